//! Malformed XRCE input gives a typed error naming the field and its
//! offset; the worked examples of `protocols/xrce.md` §13 decode to the
//! fields the facts file gives.

use courier_wire::xrce::{
    serial::{self, SerialDecoder, SerialError, SerialFrame},
    tcp::{self, TcpDeframer, TcpError},
    ClientKey, Data, DecodeError, EncodeError, Message, MessageHeader, ObjectId, ObjectKind,
    ObjectVariant, Payload, Representation, RequestId, StreamId, Submessage, SubmessageId,
};

fn hex(s: &str) -> Vec<u8> {
    s.split_whitespace()
        .map(|b| u8::from_str_radix(b, 16).unwrap())
        .collect()
}

fn err(s: &str) -> DecodeError {
    Message::decode(&hex(s)).unwrap_err()
}

#[test]
fn truncated_headers() {
    assert_eq!(
        err("81 00"),
        DecodeError::Truncated {
            offset: 0,
            what: "message header",
            needed: 4,
            remaining: 2
        }
    );
    // session ids below 0x80 carry the 4-byte key
    assert_eq!(
        err("01 80 00 00 22 22"),
        DecodeError::Truncated {
            offset: 0,
            what: "message header",
            needed: 8,
            remaining: 6
        }
    );
}

#[test]
fn length_past_the_end() {
    // ACKNACK declaring 9 payload bytes with 5 present
    assert_eq!(
        err("81 00 00 00 0A 01 09 00 02 00 00 01 80"),
        DecodeError::Truncated {
            offset: 8,
            what: "submessage payload",
            needed: 9,
            remaining: 5
        }
    );
    // a string longer than its submessage
    let e = err("81 80 00 00 01 05 0C 00 00 0A 00 11 01 02 00 00 FF 00 00 00");
    assert!(
        matches!(
            e,
            DecodeError::Truncated {
                offset: 20,
                what: "XML representation",
                needed: 255,
                remaining: 0
            }
        ),
        "{e:?}"
    );
}

#[test]
fn bad_submessage_id() {
    assert_eq!(
        err("81 00 00 00 0A 01 05 00 02 00 00 01 80 00 00 00 10 01 00 00"),
        DecodeError::UnknownSubmessage {
            offset: 16,
            id: 0x10
        }
    );
}

#[test]
fn fields_shorter_than_the_declared_length() {
    assert_eq!(
        err("81 00 00 00 0B 01 06 00 02 00 02 00 80 00"),
        DecodeError::LengthMismatch {
            offset: 4,
            id: SubmessageId::Heartbeat,
            declared: 6,
            decoded: 5
        }
    );
}

#[test]
fn invalid_fields() {
    // CREATE_CLIENT whose optional-properties flag is 2
    assert_eq!(
        err("80 00 00 00 00 01 10 00 58 52 43 45 01 00 01 0F CC CC DD DD 81 02 FC 01"),
        DecodeError::Invalid {
            offset: 21,
            what: "properties flag",
            value: 2
        }
    );
    // CREATE of a publisher by reference (publishers take XML or binary only)
    assert_eq!(
        err("81 80 00 00 01 05 0F 00 00 0C 00 13 03 01 00 00 01 00 00 00 00 00 11 00"),
        DecodeError::Invalid {
            offset: 13,
            what: "representation format",
            value: 1
        }
    );
    // unknown object kind 0x09
    assert_eq!(
        err("81 80 00 00 01 05 05 00 00 0C 00 13 09 00 00 00"),
        DecodeError::Invalid {
            offset: 12,
            what: "object kind",
            value: 9
        }
    );
    // string with length 0, and one without its NUL
    assert_eq!(
        err("81 80 00 00 01 05 0E 00 00 0C 00 12 02 02 00 00 00 00 00 00 00 11 00 00"),
        DecodeError::Invalid {
            offset: 16,
            what: "XML representation",
            value: 0
        }
    );
    assert_eq!(
        err("81 80 00 00 01 05 0F 00 00 0C 00 12 02 02 00 00 01 00 00 00 41 00 11 00"),
        DecodeError::Invalid {
            offset: 20,
            what: "XML representation",
            value: 0x41
        }
    );
    assert_eq!(
        err("81 80 00 00 01 05 10 00 00 0C 00 12 02 02 00 00 02 00 00 00 FF 00 00 11"),
        DecodeError::NotUtf8 {
            offset: 20,
            what: "XML representation"
        }
    );
}

