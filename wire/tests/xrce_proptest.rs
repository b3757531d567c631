//! Random round trips of the XRCE codec: every submessage type in both
//! byte orders, both header forms, and the TCP and serial framings under
//! any split of the byte stream.

use courier_wire::xrce::{
    flags, serial, tcp, AckNack, ActivityInfo, AgentRepresentation, BaseObjectRequest, ClientKey,
    ClientRepresentation, Create, Data, DeliveryControl, GetInfo, Heartbeat, Info, Message,
    MessageHeader, ObjectId, ObjectInfo, ObjectVariant, Payload, Property, ReadData,
    Representation, RequestId, ResultStatus, Status, StatusAgent, StatusCode, StreamId, Submessage,
    Time, TimestampReply, TransportLocator,
};
use proptest::prelude::*;

fn text() -> impl Strategy<Value = String> {
    "\\PC{0,12}"
}

fn bytes(max: usize) -> impl Strategy<Value = Vec<u8>> {
    prop::collection::vec(any::<u8>(), 0..max)
}

fn request() -> impl Strategy<Value = BaseObjectRequest> {
    (any::<u16>(), any::<u16>()).prop_map(|(r, o)| BaseObjectRequest {
        request_id: RequestId(r),
        object_id: ObjectId(o),
    })
}

fn result() -> impl Strategy<Value = ResultStatus> {
    (any::<u8>(), any::<u8>()).prop_map(|(s, i)| ResultStatus {
        status: StatusCode(s),
        implementation_status: i,
    })
}

fn time() -> impl Strategy<Value = Time> {
    (any::<i32>(), any::<u32>()).prop_map(|(seconds, nanoseconds)| Time {
        seconds,
        nanoseconds,
    })
}

fn properties() -> impl Strategy<Value = Option<Vec<Property>>> {
    prop::option::of(prop::collection::vec(
        (text(), text()).prop_map(|(name, value)| Property { name, value }),
        0..3,
    ))
}

fn client() -> impl Strategy<Value = ClientRepresentation> {
    (
        any::<[u8; 4]>(),
        any::<[u8; 4]>(),
        any::<u8>(),
        properties(),
        any::<u16>(),
    )
        .prop_map(
            |(cookie, key, session_id, properties, mtu)| ClientRepresentation {
                cookie,
                properties,
                ..ClientRepresentation::new(ClientKey(key), session_id, mtu)
            },
        )
}

fn agent() -> impl Strategy<Value = AgentRepresentation> {
    (any::<[u8; 4]>(), any::<[u8; 2]>(), properties()).prop_map(|(cookie, vendor, properties)| {
        AgentRepresentation {
            cookie,
            vendor,
            properties,
            ..AgentRepresentation::default()
        }
    })
}

fn rep3() -> impl Strategy<Value = Representation> {
    prop_oneof![
        text().prop_map(Representation::Reference),
        text().prop_map(Representation::Xml),
        bytes(24).prop_map(Representation::Binary),
    ]
}

fn bin_xml() -> impl Strategy<Value = Representation> {
    prop_oneof![
        text().prop_map(Representation::Xml),
        bytes(24).prop_map(Representation::Binary),
    ]
}

fn ref_xml() -> impl Strategy<Value = Representation> {
    prop_oneof![
        text().prop_map(Representation::Reference),
        text().prop_map(Representation::Xml),
    ]
}

fn object() -> impl Strategy<Value = ObjectVariant> {
    use ObjectVariant as V;
    let id = || any::<u16>().prop_map(ObjectId);
    prop_oneof![
        (rep3(), any::<i16>()).prop_map(|(representation, domain_id)| V::Participant {
            representation,
            domain_id
        }),
        (rep3(), id()).prop_map(|(representation, participant_id)| V::Topic {
            representation,
            participant_id
        }),
        (bin_xml(), id()).prop_map(|(representation, participant_id)| V::Publisher {
            representation,
            participant_id
        }),
        (bin_xml(), id()).prop_map(|(representation, participant_id)| V::Subscriber {
            representation,
            participant_id
        }),
        (rep3(), id()).prop_map(|(representation, publisher_id)| V::DataWriter {
            representation,
            publisher_id
        }),
        (rep3(), id()).prop_map(|(representation, subscriber_id)| V::DataReader {
            representation,
            subscriber_id
        }),
        (rep3(), id()).prop_map(|(representation, participant_id)| V::Requester {
            representation,
            participant_id
        }),
        (rep3(), id()).prop_map(|(representation, participant_id)| V::Replier {
            representation,
            participant_id
        }),
        ref_xml().prop_map(V::Type),
        ref_xml().prop_map(V::QosProfile),
        ref_xml().prop_map(V::Application),
        agent().prop_map(V::Agent),
        client().prop_map(V::Client),
    ]
}

