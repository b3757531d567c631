//! Binary object representations (`IN_BINARY`, `protocols/xrce.md` §6): the
//! nested CDR blob a CREATE carries instead of XML or a reference, laid out
//! as eProsima's `create_entities_bin.c` writes it (little-endian, aligned
//! from the start of the blob, optionals as a boolean then the value).
//!
//! ```
//! use courier_wire::xrce::{BinaryRepresentation, TopicBinary};
//! // the topic of `udp_binary_entities` #3
//! let topic = BinaryRepresentation::Topic(TopicBinary {
//!     topic_name: "ExampleTopic".into(),
//!     type_reference: None,
//!     type_name: Some("ExampleType".into()),
//! });
//! let blob = topic.to_bytes().unwrap();
//! assert_eq!(blob.len(), 36);
//! assert_eq!(BinaryRepresentation::decode(topic.kind(), &blob).unwrap(), topic);
//! ```

use super::cursor::{Reader, Writer};
use super::object::Representation;
use super::types::{ObjectId, ObjectKind};
use super::{DecodeError, EncodeError};

/// `qos_flags` bits of [`EndpointQos`].
pub mod qos_flags {
    /// Reliable (else best effort).
    pub const RELIABLE: u16 = 0x01;
    /// Keep last (else keep all).
    pub const KEEP_LAST: u16 = 0x02;
    /// Exclusive ownership.
    pub const OWNERSHIP_EXCLUSIVE: u16 = 0x04;
    /// Transient-local durability (none of the durability bits: volatile).
    pub const TRANSIENT_LOCAL: u16 = 0x08;
    /// Transient durability.
    pub const TRANSIENT: u16 = 0x10;
    /// Persistent durability.
    pub const PERSISTENT: u16 = 0x20;
}

/// `OBJK_DomainParticipant_Binary`.
#[derive(Debug, Clone, PartialEq, Eq, Hash, Default)]
pub struct ParticipantBinary {
    /// `domain_reference`.
    pub domain_reference: Option<String>,
    /// `qos_profile_reference` (the API's participant name goes here).
    pub qos_profile_reference: Option<String>,
}

/// `OBJK_Topic_Binary`.
#[derive(Debug, Clone, PartialEq, Eq, Hash, Default)]
pub struct TopicBinary {
    /// `topic_name`.
    pub topic_name: String,
    /// `type_reference`.
    pub type_reference: Option<String>,
    /// `type_name` (the API always sends it).
    pub type_name: Option<String>,
}

/// The QoS of a publisher or subscriber.
#[derive(Debug, Clone, PartialEq, Eq, Hash, Default)]
pub struct GroupQos {
    /// `partitions`.
    pub partitions: Option<Vec<String>>,
    /// `group_data`.
    pub group_data: Option<Vec<u8>>,
}

/// `OBJK_Publisher_Binary` / `OBJK_Subscriber_Binary`.
#[derive(Debug, Clone, PartialEq, Eq, Hash, Default)]
pub struct GroupBinary {
    /// Publisher or subscriber name.
    pub name: Option<String>,
    /// QoS.
    pub qos: Option<GroupQos>,
}

/// `OBJK_Endpoint_QosBinary`: the QoS writers and readers share.
#[derive(Debug, Clone, PartialEq, Eq, Hash, Default)]
pub struct EndpointQos {
    /// [`qos_flags`] bits.
    pub flags: u16,
    /// `history_depth` (the API sends it only when not 0).
    pub history_depth: Option<u16>,
    /// `deadline_msec`.
    pub deadline_ms: Option<u32>,
    /// `lifespan_msec`.
    pub lifespan_ms: Option<u32>,
    /// `user_data`.
    pub user_data: Option<Vec<u8>>,
}

/// `OBJK_DataWriter_Binary`.
#[derive(Debug, Clone, PartialEq, Eq, Hash, Default)]
pub struct DataWriterBinary {
    /// The topic.
    pub topic_id: ObjectId,
    /// QoS: the endpoint's, then `ownership_strength`.
    pub qos: Option<(EndpointQos, Option<u64>)>,
}

/// `OBJK_DataReader_Binary`.
#[derive(Debug, Clone, PartialEq, Eq, Hash, Default)]
pub struct DataReaderBinary {
    /// The topic.
    pub topic_id: ObjectId,
    /// QoS.
    pub qos: Option<DataReaderQos>,
}

/// The QoS of a data reader.
#[derive(Debug, Clone, PartialEq, Eq, Hash, Default)]
pub struct DataReaderQos {
    /// The endpoint's QoS.
    pub base: EndpointQos,
    /// `timebasedfilter_msec`.
    pub time_based_filter_ms: Option<u64>,
    /// `contentbased_filter`.
    pub content_filter: Option<String>,
}

