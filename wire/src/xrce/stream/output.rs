//! Output streams: best-effort (numbered, sent once) and reliable
//! (window, packing, fragmentation, HEARTBEAT, retransmission).

use std::collections::VecDeque;
use std::time::Instant;

use super::super::message::MessageHeader;
use super::super::submessage::{flags, AckNack, Heartbeat, SubmessageId};
use super::super::types::StreamId;
use super::{align4, append, header_bytes, set_seq, SeqNum, StreamConfig, StreamError};

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
        self.last_sent = self.last_sent.wrapping_add(1);
        set_seq(&mut m, self.last_sent);
        Some(m)
    }

    /// Bytes queued.
    pub fn buffered(&self) -> usize {
        self.queued
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
    /// Since when messages have waited for the peer with no ACKNACK from
    /// it (`None`: nothing waits). See [`StreamConfig::silent_after`].
    unanswered_since: Option<Instant>,
    acked: VecDeque<u16>,
    /// The peer's position is unknown (the session was restored): the
    /// first ACKNACK says it.
    resync: bool,
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
            unanswered_since: None,
            acked: VecDeque::new(),
            resync: false,
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
        if sub.len() > self.cfg.max_backlog {
            return Err(StreamError::NeverFits {
                stream: self.id.0,
                len: sub.len(),
                max: self.cfg.max_backlog,
            });
        }
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
        self.last_acked.wrapping_add(self.sent as u16)
    }

    /// The last sequence number acknowledged.
    pub fn last_acked(&self) -> SeqNum {
        self.last_acked
    }

    /// Bytes held: messages not yet acknowledged and submessages queued.
    pub fn buffered(&self) -> usize {
        self.backlog_bytes + self.slots.iter().map(|s| s.bytes.len()).sum::<usize>()
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
        let seq = self.last_sent().wrapping_add(1);
        let slot = self.slots.get_mut(self.sent)?;
        set_seq(&mut slot.bytes, seq);
        let bytes = slot.bytes.clone();
        self.sent += 1;
        self.unanswered_since.get_or_insert(now);
        match self.hb_deadline {
            None => self.arm_heartbeat(now),
            Some(_) => self.touch(now),
        }
        Some(bytes)
    }

    fn arm_heartbeat(&mut self, now: Instant) {
        self.hb_base = Some(now);
        self.hb_deadline = Some(crate::time::later(now, self.heartbeat_period(now)));
    }

    /// Whether messages have waited for the peer for
    /// [`StreamConfig::silent_after`] with no ACKNACK from it.
    pub fn is_silent(&self, now: Instant) -> bool {
        match (self.cfg.silent_after, self.unanswered_since) {
            (Some(after), Some(since)) => now.saturating_duration_since(since) >= after,
            _ => false,
        }
    }

    /// Drops the submessages queued beyond the window, never sent (and so
    /// no gap for the peer), except those with a tag (whose fate someone
    /// waits for) and one partly cut into fragments already: how many.
    pub fn drop_unsent(&mut self) -> usize {
        let before = self.backlog.len();
        self.backlog.retain(|p| p.tag.is_some() || p.cut > 0);
        self.backlog_bytes = self.backlog.iter().map(|p| p.bytes.len()).sum();
        before - self.backlog.len()
    }

    /// The HEARTBEAT period, or [`SILENT_HEARTBEAT`](super::SILENT_HEARTBEAT)
    /// for a peer silent past [`StreamConfig::silent_after`].
    fn heartbeat_period(&self, now: Instant) -> std::time::Duration {
        if self.is_silent(now) {
            super::SILENT_HEARTBEAT.max(self.cfg.heartbeat_period)
        } else {
            self.cfg.heartbeat_period
        }
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
                self.hb_deadline = Some(
                    crate::time::later(now, p)
                        .min(crate::time::later(base, p.saturating_mul(2)))
                        .max(d),
                );
            }
        }
    }

    /// An ACKNACK for this stream: everything before `first_unacked` is
    /// acknowledged; the bitmap's sequence numbers are sent again. An
    /// ACKNACK of messages never sent is ignored; an old one only re-arms
    /// the heartbeat.
    pub fn on_acknack(&mut self, ack: &AckNack, now: Instant) {
        self.take_acknack(ack, now);
        // the peer is there, whatever the ACKNACK said: what still waits
        // for it waits from now
        self.unanswered_since = (self.sent > 0).then_some(now);
    }

    fn take_acknack(&mut self, ack: &AckNack, now: Instant) {
        let first = SeqNum(ack.first_unacked);
        let newly = usize::from(first.wrapping_sub(1).since(self.last_acked));
        if std::mem::take(&mut self.resync) && newly > self.sent {
            // a restored session: the peer expects `first` next, so what
            // was sent is numbered from there and sent again
            self.last_acked = first.wrapping_sub(1);
            for i in 0..self.sent {
                let seq = first.wrapping_add(i as u16);
                if let Some(s) = self.slots.get_mut(i) {
                    set_seq(&mut s.bytes, seq);
                }
                self.resend.push_back(seq);
            }
            return;
        }
        if newly <= self.sent {
            for _ in 0..newly {
                if let Some(s) = self.slots.pop_front() {
                    self.acked.extend(s.tags);
                }
                self.last_acked = self.last_acked.wrapping_add(1);
                self.sent -= 1;
            }
        } else if newly < 0x8000 {
            return; // acknowledges what was never sent
        }
        let bits = ack.nack_bits();
        let all = self.cfg.nack_resends_all && bits != 0;
        let count = if all { self.sent as u16 } else { 16 };
        let from = if all {
            self.last_acked.wrapping_add(1)
        } else {
            first
        };
        for i in 0..count {
            if all || bits & (1 << i) != 0 {
                let seq = from.wrapping_add(i);
                let sent = self.slot_index(seq).is_some_and(|j| j < self.sent);
                if sent && !self.resend.contains(&seq) {
                    self.resend.push_back(seq);
                }
            }
        }
        if self.sent > 0 {
            self.unanswered_since = Some(now);
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
            self.unanswered_since = None;
            return None;
        }
        self.arm_heartbeat(now);
        Some(Heartbeat {
            first_unacked: self.last_acked.wrapping_add(1).0,
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
    /// The session was restored without this stream's position: the
    /// peer's first ACKNACK, whatever it acknowledges, sets the numbering
    /// (what was sent meanwhile is numbered from it and sent again).
    pub fn set_resync(&mut self) {
        self.resync = true;
    }

    /// Tags of the submessages acknowledged since the last call.
    pub fn take_acked(&mut self) -> impl Iterator<Item = u16> + '_ {
        self.acked.drain(..)
    }
}
