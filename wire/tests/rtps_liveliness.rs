//! LIVELINESS end to end between two sans-I/O domains on the simulated
//! network (explicit time, no sockets): a reader that requests a finite
//! lease sees each matched writer alive, not alive when its lease lapses,
//! and alive again on the next assertion, by the rules of the writer's
//! kind; the participant messages (WLP) Courier sends, byte for byte, and
//! those Cyclone DDS and Fast DDS send, parsed.

use std::time::Duration;

use courier_wire::dds::{Domain, Event, ReaderId, WriterId};
use courier_wire::rtps::discovery::{Duration as RtpsDuration, EndpointQos, LivelinessKind};
use courier_wire::rtps::participant::{
    self, guid_prefix, Change, Config, EndpointConfig, ParticipantMessage, PmdError,
    PMD_KIND_AUTOMATIC, PMD_KIND_MANUAL,
};
use courier_wire::rtps::{EntityId, Guid, GuidPrefix, Locator};
use courier_wire::sim::{self, Faults};

const LO: [u8; 4] = [127, 0, 0, 1];

type Net = sim::Net<Domain>;

fn config(i: usize) -> Config {
    // the participants' own lease stays the default 10 s: longer than
    // every stop below, so no participant is lost
    Config::udpv4(0, i as u32, guid_prefix([i as u8 + 1; 10]), LO)
        .unwrap()
        .with_unicast_peers(&[LO], 9)
}

fn lease(kind: LivelinessKind, secs: u64) -> (LivelinessKind, RtpsDuration) {
    (kind, RtpsDuration::from_std(Duration::from_secs(secs)))
}

fn writer_cfg(topic: &str, kind: LivelinessKind, secs: u64) -> EndpointConfig {
    let mut q = EndpointQos::writer_default();
    q.liveliness = lease(kind, secs);
    EndpointConfig::writer(topic, "T").qos(q)
}

fn reader_cfg(topic: &str, kind: LivelinessKind, secs: u64) -> EndpointConfig {
    let mut q = EndpointQos::reader_default();
    q.liveliness = lease(kind, secs);
    EndpointConfig::reader(topic, "T").qos(q)
}

/// A writer on node `i` of `topic`, offering `kind` within `secs`.
fn writer(net: &mut Net, i: usize, topic: &str, kind: LivelinessKind, secs: u64) -> WriterId {
    let now = net.now();
    net.node(i)
        .create_writer(writer_cfg(topic, kind, secs), now)
        .unwrap()
}

/// A reader on node `i` of `topic`, requesting `kind` within `secs`.
fn reader(net: &mut Net, i: usize, topic: &str, kind: LivelinessKind, secs: u64) -> ReaderId {
    let now = net.now();
    net.node(i)
        .create_reader(reader_cfg(topic, kind, secs), now)
        .unwrap()
}

/// Node 0 and node 1, nothing created yet.
fn net() -> Net {
    let mut net = Net::new(7, Faults::none());
    for i in 0..2 {
        let d = Domain::new(config(i), net.now(), net.wall());
        net.add(d);
    }
    net
}

/// `(alive, alive_count, not_alive_count)` of each liveliness change of
/// reader `r` on node `i`, in order.
fn changes(net: &Net, i: usize, r: ReaderId) -> Vec<(bool, u32, u32)> {
    net.hosts[i]
        .events
        .iter()
        .filter_map(|e| match e {
            Event::LivelinessChanged {
                reader,
                alive,
                alive_count,
                not_alive_count,
                ..
            } if *reader == r => Some((*alive, *alive_count, *not_alive_count)),
            _ => None,
        })
        .collect()
}

fn participant_lost(net: &Net, i: usize) -> bool {
    net.has(i, |e| {
        matches!(
            e,
            Event::Discovery(participant::Event::ParticipantLost { .. })
        )
    })
}

fn matched(net: &mut Net, r: ReaderId) {
    assert!(
        net.run_until(Duration::from_secs(10), |n| changes(n, 1, r).len() == 1),
        "the reader never saw the writer alive: {:?}",
        changes(net, 1, r)
    );
    assert_eq!(changes(net, 1, r), [(true, 1, 0)], "alive from the match");
}

