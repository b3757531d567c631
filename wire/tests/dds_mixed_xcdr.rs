//! One keyed topic, two writers of different XCDR versions: a reader sees
//! one instance however each writer names it.
//!
//! A writer's key hash is in the XCDR version of its data (Cyclone DDS and
//! Fast DDS compute it so), and for some keys the XCDR1 and XCDR2 hashes
//! of one instance differ: `@key long id; @key long long stamp;` is `id`,
//! 4 bytes of padding, `stamp` in XCDR1 and `id`, `stamp`, 4 bytes of the
//! hash's padding in XCDR2; with a third `@key long` the XCDR1 key can
//! take 20 bytes, so its hash is an MD5 digest, while the XCDR2 one (16
//! bytes) is the key itself. The simulated writers here do what the real
//! ones do: node 0 writes XCDR1 and sends its hash with every sample and
//! dispose (Cyclone DDS 0.10 with `GenerateKeyhash`, Fast DDS 2, whose
//! disposes carry only the hash), node 1 writes XCDR2 with or without a
//! hash (Courier asked for XCDR2, Cyclone DDS 11). The reader, on node 2,
//! is told the type's keys ([`Domain::set_instance_keys`]), as the SDK's
//! typed subscriptions do.
//!
//! Deterministic: a lossless simulated network, simulated time, and a
//! marker sample (reliable writers deliver in order) before each count.

use std::borrow::Cow;
use std::fmt::Debug;
use std::time::Duration;

use courier_wire::cdr::{self, DecodeError, Encoding, Endianness, Extensibility, MaxSize, Version};
use courier_wire::dds::{Domain, Event, InstanceKeys, ReaderId, WriterId};
use courier_wire::rtps::discovery::{Duration as RtpsDuration, EndpointQos, History, Reliability};
use courier_wire::rtps::participant::{
    guid_prefix, Change, ChangeKind, Config, EndpointConfig, KeyHash, ReceivedSample,
};
use courier_wire::sim::{self, Faults};
use courier_wire::{ipc, key_hash_in, IpcMessage};

const LO: [u8; 4] = [127, 0, 0, 1];

type Net = sim::Net<Domain>;

/// A final struct whose key members come first, all primitive, then
/// the others: `IpcMessage` by hand, as `#[derive(IpcMessage)]` writes it
/// (this crate's tests cannot use the derive).
macro_rules! keyed {
    ($name:ident { $($k:ident: $kt:ty = $kid:expr),+ ; $($f:ident: $ft:ty = $fid:expr),* }) => {
        #[derive(Debug, Clone, PartialEq)]
        struct $name {
            $($k: $kt,)+
            $($f: $ft,)*
        }

        impl IpcMessage for $name {
            const FORMAT: &'static str = "{int}";
            const TYPE_NAME: &'static str = concat!("courier::test::", stringify!($name));
            const IPC_MIN_SIZE: usize = 0;
            const CDR_MIN_SIZE: usize = 1;
            const KEYS: &'static [&'static str] = &[$(stringify!($k)),+];
            const CDR_KEY_MAX_SIZE: MaxSize =
                MaxSize::EMPTY$(.then(<$kt as IpcMessage>::CDR_MAX_SIZE))+;
            type Key = ($($kt,)+);

            fn ipc_encode(&self, _: &mut ipc::Writer) {}
            fn ipc_decode(_: &mut ipc::Reader<'_>) -> Result<Self, ipc::DecodeError> {
                Err(ipc::DecodeError::Format("CDR-only test type".into()))
            }
            fn cdr_encode(&self, w: &mut cdr::Writer) {
                let s = w.begin_struct(Extensibility::Final);
                $(
                    let m = s.begin_member(w, $kid, false);
                    self.$k.cdr_encode(w);
                    s.end_member(w, m);
                )+
                $(
                    let m = s.begin_member(w, $fid, false);
                    self.$f.cdr_encode(w);
                    s.end_member(w, m);
                )*
                s.end(w);
            }
            fn cdr_decode(r: &mut cdr::Reader<'_>) -> Result<Self, DecodeError> {
                let s = r.begin_struct(Extensibility::Final)?;
                $( let $k = <$kt as IpcMessage>::cdr_decode(r)?; )+
                $( let $f = <$ft as IpcMessage>::cdr_decode(r)?; )*
                s.end(r)?;
                Ok($name { $($k,)+ $($f,)* })
            }
            fn cdr_encode_key(&self, w: &mut cdr::Writer) {
                Self::cdr_encode_key_value(&($(self.$k,)+), w);
            }
            fn cdr_decode_key(r: &mut cdr::Reader<'_>) -> Result<Self::Key, DecodeError> {
                let s = r.begin_struct(Extensibility::Final)?;
                $( let $k = <$kt as IpcMessage>::cdr_decode(r)?; )+
                s.end(r)?;
                Ok(($($k,)+))
            }
            fn cdr_encode_key_value(key: &Self::Key, w: &mut cdr::Writer) -> bool {
                let ($($k,)+) = key;
                let s = w.begin_struct(Extensibility::Final);
                $(
                    let m = s.begin_member(w, $kid, false);
                    $k.cdr_encode(w);
                    s.end_member(w, m);
                )+
                s.end(w);
                true
            }
        }
    };
}

