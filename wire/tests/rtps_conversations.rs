//! Replays of real conversations: every UDP payload a Cyclone DDS 11 and a
//! Fast DDS 2.9 publisher sent to its subscriber (SPDP, SEDP, five small
//! HelloWorld samples, one ~100 KiB fragmented sample, SPDP dispose), fed
//! with the captured timing into a Courier [`Participant`] that stands where
//! that subscriber stood: the same GUID prefix (Cyclone and Fast DDS address
//! it with INFO_DST), the same locators (127.0.0.1:7410/7411) and a reader on
//! the same topic, type and QoS.
//!
//! Fixtures: `tests/fixtures/rtps/*_conversation.txt` (copied from the pcaps
//! in shared/fixtures/rtps; see their headers). Expected values come from the
//! tshark decodes there (`spdp_*.txt`, `sedp_pub_*.txt`) and from the bytes
//! of the capture itself. What Courier sends back is parsed with
//! [`Message::parse`] and checked submessage by submessage.

use std::collections::{BTreeMap, BTreeSet};
use std::time::{Duration, Instant, SystemTime};

use courier_wire::rtps::discovery::{
    payload_params, Durability, Duration as RtpsDuration, EndpointData, EndpointQos, History,
    LivelinessKind, ParticipantData, Reliability,
};
use courier_wire::rtps::participant::{
    ChangeKind, Config, Datagram, EndpointConfig, Event, LostReason, Participant, ReceivedSample,
    PROTOCOL_VERSION, VENDOR_ID,
};
use courier_wire::rtps::{
    AckNack, EntityId, Guid, GuidPrefix, Locator, Message, ProtocolVersion, SequenceNumber,
    Submessage, Time, VendorId,
};

const LO: [u8; 4] = [127, 0, 0, 1];

fn lo(port: u16) -> Locator {
    Locator::udpv4(LO, port)
}

fn prefix(hex: &str) -> GuidPrefix {
    let b = unhex(hex);
    GuidPrefix(b.try_into().expect("12 bytes"))
}

fn unhex(hex: &str) -> Vec<u8> {
    assert!(hex.len() % 2 == 0, "odd hex {hex:?}");
    (0..hex.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&hex[i..i + 2], 16).expect("hex"))
        .collect()
}

// ---- the fixture format ----

/// One captured datagram: when (ms after the first), to which of the
/// subscriber's ports, and its bytes.
struct Frame {
    ms: u64,
    port: u16,
    bytes: Vec<u8>,
}

/// A conversation file: its `#` header and its datagrams.
struct Conversation {
    header: String,
    frames: Vec<Frame>,
}

/// Parses `@<ms> <port> <hex…>` entries; continuation lines start with a
/// space; `xx*N` is byte xx repeated N times.
fn load(text: &str) -> Conversation {
    let mut header = String::new();
    let mut frames: Vec<Frame> = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let toks: Vec<&str> = if let Some(h) = line.strip_prefix('#') {
            header.push_str(h);
            header.push('\n');
            continue;
        } else if let Some(rest) = line.strip_prefix('@') {
            let mut it = rest.split_whitespace();
            let ms = it.next().and_then(|s| s.parse().ok());
            let port = it.next().and_then(|s| s.parse().ok());
            let (Some(ms), Some(port)) = (ms, port) else {
                panic!("line {}: bad entry {line:?}", n + 1);
            };
            frames.push(Frame {
                ms,
                port,
                bytes: Vec::new(),
            });
            it.collect()
        } else if line.starts_with(' ') {
            line.split_whitespace().collect()
        } else {
            assert!(line.trim().is_empty(), "line {}: {line:?}", n + 1);
            continue;
        };
        let f = frames.last_mut().expect("bytes before the first entry");
        for t in toks {
            match t.split_once('*') {
                Some((b, count)) => {
                    let b = unhex(b);
                    assert_eq!(b.len(), 1, "line {}: {t}", n + 1);
                    let count: usize = count.parse().expect("repeat count");
                    f.bytes.extend(std::iter::repeat_n(b[0], count));
                }
                None => f.bytes.extend(unhex(t)),
            }
        }
    }
    Conversation { header, frames }
}

/// The number written just before `word` in the header ("… 5 small samples").
fn header_number_before(header: &str, word: &str) -> usize {
    let at = header
        .find(word)
        .unwrap_or_else(|| panic!("header lacks {word:?}"));
    let digits: String = header[..at]
        .trim_end()
        .chars()
        .rev()
        .take_while(|c| c.is_ascii_digit())
        .collect();
    digits.chars().rev().collect::<String>().parse().unwrap()
}

/// The 24-hex-digit prefix right after `label` in the header.
fn header_prefix_after(header: &str, label: &str) -> GuidPrefix {
    let at = header
        .find(label)
        .unwrap_or_else(|| panic!("header lacks {label:?}"))
        + label.len();
    prefix(&header[at..at + 24])
}

// ---- the two peers ----

/// What one capture is about, with the values the decodes show.
struct Peer {
    name: &'static str,
    conversation: &'static str,
    /// The subscriber's own SEDP subscription from the same capture: our
    /// reader takes its QoS.
    subscription: &'static str,
    subscriber: GuidPrefix,
    participant: ParticipantData,
    publication: EndpointData,
    /// The small samples say `<hello><i>`, the big one `<big>yyy…`.
    hello: &'static str,
    big: &'static str,
}

fn infinite_qos(reliability: Reliability, history: History) -> EndpointQos {
    EndpointQos {
        reliability,
        durability: Durability::Volatile,
        history,
        deadline: RtpsDuration::INFINITE,
        liveliness: (LivelinessKind::Automatic, RtpsDuration::INFINITE),
        exclusive_ownership: false,
        ownership_strength: 0,
        partitions: Vec::new(),
        time_based_filter: RtpsDuration::ZERO,
        lifespan: RtpsDuration::INFINITE,
        data_representation: vec![0],
    }
}

