//! What CREATE tells the agent about each entity: binary representations
//! from the type's [`TypeInfo`] and the QoS, Fast DDS XML snippets, or
//! reference profile names (see [`XrceRepresentation`]).
//!
//! QoS the chosen representation cannot carry is refused with
//! [`OpenError::Unsupported`], never dropped.

use courier_wire::xrce::{
    qos_flags, BinaryRepresentation, DataReaderBinary, DataReaderQos, DataWriterBinary,
    EndpointQos, GroupBinary, ObjectId, ObjectVariant, ParticipantBinary, Representation,
    ServiceBinary, TopicBinary,
};

use super::options::{RefKind, XrceOptions, XrceRepresentation};
use crate::error::OpenError;
use crate::qos::{Durability, History, PublicationQos, Reliability, SubscriptionQos, TypeInfo};

const SCHEME: &str = "xrce+…://";

fn unsupported(what: impl Into<String>) -> OpenError {
    OpenError::Unsupported {
        what: what.into(),
        backend: SCHEME,
    }
}

fn binary(b: BinaryRepresentation) -> Result<Representation, OpenError> {
    b.to_representation()
        .map_err(|e| unsupported(format!("this entity in binary form ({e})")))
}

fn xml_escape(s: &str) -> String {
    let mut o = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '<' => o.push_str("&lt;"),
            '>' => o.push_str("&gt;"),
            '&' => o.push_str("&amp;"),
            '"' => o.push_str("&quot;"),
            '\'' => o.push_str("&apos;"),
            c => o.push(c),
        }
    }
    o
}

fn ms(d: std::time::Duration, what: &str) -> Result<u32, OpenError> {
    u32::try_from(d.as_millis()).map_err(|_| unsupported(format!("{what} beyond {} ms", u32::MAX)))
}

/// The session's participant.
pub(crate) fn participant(o: &XrceOptions, name: &str) -> Result<ObjectVariant, OpenError> {
    let representation = match o.representation {
        XrceRepresentation::Binary => {
            binary(BinaryRepresentation::Participant(ParticipantBinary {
                domain_reference: None,
                qos_profile_reference: None,
            }))?
        }
        XrceRepresentation::Xml => Representation::Xml(format!(
            "<dds><participant><rtps><name>{}</name></rtps></participant></dds>",
            xml_escape(name)
        )),
        XrceRepresentation::Reference => {
            Representation::Reference(o.profile(RefKind::Participant, ""))
        }
    };
    Ok(ObjectVariant::Participant {
        representation,
        domain_id: o.domain,
    })
}

fn topic_xml(topic: &str, ty: &TypeInfo) -> String {
    format!(
        "<kind>{}</kind><name>{}</name><dataType>{}</dataType>",
        if ty.keyed { "WITH_KEY" } else { "NO_KEY" },
        xml_escape(topic),
        xml_escape(ty.type_name)
    )
}

/// A topic of the participant. A keyed type's topic goes as XML whatever
/// the representation (the binary topic has no key kind).
pub(crate) fn topic(
    o: &XrceOptions,
    topic: &str,
    ty: &TypeInfo,
    participant_id: ObjectId,
) -> Result<ObjectVariant, OpenError> {
    let representation = match o.representation {
        XrceRepresentation::Binary if !ty.keyed => {
            binary(BinaryRepresentation::Topic(TopicBinary {
                topic_name: topic.to_string(),
                type_reference: None,
                type_name: Some(ty.type_name.to_string()),
            }))?
        }
        XrceRepresentation::Binary | XrceRepresentation::Xml => Representation::Xml(format!(
            "<dds><topic>{}</topic></dds>",
            topic_xml(topic, ty)
        )),
        XrceRepresentation::Reference => {
            Representation::Reference(o.profile(RefKind::Topic, topic))
        }
    };
    Ok(ObjectVariant::Topic {
        representation,
        participant_id,
    })
}

