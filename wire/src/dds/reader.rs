//! Readers and the reader-side QoS the participant leaves to the domain:
//! exclusive ownership, lifespan, time-based filter and deadlines; and the
//! keep-all back-pressure the shell reports.

use foldhash::{HashMap, HashMapExt, HashSet, HashSetExt};
use smallvec::SmallVec;
use std::time::{Duration, Instant, SystemTime};

use crate::cdr::Version;
use crate::rtps::discovery::{Duration as RtpsDuration, EndpointQos, History};
use crate::rtps::participant::{ChangeKind, CreateError, EndpointConfig, KeyHash, ReceivedSample};
use crate::rtps::{Guid, SequenceNumber, Time};

use super::deadline::Deadline;
use super::instances::{InstanceKeys, Instances};
use super::{Domain, DropReason, Endpoint, Event, ReaderId, Role};

/// What the reader-side filters know of a writer (remote or local).
#[derive(Debug, Clone, Copy)]
pub(super) struct WriterInfo {
    pub(super) strength: i32,
    pub(super) lifespan: Option<Duration>,
    /// The XCDR version of its data: the first representation it
    /// announced (XCDR1 when none); `None` for another (XML).
    pub(super) version: Option<Version>,
    /// The liveliness it offers.
    pub(super) liveliness: (crate::rtps::discovery::LivelinessKind, RtpsDuration),
    /// Its readers dispose its instances when it is deleted
    /// ([`EndpointData::disposes_when_deleted`](crate::rtps::discovery::EndpointData::disposes_when_deleted)).
    pub(super) disposes_when_deleted: bool,
}

impl WriterInfo {
    /// A remote writer's, from its discovery data.
    pub(super) fn of_remote(d: &crate::rtps::discovery::EndpointData) -> Self {
        WriterInfo {
            disposes_when_deleted: d.disposes_when_deleted,
            ..Self::of(&d.qos)
        }
    }

    pub(super) fn of(q: &EndpointQos) -> Self {
        WriterInfo {
            disposes_when_deleted: false,
            liveliness: q.liveliness,
            strength: q.ownership_strength,
            lifespan: q.lifespan.to_std(),
            version: match q.data_representation.first() {
                None | Some(0) => Some(Version::Xcdr1),
                Some(2) => Some(Version::Xcdr2),
                Some(_) => None,
            },
        }
    }
}

pub(super) struct LocalReader {
    pub(super) role: Role,
    pub(super) topic: String,
    pub(super) type_name: String,
    keep_all: bool,
    exclusive: bool,
    minimum_separation: Option<Duration>,
    deadline: Option<Deadline>,
    /// Per instance: owner (exclusive ownership) and its strength.
    owners: HashMap<[u8; 16], (Guid, i32)>,
    /// Per instance: when the last sample was delivered.
    last: HashMap<[u8; 16], Instant>,
    /// The instances disposed since their last sample and not unregistered:
    /// a dispose or unregister of one of them changes nothing (DDS signals
    /// changes of instance state) and is not delivered.
    disposed: HashSet<[u8; 16]>,
    /// How instances are named: by the key hash as sent, or computed
    /// from the payload, in one XCDR version whichever version each
    /// writer writes ([`Domain::set_instance_keys`]).
    instances: Instances,
    /// Keyed readers: per instance, the live writers that wrote (or
    /// disposed) it and have not unregistered it, and its key hash. An
    /// instance none of them is left for — they unregistered it, or were
    /// deleted or lost, or their liveliness lapsed — is NOT_ALIVE_NO_WRITERS
    /// (DDS 1.4 §2.2.2.5.1; said with an [`ChangeKind::Unregistered`]
    /// change unless it is disposed) and forgotten (its deadline, owner,
    /// last sample time and disposed mark), as DDS readers drop an
    /// instance with no writers and no samples: a later sample makes it
    /// alive again. Kept, a reader of a topic whose writers come and go
    /// with keys of their own held every key ever seen, and its deadline
    /// fired for every one of them every period, for ever. `None` for a
    /// topic without key (one instance).
    writers: Option<HashMap<[u8; 16], Instance>>,
    /// A change this reader took, without its data: what the changes it
    /// makes itself (an instance left without writers) are made from.
    template: Option<ReceivedSample>,
}