fn locator() -> impl Strategy<Value = TransportLocator> {
    prop_oneof![
        (any::<[u8; 2]>(), any::<u8>())
            .prop_map(|(address, port)| TransportLocator::Small { address, port }),
        (any::<[u8; 4]>(), any::<u16>())
            .prop_map(|(address, port)| TransportLocator::Medium { address, port }),
        (any::<[u8; 16]>(), any::<u32>())
            .prop_map(|(address, port)| TransportLocator::Large { address, port }),
        text().prop_map(TransportLocator::String),
    ]
}

fn activity() -> impl Strategy<Value = ActivityInfo> {
    prop_oneof![
        (any::<i16>(), prop::collection::vec(locator(), 0..3)).prop_map(
            |(availability, locators)| ActivityInfo::Agent {
                availability,
                locators
            }
        ),
        (any::<i16>(), any::<u64>()).prop_map(|(stream_seq_num, sample_seq_num)| {
            ActivityInfo::DataWriter {
                stream_seq_num,
                sample_seq_num,
            }
        }),
        any::<i16>().prop_map(|highest_acked_num| ActivityInfo::DataReader { highest_acked_num }),
        any::<u8>()
            .prop_filter("kinds with a body", |k| ![5, 6, 0xD].contains(k))
            .prop_map(ActivityInfo::Other),
    ]
}

fn data() -> impl Strategy<Value = Data> {
    (request(), bytes(40)).prop_map(|(request, data)| Data { request, data })
}

fn payload() -> impl Strategy<Value = Payload> {
    use Payload as P;
    prop_oneof![
        client().prop_map(P::CreateClient),
        (request(), object()).prop_map(|(request, object)| P::Create(Create { request, object })),
        (request(), any::<u32>())
            .prop_map(|(request, info_mask)| P::GetInfo(GetInfo { request, info_mask })),
        request().prop_map(P::Delete),
        (result(), agent())
            .prop_map(|(result, agent)| P::StatusAgent(StatusAgent { result, agent })),
        (request(), result()).prop_map(|(request, result)| P::Status(Status { request, result })),
        (
            request(),
            result(),
            prop::option::of(object()),
            prop::option::of(activity())
        )
            .prop_map(|(request, result, config, activity)| P::Info(Info {
                request,
                result,
                info: ObjectInfo { config, activity },
            })),
        data().prop_map(P::WriteData),
        (
            request(),
            any::<u8>(),
            any::<u8>(),
            prop::option::of(text()),
            prop::option::of(any::<[u16; 4]>())
        )
            .prop_map(|(request, s, data_format, content_filter, dc)| {
                P::ReadData(ReadData {
                    request,
                    preferred_stream_id: StreamId(s),
                    data_format,
                    content_filter,
                    delivery_control: dc.map(|[a, b, c, d]| DeliveryControl {
                        max_samples: a,
                        max_elapsed_time: b,
                        max_bytes_per_second: c,
                        min_pace_period: d,
                    }),
                })
            }),
        data().prop_map(P::Data),
        (any::<u16>(), any::<[u8; 2]>(), any::<u8>()).prop_map(
            |(first_unacked, nack_bitmap, s)| {
                P::AckNack(AckNack {
                    first_unacked,
                    nack_bitmap,
                    stream_id: StreamId(s),
                })
            }
        ),
        (any::<u16>(), any::<u16>(), any::<u8>()).prop_map(|(first_unacked, last_unacked, s)| {
            P::Heartbeat(Heartbeat {
                first_unacked,
                last_unacked,
                stream_id: StreamId(s),
            })
        }),
        Just(P::Reset),
        bytes(40).prop_map(P::Fragment),
        time().prop_map(P::Timestamp),
        (time(), time(), time()).prop_map(|(transmit, receive, originate)| {
            P::TimestampReply(TimestampReply {
                transmit,
                receive,
                originate,
            })
        }),
    ]
}

/// A submessage in either byte order, with the submessage's own flag bits.
fn submessage() -> impl Strategy<Value = Submessage> {
    (payload(), any::<bool>(), 0u8..8).prop_map(|(p, le, other)| {
        let f = if le { flags::LITTLE_ENDIAN } else { 0 } | (other << 1);
        Submessage::with_flags(f, p)
    })
}

fn header() -> impl Strategy<Value = MessageHeader> {
    (any::<u8>(), any::<u8>(), any::<u16>(), any::<[u8; 4]>()).prop_map(|(session, s, seq, key)| {
        if session < 0x80 {
            MessageHeader::with_key(session, ClientKey(key), StreamId(s), seq)
        } else {
            MessageHeader::new(session, StreamId(s), seq)
        }
    })
}

