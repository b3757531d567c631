//! The XRCE agent where only a private network namespace may take it:
//! discovery on port 7400 and the multicast group 239.255.0.2
//! (MicroXRCEAgent's `-d`), found by the SDK's `XrceDiscovery`, and
//! reliable XRCE through 30 % datagram loss.
//! The namespace has only `lo`; iptables there drops anything not
//! addressed to 127.0.0.0/8 or, for discovery, 224.0.0.0/4 on `lo`.
//!
//! Each test re-executes its own binary inside the namespace with
//! `COURIER_NETNS_CHILD` set; the child is the same test function.

use std::net::{Ipv4Addr, SocketAddr, SocketAddrV4};
use std::process::Command;
use std::time::{Duration, Instant};

use courier::rtps_backend::RtpsOptions;
use courier::xrce_backend::{FoundAgent, XrceDiscovery};
use courier_broker::xrce_agent::{Transport, XrceAgent};
use courier_wire::xrce::{DeliveryControl, Event, ObjectKind};

mod xrce_client;
use xrce_client::{msg, oid, reader, runtime, unmsg, writer, XClient, R, T};

const CHILD: &str = "COURIER_NETNS_CHILD";
const DOMAIN: &str = "COURIER_NETNS_DOMAIN";

use courier_tests::netns::{sh, Netns};

/// Builds a namespace with only `lo` and `rules` (each run with `ip netns
/// exec`), runs test `name` of this binary in it and checks that it passed.
fn run_in_netns(tag: &str, name: &str, rules: &[&[&str]]) -> Netns {
    let ns = Netns(format!("courier-xa-{tag}-{}", std::process::id()));
    let domain = courier_tests::domains::lease(10).to_string();
    let setup = || -> Result<(), String> {
        sh(&["ip", "netns", "add", &ns.0])?;
        for r in rules {
            let mut cmd = vec!["ip", "netns", "exec", &ns.0];
            cmd.extend(r.iter());
            sh(&cmd)?;
        }
        Ok(())
    };
    if let Err(e) = setup() {
        panic!("cannot build the network namespace (needs root, iproute2 and iptables): {e}");
    }
    let out = Command::new("ip")
        .args(["netns", "exec", &ns.0])
        .arg(std::env::current_exe().unwrap())
        .args(["--exact", name, "--nocapture"])
        .env(CHILD, "1")
        .env(DOMAIN, &domain)
        .output()
        .unwrap();
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(out.status.success(), "child in {} failed:\n{text}", ns.0);
    assert!(text.contains("1 passed"), "the child ran the test:\n{text}");
    ns
}

const LO_UP: &[&str] = &["ip", "link", "set", "lo", "up"];
/// Nothing leaves for an address outside loopback.
const GUARD: &[&str] = &[
    "iptables",
    "-A",
    "OUTPUT",
    "!",
    "-d",
    "127.0.0.0/8",
    "-j",
    "DROP",
];

fn rtps() -> RtpsOptions {
    xrce_client::rtps(std::env::var(DOMAIN).unwrap().parse().unwrap())
}

/// The agents Courier's discovery (`XrceDiscovery`) finds at `to`
/// alone, multicast requests leaving from 127.0.0.1.
fn discover(rt: &tokio::runtime::Runtime, to: SocketAddrV4) -> Vec<FoundAgent> {
    let d = XrceDiscovery::new()
        .agent(SocketAddr::V4(to))
        .multicast_interface(Ipv4Addr::LOCALHOST)
        .attempts(3)
        .period(Duration::from_millis(300));
    rt.block_on(async { tokio::time::timeout(T, d.all()).await })
        .expect("bounded")
        .expect("discovery runs")
}

