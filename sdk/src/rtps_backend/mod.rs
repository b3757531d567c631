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
//! `Stream` (pulled with `try_next`, or awaited by a task). A subscription
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

mod net;
mod options;
mod timer;

use std::collections::VecDeque;

// seeded per process: several of these maps are keyed by GUIDs off the network
use foldhash::{HashMap, HashMapExt, HashSet, HashSetExt};
use std::net::{Ipv4Addr, SocketAddr};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant, SystemTime};

use courier_wire::rtps::discovery::{
    Durability as WireDurability, Duration as RtpsDuration, EndpointQos, History as WireHistory,
    Reliability as WireReliability,
};
use courier_wire::rtps::participant::{
    self, Change, ChangeKind, Config, EndpointConfig, Event, KeyHash, LostReason, Participant,
    ReceivedSample, SampleIdentity, Transmission, MAX_WRITE_SIZE,
};
use courier_wire::rtps::{Guid, GuidPrefix, Locator, SequenceNumber, Time};
use courier_wire::{cdr, IpcMessage};
use net::UdpSocket;
use smallvec::SmallVec;
use std::io::IoSlice;
use tokio::sync::{mpsc, oneshot, OwnedSemaphorePermit, Semaphore};

use crate::busy_poll::BusyPoll;
use crate::qos::{
    Durability, History, InstanceState, PublicationQos, Reliability, SubscriptionQos, TypeInfo,
};
use crate::session::{
    Backend, ConnectError, Encoding, QueryError, RawReply, RawRequest, RawSample, ReturnedBuffers,
    SampleQueue, SessionError, SessionEvent, WriteOptions,
};

use courier_wire::dds::fnmatch;
pub(crate) use options::RtpsOverrides;
pub use options::{RtpsOptions, LOOPBACK_MAX_MESSAGE_SIZE};

