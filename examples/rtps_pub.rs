//! Publishes Cyclone DDS's HelloWorld sample over DDS/RTPS, showing the
//! participant's options and a writer's QoS.
//!
//! ```text
//! cargo run --example rtps_pub -- --domain 7 --count 10
//! cargo run --example rtps_pub -- --domain 7 --best-effort --transient-local
//! ```
//! Pinned to `lo` with unicast discovery by default: nothing leaves the
//! machine. Cyclone's `HelloworldSubscriber` (same domain, same interface)
//! and `rtps_sub` receive it.

use clap::Parser;
use courier_examples::{seconds, Error, HelloWorld, Qos, Rounds, Rtps};

/// Publishes HelloWorld samples on a DDS topic.
#[derive(Parser, Debug)]
#[command(name = "rtps_pub")]
pub struct Args {
    #[command(flatten)]
    rtps: Rtps,
    /// The DDS topic.
    #[arg(short, long, default_value = "HelloWorldData_Msg")]
    key: String,
    /// The message text.
    #[arg(short, long, default_value = "Hello World")]
    payload: String,
    /// The `userID` key: samples of one id are one DDS instance.
    #[arg(long, default_value_t = 1)]
    user_id: i32,
    #[command(flatten)]
    qos: Qos,
    /// How many samples (default: until Ctrl-C).
    #[arg(long)]
    count: Option<u64>,
    /// Seconds between two samples.
    #[arg(long, default_value_t = 1.0, value_parser = seconds)]
    period: f64,
}

/// Joins the domain and publishes.
pub async fn run(args: Args) -> Result<(), Error> {
    let session = args.rtps.connect("rtps_pub").await?;
    let mut writer = session.publisher::<HelloWorld>(&args.key);
    if args.qos.best_effort {
        writer = writer.best_effort();
    }
    if args.qos.transient_local {
        writer = writer.transient_local().keep_last(1);
    }
    let writer = writer.build().await?;
    println!(
        "Writing on DDS topic '{}' in domain {} ({}, type {})",
        args.key,
        args.rtps.domain,
        args.rtps.interface,
        <HelloWorld as courier::IpcMessage>::TYPE_NAME
    );
    let mut rounds = Rounds::new(&session, args.count, args.period);
    while let Some(n) = rounds.next().await {
        let sample = HelloWorld {
            user_id: args.user_id,
            message: format!("{} {n}", args.payload),
        };
        println!("Writing {sample:?}");
        // Resolves once the sample is handed to the participant; with
        // `.confirmed()` it would wait until every reliable reader acked it.
        writer.publish(&sample).await?;
    }
    // Closing the writer disposes the instance it wrote (autodispose).
    drop(writer);
    session.close().await;
    Ok(())
}

fn main() -> std::process::ExitCode {
    courier_examples::main("rtps_pub", run)
}
