//! Writers: the payload padding rule, keep-all back-pressure
//! ([`Event::Writable`]) and confirmed writes ([`Event::WriteConfirmed`]).

use std::borrow::Cow;
use std::time::{Duration, Instant};

use crate::rtps::participant::{
    Change, ChangeKind, CreateError, EndpointConfig, KeyHash, WriteError,
};
use crate::rtps::{Guid, SequenceNumber};

use super::deadline::Deadline;
use super::pattern::Offer;
use super::reader::WriterInfo;
use super::{ConfirmFailure, Domain, Event, Role, WriterId};

pub(super) struct LocalWriter {
    pub(super) role: Role,
    pub(super) topic: String,
    pub(super) type_name: String,
    pub(super) offer: Offer,
    /// A write of this many bytes found the history full: tell the shell
    /// ([`Event::Writable`]) once it fits.
    blocked: Option<usize>,
    /// The deadline it offers: a sample per live instance within the
    /// period, or [`Event::OfferedDeadlineMissed`].
    deadline: Option<Deadline>,
}

pub(super) struct Confirm {
    writer: Guid,
    sn: SequenceNumber,
    deadline: Instant,
    after: Duration,
}

/// The serialized payload goes out padded with zeros to a multiple of 4,
/// as Cyclone DDS and Fast DDS send theirs; Cyclone 0.10 drops user DATA
/// whose payload is not. Owned data is padded in place (a CDR writer's
/// buffer has room for it).
pub fn pad(change: Change<'_>) -> Change<'_> {
    let len = change.data.len();
    if len % 4 == 0 {
        return change;
    }
    let mut change = change;
    let mut data = std::mem::take(&mut change.data).into_owned();
    data.resize(len.next_multiple_of(4), 0);
    change.data = Cow::Owned(data);
    change
}

impl Domain {
    /// Creates a writer. Its QoS's `ownership_strength` (with
    /// `exclusive_ownership`) and `lifespan` are what local readers'
    /// filters use too.
    pub fn create_writer(
        &mut self,
        config: EndpointConfig,
        now: Instant,
    ) -> Result<WriterId, CreateError> {
        let g = self.add_writer(config, Role::User, now)?;
        self.drain(now);
        Ok(WriterId(g))
    }

    /// Deletes a writer: its readers unmatch it (and exclusive readers
    /// take the instances it owned from the next strongest writer); its
    /// unconfirmed writes fail ([`ConfirmFailure::WriterDeleted`]). False if
    /// there is no such writer.
    pub fn delete_writer(&mut self, writer: WriterId, now: Instant) -> bool {
        if !matches!(self.writers.get(&writer.0), Some(w) if w.role == Role::User) {
            return false;
        }
        self.remove_writer(writer.0, now);
        self.drain(now);
        true
    }

    pub(super) fn add_writer(
        &mut self,
        config: EndpointConfig,
        role: Role,
        now: Instant,
    ) -> Result<Guid, CreateError> {
        let info = WriterInfo::of(&config.qos);
        let w = LocalWriter {
            role,
            topic: config.topic_name.clone(),
            type_name: config.type_name.clone(),
            offer: Offer {
                keyed: config.keyed,
                exclusive: config.qos.exclusive_ownership,
                partitions: config.qos.partitions.clone(),
                grade: super::pattern::Grade::of(&config.qos),
            },
            blocked: None,
            deadline: Deadline::new(config.qos.deadline.to_std()),
        };
        let liveliness = config.qos.liveliness;
        let g = self.p.create_writer(config, now)?;
        self.lively_writer_created(g, liveliness, now);
        let remote: Vec<(Guid, String)> = self
            .p
            .subscriptions()
            .filter(|d| d.topic_name == w.topic && d.type_name != w.type_name)
            .map(|d| (d.guid, d.type_name.clone()))
            .collect();
        // this participant's own readers (see `add_reader`); a pattern's
        // readers take every type
        let local: Vec<(Guid, String)> = self
            .readers
            .iter()
            .filter(|(_, r)| {
                r.topic == w.topic
                    && r.type_name != w.type_name
                    && !matches!(r.role, Role::Pattern(_))
            })
            .map(|(rg, r)| (*rg, r.type_name.clone()))
            .collect();
        let (topic, type_name, offer) = (w.topic.clone(), w.type_name.clone(), w.offer.clone());
        self.writer_info.insert(g, info);
        self.writers.insert(g, w);
        for (remote, remote_type) in remote {
            self.type_mismatch(g, remote, remote_type);
        }
        for (reader, reader_type) in local {
            self.type_mismatch(g, reader, reader_type);
            self.type_mismatch(reader, g, type_name.clone());
        }
        self.offer_to_patterns(&topic, &type_name, &offer, g, now);
        Ok(g)
    }

    pub(super) fn remove_writer(&mut self, g: Guid, now: Instant) {
        self.writers.remove(&g);
        self.lively_writer_deleted(g);
        self.writer_info.remove(&g);
        let mut i = 0;
        while i < self.confirms.len() {
            if self.confirms[i].writer == g {
                let c = self.confirms.swap_remove(i);
                self.events.push_back(Event::ConfirmFailed {
                    writer: WriterId(g),
                    sequence_number: c.sn,
                    reason: ConfirmFailure::WriterDeleted,
                });
            } else {
                i += 1;
            }
        }
        self.p.delete_writer(g, now);
        self.withdraw_from_patterns(g, now);
    }

    /// Whether a write of `len` bytes fits the writer's history now. When
    /// it does not (a keep-all history full of unacknowledged samples),
    /// [`Event::Writable`] follows once it does: a shell that keeps the
    /// data meanwhile writes it then.
    pub fn has_room(&mut self, writer: WriterId, len: usize) -> bool {
        let len = len.next_multiple_of(4);
        if self.p.has_room(writer.0, len) {
            return true;
        }
        if let Some(w) = self.writers.get_mut(&writer.0) {
            w.blocked = Some(w.blocked.map_or(len, |b| b.min(len)));
        }
        false
    }

    /// Writes a change, padded to a multiple of 4 bytes ([`pad`]).
    /// [`WriteError::HistoryFull`] is followed by [`Event::Writable`] when
    /// the history has room again.
    pub fn write(
        &mut self,
        writer: WriterId,
        change: Change<'_>,
        now: Instant,
    ) -> Result<SequenceNumber, WriteError> {
        let r = self.write_guid(writer.0, change, None, now);
        self.drain(now);
        r
    }

    /// [`Domain::write`], confirmed: [`Event::WriteConfirmed`] once every
    /// matched reliable reader has acknowledged it (at once when there is
    /// none), or [`Event::ConfirmFailed`] after `timeout`.
    pub fn write_confirmed(
        &mut self,
        writer: WriterId,
        change: Change<'_>,
        timeout: Duration,
        now: Instant,
    ) -> Result<SequenceNumber, WriteError> {
        let r = self.write_guid(writer.0, change, Some(timeout), now);
        self.drain(now);
        r
    }

    pub(super) fn write_guid(
        &mut self,
        g: Guid,
        change: Change<'_>,
        confirm: Option<Duration>,
        now: Instant,
    ) -> Result<SequenceNumber, WriteError> {
        if !self.writers.contains_key(&g) {
            return Err(WriteError::UnknownWriter);
        }
        let change = pad(change);
        let (len, kind, key_hash) = (change.data.len(), change.kind, change.key_hash);
        if confirm.is_some() {
            self.p.request_ack(g);
        }
        let sn = match self.p.write(g, change, now) {
            Ok(sn) => sn,
            Err(e) => {
                if matches!(e, WriteError::HistoryFull(_)) {
                    if let Some(w) = self.writers.get_mut(&g) {
                        w.blocked = Some(w.blocked.map_or(len, |b| b.min(len)));
                    }
                }
                return Err(e);
            }
        };
        self.lively_written(g, now);
        // a local reader that saw this writer lapse sees it alive again
        self.check_liveliness(now);
        if let Some(d) = self.writers.get_mut(&g).and_then(|w| w.deadline.as_mut()) {
            let instance = key_hash.map_or([0; 16], |k| k.0);
            match kind {
                ChangeKind::Alive => d.arm(instance, now),
                _ => d.forget(&instance),
            }
        }
        if let Some(after) = confirm {
            if self.p.is_acked_by_all(g, sn) {
                self.events.push_back(Event::WriteConfirmed {
                    writer: WriterId(g),
                    sequence_number: sn,
                });
            } else {
                self.confirms.push(Confirm {
                    writer: g,
                    sn,
                    deadline: crate::time::later(now, after),
                    after,
                });
            }
        }
        Ok(sn)
    }

    /// Confirmations and blocked writes a change of acknowledgements (or a
    /// reader leaving) settles.
    pub(super) fn acks_changed(&mut self, writer: Guid) {
        let mut i = 0;
        while i < self.confirms.len() {
            let c = &self.confirms[i];
            if c.writer == writer && self.p.is_acked_by_all(writer, c.sn) {
                let c = self.confirms.swap_remove(i);
                self.events.push_back(Event::WriteConfirmed {
                    writer: WriterId(writer),
                    sequence_number: c.sn,
                });
            } else {
                i += 1;
            }
        }
        self.check_writable(writer);
    }

    pub(super) fn check_writable(&mut self, writer: Guid) {
        let Some(len) = self.writers.get(&writer).and_then(|w| w.blocked) else {
            return;
        };
        if self.p.has_room(writer, len) {
            if let Some(w) = self.writers.get_mut(&writer) {
                w.blocked = None;
            }
            self.events.push_back(Event::Writable {
                writer: WriterId(writer),
            });
        }
    }

    pub(super) fn any_blocked(&self) -> bool {
        self.writers.values().any(|w| w.blocked.is_some())
    }

    pub(super) fn next_confirm_deadline(&self) -> Option<Instant> {
        self.confirms.iter().map(|c| c.deadline).min()
    }

    pub(super) fn expire_confirms(&mut self, now: Instant) {
        let mut i = 0;
        while i < self.confirms.len() {
            if self.confirms[i].deadline <= now {
                let c = self.confirms.swap_remove(i);
                self.events.push_back(Event::ConfirmFailed {
                    writer: WriterId(c.writer),
                    sequence_number: c.sn,
                    reason: ConfirmFailure::Timeout(c.after),
                });
            } else {
                i += 1;
            }
        }
    }

    pub(super) fn next_offered_deadline(&self) -> Option<Instant> {
        let due = self.writers.values().filter_map(|w| w.deadline.as_ref());
        due.filter_map(Deadline::next_due).min()
    }

    /// One [`Event::OfferedDeadlineMissed`] per instance a writer did not
    /// write within the deadline it offers.
    pub(super) fn check_offered_deadlines(&mut self, now: Instant) {
        for (g, w) in self.writers.iter_mut() {
            let Some(d) = w.deadline.as_mut() else {
                continue;
            };
            for (instance, total) in d.expire(now) {
                self.events.push_back(Event::OfferedDeadlineMissed {
                    writer: WriterId(*g),
                    instance: KeyHash(instance),
                    total,
                });
            }
        }
    }

    /// How many readers (remote and local) a writer is matched with.
    pub fn matched_readers(&self, writer: WriterId) -> usize {
        self.p.matched_readers(writer.0).len()
    }
}
