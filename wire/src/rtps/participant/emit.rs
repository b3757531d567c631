//! From the state machines to submessages: where a remote endpoint is
//! reached (`Route`, UDPv4 locators first), the DATA or DATA_FRAGs a change
//! becomes within the message size, what a writer's transmits (DATA, GAP,
//! HEARTBEAT) and a reader's (ACKNACK, or NACK_FRAG for partly reassembled
//! samples) become, and `Participant::gather`, which drains every built-in
//! and user endpoint into the outbox.

use std::collections::{BTreeMap, BTreeSet};

use super::change::{inline_qos, open, ChangeKind, Env, VENDOR_EPROSIMA};
use super::outbox::{Outbox, Unit};
use super::Participant;
use crate::rtps::discovery::EndpointData;
use crate::rtps::frag::{self, Reassembler};
use crate::rtps::matching::Participants;
use crate::rtps::reliability::Transmit;
use crate::rtps::{
    AckNack, Data, DataFrag, EntityId, FragmentNumberSet, Gap, Guid, GuidPrefix, Heartbeat,
    Locator, NackFrag, SequenceNumber, SequenceNumberSet, Submessage, Time,
};

/// Room for header, INFO_DST, INFO_TS and a DATA/DATA_FRAG header.
pub(super) const OVERHEAD: usize = 96;

/// Message size limits, copied out of the config.
#[derive(Clone, Copy)]
pub(super) struct Shape {
    pub(super) max: usize,
    pub(super) fragment_size: u16,
}

/// The best locator to send to: UDPv4 first, then UDPv6; other kinds (shared
/// memory, TCP) are not reachable by a UDP transport.
pub(super) fn pick(ls: &[Locator]) -> Option<Locator> {
    let ok = |l: &&Locator| l.port != 0 && l.port <= 0xffff;
    ls.iter()
        .filter(ok)
        .find(|l| l.kind == Locator::KIND_UDPV4)
        .or_else(|| ls.iter().filter(ok).find(|l| l.kind == Locator::KIND_UDPV6))
        .copied()
}

/// Looks up where remote endpoints live.
pub(super) struct Route<'a> {
    pub(super) participants: &'a Participants,
    pub(super) remote_writers: &'a BTreeMap<Guid, EndpointData>,
    pub(super) remote_readers: &'a BTreeMap<Guid, EndpointData>,
}

impl Route<'_> {
    fn locate(&self, g: Guid, own: Option<&EndpointData>) -> Option<Locator> {
        let p = self.participants.get(&g.prefix)?;
        if g.entity.is_builtin() {
            pick(&p.metatraffic_unicast)
                .or_else(|| pick(&p.metatraffic_multicast))
                .or_else(|| pick(&p.default_unicast))
        } else {
            own.and_then(|d| pick(&d.unicast).or_else(|| pick(&d.multicast)))
                .or_else(|| pick(&p.default_unicast))
                .or_else(|| pick(&p.default_multicast))
                .or_else(|| pick(&p.metatraffic_unicast))
        }
    }

    pub(super) fn reader(&self, r: Guid) -> Option<Locator> {
        self.locate(r, self.remote_readers.get(&r))
    }

    fn writer(&self, w: Guid) -> Option<Locator> {
        self.locate(w, self.remote_writers.get(&w))
    }

    /// Destinations for "every matched reader": one per (locator,
    /// participant); the reader's entity id when it is alone there.
    fn group(&self, readers: &BTreeSet<Guid>, groups: &mut Vec<(Locator, GuidPrefix, EntityId)>) {
        groups.clear();
        for r in readers {
            let Some(l) = self.reader(*r) else { continue };
            match groups
                .iter_mut()
                .find(|(gl, gp, _)| *gl == l && *gp == r.prefix)
            {
                Some(g) => g.2 = EntityId::UNKNOWN,
                None => groups.push((l, r.prefix, r.entity)),
            }
        }
    }
}

