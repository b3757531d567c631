//! The async [`Session`] and its pluggable [`Backend`]s.
//!
//! A `Session` is one module's connection to a messaging system. The typed
//! layer (this file) encodes values with [`IpcMessage`] and hands bytes to a
//! [`Backend`]; [`crate::ipc_backend::IpcBackend`] speaks CMU IPC
//! to a `central` (Courier's or the C one).

use std::collections::VecDeque;
use std::marker::PhantomData;
use std::pin::Pin;
use std::sync::Arc;
use std::task::{Context, Poll};
use std::time::{Duration, SystemTime};

use futures::Stream;
use tokio::sync::mpsc;

use crate::ipc_backend::{IpcBackend, IpcOptions};
use courier_wire::{ipc, IpcMessage, NamedFormats};

/// How a backend wants typed values encoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum Encoding {
    /// CMU IPC marshalling (`ipc::to_vec`).
    Ipc,
    /// OMG CDR (DDS backends).
    Cdr,
}

/// One message as a backend delivers it.
pub struct RawSample {
    /// Message name.
    pub msg: String,
    /// The bytes, as the sender marshalled them.
    pub data: Vec<u8>,
    /// Byte order of `data`.
    pub order: ipc::ByteOrder,
    /// When this process received it.
    pub received: SystemTime,
    /// Called once the user has taken the sample (IPC: the Success ack that
    /// frees central's capacity slot).
    pub done: Option<Box<dyn FnOnce() + Send>>,
}

impl std::fmt::Debug for RawSample {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RawSample")
            .field("msg", &self.msg)
            .field("data", &self.data.len())
            .field("received", &self.received)
            .finish_non_exhaustive()
    }
}

/// What a subscription does when its local queue is full.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum QueuePolicy {
    /// Keep every sample; when `n` wait, stop acknowledging so central
    /// holds the rest (back-pressure, where `set_queue_length` applies).
    KeepAll(usize),
    /// Keep the newest `n`; the oldest is dropped and counted
    /// ([`Subscriber::dropped`]), as `IPC_setMsgQueueLength` does in central.
    KeepLast(usize),
}

impl Default for QueuePolicy {
    fn default() -> Self {
        QueuePolicy::KeepAll(1000)
    }
}

/// The queue between a backend and one subscription.
#[derive(Debug)]
pub struct SampleQueue {
    state: std::sync::Mutex<QueueState>,
    space: tokio::sync::Notify,
}

#[derive(Debug)]
struct QueueState {
    items: VecDeque<RawSample>,
    cap: usize,
    keep_last: bool,
    dropped: u64,
    closed: bool,
    reported_close: bool,
    receiver_gone: bool,
    waker: Option<std::task::Waker>,
}

impl SampleQueue {
    /// An empty queue with this policy.
    pub fn new(policy: QueuePolicy) -> Arc<SampleQueue> {
        let (cap, keep_last) = match policy {
            QueuePolicy::KeepAll(n) => (n.max(1), false),
            QueuePolicy::KeepLast(n) => (n.max(1), true),
        };
        Arc::new(SampleQueue {
            state: std::sync::Mutex::new(QueueState {
                items: VecDeque::new(),
                cap,
                keep_last,
                dropped: 0,
                closed: false,
                reported_close: false,
                receiver_gone: false,
                waker: None,
            }),
            space: tokio::sync::Notify::new(),
        })
    }

    /// Adds a sample; `Err` gives it back when the queue is full under
    /// keep-all (wait with [`SampleQueue::push_wait`]).
    pub fn push(&self, s: RawSample) -> Result<(), RawSample> {
        let mut st = self.state.lock().unwrap();
        if st.receiver_gone {
            return Ok(());
        }
        if st.items.len() >= st.cap {
            if !st.keep_last {
                return Err(s);
            }
            st.items.pop_front();
            st.dropped += 1;
        }
        st.items.push_back(s);
        if let Some(w) = st.waker.take() {
            w.wake();
        }
        Ok(())
    }

