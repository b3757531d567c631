//! What an XRCE object is in DDS terms, from any of its three
//! representations: the binary blob (`binary.rs`), a Fast DDS XML snippet
//! (`<dds><data_writer>…</data_writer></dds>`, the subset eProsima's
//! clients send) or a profile name looked up in the agent's references
//! file (Fast DDS `<profiles>` XML, as MicroXRCEAgent's `-r`).
//!
//! Defaults are Fast DDS 2.9's, so that an entity means the same thing in
//! Courier's agent as in eProsima's: an XML or QoS-less data writer is
//! reliable, transient-local, keep-last 1; a data reader best-effort,
//! volatile, keep-last 1; a requester's topics are
//! `<service_name>_Request` and `<service_name>_Reply`.

use std::collections::BTreeMap;
use std::time::Duration;

use crate::rtps::discovery::{
    Durability, Duration as RtpsDuration, EndpointQos, History, LivelinessKind, Reliability,
};

use super::super::binary::{
    qos_flags, BinaryRepresentation, DataReaderBinary, DataWriterBinary, EndpointQos as BinQos,
    GroupBinary, ServiceBinary,
};
use super::super::types::ObjectKind;

/// A topic: its name, type name and whether the type has a key.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TopicProfile {
    /// DDS topic name.
    pub name: String,
    /// DDS type name.
    pub type_name: String,
    /// `WITH_KEY`.
    pub keyed: bool,
}

/// A data writer or reader: its topic and QoS.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct EndpointProfile {
    /// The topic (XML names it; binary refers to a topic object, whose
    /// profile the bridge fills in).
    pub topic: Option<TopicProfile>,
    /// QoS.
    pub qos: EndpointQos,
}

/// A requester or replier.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ServiceProfile {
    /// Service name.
    pub service_name: String,
    /// Request type name.
    pub request_type: String,
    /// Reply type name.
    pub reply_type: String,
    /// Request topic (default `<service_name>_Request`).
    pub request_topic: String,
    /// Reply topic (default `<service_name>_Reply`).
    pub reply_topic: String,
}

/// What an object is, whichever representation it came in.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Profile {
    /// A participant (its name, if it gave one).
    Participant(Option<String>),
    /// A topic.
    Topic(TopicProfile),
    /// A publisher or subscriber: its partitions.
    Group(Vec<String>),
    /// A data writer.
    Writer(EndpointProfile),
    /// A data reader.
    Reader(EndpointProfile),
    /// A requester or replier.
    Service(ServiceProfile),
}

/// Why a representation or a references file could not be used.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum ProfileError {
    /// Not XML.
    #[error("XML at line {line}, column {column}: {message}")]
    Xml {
        /// 1-based line.
        line: u32,
        /// 1-based column.
        column: u32,
        /// What the parser said.
        message: String,
    },
    /// The XML has no element for this kind of object.
    #[error("the XML has no <{0}> element")]
    Missing(&'static str),
    /// A field the object needs is absent or empty.
    #[error("<{element}> has no {field}")]
    Field {
        /// The element.
        element: &'static str,
        /// The field.
        field: &'static str,
    },
    /// A field holds a value that is not one of those allowed.
    #[error("<{element}>: {value:?} is not a valid {field}")]
    Value {
        /// The element.
        element: &'static str,
        /// The field.
        field: &'static str,
        /// What it held.
        value: String,
    },
    /// No profile of this name and kind in the references.
    #[error("no {kind} profile named {name:?} in the references")]
    UnknownReference {
        /// The kind of object.
        kind: &'static str,
        /// The name asked for.
        name: String,
    },
    /// Two profiles of one kind with the same name in a references file.
    #[error("line {line}: a second {kind} profile named {name:?} (the first is at line {first})")]
    Duplicate {
        /// The kind.
        kind: &'static str,
        /// The name.
        name: String,
        /// The second one's line (1-based).
        line: u32,
        /// The first one's.
        first: u32,
    },
    /// A profile of a references file that does not describe its object.
    #[error("line {line}: <{element} profile_name={name:?}>: {error}")]
    InProfile {
        /// The profile's line (1-based).
        line: u32,
        /// Its element.
        element: &'static str,
        /// Its name.
        name: String,
        /// What is wrong with it.
        error: Box<ProfileError>,
    },
    /// A binary representation for an object kind that has none.
    #[error("a {0:?} has no binary representation")]
    NoBinary(ObjectKind),
}

