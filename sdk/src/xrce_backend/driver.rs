//! The driver task: owns the [`Client`] machine and the link, reads the
//! mailbox, the link and the machine's timer, and answers the backend.
//!
//! Reconnection lives here. The machine reports [`Event::AgentLost`] after
//! [`XrceOptions::lost_after`] of silence (or when a ping is answered by an
//! agent that no longer knows the session) and goes on pinging; a TCP or
//! serial link that breaks is opened again every
//! [`XrceOptions::connect_interval`]. A TCP link whose agent went silent
//! (or did not answer a new session) while part of a record waits for the
//! rest is dropped and opened again too: the agent may be talking on it
//! still, but a bad length prefix has put its messages out of step for
//! good. A link with nothing part way is kept: the agent is only quiet. As soon as the agent answers without
//! the session (or the link is back), the driver creates the session again
//! ([`Client::connect`], repeated until it succeeds) and then every entity
//! and reading ([`Client::recreate_objects`], which also sends again the
//! reliable writes the agent had not acknowledged). Commands that need the
//! session wait meanwhile, in order, for at most [`XrceOptions::agent_wait`].

use std::collections::{HashMap, HashSet, VecDeque};
use std::sync::Arc;
use std::time::{Duration, Instant, SystemTime};

use courier_wire::ipc::ByteOrder;
use courier_wire::xrce::{
    Client, CommandError, CreationMode, DeliveryControl, Event, InputError, LostReason, ObjectId,
    ObjectKind, ObjectVariant, QueueError, RequestId, State, StatusCode, StreamError, StreamId,
};
use tokio::sync::{mpsc, oneshot};

use super::cmd::{Cmd, Reply};
use super::options::{RefKind, XrceCreation, XrceOptions, XrceRepresentation};
use super::repr;
use super::transport::Link;
use super::Shared;
use crate::backend::{ClientId, Handle, PubId, ServiceId, SubId, TimeSync, XrceState};
use crate::builder::ConnectError;
use crate::driver_timer::DriverTimer;
use crate::error::{OpenError, PublishError, QueryError};
use crate::event::SessionEvent;
use crate::hub::Hub;
use crate::mailbox::{Inbox, WeakMailbox};
use crate::qos::{Reliability, TypeInfo};
use crate::queue::{RawSample, SampleQueue};
use crate::reply::Responder;
use crate::session::{RawReply, RawRequest};

/// The CDR encapsulation header the agent strips from every sample it
/// hands a client and puts in front of every sample it writes (CDR_LE).
pub(super) const ENCAPSULATION: [u8; 4] = [0, 1, 0, 0];

/// A session's DELETE (at a close, or a connect given up) is sent this
/// many times, [`DELETE_INTERVAL`] apart, until the agent's STATUS: on a
/// link that loses a third of the datagrams, one DELETE in two did not
/// make the round trip, and the agent kept the session of a client that
/// was gone. A close waits at most 750 ms for an agent that does not answer.
pub(super) const DELETE_ATTEMPTS: u32 = 5;
/// See [`DELETE_ATTEMPTS`].
pub(super) const DELETE_INTERVAL: Duration = Duration::from_millis(150);

/// Prepends the encapsulation header to a body from the agent.
fn with_header(body: &[u8]) -> Vec<u8> {
    let mut v = Vec::with_capacity(body.len() + 4);
    v.extend_from_slice(&ENCAPSULATION);
    v.extend_from_slice(body);
    v
}

/// The body the agent wants: the CDR bytes without their 4-byte
/// encapsulation header.
fn body(data: &[u8]) -> &[u8] {
    data.get(4..).unwrap_or(&[])
}

struct Publication {
    writer: ObjectId,
    topic: Arc<str>,
    stream: StreamId,
}

struct Subscription {
    reader: ObjectId,
    topic: Arc<str>,
    type_name: Arc<str>,
    queue: Arc<SampleQueue>,
    reliable: bool,
    /// A keyed type's key hashes, for a keep-last queue: each sample is
    /// told to it by its instance (XRCE carries no key hash), so that it
    /// keeps the newest of each instance as on `rtps://`.
    instances: Option<courier_wire::dds::InstanceKeys>,
}

struct Service {
    replier: ObjectId,
    name: Arc<str>,
    tx: mpsc::Sender<RawRequest>,
}

struct Requester {
    requester: ObjectId,
    name: Arc<str>,
}

struct Topic {
    id: ObjectId,
    type_name: &'static str,
}

/// What an open waits for before it answers.
enum Opened {
    Publication(PubId, Reply<PubId, OpenError>),
    Subscription(SubId, Reply<SubId, OpenError>),
    Service(ServiceId, Reply<ServiceId, OpenError>),
    Client(ClientId, Reply<ClientId, OpenError>),
}

struct OpenWait {
    topic: String,
    /// When the open fails if the agent has not answered.
    deadline: Instant,
    remaining: usize,
    error: Option<OpenError>,
    /// The per-handle object to delete again if the open fails.
    own: ObjectId,
    done: Opened,
}

/// The driver's state (everything but the mailbox and the link, which the
/// loop borrows separately).
pub(super) struct Driver {
    pub(super) opts: XrceOptions,
    pub(super) name: String,
    pub(super) url: String,
    pub(super) client: Client,
    pub(super) hub: Hub<SessionEvent>,
    pub(super) shared: Arc<Shared>,
    pub(super) mailbox: WeakMailbox<Cmd>,
    pub(super) connected: Option<oneshot::Sender<Result<(), ConnectError>>>,

