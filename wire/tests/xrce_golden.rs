//! Golden bytes: every XRCE message of every capture of eProsima Micro
//! XRCE-DDS Client/Agent 2.3.0 traffic (UDP, TCP, serial) decodes, and
//! re-encodes to exactly the captured bytes. The fixtures in
//! `tests/fixtures/xrce/` were extracted from `shared/fixtures/xrce/`; each
//! file's first line names its capture.

use std::collections::{BTreeMap, BTreeSet};
use std::path::PathBuf;

use courier_wire::xrce::{
    serial::{self, SerialDecoder},
    tcp::{self, TcpDeframer},
    Message, MessageHeader, Payload, SubmessageId,
};

fn fixture(name: &str) -> String {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures/xrce")
        .join(name);
    std::fs::read_to_string(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()))
}

fn unhex(s: &str) -> Vec<u8> {
    assert!(s.len() % 2 == 0, "odd hex length");
    (0..s.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&s[i..i + 2], 16).expect("hex"))
        .collect()
}

/// A byte stream stored as hex lines after a comment line.
fn stream(name: &str) -> Vec<u8> {
    let text = fixture(name);
    assert!(
        text.starts_with("# "),
        "{name}: first line names the capture"
    );
    text.lines()
        .filter(|l| !l.starts_with('#'))
        .flat_map(|l| unhex(l.trim()))
        .collect()
}

struct Datagram {
    number: u32,
    client_to_agent: bool,
    client_port: u16,
    bytes: Vec<u8>,
}

fn datagrams(capture: &str) -> Vec<Datagram> {
    let text = fixture(&format!("{capture}.hex"));
    assert!(text.starts_with(&format!("# {capture}.pcap")));
    text.lines()
        .filter(|l| !l.starts_with('#'))
        .map(|l| {
            let f: Vec<&str> = l.split_whitespace().collect();
            Datagram {
                number: f[0].parse().unwrap(),
                client_to_agent: f[2] == "C->A",
                client_port: f[3].parse().unwrap(),
                bytes: unhex(f[4]),
            }
        })
        .collect()
}

const UDP_CAPTURES: &[(&str, usize)] = &[
    ("udp_xml_reliable_pubsub", 46),
    ("udp_xml_besteffort_pubsub", 39),
    ("udp_binary_entities", 30),
    ("udp_ref_entities_shapes", 47),
    ("udp_request_reply", 53),
    ("udp_timesync", 8),
    ("udp_ping", 6),
    ("udp_discovery", 12),
    ("udp_reliable_loss_recovery", 57),
    ("udp_fragmentation_large_sample", 68),
    ("udp_fragmentation_continuous_example", 482),
    ("udp_session_with_client_key_binary", 53),
    ("dds_bridge_two_agents", 26),
];

fn roundtrip(what: &str, bytes: &[u8]) -> Message {
    let m = Message::decode(bytes).unwrap_or_else(|e| panic!("{what}: {e}"));
    assert_eq!(m.to_vec().unwrap(), bytes, "{what}: re-encoding differs");
    m
}

#[test]
fn every_udp_message_roundtrips() {
    let mut ids = BTreeSet::new();
    let mut total = 0;
    for &(capture, count) in UDP_CAPTURES {
        let msgs = datagrams(capture);
        assert_eq!(msgs.len(), count, "{capture}");
        for d in &msgs {
            let m = roundtrip(&format!("{capture} #{}", d.number), &d.bytes);
            ids.extend(m.submessages.iter().map(|s| s.id() as u8));
            total += 1;
        }
    }
    assert_eq!(total, 927);
    // every submessage but RESET (never sent by these peers) occurs
    let all: BTreeSet<u8> = (0..=0x0F)
        .filter(|&i| i != SubmessageId::Reset as u8)
        .collect();
    assert_eq!(ids, all);
}

/// One direction of one client's fragments: seq → (header, body, last).
type Fragments = BTreeMap<u16, (MessageHeader, Vec<u8>, bool)>;

