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
    reply_topic, ClientId, ConfirmFailure, Domain, Event, PatternId, QueryFailure, QueryId,
    ReaderId, ServiceConfig, ServiceId, WriterId,
};
use courier_wire::rtps::discovery::{
    Durability as WireDurability, Duration as RtpsDuration, EndpointQos, History as WireHistory,
    Reliability as WireReliability,
};
use courier_wire::rtps::participant::{
    self, Change, ChangeKind, EndpointConfig, KeyHash, LostReason,
};
use courier_wire::rtps::{EntityId, Guid, SequenceNumber};
use tokio::sync::{mpsc, oneshot};

use super::cmd::{disconnected, Cmd, Done, Reply};
use super::{guid_hex, system_time, Listeners};
use crate::error::{OpenError, PublishError};
use crate::qos::{
    Durability, History, InstanceState, PublicationQos, Reliability, SubscriptionQos, TypeInfo,
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
}

/// A publication: one writer per topic in a session.
struct Publication {
    id: WriterId,
    type_name: String,
    /// Writes waiting for room in a full keep-all history, in order.
    pending: VecDeque<PendingWrite>,
}

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

struct Server {
    name: String,
    tx: mpsc::Sender<RawRequest>,
    dropped: u64,
}

struct Query {
    name: String,
    reply: oneshot::Sender<Result<RawReply, QueryError>>,
}

/// Subscriptions dropped by the application are deleted this often.
const HOUSEKEEPING: Duration = Duration::from_millis(200);

pub(super) struct State {
    pub(super) d: Domain,
    name: String,
    pub(super) listeners: Listeners,
    writers: HashMap<String, Publication>,
    subs: HashMap<ReaderId, Subscription>,
    patterns: HashMap<PatternId, Arc<SampleQueue>>,
    watched: HashSet<String>,
    /// `Sample::source` of the writers that delivered samples (their GUID
    /// in hex), made once per writer.
    source_names: HashMap<Guid, Arc<str>>,
    confirms: HashMap<(WriterId, SequenceNumber), Confirm>,
    next_housekeeping: Instant,
    servers: HashMap<ServiceId, Server>,
    /// The client of each service queried.
    clients: HashMap<String, ClientId>,
    queries: HashMap<QueryId, Query>,
    /// For responders: replies come back to the driver as commands.
    responder: mpsc::WeakUnboundedSender<Cmd>,
    /// Sample buffers subscribers have decoded, for the participant to reuse.
    pub(super) returns: Arc<ReturnedBuffers>,
    /// Immediate-delivery subscriptions that got samples since they were
    /// last handed to their callbacks (see [`super::driver::Shared::run_callbacks`]).
    pub(super) immediate: Vec<Arc<SampleQueue>>,
    /// While the receive thread handles a batch: the wakers of the
    /// `Subscriber`s it delivered to, woken once the batch is done and the
    /// lock released (woken at once otherwise).
    pub(super) wakes: Option<Vec<std::task::Waker>>,
}

