//! A bridge between two centrals (the IPC manual §7's use of contexts): one
//! `Session` per central; every message named on the command line that is
//! published on the first central is republished, byte for byte, on the
//! second.
//!
//! ```text
//! cargo run --example bridge -- ipc://hostA:1381 ipc://hostB:1381 message1:int message2:string
//! ```
//! Each message is given as `name:format` (its IPC format string), so the
//! bridge can define it on the second central.

use courier::Session;
use courier_examples::Error;

/// Forwards `msgs` (name, format) from `from` to `to` until `from` ends.
pub async fn bridge(
    from: &Session,
    to: &Session,
    msgs: &[(String, String)],
) -> Result<(), courier::Error> {
    let mut tasks = Vec::new();
    for (name, fmt) in msgs {
        let fmt = (!fmt.is_empty()).then_some(fmt.as_str());
        from.ipc()?.define(name, fmt).await?;
        to.ipc()?.define(name, fmt).await?;
        let mut rx = from.subscribe_raw(name).await?;
        let to = to.clone();
        let name = name.clone();
        tasks.push(tokio::spawn(async move {
            // None: the first central went away
            while let Some(s) = rx.recv().await {
                if let Err(e) = to.publish_raw(&name, &s.data).await {
                    eprintln!("bridge: {name}: {e}");
                    break;
                }
            }
        }));
    }
    for t in tasks {
        let _ = t.await;
    }
    Ok(())
}

/// Republishes messages of one central on another.
#[derive(clap::Parser, Debug)]
#[command(name = "bridge")]
pub struct Args {
    /// The central to read from.
    from: String,
    /// The central to publish on.
    to: String,
    /// The messages, each `name:format` (e.g. `message1:int`).
    #[arg(required = true, value_parser = name_format)]
    msgs: Vec<(String, String)>,
}

/// Parses `name:format`.
fn name_format(m: &str) -> Result<(String, String), String> {
    match m.split_once(':') {
        Some((n, f)) if !n.is_empty() => Ok((n.to_string(), f.to_string())),
        _ => Err(format!("{m:?} is not name:format (e.g. message1:int)")),
    }
}

/// Connects to both centrals and forwards until the first one goes away.
pub async fn run(args: Args) -> Result<(), Error> {
    let from = courier_examples::connect(
        Session::builder(&args.from).name("bridge-in"),
        &args.from,
        10.0,
    )
    .await?;
    let to = courier_examples::connect(
        Session::builder(&args.to).name("bridge-out"),
        &args.to,
        10.0,
    )
    .await?;
    println!(
        "bridge: {} -> {} for {} message(s)",
        args.from,
        args.to,
        args.msgs.len()
    );
    bridge(&from, &to, &args.msgs).await?;
    Ok(())
}

fn main() -> std::process::ExitCode {
    courier_examples::main("bridge", run)
}
