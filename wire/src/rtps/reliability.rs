//! Stateful reliable writer and reader (DDSI-RTPS §8.4.7–§8.4.12), sans-I/O.
//!
//! Driven quinn-proto style: inputs are received submessages and explicit
//! time; outputs are polled ([`Writer::poll_transmit`],
//! [`Reader::poll_transmit`], [`Reader::poll_sample`]) and timers are
//! reported by `poll_timeout` and fired by `handle_timeout(now)`. No clock
//! is read here.

use std::collections::{BTreeMap, BTreeSet, VecDeque};

// seeded per process: keyed by GUIDs off the network
use foldhash::{HashMap, HashMapExt};
use std::sync::Arc;
use std::time::{Duration, Instant};

use super::message::{AckNack, Gap, Heartbeat};

/// A sample as the writer history and reader queues hold it: opaque bytes,
/// shared between the history and what is in flight, and still a `Vec`
/// inside so that the last holder can take it without a copy.
pub type Payload = Arc<Vec<u8>>;
use super::types::{Guid, SequenceNumber, SequenceNumberSet};

/// What a writer or reader wants sent. Addressed to one remote endpoint
/// (`to`), or to every matched one when `to` is `None`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Transmit {
    /// A sample.
    Data {
        /// Destination reader (None = all matched readers).
        to: Option<Guid>,
        /// Its sequence number.
        sn: SequenceNumber,
        /// Serialized payload (with encapsulation header).
        payload: Payload,
    },
    /// Sequence numbers the reader will never get.
    Gap {
        /// Destination reader.
        to: Guid,
        /// `[start, list.base)` and the list's members are irrelevant.
        start: SequenceNumber,
        /// Further irrelevant sequence numbers.
        list: SequenceNumberSet,
    },
    /// What the writer has.
    Heartbeat {
        /// Destination (None = all matched readers).
        to: Option<Guid>,
        /// First available.
        first: SequenceNumber,
        /// Last written.
        last: SequenceNumber,
        /// Counter.
        count: i32,
        /// No reply needed.
        final_flag: bool,
        /// The L flag: it asserts the writer's liveliness (DDS
        /// `assert_liveliness` on a manual-by-topic writer).
        liveliness: bool,
    },
    /// A reader's acknowledgement / negative acknowledgement.
    AckNack {
        /// Destination writer.
        to: Guid,
        /// Acknowledged below `base`; members are missing.
        state: SequenceNumberSet,
        /// Counter.
        count: i32,
        /// No heartbeat needed in reply.
        final_flag: bool,
    },
}

#[derive(Debug, Default)]
struct ReaderProxy {
    /// A reliable reader: it acknowledges, and the writer keeps and repairs
    /// for it. A best-effort reader never sends an ACKNACK, so waiting for
    /// one would hold a keep-all history until it is full (and block).
    reliable: bool,
    /// Everything below this is acknowledged.
    acked_below: i64,
    /// First sequence number relevant to this reader: a volatile late
    /// joiner gets a GAP, not the data, for anything written before it matched.
    start: i64,
    /// Sequence numbers the reader asked for again.
    requested: BTreeSet<i64>,
    last_acknack_count: Option<i32>,
    /// A volatile reliable reader that has not yet answered one of our
    /// heartbeats: every heartbeat it gets says "nothing from `start` on".
    ///
    /// A reader may start a volatile match at the last sequence number of
    /// the first heartbeat it processes (Cyclone DDS does: that is its only
    /// way to tell history from live data), and it may drop DATA that
    /// arrives before its own matching is complete. A heartbeat naming a
    /// sample the reader dropped that way would make the sample lost for
    /// good, so the real range is announced only once the reader answered
    /// a heartbeat (an ACKNACK with a non-zero count: Cyclone's pre-emptive
    /// ACKNACKs, sent before any heartbeat, count 0).
    fresh: bool,
    /// A transient-local (durable) reader: it gets the history.
    replay: bool,
    /// When its last ACKNACK (not a pre-emptive one) was taken.
    last_ack_at: Option<Instant>,
}

/// A pre-emptive ACKNACK from a reader that had acknowledged data makes a
/// new match of it only when the reader has said nothing else for this
/// long: a reader that lost our participant and found it again was silent
/// for at least its lease, while a pre-emptive ACKNACK that the network
/// delayed past the reader's first answers is stale (taken as new, it
/// would make a volatile reader skip samples still on their way). Cyclone
/// DDS accepts any ACKNACK count after the same 500 ms.
const REMATCH_AFTER_SILENCE: Duration = Duration::from_millis(500);

/// Empty slots a [`History`] tolerates beyond as many as it holds samples
/// before it compacts itself.
const HISTORY_SLACK: usize = 64;

/// A writer's history: samples by sequence number, ascending. Sequence
/// numbers are written in order, so a sample is looked up by its distance
/// from the oldest one (a `BTreeMap` here cost ~5 % of a 16 B publisher's
/// CPU). A sample removed from the middle ([`History::remove`]:
/// per-instance keep-last) leaves an empty slot behind, which keeps that
/// lookup right; once the empty slots outnumber the samples (plus
/// [`HISTORY_SLACK`]) they are dropped, and a lookup that the distance no
/// longer finds searches. Without that, a transient-local keyed writer
/// that keeps one instance's sample while rewriting another's kept an
/// empty slot per write, for ever.
#[derive(Debug, Default)]
struct History {
    /// Sequence number and sample; the front slot is never empty.
    slots: VecDeque<(i64, Option<Payload>)>,
    count: usize,
}

impl History {
    fn len(&self) -> usize {
        self.count
    }

    /// Appends `sn`, which must follow every sequence number held.
    fn push(&mut self, sn: i64, payload: Payload) {
        debug_assert!(self.slots.back().is_none_or(|(last, _)| *last < sn));
        self.slots.push_back((sn, Some(payload)));
        self.count += 1;
    }

    /// Where `sn`'s slot is: at its distance from the front while no
    /// empty slot before it was dropped, else found by a search.
    fn index(&self, sn: i64) -> Option<usize> {
        let (first, _) = self.slots.front()?;
        let i = usize::try_from(sn.checked_sub(*first)?).ok()?;
        if self.slots.get(i).is_some_and(|(s, _)| *s == sn) {
            return Some(i);
        }
        self.slots.binary_search_by_key(&sn, |(s, _)| *s).ok()
    }

    fn get(&self, sn: i64) -> Option<&Payload> {
        self.slots.get(self.index(sn)?)?.1.as_ref()
    }

    fn remove(&mut self, sn: i64) -> Option<Payload> {
        let i = self.index(sn)?;
        let p = self.slots.get_mut(i)?.1.take()?;
        self.count -= 1;
        self.trim();
        if self.slots.len() > 2 * self.count + HISTORY_SLACK {
            self.slots.retain(|(_, p)| p.is_some());
        }
        Some(p)
    }

    /// The oldest sample.
    fn first(&self) -> Option<(i64, &Payload)> {
        // `trim` keeps the front slot full
        let (sn, p) = self.slots.front()?;
        p.as_ref().map(|p| (*sn, p))
    }

    fn pop_first(&mut self) -> Option<(i64, Payload)> {
        self.trim();
        let (sn, p) = self.slots.pop_front()?;
        self.trim();
        let p = p?; // never empty: `trim` ran
        self.count -= 1;
        Some((sn, p))
    }

    /// Drops empty slots at the front.
    fn trim(&mut self) {
        while let Some((_, None)) = self.slots.front() {
            self.slots.pop_front();
        }
    }

    /// The samples from `from` on, ascending.
    fn iter_from(&self, from: i64) -> impl Iterator<Item = (i64, &Payload)> + '_ {
        let skip = self.slots.partition_point(|(sn, _)| *sn < from);
        self.slots
            .iter()
            .skip(skip)
            .filter_map(|(sn, p)| p.as_ref().map(|p| (*sn, p)))
    }
}

/// A reliable (or best-effort) writer's history and matched readers.
#[derive(Debug)]
pub struct Writer {
    guid: Guid,
    reliable: bool,
    /// Keep at most this many samples (`None` = keep all; bounded by `max_samples`).
    depth: Option<usize>,
    max_samples: usize,
    history: History,
    /// Payload bytes in `history`.
    history_bytes: usize,
    /// A reliable keep-all writer refuses a write while this many payload
    /// bytes are unacknowledged (a high-water mark: it keeps a writer on
    /// the same CPU from overrunning its readers' socket buffers).
    max_unacked_bytes: usize,
    next_sn: i64,
    readers: HashMap<Guid, ReaderProxy>,
    heartbeat_period: Duration,
    next_heartbeat: Option<Instant>,
    /// The next write's heartbeat asks for an acknowledgement.
    ack_next: bool,
    /// The heartbeat that follows the writes queued in `out`: one for a
    /// burst of writes, sent after them (`Some(final_flag)`).
    hb_after_writes: Option<bool>,
    hb_count: i32,
    /// Keep acknowledged samples (transient-local keep-all writers).
    retain_acked: bool,
    /// A keep-last history full of samples some reader still lacks
    /// refuses a write instead of dropping the oldest of them.
    keep_unacked: bool,
    /// Samples that leave the history once every reliable reader has
    /// them, retained or not ([`Writer::drop_once_acked`]).
    drop_once_acked: BTreeSet<i64>,
    out: VecDeque<Transmit>,
}

impl Writer {
    /// A writer; `depth` = keep-last depth (None = keep all, up to `max_samples`).
    pub fn new(
        guid: Guid,
        reliable: bool,
        depth: Option<usize>,
        max_samples: usize,
        heartbeat_period: Duration,
    ) -> Self {
        Writer {
            guid,
            reliable,
            depth,
            max_samples: max_samples.max(1),
            history: History::default(),
            history_bytes: 0,
            max_unacked_bytes: usize::MAX,
            next_sn: 1,
            readers: HashMap::new(),
            heartbeat_period,
            next_heartbeat: None,
            ack_next: false,
            hb_after_writes: None,
            hb_count: 0,
            retain_acked: false,
            keep_unacked: false,
            drop_once_acked: BTreeSet::new(),
            out: VecDeque::new(),
        }
    }

    /// Keeps samples every reader acknowledged (default: a keep-all writer
    /// drops them). Transient-local writers need them for late joiners.
    pub fn retain_acked(mut self, yes: bool) -> Self {
        self.retain_acked = yes;
        self
    }

    /// Makes a reliable keep-last writer's depth a resource limit: a
    /// history full of samples some reader has not acknowledged refuses
    /// [`Writer::write`] (back-pressure, as keep-all) instead of dropping
    /// the oldest; acknowledged samples still make room. For per-instance
    /// keep-last, where the caller replaces an instance's own samples and
    /// the depth bounds all instances together: dropping the oldest would
    /// lose another instance's last change.
    pub fn keep_unacked(mut self, yes: bool) -> Self {
        self.keep_unacked = yes;
        self
    }

