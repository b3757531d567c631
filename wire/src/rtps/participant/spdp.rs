//! SPDP, participant discovery (§8.5.3): this participant's announcements
//! (periodic to the configured destinations and every known participant,
//! and directed to a newcomer), received announcements and disposals, and
//! what a participant found or lost means for the SEDP endpoints and the
//! remote endpoints it had.

use std::time::{Duration, Instant};

use super::emit::pick;
use super::outbox::Unit;
use super::{builtin_endpoints, Event, LostReason, Participant};
use crate::rtps::discovery::{payload_params, Disposal, ParticipantData};
use crate::rtps::matching::ParticipantEvent;
use crate::rtps::{Data, EntityId, Guid, GuidPrefix, Locator, SequenceNumber, Submessage};

impl Participant {
    /// Where periodic SPDP goes: the configured destinations, then each known
    /// participant's metatraffic locator not already among them.
    pub(super) fn spdp_targets(&self) -> Vec<(Locator, GuidPrefix)> {
        let mut t: Vec<(Locator, GuidPrefix)> = self
            .cfg
            .spdp_destinations
            .iter()
            .map(|l| (*l, GuidPrefix::UNKNOWN))
            .collect();
        let mut known: Vec<&ParticipantData> = self.participants.iter().collect();
        known.sort_by_key(|p| p.guid_prefix);
        for p in known {
            if let Some(l) = pick(&p.metatraffic_unicast) {
                if !t.iter().any(|(x, _)| *x == l) {
                    t.push((l, p.guid_prefix));
                }
            }
        }
        t
    }

    fn spdp_unit(&self, now: Instant) -> Unit {
        let d = Data {
            reader_id: EntityId::SPDP_READER,
            writer_id: EntityId::SPDP_WRITER,
            writer_sn: SequenceNumber(1),
            inline_qos: None,
            payload: Some(&self.spdp_payload),
            key: false,
            non_standard: false,
        };
        Unit::new(Some(self.wall(now)), &Submessage::Data(d))
    }

    pub(super) fn announce(&mut self, now: Instant) {
        for (l, p) in self.spdp_targets() {
            let u = self.spdp_unit(now);
            self.outbox.push(l, p, u);
        }
        let period = if self.initial_left > 0 {
            self.initial_left -= 1;
            self.cfg.initial_announce_period
        } else {
            // at least three announcements per lease: a short lease
            // (`lease_ms=500`) expired between 3 s announcements of an
            // idle participant, and peers dropped it while it lived
            self.cfg.announce_period.min(self.cfg.lease_duration / 3)
        };
        self.next_announce = now
            .checked_add(period.max(Duration::from_millis(1)))
            .unwrap_or(now);
    }

    #[allow(clippy::too_many_arguments)]
    pub(super) fn on_spdp(
        &mut self,
        qos: Option<&[u8]>,
        little: bool,
        payload: Option<&[u8]>,
        key: bool,
        source: Locator,
        now: Instant,
    ) {
        match Disposal::from_data(qos, little, payload, key) {
            Ok(Some(d)) => {
                let prefix = Guid::from_bytes(d.key_hash).prefix;
                if self.participants.remove(prefix).is_some() {
                    self.participant_gone(prefix, LostReason::Disposed);
                }
                return;
            }
            Ok(None) => {}
            Err(_) => {
                self.stats.discovery_errors += 1;
                return;
            }
        }
        let Some(payload) = payload.filter(|_| !key) else {
            return;
        };
        let mut data = match payload_params(payload).and_then(|l| ParticipantData::from_params(&l))
        {
            Ok(d) => d,
            Err(_) => {
                self.stats.discovery_errors += 1;
                return;
            }
        };
        if data.guid_prefix == self.cfg.guid_prefix || data.guid_prefix == GuidPrefix::UNKNOWN {
            return;
        }
        if data.domain_id.is_some_and(|d| d != self.cfg.domain_id) {
            self.stats.other_domain += 1;
            return;
        }
        if data.metatraffic_unicast.is_empty() && data.default_unicast.is_empty() {
            // nowhere announced: answer where it came from
            data.metatraffic_unicast.push(source);
        }
        let known = self.participants.get(&data.guid_prefix).is_some();
        if !known && self.participants.len() >= self.cfg.max_participants {
            // Full: a participant that announced itself and no endpoint
            // makes room, the one heard from least recently. Without it
            // 1100 forged announcements with long leases locked every new
            // peer out for as long as the leases ran.
            let Some(idle) = self.idlest_participant() else {
                self.stats.discovery_limited += 1;
                return;
            };
            self.participants.remove(idle);
            self.participant_gone(idle, LostReason::Evicted);
            self.stats.discovery_limited += 1;
        }
        match self.participants.announce(data.clone(), now) {
            Some(ParticipantEvent::Found(_)) => {
                self.events.push_back(Event::ParticipantFound(data.clone()));
                self.participant_found(&data, now);
            }
            Some(ParticipantEvent::Changed(_)) => {
                self.events.push_back(Event::ParticipantChanged(data))
            }
            _ => {}
        }
    }

