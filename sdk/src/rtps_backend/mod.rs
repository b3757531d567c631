//! The RTPS backend (`rtps://<domain>`): a DDSI-RTPS 2.x participant that
//! Cyclone DDS, Fast DDS and the other DDS implementations see as one of
//! theirs.
//!
//! The protocol is [`courier_wire::rtps::participant::Participant`], a
//! sans-I/O state machine; this module gives it sockets and a clock. One
//! driver task per session reads the sockets and keeps the timers; the
//! [`Backend`] methods send it commands. Everything else — matching, QoS
//! compatibility, reliability, fragmentation, discovery — is in `wire`.
//!
//! Delivery comes in ORTE's two kinds. A [`crate::Subscriber`] is a
//! `Stream` (pulled with `try_recv`, or awaited by a task). A subscription
//! made with [`SubscriberBuilder::listen`](crate::SubscriberBuilder::listen)
//! is *immediate*: its callback runs where the datagram was read, right
//! after the participant has taken it, and can answer on the spot with
//! [`Publisher::try_publish`](crate::Publisher::try_publish); the answers
//! go out together when the callbacks return. With `receive_thread` user
//! data is read by a thread of its own blocked in `recvmmsg` (ORTE's and
//! Cyclone DDS's way), which saves the wake-up of a tokio task per
//! datagram; otherwise the driver task reads it and runs the callbacks.
//! The participant and what surrounds it (`State`) sit behind one lock
//! shared by the driver, the receive thread and `try_publish`; callbacks
//! run with no lock held.
//!
//! What the driver adds on top of the protocol, per subscription:
//!
//! - **exclusive ownership** (ORTE's strength): with
//!   [`SubscriptionQos::exclusive`], each instance is taken only from the
//!   strongest live writer (ties: the lower GUID), as DDS specifies;
//! - **minimum separation** (DDS time-based filter): samples of an instance
//!   closer than this to the last delivered one are dropped and counted;
//! - **lifespan** (ORTE's persistence): samples older than their writer's
//!   lifespan (by source timestamp) are dropped and counted;
//! - **deadline**: an instance without a sample for the period gives
//!   [`SessionEvent::DeadlineMissed`], again every period until one comes;
//! - **liveliness** ([`crate::qos#liveliness`]): a subscription that
//!   requests one tracks each matched writer offering a finite lease, and
//!   reports [`SessionEvent::LivelinessChanged`] (with the writer's GUID)
//!   when it matches, when its lease lapses — by the writer's kind:
//!   anything from its participant for automatic, its participant's manual
//!   messages or writes for manual by participant, its own data or
//!   liveliness heartbeats for manual by topic — when it asserts itself
//!   again, and when it leaves. The driver's timer includes the lease
//!   expiries. A publication with a finite automatic lease makes the
//!   participant send a participant message (DDSI-RTPS's
//!   `ParticipantMessageData`, the writer liveliness protocol) every third
//!   of the shortest such lease; a manual one that neither publishes nor
//!   [asserts](crate::Publisher::assert_liveliness) within its lease gives
//!   [`SessionEvent::LivelinessLost`];
//! - **back-pressure**: a reliable keep-all subscription whose queue is full
//!   stops the reading of user data until the application takes a sample;
//!   what the kernel drops meanwhile the writers repair. A best-effort one
//!   drops and counts.
//!
//! Datagrams: on the loopback interface a participant sends datagrams of up
//! to [`LOOPBACK_MAX_MESSAGE_SIZE`] (65 500 bytes, Fast DDS's default; `lo`
//! fragments nothing at the IP level), elsewhere Cyclone's 14 720; a 64 KiB
//! sample then costs two sends and two receives instead of five. Received
//! sample buffers are reused once a typed [`crate::Subscriber`] has decoded
//! them.
//!
//! Network safety: when the chosen interface is a loopback one, datagrams
//! to any other address are not sent (counted, never leaked), and without
//! `multicast` no multicast datagram leaves, whatever peers announce.
//!
//! # DDS semantics, and where Cyclone DDS and Fast DDS differ
//!
//! Checked scenario by scenario against Cyclone DDS 11 and Fast DDS 2.9
//! (the same writers read by each side's reader, with the same QoS).
//! Where DDS 1.4 leaves a choice or the two differ, Courier does this:
//!
//! - **Instance states** (§2.2.2.5.1): an instance whose last live writer
//!   unregisters it, or goes without a word for it (deleted, its
//!   participant lost, its liveliness lapsed), is `Unregistered`
//!   (NOT_ALIVE_NO_WRITERS). A deleted Cyclone writer whose autodispose is
//!   on has its instances `Disposed` instead, as Cyclone's readers take
//!   them (Cyclone sends nothing per instance and announces the policy);
//!   a Cyclone writer that is *lost* stays `Unregistered` here, where
//!   Cyclone's readers dispose its instances too.
//! - **Unregister** disposes too while `autodispose` is on (Cyclone does
//!   the same; the spec's `autodispose_unregistered_instances`).
//! - **Keep-last** is per instance in the subscription's queue as in a
//!   DDS reader's history; Fast DDS also counts dispose and unregister
//!   notices against the depth, Courier keeps them beside the samples.
//! - **Volatile readers** start at a transient-local writer's first
//!   heartbeat (as Cyclone's), and take what a volatile writer has not
//!   had acknowledged yet when they match.
//! - **Transient-local history** forgets an instance its writer
//!   unregistered (as Cyclone and Fast DDS): once every matched reader has
//!   acknowledged them, its samples and the unregister leave the history,
//!   so late joiners get only live instances.
//! - **Lifespan** is applied by the writer (its history) and by the reader
//!   (by source timestamp); a Fast DDS 2.9 reader delivers expired samples.
//!   A publish that waited is stamped when it was called.
//! - **Partitions** (§2.2.3.13) match by POSIX fnmatch (`*`, `?`, `[...]`);
//!   two patterns never match each other (as Cyclone; Fast DDS matches
//!   them) and `*` matches the default partition (Fast DDS does not).
//!   Different partitions raise no `IncompatibleQos`.
//! - **Durations** (deadline, lease) compare to the nanosecond, however a
//!   peer rounded them into 2^-32 s fractions, and go out rounded up as
//!   Cyclone's do.
//! - **Exclusive ownership**: ties go to the lower GUID, compared byte by
//!   byte (as Fast DDS; Cyclone compares host-order words, so the two can
//!   pick different owners); an owner that misses its deadline, lapses or
//!   unregisters hands the instance to the next writer (Cyclone keeps an
//!   owner that missed its deadline); only the owner disposes.
//! - **Deadlines** are not counted for disposed instances, nor for ones no
//!   writer has any more; Cyclone and Fast DDS go on counting them.
//! - **Manual liveliness**: a writer is alive from its match (as Cyclone);
//!   Fast DDS counts it from its first write or assertion.
//! - **A full keep-all history** makes `publish` wait, without DDS's
//!   `max_blocking_time` and TIMEOUT (Fast DDS returns TIMEOUT after
//!   the reliability's `max_blocking_time`, 100 ms by default): put a `tokio::time::timeout` around it.
//! - **A deadline or lease of zero** is refused; Cyclone and Fast DDS take
//!   them.

