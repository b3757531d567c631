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
use std::collections::{BTreeMap, VecDeque};
use std::time::{Duration, Instant};

use super::message::{Message, MessageHeader};
use super::submessage::{flags, AckNack, Heartbeat, Payload, Submessage, SubmessageId};
use super::types::StreamId;
use super::DecodeError;

/// A stream sequence number: u16, compared with serial-number arithmetic
/// over a window of 2^15 (`uxr_seq_num_cmp`, the agent's `SeqNum`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct SeqNum(pub u16);

impl SeqNum {
    /// The value every stream starts from as "last": its first message is 0.
    pub const INITIAL_LAST: SeqNum = SeqNum(u16::MAX);

    /// `self + n`, wrapping.
    pub fn add(self, n: u16) -> SeqNum {
        SeqNum(self.0.wrapping_add(n))
    }

    /// `self - n`, wrapping.
    pub fn sub(self, n: u16) -> SeqNum {
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
}

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

/// A best-effort output stream: messages numbered from 0, sent once.
#[derive(Debug, Clone)]
pub struct BestEffortOutput {
    header: Vec<u8>,
    cfg: StreamConfig,
    last_sent: SeqNum,
    open: Option<Vec<u8>>,
    ready: VecDeque<Vec<u8>>,
    queued: usize,
}

impl BestEffortOutput {
    /// Stream `id` of the session whose messages carry `session`'s header.
    pub fn new(session: &MessageHeader, id: StreamId, cfg: StreamConfig) -> Self {
        BestEffortOutput {
            header: header_bytes(session, id),
            cfg,
            last_sent: SeqNum::INITIAL_LAST,
            open: None,
            ready: VecDeque::new(),
            queued: 0,
        }
    }

    /// Queues an encoded submessage (header and payload).
    pub fn push(&mut self, sub: &[u8]) -> Result<(), StreamError> {
        let stream = self.header.get(1).copied().unwrap_or(0);
        let max = self.cfg.mtu.saturating_sub(self.header.len());
        if sub.len() > max {
            return Err(StreamError::TooLarge {
                stream,
                len: sub.len(),
                max,
            });
        }
        if self.queued + sub.len() > self.cfg.max_backlog {
            return Err(StreamError::Backlog {
                stream,
                len: sub.len(),
                max: self.cfg.max_backlog,
            });
        }
        self.queued += sub.len();
        if let Some(open) = &mut self.open {
            if self.cfg.pack && align4(open.len()) + sub.len() <= self.cfg.mtu {
                append(open, sub);
                return Ok(());
            }
        }
        let mut m = self.header.clone();
        m.extend_from_slice(sub);
        if let Some(done) = self.open.replace(m) {
            self.ready.push_back(done);
        }
        Ok(())
    }

    /// The next message to send, numbered.
    pub fn poll_transmit(&mut self) -> Option<Vec<u8>> {
        let mut m = self.ready.pop_front().or_else(|| self.open.take())?;
        self.queued = self.queued.saturating_sub(m.len() - self.header.len());
        self.last_sent = self.last_sent.add(1);
        set_seq(&mut m, self.last_sent);
        Some(m)
    }

