//! What the driver keeps around the [`Domain`]: the application's side of
//! each handle (queues, waiting publishers and queries, servers) and the
//! mapping of the domain's events to the sdk's. The DDS decisions are the
//! domain's (`courier_wire::dds`).

use std::collections::VecDeque;
use std::sync::Arc;
use std::time::{Duration, Instant, SystemTime};

// seeded per process: several of these maps are keyed by GUIDs off the network
use foldhash::{HashMap, HashMapExt, HashSet, HashSetExt};

use courier_wire::dds::{
    reply_topic, request_topic, ConfirmFailure, Domain, Event, PatternId, QueryFailure, QueryId,
    ReaderId, ServiceConfig, WriterId,
};
use courier_wire::rtps::discovery::{
    Durability as WireDurability, Duration as RtpsDuration, EndpointQos, History as WireHistory,
    LivelinessKind as WireLivelinessKind, Reliability as WireReliability,
};
use courier_wire::rtps::participant::{
    self, Change, ChangeKind, EndpointConfig, KeyHash, LostReason,
};
use courier_wire::rtps::{EntityId, Guid, SequenceNumber};
use tokio::sync::{mpsc, oneshot};

use super::cmd::{disconnected, Cmd, Done, Reply};
use super::{guid_hex, system_time, Listeners};
use crate::backend::{ClientId, Handle, PubId, ServiceId, SubId};
use crate::error::{OpenError, PublishError};
use crate::qos::{
    Durability, History, InstanceState, KeyOf, Liveliness, LivelinessKind, PublicationQos,
    Reliability, SubscriptionQos, TypeInfo,
};
use crate::session::{
    QueryError, RawReply, RawRequest, RawSample, ReturnedBuffers, SampleQueue, SessionEvent,
};

struct PendingWrite {
    kind: ChangeKind,
    data: Vec<u8>,
    key_hash: Option<[u8; 16]>,
    confirm: Option<Duration>,
    done: Done,
    /// When the application wrote it: its source timestamp, also when
    /// it waits for room in a full history first (it was stamped when it
    /// got in, up to 1.3 s late with 4 MiB samples; audit 19).
    written: Instant,
}

/// A publication: a writer of its own (a topic may have several, each
/// with its own QoS).
struct Publication {
    id: WriterId,
    topic: String,
    type_name: String,
    /// Writes waiting for room in a full keep-all history, in order.
    pending: VecDeque<PendingWrite>,
    /// The last sample written, for lingering.
    last: Option<SequenceNumber>,
    /// Closed by the application at this instant: deleted once what it
    /// wrote is written and acknowledged, or after [`LINGER`].
    closed: Option<Instant>,
    /// The instances written and not yet disposed or unregistered (key
    /// hash → serialized key; a topic without key: its one instance, hash
    /// zero, empty key), disposed when the publication closes if
    /// `autodispose`, else unregistered.
    live: HashMap<[u8; 16], Vec<u8>>,
    /// Keyed topics: the instances this writer registered (wrote or
    /// disposed) and has not unregistered, to refuse an unregister of one
    /// it has not (DDS's PRECONDITION_NOT_MET); `None` once more than
    /// [`MAX_TRACKED_INSTANCES`] were seen, when nothing is refused.
    registered: Option<HashSet<[u8; 16]>>,
    key_of: Option<KeyOf>,
    autodispose: bool,
}

/// What a write does to the instances a publication leaves alive
/// ([`Publication::live`]).
fn track_live(live: &mut HashMap<[u8; 16], Vec<u8>>, key_of: Option<KeyOf>, pw: &PendingWrite) {
    match pw.key_hash {
        Some(hash) if pw.kind == ChangeKind::Alive => {
            let new = !live.contains_key(&hash) && live.len() < MAX_TRACKED_INSTANCES;
            if let Some(key) = key_of.filter(|_| new).and_then(|k| (k.key)(&pw.data)) {
                live.insert(hash, key);
            }
        }
        Some(hash) => {
            live.remove(&hash);
        }
        None if pw.kind == ChangeKind::Alive && key_of.is_none() && live.is_empty() => {
            // a topic without key has one instance, alive once written:
            // disposed at close as a keyed one's (Cyclone DDS does; its
            // readers saw NOT_ALIVE_NO_WRITERS instead). Its serialized key
            // is empty: the sample's encapsulation header alone.
            if let Some(h) = pw.data.get(..2) {
                live.insert([0; 16], vec![h[0], h[1], 0, 0]);
            }
        }
        None => {}
    }
}

/// Instances one publication keeps track of at most for disposing them when
/// it closes; past it, new instances are left to their readers' lease.
const MAX_TRACKED_INSTANCES: usize = 100_000;

/// How long a closed publication (service) waits at most for its readers
/// to acknowledge what it wrote (its replies) before it is deleted.
const LINGER: Duration = Duration::from_secs(10);

/// Where a reader's samples go.
struct Subscription {
    topic: String,
    type_name: Arc<str>,
    queue: Arc<SampleQueue>,
    /// The pattern subscription that made the reader, if one did.
    pattern: Option<PatternId>,
}

struct Confirm {
    topic: String,
    after: Duration,
    reply: Reply<(), PublishError>,
}

/// What a subscription handle deleted when closed.
#[derive(Clone, Copy)]
enum SubKind {
    Reader(ReaderId),
    Pattern(PatternId),
}

struct Server {
    id: courier_wire::dds::ServiceId,
    name: String,
    tx: mpsc::Sender<RawRequest>,
    dropped: u64,
}

struct Query {
    name: String,
    reply: oneshot::Sender<Result<RawReply, QueryError>>,
}

/// Writes waiting for room in a history are retried this often (besides
/// at once when the domain says the writer is writable).
const HOUSEKEEPING: Duration = Duration::from_millis(200);