/// The XML element name of an object kind, as Fast DDS profiles name it.
fn element(kind: ObjectKind) -> Option<&'static str> {
    Some(match kind {
        ObjectKind::Participant => "participant",
        ObjectKind::Topic => "topic",
        ObjectKind::Publisher => "publisher",
        ObjectKind::Subscriber => "subscriber",
        ObjectKind::DataWriter => "data_writer",
        ObjectKind::DataReader => "data_reader",
        ObjectKind::Requester => "requester",
        ObjectKind::Replier => "replier",
        _ => return None,
    })
}

/// eProsima's clients glue attributes together without a space
/// (`profile_name="a"service_name="b"`), which tinyxml2 takes and XML does
/// not: a space goes between a closing quote and the next attribute.
fn loosen(xml: &str) -> std::borrow::Cow<'_, str> {
    let mut o = String::new();
    let mut inserted = false;
    let (mut in_tag, mut quote, mut after_quote) = (false, '\0', false);
    for c in xml.chars() {
        if quote != '\0' {
            o.push(c);
            if c == quote {
                quote = '\0';
                after_quote = true;
            }
            continue;
        }
        if in_tag && after_quote && (c.is_ascii_alphabetic() || c == '_') {
            o.push(' ');
            inserted = true;
        }
        after_quote = false;
        match c {
            '<' => in_tag = true,
            '>' => in_tag = false,
            '"' | '\'' if in_tag => quote = c,
            _ => {}
        }
        o.push(c);
    }
    if inserted {
        std::borrow::Cow::Owned(o)
    } else {
        std::borrow::Cow::Borrowed(xml)
    }
}

fn parse(xml: &str) -> Result<roxmltree::Document<'_>, ProfileError> {
    roxmltree::Document::parse(xml).map_err(|e| {
        if matches!(
            e,
            roxmltree::Error::UnclosedRootNode | roxmltree::Error::UnexpectedEndOfStream
        ) {
            // roxmltree puts these at 1:1; they are at the end of the text
            // (a file cut short, as a full disk or an unfinished copy leaves)
            let line = xml.split('\n').count();
            let column = xml.rsplit('\n').next().map_or(0, |l| l.chars().count()) + 1;
            return ProfileError::Xml {
                line: u32::try_from(line).unwrap_or(u32::MAX),
                column: u32::try_from(column).unwrap_or(u32::MAX),
                message: "the text ends before the root element is closed (is it cut short?)"
                    .into(),
            };
        }
        let p = e.pos();
        let mut message = e.to_string();
        // roxmltree ends its message with the position, which comes first here
        let at = format!(" at {}:{}", p.row, p.col);
        if message.ends_with(&at) {
            message.truncate(message.len() - at.len());
        }
        ProfileError::Xml {
            line: p.row,
            column: p.col,
            message,
        }
    })
}

type Node<'a, 'i> = roxmltree::Node<'a, 'i>;

fn child<'a, 'i>(n: Node<'a, 'i>, name: &str) -> Option<Node<'a, 'i>> {
    n.children()
        .find(|c| c.is_element() && c.tag_name().name() == name)
}

fn text<'a>(n: Node<'a, '_>, name: &str) -> Option<&'a str> {
    child(n, name)
        .and_then(|c| c.text())
        .map(str::trim)
        .filter(|t| !t.is_empty())
}

fn number<T: std::str::FromStr>(
    element: &'static str,
    field: &'static str,
    s: &str,
) -> Result<T, ProfileError> {
    s.trim().parse().map_err(|_| ProfileError::Value {
        element,
        field,
        value: s.into(),
    })
}