/// `cyclone11_pubsub.pcap`: `spdp_cyclone11.txt` (the publisher's SPDP has
/// the same shape), `sedp_pub_cyclone11.txt` (frame 99).
fn cyclone() -> Peer {
    let publisher = prefix("0110a163667e51497ce8988f");
    Peer {
        name: "cyclone11",
        conversation: include_str!("fixtures/rtps/cyclone11_conversation.txt"),
        subscription: include_str!("fixtures/rtps/cyclone11_sedp_sub.hex"),
        subscriber: prefix("0110d95abd150ef8db60a89b"),
        participant: ParticipantData {
            guid_prefix: publisher,
            protocol_version: ProtocolVersion::V2_5,
            vendor: VendorId::CYCLONE,
            domain_id: Some(0),
            default_unicast: vec![lo(7413)],
            default_multicast: vec![],
            metatraffic_unicast: vec![lo(7412)],
            metatraffic_multicast: vec![],
            lease_duration: RtpsDuration {
                seconds: 10,
                fraction: 0,
            },
            builtin_endpoints: 0x0000_fc3f,
            entity_name: None,
        },
        publication: EndpointData {
            guid: Guid {
                prefix: publisher,
                entity: EntityId([0, 0, 2, 0x03]),
            },
            topic_name: "HelloWorldTopic".into(),
            type_name: "HelloWorld".into(),
            // only RELIABILITY (max blocking 1 s) and HISTORY are sent:
            // Cyclone omits what is at its default
            qos: infinite_qos(
                Reliability::Reliable(RtpsDuration {
                    seconds: 1,
                    fraction: 0,
                }),
                History::KeepLast(10),
            ),
            unicast: vec![],
            multicast: vec![],
            expects_inline_qos: false,
            type_information: Some(unhex(concat!(
                "6000000001100040280000002400000014000000f13dab25136a988a73d82a83",
                "002efa000000000000000000040000000000000002100040280000002400000014",
                "000000f2608c64d849e9f45dc8ed4ec261cc0000000000000000000400000000000000",
            ))),
            // Cyclone leaves a deleted writer's autodispose to its readers;
            // no PID_ADLINK_WRITER_DATA_LIFECYCLE: DDS's default, true
            disposes_when_deleted: true,
        },
        hello: "Hello from Cyclone #",
        big: "BIG from Cyclone ",
    }
}

/// `fastdds_pubsub.pcap`: `spdp_fastdds.txt`, `sedp_pub_fastdds.txt` (frame 269).
fn fastdds() -> Peer {
    let publisher = prefix("010f7f013f53a72d00000000");
    Peer {
        name: "fastdds",
        conversation: include_str!("fixtures/rtps/fastdds_conversation.txt"),
        subscription: include_str!("fixtures/rtps/fastdds_sedp_sub.hex"),
        subscriber: prefix("010f7f010953271500000000"),
        participant: ParticipantData {
            guid_prefix: publisher,
            protocol_version: ProtocolVersion::V2_3,
            vendor: VendorId::EPROSIMA,
            domain_id: None,
            default_unicast: vec![lo(7413)],
            default_multicast: vec![],
            metatraffic_unicast: vec![lo(7412)],
            metatraffic_multicast: vec![],
            lease_duration: RtpsDuration {
                seconds: 20,
                fraction: 0,
            },
            builtin_endpoints: 0x0c3f_0c3f,
            entity_name: Some("RTPSParticipant".into()),
        },
        publication: EndpointData {
            guid: Guid {
                prefix: publisher,
                entity: EntityId([0, 0, 1, 0x03]),
            },
            topic_name: "HelloWorldTopic".into(),
            type_name: "HelloWorld".into(),
            // every QoS is sent except HISTORY (so the DDS default, keep
            // last 1, is what a reader can know) and DATA_REPRESENTATION
            qos: infinite_qos(
                Reliability::Reliable(RtpsDuration {
                    seconds: 0,
                    fraction: 0x1999_999a, // 100 ms
                }),
                History::KeepLast(1),
            ),
            unicast: vec![lo(7413)],
            multicast: vec![],
            expects_inline_qos: false,
            type_information: None,
            disposes_when_deleted: false,
        },
        hello: "Hello from Fast DDS #",
        big: "BIG from Fast DDS ",
    }
}

/// The subscriber's reader QoS, from its own SEDP announcement in the capture.
fn subscriber_qos(peer: &Peer) -> EndpointQos {
    let hex: String = peer
        .subscription
        .lines()
        .filter(|l| !l.starts_with('#'))
        .collect();
    let b = unhex(&hex);
    let m = Message::parse(&b).unwrap();
    let d = m
        .submessages
        .iter()
        .find_map(|s| match s {
            Submessage::Data(d) if d.writer_id == EntityId::SEDP_SUBSCRIPTIONS_WRITER => Some(d),
            _ => None,
        })
        .expect("SEDP subscription");
    let e = EndpointData::from_params(&payload_params(d.payload.unwrap()).unwrap(), false).unwrap();
    assert_eq!(e.guid.prefix, peer.subscriber, "{}", peer.name);
    assert_eq!(
        (e.topic_name.as_str(), e.type_name.as_str()),
        ("HelloWorldTopic", "HelloWorld")
    );
    e.qos
}

// ---- the replay ----

/// What made the participant act.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Cause {
    /// Creation, reader creation.
    Setup,
    /// `handle_timeout`.
    Timer,
    /// `handle_datagram` with this replay's datagram number.
    Input(usize),
}

