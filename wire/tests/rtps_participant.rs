//! The sans-I/O RTPS participant on a simulated network: discovery through
//! unicast peer lists, matching, reliable and best-effort delivery under
//! loss, duplication and reordering, fragmentation, dispose, transient-local
//! late joiners, lease expiry and QoS mismatches. Deterministic: seeded
//! xorshift, simulated time, no sockets, no sleeps.

use std::time::Duration;

use courier_wire::rtps::discovery::{
    Durability, Duration as RtpsDuration, EndpointQos, History, Reliability,
};
use courier_wire::rtps::matching::Incompatible;
use courier_wire::rtps::participant::{
    guid_prefix, Change, ChangeKind, Config, EndpointConfig, Event, KeyHash, LostReason,
    Participant, ReceivedSample,
};
use courier_wire::rtps::{Guid, Locator, Message, SequenceNumber, Submessage};
use courier_wire::sim::{self, Faults};

const LO: [u8; 4] = [127, 0, 0, 1];

/// The shared simulated network, with participants on it.
type Net = sim::Net<Participant>;

fn rel() -> Reliability {
    Reliability::Reliable(RtpsDuration::ZERO)
}

/// `n` participants (indices 0..n, peers 127.0.0.1 up to index 9) on a
/// network with `loss` % loss (and then duplicates and reordering).
fn new_net(n: usize, seed: u64, loss: u32) -> Net {
    let mut net = Net::new(seed, Faults::lossy(loss));
    for i in 0..n {
        let cfg = Config::udpv4(0, i as u32, guid_prefix([i as u8 + 1; 10]), LO)
            .unwrap()
            .with_unicast_peers(&[LO], 9);
        let p = Participant::new(cfg, net.now(), net.wall());
        net.add(p);
    }
    net
}

/// What these tests look at on a network of participants.
trait Look {
    fn guid(&self, i: usize) -> courier_wire::rtps::GuidPrefix;
    fn samples(&self, i: usize) -> Vec<&ReceivedSample>;
}

impl Look for Net {
    fn guid(&self, i: usize) -> courier_wire::rtps::GuidPrefix {
        self.hosts[i].node.guid_prefix()
    }

    fn samples(&self, i: usize) -> Vec<&ReceivedSample> {
        self.hosts[i]
            .events
            .iter()
            .filter_map(|e| match e {
                Event::SampleReceived(s) => Some(s),
                _ => None,
            })
            .collect()
    }
}

fn reliable_reader(topic: &str, ty: &str) -> EndpointConfig {
    let mut q = EndpointQos::reader_default();
    q.reliability = rel();
    q.history = History::KeepAll;
    EndpointConfig::reader(topic, ty).qos(q)
}

fn keyed_writer(topic: &str, ty: &str) -> EndpointConfig {
    let mut q = EndpointQos::writer_default();
    q.history = History::KeepAll;
    EndpointConfig::writer(topic, ty).keyed(true).qos(q)
}

/// A CDR_LE sample of `struct { long id; long n; }` with key `id`.
fn sample(id: i32, n: i32) -> (Vec<u8>, KeyHash) {
    let mut b = vec![0, 1, 0, 0];
    b.extend_from_slice(&id.to_le_bytes());
    b.extend_from_slice(&n.to_le_bytes());
    (b, KeyHash::from_key(&id.to_be_bytes(), false))
}

/// Two participants on a network with `loss` % loss, a writer on the first
/// and a reader on the second, run until both sides have matched.
fn matched_pair(seed: u64, loss: u32, w: EndpointConfig, r: EndpointConfig) -> (Net, Guid, Guid) {
    let mut net = new_net(2, seed, loss);
    let now = net.now();
    let w = net.hosts[0].node.create_writer(w, now).unwrap();
    let r = net.hosts[1].node.create_reader(r, now).unwrap();
    assert!(
        net.run_until(Duration::from_secs(30), |n| matched(n, 0, w, 1, r)),
        "seed {seed}: no match after {:?}",
        net.elapsed()
    );
    (net, w, r)
}

fn matched(net: &Net, w_node: usize, w: Guid, r_node: usize, r: Guid) -> bool {
    net.has(
        w_node,
        |e| matches!(e, Event::WriterMatched { writer, reader } if *writer == w && *reader == r),
    ) && net.has(
        r_node,
        |e| matches!(e, Event::ReaderMatched { reader, writer } if *writer == w && *reader == r),
    )
}

/// Writes `count` keyed samples (5 instances) as fast as the writer's
/// keep-all history allows, then runs until every reader has them all.
fn write_all(net: &mut Net, w: Guid, readers: &[usize], count: i32, limit: Duration) -> bool {
    let mut next = 0;
    let end = net.now() + limit;
    while net.now() < end {
        while next < count {
            let (b, k) = sample(next % 5, next);
            let now = net.now();
            match net.hosts[0]
                .node
                .write(w, Change::alive(&b).with_key_hash(k), now)
            {
                Ok(_) => next += 1,
                Err(_) => break,
            }
            if next % 7 == 0 {
                break; // a few per millisecond
            }
        }
        net.pump();
        if next == count
            && readers
                .iter()
                .all(|r| net.samples(*r).len() >= count as usize)
        {
            return true;
        }
        net.step();
    }
    false
}

fn check_in_order(net: &Net, r: usize, count: i32) {
    let got = net.samples(r);
    assert_eq!(got.len(), count as usize, "node {r}: every sample once");
    for (i, s) in got.iter().enumerate() {
        let (b, k) = sample(i as i32 % 5, i as i32);
        assert_eq!(
            s.sequence_number,
            SequenceNumber(i as i64 + 1),
            "node {r}: in order"
        );
        assert_eq!(s.data(), &b[..]);
        assert_eq!(s.key_hash, Some(k));
        assert_eq!(s.kind, ChangeKind::Alive);
        assert!(s
            .source_timestamp
            .is_some_and(|t| t.seconds >= 1_700_000_000));
    }
}

