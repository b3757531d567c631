//! Replay: the client machine is fed the agent's captured bytes (eProsima
//! Micro XRCE-DDS Agent 2.3.0), at the captured times, while a script
//! makes the API calls the eProsima example made; every message it sends
//! must be the eProsima client's captured message, in the same order, and
//! sent no later than the capture shows it.
//!
//! Fixtures: `tests/fixtures/xrce/<capture>.hex` (the bytes, shared with
//! `xrce_golden.rs`) and `tests/fixtures/xrce/times/<capture>.times` (the
//! capture's timestamps), both extracted from `shared/fixtures/xrce/`.
//!
//! Fields that may differ, and why:
//! - padding contents: the eProsima client pads every submessage to 4 with
//!   whatever its buffer held (`... 21 00 10 00 00` in
//!   `udp_xml_reliable_pubsub`); Courier writes zeros. Captured messages
//!   are compared with their padding bytes set to zero (length included).
//! - nothing else: request ids, sequence numbers, packing, fragment cuts,
//!   ACKNACK bitmaps, HEARTBEAT ranges and TIMESTAMP values (the script
//!   passes the captured wall time) are compared byte for byte.
//!
//! Where the eProsima example did not run its session loop for a while,
//! it read messages late; the script hands those over when it read them
//! (`defer`), and says why.

use std::collections::VecDeque;
use std::path::PathBuf;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use courier_wire::xrce::{
    BinaryRepresentation, Client, ClientConfig, CreationMode, DataReaderBinary, DataReaderQos,
    DataWriterBinary, DeliveryControl, EndpointQos, Event, GroupBinary, LostReason, Message,
    ObjectId, ObjectKind, ObjectVariant, ParticipantBinary, Payload, Representation, RequestId,
    StreamId, TopicBinary,
};

fn fixture(name: &str) -> String {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures/xrce")
        .join(name);
    std::fs::read_to_string(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()))
}

fn unhex(s: &str) -> Vec<u8> {
    (0..s.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&s[i..i + 2], 16).expect("hex"))
        .collect()
}

fn hex(b: &[u8]) -> String {
    b.iter().map(|x| format!("{x:02x}")).collect()
}

#[derive(Clone)]
struct Rec {
    n: u32,
    t: f64,
    c2a: bool,
    bytes: Vec<u8>,
}

/// The messages of `capture` between the agent and the client at `port`.
fn records(capture: &str, port: u16) -> Vec<Rec> {
    let times = fixture(&format!("times/{capture}.times"));
    let time = |n: u32| -> f64 {
        times
            .lines()
            .filter(|l| !l.starts_with('#'))
            .find_map(|l| {
                let (a, b) = l.split_once(' ')?;
                (a.parse::<u32>().ok()? == n).then(|| b.parse().ok())?
            })
            .unwrap_or_else(|| panic!("{capture}: no time for #{n}"))
    };
    fixture(&format!("{capture}.hex"))
        .lines()
        .filter(|l| !l.starts_with('#'))
        .filter_map(|l| {
            let f: Vec<&str> = l.split_whitespace().collect();
            (f[3].parse::<u16>().ok()? == port).then(|| {
                let n = f[0].parse().unwrap();
                Rec {
                    n,
                    t: time(n),
                    c2a: f[2] == "C->A",
                    bytes: unhex(f[4]),
                }
            })
        })
        .collect()
}

/// The captured message with every padding byte set to zero.
fn zero_padding(b: &[u8]) -> (Vec<u8>, bool) {
    let mut m = Message::decode(b).unwrap();
    for s in &mut m.submessages {
        s.padding.clear();
    }
    m.trailing = vec![0; m.trailing.len()];
    let v = m.to_vec().unwrap();
    let differs = v != b;
    (v, differs)
}

type Cmd = Box<dyn FnMut(&mut Client, Instant, &[Event])>;

struct Replay {
    capture: &'static str,
    port: u16,
    cfg: ClientConfig,
    cmds: Vec<(u32, Cmd)>,
    /// `(record, after)`: hand agent record `record` over after `after`.
    defer: Vec<(u32, u32)>,
}

struct Outcome {
    events: Vec<Event>,
    compared: usize,
    padding_differed: usize,
}

fn config(key: u32) -> ClientConfig {
    // the eProsima client sends no pings of its own
    ClientConfig {
        keepalive: None,
        ..ClientConfig::new(key)
    }
}