mod cmd;
mod driver;
mod linger;
mod net;
mod options;
mod out;
mod receive;
pub mod ros2;
mod state;

use std::net::SocketAddr;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant, SystemTime};

// seeded per process
use foldhash::HashMap;

use courier_wire::dds::Domain;
use courier_wire::rtps::participant::{self, ChangeKind, Config, KeyHash, MAX_WRITE_SIZE};
use courier_wire::rtps::{Guid, GuidPrefix, Locator, Time};
use courier_wire::IpcMessage;
use tokio::sync::{mpsc, oneshot, OwnedSemaphorePermit, Semaphore};

use crate::backend::{
    Backend, Capabilities, ClientId, DdsControl, Handle, PubId, ServiceId, SubId, WriteNow,
};
use crate::busy_poll::BusyPoll;
use crate::error::{ControlError, Failure, OpenError, PublishError};
use crate::mailbox::{mailbox, Mailbox};
use crate::qos::{InstanceState, PublicationQos, SubscriptionQos, TypeInfo};
use crate::session::{
    ConnectError, Encoding, QueryError, RawReply, RawRequest, SampleQueue, SessionEvent,
    WriteOptions,
};
use cmd::{disconnected, queued_units, Cmd, Done, Reply, QUEUED_WRITE_UNIT, QUEUED_WRITE_UNITS};
use driver::{Core, Driver, Shared};
use out::Out;
use receive::ReceiveThread;
use state::State;

