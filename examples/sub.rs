//! Prints the strings published on a topic, like zenoh's `z_sub`, on any
//! backend.
//!
//! ```text
//! cargo run --example sub -- -k chatter
//! cargo run --example sub -- -e 'rtps://7?interface=lo&peers=127.0.0.1' -k chatter --count 3
//! ```
//! Runs until Ctrl-C, or until `--count` messages arrived.

use clap::Parser;
use courier_examples::{until_ctrl_c, Common, Error};
use futures::StreamExt;

/// Prints every string published on a topic.
#[derive(Parser, Debug)]
#[command(name = "sub")]
pub struct Args {
    #[command(flatten)]
    common: Common,
    /// The topic (IPC message name, DDS topic).
    #[arg(short, long, default_value = "chatter")]
    key: String,
    /// Stop after this many messages (default: run until Ctrl-C).
    #[arg(long)]
    count: Option<u64>,
}

/// Connects, subscribes, and prints what arrives.
pub async fn run(args: Args) -> Result<(), Error> {
    let session = args.common.connect("sub").await?;
    // Keep `sub` alive for as long as you want messages: dropping it
    // unsubscribes. Up to 1000 unread messages wait in it; past that it
    // applies back-pressure (`subscribe_with` and `QueuePolicy` choose).
    let mut sub = session.subscribe::<String>(&args.key).await?;
    println!("Subscribed to '{}'; Ctrl-C to quit", args.key);
    let mut n = 0u64;
    while args.count.is_none_or(|c| n < c) {
        let Some(sample) = until_ctrl_c(sub.next()).await else {
            break;
        };
        match sample {
            Some(Ok(s)) => println!(">> Received ('{}': '{}')", s.msg, s.value),
            // a message that did not decode as a string: say so, go on
            Some(Err(e)) => eprintln!("sub: {e}"),
            None => return Err("the connection ended".into()),
        }
        n += 1;
    }
    drop(sub);
    session.close().await;
    Ok(())
}

fn main() -> std::process::ExitCode {
    courier_examples::main("sub", run)
}