#[test]
fn every_truncation_of_a_golden_message_is_handled() {
    let m = hex(
        "81 80 00 00 01 05 10 00 00 0A 00 11 01 03 00 00 02 00 00 00 00 00 00 00 \
                 01 05 32 00 00 0B 00 12 02 03 00 00 24 00 00 00 0D 00 00 00 45 78 61 6D \
                 70 6C 65 54 6F 70 69 63 00 00 01 00 0C 00 00 00 45 78 61 6D 70 6C 65 54 \
                 79 70 65 00 00 11",
    );
    assert_eq!(Message::decode(&m).unwrap().submessages.len(), 2);
    for n in 0..m.len() {
        match Message::decode(&m[..n]) {
            // cutting whole submessages leaves a shorter valid message
            Ok(short) => assert!(short.submessages.len() < 2, "{n}"),
            Err(DecodeError::Truncated { offset, .. }) => assert!(offset <= n, "{n}"),
            Err(e) => panic!("{n}: {e}"),
        }
    }
}

#[test]
fn worked_examples() {
    // §13.1 CREATE_CLIENT
    let m = Message::decode(&hex(
        "80 00 00 00 00 01 10 00 58 52 43 45 01 00 01 0F CC CC DD DD 81 00 FC 01",
    ))
    .unwrap();
    assert_eq!(
        m.header,
        MessageHeader::create_client(0x81, ClientKey::from(0xCCCCDDDD))
    );
    let Payload::CreateClient(c) = &m.submessages[0].payload else {
        panic!("{m:?}")
    };
    assert_eq!(
        (c.session_id, c.mtu, u32::from(c.client_key)),
        (0x81, 508, 0xCCCCDDDD)
    );
    // §13.3 CREATE participant in binary, REPLACE
    let m = Message::decode(&hex(
        "81 80 00 00 01 05 10 00 00 0A 00 11 01 03 00 00 02 00 00 00 00 00 00 00",
    ))
    .unwrap();
    let s = &m.submessages[0];
    assert_eq!(s.flags, 0x05);
    let Payload::Create(c) = &s.payload else {
        panic!()
    };
    assert_eq!(c.request.request_id, RequestId(10));
    assert_eq!(
        c.request.object_id,
        ObjectId::new(1, ObjectKind::Participant)
    );
    assert_eq!(
        c.object,
        ObjectVariant::Participant {
            representation: Representation::Binary(vec![0, 0]),
            domain_id: 0
        }
    );
    // §13.4 WRITE_DATA with 3 bytes of trailing client padding
    let b = hex(
        "81 80 01 00 07 01 1D 00 00 0E 00 15 01 00 00 00 11 00 00 00 48 65 6C 6C \
                 6F 20 44 44 53 20 77 6F 72 6C 64 21 00 10 00 00",
    );
    let m = Message::decode(&b).unwrap();
    assert_eq!(m.trailing, [0x10, 0, 0]);
    let Payload::WriteData(Data { request, data }) = &m.submessages[0].payload else {
        panic!()
    };
    assert_eq!(request.object_id.kind(), Some(ObjectKind::DataWriter));
    assert_eq!(data.len(), 25);
    // §13.6 HEARTBEAT, §11 TIMESTAMP_REPLY
    let m = Message::decode(&hex("81 00 00 00 0B 01 05 00 02 00 02 00 80")).unwrap();
    assert!(matches!(m.submessages[0].payload, Payload::Heartbeat(h)
        if h.first_unacked == 2 && h.last_unacked == 2 && h.stream_id == StreamId::RELIABLE));
    let m = Message::decode(&hex(
        "81 00 00 00 0F 01 18 00 98 D8 02 6B 9B 30 16 32 98 D8 02 6B 25 2C 16 32 98 D8 02 6B BD A4 14 32",
    ))
    .unwrap();
    let Payload::TimestampReply(t) = m.submessages[0].payload else {
        panic!()
    };
    assert_eq!(
        (t.originate.seconds, t.originate.nanoseconds),
        (1795348632, 840213693)
    );
    assert_eq!(t.transmit.nanoseconds, 840315035);
}

#[test]
fn big_endian_payloads_follow_the_flag() {
    // ACKNACK with flags 0: first_unacked is big-endian, the header stays LE
    let m = Message::decode(&hex("81 00 00 00 0A 00 05 00 00 02 00 01 80")).unwrap();
    let Payload::AckNack(a) = m.submessages[0].payload else {
        panic!()
    };
    assert_eq!(a.first_unacked, 2);
    assert_eq!(
        m.to_vec().unwrap(),
        hex("81 00 00 00 0A 00 05 00 00 02 00 01 80")
    );
}

