//! LIVELINESS, both sides (DDS 1.4 §2.2.3.11).
//!
//! A reader that requests a finite lease tracks each matched writer that
//! offers one: the writer is alive from the match, and stays alive while
//! its liveliness is asserted within its lease, as the writer's kind says
//! ([`Participant::liveliness_asserted`](crate::rtps::participant::Participant::liveliness_asserted);
//! a writer of this domain asserts by its writes and
//! [`Domain::assert_liveliness`]). When a lease lapses the reader gets
//! [`Event::LivelinessChanged`] with `alive: false`; the next assertion
//! makes the writer alive again (another event). A writer that is not
//! alive owns no instance under exclusive ownership and writes none: the
//! instances it was the last live writer of are NOT_ALIVE_NO_WRITERS
//! until it (or another) writes them again ([`Event::Sample`] with an
//! unregister, after the [`Event::LivelinessChanged`]). A writer that
//! unmatches (deleted, or its participant lost) leaves the counts, with an
//! event. Counts are DDS's LIVELINESS_CHANGED `alive_count` and
//! `not_alive_count`.
//!
//! A writer of this domain with a MANUAL kind and a finite lease that
//! asserted nothing within it gets [`Event::LivelinessLost`] (DDS's
//! LIVELINESS_LOST), once per lapse.

use std::time::{Duration, Instant};

use foldhash::HashMap;

use super::{Domain, Event, ReaderId, WriterId};
use crate::rtps::discovery::{Duration as RtpsDuration, LivelinessKind};
use crate::rtps::participant::Participant;
use crate::rtps::Guid;

/// A finite, non-zero lease.
pub(super) fn lease_of(d: RtpsDuration) -> Option<Duration> {
    d.to_std().filter(|d| !d.is_zero())
}

/// One matched writer, as a reader sees it.
struct Tracked {
    kind: LivelinessKind,
    lease: Duration,
    alive: bool,
    /// The match, or the last lapse: assertions must come after it.
    since: Instant,
}

#[derive(Default)]
struct ReaderState {
    writers: HashMap<Guid, Tracked>,
    alive: u32,
    not_alive: u32,
}

/// A local writer with a manual kind and a finite lease.
struct Offered {
    kind: LivelinessKind,
    lease: Duration,
    last: Instant,
    lost: bool,
    total: u64,
}

/// The domain's liveliness bookkeeping.
#[derive(Default)]
pub(super) struct Liveliness {
    readers: HashMap<Guid, ReaderState>,
    offered: HashMap<Guid, Offered>,
    /// This domain's writers: the last write or assertion of each, and of
    /// any (what asserts a manual-by-participant writer).
    local_topic: HashMap<Guid, Instant>,
    local_participant: Option<Instant>,
}

impl Liveliness {
    /// The latest assertion that counts for `t` (after its match or
    /// lapse): by the participant's records for a remote writer, by its own
    /// writes for one of this domain. `None`: it never lapses (an
    /// AUTOMATIC writer of this domain, alive while the domain is).
    fn last(&self, p: &Participant, w: Guid, t: &Tracked) -> Option<Instant> {
        let asserted = if w.prefix != p.guid_prefix() {
            p.liveliness_asserted(w, t.kind)
        } else {
            match t.kind {
                LivelinessKind::Automatic => return None,
                LivelinessKind::ManualByParticipant => self.local_participant,
                LivelinessKind::ManualByTopic => self.local_topic.get(&w).copied(),
            }
        };
        Some(asserted.map_or(t.since, |a| a.max(t.since)))
    }
}

impl Domain {
    /// Asserts the liveliness of `writer` without writing (DDS's
    /// `DataWriter::assert_liveliness`): a MANUAL_BY_TOPIC writer sends a
    /// HEARTBEAT with the liveliness flag; a MANUAL_BY_PARTICIPANT one also
    /// asserts every such writer of this domain (a participant message of
    /// the manual kind). Writes assert too. False for an unknown writer.
    pub fn assert_liveliness(&mut self, writer: WriterId, now: Instant) -> bool {
        if !self.writers.contains_key(&writer.0) {
            return false;
        }
        self.p.assert_writer_liveliness(writer.0, now);
        self.lively_written(writer.0, now);
        self.drain(now);
        self.check_liveliness(now);
        true
    }

    /// Asserts the liveliness of every MANUAL_BY_PARTICIPANT writer of
    /// this domain without writing (DDS's
    /// `DomainParticipant::assert_liveliness`): one participant message of
    /// the manual kind to every matched participant. MANUAL_BY_TOPIC
    /// writers are not asserted by it (each asserts by its own writes or
    /// [`Domain::assert_liveliness`]).
    pub fn assert_participant_liveliness(&mut self, now: Instant) {
        self.p.assert_liveliness(now);
        self.lively_asserted(None, now);
        self.drain(now);
        self.check_liveliness(now);
    }

    /// A local writer wrote or asserted at `now`.
    pub(super) fn lively_written(&mut self, writer: Guid, now: Instant) {
        self.lively_asserted(Some(writer), now);
    }

    /// `writer` (a local writer) wrote or asserted at `now`, or, without
    /// one, the participant asserted itself: its manual-by-participant
    /// writers are asserted either way (DDS 1.4 §2.2.3.11; Cyclone renews
    /// their lease on data of any writer of the participant), and the
    /// writer itself.
    fn lively_asserted(&mut self, writer: Option<Guid>, now: Instant) {
        let l = &mut self.liveliness;
        // only manual writers with a finite lease are asked about their
        // writes (`last`); a domain without any pays nothing per write
        if l.offered.is_empty() {
            return;
        }
        if let Some(w) = writer.filter(|w| l.offered.contains_key(w)) {
            l.local_topic.insert(w, now);
        }
        l.local_participant = Some(now);
        for (g, o) in l.offered.iter_mut() {
            if Some(*g) == writer || o.kind == LivelinessKind::ManualByParticipant {
                o.last = now;
                o.lost = false;
            }
        }
    }