#[test]
fn an_automatic_writer_stays_alive_without_data_lapses_when_its_participant_stops_and_comes_back() {
    let mut net = net();
    let w = writer(&mut net, 0, "lidar", LivelinessKind::Automatic, 1);
    let r = reader(&mut net, 1, "lidar", LivelinessKind::Automatic, 2);
    matched(&mut net, r);
    // no data, and SPDP only every 3 s: the participant messages keep
    // the 1 s lease
    net.run_for(Duration::from_secs(5));
    assert_eq!(changes(&net, 1, r), [(true, 1, 0)], "alive throughout");

    // the writer's process stops: within its lease (plus the check) the
    // reader sees it not alive, and its participant is still known
    net.freeze(0);
    assert!(
        net.run_until(Duration::from_millis(1500), |n| changes(n, 1, r).len() == 2),
        "no lapse"
    );
    assert_eq!(changes(&net, 1, r)[1], (false, 0, 1));
    assert!(!participant_lost(&net, 1), "the participant is still known");
    net.run_for(Duration::from_secs(1));
    assert_eq!(changes(&net, 1, r).len(), 2, "one lapse, one event");

    // it resumes: the next thing it sends makes the writer alive again
    net.thaw(0);
    assert!(
        net.run_until(Duration::from_secs(2), |n| changes(n, 1, r).len() == 3),
        "not alive again"
    );
    assert_eq!(changes(&net, 1, r)[2], (true, 1, 0));
    // and deleting it takes it out of the counts
    let now = net.now();
    assert!(net.node(0).delete_writer(w, now));
    assert!(
        net.run_until(Duration::from_secs(2), |n| changes(n, 1, r).len() == 4),
        "deletion not seen"
    );
    assert_eq!(changes(&net, 1, r)[3], (false, 0, 0));
    assert!(!participant_lost(&net, 1));
}

#[test]
fn a_manual_by_topic_writer_lapses_without_writes_while_its_participant_talks() {
    let mut net = net();
    // another writer of node 0 with an automatic lease: its participant
    // messages go out every 333 ms, so node 0 is heard all the time
    writer(&mut net, 0, "chatter", LivelinessKind::Automatic, 1);
    let w = writer(&mut net, 0, "lidar", LivelinessKind::ManualByTopic, 1);
    let r = reader(&mut net, 1, "lidar", LivelinessKind::ManualByTopic, 2);
    matched(&mut net, r);
    assert!(
        net.run_until(Duration::from_millis(1500), |n| changes(n, 1, r).len() == 2),
        "no lapse without writes"
    );
    assert_eq!(changes(&net, 1, r)[1], (false, 0, 1));
    // the writer knows it too
    assert!(net.has(0, |e| matches!(
        e,
        Event::LivelinessLost { writer, total: 1 } if *writer == w
    )));

    // a write asserts it
    let now = net.now();
    net.node(0)
        .write(w, Change::alive(&[0, 1, 0, 0, 1, 0, 0, 0]), now)
        .unwrap();
    assert!(
        net.run_until(Duration::from_millis(500), |n| changes(n, 1, r).len() == 3),
        "a write did not make it alive"
    );
    assert_eq!(changes(&net, 1, r)[2], (true, 1, 0));

    // and so does assert_liveliness (a HEARTBEAT with the liveliness
    // flag), again and again, without data
    for _ in 0..6 {
        net.run_for(Duration::from_millis(500));
        let now = net.now();
        assert!(net.node(0).assert_liveliness(w, now));
    }
    assert_eq!(changes(&net, 1, r).len(), 3, "asserted: no lapse");
    assert!(
        net.run_until(Duration::from_millis(1500), |n| changes(n, 1, r).len() == 4),
        "no lapse after the assertions stopped"
    );
    assert_eq!(changes(&net, 1, r)[3], (false, 0, 1));
    assert!(!participant_lost(&net, 1));
}

