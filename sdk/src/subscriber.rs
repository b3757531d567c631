//! Typed subscriptions: [`SubscriberBuilder`], [`Subscriber`], [`Listener`], [`Sample`],
//! and instance state changes ([`InstanceChange`], [`Received`]).
//!
//! A subscriber yields samples. On a keyed DDS topic an instance also
//! changes state without a sample: a writer disposes it or unregisters it
//! (or closes, which disposes what it leaves: DDS's
//! `autodispose_unregistered_instances`). Those changes are yielded too by
//! a subscriber built [`with_instances`](SubscriberBuilder::with_instances),
//! in order with the samples, as [`Received::Instance`]; a plain one skips
//! them and counts them ([`Subscriber::instance_changes_skipped`]). Neither
//! is an error, so a `?` loop goes on past them.
//!
//! ```no_run
//! # async fn demo() -> Result<(), Box<dyn std::error::Error>> {
//! use courier::{IpcMessage, Received, Session};
//! use futures::StreamExt;
//! #[derive(IpcMessage, Debug)]
//! struct Pose { #[ipc(key)] robot: i32, x: f64 }
//! let s = Session::builder("rtps://0?interface=lo&peers=127.0.0.1").connect().await?;
//! let mut sub = s.subscriber::<Pose>("pose").with_instances().build().await?;
//! while let Some(item) = sub.next().await {
//!     match item? {
//!         Received::Sample(p) => println!("robot {} at {}", p.value.robot, p.value.x),
//!         // the key decoded as the type's key: here the robot's i32
//!         Received::Instance(c) => println!("robot {:?} {:?}", c.key, c.state),
//!     }
//! }
//! # Ok(()) }
//! ```

use crate::backend::Handle;
use crate::error::OpenError;
use crate::format_check::FormatCheck;
use crate::qos::{
    DataRepresentation, Durability, History, InstanceState, Reliability, SubscriptionQos, TypeInfo,
};
use crate::queue::{Popped, QueuePolicy, RawSample, RawSubscriber, SampleQueue};
use crate::session::{decode, Encoding, Session};
use crate::session_end::SessionEnd;
use courier_wire::{cdr, IpcMessage};
use futures::Stream;
use std::marker::PhantomData;
use std::pin::Pin;
use std::sync::Arc;
use std::task::{Context, Poll};
use std::time::{Duration, SystemTime};

mod sealed {
    pub trait Sealed {}
    impl Sealed for super::Samples {}
    impl Sealed for super::WithInstances {}
}

/// What a [`Subscriber`] (or a [`Listener`]'s callback) gets: samples only
/// ([`Samples`], the default) or samples and instance state changes
/// ([`WithInstances`]). Sealed.
pub trait Delivery<T: IpcMessage>: sealed::Sealed + 'static {
    /// The stream's item (inside `Result<_, RecvError>`).
    type Item;
    #[doc(hidden)]
    fn sample(s: Sample<T>) -> Self::Item;
    /// `None`: skipped (and counted).
    #[doc(hidden)]
    fn change(c: InstanceChange<T>) -> Option<Self::Item>;
}

/// [`Delivery`] of samples only: instance state changes are skipped and
/// counted ([`Subscriber::instance_changes_skipped`]).
#[derive(Debug, Clone, Copy)]
pub enum Samples {}

/// [`Delivery`] of samples and instance state changes, in order, as
/// [`Received`] ([`SubscriberBuilder::with_instances`]).
#[derive(Debug, Clone, Copy)]
pub enum WithInstances {}

impl<T: IpcMessage> Delivery<T> for Samples {
    type Item = Sample<T>;
    fn sample(s: Sample<T>) -> Sample<T> {
        s
    }
    fn change(_: InstanceChange<T>) -> Option<Sample<T>> {
        None
    }
}

impl<T: IpcMessage> Delivery<T> for WithInstances {
    type Item = Received<T>;
    fn sample(s: Sample<T>) -> Received<T> {
        Received::Sample(s)
    }
    fn change(c: InstanceChange<T>) -> Option<Received<T>> {
        Some(Received::Instance(c))
    }
}

/// What a subscriber built [`with_instances`](SubscriberBuilder::with_instances) yields.
pub enum Received<T: IpcMessage> {
    /// A sample.
    Sample(Sample<T>),
    /// An instance changed state without a sample (keyed DDS topics).
    Instance(InstanceChange<T>),
}

