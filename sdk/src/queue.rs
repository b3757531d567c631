//! The queue between a backend and one subscription: [`SampleQueue`], its
//! [`QueuePolicy`], the [`RawSample`]s it holds and the [`RawSubscriber`] that reads them.

use crate::qos::InstanceState;
use crate::session::Owned;
use courier_wire::ipc;
use std::collections::{HashMap, VecDeque};
use std::sync::Arc;
use std::task::{Context, Poll};
use std::time::SystemTime;

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
    /// Who sent it, when the backend knows (DDS: the writer's GUID, as
    /// `SessionEvent`s name it).
    pub source: Option<crate::event::Guid>,
    /// The sender's type name, when the backend knows (DDS; shared by every
    /// sample of the subscription); IPC: the message's format as central
    /// holds it (expanded), which a typed subscription checks its type
    /// against ([`RecvError::FormatMismatch`](crate::RecvError::FormatMismatch)).
    pub type_name: Option<Arc<str>>,
    /// Sample, dispose or unregister (always `Alive` on IPC).
    pub state: InstanceState,
    /// The instance's key hash (keyed DDS topics), when sent.
    pub key_hash: Option<[u8; 16]>,
    /// The XCDR version `key_hash` is in, when the backend knows: the data
    /// representation the writer announced (DDS writers compute the key
    /// hash in the version of their data, and the two versions lay out
    /// some keys differently). Set on instance changes (disposes and
    /// unregisters), where a key may have to be read back from the hash
    /// ([`courier_wire::cdr::key_from_key_hash_in`]); `None` otherwise.
    pub key_hash_version: Option<courier_wire::cdr::Version>,
    /// The writer's source timestamp, when sent (DDS `INFO_TS`).
    pub source_time: Option<SystemTime>,
    /// When the sample expires (DDS LIFESPAN: its source time plus its
    /// writer's lifespan): a sample still unread then is dropped from the
    /// queue, counted by `dropped()`, never handed out.
    pub expires: Option<SystemTime>,
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
            key_hash_version: None,
            source_time: None,
            expires: None,
        }
    }

    /// A live sample whose lifespan has ended.
    fn expired(&self) -> bool {
        self.state == InstanceState::Alive && self.expires.is_some_and(|e| SystemTime::now() > e)
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
    /// A subscription refuses `n` of 0 (`OpenError::Qos`).
    KeepAll(usize),
    /// Keep the newest `n` of each instance, as a DDS reader's KEEP_LAST
    /// history does: samples of a keyed DDS topic are told apart by their
    /// key hash (on XRCE, which carries none, a typed subscription
    /// computes it), every other sample (IPC, a topic without key, a raw
    /// XRCE subscription) is of one instance, so there it is the newest
    /// `n`, as `IPC_setMsgQueueLength` does in central. Instance changes (disposes,
    /// unregisters) are kept beside them. At most `n` × 1024 samples wait
    /// in all; past that the oldest go too. What is dropped is counted
    /// ([`Subscriber::dropped`]). A subscription refuses `n` of 0
    /// (`OpenError::Qos`).
    ///
    /// [`Subscriber::dropped`]: crate::Subscriber::dropped
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
    pub(crate) returns: std::sync::OnceLock<Arc<ReturnedBuffers>>,
    /// Immediate delivery: the callback every sample goes to.
    handler: std::sync::OnceLock<Handler>,
}

/// The callback of an immediate-delivery subscription (ORTE's IMMEDIATE
/// mode, a DDS listener): called with the queue and one sample, in order,
/// by one thread at a time; once with `None` when the connection has ended.
struct Handler(std::sync::Mutex<HandlerFn>);

type HandlerFn = Box<dyn FnMut(&SampleQueue, Option<RawSample>) + Send>;

/// What a queue yields: a sample, or (once) the end of the connection.
pub(crate) enum Popped {
    Sample(RawSample),
    End,
}

impl std::fmt::Debug for Handler {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Handler")
    }
}

/// A keep-last queue holds at most this many times its depth in all
/// (instances × depth beyond it are not kept).
const KEEP_LAST_INSTANCES: usize = 1024;

