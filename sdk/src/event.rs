//! What [`Session::events`](crate::Session::events) yields: the
//! [`SessionEvent`]s and the SDK's own descriptions of what DDS discovery
//! finds ([`ParticipantInfo`], [`EndpointInfo`], [`Guid`]), so that the
//! public API does not change with the wire crate's discovery structures.

use std::net::SocketAddr;
use std::time::Duration;

use courier_wire::rtps::discovery::{self as wire, EndpointData, ParticipantData};
use courier_wire::rtps::matching::Incompatible;
use courier_wire::rtps::Locator;

use crate::qos::{History, LivelinessKind, Reliability};

/// A DDS GUID: a participant's 12-byte prefix and a 4-byte entity id.
/// Prints as 32 lower-case hex digits, as [`Sample::source`] names writers.
///
/// [`Sample::source`]: crate::Sample::source
#[derive(Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Guid(pub [u8; 16]);

impl Guid {
    /// The participant's part (the GUID prefix).
    pub fn prefix(&self) -> [u8; 12] {
        let mut p = [0; 12];
        p.copy_from_slice(&self.0[..12]);
        p
    }

    /// Whether this GUID belongs to the participant with that prefix.
    pub fn is_of(&self, prefix: [u8; 12]) -> bool {
        self.prefix() == prefix
    }

    /// For an endpoint's GUID: whether its entity kind is keyed
    /// (`WITH_KEY`), i.e. its topic's type has a key.
    pub fn is_keyed(&self) -> bool {
        courier_wire::rtps::EntityId([self.0[12], self.0[13], self.0[14], self.0[15]]).is_keyed()
    }
}

impl std::fmt::Display for Guid {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        self.0.iter().try_for_each(|b| write!(f, "{b:02x}"))
    }
}

impl std::fmt::Debug for Guid {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Guid({self})")
    }
}

impl From<courier_wire::rtps::Guid> for Guid {
    fn from(g: courier_wire::rtps::Guid) -> Self {
        Guid(g.to_bytes())
    }
}

/// A DDS participant found by discovery (SPDP).
#[derive(Debug, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub struct ParticipantInfo {
    /// Its GUID (prefix and the participant entity id `000001c1`).
    pub guid: Guid,
    /// Its entity name, if it announced one (a Courier session's name).
    pub name: Option<String>,
    /// Its vendor id (`[1, 16]` Cyclone DDS, `[1, 15]` Fast DDS, `[1, 1]`
    /// RTI Connext).
    pub vendor: [u8; 2],
    /// The DDS domain id it announced, if any.
    pub domain_id: Option<u32>,
    /// Its unicast addresses: discovery's first, then user data's.
    pub unicast: Vec<SocketAddr>,
    /// Its multicast addresses, in the same order.
    pub multicast: Vec<SocketAddr>,
    /// How long it stays known without announcing itself (`None`: for ever).
    pub lease: Option<Duration>,
}

/// Durability as a remote endpoint announces it (DDS has two more kinds
/// than a Courier publication offers).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum DurabilityKind {
    /// Only readers present when a sample is written get it.
    Volatile,
    /// The writer keeps its history for late joiners.
    TransientLocal,
    /// Kept by a durability service beyond the writer.
    Transient,
    /// Kept on disk by a durability service.
    Persistent,
}

/// The QoS a remote endpoint announced, summarized.
#[derive(Debug, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub struct QosSummary {
    /// Reliability.
    pub reliability: Reliability,
    /// Durability.
    pub durability: DurabilityKind,
    /// History.
    pub history: History,
    /// Deadline (`None`: infinite).
    pub deadline: Option<Duration>,
    /// `Some(strength)` for exclusive ownership.
    pub exclusive: Option<i32>,
    /// Lifespan (`None`: infinite).
    pub lifespan: Option<Duration>,
    /// Liveliness (`None`: automatic with an infinite lease, DDS's default).
    pub liveliness: Option<crate::qos::Liveliness>,
    /// Partitions.
    pub partitions: Vec<String>,
    /// Data representations (`DataRepresentationId_t`: 0 XCDR1, 1 XML, 2
    /// XCDR2): what a writer writes (the first) or a reader accepts.
    pub data_representation: Vec<i16>,
}

