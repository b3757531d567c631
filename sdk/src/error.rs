//! One error type per operation, and [`Error`], which each converts into.
//!
//! Opening a publication, subscription, service or client fails with an
//! [`OpenError`]; a write (a publish, a reply, a dispose) with a
//! [`PublishError`]; a query with a [`QueryError`]; a backend-specific
//! control (`session.ipc()`, `session.dds()`) with a [`ControlError`]; a
//! subscription's stream yields [`RecvError`](crate::RecvError)s; connecting
//! fails with a [`ConnectError`](crate::ConnectError). Each is
//! `#[non_exhaustive]` and names the cause where it is known; the lower
//! layer's error is its [`source`](std::error::Error::source), which the
//! message does not repeat (print the chain, as `anyhow`'s `{:#}` does, to
//! see both).
//!
//! Code that does several of these and returns `Result<_, courier::Error>`
//! can use `?` on all of them:
//!
//! ```no_run
//! # async fn demo() -> Result<(), courier::Error> {
//! use courier::Session;
//! let s = Session::builder("ipc://127.0.0.1:1381").connect().await?; // ConnectError
//! let p = s.publisher::<i32>("count").build().await?;                 // OpenError
//! p.publish(&1).await?;                                                // PublishError
//! let n: i32 = s.query("double", &21i32).await?;                       // QueryError
//! # let _ = n; Ok(()) }
//! ```

use std::time::Duration;

use courier_wire::ipc::module::Error as CentralError;
use courier_wire::rtps::participant::{CreateError, WriteError};

use crate::session::{ConnectError, RecvError};

/// Why a publication, subscription, service or client could not be
/// opened (a message defined, a DDS endpoint created).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum OpenError {
    /// The connection is gone (central died, or the session was closed).
    #[error("disconnected from {0}")]
    Disconnected(String),
    /// A topic (IPC message) is used with another type than the one this
    /// session first used it with. Two types may share a topic only if they
    /// have the same IPC format and DDS type name.
    #[error("{msg} carries {bound} in this session, not {given}")]
    TypeMismatch {
        /// The topic.
        msg: String,
        /// The Rust type the topic was first used with.
        bound: &'static str,
        /// The Rust type of this use.
        given: &'static str,
    },
    /// The backend cannot honour what was asked (a DDS QoS setting on an
    /// IPC session, a reply message name on a DDS one, say).
    #[error("{what}: not available on {backend} sessions")]
    Unsupported {
        /// What was asked.
        what: String,
        /// The backend's URL scheme.
        backend: &'static str,
    },
    /// The session already publishes the topic with another DDS type.
    #[error("{msg} is already published in this session with type {existing}, not {given}")]
    TypeConflict {
        /// The topic.
        msg: String,
        /// The type name of the existing publication.
        existing: String,
        /// The type name asked for.
        given: String,
    },
    /// The session already serves this service.
    #[error("{0} is already served by this session")]
    AlreadyServed(String),
    /// IPC: central already holds the message with a format the type does
    /// not fit (another module defined it): defined or published as this
    /// type, its data would be read as wrong values there (C would replace
    /// the definition under that module's feet); subscribed as this type,
    /// every message would read as wrong values. Use the type it was
    /// defined with. `detail` gives the type's format and where the two
    /// differ.
    #[error(
        "central holds the format {central} for {msg} (defined by another module, or an \
         earlier run of this one), which {ty} does not fit: {detail}"
    )]
    FormatMismatch {
        /// The message.
        msg: String,
        /// The type used.
        ty: &'static str,
        /// Central's format of the message.
        central: String,
        /// Where they differ.
        detail: String,
    },
    /// IPC: two types of this session name different formats alike (two
    /// Rust types of one name in different modules): defining the second
    /// would change the first's messages.
    #[error(
        "the named format {name} is {existing} in this session, not {given}: give one of the two types its own name (#[ipc(name = \"...\")])"
    )]
    NamedFormatConflict {
        /// The format name.
        name: String,
        /// What the session defined it as.
        existing: String,
        /// What it was asked to define it as.
        given: String,
    },
    /// Central refused the definition or subscription.
    #[error("central refused {msg}")]
    Central {
        /// The message.
        msg: String,
        /// Central's answer.
        #[source]
        source: CentralError,
    },
    /// The XRCE agent refused to create an entity (its STATUS code named).
    #[error("the XRCE agent refused the {entity} of {topic}: {status}{hint}")]
    Refused {
        /// The topic (or service; for the participant, the session's name).
        topic: String,
        /// Which entity (`data writer`, `topic`, …).
        entity: &'static str,
        /// The agent's answer.
        status: courier_wire::xrce::StatusCode,
        /// What usually causes it, when the status says little (empty, or
        /// ` (…)`; with representation=reference, the profile looked up):
        /// a status carries no text.
        hint: String,
    },
    /// IPC: central did not answer within
    /// [`CENTRAL_ANSWER_TIMEOUT`](crate::CENTRAL_ANSWER_TIMEOUT) (a central that
    /// stopped answering, or held this module back that long).
    #[error("no answer to {what} within {after:?}")]
    Timeout {
        /// What was asked.
        what: String,
        /// The bound.
        after: Duration,
    },
    /// The XRCE agent did not answer the creation in time.
    #[error("the XRCE agent did not confirm the entities of {topic} within {after:?}")]
    NoAnswer {
        /// The topic (or service).
        topic: String,
        /// The bound.
        after: Duration,
    },
    /// The QoS cannot work as asked (a zero deadline, a minimum separation
    /// longer than the deadline or than RTPS can say).
    #[error("QoS of {topic}: {why}")]
    Qos {
        /// The topic.
        topic: String,
        /// What is wrong.
        why: String,
    },
    /// The topic (IPC message, service) name cannot be used: it is empty,
    /// or (DDS-XRCE) holds a NUL or is longer than DDS allows.
    #[error("bad name {}: {why}", shown_name(name))]
    BadName {
        /// The name.
        name: String,
        /// What is wrong with it.
        why: &'static str,
    },
    /// The DDS participant could not create the endpoint.
    #[error("cannot create a DDS endpoint of {topic}")]
    Endpoint {
        /// The topic (or service).
        topic: String,
        /// Why.
        #[source]
        source: CreateError,
    },
}