// `courier::test::Stamped` of tests/peers/rtps/types.idl (without its text)
keyed!(Stamped { id: i32 = 0, stamp: i64 = 1; seq: u32 = 2 });
// a third key member: the XCDR1 key can take 20 bytes (MD5), XCDR2 16
keyed!(Triple { id: i32 = 0, stamp: i64 = 1, extra: i32 = 2; seq: u32 = 3 });

/// The test types: instance `id`, sample `seq`.
trait Inst: IpcMessage + Clone + Debug {
    fn make(id: i32, seq: u32) -> Self;
    fn seq(&self) -> u32;
}

impl Inst for Stamped {
    fn make(id: i32, seq: u32) -> Self {
        let stamp = 0x0102_0304_0506_0708 + i64::from(id);
        Stamped { id, stamp, seq }
    }
    fn seq(&self) -> u32 {
        self.seq
    }
}

impl Inst for Triple {
    fn make(id: i32, seq: u32) -> Self {
        let stamp = 0x0102_0304_0506_0708 + i64::from(id);
        Triple {
            id,
            stamp,
            extra: -id,
            seq,
        }
    }
    fn seq(&self) -> u32 {
        self.seq
    }
}

/// How the reader is told its type's instances.
fn keys<T: Inst>() -> InstanceKeys {
    InstanceKeys::of::<T>()
}

/// The instance of the test.
const ID: i32 = 7;
/// Another instance: marker samples.
const MARK: i32 = 8;

fn ms(n: u64) -> Duration {
    Duration::from_millis(n)
}

fn config(i: usize) -> Config {
    Config::udpv4(0, i as u32, guid_prefix([i as u8 + 1; 10]), LO)
        .unwrap()
        .with_unicast_peers(&[LO], 9)
}

/// Nodes 0 (XCDR1 writer), 1 (XCDR2 writer), 2 (reader), lossless.
fn new_net(seed: u64) -> Net {
    let mut net = Net::new(seed, Faults::none());
    for i in 0..3 {
        let d = Domain::new(config(i), net.now(), net.wall());
        net.add(d);
    }
    net
}

/// A simulated writer: its node, its data's version, whether it sends
/// `PID_KEY_HASH`.
struct W {
    node: usize,
    id: WriterId,
    version: Version,
    sends_hash: bool,
}

/// The topic's reader on node 2.
struct R {
    id: ReaderId,
}

fn code(v: Version) -> i16 {
    match v {
        Version::Xcdr1 => 0,
        Version::Xcdr2 => 2,
    }
}