    /// Whether nothing is queued.
    pub fn is_empty(&self) -> bool {
        self.open.is_none() && self.ready.is_empty()
    }
}

/// One message of a reliable output stream.
#[derive(Debug, Clone)]
struct Slot {
    bytes: Vec<u8>,
    /// Tags of the submessages that end in this message.
    tags: Vec<u16>,
}

/// A submessage waiting for room in the window.
#[derive(Debug, Clone)]
struct Pending {
    bytes: Vec<u8>,
    /// Bytes already cut into fragments.
    cut: usize,
    tag: Option<u16>,
}

/// A reliable output stream.
#[derive(Debug, Clone)]
pub struct ReliableOutput {
    id: StreamId,
    header: Vec<u8>,
    cfg: StreamConfig,
    /// Everything up to here is acknowledged.
    last_acked: SeqNum,
    /// `slots[i]` has sequence number `last_acked + 1 + i`.
    slots: VecDeque<Slot>,
    /// How many of `slots` were sent (a prefix).
    sent: usize,
    backlog: VecDeque<Pending>,
    backlog_bytes: usize,
    resend: VecDeque<SeqNum>,
    hb_deadline: Option<Instant>,
    hb_base: Option<Instant>,
    acked: VecDeque<u16>,
}

impl ReliableOutput {
    /// Stream `id` of the session whose messages carry `session`'s header.
    pub fn new(session: &MessageHeader, id: StreamId, cfg: StreamConfig) -> Self {
        ReliableOutput {
            id,
            header: header_bytes(session, id),
            cfg,
            last_acked: SeqNum::INITIAL_LAST,
            slots: VecDeque::new(),
            sent: 0,
            backlog: VecDeque::new(),
            backlog_bytes: 0,
            resend: VecDeque::new(),
            hb_deadline: None,
            hb_base: None,
            acked: VecDeque::new(),
        }
    }

    /// The stream id.
    pub fn id(&self) -> StreamId {
        self.id
    }

    /// Queues an encoded submessage; `tag` (a request id) is reported by
    /// [`take_acked`](Self::take_acked) once every byte of it is
    /// acknowledged.
    pub fn push(&mut self, sub: Vec<u8>, tag: Option<u16>) -> Result<(), StreamError> {
        if self.backlog_bytes + sub.len() > self.cfg.max_backlog {
            return Err(StreamError::Backlog {
                stream: self.id.0,
                len: sub.len(),
                max: self.cfg.max_backlog,
            });
        }
        self.push_unchecked(sub, tag);
        Ok(())
    }

    /// [`push`](Self::push) without the backlog limit (for submessages
    /// already accepted once, queued again after a session reset).
    pub fn push_unchecked(&mut self, sub: Vec<u8>, tag: Option<u16>) {
        self.backlog_bytes += sub.len();
        self.backlog.push_back(Pending {
            bytes: sub,
            cut: 0,
            tag,
        });
    }

    /// The last sequence number sent.
    pub fn last_sent(&self) -> SeqNum {
        self.last_acked.add(self.sent as u16)
    }

    /// The last sequence number acknowledged.
    pub fn last_acked(&self) -> SeqNum {
        self.last_acked
    }

    /// Whether nothing is queued, unsent or unacknowledged.
    pub fn is_idle(&self) -> bool {
        self.slots.is_empty() && self.backlog.is_empty()
    }

    fn window_open(&self) -> bool {
        self.slots.len() < usize::from(self.cfg.depth)
    }

    fn new_slot(&mut self) -> Option<&mut Slot> {
        self.slots.push_back(Slot {
            bytes: self.header.clone(),
            tags: Vec::new(),
        });
        self.slots.back_mut()
    }

    /// The unsent last slot, when submessages may still be packed into it.
    fn open_len(&self) -> Option<usize> {
        (self.cfg.pack && self.slots.len() > self.sent)
            .then(|| self.slots.back().map(|s| s.bytes.len()))
            .flatten()
    }

    /// Moves queued submessages into messages while the window has room,
    /// packing and fragmenting them.
    fn fill(&mut self) {
        let mtu = self.cfg.mtu;
        let hlen = self.header.len();
        while let Some(p) = self.backlog.front() {
            let rest = p.bytes.len().saturating_sub(p.cut);
            let whole = p.cut == 0;
            let open = self.open_len();
            if whole && open.is_some_and(|l| align4(l) + rest <= mtu) {
                self.place(true, None);
                continue;
            }
            if whole && hlen + rest <= mtu {
                if !self.window_open() {
                    return;
                }
                self.place(false, None);
                continue;
            }
            // a fragment: the first one may share the open message
            let (into_open, room) = match open {
                Some(l) if whole && align4(l) + 4 < mtu => (true, mtu - align4(l) - 4),
                _ if self.window_open() && hlen + 4 < mtu => (false, mtu - hlen - 4),
                _ => return,
            };
            self.place(into_open, Some(room.min(rest)));
        }
    }

