//! SEDP, endpoint discovery (§8.5.4), and matching: local endpoints
//! announced on (and disposed from) the built-in publications and
//! subscriptions writers, remote endpoints found, changed and lost, and
//! each matched against the local endpoints with
//! [`check_match`](crate::rtps::matching::check_match), local endpoints
//! also against each other (delivery in process).

use std::time::Instant;

use super::change::{envelope, open, ChangeKind, ReceivedSample};
use super::{Event, KeyHash, Participant, PROTOCOL_VERSION, VENDOR_ID};
use crate::rtps::discovery::{payload_params, pid, Durability, EndpointData, Reliability};
use crate::rtps::matching::check_match;
use crate::rtps::parameter::ParameterList;
use crate::rtps::{EntityId, Guid, SequenceNumber};

/// The parameter-list key of a built-in instance (participant or endpoint GUID).
pub(super) fn builtin_key(pid: u16, g: Guid) -> Vec<u8> {
    let mut v = vec![0x00, 0x03, 0x00, 0x00];
    ParameterList::write(&[(pid, &g.to_bytes())], true, &mut v);
    v
}

impl Participant {
    pub(super) fn announce_endpoint(
        &mut self,
        data: &EndpointData,
        publication: bool,
        now: Instant,
    ) {
        let payload = data.to_payload(VENDOR_ID, PROTOCOL_VERSION);
        let env = envelope(ChangeKind::Alive, None, Some(self.wall(now)), &payload);
        let w = if publication {
            &mut self.pub_writer
        } else {
            &mut self.sub_writer
        };
        match w.write(env, now) {
            Some(sn) => {
                self.announcements.insert(data.guid, sn);
            }
            None => self.stats.discovery_limited += 1,
        }
    }

    pub(super) fn unannounce_endpoint(&mut self, guid: Guid, publication: bool, now: Instant) {
        let key = builtin_key(pid::ENDPOINT_GUID, guid);
        let env = envelope(
            ChangeKind::DisposedUnregistered,
            Some(KeyHash(guid.to_bytes())),
            Some(self.wall(now)),
            &key,
        );
        let w = if publication {
            &mut self.pub_writer
        } else {
            &mut self.sub_writer
        };
        if let Some(sn) = self.announcements.remove(&guid) {
            // late joiners must not learn of an endpoint that is gone
            w.remove(sn);
        }
        match w.write(env, now) {
            Some(sn) => self.builtin_disposals.push((publication, sn)),
            None => self.stats.discovery_limited += 1,
        }
    }

    pub(super) fn on_sedp_sample(
        &mut self,
        publications: bool,
        from: Guid,
        env: &[u8],
        now: Instant,
    ) {
        let e = open(env);
        if e.kind != ChangeKind::Alive {
            if let Some(k) = e.key_hash {
                let g = Guid::from_bytes(k.0);
                if g.prefix == from.prefix {
                    if publications {
                        self.remote_writer_gone(g);
                    } else {
                        self.remote_reader_gone(g);
                    }
                }
            }
            return;
        }
        let vendor = self.participants.get(&from.prefix).map(|p| p.vendor);
        let data = match payload_params(e.data).and_then(|l| {
            let mut d = EndpointData::from_params(&l, publications)?;
            if let Some(v) = vendor {
                d.read_vendor_params(&l, v);
            }
            Ok(d)
        }) {
            Ok(d) => d,
            Err(_) => {
                self.stats.discovery_errors += 1;
                return;
            }
        };
        let kind_ok = if publications {
            data.guid.entity.is_writer()
        } else {
            data.guid.entity.is_reader()
        };
        if data.guid.prefix != from.prefix || !kind_ok || data.guid.entity.is_builtin() {
            self.stats.discovery_errors += 1;
            return;
        }
        let g = data.guid;
        let liveliness = data.qos.liveliness;
        let (map, other) = if publications {
            (&mut self.remote_writers, self.remote_readers.len())
        } else {
            (&mut self.remote_readers, self.remote_writers.len())
        };
        let bytes = footprint(&data);
        let held = self.remote_endpoint_bytes;
        let event = match map.get(&g) {
            Some(old) if *old == data => return,
            Some(old) => {
                let held = held - footprint(old);
                if held + bytes > self.cfg.max_remote_endpoint_bytes {
                    // (the endpoint as it was stays: what it announces now
                    // is not taken)
                    self.stats.discovery_limited += 1;
                    return;
                }
                self.remote_endpoint_bytes = held + bytes;
                map.insert(g, data.clone());
                if publications {
                    Event::PublicationChanged(data)
                } else {
                    Event::SubscriptionChanged(data)
                }
            }
            None => {
                if map.len() + other >= self.cfg.max_remote_endpoints
                    || held + bytes > self.cfg.max_remote_endpoint_bytes
                {
                    self.stats.discovery_limited += 1;
                    return;
                }
                self.remote_endpoint_bytes = held + bytes;
                map.insert(g, data.clone());
                if publications {
                    Event::PublicationFound(data)
                } else {
                    Event::SubscriptionFound(data)
                }
            }
        };
        if publications {
            self.wlp_writer_known(liveliness.0, liveliness.1);
        }
        self.events.push_back(event);
        if publications {
            let rs: Vec<EntityId> = self.readers.keys().copied().collect();
            for r in rs {
                self.match_remote_writer(r, g, now);
            }
        } else {
            let ws: Vec<EntityId> = self.writers.keys().copied().collect();
            for w in ws {
                self.match_remote_reader(w, g, now);
            }
        }
    }