    /// Bounds the unacknowledged payload bytes of a reliable keep-all
    /// writer: [`Writer::write`] refuses while `max` bytes wait for an
    /// acknowledgement (one sample is always accepted, whatever its size).
    pub fn max_unacked_bytes(mut self, max: usize) -> Self {
        self.max_unacked_bytes = max.max(1);
        self
    }

    /// The writer's GUID.
    pub fn guid(&self) -> Guid {
        self.guid
    }

    /// A reader matched. A late joiner gets the history the writer still holds
    /// (transient-local behaviour is the caller's choice: pass `replay`).
    pub fn add_reader(&mut self, reader: Guid, replay: bool, now: Instant) {
        let first = self.first_sn();
        let acked_below = if replay { first } else { self.next_sn };
        self.readers.insert(
            reader,
            ReaderProxy {
                reliable: true,
                acked_below,
                start: acked_below,
                fresh: !replay,
                replay,
                ..ReaderProxy::default()
            },
        );
        if self.reliable && !replay && first < self.next_sn {
            // what is already written is irrelevant to a volatile late
            // joiner: say so at once, as Fast DDS does
            self.out.push_back(Transmit::Gap {
                to: reader,
                start: SequenceNumber(first),
                list: SequenceNumberSet::empty(SequenceNumber(self.next_sn)),
            });
        }
        if self.reliable {
            // announce what we have so the reader can ask
            self.push_heartbeat(Some(reader), false);
            self.next_heartbeat
                .get_or_insert(now + self.heartbeat_period);
        }
    }

    /// A best-effort reader matched: it gets every sample as written, but it
    /// never acknowledges, so neither the history, nor heartbeats, nor
    /// [`Writer::acked_by_all`] wait for it.
    pub fn add_best_effort_reader(&mut self, reader: Guid) {
        self.readers.insert(
            reader,
            ReaderProxy {
                reliable: false,
                acked_below: self.next_sn,
                start: self.next_sn,
                ..ReaderProxy::default()
            },
        );
    }

    /// A reader went away.
    pub fn remove_reader(&mut self, reader: Guid) {
        self.readers.remove(&reader);
        self.drop_acked_marked();
    }

    fn first_sn(&self) -> i64 {
        self.history.first().map_or(self.next_sn, |(sn, _)| sn)
    }

    /// A sample still in the history.
    pub fn get(&self, sn: SequenceNumber) -> Option<&Payload> {
        self.history.get(sn.0)
    }

    /// The samples in the history, ascending.
    pub fn samples(&self) -> impl Iterator<Item = (SequenceNumber, &Payload)> + '_ {
        self.history
            .iter_from(i64::MIN)
            .map(|(sn, p)| (SequenceNumber(sn), p))
    }

    /// Removes one sample from the history (per-instance keep-last
    /// bookkeeping, or a replaced announcement). Readers that ask for it
    /// later get a GAP.
    pub fn remove(&mut self, sn: SequenceNumber) -> bool {
        match self.history.remove(sn.0) {
            Some(p) => {
                self.history_bytes -= p.len();
                true
            }
            None => false,
        }
    }

    /// Takes samples out of the history once every matched reliable reader
    /// has acknowledged them (at once when none is matched), even when
    /// acknowledged samples are retained for late joiners: the samples of
    /// an instance its writer unregistered, which a late joiner is not to
    /// get (as Cyclone DDS and Fast DDS do) while a reader still missing
    /// one gets it repaired.
    pub fn drop_once_acked(&mut self, sns: impl IntoIterator<Item = SequenceNumber>) {
        for sn in sns {
            if self.history.get(sn.0).is_some() {
                self.drop_once_acked.insert(sn.0);
            }
        }
        self.drop_acked_marked();
    }

    /// Drops the samples [`Writer::drop_once_acked`] marked that every
    /// reliable reader has acknowledged.
    fn drop_acked_marked(&mut self) {
        if self.drop_once_acked.is_empty() {
            return;
        }
        let below = self.min_acked_below();
        while let Some(&sn) = self.drop_once_acked.first() {
            if sn >= below {
                break;
            }
            self.drop_once_acked.pop_first();
            self.remove(SequenceNumber(sn));
        }
        if self.drop_once_acked.len() > self.history.len() {
            // marks of samples that left the history by other ways
            // (replaced, expired, the oldest dropped for room)
            let h = &self.history;
            self.drop_once_acked.retain(|sn| h.get(*sn).is_some());
        }
    }

    fn pop_oldest(&mut self) {
        if let Some((_, p)) = self.history.pop_first() {
            self.history_bytes -= p.len();
        }
    }

    /// Payload bytes no reliable reader has acknowledged yet (all of the
    /// history unless acknowledged samples are retained).
    pub fn unacked_bytes(&self) -> usize {
        if !self.retain_acked {
            return self.history_bytes;
        }
        let below = self.min_acked_below();
        self.history.iter_from(below).map(|(_, p)| p.len()).sum()
    }

    fn min_acked_below(&self) -> i64 {
        self.readers
            .values()
            .filter(|r| r.reliable)
            .map(|r| r.acked_below)
            .min()
            .unwrap_or(self.next_sn)
    }

    /// The last sequence number written (0 before the first write).
    pub fn last_sn(&self) -> SequenceNumber {
        SequenceNumber(self.next_sn - 1)
    }

    /// Highest sequence number every matched reader acknowledged, with
    /// everything before it ([`Writer::last_sn`] when no reader is matched).
    pub fn acked_by_all(&self) -> SequenceNumber {
        let below = self
            .readers
            .values()
            .filter(|r| r.reliable)
            .map(|r| r.acked_below)
            .min()
            .unwrap_or(self.next_sn);
        SequenceNumber(below.min(self.next_sn) - 1)
    }

    /// Number of matched readers.
    pub fn reader_count(&self) -> usize {
        self.readers.len()
    }

    /// Writes a sample; returns its sequence number. Reliable keep-all
    /// writers refuse (return `None`) while `max_samples` unacknowledged
    /// samples or the unacknowledged-bytes limit are held: the caller
    /// applies back-pressure instead of losing data.
    ///
    /// The sample is queued for [`Writer::poll_transmit`]; a reliable
    /// writer's heartbeat follows the last of the samples queued together,
    /// so that a burst of writes costs one heartbeat.
    pub fn write(&mut self, payload: Payload, now: Instant) -> Option<SequenceNumber> {
        // unacknowledged bytes once this sample is in (keep-all reliable only;
        // a sum over the history when acknowledged samples are retained)
        let holds_unacked = self.holds_unacked();
        let unacked_after = self.unacked_after(payload.len())?;
        let len = payload.len();
        let sn = self.next_sn;
        self.next_sn += 1;
        self.history_bytes += payload.len();
        self.history.push(sn, payload.clone());
        // A best-effort writer resends nothing, so unless it keeps samples
        // for late joiners (transient-local) a sample needs no place in the
        // history once it is queued: a keep-all history of 64 KiB samples
        // held 256 MiB that nothing would read.
        let limit = if self.reliable || self.retain_acked {
            self.depth.unwrap_or(self.max_samples)
        } else {
            0
        };
        while self.history.len() > limit {
            self.pop_oldest();
        }
        self.out.push_back(Transmit::Data {
            to: None,
            sn: SequenceNumber(sn),
            payload,
        });
        if self.reliable {
            // piggyback a heartbeat, as Cyclone does; it asks for an
            // acknowledgement only every ACK_EVERY samples (and when a
            // keep-all history is half full, by count or by bytes), so that
            // readers do not answer every sample: a reader missing something
            // answers any heartbeat, and the periodic heartbeat asks until
            // everything is acked
            let want_ack = std::mem::take(&mut self.ack_next)
                || sn % ACK_EVERY == 0
                || (holds_unacked
                    && (self.history.len() * 2 >= self.max_samples
                        || unacked_after.saturating_mul(2) >= self.max_unacked_bytes));
            let final_flag = self.hb_after_writes.unwrap_or(true) && !want_ack;
            self.hb_after_writes = Some(final_flag);
            let next = if len >= LARGE_SAMPLE {
                // the piggybacked heartbeat ends a burst that may have
                // overrun the reader's socket buffer, and gone with it:
                // another soon, once the reader had time to drain
                now + LARGE_SAMPLE_HEARTBEAT.min(self.heartbeat_period)
            } else {
                now + self.heartbeat_period
            };
            self.next_heartbeat = Some(self.next_heartbeat.map_or(next, |t| t.min(next)));
        }
        Some(SequenceNumber(sn))
    }

    /// Drops samples every reader acknowledged (keep-all writers).
    fn release_acked(&mut self) {
        if self.retain_acked {
            return;
        }
        let min_acked = self.min_acked_below();
        while let Some((sn, _)) = self.history.first() {
            if sn >= min_acked {
                break;
            }
            self.pop_oldest();
        }
    }

    /// True when every matched reader acknowledged `sn` (for `publish().confirmed()`).
    pub fn is_acked_by_all(&self, sn: SequenceNumber) -> bool {
        self.readers
            .values()
            .all(|r| !r.reliable || r.acked_below > sn.0)
    }

    /// Makes the heartbeat piggybacked on the next write ask every reader
    /// for an acknowledgement (e.g. for a confirmed write): in the same
    /// datagram as the data, so that a reader that stops reading right
    /// after it (back-pressure) still acknowledges it.
    pub fn request_ack_with_next_write(&mut self) {
        self.ack_next = true;
    }

    /// Asks `reader` at once what it still misses (a heartbeat that wants
    /// an answer). For a writer that resent the fragments a NACK_FRAG asked
    /// for while the sample has more than that NACK_FRAG could name (a
    /// fragment number set spans 256): the reader then asks for the next
    /// ones a round trip later instead of a heartbeat period later. An
    /// 8 MiB sample whose first burst overflowed a 1 MiB socket buffer
    /// took ~20 periodic heartbeats (2 s) to repair.
    pub fn heartbeat_to(&mut self, reader: Guid) {
        if self.reliable && self.readers.contains_key(&reader) {
            self.push_heartbeat(Some(reader), false);
        }
    }

    /// Queues a liveliness-only heartbeat (DDS `assert_liveliness` on a
    /// manual-by-topic writer): the range it has, a fresh count and the L
    /// flag, to every matched reader, asking for no answer.
    pub fn assert_liveliness(&mut self) {
        self.hb_count = self.hb_count.wrapping_add(1);
        self.out.push_back(Transmit::Heartbeat {
            to: None,
            first: SequenceNumber(self.first_sn()),
            last: SequenceNumber(self.next_sn - 1),
            count: self.hb_count,
            final_flag: true,
            liveliness: true,
        });
    }

    /// Queues a heartbeat for one reader, or for all of them. A fresh
    /// reader (see [`ReaderProxy::fresh`]) gets its own, announcing nothing
    /// from its start on and asking for an answer.
    fn push_heartbeat(&mut self, to: Option<Guid>, final_flag: bool) {
        self.hb_count = self.hb_count.wrapping_add(1);
        let count = self.hb_count;
        let range = (
            SequenceNumber(self.first_sn()),
            SequenceNumber(self.next_sn - 1),
        );
        let of = |p: &ReaderProxy| {
            if p.fresh {
                (SequenceNumber(p.start), SequenceNumber(p.start - 1), false)
            } else {
                (range.0, range.1, final_flag)
            }
        };
        let heartbeat = |to, (first, last, final_flag)| Transmit::Heartbeat {
            to,
            first,
            last,
            count,
            final_flag,
            liveliness: false,
        };
        match to {
            Some(r) => {
                let h = self
                    .readers
                    .get(&r)
                    .map_or((range.0, range.1, final_flag), of);
                self.out.push_back(heartbeat(Some(r), h));
            }
            None if !self.readers.values().any(|p| p.fresh) => {
                self.out
                    .push_back(heartbeat(None, (range.0, range.1, final_flag)));
            }
            None => {
                // one each while some reader is fresh, in a stable order
                let mut each: Vec<(Guid, (SequenceNumber, SequenceNumber, bool))> = self
                    .readers
                    .iter()
                    .filter(|(_, p)| p.reliable)
                    .map(|(g, p)| (*g, of(p)))
                    .collect();
                each.sort_unstable_by_key(|(g, _)| *g);
                for (g, h) in each {
                    self.out.push_back(heartbeat(Some(g), h));
                }
            }
        }
    }

    /// An ACKNACK from a matched reader, received at `now`: record the
    /// acknowledgement and resend (or GAP) what it is missing.
    pub fn handle_acknack(&mut self, reader: Guid, a: &AckNack, now: Instant) {
        let Some(p) = self.readers.get_mut(&reader) else {
            return;
        };
        // a pre-emptive ACKNACK (base 1 or less, nothing missing, count 0:
        // Cyclone DDS's and ours; RTI sends base 0): a reader that matched
        // us anew and has nothing. Taken whatever the count and answered
        // with a heartbeat, even an empty one, which ends its repeats.
        let base = a.reader_sn_state.base.0;
        let preemptive =
            a.reader_sn_state.num_bits == 0 && (base < 1 || (base == 1 && a.count == 0));
        let silent = p
            .last_ack_at
            .is_none_or(|t| now.saturating_duration_since(t) >= REMATCH_AFTER_SILENCE);
        // A reader that lost our participant and found it again (an
        // asymmetric lease expiry: our side never lost it) matched us anew
        // and counts from 0 again: after a silence, its pre-emptive
        // ACKNACK, or one below what it had acknowledged (our heartbeat
        // overtook its pre-emptive one), makes a new match of it.
        let rematch =
            silent && !p.fresh && p.acked_below > p.start && (preemptive || base < p.acked_below);
        if rematch {
            // a durable reader gets the history again; a volatile one
            // starts now (what it had before was delivered: again would
            // be twice), told so by a GAP
            p.requested.clear();
            let first = self.history.first().map_or(self.next_sn, |(sn, _)| sn);
            if p.replay {
                p.start = first;
                p.acked_below = first;
            } else {
                p.start = self.next_sn;
                p.acked_below = self.next_sn;
                p.fresh = true;
                if first < self.next_sn {
                    self.out.push_back(Transmit::Gap {
                        to: reader,
                        start: SequenceNumber(first),
                        list: SequenceNumberSet::empty(SequenceNumber(self.next_sn)),
                    });
                }
            }
        }
        if preemptive || rematch {
            p.last_acknack_count = Some(a.count);
            if rematch {
                p.last_ack_at = Some(now);
                // it lacks what it is to get: heartbeat until it has it
                self.next_heartbeat
                    .get_or_insert(now + self.heartbeat_period);
            }
            if !a.final_flag || rematch {
                self.push_heartbeat(Some(reader), false);
            }
            return;
        }
        // duplicate or stale, unless after a silence (its counter may have
        // started again: Cyclone DDS takes any count after 500 ms too)
        if !silent
            && p.last_acknack_count
                .is_some_and(|c| a.count.wrapping_sub(c) <= 0)
        {
            return;
        }
        p.last_acknack_count = Some(a.count);
        p.last_ack_at = Some(now);
        // an answer to a heartbeat: from now on it hears the real range,
        // at once if something is unacknowledged
        let answered = p.fresh && a.count != 0;
        p.fresh &= !answered;
        let acked_more = base > p.acked_below;
        if acked_more {
            p.acked_below = base.min(self.next_sn);
        }
        for sn in a.reader_sn_state.iter() {
            p.requested.insert(sn.0);
        }
        let start = p.start;
        let requested: Vec<i64> = std::mem::take(&mut p.requested).into_iter().collect();
        let mut gaps: Vec<(i64, i64)> = Vec::new();
        for sn in requested {
            if sn >= self.next_sn {
                continue;
            }
            match self.history.get(sn).filter(|_| sn >= start) {
                Some(payload) => self.out.push_back(Transmit::Data {
                    to: Some(reader),
                    sn: SequenceNumber(sn),
                    payload: payload.clone(),
                }),
                // consecutive runs only: a GAP must never cover a sample
                // that is being resent
                None => match gaps.last_mut() {
                    Some((_, hi)) if *hi + 1 == sn => *hi = sn,
                    _ => gaps.push((sn, sn)),
                },
            }
        }
        // samples that fell out of the history (or predate a volatile
        // reader) are irrelevant now: say so
        for (lo, hi) in gaps {
            self.out.push_back(Transmit::Gap {
                to: reader,
                start: SequenceNumber(lo),
                list: SequenceNumberSet::empty(SequenceNumber(hi + 1)),
            });
        }
        if (answered || (!a.final_flag && a.reader_sn_state.num_bits == 0)) && base < self.next_sn {
            self.push_heartbeat(Some(reader), false);
        }
        if acked_more {
            self.drop_acked_marked();
        }
    }

    /// When the next periodic heartbeat is due.
    pub fn poll_timeout(&self) -> Option<Instant> {
        self.next_heartbeat
    }

    /// Fires timers: a heartbeat while some reader has not acknowledged everything.
    pub fn handle_timeout(&mut self, now: Instant) {
        if let Some(t) = self.next_heartbeat {
            if now >= t {
                let unacked = self
                    .readers
                    .values()
                    .any(|r| r.reliable && r.acked_below < self.next_sn);
                if unacked {
                    self.push_heartbeat(None, false);
                    self.next_heartbeat = Some(now + self.heartbeat_period);
                } else {
                    self.next_heartbeat = None;
                }
            }
        }
    }

    /// A reliable writer that keeps what is unacknowledged, bounded in
    /// samples and in bytes, and refuses writes when full: keep-all, or
    /// keep-last told to [`Writer::keep_unacked`].
    fn holds_unacked(&self) -> bool {
        (self.depth.is_none() || self.keep_unacked) && self.reliable
    }

    /// True when [`Writer::write`] would take a sample of `len` bytes now
    /// (a keep-all reliable history can be full, in samples or in
    /// unacknowledged bytes).
    pub fn has_room(&mut self, len: usize) -> bool {
        self.unacked_after(len).is_some()
    }

    /// The unacknowledged bytes once a sample of `len` bytes is in (0 when
    /// the writer does not count them), or `None` when it does not fit.
    fn unacked_after(&mut self, len: usize) -> Option<usize> {
        if !self.holds_unacked() {
            return Some(0);
        }
        self.release_acked();
        let limit = self.depth.unwrap_or(self.max_samples).min(self.max_samples);
        if self.history.len() >= limit {
            // a history that keeps acknowledged samples (for late joiners)
            // drops its oldest to make room, once every reader has it
            let below = self.min_acked_below();
            if self.history.first().is_none_or(|(sn, _)| sn >= below) {
                return None;
            }
        }
        let unacked = self.unacked_bytes();
        if unacked > 0 && unacked + len > self.max_unacked_bytes {
            return None;
        }
        Some(unacked + len)
    }

    /// The next thing to send.
    pub fn poll_transmit(&mut self) -> Option<Transmit> {
        if let Some(t) = self.out.pop_front() {
            return Some(t);
        }
        let final_flag = self.hb_after_writes.take()?;
        self.push_heartbeat(None, final_flag);
        self.out.pop_front()
    }
}

