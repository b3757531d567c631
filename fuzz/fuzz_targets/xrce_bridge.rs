//! Fuzzes `courier_wire::xrce::bridge::Bridge`, the agent's host over a
//! DDS Domain: clients create objects with the fuzzer's representations
//! (XML, references, binary blobs, kinds and parents of its choosing),
//! write, read with any delivery control, delete, acknowledge (or not),
//! while RTPS datagrams of the fuzzer's own arrive and time passes (in
//! steps of up to 4 minutes: a client that answers nothing for 30 s gets
//! slow HEARTBEATs, its unsent backlog dropped and its readers trimmed).
//! Writers and readers made from XML offer or request a liveliness of the
//! fuzzer's kind and lease. Nothing may panic and the agent machine's
//! memory stays bounded.
#![no_main]

use std::time::{Duration, Instant, SystemTime};

use courier_wire::dds::Domain;
use courier_wire::rtps::participant::{guid_prefix, Config};
use courier_wire::rtps::Locator;
use courier_wire::xrce::bridge::{Bridge, BridgeConfig, Profiles};
use courier_wire::xrce::{
    AckNack, BaseObjectRequest, ClientKey, ClientRepresentation, Create, DeliveryControl, Message,
    MessageHeader, ObjectId, ObjectKind, ObjectVariant, Payload, ReadData, Representation,
    RequestId, StreamId, Submessage,
};
use libfuzzer_sys::fuzz_target;

const REFS: &str = r#"<profiles>
  <participant profile_name="p"><rtps><name>p</name></rtps></participant>
  <topic profile_name="t"><name>T</name><dataType>D</dataType></topic>
  <data_writer profile_name="w"><topic><name>T</name><dataType>D</dataType></topic></data_writer>
  <data_reader profile_name="r"><topic><name>T</name><dataType>D</dataType></topic></data_reader>
  <requester profile_name="q" service_name="s" request_type="a" reply_type="b"/>
  <replier profile_name="y" service_name="s" request_type="a" reply_type="b"/>
</profiles>"#;

const KINDS: [ObjectKind; 9] = [
    ObjectKind::Participant,
    ObjectKind::Topic,
    ObjectKind::Publisher,
    ObjectKind::Subscriber,
    ObjectKind::DataWriter,
    ObjectKind::DataReader,
    ObjectKind::Requester,
    ObjectKind::Replier,
    ObjectKind::QosProfile,
];

