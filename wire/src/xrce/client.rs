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
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use super::message::MessageHeader;
use super::object::ActivityInfo;
use super::object::{AgentRepresentation, ClientRepresentation, ObjectInfo, ObjectVariant};
use super::session::{single, InputError, QueueError, Streams};
use super::stream::StreamConfig;
use super::submessage::{
    flags, Create, Data, DeliveryControl, GetInfo, Info, Payload, ReadData, Status, Submessage,
    TimestampReply,
};
use super::types::{
    BaseObjectRequest, ClientKey, ObjectId, ObjectKind, Property, RequestId, ResultStatus,
    StatusCode, StreamId, Time,
};
use super::{EncodeError, Message};

/// Pings that tell when the agent has gone silent.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Keepalive {
    /// Ping the agent after this long without hearing from it, and again
    /// every `interval` while it stays silent.
    pub interval: Duration,
    /// Report [`Event::AgentLost`] after this long without hearing from it.
    pub timeout: Duration,
}

/// How a client session behaves.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ClientConfig {
    /// The client key (0 is refused by the agent).
    pub client_key: ClientKey,
    /// The session id: 0x81 as the eProsima library always uses; below
    /// 0x80 every message header carries the client key.
    pub session_id: u8,
    /// Stream sizes and timing; `mtu` is advertised in CREATE_CLIENT.
    pub streams: StreamConfig,
    /// Output streams of each kind, and input streams of each kind, a
    /// session may open.
    pub max_streams: usize,
    /// CREATE_CLIENT attempts (10 in the eProsima library).
    pub create_attempts: u32,
    /// Time between them (1 s).
    pub create_interval: Duration,
    /// Attempts at DELETE of the session (10, 1 s apart).
    pub delete_attempts: u32,
    /// Silence detection; `None` sends no pings of its own.
    pub keepalive: Option<Keepalive>,
    /// The stream CREATE and DELETE go on (the built-in reliable 0x80).
    pub control_stream: StreamId,
    /// Requests waiting for a STATUS at most.
    pub max_pending: usize,
    /// CLIENT_Representation properties (`uxr_sm`, `uxr_hl`).
    pub properties: Option<Vec<Property>>,
}

impl ClientConfig {
    /// The eProsima defaults for `client_key`, with pings every second of
    /// silence and the agent reported lost after three.
    pub fn new(client_key: impl Into<ClientKey>) -> Self {
        ClientConfig {
            client_key: client_key.into(),
            session_id: 0x81,
            streams: StreamConfig::client(),
            max_streams: 4,
            create_attempts: 10,
            create_interval: Duration::from_secs(1),
            delete_attempts: 10,
            keepalive: Some(Keepalive {
                interval: Duration::from_secs(1),
                timeout: Duration::from_secs(3),
            }),
            control_stream: StreamId::RELIABLE,
            max_pending: 4096,
            properties: None,
        }
    }
}

/// CREATE's creation mode (flags `REUSE`, `REPLACE`; §6).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct CreationMode {
    /// An existing object whose representation matches is kept (`OK_MATCHED`).
    pub reuse: bool,
    /// An existing object is replaced.
    pub replace: bool,
}

impl CreationMode {
    /// Neither: an existing object gives `ERR_ALREADY_EXISTS`.
    pub const CREATE: CreationMode = CreationMode {
        reuse: false,
        replace: false,
    };
    /// Replace what exists (the eProsima examples' choice).
    pub const REPLACE: CreationMode = CreationMode {
        reuse: false,
        replace: true,
    };
    /// Keep what matches, replace what does not.
    pub const REUSE_OR_REPLACE: CreationMode = CreationMode {
        reuse: true,
        replace: true,
    };

    /// The CREATE flags.
    pub fn flags(self) -> u8 {
        let mut f = flags::LITTLE_ENDIAN;
        if self.reuse {
            f |= flags::REUSE;
        }
        if self.replace {
            f |= flags::REPLACE;
        }
        f
    }

    /// The mode of CREATE `flags`.
    pub fn from_flags(f: u8) -> Self {
        CreationMode {
            reuse: f & flags::REUSE != 0,
            replace: f & flags::REPLACE != 0,
        }
    }
}

