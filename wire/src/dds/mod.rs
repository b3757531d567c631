//! A sans-I/O DDS domain over the RTPS [`Participant`]: what DDS adds on
//! top of the wire protocol, for shells that hold many writers, readers,
//! services and clients in one participant (the sdk's RTPS backend, an
//! XRCE agent serving many clients).
//!
//! [`Domain`] is driven like the participant, quinn-proto style: the shell
//! feeds it datagrams ([`Domain::handle_datagram`]) and time
//! ([`Domain::handle_timeout`] when [`Domain::poll_timeout`] says so), calls
//! its commands (create and delete [writers](Domain::create_writer),
//! [readers](Domain::create_reader), [pattern
//! subscriptions](Domain::create_pattern), [services](Domain::create_service)
//! and [clients](Domain::create_client); [write](Domain::write),
//! [query](Domain::query), [reply](Domain::reply)), and takes out datagrams
//! ([`Domain::poll_transmit`]) and [`Event`]s ([`Domain::poll_event`]). It
//! reads no clock: every entry point takes `now`, and the wall clock is
//! derived from the one given to [`Domain::new`].
//!
//! What it decides:
//! - **exclusive ownership**: a reader with `exclusive_ownership` takes
//!   each instance only from the strongest live writer (ties: the lower
//!   GUID), its disposes only from it too; when the owner is deleted or
//!   lost (its participant's lease ends), unregisters the instance, misses
//!   the deadline or, for a reader that tracks liveliness, is not alive
//!   any more, the next writer's samples are taken;
//! - **instance states** of keyed readers (DDS 1.4 §2.2.2.5.1): an
//!   instance is NOT_ALIVE_NO_WRITERS (an
//!   [`Unregistered`](participant::ChangeKind::Unregistered) change) when its last live writer unregisters it, or leaves without a
//!   word for it — deleted (Cyclone DDS unregisters nothing when a writer
//!   closes), its participant lost, or, for a reader that tracks
//!   liveliness, not alive any more: then the reader makes the change
//!   itself, with no data. An unregister from a writer that is not the
//!   last, or of an instance the reader never saw, says nothing; a
//!   disposed instance stays disposed. A dispose that carries the whole
//!   sample (Cyclone's `write_dispose`) is the sample, then the dispose;
//! - **lifespan**: samples older than their writer's lifespan by source
//!   timestamp are dropped ([`Event::SampleDropped`]);
//! - **time-based filter**: samples of an instance closer than the
//!   reader's minimum separation to the last one taken are dropped;
//! - **deadline**: [`Event::DeadlineMissed`] per instance and missed period
//!   for readers, [`Event::OfferedDeadlineMissed`] for writers that did not
//!   write a live instance within the deadline they offer;
//! - **liveliness**: [`Event::LivelinessChanged`] for readers that request a finite lease,
//!   [`Event::LivelinessLost`] for manual writers that did not assert;
//! - **request/reply** as ROS 2 does it ([`rpc`](self#request-reply));
//! - **pattern subscriptions** ([`fnmatch`] on topic and type names);
//! - **keep-all back-pressure** both ways: a writer whose history is full
//!   refuses writes and says when it has room ([`Event::Writable`]); a
//!   reader whose queue (in the shell) is full pauses the reading of user
//!   data ([`Domain::set_reader_full`], [`Domain::paused_reader`]);
//! - **confirmed writes** ([`Domain::write_confirmed`]);
//! - **instances** of keyed topics, for all of the above: by the key hash
//!   a writer sends, or computed from the payload when it sends none, and
//!   named alike when writers of one topic write different XCDR versions
//!   ([`InstanceKeys`], [`Domain::set_instance_keys`]);
//! - the **4-byte payload padding** Cyclone DDS needs ([`pad`]);
//! - remote endpoints of another type on our topics ([`Event::TypeMismatch`]).
//!
//! # Request/reply
//!
//! A service reads `rq/<name>Request` and writes `rr/<name>Reply`; a client
//! the other way round. A request names the client's reply reader as its
//! related sample identity (as rmw_fastrtps clients do); the reply names
//! the request, so each client takes only the replies to its own queries.
//!
//! ```
//! use std::time::{Duration, Instant, SystemTime};
//! use courier_wire::dds::{Domain, Event, ServiceConfig};
//! use courier_wire::rtps::participant::{guid_prefix, Config};
//!
//! let now = Instant::now();
//! let cfg = Config::udpv4(0, 0, guid_prefix([1; 10]), [127, 0, 0, 1]).unwrap();
//! let mut d = Domain::new(cfg, now, SystemTime::UNIX_EPOCH);
//! let svc = ServiceConfig::new("add", "AddRequest", "AddReply");
//! let s = d.create_service(&svc, now).unwrap();
//! let c = d.create_client(&svc, now).unwrap();
//! // service and client of one domain match in process
//! let q = d.query(c, vec![0, 1, 0, 0, 2, 0, 0, 0], Duration::from_secs(1), now).unwrap();
//! let mut reply = None;
//! while let Some(e) = d.poll_event() {
//!     match e {
//!         Event::Request { service, request, .. } => {
//!             assert_eq!(service, s);
//!             d.reply(service, request, vec![0, 1, 0, 0, 4, 0, 0, 0], now).unwrap();
//!         }
//!         Event::Reply { client, query, sample } => reply = Some((client, query, sample)),
//!         _ => {}
//!     }
//! }
//! let (client, query, sample) = reply.unwrap();
//! assert_eq!((client, query), (c, q));
//! assert_eq!(sample.data(), [0, 1, 0, 0, 4, 0, 0, 0]);
//! ```