#[test]
fn two_participants_discover_by_unicast_peers_and_deliver_reliably_under_30_percent_loss() {
    for seed in [1u64, 42, 7777] {
        let mut net = new_net(2, seed, 30);
        let (p0, p1) = (net.guid(0), net.guid(1));
        let now = net.now();
        let w = net.hosts[0]
            .node
            .create_writer(keyed_writer("Robot", "Pose"), now)
            .unwrap();
        let r = net.hosts[1]
            .node
            .create_reader(reliable_reader("Robot", "Pose").keyed(true), now)
            .unwrap();
        assert!(
            net.run_until(Duration::from_secs(30), |n| matched(n, 0, w, 1, r)),
            "seed {seed}: no match after {:?}",
            net.elapsed()
        );
        assert!(net.has(
            0,
            |e| matches!(e, Event::ParticipantFound(d) if d.guid_prefix == p1)
        ));
        assert!(net.has(
            1,
            |e| matches!(e, Event::ParticipantFound(d) if d.guid_prefix == p0)
        ));
        assert!(net.has(
            1,
            |e| matches!(e, Event::PublicationFound(d) if d.guid == w && d.topic_name == "Robot")
        ));
        assert!(net.has(
            0,
            |e| matches!(e, Event::SubscriptionFound(d) if d.guid == r)
        ));
        assert!(
            write_all(&mut net, w, &[1], 300, Duration::from_secs(120)),
            "seed {seed}: only {} of 300 after {:?}",
            net.samples(1).len(),
            net.elapsed()
        );
        check_in_order(&net, 1, 300);
        eprintln!("seed {seed}: 300 samples delivered at {:?}", net.elapsed());
        // and the writer learns that everything was acknowledged
        assert!(
            net.run_until(Duration::from_secs(30), |n| n.has(0, |e| matches!(
                e,
                Event::AckedByAll { writer, up_to } if *writer == w && up_to.0 == 300
            )))
        );
        assert!(net.hosts[0].node.is_acked_by_all(w, SequenceNumber(300)));
    }
}

#[test]
fn three_participants_each_reader_gets_everything_in_order() {
    let mut net = new_net(3, 99, 30);
    let now = net.now();
    let w = net.hosts[0]
        .node
        .create_writer(keyed_writer("T", "Ty"), now)
        .unwrap();
    let r1 = net.hosts[1]
        .node
        .create_reader(reliable_reader("T", "Ty").keyed(true), now)
        .unwrap();
    let r2 = net.hosts[2]
        .node
        .create_reader(reliable_reader("T", "Ty").keyed(true), now)
        .unwrap();
    assert!(
        net.run_until(Duration::from_secs(30), |n| matched(n, 0, w, 1, r1)
            && matched(n, 0, w, 2, r2))
    );
    // everybody knows everybody
    for i in 0..3 {
        assert_eq!(net.hosts[i].node.participants().count(), 2, "node {i}");
    }
    assert!(write_all(
        &mut net,
        w,
        &[1, 2],
        200,
        Duration::from_secs(120)
    ));
    check_in_order(&net, 1, 200);
    check_in_order(&net, 2, 200);
    assert_eq!(net.hosts[0].node.matched_readers(w), vec![r1, r2]);
}

#[test]
fn best_effort_delivers_in_order_without_repair() {
    // lossless: everything arrives
    let mut net = new_net(2, 5, 0);
    let now = net.now();
    let mut wq = EndpointQos::writer_default();
    wq.reliability = Reliability::BestEffort;
    let w = net.hosts[0]
        .node
        .create_writer(EndpointConfig::writer("B", "T").qos(wq.clone()), now)
        .unwrap();
    let r = net.hosts[1]
        .node
        .create_reader(EndpointConfig::reader("B", "T"), now)
        .unwrap();
    assert!(net.run_until(Duration::from_secs(10), |n| matched(n, 0, w, 1, r)));
    for i in 0..50 {
        let (b, _) = sample(0, i);
        let now = net.now();
        net.hosts[0].node.write(w, Change::alive(&b), now).unwrap();
        net.step();
    }
    net.run_for(Duration::from_millis(100));
    assert_eq!(net.samples(1).len(), 50);
    // lossy: what arrives is in order, once, and nothing is repaired
    let (mut net, w, _) = matched_pair(
        6,
        30,
        EndpointConfig::writer("B", "T").qos(wq),
        EndpointConfig::reader("B", "T"),
    );
    for i in 0..200 {
        let (b, _) = sample(0, i);
        let now = net.now();
        net.hosts[0].node.write(w, Change::alive(&b), now).unwrap();
        // slower than the network reorders: a late sample would be dropped
        net.run_for(Duration::from_millis(25));
    }
    net.run_for(Duration::from_secs(1));
    let sns: Vec<i64> = net.samples(1).iter().map(|s| s.sequence_number.0).collect();
    assert!(sns.len() > 100 && sns.len() < 200, "{}", sns.len());
    assert!(sns.windows(2).all(|w| w[0] < w[1]));
    assert!(!net.has(0, |e| matches!(e, Event::AckedByAll { .. })));
}

#[test]
fn a_200_kib_sample_is_fragmented_and_reassembled_under_loss() {
    let big: Vec<u8> = [0u8, 1, 0, 0]
        .into_iter()
        .chain((0..200 * 1024).map(|i| (i * 31 % 251) as u8))
        .collect();
    for (seed, loss) in [(3u64, 0u32), (11, 30), (12, 30)] {
        let (mut net, w, _) = matched_pair(
            seed,
            loss,
            EndpointConfig::writer("Big", "Blob"),
            reliable_reader("Big", "Blob"),
        );
        net.tapping = true;
        let now = net.now();
        net.hosts[0]
            .node
            .write(w, Change::alive(&big), now)
            .unwrap();
        net.pump();
        assert!(
            net.run_until(Duration::from_secs(60), |n| !n.samples(1).is_empty()),
            "seed {seed}"
        );
        assert_eq!(net.samples(1)[0].data(), &big[..]);
        // on the wire: DATA_FRAGs of 1344-byte fragments, 10 per submessage,
        // in datagrams no larger than 14720 bytes (Cyclone's shape)
        let mut frags = 0;
        let mut nack_frags = 0;
        for d in &net.tap {
            assert!(d.payload.len() <= 14_720);
            for s in Message::parse(&d.payload).unwrap().submessages {
                match s {
                    Submessage::DataFrag(f) => {
                        frags += 1;
                        assert_eq!(f.fragment_size, 1344);
                        assert_eq!(f.sample_size as usize, big.len());
                        assert!(
                            f.fragments_in_submessage == 10
                                || loss > 0
                                || f.fragment_starting_num > 150
                        );
                    }
                    Submessage::NackFrag(_) => nack_frags += 1,
                    _ => {}
                }
            }
        }
        assert!(frags >= 16, "{frags}");
        if loss > 0 {
            assert!(
                nack_frags > 0,
                "the reader asked for missing fragments only"
            );
        }
    }
}