/// Writer QoS: reliable keep-all, of the version's representation.
fn writer_qos(version: Version, strength: Option<i32>, deadline: Option<Duration>) -> EndpointQos {
    let mut q = EndpointQos::writer_default();
    q.reliability = Reliability::Reliable(RtpsDuration::ZERO);
    q.history = History::KeepAll;
    q.data_representation = vec![code(version)];
    if let Some(s) = strength {
        q.exclusive_ownership = true;
        q.ownership_strength = s;
    }
    if let Some(d) = deadline {
        q.deadline = RtpsDuration::from_std(d);
    }
    q
}

/// Node 0 writes XCDR1, node 1 XCDR2.
const BOTH: [Version; 2] = [Version::Xcdr1, Version::Xcdr2];

/// What the two writers and the reader are: the reader's ownership is
/// exclusive when the writers have strengths.
struct Setup {
    /// What nodes 0 and 1 write (XCDR1 and XCDR2 but in one test).
    versions: [Version; 2],
    strengths: Option<[i32; 2]>,
    deadline: Option<Duration>,
    xcdr2_sends_hash: bool,
}

/// The writers (XCDR1, XCDR2) and the reader of `T`, matched both ways.
fn start<T: Inst>(net: &mut Net, s: &Setup) -> ([W; 2], R) {
    start_with::<T>(net, s, keys::<T>())
}

fn start_with<T: Inst>(net: &mut Net, s: &Setup, keys: InstanceKeys) -> ([W; 2], R) {
    let topic = "mixed";
    let now = net.now();
    let mut ws = Vec::new();
    for (node, version) in s.versions.into_iter().enumerate() {
        let q = writer_qos(version, s.strengths.map(|st| st[node]), s.deadline);
        let cfg = EndpointConfig::writer(topic, T::TYPE_NAME)
            .keyed(true)
            .qos(q);
        let id = net.node(node).create_writer(cfg, now).unwrap();
        let sends_hash = version == Version::Xcdr1 || s.xcdr2_sends_hash;
        ws.push(W {
            node,
            id,
            version,
            sends_hash,
        });
    }
    let mut q = EndpointQos::reader_default();
    q.reliability = Reliability::Reliable(RtpsDuration::ZERO);
    q.history = History::KeepAll;
    q.data_representation = vec![0, 2];
    q.exclusive_ownership = s.strengths.is_some();
    if let Some(d) = s.deadline {
        q.deadline = RtpsDuration::from_std(d);
    }
    let cfg = EndpointConfig::reader(topic, T::TYPE_NAME)
        .keyed(true)
        .qos(q);
    let r = net.node(2).create_reader(cfg, now).unwrap();
    assert!(net.node(2).set_instance_keys(r, keys));
    let matched = |n: &Net| {
        let readers = n.hosts[2]
            .events
            .iter()
            .filter(|e| matches!(e, Event::ReaderMatched { reader, .. } if *reader == r))
            .count();
        let writers = (0..2).all(|i| {
            n.has(
                i,
                |e| matches!(e, Event::WriterMatched { writer, .. } if *writer == ws[i].id),
            )
        });
        readers == 2 && writers
    };
    assert!(net.run_until(Duration::from_secs(10), matched), "matched");
    let ws: [W; 2] = ws.try_into().ok().unwrap();
    (ws, R { id: r })
}

fn encoding(v: Version) -> Encoding {
    Encoding::new(v, Endianness::Little)
}

fn hash_of<T: Inst>(w: &W, v: &T) -> KeyHash {
    KeyHash(key_hash_in(v, w.version))
}

/// `w` writes sample `seq` of instance `id`.
fn write<T: Inst>(net: &mut Net, w: &W, id: i32, seq: u32) {
    let v = T::make(id, seq);
    let mut c = Change::alive_owned(cdr::to_vec(&v, encoding(w.version)));
    if w.sends_hash {
        c = c.with_key_hash(hash_of(w, &v));
    }
    let now = net.now();
    net.node(w.node).write(w.id, c, now).unwrap();
}

