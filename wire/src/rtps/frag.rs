//! Fragmentation and reassembly of large samples (§8.4.14.1, §8.3.7.3).
//!
//! Peers differ a lot (`shared/protocols/rtps.md` §3): Cyclone cuts samples
//! into 1344-byte fragments and packs 10 per DATA_FRAG; Fast DDS sends one
//! ~64 KB fragment per DATA_FRAG. [`Reassembler`] accepts any mix, in any
//! order, with duplicates, and bounds its memory.

use std::collections::BTreeMap;

use super::message::DataFrag;
use super::types::{EntityId, Guid, SequenceNumber, Time};

/// Splits a serialized sample into DATA_FRAG submessages of
/// `frags_per_submessage` fragments of `fragment_size` bytes (the last
/// fragment may be shorter).
pub fn fragment<'a>(
    reader_id: EntityId,
    writer_id: EntityId,
    writer_sn: SequenceNumber,
    sample: &'a [u8],
    fragment_size: u16,
    frags_per_submessage: u16,
) -> impl Iterator<Item = DataFrag<'a>> + 'a {
    let fs = usize::from(fragment_size.max(1));
    let per = usize::from(frags_per_submessage.max(1));
    let total_frags = sample.len().div_ceil(fs).max(1);
    (0..total_frags).step_by(per).map(move |first| {
        let n = per.min(total_frags - first);
        let start = first * fs;
        let end = ((first + n) * fs).min(sample.len());
        DataFrag {
            reader_id,
            writer_id,
            writer_sn,
            fragment_starting_num: first as u32 + 1,
            fragments_in_submessage: n as u16,
            fragment_size: fs as u16,
            sample_size: sample.len() as u32,
            inline_qos: None,
            payload: &sample[start..end],
            key: false,
            non_standard: false,
        }
    })
}

/// Why a DATA_FRAG was not accepted.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum FragError {
    /// The sample is larger than the configured limit.
    #[error("sample of {size} bytes exceeds the reassembly limit of {limit} bytes")]
    TooLarge {
        /// Announced sample size.
        size: u32,
        /// The limit.
        limit: usize,
    },
    /// Fragment numbers, sizes and payload length disagree.
    #[error("inconsistent DATA_FRAG: {0}")]
    Inconsistent(&'static str),
}

#[derive(Debug)]
struct Partial {
    sample_size: u32,
    fragment_size: u16,
    data: Vec<u8>,
    /// Which fragments arrived, a bit each (a 16 MiB sample in 1-byte
    /// fragments is 2 MiB of them, counted in [`Partial::held`]).
    have: Vec<u64>,
    /// Fragments in the sample.
    total: usize,
    /// How many have not arrived.
    missing: usize,
    /// The lowest fragment index (0-based) not arrived yet, where
    /// [`Reassembler::missing`] starts.
    first_missing: usize,
    /// The first source timestamp (INFO_TS) seen with any fragment: vendors
    /// send INFO_TS once before the first fragment, not before every one.
    ts: Option<Time>,
    /// The first inline QoS seen with any fragment and its byte order:
    /// Cyclone sends inline QoS only with the DATA_FRAG that holds fragment
    /// 1; Fast DDS and Courier send it with every DATA_FRAG.
    qos: Option<(Vec<u8>, bool)>,
}

impl Partial {
    /// Bytes this partial sample holds (counted against the limit).
    fn held(&self) -> usize {
        self.sample_size as usize + self.have.len() * 8 + self.qos.as_ref().map_or(0, |q| q.0.len())
    }

    fn has(&self, i: usize) -> bool {
        self.have
            .get(i / 64)
            .is_some_and(|w| w & (1 << (i % 64)) != 0)
    }

    /// Marks fragment `i` (0-based) as arrived; true if it had not.
    fn set(&mut self, i: usize) -> bool {
        let (w, bit) = (i / 64, 1u64 << (i % 64));
        let new = self.have[w] & bit == 0;
        self.have[w] |= bit;
        new
    }
}

/// The most fragment numbers [`Reassembler::missing`] gives: what one
/// NACK_FRAG can ask for.
pub const MAX_MISSING: usize = 256;

/// Smallest buffer worth keeping for reuse: below this the allocator's
/// own free lists are as fast.
pub const SPARE_MIN: usize = 4096;