/// A Fast DDS duration element (`<sec>`, `<nanosec>`, or the word
/// `DURATION_INFINITY`); `None` is infinite.
fn duration(element: &'static str, n: Node<'_, '_>) -> Result<Option<Duration>, ProfileError> {
    let word = |s: &str| s.contains("INFINIT");
    if n.text().map(str::trim).is_some_and(word) {
        return Ok(None);
    }
    let sec = match text(n, "sec") {
        Some(s) if word(s) => return Ok(None),
        Some(s) => number::<u64>(element, "sec", s)?,
        None => 0,
    };
    let nanos = match text(n, "nanosec") {
        Some(s) if word(s) => return Ok(None),
        Some(s) => number::<u32>(element, "nanosec", s)?,
        None => 0,
    };
    Ok(Some(
        Duration::from_secs(sec) + Duration::from_nanos(u64::from(nanos)),
    ))
}

fn rtps_duration(d: Option<Duration>) -> RtpsDuration {
    d.map_or(RtpsDuration::INFINITE, RtpsDuration::from_std)
}

fn topic_of(element: &'static str, n: Node<'_, '_>) -> Result<TopicProfile, ProfileError> {
    let name = text(n, "name").ok_or(ProfileError::Field {
        element,
        field: "<name>",
    })?;
    let type_name = text(n, "dataType").ok_or(ProfileError::Field {
        element,
        field: "<dataType>",
    })?;
    let keyed = match text(n, "kind") {
        None | Some("NO_KEY") => false,
        Some("WITH_KEY") => true,
        Some(v) => {
            return Err(ProfileError::Value {
                element,
                field: "topic <kind>",
                value: v.into(),
            })
        }
    };
    Ok(TopicProfile {
        name: name.into(),
        type_name: type_name.into(),
        keyed,
    })
}

fn partitions(n: Node<'_, '_>) -> Vec<String> {
    child(n, "qos")
        .and_then(|q| child(q, "partition"))
        .and_then(|p| child(p, "names"))
        .map(|names| {
            names
                .children()
                .filter(|c| c.is_element() && c.tag_name().name() == "name")
                .filter_map(|c| c.text())
                .map(|t| t.trim().to_string())
                .collect()
        })
        .unwrap_or_default()
}

/// Fast DDS's defaults for an endpoint made from XML or attributes.
pub(crate) fn default_qos(writer: bool) -> EndpointQos {
    let mut q = EndpointQos::reader_default();
    if writer {
        q.reliability = Reliability::Reliable(RtpsDuration::from_std(Duration::from_millis(100)));
        q.durability = Durability::TransientLocal;
    }
    q
}

fn endpoint_of(
    element: &'static str,
    writer: bool,
    n: Node<'_, '_>,
) -> Result<EndpointProfile, ProfileError> {
    let mut qos = default_qos(writer);
    let topic_node = child(n, "topic");
    let topic = topic_node.map(|t| topic_of(element, t)).transpose()?;
    if let Some(h) = topic_node.and_then(|t| child(t, "historyQos")) {
        let depth = text(h, "depth")
            .map(|d| number::<i32>(element, "history <depth>", d))
            .transpose()?
            .unwrap_or(1);
        qos.history = match text(h, "kind") {
            None | Some("KEEP_LAST") | Some("KEEP_LAST_HISTORY_QOS") => {
                History::KeepLast(depth.max(1))
            }
            Some("KEEP_ALL") | Some("KEEP_ALL_HISTORY_QOS") => History::KeepAll,
            Some(v) => {
                return Err(ProfileError::Value {
                    element,
                    field: "history <kind>",
                    value: v.into(),
                })
            }
        };
    }
    qos.partitions = partitions(n);
    if let Some(q) = child(n, "qos") {
        if let Some(k) = child(q, "reliability").and_then(|r| text(r, "kind")) {
            qos.reliability = match k {
                "RELIABLE" | "RELIABLE_RELIABILITY_QOS" => {
                    Reliability::Reliable(RtpsDuration::from_std(Duration::from_millis(100)))
                }
                "BEST_EFFORT" | "BEST_EFFORT_RELIABILITY_QOS" => Reliability::BestEffort,
                v => {
                    return Err(ProfileError::Value {
                        element,
                        field: "reliability <kind>",
                        value: v.into(),
                    })
                }
            };
        }
        if let Some(k) = child(q, "durability").and_then(|r| text(r, "kind")) {
            qos.durability = match k {
                "VOLATILE" | "VOLATILE_DURABILITY_QOS" => Durability::Volatile,
                "TRANSIENT_LOCAL" | "TRANSIENT_LOCAL_DURABILITY_QOS" => Durability::TransientLocal,
                "TRANSIENT" | "TRANSIENT_DURABILITY_QOS" => Durability::Transient,
                "PERSISTENT" | "PERSISTENT_DURABILITY_QOS" => Durability::Persistent,
                v => {
                    return Err(ProfileError::Value {
                        element,
                        field: "durability <kind>",
                        value: v.into(),
                    })
                }
            };
        }
        if let Some(k) = child(q, "ownership").and_then(|r| text(r, "kind")) {
            qos.exclusive_ownership = match k {
                "SHARED" | "SHARED_OWNERSHIP_QOS" => false,
                "EXCLUSIVE" | "EXCLUSIVE_OWNERSHIP_QOS" => true,
                v => {
                    return Err(ProfileError::Value {
                        element,
                        field: "ownership <kind>",
                        value: v.into(),
                    })
                }
            };
        }
        if let Some(v) = child(q, "ownershipStrength").and_then(|r| text(r, "value")) {
            qos.ownership_strength = number(element, "ownershipStrength <value>", v)?;
        }
        if let Some(p) = child(q, "deadline").and_then(|d| child(d, "period")) {
            qos.deadline = rtps_duration(duration(element, p)?);
        }
        if let Some(p) = child(q, "lifespan").and_then(|d| child(d, "duration")) {
            qos.lifespan = rtps_duration(duration(element, p)?);
        }
        if let Some(l) = child(q, "liveliness") {
            qos.liveliness = liveliness(element, l)?;
        }
        if let Some(p) = child(q, "timeBasedFilter").and_then(|d| child(d, "minimum_separation")) {
            qos.time_based_filter =
                duration(element, p)?.map_or(RtpsDuration::ZERO, RtpsDuration::from_std);
        }
    }
    Ok(EndpointProfile { topic, qos })
}