    /// The participant without any known endpoint that was heard from
    /// least recently.
    fn idlest_participant(&self) -> Option<GuidPrefix> {
        let has_endpoints = |prefix: GuidPrefix| {
            self.remote_writers.range(prefix.guids()).next().is_some()
                || self.remote_readers.range(prefix.guids()).next().is_some()
        };
        self.participants
            .iter()
            .map(|d| d.guid_prefix)
            .filter(|p| !has_endpoints(*p))
            .min_by_key(|p| self.participants.heard(p))
    }

    fn participant_found(&mut self, data: &ParticipantData, now: Instant) {
        use builtin_endpoints as b;
        let prefix = data.guid_prefix;
        // Fast DDS repeats the SEDP bits in the (security) upper half: mask
        // to what we implement; a peer announcing nothing gets the standard four
        let mut bes = data.builtin_endpoints & b::COURIER;
        if bes & !(b::PARTICIPANT_ANNOUNCER | b::PARTICIPANT_DETECTOR) == 0 {
            bes |= b::DISCOVERY;
        }
        let g = |entity| Guid { prefix, entity };
        // our SPDP first, directly, so that it arrives before our SEDP heartbeats
        if let Some(l) = pick(&data.metatraffic_unicast).or_else(|| pick(&data.default_unicast)) {
            let u = self.spdp_unit(now);
            self.outbox.push(l, prefix, u);
        }
        if bes & b::PUBLICATIONS_DETECTOR != 0 {
            let r = g(EntityId::SEDP_PUBLICATIONS_READER);
            self.pub_writer.add_reader(r, true, now);
            self.pub_writer_readers.insert(r);
        }
        if bes & b::SUBSCRIPTIONS_DETECTOR != 0 {
            let r = g(EntityId::SEDP_SUBSCRIPTIONS_READER);
            self.sub_writer.add_reader(r, true, now);
            self.sub_writer_readers.insert(r);
        }
        if bes & b::PUBLICATIONS_ANNOUNCER != 0 {
            self.pub_reader
                .add_writer(g(EntityId::SEDP_PUBLICATIONS_WRITER), now);
        }
        if bes & b::SUBSCRIPTIONS_ANNOUNCER != 0 {
            self.sub_reader
                .add_writer(g(EntityId::SEDP_SUBSCRIPTIONS_WRITER), now);
        }
        if bes & b::PARTICIPANT_MESSAGE_READER != 0 {
            let r = g(EntityId::P2P_MESSAGE_READER);
            self.wlp.writer.add_reader(r, true, now);
            self.wlp.readers.insert(r);
        }
        if bes & b::PARTICIPANT_MESSAGE_WRITER != 0 {
            self.wlp
                .reader
                .add_writer(g(EntityId::P2P_MESSAGE_WRITER), now);
        }
    }

    /// Cleans up after a participant that left (already out of the table).
    pub(super) fn participant_gone(&mut self, prefix: GuidPrefix, reason: LostReason) {
        let g = |entity| Guid { prefix, entity };
        for (w, set, e) in [
            (
                &mut self.pub_writer,
                &mut self.pub_writer_readers,
                EntityId::SEDP_PUBLICATIONS_READER,
            ),
            (
                &mut self.sub_writer,
                &mut self.sub_writer_readers,
                EntityId::SEDP_SUBSCRIPTIONS_READER,
            ),
        ] {
            w.remove_reader(g(e));
            set.remove(&g(e));
        }
        let r = g(EntityId::P2P_MESSAGE_READER);
        self.wlp.writer.remove_reader(r);
        self.wlp.readers.remove(&r);
        self.wlp
            .reader
            .remove_writer(g(EntityId::P2P_MESSAGE_WRITER));
        self.wlp.forget_participant(prefix);
        for (r, e) in [
            (&mut self.pub_reader, EntityId::SEDP_PUBLICATIONS_WRITER),
            (&mut self.sub_reader, EntityId::SEDP_SUBSCRIPTIONS_WRITER),
        ] {
            r.remove_writer(g(e));
            self.reassembler
                .forget_below(g(e), SequenceNumber(i64::MAX));
        }
        let ws: Vec<Guid> = self
            .remote_writers
            .range(prefix.guids())
            .map(|(g, _)| *g)
            .collect();
        for w in ws {
            self.remote_writer_gone(w);
        }
        let rs: Vec<Guid> = self
            .remote_readers
            .range(prefix.guids())
            .map(|(g, _)| *g)
            .collect();
        for r in rs {
            self.remote_reader_gone(r);
        }
        self.events
            .push_back(Event::ParticipantLost { prefix, reason });
    }
}
