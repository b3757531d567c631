//! Input streams: best-effort (newer only) and reliable (window,
//! in-order hand-over, ACKNACK, reassembly).

use std::collections::BTreeMap;
use std::time::Instant;

use super::super::message::{Message, MessageHeader};
use super::super::submessage::{AckNack, Heartbeat, Payload, Submessage, SubmessageId};
use super::super::types::{ObjectId, StreamId};
use super::{FragmentError, SeqNum, StreamConfig};

/// The object a rebuilt submessage starting with `head` is for, if it is a
/// DATA or WRITE_DATA: after the submessage header come its request id
/// and object id.
fn data_object(head: &[u8]) -> Option<ObjectId> {
    match *head {
        [id, _, _, _, _, _, a, b, ..]
            if id == SubmessageId::Data as u8 || id == SubmessageId::WriteData as u8 =>
        {
            Some(ObjectId(u16::from_be_bytes([a, b])))
        }
        _ => None,
    }
}

/// A best-effort input stream.
#[derive(Debug, Clone)]
pub struct BestEffortInput {
    last: SeqNum,
    resync: bool,
}

impl Default for BestEffortInput {
    fn default() -> Self {
        BestEffortInput {
            last: SeqNum::INITIAL_LAST,
            resync: false,
        }
    }
}

impl BestEffortInput {
    /// A stream of a restored session: the next message is taken whatever
    /// its number, and numbering goes on from it.
    pub fn resynced() -> Self {
        BestEffortInput {
            last: SeqNum::INITIAL_LAST,
            resync: true,
        }
    }

