//! XRCE streams (`protocols/xrce.md` §8, §10): sequence numbers with
//! serial arithmetic, best-effort and reliable output and input streams,
//! HEARTBEAT/ACKNACK bookkeeping, retransmission and FRAGMENT in both
//! directions. Both the client ([`Client`](super::Client)) and the agent
//! ([`Agent`](super::Agent)) are built from these.
//!
//! Rules (from eProsima Micro XRCE-DDS Client/Agent 2.3.0):
//! - every stream starts with "last" = 0xFFFF, so its first message is
//!   sequence 0; "a before b" is serial-number comparison with a window of
//!   2^15 ([`SeqNum::serial_cmp`]);
//! - a best-effort receiver takes a message only if it is newer than the
//!   last one it took: old and duplicate messages are dropped;
//! - a reliable sender holds at most `depth` unacknowledged messages, sends
//!   a HEARTBEAT (first/last unacked) while any is unacknowledged, and
//!   resends the sequence numbers an ACKNACK's bitmap names (the client:
//!   every unacknowledged one when the bitmap names any);
//! - a reliable receiver accepts messages in `(last_handled, last_handled +
//!   depth]`, holds those that come early and hands them on in order; its
//!   ACKNACK names the first missing sequence number and a 16-bit bitmap of
//!   the missing ones up to the highest it has heard of;
//! - a submessage larger than a message is cut into FRAGMENT submessages,
//!   one per message, the last flagged; the receiver rebuilds it behind the
//!   header of the message that carried the first fragment. Fragments are
//!   cut as the window opens, and reassembled as they arrive in order, so a
//!   sample may need more fragments than the window holds; reassembly is
//!   bounded by [`StreamConfig::max_reassembly`].

use std::cmp::Ordering;
use std::time::Duration;

use super::message::MessageHeader;
use super::types::{ObjectId, StreamId};
use super::DecodeError;

mod input;
mod output;

pub use input::{BestEffortInput, Received, ReliableInput};
pub use output::{BestEffortOutput, ReliableOutput};

/// A stream sequence number: u16, compared with serial-number arithmetic
/// over a window of 2^15 (`uxr_seq_num_cmp`, the agent's `SeqNum`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct SeqNum(pub u16);

impl SeqNum {
    /// The value every stream starts from as "last": its first message is 0.
    pub const INITIAL_LAST: SeqNum = SeqNum(u16::MAX);

    /// `self + n`, wrapping.
    pub fn wrapping_add(self, n: u16) -> SeqNum {
        SeqNum(self.0.wrapping_add(n))
    }

    /// `self - n`, wrapping.
    pub fn wrapping_sub(self, n: u16) -> SeqNum {
        SeqNum(self.0.wrapping_sub(n))
    }

    /// How many steps `self` is after `earlier`, wrapping (0 when equal).
    pub fn since(self, earlier: SeqNum) -> u16 {
        self.0.wrapping_sub(earlier.0)
    }

    /// Serial-number order: `self` is before `other` when `other` is 1 to
    /// 2^15 − 1 steps ahead of it.
    pub fn serial_cmp(self, other: SeqNum) -> Ordering {
        match other.since(self) {
            0 => Ordering::Equal,
            d if d < 0x8000 => Ordering::Less,
            _ => Ordering::Greater,
        }
    }

    /// Whether `self` comes after `other` in serial order.
    pub fn is_after(self, other: SeqNum) -> bool {
        self.serial_cmp(other) == Ordering::Greater
    }
}

/// How long Courier's client and agent hold an ACKNACK
/// ([`StreamConfig::delayed_acks`]).
pub const DELAYED_ACK: Duration = Duration::from_millis(2);

/// Sizes, windows and timing of a session's streams.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StreamConfig {
    /// The largest message sent (header included). The eProsima client
    /// advertises its transport MTU minus 4 (508 over 512), and the agent
    /// cuts its messages to what the client advertised.
    pub mtu: usize,
    /// Reliable window: unacknowledged messages a sender holds, and how far
    /// ahead of the next expected message a receiver accepts (16 in the
    /// agent; the client's history).
    pub depth: u16,
    /// Pack several submessages into one message while they fit (the
    /// eProsima client does; its agent sends one submessage per message).
    pub pack: bool,
    /// Pad every submessage to 4 bytes, the last one too, as the eProsima
    /// client does (its agent does not).
    pub pad: bool,
    /// Bytes an output stream queues beyond its window before refusing.
    pub max_backlog: usize,
    /// The largest submessage rebuilt from fragments.
    pub max_reassembly: usize,
    /// How often a reliable sender repeats its HEARTBEAT while messages are
    /// unacknowledged (client 100 ms, agent 200 ms).
    pub heartbeat_period: Duration,
    /// Postpone the next HEARTBEAT whenever something arrives, as the
    /// eProsima client's session loop does, but never past two periods.
    pub heartbeat_slides: bool,
    /// On an ACKNACK naming any missing message, send again every
    /// unacknowledged one, as the eProsima client does; otherwise (the
    /// agent) exactly those the bitmap names.
    pub nack_resends_all: bool,
    /// Delayed acknowledgement: `None` (eProsima's client and agent) sends
    /// an ACKNACK for every reliable message at once. `Some(d)` holds it up
    /// to `d`, so that one ACKNACK covers several messages; it still goes
    /// at once on a gap, a duplicate, a HEARTBEAT, or when half a window is
    /// unacknowledged (so a sender never waits for its window, and loss is
    /// reported as soon as it is seen). Keep `d` well below the peer's
    /// HEARTBEAT period (100 ms for eProsima's client, 200 ms its agent).
    pub ack_delay: Option<Duration>,
    /// A peer that has acknowledged nothing for this long while messages
    /// wait for it is taken for gone (a client that died without DELETE)
    /// and gets a HEARTBEAT only every [`SILENT_HEARTBEAT`] until it
    /// answers: a HEARTBEAT every period to each of a thousand dead
    /// clients kept an agent busy for ever. `None` (the client's): the
    /// period always. The agent's: 30 s, MicroXRCEAgent's
    /// `CLIENT_DEAD_TIME` (which stops HEARTBEATs to such a client
    /// altogether; a client that comes back would then never learn what
    /// it missed).
    pub silent_after: Option<Duration>,
}