pub(super) struct State {
    pub(super) d: Domain,
    name: String,
    pub(super) listeners: Listeners,
    /// Handle numbers, shared by every kind.
    next_handle: u64,
    writers: HashMap<PubId, Publication>,
    subs: HashMap<ReaderId, Subscription>,
    patterns: HashMap<PatternId, Arc<SampleQueue>>,
    sub_handles: HashMap<SubId, SubKind>,
    /// Topics whose handler count is watched, with the count last reported.
    watched: HashMap<String, Option<i32>>,
    confirms: HashMap<(WriterId, SequenceNumber), Confirm>,
    next_housekeeping: Instant,
    servers: HashMap<ServiceId, Server>,
    /// Services the application closed, deleted at these instants (their
    /// last replies go out meanwhile), in order.
    closed_services: Vec<(courier_wire::dds::ServiceId, Instant)>,
    /// Clients, with the service each queries.
    clients: HashMap<ClientId, (String, courier_wire::dds::ClientId)>,
    queries: HashMap<QueryId, Query>,
    /// Topics where a remote endpoint of another type was seen (ours,
    /// theirs), to say why a query found no server; bounded.
    mismatched: HashMap<String, (String, String)>,
    /// For responders: replies come back to the driver as commands.
    responder: crate::mailbox::WeakMailbox<Cmd>,
    /// The request/reply style of services and clients (`None`: each
    /// peer's).
    pub(super) service_style: Option<courier_wire::dds::RpcStyle>,
    /// Sample buffers subscribers have decoded, for the participant to reuse.
    pub(super) returns: Arc<ReturnedBuffers>,
    /// Immediate-delivery subscriptions that got samples since they were
    /// last handed to their callbacks (see [`super::driver::Shared::run_callbacks`]).
    pub(super) immediate: Vec<Arc<SampleQueue>>,
    /// While the receive thread handles a batch: the wakers of the
    /// `Subscriber`s it delivered to, woken once the batch is done and the
    /// lock released (woken at once otherwise).
    pub(super) wakes: Option<Vec<std::task::Waker>>,
    /// The ROS 2 graph topic, when the session reads it.
    pub(super) ros2: Option<super::ros2::Ros2Graph>,
    /// The XCDR version of each remote writer's data (the first data
    /// representation it announced; XCDR1 when it named none), which the
    /// key hashes it sends are in: an instance change says so
    /// ([`RawSample::key_hash_version`]), so that a key can be read back
    /// from a hash in either version.
    writer_versions: HashMap<Guid, courier_wire::cdr::Version>,
    /// When a full subscription queue was last warned of, and how many
    /// times it filled since without a line (a slow subscriber fills it
    /// again at every refill).
    full_said: courier_wire::throttle::Throttle,
}

/// At most one "queue is full" warning this often.
const FULL_LINE_EVERY: Duration = Duration::from_secs(10);

/// The XCDR version of a writer's data: the first data representation it
/// announced (DDS-XTypes 1.3 §7.6.3.1.1: a writer offers the one it
/// writes), XCDR1 when it announced none; `None` for XML.
fn data_version(representations: &[i16]) -> Option<courier_wire::cdr::Version> {
    use courier_wire::cdr::Version;
    match representations.first() {
        None | Some(0) => Some(Version::Xcdr1),
        Some(2) => Some(Version::Xcdr2),
        Some(_) => None,
    }
}

impl State {
    pub(super) fn new(
        d: Domain,
        name: &str,
        listeners: Listeners,
        responder: crate::mailbox::WeakMailbox<Cmd>,
        now: Instant,
    ) -> Self {
        State {
            d,
            name: name.to_string(),
            listeners,
            next_handle: 1,
            writers: HashMap::default(),
            subs: HashMap::new(),
            patterns: HashMap::new(),
            sub_handles: HashMap::new(),
            watched: HashMap::new(),
            confirms: HashMap::new(),
            next_housekeeping: now,
            servers: HashMap::new(),
            closed_services: Vec::new(),
            clients: HashMap::new(),
            queries: HashMap::new(),
            mismatched: HashMap::new(),
            responder,
            service_style: None,
            returns: Arc::default(),
            immediate: Vec::new(),
            wakes: None,
            ros2: None,
            writer_versions: HashMap::new(),
            full_said: courier_wire::throttle::Throttle::new(FULL_LINE_EVERY),
        }
    }

    fn handle(&mut self) -> u64 {
        self.next_handle += 1;
        self.next_handle - 1
    }

    fn emit(&self, e: SessionEvent) {
        self.listeners.send(e);
    }

    pub(super) fn next_wakeup(&self) -> Instant {
        let t = self.next_housekeeping;
        self.d.poll_timeout().map_or(t, |p| t.min(p))
    }

    /// A keep-all subscription queue the application has not emptied:
    /// user data is not read until it has room. A reliable writer then
    /// waits for acknowledgements; a best-effort burst waits in the socket
    /// buffer (where the kernel drops what does not fit) instead of being
    /// read and thrown away here.
    pub(super) fn full_queue(&mut self) -> Option<Arc<SampleQueue>> {
        while let Some(r) = self.d.paused_reader() {
            match self.subs.get(&r) {
                Some(s) if s.queue.is_full() => return Some(s.queue.clone()),
                _ => self.d.set_reader_full(r, false),
            }
        }
        None
    }

    /// Runs what is due at `now`: the domain's timers and housekeeping.
    /// The driver calls it once [`State::next_wakeup`] has come.
    pub(super) fn tick(&mut self, now: Instant) {
        if self.d.poll_timeout().is_some_and(|t| t <= now) {
            self.d.handle_timeout(now);
        }
        if now >= self.next_housekeeping {
            self.next_housekeeping = now + HOUSEKEEPING;
            let waiting: Vec<PubId> = self
                .writers
                .iter()
                .filter(|(_, w)| !w.pending.is_empty())
                .map(|(p, _)| *p)
                .collect();
            for p in waiting {
                self.retry_pending(p, now);
            }
            self.delete_lingering(now);
            self.forget_dropped_queries();
        }
    }

    /// Queries whose caller stopped waiting (the future was dropped) are
    /// forgotten rather than kept, and scanned at every turn, until their
    /// own timeout: 100 000 dropped queries of an hour made every other
    /// query ten times slower.
    fn forget_dropped_queries(&mut self) {
        let gone: std::collections::HashSet<QueryId> = self
            .queries
            .iter()
            .filter(|(_, q)| q.reply.is_closed())
            .map(|(id, _)| *id)
            .collect();
        if !gone.is_empty() {
            self.queries.retain(|id, _| !gone.contains(id));
            self.d.cancel_queries(&gone);
        }
    }

