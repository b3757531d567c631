//! Appendix A's module1 on Courier's Session API: publishes `message1`,
//! queries `query1`, prints `message2`. Interoperates with the C module2
//! and module3 (and the Rust ones) through any central.
//!
//! ```text
//! CENTRALHOST=127.0.0.1:1381 cargo run -p courier-examples --bin module1 -- m r m q
//! ```
//! Commands come from the arguments, else from stdin, one per line, as in
//! C: `m` publishes message1, `r` queries query1, `q` quits.

#[path = "appendix_a.rs"]
mod appendix;

use std::io::BufRead;
use std::time::Duration;

use appendix::{appendix_a, T1, T2};
use courier::Session;
use futures::StreamExt;

#[tokio::main(flavor = "current_thread")]
async fn main() -> Result<(), Box<dyn std::error::Error>> {
    let s = Session::builder("ipc://").name("module1").connect().await?;
    println!("module1: connected");
    // As in C, module1 registers both named formats (module2 defines
    // response1 as "T2" and relies on central knowing it).
    s.ipc()?.define_formats::<T2>().await?;
    s.define::<i32>("message1").await?;
    s.define::<T1>("query1").await?;
    let mut msg2 = s.subscribe::<String>("message2").await?;
    tokio::spawn(async move {
        while let Some(m) = msg2.next().await {
            match m {
                Ok(v) => println!("msg2Handler: Receiving message2 ({}) [module1]", v.value),
                Err(e) => println!("msg2Handler: {e}"),
            }
        }
    });
    let args: Vec<String> = std::env::args().skip(1).collect();
    let commands: Box<dyn Iterator<Item = String>> = if args.is_empty() {
        println!("Type 'm' to send message1; Type 'r' to send query1; Type 'q' to quit");
        Box::new(
            std::io::stdin()
                .lock()
                .lines()
                .map_while(Result::ok)
                .collect::<Vec<_>>()
                .into_iter(),
        )
    } else {
        Box::new(args.into_iter())
    };
    let (t1, _) = appendix_a();
    for c in commands {
        match c.trim() {
            "m" => {
                println!("\n  IPC_publishData(message1, &i1) [42]");
                s.publish("message1", &42i32).await?;
            }
            "r" => {
                println!("\n  IPC_queryResponseData(query1, &t1, &r1Ptr, IPC_WAIT_FOREVER)");
                let r: T2 = s
                    .query("query1", &t1)
                    .timeout(Duration::from_secs(10))
                    .await?;
                println!("\n  Received response:\n{r:?}");
            }
            "q" => break,
            other => println!("unknown command {other:?}"),
        }
        tokio::time::sleep(Duration::from_millis(300)).await;
    }
    s.close().await;
    Ok(())
}
