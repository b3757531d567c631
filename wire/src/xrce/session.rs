//! The stream side of one XRCE session, shared by the client and the
//! agent: the session's message header, its output and input streams by
//! id (created on first use, up to a limit), and what an arriving message
//! does to them: HEARTBEAT and ACKNACK handling, best-effort filtering,
//! in-order hand-over and fragment reassembly on reliable streams, and the
//! ACKNACK every reliable message is answered with.

use std::collections::{BTreeMap, VecDeque};
use std::time::Instant;

use super::message::{Message, MessageHeader};
use super::stream::{
    BestEffortInput, BestEffortOutput, FragmentError, ReliableInput, ReliableOutput, SeqNum,
    StreamConfig, StreamError,
};
use super::submessage::{Payload, Submessage};
use super::types::{ClientKey, StreamId};
use super::{DecodeError, EncodeError};

/// Why an arriving message (or part of it) was not used. The machine that
/// returned it goes on working.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum InputError {
    /// The bytes are not an XRCE message.
    #[error(transparent)]
    Decode(#[from] DecodeError),
    /// A message of another session.
    #[error("XRCE message for session {got:#04x}, this one is {expected:#04x}")]
    WrongSession {
        /// This session's id.
        expected: u8,
        /// The header's.
        got: u8,
    },
    /// The header's client key is not this session's.
    #[error("XRCE message with client key {got:08x}, this session's is {expected:08x}")]
    WrongClientKey {
        /// This session's key.
        expected: u32,
        /// The header's.
        got: u32,
    },
    /// The agent knows no client for this message.
    #[error("XRCE message from an unknown client (session {session_id:#04x})")]
    UnknownClient {
        /// The header's session id.
        session_id: u8,
    },
    /// A submessage this side never receives, or not on this stream.
    #[error("unexpected XRCE {what} on stream {stream:#04x}")]
    Unexpected {
        /// The submessage.
        what: &'static str,
        /// The stream it came on.
        stream: u8,
    },
    /// More streams than the session allows.
    #[error("XRCE stream {0:#04x} is one more stream than this session allows")]
    TooManyStreams(u8),
    /// Fragments that do not fit together.
    #[error(transparent)]
    Fragment(#[from] FragmentError),
    /// WRITE_DATA or DATA in a format other than FORMAT_DATA.
    #[error("XRCE data format {0:#04x} is not FORMAT_DATA")]
    DataFormat(u8),
    /// DATA too short for what its object kind puts in front of the sample.
    #[error("XRCE DATA for object {object:#06x} has {len} byte(s), its prefix needs {needed}")]
    ShortData {
        /// The requester or replier.
        object: u16,
        /// Bytes received.
        len: usize,
        /// Bytes the prefix needs.
        needed: usize,
    },
    /// A HEARTBEAT whose first sequence number is after its last + 1: it
    /// names no range of messages, and was ignored.
    #[error(
        "malformed XRCE HEARTBEAT on stream {stream:#04x}: first {first} is after last {last} + 1 \
         (ignored)"
    )]
    BadHeartbeat {
        /// The reliable stream it is for.
        stream: u8,
        /// Its first unacknowledged sequence number.
        first: u16,
        /// Its last unacknowledged sequence number.
        last: u16,
    },
    /// A reply to nothing this side asked.
    #[error("XRCE {what} answers nothing this session asked")]
    Unsolicited {
        /// The submessage.
        what: &'static str,
    },
}