#[test]
fn a_manual_by_participant_writer_is_kept_alive_by_manual_participant_messages() {
    let mut net = net();
    let w = writer(&mut net, 0, "lidar", LivelinessKind::ManualByParticipant, 1);
    // a second manual-by-participant writer, never written: asserting
    // the first asserts it too
    let w2 = writer(&mut net, 0, "imu", LivelinessKind::ManualByParticipant, 1);
    let r = reader(&mut net, 1, "imu", LivelinessKind::ManualByParticipant, 2);
    matched(&mut net, r);
    for _ in 0..6 {
        net.run_for(Duration::from_millis(500));
        let now = net.now();
        assert!(net.node(0).assert_liveliness(w, now));
    }
    assert_eq!(changes(&net, 1, r), [(true, 1, 0)], "kept alive");
    assert!(!net.has(
        0,
        |e| matches!(e, Event::LivelinessLost { writer, .. } if *writer == w2)
    ));
    assert!(
        net.run_until(Duration::from_millis(1500), |n| changes(n, 1, r).len() == 2),
        "no lapse"
    );
    assert_eq!(changes(&net, 1, r)[1], (false, 0, 1));
}

/// DDS's `DomainParticipant::assert_liveliness`: the domain-wide
/// assertion keeps its manual-by-participant writers alive at a remote
/// reader and at the writers themselves, and asserts no manual-by-topic
/// writer.
#[test]
fn the_participant_assertion_keeps_manual_by_participant_writers_alive_only() {
    let mut net = net();
    let by_pp = writer(&mut net, 0, "imu", LivelinessKind::ManualByParticipant, 1);
    let by_topic = writer(&mut net, 0, "lidar", LivelinessKind::ManualByTopic, 1);
    let r_pp = reader(&mut net, 1, "imu", LivelinessKind::ManualByParticipant, 2);
    let r_topic = reader(&mut net, 1, "lidar", LivelinessKind::ManualByTopic, 2);
    matched(&mut net, r_pp);
    assert!(
        net.run_until(Duration::from_secs(1), |n| !changes(n, 1, r_topic)
            .is_empty()),
        "the manual-by-topic writer never matched"
    );
    for _ in 0..6 {
        net.run_for(Duration::from_millis(500));
        let now = net.now();
        net.node(0).assert_participant_liveliness(now);
    }
    assert_eq!(changes(&net, 1, r_pp), [(true, 1, 0)], "kept alive");
    assert_eq!(
        changes(&net, 1, r_topic),
        [(true, 1, 0), (false, 0, 1)],
        "the participant's assertion does not assert a manual-by-topic writer"
    );
    let lost = |net: &Net, of: WriterId| {
        net.has(
            0,
            |e| matches!(e, Event::LivelinessLost { writer, .. } if *writer == of),
        )
    };
    assert!(!lost(&net, by_pp), "its own writer saw it asserted");
    assert!(lost(&net, by_topic));
    assert!(
        net.run_until(Duration::from_millis(1500), |n| changes(n, 1, r_pp).len()
            == 2),
        "no lapse after the assertions stopped"
    );
    assert_eq!(changes(&net, 1, r_pp)[1], (false, 0, 1));
    assert!(lost(&net, by_pp));
}

