//! Publications: [`Publish`], [`PublisherBuilder`], [`Publisher`], [`PeriodicPublication`].

use crate::backend::{Handle, PubId, WriteNow};
use crate::error::{OpenError, PublishError};
use crate::qos::{
    DataRepresentation, Durability, History, InstanceState, PublicationQos, Reliability,
};
use crate::session::{Owned, Session};
use crate::timer::Tick;
use crate::topics::Definition;
use courier_wire::{cdr, IpcMessage};
use std::future::Future;
use std::marker::PhantomData;
use std::pin::Pin;
use std::sync::Arc;
use std::task::{Context, Poll};
use std::time::Duration;

/// How [`Backend::write`] publishes.
///
/// [`Backend::write`]: crate::Backend::write
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[non_exhaustive]
pub struct WriteOptions {
    /// The instance's key hash (keyed DDS topics).
    pub key_hash: Option<[u8; 16]>,
    /// Wait at most this long for every matched reader's acknowledgement.
    pub confirm: Option<Duration>,
}

/// A publish being built; `.await` it.
///
/// Cancelling it (dropping the future, as `tokio::time::timeout` does) does
/// not take back a sample the session already took: one that waited for
/// room (back-pressure) may still be sent and delivered after the future
/// was dropped. Bound the wait with `.confirmed_within(..)` (DDS) to
/// know; a timed-out confirmed publish may also still arrive.
#[derive(Debug)]
#[must_use = "a publish does nothing until awaited"]
pub struct Publish<'a> {
    pub(crate) session: &'a Session,
    pub(crate) msg: &'a str,
    pub(crate) data: Vec<u8>,
    pub(crate) confirm: Option<Duration>,
    pub(crate) key_hash: Option<[u8; 16]>,
    /// Where it goes: an open publication, or the definition of the
    /// session's publication to make first; or the type mismatch.
    pub(crate) target: Result<Target, PublishError>,
    /// A first use's binding, let go if it is dropped unsettled.
    pub(crate) first: Option<crate::topics::Unsettled<'a>>,
}

/// Where a [`Publish`] goes.
#[derive(Debug)]
pub(crate) enum Target {
    Open(PubId),
    Define(Definition),
}

impl<'a> Publish<'a> {
    /// Resolve only once every matched reader has acknowledged the sample
    /// (reliable DDS writers), waiting at most 10 s
    /// ([`confirmed_within`](Self::confirmed_within) gives the bound).
    ///
    /// As DDS's `wait_for_acknowledgments`: the readers waited for are
    /// those matched while it waits. A reader that leaves (or whose lease
    /// ends) before acknowledging is no longer waited for, best-effort
    /// readers never are, and with no reliable reader it resolves at once.
    /// To know that somebody got it, wait for readers first
    /// ([`Session::num_handlers`](crate::Session::num_handlers)). A reader
    /// that gives a sample up as larger than it takes (its
    /// `max_sample_size`; it reports `SessionEvent::SampleLost`)
    /// acknowledges it too. A confirmed publish that times out was still
    /// sent, and may arrive later: publishing it again can deliver it twice.
    pub fn confirmed(mut self) -> Self {
        self.confirm.get_or_insert(Duration::from_secs(10));
        self
    }

    /// [`confirmed`](Self::confirmed), waiting at most `d` for the
    /// acknowledgements (`Duration::MAX`: as long as it takes).
    pub fn confirmed_within(mut self, d: Duration) -> Self {
        self.confirm = Some(d);
        self
    }

    /// The old name of [`confirmed_within`](Self::confirmed_within): it
    /// makes the publish a confirmed one, which its name did not say (an
    /// IPC session refuses confirmed publishes), and it does not bound the
    /// wait for room of an unconfirmed publish (wrap that in
    /// `tokio::time::timeout`).
    #[deprecated(note = "it makes the publish confirmed: use .confirmed_within(d)")]
    pub fn timeout(self, d: Duration) -> Self {
        self.confirmed_within(d)
    }
}