/// A name as an error shows it: quoted, and cut after 64 characters (a
/// name of 70 000 would fill a screen).
fn shown_name(name: &str) -> String {
    match name.char_indices().nth(64) {
        Some((cut, _)) => format!("{:?}… ({} bytes)", &name[..cut], name.len()),
        None => format!("{name:?}"),
    }
}

/// DDS's rule for topic and type names (Courier's participant enforces it
/// too): 1 to 256 bytes, no NUL. For XRCE sessions, whose agent would
/// answer a bare `STATUS_ERR_DDS_ERROR`.
pub(crate) fn dds_name(name: &str) -> Result<(), OpenError> {
    let why = if name.is_empty() {
        "a topic needs a name"
    } else if name.contains('\0') {
        "DDS names cannot hold a NUL"
    } else if name.len() > 256 {
        "DDS names are at most 256 bytes"
    } else {
        return Ok(());
    };
    Err(OpenError::BadName {
        name: name.to_string(),
        why,
    })
}

/// Why a write (publish, reply, dispose) failed.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum PublishError {
    /// The connection is gone (central died, or the session was closed).
    #[error("disconnected from {0}")]
    Disconnected(String),
    /// The publication a publish needed could not be opened.
    #[error(transparent)]
    Open(#[from] OpenError),
    /// The session has no publication of the topic.
    #[error("{0} has no publication in this session: create one with Session::publisher::<T>(..).build().await")]
    NoPublication(String),
    /// The publication handle was closed (its `Publisher` dropped).
    #[error("publication {0:?} is closed")]
    Closed(crate::backend::PubId),
    /// The backend cannot do this kind of write (a confirmed publish or an
    /// instance on IPC, a write that does not wait on IPC).
    #[error("{what}: not available on {backend} sessions")]
    Unsupported {
        /// What was asked.
        what: String,
        /// The backend's URL scheme.
        backend: &'static str,
    },
    /// Only keyed topics have instances to dispose or unregister.
    #[error("{0} has no key fields: only keyed topics have instances to dispose")]
    NotKeyed(&'static str),
    /// A write that must not wait found the session's write queue full.
    #[error("cannot publish {msg} without waiting: the session's write queue is full ({bytes} bytes wait for the participant)")]
    QueueFull {
        /// The topic.
        msg: String,
        /// The queue's bound.
        bytes: usize,
    },
    /// A `Vec` of the value is longer than its length field's type can say
    /// ([`IpcMessage::check_lengths`](courier_wire::IpcMessage::check_lengths)):
    /// nothing is sent, rather than fewer elements than the value has.
    #[error("cannot publish {msg}: {error}")]
    Length {
        /// The topic.
        msg: String,
        /// Which field, how long, and what its length field holds.
        error: courier_wire::LengthError,
    },
    /// The sample is larger than the transport can carry.
    #[error("cannot publish {msg}: a sample of {len} bytes is larger than {max}")]
    TooLarge {
        /// The topic.
        msg: String,
        /// The sample's size.
        len: usize,
        /// The largest possible.
        max: usize,
    },
    /// A confirmed write was not acknowledged in time.
    #[error("{what} did not complete within {after:?}")]
    Timeout {
        /// What was waited for.
        what: String,
        /// The bound.
        after: Duration,
    },
    /// The request was already answered.
    #[error("request already answered")]
    AlreadyAnswered,
    /// A publish's future was polled again after it completed.
    #[error("this publish already completed (its future was polled after it returned Ready)")]
    Completed,
    /// Central refused the message.
    #[error("central refused {msg}")]
    Central {
        /// The message.
        msg: String,
        /// Central's answer.
        #[source]
        source: CentralError,
    },
    /// The XRCE session refused the sample.
    #[error("cannot publish {topic} over XRCE")]
    Xrce {
        /// The topic.
        topic: String,
        /// Why.
        #[source]
        source: courier_wire::xrce::CommandError,
    },
    /// XRCE: the agent does not have this publication's data writer: it
    /// refused it when the session was re-created (a
    /// [`SessionEvent::EntityError`](crate::SessionEvent::EntityError) said
    /// so), or answered a write with an error (an agent restored from its
    /// state that could not make the writer again). Nothing is sent until
    /// the session is re-created and the agent takes it.
    #[error("cannot publish {topic}: the XRCE agent refused its {entity} ({status})")]
    AgentRefused {
        /// The topic.
        topic: String,
        /// Which entity.
        entity: &'static str,
        /// The agent's STATUS code.
        status: courier_wire::xrce::StatusCode,
    },
    /// The DDS writer refused the sample.
    #[error("cannot publish {topic}")]
    Writer {
        /// The topic.
        topic: String,
        /// Why.
        #[source]
        source: WriteError,
    },
    /// `unregister` of an instance this publication has not registered
    /// (never written or disposed, or unregistered already): DDS's
    /// `PRECONDITION_NOT_MET`. Nothing is sent.
    #[error("cannot unregister that instance of {topic}: this publication has not registered it (written or disposed), or unregistered it already")]
    NotRegistered {
        /// The topic.
        topic: String,
    },
    /// The function of a [`PeriodicPublication`](crate::PeriodicPublication)
    /// panicked, which ended it.
    #[error("the periodic publication of {msg} ended: its function panicked: {panic}")]
    Panicked {
        /// The topic.
        msg: String,
        /// The panic's message.
        panic: String,
    },
}

/// Why a query failed.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum QueryError {
    /// No reply within the timeout (IPC: central was answering; see
    /// [`QueryError::CentralSilent`]).
    #[error("no reply to {msg} within {timeout:?}")]
    Timeout {
        /// Query message.
        msg: String,
        /// The timeout.
        timeout: Duration,
    },
    /// No server of the query was found within the timeout (backends that
    /// can tell this apart from [`QueryError::Timeout`]; IPC: central
    /// counted no handler of the message when the wait ended, and keeps
    /// the query until one subscribes, as C's central does).
    #[error("nobody serves {msg} (waited {timeout:?})")]
    NoResponder {
        /// Query message.
        msg: String,
        /// The timeout.
        timeout: Duration,
    },
    /// No reply within the timeout, but replies came meanwhile that
    /// answered no open query: late replies to earlier queries that had
    /// timed out (a server that stalled and answered its backlog once it
    /// resumed), or a service that ties replies to requests another way
    /// (see [`ServiceStyle`](crate::ServiceStyle)).
    #[error(
        "no reply to {msg} within {timeout:?}; {replies} reply(ies) came that answered no open \
         query: late replies to earlier queries that had timed out (a server that stalled \
         answers them once it resumes), or a ROS 2 service of the other request/reply style \
         (see the `services` option)"
    )]
    Unmatched {
        /// Query message.
        msg: String,
        /// The timeout.
        timeout: Duration,
        /// Replies that matched nothing.
        replies: u64,
    },
    /// IPC: no reply within the timeout, and central did not answer a
    /// question of the session's own either: asked who serves the message
    /// `asked` before the end (a tenth of the timeout, at most 1 s), it
    /// said nothing. Central is stopped, overloaded or cut off, not (only)
    /// the server slow; [`QueryError::Timeout`] says central answered.
    #[error(
        "no reply to {msg} within {timeout:?}, and central did not answer either \
         (asked who serves it {asked:?} before the end): central is stopped, overloaded or cut off"
    )]
    CentralSilent {
        /// Query message.
        msg: String,
        /// The timeout.
        timeout: Duration,
        /// How long before the end central was asked.
        asked: Duration,
    },
    /// XRCE: no reply within the timeout, and the agent was not answering
    /// when it ended ([`SessionEvent::AgentLost`](crate::SessionEvent::AgentLost)).
    #[error("no reply to {msg} within {timeout:?}: the XRCE agent is not answering")]
    AgentLost {
        /// Query message.
        msg: String,
        /// The timeout.
        timeout: Duration,
    },
    /// No server of the query was found within the timeout, but one of
    /// other types was: its request or reply topic carries another type
    /// ([`SessionEvent::TypeMismatch`](crate::SessionEvent::TypeMismatch)
    /// names it too).
    #[error(
        "nobody serves {msg} with these types (waited {timeout:?}): {topic} carries {remote_type} there, {local_type} here"
    )]
    ServerTypeMismatch {
        /// Query message.
        msg: String,
        /// The timeout.
        timeout: Duration,
        /// The request or reply topic.
        topic: String,
        /// This side's type.
        local_type: String,
        /// The server's.
        remote_type: String,
    },
    /// The session ended before the reply.
    #[error("disconnected before {0} was answered")]
    Disconnected(String),
    /// DDS: every server the query went to left (closed its session or
    /// stopped serving) before it answered; no reply will come.
    #[error("the server of {0} left before it answered")]
    ServerLost(String),
    /// The query could not be sent.
    #[error("query {msg} could not be sent")]
    Refused {
        /// Query message.
        msg: String,
        /// Why.
        #[source]
        source: PublishError,
    },
    /// The query's client (or its message definition) could not be opened.
    #[error("query {msg} could not be opened")]
    Open {
        /// Query message.
        msg: String,
        /// Why.
        #[source]
        source: OpenError,
    },
    /// The reply is not the expected type.
    #[error("reply {reply} to {msg} is not a {ty}: {detail}")]
    Decode {
        /// Query message.
        msg: String,
        /// Reply message name.
        reply: String,
        /// Expected Rust type.
        ty: &'static str,
        /// The decoder's message.
        detail: String,
    },
}

