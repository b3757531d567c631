//! Datagrams in: [`Participant::handle_datagram`] checks a whole datagram,
//! keeps the receiver state (INFO_TS, INFO_DST, INFO_SRC) and hands each
//! submessage to the endpoints it is for: DATA and DATA_FRAG (reassembled)
//! to SPDP, the SEDP readers or the matched user readers; HEARTBEAT and GAP
//! to readers; ACKNACK and NACK_FRAG to writers.

use std::borrow::Cow;
use std::collections::BTreeSet;
use std::time::Instant;

use smallvec::SmallVec;

use super::change::{envelope, envelope_with, inline_info, open, ChangeKind, ENVELOPE_ROOM};
use super::emit::{data_units, key_form_for, Route, Shape};
use super::{Event, KeyHash, Participant};
use crate::rtps::discovery::Disposal;
use crate::rtps::frag::{self, FragError};
use crate::rtps::{
    AckNack, DataFrag, EntityId, Gap, Guid, GuidPrefix, Heartbeat, Locator, Message, NackFrag,
    SequenceNumber, Submessage, Time, VendorId,
};

/// The receiver state of one message (§8.3.4).
#[derive(Clone, Copy)]
struct Rx {
    src: GuidPrefix,
    dst: GuidPrefix,
    ts: Option<Time>,
    vendor: VendorId,
}