fn cmd(n: u32, f: impl FnMut(&mut Client, Instant, &[Event]) + 'static) -> (u32, Cmd) {
    (n, Box::new(f))
}

fn run(mut r: Replay) -> Outcome {
    let mut recs = records(r.capture, r.port);
    assert!(
        !recs.is_empty(),
        "{}: no messages for port {}",
        r.capture,
        r.port
    );
    for &(d, after) in &r.defer {
        let i = recs.iter().position(|x| x.n == d).unwrap();
        let mut rec = recs.remove(i);
        assert!(!rec.c2a, "only agent messages are deferred");
        let j = recs.iter().position(|x| x.n == after).unwrap();
        rec.t = recs[j].t;
        recs.insert(j + 1, rec);
    }
    let t0 = Instant::now();
    let mut c = Client::new(r.cfg.clone());
    let mut out: VecDeque<Vec<u8>> = VecDeque::new();
    let mut events = Vec::new();
    let mut o = Outcome {
        events: Vec::new(),
        compared: 0,
        padding_differed: 0,
    };
    let drain = |c: &mut Client, out: &mut VecDeque<Vec<u8>>, events: &mut Vec<Event>| {
        while let Some(m) = c.poll_transmit() {
            out.push_back(m);
        }
        while let Some(e) = c.poll_event() {
            events.push(e);
        }
    };
    for rec in recs {
        let now = t0 + Duration::from_secs_f64(rec.t);
        for (_, f) in r.cmds.iter_mut().filter(|(n, _)| *n == rec.n) {
            f(&mut c, now, &events);
        }
        if c.poll_timeout().is_some_and(|d| d <= now) {
            c.handle_timeout(now);
        }
        drain(&mut c, &mut out, &mut events);
        if rec.c2a {
            let (want, differs) = zero_padding(&rec.bytes);
            let got = out.pop_front().unwrap_or_else(|| {
                panic!(
                    "{} #{}: the client sent nothing; eProsima's sent {}",
                    r.capture,
                    rec.n,
                    hex(&want)
                )
            });
            assert_eq!(hex(&got), hex(&want), "{} #{}", r.capture, rec.n);
            o.compared += 1;
            o.padding_differed += usize::from(differs);
        } else {
            c.handle_input(&rec.bytes, now)
                .unwrap_or_else(|e| panic!("{} #{}: {e}", r.capture, rec.n));
            drain(&mut c, &mut out, &mut events);
        }
    }
    assert!(
        out.is_empty(),
        "{}: the client sent more than eProsima's: {:?}",
        r.capture,
        out.iter().map(|m| hex(m)).collect::<Vec<_>>()
    );
    eprintln!(
        "{} port {}: {} messages identical, {} of them after zeroing eProsima's padding",
        r.capture, r.port, o.compared, o.padding_differed
    );
    o.events = events;
    o
}

fn oid(id: u16, kind: ObjectKind) -> ObjectId {
    ObjectId::new(id, kind)
}

const R: StreamId = StreamId::RELIABLE;
const UNLIMITED: Option<DeliveryControl> = Some(DeliveryControl {
    max_samples: 0xFFFF,
    max_elapsed_time: 0,
    max_bytes_per_second: 0,
    min_pace_period: 0,
});

fn xml(s: &str) -> Representation {
    Representation::Xml(s.to_string())
}

const PARTICIPANT_XML: &str =
    "<dds><participant><rtps><name>default_xrce_participant</name></rtps></participant></dds>";
const TOPIC_XML: &str =
    "<dds><topic><name>HelloWorldTopic</name><dataType>HelloWorld</dataType></topic></dds>";
const READER_XML: &str = "<dds><data_reader><topic><kind>NO_KEY</kind><name>HelloWorldTopic</name><dataType>HelloWorld</dataType></topic></data_reader></dds>";
const WRITER_XML: &str = "<dds><data_writer><topic><kind>NO_KEY</kind><name>HelloWorldTopic</name><dataType>HelloWorld</dataType></topic></data_writer></dds>";

fn create(c: &mut Client, now: Instant, id: ObjectId, v: ObjectVariant) -> RequestId {
    c.create(id, v, CreationMode::REPLACE, now).unwrap()
}

