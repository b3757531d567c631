//! A sans-I/O DDS domain participant (DDSI-RTPS 2.x): SPDP, SEDP, endpoint
//! matching and user writers/readers, driven quinn-proto style.
//!
//! [`Participant`] opens no socket and reads no clock. The caller feeds it
//! received datagrams with [`Participant::handle_datagram`] and explicit time
//! with [`Participant::handle_timeout`] (when [`Participant::poll_timeout`]
//! says so), and takes out datagrams to send ([`Participant::poll_transmit`],
//! each with its destination [`Locator`](super::Locator); or [`Participant::poll_transmission`],
//! whose large sample data stays in the writer's history for a vectored
//! send) and [`Event`]s
//! ([`Participant::poll_event`]). Writing a sample, creating or deleting an
//! endpoint and closing are method calls that take `now` too.
//!
//! It ties the lower layers together:
//! - SPDP: a best-effort announcement of [`ParticipantData`] to the configured
//!   destinations ([`Config::spdp_destinations`]: a unicast peer list and/or
//!   the SPDP multicast locator) and to every known participant, five times
//!   100 ms apart at start-up and then every [`Config::announce_period`], plus
//!   an immediate, directed announcement to each newly found participant (both
//!   Cyclone DDS and Fast DDS answer a newcomer that way). Leases are kept
//!   with [`Participants`] and renewed by any traffic from the participant;
//!   expiry or an SPDP dispose gives [`Event::ParticipantLost`].
//! - SEDP: the four built-in endpoints (publications and subscriptions,
//!   writer and reader), reliable and transient-local, built from
//!   [`reliability`](super::reliability). Local endpoints are announced as
//!   [`EndpointData`] with every QoS (defaults included, as Fast DDS does)
//!   and `DATA_REPRESENTATION` = XCDR1 unless configured otherwise, so
//!   Fast DDS 2.9 matches them; deleting one sends a dispose.
//! - The writer liveliness protocol: the built-in participant-message
//!   pair (reliable, keyed [`ParticipantMessage`]s), an automatic message
//!   every third of the shortest finite AUTOMATIC lease of the local
//!   writers, manual ones on [`Participant::assert_liveliness`], liveliness
//!   HEARTBEATs on [`Participant::assert_writer_liveliness`], and what
//!   asserted each remote writer ([`Participant::liveliness_asserted`]).
//! - Matching with [`check_match`](super::matching::check_match): topic, type name and requested/offered
//!   QoS (partitions included), in both directions and also between local
//!   endpoints (delivered in process, no datagram). A same-topic pair that
//!   does not match gives [`Event::IncompatibleQos`] with the reason.
//! - User writers and readers, best effort or reliable, keyed or not, with
//!   per-instance keep-last or keep-all history, transient-local replay for
//!   late joiners, GAP for what a reader will never get, INFO_TS source
//!   timestamps and INFO_DST addressing. Large samples are cut with
//!   [`frag`](super::frag) and reassembled with its [`Reassembler`];
//!   a reliable reader asks for missing fragments with NACK_FRAG and a writer
//!   answers NACK_FRAG with just those fragments.
//! - Dispose and unregister both ways on the wire: a DATA with inline
//!   `PID_KEY_HASH` + `PID_STATUS_INFO` (what Fast DDS sends) *and* the
//!   serialized key with the K flag (what Cyclone sends); on receipt either
//!   form is understood.
//!
//! # What the peers do, and what Courier does (`shared/protocols/rtps.md` §7)
//!
//! | | Cyclone DDS 11 | Fast DDS 2.9 | Courier |
//! |---|---|---|---|
//! | header version | 2.5 (2.1 in 0.10) | 2.3 | 2.4 ([`PROTOCOL_VERSION`]); any 2.x accepted |
//! | vendor id | 01.10 | 01.0f | 01.c0 ([`VENDOR_ID`], unregistered) |
//! | lease | 10 s | 20 s | 10 s, announced every 3 s |
//! | user DATA addressing | INFO_TS, DATA to ENTITYID_UNKNOWN, HEARTBEAT piggybacked | INFO_DST + INFO_TS + DATA to the reader's entity id | INFO_DST per participant; the reader's entity id when one reader there is matched, else UNKNOWN; HEARTBEAT piggybacked |
//! | fragments | 1344 B, 10 per DATA_FRAG, only above 14720 B messages | one ~64 KB fragment per datagram | 1344 B fragments as Cyclone ([`Config::fragment_size`]); datagrams up to [`Config::max_message_size`], 14720 as Cyclone, which the sdk raises to Fast DDS's 65500 on the loopback interface |
//! | builtin endpoint set | 0xfc3f | 0x0c3f0c3f | 0xc3f (SPDP, SEDP and the participant-message pair: [`ParticipantMessage`]); unknown bits of peers are ignored |
//!
//! # Vendor id
//!
//! Courier announces vendor id `01.c0`. It is **not** assigned by the OMG:
//! the registry (<https://www.dds-foundation.org/dds-rtps-vendor-and-product-ids/>)
//! ran sequentially up to 01.16 in 2024; 01.c0 sits far above it, clear of
//! other unofficial choices seen in public code (01.20, 01.aa). Peers treat an
//! unknown vendor as a plain standard participant: they read none of its
//! vendor-specific PIDs (and Courier sends none). Replace it if the OMG
//! assigns Courier an id.
//!
//! # Example: two participants on a perfect network
//!
//! ```
//! use std::time::{Duration, Instant, SystemTime};
//! use courier_wire::rtps::participant::{Change, Config, EndpointConfig, Event, Participant};
//! use courier_wire::rtps::discovery::{Duration as RtpsDuration, EndpointQos, Reliability};
//!
//! let t0 = Instant::now();
//! let peers = [[127, 0, 0, 1]];
//! let mk = |i: u32, id: u8| {
//!     let cfg = Config::udpv4(0, i, courier_wire::rtps::participant::guid_prefix([id; 10]), [127, 0, 0, 1])
//!         .unwrap()
//!         .with_unicast_peers(&peers, 3);
//!     Participant::new(cfg, t0, SystemTime::UNIX_EPOCH)
//! };
//! let mut ps = [mk(0, 1), mk(1, 2)];
//! let mut qos = EndpointQos::reader_default();
//! qos.reliability = Reliability::Reliable(RtpsDuration::ZERO);
//! let w = ps[0].create_writer(EndpointConfig::writer("Hello", "Msg"), t0).unwrap();
//! ps[1].create_reader(EndpointConfig::reader("Hello", "Msg").qos(qos), t0).unwrap();
//!
//! // deliver every datagram to the participant that owns its destination
//! let mut now = t0;
//! let mut got = None;
//! for step in 0..100 {
//!     for i in 0..2 {
//!         while let Some(d) = ps[i].poll_transmit() {
//!             for p in ps.iter_mut() {
//!                 if p.config().metatraffic_unicast.contains(&d.destination)
//!                     || p.config().default_unicast.contains(&d.destination)
//!                 {
//!                     p.handle_datagram(d.destination, &d.payload, now);
//!                 }
//!             }
//!         }
//!     }
//!     if step == 10 {
//!         ps[0].write(w, Change::alive(b"\x00\x01\x00\x00hi!\x00"), now).unwrap();
//!     }
//!     while let Some(e) = ps[1].poll_event() {
//!         if let Event::SampleReceived(s) = e {
//!             got = Some(s.data().to_vec());
//!         }
//!     }
//!     now += Duration::from_millis(10);
//!     for p in ps.iter_mut() {
//!         p.handle_timeout(now);
//!     }
//! }
//! assert_eq!(got.as_deref(), Some(&b"\x00\x01\x00\x00hi!\x00"[..]));
//! ```