/// `SampleIdentity`: the writer GUID and sequence number of a request, in
/// front of the data a replier reads and writes (§9).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct SampleIdentity {
    /// The request writer's GUID.
    pub writer_guid: [u8; 16],
    /// Sequence number, high half.
    pub sequence_high: i32,
    /// Sequence number, low half.
    pub sequence_low: u32,
}

impl SampleIdentity {
    /// Its size on the wire.
    pub const LEN: usize = 24;

    /// The 24 bytes (sequence number little-endian).
    pub fn to_bytes(&self) -> [u8; 24] {
        let mut b = [0; 24];
        b[..16].copy_from_slice(&self.writer_guid);
        b[16..20].copy_from_slice(&self.sequence_high.to_le_bytes());
        b[20..].copy_from_slice(&self.sequence_low.to_le_bytes());
        b
    }

    /// Reads the first 24 bytes of `b`.
    pub fn from_bytes(b: &[u8]) -> Option<Self> {
        Some(SampleIdentity {
            writer_guid: b.get(..16)?.try_into().ok()?,
            sequence_high: i32::from_le_bytes(b.get(16..20)?.try_into().ok()?),
            sequence_low: u32::from_le_bytes(b.get(20..24)?.try_into().ok()?),
        })
    }
}

/// Why the session could not be created.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum ConnectError {
    /// No STATUS_AGENT came back.
    #[error("no XRCE agent answered {attempts} CREATE_CLIENT")]
    NoAnswer {
        /// Attempts made.
        attempts: u32,
    },
    /// The agent answered with an error.
    #[error("the XRCE agent refused the session: {0}")]
    Refused(StatusCode),
}

/// An error STATUS for a request.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("the XRCE agent answered {0}")]
pub struct StatusError(pub StatusCode);

/// Why the agent is considered lost.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LostReason {
    /// Nothing heard for [`Keepalive::timeout`].
    Silent,
    /// A ping in the session was answered by an agent that does not know
    /// it (restarted).
    SessionUnknown,
}

/// What the client reports.
#[derive(Debug, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub enum Event {
    /// STATUS_AGENT OK: the session exists; streams start from 0.
    Connected {
        /// What the agent says of itself.
        agent: AgentRepresentation,
    },
    /// CREATE_CLIENT failed.
    ConnectFailed(ConnectError),
    /// The STATUS of a CREATE, DELETE or READ_DATA.
    Status {
        /// The request.
        request: RequestId,
        /// Its object.
        object: ObjectId,
        /// `OK` / `OK_MATCHED`, or the error the agent named.
        result: Result<StatusCode, StatusError>,
    },
    /// A sample for a data reader.
    Data {
        /// The reader.
        reader: ObjectId,
        /// The READ_DATA that asked for it.
        request: RequestId,
        /// The stream it came on.
        stream: StreamId,
        /// The sample's serialized body.
        data: Vec<u8>,
    },
    /// A request for a replier.
    Request {
        /// The replier.
        replier: ObjectId,
        /// The READ_DATA that asked for it.
        request: RequestId,
        /// Pass to [`Client::reply`].
        identity: SampleIdentity,
        /// The request body.
        data: Vec<u8>,
    },
    /// A reply for a requester.
    Reply {
        /// The requester.
        requester: ObjectId,
        /// The [`Client::request`] it answers.
        request: RequestId,
        /// The reply body.
        data: Vec<u8>,
    },
    /// The agent acknowledged every byte of a reliable write.
    WriteAcked(RequestId),
    /// The agent answered a ping.
    Pong {
        /// Whether the agent knows this session.
        in_session: bool,
        /// Round trip, when the ping was this machine's.
        rtt: Option<Duration>,
    },
    /// TIMESTAMP_REPLY: agent time = local wall time − `offset_ns`.
    TimeSynced {
        /// `((t0 + t3) − (t1 + t2)) / 2` in nanoseconds.
        offset_ns: i64,
        /// Round trip.
        rtt: Duration,
    },
    /// The agent stopped answering or forgot the session.
    AgentLost(LostReason),
    /// A lost agent answered again and still has the session.
    AgentBack,
    /// The session is deleted (or the agent never confirmed it).
    SessionDeleted {
        /// Whether the agent's STATUS came.
        confirmed: bool,
    },
}