/// A Courier participant in the subscriber's place, with everything it did.
struct Replay {
    p: Participant,
    reader: Guid,
    reader_qos: EndpointQos,
    /// When the first datagram of the current pass arrives.
    base: Instant,
    now: Instant,
    /// Frame numbers restart at each pass; this one's start in `sent`/`events`.
    sent: Vec<(Cause, Datagram)>,
    events: Vec<(Cause, Event)>,
    /// Per datagram of the current pass: `sent.len()` just before it was handled.
    marks: Vec<usize>,
}

/// The subscriber was up about a second before the publisher in both captures.
const LEAD: Duration = Duration::from_secs(1);

impl Replay {
    fn new(peer: &Peer, our_prefix: GuidPrefix) -> Replay {
        let t0 = Instant::now();
        let wall = SystemTime::UNIX_EPOCH + Duration::from_secs(1_795_349_255);
        let cfg = Config::udpv4(0, 0, our_prefix, LO).unwrap();
        assert_eq!(cfg.metatraffic_unicast, [lo(7410)]);
        assert_eq!(cfg.default_unicast, [lo(7411)]);
        let mut p = Participant::new(cfg, t0, wall);
        let reader_qos = subscriber_qos(peer);
        let reader = p
            .create_reader(
                EndpointConfig::reader("HelloWorldTopic", "HelloWorld").qos(reader_qos.clone()),
                t0,
            )
            .unwrap();
        let mut r = Replay {
            p,
            reader,
            reader_qos,
            base: t0 + LEAD,
            now: t0,
            sent: Vec::new(),
            events: Vec::new(),
            marks: Vec::new(),
        };
        r.collect(Cause::Setup);
        r
    }

    fn collect(&mut self, cause: Cause) {
        while let Some(d) = self.p.poll_transmit() {
            self.sent.push((cause, d));
        }
        while let Some(e) = self.p.poll_event() {
            self.events.push((cause, e));
        }
    }

    /// Fires every timer due up to `to`, each at its own time.
    fn advance(&mut self, to: Instant) {
        for _ in 0..1_000_000 {
            match self.p.poll_timeout() {
                Some(t) if t <= to => {
                    self.now = self.now.max(t);
                    self.p.handle_timeout(self.now);
                    self.collect(Cause::Timer);
                }
                _ => {
                    self.now = self.now.max(to);
                    return;
                }
            }
        }
        panic!("timers never settle");
    }

    /// Delivers datagram `i` (of this pass) `ms` after the pass began.
    fn deliver(&mut self, i: usize, ms: u64, bytes: &[u8]) {
        self.advance(self.base + Duration::from_millis(ms));
        self.marks.push(self.sent.len());
        // the publisher sent from an ephemeral port, not one it announced
        self.p
            .handle_datagram(Locator::udpv4(LO, 38946), bytes, self.now);
        self.collect(Cause::Input(i));
    }

    /// Feeds a whole conversation with its timing, then lets `after` pass.
    fn play(&mut self, frames: &[Frame], after: Duration) {
        self.marks.clear();
        for (i, f) in frames.iter().enumerate() {
            assert!(
                [7410, 7411].contains(&f.port),
                "sent to one of the subscriber's locators"
            );
            self.deliver(i, f.ms, &f.bytes);
        }
        let end = self.base + Duration::from_millis(frames.last().map_or(0, |f| f.ms)) + after;
        self.advance(end);
    }
}

// ---- what the publisher sent ----

/// The publisher's submessages that matter here, flattened, with the INFO_TS
/// in force for each.
#[derive(Debug, Clone)]
enum In {
    Data {
        writer: EntityId,
        sn: i64,
        ts: Option<Time>,
        payload: Vec<u8>,
    },
    Frag {
        writer: EntityId,
        sn: i64,
        ts: Option<Time>,
        first: u32,
        count: u16,
        fragment_size: u16,
        sample_size: u32,
        payload: Vec<u8>,
    },
    Heartbeat {
        writer: EntityId,
        first: i64,
        last: i64,
        final_flag: bool,
    },
    AckNack {
        writer: EntityId,
        base: i64,
        missing: Vec<i64>,
    },
}

/// The publisher's submessages addressed to the subscriber (no INFO_DST or
/// one naming it), per datagram.
fn inputs(frames: &[Frame], subscriber: GuidPrefix) -> Vec<Vec<In>> {
    frames
        .iter()
        .map(|f| {
            let m = Message::parse(&f.bytes).expect("the capture parses");
            let mut dst = GuidPrefix::UNKNOWN;
            let mut ts = None;
            let mut out = Vec::new();
            for s in &m.submessages {
                match s {
                    Submessage::InfoDst(p) => dst = *p,
                    Submessage::InfoTs(t) => ts = *t,
                    _ => {}
                }
                if dst != GuidPrefix::UNKNOWN && dst != subscriber {
                    continue;
                }
                out.push(match s {
                    Submessage::Data(d) => In::Data {
                        writer: d.writer_id,
                        sn: d.writer_sn.0,
                        ts,
                        payload: d.payload.unwrap_or(&[]).to_vec(),
                    },
                    Submessage::DataFrag(d) => In::Frag {
                        writer: d.writer_id,
                        sn: d.writer_sn.0,
                        ts,
                        first: d.fragment_starting_num,
                        count: d.fragments_in_submessage,
                        fragment_size: d.fragment_size,
                        sample_size: d.sample_size,
                        payload: d.payload.to_vec(),
                    },
                    Submessage::Heartbeat(h) => In::Heartbeat {
                        writer: h.writer_id,
                        first: h.first_sn.0,
                        last: h.last_sn.0,
                        final_flag: h.final_flag,
                    },
                    Submessage::AckNack(a) => In::AckNack {
                        writer: a.writer_id,
                        base: a.reader_sn_state.base.0,
                        missing: a.reader_sn_state.iter().map(|s| s.0).collect(),
                    },
                    _ => continue,
                });
            }
            out
        })
        .collect()
}