    /// Adds a sample, waiting for room.
    pub async fn push_wait(&self, mut s: RawSample) {
        loop {
            let notified = self.space.notified();
            match self.push(s) {
                Ok(()) => return,
                Err(back) => s = back,
            }
            notified.await;
        }
    }

    /// No more samples will come (the connection ended).
    pub fn close(&self) {
        let mut st = self.state.lock().unwrap();
        st.closed = true;
        if let Some(w) = st.waker.take() {
            w.wake();
        }
    }

    /// Whether the subscription was dropped by the user.
    pub fn is_receiver_gone(&self) -> bool {
        self.state.lock().unwrap().receiver_gone
    }

    /// Samples dropped by keep-last.
    pub fn dropped(&self) -> u64 {
        self.state.lock().unwrap().dropped
    }

    fn receiver_dropped(&self) {
        let mut st = self.state.lock().unwrap();
        st.receiver_gone = true;
        st.items.clear();
        drop(st);
        self.space.notify_waiters();
    }

    /// `Ready(Some(marker))` with an empty message name once after close.
    fn poll_pop(&self, cx: &mut Context<'_>) -> Poll<Option<RawSample>> {
        let mut st = self.state.lock().unwrap();
        if let Some(s) = st.items.pop_front() {
            drop(st);
            self.space.notify_waiters();
            return Poll::Ready(Some(s));
        }
        if st.closed {
            if st.reported_close {
                return Poll::Ready(None);
            }
            st.reported_close = true;
            return Poll::Ready(Some(RawSample {
                msg: String::new(),
                data: Vec::new(),
                order: ipc::ByteOrder::NATIVE,
                received: SystemTime::now(),
                done: None,
            }));
        }
        st.waker = Some(cx.waker().clone());
        Poll::Pending
    }
}

/// Raw samples of one subscription (`Session::subscribe_raw`); dropping it
/// unsubscribes.
#[derive(Debug)]
pub struct RawSubscriber {
    queue: Arc<SampleQueue>,
}

impl RawSubscriber {
    /// The next sample; `None` once the connection has ended.
    pub async fn recv(&mut self) -> Option<RawSample> {
        std::future::poll_fn(|cx| self.queue.poll_pop(cx)).await
    }

    /// Samples dropped by a keep-last policy.
    pub fn dropped(&self) -> u64 {
        self.queue.dropped()
    }
}

impl Drop for RawSubscriber {
    fn drop(&mut self) {
        self.queue.receiver_dropped();
    }
}

/// Sends a reply: the reply message's name and its bytes.
pub type Responder = Box<dyn FnOnce(&str, Vec<u8>) -> Result<(), SessionError> + Send>;

/// A reply as a backend returns it: reply message name, bytes, byte order.
pub type RawReply = (String, Vec<u8>, ipc::ByteOrder);

/// A request delivered to a server, with the way to answer it.
pub struct RawRequest {
    /// Query message name.
    pub msg: String,
    /// The request bytes.
    pub data: Vec<u8>,
    /// Byte order of `data`.
    pub order: ipc::ByteOrder,
    /// Sends the reply (reply message name, bytes); may be called later and
    /// from any task (IPC_delayResponse).
    pub respond: Responder,
}

impl std::fmt::Debug for RawRequest {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RawRequest")
            .field("msg", &self.msg)
            .field("data", &self.data.len())
            .finish_non_exhaustive()
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
    /// This session lost its connection (with reconnect on, a
    /// [`SessionEvent::Reconnected`] follows once central is back).
    Disconnected,
    /// The session reached central again and defined and subscribed
    /// everything anew (see [`SessionBuilder::reconnect`]).
    Reconnected,
}

