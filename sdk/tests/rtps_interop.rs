//! Courier's RTPS backend against the real thing: Cyclone DDS 0.10 and
//! Fast DDS 2.9 (the Debian packages), through the peer programs in
//! `tests/peers/rtps/`, built and run by `courier_tests::peers`. Both directions, best effort and reliable, a 200 KiB sample,
//! a keyed topic with dispose, transient-local late joiners, discovery and
//! loss of a peer, reliable samples written before the peer matched us.
//!
//! Loopback only: the peers embed a loopback-only unicast configuration
//! (interface `lo`, no multicast, SPDP to 127.0.0.1) and Courier's sessions
//! use `interface=lo&peers=127.0.0.1`. Each test has its own domain id, leased machine-wide (`courier_tests::domains`).
//! Missing tools or libraries fail the tests (`.ci/run` installs them).

use std::time::Duration;

use courier::{InstanceState, Received, Session, SessionEvent};
use futures::StreamExt;

mod common;
use common::{next, Keyed, Msg, Stamped, T};

use courier_tests::peers::{cyclone_peer, fastdds_peer, fnv1a32, payload, stamp, PeerProcess};

#[derive(Clone, Copy, Debug)]
enum Vendor {
    Cyclone,
    FastDds,
}

/// A running peer (`courier_tests::peers`), killed and reaped when dropped;
/// every wait is bounded by `T` and a miss panics with what the peer said.
struct Peer(PeerProcess);

impl Peer {
    fn start(vendor: Vendor, args: &[&str]) -> Peer {
        let exe = match vendor {
            Vendor::Cyclone => cyclone_peer(),
            Vendor::FastDds => fastdds_peer(),
        }
        .unwrap_or_else(|e| panic!("cannot build the {vendor:?} interop peer: {e}"));
        Peer(PeerProcess::spawn(exe, args).unwrap_or_else(|e| panic!("{e}")))
    }

    /// The next line starting with `prefix` (blocking: call from
    /// `blocking`).
    fn expect(&mut self, prefix: &str) -> String {
        self.0
            .expect_line(prefix, T)
            .unwrap_or_else(|e| panic!("{e}"))
    }

    fn exit_code(&mut self) -> Option<i32> {
        self.0.wait(T).unwrap_or_else(|e| panic!("{e}")).code()
    }
}

async fn blocking<R: Send + 'static>(f: impl FnOnce() -> R + Send + 'static) -> R {
    tokio::task::spawn_blocking(f).await.expect("blocking task")
}

/// What the peer printed until `done`, but for its `matched` lines.
async fn peer_lines(mut peer: Peer) -> Vec<String> {
    blocking(move || {
        let mut v = Vec::new();
        loop {
            let l = peer.expect("");
            if l == "done" {
                return v;
            }
            if !l.starts_with("matched") {
                v.push(l);
            }
        }
    })
    .await
}

async fn session(domain: u32) -> Session {
    common::session(domain, "courier").await
}

async fn await_handlers(s: &Session, topic: &str) {
    common::await_handlers(s, topic, 1).await
}

/// The peer's `--domain`: the domain leased to key `d`, as the sessions
/// of `common::session(d, ..)` use.
fn domain_arg(d: u32) -> String {
    courier_tests::domains::lease(d).to_string()
}

// ---------------------------------------------------------------------------
// Peer publishes, Courier subscribes

/// The peer publishes 3 samples on `interop` once a reader matched:
/// `peer-1..3`, 16 B each, or 16 B, 200 KiB, 16 B when reliable.
fn start_publisher(vendor: Vendor, domain: u32, reliable: bool) -> Peer {
    let d = domain_arg(domain);
    let rel = if reliable {
        "--reliable"
    } else {
        "--best-effort"
    };
    let sizes = if reliable { "16,204800,16" } else { "16" };
    Peer::start(
        vendor,
        &[
            "--domain",
            &d,
            "--topic",
            "interop",
            "--type",
            "msg",
            "--pub",
            rel,
            "--count",
            "3",
            "--size",
            sizes,
            "--wait-match",
            "1",
            "--settle-ms",
            "300",
            "--text",
            "peer",
            "--linger-ms",
            "300",
            "--timeout-s",
            "20",
        ],
    )
}