/// One instance of a keyed reader (see [`LocalReader::writers`]).
#[derive(Default)]
struct Instance {
    /// Its live writers that have not unregistered it.
    writers: SmallVec<[Guid; 1]>,
    /// Its key hash, as the last change taken of it carried it.
    key: Option<KeyHash>,
}

/// An RTPS `Time_t` as a `SystemTime`.
fn system_time(t: Time) -> Option<SystemTime> {
    t.to_system_time()
}

impl LocalReader {
    fn new(cfg: &EndpointConfig, role: Role, now: Instant) -> Self {
        let q = &cfg.qos;
        let mut deadline = Deadline::new(q.deadline.to_std());
        if let Some(d) = deadline.as_mut().filter(|_| !cfg.keyed) {
            // a topic without key has its one instance from the start
            d.arm([0; 16], now);
        }
        LocalReader {
            role,
            topic: cfg.topic_name.clone(),
            type_name: cfg.type_name.clone(),
            keep_all: q.history == History::KeepAll,
            exclusive: q.exclusive_ownership,
            minimum_separation: q.time_based_filter.to_std().filter(|d| !d.is_zero()),
            deadline,
            owners: HashMap::new(),
            last: HashMap::new(),
            disposed: HashSet::new(),
            instances: Instances::new(),
            writers: cfg.keyed.then(HashMap::new),
            template: None,
        }
    }

    /// `writer` wrote (or disposed) `instance`, a change with key hash `key`.
    fn register(&mut self, instance: [u8; 16], writer: Guid, key: Option<KeyHash>) {
        if let Some(ws) = self.writers.as_mut() {
            let i = ws.entry(instance).or_default();
            if !i.writers.contains(&writer) {
                i.writers.push(writer);
            }
            if key.is_some() {
                i.key = key;
            }
        }
    }

    /// Whether `writer` has `instance` registered (keyed readers).
    fn registered(&self, instance: &[u8; 16], writer: Guid) -> bool {
        self.writers
            .as_ref()
            .and_then(|ws| ws.get(instance))
            .is_some_and(|i| i.writers.contains(&writer))
    }

    /// Whether any writer has `instance` registered (keyed readers).
    fn has_writers(&self, instance: &[u8; 16]) -> bool {
        self.writers
            .as_ref()
            .and_then(|ws| ws.get(instance))
            .is_some_and(|i| !i.writers.is_empty())
    }

    /// `writer` unregistered `instance` (keyed readers).
    fn unregister(&mut self, instance: [u8; 16], writer: Guid) {
        if let Some(i) = self.writers.as_mut().and_then(|ws| ws.get_mut(&instance)) {
            i.writers.retain(|g| *g != writer);
        }
    }

    /// Whether `writer` of `strength` may change `instance` under exclusive
    /// ownership: it owns it, no writer does, or it is stronger than the
    /// owner (ties: the lower GUID).
    fn may_own(&self, instance: &[u8; 16], writer: Guid, strength: i32) -> bool {
        match self.owners.get(instance) {
            Some(&(owner, os)) => {
                owner == writer || !(os > strength || (os == strength && owner < writer))
            }
            None => true,
        }
    }

    /// Forgets everything of `instance` (keyed readers).
    fn forget(&mut self, instance: &[u8; 16]) {
        if let Some(ws) = self.writers.as_mut() {
            ws.remove(instance);
        }
        if let Some(d) = self.deadline.as_mut() {
            d.forget(instance);
        }
        self.owners.remove(instance);
        self.last.remove(instance);
        self.disposed.remove(instance);
        self.instances.forget(instance);
    }

    /// The instance `s` is of, as this reader names it (see
    /// [`Instances::identify`]).
    fn identify(&mut self, s: &mut ReceivedSample, writer: Option<WriterInfo>) -> [u8; 16] {
        let empty = self.writers.as_ref().is_some_and(|w| w.is_empty());
        self.instances
            .identify(s, writer.and_then(|w| w.version), empty)
    }

    /// Instances the reader keeps anything for (tests).
    #[cfg(test)]
    fn instances(&self) -> usize {
        let mut all: HashSet<[u8; 16]> = HashSet::new();
        all.extend(self.owners.keys());
        all.extend(self.last.keys());
        all.extend(self.disposed.iter());
        if let Some(d) = &self.deadline {
            all.extend(d.instances());
        }
        if let Some(ws) = &self.writers {
            all.extend(ws.keys());
        }
        all.len()
    }