/// A sample as the capture has it: sequence number, source timestamp, bytes.
#[derive(Debug, Clone, PartialEq)]
struct Expected {
    sn: i64,
    ts: Option<Time>,
    data: Vec<u8>,
}

/// The user writer's samples from the capture; fragments are put together
/// here independently of Courier's reassembler (the timestamp is the one in
/// force for the first fragment).
fn expected_samples(ins: &[Vec<In>], writer: EntityId) -> Vec<Expected> {
    let mut done: BTreeMap<i64, Expected> = BTreeMap::new();
    let mut partial: BTreeMap<i64, (Expected, usize, usize)> = BTreeMap::new();
    for i in ins.iter().flatten() {
        match i {
            In::Data {
                writer: w,
                sn,
                ts,
                payload,
            } if *w == writer => {
                done.entry(*sn).or_insert(Expected {
                    sn: *sn,
                    ts: *ts,
                    data: payload.clone(),
                });
            }
            In::Frag {
                writer: w,
                sn,
                ts,
                first,
                count,
                fragment_size,
                sample_size,
                payload,
            } if *w == writer => {
                let fs = usize::from(*fragment_size);
                let size = *sample_size as usize;
                let total = size.div_ceil(fs);
                let e = partial.entry(*sn).or_insert_with(|| {
                    (
                        Expected {
                            sn: *sn,
                            ts: *ts,
                            data: vec![0; size],
                        },
                        0,
                        total,
                    )
                });
                let start = (*first as usize - 1) * fs;
                let end = (start + usize::from(*count) * fs).min(size);
                e.0.data[start..end].copy_from_slice(&payload[..end - start]);
                e.1 += usize::from(*count);
                if e.1 == e.2 {
                    let (x, _, _) = partial.remove(sn).unwrap();
                    done.insert(*sn, x);
                }
            }
            _ => {}
        }
    }
    assert!(partial.is_empty(), "every fragment is in the capture");
    done.into_values().collect()
}

/// `struct HelloWorld { long id; string msg; }` in CDR_LE with its
/// encapsulation header; what follows the string is at most 3 zero bytes.
fn hello_world(b: &[u8]) -> (i32, String) {
    assert_eq!(&b[..4], &[0, 1, 0, 0], "CDR_LE, options 0");
    let id = i32::from_le_bytes(b[4..8].try_into().unwrap());
    let n = u32::from_le_bytes(b[8..12].try_into().unwrap()) as usize;
    let s = &b[12..12 + n];
    assert_eq!(s.last(), Some(&0), "NUL-terminated");
    let pad = &b[12 + n..];
    assert!(
        pad.len() < 4 && pad.iter().all(|x| *x == 0),
        "padding {pad:?}"
    );
    (id, String::from_utf8(s[..n - 1].to_vec()).unwrap())
}

// ---- what Courier sent ----

/// One submessage Courier sent, with where it went.
struct Out<'a> {
    /// Index of its datagram in the slice given to [`outputs`].
    idx: usize,
    cause: Cause,
    to: Locator,
    /// The INFO_DST in force (UNKNOWN if none).
    dst: GuidPrefix,
    sm: Submessage<'a>,
}

fn outputs(sent: &[(Cause, Datagram)], ours: GuidPrefix) -> Vec<Out<'_>> {
    let mut v = Vec::new();
    for (idx, (cause, d)) in sent.iter().enumerate() {
        let m = Message::parse(&d.payload).expect("what Courier sends parses");
        assert_eq!(m.header.guid_prefix, ours);
        assert_eq!(m.header.vendor, VENDOR_ID);
        assert_eq!(m.header.version, PROTOCOL_VERSION);
        let mut dst = GuidPrefix::UNKNOWN;
        for sm in m.submessages {
            if let Submessage::InfoDst(p) = sm {
                dst = p;
            }
            v.push(Out {
                idx,
                cause: *cause,
                to: d.destination,
                dst,
                sm,
            });
        }
    }
    v
}

fn samples(events: &[(Cause, Event)]) -> Vec<&ReceivedSample> {
    events
        .iter()
        .filter_map(|(_, e)| match e {
            Event::SampleReceived(s) => Some(s),
            _ => None,
        })
        .collect()
}

/// The SEDP reader that answers a peer's SEDP writer.
fn sedp_reader_of(writer: EntityId) -> Option<EntityId> {
    match writer {
        EntityId::SEDP_PUBLICATIONS_WRITER => Some(EntityId::SEDP_PUBLICATIONS_READER),
        EntityId::SEDP_SUBSCRIPTIONS_WRITER => Some(EntityId::SEDP_SUBSCRIPTIONS_READER),
        _ => None,
    }
}

