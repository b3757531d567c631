//! DDS LIVELINESS against Cyclone DDS 11 (the PyPI `cyclonedds` package,
//! `tests/peers/rtps/cyclone11_peer.py --liveliness`), and between Courier
//! sessions:
//!
//! - a Cyclone reader requesting AUTOMATIC with a 1 s lease matches a
//!   Courier publication offering it, and sees it alive — never lost —
//!   for seconds without a sample: Courier's participant messages keep
//!   the lease;
//! - a Courier subscription requesting liveliness sees a Cyclone writer
//!   (AUTOMATIC, 1 s) go not alive when the Cyclone process is stopped
//!   (`SIGSTOP`; its participant lease, 10 s, outlives the stop, so the
//!   participant is not lost), and alive again when it continues;
//! - a Cyclone reader follows a Courier manual-by-topic or
//!   manual-by-participant publication kept alive by `assert_liveliness`
//!   alone (liveliness HEARTBEATs, manual participant messages), and sees
//!   it lapse when the assertions stop;
//! - against Fast DDS 2.9 (`tests/peers/rtps/fastdds_peer.cpp
//!   --liveliness`): a Fast DDS reader requesting AUTOMATIC 1 s sees an
//!   idle Courier automatic writer alive, never lost; a Fast DDS automatic
//!   writer goes not alive at Courier while its process is stopped (its
//!   participant lease, 20 s, outlives the stop) and alive after it
//!   continues; a Fast DDS reader follows a Courier manual-by-topic writer
//!   kept alive by `assert_liveliness` alone and sees it lapse; a Courier
//!   reader follows a Fast DDS manual-by-topic writer kept alive by
//!   `DataWriter::assert_liveliness` alone (liveliness HEARTBEATs) and sees
//!   it lapse when the assertions stop;
//! - between Courier sessions: a manual-by-topic publication lapses
//!   without writes (both sides say so) and `assert_liveliness` revives it;
//!   nonsense leases are refused.
//!
//! Loopback only: the peer runs its built-in loopback-only unicast
//! configuration, Courier `interface=lo&peers=127.0.0.1`; domains leased
//! machine-wide (`courier_tests::domains`). A missing peer fails the test
//! with what is missing. Every wait is bounded.

use std::time::Duration;

use courier::qos::LivelinessKind;
use courier::{Events, Guid, OpenError, Session, SessionEvent};
use futures::StreamExt;

mod common;
use common::{next, Keyed, T};

use courier_tests::peers::{cyclone11_peer_args, cyclone11_python, fastdds_peer, PeerProcess};

/// A running Cyclone 11 peer, continued (if stopped), killed and reaped
/// when dropped.
struct Peer(PeerProcess);

/// The DDS implementation a peer runs.
#[derive(Debug, Clone, Copy)]
enum Vendor {
    /// Cyclone DDS 11 (the PyPI package; `cyclone11_peer.py`).
    Cyclone,
    /// Fast DDS 2.9 (`fastdds_peer.cpp`, built on first use).
    FastDds,
}

impl Peer {
    /// A peer on the domain leased to `key`, with `role` (`--pub` or
    /// `--sub`) on `topic` (keyed, reliable) and `liveliness` (the peer's
    /// `--liveliness`), then `more` of its options.
    fn start(
        vendor: Vendor,
        key: u32,
        topic: &str,
        role: &str,
        liveliness: &str,
        more: &[&str],
    ) -> Peer {
        let d = courier_tests::domains::lease(key).to_string();
        let mut args = vec![
            "--domain",
            &d,
            "--topic",
            topic,
            "--type",
            "keyed",
            role,
            "--reliable",
            "--liveliness",
            liveliness,
        ];
        args.extend_from_slice(more);
        let p = match vendor {
            Vendor::Cyclone => cyclone11_python()
                .and_then(|py| PeerProcess::spawn(py, &cyclone11_peer_args(&args))),
            Vendor::FastDds => fastdds_peer().and_then(|exe| PeerProcess::spawn(exe, &args)),
        };
        Peer(p.unwrap_or_else(|e| panic!("cannot start the {vendor:?} interop peer: {e}")))
    }