    /// The filters, in DDS's order: lifespan, ownership, time-based filter;
    /// then the deadline is moved. `instance`: what [`LocalReader::identify`]
    /// named. `Err(None)`: dropped silently (another writer owns the
    /// instance).
    pub(super) fn admit(
        &mut self,
        s: &mut ReceivedSample,
        instance: [u8; 16],
        writer: Option<WriterInfo>,
        now: Instant,
        wall: SystemTime,
    ) -> Result<(), Option<DropReason>> {
        if s.kind != ChangeKind::Alive {
            return self.instance_change(s, instance, writer);
        }
        self.register(instance, s.writer, s.key_hash);
        if let (Some(life), Some(ts)) = (
            writer.and_then(|i| i.lifespan),
            s.source_timestamp.and_then(system_time),
        ) {
            if wall.duration_since(ts).is_ok_and(|age| age > life) {
                return Err(Some(DropReason::Lifespan));
            }
        }
        if self.exclusive {
            let strength = writer.map_or(0, |i| i.strength);
            if !self.may_own(&instance, s.writer, strength) {
                return Err(None);
            }
            self.owners.insert(instance, (s.writer, strength));
        }
        if let Some(sep) = self.minimum_separation {
            if self
                .last
                .get(&instance)
                .is_some_and(|t| now.saturating_duration_since(*t) < sep)
            {
                return Err(Some(DropReason::MinimumSeparation));
            }
            self.last.insert(instance, now);
        }
        if let Some(d) = self.deadline.as_mut() {
            d.arm(instance, now);
        }
        if !self.disposed.is_empty() {
            self.disposed.remove(&instance);
        }
        Ok(())
    }

    /// A dispose or unregister (`s`, of `instance`), by DDS's rules
    /// (§2.2.2.5.1, §2.2.3.9.2): a dispose counts only from the owner
    /// under exclusive ownership (or a writer strong enough to take the
    /// instance); a disposed instance stays NOT_ALIVE_DISPOSED until a
    /// sample comes, whatever else its writers say (a dispose that also
    /// unregisters, as a deleted writer autodisposes, too); an unregister
    /// says something only from the instance's last writer, as
    /// NOT_ALIVE_NO_WRITERS (`s` becomes [`ChangeKind::Unregistered`] when
    /// only its unregister counts). `Err(None)`: nothing to say.
    fn instance_change(
        &mut self,
        s: &mut ReceivedSample,
        instance: [u8; 16],
        writer: Option<WriterInfo>,
    ) -> Result<(), Option<DropReason>> {
        let disposes = matches!(
            s.kind,
            ChangeKind::Disposed | ChangeKind::DisposedUnregistered
        );
        let unregisters = matches!(
            s.kind,
            ChangeKind::Unregistered | ChangeKind::DisposedUnregistered
        );
        let strength = writer.map_or(0, |i| i.strength);
        let mut said = false;
        if disposes && (!self.exclusive || self.may_own(&instance, s.writer, strength)) {
            if self.exclusive {
                self.owners.insert(instance, (s.writer, strength));
            }
            if let Some(d) = self.deadline.as_mut() {
                d.forget(&instance);
            }
            said = self.disposed.insert(instance);
        }
        if !unregisters {
            self.register(instance, s.writer, s.key_hash);
            return if said { Ok(()) } else { Err(None) };
        }
        if self
            .owners
            .get(&instance)
            .is_some_and(|(o, _)| *o == s.writer)
        {
            self.owners.remove(&instance);
        }
        if self.writers.is_none() {
            // a topic without key: its one instance, writers not counted
            if let Some(d) = self.deadline.as_mut() {
                d.forget(&instance);
            }
            return if said || (!disposes && !self.disposed.contains(&instance)) {
                Ok(())
            } else {
                Err(None)
            };
        }
        let was_registered = self.registered(&instance, s.writer);
        self.unregister(instance, s.writer);
        if self.has_writers(&instance) {
            // another writer still has it: it stays as it is
            return if said { Ok(()) } else { Err(None) };
        }
        // no writer left (or none had it: an instance this reader never
        // saw, or another writer's)
        let disposed = self.disposed.contains(&instance);
        self.forget(&instance);
        if said {
            Ok(())
        } else if was_registered && !disposed {
            s.kind = ChangeKind::Unregistered;
            Ok(())
        } else {
            Err(None)
        }
    }

