//! DDS-XRCE (sans-I/O), as eProsima Micro XRCE-DDS Client and Agent 2.x
//! put it on the wire (`shared/protocols/xrce.md`): the message header in
//! both forms, every submessage 0x00–0x0F with its payload, binary object
//! representations ([`BinaryRepresentation`]), the TCP ([`tcp`]) and
//! serial ([`serial`]) framings (UDP carries one message per datagram with
//! no framing), the [`stream`]s, and the two session machines: [`Client`]
//! and the agent's half, [`Agent`]; agent [`discovery`]; and the agent's host over one DDS
//! domain, [`bridge::Bridge`]. With the cargo feature `sim`, `xrce::sim`
//! puts the machines on the shared simulated network.
//!
//! ```
//! use courier_wire::xrce::{
//!     AckNack, Message, MessageHeader, Payload, StreamId, Submessage,
//! };
//! // an ACKNACK from `udp_reliable_loss_recovery`: seq 2 of stream 0x80 is missing
//! let bytes = [0x81, 0, 0, 0, 0x0A, 0x01, 5, 0, 2, 0, 0, 1, 0x80];
//! let m = Message::decode(&bytes).unwrap();
//! assert_eq!(m.header, MessageHeader::new(0x81, StreamId::NONE, 0));
//! let Payload::AckNack(a) = &m.submessages[0].payload else { panic!() };
//! assert_eq!((a.first_unacked, a.nack_bits(), a.stream_id), (2, 1, StreamId::RELIABLE));
//! assert_eq!(m.to_vec().unwrap(), bytes);
//!
//! let mut ack = AckNack { first_unacked: 2, nack_bitmap: [0; 2], stream_id: StreamId::RELIABLE };
//! ack.set_nack_bits(1);
//! let m2 = Message::new(m.header, vec![Submessage::new(Payload::AckNack(ack))]);
//! assert_eq!(m2, m);
//! ```
//!
//! # Rules the codec follows
//! - Payloads are decoded by their type, as the peers do, and must fill the
//!   declared `submessageLength` exactly; submessage headers are 4-aligned
//!   from the start of the message and the padding bytes between them are
//!   kept ([`Submessage::padding`]), as are bytes after the last submessage
//!   ([`Message::trailing`]), so decoding and re-encoding what the peers
//!   sent gives the same bytes.
//! - Payload primitives follow the submessage's endianness flag; the
//!   message header's sequence number and the submessage length are always
//!   little-endian; request and object ids are big-endian byte pairs.
//! - Alignment padding *inside* a payload is not checked and is written as
//!   zeros.
//! - Binary object representations and FRAGMENT bodies are opaque bytes;
//!   [`Message::reassembled`] decodes a submessage rebuilt from fragments.
//! - Decoding never panics and allocates no more than the input holds;
//!   errors name the field and its byte offset in the message.
//!
//! # The session machines
//! [`Client`] and [`Agent`] read no clock and touch no socket: messages
//! come in through `handle_input(.., now)`, time through
//! `handle_timeout(now)`, and out of `poll_transmit`, `poll_event` and
//! `poll_timeout`. Commands return request ids at once. A machine given
//! bytes it cannot use returns an [`InputError`] and goes on; what it holds
//! is bounded by its configuration (`buffered_bytes` tells how much).
//! On the wire the client is the eProsima client (`tests/xrce_replay.rs`
//! replays nine captures) and the agent is the eProsima agent
//! (`tests/xrce_agent_replay.rs`), except where noted below.
//!
//! ## Deviations from eProsima Micro XRCE-DDS 2.3.0
//! - Padding bytes are zeros; the eProsima client sends whatever its
//!   buffers held.
//! - The client postpones a HEARTBEAT whenever something arrives, as
//!   eProsima's session loop does, but never by more than two periods: a
//!   stream of incoming samples cannot keep a lost message from being
//!   announced.
//! - Fragments are cut as the window opens and rebuilt as they arrive, so
//!   a sample may take more fragments than the window holds (20 000 bytes
//!   in 41 fragments through a 16-message window). eProsima's client
//!   needs every fragment of a submessage in its input history at once:
//!   an agent sending it samples must keep them within history × MTU.
//! - A receiver NACKs only inside its window, and honours a HEARTBEAT
//!   whose first sequence number is past what it expects (the agent's
//!   rule; eProsima's client ignores it).
//! - The agent answers TIMESTAMP with one reading of its clock for both
//!   receive and transmit time, acknowledges a reliable message before its
//!   host has acted on it unless [`AgentConfig::host_confirms_writes`] (the
//!   [`bridge`] always sets it), refuses a best-effort sample larger than the
//!   client's MTU to its host instead of dropping it silently, and refuses
//!   CREATE_CLIENT with an MTU below [`AgentConfig::min_mtu`].