/// A 4 MiB sample whose first burst the reader's socket buffer mostly
/// dropped (only its first 64 datagrams, ~0.9 MiB, arrive): one NACK_FRAG
/// names at most 256 missing fragments, so the ~2400 missing take ten
/// rounds. Each resend that leaves more to ask for ends with a heartbeat
/// to that reader, so the rounds go at the network's pace: simulated, the
/// sample is whole within 100 ms, the first periodic heartbeat's time
/// (before, each round waited for one: ~1 s).
#[test]
fn a_large_sample_mostly_lost_is_repaired_a_round_trip_per_nack_frag() {
    let big: Vec<u8> = [0u8, 1, 0, 0]
        .into_iter()
        .chain((0..4 << 20).map(|i| (i * 31 % 251) as u8))
        .collect();
    let (mut net, w, _) = matched_pair(
        21,
        0,
        EndpointConfig::writer("Big", "Blob"),
        reliable_reader("Big", "Blob"),
    );
    let now = net.now();
    let start = net.elapsed();
    net.hosts[0]
        .node
        .write(w, Change::alive(&big), now)
        .unwrap();
    // the first burst: what a 1 MiB receive buffer takes, the rest dropped
    let from = sim::Node::address(&net.hosts[0].node);
    let mut sent = 0;
    while let Some(d) = net.hosts[0].node.poll_transmit() {
        sent += 1;
        if sent <= 64 {
            net.send(sim::Packet {
                from,
                to: d.destination,
                payload: d.payload,
            });
        }
    }
    assert!(sent > 250, "{sent} datagrams");
    net.tapping = true;
    assert!(net.run_until(Duration::from_secs(10), |n| !n.samples(1).is_empty()));
    assert_eq!(net.samples(1)[0].data(), &big[..]);
    let took = net.elapsed() - start;
    assert!(took < Duration::from_millis(100), "{took:?}");
    let nack_frags = net
        .tap
        .iter()
        .flat_map(|d| Message::parse(&d.payload).unwrap().submessages)
        .filter(|s| matches!(s, Submessage::NackFrag(_)))
        .count();
    assert!(nack_frags >= 9, "{nack_frags}");
}

/// Takes the samples node `i` has received so far, as owned values.
fn take_samples(net: &mut Net, i: usize) -> Vec<ReceivedSample> {
    std::mem::take(&mut net.hosts[i].events)
        .into_iter()
        .filter_map(|e| match e {
            Event::SampleReceived(s) => Some(s),
            _ => None,
        })
        .collect()
}

#[test]
fn sample_buffers_handed_back_are_received_into_again() {
    let (mut net, w, _) = matched_pair(
        5,
        0,
        EndpointConfig::writer("Big", "Blob"),
        reliable_reader("Big", "Blob"),
    );
    take_samples(&mut net, 1);
    // one DATA (10 kB) and one sample in DATA_FRAGs (40 kB)
    for size in [10_000usize, 40_000] {
        let mut last = None;
        // (a spare of the other size stays: it does not fit)
        let other = net.hosts[1].node.spare_bytes();
        for round in 0..3u8 {
            let data: Vec<u8> = [0u8, 1, 0, 0]
                .into_iter()
                .chain((0..size).map(|i| (i as u8) ^ round))
                .collect();
            let now = net.now();
            net.hosts[0]
                .node
                .write(w, Change::alive(&data), now)
                .unwrap();
            net.pump();
            assert!(net.run_until(Duration::from_secs(5), |n| !n.samples(1).is_empty()));
            let got = take_samples(&mut net, 1);
            assert_eq!(got.len(), 1);
            let buf = got.into_iter().next().unwrap().into_data();
            assert_eq!(buf, data, "size {size} round {round}");
            if let Some(at) = last {
                assert_eq!(buf.as_ptr(), at, "size {size} round {round}: a new buffer");
            }
            // the spare was taken for this sample
            assert_eq!(net.hosts[1].node.spare_bytes(), other);
            last = Some(buf.as_ptr());
            net.hosts[1].node.recycle(buf);
            assert!(net.hosts[1].node.spare_bytes() > size);
        }
    }
}

#[test]
fn dispose_and_unregister_are_events_and_go_out_both_ways() {
    let mut net = new_net(2, 8, 0);
    let now = net.now();
    let w = net.hosts[0]
        .node
        .create_writer(keyed_writer("K", "T"), now)
        .unwrap();
    let r = net.hosts[1]
        .node
        .create_reader(reliable_reader("K", "T").keyed(true), now)
        .unwrap();
    assert!(net.run_until(Duration::from_secs(10), |n| matched(n, 0, w, 1, r)));
    net.tapping = true;
    let (b, k) = sample(7, 1);
    let key = [0u8, 1, 0, 0, 7, 0, 0, 0];
    let now = net.now();
    net.hosts[0]
        .node
        .write(w, Change::alive(&b).with_key_hash(k), now)
        .unwrap();
    net.hosts[0]
        .node
        .write(w, Change::dispose(&key, k), now)
        .unwrap();
    net.hosts[0]
        .node
        .write(w, Change::unregister(&[], k), now)
        .unwrap();
    net.pump();
    assert!(net.run_until(Duration::from_secs(5), |n| n.samples(1).len() == 3));
    let got = net.samples(1);
    assert_eq!(
        got.iter().map(|s| (s.kind, s.key_hash)).collect::<Vec<_>>(),
        [
            (ChangeKind::Alive, Some(k)),
            (ChangeKind::Disposed, Some(k)),
            (ChangeKind::Unregistered, Some(k))
        ]
    );
    assert_eq!(got[1].data(), &key);
    assert_eq!(got[2].data(), b"");
    // the dispose DATA carries inline KEY_HASH + STATUS_INFO (Fast DDS's
    // way) and the serialized key with the K flag (Cyclone's way)
    let dispose = net
        .tap
        .iter()
        .flat_map(|d| {
            let m = Message::parse(&d.payload).unwrap();
            m.submessages
                .into_iter()
                .filter_map(|s| match s {
                    Submessage::Data(d)
                        if d.writer_sn == SequenceNumber(2) && d.writer_id == w.entity =>
                    {
                        Some((
                            d.key,
                            d.payload.map(<[u8]>::to_vec),
                            d.inline_qos.map(<[u8]>::to_vec),
                        ))
                    }
                    _ => None,
                })
                .collect::<Vec<_>>()
        })
        .next()
        .unwrap();
    assert!(dispose.0, "K flag");
    assert_eq!(dispose.1.as_deref(), Some(&key[..]));
    let q = dispose.2.unwrap();
    // golden: KEY_HASH (0x0070, the key hash of `long id = 7`), STATUS_INFO
    // (0x0071, disposed), sentinel; then the serialized key with its
    // encapsulation header (CDR_LE, id 7) as the K-flag payload
    assert_eq!(
        q,
        [
            0x70, 0x00, 0x10, 0x00, 0, 0, 0, 7, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, //
            0x71, 0x00, 0x04, 0x00, 0, 0, 0, 1, //
            0x01, 0x00, 0x00, 0x00,
        ]
    );
    let d = courier_wire::rtps::discovery::Disposal::from_data(Some(&q), true, None, false)
        .unwrap()
        .unwrap();
    assert_eq!(d.key_hash, k.0);
    assert!(d.status.disposed && !d.status.unregistered);
}

fn tl_writer(depth: i32) -> EndpointConfig {
    let mut q = EndpointQos::writer_default();
    q.durability = Durability::TransientLocal;
    q.history = History::KeepLast(depth);
    EndpointConfig::writer("Late", "T").keyed(true).qos(q)
}