/// The DATA or DATA_FRAG submessages for one change, each handed to `emit`
/// with the change's timestamp; `only` restricts DATA_FRAGs to those
/// fragment numbers (a NACK_FRAG answer).
pub(super) fn data_units(
    shape: Shape,
    reader_id: EntityId,
    writer_id: EntityId,
    sn: SequenceNumber,
    e: &Env<'_>,
    only: Option<&BTreeSet<u32>>,
    mut emit: impl FnMut(Option<Time>, &Submessage<'_>),
) {
    let q = inline_qos(e);
    let qlen = q.as_ref().map_or(0, Vec::len);
    let key = e.kind != ChangeKind::Alive;
    if only.is_none() && e.data.len() + qlen + OVERHEAD <= shape.max {
        let payload = if key && e.data.is_empty() {
            None
        } else {
            Some(e.data)
        };
        let d = Data {
            reader_id,
            writer_id,
            writer_sn: sn,
            inline_qos: q.as_deref(),
            payload,
            key: key && payload.is_some(),
            non_standard: false,
        };
        emit(e.ts, &Submessage::Data(d));
        return;
    }
    let fs = shape.fragment_size.max(1);
    let per = if only.is_some() {
        1
    } else {
        (shape.max.saturating_sub(OVERHEAD + qlen) / usize::from(fs)).clamp(1, 0xffff) as u16
    };
    for f in frag::fragment(reader_id, writer_id, sn, e.data, fs, per)
        .filter(|f| only.is_none_or(|o| o.contains(&f.fragment_starting_num)))
    {
        let f = DataFrag {
            inline_qos: q.as_deref(),
            key,
            ..f
        };
        emit(e.ts, &Submessage::DataFrag(f));
    }
}

/// [`data_units`] collected, for a change sent to several destinations
/// outside the per-sample path.
pub(super) fn data_unit_list(
    shape: Shape,
    reader_id: EntityId,
    writer_id: EntityId,
    sn: SequenceNumber,
    e: &Env<'_>,
) -> Vec<Unit> {
    let mut units = Vec::new();
    data_units(shape, reader_id, writer_id, sn, e, None, |ts, sm| {
        units.push(Unit::new(ts, sm))
    });
    units
}

/// A dispose or unregister as the participant `to` reads it. It carries the
/// serialized key (K flag), which Cyclone DDS needs to find an instance whose
/// key hash is an MD5 digest (Cyclone 11 needs it always), and the key hash
/// inline. Fast DDS (2.9 and before) copies a key payload of up to 16 bytes
/// over the key hash into the instance handle, so that the change lands on
/// an instance of its own: to eProsima's participants it goes as Fast DDS
/// sends its own, key hash only.
pub(super) fn key_form_for<'a>(route: &Route<'_>, to: GuidPrefix, e: &Env<'a>) -> Env<'a> {
    let strip = e.kind != ChangeKind::Alive
        && e.key_hash.is_some()
        && !e.data.is_empty()
        && route
            .participants
            .get(&to)
            .is_some_and(|p| p.vendor == VENDOR_EPROSIMA);
    Env {
        data: if strip { &[] } else { e.data },
        ..*e
    }
}

/// Sends what a writer (built-in or user) asked for.
fn emit_writer(
    route: &Route<'_>,
    shape: Shape,
    outbox: &mut Outbox,
    writer_id: EntityId,
    matched: &BTreeSet<Guid>,
    t: Transmit,
) {
    // the destinations, in the outbox's scratch vector
    let targets = |to: Option<Guid>, outbox: &mut Outbox| {
        let mut t = std::mem::take(&mut outbox.targets);
        match to {
            Some(r) => {
                t.clear();
                t.extend(route.reader(r).map(|l| (l, r.prefix, r.entity)));
            }
            None => route.group(matched, &mut t),
        }
        t
    };
    match t {
        Transmit::Data { to, sn, payload } => {
            let e = open(&payload);
            let t = targets(to, outbox);
            for &(l, p, rid) in &t {
                let e = key_form_for(route, p, &e);
                data_units(shape, rid, writer_id, sn, &e, None, |ts, sm| {
                    outbox.push_sample(l, p, ts, sm, &payload)
                });
            }
            outbox.targets = t;
        }
        Transmit::Gap { to, start, list } => {
            if let Some(l) = route.reader(to) {
                let g = Gap {
                    reader_id: to.entity,
                    writer_id,
                    gap_start: start,
                    gap_list: list,
                    extra: Vec::new(),
                };
                outbox.push_sm(l, to.prefix, None, &Submessage::Gap(g));
            }
        }
        Transmit::Heartbeat {
            to,
            first,
            last,
            count,
            final_flag,
            liveliness,
        } => {
            let t = targets(to, outbox);
            for &(l, p, rid) in &t {
                let h = Heartbeat {
                    reader_id: rid,
                    writer_id,
                    first_sn: first,
                    last_sn: last,
                    count,
                    final_flag,
                    liveliness,
                };
                outbox.push_sm(l, p, None, &Submessage::Heartbeat(h));
            }
            outbox.targets = t;
        }
        Transmit::AckNack { .. } => {}
    }
}

/// Sends a reader's ACKNACK; samples that are partly reassembled are asked
/// for by fragment with NACK_FRAG instead, as Cyclone does.
fn emit_reader(
    route: &Route<'_>,
    outbox: &mut Outbox,
    reassembler: &Reassembler,
    nackfrag_count: &mut i32,
    reader_id: EntityId,
    t: Transmit,
) {
    let Transmit::AckNack {
        to,
        state,
        count,
        final_flag,
    } = t
    else {
        return;
    };
    let Some(l) = route.writer(to) else { return };
    let mut whole = Vec::new();
    let mut partial = Vec::new();
    for sn in state.iter() {
        let missing = reassembler.missing(to, sn);
        if missing.is_empty() {
            whole.push(sn);
        } else {
            partial.push((sn, missing));
        }
    }
    let (state, final_flag) = if partial.is_empty() {
        (state, final_flag)
    } else {
        let s = SequenceNumberSet::from_members(state.base, state.num_bits, whole.iter().copied());
        (s, whole.is_empty())
    };
    let a = AckNack {
        reader_id,
        writer_id: to.entity,
        reader_sn_state: state,
        count,
        final_flag,
    };
    outbox.push_sm(l, to.prefix, None, &Submessage::AckNack(a));
    for (sn, missing) in partial {
        let base = missing[0];
        let last = missing
            .iter()
            .copied()
            .take_while(|f| *f < base.saturating_add(256))
            .last()
            .unwrap_or(base);
        let num_bits = last - base + 1;
        let mut bitmap = vec![0u32; num_bits.div_ceil(32) as usize];
        for f in missing.iter().copied().filter(|f| *f <= last) {
            let d = f - base;
            bitmap[(d / 32) as usize] |= 1 << (31 - d % 32);
        }
        *nackfrag_count = nackfrag_count.wrapping_add(1);
        let n = NackFrag {
            reader_id,
            writer_id: to.entity,
            writer_sn: sn,
            fragment_number_state: FragmentNumberSet {
                base,
                num_bits,
                bitmap,
            },
            count: *nackfrag_count,
        };
        outbox.push_sm(l, to.prefix, None, &Submessage::NackFrag(n));
    }
}

impl Participant {
    /// Moves what the writers and readers want sent into datagrams.
    pub(super) fn gather(&mut self) {
        // everything pending goes into `out` below
        self.gather_due = false;
        let shape = self.shape();
        let route = Route {
            participants: &self.participants,
            remote_writers: &self.remote_writers,
            remote_readers: &self.remote_readers,
        };
        let outbox = &mut self.outbox;
        while let Some(t) = self.pub_writer.poll_transmit() {
            emit_writer(
                &route,
                shape,
                outbox,
                EntityId::SEDP_PUBLICATIONS_WRITER,
                &self.pub_writer_readers,
                t,
            );
        }
        while let Some(t) = self.sub_writer.poll_transmit() {
            emit_writer(
                &route,
                shape,
                outbox,
                EntityId::SEDP_SUBSCRIPTIONS_WRITER,
                &self.sub_writer_readers,
                t,
            );
        }
        while let Some(t) = self.pub_reader.poll_transmit() {
            emit_reader(
                &route,
                outbox,
                &self.reassembler,
                &mut self.nackfrag_count,
                EntityId::SEDP_PUBLICATIONS_READER,
                t,
            );
        }
        while let Some(t) = self.sub_reader.poll_transmit() {
            emit_reader(
                &route,
                outbox,
                &self.reassembler,
                &mut self.nackfrag_count,
                EntityId::SEDP_SUBSCRIPTIONS_READER,
                t,
            );
        }
        while let Some(t) = self.wlp.writer.poll_transmit() {
            emit_writer(
                &route,
                shape,
                outbox,
                EntityId::P2P_MESSAGE_WRITER,
                &self.wlp.readers,
                t,
            );
        }
        while let Some(t) = self.wlp.reader.poll_transmit() {
            emit_reader(
                &route,
                outbox,
                &self.reassembler,
                &mut self.nackfrag_count,
                EntityId::P2P_MESSAGE_READER,
                t,
            );
        }
        for (w, r, sn, payload) in self.replays.drain(..) {
            if let Some(lw) = self.writers.get(&w) {
                let t = Transmit::Data {
                    to: Some(r),
                    sn,
                    payload,
                };
                emit_writer(&route, shape, outbox, w, &lw.matched, t);
            }
        }
        for (e, lw) in self.writers.iter_mut() {
            while let Some(t) = lw.writer.poll_transmit() {
                emit_writer(&route, shape, outbox, *e, &lw.matched, t);
            }
        }
        for (e, lr) in self.readers.iter_mut() {
            while let Some(t) = lr.reader.poll_transmit() {
                emit_reader(
                    &route,
                    outbox,
                    &self.reassembler,
                    &mut self.nackfrag_count,
                    *e,
                    t,
                );
            }
        }
        self.outbox.drain(&mut self.out, &mut self.stats);
    }
}