/// Why a backend-specific control (`session.ipc()`, `session.dds()`)
/// failed.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum ControlError {
    /// The connection is gone (central died, or the session was closed).
    #[error("disconnected from {0}")]
    Disconnected(String),
    /// The session's backend has no such control (an IPC control on a DDS
    /// session, say).
    #[error("{what}: not available on {backend} sessions")]
    Unsupported {
        /// What was asked.
        what: String,
        /// The backend's URL scheme.
        backend: &'static str,
    },
    /// Central refused it.
    #[error("central refused {what}")]
    Central {
        /// What was asked.
        what: String,
        /// Central's answer.
        #[source]
        source: CentralError,
    },
    /// An argument out of its range (C's `IPC_Argument_Out_Of_Range`).
    #[error("{what}: {value} is out of range, it must be at least {min}")]
    OutOfRange {
        /// The call.
        what: String,
        /// The value given.
        value: i64,
        /// The least allowed.
        min: i64,
    },
    /// No answer within the bound (an XRCE ping or time sync).
    #[error("no answer to {what} within {after:?}")]
    Timeout {
        /// What was asked.
        what: String,
        /// The bound.
        after: Duration,
    },
}

/// What the backends make of a lost connection and of central's refusals,
/// for whichever operation's error.
pub(crate) trait Failure: Sized {
    /// The connection to `to` is gone.
    fn disconnected(to: String) -> Self;
    /// Central refused `what` (a closed connection is
    /// [`Failure::disconnected`]).
    fn central(what: &str, e: CentralError) -> Self;
}

