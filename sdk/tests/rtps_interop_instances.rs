//! Instance states against a real peer: a Cyclone DDS 11 writer (the PyPI
//! `cyclonedds` package, `tests/peers/rtps/cyclone11_peer.py`) writes two
//! instances of `courier::test::Keyed` and is deleted while its
//! participant stays. Cyclone sends no unregister or dispose per instance
//! when a writer goes — only its SEDP dispose says it left — and its own
//! readers take each instance that writer was the last writer of as
//! NOT_ALIVE_NO_WRITERS (DDS 1.4 §2.2.2.5.1) with `autodispose` false, as
//! disposed with `autodispose` true (the default, which Cyclone announces
//! in `PID_ADLINK_WRITER_DATA_LIFECYCLE` or by leaving it out). Courier's
//! subscriber must see the same: an `Unregistered` or `Disposed` change of
//! each instance, with its key.
//!
//! Loopback only: the peer runs its loopback-only unicast configuration,
//! Courier `interface=lo&peers=127.0.0.1`; domains leased machine-wide
//! (`courier_tests::domains`). A missing peer fails the test with what is
//! missing.

use std::collections::BTreeSet;

use courier::{InstanceState, Received, Session};

mod common;
use common::{next, Keyed, T};

use courier_tests::peers::{cyclone11_peer_args, cyclone11_python, PeerProcess};

async fn blocking<R: Send + 'static>(f: impl FnOnce() -> R + Send + 'static) -> R {
    tokio::task::spawn_blocking(f).await.expect("blocking task")
}

/// A Cyclone 11 writer that goes without autodispose: both instances are
/// NOT_ALIVE_NO_WRITERS. Before, Courier's reader forgot them without a
/// word.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_cyclone_writer_that_closes_leaves_its_instances_without_writers() {
    a_cyclone_writer_closes(1, false, InstanceState::Unregistered).await;
}

/// With autodispose (Cyclone's default), its instances are disposed, as
/// Cyclone's own readers take them.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_cyclone_writer_with_autodispose_that_closes_disposes_its_instances() {
    a_cyclone_writer_closes(2, true, InstanceState::Disposed).await;
}

async fn a_cyclone_writer_closes(key: u32, autodispose: bool, want: InstanceState) {
    let s: Session = common::session(key, "courier").await;
    let mut sub = s
        .subscriber::<Keyed>("closing")
        .with_instances()
        .build()
        .await
        .unwrap();
    let d = courier_tests::domains::lease(key).to_string();
    let mut args = vec![
        "--domain",
        &d,
        "--topic",
        "closing",
        "--type",
        "keyed",
        "--pub",
        "--reliable",
        "--count",
        "2",
        "--keys",
        "1,2",
        "--close-writer",
        "--wait-match",
        "1",
        "--settle-ms",
        "300",
        "--text",
        "k",
        "--linger-ms",
        "20000",
        "--timeout-s",
        "60",
    ];
    if !autodispose {
        args.push("--no-autodispose");
    }
    let mut peer = cyclone11_python()
        .and_then(|py| PeerProcess::spawn(py, &cyclone11_peer_args(&args)))
        .unwrap_or_else(|e| panic!("cannot start the Cyclone 11 interop peer: {e}"));
    for seq in 1..=2u32 {
        match next(&mut sub).await {
            Ok(Received::Sample(smp)) => assert_eq!(
                (smp.value.id, smp.value.seq, smp.value.text.as_str()),
                (seq as i32, seq, &*format!("k-{seq}"))
            ),
            other => panic!("expected sample {seq}, got {other:?}"),
        }
    }
    let mut gone = BTreeSet::new();
    while gone.len() < 2 {
        match next(&mut sub).await {
            Ok(Received::Instance(c)) => {
                assert_eq!(c.state, want, "{c:?}");
                let key = c.key.unwrap_or_else(|| panic!("no key: {c:?}"));
                assert!(gone.insert(key), "instance {key} twice: {c:?}");
            }
            other => panic!("expected the instances without writers, got {other:?}"),
        }
    }
    assert_eq!(gone, BTreeSet::from([1, 2]));
    // the peer is killed when dropped
    let peer = blocking(move || {
        peer.expect_line("closed", T)
            .unwrap_or_else(|e| panic!("{e}"));
        peer
    })
    .await;
    drop(peer);
    s.close().await;
}
