//! The README's first command: one Rust type travelling through every kind
//! of system Courier talks to, in one process, with nothing to install.
//!
//! ```text
//! cargo run --example demo              # a sentence per step
//! cargo run --example demo -- --bytes   # and the bytes each protocol carries
//! ```
//!
//! The cast, all on 127.0.0.1 (DDS pinned to `lo`, unicast discovery):
//! - an IPC **central**: the broker of CMU IPC, to which robot modules
//!   written in C, Python, Lisp or Java connect (here Courier's own,
//!   embedded, on a free port);
//! - two IPC **modules**, `sensor` and `bridge`: Courier sessions speaking
//!   the C library's wire protocol, so a C module could take either role;
//! - a **DDS participant** (the `bridge` module's second session), which
//!   Cyclone DDS, Fast DDS or ROS 2 nodes would see as one of theirs;
//! - a **DDS-XRCE agent**: the gateway through which microcontrollers
//!   (micro-ROS, eProsima's Micro XRCE-DDS clients) reach DDS;
//! - an XRCE **client** session, standing in for such a microcontroller.
//!
//! A `Reading` published by `sensor` on IPC is routed by central to
//! `bridge`, written by it into DDS, read from DDS by the agent and handed
//! to the XRCE client; the client's answer takes the way back. Every step
//! has a deadline: a step that does not happen in time ends the demo with
//! a message and exit status 1.

mod bytes;

use std::process::ExitCode;
use std::time::Duration;

use clap::Parser;
use courier::rtps_backend::RtpsOptions;
use courier::{IpcMessage, Session, SessionEvent};
use courier_broker::xrce_agent::{Transport, XrceAgent};
use courier_broker::{CentralServer, LogSink};
use courier_examples::{seconds, Error};
use futures::StreamExt;

/// The one message type of the demo. `#[derive(IpcMessage)]` gives it an IPC
/// format string (`{string, uint, double}`), C-identical IPC bytes, DDS's
/// CDR encoding and a DDS type name.
#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "courier_demo::Reading")]
pub struct Reading {
    /// Who measured it.
    pub sensor: String,
    /// Its number.
    pub seq: u32,
    /// The temperature.
    pub celsius: f64,
}

/// The demo's arguments.
#[derive(Parser, Debug)]
#[command(
    name = "demo",
    about = "One Rust type through CMU IPC, DDS and DDS-XRCE, in one process"
)]
pub struct Args {
    /// Also print the bytes of each protocol.
    #[arg(long)]
    bytes: bool,
    /// The DDS domain id the participants join (on `lo` only).
    #[arg(long, default_value_t = 0)]
    domain: u32,
    /// How long each step may take (seconds).
    #[arg(long, default_value_t = 10.0, value_parser = seconds)]
    timeout: f64,
}

/// Bounds one step: its error, or a message saying what did not happen.
async fn step<T, E: Into<Error>>(
    t: Duration,
    what: &str,
    f: impl std::future::IntoFuture<Output = Result<T, E>>,
) -> Result<T, Error> {
    match tokio::time::timeout(t, f.into_future()).await {
        Ok(r) => r.map_err(|e| format!("{what}: {}", e.into()).into()),
        Err(_) => Err(format!("{what}: did not happen within {} s", t.as_secs_f64()).into()),
    }
}

/// The next value of a subscription, within `t`.
async fn next<T: IpcMessage>(
    t: Duration,
    what: &str,
    sub: &mut courier::Subscriber<T>,
) -> Result<T, Error> {
    let s = step(t, what, async {
        sub.next().await.ok_or("the subscription ended")
    })
    .await?;
    Ok(s.map_err(|e| format!("{what}: {e}"))?.value)
}