/// Checks the samples delivered: each one once, in order, the capture's
/// bytes, decoded as HelloWorld.
fn check_samples(peer: &Peer, c: &Conversation, r: &Replay, events: &[(Cause, Event)]) {
    let name = peer.name;
    let writer = peer.publication.guid;
    let ins = inputs(&c.frames, peer.subscriber);
    let want = expected_samples(&ins, writer.entity);
    let small = header_number_before(&c.header, "small samples");
    let big_size = header_number_before(&c.header, "-byte sample");
    assert_eq!(want.len(), small + 1, "{name}: the header's sample count");
    let got: Vec<&ReceivedSample> = samples(events)
        .into_iter()
        .filter(|s| s.writer == writer)
        .collect();
    assert_eq!(got.len(), want.len(), "{name}: each sample exactly once");
    for (i, (s, w)) in got.iter().zip(&want).enumerate() {
        assert_eq!(s.reader, r.reader, "{name}");
        assert_eq!(s.sequence_number, SequenceNumber(i as i64 + 1), "{name}");
        assert_eq!(s.sequence_number.0, w.sn, "{name}");
        assert_eq!(s.kind, ChangeKind::Alive, "{name}");
        assert_eq!(s.key_hash, None, "{name}: keyless type, no PID_KEY_HASH");
        assert!(s.data() == &w.data[..], "{name}: sample {} bytes", w.sn);
        assert_eq!(
            s.source_timestamp, w.ts,
            "{name}: sample {} source timestamp",
            w.sn
        );
        assert!(w.ts.is_some(), "{name}: both vendors send INFO_TS");
        let (id, msg) = hello_world(s.data());
        assert_eq!(id, i as i32, "{name}");
        if i < small {
            assert_eq!(msg, format!("{}{i}", peer.hello), "{name}");
        } else {
            assert_eq!(s.data().len(), big_size, "{name}: the header's size");
            let body = msg.strip_prefix(peer.big).expect("BIG …");
            assert_eq!(peer.big.len() + body.len(), 102_400, "{name}");
            assert!(body.bytes().all(|b| b == b'y'), "{name}");
        }
    }
}