/// What can go wrong with a session operation.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum SessionError {
    /// The connection is gone (central died, or the session was closed).
    #[error("disconnected from {0}")]
    Disconnected(String),
    /// The messaging system refused the operation.
    #[error("{0}")]
    Refused(String),
    /// A value could not be decoded as the expected type.
    #[error("cannot decode {msg} as {ty}: {detail}")]
    Decode {
        /// Message name.
        msg: String,
        /// Expected Rust type.
        ty: &'static str,
        /// The decoder's message.
        detail: String,
    },
}

/// Why a query failed.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum QueryError {
    /// No reply within the timeout.
    #[error("no reply to {msg} within {timeout:?}")]
    Timeout {
        /// Query message.
        msg: String,
        /// The timeout.
        timeout: Duration,
    },
    /// The session ended before the reply.
    #[error("disconnected before {0} was answered")]
    Disconnected(String),
    /// The query could not be sent.
    #[error("query {msg} refused: {detail}")]
    Refused {
        /// Query message.
        msg: String,
        /// Why.
        detail: String,
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

/// Why connecting failed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ConnectError {
    /// The URL is not understood.
    #[error("bad session URL {url:?}: {why}")]
    BadUrl {
        /// The URL.
        url: String,
        /// What is wrong.
        why: String,
    },
    /// No central answered.
    #[error("cannot connect to central at {addr} after {attempts} attempt(s): {source}")]
    Unreachable {
        /// Where it tried.
        addr: String,
        /// How often.
        attempts: u32,
        /// The last error.
        source: std::io::Error,
    },
    /// The handshake failed.
    #[error("handshake with central at {addr} failed: {why}")]
    Handshake {
        /// Where.
        addr: String,
        /// Why.
        why: String,
    },
}

/// A pluggable transport: bytes in, bytes out, plus type metadata. Object
/// safe, so a `Session` holds an `Arc<dyn Backend>`.
#[async_trait::async_trait]
pub trait Backend: Send + Sync + std::fmt::Debug {
    /// How typed values must be encoded.
    fn encoding(&self) -> Encoding;
    /// Registers a named format (IPC_defineFormat).
    async fn define_format(&self, name: &str, format: &str) -> Result<(), SessionError>;
    /// Defines a message with its format (IPC_defineMsg).
    async fn define(&self, msg: &str, format: Option<&str>) -> Result<(), SessionError>;
    /// Publishes; resolves once handed to the transport.
    async fn publish(&self, msg: &str, data: Vec<u8>) -> Result<(), SessionError>;
    /// Subscribes; samples arrive on the returned channel until it is
    /// dropped (then the backend unsubscribes).
    async fn subscribe(&self, msg: &str, queue: Arc<SampleQueue>) -> Result<(), SessionError>;
    /// Sends a query; the reply's message name and bytes.
    async fn query(
        &self,
        msg: &str,
        data: Vec<u8>,
        timeout: Duration,
    ) -> Result<RawReply, QueryError>;
    /// Serves queries of `msg`.
    async fn serve(
        &self,
        msg: &str,
        queue: usize,
    ) -> Result<mpsc::Receiver<RawRequest>, SessionError>;
    /// A stream of system events.
    fn events(&self) -> mpsc::UnboundedReceiver<SessionEvent>;
    /// Whether a module of that name is connected.
    async fn is_module_connected(&self, module: &str) -> Result<bool, SessionError>;
    /// How many handlers a message has.
    async fn num_handlers(&self, msg: &str) -> Result<i32, SessionError>;
    /// IPC_setCapacity.
    async fn set_capacity(&self, n: i32) -> Result<(), SessionError>;
    /// IPC_setMsgPriority.
    async fn set_priority(&self, msg: &str, priority: i32) -> Result<(), SessionError>;
    /// IPC_setMsgQueueLength.
    async fn set_queue_length(&self, msg: &str, n: i32) -> Result<(), SessionError>;
    /// Reports handler-count changes of `msg` on the event streams.
    async fn watch_handlers(&self, msg: &str) -> Result<(), SessionError>;
    /// Disconnects cleanly.
    async fn close(&self);
}