/// A remote DDS publication (DataWriter) or subscription (DataReader)
/// found by discovery (SEDP).
#[derive(Debug, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub struct EndpointInfo {
    /// Its GUID; [`Guid::prefix`] is its participant's.
    pub guid: Guid,
    /// The topic.
    pub topic: String,
    /// The DDS type name.
    pub type_name: String,
    /// Its QoS.
    pub qos: QosSummary,
}

/// Socket addresses of locators, each once.
fn addrs<'a>(ls: impl IntoIterator<Item = &'a Locator>) -> Vec<SocketAddr> {
    let mut v = Vec::new();
    for a in ls.into_iter().filter_map(|l| l.socket_addr()) {
        if !v.contains(&a) {
            v.push(a);
        }
    }
    v
}

impl From<&ParticipantData> for ParticipantInfo {
    fn from(p: &ParticipantData) -> Self {
        let guid = courier_wire::rtps::Guid {
            prefix: p.guid_prefix,
            entity: courier_wire::rtps::EntityId::PARTICIPANT,
        };
        ParticipantInfo {
            guid: guid.into(),
            name: p.entity_name.clone(),
            vendor: p.vendor.0,
            domain_id: p.domain_id,
            unicast: addrs(p.metatraffic_unicast.iter().chain(&p.default_unicast)),
            multicast: addrs(p.metatraffic_multicast.iter().chain(&p.default_multicast)),
            lease: p.lease_duration.to_std(),
        }
    }
}

impl EndpointInfo {
    /// Whether its topic's type is keyed, as its GUID's entity kind says
    /// (`WITH_KEY`): a writer and a reader match only if both are or
    /// neither is.
    pub fn keyed(&self) -> bool {
        self.guid.is_keyed()
    }
}

impl From<&EndpointData> for EndpointInfo {
    fn from(e: &EndpointData) -> Self {
        let q = &e.qos;
        EndpointInfo {
            guid: e.guid.into(),
            topic: e.topic_name.clone(),
            type_name: e.type_name.clone(),
            qos: QosSummary {
                reliability: match q.reliability {
                    wire::Reliability::BestEffort => Reliability::BestEffort,
                    wire::Reliability::Reliable(_) => Reliability::Reliable,
                },
                durability: match q.durability {
                    wire::Durability::Volatile => DurabilityKind::Volatile,
                    wire::Durability::TransientLocal => DurabilityKind::TransientLocal,
                    wire::Durability::Transient => DurabilityKind::Transient,
                    wire::Durability::Persistent => DurabilityKind::Persistent,
                },
                history: match q.history {
                    wire::History::KeepLast(n) => {
                        History::KeepLast(u32::try_from(n.max(1)).unwrap_or(1))
                    }
                    wire::History::KeepAll => History::KeepAll,
                },
                deadline: q.deadline.to_std(),
                exclusive: q.exclusive_ownership.then_some(q.ownership_strength),
                lifespan: q.lifespan.to_std(),
                liveliness: match (q.liveliness.0, q.liveliness.1.to_std()) {
                    (wire::LivelinessKind::Automatic, None) => None,
                    (kind, lease) => Some(crate::qos::Liveliness::new(
                        match kind {
                            wire::LivelinessKind::Automatic => LivelinessKind::Automatic,
                            wire::LivelinessKind::ManualByParticipant => {
                                LivelinessKind::ManualByParticipant
                            }
                            wire::LivelinessKind::ManualByTopic => LivelinessKind::ManualByTopic,
                        },
                        // a manual kind with an infinite lease: the longest
                        lease.unwrap_or(Duration::MAX),
                    )),
                },
                partitions: q.partitions.clone(),
                data_representation: q.data_representation.clone(),
            },
        }
    }
}