/// The HelloWorld example's entities by XML: participant, topic, and a
/// subscriber + reader or a publisher + writer.
fn hello_entities(c: &mut Client, now: Instant, reader: bool) {
    let p = oid(1, ObjectKind::Participant);
    let t = oid(1, ObjectKind::Topic);
    create(
        c,
        now,
        p,
        ObjectVariant::Participant {
            representation: xml(PARTICIPANT_XML),
            domain_id: 0,
        },
    );
    create(
        c,
        now,
        t,
        ObjectVariant::Topic {
            representation: xml(TOPIC_XML),
            participant_id: p,
        },
    );
    if reader {
        let s = oid(1, ObjectKind::Subscriber);
        create(
            c,
            now,
            s,
            ObjectVariant::Subscriber {
                representation: xml(""),
                participant_id: p,
            },
        );
        create(
            c,
            now,
            oid(1, ObjectKind::DataReader),
            ObjectVariant::DataReader {
                representation: xml(READER_XML),
                subscriber_id: s,
            },
        );
    } else {
        let s = oid(1, ObjectKind::Publisher);
        create(
            c,
            now,
            s,
            ObjectVariant::Publisher {
                representation: xml(""),
                participant_id: p,
            },
        );
        create(
            c,
            now,
            oid(1, ObjectKind::DataWriter),
            ObjectVariant::DataWriter {
                representation: xml(WRITER_XML),
                publisher_id: s,
            },
        );
    }
}

/// HelloWorld { index, "Hello DDS world!" } in CDR.
fn hello(index: u32) -> Vec<u8> {
    let mut v = index.to_le_bytes().to_vec();
    v.extend_from_slice(&17u32.to_le_bytes());
    v.extend_from_slice(b"Hello DDS world!\0");
    v
}

fn connect_at(n: u32) -> (u32, Cmd) {
    cmd(n, |c, now, _| c.connect(now))
}

fn disconnect_at(n: u32) -> (u32, Cmd) {
    cmd(n, |c, now, _| c.disconnect(now).unwrap())
}

fn write_at(n: u32, stream: StreamId, data: Vec<u8>) -> (u32, Cmd) {
    cmd(n, move |c, now, _| {
        c.write(oid(1, ObjectKind::DataWriter), stream, &data, now)
            .unwrap();
    })
}

fn read_at(n: u32, object: ObjectId, preferred: StreamId) -> (u32, Cmd) {
    cmd(n, move |c, now, _| {
        c.read(object, R, preferred, UNLIMITED, now).unwrap();
    })
}

fn data_of(events: &[Event]) -> Vec<Vec<u8>> {
    events
        .iter()
        .filter_map(|e| match e {
            Event::Data { data, .. } => Some(data.clone()),
            _ => None,
        })
        .collect()
}

fn statuses_ok(events: &[Event]) -> usize {
    events
        .iter()
        .filter(|e| matches!(e, Event::Status { result: Ok(_), .. }))
        .count()
}

