//! The async [`Session`] and its pluggable [`Backend`]s.
//!
//! A `Session` is one module's connection to a messaging system. The typed
//! layer (this module and the ones it re-exports from) encodes values with
//! [`IpcMessage`] and hands bytes to a [`Backend`];
//! [`crate::ipc_backend::IpcBackend`] speaks CMU IPC to a `central`
//! (Courier's or the C one).

use std::marker::PhantomData;
use std::pin::Pin;
use std::sync::Arc;
use std::task::{Context, Poll};
use std::time::Duration;

use courier_wire::ipc::introspect::{Answer, Ask, MessageDetails, ModuleDetails};
use courier_wire::{cdr, ipc, IpcMessage, NamedFormats};
use futures::Stream;

pub use crate::builder::{ConnectError, SessionBuilder};
pub use crate::error::{ControlError, OpenError, PublishError, QueryError};
pub use crate::event::SessionEvent;
use crate::ipc_backend::IpcOptions;
use crate::publisher::Target;
pub use crate::publisher::{
    PeriodicPublication, Publish, PublishFuture, Publisher, PublisherBuilder, WriteOptions,
};
use crate::qos::DataRepresentation;
pub use crate::qos::{InstanceState, PublicationQos, SubscriptionQos, TypeInfo};
pub(crate) use crate::queue::ReturnedBuffers;
pub use crate::queue::{QueuePolicy, RawSample, RawSubscriber, SampleQueue};
use crate::rpc::open_failed;
pub use crate::rpc::{Query, RawReply, RawRequest, RawRequests, Request, Requests};
pub use crate::subscriber::{
    Delivery, InstanceChange, Listener, Received, RecvError, Sample, Samples, Subscriber,
    SubscriberBuilder, WithInstances,
};
pub use crate::timer::{Tick, Timer};
use crate::topics::{Definition, Topics};

/// How a backend wants typed values encoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum Encoding {
    /// CMU IPC marshalling (`ipc::to_vec`).
    Ipc,
    /// OMG CDR (DDS backends).
    Cdr,
}

pub use crate::reply::{Reply, ReplyFuture, Responder};

pub use crate::backend::{
    Backend, Capabilities, ClientId, DdsControl, Handle, IpcControl, PubId, ServiceId, SubId,
    TimeSync, XrceControl, XrceState,
};

/// A handle the typed layer owns: closed when dropped. It keeps the
/// session's backend alive, as the crate's rules promise: a subscriber made
/// from a `Session` that was dropped (`connect().await?.subscribe(..)`)
/// still receives, and the session disconnects when the last of the
/// `Session` clones and their handles is gone.
pub(crate) struct Owned {
    pub(crate) backend: Option<Arc<dyn Backend>>,
    pub(crate) handle: Handle,
    /// The topics it binds to their types while it lives.
    pub(crate) uses: Vec<crate::topics::TopicUse>,
}

impl Owned {
    pub(crate) fn new(backend: &Arc<dyn Backend>, handle: Handle) -> Self {
        Owned {
            backend: Some(backend.clone()),
            handle,
            uses: Vec::new(),
        }
    }

    /// Keeps `topic` bound while the handle lives.
    pub(crate) fn binding(mut self, topic: crate::topics::TopicUse) -> Self {
        self.uses.push(topic);
        self
    }
}

impl std::fmt::Debug for Owned {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        self.handle.fmt(f)
    }
}

impl Drop for Owned {
    fn drop(&mut self) {
        if let Some(b) = &self.backend {
            b.close_handle(self.handle);
        }
    }
}

/// A request or reply encoded for the session's backend: CDR as XCDR1
/// whatever the type (what a service announces, and what ROS 2's RMWs
/// write; an XCDR1 appendable type is written as a final one).
pub(crate) fn encode_rpc<T: IpcMessage>(
    enc: Encoding,
    msg: &str,
    value: &T,
) -> Result<Vec<u8>, PublishError> {
    check_lengths(msg, value)?;
    Ok(match enc {
        Encoding::Ipc => ipc::to_vec(value),
        Encoding::Cdr => cdr::to_vec(value, cdr::Encoding::Xcdr1Le),
    })
}

/// Refuses a value a `Vec` of which is longer than its length field can
/// say (the encoders would send fewer elements than it has), or with a
/// `String` or `Vec` over its `#[ipc(bound = N)]`.
pub(crate) fn check_lengths<T: IpcMessage>(msg: &str, value: &T) -> Result<(), PublishError> {
    if T::CHECKS_LENGTHS {
        value
            .check_lengths()
            .map_err(|error| PublishError::Length {
                msg: msg.to_string(),
                error,
            })?;
    }
    Ok(())
}

pub(crate) fn decode<T: IpcMessage>(
    enc: Encoding,
    data: &[u8],
    order: ipc::ByteOrder,
) -> Result<T, String> {
    let value = match enc {
        Encoding::Ipc => ipc::from_slice_with_order::<T>(data, order).map_err(|e| e.to_string()),
        Encoding::Cdr => cdr::from_slice::<T>(data).map_err(|e| e.to_string()),
    }?;
    // a bounded `String` or `Vec` over its bound: refused, as a DDS reader
    // of the bounded type refuses it (a decoded `Vec` always fits its
    // length field, which it was read by)
    if T::CHECKS_LENGTHS {
        value.check_lengths().map_err(|e| e.to_string())?;
    }
    Ok(value)
}