    fn expect(&mut self, prefix: &str) -> String {
        self.0
            .expect_line(prefix, T)
            .unwrap_or_else(|e| panic!("{e}"))
    }

    fn signal(&self, sig: &str) {
        let ok = std::process::Command::new("kill")
            .args([sig, &self.0.id().to_string()])
            .status()
            .is_ok_and(|s| s.success());
        assert!(ok, "kill {sig} {}", self.0.id());
    }
}

impl Drop for Peer {
    fn drop(&mut self) {
        let _ = std::process::Command::new("kill")
            .args(["-CONT", &self.0.id().to_string()])
            .status();
    }
}

async fn blocking<R: Send + 'static>(f: impl FnOnce() -> R + Send + 'static) -> R {
    tokio::task::spawn_blocking(f).await.expect("blocking task")
}

/// The next liveliness change of `topic`, as `(writer, alive, alive_count,
/// not_alive_count)`; every other event goes to `seen`.
async fn next_liveliness(
    ev: &mut Events,
    topic: &str,
    seen: &mut Vec<SessionEvent>,
) -> (Guid, bool, u32, u32) {
    tokio::time::timeout(T, async {
        loop {
            match ev.next().await.expect("session events") {
                SessionEvent::LivelinessChanged {
                    msg,
                    writer,
                    alive,
                    alive_count,
                    not_alive_count,
                } if msg == topic => return (writer, alive, alive_count, not_alive_count),
                e => seen.push(e),
            }
        }
    })
    .await
    .unwrap_or_else(|_| panic!("no liveliness change of {topic} in time; saw {seen:?}"))
}

/// Every event of `ev` for `d`.
async fn events_for(ev: &mut Events, d: Duration) -> Vec<SessionEvent> {
    let mut out = Vec::new();
    let _ = tokio::time::timeout(d, async {
        while let Some(e) = ev.next().await {
            out.push(e);
        }
    })
    .await;
    out
}

fn lost_participant(events: &[SessionEvent]) -> bool {
    events
        .iter()
        .any(|e| matches!(e, SessionEvent::ParticipantLost { .. }))
}