pub use courier_wire::ros2::graph::GidSize;
pub use net::interface_address;
pub(crate) use options::RtpsOverrides;
pub use options::{parse_peer, RtpsOptions, ServiceStyle, LOOPBACK_MAX_MESSAGE_SIZE};
pub use ros2::{Ros2Endpoint, Ros2Kind, Ros2Node, Ros2NodeName};

/// The DDS key hash of `value` (DDSI-RTPS §9.6.4.8) that a writer of data
/// in XCDR version `version` sends: its key fields big-endian in that
/// version, zero-padded when the key can never exceed 16 bytes in it,
/// else their MD5. The version of the data, as Cyclone DDS and Fast DDS
/// compute it (a Fast DDS reader tells instances apart by it): XCDR1 for
/// a final type unless the publication asks otherwise.
pub(crate) fn key_hash_of<T: IpcMessage>(
    value: &T,
    version: courier_wire::cdr::Version,
) -> [u8; 16] {
    KeyHash::of_in(value, version).0
}

/// A GUID as 32 hex digits (prefix, then entity id).
pub fn guid_hex(g: Guid) -> String {
    const HEX: &[u8; 16] = b"0123456789abcdef";
    // once per received sample: no formatting machinery
    let mut s = String::with_capacity(32);
    for b in g.to_bytes() {
        s.push(char::from(HEX[usize::from(b >> 4)]));
        s.push(char::from(HEX[usize::from(b & 15)]));
    }
    s
}

/// An RTPS `Time_t` as a `SystemTime`.
pub(crate) fn system_time(t: Time) -> Option<SystemTime> {
    t.to_system_time()
}

/// A Courier session's DDS participant (see the [module docs](self)).
#[derive(Debug)]
pub struct RtpsBackend {
    /// The participant, shared with the driver task (and the receive
    /// thread): for writes that do not wait.
    shared: Arc<Shared>,
    cmd: Mailbox<Cmd>,
    /// The open publications, with their topics: a write to one of them
    /// cannot be refused, so it need not wait.
    published: Mutex<HashMap<PubId, Arc<str>>>,
    queue_budget: Arc<Semaphore>,
    listeners: Listeners,
    guid_prefix: GuidPrefix,
    locator: SocketAddr,
    participant_index: u32,
}

pub(crate) type Listeners = crate::hub::Hub<SessionEvent>;