    participant: Option<ObjectId>,
    publisher: Option<ObjectId>,
    subscriber: Option<ObjectId>,
    topics: HashMap<String, Topic>,
    used_ids: HashSet<u16>,
    next_id: u16,
    next_handle: u64,
    /// What each object is, for errors: topic (or service) and entity.
    names: HashMap<ObjectId, (Arc<str>, &'static str)>,

    pubs: HashMap<PubId, Publication>,
    subs: HashMap<SubId, Subscription>,
    by_reader: HashMap<ObjectId, SubId>,
    services: HashMap<ServiceId, Service>,
    by_replier: HashMap<ObjectId, ServiceId>,
    requesters: HashMap<ClientId, Requester>,
    by_requester: HashMap<ObjectId, ClientId>,

    creates: HashMap<u16, u64>,
    opens: HashMap<u64, OpenWait>,
    next_open: u64,
    acks: HashMap<u16, Reply<(), PublishError>>,
    queries: HashMap<(ObjectId, u16), Reply<RawReply, QueryError>>,
    pings: Vec<Reply<Duration, crate::error::ControlError>>,
    syncs: Vec<Reply<TimeSync, crate::error::ControlError>>,
    /// Commands waiting for the session (or for room in its streams), in
    /// order, each with the time it gives up.
    parked: VecDeque<(Instant, Cmd)>,
    /// CREATEs of a re-created session still unanswered.
    recreating: HashSet<u16>,
    recreated: usize,
    /// Of those, the ones the agent refused.
    recreate_refused: usize,
    /// Objects the agent refused (when the session was re-created, or a
    /// write to one it does not have), with its status: writes through
    /// them fail instead of vanishing.
    refused: HashMap<ObjectId, StatusCode>,
    /// AgentLost was reported and neither AgentBack nor SessionRecreated yet.
    lost_reported: bool,
    /// While connecting the first time: the last message that came back
    /// for another session (session id or client key), which the connect
    /// error names.
    mismatch: Option<InputError>,
    /// The link broke; open it again at this time.
    pub(super) redial_at: Option<Instant>,
    /// Nothing came back on the link for a while: a stream link (TCP) is
    /// to be dropped and opened again, as its framing may be lost.
    pub(super) relink: bool,
    /// A full keep-all reliable subscription: the link is not read until
    /// it has room (back-pressure through the agent's reliable window).
    pub(super) stalled: Option<Arc<SampleQueue>>,
    /// The link reports that nothing listens at the agent's address
    /// (UDP: an ICMP "port unreachable" since the agent last spoke).
    pub(super) unreachable: bool,
    /// Closing: the session's DELETE is out (or waits for `draining`),
    /// stop at this time at the latest.
    pub(super) closing: Option<(Instant, oneshot::Sender<()>)>,
    /// Closing: the DELETE waits until the agent acknowledged what the
    /// reliable streams hold, or this time.
    pub(super) draining: Option<Instant>,
    pub(super) done: bool,
}

impl Drop for Driver {
    /// A driver task dropped before it ended (its runtime was shut down
    /// while the session's handles live on): their streams end and their
    /// waiting calls fail instead of waiting for ever.
    fn drop(&mut self) {
        if !self.done {
            self.finish();
        }
    }
}

fn entity_name(kind: ObjectKind) -> &'static str {
    match kind {
        ObjectKind::Participant => "participant",
        ObjectKind::Topic => "topic",
        ObjectKind::Publisher => "publisher",
        ObjectKind::Subscriber => "subscriber",
        ObjectKind::DataWriter => "data writer",
        ObjectKind::DataReader => "data reader",
        ObjectKind::Requester => "requester",
        ObjectKind::Replier => "replier",
        _ => "object",
    }
}

fn xrce_error(topic: &str, e: CommandError) -> PublishError {
    match e {
        CommandError::NotConnected => PublishError::Disconnected("the XRCE agent".into()),
        CommandError::Queue(QueueError::Stream(
            StreamError::TooLarge { len, max, .. } | StreamError::NeverFits { len, max, .. },
        )) => PublishError::TooLarge {
            msg: topic.to_string(),
            len,
            max,
        },
        source => PublishError::Xrce {
            topic: topic.to_string(),
            source,
        },
    }
}

/// What an agent's refusal usually means, where the status alone says
/// little (an XRCE STATUS carries no text; the agent's log has it).
fn refusal_hint(opts: &XrceOptions, object: ObjectId, topic: &str, status: StatusCode) -> String {
    let kind = object.kind().and_then(|k| match k {
        ObjectKind::Participant => Some(RefKind::Participant),
        ObjectKind::Topic => Some(RefKind::Topic),
        ObjectKind::DataWriter => Some(RefKind::DataWriter),
        ObjectKind::DataReader => Some(RefKind::DataReader),
        ObjectKind::Requester => Some(RefKind::Requester),
        ObjectKind::Replier => Some(RefKind::Replier),
        _ => None,
    });
    let by_reference = opts.representation == XrceRepresentation::Reference;
    match (kind, status) {
        (Some(RefKind::Participant), StatusCode::ERR_INCOMPATIBLE) => {
            " (is the session's domain= the agent's --domain? An agent takes participants of \
             its own domain only, unless started with --any-domain)"
                .into()
        }
        (Some(k), StatusCode::ERR_UNKNOWN_REFERENCE) if by_reference => format!(
            " (representation=reference: the agent's -r file has no {} profile named {:?}, \
             or it names something the agent refused)",
            k.name(),
            opts.profile(k, topic)
        ),
        (_, StatusCode::ERR_UNKNOWN_REFERENCE) => {
            " (it names an entity the agent does not have: refused or deleted)".into()
        }
        _ => String::new(),
    }
}

/// Whether a command error means "wait and try again".
fn must_wait(e: &CommandError) -> bool {
    matches!(
        e,
        CommandError::NotConnected
            | CommandError::TooManyRequests(_)
            | CommandError::Queue(QueueError::Stream(StreamError::Backlog { .. }))
    )
}

impl Driver {
    pub(super) fn new(
        opts: XrceOptions,
        name: String,
        client: Client,
        hub: Hub<SessionEvent>,
        shared: Arc<Shared>,
        mailbox: WeakMailbox<Cmd>,
        connected: oneshot::Sender<Result<(), ConnectError>>,
    ) -> Self {
        Driver {
            url: opts.transport.to_string(),
            opts,
            name,
            client,
            hub,
            shared,
            mailbox,
            connected: Some(connected),
            participant: None,
            publisher: None,
            subscriber: None,
            topics: HashMap::new(),
            used_ids: HashSet::new(),
            next_id: 1,
            next_handle: 1,
            names: HashMap::new(),
            pubs: HashMap::new(),
            subs: HashMap::new(),
            by_reader: HashMap::new(),
            services: HashMap::new(),
            by_replier: HashMap::new(),
            requesters: HashMap::new(),
            by_requester: HashMap::new(),
            creates: HashMap::new(),
            opens: HashMap::new(),
            next_open: 1,
            acks: HashMap::new(),
            queries: HashMap::new(),
            pings: Vec::new(),
            syncs: Vec::new(),
            parked: VecDeque::new(),
            recreating: HashSet::new(),
            recreated: 0,
            recreate_refused: 0,
            refused: HashMap::new(),
            lost_reported: false,
            mismatch: None,
            redial_at: None,
            relink: false,
            stalled: None,
            unreachable: false,
            closing: None,
            draining: None,
            done: false,
        }
    }

    fn mode(&self) -> CreationMode {
        match self.opts.creation {
            XrceCreation::Replace => CreationMode::REPLACE,
            XrceCreation::ReuseOrReplace => CreationMode::REUSE_OR_REPLACE,
            XrceCreation::Create => CreationMode::CREATE,
        }
    }

    fn in_session(&self) -> bool {
        matches!(self.client.state(), State::Connected | State::Lost)
    }

    fn alloc(&mut self, kind: ObjectKind) -> Option<ObjectId> {
        for _ in 0..0x1000 {
            let id = self.next_id;
            self.next_id = if id >= 0xFFF { 1 } else { id + 1 };
            if self.used_ids.insert(id) {
                return Some(ObjectId::new(id, kind));
            }
        }
        None
    }

    fn free(&mut self, o: ObjectId) {
        self.used_ids.remove(&o.id());
        self.names.remove(&o);
    }

