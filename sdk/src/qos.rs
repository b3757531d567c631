//! Quality of service for publications and subscriptions, in ORTE's terms
//! (strength, persistence, deadline, minimum separation, best effort or
//! strict reliable) mapped onto DDS QoS.
//!
//! | ORTE | Courier | DDS QoS on the wire |
//! |---|---|---|
//! | publication `strength` | [`PublicationQos::strength`] | OWNERSHIP exclusive + OWNERSHIP_STRENGTH |
//! | publication `persistence` | [`PublicationQos::persistence`] | LIFESPAN |
//! | subscription `deadline` | [`SubscriptionQos::deadline`] | DEADLINE; a miss is a [`SessionEvent::DeadlineMissed`](crate::SessionEvent::DeadlineMissed) |
//! | subscription `minimumSeparation` | [`SubscriptionQos::minimum_separation`] | TIME_BASED_FILTER |
//! | `BEST_EFFORTS` / `STRICT_RELIABLE` | [`Reliability`] | RELIABILITY |
//! | — | [`Durability::TransientLocal`] | DURABILITY: late joiners get the history |
//! | `sendQueueSize` / `recvQueueSize` | [`History`] | HISTORY keep-last(n) / keep-all |
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

/// QoS of a publication (a DDS DataWriter).
#[derive(Debug, Clone, PartialEq, Eq, Default)]
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
    /// The period within which the writer promises a new sample per instance.
    pub deadline: Option<Duration>,
    /// DDS partitions (none = the default partition).
    pub partitions: Vec<String>,
}

impl PublicationQos {
    /// Reliable, volatile, keep-all.
    pub fn new() -> Self {
        Self::default()
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
        } else if !self.partitions.is_empty() {
            Some("partitions")
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
    /// Deliver at most one sample per instance within this time (ORTE's
    /// minimum separation; DDS time-based filter). Others are dropped and counted.
    pub minimum_separation: Option<Duration>,
    /// Take each instance only from the strongest writer (DDS exclusive ownership).
    pub exclusive: bool,
    /// DDS partitions (none = the default partition).
    pub partitions: Vec<String>,
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
        } else if self.minimum_separation.is_some() {
            Some("minimum separation (time-based filter)")
        } else if self.exclusive {
            Some("exclusive ownership")
        } else if !self.partitions.is_empty() {
            Some("partitions")
        } else {
            None
        }
    }
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
}

impl TypeInfo {
    /// The information of `T`.
    pub fn of<T: courier_wire::IpcMessage>() -> Self {
        TypeInfo {
            format: Some(T::FORMAT),
            type_name: T::TYPE_NAME,
            keyed: !T::KEYS.is_empty(),
        }
    }

    /// No type: raw bytes of a message whose type the backend does not
    /// need (IPC: somebody else defined it) or learns (DDS subscriptions).
    pub fn untyped() -> Self {
        TypeInfo {
            format: None,
            type_name: "",
            keyed: false,
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
    /// The instance was disposed (its data carries only the key, if anything).
    Disposed,
    /// The writer unregistered the instance.
    Unregistered,
}