    /// An open whose caller stopped waiting (its future was dropped: a
    /// `timeout` or `select!` cancelled it): nobody will hold the handle,
    /// so what it stands for goes at once. Left, a subscription's queue
    /// would fill and hold the whole session, and a service would keep its
    /// name for ever.
    fn abandoned(&mut self, h: Handle, now: Instant) {
        tracing::debug!("an open was cancelled: closing {h:?}");
        self.close_handle(h, now);
    }

    /// Deletes what a handle the application closed stands for.
    fn close_handle(&mut self, h: Handle, now: Instant) {
        match h {
            Handle::Publication(p) => {
                self.dispose_live(p, now);
                // what was published before the close still reaches the
                // readers: the writer lingers until it is acknowledged
                if let Some(w) = self.writers.get_mut(&p) {
                    w.closed.get_or_insert(now);
                }
                self.delete_lingering(now);
            }
            Handle::Subscription(id) => match self.sub_handles.remove(&id) {
                Some(SubKind::Reader(r)) => {
                    self.subs.remove(&r);
                    self.d.delete_reader(r, now);
                }
                Some(SubKind::Pattern(p)) => {
                    self.patterns.remove(&p);
                    self.subs.retain(|_, s| s.pattern != Some(p));
                    self.d.delete_pattern(p, now);
                }
                None => {}
            },
            Handle::Service(id) => {
                // no more requests; replies already given still go out
                // (and are repaired) before the service is deleted
                if let Some(srv) = self.servers.remove(&id) {
                    // its request reader goes now: a request sent to it
                    // meanwhile would be taken and dropped, and a server
                    // that replaces it would never get it
                    self.d.stop_service(srv.id, now);
                    self.closed_services.push((srv.id, now + LINGER));
                }
            }
            Handle::Client(id) => {
                if let Some((_, c)) = self.clients.remove(&id) {
                    self.d.delete_client(c, now);
                }
            }
        }
    }

    /// A publication that closes disposes the instances it left alive
    /// (DDS's `autodispose_unregistered_instances`), or unregisters them
    /// when told not to, as a DDS writer that is deleted does: with their
    /// serialized key and key hash, after what it still has to write.
    fn dispose_live(&mut self, p: PubId, now: Instant) {
        let Some(w) = self.writers.get_mut(&p) else {
            return;
        };
        if w.closed.is_some() {
            return;
        }
        let kind = if w.autodispose {
            ChangeKind::Disposed
        } else {
            ChangeKind::Unregistered
        };
        // what is still waiting for room in the history counts too: its
        // disposes go after it
        let mut live = std::mem::take(&mut w.live);
        for pw in &w.pending {
            track_live(&mut live, w.key_of, pw);
        }
        for (hash, key) in live {
            let pw = PendingWrite {
                kind,
                data: key,
                key_hash: Some(hash),
                confirm: None,
                done: Done::Ignored,
                written: now,
            };
            let Some(w) = self.writers.get_mut(&p) else {
                return;
            };
            if !w.pending.is_empty() {
                w.pending.push_back(pw);
            } else if let Some(pw) = self.try_write(p, pw, now) {
                if let Some(w) = self.writers.get_mut(&p) {
                    w.pending.push_back(pw);
                }
            }
        }
    }

    /// Dispose of every publication's live instances (see
    /// [`State::dispose_live`]): when the session closes.
    pub(super) fn dispose_all_live(&mut self, now: Instant) {
        let ps: Vec<PubId> = self.writers.keys().copied().collect();
        for p in ps {
            self.dispose_live(p, now);
        }
    }

    /// Deletes the closed publications that are done: nothing waits to be
    /// written and every reader acknowledged the rest (or [`LINGER`] is
    /// over).
    fn delete_lingering(&mut self, now: Instant) {
        let done: Vec<PubId> = self
            .writers
            .iter()
            .filter(|(_, w)| {
                w.closed.is_some_and(|at| {
                    now >= at + LINGER
                        || (w.pending.is_empty()
                            && w.last.is_none_or(|sn| {
                                self.d.participant().is_acked_by_all(w.id.guid(), sn)
                            }))
                })
            })
            .map(|(p, _)| *p)
            .collect();
        for p in done {
            let Some(w) = self.writers.remove(&p) else {
                continue;
            };
            for pw in w.pending {
                pw.done.send(Err(PublishError::Closed(p)));
            }
            self.d.delete_writer(w.id, now);
        }
        while let Some(&(srv, at)) = self.closed_services.first() {
            if now < at {
                break;
            }
            self.closed_services.remove(0);
            self.d.delete_service(srv, now);
        }
    }

    /// At close: every waiter fails, every queue ends.
    /// The start of a close: the session's streams end, its queries and
    /// services stop, the instances its publications leave are disposed;
    /// what its writers hold still goes out (see [`State::quiet`]).
    pub(super) fn begin_close(&mut self, now: Instant) {
        for s in self.subs.values() {
            s.queue.close();
        }
        for q in self.patterns.values() {
            q.close();
        }
        for (_, q) in self.queries.drain() {
            let _ = q.reply.send(Err(QueryError::Disconnected(q.name)));
        }
        self.servers.clear();
        self.dispose_all_live(now);
    }

    /// Every writer has written what it holds and every reliable reader
    /// matched with it has acknowledged all of it: a closing session loses
    /// nothing its `publish().await`s returned `Ok` for by leaving now.
    pub(super) fn quiet(&self) -> bool {
        self.writers.values().all(|w| {
            w.pending.is_empty()
                && w.last
                    .is_none_or(|sn| self.d.participant().is_acked_by_all(w.id.guid(), sn))
        })
    }

    pub(super) fn fail_all(&mut self) {
        for s in self.subs.values() {
            s.queue.close();
        }
        for q in self.patterns.values() {
            q.close();
        }
        for w in self.writers.values_mut() {
            for pw in w.pending.drain(..) {
                pw.done.send(Err(disconnected()));
            }
        }
        for (_, c) in self.confirms.drain() {
            let _ = c.reply.send(Err(disconnected()));
        }
        for (_, q) in self.queries.drain() {
            let _ = q.reply.send(Err(QueryError::Disconnected(q.name)));
        }
        self.servers.clear(); // ends every Requests stream
        self.listeners.send(SessionEvent::Disconnected);
        self.listeners.close();
    }