/// Why a command was refused.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum CommandError {
    /// There is no session (connect first).
    #[error("no XRCE session")]
    NotConnected,
    /// The object's kind does not fit the command or representation.
    #[error("XRCE object {object:#06x} is not a {expected}", object = .object.0)]
    KindMismatch {
        /// The object.
        object: ObjectId,
        /// The kind the command needs.
        expected: &'static str,
    },
    /// Too many requests wait for a STATUS.
    #[error("{0} XRCE requests already wait for a STATUS")]
    TooManyRequests(usize),
    /// The stream refused the submessage.
    #[error(transparent)]
    Queue(#[from] QueueError),
}

impl From<EncodeError> for CommandError {
    fn from(e: EncodeError) -> Self {
        CommandError::Queue(QueueError::Encode(e))
    }
}

/// Where the session stands.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum State {
    /// No session.
    Idle,
    /// CREATE_CLIENT sent.
    Connecting {
        /// Attempts so far.
        attempt: u32,
        /// When the next is due.
        next: Instant,
    },
    /// The session exists.
    Connected,
    /// The session exists but the agent is silent.
    Lost,
    /// DELETE of the session sent.
    Deleting {
        /// Attempts so far.
        attempt: u32,
        /// When the next is due.
        next: Instant,
    },
    /// The session was deleted.
    Closed,
}

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