/// Something that happened to the session or the system.
#[derive(Debug, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub enum SessionEvent {
    /// A module connected to central.
    ModuleConnected(String),
    /// A module disconnected from central.
    ModuleDisconnected(String),
    /// The number of handlers of a message changed.
    HandlersChanged {
        /// Message name.
        msg: String,
        /// Handlers now.
        count: i32,
    },
    /// A keep-all subscription's queue is full (`queued` samples unread),
    /// so the session takes nothing more until the application takes one,
    /// and **every** subscription and server of the session waits
    /// meanwhile. IPC: central hands a module its messages one by one (as
    /// a C module whose handler does not return). RTPS: the participant
    /// stops reading user data; reliable writers hold the rest
    /// (back-pressure, not loss). XRCE: the session stops reading the
    /// link (a reliable subscription's queue). Reported once each time it
    /// fills. Read
    /// the subscription, drop it, or give it
    /// [`QueuePolicy::KeepLast`](crate::QueuePolicy::KeepLast) to drop the
    /// oldest instead.
    SubscriberFull {
        /// Message name.
        msg: String,
        /// Samples waiting in its queue.
        queued: usize,
    },
    /// This session lost its connection (with reconnect on, a
    /// [`SessionEvent::Reconnected`] follows once central is back).
    Disconnected,
    /// The session reached central again and defined and subscribed
    /// everything anew (see [`SessionBuilder::reconnect`](crate::SessionBuilder::reconnect)).
    Reconnected,
    /// XRCE: the agent stopped answering (`silent`: nothing heard for the
    /// keepalive timeout, or its TCP connection or serial line broke) or
    /// answered without knowing the session (it restarted). Reliable writes made meanwhile are kept and sent once
    /// it is back; the session re-creates itself on its own.
    AgentLost {
        /// True if it went silent (or the link broke), false if it forgot
        /// the session.
        silent: bool,
    },
    /// XRCE: a lost agent answered again and still had the session.
    AgentBack,
    /// XRCE: the session was created anew on an agent that had lost it,
    /// with every entity and reading of the session; its `Subscriber`s
    /// stayed open throughout.
    SessionRecreated {
        /// Entities the agent took again (each it refused came before as
        /// [`SessionEvent::EntityError`], and writes through a refused
        /// data writer fail with
        /// [`PublishError::AgentRefused`](crate::PublishError::AgentRefused)).
        entities: usize,
    },
    /// XRCE: the agent refused an entity (when the session was re-created,
    /// or a reading it had accepted).
    EntityError {
        /// The topic or service.
        topic: String,
        /// Which entity.
        entity: &'static str,
        /// The agent's STATUS code.
        status: courier_wire::xrce::StatusCode,
    },
    /// DDS: a participant announced itself for the first time.
    ParticipantFound(Box<ParticipantInfo>),
    /// DDS: a known participant announced different data.
    ParticipantChanged(Box<ParticipantInfo>),
    /// DDS: a participant left (`disposed`) or its lease expired.
    ParticipantLost {
        /// Its GUID (see [`ParticipantInfo::guid`]).
        guid: Guid,
        /// True if it said goodbye, false if it went silent.
        disposed: bool,
    },
    /// DDS: a remote publication (DataWriter) was announced.
    PublicationFound(Box<EndpointInfo>),
    /// DDS: a remote publication changed its QoS.
    PublicationChanged(Box<EndpointInfo>),
    /// DDS: a remote publication is gone.
    PublicationLost(Guid),
    /// DDS: a remote subscription (DataReader) was announced.
    SubscriptionFound(Box<EndpointInfo>),
    /// DDS: a remote subscription changed its QoS.
    SubscriptionChanged(Box<EndpointInfo>),
    /// DDS: a remote subscription is gone.
    SubscriptionLost(Guid),
    /// DDS: a subscription with a deadline got no sample of an instance
    /// within it (the publication's side is
    /// [`SessionEvent::OfferedDeadlineMissed`]).
    DeadlineMissed {
        /// Topic.
        msg: String,
        /// Misses on this subscription so far.
        total: u64,
    },
    /// DDS: a publication with a
    /// [`PublicationQos::deadline`](crate::PublicationQos::deadline) wrote
    /// no sample of an instance it wrote before (and did not dispose or
    /// unregister) within it; again every period until it writes one (DDS's
    /// OFFERED_DEADLINE_MISSED).
    OfferedDeadlineMissed {
        /// Topic.
        msg: String,
        /// Misses of this publication so far.
        total: u64,
    },
    /// DDS: a writer matched with a subscription that requests a
    /// [liveliness](crate::qos#liveliness) changed liveliness (DDS's
    /// LIVELINESS_CHANGED): alive when it matched or asserted itself
    /// again after a lapse; not alive when its lease lapsed (its
    /// participant may well still be known) or when it left (then it is
    /// in neither count any more).
    LivelinessChanged {
        /// Topic.
        msg: String,
        /// The writer.
        writer: Guid,
        /// Whether it is alive now.
        alive: bool,
        /// The subscription's matched writers that are alive.
        alive_count: u32,
        /// The subscription's matched writers whose lease lapsed.
        not_alive_count: u32,
    },
    /// DDS: a publication with a manual
    /// [`PublicationQos::liveliness`](crate::PublicationQos::liveliness)
    /// neither published nor asserted its liveliness within its lease
    /// (DDS's LIVELINESS_LOST): its readers see it not alive. Once per lapse.
    LivelinessLost {
        /// Topic.
        msg: String,
        /// Lapses of this publication so far.
        total: u64,
    },
    /// DDS: a sample was larger than this session takes
    /// ([`SessionBuilder::max_message_bytes`](crate::SessionBuilder::max_message_bytes),
    /// URL option `max_sample_size`): the subscription skipped it (counted
    /// in its `dropped()`), and a reliable writer went on with the next.
    SampleLost {
        /// Topic.
        msg: String,
        /// The writer.
        writer: Guid,
        /// The sample's size in bytes.
        size: u64,
        /// The largest this session takes.
        limit: u64,
    },
    /// DDS: an endpoint on one of our topics does not match ours.
    IncompatibleQos {
        /// Topic.
        msg: String,
        /// The other endpoint.
        remote: Guid,
        /// The first rule that failed; its `Display` names both sides and
        /// what to change. Match on it (`Incompatible::Reliability`, …)
        /// rather than on its text.
        reason: Incompatible,
    },
    /// ROS 2 (a session with [`RtpsOptions::ros2_node`] or
    /// [`RtpsOptions::ros2_graph`]): a participant's ROS 2 nodes changed,
    /// as its latest `ros_discovery_info` sample lists them; empty when it
    /// left. [`DdsControl::ros2_nodes`](crate::DdsControl::ros2_nodes)
    /// gives each node's topics.
    ///
    /// [`RtpsOptions::ros2_node`]: crate::RtpsOptions::ros2_node
    /// [`RtpsOptions::ros2_graph`]: crate::RtpsOptions::ros2_graph
    Ros2Nodes {
        /// The participant (its GID, as a GUID).
        participant: Guid,
        /// Its nodes, in the order it listed them.
        nodes: Vec<crate::rtps_backend::Ros2NodeName>,
    },
    /// ROS 2: a `ros_discovery_info` sample was refused (it does not
    /// decode, or speaks for another participant than its writer's); what
    /// was known of the writer's participant stays as it was.
    Ros2GraphRefused {
        /// The writer that sent it.
        writer: Guid,
        /// Why.
        reason: String,
    },
    /// DDS: an endpoint on one of our topics has another type name, so
    /// the two do not match.
    TypeMismatch {
        /// Topic.
        topic: String,
        /// The other endpoint.
        remote: Guid,
        /// Our type name.
        local_type: String,
        /// Theirs.
        remote_type: String,
    },
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_guid_prints_as_32_hex_digits_and_knows_its_participant() {
        let b: [u8; 16] = std::array::from_fn(|i| i as u8 * 17);
        let g = Guid(b);
        assert_eq!(g.to_string(), "00112233445566778899aabbccddeeff");
        assert_eq!(format!("{g:?}"), "Guid(00112233445566778899aabbccddeeff)");
        assert!(g.is_of([0, 17, 34, 51, 68, 85, 102, 119, 136, 153, 170, 187]));
        assert_eq!(
            g.to_string(),
            crate::rtps_backend::guid_hex(courier_wire::rtps::Guid::from_bytes(b))
        );
    }
}