mod change;
mod config;
mod emit;
mod event;
mod keyhash;
mod outbox;
mod pmd;
mod ports;
mod receive;
mod sedp;
mod spdp;
mod user;

pub(crate) use change::ENVELOPE_ROOM;
pub use change::{
    Change, ChangeKind, Envelope, ReceivedSample, SampleIdentity,
    PID_FASTDDS_RELATED_SAMPLE_IDENTITY, PID_RELATED_SAMPLE_IDENTITY,
};
pub use config::{
    builtin_endpoints, entity_id, guid_prefix, Config, EndpointConfig, EndpointKind,
    DEFAULT_MAX_MESSAGE_SIZE, PROTOCOL_VERSION, VENDOR_ID,
};
pub use event::{CreateError, Event, LostReason, Stats, WriteError, MAX_WRITE_SIZE};
pub use keyhash::{md5, KeyHash};
pub use outbox::{Datagram, Transmission};
pub use pmd::{ParticipantMessage, PmdError, PMD_KIND_AUTOMATIC, PMD_KIND_MANUAL};
pub use ports::{PortMapping, SPDP_MULTICAST_ADDRESS};

use std::collections::{BTreeMap, BTreeSet, VecDeque};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

// seeded per process: keyed by GUIDs and key hashes off the network
use foldhash::{HashMap, HashMapExt};

