//! The ROS 2 graph topic `ros_discovery_info` both ways with a peer that
//! writes and reads it as rmw_cyclonedds does (rmw_dds_common's field
//! layout and QoS, on Cyclone DDS 11: the PyPI `cyclonedds` package,
//! `tests/peers/rtps/ros2_graph_peer.py`): Courier's session reports the
//! peer's node with its topics resolved through discovery, and the peer
//! reads Courier's node, resolves its GIDs to Courier's DDS topics, and
//! sees the node change when Courier drops a publisher. Humble's 24-byte
//! GIDs both ways; broken samples from a peer are reported.
//!
//! Loopback only: the peer's built-in unicast configuration on `lo`,
//! Courier `interface=lo&peers=127.0.0.1`.

use std::time::Duration;

use courier::rtps_backend::{Ros2Kind, Ros2Node};
use courier::{IpcMessage, Session, SessionEvent};
use futures::StreamExt;

mod common;
use common::T;

use courier_tests::peers::{cyclone11_python, sources_dir, PeerProcess};

/// `std_msgs/msg/String` as ROS 2 names it in DDS.
#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "std_msgs::msg::dds_::String_")]
struct RosString {
    data: String,
}

fn peer(key: u32, args: &[&str]) -> PeerProcess {
    let python = cyclone11_python().unwrap_or_else(|e| panic!("the Cyclone 11 peer: {e}"));
    let mut a = vec![
        sources_dir().join("ros2_graph_peer.py").into_os_string(),
        "--domain".into(),
        courier_tests::domains::lease(key).to_string().into(),
    ];
    a.extend(args.iter().map(|s| s.into()));
    PeerProcess::spawn(python, &a).unwrap_or_else(|e| panic!("cannot start the peer: {e}"))
}

async fn blocking<R: Send + 'static>(f: impl FnOnce() -> R + Send + 'static) -> R {
    tokio::task::spawn_blocking(f).await.expect("blocking task")
}

/// The peer's `ready` line: its participant GID, writer and reader GUIDs.
struct Ready {
    participant: String,
    writer: String,
    reader: String,
}

async fn ready(mut p: PeerProcess) -> (PeerProcess, Ready) {
    blocking(move || {
        let l = p.expect_line("ready ", T).unwrap_or_else(|e| panic!("{e}"));
        let w: Vec<&str> = l.split(' ').collect();
        let [_, participant, "writer", writer, "reader", reader] = w[..] else {
            panic!("unexpected ready line {l:?}");
        };
        let r = Ready {
            participant: participant.to_string(),
            writer: writer.to_string(),
            reader: reader.to_string(),
        };
        (p, r)
    })
    .await
}

/// Waits for a line of the peer's equal to `line`; its lines meanwhile.
async fn expect_exact(mut p: PeerProcess, line: String) -> PeerProcess {
    blocking(move || {
        let l = p.expect_line(&line, T).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(l, line, "seen: {:?}", p.seen());
        p
    })
    .await
}

async fn finish(mut p: PeerProcess) {
    blocking(move || {
        p.close_stdin();
        p.expect_line("done", T).unwrap_or_else(|e| panic!("{e}"));
        p.wait_success(T).unwrap_or_else(|e| panic!("{e}"));
    })
    .await
}

async fn session(key: u32, opts: &str) -> Session {
    let url = format!("{}&{opts}", common::url(key));
    tokio::time::timeout(T, Session::builder(url).name("courier").connect())
        .await
        .expect("connect in time")
        .expect("connect")
}

/// `ros2_nodes()` until `done` says what it answers is complete.
async fn nodes_until(s: &Session, what: &str, done: impl Fn(&[Ros2Node]) -> bool) -> Vec<Ros2Node> {
    tokio::time::timeout(T, async {
        loop {
            let n = s.dds().unwrap().ros2_nodes().await.unwrap();
            if done(&n) {
                return n;
            }
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    })
    .await
    .unwrap_or_else(|_| panic!("{what}: not within {T:?}"))
}

fn find<'a>(nodes: &'a [Ros2Node], full: &str) -> Option<&'a Ros2Node> {
    nodes.iter().find(|n| n.name.to_string() == full)
}