impl<'a> std::future::IntoFuture for Publish<'a> {
    type Output = Result<(), PublishError>;
    type IntoFuture = PublishFuture<'a>;

    fn into_future(self) -> Self::IntoFuture {
        let opts = WriteOptions {
            key_hash: self.key_hash,
            confirm: self.confirm,
        };
        PublishFuture(match self.target {
            Err(e) => Step::Done(Some(Err(e))),
            Ok(Target::Open(id)) => Step::Now {
                session: self.session,
                id,
                data: self.data,
                opts,
            },
            Ok(Target::Define(def)) => Step::Wait(
                Box::pin(async move {
                    let _first = self.first;
                    let r = self.session.define_shared(self.msg, def).await;
                    let id = self.session.settled(&[self.msg], r)?;
                    self.session.backend.write(id, self.data, opts).await
                }),
                self.session,
            ),
        })
    }
}

/// The future of a [`Publish`]. A publish that need not wait (the usual
/// case) is done in its first poll with no allocation of its own
/// ([`Backend::write_now`](crate::Backend::write_now)); it still counts
/// against tokio's cooperative budget, so that a publishing loop lets
/// other tasks run.
#[must_use = "futures do nothing unless polled"]
pub struct PublishFuture<'a>(Step<'a>);

enum Step<'a> {
    Now {
        session: &'a Session,
        id: PubId,
        data: Vec<u8>,
        opts: WriteOptions,
    },
    /// With the session, whose runtime the poll enters from a thread
    /// outside any (a confirmed XRCE publish makes a tokio timer).
    Wait(
        Pin<Box<dyn Future<Output = Result<(), PublishError>> + Send + 'a>>,
        &'a Session,
    ),
    Done(Option<Result<(), PublishError>>),
}

impl std::fmt::Debug for PublishFuture<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let step = match &self.0 {
            Step::Now { .. } => "not polled",
            Step::Wait(..) => "waiting",
            Step::Done(_) => "done",
        };
        f.debug_tuple("PublishFuture").field(&step).finish()
    }
}

impl Future for PublishFuture<'_> {
    type Output = Result<(), PublishError>;

    fn poll(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<Self::Output> {
        loop {
            match std::mem::replace(&mut self.0, Step::Done(None)) {
                Step::Now {
                    session,
                    id,
                    data,
                    opts,
                } => {
                    let Poll::Ready(coop) = tokio::task::coop::poll_proceed(cx) else {
                        self.0 = Step::Now {
                            session,
                            id,
                            data,
                            opts,
                        };
                        return Poll::Pending;
                    };
                    match session.backend.write_now(id, data, opts) {
                        WriteNow::Done(r) => {
                            coop.made_progress();
                            return Poll::Ready(r);
                        }
                        WriteNow::Wait(data, opts) => {
                            self.0 = Step::Wait(session.backend.write(id, data, opts), session);
                        }
                    }
                }
                Step::Wait(mut f, session) => {
                    let r = {
                        let _in = session.home.enter();
                        f.as_mut().poll(cx)
                    };
                    if r.is_pending() {
                        self.0 = Step::Wait(f, session);
                    }
                    return r;
                }
                Step::Done(r) => return Poll::Ready(r.unwrap_or(Err(PublishError::Completed))),
            }
        }
    }
}

/// Builds a [`Publisher`]: ORTE's publication parameters as DDS QoS.
#[must_use = "a builder does nothing until `.build().await`"]
pub struct PublisherBuilder<T> {
    pub(crate) session: Session,
    pub(crate) msg: String,
    pub(crate) qos: PublicationQos,
    pub(crate) _t: PhantomData<fn(T)>,
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