/// Checks the replay of a whole conversation by a fresh participant.
fn check_conversation(peer: &Peer) {
    let name = peer.name;
    let c = load(peer.conversation);
    let publisher = peer.participant.guid_prefix;
    let writer = peer.publication.guid;

    // the header says what is in the file
    let frames_listed = c.header.split("frames ").nth(1).expect("frame list");
    let frames_listed = frames_listed[..frames_listed.find(')').unwrap()]
        .split(',')
        .count();
    assert_eq!(frames_listed, c.frames.len(), "{name}: one entry per frame");
    assert_eq!(header_prefix_after(&c.header, "(prefix "), publisher);
    assert_eq!(
        header_prefix_after(&c.header, "Subscriber prefix: "),
        peer.subscriber
    );
    assert!(c.frames.windows(2).all(|w| w[0].ms <= w[1].ms));
    for f in &c.frames {
        let m = Message::parse(&f.bytes).unwrap();
        assert_eq!(m.header.guid_prefix, publisher, "{name}: publisher only");
        for s in &m.submessages {
            if let Submessage::InfoDst(p) = s {
                assert!(
                    *p == GuidPrefix::UNKNOWN || *p == peer.subscriber,
                    "{name}: addressed to the subscriber"
                );
            }
        }
    }

    let mut r = Replay::new(peer, peer.subscriber);
    r.play(&c.frames, Duration::from_secs(10));
    let last = c.frames.len() - 1;
    let ins = inputs(&c.frames, peer.subscriber);

    // ---- events ----
    let ev: Vec<&Event> = r.events.iter().map(|(_, e)| e).collect();
    let found: Vec<_> = r
        .events
        .iter()
        .filter_map(|(c, e)| match e {
            Event::ParticipantFound(d) => Some((*c, d)),
            _ => None,
        })
        .collect();
    assert_eq!(found.len(), 1, "{name}: found once");
    assert_eq!(found[0].0, Cause::Input(0), "{name}: by its first SPDP");
    assert_eq!(*found[0].1, peer.participant, "{name}: SPDP data");
    let pubs: Vec<&EndpointData> = ev
        .iter()
        .filter_map(|e| match e {
            Event::PublicationFound(d) => Some(d),
            _ => None,
        })
        .collect();
    assert_eq!(pubs, [&peer.publication], "{name}: the publication, once");
    for e in &ev {
        assert!(
            !matches!(
                e,
                Event::ParticipantChanged(_)
                    | Event::PublicationChanged(_)
                    | Event::SubscriptionFound(_)
                    | Event::IncompatibleQos { .. }
            ),
            "{name}: unexpected {e:?}"
        );
    }
    let pos = |f: &dyn Fn(&Event) -> bool| ev.iter().position(|e| f(e));
    let matched = pos(&|e| {
        matches!(e, Event::ReaderMatched { reader, writer: w } if *reader == r.reader && *w == writer)
    })
    .expect("our reader matches the publication");
    let first_sample = pos(&|e| matches!(e, Event::SampleReceived(_))).unwrap();
    assert!(matched < first_sample, "{name}");
    check_samples(peer, &c, &r, &r.events);

    // the SPDP dispose: endpoints first, then the participant, all at once
    let tail: Vec<&Event> = r
        .events
        .iter()
        .filter(|(c, _)| *c == Cause::Input(last))
        .map(|(_, e)| e)
        .collect();
    assert_eq!(
        tail,
        [
            &Event::ReaderUnmatched {
                reader: r.reader,
                writer
            },
            &Event::PublicationLost(writer),
            &Event::ParticipantLost {
                prefix: publisher,
                reason: LostReason::Disposed
            },
        ],
        "{name}: the dispose"
    );
    assert!(r.p.participant(publisher).is_none(), "{name}");
    assert_eq!(r.p.publications().count(), 0, "{name}: publication gone");
    assert!(r.p.matched_writers(r.reader).is_empty(), "{name}");
    assert!(
        r.events.iter().all(|(c, _)| *c != Cause::Timer),
        "{name}: no lease expired"
    );

    // nothing was dropped or refused on the way
    let st = r.p.stats();
    assert_eq!(st.datagrams_received, c.frames.len() as u64, "{name}");
    assert_eq!(
        (
            st.datagrams_malformed,
            st.datagrams_ignored,
            st.submessages_not_for_us,
            st.discovery_errors,
            st.fragments_rejected,
            st.data_unmatched,
        ),
        (0, 0, 0, 0, 0, 0),
        "{name}: {st:?}"
    );

    // ---- what Courier sent ----
    let out = outputs(&r.sent, peer.subscriber);
    let meta = peer.participant.metatraffic_unicast[0];
    let user = peer
        .publication
        .unicast
        .first()
        .copied()
        .unwrap_or(peer.participant.default_unicast[0]);
    for o in &out {
        assert!(
            o.to == meta || o.to == user,
            "{name}: only to the publisher's locators, not {:?}",
            o.to
        );
        assert_eq!(o.dst, publisher, "{name}: every datagram names it");
        assert!(
            o.idx >= r.marks[0] && o.idx < r.marks[last],
            "{name}: nothing before it is found or after it left"
        );
        if o.to == user {
            assert!(
                matches!(&o.sm, Submessage::InfoDst(_) | Submessage::AckNack(_)),
                "{name}: only ACKNACKs go to the user locator"
            );
        }
    }
    // SPDP: at once to the newcomer's metatraffic locator, and periodically
    let spdp: Vec<&Out> = out
        .iter()
        .filter(|o| matches!(&o.sm, Submessage::Data(d) if d.writer_id == EntityId::SPDP_WRITER))
        .collect();
    assert!(!spdp.is_empty(), "{name}: SPDP sent");
    assert_eq!(spdp[0].cause, Cause::Input(0), "{name}: answered at once");
    for o in &spdp {
        assert_eq!(o.to, meta, "{name}: SPDP to the metatraffic locator");
        let Submessage::Data(d) = &o.sm else {
            unreachable!()
        };
        let ours =
            ParticipantData::from_params(&payload_params(d.payload.unwrap()).unwrap()).unwrap();
        assert_eq!(ours.guid_prefix, peer.subscriber, "{name}");
        assert_eq!(ours.vendor, VENDOR_ID, "{name}");
        assert_eq!(ours.domain_id, Some(0), "{name}");
        assert_eq!(ours.metatraffic_unicast, [lo(7410)], "{name}");
        assert_eq!(ours.default_unicast, [lo(7411)], "{name}");
    }

    // SEDP: our subscription, sent (again) whenever the publisher asks
    let sub_datas: Vec<&Out> = out
        .iter()
        .filter(|o| {
            matches!(&o.sm, Submessage::Data(d) if d.writer_id == EntityId::SEDP_SUBSCRIPTIONS_WRITER)
        })
        .collect();
    assert!(!sub_datas.is_empty(), "{name}: our subscription sent");
    for o in &sub_datas {
        let Submessage::Data(d) = &o.sm else {
            unreachable!()
        };
        assert_eq!(o.to, meta, "{name}");
        assert_eq!(d.writer_sn, SequenceNumber(1), "{name}");
        let e =
            EndpointData::from_params(&payload_params(d.payload.unwrap()).unwrap(), false).unwrap();
        assert_eq!(e.guid, r.reader, "{name}");
        assert_eq!(
            (e.topic_name.as_str(), e.type_name.as_str()),
            ("HelloWorldTopic", "HelloWorld")
        );
        assert_eq!(e.qos, r.reader_qos, "{name}");
    }
    assert!(
        !out.iter().any(
            |o| matches!(&o.sm, Submessage::Data(d) if d.writer_id == EntityId::SEDP_PUBLICATIONS_WRITER)
        ),
        "{name}: no publications to announce"
    );
    let mut asked = 0;
    for (i, step) in ins.iter().enumerate() {
        for x in step {
            if let In::AckNack {
                writer: EntityId::SEDP_SUBSCRIPTIONS_WRITER,
                missing,
                ..
            } = x
            {
                for sn in missing {
                    asked += 1;
                    assert!(
                        sub_datas.iter().any(|o| o.cause == Cause::Input(i)
                            && matches!(&o.sm, Submessage::Data(d) if d.writer_sn.0 == *sn)),
                        "{name}: datagram {i} asks for our subscription {sn}; it is resent"
                    );
                }
            }
        }
    }
    assert_eq!(asked, 1, "{name}: the publisher asked for it once");
    // our SEDP writers stop heartbeating once the publisher acknowledged
    let acked_at = ins
        .iter()
        .position(|step| {
            step.iter().any(|x| {
                matches!(
                    x,
                    In::AckNack {
                        writer: EntityId::SEDP_SUBSCRIPTIONS_WRITER,
                        base: 2,
                        ..
                    }
                )
            })
        })
        .expect("the publisher acknowledges our subscription");
    // (the participant-message writer's handshake goes to a peer that,
    // in these captures, never knew of it: it is not SEDP's business)
    let heartbeats: Vec<&Out> = out
        .iter()
        .filter(|o| {
            matches!(&o.sm, Submessage::Heartbeat(h) if h.writer_id != EntityId::P2P_MESSAGE_WRITER)
        })
        .collect();
    assert!(!heartbeats.is_empty(), "{name}");
    for o in heartbeats {
        let Submessage::Heartbeat(h) = &o.sm else {
            unreachable!()
        };
        assert!(sedp_reader_of(h.writer_id).is_some(), "{name}: SEDP only");
        assert_eq!(o.to, meta, "{name}");
        assert!(
            o.idx < r.marks[acked_at + 1],
            "{name}: silent once acknowledged"
        );
    }

    // ACKNACKs: one for every heartbeat of the publisher's SEDP writers and
    // of its user writer, in the same step, saying exactly what arrived
    let mut received: BTreeMap<EntityId, BTreeSet<i64>> = BTreeMap::new();
    let mut frags: BTreeMap<(EntityId, i64), usize> = BTreeMap::new();
    let mut next: BTreeMap<EntityId, i64> = BTreeMap::new();
    let mut heartbeats = 0;
    let mut user_acks = 0;
    for (i, step) in ins.iter().enumerate() {
        for x in step {
            match x {
                In::Data { writer: w, sn, .. } => {
                    received.entry(*w).or_default().insert(*sn);
                }
                In::Frag {
                    writer: w,
                    sn,
                    count,
                    fragment_size,
                    sample_size,
                    ..
                } => {
                    let n = frags.entry((*w, *sn)).or_default();
                    *n += usize::from(*count);
                    if *n == (*sample_size as usize).div_ceil(usize::from(*fragment_size)) {
                        received.entry(*w).or_default().insert(*sn);
                    }
                }
                In::Heartbeat {
                    writer: w,
                    first,
                    last,
                    final_flag,
                } => {
                    let (reader_id, to) = match sedp_reader_of(*w) {
                        Some(e) => (e, meta),
                        None if *w == writer.entity => (r.reader.entity, user),
                        // the participant-message pair is matched too
                        None if *w == EntityId::P2P_MESSAGE_WRITER => {
                            (EntityId::P2P_MESSAGE_READER, meta)
                        }
                        None => continue, // type lookup: not ours
                    };
                    assert!(!final_flag, "{name}: both vendors ask for an answer");
                    heartbeats += 1;
                    let got = received.entry(*w).or_default();
                    let n = next.entry(*w).or_insert(1);
                    *n = (*n).max(*first);
                    while got.contains(n) {
                        *n += 1;
                    }
                    let missing: Vec<i64> = (*n..=*last).filter(|s| !got.contains(s)).collect();
                    let acks: Vec<&Out> = out
                        .iter()
                        .filter(|o| {
                            o.cause == Cause::Input(i)
                                && matches!(&o.sm, Submessage::AckNack(a) if a.writer_id == *w && !preemptive(a))
                        })
                        .collect();
                    assert_eq!(acks.len(), 1, "{name}: datagram {i}: one ACKNACK for {w:?}");
                    let Submessage::AckNack(a) = &acks[0].sm else {
                        unreachable!()
                    };
                    assert_eq!(acks[0].to, to, "{name}: datagram {i}");
                    assert_eq!(a.reader_id, reader_id, "{name}: datagram {i}");
                    assert_eq!(a.reader_sn_state.base.0, *n, "{name}: datagram {i}");
                    let asks: Vec<i64> = a.reader_sn_state.iter().map(|s| s.0).collect();
                    assert_eq!(asks, missing, "{name}: datagram {i}");
                    assert_eq!(a.final_flag, missing.is_empty(), "{name}: datagram {i}");
                    if *w == writer.entity {
                        // nothing is lost on a replay: every ACKNACK to the
                        // user writer acknowledges all it announced
                        assert!(missing.is_empty(), "{name}: datagram {i}");
                        assert_eq!(*n, last + 1, "{name}: datagram {i}");
                        user_acks += 1;
                    }
                }
                _ => {}
            }
        }
    }
    let acknacks = out
        .iter()
        .filter(|o| matches!(&o.sm, Submessage::AckNack(a) if !preemptive(a)))
        .count();
    assert_eq!(
        acknacks, heartbeats,
        "{name}: ACKNACKs answer heartbeats, besides the pre-emptive ones"
    );
    // and pre-emptive ACKNACKs to each writer from when it matched (the
    // SEDP writers when the participant was found, the user writer when
    // its publication was) until it heartbeats: one, or one a second
    // while the writer says nothing (Fast DDS's SEDP writers take seconds)
    let pre: Vec<(usize, EntityId)> = out
        .iter()
        .filter_map(|o| match &o.sm {
            Submessage::AckNack(a) if preemptive(a) => Some((o.idx, a.writer_id)),
            _ => None,
        })
        .collect();
    let mut to: Vec<EntityId> = pre.iter().map(|(_, w)| *w).collect();
    to.sort();
    to.dedup();
    let mut expected = vec![
        EntityId::SEDP_PUBLICATIONS_WRITER,
        EntityId::SEDP_SUBSCRIPTIONS_WRITER,
        EntityId::P2P_MESSAGE_WRITER,
        writer.entity,
    ];
    expected.sort();
    assert_eq!(to, expected, "{name}: pre-emptive ACKNACKs to every writer");
    for (idx, w) in &pre {
        let first_answer = out
            .iter()
            .find(
                |o| matches!(&o.sm, Submessage::AckNack(a) if a.writer_id == *w && !preemptive(a)),
            )
            .map(|o| o.idx);
        assert!(
            first_answer.is_none_or(|a| a > *idx),
            "{name}: the pre-emptive ACKNACK to {w:?} comes first"
        );
    }
    assert!(user_acks >= 2, "{name}");
    // the last ACKNACK to the user writer acknowledges all six samples
    let last_user_ack = out
        .iter()
        .rev()
        .find_map(|o| match &o.sm {
            Submessage::AckNack(a) if a.writer_id == writer.entity => Some(a),
            _ => None,
        })
        .unwrap();
    assert_eq!(last_user_ack.reader_sn_state.base, SequenceNumber(7));
    assert!(last_user_ack.final_flag && last_user_ack.reader_sn_state.num_bits == 0);
    // the last ACKNACK to the publications writer acknowledges the publication
    let last_pub_ack = out
        .iter()
        .rev()
        .find_map(|o| match &o.sm {
            Submessage::AckNack(a) if a.writer_id == EntityId::SEDP_PUBLICATIONS_WRITER => Some(a),
            _ => None,
        })
        .unwrap();
    assert_eq!(last_pub_ack.reader_sn_state.base, SequenceNumber(2));
    assert!(last_pub_ack.final_flag);
    assert!(
        !out.iter().any(|o| matches!(o.sm, Submessage::NackFrag(_))),
        "{name}: no fragment was missing"
    );
}

