//! Runs every example briefly, with the arguments a user would type, against
//! an embedded central on a free port, DDS participants pinned to `lo` in a
//! domain leased machine-wide, and an embedded XRCE agent on a free port.
//! Each example's file is compiled into this test as a module and its `run`
//! called with parsed arguments; every wait is bounded.

#![allow(dead_code)] // each example's `main`, unused here

#[path = "../bridge.rs"]
mod bridge;
#[path = "../demo/main.rs"]
mod demo;
#[path = "../module1.rs"]
mod module1;
#[path = "../module2.rs"]
mod module2;
#[path = "../module3.rs"]
mod module3;
#[path = "../pub.rs"]
mod publish;
#[path = "../query.rs"]
mod query;
#[path = "../rtps_pub.rs"]
mod rtps_pub;
#[path = "../rtps_sub.rs"]
mod rtps_sub;
#[path = "../serve.rs"]
mod serve;
#[path = "../sub.rs"]
mod sub;
#[path = "../xrce_check.rs"]
mod xrce_check;

use std::future::Future;
use std::time::Duration;

use clap::Parser;
use courier::rtps_backend::RtpsOptions;
use courier::Session;
use courier_broker::xrce_agent::{Transport, XrceAgent};
use courier_broker::{CentralHandle, CentralServer, LogSink};
use courier_examples::Error;
use futures::StreamExt;

/// The bound on every example and every wait.
const T: Duration = Duration::from_secs(30);

/// A central on a free port of 127.0.0.1, and its URL.
async fn central() -> (CentralHandle, String) {
    let c = CentralServer::builder()
        .bind([127, 0, 0, 1].into())
        .port(0)
        .log_sink(LogSink::discard())
        .spawn()
        .await
        .expect("central starts");
    let url = format!("ipc://{}", c.local_addr());
    (c, url)
}

/// An `rtps://` URL for the leased domain `key`, pinned to lo.
fn rtps_url(key: u32) -> String {
    let d = courier_tests::domains::lease(key);
    format!("rtps://{d}?interface=lo&peers=127.0.0.1&multicast=false")
}

/// An XRCE agent on a free UDP port whose DDS side is pinned to lo in the
/// leased domain `key`, and the `xrce+udp://` URL of a client of it.
async fn agent(key: u32) -> (XrceAgent, String) {
    let d = courier_tests::domains::lease(key);
    let mut rtps = RtpsOptions::default();
    rtps.domain = d;
    rtps.interface = Some("127.0.0.1".into());
    rtps.peers = vec!["127.0.0.1".into()];
    rtps.multicast = false;
    let a = XrceAgent::builder()
        .transport(Transport::Udp("127.0.0.1:0".parse().unwrap()))
        .rtps(rtps)
        .spawn()
        .await
        .expect("agent starts");
    let url = format!("xrce+udp://{}?domain={d}", a.udp_addrs()[0]);
    (a, url)
}

/// Parses `args` as the example's command line would.
fn args<A: Parser>(args: &[&str]) -> A {
    A::try_parse_from(args).unwrap_or_else(|e| panic!("{args:?}: {e}"))
}

/// Awaits an example within the bound; its error fails the test.
async fn bounded(what: &str, f: impl Future<Output = Result<(), Error>>) {
    match tokio::time::timeout(T, f).await {
        Ok(Ok(())) => {}
        Ok(Err(e)) => panic!("{what}: {e}"),
        Err(_) => panic!("{what} did not finish within {T:?}"),
    }
}

