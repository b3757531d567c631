//! Appendix A's module3 on Courier's Session API: prints `message1` and
//! `message2`.
//!
//! ```text
//! CENTRALHOST=127.0.0.1:1381 cargo run -p courier-examples --bin module3 [-- SECONDS]
//! ```

#[path = "appendix_a.rs"]
mod appendix;

use courier::Session;
use futures::StreamExt;

#[tokio::main(flavor = "current_thread")]
async fn main() -> Result<(), Box<dyn std::error::Error>> {
    let s = Session::builder("ipc://").name("module3").connect().await?;
    println!("module3: connected");
    let mut msg1 = s.subscribe::<i32>("message1").await?;
    let mut msg2 = s.subscribe::<String>("message2").await?;
    let stop = appendix::stop_signal();
    tokio::pin!(stop);
    loop {
        tokio::select! {
            Some(m) = msg1.next() => match m {
                Ok(v) => println!("msg1Handler: Receiving message1 ({}) [module3]", v.value),
                Err(e) => { println!("{e}"); break; }
            },
            Some(m) = msg2.next() => match m {
                Ok(v) => println!("msg2Handler: Receiving message2 ({}) [module3]", v.value),
                Err(e) => { println!("{e}"); break; }
            },
            _ = &mut stop => break,
        }
    }
    s.close().await;
    Ok(())
}
