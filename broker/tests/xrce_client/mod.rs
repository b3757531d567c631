//! Courier's XRCE client machine over blocking sockets, and the objects
//! the agent tests create (shared by `xrce_agent.rs` and
//! `xrce_agent_netns.rs`, `xrce_agent_fastdds.rs`).
#![allow(dead_code)]

use std::io::{Read, Write};
use std::net::{SocketAddr, TcpStream, UdpSocket};
use std::path::Path;
use std::time::{Duration, Instant};

use courier_wire::xrce::serial::{self, SerialDecoder};
use courier_wire::xrce::tcp::{self, TcpDeframer};
use courier_wire::xrce::{
    qos_flags, BinaryRepresentation, Client, ClientConfig, CreationMode, DataReaderBinary,
    DataReaderQos, DataWriterBinary, EndpointQos, Event, GroupBinary, ObjectId, ObjectKind,
    ObjectVariant, ParticipantBinary, StreamId, TopicBinary,
};

pub const T: Duration = Duration::from_secs(30);

/// The agent's DDS participant for the tests: `lo`, unicast discovery to
/// 127.0.0.1, multicast off, in `domain`.
pub fn rtps(domain: u32) -> courier::rtps_backend::RtpsOptions {
    let mut o = courier::rtps_backend::RtpsOptions::default();
    o.domain = domain;
    o.interface = Some("lo".into());
    o.peers = vec!["127.0.0.1".into()];
    o.multicast = false;
    o
}

/// A two-thread runtime for the agent and sessions.
pub fn runtime() -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap()
}
pub const R: StreamId = StreamId::RELIABLE;

pub enum Io {
    Udp(UdpSocket),
    Tcp(TcpStream, TcpDeframer),
    Serial(Box<dyn serialport::SerialPort>, SerialDecoder),
}

/// Courier's XRCE client machine over a blocking socket.
pub struct XClient {
    pub c: Client,
    pub io: Io,
    pub events: Vec<Event>,
}

impl XClient {
    pub fn new(key: u32, io: Io) -> Self {
        let mut c = Client::new(ClientConfig::new(key));
        c.connect(Instant::now());
        let mut x = XClient {
            c,
            io,
            events: Vec::new(),
        };
        assert!(
            x.until(T, |e| e
                .iter()
                .any(|e| matches!(e, Event::Connected { .. }))),
            "no session"
        );
        x
    }

    pub fn udp(key: u32, agent: SocketAddr) -> Self {
        let s = UdpSocket::bind("127.0.0.1:0").unwrap();
        s.connect(agent).unwrap();
        Self::new(key, Io::Udp(s))
    }

    pub fn tcp(key: u32, agent: SocketAddr) -> Self {
        let s = TcpStream::connect(agent).unwrap();
        s.set_nodelay(true).unwrap();
        Self::new(key, Io::Tcp(s, TcpDeframer::new()))
    }

    pub fn serial(key: u32, path: &Path) -> Self {
        let p = serialport::new(path.to_string_lossy(), 115_200)
            .timeout(Duration::from_millis(5))
            .open()
            .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        Self::new(key, Io::Serial(p, SerialDecoder::new()))
    }