    /// `writer` left this reader (deleted, lost, or its liveliness
    /// lapsed): it owns nothing any more and has no instance registered;
    /// an instance it was the last writer of is NOT_ALIVE_NO_WRITERS unless
    /// disposed (or, with `dispose`, disposed now), and forgotten. The
    /// changes that say so, one per such instance (no data, no timestamp,
    /// its key hash as its last change carried it, `writer` as their
    /// writer), in the order of their key hashes.
    pub(super) fn writer_gone(&mut self, writer: Guid, dispose: bool) -> Vec<ReceivedSample> {
        self.owners.retain(|_, (w, _)| *w != writer);
        let Some(ws) = self.writers.as_mut() else {
            return Vec::new();
        };
        let mut orphans = Vec::new();
        for (instance, i) in ws.iter_mut() {
            let before = i.writers.len();
            i.writers.retain(|g| *g != writer);
            if i.writers.is_empty() && before > 0 {
                orphans.push((*instance, i.key));
            }
        }
        orphans.sort_unstable_by_key(|(instance, _)| *instance);
        let mut changes = Vec::new();
        for (instance, key) in orphans {
            let disposed = self.disposed.contains(&instance);
            self.forget(&instance);
            if disposed {
                continue;
            }
            if let Some(mut s) = self.template.clone() {
                s.writer = writer;
                s.sequence_number = SequenceNumber::UNKNOWN;
                s.source_timestamp = None;
                s.key_hash = key;
                s.kind = if dispose {
                    ChangeKind::DisposedUnregistered
                } else {
                    ChangeKind::Unregistered
                };
                s.related_sample_identity = None;
                changes.push(s);
            }
        }
        changes
    }

    pub(super) fn next_due(&self) -> Option<Instant> {
        self.deadline.as_ref().and_then(Deadline::next_due)
    }
}

impl Domain {
    /// Creates a reader. Its QoS also sets the domain's filters:
    /// `exclusive_ownership` (each instance only from the strongest live
    /// writer; ties to the lower GUID), `time_based_filter` (minimum
    /// separation per instance), `deadline` ([`Event::DeadlineMissed`]); the
    /// writers' `lifespan` drops samples older than it by source timestamp.
    pub fn create_reader(
        &mut self,
        config: EndpointConfig,
        now: Instant,
    ) -> Result<ReaderId, CreateError> {
        let g = self.add_reader(config, Role::User, now)?;
        self.drain(now);
        Ok(ReaderId(g))
    }

    /// Deletes a reader (not one of a pattern's: see
    /// [`Domain::delete_pattern`]); false if there is no such reader.
    pub fn delete_reader(&mut self, reader: ReaderId, now: Instant) -> bool {
        if !matches!(self.readers.get(&reader.0), Some(r) if r.role == Role::User) {
            return false;
        }
        self.remove_reader(reader.0, now);
        self.drain(now);
        true
    }

    pub(super) fn add_reader(
        &mut self,
        config: EndpointConfig,
        role: Role,
        now: Instant,
    ) -> Result<Guid, CreateError> {
        let r = LocalReader::new(&config, role, now);
        let lease = config.qos.liveliness.1;
        let g = self.p.create_reader(config, now)?;
        self.lively_reader_created(g, lease);
        let remote: Vec<(Guid, String)> = self
            .p
            .publications()
            .filter(|d| d.topic_name == r.topic && d.type_name != r.type_name)
            .map(|d| (d.guid, d.type_name.clone()))
            .collect();
        // this participant's own writers are matched with it locally and
        // never discovered: the same check (an XRCE agent hosts several
        // clients' endpoints in one participant)
        let local: Vec<(Guid, String)> = if matches!(role, Role::Pattern(_)) {
            Vec::new()
        } else {
            self.writers
                .iter()
                .filter(|(_, w)| w.topic == r.topic && w.type_name != r.type_name)
                .map(|(wg, w)| (*wg, w.type_name.clone()))
                .collect()
        };
        let type_name = r.type_name.clone();
        self.readers.insert(g, r);
        for (remote, remote_type) in remote {
            self.type_mismatch(g, remote, remote_type);
        }
        for (writer, writer_type) in local {
            self.type_mismatch(g, writer, writer_type);
            self.type_mismatch(writer, g, type_name.clone());
        }
        Ok(g)
    }