fuzz_target!(|data: &[u8]| {
    let t0 = Instant::now();
    let mut now = t0;
    let cfg = Config::udpv4(0, 0, guid_prefix([3; 10]), [127, 0, 0, 1]).unwrap();
    let domain = Domain::new(cfg, t0, SystemTime::UNIX_EPOCH);
    let mut bc = BridgeConfig::default();
    bc.profiles = Profiles::parse(REFS).unwrap();
    bc.reader_queue = 16;
    bc.agent.max_clients = 4;
    let mut b: Bridge<u8> = Bridge::new(bc, domain, t0, SystemTime::UNIX_EPOCH);
    let mut bytes = data.iter().copied();
    let mut next = || bytes.next().unwrap_or(0);
    let mut seq = [0u16; 4];
    for _ in 0..data.len() {
        let op = next();
        let arg = next();
        let from = arg & 3;
        let header = |seq: &mut [u16; 4], reliable: bool| {
            let s = &mut seq[usize::from(from)];
            *s = s.wrapping_add(1);
            let stream = if reliable { StreamId::RELIABLE } else { StreamId::BEST_EFFORT };
            MessageHeader::new(0x81, stream, s.wrapping_sub(1))
        };
        let sub = match op % 9 {
            0 => {
                let len = usize::from(next());
                let m: Vec<u8> = (0..len).map(|_| next()).collect();
                let _ = b.handle_input(from, &m, now);
                None
            }
            1 if op & 0x80 != 0 => {
                // an ACKNACK of the reliable output stream: the client answers
                let ack = AckNack {
                    first_unacked: u16::from(next()) | u16::from(next()) << 8,
                    nack_bitmap: [next() & (arg >> 2), 0],
                    stream_id: StreamId::RELIABLE,
                };
                let m = Message::new(
                    MessageHeader::new(0x81, StreamId::NONE, 0),
                    vec![Submessage::new(Payload::AckNack(ack))],
                );
                if let Ok(m) = m.to_vec() {
                    let _ = b.handle_input(from, &m, now);
                }
                None
            }
            1 => {
                seq[usize::from(from)] = 0;
                let key = ClientKey::from(u32::from(from) + 1);
                let rep = ClientRepresentation::new(key, 0x81, 512);
                let m = Message::new(
                    MessageHeader::create_client(0x81, key),
                    vec![Submessage::new(Payload::CreateClient(rep))],
                );
                if let Ok(m) = m.to_vec() {
                    let _ = b.handle_input(from, &m, now);
                }
                None
            }
            2 => {
                let kind = KINDS[usize::from(arg >> 2) % KINDS.len()];
                let id = ObjectId::new(u16::from(next() % 3), kind);
                let parent = ObjectId(u16::from(next()) << 4 | u16::from(next() % 16));
                let len = usize::from(next() % 64);
                let text: Vec<u8> = (0..len).map(|_| next()).collect();
                let rep = match next() % 4 {
                    0 => Representation::Binary(text),
                    1 => Representation::Xml(String::from_utf8_lossy(&text).into_owned()),
                    2 => Representation::Reference(["p", "t", "w", "r", "q", "y", "x"][usize::from(arg % 7)].into()),
                    _ => {
                        // a liveliness by the first byte: kind, lease
                        let l = text.first().copied().unwrap_or(0xff);
                        let kind = ["AUTOMATIC", "MANUAL_BY_PARTICIPANT", "MANUAL_BY_TOPIC_LIVELINESS_QOS", "SOMETIMES"][usize::from(l & 3)];
                        let lease = [
                            "<sec>0</sec><nanosec>200000000</nanosec>",
                            "<sec>1</sec>",
                            "<sec>DURATION_INFINITY</sec>",
                            "<sec>0</sec>",
                        ][usize::from(l >> 2 & 3)];
                        let qos = match l >> 4 {
                            0..=11 => format!("<qos><liveliness><kind>{kind}</kind><lease_duration>{lease}</lease_duration></liveliness></qos>"),
                            12 | 13 => format!("<qos><liveliness><kind>{kind}</kind></liveliness></qos>"),
                            _ => String::new(),
                        };
                        Representation::Xml(format!(
                            "<dds><{0}><topic><name>T</name><dataType>D</dataType></topic>{qos}</{0}></dds>",
                            ["data_writer", "data_reader", "topic"][usize::from(arg % 3)]
                        ))
                    }
                };
                let object = match kind {
                    ObjectKind::Participant => ObjectVariant::Participant { representation: rep, domain_id: i16::from(arg % 2) },
                    ObjectKind::Topic => ObjectVariant::Topic { representation: rep, participant_id: parent },
                    ObjectKind::Publisher => ObjectVariant::Publisher { representation: rep, participant_id: parent },
                    ObjectKind::Subscriber => ObjectVariant::Subscriber { representation: rep, participant_id: parent },
                    ObjectKind::DataWriter => ObjectVariant::DataWriter { representation: rep, publisher_id: parent },
                    ObjectKind::DataReader => ObjectVariant::DataReader { representation: rep, subscriber_id: parent },
                    ObjectKind::Requester => ObjectVariant::Requester { representation: rep, participant_id: parent },
                    ObjectKind::Replier => ObjectVariant::Replier { representation: rep, participant_id: parent },
                    _ => ObjectVariant::QosProfile(rep),
                };
                Some(Submessage::with_flags(
                    1 | (op & 0x06),
                    Payload::Create(Create {
                        request: BaseObjectRequest::new(u16::from(next()) + 10, id),
                        object,
                    }),
                ))
            }
            3 => {
                let len = usize::from(next()) * usize::from(next() % 8 + 1);
                let id = ObjectId::new(u16::from(next() % 3), KINDS[usize::from(arg >> 2) % 8]);
                Some(Submessage::new(Payload::WriteData(courier_wire::xrce::Data {
                    request: BaseObjectRequest::new(u16::from(next()) + 10, id),
                    data: vec![arg; len],
                })))
            }
            4 => {
                let id = ObjectId::new(u16::from(next() % 3), KINDS[usize::from(arg >> 2) % 8]);
                // (with delivery control by `op`'s bit 7 too: clients 0
                // and 2, the ones that can have a participant, read with it)
                let dc = (arg & 1 == 1 || op & 0x80 != 0).then(|| DeliveryControl {
                    max_samples: u16::from(next()) * 257,
                    max_elapsed_time: u16::from(next() % 4),
                    max_bytes_per_second: u16::from(next()) * 16,
                    min_pace_period: u16::from(next()),
                });
                Some(Submessage::new(Payload::ReadData(ReadData {
                    request: BaseObjectRequest::new(u16::from(next()) + 10, id),
                    preferred_stream_id: if op & 0x10 == 0 { StreamId::RELIABLE } else { StreamId::BEST_EFFORT },
                    data_format: 0,
                    content_filter: None,
                    delivery_control: dc,
                })))
            }
            5 => {
                let id = ObjectId(u16::from(next()) << 8 | u16::from(next()));
                Some(Submessage::new(Payload::Delete(BaseObjectRequest {
                    request_id: RequestId(u16::from(next()) + 10),
                    object_id: id,
                })))
            }
            6 => {
                let len = usize::from(next());
                let m: Vec<u8> = (0..len).map(|_| next()).collect();
                b.handle_datagram(Locator::udpv4([127, 0, 0, 1], 7411), &m, now);
                None
            }
            _ => {
                now += if op % 9 == 8 && op & 0x80 != 0 {
                    Duration::from_secs(u64::from(arg))
                } else {
                    Duration::from_millis(u64::from(arg) * 10)
                };
                b.handle_timeout(now);
                None
            }
        };
        if let Some(sub) = sub {
            let reliable = op & 0x40 == 0;
            if let Ok(m) = Message::new(header(&mut seq, reliable), vec![sub]).to_vec() {
                let _ = b.handle_input(from, &m, now);
            }
        }
        while b.poll_transmit().is_some() {}
        while b.poll_datagram().is_some() {}
        while b.poll_event().is_some() {}
        assert!(
            b.agent().buffered_bytes() < 32 << 20,
            "agent holds {} bytes",
            b.agent().buffered_bytes()
        );
    }
});
