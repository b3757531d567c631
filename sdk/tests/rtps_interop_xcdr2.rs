//! XCDR2 and instances against the real peers: `@appendable` and
//! `@mutable` samples both ways with Cyclone DDS 11 (the PyPI `cyclonedds`
//! package, its own Cyclone 11 C core inside; `tests/peers/rtps/cyclone11_peer.py`)
//! and from an older version of each type (defaults for what it lacks),
//! and an int-keyed and a string-keyed dispose — one explicit, one by
//! closing the publisher (autodispose) — seen as disposed by Cyclone DDS
//! 0.10 (C), Fast DDS 2.9 and Cyclone DDS 11. XCDR1 with Fast DDS 2.9 is
//! what `rtps_interop.rs` runs (final types), and the keyed cases here too.
//!
//! Loopback only, as in `rtps_interop.rs`: every peer runs its built-in
//! loopback-only unicast configuration, Courier `interface=lo&peers=127.0.0.1`.
//! A missing peer (the Debian packages, or the `cyclonedds` Python package
//! that `.ci/run` installs under `target/cyclonedds-py`) fails the test
//! with what is missing.

use std::time::Duration;

use courier::{IpcMessage, Session};
use futures::{FutureExt, StreamExt};

mod common;
use common::{next, T};

use courier_tests::peers::{
    cyclone11_peer_args, cyclone11_python, cyclone_peer, fastdds_peer, PeerProcess,
};

#[derive(Clone, Copy, Debug, PartialEq)]
enum Vendor {
    Cyclone,
    FastDds,
    Cyclone11,
}

struct Peer(PeerProcess);