    pub(super) fn remote_writer_gone(&mut self, g: Guid) {
        let Some(old) = self.remote_writers.remove(&g) else {
            return;
        };
        self.remote_endpoint_bytes -= footprint(&old);
        let prefix = self.cfg.guid_prefix;
        for (e, lr) in self.readers.iter_mut() {
            if lr.matched.remove(&g) {
                lr.reader.remove_writer(g);
                let reader = Guid { prefix, entity: *e };
                self.events
                    .push_back(Event::ReaderUnmatched { reader, writer: g });
            }
        }
        self.reassembler.forget_below(g, SequenceNumber(i64::MAX));
        self.wlp.forget_writer(g);
        self.events.push_back(Event::PublicationLost(g));
    }

    pub(super) fn remote_reader_gone(&mut self, g: Guid) {
        let Some(old) = self.remote_readers.remove(&g) else {
            return;
        };
        self.remote_endpoint_bytes -= footprint(&old);
        let prefix = self.cfg.guid_prefix;
        for (e, lw) in self.writers.iter_mut() {
            if lw.matched.remove(&g) {
                lw.writer.remove_reader(g);
                let writer = Guid { prefix, entity: *e };
                self.events
                    .push_back(Event::WriterUnmatched { writer, reader: g });
            }
        }
        self.events.push_back(Event::SubscriptionLost(g));
    }

    /// (Re)evaluates a remote writer against a local reader.
    pub(super) fn match_remote_writer(&mut self, reader: EntityId, g: Guid, now: Instant) {
        let prefix = self.cfg.guid_prefix;
        let (Some(lr), Some(rw)) = (self.readers.get_mut(&reader), self.remote_writers.get(&g))
        else {
            return;
        };
        let local = Guid {
            prefix,
            entity: reader,
        };
        let was = lr.matched.contains(&g);
        let res = (rw.topic_name == lr.data.topic_name).then(|| check_match(rw, &lr.data));
        if was && !matches!(res, Some(Ok(()))) {
            lr.matched.remove(&g);
            lr.reader.remove_writer(g);
            self.events.push_back(Event::ReaderUnmatched {
                reader: local,
                writer: g,
            });
        }
        match res {
            Some(Ok(())) if !was => {
                lr.matched.insert(g);
                if rw.qos.durability >= Durability::TransientLocal {
                    lr.reader.add_durable_writer(g, now);
                } else {
                    lr.reader.add_writer(g, now);
                }
                self.events.push_back(Event::ReaderMatched {
                    reader: local,
                    writer: g,
                });
            }
            Some(Err(reason)) if reason.is_reported() => {
                self.events.push_back(Event::IncompatibleQos {
                    local,
                    remote: g,
                    reason,
                })
            }
            _ => {}
        }
    }