impl<T: IpcMessage + std::fmt::Debug> std::fmt::Debug for Received<T>
where
    T::Key: std::fmt::Debug,
{
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Received::Sample(s) => f.debug_tuple("Sample").field(s).finish(),
            Received::Instance(c) => f.debug_tuple("Instance").field(c).finish(),
        }
    }
}

impl<T: IpcMessage + Clone> Clone for Received<T>
where
    T::Key: Clone,
{
    fn clone(&self) -> Self {
        match self {
            Received::Sample(s) => Received::Sample(s.clone()),
            Received::Instance(c) => Received::Instance(c.clone()),
        }
    }
}

impl<T: IpcMessage + PartialEq> PartialEq for Received<T>
where
    T::Key: PartialEq,
{
    fn eq(&self, other: &Self) -> bool {
        match (self, other) {
            (Received::Sample(a), Received::Sample(b)) => a == b,
            (Received::Instance(a), Received::Instance(b)) => a == b,
            _ => false,
        }
    }
}

impl<T: IpcMessage> Received<T> {
    /// The sample, if this is one.
    pub fn sample(self) -> Option<Sample<T>> {
        match self {
            Received::Sample(s) => Some(s),
            Received::Instance(_) => None,
        }
    }
}

/// An instance of a keyed topic that a writer disposed or unregistered.
///
/// DDS: the subscription tells instances apart by key, whatever XCDR
/// version each writer's key hash is in (writers of both versions on one
/// topic name some keys by different hashes, see
/// [`key_hash`](Self::key_hash)): a dispose from one writer disposes what
/// another wrote, and a dispose or unregister of an instance that is
/// disposed already changes nothing and does not come.
#[derive(Debug, Clone, PartialEq)]
pub struct InstanceChange<T: IpcMessage> {
    /// Topic.
    pub msg: String,
    /// [`InstanceState::Disposed`] or [`InstanceState::Unregistered`].
    pub state: InstanceState,
    /// The instance's key, as the type's [`IpcMessage::Key`] (for
    /// `struct S { #[ipc(key)] id: i32, .. }` an `i32`): from the serialized
    /// key when the writer sent it (Cyclone DDS and Courier do), else from
    /// the key hash when that holds the key itself (a key of at most 16
    /// bytes, read in the XCDR version of the writer's data,
    /// [`key_hash_version`](Self::key_hash_version); Fast DDS sends only
    /// the hash). `None` when neither gives it (Fast DDS's dispose of a
    /// string key: compare [`key_hash`](Self::key_hash) with
    /// [`courier_wire::key_hash_in`] of the values seen), and always on a
    /// topic without key fields.
    pub key: Option<T::Key>,
    /// The instance's key hash: as the writer sent it, or computed from
    /// the serialized key when it sent none (Cyclone DDS 11 sends none).
    /// `None` when neither is there. Writers compute it in the XCDR
    /// version of their data, [`key_hash_version`](Self::key_hash_version):
    /// for some keys (an 8-byte member after a 4-byte one, an array of
    /// enums) the XCDR1 and XCDR2 hashes of one instance differ.
    pub key_hash: Option<[u8; 16]>,
    /// The XCDR version [`key_hash`](Self::key_hash) is in, when the
    /// backend knows (DDS: the data representation the writer announced):
    /// `courier_wire::key_hash_in(&value, version)` of a value of this
    /// instance equals it.
    pub key_hash_version: Option<cdr::Version>,
    /// When it was received.
    pub received: SystemTime,
    /// The writer (its GUID, as `SessionEvent`s name it), when known.
    pub source: Option<crate::event::Guid>,
    /// The writer's timestamp, when sent.
    pub source_time: Option<SystemTime>,
}

/// Builds a [`Subscriber`]: ORTE's subscription parameters as DDS QoS.
#[must_use = "a builder does nothing until `.build().await` or `.listen(f).await`"]
pub struct SubscriberBuilder<T, D = Samples> {
    pub(crate) session: Session,
    pub(crate) msg: String,
    pub(crate) qos: SubscriptionQos,
    pub(crate) policy: Option<QueuePolicy>,
    pub(crate) _t: PhantomData<fn() -> (T, D)>,
}