    /// Keep only the newest `n` samples per instance; `build` refuses 0
    /// ([`OpenError::Qos`]).
    pub fn keep_last(mut self, n: u32) -> Self {
        self.qos.history = History::KeepLast(n);
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

    /// The offered liveliness: `kind` within `lease` (see
    /// [`qos`](crate::qos#liveliness)). With a manual kind, publish or
    /// [`Publisher::assert_liveliness`] within every `lease`, or the
    /// session reports [`SessionEvent::LivelinessLost`](crate::SessionEvent::LivelinessLost)
    /// and readers see the publication not alive. `build` refuses a lease
    /// under [`MIN_LEASE`](crate::qos::MIN_LEASE) ([`OpenError::Qos`]) and
    /// liveliness on IPC, or on XRCE in the binary or reference
    /// representation ([`OpenError::Unsupported`]; XRCE with
    /// `representation=xml` offers it, see [`qos`](crate::qos#liveliness)).
    pub fn liveliness(mut self, kind: crate::qos::LivelinessKind, lease: Duration) -> Self {
        self.qos.liveliness = Some(crate::qos::Liveliness::new(kind, lease));
        self
    }

    /// Adds a DDS partition.
    pub fn partition(mut self, p: impl Into<String>) -> Self {
        self.qos.partitions.push(p.into());
        self
    }

    /// Writes this representation instead of the one the type calls for
    /// (XCDR1 for a final type, XCDR2 for an appendable or mutable one):
    /// XCDR2 for readers that ask for it, XCDR1 for Fast DDS 2.9.
    pub fn data_representation(mut self, r: DataRepresentation) -> Self {
        self.qos.data_representation = Some(r);
        self
    }

    /// Whether closing the publication disposes the instances it leaves
    /// alive, and [`Publisher::unregister`] disposes what it unregisters
    /// (DDS's `autodispose_unregistered_instances`; the default). `false`
    /// unregisters them only: their readers see them not-alive-no-writers.
    /// Closing is dropping the last clone of the [`Publisher`] (or the
    /// session).
    pub fn autodispose(mut self, on: bool) -> Self {
        self.qos.autodispose = on;
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
        crate::qos::check_history(&self.msg, self.qos.history)?;
        crate::qos::check_liveliness(&self.msg, self.qos.liveliness)?;
        if self.qos.liveliness.is_some() && !self.session.caps.offers_liveliness {
            return Err(OpenError::Unsupported {
                what: format!("liveliness on the publication of {}", self.msg),
                backend: self.session.caps.scheme,
            });
        }
        self.session.topics.bind::<T>(&self.msg)?;
        let id = {
            let _first = self.session.topics.unsettled(&[&self.msg]);
            let r = self
                .session
                .open_as(&self.msg, &Definition::of::<T>(), &self.qos)
                .await;
            self.session.settled(&[&self.msg], r)?
        };
        Ok(Publisher {
            handle: Arc::new(
                self.session
                    .owned(Handle::Publication(id))
                    .binding(self.session.topics.hold::<T>(&self.msg)),
            ),
            id,
            cdr: self.qos.representation_for(T::EXTENSIBILITY).encoding(),
            session: self.session,
            msg: self.msg,
            last_len: Arc::default(),
            _t: PhantomData,
        })
    }
}

/// A typed publication handle (DDS: a DataWriter).
pub struct Publisher<T> {
    session: Session,
    id: PubId,
    /// Closes the publication when the last clone goes.
    handle: Arc<Owned>,
    msg: String,
    /// The CDR encoding of its data representation.
    cdr: cdr::Encoding,
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
            cdr: self.cdr,
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
        let p =
            self.session
                .publish_sized(&self.msg, value, hint, self.cdr, Ok(Target::Open(self.id)));
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
        // a value it refuses (a Vec its length field cannot say)
        p.target?;
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

