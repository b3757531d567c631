//! Quality of service for publications and subscriptions, in ORTE's terms
//! (strength, persistence, deadline, minimum separation, best effort or
//! strict reliable) mapped onto DDS QoS.
//!
//! | ORTE | Courier | DDS QoS on the wire |
//! |---|---|---|
//! | publication `strength` | [`PublicationQos::strength`] | OWNERSHIP exclusive + OWNERSHIP_STRENGTH |
//! | publication `persistence` | [`PublicationQos::persistence`] | LIFESPAN |
//! | subscription `deadline` | [`SubscriptionQos::deadline`] | DEADLINE; a miss is a [`SessionEvent::DeadlineMissed`](crate::SessionEvent::DeadlineMissed) |
//! | publication `deadline` | [`PublicationQos::deadline`] | DEADLINE offered; a miss is a [`SessionEvent::OfferedDeadlineMissed`](crate::SessionEvent::OfferedDeadlineMissed) |
//! | — | [`SubscriptionQos::liveliness`] | LIVELINESS requested; each matched writer that offers a lease is tracked: [`SessionEvent::LivelinessChanged`](crate::SessionEvent::LivelinessChanged) when it matches, when its lease lapses, when it asserts itself again and when it leaves |
//! | — | [`PublicationQos::liveliness`] | LIVELINESS offered, kept by [participant messages](courier_wire::rtps::participant::ParticipantMessage) (automatic), writes and [`Publisher::assert_liveliness`](crate::Publisher::assert_liveliness) (manual); a manual lease that lapses is a [`SessionEvent::LivelinessLost`](crate::SessionEvent::LivelinessLost) |
//! | subscription `minimumSeparation` | [`SubscriptionQos::minimum_separation`] | TIME_BASED_FILTER |
//! | `BEST_EFFORTS` / `STRICT_RELIABLE` | [`Reliability`] | RELIABILITY |
//! | — | [`Durability::TransientLocal`] | DURABILITY: late joiners get the history |
//! | `sendQueueSize` / `recvQueueSize` | [`History`] | HISTORY keep-last(n) / keep-all |
//! | — | [`DataRepresentation`] | DATA_REPRESENTATION: XCDR1 or XCDR2 on the wire |
//! | — | [`PublicationQos::autodispose`] | WRITER_DATA_LIFECYCLE `autodispose_unregistered_instances` |
//!
//! # Data representation
//!
//! A publication writes one representation and announces it; a
//! subscription announces the ones it accepts, and decodes each sample by
//! its encapsulation header. By default a publication writes what its type
//! calls for, as Cyclone DDS does: XCDR1 for a final type (which Fast DDS
//! 2.9, that speaks nothing else, then reads), XCDR2 for an appendable or
//! mutable one (`#[ipc(extensibility = "...")]`); a subscription accepts
//! both. A writer and a reader match only when the reader accepts what the
//! writer writes; when they do not, the
//! [`SessionEvent::IncompatibleQos`](crate::SessionEvent::IncompatibleQos)
//! names both sides' representations.
//!
//! # Liveliness
//!
//! A publication offers a [`Liveliness`]: a kind and a lease within which
//! it promises to show it is alive. [`LivelinessKind::Automatic`]: the
//! session does it (Courier sends a participant message every third of
//! the shortest automatic lease of its publications); a stopped or
//! disconnected process lapses. [`LivelinessKind::ManualByParticipant`]:
//! any write of the session, [`Publisher::assert_liveliness`](crate::Publisher::assert_liveliness)
//! of any such publication, or [`Session::assert_liveliness`](crate::Session::assert_liveliness)
//! asserts them all.
//! [`LivelinessKind::ManualByTopic`]: only the publication's own writes and
//! assertions count. A subscription that requests a liveliness (a kind at
//! least as strict as the writer's, a lease at least as long) matches
//! only writers that offer as much, and reports each one's liveliness
//! (DDS's LIVELINESS_CHANGED) with the writer's GUID: a robot can tell
//! that the lidar driver's writer stopped while its participant is still
//! known. Without a liveliness (the default) a publication offers
//! automatic with an infinite lease, and a subscription tracks nothing.
//! A lease under [`MIN_LEASE`] or longer than RTPS can say is refused
//! ([`OpenError::Qos`](crate::OpenError::Qos)). The RTPS backend has all
//! of it. On XRCE a publication may offer a liveliness with
//! `representation=xml` (the agent's DDS writer offers it; its writes of
//! the session's samples assert a manual one, there is no
//! `assert_liveliness` and no `LivelinessLost`: DDS-XRCE carries neither),
//! and a subscription cannot request one. Elsewhere, and where these say
//! no, opening with one fails with
//! [`OpenError::Unsupported`](crate::OpenError::Unsupported).
//!
//! On the IPC backends only the parts with an IPC meaning apply: IPC over
//! TCP is reliable, volatile and keeps everything, which also satisfies a
//! best-effort request, and a subscription's keep-last history is its local
//! queue policy. Any other setting (durability, deadline, strength,
//! lifespan, minimum separation, exclusive ownership, partitions, a
//! publication's keep-last history) cannot be honoured there, and creating
//! the publication or subscription fails with
//! [`OpenError::Unsupported`](crate::OpenError::Unsupported) naming
//! it: never silently ignored.

