//! What the backend's handles ask of the driver.

use std::sync::Arc;
use std::time::{Duration, Instant};

use courier_wire::dds::{RequestId, ServiceId};

use crate::backend::{ClientId, Handle, PubId, SubId};
use courier_wire::rtps::participant::ChangeKind;
use tokio::sync::{mpsc, oneshot, OwnedSemaphorePermit};

use crate::error::{ControlError, Failure, OpenError, PublishError};
use crate::qos::{PublicationQos, SubscriptionQos, TypeInfo};
use crate::session::{QueryError, RawReply, RawRequest, SampleQueue};

pub(super) fn disconnected<E: Failure>() -> E {
    E::disconnected("the RTPS participant (session closed)".into())
}

pub(super) type Reply<T, E> = oneshot::Sender<Result<T, E>>;

/// How the driver tells a publisher that a write is done.
pub(super) enum Done {
    /// The publisher waits for the result (confirmed writes, first writes).
    Reply(Reply<(), PublishError>),
    /// The publisher went on once the write was queued; the permit it holds
    /// is its share of [`QUEUED_WRITE_UNITS`], given back when the write
    /// enters the writer's history.
    Queued(OwnedSemaphorePermit),
    /// Nobody waits (the disposes of a publication that closes).
    Ignored,
}

impl Done {
    pub(super) fn send(self, r: Result<(), PublishError>) {
        match self {
            Done::Reply(tx) => {
                let _ = tx.send(r);
            }
            Done::Queued(_permit) => {
                if let Err(e) = r {
                    tracing::warn!("a queued write failed: {e}");
                }
            }
            Done::Ignored => {
                if let Err(e) = r {
                    tracing::warn!("a dispose of a closing publication failed: {e}");
                }
            }
        }
    }
}

/// Bytes of writes queued for the driver (not yet in a writer's history)
/// at most, in units of [`QUEUED_WRITE_UNIT`] bytes: `publish().await`
/// returns as soon as its write is queued, so that the driver can pack a
/// burst of writes into one datagram, and waits while this much is queued
/// (back-pressure from a full keep-all history reaches the publisher here).
pub(super) const QUEUED_WRITE_UNITS: usize = 16 * 1024;
pub(super) const QUEUED_WRITE_UNIT: usize = 64;

/// A write's share of the queue budget (at least one unit, at most all).
pub(super) fn queued_units(len: usize) -> u32 {
    let units = len.div_ceil(QUEUED_WRITE_UNIT).clamp(1, QUEUED_WRITE_UNITS);
    u32::try_from(units).unwrap_or(u32::MAX)
}

pub(super) enum Cmd {
    // (the rare commands box their bulk: every write moves a `Cmd`)
    Publication {
        topic: String,
        ty: Box<TypeInfo>,
        qos: Box<PublicationQos>,
        reply: Reply<PubId, OpenError>,
    },
    Subscription {
        topic: String,
        ty: Option<Box<TypeInfo>>,
        qos: Box<SubscriptionQos>,
        queue: Arc<SampleQueue>,
        reply: Reply<SubId, OpenError>,
    },
    Pattern {
        topic: String,
        type_name: String,
        queue: Arc<SampleQueue>,
        reply: Reply<SubId, OpenError>,
    },
    Write {
        publication: PubId,
        kind: ChangeKind,
        data: Vec<u8>,
        key_hash: Option<[u8; 16]>,
        confirm: Option<Duration>,
        done: Done,
        /// When the application wrote it, if it waited before it was
        /// sent here (its source timestamp); `None`: when it arrives.
        written: Option<Instant>,
    },
    ModuleConnected {
        name: String,
        reply: Reply<bool, ControlError>,
    },
    AssertLiveliness {
        publication: PubId,
        reply: Reply<(), PublishError>,
    },
    AssertParticipantLiveliness {
        reply: Reply<(), PublishError>,
    },
    NumHandlers {
        topic: String,
        reply: Reply<i32, ControlError>,
    },
    ReadersOf {
        topic: String,
        reply: Reply<Vec<crate::EndpointInfo>, ControlError>,
    },
    Watch {
        topic: String,
    },
    Close {
        reply: oneshot::Sender<()>,
    },
    Client {
        name: String,
        req: Box<TypeInfo>,
        resp: Box<TypeInfo>,
        reply: Reply<ClientId, OpenError>,
    },
    Query {
        client: ClientId,
        data: Vec<u8>,
        timeout: Duration,
        reply: oneshot::Sender<Result<RawReply, QueryError>>,
    },
    Serve {
        name: String,
        req: Box<TypeInfo>,
        resp: Box<TypeInfo>,
        tx: mpsc::Sender<RawRequest>,
        reply: Reply<crate::backend::ServiceId, OpenError>,
    },
    /// The ROS 2 nodes known (see [`super::ros2`]).
    Ros2Nodes {
        reply: Reply<Vec<super::ros2::Ros2Node>, ControlError>,
    },
    /// A handle the application closed (dropped).
    CloseHandle(Handle),
    Respond {
        service: ServiceId,
        data: Vec<u8>,
        request: RequestId,
    },
}

impl Cmd {
    /// A write that is not confirmed and holds its share of the queue
    /// budget until it enters the writer's history.
    pub(super) fn queued_write(
        publication: PubId,
        data: Vec<u8>,
        key_hash: Option<[u8; 16]>,
        permit: OwnedSemaphorePermit,
    ) -> Cmd {
        Cmd::Write {
            publication,
            kind: ChangeKind::Alive,
            data,
            key_hash,
            confirm: None,
            done: Done::Queued(permit),
            written: None,
        }
    }
}