    pub(super) fn remove_reader(&mut self, g: Guid, now: Instant) {
        self.readers.remove(&g);
        self.lively_reader_deleted(g);
        self.full.retain(|r| *r != g);
        self.p.delete_reader(g, now);
    }

    /// The shell's queue for a keep-all reader is full (`true`) or has
    /// room again (`false`). While one is full, [`Domain::paused_reader`]
    /// names it: the shell stops reading user data, and what reliable
    /// writers send meanwhile they repair later (back-pressure reaches
    /// them as unacknowledged history). Ignored for keep-last readers,
    /// whose queues drop the oldest.
    pub fn set_reader_full(&mut self, reader: ReaderId, full: bool) {
        let keep_all = self.readers.get(&reader.0).is_some_and(|r| r.keep_all);
        self.full.retain(|r| *r != reader.0);
        if full && keep_all {
            self.full.push(reader.0);
        }
    }

    /// The lifespan a remote writer offers (DDS LIFESPAN), if finite: a
    /// sample of it expires that long after its source timestamp, also
    /// while it waits unread in the shell's queue.
    pub fn writer_lifespan(&self, writer: Guid) -> Option<Duration> {
        self.writer_info.get(&writer).and_then(|i| i.lifespan)
    }

    /// A keep-all reader whose queue the shell reported full, if any:
    /// while there is one, user data should not be read.
    pub fn paused_reader(&self) -> Option<ReaderId> {
        self.full.first().copied().map(ReaderId)
    }

    /// Tells a keyed reader its type's keys ([`InstanceKeys::of`]), for
    /// its disposes, deadlines, ownership and time-based filter, which go
    /// by instance. False if there is no such reader. Without them:
    ///
    /// - the instance of a sample whose writer sent no key hash (Cyclone
    ///   DDS 11 sends none; it is optional in RTPS) is unknown: every
    ///   such sample counts as one instance. With them it is the hash
    ///   computed from the payload, in the payload's version (what its
    ///   writer would have sent), and the sample is delivered with it;
    /// - writers of different XCDR versions whose hashes of one instance
    ///   differ name it apart (see [`KeyHash`] for which keys): a dispose
    ///   from one does not dispose what the other wrote, and so on. With
    ///   them the reader names each instance in one version, whatever its
    ///   writers send ([`InstanceKeys`] says how, and what it costs:
    ///   nothing while they all write one version).
    ///
    /// Either way the changes delivered ([`Event::Sample`]) carry the key
    /// hash in their writer's version, as it sent it: a key read back
    /// from it must be read in that version
    /// ([`cdr::key_from_key_hash_in`](crate::cdr::key_from_key_hash_in)).
    /// [`Event::DeadlineMissed`] names an instance as the reader does.
    pub fn set_instance_keys(&mut self, reader: ReaderId, keys: InstanceKeys) -> bool {
        match self.readers.get_mut(&reader.0) {
            Some(r) => {
                r.instances.set_keys(keys);
                true
            }
            None => false,
        }
    }

    /// Filters a sample for a user or pattern reader and passes it on.
    /// A dispose that carries its writer's whole sample (Cyclone DDS's
    /// `write_dispose`: the data, not the key, with the dispose flag) is
    /// taken as the sample, then the dispose of its instance.
    pub(super) fn deliver(&mut self, mut s: ReceivedSample, now: Instant) {
        let Some(r) = self.readers.get_mut(&s.reader) else {
            return;
        };
        if r.writers.is_some() && r.template.is_none() {
            r.template = Some(s.without_data());
        }
        if r.instances.carries_sample(&s) {
            let mut dispose = s.without_data();
            s.kind = ChangeKind::Alive;
            let key = self.deliver_one(s, now);
            // the dispose names the instance the sample did
            dispose.key_hash = dispose.key_hash.or(key);
            s = dispose;
        }
        self.deliver_one(s, now);
    }

    /// [`Domain::deliver`] of one change; its key hash, once known.
    fn deliver_one(&mut self, mut s: ReceivedSample, now: Instant) -> Option<KeyHash> {
        let writer = self.writer_info.get(&s.writer).copied();
        let wall = self.wall(now);
        let r = self.readers.get_mut(&s.reader)?;
        let instance = r.identify(&mut s, writer);
        let key = s.key_hash;
        let reader = ReaderId(s.reader);
        match r.admit(&mut s, instance, writer, now, wall) {
            Ok(()) => self.events.push_back(Event::Sample { reader, sample: s }),
            Err(Some(reason)) => self
                .events
                .push_back(Event::SampleDropped { reader, reason }),
            Err(None) => {}
        }
        key
    }