fn tl_reader(durability: Durability) -> EndpointConfig {
    let mut q = EndpointQos::reader_default();
    q.reliability = rel();
    q.durability = durability;
    q.history = History::KeepAll;
    EndpointConfig::reader("Late", "T").keyed(true).qos(q)
}

#[test]
fn transient_local_late_joiner_gets_the_history_per_instance_and_volatile_does_not() {
    let mut net = new_net(3, 21, 20);
    let now = net.now();
    let w = net.hosts[0].node.create_writer(tl_writer(2), now).unwrap();
    // 3 instances × 4 samples, written before anybody listens
    for n in 0..12 {
        let (b, k) = sample(n % 3, n);
        let now = net.now();
        net.hosts[0]
            .node
            .write(w, Change::alive(&b).with_key_hash(k), now)
            .unwrap();
    }
    net.run_for(Duration::from_secs(2));
    let now = net.now();
    let late = net.hosts[1]
        .node
        .create_reader(tl_reader(Durability::TransientLocal), now)
        .unwrap();
    let vol = net.hosts[2]
        .node
        .create_reader(tl_reader(Durability::Volatile), now)
        .unwrap();
    assert!(
        net.run_until(Duration::from_secs(30), |n| matched(n, 0, w, 1, late)
            && matched(n, 0, w, 2, vol)
            && n.samples(1).len() >= 6)
    );
    net.run_for(Duration::from_secs(2));
    // keep-last 2 per instance: samples 6..=11 remain, the rest was gapped
    let got: Vec<i64> = net.samples(1).iter().map(|s| s.sequence_number.0).collect();
    assert_eq!(got, [7, 8, 9, 10, 11, 12]);
    assert!(
        net.samples(2).is_empty(),
        "a volatile reader gets no history"
    );
    // both get what comes next
    let (b, k) = sample(1, 99);
    let now = net.now();
    net.hosts[0]
        .node
        .write(w, Change::alive(&b).with_key_hash(k), now)
        .unwrap();
    net.pump();
    assert!(
        net.run_until(Duration::from_secs(10), |n| n.samples(1).len() == 7
            && n.samples(2).len() == 1)
    );
    assert_eq!(net.samples(2)[0].sequence_number, SequenceNumber(13));
}

/// A transient-local writer forgets an instance it unregistered, as
/// Cyclone DDS and Fast DDS do (audit 19): a late joiner gets neither its
/// samples nor the unregister, while a reader matched before gets both.
/// And its history, bounded in samples, keeps every live instance's last
/// value however many instances came and went: before, the samples of
/// unregistered instances filled it and pushed the oldest live instance's
/// value out.
#[test]
fn a_transient_local_writer_forgets_unregistered_instances() {
    let mut net = Net::new(23, Faults::none());
    for i in 0..3u8 {
        let mut cfg = Config::udpv4(0, u32::from(i), guid_prefix([i + 1; 10]), LO)
            .unwrap()
            .with_unicast_peers(&[LO], 9);
        cfg.max_history = 16;
        let p = Participant::new(cfg, net.now(), net.wall());
        net.add(p);
    }
    let now = net.now();
    let w = net.hosts[0].node.create_writer(tl_writer(1), now).unwrap();
    let early = net.hosts[1]
        .node
        .create_reader(tl_reader(Durability::TransientLocal), now)
        .unwrap();
    assert!(net.run_until(Duration::from_secs(10), |n| matched(n, 0, w, 1, early)));
    let write = |net: &mut Net, change: Change<'_>| {
        let now = net.now();
        net.hosts[0].node.write(w, change, now).unwrap().0
    };
    // instance 0 lives throughout; 40 others come and go, more than the
    // history holds
    let (b, k) = sample(0, 0);
    let kept = write(&mut net, Change::alive(&b).with_key_hash(k));
    let mut gone = Vec::new();
    for id in 1..=40 {
        let (b, k) = sample(id, id);
        gone.push(write(&mut net, Change::alive(&b).with_key_hash(k)));
        let key = [0, 1, 0, 0, id as u8, 0, 0, 0];
        gone.push(write(&mut net, Change::unregister(&key, k)));
        net.run_for(Duration::from_millis(50));
    }
    assert!(net.run_until(Duration::from_secs(10), |n| n.samples(1).len() == 81));
    let got: Vec<i64> = net.samples(1).iter().map(|s| s.sequence_number.0).collect();
    let mut all = vec![kept];
    all.extend(&gone);
    assert_eq!(got, all, "the early reader gets every change");
    net.run_for(Duration::from_secs(1)); // its acknowledgements arrive
    let now = net.now();
    let late = net.hosts[2]
        .node
        .create_reader(tl_reader(Durability::TransientLocal), now)
        .unwrap();
    assert!(
        net.run_until(Duration::from_secs(10), |n| matched(n, 0, w, 2, late)
            && !n.samples(2).is_empty())
    );
    net.run_for(Duration::from_secs(1));
    let got: Vec<i64> = net.samples(2).iter().map(|s| s.sequence_number.0).collect();
    assert_eq!(got, [kept], "the live instance only");
}

/// LIFESPAN on the writer side: a transient-local writer's history holds
/// a sample for its lifespan only, so a late joiner gets what is still
/// valid and nothing older (audit 18: a Courier writer with a 2 s lifespan
/// handed samples 3.5 s old to a late-joining Cyclone reader). A source
/// timestamp given with the change counts from then.
#[test]
fn a_transient_local_writer_keeps_samples_for_their_lifespan_only() {
    let mut net = new_net(3, 22, 0);
    let now = net.now();
    let mut cfg = tl_writer(10);
    cfg.qos.lifespan = RtpsDuration::from_std(Duration::from_secs(2));
    let w = net.hosts[0].node.create_writer(cfg, now).unwrap();
    let write = |net: &mut Net, n: i32, stamp: Option<courier_wire::rtps::Time>| {
        let (b, k) = sample(n, n);
        let now = net.now();
        let mut c = Change::alive(&b).with_key_hash(k);
        c.source_timestamp = stamp;
        net.hosts[0].node.write(w, c, now).unwrap();
    };
    write(&mut net, 1, None);
    write(&mut net, 2, None);
    net.run_for(Duration::from_millis(1500));
    write(&mut net, 3, None);
    // stamped 1.2 s ago: it expires at 2.3 s, 1.2 s before 3
    let d = (net.wall() - Duration::from_millis(1200))
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap();
    let stamp = courier_wire::rtps::Time {
        seconds: d.as_secs() as i32,
        fraction: ((u64::from(d.subsec_nanos()) << 32) / 1_000_000_000) as u32,
    };
    write(&mut net, 4, Some(stamp));
    net.run_for(Duration::from_millis(1000));
    // at 2.5 s: 1, 2 and 4 expired, 3 has a second left
    let now = net.now();
    let late = net.hosts[1]
        .node
        .create_reader(tl_reader(Durability::TransientLocal), now)
        .unwrap();
    assert!(
        net.run_until(Duration::from_secs(10), |n| matched(n, 0, w, 1, late)
            && !n.samples(1).is_empty())
    );
    net.run_for(Duration::from_millis(200));
    let got: Vec<i64> = net.samples(1).iter().map(|s| s.sequence_number.0).collect();
    assert_eq!(got, [3], "only what is still within its lifespan");
    // and once 3 expired, the next late joiner gets nothing
    net.run_for(Duration::from_secs(2));
    let now = net.now();
    let later = net.hosts[2]
        .node
        .create_reader(tl_reader(Durability::TransientLocal), now)
        .unwrap();
    assert!(net.run_until(Duration::from_secs(10), |n| matched(n, 0, w, 2, later)));
    net.run_for(Duration::from_secs(1));
    assert!(net.samples(2).is_empty(), "{:?}", net.samples(2));
}

