//! One keyed topic written in both XCDR versions by real peers: Cyclone
//! DDS 0.10 (C, `tests/peers/rtps/cyclone_peer.c`, XCDR1, sending
//! `PID_KEY_HASH` with `--keyhash`) and Cyclone DDS 11 (the PyPI
//! `cyclonedds` package, `tests/peers/rtps/cyclone11_peer.py --type stamped`,
//! XCDR2, sending no key hash) both write instance 1 of
//! `courier::test::Stamped` (`@key long id; @key long long stamp;`), whose
//! XCDR1 key hash (`id`, 4 bytes of padding, `stamp`) differs from its
//! XCDR2 one (`id`, `stamp`). Courier's subscriber must see one instance:
//! with a minimum separation of an hour, the second writer's sample of it
//! is filtered out as a second sample of the same instance, and the
//! second writer's dispose disposes it — reported with the key, and with
//! the hash in that writer's version.
//!
//! Loopback only: the peers run their built-in loopback-only unicast
//! configurations, Courier `interface=lo&peers=127.0.0.1`; domains leased
//! machine-wide (`courier_tests::domains`). A missing peer fails the test
//! with what is missing.

use std::time::Duration;

use courier::cdr::Version;
use courier::{InstanceState, Received, Session};

mod common;
use common::{next, Stamped, T};

use courier_tests::peers::{
    cyclone11_peer_args, cyclone11_python, cyclone_peer, stamp, PeerProcess,
};

#[derive(Clone, Copy, Debug)]
enum Vendor {
    /// Cyclone DDS 0.10: XCDR1, with key hashes (`--keyhash`).
    Cyclone,
    /// Cyclone DDS 11: XCDR2 (`--representation xcdr2`), no key hashes.
    Cyclone11,
}

/// A running peer, killed and reaped when dropped.
struct Peer(PeerProcess);

impl Peer {
    fn start(vendor: Vendor, args: &[&str]) -> Peer {
        let p = match vendor {
            Vendor::Cyclone => cyclone_peer().and_then(|exe| PeerProcess::spawn(exe, args)),
            Vendor::Cyclone11 => {
                cyclone11_python().and_then(|py| PeerProcess::spawn(py, &cyclone11_peer_args(args)))
            }
        };
        Peer(p.unwrap_or_else(|e| panic!("cannot start the {vendor:?} interop peer: {e}")))
    }

    fn expect(&mut self, prefix: &str) -> String {
        self.0
            .expect_line(prefix, T)
            .unwrap_or_else(|e| panic!("{e}"))
    }
}

async fn blocking<R: Send + 'static>(f: impl FnOnce() -> R + Send + 'static) -> R {
    tokio::task::spawn_blocking(f).await.expect("blocking task")
}

/// Instance 1 of `Stamped`, sample `seq` written by `who`.
fn value(seq: u32, who: &str) -> Stamped {
    Stamped {
        id: 1,
        stamp: stamp(1),
        seq,
        text: format!("{who}-{seq}"),
    }
}

/// A peer writing instance 1 once, and disposing it after if `dispose`;
/// it stays (the first writer stays to the end of the test: gone, it would
/// take the instance with it).
fn writer(vendor: Vendor, domain: &str, dispose: bool) -> Peer {
    let mut args = vec![
        "--domain",
        domain,
        "--topic",
        "mixed",
        "--type",
        "stamped",
        "--pub",
        "--reliable",
        "--count",
        "1",
        "--wait-match",
        "1",
        "--settle-ms",
        "300",
        "--linger-ms",
        "30000",
        "--timeout-s",
        "60",
    ];
    match vendor {
        // sample 1 is instance 1 % 2
        Vendor::Cyclone => args.extend(["--keyhash", "--keys", "2", "--text", "c10"]),
        Vendor::Cyclone11 => {
            args.extend(["--representation", "xcdr2", "--keys", "1", "--text", "c11"])
        }
    }
    match (dispose, vendor) {
        (false, _) => {}
        (true, Vendor::Cyclone) => args.extend(["--dispose-every", "1"]),
        (true, Vendor::Cyclone11) => args.push("--dispose"),
    }
    Peer::start(vendor, &args)
}

/// `first` writes instance 1; then `second` writes it and disposes it.
/// Courier takes the first sample, filters the second out (the same
/// instance, within the minimum separation) and reports the dispose; it
/// took the second sample as another instance's when it named instances
/// by the hashes as sent.
async fn one_instance_for_both_versions(domain: u32, first: Vendor, second: Vendor) {
    let s: Session = common::session(domain, "courier").await;
    let mut sub = s
        .subscriber::<Stamped>("mixed")
        .with_instances()
        .minimum_separation(Duration::from_secs(3600))
        .build()
        .await
        .unwrap();
    let d = courier_tests::domains::lease(domain).to_string();
    let name = |v| match v {
        Vendor::Cyclone => "c10",
        Vendor::Cyclone11 => "c11",
    };
    let first_peer = writer(first, &d, false);
    match next(&mut sub).await {
        Ok(Received::Sample(smp)) => assert_eq!(smp.value, value(1, name(first))),
        other => panic!("expected {first:?}'s sample, got {other:?}"),
    }
    let mut second_peer = writer(second, &d, true);
    match next(&mut sub).await {
        Ok(Received::Instance(c)) => {
            let version = match second {
                Vendor::Cyclone => Version::Xcdr1,
                Vendor::Cyclone11 => Version::Xcdr2,
            };
            assert_eq!(c.state, InstanceState::Disposed, "{c:?}");
            assert_eq!(c.key, Some((1, stamp(1))), "{c:?}");
            assert_eq!(c.key_hash_version, Some(version), "{c:?}");
            let hash = courier::key_hash_in(&value(0, ""), version);
            assert_eq!(c.key_hash, Some(hash), "{second:?}'s hash: {c:?}");
        }
        other => panic!(
            "expected {second:?}'s dispose of the instance {first:?} wrote (its sample \
             filtered as the same instance's), got {other:?}"
        ),
    }
    // both peers are killed when dropped
    let second_peer = blocking(move || {
        second_peer.expect("acked");
        second_peer
    })
    .await;
    drop((first_peer, second_peer));
    s.close().await;
}

/// Cyclone 11 (XCDR2, no key hash) writes first; Cyclone 0.10's XCDR1
/// sample is the same instance, and its dispose (serialized key and XCDR1
/// hash) disposes it.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn cyclone11_writes_cyclone010_disposes_one_instance() {
    one_instance_for_both_versions(1, Vendor::Cyclone11, Vendor::Cyclone).await;
}

/// Cyclone 0.10 (XCDR1, key hash) writes first; Cyclone 11's XCDR2
/// sample is the same instance, and its dispose (serialized key, no hash)
/// disposes it.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn cyclone010_writes_cyclone11_disposes_one_instance() {
    one_instance_for_both_versions(2, Vendor::Cyclone, Vendor::Cyclone11).await;
}