    /// Sends, receives for up to 5 ms, fires timers.
    pub fn turn(&mut self) {
        while let Some(m) = self.c.poll_transmit() {
            match &mut self.io {
                Io::Udp(s) => {
                    // a connected UDP socket reports an earlier datagram's
                    // ICMP "port unreachable" on the next send: the agent
                    // was down (restart tests); the machine sends again
                    match s.send(&m) {
                        Err(e) if e.kind() == std::io::ErrorKind::ConnectionRefused => {}
                        r => {
                            r.unwrap();
                        }
                    }
                }
                Io::Tcp(s, _) => {
                    let mut f = Vec::new();
                    tcp::encode(&m, &mut f).unwrap();
                    s.write_all(&f).unwrap();
                }
                Io::Serial(p, _) => {
                    let mut f = Vec::new();
                    serial::encode(1, 0, &m, &mut f).unwrap();
                    p.write_all(&f).unwrap();
                }
            }
        }
        let mut got: Vec<Vec<u8>> = Vec::new();
        let mut buf = vec![0u8; 65_536];
        match &mut self.io {
            Io::Udp(s) => {
                s.set_read_timeout(Some(Duration::from_millis(5))).unwrap();
                if let Ok(n) = s.recv(&mut buf) {
                    got.push(buf[..n].to_vec());
                }
            }
            Io::Tcp(s, d) => {
                s.set_read_timeout(Some(Duration::from_millis(5))).unwrap();
                if let Ok(n) = s.read(&mut buf) {
                    d.push(&buf[..n]);
                }
                while let Some(Ok(m)) = d.next_frame() {
                    got.push(m);
                }
            }
            Io::Serial(p, d) => {
                if let Ok(n) = p.read(&mut buf) {
                    d.push(&buf[..n]);
                }
                while let Some(Ok(f)) = d.next_frame() {
                    got.push(f.payload);
                }
            }
        }
        let now = Instant::now();
        for m in got {
            let _ = self.c.handle_input(&m, now);
        }
        if self.c.poll_timeout().is_some_and(|t| t <= now) {
            self.c.handle_timeout(now);
        }
        while let Some(e) = self.c.poll_event() {
            self.events.push(e);
        }
    }

    pub fn until(&mut self, limit: Duration, mut done: impl FnMut(&[Event]) -> bool) -> bool {
        let end = Instant::now() + limit;
        while Instant::now() < end {
            if done(&self.events) {
                return true;
            }
            self.turn();
        }
        done(&self.events)
    }

    pub fn ok_statuses(&self) -> usize {
        self.events
            .iter()
            .filter(|e| matches!(e, Event::Status { result: Ok(_), .. }))
            .count()
    }

    /// Creates objects and waits for them all to be OK.
    pub fn create(&mut self, objects: Vec<(ObjectId, ObjectVariant)>) {
        let n = self.ok_statuses() + objects.len();
        for (id, v) in objects {
            self.c
                .create(id, v, CreationMode::REPLACE, Instant::now())
                .unwrap();
        }
        let ok = self.until(T, |e| {
            e.iter()
                .filter(|e| matches!(e, Event::Status { result: Ok(_), .. }))
                .count()
                >= n
        });
        let errors: Vec<&Event> = self
            .events
            .iter()
            .filter(|e| matches!(e, Event::Status { result: Err(_), .. }))
            .collect();
        assert!(ok && errors.is_empty(), "{errors:?}");
    }

    pub fn data(&self) -> Vec<Vec<u8>> {
        self.events
            .iter()
            .filter_map(|e| match e {
                Event::Data { data, .. } => Some(data.clone()),
                _ => None,
            })
            .collect()
    }
}

pub fn oid(kind: ObjectKind) -> ObjectId {
    ObjectId::new(1, kind)
}

pub fn bin(b: BinaryRepresentation) -> courier_wire::xrce::Representation {
    b.to_representation().unwrap()
}

pub const MSG: &str = "courier::test::Msg";

/// `courier::test::Msg` of the peers' `types.idl` (what [`msg`] encodes),
/// for a Courier session on the DDS side.
#[derive(courier::IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "courier::test::Msg")]
pub struct Msg {
    pub seq: u32,
    pub text: String,
    pub payload: Vec<u8>,
}

pub fn base(domain: u32, topic: &str) -> Vec<(ObjectId, ObjectVariant)> {
    vec![
        (
            oid(ObjectKind::Participant),
            ObjectVariant::Participant {
                representation: bin(BinaryRepresentation::Participant(
                    ParticipantBinary::default(),
                )),
                domain_id: domain as i16,
            },
        ),
        (
            oid(ObjectKind::Topic),
            ObjectVariant::Topic {
                representation: bin(BinaryRepresentation::Topic(TopicBinary {
                    topic_name: topic.into(),
                    type_reference: None,
                    type_name: Some(MSG.into()),
                })),
                participant_id: oid(ObjectKind::Participant),
            },
        ),
    ]
}