    /// When the loop must wake up next for the driver's own sake.
    pub(super) fn next_wakeup(&self) -> Option<Instant> {
        let parked = self.parked.iter().map(|(t, _)| *t).min();
        let closing = self.closing.as_ref().map(|c| c.0);
        let closing = closing.into_iter().chain(self.draining).min();
        let opens = self.opens.values().map(|w| w.deadline).min();
        [
            self.client.poll_timeout(),
            parked,
            self.redial_at,
            closing,
            opens,
        ]
        .into_iter()
        .flatten()
        .min()
    }

    // -----------------------------------------------------------------
    // commands

    /// Runs `cmd`, or parks it (in order) while the session cannot take it.
    pub(super) fn command(&mut self, cmd: Cmd, now: Instant) {
        if self.done {
            cmd.closed();
            return;
        }
        if cmd.needs_session() && (!self.parked.is_empty() || !self.in_session()) {
            self.park(courier_wire::time::later(now, self.opts.agent_wait), cmd);
            return;
        }
        if let Err(cmd) = self.run(cmd, now) {
            self.park(courier_wire::time::later(now, self.opts.agent_wait), cmd);
        }
    }

    fn park(&mut self, until: Instant, cmd: Cmd) {
        self.parked.push_back((until, cmd));
    }

    /// Runs parked commands while the session takes them.
    fn unpark(&mut self, now: Instant) {
        while self.in_session() {
            let Some((until, cmd)) = self.parked.pop_front() else {
                break;
            };
            if let Err(cmd) = self.run(cmd, now) {
                self.parked.push_front((until, cmd));
                break;
            }
        }
    }

    /// Runs a command; gives it back if it has to wait.
    #[allow(clippy::result_large_err)] // handed straight back to be parked
    fn run(&mut self, cmd: Cmd, now: Instant) -> Result<(), Cmd> {
        match cmd {
            Cmd::Publication {
                topic,
                ty,
                qos,
                reply,
            } => {
                let stream = match qos.reliability {
                    Reliability::Reliable => StreamId::RELIABLE,
                    Reliability::BestEffort => StreamId::BEST_EFFORT,
                };
                let id = PubId(self.next_handle);
                let result = self.open_endpoint(&topic, &ty, true, now, |d, topic_id, parent| {
                    repr::writer(&d.opts, &topic, &ty, topic_id, &qos, parent)
                });
                match result {
                    Ok((writer, open)) => {
                        self.next_handle += 1;
                        self.pubs.insert(
                            id,
                            Publication {
                                writer,
                                topic: Arc::from(topic.as_str()),
                                stream,
                            },
                        );
                        self.finish_open(open, writer, Opened::Publication(id, reply));
                    }
                    Err(e) => {
                        let _ = reply.send(Err(e));
                    }
                }
                Ok(())
            }
            Cmd::Subscription {
                topic,
                ty,
                qos,
                queue,
                reply,
            } => {
                let ty = match ty.or_else(|| {
                    self.topics
                        .get(&topic)
                        .map(|t| TypeInfo::dynamic(None, t.type_name))
                }) {
                    Some(t) => t,
                    None => {
                        let _ = reply.send(Err(OpenError::Unsupported {
                            what: format!(
                                "a subscription of {topic} without its type (use \
                                 Session::subscribe::<T>)"
                            ),
                            backend: "xrce+…://",
                        }));
                        return Ok(());
                    }
                };
                let id = SubId(self.next_handle);
                let result = self.open_endpoint(&topic, &ty, false, now, |d, topic_id, parent| {
                    repr::reader(&d.opts, &topic, &ty, topic_id, &qos, parent)
                });
                match result {
                    Ok((reader, open)) => {
                        self.next_handle += 1;
                        let reliable = qos.reliability == Reliability::Reliable;
                        let preferred = if reliable {
                            StreamId::RELIABLE
                        } else {
                            StreamId::BEST_EFFORT
                        };
                        if let Err(e) = self.client.read(
                            reader,
                            StreamId::RELIABLE,
                            preferred,
                            Some(DeliveryControl {
                                max_samples: 0xFFFF,
                                ..DeliveryControl::default()
                            }),
                            now,
                        ) {
                            tracing::warn!("XRCE: READ_DATA of {topic} refused: {e}");
                        }
                        let instances = ty
                            .key_of
                            .filter(|_| queue.is_keep_last())
                            .map(|k| k.instances);
                        self.subs.insert(
                            id,
                            Subscription {
                                reader,
                                topic: Arc::from(topic.as_str()),
                                type_name: Arc::from(ty.type_name),
                                queue,
                                reliable,
                                instances,
                            },
                        );
                        self.by_reader.insert(reader, id);
                        self.finish_open(open, reader, Opened::Subscription(id, reply));
                    }
                    Err(e) => {
                        let _ = reply.send(Err(e));
                    }
                }
                Ok(())
            }
            Cmd::Service {
                name,
                req,
                resp,
                tx,
                reply,
            } => {
                if self.services.values().any(|s| *s.name == *name) {
                    let _ = reply.send(Err(OpenError::AlreadyServed(name)));
                    return Ok(());
                }
                let id = ServiceId(self.next_handle);
                match self.open_service(&name, &req, &resp, true, now) {
                    Ok((replier, open)) => {
                        self.next_handle += 1;
                        self.services.insert(
                            id,
                            Service {
                                replier,
                                name: Arc::from(name.as_str()),
                                tx,
                            },
                        );
                        self.by_replier.insert(replier, id);
                        self.finish_open(open, replier, Opened::Service(id, reply));
                    }
                    Err(e) => {
                        let _ = reply.send(Err(e));
                    }
                }
                Ok(())
            }
            Cmd::Client {
                name,
                req,
                resp,
                reply,
            } => {
                let id = ClientId(self.next_handle);
                match self.open_service(&name, &req, &resp, false, now) {
                    Ok((requester, open)) => {
                        self.next_handle += 1;
                        self.requesters.insert(
                            id,
                            Requester {
                                requester,
                                name: Arc::from(name.as_str()),
                            },
                        );
                        self.by_requester.insert(requester, id);
                        self.finish_open(open, requester, Opened::Client(id, reply));
                    }
                    Err(e) => {
                        let _ = reply.send(Err(e));
                    }
                }
                Ok(())
            }
            Cmd::Write {
                publication,
                data,
                confirm,
                reply,
            } => {
                let Some(p) = self.pubs.get(&publication) else {
                    let _ = reply.send(Err(PublishError::Closed(publication)));
                    return Ok(());
                };
                let (writer, stream, topic) = (p.writer, p.stream, p.topic.clone());
                if let Some(&status) = self.refused.get(&writer) {
                    let _ = reply.send(Err(PublishError::AgentRefused {
                        topic: topic.to_string(),
                        entity: "data writer",
                        status,
                    }));
                    return Ok(());
                }
                match self.client.write(writer, stream, body(&data), now) {
                    Ok(req) => {
                        if confirm && stream.is_reliable() {
                            self.acks.retain(|_, r| !r.is_closed());
                            self.acks.insert(req.0, reply);
                        } else {
                            let _ = reply.send(Ok(()));
                        }
                        Ok(())
                    }
                    Err(e) if must_wait(&e) => Err(Cmd::Write {
                        publication,
                        data,
                        confirm,
                        reply,
                    }),
                    Err(e) => {
                        let _ = reply.send(Err(xrce_error(&topic, e)));
                        Ok(())
                    }
                }
            }
            Cmd::Query {
                client,
                data,
                reply,
            } => {
                let Some(r) = self.requesters.get(&client) else {
                    let _ = reply.send(Err(QueryError::Disconnected(format!("{client:?}"))));
                    return Ok(());
                };
                let (requester, name) = (r.requester, r.name.clone());
                if let Some(&status) = self.refused.get(&requester) {
                    let _ = reply.send(Err(QueryError::Refused {
                        msg: name.to_string(),
                        source: PublishError::AgentRefused {
                            topic: name.to_string(),
                            entity: "requester",
                            status,
                        },
                    }));
                    return Ok(());
                }
                match self
                    .client
                    .request(requester, StreamId::RELIABLE, body(&data), now)
                {
                    Ok(req) => {
                        self.queries.retain(|_, r| !r.is_closed());
                        self.queries.insert((requester, req.0), reply);
                        Ok(())
                    }
                    Err(e) if must_wait(&e) => Err(Cmd::Query {
                        client,
                        data,
                        reply,
                    }),
                    Err(e) => {
                        let _ = reply.send(Err(QueryError::Refused {
                            msg: name.to_string(),
                            source: xrce_error(&name, e),
                        }));
                        Ok(())
                    }
                }
            }
            Cmd::Respond {
                service,
                identity,
                data,
            } => {
                let Some(s) = self.services.get(&service) else {
                    return Ok(());
                };
                let replier = s.replier;
                match self
                    .client
                    .reply(replier, StreamId::RELIABLE, &identity, body(&data), now)
                {
                    Ok(_) => Ok(()),
                    Err(e) if must_wait(&e) => Err(Cmd::Respond {
                        service,
                        identity,
                        data,
                    }),
                    Err(e) => {
                        tracing::warn!("XRCE: a reply is refused: {e}");
                        Ok(())
                    }
                }
            }
            Cmd::Ping { reply } => {
                self.client.ping(now);
                self.pings.retain(|r| !r.is_closed());
                self.pings.push(reply);
                Ok(())
            }
            Cmd::SyncTime { reply } => {
                match self.client.sync_time(now, SystemTime::now()) {
                    Ok(()) => {
                        self.syncs.retain(|r| !r.is_closed());
                        self.syncs.push(reply);
                    }
                    Err(_) => {
                        let _ = reply.send(Err(crate::error::ControlError::Disconnected(
                            "the XRCE agent (no session)".into(),
                        )));
                    }
                }
                Ok(())
            }
            Cmd::CloseHandle(h) => {
                let mut topic = None;
                let object = match h {
                    Handle::Publication(p) => self.pubs.remove(&p).map(|p| {
                        topic = Some(p.topic.clone());
                        p.writer
                    }),
                    Handle::Subscription(s) => self.subs.remove(&s).map(|s| {
                        topic = Some(s.topic.clone());
                        self.by_reader.remove(&s.reader);
                        if self
                            .stalled
                            .as_ref()
                            .is_some_and(|q| Arc::ptr_eq(q, &s.queue))
                        {
                            self.stalled = None;
                            self.client.set_deaf(false, Instant::now());
                        }
                        s.reader
                    }),
                    Handle::Service(s) => self.services.remove(&s).map(|s| {
                        self.by_replier.remove(&s.replier);
                        s.replier
                    }),
                    Handle::Client(c) => self.requesters.remove(&c).map(|r| {
                        self.by_requester.remove(&r.requester);
                        self.queries.retain(|(o, _), _| *o != r.requester);
                        r.requester
                    }),
                };
                if let Some(o) = object {
                    match self.client.delete(o, now) {
                        Ok(_) => self.free(o),
                        Err(e) if must_wait(&e) => {
                            // deleted once the session takes it
                            self.restore_for_delete(h, o);
                            return Err(Cmd::CloseHandle(h));
                        }
                        Err(e) => tracing::debug!("XRCE: DELETE refused: {e}"),
                    }
                }
                if let Some(t) = topic {
                    self.drop_unused_topic(&t, now);
                }
                Ok(())
            }
            Cmd::Close { reply } => {
                self.begin_close(now, reply);
                Ok(())
            }
        }
    }

