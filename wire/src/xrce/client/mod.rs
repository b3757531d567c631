//! The DDS-XRCE client session, sans-I/O (`protocols/xrce.md` §2, §5–§11),
//! behaving on the wire as eProsima Micro XRCE-DDS Client 2.3.0 does.
//!
//! Inputs: [`Client::handle_input`] (one received message) and
//! [`Client::handle_timeout`]; commands ([`Client::connect`],
//! [`Client::create`], [`Client::write`], [`Client::read`], …) return
//! request ids at once and queue submessages; outputs:
//! [`Client::poll_transmit`] (messages for the agent, in order),
//! [`Client::poll_event`] and [`Client::poll_timeout`]. The machine never
//! reads a clock: every input carries `now`, and [`Client::sync_time`]
//! takes the wall-clock time it stamps.
//!
//! Submessages queued between two calls of `poll_transmit` share messages
//! while they fit, as the eProsima client's do between two flushes.
//!
//! ```
//! use std::time::Instant;
//! use courier_wire::xrce::{Client, ClientConfig, Event};
//! let now = Instant::now();
//! let mut c = Client::new(ClientConfig::new(0xCCCC_DDDD));
//! c.connect(now);
//! // CREATE_CLIENT, as `udp_xml_reliable_pubsub` #1
//! assert_eq!(c.poll_transmit().unwrap()[..8], [0x80, 0, 0, 0, 0x00, 0x01, 0x10, 0]);
//! // the agent's STATUS_AGENT (#2)
//! let status_agent = [0x81, 0, 0, 0, 4, 1, 11, 0, 0, 0, b'X', b'R', b'C', b'E', 1, 0, 1, 0x0F, 0];
//! c.handle_input(&status_agent, now).unwrap();
//! assert!(matches!(c.poll_event(), Some(Event::Connected { .. })));
//! ```
//!
//! # Re-creating a session
//! The client keeps the definition of every object it created, the
//! READ_DATA of every reader that is still reading and every reliable
//! write the agent has not acknowledged. After the agent is lost
//! ([`Event::AgentLost`]), call [`Client::connect`] again and, once
//! [`Event::Connected`] comes, [`Client::recreate_objects`]: it creates
//! every object again (with REUSE|REPLACE, so an agent that kept them
//! answers `OK_MATCHED`), repeats pending DELETEs and READ_DATAs under
//! their request ids, then resends the unacknowledged writes (which the
//! agent may therefore see twice).

use std::collections::{BTreeMap, VecDeque};
use std::time::{Instant, SystemTime, UNIX_EPOCH};

use super::message::MessageHeader;
use super::object::{AgentRepresentation, ClientRepresentation, ObjectVariant};
use super::session::{single, QueueError, Streams};
use super::stream::StreamError;
use super::submessage::{
    flags, Create, Data, DeliveryControl, GetInfo, Payload, ReadData, Submessage,
};
use super::types::{BaseObjectRequest, ObjectId, ObjectKind, RequestId, StreamId, Time};

mod input;
mod types;

pub use types::{
    ClientConfig, CommandError, ConnectError, CreationMode, Event, Keepalive, LostReason,
    ObjectDef, SampleIdentity, State, StatusError,
};

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum PendingKind {
    Create,
    Delete,
}

#[derive(Debug, Clone)]
struct ReadDef {
    request: u16,
    stream: StreamId,
    read: ReadData,
}

/// Reliable writes the agent has not acknowledged, kept to be sent again
/// in a new session: in order, and by request id.
#[derive(Debug, Clone, Default)]
struct Unconfirmed {
    writes: BTreeMap<u64, (u16, StreamId, Vec<u8>)>,
    ids: BTreeMap<u16, u64>,
    bytes: usize,
    next: u64,
}

impl Unconfirmed {
    fn push(&mut self, id: u16, stream: StreamId, bytes: Vec<u8>) {
        self.bytes += bytes.len();
        self.ids.insert(id, self.next);
        self.writes.insert(self.next, (id, stream, bytes));
        self.next += 1;
    }

    fn acked(&mut self, id: u16) {
        if let Some(w) = self.ids.remove(&id).and_then(|k| self.writes.remove(&k)) {
            self.bytes = self.bytes.saturating_sub(w.2.len());
        }
    }
}

