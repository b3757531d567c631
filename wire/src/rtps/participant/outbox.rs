//! Datagrams out: a [`Datagram`], and a [`Transmission`] whose large sample
//! data stays in the writer's history for a vectored send; and the outbox
//! that serializes submessages straight into datagrams, one queue per
//! destination (locator and INFO_DST prefix), as few datagrams as
//! [`Config::max_message_size`](super::Config::max_message_size) allows.

use std::collections::VecDeque;
use std::ops::Range;

use super::Stats;
use crate::rtps::reliability::Payload;
use crate::rtps::{Data, DataFrag, EntityId, GuidPrefix, Header, Locator, Submessage, Time};

/// A datagram to send.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Datagram {
    /// Where to send it.
    pub destination: Locator,
    /// The RTPS message.
    pub payload: Vec<u8>,
}

/// A datagram to send whose large sample data is carried by reference to
/// the writer's history instead of being copied into it: send its
/// [`Transmission::parts`] with one vectored system call (`sendmsg`), or
/// make it a [`Datagram`].
#[derive(Debug, Clone)]
pub struct Transmission {
    destination: Locator,
    /// The message's own bytes; the shared parts go in between.
    head: Vec<u8>,
    /// Shared parts: where in `head` each goes, and its bytes, by position.
    shared: Vec<(usize, Payload, Range<usize>)>,
}

impl Transmission {
    /// Where to send it.
    pub fn destination(&self) -> Locator {
        self.destination
    }

    /// Its length in bytes.
    pub fn len(&self) -> usize {
        self.head.len() + self.shared.iter().map(|(_, _, r)| r.len()).sum::<usize>()
    }

    /// Whether it is empty (never, for a transmission from a participant).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Its bytes, in order, as a few slices (at most `2 × shared + 1`).
    pub fn parts(&self) -> impl Iterator<Item = &[u8]> + '_ {
        let mut from = 0;
        self.shared
            .iter()
            .flat_map(move |(at, p, r)| {
                let own = &self.head[from..*at];
                from = *at;
                [own, &p[r.clone()]]
            })
            .chain(std::iter::once(
                &self.head[self.shared.last().map_or(0, |(at, _, _)| *at)..],
            ))
            .filter(|b| !b.is_empty())
    }

    /// The whole message in one buffer (copies the shared parts, if any).
    pub fn into_datagram(self) -> Datagram {
        let payload = if self.shared.is_empty() {
            self.head
        } else {
            let mut b = Vec::with_capacity(self.len());
            for part in self.parts() {
                b.extend_from_slice(part);
            }
            b
        };
        Datagram {
            destination: self.destination,
            payload,
        }
    }
}

/// Data parts at least this long are sent by reference (see
/// [`Transmission`]); shorter ones are cheaper to copy than to describe.
const SHARE_MIN: usize = 1024;

/// One or more submessages that travel together, after an INFO_TS if `ts` is set.
pub(super) struct Unit {
    pub(super) ts: Option<Time>,
    pub(super) bytes: Vec<u8>,
}

impl Unit {
    pub(super) fn new(ts: Option<Time>, sm: &Submessage<'_>) -> Self {
        let mut bytes = Vec::new();
        sm.write(&mut bytes, true);
        Unit { ts, bytes }
    }
}

/// The datagram being filled for one destination (locator + INFO_DST
/// prefix).
struct Queue {
    dst: GuidPrefix,
    /// The datagram so far (empty: none begun).
    t: Transmission,
    /// The INFO_TS in force at the end of the datagram.
    ts: Option<Time>,
}

impl Queue {
    fn take(&mut self) -> Transmission {
        let empty = Transmission {
            destination: self.t.destination,
            head: Vec::new(),
            shared: Vec::new(),
        };
        std::mem::replace(&mut self.t, empty)
    }
}

/// Submessages for each destination, serialized straight into the datagrams
/// that carry them: a datagram that cannot take the next submessage is
/// closed and a new one started, so nothing is copied after serializing.
pub(super) struct Outbox {
    header: Header,
    max: usize,
    queues: Vec<Queue>,
    /// Closed datagrams, in the order they filled.
    full: Vec<Transmission>,
    /// Scratch for [`Route::group`](super::emit::Route::group), kept for its capacity.
    pub(super) targets: Vec<(Locator, GuidPrefix, EntityId)>,
}

impl Outbox {
    pub(super) fn new(header: Header, max: usize) -> Self {
        Outbox {
            header,
            max,
            queues: Vec::new(),
            full: Vec::new(),
            targets: Vec::new(),
        }
    }