use std::time::Duration;

/// The shortest deadline: below it `DeadlineMissed` would fire without
/// pause (a zero deadline did, thousands of events a second and a core).
pub const MIN_DEADLINE: Duration = Duration::from_millis(1);

/// The shortest liveliness lease: below it a writer would lapse without
/// pause.
pub const MIN_LEASE: Duration = Duration::from_millis(1);

/// LIVELINESS kind: what shows that a writer is alive (DDS 1.4 §2.2.3.11).
/// A reader requesting a kind matches writers offering it or a stricter
/// one (automatic < manual by participant < manual by topic).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum LivelinessKind {
    /// The session asserts it while it runs (participant messages).
    #[default]
    Automatic,
    /// Any write or assertion of any such publication of the session.
    ManualByParticipant,
    /// The publication's own writes and assertions.
    ManualByTopic,
}

/// LIVELINESS: a kind and a lease (see the [module docs](self#liveliness)).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Liveliness {
    /// What asserts it.
    pub kind: LivelinessKind,
    /// How long an assertion lasts (writers: offered; readers: the longest
    /// lease a writer may offer).
    pub lease: Duration,
}

impl Liveliness {
    /// `kind` with `lease`.
    pub fn new(kind: LivelinessKind, lease: Duration) -> Self {
        Liveliness { kind, lease }
    }
}

/// Why a liveliness cannot work, if so.
pub(crate) fn check_liveliness(topic: &str, l: Option<Liveliness>) -> Result<(), crate::OpenError> {
    let Some(l) = l else { return Ok(()) };
    let why = if l.lease < MIN_LEASE {
        format!(
            "a liveliness lease of {:?} is under {MIN_LEASE:?}: the writer would lapse without pause",
            l.lease
        )
    } else if l.lease > MAX_WIRE {
        format!(
            "a liveliness lease of {:?} is longer than RTPS can say (about 68 years): leave \
             liveliness unset for an infinite lease",
            l.lease
        )
    } else {
        return Ok(());
    };
    Err(crate::OpenError::Qos {
        topic: topic.to_string(),
        why,
    })
}

/// The longest finite duration RTPS carries (`i32::MAX` seconds, about 68
/// years); longer is "infinite" on the wire.
const MAX_WIRE: Duration = Duration::from_secs(i32::MAX as u64);

/// A keep-last history of 0 samples keeps nothing (DDS's
/// INCONSISTENT_POLICY); it was taken as 1, silently.
pub(crate) fn check_history(topic: &str, h: History) -> Result<(), crate::OpenError> {
    if h == History::KeepLast(0) {
        return Err(crate::OpenError::Qos {
            topic: topic.to_string(),
            why: "keep_last(0) keeps nothing: give 1 or more (or keep_all)".into(),
        });
    }
    Ok(())
}

/// Why a deadline and a minimum separation cannot work together, if so.
pub(crate) fn check_timing(
    deadline: Option<Duration>,
    minimum_separation: Option<Duration>,
) -> Result<(), String> {
    if let Some(d) = deadline.filter(|d| *d < MIN_DEADLINE) {
        return Err(format!(
            "a deadline of {d:?} is under {MIN_DEADLINE:?}: it would be missed without pause"
        ));
    }
    if let Some(s) = minimum_separation {
        if s > MAX_WIRE {
            return Err(format!(
                "a minimum separation of {s:?} is longer than RTPS can say (about 68 years): \
                 it would mean no separation at all"
            ));
        }
        if let Some(d) = deadline.filter(|d| s > *d) {
            return Err(format!(
                "the minimum separation {s:?} is longer than the deadline {d:?}: every \
                 deadline would be missed (DDS's INCONSISTENT_POLICY)"
            ));
        }
    }
    Ok(())
}