/// `w` disposes instance `id` with its key hash only (Fast DDS).
fn dispose_hash_only<T: Inst>(net: &mut Net, w: &W, id: i32) {
    assert!(w.sends_hash);
    let h = hash_of(w, &T::make(id, 0));
    let now = net.now();
    net.node(w.node)
        .write(w.id, Change::dispose(&[], h), now)
        .unwrap();
}

/// `w` disposes instance `id` with its serialized key (and its hash if it
/// sends hashes: Cyclone DDS).
fn dispose_with_key<T: Inst>(net: &mut Net, w: &W, id: i32) {
    let v = T::make(id, 0);
    let key = cdr::key_to_vec(&v, encoding(w.version));
    let c = Change {
        kind: ChangeKind::Disposed,
        data: Cow::Owned(key),
        key_hash: w.sends_hash.then(|| hash_of(w, &v)),
        source_timestamp: None,
        related_sample_identity: None,
    };
    let now = net.now();
    net.node(w.node).write(w.id, c, now).unwrap();
}

/// What reader `r` took: live samples as (id, seq), changes as their kind
/// and the key hash delivered with them.
#[derive(Debug, Clone, PartialEq)]
enum Got {
    Sample(i32, u32),
    Change(ChangeKind, Option<KeyHash>),
}

fn got<T: Inst>(net: &Net, r: &R) -> Vec<Got> {
    net.hosts[2]
        .events
        .iter()
        .filter_map(|e| match e {
            Event::Sample { reader, sample } if *reader == r.id => Some(taken::<T>(sample)),
            _ => None,
        })
        .collect()
}

fn taken<T: Inst>(s: &ReceivedSample) -> Got {
    if s.kind != ChangeKind::Alive {
        return Got::Change(s.kind, s.key_hash);
    }
    let v: T = cdr::from_slice(s.data()).expect("a test sample");
    let hash = key_hash_in(&v, Version::Xcdr1);
    let id = if hash == key_hash_in(&T::make(ID, 0), Version::Xcdr1) {
        ID
    } else {
        MARK
    };
    Got::Sample(id, v.seq())
}

/// Runs until reader `r` has taken `n` changes.
fn until_taken<T: Inst>(net: &mut Net, r: &R, n: usize) {
    let ok = net.run_until(Duration::from_secs(10), |net| got::<T>(net, r).len() >= n);
    assert!(ok, "{n} taken: {:?}", got::<T>(net, r));
}

/// The two versions' hashes of the test instance differ, and for `Triple`
/// the XCDR1 one is a digest: what makes these tests mean something.
#[test]
fn the_two_versions_name_the_instances_apart() {
    let s = Stamped::make(ID, 0);
    assert_eq!(
        key_hash_in(&s, Version::Xcdr1),
        [0, 0, 0, 7, 0, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 15]
    );
    assert_eq!(
        key_hash_in(&s, Version::Xcdr2),
        [0, 0, 0, 7, 1, 2, 3, 4, 5, 6, 7, 15, 0, 0, 0, 0]
    );
    let t = Triple::make(ID, 0);
    let x2 = key_hash_in(&t, Version::Xcdr2);
    assert_eq!(x2[..12], [0, 0, 0, 7, 1, 2, 3, 4, 5, 6, 7, 15]);
    assert_eq!(x2[12..], (-7i32).to_be_bytes());
    let x1 = key_hash_in(&t, Version::Xcdr1);
    assert_ne!(x1, x2);
    assert_ne!(x1[..4], [0, 0, 0, 7], "XCDR1: an MD5 digest");
}