/// An automatic participant message, as Courier sends it (RTPS 2.5
/// §9.6.2.1 and Cyclone DDS's `ddsi_participant_message_data_ops` = GUID
/// prefix + kind as one big-endian GUID, then the data sequence): DATA
/// from ENTITYID_P2P_BUILTIN_PARTICIPANT_MESSAGE_WRITER with the instance's
/// key hash inline and a 24-octet CDR_LE payload.
#[test]
fn participant_messages_are_sent_byte_for_byte_as_the_spec_lays_them_out() {
    let mut net = net();
    net.tapping = true;
    writer(&mut net, 0, "lidar", LivelinessKind::Automatic, 1);
    net.run_for(Duration::from_secs(2));
    let prefix = net.node(0).participant().guid_prefix().0;
    let mut key = prefix.to_vec();
    key.extend_from_slice(&[0, 0, 0, 1]);
    let mut payload = vec![0x00, 0x01, 0x00, 0x00]; // CDR_LE, options 0
    payload.extend_from_slice(&prefix); // participantGuidPrefix
    payload.extend_from_slice(&[0, 0, 0, 1]); // kind: AUTOMATIC_LIVELINESS_UPDATE
    payload.extend_from_slice(&[0, 0, 0, 0]); // data: sequence<octet> of length 0
                                              // DATA, flags E|Q|D, 20 + 24 (inline QoS) + 24 (payload) octets
    let mut head = vec![0x15, 0x07, 68, 0];
    head.extend_from_slice(&[0, 0, 16, 0]); // extra flags, octetsToInlineQos
                                            // reader id: the one PMD reader on node 1
    head.extend_from_slice(&[0x00, 0x02, 0x00, 0xc7, 0x00, 0x02, 0x00, 0xc2]);
    let mut qos = vec![0x70, 0x00, 16, 0]; // PID_KEY_HASH
    qos.extend_from_slice(&key);
    qos.extend_from_slice(&[0x01, 0x00, 0, 0]); // PID_SENTINEL
    let mut sns = Vec::new();
    let mut found = 0;
    for p in &net.tap {
        let b = &p.payload;
        for at in 0..b
            .len()
            .saturating_sub(head.len() + 8 + qos.len() + payload.len())
        {
            if b[at..].starts_with(&head) {
                let sn = &b[at + head.len()..at + head.len() + 8];
                let rest = &b[at + head.len() + 8..];
                assert!(rest.starts_with(&qos), "inline QoS: {rest:02x?}");
                assert!(
                    rest[qos.len()..].starts_with(&payload),
                    "payload: {:02x?}",
                    &rest[qos.len()..]
                );
                sns.push(sn.to_vec());
                found += 1;
            }
        }
    }
    // one at once and every 333 ms: about six in 2 s
    assert!(found >= 5, "{found} participant messages sent");
    assert_eq!(
        sns[0],
        [0, 0, 0, 0, 1, 0, 0, 0],
        "the first is sequence number 1"
    );
}

/// A datagram Cyclone DDS 11 (the `cyclonedds` 11.0.1 Python package)
/// sent from one participant to another on `lo`, captured with tcpdump
/// (a writer offering AUTOMATIC 1 s, domain 197): INFO_DST, INFO_TS, the
/// automatic participant message (DATA, no inline QoS, CDR_LE with options
/// 0, data length 1 with one zero octet and 3 of padding;
/// `ddsi_write_pmd_message` in src/core/ddsi/src/ddsi_pmd.c), and a
/// HEARTBEAT of the participant-message writer.
const CYCLONE_PMD_DATAGRAM: &str = "5254505302050110011000b28b7cf4b8389bf4f2\
    0e010c000110b69d2828e38439203e4a\
    09010800c3710a6bf5e12a1c\
    1505300000001000000200c7000200c2000000000100000000010000011000b28b7cf4b8389bf4f2\
    000000010100000000000000\
    07011c00000200c7000200c20000000001000000000000000100000002000000";

fn unhex(s: &str) -> Vec<u8> {
    let s: String = s.split_whitespace().collect();
    (0..s.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&s[i..i + 2], 16).unwrap())
        .collect()
}

/// An SPDP announcement of participant `prefix` (domain 0, on `lo`).
fn spdp_of(prefix: GuidPrefix) -> Vec<u8> {
    use courier_wire::rtps::discovery::ParticipantData;
    use courier_wire::rtps::{Data, ProtocolVersion, SequenceNumber, Submessage, VendorId};
    let meta = Locator::udpv4(LO, 7410);
    let p = ParticipantData {
        guid_prefix: prefix,
        protocol_version: ProtocolVersion::V2_5,
        vendor: VendorId([1, 0x10]),
        domain_id: Some(0),
        default_unicast: vec![Locator::udpv4(LO, 7411)],
        default_multicast: Vec::new(),
        metatraffic_unicast: vec![meta],
        metatraffic_multicast: Vec::new(),
        lease_duration: RtpsDuration::from_std(Duration::from_secs(10)),
        builtin_endpoints: 0xfc3f,
        entity_name: None,
    };
    let payload = p.to_payload();
    let mut b = b"RTPS\x02\x05\x01\x10".to_vec();
    b.extend_from_slice(&prefix.0);
    Submessage::Data(Data {
        reader_id: EntityId::SPDP_READER,
        writer_id: EntityId::SPDP_WRITER,
        writer_sn: SequenceNumber(1),
        inline_qos: None,
        payload: Some(&payload),
        key: false,
        non_standard: false,
    })
    .write(&mut b, true);
    b
}