/// (a) The peer's reader requests AUTOMATIC within 1 s; the Courier
/// publication offers exactly that and writes nothing. The peer matches
/// it (before, Courier offered an infinite lease only: incompatible) and
/// its liveliness-changed status says alive, and never not alive, for
/// `run_s` seconds: Courier's automatic participant messages keep the
/// lease (Fast DDS asserts an AUTOMATIC writer on nothing else).
async fn a_peer_reader_sees_a_courier_automatic_writer_alive_without_data(
    vendor: Vendor,
    key: u32,
    topic: &'static str,
    run_s: &str,
) {
    let s: Session = common::session(key, "courier").await;
    let _publ = s
        .publisher::<Keyed>(topic)
        .liveliness(LivelinessKind::Automatic, Duration::from_secs(1))
        .build()
        .await
        .unwrap();
    let mut peer = Peer::start(
        vendor,
        key,
        topic,
        "--sub",
        "automatic:1",
        &["--run-s", run_s, "--timeout-s", "60"],
    );
    let lines = blocking(move || {
        peer.expect("ready");
        let lines = peer
            .0
            .lines_until("done", T)
            .unwrap_or_else(|e| panic!("{e}"));
        (peer, lines)
    })
    .await
    .1;
    assert!(
        lines.iter().any(|l| l == "matched 1"),
        "{vendor:?}'s reader never matched the writer: {lines:?}"
    );
    let liveliness = liveliness_lines(&lines);
    assert!(
        liveliness.iter().any(|l| l == "liveliness 1 0"),
        "never alive: {lines:?}"
    );
    assert_eq!(
        liveliness.last().map(|l| l.as_str()),
        Some("liveliness 1 0"),
        "alive to the end: {lines:?}"
    );
    assert!(
        liveliness.iter().all(|l| l.ends_with(" 0")),
        "{vendor:?} saw the writer not alive: {lines:?}"
    );
    s.close().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_cyclone_reader_sees_a_courier_automatic_writer_alive_without_data() {
    a_peer_reader_sees_a_courier_automatic_writer_alive_without_data(
        Vendor::Cyclone,
        1,
        "lv_auto",
        "6",
    )
    .await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_fastdds_reader_sees_a_courier_automatic_writer_alive_without_data() {
    a_peer_reader_sees_a_courier_automatic_writer_alive_without_data(
        Vendor::FastDds,
        7,
        "lv_fd_auto",
        "4",
    )
    .await;
}

/// Between Courier sessions: a manual-by-topic publication that writes
/// nothing lapses (the publisher gets `LivelinessLost`, the subscriber
/// `LivelinessChanged` not alive), and `assert_liveliness` — no sample —
/// makes it alive again.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_manual_by_topic_publication_lapses_and_assert_liveliness_revives_it() {
    let a: Session = common::session(3, "pub").await;
    let b: Session = common::session(3, "sub").await;
    let mut pub_ev = a.events();
    let mut sub_ev = b.events();
    let _sub = b
        .subscriber::<Keyed>("lv_manual")
        .liveliness(LivelinessKind::ManualByTopic, Duration::from_secs(2))
        .build()
        .await
        .unwrap();
    let publ = a
        .publisher::<Keyed>("lv_manual")
        .liveliness(LivelinessKind::ManualByTopic, Duration::from_millis(500))
        .build()
        .await
        .unwrap();
    let mut seen = Vec::new();
    let (writer, alive, ..) = next_liveliness(&mut sub_ev, "lv_manual", &mut seen).await;
    assert!(alive, "alive from the match");
    let lapsed = next_liveliness(&mut sub_ev, "lv_manual", &mut seen).await;
    assert_eq!(lapsed, (writer, false, 0, 1), "lapsed without writes");
    tokio::time::timeout(T, async {
        loop {
            if let SessionEvent::LivelinessLost { msg, total } = pub_ev.next().await.unwrap() {
                assert_eq!((msg.as_str(), total), ("lv_manual", 1));
                return;
            }
        }
    })
    .await
    .expect("the publisher is told");
    publ.assert_liveliness().await.unwrap();
    let back = next_liveliness(&mut sub_ev, "lv_manual", &mut seen).await;
    assert_eq!(back, (writer, true, 1, 0), "asserted: alive again");
    drop(publ);
    a.close().await;
    b.close().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn nonsense_leases_are_refused() {
    let s: Session = common::session(4, "courier").await;
    let e = s
        .publisher::<Keyed>("lv_bad")
        .liveliness(LivelinessKind::ManualByTopic, Duration::ZERO)
        .build()
        .await
        .unwrap_err();
    assert!(matches!(e, OpenError::Qos { .. }), "{e:?}");
    let e = s
        .subscriber::<Keyed>("lv_bad")
        .liveliness(LivelinessKind::Automatic, Duration::from_secs(u64::MAX / 4))
        .build()
        .await
        .unwrap_err();
    assert!(matches!(e, OpenError::Qos { .. }), "{e:?}");
    s.close().await;
}

/// The `liveliness ...` lines among `lines`.
fn liveliness_lines(lines: &[String]) -> Vec<String> {
    lines
        .iter()
        .filter(|l| l.starts_with("liveliness "))
        .cloned()
        .collect()
}

/// (b) A Courier subscription requesting AUTOMATIC within 2 s matches a
/// peer writer offering AUTOMATIC within 1 s: alive while it writes
/// nothing (the peer's participant messages keep it; Fast DDS's a third
/// of the lease apart), not alive once the peer process is stopped — its
/// participant, leased 10 s (Cyclone) or 20 s (Fast DDS), still known —
/// and alive again when it continues.
async fn a_stopped_peer_writer_goes_not_alive_and_comes_back(
    vendor: Vendor,
    key: u32,
    topic: &'static str,
) {
    let s: Session = common::session(key, "courier").await;
    let mut ev = s.events();
    let mut sub = s
        .subscriber::<Keyed>(topic)
        .liveliness(LivelinessKind::Automatic, Duration::from_secs(2))
        .build()
        .await
        .unwrap();
    let mut peer = Peer::start(
        vendor,
        key,
        topic,
        "--pub",
        "automatic:1",
        &[
            "--count",
            "1",
            "--wait-match",
            "1",
            "--linger-ms",
            "60000",
            "--timeout-s",
            "90",
        ],
    );
    let mut seen = Vec::new();
    let (writer, alive, a, n) = next_liveliness(&mut ev, topic, &mut seen).await;
    assert_eq!((alive, a, n), (true, 1, 0), "alive from the match");
    let sample = next(&mut sub).await.unwrap();
    assert_eq!(sample.value.seq, 1);
    peer = blocking(move || {
        peer.expect("acked");
        peer
    })
    .await;

    // kept alive while it writes nothing, for several leases
    let quiet = events_for(&mut ev, Duration::from_millis(2500)).await;
    assert!(
        !quiet
            .iter()
            .any(|e| matches!(e, SessionEvent::LivelinessChanged { alive: false, .. })),
        "the idle {vendor:?} writer lapsed: {quiet:?}"
    );

    peer.signal("-STOP");
    let mut seen = Vec::new();
    let stopped = next_liveliness(&mut ev, topic, &mut seen).await;
    assert_eq!(stopped, (writer, false, 0, 1), "not alive once stopped");
    assert!(
        !lost_participant(&seen),
        "its participant is still known: {seen:?}"
    );

    peer.signal("-CONT");
    let back = next_liveliness(&mut ev, topic, &mut seen).await;
    assert_eq!(back, (writer, true, 1, 0), "alive again");
    assert!(!lost_participant(&seen), "{seen:?}");
    drop(peer);
    s.close().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_stopped_cyclone_writer_goes_not_alive_and_comes_back() {
    a_stopped_peer_writer_goes_not_alive_and_comes_back(Vendor::Cyclone, 2, "lv_stop").await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_stopped_fastdds_writer_goes_not_alive_and_comes_back() {
    a_stopped_peer_writer_goes_not_alive_and_comes_back(Vendor::FastDds, 8, "lv_fd_stop").await;
}

/// Which call asserts: `Publisher::assert_liveliness` (DDS's
/// `DataWriter::assert_liveliness`) or `Session::assert_liveliness`
/// (`DomainParticipant::assert_liveliness`).
#[derive(Clone, Copy, Debug)]
enum AssertBy {
    Publication,
    Session,
}

/// A Courier publication with a manual liveliness (`kind`, 1 s) writes
/// nothing but asserts its liveliness four times a lease for three
/// seconds, then writes one sample and stops: the peer's reader
/// (requesting `peer_kind`, 1 s) sees it alive, never not alive, before
/// the sample — the assertions reach it: a HEARTBEAT with the liveliness
/// flag for manual by topic, a participant message of the manual kind for
/// manual by participant — and not alive a lease after it.
async fn a_peer_reader_follows_courier_manual_assertions(
    vendor: Vendor,
    key: u32,
    topic: &'static str,
    kind: LivelinessKind,
    peer_kind: &str,
    by: AssertBy,
) {
    let s: Session = common::session(key, "courier").await;
    let publ = s
        .publisher::<Keyed>(topic)
        .liveliness(kind, Duration::from_secs(1))
        .build()
        .await
        .unwrap();
    let mut peer = Peer::start(
        vendor,
        key,
        topic,
        "--sub",
        peer_kind,
        &["--count", "1", "--linger-ms", "2500", "--timeout-s", "60"],
    );
    let mut peer = blocking(move || {
        peer.expect("matched 1");
        peer
    })
    .await;
    for _ in 0..12 {
        match by {
            AssertBy::Publication => publ.assert_liveliness().await.unwrap(),
            AssertBy::Session => s.assert_liveliness().await.unwrap(),
        }
        tokio::time::sleep(Duration::from_millis(250)).await;
    }
    // Fast DDS counts a writer alive only from its first assertion (data
    // would be one too; Cyclone from the match): alive before any sample
    // means, for Fast DDS, that the assertions did it
    let (mut peer, first) = blocking(move || {
        let first = peer.0.lines_until("liveliness ", T).unwrap_or_else(|e| {
            panic!(
                "{vendor:?}, {kind:?}: never saw the asserting writer alive (no sample yet): {e}"
            )
        });
        (peer, first)
    })
    .await;
    assert_eq!(
        first.last().map(|l| l.as_str()),
        Some("liveliness 1 0"),
        "{kind:?}: alive by the assertions, before any sample: {first:?}"
    );
    let v = Keyed {
        id: 1,
        seq: 1,
        text: "last".into(),
    };
    publ.publish(&v).await.unwrap();
    let lines = blocking(move || {
        peer.0
            .lines_until("done", T)
            .unwrap_or_else(|e| panic!("{e}"))
    })
    .await;
    let at = lines
        .iter()
        .position(|l| l.starts_with("sample "))
        .unwrap_or_else(|| panic!("no sample: {lines:?}"));
    let (before, after) = lines.split_at(at);
    let before = liveliness_lines(before);
    assert!(
        before.iter().all(|l| l.ends_with(" 0")),
        "{vendor:?}, {kind:?}: the writer was not alive while it asserted: {lines:?}"
    );
    assert_eq!(
        liveliness_lines(after),
        ["liveliness 0 1"],
        "{kind:?}: not alive a lease after the last sample: {lines:?}"
    );
    drop(publ);
    s.close().await;
}

/// (c) manual by topic: liveliness HEARTBEATs.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_cyclone_reader_follows_courier_manual_by_topic_assertions() {
    a_peer_reader_follows_courier_manual_assertions(
        Vendor::Cyclone,
        5,
        "lv_m_topic",
        LivelinessKind::ManualByTopic,
        "topic:1",
        AssertBy::Publication,
    )
    .await;
}

/// Manual by participant: Courier's manual participant messages.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_cyclone_reader_follows_courier_manual_by_participant_assertions() {
    a_peer_reader_follows_courier_manual_assertions(
        Vendor::Cyclone,
        6,
        "lv_m_pp",
        LivelinessKind::ManualByParticipant,
        "participant:1",
        AssertBy::Publication,
    )
    .await;
}

/// Manual by participant, asserted by the session
/// (`DomainParticipant::assert_liveliness`) rather than the publication.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_cyclone_reader_follows_the_courier_sessions_assertions() {
    a_peer_reader_follows_courier_manual_assertions(
        Vendor::Cyclone,
        13,
        "lv_m_session",
        LivelinessKind::ManualByParticipant,
        "participant:1",
        AssertBy::Session,
    )
    .await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_fastdds_reader_follows_courier_manual_by_topic_assertions() {
    a_peer_reader_follows_courier_manual_assertions(
        Vendor::FastDds,
        9,
        "lv_fd_m_topic",
        LivelinessKind::ManualByTopic,
        "topic:1",
        AssertBy::Publication,
    )
    .await;
}

/// Fast DDS 2.9 reads Courier's participant messages at the same offsets
/// whatever their encapsulation.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_fastdds_reader_follows_courier_manual_by_participant_assertions() {
    a_peer_reader_follows_courier_manual_assertions(
        Vendor::FastDds,
        12,
        "lv_fd_m_pp",
        LivelinessKind::ManualByParticipant,
        "participant:1",
        AssertBy::Publication,
    )
    .await;
}

/// A Fast DDS writer with a manual liveliness (`peer_kind`, 1 s) writes
/// nothing and calls `DataWriter::assert_liveliness` every 250 ms for
/// three seconds: the Courier subscription (requesting `kind`, 1 s) sees
/// it alive throughout — three leases — and not alive once the
/// assertions stopped. Fast DDS 2.9 asserts a manual-by-topic writer with
/// a HEARTBEAT with the liveliness flag, a manual-by-participant one with
/// participant messages of the manual kind (encapsulated `PL_CDR_LE`).
async fn a_courier_reader_follows_fastdds_manual_assertions(
    key: u32,
    topic: &'static str,
    kind: LivelinessKind,
    peer_kind: &str,
) {
    let s: Session = common::session(key, "courier").await;
    let mut ev = s.events();
    let _sub = s
        .subscriber::<Keyed>(topic)
        .liveliness(kind, Duration::from_secs(1))
        .build()
        .await
        .unwrap();
    let mut peer = Peer::start(
        Vendor::FastDds,
        key,
        topic,
        "--pub",
        peer_kind,
        &[
            "--count",
            "0",
            "--wait-match",
            "1",
            "--settle-ms",
            "0",
            "--assert-ms",
            "250",
            "--assert-for-s",
            "3",
            "--linger-ms",
            "10000",
            "--timeout-s",
            "60",
        ],
    );
    let mut seen = Vec::new();
    let (writer, alive, a, n) = next_liveliness(&mut ev, topic, &mut seen).await;
    assert_eq!(
        (alive, a, n),
        (true, 1, 0),
        "{kind:?}: alive from the match"
    );

    // everything Courier says while the writer asserts (until the peer
    // says it stopped): never not alive, though three leases pass
    let mut asserted = tokio::task::spawn_blocking(move || {
        peer.expect("asserted");
        peer
    });
    let mut during = Vec::new();
    let peer = tokio::time::timeout(T, async {
        loop {
            tokio::select! {
                p = &mut asserted => return p.expect("blocking task"),
                e = ev.next() => during.push(e.expect("session events")),
            }
        }
    })
    .await
    .expect("the peer stops asserting in time");
    assert!(
        !during
            .iter()
            .any(|e| matches!(e, SessionEvent::LivelinessChanged { alive: false, .. })),
        "{kind:?}: the asserting Fast DDS writer lapsed: {during:?}"
    );

    let lapsed = next_liveliness(&mut ev, topic, &mut seen).await;
    assert_eq!(
        lapsed,
        (writer, false, 0, 1),
        "{kind:?}: lapsed after the assertions"
    );
    assert!(!lost_participant(&seen), "{seen:?}");
    drop(peer);
    s.close().await;
}

/// (d, Fast DDS) manual by topic: liveliness HEARTBEATs.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_courier_reader_follows_fastdds_manual_by_topic_assertions() {
    a_courier_reader_follows_fastdds_manual_assertions(
        10,
        "lv_fd_assert",
        LivelinessKind::ManualByTopic,
        "topic:1",
    )
    .await;
}

