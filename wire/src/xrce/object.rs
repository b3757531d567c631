//! Object representations (`protocols/xrce.md` §4, §6, §11): the CLIENT and
//! AGENT representations exchanged at session set-up, the `ObjectVariant`
//! a CREATE carries, and the `ObjectInfo` of an INFO reply.
//!
//! Binary representations (`IN_BINARY`) are kept as the opaque bytes of
//! their nested CDR blob ([`Representation::Binary`]): their layout depends
//! on the object kind and is aligned from the start of the blob, not of the
//! message.

use super::cursor::{Reader, Writer};
use super::types::{
    read_properties, write_properties, ClientKey, ObjectId, ObjectKind, Property, TransportLocator,
    COOKIE, VENDOR_EPROSIMA, VERSION,
};
use super::{DecodeError, EncodeError};

/// `CLIENT_Representation`: the payload of CREATE_CLIENT (16 bytes without properties).
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub struct ClientRepresentation {
    /// `xrce_cookie`, [`COOKIE`] from any real client.
    pub cookie: [u8; 4],
    /// `xrce_version`, [`VERSION`].
    pub version: [u8; 2],
    /// `xrce_vendor_id`.
    pub vendor: [u8; 2],
    /// The client key.
    pub client_key: ClientKey,
    /// The session id every later message of the session carries (0x81 from
    /// the eProsima library).
    pub session_id: u8,
    /// Optional properties.
    pub properties: Option<Vec<Property>>,
    /// The largest message the client accepts (508 over a 512-byte transport).
    pub mtu: u16,
}

impl ClientRepresentation {
    /// A representation with the standard cookie, version 1.0, eProsima's
    /// vendor id and no properties.
    pub fn new(client_key: ClientKey, session_id: u8, mtu: u16) -> Self {
        ClientRepresentation {
            cookie: COOKIE,
            version: VERSION,
            vendor: VENDOR_EPROSIMA,
            client_key,
            session_id,
            properties: None,
            mtu,
        }
    }

    pub(crate) fn read(r: &mut Reader<'_>) -> Result<Self, DecodeError> {
        Ok(ClientRepresentation {
            cookie: r.array("cookie")?,
            version: r.array("version")?,
            vendor: r.array("vendor id")?,
            client_key: ClientKey(r.array("client key")?),
            session_id: r.u8("session id")?,
            properties: read_properties(r)?,
            mtu: r.u16("mtu")?,
        })
    }

    pub(crate) fn write(&self, w: &mut Writer<'_>) -> Result<(), EncodeError> {
        w.bytes(&self.cookie);
        w.bytes(&self.version);
        w.bytes(&self.vendor);
        w.bytes(&self.client_key.0);
        w.u8(self.session_id);
        write_properties(w, self.properties.as_ref())?;
        w.u16(self.mtu);
        Ok(())
    }
}

/// `AGENT_Representation`: what STATUS_AGENT and INFO tell about the agent.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub struct AgentRepresentation {
    /// `xrce_cookie`.
    pub cookie: [u8; 4],
    /// `xrce_version`.
    pub version: [u8; 2],
    /// `xrce_vendor_id`.
    pub vendor: [u8; 2],
    /// Optional properties.
    pub properties: Option<Vec<Property>>,
}

impl Default for AgentRepresentation {
    /// The standard cookie, version 1.0, eProsima's vendor id, no properties.
    fn default() -> Self {
        AgentRepresentation {
            cookie: COOKIE,
            version: VERSION,
            vendor: VENDOR_EPROSIMA,
            properties: None,
        }
    }
}

impl AgentRepresentation {
    pub(crate) fn read(r: &mut Reader<'_>) -> Result<Self, DecodeError> {
        Ok(AgentRepresentation {
            cookie: r.array("cookie")?,
            version: r.array("version")?,
            vendor: r.array("vendor id")?,
            properties: read_properties(r)?,
        })
    }

    pub(crate) fn write(&self, w: &mut Writer<'_>) -> Result<(), EncodeError> {
        w.bytes(&self.cookie);
        w.bytes(&self.version);
        w.bytes(&self.vendor);
        write_properties(w, self.properties.as_ref())
    }
}

