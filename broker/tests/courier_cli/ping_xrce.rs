//! `courier ping` over `xrce+udp://`, through Courier's XRCE agent
//! embedded in the test (UDP 127.0.0.1 port 0; its DDS participant on
//! `lo`, unicast, in a leased domain): publisher to subscriber, and round
//! trips through `courier pong`. An agent tells its clients nothing of
//! matched readers, so neither side prints `matched`.

use courier::rtps_backend::RtpsOptions;
use courier_broker::xrce_agent::{Transport, XrceAgent};

use crate::Proc;

/// The agent, its runtime, and the session URL of its clients.
fn agent(key: u32) -> (tokio::runtime::Runtime, XrceAgent, String) {
    let domain = courier_tests::domains::lease(key);
    let mut o = RtpsOptions::default();
    o.domain = domain;
    o.interface = Some("lo".into());
    o.peers = vec!["127.0.0.1".into()];
    o.multicast = false;
    let rt = tokio::runtime::Runtime::new().unwrap();
    let a = rt
        .block_on(
            XrceAgent::builder()
                .transport(Transport::Udp("127.0.0.1:0".parse().unwrap()))
                .rtps(o)
                .spawn(),
        )
        .unwrap();
    let url = format!("xrce+udp://{}?domain={domain}", a.udp_addrs()[0]);
    (rt, a, url)
}

#[test]
fn ping_publisher_to_subscriber_over_xrce() {
    let (rt, a, u) = agent(260);
    let mut sub = Proc::start(&["ping", &u, "--subscribe", "--count", "3", "--name", "rx"]);
    sub.expect("ready");
    let mut publ = Proc::start(&["ping", &u, "--publish", "--period", "50", "--name", "tx"]);
    publ.expect("ready");
    for _ in 0..3 {
        sub.expect("received ");
    }
    sub.expect("done");
    assert_eq!(sub.wait(), Some(0));
    drop(publ);
    rt.block_on(a.shutdown());
}

#[test]
fn ping_rtt_through_pong_over_xrce() {
    let (rt, a, u) = agent(261);
    let mut pong = Proc::start(&["pong", &u]);
    pong.expect("ready");
    let mut ping = Proc::start(&["ping", &u, "--rtt", "--count", "20", "--size", "64"]);
    ping.expect("ready");
    let total = ping.expect("total ");
    assert!(total.starts_with("total n=20 "), "{total}");
    assert!(total.contains(" lost=0 "), "{total}");
    ping.expect("done");
    assert_eq!(ping.wait(), Some(0));
    assert!(
        !ping.seen.iter().any(|l| l.starts_with("matched")),
        "an XRCE session knows no matches: {:?}",
        ping.seen
    );
    drop(pong);
    rt.block_on(a.shutdown());
}