/// Most buffers kept for reuse, whatever their size.
const SPARE_COUNT: usize = 64;

/// Sample buffers handed back after use ([`Reassembler::recycle`]), reused
/// for the next large samples received. Without them a stream of large
/// samples that queue up and drain allocates and frees a burst of buffers
/// each time; glibc then returns the top of the heap to the kernel and
/// faults the same pages back in, zeroed, with the next burst (measured:
/// one `brk` per 64 KiB sample, 40 % of a reliable subscriber's time).
#[derive(Debug)]
struct Spares {
    bufs: Vec<Vec<u8>>,
    bytes: usize,
    limit: usize,
}

impl Spares {
    fn give(&mut self, mut b: Vec<u8>) {
        let c = b.capacity();
        if c < SPARE_MIN || self.bytes + c > self.limit || self.bufs.len() >= SPARE_COUNT {
            return;
        }
        b.clear();
        self.bytes += c;
        self.bufs.push(b);
    }

    /// An empty buffer with room for `need` bytes: the most recently given
    /// spare that fits without wasting more than half of itself, else a
    /// new one.
    fn take(&mut self, need: usize) -> Vec<u8> {
        if need >= SPARE_MIN / 2 {
            if let Some(i) = self
                .bufs
                .iter()
                .rposition(|b| b.capacity() >= need && b.capacity() / 2 <= need)
            {
                let b = self.bufs.swap_remove(i);
                self.bytes -= b.capacity();
                return b;
            }
        }
        Vec::with_capacity(need)
    }
}

/// A completed sample and the first source timestamp its fragments carried.
pub type Reassembled = (Vec<u8>, Option<Time>);

/// A completed sample with what its fragments carried besides the data.
#[derive(Debug, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub struct Completed {
    /// The whole serialized sample.
    pub data: Vec<u8>,
    /// The first source timestamp any of its fragments carried.
    pub ts: Option<Time>,
    /// The first inline QoS any of its fragments carried (Cyclone puts it
    /// only on the DATA_FRAG with fragment 1), in the byte order of
    /// [`Completed::little_endian`].
    pub inline_qos: Option<Vec<u8>>,
    /// Byte order of `inline_qos` (the E flag of the DATA_FRAG it came in).
    pub little_endian: bool,
}

/// Reassembles fragmented samples per (writer, sequence number).
#[derive(Debug)]
pub struct Reassembler {
    max_sample: usize,
    max_bytes: usize,
    bytes: usize,
    partial: BTreeMap<(Guid, SequenceNumber), Partial>,
    spares: Spares,
}

impl Reassembler {
    /// A reassembler that accepts samples up to `max_sample` bytes and
    /// holds at most `max_bytes` of incomplete samples (the oldest
    /// incomplete samples — lowest sequence numbers — are dropped first).
    pub fn new(max_sample: usize, max_bytes: usize) -> Self {
        Reassembler {
            max_sample,
            max_bytes,
            bytes: 0,
            partial: BTreeMap::new(),
            spares: Spares {
                bufs: Vec::new(),
                bytes: 0,
                limit: 0,
            },
        }
    }

    /// Keeps up to `bytes` of buffers handed back with
    /// [`recycle`](Self::recycle) for reuse (default 0: none kept).
    pub fn with_spare_limit(mut self, bytes: usize) -> Self {
        self.spares.limit = bytes;
        self
    }

    /// Hands back a sample buffer this reassembler (or [`spare`](Self::spare))
    /// gave out, once its contents are no longer needed: the next large
    /// sample is reassembled into it. Buffers beyond the spare limit, or
    /// smaller than [`SPARE_MIN`], are dropped.
    pub fn recycle(&mut self, buf: Vec<u8>) {
        self.spares.give(buf);
    }

    /// An empty buffer with room for `need` bytes, from the spares when one
    /// fits.
    pub fn spare(&mut self, need: usize) -> Vec<u8> {
        self.spares.take(need)
    }

    /// Bytes of spare buffers held for reuse.
    pub fn spare_bytes(&self) -> usize {
        self.spares.bytes
    }

    /// Bytes held by incomplete samples.
    pub fn buffered_bytes(&self) -> usize {
        self.bytes
    }

