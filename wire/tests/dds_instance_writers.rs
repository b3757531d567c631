//! A keyed reader's instances and their writers (DDS 1.4 §2.2.2.5.1,
//! §2.2.3.9.2, §2.2.3.11), as Cyclone DDS 11's reader keeps them:
//!
//! - an instance whose last live writer goes without a word for it —
//!   deleted (Cyclone sends no unregister per instance when a writer
//!   closes), its participant lost, its liveliness lapsed — is
//!   NOT_ALIVE_NO_WRITERS (an `Unregistered` change), unless disposed; a
//!   later sample makes it alive again;
//! - an unregister says so only from the instance's last writer, and
//!   nothing for an instance the reader never saw;
//! - under exclusive ownership only the owner disposes, and a writer whose
//!   liveliness lapsed owns nothing;
//! - a dispose that carries the whole sample (Cyclone's `write_dispose`)
//!   is the sample, then the dispose.
//!
//! Deterministic: a lossless simulated network, simulated time.

use std::borrow::Cow;
use std::time::Duration;

use courier_wire::cdr::{self, DecodeError, Encoding, Endianness, Extensibility, MaxSize, Version};
use courier_wire::dds::{Domain, Event, InstanceKeys, ReaderId, WriterId};
use courier_wire::rtps::discovery::{
    Duration as RtpsDuration, EndpointQos, History, LivelinessKind, Reliability,
};
use courier_wire::rtps::participant::{
    self, guid_prefix, Change, ChangeKind, Config, EndpointConfig, KeyHash,
};
use courier_wire::rtps::Guid;
use courier_wire::sim::{self, Faults};
use courier_wire::{ipc, key_hash_in, IpcMessage};

const LO: [u8; 4] = [127, 0, 0, 1];

type Net = sim::Net<Domain>;

fn ms(n: u64) -> Duration {
    Duration::from_millis(n)
}

fn config(i: usize) -> Config {
    let mut c = Config::udpv4(0, i as u32, guid_prefix([i as u8 + 1; 10]), LO)
        .unwrap()
        .with_unicast_peers(&[LO], 9);
    // a crashed participant is lost after 1 s
    c.lease_duration = Duration::from_secs(1);
    c.announce_period = ms(250);
    c
}

/// `n` domains on a lossless network.
fn new_net(n: usize, seed: u64) -> Net {
    let mut net = Net::new(seed, Faults::none());
    for i in 0..n {
        let d = Domain::new(config(i), net.now(), net.wall());
        net.add(d);
    }
    net
}

fn writer_qos() -> EndpointQos {
    let mut q = EndpointQos::writer_default();
    q.reliability = Reliability::Reliable(RtpsDuration::ZERO);
    q.history = History::KeepAll;
    q
}

fn reader_qos() -> EndpointQos {
    let mut q = EndpointQos::reader_default();
    q.reliability = Reliability::Reliable(RtpsDuration::ZERO);
    q.history = History::KeepAll;
    q
}

fn lease(kind: LivelinessKind, n: u64) -> (LivelinessKind, RtpsDuration) {
    (kind, RtpsDuration::from_std(ms(n)))
}

/// Exclusive ownership with `strength`.
fn owned(mut q: EndpointQos, strength: i32) -> EndpointQos {
    q.exclusive_ownership = true;
    q.ownership_strength = strength;
    q
}

fn writer_with(net: &mut Net, i: usize, topic: &str, q: EndpointQos) -> WriterId {
    let now = net.now();
    let cfg = EndpointConfig::writer(topic, "T").keyed(true).qos(q);
    net.node(i).create_writer(cfg, now).unwrap()
}

fn writer(net: &mut Net, i: usize, topic: &str) -> WriterId {
    writer_with(net, i, topic, writer_qos())
}

fn reader_with(net: &mut Net, i: usize, topic: &str, q: EndpointQos) -> ReaderId {
    let now = net.now();
    let cfg = EndpointConfig::reader(topic, "T").keyed(true).qos(q);
    net.node(i).create_reader(cfg, now).unwrap()
}

fn reader(net: &mut Net, i: usize, topic: &str) -> ReaderId {
    reader_with(net, i, topic, reader_qos())
}

