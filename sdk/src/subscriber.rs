//! Typed subscriptions: [`SubscriberBuilder`], [`Subscriber`], [`Listener`], [`Sample`].

use crate::backend::Handle;
use crate::error::OpenError;
use crate::qos::{Durability, History, InstanceState, Reliability, SubscriptionQos, TypeInfo};
use crate::queue::{Popped, QueuePolicy, RawSample, RawSubscriber, SampleQueue};
use crate::session::{decode, Encoding, Session};
use courier_wire::IpcMessage;
use futures::Stream;
use std::marker::PhantomData;
use std::pin::Pin;
use std::sync::Arc;
use std::task::{Context, Poll};
use std::time::{Duration, SystemTime};

/// Builds a [`Subscriber`]: ORTE's subscription parameters as DDS QoS.
#[derive(Debug)]
pub struct SubscriberBuilder<T> {
    pub(crate) session: Session,
    pub(crate) msg: String,
    pub(crate) qos: SubscriptionQos,
    pub(crate) policy: Option<QueuePolicy>,
    pub(crate) _t: PhantomData<fn() -> T>,
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
    ///
    /// [`SessionEvent::DeadlineMissed`]: crate::SessionEvent::DeadlineMissed
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
    ///
    /// [`Publisher::try_publish`]: crate::Publisher::try_publish
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::backend::SubId;
    use crate::queue::ReturnedBuffers;
    use crate::session::Owned;
    use courier_wire::cdr;

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
    fn without_a_backend_that_reuses_them_buffers_are_freed() {
        let queue = SampleQueue::new(QueuePolicy::default());
        let mut sub = subscriber::<String>(&queue);
        let big = cdr::to_vec(&"x".repeat(10_000), cdr::Encoding::Xcdr1Le);
        queue.push(RawSample::new("m", big)).unwrap();
        assert_eq!(sub.try_recv().unwrap().unwrap().value.len(), 10_000);
        assert!(queue.returns.get().is_none());
    }
}