/// Exclusive ownership: the weaker writer's sample of the instance the
/// stronger one owns is dropped, whichever version each writes (and
/// whichever wrote first).
#[test]
fn the_weaker_writer_of_the_other_version_does_not_take_the_instance() {
    for (seed, strong) in [(1, 0usize), (2, 1)] {
        let mut net = new_net(seed);
        let mut strengths = [1, 1];
        strengths[strong] = 10;
        let setup = Setup {
            versions: BOTH,
            strengths: Some(strengths),
            deadline: None,
            xcdr2_sends_hash: false,
        };
        let (ws, r) = start::<Stamped>(&mut net, &setup);
        let weak = 1 - strong;
        write::<Stamped>(&mut net, &ws[strong], ID, 1);
        until_taken::<Stamped>(&mut net, &r, 1);
        write::<Stamped>(&mut net, &ws[weak], ID, 2);
        // the marker comes after the weak sample (one writer, in order)
        write::<Stamped>(&mut net, &ws[weak], MARK, 3);
        until_taken::<Stamped>(&mut net, &r, 2);
        net.run_for(ms(100));
        assert_eq!(
            got::<Stamped>(&net, &r),
            [Got::Sample(ID, 1), Got::Sample(MARK, 3)],
            "strong writer: {:?}",
            ws[strong].version
        );
    }
}

/// Both write the instance; the writer of version `second` disposes it
/// with its key hash alone; then the other disposes it too, which
/// changes nothing (the instance is disposed already) and is not
/// delivered. The dispose delivered carries the hash as its writer sent
/// it (what the key is read back from).
fn a_hash_only_dispose_disposes_the_other_writers_instance<T: Inst>(
    seed: u64,
    first: Version,
    xcdr2_sends_hash: bool,
) {
    let mut net = new_net(seed);
    let setup = Setup {
        versions: BOTH,
        strengths: None,
        deadline: None,
        xcdr2_sends_hash,
    };
    let (ws, r) = start::<T>(&mut net, &setup);
    let (a, b) = match first {
        Version::Xcdr1 => (&ws[0], &ws[1]),
        Version::Xcdr2 => (&ws[1], &ws[0]),
    };
    write::<T>(&mut net, a, ID, 1);
    until_taken::<T>(&mut net, &r, 1);
    write::<T>(&mut net, b, ID, 2);
    until_taken::<T>(&mut net, &r, 2);
    dispose_hash_only::<T>(&mut net, b, ID);
    until_taken::<T>(&mut net, &r, 3);
    dispose_with_key::<T>(&mut net, a, ID);
    write::<T>(&mut net, a, MARK, 3);
    until_taken::<T>(&mut net, &r, 4);
    net.run_for(ms(100));
    let sent = hash_of(b, &T::make(ID, 0));
    assert_eq!(
        got::<T>(&net, &r),
        [
            Got::Sample(ID, 1),
            Got::Sample(ID, 2),
            Got::Change(ChangeKind::Disposed, Some(sent)),
            Got::Sample(MARK, 3),
        ],
        "{} first {first:?}, then a hash-only dispose",
        T::TYPE_NAME
    );
}

/// `Stamped`: both versions' hashes hold the key (padded).
#[test]
fn a_padded_hash_only_dispose_of_either_version_disposes_the_instance() {
    // Cyclone 11 (no hash, XCDR2) first, Fast DDS's dispose (XCDR1)
    a_hash_only_dispose_disposes_the_other_writers_instance::<Stamped>(3, Version::Xcdr2, false);
    // XCDR1 first, a hash-only XCDR2 dispose
    a_hash_only_dispose_disposes_the_other_writers_instance::<Stamped>(4, Version::Xcdr1, true);
}

/// `Triple`: the XCDR1 hash is an MD5 digest, the XCDR2 one the key.
#[test]
fn a_digest_hash_only_dispose_disposes_the_instance() {
    // XCDR2 first: the XCDR1 writer's digest is known from its sample
    a_hash_only_dispose_disposes_the_other_writers_instance::<Triple>(5, Version::Xcdr2, true);
    a_hash_only_dispose_disposes_the_other_writers_instance::<Triple>(6, Version::Xcdr2, false);
    // XCDR1 first: the XCDR2 hash holds the key, whose XCDR1 digest is computed
    a_hash_only_dispose_disposes_the_other_writers_instance::<Triple>(7, Version::Xcdr1, true);
}