impl<T: IpcMessage> SubscriberBuilder<T> {
    /// Also yield instance state changes ([`Received::Instance`]: a writer
    /// disposed or unregistered an instance, or closed) with the samples,
    /// in order; without it they are skipped and counted.
    pub fn with_instances(self) -> SubscriberBuilder<T, WithInstances> {
        SubscriberBuilder {
            session: self.session,
            msg: self.msg,
            qos: self.qos,
            policy: self.policy,
            _t: PhantomData,
        }
    }
}

impl<T: IpcMessage, D: Delivery<T>> SubscriberBuilder<T, D> {
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

    /// Keep the newest `n` samples of each instance: DDS's history (what
    /// writers send a late joiner) and also the local queue
    /// ([`QueuePolicy::KeepLast`]): a reader slower than its writers finds
    /// the newest `n` of every instance of a keyed topic (of all samples on
    /// a topic without key), the older ones dropped and counted by
    /// `dropped()`. `build` refuses 0 ([`OpenError::Qos`]).
    pub fn keep_last(mut self, n: u32) -> Self {
        self.qos.history = History::KeepLast(n);
        self
    }

    /// A [`SessionEvent::DeadlineMissed`] whenever no sample came for `d`.
    ///
    /// [`SessionEvent::DeadlineMissed`]: crate::SessionEvent::DeadlineMissed
    pub fn deadline(mut self, d: Duration) -> Self {
        self.qos.deadline = Some(d);
        self
    }