/// `OBJK_Requester_Binary` / `OBJK_Replier_Binary`.
#[derive(Debug, Clone, PartialEq, Eq, Hash, Default)]
pub struct ServiceBinary {
    /// `service_name`.
    pub service_name: String,
    /// `request_type`.
    pub request_type: String,
    /// `reply_type`.
    pub reply_type: String,
    /// `request_topic_name`.
    pub request_topic_name: Option<String>,
    /// `reply_topic_name`.
    pub reply_topic_name: Option<String>,
}

/// A binary representation, by object kind.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub enum BinaryRepresentation {
    /// A participant.
    Participant(ParticipantBinary),
    /// A topic.
    Topic(TopicBinary),
    /// A publisher.
    Publisher(GroupBinary),
    /// A subscriber.
    Subscriber(GroupBinary),
    /// A data writer.
    DataWriter(DataWriterBinary),
    /// A data reader.
    DataReader(DataReaderBinary),
    /// A requester.
    Requester(ServiceBinary),
    /// A replier.
    Replier(ServiceBinary),
}

fn opt_string(
    w: &mut Writer<'_>,
    what: &'static str,
    s: Option<&String>,
) -> Result<(), EncodeError> {
    w.optional(s, |w, s| w.string(what, s))
}

fn read_opt_string(r: &mut Reader<'_>, what: &'static str) -> Result<Option<String>, DecodeError> {
    r.optional(what, |r| r.string(what))
}

fn write_endpoint(w: &mut Writer<'_>, q: &EndpointQos) -> Result<(), EncodeError> {
    w.u16(q.flags);
    w.optional(q.history_depth.as_ref(), |w, d| {
        w.u16(*d);
        Ok(())
    })?;
    w.optional(q.deadline_ms.as_ref(), |w, d| {
        w.u32(*d);
        Ok(())
    })?;
    w.optional(q.lifespan_ms.as_ref(), |w, d| {
        w.u32(*d);
        Ok(())
    })?;
    w.optional(q.user_data.as_ref(), |w, d| w.octets("user data", d))
}

fn read_endpoint(r: &mut Reader<'_>) -> Result<EndpointQos, DecodeError> {
    Ok(EndpointQos {
        flags: r.u16("qos flags")?,
        history_depth: r.optional("history depth flag", |r| r.u16("history depth"))?,
        deadline_ms: r.optional("deadline flag", |r| r.u32("deadline"))?,
        lifespan_ms: r.optional("lifespan flag", |r| r.u32("lifespan"))?,
        user_data: r.optional("user data flag", |r| r.octets("user data"))?,
    })
}

fn write_group(w: &mut Writer<'_>, g: &GroupBinary) -> Result<(), EncodeError> {
    opt_string(w, "group name", g.name.as_ref())?;
    w.optional(g.qos.as_ref(), |w, q| {
        w.optional(q.partitions.as_ref(), |w, p| {
            w.sequence("partition count", p, |w, s| w.string("partition", s))
        })?;
        w.optional(q.group_data.as_ref(), |w, d| w.octets("group data", d))
    })
}

fn read_group(r: &mut Reader<'_>) -> Result<GroupBinary, DecodeError> {
    Ok(GroupBinary {
        name: read_opt_string(r, "group name")?,
        qos: r.optional("group qos flag", |r| {
            Ok(GroupQos {
                partitions: r.optional("partitions flag", |r| {
                    r.sequence("partition count", |r| r.string("partition"))
                })?,
                group_data: r.optional("group data flag", |r| r.octets("group data"))?,
            })
        })?,
    })
}

fn write_service(w: &mut Writer<'_>, s: &ServiceBinary) -> Result<(), EncodeError> {
    w.string("service name", &s.service_name)?;
    w.string("request type", &s.request_type)?;
    w.string("reply type", &s.reply_type)?;
    opt_string(w, "request topic name", s.request_topic_name.as_ref())?;
    opt_string(w, "reply topic name", s.reply_topic_name.as_ref())
}

fn read_service(r: &mut Reader<'_>) -> Result<ServiceBinary, DecodeError> {
    Ok(ServiceBinary {
        service_name: r.string("service name")?,
        request_type: r.string("request type")?,
        reply_type: r.string("reply type")?,
        request_topic_name: read_opt_string(r, "request topic name")?,
        reply_topic_name: read_opt_string(r, "reply topic name")?,
    })
}