    /// A local writer was created with `kind` and `lease`.
    pub(super) fn lively_writer_created(
        &mut self,
        writer: Guid,
        liveliness: (LivelinessKind, RtpsDuration),
        now: Instant,
    ) {
        if let (LivelinessKind::ManualByParticipant | LivelinessKind::ManualByTopic, Some(lease)) =
            (liveliness.0, lease_of(liveliness.1))
        {
            self.liveliness.offered.insert(
                writer,
                Offered {
                    kind: liveliness.0,
                    lease,
                    last: now,
                    lost: false,
                    total: 0,
                },
            );
        }
    }

    pub(super) fn lively_writer_deleted(&mut self, writer: Guid) {
        self.liveliness.offered.remove(&writer);
        self.liveliness.local_topic.remove(&writer);
    }

    /// A local reader that requested `lease`: it tracks its writers when
    /// the lease is finite.
    pub(super) fn lively_reader_created(&mut self, reader: Guid, lease: RtpsDuration) {
        if lease_of(lease).is_some() {
            self.liveliness
                .readers
                .insert(reader, ReaderState::default());
        }
    }

    pub(super) fn lively_reader_deleted(&mut self, reader: Guid) {
        self.liveliness.readers.remove(&reader);
    }

    /// A reader matched `writer`: tracked (alive) when it offers a finite lease.
    pub(super) fn lively_matched(&mut self, reader: Guid, writer: Guid, now: Instant) {
        let Some(offer) = self.writer_info.get(&writer).map(|i| i.liveliness) else {
            return;
        };
        let Some(lease) = lease_of(offer.1) else {
            return;
        };
        let Some(r) = self.liveliness.readers.get_mut(&reader) else {
            return;
        };
        if r.writers.contains_key(&writer) {
            return;
        }
        r.writers.insert(
            writer,
            Tracked {
                kind: offer.0,
                lease,
                alive: true,
                since: now,
            },
        );
        r.alive += 1;
        let (alive_count, not_alive_count) = (r.alive, r.not_alive);
        self.events.push_back(Event::LivelinessChanged {
            reader: ReaderId(reader),
            writer,
            alive: true,
            alive_count,
            not_alive_count,
        });
    }

    /// A reader lost `writer` (deleted, unmatched, participant lost).
    pub(super) fn lively_unmatched(&mut self, reader: Guid, writer: Guid) {
        let Some(r) = self.liveliness.readers.get_mut(&reader) else {
            return;
        };
        let Some(t) = r.writers.remove(&writer) else {
            return;
        };
        if t.alive {
            r.alive -= 1;
        } else {
            r.not_alive -= 1;
        }
        let (alive_count, not_alive_count) = (r.alive, r.not_alive);
        self.events.push_back(Event::LivelinessChanged {
            reader: ReaderId(reader),
            writer,
            alive: false,
            alive_count,
            not_alive_count,
        });
    }

    /// When a tracked lease next lapses, or an offered one.
    pub(super) fn next_liveliness_due(&self) -> Option<Instant> {
        let l = &self.liveliness;
        let readers = l.readers.values().flat_map(|r| {
            r.writers
                .iter()
                .filter(|(_, t)| t.alive)
                .filter_map(|(w, t)| Some(crate::time::later(l.last(&self.p, *w, t)?, t.lease)))
        });
        let offered = l
            .offered
            .values()
            .filter(|o| !o.lost)
            .map(|o| crate::time::later(o.last, o.lease));
        readers.chain(offered).min()
    }

    /// Lapsed leases become not alive; not-alive writers asserted since
    /// become alive again; offered leases that lapsed are lost.
    pub(super) fn check_liveliness(&mut self, now: Instant) {
        let l = &mut self.liveliness;
        if l.readers.is_empty() && l.offered.is_empty() {
            return;
        }
        let mut changes = Vec::new();
        for (reader, r) in l.readers.iter() {
            for (w, t) in r.writers.iter() {
                let Some(last) = l.last(&self.p, *w, t) else {
                    continue;
                };
                let lapsed = crate::time::later(last, t.lease) <= now;
                if t.alive && lapsed {
                    changes.push((*reader, *w, false));
                } else if !t.alive && last > t.since {
                    changes.push((*reader, *w, true));
                }
            }
        }
        let mut lapsed = Vec::new();
        for (reader, w, alive) in changes {
            let Some(r) = l.readers.get_mut(&reader) else {
                continue;
            };
            let Some(t) = r.writers.get_mut(&w) else {
                continue;
            };
            t.alive = alive;
            if alive {
                r.alive += 1;
                r.not_alive -= 1;
            } else {
                // an assertion counts only after the lapse
                t.since = now;
                r.alive -= 1;
                r.not_alive += 1;
                lapsed.push((reader, w));
            }
            self.events.push_back(Event::LivelinessChanged {
                reader: ReaderId(reader),
                writer: w,
                alive,
                alive_count: r.alive,
                not_alive_count: r.not_alive,
            });
        }
        // a writer that is not alive writes no instance and owns none
        // (DDS 1.4 §2.2.3.9.2, §2.2.3.11) until it writes again
        for (reader, w) in lapsed {
            self.writer_left_reader(reader, w, false);
        }
        let l = &mut self.liveliness;
        for (g, o) in l.offered.iter_mut() {
            if !o.lost && crate::time::later(o.last, o.lease) <= now {
                o.lost = true;
                o.total += 1;
                self.events.push_back(Event::LivelinessLost {
                    writer: WriterId(*g),
                    total: o.total,
                });
            }
        }
    }
}