/// A DDS-XRCE client session.
#[derive(Debug, Clone)]
pub struct Client {
    cfg: ClientConfig,
    state: State,
    streams: Streams,
    now: Option<Instant>,
    next_request: u16,
    pending: BTreeMap<u16, (ObjectId, PendingKind)>,
    objects: Vec<ObjectDef>,
    reads: BTreeMap<u16, ReadDef>,
    unconfirmed: Unconfirmed,
    events: VecDeque<Event>,
    agent: Option<AgentRepresentation>,
    ping_sent: Option<Instant>,
    sync: Option<(Instant, i64, Time)>,
    last_heard: Option<Instant>,
    last_ping: Option<Instant>,
    offset_ns: Option<i64>,
    /// The application reads nothing from the agent for now (see
    /// [`Client::set_deaf`]).
    deaf: bool,
}

fn wall_ns(wall: SystemTime) -> i64 {
    match wall.duration_since(UNIX_EPOCH) {
        Ok(d) => i64::try_from(d.as_nanos()).unwrap_or(i64::MAX),
        Err(e) => i64::try_from(e.duration().as_nanos()).map_or(i64::MIN, |n| -n),
    }
}

fn time_ns(t: Time) -> i64 {
    i64::from(t.seconds) * 1_000_000_000 + i64::from(t.nanoseconds)
}

fn kind_name(k: ObjectKind) -> &'static str {
    match k {
        ObjectKind::Participant => "participant",
        ObjectKind::Topic => "topic",
        ObjectKind::Publisher => "publisher",
        ObjectKind::Subscriber => "subscriber",
        ObjectKind::DataWriter => "data writer",
        ObjectKind::DataReader => "data reader",
        ObjectKind::Requester => "requester",
        ObjectKind::Replier => "replier",
        _ => "creatable object",
    }
}

impl Client {
    /// A client with no session yet.
    pub fn new(cfg: ClientConfig) -> Self {
        let header = super::session::session_header(cfg.session_id, cfg.client_key);
        let streams = Streams::new(header, cfg.streams, cfg.max_streams);
        Client {
            cfg,
            state: State::Idle,
            streams,
            now: None,
            next_request: 10,
            pending: BTreeMap::new(),
            objects: Vec::new(),
            reads: BTreeMap::new(),
            unconfirmed: Unconfirmed::default(),
            events: VecDeque::new(),
            agent: None,
            ping_sent: None,
            sync: None,
            last_heard: None,
            deaf: false,
            last_ping: None,
            offset_ns: None,
        }
    }

    /// The configuration.
    pub fn config(&self) -> &ClientConfig {
        &self.cfg
    }

    /// Where the session stands.
    pub fn state(&self) -> State {
        self.state
    }

    /// The agent, once connected.
    pub fn agent(&self) -> Option<&AgentRepresentation> {
        self.agent.as_ref()
    }

    /// The last time-sync offset: agent time = local wall time − offset.
    pub fn time_offset_ns(&self) -> Option<i64> {
        self.offset_ns
    }

    /// The objects the session has (or is creating), in creation order.
    pub fn objects(&self) -> &[ObjectDef] {
        &self.objects
    }

    /// Whether every queued submessage is sent and acknowledged.
    pub fn is_idle(&self) -> bool {
        self.streams.is_idle()
    }

    /// Bytes the session holds: queued, unacknowledged and early messages,
    /// a partly rebuilt submessage, writes kept for a new session. Bounded
    /// by the stream configuration.
    pub fn buffered_bytes(&self) -> usize {
        self.streams.buffered() + self.unconfirmed.bytes
    }

    fn tick(&mut self, now: Instant) -> Instant {
        let n = self.now.map_or(now, |t| t.max(now));
        self.now = Some(n);
        n
    }

    fn in_session(&self) -> bool {
        matches!(self.state, State::Connected | State::Lost)
    }

    fn require_session(&self) -> Result<(), CommandError> {
        if self.in_session() {
            Ok(())
        } else {
            Err(CommandError::NotConnected)
        }
    }

    fn out_of_session_header(&self) -> MessageHeader {
        MessageHeader::create_client(self.cfg.session_id, self.cfg.client_key)
    }

