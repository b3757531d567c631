//! Publishes a string on a topic, like zenoh's `z_pub`, on any backend.
//!
//! ```text
//! cargo run --example pub -- -k chatter -p 'Hello from Rust!' --count 10
//! cargo run --example pub -- -e 'rtps://7?interface=lo&peers=127.0.0.1' -k chatter
//! cargo run --example pub -- -e xrce+udp://127.0.0.1:8888 -k chatter
//! ```
//! The default endpoint is a central on 127.0.0.1:1381
//! (`cargo run -p courier-broker --bin central` starts one). Over CMU IPC a
//! message nobody subscribes to is not sent at all, as in C: start `sub`
//! first.

use clap::Parser;
use courier_examples::{seconds, Common, Error, Rounds};

/// Publishes `[   N] PAYLOAD` on a topic every period.
#[derive(Parser, Debug)]
#[command(name = "pub")]
pub struct Args {
    #[command(flatten)]
    common: Common,
    /// The topic (IPC message name, DDS topic).
    #[arg(short, long, default_value = "chatter")]
    key: String,
    /// The text to publish.
    #[arg(short, long, default_value = "Hello from Rust!")]
    payload: String,
    /// How many messages to publish (default: until Ctrl-C).
    #[arg(long)]
    count: Option<u64>,
    /// Seconds between two messages.
    #[arg(long, default_value_t = 1.0, value_parser = seconds)]
    period: f64,
}

/// Connects, then publishes until `--count` messages are out.
pub async fn run(args: Args) -> Result<(), Error> {
    let session = args.common.connect("pub").await?;
    // A Publisher handle: the topic is defined (IPC) or the DDS writer made once.
    let publisher = session.publisher::<String>(&args.key).build().await?;
    let mut rounds = Rounds::new(&session, args.count, args.period);
    while let Some(n) = rounds.next().await {
        let text = format!("[{n:4}] {}", args.payload);
        println!("Putting data ('{}': '{text}')...", args.key);
        publisher.publish(&text).await?;
    }
    // Publisher and session close when dropped; closing explicitly waits
    // until the connection said goodbye.
    drop(publisher);
    session.close().await;
    Ok(())
}

fn main() -> std::process::ExitCode {
    courier_examples::main("pub", run)
}