fn message() -> impl Strategy<Value = Message> {
    (
        header(),
        prop::collection::vec(submessage(), 0..4),
        bytes(4),
    )
        .prop_map(|(header, submessages, trailing)| {
            let mut m = Message::new(header, submessages);
            m.trailing = trailing;
            m
        })
        .prop_filter("trailing bytes that could start a submessage", |m| {
            // after the last submessage, bytes left must not hold a header once aligned
            let len = m.to_vec().unwrap().len() - m.trailing.len();
            len.div_ceil(4) * 4 + 4 > len + m.trailing.len()
        })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(512))]

    #[test]
    fn message_roundtrips(m in message()) {
        let bytes = m.to_vec().unwrap();
        let back = Message::decode(&bytes).unwrap();
        prop_assert_eq!(&back, &m);
        prop_assert_eq!(back.to_vec().unwrap(), bytes);
    }

    /// Nonzero padding contents survive decoding and re-encoding.
    #[test]
    fn padding_is_kept(m in message(), pads in prop::collection::vec(bytes(6), 4)) {
        let mut m = m;
        for (s, p) in m.submessages.iter_mut().zip(pads) {
            s.padding = p;
        }
        let bytes = m.to_vec().unwrap();
        let back = Message::decode(&bytes).unwrap();
        prop_assert_eq!(back.to_vec().unwrap(), bytes);
    }

    /// Arbitrary bytes never panic the decoder, and what decodes re-encodes
    /// to the same bytes.
    #[test]
    fn arbitrary_bytes(b in bytes(96)) {
        if let Ok(m) = Message::decode(&b) {
            prop_assert_eq!(m.to_vec().unwrap(), b);
        }
    }

    /// Valid messages with one byte changed: never a panic, and exact
    /// re-encoding whenever they still decode.
    #[test]
    fn mutated_messages(m in message(), at in any::<prop::sample::Index>(), x in 1u8..) {
        let mut b = m.to_vec().unwrap();
        let i = at.index(b.len());
        b[i] ^= x;
        if let Ok(m) = Message::decode(&b) {
            prop_assert_eq!(m.to_vec().unwrap(), b);
        }
    }

    #[test]
    fn tcp_any_split(msgs in prop::collection::vec(prop::collection::vec(any::<u8>(), 1..300), 0..6),
                     cuts in prop::collection::vec(1usize..64, 1..16)) {
        let mut wire = Vec::new();
        for m in &msgs {
            tcp::encode(m, &mut wire).unwrap();
        }
        let mut d = tcp::TcpDeframer::new();
        let mut got = Vec::new();
        let mut at = 0;
        for c in cuts.iter().cycle() {
            if at >= wire.len() { break; }
            let end = (at + c).min(wire.len());
            d.push(&wire[at..end]);
            at = end;
            while let Some(f) = d.next_frame() { got.push(f.unwrap()); }
        }
        prop_assert_eq!(got, msgs);
    }

    #[test]
    fn serial_any_split(frames in prop::collection::vec((any::<u8>(), any::<u8>(), bytes(200)), 0..6),
                        noise in prop::collection::vec(any::<u8>().prop_filter("no flag", |b| *b != 0x7E), 0..8),
                        cuts in prop::collection::vec(1usize..64, 1..16)) {
        let mut wire = noise.clone();
        for (s, d, p) in &frames {
            serial::encode(*s, *d, p, &mut wire).unwrap();
        }
        let mut dec = serial::SerialDecoder::new();
        let mut got = Vec::new();
        let mut at = 0;
        for c in cuts.iter().cycle() {
            if at >= wire.len() { break; }
            let end = (at + c).min(wire.len());
            dec.push(&wire[at..end]);
            at = end;
            while let Some(f) = dec.next_frame() {
                let f = f.unwrap();
                got.push((f.src, f.dst, f.payload));
            }
        }
        prop_assert_eq!(got, frames);
        prop_assert_eq!(dec.skipped(), noise.len() as u64);
    }

    /// Garbage never panics the serial decoder, which finds a good frame after it.
    #[test]
    fn serial_resyncs(garbage in bytes(64), payload in bytes(40)) {
        let mut wire = garbage;
        serial::encode(1, 0, &payload, &mut wire).unwrap();
        let mut dec = serial::SerialDecoder::new();
        dec.push(&wire);
        let mut last = None;
        while let Some(f) = dec.next_frame() { last = Some(f); }
        prop_assert_eq!(last, Some(Ok(serial::SerialFrame { src: 1, dst: 0, payload })));
    }
}
