//! The [`Backend`] trait behind every [`Session`](crate::Session): handles
//! in, bytes in and out, and backend-specific controls behind extension
//! traits ([`IpcControl`], [`DdsControl`]).
//!
//! A backend opens publications, subscriptions, services and clients and
//! hands back a handle for each ([`PubId`], [`SubId`], [`ServiceId`],
//! [`ClientId`]); every later operation names its handle, and
//! [`Backend::close_handle`] ends it. The typed layer closes a handle when
//! the user's `Publisher`, `Subscriber`, `Listener` or `Requests` is
//! dropped. What a backend can do beyond that is stated up front in its
//! [`Capabilities`] rather than discovered by calling a method it refuses.

use std::sync::Arc;
use std::time::Duration;

use courier_wire::ipc::introspect::{Answer, Ask};
use courier_wire::ipc::module::MsgInfo;
use tokio::sync::mpsc;

use crate::error::{ControlError, OpenError, PublishError, QueryError};
use crate::event::SessionEvent;
use crate::hub;
use crate::qos::{InstanceState, PublicationQos, SubscriptionQos, TypeInfo};
use crate::session::{Encoding, RawReply, RawRequest, SampleQueue, WriteOptions};

macro_rules! handle_id {
    ($(#[$doc:meta])* $name:ident) => {
        $(#[$doc])*
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
        pub struct $name(pub u64);
    };
}

handle_id!(
    /// A publication opened with [`Backend::open_publication`] (DDS: a
    /// DataWriter; IPC: a defined message).
    PubId
);
handle_id!(
    /// A subscription opened with [`Backend::open_subscription`] (or
    /// [`DdsControl::open_pattern`]).
    SubId
);
handle_id!(
    /// A service opened with [`Backend::open_service`].
    ServiceId
);
handle_id!(
    /// A client opened with [`Backend::open_client`].
    ClientId
);

/// Any handle, for [`Backend::close_handle`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum Handle {
    /// A publication.
    Publication(PubId),
    /// A subscription.
    Subscription(SubId),
    /// A service.
    Service(ServiceId),
    /// A client.
    Client(ClientId),
}

/// What a backend can do beyond the common operations.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub struct Capabilities {
    /// The URL scheme, for error messages (`"ipc://"`).
    pub scheme: &'static str,
    /// How typed values are encoded.
    pub encoding: Encoding,
    /// Keyed topics: instances, disposing and unregistering them.
    pub instances: bool,
    /// [`WriteOptions::confirm`]: waiting for every reader's acknowledgement.
    pub confirmed_writes: bool,
    /// [`DdsControl::open_pattern`].
    pub pattern_subscriptions: bool,
    /// The backend runs the handlers of immediate-delivery queues itself
    /// ([`SampleQueue::run_handler`]) as it delivers; otherwise the session
    /// runs each on a task of its own.
    pub immediate_delivery: bool,
    /// [`Backend::try_write`] works.
    pub try_write: bool,
    /// A publication may be opened without a type ([`TypeInfo::untyped`]):
    /// publishing a message somebody else defined (IPC).
    pub untyped_publications: bool,
    /// Replies may carry a message name of their own (IPC's
    /// `IPC_respond`); otherwise they travel on the service's reply topic.
    pub reply_names: bool,
    /// IPC named formats (`IPC_defineFormat`) come before a definition.
    pub named_formats: bool,
    /// DDS LIVELINESS on publications and subscriptions
    /// ([`DdsControl::assert_liveliness`]).
    pub liveliness: bool,
    /// DDS LIVELINESS offered by publications only (XRCE: the agent's DDS
    /// writer offers it; nothing is reported back, nothing asserted but
    /// by writes).
    pub offers_liveliness: bool,
}

impl Capabilities {
    /// A backend of `scheme` encoding values as `encoding`, with none of
    /// the optional capabilities (set the fields it has).
    pub fn new(scheme: &'static str, encoding: Encoding) -> Self {
        Capabilities {
            scheme,
            encoding,
            instances: false,
            confirmed_writes: false,
            pattern_subscriptions: false,
            immediate_delivery: false,
            try_write: false,
            untyped_publications: false,
            reply_names: false,
            liveliness: false,
            offers_liveliness: false,
            named_formats: false,
        }
    }
}

/// A pluggable transport working on handles: bytes in, bytes out, plus
/// type metadata. Object safe, so a `Session` holds an `Arc<dyn Backend>`.
///
/// Operations that wait are `async`; [`Backend::try_write`] and
/// [`Backend::close_handle`] never wait (they run in `Drop` and in
/// subscription callbacks).
#[async_trait::async_trait]
pub trait Backend: Send + Sync + std::fmt::Debug {
    /// What this backend can do.
    fn capabilities(&self) -> Capabilities;