#[test]
fn binary_entities_pub_and_sub_in_one_client() {
    let p = oid(1, ObjectKind::Participant);
    let t = oid(1, ObjectKind::Topic);
    let qos = EndpointQos {
        flags: 0x0B,
        ..Default::default()
    };
    let o = run(Replay {
        capture: "udp_binary_entities",
        port: 40452,
        cfg: config(0xAAAA_BBBB),
        cmds: vec![
            connect_at(1),
            cmd(3, move |c, now, _| {
                let bin = |b: BinaryRepresentation| b.to_representation().unwrap();
                let pubr = oid(1, ObjectKind::Publisher);
                let sub = oid(1, ObjectKind::Subscriber);
                create(
                    c,
                    now,
                    p,
                    ObjectVariant::Participant {
                        representation: bin(BinaryRepresentation::Participant(
                            ParticipantBinary::default(),
                        )),
                        domain_id: 0,
                    },
                );
                create(
                    c,
                    now,
                    t,
                    ObjectVariant::Topic {
                        representation: bin(BinaryRepresentation::Topic(TopicBinary {
                            topic_name: "ExampleTopic".into(),
                            type_reference: None,
                            type_name: Some("ExampleType".into()),
                        })),
                        participant_id: p,
                    },
                );
                create(
                    c,
                    now,
                    pubr,
                    ObjectVariant::Publisher {
                        representation: bin(
                            BinaryRepresentation::Publisher(GroupBinary::default()),
                        ),
                        participant_id: p,
                    },
                );
                create(
                    c,
                    now,
                    oid(1, ObjectKind::DataWriter),
                    ObjectVariant::DataWriter {
                        representation: bin(BinaryRepresentation::DataWriter(DataWriterBinary {
                            topic_id: t,
                            qos: Some((qos.clone(), None)),
                        })),
                        publisher_id: pubr,
                    },
                );
                create(
                    c,
                    now,
                    sub,
                    ObjectVariant::Subscriber {
                        representation: bin(BinaryRepresentation::Subscriber(
                            GroupBinary::default(),
                        )),
                        participant_id: p,
                    },
                );
                create(
                    c,
                    now,
                    oid(1, ObjectKind::DataReader),
                    ObjectVariant::DataReader {
                        representation: bin(BinaryRepresentation::DataReader(DataReaderBinary {
                            topic_id: t,
                            qos: Some(DataReaderQos {
                                base: qos.clone(),
                                ..Default::default()
                            }),
                        })),
                        subscriber_id: sub,
                    },
                );
            }),
            read_at(17, oid(1, ObjectKind::DataReader), R),
            write_at(17, R, vec![0; 4]),
            write_at(21, R, vec![1, 0, 0, 0]),
            write_at(25, R, vec![2, 0, 0, 0]),
            disconnect_at(29),
        ],
        defer: vec![],
    });
    assert_eq!(statuses_ok(&o.events), 6);
    assert_eq!(
        data_of(&o.events),
        vec![vec![0; 4], vec![1, 0, 0, 0], vec![2, 0, 0, 0]]
    );
    let acked: Vec<_> = o
        .events
        .iter()
        .filter_map(|e| match e {
            Event::WriteAcked(r) => Some(r.0),
            _ => None,
        })
        .collect();
    assert_eq!(acked, [0x11, 0x12, 0x13]);
    assert_eq!(
        o.events.last(),
        Some(&Event::SessionDeleted { confirmed: true })
    );
}

/// The two clients of a HelloWorld capture, each replayed on its own port:
/// the subscriber (key CCCCDDDD) connects at record 1, creates its
/// entities at 3, asks to read at 13 and disconnects at `sub_end`; the
/// publisher (key AAAABBBB) connects at 15, creates its entities at 17,
/// writes samples 1, 2, … at the records `writes` and disconnects at
/// `pub_end`. Returns (subscriber, publisher).
struct HelloPair {
    capture: &'static str,
    stream: StreamId,
    sub_port: u16,
    sub_end: u32,
    pub_port: u16,
    writes: [u32; 5],
    pub_end: u32,
}

fn hello_pair(p: HelloPair) -> (Outcome, Outcome) {
    let sub = run(Replay {
        capture: p.capture,
        port: p.sub_port,
        cfg: config(0xCCCC_DDDD),
        cmds: vec![
            connect_at(1),
            cmd(3, |c, now, _| hello_entities(c, now, true)),
            read_at(13, oid(1, ObjectKind::DataReader), p.stream),
            disconnect_at(p.sub_end),
        ],
        defer: vec![],
    });
    let mut cmds = vec![
        connect_at(15),
        cmd(17, |c, now, _| hello_entities(c, now, false)),
    ];
    for (i, n) in p.writes.into_iter().enumerate() {
        cmds.push(write_at(n, p.stream, hello(i as u32 + 1)));
    }
    cmds.push(disconnect_at(p.pub_end));
    let publ = run(Replay {
        capture: p.capture,
        port: p.pub_port,
        cfg: config(0xAAAA_BBBB),
        cmds,
        defer: vec![],
    });
    (sub, publ)
}

#[test]
fn xml_reliable_hello_world_subscriber_and_publisher() {
    let (sub, publ) = hello_pair(HelloPair {
        capture: "udp_xml_reliable_pubsub",
        stream: R,
        sub_port: 54235,
        sub_end: 39,
        pub_port: 43825,
        writes: [27, 31, 35, 40, 43],
        pub_end: 45,
    });
    assert_eq!(statuses_ok(&sub.events), 4);
    assert_eq!(data_of(&sub.events), vec![hello(1), hello(2), hello(3)]);
    assert!(
        publ.padding_differed > 0,
        "the capture's garbage padding is seen"
    );
}