/// Why a submessage could not be queued.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum QueueError {
    /// The stream refused it.
    #[error(transparent)]
    Stream(#[from] StreamError),
    /// It could not be encoded.
    #[error(transparent)]
    Encode(#[from] EncodeError),
    /// Stream 0 carries no data, and a session has a limited number of streams.
    #[error("XRCE stream {0:#04x} is stream 0, or one more stream than the session allows")]
    BadStream(u8),
}

/// What one arriving message gave.
#[derive(Debug, Default)]
pub(crate) struct Arrival {
    /// Submessages to act on, in order, with the stream they came on
    /// (ACKNACK and HEARTBEAT are handled here and not included).
    pub subs: Vec<(StreamId, Submessage)>,
    /// For each of `subs` on a reliable stream: the sequence number of the
    /// message that completed it.
    pub origins: Vec<Option<SeqNum>>,
    /// Reliable messages handed on, in order, with their stream.
    pub handed: Vec<(StreamId, SeqNum)>,
    /// ACKNACKs to send once the submessages are acted on.
    pub replies: Vec<Vec<u8>>,
    /// Reliable streams whose ACKNACK the caller sends once it has acted
    /// (instead of `replies`), when acknowledgement is deferred.
    pub ack_later: Vec<StreamId>,
    /// What went wrong on the way.
    pub errors: Vec<InputError>,
}

/// The streams of one session.
#[derive(Debug, Clone)]
pub(crate) struct Streams {
    header: MessageHeader,
    cfg: StreamConfig,
    max_streams: usize,
    be_out: BTreeMap<u8, BestEffortOutput>,
    rel_out: BTreeMap<u8, ReliableOutput>,
    be_in: BTreeMap<u8, BestEffortInput>,
    rel_in: BTreeMap<u8, ReliableInput>,
    /// Reliable input is acknowledged only as the owner confirms it.
    deferred: bool,
    /// A restored session: streams take the peer's position from its first
    /// message, HEARTBEAT or ACKNACK.
    resync: bool,
    /// ACKNACKs acknowledge no further than the host saved
    /// ([`Streams::hold_acks_until_saved`]).
    hold_acks: bool,
    /// A restored session's reliable input positions the host kept: the
    /// last message each stream handled before the restart.
    restored_inputs: BTreeMap<u8, SeqNum>,
    /// Messages on stream 0, ready to go.
    pub control: VecDeque<Vec<u8>>,
}

/// The header of session `session_id` (with `key` when below 0x80) on stream 0.
pub(crate) fn session_header(session_id: u8, key: ClientKey) -> MessageHeader {
    if session_id < super::SESSION_ID_WITHOUT_CLIENT_KEY {
        MessageHeader::with_key(session_id, key, StreamId::NONE, 0)
    } else {
        MessageHeader::new(session_id, StreamId::NONE, 0)
    }
}

/// A one-submessage message.
pub(crate) fn single(header: MessageHeader, sub: Submessage) -> Result<Vec<u8>, EncodeError> {
    Message::new(header, vec![sub]).to_vec()
}

impl Streams {
    /// The streams of the session whose messages carry `header` (session
    /// id and key; stream and sequence number are set per message). The
    /// MTU is kept between 64 and 65535 bytes and the window between 1 and 64.
    pub fn new(header: MessageHeader, mut cfg: StreamConfig, max_streams: usize) -> Self {
        cfg.mtu = cfg.mtu.clamp(64, usize::from(u16::MAX));
        cfg.depth = cfg.depth.clamp(1, 64);
        Streams {
            header,
            cfg,
            max_streams: max_streams.max(1),
            be_out: BTreeMap::new(),
            rel_out: BTreeMap::new(),
            be_in: BTreeMap::new(),
            rel_in: BTreeMap::new(),
            deferred: false,
            resync: false,
            hold_acks: false,
            restored_inputs: BTreeMap::new(),
            control: VecDeque::new(),
        }
    }

    /// Defers acknowledgement of reliable input: a message handed on is
    /// acknowledged only through [`confirm_through`](Self::confirm_through)
    /// or [`confirm_all`](Self::confirm_all), and ACKNACKs for arriving
    /// messages are left to the caller ([`Arrival::ack_later`]).
    pub fn set_deferred(&mut self, deferred: bool) {
        self.deferred = deferred;
        for s in self.rel_in.values_mut() {
            s.set_deferred(deferred);
        }
    }

    /// The session was restored without its streams' positions: every
    /// stream takes the peer's from what the peer sends first (a reliable
    /// output stream from the first ACKNACK, a reliable input stream from
    /// the first HEARTBEAT, a best-effort input stream from its first
    /// message). Best-effort output starts from 0 again.
    pub fn set_resync(&mut self) {
        self.resync = true;
    }

    /// The host saves the reliable input streams' positions
    /// ([`input_positions`](Self::input_positions)) and says so with
    /// [`saved_through`](Self::saved_through): until then an ACKNACK
    /// acknowledges nothing past what was saved
    /// ([`ReliableInput::hold_acks_at`]).
    pub fn hold_acks_until_saved(&mut self) {
        self.hold_acks = true;
        for s in self.rel_in.values_mut() {
            let saved = s.confirmed();
            s.hold_acks_at(saved);
        }
    }

    /// The host saved `seq` as reliable input stream `id`'s position; an
    /// ACKNACK that may now go further is queued on stream 0. Whether one
    /// was.
    pub fn saved_through(&mut self, id: StreamId, seq: SeqNum) -> bool {
        let Some(s) = self.rel_in.get_mut(&id.0) else {
            return false;
        };
        if !s.hold_acks_at(seq) {
            return false;
        }
        match self.acknack_message(id) {
            Some(m) => {
                self.control.push_back(m);
                true
            }
            None => false,
        }
    }

    /// Each reliable input stream's position: the last message handled and
    /// confirmed (for a host that confirms writes: written), by stream id.
    /// Streams still waiting for the peer's HEARTBEAT to know theirs give
    /// the position they were restored with, if any.
    pub fn input_positions(&self) -> Vec<(StreamId, SeqNum)> {
        let mut v: BTreeMap<u8, SeqNum> = self.restored_inputs.clone();
        for (id, s) in &self.rel_in {
            if !s.is_resyncing() {
                v.insert(*id, s.confirmed());
            }
        }
        v.into_iter().map(|(id, s)| (StreamId(id), s)).collect()
    }

    /// A restored session's reliable input positions, as
    /// [`input_positions`](Self::input_positions) gave them before the
    /// restart: those streams go on from there (what the peer sends again
    /// up to it is a duplicate) instead of taking the peer's position from
    /// its HEARTBEAT.
    pub fn restore_inputs(&mut self, positions: &[(StreamId, SeqNum)]) {
        for &(id, seq) in positions {
            if !id.is_reliable() {
                continue;
            }
            self.restored_inputs.insert(id.0, seq);
            if let Some(s) = self.rel_in.get_mut(&id.0) {
                s.restore(seq);
            }
        }
    }

    /// Acknowledges reliable input stream `id` up to `seq`; whether it moved.
    pub fn confirm_through(&mut self, id: StreamId, seq: SeqNum) -> bool {
        self.rel_in
            .get_mut(&id.0)
            .is_some_and(|s| s.confirm_through(seq))
    }

    /// Acknowledges everything stream `id` handed on; whether it moved.
    pub fn confirm_all(&mut self, id: StreamId) -> bool {
        self.rel_in.get_mut(&id.0).is_some_and(|s| s.confirm_all())
    }

    /// The ACKNACK of reliable input stream `id` as a message, if it is to
    /// go now ([`StreamConfig::ack_delay`]: else
    /// [`poll_transmit`](Self::poll_transmit) sends it when due).
    pub fn acknack_for(&mut self, id: StreamId, now: Instant) -> Option<Vec<u8>> {
        if !self.rel_in.get_mut(&id.0)?.ack_now(now) {
            return None;
        }
        self.acknack_message(id)
    }

    pub fn header(&self) -> MessageHeader {
        self.header
    }

    pub fn config(&self) -> &StreamConfig {
        &self.cfg
    }

    /// Forgets every stream (a session created again starts from 0).
    pub fn reset(&mut self) {
        self.resync = false;
        self.restored_inputs.clear();
        self.be_out.clear();
        self.rel_out.clear();
        self.be_in.clear();
        self.rel_in.clear();
        self.control.clear();
    }

    /// A message on stream 0 holding `sub`.
    pub fn control_message(&self, sub: Submessage) -> Result<Vec<u8>, EncodeError> {
        single(self.header, sub)
    }

    /// Queues `sub` on stream 0.
    pub fn send_control(&mut self, sub: Submessage) -> Result<(), EncodeError> {
        let m = self.control_message(sub)?;
        self.control.push_back(m);
        Ok(())
    }

    /// The bytes of `sub` as it goes into a stream: header, payload and,
    /// when the configuration says so, padding to 4.
    pub fn encode(&self, sub: &Submessage) -> Result<Vec<u8>, EncodeError> {
        let mut v = Vec::new();
        sub.encode(&mut v, 0)?;
        if self.cfg.pad {
            v.resize((v.len() + 3) & !3, 0);
        }
        Ok(v)
    }

    /// Queues encoded submessage bytes on output stream `id`; `tag` comes
    /// back from [`take_acked`](Self::take_acked) once a reliable stream's
    /// peer has it all. `force` skips the backlog limit.
    pub fn push(
        &mut self,
        id: StreamId,
        bytes: Vec<u8>,
        tag: Option<u16>,
        force: bool,
    ) -> Result<(), QueueError> {
        let n = self.rel_out.len() + self.be_out.len();
        if id.is_reliable() {
            if !self.rel_out.contains_key(&id.0) && n >= 2 * self.max_streams {
                return Err(QueueError::BadStream(id.0));
            }
            let (h, c, r) = (self.header, self.cfg, self.resync);
            let s = self.rel_out.entry(id.0).or_insert_with(|| {
                let mut s = ReliableOutput::new(&h, id, c);
                if r {
                    s.set_resync();
                }
                s
            });
            if force {
                s.push_unchecked(bytes, tag);
                Ok(())
            } else {
                Ok(s.push(bytes, tag)?)
            }
        } else if id.is_best_effort() {
            if !self.be_out.contains_key(&id.0) && n >= 2 * self.max_streams {
                return Err(QueueError::BadStream(id.0));
            }
            let (h, c) = (self.header, self.cfg);
            let s = self
                .be_out
                .entry(id.0)
                .or_insert_with(|| BestEffortOutput::new(&h, id, c));
            Ok(s.push(&bytes)?)
        } else {
            Err(QueueError::BadStream(0))
        }
    }

    fn reliable_input(&mut self, id: StreamId) -> Option<&mut ReliableInput> {
        if !self.rel_in.contains_key(&id.0) && self.rel_in.len() >= self.max_streams {
            return None;
        }
        let (c, deferred, resync, hold) = (self.cfg, self.deferred, self.resync, self.hold_acks);
        let restored = self.restored_inputs.get(&id.0).copied();
        Some(self.rel_in.entry(id.0).or_insert_with(|| {
            let mut s = ReliableInput::new(id, c);
            s.set_deferred(deferred);
            if hold {
                s.hold_acks_at(SeqNum::INITIAL_LAST);
            }
            match restored {
                Some(last) => s.restore(last),
                None if resync => s.set_resync(),
                None => {}
            }
            s
        }))
    }

    fn acknack_message(&mut self, id: StreamId) -> Option<Vec<u8>> {
        let input = self.rel_in.get_mut(&id.0)?;
        input.ack_sent();
        if input.is_resyncing() {
            return None;
        }
        let a = input.acknack();
        self.control_message(Submessage::new(Payload::AckNack(a)))
            .ok()
    }

    /// Takes an arriving message of this session.
    pub fn receive(&mut self, message: Message, len: usize, now: Instant) -> Arrival {
        let mut a = Arrival::default();
        for s in self.rel_out.values_mut() {
            s.touch(now);
        }
        let id = message.header.stream_id;
        let seq = SeqNum(message.header.sequence_nr);
        let deferred = self.deferred;
        let subs: Vec<(Option<SeqNum>, Submessage)> = if id == StreamId::NONE {
            message.submessages.into_iter().map(|s| (None, s)).collect()
        } else if id.is_best_effort() {
            if !self.be_in.contains_key(&id.0) && self.be_in.len() >= self.max_streams {
                a.errors.push(InputError::TooManyStreams(id.0));
                return a;
            }
            let resync = self.resync;
            let input = self.be_in.entry(id.0).or_insert_with(|| {
                if resync {
                    BestEffortInput::resynced()
                } else {
                    BestEffortInput::default()
                }
            });
            if !input.accept(seq) {
                return a;
            }
            message.submessages.into_iter().map(|s| (None, s)).collect()
        } else {
            let Some(input) = self.reliable_input(id) else {
                a.errors.push(InputError::TooManyStreams(id.0));
                return a;
            };
            input.receive(seq, message, len);
            let mut subs = Vec::new();
            let mut errors = Vec::new();
            while let Some(m) = input.next_message() {
                let s = SeqNum(m.header.sequence_nr);
                a.handed.push((id, s));
                subs.extend(
                    input
                        .unpack(m, &mut errors)
                        .into_iter()
                        .map(|x| (Some(s), x)),
                );
            }
            a.errors.extend(errors.into_iter().map(InputError::from));
            if deferred {
                a.ack_later.push(id);
            } else {
                a.replies.extend(self.acknack_for(id, now));
            }
            subs
        };
        for (origin, sub) in subs {
            match &sub.payload {
                Payload::AckNack(ack) => {
                    if let Some(s) = self.rel_out.get_mut(&ack.stream_id.0) {
                        s.on_acknack(ack, now);
                    }
                }
                Payload::Heartbeat(hb) if hb.stream_id.is_reliable() => {
                    match self.reliable_input(hb.stream_id) {
                        Some(input) => {
                            if !input.on_heartbeat(hb) {
                                a.errors.push(InputError::BadHeartbeat {
                                    stream: hb.stream_id.0,
                                    first: hb.first_unacked,
                                    last: hb.last_unacked,
                                });
                                continue;
                            }
                            // messages held behind one the sender gave up on
                            // (or, restored, before its window) go on now
                            let mut errors = Vec::new();
                            while let Some(m) = input.next_message() {
                                let s = SeqNum(m.header.sequence_nr);
                                a.handed.push((hb.stream_id, s));
                                for x in input.unpack(m, &mut errors) {
                                    a.subs.push((hb.stream_id, x));
                                    a.origins.push(Some(s));
                                }
                            }
                            a.errors.extend(errors.into_iter().map(InputError::from));
                            if deferred {
                                a.ack_later.push(hb.stream_id);
                            } else {
                                a.replies.extend(self.acknack_for(hb.stream_id, now));
                            }
                        }
                        None => a.errors.push(InputError::TooManyStreams(hb.stream_id.0)),
                    }
                }
                Payload::Fragment(_) if !id.is_reliable() => {
                    a.errors
                        .push(InputError::Fragment(FragmentError::NotReliable(id.0)));
                }
                Payload::Heartbeat(_) => a.errors.push(InputError::Unexpected {
                    what: "HEARTBEAT",
                    stream: id.0,
                }),
                _ => {
                    a.subs.push((id, sub));
                    a.origins.push(origin);
                }
            }
        }
        a
    }

    /// The next message to send: stream 0 first, then retransmissions and
    /// new messages of each stream, then held ACKNACKs and HEARTBEATs that
    /// are due.
    pub fn poll_transmit(&mut self, now: Instant) -> Option<Vec<u8>> {
        if let Some(m) = self.control.pop_front() {
            return Some(m);
        }
        for s in self.rel_out.values_mut() {
            if let Some(m) = s.poll_transmit(now) {
                return Some(m);
            }
        }
        for s in self.be_out.values_mut() {
            if let Some(m) = s.poll_transmit() {
                return Some(m);
            }
        }
        let due = self
            .rel_in
            .iter()
            .find(|(_, s)| s.ack_deadline().is_some_and(|t| t <= now))
            .map(|(id, _)| StreamId(*id));
        if let Some(id) = due {
            if let Some(m) = self.acknack_message(id) {
                return Some(m);
            }
        }
        let hb = self
            .rel_out
            .values_mut()
            .find_map(|s| s.poll_heartbeat(now))?;
        self.control_message(Submessage::new(Payload::Heartbeat(hb)))
            .ok()
    }

    /// The earliest HEARTBEAT or held ACKNACK deadline.
    pub fn poll_timeout(&self) -> Option<Instant> {
        let hb = self.rel_out.values().filter_map(|s| s.poll_timeout());
        let ack = self.rel_in.values().filter_map(ReliableInput::ack_deadline);
        hb.chain(ack).min()
    }

    /// Tags of reliable submessages the peer acknowledged since the last call.
    pub fn take_acked(&mut self) -> Vec<u16> {
        self.rel_out
            .values_mut()
            .flat_map(|s| s.take_acked().collect::<Vec<_>>())
            .collect()
    }

    /// Bytes the session holds in its streams.
    pub fn buffered(&self) -> usize {
        self.control.iter().map(Vec::len).sum::<usize>()
            + self
                .rel_out
                .values()
                .map(ReliableOutput::buffered)
                .sum::<usize>()
            + self
                .be_out
                .values()
                .map(BestEffortOutput::buffered)
                .sum::<usize>()
            + self
                .rel_in
                .values()
                .map(ReliableInput::buffered)
                .sum::<usize>()
    }

    /// Whether a reliable output stream's peer has answered nothing for
    /// [`StreamConfig::silent_after`] while messages waited.
    pub fn is_silent(&self, now: Instant) -> bool {
        self.rel_out.values().any(|s| s.is_silent(now))
    }

    /// Drops what the reliable output streams queue beyond their windows,
    /// never sent ([`ReliableOutput::drop_unsent`]): how many submessages.
    pub fn drop_unsent(&mut self) -> usize {
        self.rel_out
            .values_mut()
            .map(ReliableOutput::drop_unsent)
            .sum()
    }

    /// Whether every output stream is empty and acknowledged.
    pub fn is_idle(&self) -> bool {
        self.control.is_empty()
            && self.rel_out.values().all(|s| s.is_idle())
            && self.be_out.values().all(|s| s.is_empty())
    }
}