/// Both directions with GIDs of `gid` bytes (16: ROS 2 Iron and later,
/// 24: Humble).
async fn round_trip(key: u32, gid: usize) {
    let s = session(
        key,
        &format!("ros2_node=/courier_ns/graph_node&ros2_gid={gid}"),
    )
    .await;
    let mut events = s.events();
    let out = s
        .publisher::<RosString>("rt/courier_out")
        .build()
        .await
        .unwrap();
    let _in = s.subscribe::<RosString>("rt/courier_in").await.unwrap();
    let gid_arg = gid.to_string();
    let p = peer(
        key,
        &[
            "--node",
            "/py_ns/py_node",
            "--publish",
            "/py_out",
            "--subscribe",
            "/py_in",
            "--gid-size",
            &gid_arg,
        ],
    );
    let (p, r) = ready(p).await;

    // the peer's node, as an event ...
    tokio::time::timeout(T, async {
        while let Some(e) = events.next().await {
            if let SessionEvent::Ros2Nodes { participant, nodes } = e {
                if participant.to_string() == r.participant {
                    let names: Vec<String> = nodes.iter().map(|n| n.to_string()).collect();
                    assert_eq!(names, ["/py_ns/py_node"]);
                    return;
                }
            }
        }
        panic!("events ended");
    })
    .await
    .expect("the peer's node as an event");

    // ... and in the graph, its topics resolved through discovery
    let nodes = nodes_until(&s, "the peer's topics resolved", |n| {
        find(n, "/py_ns/py_node")
            .is_some_and(|n| n.writers.iter().chain(&n.readers).all(|e| e.dds.is_some()))
    })
    .await;
    let py = find(&nodes, "/py_ns/py_node").unwrap();
    assert!(!py.local);
    assert_eq!(py.participant.to_string(), r.participant);
    assert_eq!(py.gid_bytes, gid);
    assert_eq!(py.writers.len(), 1);
    assert_eq!(py.writers[0].guid.to_string(), r.writer);
    assert_eq!(
        py.writers[0].ros_name,
        Some(("/py_out".to_string(), Ros2Kind::Topic))
    );
    assert_eq!(py.readers[0].guid.to_string(), r.reader);
    assert_eq!(
        py.publishes(),
        [("/py_out".to_string(), "std_msgs/msg/String".to_string())]
    );
    assert_eq!(
        py.subscribes(),
        [("/py_in".to_string(), "std_msgs/msg/String".to_string())]
    );

    // Courier's own node, which the peer reads and resolves
    let me = find(&nodes, "/courier_ns/graph_node").expect("the session's own node");
    assert!(me.local);
    assert_eq!(me.publishes()[0].0, "/courier_out");
    assert_eq!(me.subscribes()[0].0, "/courier_in");
    let (w, rd) = (me.writers[0].guid, me.readers[0].guid);
    let p = expect_exact(
        p,
        format!(
            "node /courier_ns graph_node writers rt/courier_out={w} readers rt/courier_in={rd}"
        ),
    )
    .await;

    // dropping the publisher publishes the node again without it
    drop(out);
    let p = expect_exact(
        p,
        format!("node /courier_ns graph_node writers - readers rt/courier_in={rd}"),
    )
    .await;
    assert!(
        p.seen()
            .iter()
            .filter(|l| l.starts_with("graph "))
            .all(|l| l.contains(" known ")),
        "every GID the peer read is a participant discovery knows: {:?}",
        p.seen()
    );
    finish(p).await;

    // the peer's participant leaves: its node goes with it
    nodes_until(&s, "the peer's node gone", |n| {
        find(n, "/py_ns/py_node").is_none()
    })
    .await;
    s.close().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn graph_round_trip_with_an_rmw_cyclonedds_style_peer() {
    round_trip(1, 16).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn graph_round_trip_with_humbles_24_byte_gids() {
    round_trip(2, 24).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn broken_graph_samples_from_peers_are_reported_and_change_nothing() {
    let s = session(3, "ros2_graph=true").await;
    let mut events = s.events();
    let mut peers = Vec::new();
    let mut expected = Vec::new();
    for (kind, why) in [
        ("huge-count", "does not decode"),
        ("long-name", "256"),
        ("foreign", "speaks for participant 424242"),
    ] {
        let p = peer(
            3,
            &[
                "--node",
                &format!("/bad_{}", kind.replace('-', "_")),
                "--malformed",
                kind,
            ],
        );
        let (p, r) = ready(p).await;
        expected.push((r.participant[..24].to_string(), kind, why));
        peers.push(p);
    }
    let mut seen = Vec::new();
    tokio::time::timeout(T, async {
        while seen.len() < expected.len() {
            match events.next().await.expect("events open") {
                SessionEvent::Ros2GraphRefused { writer, reason } => {
                    let prefix = writer.to_string()[..24].to_string();
                    let Some((_, kind, why)) = expected.iter().find(|(p, ..)| *p == prefix) else {
                        panic!("a refusal from an unknown writer {writer}: {reason}");
                    };
                    assert!(reason.contains(why), "{kind}: {reason}");
                    if !seen.contains(kind) {
                        seen.push(*kind);
                    }
                }
                SessionEvent::Ros2Nodes { participant, nodes } => {
                    panic!("a broken sample was taken: {participant} {nodes:?}")
                }
                _ => {}
            }
        }
    })
    .await
    .unwrap_or_else(|_| panic!("refusals seen: {seen:?} of {expected:?}"));
    // the session goes on, knowing no node
    assert!(s.dds().unwrap().ros2_nodes().await.unwrap().is_empty());
    for p in peers {
        finish(p).await;
    }
    s.close().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_session_without_the_graph_says_how_to_get_it() {
    let s = session(4, "multicast=false").await;
    let e = s.dds().unwrap().ros2_nodes().await.unwrap_err().to_string();
    assert!(e.contains("ros2_node=/namespace/name"), "{e}");
    let e = Session::builder(common::url(4))
        .ros2_node("/ok", "2bad")
        .connect()
        .await
        .expect_err("refused")
        .to_string();
    assert!(e.contains("starts with a digit"), "{e}");
    // the builder's argument is named, not the URL, which is fine
    assert!(e.starts_with("bad SessionBuilder::ros2_node: "), "{e}");
    s.close().await;
}