/// Runs until reader `r` on node `i` matched `n` writers.
fn matched(net: &mut Net, i: usize, r: ReaderId, n: usize) {
    let ok = net.run_until(Duration::from_secs(10), |net| {
        net.hosts[i]
            .events
            .iter()
            .filter(|e| matches!(e, Event::ReaderMatched { reader, .. } if *reader == r))
            .count()
            >= n
    });
    assert!(ok, "reader matched {n} writers");
    net.run_for(ms(100));
}

/// The key hash of instance `k`.
fn key(k: u8) -> KeyHash {
    let mut h = [0; 16];
    h[3] = k;
    KeyHash(h)
}

/// A CDR_LE sample holding `n`.
fn sample(n: u32) -> Vec<u8> {
    let mut b = vec![0, 1, 0, 0];
    b.extend_from_slice(&n.to_le_bytes());
    b
}

/// `w` on node `i` writes `n` to instance `k`.
fn write(net: &mut Net, i: usize, w: WriterId, k: u8, n: u32) {
    let now = net.now();
    let c = Change::alive_owned(sample(n)).with_key_hash(key(k));
    net.node(i).write(w, c, now).unwrap();
}

/// `w` on node `i` sends a `kind` change of instance `k` (the key hash only).
fn change(net: &mut Net, i: usize, w: WriterId, k: u8, kind: ChangeKind) {
    let now = net.now();
    let c = Change {
        kind,
        ..Change::dispose(&[], key(k))
    };
    net.node(i).write(w, c, now).unwrap();
}

/// What a reader took.
#[derive(Debug, Clone, PartialEq)]
enum Got {
    /// A sample: instance, value.
    Sample(u8, u32),
    /// An instance change: kind, instance, writer.
    Change(ChangeKind, u8, Guid),
}

/// What reader `r` on node `i` took since the last call.
fn took(net: &mut Net, i: usize, r: ReaderId) -> Vec<Got> {
    net.take_events(i)
        .into_iter()
        .filter_map(|e| match e {
            Event::Sample { reader, sample } if reader == r => {
                let k = sample.key_hash.map_or(0, |h| h.0[3]);
                Some(match sample.kind {
                    ChangeKind::Alive => Got::Sample(
                        k,
                        u32::from_le_bytes(sample.data()[4..8].try_into().unwrap()),
                    ),
                    kind => {
                        assert!(sample.data().is_empty(), "{kind:?} with data");
                        Got::Change(kind, k, sample.writer)
                    }
                })
            }
            _ => None,
        })
        .collect()
}

fn guid(_: &Net, _: usize, w: WriterId) -> Guid {
    w.guid()
}

const NO_WRITERS: ChangeKind = ChangeKind::Unregistered;

/// A writer deleted without unregistering anything (as Cyclone closes
/// one): each instance it was the last writer of is NOT_ALIVE_NO_WRITERS,
/// one it disposed stays disposed, one another writer still writes stays
/// alive; a later sample makes an instance alive again. Before, the
/// instances were forgotten without a word.
#[test]
fn a_deleted_writer_leaves_the_instances_only_it_wrote_without_writers() {
    let mut net = new_net(3, 1);
    let topic = "deleted";
    let r = reader(&mut net, 2, topic);
    let w = writer(&mut net, 0, topic);
    let other = writer(&mut net, 1, topic);
    matched(&mut net, 2, r, 2);
    for k in 1..=4 {
        write(&mut net, 0, w, k, u32::from(k));
    }
    write(&mut net, 1, other, 4, 40);
    net.run_for(ms(100));
    change(&mut net, 0, w, 1, ChangeKind::Disposed);
    net.run_for(ms(100));
    let mut got = took(&mut net, 2, r);
    let wg = guid(&net, 0, w);
    assert_eq!(
        got.split_off(5),
        [Got::Change(ChangeKind::Disposed, 1, wg)],
        "{got:?}"
    );
    let now = net.now();
    assert!(net.node(0).delete_writer(w, now));
    assert!(net.run_until(Duration::from_secs(5), |n| n.has(
        2,
        |e| matches!(e, Event::ReaderUnmatched { writer, .. } if *writer == wg)
    )));
    net.run_for(ms(100));
    assert_eq!(
        took(&mut net, 2, r),
        [
            Got::Change(NO_WRITERS, 2, wg),
            Got::Change(NO_WRITERS, 3, wg)
        ],
        "instances 2 and 3 have no writer left; 1 stays disposed, 4 alive"
    );
    // a sample makes one alive again; the other writer's leaving takes
    // instances 2 and 4 with it
    write(&mut net, 1, other, 2, 20);
    net.run_for(ms(100));
    assert_eq!(took(&mut net, 2, r), [Got::Sample(2, 20)]);
    let og = guid(&net, 1, other);
    let now = net.now();
    assert!(net.node(1).delete_writer(other, now));
    net.run_for(ms(500));
    assert_eq!(
        took(&mut net, 2, r),
        [
            Got::Change(NO_WRITERS, 2, og),
            Got::Change(NO_WRITERS, 4, og)
        ]
    );
}

