//! ROS 2 services against a peer of the other request/reply style: an
//! rmw_cyclonedds-style server and client (a 16-byte header before each
//! body, no related sample identity) played on Cyclone DDS 11 (the PyPI
//! `cyclonedds` package, `tests/peers/rtps/ros2_service_peer.py`). Courier
//! runs with the default `services=auto`: it must tell the style from the
//! peer (its vendor, and the request's missing identity). The Fast DDS
//! style is what `rtps_interop.rs` checks against Fast DDS 2.9.
//!
//! Loopback only: the peer's built-in unicast configuration on `lo`,
//! Courier `interface=lo&peers=127.0.0.1`.

use courier::{IpcMessage, Session};
use futures::StreamExt;

mod common;
use common::T;

use courier_tests::peers::{cyclone11_python, sources_dir, PeerProcess};

/// `example_interfaces/srv/AddTwoInts` as ROS 2 names it in DDS, in the
/// test's namespace.
#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "courier::test::AddTwoInts_Request_")]
struct AddReq {
    a: i64,
    b: i64,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "courier::test::AddTwoInts_Response_")]
struct AddResp {
    sum: i64,
}

fn peer(domain: u32, args: &[&str]) -> PeerProcess {
    let python = cyclone11_python().unwrap_or_else(|e| panic!("the Cyclone 11 peer: {e}"));
    let mut a = vec![
        sources_dir().join("ros2_service_peer.py").into_os_string(),
        "--domain".into(),
        courier_tests::domains::lease(domain).to_string().into(),
    ];
    a.extend(args.iter().map(|s| s.into()));
    PeerProcess::spawn(python, &a).unwrap_or_else(|e| panic!("cannot start the peer: {e}"))
}

async fn blocking<R: Send + 'static>(f: impl FnOnce() -> R + Send + 'static) -> R {
    tokio::task::spawn_blocking(f).await.expect("blocking task")
}

fn expect(p: &mut PeerProcess, prefix: &str) -> String {
    p.expect_line(prefix, T).unwrap_or_else(|e| panic!("{e}"))
}

async fn session(key: u32) -> Session {
    common::session(key, "courier").await
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_courier_query_is_answered_by_an_rmw_cyclonedds_style_service() {
    let s = session(1).await;
    let mut p = peer(1, &["--service", "add", "--server", "--count", "3"]);
    let p_ready = blocking(move || {
        expect(&mut p, "ready");
        p
    })
    .await;
    let mut p = p_ready;
    for n in 1..=3i64 {
        let r: AddResp = s
            .query("add", &AddReq { a: 10 * n, b: n })
            .timeout(T)
            .await
            .unwrap_or_else(|e| panic!("query {n}: {e}"));
        assert_eq!(r.sum, 11 * n);
    }
    let lines = blocking(move || {
        let l = p.lines_until("done", T).unwrap_or_else(|e| panic!("{e}"));
        p.wait_success(T).unwrap_or_else(|e| panic!("{e}"));
        l
    })
    .await;
    let requests: Vec<&String> = lines.iter().filter(|l| l.starts_with("request ")).collect();
    // the header's request numbers count from 1, the body is whole
    assert_eq!(
        requests,
        ["request 1 10 1", "request 2 20 2", "request 3 30 3"]
    );
    s.close().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_courier_service_answers_an_rmw_cyclonedds_style_client() {
    let s = session(2).await;
    let mut reqs = s.serve::<AddReq, AddResp>("add", "").await.unwrap();
    // answers until the test ends (the peer asks again when an answer is
    // late, so the number of requests is not fixed)
    let server = tokio::spawn(async move {
        while let Some(r) = reqs.next().await {
            let r = r.expect("the body decodes (the header was taken off)");
            let sum = r.value.a + r.value.b;
            r.reply(&AddResp { sum }).await.unwrap();
        }
    });
    let mut p = peer(2, &["--service", "add", "--client", "--count", "3"]);
    let lines = blocking(move || {
        let l = p.lines_until("done", T).unwrap_or_else(|e| panic!("{e}"));
        p.wait_success(T).unwrap_or_else(|e| panic!("{e}"));
        l
    })
    .await;
    let replies: Vec<&String> = lines.iter().filter(|l| l.starts_with("reply ")).collect();
    // each reply echoed the client's id and request number
    assert_eq!(replies, ["reply 1 11", "reply 2 22", "reply 3 33"]);
    assert!(!lines.iter().any(|l| l.starts_with("foreign")), "{lines:?}");
    assert!(!server.is_finished(), "the service ran to the end");
    server.abort();
    s.close().await;
}