/// An object representation: a `format` byte, then a string or a blob.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub enum Representation {
    /// Format 0x01 `BY_REFERENCE`: a profile name the agent looks up.
    Reference(String),
    /// Format 0x02 `AS_XML_STRING`: a Fast DDS XML snippet (may be empty).
    Xml(String),
    /// Format 0x03 `IN_BINARY`: the nested CDR blob, kept opaque.
    Binary(Vec<u8>),
}

/// Which representation formats an object kind accepts.
#[derive(Clone, Copy)]
enum Formats {
    /// Reference, XML and binary ("Rep3").
    All,
    /// XML and binary (publisher, subscriber).
    BinXml,
    /// Reference and XML (type, QoS profile, application).
    RefXml,
}

impl Representation {
    fn format(&self) -> u8 {
        match self {
            Representation::Reference(_) => 1,
            Representation::Xml(_) => 2,
            Representation::Binary(_) => 3,
        }
    }

    fn read(r: &mut Reader<'_>, allowed: Formats) -> Result<Self, DecodeError> {
        let at = r.pos();
        let format = r.u8("representation format")?;
        let ok = match allowed {
            Formats::All => (1..=3).contains(&format),
            Formats::BinXml => (2..=3).contains(&format),
            Formats::RefXml => (1..=2).contains(&format),
        };
        if !ok {
            return Err(r.invalid(at, "representation format", format.into()));
        }
        Ok(match format {
            1 => Representation::Reference(r.string("reference")?),
            2 => Representation::Xml(r.string("XML representation")?),
            _ => Representation::Binary(r.octets("binary representation")?),
        })
    }

    fn write(&self, w: &mut Writer<'_>) -> Result<(), EncodeError> {
        w.u8(self.format());
        match self {
            Representation::Reference(s) => w.string("reference", s),
            Representation::Xml(s) => w.string("XML representation", s),
            Representation::Binary(b) => w.octets("binary representation", b),
        }
    }
}

/// `ObjectVariant`: the kind byte and the kind's representation (§6).
///
/// Encoding does not check that a representation is one the kind accepts
/// (publisher and subscriber take no reference; type, QoS profile and
/// application take no binary); decoding does.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub enum ObjectVariant {
    /// A DDS participant in `domain_id`.
    Participant {
        /// Representation.
        representation: Representation,
        /// DDS domain id (i16).
        domain_id: i16,
    },
    /// A topic of `participant_id`.
    Topic {
        /// Representation.
        representation: Representation,
        /// Parent participant.
        participant_id: ObjectId,
    },
    /// A publisher of `participant_id` (XML or binary only).
    Publisher {
        /// Representation.
        representation: Representation,
        /// Parent participant.
        participant_id: ObjectId,
    },
    /// A subscriber of `participant_id` (XML or binary only).
    Subscriber {
        /// Representation.
        representation: Representation,
        /// Parent participant.
        participant_id: ObjectId,
    },
    /// A data writer of `publisher_id`.
    DataWriter {
        /// Representation.
        representation: Representation,
        /// Parent publisher.
        publisher_id: ObjectId,
    },
    /// A data reader of `subscriber_id`.
    DataReader {
        /// Representation.
        representation: Representation,
        /// Parent subscriber.
        subscriber_id: ObjectId,
    },
    /// A requester of `participant_id`.
    Requester {
        /// Representation.
        representation: Representation,
        /// Parent participant.
        participant_id: ObjectId,
    },
    /// A replier of `participant_id`.
    Replier {
        /// Representation.
        representation: Representation,
        /// Parent participant.
        participant_id: ObjectId,
    },
    /// A type (reference or XML only).
    Type(Representation),
    /// A QoS profile (reference or XML only).
    QosProfile(Representation),
    /// An application (reference or XML only).
    Application(Representation),
    /// The agent (only inside INFO).
    Agent(AgentRepresentation),
    /// A client (only inside INFO).
    Client(ClientRepresentation),
}