    /// Fragment numbers (1-based) still missing for a sample being
    /// reassembled: those among the [`MAX_MISSING`] from the first missing
    /// one on (what one NACK_FRAG asks for). The work is that of those
    /// 256, however many fragments the sample has: a peer announcing 16 MiB
    /// samples in 1-byte fragments made every ACKNACK walk 16 million
    /// flags per sample, and a reader spin.
    pub fn missing(&self, writer: Guid, sn: SequenceNumber) -> Vec<u32> {
        let Some(p) = self.partial.get(&(writer, sn)) else {
            return Vec::new();
        };
        let end = p.first_missing.saturating_add(MAX_MISSING).min(p.total);
        (p.first_missing..end)
            .filter(|i| !p.has(*i))
            .map(|i| i as u32 + 1)
            .collect()
    }

    /// Drops every incomplete sample of `writer` below `sn` (the writer
    /// gave up on them, or they were delivered another way).
    pub fn forget_below(&mut self, writer: Guid, sn: SequenceNumber) {
        let keys: Vec<_> = self
            .partial
            .range((writer, SequenceNumber(i64::MIN))..(writer, sn))
            .map(|(k, _)| *k)
            .collect();
        for k in keys {
            if let Some(p) = self.partial.remove(&k) {
                self.bytes -= p.held();
                self.spares.give(p.data);
            }
        }
    }

    /// Adds one DATA_FRAG from `writer`. Returns the whole sample when this
    /// submessage completed it.
    pub fn insert(&mut self, writer: Guid, f: &DataFrag<'_>) -> Result<Option<Vec<u8>>, FragError> {
        Ok(self.insert_timed(writer, f, None)?.map(|(data, _)| data))
    }

    /// As [`insert`](Self::insert), with the source timestamp in force for
    /// this DATA_FRAG; the completed sample comes with the first timestamp
    /// any of its fragments carried.
    pub fn insert_timed(
        &mut self,
        writer: Guid,
        f: &DataFrag<'_>,
        ts: Option<Time>,
    ) -> Result<Option<Reassembled>, FragError> {
        Ok(self
            .insert_with_qos(writer, f, ts, true)?
            .map(|c| (c.data, c.ts)))
    }