/// A writer whose participant is lost (killed: no goodbye, its lease
/// ends): its instances are NOT_ALIVE_NO_WRITERS. Before: nothing.
#[test]
fn a_lost_participant_leaves_its_instances_without_writers() {
    let mut net = new_net(2, 2);
    let topic = "lost";
    let r = reader(&mut net, 1, topic);
    let w = writer(&mut net, 0, topic);
    matched(&mut net, 1, r, 1);
    write(&mut net, 0, w, 1, 1);
    write(&mut net, 0, w, 2, 2);
    net.run_for(ms(100));
    assert_eq!(took(&mut net, 1, r), [Got::Sample(1, 1), Got::Sample(2, 2)]);
    let wg = guid(&net, 0, w);
    net.hosts[0].up = false;
    let lost = |n: &Net| {
        n.has(1, |e| {
            matches!(
                e,
                Event::Discovery(participant::Event::ParticipantLost { .. })
            )
        })
    };
    assert!(net.run_until(Duration::from_secs(5), lost));
    net.run_for(ms(100));
    assert_eq!(
        took(&mut net, 1, r),
        [
            Got::Change(NO_WRITERS, 1, wg),
            Got::Change(NO_WRITERS, 2, wg)
        ]
    );
}

/// The only writer's liveliness lapses (MANUAL_BY_TOPIC, 500 ms): its
/// instances are NOT_ALIVE_NO_WRITERS right after the reader is told it
/// is not alive; a sample makes its instance alive again (the other stays
/// without writers), and the next lapse says so for that one alone. A
/// reader that tracks no liveliness sees nothing of it. Before: nothing.
#[test]
fn a_writer_whose_liveliness_lapses_leaves_its_instances_without_writers() {
    let mut net = new_net(2, 3);
    let topic = "lapses";
    let mut rq = reader_qos();
    rq.liveliness = lease(LivelinessKind::Automatic, 1000);
    let r = reader_with(&mut net, 1, topic, rq);
    let plain = reader(&mut net, 1, topic);
    let mut wq = writer_qos();
    wq.liveliness = lease(LivelinessKind::ManualByTopic, 500);
    let w = writer_with(&mut net, 0, topic, wq);
    matched(&mut net, 1, r, 1);
    matched(&mut net, 1, plain, 1);
    write(&mut net, 0, w, 1, 1);
    write(&mut net, 0, w, 2, 2);
    net.run_for(ms(100));
    let events = net.take_events(1);
    let samples = events
        .iter()
        .filter(|e| matches!(e, Event::Sample { .. }))
        .count();
    assert_eq!(samples, 4, "both readers took both samples");
    let wg = guid(&net, 0, w);
    // silent: the lease lapses
    net.run_for(ms(1000));
    let events = net.hosts[1].events.clone();
    let lapse = events
        .iter()
        .position(|e| matches!(e, Event::LivelinessChanged { alive: false, .. }))
        .expect("the lease lapsed");
    let no_writers = events
        .iter()
        .position(|e| matches!(e, Event::Sample { .. }))
        .expect("instances without writers");
    assert!(lapse < no_writers, "said after the lapse");
    assert_eq!(
        took(&mut net, 1, r),
        [
            Got::Change(NO_WRITERS, 1, wg),
            Got::Change(NO_WRITERS, 2, wg)
        ]
    );
    // alive again by a sample of instance 1; instance 2 stays without
    // writers; the next lapse is of instance 1 only
    write(&mut net, 0, w, 1, 3);
    net.run_for(ms(1000));
    assert_eq!(
        took(&mut net, 1, r),
        [Got::Sample(1, 3), Got::Change(NO_WRITERS, 1, wg)]
    );
    assert!(
        !net.hosts[1]
            .events
            .iter()
            .any(|e| matches!(e, Event::Sample { reader, .. } if *reader == plain)),
        "a reader without liveliness tracks none"
    );
}