/// Builds a [`Session`].
#[derive(Debug, Clone)]
pub struct SessionBuilder {
    url: String,
    name: Option<String>,
    opts: IpcOptions,
}

impl SessionBuilder {
    /// The module name (default: `courier-<pid>`).
    pub fn name(mut self, name: impl Into<String>) -> Self {
        self.name = Some(name.into());
        self
    }

    /// `IPC_connectNoListen`: publishing is not filtered by the list of
    /// subscribed messages.
    pub fn no_listen(mut self) -> Self {
        self.opts.listen = false;
        self
    }

    /// How long to keep trying to reach central (default 5 s, as C's five
    /// one-second retries).
    pub fn connect_timeout(mut self, d: Duration) -> Self {
        self.opts.connect_timeout = d;
        self
    }

    /// After losing central, keep trying to reach it (first after `backoff`,
    /// doubling up to 5 s), then define and subscribe everything again;
    /// subscribers stay open meanwhile. Operations fail while disconnected.
    pub fn reconnect(mut self, backoff: Duration) -> Self {
        self.opts.reconnect = Some(backoff);
        self
    }

    /// Connects.
    pub async fn connect(self) -> Result<Session, ConnectError> {
        let name = self
            .name
            .unwrap_or_else(|| format!("courier-{}", std::process::id()));
        let backend = IpcBackend::connect(&self.url, &name, self.opts).await?;
        Ok(Session::with_backend(Arc::new(backend), name))
    }
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
    backend: Arc<dyn Backend>,
    name: String,
}

impl Session {
    /// A builder for `url`: `ipc://host:port` (`ipc://` alone: `CENTRALHOST`,
    /// then localhost:1381).
    pub fn builder(url: impl Into<String>) -> SessionBuilder {
        SessionBuilder {
            url: url.into(),
            name: None,
            opts: IpcOptions::default(),
        }
    }