    fn send_create_client(&mut self) {
        let rep = ClientRepresentation {
            properties: self.cfg.properties.clone(),
            ..ClientRepresentation::new(
                self.cfg.client_key,
                self.cfg.session_id,
                u16::try_from(self.streams.config().mtu).unwrap_or(u16::MAX),
            )
        };
        let sub = Submessage::new(Payload::CreateClient(rep));
        if let Ok(m) = single(self.out_of_session_header(), sub) {
            self.streams.control.push_back(m);
        }
    }

    fn send_delete_session(&mut self) {
        let req = BaseObjectRequest::new(RequestId::LOGOUT.0, ObjectId::CLIENT);
        let _ = self
            .streams
            .send_control(Submessage::new(Payload::Delete(req)));
    }

    /// Starts (or starts again) the session: CREATE_CLIENT, repeated
    /// [`ClientConfig::create_attempts`] times. Every stream starts over;
    /// object definitions, pending requests and unacknowledged writes are
    /// kept for [`recreate_objects`](Self::recreate_objects).
    pub fn connect(&mut self, now: Instant) {
        let now = self.tick(now);
        self.streams.reset();
        self.state = State::Connecting {
            attempt: 1,
            next: crate::time::later(now, self.cfg.create_interval),
        };
        self.send_create_client();
    }

    /// Deletes the session (DELETE of the client object, repeated
    /// [`ClientConfig::delete_attempts`] times,
    /// [`ClientConfig::delete_interval`] apart, until the agent's STATUS);
    /// [`Event::SessionDeleted`] follows. Also while
    /// connecting: the agent may have created the session already, and
    /// would keep it for a client that is gone.
    pub fn disconnect(&mut self, now: Instant) -> Result<(), CommandError> {
        let now = self.tick(now);
        if !matches!(self.state, State::Connecting { .. }) {
            self.require_session()?;
        }
        self.state = State::Deleting {
            attempt: 1,
            next: crate::time::later(now, self.cfg.delete_interval),
        };
        self.send_delete_session();
        Ok(())
    }

    /// Pings the agent (GET_INFO of its activity, request id 10), inside
    /// the session when there is one, else with the out-of-session header
    /// (`80 00 00 00`). [`Event::Pong`] follows if it answers.
    pub fn ping(&mut self, now: Instant) {
        let now = self.tick(now);
        self.ping_sent = Some(now);
        let sub = Submessage::new(Payload::GetInfo(GetInfo {
            request: BaseObjectRequest::new(RequestId::PING.0, ObjectId::AGENT),
            info_mask: GetInfo::ACTIVITY,
        }));
        if self.in_session() {
            self.last_ping = Some(now);
            let _ = self.streams.send_control(sub);
        } else if let Ok(m) = single(self.out_of_session_header(), sub) {
            self.streams.control.push_back(m);
        }
    }

    /// Asks the agent for its time (TIMESTAMP stamped with `wall`, the
    /// local wall clock now); [`Event::TimeSynced`] follows.
    pub fn sync_time(&mut self, now: Instant, wall: SystemTime) -> Result<(), CommandError> {
        let now = self.tick(now);
        self.require_session()?;
        let ns = wall_ns(wall);
        let t = Time {
            seconds: ns.div_euclid(1_000_000_000) as i32,
            nanoseconds: ns.rem_euclid(1_000_000_000) as u32,
        };
        self.sync = Some((now, ns, t));
        self.streams
            .send_control(Submessage::new(Payload::Timestamp(t)))?;
        Ok(())
    }

    fn alloc_request(&mut self) -> Result<u16, CommandError> {
        if self.pending.len() >= self.cfg.max_pending {
            return Err(CommandError::TooManyRequests(self.pending.len()));
        }
        for _ in 0..=u16::MAX {
            let id = self.next_request;
            self.next_request = if id == u16::MAX { 10 } else { id + 1 };
            let used = self.pending.contains_key(&id)
                || self.unconfirmed.ids.contains_key(&id)
                || self.reads.values().any(|r| r.request == id);
            if !used {
                return Ok(id);
            }
        }
        Err(CommandError::TooManyRequests(self.pending.len()))
    }

    fn check_kind(object: ObjectId, kinds: &[ObjectKind]) -> Result<(), CommandError> {
        match object.kind() {
            Some(k) if kinds.contains(&k) => Ok(()),
            _ => Err(CommandError::KindMismatch {
                object,
                expected: kinds.first().map_or("object", |k| kind_name(*k)),
            }),
        }
    }