impl RtpsBackend {
    /// Joins the domain: binds the sockets (probing participant indices),
    /// starts the driver task and announces the participant.
    pub async fn start(opts: RtpsOptions, name: &str) -> Result<Self, ConnectError> {
        let url = format!("rtps://{}", opts.domain);
        let fail = |why: String| ConnectError::Network {
            url: url.clone(),
            why,
        };
        let address = net::interface_address(&opts).map_err(fail)?;
        let mut peers: Vec<Locator> = Vec::new();
        let mut peer_hosts: Vec<[u8; 4]> = Vec::new();
        for p in &opts.peers {
            let (ip, port) = options::parse_peer(p).map_err(fail)?;
            match port {
                Some(port) => peers.push(Locator::udpv4(ip.octets(), port)),
                None => peer_hosts.push(ip.octets()),
            }
        }
        if opts.peers.is_empty() && !opts.multicast {
            // no way to find anyone else: at least this host's participants
            peer_hosts.push(address.octets());
        }
        let socks = net::open(&opts, address).map_err(fail)?;
        let prefix = participant::guid_prefix(entropy());
        let mut cfg = Config::udpv4(opts.domain, socks.index, prefix, address.octets())
            .ok_or_else(|| fail(format!("no ports for participant index {}", socks.index)))?
            .with_unicast_peers(&peer_hosts, opts.max_participant_index);
        for l in peers {
            if !cfg.spdp_destinations.contains(&l) {
                cfg.spdp_destinations.push(l);
            }
        }
        if opts.multicast {
            cfg = cfg.with_multicast();
        }
        cfg.lease_duration = opts.lease;
        cfg.max_message_size = opts.max_message_size_on(address);
        if let Some(n) = opts.fragment_size {
            cfg.fragment_size = n;
        }
        if let Some(n) = opts.max_sample_size {
            cfg.max_sample_size = n;
            // room to reassemble at least one such sample
            cfg.reassembly_limit = cfg.reassembly_limit.max(n);
        }
        cfg.entity_name = Some(name.to_string());
        let locator = SocketAddr::from((
            address,
            socks.meta.get_ref().local_addr().map_or(0, |a| a.port()),
        ));
        let index = socks.index;
        let now = Instant::now();
        let (tx, rx) = mailbox(crate::mailbox::CAPACITY);
        let listeners = Listeners::new(crate::hub::DEFAULT_CAPACITY);
        let responder = tx.downgrade();
        let mut st = State::new(
            Domain::new(cfg, now, SystemTime::now()),
            name,
            listeners.clone(),
            responder,
            now,
        );
        st.service_style = opts.services.wire();
        if opts.reads_ros2_graph() {
            let g = ros2::Ros2Graph::start(&mut st.d, opts.ros2_node.clone(), opts.ros2_gid, now)
                .map_err(|e| fail(format!("the ROS 2 graph topic: {e}")))?;
            st.ros2 = Some(g);
            // the node, with no endpoints yet
            st.publish_ros2_node(now);
        }
        let sock_err = |e: std::io::Error| fail(format!("user data socket: {e}"));
        let out = Out::new(
            socks.user.try_clone().map_err(sock_err)?,
            address.is_loopback(),
            opts.multicast,
        );
        let timer = crate::driver_timer::DriverTimer::new(st.next_wakeup());
        let shared = Arc::new(Shared {
            core: Mutex::new(Core {
                st,
                out,
                cmd: rx,
                timer,
                close: None,
            }),
            attention: tokio::sync::Notify::new(),
            closing: std::sync::atomic::AtomicBool::new(false),
            stopping: tokio::sync::Notify::new(),
        });
        let send_sock = socks.user.try_clone().map_err(sock_err)?;
        let (user, receiver) = if opts.receive_thread {
            let t = ReceiveThread::start(shared.clone(), socks.user, name).map_err(sock_err)?;
            (None, Some(t))
        } else {
            (
                Some(net::register_readable(socks.user).map_err(sock_err)?),
                None,
            )
        };
        let driver = Driver {
            spin: opts.busy_poll.map(BusyPoll::start),
            shared: shared.clone(),
            meta: socks.meta,
            user,
            meta_mc: socks.meta_mc,
            user_mc: socks.user_mc,
            batch: net::RecvBatch::new(),
            send_sock,
            receiver,
            immediate: Vec::new(),
            finished: false,
        };
        let session = name.to_string();
        tokio::spawn(async move {
            use futures::FutureExt;
            // a bug in the driver ends the session as a close would (the
            // driver's drop ends its streams and fails its calls): say so,
            // or the session looks closed by its user
            let Err(panic) = std::panic::AssertUnwindSafe(driver.run())
                .catch_unwind()
                .await
            else {
                return;
            };
            let what = panic
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| panic.downcast_ref::<String>().cloned())
                .unwrap_or_default();
            tracing::error!(
                "the RTPS driver of session {session:?} panicked ({what}): the session is closed"
            );
        });
        Ok(RtpsBackend {
            shared,
            cmd: tx,
            published: Mutex::default(),
            queue_budget: Arc::new(Semaphore::new(QUEUED_WRITE_UNITS)),
            listeners,
            guid_prefix: prefix,
            locator,
            participant_index: index,
        })
    }

    /// This participant's GUID prefix.
    pub fn guid_prefix(&self) -> GuidPrefix {
        self.guid_prefix
    }

    /// The metatraffic unicast address (interface address and 7410 + 2i).
    pub fn locator(&self) -> SocketAddr {
        self.locator
    }

    /// The participant index claimed.
    pub fn participant_index(&self) -> u32 {
        self.participant_index
    }

    fn published(&self) -> std::sync::MutexGuard<'_, HashMap<PubId, Arc<str>>> {
        self.published.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// The topic of the open publication `p` (each write shares the name
    /// instead of copying it).
    fn topic_of(&self, p: PubId) -> Result<Arc<str>, PublishError> {
        self.published()
            .get(&p)
            .cloned()
            .ok_or(PublishError::Closed(p))
    }

    /// What a write of `len` bytes to `p` needs to go without waiting:
    /// a share of the queue budget; or why it cannot.
    fn reserve(&self, p: PubId, len: usize) -> Result<OwnedSemaphorePermit, PublishError> {
        let topic = self.topic_of(p)?;
        if len > MAX_WRITE_SIZE {
            return Err(too_large(&topic, len));
        }
        let permit = self
            .queue_budget
            .clone()
            .try_acquire_many_owned(queued_units(len))
            .map_err(|_| PublishError::QueueFull {
                msg: topic.to_string(),
                bytes: QUEUED_WRITE_UNITS * QUEUED_WRITE_UNIT,
            })?;
        Ok(permit)
    }

    /// Queues an unconfirmed write of a known publication without
    /// waiting, when the queue budget has room; otherwise gives the data
    /// back for [`RtpsBackend::write_slow`].
    fn try_queue(
        &self,
        p: PubId,
        data: Vec<u8>,
        key_hash: Option<[u8; 16]>,
    ) -> Result<Result<(), PublishError>, Vec<u8>> {
        let Ok(permit) = self.reserve(p, data.len()) else {
            return Err(data);
        };
        // bounded by the write budget its permit is part of
        Ok(self
            .cmd
            .post(Cmd::queued_write(p, data, key_hash, permit))
            .map_err(|_| disconnected()))
    }

    /// A write: queued at once in the usual case (a known publication, no
    /// confirmation, room in the queue budget), with no boxed future of its
    /// own; else [`RtpsBackend::write_slow`]. A write that never waits still
    /// counts against tokio's cooperative budget, so that a publishing loop
    /// lets the driver and other tasks run.
    async fn queue_write(
        &self,
        p: PubId,
        data: Vec<u8>,
        opts: WriteOptions,
    ) -> Result<(), PublishError> {
        if opts.confirm.is_some() {
            return self.write_slow(p, data, opts).await;
        }
        tokio::task::consume_budget().await;
        match self.try_queue(p, data, opts.key_hash) {
            Ok(done) => done,
            Err(data) => self.write_slow(p, data, opts).await,
        }
    }

    /// A write that may wait: for room in the queue budget, or for the
    /// driver's answer (confirmed writes).
    async fn write_slow(
        &self,
        publication: PubId,
        data: Vec<u8>,
        opts: WriteOptions,
    ) -> Result<(), PublishError> {
        // its source timestamp, whatever it waits for
        let written = Some(Instant::now());
        let topic = self.topic_of(publication)?;
        if opts.confirm.is_none() {
            if data.len() > MAX_WRITE_SIZE {
                return Err(too_large(&topic, data.len()));
            }
            // returns once queued: the driver packs what is queued
            let permit = self
                .queue_budget
                .clone()
                .acquire_many_owned(queued_units(data.len()))
                .await
                .map_err(|_| disconnected::<PublishError>())?;
            // bounded by the write budget its permit is part of
            return self
                .cmd
                .post(Cmd::Write {
                    publication,
                    kind: ChangeKind::Alive,
                    data,
                    key_hash: opts.key_hash,
                    confirm: None,
                    done: Done::Queued(permit),
                    written,
                })
                .map_err(|_| disconnected());
        }
        self.ask(|reply| Cmd::Write {
            publication,
            kind: ChangeKind::Alive,
            data,
            key_hash: opts.key_hash,
            confirm: opts.confirm,
            done: Done::Reply(reply),
            written,
        })
        .await
    }

    async fn ask<T, E: Failure>(&self, make: impl FnOnce(Reply<T, E>) -> Cmd) -> Result<T, E> {
        let (tx, rx) = oneshot::channel();
        self.cmd.send(make(tx)).await.map_err(|_| disconnected())?;
        rx.await.map_err(|_| disconnected())?
    }

    /// As `ask`, for a command that opens what `handle` names: if the
    /// caller stops waiting (a `timeout` or `select!` drops the future),
    /// what the driver opened is closed (see [`OpenAnswer`]).
    ///
    /// [`OpenAnswer`]: crate::open_answer::OpenAnswer
    async fn ask_open<T: Copy, E: Failure>(
        &self,
        handle: fn(T) -> Handle,
        make: impl FnOnce(Reply<T, E>) -> Cmd,
    ) -> Result<T, E> {
        crate::open_answer::ask_open(&self.cmd, self, handle, make, disconnected).await
    }
}