    /// A session over any backend.
    pub fn with_backend(backend: Arc<dyn Backend>, name: impl Into<String>) -> Self {
        Session {
            backend,
            name: name.into(),
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

    /// Registers `T`'s named formats (`IPC_defineFormat`).
    pub async fn define_format<T: IpcMessage>(&self) -> Result<(), SessionError> {
        for (name, fmt) in NamedFormats::of::<T>().iter() {
            self.backend.define_format(name, fmt).await?;
        }
        Ok(())
    }

    /// Defines `msg` carrying `T` (its named formats first).
    pub async fn define<T: IpcMessage>(&self, msg: &str) -> Result<(), SessionError> {
        self.define_format::<T>().await?;
        self.backend.define(msg, Some(T::FORMAT)).await
    }

    /// Publishes a value. Like C, a message nobody subscribes is not sent.
    pub async fn publish<T: IpcMessage>(&self, msg: &str, value: &T) -> Result<(), SessionError> {
        self.backend.publish(msg, ipc::to_vec(value)).await
    }

    /// Publishes raw bytes.
    pub async fn publish_raw(&self, msg: &str, data: &[u8]) -> Result<(), SessionError> {
        self.backend.publish(msg, data.to_vec()).await
    }

    /// Subscribes with the default queue policy (keep all, 1000 samples,
    /// then back-pressure).
    pub async fn subscribe<T: IpcMessage>(&self, msg: &str) -> Result<Subscriber<T>, SessionError> {
        self.subscribe_with(msg, QueuePolicy::default()).await
    }

    /// Subscribes with a queue policy.
    pub async fn subscribe_with<T: IpcMessage>(
        &self,
        msg: &str,
        policy: QueuePolicy,
    ) -> Result<Subscriber<T>, SessionError> {
        let queue = SampleQueue::new(policy);
        self.backend.subscribe(msg, queue.clone()).await?;
        Ok(Subscriber {
            raw: RawSubscriber { queue },
            msg: msg.to_string(),
            decode_errors: 0,
            _t: PhantomData,
        })
    }

    /// Subscribes to raw samples.
    pub async fn subscribe_raw(&self, msg: &str) -> Result<RawSubscriber, SessionError> {
        let queue = SampleQueue::new(QueuePolicy::default());
        self.backend.subscribe(msg, queue.clone()).await?;
        Ok(RawSubscriber { queue })
    }

    /// A query; `.timeout(d)` bounds the wait (default 10 s).
    pub fn query<'a, Req: IpcMessage, Resp: IpcMessage>(
        &'a self,
        msg: &'a str,
        req: &Req,
    ) -> Query<'a, Resp> {
        Query {
            session: self,
            msg,
            data: ipc::to_vec(req),
            timeout: Duration::from_secs(10),
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
        self.backend.query(msg, data.to_vec(), timeout).await
    }

    /// Serves queries of `msg` as raw requests (answer with
    /// [`RawRequest::respond`]).
    pub async fn serve_raw(&self, msg: &str) -> Result<mpsc::Receiver<RawRequest>, SessionError> {
        self.backend.serve(msg, 1000).await
    }

    /// Serves queries of `msg`, answering with `reply_msg` messages.
    pub async fn serve<Req: IpcMessage, Resp: IpcMessage>(
        &self,
        msg: &str,
        reply_msg: &str,
    ) -> Result<Requests<Req, Resp>, SessionError> {
        let rx = self.backend.serve(msg, 1000).await?;
        Ok(Requests {
            rx,
            reply_msg: reply_msg.to_string(),
            _t: PhantomData,
        })
    }

    /// Timer ticks every `period`, the first one `period` from now.
    pub fn every(&self, period: Duration) -> Timer {
        Timer::new(period, None)
    }

    /// One tick after `delay`.
    pub fn after(&self, delay: Duration) -> Timer {
        Timer::new(delay, Some(1))
    }

    /// `n` ticks, `period` apart.
    pub fn times(&self, n: u64, period: Duration) -> Timer {
        Timer::new(period, Some(n))
    }

    /// System events (module connect/disconnect, handler counts, loss of
    /// the connection).
    pub fn events(&self) -> Events {
        Events {
            rx: self.backend.events(),
        }
    }

    /// Reports [`SessionEvent::HandlersChanged`] for `msg`
    /// (IPC_subscribeHandlerChange).
    pub async fn watch_handlers(&self, msg: &str) -> Result<(), SessionError> {
        self.backend.watch_handlers(msg).await
    }

    /// Whether a module of that name is connected to central.
    pub async fn is_module_connected(&self, module: &str) -> Result<bool, SessionError> {
        self.backend.is_module_connected(module).await
    }

    /// How many handlers subscribe `msg`.
    pub async fn num_handlers(&self, msg: &str) -> Result<i32, SessionError> {
        self.backend.num_handlers(msg).await
    }

    /// How many messages central may deliver at once (default 1).
    pub async fn set_capacity(&self, n: i32) -> Result<(), SessionError> {
        self.backend.set_capacity(n).await
    }

    /// Priority of `msg` in this module's pending queue.
    pub async fn set_priority(&self, msg: &str, priority: i32) -> Result<(), SessionError> {
        self.backend.set_priority(msg, priority).await
    }

    /// Most pending `msg` deliveries central keeps for this module (oldest dropped).
    pub async fn set_queue_length(&self, msg: &str, n: i32) -> Result<(), SessionError> {
        self.backend.set_queue_length(msg, n).await
    }

    /// Disconnects cleanly (also done when the last clone is dropped).
    pub async fn close(&self) {
        self.backend.close().await
    }
}

/// A received value with its metadata.
#[derive(Debug, Clone, PartialEq)]
pub struct Sample<T> {
    /// The value.
    pub value: T,
    /// Message name.
    pub msg: String,
    /// When it was received.
    pub received: SystemTime,
}

/// Why a subscriber yielded an error.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum RecvError {
    /// A message did not decode as the subscriber's type (it is skipped).
    #[error("cannot decode {msg} as {ty}: {detail}")]
    Decode {
        /// Message name.
        msg: String,
        /// Expected type.
        ty: &'static str,
        /// The decoder's message.
        detail: String,
    },
    /// The session lost its connection; the stream ends after this.
    #[error("disconnected")]
    Disconnected,
}