#[test]
fn xml_best_effort_hello_world_subscriber_and_publisher() {
    let (sub, _) = hello_pair(HelloPair {
        capture: "udp_xml_besteffort_pubsub",
        stream: StreamId::BEST_EFFORT,
        sub_port: 35650,
        sub_end: 35,
        pub_port: 51656,
        writes: [27, 28, 30, 32, 34],
        pub_end: 38,
    });
    // sample 1 was written before DDS matched the endpoints
    assert_eq!(
        data_of(&sub.events),
        vec![hello(2), hello(3), hello(4), hello(5)]
    );
}

#[test]
fn reliable_loss_recovery_heartbeats_acknacks_and_retransmission() {
    let (sub, publ) = hello_pair(HelloPair {
        capture: "udp_reliable_loss_recovery",
        stream: R,
        sub_port: 59323,
        sub_end: 55,
        pub_port: 40530,
        writes: [29, 33, 40, 44, 50],
        pub_end: 54,
    });
    // DATA seq 6 (sample 4) was dropped by the proxy, NACKed (#47) and resent
    assert_eq!(
        data_of(&sub.events),
        vec![hello(2), hello(3), hello(4), hello(5)]
    );
    let acked = publ
        .events
        .iter()
        .filter(|e| matches!(e, Event::WriteAcked(_)))
        .count();
    assert_eq!(acked, 5);
}

/// The reassembled WRITE_DATA/DATA body carried by FRAGMENT records `nums`.
fn fragmented_sample(capture: &str, port: u16, nums: &[u32]) -> Vec<u8> {
    let recs = records(capture, port);
    let mut body = Vec::new();
    let mut header = None;
    for n in nums {
        let m = Message::decode(&recs.iter().find(|r| r.n == *n).unwrap().bytes).unwrap();
        header.get_or_insert(m.header);
        let Payload::Fragment(b) = &m.submessages[0].payload else {
            panic!("#{n} is no FRAGMENT")
        };
        body.extend_from_slice(b);
    }
    let m = Message::reassembled(&header.unwrap(), &body).unwrap();
    match &m.submessages[0].payload {
        Payload::WriteData(d) | Payload::Data(d) => d.data.clone(),
        p => panic!("{p:?}"),
    }
}

fn bench_entities(c: &mut Client, now: Instant, reader: bool, topic_id: u16) {
    let bin = |b: BinaryRepresentation| b.to_representation().unwrap();
    let p = oid(1, ObjectKind::Participant);
    let t = oid(topic_id, ObjectKind::Topic);
    let qos = EndpointQos {
        flags: 0x03,
        history_depth: Some(100),
        ..Default::default()
    };
    create(
        c,
        now,
        p,
        ObjectVariant::Participant {
            representation: bin(BinaryRepresentation::Participant(
                ParticipantBinary::default(),
            )),
            domain_id: 0,
        },
    );
    create(
        c,
        now,
        t,
        ObjectVariant::Topic {
            representation: bin(BinaryRepresentation::Topic(TopicBinary {
                topic_name: "BenchTopic".into(),
                type_reference: None,
                type_name: Some("BenchType".into()),
            })),
            participant_id: p,
        },
    );
    if reader {
        let s = oid(1, ObjectKind::Subscriber);
        create(
            c,
            now,
            s,
            ObjectVariant::Subscriber {
                representation: bin(BinaryRepresentation::Subscriber(GroupBinary::default())),
                participant_id: p,
            },
        );
        create(
            c,
            now,
            oid(1, ObjectKind::DataReader),
            ObjectVariant::DataReader {
                representation: bin(BinaryRepresentation::DataReader(DataReaderBinary {
                    topic_id: t,
                    qos: Some(DataReaderQos {
                        base: qos,
                        ..Default::default()
                    }),
                })),
                subscriber_id: s,
            },
        );
    } else {
        let s = oid(1, ObjectKind::Publisher);
        create(
            c,
            now,
            s,
            ObjectVariant::Publisher {
                representation: bin(BinaryRepresentation::Publisher(GroupBinary::default())),
                participant_id: p,
            },
        );
        create(
            c,
            now,
            oid(1, ObjectKind::DataWriter),
            ObjectVariant::DataWriter {
                representation: bin(BinaryRepresentation::DataWriter(DataWriterBinary {
                    topic_id: t,
                    qos: Some((qos, None)),
                })),
                publisher_id: s,
            },
        );
    }
}