/// The instances the reader's deadline missed, from `from` on.
fn missed(net: &Net, r: &R, from: usize) -> Vec<KeyHash> {
    let mut v: Vec<KeyHash> = net.hosts[2].events[from..]
        .iter()
        .filter_map(|e| match e {
            Event::DeadlineMissed {
                reader, instance, ..
            } if *reader == r.id => Some(*instance),
            _ => None,
        })
        .collect();
    v.sort();
    v.dedup();
    v
}

/// A deadline counts one instance for the two writers, and a hash-only
/// dispose from one ends it for both.
#[test]
fn a_deadline_is_per_instance_across_versions() {
    let mut net = new_net(8);
    let setup = Setup {
        versions: BOTH,
        strengths: None,
        deadline: Some(ms(100)),
        xcdr2_sends_hash: false,
    };
    let (ws, r) = start::<Stamped>(&mut net, &setup);
    write::<Stamped>(&mut net, &ws[1], ID, 1);
    until_taken::<Stamped>(&mut net, &r, 1);
    write::<Stamped>(&mut net, &ws[0], ID, 2);
    until_taken::<Stamped>(&mut net, &r, 2);
    let from = net.hosts[2].events.len();
    net.run_for(ms(1000));
    assert_eq!(missed(&net, &r, from).len(), 1, "one instance missed");
    dispose_hash_only::<Stamped>(&mut net, &ws[0], ID);
    until_taken::<Stamped>(&mut net, &r, 3);
    let from = net.hosts[2].events.len();
    net.run_for(ms(1000));
    assert_eq!(
        missed(&net, &r, from),
        [],
        "the disposed instance has no deadline"
    );
}

thread_local! {
    /// Calls of the counting key functions on this thread.
    static CALLS: std::cell::Cell<u32> = const { std::cell::Cell::new(0) };
}

fn count() {
    CALLS.with(|c| c.set(c.get() + 1));
}

/// `Stamped`'s keys, counted.
fn counted() -> InstanceKeys {
    InstanceKeys {
        hash_in: |data, key_only, v| {
            count();
            cdr::key_hash_of_payload_in::<Stamped>(data, key_only, v)
        },
        translate: |h, from, to| {
            count();
            cdr::translate_key_hash::<Stamped>(h, from, to)
        },
    }
}

/// Writers of one version (both XCDR1, sending their hashes): the reader
/// names instances by the hashes they send, decoding and hashing nothing,
/// and still one dispose disposes the instance for both.
#[test]
fn writers_of_one_version_cost_no_hashing() {
    let mut net = new_net(9);
    let setup = Setup {
        versions: [Version::Xcdr1; 2],
        strengths: None,
        deadline: None,
        xcdr2_sends_hash: false,
    };
    let (ws, r) = start_with::<Stamped>(&mut net, &setup, counted());
    let before = CALLS.with(std::cell::Cell::get);
    write::<Stamped>(&mut net, &ws[0], ID, 1);
    until_taken::<Stamped>(&mut net, &r, 1);
    write::<Stamped>(&mut net, &ws[1], ID, 2);
    until_taken::<Stamped>(&mut net, &r, 2);
    dispose_hash_only::<Stamped>(&mut net, &ws[1], ID);
    until_taken::<Stamped>(&mut net, &r, 3);
    dispose_with_key::<Stamped>(&mut net, &ws[0], ID);
    write::<Stamped>(&mut net, &ws[0], MARK, 3);
    until_taken::<Stamped>(&mut net, &r, 4);
    let sent = hash_of(&ws[1], &Stamped::make(ID, 0));
    assert_eq!(
        got::<Stamped>(&net, &r),
        [
            Got::Sample(ID, 1),
            Got::Sample(ID, 2),
            Got::Change(ChangeKind::Disposed, Some(sent)),
            Got::Sample(MARK, 3),
        ]
    );
    assert_eq!(
        CALLS.with(std::cell::Cell::get),
        before,
        "no key function called"
    );
}