/// A piggybacked heartbeat asks for an acknowledgement every this many samples.
const ACK_EVERY: i64 = 16;

/// A sample at least this large is sent in a burst longer than a socket
/// buffer may hold (Cyclone DDS and Courier ask for 1 MiB; Linux's default
/// is 208 KiB) ...
const LARGE_SAMPLE: usize = 128 * 1024;

/// ... so the next heartbeat follows it after this, not a whole
/// heartbeat period later: the repair of what the reader dropped starts
/// then (an 8 MiB sample to a reader with a 1 MiB buffer took a 100 ms
/// period per sample).
const LARGE_SAMPLE_HEARTBEAT: Duration = Duration::from_millis(5);

#[derive(Debug)]
struct WriterProxy {
    /// Next sequence number to deliver.
    next: i64,
    /// Received out of order, waiting for the gap before them to fill.
    pending: BTreeMap<i64, Option<Payload>>,
    /// Highest sequence number the writer says it has.
    last_available: i64,
    last_hb_count: Option<i32>,
    acknack_count: i32,
    ack_due: bool,
    /// When it matched (the pre-emptive ACKNACKs slow down with age).
    matched_at: Instant,
    /// When the next pre-emptive ACKNACK goes out; `None` once the writer
    /// has sent a heartbeat (or for a best-effort reader).
    preemptive_at: Option<Instant>,
    /// It keeps a history for late joiners (transient-local or more).
    durable: bool,
}

/// How long after the match a pre-emptive ACKNACK is sent again while the
/// writer has sent no heartbeat: as Cyclone DDS does, every second for
/// the first 10 s, then every 2 s up to a minute, 5 s up to two, 10 s on.
fn preemptive_interval(age: Duration) -> Duration {
    let secs = match age.as_secs() {
        0..=9 => 1,
        10..=59 => 2,
        60..=119 => 5,
        _ => 10,
    };
    Duration::from_secs(secs)
}

/// [`Reader::max_pending_bytes`] unless told otherwise.
const DEFAULT_MAX_PENDING_BYTES: usize = 64 << 20;

/// Payload bytes of an out-of-order buffer.
fn held(pending: &BTreeMap<i64, Option<Payload>>) -> usize {
    pending.values().flatten().map(|p| p.len()).sum()
}

/// A reader's view of its matched writers: in-order delivery for reliable
/// writers, newest-only for best-effort ones.
#[derive(Debug)]
pub struct Reader {
    reliable: bool,
    /// A volatile reader: it takes nothing a writer wrote before the
    /// match (see [`Reader::volatile`]).
    volatile: bool,
    /// Most out-of-order samples buffered per writer.
    max_pending: usize,
    /// Most payload bytes buffered out of order, all writers together.
    max_pending_bytes: usize,
    /// Payload bytes buffered out of order now.
    pending_bytes: usize,
    writers: HashMap<Guid, WriterProxy>,
    samples: VecDeque<(Guid, SequenceNumber, Payload)>,
    out: VecDeque<Transmit>,
    /// No pre-emptive ACKNACK is due before this (it may be early: a
    /// heartbeat that ends one does not move it).
    next_preemptive: Option<Instant>,
}