#[test]
fn fragmentation_of_1200_byte_samples_both_ways() {
    let cap = "udp_fragmentation_large_sample";
    let s1 = fragmented_sample(cap, 36529, &[27, 28, 29]);
    let s2 = fragmented_sample(cap, 36529, &[39, 40, 41]);
    assert_eq!((s1.len(), s2.len()), (1200, 1200));
    let sub = run(Replay {
        capture: cap,
        port: 60372,
        cfg: config(0x2222_0002),
        cmds: vec![
            connect_at(1),
            cmd(3, |c, now, _| bench_entities(c, now, true, 2)),
            read_at(12, oid(1, ObjectKind::DataReader), R),
            disconnect_at(53),
        ],
        defer: vec![],
    });
    assert_eq!(data_of(&sub.events), vec![s1.clone(), s2.clone()]);
    let publ = run(Replay {
        capture: cap,
        port: 36529,
        cfg: config(0x1111_0001),
        cmds: vec![
            connect_at(15),
            cmd(17, |c, now, _| bench_entities(c, now, false, 1)),
            write_at(27, R, s1),
            write_at(39, R, s2),
            disconnect_at(67),
        ],
        // the example slept 200 ms after the first sample without running
        // its session: it read the three ACKNACKs after sending the second
        // sample and its HEARTBEAT (#42 still says first_unacked = 1)
        defer: vec![(30, 42), (31, 42), (32, 42)],
    });
    let acked = publ
        .events
        .iter()
        .filter(|e| matches!(e, Event::WriteAcked(_)))
        .count();
    assert_eq!(acked, 2);
}

#[test]
fn ping_outside_and_inside_the_session() {
    let o = run(Replay {
        capture: "udp_ping",
        port: 34611,
        cfg: config(0xAAAA_BBBB),
        cmds: vec![
            cmd(1, |c, now, _| c.ping(now)),
            connect_at(3),
            cmd(5, |c, now, _| c.ping(now)),
        ],
        defer: vec![],
    });
    let pongs: Vec<_> = o
        .events
        .iter()
        .filter_map(|e| match e {
            Event::Pong { in_session, rtt } => Some((*in_session, rtt.is_some())),
            _ => None,
        })
        .collect();
    assert_eq!(pongs, [(false, true), (true, true)]);
}

#[test]
fn time_sync_offsets_from_the_four_timestamps() {
    // the TIMESTAMPs' transmit times, as the eProsima client stamped them
    let walls = [
        (3, 1_795_348_632, 840_213_693),
        (5, 1_795_348_633, 840_565_006),
        (7, 1_795_348_634, 841_079_782),
    ];
    let mut cmds = vec![connect_at(1)];
    for (n, s, ns) in walls {
        cmds.push(cmd(n, move |c, now, _| {
            let wall = UNIX_EPOCH + Duration::new(s, ns);
            c.sync_time(now, wall).unwrap();
        }));
    }
    let o = run(Replay {
        capture: "udp_timesync",
        port: 34678,
        cfg: config(0xCCCC_DDDD),
        cmds,
        defer: vec![],
    });
    // offset = ((t0 + t3) - (t1 + t2)) / 2, t3 = t0 + the captured round trip
    let recs = records("udp_timesync", 34678);
    let mut want = Vec::new();
    for pair in recs[2..].chunks(2) {
        let m = Message::decode(&pair[1].bytes).unwrap();
        let Payload::TimestampReply(r) = m.submessages[0].payload else {
            panic!()
        };
        let ns = |t: courier_wire::xrce::Time| {
            i64::from(t.seconds) * 1_000_000_000 + i64::from(t.nanoseconds)
        };
        let rtt = Duration::from_secs_f64(pair[1].t) - Duration::from_secs_f64(pair[0].t);
        let t0 = ns(r.originate);
        let t3 = t0 + rtt.as_nanos() as i64;
        want.push(((t0 + t3) - (ns(r.receive) + ns(r.transmit))) / 2);
    }
    let got: Vec<i64> = o
        .events
        .iter()
        .filter_map(|e| match e {
            Event::TimeSynced { offset_ns, .. } => Some(*offset_ns),
            _ => None,
        })
        .collect();
    assert_eq!(got, want);
    // the agent's clock was ~100 µs (first) to ~200 µs (last) ahead
    assert!(got.iter().all(|o| (-300_000..0).contains(o)), "{got:?}");
    let _ = SystemTime::now;
}

