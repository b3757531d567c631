//! Reads Cyclone DDS's HelloWorld samples over DDS/RTPS, and prints who is
//! on the domain as it discovers them.
//!
//! ```text
//! cargo run --example rtps_sub -- --domain 7
//! cargo run --example rtps_sub -- --domain 7 --best-effort --count 3
//! ```
//! Pinned to `lo` with unicast discovery by default: nothing leaves the
//! machine.

use clap::Parser;
use courier::SessionEvent;
use courier_examples::{Error, HelloWorld, Qos, Rtps};
use futures::StreamExt;

/// Prints HelloWorld samples and discovery events.
#[derive(Parser, Debug)]
#[command(name = "rtps_sub")]
pub struct Args {
    #[command(flatten)]
    rtps: Rtps,
    /// The DDS topic.
    #[arg(short, long, default_value = "HelloWorldData_Msg")]
    key: String,
    #[command(flatten)]
    qos: Qos,
    /// Stop after this many samples (default: until Ctrl-C).
    #[arg(long)]
    count: Option<u64>,
}

/// Joins the domain and reads.
pub async fn run(args: Args) -> Result<(), Error> {
    let session = args.rtps.connect("rtps_sub").await?;
    // Take the event stream before making readers, to see every discovery.
    let mut events = session.events();
    let mut reader = session.subscriber::<HelloWorld>(&args.key);
    if args.qos.best_effort {
        reader = reader.best_effort();
    }
    if args.qos.transient_local {
        reader = reader.transient_local();
    }
    let mut reader = reader.build().await?;
    println!(
        "Reading DDS topic '{}' in domain {}",
        args.key, args.rtps.domain
    );
    let mut n = 0u64;
    while args.count.is_none_or(|c| n < c) {
        tokio::select! {
            s = reader.next() => match s {
                Some(Ok(s)) => {
                    println!(">> {:?} from writer {}", s.value, s.source.map_or("?".into(), |g| g.to_string()));
                    n += 1;
                }
                Some(Err(e)) => eprintln!("rtps_sub: {e}"),
                None => return Err("the participant stopped".into()),
            },
            Some(e) = events.next() => match e {
                SessionEvent::PublicationFound(w) if w.topic == args.key => {
                    println!("found a writer of '{}' (type {})", w.topic, w.type_name)
                }
                SessionEvent::IncompatibleQos { .. } | SessionEvent::TypeMismatch { .. } => {
                    eprintln!("rtps_sub: {e:?}")
                }
                _ => {}
            },
            _ = tokio::signal::ctrl_c() => break,
        }
    }
    drop(reader);
    session.close().await;
    Ok(())
}

fn main() -> std::process::ExitCode {
    courier_examples::main("rtps_sub", run)
}