#[test]
fn cyclone_dds_11_publisher_conversation() {
    check_conversation(&cyclone());
}

#[test]
fn fast_dds_2_9_publisher_conversation() {
    check_conversation(&fastdds());
}

/// A participant whose prefix the publisher did not address skips what is
/// behind an INFO_DST naming the real subscriber. Cyclone sends its SEDP
/// publication and user DATA (with piggybacked HEARTBEATs) without INFO_DST,
/// so those still arrive and only its unaddressed heartbeats are answered;
/// Fast DDS addresses everything but SPDP, so nothing beyond the participant
/// is learnt and nothing is acknowledged.
#[test]
fn info_dst_naming_another_participant_is_skipped() {
    let other = prefix("01c0000000000000000000aa");
    for (peer, publication, delivered, answered) in
        [(cyclone(), true, 6, 6), (fastdds(), false, 0, 0)]
    {
        let name = peer.name;
        let c = load(peer.conversation);
        let mut r = Replay::new(&peer, other);
        r.play(&c.frames, Duration::from_secs(1));
        assert!(r.p.stats().submessages_not_for_us > 0, "{name}");
        let found = r
            .events
            .iter()
            .any(|(_, e)| matches!(e, Event::ParticipantFound(d) if *d == peer.participant));
        assert!(found, "{name}: SPDP is not addressed");
        let pubs = r
            .events
            .iter()
            .any(|(_, e)| matches!(e, Event::PublicationFound(_)));
        assert_eq!(pubs, publication, "{name}");
        assert_eq!(samples(&r.events).len(), delivered, "{name}");
        let writer = peer.publication.guid.entity;
        let unaddressed = inputs(&c.frames, other)
            .iter()
            .flatten()
            .filter(|x| matches!(x, In::Heartbeat { writer: w, .. } if *w == writer))
            .count();
        assert_eq!(unaddressed, answered, "{name}");
        let acks = outputs(&r.sent, other)
            .iter()
            .filter(|o| matches!(&o.sm, Submessage::AckNack(a) if a.writer_id == writer && !preemptive(a)))
            .count();
        assert_eq!(
            acks, answered,
            "{name}: only unaddressed heartbeats answered"
        );
    }
}