use super::discovery::{self, pid, EndpointData, ParticipantData};
use super::frag::Reassembler;
use super::matching::{ParticipantEvent, Participants};
use super::reliability::{Reader, Writer};
use super::{EntityId, Guid, GuidPrefix, Header, SequenceNumber, Time};
use change::{envelope, open};
use emit::{data_unit_list, Shape, OVERHEAD};
use outbox::{Outbox, Unit};
use sedp::builtin_key;
use user::{LocalReader, LocalWriter};

/// A sans-I/O DDS domain participant. See the [module docs](self).
pub struct Participant {
    cfg: Config,
    start: Instant,
    wall_start: Duration,
    spdp_payload: Vec<u8>,
    next_announce: Instant,
    initial_left: u32,
    closed: bool,
    participants: Participants,
    pub_writer: Writer,
    sub_writer: Writer,
    pub_reader: Reader,
    sub_reader: Reader,
    pub_writer_readers: BTreeSet<Guid>,
    sub_writer_readers: BTreeSet<Guid>,
    /// The writer liveliness protocol's built-in pair and what it heard.
    wlp: pmd::Wlp,
    announcements: HashMap<Guid, SequenceNumber>,
    builtin_disposals: Vec<(bool, SequenceNumber)>,
    writers: BTreeMap<EntityId, LocalWriter>,
    readers: BTreeMap<EntityId, LocalReader>,
    remote_writers: BTreeMap<Guid, EndpointData>,
    remote_readers: BTreeMap<Guid, EndpointData>,
    /// What the remote endpoints take ([`sedp::footprint`]), all together
    /// ([`Config::max_remote_endpoint_bytes`]).
    remote_endpoint_bytes: usize,
    replays: Vec<(EntityId, Guid, SequenceNumber, Envelope)>,
    reassembler: Reassembler,
    next_key: u32,
    nackfrag_count: i32,
    outbox: Outbox,
    out: VecDeque<Transmission>,
    /// Something may have queued a transmission since the last
    /// [`Participant::gather`]: set by every `&mut` entry point that can
    /// change what the writers and readers want sent, so that asking for
    /// the next datagram when nothing changed costs no walk over them.
    gather_due: bool,
    /// [`Participant::poll_timeout`]'s answer, until an entry point
    /// changes something (the driver asks several times per turn).
    /// Gathering does not move a timeout: the writers' `poll_transmit`
    /// leaves their heartbeat timers alone.
    next_timeout: std::cell::Cell<Option<Option<Instant>>>,
    events: VecDeque<Event>,
    stats: Stats,
}

impl std::fmt::Debug for Participant {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Participant")
            .field("guid_prefix", &self.cfg.guid_prefix)
            .field("domain_id", &self.cfg.domain_id)
            .field("participants", &self.participants.len())
            .field("writers", &self.writers.len())
            .field("readers", &self.readers.len())
            .field("closed", &self.closed)
            .finish()
    }
}