/// Fast DDS's `<liveliness>`: `<kind>` (AUTOMATIC, MANUAL_BY_PARTICIPANT,
/// MANUAL_BY_TOPIC; default AUTOMATIC) and `<lease_duration>` (default
/// infinite). `<announcement_period>` is Fast DDS's own pacing of its
/// participant messages; Courier's agent paces them by the lease.
fn liveliness(
    element: &'static str,
    l: Node<'_, '_>,
) -> Result<(LivelinessKind, RtpsDuration), ProfileError> {
    let kind = match text(l, "kind") {
        None | Some("AUTOMATIC") | Some("AUTOMATIC_LIVELINESS_QOS") => LivelinessKind::Automatic,
        Some("MANUAL_BY_PARTICIPANT") | Some("MANUAL_BY_PARTICIPANT_LIVELINESS_QOS") => {
            LivelinessKind::ManualByParticipant
        }
        Some("MANUAL_BY_TOPIC") | Some("MANUAL_BY_TOPIC_LIVELINESS_QOS") => {
            LivelinessKind::ManualByTopic
        }
        Some(v) => {
            return Err(ProfileError::Value {
                element,
                field: "liveliness <kind>",
                value: v.into(),
            })
        }
    };
    let lease = match child(l, "lease_duration") {
        Some(d) => match duration(element, d)? {
            Some(d) if d.is_zero() => {
                return Err(ProfileError::Value {
                    element,
                    field: "liveliness <lease_duration>",
                    value: "0".into(),
                })
            }
            d => rtps_duration(d),
        },
        None => RtpsDuration::INFINITE,
    };
    Ok((kind, lease))
}

fn service_of(element: &'static str, n: Node<'_, '_>) -> Result<ServiceProfile, ProfileError> {
    let attr = |field: &'static str| {
        n.attribute(field)
            .filter(|v| !v.is_empty())
            .ok_or(ProfileError::Field { element, field })
    };
    let service_name = attr("service_name")?.to_string();
    Ok(ServiceProfile {
        request_type: attr("request_type")?.into(),
        reply_type: attr("reply_type")?.into(),
        request_topic: n
            .attribute("request_topic_name")
            .map_or_else(|| format!("{service_name}_Request"), String::from),
        reply_topic: n
            .attribute("reply_topic_name")
            .map_or_else(|| format!("{service_name}_Reply"), String::from),
        service_name,
    })
}

