//! Reliable RTPS delivery through a real lossy network: two Courier
//! participants in a network namespace that has only `lo`, where iptables
//! drops 30 % of all UDP datagrams at random (DATA, DATA_FRAG, HEARTBEAT,
//! ACKNACK, NACK_FRAG and discovery alike). Every sample must arrive,
//! complete and in order. (The kernel here has no `netem`, so reordering is
//! covered by the simulated-network tests in `wire/tests/rtps_participant.rs`.)
//!
//! The test re-executes its own binary inside the namespace with
//! `COURIER_NETNS_CHILD` set; the child is the same test function.

use std::process::Command;
use std::time::Duration;

use courier::Session;
use futures::StreamExt;

mod common;
use common::Msg;

const CHILD: &str = "COURIER_NETNS_CHILD";
const N: u32 = 400;

fn sh(args: &[&str]) -> Result<(), String> {
    let out = Command::new(args[0])
        .args(&args[1..])
        .output()
        .map_err(|e| format!("cannot run {}: {e}", args[0]))?;
    if out.status.success() {
        Ok(())
    } else {
        Err(format!(
            "{} failed: {}",
            args.join(" "),
            String::from_utf8_lossy(&out.stderr).trim()
        ))
    }
}

/// Removes the namespace however the test ends.
struct Netns(String);

impl Drop for Netns {
    fn drop(&mut self) {
        let _ = sh(&["ip", "netns", "del", &self.0]);
    }
}

fn payload(seq: u32) -> Vec<u8> {
    // every 50th sample is fragmented (100 KiB in 1344-byte fragments)
    let n = if seq % 50 == 0 { 100 * 1024 } else { 64 };
    (0..n).map(|i| (i as u32 ^ seq) as u8).collect()
}

async fn child() {
    let url = "rtps://60?interface=lo&peers=127.0.0.1&lease_ms=30000";
    let a = Session::builder(url).name("a").connect().await.unwrap();
    let b = Session::builder(url).name("b").connect().await.unwrap();
    let p = a.publisher::<Msg>("lossy").build().await.unwrap();
    let mut sub = b.subscribe::<Msg>("lossy").await.unwrap();
    tokio::time::timeout(Duration::from_secs(60), async {
        while a.num_handlers("lossy").await.unwrap() < 1 {
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    })
    .await
    .expect("discovery through 30 % loss");
    let writer = tokio::spawn(async move {
        for seq in 0..N {
            p.publish(&Msg {
                seq,
                text: format!("m{seq}"),
                payload: payload(seq),
            })
            .await
            .unwrap();
        }
        p.publish(&Msg {
            seq: N,
            text: "last".into(),
            payload: Vec::new(),
        })
        .confirmed()
        .timeout(Duration::from_secs(120))
        .await
        .unwrap();
    });
    for seq in 0..N {
        let s = tokio::time::timeout(Duration::from_secs(60), sub.next())
            .await
            .unwrap_or_else(|_| panic!("sample {seq} never came"))
            .expect("open")
            .expect("decodes");
        assert_eq!(s.value.seq, seq, "in order");
        assert_eq!(s.value.payload, payload(seq), "sample {seq} intact");
    }
    writer.await.unwrap();
    assert_eq!(sub.dropped(), 0);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn reliable_delivery_through_30_percent_loss_in_a_network_namespace() {
    if std::env::var_os(CHILD).is_some() {
        return child().await;
    }
    let ns = Netns(format!("courier-loss-{}", std::process::id()));
    let setup = || -> Result<(), String> {
        sh(&["ip", "netns", "add", &ns.0])?;
        sh(&[
            "ip", "netns", "exec", &ns.0, "ip", "link", "set", "lo", "up",
        ])?;
        sh(&[
            "ip",
            "netns",
            "exec",
            &ns.0,
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
        ])
    };
    if let Err(e) = setup() {
        panic!(
            "cannot build the lossy network namespace (needs root, iproute2 and iptables; \
             .ci/run installs iptables): {e}"
        );
    }
    let exe = std::env::current_exe().unwrap();
    let out = tokio::task::spawn_blocking({
        let ns = ns.0.clone();
        move || {
            Command::new("ip")
                .args(["netns", "exec", &ns])
                .arg(exe)
                .args([
                    "--exact",
                    "reliable_delivery_through_30_percent_loss_in_a_network_namespace",
                    "--nocapture",
                ])
                .env(CHILD, "1")
                .output()
                .unwrap()
        }
    })
    .await
    .unwrap();
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(out.status.success(), "child under loss failed:\n{text}");
    assert!(text.contains("1 passed"), "the child ran the test:\n{text}");
    // and the loss was real: the DROP rule's packet counter
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
        .unwrap_or_else(|| panic!("no DROP counter in:\n{rules}"));
    eprintln!("datagrams dropped by the namespace: {dropped}");
    assert!(dropped > 100, "only {dropped} datagrams dropped:\n{rules}");
}