impl Participant {
    /// A participant; it announces itself at once (see
    /// [`Participant::poll_transmit`]). `wall_clock` is the wall-clock time at
    /// `now`, read by the caller: source timestamps are derived from it and
    /// the monotonic `now` of later calls.
    pub fn new(config: Config, now: Instant, wall_clock: SystemTime) -> Self {
        let mut cfg = config;
        cfg.max_message_size = cfg.max_message_size.clamp(512, 65_507);
        let max_fs = u16::try_from(cfg.max_message_size - OVERHEAD - 64).unwrap_or(u16::MAX);
        cfg.fragment_size = cfg.fragment_size.clamp(64, max_fs);
        cfg.max_history = cfg.max_history.max(1);
        let prefix = cfg.guid_prefix;
        let spdp = ParticipantData {
            guid_prefix: prefix,
            protocol_version: PROTOCOL_VERSION,
            vendor: VENDOR_ID,
            domain_id: Some(cfg.domain_id),
            default_unicast: cfg.default_unicast.clone(),
            default_multicast: cfg.default_multicast.clone(),
            metatraffic_unicast: cfg.metatraffic_unicast.clone(),
            metatraffic_multicast: cfg.metatraffic_multicast.clone(),
            lease_duration: discovery::Duration::from_std(cfg.lease_duration),
            builtin_endpoints: builtin_endpoints::COURIER,
            entity_name: cfg.entity_name.clone(),
        };
        let g = |entity| Guid { prefix, entity };
        let hb = cfg.heartbeat_period;
        let sedp_writer = |e| Writer::new(g(e), true, None, 1 << 16, hb).retain_acked(true);
        let header = Header {
            version: PROTOCOL_VERSION,
            vendor: VENDOR_ID,
            guid_prefix: prefix,
        };
        let mut p = Participant {
            start: now,
            wall_start: wall_clock.duration_since(UNIX_EPOCH).unwrap_or_default(),
            spdp_payload: spdp.to_payload(),
            next_announce: now,
            initial_left: cfg.initial_announcements,
            closed: false,
            participants: Participants::new(),
            pub_writer: sedp_writer(EntityId::SEDP_PUBLICATIONS_WRITER),
            sub_writer: sedp_writer(EntityId::SEDP_SUBSCRIPTIONS_WRITER),
            pub_reader: Reader::new(true, cfg.max_out_of_order),
            sub_reader: Reader::new(true, cfg.max_out_of_order),
            pub_writer_readers: BTreeSet::new(),
            sub_writer_readers: BTreeSet::new(),
            wlp: pmd::Wlp::new(prefix, hb, cfg.max_out_of_order),
            announcements: HashMap::new(),
            builtin_disposals: Vec::new(),
            writers: BTreeMap::new(),
            readers: BTreeMap::new(),
            remote_writers: BTreeMap::new(),
            remote_readers: BTreeMap::new(),
            remote_endpoint_bytes: 0,
            replays: Vec::new(),
            reassembler: Reassembler::new(cfg.max_sample_size, cfg.reassembly_limit)
                .with_spare_limit(cfg.spare_buffer_bytes),
            next_key: 1,
            nackfrag_count: 0,
            outbox: Outbox::new(header, cfg.max_message_size),
            out: VecDeque::new(),
            gather_due: true,
            next_timeout: std::cell::Cell::new(None),
            events: VecDeque::new(),
            stats: Stats::default(),
            cfg,
        };
        p.announce(now);
        p.flush(now);
        p
    }

    /// This participant's GUID prefix.
    pub fn guid_prefix(&self) -> GuidPrefix {
        self.cfg.guid_prefix
    }

    /// The configuration in use (sizes clamped to what works).
    pub fn config(&self) -> &Config {
        &self.cfg
    }

    /// The counters.
    pub fn stats(&self) -> Stats {
        self.stats
    }

    /// A known remote participant.
    pub fn participant(&self, prefix: GuidPrefix) -> Option<&ParticipantData> {
        self.participants.get(&prefix)
    }