mod deadline;
mod event;
mod handles;
mod instances;
mod liveliness;
mod pattern;
mod reader;
mod request_header;
mod rpc;
mod writer;

use std::collections::{BTreeMap, VecDeque};

use foldhash::{HashMap, HashMapExt};
use std::time::{Duration, Instant, SystemTime};

use crate::rtps::participant::{self, Config, Datagram, Participant, Transmission};
use crate::rtps::{Guid, Locator};

pub use event::{ConfirmFailure, DropReason, Event, QueryFailure};
pub use handles::{
    ClientId, Endpoint, PatternId, QueryId, ReaderId, RequestId, ServiceId, WriterId,
};
pub use instances::{InstanceKeys, MAX_KEY_HASH_ALIASES};
pub use pattern::fnmatch;
pub use request_header::{RequestHeader, RpcStyle};
pub use rpc::{reply_topic, request_topic, ServiceConfig};
pub use writer::pad;

/// What a local endpoint of the participant is for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Role {
    User,
    Pattern(PatternId),
    Service(ServiceId),
    Client(ClientId),
}

/// How often writers blocked on a full history are looked at again (besides
/// acknowledgements and readers leaving, which are looked at at once).
const HOUSEKEEPING: Duration = Duration::from_millis(200);

/// A sans-I/O DDS domain participant. See the [module docs](self).
pub struct Domain {
    p: Participant,
    start: Instant,
    wall_start: SystemTime,
    writers: HashMap<Guid, writer::LocalWriter>,
    readers: HashMap<Guid, reader::LocalReader>,
    /// Strength and lifespan of every writer known (remote and local).
    writer_info: HashMap<Guid, reader::WriterInfo>,
    confirms: Vec<writer::Confirm>,
    /// Keep-all readers whose shell queue is full.
    full: Vec<Guid>,
    patterns: BTreeMap<PatternId, pattern::Pattern>,
    services: BTreeMap<ServiceId, rpc::Service>,
    clients: BTreeMap<ClientId, rpc::Client>,
    waiting: Vec<rpc::Waiting>,
    inflight: HashMap<handles::RequestKey, rpc::Inflight>,
    /// Sent queries cancelled lately ([`Domain::cancel_queries`]): their
    /// replies are dropped, not counted as answering no query.
    cancelled: VecDeque<handles::RequestKey>,
    next_id: u64,
    next_housekeeping: Instant,
    events: VecDeque<Event>,
    liveliness: liveliness::Liveliness,
}

impl std::fmt::Debug for Domain {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Domain")
            .field("participant", &self.p)
            .field("writers", &self.writers.len())
            .field("readers", &self.readers.len())
            .field("services", &self.services.len())
            .field("clients", &self.clients.len())
            .finish()
    }
}

impl Domain {
    /// A domain participant with `config`; `wall_clock` is the wall-clock
    /// time at `now` (source timestamps sent and the lifespan of those
    /// received are reckoned from it and later `now`s).
    pub fn new(config: Config, now: Instant, wall_clock: SystemTime) -> Self {
        Domain {
            p: Participant::new(config, now, wall_clock),
            start: now,
            wall_start: wall_clock,
            writers: HashMap::new(),
            readers: HashMap::new(),
            writer_info: HashMap::new(),
            confirms: Vec::new(),
            full: Vec::new(),
            patterns: BTreeMap::new(),
            services: BTreeMap::new(),
            clients: BTreeMap::new(),
            waiting: Vec::new(),
            inflight: HashMap::new(),
            cancelled: VecDeque::new(),
            next_id: 1,
            next_housekeeping: now + HOUSEKEEPING,
            events: VecDeque::new(),
            liveliness: liveliness::Liveliness::default(),
        }
    }