    /// At the end: lets go of every subscription's queue, and returns
    /// those with callbacks, for their end markers. A callback often holds
    /// a publisher of its own session: kept here, it would keep the
    /// session alive for ever.
    pub(super) fn take_handler_queues(&mut self) -> Vec<Arc<SampleQueue>> {
        let immediate = std::mem::take(&mut self.immediate);
        std::mem::take(&mut self.subs)
            .into_values()
            .filter(|s| s.pattern.is_none())
            .map(|s| s.queue)
            .chain(std::mem::take(&mut self.patterns).into_values())
            .filter(|q| q.has_handler())
            .chain(immediate)
            .collect()
    }

    pub(super) fn command(&mut self, c: Cmd, now: Instant) {
        // what changes the session's endpoints changes its ROS 2 node
        let endpoints = matches!(
            c,
            Cmd::Publication { .. }
                | Cmd::Subscription { .. }
                | Cmd::Pattern { .. }
                | Cmd::Client { .. }
                | Cmd::Serve { .. }
                | Cmd::CloseHandle(_)
        );
        self.apply(c, now);
        if endpoints {
            self.publish_ros2_node(now);
        }
    }

    /// The GIDs of the session's open readers and writers: what its ROS 2
    /// node lists (a closed publication that lingers is not listed).
    fn endpoint_gids(
        &self,
    ) -> (
        Vec<courier_wire::ros2::graph::Gid>,
        Vec<courier_wire::ros2::graph::Gid>,
    ) {
        let mut readers: Vec<_> = self.subs.keys().map(|r| r.guid().into()).collect();
        let mut writers: Vec<_> = self
            .writers
            .values()
            .filter(|w| w.closed.is_none())
            .map(|w| w.id.guid().into())
            .collect();
        let pairs = self
            .servers
            .values()
            .filter_map(|s| self.d.service_endpoints(s.id))
            .chain(
                self.clients
                    .values()
                    .filter_map(|(_, c)| self.d.client_endpoints(*c)),
            );
        for (w, r) in pairs {
            writers.push(w.guid().into());
            readers.push(r.guid().into());
        }
        (readers, writers)
    }

    /// Publishes the session's ROS 2 node if its endpoints changed.
    pub(super) fn publish_ros2_node(&mut self, now: Instant) {
        if self.ros2.is_none() {
            return;
        }
        let (readers, writers) = self.endpoint_gids();
        if let Some(g) = &mut self.ros2 {
            g.publish(&mut self.d, readers, writers, now);
        }
    }