    /// Puts the front of the backlog, whole or its next `fragment` bytes
    /// as a FRAGMENT, into the open message or a new one.
    fn place(&mut self, into_open: bool, fragment: Option<usize>) {
        let (piece, done) = match fragment {
            None => match self.backlog.front() {
                Some(p) => (p.bytes.clone(), true),
                None => return,
            },
            Some(n) => {
                let Some(p) = self.backlog.front_mut() else {
                    return;
                };
                let chunk = p.bytes.get(p.cut..p.cut + n).unwrap_or(&[]);
                let last = p.cut + n >= p.bytes.len();
                let flag = if last { flags::LAST_FRAGMENT } else { 0 };
                let mut sub = vec![SubmessageId::Fragment as u8, flags::LITTLE_ENDIAN | flag];
                sub.extend_from_slice(&(chunk.len() as u16).to_le_bytes());
                sub.extend_from_slice(chunk);
                p.cut += n;
                (sub, last)
            }
        };
        let slot = if into_open {
            self.slots.back_mut()
        } else {
            self.new_slot()
        };
        if let Some(slot) = slot {
            append(&mut slot.bytes, &piece);
        }
        if done {
            self.finish_front();
        }
    }

    /// The front of the backlog is all in messages: tag its last one.
    fn finish_front(&mut self) {
        if let Some(p) = self.backlog.pop_front() {
            self.backlog_bytes = self.backlog_bytes.saturating_sub(p.bytes.len());
            if let (Some(tag), Some(slot)) = (p.tag, self.slots.back_mut()) {
                slot.tags.push(tag);
            }
        }
    }

    fn slot_index(&self, seq: SeqNum) -> Option<usize> {
        let d = usize::from(seq.since(self.last_acked));
        d.checked_sub(1).filter(|&i| i < self.slots.len())
    }

    /// The next message to send: a retransmission asked for by an ACKNACK,
    /// else the next new one the window allows.
    pub fn poll_transmit(&mut self, now: Instant) -> Option<Vec<u8>> {
        while let Some(seq) = self.resend.pop_front() {
            if let Some(i) = self.slot_index(seq).filter(|&i| i < self.sent) {
                if let Some(s) = self.slots.get(i) {
                    return Some(s.bytes.clone());
                }
            }
        }
        self.fill();
        let seq = self.last_sent().add(1);
        let slot = self.slots.get_mut(self.sent)?;
        set_seq(&mut slot.bytes, seq);
        let bytes = slot.bytes.clone();
        self.sent += 1;
        match self.hb_deadline {
            None => self.arm_heartbeat(now),
            Some(_) => self.touch(now),
        }
        Some(bytes)
    }

    fn arm_heartbeat(&mut self, now: Instant) {
        self.hb_base = Some(now);
        self.hb_deadline = Some(now + self.cfg.heartbeat_period);
    }

    /// Something arrived from the peer (or was sent): with
    /// [`StreamConfig::heartbeat_slides`] the next HEARTBEAT moves to one
    /// period from now, but no later than two periods after the last.
    pub fn touch(&mut self, now: Instant) {
        if !self.cfg.heartbeat_slides {
            return;
        }
        if let (Some(d), Some(base)) = (self.hb_deadline, self.hb_base) {
            if d > now {
                let p = self.cfg.heartbeat_period;
                self.hb_deadline = Some((now + p).min(base + 2 * p).max(d));
            }
        }
    }

