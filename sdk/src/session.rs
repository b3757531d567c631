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

pub use crate::error::{ControlError, OpenError, PublishError, QueryError};
pub use crate::event::SessionEvent;
use crate::ipc_backend::{IpcBackend, IpcOptions};
use crate::qos::{Durability, History, Reliability};
pub use crate::qos::{InstanceState, PublicationQos, SubscriptionQos, TypeInfo};
use crate::rtps_backend::{RtpsBackend, RtpsOptions};
use crate::scheme::Resolved;
use crate::topics::{Definition, Topics};
use courier_wire::{cdr, ipc, IpcMessage, NamedFormats};

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
    /// Message name (DDS: topic name).
    pub msg: String,
    /// The bytes, as the sender marshalled them (DDS: CDR with its
    /// encapsulation header; for a dispose or unregister, the serialized
    /// key if the writer sent one).
    pub data: Vec<u8>,
    /// Byte order of `data` (IPC).
    pub order: ipc::ByteOrder,
    /// When this process received it.
    pub received: SystemTime,
    /// Who sent it, when the backend knows (DDS: the writer's GUID in hex;
    /// shared by every sample of that writer).
    pub source: Option<Arc<str>>,
    /// The sender's type name, when the backend knows (DDS; shared by every
    /// sample of the subscription).
    pub type_name: Option<Arc<str>>,
    /// Sample, dispose or unregister (always `Alive` on IPC).
    pub state: InstanceState,
    /// The instance's key hash (keyed DDS topics), when sent.
    pub key_hash: Option<[u8; 16]>,
    /// The writer's source timestamp, when sent (DDS `INFO_TS`).
    pub source_time: Option<SystemTime>,
    /// Called once the user has taken the sample (IPC: the Success ack that
    /// frees central's capacity slot).
    pub done: Option<Box<dyn FnOnce() + Send>>,
}

impl RawSample {
    /// A live sample of `msg`, received now, with no other metadata.
    pub fn new(msg: impl Into<String>, data: Vec<u8>) -> Self {
        RawSample {
            msg: msg.into(),
            data,
            order: ipc::ByteOrder::NATIVE,
            received: SystemTime::now(),
            source: None,
            type_name: None,
            state: InstanceState::Alive,
            key_hash: None,
            source_time: None,
            done: None,
        }
    }
}

impl std::fmt::Debug for RawSample {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RawSample")
            .field("msg", &self.msg)
            .field("data", &self.data.len())
            .field("received", &self.received)
            .field("source", &self.source)
            .field("state", &self.state)
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

/// Sample buffers a [`Subscriber`] has decoded, on their way back to the
/// backend that filled them (RTPS: to be reassembled into again).
#[derive(Debug, Default)]
pub(crate) struct ReturnedBuffers {
    /// The buffers and their total capacity.
    bufs: std::sync::Mutex<(Vec<Vec<u8>>, usize)>,
    /// Set with every buffer given, cleared by the taker: the taker's
    /// check costs no lock while nothing comes back.
    any: std::sync::atomic::AtomicBool,
}

impl ReturnedBuffers {
    /// Most buffers waiting to be taken; the rest are freed.
    const MAX: usize = 64;
    /// Most bytes waiting to be taken (a subscriber can drain a long queue
    /// while the backend takes nothing); the rest are freed.
    const MAX_BYTES: usize = 4 << 20;

    fn give(&self, b: Vec<u8>) {
        use std::sync::atomic::Ordering;
        let mut g = self.bufs.lock().unwrap();
        let (bufs, bytes) = &mut *g;
        if bufs.len() < Self::MAX && *bytes + b.capacity() <= Self::MAX_BYTES {
            *bytes += b.capacity();
            bufs.push(b);
            self.any.store(true, Ordering::Release);
        }
    }