#[test]
fn a_captured_cyclone_participant_message_parses_and_is_accepted() {
    use courier_wire::rtps::{Message, Submessage};
    let datagram = unhex(CYCLONE_PMD_DATAGRAM);
    let mut payload = None;
    let header = Message::parse_each(&datagram, |_, sm| {
        if let Submessage::Data(d) = sm {
            if d.writer_id == EntityId::P2P_MESSAGE_WRITER {
                payload = d.payload;
            }
        }
    })
    .unwrap();
    let m = ParticipantMessage::from_payload(payload.expect("a DATA of the PMD writer")).unwrap();
    assert_eq!(m.prefix, header.guid_prefix, "it speaks for its sender");
    assert_eq!(m.kind, PMD_KIND_AUTOMATIC);
    assert_eq!(m.data, [0]);
    // a domain takes it, addressed to it (INFO_DST names the receiver)
    let mut net = net();
    let now = net.now();
    let d = net.node(0);
    let ours = d.participant().guid_prefix().0;
    let mut to_us = datagram.clone();
    to_us[24..36].copy_from_slice(&ours);
    let from = Locator::udpv4(LO, 56660);
    let writer = Guid {
        prefix: header.guid_prefix,
        entity: EntityId([0, 0, 1, 2]),
    };
    // from a participant not known (no SPDP yet): ignored, as Cyclone does
    d.handle_datagram(from, &to_us, now);
    assert_eq!(d.participant().pmd_ignored(), 1, "unknown participant");
    d.handle_datagram(from, &spdp_of(header.guid_prefix), now);
    assert!(d.participant().participant(header.guid_prefix).is_some());
    d.handle_datagram(from, &to_us, now);
    assert_eq!(d.participant().pmd_ignored(), 1, "not malformed");
    // automatic: it asserts no manual-by-participant writer
    let manual = LivelinessKind::ManualByParticipant;
    assert_eq!(d.participant().liveliness_asserted(writer, manual), None);
    // the same message of the manual kind (the next sequence number) does
    let later = now + Duration::from_millis(5);
    let mut manual_msg = to_us.clone();
    manual_msg[91] = 2; // the last octet of the kind
    manual_msg[68] = 2; // writerSN low word (little-endian): 2
    d.handle_datagram(from, &manual_msg, later);
    assert_eq!(d.participant().pmd_ignored(), 1);
    assert_eq!(
        d.participant().liveliness_asserted(writer, manual),
        Some(later)
    );
}

/// A datagram Fast DDS 2.9.1 (Debian's libfastrtps2.9) sent to another
/// Fast DDS participant on `lo`, captured with tcpdump (a writer offering
/// MANUAL_BY_PARTICIPANT 1 s asserting its liveliness, domain 196):
/// INFO_TS, the manual participant message (DATA, no inline QoS so no key
/// hash, encapsulation PL_CDR_LE 00 03 though the body is plain CDR, data
/// length 0 and four more zero octets; `WLP::send_liveliness_message` in
/// src/cpp/rtps/builtin/liveliness/WLP.cpp, 2.9.1 lines 901-913), and a
/// vendor-specific submessage (0x80) of Fast DDS's.
const FASTDDS_PMD_DATAGRAM: &str = "525450530203010f010f78fd1256853400000000\
    09010800b2760a6b52fcb6a1\
    1505300000001000000200c7000200c200000000010000000003000\
    0010f78fd125685340000000000000002000000000000000\
    080013800010000005adc00000000000000000000000000007f000001b2760a6b\
    1822b9a1130000000000000054190000000000000000000000000000";