/// Reliability.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum Reliability {
    /// Samples may be lost; nothing is repaired (ORTE `BEST_EFFORTS`).
    BestEffort,
    /// Every sample is delivered in order, repaired by the protocol (ORTE
    /// `STRICT_RELIABLE`).
    #[default]
    Reliable,
}

/// Durability.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum Durability {
    /// Only readers present when a sample is written get it.
    #[default]
    Volatile,
    /// The writer keeps its history for readers that join later.
    TransientLocal,
}

/// History kept per instance (writers: for repair and late joiners;
/// readers: before the application takes samples).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum History {
    /// The newest `n` samples.
    KeepLast(u32),
    /// Everything, within resource limits (writers then wait for
    /// acknowledgements before writing more).
    #[default]
    KeepAll,
}

/// How samples are serialized on the wire (DDS-XTypes 1.3 §7.6.3.1.1,
/// `DataRepresentationQosPolicy`); see the [module docs](self#data-representation).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum DataRepresentation {
    /// XCDR version 1 (`XCDR_DATA_REPRESENTATION`, id 0): plain CDR, and
    /// a parameter list for mutable types. The only one Fast DDS 2.9 speaks.
    Xcdr1,
    /// XCDR version 2 (`XCDR2_DATA_REPRESENTATION`, id 2): `DHEADER`s for
    /// appendable types, `EMHEADER`s for mutable ones, 4-byte alignment at
    /// most. What Cyclone DDS 11 writes for appendable and mutable types.
    Xcdr2,
}

impl DataRepresentation {
    /// What a type of this extensibility is written as unless asked
    /// otherwise: XCDR1 when final, XCDR2 when appendable or mutable.
    pub fn default_for(ext: courier_wire::cdr::Extensibility) -> Self {
        match ext {
            courier_wire::cdr::Extensibility::Final => DataRepresentation::Xcdr1,
            _ => DataRepresentation::Xcdr2,
        }
    }

    /// The `DataRepresentationId_t` announced on the wire.
    pub fn id(self) -> i16 {
        match self {
            DataRepresentation::Xcdr1 => 0,
            DataRepresentation::Xcdr2 => 2,
        }
    }

    /// The little-endian CDR encoding of this representation.
    pub fn encoding(self) -> courier_wire::cdr::Encoding {
        match self {
            DataRepresentation::Xcdr1 => courier_wire::cdr::Encoding::Xcdr1Le,
            DataRepresentation::Xcdr2 => courier_wire::cdr::Encoding::Xcdr2Le,
        }
    }
}

impl std::fmt::Display for DataRepresentation {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            DataRepresentation::Xcdr1 => "XCDR1",
            DataRepresentation::Xcdr2 => "XCDR2",
        })
    }
}

/// QoS of a publication (a DDS DataWriter).
#[derive(Debug, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub struct PublicationQos {
    /// Reliable by default.
    pub reliability: Reliability,
    /// Volatile by default.
    pub durability: Durability,
    /// Keep-all by default (no sample overwritten before it is acknowledged).
    pub history: History,
    /// ORTE's strength: `Some` makes the publication exclusive (DDS
    /// exclusive ownership) with this strength; readers that ask for
    /// exclusive ownership take each instance from the strongest live writer.
    pub strength: Option<i32>,
    /// ORTE's persistence (DDS lifespan): how long a sample stays valid.
    pub persistence: Option<Duration>,
    /// The period within which the writer promises a new sample per
    /// instance; a reader asking for a shorter one does not match. Each
    /// period an instance goes unwritten is a
    /// [`SessionEvent::OfferedDeadlineMissed`](crate::SessionEvent::OfferedDeadlineMissed).
    pub deadline: Option<Duration>,
    /// The liveliness offered (`None`, the default: automatic, infinite
    /// lease); see the [module docs](self#liveliness).
    pub liveliness: Option<Liveliness>,
    /// DDS partitions (none = the default partition).
    pub partitions: Vec<String>,
    /// What the publication writes; `None` (the default): what the type
    /// calls for ([`DataRepresentation::default_for`]).
    pub data_representation: Option<DataRepresentation>,
    /// Closing the publication disposes the instances it wrote and did
    /// not dispose or unregister, and an unregister disposes too (DDS's
    /// `autodispose_unregistered_instances`, true by default); false
    /// unregisters only (its readers see the instances
    /// not-alive-no-writers).
    pub autodispose: bool,
}