    /// Requests liveliness `kind` within `lease`: matches only writers
    /// offering as much, and reports each one's liveliness as
    /// [`SessionEvent::LivelinessChanged`] (alive when it matches, not
    /// alive when its lease lapses, alive again when it asserts itself,
    /// not alive when it leaves); see [`qos`](crate::qos#liveliness).
    /// `build` refuses a lease under [`MIN_LEASE`](crate::qos::MIN_LEASE)
    /// ([`OpenError::Qos`]) and liveliness on a backend other than RTPS
    /// ([`OpenError::Unsupported`]).
    ///
    /// [`SessionEvent::LivelinessChanged`]: crate::SessionEvent::LivelinessChanged
    pub fn liveliness(mut self, kind: crate::qos::LivelinessKind, lease: Duration) -> Self {
        self.qos.liveliness = Some(crate::qos::Liveliness::new(kind, lease));
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

    /// Accepts only these data representations (by default XCDR1 and
    /// XCDR2: every sample is decoded by its own encapsulation header).
    pub fn data_representation(mut self, accepted: &[DataRepresentation]) -> Self {
        self.qos.data_representation = accepted.to_vec();
        self
    }

    /// The local queue policy, whatever the history: without it the
    /// queue follows the history (keep-last `n`: the newest `n`;
    /// keep-all: [`QueuePolicy::default`]). `build` refuses a queue of 0.
    pub fn queue(mut self, policy: QueuePolicy) -> Self {
        self.policy = Some(policy);
        self
    }

    /// Replaces the whole QoS (its history sets the local queue too, as
    /// [`keep_last`](Self::keep_last) does, unless [`queue`](Self::queue)
    /// gives one).
    pub fn qos(mut self, qos: SubscriptionQos) -> Self {
        self.qos = qos;
        self
    }

    /// The local queue: as [`queue`](Self::queue) set it, else as the
    /// history says.
    fn queue_policy(&self) -> Result<QueuePolicy, OpenError> {
        let p = self.policy.unwrap_or(match self.qos.history {
            History::KeepLast(n) => QueuePolicy::KeepLast(n as usize),
            History::KeepAll => QueuePolicy::default(),
        });
        if matches!(p, QueuePolicy::KeepAll(0) | QueuePolicy::KeepLast(0)) {
            return Err(OpenError::Qos {
                topic: self.msg.clone(),
                why: format!("a queue of {p:?} holds nothing: give 1 or more"),
            });
        }
        Ok(p)
    }

    /// The backend's subscription of this type and QoS, into `queue`.
    async fn create(&self, queue: Arc<SampleQueue>) -> Result<RawSubscriber, OpenError> {
        crate::qos::check_history(&self.msg, self.qos.history)?;
        crate::qos::check_liveliness(&self.msg, self.qos.liveliness)?;
        if self.qos.liveliness.is_some() && !self.session.caps.liveliness {
            return Err(OpenError::Unsupported {
                what: format!("liveliness on the subscription of {}", self.msg),
                backend: self.session.caps.scheme,
            });
        }
        self.session.topics.bind::<T>(&self.msg)?;
        let _first = self.session.topics.unsettled(&[&self.msg]);
        // IPC: a type that does not fit the format central holds already
        // is refused now, not message by message
        let fits = crate::format_check::subscribable::<T>(&self.session, &self.msg).await;
        let r = match fits {
            Ok(()) => {
                self.session
                    .backend
                    .open_subscription(
                        &self.msg,
                        Some(&TypeInfo::of::<T>()),
                        &self.qos,
                        queue.clone(),
                    )
                    .await
            }
            Err(e) => Err(e),
        };
        let id = self.session.settled(&[&self.msg], r)?;
        Ok(RawSubscriber::new(
            queue,
            self.session
                .owned(Handle::Subscription(id))
                .binding(self.session.topics.hold::<T>(&self.msg)),
        ))
    }

    /// Creates the subscription with immediate delivery (ORTE's IMMEDIATE
    /// mode, a DDS listener): `f` gets every sample, in order, as soon as
    /// the backend has it, and `Err(RecvError::Disconnected)` once if the
    /// session loses its connection (not after [`Session::close`]). On
    /// RTPS it runs where the datagram was read: the participant's
    /// receive thread (`receive_thread`), or else its driver task; keep it
    /// short and never block in it (it holds up reception). It can answer
    /// at once with [`Publisher::try_publish`]. Other backends call it from
    /// a task of its own. A `close()` of the callback's own session inside
    /// it cannot be waited for there: it returns at once (logging an error)
    /// and the close goes on when the callback returns; spawn it to wait.
    /// A callback that panics loses that sample only:
    /// the panic is caught (and logged), and the next sample calls it
    /// again. Dropping the [`Listener`] unsubscribes.
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
    ///
    /// [`Publisher::try_publish`]: crate::Publisher::try_publish
    pub async fn listen<F>(self, mut f: F) -> Result<Listener, OpenError>
    where
        F: FnMut(Result<D::Item, RecvError>) + Send + 'static,
    {
        let queue = SampleQueue::new(self.queue_policy()?);
        let enc = self.session.enc();
        let skipped = Arc::new(std::sync::atomic::AtomicU64::new(0));
        let count = skipped.clone();
        let mut check = FormatCheck::default();
        let end = self.session.end.clone();
        queue.set_handler(move |q, s| {
            let Some(s) = s else {
                // a `close()` asked for is no error to report
                if !end.ended() {
                    f(Err(RecvError::Disconnected));
                }
                return;
            };
            match convert::<T, D>(enc, q, &mut check, s) {
                Some(r) => f(r),
                None => {
                    count.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                }
            }
        });
        let raw = self.create(queue.clone()).await?;
        if !self.session.caps.immediate_delivery {
            let session = self.session.end.clone();
            self.session.home.spawn(async move {
                while std::future::poll_fn(|cx| queue.poll_waiting(cx)).await {
                    session.in_callback(|| queue.run_handler());
                }
            });
        }
        Ok(Listener {
            raw,
            msg: self.msg,
            skipped,
        })
    }

    /// Creates the subscription.
    pub async fn build(self) -> Result<Subscriber<T, D>, OpenError> {
        let queue = SampleQueue::new(self.queue_policy()?);
        let raw = self.create(queue).await?;
        Ok(Subscriber {
            raw,
            msg: self.msg,
            enc: self.session.enc(),
            check: FormatCheck::default(),
            decode_errors: 0,
            skipped: 0,
            end: self.session.end.clone(),
            _t: PhantomData,
        })
    }
}

/// An immediate-delivery subscription
/// ([`SubscriberBuilder::listen`]); dropping it unsubscribes (a callback
/// already running finishes).
#[derive(Debug)]
#[must_use = "dropping it unsubscribes"]
pub struct Listener {
    raw: RawSubscriber,
    msg: String,
    skipped: Arc<std::sync::atomic::AtomicU64>,
}

impl Listener {
    /// The message subscribed.
    pub fn msg(&self) -> &str {
        &self.msg
    }

    /// Samples dropped by a keep-last policy or a backend filter so far,
    /// (IPC) messages whose body did not hold together, (DDS) samples
    /// larger than the session takes ([`SessionEvent::SampleLost`](crate::SessionEvent::SampleLost)),
    /// and (XRCE) samples whose fragments passed the 1 MiB a session
    /// rebuilds (each logged as a warning).
    pub fn dropped(&self) -> u64 {
        self.raw.dropped()
    }