/// Two writers of instance 1: the first one's unregister says nothing
/// (the instance still has a writer), the second's says NO_WRITERS. Under
/// exclusive ownership the owner's unregister hands the instance to the
/// other writer, silently. Before, each unregister was delivered.
#[test]
fn an_unregister_says_no_writers_only_from_the_last_writer() {
    let mut net = new_net(3, 4);
    let topic = "two";
    let r = reader(&mut net, 2, topic);
    let a = writer(&mut net, 0, topic);
    let b = writer(&mut net, 1, topic);
    matched(&mut net, 2, r, 2);
    write(&mut net, 0, a, 1, 1);
    write(&mut net, 1, b, 1, 101);
    net.run_for(ms(100));
    change(&mut net, 0, a, 1, ChangeKind::Unregistered);
    net.run_for(ms(100));
    write(&mut net, 1, b, 1, 102);
    net.run_for(ms(100));
    change(&mut net, 1, b, 1, ChangeKind::Unregistered);
    net.run_for(ms(100));
    let bg = guid(&net, 1, b);
    assert_eq!(
        took(&mut net, 2, r),
        [
            Got::Sample(1, 1),
            Got::Sample(1, 101),
            Got::Sample(1, 102),
            Got::Change(ChangeKind::Unregistered, 1, bg)
        ]
    );

    // exclusive: the owner (20) unregisters; the weaker (10) one's
    // samples are taken from then on
    let topic = "two-owned";
    let r = reader_with(&mut net, 2, topic, owned(reader_qos(), 0));
    let weak = writer_with(&mut net, 0, topic, owned(writer_qos(), 10));
    let strong = writer_with(&mut net, 1, topic, owned(writer_qos(), 20));
    matched(&mut net, 2, r, 2);
    write(&mut net, 1, strong, 1, 101);
    net.run_for(ms(100));
    write(&mut net, 0, weak, 1, 1);
    net.run_for(ms(100));
    change(&mut net, 1, strong, 1, ChangeKind::Unregistered);
    net.run_for(ms(100));
    write(&mut net, 0, weak, 1, 2);
    net.run_for(ms(100));
    assert_eq!(
        took(&mut net, 2, r),
        [Got::Sample(1, 101), Got::Sample(1, 2)],
        "no word of the owner's unregister: the weaker writer still writes"
    );
}

/// An unregister of an instance the reader never saw says nothing (a
/// dispose of one does: Cyclone delivers it too). Before, the unregister
/// was delivered.
#[test]
fn an_unregister_of_an_instance_never_seen_says_nothing() {
    let mut net = new_net(2, 5);
    let topic = "unseen";
    let r = reader(&mut net, 1, topic);
    let w = writer(&mut net, 0, topic);
    matched(&mut net, 1, r, 1);
    write(&mut net, 0, w, 1, 1);
    change(&mut net, 0, w, 8, ChangeKind::Unregistered);
    change(&mut net, 0, w, 9, ChangeKind::Disposed);
    net.run_for(ms(100));
    let wg = guid(&net, 0, w);
    assert_eq!(
        took(&mut net, 1, r),
        [Got::Sample(1, 1), Got::Change(ChangeKind::Disposed, 9, wg)]
    );
}

/// Exclusive ownership: the weaker writer's dispose, unregister, and
/// dispose-and-unregister (as a writer deleted with autodispose sends)
/// of instances the stronger one owns change nothing; the owner's dispose
/// does. Before, the weaker writer disposed the owner's instances.
#[test]
fn only_the_owner_disposes_under_exclusive_ownership() {
    let mut net = new_net(3, 6);
    let topic = "owned";
    let r = reader_with(&mut net, 2, topic, owned(reader_qos(), 0));
    let weak = writer_with(&mut net, 0, topic, owned(writer_qos(), 10));
    let strong = writer_with(&mut net, 1, topic, owned(writer_qos(), 20));
    matched(&mut net, 2, r, 2);
    for k in 1..=3 {
        write(&mut net, 1, strong, k, 100 + u32::from(k));
    }
    net.run_for(ms(100));
    for k in 1..=3 {
        write(&mut net, 0, weak, k, u32::from(k));
    }
    net.run_for(ms(100));
    change(&mut net, 0, weak, 1, ChangeKind::Disposed);
    change(&mut net, 0, weak, 2, ChangeKind::Unregistered);
    change(&mut net, 0, weak, 3, ChangeKind::DisposedUnregistered);
    net.run_for(ms(100));
    for k in 1..=3 {
        write(&mut net, 1, strong, k, 200 + u32::from(k));
    }
    net.run_for(ms(100));
    change(&mut net, 1, strong, 1, ChangeKind::Disposed);
    net.run_for(ms(100));
    let sg = guid(&net, 1, strong);
    assert_eq!(
        took(&mut net, 2, r),
        [
            Got::Sample(1, 101),
            Got::Sample(2, 102),
            Got::Sample(3, 103),
            Got::Sample(1, 201),
            Got::Sample(2, 202),
            Got::Sample(3, 203),
            Got::Change(ChangeKind::Disposed, 1, sg),
        ]
    );
}

