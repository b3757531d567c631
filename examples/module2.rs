//! Appendix A's module2 of the CMU IPC manual on Courier's Session API:
//! prints `message1`, answers `query1` with `response1` after publishing
//! `message2` — the reply is sent from another task, as IPC_delayResponse
//! allows.
//!
//! ```text
//! cargo run --example module2 [-- --seconds 30]
//! ```
//! Runs until Ctrl-C, or for `--seconds`.

use courier_examples::appendix_a::{appendix_a, T1, T2};
use courier_examples::Error;
use futures::StreamExt;

/// The arguments: `-e URL`, `--seconds S`.
pub type Args = courier_examples::Module;

/// What a stream that ends means.
const GONE: &str = "the connection to central ended";

/// Connects and handles message1 and query1 until stopped.
pub async fn run(args: Args) -> Result<(), Error> {
    let s = args.central.connect("module2").await?;
    println!("module2: connected");
    s.define::<String>("message2").await?;
    s.define::<T2>("response1").await?;
    let mut msg1 = s.subscribe::<i32>("message1").await?;
    let mut queries = s.serve::<T1, T2>("query1", "response1").await?;
    let stop = courier_examples::stop_after(args.seconds);
    tokio::pin!(stop);
    loop {
        tokio::select! {
            m = msg1.next() => match m {
                Some(Ok(v)) => println!("msg1Handler: Receiving message1 ({}) [module2]", v.value),
                Some(Err(e)) => println!("msg1Handler: {e}"),
                None => return Err(GONE.into()),
            },
            q = queries.next() => match q {
                Some(Ok(req)) => {
                    println!("queryHandler: Receiving query1 [module2]\n{:?}", req.value);
                    println!("\n  IPC_publishData(message2, &str1) [Hello, world]");
                    s.publish("message2", &String::from("Hello, world")).await?;
                    let (_, t2) = appendix_a();
                    tokio::spawn(async move {
                        println!("\n  IPC_respondData(response1, &t2)");
                        if let Err(e) = req.reply(&t2).await {
                            println!("respond failed: {e}");
                        }
                    });
                }
                Some(Err(e)) => println!("queryHandler: {e}"),
                None => return Err(GONE.into()),
            },
            _ = &mut stop => break,
        }
    }
    s.close().await;
    Ok(())
}

fn main() -> std::process::ExitCode {
    courier_examples::main("module2", run)
}