    fn queue(
        &mut self,
        stream: StreamId,
        sub: &Submessage,
        tag: Option<u16>,
        force: bool,
    ) -> Result<Vec<u8>, CommandError> {
        let bytes = self.streams.encode(sub)?;
        self.streams.push(stream, bytes.clone(), tag, force)?;
        Ok(bytes)
    }

    /// CREATE `object` (its id's kind must be the variant's) on the control
    /// stream; [`Event::Status`] answers. The definition is kept for
    /// [`recreate_objects`](Self::recreate_objects).
    pub fn create(
        &mut self,
        object: ObjectId,
        variant: ObjectVariant,
        mode: CreationMode,
        now: Instant,
    ) -> Result<RequestId, CommandError> {
        self.tick(now);
        self.require_session()?;
        let creatable = [
            ObjectKind::Participant,
            ObjectKind::Topic,
            ObjectKind::Publisher,
            ObjectKind::Subscriber,
            ObjectKind::DataWriter,
            ObjectKind::DataReader,
            ObjectKind::Requester,
            ObjectKind::Replier,
            ObjectKind::Type,
            ObjectKind::QosProfile,
            ObjectKind::Application,
        ];
        if !creatable.contains(&variant.kind()) || object.kind() != Some(variant.kind()) {
            return Err(CommandError::KindMismatch {
                object,
                expected: kind_name(variant.kind()),
            });
        }
        let req = self.alloc_request()?;
        let sub = Submessage::with_flags(
            mode.flags(),
            Payload::Create(Create {
                request: BaseObjectRequest::new(req, object),
                object: variant.clone(),
            }),
        );
        self.queue(self.cfg.control_stream, &sub, None, false)?;
        self.pending.insert(req, (object, PendingKind::Create));
        // a replaced object keeps its place: children come after it
        match self.objects.iter_mut().find(|d| d.id == object) {
            Some(d) => d.variant = variant,
            None => self.objects.push(ObjectDef {
                id: object,
                variant,
            }),
        }
        Ok(RequestId(req))
    }

    /// DELETE `object`; [`Event::Status`] answers.
    pub fn delete(&mut self, object: ObjectId, now: Instant) -> Result<RequestId, CommandError> {
        self.tick(now);
        self.require_session()?;
        let req = self.alloc_request()?;
        let sub = Submessage::new(Payload::Delete(BaseObjectRequest::new(req, object)));
        self.queue(self.cfg.control_stream, &sub, None, false)?;
        self.pending.insert(req, (object, PendingKind::Delete));
        self.objects.retain(|d| d.id != object);
        self.reads.retain(|_, r| r.read.request.object_id != object);
        Ok(RequestId(req))
    }

    fn write_data(
        &mut self,
        object: ObjectId,
        stream: StreamId,
        data: Vec<u8>,
    ) -> Result<RequestId, CommandError> {
        self.require_session()?;
        let req = self.alloc_request()?;
        let data_len = data.len();
        let sub = Submessage::new(Payload::WriteData(Data {
            request: BaseObjectRequest::new(req, object),
            data,
        }));
        let tag = stream.is_reliable().then_some(req);
        if stream.is_reliable() {
            // writes kept for a new session count against the backlog too
            if self.unconfirmed.ids.len() >= self.cfg.max_pending {
                return Err(CommandError::TooManyRequests(self.unconfirmed.ids.len()));
            }
            let max = self.cfg.streams.max_backlog;
            if data_len > max {
                // no wait makes room for it
                return Err(QueueError::Stream(StreamError::NeverFits {
                    stream: stream.0,
                    len: data_len,
                    max,
                })
                .into());
            }
            if self.unconfirmed.bytes + data_len > max {
                return Err(QueueError::Stream(StreamError::Backlog {
                    stream: stream.0,
                    len: data_len,
                    max,
                })
                .into());
            }
        }
        let bytes = self.queue(stream, &sub, tag, false)?;
        if stream.is_reliable() {
            self.unconfirmed.push(req, stream, bytes);
        }
        Ok(RequestId(req))
    }

