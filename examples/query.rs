//! Sends one query and prints the reply, like zenoh's `z_get`; `serve`
//! answers it.
//!
//! ```text
//! cargo run --example query -- -k greet -p 'Who are you?'
//! cargo run --example query -- -e 'rtps://7?interface=lo&peers=127.0.0.1' -k greet
//! ```
//! Over CMU IPC, central holds the query until a module serves it; over DDS
//! it waits for a service (a ROS 2 one is fine). Either way no longer than
//! `--timeout`.

use std::time::Duration;

use clap::Parser;
use courier_examples::{seconds, Common, Error};

/// Asks a question, prints the answer.
#[derive(Parser, Debug)]
#[command(name = "query")]
pub struct Args {
    #[command(flatten)]
    common: Common,
    /// The query (IPC message name, DDS service name).
    #[arg(short, long, default_value = "greet")]
    key: String,
    /// The request text.
    #[arg(short, long, default_value = "Who are you?")]
    payload: String,
    /// How long to wait for the reply (seconds).
    #[arg(long, default_value_t = 10.0, value_parser = seconds)]
    timeout: f64,
}

/// Connects, queries once, prints the reply.
pub async fn run(args: Args) -> Result<(), Error> {
    let session = args.common.connect("query").await?;
    println!("Sending query '{}' ('{}')...", args.key, args.payload);
    // Every query is bounded: without `.timeout` it gives up after 10 s.
    let reply: String = session
        .query(&args.key, &args.payload)
        .timeout(Duration::from_secs_f64(args.timeout))
        .await?;
    println!(">> Received reply ('{}': '{reply}')", args.key);
    session.close().await;
    Ok(())
}

fn main() -> std::process::ExitCode {
    courier_examples::main("query", run)
}