/// One module's connection: publish, subscribe, query, serve, timers, events.
///
/// ```no_run
/// # async fn demo() -> Result<(), Box<dyn std::error::Error>> {
/// use courier::Session;
/// use futures::StreamExt;
/// let s = Session::builder("ipc://127.0.0.1:1381").name("module1").connect().await?;
/// s.define::<i32>("message1").await?;
/// let mut sub = s.subscribe::<i32>("message1").await?;
/// s.publish("message1", &42).await?;
/// let sample = sub.next().await.unwrap()?;
/// assert_eq!(sample.value, 42);
/// # Ok(()) }
/// ```
#[derive(Debug, Clone)]
pub struct Session {
    pub(crate) backend: Arc<dyn Backend>,
    pub(crate) caps: Capabilities,
    name: String,
    pub(crate) topics: Arc<Topics>,
    /// IPC: whether central's format of each message fits each type this
    /// session reads or writes it as.
    pub(crate) central_formats: Arc<crate::format_check::CentralFormats>,
    /// Whether its user closed it; ends its timers at the close.
    pub(crate) end: Arc<crate::session_end::SessionEnd>,
    /// The runtime it was made on, for calls from threads outside any.
    pub(crate) home: crate::home::Home,
}

impl Session {
    /// A builder for `url`: `ipc://host:port` (`ipc://` alone: `CENTRALHOST`,
    /// then localhost:1381) or `rtps://<domain>` with options as a query
    /// string (see [`RtpsOptions::from_url`]).
    ///
    /// [`RtpsOptions::from_url`]: crate::RtpsOptions::from_url
    pub fn builder(url: impl Into<String>) -> SessionBuilder {
        SessionBuilder {
            url: url.into(),
            name: None,
            opts: IpcOptions::default(),
            rtps: Default::default(),
            xrce: None,
            set: Vec::new(),
        }
    }

    /// A session over any backend.
    pub fn with_backend(backend: Arc<dyn Backend>, name: impl Into<String>) -> Self {
        Session {
            caps: backend.capabilities(),
            backend,
            name: name.into(),
            topics: Arc::default(),
            central_formats: Arc::default(),
            end: Arc::default(),
            home: crate::home::Home::here(),
        }
    }

    /// This module's name.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// The backend.
    pub fn backend(&self) -> &Arc<dyn Backend> {
        &self.backend
    }

    pub(crate) fn enc(&self) -> Encoding {
        self.caps.encoding
    }

    /// What the backend can do.
    pub fn capabilities(&self) -> Capabilities {
        self.caps
    }