/// Fast DDS's participant messages are taken as what they say: a manual one
/// asserts its participant's MANUAL_BY_PARTICIPANT writers (before, its
/// PL_CDR_LE label made Courier count it as malformed, and a Fast DDS
/// manual-by-participant writer lapsed while it asserted).
#[test]
fn a_captured_fast_dds_participant_message_is_accepted() {
    use courier_wire::rtps::{Message, Submessage};
    let datagram = unhex(FASTDDS_PMD_DATAGRAM);
    let mut payload = None;
    let header = Message::parse_each(&datagram, |_, sm| {
        if let Submessage::Data(d) = sm {
            if d.writer_id == EntityId::P2P_MESSAGE_WRITER {
                payload = d.payload;
            }
        }
    })
    .unwrap();
    let payload = payload.expect("a DATA of the PMD writer");
    assert_eq!(&payload[..4], [0, 3, 0, 0], "labelled PL_CDR_LE");
    let m = ParticipantMessage::from_payload(payload).unwrap();
    assert_eq!(m.prefix, header.guid_prefix, "it speaks for its sender");
    assert_eq!((m.kind, m.data.len()), (PMD_KIND_MANUAL, 0));

    let mut net = net();
    let now = net.now();
    let d = net.node(0);
    let from = Locator::udpv4(LO, 56650);
    let writer = Guid {
        prefix: header.guid_prefix,
        entity: EntityId([0, 0, 1, 2]),
    };
    d.handle_datagram(from, &spdp_of(header.guid_prefix), now);
    assert!(d.participant().participant(header.guid_prefix).is_some());
    let manual = LivelinessKind::ManualByParticipant;
    assert_eq!(d.participant().liveliness_asserted(writer, manual), None);
    let later = now + Duration::from_millis(5);
    d.handle_datagram(from, &datagram, later);
    assert_eq!(d.participant().pmd_ignored(), 0, "not malformed");
    assert_eq!(
        d.participant().liveliness_asserted(writer, manual),
        Some(later)
    );
}

/// A manual participant message laid out as Cyclone DDS 11 writes one (as
/// captured above, with kind MANUAL_LIVELINESS_UPDATE = 2 of
/// src/core/ddsi/include/dds/ddsi/ddsi_protocol.h) and one as Cyclone's
/// own test sends (src/core/ddsi/tests/pmd_message.c: CDR_BE, data
/// length 0).
#[test]
fn cyclone_participant_messages_parse_and_malformed_ones_are_refused() {
    let prefix = [
        0x01, 0x10, 0x4b, 0x2a, 0x11, 0x22, 0x33, 0x44, 0x00, 0x00, 0x00, 0x01,
    ];
    let mut cyclone = vec![0x00, 0x01, 0x00, 0x00];
    cyclone.extend_from_slice(&prefix);
    cyclone.extend_from_slice(&[0, 0, 0, 2, 1, 0, 0, 0, 0, 0, 0, 0]);
    let m = ParticipantMessage::from_payload(&cyclone).unwrap();
    assert_eq!(m.prefix, GuidPrefix(prefix));
    assert_eq!(m.kind, PMD_KIND_MANUAL);
    assert_eq!(m.data, [0]);

    let mut be = vec![0x00, 0x00, 0x00, 0x00];
    be.extend_from_slice(&prefix);
    be.extend_from_slice(&[0, 0, 0, 1, 0, 0, 0, 0]);
    let m = ParticipantMessage::from_payload(&be).unwrap();
    assert_eq!((m.kind, m.data.len()), (PMD_KIND_AUTOMATIC, 0));

    let mut long = be.clone();
    long[23] = 200;
    assert_eq!(
        ParticipantMessage::from_payload(&long),
        Err(PmdError::Length(200))
    );
    assert_eq!(
        ParticipantMessage::from_payload(&be[..20]),
        Err(PmdError::Short)
    );
}