/// A created object as [`Client::recreate_objects`] creates it again.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ObjectDef {
    /// Its id.
    pub id: ObjectId,
    /// What it is.
    pub variant: ObjectVariant,
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
    unconfirmed: VecDeque<(u16, StreamId, Vec<u8>)>,
    events: VecDeque<Event>,
    agent: Option<AgentRepresentation>,
    ping_sent: Option<Instant>,
    sync: Option<(Instant, i64, Time)>,
    last_heard: Option<Instant>,
    last_ping: Option<Instant>,
    offset_ns: Option<i64>,
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
            unconfirmed: VecDeque::new(),
            events: VecDeque::new(),
            agent: None,
            ping_sent: None,
            sync: None,
            last_heard: None,
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
            next: now + self.cfg.create_interval,
        };
        self.send_create_client();
    }

    /// Deletes the session (DELETE of the client object, repeated as
    /// CREATE_CLIENT is); [`Event::SessionDeleted`] follows.
    pub fn disconnect(&mut self, now: Instant) -> Result<(), CommandError> {
        let now = self.tick(now);
        self.require_session()?;
        self.state = State::Deleting {
            attempt: 1,
            next: now + self.cfg.create_interval,
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
        loop {
            let id = self.next_request;
            self.next_request = if id == u16::MAX { 10 } else { id + 1 };
            let used = self.pending.contains_key(&id)
                || self.reads.values().any(|r| r.request == id)
                || self.unconfirmed.iter().any(|u| u.0 == id);
            if !used {
                return Ok(id);
            }
        }
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
        self.objects.retain(|d| d.id != object);
        self.objects.push(ObjectDef {
            id: object,
            variant,
        });
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
        let sub = Submessage::new(Payload::WriteData(Data {
            request: BaseObjectRequest::new(req, object),
            data,
        }));
        let tag = stream.is_reliable().then_some(req);
        let bytes = self.queue(stream, &sub, tag, false)?;
        if stream.is_reliable() {
            self.unconfirmed.push_back((req, stream, bytes));
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
        for (req, stream, bytes) in self.unconfirmed.clone() {
            self.streams.push(stream, bytes, Some(req), true)?;
        }
        Ok(ids)
    }

    /// Takes one message from the agent.
    pub fn handle_input(&mut self, bytes: &[u8], now: Instant) -> Result<(), InputError> {
        let now = self.tick(now);
        let msg = Message::decode(bytes)?;
        let h = msg.header;
        let own = self.cfg.session_id;
        let outside = h.session_id == own & 0x80 && h.session_id != own;
        if h.session_id != own && !outside {
            return Err(InputError::WrongSession {
                expected: own,
                got: h.session_id,
            });
        }
        if let Some(k) = h.client_key.filter(|k| *k != self.cfg.client_key) {
            return Err(InputError::WrongClientKey {
                expected: self.cfg.client_key.into(),
                got: k.into(),
            });
        }
        let streams_open = matches!(
            self.state,
            State::Connected | State::Lost | State::Deleting { .. }
        );
        if outside || !streams_open {
            // only answers to what was sent outside the streams
            if h.stream_id != super::StreamId::NONE {
                return Err(InputError::Unsolicited {
                    what: "stream message outside a session",
                });
            }
            let mut first = Ok(());
            for sub in msg.submessages {
                let r = match sub.payload {
                    Payload::Info(i) => self.on_info(i, now),
                    Payload::StatusAgent(s) if !outside => self.on_status_agent(s, now),
                    Payload::Status(s) if !outside => self.on_session_status(s),
                    p => Err(InputError::Unexpected {
                        what: p.id().name(),
                        stream: 0,
                    }),
                };
                first = first.and(r);
            }
            return first;
        }
        self.heard(now);
        let arrival = self.streams.receive(msg, now);
        let mut first = arrival.errors.into_iter().next().map_or(Ok(()), Err);
        for (stream, sub) in arrival.subs {
            let r = self.on_submessage(stream, sub, now);
            first = first.and(r);
        }
        self.streams.control.extend(arrival.replies);
        for tag in self.streams.take_acked() {
            self.unconfirmed.retain(|u| u.0 != tag);
            self.events.push_back(Event::WriteAcked(RequestId(tag)));
        }
        first
    }

    fn heard(&mut self, now: Instant) {
        self.last_heard = Some(now);
        if self.state == State::Lost {
            self.state = State::Connected;
            self.events.push_back(Event::AgentBack);
        }
    }

    fn on_submessage(
        &mut self,
        stream: StreamId,
        sub: Submessage,
        now: Instant,
    ) -> Result<(), InputError> {
        let format = sub.data_format();
        match sub.payload {
            Payload::Status(s) if stream == StreamId::NONE => self.on_session_status(s),
            Payload::Status(s) => self.on_status(s),
            Payload::Info(i) => self.on_info(i, now),
            Payload::Data(d) => self.on_data(stream, format, d),
            Payload::TimestampReply(t) => self.on_timestamp_reply(t, now),
            Payload::GetInfo(g) => {
                let info = Info {
                    request: BaseObjectRequest::new(g.request.request_id.0, ObjectId::INVALID),
                    result: ResultStatus::default(),
                    info: ObjectInfo::default(),
                };
                let _ = self
                    .streams
                    .send_control(Submessage::new(Payload::Info(info)));
                Ok(())
            }
            p => Err(InputError::Unexpected {
                what: p.id().name(),
                stream: stream.0,
            }),
        }
    }

    fn on_status_agent(
        &mut self,
        s: super::submessage::StatusAgent,
        now: Instant,
    ) -> Result<(), InputError> {
        if !matches!(self.state, State::Connecting { .. }) {
            return Err(InputError::Unsolicited {
                what: "STATUS_AGENT",
            });
        }
        if s.result.status.is_ok() {
            self.state = State::Connected;
            self.streams.reset();
            self.last_heard = Some(now);
            self.last_ping = None;
            self.agent = Some(s.agent.clone());
            self.events.push_back(Event::Connected { agent: s.agent });
        } else {
            self.state = State::Idle;
            self.events
                .push_back(Event::ConnectFailed(ConnectError::Refused(s.result.status)));
        }
        Ok(())
    }

    fn on_session_status(&mut self, s: Status) -> Result<(), InputError> {
        if !matches!(self.state, State::Deleting { .. })
            || s.request.request_id != RequestId::LOGOUT
        {
            return Err(InputError::Unsolicited { what: "STATUS" });
        }
        self.state = State::Closed;
        self.streams.reset();
        self.events
            .push_back(Event::SessionDeleted { confirmed: true });
        Ok(())
    }

    fn on_status(&mut self, s: Status) -> Result<(), InputError> {
        let req = s.request.request_id.0;
        let object = s.request.object_id;
        let code = s.result.status;
        let result = if code.is_ok() {
            Ok(code)
        } else {
            Err(StatusError(code))
        };
        match self.pending.get(&req) {
            Some(&(o, kind)) if o == object => {
                self.pending.remove(&req);
                if kind == PendingKind::Create && result.is_err() {
                    self.objects.retain(|d| d.id != object);
                }
            }
            _ => {
                let read = self
                    .reads
                    .iter()
                    .find(|(_, r)| r.request == req && r.read.request.object_id == object)
                    .map(|(k, _)| *k);
                match read {
                    Some(k) => {
                        if result.is_err() {
                            self.reads.remove(&k);
                        }
                    }
                    None => return Err(InputError::Unsolicited { what: "STATUS" }),
                }
            }
        }
        self.events.push_back(Event::Status {
            request: RequestId(req),
            object,
            result,
        });
        Ok(())
    }

    fn on_info(&mut self, i: Info, now: Instant) -> Result<(), InputError> {
        if i.request.request_id != RequestId::PING {
            return Err(InputError::Unsolicited { what: "INFO" });
        }
        let available = matches!(
            i.info.activity,
            Some(ActivityInfo::Agent { availability, .. }) if availability > 0
        );
        if !available {
            return Ok(());
        }
        let rtt = self
            .ping_sent
            .take()
            .map(|t| now.saturating_duration_since(t));
        let in_session = i.result.implementation_status != 0;
        if self.in_session() {
            if in_session {
                self.heard(now);
            } else if self.state == State::Connected {
                self.state = State::Lost;
                self.events
                    .push_back(Event::AgentLost(LostReason::SessionUnknown));
            }
        }
        self.events.push_back(Event::Pong { in_session, rtt });
        Ok(())
    }

    fn on_data(&mut self, stream: StreamId, format: u8, d: Data) -> Result<(), InputError> {
        if format != flags::FORMAT_DATA {
            return Err(InputError::DataFormat(format));
        }
        let object = d.request.object_id;
        let request = d.request.request_id;
        let short = |needed| InputError::ShortData {
            object: object.0,
            len: d.data.len(),
            needed,
        };
        let event = match object.kind() {
            Some(ObjectKind::DataReader) => Event::Data {
                reader: object,
                request,
                stream,
                data: d.data,
            },
            Some(ObjectKind::Requester) => {
                let (Some(&[r0, r1]), Some(rest)) = (d.data.get(..2), d.data.get(4..)) else {
                    return Err(short(4));
                };
                Event::Reply {
                    requester: object,
                    request: RequestId(u16::from_be_bytes([r0, r1])),
                    data: rest.to_vec(),
                }
            }
            Some(ObjectKind::Replier) => {
                let (Some(identity), Some(rest)) = (
                    SampleIdentity::from_bytes(&d.data),
                    d.data.get(SampleIdentity::LEN..),
                ) else {
                    return Err(short(SampleIdentity::LEN));
                };
                Event::Request {
                    replier: object,
                    request,
                    identity,
                    data: rest.to_vec(),
                }
            }
            _ => {
                return Err(InputError::Unexpected {
                    what: "DATA for an object that does not read",
                    stream: stream.0,
                })
            }
        };
        self.events.push_back(event);
        Ok(())
    }

    fn on_timestamp_reply(&mut self, t: TimestampReply, now: Instant) -> Result<(), InputError> {
        let Some((sent_at, sent_ns, sent)) = self.sync.filter(|s| s.2 == t.originate) else {
            return Err(InputError::Unsolicited {
                what: "TIMESTAMP_REPLY",
            });
        };
        self.sync = None;
        let rtt = now.saturating_duration_since(sent_at);
        let t3 = i128::from(sent_ns) + i128::try_from(rtt.as_nanos()).unwrap_or(0);
        let t0 = i128::from(time_ns(sent));
        let (t1, t2) = (
            i128::from(time_ns(t.receive)),
            i128::from(time_ns(t.transmit)),
        );
        let offset = ((t0 + t3) - (t1 + t2)) / 2;
        let offset_ns =
            i64::try_from(offset).unwrap_or(if offset < 0 { i64::MIN } else { i64::MAX });
        self.offset_ns = Some(offset_ns);
        self.events.push_back(Event::TimeSynced { offset_ns, rtt });
        Ok(())
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
                        next: now + self.cfg.create_interval,
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
                        next: now + self.cfg.create_interval,
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

    fn keepalive_times(&self) -> Option<(Option<Instant>, Instant)> {
        let k = self.cfg.keepalive?;
        let heard = self.last_heard.filter(|_| self.in_session())?;
        let lost_at = (self.state == State::Connected).then(|| heard + k.timeout);
        let ping_at = self.last_ping.map_or(heard, |p| p.max(heard)) + k.interval;
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