/// The session's publisher (`publisher`) or subscriber.
pub(crate) fn group(
    o: &XrceOptions,
    publisher: bool,
    participant_id: ObjectId,
) -> Result<ObjectVariant, OpenError> {
    // publishers and subscribers take no reference: empty XML, as
    // eProsima's examples send
    let representation = match o.representation {
        XrceRepresentation::Binary => {
            let g = GroupBinary::default();
            binary(if publisher {
                BinaryRepresentation::Publisher(g)
            } else {
                BinaryRepresentation::Subscriber(g)
            })?
        }
        _ => Representation::Xml(String::new()),
    };
    Ok(if publisher {
        ObjectVariant::Publisher {
            representation,
            participant_id,
        }
    } else {
        ObjectVariant::Subscriber {
            representation,
            participant_id,
        }
    })
}

fn base_flags(rel: Reliability, dur: Durability, history: History) -> (u16, Option<u16>) {
    let mut flags = 0;
    if rel == Reliability::Reliable {
        flags |= qos_flags::RELIABLE;
    }
    if dur == Durability::TransientLocal {
        flags |= qos_flags::TRANSIENT_LOCAL;
    }
    let depth = match history {
        History::KeepLast(n) => {
            flags |= qos_flags::KEEP_LAST;
            Some(u16::try_from(n).unwrap_or(u16::MAX).max(1))
        }
        History::KeepAll => None,
    };
    (flags, depth)
}

fn qos_xml(rel: Reliability, dur: Durability) -> String {
    format!(
        "<reliability><kind>{}</kind></reliability><durability><kind>{}</kind></durability>",
        match rel {
            Reliability::Reliable => "RELIABLE",
            Reliability::BestEffort => "BEST_EFFORT",
        },
        match dur {
            Durability::Volatile => "VOLATILE",
            Durability::TransientLocal => "TRANSIENT_LOCAL",
        }
    )
}

fn history_xml(h: History) -> String {
    match h {
        History::KeepAll => "<historyQos><kind>KEEP_ALL</kind></historyQos>".into(),
        History::KeepLast(n) => {
            format!(
                "<historyQos><kind>KEEP_LAST</kind><depth>{}</depth></historyQos>",
                n.max(1)
            )
        }
    }
}

fn duration_xml(tag: &str, inner: &str, d: std::time::Duration) -> String {
    format!(
        "<{tag}><{inner}><sec>{}</sec><nanosec>{}</nanosec></{inner}></{tag}>",
        d.as_secs(),
        d.subsec_nanos()
    )
}

/// Fast DDS's `<liveliness>` (XMLParserCommon.cpp's element names).
fn liveliness_xml(l: crate::qos::Liveliness) -> String {
    use crate::qos::LivelinessKind as K;
    let kind = match l.kind {
        K::Automatic => "AUTOMATIC",
        K::ManualByParticipant => "MANUAL_BY_PARTICIPANT",
        K::ManualByTopic => "MANUAL_BY_TOPIC",
    };
    let lease = duration_xml("x", "lease_duration", l.lease);
    // the lease's element alone, out of duration_xml's wrapper
    let lease = &lease["<x>".len()..lease.len() - "</x>".len()];
    format!("<liveliness><kind>{kind}</kind>{lease}</liveliness>")
}

/// In reference mode the profile holds the QoS: only reliability (which
/// picks the XRCE stream) may be chosen here.
fn reference_qos_default(
    pub_qos: Option<&PublicationQos>,
    sub_qos: Option<&SubscriptionQos>,
) -> Result<(), OpenError> {
    let pub_ok = pub_qos.is_none_or(|q| {
        PublicationQos {
            reliability: q.reliability,
            ..PublicationQos::default()
        } == *q
    });
    let sub_ok = sub_qos.is_none_or(|q| {
        SubscriptionQos {
            reliability: q.reliability,
            ..SubscriptionQos::default()
        } == *q
    });
    if pub_ok && sub_ok {
        Ok(())
    } else {
        Err(unsupported(
            "QoS beyond reliability with representation=reference (the agent's profile holds the QoS)",
        ))
    }
}

