//! The client's configuration, commands' parameters, events and errors.

use std::time::{Duration, Instant};

use super::super::object::{AgentRepresentation, ObjectVariant};
use super::super::session::QueueError;
use super::super::stream::StreamConfig;
use super::super::submessage::flags;
use super::super::types::{ClientKey, ObjectId, Property, RequestId, StatusCode, StreamId};
use super::super::EncodeError;

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
    /// Attempts at DELETE of the session (10 in the eProsima library).
    pub delete_attempts: u32,
    /// Time between them (1 s, as between CREATE_CLIENTs).
    pub delete_interval: Duration,
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
            delete_interval: Duration::from_secs(1),
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
    /// The STATUS of a CREATE, DELETE or READ_DATA, or the agent's refusal
    /// of a WRITE_DATA (an error status naming the write's request).
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
        /// Pass to [`Client::reply`](super::Client::reply).
        identity: SampleIdentity,
        /// The request body.
        data: Vec<u8>,
    },
    /// A reply for a requester.
    Reply {
        /// The requester.
        requester: ObjectId,
        /// The [`Client::request`](super::Client::request) it answers.
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
    /// A submessage from the agent (a DATA: a sample) came in fragments
    /// adding up to more than [`StreamConfig::max_reassembly`] and was
    /// given up (also returned by `handle_input` as its error, when it is
    /// the first; reported here whatever else the input held).
    TooLarge {
        /// What it was for, as its first fragment says (the reader, for a
        /// sample).
        object: Option<ObjectId>,
        /// The bound.
        max: usize,
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

/// A created object as [`Client::recreate_objects`](super::Client::recreate_objects) creates it again.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ObjectDef {
    /// Its id.
    pub id: ObjectId,
    /// What it is.
    pub variant: ObjectVariant,
}