    /// Opens a publication of `topic` with its type and QoS (IPC: defines
    /// the message, once however many publications share it; DDS: a
    /// DataWriter of its own for each).
    async fn open_publication(
        &self,
        topic: &str,
        ty: &TypeInfo,
        qos: &PublicationQos,
    ) -> Result<PubId, OpenError>;

    /// Opens a subscription of `topic`: samples go to `queue` until the
    /// handle is closed, and the queue is closed when the session ends.
    /// Without a type, the backend learns it (DDS) or does not need it (IPC).
    async fn open_subscription(
        &self,
        topic: &str,
        ty: Option<&TypeInfo>,
        qos: &SubscriptionQos,
        queue: Arc<SampleQueue>,
    ) -> Result<SubId, OpenError>;

    /// Serves queries of `name`: requests arrive on the returned channel
    /// (at most `queue` waiting) until the handle is closed; the channel
    /// closes when the session ends.
    async fn open_service(
        &self,
        name: &str,
        req: &TypeInfo,
        resp: &TypeInfo,
        queue: usize,
    ) -> Result<(ServiceId, mpsc::Receiver<RawRequest>), OpenError>;

    /// Opens a client of the service `name`, for [`Backend::query`].
    async fn open_client(
        &self,
        name: &str,
        req: &TypeInfo,
        resp: &TypeInfo,
    ) -> Result<ClientId, OpenError>;

    /// Publishes `data` on `publication`; resolves once handed to the
    /// transport (or, with [`WriteOptions::confirm`], acknowledged).
    async fn write(
        &self,
        publication: PubId,
        data: Vec<u8>,
        opts: WriteOptions,
    ) -> Result<(), PublishError>;

    /// The part of [`Backend::write`] that needs no waiting, if the write
    /// can be done that way now (the usual case: an open publication with
    /// room in its queue): called before `write` by every `publish().await`
    /// so that a publish that does not wait costs no boxed future. Gives
    /// the data back ([`WriteNow::Wait`]) for `write` otherwise; the
    /// default always does.
    fn write_now(&self, publication: PubId, data: Vec<u8>, opts: WriteOptions) -> WriteNow {
        let _ = publication;
        WriteNow::Wait(data, opts)
    }

    /// Publishes without waiting, from any thread (a subscription callback
    /// among them): queued or sent before it returns, or an error. The
    /// default refuses ([`Capabilities::try_write`] is false).
    fn try_write(
        &self,
        publication: PubId,
        data: Vec<u8>,
        opts: WriteOptions,
    ) -> Result<(), PublishError> {
        let _ = (publication, data, opts);
        Err(PublishError::Unsupported {
            what: "publishing without waiting (use publish().await)".into(),
            backend: self.capabilities().scheme,
        })
    }

    /// Sends a query through `client`; the reply's message name and bytes.
    async fn query(
        &self,
        client: ClientId,
        data: Vec<u8>,
        timeout: Duration,
    ) -> Result<RawReply, QueryError>;

    /// Ends a handle: unsubscribes, stops serving, deletes the writer or
    /// client. Never waits; closing a handle twice or after the session
    /// ended does nothing.
    fn close_handle(&self, handle: Handle);

    /// A stream of system events from the backend's [`hub::Hub`]: bounded,
    /// dropping (and counting) the oldest for a listener that falls
    /// behind; it ends when the session closes.
    fn events(&self) -> hub::Listener<SessionEvent>;

    /// Disconnects cleanly.
    async fn close(&self);

    /// The CMU IPC controls, on an IPC backend.
    fn ipc(&self) -> Option<&dyn IpcControl> {
        None
    }

    /// The DDS controls, on a DDS backend.
    fn dds(&self) -> Option<&dyn DdsControl> {
        None
    }

    /// The DDS-XRCE controls, on an XRCE backend.
    fn xrce(&self) -> Option<&dyn XrceControl> {
        None
    }
}

/// The agent's clock as a time sync measured it
/// ([`XrceControl::sync_time`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TimeSync {
    /// Agent time = local wall-clock time − `offset_ns` (DDS-XRCE's
    /// `((t0 + t3) − (t1 + t2)) / 2`, as eProsima's client computes it).
    pub offset_ns: i64,
    /// The round trip of the TIMESTAMP.
    pub rtt: Duration,
}