#[derive(Debug)]
struct QueueState {
    items: VecDeque<RawSample>,
    /// Keep-all: the capacity; keep-last: the depth per instance.
    cap: usize,
    keep_last: bool,
    /// Keep-last: the live samples waiting, per instance (key hash)...
    per_instance: HashMap<[u8; 16], usize>,
    /// ... and those without a key hash (one instance; no hashing on the
    /// way of IPC's keep-last queues).
    unkeyed: usize,
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
                per_instance: HashMap::new(),
                unkeyed: 0,
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
    ///
    /// [`Capabilities::immediate_delivery`]: crate::Capabilities::immediate_delivery
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
    pub(crate) fn poll_waiting(&self, cx: &mut Context<'_>) -> Poll<bool> {
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
    pub(crate) fn give_back(&self, buf: Vec<u8>) {
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
        if st.keep_last {
            st.keep_last_insert(s);
        } else {
            if st.items.len() >= st.cap && !over {
                return Err(s);
            }
            st.items.push_back(s);
        }
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

    /// Samples waiting to be taken.
    pub fn len(&self) -> usize {
        self.state.lock().unwrap().items.len()
    }

    /// No sample waits.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Whether this is a keep-last queue (one that tells instances apart).
    pub(crate) fn is_keep_last(&self) -> bool {
        self.state.lock().unwrap().keep_last
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
        st.per_instance.clear();
        st.unkeyed = 0;
        let waker = st.waker.take();
        drop(st);
        self.space.notify_waiters();
        if let Some(w) = waker {
            w.wake(); // the task running a `listen` callback ends
        }
    }

    /// The next sample, or the end once after close; `None` when nothing
    /// waits.
    pub(crate) fn try_pop(&self) -> Option<Popped> {
        let mut st = self.state.lock().unwrap();
        let was_full = st.items.len() >= st.cap;
        let (next, expired) = pop_live(&mut st);
        let Some(s) = next else {
            let end = st.closed && !st.reported_close;
            st.reported_close |= end;
            drop(st);
            self.discard(expired, was_full);
            return end.then_some(Popped::End);
        };
        drop(st);
        self.discard(expired, was_full);
        Some(Popped::Sample(s))
    }

    /// Samples taken out unread (expired): their buffers go back; waiters
    /// for room are woken if there was none.
    fn discard(&self, expired: Vec<RawSample>, was_full: bool) {
        for e in expired {
            self.give_back(e.data);
        }
        if was_full {
            self.space.notify_waiters();
        }
    }

    /// The next sample, then (once after close) the end, then `None`.
    pub(crate) fn poll_pop(&self, cx: &mut Context<'_>) -> Poll<Option<Popped>> {
        let mut st = self.state.lock().unwrap();
        let was_full = st.items.len() >= st.cap;
        let (next, expired) = pop_live(&mut st);
        if let Some(s) = next {
            drop(st);
            // only a full queue has anyone waiting for room
            self.discard(expired, was_full);
            return Poll::Ready(Some(Popped::Sample(s)));
        }
        if !expired.is_empty() {
            drop(st);
            self.discard(expired, was_full);
            st = self.state.lock().unwrap();
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

impl QueueState {
    /// Keep-last: adds `s`, dropping the oldest live sample of its
    /// instance when the instance has `cap` waiting, and the oldest of all
    /// past `cap` × [`KEEP_LAST_INSTANCES`].
    fn keep_last_insert(&mut self, s: RawSample) {
        if s.state == InstanceState::Alive {
            let n = match s.key_hash {
                Some(k) => self.per_instance.entry(k).or_default(),
                None => &mut self.unkeyed,
            };
            if *n >= self.cap {
                let same =
                    |x: &RawSample| x.state == InstanceState::Alive && x.key_hash == s.key_hash;
                if let Some(i) = self.items.iter().position(same) {
                    self.items.remove(i);
                    self.dropped += 1;
                }
            } else {
                *n += 1;
            }
        }
        self.items.push_back(s);
        if self.items.len() > self.cap.saturating_mul(KEEP_LAST_INSTANCES) {
            if let Some(old) = self.pop_front() {
                self.dropped += 1;
                drop(old);
            }
        }
    }

    /// Takes the oldest item, keeping the per-instance counts.
    fn pop_front(&mut self) -> Option<RawSample> {
        let s = self.items.pop_front()?;
        if self.keep_last && s.state == InstanceState::Alive {
            match s.key_hash {
                None => self.unkeyed = self.unkeyed.saturating_sub(1),
                Some(k) => {
                    if let Some(n) = self.per_instance.get_mut(&k) {
                        *n -= 1;
                        if *n == 0 {
                            self.per_instance.remove(&k);
                        }
                    }
                }
            }
        }
        Some(s)
    }
}

/// The first sample whose lifespan has not ended, and the expired ones
/// before it (counted as dropped).
fn pop_live(st: &mut QueueState) -> (Option<RawSample>, Vec<RawSample>) {
    let mut expired = Vec::new();
    while let Some(s) = st.pop_front() {
        if s.expired() {
            st.dropped += 1;
            expired.push(s);
        } else {
            return (Some(s), expired);
        }
    }
    (None, expired)
}

/// Raw samples of one subscription (`Session::subscribe_raw`); dropping it
/// unsubscribes.
#[derive(Debug)]
#[must_use = "dropping it unsubscribes"]
pub struct RawSubscriber {
    pub(crate) queue: Arc<SampleQueue>,
    /// Unsubscribes when dropped (after the queue is marked abandoned).
    _handle: Owned,
}

impl RawSubscriber {
    pub(crate) fn new(queue: Arc<SampleQueue>, handle: Owned) -> Self {
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

/// The samples as a `Stream` (as [`RawSubscriber::recv`]); it ends with
/// the connection.
impl futures::Stream for RawSubscriber {
    type Item = RawSample;

    fn poll_next(self: std::pin::Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<Option<RawSample>> {
        match self.queue.poll_pop(cx) {
            Poll::Ready(Some(Popped::Sample(s))) => Poll::Ready(Some(s)),
            Poll::Ready(Some(Popped::End) | None) => Poll::Ready(None),
            Poll::Pending => Poll::Pending,
        }
    }
}

impl Drop for RawSubscriber {
    fn drop(&mut self) {
        self.queue.receiver_dropped();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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

    fn sample(key: Option<u8>, n: u8, state: InstanceState) -> RawSample {
        let mut s = RawSample::new("t", vec![n]);
        s.key_hash = key.map(|k| [k; 16]);
        s.state = state;
        s
    }

    fn drain(q: &SampleQueue) -> Vec<(Option<u8>, u8)> {
        std::iter::from_fn(|| match q.try_pop() {
            Some(Popped::Sample(s)) => Some((s.key_hash.map(|k| k[0]), s.data[0])),
            _ => None,
        })
        .collect()
    }

    /// Keep-last is per instance, as a DDS reader's history: a slow reader
    /// of keep-last 1 over three instances finds the newest of each (it
    /// found only the newest of all; audit 18, against Cyclone DDS), and
    /// instance changes stay beside the samples.
    #[test]
    fn keep_last_keeps_the_newest_of_each_instance() {
        use InstanceState::*;
        let q = SampleQueue::new(QueuePolicy::KeepLast(1));
        for n in 0..9u8 {
            q.push(sample(Some(n % 3), n, Alive)).unwrap();
        }
        q.push(sample(Some(1), 100, Disposed)).unwrap();
        assert_eq!(q.dropped(), 6);
        assert_eq!(
            drain(&q),
            [(Some(0), 6), (Some(1), 7), (Some(2), 8), (Some(1), 100)]
        );
        // samples without a key hash are one instance: the newest n of all
        let q = SampleQueue::new(QueuePolicy::KeepLast(2));
        for n in 0..5u8 {
            q.push(sample(None, n, Alive)).unwrap();
        }
        assert_eq!(drain(&q), [(None, 3), (None, 4)]);
        assert_eq!(q.dropped(), 3);
        // after a pop, an instance has room again
        q.push(sample(Some(9), 1, Alive)).unwrap();
        assert_eq!(drain(&q), [(Some(9), 1)]);
        q.push(sample(Some(9), 2, Alive)).unwrap();
        q.push(sample(Some(9), 3, Alive)).unwrap();
        assert_eq!(drain(&q), [(Some(9), 2), (Some(9), 3)]);
        assert_eq!(q.dropped(), 3);
    }

    /// However many instances, a keep-last queue holds at most depth ×
    /// 1024 samples.
    #[test]
    fn keep_last_is_bounded_over_all_instances() {
        let q = SampleQueue::new(QueuePolicy::KeepLast(1));
        for n in 0..3000u32 {
            let mut s = RawSample::new("t", vec![]);
            s.key_hash = Some([
                n as u8,
                (n >> 8) as u8,
                0,
                0,
                0,
                0,
                0,
                0,
                0,
                0,
                0,
                0,
                0,
                0,
                0,
                0,
            ]);
            q.push(s).unwrap();
        }
        assert_eq!(q.len(), KEEP_LAST_INSTANCES);
        assert_eq!(q.dropped(), 3000 - KEEP_LAST_INSTANCES as u64);
        let first = match q.try_pop() {
            Some(Popped::Sample(s)) => s.key_hash.unwrap(),
            _ => panic!("empty"),
        };
        // the oldest kept is the 1977th written
        let n = 3000 - KEEP_LAST_INSTANCES as u32;
        assert_eq!(first[..2], [n as u8, (n >> 8) as u8]);
    }
}