impl BinaryRepresentation {
    /// The object kind this representation creates.
    pub fn kind(&self) -> ObjectKind {
        use BinaryRepresentation as B;
        match self {
            B::Participant(_) => ObjectKind::Participant,
            B::Topic(_) => ObjectKind::Topic,
            B::Publisher(_) => ObjectKind::Publisher,
            B::Subscriber(_) => ObjectKind::Subscriber,
            B::DataWriter(_) => ObjectKind::DataWriter,
            B::DataReader(_) => ObjectKind::DataReader,
            B::Requester(_) => ObjectKind::Requester,
            B::Replier(_) => ObjectKind::Replier,
        }
    }

    /// The blob.
    pub fn to_bytes(&self) -> Result<Vec<u8>, EncodeError> {
        use BinaryRepresentation as B;
        let mut out = Vec::new();
        let mut w = Writer::new(&mut out, 0, true, &[]);
        match self {
            B::Participant(p) => {
                opt_string(&mut w, "domain reference", p.domain_reference.as_ref())?;
                opt_string(
                    &mut w,
                    "qos profile reference",
                    p.qos_profile_reference.as_ref(),
                )?;
            }
            B::Topic(t) => {
                w.string("topic name", &t.topic_name)?;
                opt_string(&mut w, "type reference", t.type_reference.as_ref())?;
                opt_string(&mut w, "type name", t.type_name.as_ref())?;
            }
            B::Publisher(g) | B::Subscriber(g) => write_group(&mut w, g)?,
            B::DataWriter(d) => {
                w.bytes(&d.topic_id.to_bytes());
                w.optional(d.qos.as_ref(), |w, (q, strength)| {
                    write_endpoint(w, q)?;
                    w.optional(strength.as_ref(), |w, s| {
                        w.u64(*s);
                        Ok(())
                    })
                })?;
            }
            B::DataReader(d) => {
                w.bytes(&d.topic_id.to_bytes());
                w.optional(d.qos.as_ref(), |w, q| {
                    write_endpoint(w, &q.base)?;
                    w.optional(q.time_based_filter_ms.as_ref(), |w, t| {
                        w.u64(*t);
                        Ok(())
                    })?;
                    opt_string(w, "content filter", q.content_filter.as_ref())
                })?;
            }
            B::Requester(s) | B::Replier(s) => write_service(&mut w, s)?,
        }
        Ok(out)
    }

    /// The [`Representation::Binary`] a CREATE carries.
    pub fn to_representation(&self) -> Result<Representation, EncodeError> {
        self.to_bytes().map(Representation::Binary)
    }

    /// Decodes the blob of a `kind` object; every byte must be used.
    pub fn decode(kind: ObjectKind, blob: &[u8]) -> Result<Self, DecodeError> {
        use BinaryRepresentation as B;
        let mut r = Reader::new(blob, 0, blob.len(), true);
        let rep = match kind {
            ObjectKind::Participant => B::Participant(ParticipantBinary {
                domain_reference: read_opt_string(&mut r, "domain reference")?,
                qos_profile_reference: read_opt_string(&mut r, "qos profile reference")?,
            }),
            ObjectKind::Topic => B::Topic(TopicBinary {
                topic_name: r.string("topic name")?,
                type_reference: read_opt_string(&mut r, "type reference")?,
                type_name: read_opt_string(&mut r, "type name")?,
            }),
            ObjectKind::Publisher => B::Publisher(read_group(&mut r)?),
            ObjectKind::Subscriber => B::Subscriber(read_group(&mut r)?),
            ObjectKind::DataWriter => B::DataWriter(DataWriterBinary {
                topic_id: ObjectId::read(&mut r, "topic id")?,
                qos: r.optional("writer qos flag", |r| {
                    Ok((
                        read_endpoint(r)?,
                        r.optional("ownership strength flag", |r| r.u64("ownership strength"))?,
                    ))
                })?,
            }),
            ObjectKind::DataReader => B::DataReader(DataReaderBinary {
                topic_id: ObjectId::read(&mut r, "topic id")?,
                qos: r.optional("reader qos flag", |r| {
                    Ok(DataReaderQos {
                        base: read_endpoint(r)?,
                        time_based_filter_ms: r
                            .optional("time-based filter flag", |r| r.u64("time-based filter"))?,
                        content_filter: read_opt_string(r, "content filter")?,
                    })
                })?,
            }),
            ObjectKind::Requester => B::Requester(read_service(&mut r)?),
            ObjectKind::Replier => B::Replier(read_service(&mut r)?),
            k => return Err(r.invalid(0, "binary representation kind", k as u64)),
        };
        if r.remaining() != 0 {
            return Err(r.invalid(
                r.pos(),
                "binary representation trailing bytes",
                r.remaining() as u64,
            ));
        }
        Ok(rep)
    }
}