fn profile_of(kind: ObjectKind, n: Node<'_, '_>) -> Result<Profile, ProfileError> {
    let element = element(kind).ok_or(ProfileError::NoBinary(kind))?;
    Ok(match kind {
        ObjectKind::Participant => Profile::Participant(
            child(n, "rtps")
                .and_then(|r| text(r, "name"))
                .map(String::from),
        ),
        ObjectKind::Topic => Profile::Topic(topic_of(element, n)?),
        ObjectKind::Publisher | ObjectKind::Subscriber => Profile::Group(partitions(n)),
        ObjectKind::DataWriter => Profile::Writer(endpoint_of(element, true, n)?),
        ObjectKind::DataReader => Profile::Reader(endpoint_of(element, false, n)?),
        _ => Profile::Service(service_of(element, n)?),
    })
}

/// The object of `kind` an XML representation describes: the first
/// element of its name anywhere in the document (`<dds><data_writer>…`).
/// An empty string is the default publisher or subscriber.
pub fn from_xml(kind: ObjectKind, xml: &str) -> Result<Profile, ProfileError> {
    let element = element(kind).ok_or(ProfileError::NoBinary(kind))?;
    if xml.trim().is_empty() && matches!(kind, ObjectKind::Publisher | ObjectKind::Subscriber) {
        return Ok(Profile::Group(Vec::new()));
    }
    let xml = loosen(xml);
    let doc = parse(&xml)?;
    let n = doc
        .descendants()
        .find(|n| n.is_element() && n.tag_name().name() == element)
        .ok_or(ProfileError::Missing(element))?;
    profile_of(kind, n)
}

fn endpoint_qos(writer: bool, q: Option<&BinQos>) -> EndpointQos {
    let mut qos = default_qos(writer);
    let Some(q) = q else {
        return qos;
    };
    qos.reliability = if q.flags & qos_flags::RELIABLE != 0 {
        Reliability::Reliable(RtpsDuration::from_std(Duration::from_millis(100)))
    } else {
        Reliability::BestEffort
    };
    qos.durability = if q.flags & qos_flags::TRANSIENT_LOCAL != 0 {
        Durability::TransientLocal
    } else if q.flags & qos_flags::TRANSIENT != 0 {
        Durability::Transient
    } else if q.flags & qos_flags::PERSISTENT != 0 {
        Durability::Persistent
    } else {
        Durability::Volatile
    };
    qos.exclusive_ownership = q.flags & qos_flags::OWNERSHIP_EXCLUSIVE != 0;
    let depth = q.history_depth.map_or(1, |d| i32::from(d.max(1)));
    qos.history = if q.flags & qos_flags::KEEP_LAST != 0 {
        History::KeepLast(depth)
    } else {
        History::KeepAll
    };
    if let Some(ms) = q.deadline_ms {
        qos.deadline = RtpsDuration::from_std(Duration::from_millis(u64::from(ms)));
    }
    if let Some(ms) = q.lifespan_ms {
        qos.lifespan = RtpsDuration::from_std(Duration::from_millis(u64::from(ms)));
    }
    qos
}

fn group(g: &GroupBinary) -> Profile {
    Profile::Group(
        g.qos
            .as_ref()
            .and_then(|q| q.partitions.clone())
            .unwrap_or_default(),
    )
}

fn service(s: &ServiceBinary) -> Profile {
    let name = &s.service_name;
    Profile::Service(ServiceProfile {
        service_name: name.clone(),
        request_type: s.request_type.clone(),
        reply_type: s.reply_type.clone(),
        request_topic: s
            .request_topic_name
            .clone()
            .unwrap_or_else(|| format!("{name}_Request")),
        reply_topic: s
            .reply_topic_name
            .clone()
            .unwrap_or_else(|| format!("{name}_Reply")),
    })
}