impl Default for PublicationQos {
    fn default() -> Self {
        PublicationQos {
            reliability: Reliability::default(),
            durability: Durability::default(),
            history: History::default(),
            strength: None,
            persistence: None,
            deadline: None,
            liveliness: None,
            partitions: Vec::new(),
            data_representation: None,
            autodispose: true,
        }
    }
}

impl PublicationQos {
    /// Reliable, volatile, keep-all, the type's representation, instances
    /// disposed when closed.
    pub fn new() -> Self {
        Self::default()
    }

    /// The representation written for a type of extensibility `ext`.
    pub fn representation_for(&self, ext: courier_wire::cdr::Extensibility) -> DataRepresentation {
        self.data_representation
            .unwrap_or_else(|| DataRepresentation::default_for(ext))
    }

    /// The first setting an IPC publication cannot honour.
    pub(crate) fn beyond_ipc(&self) -> Option<&'static str> {
        if self.durability != Durability::Volatile {
            Some("transient-local durability")
        } else if self.history != History::KeepAll {
            Some("a keep-last writer history")
        } else if self.strength.is_some() {
            Some("strength (exclusive ownership)")
        } else if self.persistence.is_some() {
            Some("persistence (lifespan)")
        } else if self.deadline.is_some() {
            Some("a deadline")
        } else if self.liveliness.is_some() {
            Some("liveliness")
        } else if !self.partitions.is_empty() {
            Some("partitions")
        } else if self.data_representation.is_some() {
            Some("a data representation (IPC has its own encoding)")
        } else {
            None
        }
    }
}

/// QoS of a subscription (a DDS DataReader).
#[derive(Debug, Clone, PartialEq, Eq, Default)]
#[non_exhaustive]
pub struct SubscriptionQos {
    /// Reliable by default.
    pub reliability: Reliability,
    /// Volatile by default; transient-local asks writers for their history.
    pub durability: Durability,
    /// Keep-all by default.
    pub history: History,
    /// Expect a sample at least this often; each miss gives
    /// [`SessionEvent::DeadlineMissed`](crate::SessionEvent::DeadlineMissed).
    pub deadline: Option<Duration>,
    /// The liveliness requested (`None`, the default: any, and nothing
    /// tracked); each matched writer offering a finite lease is tracked
    /// ([`SessionEvent::LivelinessChanged`](crate::SessionEvent::LivelinessChanged));
    /// see the [module docs](self#liveliness).
    pub liveliness: Option<Liveliness>,
    /// Deliver at most one sample per instance within this time (ORTE's
    /// minimum separation; DDS time-based filter). Others are dropped and counted.
    pub minimum_separation: Option<Duration>,
    /// Take each instance only from the strongest writer (DDS exclusive ownership).
    pub exclusive: bool,
    /// DDS partitions (none = the default partition).
    pub partitions: Vec<String>,
    /// The representations accepted, in order of preference; empty (the
    /// default): XCDR1 and XCDR2.
    pub data_representation: Vec<DataRepresentation>,
}

impl SubscriptionQos {
    /// Reliable, volatile, keep-all.
    pub fn new() -> Self {
        Self::default()
    }

    /// The first setting an IPC subscription cannot honour (keep-last is
    /// its local queue policy).
    pub(crate) fn beyond_ipc(&self) -> Option<&'static str> {
        if self.durability != Durability::Volatile {
            Some("transient-local durability")
        } else if self.deadline.is_some() {
            Some("a deadline")
        } else if self.liveliness.is_some() {
            Some("liveliness")
        } else if self.minimum_separation.is_some() {
            Some("minimum separation (time-based filter)")
        } else if self.exclusive {
            Some("exclusive ownership")
        } else if !self.partitions.is_empty() {
            Some("partitions")
        } else if !self.data_representation.is_empty() {
            Some("a data representation (IPC has its own encoding)")
        } else {
            None
        }
    }

    /// The representations accepted: [`SubscriptionQos::data_representation`],
    /// or XCDR1 and XCDR2 when it is empty.
    pub fn accepted_representations(&self) -> Vec<DataRepresentation> {
        if self.data_representation.is_empty() {
            vec![DataRepresentation::Xcdr1, DataRepresentation::Xcdr2]
        } else {
            self.data_representation.clone()
        }
    }
}