/// A participant whose table of peers is full of participants that
/// announced no endpoint (audit 20: 1100 forged SPDP announcements with
/// long leases) still finds a newcomer with a writer for its reader: the
/// newcomer takes the place of the one heard from least recently, which
/// is reported lost (`Evicted`). Before, the newcomer was refused for as
/// long as the others' leases ran.
#[test]
fn a_full_table_of_idle_participants_makes_room_for_a_newcomer() {
    let mut net = Net::new(38, Faults::none());
    for i in 0..4u8 {
        let mut cfg = Config::udpv4(0, u32::from(i), guid_prefix([i + 1; 10]), LO)
            .unwrap()
            .with_unicast_peers(&[LO], 9);
        if i == 0 {
            cfg.max_participants = 2;
        }
        let p = Participant::new(cfg, net.now(), net.wall());
        net.add(p);
    }
    let now = net.now();
    let r = net.hosts[0]
        .node
        .create_reader(reliable_reader("T", "t"), now)
        .unwrap();
    // hosts 1 and 2 (no endpoints) fill host 0's table first
    net.run_for(Duration::from_secs(2));
    assert_eq!(net.hosts[0].node.participants().count(), 2);
    let now = net.now();
    let mut q = EndpointQos::writer_default();
    q.reliability = rel();
    let w = net.hosts[3]
        .node
        .create_writer(EndpointConfig::writer("T", "t").qos(q), now)
        .unwrap();
    assert!(
        net.run_until(Duration::from_secs(10), |n| matched(n, 3, w, 0, r)),
        "the newcomer with a writer was never matched"
    );
    assert!(net.has(0, |e| matches!(
        e,
        Event::ParticipantLost {
            reason: LostReason::Evicted,
            ..
        }
    )));
    // and it keeps its place: it has an endpoint now
    net.run_for(Duration::from_secs(5));
    assert!(matched(&net, 3, w, 0, r));
    assert!(net.hosts[0]
        .node
        .participants()
        .any(|p| p.guid_prefix == net.hosts[3].node.guid_prefix()));
}

/// Remote endpoints are bounded in bytes as well as in number (audit 20:
/// endpoints announcing 60 KB of type information each could take about
/// 4 GiB within the 65 536-endpoint bound): past
/// `max_remote_endpoint_bytes` a new one is not tracked and counted in
/// `discovery_limited`; one that goes gives its bytes back.
#[test]
fn remote_endpoints_are_bounded_in_bytes() {
    let mut net = Net::new(39, Faults::none());
    // 2000 bytes of partition names per endpoint
    let big = |topic: String| {
        let mut q = EndpointQos::writer_default();
        q.partitions = (0..10).map(|k| format!("{k}{}", "p".repeat(199))).collect();
        EndpointConfig::writer(&topic, "t").qos(q)
    };
    for i in 0..2u8 {
        let mut cfg = Config::udpv4(0, u32::from(i), guid_prefix([i + 1; 10]), LO)
            .unwrap()
            .with_unicast_peers(&[LO], 9);
        if i == 0 {
            // room for three of those endpoints, not four
            cfg.max_remote_endpoint_bytes =
                3 * (std::mem::size_of::<courier_wire::rtps::discovery::EndpointData>() + 2400);
        }
        let p = Participant::new(cfg, net.now(), net.wall());
        net.add(p);
    }
    let now = net.now();
    let ws: Vec<Guid> = (0..5)
        .map(|k| {
            net.hosts[1]
                .node
                .create_writer(big(format!("t{k}")), now)
                .unwrap()
        })
        .collect();
    net.run_for(Duration::from_secs(3));
    assert_eq!(net.hosts[0].node.publications().count(), 3);
    assert_eq!(net.hosts[0].node.stats().discovery_limited, 2);
    // two of those tracked go: their room takes a new one
    let tracked: Vec<Guid> = net.hosts[0].node.publications().map(|d| d.guid).collect();
    let now = net.now();
    for g in &tracked[..2] {
        assert!(net.hosts[1].node.delete_writer(*g, now));
    }
    net.run_for(Duration::from_secs(2));
    assert_eq!(net.hosts[0].node.publications().count(), 1);
    let now = net.now();
    let late = net.hosts[1]
        .node
        .create_writer(big("late".into()), now)
        .unwrap();
    net.run_for(Duration::from_secs(2));
    assert!(
        net.hosts[0].node.publications().any(|d| d.guid == late),
        "room given back is used"
    );
    assert!(ws.contains(&tracked[2]));
}

/// A participant with a short lease (600 ms) that sends nothing else
/// announces itself often enough: its peer keeps it for 10 s of idleness
/// (with 3 s announcements it was lost and found again every few seconds).
#[test]
fn an_idle_participant_with_a_short_lease_is_not_lost() {
    let mut net = Net::new(37, Faults::none());
    for i in 0..2u8 {
        let mut cfg = Config::udpv4(0, u32::from(i), guid_prefix([i + 1; 10]), LO)
            .unwrap()
            .with_unicast_peers(&[LO], 9);
        cfg.lease_duration = Duration::from_millis(600);
        let p = Participant::new(cfg, net.now(), net.wall());
        net.add(p);
    }
    assert!(net.run_until(Duration::from_secs(5), |n| n.hosts[0]
        .node
        .participants()
        .count()
        == 1));
    net.run_for(Duration::from_secs(10));
    assert!(
        !net.has(0, |e| matches!(e, Event::ParticipantLost { .. })),
        "lost while it lived"
    );
}