/// `sub --count 2` ends once two messages of `pub` (which goes on
/// publishing every 50 ms, through discovery and subscription) arrived.
async fn pub_sub(url: &str) {
    let sub = sub::run(args(&["sub", "-e", url, "-k", "chatter", "--count", "2"]));
    let publish = publish::run(args(&[
        "pub", "-e", url, "-k", "chatter", "-p", "hi", "--count", "1000", "--period", "0.05",
    ]));
    tokio::select! {
        r = tokio::time::timeout(T, sub) => match r {
            Ok(r) => r.expect("sub"),
            Err(_) => panic!("sub got no 2 messages within {T:?} on {url}"),
        },
        r = publish => panic!("pub ended before sub had 2 messages: {r:?}"),
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_demo_runs_to_the_end() {
    let d = courier_tests::domains::lease(1).to_string();
    bounded(
        "demo",
        demo::run(args(&["demo", "--domain", &d, "--bytes"])),
    )
    .await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_demo_step_that_does_not_happen_fails_with_a_message() {
    // a timeout too short for any step: the first one reports it
    let d = courier_tests::domains::lease(2).to_string();
    let r = demo::run(args(&["demo", "--domain", &d, "--timeout", "0.000001"])).await;
    let e = r
        .expect_err("the demo cannot finish in a microsecond a step")
        .to_string();
    assert!(e.contains("did not happen within"), "{e}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn pub_and_sub_over_ipc() {
    let (c, url) = central().await;
    pub_sub(&url).await;
    c.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn pub_and_sub_over_rtps() {
    pub_sub(&rtps_url(3)).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn pub_and_sub_through_an_xrce_agent() {
    let (a, url) = agent(4).await;
    pub_sub(&url).await;
    a.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn query_and_serve_over_ipc() {
    let (c, url) = central().await;
    let serve = tokio::spawn(serve::run(args(&[
        "serve", "-e", &url, "-k", "greet", "-p", "hello", "--count", "1",
    ])));
    // central holds the query until serve's handler is there
    bounded(
        "query",
        query::run(args(&[
            "query",
            "-e",
            &url,
            "-k",
            "greet",
            "--timeout",
            "20",
        ])),
    )
    .await;
    let r = tokio::time::timeout(T, serve)
        .await
        .expect("serve ends after one answer");
    r.expect("serve task").expect("serve");
    c.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn query_without_central_says_what_to_start() {
    // a port nothing listens on: bind one, then free it
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let url = format!("ipc://127.0.0.1:{port}");
    let r = query::run(args(&["query", "-e", &url, "--connect-timeout", "2"])).await;
    let e = r.expect_err("no central").to_string();
    assert!(
        e.contains(&url) && e.contains("is a central running?"),
        "{e}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_wrong_url_is_not_blamed_on_a_missing_server() {
    // the URL is wrong: starting a central would not help, so no such hint
    let url = "ipc://127.0.0.1:99999";
    let r = query::run(args(&["query", "-e", url, "--connect-timeout", "2"])).await;
    let e = r.expect_err("bad port").to_string();
    assert!(
        e.contains("'99999' is not a port number") && !e.contains("running?"),
        "{e}"
    );
    // a serial device that is not there: the hint is about the device, not UDP
    let url = "xrce+serial:///dev/courier-no-such-tty";
    let r = query::run(args(&["query", "-e", url, "--connect-timeout", "2"])).await;
    let e = r.expect_err("no device").to_string();
    assert!(
        e.contains("does the device exist") && !e.contains("udp4"),
        "{e}"
    );
}

#[test]
fn bad_arguments_are_usage_errors() {
    let e = publish::Args::try_parse_from(["pub", "--period", "0"]).unwrap_err();
    assert_eq!(e.exit_code(), 2);
    assert!(
        e.to_string().contains("not a positive number of seconds"),
        "{e}"
    );
    let e = bridge::Args::try_parse_from(["bridge", "ipc://a", "ipc://b", "message1"]).unwrap_err();
    assert!(e.to_string().contains("is not name:format"), "{e}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn rtps_pub_and_rtps_sub() {
    let d = courier_tests::domains::lease(5).to_string();
    let sub = rtps_sub::run(args(&["rtps_sub", "--domain", &d, "--count", "2"]));
    let publish = rtps_pub::run(args(&[
        "rtps_pub",
        "--domain",
        &d,
        "--count",
        "1000",
        "--period",
        "0.05",
        "--user-id",
        "7",
    ]));
    tokio::select! {
        r = tokio::time::timeout(T, sub) => r.expect("rtps_sub got 2 samples in time").expect("rtps_sub"),
        r = publish => panic!("rtps_pub ended first: {r:?}"),
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn appendix_a_modules_talk_through_central() {
    let (c, url) = central().await;
    // module3 listens, module2 serves; a probe waits until both are there
    let m2 = tokio::spawn(module2::run(args(&[
        "module2",
        "-e",
        &url,
        "--seconds",
        "60",
    ])));
    let m3 = tokio::spawn(module3::run(args(&[
        "module3",
        "-e",
        &url,
        "--seconds",
        "60",
    ])));
    let probe = Session::builder(&url)
        .name("probe")
        .connect()
        .await
        .unwrap();
    tokio::time::timeout(T, async {
        // module2 serves query1 once subscribed to message1; module3
        // subscribes to message2 after message1
        while !(probe.num_handlers("query1").await.unwrap() == 1
            && probe.num_handlers("message2").await.unwrap() == 1)
        {
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    })
    .await
    .expect("module2 and module3 subscribed in time");
    // module1 fails if its query gets no response1
    bounded(
        "module1",
        module1::run(args(&["module1", "-e", &url, "m", "r", "m", "q"])),
    )
    .await;
    probe.close().await;
    m2.abort();
    m3.abort();
    c.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn xrce_check_passes_against_courier_s_agent() {
    let (a, url) = agent(6).await;
    bounded("xrce_check pubsub", xrce_check::pubsub(&url, true)).await;
    bounded("xrce_check rpc", xrce_check::rpc(&url, true)).await;
    a.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bridge_carries_messages_from_one_central_to_the_other() {
    let ((a, ua), (b, ub)) = (central().await, central().await);
    let listener = Session::builder(&ub)
        .name("listener")
        .connect()
        .await
        .unwrap();
    let mut sub = listener.subscribe::<i32>("message1").await.unwrap();
    listener.num_handlers("message1").await.unwrap();
    let bridge = tokio::spawn(bridge::run(args(&["bridge", &ua, &ub, "message1:int"])));
    let publisher = Session::builder(&ua)
        .name("publisher")
        .connect()
        .await
        .unwrap();
    // Publish until the bridge's subscription is known on central A and
    // the listener's on central B reaches the bridge.
    let deadline = tokio::time::Instant::now() + T;
    let v = loop {
        publisher.publish("message1", &42i32).await.unwrap();
        if let Ok(Some(s)) = tokio::time::timeout(Duration::from_millis(200), sub.next()).await {
            break s.unwrap().value;
        }
        assert!(
            tokio::time::Instant::now() < deadline,
            "nothing crossed the bridge"
        );
    };
    assert_eq!(v, 42);
    publisher.close().await;
    a.shutdown().await;
    // the first central gone, the bridge ends
    let r = tokio::time::timeout(T, bridge)
        .await
        .expect("bridge ends with central A");
    r.expect("bridge task").expect("bridge");
    listener.close().await;
    b.shutdown().await;
}
