//! Appendix A's module3 of the CMU IPC manual on Courier's Session API:
//! prints `message1` and `message2`.
//!
//! ```text
//! cargo run --example module3 [-- --seconds 30]
//! ```
//! Runs until Ctrl-C, or for `--seconds`.

use courier_examples::Error;
use futures::StreamExt;

/// The arguments: `-e URL`, `--seconds S`.
pub type Args = courier_examples::Module;

/// What a stream that ends means.
const GONE: &str = "the connection to central ended";

/// Connects and prints message1 and message2 until stopped.
pub async fn run(args: Args) -> Result<(), Error> {
    let s = args.central.connect("module3").await?;
    println!("module3: connected");
    let mut msg1 = s.subscribe::<i32>("message1").await?;
    let mut msg2 = s.subscribe::<String>("message2").await?;
    let stop = courier_examples::stop_after(args.seconds);
    tokio::pin!(stop);
    loop {
        tokio::select! {
            m = msg1.next() => match m {
                Some(Ok(v)) => println!("msg1Handler: Receiving message1 ({}) [module3]", v.value),
                Some(Err(e)) => println!("msg1Handler: {e}"),
                None => return Err(GONE.into()),
            },
            m = msg2.next() => match m {
                Some(Ok(v)) => println!("msg2Handler: Receiving message2 ({}) [module3]", v.value),
                Some(Err(e)) => println!("msg2Handler: {e}"),
                None => return Err(GONE.into()),
            },
            _ = &mut stop => break,
        }
    }
    s.close().await;
    Ok(())
}

fn main() -> std::process::ExitCode {
    courier_examples::main("module3", run)
}