/// What a backend needs to know of a keyed type's instances, from encoded
/// bytes alone.
#[derive(Clone, Copy)]
pub struct KeyOf {
    /// The serialized key (with encapsulation header, in the sample's own
    /// encoding) of the instance an encoded sample belongs to, or `None` if
    /// it does not decode: what a backend needs to dispose the instances a
    /// publication leaves behind ([`PublicationQos::autodispose`]).
    pub key: fn(&[u8]) -> Option<Vec<u8>>,
    /// The DDS key hashes of received payloads, in either XCDR version
    /// ([`courier_wire::dds::InstanceKeys`]): how a reader tells the
    /// instances of a writer that sends no key hash apart (Cyclone DDS 11
    /// sends none), and names one instance alike when writers of
    /// different XCDR versions name it apart (their key hashes differ for
    /// some keys).
    pub instances: courier_wire::dds::InstanceKeys,
}

impl std::fmt::Debug for KeyOf {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("KeyOf(..)")
    }
}

impl PartialEq for KeyOf {
    /// Always equal: the key functions of a type follow from the type,
    /// which [`TypeInfo`]'s other fields name.
    fn eq(&self, _: &Self) -> bool {
        true
    }
}

impl Eq for KeyOf {}

/// The serialized key of a CDR sample of `T` (see [`KeyOf`]).
fn key_of<T: courier_wire::IpcMessage>(sample: &[u8]) -> Option<Vec<u8>> {
    use courier_wire::cdr;
    let v = cdr::from_slice::<T>(sample).ok()?;
    let enc = cdr::Reader::with_header(sample).ok()?.encoding();
    Some(cdr::key_to_vec(&v, enc))
}

/// What the typed layer knows about a message's Rust type.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TypeInfo {
    /// The IPC format string, when the type has one.
    pub format: Option<&'static str>,
    /// The DDS type name (`#[ipc(type_name = "...")]`).
    pub type_name: &'static str,
    /// The type has key fields (a keyed DDS topic).
    pub keyed: bool,
    /// Its CDR extensibility (which representation it is written in by default).
    pub extensibility: courier_wire::cdr::Extensibility,
    /// For a keyed type: the key and key hash of encoded samples.
    pub key_of: Option<KeyOf>,
}

impl TypeInfo {
    /// The information of `T`.
    pub fn of<T: courier_wire::IpcMessage>() -> Self {
        let keyed = !T::KEYS.is_empty();
        TypeInfo {
            format: Some(T::FORMAT),
            type_name: T::TYPE_NAME,
            keyed,
            extensibility: T::EXTENSIBILITY,
            key_of: keyed.then_some(KeyOf {
                key: key_of::<T>,
                instances: courier_wire::dds::InstanceKeys::of::<T>(),
            }),
        }
    }

    /// A final type without keys known only by its DDS type name and
    /// layout (an IPC format string): what tools that encode dynamic values
    /// (the `courier` CLI) publish and query with.
    pub const fn dynamic(format: Option<&'static str>, type_name: &'static str) -> Self {
        TypeInfo {
            format,
            type_name,
            keyed: false,
            extensibility: courier_wire::cdr::Extensibility::Final,
            key_of: None,
        }
    }

    /// No type: raw bytes of a message whose type the backend does not
    /// need (IPC: somebody else defined it) or learns (DDS subscriptions).
    pub fn untyped() -> Self {
        TypeInfo {
            format: None,
            type_name: "",
            keyed: false,
            extensibility: courier_wire::cdr::Extensibility::Final,
            key_of: None,
        }
    }

    /// Whether this is [`TypeInfo::untyped`].
    pub fn is_untyped(&self) -> bool {
        self.format.is_none() && self.type_name.is_empty()
    }
}

/// What a change does to its instance.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum InstanceState {
    /// A sample with data.
    #[default]
    Alive,
    /// The instance was disposed (its data carries only the key, if
    /// anything): by a writer, or, for a deleted writer that leaves its
    /// autodispose to the readers (Cyclone DDS), by the subscription.
    Disposed,
    /// No live writer has the instance any more (DDS's
    /// NOT_ALIVE_NO_WRITERS): its last writer unregistered it, or went
    /// without a word for it (deleted, its participant lost, or, for a
    /// subscription that tracks liveliness, its lease lapsed). A later
    /// sample makes it alive again.
    Unregistered,
}