    /// The RTPS participant, to look at (discovery data, matches, counters).
    pub fn participant(&self) -> &Participant {
        &self.p
    }

    /// The topic and type name of this domain's writer or reader `guid`
    /// (of any kind: plain, of a pattern, service or client).
    pub fn local_endpoint(&self, guid: Guid) -> Option<(&str, &str)> {
        match self.writers.get(&guid) {
            Some(w) => Some((&w.topic, &w.type_name)),
            None => self
                .readers
                .get(&guid)
                .map(|r| (r.topic.as_str(), r.type_name.as_str())),
        }
    }

    /// The next datagram to send.
    pub fn poll_transmit(&mut self) -> Option<Datagram> {
        self.p.poll_transmit()
    }

    /// The next datagram to send, large sample data by reference
    /// ([`Participant::poll_transmission`]).
    pub fn poll_transmission(&mut self) -> Option<Transmission> {
        self.p.poll_transmission()
    }

    /// The next event.
    pub fn poll_event(&mut self) -> Option<Event> {
        self.events.pop_front()
    }

    /// When [`Domain::handle_timeout`] must be called next.
    pub fn poll_timeout(&self) -> Option<Instant> {
        let deadlines = self.readers.values().filter_map(|r| r.next_due());
        [
            self.p.poll_timeout(),
            self.next_confirm_deadline(),
            self.next_query_deadline(),
            self.next_offered_deadline(),
            self.next_liveliness_due(),
            self.any_blocked().then_some(self.next_housekeeping),
        ]
        .into_iter()
        .flatten()
        .chain(deadlines)
        .min()
    }

    /// Fires what is due at `now`: the participant's timers, missed
    /// deadlines, confirmations and queries that ran out of time.
    pub fn handle_timeout(&mut self, now: Instant) {
        if self.p.poll_timeout().is_some_and(|t| t <= now) {
            self.p.handle_timeout(now);
        }
        self.drain(now);
        self.expire_confirms(now);
        self.check_deadlines(now);
        self.check_offered_deadlines(now);
        self.check_liveliness(now);
        self.expire_queries(now);
        if now >= self.next_housekeeping {
            self.next_housekeeping = now + HOUSEKEEPING;
            let blocked: Vec<Guid> = self.writers.keys().copied().collect();
            for w in blocked {
                self.check_writable(w);
            }
        }
    }

    /// A datagram arrived from `source` at `now` (any bytes: what does not
    /// parse is counted by the participant and ignored).
    pub fn handle_datagram(&mut self, source: Locator, datagram: &[u8], now: Instant) {
        self.p.handle_datagram(source, datagram, now);
        self.drain(now);
        self.check_liveliness(now);
    }

    /// Hands back a received sample's buffer for reuse ([`Participant::recycle`]).
    pub fn recycle(&mut self, buf: Vec<u8>) {
        self.p.recycle(buf);
    }

    /// Leaves the domain: every endpoint is disposed and the participant
    /// says goodbye (see [`Domain::poll_transmit`]). What waited on the
    /// domain (confirmations, queries) is dropped without an event: the
    /// shell fails its own waiters.
    pub fn close(&mut self, now: Instant) {
        self.p.close(now);
        while self.p.poll_event().is_some() {}
        self.writers.clear();
        self.readers.clear();
        self.confirms.clear();
        self.full.clear();
        self.patterns.clear();
        self.services.clear();
        self.clients.clear();
        self.waiting.clear();
        self.inflight.clear();
    }

    fn next_id(&mut self) -> u64 {
        self.next_id += 1;
        self.next_id
    }

    /// Wall-clock time at `now`.
    fn wall(&self, now: Instant) -> SystemTime {
        self.wall_start + now.saturating_duration_since(self.start)
    }