    pub(super) fn push(&mut self, to: Locator, dst: GuidPrefix, unit: Unit) {
        self.push_with(to, dst, unit.ts, unit.bytes.len(), None, |b| {
            b.extend_from_slice(&unit.bytes)
        });
    }

    /// Queues one submessage, serialized in place.
    pub(super) fn push_sm(
        &mut self,
        to: Locator,
        dst: GuidPrefix,
        ts: Option<Time>,
        sm: &Submessage<'_>,
    ) {
        self.push_with(to, dst, ts, sm.encoded_len(), None, |b| sm.write(b, true));
    }

    /// Queues a DATA or DATA_FRAG whose data lies in `env`: a large part is
    /// carried by reference to `env` instead of copied.
    pub(super) fn push_sample(
        &mut self,
        to: Locator,
        dst: GuidPrefix,
        ts: Option<Time>,
        sm: &Submessage<'_>,
        env: &Payload,
    ) {
        let (data, head) = match sm {
            Submessage::Data(d) => (
                d.payload.unwrap_or(&[]),
                Submessage::Data(Data {
                    payload: d.payload.map(|_| &[][..]),
                    ..d.clone()
                }),
            ),
            Submessage::DataFrag(f) => (
                f.payload,
                Submessage::DataFrag(DataFrag {
                    payload: &[],
                    ..f.clone()
                }),
            ),
            _ => return self.push_sm(to, dst, ts, sm),
        };
        let (base, at) = (env.as_ptr() as usize, data.as_ptr() as usize);
        if data.len() < SHARE_MIN || at < base || at + data.len() > base + env.len() {
            return self.push_sm(to, dst, ts, sm);
        }
        let range = at - base..at - base + data.len();
        let len = sm.encoded_len();
        let share = Some((env.clone(), range));
        self.push_with(to, dst, ts, len, share, |b| {
            // the submessage without its data (the data comes last in
            // both), with the length it has with it
            let start = b.len();
            head.write(b, true);
            let n = u16::try_from(len - 4).unwrap_or(0);
            b[start + 2..start + 4].copy_from_slice(&n.to_le_bytes());
        });
    }

    /// Queues `len` bytes that `write` appends, after an INFO_TS if `ts`
    /// differs from the one in force.
    fn push_with(
        &mut self,
        to: Locator,
        dst: GuidPrefix,
        ts: Option<Time>,
        len: usize,
        share: Option<(Payload, Range<usize>)>,
        write: impl FnOnce(&mut Vec<u8>),
    ) {
        let i = match self
            .queues
            .iter()
            .position(|q| q.t.destination == to && q.dst == dst)
        {
            Some(i) => i,
            None => {
                self.queues.push(Queue {
                    dst,
                    t: Transmission {
                        destination: to,
                        head: Vec::new(),
                        shared: Vec::new(),
                    },
                    ts: None,
                });
                self.queues.len() - 1
            }
        };
        let q = &mut self.queues[i];
        let base = crate::rtps::HEADER_SIZE + if dst == GuidPrefix::UNKNOWN { 0 } else { 16 };
        let ts_len = |q: &Queue| if ts.is_some() && ts != q.ts { 12 } else { 0 };
        let filled = q.t.len();
        if filled > base && filled + ts_len(q) + len > self.max {
            let t = q.take();
            self.full.push(t);
        }
        let buf = &mut q.t.head;
        if buf.is_empty() {
            // most datagrams carry a few small submessages; a big one (a
            // fragment) gets its size at once instead of growing into it
            let own = len - share.as_ref().map_or(0, |(_, r)| r.len());
            let want = base + 12 + own;
            *buf = Vec::with_capacity(if want > 1500 {
                want.min(self.max)
            } else {
                1500
            });
            self.header.write(buf);
            if dst != GuidPrefix::UNKNOWN {
                Submessage::InfoDst(dst).write(buf, true);
            }
            q.ts = None;
        }
        if let Some(t) = ts {
            if q.ts != Some(t) {
                Submessage::InfoTs(Some(t)).write(buf, true);
                q.ts = Some(t);
            }
        }
        write(buf);
        if let Some((p, r)) = share {
            q.t.shared.push((buf.len(), p, r));
        }
    }