    /// Unregisters the instance that `value`'s key fields name (keyed
    /// topics). With [`autodispose`](PublisherBuilder::autodispose) on (the
    /// default) it is disposed as well, as DDS's
    /// `autodispose_unregistered_instances` says: readers see it disposed;
    /// with it off, they see it without writers once no other writer has
    /// it.
    pub async fn unregister(&self, value: &T) -> Result<(), PublishError> {
        self.end(value, InstanceState::Unregistered).await
    }

    /// Asserts the publication's liveliness without publishing (DDS's
    /// `DataWriter::assert_liveliness`), for a manual
    /// [`liveliness`](PublisherBuilder::liveliness): manual by topic, a
    /// HEARTBEAT with the liveliness flag to its readers; manual by
    /// participant, also a participant message that asserts every such
    /// publication of the session. Each publish asserts too. Harmless for
    /// an automatic one. [`PublishError::Unsupported`] on a backend other
    /// than RTPS.
    pub async fn assert_liveliness(&self) -> Result<(), PublishError> {
        match self.session.backend.dds() {
            Some(dds) if self.session.caps.liveliness => dds.assert_liveliness(self.id).await,
            _ => Err(PublishError::Unsupported {
                what: format!("asserting the liveliness of {}", self.msg),
                backend: self.session.caps.scheme,
            }),
        }
    }

    async fn end(&self, value: &T, state: InstanceState) -> Result<(), PublishError> {
        if T::KEYS.is_empty() {
            return Err(PublishError::NotKeyed(T::TYPE_NAME));
        }
        // The serialized key (K flag) and the inline KEY_HASH: Cyclone DDS 11
        // finds the instance only by the key, Fast DDS 2.9 only by the hash
        // (the participant sends it the hash alone).
        let key = cdr::key_to_vec(value, self.cdr);
        // in the version of the publication's data, as its samples' hashes
        let hash = crate::rtps_backend::key_hash_of(value, self.cdr.version());
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
        let task = self.session.home.spawn(async move {
            use futures::StreamExt;
            let mut timer = p.session.every(period);
            while let Some(tick) = timer.next().await {
                if let Some(v) = f(tick) {
                    p.publish(&v).await?;
                }
            }
            Ok(())
        });
        PeriodicPublication {
            task,
            msg: self.msg.clone(),
        }
    }
}

/// A publication driven by a timer ([`Publisher::send_every`]); dropping it stops it.
#[derive(Debug)]
#[must_use = "dropping it stops the periodic publication"]
pub struct PeriodicPublication {
    task: tokio::task::JoinHandle<Result<(), PublishError>>,
    msg: String,
}

impl PeriodicPublication {
    /// Stops it and returns why it ended, if it ended by itself: a publish
    /// that failed, or [`PublishError::Panicked`] when its function panicked.
    pub async fn stop(mut self) -> Result<(), PublishError> {
        self.task.abort();
        match (&mut self.task).await {
            Ok(r) => r,
            Err(e) if e.is_panic() => {
                let p = e.into_panic();
                let panic = p
                    .downcast_ref::<&str>()
                    .map(|s| s.to_string())
                    .or_else(|| p.downcast_ref::<String>().cloned())
                    .unwrap_or_else(|| "(not a string)".into());
                Err(PublishError::Panicked {
                    msg: std::mem::take(&mut self.msg),
                    panic,
                })
            }
            Err(_) => Ok(()), // stopped here
        }
    }
}

impl Drop for PeriodicPublication {
    fn drop(&mut self) {
        self.task.abort();
    }
}

// (by hand: a derive would want `T: Debug`)
impl<T> std::fmt::Debug for Publisher<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Publisher")
            .field("msg", &self.msg)
            .field("type", &std::any::type_name::<T>())
            .finish_non_exhaustive()
    }
}

impl<T> std::fmt::Debug for PublisherBuilder<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PublisherBuilder")
            .field("msg", &self.msg)
            .field("type", &std::any::type_name::<T>())
            .field("qos", &self.qos)
            .finish_non_exhaustive()
    }
}