    /// An ACKNACK for this stream: everything before `first_unacked` is
    /// acknowledged; the bitmap's sequence numbers are sent again. An
    /// ACKNACK of messages never sent is ignored; an old one only re-arms
    /// the heartbeat.
    pub fn on_acknack(&mut self, ack: &AckNack, now: Instant) {
        let first = SeqNum(ack.first_unacked);
        let newly = usize::from(first.sub(1).since(self.last_acked));
        if newly <= self.sent {
            for _ in 0..newly {
                if let Some(s) = self.slots.pop_front() {
                    self.acked.extend(s.tags);
                }
                self.last_acked = self.last_acked.add(1);
                self.sent -= 1;
            }
        } else if newly < 0x8000 {
            return; // acknowledges what was never sent
        }
        let bits = ack.nack_bits();
        let all = self.cfg.nack_resends_all && bits != 0;
        let count = if all { self.sent as u16 } else { 16 };
        let from = if all { self.last_acked.add(1) } else { first };
        for i in 0..count {
            if all || bits & (1 << i) != 0 {
                let seq = from.add(i);
                let sent = self.slot_index(seq).is_some_and(|j| j < self.sent);
                if sent && !self.resend.contains(&seq) {
                    self.resend.push_back(seq);
                }
            }
        }
        if self.sent > 0 {
            self.arm_heartbeat(now);
        } else {
            self.hb_deadline = None;
        }
    }

    /// A HEARTBEAT when one is due: the range of sent messages not yet
    /// acknowledged.
    pub fn poll_heartbeat(&mut self, now: Instant) -> Option<Heartbeat> {
        if self.hb_deadline.is_none_or(|d| d > now) {
            return None;
        }
        if self.sent == 0 {
            self.hb_deadline = None;
            return None;
        }
        self.arm_heartbeat(now);
        Some(Heartbeat {
            first_unacked: self.last_acked.add(1).0,
            last_unacked: self.last_sent().0,
            stream_id: self.id,
        })
    }

    /// When the next HEARTBEAT is due.
    pub fn poll_timeout(&self) -> Option<Instant> {
        self.hb_deadline.filter(|_| self.sent > 0)
    }

    /// Whether a message is ready to go now.
    pub fn has_transmit(&self) -> bool {
        !self.resend.is_empty()
            || self.slots.len() > self.sent
            || (!self.backlog.is_empty() && self.window_open())
    }

    /// Tags of submessages acknowledged since the last call, in order.
    pub fn take_acked(&mut self) -> impl Iterator<Item = u16> + '_ {
        self.acked.drain(..)
    }
}

/// A best-effort input stream.
#[derive(Debug, Clone)]
pub struct BestEffortInput {
    last: SeqNum,
}

impl Default for BestEffortInput {
    fn default() -> Self {
        BestEffortInput {
            last: SeqNum::INITIAL_LAST,
        }
    }
}

impl BestEffortInput {
    /// Whether to take message `seq`: only if it is newer than the last taken.
    pub fn accept(&mut self, seq: SeqNum) -> bool {
        let take = seq.is_after(self.last);
        if take {
            self.last = seq;
        }
        take
    }
}

/// What a reliable input stream did with a message.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Received {
    /// Kept, to be handed on in order.
    Accepted,
    /// Already handled or already held.
    Duplicate,
    /// Too far ahead of the window.
    OutOfWindow,
}

#[derive(Debug, Clone)]
struct Reassembly {
    header: MessageHeader,
    buf: Vec<u8>,
    overflow: bool,
}

/// A reliable input stream: window, in-order hand-over, ACKNACK and
/// fragment reassembly.
#[derive(Debug, Clone)]
pub struct ReliableInput {
    id: StreamId,
    cfg: StreamConfig,
    last_handled: SeqNum,
    last_announced: SeqNum,
    held: BTreeMap<u16, Message>,
    reassembly: Option<Reassembly>,
}

impl ReliableInput {
    /// Input stream `id`.
    pub fn new(id: StreamId, cfg: StreamConfig) -> Self {
        ReliableInput {
            id,
            cfg,
            last_handled: SeqNum::INITIAL_LAST,
            last_announced: SeqNum::INITIAL_LAST,
            held: BTreeMap::new(),
            reassembly: None,
        }
    }

    /// The last message handed on.
    pub fn last_handled(&self) -> SeqNum {
        self.last_handled
    }

    /// Takes message `seq` if it is inside the window and new.
    pub fn receive(&mut self, seq: SeqNum, message: Message) -> Received {
        let d = seq.since(self.last_handled);
        if d == 0 || d >= 0x8000 {
            return Received::Duplicate;
        }
        if d > self.cfg.depth {
            return Received::OutOfWindow;
        }
        if self.held.contains_key(&seq.0) {
            return Received::Duplicate;
        }
        self.held.insert(seq.0, message);
        if seq.is_after(self.last_announced) {
            self.last_announced = seq;
        }
        Received::Accepted
    }