impl Reader {
    /// A reader; `max_pending` bounds the out-of-order buffer per writer.
    pub fn new(reliable: bool, max_pending: usize) -> Self {
        Reader {
            reliable,
            volatile: false,
            max_pending: max_pending.max(1),
            max_pending_bytes: DEFAULT_MAX_PENDING_BYTES,
            pending_bytes: 0,
            writers: HashMap::new(),
            samples: VecDeque::new(),
            out: VecDeque::new(),
            next_preemptive: None,
        }
    }

    /// Bounds the payload bytes buffered out of order, all writers
    /// together (default 64 MiB): a sample that does not come next and
    /// would go over it is dropped, and the writer sends it again when
    /// asked. The sample that comes next is always taken.
    pub fn max_pending_bytes(mut self, max: usize) -> Self {
        self.max_pending_bytes = max;
        self
    }

    /// Payload bytes buffered out of order.
    pub fn pending_bytes(&self) -> usize {
        self.pending_bytes
    }

    /// Makes this reader volatile (DURABILITY VOLATILE): the first
    /// HEARTBEAT of a writer that keeps a history for late joiners (see
    /// [`Reader::add_durable_writer`]) is where it starts, so that what the
    /// writer kept from before the match is not asked for (DDS 1.4
    /// §2.2.3.4). Samples it received before that HEARTBEAT were written
    /// after the match and are kept, and so is everything after the first
    /// of them. Cyclone DDS starts a volatile reader the same way (its
    /// first heartbeat's GAP up to `lastSN`); without it a reliable volatile
    /// reader asked a Cyclone transient-local writer for its whole history
    /// and delivered it. A volatile writer's samples from just before the
    /// match are still taken: what it holds is what its readers have not
    /// acknowledged yet, often samples written while this reader's
    /// discovery of it lagged behind its discovery of this reader.
    pub fn volatile(mut self) -> Self {
        self.volatile = true;
        self
    }

    /// A writer with a history for late joiners (transient-local or more)
    /// matched: as [`Reader::add_writer`], and a volatile reader starts at
    /// its first HEARTBEAT (see [`Reader::volatile`]).
    pub fn add_durable_writer(&mut self, writer: Guid, now: Instant) {
        self.add_writer(writer, now);
        if let Some(w) = self.writers.get_mut(&writer) {
            w.durable = true;
        }
    }

    /// A writer matched. A reliable reader tells it at once with a
    /// pre-emptive ACKNACK (DDSI-RTPS §8.4.2.3.4: base 1, nothing
    /// missing, count 0), and again with growing intervals
    /// ([`Reader::poll_timeout`]) until the writer sends a heartbeat.
    ///
    /// The writer may well know the reader already: after an asymmetric
    /// lease expiry (this side lost the writer's participant and found it
    /// again, the writer's side never lost ours) the writer believes the
    /// reader has everything, heartbeats no more, and, without this, the
    /// reader would wait for it forever.
    pub fn add_writer(&mut self, writer: Guid, now: Instant) {
        if self.writers.contains_key(&writer) {
            return;
        }
        let mut proxy = WriterProxy {
            next: 1,
            pending: BTreeMap::new(),
            last_available: 0,
            last_hb_count: None,
            acknack_count: 0,
            ack_due: false,
            matched_at: now,
            preemptive_at: None,
            durable: false,
        };
        if self.reliable {
            self.out.push_back(Self::preemptive(writer));
            let at = now + preemptive_interval(Duration::ZERO);
            proxy.preemptive_at = Some(at);
            self.next_preemptive = Some(self.next_preemptive.map_or(at, |t| t.min(at)));
        }
        self.writers.insert(writer, proxy);
    }

    fn preemptive(writer: Guid) -> Transmit {
        Transmit::AckNack {
            to: writer,
            state: SequenceNumberSet::empty(SequenceNumber(1)),
            count: 0,
            final_flag: false,
        }
    }

    /// When [`Reader::handle_timeout`] must be called next: a pre-emptive
    /// ACKNACK to a writer that has not sent a heartbeat yet.
    pub fn poll_timeout(&self) -> Option<Instant> {
        self.next_preemptive
    }

    /// Sends the pre-emptive ACKNACKs that are due.
    pub fn handle_timeout(&mut self, now: Instant) {
        if self.next_preemptive.is_none_or(|t| t > now) {
            return;
        }
        let mut next: Option<Instant> = None;
        for (g, w) in &mut self.writers {
            let Some(at) = w.preemptive_at else {
                continue;
            };
            let at = if at <= now {
                self.out.push_back(Self::preemptive(*g));
                let later = now + preemptive_interval(now.saturating_duration_since(w.matched_at));
                w.preemptive_at = Some(later);
                later
            } else {
                at
            };
            next = Some(next.map_or(at, |t| t.min(at)));
        }
        self.next_preemptive = next;
    }

    /// A writer went away.
    pub fn remove_writer(&mut self, writer: Guid) {
        if let Some(w) = self.writers.remove(&writer) {
            self.pending_bytes -= held(&w.pending);
        }
    }

    /// The next sequence number this reader will deliver from a matched
    /// writer (anything below is delivered or given up); `None` if not matched.
    pub fn next_expected(&self, writer: Guid) -> Option<SequenceNumber> {
        self.writers.get(&writer).map(|w| SequenceNumber(w.next))
    }

    /// Delivers what is buffered below `to` in order and moves the next
    /// expected sequence number there: the writer says the rest is gone.
    fn skip_to(
        w: &mut WriterProxy,
        writer: Guid,
        to: i64,
        samples: &mut VecDeque<(Guid, SequenceNumber, Payload)>,
        pending_bytes: &mut usize,
    ) {
        if to <= w.next {
            return;
        }
        let keep = w.pending.split_off(&to);
        for (sn, p) in std::mem::replace(&mut w.pending, keep) {
            if let Some(p) = p {
                *pending_bytes -= p.len();
                samples.push_back((writer, SequenceNumber(sn), p));
            }
        }
        w.next = to;
    }

    /// A DATA (or a reassembled DATA_FRAG sample) from a matched writer.
    pub fn handle_data(&mut self, writer: Guid, sn: SequenceNumber, payload: Payload) {
        let Some(w) = self.writers.get_mut(&writer) else {
            return;
        };
        if !self.reliable {
            if sn.0 >= w.next {
                w.next = sn.0 + 1;
                self.samples.push_back((writer, sn, payload));
            }
            return;
        }
        if sn.0 == w.next && w.pending.is_empty() {
            // the common case: the next one, nothing held back
            w.next += 1;
            self.samples.push_back((writer, sn, payload));
            return;
        }
        if sn.0 < w.next || w.pending.contains_key(&sn.0) {
            return; // duplicate
        }
        if sn.0 > w.next
            && (w.pending.len() >= self.max_pending
                || self.pending_bytes + payload.len() > self.max_pending_bytes)
        {
            return; // no room: the writer will resend it after our ACKNACK
        }
        self.pending_bytes += payload.len();
        w.pending.insert(sn.0, Some(payload));
        Self::drain(w, writer, &mut self.samples, &mut self.pending_bytes);
    }

    fn drain(
        w: &mut WriterProxy,
        writer: Guid,
        samples: &mut VecDeque<(Guid, SequenceNumber, Payload)>,
        pending_bytes: &mut usize,
    ) {
        while let Some(entry) = w.pending.remove(&w.next) {
            if let Some(p) = entry {
                *pending_bytes -= p.len();
                samples.push_back((writer, SequenceNumber(w.next), p));
            }
            w.next += 1;
        }
    }

    /// This reader cannot take sample `sn` of `writer` (it is larger than
    /// it may be): it is skipped as if the writer had sent a GAP for it, so
    /// that a reliable writer goes on with the next instead of resending
    /// it forever. `true` if it was still awaited (the first time only).
    pub fn give_up(&mut self, writer: Guid, sn: SequenceNumber) -> bool {
        let Some(w) = self.writers.get_mut(&writer) else {
            return false;
        };
        if sn.0 < w.next {
            return false;
        }
        if !self.reliable {
            w.next = sn.0 + 1;
            return true;
        }
        if sn.0 == w.next {
            w.next += 1;
            Self::drain(w, writer, &mut self.samples, &mut self.pending_bytes);
            return true;
        }
        if w.pending.contains_key(&sn.0) || w.pending.len() >= self.max_pending {
            // known, or no room: asked for again and given up again later
            return false;
        }
        w.pending.insert(sn.0, None);
        true
    }

    /// A GAP: those sequence numbers will never come.
    pub fn handle_gap(&mut self, writer: Guid, g: &Gap) {
        let Some(w) = self.writers.get_mut(&writer) else {
            return;
        };
        if g.gap_start.0 <= w.next {
            // the gap starts at (or before) what we wait for: jump over it
            Self::skip_to(
                w,
                writer,
                g.gap_list.base.0,
                &mut self.samples,
                &mut self.pending_bytes,
            );
        } else {
            // a gap further on: remember (a bounded part of) it; the rest
            // is asked for again and gapped again later
            let room = self.max_pending.saturating_sub(w.pending.len()) as i64;
            let end = g.gap_list.base.0.min(g.gap_start.0.saturating_add(room));
            for sn in g.gap_start.0..end {
                w.pending.entry(sn).or_insert(None);
            }
        }
        for sn in g.gap_list.iter() {
            if sn.0 >= w.next {
                w.pending.entry(sn.0).or_insert(None);
            }
        }
        Self::drain(w, writer, &mut self.samples, &mut self.pending_bytes);
    }

    /// A HEARTBEAT: skip what the writer no longer has; answer with an ACKNACK.
    pub fn handle_heartbeat(&mut self, writer: Guid, h: &Heartbeat) {
        if !self.reliable {
            return;
        }
        let Some(w) = self.writers.get_mut(&writer) else {
            return;
        };
        // the writer knows us: no more pre-emptive ACKNACKs
        w.preemptive_at = None;
        if w.last_hb_count
            .is_some_and(|c| h.count.wrapping_sub(c) <= 0)
        {
            return;
        }
        let first = w.last_hb_count.is_none();
        w.last_hb_count = Some(h.count);
        w.last_available = w.last_available.max(h.last_sn.0);
        if first && self.volatile && w.durable {
            // start after what the writer had, or at the first sample
            // received since the match, whichever comes first
            let live = w.pending.keys().next().copied();
            let start = live.map_or(h.last_sn.0 + 1, |sn| sn.min(h.last_sn.0 + 1));
            Self::skip_to(w, writer, start, &mut self.samples, &mut self.pending_bytes);
            Self::drain(w, writer, &mut self.samples, &mut self.pending_bytes);
        }
        if h.first_sn.0 > w.next {
            // the writer dropped those: they are lost for us, deliver on
            Self::skip_to(
                w,
                writer,
                h.first_sn.0,
                &mut self.samples,
                &mut self.pending_bytes,
            );
            Self::drain(w, writer, &mut self.samples, &mut self.pending_bytes);
        }
        if !h.final_flag || w.next <= w.last_available {
            w.ack_due = true;
        }
        self.flush_acks();
    }