/// Runs the whole demo; every step bounded by `--timeout`.
pub async fn run(args: Args) -> Result<(), Error> {
    let t = Duration::from_secs_f64(args.timeout);
    let reading = Reading {
        sensor: "thermometer-1".into(),
        seq: 1,
        celsius: 21.5,
    };
    println!("Courier demo: one Rust type, `Reading`, through CMU IPC, DDS and DDS-XRCE.\n");
    if args.bytes {
        bytes::show(&reading);
    }

    // 1. The IPC central, embedded, on a free port of 127.0.0.1.
    let central = step(t, "starting central", async {
        CentralServer::builder()
            .bind([127, 0, 0, 1].into())
            .port(0)
            .log_sink(LogSink::discard())
            .spawn()
            .await
    })
    .await?;
    let ipc_url = format!("ipc://{}", central.local_addr());
    println!(
        "1. An IPC central is running on {}: CMU IPC modules, in C or Rust, connect to it.",
        central.local_addr()
    );

    // 2. The bridge module: on IPC (an in-process link to the central this
    //    program hosts) and in DDS (a participant pinned to lo).
    let bridge_ipc = step(
        t,
        "module 'bridge' connecting to central",
        central.session("bridge").connect(),
    )
    .await?;
    let rtps_url = format!("rtps://{}", args.domain);
    let bridge_dds = step(
        t,
        "module 'bridge' joining DDS",
        Session::builder(&rtps_url)
            .name("bridge")
            .interface("lo")
            .peers(["127.0.0.1"])
            .multicast(false)
            .connect(),
    )
    .await?;
    let mut discovery = bridge_dds.events();
    let mut from_ipc = step(
        t,
        "bridge subscribing on IPC",
        bridge_ipc.subscribe::<Reading>("reading"),
    )
    .await?;
    let to_dds = step(
        t,
        "bridge making its DDS writer",
        bridge_dds.publisher::<Reading>("reading").build(),
    )
    .await?;
    let mut from_dds = step(
        t,
        "bridge making its DDS reader",
        bridge_dds.subscribe::<Reading>("reading_ack"),
    )
    .await?;
    let to_ipc = step(
        t,
        "bridge defining 'reading_ack' on IPC",
        bridge_ipc.publisher::<Reading>("reading_ack").build(),
    )
    .await?;
    println!(
        "2. Module 'bridge' joined central and DDS domain {} (interface lo, unicast discovery): \
         it copies IPC message 'reading' into DDS topic 'reading', and DDS 'reading_ack' back into IPC.",
        args.domain
    );

    // 3. The XRCE agent: UDP on a free port; its DDS side pinned to lo too.
    let mut rtps = RtpsOptions::default();
    rtps.domain = args.domain;
    rtps.interface = Some("lo".into());
    rtps.peers = vec!["127.0.0.1".into()];
    rtps.multicast = false;
    let agent = step(t, "starting the XRCE agent", async {
        XrceAgent::builder()
            .transport(Transport::Udp(([127, 0, 0, 1], 0).into()))
            .rtps(rtps)
            .spawn()
            .await
    })
    .await?;
    let agent_addr = agent.udp_addrs()[0];
    println!(
        "3. A DDS-XRCE agent listens on udp {agent_addr}: microcontrollers too small for DDS reach \
         the DDS domain through it."
    );

    // The rest runs in a function of its own so that, whatever happens,
    // everything started above is stopped below.
    let result = travel(
        t,
        &args,
        &reading,
        &ipc_url,
        agent_addr,
        Bridge {
            from_ipc: &mut from_ipc,
            to_dds: &to_dds,
            from_dds: &mut from_dds,
            to_ipc: &to_ipc,
            discovery: &mut discovery,
        },
    )
    .await;

    drop((from_ipc, to_dds, from_dds, to_ipc));
    let stop = async {
        bridge_dds.close().await;
        bridge_ipc.close().await;
        agent.shutdown().await;
        central.shutdown().await;
    };
    if tokio::time::timeout(t, stop).await.is_err() && result.is_ok() {
        return Err("stopping the agent, the participant and central took too long".into());
    }
    result
}

/// The bridge module's four ends.
struct Bridge<'a> {
    from_ipc: &'a mut courier::Subscriber<Reading>,
    to_dds: &'a courier::Publisher<Reading>,
    from_dds: &'a mut courier::Subscriber<Reading>,
    to_ipc: &'a courier::Publisher<Reading>,
    discovery: &'a mut courier::Events,
}