/// Exclusive ownership: the strong owner's liveliness lapses (MANUAL_BY_TOPIC,
/// 500 ms) while it stays; the weaker writer's samples are taken from the
/// lapse on, and the strong one's again when it writes. Before, the reader
/// waited for the silent owner (the weaker one's samples were dropped).
#[test]
fn an_owner_whose_liveliness_lapses_hands_the_instance_over() {
    let mut net = new_net(3, 7);
    let topic = "own-lapse";
    let mut rq = owned(reader_qos(), 0);
    rq.liveliness = lease(LivelinessKind::Automatic, 1000);
    let r = reader_with(&mut net, 2, topic, rq);
    let mut sq = owned(writer_qos(), 20);
    sq.liveliness = lease(LivelinessKind::ManualByTopic, 500);
    let strong = writer_with(&mut net, 1, topic, sq);
    let mut wq = owned(writer_qos(), 10);
    wq.liveliness = lease(LivelinessKind::Automatic, 1000);
    let weak = writer_with(&mut net, 0, topic, wq);
    matched(&mut net, 2, r, 2);
    write(&mut net, 1, strong, 1, 100);
    net.run_for(ms(50));
    // the weak one writes every 100 ms; the strong one is silent
    for n in 0..15 {
        write(&mut net, 0, weak, 1, n);
        net.run_for(ms(100));
    }
    let got = took(&mut net, 2, r);
    assert_eq!(got[0], Got::Sample(1, 100));
    assert!(
        got.len() > 6 && got.len() < 12,
        "the weak writer's samples from the lapse (~550 ms) on: {got:?}"
    );
    let first = match got[1] {
        Got::Sample(1, n) => n,
        ref g => panic!("{g:?}"),
    };
    let want: Vec<Got> = (first..15).map(|n| Got::Sample(1, n)).collect();
    assert_eq!(got[1..], want[..]);
    // the strong one writes again: it owns the instance again
    write(&mut net, 1, strong, 1, 200);
    net.run_for(ms(50));
    write(&mut net, 0, weak, 1, 99);
    net.run_for(ms(50));
    assert_eq!(took(&mut net, 2, r), [Got::Sample(1, 200)]);
}

/// `@key long id; unsigned long seq;` (final), as `#[derive(IpcMessage)]`
/// writes it (this crate's tests cannot use the derive).
#[derive(Debug, Clone, PartialEq)]
struct Keyed {
    id: i32,
    seq: u32,
}