impl TimeSync {
    /// The agent's time at local wall-clock time `local`.
    pub fn agent_time(&self, local: std::time::SystemTime) -> std::time::SystemTime {
        let d = Duration::from_nanos(self.offset_ns.unsigned_abs());
        if self.offset_ns >= 0 {
            local.checked_sub(d).unwrap_or(local)
        } else {
            local.checked_add(d).unwrap_or(local)
        }
    }
}

/// Where an XRCE session stands ([`XrceControl::state`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum XrceState {
    /// The session exists and the agent answers.
    Connected,
    /// The agent is silent or lost the session; the session waits for it
    /// and creates itself again.
    Lost,
    /// The session ended.
    Closed,
}

/// What only a DDS-XRCE backend does ([`Session::xrce`](crate::Session::xrce)).
#[async_trait::async_trait]
pub trait XrceControl: Send + Sync {
    /// Pings the agent inside the session (`uxr_ping_agent_session`): the
    /// round trip, or [`ControlError::Timeout`].
    async fn ping(&self, timeout: Duration) -> Result<Duration, ControlError>;
    /// Measures the agent's clock offset (`uxr_sync_session`); the result
    /// is kept for [`XrceControl::time_offset`].
    async fn sync_time(&self, timeout: Duration) -> Result<TimeSync, ControlError>;
    /// The last time sync, if any (`session.time_offset`).
    fn time_offset(&self) -> Option<TimeSync>;
    /// The agent's time now by the last sync (`uxr_epoch_nanos`), or
    /// `None` before the first.
    fn agent_time(&self) -> Option<std::time::SystemTime> {
        self.time_offset()
            .map(|t| t.agent_time(std::time::SystemTime::now()))
    }
    /// Where the session stands.
    fn state(&self) -> XrceState;
    /// The client key the session uses.
    fn client_key(&self) -> u32;
}

/// What only a CMU IPC backend does ([`Session::ipc`](crate::Session::ipc)).
#[async_trait::async_trait]
pub trait IpcControl: Send + Sync {
    /// Registers a named format (`IPC_defineFormat`).
    async fn define_format(&self, name: &str, format: &str) -> Result<(), OpenError>;
    /// Defines a message with a format string given at run time
    /// (`IPC_defineMsg`; the typed API defines from the type instead).
    async fn define(&self, msg: &str, format: Option<&str>) -> Result<(), OpenError>;
    /// Whether a module of that name is connected (`IPC_isModuleConnected`).
    async fn is_module_connected(&self, module: &str) -> Result<bool, ControlError>;
    /// How many handlers subscribe `msg` (`IPC_numHandlers`).
    async fn num_handlers(&self, msg: &str) -> Result<i32, ControlError>;
    /// Reports handler-count changes of `msg` on the event streams
    /// (`IPC_subscribeHandlerChange`).
    async fn watch_handlers(&self, msg: &str) -> Result<(), ControlError>;
    /// How many messages central may deliver at once (`IPC_setCapacity`).
    async fn set_capacity(&self, n: i32) -> Result<(), ControlError>;
    /// Priority of `msg` in this module's pending queue (`IPC_setMsgPriority`).
    async fn set_priority(&self, msg: &str, priority: i32) -> Result<(), ControlError>;
    /// Most pending `msg` deliveries central keeps for this module, the
    /// oldest dropped (`IPC_setMsgQueueLength`).
    async fn set_queue_length(&self, msg: &str, n: i32) -> Result<(), ControlError>;
    /// Asks central about the other modules and messages (see
    /// [`courier_wire::ipc::introspect`]; [`Ipc::messages`],
    /// [`Ipc::message_details`] and [`Ipc::modules`] are the typed forms).
    ///
    /// [`Ipc::messages`]: crate::Ipc::messages
    /// [`Ipc::message_details`]: crate::Ipc::message_details
    /// [`Ipc::modules`]: crate::Ipc::modules
    async fn ask_central(&self, ask: Ask) -> Result<Answer, ControlError> {
        Err(ControlError::Unsupported {
            what: format!("ask_central({})", ask.message()),
            backend: "this backend",
        })
    }