    /// `writer` no longer writes for `reader`: it left (deleted,
    /// unmatched, its participant lost) or its liveliness lapsed. The
    /// instances it was the last live writer of become NOT_ALIVE_NO_WRITERS
    /// ([`Event::Sample`] with a [`ChangeKind::Unregistered`] change of
    /// `writer`, no data, for a user or pattern reader), or NOT_ALIVE_DISPOSED
    /// with `dispose` ([`ChangeKind::DisposedUnregistered`]: a deleted
    /// writer whose vendor leaves its autodispose to the readers, see
    /// [`EndpointData::disposes_when_deleted`](crate::rtps::discovery::EndpointData::disposes_when_deleted)),
    /// and it owns none.
    pub(super) fn writer_left_reader(&mut self, reader: Guid, writer: Guid, dispose: bool) {
        let Some(r) = self.readers.get_mut(&reader) else {
            return;
        };
        let changes = r.writer_gone(writer, dispose);
        if matches!(r.role, Role::User | Role::Pattern(_)) {
            self.events
                .extend(changes.into_iter().map(|sample| Event::Sample {
                    reader: ReaderId(reader),
                    sample,
                }));
        }
    }

    /// One [`Event::DeadlineMissed`] per instance whose deadline passed.
    pub(super) fn check_deadlines(&mut self, now: Instant) {
        for (g, r) in self.readers.iter_mut() {
            let Some(d) = r.deadline.as_mut() else {
                continue;
            };
            for (instance, total) in d.expire(now) {
                // an owner that missed the deadline loses the instance
                // (DDS 2.2.3.9): the next writer's sample takes it
                r.owners.remove(&instance);
                self.events.push_back(Event::DeadlineMissed {
                    reader: ReaderId(*g),
                    instance: KeyHash(instance),
                    total,
                });
            }
        }
    }

    pub(super) fn type_mismatch(&mut self, local: Guid, remote: Guid, remote_type: String) {
        let (topic, local_type, endpoint) = if let Some(r) = self.readers.get(&local) {
            (
                r.topic.clone(),
                r.type_name.clone(),
                self.endpoint(local, r.role, false),
            )
        } else if let Some(w) = self.writers.get(&local) {
            (
                w.topic.clone(),
                w.type_name.clone(),
                self.endpoint(local, w.role, true),
            )
        } else {
            return;
        };
        self.events.push_back(Event::TypeMismatch {
            local: endpoint,
            remote,
            topic,
            local_type,
            remote_type,
        });
    }