/// A data writer of `topic` (object `topic_id`) under the publisher.
pub(crate) fn writer(
    o: &XrceOptions,
    topic: &str,
    ty: &TypeInfo,
    topic_id: ObjectId,
    qos: &PublicationQos,
    publisher_id: ObjectId,
) -> Result<ObjectVariant, OpenError> {
    if !qos.partitions.is_empty() {
        return Err(unsupported("partitions"));
    }
    crate::qos::check_timing(qos.deadline, None).map_err(|why| OpenError::Qos {
        topic: topic.to_string(),
        why,
    })?;
    let representation = match o.representation {
        XrceRepresentation::Binary => {
            let (mut flags, history_depth) =
                base_flags(qos.reliability, qos.durability, qos.history);
            if qos.strength.is_some() {
                flags |= qos_flags::OWNERSHIP_EXCLUSIVE;
            }
            if qos.liveliness.is_some() {
                return Err(unsupported(
                    "liveliness in the binary representation, which has no field for it \
                     (use representation=xml)",
                ));
            }
            let strength = match qos.strength {
                Some(s) if s < 0 => return Err(unsupported("a negative strength")),
                s => s.map(|s| s as u64),
            };
            binary(BinaryRepresentation::DataWriter(DataWriterBinary {
                topic_id,
                qos: Some((
                    EndpointQos {
                        flags,
                        history_depth,
                        deadline_ms: qos.deadline.map(|d| ms(d, "a deadline")).transpose()?,
                        lifespan_ms: qos.persistence.map(|d| ms(d, "persistence")).transpose()?,
                        user_data: None,
                    },
                    strength,
                )),
            }))?
        }
        XrceRepresentation::Xml => {
            if qos.strength.is_some() {
                return Err(unsupported(
                    "strength with representation=xml (use the binary representation)",
                ));
            }
            let mut q = qos_xml(qos.reliability, qos.durability);
            if let Some(d) = qos.deadline {
                q.push_str(&duration_xml("deadline", "period", d));
            }
            if let Some(d) = qos.persistence {
                q.push_str(&duration_xml("lifespan", "duration", d));
            }
            if let Some(l) = qos.liveliness {
                q.push_str(&liveliness_xml(l));
            }
            Representation::Xml(format!(
                "<dds><data_writer><topic>{}{}</topic><qos>{q}</qos>\
                 <historyMemoryPolicy>PREALLOCATED_WITH_REALLOC</historyMemoryPolicy>\
                 </data_writer></dds>",
                topic_xml(topic, ty),
                history_xml(qos.history)
            ))
        }
        XrceRepresentation::Reference => {
            reference_qos_default(Some(qos), None)?;
            Representation::Reference(o.profile(RefKind::DataWriter, topic))
        }
    };
    Ok(ObjectVariant::DataWriter {
        representation,
        publisher_id,
    })
}

/// A data reader of `topic` under the subscriber.
pub(crate) fn reader(
    o: &XrceOptions,
    topic: &str,
    ty: &TypeInfo,
    topic_id: ObjectId,
    qos: &SubscriptionQos,
    subscriber_id: ObjectId,
) -> Result<ObjectVariant, OpenError> {
    if !qos.partitions.is_empty() {
        return Err(unsupported("partitions"));
    }
    if qos.deadline.is_some() {
        return Err(unsupported(
            "a subscription deadline (the agent reports no missed deadline to its clients)",
        ));
    }
    let representation = match o.representation {
        XrceRepresentation::Binary => {
            let (mut flags, history_depth) =
                base_flags(qos.reliability, qos.durability, qos.history);
            if qos.exclusive {
                flags |= qos_flags::OWNERSHIP_EXCLUSIVE;
            }
            let filter = qos
                .minimum_separation
                .map(|d| u64::try_from(d.as_millis()).unwrap_or(u64::MAX));
            binary(BinaryRepresentation::DataReader(DataReaderBinary {
                topic_id,
                qos: Some(DataReaderQos {
                    base: EndpointQos {
                        flags,
                        history_depth,
                        deadline_ms: None,
                        lifespan_ms: None,
                        user_data: None,
                    },
                    time_based_filter_ms: filter,
                    content_filter: None,
                }),
            }))?
        }
        XrceRepresentation::Xml => {
            if qos.minimum_separation.is_some() {
                return Err(unsupported(
                    "minimum separation with representation=xml (use the binary representation)",
                ));
            }
            let mut q = qos_xml(qos.reliability, qos.durability);
            if qos.exclusive {
                q.push_str("<ownership><kind>EXCLUSIVE</kind></ownership>");
            }
            Representation::Xml(format!(
                "<dds><data_reader><topic>{}{}</topic><qos>{q}</qos>\
                 <historyMemoryPolicy>PREALLOCATED_WITH_REALLOC</historyMemoryPolicy>\
                 </data_reader></dds>",
                topic_xml(topic, ty),
                history_xml(qos.history)
            ))
        }
        XrceRepresentation::Reference => {
            reference_qos_default(None, Some(qos))?;
            Representation::Reference(o.profile(RefKind::DataReader, topic))
        }
    };
    Ok(ObjectVariant::DataReader {
        representation,
        subscriber_id,
    })
}