fn too_large(msg: &str, len: usize) -> PublishError {
    PublishError::TooLarge {
        msg: msg.to_string(),
        len,
        max: MAX_WRITE_SIZE,
    }
}

fn entropy() -> [u8; 10] {
    use std::hash::{BuildHasher, Hasher};
    let mut out = [0; 10];
    let t = SystemTime::now()
        .duration_since(SystemTime::UNIX_EPOCH)
        .unwrap_or_default();
    for (i, chunk) in out.chunks_mut(8).enumerate() {
        let mut h = std::collections::hash_map::RandomState::new().build_hasher();
        h.write_u32(std::process::id());
        h.write_u128(t.as_nanos());
        h.write_usize(i);
        let v = h.finish().to_le_bytes();
        chunk.copy_from_slice(&v[..chunk.len()]);
    }
    out
}

/// Why an RTPS backend cannot open something without its type.
fn untyped(what: String) -> OpenError {
    OpenError::Unsupported {
        what,
        backend: "rtps://",
    }
}

#[async_trait::async_trait]
impl Backend for RtpsBackend {
    fn capabilities(&self) -> Capabilities {
        let mut c = Capabilities::new("rtps://", Encoding::Cdr);
        c.instances = true;
        c.confirmed_writes = true;
        c.pattern_subscriptions = true;
        c.immediate_delivery = true;
        c.try_write = true;
        c.liveliness = true;
        c.offers_liveliness = true;
        c
    }

