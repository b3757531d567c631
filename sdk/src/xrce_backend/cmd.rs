//! The commands the backend's methods send its driver.

use std::sync::Arc;
use std::time::Duration;

use courier_wire::xrce::SampleIdentity;
use tokio::sync::{mpsc, oneshot};

use crate::backend::{ClientId, Handle, PubId, ServiceId, SubId, TimeSync};
use crate::error::{ControlError, OpenError, PublishError, QueryError};
use crate::qos::{PublicationQos, SubscriptionQos, TypeInfo};
use crate::session::{RawReply, RawRequest, SampleQueue};

pub(super) type Reply<T, E> = oneshot::Sender<Result<T, E>>;

/// What the driver is asked to do.
pub(super) enum Cmd {
    Publication {
        topic: String,
        ty: TypeInfo,
        qos: Box<PublicationQos>,
        reply: Reply<PubId, OpenError>,
    },
    Subscription {
        topic: String,
        ty: Option<TypeInfo>,
        qos: Box<SubscriptionQos>,
        queue: Arc<SampleQueue>,
        reply: Reply<SubId, OpenError>,
    },
    Service {
        name: String,
        req: TypeInfo,
        resp: TypeInfo,
        tx: mpsc::Sender<RawRequest>,
        reply: Reply<ServiceId, OpenError>,
    },
    Client {
        name: String,
        req: TypeInfo,
        resp: TypeInfo,
        reply: Reply<ClientId, OpenError>,
    },
    Write {
        publication: PubId,
        data: Vec<u8>,
        /// Answer once the agent has acknowledged it (else once queued).
        confirm: bool,
        reply: Reply<(), PublishError>,
    },
    Query {
        client: ClientId,
        data: Vec<u8>,
        reply: Reply<RawReply, QueryError>,
    },
    Respond {
        service: ServiceId,
        identity: SampleIdentity,
        data: Vec<u8>,
    },
    Ping {
        reply: Reply<Duration, ControlError>,
    },
    SyncTime {
        reply: Reply<TimeSync, ControlError>,
    },
    CloseHandle(Handle),
    Close {
        reply: oneshot::Sender<()>,
    },
}

impl Cmd {
    /// Whether the command needs the session and so waits, in order, while
    /// the agent is away.
    pub(super) fn needs_session(&self) -> bool {
        !matches!(
            self,
            Cmd::Ping { .. } | Cmd::SyncTime { .. } | Cmd::Close { .. }
        )
    }

    /// Fails the command: it waited longer than the bound for the agent.
    pub(super) fn expire(self, after: Duration) {
        self.fail("the XRCE agent (it did not come back in time)", Some(after));
    }

    /// Fails the command: the session ended.
    pub(super) fn closed(self) {
        self.fail("the XRCE agent (session closed)", None);
    }

    /// Answers the command with an error naming `gone`; a write that
    /// `expired_after` a bound is a timeout, and a close is simply done.
    fn fail(self, gone: &str, expired_after: Option<Duration>) {
        let gone = || gone.to_string();
        match self {
            Cmd::Publication { reply, .. } => {
                let _ = reply.send(Err(OpenError::Disconnected(gone())));
            }
            Cmd::Subscription { reply, .. } => {
                let _ = reply.send(Err(OpenError::Disconnected(gone())));
            }
            Cmd::Service { reply, .. } => {
                let _ = reply.send(Err(OpenError::Disconnected(gone())));
            }
            Cmd::Client { reply, .. } => {
                let _ = reply.send(Err(OpenError::Disconnected(gone())));
            }
            Cmd::Write { reply, .. } => {
                let _ = reply.send(Err(match expired_after {
                    Some(after) => PublishError::Timeout {
                        what: "waiting for the XRCE agent to take the sample".into(),
                        after,
                    },
                    None => PublishError::Disconnected(gone()),
                }));
            }
            Cmd::Query { reply, .. } => {
                let _ = reply.send(Err(QueryError::Disconnected(gone())));
            }
            Cmd::Ping { reply } => {
                let _ = reply.send(Err(ControlError::Disconnected(gone())));
            }
            Cmd::SyncTime { reply } => {
                let _ = reply.send(Err(ControlError::Disconnected(gone())));
            }
            Cmd::Respond { .. } => {
                if expired_after.is_some() {
                    tracing::warn!("XRCE: a reply is dropped: the agent did not come back in time")
                }
            }
            Cmd::Close { reply } => {
                if expired_after.is_none() {
                    let _ = reply.send(());
                }
            }
            Cmd::CloseHandle(_) => {}
        }
    }
}