/// The DDS request and reply topics of a service, as Courier's RTPS
/// backend and ROS 2 name them, so that either side can be XRCE.
pub(crate) fn service_topics(name: &str) -> (String, String) {
    (format!("rq/{name}Request"), format!("rr/{name}Reply"))
}

/// A requester (`replier` false) or replier of service `name`.
pub(crate) fn service(
    o: &XrceOptions,
    name: &str,
    req: &TypeInfo,
    resp: &TypeInfo,
    replier: bool,
    participant_id: ObjectId,
) -> Result<ObjectVariant, OpenError> {
    let (rq, rr) = service_topics(name);
    let representation = match o.representation {
        XrceRepresentation::Binary => {
            let s = ServiceBinary {
                service_name: name.to_string(),
                request_type: req.type_name.to_string(),
                reply_type: resp.type_name.to_string(),
                request_topic_name: Some(rq),
                reply_topic_name: Some(rr),
            };
            binary(if replier {
                BinaryRepresentation::Replier(s)
            } else {
                BinaryRepresentation::Requester(s)
            })?
        }
        XrceRepresentation::Xml => {
            let tag = if replier { "replier" } else { "requester" };
            Representation::Xml(format!(
                "<dds><{tag} profile_name=\"{p}\" service_name=\"{s}\" request_type=\"{q}\" \
                 reply_type=\"{r}\" request_topic_name=\"{rq}\" reply_topic_name=\"{rr}\">\
                 </{tag}></dds>",
                p = xml_escape(&format!("{name}_{tag}")),
                s = xml_escape(name),
                q = xml_escape(req.type_name),
                r = xml_escape(resp.type_name),
                rq = xml_escape(&rq),
                rr = xml_escape(&rr),
            ))
        }
        XrceRepresentation::Reference => Representation::Reference(o.profile(
            if replier {
                RefKind::Replier
            } else {
                RefKind::Requester
            },
            name,
        )),
    };
    Ok(if replier {
        ObjectVariant::Replier {
            representation,
            participant_id,
        }
    } else {
        ObjectVariant::Requester {
            representation,
            participant_id,
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::xrce_backend::options::XrceTransport;
    use courier_wire::xrce::ObjectKind;

    fn opts(r: XrceRepresentation) -> XrceOptions {
        let mut o = XrceOptions::new(XrceTransport::Udp("127.0.0.1:1".into()));
        o.representation = r;
        o
    }

    const TY: TypeInfo = TypeInfo::dynamic(None, "demo::Msg");

    #[test]
    fn a_binary_writer_carries_the_qos() {
        let o = opts(XrceRepresentation::Binary);
        let q = PublicationQos {
            history: History::KeepLast(5),
            durability: Durability::TransientLocal,
            strength: Some(7),
            ..Default::default()
        };
        let t = ObjectId::new(3, ObjectKind::Topic);
        let v = writer(
            &o,
            "chatter",
            &TY,
            t,
            &q,
            ObjectId::new(1, ObjectKind::Publisher),
        )
        .unwrap();
        let ObjectVariant::DataWriter {
            representation: Representation::Binary(blob),
            ..
        } = v
        else {
            panic!("{v:?}")
        };
        let BinaryRepresentation::DataWriter(w) =
            BinaryRepresentation::decode(ObjectKind::DataWriter, &blob).unwrap()
        else {
            panic!()
        };
        assert_eq!(w.topic_id, t);
        let (e, strength) = w.qos.unwrap();
        assert_eq!(
            e.flags,
            qos_flags::RELIABLE
                | qos_flags::KEEP_LAST
                | qos_flags::TRANSIENT_LOCAL
                | qos_flags::OWNERSHIP_EXCLUSIVE
        );
        assert_eq!((e.history_depth, strength), (Some(5), Some(7)));
    }

    /// A liveliness goes as Fast DDS's `<liveliness>`, which the agent
    /// reads back; the binary representation has no field for it.
    #[test]
    fn liveliness_goes_as_xml_only() {
        use crate::qos::{Liveliness, LivelinessKind};
        let q = PublicationQos {
            liveliness: Some(Liveliness::new(
                LivelinessKind::ManualByTopic,
                std::time::Duration::from_millis(1500),
            )),
            ..Default::default()
        };
        let (t, p) = (
            ObjectId::new(3, ObjectKind::Topic),
            ObjectId::new(1, ObjectKind::Publisher),
        );
        let e = writer(&opts(XrceRepresentation::Binary), "a", &TY, t, &q, p).unwrap_err();
        assert!(e.to_string().contains("use representation=xml"), "{e}");
        let e = writer(&opts(XrceRepresentation::Reference), "a", &TY, t, &q, p).unwrap_err();
        assert!(matches!(e, OpenError::Unsupported { .. }), "{e}");
        let ObjectVariant::DataWriter {
            representation: Representation::Xml(x),
            ..
        } = writer(&opts(XrceRepresentation::Xml), "a", &TY, t, &q, p).unwrap()
        else {
            panic!()
        };
        assert!(
            x.contains(
                "<liveliness><kind>MANUAL_BY_TOPIC</kind><lease_duration><sec>1</sec>\
                 <nanosec>500000000</nanosec></lease_duration></liveliness>"
            ),
            "{x}"
        );
        let Ok(courier_wire::xrce::bridge::Profile::Writer(w)) =
            courier_wire::xrce::bridge::from_xml(ObjectKind::DataWriter, &x)
        else {
            panic!("the agent cannot read {x}")
        };
        assert_eq!(
            w.qos.liveliness,
            (
                courier_wire::rtps::discovery::LivelinessKind::ManualByTopic,
                courier_wire::rtps::discovery::Duration::from_std(
                    std::time::Duration::from_millis(1500)
                )
            )
        );
    }

    #[test]
    fn a_keyed_topic_goes_as_xml_with_its_key_kind() {
        let o = opts(XrceRepresentation::Binary);
        let keyed = TypeInfo { keyed: true, ..TY };
        let p = ObjectId::new(1, ObjectKind::Participant);
        let ObjectVariant::Topic {
            representation: Representation::Xml(x),
            ..
        } = topic(&o, "a<b", &keyed, p).unwrap()
        else {
            panic!()
        };
        assert_eq!(
            x,
            "<dds><topic><kind>WITH_KEY</kind><name>a&lt;b</name><dataType>demo::Msg</dataType></topic></dds>"
        );
        assert!(matches!(
            topic(&o, "t", &TY, p).unwrap(),
            ObjectVariant::Topic {
                representation: Representation::Binary(_),
                ..
            }
        ));
    }

    #[test]
    fn what_a_representation_cannot_carry_is_refused() {
        let p = ObjectId::new(1, ObjectKind::Publisher);
        let t = ObjectId::new(1, ObjectKind::Topic);
        let mut q = PublicationQos {
            history: History::KeepLast(3),
            ..Default::default()
        };
        let e = writer(&opts(XrceRepresentation::Reference), "t", &TY, t, &q, p).unwrap_err();
        assert!(e.to_string().contains("profile holds the QoS"), "{e}");
        q = PublicationQos::default();
        q.reliability = Reliability::BestEffort;
        let v = writer(
            &opts(XrceRepresentation::Reference),
            "Square",
            &TY,
            t,
            &q,
            p,
        )
        .unwrap();
        assert!(matches!(
            v,
            ObjectVariant::DataWriter { representation: Representation::Reference(ref r), .. } if r == "Square_data_writer"
        ));
        q.strength = Some(1);
        assert!(writer(&opts(XrceRepresentation::Xml), "t", &TY, t, &q, p).is_err());
        let s = SubscriptionQos {
            deadline: Some(std::time::Duration::from_secs(1)),
            ..Default::default()
        };
        let sub = ObjectId::new(1, ObjectKind::Subscriber);
        assert!(reader(&opts(XrceRepresentation::Binary), "t", &TY, t, &s, sub).is_err());
    }
}