/// Steps 4 to 10: the client and the sensor connect, and a reading goes
/// from IPC to XRCE and its acknowledgement back.
async fn travel(
    t: Duration,
    args: &Args,
    reading: &Reading,
    ipc_url: &str,
    agent_addr: std::net::SocketAddr,
    bridge: Bridge<'_>,
) -> Result<(), Error> {
    // 4. An XRCE client, as a microcontroller would run it.
    let xrce_url = format!("xrce+udp://{agent_addr}?domain={}", args.domain);
    let device = step(
        t,
        "the XRCE client connecting to the agent",
        Session::builder(&xrce_url).name("device").connect(),
    )
    .await?;
    let mut readings = step(
        t,
        "the XRCE client subscribing",
        device.subscribe::<Reading>("reading"),
    )
    .await?;
    let acks = step(
        t,
        "the XRCE client making its writer",
        device.publisher::<Reading>("reading_ack").build(),
    )
    .await?;
    println!("4. An XRCE client (standing in for a microcontroller) connected to the agent and subscribed to 'reading'.");

    // 5. DDS discovery: the bridge's writer meets the agent's reader (and
    //    the agent's writer the bridge's reader).
    let (mut reader_seen, mut writer_seen) = (false, false);
    step(t, "DDS discovery between the bridge and the agent", async {
        while !(reader_seen && writer_seen) {
            match bridge.discovery.next().await {
                Some(SessionEvent::SubscriptionFound(e)) if e.topic == "reading" => {
                    reader_seen = true
                }
                Some(SessionEvent::PublicationFound(e)) if e.topic == "reading_ack" => {
                    writer_seen = true
                }
                Some(_) => {}
                None => return Err("the DDS participant stopped"),
            }
        }
        Ok(())
    })
    .await?;
    println!("5. DDS discovery: the bridge's participant and the agent's found each other's readers and writers.");

    // 6. The sensor: an IPC module over TCP, exactly as a C module connects.
    let sensor = step(
        t,
        "module 'sensor' connecting to central",
        Session::builder(ipc_url).name("sensor").connect(),
    )
    .await?;
    step(
        t,
        "sensor defining 'reading'",
        sensor.define::<Reading>("reading"),
    )
    .await?;
    let mut acks_in = step(
        t,
        "sensor subscribing to 'reading_ack'",
        sensor.subscribe::<Reading>("reading_ack"),
    )
    .await?;
    // As in C, a module does not send a message nobody subscribes to; this
    // asks central, so the sensor knows the bridge is listening.
    let handlers = step(
        t,
        "sensor asking central who listens",
        sensor.num_handlers("reading"),
    )
    .await?;
    println!(
        "6. Module 'sensor' connected to central over TCP, as a C module does, and defined 'reading' \
         with IPC format {:?}; central says {handlers} module listens to it.",
        Reading::FORMAT
    );

    let result = async {
        // 7. IPC publish.
        step(t, "sensor publishing", sensor.publish("reading", reading)).await?;
        println!("7. 'sensor' published {reading:?} on IPC.");

        // 8. central → bridge → DDS.
        let got = next(
            t,
            "central routing the reading to 'bridge'",
            bridge.from_ipc,
        )
        .await?;
        step(t, "bridge writing into DDS", bridge.to_dds.publish(&got)).await?;
        println!(
            "8. Central routed it to 'bridge', which wrote it into DDS topic 'reading' (type {}).",
            Reading::TYPE_NAME
        );

        // 9. DDS → agent → XRCE client.
        let on_device = next(
            t,
            "the reading reaching the XRCE client through the agent",
            &mut readings,
        )
        .await?;
        if on_device != *reading {
            return Err(format!("the XRCE client got {on_device:?}, not what was sent").into());
        }
        println!("9. The agent read it from DDS and handed it to the XRCE client: {on_device:?}.");

        // 10. The way back: XRCE → agent → DDS → bridge → IPC.
        let ack = Reading {
            sensor: "device".into(),
            ..on_device
        };
        step(t, "the XRCE client acknowledging", acks.publish(&ack)).await?;
        let got = next(
            t,
            "the acknowledgement reaching the bridge through DDS",
            bridge.from_dds,
        )
        .await?;
        step(
            t,
            "bridge publishing the acknowledgement on IPC",
            bridge.to_ipc.publish(&got),
        )
        .await?;
        let back = next(t, "the acknowledgement reaching 'sensor'", &mut acks_in).await?;
        if back != ack {
            return Err(format!("'sensor' got {back:?}, not the acknowledgement").into());
        }
        println!(
            "10. And back: the XRCE client answered on 'reading_ack'; through the agent, DDS, \
             'bridge' and central, 'sensor' received {back:?}."
        );
        Ok::<(), Error>(())
    }
    .await;

    drop((readings, acks, acks_in));
    sensor.close().await;
    device.close().await;
    if result.is_ok() {
        println!("\nOne Rust type, three protocols, no glue code. Done.");
    }
    result
}

fn main() -> ExitCode {
    courier_examples::main("demo", run)
}