mod agent;
mod binary;
pub mod bridge;
mod client;
mod cursor;
pub mod discovery;
mod message;
mod object;
pub mod serial;
mod session;
#[cfg(feature = "sim")]
pub mod sim;
pub mod stream;
mod submessage;
pub mod tcp;
mod types;

pub use agent::{Agent, AgentCommandError, AgentConfig, AgentEvent, WriteTicket};
pub use binary::{
    qos_flags, BinaryRepresentation, DataReaderBinary, DataReaderQos, DataWriterBinary,
    EndpointQos, GroupBinary, GroupQos, ParticipantBinary, ServiceBinary, TopicBinary,
};
pub use client::{
    Client, ClientConfig, CommandError, ConnectError, CreationMode, Event, Keepalive, LostReason,
    ObjectDef, SampleIdentity, State, StatusError,
};
pub use session::{InputError, QueueError};
pub use stream::{FragmentError, SeqNum, StreamConfig, StreamError};

pub use message::{Message, MessageHeader, SESSION_ID_WITHOUT_CLIENT_KEY};
pub use object::{
    ActivityInfo, AgentRepresentation, ClientRepresentation, ObjectInfo, ObjectVariant,
    Representation,
};
pub use submessage::{
    flags, AckNack, Create, Data, DeliveryControl, GetInfo, Heartbeat, Info, Payload, ReadData,
    Status, StatusAgent, Submessage, SubmessageId, TimestampReply, SUBMESSAGE_HEADER_SIZE,
};
pub use types::{
    BaseObjectRequest, ClientKey, ObjectId, ObjectKind, Property, RequestId, ResultStatus,
    StatusCode, StreamId, Time, TransportLocator, COOKIE, VENDOR_EPROSIMA, VERSION,
};

/// Why bytes are not an XRCE message. Offsets count from the first byte
/// of the message.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum DecodeError {
    /// A field runs past the end of its submessage or message.
    #[error("XRCE {what} truncated at byte {offset}: {needed} byte(s) needed, {remaining} left")]
    Truncated {
        /// Offset of the field.
        offset: usize,
        /// Which field.
        what: &'static str,
        /// Bytes it needs.
        needed: usize,
        /// Bytes left.
        remaining: usize,
    },
    /// A submessage id outside 0x00–0x0F.
    #[error("unknown XRCE submessage id {id:#04x} at byte {offset}")]
    UnknownSubmessage {
        /// Offset of the submessage header.
        offset: usize,
        /// The id.
        id: u8,
    },
    /// The payload's fields end before the declared length does.
    #[error("XRCE {} at byte {offset} declares {declared} payload byte(s), its fields take {decoded}", .id.name())]
    LengthMismatch {
        /// Offset of the submessage header.
        offset: usize,
        /// The submessage.
        id: SubmessageId,
        /// `submessageLength`.
        declared: usize,
        /// Bytes its fields took.
        decoded: usize,
    },
    /// A field holds a value it cannot have (a boolean other than 0/1, an
    /// unknown object kind or representation format, an empty or
    /// unterminated string).
    #[error("invalid XRCE {what} {value:#x} at byte {offset}")]
    Invalid {
        /// Offset of the field.
        offset: usize,
        /// Which field.
        what: &'static str,
        /// Its value.
        value: u64,
    },
    /// A string that is not UTF-8.
    #[error("XRCE {what} at byte {offset} is not UTF-8")]
    NotUtf8 {
        /// Offset of the string's bytes.
        offset: usize,
        /// Which field.
        what: &'static str,
    },
}

/// Why a message or frame cannot be encoded.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum EncodeError {
    /// A session id below 0x80 needs the client key in the header.
    #[error("XRCE session id {0:#04x} is below 0x80: the header needs a client key")]
    MissingClientKey(u8),
    /// A session id of 0x80 or above has no client key in the header.
    #[error("XRCE session id {0:#04x} is 0x80 or above: the header carries no client key")]
    UnexpectedClientKey(u8),
    /// A length does not fit its field.
    #[error("XRCE {what} is {len} bytes, more than the {max} its length field allows")]
    TooLong {
        /// What was too long.
        what: &'static str,
        /// Its length.
        len: usize,
        /// The largest length allowed.
        max: usize,
    },
}