pub fn reliable() -> EndpointQos {
    EndpointQos {
        flags: qos_flags::RELIABLE,
        ..EndpointQos::default()
    }
}

/// Reliable, transient-local, keep-all: a reader that the agent's
/// participant has not discovered yet when the client writes still gets
/// every sample.
pub fn writer(domain: u32, topic: &str) -> Vec<(ObjectId, ObjectVariant)> {
    writer_with(
        domain,
        topic,
        qos_flags::RELIABLE | qos_flags::TRANSIENT_LOCAL,
    )
}

/// A writer with these QoS flags (reliable and volatile: what a Courier
/// session's publisher is by default).
pub fn writer_with(domain: u32, topic: &str, flags: u16) -> Vec<(ObjectId, ObjectVariant)> {
    let mut v = base(domain, topic);
    v.push((
        oid(ObjectKind::Publisher),
        ObjectVariant::Publisher {
            representation: bin(BinaryRepresentation::Publisher(GroupBinary::default())),
            participant_id: oid(ObjectKind::Participant),
        },
    ));
    v.push((
        oid(ObjectKind::DataWriter),
        ObjectVariant::DataWriter {
            representation: bin(BinaryRepresentation::DataWriter(DataWriterBinary {
                topic_id: oid(ObjectKind::Topic),
                qos: Some((
                    EndpointQos {
                        flags,
                        ..EndpointQos::default()
                    },
                    None,
                )),
            })),
            publisher_id: oid(ObjectKind::Publisher),
        },
    ));
    v
}

pub fn reader(domain: u32, topic: &str) -> Vec<(ObjectId, ObjectVariant)> {
    let mut v = base(domain, topic);
    v.push((
        oid(ObjectKind::Subscriber),
        ObjectVariant::Subscriber {
            representation: bin(BinaryRepresentation::Subscriber(GroupBinary::default())),
            participant_id: oid(ObjectKind::Participant),
        },
    ));
    v.push((
        oid(ObjectKind::DataReader),
        ObjectVariant::DataReader {
            representation: bin(BinaryRepresentation::DataReader(DataReaderBinary {
                topic_id: oid(ObjectKind::Topic),
                qos: Some(DataReaderQos {
                    base: reliable(),
                    time_based_filter_ms: None,
                    content_filter: None,
                }),
            })),
            subscriber_id: oid(ObjectKind::Subscriber),
        },
    ));
    v
}

/// A `courier::test::Msg` body (XCDR1 little-endian, origin at its first byte).
pub fn msg(seq: u32, text: &str, payload: &[u8]) -> Vec<u8> {
    let mut v = seq.to_le_bytes().to_vec();
    v.extend_from_slice(&(text.len() as u32 + 1).to_le_bytes());
    v.extend_from_slice(text.as_bytes());
    v.push(0);
    v.resize(v.len().next_multiple_of(4), 0);
    v.extend_from_slice(&(payload.len() as u32).to_le_bytes());
    v.extend_from_slice(payload);
    v
}

/// seq, text and payload of a `Msg` body.
pub fn unmsg(b: &[u8]) -> (u32, String, Vec<u8>) {
    let u = |at: usize| u32::from_le_bytes(b[at..at + 4].try_into().unwrap()) as usize;
    let seq = u(0) as u32;
    let tl = u(4);
    let text = String::from_utf8(b[8..8 + tl - 1].to_vec()).unwrap();
    let at = (8 + tl).next_multiple_of(4);
    let pl = u(at);
    (seq, text, b[at + 4..at + 4 + pl].to_vec())
}