    /// Instance state changes the callback did not get, because it takes
    /// samples only (see [`SubscriberBuilder::with_instances`]).
    pub fn instance_changes_skipped(&self) -> u64 {
        self.skipped.load(std::sync::atomic::Ordering::Relaxed)
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
    /// Who sent it, when the backend knows (DDS: the writer's GUID, as
    /// [`SessionEvent`](crate::SessionEvent)s name it; its `Display` is the
    /// 32 hex digits DDS tools print).
    ///
    /// Always `None` on IPC: a delivery frame's header (`classTotal`,
    /// `msgTotal`, `parentRef`, `intent`, `classId`, `dispatchRef`,
    /// `msgRef`) names no sender, central adds none, and a direct link
    /// starts without a handshake, so its receiving end does not learn who
    /// opened it either (CMU IPC has no such call for the same reason). Put
    /// the sender in the message if the receiver needs it.
    pub source: Option<crate::event::Guid>,
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
    /// The session lost its connection; the stream ends after this. (A
    /// session closed by [`Session::close`] ends its streams without it.)
    #[error("disconnected")]
    Disconnected,
    /// IPC: the message's format, as central holds it (its definer's),
    /// does not fit the subscriber's type, so its data would read as wrong
    /// values; it is skipped undecoded. Every message of that format gives
    /// this error, until the definition changes. Define the message with
    /// the type the subscriber reads, or subscribe with the sender's.
    #[error("{msg} is sent as {central} (central's format), which does not fit {ty}: {detail}")]
    FormatMismatch {
        /// Message name.
        msg: String,
        /// The subscriber's type.
        ty: &'static str,
        /// Central's format of the message.
        central: String,
        /// Where they differ.
        detail: String,
    },
}

/// A typed subscription: a `Stream` of samples (and, built
/// [`with_instances`](SubscriberBuilder::with_instances), instance state
/// changes). Dropping it unsubscribes.
#[must_use = "dropping it unsubscribes"]
pub struct Subscriber<T, D = Samples> {
    raw: RawSubscriber,
    msg: String,
    enc: Encoding,
    /// IPC: central's format of the message against `T`.
    check: FormatCheck,
    decode_errors: u64,
    skipped: u64,
    /// Whether the session was closed by its user (the stream then ends
    /// without `Err(Disconnected)`).
    end: Arc<SessionEnd>,
    _t: PhantomData<fn() -> (T, D)>,
}

/// The key of an instance change, decoded to `T::Key` (see
/// [`InstanceChange::key`]): from the serialized key, else from the key
/// hash read in `version`, the XCDR version of the writer's data (XCDR2,
/// the specification's form, when the backend does not say).
fn change_key<T: IpcMessage>(
    enc: Encoding,
    data: &[u8],
    key_hash: Option<[u8; 16]>,
    version: Option<cdr::Version>,
) -> Option<T::Key> {
    if T::KEYS.is_empty() || enc != Encoding::Cdr {
        return None;
    }
    let from_key = (!data.is_empty())
        .then(|| cdr::key_from_slice::<T>(data).ok())
        .flatten();
    let version = version.unwrap_or(cdr::Version::Xcdr2);
    from_key.or_else(|| key_hash.and_then(|h| cdr::key_from_key_hash_in::<T>(&h, version)))
}

/// A raw sample as the typed item (or why not): what both a
/// [`Subscriber`] and a [`Listener`]'s callback see; `None` for an
/// instance change that `D` skips.
fn convert<T: IpcMessage, D: Delivery<T>>(
    enc: Encoding,
    queue: &SampleQueue,
    check: &mut FormatCheck,
    s: RawSample,
) -> Option<Result<D::Item, RecvError>> {
    // IPC: the backend tags a sample with central's format of the message
    if let (Encoding::Ipc, Some(theirs)) = (enc, &s.type_name) {
        if let Err(e) = check.check::<T>(&s.msg, theirs) {
            queue.give_back(s.data);
            return Some(Err(e));
        }
    }
    if s.state != InstanceState::Alive {
        let key = change_key::<T>(enc, &s.data, s.key_hash, s.key_hash_version);
        return D::change(InstanceChange {
            msg: s.msg,
            state: s.state,
            key,
            key_hash: s.key_hash,
            key_hash_version: s.key_hash_version,
            received: s.received,
            source: s.source,
            source_time: s.source_time,
        })
        .map(Ok);
    }
    let decoded = decode::<T>(enc, &s.data, s.order);
    queue.give_back(s.data);
    Some(match decoded {
        Ok(value) => Ok(D::sample(Sample {
            value,
            msg: s.msg,
            received: s.received,
            source: s.source,
            source_time: s.source_time,
        })),
        Err(detail) => Err(RecvError::Decode {
            msg: s.msg,
            ty: std::any::type_name::<T>(),
            detail,
        }),
    })
}

impl<T: IpcMessage, D: Delivery<T>> Subscriber<T, D> {
    /// The item of a popped sample; `None` for a skipped instance change.
    fn convert(&mut self, s: RawSample) -> Option<Result<D::Item, RecvError>> {
        let r = convert::<T, D>(self.enc, &self.raw.queue, &mut self.check, s);
        match &r {
            Some(Err(RecvError::Decode { .. } | RecvError::FormatMismatch { .. })) => {
                self.decode_errors += 1
            }
            None => self.skipped += 1,
            _ => {}
        }
        r
    }