    async fn open_publication(
        &self,
        msg: &str,
        ty: &TypeInfo,
        qos: &PublicationQos,
    ) -> Result<PubId, OpenError> {
        crate::error::dds_name(msg)?;
        if ty.is_untyped() {
            return Err(untyped(format!(
                "a publication of {msg} without its type (use Session::define::<T>() or \
                 Session::publisher::<T>())"
            )));
        }
        crate::qos::check_timing(qos.deadline, None).map_err(|why| OpenError::Qos {
            topic: msg.to_string(),
            why,
        })?;
        crate::qos::check_liveliness(msg, qos.liveliness)?;
        let (topic, ty, qos) = (msg.to_string(), Box::new(ty.clone()), Box::new(qos.clone()));
        let id = self
            .ask_open(Handle::Publication, |reply| Cmd::Publication {
                topic,
                ty,
                qos,
                reply,
            })
            .await?;
        self.published().insert(id, Arc::from(msg));
        Ok(id)
    }

    async fn open_subscription(
        &self,
        msg: &str,
        ty: Option<&TypeInfo>,
        qos: &SubscriptionQos,
        queue: Arc<SampleQueue>,
    ) -> Result<SubId, OpenError> {
        crate::error::dds_name(msg)?;
        crate::qos::check_timing(qos.deadline, qos.minimum_separation).map_err(|why| {
            OpenError::Qos {
                topic: msg.to_string(),
                why,
            }
        })?;
        crate::qos::check_liveliness(msg, qos.liveliness)?;
        let (topic, ty, qos) = (
            msg.to_string(),
            ty.filter(|t| !t.is_untyped()).cloned().map(Box::new),
            Box::new(qos.clone()),
        );
        self.ask_open(Handle::Subscription, |reply| Cmd::Subscription {
            topic,
            ty,
            qos,
            queue,
            reply,
        })
        .await
    }