    /// Deletes the topic object of `topic` once no publication or
    /// subscription of the session uses it: its id is free again (a
    /// session that went through thousands of topics ran out of the 4095
    /// ids XRCE has for objects) and the agent forgets it.
    fn drop_unused_topic(&mut self, topic: &str, now: Instant) {
        let used = self.pubs.values().any(|p| &*p.topic == topic)
            || self.subs.values().any(|s| &*s.topic == topic);
        if used {
            return;
        }
        let Some(t) = self.topics.get(topic) else {
            return;
        };
        let id = t.id;
        if self.client.delete(id, now).is_ok() {
            self.topics.remove(topic);
            self.free(id);
        }
    }

    /// A close that has to wait: keep a placeholder so that the retry finds
    /// the object again.
    fn restore_for_delete(&mut self, h: Handle, o: ObjectId) {
        let topic: Arc<str> = Arc::from("");
        match h {
            Handle::Publication(p) => {
                self.pubs.insert(
                    p,
                    Publication {
                        writer: o,
                        topic,
                        stream: StreamId::RELIABLE,
                    },
                );
            }
            Handle::Subscription(s) => {
                self.subs.insert(
                    s,
                    Subscription {
                        reader: o,
                        topic: topic.clone(),
                        type_name: topic,
                        queue: SampleQueue::new(crate::queue::QueuePolicy::KeepLast(1)),
                        reliable: false,
                        instances: None,
                    },
                );
            }
            Handle::Service(s) => {
                let (tx, _) = mpsc::channel(1);
                self.services.insert(
                    s,
                    Service {
                        replier: o,
                        name: topic,
                        tx,
                    },
                );
            }
            Handle::Client(c) => {
                self.requesters.insert(
                    c,
                    Requester {
                        requester: o,
                        name: topic,
                    },
                );
            }
        }
    }