    /// The CMU IPC controls (capacity, priorities, queue lengths, named
    /// formats, …); [`ControlError::Unsupported`] on other backends.
    pub fn ipc(&self) -> Result<Ipc<'_>, ControlError> {
        match self.backend.ipc() {
            Some(ctl) => Ok(Ipc { ctl }),
            None => Err(ControlError::Unsupported {
                what: "Session::ipc (CMU IPC's controls: IPC_setCapacity, IPC_setMsgPriority, \
                       IPC_setMsgQueueLength, IPC_defineFormat; no DDS equivalent: use the \
                       QoS of publishers and subscribers)"
                    .into(),
                backend: self.caps.scheme,
            }),
        }
    }

    /// The DDS controls (matched readers, participants, instances,
    /// pattern subscriptions); [`ControlError::Unsupported`] on other
    /// backends.
    pub fn dds(&self) -> Result<&dyn DdsControl, ControlError> {
        self.backend.dds().ok_or_else(|| ControlError::Unsupported {
            what: "Session::dds (the DDS controls)".into(),
            backend: self.caps.scheme,
        })
    }

    /// The DDS-XRCE controls (agent ping, time sync, session state);
    /// [`ControlError::Unsupported`] on other backends.
    pub fn xrce(&self) -> Result<&dyn XrceControl, ControlError> {
        self.backend
            .xrce()
            .ok_or_else(|| ControlError::Unsupported {
                what: "Session::xrce (the DDS-XRCE controls: agent ping, time sync)".into(),
                backend: self.caps.scheme,
            })
    }

    /// Defines `msg` carrying `T` (its named formats first). On DDS this
    /// creates the topic's writer with the default [`PublicationQos`]
    /// (reliable, volatile, keep-all); use [`Session::publisher`] for others.
    ///
    /// A topic carries one type per session while the session uses it:
    /// defining, publishing, subscribing, querying or serving it later with
    /// a type of another IPC format or DDS type name fails with
    /// [`OpenError::TypeMismatch`]. A topic the session defined, published
    /// or queried stays bound for the session's life; one it only
    /// subscribed, served or had publishers of is free again once the last
    /// of those handles is dropped (and the session forgets its name).
    /// Typed [`publish`](Session::publish), [`query`](Session::query) and
    /// [`serve`](Session::serve) define what they need themselves; call
    /// `define` to choose the moment (IPC_defineMsg ahead of time).
    ///
    /// On IPC it returns once central has the definition. A message central
    /// already defines with a format that does not fit `T` is refused
    /// ([`OpenError::FormatMismatch`]) rather than replaced, as C would
    /// replace another module's definition; so is one whose definition
    /// another module replaced at the same moment (central keeps the last).
    pub async fn define<T: IpcMessage>(&self, msg: &str) -> Result<(), OpenError> {
        if self.topics.bind::<T>(msg)?.is_none() {
            let _first = self.topics.unsettled(&[msg]);
            let r = self.define_shared(msg, Definition::of::<T>()).await;
            self.settled(&[msg], r)?;
        }
        Ok(())
    }

    /// The result of a typed first use of `msgs`, after which their
    /// bindings stay (success) or are let go if nothing uses them
    /// (failure: see `Topics::settle`).
    pub(crate) fn settled<R, E>(&self, msgs: &[&str], r: Result<R, E>) -> Result<R, E> {
        self.topics.settle(msgs, r.is_ok());
        r
    }

    /// Opens a publication of `msg` as `def` says (named formats first on
    /// IPC).
    pub(crate) async fn open_as(
        &self,
        msg: &str,
        def: &Definition,
        qos: &PublicationQos,
    ) -> Result<PubId, OpenError> {
        // the first definition of `msg` as this type: checked again once
        // central has it (below)
        let mut first = false;
        if let (true, Some(ipc)) = (self.caps.named_formats, self.backend.ipc()) {
            self.central_formats.named_formats(&def.formats)?;
            // what another module defined: not replaced by a misfit
            if def.ty.format.is_some() {
                first = !self.central_formats.known(msg, def.rust);
                if let Err((central, detail)) = self
                    .central_formats
                    .check(self, msg, def.rust, def.fits)
                    .await
                {
                    return Err(OpenError::FormatMismatch {
                        msg: msg.to_string(),
                        ty: def.rust,
                        central,
                        detail,
                    });
                }
            }
            for (name, fmt) in &def.formats {
                ipc.define_format(name, fmt).await?;
            }
        }
        let id = self.backend.open_publication(msg, &def.ty, qos).await?;
        // closed if this future is dropped before it hands the id over
        let opened = Opened::new(&*self.backend, Handle::Publication(id));
        if first {
            // The definition went out after the check: central has it once
            // it answers this lookup (it reads a module's frames in order),
            // and `define().await` means central knows the message. A
            // misfit now is another module's definition that came in
            // between, which replaced this one (C semantics).
            self.central_formats.forget(msg, def.rust);
            if let Err((central, detail)) = self
                .central_formats
                .check(self, msg, def.rust, def.fits)
                .await
            {
                // (`opened` closes the publication)
                return Err(OpenError::FormatMismatch {
                    msg: msg.to_string(),
                    ty: def.rust,
                    central,
                    detail: format!(
                        "{detail} (another module defined {msg} at the same time, and central \
                         keeps the last definition)"
                    ),
                });
            }
        }
        opened.keep();
        Ok(id)
    }

    /// The session's own publication of `msg` (default QoS), opened now.
    pub(crate) async fn define_shared(
        &self,
        msg: &str,
        def: Definition,
    ) -> Result<PubId, OpenError> {
        let id = self.open_as(msg, &def, &PublicationQos::default()).await?;
        let kept = self.topics.set_publication(msg, id);
        if kept != id {
            self.backend.close_handle(Handle::Publication(id));
        }
        Ok(kept)
    }

    /// A publication of `msg` with QoS (ORTE's `ORTEPublicationCreate`);
    /// `.build().await` creates it.
    pub fn publisher<T: IpcMessage>(&self, msg: &str) -> PublisherBuilder<T> {
        PublisherBuilder {
            session: self.clone(),
            msg: msg.to_string(),
            qos: PublicationQos::default(),
            _t: PhantomData,
        }
    }

    /// Publishes a value; `.confirmed()` also waits for every matched reader
    /// to acknowledge it (DDS, reliable). On IPC, like C, a message nobody
    /// subscribes is not sent.
    ///
    /// On DDS the future resolves once the sample is queued for the
    /// session's participant (on a topic this session defined; otherwise
    /// the error comes back), so that a burst of publishes goes out packed
    /// into shared datagrams. What is queued is bounded (1 MiB per session, plus
    /// 1 MiB unacknowledged per reliable keep-all writer): when readers
    /// fall behind, `publish().await` waits: back-pressure, not loss. The
    /// session's queue is shared by all its topics: a reader that stops
    /// reading one topic holds back the session's publishes of every
    /// topic once that 1 MiB is full (a keep-last publication, or a session
    /// per topic, keeps the others going).
    pub fn publish<'a, T: IpcMessage>(&'a self, msg: &'a str, value: &T) -> Publish<'a> {
        let target = self.topics.bind::<T>(msg).map(|known| match known {
            Some(id) => Target::Open(id),
            None => Target::Define(Definition::of::<T>()),
        });
        let cdr = DataRepresentation::default_for(T::EXTENSIBILITY).encoding();
        self.publish_sized(msg, value, 0, cdr, target)
    }

    /// [`Session::publish`], encoding into a buffer of `size_hint` bytes
    /// (CDR: as `cdr`), to `target` (see [`Publish`]).
    pub(crate) fn publish_sized<'a, T: IpcMessage>(
        &'a self,
        msg: &'a str,
        value: &T,
        size_hint: usize,
        cdr: cdr::Encoding,
        target: Result<Target, OpenError>,
    ) -> Publish<'a> {
        let target = match check_lengths(msg, value) {
            Ok(()) => target.map_err(PublishError::from),
            Err(e) => {
                self.topics.settle(&[msg], false);
                Err(e)
            }
        };
        // the key hash in the XCDR version of the data it goes with
        let key_hash = (self.enc() == Encoding::Cdr && !T::KEYS.is_empty() && target.is_ok())
            .then(|| crate::rtps_backend::key_hash_of(value, cdr.version()));
        let first = matches!(target, Ok(Target::Define(_))).then(|| self.topics.unsettled(&[msg]));
        let data = match (self.enc(), &target) {
            (_, Err(_)) => Vec::new(),
            (Encoding::Cdr, _) => cdr::to_vec_with_capacity(value, cdr, size_hint),
            (Encoding::Ipc, _) => ipc::to_vec(value),
        };
        Publish {
            session: self,
            msg,
            data,
            confirm: None,
            key_hash,
            target,
            first,
        }
    }

    /// Publishes raw bytes: on the session's publication of `msg` (made by
    /// [`Session::define`] or a typed publish), or, where the backend
    /// publishes untyped messages (IPC: a message somebody else defined),
    /// on one opened now; otherwise [`PublishError::NoPublication`].
    pub async fn publish_raw(&self, msg: &str, data: &[u8]) -> Result<(), PublishError> {
        let id = match self.topics.publication(msg) {
            Some(id) => id,
            None if self.caps.untyped_publications => {
                let def = Definition {
                    ty: TypeInfo::untyped(),
                    formats: Vec::new(),
                    rust: "raw bytes",
                    fits: |_| Ok(()),
                };
                self.define_shared(msg, def).await?
            }
            None => return Err(PublishError::NoPublication(msg.to_string())),
        };
        self.backend
            .write(id, data.to_vec(), WriteOptions::default())
            .await
    }

    /// Subscribes with the default queue policy (keep all, 1000 samples,
    /// then back-pressure).
    pub async fn subscribe<T: IpcMessage>(&self, msg: &str) -> Result<Subscriber<T>, OpenError> {
        self.subscribe_with(msg, QueuePolicy::default()).await
    }

    /// Subscribes with a queue policy.
    pub async fn subscribe_with<T: IpcMessage>(
        &self,
        msg: &str,
        policy: QueuePolicy,
    ) -> Result<Subscriber<T>, OpenError> {
        self.subscriber::<T>(msg).queue(policy).build().await
    }

    /// A subscription of `msg` with QoS (ORTE's `ORTESubscriptionCreate`);
    /// `.build().await` creates it.
    pub fn subscriber<T: IpcMessage>(&self, msg: &str) -> SubscriberBuilder<T> {
        SubscriberBuilder {
            session: self.clone(),
            msg: msg.to_string(),
            qos: SubscriptionQos::default(),
            policy: None,
            _t: PhantomData,
        }
    }

    /// Subscribes to raw samples.
    ///
    /// The subscription names no type: IPC and RTPS take every sample of
    /// `msg`, whatever its type. A DDS-XRCE agent must create a typed DDS
    /// reader for its client, so on `xrce+…://` use
    /// [`Session::subscribe_raw_as`].
    pub async fn subscribe_raw(&self, msg: &str) -> Result<RawSubscriber, OpenError> {
        self.raw_subscription(msg, None).await
    }

    /// Subscribes to raw samples of `msg` announced as type `ty` (a DDS
    /// type name and layout, see [`TypeInfo::dynamic`]): what tools that
    /// learn the type at run time use on backends whose readers are typed
    /// (DDS-XRCE; on RTPS the reader then matches only writers of that
    /// type name).
    pub async fn subscribe_raw_as(
        &self,
        msg: &str,
        ty: &TypeInfo,
    ) -> Result<RawSubscriber, OpenError> {
        self.raw_subscription(msg, Some(ty)).await
    }

    async fn raw_subscription(
        &self,
        msg: &str,
        ty: Option<&TypeInfo>,
    ) -> Result<RawSubscriber, OpenError> {
        let queue = SampleQueue::new(QueuePolicy::default());
        let id = self
            .backend
            .open_subscription(msg, ty, &SubscriptionQos::default(), queue.clone())
            .await?;
        Ok(RawSubscriber::new(
            queue,
            self.owned(Handle::Subscription(id)),
        ))
    }

    pub(crate) fn owned(&self, handle: Handle) -> Owned {
        Owned::new(&self.backend, handle)
    }

    /// Subscribes to every topic whose name matches `topic` and whose type
    /// name matches `type_name` (fnmatch patterns: `*`, `?`, `[…]`), as
    /// ORTEDomainAppSubscriptionPatternAdd: existing topics and those
    /// discovered later, best effort, as raw samples carrying topic and type.
    pub async fn subscribe_pattern(
        &self,
        topic: &str,
        type_name: &str,
    ) -> Result<RawSubscriber, OpenError> {
        let Some(dds) = self
            .backend
            .dds()
            .filter(|_| self.caps.pattern_subscriptions)
        else {
            return Err(OpenError::Unsupported {
                what: "a pattern subscription".into(),
                backend: self.caps.scheme,
            });
        };
        let queue = SampleQueue::new(QueuePolicy::KeepLast(10_000));
        let id = dds.open_pattern(topic, type_name, queue.clone()).await?;
        Ok(RawSubscriber::new(
            queue,
            self.owned(Handle::Subscription(id)),
        ))
    }

    /// A query; `.timeout(d)` bounds the wait (default 10 s).
    ///
    /// The query message is bound to `Req` as a topic is to its type. DDS
    /// and XRCE: a session's queries of one service share one client, whose
    /// reply reader has one type, so the replies are bound to `Resp` too;
    /// another type for either is [`QueryError::Open`] with an
    /// [`OpenError::TypeMismatch`]. That client (a request writer and a
    /// reply reader, which every participant of the domain learns of) is
    /// opened by the first query and stays open while the session lives:
    /// a program that asks very many different services (a generic tool,
    /// say) asks them from a session of their own and closes it when done.
    pub fn query<'a, Req: IpcMessage, Resp: IpcMessage>(
        &'a self,
        msg: &'a str,
        req: &Req,
    ) -> Query<'a, Resp> {
        // IPC: the query message must be defined in central (by anyone);
        // the reply is decoded as `Resp` whatever message the server used
        // DDS: the session's one client of the service reads one reply type
        let check = self.topics.bind::<Req>(msg).and_then(|known| {
            if self.enc() == Encoding::Ipc {
                return Ok(known.is_none().then(Definition::of::<Req>));
            }
            self.topics.bind_reply::<Resp>(msg).map(|()| None)
        });
        let first = check.is_ok().then(|| self.topics.unsettled(&[msg]));
        Query {
            session: self,
            msg,
            req: TypeInfo::of::<Req>(),
            data: encode_rpc(self.enc(), msg, req),
            timeout: Duration::from_secs(10),
            check,
            _first: first,
            _t: PhantomData,
        }
    }

    /// A query with raw bytes; the reply's message name and bytes.
    pub async fn query_raw(
        &self,
        msg: &str,
        data: &[u8],
        timeout: Duration,
    ) -> Result<RawReply, QueryError> {
        let untyped = TypeInfo::untyped();
        let client = self
            .client(msg, &untyped, &untyped)
            .await
            .map_err(|e| open_failed(msg, e))?;
        self.home
            .run(self.backend.query(client, data.to_vec(), timeout))
            .await
    }

    /// The session's client of the service `msg`, opened on first use.
    pub(crate) async fn client(
        &self,
        msg: &str,
        req: &TypeInfo,
        resp: &TypeInfo,
    ) -> Result<ClientId, OpenError> {
        if let Some(c) = self.topics.client(msg) {
            return Ok(c);
        }
        // one opens it; the others wait for it, and fail with its error
        // (one after another, each would wait out its own open), or try
        // themselves if it was dropped
        let opening = self.topics.client_opening(msg);
        let mut turn = opening.lock().await;
        if let Some(c) = self.topics.client(msg) {
            return Ok(c);
        }
        if let Some(e) = &*turn {
            return Err(e.clone());
        }
        let id = match self.backend.open_client(msg, req, resp).await {
            Ok(id) => id,
            Err(e) => {
                *turn = Some(e.clone());
                self.topics.client_open_done(msg);
                return Err(e);
            }
        };
        let kept = self.topics.set_client(msg, id);
        if kept != id {
            self.backend.close_handle(Handle::Client(id));
        }
        Ok(kept)
    }

    /// Serves queries of `msg` as raw requests (answer with
    /// [`RawRequest::respond`]); the stream ends when the connection is
    /// gone, and dropping it stops serving. IPC only: a DDS service needs
    /// its request and reply types (use [`Session::serve`]).
    pub async fn serve_raw(&self, msg: &str) -> Result<RawRequests, OpenError> {
        let untyped = TypeInfo::untyped();
        let (id, rx) = self
            .backend
            .open_service(msg, &untyped, &untyped, 1000)
            .await?;
        Ok(RawRequests {
            rx,
            _handle: self.owned(Handle::Service(id)),
        })
    }

    /// Serves queries of `msg`, answering with `reply_msg` messages.
    ///
    /// The reply message name is IPC's (`IPC_respond`'s `replyMsgName`):
    /// an IPC asker decodes the reply by it. `""` takes the backend's own:
    /// `<msg>Reply` on IPC; on DDS replies always travel on the service's
    /// reply topic (`rr/<msg>Reply`), so there any other name is refused
    /// with [`OpenError::Unsupported`] rather than ignored.
    ///
    /// IPC: central hands the session one message at a time until it
    /// raises its capacity, and an unanswered request holds that slot (see
    /// [`Request::reply`](crate::Request::reply)): a server that answers
    /// from spawned tasks calls `set_capacity` first.
    pub async fn serve<Req: IpcMessage, Resp: IpcMessage>(
        &self,
        msg: &str,
        reply_msg: &str,
    ) -> Result<Requests<Req, Resp>, OpenError> {
        let reply_msg = match (self.caps.reply_names, reply_msg) {
            (true, "") => format!("{msg}Reply"),
            (true, name) => name.to_string(),
            (false, "") => String::new(),
            (false, name) => {
                return Err(OpenError::Unsupported {
                    what: format!(
                        "reply message name {name:?} (DDS replies go on the service's reply \
                         topic; pass \"\")"
                    ),
                    backend: self.caps.scheme,
                })
            }
        };
        let reply_msg = reply_msg.as_str();
        let define_req = self.topics.bind::<Req>(msg)?.is_none();
        let define_resp = if reply_msg.is_empty() {
            false
        } else {
            match self.topics.bind::<Resp>(reply_msg) {
                Ok(known) => known.is_none(),
                Err(e) => {
                    self.topics.settle(&[msg], false);
                    return Err(e);
                }
            }
        };
        let _first = self.topics.unsettled(&[msg, reply_msg]);
        let r = self
            .open_service::<Req, Resp>(msg, reply_msg, define_req, define_resp)
            .await;
        self.settled(&[msg, reply_msg], r)
    }

    /// [`Session::serve`] once its topics are bound.
    async fn open_service<Req: IpcMessage, Resp: IpcMessage>(
        &self,
        msg: &str,
        reply_msg: &str,
        define_req: bool,
        define_resp: bool,
    ) -> Result<Requests<Req, Resp>, OpenError> {
        if self.caps.reply_names {
            // both must be defined in central: a reply to an undefined
            // message could not be sent
            if define_req {
                self.define_shared(msg, Definition::of::<Req>()).await?;
            }
            if define_resp {
                self.define_shared(reply_msg, Definition::of::<Resp>())
                    .await?;
            }
        }
        let (id, rx) = self
            .backend
            .open_service(msg, &TypeInfo::of::<Req>(), &TypeInfo::of::<Resp>(), 1000)
            .await?;
        let mut handle = self
            .owned(Handle::Service(id))
            .binding(self.topics.hold::<Req>(msg));
        if !reply_msg.is_empty() {
            handle = handle.binding(self.topics.hold::<Resp>(reply_msg));
        }
        Ok(Requests {
            rx,
            _handle: handle,
            ended: false,
            end: self.end.clone(),
            reply_msg: reply_msg.to_string(),
            enc: self.enc(),
            check: Default::default(),
            _t: PhantomData,
        })
    }

    /// Timer ticks every `period`, the first one `period` from now. The
    /// stream ends when the session is closed. A zero period ticks at
    /// every poll, as fast as the stream is read. Ticks missed while the
    /// reader was held up are skipped, not sent in a burst ([`Timer`]).
    ///
    /// # Panics
    /// Outside a tokio runtime (as every tokio timer does), with a message
    /// that says so; so do [`after`](Self::after) and
    /// [`times`](Self::times).
    pub fn every(&self, period: Duration) -> Timer {
        self.timer(period, None)
    }

    /// One tick after `delay` (none if the session is closed first).
    pub fn after(&self, delay: Duration) -> Timer {
        self.timer(delay, Some(1))
    }

    /// `n` ticks, `period` apart (fewer if the session is closed first).
    pub fn times(&self, n: u64, period: Duration) -> Timer {
        self.timer(period, Some(n))
    }

    fn timer(&self, period: Duration, count: Option<u64>) -> Timer {
        assert!(
            self.home.reachable(),
            "Session::every, after and times make tokio timers: call them within a tokio \
             runtime (this session was made outside any)"
        );
        let _in = self.home.enter();
        if period.is_zero() && count != Some(1) {
            tracing::warn!(
                "a timer of {} with a zero period ticks at every poll (as fast as it is read)",
                self.name
            );
        }
        Timer::of_session(&self.end, period, count)
    }

    /// System events: module connect/disconnect, handler counts and loss of
    /// the connection (IPC); participants, publications and subscriptions
    /// found, changed and lost, deadline misses and QoS mismatches (DDS).
    /// A listener sees what happens after it is made: make it before the
    /// publishers and subscribers whose events it is for (a type mismatch
    /// with a reader discovered already is reported while the writer is
    /// created).
    pub fn events(&self) -> Events {
        Events {
            rx: self.backend.events(),
            end: self.end.clone(),
        }
    }

    fn no_controls(&self, what: &str) -> ControlError {
        ControlError::Unsupported {
            what: what.to_string(),
            backend: self.caps.scheme,
        }
    }

    /// Reports [`SessionEvent::HandlersChanged`] for `msg`
    /// (IPC_subscribeHandlerChange; DDS: readers matched with our writers,
    /// [`DdsControl::watch_matches`]). On IPC the message must be defined
    /// (by any module) first, as in C: otherwise
    /// [`ControlError::Central`] with `UnknownMessage`.
    pub async fn watch_handlers(&self, msg: &str) -> Result<(), ControlError> {
        match (self.backend.ipc(), self.backend.dds()) {
            (Some(ipc), _) => ipc.watch_handlers(msg).await,
            (_, Some(dds)) => dds.watch_matches(msg).await,
            _ => Err(self.no_controls("watching handlers")),
        }
    }

    /// Whether a module of that name is connected to central (DDS: a
    /// participant with that entity name is known,
    /// [`DdsControl::participant_named`]).
    pub async fn is_module_connected(&self, module: &str) -> Result<bool, ControlError> {
        match (self.backend.ipc(), self.backend.dds()) {
            (Some(ipc), _) => ipc.is_module_connected(module).await,
            (_, Some(dds)) => dds.participant_named(module).await,
            _ => Err(self.no_controls("is_module_connected")),
        }
    }

    /// How many handlers subscribe `msg` (DDS: readers matched with our
    /// writers, [`DdsControl::matched_readers`]).
    ///
    /// IPC, as C's `IPC_numHandlers`: central counts every handler of a
    /// defined (broadcast) message, but at most one of a message nobody has
    /// defined yet, however many modules subscribe it. To wait for `n > 1`
    /// subscribers, [`define`](Self::define) the message first.
    pub async fn num_handlers(&self, msg: &str) -> Result<i32, ControlError> {
        match (self.backend.ipc(), self.backend.dds()) {
            (Some(ipc), _) => ipc.num_handlers(msg).await,
            (_, Some(dds)) => dds.matched_readers(msg).await,
            _ => Err(self.no_controls("num_handlers")),
        }
    }

    /// Waits until `msg` has at least `n` handlers ([`num_handlers`](Self::num_handlers)),
    /// at most `timeout`; the count reached, or
    /// [`ControlError::Timeout`] naming the count it stayed at.
    ///
    /// IPC sends no message nobody subscribes to (as C) and DDS writers
    /// send nothing to readers they have not matched yet: a publisher that
    /// must not lose its first samples waits for its subscribers first.
    /// (On IPC, define the message first to count more than one; see
    /// `num_handlers`.)
    pub async fn wait_for_handlers(
        &self,
        msg: &str,
        n: i32,
        timeout: Duration,
    ) -> Result<i32, ControlError> {
        if self.backend.ipc().is_none() && self.backend.dds().is_none() {
            return Err(self.no_controls("wait_for_handlers"));
        }
        self.home
            .run(async {
                let deadline = crate::deadline::after(timeout);
                let mut pause = Duration::from_millis(2);
                loop {
                    let now = self.num_handlers(msg).await?;
                    if now >= n {
                        return Ok(now);
                    }
                    if tokio::time::Instant::now() + pause > deadline {
                        return Err(ControlError::Timeout {
                            what: format!("{n} handler(s) of {msg} (there are {now})"),
                            after: timeout,
                        });
                    }
                    tokio::time::sleep(pause).await;
                    pause = (pause * 2).min(Duration::from_millis(50));
                }
            })
            .await
    }

    /// Asserts the liveliness of every publication of this session whose
    /// [`liveliness`](crate::PublisherBuilder::liveliness) is manual by
    /// participant, without publishing (DDS's
    /// `DomainParticipant::assert_liveliness`): one participant message to
    /// every matched participant. Publications that are manual by topic
    /// are not asserted by it: each asserts by its own publishes or
    /// [`Publisher::assert_liveliness`](crate::Publisher::assert_liveliness).
    /// A publish of any publication of the session asserts too.
    ///
    /// [`PublishError::Unsupported`] on a backend other than RTPS (IPC
    /// has no liveliness; DDS-XRCE carries no assertion).
    pub async fn assert_liveliness(&self) -> Result<(), PublishError> {
        match self.backend.dds() {
            Some(dds) if self.caps.liveliness => dds.assert_participant_liveliness().await,
            _ => Err(PublishError::Unsupported {
                what: "asserting the session's liveliness (Session::assert_liveliness)".into(),
                backend: self.caps.scheme,
            }),
        }
    }

    /// Disconnects cleanly (also done when the last clone and handle is
    /// dropped). The session's streams end (with `None`, no
    /// `Err(RecvError::Disconnected)`) and its calls fail at once. On
    /// DDS the instances its publications leave are disposed (or
    /// unregistered, per `autodispose`), and the close waits, up to one
    /// second as Cyclone DDS's writer linger, until the readers
    /// acknowledged what its writers hold: a burst of `publish().await`s
    /// right before it is not lost. On XRCE the close likewise waits, up to
    /// [`XrceOptions::linger`](crate::xrce_backend::XrceOptions::linger)
    /// (3 s), for the agent to acknowledge what the reliable streams hold
    /// before it deletes the session. A `.confirmed()` publish is the way
    /// to know that one sample arrived.
    ///
    /// Dropping the last clone and handle closes in the background. On
    /// DDS, a runtime that shuts down meanwhile (the program returns from
    /// `main` right after the drop) ends that close by running its linger
    /// in the runtime's shutdown, blocking it for up to that second; on
    /// IPC and XRCE the close may be cut short. `close().await` is the way
    /// to be sure.
    pub async fn close(&self) {
        self.end.end();
        if self.end.in_own_callback() {
            // the callback's task (on a current-thread runtime, the whole
            // runtime) waits for the callback, which would wait for the
            // close: the close goes on by itself
            tracing::error!(
                "close() called inside a listen callback of its own session: it goes on once \
                 the callback returns (spawn the close to wait for it)"
            );
            let backend = self.backend.clone();
            tokio::spawn(async move { backend.close().await });
            return;
        }
        self.backend.close().await
    }
}