/// FRAGMENT bodies of consecutive reliable messages, concatenated up to the
/// last fragment, give a submessage that decodes behind the first
/// fragment's header and re-encodes to the same bytes.
#[test]
fn fragments_reassemble() {
    let mut rebuilt = 0;
    for capture in [
        "udp_fragmentation_large_sample",
        "udp_fragmentation_continuous_example",
    ] {
        let mut frags: BTreeMap<(u16, bool), Fragments> = BTreeMap::new();
        for d in datagrams(capture) {
            let m = Message::decode(&d.bytes).unwrap();
            for s in &m.submessages {
                if let Payload::Fragment(body) = &s.payload {
                    frags
                        .entry((d.client_port, d.client_to_agent))
                        .or_default()
                        .insert(
                            m.header.sequence_nr,
                            (m.header, body.clone(), s.is_last_fragment()),
                        );
                }
            }
        }
        for stream in frags.values() {
            let mut body = Vec::new();
            let mut first: Option<MessageHeader> = None;
            let mut prev_seq = None;
            for (&seq, (header, bytes, last)) in stream {
                if prev_seq.is_some_and(|p: u16| p + 1 != seq) {
                    body.clear();
                    first = None;
                }
                prev_seq = Some(seq);
                first.get_or_insert(*header);
                body.extend_from_slice(bytes);
                if *last {
                    let h = first.take().unwrap();
                    let m = Message::reassembled(&h, &body)
                        .unwrap_or_else(|e| panic!("{capture} seq {seq}: {e}"));
                    assert_eq!(m.submessages.len(), 1);
                    assert!(matches!(
                        m.submessages[0].payload,
                        Payload::WriteData(_) | Payload::Data(_) | Payload::Create(_)
                    ));
                    let mut expect = Vec::new();
                    h.encode(&mut expect).unwrap();
                    expect.extend_from_slice(&body);
                    assert_eq!(m.to_vec().unwrap(), expect);
                    body.clear();
                    rebuilt += 1;
                }
            }
        }
    }
    // 4 in continuous_example (3 CREATEs, one 20000-byte sample), 4 distinct
    // ones in large_sample (its retransmissions carry the same seqs)
    assert_eq!(rebuilt, 8);
}

/// Feeds `bytes` in chunks of 1, 2, 3, … 7 bytes, cycling.
fn chunks(bytes: &[u8]) -> impl Iterator<Item = &[u8]> {
    let mut at = 0;
    let mut n = 0;
    std::iter::from_fn(move || {
        if at >= bytes.len() {
            return None;
        }
        n = n % 7 + 1;
        let end = (at + n).min(bytes.len());
        let c = &bytes[at..end];
        at = end;
        Some(c)
    })
}

/// A frame from a stream: source and destination address (serial only) and the message.
type Frame = (u8, u8, Vec<u8>);

/// Replays a captured byte stream through a deframer in small chunks: every
/// frame round-trips as a message, and framing them again gives the stream
/// back. Returns the number of frames.
fn replay(
    file: &str,
    mut deframe: impl FnMut(&[u8]) -> Vec<Frame>,
    frame: impl Fn(&Frame, &mut Vec<u8>),
) -> usize {
    let wire = stream(file);
    let mut again = Vec::new();
    let mut n = 0;
    for c in chunks(&wire) {
        for (src, dst, msg) in deframe(c) {
            let m = roundtrip(&format!("{file} frame {n}"), &msg);
            frame(&(src, dst, m.to_vec().unwrap()), &mut again);
            n += 1;
        }
    }
    assert_eq!(again, wire, "{file}");
    n
}

#[test]
fn tcp_streams_roundtrip() {
    for file in [
        "tcp_shapes_ref_and_ping_c2a.hex",
        "tcp_shapes_ref_and_ping_a2c.hex",
    ] {
        let mut d = TcpDeframer::new();
        let n = replay(
            file,
            |c| {
                d.push(c);
                std::iter::from_fn(|| d.next_frame())
                    .map(|f| (0, 0, f.unwrap()))
                    .collect()
            },
            |(_, _, m), out| tcp::encode(m, out).unwrap(),
        );
        assert_eq!(d.buffered(), 0);
        assert_eq!(n, 22, "{file}");
    }
}

#[test]
fn serial_streams_roundtrip() {
    for file in [
        "serial_ping_and_shapes_c2a.hex",
        "serial_ping_and_shapes_a2c.hex",
    ] {
        let mut d = SerialDecoder::new();
        let n = replay(
            file,
            |c| {
                d.push(c);
                std::iter::from_fn(|| d.next_frame())
                    .map(|f| {
                        let f = f.unwrap_or_else(|e| panic!("{file}: {e}"));
                        (f.src, f.dst, f.payload)
                    })
                    .collect()
            },
            |(src, dst, m), out| serial::encode(*src, *dst, m, out).unwrap(),
        );
        assert_eq!(d.skipped(), 0);
        assert_eq!(n, 14, "{file}");
    }
}