impl State {
    pub(super) fn new(
        d: Domain,
        name: &str,
        listeners: Listeners,
        responder: mpsc::WeakUnboundedSender<Cmd>,
        now: Instant,
    ) -> Self {
        State {
            d,
            name: name.to_string(),
            listeners,
            writers: HashMap::default(),
            subs: HashMap::new(),
            patterns: HashMap::new(),
            watched: HashSet::new(),
            source_names: HashMap::new(),
            confirms: HashMap::new(),
            next_housekeeping: now,
            servers: HashMap::new(),
            clients: HashMap::new(),
            queries: HashMap::new(),
            responder,
            returns: Arc::default(),
            immediate: Vec::new(),
            wakes: None,
        }
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
            self.drop_abandoned(now);
            let topics: Vec<String> = self
                .writers
                .iter()
                .filter(|(_, w)| !w.pending.is_empty())
                .map(|(t, _)| t.clone())
                .collect();
            for t in topics {
                self.retry_pending(&t, now);
            }
        }
    }

    /// Deletes the readers of subscriptions the application dropped.
    fn drop_abandoned(&mut self, now: Instant) {
        let gone: Vec<ReaderId> = self
            .subs
            .iter()
            .filter(|(_, s)| s.pattern.is_none() && s.queue.is_receiver_gone())
            .map(|(r, _)| *r)
            .collect();
        for r in gone {
            self.subs.remove(&r);
            self.d.delete_reader(r, now);
        }
        let gone: Vec<PatternId> = self
            .patterns
            .iter()
            .filter(|(_, q)| q.is_receiver_gone())
            .map(|(p, _)| *p)
            .collect();
        for p in gone {
            self.patterns.remove(&p);
            self.subs.retain(|_, s| s.pattern != Some(p));
            self.d.delete_pattern(p, now);
        }
    }

    /// At close: every waiter fails, every queue ends.
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

    /// The queues with callbacks, for their end markers (at close).
    pub(super) fn handler_queues(&mut self) -> Vec<Arc<SampleQueue>> {
        let immediate = std::mem::take(&mut self.immediate);
        self.subs
            .values()
            .filter(|s| s.pattern.is_none())
            .map(|s| s.queue.clone())
            .chain(self.patterns.values().cloned())
            .filter(|q| q.has_handler())
            .chain(immediate)
            .collect()
    }

    pub(super) fn command(&mut self, c: Cmd, now: Instant) {
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
                    Some(ty) => {
                        let cfg = EndpointConfig::reader(&topic, ty.type_name)
                            .keyed(ty.keyed)
                            .qos(subscription_qos(&qos));
                        self.d
                            .create_reader(cfg, now)
                            .map(|id| {
                                self.subs.insert(
                                    id,
                                    Subscription {
                                        topic: topic.clone(),
                                        type_name: Arc::from(ty.type_name),
                                        queue,
                                        pattern: None,
                                    },
                                );
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
                let p = self.d.create_pattern(&topic, &type_name, q, now);
                self.patterns.insert(p, queue);
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
                    done.send(Err(PublishError::NoPublication(topic.to_string())));
                    return;
                };
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
                        .d
                        .participant()
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
                service,
                data,
                request,
            } => {
                // a reliable keep-all reply writer only refuses when thousands
                // of replies are unacknowledged; the client then times out
                let _ = self.d.reply(service, request, data, now);
            }
            Cmd::Query {
                name,
                req,
                resp,
                data,
                timeout,
                reply,
            } => {
                let client = match self.client(&name, &req, &resp, now) {
                    Ok(c) => c,
                    Err(source) => {
                        let _ = reply.send(Err(QueryError::Open { msg: name, source }));
                        return;
                    }
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
    ) -> Result<(), OpenError> {
        if self.servers.values().any(|s| s.name == name) {
            return Err(OpenError::AlreadyServed(name));
        }
        let id = self
            .d
            .create_service(&service_config(&name, req, resp), now)
            .map_err(|source| OpenError::Endpoint {
                topic: name.clone(),
                source,
            })?;
        self.servers.insert(
            id,
            Server {
                name,
                tx,
                dropped: 0,
            },
        );
        Ok(())
    }

    /// The client for querying `name`.
    fn client(
        &mut self,
        name: &str,
        req: &TypeInfo,
        resp: &TypeInfo,
        now: Instant,
    ) -> Result<ClientId, OpenError> {
        if let Some(c) = self.clients.get(name) {
            return Ok(*c);
        }
        let c = self
            .d
            .create_client(&service_config(name, req, resp), now)
            .map_err(|source| OpenError::Endpoint {
                topic: name.to_string(),
                source,
            })?;
        self.clients.insert(name.to_string(), c);
        Ok(c)
    }

    /// Readers of `topic`: those matched with our writer, else every
    /// known remote reader of it plus our own.
    fn handlers(&self, topic: &str) -> i32 {
        let n = match self.writers.get(topic) {
            Some(w) => self.d.matched_readers(w.id),
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
    ) -> Result<(), OpenError> {
        if let Some(w) = self.writers.get(&topic) {
            if w.type_name == ty.type_name {
                return Ok(());
            }
            return Err(OpenError::TypeConflict {
                msg: topic,
                existing: w.type_name.clone(),
                given: ty.type_name.to_string(),
            });
        }
        let cfg = EndpointConfig::writer(&topic, ty.type_name)
            .keyed(ty.keyed)
            .qos(publication_qos(qos));
        let id = self
            .d
            .create_writer(cfg, now)
            .map_err(|source| OpenError::Endpoint {
                topic: topic.clone(),
                source,
            })?;
        self.writers.insert(
            topic,
            Publication {
                id,
                type_name: ty.type_name.to_string(),
                pending: VecDeque::new(),
            },
        );
        Ok(())
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
        let id = w.id;
        if !self.d.has_room(id, pw.data.len()) {
            return Some(pw); // a full keep-all history: Event::Writable follows
        }
        // the encoded sample becomes the history's copy (the CDR writer
        // left room for its envelope)
        let mut change = Change::alive_owned(std::mem::take(&mut pw.data));
        change.kind = pw.kind;
        change.key_hash = pw.key_hash.map(KeyHash);
        let refused = |source: participant::WriteError| PublishError::Writer {
            topic: topic.to_string(),
            source,
        };
        match (pw.confirm, pw.done) {
            (Some(after), Done::Reply(reply)) => {
                match self.d.write_confirmed(id, change, after, now) {
                    Ok(sn) => {
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
            (_, done) => done.send(self.d.write(id, change, now).map(drop).map_err(refused)),
        }
        None
    }

    /// Retries the writes to `topic` that waited for room in its history.
    fn retry_pending(&mut self, topic: &str, now: Instant) {
        while let Some(pw) = self
            .writers
            .get_mut(topic)
            .and_then(|w| w.pending.pop_front())
        {
            if let Some(back) = self.try_write(topic, pw, now) {
                if let Some(w) = self.writers.get_mut(topic) {
                    w.pending.push_front(back);
                }
                break;
            }
        }
    }

    fn writer_topic(&self, writer: WriterId) -> Option<String> {
        self.writers
            .iter()
            .find(|(_, w)| w.id == writer)
            .map(|(t, _)| t.clone())
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
            Event::DeadlineMissed { reader, total, .. } => {
                if let Some(s) = self.subs.get(&reader) {
                    self.emit(SessionEvent::DeadlineMissed {
                        msg: s.topic.clone(),
                        total,
                    });
                }
            }
            Event::PatternMatched {
                pattern,
                reader,
                topic,
                type_name,
            } => {
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
                }
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
                        QueryFailure::Refused(source) => QueryError::Refused {
                            source: PublishError::Writer {
                                topic: q.name.clone(),
                                source,
                            },
                            msg: q.name,
                        },
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
            Event::Writable { writer } => {
                if let Some(t) = self.writer_topic(writer) {
                    self.retry_pending(&t, now);
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
                reason: reason.to_string(),
            }),
            Event::Discovery(d) => match d {
                P::ParticipantFound(d) => {
                    self.emit(SessionEvent::ParticipantFound(Box::new((&d).into())))
                }
                P::ParticipantChanged(d) => {
                    self.emit(SessionEvent::ParticipantChanged(Box::new((&d).into())))
                }
                P::ParticipantLost { prefix, reason } => self.emit(SessionEvent::ParticipantLost {
                    guid: Guid {
                        prefix,
                        entity: EntityId::PARTICIPANT,
                    }
                    .into(),
                    disposed: reason == LostReason::Disposed,
                }),
                P::PublicationFound(d) => {
                    self.emit(SessionEvent::PublicationFound(Box::new((&d).into())))
                }
                P::PublicationChanged(d) => {
                    self.emit(SessionEvent::PublicationChanged(Box::new((&d).into())))
                }
                P::PublicationLost(g) => {
                    self.source_names.remove(&g);
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

    fn handlers_changed(&self, writer: WriterId) {
        if let Some(topic) = self.writer_topic(writer) {
            if self.watched.contains(&topic) {
                let count = self.handlers(&topic);
                self.emit(SessionEvent::HandlersChanged { msg: topic, count });
            }
        }
    }

    /// A request for one of our services: to its `Requests` stream.
    fn request(
        &mut self,
        service: ServiceId,
        request: courier_wire::dds::RequestId,
        s: participant::ReceivedSample,
    ) {
        let Some(srv) = self.servers.get_mut(&service) else {
            return;
        };
        let cmd = self.responder.clone();
        let respond = crate::session::Responder::from_fn(move |_reply_msg, data| {
            let tx = cmd.upgrade().ok_or_else(disconnected::<PublishError>)?;
            tx.send(Cmd::Respond {
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
            respond,
        };
        if srv.tx.try_send(r).is_err() {
            // the server's queue is full (or it stopped serving): the
            // client times out; counted
            srv.dropped += 1;
        }
    }

    fn sample(&mut self, reader: ReaderId, s: participant::ReceivedSample, received: SystemTime) {
        let Some(r) = self.subs.get(&reader) else {
            return;
        };
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
        // may exceed the capacity by what one receive batch (8 datagrams)
        // carried; reading stops until the application catches up (see
        // `full_queue`)
        match &mut self.wakes {
            Some(wakes) => wakes.extend(r.queue.push_over_deferred(raw)),
            None => r.queue.push_over(raw),
        }
        if r.queue.is_full() {
            self.d.set_reader_full(reader, true);
        }
        if r.queue.has_handler() && !self.immediate.iter().any(|q| Arc::ptr_eq(q, &r.queue)) {
            self.immediate.push(r.queue.clone());
        }
    }
}

fn service_config(name: &str, req: &TypeInfo, resp: &TypeInfo) -> ServiceConfig {
    let mut c =
        ServiceConfig::new(name, req.type_name, resp.type_name).keyed(req.keyed, resp.keyed);
    c.writer_qos = publication_qos(&PublicationQos::default());
    c.reader_qos = subscription_qos(&SubscriptionQos::default());
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