macro_rules! failure {
    ($($t:ident),*) => {$(
        impl Failure for $t {
            fn disconnected(to: String) -> Self {
                $t::Disconnected(to)
            }
            fn central(what: &str, e: CentralError) -> Self {
                match e {
                    CentralError::Closed => $t::Disconnected("central".into()),
                    source => failure!(@central $t, what, source),
                }
            }
        }
    )*};
    (@central ControlError, $what:ident, $source:ident) => {
        ControlError::Central { what: $what.to_string(), source: $source }
    };
    (@central PublishError, $what:ident, $source:ident) => {
        match $source {
            CentralError::TooLarge { msg, len, max } => PublishError::TooLarge {
                msg,
                len,
                max: usize::try_from(max).unwrap_or(usize::MAX),
            },
            source => PublishError::Central { msg: $what.to_string(), source },
        }
    };
    (@central $t:ident, $what:ident, $source:ident) => {
        $t::Central { msg: $what.to_string(), source: $source }
    };
}
failure!(OpenError, PublishError, ControlError);

/// The errors of operations that wait for an answer, and give up.
pub(crate) trait TimedOut {
    /// No answer to `what` within `after`.
    fn timed_out(what: String, after: Duration) -> Self;
}

impl TimedOut for OpenError {
    fn timed_out(what: String, after: Duration) -> Self {
        OpenError::Timeout { what, after }
    }
}

