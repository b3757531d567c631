//! Appendix A's module1 of the CMU IPC manual on Courier's Session API:
//! publishes `message1`, queries `query1`, prints `message2`. It works with
//! the C module2 and module3 (and the Rust ones) through any central, C or
//! Courier's.
//!
//! ```text
//! cargo run --example module1 -- m r m q
//! CENTRALHOST=otherhost:1381 cargo run --example module1
//! ```
//! Commands come from the arguments, else from stdin, one per line, as in
//! C: `m` publishes message1, `r` queries query1, `q` quits. Each line is
//! acted on as it is typed, while the session keeps serving central.

use std::time::Duration;

use clap::Parser;
use courier::Session;
use courier_examples::appendix_a::{appendix_a, T1, T2};
use courier_examples::Error;
use futures::StreamExt;
use tokio::io::AsyncBufReadExt;

/// Appendix A's module1.
#[derive(Parser, Debug)]
#[command(name = "module1")]
pub struct Args {
    #[command(flatten)]
    central: courier_examples::Central,
    /// Commands (`m`, `r`, `q`); none: read them from stdin.
    commands: Vec<String>,
}

/// Connects, defines module1's messages, then runs the commands.
pub async fn run(args: Args) -> Result<(), Error> {
    let s = args.central.connect("module1").await?;
    println!("module1: connected");
    // As in C, module1 registers both named formats (module2 defines
    // response1 as "T2" and relies on central knowing it).
    s.ipc()?.define_formats::<T2>().await?;
    s.define::<i32>("message1").await?;
    s.define::<T1>("query1").await?;
    let mut msg2 = s.subscribe::<String>("message2").await?;
    let printer = tokio::spawn(async move {
        while let Some(m) = msg2.next().await {
            match m {
                Ok(v) => println!("msg2Handler: Receiving message2 ({}) [module1]", v.value),
                Err(e) => println!("msg2Handler: {e}"),
            }
        }
    });
    let result = if args.commands.is_empty() {
        println!("Type 'm' to send message1; Type 'r' to send query1; Type 'q' to quit");
        // tokio's stdin: the runtime keeps serving the session (central's
        // updates, message2) while this waits for the next line.
        let mut lines = tokio::io::BufReader::new(tokio::io::stdin()).lines();
        loop {
            match lines.next_line().await {
                Ok(Some(line)) => match command(&s, &line).await {
                    Ok(true) => continue,
                    Ok(false) => break Ok(()),
                    Err(e) => break Err(e),
                },
                Ok(None) => break Ok(()),
                Err(e) => break Err(format!("cannot read stdin: {e}").into()),
            }
        }
    } else {
        let mut result = Ok(());
        for c in &args.commands {
            match command(&s, c).await {
                Ok(true) => tokio::time::sleep(Duration::from_millis(300)).await,
                Ok(false) => break,
                Err(e) => {
                    result = Err(e);
                    break;
                }
            }
        }
        result
    };
    s.close().await;
    printer.abort();
    result
}

/// Runs one command; `false` to quit.
async fn command(s: &Session, c: &str) -> Result<bool, Error> {
    match c.trim() {
        "m" => {
            println!("\n  IPC_publishData(message1, &i1) [42]");
            s.publish("message1", &42i32).await?;
        }
        "r" => {
            println!("\n  IPC_queryResponseData(query1, &t1, &r1Ptr, IPC_WAIT_FOREVER)");
            let (t1, _) = appendix_a();
            let r: T2 = s
                .query("query1", &t1)
                .timeout(Duration::from_secs(10))
                .await?;
            println!("\n  Received response:\n{r:?}");
        }
        "q" => return Ok(false),
        "" => {}
        other => println!("unknown command {other:?}: 'm', 'r' or 'q'"),
    }
    Ok(true)
}

fn main() -> std::process::ExitCode {
    courier_examples::main("module1", run)
}