async fn peer_to_courier(vendor: Vendor, domain: u32, reliable: bool) {
    let s = session(domain).await;
    let b = s.subscriber::<Msg>("interop");
    let b = if reliable { b } else { b.best_effort() };
    let mut sub = b.build().await.unwrap();
    let mut peer = start_publisher(vendor, domain, reliable);
    for seq in 1..=3u32 {
        let v = next(&mut sub).await.unwrap().value;
        let size = if reliable && seq == 2 { 204_800 } else { 16 };
        assert_eq!(v.seq, seq, "{vendor:?}: in order");
        assert_eq!(v.text, format!("peer-{seq}"));
        assert_eq!(
            v.payload,
            payload(seq, size),
            "{vendor:?}: sample {seq} bytes"
        );
    }
    let code = blocking(move || {
        peer.expect("done");
        peer.exit_code()
    })
    .await;
    assert_eq!(code, Some(0), "{vendor:?} publisher exit");
    s.close().await;
}

// ---------------------------------------------------------------------------
// Courier publishes, peer subscribes

/// How [`courier_to_peer`] publishes.
#[derive(Clone, Copy, PartialEq)]
enum Publish {
    /// Best effort, paced, once both sides matched.
    BestEffort,
    /// Reliable, once both sides matched.
    Reliable,
    /// Reliable, as soon as Courier matched the peer's reader, which may
    /// not have matched Courier's writer yet (Cyclone drops such DATA and
    /// starts a volatile reader at the first heartbeat it sees).
    ReliableBeforePeerMatched,
}

async fn courier_to_peer(vendor: Vendor, domain: u32, publish: Publish) {
    let reliable = publish != Publish::BestEffort;
    let s = session(domain).await;
    let b = s.publisher::<Msg>("interop");
    let p = if reliable { b } else { b.best_effort() }
        .build()
        .await
        .unwrap();
    let d = domain_arg(domain);
    let rel = if reliable {
        "--reliable"
    } else {
        "--best-effort"
    };
    let count = "3";
    let mut peer = Peer::start(
        vendor,
        &[
            "--domain",
            &d,
            "--topic",
            "interop",
            "--type",
            "msg",
            "--sub",
            rel,
            "--count",
            count,
            "--timeout-s",
            "20",
        ],
    );
    await_handlers(&s, "interop").await;
    if publish != Publish::ReliableBeforePeerMatched {
        peer = blocking(move || {
            peer.expect("matched 1");
            peer
        })
        .await;
    }
    let sizes = if reliable {
        [16, 204_800, 16]
    } else {
        [16, 16, 16]
    };
    let mut want = Vec::new();
    for (i, size) in sizes.into_iter().enumerate() {
        let seq = i as u32 + 1;
        let v = Msg {
            seq,
            text: format!("courier-{seq}"),
            payload: payload(seq, size),
        };
        want.push(format!(
            "sample {seq} courier-{seq} {size} {:08x}",
            fnv1a32(&v.payload)
        ));
        if reliable {
            p.publish(&v).await.unwrap();
        } else {
            // best effort: a sample in flight before the peer's reader is
            // ready is legitimately lost, so pace them, the first one too
            // (Cyclone reports the match a moment before it accepts data:
            // ddsi_new_proxy_writer's local_matching_inprogress)
            tokio::time::sleep(Duration::from_millis(50)).await;
            p.publish(&v).await.unwrap();
        }
    }
    let (got, code) = blocking(move || {
        if publish == Publish::ReliableBeforePeerMatched {
            peer.expect("matched 1");
        }
        let got: Vec<String> = (0..3).map(|_| peer.expect("sample ")).collect();
        peer.expect("done");
        (got, peer.exit_code())
    })
    .await;
    assert_eq!(got, want, "{vendor:?} subscriber");
    assert_eq!(code, Some(0));
    s.close().await;
}