impl Peer {
    fn start(vendor: Vendor, args: &[&str]) -> Peer {
        let p = match vendor {
            Vendor::Cyclone => cyclone_peer().and_then(|exe| PeerProcess::spawn(exe, args)),
            Vendor::FastDds => fastdds_peer().and_then(|exe| PeerProcess::spawn(exe, args)),
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

fn domain_arg(d: u32) -> String {
    courier_tests::domains::lease(d).to_string()
}

async fn session(domain: u32) -> Session {
    common::session(domain, "courier").await
}

/// `@appendable struct courier::test::Appendable { @key int32 id; uint32 seq; string text; }`
#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "courier::test::Appendable", extensibility = "appendable")]
struct Appendable {
    #[ipc(key)]
    id: i32,
    seq: u32,
    text: String,
}

/// The same members, `@mutable`.
#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "courier::test::Mutable", extensibility = "mutable")]
struct Mutable {
    #[ipc(key)]
    id: i32,
    seq: u32,
    text: String,
}

/// What the peer printed until `done`, but for its `ready` and `matched`
/// lines.
async fn peer_lines(mut peer: Peer) -> Vec<String> {
    blocking(move || {
        let mut v = Vec::new();
        loop {
            let l = peer.expect("");
            if l == "done" {
                return v;
            }
            if !l.starts_with("matched") && l != "ready" {
                v.push(l);
            }
        }
    })
    .await
}

/// `courier::test::Unkeyed`: the same members, no key.
#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "courier::test::Unkeyed")]
struct Unkeyed {
    id: i32,
    seq: u32,
    text: String,
}

/// A topic without key has one instance; closing the publisher disposes
/// it for a Cyclone 11 reader, as closing a Cyclone writer does (the reader
/// saw NOT_ALIVE_NO_WRITERS instead: Courier disposed keyed instances only).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn closing_a_publisher_of_a_topic_without_key_disposes_it_for_cyclone11() {
    let s = session(17).await;
    let p = s.publisher::<Unkeyed>("one").build().await.unwrap();
    let d = domain_arg(17);
    let peer = Peer::start(
        Vendor::Cyclone11,
        &[
            "--domain",
            &d,
            "--topic",
            "one",
            "--type",
            "unkeyed",
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
    common::await_handlers(&s, "one", 1).await;
    for seq in 1..=2 {
        let v = Unkeyed {
            id: 5,
            seq,
            text: "x".into(),
        };
        p.publish(&v).await.unwrap();
    }
    drop(p);
    let lines = peer_lines(peer).await;
    // (the peer reports the state as samples are taken: the dispose may
    // show on the first of a batch)
    assert!(lines.iter().any(|l| l == "disposed 5"), "{lines:?}");
    for seq in 1..=2 {
        assert!(lines.contains(&format!("sample 5 {seq} x")), "{lines:?}");
    }
    s.close().await;
}

/// `courier::test::Keyed` (tests/peers/rtps/types.idl), final.
#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "courier::test::Keyed")]
struct Keyed {
    #[ipc(key)]
    id: i32,
    seq: u32,
    text: String,
}

/// `courier::test::StrKeyed` (tests/peers/rtps/types.idl), final: a key
/// whose hash is an MD5 digest.
#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "courier::test::StrKeyed")]
struct StrKeyed {
    #[ipc(key)]
    name: String,
    seq: u32,
    text: String,
}

/// The three members every type here has.
trait Three: IpcMessage + Clone + std::fmt::Debug + PartialEq + Send + Sync + 'static {
    fn make(id: i32, seq: u32, text: &str) -> Self;
}

macro_rules! three {
    ($t:ident) => {
        impl Three for $t {
            fn make(id: i32, seq: u32, text: &str) -> Self {
                $t {
                    id,
                    seq,
                    text: text.into(),
                }
            }
        }
    };
}
three!(Appendable);
three!(Mutable);

// ---------------------------------------------------------------------------
// XCDR2 with Cyclone DDS 11

/// Cyclone 11 writes three samples of an appendable or mutable type
/// (XCDR2, its default for them); Courier's subscriber takes them, and its
/// raw subscription sees the XCDR2 encapsulation id `want`.
async fn xcdr2_cyclone11_to_courier<M: Three>(ty: &str, want: [u8; 2], domain: u32) {
    xcdr2_cyclone11_version_to_courier::<M>(ty, "c11", want, domain).await
}

/// As [`xcdr2_cyclone11_to_courier`], Cyclone 11 writing `peer_ty`, whose
/// samples Courier reads with text `text`.
async fn xcdr2_cyclone11_version_to_courier<M: Three>(
    peer_ty: &str,
    text: &str,
    want: [u8; 2],
    domain: u32,
) {
    let ty = peer_ty;
    let s = session(domain).await;
    let mut sub = s.subscribe::<M>("x2").await.unwrap();
    let mut raw = s.subscribe_raw("x2").await.unwrap();
    let d = domain_arg(domain);
    let mut peer = Peer::start(
        Vendor::Cyclone11,
        &[
            "--domain",
            &d,
            "--topic",
            "x2",
            "--type",
            ty,
            "--pub",
            "--reliable",
            "--count",
            "3",
            "--keys",
            "5",
            "--wait-match",
            "1",
            "--settle-ms",
            "300",
            "--text",
            text,
            "--linger-ms",
            "300",
            "--timeout-s",
            "20",
        ],
    );
    for seq in 1..=3u32 {
        let v = next(&mut sub).await.unwrap().value;
        let text = if text.is_empty() {
            String::new()
        } else {
            format!("{text}-{seq}")
        };
        assert_eq!(v, M::make(5, seq, &text), "{ty}");
    }
    let header = tokio::time::timeout(T, async {
        loop {
            if let Some(s) = raw.try_recv() {
                return [s.data[0], s.data[1]];
            }
            tokio::time::sleep(Duration::from_millis(5)).await;
        }
    })
    .await
    .expect("a raw sample in time");
    assert_eq!(header, want, "{ty}: Cyclone 11 wrote XCDR2");
    blocking(move || peer.expect("done")).await;
    s.close().await;
}

/// Courier writes three samples of an appendable or mutable type (XCDR2
/// by default); Cyclone 11's reader accepts XCDR2 only and takes them.
async fn xcdr2_courier_to_cyclone11<M: Three>(ty: &str, domain: u32) {
    let s = session(domain).await;
    let p = s.publisher::<M>("x2").build().await.unwrap();
    let d = domain_arg(domain);
    let mut peer = Peer::start(
        Vendor::Cyclone11,
        &[
            "--domain",
            &d,
            "--topic",
            "x2",
            "--type",
            ty,
            "--sub",
            "--reliable",
            "--representation",
            "xcdr2",
            "--count",
            "3",
            "--timeout-s",
            "20",
        ],
    );
    common::await_handlers(&s, "x2", 1).await;
    let mut peer = blocking(move || {
        peer.expect("matched 1");
        peer
    })
    .await;
    for seq in 1..=3u32 {
        p.publish(&M::make(9, seq, &format!("c-{seq}")))
            .await
            .unwrap();
    }
    let got = blocking(move || (0..3).map(|_| peer.expect("sample ")).collect::<Vec<_>>()).await;
    let want: Vec<String> = (1..=3)
        .map(|seq| format!("sample 9 {seq} c-{seq}"))
        .collect();
    assert_eq!(got, want, "{ty}");
    s.close().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn appendable_xcdr2_cyclone11_to_courier() {
    xcdr2_cyclone11_to_courier::<Appendable>("appendable", [0x00, 0x09], 1).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn mutable_xcdr2_cyclone11_to_courier() {
    xcdr2_cyclone11_to_courier::<Mutable>("mutable", [0x00, 0x0b], 2).await;
}

/// Type evolution (XTypes): Cyclone 11 writes an older version of the
/// type, without its last member `text`; Courier's reader of the newer
/// version takes the samples with `text` at its default, "" (it refused
/// mutable ones with `MissingMember`, and failed appendable ones at the
/// end of the data).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn appendable_older_version_from_cyclone11_gets_defaults() {
    xcdr2_cyclone11_version_to_courier::<Appendable>("appendable_v1", "", [0x00, 0x09], 18).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn mutable_older_version_from_cyclone11_gets_defaults() {
    xcdr2_cyclone11_version_to_courier::<Mutable>("mutable_v1", "", [0x00, 0x0b], 19).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn appendable_xcdr2_courier_to_cyclone11() {
    xcdr2_courier_to_cyclone11::<Appendable>("appendable", 3).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn mutable_xcdr2_courier_to_cyclone11() {
    xcdr2_courier_to_cyclone11::<Mutable>("mutable", 4).await;
}

// ---------------------------------------------------------------------------
// Sequences and arrays of enums (XCDR2 DHEADER) with Cyclone DDS 11

/// `enum courier::test::Color { RED, GREEN, BLUE }`
#[derive(IpcMessage, Debug, Clone, Copy, PartialEq)]
#[ipc(type_name = "courier::test::Color")]
enum Color {
    Red,
    Green,
    Blue,
}

impl Color {
    fn of(n: u32) -> Color {
        [Color::Red, Color::Green, Color::Blue][(n % 3) as usize]
    }

    /// The enumerator's IDL name, as the peer prints it.
    fn name(self) -> &'static str {
        match self {
            Color::Red => "RED",
            Color::Green => "GREEN",
            Color::Blue => "BLUE",
        }
    }
}

/// `@final struct courier::test::Colors { @key int32 id; uint32 seq;
/// sequence<Color> colors; Color pair[2]; string text; }`: XCDR2 puts a
/// `DHEADER` before `colors` and before `pair` (an enum is no CDR
/// primitive), and `text` comes after them.
#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "courier::test::Colors")]
struct Colors {
    #[ipc(key)]
    id: i32,
    seq: u32,
    colors: Vec<Color>,
    pair: [Color; 2],
    text: String,
}

impl Colors {
    /// Sample `seq` as `cyclone11_peer.py --type colors` makes it: `seq %
    /// 4` colors (0 to 3, so one is empty) and a pair, both from `seq`.
    fn make(id: i32, seq: u32, text: &str) -> Colors {
        Colors {
            id,
            seq,
            colors: (0..seq % 4).map(|i| Color::of(seq + i)).collect(),
            pair: [Color::of(seq), Color::of(2 * seq + 1)],
            text: text.into(),
        }
    }
}

/// The peer's colors or pair: enumerator names joined by commas, `""`
/// for none.
fn color_names(v: &[Color]) -> String {
    if v.is_empty() {
        return "\"\"".into();
    }
    v.iter().map(|c| c.name()).collect::<Vec<_>>().join(",")
}

/// Samples of `Colors` for seq 1 to 4: one with an empty sequence, and
/// sequences of one to three enums.
const COLORS_COUNT: u32 = 4;

/// Courier writes `Colors` in XCDR2; Cyclone 11's reader (XCDR2 only)
/// takes every sample and prints each member, checked one by one. Courier
/// wrote no DHEADER before the sequence and the array of enums, and the
/// reader took no sample.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn enum_sequence_and_array_xcdr2_courier_to_cyclone11() {
    let domain = 21;
    let s = session(domain).await;
    let p = s
        .publisher::<Colors>("colors")
        .data_representation(courier::DataRepresentation::Xcdr2)
        .build()
        .await
        .unwrap();
    let d = domain_arg(domain);
    let n = COLORS_COUNT.to_string();
    let mut peer = Peer::start(
        Vendor::Cyclone11,
        &[
            "--domain",
            &d,
            "--topic",
            "colors",
            "--type",
            "colors",
            "--sub",
            "--reliable",
            "--representation",
            "xcdr2",
            "--count",
            &n,
            "--timeout-s",
            "20",
        ],
    );
    common::await_handlers(&s, "colors", 1).await;
    let mut peer = blocking(move || {
        peer.expect("matched 1");
        peer
    })
    .await;
    let sent: Vec<Colors> = (1..=COLORS_COUNT)
        .map(|seq| Colors::make(9, seq, &format!("c-{seq}")))
        .collect();
    for v in &sent {
        p.publish(v).await.unwrap();
    }
    let got = blocking(move || {
        (0..COLORS_COUNT)
            .map(|_| peer.expect("sample "))
            .collect::<Vec<_>>()
    })
    .await;
    for (line, v) in got.iter().zip(&sent) {
        let f: Vec<&str> = line.split(' ').collect();
        assert_eq!(
            f.len(),
            6,
            "{line}: sample <id> <seq> <text> <colors> <pair>"
        );
        assert_eq!(f[1], v.id.to_string(), "id: {line}");
        assert_eq!(f[2], v.seq.to_string(), "seq: {line}");
        assert_eq!(f[3], v.text, "text: {line}");
        assert_eq!(f[4], color_names(&v.colors), "colors: {line}");
        assert_eq!(f[5], color_names(&v.pair), "pair: {line}");
    }
    s.close().await;
}

/// Cyclone 11 writes `Colors` in XCDR2 (`CDR2_LE`); Courier's subscriber,
/// accepting XCDR2 only, reads every member as written. Courier read the
/// DHEADER before the sequence as its count, and took no sample.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn enum_sequence_and_array_xcdr2_cyclone11_to_courier() {
    let domain = 22;
    let s = session(domain).await;
    let mut sub = s
        .subscriber::<Colors>("colors")
        .data_representation(&[courier::DataRepresentation::Xcdr2])
        .build()
        .await
        .unwrap();
    let mut raw = s.subscribe_raw("colors").await.unwrap();
    let d = domain_arg(domain);
    let n = COLORS_COUNT.to_string();
    let mut peer = Peer::start(
        Vendor::Cyclone11,
        &[
            "--domain",
            &d,
            "--topic",
            "colors",
            "--type",
            "colors",
            "--pub",
            "--reliable",
            "--representation",
            "xcdr2",
            "--count",
            &n,
            "--keys",
            "5",
            "--wait-match",
            "1",
            "--settle-ms",
            "300",
            "--text",
            "c11",
            "--linger-ms",
            "300",
            "--timeout-s",
            "20",
        ],
    );
    for seq in 1..=COLORS_COUNT {
        let v = next(&mut sub).await.unwrap().value;
        let want = Colors::make(5, seq, &format!("c11-{seq}"));
        assert_eq!(v.id, want.id, "id of sample {seq}");
        assert_eq!(v.seq, want.seq, "seq of sample {seq}");
        assert_eq!(v.colors, want.colors, "colors of sample {seq}");
        assert_eq!(v.pair, want.pair, "pair of sample {seq}");
        assert_eq!(v.text, want.text, "text of sample {seq}");
    }
    let header = tokio::time::timeout(T, async {
        loop {
            if let Some(s) = raw.try_recv() {
                return [s.data[0], s.data[1]];
            }
            tokio::time::sleep(Duration::from_millis(5)).await;
        }
    })
    .await
    .expect("a raw sample in time");
    assert_eq!(header, [0x00, 0x07], "CDR2_LE: Cyclone 11 wrote XCDR2");
    blocking(move || peer.expect("done")).await;
    s.close().await;
}

// ---------------------------------------------------------------------------
// Disposes every peer reads

/// Courier writes instances `a` and `b`, disposes `a`, then closes the
/// publisher, which disposes `b` (autodispose); the peer, a reliable
/// subscriber, must see both samples and both instances disposed — on the
/// instance it saw alive (Fast DDS runs `--strict-instances`: a dispose
/// that lands on an instance of its own fails).
async fn dispose_seen_by<K: IpcMessage + Send + Sync + 'static>(
    vendor: Vendor,
    ty: &str,
    make: fn(&str, u32) -> K,
    keys: [&str; 2],
    domain: u32,
) {
    let s = session(domain).await;
    let p = s.publisher::<K>("inst").build().await.unwrap();
    let d = domain_arg(domain);
    let mut args = vec![
        "--domain",
        &d,
        "--topic",
        "inst",
        "--type",
        ty,
        "--sub",
        "--reliable",
        "--count",
        "2",
        "--disposed",
        "2",
        "--timeout-s",
        "20",
    ];
    if vendor == Vendor::FastDds {
        args.push("--strict-instances");
    }
    let mut peer = Peer::start(vendor, &args);
    common::await_handlers(&s, "inst", 1).await;
    let peer = blocking(move || {
        peer.expect("matched 1");
        peer
    })
    .await;
    p.publish(&make(keys[0], 1)).await.unwrap();
    p.publish(&make(keys[1], 2)).await.unwrap();
    p.dispose(&make(keys[0], 0)).await.unwrap();
    drop(p);
    let mut lines = peer_lines(peer).await;
    lines.sort();
    let mut want = vec![
        format!("disposed {}", keys[0]),
        format!("disposed {}", keys[1]),
        format!("sample {} 1 c-1", keys[0]),
        format!("sample {} 2 c-2", keys[1]),
    ];
    want.sort();
    assert_eq!(lines, want, "{vendor:?} {ty}");
    s.close().await;
}

/// A publisher of more live instances than its history holds
/// (`max_history`, 4096) closes right after writing them: a Cyclone 11
/// reader in another process, slower than Courier, must still see every
/// instance disposed. The disposes wait for room in the history; a full
/// keyed keep-last history dropped its oldest unacknowledged changes.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_instance_of_a_closing_publisher_is_disposed_for_a_slow_cyclone11_reader() {
    const N: u32 = 6000;
    let domain = 20;
    let s = session(domain).await;
    let p = s.publisher::<Keyed>("many").build().await.unwrap();
    let d = domain_arg(domain);
    let n = N.to_string();
    let peer = Peer::start(
        Vendor::Cyclone11,
        &[
            "--domain",
            &d,
            "--topic",
            "many",
            "--type",
            "keyed",
            "--sub",
            "--reliable",
            "--count",
            &n,
            "--disposed",
            &n,
            "--timeout-s",
            "60",
        ],
    );
    common::await_handlers(&s, "many", 1).await;
    for id in 0..N {
        p.publish(&keyed(&id.to_string(), 1)).await.unwrap();
    }
    drop(p);
    let lines = peer_lines(peer).await;
    let count = |prefix: &str| lines.iter().filter(|l| l.starts_with(prefix)).count();
    assert_eq!(
        (count("sample "), count("disposed ")),
        (N as usize, N as usize),
        "{:?}",
        lines
            .iter()
            .filter(|l| !l.starts_with("sample "))
            .take(5)
            .collect::<Vec<_>>()
    );
    s.close().await;
}

fn keyed(k: &str, seq: u32) -> Keyed {
    Keyed {
        id: k.parse().expect("an int key"),
        seq,
        text: format!("c-{seq}"),
    }
}

fn strkeyed(k: &str, seq: u32) -> StrKeyed {
    StrKeyed {
        name: k.into(),
        seq,
        text: format!("c-{seq}"),
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn int_keyed_dispose_seen_by_cyclone() {
    dispose_seen_by(Vendor::Cyclone, "keyed", keyed, ["41", "42"], 10).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn int_keyed_dispose_seen_by_fastdds() {
    dispose_seen_by(Vendor::FastDds, "keyed", keyed, ["41", "42"], 11).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn int_keyed_dispose_seen_by_cyclone11() {
    dispose_seen_by(Vendor::Cyclone11, "keyed", keyed, ["41", "42"], 12).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn string_keyed_dispose_seen_by_cyclone() {
    dispose_seen_by(Vendor::Cyclone, "strkeyed", strkeyed, ["ab", "robot-7"], 13).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn string_keyed_dispose_seen_by_fastdds() {
    dispose_seen_by(Vendor::FastDds, "strkeyed", strkeyed, ["ab", "robot-7"], 14).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn string_keyed_dispose_seen_by_cyclone11() {
    dispose_seen_by(
        Vendor::Cyclone11,
        "strkeyed",
        strkeyed,
        ["ab", "robot-7"],
        15,
    )
    .await;
}

/// Cyclone 11 writes three instances and disposes each; a Courier
/// subscriber with instance events gets every change with its key decoded.
/// Cyclone 11 sends no key hash: the reader computes it from the serialized
/// key (without that, the three counted as one instance, and the second
/// and third disposes were taken for repeats of the first and dropped).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn cyclone11_string_keyed_dispose_reaches_courier_with_its_key() {
    let s = session(16).await;
    let mut sub = s
        .subscriber::<StrKeyed>("inst")
        .with_instances()
        .build()
        .await
        .unwrap();
    let d = domain_arg(16);
    let keys = ["robot-9", "robot-8", "robot-7"];
    let mut peer = Peer::start(
        Vendor::Cyclone11,
        &[
            "--domain",
            &d,
            "--topic",
            "inst",
            "--type",
            "strkeyed",
            "--pub",
            "--reliable",
            "--count",
            "3",
            "--keys",
            &keys.join(","),
            "--dispose",
            "--wait-match",
            "1",
            "--settle-ms",
            "300",
            "--linger-ms",
            "300",
            "--timeout-s",
            "20",
        ],
    );
    let mut samples = Vec::new();
    let mut disposed = Vec::new();
    while disposed.len() < keys.len() {
        match next(&mut sub).await.unwrap() {
            courier::Received::Sample(v) => samples.push(v.value.name),
            courier::Received::Instance(c) => {
                assert_eq!(c.state, courier::InstanceState::Disposed);
                let key = c.key.clone().expect("the key, decoded");
                // computed by the reader: Cyclone 11 sent none
                let want = courier::key_hash(&StrKeyed {
                    name: key.clone(),
                    seq: 0,
                    text: String::new(),
                });
                assert_eq!(c.key_hash, Some(want), "{c:?}");
                disposed.push(key);
            }
        }
    }
    assert_eq!(samples, keys);
    assert_eq!(disposed, keys);
    blocking(move || peer.expect("done")).await;
    // the stream goes on
    assert!(sub.next().now_or_never().is_none());
    s.close().await;
}