    /// Hands every buffer given back so far to `f`.
    pub(crate) fn take(&self, mut f: impl FnMut(Vec<u8>)) {
        use std::sync::atomic::Ordering;
        if !self.any.swap(false, Ordering::Acquire) {
            return;
        }
        let mut g = self.bufs.lock().unwrap();
        g.1 = 0;
        for b in g.0.drain(..) {
            f(b);
        }
    }
}

/// The queue between a backend and one subscription.
#[derive(Debug)]
pub struct SampleQueue {
    state: std::sync::Mutex<QueueState>,
    space: tokio::sync::Notify,
    /// Where a typed subscriber puts decoded sample buffers, if the backend
    /// reuses them.
    returns: std::sync::OnceLock<Arc<ReturnedBuffers>>,
    /// Immediate delivery: the callback every sample goes to.
    handler: std::sync::OnceLock<Handler>,
}

/// The callback of an immediate-delivery subscription (ORTE's IMMEDIATE
/// mode, a DDS listener): called with the queue and one sample, in order,
/// by one thread at a time; once with `None` when the connection has ended.
struct Handler(std::sync::Mutex<HandlerFn>);

type HandlerFn = Box<dyn FnMut(&SampleQueue, Option<RawSample>) + Send>;

/// What a queue yields: a sample, or (once) the end of the connection.
enum Popped {
    Sample(RawSample),
    End,
}

impl std::fmt::Debug for Handler {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Handler")
    }
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
            returns: std::sync::OnceLock::new(),
            handler: std::sync::OnceLock::new(),
        })
    }

    /// Makes this an immediate-delivery queue: its samples go to `f` (once
    /// set, for the queue's life) when [`SampleQueue::run_handler`] runs,
    /// then `None` once after [`SampleQueue::close`].
    pub fn set_handler(&self, f: impl FnMut(&SampleQueue, Option<RawSample>) + Send + 'static) {
        let _ = self
            .handler
            .set(Handler(std::sync::Mutex::new(Box::new(f))));
    }

    /// Whether the queue has a handler (see [`SampleQueue::set_handler`]).
    pub fn has_handler(&self) -> bool {
        self.handler.get().is_some()
    }

    /// Hands every waiting sample to the queue's handler, in order, on the
    /// calling thread; `false` if it has none. Backends that deliver
    /// immediately ([`Capabilities::immediate_delivery`]) call it after
    /// pushing, holding none of their own locks: the handler may publish.
    /// A handler that panics loses that sample, not the subscription.
    pub fn run_handler(&self) -> bool {
        let Some(h) = self.handler.get() else {
            return false;
        };
        let mut f = h.0.lock().unwrap_or_else(|p| p.into_inner());
        while let Some(p) = self.try_pop() {
            let s = match p {
                Popped::Sample(s) => Some(s),
                Popped::End => None,
            };
            let call = std::panic::AssertUnwindSafe(|| f(self, s));
            if std::panic::catch_unwind(call).is_err() {
                tracing::error!("a subscription callback panicked; its sample is lost");
            }
        }
        true
    }

    /// Ready with `true` when a sample (or the end) waits, `false`
    /// once nothing more will come to the handler (the end was taken, or
    /// the subscription was dropped).
    fn poll_waiting(&self, cx: &mut Context<'_>) -> Poll<bool> {
        let mut st = self.state.lock().unwrap();
        if st.receiver_gone || (st.closed && st.reported_close && st.items.is_empty()) {
            return Poll::Ready(false);
        }
        if !st.items.is_empty() || st.closed {
            return Poll::Ready(true);
        }
        st.waker = Some(cx.waker().clone());
        Poll::Pending
    }

    /// Decoded sample buffers of this queue go back to `to` (once set, for
    /// the queue's life).
    pub(crate) fn return_buffers_to(&self, to: &Arc<ReturnedBuffers>) {
        let _ = self.returns.set(to.clone());
    }

    /// A sample buffer the subscriber is done with.
    fn give_back(&self, buf: Vec<u8>) {
        // small buffers are the allocator's business
        if buf.capacity() >= courier_wire::rtps::frag::SPARE_MIN {
            if let Some(r) = self.returns.get() {
                r.give(buf);
            }
        }
    }

    /// Adds a sample; `Err` gives it back when the queue is full under
    /// keep-all (wait with [`SampleQueue::push_wait`]).
    #[allow(clippy::result_large_err)] // handed straight back, never stored
    pub fn push(&self, s: RawSample) -> Result<(), RawSample> {
        // woken outside the lock: the woken task takes it at once, and on
        // the pusher's CPU it may run before the pusher gets further
        if let Some(w) = self.insert(s, false)? {
            w.wake();
        }
        Ok(())
    }

    /// Adds a sample under the lock (beyond a keep-all capacity if `over`,
    /// else giving it back); keep-last drops the oldest. Returns the waker
    /// of a waiting receiver, for the caller to wake after the lock.
    #[allow(clippy::result_large_err)] // handed straight back, never stored
    fn insert(&self, s: RawSample, over: bool) -> Result<Option<std::task::Waker>, RawSample> {
        let mut st = self.state.lock().unwrap();
        if st.receiver_gone {
            return Ok(None);
        }
        if st.items.len() >= st.cap {
            if st.keep_last {
                st.items.pop_front();
                st.dropped += 1;
            } else if !over {
                return Err(s);
            }
        }
        st.items.push_back(s);
        Ok(st.waker.take())
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

    /// Adds a sample even beyond the capacity (for backends that cannot
    /// wait; they stop reading until [`SampleQueue::is_full`] turns false).
    /// Keep-last still drops the oldest.
    pub fn push_over(&self, s: RawSample) {
        if let Some(w) = self.push_over_deferred(s) {
            w.wake();
        }
    }

    /// [`SampleQueue::push_over`], but the waker of a waiting receiver is
    /// returned instead of woken: a backend that delivers a batch under
    /// its own lock wakes receivers once, after the batch and the lock.
    pub fn push_over_deferred(&self, s: RawSample) -> Option<std::task::Waker> {
        // with `over` nothing is given back
        self.insert(s, true).unwrap_or_default()
    }

    /// Whether a keep-all queue holds its capacity or more.
    pub fn is_full(&self) -> bool {
        let st = self.state.lock().unwrap();
        !st.keep_last && !st.receiver_gone && st.items.len() >= st.cap
    }

    /// Resolves after the next sample is taken out (room may have appeared).
    pub async fn space(&self) {
        let n = self.space.notified();
        if !self.is_full() {
            return;
        }
        n.await
    }

    /// Counts a sample dropped by a filter of the backend (e.g. minimum separation).
    pub fn count_dropped(&self) {
        self.state.lock().unwrap().dropped += 1;
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
        let waker = st.waker.take();
        drop(st);
        self.space.notify_waiters();
        if let Some(w) = waker {
            w.wake(); // the task running a `listen` callback ends
        }
    }

    /// The next sample, or the end once after close; `None` when nothing
    /// waits.
    fn try_pop(&self) -> Option<Popped> {
        let mut st = self.state.lock().unwrap();
        let was_full = st.items.len() >= st.cap;
        let Some(s) = st.items.pop_front() else {
            if st.closed && !st.reported_close {
                st.reported_close = true;
                return Some(Popped::End);
            }
            return None;
        };
        drop(st);
        if was_full {
            self.space.notify_waiters();
        }
        Some(Popped::Sample(s))
    }

    /// The next sample, then (once after close) the end, then `None`.
    fn poll_pop(&self, cx: &mut Context<'_>) -> Poll<Option<Popped>> {
        let mut st = self.state.lock().unwrap();
        let was_full = st.items.len() >= st.cap;
        if let Some(s) = st.items.pop_front() {
            drop(st);
            if was_full {
                // only a full queue has anyone waiting for room
                self.space.notify_waiters();
            }
            return Poll::Ready(Some(Popped::Sample(s)));
        }
        if st.closed {
            if st.reported_close {
                return Poll::Ready(None);
            }
            st.reported_close = true;
            return Poll::Ready(Some(Popped::End));
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
    /// Unsubscribes when dropped (after the queue is marked abandoned).
    _handle: Owned,
}

impl RawSubscriber {
    fn new(queue: Arc<SampleQueue>, handle: Owned) -> Self {
        RawSubscriber {
            queue,
            _handle: handle,
        }
    }

    /// The next sample; `None` once the connection has ended.
    pub async fn recv(&mut self) -> Option<RawSample> {
        match std::future::poll_fn(|cx| self.queue.poll_pop(cx)).await? {
            Popped::Sample(s) => Some(s),
            Popped::End => None,
        }
    }

    /// Pulled delivery (ORTE's `ORTEAppSubscriptionPull`): the next sample
    /// if one is waiting, without waiting. After the end of the connection,
    /// `None` forever ([`RawSubscriber::recv`] tells the end apart).
    pub fn try_recv(&mut self) -> Option<RawSample> {
        match self.queue.try_pop()? {
            Popped::Sample(s) => Some(s),
            Popped::End => None,
        }
    }

    /// Samples dropped by a keep-last policy or a backend filter, and (IPC)
    /// messages whose body did not hold together.
    pub fn dropped(&self) -> u64 {
        self.queue.dropped()
    }
}

impl Drop for RawSubscriber {
    fn drop(&mut self) {
        self.queue.receiver_dropped();
    }
}

pub use crate::reply::{Reply, ReplyFuture, Responder};

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
    /// from any task (IPC_delayResponse). Dropping it unanswered declines
    /// the request.
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

/// Why connecting failed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ConnectError {
    /// The URL's scheme names no backend this process knows.
    #[error("{}", unknown_scheme(url, scheme.as_deref(), known))]
    UnknownScheme {
        /// The URL.
        url: String,
        /// Its scheme (`None`: the URL has no `scheme://`).
        scheme: Option<String>,
        /// The schemes this process knows.
        known: Vec<String>,
    },
    /// An option was set that the URL's backend cannot honour.
    #[error("{option} is not an option of {scheme}:// sessions ({hint})")]
    Unsupported {
        /// The builder method.
        option: &'static str,
        /// The URL's scheme.
        scheme: String,
        /// Which backends have it.
        hint: &'static str,
    },
    /// The URL is not understood.
    #[error("bad session URL {url:?}: {why}")]
    BadUrl {
        /// The URL.
        url: String,
        /// What is wrong.
        why: String,
    },
    /// No central answered.
    #[error("cannot connect to central at {addr} after {attempts} attempt(s)")]
    Unreachable {
        /// Where it tried.
        addr: String,
        /// How often.
        attempts: u32,
        /// The last error (the message does not repeat it).
        #[source]
        source: std::io::Error,
    },
    /// A DDS participant could not join the network (no such interface,
    /// no free participant index, a socket error).
    #[error("cannot join {url}: {why}")]
    Network {
        /// The session URL.
        url: String,
        /// Why.
        why: String,
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

fn unknown_scheme(url: &str, scheme: Option<&str>, known: &[String]) -> String {
    let what = match scheme {
        Some(s) => format!("unknown URL scheme {s:?} in {url:?}"),
        None => format!("no scheme in session URL {url:?}"),
    };
    format!("{what}; known schemes: {}", known.join(", "))
}

pub use crate::backend::{
    Backend, Capabilities, ClientId, DdsControl, Handle, IpcControl, PubId, ServiceId, SubId,
};

/// A handle the typed layer owns: closed when dropped, if the session is
/// still there (a handle does not keep the session alive).
struct Owned {
    backend: Option<std::sync::Weak<dyn Backend>>,
    handle: Handle,
}

impl Owned {
    fn new(backend: &Arc<dyn Backend>, handle: Handle) -> Self {
        Owned {
            backend: Some(Arc::downgrade(backend)),
            handle,
        }
    }
}

impl std::fmt::Debug for Owned {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        self.handle.fmt(f)
    }
}

impl Drop for Owned {
    fn drop(&mut self) {
        if let Some(b) = self.backend.as_ref().and_then(std::sync::Weak::upgrade) {
            b.close_handle(self.handle);
        }
    }
}

/// How [`Backend::write`] publishes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[non_exhaustive]
pub struct WriteOptions {
    /// The instance's key hash (keyed DDS topics).
    pub key_hash: Option<[u8; 16]>,
    /// Wait at most this long for every matched reader's acknowledgement.
    pub confirm: Option<Duration>,
}

/// Builds a [`Session`].
#[derive(Debug, Clone)]
pub struct SessionBuilder {
    url: String,
    name: Option<String>,
    opts: IpcOptions,
    rtps: crate::rtps_backend::RtpsOverrides,
    /// Builder methods called, by the backends that honour them: one the
    /// URL's backend cannot honour fails `connect`.
    set: Vec<(&'static str, Honoured)>,
}

/// Which backends honour a [`SessionBuilder`] option.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Honoured {
    Ipc,
    Rtps,
    Both,
}

impl SessionBuilder {
    /// The module name (default: `courier-<pid>`; DDS: the participant's
    /// entity name).
    pub fn name(mut self, name: impl Into<String>) -> Self {
        self.name = Some(name.into());
        self
    }

    /// `IPC_connectNoListen`: publishing is not filtered by the list of
    /// subscribed messages.
    pub fn no_listen(mut self) -> Self {
        self.set.push(("no_listen", Honoured::Ipc));
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
    /// An embedded central reached through [`SessionBuilder::dial`] that has
    /// stopped is not retried: the session ends as without reconnect.
    pub fn reconnect(mut self, backoff: Duration) -> Self {
        self.set.push(("reconnect", Honoured::Ipc));
        self.opts.reconnect = Some(backoff);
        self
    }

    /// Lower latency for CPU: after every message keep polling for `window`
    /// instead of sleeping until the next one (see [`crate::busy_poll`]).
    /// Off by default; costs a CPU while messages flow. Effective on a
    /// current-thread tokio runtime; on the project's 2-vCPU VM a 4 B query
    /// between processes through a busy-polling central went from 80–105 µs
    /// to 40–44 µs over TCP, and an RTPS round trip across cores from 70 to
    /// 17 µs (BENCHMARKS.md). RTPS: also `busy_poll_us=` in the URL.
    pub fn busy_poll(mut self, window: Duration) -> Self {
        self.set.push(("busy_poll", Honoured::Both));
        self.opts.busy_poll = Some(window);
        self.rtps.busy_poll = Some(window);
        self
    }

    /// IPC: reach central through `dial` instead of a socket; it is called
    /// for the first connection and for every reconnect. The URL still
    /// names central (error messages, direct mode's listening address).
    /// [`CentralHandle::session`] uses it for an in-process link to an
    /// embedded central.
    ///
    /// [`CentralHandle::session`]: https://docs.rs/courier-broker/latest/courier_broker/struct.CentralHandle.html#method.session
    pub fn dial<F, Fut>(mut self, dial: F) -> Self
    where
        F: Fn() -> Fut + Send + Sync + 'static,
        Fut: std::future::Future<Output = std::io::Result<Box<dyn crate::ipc_backend::IpcStream>>>
            + Send
            + 'static,
    {
        self.set.push(("dial", Honoured::Ipc));
        self.opts.dial = Some(crate::ipc_backend::Dial::new(dial));
        self
    }

    /// RTPS: read user data on a receive thread of its own, which also runs
    /// the callbacks of [`SubscriberBuilder::listen`] (see
    /// [`RtpsOptions::receive_thread`]). Also `receive_thread=true` in the
    /// URL. Other backends ignore it.
    pub fn receive_thread(mut self, on: bool) -> Self {
        self.set.push(("receive_thread", Honoured::Rtps));
        self.rtps.receive_thread = Some(on);
        self
    }

    /// RTPS: the network interface, by name (`lo`) or IPv4 address
    /// (URL: `interface=`).
    pub fn interface(mut self, interface: impl Into<String>) -> Self {
        self.set.push(("interface", Honoured::Rtps));
        self.rtps.interface = Some(interface.into());
        self
    }

    /// RTPS: unicast discovery peers, `ip` or `ip:port` (URL: `peers=`);
    /// a peer list alone turns multicast off.
    pub fn peers<I: IntoIterator<Item = S>, S: Into<String>>(mut self, peers: I) -> Self {
        self.set.push(("peers", Honoured::Rtps));
        self.rtps.peers = Some(peers.into_iter().map(Into::into).collect());
        self
    }

    /// RTPS: standard SPDP multicast discovery on or off (URL: `multicast=`).
    pub fn multicast(mut self, on: bool) -> Self {
        self.set.push(("multicast", Honoured::Rtps));
        self.rtps.multicast = Some(on);
        self
    }

    /// RTPS: a fixed participant index instead of probing (URL: `index=`).
    pub fn participant_index(mut self, index: u32) -> Self {
        self.set.push(("participant_index", Honoured::Rtps));
        self.rtps.participant_index = Some(index);
        self
    }

    /// RTPS: socket receive and send buffer sizes in bytes (URL:
    /// `recv_buffer=`, `send_buffer=`).
    pub fn socket_buffers(mut self, recv: usize, send: usize) -> Self {
        self.set.push(("socket_buffers", Honoured::Rtps));
        self.rtps.recv_buffer = Some(recv);
        self.rtps.send_buffer = Some(send);
        self
    }

    /// Connects: `ipc://…` reaches a central, `rtps://<domain>?…` joins a
    /// DDS domain, a scheme plugged in with
    /// [`register_scheme`](crate::scheme::register_scheme) its backend.
    ///
    /// Fails at once, naming the option, if an option was set that this
    /// URL's backend cannot honour (say, [`interface`](Self::interface) on
    /// an `ipc://` session), and names the known schemes for an unknown one.
    pub async fn connect(self) -> Result<Session, ConnectError> {
        let name = self
            .name
            .unwrap_or_else(|| format!("courier-{}", std::process::id()));
        let scheme = self.url.split_once("://").map_or("", |(s, _)| s);
        let refuse = |honoured: &[Honoured]| {
            let bad = self.set.iter().find(|(_, h)| !honoured.contains(h));
            bad.map(|(option, h)| ConnectError::Unsupported {
                option,
                scheme: scheme.to_string(),
                hint: match h {
                    Honoured::Ipc => "it is for ipc:// sessions",
                    Honoured::Rtps => "it is for rtps:// sessions",
                    Honoured::Both => "it is for ipc:// and rtps:// sessions",
                },
            })
        };
        let backend: Arc<dyn Backend> = match crate::scheme::resolve(&self.url)? {
            Resolved::Rtps => {
                if let Some(e) = refuse(&[Honoured::Rtps, Honoured::Both]) {
                    return Err(e);
                }
                let mut o = RtpsOptions::from_url(&self.url)?;
                self.rtps.apply(&mut o);
                Arc::new(RtpsBackend::start(o, &name).await?)
            }
            Resolved::Ipc => {
                if let Some(e) = refuse(&[Honoured::Ipc, Honoured::Both]) {
                    return Err(e);
                }
                Arc::new(IpcBackend::connect(&self.url, &name, self.opts).await?)
            }
            Resolved::Plugged(connect) => {
                if let Some(e) = refuse(&[]) {
                    return Err(e);
                }
                connect(crate::scheme::ConnectRequest {
                    url: self.url,
                    name: name.clone(),
                })
                .await?
            }
        };
        Ok(Session::with_backend(backend, name))
    }
}

fn encode<T: IpcMessage>(enc: Encoding, value: &T) -> Vec<u8> {
    match enc {
        Encoding::Ipc => ipc::to_vec(value),
        Encoding::Cdr => cdr::to_vec(value, cdr::Encoding::Xcdr1Le),
    }
}

fn decode<T: IpcMessage>(enc: Encoding, data: &[u8], order: ipc::ByteOrder) -> Result<T, String> {
    match enc {
        Encoding::Ipc => ipc::from_slice_with_order::<T>(data, order).map_err(|e| e.to_string()),
        Encoding::Cdr => cdr::from_slice::<T>(data).map_err(|e| e.to_string()),
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
    caps: Capabilities,
    name: String,
    topics: Arc<Topics>,
}

impl Session {
    /// A builder for `url`: `ipc://host:port` (`ipc://` alone: `CENTRALHOST`,
    /// then localhost:1381) or `rtps://<domain>` with options as a query
    /// string (see [`RtpsOptions::from_url`]).
    pub fn builder(url: impl Into<String>) -> SessionBuilder {
        SessionBuilder {
            url: url.into(),
            name: None,
            opts: IpcOptions::default(),
            rtps: Default::default(),
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

    fn enc(&self) -> Encoding {
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
                what: "CMU IPC's controls (IPC_setCapacity, IPC_setMsgPriority, \
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
            what: "DDS's controls".into(),
            backend: self.caps.scheme,
        })
    }

    /// Defines `msg` carrying `T` (its named formats first). On DDS this
    /// creates the topic's writer with the default [`PublicationQos`]
    /// (reliable, volatile, keep-all); use [`Session::publisher`] for others.
    ///
    /// A topic carries one type per session: defining, publishing,
    /// subscribing, querying or serving it later with a type of another
    /// IPC format or DDS type name fails with [`OpenError::TypeMismatch`].
    /// Typed [`publish`](Session::publish), [`query`](Session::query) and
    /// [`serve`](Session::serve) define what they need themselves; call
    /// `define` to choose the moment (IPC_defineMsg ahead of time).
    pub async fn define<T: IpcMessage>(&self, msg: &str) -> Result<(), OpenError> {
        if self.topics.bind::<T>(msg)?.is_none() {
            self.define_shared(msg, Definition::of::<T>()).await?;
        }
        Ok(())
    }

    /// Opens a publication of `msg` as `def` says (named formats first on
    /// IPC).
    async fn open_as(
        &self,
        msg: &str,
        def: &Definition,
        qos: &PublicationQos,
    ) -> Result<PubId, OpenError> {
        if let (true, Some(ipc)) = (self.caps.named_formats, self.backend.ipc()) {
            for (name, fmt) in &def.formats {
                ipc.define_format(name, fmt).await?;
            }
        }
        self.backend.open_publication(msg, &def.ty, qos).await
    }

    /// The session's own publication of `msg` (default QoS), opened now.
    async fn define_shared(&self, msg: &str, def: Definition) -> Result<PubId, OpenError> {
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
    /// fall behind, `publish().await` waits: back-pressure, not loss.
    pub fn publish<'a, T: IpcMessage>(&'a self, msg: &'a str, value: &T) -> Publish<'a> {
        let target = self.topics.bind::<T>(msg).map(|known| match known {
            Some(id) => Target::Open(id),
            None => Target::Define(Definition::of::<T>()),
        });
        self.publish_sized(msg, value, 0, target)
    }

    /// [`Session::publish`], encoding into a buffer of `size_hint` bytes,
    /// to `target` (see [`Publish`]).
    fn publish_sized<'a, T: IpcMessage>(
        &'a self,
        msg: &'a str,
        value: &T,
        size_hint: usize,
        target: Result<Target, OpenError>,
    ) -> Publish<'a> {
        let key_hash = (self.enc() == Encoding::Cdr && !T::KEYS.is_empty())
            .then(|| crate::rtps_backend::key_hash_of(value));
        let data = match self.enc() {
            Encoding::Cdr if size_hint > 0 => {
                cdr::to_vec_with_capacity(value, cdr::Encoding::Xcdr1Le, size_hint)
            }
            enc => encode(enc, value),
        };
        Publish {
            session: self,
            msg,
            data,
            confirm: None,
            key_hash,
            target,
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
    pub async fn subscribe_raw(&self, msg: &str) -> Result<RawSubscriber, OpenError> {
        let queue = SampleQueue::new(QueuePolicy::default());
        let id = self
            .backend
            .open_subscription(msg, None, &SubscriptionQos::default(), queue.clone())
            .await?;
        Ok(RawSubscriber::new(
            queue,
            self.owned(Handle::Subscription(id)),
        ))
    }

    fn owned(&self, handle: Handle) -> Owned {
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
    pub fn query<'a, Req: IpcMessage, Resp: IpcMessage>(
        &'a self,
        msg: &'a str,
        req: &Req,
    ) -> Query<'a, Resp> {
        // IPC: the query message must be defined in central (by anyone);
        // the reply is decoded as `Resp` whatever message the server used
        let check = self.topics.bind::<Req>(msg).map(|known| {
            (known.is_none() && self.enc() == Encoding::Ipc).then(Definition::of::<Req>)
        });
        Query {
            session: self,
            msg,
            req: TypeInfo::of::<Req>(),
            data: encode(self.enc(), req),
            timeout: Duration::from_secs(10),
            check,
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
        self.backend.query(client, data.to_vec(), timeout).await
    }

    /// The session's client of the service `msg`, opened on first use.
    async fn client(
        &self,
        msg: &str,
        req: &TypeInfo,
        resp: &TypeInfo,
    ) -> Result<ClientId, OpenError> {
        if let Some(c) = self.topics.client(msg) {
            return Ok(c);
        }
        let id = self.backend.open_client(msg, req, resp).await?;
        let kept = self.topics.set_client(msg, id);
        if kept != id {
            self.backend.close_handle(Handle::Client(id));
        }
        Ok(kept)
    }

    /// Serves queries of `msg` as raw requests (answer with
    /// [`RawRequest::respond`]); the stream ends when the connection is
    /// gone, and dropping it stops serving.
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
            self.topics.bind::<Resp>(reply_msg)?.is_none()
        };
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
        Ok(Requests {
            rx,
            _handle: self.owned(Handle::Service(id)),
            ended: false,
            reply_msg: reply_msg.to_string(),
            enc: self.enc(),
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

    /// System events: module connect/disconnect, handler counts and loss of
    /// the connection (IPC); participants, publications and subscriptions
    /// found, changed and lost, deadline misses and QoS mismatches (DDS).
    pub fn events(&self) -> Events {
        Events {
            rx: self.backend.events(),
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
    /// [`DdsControl::watch_matches`]).
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
    pub async fn num_handlers(&self, msg: &str) -> Result<i32, ControlError> {
        match (self.backend.ipc(), self.backend.dds()) {
            (Some(ipc), _) => ipc.num_handlers(msg).await,
            (_, Some(dds)) => dds.matched_readers(msg).await,
            _ => Err(self.no_controls("num_handlers")),
        }
    }

    /// Disconnects cleanly (also done when the last clone is dropped).
    pub async fn close(&self) {
        self.backend.close().await
    }
}

/// A publish being built; `.await` it.
#[derive(Debug)]
#[must_use = "a publish does nothing until awaited"]
pub struct Publish<'a> {
    session: &'a Session,
    msg: &'a str,
    data: Vec<u8>,
    confirm: Option<Duration>,
    key_hash: Option<[u8; 16]>,
    /// Where it goes: an open publication, or the definition of the
    /// session's publication to make first; or the type mismatch.
    target: Result<Target, OpenError>,
}

/// Where a [`Publish`] goes.
#[derive(Debug)]
enum Target {
    Open(PubId),
    Define(Definition),
}

impl<'a> Publish<'a> {
    /// Resolve only once every matched reader has acknowledged the sample
    /// (reliable DDS writers), waiting at most 10 s unless `.timeout(d)`.
    pub fn confirmed(mut self) -> Self {
        self.confirm.get_or_insert(Duration::from_secs(10));
        self
    }

    /// Bounds the wait of a confirmed publish (implies `.confirmed()`).
    pub fn timeout(mut self, d: Duration) -> Self {
        self.confirm = Some(d);
        self
    }
}

impl<'a> std::future::IntoFuture for Publish<'a> {
    type Output = Result<(), PublishError>;
    type IntoFuture = Pin<Box<dyn std::future::Future<Output = Self::Output> + Send + 'a>>;

    fn into_future(self) -> Self::IntoFuture {
        let opts = WriteOptions {
            key_hash: self.key_hash,
            confirm: self.confirm,
        };
        match self.target {
            Err(e) => Box::pin(std::future::ready(Err(e.into()))),
            // the backend's own (boxed) future, not a box around it
            Ok(Target::Open(id)) => self.session.backend.write(id, self.data, opts),
            Ok(Target::Define(def)) => Box::pin(async move {
                let id = self.session.define_shared(self.msg, def).await?;
                self.session.backend.write(id, self.data, opts).await
            }),
        }
    }
}

/// Builds a [`Publisher`]: ORTE's publication parameters as DDS QoS.
#[derive(Debug)]
pub struct PublisherBuilder<T> {
    session: Session,
    msg: String,
    qos: PublicationQos,
    _t: PhantomData<fn(T)>,
}

impl<T: IpcMessage> PublisherBuilder<T> {
    /// Best effort: nothing is repaired.
    pub fn best_effort(mut self) -> Self {
        self.qos.reliability = Reliability::BestEffort;
        self
    }

    /// Strict reliable (the default).
    pub fn reliable(mut self) -> Self {
        self.qos.reliability = Reliability::Reliable;
        self
    }

    /// Keep the history for late-joining transient-local readers.
    pub fn transient_local(mut self) -> Self {
        self.qos.durability = Durability::TransientLocal;
        self
    }

    /// Keep only the newest `n` samples per instance.
    pub fn keep_last(mut self, n: u32) -> Self {
        self.qos.history = History::KeepLast(n.max(1));
        self
    }

    /// Keep every sample until acknowledged (the default).
    pub fn keep_all(mut self) -> Self {
        self.qos.history = History::KeepAll;
        self
    }

    /// ORTE's strength: exclusive ownership with this strength.
    pub fn strength(mut self, strength: i32) -> Self {
        self.qos.strength = Some(strength);
        self
    }

    /// ORTE's persistence: how long each sample stays valid (DDS lifespan).
    pub fn persistence(mut self, d: Duration) -> Self {
        self.qos.persistence = Some(d);
        self
    }

    /// The offered deadline.
    pub fn deadline(mut self, d: Duration) -> Self {
        self.qos.deadline = Some(d);
        self
    }

    /// Adds a DDS partition.
    pub fn partition(mut self, p: impl Into<String>) -> Self {
        self.qos.partitions.push(p.into());
        self
    }

    /// Replaces the whole QoS.
    pub fn qos(mut self, qos: PublicationQos) -> Self {
        self.qos = qos;
        self
    }

    /// Creates the publication.
    ///
    /// Each is a publication of its own (DDS: a DataWriter of its own, so
    /// that publishers of one topic with different QoS coexist); on IPC
    /// they share the message's definition. Dropping the last clone closes
    /// it.
    pub async fn build(self) -> Result<Publisher<T>, OpenError> {
        self.session.topics.bind::<T>(&self.msg)?;
        let id = self
            .session
            .open_as(&self.msg, &Definition::of::<T>(), &self.qos)
            .await?;
        Ok(Publisher {
            handle: Arc::new(self.session.owned(Handle::Publication(id))),
            id,
            session: self.session,
            msg: self.msg,
            last_len: Arc::default(),
            _t: PhantomData,
        })
    }
}

/// A typed publication handle (DDS: a DataWriter).
#[derive(Debug)]
pub struct Publisher<T> {
    session: Session,
    id: PubId,
    /// Closes the publication when the last clone goes.
    handle: Arc<Owned>,
    msg: String,
    /// Encoded size of the last sample, shared by the clones: the next
    /// one is encoded into a buffer that size, so a large sample is not
    /// reallocated while it is written.
    last_len: Arc<std::sync::atomic::AtomicUsize>,
    _t: PhantomData<fn(T)>,
}

impl<T> Clone for Publisher<T> {
    fn clone(&self) -> Self {
        Publisher {
            session: self.session.clone(),
            id: self.id,
            handle: self.handle.clone(),
            msg: self.msg.clone(),
            last_len: self.last_len.clone(),
            _t: PhantomData,
        }
    }
}

impl<T: IpcMessage> Publisher<T> {
    /// The topic.
    pub fn msg(&self) -> &str {
        &self.msg
    }

    /// Publishes a value (`.confirmed()` to wait for acknowledgements).
    pub fn publish(&self, value: &T) -> Publish<'_> {
        use std::sync::atomic::Ordering::Relaxed;
        let hint = self.last_len.load(Relaxed);
        // checked and opened when the publisher was built
        let p = self
            .session
            .publish_sized(&self.msg, value, hint, Ok(Target::Open(self.id)));
        if p.data.len() != hint {
            self.last_len.store(p.data.len(), Relaxed);
        }
        p
    }

    /// Publishes without waiting and from any thread, a subscription
    /// callback's among them (ORTE's `ORTEPublicationSend`): the sample is
    /// queued or sent when this returns. Fails where `publish().await`
    /// would wait (the session's write queue is full) and on backends that
    /// cannot (IPC: use `publish().await`). Inside a callback of an
    /// immediate subscription the datagram goes out when the callback
    /// returns, packed with the callback's other writes.
    pub fn try_publish(&self, value: &T) -> Result<(), PublishError> {
        let p = self.publish(value);
        let opts = WriteOptions {
            key_hash: p.key_hash,
            confirm: None,
        };
        self.session.backend.try_write(self.id, p.data, opts)
    }

    /// Disposes the instance that `value`'s key fields name (keyed topics).
    pub async fn dispose(&self, value: &T) -> Result<(), PublishError> {
        self.end(value, InstanceState::Disposed).await
    }

    /// Unregisters the instance that `value`'s key fields name (keyed topics).
    pub async fn unregister(&self, value: &T) -> Result<(), PublishError> {
        self.end(value, InstanceState::Unregistered).await
    }

    async fn end(&self, value: &T, state: InstanceState) -> Result<(), PublishError> {
        if T::KEYS.is_empty() {
            return Err(PublishError::NotKeyed(T::TYPE_NAME));
        }
        // A key that always fits in the key hash travels only as the inline
        // KEY_HASH (as Fast DDS sends it, and the only form Fast DDS 2.9
        // acts on); a longer key also as the serialized key (K flag), which
        // Cyclone needs to find the instance behind an MD5 hash.
        let key = if T::CDR_KEY_BOUNDED {
            Vec::new()
        } else {
            cdr::key_to_vec(value, cdr::Encoding::Xcdr1Le)
        };
        let hash = crate::rtps_backend::key_hash_of(value);
        match self
            .session
            .backend
            .dds()
            .filter(|_| self.session.caps.instances)
        {
            Some(dds) => dds.end_instance(self.id, state, key, hash).await,
            None => Err(PublishError::Unsupported {
                what: format!("disposing or unregistering an instance of {}", self.msg),
                backend: self.session.caps.scheme,
            }),
        }
    }

    /// ORTE's send callback: every `period`, `f` is asked for a value to
    /// publish (`None` skips that tick). Runs on a task until the returned
    /// handle is dropped or stopped, or publishing fails.
    pub fn send_every<F>(&self, period: Duration, mut f: F) -> PeriodicPublication
    where
        T: Send + 'static,
        F: FnMut(Tick) -> Option<T> + Send + 'static,
    {
        let p = self.clone();
        let task = tokio::spawn(async move {
            use futures::StreamExt;
            let mut timer = p.session.every(period);
            while let Some(tick) = timer.next().await {
                if let Some(v) = f(tick) {
                    p.publish(&v).await?;
                }
            }
            Ok(())
        });
        PeriodicPublication { task }
    }
}

/// A publication driven by a timer ([`Publisher::send_every`]); dropping it stops it.
#[derive(Debug)]
pub struct PeriodicPublication {
    task: tokio::task::JoinHandle<Result<(), PublishError>>,
}

impl PeriodicPublication {
    /// Stops it and returns why it ended, if it ended by itself.
    pub async fn stop(mut self) -> Result<(), PublishError> {
        self.task.abort();
        (&mut self.task).await.unwrap_or(Ok(()))
    }
}

impl Drop for PeriodicPublication {
    fn drop(&mut self) {
        self.task.abort();
    }
}

/// Builds a [`Subscriber`]: ORTE's subscription parameters as DDS QoS.
#[derive(Debug)]
pub struct SubscriberBuilder<T> {
    session: Session,
    msg: String,
    qos: SubscriptionQos,
    policy: Option<QueuePolicy>,
    _t: PhantomData<fn() -> T>,
}

impl<T: IpcMessage> SubscriberBuilder<T> {
    /// Best effort: matches every writer; nothing is repaired.
    pub fn best_effort(mut self) -> Self {
        self.qos.reliability = Reliability::BestEffort;
        self
    }

    /// Strict reliable (the default).
    pub fn reliable(mut self) -> Self {
        self.qos.reliability = Reliability::Reliable;
        self
    }

    /// Ask writers for their history when joining late.
    pub fn transient_local(mut self) -> Self {
        self.qos.durability = Durability::TransientLocal;
        self
    }

    /// Keep the newest `n` samples (also the local queue policy).
    pub fn keep_last(mut self, n: u32) -> Self {
        self.qos.history = History::KeepLast(n.max(1));
        self.policy = Some(QueuePolicy::KeepLast(n.max(1) as usize));
        self
    }

    /// A [`SessionEvent::DeadlineMissed`] whenever no sample came for `d`.
    pub fn deadline(mut self, d: Duration) -> Self {
        self.qos.deadline = Some(d);
        self
    }

    /// ORTE's minimum separation: at most one sample per instance per `d`.
    pub fn minimum_separation(mut self, d: Duration) -> Self {
        self.qos.minimum_separation = Some(d);
        self
    }

    /// Take each instance from the strongest writer only (exclusive ownership).
    pub fn exclusive(mut self) -> Self {
        self.qos.exclusive = true;
        self
    }

    /// Adds a DDS partition.
    pub fn partition(mut self, p: impl Into<String>) -> Self {
        self.qos.partitions.push(p.into());
        self
    }

    /// The local queue policy.
    pub fn queue(mut self, policy: QueuePolicy) -> Self {
        self.policy = Some(policy);
        self
    }

    /// Replaces the whole QoS.
    pub fn qos(mut self, qos: SubscriptionQos) -> Self {
        self.qos = qos;
        self
    }

    /// The backend's subscription of this type and QoS, into `queue`.
    async fn create(&self, queue: Arc<SampleQueue>) -> Result<RawSubscriber, OpenError> {
        self.session.topics.bind::<T>(&self.msg)?;
        let id = self
            .session
            .backend
            .open_subscription(
                &self.msg,
                Some(&TypeInfo::of::<T>()),
                &self.qos,
                queue.clone(),
            )
            .await?;
        Ok(RawSubscriber::new(
            queue,
            self.session.owned(Handle::Subscription(id)),
        ))
    }

    /// Creates the subscription with immediate delivery (ORTE's IMMEDIATE
    /// mode, a DDS listener): `f` gets every sample, in order, as soon as
    /// the backend has it, and `Err(RecvError::Disconnected)` once at the
    /// end. On RTPS it runs where the datagram was read: the participant's
    /// receive thread (`receive_thread`), or else its driver task; keep it
    /// short and never block in it (it holds up reception). It can answer
    /// at once with [`Publisher::try_publish`]. Other backends call it from
    /// a task of its own. Dropping the [`Listener`] unsubscribes.
    ///
    /// ```no_run
    /// # async fn demo() -> Result<(), Box<dyn std::error::Error>> {
    /// use courier::Session;
    /// let s = Session::builder("rtps://0?interface=lo&peers=127.0.0.1&receive_thread=true")
    ///     .connect()
    ///     .await?;
    /// let pong = s.publisher::<u32>("pong").build().await?;
    /// // answered on the receive thread, without a task in between
    /// let _ping = s
    ///     .subscriber::<u32>("ping")
    ///     .listen(move |sample| {
    ///         if let Ok(sample) = sample {
    ///             let _ = pong.try_publish(&sample.value);
    ///         }
    ///     })
    ///     .await?;
    /// # Ok(()) }
    /// ```
    pub async fn listen<F>(self, mut f: F) -> Result<Listener, OpenError>
    where
        F: FnMut(Result<Sample<T>, RecvError>) + Send + 'static,
    {
        let queue = SampleQueue::new(self.policy.unwrap_or_default());
        let enc = self.session.enc();
        queue.set_handler(move |q, s| {
            f(s.map_or(Err(RecvError::Disconnected), |s| convert::<T>(enc, q, s)))
        });
        let raw = self.create(queue.clone()).await?;
        if !self.session.caps.immediate_delivery {
            tokio::spawn(async move {
                while std::future::poll_fn(|cx| queue.poll_waiting(cx)).await {
                    queue.run_handler();
                }
            });
        }
        Ok(Listener { raw, msg: self.msg })
    }

    /// Creates the subscription.
    pub async fn build(self) -> Result<Subscriber<T>, OpenError> {
        let queue = SampleQueue::new(self.policy.unwrap_or_default());
        let raw = self.create(queue).await?;
        Ok(Subscriber {
            raw,
            msg: self.msg,
            enc: self.session.enc(),
            decode_errors: 0,
            _t: PhantomData,
        })
    }
}

/// An immediate-delivery subscription
/// ([`SubscriberBuilder::listen`]); dropping it unsubscribes (a callback
/// already running finishes).
#[derive(Debug)]
pub struct Listener {
    raw: RawSubscriber,
    msg: String,
}

impl Listener {
    /// The message subscribed.
    pub fn msg(&self) -> &str {
        &self.msg
    }

    /// Samples dropped by a keep-last policy or a backend filter so far, and
    /// (IPC) messages whose body did not hold together.
    pub fn dropped(&self) -> u64 {
        self.raw.dropped()
    }
}

/// A received value with its metadata.
#[derive(Debug, Clone, PartialEq)]
pub struct Sample<T> {
    /// The value.
    pub value: T,
    /// Message name (DDS: topic).
    pub msg: String,
    /// When it was received.
    pub received: SystemTime,
    /// Who sent it, when the backend knows (DDS: the writer's GUID in hex).
    ///
    /// Always `None` on IPC: a delivery frame's header (`classTotal`,
    /// `msgTotal`, `parentRef`, `intent`, `classId`, `dispatchRef`,
    /// `msgRef`) names no sender, central adds none, and a direct link
    /// starts without a handshake, so its receiving end does not learn who
    /// opened it either (CMU IPC has no such call for the same reason). Put
    /// the sender in the message if the receiver needs it.
    pub source: Option<Arc<str>>,
    /// The writer's timestamp, when sent (DDS).
    pub source_time: Option<SystemTime>,
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
    /// Not a failure: an instance of a keyed topic was disposed or
    /// unregistered (the change carries no value); the stream goes on.
    #[error("instance of {msg} {state:?}")]
    Instance {
        /// Topic.
        msg: String,
        /// Disposed or unregistered.
        state: InstanceState,
        /// The instance's key hash, when known.
        key_hash: Option<[u8; 16]>,
        /// The serialized key, if the writer sent it.
        key: Vec<u8>,
    },
}

/// A typed subscription: a `Stream` of samples. Dropping it unsubscribes.
#[derive(Debug)]
pub struct Subscriber<T> {
    raw: RawSubscriber,
    msg: String,
    enc: Encoding,
    decode_errors: u64,
    _t: PhantomData<fn() -> T>,
}

/// A raw sample as the typed `Sample` (or why not): what both a
/// [`Subscriber`] and a [`Listener`]'s callback see.
fn convert<T: IpcMessage>(
    enc: Encoding,
    queue: &SampleQueue,
    mut s: RawSample,
) -> Result<Sample<T>, RecvError> {
    if let Some(done) = s.done.take() {
        done();
    }
    if s.state != InstanceState::Alive {
        return Err(RecvError::Instance {
            msg: s.msg,
            state: s.state,
            key_hash: s.key_hash,
            key: s.data,
        });
    }
    let decoded = decode::<T>(enc, &s.data, s.order);
    queue.give_back(s.data);
    match decoded {
        Ok(value) => Ok(Sample {
            value,
            msg: s.msg,
            received: s.received,
            source: s.source,
            source_time: s.source_time,
        }),
        Err(detail) => Err(RecvError::Decode {
            msg: s.msg,
            ty: std::any::type_name::<T>(),
            detail,
        }),
    }
}

impl<T: IpcMessage> Subscriber<T> {
    fn convert(&mut self, p: Popped) -> Result<Sample<T>, RecvError> {
        let Popped::Sample(s) = p else {
            return Err(RecvError::Disconnected);
        };
        let r = convert(self.enc, &self.raw.queue, s);
        if matches!(r, Err(RecvError::Decode { .. })) {
            self.decode_errors += 1;
        }
        r
    }

    /// Pulled delivery (ORTE's `ORTEAppSubscriptionPull`): the next sample
    /// if one is waiting, without waiting; `None` when none is waiting
    /// (not the end of the stream: for that, poll the `Stream`).
    ///
    /// Named like [`RawSubscriber::try_recv`] and tokio's receivers, so
    /// that it never shadows `futures::TryStreamExt::try_next`, which
    /// waits.
    pub fn try_recv(&mut self) -> Option<Result<Sample<T>, RecvError>> {
        let s = self.raw.queue.try_pop()?;
        Some(self.convert(s))
    }
}

impl<T: IpcMessage> Stream for Subscriber<T> {
    type Item = Result<Sample<T>, RecvError>;

    fn poll_next(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<Option<Self::Item>> {
        match self.raw.queue.poll_pop(cx) {
            Poll::Ready(Some(s)) => Poll::Ready(Some(self.convert(s))),
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

    /// Samples dropped by a keep-last policy or a backend filter so far, and
    /// (IPC) messages whose body did not hold together.
    pub fn dropped(&self) -> u64 {
        self.raw.dropped()
    }

    /// Samples that did not decode as `T` so far (each was yielded as a
    /// [`RecvError::Decode`]).
    pub fn decode_errors(&self) -> u64 {
        self.decode_errors
    }
}

/// A query that could not start: opening what it needs failed.
fn open_failed(msg: &str, e: OpenError) -> QueryError {
    match e {
        OpenError::Disconnected(_) => QueryError::Disconnected(msg.to_string()),
        source => QueryError::Open {
            msg: msg.to_string(),
            source,
        },
    }
}

/// A query being built; `.await` it.
#[derive(Debug)]
pub struct Query<'a, Resp> {
    session: &'a Session,
    msg: &'a str,
    req: TypeInfo,
    data: Vec<u8>,
    timeout: Duration,
    /// The query message's type check, as [`Publish`]'s.
    check: Result<Option<Definition>, OpenError>,
    _t: PhantomData<fn() -> Resp>,
}

impl<'a, Resp: IpcMessage + 'a> Query<'a, Resp> {
    /// Bounds the wait for the reply.
    pub fn timeout(mut self, d: Duration) -> Self {
        self.timeout = d;
        self
    }

    async fn run(self) -> Result<Resp, QueryError> {
        let refused = |e: OpenError| open_failed(self.msg, e);
        if let Some(def) = self.check.map_err(refused)? {
            self.session
                .define_shared(self.msg, def)
                .await
                .map_err(refused)?;
        }
        let client = self
            .session
            .client(self.msg, &self.req, &TypeInfo::of::<Resp>())
            .await
            .map_err(refused)?;
        let (reply, data, order) = self
            .session
            .backend
            .query(client, self.data, self.timeout)
            .await?;
        decode::<Resp>(self.session.enc(), &data, order).map_err(|detail| QueryError::Decode {
            msg: self.msg.to_string(),
            reply,
            ty: std::any::type_name::<Resp>(),
            detail,
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
    enc: Encoding,
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
    /// Answers the request (now or later, from any task); resolves once
    /// the reply is sent, or with why it could not be.
    ///
    /// A `Request` dropped without a reply is declined: the server keeps
    /// receiving (on IPC, central frees the module's capacity slot), and
    /// the asker gets no reply and runs into its timeout.
    pub async fn reply(mut self, resp: &Resp) -> Result<(), PublishError> {
        let r = self.respond.take().ok_or(PublishError::AlreadyAnswered)?;
        r.reply(&self.reply_msg, encode(self.enc, resp)).await
    }
}

/// Raw requests of [`Session::serve_raw`]; dropping it stops serving.
#[derive(Debug)]
pub struct RawRequests {
    rx: mpsc::Receiver<RawRequest>,
    _handle: Owned,
}

impl RawRequests {
    /// The next request; `None` once the connection has ended.
    pub async fn recv(&mut self) -> Option<RawRequest> {
        self.rx.recv().await
    }
}

impl Stream for RawRequests {
    type Item = RawRequest;
    fn poll_next(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<Option<RawRequest>> {
        self.rx.poll_recv(cx)
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
        for (name, fmt) in NamedFormats::of::<T>().iter() {
            self.ctl.define_format(name, fmt).await?;
        }
        Ok(())
    }
}

/// The stream of requests of [`Session::serve`].
#[derive(Debug)]
pub struct Requests<Req, Resp> {
    rx: mpsc::Receiver<RawRequest>,
    /// Stops serving when dropped.
    _handle: Owned,
    /// The end (`Err(Disconnected)`) was yielded.
    ended: bool,
    reply_msg: String,
    enc: Encoding,
    _t: PhantomData<fn() -> (Req, Resp)>,
}

impl<Req: IpcMessage, Resp: IpcMessage> Stream for Requests<Req, Resp> {
    type Item = Result<Request<Req, Resp>, RecvError>;

    fn poll_next(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<Option<Self::Item>> {
        match self.rx.poll_recv(cx) {
            Poll::Ready(Some(r)) => {
                let v = decode::<Req>(self.enc, &r.data, r.order);
                Poll::Ready(Some(match v {
                    Ok(value) => Ok(Request {
                        value,
                        reply_msg: self.reply_msg.clone(),
                        enc: self.enc,
                        respond: Some(r.respond),
                        _t: PhantomData,
                    }),
                    Err(e) => Err(RecvError::Decode {
                        msg: r.msg,
                        ty: std::any::type_name::<Req>(),
                        detail: e,
                    }),
                }))
            }
            // the backend closed the channel: the session is gone
            Poll::Ready(None) if !self.ended => {
                self.ended = true;
                Poll::Ready(Some(Err(RecvError::Disconnected)))
            }
            Poll::Ready(None) => Poll::Ready(None),
            Poll::Pending => Poll::Pending,
        }
    }
}

/// The stream of [`SessionEvent`]s ([`Session::events`]).
///
/// Each stream has a bounded queue of its own: one that is not read often
/// enough loses its oldest events, never holding up the session or the
/// other streams; [`Events::lost`] counts them. The stream ends after
/// [`SessionEvent::Disconnected`] when the session closes (one opened
/// after that ends at once).
#[derive(Debug)]
pub struct Events {
    rx: crate::hub::Listener<SessionEvent>,
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
        Pin::new(&mut self.rx).poll_next(cx)
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

#[cfg(test)]
mod tests {
    use super::*;

    fn subscriber<T>(queue: &Arc<SampleQueue>) -> Subscriber<T> {
        Subscriber {
            raw: RawSubscriber::new(
                queue.clone(),
                Owned {
                    backend: None,
                    handle: Handle::Subscription(SubId(0)),
                },
            ),
            msg: "m".into(),
            enc: Encoding::Cdr,
            decode_errors: 0,
            _t: PhantomData,
        }
    }

    #[test]
    fn decoded_sample_buffers_go_back_to_the_backend() {
        let returns = Arc::<ReturnedBuffers>::default();
        let queue = SampleQueue::new(QueuePolicy::default());
        queue.return_buffers_to(&returns);
        let mut sub = subscriber::<String>(&queue);
        let big = cdr::to_vec(&"x".repeat(10_000), cdr::Encoding::Xcdr1Le);
        let (at, small) = (
            big.as_ptr(),
            cdr::to_vec(&"y".to_string(), cdr::Encoding::Xcdr1Le),
        );
        queue.push(RawSample::new("m", big)).unwrap();
        queue.push(RawSample::new("m", small)).unwrap();
        // a buffer that does not decode goes back too
        queue.push(RawSample::new("m", vec![0xff; 5000])).unwrap();
        assert_eq!(sub.try_recv().unwrap().unwrap().value, "x".repeat(10_000));
        assert_eq!(sub.try_recv().unwrap().unwrap().value, "y");
        assert!(matches!(
            sub.try_recv(),
            Some(Err(RecvError::Decode { .. }))
        ));
        let mut back = Vec::new();
        returns.take(|b| back.push(b));
        assert_eq!(back.len(), 2, "the small buffer is left to the allocator");
        assert_eq!(back[0].as_ptr(), at);
        returns.take(|_| panic!("taken already"));
    }

    #[test]
    fn a_deferred_push_hands_the_waker_back_instead_of_waking() {
        use futures::task::ArcWake;
        use futures::StreamExt;
        use std::sync::atomic::{AtomicUsize, Ordering};
        struct Count(AtomicUsize);
        impl ArcWake for Count {
            fn wake_by_ref(c: &Arc<Self>) {
                c.0.fetch_add(1, Ordering::SeqCst);
            }
        }
        let count = Arc::new(Count(AtomicUsize::new(0)));
        let waker = futures::task::waker(count.clone());
        let mut cx = Context::from_waker(&waker);
        let woken = || count.0.load(Ordering::SeqCst);
        let sample =
            |v: &str| RawSample::new("m", cdr::to_vec(&v.to_string(), cdr::Encoding::Xcdr1Le));
        let queue = SampleQueue::new(QueuePolicy::KeepLast(2));
        let mut sub = subscriber::<String>(&queue);
        assert!(sub.poll_next_unpin(&mut cx).is_pending());
        let w = queue
            .push_over_deferred(sample("a"))
            .expect("the waiting receiver's waker");
        assert!(
            queue.push_over_deferred(sample("b")).is_none(),
            "taken once"
        );
        assert!(queue.push_over_deferred(sample("c")).is_none());
        assert_eq!(woken(), 0, "nobody woken by the pushes");
        w.wake();
        assert_eq!(woken(), 1);
        // keep-last 2: "a" made room for "c"
        let got: Vec<String> = std::iter::from_fn(|| sub.try_recv())
            .map(|s| s.unwrap().value)
            .collect();
        assert_eq!(got, ["b", "c"]);
        assert_eq!(queue.dropped(), 1);
        drop(sub);
        assert!(queue.push_over_deferred(sample("d")).is_none());
        assert!(!queue.is_full());
    }

    #[test]
    fn buffers_waiting_to_go_back_are_bounded() {
        let returns = ReturnedBuffers::default();
        for _ in 0..10 {
            returns.give(Vec::with_capacity(1 << 20));
        }
        let mut n = 0;
        returns.take(|_| n += 1);
        assert_eq!(n, 4, "4 MiB at most");
        for _ in 0..100 {
            returns.give(Vec::with_capacity(8192));
        }
        returns.take(|_| n += 1);
        assert_eq!(n, 4 + ReturnedBuffers::MAX);
    }

    #[test]
    fn without_a_backend_that_reuses_them_buffers_are_freed() {
        let queue = SampleQueue::new(QueuePolicy::default());
        let mut sub = subscriber::<String>(&queue);
        let big = cdr::to_vec(&"x".repeat(10_000), cdr::Encoding::Xcdr1Le);
        queue.push(RawSample::new("m", big)).unwrap();
        assert_eq!(sub.try_recv().unwrap().unwrap().value.len(), 10_000);
        assert!(queue.returns.get().is_none());
    }
}