    fn create(
        &mut self,
        id: ObjectId,
        variant: ObjectVariant,
        what: (&Arc<str>, &'static str),
        now: Instant,
        requests: &mut Vec<u16>,
    ) -> Result<(), OpenError> {
        let mode = self.mode();
        match self.client.create(id, variant, mode, now) {
            Ok(r) => {
                self.names.insert(id, (what.0.clone(), what.1));
                requests.push(r.0);
                Ok(())
            }
            Err(e) => Err(OpenError::Unsupported {
                what: format!("creating the {} of {} ({e})", what.1, what.0),
                backend: "xrce+…://",
            }),
        }
    }

    fn ensure_participant(
        &mut self,
        now: Instant,
        requests: &mut Vec<u16>,
    ) -> Result<ObjectId, OpenError> {
        if let Some(p) = self.participant {
            return Ok(p);
        }
        let id = self.alloc(ObjectKind::Participant).ok_or_else(full)?;
        let v = repr::participant(&self.opts, &self.name)?;
        let name: Arc<str> = Arc::from(self.name.as_str());
        self.create(id, v, (&name, "participant"), now, requests)?;
        self.participant = Some(id);
        Ok(id)
    }

    fn ensure_group(
        &mut self,
        publisher: bool,
        participant: ObjectId,
        now: Instant,
        requests: &mut Vec<u16>,
    ) -> Result<ObjectId, OpenError> {
        let have = if publisher {
            self.publisher
        } else {
            self.subscriber
        };
        if let Some(g) = have {
            return Ok(g);
        }
        let kind = if publisher {
            ObjectKind::Publisher
        } else {
            ObjectKind::Subscriber
        };
        let id = self.alloc(kind).ok_or_else(full)?;
        let v = repr::group(&self.opts, publisher, participant)?;
        let name: Arc<str> = Arc::from(self.name.as_str());
        self.create(id, v, (&name, entity_name(kind)), now, requests)?;
        if publisher {
            self.publisher = Some(id);
        } else {
            self.subscriber = Some(id);
        }
        Ok(id)
    }

    /// Participant, topic, publisher or subscriber as needed, then the
    /// endpoint `make` describes; the endpoint and the requests to wait for.
    fn open_endpoint(
        &mut self,
        topic: &str,
        ty: &TypeInfo,
        publisher: bool,
        now: Instant,
        make: impl Fn(&Driver, ObjectId, ObjectId) -> Result<ObjectVariant, OpenError>,
    ) -> Result<(ObjectId, Vec<u16>), OpenError> {
        // what the endpoint cannot be (its QoS, say) is refused before its
        // topic and group go to the agent: made with stand-in ids first
        make(self, ObjectId::INVALID, ObjectId::INVALID)?;
        if let Some(t) = self.topics.get(topic) {
            if t.type_name != ty.type_name {
                return Err(OpenError::TypeConflict {
                    msg: topic.to_string(),
                    existing: t.type_name.to_string(),
                    given: ty.type_name.to_string(),
                });
            }
        }
        let mut requests = Vec::new();
        let participant = self.ensure_participant(now, &mut requests)?;
        let topic_id = match self.topics.get(topic) {
            Some(t) => t.id,
            None => {
                let id = self.alloc(ObjectKind::Topic).ok_or_else(full)?;
                let v = repr::topic(&self.opts, topic, ty, participant)?;
                let name: Arc<str> = Arc::from(topic);
                if let Err(e) = self.create(id, v, (&name, "topic"), now, &mut requests) {
                    self.free(id);
                    return Err(e);
                }
                self.topics.insert(
                    topic.to_string(),
                    Topic {
                        id,
                        type_name: ty.type_name,
                    },
                );
                id
            }
        };
        let group = self.ensure_group(publisher, participant, now, &mut requests)?;
        let kind = if publisher {
            ObjectKind::DataWriter
        } else {
            ObjectKind::DataReader
        };
        let variant = make(self, topic_id, group)?;
        let id = self.alloc(kind).ok_or_else(full)?;
        let name: Arc<str> = Arc::from(topic);
        if let Err(e) = self.create(id, variant, (&name, entity_name(kind)), now, &mut requests) {
            self.free(id);
            return Err(e);
        }
        Ok((id, requests))
    }

    fn open_service(
        &mut self,
        name: &str,
        req: &TypeInfo,
        resp: &TypeInfo,
        replier: bool,
        now: Instant,
    ) -> Result<(ObjectId, Vec<u16>), OpenError> {
        if req.is_untyped() || resp.is_untyped() {
            return Err(OpenError::Unsupported {
                what: format!(
                    "{} {name} without its types (use Session::query / Session::serve)",
                    if replier { "serving" } else { "querying" }
                ),
                backend: "xrce+…://",
            });
        }
        let mut requests = Vec::new();
        let participant = self.ensure_participant(now, &mut requests)?;
        let kind = if replier {
            ObjectKind::Replier
        } else {
            ObjectKind::Requester
        };
        let v = repr::service(&self.opts, name, req, resp, replier, participant)?;
        let id = self.alloc(kind).ok_or_else(full)?;
        let n: Arc<str> = Arc::from(name);
        if let Err(e) = self.create(id, v, (&n, entity_name(kind)), now, &mut requests) {
            self.free(id);
            return Err(e);
        }
        if let Err(e) = self.client.read(
            id,
            StreamId::RELIABLE,
            StreamId::RELIABLE,
            Some(DeliveryControl {
                max_samples: 0xFFFF,
                ..DeliveryControl::default()
            }),
            now,
        ) {
            tracing::warn!("XRCE: READ_DATA of {name} refused: {e}");
        }
        Ok((id, requests))
    }

    fn finish_open(&mut self, requests: Vec<u16>, own: ObjectId, done: Opened) {
        let topic = self
            .names
            .get(&own)
            .map(|n| n.0.to_string())
            .unwrap_or_default();
        let key = self.next_open;
        self.next_open += 1;
        for r in &requests {
            self.creates.insert(*r, key);
        }
        let wait = OpenWait {
            deadline: courier_wire::time::later(Instant::now(), self.opts.agent_wait),
            topic,
            remaining: requests.len(),
            error: None,
            own,
            done,
        };
        if requests.is_empty() {
            self.complete(wait, Instant::now());
        } else {
            self.opens.insert(key, wait);
        }
    }

    fn complete(&mut self, w: OpenWait, now: Instant) {
        match w.error {
            None => match w.done {
                Opened::Publication(id, r) => {
                    if r.send(Ok(id)).is_err() {
                        let _ = self.run(Cmd::CloseHandle(Handle::Publication(id)), now);
                    }
                }
                Opened::Subscription(id, r) => {
                    if r.send(Ok(id)).is_err() {
                        let _ = self.run(Cmd::CloseHandle(Handle::Subscription(id)), now);
                    }
                }
                Opened::Service(id, r) => {
                    if r.send(Ok(id)).is_err() {
                        let _ = self.run(Cmd::CloseHandle(Handle::Service(id)), now);
                    }
                }
                Opened::Client(id, r) => {
                    if r.send(Ok(id)).is_err() {
                        let _ = self.run(Cmd::CloseHandle(Handle::Client(id)), now);
                    }
                }
            },
            Some(e) => {
                let h = match w.done {
                    Opened::Publication(id, r) => {
                        let _ = r.send(Err(e));
                        Handle::Publication(id)
                    }
                    Opened::Subscription(id, r) => {
                        let _ = r.send(Err(e));
                        Handle::Subscription(id)
                    }
                    Opened::Service(id, r) => {
                        let _ = r.send(Err(e));
                        Handle::Service(id)
                    }
                    Opened::Client(id, r) => {
                        let _ = r.send(Err(e));
                        Handle::Client(id)
                    }
                };
                // the endpoint itself may exist: delete it
                let _ = self.run(Cmd::CloseHandle(h), now);
                let _ = w.own;
            }
        }
    }

    fn begin_close(&mut self, now: Instant, reply: oneshot::Sender<()>) {
        if self.closing.is_some() || self.done {
            let _ = reply.send(());
            return;
        }
        // a full subscription no longer holds the link: the agent's
        // acknowledgements (and the DELETE's STATUS) must be read
        if self.stalled.take().is_some() {
            self.client.set_deaf(false, now);
        }
        if self.client.state() == State::Connected
            && !self.client.is_idle()
            && !self.opts.linger.is_zero()
        {
            // what the reliable streams hold goes out first: deleted with
            // the session, a write whose publish returned would be lost
            let until = courier_wire::time::later(now, self.opts.linger);
            self.draining = Some(until);
            self.closing = Some((until, reply));
            return;
        }
        let end = self.delete_session(now);
        self.closing = Some((end, reply));
    }

    /// A draining close goes on once the reliable streams are acknowledged
    /// or its linger is over (called every turn of the loop).
    pub(super) fn drained(&mut self, now: Instant) {
        let Some(until) = self.draining else { return };
        // (a lost agent acknowledges nothing: no use waiting)
        if self.client.state() == State::Connected && !self.client.is_idle() && now < until {
            return;
        }
        self.draining = None;
        let end = self.delete_session(now);
        if let Some(c) = &mut self.closing {
            c.0 = end;
        }
    }

    /// The close's DELETE goes out (if there is a session); what the agent
    /// has not acknowledged is reported. Returns when the close stops
    /// waiting for the agent's answer.
    fn delete_session(&mut self, now: Instant) -> Instant {
        let unacked = self.acks.len();
        if unacked > 0 {
            tracing::warn!("XRCE session closes with {unacked} confirmed write(s) unacknowledged");
        } else if self.in_session() && !self.client.is_idle() {
            tracing::warn!(
                "XRCE session closes with writes the agent has not acknowledged (linger_ms={})",
                self.opts.linger.as_millis()
            );
        }
        // (while connecting too: the agent may have made the session)
        let may_have_session =
            self.in_session() || matches!(self.client.state(), State::Connecting { .. });
        if may_have_session && self.client.disconnect(now).is_ok() {
            // (the client says when it gave up: this is a backstop)
            now + DELETE_INTERVAL * (DELETE_ATTEMPTS + 1)
        } else {
            now
        }
    }

    /// Ends the session: every waiting caller fails, every queue closes.
    pub(super) fn finish(&mut self) {
        self.done = true;
        self.shared.set_state(XrceState::Closed);
        for (_, c) in self.parked.drain(..) {
            c.closed();
        }
        for (_, w) in self.opens.drain() {
            let e = OpenError::Disconnected("the XRCE agent (session closed)".into());
            match w.done {
                Opened::Publication(_, r) => drop(r.send(Err(e))),
                Opened::Subscription(_, r) => drop(r.send(Err(e))),
                Opened::Service(_, r) => drop(r.send(Err(e))),
                Opened::Client(_, r) => drop(r.send(Err(e))),
            }
        }
        for (_, r) in self.acks.drain() {
            let _ = r.send(Err(PublishError::Disconnected(
                "the XRCE agent (session closed before it acknowledged)".into(),
            )));
        }
        for (_, r) in self.queries.drain() {
            let _ = r.send(Err(QueryError::Disconnected("the XRCE agent".into())));
        }
        for s in self.subs.values() {
            s.queue.close();
        }
        self.subs.clear();
        self.services.clear();
        self.pings.clear();
        self.syncs.clear();
        if let Some((_, r)) = self.closing.take() {
            let _ = r.send(());
        }
        if let Some(c) = self.connected.take() {
            let _ = c.send(Err(ConnectError::Agent {
                url: self.url.clone(),
                why: "the session was closed while connecting".into(),
            }));
        }
        self.hub.send(SessionEvent::Disconnected);
        self.hub.close();
    }

    // -----------------------------------------------------------------
    // time

    /// Time passed: the machine's timers, parked commands that give up,
    /// the end of a close.
    pub(super) fn on_timer(&mut self, now: Instant) {
        self.client.handle_timeout(now);
        while self.parked.front().is_some_and(|(t, _)| *t <= now) {
            if let Some((_, c)) = self.parked.pop_front() {
                c.expire(self.opts.agent_wait);
            }
        }
        let late: Vec<u64> = self
            .opens
            .iter()
            .filter(|(_, w)| w.deadline <= now)
            .map(|(k, _)| *k)
            .collect();
        for k in late {
            if let Some(mut w) = self.opens.remove(&k) {
                self.creates.retain(|_, o| *o != k);
                w.error = Some(OpenError::NoAnswer {
                    topic: w.topic.clone(),
                    after: self.opts.agent_wait,
                });
                self.complete(w, now);
            }
        }
        self.drained(now);
        if self.closing.as_ref().is_some_and(|c| c.0 <= now) {
            self.finish();
        }
    }

    /// The link broke (TCP closed, tty gone).
    pub(super) fn link_down(&mut self, now: Instant, why: &std::io::Error) {
        tracing::info!("XRCE link to {} lost: {why}", self.url);
        self.redial_at = Some(courier_wire::time::later(now, self.opts.connect_interval));
        if !self.lost_reported && self.connected.is_none() {
            self.lost_reported = true;
            self.shared.set_state(XrceState::Lost);
            self.hub.send(SessionEvent::AgentLost { silent: true });
        }
    }

    /// The link is open again: create the session anew on it.
    pub(super) fn link_up(&mut self, now: Instant) {
        self.redial_at = None;
        self.client.connect(now);
    }

    /// A message from the agent the machine could not use. (A sample too
    /// large is an event of its own: [`Event::TooLarge`].)
    pub(super) fn input_error(&mut self, e: InputError) {
        tracing::debug!("XRCE input: {e}");
        if self.connected.is_some()
            && matches!(
                e,
                InputError::WrongSession { .. } | InputError::WrongClientKey { .. }
            )
        {
            self.mismatch = Some(e);
        }
    }

    // -----------------------------------------------------------------
    // the machine's events

    pub(super) fn events(&mut self, now: Instant) {
        while let Some(e) = self.client.poll_event() {
            self.event(e, now);
        }
    }

    fn event(&mut self, e: Event, now: Instant) {
        match e {
            Event::TooLarge { object, max } => {
                // a sample lost: counted in its subscription's `dropped()`
                // and said (at most once per `max` bytes from the agent)
                let sub = object
                    .and_then(|o| self.by_reader.get(&o))
                    .and_then(|id| self.subs.get(id));
                match sub {
                    Some(s) => {
                        s.queue.count_dropped();
                        tracing::warn!(
                            topic = %s.topic,
                            "gave up a sample from the XRCE agent: its fragments add up to \
                             more than the {max} bytes this session takes"
                        );
                    }
                    None => tracing::warn!(
                        "gave up a submessage from the XRCE agent: its fragments add up to \
                         more than the {max} bytes this session takes"
                    ),
                }
            }
            Event::Connected { .. } => {
                self.shared.set_state(XrceState::Connected);
                if let Some(c) = self.connected.take() {
                    // the first session: `connect().await` returns
                    let _ = c.send(Ok(()));
                } else {
                    match self.client.recreate_objects(now) {
                        Ok(ids) => {
                            self.recreated = ids.len();
                            self.recreate_refused = 0;
                            self.recreating = ids.into_iter().map(|r| r.0).collect();
                            if self.recreating.is_empty() {
                                self.recreated_all();
                            }
                        }
                        Err(e) => tracing::warn!("XRCE: re-creating the entities failed: {e}"),
                    }
                }
                self.unpark(now);
            }
            Event::ConnectFailed(e) => {
                if let Some(c) = self.connected.take() {
                    let mut why = e.to_string();
                    if let Some(m) = self.mismatch.take() {
                        why.push_str(&format!(
                            "; what came back was for another session: {m} (is it this \
                             session's agent, and are `session=` and `key=` right?)"
                        ));
                    }
                    if self.unreachable {
                        why.push_str(
                            "; nothing listens on that UDP port (the host answered \"port \
                             unreachable\"): is the agent running, on this port?",
                        );
                    }
                    let _ = c.send(Err(ConnectError::Agent {
                        url: self.url.clone(),
                        why,
                    }));
                    self.done = true;
                } else {
                    // keep trying until the agent is back (on a new link,
                    // if it is a stream)
                    tracing::debug!("XRCE: {e}; trying again");
                    self.relink = true;
                    self.client.connect(now);
                }
            }
            Event::Status {
                request,
                object,
                result,
            } => self.status(request, object, result, now),
            Event::Data { reader, data, .. } => self.data(reader, data),
            Event::Request {
                replier,
                identity,
                data,
                ..
            } => {
                let Some(s) = self
                    .by_replier
                    .get(&replier)
                    .and_then(|id| self.services.get(id))
                else {
                    return;
                };
                let service = self.by_replier[&replier];
                let mailbox = self.mailbox.clone();
                let respond = Responder::from_fn(move |_, data| {
                    let m = mailbox.upgrade().ok_or_else(|| {
                        PublishError::Disconnected("the XRCE agent (session closed)".into())
                    })?;
                    // one reply per request, and requests are bounded by
                    // the service's channel
                    m.post(Cmd::Respond {
                        service,
                        identity,
                        data,
                    })
                    .map_err(|_| PublishError::Disconnected("the XRCE agent".into()))
                });
                let req = RawRequest {
                    msg: s.name.to_string(),
                    data: with_header(&data),
                    order: ByteOrder::Little,
                    format: None,
                    respond,
                };
                if let Err(e) = s.tx.try_send(req) {
                    if matches!(e, mpsc::error::TrySendError::Full(_)) {
                        tracing::warn!(
                            "XRCE: a request of {} is declined: its server's queue is full",
                            s.name
                        );
                    }
                }
            }
            Event::Reply {
                requester,
                request,
                data,
            } => {
                if let Some(r) = self.queries.remove(&(requester, request.0)) {
                    let name = self
                        .by_requester
                        .get(&requester)
                        .and_then(|c| self.requesters.get(c))
                        .map(|r| r.name.to_string())
                        .unwrap_or_default();
                    let _ = r.send(Ok((name, with_header(&data), ByteOrder::Little)));
                }
            }
            Event::WriteAcked(req) => {
                if let Some(r) = self.acks.remove(&req.0) {
                    let _ = r.send(Ok(()));
                }
                if !self.parked.is_empty() {
                    self.unpark(now);
                }
            }
            Event::Pong { in_session, rtt } => {
                if in_session {
                    let rtt = rtt.unwrap_or_default();
                    for p in self.pings.drain(..) {
                        let _ = p.send(Ok(rtt));
                    }
                } else if self.client.state() == State::Lost {
                    // the agent is back but has forgotten the session
                    self.client.connect(now);
                } else if !self.in_session() && !self.pings.is_empty() {
                    let rtt = rtt.unwrap_or_default();
                    for p in self.pings.drain(..) {
                        let _ = p.send(Ok(rtt));
                    }
                }
            }
            Event::TimeSynced { offset_ns, rtt } => {
                let t = TimeSync { offset_ns, rtt };
                self.shared.set_sync(t);
                for s in self.syncs.drain(..) {
                    let _ = s.send(Ok(t));
                }
            }
            Event::AgentLost(reason) => {
                self.shared.set_state(XrceState::Lost);
                if !self.lost_reported {
                    self.lost_reported = true;
                    self.hub.send(SessionEvent::AgentLost {
                        silent: reason == LostReason::Silent,
                    });
                }
                match reason {
                    LostReason::SessionUnknown => self.client.connect(now),
                    // silent: a TCP link out of step is dialled again (a
                    // session that does not read its link is never
                    // reported silent)
                    _ => self.relink = true,
                }
            }
            Event::AgentBack => {
                self.shared.set_state(XrceState::Connected);
                if self.lost_reported {
                    self.lost_reported = false;
                    self.hub.send(SessionEvent::AgentBack);
                }
                self.unpark(now);
            }
            Event::SessionDeleted { .. } if self.closing.is_some() => self.finish(),
            _ => {}
        }
    }

    fn recreated_all(&mut self) {
        self.shared.set_state(XrceState::Connected);
        self.lost_reported = false;
        self.hub.send(SessionEvent::SessionRecreated {
            entities: self.recreated - self.recreate_refused.min(self.recreated),
        });
    }

    fn status(
        &mut self,
        request: RequestId,
        object: ObjectId,
        result: Result<StatusCode, courier_wire::xrce::StatusError>,
        now: Instant,
    ) {
        let (topic, entity) = self
            .names
            .get(&object)
            .map(|(t, e)| (t.to_string(), *e))
            .unwrap_or_else(|| (String::new(), object.kind().map_or("object", entity_name)));
        match result {
            Err(e) => {
                self.refused.insert(object, e.0);
                if self.recreating.contains(&request.0) {
                    self.recreate_refused += 1;
                }
                // a confirmed write the agent refused
                if let Some(r) = self.acks.remove(&request.0) {
                    let _ = r.send(Err(PublishError::AgentRefused {
                        topic: topic.clone(),
                        entity,
                        status: e.0,
                    }));
                }
            }
            Ok(_) => {
                self.refused.remove(&object);
            }
        }
        if let Err(e) = result {
            // a shared object that failed is made again by the next open
            if self.participant == Some(object) {
                self.participant = None;
            }
            if self.publisher == Some(object) {
                self.publisher = None;
            }
            if self.subscriber == Some(object) {
                self.subscriber = None;
            }
            self.topics.retain(|_, t| t.id != object);
            if !self.names.contains_key(&object) {
                // an object this session let go (the DELETE of an entity
                // the agent never had, after a refused open): no news
                tracing::debug!("XRCE: {entity} {object:?} gone: {}", e.0);
            } else if !self.creates.contains_key(&request.0) {
                self.hub.send(SessionEvent::EntityError {
                    topic: topic.clone(),
                    entity,
                    status: e.0,
                });
            }
        }
        if self.recreating.remove(&request.0) && self.recreating.is_empty() {
            self.recreated_all();
        }
        let Some(key) = self.creates.remove(&request.0) else {
            return;
        };
        let Some(w) = self.opens.get_mut(&key) else {
            return;
        };
        w.remaining = w.remaining.saturating_sub(1);
        if let Err(e) = result {
            if w.error.is_none() {
                w.error = Some(OpenError::Refused {
                    topic: if topic.is_empty() {
                        w.topic.clone()
                    } else {
                        topic
                    },
                    entity,
                    status: e.0,
                    hint: refusal_hint(&self.opts, object, &w.topic, e.0),
                });
            }
        }
        if w.remaining == 0 {
            if let Some(w) = self.opens.remove(&key) {
                self.complete(w, now);
            }
        }
    }

    fn data(&mut self, reader: ObjectId, data: Vec<u8>) {
        let Some(s) = self.by_reader.get(&reader).and_then(|id| self.subs.get(id)) else {
            return;
        };
        let mut sample = RawSample::new(&*s.topic, with_header(&data));
        sample.order = ByteOrder::Little;
        sample.type_name = Some(s.type_name.clone());
        if let Some(k) = s.instances {
            sample.key_hash = (k.hash_in)(&sample.data, false, courier_wire::cdr::Version::Xcdr1);
        }
        match s.queue.push(sample) {
            Ok(()) => {}
            // (closing: nobody will read it; the link must stay read)
            Err(back) if s.reliable && self.closing.is_none() => {
                // keep it, and read no more until the subscriber makes room
                // (every subscription of the session waits: say so)
                s.queue.push_over(back);
                tracing::warn!(
                    "the queue of a subscription of {} is full: this session reads nothing \
                     more until it is read",
                    s.topic
                );
                self.hub.send(SessionEvent::SubscriberFull {
                    msg: s.topic.to_string(),
                    queued: s.queue.len(),
                });
                self.stalled = Some(s.queue.clone());
                // the link is not read meanwhile: its silence is not the agent's
                self.client.set_deaf(true, Instant::now());
            }
            Err(_) => s.queue.count_dropped(),
        }
        if s.queue.has_handler() {
            // (a `close()` there cannot wait: see XrceBackend::close)
            crate::in_callback::running(Arc::as_ptr(&self.shared) as usize, || {
                s.queue.run_handler();
            });
        }
    }
}

fn full() -> OpenError {
    OpenError::Unsupported {
        what: "more than 4095 XRCE entities in one session".into(),
        backend: "xrce+…://",
    }
}

/// The loop: transmits, events, then waits for a command, a message from
/// the agent or a timer.
pub(super) async fn run(mut d: Driver, mut inbox: Inbox<Cmd>, mut link: Option<Link>) {
    let mut buf = vec![0u8; 65_536];
    // every sender is gone: nothing more to read (the close is under way)
    let mut orphaned = false;
    let now = Instant::now();
    d.client.connect(now);
    // One timer for the whole loop, moved when the next wake-up moves.
    let mut timer = DriverTimer::quiet();
    loop {
        let now = Instant::now();
        d.unreachable = link.as_ref().is_some_and(Link::unreachable);
        d.events(now);
        if std::mem::take(&mut d.relink) && link.as_ref().is_some_and(Link::mid_record) {
            // a TCP agent that said nothing usable while bytes wait for the
            // rest of a record is talking out of step (one bad length
            // prefix swallows what follows): only a new connection
            // recovers. One merely quiet (nothing part way) keeps its link
            // and session, and what the agent still has for it.
            link = None;
            d.link_down(
                now,
                &std::io::Error::new(
                    std::io::ErrorKind::TimedOut,
                    "nothing usable came back on it; connecting again",
                ),
            );
        }
        d.drained(now);
        // transmit what the machine has
        while let Some(m) = d.client.poll_transmit() {
            let Some(l) = link.as_mut() else {
                continue; // dropped: the machine repeats what matters
            };
            if let Err(e) = l.send(&m).await {
                if l.is_stream() || e.kind() != std::io::ErrorKind::WouldBlock {
                    link = None;
                    d.link_down(Instant::now(), &e);
                }
            }
        }
        if d.done {
            break;
        }
        timer.set_next(d.next_wakeup());
        let stalled = d.stalled.clone();
        let readable = link.is_some() && stalled.is_none();
        tokio::select! {
            biased;
            cmd = inbox.recv(), if !orphaned => match cmd {
                Some(c) => {
                    d.command(c, Instant::now());
                    // take what else is queued before transmitting
                    while let Ok(c) = inbox.try_recv() {
                        d.command(c, Instant::now());
                        if d.done { break; }
                    }
                }
                None => {
                    orphaned = true;
                    let (tx, _rx) = oneshot::channel();
                    d.command(Cmd::Close { reply: tx }, Instant::now());
                    if d.closing.as_ref().is_some_and(|c| c.0 <= Instant::now()) {
                        d.finish();
                    }
                }
            },
            r = async {
                match link.as_mut() {
                    Some(l) => l.recv(&mut buf).await,
                    None => std::future::pending().await,
                }
            }, if readable => match r {
                Ok(m) => {
                    let now = Instant::now();
                    if let Err(e) = d.client.handle_input(&m, now) {
                        d.input_error(e);
                    }
                }
                Err(e) => {
                    link = None;
                    d.link_down(Instant::now(), &e);
                }
            },
            _ = async {
                match &stalled {
                    Some(q) => q.space().await,
                    None => std::future::pending().await,
                }
            }, if stalled.is_some() => {
                if stalled.as_ref().is_some_and(|q| !q.is_full() || q.is_receiver_gone()) {
                    d.stalled = None;
                    d.client.set_deaf(false, Instant::now());
                }
            },
            () = std::future::poll_fn(|cx| timer.poll_fired(cx)) => {
                let now = Instant::now();
                if d.redial_at.is_some_and(|t| t <= now) {
                    let dial = Link::open(&d.opts.transport, usize::from(d.opts.mtu));
                    match tokio::time::timeout(d.opts.connect_interval, dial).await {
                        Ok(Ok(l)) => {
                            link = Some(l);
                            d.link_up(Instant::now());
                        }
                        _ => {
                            let next = courier_wire::time::later(Instant::now(), d.opts.connect_interval);
                            d.redial_at = Some(next);
                        }
                    }
                }
                d.on_timer(Instant::now());
            },
        }
    }
    if !d.done {
        d.finish();
    }
    inbox.close();
    while let Ok(c) = inbox.try_recv() {
        c.closed();
    }
}