    /// Acts on everything the participant reported.
    fn drain(&mut self, now: Instant) {
        use participant::Event as P;
        while let Some(e) = self.p.poll_event() {
            match e {
                P::SampleReceived(s) => match self.readers.get(&s.reader).map(|r| r.role) {
                    Some(Role::Service(id)) => self.on_request(id, s),
                    Some(Role::Client(id)) => self.on_reply(id, s),
                    Some(_) => self.deliver(s, now),
                    None => {}
                },
                P::SampleLost {
                    reader,
                    writer,
                    size,
                    limit,
                    ..
                } => {
                    if self.readers.contains_key(&reader) {
                        self.events.push_back(Event::SampleLost {
                            reader: ReaderId(reader),
                            writer,
                            size,
                            limit,
                        });
                    }
                }
                P::AckedByAll { writer, .. } => self.acks_changed(writer),
                P::WriterMatched { writer, reader } => {
                    match self.writers.get(&writer).map(|w| w.role) {
                        Some(Role::User) => self.events.push_back(Event::WriterMatched {
                            writer: WriterId(writer),
                            reader,
                        }),
                        Some(Role::Client(_)) => self.send_waiting(now),
                        _ => {}
                    }
                }
                P::WriterUnmatched { writer, reader } => {
                    match self.writers.get(&writer).map(|w| w.role) {
                        Some(Role::User) => self.events.push_back(Event::WriterUnmatched {
                            writer: WriterId(writer),
                            reader,
                        }),
                        Some(Role::Client(c)) => self.client_unmatched(c),
                        _ => {}
                    }
                    // a reader that left may have been what held the history
                    self.acks_changed(writer);
                }
                P::ReaderMatched { reader, writer } => {
                    self.lively_matched(reader, writer, now);
                    match self.readers.get(&reader).map(|r| r.role) {
                        Some(Role::User | Role::Pattern(_)) => {
                            self.events.push_back(Event::ReaderMatched {
                                reader: ReaderId(reader),
                                writer,
                            })
                        }
                        Some(Role::Client(_)) => self.send_waiting(now),
                        _ => {}
                    }
                }
                P::ReaderUnmatched { reader, writer } => {
                    self.lively_unmatched(reader, writer);
                    // deleted (its participant still here, it not):
                    // disposed, if its readers are to dispose it; lost or
                    // unmatched by a QoS change: without writers
                    let deleted = self.p.participant(writer.prefix).is_some()
                        && self.p.publication(writer).is_none();
                    let dispose = deleted
                        && self
                            .writer_info
                            .get(&writer)
                            .is_some_and(|i| i.disposes_when_deleted);
                    self.writer_left_reader(reader, writer, dispose);
                    if let Some(r) = self.readers.get_mut(&reader) {
                        if matches!(r.role, Role::User | Role::Pattern(_)) {
                            self.events.push_back(Event::ReaderUnmatched {
                                reader: ReaderId(reader),
                                writer,
                            });
                        }
                        if let Role::Client(c) = r.role {
                            self.client_unmatched(c);
                        }
                    }
                }
                P::IncompatibleQos {
                    local,
                    remote,
                    reason,
                } => {
                    let found = if let Some(r) = self.readers.get(&local) {
                        Some((r.topic.clone(), self.endpoint(local, r.role, false)))
                    } else {
                        self.writers
                            .get(&local)
                            .map(|w| (w.topic.clone(), self.endpoint(local, w.role, true)))
                    };
                    // another type name is reported as a type mismatch,
                    // with both names, when either endpoint appears
                    let typed = matches!(reason, crate::rtps::matching::Incompatible::Type { .. });
                    if let (Some((topic, local)), false) = (found, typed) {
                        self.events.push_back(Event::IncompatibleQos {
                            local,
                            topic,
                            remote,
                            reason,
                        });
                    }
                }
                P::PublicationFound(d) => {
                    self.writer_info
                        .insert(d.guid, reader::WriterInfo::of_remote(&d));
                    let ours: Vec<Guid> = self
                        .readers
                        .iter()
                        .filter(|(_, r)| {
                            r.topic == d.topic_name
                                && r.type_name != d.type_name
                                && !matches!(r.role, Role::Pattern(_))
                        })
                        .map(|(g, _)| *g)
                        .collect();
                    for g in ours {
                        self.type_mismatch(g, d.guid, d.type_name.clone());
                    }
                    let offer = pattern::Offer::of(&d);
                    self.offer_to_patterns(&d.topic_name, &d.type_name, &offer, d.guid, now);
                    self.events
                        .push_back(Event::Discovery(P::PublicationFound(d)));
                }
                P::PublicationChanged(d) => {
                    self.writer_info
                        .insert(d.guid, reader::WriterInfo::of_remote(&d));
                    self.events
                        .push_back(Event::Discovery(P::PublicationChanged(d)));
                }
                P::PublicationLost(g) => {
                    self.writer_info.remove(&g);
                    self.withdraw_from_patterns(g, now);
                    self.events
                        .push_back(Event::Discovery(P::PublicationLost(g)));
                }
                P::SubscriptionFound(d) => {
                    let ours: Vec<Guid> = self
                        .writers
                        .iter()
                        .filter(|(_, w)| w.topic == d.topic_name && w.type_name != d.type_name)
                        .map(|(g, _)| *g)
                        .collect();
                    for g in ours {
                        self.type_mismatch(g, d.guid, d.type_name.clone());
                    }
                    self.events
                        .push_back(Event::Discovery(P::SubscriptionFound(d)));
                }
                e => self.events.push_back(Event::Discovery(e)),
            }
        }
    }
}
