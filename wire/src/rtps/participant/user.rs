//! User writers and readers: creating them (entity ids, matching right
//! away), deleting them, writing changes (per-instance keep-last history,
//! in-process delivery to local readers) and the calls around writing:
//! buffer recycling, room in the history, acknowledgement requests.

use std::collections::{BTreeSet, VecDeque};
use std::time::{Duration, Instant};

use foldhash::{HashMap, HashMapExt};

use super::change::{envelope_with, ReceivedSample, ENVELOPE_ROOM};
use super::{
    entity_id, Change, CreateError, EndpointConfig, EndpointKind, Event, Participant, WriteError,
    MAX_WRITE_SIZE,
};
use crate::rtps::discovery::{Durability, EndpointData, History, Reliability};
use crate::rtps::reliability::{Reader, Writer};
use crate::rtps::{EntityId, Guid, SequenceNumber, Time};

pub(super) struct LocalWriter {
    pub(super) data: EndpointData,
    pub(super) writer: Writer,
    pub(super) reliable: bool,
    pub(super) durable: bool,
    /// Per-instance keep-last depth (keyed topics only).
    pub(super) keep_last: Option<usize>,
    /// The sequence numbers in the history of each instance, by key hash
    /// (per-instance keep-last, and transient-local keyed writers).
    pub(super) instances: HashMap<[u8; 16], VecDeque<i64>>,
    pub(super) matched: BTreeSet<Guid>,
    pub(super) local_readers: BTreeSet<EntityId>,
    pub(super) acked_reported: i64,
    /// LIFESPAN, if finite: a sample leaves the history this long after
    /// its source timestamp (DDS 1.4 §2.2.3.16), so that neither a late
    /// joiner nor a repair gets it.
    pub(super) lifespan: Option<Duration>,
    /// When each sample in the history expires, by sequence number.
    pub(super) expiries: BTreeSet<(Instant, i64)>,
}

impl LocalWriter {
    /// When the next sample expires.
    pub(super) fn next_expiry(&self) -> Option<Instant> {
        self.expiries.first().map(|e| e.0)
    }

    /// Drops the samples whose lifespan ended by `now` from the history
    /// (a reader that still asks for one gets a GAP).
    pub(super) fn expire(&mut self, now: Instant) {
        while let Some(&(at, sn)) = self.expiries.first() {
            if at > now {
                break;
            }
            self.expiries.pop_first();
            self.writer.remove(SequenceNumber(sn));
        }
    }
}

pub(super) struct LocalReader {
    pub(super) data: EndpointData,
    pub(super) reader: Reader,
    pub(super) matched: BTreeSet<Guid>,
    pub(super) local_writers: BTreeSet<EntityId>,
}

/// The largest entity key (24 bits).
const MAX_KEY: u32 = 0x00ff_ffff;

fn valid_name(s: &str) -> bool {
    !s.is_empty() && s.len() <= 256 && !s.contains('\0')
}

impl Participant {
    /// Creates a local writer and announces it. Matching readers (remote,
    /// and local ones in this participant) are matched right away.
    pub fn create_writer(
        &mut self,
        config: EndpointConfig,
        now: Instant,
    ) -> Result<Guid, CreateError> {
        self.touch();
        let (guid, data) = self.new_endpoint(config, EndpointKind::Writer)?;
        let keyed = guid.entity.kind() == 0x02;
        let q = &data.qos;
        let reliable = matches!(q.reliability, Reliability::Reliable(_));
        let durable = q.durability >= Durability::TransientLocal;
        let max = self.cfg.max_history;
        let (depth, keep_last) = match q.history {
            History::KeepLast(n) => {
                let n = usize::try_from(n.max(1)).unwrap_or(1).min(max);
                if keyed {
                    (Some(max), Some(n))
                } else {
                    (Some(n), None)
                }
            }
            History::KeepAll => (None, None),
        };
        let lifespan = q.lifespan.to_std();
        let writer = Writer::new(guid, reliable, depth, max, self.cfg.heartbeat_period)
            .retain_acked(durable)
            // per-instance keep-last: the depth bounds all instances
            // together, and another instance's last change (its dispose,
            // say) must not make room for this one before readers have it
            .keep_unacked(keep_last.is_some())
            .max_unacked_bytes(self.cfg.max_unacked_bytes);
        self.announce_endpoint(&data, true, now);
        self.writers.insert(
            guid.entity,
            LocalWriter {
                data,
                writer,
                reliable,
                durable,
                keep_last,
                instances: HashMap::new(),
                matched: BTreeSet::new(),
                local_readers: BTreeSet::new(),
                acked_reported: 0,
                lifespan,
                expiries: BTreeSet::new(),
            },
        );
        let remote: Vec<Guid> = self.remote_readers.keys().copied().collect();
        for r in remote {
            self.match_remote_reader(guid.entity, r, now);
        }
        let local: Vec<EntityId> = self.readers.keys().copied().collect();
        for r in local {
            self.match_local(guid.entity, r);
        }
        self.wlp_reschedule(now);
        self.flush(now);
        Ok(guid)
    }

