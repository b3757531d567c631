//! Appendix A's module2 on Courier's Session API: prints `message1`,
//! answers `query1` with `response1` after publishing `message2` — the
//! reply is sent from another task, as IPC_delayResponse allows.
//!
//! ```text
//! CENTRALHOST=127.0.0.1:1381 cargo run -p courier-examples --bin module2 [-- SECONDS]
//! ```
//! Runs for SECONDS (default: until Ctrl-C).

#[path = "appendix_a.rs"]
mod appendix;

use appendix::{appendix_a, T1, T2};
use courier::Session;
use futures::StreamExt;

#[tokio::main(flavor = "current_thread")]
async fn main() -> Result<(), Box<dyn std::error::Error>> {
    let s = Session::builder("ipc://").name("module2").connect().await?;
    println!("module2: connected");
    s.define::<String>("message2").await?;
    s.define::<T2>("response1").await?;
    let mut msg1 = s.subscribe::<i32>("message1").await?;
    let mut queries = s.serve::<T1, T2>("query1", "response1").await?;
    let stop = appendix::stop_signal();
    tokio::pin!(stop);
    loop {
        tokio::select! {
            Some(m) = msg1.next() => match m {
                Ok(v) => println!("msg1Handler: Receiving message1 ({}) [module2]", v.value),
                Err(e) => { println!("msg1Handler: {e}"); break; }
            },
            Some(q) = queries.next() => match q {
                Ok(req) => {
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
                Err(e) => { println!("queryHandler: {e}"); break; }
            },
            _ = &mut stop => break,
        }
    }
    s.close().await;
    Ok(())
}