    /// The next sample, waiting for it; `None` at the end of the stream
    /// (see [How streams end](crate#rules)). The `Stream`'s `next()`
    /// without importing `futures::StreamExt`, named like tokio's receivers.
    pub async fn recv(&mut self) -> Option<Result<D::Item, RecvError>> {
        futures::StreamExt::next(self).await
    }

    /// Pulled delivery (ORTE's `ORTEAppSubscriptionPull`): the next sample
    /// if one is waiting, without waiting; `None` when none is waiting
    /// (not the end of the stream: for that, poll the `Stream`).
    ///
    /// Named like [`RawSubscriber::try_recv`] and tokio's receivers, so
    /// that it never shadows `futures::TryStreamExt::try_next`, which
    /// waits.
    pub fn try_recv(&mut self) -> Option<Result<D::Item, RecvError>> {
        loop {
            let s = match self.raw.queue.try_pop()? {
                Popped::Sample(s) => s,
                Popped::End => return self.lost().then_some(Err(RecvError::Disconnected)),
            };
            if let Some(r) = self.convert(s) {
                return Some(r);
            }
        }
    }

    /// At the end: whether the connection was lost (the stream yields
    /// `Err(Disconnected)`), not closed by the session's user (it just ends).
    fn lost(&self) -> bool {
        !self.end.ended()
    }
}

impl<T: IpcMessage, D: Delivery<T>> Stream for Subscriber<T, D> {
    type Item = Result<D::Item, RecvError>;

    fn poll_next(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<Option<Self::Item>> {
        loop {
            match self.raw.queue.poll_pop(cx) {
                Poll::Ready(Some(Popped::Sample(s))) => {
                    if let Some(r) = self.convert(s) {
                        return Poll::Ready(Some(r));
                    }
                }
                Poll::Ready(Some(Popped::End)) if self.lost() => {
                    return Poll::Ready(Some(Err(RecvError::Disconnected)))
                }
                Poll::Ready(Some(Popped::End)) => return Poll::Ready(None),
                Poll::Ready(None) => return Poll::Ready(None),
                Poll::Pending => return Poll::Pending,
            }
        }
    }
}

impl<T, D> Subscriber<T, D> {
    /// Instance state changes skipped so far: a subscriber that takes
    /// samples only does not yield them (see
    /// [`SubscriberBuilder::with_instances`]).
    pub fn instance_changes_skipped(&self) -> u64 {
        self.skipped
    }

    /// The message subscribed.
    pub fn msg(&self) -> &str {
        &self.msg
    }

    /// Samples dropped by a keep-last policy or a backend filter so far,
    /// (IPC) messages whose body did not hold together, (DDS) samples
    /// larger than the session takes ([`SessionEvent::SampleLost`](crate::SessionEvent::SampleLost)),
    /// and (XRCE) samples whose fragments passed the 1 MiB a session
    /// rebuilds (each logged as a warning).
    pub fn dropped(&self) -> u64 {
        self.raw.dropped()
    }

