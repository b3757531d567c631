//! XRCE agent discovery (`uxr_discovery_agents` with a unicast list)
//! against Courier's own agent (courier-broker's `xrce-agent`, embedded),
//! which answers discovery as MicroXRCEAgent's `-d` does: on its
//! discovery port with the locators of its XRCE transports, and on its
//! XRCE port as to a ping. Everything is unicast on 127.0.0.1, every port
//! chosen by the system, every wait bounded. Multicast discovery is
//! tested inside a private network namespace (broker/tests/xrce_agent_netns.rs).

use std::net::{Ipv4Addr, SocketAddr, SocketAddrV4, UdpSocket};
use std::time::Duration;

use courier::rtps_backend::RtpsOptions;
use courier::xrce_backend::{DiscoverError, XrceDiscovery};
use courier::{ConnectError, Session};
use courier_broker::xrce_agent::{Transport, XrceAgent};
use futures::StreamExt;

/// The bound on every wait.
const T: Duration = Duration::from_secs(20);

fn rtps(key: u32) -> RtpsOptions {
    let mut o = RtpsOptions::default();
    o.domain = courier_tests::domains::lease(key);
    o.interface = Some("lo".into());
    o.peers = vec!["127.0.0.1".into()];
    o.multicast = false;
    o
}

/// An agent on UDP 127.0.0.1:0, answering discovery on 127.0.0.1:0 when asked.
async fn agent(key: u32, discovery: bool) -> XrceAgent {
    let mut b = XrceAgent::builder()
        .transport(Transport::Udp("127.0.0.1:0".parse().unwrap()))
        .rtps(rtps(key));
    if discovery {
        b = b.discovery(SocketAddrV4::new(Ipv4Addr::LOCALHOST, 0));
    }
    tokio::time::timeout(T, b.spawn()).await.unwrap().unwrap()
}

/// A port where something listens and never answers.
fn silent() -> (UdpSocket, SocketAddr) {
    let s = UdpSocket::bind("127.0.0.1:0").unwrap();
    let a = s.local_addr().unwrap();
    (s, a)
}

/// A port where nothing listens (datagrams to it draw ICMP port unreachable).
fn closed() -> SocketAddr {
    let s = UdpSocket::bind("127.0.0.1:0").unwrap();
    s.local_addr().unwrap()
}

fn quick() -> XrceDiscovery {
    XrceDiscovery::new()
        .attempts(2)
        .period(Duration::from_millis(300))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn two_agents_out_of_three_addresses() {
    let a = agent(1, true).await;
    let b = agent(2, true).await;
    let (_dead, dead) = silent();
    let (a_disc, b_disc) = (a.discovery_addr().unwrap(), b.discovery_addr().unwrap());
    let found = tokio::time::timeout(T, quick().agent(a_disc).agent(dead).agent(b_disc).all())
        .await
        .unwrap()
        .unwrap();
    let mut got: Vec<_> = found
        .iter()
        .map(|f| {
            (
                f.address,
                f.answered_from,
                f.version,
                f.vendor,
                f.availability,
            )
        })
        .collect();
    got.sort();
    let mut want = vec![
        (a.udp_addrs()[0], a_disc, [1, 0], [0x01, 0x0F], Some(1)),
        (b.udp_addrs()[0], b_disc, [1, 0], [0x01, 0x0F], Some(1)),
    ];
    want.sort();
    assert_eq!(got, want, "each agent once, at its XRCE port");
    a.shutdown().await;
    b.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_agents_xrce_port_answers_as_itself() {
    // no -d: GET_INFO on the XRCE port is answered as a ping, naming no
    // locator; the agent is the address that answered
    let a = agent(3, false).await;
    let found = tokio::time::timeout(T, quick().agent(closed()).agent(a.udp_addrs()[0]).all())
        .await
        .unwrap()
        .unwrap();
    assert_eq!(found.len(), 1, "{found:?}");
    assert_eq!(found[0].address, a.udp_addrs()[0]);
    assert_eq!(found[0].answered_from, a.udp_addrs()[0]);
    a.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_session_on_the_first_agent_discovered() {
    let a = agent(4, true).await;
    let (_dead, dead) = silent();
    let url = format!(
        "xrce+udp://?discover={dead},{}&discover_ms=200&domain={}",
        a.discovery_addr().unwrap(),
        courier_tests::domains::lease(4)
    );
    let s = tokio::time::timeout(T, Session::builder(&url).connect())
        .await
        .unwrap()
        .unwrap();
    let x = s.xrce().unwrap();
    tokio::time::timeout(T, x.ping(T)).await.unwrap().unwrap();
    let mut sub = s.subscribe::<u32>("found").await.unwrap();
    let p = s.publisher::<u32>("found").build().await.unwrap();
    // the agent's DDS reader and writer match in its domain; publish until
    // the first sample comes through
    let got = tokio::time::timeout(T, async {
        let mut tick = tokio::time::interval(Duration::from_millis(100));
        loop {
            tokio::select! {
                _ = tick.tick() => p.publish(&7u32).await.unwrap(),
                s = sub.next() => break s.unwrap().unwrap().value,
            }
        }
    })
    .await
    .unwrap();
    assert_eq!(got, 7);
    s.close().await;
    a.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn nobody_answers() {
    let (_dead, dead) = silent();
    let gone = closed();
    let e = tokio::time::timeout(T, quick().agent(dead).agent(gone).first())
        .await
        .unwrap()
        .unwrap_err();
    match &e {
        DiscoverError::NotFound {
            tried, attempts, ..
        } => {
            assert_eq!(tried, &vec![dead, gone]);
            assert_eq!(*attempts, 2);
        }
        e => panic!("{e}"),
    }
    assert!(e.to_string().contains(&dead.to_string()), "{e}");
    assert!(tokio::time::timeout(T, quick().agent(dead).all())
        .await
        .unwrap()
        .unwrap()
        .is_empty());
    assert!(matches!(
        XrceDiscovery::new().all().await,
        Err(DiscoverError::NoTargets)
    ));
    let url = format!("xrce+udp://?discover={dead}&discover_attempts=1&discover_ms=100");
    let Err(e) = tokio::time::timeout(T, Session::builder(&url).connect())
        .await
        .unwrap()
    else {
        panic!("connected to nobody")
    };
    assert!(matches!(e, ConnectError::Agent { .. }), "{e}");
    assert!(
        e.to_string().contains("no XRCE agent answered discovery"),
        "{e}"
    );
}