impl Participant {
    /// A datagram arrived from `source` at `now`. Any bytes are accepted:
    /// what does not parse is counted in [`Stats`](super::Stats) and otherwise ignored.
    pub fn handle_datagram(&mut self, source: Locator, datagram: &[u8], now: Instant) {
        self.touch();
        self.stats.datagrams_received += 1;
        if self.closed {
            self.stats.datagrams_ignored += 1;
            return;
        }
        // the whole datagram is checked before any of it is acted on; a
        // datagram's few submessages stay off the heap
        let mut sms: SmallVec<[(bool, Submessage<'_>); 8]> = SmallVec::new();
        let header = match Message::parse_each(datagram, |little, sm| sms.push((little, sm))) {
            Ok(h) => h,
            Err(_) => {
                self.stats.datagrams_malformed += 1;
                return;
            }
        };
        let ours = self.cfg.guid_prefix;
        if header.guid_prefix == ours {
            self.stats.datagrams_ignored += 1;
            return;
        }
        self.participants.renew(header.guid_prefix, now);
        let mut rx = Rx {
            src: header.guid_prefix,
            dst: GuidPrefix::UNKNOWN,
            ts: None,
            vendor: header.vendor,
        };
        for (little, sm) in &sms {
            let little = *little;
            match sm {
                Submessage::InfoTs(t) => {
                    rx.ts = *t;
                    continue;
                }
                Submessage::InfoDst(p) => {
                    rx.dst = *p;
                    continue;
                }
                Submessage::InfoSrc(s) => {
                    rx.src = s.guid_prefix;
                    rx.ts = None;
                    continue;
                }
                _ => {}
            }
            if (rx.dst != GuidPrefix::UNKNOWN && rx.dst != ours) || rx.src == ours {
                self.stats.submessages_not_for_us += 1;
                continue;
            }
            match sm {
                Submessage::Data(d) => self.on_data(
                    &rx,
                    d.reader_id,
                    d.writer_id,
                    d.writer_sn,
                    d.inline_qos,
                    little,
                    d.payload.map(Cow::Borrowed),
                    d.key,
                    source,
                    now,
                ),
                Submessage::DataFrag(f) => self.on_data_frag(&rx, f, little, source, now),
                Submessage::Heartbeat(h) => self.on_heartbeat(&rx, h, now),
                Submessage::Gap(g) => self.on_gap(&rx, g),
                Submessage::AckNack(a) => self.on_acknack(&rx, a, now),
                Submessage::NackFrag(n) => self.on_nack_frag(&rx, n),
                _ => {}
            }
        }
        self.flush(now);
    }

    #[allow(clippy::too_many_arguments)]
    fn on_data(
        &mut self,
        rx: &Rx,
        reader_id: EntityId,
        writer_id: EntityId,
        sn: SequenceNumber,
        qos: Option<&[u8]>,
        little: bool,
        payload: Option<Cow<'_, [u8]>>,
        key: bool,
        source: Locator,
        now: Instant,
    ) {
        let writer = Guid {
            prefix: rx.src,
            entity: writer_id,
        };
        match writer_id {
            EntityId::SPDP_WRITER => {
                self.on_spdp(qos, little, payload.as_deref(), key, source, now)
            }
            EntityId::SEDP_PUBLICATIONS_WRITER | EntityId::SEDP_SUBSCRIPTIONS_WRITER => {
                let payload = payload.as_deref();
                let (kind, key_hash) = match Disposal::from_data(qos, little, payload, key) {
                    Ok(Some(d)) => (ChangeKind::from_status(d.status), Some(KeyHash(d.key_hash))),
                    Ok(None) => (ChangeKind::Alive, None),
                    Err(_) => {
                        self.stats.discovery_errors += 1;
                        return;
                    }
                };
                let data: &[u8] = match (kind, payload) {
                    (ChangeKind::Alive, Some(p)) if !key => p,
                    (ChangeKind::Alive, _) => return,
                    _ => &[],
                };
                let env = envelope(kind, key_hash, rx.ts, data);
                let r = if writer_id == EntityId::SEDP_PUBLICATIONS_WRITER {
                    &mut self.pub_reader
                } else {
                    &mut self.sub_reader
                };
                r.handle_data(writer, sn, env);
            }
            EntityId::P2P_MESSAGE_WRITER => match payload.as_deref() {
                Some(p) if !key => self.on_pmd(writer, sn, p, now),
                // a dispose of the participant's messages: its SPDP
                // dispose or lease says when it leaves
                _ => {}
            },
            e if e.is_builtin() => {}
            _ => {
                // the reader's limit holds for a sample in one DATA as for
                // a fragmented one
                let limit = self.cfg.max_sample_size;
                if let Some(p) = payload.as_ref().filter(|p| p.len() > limit) {
                    let size = u32::try_from(p.len()).unwrap_or(u32::MAX);
                    self.give_up(writer, reader_id, sn, size, limit);
                    return;
                }
                let (key_hash, status, related) = inline_info(qos, little, rx.vendor);
                let kind = match status {
                    Some(s) => ChangeKind::from_status(s),
                    // a serialized key without status: an old-style dispose
                    None if key => ChangeKind::Disposed,
                    None => ChangeKind::Alive,
                };
                let payload = match payload {
                    // large samples go into a recycled buffer when there is one
                    Some(Cow::Borrowed(d)) if d.len() >= frag::SPARE_MIN => {
                        let mut v = self.reassembler.spare(d.len() + ENVELOPE_ROOM);
                        v.extend_from_slice(d);
                        Some(Cow::Owned(v))
                    }
                    p => p,
                };
                let env = match (kind, payload) {
                    (ChangeKind::Alive, None) => return,
                    (_, p) => envelope_with(kind, key_hash, rx.ts, related, p.unwrap_or_default()),
                };
                self.writer_asserted(writer, now);
                let mut delivered = false;
                for (e, lr) in self.readers.iter_mut() {
                    if (reader_id == EntityId::UNKNOWN || reader_id == *e)
                        && lr.matched.contains(&writer)
                    {
                        lr.reader.handle_data(writer, sn, env.clone());
                        delivered = true;
                    }
                }
                if !delivered {
                    self.stats.data_unmatched += 1;
                }
            }
        }
    }

    /// Whether some local reader still needs `sn` from `writer`.
    fn wants(&self, writer: Guid, reader_id: EntityId, sn: SequenceNumber) -> bool {
        match writer.entity {
            EntityId::SPDP_WRITER => true,
            EntityId::SEDP_PUBLICATIONS_WRITER => self
                .pub_reader
                .next_expected(writer)
                .is_some_and(|n| sn >= n),
            EntityId::SEDP_SUBSCRIPTIONS_WRITER => self
                .sub_reader
                .next_expected(writer)
                .is_some_and(|n| sn >= n),
            EntityId::P2P_MESSAGE_WRITER => self
                .wlp
                .reader
                .next_expected(writer)
                .is_some_and(|n| sn >= n),
            e if e.is_builtin() => false,
            _ => self.readers.iter().any(|(e, lr)| {
                (reader_id == EntityId::UNKNOWN || reader_id == *e)
                    && lr.matched.contains(&writer)
                    && lr.reader.next_expected(writer).is_some_and(|n| sn >= n)
            }),
        }
    }

    fn on_data_frag(
        &mut self,
        rx: &Rx,
        f: &DataFrag<'_>,
        little: bool,
        source: Locator,
        now: Instant,
    ) {
        let writer = Guid {
            prefix: rx.src,
            entity: f.writer_id,
        };
        if !self.wants(writer, f.reader_id, f.writer_sn) {
            return;
        }
        // the inline QoS of the first fragment that had one: Cyclone sends
        // it only with fragment 1, which need not be the last to arrive
        match self.reassembler.insert_with_qos(writer, f, rx.ts, little) {
            Ok(Some(c)) => self.on_data(
                &Rx { ts: c.ts, ..*rx },
                f.reader_id,
                f.writer_id,
                f.writer_sn,
                c.inline_qos.as_deref(),
                c.little_endian,
                Some(Cow::Owned(c.data)),
                f.key,
                source,
                now,
            ),
            Ok(None) => {}
            Err(FragError::TooLarge { size, limit }) => {
                self.stats.fragments_rejected += 1;
                self.give_up(writer, f.reader_id, f.writer_sn, size, limit);
            }
            Err(_) => self.stats.fragments_rejected += 1,
        }
    }

    /// A sample too large to take: each local reader that awaits it skips
    /// it and says so (once); discovery data is not given up (its writer
    /// resends it, and a participant that big is refused anyway).
    fn give_up(
        &mut self,
        writer: Guid,
        reader_id: EntityId,
        sn: SequenceNumber,
        size: u32,
        limit: usize,
    ) {
        if writer.entity.is_builtin() {
            return;
        }
        let prefix = self.cfg.guid_prefix;
        for (e, lr) in self.readers.iter_mut() {
            if (reader_id == EntityId::UNKNOWN || reader_id == *e)
                && lr.matched.contains(&writer)
                && lr.reader.give_up(writer, sn)
            {
                self.events.push_back(Event::SampleLost {
                    reader: Guid { prefix, entity: *e },
                    writer,
                    sn,
                    size,
                    limit,
                });
            }
        }
    }

    fn on_heartbeat(&mut self, rx: &Rx, h: &Heartbeat, now: Instant) {
        let writer = Guid {
            prefix: rx.src,
            entity: h.writer_id,
        };
        match h.writer_id {
            EntityId::SEDP_PUBLICATIONS_WRITER => self.pub_reader.handle_heartbeat(writer, h),
            EntityId::SEDP_SUBSCRIPTIONS_WRITER => self.sub_reader.handle_heartbeat(writer, h),
            EntityId::P2P_MESSAGE_WRITER => self.wlp.reader.handle_heartbeat(writer, h),
            e if e.is_builtin() => return,
            _ => {
                if h.liveliness {
                    self.writer_asserted(writer, now);
                }
                for (e, lr) in self.readers.iter_mut() {
                    if (h.reader_id == EntityId::UNKNOWN || h.reader_id == *e)
                        && lr.matched.contains(&writer)
                    {
                        lr.reader.handle_heartbeat(writer, h);
                    }
                }
            }
        }
        // fragments of samples the writer no longer has will never complete
        self.reassembler.forget_below(writer, h.first_sn);
    }

    fn on_gap(&mut self, rx: &Rx, g: &Gap) {
        let writer = Guid {
            prefix: rx.src,
            entity: g.writer_id,
        };
        match g.writer_id {
            EntityId::SEDP_PUBLICATIONS_WRITER => self.pub_reader.handle_gap(writer, g),
            EntityId::SEDP_SUBSCRIPTIONS_WRITER => self.sub_reader.handle_gap(writer, g),
            EntityId::P2P_MESSAGE_WRITER => self.wlp.reader.handle_gap(writer, g),
            e if e.is_builtin() => {}
            _ => {
                for (e, lr) in self.readers.iter_mut() {
                    if (g.reader_id == EntityId::UNKNOWN || g.reader_id == *e)
                        && lr.matched.contains(&writer)
                    {
                        lr.reader.handle_gap(writer, g);
                    }
                }
            }
        }
    }

    fn on_acknack(&mut self, rx: &Rx, a: &AckNack, now: Instant) {
        let reader = Guid {
            prefix: rx.src,
            entity: a.reader_id,
        };
        match a.writer_id {
            EntityId::SEDP_PUBLICATIONS_WRITER => self.pub_writer.handle_acknack(reader, a, now),
            EntityId::SEDP_SUBSCRIPTIONS_WRITER => self.sub_writer.handle_acknack(reader, a, now),
            EntityId::P2P_MESSAGE_WRITER => self.wlp.writer.handle_acknack(reader, a, now),
            e if e.is_builtin() => {}
            e => {
                if let Some(w) = self.writers.get_mut(&e) {
                    w.writer.handle_acknack(reader, a, now);
                }
            }
        }
    }

    fn on_nack_frag(&mut self, rx: &Rx, n: &NackFrag) {
        let reader = Guid {
            prefix: rx.src,
            entity: n.reader_id,
        };
        let sample = match n.writer_id {
            EntityId::SEDP_PUBLICATIONS_WRITER if self.pub_writer_readers.contains(&reader) => {
                self.pub_writer.get(n.writer_sn).cloned()
            }
            EntityId::SEDP_SUBSCRIPTIONS_WRITER if self.sub_writer_readers.contains(&reader) => {
                self.sub_writer.get(n.writer_sn).cloned()
            }
            e if e.is_builtin() => None,
            e => self
                .writers
                .get(&e)
                .filter(|w| w.matched.contains(&reader))
                .and_then(|w| w.writer.get(n.writer_sn).cloned()),
        };
        let Some(sample) = sample else { return };
        let frags: BTreeSet<u32> = n.fragment_number_state.iter().collect();
        let route = Route {
            participants: &self.participants,
            remote_writers: &self.remote_writers,
            remote_readers: &self.remote_readers,
        };
        let Some(l) = route.reader(reader) else {
            return;
        };
        let shape = Shape {
            max: self.cfg.max_message_size,
            fragment_size: self.cfg.fragment_size,
        };
        let outbox = &mut self.outbox;
        let env = open(&sample);
        // fragments past what this NACK_FRAG could name: ask for the rest
        // right after these (see `Writer::heartbeat_to`)
        let fs = usize::from(shape.fragment_size.max(1));
        let set = &n.fragment_number_state;
        let more =
            env.data.len().div_ceil(fs) as u64 > u64::from(set.base) + u64::from(set.num_bits) - 1;
        data_units(
            shape,
            n.reader_id,
            n.writer_id,
            n.writer_sn,
            &key_form_for(&route, reader.prefix, &env),
            Some(&frags),
            |ts, sm| outbox.push_sample(l, reader.prefix, ts, sm, &sample),
        );
        if more {
            let writer = match n.writer_id {
                EntityId::SEDP_PUBLICATIONS_WRITER => Some(&mut self.pub_writer),
                EntityId::SEDP_SUBSCRIPTIONS_WRITER => Some(&mut self.sub_writer),
                e => self.writers.get_mut(&e).map(|w| &mut w.writer),
            };
            if let Some(w) = writer {
                w.heartbeat_to(reader);
            }
        }
    }
}