    /// As [`insert_timed`](Self::insert_timed), also keeping the first
    /// inline QoS the fragments carried (`little`: the DATA_FRAG's E flag).
    /// Its bytes count against the limit like the sample's.
    pub fn insert_with_qos(
        &mut self,
        writer: Guid,
        f: &DataFrag<'_>,
        ts: Option<Time>,
        little: bool,
    ) -> Result<Option<Completed>, FragError> {
        let size = f.sample_size as usize;
        if size > self.max_sample {
            return Err(FragError::TooLarge {
                size: f.sample_size,
                limit: self.max_sample,
            });
        }
        let fs = usize::from(f.fragment_size);
        if fs == 0 {
            return Err(FragError::Inconsistent("fragmentSize 0"));
        }
        let total = size.div_ceil(fs).max(1);
        let first = f.fragment_starting_num as usize;
        let n = usize::from(f.fragments_in_submessage);
        if first == 0 || n == 0 || first - 1 + n > total {
            return Err(FragError::Inconsistent(
                "fragment numbers outside the sample",
            ));
        }
        let start = (first - 1) * fs;
        let end = ((first - 1 + n) * fs).min(size);
        if f.payload.len() < end - start {
            return Err(FragError::Inconsistent(
                "payload shorter than its fragments",
            ));
        }
        let key = (writer, f.writer_sn);
        let qlen = f.inline_qos.map_or(0, <[u8]>::len);
        if !self.partial.contains_key(&key) {
            // make room: drop the oldest incomplete samples
            let need = size + total.div_ceil(64) * 8;
            while self.bytes + need + qlen > self.max_bytes {
                let Some((&oldest, _)) = self.partial.iter().next() else {
                    break;
                };
                if let Some(p) = self.partial.remove(&oldest) {
                    self.bytes -= p.held();
                    self.spares.give(p.data);
                }
            }
            if self.bytes + need > self.max_bytes {
                return Err(FragError::TooLarge {
                    size: f.sample_size,
                    limit: self.max_bytes,
                });
            }
            self.bytes += need;
            self.partial.insert(
                key,
                Partial {
                    sample_size: f.sample_size,
                    fragment_size: f.fragment_size,
                    // room for the envelope's trailer (see
                    // Participant::on_data), so the sample is never moved
                    data: self.spares.take(size + super::participant::ENVELOPE_ROOM),
                    have: vec![0; total.div_ceil(64)],
                    total,
                    missing: total,
                    first_missing: 0,
                    ts: None,
                    qos: None,
                },
            );
        }
        let p = self
            .partial
            .get_mut(&key)
            .ok_or(FragError::Inconsistent("lost partial"))?;
        if p.sample_size != f.sample_size || p.fragment_size != f.fragment_size {
            return Err(FragError::Inconsistent(
                "sample or fragment size changed between fragments",
            ));
        }
        // written where it belongs; the buffer grows as fragments arrive
        // (in order, the usual case, nothing is zeroed first)
        let bytes = &f.payload[..end - start];
        if p.data.len() < start {
            p.data.resize(start, 0);
        }
        let overlap = (p.data.len() - start).min(bytes.len());
        p.data[start..start + overlap].copy_from_slice(&bytes[..overlap]);
        p.data.extend_from_slice(&bytes[overlap..]);
        p.ts = p.ts.or(ts);
        if let (None, Some(q)) = (&p.qos, f.inline_qos) {
            if self.bytes + q.len() <= self.max_bytes {
                self.bytes += q.len();
                p.qos = Some((q.to_vec(), little));
            }
        }
        for i in first - 1..first - 1 + n {
            if p.set(i) {
                p.missing -= 1;
            }
        }
        while p.first_missing < p.total && p.has(p.first_missing) {
            p.first_missing += 1;
        }
        if p.missing > 0 {
            return Ok(None);
        }
        let done = self
            .partial
            .remove(&key)
            .ok_or(FragError::Inconsistent("lost partial"))?;
        self.bytes -= done.held();
        let (inline_qos, little_endian) = match done.qos {
            Some((q, l)) => (Some(q), l),
            None => (None, little),
        };
        Ok(Some(Completed {
            data: done.data,
            ts: done.ts,
            inline_qos,
            little_endian,
        }))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rtps::GuidPrefix;

    fn w() -> Guid {
        Guid {
            prefix: GuidPrefix([1; 12]),
            entity: EntityId([0, 0, 2, 3]),
        }
    }

    fn sample(n: usize) -> Vec<u8> {
        (0..n).map(|i| (i * 7 % 251) as u8).collect()
    }

    #[test]
    fn cyclone_and_fast_dds_shapes_reassemble_in_any_order() {
        let s = sample(102_416);
        for (fs, per) in [(1344u16, 10u16), (65324, 1), (1000, 3), (1, 4000)] {
            let mut frags: Vec<_> = fragment(
                EntityId::UNKNOWN,
                w().entity,
                SequenceNumber(6),
                &s,
                fs,
                per,
            )
            .collect();
            assert_eq!(
                frags.iter().map(|f| f.payload.len()).sum::<usize>(),
                s.len()
            );
            // reverse order plus a duplicate of the first
            frags.reverse();
            let dup = frags[0].clone();
            frags.insert(1, dup);
            let mut r = Reassembler::new(1 << 20, 4 << 20);
            let mut out = None;
            for f in &frags {
                if let Some(done) = r.insert(w(), f).unwrap() {
                    assert!(out.is_none(), "completed twice");
                    out = Some(done);
                }
            }
            assert_eq!(out.as_deref(), Some(&s[..]), "fs {fs} per {per}");
            assert_eq!(r.buffered_bytes(), 0);
        }
    }

    #[test]
    fn missing_fragments_are_reported() {
        let s = sample(5000);
        let frags: Vec<_> = fragment(
            EntityId::UNKNOWN,
            w().entity,
            SequenceNumber(1),
            &s,
            1000,
            1,
        )
        .collect();
        let mut r = Reassembler::new(1 << 20, 1 << 20);
        for f in frags.iter().filter(|f| f.fragment_starting_num != 3) {
            assert!(r.insert(w(), f).unwrap().is_none());
        }
        assert_eq!(r.missing(w(), SequenceNumber(1)), [3]);
        assert_eq!(r.insert(w(), &frags[2]).unwrap().unwrap(), s);
    }

    #[test]
    fn inline_qos_of_the_first_fragment_survives_any_order() {
        // Cyclone's shape: inline QoS only with fragment 1, big-endian here
        let s = sample(5000);
        let qos = [0x00u8, 0x71, 0x00, 0x04, 0, 0, 0, 1, 0x00, 0x01, 0x00, 0x00];
        let mut frags: Vec<_> = fragment(
            EntityId::UNKNOWN,
            w().entity,
            SequenceNumber(4),
            &s,
            1000,
            2,
        )
        .collect();
        frags[0].inline_qos = Some(&qos);
        frags.reverse();
        let mut r = Reassembler::new(1 << 20, 1 << 20);
        let mut out = None;
        for f in &frags {
            // the E flag of the later (unrelated) fragments does not matter
            let little = f.inline_qos.is_none();
            if let Some(c) = r.insert_with_qos(w(), f, None, little).unwrap() {
                out = Some(c);
            } else {
                // the sample, its QoS and a bit per fragment
                let flags = s.len().div_ceil(1000).div_ceil(64) * 8;
                assert!(r.buffered_bytes() <= s.len() + qos.len() + flags);
            }
        }
        let c = out.unwrap();
        assert_eq!(c.data, s);
        assert_eq!(c.inline_qos.as_deref(), Some(&qos[..]));
        assert!(!c.little_endian);
        assert_eq!(r.buffered_bytes(), 0);
        // without any inline QoS: none, and the byte order of the last one
        let frags: Vec<_> = fragment(
            EntityId::UNKNOWN,
            w().entity,
            SequenceNumber(5),
            &s,
            1000,
            3,
        )
        .collect();
        let mut out = None;
        for f in &frags {
            out = r.insert_with_qos(w(), f, None, true).unwrap().or(out);
        }
        let c = out.unwrap();
        assert_eq!((c.inline_qos, c.little_endian), (None, true));
        // a partial sample's inline QoS is counted and released
        let mut f = frags[0].clone();
        f.writer_sn = SequenceNumber(6);
        f.inline_qos = Some(&qos);
        assert!(r.insert_with_qos(w(), &f, None, true).unwrap().is_none());
        let flags = s.len().div_ceil(1000).div_ceil(64) * 8;
        assert_eq!(r.buffered_bytes(), s.len() + qos.len() + flags);
        r.forget_below(w(), SequenceNumber(7));
        assert_eq!(r.buffered_bytes(), 0);
    }

    #[test]
    fn hostile_fragments_are_bounded() {
        let s = sample(10_000);
        let good: Vec<_> = fragment(
            EntityId::UNKNOWN,
            w().entity,
            SequenceNumber(1),
            &s,
            1000,
            2,
        )
        .collect();
        let mut r = Reassembler::new(50_000, 60_000);
        let mut f = good[0].clone();
        f.sample_size = 4_000_000_000;
        assert!(matches!(r.insert(w(), &f), Err(FragError::TooLarge { .. })));
        let mut f = good[0].clone();
        f.fragment_starting_num = 20;
        assert!(r.insert(w(), &f).is_err());
        let mut f = good[0].clone();
        f.payload = &f.payload[..10];
        assert!(r.insert(w(), &f).is_err());
        // many incomplete samples: memory stays under the limit, oldest dropped
        for sn in 0..100 {
            let mut f = good[0].clone();
            f.writer_sn = SequenceNumber(sn);
            r.insert(w(), &f).unwrap();
            assert!(r.buffered_bytes() <= 60_000);
        }
        assert!(r.missing(w(), SequenceNumber(0)).is_empty());
        assert_eq!(r.missing(w(), SequenceNumber(99)).len(), 8);
        r.forget_below(w(), SequenceNumber(100));
        assert_eq!(r.buffered_bytes(), 0);
    }

    /// A peer announcing a 16 MiB sample in 1-byte fragments (audit 20):
    /// `missing`, asked for each sequence number of every ACKNACK, gives
    /// at most what one NACK_FRAG asks for, from the first missing
    /// fragment on (it listed all 16 million, and a few such samples
    /// under a stream of HEARTBEATs kept a reader's core busy), and the
    /// flags that track 16 million fragments are counted as held.
    #[test]
    fn a_sample_in_one_byte_fragments_costs_what_a_nack_frag_holds() {
        const SIZE: u32 = 16 << 20;
        let mut r = Reassembler::new(SIZE as usize, 64 << 20);
        let frag = |first: u32, payload: &'static [u8]| DataFrag {
            reader_id: EntityId::UNKNOWN,
            writer_id: w().entity,
            writer_sn: SequenceNumber(1),
            fragment_starting_num: first,
            fragments_in_submessage: payload.len() as u16,
            fragment_size: 1,
            sample_size: SIZE,
            inline_qos: None,
            payload,
            key: false,
            non_standard: false,
        };
        assert!(r.insert(w(), &frag(1, &[1, 2, 3, 4])).unwrap().is_none());
        assert!(r.insert(w(), &frag(10, &[10])).unwrap().is_none());
        let missing = r.missing(w(), SequenceNumber(1));
        let want: Vec<u32> = (5..=9).chain(11..=260).collect();
        assert_eq!(missing, want);
        assert_eq!(
            missing.len(),
            MAX_MISSING - 1,
            "256 from fragment 5 on, less 10"
        );
        assert_eq!(r.buffered_bytes(), SIZE as usize + (SIZE as usize / 64) * 8);
        // as the front fills, the window moves on
        assert!(r.insert(w(), &frag(5, &[5, 6, 7, 8, 9])).unwrap().is_none());
        assert_eq!(r.missing(w(), SequenceNumber(1))[0], 11);
    }