/// The DDS key hash of `value` (DDSI-RTPS §9.6.4.8): its key fields as
/// big-endian XCDR2, zero-padded when the key can never exceed 16 bytes,
/// else their MD5.
pub(crate) fn key_hash_of<T: IpcMessage>(value: &T) -> [u8; 16] {
    let mut w = cdr::Writer::new(cdr::Encoding::Xcdr2Be);
    value.cdr_encode_key(&mut w);
    KeyHash::from_key(&w.into_vec(), !T::CDR_KEY_BOUNDED).0
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
fn system_time(t: Time) -> Option<SystemTime> {
    let secs = u64::try_from(t.seconds).ok()?;
    let nanos = (u64::from(t.fraction) * 1_000_000_000) >> 32;
    SystemTime::UNIX_EPOCH.checked_add(Duration::new(secs, nanos as u32))
}

fn disconnected() -> SessionError {
    SessionError::Disconnected("the RTPS participant (session closed)".into())
}

type Reply<T> = oneshot::Sender<Result<T, SessionError>>;

/// How the driver tells a publisher that a write is done.
enum Done {
    /// The publisher waits for the result (confirmed writes, first writes).
    Reply(Reply<()>),
    /// The publisher went on once the write was queued; the permit it holds
    /// is its share of [`QUEUED_WRITE_UNITS`], given back when the write
    /// enters the writer's history.
    Queued(OwnedSemaphorePermit),
}

impl Done {
    fn send(self, r: Result<(), SessionError>) {
        match self {
            Done::Reply(tx) => {
                let _ = tx.send(r);
            }
            Done::Queued(_permit) => {
                if let Err(e) = r {
                    tracing::warn!("a queued write failed: {e}");
                }
            }
        }
    }
}

/// Bytes of writes queued for the driver (not yet in a writer's history)
/// at most, in units of [`QUEUED_WRITE_UNIT`] bytes: `publish().await`
/// returns as soon as its write is queued, so that the driver can pack a
/// burst of writes into one datagram, and waits while this much is queued
/// (back-pressure from a full keep-all history reaches the publisher here).
const QUEUED_WRITE_UNITS: usize = 16 * 1024;
const QUEUED_WRITE_UNIT: usize = 64;

/// A write's share of the queue budget (at least one unit, at most all).
fn queued_units(len: usize) -> u32 {
    let units = len.div_ceil(QUEUED_WRITE_UNIT).clamp(1, QUEUED_WRITE_UNITS);
    u32::try_from(units).unwrap_or(u32::MAX)
}

enum Cmd {
    // (the rare commands box their bulk: every write moves a `Cmd`)
    Publication {
        topic: String,
        ty: Box<TypeInfo>,
        qos: Box<PublicationQos>,
        reply: Reply<()>,
    },
    Subscription {
        topic: String,
        ty: Option<Box<TypeInfo>>,
        qos: Box<SubscriptionQos>,
        queue: Arc<SampleQueue>,
        reply: Reply<()>,
    },
    Pattern {
        topic: String,
        type_name: String,
        queue: Arc<SampleQueue>,
        reply: Reply<()>,
    },
    Write {
        topic: Arc<str>,
        kind: ChangeKind,
        data: Vec<u8>,
        key_hash: Option<[u8; 16]>,
        confirm: Option<Duration>,
        done: Done,
    },
    ModuleConnected {
        name: String,
        reply: Reply<bool>,
    },
    NumHandlers {
        topic: String,
        reply: Reply<i32>,
    },
    Watch {
        topic: String,
    },
    Close {
        reply: oneshot::Sender<()>,
    },
    Query {
        name: String,
        req: Box<TypeInfo>,
        resp: Box<TypeInfo>,
        data: Vec<u8>,
        timeout: Duration,
        reply: oneshot::Sender<Result<RawReply, QueryError>>,
    },
    Serve {
        name: String,
        req: Box<TypeInfo>,
        resp: Box<TypeInfo>,
        tx: mpsc::Sender<RawRequest>,
        reply: Reply<()>,
    },
    Respond {
        name: String,
        data: Vec<u8>,
        request: SampleIdentity,
    },
}

impl Cmd {
    /// A write that is not confirmed and holds its share of the queue
    /// budget until it enters the writer's history.
    fn queued_write(
        topic: Arc<str>,
        data: Vec<u8>,
        key_hash: Option<[u8; 16]>,
        permit: OwnedSemaphorePermit,
    ) -> Cmd {
        Cmd::Write {
            topic,
            kind: ChangeKind::Alive,
            data,
            key_hash,
            confirm: None,
            done: Done::Queued(permit),
        }
    }
}

/// ROS 2's service topics: `rq/<name>Request` and `rr/<name>Reply`.
fn request_topic(name: &str) -> String {
    format!("rq/{name}Request")
}

fn reply_topic(name: &str) -> String {
    format!("rr/{name}Reply")
}

/// A Courier session's DDS participant (see the [module docs](self)).
#[derive(Debug)]
pub struct RtpsBackend {
    /// The participant, shared with the driver task (and the receive
    /// thread): for writes that do not wait.
    shared: Arc<Shared>,
    cmd: mpsc::UnboundedSender<Cmd>,
    /// Topics this session publishes (publications are never deleted): a
    /// write to one of them cannot be refused, so it need not wait.
    published: Mutex<HashMap<String, Arc<str>>>,
    queue_budget: Arc<Semaphore>,
    listeners: Listeners,
    guid_prefix: GuidPrefix,
    locator: SocketAddr,
    participant_index: u32,
}

type Listeners = Arc<Mutex<Vec<mpsc::UnboundedSender<SessionEvent>>>>;

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
        cfg.entity_name = Some(name.to_string());
        let locator = SocketAddr::from((
            address,
            socks.meta.get_ref().local_addr().map_or(0, |a| a.port()),
        ));
        let index = socks.index;
        let now = Instant::now();
        let p = Participant::new(cfg, now, SystemTime::now());
        let (tx, rx) = mpsc::unbounded_channel();
        let listeners: Listeners = Arc::default();
        let responder = tx.downgrade();
        let st = State {
            p,
            name: name.to_string(),
            listeners: listeners.clone(),
            writers: HashMap::default(),
            readers: HashMap::new(),
            patterns: Vec::new(),
            watched: HashSet::new(),
            remote_writers: HashMap::new(),
            source_names: HashMap::new(),
            confirms: Vec::new(),
            next_housekeeping: now,
            servers: HashMap::new(),
            clients: HashMap::new(),
            client_readers: HashMap::new(),
            waiting: Vec::new(),
            inflight: HashMap::new(),
            responder,
            returns: Arc::default(),
            immediate: Vec::new(),
            wakes: None,
        };
        let sock_err = |e: std::io::Error| fail(format!("user data socket: {e}"));
        let out = Out {
            sock: socks.user.try_clone().map_err(sock_err)?,
            loopback_only: address.is_loopback(),
            multicast: opts.multicast,
            refused: 0,
            send_errors: 0,
        };
        let timer = timer::DriverTimer::new(st.next_wakeup());
        let shared = Arc::new(Shared {
            core: Mutex::new(Core {
                st,
                out,
                cmd: rx,
                timer,
                stalled: None,
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
        };
        tokio::spawn(driver.run());
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

    /// The shared name of this session's publication `msg`, if it has one
    /// (each write shares it instead of copying the name).
    fn publication(&self, msg: &str) -> Option<Arc<str>> {
        self.published
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .get(msg)
            .cloned()
    }

    /// What a write of `len` bytes to `msg` needs to go without waiting:
    /// the publication's shared name and a share of the queue budget; or
    /// why it cannot.
    fn reserve(&self, msg: &str, len: usize) -> Result<(Arc<str>, OwnedSemaphorePermit), String> {
        let topic = self.publication(msg).ok_or_else(|| {
            "this session has no publication of it (create one with \
             Session::publisher::<T>(..).build().await)"
                .to_string()
        })?;
        if len > MAX_WRITE_SIZE {
            return Err(format!(
                "a sample of {len} bytes is larger than {MAX_WRITE_SIZE}"
            ));
        }
        let permit = self
            .queue_budget
            .clone()
            .try_acquire_many_owned(queued_units(len))
            .map_err(|_| {
                format!(
                    "the session's write queue is full ({} bytes wait for the participant)",
                    QUEUED_WRITE_UNITS * QUEUED_WRITE_UNIT
                )
            })?;
        Ok((topic, permit))
    }

    /// Queues an unconfirmed write of a known publication without
    /// waiting, when the queue budget has room; otherwise gives the data
    /// back for [`RtpsBackend::write_slow`].
    fn try_queue(
        &self,
        msg: &str,
        data: Vec<u8>,
        key_hash: Option<[u8; 16]>,
    ) -> Result<Result<(), SessionError>, Vec<u8>> {
        let Ok((topic, permit)) = self.reserve(msg, data.len()) else {
            return Err(data);
        };
        Ok(self
            .cmd
            .send(Cmd::queued_write(topic, data, key_hash, permit))
            .map_err(|_| disconnected()))
    }

    /// A write: queued at once in the usual case (a known publication, no
    /// confirmation, room in the queue budget), with no boxed future of its
    /// own; else [`RtpsBackend::write_slow`]. A write that never waits still
    /// counts against tokio's cooperative budget, so that a publishing loop
    /// lets the driver and other tasks run.
    async fn queue_write(
        &self,
        msg: &str,
        data: Vec<u8>,
        opts: WriteOptions,
    ) -> Result<(), SessionError> {
        if opts.confirm.is_some() {
            return self.write_slow(msg, data, opts).await;
        }
        tokio::task::consume_budget().await;
        match self.try_queue(msg, data, opts.key_hash) {
            Ok(done) => done,
            Err(data) => self.write_slow(msg, data, opts).await,
        }
    }

    /// A write that may wait: for room in the queue budget, or for the
    /// driver's answer (confirmed writes, unknown publications).
    async fn write_slow(
        &self,
        msg: &str,
        data: Vec<u8>,
        opts: WriteOptions,
    ) -> Result<(), SessionError> {
        let known = self.publication(msg);
        let topic = known.clone().unwrap_or_else(|| Arc::from(msg));
        if let (None, Some(topic)) = (opts.confirm, known) {
            if data.len() > MAX_WRITE_SIZE {
                return Err(SessionError::Refused(format!(
                    "cannot publish {topic}: a sample of {} bytes is larger than {MAX_WRITE_SIZE}",
                    data.len()
                )));
            }
            // returns once queued: the driver packs what is queued
            let permit = self
                .queue_budget
                .clone()
                .acquire_many_owned(queued_units(data.len()))
                .await
                .map_err(|_| disconnected())?;
            return self
                .cmd
                .send(Cmd::Write {
                    topic,
                    kind: ChangeKind::Alive,
                    data,
                    key_hash: opts.key_hash,
                    confirm: None,
                    done: Done::Queued(permit),
                })
                .map_err(|_| disconnected());
        }
        self.ask(|reply| Cmd::Write {
            topic,
            kind: ChangeKind::Alive,
            data,
            key_hash: opts.key_hash,
            confirm: opts.confirm,
            done: Done::Reply(reply),
        })
        .await
    }

    async fn ask<T>(&self, make: impl FnOnce(Reply<T>) -> Cmd) -> Result<T, SessionError> {
        let (tx, rx) = oneshot::channel();
        self.cmd.send(make(tx)).map_err(|_| disconnected())?;
        rx.await.map_err(|_| disconnected())?
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

#[async_trait::async_trait]
impl Backend for RtpsBackend {
    fn encoding(&self) -> Encoding {
        Encoding::Cdr
    }

    async fn define_format(&self, _name: &str, _format: &str) -> Result<(), SessionError> {
        Ok(())
    }

    async fn define(&self, msg: &str, _format: Option<&str>) -> Result<(), SessionError> {
        Err(SessionError::Refused(format!(
            "a DDS publication of {msg} needs a type: use Session::define::<T>() or \
             Session::publisher::<T>()"
        )))
    }

    async fn publish(&self, msg: &str, data: Vec<u8>) -> Result<(), SessionError> {
        self.queue_write(msg, data, WriteOptions::default()).await
    }

    async fn subscribe(&self, msg: &str, queue: Arc<SampleQueue>) -> Result<(), SessionError> {
        self.create_subscription(msg, None, &SubscriptionQos::default(), queue)
            .await
    }

    async fn query(
        &self,
        msg: &str,
        _data: Vec<u8>,
        _timeout: Duration,
    ) -> Result<RawReply, QueryError> {
        Err(QueryError::Refused {
            msg: msg.into(),
            detail: "a DDS request topic needs its types: use Session::query".into(),
        })
    }

    async fn serve(
        &self,
        msg: &str,
        _queue: usize,
    ) -> Result<mpsc::Receiver<RawRequest>, SessionError> {
        Err(SessionError::Refused(format!(
            "the DDS request topic of {msg} needs its types: use Session::serve"
        )))
    }

    async fn query_typed(
        &self,
        msg: &str,
        req: &TypeInfo,
        resp: &TypeInfo,
        data: Vec<u8>,
        timeout: Duration,
    ) -> Result<RawReply, QueryError> {
        let (tx, rx) = oneshot::channel();
        let gone = || QueryError::Disconnected(msg.to_string());
        self.cmd
            .send(Cmd::Query {
                name: msg.to_string(),
                req: Box::new(req.clone()),
                resp: Box::new(resp.clone()),
                data,
                timeout,
                reply: tx,
            })
            .map_err(|_| gone())?;
        rx.await.map_err(|_| gone())?
    }

    async fn serve_typed(
        &self,
        msg: &str,
        req: &TypeInfo,
        resp: &TypeInfo,
        queue: usize,
    ) -> Result<mpsc::Receiver<RawRequest>, SessionError> {
        let (tx, rx) = mpsc::channel(queue.max(1));
        let (name, req, resp) = (
            msg.to_string(),
            Box::new(req.clone()),
            Box::new(resp.clone()),
        );
        self.ask(|reply| Cmd::Serve {
            name,
            req,
            resp,
            tx,
            reply,
        })
        .await?;
        Ok(rx)
    }

    fn events(&self) -> mpsc::UnboundedReceiver<SessionEvent> {
        let (tx, rx) = mpsc::unbounded_channel();
        if self.cmd.is_closed() {
            let _ = tx.send(SessionEvent::Disconnected);
        } else {
            self.listeners.lock().unwrap().push(tx);
        }
        rx
    }

    async fn is_module_connected(&self, module: &str) -> Result<bool, SessionError> {
        let name = module.to_string();
        self.ask(|reply| Cmd::ModuleConnected { name, reply }).await
    }

    async fn num_handlers(&self, msg: &str) -> Result<i32, SessionError> {
        let topic = msg.to_string();
        self.ask(|reply| Cmd::NumHandlers { topic, reply }).await
    }

    async fn set_capacity(&self, _n: i32) -> Result<(), SessionError> {
        Err(SessionError::Refused(
            "IPC_setCapacity has no DDS equivalent: bound a subscription with its queue policy"
                .into(),
        ))
    }

    async fn set_priority(&self, msg: &str, _priority: i32) -> Result<(), SessionError> {
        Err(SessionError::Refused(format!(
            "IPC_setMsgPriority ({msg}) has no DDS equivalent: use ownership strength"
        )))
    }

    async fn set_queue_length(&self, msg: &str, _n: i32) -> Result<(), SessionError> {
        Err(SessionError::Refused(format!(
            "IPC_setMsgQueueLength ({msg}) has no DDS equivalent: use History::KeepLast"
        )))
    }

    async fn watch_handlers(&self, msg: &str) -> Result<(), SessionError> {
        self.cmd
            .send(Cmd::Watch { topic: msg.into() })
            .map_err(|_| disconnected())
    }

    async fn close(&self) {
        let (tx, rx) = oneshot::channel();
        if self.cmd.send(Cmd::Close { reply: tx }).is_ok() {
            let _ = rx.await;
        }
    }

    async fn create_publication(
        &self,
        msg: &str,
        ty: &TypeInfo,
        qos: &PublicationQos,
    ) -> Result<(), SessionError> {
        let (topic, ty, qos) = (msg.to_string(), Box::new(ty.clone()), Box::new(qos.clone()));
        self.ask(|reply| Cmd::Publication {
            topic,
            ty,
            qos,
            reply,
        })
        .await?;
        self.published
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .insert(msg.to_string(), Arc::from(msg));
        Ok(())
    }

    async fn create_subscription(
        &self,
        msg: &str,
        ty: Option<&TypeInfo>,
        qos: &SubscriptionQos,
        queue: Arc<SampleQueue>,
    ) -> Result<(), SessionError> {
        let (topic, ty, qos) = (
            msg.to_string(),
            ty.cloned().map(Box::new),
            Box::new(qos.clone()),
        );
        self.ask(|reply| Cmd::Subscription {
            topic,
            ty,
            qos,
            queue,
            reply,
        })
        .await
    }

    async fn subscribe_pattern(
        &self,
        topic: &str,
        type_name: &str,
        queue: Arc<SampleQueue>,
    ) -> Result<(), SessionError> {
        let (topic, type_name) = (topic.to_string(), type_name.to_string());
        self.ask(|reply| Cmd::Pattern {
            topic,
            type_name,
            queue,
            reply,
        })
        .await
    }

    async fn write(
        &self,
        msg: &str,
        data: Vec<u8>,
        opts: WriteOptions,
    ) -> Result<(), SessionError> {
        self.queue_write(msg, data, opts).await
    }

    fn delivers_immediately(&self) -> bool {
        true
    }

    fn try_write(
        &self,
        msg: &str,
        data: Vec<u8>,
        key_hash: Option<[u8; 16]>,
    ) -> Result<(), SessionError> {
        let (topic, permit) = self.reserve(msg, data.len()).map_err(|why| {
            SessionError::Refused(format!("cannot publish {msg} without waiting: {why}"))
        })?;
        let now = Instant::now();
        let mut c = self.shared.lock();
        if c.close.is_some() {
            return Err(disconnected());
        }
        // what was queued before goes first
        c.take_commands(now);
        c.st.command(Cmd::queued_write(topic, data, key_hash, permit), now);
        if IN_CALLBACK.with(|t| t.get()) == self.shared.id() {
            // sent, packed with the callbacks' other writes, when they return
            return Ok(());
        }
        let full = c.flush(now).is_err();
        c.rearm();
        let close = c.close.is_some();
        drop(c);
        if full || close {
            self.shared.attention.notify_one();
        }
        Ok(())
    }

    async fn end_instance(
        &self,
        msg: &str,
        state: InstanceState,
        key: Vec<u8>,
        key_hash: [u8; 16],
    ) -> Result<(), SessionError> {
        let kind = match state {
            InstanceState::Alive => {
                return Err(SessionError::Refused(
                    "end_instance takes Disposed or Unregistered".into(),
                ))
            }
            InstanceState::Disposed => ChangeKind::Disposed,
            InstanceState::Unregistered => ChangeKind::Unregistered,
        };
        let topic = Arc::from(msg);
        self.ask(|reply| Cmd::Write {
            topic,
            kind,
            data: key,
            key_hash: Some(key_hash),
            confirm: None,
            done: Done::Reply(reply),
        })
        .await
    }
}

impl Drop for RtpsBackend {
    fn drop(&mut self) {
        // the driver leaves the domain (disposes everything) and ends
        let (tx, _rx) = oneshot::channel();
        let _ = self.cmd.send(Cmd::Close { reply: tx });
    }
}

// ---------------------------------------------------------------------------
// QoS mapping

fn wire_duration(d: Option<Duration>) -> RtpsDuration {
    d.map_or(RtpsDuration::INFINITE, RtpsDuration::from_std)
}

fn wire_history(h: History) -> WireHistory {
    match h {
        History::KeepLast(n) => WireHistory::KeepLast(i32::try_from(n.max(1)).unwrap_or(i32::MAX)),
        History::KeepAll => WireHistory::KeepAll,
    }
}

fn wire_reliability(r: Reliability) -> WireReliability {
    match r {
        Reliability::BestEffort => WireReliability::BestEffort,
        Reliability::Reliable => {
            WireReliability::Reliable(RtpsDuration::from_std(Duration::from_millis(100)))
        }
    }
}

fn wire_durability(d: Durability) -> WireDurability {
    match d {
        Durability::Volatile => WireDurability::Volatile,
        Durability::TransientLocal => WireDurability::TransientLocal,
    }
}

fn publication_qos(q: &PublicationQos) -> EndpointQos {
    let mut e = EndpointQos::writer_default();
    e.reliability = wire_reliability(q.reliability);
    e.durability = wire_durability(q.durability);
    e.history = wire_history(q.history);
    e.deadline = wire_duration(q.deadline);
    e.lifespan = wire_duration(q.persistence);
    if let Some(s) = q.strength {
        e.exclusive_ownership = true;
        e.ownership_strength = s;
    }
    e.partitions = q.partitions.clone();
    e
}

fn subscription_qos(q: &SubscriptionQos) -> EndpointQos {
    let mut e = EndpointQos::reader_default();
    e.reliability = wire_reliability(q.reliability);
    e.durability = wire_durability(q.durability);
    e.history = wire_history(q.history);
    e.deadline = wire_duration(q.deadline);
    e.time_based_filter = q
        .minimum_separation
        .map_or(RtpsDuration::ZERO, RtpsDuration::from_std);
    e.exclusive_ownership = q.exclusive;
    e.partitions = q.partitions.clone();
    e
}

fn is_keyed_entity(g: Guid) -> bool {
    matches!(g.entity.0[3], 0x02 | 0x07)
}

// ---------------------------------------------------------------------------
// The driver

/// The sending side: the user-data unicast socket (every datagram goes
/// out from it) and the rules on where datagrams may go.
struct Out {
    sock: std::net::UdpSocket,
    loopback_only: bool,
    multicast: bool,
    /// Datagrams not sent because of the loopback/multicast rules.
    refused: u64,
    send_errors: u64,
}

/// A datagram that found the socket's send buffer full.
struct Full;

impl Out {
    fn allowed(&self, to: SocketAddr) -> bool {
        match to {
            SocketAddr::V4(a) => {
                let ip: Ipv4Addr = *a.ip();
                if ip.is_multicast() {
                    self.multicast && !self.loopback_only
                } else {
                    !self.loopback_only || ip.is_loopback()
                }
            }
            SocketAddr::V6(_) => false,
        }
    }

    /// Sends one message without waiting (the socket may be in blocking
    /// mode for a receive thread: every send says `MSG_DONTWAIT`); large
    /// sample data goes from the writer's history to the kernel without a
    /// copy, with one vectored `sendmsg`. `Err(Full)` when the send buffer
    /// is full: send it again once the socket is writable.
    fn try_send(&mut self, t: &Transmission) -> Result<(), Full> {
        let Some(addr) = t.destination().socket_addr().filter(|a| self.allowed(*a)) else {
            self.refused += 1;
            return Ok(());
        };
        // a few parts (2 per shared piece + 1), kept off the heap
        let parts: SmallVec<[IoSlice<'_>; 8]> = t.parts().map(IoSlice::new).collect();
        let to = socket2::SockAddr::from(addr);
        let sock = socket2::SockRef::from(&self.sock);
        let sent = match &parts[..] {
            [] => return Ok(()),
            [one] => sock.send_to_with_flags(one, &to, DONTWAIT),
            _ => sock.send_to_vectored_with_flags(&parts, &to, DONTWAIT),
        };
        match sent {
            Ok(_) => Ok(()),
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => Err(Full),
            Err(_) => {
                self.send_errors += 1;
                Ok(())
            }
        }
    }
}

#[cfg(unix)]
const DONTWAIT: libc::c_int = libc::MSG_DONTWAIT;
#[cfg(not(unix))]
const DONTWAIT: std::ffi::c_int = 0;

/// The socket has data. The driver is its only reader, so it waits in the
/// socket's one read-waker slot (`poll_read_ready`), not in the list of
/// waiters that `readable()` joins and leaves on every turn.
async fn recv_ready(s: &UdpSocket) -> std::io::Result<()> {
    // the guard is dropped without clearing: `recv_batch` clears readiness
    // when it finds the queue empty
    std::future::poll_fn(|cx| s.poll_read_ready(cx).map_ok(drop)).await
}

async fn recv_ready_opt(s: &Option<UdpSocket>) -> std::io::Result<()> {
    match s {
        Some(s) => recv_ready(s).await,
        None => std::future::pending().await,
    }
}

enum Wake {
    Cmd(Option<Cmd>),
    /// Socket `i` (meta, user, meta multicast, user multicast) has data.
    Readable(usize),
    Space,
    Timer,
    /// Someone else changed the core: a send found the socket full, or a
    /// close was found among the commands.
    Attention,
}

/// What the driver task, a receive thread and `try_publish` share: the
/// participant and everything around it, one at a time.
struct Shared {
    core: Mutex<Core>,
    /// The driver should look at the core (see [`Wake::Attention`]).
    attention: tokio::sync::Notify,
    /// The receive thread stops (set before it is woken).
    closing: std::sync::atomic::AtomicBool,
    /// Wakes the receive thread where it waits for room in a queue.
    stopping: tokio::sync::Notify,
}

impl std::fmt::Debug for Shared {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Shared")
    }
}

impl Shared {
    fn lock(&self) -> std::sync::MutexGuard<'_, Core> {
        // a panic while locked leaves the state as consistent as any
        // protocol error would: go on
        self.core.lock().unwrap_or_else(|p| p.into_inner())
    }

    fn id(&self) -> usize {
        std::ptr::from_ref(self) as usize
    }

    /// Hands the samples of immediate-delivery subscriptions to their
    /// callbacks, holding no lock, then sends what the callbacks wrote;
    /// leaves `queues` empty (its allocation is passed around, not
    /// renewed per datagram). `Err(Full)` when that found the send buffer
    /// full.
    fn run_callbacks(&self, queues: &mut Vec<Arc<SampleQueue>>) -> Result<(), Full> {
        let mut full = false;
        while !queues.is_empty() {
            IN_CALLBACK.with(|c| c.set(self.id()));
            for q in queues.iter() {
                q.run_handler();
            }
            IN_CALLBACK.with(|c| c.set(0));
            queues.clear();
            let now = Instant::now();
            let mut c = self.lock();
            // a full socket does not hold up callbacks: what they write
            // waits in the participant for the driver
            full |= c.flush(now).is_err();
            c.rearm();
            std::mem::swap(queues, &mut c.st.immediate);
        }
        if full {
            Err(Full)
        } else {
            Ok(())
        }
    }
}

thread_local! {
    /// The [`Shared`] whose subscription callback this thread is running
    /// (0: none): its writes are sent when the callbacks are done.
    static IN_CALLBACK: std::cell::Cell<usize> = const { std::cell::Cell::new(0) };
}

struct Core {
    st: State,
    out: Out,
    cmd: mpsc::UnboundedReceiver<Cmd>,
    /// The driver's deadlines (see [`timer`]).
    timer: timer::DriverTimer,
    /// A datagram that found the send buffer full: it goes first.
    stalled: Option<Transmission>,
    /// A close taken from the commands by someone other than the driver
    /// (`None` inside: every sender was dropped).
    close: Option<Option<oneshot::Sender<()>>>,
}

impl Core {
    /// Hands received samples and events to the application and sends
    /// what the participant has to send, until the socket is full.
    fn flush(&mut self, now: Instant) -> Result<(), Full> {
        self.st.pump(now);
        if let Some(t) = self.stalled.take() {
            if let Err(full) = self.out.try_send(&t) {
                self.stalled = Some(t);
                return Err(full);
            }
        }
        while let Some(t) = self.st.p.poll_transmission() {
            if let Err(full) = self.out.try_send(&t) {
                self.stalled = Some(t);
                return Err(full);
            }
        }
        Ok(())
    }

    /// Arms the timer for the next deadline, if that moved earlier.
    fn rearm(&mut self) {
        self.timer.set(self.st.next_wakeup());
    }

    /// Takes the commands already queued, in order (so that a write made
    /// without waiting comes after the `publish().await`s before it).
    fn take_commands(&mut self, now: Instant) {
        while self.close.is_none() {
            match self.cmd.try_recv() {
                Ok(Cmd::Close { reply }) => self.close = Some(Some(reply)),
                Ok(c) => self.st.command(c, now),
                Err(mpsc::error::TryRecvError::Empty) => return,
                Err(mpsc::error::TryRecvError::Disconnected) => self.close = Some(None),
            }
        }
    }

    /// Hands the first `n` datagrams of `batch` to the participant, and
    /// what they deliver to the subscriptions; sample buffers the
    /// application has given back are reused first.
    fn receive(&mut self, batch: &net::RecvBatch, n: usize, now: Instant) {
        let st = &mut self.st;
        st.returns.take(|b| st.p.recycle(b));
        for k in 0..n {
            let (bytes, from) = batch.get(k);
            self.st.p.handle_datagram(locator_of(from), bytes, now);
            // deliver as we go so that back-pressure is seen
            self.st.pump(now);
        }
    }
}

struct Driver {
    /// Busy polling after activity, when configured.
    spin: Option<BusyPoll>,
    shared: Arc<Shared>,
    meta: UdpSocket,
    /// User data, when the driver reads it (no receive thread).
    user: Option<UdpSocket>,
    meta_mc: Option<UdpSocket>,
    user_mc: Option<UdpSocket>,
    batch: net::RecvBatch,
    /// A duplicate of the sending socket, to wait for room.
    send_sock: std::net::UdpSocket,
    receiver: Option<ReceiveThread>,
    /// Immediate subscriptions with samples for their callbacks.
    immediate: Vec<Arc<SampleQueue>>,
}

impl Driver {
    async fn run(mut self) {
        // one clock reading per turn, taken when the driver wakes
        let mut now = Instant::now();
        let shared = self.shared.clone();
        loop {
            // what the last turn produced goes out first; then what is due
            let (paused, flushed, close) = {
                let mut c = shared.lock();
                let mut flushed = c.flush(now);
                let next = c.st.next_wakeup();
                if next <= now && flushed.is_ok() {
                    c.st.tick(now);
                    flushed = c.flush(now);
                }
                c.rearm();
                (c.st.full_queue(), flushed, c.close.take())
            };
            if let Some(reply) = close {
                self.close(Instant::now()).await;
                if let Some(reply) = reply {
                    let _ = reply.send(());
                }
                return;
            }
            if flushed.is_err() {
                if net::wait_writable(&self.send_sock).await.is_err() {
                    // cannot wait: drop the datagram (reliable writers repair)
                    let mut c = shared.lock();
                    c.stalled = None;
                    c.out.send_errors += 1;
                }
                now = Instant::now();
                continue;
            }
            let wake = tokio::select! {
                biased;
                c = std::future::poll_fn(|cx| shared.lock().cmd.poll_recv(cx)) => Wake::Cmd(c),
                _ = recv_ready(&self.meta) => Wake::Readable(0),
                _ = recv_ready_opt(&self.user), if paused.is_none() => Wake::Readable(1),
                _ = recv_ready_opt(&self.meta_mc) => Wake::Readable(2),
                _ = recv_ready_opt(&self.user_mc), if paused.is_none() => Wake::Readable(3),
                _ = async { if let Some(q) = &paused { q.space().await } }, if paused.is_some() => Wake::Space,
                _ = std::future::poll_fn(|cx| shared.lock().timer.poll_fired(cx)) => Wake::Timer,
                _ = shared.attention.notified() => Wake::Attention,
            };
            now = Instant::now();
            if let (Some(s), Wake::Cmd(_) | Wake::Readable(_)) = (&self.spin, &wake) {
                s.activity();
            }
            match wake {
                Wake::Cmd(None) => break,
                Wake::Cmd(Some(Cmd::Close { reply })) => {
                    self.close(now).await;
                    let _ = reply.send(());
                    return;
                }
                Wake::Cmd(Some(c)) => {
                    let mut core = shared.lock();
                    core.st.command(c, now);
                    // take every command already queued before flushing
                    core.take_commands(now);
                    std::mem::swap(&mut self.immediate, &mut core.st.immediate);
                }
                Wake::Readable(i) => self.drain(i, now),
                Wake::Space | Wake::Timer | Wake::Attention => {}
            }
            if !self.immediate.is_empty() {
                // a full send buffer is seen by the next turn's flush
                let _ = shared.run_callbacks(&mut self.immediate);
            }
        }
        self.close(Instant::now()).await;
    }

    /// Reads what is waiting on socket `i`, a batch per system call, up
    /// to a limit (so that commands and timers are not starved); takes the
    /// immediate-delivery subscriptions that got samples.
    fn drain(&mut self, i: usize, now: Instant) {
        let mut c = self.shared.lock();
        let sock = match i {
            0 => Some(&self.meta),
            1 => self.user.as_ref(),
            2 => self.meta_mc.as_ref(),
            _ => self.user_mc.as_ref(),
        };
        if let Some(sock) = sock {
            for _ in 0..8 {
                if i % 2 == 1 && c.st.full_queue().is_some() {
                    break;
                }
                let n = match net::recv_batch(sock, &mut self.batch) {
                    Ok(n) => n,
                    // ICMP port unreachable and the like: reported once, nothing to do
                    Err(_) => continue,
                };
                c.receive(&self.batch, n, now);
                if n < net::RECV_SLOTS {
                    break; // the socket was emptied
                }
            }
        }
        std::mem::swap(&mut self.immediate, &mut c.st.immediate);
    }

    async fn close(&mut self, now: Instant) {
        if let Some(r) = self.receiver.take() {
            r.stop().await;
        }
        let stalled = {
            let mut c = self.shared.lock();
            c.st.p.close(now);
            c.flush(now).is_err()
        };
        if stalled {
            // the goodbyes, once there is room (a bounded wait)
            let room = net::wait_writable(&self.send_sock);
            if let Ok(Ok(())) = tokio::time::timeout(Duration::from_millis(100), room).await {
                let _ = self.shared.lock().flush(now);
            }
        }
        let mut c = self.shared.lock();
        let st = &mut c.st;
        st.pump(now);
        for r in st.readers.values() {
            r.queue.close();
        }
        for p in &st.patterns {
            p.queue.close();
        }
        for w in st.writers.values_mut() {
            for pw in w.pending.drain(..) {
                pw.done.send(Err(disconnected()));
            }
        }
        for c in st.confirms.drain(..) {
            let _ = c.reply.send(Err(disconnected()));
        }
        for q in st.waiting.drain(..) {
            let _ = q.reply.send(Err(QueryError::Disconnected(q.name)));
        }
        for (_, q) in st.inflight.drain() {
            let _ = q.reply.send(Err(QueryError::Disconnected(q.name)));
        }
        st.servers.clear(); // ends every Requests stream
        {
            let mut l = st.listeners.lock().unwrap();
            for tx in l.iter() {
                let _ = tx.send(SessionEvent::Disconnected);
            }
            l.clear();
        }
        // later commands fail at once (an `ask` gets its reply dropped),
        // and so do writes that do not wait
        c.cmd.close();
        while let Ok(cmd) = c.cmd.try_recv() {
            if let Cmd::Write { done, .. } = cmd {
                done.send(Err(disconnected()));
            }
        }
        c.close = Some(None);
        let st = &mut c.st;
        // the end markers go to immediate subscriptions' callbacks too
        let immediate = std::mem::take(&mut st.immediate);
        let queues: Vec<Arc<SampleQueue>> = st
            .readers
            .values()
            .map(|r| r.queue.clone())
            .chain(st.patterns.iter().map(|p| p.queue.clone()))
            .filter(|q| q.has_handler())
            .chain(immediate)
            .collect();
        drop(c);
        for q in queues {
            q.run_handler();
        }
    }
}

// ---------------------------------------------------------------------------
// The receive thread

/// A thread that blocks in `recvmmsg` on the user-data socket and handles
/// what arrives right there: the participant under the [`Shared`] lock,
/// then the callbacks of immediate subscriptions, which can answer at
/// once ([`Publisher::try_publish`](crate::Publisher::try_publish)). This
/// is how ORTE, Cyclone DDS (listeners) and ddsperf receive; it saves the
/// wake-up of a task in a tokio runtime per datagram.
struct ReceiveThread {
    /// `None` once joined.
    handle: Option<std::thread::JoinHandle<()>>,
    /// Where a datagram wakes the thread to stop.
    addr: SocketAddr,
    shared: Arc<Shared>,
}

impl ReceiveThread {
    fn start(shared: Arc<Shared>, sock: std::net::UdpSocket, name: &str) -> std::io::Result<Self> {
        sock.set_nonblocking(false)?;
        let addr = sock.local_addr()?;
        let s = shared.clone();
        let handle = std::thread::Builder::new()
            .name(format!("rtps-rx {name}"))
            .spawn(move || receive_loop(&s, &sock))?;
        Ok(ReceiveThread {
            handle: Some(handle),
            addr,
            shared,
        })
    }

    /// Tells the thread to stop, wherever it waits.
    fn signal(&self) {
        use std::sync::atomic::Ordering;
        self.shared.closing.store(true, Ordering::SeqCst);
        self.shared.stopping.notify_waiters();
        // a datagram to its own socket wakes the blocking receive
        let woken =
            std::net::UdpSocket::bind((self.addr.ip(), 0)).and_then(|s| s.send_to(&[], self.addr));
        if let Err(e) = woken {
            tracing::warn!("cannot wake the RTPS receive thread ({e}); it ends with the process");
        }
    }

    /// Stops the thread and waits for it.
    async fn stop(mut self) {
        self.signal();
        if let Some(h) = self.handle.take() {
            let _ = tokio::task::spawn_blocking(move || h.join()).await;
        }
    }
}

impl Drop for ReceiveThread {
    /// Without [`ReceiveThread::stop`] (the runtime went away with the
    /// driver task): the thread still ends, unwaited.
    fn drop(&mut self) {
        if self.handle.is_some() {
            self.signal();
        }
    }
}

fn receive_loop(shared: &Shared, sock: &std::net::UdpSocket) {
    use std::sync::atomic::Ordering;
    let mut batch = net::RecvBatch::new();
    let mut immediate = Vec::new();
    let mut wakes = Vec::new();
    loop {
        // an error (ICMP port unreachable and the like) reads nothing
        let n = net::recv_batch_blocking(sock, &mut batch).unwrap_or_default();
        if shared.closing.load(Ordering::SeqCst) {
            return;
        }
        let now = Instant::now();
        let (full, paused) = {
            let mut c = shared.lock();
            c.st.wakes = Some(std::mem::take(&mut wakes));
            c.receive(&batch, n, now);
            std::mem::swap(&mut immediate, &mut c.st.immediate);
            // with callbacks to run, what this produced (acknowledgements)
            // goes out after them, packed with their answers
            let full = immediate.is_empty() && c.flush(now).is_err();
            if immediate.is_empty() {
                c.rearm();
            }
            wakes = c.st.wakes.take().unwrap_or_default();
            (full, c.st.full_queue())
        };
        // a woken Subscriber's task (often on this CPU) runs once per batch,
        // and does not find the lock held
        for w in wakes.drain(..) {
            w.wake();
        }
        let full = full || shared.run_callbacks(&mut immediate).is_err();
        if full {
            // the driver waits for room and sends the rest
            shared.attention.notify_one();
        }
        let mut paused = paused;
        while let Some(q) = paused {
            // a Stream subscriber has not caught up: stop reading until it
            // has (the socket buffer, then the writer, hold the rest)
            let stopping = shared.stopping.notified();
            let mut stopping = std::pin::pin!(stopping);
            stopping.as_mut().enable(); // from here on no stop is missed
            if shared.closing.load(Ordering::SeqCst) {
                return;
            }
            // no runtime needed: both are woken by whoever acts
            futures::executor::block_on(async {
                tokio::select! {
                    _ = q.space() => {}
                    _ = stopping => {}
                }
            });
            paused = shared.lock().st.full_queue();
        }
    }
}

fn locator_of(a: SocketAddr) -> Locator {
    match a {
        SocketAddr::V4(v) => Locator::udpv4(v.ip().octets(), v.port()),
        SocketAddr::V6(v) => Locator {
            kind: Locator::KIND_UDPV6,
            port: u32::from(v.port()),
            address: v.ip().octets(),
        },
    }
}

struct PendingWrite {
    kind: ChangeKind,
    data: Vec<u8>,
    key_hash: Option<[u8; 16]>,
    confirm: Option<Duration>,
    done: Done,
}

/// What a publication offers that a pattern reader must copy to match it.
#[derive(Clone)]
struct Offer {
    keyed: bool,
    exclusive: bool,
    partitions: Vec<String>,
}

impl Offer {
    fn of(e: &courier_wire::rtps::discovery::EndpointData) -> Self {
        Offer {
            keyed: is_keyed_entity(e.guid),
            exclusive: e.qos.exclusive_ownership,
            partitions: e.qos.partitions.clone(),
        }
    }
}

struct LocalWriter {
    guid: Guid,
    type_name: String,
    offer: Offer,
    /// Writes waiting for room in a full keep-all history, in order.
    pending: VecDeque<PendingWrite>,
}

struct Confirm {
    writer: Guid,
    sn: SequenceNumber,
    deadline: Instant,
    after: Duration,
    topic: String,
    reply: Reply<()>,
}

struct LocalReader {
    topic: String,
    type_name: Arc<str>,
    queue: Arc<SampleQueue>,
    exclusive: bool,
    minimum_separation: Option<Duration>,
    deadline: Option<Duration>,
    /// Per instance: owner (exclusive ownership) and strength.
    owners: HashMap<[u8; 16], (Guid, i32)>,
    /// Per instance: when the last sample was delivered.
    last: HashMap<[u8; 16], Instant>,
    /// Per instance: when the deadline is next checked.
    due: HashMap<[u8; 16], Instant>,
    misses: u64,
}

/// A pattern subscription (or a subscription to a topic whose type is not
/// known yet): readers are created as matching publications appear.
struct Pattern {
    topic: String,
    type_name: String,
    qos: EndpointQos,
    queue: Arc<SampleQueue>,
    /// (topic, type) pairs that have a reader already.
    have: HashSet<(String, String)>,
    readers: Vec<Guid>,
}

/// What is known about a writer, for the reader-side filters.
#[derive(Clone, Copy)]
struct WriterInfo {
    strength: i32,
    lifespan: Option<Duration>,
}

struct State {
    p: Participant,
    name: String,
    listeners: Listeners,
    writers: HashMap<String, LocalWriter>,
    readers: HashMap<Guid, LocalReader>,
    patterns: Vec<Pattern>,
    watched: HashSet<String>,
    remote_writers: HashMap<Guid, WriterInfo>,
    /// `Sample::source` of the writers that delivered samples (their GUID
    /// in hex), made once per writer.
    source_names: HashMap<Guid, Arc<str>>,
    confirms: Vec<Confirm>,
    next_housekeeping: Instant,
    /// Request readers of `serve`, by reader GUID: service name and where
    /// requests go.
    servers: HashMap<Guid, Server>,
    /// Request writer and reply reader of each service queried.
    clients: HashMap<String, Client>,
    /// Reply readers of clients → service name.
    client_readers: HashMap<Guid, String>,
    /// Queries waiting for the service's endpoints to match.
    waiting: Vec<WaitingQuery>,
    /// Queries sent, by the request's identity.
    inflight: HashMap<SampleIdentity, InflightQuery>,
    /// For responders: replies come back to the driver as commands.
    responder: mpsc::WeakUnboundedSender<Cmd>,
    /// Sample buffers subscribers have decoded, for the participant to reuse.
    returns: Arc<ReturnedBuffers>,
    /// Immediate-delivery subscriptions that got samples since they were
    /// last handed to their callbacks (see [`Shared::run_callbacks`]).
    immediate: Vec<Arc<SampleQueue>>,
    /// While the receive thread handles a batch: the wakers of the
    /// `Subscriber`s it delivered to, woken once the batch is done and the
    /// lock released (woken at once otherwise).
    wakes: Option<Vec<std::task::Waker>>,
}

struct Server {
    name: String,
    tx: mpsc::Sender<RawRequest>,
    dropped: u64,
}

struct Client {
    writer: Guid,
    reader: Guid,
}

struct WaitingQuery {
    name: String,
    data: Vec<u8>,
    deadline: Instant,
    timeout: Duration,
    reply: oneshot::Sender<Result<RawReply, QueryError>>,
}

struct InflightQuery {
    name: String,
    deadline: Instant,
    timeout: Duration,
    reply: oneshot::Sender<Result<RawReply, QueryError>>,
}

const HOUSEKEEPING: Duration = Duration::from_millis(200);

impl State {
    fn emit(&self, e: SessionEvent) {
        let mut l = self.listeners.lock().unwrap();
        l.retain(|tx| tx.send(e.clone()).is_ok());
    }

    fn next_wakeup(&self) -> Instant {
        let mut t = self.next_housekeeping;
        if let Some(p) = self.p.poll_timeout() {
            t = t.min(p);
        }
        for c in &self.confirms {
            t = t.min(c.deadline);
        }
        for q in &self.waiting {
            t = t.min(q.deadline);
        }
        for q in self.inflight.values() {
            t = t.min(q.deadline);
        }
        for r in self.readers.values() {
            for d in r.due.values() {
                t = t.min(*d);
            }
        }
        t
    }

    /// A reliable keep-all subscription whose queue is full, if any.
    /// A keep-all subscription queue the application has not emptied:
    /// user data is not read until it has room. A reliable writer then
    /// waits for acknowledgements; a best-effort burst waits in the socket
    /// buffer (where the kernel drops what does not fit) instead of being
    /// read and thrown away here.
    fn full_queue(&self) -> Option<Arc<SampleQueue>> {
        self.readers
            .values()
            .find(|r| r.queue.is_full())
            .map(|r| r.queue.clone())
    }

    /// Runs what is due at `now`: the participant's timers, confirmations
    /// and queries that ran out of time, missed deadlines, housekeeping. The
    /// driver calls it once [`State::next_wakeup`], the earliest of exactly
    /// these deadlines, has come.
    fn tick(&mut self, now: Instant) {
        if self.p.poll_timeout().is_some_and(|t| t <= now) {
            self.p.handle_timeout(now);
        }
        // confirmations that ran out of time
        let mut i = 0;
        while i < self.confirms.len() {
            if self.confirms[i].deadline <= now {
                let c = self.confirms.swap_remove(i);
                let _ = c.reply.send(Err(SessionError::Timeout {
                    what: format!("acknowledgement of a sample of {} by every reader", c.topic),
                    after: c.after,
                }));
            } else {
                i += 1;
            }
        }
        self.check_deadlines(now);
        self.expire_queries(now);
        if now >= self.next_housekeeping {
            self.next_housekeeping = now + HOUSEKEEPING;
            self.drop_abandoned(now);
            self.retry_pending(now);
        }
    }

    fn check_deadlines(&mut self, now: Instant) {
        let mut missed = Vec::new();
        for r in self.readers.values_mut() {
            let Some(period) = r.deadline else { continue };
            for due in r.due.values_mut() {
                if *due <= now {
                    r.misses += 1;
                    *due = now + period;
                    missed.push(SessionEvent::DeadlineMissed {
                        msg: r.topic.clone(),
                        total: r.misses,
                    });
                }
            }
        }
        for e in missed {
            self.emit(e);
        }
    }

    /// Deletes the readers of subscriptions the application dropped.
    fn drop_abandoned(&mut self, now: Instant) {
        let gone: Vec<Guid> = self
            .readers
            .iter()
            .filter(|(_, r)| r.queue.is_receiver_gone())
            .map(|(g, _)| *g)
            .collect();
        for g in gone {
            self.readers.remove(&g);
            self.p.delete_reader(g, now);
        }
        let mut i = 0;
        while i < self.patterns.len() {
            if self.patterns[i].queue.is_receiver_gone() {
                let pat = self.patterns.swap_remove(i);
                for g in pat.readers {
                    self.readers.remove(&g);
                    self.p.delete_reader(g, now);
                }
            } else {
                i += 1;
            }
        }
    }

    fn command(&mut self, c: Cmd, now: Instant) {
        match c {
            Cmd::Publication {
                topic,
                ty,
                qos,
                reply,
            } => {
                let _ = reply.send(self.create_writer(topic, &ty, &qos, now));
            }
            Cmd::Subscription {
                topic,
                ty,
                qos,
                queue,
                reply,
            } => {
                queue.return_buffers_to(&self.returns);
                let r = match ty {
                    Some(ty) => self
                        .create_reader(
                            &topic,
                            ty.type_name,
                            ty.keyed,
                            subscription_qos(&qos),
                            &qos,
                            queue,
                            now,
                        )
                        .map(|_| ()),
                    None => {
                        // the type is learned from the first publication seen
                        self.add_pattern(
                            topic.clone(),
                            "*".into(),
                            subscription_qos(&qos),
                            queue,
                            now,
                        );
                        Ok(())
                    }
                };
                let _ = reply.send(r);
            }
            Cmd::Pattern {
                topic,
                type_name,
                queue,
                reply,
            } => {
                queue.return_buffers_to(&self.returns);
                let mut q = EndpointQos::reader_default();
                q.history = WireHistory::KeepAll;
                self.add_pattern(topic, type_name, q, queue, now);
                let _ = reply.send(Ok(()));
            }
            Cmd::Write {
                topic,
                kind,
                data,
                key_hash,
                confirm,
                done,
            } => {
                let Some(w) = self.writers.get_mut(&*topic) else {
                    done.send(Err(SessionError::Refused(format!(
                        "{topic} has no publication in this session: call define::<T>() or \
                         publisher::<T>() first"
                    ))));
                    return;
                };
                // the serialized payload goes out padded with zeros to a
                // multiple of 4, as Cyclone DDS and Fast DDS send theirs;
                // Cyclone 0.10 drops user DATA whose payload is not
                let mut data = data;
                data.resize(data.len().next_multiple_of(4), 0);
                let pw = PendingWrite {
                    kind,
                    data,
                    key_hash,
                    confirm,
                    done,
                };
                if !w.pending.is_empty() {
                    w.pending.push_back(pw);
                    return;
                }
                if let Some(pw) = self.try_write(&topic, pw, now) {
                    if let Some(w) = self.writers.get_mut(&*topic) {
                        w.pending.push_back(pw);
                    }
                }
            }
            Cmd::ModuleConnected { name, reply } => {
                let known = name == self.name
                    || self
                        .p
                        .participants()
                        .any(|d| d.entity_name.as_deref() == Some(name.as_str()));
                let _ = reply.send(Ok(known));
            }
            Cmd::NumHandlers { topic, reply } => {
                let _ = reply.send(Ok(self.handlers(&topic)));
            }
            Cmd::Watch { topic } => {
                self.watched.insert(topic);
            }
            Cmd::Close { .. } => {}
            Cmd::Serve {
                name,
                req,
                resp,
                tx,
                reply,
            } => {
                let _ = reply.send(self.serve(name, &req, &resp, tx, now));
            }
            Cmd::Respond {
                name,
                data,
                request,
            } => self.respond(&name, data, request, now),
            Cmd::Query {
                name,
                req,
                resp,
                data,
                timeout,
                reply,
            } => {
                if let Err(e) = self.client(&name, &req, &resp, now) {
                    let _ = reply.send(Err(QueryError::Refused {
                        msg: name,
                        detail: e.to_string(),
                    }));
                    return;
                }
                self.waiting.push(WaitingQuery {
                    name,
                    data,
                    deadline: now + timeout,
                    timeout,
                    reply,
                });
                self.send_waiting(now);
            }
        }
    }

    /// Serves `name`: a reader of its request topic and a writer of its
    /// reply topic.
    fn serve(
        &mut self,
        name: String,
        req: &TypeInfo,
        resp: &TypeInfo,
        tx: mpsc::Sender<RawRequest>,
        now: Instant,
    ) -> Result<(), SessionError> {
        if self.servers.values().any(|s| s.name == name) {
            return Err(SessionError::Refused(format!(
                "{name} is already served by this session"
            )));
        }
        self.create_writer(reply_topic(&name), resp, &PublicationQos::default(), now)?;
        let cfg = EndpointConfig::reader(&request_topic(&name), req.type_name)
            .keyed(req.keyed)
            .qos(subscription_qos(&SubscriptionQos::default()));
        let g = self
            .p
            .create_reader(cfg, now)
            .map_err(|e| SessionError::Refused(format!("cannot serve {name}: {e}")))?;
        self.servers.insert(
            g,
            Server {
                name,
                tx,
                dropped: 0,
            },
        );
        Ok(())
    }

    fn respond(&mut self, name: &str, data: Vec<u8>, request: SampleIdentity, now: Instant) {
        let Some(w) = self.writers.get(&reply_topic(name)) else {
            return;
        };
        let mut data = data;
        data.resize(data.len().next_multiple_of(4), 0);
        let change = Change::alive(&data).with_related_sample_identity(request);
        // a reliable keep-all reply writer only refuses when thousands of
        // replies are unacknowledged; the client then times out
        let _ = self.p.write(w.guid, change, now);
    }

    /// The request writer and reply reader for querying `name`.
    fn client(
        &mut self,
        name: &str,
        req: &TypeInfo,
        resp: &TypeInfo,
        now: Instant,
    ) -> Result<(), SessionError> {
        if self.clients.contains_key(name) {
            return Ok(());
        }
        self.create_writer(request_topic(name), req, &PublicationQos::default(), now)?;
        let writer = self.writers[&request_topic(name)].guid;
        let cfg = EndpointConfig::reader(&reply_topic(name), resp.type_name)
            .keyed(resp.keyed)
            .qos(subscription_qos(&SubscriptionQos::default()));
        let reader = self
            .p
            .create_reader(cfg, now)
            .map_err(|e| SessionError::Refused(format!("cannot query {name}: {e}")))?;
        self.clients
            .insert(name.to_string(), Client { writer, reader });
        self.client_readers.insert(reader, name.to_string());
        Ok(())
    }

    /// Sends the queries whose service is matched both ways (a request
    /// reader for our request writer, a reply writer for our reply reader).
    fn send_waiting(&mut self, now: Instant) {
        let mut i = 0;
        while i < self.waiting.len() {
            let name = &self.waiting[i].name;
            let Some(c) = self.clients.get(name) else {
                i += 1;
                continue;
            };
            let ready = !self.p.matched_readers(c.writer).is_empty()
                && !self.p.matched_writers(c.reader).is_empty();
            if !ready {
                i += 1;
                continue;
            }
            let q = self.waiting.swap_remove(i);
            let (writer, reader) = (c.writer, c.reader);
            let mut data = q.data;
            data.resize(data.len().next_multiple_of(4), 0);
            // as rmw_fastrtps clients do: the request names the reader its
            // reply should go to (sequence number unknown)
            let to = SampleIdentity {
                writer: reader,
                sequence_number: SequenceNumber(-1 << 32),
            };
            let change = Change::alive(&data).with_related_sample_identity(to);
            match self.p.write(writer, change, now) {
                Ok(sn) => {
                    self.inflight.insert(
                        SampleIdentity {
                            writer,
                            sequence_number: sn,
                        },
                        InflightQuery {
                            name: q.name,
                            deadline: q.deadline,
                            timeout: q.timeout,
                            reply: q.reply,
                        },
                    );
                }
                Err(e) => {
                    let _ = q.reply.send(Err(QueryError::Refused {
                        msg: q.name,
                        detail: e.to_string(),
                    }));
                }
            }
        }
    }

    /// Queries whose time ran out, waiting or sent.
    fn expire_queries(&mut self, now: Instant) {
        let mut i = 0;
        while i < self.waiting.len() {
            if self.waiting[i].deadline <= now {
                let q = self.waiting.swap_remove(i);
                let _ = q.reply.send(Err(QueryError::Timeout {
                    msg: q.name,
                    timeout: q.timeout,
                }));
            } else {
                i += 1;
            }
        }
        let late: Vec<SampleIdentity> = self
            .inflight
            .iter()
            .filter(|(_, q)| q.deadline <= now)
            .map(|(k, _)| *k)
            .collect();
        for k in late {
            if let Some(q) = self.inflight.remove(&k) {
                let _ = q.reply.send(Err(QueryError::Timeout {
                    msg: q.name,
                    timeout: q.timeout,
                }));
            }
        }
    }

    /// A request for one of our services, or a reply to one of our queries.
    fn rpc_sample(&mut self, s: &ReceivedSample) -> bool {
        if let Some(srv) = self.servers.get_mut(&s.reader) {
            if s.kind != ChangeKind::Alive {
                return true;
            }
            // as rmw_fastrtps: a request that names a reply reader (its
            // related identity's GUID) is answered for that GUID with the
            // request's sequence number; otherwise for the request itself
            let request = match s.related_sample_identity {
                Some(r) if r.writer.prefix != GuidPrefix::UNKNOWN => SampleIdentity {
                    writer: r.writer,
                    sequence_number: s.sequence_number,
                },
                _ => s.identity(),
            };
            let name = srv.name.clone();
            let cmd = self.responder.clone();
            let respond: crate::session::Responder = Box::new(move |_reply_msg, data| {
                let tx = cmd.upgrade().ok_or_else(disconnected)?;
                tx.send(Cmd::Respond {
                    name,
                    data,
                    request,
                })
                .map_err(|_| disconnected())
            });
            let r = RawRequest {
                msg: srv.name.clone(),
                data: s.data().to_vec(),
                order: courier_wire::ipc::ByteOrder::NATIVE,
                respond,
            };
            if srv.tx.try_send(r).is_err() {
                // the server's queue is full (or it stopped serving): the
                // client times out; counted
                srv.dropped += 1;
            }
            return true;
        }
        if let Some(name) = self.client_readers.get(&s.reader) {
            // a reply names our request writer (Courier, Fast DDS) or our
            // reply reader (rmw_fastrtps) with the request's sequence number
            let key = s
                .related_sample_identity
                .map(|id| match self.clients.get(name) {
                    Some(c) if id.writer == c.reader => SampleIdentity {
                        writer: c.writer,
                        sequence_number: id.sequence_number,
                    },
                    _ => id,
                });
            if let Some(q) = key.and_then(|id| self.inflight.remove(&id)) {
                let _ = q.reply.send(Ok((
                    reply_topic(name),
                    s.data().to_vec(),
                    courier_wire::ipc::ByteOrder::NATIVE,
                )));
            }
            // replies to other clients of the same service are not ours
            return true;
        }
        false
    }

    /// Readers of `topic`: those matched with our writer, else every
    /// known remote reader of it plus our own.
    fn handlers(&self, topic: &str) -> i32 {
        let n = match self.writers.get(topic) {
            Some(w) => self.p.matched_readers(w.guid).len(),
            None => {
                self.p
                    .subscriptions()
                    .filter(|s| s.topic_name == topic)
                    .count()
                    + self.readers.values().filter(|r| r.topic == topic).count()
            }
        };
        i32::try_from(n).unwrap_or(i32::MAX)
    }

    fn create_writer(
        &mut self,
        topic: String,
        ty: &TypeInfo,
        qos: &PublicationQos,
        now: Instant,
    ) -> Result<(), SessionError> {
        if let Some(w) = self.writers.get(&topic) {
            if w.type_name == ty.type_name {
                return Ok(());
            }
            return Err(SessionError::Refused(format!(
                "{topic} is already published in this session with type {}, not {}",
                w.type_name, ty.type_name
            )));
        }
        let cfg = EndpointConfig::writer(&topic, ty.type_name)
            .keyed(ty.keyed)
            .qos(publication_qos(qos));
        let guid = self
            .p
            .create_writer(cfg, now)
            .map_err(|e| SessionError::Refused(format!("cannot publish {topic}: {e}")))?;
        self.remote_writers.insert(
            guid,
            WriterInfo {
                strength: qos.strength.unwrap_or(0),
                lifespan: qos.persistence,
            },
        );
        self.writers.insert(
            topic,
            LocalWriter {
                guid,
                type_name: ty.type_name.to_string(),
                offer: Offer {
                    keyed: ty.keyed,
                    exclusive: qos.strength.is_some(),
                    partitions: qos.partitions.clone(),
                },
                pending: VecDeque::new(),
            },
        );
        Ok(())
    }

    #[allow(clippy::too_many_arguments)]
    fn create_reader(
        &mut self,
        topic: &str,
        type_name: &str,
        keyed: bool,
        wire_qos: EndpointQos,
        qos: &SubscriptionQos,
        queue: Arc<SampleQueue>,
        now: Instant,
    ) -> Result<Guid, SessionError> {
        let exclusive = wire_qos.exclusive_ownership;
        let cfg = EndpointConfig::reader(topic, type_name)
            .keyed(keyed)
            .qos(wire_qos);
        let guid = self
            .p
            .create_reader(cfg, now)
            .map_err(|e| SessionError::Refused(format!("cannot subscribe {topic}: {e}")))?;
        let mut due = HashMap::new();
        if let Some(d) = qos.deadline {
            if !keyed {
                due.insert([0; 16], now + d);
            }
        }
        self.readers.insert(
            guid,
            LocalReader {
                topic: topic.to_string(),
                type_name: Arc::from(type_name),
                queue,
                exclusive,
                minimum_separation: qos.minimum_separation.filter(|d| !d.is_zero()),
                deadline: qos.deadline,
                owners: HashMap::new(),
                last: HashMap::new(),
                due,
                misses: 0,
            },
        );
        Ok(guid)
    }

    fn add_pattern(
        &mut self,
        topic: String,
        type_name: String,
        qos: EndpointQos,
        queue: Arc<SampleQueue>,
        now: Instant,
    ) {
        self.patterns.push(Pattern {
            topic,
            type_name,
            qos,
            queue,
            have: HashSet::new(),
            readers: Vec::new(),
        });
        let idx = self.patterns.len() - 1;
        let mut known: Vec<(String, String, Offer)> = self
            .p
            .publications()
            .map(|e| (e.topic_name.clone(), e.type_name.clone(), Offer::of(e)))
            .collect();
        for (t, w) in self.writers.iter() {
            known.push((t.clone(), w.type_name.clone(), w.offer.clone()));
        }
        for (t, ty, offer) in known {
            self.pattern_match(idx, &t, &ty, &offer, now);
        }
    }

    /// Creates the reader of pattern `idx` for a publication of `topic` if
    /// it matches; the reader takes the publication's ownership kind and
    /// partitions, which must be equal for DDS to match them.
    fn pattern_match(
        &mut self,
        idx: usize,
        topic: &str,
        type_name: &str,
        offer: &Offer,
        now: Instant,
    ) {
        let pat = &self.patterns[idx];
        if !fnmatch(&pat.topic, topic) || !fnmatch(&pat.type_name, type_name) {
            return;
        }
        let key = (topic.to_string(), type_name.to_string());
        if pat.have.contains(&key) {
            return;
        }
        let (mut qos, queue) = (pat.qos.clone(), pat.queue.clone());
        qos.exclusive_ownership = offer.exclusive;
        qos.partitions = offer.partitions.clone();
        let sq = SubscriptionQos::default();
        if let Ok(g) = self.create_reader(topic, type_name, offer.keyed, qos, &sq, queue, now) {
            let pat = &mut self.patterns[idx];
            pat.have.insert(key);
            pat.readers.push(g);
        }
    }

    /// Writes now, or gives the write back when the history is full.
    fn try_write(
        &mut self,
        topic: &str,
        mut pw: PendingWrite,
        now: Instant,
    ) -> Option<PendingWrite> {
        let Some(w) = self.writers.get(topic) else {
            pw.done.send(Err(disconnected()));
            return None;
        };
        let guid = w.guid;
        if !self.p.has_room(guid, pw.data.len()) {
            return Some(pw); // a full keep-all history: wait for acknowledgements
        }
        // the encoded sample becomes the history's copy (the CDR writer
        // left room for its envelope)
        let mut change = Change::alive_owned(std::mem::take(&mut pw.data));
        change.kind = pw.kind;
        change.key_hash = pw.key_hash.map(KeyHash);
        if pw.confirm.is_some() {
            self.p.request_ack(guid);
        }
        match self.p.write(guid, change, now) {
            Ok(sn) => {
                match (pw.confirm, pw.done) {
                    (Some(after), Done::Reply(reply)) if !self.p.is_acked_by_all(guid, sn) => {
                        self.confirms.push(Confirm {
                            writer: guid,
                            sn,
                            deadline: now + after,
                            after,
                            topic: topic.to_string(),
                            reply,
                        });
                    }
                    (_, done) => done.send(Ok(())),
                }
                None
            }
            Err(e) => {
                pw.done.send(Err(SessionError::Refused(format!(
                    "cannot publish {topic}: {e}"
                ))));
                None
            }
        }
    }

    /// Retries writes that waited for room in a full history.
    fn retry_pending(&mut self, now: Instant) {
        let topics: Vec<String> = self
            .writers
            .iter()
            .filter(|(_, w)| !w.pending.is_empty())
            .map(|(t, _)| t.clone())
            .collect();
        for t in topics {
            while let Some(pw) = self.writers.get_mut(&t).and_then(|w| w.pending.pop_front()) {
                if let Some(back) = self.try_write(&t, pw, now) {
                    if let Some(w) = self.writers.get_mut(&t) {
                        w.pending.push_front(back);
                    }
                    break;
                }
            }
        }
    }

    fn resolve_confirms(&mut self, writer: Guid) {
        let mut i = 0;
        while i < self.confirms.len() {
            let c = &self.confirms[i];
            if c.writer == writer && self.p.is_acked_by_all(writer, c.sn) {
                let c = self.confirms.swap_remove(i);
                let _ = c.reply.send(Ok(()));
            } else {
                i += 1;
            }
        }
    }

    fn writer_topic(&self, writer: Guid) -> Option<String> {
        self.writers
            .iter()
            .find(|(_, w)| w.guid == writer)
            .map(|(t, _)| t.clone())
    }

    /// Handles every event the participant has.
    fn pump(&mut self, now: Instant) {
        let mut wall = None;
        while let Some(e) = self.p.poll_event() {
            match e {
                // one clock reading for every sample of a datagram
                Event::SampleReceived(s) => {
                    let wall = *wall.get_or_insert_with(SystemTime::now);
                    self.sample(s, now, wall)
                }
                e => self.event(e, now),
            }
        }
    }

    fn event(&mut self, e: Event, now: Instant) {
        match e {
            Event::SampleReceived(s) => self.sample(s, now, SystemTime::now()),
            Event::AckedByAll { writer, .. } => {
                self.resolve_confirms(writer);
                self.retry_pending(now);
            }
            Event::ParticipantFound(d) => self.emit(SessionEvent::ParticipantFound(Box::new(d))),
            Event::ParticipantChanged(d) => {
                self.emit(SessionEvent::ParticipantChanged(Box::new(d)))
            }
            Event::ParticipantLost { prefix, reason } => self.emit(SessionEvent::ParticipantLost {
                guid_prefix: prefix,
                disposed: reason == LostReason::Disposed,
            }),
            Event::PublicationFound(d) => {
                self.remote_writers.insert(
                    d.guid,
                    WriterInfo {
                        strength: d.qos.ownership_strength,
                        lifespan: d.qos.lifespan.to_std(),
                    },
                );
                let offer = Offer::of(&d);
                for i in 0..self.patterns.len() {
                    self.pattern_match(i, &d.topic_name, &d.type_name, &offer, now);
                }
                self.emit(SessionEvent::PublicationFound(Box::new(d)));
            }
            Event::PublicationChanged(d) => {
                self.remote_writers.insert(
                    d.guid,
                    WriterInfo {
                        strength: d.qos.ownership_strength,
                        lifespan: d.qos.lifespan.to_std(),
                    },
                );
                self.emit(SessionEvent::PublicationChanged(Box::new(d)));
            }
            Event::PublicationLost(g) => {
                self.remote_writers.remove(&g);
                self.source_names.remove(&g);
                self.emit(SessionEvent::PublicationLost(g));
            }
            Event::SubscriptionFound(d) => self.emit(SessionEvent::SubscriptionFound(Box::new(d))),
            Event::SubscriptionChanged(d) => {
                self.emit(SessionEvent::SubscriptionChanged(Box::new(d)))
            }
            Event::SubscriptionLost(g) => self.emit(SessionEvent::SubscriptionLost(g)),
            Event::WriterMatched { writer, .. } => {
                self.handlers_changed(writer);
                self.send_waiting(now);
            }
            Event::WriterUnmatched { writer, .. } => {
                self.handlers_changed(writer);
                // a reader that left may have been what kept the history full
                self.resolve_confirms(writer);
                self.retry_pending(now);
            }
            Event::ReaderMatched { .. } => self.send_waiting(now),
            Event::ReaderUnmatched { reader, writer } => {
                if let Some(r) = self.readers.get_mut(&reader) {
                    r.owners.retain(|_, (w, _)| *w != writer);
                }
            }
            Event::IncompatibleQos {
                local,
                remote,
                reason,
            } => {
                let msg = self
                    .readers
                    .get(&local)
                    .map(|r| r.topic.clone())
                    .or_else(|| self.writer_topic(local))
                    .unwrap_or_default();
                self.emit(SessionEvent::IncompatibleQos {
                    msg,
                    remote,
                    reason: reason.to_string(),
                });
            }
            _ => {}
        }
    }

    fn handlers_changed(&self, writer: Guid) {
        if let Some(topic) = self.writer_topic(writer) {
            if self.watched.contains(&topic) {
                let count = self.handlers(&topic);
                self.emit(SessionEvent::HandlersChanged { msg: topic, count });
            }
        }
    }

    fn sample(&mut self, s: ReceivedSample, now: Instant, received: SystemTime) {
        if self.rpc_sample(&s) {
            return;
        }
        let info = self.remote_writers.get(&s.writer).copied();
        let Some(r) = self.readers.get_mut(&s.reader) else {
            return;
        };
        let instance = s.key_hash.map_or([0; 16], |k| k.0);
        let alive = s.kind == ChangeKind::Alive;
        if alive {
            if let (Some(life), Some(ts)) = (
                info.and_then(|i| i.lifespan),
                s.source_timestamp.and_then(system_time),
            ) {
                if received.duration_since(ts).is_ok_and(|age| age > life) {
                    r.queue.count_dropped();
                    return;
                }
            }
            if r.exclusive {
                let strength = info.map_or(0, |i| i.strength);
                match r.owners.get(&instance) {
                    Some(&(owner, os))
                        if owner != s.writer
                            && (os > strength || (os == strength && owner < s.writer)) =>
                    {
                        return;
                    }
                    _ => {
                        r.owners.insert(instance, (s.writer, strength));
                    }
                }
            }
            if let Some(sep) = r.minimum_separation {
                if r.last
                    .get(&instance)
                    .is_some_and(|t| now.saturating_duration_since(*t) < sep)
                {
                    r.queue.count_dropped();
                    return;
                }
            }
            if r.minimum_separation.is_some() {
                r.last.insert(instance, now);
            }
            if let Some(d) = r.deadline {
                r.due.insert(instance, now + d);
            }
        } else {
            r.due.remove(&instance);
            r.owners.remove(&instance);
        }
        let source = self
            .source_names
            .entry(s.writer)
            .or_insert_with(|| Arc::from(guid_hex(s.writer)));
        let raw = RawSample {
            msg: r.topic.clone(),
            order: courier_wire::ipc::ByteOrder::NATIVE,
            received,
            source: Some(source.clone()),
            type_name: Some(r.type_name.clone()),
            state: match s.kind {
                ChangeKind::Alive => InstanceState::Alive,
                ChangeKind::Unregistered => InstanceState::Unregistered,
                ChangeKind::Disposed | ChangeKind::DisposedUnregistered => InstanceState::Disposed,
            },
            key_hash: s.key_hash.map(|k| k.0),
            source_time: s.source_timestamp.and_then(system_time),
            done: None,
            // last: the received buffer itself, not a copy
            data: s.into_data(),
        };
        // may exceed the capacity by what one receive batch (8 datagrams) carried; reading
        // stops until the application catches up (see `full_queue`)
        match &mut self.wakes {
            Some(wakes) => wakes.extend(r.queue.push_over_deferred(raw)),
            None => r.queue.push_over(raw),
        }
        if r.queue.has_handler() && !self.immediate.iter().any(|q| Arc::ptr_eq(q, &r.queue)) {
            self.immediate.push(r.queue.clone());
        }
    }
}

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