#[test]
fn a_silent_participant_is_lost_after_its_lease_and_a_closed_one_at_once() {
    let mut net = new_net(3, 31, 0);
    let (p1, p2) = (net.guid(1), net.guid(2));
    let now = net.now();
    let w = net.hosts[0]
        .node
        .create_writer(EndpointConfig::writer("L", "T"), now)
        .unwrap();
    let r = net.hosts[1]
        .node
        .create_reader(reliable_reader("L", "T"), now)
        .unwrap();
    assert!(
        net.run_until(Duration::from_secs(10), |n| matched(n, 0, w, 1, r)
            && n.hosts[0].node.participants().count() == 2)
    );
    // node 1 crashes: no goodbye
    net.hosts[1].up = false;
    let crash = net.now();
    assert!(
        net.run_until(Duration::from_secs(30), |n| n.has(0, |e| matches!(
            e,
            Event::ParticipantLost { prefix, reason: LostReason::LeaseExpired } if *prefix == p1
        )))
    );
    let after = net.now() - crash;
    assert!(
        after >= Duration::from_secs(7) && after <= Duration::from_secs(11),
        "lost after {after:?} (lease 10 s, last announcement up to 3 s before the crash)"
    );
    let ev = &net.hosts[0].events;
    let pos = |f: &dyn Fn(&Event) -> bool| ev.iter().position(f).unwrap();
    let unmatched = pos(
        &|e| matches!(e, Event::WriterUnmatched { writer, reader } if *writer == w && *reader == r),
    );
    let sub_lost = pos(&|e| matches!(e, Event::SubscriptionLost(g) if *g == r));
    let lost = pos(&|e| matches!(e, Event::ParticipantLost { prefix, .. } if *prefix == p1));
    assert!(
        unmatched < sub_lost && sub_lost < lost,
        "endpoints go first"
    );
    assert!(net.hosts[0].node.matched_readers(w).is_empty());
    // node 2 leaves properly: lost at once, as disposed
    let now = net.now();
    net.hosts[2].node.close(now);
    net.pump();
    assert!(
        net.run_until(Duration::from_millis(100), |n| n.has(0, |e| matches!(
            e,
            Event::ParticipantLost { prefix, reason: LostReason::Disposed } if *prefix == p2
        )))
    );
}

#[test]
fn qos_mismatch_gives_an_incompatibility_and_no_match() {
    let mut net = new_net(2, 41, 0);
    let now = net.now();
    let mut be = EndpointQos::writer_default();
    be.reliability = Reliability::BestEffort;
    let w = net.hosts[0]
        .node
        .create_writer(EndpointConfig::writer("Q", "T").qos(be), now)
        .unwrap();
    let r = net.hosts[1]
        .node
        .create_reader(reliable_reader("Q", "T"), now)
        .unwrap();
    // a partition mismatch and an XCDR2-only writer on other topics
    let mut part = EndpointQos::writer_default();
    part.partitions = vec!["a".into()];
    let wp = net.hosts[0]
        .node
        .create_writer(EndpointConfig::writer("P", "T").qos(part), now)
        .unwrap();
    let mut rp = EndpointQos::reader_default();
    rp.partitions = vec!["b*".into()];
    net.hosts[1]
        .node
        .create_reader(EndpointConfig::reader("P", "T").qos(rp), now)
        .unwrap();
    let mut x2 = EndpointQos::writer_default();
    x2.data_representation = vec![2];
    let wx = net.hosts[0]
        .node
        .create_writer(EndpointConfig::writer("X", "T").qos(x2), now)
        .unwrap();
    net.hosts[1]
        .node
        .create_reader(EndpointConfig::reader("X", "T"), now)
        .unwrap();
    // a keyed writer and a reader of the same type without a key
    let wk = net.hosts[0]
        .node
        .create_writer(EndpointConfig::writer("K", "T").keyed(true), now)
        .unwrap();
    net.hosts[1]
        .node
        .create_reader(EndpointConfig::reader("K", "T"), now)
        .unwrap();
    // different type, same topic
    let wt = net.hosts[0]
        .node
        .create_writer(EndpointConfig::writer("Ty", "A"), now)
        .unwrap();
    net.hosts[1]
        .node
        .create_reader(EndpointConfig::reader("Ty", "B"), now)
        .unwrap();
    net.run_for(Duration::from_secs(3));
    let incompatible =
        |node: usize, local: Option<Guid>, remote: Option<Guid>| -> Vec<Incompatible> {
            net.hosts[node]
                .events
                .iter()
                .filter_map(|e| match e {
                    Event::IncompatibleQos {
                        local: l,
                        remote: rm,
                        reason,
                    } if local.is_none_or(|x| x == *l) && remote.is_none_or(|x| x == *rm) => {
                        Some(reason.clone())
                    }
                    _ => None,
                })
                .collect()
        };
    assert_eq!(
        incompatible(0, Some(w), Some(r)),
        [Incompatible::Reliability]
    );
    assert_eq!(
        incompatible(1, Some(r), Some(w)),
        [Incompatible::Reliability]
    );
    // different partitions keep endpoints apart without a word (DDS 1.4
    // §2.2.3.13; Cyclone DDS and Fast DDS report nothing either)
    assert_eq!(incompatible(0, Some(wp), None), []);
    assert_eq!(incompatible(1, None, Some(wp)), []);
    assert!(!net.has(
        0,
        |e| matches!(e, Event::WriterMatched { writer, .. } if *writer == wp)
    ));
    assert!(matches!(
        incompatible(0, Some(wx), None)[..],
        [Incompatible::DataRepresentation { .. }]
    ));
    assert!(matches!(
        incompatible(0, Some(wt), None)[..],
        [Incompatible::Type { .. }]
    ));
    let kind = incompatible(0, Some(wk), None);
    assert_eq!(
        kind,
        [Incompatible::TopicKind {
            writer_keyed: true,
            reader_keyed: false
        }]
    );
    assert_eq!(
        kind[0].to_string(),
        "topic kind: the writer is keyed (WITH_KEY), the reader not keyed (NO_KEY): declare the \
         same key fields on both sides"
    );
    assert!(!net.has(0, |e| matches!(e, Event::WriterMatched { .. })));
    assert!(!net.has(1, |e| matches!(e, Event::ReaderMatched { .. })));
    // and no user data flows
    let now = net.now();
    net.hosts[0]
        .node
        .write(w, Change::alive(b"\0\x01\0\0x"), now)
        .unwrap();
    net.run_for(Duration::from_millis(100));
    assert!(net.samples(1).is_empty());
}

#[test]
fn local_writer_and_reader_match_in_process() {
    let mut net = new_net(1, 1, 0);
    let now = net.now();
    let mut q = EndpointQos::writer_default();
    q.durability = Durability::TransientLocal;
    q.history = History::KeepLast(3);
    let w = net.hosts[0]
        .node
        .create_writer(EndpointConfig::writer("Self", "T").qos(q), now)
        .unwrap();
    for i in 0..5 {
        let (b, _) = sample(0, i);
        net.hosts[0].node.write(w, Change::alive(&b), now).unwrap();
    }
    let mut rq = EndpointQos::reader_default();
    rq.durability = Durability::TransientLocal;
    let r = net.hosts[0]
        .node
        .create_reader(EndpointConfig::reader("Self", "T").qos(rq), now)
        .unwrap();
    let (b, _) = sample(0, 5);
    net.hosts[0].node.write(w, Change::alive(&b), now).unwrap();
    net.pump();
    assert!(matched(&net, 0, w, 0, r));
    let sns: Vec<i64> = net.samples(0).iter().map(|s| s.sequence_number.0).collect();
    assert_eq!(sns, [3, 4, 5, 6]);
    assert!(net.hosts[0].node.delete_reader(r, now));
    net.pump();
    assert!(net.has(
        0,
        |e| matches!(e, Event::ReaderUnmatched { reader, .. } if *reader == r)
    ));
}