    /// (Re)evaluates a remote reader against a local writer.
    pub(super) fn match_remote_reader(&mut self, writer: EntityId, g: Guid, now: Instant) {
        let prefix = self.cfg.guid_prefix;
        let (Some(lw), Some(rr)) = (self.writers.get_mut(&writer), self.remote_readers.get(&g))
        else {
            return;
        };
        let local = Guid {
            prefix,
            entity: writer,
        };
        let was = lw.matched.contains(&g);
        let res = (rr.topic_name == lw.data.topic_name).then(|| check_match(&lw.data, rr));
        if was && !matches!(res, Some(Ok(()))) {
            lw.matched.remove(&g);
            lw.writer.remove_reader(g);
            self.events.push_back(Event::WriterUnmatched {
                writer: local,
                reader: g,
            });
        }
        match res {
            Some(Ok(())) if !was => {
                let replay = lw.durable && rr.qos.durability >= Durability::TransientLocal;
                let reliable = matches!(rr.qos.reliability, Reliability::Reliable(_));
                lw.matched.insert(g);
                if reliable {
                    lw.writer.add_reader(g, replay, now);
                } else {
                    // it never acknowledges: nothing may wait for it
                    lw.writer.add_best_effort_reader(g);
                }
                if replay && !(lw.reliable && reliable) {
                    // best effort has no repair: push the history once
                    for (sn, p) in lw.writer.samples() {
                        self.replays.push((writer, g, sn, p.clone()));
                    }
                }
                self.events.push_back(Event::WriterMatched {
                    writer: local,
                    reader: g,
                });
            }
            Some(Err(reason)) if reason.is_reported() => {
                self.events.push_back(Event::IncompatibleQos {
                    local,
                    remote: g,
                    reason,
                })
            }
            _ => {}
        }
    }

    /// Matches a local writer with a local reader (in-process delivery).
    pub(super) fn match_local(&mut self, writer: EntityId, reader: EntityId) {
        let (w, r) = (self.guid(writer), self.guid(reader));
        let (Some(lw), Some(lr)) = (self.writers.get_mut(&writer), self.readers.get_mut(&reader))
        else {
            return;
        };
        if lw.data.topic_name != lr.data.topic_name {
            return;
        }
        match check_match(&lw.data, &lr.data) {
            Ok(()) => {
                if !lw.local_readers.insert(reader) {
                    return;
                }
                lr.local_writers.insert(writer);
                self.events.push_back(Event::WriterMatched {
                    writer: w,
                    reader: r,
                });
                self.events.push_back(Event::ReaderMatched {
                    reader: r,
                    writer: w,
                });
                if lw.durable && lr.data.qos.durability >= Durability::TransientLocal {
                    for (sn, p) in lw.writer.samples() {
                        let s = ReceivedSample::new(r, w, sn, p.clone());
                        self.events.push_back(Event::SampleReceived(s));
                    }
                }
            }
            Err(reason) if reason.is_reported() => {
                self.events.push_back(Event::IncompatibleQos {
                    local: w,
                    remote: r,
                    reason: reason.clone(),
                });
                self.events.push_back(Event::IncompatibleQos {
                    local: r,
                    remote: w,
                    reason,
                });
            }
            Err(_) => {}
        }
    }
}

/// What a remote endpoint's record takes: the record and what its names,
/// locators, partitions and type information hold
/// ([`Config::max_remote_endpoint_bytes`](super::Config::max_remote_endpoint_bytes)).
/// A function of the record alone, so that what was added is what is
/// taken off.
pub(super) fn footprint(d: &EndpointData) -> usize {
    std::mem::size_of::<EndpointData>()
        + d.topic_name.len()
        + d.type_name.len()
        + (d.unicast.len() + d.multicast.len()) * std::mem::size_of::<crate::rtps::Locator>()
        + d.type_information.as_ref().map_or(0, Vec::len)
        + d.qos
            .partitions
            .iter()
            .map(|p| p.len() + std::mem::size_of::<String>())
            .sum::<usize>()
        + d.qos.data_representation.len() * 2
}