    async fn open_service(
        &self,
        msg: &str,
        req: &TypeInfo,
        resp: &TypeInfo,
        queue: usize,
    ) -> Result<(ServiceId, mpsc::Receiver<RawRequest>), OpenError> {
        crate::error::dds_name(msg)?;
        if req.is_untyped() || resp.is_untyped() {
            return Err(untyped(format!(
                "serving {msg} without its types (use Session::serve)"
            )));
        }
        let (tx, rx) = mpsc::channel(queue.max(1));
        let (name, req, resp) = (
            msg.to_string(),
            Box::new(req.clone()),
            Box::new(resp.clone()),
        );
        let id = self
            .ask_open(Handle::Service, |reply| Cmd::Serve {
                name,
                req,
                resp,
                tx,
                reply,
            })
            .await?;
        Ok((id, rx))
    }

    async fn open_client(
        &self,
        msg: &str,
        req: &TypeInfo,
        resp: &TypeInfo,
    ) -> Result<ClientId, OpenError> {
        crate::error::dds_name(msg)?;
        if req.is_untyped() || resp.is_untyped() {
            return Err(untyped(
                "a query without its types (use Session::query)".into(),
            ));
        }
        let (name, req, resp) = (
            msg.to_string(),
            Box::new(req.clone()),
            Box::new(resp.clone()),
        );
        self.ask_open(Handle::Client, |reply| Cmd::Client {
            name,
            req,
            resp,
            reply,
        })
        .await
    }

    async fn write(
        &self,
        publication: PubId,
        data: Vec<u8>,
        opts: WriteOptions,
    ) -> Result<(), PublishError> {
        self.queue_write(publication, data, opts).await
    }

    fn write_now(&self, publication: PubId, data: Vec<u8>, opts: WriteOptions) -> WriteNow {
        if opts.confirm.is_some() {
            return WriteNow::Wait(data, opts);
        }
        match self.try_queue(publication, data, opts.key_hash) {
            Ok(done) => WriteNow::Done(done),
            Err(data) => WriteNow::Wait(data, opts),
        }
    }

    fn try_write(
        &self,
        publication: PubId,
        data: Vec<u8>,
        opts: WriteOptions,
    ) -> Result<(), PublishError> {
        if opts.confirm.is_some() {
            return Err(PublishError::Unsupported {
                what: "a confirmed write that does not wait".into(),
                backend: "rtps://",
            });
        }
        let permit = self.reserve(publication, data.len())?;
        let now = Instant::now();
        let mut c = self.shared.lock();
        if c.close.is_some() {
            return Err(disconnected());
        }
        // what was queued before goes first
        c.take_commands(now);
        c.st.command(
            Cmd::queued_write(publication, data, opts.key_hash, permit),
            now,
        );
        if crate::in_callback::inside(self.shared.id()) {
            // sent, packed with the callbacks' other writes, when they return
            return Ok(());
        }
        let full = c.flush(now).is_err();
        c.rearm();
        let close = c.close.is_some();
        // the write reached a subscription of this session with a
        // callback: the driver runs it
        let callbacks = !c.st.immediate.is_empty();
        drop(c);
        if full || close || callbacks {
            self.shared.attention.notify_one();
        }
        Ok(())
    }

    async fn query(
        &self,
        client: ClientId,
        data: Vec<u8>,
        timeout: Duration,
    ) -> Result<RawReply, QueryError> {
        let (tx, rx) = oneshot::channel();
        let gone = || QueryError::Disconnected(format!("{client:?}"));
        self.cmd
            .send(Cmd::Query {
                client,
                data,
                timeout,
                reply: tx,
            })
            .await
            .map_err(|_| gone())?;
        rx.await.map_err(|_| gone())?
    }