#[test]
fn deleted_endpoints_are_lost_remotely() {
    let (mut net, w, r) = matched_pair(
        51,
        10,
        EndpointConfig::writer("D", "T"),
        reliable_reader("D", "T"),
    );
    let now = net.now();
    assert!(net.hosts[0].node.delete_writer(w, now));
    net.pump();
    assert!(net.run_until(Duration::from_secs(10), |n| n
        .has(1, |e| matches!(e, Event::PublicationLost(g) if *g == w))));
    assert!(net.has(
        1,
        |e| matches!(e, Event::ReaderUnmatched { reader, writer } if *reader == r && *writer == w)
    ));
    // a participant that joins now does not learn of the deleted writer
    let mut net2 = net;
    let now = net2.now();
    let w2 = net2.hosts[0]
        .node
        .create_writer(EndpointConfig::writer("D2", "T"), now)
        .unwrap();
    net2.run_for(Duration::from_secs(1));
    assert!(net2.has(
        1,
        |e| matches!(e, Event::PublicationFound(d) if d.guid == w2)
    ));
    assert_eq!(net2.hosts[1].node.publications().count(), 1);
}

#[test]
fn hostile_datagrams_do_not_hurt() {
    let mut net = new_net(2, 61, 0);
    let now = net.now();
    let w = net.hosts[0]
        .node
        .create_writer(keyed_writer("H", "T"), now)
        .unwrap();
    let r = net.hosts[1]
        .node
        .create_reader(reliable_reader("H", "T").keyed(true), now)
        .unwrap();
    net.tapping = true;
    assert!(net.run_until(Duration::from_secs(10), |n| matched(n, 0, w, 1, r)));
    let (b, k) = sample(1, 1);
    let now = net.now();
    net.hosts[0]
        .node
        .write(w, Change::alive(&b).with_key_hash(k), now)
        .unwrap();
    net.run_for(Duration::from_millis(50));
    let corpus: Vec<Vec<u8>> = net.tap.iter().map(|d| d.payload.clone()).collect();
    assert!(!corpus.is_empty());
    // mutate real datagrams byte by byte and feed them to a fresh participant
    let mut victim = new_net(1, 62, 0);
    let now = victim.now();
    victim.hosts[0]
        .node
        .create_reader(reliable_reader("H", "T").keyed(true), now)
        .unwrap();
    let mut seed = 0x1234_5678_9abc_def0u64;
    let mut rnd = || {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        seed
    };
    for round in 0..20_000 {
        let mut d = corpus[round % corpus.len()].clone();
        for _ in 0..1 + rnd() % 4 {
            let i = (rnd() as usize) % d.len();
            d[i] = rnd() as u8;
        }
        if rnd() % 8 == 0 {
            d.truncate((rnd() as usize) % d.len());
        }
        let now = victim.now();
        victim.hosts[0]
            .node
            .handle_datagram(Locator::udpv4(LO, 1), &d, now);
        if round % 100 == 0 {
            victim.step();
        }
    }
    victim.run_for(Duration::from_secs(30));
    let s = victim.hosts[0].node.stats();
    assert_eq!(s.datagrams_received, 20_000);
    assert!(s.datagrams_malformed > 0);
}

#[test]
fn replies_carry_the_related_sample_identity_through_loss_fragments_and_late_joining() {
    use courier_wire::rtps::participant::{
        SampleIdentity, PID_FASTDDS_RELATED_SAMPLE_IDENTITY, PID_RELATED_SAMPLE_IDENTITY,
    };
    let request = SampleIdentity {
        writer: Guid::from_bytes([9; 16]),
        sequence_number: SequenceNumber((3 << 32) | 7),
    };
    let small = vec![0u8, 1, 0, 0, 42, 0, 0, 0];
    let big: Vec<u8> = [0u8, 1, 0, 0]
        .into_iter()
        .chain((0..100 * 1024).map(|i| (i % 253) as u8))
        .collect();
    for (seed, loss) in [(5u64, 0u32), (21, 30)] {
        let mut net = new_net(2, seed, loss);
        let now = net.now();
        let w = net.hosts[0].node.create_writer(tl_writer(10), now).unwrap();
        for data in [&small, &big] {
            net.hosts[0]
                .node
                .write(
                    w,
                    Change::alive(data).with_related_sample_identity(request),
                    now,
                )
                .unwrap();
        }
        net.hosts[0]
            .node
            .write(w, Change::alive(&small), now)
            .unwrap();
        net.tapping = true;
        // a transient-local reader joins after the writes: the history it
        // gets still carries the identities
        let r = net.hosts[1]
            .node
            .create_reader(tl_reader(Durability::TransientLocal), now)
            .unwrap();
        assert!(
            net.run_until(Duration::from_secs(60), |n| n.samples(1).len() == 3),
            "seed {seed}"
        );
        let got = net.samples(1);
        assert_eq!(got[0].related_sample_identity, Some(request));
        assert_eq!(got[1].related_sample_identity, Some(request));
        assert_eq!(got[1].data(), &big[..]);
        assert_eq!(got[2].related_sample_identity, None);
        assert_eq!(got[0].data(), &small[..]);
        assert_eq!(got[0].identity().writer, w);
        assert_eq!(got[0].identity().sequence_number, SequenceNumber(1));
        assert_eq!(got[0].reader, r);
        // on the wire: both PIDs, 24 bytes each, GUID then high/low
        let mut seen = 0;
        for d in &net.tap {
            for s in Message::parse(&d.payload).unwrap().submessages {
                let q = match &s {
                    Submessage::Data(d) if d.writer_id == w.entity => d.inline_qos,
                    Submessage::DataFrag(f) if f.writer_id == w.entity => f.inline_qos,
                    _ => None,
                };
                let Some(q) = q else { continue };
                let list = courier_wire::rtps::ParameterList::parse(q, true).unwrap().0;
                for pid in [
                    PID_RELATED_SAMPLE_IDENTITY,
                    PID_FASTDDS_RELATED_SAMPLE_IDENTITY,
                ] {
                    let p = list
                        .params
                        .iter()
                        .find(|p| p.pid == pid)
                        .expect("both PIDs");
                    let mut want = [9u8; 24];
                    want[16..20].copy_from_slice(&3i32.to_le_bytes());
                    want[20..].copy_from_slice(&7u32.to_le_bytes());
                    assert_eq!(p.value, want);
                }
                seen += 1;
            }
        }
        assert!(seen >= 2, "seed {seed}: {seen}");
    }
}