    /// Creates a local reader and announces it. Matching writers (remote,
    /// and local ones in this participant) are matched right away.
    pub fn create_reader(
        &mut self,
        config: EndpointConfig,
        now: Instant,
    ) -> Result<Guid, CreateError> {
        self.touch();
        let (guid, data) = self.new_endpoint(config, EndpointKind::Reader)?;
        let reliable = matches!(data.qos.reliability, Reliability::Reliable(_));
        let mut reader = Reader::new(reliable, self.cfg.max_out_of_order)
            .max_pending_bytes(self.cfg.max_out_of_order_bytes);
        if data.qos.durability == Durability::Volatile {
            reader = reader.volatile();
        }
        self.announce_endpoint(&data, false, now);
        self.readers.insert(
            guid.entity,
            LocalReader {
                data,
                reader,
                matched: BTreeSet::new(),
                local_writers: BTreeSet::new(),
            },
        );
        let remote: Vec<Guid> = self.remote_writers.keys().copied().collect();
        for w in remote {
            self.match_remote_writer(guid.entity, w, now);
        }
        let local: Vec<EntityId> = self.writers.keys().copied().collect();
        for w in local {
            self.match_local(w, guid.entity);
        }
        self.flush(now);
        Ok(guid)
    }

    fn new_endpoint(
        &mut self,
        config: EndpointConfig,
        kind: EndpointKind,
    ) -> Result<(Guid, EndpointData), CreateError> {
        if self.closed {
            return Err(CreateError::Closed);
        }
        if !valid_name(&config.topic_name) || !valid_name(&config.type_name) {
            return Err(CreateError::InvalidName);
        }
        let entity = self
            .free_entity(kind, config.keyed)
            .ok_or(CreateError::TooManyEndpoints)?;
        let mut qos = config.qos;
        if qos.data_representation.is_empty() {
            qos.data_representation = vec![0];
        }
        let guid = self.guid(entity);
        let data = EndpointData {
            guid,
            topic_name: config.topic_name,
            type_name: config.type_name,
            qos,
            unicast: Vec::new(),
            multicast: Vec::new(),
            expects_inline_qos: false,
            type_information: None,
            disposes_when_deleted: false,
        };
        Ok((guid, data))
    }

    /// The next entity id not in use. Keys count up to 2^24 - 1 and then
    /// start again from 1 (a long-lived participant creates and deletes
    /// endpoints without end), skipping the ones in use; a key comes back
    /// only after every other one was given out since, long after any
    /// peer forgot the endpoint that had it.
    fn free_entity(&mut self, kind: EndpointKind, keyed: bool) -> Option<EntityId> {
        for _ in 0..MAX_KEY {
            let key = self.next_key;
            self.next_key = if key >= MAX_KEY { 1 } else { key + 1 };
            let e = entity_id(key, kind, keyed)?;
            if !self.writers.contains_key(&e) && !self.readers.contains_key(&e) {
                return Some(e);
            }
        }
        None
    }