    fn reassemble(r: &mut Reassembler, sn: i64, s: &[u8]) -> Vec<u8> {
        let mut out = None;
        for f in fragment(
            EntityId::UNKNOWN,
            w().entity,
            SequenceNumber(sn),
            s,
            1344,
            10,
        ) {
            if let Some(done) = r.insert(w(), &f).unwrap() {
                out = Some(done);
            }
        }
        out.expect("every fragment was given")
    }

    #[test]
    fn recycled_buffers_are_reassembled_into() {
        let mut r = Reassembler::new(1 << 20, 1 << 20).with_spare_limit(200_000);
        let a = reassemble(&mut r, 1, &sample(65_536));
        let at = a.as_ptr();
        r.recycle(a);
        assert!(r.spare_bytes() >= 65_536);
        // the next sample of about that size lands in the same memory
        let s = sample(60_000);
        let b = reassemble(&mut r, 2, &s);
        assert_eq!((b.as_ptr(), &b[..]), (at, &s[..]));
        assert_eq!(r.spare_bytes(), 0);
        // a spare more than twice the size needed is left for a larger sample
        r.recycle(b);
        let small = reassemble(&mut r, 3, &sample(20_000));
        assert_ne!(small.as_ptr(), at);
        let again = r.spare(50_000);
        assert_eq!(again.as_ptr(), at);
    }