/// A typed subscription: a `Stream` of samples. Dropping it unsubscribes.
#[derive(Debug)]
pub struct Subscriber<T> {
    raw: RawSubscriber,
    msg: String,
    decode_errors: u64,
    _t: PhantomData<fn() -> T>,
}

impl<T: IpcMessage> Stream for Subscriber<T> {
    type Item = Result<Sample<T>, RecvError>;

    fn poll_next(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<Option<Self::Item>> {
        match self.raw.queue.poll_pop(cx) {
            Poll::Ready(Some(mut s)) => {
                if let Some(done) = s.done.take() {
                    done();
                }
                if s.msg.is_empty() {
                    // The backend's end-of-connection marker.
                    return Poll::Ready(Some(Err(RecvError::Disconnected)));
                }
                let v = ipc::from_slice_with_order::<T>(&s.data, s.order).map_err(|e| {
                    RecvError::Decode {
                        msg: s.msg.clone(),
                        ty: std::any::type_name::<T>(),
                        detail: e.to_string(),
                    }
                });
                if v.is_err() {
                    self.decode_errors += 1;
                }
                Poll::Ready(Some(v.map(|value| Sample {
                    value,
                    msg: std::mem::take(&mut s.msg),
                    received: s.received,
                })))
            }
            Poll::Ready(None) => Poll::Ready(None),
            Poll::Pending => Poll::Pending,
        }
    }
}

impl<T> Subscriber<T> {
    /// The message subscribed.
    pub fn msg(&self) -> &str {
        &self.msg
    }

    /// Samples dropped by a keep-last policy so far.
    pub fn dropped(&self) -> u64 {
        self.raw.dropped()
    }

    /// Samples that did not decode as `T` so far (each was yielded as a
    /// [`RecvError::Decode`]).
    pub fn decode_errors(&self) -> u64 {
        self.decode_errors
    }
}

/// A query being built; `.await` it.
#[derive(Debug)]
pub struct Query<'a, Resp> {
    session: &'a Session,
    msg: &'a str,
    data: Vec<u8>,
    timeout: Duration,
    _t: PhantomData<fn() -> Resp>,
}

impl<'a, Resp: IpcMessage + 'a> Query<'a, Resp> {
    /// Bounds the wait for the reply.
    pub fn timeout(mut self, d: Duration) -> Self {
        self.timeout = d;
        self
    }

    async fn run(self) -> Result<Resp, QueryError> {
        let (reply, data, order) = self
            .session
            .backend
            .query(self.msg, self.data, self.timeout)
            .await?;
        ipc::from_slice_with_order::<Resp>(&data, order).map_err(|e| QueryError::Decode {
            msg: self.msg.to_string(),
            reply,
            ty: std::any::type_name::<Resp>(),
            detail: e.to_string(),
        })
    }
}

impl<'a, Resp: IpcMessage + 'a> std::future::IntoFuture for Query<'a, Resp> {
    type Output = Result<Resp, QueryError>;
    type IntoFuture = Pin<Box<dyn std::future::Future<Output = Self::Output> + Send + 'a>>;

    fn into_future(self) -> Self::IntoFuture {
        Box::pin(self.run())
    }
}