impl TimedOut for ControlError {
    fn timed_out(what: String, after: Duration) -> Self {
        ControlError::Timeout { what, after }
    }
}

/// Any Courier error: each per-operation error converts into it, so that
/// `?` works across them in code returning `Result<_, courier::Error>`.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// Connecting failed.
    #[error(transparent)]
    Connect(#[from] ConnectError),
    /// Opening a publication, subscription, service or client failed.
    #[error(transparent)]
    Open(#[from] OpenError),
    /// A write failed.
    #[error(transparent)]
    Publish(#[from] PublishError),
    /// A query failed.
    #[error(transparent)]
    Query(#[from] QueryError),
    /// A subscription yielded an error.
    #[error(transparent)]
    Recv(#[from] RecvError),
    /// A backend-specific control failed.
    #[error(transparent)]
    Control(#[from] ControlError),
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::error::Error as _;

    #[test]
    fn question_mark_works_across_operations() {
        fn all(step: u8) -> Result<(), Error> {
            match step {
                0 => Err(OpenError::AlreadyServed("s".into()))?,
                1 => Err(PublishError::AlreadyAnswered)?,
                2 => Err(QueryError::Disconnected("q".into()))?,
                3 => Err(RecvError::Disconnected)?,
                _ => Err(ControlError::Disconnected("c".into()))?,
            }
        }
        for step in 0..5 {
            assert!(all(step).is_err());
        }
    }

    #[test]
    fn a_lower_layer_error_is_the_source_and_printed_once_by_chain_walkers() {
        let e = OpenError::Central {
            msg: "m".into(),
            source: CentralError::UnknownMessage("m".into()),
        };
        let source = e.source().expect("central's error").to_string();
        assert!(!e.to_string().contains(&source), "{e}");
        let p = PublishError::from(e.clone());
        // transparent: the same message and source as the OpenError
        assert_eq!(p.to_string(), e.to_string());
    }
}