    #[test]
    fn spares_stay_within_their_limit() {
        let mut r = Reassembler::new(1 << 20, 1 << 20).with_spare_limit(100_000);
        r.recycle(Vec::with_capacity(SPARE_MIN - 1));
        assert_eq!(r.spare_bytes(), 0, "small buffers are not kept");
        r.recycle(Vec::with_capacity(60_000));
        r.recycle(Vec::with_capacity(60_000));
        assert_eq!(r.spare_bytes(), 60_000, "the second would pass the limit");
        // without a limit nothing is kept
        let mut none = Reassembler::new(1 << 20, 1 << 20);
        none.recycle(Vec::with_capacity(60_000));
        assert_eq!(none.spare_bytes(), 0);
    }

    #[test]
    fn dropped_partial_samples_leave_their_buffers_as_spares() {
        let mut r = Reassembler::new(1 << 20, 1 << 20).with_spare_limit(1 << 20);
        let s = sample(30_000);
        let first = fragment(
            EntityId::UNKNOWN,
            w().entity,
            SequenceNumber(5),
            &s,
            1344,
            10,
        )
        .next()
        .unwrap();
        assert!(r.insert(w(), &first).unwrap().is_none());
        r.forget_below(w(), SequenceNumber(6));
        assert!(r.spare_bytes() >= 30_000);
    }
}