/// A reader's pre-emptive ACKNACK, sent when a writer matches and until
/// it heartbeats (base 1, nothing missing, count 0).
fn preemptive(a: &AckNack) -> bool {
    a.reader_sn_state.base.0 == 1 && a.reader_sn_state.num_bits == 0 && a.count == 0
}

// ---- mutated conversations ----

/// xorshift64: deterministic and dependency-free.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }

    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
}

/// Damaged copies of a datagram: truncated at a random point, random bytes
/// flipped anywhere, random bytes flipped in the first 96 bytes (header,
/// INFO_*, submessage headers, sequence numbers), and both.
fn mutations(rng: &mut Rng, b: &[u8]) -> Vec<Vec<u8>> {
    let mut v = Vec::new();
    let flip = |rng: &mut Rng, d: &mut Vec<u8>, span: usize, n: usize| {
        for _ in 0..n {
            let i = rng.below(span.min(d.len()));
            d[i] ^= 1 + rng.below(255) as u8;
        }
    };
    let mut t = b.to_vec();
    t.truncate(rng.below(b.len()));
    v.push(t);
    for _ in 0..3 {
        let mut d = b.to_vec();
        let n = 1 + rng.below(8);
        flip(rng, &mut d, usize::MAX, n);
        v.push(d);
        let mut d = b.to_vec();
        let n = 1 + rng.below(4);
        flip(rng, &mut d, 96, n);
        v.push(d);
    }
    let mut d = b.to_vec();
    flip(rng, &mut d, 96, 2);
    d.truncate(20 + rng.below(b.len().saturating_sub(20)));
    v.push(d);
    v
}

/// Every datagram of both conversations, damaged in several ways, fed with
/// the captured timing: no panic, what Courier sends still parses, and after
/// the publisher's (undamaged) dispose has cleared what the damaged copies
/// taught it, the undamaged conversation replayed to the same participant
/// delivers every sample once and in order.
#[test]
fn mutated_conversations_do_not_hurt() {
    for (peer, seed) in [(cyclone(), 0x00c0_ffee_u64), (fastdds(), 0x0bad_cafe)] {
        let name = peer.name;
        let c = load(peer.conversation);
        let mut rng = Rng(seed);
        let mut r = Replay::new(&peer, peer.subscriber);
        let mut fed = 0u64;
        for (i, f) in c.frames.iter().enumerate() {
            for m in mutations(&mut rng, &f.bytes) {
                r.deliver(i, f.ms, &m);
                fed += 1;
            }
        }
        let last = c.frames.last().unwrap();
        r.deliver(c.frames.len(), last.ms + 1, &last.bytes);
        fed += 1;
        r.advance(r.now + Duration::from_secs(1));
        let st = r.p.stats();
        assert_eq!(st.datagrams_received, fed, "{name}");
        assert!(st.datagrams_malformed > 0, "{name}: {st:?}");
        outputs(&r.sent, peer.subscriber);

        // the real conversation again, later, to the same participant
        r.base = r.now + Duration::from_secs(1);
        let (sent_mark, event_mark) = (r.sent.len(), r.events.len());
        r.play(&c.frames, Duration::from_secs(1));
        let events = &r.events[event_mark..];
        assert!(
            events
                .iter()
                .any(|(_, e)| matches!(e, Event::ReaderMatched { reader, writer }
                if *reader == r.reader && *writer == peer.publication.guid)),
            "{name}: matched again"
        );
        check_samples(&peer, &c, &r, events);
        let out = outputs(&r.sent[sent_mark..], peer.subscriber);
        let acked_all = out.iter().any(|o| {
            matches!(&o.sm, Submessage::AckNack(a) if a.writer_id == peer.publication.guid.entity
                && a.reader_sn_state.base == SequenceNumber(7) && a.final_flag)
        });
        assert!(acked_all, "{name}: all six acknowledged");
    }
}