#[test]
fn request_reply_through_requester_and_replier() {
    let replier = oid(1, ObjectKind::Replier);
    let requester = oid(1, ObjectKind::Requester);
    let participant = |c: &mut Client, now| {
        create(
            c,
            now,
            oid(1, ObjectKind::Participant),
            ObjectVariant::Participant {
                representation: xml(PARTICIPANT_XML),
                domain_id: 0,
            },
        );
    };
    // the replier answers a + b (u32 LE each) as a u64 LE
    let answer = move |nth: usize| {
        move |c: &mut Client, now: Instant, events: &[Event]| {
            let (identity, data) = events
                .iter()
                .filter_map(|e| match e {
                    Event::Request { identity, data, .. } => Some((*identity, data.clone())),
                    _ => None,
                })
                .nth(nth)
                .expect("the request came");
            let a = u32::from_le_bytes(data[..4].try_into().unwrap());
            let b = u32::from_le_bytes(data[4..8].try_into().unwrap());
            let sum = u64::from(a) + u64::from(b);
            c.reply(replier, R, &identity, &sum.to_le_bytes(), now)
                .unwrap();
        }
    };
    run(Replay {
        capture: "udp_request_reply",
        port: 51541,
        cfg: config(0xCCCC_DDDD),
        cmds: vec![
            connect_at(1),
            cmd(3, move |c, now, _| {
                participant(c, now);
                create(c, now, replier, ObjectVariant::Replier {
                    representation: xml("<dds><replier profile_name=\"my_requester\"service_name=\"service_name\"request_type=\"request_type\"reply_type=\"reply_type\"></replier></dds>"),
                    participant_id: oid(1, ObjectKind::Participant),
                });
            }),
            read_at(9, replier, R),
            cmd(31, answer(0)),
            cmd(38, answer(1)),
            cmd(46, answer(2)),
        ],
        defer: vec![],
    });
    let request = move |a: u32, b: u32| {
        move |c: &mut Client, now: Instant, _: &[Event]| {
            let mut d = a.to_le_bytes().to_vec();
            d.extend_from_slice(&b.to_le_bytes());
            c.request(requester, R, &d, now).unwrap();
        }
    };
    let o = run(Replay {
        capture: "udp_request_reply",
        port: 42300,
        cfg: config(0xAAAA_BBBB),
        cmds: vec![
            connect_at(11),
            cmd(13, move |c, now, _| {
                participant(c, now);
                create(c, now, requester, ObjectVariant::Requester {
                    representation: xml("<dds><requester profile_name=\"my_requester\"service_name=\"service_name\"request_type=\"request_type\"reply_type=\"reply_type\"></requester></dds>"),
                    participant_id: oid(1, ObjectKind::Participant),
                });
            }),
            read_at(24, requester, R),
            cmd(24, request(0, 0)),
            cmd(26, request(1, 1)),
            cmd(30, request(2, 2)),
            cmd(39, request(3, 3)),
            cmd(47, request(4, 4)),
        ],
        defer: vec![],
    });
    // the reply to request 1 + 1 (request id 0x0E) says 2, and so on
    let replies: Vec<(u16, u64)> = o
        .events
        .iter()
        .filter_map(|e| match e {
            Event::Reply {
                request,
                data,
                requester: r,
            } if *r == requester => {
                Some((request.0, u64::from_le_bytes(data[..8].try_into().unwrap())))
            }
            _ => None,
        })
        .collect();
    assert_eq!(replies, [(0x0E, 2), (0x0F, 4), (0x10, 6)]);
}

#[test]
fn session_with_client_key_in_every_header() {
    let o = run(Replay {
        capture: "udp_session_with_client_key_binary",
        port: 53120,
        cfg: ClientConfig {
            session_id: 0x01,
            ..config(0x2222_0002)
        },
        cmds: vec![
            connect_at(1),
            cmd(3, |c, now, _| bench_entities(c, now, true, 2)),
            read_at(13, oid(1, ObjectKind::DataReader), R),
            disconnect_at(50),
        ],
        defer: vec![],
    });
    assert_eq!(data_of(&o.events).len(), 3);
    assert!(!o
        .events
        .iter()
        .any(|e| matches!(e, Event::AgentLost(LostReason::Silent))));
}