    /// Samples that did not decode as `T` so far (each was yielded as a
    /// [`RecvError::Decode`]).
    pub fn decode_errors(&self) -> u64 {
        self.decode_errors
    }
}

// (by hand: a derive would want `T: Debug`)
impl<T, D> std::fmt::Debug for Subscriber<T, D> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Subscriber")
            .field("msg", &self.msg)
            .field("type", &std::any::type_name::<T>())
            .field("decode_errors", &self.decode_errors)
            .finish_non_exhaustive()
    }
}

impl<T, D> std::fmt::Debug for SubscriberBuilder<T, D> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SubscriberBuilder")
            .field("msg", &self.msg)
            .field("type", &std::any::type_name::<T>())
            .field("qos", &self.qos)
            .field("queue", &self.policy)
            .finish_non_exhaustive()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::backend::SubId;
    use crate::queue::ReturnedBuffers;
    use crate::session::Owned;

    fn subscriber<T>(queue: &Arc<SampleQueue>) -> Subscriber<T> {
        subscriber_of(queue)
    }

    fn subscriber_of<T, D>(queue: &Arc<SampleQueue>) -> Subscriber<T, D> {
        Subscriber {
            raw: RawSubscriber::new(
                queue.clone(),
                Owned {
                    backend: None,
                    handle: Handle::Subscription(SubId(0)),
                    uses: Vec::new(),
                },
            ),
            msg: "m".into(),
            enc: Encoding::Cdr,
            check: FormatCheck::default(),
            decode_errors: 0,
            skipped: 0,
            end: Arc::default(),
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
    fn without_a_backend_that_reuses_them_buffers_are_freed() {
        let queue = SampleQueue::new(QueuePolicy::default());
        let mut sub = subscriber::<String>(&queue);
        let big = cdr::to_vec(&"x".repeat(10_000), cdr::Encoding::Xcdr1Le);
        queue.push(RawSample::new("m", big)).unwrap();
        assert_eq!(sub.try_recv().unwrap().unwrap().value.len(), 10_000);
        assert!(queue.returns.get().is_none());
    }

    /// `struct Stamped { @key long id; @key long long stamp; }`: its key
    /// hash differs between XCDR1 (`id`, 4 bytes of padding, `stamp`) and
    /// XCDR2 (`id`, `stamp`, the hash's padding).
    #[derive(courier_derive::IpcMessage, Debug, Clone, PartialEq)]
    #[ipc(type_name = "Stamped", crate = "::courier_wire")]
    struct Stamped {
        #[ipc(key)]
        id: i32,
        #[ipc(key)]
        stamp: i64,
        v: u8,
    }

    /// A dispose that carries only the key hash (Fast DDS sends no
    /// serialized key): the key is read from the hash in the XCDR version
    /// of the writer's data, which the backend says.
    #[test]
    fn a_key_is_read_from_a_hash_in_the_writers_version() {
        let queue = SampleQueue::new(QueuePolicy::default());
        let mut sub = subscriber_of::<Stamped, WithInstances>(&queue);
        let v = Stamped {
            id: 7,
            stamp: 0x0102_0304_0506_0708,
            v: 0,
        };
        let dispose = |version: Option<cdr::Version>, hash: [u8; 16]| {
            let mut s = RawSample::new("m", Vec::new());
            s.state = InstanceState::Disposed;
            s.key_hash = Some(hash);
            s.key_hash_version = version;
            s
        };
        let x1 = courier_wire::key_hash_in(&v, cdr::Version::Xcdr1);
        let x2 = courier_wire::key_hash_in(&v, cdr::Version::Xcdr2);
        assert_ne!(x1, x2);
        queue.push(dispose(Some(cdr::Version::Xcdr1), x1)).unwrap();
        queue.push(dispose(Some(cdr::Version::Xcdr2), x2)).unwrap();
        // a backend that does not say: the specification's form, XCDR2
        queue.push(dispose(None, x2)).unwrap();
        for want in [Some(cdr::Version::Xcdr1), Some(cdr::Version::Xcdr2), None] {
            match sub.try_recv() {
                Some(Ok(crate::Received::Instance(c))) => {
                    assert_eq!(c.key, Some((7, 0x0102_0304_0506_0708)), "{want:?}");
                    assert_eq!(c.key_hash_version, want);
                }
                other => panic!("{want:?}: expected a dispose, got {other:?}"),
            }
        }
    }
}