    /// What central told this session about `msg` (C's `msgInfo`: its
    /// class and formats, the user's format as `res_format`), or `None`
    /// if the session has not looked `msg` up or central does not know it.
    ///
    /// The session looks a message up when it first publishes or queries
    /// it, at the first delivery of a subscription, for the message of a
    /// reply, and in [`IpcControl::watch_handlers`]; operations run in
    /// order, so once a later [`IpcControl::num_handlers`] of any message
    /// has answered, that lookup is done. Tools that handle messages whose
    /// type they learn at run time (`courier echo`) decode through it. The
    /// default says the backend has none.
    async fn message_info(&self, msg: &str) -> Result<Option<MsgInfo>, ControlError> {
        Err(ControlError::Unsupported {
            what: format!("message_info({msg})"),
            backend: "this backend",
        })
    }

    /// Looks `msg` up in central now (as a C module does before it first
    /// uses a message) and answers what central holds of it: `None` when
    /// central does not know it. Answered from this module's cache once
    /// looked up. The default says the backend has none.
    async fn look_up(&self, msg: &str) -> Result<Option<MsgInfo>, ControlError> {
        Err(ControlError::Unsupported {
            what: format!("look_up({msg})"),
            backend: "this backend",
        })
    }
}

/// What only a DDS backend does ([`Session::dds`](crate::Session::dds)).
#[async_trait::async_trait]
pub trait DdsControl: Send + Sync {
    /// Readers matched with this session's writers of `topic` (the most
    /// any one of them has), or, without a writer, the readers of it known.
    async fn matched_readers(&self, topic: &str) -> Result<i32, ControlError>;
    /// Reports [`SessionEvent::HandlersChanged`] when the readers matched
    /// with this session's writers of `topic` change.
    async fn watch_matches(&self, topic: &str) -> Result<(), ControlError>;
    /// Whether a participant with this entity name (or this session's own
    /// name) is known.
    async fn participant_named(&self, name: &str) -> Result<bool, ControlError>;
    /// The remote readers of `topic` known through discovery, matched with
    /// this session's writers or not (what a tool needs to write a topic
    /// the way its readers expect, e.g. keyed: [`EndpointInfo::keyed`]).
    ///
    /// [`EndpointInfo::keyed`]: crate::EndpointInfo::keyed
    async fn readers_of(&self, topic: &str) -> Result<Vec<crate::EndpointInfo>, ControlError> {
        Err(ControlError::Unsupported {
            what: format!("readers_of({topic})"),
            backend: "this backend",
        })
    }
    /// Asserts the liveliness of `publication` without writing (see
    /// [`Publisher::assert_liveliness`](crate::Publisher::assert_liveliness)).
    async fn assert_liveliness(&self, publication: PubId) -> Result<(), PublishError> {
        let _ = publication;
        Err(PublishError::Unsupported {
            what: "assert_liveliness".into(),
            backend: "this backend",
        })
    }
    /// Asserts the liveliness of every manual-by-participant publication of
    /// the session without writing (see
    /// [`Session::assert_liveliness`](crate::Session::assert_liveliness)).
    async fn assert_participant_liveliness(&self) -> Result<(), PublishError> {
        Err(PublishError::Unsupported {
            what: "assert_participant_liveliness".into(),
            backend: "this backend",
        })
    }
    /// Disposes or unregisters an instance written by `publication`;
    /// `key` is the serialized key (CDR with its encapsulation header),
    /// empty when the key hash alone names it.
    async fn end_instance(
        &self,
        publication: PubId,
        state: InstanceState,
        key: Vec<u8>,
        key_hash: [u8; 16],
    ) -> Result<(), PublishError>;
    /// The ROS 2 nodes known: this session's own (with
    /// [`RtpsOptions::ros2_node`](crate::RtpsOptions::ros2_node)) and
    /// every other participant's from its `ros_discovery_info` samples,
    /// each with its readers and writers resolved through discovery (see
    /// [`rtps_backend::ros2`](crate::rtps_backend::ros2)).
    /// [`ControlError::Unsupported`] unless the session reads the graph
    /// (`ros2_node` or `ros2_graph`).
    async fn ros2_nodes(&self) -> Result<Vec<crate::rtps_backend::Ros2Node>, ControlError>;
    /// Subscribes to every topic whose name and type name match the
    /// fnmatch patterns (ORTE's pattern subscriptions), now and as they are
    /// discovered; close it as a subscription.
    async fn open_pattern(
        &self,
        topic: &str,
        type_name: &str,
        queue: Arc<SampleQueue>,
    ) -> Result<SubId, OpenError>;
}

/// What [`Backend::write_now`] did.
#[derive(Debug)]
pub enum WriteNow {
    /// Written (or refused) without waiting.
    Done(Result<(), PublishError>),
    /// The write has to wait: do it with [`Backend::write`].
    Wait(Vec<u8>, WriteOptions),
}