/// A handle an open has made but not yet handed over: closed if the open
/// ends otherwise (an error, or its future dropped across an await).
struct Opened<'a> {
    backend: &'a dyn Backend,
    handle: Option<Handle>,
}

impl<'a> Opened<'a> {
    fn new(backend: &'a dyn Backend, handle: Handle) -> Self {
        Opened {
            backend,
            handle: Some(handle),
        }
    }

    /// Handed over: its owner closes it.
    fn keep(mut self) {
        self.handle = None;
    }
}

impl Drop for Opened<'_> {
    fn drop(&mut self) {
        if let Some(h) = self.handle.take() {
            self.backend.close_handle(h);
        }
    }
}

/// CMU IPC's controls on a session ([`Session::ipc`]): the typed
/// [`Ipc::define_formats`], and every [`IpcControl`] method through `Deref`.
#[derive(Clone, Copy)]
pub struct Ipc<'a> {
    ctl: &'a dyn IpcControl,
}

impl std::fmt::Debug for Ipc<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Ipc")
    }
}

impl<'a> std::ops::Deref for Ipc<'a> {
    type Target = dyn IpcControl + 'a;
    fn deref(&self) -> &Self::Target {
        self.ctl
    }
}

impl Ipc<'_> {
    /// Registers `T`'s named formats (`IPC_defineFormat`; also done by
    /// every definition of a message carrying `T`).
    pub async fn define_formats<T: IpcMessage>(&self) -> Result<(), OpenError> {
        let formats = NamedFormats::of::<T>();
        if let Some((name, existing, given)) = formats.conflict() {
            return Err(OpenError::NamedFormatConflict {
                name: name.to_string(),
                existing: existing.to_string(),
                given: given.to_string(),
            });
        }
        for (name, fmt) in formats.iter() {
            self.ctl.define_format(name, fmt).await?;
        }
        Ok(())
    }

    /// Every message central knows, by name, internal ones left out
    /// (`x_ipc_getMessages`: C's central answers it too).
    pub async fn messages(&self) -> Result<Vec<String>, ControlError> {
        match self.ctl.ask_central(Ask::Messages).await? {
            Answer::Messages(v) => Ok(v),
            other => Err(unexpected_answer("x_ipc_getMessages", &other)),
        }
    }

    /// What central holds of one message: formats, class, handlers and the
    /// first handler's module (`x_ipc_getMessageInfo`: C's central answers
    /// it too). A message central does not know comes back with its name
    /// only (class 0, no formats, no handlers).
    pub async fn message_details(&self, msg: &str) -> Result<MessageDetails, ControlError> {
        match self
            .ctl
            .ask_central(Ask::MessageDetails(msg.into()))
            .await?
        {
            Answer::MessageDetails(d) => Ok(d),
            other => Err(unexpected_answer("x_ipc_getMessageInfo", &other)),
        }
    }

    /// Every module connected to central, by name, with its host, handler
    /// count and the messages central holds for it. Only Courier's
    /// central answers this (`courier_getModules`); the C central has no
    /// such request, and the error then names that message as unknown to
    /// central.
    pub async fn modules(&self) -> Result<Vec<ModuleDetails>, ControlError> {
        match self.ctl.ask_central(Ask::Modules).await? {
            Answer::Modules(v) => Ok(v),
            other => Err(unexpected_answer("courier_getModules", &other)),
        }
    }
}