/// A DATA from a peer's participant-message writer that does not decode,
/// or that speaks for another participant, is counted and ignored.
#[test]
fn malformed_participant_messages_are_counted_not_acted_on() {
    let mut net = net();
    let now = net.now();
    let d = net.node(0);
    let sender = [0x01, 0x10, 9, 9, 9, 9, 9, 9, 9, 9, 9, 9];
    let data = |payload: &[u8]| {
        let mut b = b"RTPS\x02\x05\x01\x10".to_vec();
        b.extend_from_slice(&sender);
        let len = 20 + payload.len();
        b.extend_from_slice(&[0x15, 0x05, len as u8, 0, 0, 0, 16, 0]);
        b.extend_from_slice(&[0, 0, 0, 0, 0x00, 0x02, 0x00, 0xc2, 0, 0, 0, 0, 1, 0, 0, 0]);
        b.extend_from_slice(payload);
        b
    };
    let src = Locator::udpv4(LO, 7400);
    d.handle_datagram(src, &data(&[0, 1, 0, 0, 1, 2, 3]), now);
    let mut other = vec![0, 1, 0, 0];
    other.extend_from_slice(&[8; 12]);
    other.extend_from_slice(&[0, 0, 0, 2, 0, 0, 0, 0]);
    d.handle_datagram(src, &data(&other), now);
    let mut huge = vec![0, 1, 0, 0];
    huge.extend_from_slice(&sender);
    huge.extend_from_slice(&[0, 0, 0, 2, 0xff, 0xff, 0xff, 0xff]);
    d.handle_datagram(src, &data(&huge), now);
    assert_eq!(d.participant().pmd_ignored(), 3);
}

/// Drives `d` as a shell does (its timer, no datagrams) until `until`,
/// collecting its events.
fn drive(
    d: &mut Domain,
    events: &mut Vec<Event>,
    now: &mut std::time::Instant,
    until: std::time::Instant,
) {
    while let Some(t) = d.poll_timeout().filter(|t| *t <= until) {
        *now = t.max(*now);
        d.handle_timeout(*now);
        events.extend(std::iter::from_fn(|| d.poll_event()));
    }
    *now = until;
    events.extend(std::iter::from_fn(|| d.poll_event()));
}

/// A writer and a reader of one domain (matched in process): a
/// manual-by-topic writer lapses at the domain's own timeout and its
/// write revives it; a manual-by-participant writer is asserted by a
/// write of any writer of the domain, and lost without one.
#[test]
fn in_process_writers_lapse_and_revive_by_their_kind() {
    let mut net = net();
    let t0 = net.now();
    let ms = |n| t0 + Duration::from_millis(n);
    let d = net.node(0);
    let w = d
        .create_writer(writer_cfg("lidar", LivelinessKind::ManualByTopic, 1), t0)
        .unwrap();
    let by_pp = d
        .create_writer(
            writer_cfg("imu", LivelinessKind::ManualByParticipant, 1),
            t0,
        )
        .unwrap();
    let other = d
        .create_writer(writer_cfg("odom", LivelinessKind::Automatic, 1), t0)
        .unwrap();
    let r = d
        .create_reader(reader_cfg("lidar", LivelinessKind::ManualByTopic, 1), t0)
        .unwrap();
    let mut events = Vec::new();
    let alive = |events: &[Event]| -> Vec<bool> {
        events
            .iter()
            .filter_map(|e| match e {
                Event::LivelinessChanged { reader, alive, .. } if *reader == r => Some(*alive),
                _ => None,
            })
            .collect()
    };
    let lost = |events: &[Event], of| {
        events
            .iter()
            .filter(|e| matches!(e, Event::LivelinessLost { writer, .. } if *writer == of))
            .count()
    };
    let sample = [0, 1, 0, 0, 1, 0, 0, 0];
    let mut now = t0;
    drive(d, &mut events, &mut now, ms(900));
    assert_eq!(alive(&events), [true], "alive from the match");
    // another writer's write asserts the manual-by-participant writer,
    // not the manual-by-topic one
    d.write(other, Change::alive(&sample), now).unwrap();
    drive(d, &mut events, &mut now, ms(1500));
    assert_eq!(alive(&events), [true, false], "lapsed at 1 s");
    assert_eq!(lost(&events, w), 1);
    assert_eq!(lost(&events, by_pp), 0, "asserted at 900 ms");
    d.write(w, Change::alive(&sample), now).unwrap();
    drive(d, &mut events, &mut now, ms(1600));
    assert_eq!(alive(&events), [true, false, true], "its write revives it");
    // nothing written after 1500 ms: both manual writers are lost once
    drive(d, &mut events, &mut now, ms(3000));
    assert_eq!(lost(&events, by_pp), 1);
    assert_eq!(lost(&events, w), 2);
    assert_eq!(alive(&events), [true, false, true, false]);
}