    /// WRITE_DATA (FORMAT_DATA) of a sample's serialized body to `writer`
    /// on `stream`. On a reliable stream, [`Event::WriteAcked`] follows
    /// once the agent has it all (the agent confirms nothing more).
    pub fn write(
        &mut self,
        writer: ObjectId,
        stream: StreamId,
        data: &[u8],
        now: Instant,
    ) -> Result<RequestId, CommandError> {
        self.tick(now);
        Self::check_kind(writer, &[ObjectKind::DataWriter])?;
        self.write_data(writer, stream, data.to_vec())
    }

    /// A request through `requester`; the [`Event::Reply`] carries the
    /// returned id.
    pub fn request(
        &mut self,
        requester: ObjectId,
        stream: StreamId,
        data: &[u8],
        now: Instant,
    ) -> Result<RequestId, CommandError> {
        self.tick(now);
        Self::check_kind(requester, &[ObjectKind::Requester])?;
        self.write_data(requester, stream, data.to_vec())
    }

    /// A reply through `replier` to the request `identity` came with.
    pub fn reply(
        &mut self,
        replier: ObjectId,
        stream: StreamId,
        identity: &SampleIdentity,
        data: &[u8],
        now: Instant,
    ) -> Result<RequestId, CommandError> {
        self.tick(now);
        Self::check_kind(replier, &[ObjectKind::Replier])?;
        let mut body = identity.to_bytes().to_vec();
        body.extend_from_slice(data);
        self.write_data(replier, stream, body)
    }

    /// READ_DATA: asks the agent to send samples of a reader, requester or
    /// replier on `preferred_stream` (FORMAT_DATA). `delivery` `None` means
    /// one sample; all fields 0 cancels the reading. A new READ_DATA on the
    /// same object replaces the previous one.
    pub fn read(
        &mut self,
        object: ObjectId,
        stream: StreamId,
        preferred_stream: StreamId,
        delivery: Option<DeliveryControl>,
        now: Instant,
    ) -> Result<RequestId, CommandError> {
        self.tick(now);
        self.require_session()?;
        Self::check_kind(
            object,
            &[
                ObjectKind::DataReader,
                ObjectKind::Requester,
                ObjectKind::Replier,
            ],
        )?;
        let req = self.alloc_request()?;
        let read = ReadData {
            request: BaseObjectRequest::new(req, object),
            preferred_stream_id: preferred_stream,
            data_format: flags::FORMAT_DATA,
            content_filter: None,
            delivery_control: delivery,
        };
        self.queue(
            stream,
            &Submessage::new(Payload::ReadData(read.clone())),
            None,
            false,
        )?;
        self.reads.retain(|_, r| r.read.request.object_id != object);
        if delivery.is_some_and(|d| d != DeliveryControl::default()) {
            self.reads.insert(
                object.0,
                ReadDef {
                    request: req,
                    stream,
                    read,
                },
            );
        }
        Ok(RequestId(req))
    }

    /// Creates every object again (REUSE|REPLACE), repeats pending DELETEs
    /// and ongoing READ_DATAs under their request ids, and queues the
    /// unacknowledged reliable writes again. Call it after
    /// [`Event::Connected`] of a session created anew. Returns the request
    /// ids of the CREATEs, in creation order.
    pub fn recreate_objects(&mut self, now: Instant) -> Result<Vec<RequestId>, CommandError> {
        self.tick(now);
        self.require_session()?;
        let mut ids = Vec::new();
        let control = self.cfg.control_stream;
        for def in self.objects.clone() {
            let pending = self
                .pending
                .iter()
                .find(|(_, p)| **p == (def.id, PendingKind::Create))
                .map(|(r, _)| *r);
            let req = match pending {
                Some(r) => r,
                None => self.alloc_request()?,
            };
            let sub = Submessage::with_flags(
                CreationMode::REUSE_OR_REPLACE.flags(),
                Payload::Create(Create {
                    request: BaseObjectRequest::new(req, def.id),
                    object: def.variant,
                }),
            );
            self.queue(control, &sub, None, true)?;
            self.pending.insert(req, (def.id, PendingKind::Create));
            ids.push(RequestId(req));
        }
        let deletes: Vec<(u16, ObjectId)> = self
            .pending
            .iter()
            .filter(|(_, p)| p.1 == PendingKind::Delete)
            .map(|(r, p)| (*r, p.0))
            .collect();
        for (req, object) in deletes {
            let sub = Submessage::new(Payload::Delete(BaseObjectRequest::new(req, object)));
            self.queue(control, &sub, None, true)?;
        }
        for r in self.reads.values().cloned().collect::<Vec<_>>() {
            self.queue(
                r.stream,
                &Submessage::new(Payload::ReadData(r.read)),
                None,
                true,
            )?;
        }
        for (req, stream, bytes) in self.unconfirmed.writes.clone().into_values() {
            self.streams.push(stream, bytes, Some(req), true)?;
        }
        Ok(ids)
    }