impl IpcMessage for Keyed {
    const FORMAT: &'static str = "{int, uint}";
    const TYPE_NAME: &'static str = "courier::test::KeyedSeq";
    const IPC_MIN_SIZE: usize = 0;
    const CDR_MIN_SIZE: usize = 1;
    const KEYS: &'static [&'static str] = &["id"];
    const CDR_KEY_MAX_SIZE: MaxSize = MaxSize::EMPTY.then(<i32 as IpcMessage>::CDR_MAX_SIZE);
    type Key = (i32,);

    fn ipc_encode(&self, _: &mut ipc::Writer) {}
    fn ipc_decode(_: &mut ipc::Reader<'_>) -> Result<Self, ipc::DecodeError> {
        Err(ipc::DecodeError::Format("CDR-only test type".into()))
    }
    fn cdr_encode(&self, w: &mut cdr::Writer) {
        let s = w.begin_struct(Extensibility::Final);
        let m = s.begin_member(w, 0, false);
        self.id.cdr_encode(w);
        s.end_member(w, m);
        let m = s.begin_member(w, 1, false);
        self.seq.cdr_encode(w);
        s.end_member(w, m);
        s.end(w);
    }
    fn cdr_decode(r: &mut cdr::Reader<'_>) -> Result<Self, DecodeError> {
        let s = r.begin_struct(Extensibility::Final)?;
        let id = i32::cdr_decode(r)?;
        let seq = u32::cdr_decode(r)?;
        s.end(r)?;
        Ok(Keyed { id, seq })
    }
    fn cdr_encode_key(&self, w: &mut cdr::Writer) {
        Self::cdr_encode_key_value(&(self.id,), w);
    }
    fn cdr_decode_key(r: &mut cdr::Reader<'_>) -> Result<Self::Key, DecodeError> {
        let s = r.begin_struct(Extensibility::Final)?;
        let id = i32::cdr_decode(r)?;
        s.end(r)?;
        Ok((id,))
    }
    fn cdr_encode_key_value(key: &Self::Key, w: &mut cdr::Writer) -> bool {
        let s = w.begin_struct(Extensibility::Final);
        let m = s.begin_member(w, 0, false);
        key.0.cdr_encode(w);
        s.end_member(w, m);
        s.end(w);
        true
    }
}

/// Cyclone DDS's `write_dispose`: a DATA with the whole sample, the
/// dispose flag and no key hash. The reader takes the sample, then the
/// dispose of its instance (its key hash from the payload), for an
/// instance it knew and for a new one; a plain dispose with the serialized
/// key stays a dispose. Before: a dispose of no instance, or nothing.
#[test]
fn a_dispose_with_the_whole_sample_is_the_sample_then_the_dispose() {
    let mut net = new_net(2, 8);
    let topic = "write-dispose";
    let now = net.now();
    let cfg = EndpointConfig::reader(topic, Keyed::TYPE_NAME)
        .keyed(true)
        .qos(reader_qos());
    let r = net.node(1).create_reader(cfg, now).unwrap();
    assert!(net
        .node(1)
        .set_instance_keys(r, InstanceKeys::of::<Keyed>()));
    let cfg = EndpointConfig::writer(topic, Keyed::TYPE_NAME)
        .keyed(true)
        .qos(writer_qos());
    let w = net.node(0).create_writer(cfg, now).unwrap();
    matched(&mut net, 1, r, 1);
    let enc = Encoding::new(Version::Xcdr1, Endianness::Little);
    let send = |net: &mut Net, kind: ChangeKind, data: Vec<u8>| {
        let now = net.now();
        let c = Change {
            kind,
            data: Cow::Owned(data),
            key_hash: None,
            source_timestamp: None,
            related_sample_identity: None,
        };
        net.node(0).write(w, c, now).unwrap();
    };
    let v = |id, seq| Keyed { id, seq };
    send(&mut net, ChangeKind::Alive, cdr::to_vec(&v(1, 1), enc));
    send(&mut net, ChangeKind::Disposed, cdr::to_vec(&v(1, 2), enc));
    send(&mut net, ChangeKind::Disposed, cdr::to_vec(&v(2, 7), enc));
    send(
        &mut net,
        ChangeKind::Disposed,
        cdr::key_to_vec(&v(3, 0), enc),
    );
    net.run_for(ms(100));
    let hash = |id| Some(KeyHash(key_hash_in(&v(id, 0), Version::Xcdr1)));
    let got: Vec<(ChangeKind, Option<KeyHash>, Option<Keyed>)> = net
        .take_events(1)
        .into_iter()
        .filter_map(|e| match e {
            Event::Sample { reader, sample } if reader == r => Some((
                sample.kind,
                sample.key_hash,
                (sample.kind == ChangeKind::Alive)
                    .then(|| cdr::from_slice::<Keyed>(sample.data()).unwrap()),
            )),
            _ => None,
        })
        .collect();
    assert_eq!(
        got,
        [
            (ChangeKind::Alive, hash(1), Some(v(1, 1))),
            (ChangeKind::Alive, hash(1), Some(v(1, 2))),
            (ChangeKind::Disposed, hash(1), None),
            (ChangeKind::Alive, hash(2), Some(v(2, 7))),
            (ChangeKind::Disposed, hash(2), None),
            (ChangeKind::Disposed, hash(3), None),
        ]
    );
}