#[test]
fn encode_errors() {
    let no_key = Message::new(MessageHeader::new(0x01, StreamId::NONE, 0), vec![]);
    assert_eq!(no_key.to_vec(), Err(EncodeError::MissingClientKey(0x01)));
    let mut keyed = no_key.clone();
    keyed.header.session_id = 0x81;
    keyed.header.client_key = Some(ClientKey::from(1));
    assert_eq!(keyed.to_vec(), Err(EncodeError::UnexpectedClientKey(0x81)));

    let big = Submessage::new(Payload::Fragment(vec![0; 70000]));
    let m = Message::new(MessageHeader::new(0x81, StreamId::RELIABLE, 0), vec![big]);
    assert!(matches!(
        m.to_vec(),
        Err(EncodeError::TooLong {
            what: "FRAGMENT",
            len: 70000,
            ..
        })
    ));
    let mut out = vec![1, 2];
    assert!(m.encode(&mut out).is_err());
    assert_eq!(out, [1, 2], "a failed encode leaves the buffer as it was");
}

#[test]
fn write_data_over_65535_bytes_has_length_zero() {
    let d = Data {
        request: courier_wire::xrce::BaseObjectRequest::new(14, ObjectId(0x15)),
        data: (0..70000u32).map(|i| i as u8).collect(),
    };
    let m = Message::new(
        MessageHeader::new(0x81, StreamId::RELIABLE, 1),
        vec![Submessage::new(Payload::WriteData(d))],
    );
    let b = m.to_vec().unwrap();
    assert_eq!(b[4..8], [0x07, 0x01, 0x00, 0x00]);
    assert_eq!(Message::decode(&b).unwrap(), m);
}

#[test]
fn tcp_oversize_and_zero_length() {
    let mut d = TcpDeframer::with_max_len(8);
    let mut wire = vec![0, 0]; // skipped
    wire.extend_from_slice(&[20, 0]);
    wire.extend_from_slice(&[0xAA; 20]);
    tcp::encode(&[0x81, 0, 0, 0], &mut wire).unwrap();
    d.push(&wire);
    assert_eq!(
        d.next_frame(),
        Some(Err(TcpError::Oversize {
            offset: 2,
            len: 20,
            max: 8
        }))
    );
    assert_eq!(d.next_frame(), Some(Ok(vec![0x81, 0, 0, 0])));
    assert_eq!(d.next_frame(), None);
    assert!(tcp::encode(&[], &mut Vec::new()).is_err());
    assert!(tcp::encode(&vec![0; 65536], &mut Vec::new()).is_err());
}

fn frame(payload: &[u8]) -> Vec<u8> {
    let mut w = Vec::new();
    serial::encode(1, 0, payload, &mut w).unwrap();
    w
}

#[test]
fn serial_escaping_matches_the_capture() {
    // §12: CRC 0x7E9B goes out as 9B 7D 5E
    let payload = hex(
        "81 00 00 00 06 01 1C 00 00 0A FF FD 00 01 01 0D 58 52 43 45 01 00 01 0F \
                       00 01 0D 00 01 00 00 00 00 00 00 00",
    );
    assert_eq!(serial::crc16(&payload), 0x7E9B);
    let mut w = Vec::new();
    serial::encode(0, 1, &payload, &mut w).unwrap();
    assert_eq!(w[w.len() - 3..], [0x9B, 0x7D, 0x5E]);
    assert_eq!(serial::crc16(b"123456789"), 0xBB3D);
}

#[test]
fn serial_bad_crc_then_resync() {
    let mut w = frame(&[1, 2, 3]);
    let n = w.len();
    w[n - 1] ^= 0xFF;
    w.extend(frame(&[4]));
    let mut d = SerialDecoder::new();
    d.push(&w);
    assert!(matches!(
        d.next_frame(),
        Some(Err(SerialError::BadCrc { offset: 0, .. }))
    ));
    assert_eq!(
        d.next_frame(),
        Some(Ok(SerialFrame {
            src: 1,
            dst: 0,
            payload: vec![4]
        }))
    );
}

#[test]
fn serial_bad_escape_oversize_and_interruption() {
    let mut d = SerialDecoder::with_max_payload(16);
    // 7D 00 is no escape
    d.push(&[0x7E, 0x01, 0x7D, 0x00]);
    assert_eq!(
        d.next_frame(),
        Some(Err(SerialError::BadEscape {
            offset: 3,
            byte: 0x00
        }))
    );
    // length 0x0100 > 16
    d.push(&[0x7E, 0x01, 0x00, 0x00, 0x01]);
    assert_eq!(
        d.next_frame(),
        Some(Err(SerialError::Oversize {
            offset: 4,
            len: 256,
            max: 16
        }))
    );
    // the rest of that frame is line noise; a frame cut short by a new flag
    d.push(&[0xAA, 0xBB]);
    d.push(&[0x7E, 0x01, 0x00, 0x05]);
    d.push(&frame(&[9]));
    assert_eq!(
        d.next_frame(),
        Some(Err(SerialError::Interrupted {
            offset: 11,
            restart: 15
        }))
    );
    assert_eq!(d.next_frame().unwrap().unwrap().payload, [9]);
    assert_eq!(d.skipped(), 2);
}