    fn apply(&mut self, c: Cmd, now: Instant) {
        match c {
            Cmd::Publication {
                topic,
                ty,
                qos,
                reply,
            } => {
                let r = self.create_writer(topic, &ty, &qos, now);
                if let Err(Ok(id)) = reply.send(r) {
                    self.abandoned(Handle::Publication(id), now);
                }
            }
            Cmd::Subscription {
                topic,
                ty,
                qos,
                queue,
                reply,
            } => {
                queue.return_buffers_to(&self.returns);
                let kind = match ty {
                    Some(ty) => {
                        let cfg = EndpointConfig::reader(&topic, ty.type_name)
                            .keyed(ty.keyed)
                            .qos(subscription_qos(&qos));
                        self.d
                            .create_reader(cfg, now)
                            .map(|id| {
                                if let Some(k) = ty.key_of {
                                    self.d.set_instance_keys(id, k.instances);
                                }
                                self.subs.insert(
                                    id,
                                    Subscription {
                                        topic: topic.clone(),
                                        type_name: Arc::from(ty.type_name),
                                        queue,
                                        pattern: None,
                                    },
                                );
                                SubKind::Reader(id)
                            })
                            .map_err(|source| OpenError::Endpoint {
                                topic: topic.clone(),
                                source,
                            })
                    }
                    None => {
                        // the type is learned from the first publication seen
                        let p = self
                            .d
                            .create_pattern(&topic, "*", subscription_qos(&qos), now);
                        self.patterns.insert(p, queue);
                        Ok(SubKind::Pattern(p))
                    }
                };
                let r = kind.map(|k| self.sub_handle(k));
                if let Err(Ok(id)) = reply.send(r) {
                    self.abandoned(Handle::Subscription(id), now);
                }
            }
            Cmd::Pattern {
                topic,
                type_name,
                queue,
                reply,
            } => {
                queue.return_buffers_to(&self.returns);
                let mut q = subscription_qos(&SubscriptionQos::default());
                q.reliability = WireReliability::BestEffort;
                q.history = WireHistory::KeepAll;
                let p = self.d.create_pattern(&topic, &type_name, q, now);
                self.patterns.insert(p, queue);
                let r = Ok(self.sub_handle(SubKind::Pattern(p)));
                if let Err(Ok(id)) = reply.send(r) {
                    self.abandoned(Handle::Subscription(id), now);
                }
            }
            Cmd::Write {
                publication,
                kind,
                data,
                key_hash,
                confirm,
                done,
                written,
            } => {
                let Some(w) = self.writers.get_mut(&publication) else {
                    done.send(Err(PublishError::Closed(publication)));
                    return;
                };
                let pw = PendingWrite {
                    kind,
                    data,
                    key_hash,
                    confirm,
                    done,
                    written: written.map_or(now, |t| t.min(now)),
                };
                if !w.pending.is_empty() {
                    w.pending.push_back(pw);
                    return;
                }
                if let Some(pw) = self.try_write(publication, pw, now) {
                    if let Some(w) = self.writers.get_mut(&publication) {
                        w.pending.push_back(pw);
                    }
                }
            }
            Cmd::ModuleConnected { name, reply } => {
                let known = name == self.name
                    || self
                        .d
                        .participant()
                        .participants()
                        .any(|d| d.entity_name.as_deref() == Some(name.as_str()));
                let _ = reply.send(Ok(known));
            }
            Cmd::AssertLiveliness { publication, reply } => {
                let r = match self.writers.get(&publication) {
                    Some(w) if w.closed.is_none() => {
                        self.d.assert_liveliness(w.id, now);
                        Ok(())
                    }
                    _ => Err(PublishError::Closed(publication)),
                };
                let _ = reply.send(r);
            }
            Cmd::AssertParticipantLiveliness { reply } => {
                self.d.assert_participant_liveliness(now);
                let _ = reply.send(Ok(()));
            }
            Cmd::NumHandlers { topic, reply } => {
                let _ = reply.send(Ok(self.handlers(&topic)));
            }
            Cmd::ReadersOf { topic, reply } => {
                let readers = self
                    .d
                    .participant()
                    .subscriptions()
                    .filter(|s| s.topic_name == topic)
                    .map(crate::EndpointInfo::from)
                    .collect();
                let _ = reply.send(Ok(readers));
            }
            Cmd::Watch { topic } => {
                self.watched.entry(topic).or_insert(None);
            }
            Cmd::Close { .. } => {}
            Cmd::Ros2Nodes { reply } => {
                let r = match &self.ros2 {
                    Some(g) => {
                        let (readers, writers) = self.endpoint_gids();
                        Ok(g.nodes(&self.d, readers, writers))
                    }
                    None => Err(crate::error::ControlError::Unsupported {
                        what: "the ROS 2 graph (connect with ros2_node=/namespace/name or \
                               ros2_graph=true)"
                            .into(),
                        backend: "rtps://",
                    }),
                };
                let _ = reply.send(r);
            }
            Cmd::CloseHandle(h) => self.close_handle(h, now),
            Cmd::Client {
                name,
                req,
                resp,
                reply,
            } => {
                let r = self
                    .d
                    .create_client(&service_config(&name, &req, &resp, self.service_style), now)
                    .map(|c| {
                        let id = ClientId(self.handle());
                        self.clients.insert(id, (name.clone(), c));
                        id
                    })
                    .map_err(|source| OpenError::Endpoint {
                        topic: name.clone(),
                        source,
                    });
                if let Err(Ok(id)) = reply.send(r) {
                    self.abandoned(Handle::Client(id), now);
                }
            }
            Cmd::Serve {
                name,
                req,
                resp,
                tx,
                reply,
            } => {
                let r = self.serve(name, &req, &resp, tx, now);
                if let Err(Ok(id)) = reply.send(r) {
                    self.abandoned(Handle::Service(id), now);
                }
            }
            Cmd::Respond {
                service,
                data,
                request,
            } => {
                // a reliable keep-all reply writer only refuses when thousands
                // of replies are unacknowledged; the client then times out
                let _ = self.d.reply(service, request, data, now);
            }
            Cmd::Query {
                client,
                data,
                timeout,
                reply,
            } => {
                let Some((name, client)) = self.clients.get(&client).cloned() else {
                    let _ = reply.send(Err(QueryError::Disconnected(format!(
                        "{client:?} (closed)"
                    ))));
                    return;
                };
                match self.d.query(client, data, timeout, now) {
                    Ok(q) => {
                        self.queries.insert(q, Query { name, reply });
                    }
                    Err(source) => {
                        let source = PublishError::Writer {
                            topic: name.clone(),
                            source,
                        };
                        let _ = reply.send(Err(QueryError::Refused { msg: name, source }));
                    }
                }
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
    ) -> Result<ServiceId, OpenError> {
        if self.servers.values().any(|s| s.name == name) {
            return Err(OpenError::AlreadyServed(name));
        }
        let id = self
            .d
            .create_service(&service_config(&name, req, resp, self.service_style), now)
            .map_err(|source| OpenError::Endpoint {
                topic: name.clone(),
                source,
            })?;
        let handle = ServiceId(self.handle());
        self.servers.insert(
            handle,
            Server {
                id,
                name,
                tx,
                dropped: 0,
            },
        );
        Ok(handle)
    }

    fn sub_handle(&mut self, kind: SubKind) -> SubId {
        let id = SubId(self.handle());
        self.sub_handles.insert(id, kind);
        id
    }

    /// Readers of `topic`: those matched with our writers of it (the most
    /// any one has), else every known remote reader of it plus our own.
    fn handlers(&self, topic: &str) -> i32 {
        let ours = self
            .writers
            .values()
            .filter(|w| w.topic == topic)
            .map(|w| self.d.matched_readers(w.id))
            .max();
        let n = match ours {
            Some(n) => n,
            None => {
                self.d
                    .participant()
                    .subscriptions()
                    .filter(|s| s.topic_name == topic)
                    .count()
                    + self.subs.values().filter(|s| s.topic == topic).count()
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
    ) -> Result<PubId, OpenError> {
        // one topic, one type (DDS: a topic is created with its type)
        if let Some(w) = self
            .writers
            .values()
            .find(|w| w.topic == topic && w.type_name != ty.type_name)
        {
            return Err(OpenError::TypeConflict {
                msg: topic,
                existing: w.type_name.clone(),
                given: ty.type_name.to_string(),
            });
        }
        let cfg = EndpointConfig::writer(&topic, ty.type_name)
            .keyed(ty.keyed)
            .qos(publication_qos(qos, ty));
        let id = self
            .d
            .create_writer(cfg, now)
            .map_err(|source| OpenError::Endpoint {
                topic: topic.clone(),
                source,
            })?;
        let handle = PubId(self.handle());
        self.writers.insert(
            handle,
            Publication {
                id,
                topic,
                type_name: ty.type_name.to_string(),
                pending: VecDeque::new(),
                last: None,
                closed: None,
                live: HashMap::new(),
                registered: Some(HashSet::new()),
                key_of: ty.key_of,
                autodispose: qos.autodispose,
            },
        );
        Ok(handle)
    }

    /// Writes now, or gives the write back when the history is full.
    fn try_write(
        &mut self,
        publication: PubId,
        mut pw: PendingWrite,
        now: Instant,
    ) -> Option<PendingWrite> {
        let Some(w) = self.writers.get_mut(&publication) else {
            pw.done.send(Err(PublishError::Closed(publication)));
            return None;
        };
        let id = w.id;
        if !self.d.has_room(id, pw.data.len()) {
            return Some(pw); // a full keep-all history: Event::Writable follows
        }
        if let Some(hash) = pw.key_hash {
            if let Some(reg) = &mut w.registered {
                if pw.kind == ChangeKind::Unregistered {
                    if !reg.remove(&hash) {
                        pw.done.send(Err(PublishError::NotRegistered {
                            topic: w.topic.clone(),
                        }));
                        return None;
                    }
                } else if reg.len() < MAX_TRACKED_INSTANCES {
                    reg.insert(hash);
                } else if !reg.contains(&hash) {
                    // too many to know: refuse nothing from now on
                    w.registered = None;
                }
            }
        }
        // the instances left alive, for autodispose
        track_live(&mut w.live, w.key_of, &pw);
        // the encoded sample becomes the history's copy (the CDR writer
        // left room for its envelope)
        let mut change = Change::alive_owned(std::mem::take(&mut pw.data));
        change.kind = match pw.kind {
            // DDS's autodispose_unregistered_instances: an unregister
            // disposes too, as Cyclone DDS's does (its readers saw the
            // instance disposed, Courier's no writers; audit 18)
            ChangeKind::Unregistered if w.autodispose => ChangeKind::DisposedUnregistered,
            kind => kind,
        };
        change.key_hash = pw.key_hash.map(KeyHash);
        if pw.written < now {
            // it waited for room: stamped when it was written
            change.source_timestamp = Some(self.d.participant().time_at(pw.written));
        }
        let topic = w.topic.as_str();
        let refused = |source: participant::WriteError| PublishError::Writer {
            topic: topic.to_string(),
            source,
        };
        match (pw.confirm, pw.done) {
            (Some(after), Done::Reply(reply)) => {
                match self.d.write_confirmed(id, change, after, now) {
                    Ok(sn) => {
                        w.last = Some(sn);
                        self.confirms.insert(
                            (id, sn),
                            Confirm {
                                topic: topic.to_string(),
                                after,
                                reply,
                            },
                        );
                    }
                    Err(e) => {
                        let _ = reply.send(Err(refused(e)));
                    }
                }
            }
            (_, done) => {
                let r = self.d.write(id, change, now);
                if let Ok(sn) = r {
                    w.last = Some(sn);
                }
                done.send(r.map(drop).map_err(refused))
            }
        }
        None
    }

    /// Retries the writes to `topic` that waited for room in its history.
    fn retry_pending(&mut self, publication: PubId, now: Instant) {
        while let Some(pw) = self
            .writers
            .get_mut(&publication)
            .and_then(|w| w.pending.pop_front())
        {
            if let Some(back) = self.try_write(publication, pw, now) {
                if let Some(w) = self.writers.get_mut(&publication) {
                    w.pending.push_front(back);
                }
                break;
            }
        }
    }

    /// The publication of `writer` and its topic.
    fn publication_of(&self, writer: WriterId) -> Option<(PubId, &str)> {
        self.writers
            .iter()
            .find(|(_, w)| w.id == writer)
            .map(|(p, w)| (*p, w.topic.as_str()))
    }

    /// Handles every event the domain has.
    pub(super) fn pump(&mut self, now: Instant) {
        let mut wall = None;
        while let Some(e) = self.d.poll_event() {
            match e {
                // one clock reading for every sample of a datagram
                Event::Sample { reader, sample } => {
                    let wall = *wall.get_or_insert_with(SystemTime::now);
                    self.sample(reader, sample, wall)
                }
                e => self.event(e, now),
            }
        }
    }

    fn event(&mut self, e: Event, now: Instant) {
        use participant::Event as P;
        match e {
            Event::Sample { reader, sample } => self.sample(reader, sample, SystemTime::now()),
            Event::SampleDropped { reader, .. } => {
                if let Some(s) = self.subs.get(&reader) {
                    s.queue.count_dropped();
                }
            }
            Event::SampleLost {
                reader,
                writer,
                size,
                limit,
            } => {
                if let Some(s) = self.subs.get(&reader) {
                    s.queue.count_dropped();
                    tracing::warn!(topic = %s.topic, "gave up a sample of {size} bytes: larger than the {limit} this session takes");
                    self.emit(SessionEvent::SampleLost {
                        msg: s.topic.clone(),
                        writer: writer.into(),
                        size: u64::from(size),
                        limit: limit as u64,
                    });
                }
            }
            Event::DeadlineMissed { reader, total, .. } => {
                if let Some(s) = self.subs.get(&reader) {
                    self.emit(SessionEvent::DeadlineMissed {
                        msg: s.topic.clone(),
                        total,
                    });
                }
            }
            Event::LivelinessChanged {
                reader,
                writer,
                alive,
                alive_count,
                not_alive_count,
            } => {
                if let Some(s) = self.subs.get(&reader) {
                    self.emit(SessionEvent::LivelinessChanged {
                        msg: s.topic.clone(),
                        writer: writer.into(),
                        alive,
                        alive_count,
                        not_alive_count,
                    });
                }
            }
            Event::PatternMatched {
                pattern,
                reader,
                topic,
                type_name,
                replaces,
            } => {
                if let Some(old) = replaces {
                    self.subs.remove(&old);
                }
                if let Some(q) = self.patterns.get(&pattern) {
                    self.subs.insert(
                        reader,
                        Subscription {
                            topic,
                            type_name: Arc::from(type_name),
                            queue: q.clone(),
                            pattern: Some(pattern),
                        },
                    );
                    // a reader of the session's: in its ROS 2 node
                    self.publish_ros2_node(now);
                }
            }
            Event::PatternUnmatched { reader, .. } => {
                // its publications are gone: the domain deleted it
                self.subs.remove(&reader);
                self.publish_ros2_node(now);
            }
            Event::Request {
                service,
                request,
                sample,
            } => self.request(service, request, sample),
            Event::Reply { query, sample, .. } => {
                if let Some(q) = self.queries.remove(&query) {
                    let data = sample.into_data();
                    let _ = q.reply.send(Ok((
                        reply_topic(&q.name),
                        data,
                        courier_wire::ipc::ByteOrder::NATIVE,
                    )));
                }
            }
            Event::QueryFailed { query, reason, .. } => {
                if let Some(q) = self.queries.remove(&query) {
                    let e = match reason {
                        QueryFailure::Timeout(timeout) => QueryError::Timeout {
                            msg: q.name,
                            timeout,
                        },
                        QueryFailure::NoService(timeout) => {
                            let seen = [request_topic(&q.name), reply_topic(&q.name)]
                                .into_iter()
                                .find_map(|t| self.mismatched.get(&t).map(|m| (t, m.clone())));
                            match seen {
                                Some((topic, (local_type, remote_type))) => {
                                    QueryError::ServerTypeMismatch {
                                        msg: q.name,
                                        timeout,
                                        topic,
                                        local_type,
                                        remote_type,
                                    }
                                }
                                None => QueryError::NoResponder {
                                    msg: q.name,
                                    timeout,
                                },
                            }
                        }
                        QueryFailure::Unmatched { timeout, replies } => QueryError::Unmatched {
                            msg: q.name,
                            timeout,
                            replies,
                        },
                        QueryFailure::Refused(source) => QueryError::Refused {
                            source: PublishError::Writer {
                                topic: q.name.clone(),
                                source,
                            },
                            msg: q.name,
                        },
                        QueryFailure::ServiceLost => QueryError::ServerLost(q.name),
                        _ => QueryError::Disconnected(q.name),
                    };
                    let _ = q.reply.send(Err(e));
                }
            }
            Event::WriteConfirmed {
                writer,
                sequence_number,
            } => {
                if let Some(c) = self.confirms.remove(&(writer, sequence_number)) {
                    let _ = c.reply.send(Ok(()));
                }
            }
            Event::ConfirmFailed {
                writer,
                sequence_number,
                reason,
            } => {
                if let Some(c) = self.confirms.remove(&(writer, sequence_number)) {
                    let e = match reason {
                        ConfirmFailure::Timeout(_) => PublishError::Timeout {
                            what: format!(
                                "acknowledgement of a sample of {} by every reader",
                                c.topic
                            ),
                            after: c.after,
                        },
                        _ => disconnected(),
                    };
                    let _ = c.reply.send(Err(e));
                }
            }
            Event::OfferedDeadlineMissed { writer, total, .. } => {
                let open = self
                    .writers
                    .values()
                    .find(|w| w.id == writer && w.closed.is_none());
                if let Some(w) = open {
                    self.emit(SessionEvent::OfferedDeadlineMissed {
                        msg: w.topic.clone(),
                        total,
                    });
                }
            }
            Event::LivelinessLost { writer, total } => {
                let open = self
                    .writers
                    .values()
                    .find(|w| w.id == writer && w.closed.is_none());
                if let Some(w) = open {
                    self.emit(SessionEvent::LivelinessLost {
                        msg: w.topic.clone(),
                        total,
                    });
                }
            }
            Event::Writable { writer } => {
                if let Some((p, _)) = self.publication_of(writer) {
                    self.retry_pending(p, now);
                }
            }
            Event::WriterMatched { writer, .. } | Event::WriterUnmatched { writer, .. } => {
                self.handlers_changed(writer)
            }
            Event::TypeMismatch {
                topic,
                remote,
                local_type,
                remote_type,
                ..
            } => {
                tracing::warn!(
                    "{topic}: remote endpoint {} has type {remote_type}, ours is {local_type}",
                    guid_hex(remote)
                );
                if self.mismatched.len() < 1024 {
                    self.mismatched
                        .insert(topic.clone(), (local_type.clone(), remote_type.clone()));
                }
                self.emit(SessionEvent::TypeMismatch {
                    topic,
                    remote: remote.into(),
                    local_type,
                    remote_type,
                })
            }
            Event::IncompatibleQos {
                topic,
                remote,
                reason,
                ..
            } => self.emit(SessionEvent::IncompatibleQos {
                msg: topic,
                remote: remote.into(),
                reason,
            }),
            Event::Discovery(d) => match d {
                P::ParticipantFound(d) => {
                    self.emit(SessionEvent::ParticipantFound(Box::new((&d).into())))
                }
                P::ParticipantChanged(d) => {
                    self.emit(SessionEvent::ParticipantChanged(Box::new((&d).into())))
                }
                P::ParticipantLost { prefix, reason } => {
                    self.emit(SessionEvent::ParticipantLost {
                        guid: Guid {
                            prefix,
                            entity: EntityId::PARTICIPANT,
                        }
                        .into(),
                        disposed: reason == LostReason::Disposed,
                    });
                    if let Some(g) = &mut self.ros2 {
                        g.participant_lost(prefix, &self.listeners);
                    }
                }
                P::PublicationFound(d) => {
                    self.note_writer_version(d.guid, &d.qos.data_representation);
                    self.emit(SessionEvent::PublicationFound(Box::new((&d).into())))
                }
                P::PublicationChanged(d) => {
                    self.note_writer_version(d.guid, &d.qos.data_representation);
                    self.emit(SessionEvent::PublicationChanged(Box::new((&d).into())))
                }
                P::PublicationLost(g) => {
                    self.writer_versions.remove(&g);
                    self.emit(SessionEvent::PublicationLost(g.into()));
                }
                P::SubscriptionFound(d) => {
                    self.emit(SessionEvent::SubscriptionFound(Box::new((&d).into())))
                }
                P::SubscriptionChanged(d) => {
                    self.emit(SessionEvent::SubscriptionChanged(Box::new((&d).into())))
                }
                P::SubscriptionLost(g) => self.emit(SessionEvent::SubscriptionLost(g.into())),
                _ => {}
            },
            _ => {}
        }
    }

    /// A writer's readers changed: a watched topic's count, once per change
    /// (each of the topic's writers sees the same reader come).
    fn handlers_changed(&mut self, writer: WriterId) {
        let Some((_, topic)) = self.publication_of(writer) else {
            return;
        };
        let msg = topic.to_string();
        if !self.watched.contains_key(&msg) {
            return;
        }
        let count = self.handlers(&msg);
        if self.watched.insert(msg.clone(), Some(count)) != Some(Some(count)) {
            self.emit(SessionEvent::HandlersChanged { msg, count });
        }
    }

    /// A request for one of our services: to its `Requests` stream.
    fn request(
        &mut self,
        service: courier_wire::dds::ServiceId,
        request: courier_wire::dds::RequestId,
        s: participant::ReceivedSample,
    ) {
        let Some(srv) = self.servers.values_mut().find(|s| s.id == service) else {
            return;
        };
        let cmd = self.responder.clone();
        let respond = crate::session::Responder::from_fn(move |_reply_msg, data| {
            let tx = cmd.upgrade().ok_or_else(disconnected::<PublishError>)?;
            // one reply per request
            tx.post(Cmd::Respond {
                service,
                data,
                request,
            })
            .map_err(|_| disconnected())
        });
        let r = RawRequest {
            msg: srv.name.clone(),
            data: s.into_data(),
            order: courier_wire::ipc::ByteOrder::NATIVE,
            format: None,
            respond,
        };
        if srv.tx.try_send(r).is_err() {
            // the server's queue is full (or it stopped serving): the
            // client times out; counted
            srv.dropped += 1;
        }
    }

    /// Remembers the XCDR version of remote writer `g`'s data (see
    /// [`State::writer_versions`]).
    fn note_writer_version(&mut self, g: Guid, representations: &[i16]) {
        match data_version(representations) {
            Some(v) => self.writer_versions.insert(g, v),
            None => self.writer_versions.remove(&g),
        };
    }

    fn sample(&mut self, reader: ReaderId, s: participant::ReceivedSample, received: SystemTime) {
        let Some(r) = self.subs.get(&reader) else {
            if let Some(g) = self.ros2.as_mut().filter(|g| g.is_reader(reader)) {
                g.receive(s, &self.listeners);
            }
            return;
        };
        let source_time = s.source_timestamp.and_then(system_time);
        let expires = self
            .d
            .writer_lifespan(s.writer)
            .zip(source_time)
            .and_then(|(life, t)| t.checked_add(life));
        let raw = RawSample {
            msg: r.topic.clone(),
            order: courier_wire::ipc::ByteOrder::NATIVE,
            received,
            source: Some(s.writer.into()),
            type_name: Some(r.type_name.clone()),
            state: match s.kind {
                ChangeKind::Alive => InstanceState::Alive,
                ChangeKind::Unregistered => InstanceState::Unregistered,
                ChangeKind::Disposed | ChangeKind::DisposedUnregistered => InstanceState::Disposed,
            },
            key_hash: s.key_hash.map(|k| k.0),
            // the hash of an instance change may be all there is of its key
            key_hash_version: if s.kind == ChangeKind::Alive {
                None
            } else {
                self.writer_versions.get(&s.writer).copied()
            },
            source_time,
            expires,
            // last: the received buffer itself, not a copy
            data: s.into_data(),
        };
        // may exceed the capacity by what one receive batch (8 datagrams)
        // carried; reading stops until the application catches up (see
        // `full_queue`)
        let was_full = r.queue.is_full();
        match &mut self.wakes {
            Some(wakes) => wakes.extend(r.queue.push_over_deferred(raw)),
            None => r.queue.push_over(raw),
        }
        if r.queue.is_full() {
            self.d.set_reader_full(reader, true);
            if !was_full {
                // every subscription of the session waits now: say so
                // (a warning too, once in a while: nobody may be reading
                // the events)
                if let Some(again) = self.full_said.admit(received) {
                    let since = if again > 0 {
                        format!(" (queues filled {again} time(s) since the last such line)")
                    } else {
                        String::new()
                    };
                    tracing::warn!(
                        "the queue of a subscription of {} is full: this session reads nothing \
                         more until it is read{since}",
                        r.topic
                    );
                }
                self.listeners.send(SessionEvent::SubscriberFull {
                    msg: r.topic.to_string(),
                    queued: r.queue.len(),
                });
            }
        }
        if r.queue.has_handler() && !self.immediate.iter().any(|q| Arc::ptr_eq(q, &r.queue)) {
            self.immediate.push(r.queue.clone());
        }
    }
}

fn service_config(
    name: &str,
    req: &TypeInfo,
    resp: &TypeInfo,
    style: Option<courier_wire::dds::RpcStyle>,
) -> ServiceConfig {
    let mut c =
        ServiceConfig::new(name, req.type_name, resp.type_name).keyed(req.keyed, resp.keyed);
    // requests and replies are written as final types are (XCDR1, what ROS 2's
    // RMWs read), whatever the types; both are accepted
    c.writer_qos = publication_qos(&PublicationQos::default(), &TypeInfo::untyped());
    c.reader_qos = subscription_qos(&SubscriptionQos::default());
    c.style = style;
    c
}

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

/// Unset: automatic with an infinite lease (DDS's default).
fn wire_liveliness(l: Option<Liveliness>) -> (WireLivelinessKind, RtpsDuration) {
    match l {
        None => (WireLivelinessKind::Automatic, RtpsDuration::INFINITE),
        Some(l) => (
            match l.kind {
                LivelinessKind::Automatic => WireLivelinessKind::Automatic,
                LivelinessKind::ManualByParticipant => WireLivelinessKind::ManualByParticipant,
                LivelinessKind::ManualByTopic => WireLivelinessKind::ManualByTopic,
            },
            RtpsDuration::from_std(l.lease),
        ),
    }
}

fn publication_qos(q: &PublicationQos, ty: &TypeInfo) -> EndpointQos {
    let mut e = EndpointQos::writer_default();
    e.data_representation = vec![q.representation_for(ty.extensibility).id()];
    e.reliability = wire_reliability(q.reliability);
    e.durability = wire_durability(q.durability);
    e.history = wire_history(q.history);
    e.deadline = wire_duration(q.deadline);
    e.liveliness = wire_liveliness(q.liveliness);
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
    e.data_representation = q
        .accepted_representations()
        .iter()
        .map(|r| r.id())
        .collect();
    e.reliability = wire_reliability(q.reliability);
    e.durability = wire_durability(q.durability);
    e.history = wire_history(q.history);
    e.deadline = wire_duration(q.deadline);
    e.liveliness = wire_liveliness(q.liveliness);
    e.time_based_filter = q
        .minimum_separation
        .map_or(RtpsDuration::ZERO, RtpsDuration::from_std);
    e.exclusive_ownership = q.exclusive;
    e.partitions = q.partitions.clone();
    e
}