    /// Time passed: CREATE_CLIENT and DELETE retries, keepalive pings and
    /// loss detection; HEARTBEATs that are due go out with the next
    /// [`poll_transmit`](Self::poll_transmit).
    pub fn handle_timeout(&mut self, now: Instant) {
        let now = self.tick(now);
        match self.state {
            State::Connecting { attempt, next } if now >= next => {
                if attempt < self.cfg.create_attempts {
                    self.state = State::Connecting {
                        attempt: attempt + 1,
                        next: crate::time::later(now, self.cfg.create_interval),
                    };
                    self.send_create_client();
                } else {
                    self.state = State::Idle;
                    self.events
                        .push_back(Event::ConnectFailed(ConnectError::NoAnswer {
                            attempts: attempt,
                        }));
                }
            }
            State::Deleting { attempt, next } if now >= next => {
                if attempt < self.cfg.delete_attempts {
                    self.state = State::Deleting {
                        attempt: attempt + 1,
                        next: crate::time::later(now, self.cfg.delete_interval),
                    };
                    self.send_delete_session();
                } else {
                    self.state = State::Closed;
                    self.streams.reset();
                    self.events
                        .push_back(Event::SessionDeleted { confirmed: false });
                }
            }
            State::Connected | State::Lost => self.keepalive(now),
            _ => {}
        }
    }

    /// The application stops reading the agent's messages (`true`: a full
    /// subscription holds the session back, the agent's reliable window
    /// holding the rest) or reads them again. Silence while deaf is not
    /// the agent's: the session is not reported lost then, and silence is
    /// counted afresh from when it listens again.
    pub fn set_deaf(&mut self, deaf: bool, now: Instant) {
        if self.deaf && !deaf {
            if let Some(h) = &mut self.last_heard {
                *h = (*h).max(now);
            }
        }
        self.deaf = deaf;
    }

    fn keepalive_times(&self) -> Option<(Option<Instant>, Instant)> {
        let k = self.cfg.keepalive?;
        let heard = self.last_heard.filter(|_| self.in_session())?;
        let lost_at = (self.state == State::Connected && !self.deaf)
            .then(|| crate::time::later(heard, k.timeout));
        let ping_at =
            crate::time::later(self.last_ping.map_or(heard, |p| p.max(heard)), k.interval);
        Some((lost_at, ping_at))
    }

    fn keepalive(&mut self, now: Instant) {
        let Some((lost_at, ping_at)) = self.keepalive_times() else {
            return;
        };
        if lost_at.is_some_and(|t| now >= t) {
            self.state = State::Lost;
            self.events.push_back(Event::AgentLost(LostReason::Silent));
        }
        if now >= ping_at {
            self.ping(now);
        }
    }

    /// When [`handle_timeout`](Self::handle_timeout) is next needed.
    pub fn poll_timeout(&self) -> Option<Instant> {
        let retry = match self.state {
            State::Connecting { next, .. } | State::Deleting { next, .. } => Some(next),
            _ => None,
        };
        let keep = self
            .keepalive_times()
            .map(|(l, p)| l.map_or(p, |l| l.min(p)));
        let streams = if self.in_session() {
            self.streams.poll_timeout()
        } else {
            None
        };
        [retry, keep, streams].into_iter().flatten().min()
    }

    /// The next message for the agent.
    pub fn poll_transmit(&mut self) -> Option<Vec<u8>> {
        let now = self.now?;
        if self.in_session() || matches!(self.state, State::Deleting { .. }) {
            self.streams.poll_transmit(now)
        } else {
            self.streams.control.pop_front()
        }
    }

    /// The next event.
    pub fn poll_event(&mut self) -> Option<Event> {
        self.events.pop_front()
    }
}