    fn flush_acks(&mut self) {
        for (g, w) in &mut self.writers {
            if !w.ack_due {
                continue;
            }
            w.ack_due = false;
            let base = SequenceNumber(w.next);
            let span = (w.last_available - w.next + 1).clamp(0, 256) as u32;
            let missing = (w.next..w.next + span as i64)
                .filter(|sn| !w.pending.contains_key(sn))
                .map(SequenceNumber);
            let state = SequenceNumberSet::from_members(base, span, missing);
            w.acknack_count = w.acknack_count.wrapping_add(1);
            let final_flag = state.iter().next().is_none();
            self.out.push_back(Transmit::AckNack {
                to: *g,
                state,
                count: w.acknack_count,
                final_flag,
            });
        }
    }

    /// The next sample to hand to the application, in order per writer.
    pub fn poll_sample(&mut self) -> Option<(Guid, SequenceNumber, Payload)> {
        self.samples.pop_front()
    }

    /// The next thing to send.
    pub fn poll_transmit(&mut self) -> Option<Transmit> {
        self.out.pop_front()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rtps::{EntityId, GuidPrefix};

    /// A deterministic lossy network: drops, duplicates and reorders.
    struct Net {
        seed: u64,
        loss: u32,
        queue: Vec<(u64, Transmit)>,
        tick: u64,
    }

    impl Net {
        fn rand(&mut self) -> u32 {
            self.seed ^= self.seed << 13;
            self.seed ^= self.seed >> 7;
            self.seed ^= self.seed << 17;
            (self.seed >> 32) as u32
        }
        fn send(&mut self, t: Transmit) {
            if self.rand() % 100 < self.loss {
                return;
            }
            let delay = u64::from(self.rand() % 5);
            if self.rand() % 10 == 0 {
                self.queue.push((self.tick + delay + 1, t.clone()));
            }
            self.queue.push((self.tick + delay, t));
        }
        fn due(&mut self) -> Vec<Transmit> {
            self.tick += 1;
            let tick = self.tick;
            let (now, later): (Vec<_>, Vec<_>) =
                self.queue.drain(..).partition(|(t, _)| *t <= tick);
            self.queue = later;
            now.into_iter().map(|(_, t)| t).collect()
        }
    }

    fn guid(e: u8) -> Guid {
        Guid {
            prefix: GuidPrefix([e; 12]),
            entity: EntityId([0, 0, e, 2]),
        }
    }

    fn run(loss: u32, seed: u64, samples: usize, depth: Option<usize>) -> Vec<i64> {
        let (wg, rg) = (guid(1), guid(2));
        let t0 = Instant::now();
        let mut w = Writer::new(wg, true, depth, 64, Duration::from_millis(10));
        let mut r = Reader::new(true, 256);
        w.add_reader(rg, false, t0);
        r.add_writer(wg, t0);
        let mut to_reader = Net {
            seed,
            loss,
            queue: Vec::new(),
            tick: 0,
        };
        let mut to_writer = Net {
            seed: seed ^ 0x9e37_79b9,
            loss,
            queue: Vec::new(),
            tick: 0,
        };
        let mut got = Vec::new();
        let mut written = 0;
        for step in 0..20_000u64 {
            let now = t0 + Duration::from_millis(step);
            // write one sample per ms while the writer accepts (keep-all back-pressure)
            if written < samples && w.write(Arc::from(vec![written as u8; 8]), now).is_some() {
                written += 1;
            }
            w.handle_timeout(now);
            r.handle_timeout(now);
            while let Some(t) = w.poll_transmit() {
                to_reader.send(t);
            }
            for t in to_reader.due() {
                match t {
                    Transmit::Data { sn, payload, .. } => r.handle_data(wg, sn, payload),
                    Transmit::Gap { start, list, .. } => r.handle_gap(
                        wg,
                        &Gap {
                            reader_id: rg.entity,
                            writer_id: wg.entity,
                            gap_start: start,
                            gap_list: list,
                            extra: vec![],
                        },
                    ),
                    Transmit::Heartbeat {
                        first,
                        last,
                        count,
                        final_flag,
                        liveliness,
                        ..
                    } => r.handle_heartbeat(
                        wg,
                        &Heartbeat {
                            reader_id: rg.entity,
                            writer_id: wg.entity,
                            first_sn: first,
                            last_sn: last,
                            count,
                            final_flag,
                            liveliness,
                        },
                    ),
                    Transmit::AckNack { .. } => unreachable!(),
                }
            }
            while let Some((_, sn, p)) = r.poll_sample() {
                assert_eq!(
                    p[0],
                    (sn.0 - 1) as u8,
                    "payload matches its sequence number"
                );
                got.push(sn.0);
            }
            while let Some(t) = r.poll_transmit() {
                to_writer.send(t);
            }
            for t in to_writer.due() {
                if let Transmit::AckNack {
                    state,
                    count,
                    final_flag,
                    ..
                } = t
                {
                    w.handle_acknack(
                        rg,
                        &AckNack {
                            reader_id: rg.entity,
                            writer_id: wg.entity,
                            reader_sn_state: state,
                            count,
                            final_flag,
                        },
                        now,
                    );
                }
            }
            if written == samples && w.is_acked_by_all(SequenceNumber(samples as i64)) {
                break;
            }
        }
        got
    }

    #[test]
    fn reliable_delivery_is_complete_and_in_order_under_30_percent_loss() {
        for seed in [1u64, 7, 42, 1234, 99_999] {
            let got = run(30, seed, 500, None);
            assert_eq!(got, (1..=500).collect::<Vec<_>>(), "seed {seed}");
        }
    }

    #[test]
    fn a_sample_given_up_is_skipped_in_order_and_once() {
        let wg = guid(1);
        let mut r = Reader::new(true, 256);
        r.add_writer(wg, Instant::now());
        let p = |b: u8| -> Payload { Arc::from(vec![b; 4]) };
        // 2 is given up before 1 arrives: held as a gap, 3 waits behind 1
        assert!(r.give_up(wg, SequenceNumber(2)));
        assert!(!r.give_up(wg, SequenceNumber(2)), "once");
        r.handle_data(wg, SequenceNumber(3), p(3));
        assert!(r.poll_sample().is_none());
        r.handle_data(wg, SequenceNumber(1), p(1));
        let got: Vec<i64> = std::iter::from_fn(|| r.poll_sample())
            .map(|(_, sn, _)| sn.0)
            .collect();
        assert_eq!(got, [1, 3]);
        // the next expected one given up: the ones behind it come out
        r.handle_data(wg, SequenceNumber(5), p(5));
        assert!(r.give_up(wg, SequenceNumber(4)));
        assert_eq!(r.poll_sample().map(|(_, sn, _)| sn.0), Some(5));
        assert_eq!(r.next_expected(wg), Some(SequenceNumber(6)));
        // what was delivered is not given up
        assert!(!r.give_up(wg, SequenceNumber(5)));
        // an unknown writer: nothing
        assert!(!r.give_up(guid(9), SequenceNumber(1)));
    }

    #[test]
    fn lossless_network_delivers_everything_once() {
        assert_eq!(run(0, 5, 200, None), (1..=200).collect::<Vec<_>>());
    }

    #[test]
    fn keep_last_writer_gaps_what_it_dropped_and_order_holds() {
        // depth 4 with 30 % loss: some samples are replaced before they are
        // repaired; the reader must never see them out of order or twice
        for seed in [3u64, 11, 77] {
            let got = run(30, seed, 300, Some(4));
            assert!(got.windows(2).all(|w| w[0] < w[1]), "seed {seed}: {got:?}");
            assert_eq!(got.last(), Some(&300), "seed {seed}");
        }
    }

    fn hb(first: i64, last: i64, count: i32) -> Heartbeat {
        Heartbeat {
            reader_id: EntityId::UNKNOWN,
            writer_id: guid(1).entity,
            first_sn: SequenceNumber(first),
            last_sn: SequenceNumber(last),
            count,
            final_flag: false,
            liveliness: false,
        }
    }

    #[test]
    fn hostile_heartbeats_and_gaps_stay_bounded() {
        let wg = guid(1);
        let mut r = Reader::new(true, 16);
        r.add_writer(wg, Instant::now());
        r.handle_data(wg, SequenceNumber(3), Arc::from(vec![3u8]));
        // a heartbeat far ahead skips at once (no per-number work), and what
        // was buffered before that point is still delivered
        r.handle_heartbeat(wg, &hb(1 << 62, 1 << 62, 1));
        assert_eq!(r.next_expected(wg), Some(SequenceNumber(1 << 62)));
        assert_eq!(r.poll_sample().map(|s| s.1), Some(SequenceNumber(3)));
        let gap = |start: i64, base: i64| Gap {
            reader_id: EntityId::UNKNOWN,
            writer_id: wg.entity,
            gap_start: SequenceNumber(start),
            gap_list: SequenceNumberSet::empty(SequenceNumber(base)),
            extra: vec![],
        };
        // a huge gap further on buffers at most max_pending entries
        r.handle_gap(wg, &gap((1 << 62) + 10, i64::MAX));
        assert!(r.writers[&wg].pending.len() <= 16);
        // a huge gap at the front jumps
        r.handle_gap(wg, &gap(1 << 62, i64::MAX - 1));
        assert_eq!(r.next_expected(wg), Some(SequenceNumber(i64::MAX - 1)));
    }

    /// Writers that never send their first sample fill the out-of-order
    /// buffer up to its byte bound, all writers together, not 1024 samples
    /// of up to 16 MiB each (audit 20: 16 fake writers took a reader to
    /// 955 MB); the sample that comes next is always taken, and what was
    /// dropped is delivered in order once sent again.
    #[test]
    fn out_of_order_samples_are_bounded_in_bytes() {
        let (a, b) = (guid(1), guid(2));
        let t0 = Instant::now();
        let mut r = Reader::new(true, 1024).max_pending_bytes(1000);
        r.add_writer(a, t0);
        r.add_writer(b, t0);
        let data = |n: usize| Arc::from(vec![7u8; n]);
        for sn in 2..=20 {
            r.handle_data(a, SequenceNumber(sn), data(100));
        }
        assert_eq!(r.pending_bytes(), 1000, "10 of 100 bytes");
        r.handle_data(b, SequenceNumber(2), data(100));
        assert_eq!(r.pending_bytes(), 1000, "full for every writer");
        // the next one is taken and drains what waited
        r.handle_data(b, SequenceNumber(1), data(100));
        assert_eq!(r.poll_sample().map(|s| (s.0, s.2.len())), Some((b, 100)));
        r.handle_data(a, SequenceNumber(1), data(100));
        assert_eq!(r.pending_bytes(), 0);
        let got: Vec<i64> = std::iter::from_fn(|| r.poll_sample())
            .filter(|s| s.0 == a)
            .map(|s| s.1 .0)
            .collect();
        assert_eq!(got, (1..=11).collect::<Vec<_>>());
        for sn in 12..=20 {
            r.handle_data(a, SequenceNumber(sn), data(100));
        }
        assert_eq!(r.poll_sample().map(|s| s.1 .0), Some(12));
        // a writer that goes takes its bytes with it
        r.handle_data(b, SequenceNumber(5), data(300));
        assert_eq!(r.pending_bytes(), 300);
        r.remove_writer(b);
        assert_eq!(r.pending_bytes(), 0);
    }

    /// A volatile reader starts where a transient-local writer's first
    /// HEARTBEAT says the writer is, keeping what it received since the
    /// match; it takes a volatile writer's unacknowledged samples, and a
    /// transient-local reader asks for the history (audit 18: a Cyclone
    /// DDS transient-local writer's history reached Courier's volatile
    /// readers).
    #[test]
    fn a_volatile_reader_starts_at_the_first_heartbeat() {
        let wg = guid(1);
        let t0 = Instant::now();
        let acknack = |r: &mut Reader| loop {
            match r.poll_transmit() {
                Some(Transmit::AckNack { state, .. }) if state.base.0 > 1 => break state,
                Some(_) => continue,
                None => panic!("no ACKNACK"),
            }
        };
        // the writer holds 1..=5 from before the match
        let mut v = Reader::new(true, 16).volatile();
        v.add_durable_writer(wg, t0);
        v.handle_heartbeat(wg, &hb(1, 5, 1));
        let state = acknack(&mut v);
        assert_eq!(
            (state.base.0, state.iter().count()),
            (6, 0),
            "asks for nothing old"
        );
        assert!(v.poll_sample().is_none());
        v.handle_data(wg, SequenceNumber(6), Arc::from(vec![6u8]));
        assert_eq!(v.poll_sample().map(|s| s.1 .0), Some(6));

        // sample 7, written after the match, came before the first
        // heartbeat (which says 7): it is kept, 1..=6 are not asked for
        let mut v = Reader::new(true, 16).volatile();
        v.add_durable_writer(wg, t0);
        v.handle_data(wg, SequenceNumber(7), Arc::from(vec![7u8]));
        assert!(v.poll_sample().is_none(), "held: 1..=6 unknown yet");
        v.handle_heartbeat(wg, &hb(1, 7, 1));
        assert_eq!(v.poll_sample().map(|s| s.1 .0), Some(7));
        assert_eq!(v.next_expected(wg), Some(SequenceNumber(8)));
        // later heartbeats move nothing back
        while v.poll_transmit().is_some() {}
        v.handle_heartbeat(wg, &hb(1, 9, 2));
        let state = acknack(&mut v);
        assert_eq!(
            (state.base.0, state.iter().map(|s| s.0).collect::<Vec<_>>()),
            (8, vec![8, 9])
        );

        // a volatile writer's samples from before the match are taken
        // (what its readers have not acknowledged yet)
        let mut v = Reader::new(true, 16).volatile();
        v.add_writer(wg, t0);
        v.handle_heartbeat(wg, &hb(1, 3, 1));
        let state = loop {
            match v.poll_transmit() {
                Some(Transmit::AckNack { state, count, .. }) if count > 0 => break state,
                Some(_) => continue,
                None => panic!("no ACKNACK"),
            }
        };
        assert_eq!(state.iter().map(|s| s.0).collect::<Vec<_>>(), [1, 2, 3]);

        // a transient-local reader asks for the history
        let mut tl = Reader::new(true, 16);
        tl.add_writer(wg, t0);
        tl.handle_heartbeat(wg, &hb(1, 5, 1));
        let state = loop {
            match tl.poll_transmit() {
                Some(Transmit::AckNack { state, count, .. }) if count > 0 => break state,
                Some(_) => continue,
                None => panic!("no ACKNACK"),
            }
        };
        assert_eq!(
            state.iter().map(|s| s.0).collect::<Vec<_>>(),
            [1, 2, 3, 4, 5]
        );
    }

    #[test]
    fn gaps_never_cover_resent_samples_and_volatile_joiners_get_a_gap() {
        let (wg, rg, late) = (guid(1), guid(2), guid(3));
        let t0 = Instant::now();
        let mut w = Writer::new(wg, true, None, 64, Duration::from_millis(10)).retain_acked(true);
        w.add_reader(rg, true, t0);
        for i in 1..=6u8 {
            w.write(Arc::from(vec![i]), t0).unwrap();
        }
        // samples 2 and 4 replaced (per-instance keep-last), 1..=6 requested
        assert!(w.remove(SequenceNumber(2)) && w.remove(SequenceNumber(4)));
        while w.poll_transmit().is_some() {}
        w.handle_acknack(
            rg,
            &AckNack {
                reader_id: rg.entity,
                writer_id: wg.entity,
                reader_sn_state: SequenceNumberSet::from_members(
                    SequenceNumber(1),
                    6,
                    (1..=6).map(SequenceNumber),
                ),
                count: 1,
                final_flag: false,
            },
            t0,
        );
        let mut data = vec![];
        let mut gaps = vec![];
        while let Some(t) = w.poll_transmit() {
            match t {
                Transmit::Data { sn, .. } => data.push(sn.0),
                Transmit::Gap { start, list, .. } => gaps.push((start.0, list.base.0)),
                _ => {}
            }
        }
        assert_eq!(data, [1, 3, 5, 6]);
        assert_eq!(gaps, [(2, 3), (4, 5)]);
        // a volatile late joiner: GAP for what predates it, also on request
        w.add_reader(late, false, t0);
        assert!(matches!(
            w.poll_transmit(),
            Some(Transmit::Gap { start: SequenceNumber(1), list, .. }) if list.base == SequenceNumber(7)
        ));
        assert_eq!(w.acked_by_all(), SequenceNumber(0));
    }

    /// A reliable writer that wrote samples 1..=3, with a matched reader
    /// (`replay`: durable).
    fn wrote_three(replay: bool) -> (Writer, Guid) {
        let (wg, rg) = (guid(1), guid(2));
        let t0 = Instant::now();
        let mut w = Writer::new(wg, true, None, 64, Duration::from_millis(10)).retain_acked(true);
        w.add_reader(rg, replay, t0);
        for i in 1..=3u8 {
            w.write(Arc::from(vec![i]), t0).unwrap();
        }
        (w, rg)
    }

    /// An ACKNACK of reader `rg` to `guid(1)`.
    fn ack_of(rg: Guid, base: i64, missing: &[i64], count: i32) -> AckNack {
        AckNack {
            reader_id: rg.entity,
            writer_id: guid(1).entity,
            reader_sn_state: SequenceNumberSet::from_members(
                SequenceNumber(base),
                missing.len() as u32,
                missing.iter().map(|s| SequenceNumber(*s)),
            ),
            count,
            final_flag: missing.is_empty(),
        }
    }

    /// A reader that acknowledged everything, then lost and found our
    /// participant again (an asymmetric lease expiry: only its side lost
    /// the match), announces itself with Cyclone DDS's pre-emptive ACKNACK
    /// (base 1, nothing missing, count 0). The writer takes it although
    /// the count went back, heartbeats, and resends all it keeps; it
    /// dropped it as stale before, so the reader never got the writer's
    /// history (its discovery data) again.
    #[test]
    fn a_reader_that_forgot_everything_is_sent_it_again() {
        let (mut w, rg) = wrote_three(true);
        // everything acknowledged, at count 57
        let t0 = Instant::now();
        w.handle_acknack(rg, &ack_of(rg, 4, &[], 57), t0);
        assert_eq!(w.acked_by_all(), SequenceNumber(3));
        while w.poll_transmit().is_some() {}
        // the pre-emptive ACKNACK of a reader that has nothing
        // (a lease later)
        let t1 = t0 + Duration::from_secs(1);
        let mut pre = ack_of(rg, 1, &[], 0);
        pre.final_flag = false;
        w.handle_acknack(rg, &pre, t1);
        assert!(
            matches!(w.poll_transmit(), Some(Transmit::Heartbeat { .. })),
            "a heartbeat for the reader"
        );
        assert_eq!(
            w.acked_by_all(),
            SequenceNumber(0),
            "not acknowledged any more"
        );
        // its answer (count 1, lower than 57) is taken: all three resent
        while w.poll_transmit().is_some() {}
        w.handle_acknack(rg, &ack_of(rg, 1, &[1, 2, 3], 1), t1);
        let mut data = vec![];
        while let Some(t) = w.poll_transmit() {
            if let Transmit::Data { sn, .. } = t {
                data.push(sn.0);
            }
        }
        assert_eq!(data, [1, 2, 3]);
    }

    /// The same for a volatile reader: it matched anew, so it starts at
    /// the next sample (a GAP says so), and what its old match delivered is
    /// not sent again.
    #[test]
    fn a_volatile_reader_that_matched_anew_starts_at_the_match() {
        let (mut w, rg) = wrote_three(false);
        let t0 = Instant::now();
        w.handle_acknack(rg, &ack_of(rg, 4, &[], 5), t0);
        while w.poll_transmit().is_some() {}
        let t1 = t0 + Duration::from_secs(1);
        let mut pre = ack_of(rg, 1, &[], 0);
        pre.final_flag = false;
        w.handle_acknack(rg, &pre, t1);
        let mut gap = None;
        while let Some(t) = w.poll_transmit() {
            if let Transmit::Gap { start, list, .. } = t {
                gap = Some((start.0, list.base.0));
            }
        }
        assert_eq!(
            gap,
            Some((1, 4)),
            "what predates the new match is irrelevant to it"
        );
        // it asks for 1..3 all the same: GAPs, no data
        w.handle_acknack(rg, &ack_of(rg, 1, &[1, 2, 3], 1), t1);
        let mut data = vec![];
        while let Some(t) = w.poll_transmit() {
            if let Transmit::Data { sn, .. } = t {
                data.push(sn.0);
            }
        }
        assert!(data.is_empty(), "{data:?}");
    }

    /// A pre-emptive ACKNACK that comes soon after the reader's answers
    /// (delayed or duplicated by the network) is stale: it is answered
    /// with a heartbeat, but the reader's match goes on; taken as a new
    /// match, a volatile reader would be told to skip samples on their way.
    #[test]
    fn a_pre_emptive_acknack_overtaken_by_the_readers_answers_changes_nothing() {
        for replay in [false, true] {
            let (mut w, rg) = wrote_three(replay);
            let t0 = Instant::now();
            w.handle_acknack(rg, &ack_of(rg, 3, &[], 1), t0);
            while w.poll_transmit().is_some() {}
            let mut pre = ack_of(rg, 1, &[], 0);
            pre.final_flag = false;
            w.handle_acknack(rg, &pre, t0 + Duration::from_millis(30));
            let out: Vec<Transmit> = std::iter::from_fn(|| w.poll_transmit()).collect();
            assert!(
                out.iter().all(|t| matches!(t, Transmit::Heartbeat { .. })) && !out.is_empty(),
                "replay {replay}: a heartbeat only: {out:?}"
            );
            assert_eq!(w.acked_by_all(), SequenceNumber(2), "replay {replay}");
            // its next answer goes on from where it was
            w.handle_acknack(rg, &ack_of(rg, 3, &[3], 2), t0 + Duration::from_millis(40));
            let data: Vec<i64> = std::iter::from_fn(|| w.poll_transmit())
                .filter_map(|t| match t {
                    Transmit::Data { sn, .. } => Some(sn.0),
                    _ => None,
                })
                .collect();
            assert_eq!(data, [3], "replay {replay}");
        }
    }

    /// A reliable reader sends a pre-emptive ACKNACK when a writer
    /// matches, again after 1 s, 2 s... while the writer says nothing, and
    /// stops at the writer's first heartbeat.
    #[test]
    fn a_reader_repeats_its_pre_emptive_acknack_until_the_writer_heartbeats() {
        let (wg, t0) = (guid(1), Instant::now());
        let mut r = Reader::new(true, 16);
        r.add_writer(wg, t0);
        let pre = |r: &mut Reader| {
            std::iter::from_fn(|| r.poll_transmit())
                .filter(|t| {
                    matches!(t, Transmit::AckNack { to, state, count: 0, final_flag: false }
                        if *to == wg && state.base == SequenceNumber(1) && state.num_bits == 0)
                })
                .count()
        };
        assert_eq!(pre(&mut r), 1, "at once");
        assert_eq!(r.poll_timeout(), Some(t0 + Duration::from_secs(1)));
        r.handle_timeout(t0 + Duration::from_millis(999));
        assert_eq!(pre(&mut r), 0);
        for s in 1..=12u64 {
            let now = t0 + Duration::from_secs(s);
            if r.poll_timeout().is_some_and(|t| t <= now) {
                r.handle_timeout(now);
            }
        }
        // every second for 10 s, then every 2 s: 1 s .. 10 s and 12 s
        assert_eq!(pre(&mut r), 11);
        let hb = Heartbeat {
            reader_id: EntityId([0, 0, 2, 7]),
            writer_id: wg.entity,
            first_sn: SequenceNumber(1),
            last_sn: SequenceNumber(0),
            count: 1,
            final_flag: false,
            liveliness: false,
        };
        r.handle_heartbeat(wg, &hb);
        r.handle_timeout(t0 + Duration::from_secs(60));
        let out: Vec<Transmit> = std::iter::from_fn(|| r.poll_transmit()).collect();
        assert!(
            matches!(
                &out[..],
                [Transmit::AckNack {
                    count: 1,
                    final_flag: true,
                    ..
                }]
            ),
            "the heartbeat's answer, and no more pre-emptive ones: {out:?}"
        );
        assert_eq!(r.poll_timeout(), None);
        // a best-effort reader sends none
        let mut be = Reader::new(false, 16);
        be.add_writer(wg, t0);
        assert_eq!(be.poll_transmit(), None);
        assert_eq!(be.poll_timeout(), None);
    }

    /// Cyclone DDS's reader, as far as its start point goes: DATA that
    /// arrives while its own matching is in progress is dropped, and the
    /// first heartbeat it processes moves its start past that heartbeat's
    /// last sequence number (ddsi_receive.c, handle_Heartbeat).
    #[derive(Default)]
    struct StartsAtFirstHeartbeat {
        next: i64,
        seen_heartbeat: bool,
        last_available: i64,
        held: BTreeSet<i64>,
        got: Vec<i64>,
        count: i32,
    }

    impl StartsAtFirstHeartbeat {
        fn deliver(&mut self) {
            while self.held.remove(&self.next) {
                self.got.push(self.next);
                self.next += 1;
            }
        }

        /// Takes one transmit; returns its ACKNACK, if it sends one.
        fn take(&mut self, me: Guid, w: Guid, t: Transmit, matching: bool) -> Option<AckNack> {
            match t {
                Transmit::Data { sn, .. } if !matching && sn.0 >= self.next => {
                    self.held.insert(sn.0);
                }
                Transmit::Gap { list, .. } => {
                    self.next = self.next.max(list.base.0);
                }
                Transmit::Heartbeat {
                    first,
                    last,
                    final_flag,
                    ..
                } => {
                    let start = if self.seen_heartbeat {
                        first.0
                    } else {
                        last.0 + 1
                    };
                    self.seen_heartbeat = true;
                    self.next = self.next.max(start);
                    self.held.retain(|&sn| sn >= start);
                    self.last_available = self.last_available.max(last.0);
                    self.deliver();
                    if !final_flag || self.next <= self.last_available {
                        self.count += 1;
                        let span = (self.last_available - self.next + 1).max(0) as u32;
                        let missing = (self.next..self.next + i64::from(span))
                            .filter(|sn| !self.held.contains(sn))
                            .map(SequenceNumber);
                        return Some(AckNack {
                            reader_id: me.entity,
                            writer_id: w.entity,
                            reader_sn_state: SequenceNumberSet::from_members(
                                SequenceNumber(self.next),
                                span,
                                missing,
                            ),
                            count: self.count,
                            final_flag: false,
                        });
                    }
                }
                _ => {}
            }
            self.deliver();
            None
        }
    }

    #[test]
    fn a_large_sample_is_followed_by_a_heartbeat_soon_a_small_one_a_period_later() {
        let t0 = Instant::now();
        let period = Duration::from_millis(100);
        let mut w = Writer::new(guid(1), true, None, 64, period);
        w.add_reader(guid(2), false, t0);
        while w.poll_transmit().is_some() {}
        w.write(Arc::from(vec![0u8; 100]), t0).unwrap();
        assert_eq!(w.poll_timeout(), Some(t0 + period));
        // a large one brings it forward, and it stays there
        let t1 = t0 + Duration::from_millis(1);
        w.write(Arc::from(vec![0u8; LARGE_SAMPLE]), t1).unwrap();
        assert_eq!(w.poll_timeout(), Some(t1 + LARGE_SAMPLE_HEARTBEAT));
        w.write(Arc::from(vec![0u8; 100]), t1).unwrap();
        assert_eq!(w.poll_timeout(), Some(t1 + LARGE_SAMPLE_HEARTBEAT));
        while w.poll_transmit().is_some() {}
        // it asks the unacknowledging reader, then the period resumes
        let t2 = t1 + LARGE_SAMPLE_HEARTBEAT;
        w.handle_timeout(t2);
        assert!(matches!(
            w.poll_transmit(),
            Some(Transmit::Heartbeat {
                final_flag: false,
                ..
            })
        ));
        assert_eq!(w.poll_timeout(), Some(t2 + period));
    }

    #[test]
    fn a_reader_that_starts_at_its_first_heartbeat_loses_nothing_written_after_the_match() {
        let (wg, rg) = (guid(1), guid(2));
        let t0 = Instant::now();
        let mut w = Writer::new(wg, true, Some(16), 64, Duration::from_millis(100));
        w.write(Arc::from(vec![0u8]), t0).unwrap(); // before the match
        while w.poll_transmit().is_some() {}
        let mut r = StartsAtFirstHeartbeat {
            next: 1,
            ..Default::default()
        };
        // the match's heartbeat reaches the reader before it knows the writer
        w.add_reader(rg, false, t0);
        let mut before = Vec::new();
        while let Some(t) = w.poll_transmit() {
            before.push(t);
        }
        assert!(before
            .iter()
            .any(|t| matches!(t, Transmit::Heartbeat { .. })));
        // sample 2 arrives while the reader's matching is still in progress:
        // the DATA is dropped, its piggybacked heartbeat is the first one seen
        w.write(Arc::from(vec![2u8]), t0).unwrap();
        let mut acks = Vec::new();
        while let Some(t) = w.poll_transmit() {
            if let Transmit::Heartbeat { last, .. } = t {
                assert!(last.0 < 2, "a fresh reader hears nothing of sample 2 yet");
            }
            acks.extend(r.take(rg, wg, t, true));
        }
        // from now on the network works; later writes go out as usual
        w.write(Arc::from(vec![3u8]), t0).unwrap();
        for i in 1..=10 {
            let now = t0 + Duration::from_millis(100 * i);
            for a in acks.drain(..) {
                w.handle_acknack(rg, &a, now);
            }
            w.handle_timeout(now);
            while let Some(t) = w.poll_transmit() {
                acks.extend(r.take(rg, wg, t, false));
            }
        }
        assert_eq!(r.got, [2, 3], "sample 1 predates the match; 2 is resent");
        assert_eq!(w.acked_by_all(), SequenceNumber(3));
        // once it answered, heartbeats go to all readers at once again
        w.write(Arc::from(vec![4u8]), t0).unwrap();
        let hbs: Vec<_> = std::iter::from_fn(|| w.poll_transmit())
            .filter_map(|t| match t {
                Transmit::Heartbeat { to, last, .. } => Some((to, last.0)),
                _ => None,
            })
            .collect();
        assert_eq!(hbs, [(None, 4)]);
    }

    #[test]
    fn history_keeps_order_through_removals_in_the_middle() {
        let p = |n: u8| -> Payload { Arc::new(vec![n; usize::from(n)]) };
        let mut h = History::default();
        for sn in 5..10 {
            h.push(sn, p(sn as u8));
        }
        assert_eq!(h.len(), 5);
        assert_eq!(h.remove(7).as_deref(), Some(&vec![7u8; 7]));
        assert!(h.remove(7).is_none() && h.get(7).is_none());
        assert_eq!(h.get(8).map(|p| p.len()), Some(8));
        assert!(h.get(4).is_none() && h.get(10).is_none() && h.get(i64::MIN).is_none());
        let sns: Vec<i64> = h.iter_from(i64::MIN).map(|(sn, _)| sn).collect();
        assert_eq!(sns, [5, 6, 8, 9]);
        let sns: Vec<i64> = h.iter_from(7).map(|(sn, _)| sn).collect();
        assert_eq!(sns, [8, 9]);
        // removing the oldest moves the front past the hole
        assert!(h.remove(5).is_some());
        assert_eq!(h.pop_first().map(|(sn, _)| sn), Some(6));
        assert_eq!(h.first().map(|(sn, _)| sn), Some(8));
        assert_eq!(h.len(), 2);
        assert_eq!(h.pop_first().map(|(sn, _)| sn), Some(8));
        assert_eq!(h.pop_first().map(|(sn, _)| sn), Some(9));
        assert!(h.pop_first().is_none() && h.first().is_none());
        assert_eq!(h.len(), 0);
        // a new run starts wherever the next write is
        h.push(20, p(1));
        assert_eq!(h.first().map(|(sn, _)| sn), Some(20));
    }

    #[test]
    fn best_effort_readers_never_hold_a_reliable_history() {
        let (wg, be, rel) = (guid(1), guid(2), guid(3));
        let t0 = Instant::now();
        let mut w = Writer::new(wg, true, None, 4, Duration::from_millis(10));
        w.add_best_effort_reader(be);
        // keep-all with room for 4: a reader that never acknowledges must
        // not fill it (it did, and the writer blocked for good)
        for i in 1..=10u8 {
            let sn = w.write(Arc::from(vec![i]), t0).expect("room");
            assert!(w.is_acked_by_all(sn));
        }
        assert_eq!(w.acked_by_all(), SequenceNumber(10));
        // no periodic heartbeat for it either
        w.handle_timeout(t0 + Duration::from_secs(1));
        assert_eq!(w.poll_timeout(), None);
        // a reliable reader still holds what it has not acknowledged
        w.add_reader(rel, false, t0);
        for i in 11..=14u8 {
            w.write(Arc::from(vec![i]), t0).expect("room");
        }
        assert_eq!(w.write(Arc::from(vec![15u8]), t0), None);
        assert_eq!(w.acked_by_all(), SequenceNumber(10));
    }

    /// A volatile best-effort writer keeps nothing once a sample is queued
    /// (it resends nothing); a transient-local one keeps its depth for
    /// late joiners; a reliable one keeps what is unacknowledged.
    #[test]
    fn only_writers_that_may_resend_keep_a_history() {
        let t0 = Instant::now();
        let mut be = Writer::new(guid(1), false, None, 4096, Duration::from_millis(10));
        be.add_best_effort_reader(guid(2));
        for i in 0..100u8 {
            let sn = be.write(Arc::from(vec![i; 1000]), t0).expect("room");
            assert_eq!(be.samples().count(), 0);
            match be.poll_transmit() {
                Some(Transmit::Data { sn: s, payload, .. }) => {
                    assert_eq!((s, payload[0]), (sn, i), "the queued sample still goes out");
                }
                t => panic!("expected the sample, got {t:?}"),
            }
        }
        let mut durable = Writer::new(guid(1), false, Some(3), 4096, Duration::from_millis(10))
            .retain_acked(true);
        for i in 0..10u8 {
            durable.write(Arc::from(vec![i]), t0).expect("room");
        }
        assert_eq!(durable.samples().count(), 3);
        let mut rel = Writer::new(guid(1), true, None, 4096, Duration::from_millis(10));
        rel.add_reader(guid(2), false, t0);
        for i in 0..10u8 {
            rel.write(Arc::from(vec![i]), t0).expect("room");
        }
        assert_eq!(rel.samples().count(), 10, "unacknowledged: kept for repair");
    }

    fn ack_up_to(w: &mut Writer, reader: Guid, next: i64, count: i32) {
        w.handle_acknack(
            reader,
            &AckNack {
                reader_id: reader.entity,
                writer_id: w.guid().entity,
                reader_sn_state: SequenceNumberSet::empty(SequenceNumber(next)),
                count,
                final_flag: true,
            },
            Instant::now(),
        );
    }

    /// Samples marked to drop once acknowledged (an unregistered
    /// instance's, in a transient-local history) stay while a reader still
    /// lacks them, so that a repair finds them, and leave as acknowledged;
    /// with no reliable reader they leave at once. Unmarked samples stay.
    #[test]
    fn marked_samples_leave_a_retaining_history_once_acknowledged() {
        let (wg, rg) = (guid(1), guid(2));
        let t0 = Instant::now();
        let mut w = Writer::new(wg, true, None, 16, Duration::from_millis(10)).retain_acked(true);
        w.add_reader(rg, false, t0);
        for i in 1..=4u8 {
            w.write(Arc::from(vec![i]), t0).expect("room");
        }
        w.drop_once_acked([SequenceNumber(1), SequenceNumber(3)]);
        let held = |w: &Writer| -> Vec<i64> { w.samples().map(|(sn, _)| sn.0).collect() };
        assert_eq!(held(&w), [1, 2, 3, 4], "unacknowledged: kept for repairs");
        ack_up_to(&mut w, rg, 3, 1);
        assert_eq!(held(&w), [2, 3, 4]);
        ack_up_to(&mut w, rg, 5, 2);
        assert_eq!(held(&w), [2, 4], "acknowledged and unmarked: retained");
        // no reliable reader left: marked samples go at once
        w.remove_reader(rg);
        w.drop_once_acked([SequenceNumber(4), SequenceNumber(9)]);
        assert_eq!(held(&w), [2]);
        // a reader that unmatches was the last one holding a mark back
        let mut w = Writer::new(wg, true, None, 16, Duration::from_millis(10)).retain_acked(true);
        w.add_reader(rg, false, t0);
        w.write(Arc::from(vec![1u8]), t0).expect("room");
        w.drop_once_acked([SequenceNumber(1)]);
        assert_eq!(held(&w), [1]);
        w.remove_reader(rg);
        assert!(held(&w).is_empty());
    }

    /// Per-instance keep-last (`keep_unacked`): a full history refuses
    /// while its oldest sample is unacknowledged (dropping it would lose
    /// another instance's last change), and makes room once it is.
    #[test]
    fn keep_unacked_refuses_instead_of_dropping_what_a_reader_lacks() {
        let (wg, rg) = (guid(1), guid(2));
        let t0 = Instant::now();
        let mut w = Writer::new(wg, true, Some(4), 4, Duration::from_millis(10)).keep_unacked(true);
        w.add_reader(rg, false, t0);
        for i in 1..=4u8 {
            assert!(w.has_room(1));
            w.write(Arc::from(vec![i]), t0).expect("room");
        }
        assert!(!w.has_room(1));
        assert_eq!(w.write(Arc::from(vec![5u8]), t0), None);
        assert_eq!(w.samples().count(), 4, "nothing unacknowledged dropped");
        ack_up_to(&mut w, rg, 3, 1);
        let sn = w
            .write(Arc::from(vec![5u8]), t0)
            .expect("room once acknowledged");
        assert_eq!(sn, SequenceNumber(5));
        // a plain keep-last writer drops its oldest, acknowledged or not
        let mut plain = Writer::new(wg, true, Some(4), 4, Duration::from_millis(10));
        plain.add_reader(rg, false, t0);
        for i in 1..=5u8 {
            plain.write(Arc::from(vec![i]), t0).expect("room");
        }
        assert_eq!(
            plain.samples().next().map(|(sn, _)| sn),
            Some(SequenceNumber(2))
        );
    }

    /// Per-instance keep-last of a transient-local keyed writer (what
    /// `Participant::create_writer` makes of one): one instance written
    /// once and kept for late joiners, another rewritten over and over,
    /// each write replacing its previous sample. The history holds two
    /// samples; what it takes in memory must not grow with the number of
    /// writes (it kept an empty slot per replaced sample behind the
    /// oldest one, for ever: 8 bytes a write, 31 MB after 4 million).
    #[test]
    fn replaced_samples_behind_a_kept_one_leave_no_trace() {
        let t0 = Instant::now();
        let mut w = Writer::new(guid(1), true, Some(4096), 4096, Duration::from_millis(10))
            .retain_acked(true)
            .keep_unacked(true);
        w.write(Arc::from(vec![1u8]), t0).expect("room");
        let mut last = w.write(Arc::from(vec![2u8]), t0).expect("room");
        for i in 0..100_000u32 {
            assert!(w.remove(last));
            last = w.write(Arc::from(vec![i as u8]), t0).expect("room");
        }
        assert_eq!(w.history.len(), 2);
        let kept: Vec<i64> = w.samples().map(|(sn, _)| sn.0).collect();
        assert_eq!(kept, [1, last.0]);
        assert!(
            w.history.slots.len() <= 2 * w.history.len() + HISTORY_SLACK,
            "{} slots for {} samples",
            w.history.slots.len(),
            w.history.len()
        );
        assert!(w.get(SequenceNumber(1)).is_some() && w.get(last).is_some());
        assert!(w.get(SequenceNumber(2)).is_none());
    }

    /// A transient-local keep-all history at its sample limit drops its
    /// oldest acknowledged sample for a new one (it stalled for good: the
    /// acknowledged samples it keeps for late joiners filled it).
    #[test]
    fn a_full_durable_keep_all_history_makes_room_from_acknowledged_samples() {
        let (wg, rg) = (guid(1), guid(2));
        let t0 = Instant::now();
        let mut w = Writer::new(wg, true, None, 4, Duration::from_millis(10)).retain_acked(true);
        w.add_reader(rg, false, t0);
        for i in 1..=4u8 {
            w.write(Arc::from(vec![i]), t0).expect("room");
        }
        assert_eq!(
            w.write(Arc::from(vec![5u8]), t0),
            None,
            "all unacknowledged"
        );
        ack_up_to(&mut w, rg, 5, 1);
        for i in 5..=12u8 {
            assert!(w.has_room(1));
            let sn = w.write(Arc::from(vec![i]), t0).expect("room");
            ack_up_to(&mut w, rg, sn.0 + 1, i32::from(i));
        }
        let kept: Vec<i64> = w.samples().map(|(sn, _)| sn.0).collect();
        assert_eq!(kept, [9, 10, 11, 12], "the newest, for late joiners");
    }

    /// `has_room` says beforehand what `write` will do, at the sample
    /// limit and at the unacknowledged-bytes limit, so that a caller can
    /// keep data it would otherwise hand over to a refused write.
    #[test]
    fn has_room_agrees_with_write_at_both_limits() {
        let t0 = Instant::now();
        let mut w = Writer::new(guid(1), true, None, 4, Duration::from_millis(10));
        w.add_reader(guid(2), false, t0);
        for i in 0..4u8 {
            assert!(w.has_room(1));
            assert!(w.write(Arc::from(vec![i]), t0).is_some());
        }
        assert!(!w.has_room(1));
        assert_eq!(w.write(Arc::from(vec![9u8]), t0), None);

        let mut w =
            Writer::new(guid(1), true, None, 100, Duration::from_millis(10)).max_unacked_bytes(250);
        w.add_reader(guid(2), false, t0);
        // the first sample always fits; then up to 250 unacknowledged bytes
        assert!(w.has_room(1000));
        assert!(w.write(Arc::from(vec![0u8; 100]), t0).is_some());
        assert!(w.has_room(150) && !w.has_room(151));
        assert!(w.write(Arc::from(vec![0u8; 151]), t0).is_none());
        assert!(w.write(Arc::from(vec![0u8; 150]), t0).is_some());
        assert!(!w.has_room(1));
    }

    #[test]
    fn best_effort_reader_drops_old_and_duplicates() {
        let wg = guid(1);
        let mut r = Reader::new(false, 8);
        r.add_writer(wg, Instant::now());
        for sn in [1, 3, 2, 3, 5] {
            r.handle_data(wg, SequenceNumber(sn), Arc::from(vec![0u8]));
        }
        let got: Vec<i64> = std::iter::from_fn(|| r.poll_sample())
            .map(|(_, s, _)| s.0)
            .collect();
        assert_eq!(got, [1, 3, 5]);
    }
}