    pub(super) fn endpoint(&self, g: Guid, role: Role, writer: bool) -> Endpoint {
        match role {
            Role::Service(s) => Endpoint::Service(s),
            Role::Client(c) => Endpoint::Client(c),
            Role::User | Role::Pattern(_) if writer => Endpoint::Writer(super::WriterId(g)),
            Role::User | Role::Pattern(_) => Endpoint::Reader(ReaderId(g)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rtps::discovery::{Duration as RtpsDuration, Reliability};
    use crate::rtps::participant::{guid_prefix, Change, Config};
    use std::time::SystemTime;

    fn qos(reader: bool) -> EndpointQos {
        let mut q = if reader {
            EndpointQos::reader_default()
        } else {
            EndpointQos::writer_default()
        };
        q.reliability = Reliability::Reliable(RtpsDuration::ZERO);
        q.deadline = RtpsDuration::from_std(Duration::from_secs(1));
        q.exclusive_ownership = true;
        if reader {
            q.time_based_filter = RtpsDuration::from_std(Duration::from_millis(10));
        }
        q
    }

    fn domain(now: Instant) -> Domain {
        let cfg = Config::udpv4(0, 0, guid_prefix([7; 10]), [127, 0, 0, 1]).unwrap();
        Domain::new(cfg, now, SystemTime::UNIX_EPOCH)
    }

    /// A reader (`true`) or a writer of keyed topic `K`.
    fn keyed(reader: bool) -> EndpointConfig {
        let c = if reader {
            EndpointConfig::reader("K", "T")
        } else {
            EndpointConfig::writer("K", "T")
        };
        c.keyed(true)
    }

    fn key(n: u32) -> KeyHash {
        let mut k = [0; 16];
        k[..4].copy_from_slice(&n.to_be_bytes());
        KeyHash(k)
    }

    /// A keyed reader keeps per-instance state (deadline, owner, last
    /// sample time, disposed mark) only for instances some writer still
    /// has: writers that come and go, each with instances of its own, and
    /// leave (deleted, after disposing some and unregistering others)
    /// leave nothing behind but the instance a remaining writer holds.
    #[test]
    fn a_keyed_reader_forgets_the_instances_its_writers_took_with_them() {
        let mut now = Instant::now();
        let mut d = domain(now);
        let cfg = |r| keyed(r).qos(qos(r));
        let r = d.create_reader(cfg(true), now).unwrap();
        let stays = d.create_writer(cfg(false), now).unwrap();
        let data = vec![0, 1, 0, 0, 1, 0, 0, 0];
        d.write(
            stays,
            Change::alive_owned(data.clone()).with_key_hash(key(0)),
            now,
        )
        .unwrap();
        for round in 0..50u32 {
            let w = d.create_writer(cfg(false), now).unwrap();
            for i in 0..4 {
                let k = key(1 + round * 4 + i);
                d.write(w, Change::alive_owned(data.clone()).with_key_hash(k), now)
                    .unwrap();
            }
            let k = key(1 + round * 4);
            d.write(w, Change::dispose(&data[..4], k), now).unwrap();
            let k = key(2 + round * 4);
            d.write(w, Change::unregister(&data[..4], k), now).unwrap();
            now += Duration::from_millis(20);
            assert!(d.delete_writer(w, now));
        }
        while d.poll_event().is_some() {}
        let reader = &d.readers[&r.0];
        assert_eq!(reader.instances(), 1, "only the remaining writer's");
        // and no deadline fires for the ones gone: one instance, one miss
        now += Duration::from_millis(1500);
        d.handle_timeout(now);
        let missed: Vec<KeyHash> = std::iter::from_fn(|| d.poll_event())
            .filter_map(|e| match e {
                Event::DeadlineMissed { instance, .. } => Some(instance),
                _ => None,
            })
            .collect();
        assert_eq!(missed, [key(0)]);
    }

    /// Two writers of one instance: once one disposed it — with a plain
    /// dispose, or unregistering it too as a deleted writer does — neither
    /// the other's dispose nor an unregister and a dispose again say
    /// anything new, until a sample makes it alive.
    #[test]
    fn a_disposed_instance_is_reported_once_whoever_disposes_it_again() {
        let now = Instant::now();
        let mut d = domain(now);
        let cfg = keyed;
        let r = d.create_reader(cfg(true), now).unwrap();
        let w1 = d.create_writer(cfg(false), now).unwrap();
        let w2 = d.create_writer(cfg(false), now).unwrap();
        let w3 = d.create_writer(cfg(false), now).unwrap();
        let data = vec![0, 1, 0, 0, 1, 0, 0, 0];
        let k = key(1);
        let kinds = |d: &mut Domain| -> Vec<ChangeKind> {
            std::iter::from_fn(|| d.poll_event())
                .filter_map(|e| match e {
                    Event::Sample { reader, sample } if reader == r => Some(sample.kind),
                    _ => None,
                })
                .collect()
        };
        for w in [w1, w2, w3] {
            d.write(w, Change::alive_owned(data.clone()).with_key_hash(k), now)
                .unwrap();
        }
        assert_eq!(kinds(&mut d).len(), 3);
        let gone = Change {
            kind: ChangeKind::DisposedUnregistered,
            ..Change::dispose(&data[..4], k)
        };
        d.write(w1, gone, now).unwrap();
        d.write(w2, Change::dispose(&data[..4], k), now).unwrap();
        d.write(w2, Change::unregister(&data[..4], k), now).unwrap();
        d.write(w3, Change::dispose(&data[..4], k), now).unwrap();
        assert_eq!(kinds(&mut d), [ChangeKind::DisposedUnregistered]);
        d.write(w3, Change::alive_owned(data.clone()).with_key_hash(k), now)
            .unwrap();
        d.write(w3, Change::dispose(&data[..4], k), now).unwrap();
        assert_eq!(kinds(&mut d), [ChangeKind::Alive, ChangeKind::Disposed]);
    }
}