    /// The next message in order, if it is here.
    pub fn next_message(&mut self) -> Option<Message> {
        let next = self.last_handled.add(1);
        let m = self.held.remove(&next.0)?;
        self.last_handled = next;
        Some(m)
    }

    /// A HEARTBEAT from the sender: it holds `first..=last`. Messages the
    /// sender no longer holds are skipped (as the agent does); `last` tells
    /// how far to NACK (at most one window ahead).
    pub fn on_heartbeat(&mut self, hb: &Heartbeat) {
        let first = SeqNum(hb.first_unacked);
        if first.is_after(self.last_handled.add(1)) && first.since(self.last_handled) < 0x8000 {
            self.last_handled = first.sub(1);
            let keep: BTreeMap<u16, Message> = std::mem::take(&mut self.held)
                .into_iter()
                .filter(|(s, _)| SeqNum(*s).is_after(self.last_handled))
                .collect();
            self.held = keep;
            self.reassembly = None;
            if self.last_handled.is_after(self.last_announced) {
                self.last_announced = self.last_handled;
            }
        }
        let last = SeqNum(hb.last_unacked);
        let limit = self.last_handled.add(self.cfg.depth);
        let last = if last.is_after(limit) { limit } else { last };
        if last.is_after(self.last_announced) {
            self.last_announced = last;
        }
    }

    /// The ACKNACK describing this stream now.
    pub fn acknack(&self) -> AckNack {
        let first = self.last_handled.add(1);
        let known = self.last_announced.since(self.last_handled);
        let mut bits = 0u16;
        for i in 0..16u16 {
            if i < known && known < 0x8000 && !self.held.contains_key(&first.add(i).0) {
                bits |= 1 << i;
            }
        }
        let mut a = AckNack {
            first_unacked: first.0,
            nack_bitmap: [0; 2],
            stream_id: self.id,
        };
        a.set_nack_bits(bits);
        a
    }

    /// The submessages of a message handed on in order, with FRAGMENTs
    /// rebuilt: complete submessages come out as they are, fragments are
    /// collected until the last one. Problems are pushed to `errors` and
    /// the rest goes on.
    pub fn unpack(&mut self, message: Message, errors: &mut Vec<FragmentError>) -> Vec<Submessage> {
        let mut out = Vec::new();
        let n = message.submessages.len();
        for (i, s) in message.submessages.into_iter().enumerate() {
            let last_fragment = s.is_last_fragment();
            let Payload::Fragment(body) = s.payload else {
                if self.reassembly.take().is_some() {
                    errors.push(FragmentError::Interleaved(s.id().name()));
                }
                out.push(s);
                continue;
            };
            if !last_fragment && i + 1 != n {
                self.reassembly = None;
                errors.push(FragmentError::NotLastInMessage);
                continue;
            }
            let max = self.cfg.max_reassembly;
            let r = self.reassembly.get_or_insert_with(|| Reassembly {
                header: message.header,
                buf: Vec::new(),
                overflow: false,
            });
            if !r.overflow {
                if r.buf.len() + body.len() > max {
                    r.overflow = true;
                    r.buf = Vec::new();
                    errors.push(FragmentError::TooLarge { max });
                } else {
                    r.buf.extend_from_slice(&body);
                }
            }
            if last_fragment {
                if let Some(r) = self.reassembly.take().filter(|r| !r.overflow) {
                    match Message::reassembled(&r.header, &r.buf) {
                        Ok(m) => {
                            for sub in m.submessages {
                                if sub.id() == SubmessageId::Fragment {
                                    errors.push(FragmentError::Nested);
                                } else {
                                    out.push(sub);
                                }
                            }
                        }
                        Err(e) => errors.push(FragmentError::Decode(e)),
                    }
                }
            }
        }
        out
    }
}