/// Manual by participant: Fast DDS's manual participant messages, which
/// Fast DDS 2.9 encapsulates as `PL_CDR_LE` (00 03), not `CDR_LE`.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_courier_reader_follows_fastdds_manual_by_participant_assertions() {
    a_courier_reader_follows_fastdds_manual_assertions(
        11,
        "lv_fd_assert_pp",
        LivelinessKind::ManualByParticipant,
        "participant:1",
    )
    .await;
}

/// A lease given alike on both sides matches, however each side rounds it
/// into RTPS's 2^-32 s fractions: Cyclone DDS 11 sends 700 ms rounded up
/// (3006477108/2^32 s); Courier, which rounded down and compared the bits,
/// refused the Cyclone writer as offering a longer lease than it requested
/// (audit 18), and the Cyclone writer, matched on its side, waited for
/// acknowledgements that never came.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_lease_given_alike_matches_however_cyclone_rounds_it() {
    let s: Session = common::session(14, "courier").await;
    let mut ev = s.events();
    let mut sub = s
        .subscriber::<Keyed>("lv_round")
        .liveliness(LivelinessKind::Automatic, Duration::from_millis(700))
        .build()
        .await
        .unwrap();
    let peer = Peer::start(
        Vendor::Cyclone,
        14,
        "lv_round",
        "--pub",
        "automatic:0.7",
        &["--count", "1", "--wait-match", "1", "--timeout-s", "60"],
    );
    let mut seen = Vec::new();
    let (_, alive, a, n) = next_liveliness(&mut ev, "lv_round", &mut seen).await;
    assert_eq!((alive, a, n), (true, 1, 0), "matched and alive: {seen:?}");
    assert!(
        !seen
            .iter()
            .any(|e| matches!(e, SessionEvent::IncompatibleQos { .. })),
        "{seen:?}"
    );
    let sample = next(&mut sub).await.unwrap();
    assert_eq!(sample.value.seq, 1);
    drop(peer);
    s.close().await;
}