    /// Moves every datagram, closed or still filling, to `out`.
    pub(super) fn drain(&mut self, out: &mut VecDeque<Transmission>, stats: &mut Stats) {
        let open = self
            .queues
            .drain(..)
            .filter(|q| !q.t.head.is_empty())
            .map(|q| q.t);
        for t in self.full.drain(..).chain(open) {
            stats.datagrams_sent += 1;
            stats.bytes_sent += t.len() as u64;
            out.push_back(t);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rtps::participant::change::{envelope, open, ChangeKind};
    use crate::rtps::participant::emit::{data_units, Shape};
    use crate::rtps::participant::{PROTOCOL_VERSION, VENDOR_ID};
    use crate::rtps::{Message, SequenceNumber};

    /// The header of the outbox tests' participant.
    fn test_header() -> Header {
        Header {
            version: PROTOCOL_VERSION,
            vendor: VENDOR_ID,
            guid_prefix: GuidPrefix([1; 12]),
        }
    }

    #[test]
    fn outbox_packs_by_destination_and_size() {
        let h = test_header();
        let a = Locator::udpv4([127, 0, 0, 1], 7410);
        let b = Locator::udpv4([127, 0, 0, 1], 7412);
        let t = Time {
            seconds: 1,
            fraction: 0,
        };
        let mut o = Outbox::new(h, 512);
        for _ in 0..3 {
            o.push(
                a,
                GuidPrefix([2; 12]),
                Unit {
                    ts: Some(t),
                    bytes: vec![0x01, 0x01, 196, 0]
                        .into_iter()
                        .chain([0; 196])
                        .collect(),
                },
            );
        }
        o.push(
            b,
            GuidPrefix::UNKNOWN,
            Unit {
                ts: None,
                bytes: vec![0x01, 0x01, 0, 0],
            },
        );
        let mut out = VecDeque::new();
        let mut stats = Stats::default();
        o.drain(&mut out, &mut stats);
        let out: Vec<Datagram> = out.into_iter().map(Transmission::into_datagram).collect();
        // 20 header + 16 INFO_DST + 12 INFO_TS + 2×200 fit in 512, the third does not
        assert_eq!(out.len(), 3);
        assert_eq!(out[0].destination, a);
        assert_eq!(out[0].payload.len(), 20 + 16 + 12 + 400);
        assert_eq!(out[1].payload.len(), 20 + 16 + 12 + 200);
        assert_eq!(out[2].payload.len(), 24);
        for d in &out {
            Message::parse(&d.payload).unwrap();
        }
        assert_eq!(stats.datagrams_sent, 3);
    }

    /// Large sample data goes by reference; the parts, joined, are the
    /// bytes the submessages serialized in place would have been.
    #[test]
    fn large_sample_data_is_carried_by_reference() {
        let h = test_header();
        let to = Locator::udpv4([127, 0, 0, 1], 7410);
        let dst = GuidPrefix([2; 12]);
        let ts = Some(Time {
            seconds: 3,
            fraction: 4,
        });
        let data: Vec<u8> = (0..5000u32).map(|i| (i % 251) as u8).collect();
        let env = envelope(ChangeKind::Alive, None, ts, &data);
        let e = open(&env);
        let shape = Shape {
            max: 4096,
            fragment_size: 1000,
        };
        let (w, r) = (EntityId([0, 0, 1, 2]), EntityId([0, 0, 1, 7]));
        let mut by_ref = Outbox::new(h, 4096);
        let mut copied = Outbox::new(h, 4096);
        data_units(shape, r, w, SequenceNumber(9), &e, None, |ts, sm| {
            by_ref.push_sample(to, dst, ts, sm, &env);
            copied.push_sm(to, dst, ts, sm);
        });
        // a small DATA is copied even when offered by reference
        let small = envelope(ChangeKind::Alive, None, ts, b"\0\x01\0\0tiny");
        data_units(
            shape,
            r,
            w,
            SequenceNumber(10),
            &open(&small),
            None,
            |ts, sm| {
                by_ref.push_sample(to, dst, ts, sm, &small);
                copied.push_sm(to, dst, ts, sm);
            },
        );
        let (mut a, mut b) = (VecDeque::new(), VecDeque::new());
        let mut stats = Stats::default();
        by_ref.drain(&mut a, &mut stats);
        copied.drain(&mut b, &mut stats);
        assert_eq!(a.len(), b.len());
        assert!(a.len() >= 2, "{} datagrams", a.len());
        assert!(a.iter().any(|t| !t.shared.is_empty()));
        assert!(a.iter().all(|t| t.len() <= 4096));
        for (t, c) in a.into_iter().zip(b) {
            assert!(c.shared.is_empty());
            let joined: Vec<u8> = t.parts().flatten().copied().collect();
            assert_eq!(joined.len(), t.len());
            let d = t.into_datagram();
            assert_eq!(d.payload, joined);
            assert_eq!(d, c.into_datagram());
            Message::parse(&d.payload).unwrap();
        }
    }
}