impl ObjectVariant {
    /// Bytes of its representation (the XML, binary blob or reference
    /// name a client sent), what keeping it costs beyond a fixed part.
    pub fn representation_len(&self) -> usize {
        use ObjectVariant as V;
        let r = match self {
            V::Participant { representation, .. }
            | V::Topic { representation, .. }
            | V::Publisher { representation, .. }
            | V::Subscriber { representation, .. }
            | V::DataWriter { representation, .. }
            | V::DataReader { representation, .. }
            | V::Requester { representation, .. }
            | V::Replier { representation, .. }
            | V::Type(representation)
            | V::QosProfile(representation)
            | V::Application(representation) => representation,
            V::Agent(_) | V::Client(_) => return 0,
        };
        match r {
            Representation::Reference(s) | Representation::Xml(s) => s.len(),
            Representation::Binary(b) => b.len(),
        }
    }

    /// The kind byte this variant is sent with.
    pub fn kind(&self) -> ObjectKind {
        use ObjectVariant as V;
        match self {
            V::Participant { .. } => ObjectKind::Participant,
            V::Topic { .. } => ObjectKind::Topic,
            V::Publisher { .. } => ObjectKind::Publisher,
            V::Subscriber { .. } => ObjectKind::Subscriber,
            V::DataWriter { .. } => ObjectKind::DataWriter,
            V::DataReader { .. } => ObjectKind::DataReader,
            V::Requester { .. } => ObjectKind::Requester,
            V::Replier { .. } => ObjectKind::Replier,
            V::Type(_) => ObjectKind::Type,
            V::QosProfile(_) => ObjectKind::QosProfile,
            V::Application(_) => ObjectKind::Application,
            V::Agent(_) => ObjectKind::Agent,
            V::Client(_) => ObjectKind::Client,
        }
    }

    pub(crate) fn read(r: &mut Reader<'_>) -> Result<Self, DecodeError> {
        use ObjectVariant as V;
        let at = r.pos();
        let kind = r.u8("object kind")?;
        let Some(kind) = ObjectKind::from_u8(kind) else {
            return Err(r.invalid(at, "object kind", kind.into()));
        };
        let rep = |r: &mut Reader<'_>| Representation::read(r, Formats::All);
        let parent = |r: &mut Reader<'_>| ObjectId::read(r, "parent object id");
        Ok(match kind {
            ObjectKind::Participant => V::Participant {
                representation: rep(r)?,
                domain_id: r.i16("domain id")?,
            },
            ObjectKind::Topic => V::Topic {
                representation: rep(r)?,
                participant_id: parent(r)?,
            },
            ObjectKind::Publisher => V::Publisher {
                representation: Representation::read(r, Formats::BinXml)?,
                participant_id: parent(r)?,
            },
            ObjectKind::Subscriber => V::Subscriber {
                representation: Representation::read(r, Formats::BinXml)?,
                participant_id: parent(r)?,
            },
            ObjectKind::DataWriter => V::DataWriter {
                representation: rep(r)?,
                publisher_id: parent(r)?,
            },
            ObjectKind::DataReader => V::DataReader {
                representation: rep(r)?,
                subscriber_id: parent(r)?,
            },
            ObjectKind::Requester => V::Requester {
                representation: rep(r)?,
                participant_id: parent(r)?,
            },
            ObjectKind::Replier => V::Replier {
                representation: rep(r)?,
                participant_id: parent(r)?,
            },
            ObjectKind::Type => V::Type(Representation::read(r, Formats::RefXml)?),
            ObjectKind::QosProfile => V::QosProfile(Representation::read(r, Formats::RefXml)?),
            ObjectKind::Application => V::Application(Representation::read(r, Formats::RefXml)?),
            ObjectKind::Agent => V::Agent(AgentRepresentation::read(r)?),
            ObjectKind::Client => V::Client(ClientRepresentation::read(r)?),
            ObjectKind::Other => return Err(r.invalid(at, "object kind", kind as u64)),
        })
    }