    /// Deletes a local writer: its readers are unmatched and a dispose is
    /// announced. Returns false if there is no such writer.
    pub fn delete_writer(&mut self, writer: Guid, now: Instant) -> bool {
        self.touch();
        if !self.is_local(writer) {
            return false;
        }
        let Some(w) = self.writers.remove(&writer.entity) else {
            return false;
        };
        for r in &w.matched {
            self.events
                .push_back(Event::WriterUnmatched { writer, reader: *r });
        }
        for r in &w.local_readers {
            if let Some(lr) = self.readers.get_mut(r) {
                lr.local_writers.remove(&writer.entity);
            }
            let reader = self.guid(*r);
            self.events
                .push_back(Event::WriterUnmatched { writer, reader });
            self.events
                .push_back(Event::ReaderUnmatched { reader, writer });
        }
        self.unannounce_endpoint(writer, true, now);
        self.wlp_reschedule(now);
        self.flush(now);
        true
    }

    /// Deletes a local reader: its writers are unmatched and a dispose is
    /// announced. Returns false if there is no such reader.
    pub fn delete_reader(&mut self, reader: Guid, now: Instant) -> bool {
        self.touch();
        if !self.is_local(reader) {
            return false;
        }
        let Some(r) = self.readers.remove(&reader.entity) else {
            return false;
        };
        for w in &r.matched {
            self.events
                .push_back(Event::ReaderUnmatched { reader, writer: *w });
        }
        for w in &r.local_writers {
            if let Some(lw) = self.writers.get_mut(w) {
                lw.local_readers.remove(&reader.entity);
            }
            let writer = self.guid(*w);
            self.events
                .push_back(Event::ReaderUnmatched { reader, writer });
            self.events
                .push_back(Event::WriterUnmatched { writer, reader });
        }
        self.unannounce_endpoint(reader, false, now);
        self.flush(now);
        true
    }

    /// Writes a change with a local writer; returns its sequence number.
    /// Matched local readers get it at once as [`Event::SampleReceived`].
    pub fn write(
        &mut self,
        writer: Guid,
        change: Change<'_>,
        now: Instant,
    ) -> Result<SequenceNumber, WriteError> {
        self.touch();
        if self.closed {
            return Err(WriteError::Closed);
        }
        if !self.is_local(writer) {
            return Err(WriteError::UnknownWriter);
        }
        if change.data.len() > MAX_WRITE_SIZE {
            return Err(WriteError::TooLarge(change.data.len()));
        }
        let wall = self.wall(now);
        let ts = change.source_timestamp.unwrap_or(wall);
        let max = self.cfg.max_history;
        let lw = self
            .writers
            .get_mut(&writer.entity)
            .ok_or(WriteError::UnknownWriter)?;
        let env = envelope_with(
            change.kind,
            change.key_hash,
            Some(ts),
            change.related_sample_identity,
            change.data,
        );
        let key = change.key_hash.unwrap_or_default().0;
        if let Some(depth) = lw.keep_last {
            // per-instance keep-last: the oldest sample of this instance goes
            if let Some(q) = lw.instances.get_mut(&key) {
                while q.len() >= depth {
                    if let Some(old) = q.pop_front() {
                        lw.writer.remove(SequenceNumber(old));
                    }
                }
            }
        }
        let sn = lw
            .writer
            .write(env.clone(), now)
            .ok_or(WriteError::HistoryFull(max))?;
        if let Some(lifespan) = lw.lifespan {
            // from the source timestamp: an older one given with the
            // change expires sooner
            let since = |t: Time| t.since_epoch().unwrap_or_default();
            let age = since(wall).saturating_sub(since(ts));
            lw.expiries
                .insert((now + lifespan.saturating_sub(age), sn.0));
            if lw.expiries.len() > max {
                // forget what left the history by other ways (acknowledged,
                // replaced by a newer sample of its instance)
                let w = &lw.writer;
                lw.expiries
                    .retain(|(_, s)| w.get(SequenceNumber(*s)).is_some());
            }
        }
        // a transient-local keyed writer knows its instances' samples too,
        // to forget an unregistered one's
        let unregistered = change.kind.status_info().unregistered;
        if lw.keep_last.is_some() || (lw.durable && change.key_hash.is_some()) {
            let q = lw.instances.entry(key).or_default();
            while q
                .front()
                .is_some_and(|s| lw.writer.get(SequenceNumber(*s)).is_none())
            {
                q.pop_front(); // left the history (keep-all: oldest first)
            }
            q.push_back(sn.0);
            if lw.durable && unregistered {
                // late joiners are not to get an instance its writer
                // unregistered (as Cyclone DDS and Fast DDS keep it): its
                // samples, the unregister too, leave the history once
                // every reader has them
                if let Some(q) = lw.instances.remove(&key) {
                    lw.writer.drop_once_acked(q.into_iter().map(SequenceNumber));
                }
            }
            if lw.instances.len() > max {
                // forget instances whose samples all left the history
                let (inst, w) = (&mut lw.instances, &lw.writer);
                inst.retain(|_, q| {
                    q.retain(|s| w.get(SequenceNumber(*s)).is_some());
                    !q.is_empty()
                });
            }
        }
        let local: Vec<EntityId> = lw.local_readers.iter().copied().collect();
        for r in local {
            let s = ReceivedSample::new(self.guid(r), writer, sn, env.clone());
            self.events.push_back(Event::SampleReceived(s));
        }
        // sent by the next poll_transmit, packed with whatever else is
        // written before it
        Ok(sn)
    }

