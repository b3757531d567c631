//! Answers queries with a string, like zenoh's `z_queryable`; `query` asks.
//!
//! ```text
//! cargo run --example serve -- -k greet -p 'I am serve'
//! cargo run --example serve -- -e 'rtps://7?interface=lo&peers=127.0.0.1' -k greet
//! ```
//! Runs until Ctrl-C, or until it answered `--count` queries.

use clap::Parser;
use courier_examples::{until_ctrl_c, Common, Error};
use futures::StreamExt;

/// Answers every query with `PAYLOAD (you asked: REQUEST)`.
#[derive(Parser, Debug)]
#[command(name = "serve")]
pub struct Args {
    #[command(flatten)]
    common: Common,
    /// The query (IPC message name, DDS service name).
    #[arg(short, long, default_value = "greet")]
    key: String,
    /// The answer text.
    #[arg(short, long, default_value = "I am serve")]
    payload: String,
    /// Stop after answering this many queries (default: until Ctrl-C).
    #[arg(long)]
    count: Option<u64>,
}

/// Connects, serves, answers.
pub async fn run(args: Args) -> Result<(), Error> {
    let session = args.common.connect("serve").await?;
    // "": the reply goes under the backend's own name (IPC: `<key>Reply`;
    // DDS: the service's reply topic). Dropping `requests` stops serving.
    let mut requests = session.serve::<String, String>(&args.key, "").await?;
    println!("Serving '{}'; Ctrl-C to quit", args.key);
    let mut n = 0u64;
    while args.count.is_none_or(|c| n < c) {
        let Some(request) = until_ctrl_c(requests.next()).await else {
            break;
        };
        let request = match request {
            Some(Ok(r)) => r,
            Some(Err(e)) => {
                eprintln!("serve: {e}");
                continue;
            }
            None => return Err("the connection ended".into()),
        };
        println!(">> Received query ('{}': '{}')", args.key, request.value);
        let answer = format!("{} (you asked: {})", args.payload, request.value);
        // A reply can also be sent later, from another task (IPC_delayResponse).
        request.reply(&answer).await?;
        n += 1;
    }
    drop(requests);
    session.close().await;
    Ok(())
}

fn main() -> std::process::ExitCode {
    courier_examples::main("serve", run)
}