/// A backend answered an [`Ask`] with the answer to another one.
fn unexpected_answer(asked: &str, got: &Answer) -> ControlError {
    ControlError::Unsupported {
        what: format!("{asked} (the backend answered {got:?})"),
        backend: "this backend",
    }
}

/// The stream of [`SessionEvent`]s ([`Session::events`]).
///
/// Each stream has a bounded queue of its own: one that is not read often
/// enough loses its oldest events, never holding up the session or the
/// other streams; [`Events::lost`] counts them. The stream ends (`None`)
/// when the session ends: after [`SessionEvent::Disconnected`] when the
/// connection is lost for good, and without it when the session's user
/// calls [`Session::close`] (on any clone). One made after that ends at
/// once.
#[derive(Debug)]
#[must_use = "dropping it stops listening"]
pub struct Events {
    rx: crate::hub::Listener<SessionEvent>,
    end: Arc<crate::session_end::SessionEnd>,
}

impl Events {
    /// Events this stream lost so far because it was not read fast enough
    /// (the oldest are dropped first).
    pub fn lost(&self) -> u64 {
        self.rx.lost()
    }
}

impl Stream for Events {
    type Item = SessionEvent;
    fn poll_next(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<Option<SessionEvent>> {
        match Pin::new(&mut self.rx).poll_next(cx) {
            // a `close()` asked for is no loss to report
            Poll::Ready(Some(SessionEvent::Disconnected)) if self.end.ended() => Poll::Ready(None),
            other => other,
        }
    }
}