/// The object a binary representation describes. A writer's or reader's
/// topic is left for the bridge to fill in from its topic object.
pub fn from_binary(b: &BinaryRepresentation) -> Profile {
    use BinaryRepresentation as B;
    match b {
        B::Participant(p) => Profile::Participant(p.qos_profile_reference.clone()),
        B::Topic(t) => Profile::Topic(TopicProfile {
            name: t.topic_name.clone(),
            type_name: t
                .type_name
                .clone()
                .or_else(|| t.type_reference.clone())
                .unwrap_or_default(),
            keyed: false,
        }),
        B::Publisher(g) | B::Subscriber(g) => group(g),
        B::DataWriter(DataWriterBinary { qos, .. }) => {
            let mut q = endpoint_qos(true, qos.as_ref().map(|q| &q.0));
            if let Some(s) = qos.as_ref().and_then(|q| q.1) {
                q.ownership_strength = i32::try_from(s).unwrap_or(i32::MAX);
            }
            Profile::Writer(EndpointProfile {
                topic: None,
                qos: q,
            })
        }
        B::DataReader(DataReaderBinary { qos, .. }) => {
            let mut q = endpoint_qos(false, qos.as_ref().map(|q| &q.base));
            if let Some(ms) = qos.as_ref().and_then(|q| q.time_based_filter_ms) {
                q.time_based_filter = RtpsDuration::from_std(Duration::from_millis(ms));
            }
            Profile::Reader(EndpointProfile {
                topic: None,
                qos: q,
            })
        }
        B::Requester(s) | B::Replier(s) => service(s),
    }
}

/// The profiles of a references file (MicroXRCEAgent's `-r`): Fast DDS
/// `<profiles>` XML whose participant, topic, data_writer, data_reader,
/// requester and replier elements are named by `profile_name`.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Profiles {
    by_kind: BTreeMap<(u8, String), Profile>,
}

impl Profiles {
    /// No profiles.
    pub fn new() -> Self {
        Self::default()
    }

    /// Reads a references file's text. Every profile must parse, and names
    /// must be unique per kind.
    pub fn parse(xml: &str) -> Result<Self, ProfileError> {
        let xml = loosen(xml);
        let doc = parse(&xml)?;
        let mut by_kind = BTreeMap::new();
        let mut lines: BTreeMap<(u8, &str), u32> = BTreeMap::new();
        let kinds = [
            ObjectKind::Participant,
            ObjectKind::Topic,
            ObjectKind::DataWriter,
            ObjectKind::DataReader,
            ObjectKind::Requester,
            ObjectKind::Replier,
            ObjectKind::Publisher,
            ObjectKind::Subscriber,
        ];
        for n in doc.descendants().filter(|n| n.is_element()) {
            let Some(name) = n.attribute("profile_name") else {
                continue;
            };
            let Some(&kind) = kinds
                .iter()
                .find(|k| element(**k) == Some(n.tag_name().name()))
            else {
                continue;
            };
            // `loosen` adds spaces only: the lines are the file's
            let line = doc.text_pos_at(n.range().start).row;
            let tag = element(kind).unwrap_or("?");
            let p = profile_of(kind, n).map_err(|e| ProfileError::InProfile {
                line,
                element: tag,
                name: name.into(),
                error: Box::new(e),
            })?;
            if let Some(&first) = lines.get(&(kind as u8, name)) {
                return Err(ProfileError::Duplicate {
                    kind: tag,
                    name: name.into(),
                    line,
                    first,
                });
            }
            lines.insert((kind as u8, name), line);
            by_kind.insert((kind as u8, name.to_string()), p);
        }
        Ok(Profiles { by_kind })
    }

    /// The profile of `kind` named `name`.
    pub fn get(&self, kind: ObjectKind, name: &str) -> Result<&Profile, ProfileError> {
        self.by_kind
            .get(&(kind as u8, name.to_string()))
            .ok_or_else(|| ProfileError::UnknownReference {
                kind: element(kind).unwrap_or("object"),
                name: name.into(),
            })
    }