    /// Hands back the buffer of a received sample ([`ReceivedSample::into_data`])
    /// once the application is done with it: the next large sample received
    /// is stored in it instead of a fresh allocation. Up to
    /// [`Config::spare_buffer_bytes`](super::Config::spare_buffer_bytes) are kept; the rest is dropped.
    pub fn recycle(&mut self, buf: Vec<u8>) {
        self.reassembler.recycle(buf);
    }

    /// Bytes of buffers held for reuse ([`Participant::recycle`]).
    pub fn spare_bytes(&self) -> usize {
        self.reassembler.spare_bytes()
    }

    /// True when [`Participant::write`] of `len` bytes to this local writer
    /// would not fail with [`WriteError::HistoryFull`]: a caller handing
    /// over owned data can keep it instead when it would.
    pub fn has_room(&mut self, writer: Guid, len: usize) -> bool {
        if !self.is_local(writer) {
            return true; // write answers UnknownWriter
        }
        self.writers
            .get_mut(&writer.entity)
            .is_none_or(|lw| lw.writer.has_room(len + ENVELOPE_ROOM))
    }

    /// Makes the next [`Participant::write`] of a reliable local writer ask
    /// its readers to acknowledge at once (writes normally ask only every
    /// few samples); for confirmed writes.
    pub fn request_ack(&mut self, writer: Guid) {
        self.touch();
        if !self.is_local(writer) {
            return;
        }
        if let Some(w) = self.writers.get_mut(&writer.entity) {
            w.writer.request_ack_with_next_write();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rtps::participant::{guid_prefix, Config};
    use std::time::SystemTime;

    /// Entity keys are 24 bits. A participant that creates and deletes
    /// endpoints for a long time (a session opening and closing
    /// subscriptions, an XRCE agent whose clients come and go) goes on
    /// past the 2^24 - 1st: keys start again from 1, skipping those in
    /// use. It refused every endpoint for ever once the counter got there
    /// (at 1000 endpoints a second, after 4.7 hours).
    #[test]
    fn entity_keys_are_used_again_once_all_were_given_out() {
        let now = Instant::now();
        let cfg = Config::udpv4(0, 0, guid_prefix([3; 10]), [127, 0, 0, 1]).unwrap();
        let mut p = Participant::new(cfg, now, SystemTime::UNIX_EPOCH);
        let kept = p
            .create_writer(EndpointConfig::writer("kept", "T"), now)
            .unwrap();
        assert_eq!(
            kept.entity,
            entity_id(1, EndpointKind::Writer, false).unwrap()
        );
        // as if 2^24 - 4 more had been created and deleted since
        p.next_key = 0x00ff_fffd;
        let mut made = Vec::new();
        for i in 0..6 {
            let cfg = EndpointConfig::writer(&format!("t{i}"), "T");
            let w = p.create_writer(cfg, now).expect("a key is free");
            made.push(w.entity);
            assert!(p.delete_writer(w, now));
        }
        let key = |e: EntityId| u32::from_be_bytes([0, e.0[0], e.0[1], e.0[2]]);
        let keys: Vec<u32> = made.into_iter().map(key).collect();
        assert_eq!(
            keys,
            [0x00ff_fffd, 0x00ff_fffe, 0x00ff_ffff, 2, 3, 4],
            "from 1 again, past the one in use"
        );
        assert!(p.writers.contains_key(&kept.entity));
    }
}