#[test]
fn discovery_by_multicast_and_unicast_in_a_network_namespace() {
    if std::env::var_os(CHILD).is_some() {
        let rt = runtime();
        let agent = rt
            .block_on(
                XrceAgent::builder()
                    .transport(Transport::Udp("127.0.0.1:0".parse().unwrap()))
                    .discovery(SocketAddrV4::new(Ipv4Addr::UNSPECIFIED, 7400))
                    .rtps(rtps())
                    .spawn(),
            )
            .unwrap();
        let SocketAddr::V4(udp) = agent.udp_addrs()[0] else {
            unreachable!()
        };
        let unicast = discover(&rt, SocketAddrV4::new(Ipv4Addr::LOCALHOST, 7400));
        let multicast = discover(&rt, SocketAddrV4::new(Ipv4Addr::new(239, 255, 0, 2), 7400));
        for (how, found) in [("unicast", unicast), ("multicast", multicast)] {
            let got: Vec<_> = found
                .iter()
                .map(|f| (f.address, f.version, f.vendor, f.answered_from.port()))
                .collect();
            let want = vec![(SocketAddr::V4(udp), [1, 0], [0x01, 0x0F], 7400)];
            assert_eq!(got, want, "{how}: {found:?}");
        }
        rt.block_on(agent.shutdown());
        return;
    }
    run_in_netns(
        "disc",
        "discovery_by_multicast_and_unicast_in_a_network_namespace",
        &[
            LO_UP,
            &["ip", "link", "set", "lo", "multicast", "on"],
            &[
                "ip",
                "route",
                "add",
                "224.0.0.0/4",
                "dev",
                "lo",
                "src",
                "127.0.0.1",
            ],
            &[
                "iptables",
                "-A",
                "OUTPUT",
                "-o",
                "lo",
                "-d",
                "224.0.0.0/4",
                "-j",
                "ACCEPT",
            ],
            GUARD,
        ],
    );
}

#[test]
fn reliable_xrce_through_30_percent_loss_in_a_network_namespace() {
    const N: u32 = 200;
    if std::env::var_os(CHILD).is_some() {
        let rt = runtime();
        let agent = rt
            .block_on(
                XrceAgent::builder()
                    .transport(Transport::Udp("127.0.0.1:0".parse().unwrap()))
                    .rtps(rtps())
                    .spawn(),
            )
            .unwrap();
        let d = rtps().domain;
        let a = agent.udp_addrs()[0];
        let mut w = XClient::udp(0x3333_0001, a);
        let mut r = XClient::udp(0x3333_0002, a);
        r.create(reader(d, "lossy"));
        let unlimited = Some(DeliveryControl {
            max_samples: u16::MAX,
            ..DeliveryControl::default()
        });
        r.c.read(oid(ObjectKind::DataReader), R, R, unlimited, Instant::now())
            .unwrap();
        w.create(writer(d, "lossy"));
        let mut next = 0u32;
        let end = Instant::now() + Duration::from_secs(120);
        while r.data().len() < N as usize && Instant::now() < end {
            while next < N {
                let body = msg(
                    next,
                    "lossy",
                    &vec![next as u8; 64 + (next as usize % 7) * 100],
                );
                match w
                    .c
                    .write(oid(ObjectKind::DataWriter), R, &body, Instant::now())
                {
                    Ok(_) => next += 1,
                    Err(_) => break,
                }
            }
            w.turn();
            r.turn();
        }
        let got: Vec<u32> = r.data().iter().map(|b| unmsg(b).0).collect();
        assert_eq!(got, (0..N).collect::<Vec<_>>(), "complete and in order");
        for (i, b) in r.data().iter().enumerate() {
            let (_, _, p) = unmsg(b);
            assert_eq!(p, vec![i as u8; 64 + (i % 7) * 100]);
        }
        assert!(w.until(T, |e| e
            .iter()
            .filter(|e| matches!(e, Event::WriteAcked(_)))
            .count()
            == N as usize));
        rt.block_on(agent.shutdown());
        return;
    }
    let ns = run_in_netns(
        "loss",
        "reliable_xrce_through_30_percent_loss_in_a_network_namespace",
        &[
            LO_UP,
            GUARD,
            &[
                "iptables",
                "-A",
                "INPUT",
                "-i",
                "lo",
                "-p",
                "udp",
                "-m",
                "statistic",
                "--mode",
                "random",
                "--probability",
                "0.3",
                "-j",
                "DROP",
            ],
        ],
    );
    let rules = Command::new("ip")
        .args([
            "netns", "exec", &ns.0, "iptables", "-L", "INPUT", "-v", "-x", "-n",
        ])
        .output()
        .unwrap();
    let rules = String::from_utf8_lossy(&rules.stdout);
    let dropped: u64 = rules
        .lines()
        .find(|l| l.contains("DROP"))
        .and_then(|l| l.split_whitespace().next())
        .and_then(|n| n.parse().ok())
        .unwrap_or(0);
    assert!(dropped > 50, "only {dropped} datagrams dropped:\n{rules}");
}