    /// How many profiles there are.
    pub fn len(&self) -> usize {
        self.by_kind.len()
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.by_kind.is_empty()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const REFS: &str = r#"<profiles>
    <participant profile_name="default_xrce_participant">
        <rtps><name>default_xrce_participant</name></rtps>
    </participant>
    <data_writer profile_name="shapetype_data_writer">
        <topic><kind>WITH_KEY</kind><name>Square</name><dataType>ShapeType</dataType></topic>
    </data_writer>
    <data_reader profile_name="shapetype_data_reader">
        <topic><kind>WITH_KEY</kind><name>Square</name><dataType>ShapeType</dataType></topic>
    </data_reader>
    <topic profile_name="shapetype_topic">
        <kind>WITH_KEY</kind><name>Square</name><dataType>ShapeType</dataType>
    </topic>
    <requester profile_name="shapetype_requester" service_name="shapetype_service"
               request_type="request_type" reply_type="reply_type"></requester>
    <replier profile_name="shapetype_replier" service_name="shapetype_service"
             request_type="request_type" reply_type="reply_type"></replier>
</profiles>"#;

    #[test]
    fn a_references_file_error_names_the_line_of_its_profile() {
        let topic = |name: &str, kind: &str| {
            format!("  <topic profile_name=\"{name}\"><kind>{kind}</kind><name>T</name><dataType>D</dataType></topic>\n")
        };
        let file = |body: String| format!("<profiles>\n{body}</profiles>\n");
        let twice = file(topic("a", "NO_KEY") + &topic("b", "NO_KEY") + &topic("a", "NO_KEY"));
        assert_eq!(
            Profiles::parse(&twice).unwrap_err().to_string(),
            "line 4: a second topic profile named \"a\" (the first is at line 2)"
        );
        let bad = file(topic("a", "NO_KEY") + &topic("b", "SOMETIMES"));
        let e = Profiles::parse(&bad).unwrap_err();
        assert!(
            e.to_string().starts_with(
                "line 3: <topic profile_name=\"b\">: <topic>: \"SOMETIMES\" is not a valid"
            ),
            "{e}"
        );
    }

    #[test]
    fn the_shared_references_file() {
        let p = Profiles::parse(REFS).unwrap();
        assert_eq!(p.len(), 6);
        let Profile::Writer(w) = p
            .get(ObjectKind::DataWriter, "shapetype_data_writer")
            .unwrap()
        else {
            panic!()
        };
        let t = w.topic.as_ref().unwrap();
        assert_eq!(
            (t.name.as_str(), t.type_name.as_str(), t.keyed),
            ("Square", "ShapeType", true)
        );
        assert_eq!(w.qos.durability, Durability::TransientLocal);
        let Profile::Service(s) = p.get(ObjectKind::Requester, "shapetype_requester").unwrap()
        else {
            panic!()
        };
        assert_eq!(s.request_topic, "shapetype_service_Request");
        assert!(matches!(
            p.get(ObjectKind::DataReader, "shapetype_data_writer"),
            Err(ProfileError::UnknownReference {
                kind: "data_reader",
                ..
            })
        ));
    }

    #[test]
    fn glued_attributes_of_the_eprosima_examples() {
        let xml = "<dds><requester profile_name=\"my_requester\"service_name=\"service_name\"request_type=\"request_type\"reply_type=\"reply_type\"></requester></dds>";
        let Profile::Service(s) = from_xml(ObjectKind::Requester, xml).unwrap() else {
            panic!()
        };
        assert_eq!(s.service_name, "service_name");
        assert_eq!(s.reply_topic, "service_name_Reply");
    }

    #[test]
    fn hello_world_writer_and_qos() {
        let xml = "<dds><data_writer><topic><kind>NO_KEY</kind><name>HelloWorldTopic</name><dataType>HelloWorld</dataType><historyQos><kind>KEEP_ALL</kind></historyQos></topic><qos><reliability><kind>BEST_EFFORT_RELIABILITY_QOS</kind></reliability><durability><kind>VOLATILE_DURABILITY_QOS</kind></durability><partition><names><name>a</name></names></partition><deadline><period><sec>1</sec><nanosec>500000000</nanosec></period></deadline></qos></data_writer></dds>";
        let Profile::Writer(w) = from_xml(ObjectKind::DataWriter, xml).unwrap() else {
            panic!()
        };
        assert_eq!(w.qos.reliability, Reliability::BestEffort);
        assert_eq!(w.qos.durability, Durability::Volatile);
        assert_eq!(w.qos.history, History::KeepAll);
        assert_eq!(w.qos.partitions, ["a"]);
        assert_eq!(w.qos.deadline.to_std(), Some(Duration::from_millis(1500)));
    }

    /// Fast DDS's `<liveliness>` (XMLParserCommon.cpp: liveliness, kind,
    /// lease_duration, announcement_period): it reaches the DDS endpoint,
    /// so a client's reader that requests manual liveliness matches only
    /// writers that offer it, and a client's manual writer lapses when the
    /// client stops writing.
    #[test]
    fn liveliness_in_xml() {
        let w = |qos: &str| {
            from_xml(
                ObjectKind::DataWriter,
                &format!("<dds><data_writer><topic><name>a</name><dataType>b</dataType></topic><qos>{qos}</qos></data_writer></dds>"),
            )
        };
        let ok = |qos: &str| match w(qos).unwrap() {
            Profile::Writer(e) => e.qos.liveliness,
            p => panic!("{p:?}"),
        };
        assert_eq!(
            ok("<liveliness><kind>MANUAL_BY_TOPIC</kind><lease_duration><sec>1</sec><nanosec>500000000</nanosec></lease_duration><announcement_period><sec>0</sec><nanosec>500000000</nanosec></announcement_period></liveliness>"),
            (
                LivelinessKind::ManualByTopic,
                RtpsDuration::from_std(Duration::from_millis(1500))
            )
        );
        assert_eq!(
            ok("<liveliness><kind>MANUAL_BY_PARTICIPANT_LIVELINESS_QOS</kind><lease_duration><sec>DURATION_INFINITY</sec></lease_duration></liveliness>"),
            (LivelinessKind::ManualByParticipant, RtpsDuration::INFINITE)
        );
        assert_eq!(
            ok("<liveliness><lease_duration><sec>2</sec></lease_duration></liveliness>"),
            (
                LivelinessKind::Automatic,
                RtpsDuration::from_std(Duration::from_secs(2))
            )
        );
        assert_eq!(
            ok("<reliability><kind>RELIABLE</kind></reliability>"),
            (LivelinessKind::Automatic, RtpsDuration::INFINITE),
            "DDS's default"
        );
        assert_eq!(
            w("<liveliness><kind>SOMETIMES</kind></liveliness>")
                .unwrap_err()
                .to_string(),
            "<data_writer>: \"SOMETIMES\" is not a valid liveliness <kind>"
        );
        assert_eq!(
            w("<liveliness><lease_duration><sec>0</sec></lease_duration></liveliness>")
                .unwrap_err()
                .to_string(),
            "<data_writer>: \"0\" is not a valid liveliness <lease_duration>"
        );
    }

    #[test]
    fn errors_say_where_and_what() {
        let e = Profiles::parse(
            "<profiles>\n<topic profile_name=\"t\"><name>x</name></topic>\n</profiles>",
        )
        .unwrap_err();
        assert_eq!(
            e.to_string(),
            "line 2: <topic profile_name=\"t\">: <topic> has no <dataType>"
        );
        let e = Profiles::parse("<profiles>\n<topic profile_name=\"t\">\n</profile>").unwrap_err();
        assert!(e.to_string().starts_with("XML at line 3"), "{e}");
        // A file cut short is said where it ends (the parser puts it at 1:1).
        let e = Profiles::parse("<profiles>\n  <topic profile_name=\"t\">\n    <na").unwrap_err();
        assert_eq!(
            e.to_string(),
            "XML at line 3, column 8: the text ends before the root element is closed \
             (is it cut short?)"
        );
        let e = Profiles::parse("<profiles>\n<topic/>\n").unwrap_err();
        assert!(
            e.to_string()
                .starts_with("XML at line 3, column 1: the text ends"),
            "{e}"
        );
        let e = from_xml(
            ObjectKind::DataReader,
            "<dds><data_reader><topic><kind>MAYBE</kind><name>a</name><dataType>b</dataType></topic></data_reader></dds>",
        )
        .unwrap_err();
        assert_eq!(
            e.to_string(),
            "<data_reader>: \"MAYBE\" is not a valid topic <kind>"
        );
        assert_eq!(
            from_xml(ObjectKind::DataWriter, "<dds/>").unwrap_err(),
            ProfileError::Missing("data_writer")
        );
    }
}