    fn close_handle(&self, handle: Handle) {
        if let Handle::Publication(p) = handle {
            // writes that do not wait are refused from now on
            self.published().remove(&p);
        }
        // one per handle
        let _ = self.cmd.post(Cmd::CloseHandle(handle));
    }

    fn events(&self) -> crate::hub::Listener<SessionEvent> {
        self.listeners.listen()
    }

    async fn close(&self) {
        self.cmd
            .close_session(self.shared.id(), |reply| Cmd::Close { reply })
            .await
    }

    fn dds(&self) -> Option<&dyn DdsControl> {
        Some(self)
    }
}

#[async_trait::async_trait]
impl DdsControl for RtpsBackend {
    async fn matched_readers(&self, topic: &str) -> Result<i32, ControlError> {
        let topic = topic.to_string();
        self.ask(|reply| Cmd::NumHandlers { topic, reply }).await
    }

    async fn watch_matches(&self, topic: &str) -> Result<(), ControlError> {
        self.cmd
            .send(Cmd::Watch {
                topic: topic.into(),
            })
            .await
            .map_err(|_| disconnected())
    }

    async fn participant_named(&self, name: &str) -> Result<bool, ControlError> {
        let name = name.to_string();
        self.ask(|reply| Cmd::ModuleConnected { name, reply }).await
    }

    async fn readers_of(&self, topic: &str) -> Result<Vec<crate::EndpointInfo>, ControlError> {
        let topic = topic.to_string();
        self.ask(|reply| Cmd::ReadersOf { topic, reply }).await
    }

    async fn assert_liveliness(&self, publication: PubId) -> Result<(), PublishError> {
        self.topic_of(publication)?;
        self.ask(|reply| Cmd::AssertLiveliness { publication, reply })
            .await
    }

    async fn assert_participant_liveliness(&self) -> Result<(), PublishError> {
        self.ask(|reply| Cmd::AssertParticipantLiveliness { reply })
            .await
    }

    async fn end_instance(
        &self,
        publication: PubId,
        state: InstanceState,
        key: Vec<u8>,
        key_hash: [u8; 16],
    ) -> Result<(), PublishError> {
        let kind = match state {
            InstanceState::Alive => {
                return Err(PublishError::Unsupported {
                    what: "end_instance with InstanceState::Alive (it takes Disposed or \
                           Unregistered)"
                        .into(),
                    backend: "rtps://",
                })
            }
            InstanceState::Disposed => ChangeKind::Disposed,
            InstanceState::Unregistered => ChangeKind::Unregistered,
        };
        self.topic_of(publication)?;
        self.ask(|reply| Cmd::Write {
            publication,
            kind,
            data: key,
            key_hash: Some(key_hash),
            confirm: None,
            done: Done::Reply(reply),
            written: None,
        })
        .await
    }

    async fn ros2_nodes(&self) -> Result<Vec<Ros2Node>, ControlError> {
        self.ask(|reply| Cmd::Ros2Nodes { reply }).await
    }

    async fn open_pattern(
        &self,
        topic: &str,
        type_name: &str,
        queue: Arc<SampleQueue>,
    ) -> Result<SubId, OpenError> {
        let (topic, type_name) = (topic.to_string(), type_name.to_string());
        self.ask_open(Handle::Subscription, |reply| Cmd::Pattern {
            topic,
            type_name,
            queue,
            reply,
        })
        .await
    }
}

impl Drop for RtpsBackend {
    fn drop(&mut self) {
        // the driver leaves the domain (disposes everything) and ends
        let (tx, _rx) = oneshot::channel();
        let _ = self.cmd.post(Cmd::Close { reply: tx });
    }
}

// ---------------------------------------------------------------------------
// The driver

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn guid_hex_is_the_16_bytes_in_lower_case_hex() {
        let mut b = [0u8; 16];
        for (i, x) in b.iter_mut().enumerate() {
            *x = (i as u8) * 17;
        }
        b[15] = 0xc2;
        assert_eq!(
            guid_hex(Guid::from_bytes(b)),
            "00112233445566778899aabbccddeec2"
        );
    }
}