    /// The known remote participants, in no particular order.
    pub fn participants(&self) -> impl Iterator<Item = &ParticipantData> + '_ {
        self.participants.iter()
    }

    /// A known remote writer.
    pub fn publication(&self, writer: Guid) -> Option<&EndpointData> {
        self.remote_writers.get(&writer)
    }

    /// The known remote writers.
    pub fn publications(&self) -> impl Iterator<Item = &EndpointData> + '_ {
        self.remote_writers.values()
    }

    /// The known remote readers.
    pub fn subscriptions(&self) -> impl Iterator<Item = &EndpointData> + '_ {
        self.remote_readers.values()
    }

    /// The readers (remote and local) a local writer is matched with.
    pub fn matched_readers(&self, writer: Guid) -> Vec<Guid> {
        let Some(w) = self
            .writers
            .get(&writer.entity)
            .filter(|_| self.is_local(writer))
        else {
            return Vec::new();
        };
        let local = w.local_readers.iter().map(|e| self.guid(*e));
        w.matched.iter().copied().chain(local).collect()
    }

    /// The writers (remote and local) a local reader is matched with.
    pub fn matched_writers(&self, reader: Guid) -> Vec<Guid> {
        let Some(r) = self
            .readers
            .get(&reader.entity)
            .filter(|_| self.is_local(reader))
        else {
            return Vec::new();
        };
        let local = r.local_writers.iter().map(|e| self.guid(*e));
        r.matched.iter().copied().chain(local).collect()
    }

    /// True when every reader matched with a reliable local writer has
    /// acknowledged `sn` and everything before it.
    pub fn is_acked_by_all(&self, writer: Guid, sn: SequenceNumber) -> bool {
        self.writers
            .get(&writer.entity)
            .filter(|_| self.is_local(writer))
            .is_some_and(|w| w.writer.acked_by_all() >= sn)
    }

    /// True when every reader matched with local writer `writer` has
    /// acknowledged all it wrote (false for an unknown writer).
    pub fn is_all_acked(&self, writer: Guid) -> bool {
        self.writers
            .get(&writer.entity)
            .filter(|_| self.is_local(writer))
            .is_some_and(|w| w.writer.acked_by_all() >= w.writer.last_sn())
    }

    fn is_local(&self, g: Guid) -> bool {
        g.prefix == self.cfg.guid_prefix
    }

    fn guid(&self, entity: EntityId) -> Guid {
        Guid {
            prefix: self.cfg.guid_prefix,
            entity,
        }
    }

    fn shape(&self) -> Shape {
        Shape {
            max: self.cfg.max_message_size,
            fragment_size: self.cfg.fragment_size,
        }
    }

    /// The source timestamp this participant gives a change written at
    /// `at` (its wall clock then): for a write that waited for room in a
    /// full history before it reached [`Participant::write`], stamped as
    /// when the application wrote it (DDS 1.4 §2.2.2.4.2.11).
    pub fn time_at(&self, at: Instant) -> Time {
        self.wall(at)
    }

    /// Wall-clock time at `now`, as an RTPS `Time_t`.
    fn wall(&self, now: Instant) -> Time {
        let d = self.wall_start + now.saturating_duration_since(self.start);
        Time {
            seconds: i32::try_from(d.as_secs()).unwrap_or(i32::MAX),
            fraction: ((u64::from(d.subsec_nanos()) << 32) / 1_000_000_000) as u32,
        }
    }

    /// The next datagram to send.
    ///
    /// Writes are packed: every submessage produced since the last call
    /// that emptied the queue goes out in as few datagrams per destination
    /// as [`Config::max_message_size`] allows, so a caller that makes
    /// several [`Participant::write`]s before polling sends them together.
    pub fn poll_transmit(&mut self) -> Option<Datagram> {
        self.poll_transmission().map(Transmission::into_datagram)
    }

    /// [`Participant::poll_transmit`] without copying large sample data
    /// into the datagram: for a sender that can send a [`Transmission`]'s
    /// parts with one vectored call.
    pub fn poll_transmission(&mut self) -> Option<Transmission> {
        if self.out.is_empty() && self.gather_due {
            self.gather();
        }
        self.out.pop_front()
    }

    /// The next event.
    pub fn poll_event(&mut self) -> Option<Event> {
        self.events.pop_front()
    }

    /// When [`Participant::handle_timeout`] must be called next.
    pub fn poll_timeout(&self) -> Option<Instant> {
        if let Some(t) = self.next_timeout.get() {
            return t;
        }
        let t = self.compute_timeout();
        self.next_timeout.set(Some(t));
        t
    }

    fn compute_timeout(&self) -> Option<Instant> {
        if self.closed {
            return None;
        }
        [
            Some(self.next_announce),
            self.participants.poll_timeout(),
            self.pub_writer.poll_timeout(),
            self.sub_writer.poll_timeout(),
            self.pub_reader.poll_timeout(),
            self.sub_reader.poll_timeout(),
        ]
        .into_iter()
        .chain(self.wlp.poll_timeout())
        .chain(self.writers.values().map(|w| w.writer.poll_timeout()))
        .chain(self.writers.values().map(|w| w.next_expiry()))
        .chain(self.readers.values().map(|r| r.reader.poll_timeout()))
        .flatten()
        .min()
    }

    /// Fires what is due at `now`: SPDP announcements, lease expiry,
    /// heartbeats, pre-emptive ACKNACKs.
    pub fn handle_timeout(&mut self, now: Instant) {
        self.touch();
        if self.closed {
            return;
        }
        if now >= self.next_announce {
            self.announce(now);
        }
        for e in self.participants.handle_timeout(now) {
            if let ParticipantEvent::Lost(p) = e {
                self.participant_gone(p, LostReason::LeaseExpired);
            }
        }
        self.pub_writer.handle_timeout(now);
        self.sub_writer.handle_timeout(now);
        for w in self.writers.values_mut() {
            w.expire(now);
            w.writer.handle_timeout(now);
        }
        self.pub_reader.handle_timeout(now);
        self.sub_reader.handle_timeout(now);
        self.wlp_timeout(now);
        for r in self.readers.values_mut() {
            r.reader.handle_timeout(now);
        }
        self.flush(now);
    }

    /// Leaves the domain: every local endpoint and then the participant
    /// itself are disposed (sent now, see [`Participant::poll_transmit`]);
    /// afterwards nothing is sent or received.
    pub fn close(&mut self, now: Instant) {
        self.touch();
        if self.closed {
            return;
        }
        let ws: Vec<EntityId> = self.writers.keys().copied().collect();
        for w in ws {
            self.delete_writer(self.guid(w), now);
        }
        let rs: Vec<EntityId> = self.readers.keys().copied().collect();
        for r in rs {
            self.delete_reader(self.guid(r), now);
        }
        let key = builtin_key(pid::PARTICIPANT_GUID, self.guid(EntityId::PARTICIPANT));
        let env = envelope(
            ChangeKind::DisposedUnregistered,
            Some(KeyHash(self.guid(EntityId::PARTICIPANT).to_bytes())),
            Some(self.wall(now)),
            &key,
        );
        let units = data_unit_list(
            self.shape(),
            EntityId::SPDP_READER,
            EntityId::SPDP_WRITER,
            SequenceNumber(2),
            &open(&env),
        );
        for (l, p) in self.spdp_targets() {
            for u in &units {
                self.outbox.push(
                    l,
                    p,
                    Unit {
                        ts: u.ts,
                        bytes: u.bytes.clone(),
                    },
                );
            }
        }
        self.flush(now);
        self.closed = true;
    }

    /// Moves everything the state machines produced into datagrams and events.
    fn flush(&mut self, now: Instant) {
        // SEDP samples first: they can create matches, and so more to send
        loop {
            let mut any = false;
            while let Some((w, _, env)) = self.pub_reader.poll_sample() {
                any = true;
                self.on_sedp_sample(true, w, &env, now);
            }
            while let Some((w, _, env)) = self.sub_reader.poll_sample() {
                any = true;
                self.on_sedp_sample(false, w, &env, now);
            }
            if !any {
                break;
            }
        }
        // disposals every current reader has are of no use to late joiners
        let (pa, sa) = (
            self.pub_writer.acked_by_all(),
            self.sub_writer.acked_by_all(),
        );
        let (pw, sw) = (&mut self.pub_writer, &mut self.sub_writer);
        self.builtin_disposals.retain(|(publ, sn)| {
            let (w, acked) = if *publ {
                (&mut *pw, pa)
            } else {
                (&mut *sw, sa)
            };
            if *sn <= acked {
                w.remove(*sn);
                false
            } else {
                true
            }
        });
        self.gather();
        let prefix = self.cfg.guid_prefix;
        for (e, lw) in self.writers.iter_mut() {
            if lw.reliable {
                let acked = lw.writer.acked_by_all();
                if acked.0 > lw.acked_reported {
                    lw.acked_reported = acked.0;
                    self.events.push_back(Event::AckedByAll {
                        writer: Guid { prefix, entity: *e },
                        up_to: acked,
                    });
                }
            }
        }
        self.wlp_drain();
        for (e, lr) in self.readers.iter_mut() {
            while let Some((w, sn, env)) = lr.reader.poll_sample() {
                let s = ReceivedSample::new(Guid { prefix, entity: *e }, w, sn, env);
                self.events.push_back(Event::SampleReceived(s));
            }
        }
    }

    /// An entry point may change what is to be sent and when the next
    /// timeout is due.
    fn touch(&mut self) {
        self.gather_due = true;
        self.next_timeout.set(None);
    }
}