    pub(crate) fn write(&self, w: &mut Writer<'_>) -> Result<(), EncodeError> {
        use ObjectVariant as V;
        w.u8(self.kind() as u8);
        let (rep, parent) = match self {
            V::Participant {
                representation,
                domain_id,
            } => {
                representation.write(w)?;
                w.i16(*domain_id);
                return Ok(());
            }
            V::Topic {
                representation: r,
                participant_id: p,
            }
            | V::Publisher {
                representation: r,
                participant_id: p,
            }
            | V::Subscriber {
                representation: r,
                participant_id: p,
            }
            | V::Requester {
                representation: r,
                participant_id: p,
            }
            | V::Replier {
                representation: r,
                participant_id: p,
            }
            | V::DataWriter {
                representation: r,
                publisher_id: p,
            }
            | V::DataReader {
                representation: r,
                subscriber_id: p,
            } => (r, Some(p)),
            V::Type(r) | V::QosProfile(r) | V::Application(r) => (r, None),
            V::Agent(a) => return a.write(w),
            V::Client(c) => return c.write(w),
        };
        rep.write(w)?;
        if let Some(p) = parent {
            w.bytes(&p.to_bytes());
        }
        Ok(())
    }
}

/// `ActivityInfoVariant`: what INFO says an object is doing.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub enum ActivityInfo {
    /// The agent: its availability (> 0 answers a ping) and its addresses.
    Agent {
        /// `availability`.
        availability: i16,
        /// `address_seq`.
        locators: Vec<TransportLocator>,
    },
    /// A data writer.
    DataWriter {
        /// `stream_seq_num`.
        stream_seq_num: i16,
        /// `sample_seq_num` (u64, 8-aligned from the message start).
        sample_seq_num: u64,
    },
    /// A data reader.
    DataReader {
        /// `highest_acked_num`.
        highest_acked_num: i16,
    },
    /// Any other kind: the kind byte alone.
    Other(u8),
}

impl ActivityInfo {
    fn read(r: &mut Reader<'_>) -> Result<Self, DecodeError> {
        Ok(match r.u8("activity kind")? {
            k if k == ObjectKind::Agent as u8 => ActivityInfo::Agent {
                availability: r.i16("availability")?,
                locators: r.sequence("locator count", TransportLocator::read)?,
            },
            k if k == ObjectKind::DataWriter as u8 => ActivityInfo::DataWriter {
                stream_seq_num: r.i16("stream sequence number")?,
                sample_seq_num: r.u64("sample sequence number")?,
            },
            k if k == ObjectKind::DataReader as u8 => ActivityInfo::DataReader {
                highest_acked_num: r.i16("highest acked number")?,
            },
            k => ActivityInfo::Other(k),
        })
    }

    fn write(&self, w: &mut Writer<'_>) -> Result<(), EncodeError> {
        match self {
            ActivityInfo::Agent {
                availability,
                locators,
            } => {
                w.u8(ObjectKind::Agent as u8);
                w.i16(*availability);
                w.sequence("locator count", locators, |w, l| l.write(w))?;
            }
            ActivityInfo::DataWriter {
                stream_seq_num,
                sample_seq_num,
            } => {
                w.u8(ObjectKind::DataWriter as u8);
                w.i16(*stream_seq_num);
                w.u64(*sample_seq_num);
            }
            ActivityInfo::DataReader { highest_acked_num } => {
                w.u8(ObjectKind::DataReader as u8);
                w.i16(*highest_acked_num);
            }
            ActivityInfo::Other(k) => w.u8(*k),
        }
        Ok(())
    }
}

/// `ObjectInfo`: the optional configuration and activity of an INFO reply.
#[derive(Debug, Clone, PartialEq, Eq, Hash, Default)]
pub struct ObjectInfo {
    /// `config`: the object's representation.
    pub config: Option<ObjectVariant>,
    /// `activity`.
    pub activity: Option<ActivityInfo>,
}

impl ObjectInfo {
    pub(crate) fn read(r: &mut Reader<'_>) -> Result<Self, DecodeError> {
        Ok(ObjectInfo {
            config: r.optional("config flag", ObjectVariant::read)?,
            activity: r.optional("activity flag", ActivityInfo::read)?,
        })
    }

    pub(crate) fn write(&self, w: &mut Writer<'_>) -> Result<(), EncodeError> {
        w.optional(self.config.as_ref(), |w, c| c.write(w))?;
        w.optional(self.activity.as_ref(), |w, a| a.write(w))
    }
}