/// How often a peer silent for [`StreamConfig::silent_after`] gets a
/// HEARTBEAT.
pub const SILENT_HEARTBEAT: Duration = Duration::from_secs(5);

impl StreamConfig {
    /// The eProsima client's settings: MTU 508, window 16, packing and
    /// padding, HEARTBEAT every 100 ms after the last input.
    pub fn client() -> Self {
        StreamConfig {
            mtu: 508,
            depth: 16,
            pack: true,
            pad: true,
            max_backlog: 1 << 20,
            max_reassembly: 1 << 20,
            heartbeat_period: Duration::from_millis(100),
            heartbeat_slides: true,
            nack_resends_all: true,
            ack_delay: None,
            silent_after: None,
        }
    }

    /// The same with Courier's delayed acknowledgement
    /// ([`StreamConfig::ack_delay`] of [`DELAYED_ACK`]), which Courier's
    /// client and agent use: one ACKNACK per half window or per 2 ms
    /// instead of one per message, so that a reliable round trip is not
    /// two more datagrams (and wake-ups) per hop. eProsima's peers accept
    /// it: an ACKNACK is a statement of the receiver's state whenever it
    /// comes, and it comes well within their HEARTBEAT periods.
    pub fn delayed_acks(self) -> Self {
        StreamConfig {
            ack_delay: Some(DELAYED_ACK),
            ..self
        }
    }

    /// The eProsima agent's settings: window 16, one unpadded submessage per
    /// message, HEARTBEAT every 200 ms. The MTU is the client's.
    pub fn agent() -> Self {
        StreamConfig {
            pack: false,
            pad: false,
            heartbeat_period: Duration::from_millis(200),
            heartbeat_slides: false,
            nack_resends_all: false,
            silent_after: Some(Duration::from_secs(30)),
            ..Self::client()
        }
    }
}

/// Why an output stream refused a submessage.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum StreamError {
    /// The stream's queue is full; try again once the peer acknowledges.
    #[error("XRCE stream {stream:#04x}: {len} more byte(s) would pass its backlog limit of {max}")]
    Backlog {
        /// The stream.
        stream: u8,
        /// Bytes refused.
        len: usize,
        /// The limit.
        max: usize,
    },
    /// A reliable stream's submessage larger than all it may queue: it can
    /// never go (waiting for room would wait forever).
    #[error(
        "XRCE reliable stream {stream:#04x}: a {len}-byte submessage is larger than the {max} bytes the stream may queue (raise the session's history= or mtu=)"
    )]
    NeverFits {
        /// The stream.
        stream: u8,
        /// Submessage size.
        len: usize,
        /// The most the stream queues.
        max: usize,
    },
    /// Best-effort streams do not fragment.
    #[error("XRCE best-effort stream {stream:#04x}: a {len}-byte submessage does not fit a {max}-byte message")]
    TooLarge {
        /// The stream.
        stream: u8,
        /// Submessage size with its header.
        len: usize,
        /// Largest submessage a message holds.
        max: usize,
    },
}

/// Why fragments could not be put back together. The partial submessage
/// is dropped; the stream goes on with the next one.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum FragmentError {
    /// FRAGMENT outside a reliable stream.
    #[error("XRCE FRAGMENT on stream {0:#04x}, which is not reliable")]
    NotReliable(u8),
    /// A fragment that is not the last is followed by another submessage.
    #[error("XRCE FRAGMENT that is not the last one is followed by another submessage")]
    NotLastInMessage,
    /// A complete submessage arrived while fragments were being collected.
    #[error("XRCE {0} arrived in the middle of a fragmented submessage")]
    Interleaved(&'static str),
    /// The rebuilt submessage would pass the limit.
    #[error("XRCE fragments add up to more than the {max} bytes allowed")]
    TooLarge {
        /// [`StreamConfig::max_reassembly`].
        max: usize,
        /// The object the submessage was for when it is a DATA (the
        /// reader: the sample is lost to it) or a WRITE_DATA (the writer),
        /// as its first fragment says.
        object: Option<ObjectId>,
    },
    /// The rebuilt bytes are not a submessage.
    #[error("XRCE reassembled submessage: {0}")]
    Decode(DecodeError),
    /// The rebuilt submessage holds a FRAGMENT itself.
    #[error("XRCE reassembled submessage is itself a FRAGMENT")]
    Nested,
}

fn align4(n: usize) -> usize {
    (n + 3) & !3
}

/// The header bytes of a stream's messages: session id, stream id,
/// sequence number (patched per message), client key when the session id
/// is below 0x80.
fn header_bytes(session: &MessageHeader, stream: StreamId) -> Vec<u8> {
    let mut v = vec![session.session_id, stream.0, 0, 0];
    if let Some(k) = session.client_key {
        v.extend_from_slice(&k.0);
    }
    v
}

fn set_seq(message: &mut [u8], seq: SeqNum) {
    if let Some(s) = message.get_mut(2..4) {
        s.copy_from_slice(&seq.0.to_le_bytes());
    }
}

/// Appends `bytes` to a message, aligning the submessage to 4 first.
fn append(message: &mut Vec<u8>, bytes: &[u8]) {
    message.resize(align4(message.len()), 0);
    message.extend_from_slice(bytes);
}