/// The peer publishes to a Courier session that reads on its receive
/// thread and takes the samples in a `listen` callback.
async fn peer_to_courier_callback(vendor: Vendor, domain: u32) {
    let s = tokio::time::timeout(
        T,
        Session::builder(common::url(domain))
            .name("courier")
            .receive_thread(true)
            .connect(),
    )
    .await
    .expect("connect in time")
    .expect("connect");
    let (tx, rx) = std::sync::mpsc::channel();
    let _l = s
        .subscriber::<Msg>("interop")
        .listen(move |r| drop(tx.send(r)))
        .await
        .unwrap();
    let mut peer = start_publisher(vendor, domain, true);
    let got = blocking(move || {
        (1..=3u32)
            .map(|_| {
                rx.recv_timeout(T)
                    .expect("a callback in time")
                    .unwrap()
                    .value
            })
            .collect::<Vec<_>>()
    })
    .await;
    for (v, seq) in got.iter().zip(1..=3u32) {
        let size = if seq == 2 { 204_800 } else { 16 };
        assert_eq!(v.seq, seq, "{vendor:?}: in order");
        assert_eq!(v.text, format!("peer-{seq}"));
        assert_eq!(v.payload, payload(seq, size), "{vendor:?}: sample {seq}");
    }
    let code = blocking(move || {
        peer.expect("done");
        peer.exit_code()
    })
    .await;
    assert_eq!(code, Some(0), "{vendor:?} publisher exit");
    s.close().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn cyclone_to_courier_callback_on_the_receive_thread() {
    peer_to_courier_callback(Vendor::Cyclone, 190).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn fastdds_to_courier_callback_on_the_receive_thread() {
    peer_to_courier_callback(Vendor::FastDds, 191).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn cyclone_to_courier_reliable_with_200_kib() {
    peer_to_courier(Vendor::Cyclone, 170, true).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn cyclone_to_courier_best_effort() {
    peer_to_courier(Vendor::Cyclone, 171, false).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn fastdds_to_courier_reliable_with_200_kib() {
    peer_to_courier(Vendor::FastDds, 172, true).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn fastdds_to_courier_best_effort() {
    peer_to_courier(Vendor::FastDds, 173, false).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn courier_to_cyclone_reliable_with_200_kib() {
    courier_to_peer(Vendor::Cyclone, 174, Publish::Reliable).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn courier_to_cyclone_reliable_before_cyclone_matched() {
    courier_to_peer(Vendor::Cyclone, 192, Publish::ReliableBeforePeerMatched).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn courier_to_fastdds_reliable_before_fastdds_matched() {
    courier_to_peer(Vendor::FastDds, 193, Publish::ReliableBeforePeerMatched).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn courier_to_cyclone_best_effort() {
    courier_to_peer(Vendor::Cyclone, 175, Publish::BestEffort).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn courier_to_fastdds_reliable_with_200_kib() {
    courier_to_peer(Vendor::FastDds, 176, Publish::Reliable).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn courier_to_fastdds_best_effort() {
    courier_to_peer(Vendor::FastDds, 177, Publish::BestEffort).await;
}

// ---------------------------------------------------------------------------
// Keyed topics and dispose

async fn keyed_peer_to_courier(vendor: Vendor, domain: u32) {
    let s = session(domain).await;
    let mut sub = s
        .subscriber::<Keyed>("keyed")
        .with_instances()
        .build()
        .await
        .unwrap();
    let d = domain_arg(domain);
    let mut peer = Peer::start(
        vendor,
        &[
            "--domain",
            &d,
            "--topic",
            "keyed",
            "--type",
            "keyed",
            "--pub",
            "--reliable",
            "--count",
            "2",
            "--keys",
            "5",
            "--dispose-every",
            "2",
            "--wait-match",
            "1",
            "--settle-ms",
            "300",
            "--text",
            "k",
            "--linger-ms",
            "300",
            "--timeout-s",
            "20",
        ],
    );
    // ids n % 5: 1, 2; then instance 2 is disposed
    for seq in 1..=2u32 {
        let v = match next(&mut sub).await {
            Ok(Received::Sample(s)) => s.value,
            other => panic!("{vendor:?}: expected sample {seq}, got {other:?}"),
        };
        assert_eq!(
            (v.id, v.seq, v.text.as_str()),
            (seq as i32, seq, &*format!("k-{seq}"))
        );
    }
    match next(&mut sub).await {
        Ok(Received::Instance(c)) => {
            assert_eq!(c.state, InstanceState::Disposed, "{vendor:?}");
            // Cyclone sends the key (K flag, CDR with the id), Fast DDS only
            // the key hash, which holds this key: either way instance 2
            assert_eq!(c.key, Some(2), "{vendor:?}: {c:?}");
        }
        other => panic!("{vendor:?}: expected the dispose of instance 2, got {other:?}"),
    }
    blocking(move || peer.expect("done")).await;
    s.close().await;
}

async fn keyed_courier_to_peer(vendor: Vendor, domain: u32) {
    let s = session(domain).await;
    let p = s.publisher::<Keyed>("keyed").build().await.unwrap();
    let d = domain_arg(domain);
    let mut peer = Peer::start(
        vendor,
        &[
            "--domain",
            &d,
            "--topic",
            "keyed",
            "--type",
            "keyed",
            "--sub",
            "--reliable",
            "--count",
            "2",
            "--timeout-s",
            "20",
        ],
    );
    await_handlers(&s, "keyed").await;
    let peer = blocking(move || {
        peer.expect("matched 1");
        peer
    })
    .await;
    let k = |id, seq| Keyed {
        id,
        seq,
        text: format!("c-{seq}"),
    };
    // dispose before the second sample: the subscriber stops after two
    // samples and reports instance changes as it takes them
    p.publish(&k(7, 1)).await.unwrap();
    p.dispose(&k(7, 0)).await.unwrap();
    p.publish(&k(8, 2)).await.unwrap();
    let mut lines = peer_lines(peer).await;
    lines.sort();
    assert_eq!(
        lines,
        ["disposed 7", "sample 7 1 c-1", "sample 8 2 c-2"],
        "{vendor:?}"
    );
    s.close().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn keyed_dispose_cyclone_to_courier() {
    keyed_peer_to_courier(Vendor::Cyclone, 178).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn keyed_dispose_fastdds_to_courier() {
    keyed_peer_to_courier(Vendor::FastDds, 179).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn keyed_dispose_courier_to_cyclone() {
    keyed_courier_to_peer(Vendor::Cyclone, 180).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn keyed_dispose_courier_to_fastdds() {
    keyed_courier_to_peer(Vendor::FastDds, 181).await;
}

// ---------------------------------------------------------------------------
// Key hashes in the XCDR version of the data: Cyclone DDS 0.10 as the oracle

/// Cyclone DDS 0.10 (`--keyhash`: Internal/GenerateKeyhash) sends
/// `PID_KEY_HASH` computed in the XCDR version of its data, XCDR1 here:
/// for `Stamped` (`@key long id; @key long long stamp;`) that is `id`, 4
/// bytes of padding, `stamp`, where the XCDR2 form is `id`, `stamp`, 4
/// bytes of the hash's padding. A raw subscription (no type, so Courier
/// computes no hash of its own) shows the hash exactly as Cyclone sent it,
/// with each sample and with the dispose; a typed one reports the dispose
/// with that hash, says it is XCDR1, and decodes the key.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn cyclone_sends_the_key_hash_in_xcdr1() {
    use courier::cdr::Version;
    let domain = 194;
    let s = session(domain).await;
    let mut sub = s
        .subscriber::<Stamped>("stamped")
        .with_instances()
        .build()
        .await
        .unwrap();
    let mut raw = s.subscribe_raw("stamped").await.unwrap();
    let d = domain_arg(domain);
    let mut peer = Peer::start(
        Vendor::Cyclone,
        &[
            "--domain",
            &d,
            "--topic",
            "stamped",
            "--type",
            "stamped",
            "--pub",
            "--reliable",
            "--keyhash",
            "--count",
            "2",
            "--keys",
            "5",
            "--dispose-every",
            "2",
            "--wait-match",
            "2",
            "--settle-ms",
            "300",
            "--text",
            "k",
            "--linger-ms",
            "300",
            "--timeout-s",
            "20",
        ],
    );
    let v = |id: i32, seq: u32| Stamped {
        id,
        stamp: stamp(id),
        seq,
        text: format!("k-{seq}"),
    };
    let xcdr1 = |id| courier::key_hash_in(&v(id, 0), Version::Xcdr1);
    // written out: id 2, padding, 0x0102030405060708 + 2
    assert_eq!(xcdr1(2), [0, 0, 0, 2, 0, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 10]);
    assert_ne!(xcdr1(2), courier::key_hash(&v(2, 0)), "XCDR2 differs");
    // ids n % 5: 1, 2; then instance 2 is disposed
    for seq in 1..=2u32 {
        match next(&mut sub).await {
            Ok(Received::Sample(smp)) => assert_eq!(smp.value, v(seq as i32, seq)),
            other => panic!("expected sample {seq}, got {other:?}"),
        }
    }
    match next(&mut sub).await {
        Ok(Received::Instance(c)) => {
            assert_eq!(c.state, InstanceState::Disposed, "{c:?}");
            assert_eq!(c.key_hash, Some(xcdr1(2)), "Cyclone's hash: {c:?}");
            assert_eq!(c.key_hash_version, Some(Version::Xcdr1), "{c:?}");
            assert_eq!(c.key, Some((2, stamp(2))), "{c:?}");
        }
        other => panic!("expected the dispose of instance 2, got {other:?}"),
    }
    // what Cyclone put on the wire, untouched
    let mut got = Vec::new();
    for _ in 0..3 {
        let r = tokio::time::timeout(T, raw.recv())
            .await
            .expect("a raw sample in time")
            .expect("open");
        got.push((r.state, r.key_hash));
    }
    assert_eq!(
        got,
        [
            (InstanceState::Alive, Some(xcdr1(1))),
            (InstanceState::Alive, Some(xcdr1(2))),
            (InstanceState::Disposed, Some(xcdr1(2))),
        ],
        "the PID_KEY_HASH Cyclone sent"
    );
    blocking(move || peer.expect("done")).await;
    s.close().await;
}

/// Courier's writer sends the XCDR1 key hash with its XCDR1 samples and
/// dispose; a Cyclone DDS 0.10 reader takes them, and the dispose lands on
/// the instance written.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn courier_to_cyclone_with_a_long_long_key() {
    let domain = 195;
    let s = session(domain).await;
    let p = s.publisher::<Stamped>("stamped").build().await.unwrap();
    let d = domain_arg(domain);
    let mut peer = Peer::start(
        Vendor::Cyclone,
        &[
            "--domain",
            &d,
            "--topic",
            "stamped",
            "--type",
            "stamped",
            "--sub",
            "--reliable",
            "--count",
            "2",
            "--disposed",
            "1",
            "--timeout-s",
            "20",
        ],
    );
    await_handlers(&s, "stamped").await;
    let peer = blocking(move || {
        peer.expect("matched 1");
        peer
    })
    .await;
    let k = |id, seq| Stamped {
        id,
        stamp: stamp(id),
        seq,
        text: format!("c-{seq}"),
    };
    p.publish(&k(7, 1)).await.unwrap();
    p.dispose(&k(7, 0)).await.unwrap();
    p.publish(&k(8, 2)).await.unwrap();
    let mut lines = peer_lines(peer).await;
    lines.sort();
    let (s7, s8) = (stamp(7), stamp(8));
    assert_eq!(
        lines,
        [
            format!("disposed 7:{s7}"),
            format!("sample 7:{s7} 1 c-1"),
            format!("sample 8:{s8} 2 c-2"),
        ]
    );
    s.close().await;
}

// ---------------------------------------------------------------------------
// Transient-local late joiners

async fn late_peer_reader(vendor: Vendor, domain: u32) {
    let s = session(domain).await;
    let p = s
        .publisher::<Msg>("history")
        .transient_local()
        .keep_last(10)
        .build()
        .await
        .unwrap();
    for seq in 1..=3u32 {
        p.publish(&Msg {
            seq,
            text: format!("old-{seq}"),
            payload: payload(seq, 8),
        })
        .await
        .unwrap();
    }
    // the reader starts after everything was written
    let d = domain_arg(domain);
    let mut peer = Peer::start(
        vendor,
        &[
            "--domain",
            &d,
            "--topic",
            "history",
            "--type",
            "msg",
            "--sub",
            "--reliable",
            "--transient-local",
            "--count",
            "3",
            "--timeout-s",
            "20",
        ],
    );
    let got = blocking(move || (0..3).map(|_| peer.expect("sample ")).collect::<Vec<_>>()).await;
    let want: Vec<String> = (1..=3u32)
        .map(|seq| format!("sample {seq} old-{seq} 8 {:08x}", fnv1a32(&payload(seq, 8))))
        .collect();
    assert_eq!(got, want, "{vendor:?} late joiner");
    s.close().await;
}

/// A late joiner of a Courier transient-local writer gets no instance the
/// writer unregistered, as it would get none from a Cyclone or Fast DDS
/// writer (audit 19: Courier's history kept the instance's samples and
/// its unregister for late joiners).
async fn late_peer_reader_of_unregistered(vendor: Vendor, domain: u32) {
    let s = session(domain).await;
    let p = s
        .publisher::<Keyed>("gone")
        .transient_local()
        .keep_last(10)
        .build()
        .await
        .unwrap();
    let k = |id, seq| Keyed {
        id,
        seq,
        text: format!("c-{seq}"),
    };
    p.publish(&k(1, 1)).await.unwrap();
    p.publish(&k(2, 2)).await.unwrap();
    p.unregister(&k(1, 0)).await.unwrap();
    let d = domain_arg(domain);
    let peer = Peer::start(
        vendor,
        &[
            "--domain",
            &d,
            "--topic",
            "gone",
            "--type",
            "keyed",
            "--sub",
            "--reliable",
            "--transient-local",
            "--count",
            "1",
            "--timeout-s",
            "20",
        ],
    );
    let mut lines = peer_lines(peer).await;
    lines.retain(|l| l != "ready");
    assert_eq!(lines, ["sample 2 2 c-2"], "{vendor:?} late joiner");
    s.close().await;
}

async fn late_courier_reader(vendor: Vendor, domain: u32) {
    let d = domain_arg(domain);
    let mut peer = Peer::start(
        vendor,
        &[
            "--domain",
            &d,
            "--topic",
            "history",
            "--type",
            "msg",
            "--pub",
            "--reliable",
            "--transient-local",
            "--depth",
            "10",
            "--count",
            "3",
            "--size",
            "8",
            "--text",
            "old",
            "--linger-ms",
            "15000",
            "--timeout-s",
            "25",
        ],
    );
    let mut peer = blocking(move || {
        for _ in 0..3 {
            peer.expect("sent ");
        }
        peer
    })
    .await;
    let s = session(domain).await;
    // a volatile reliable reader beside it takes none of the history
    // (audit 18: it asked a Cyclone writer for all of it and got it)
    let mut volatile = s.subscriber::<Msg>("history").build().await.unwrap();
    let mut sub = s
        .subscriber::<Msg>("history")
        .transient_local()
        .build()
        .await
        .unwrap();
    for seq in 1..=3u32 {
        let v = next(&mut sub).await.unwrap().value;
        assert_eq!((v.seq, v.text), (seq, format!("old-{seq}")), "{vendor:?}");
        assert_eq!(v.payload, payload(seq, 8));
    }
    // what the transient-local reader got by repair, the volatile one
    // would have got by now too
    let leak = tokio::time::timeout(Duration::from_millis(500), volatile.next()).await;
    assert!(
        leak.is_err(),
        "{vendor:?}: a volatile reader got history: {leak:?}"
    );
    drop(volatile);
    drop(sub);
    s.close().await;
    peer.0.kill();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn transient_local_cyclone_late_joiner() {
    late_peer_reader(Vendor::Cyclone, 182).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn transient_local_fastdds_late_joiner() {
    late_peer_reader(Vendor::FastDds, 183).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn transient_local_cyclone_late_joiner_gets_no_unregistered_instance() {
    late_peer_reader_of_unregistered(Vendor::Cyclone, 196).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn transient_local_fastdds_late_joiner_gets_no_unregistered_instance() {
    late_peer_reader_of_unregistered(Vendor::FastDds, 197).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn transient_local_courier_late_joiner_of_cyclone() {
    late_courier_reader(Vendor::Cyclone, 184).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn transient_local_courier_late_joiner_of_fastdds() {
    late_courier_reader(Vendor::FastDds, 185).await;
}

// ---------------------------------------------------------------------------
// Discovery and loss of a peer, as events

async fn discovery_events(vendor: Vendor, domain: u32) {
    let s = session(domain).await;
    let mut ev = s.events();
    let d = domain_arg(domain);
    let peer = Peer::start(
        vendor,
        &[
            "--domain",
            &d,
            "--topic",
            "seen",
            "--type",
            "msg",
            "--pub",
            "--reliable",
            "--count",
            "0",
            "--linger-ms",
            "1500",
            "--timeout-s",
            "20",
        ],
    );
    let mut prefix = None;
    let mut publication = false;
    tokio::time::timeout(T, async {
        while prefix.is_none() || !publication {
            match ev.next().await.expect("events") {
                SessionEvent::ParticipantFound(p) => prefix = Some(p.guid.prefix()),
                SessionEvent::PublicationFound(e) => {
                    publication |= e.topic == "seen" && e.type_name == "courier::test::Msg"
                }
                _ => {}
            }
        }
    })
    .await
    .unwrap_or_else(|_| panic!("{vendor:?}: participant and publication found"));
    let prefix = prefix.unwrap();
    // the peer exits by itself after lingering and says goodbye
    let lost = tokio::time::timeout(T, async {
        loop {
            if let SessionEvent::ParticipantLost { guid, disposed } =
                ev.next().await.expect("events")
            {
                if guid.is_of(prefix) {
                    return disposed;
                }
            }
        }
    })
    .await
    .unwrap_or_else(|_| panic!("{vendor:?}: participant lost"));
    assert!(lost, "{vendor:?}: a clean exit disposes the participant");
    drop(peer);
    s.close().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn discovery_and_loss_of_cyclone() {
    discovery_events(Vendor::Cyclone, 186).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn discovery_and_loss_of_fastdds() {
    discovery_events(Vendor::FastDds, 187).await;
}

// ---------------------------------------------------------------------------
// ROS 2-style services (rq/<name>Request, rr/<name>Reply) with Fast DDS,
// matched by related sample identity as rmw_fastrtps does

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn courier_queries_a_fastdds_service() {
    let s = session(188).await;
    let mut peer = Peer::start(
        Vendor::FastDds,
        &[
            "--domain",
            &domain_arg(188),
            "--topic",
            "echo",
            "--type",
            "msg",
            "--serve",
            "--reliable",
            "--count",
            "3",
            "--timeout-s",
            "20",
        ],
    );
    for seq in 1..=3u32 {
        let req = Msg {
            seq,
            text: format!("q{seq}"),
            payload: payload(seq, 100),
        };
        let r: Msg = s.query("echo", &req).timeout(T).await.unwrap();
        assert_eq!(r.seq, seq);
        assert_eq!(r.text, format!("re:q{seq}"));
        assert_eq!(r.payload, req.payload);
    }
    let lines = blocking(move || {
        let v: Vec<String> = (0..3).map(|_| peer.expect("request ")).collect();
        peer.expect("done");
        v
    })
    .await;
    assert_eq!(lines, ["request 1 q1", "request 2 q2", "request 3 q3"]);
    s.close().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_fastdds_client_queries_a_courier_service() {
    let s = session(189).await;
    let mut reqs = s.serve::<Msg, Msg>("echo", "").await.unwrap();
    let server = tokio::spawn(async move {
        for _ in 0..3 {
            let r = tokio::time::timeout(T, reqs.next())
                .await
                .expect("a request in time")
                .expect("open")
                .expect("decodes");
            let mut v = r.value.clone();
            v.text = format!("re:{}", v.text);
            r.reply(&v).await.unwrap();
        }
    });
    let mut peer = Peer::start(
        Vendor::FastDds,
        &[
            "--domain",
            &domain_arg(189),
            "--topic",
            "echo",
            "--type",
            "msg",
            "--request",
            "--reliable",
            "--count",
            "3",
            "--text",
            "ros",
            "--timeout-s",
            "20",
        ],
    );
    let lines = blocking(move || {
        let v: Vec<String> = (0..3).map(|_| peer.expect("reply ")).collect();
        peer.expect("done");
        v
    })
    .await;
    assert_eq!(
        lines,
        [
            "reply 1 re:ros-1 related",
            "reply 2 re:ros-2 related",
            "reply 3 re:ros-3 related"
        ]
    );
    server.await.unwrap();
    s.close().await;
}