/// A request to a [`Session::serve`] server.
pub struct Request<Req, Resp> {
    /// The request.
    pub value: Req,
    reply_msg: String,
    respond: Option<Responder>,
    _t: PhantomData<fn(Resp)>,
}

impl<Req: std::fmt::Debug, Resp> std::fmt::Debug for Request<Req, Resp> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Request")
            .field("value", &self.value)
            .finish_non_exhaustive()
    }
}

impl<Req, Resp: IpcMessage> Request<Req, Resp> {
    /// Answers the request (now or later, from any task).
    pub async fn reply(mut self, resp: &Resp) -> Result<(), SessionError> {
        let f = self
            .respond
            .take()
            .ok_or_else(|| SessionError::Refused("already answered".into()))?;
        f(&self.reply_msg, ipc::to_vec(resp))
    }
}

/// The stream of requests of [`Session::serve`].
#[derive(Debug)]
pub struct Requests<Req, Resp> {
    rx: mpsc::Receiver<RawRequest>,
    reply_msg: String,
    _t: PhantomData<fn() -> (Req, Resp)>,
}

impl<Req: IpcMessage, Resp: IpcMessage> Stream for Requests<Req, Resp> {
    type Item = Result<Request<Req, Resp>, RecvError>;

    fn poll_next(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<Option<Self::Item>> {
        match self.rx.poll_recv(cx) {
            Poll::Ready(Some(r)) => {
                if r.msg.is_empty() {
                    return Poll::Ready(Some(Err(RecvError::Disconnected)));
                }
                let v = ipc::from_slice_with_order::<Req>(&r.data, r.order);
                Poll::Ready(Some(match v {
                    Ok(value) => Ok(Request {
                        value,
                        reply_msg: self.reply_msg.clone(),
                        respond: Some(r.respond),
                        _t: PhantomData,
                    }),
                    Err(e) => Err(RecvError::Decode {
                        msg: r.msg,
                        ty: std::any::type_name::<Req>(),
                        detail: e.to_string(),
                    }),
                }))
            }
            Poll::Ready(None) => Poll::Ready(None),
            Poll::Pending => Poll::Pending,
        }
    }
}

/// The stream of [`SessionEvent`]s.
#[derive(Debug)]
pub struct Events {
    rx: mpsc::UnboundedReceiver<SessionEvent>,
}

impl Stream for Events {
    type Item = SessionEvent;
    fn poll_next(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<Option<SessionEvent>> {
        self.rx.poll_recv(cx)
    }
}

/// A timer tick: when it was due and when it fired.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Tick {
    /// The scheduled instant.
    pub scheduled: tokio::time::Instant,
    /// The instant the timer fired.
    pub fired: tokio::time::Instant,
}

/// A timer `Stream` (IPC_addTimer): ticks at fixed instants, skipping none.
#[derive(Debug)]
pub struct Timer {
    interval: tokio::time::Interval,
    remaining: Option<u64>,
    queued: VecDeque<Tick>,
}

impl Timer {
    fn new(period: Duration, count: Option<u64>) -> Timer {
        let period = period.max(Duration::from_nanos(1));
        let mut interval = tokio::time::interval_at(tokio::time::Instant::now() + period, period);
        interval.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Burst);
        Timer {
            interval,
            remaining: count,
            queued: VecDeque::new(),
        }
    }
}

impl Stream for Timer {
    type Item = Tick;
    fn poll_next(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<Option<Tick>> {
        if self.remaining == Some(0) {
            return Poll::Ready(None);
        }
        if let Some(t) = self.queued.pop_front() {
            return Poll::Ready(Some(t));
        }
        match self.interval.poll_tick(cx) {
            Poll::Ready(scheduled) => {
                if let Some(n) = self.remaining.as_mut() {
                    *n -= 1;
                }
                Poll::Ready(Some(Tick {
                    scheduled,
                    fired: tokio::time::Instant::now(),
                }))
            }
            Poll::Pending => Poll::Pending,
        }
    }
}