#[test]
fn sample_identity_bytes_in_both_byte_orders() {
    use courier_wire::rtps::participant::SampleIdentity;
    let id = SampleIdentity {
        writer: Guid::from_bytes(*b"0123456789abcdef"),
        sequence_number: SequenceNumber(0x0000_0001_0000_0002),
    };
    let le = id.to_bytes(true);
    assert_eq!(&le[..16], b"0123456789abcdef");
    assert_eq!(&le[16..], [1, 0, 0, 0, 2, 0, 0, 0]);
    let be = id.to_bytes(false);
    assert_eq!(&be[16..], [0, 0, 0, 1, 0, 0, 0, 2]);
    assert_eq!(SampleIdentity::from_bytes(&le, true), Some(id));
    assert_eq!(SampleIdentity::from_bytes(&be, false), Some(id));
    assert_eq!(
        SampleIdentity::from_bytes(&le[..23], true),
        None,
        "truncated"
    );
}

/// The user-data DATA and HEARTBEAT submessages of writer `w` in one datagram.
fn user_submessages(payload: &[u8], w: Guid) -> (Vec<i64>, Vec<(i64, bool)>) {
    let (mut data, mut hbs) = (Vec::new(), Vec::new());
    for s in Message::parse(payload).unwrap().submessages {
        match s {
            Submessage::Data(d) if d.writer_id == w.entity => data.push(d.writer_sn.0),
            Submessage::Heartbeat(h) if h.writer_id == w.entity => {
                hbs.push((h.last_sn.0, h.final_flag))
            }
            _ => {}
        }
    }
    (data, hbs)
}

#[test]
fn writes_made_before_polling_share_datagrams_and_one_heartbeat() {
    let mut net = new_net(2, 11, 0);
    let now = net.now();
    let w = net.hosts[0]
        .node
        .create_writer(keyed_writer("Burst", "T"), now)
        .unwrap();
    let r = net.hosts[1]
        .node
        .create_reader(reliable_reader("Burst", "T").keyed(true), now)
        .unwrap();
    assert!(net.run_until(Duration::from_secs(10), |n| matched(n, 0, w, 1, r)));
    net.run_for(Duration::from_millis(50));
    // 100 small samples written back to back, then polled once
    let now = net.now();
    for i in 0..100 {
        let (b, k) = sample(i % 5, i);
        net.hosts[0]
            .node
            .write(w, Change::alive(&b).with_key_hash(k), now)
            .unwrap();
    }
    let mut burst = Vec::new();
    while let Some(d) = net.hosts[0].node.poll_transmit() {
        burst.push(d);
    }
    let mut sns = Vec::new();
    let mut hbs = Vec::new();
    for d in &burst {
        assert!(d.payload.len() <= 14_720);
        let (data, hb) = user_submessages(&d.payload, w);
        sns.extend(data);
        hbs.extend(hb);
    }
    assert_eq!(sns, (1..=100).collect::<Vec<_>>(), "every sample, in order");
    assert!(
        burst.len() <= 2,
        "100 samples of ~60 bytes fit in one or two datagrams, not {}",
        burst.len()
    );
    // one heartbeat after the last sample; it asks for an acknowledgement
    // because sample 16 (and 32, …) wanted one
    assert_eq!(hbs, vec![(100, false)]);
    for d in burst {
        let from = net.hosts[0].node.config().default_unicast[0];
        net.send(sim::Packet {
            from,
            to: d.destination,
            payload: d.payload,
        });
    }
    net.run_for(Duration::from_millis(50));
    check_in_order(&net, 1, 100);
    assert!(net.hosts[0].node.is_acked_by_all(w, SequenceNumber(100)));
    // a single write still goes out at the next poll, with a final
    // heartbeat (sample 101 wants no acknowledgement)
    let (b, k) = sample(1, 100);
    let now = net.now();
    net.hosts[0]
        .node
        .write(w, Change::alive(&b).with_key_hash(k), now)
        .unwrap();
    let d = net.hosts[0].node.poll_transmit().unwrap();
    assert_eq!(
        user_submessages(&d.payload, w),
        (vec![101], vec![(101, true)])
    );
}

#[test]
fn a_keep_all_writer_stops_at_its_unacknowledged_bytes_limit_and_resumes_on_acknowledgement() {
    let mut net = new_net(2, 13, 0);
    // node 0 again, with a 64 KiB high-water mark
    let mut cfg = Config::udpv4(0, 0, guid_prefix([1; 10]), LO)
        .unwrap()
        .with_unicast_peers(&[LO], 9);
    cfg.max_unacked_bytes = 64 << 10;
    let p = Participant::new(cfg, net.now(), net.wall());
    net.hosts[0].node = p;
    let now = net.now();
    let mut wq = EndpointQos::writer_default();
    wq.history = History::KeepAll;
    let w = net.hosts[0]
        .node
        .create_writer(EndpointConfig::writer("Big", "T").qos(wq), now)
        .unwrap();
    let r = net.hosts[1]
        .node
        .create_reader(reliable_reader("Big", "T"), now)
        .unwrap();
    assert!(net.run_until(Duration::from_secs(10), |n| matched(n, 0, w, 1, r)));
    net.run_for(Duration::from_millis(50));
    // 10 KiB samples: the seventh would put 70 KiB in flight
    let mut big = vec![0u8, 1, 0, 0];
    big.resize(10 << 10, 7);
    let now = net.now();
    let mut written = 0;
    let refused = loop {
        match net.hosts[0].node.write(w, Change::alive(&big), now) {
            Ok(_) => written += 1,
            Err(e) => break e,
        }
        assert!(written < 100, "no limit");
    };
    assert_eq!(written, 6, "64 KiB / ~10 KiB samples");
    assert!(
        refused.to_string().contains("max_unacked_bytes"),
        "{refused}"
    );
    // the reader acknowledges (the burst asked for it: over half the
    // limit), and the writer takes more
    net.pump();
    assert!(net.run_until(Duration::from_secs(1), |n| n.hosts[0]
        .node
        .is_acked_by_all(w, SequenceNumber(6))));
    let now = net.now();
    net.hosts[0]
        .node
        .write(w, Change::alive(&big), now)
        .unwrap();
    // one sample larger than the whole limit is still accepted when
    // nothing else is in flight
    assert!(net.run_until(Duration::from_secs(1), |n| n.hosts[0]
        .node
        .is_acked_by_all(w, SequenceNumber(7))));
    let mut huge = vec![0u8, 1, 0, 0];
    huge.resize(100 << 10, 9);
    let now = net.now();
    net.hosts[0]
        .node
        .write(w, Change::alive(&huge), now)
        .unwrap();
    assert!(net.hosts[0]
        .node
        .write(w, Change::alive(&big), now)
        .is_err());
    net.run_for(Duration::from_millis(200));
    assert_eq!(net.samples(1).len(), 8);
}