    /// Whether to take message `seq`: only if it is newer than the last taken.
    pub fn accept(&mut self, seq: SeqNum) -> bool {
        let take = std::mem::take(&mut self.resync) || seq.is_after(self.last);
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
///
/// A message is acknowledged once handed on, unless acknowledgement is
/// [deferred](ReliableInput::set_deferred): then the ACKNACK names the
/// first message not yet [confirmed](ReliableInput::confirm_through), and
/// the window counts from there, so a sender whose messages are not
/// confirmed stops after one window.
#[derive(Debug, Clone)]
pub struct ReliableInput {
    id: StreamId,
    cfg: StreamConfig,
    last_handled: SeqNum,
    /// The last message acknowledged: `last_handled` unless deferred.
    confirmed: SeqNum,
    deferred: bool,
    /// With [`hold_acks_at`](ReliableInput::hold_acks_at): the last message
    /// the host has saved as handled; no ACKNACK acknowledges past it.
    saved: Option<SeqNum>,
    /// A restored session: the sender's first HEARTBEAT sets the position.
    resync: bool,
    /// A restored stream whose position the host kept: the first
    /// HEARTBEAT moves it forward (never back).
    kept: bool,
    last_announced: SeqNum,
    held: BTreeMap<u16, (usize, Message)>,
    held_bytes: usize,
    reassembly: Option<Reassembly>,
    /// The last message an ACKNACK acknowledged.
    ack_sent: SeqNum,
    /// An ACKNACK must go at once (gap, duplicate, HEARTBEAT).
    ack_urgent: bool,
    /// A delayed ACKNACK is due then ([`StreamConfig::ack_delay`]).
    ack_due: Option<Instant>,
}

impl ReliableInput {
    /// Input stream `id`.
    pub fn new(id: StreamId, cfg: StreamConfig) -> Self {
        ReliableInput {
            id,
            cfg,
            last_handled: SeqNum::INITIAL_LAST,
            confirmed: SeqNum::INITIAL_LAST,
            deferred: false,
            saved: None,
            resync: false,
            kept: false,
            last_announced: SeqNum::INITIAL_LAST,
            held: BTreeMap::new(),
            held_bytes: 0,
            reassembly: None,
            ack_sent: SeqNum::INITIAL_LAST,
            ack_urgent: false,
            ack_due: None,
        }
    }

    /// Whether the ACKNACK describing the stream should go now; else it is
    /// held until [`ack_deadline`](Self::ack_deadline)
    /// ([`StreamConfig::ack_delay`]). Call [`ack_sent`](Self::ack_sent)
    /// when one goes.
    pub fn ack_now(&mut self, now: Instant) -> bool {
        let Some(delay) = self.cfg.ack_delay else {
            return true;
        };
        let half = (self.cfg.depth / 2).max(1);
        let gap = !self.held.is_empty() || self.last_announced.is_after(self.last_handled);
        let acked = self.acked();
        if self.ack_urgent || gap || acked.since(self.ack_sent) >= half {
            return true;
        }
        if acked != self.ack_sent {
            self.ack_due.get_or_insert(crate::time::later(now, delay));
        }
        false
    }

    /// An ACKNACK describing the stream now went out.
    pub fn ack_sent(&mut self) {
        self.ack_sent = self.acked();
        self.ack_urgent = false;
        self.ack_due = None;
    }

    /// When a held ACKNACK is due.
    pub fn ack_deadline(&self) -> Option<Instant> {
        self.ack_due
    }

    /// The last message handed on.
    pub fn last_handled(&self) -> SeqNum {
        self.last_handled
    }

    /// Whether messages handed on wait for
    /// [`confirm_through`](Self::confirm_through) before they are
    /// acknowledged. Turning it off confirms everything handed on.
    pub fn set_deferred(&mut self, deferred: bool) {
        self.deferred = deferred;
        if !deferred {
            self.confirmed = self.last_handled;
        }
    }

    /// The session was restored without this stream's position: the
    /// sender's first HEARTBEAT sets it.
    pub fn set_resync(&mut self) {
        self.resync = true;
    }

    /// Whether the stream waits for the sender's HEARTBEAT to know where
    /// it stands (it sends no ACKNACK meanwhile: one would name messages
    /// missing that the sender may long have had acknowledged, and a sender
    /// that resends on any NACK would answer each with everything again).
    pub fn is_resyncing(&self) -> bool {
        self.resync
    }

    /// The last message confirmed (handed on and, when deferred,
    /// [confirmed](Self::confirm_through)): what the stream has done.
    pub fn confirmed(&self) -> SeqNum {
        self.confirmed
    }

    /// The last message an ACKNACK may acknowledge: the last
    /// [confirmed](Self::confirmed), held back to the last
    /// [saved](Self::hold_acks_at) when the host saves positions.
    pub fn acked(&self) -> SeqNum {
        match self.saved {
            Some(s) if self.confirmed.is_after(s) => s,
            _ => self.confirmed,
        }
    }

    /// The host keeps the stream's position (the last message handled)
    /// somewhere that outlives it, and has saved `saved`: from now on an
    /// ACKNACK acknowledges nothing past the last position saved, so a
    /// restarted host never sees the sender go on past what it knows it
    /// handled. Called again as the host saves; whether that lets the
    /// ACKNACK move (it is then due at once).
    pub fn hold_acks_at(&mut self, saved: SeqNum) -> bool {
        let before = self.acked();
        self.saved = Some(saved);
        let moved = self.acked() != before && self.acked() != self.ack_sent;
        if moved {
            self.ack_urgent = true;
        }
        moved
    }

    /// A restored session whose host kept this stream's position: `last`
    /// was the last message handled (and confirmed) before the restart.
    /// Messages up to it that the sender sends again are duplicates, not
    /// handed on. As for a stream restored without its position, no
    /// ACKNACK goes before the sender's first HEARTBEAT (one would name
    /// messages missing that the sender may have had acknowledged, if the
    /// position kept is older than its), which moves the position forward
    /// to the sender's if that is further on, never back.
    pub fn restore(&mut self, last: SeqNum) {
        self.last_handled = last;
        self.confirmed = last;
        self.last_announced = last;
        self.ack_sent = last;
        if self.saved.is_some() {
            self.saved = Some(last);
        }
        self.kept = true;
        self.resync = true;
        self.held.clear();
        self.held_bytes = 0;
        self.reassembly = None;
    }

    /// Acknowledges every message up to `seq` (no further than the last one
    /// handed on). Whether that moved anything.
    pub fn confirm_through(&mut self, seq: SeqNum) -> bool {
        let seq = if seq.is_after(self.last_handled) {
            self.last_handled
        } else {
            seq
        };
        if seq.is_after(self.confirmed) {
            self.confirmed = seq;
            true
        } else {
            false
        }
    }

    /// Acknowledges every message handed on.
    pub fn confirm_all(&mut self) -> bool {
        self.confirm_through(self.last_handled)
    }

    /// Bytes held: early messages and a partly rebuilt submessage.
    pub fn buffered(&self) -> usize {
        self.held_bytes + self.reassembly.as_ref().map_or(0, |r| r.buf.len())
    }

    /// Takes message `seq` (`len` bytes on the wire) if it is inside the
    /// window and new.
    pub fn receive(&mut self, seq: SeqNum, message: Message, len: usize) -> Received {
        let d = seq.since(self.last_handled);
        if d == 0 || d >= 0x8000 {
            self.ack_urgent = true;
            return Received::Duplicate;
        }
        if seq.since(self.confirmed) > self.cfg.depth {
            self.ack_urgent = true;
            return Received::OutOfWindow;
        }
        if self.held.contains_key(&seq.0) {
            self.ack_urgent = true;
            return Received::Duplicate;
        }
        self.held.insert(seq.0, (len, message));
        self.held_bytes += len;
        if seq.is_after(self.last_announced) {
            self.last_announced = seq;
        }
        Received::Accepted
    }

    /// The next message in order, if it is here.
    pub fn next_message(&mut self) -> Option<Message> {
        let next = self.last_handled.wrapping_add(1);
        let (len, m) = self.held.remove(&next.0)?;
        self.held_bytes -= len;
        self.last_handled = next;
        if !self.deferred {
            self.confirmed = next;
        }
        Some(m)
    }

    /// A HEARTBEAT from the sender: it holds `first..=last`. Messages the
    /// sender no longer holds are skipped (as the agent does); `last` tells
    /// how far to NACK (at most one window ahead).
    ///
    /// Whether it was used: one whose `first` is after `last + 1` (serial
    /// order, so a range across the wrap-around is fine) names no range of
    /// messages, and is ignored; taken, it would skip every message before
    /// `first` that is still to come.
    pub fn on_heartbeat(&mut self, hb: &Heartbeat) -> bool {
        let first = SeqNum(hb.first_unacked);
        if first.is_after(SeqNum(hb.last_unacked).wrapping_add(1)) {
            return false;
        }
        // the sender asks: it hears back at once
        self.ack_urgent = true;
        let resync = std::mem::take(&mut self.resync);
        if resync && std::mem::take(&mut self.kept) {
            // a restored stream whose position the host kept: the sender
            // may only be further on (handled below, as any HEARTBEAT)
        } else if resync {
            // a restored session: the sender's window starts here; what
            // came before the HEARTBEAT and is not in it is forgotten
            self.last_handled = first.wrapping_sub(1);
            self.confirmed = self.last_handled;
            self.last_announced = self.last_handled;
            let keep: BTreeMap<u16, (usize, Message)> = std::mem::take(&mut self.held)
                .into_iter()
                .filter(|(s, _)| {
                    let d = SeqNum(*s).since(self.last_handled);
                    d != 0 && d <= self.cfg.depth
                })
                .collect();
            self.held_bytes = keep.values().map(|(l, _)| l).sum();
            self.held = keep;
            self.reassembly = None;
            if let Some(last) = self
                .held
                .keys()
                .map(|s| SeqNum(*s))
                .max_by(|a, b| a.serial_cmp(*b))
            {
                self.last_announced = last;
            }
        }
        if first.is_after(self.last_handled.wrapping_add(1))
            && first.since(self.last_handled) < 0x8000
        {
            let nothing_pending = self.confirmed == self.last_handled;
            self.last_handled = first.wrapping_sub(1);
            if nothing_pending || !self.deferred {
                self.confirmed = self.last_handled;
            }
            let keep: BTreeMap<u16, (usize, Message)> = std::mem::take(&mut self.held)
                .into_iter()
                .filter(|(s, _)| SeqNum(*s).is_after(self.last_handled))
                .collect();
            self.held_bytes = keep.values().map(|(l, _)| l).sum();
            self.held = keep;
            self.reassembly = None;
            if self.last_handled.is_after(self.last_announced) {
                self.last_announced = self.last_handled;
            }
        }
        let last = SeqNum(hb.last_unacked);
        let limit = self.confirmed.wrapping_add(self.cfg.depth);
        let last = if last.is_after(limit) { limit } else { last };
        if last.is_after(self.last_announced) {
            self.last_announced = last;
        }
        true
    }

    /// The ACKNACK describing this stream now: everything up to the last
    /// message acknowledged, and which later ones are missing (those handed
    /// on but not confirmed are not).
    pub fn acknack(&self) -> AckNack {
        let acked = self.acked();
        let first = acked.wrapping_add(1);
        let handed = self.last_handled.since(acked);
        let known = self.last_announced.since(acked);
        let mut bits = 0u16;
        for i in 0..16u16 {
            if i >= handed
                && i < known
                && known < 0x8000
                && !self.held.contains_key(&first.wrapping_add(i).0)
            {
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
                    let mut head = std::mem::take(&mut r.buf);
                    head.truncate(8);
                    head.extend(body.iter().take(8 - head.len()));
                    errors.push(FragmentError::TooLarge {
                        max,
                        object: data_object(&head),
                    });
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
