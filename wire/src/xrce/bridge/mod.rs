//! The XRCE agent's host, sans-I/O: every client's objects become
//! entities of ONE DDS [`Domain`], so what an XRCE client writes reaches
//! Cyclone DDS, Fast DDS, ROS 2 and Courier sessions, and what they write
//! comes back to the clients that read it.
//!
//! [`Bridge`] owns the [`Agent`] session machine and the [`Domain`]; a
//! shell feeds it XRCE messages ([`Bridge::handle_input`]), RTPS datagrams
//! ([`Bridge::handle_datagram`]) and time ([`Bridge::handle_timeout`]), and
//! sends what [`Bridge::poll_transmit`] (XRCE) and
//! [`Bridge::poll_datagram`] (RTPS) give. It reads no clock.
//!
//! How objects map:
//!
//! | XRCE object | in the Domain |
//! |---|---|
//! | participant | a grouping of the client's objects; its domain id must be the Domain's (unless [`BridgeConfig::any_domain`]) |
//! | topic | topic name, type name, keyed or not |
//! | publisher / subscriber | the partitions of its writers / readers |
//! | data writer | a Domain writer |
//! | data reader | a Domain reader, whose samples wait (keep-last its depth, keep-all up to [`BridgeConfig::reader_queue`]) until a READ_DATA delivers them |
//! | requester | a writer of the request topic and a reader of the reply topic; replies are matched to requests by their related sample identity |
//! | replier | a reader of the request topic and a writer of the reply topic; the client sees and echoes each request's sample identity |
//!
//! Objects come by binary representation, by XML (the Fast DDS subset of
//! [`from_xml`]) or by reference to a profile of the agent's references
//! file ([`Profiles`]). CREATE's mode flags behave as eProsima's agent
//! does: an existing object gives `ERR_ALREADY_EXISTS`; with REPLACE it is
//! deleted (with everything it contains) and created again; with REUSE it
//! is kept if its representation is the same (`OK_MATCHED`), else
//! `ERR_MISMATCH` (or, with REPLACE too, replaced). DELETE removes an
//! object and what it contains.
//!
//! # Where it differs from eProsima's agent on purpose
//! - **Nothing acknowledged is lost.** A reliable XRCE message is
//!   acknowledged only once DDS has taken every sample it carries. A
//!   writer whose keep-all history is full holds the sample (and the later
//!   ones of its stream) until the history has room; the client, its
//!   window full of unacknowledged messages, slows down. eProsima's agent
//!   acknowledges first and drops the rest of the message when a DDS write
//!   fails. A sample DDS refuses for good (larger than the writer can
//!   take) is counted in [`BridgeStats::writes_refused`] and reported
//!   as [`BridgeEvent::WriteRefused`], never silently.
//! - **One long-lived DDS participant** for all clients instead of one per
//!   client participant: a client's new writer matches readers the agent
//!   has long discovered, so its first sample is not lost to discovery.
//! - `min_pace_period` of READ_DATA is honoured (eProsima ignores it);
//!   `max_samples` 0 cancels delivery at once.
//! - Samples go to DDS with the CDR encapsulation `00 01 00 00` in front
//!   (as eProsima's agent), padded to 4 bytes with the pad count in the
//!   options (RTPS 2.3 §10.5); from DDS the 4-byte header and the padding
//!   it names are taken off.
//! - **A restart can be invisible.** [`Bridge::client_state`] says what to
//!   keep of a client (session, objects, READ_DATA; [`BridgeEvent::ClientChanged`]
//!   says when it changed) and [`Bridge::restore`] serves it again in a new
//!   bridge: the client, which knows nothing of the restart, goes on with
//!   its session. Its reliable input streams go on from the positions
//!   kept ([`ClientState::inputs`]), so a sample the client sends again
//!   because the old agent died before acknowledging it is not written
//!   twice; the other streams take its position from its first HEARTBEAT
//!   or ACKNACK ([`Agent::restore_client`]). A host that saves positions
//!   as they move has acknowledgements wait for the save
//!   ([`Bridge::hold_acks_until_saved`]). eProsima's agent forgets every
//!   session.
//! - TYPE, QOSPROFILE and APPLICATION objects are refused with `ERR_DENIED`.

mod profile;
mod read;

use std::collections::{BTreeMap, VecDeque};

// Looked up several times per sample, with keys the clients choose:
// foldhash is seeded per process and costs a fraction of SipHash.
use foldhash::{HashMap, HashMapExt, HashSet, HashSetExt};
use std::hash::Hash;
use std::time::{Duration, Instant, SystemTime};

use crate::dds::{Domain, Event as DdsEvent, ReaderId, WriterId};
use crate::rtps::discovery::{History, Reliability};
use crate::rtps::participant::{
    Change, ChangeKind, Datagram, EndpointConfig, SampleIdentity as RtpsIdentity, WriteError,
};
use crate::rtps::Locator;

use super::agent::{Agent, AgentCommandError, AgentConfig, AgentEvent, WriteTicket};
use super::binary::BinaryRepresentation;
use super::client::CreationMode;
use super::object::{ObjectVariant, Representation};
use super::session::{InputError, QueueError};
use super::stream::{SeqNum, StreamError};
use super::submessage::ReadData;
use super::types::{BaseObjectRequest, ClientKey, ObjectId, ObjectKind, StatusCode, StreamId};

pub use profile::{
    from_binary, from_xml, EndpointProfile, Profile, ProfileError, Profiles, ServiceProfile,
    TopicProfile,
};

/// Requests a requester remembers waiting for their replies; older ones
/// are forgotten (their replies, should they still come, are counted in
/// [`BridgeStats::replies_unmatched`]).
pub const MAX_INFLIGHT: usize = 4096;

/// How the bridge behaves.
#[derive(Debug, Clone)]
pub struct BridgeConfig {
    /// The XRCE side ([`AgentConfig::host_confirms_writes`] is always on).
    pub agent: AgentConfig,
    /// The Domain's DDS domain id: participants must name it.
    pub domain_id: u32,
    /// Take participants of any domain id into the one Domain.
    pub any_domain: bool,
    /// The references file's profiles (CREATE by reference).
    pub profiles: Profiles,
    /// Samples a keep-all reader keeps for its client at most (a keep-last
    /// reader keeps its depth). A reliable keep-all reader that holds this
    /// many makes the bridge's own reliable writers matched with it wait
    /// (and their clients with them); samples from remote DDS writers can
    /// take it to four times this, beyond which the oldest are dropped and
    /// counted.
    pub reader_queue: usize,
    /// Bytes a reader keeps for its client at most (the newest sample
    /// always): a reader whose client died without DELETE would otherwise
    /// hold `reader_queue` samples of any size. A reliable keep-all reader
    /// holds the bridge's writers back at a quarter of it.
    pub reader_bytes: usize,
    /// Bytes of object representations (XML, binary, reference names) a
    /// client's objects may hold in all, each counted with
    /// [`OBJECT_OVERHEAD`] (default 1 MiB: 500 entities of 2 KB of XML).
    /// A CREATE beyond it is refused with `ERR_RESOURCES`. Without it a
    /// client held whatever it created: 4000 topics with 60 KB names took
    /// an agent past 1 GB.
    pub max_object_bytes: usize,
}

/// What an object costs beyond its representation, for
/// [`BridgeConfig::max_object_bytes`].
pub const OBJECT_OVERHEAD: usize = 256;

impl Default for BridgeConfig {
    fn default() -> Self {
        BridgeConfig {
            agent: AgentConfig::default(),
            domain_id: 0,
            any_domain: false,
            profiles: Profiles::new(),
            reader_queue: 1024,
            reader_bytes: 16 << 20,
            max_object_bytes: 1 << 20,
        }
    }
}

/// What happened, for the shell's log.
#[derive(Debug, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub enum BridgeEvent {
    /// A session was created (`kept`: again, objects kept).
    ClientCreated {
        /// The client.
        client: ClientKey,
        /// Its session id.
        session_id: u8,
        /// Whether its objects were kept.
        kept: bool,
    },
    /// A session ended; its objects are gone.
    ClientDeleted {
        /// The client.
        client: ClientKey,
    },
    /// A session is deleted for its client's silence (see
    /// [`AgentEvent::ClientExpired`]); [`BridgeEvent::ClientDeleted`] follows.
    ClientExpired {
        /// The client.
        client: ClientKey,
        /// How long it had been silent.
        silent: std::time::Duration,
        /// The client it made room for (`None`: timed out).
        for_client: Option<ClientKey>,
    },
    /// A CREATE_CLIENT was refused.
    ClientRefused {
        /// The client.
        client: ClientKey,
        /// The answer.
        status: StatusCode,
    },
    /// A CREATE was answered.
    Created {
        /// The client.
        client: ClientKey,
        /// The object.
        object: ObjectId,
        /// The answer.
        status: StatusCode,
        /// Why, when it is an error.
        reason: Option<String>,
    },
    /// What [`Bridge::client_state`] gives for this client changed (a
    /// session created again, an object created or deleted, a READ_DATA
    /// started): a shell that keeps state saves it again. After
    /// [`BridgeEvent::ClientDeleted`] there is nothing to keep.
    ClientChanged {
        /// The client.
        client: ClientKey,
    },
    /// A DELETE was answered.
    Deleted {
        /// The client.
        client: ClientKey,
        /// The object.
        object: ObjectId,
        /// The answer.
        status: StatusCode,
    },
    /// An entity of a client does not match a DDS endpoint on its topic
    /// (another type name, or incompatible QoS): why its data does not flow.
    Unmatched {
        /// The client.
        client: ClientKey,
        /// Its writer, reader, requester or replier.
        object: ObjectId,
        /// What differs.
        why: String,
    },
    /// A sample for a best-effort reading is larger than the client's
    /// best-effort stream carries (its MTU; only reliable streams
    /// fragment): dropped and counted (`samples_dropped`). Reported once
    /// per reader.
    SampleTooLarge {
        /// The client.
        client: ClientKey,
        /// The reader (or requester, replier).
        object: ObjectId,
        /// The sample's submessage size.
        len: usize,
        /// The largest the stream carries.
        max: usize,
    },
    /// DDS refused a written sample for good (not for lack of room).
    WriteRefused {
        /// The client.
        client: ClientKey,
        /// The writer, requester or replier.
        object: ObjectId,
        /// Why.
        reason: String,
    },
}

/// Counters.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct BridgeStats {
    /// Samples written into DDS.
    pub writes: u64,
    /// Samples DDS refused for good ([`BridgeEvent::WriteRefused`]).
    pub writes_refused: u64,
    /// Best-effort samples dropped because the writer's history was full.
    pub writes_dropped: u64,
    /// WRITE_DATA to an object that is not a writer, requester or replier
    /// (each answered with `ERR_UNKNOWN_REFERENCE`).
    pub writes_unknown: u64,
    /// Samples delivered to clients.
    pub samples_sent: u64,
    /// Samples dropped on the way to a client: a reader's queue was full,
    /// or a best-effort sample did not fit the client's MTU.
    pub samples_dropped: u64,
    /// Replies for a requester that matched none of its requests.
    pub replies_unmatched: u64,
}

/// A write waiting for room in its writer's history.
#[derive(Debug, Clone)]
struct Held {
    data: Vec<u8>,
    related: Option<RtpsIdentity>,
    request: BaseObjectRequest,
    ticket: Option<WriteTicket>,
}

#[derive(Debug, Clone)]
struct Output {
    writer: WriterId,
    held: VecDeque<Held>,
}

#[derive(Debug, Clone)]
enum Entity {
    Participant,
    Topic(TopicProfile),
    Group(Vec<String>),
    Writer(Output),
    Reader(ReaderId, read::Inbox),
    Requester {
        out: Output,
        reader: ReaderId,
        inbox: read::Inbox,
        /// DDS sequence number of each request → its XRCE request; the
        /// oldest are forgotten beyond [`MAX_INFLIGHT`] (replies that never
        /// came).
        inflight: BTreeMap<i64, BaseObjectRequest>,
    },
    Replier {
        out: Output,
        reader: ReaderId,
        inbox: read::Inbox,
    },
}

#[derive(Debug, Clone)]
struct Object {
    parent: Option<ObjectId>,
    variant: ObjectVariant,
    entity: Entity,
    /// Creation order, for restoring.
    order: u64,
}

/// What the bridge keeps of a client so that a restarted agent serves it
/// again ([`Bridge::client_state`], [`Bridge::restore`]): its session, its
/// objects in creation order, the READ_DATA being served and the positions
/// of its reliable input streams (the last message of each whose samples
/// DDS has taken). Output stream positions are not kept (see
/// [`Agent::restore_client`]).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ClientState<A> {
    /// The client.
    pub client: ClientKey,
    /// Its session id.
    pub session_id: u8,
    /// The MTU its messages are cut to.
    pub mtu: u16,
    /// Where its messages go.
    pub addr: A,
    /// Its objects, in the order they were created.
    pub objects: Vec<(ObjectId, ObjectVariant)>,
    /// The READ_DATA being served.
    pub reads: Vec<ReadData>,
    /// Per reliable input stream, the last message whose every sample DDS
    /// took: what the client sends again up to it after a restart is not
    /// written a second time ([`Agent::restore_positions`]). These move
    /// with every sample: [`Bridge::take_moved_positions`] says when.
    pub inputs: Vec<(StreamId, SeqNum)>,
}

type Key = (ClientKey, ObjectId);

/// How long a restored bridge holds its clients' writes: its DDS
/// participant and writers are new, and a sample written before a remote
/// reader is matched again is lost to it (volatile) although the client
/// had it acknowledged. The clients, unacknowledged meanwhile, keep their
/// samples and resend them. Discovery on one host takes tens of
/// milliseconds; across a network, a few SPDP periods.
pub const REDISCOVERY: Duration = Duration::from_secs(1);

/// The agent's host over one Domain. See the [module docs](self).
pub struct Bridge<A> {
    agent: Agent<A>,
    domain: Domain,
    cfg: BridgeConfig,
    objects: HashMap<Key, Object>,
    /// Bytes each client's objects hold ([`BridgeConfig::max_object_bytes`]).
    object_bytes: HashMap<ClientKey, usize>,
    by_reader: HashMap<ReaderId, Key>,
    by_writer: HashMap<WriterId, Key>,
    /// Inboxes that may have something to deliver (samples and a
    /// READ_DATA): the only ones looked at after an input, so that the work
    /// per message does not grow with the number of objects.
    ready: HashSet<Key>,
    /// Reliable keep-all inboxes at their cap: the bridge's reliable
    /// writers matched with one hold their samples (and so the client's
    /// XRCE window) until it drains to half (KEEP_ALL back-pressure between
    /// two clients of this agent, where DDS has no acknowledgement to
    /// withhold). Nearly always empty.
    full: Vec<Key>,
    /// After a restore: until then writes wait, so that the new
    /// participant rediscovers the remote readers first ([`REDISCOVERY`]).
    rediscovery: Option<Instant>,
    /// Writers whose XRCE entity is gone, kept until their readers
    /// acknowledged what DDS took (or [`WRITER_LINGER`] passed), as a DDS
    /// application's deleted writer lingers: what the agent acknowledged
    /// to its client must still reach them.
    lingering: Vec<(WriterId, Instant)>,
    order: u64,
    events: VecDeque<BridgeEvent>,
    stats: BridgeStats,
    now: Instant,
}

/// How long a writer whose XRCE entity is gone waits for its readers'
/// acknowledgements (Cyclone DDS's writer linger).
pub const WRITER_LINGER: Duration = Duration::from_secs(1);

impl<A> std::fmt::Debug for Bridge<A> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Bridge")
            .field("domain", &self.domain)
            .field("objects", &self.objects.len())
            .field("stats", &self.stats)
            .finish()
    }
}

fn output_of(objects: &mut HashMap<Key, Object>, key: Key) -> Option<&mut Output> {
    match &mut objects.get_mut(&key)?.entity {
        Entity::Writer(out) | Entity::Requester { out, .. } | Entity::Replier { out, .. } => {
            Some(out)
        }
        _ => None,
    }
}

/// The CDR encapsulation in front of a sample, padded to 4 with the pad
/// count in the options.
fn encapsulate(body: &[u8]) -> Vec<u8> {
    let pad = (4 - body.len() % 4) % 4;
    let mut v = Vec::with_capacity(4 + body.len() + pad + 8);
    v.extend_from_slice(&[0x00, 0x01, 0x00, pad as u8]);
    v.extend_from_slice(body);
    v.resize(4 + body.len() + pad, 0);
    v
}

/// A sample's body: without its encapsulation header and the padding the
/// header's options name.
fn body(mut data: Vec<u8>) -> Vec<u8> {
    if data.len() < 4 {
        return Vec::new();
    }
    let pad = usize::from(data[3] & 0x03);
    let end = data.len().saturating_sub(pad).max(4);
    data.truncate(end);
    data.drain(..4);
    data
}

fn identity_bytes(id: RtpsIdentity) -> [u8; 24] {
    id.to_bytes(true)
}

fn inbox_cap(cfg: &BridgeConfig, qos: &crate::rtps::discovery::EndpointQos) -> usize {
    match qos.history {
        History::KeepLast(n) => usize::try_from(n).unwrap_or(1).clamp(1, cfg.reader_queue),
        History::KeepAll => cfg.reader_queue,
    }
}

impl<A: Clone + Eq + Hash> Bridge<A> {
    /// A bridge over `domain`; `wall` is the wall-clock time at `now`.
    pub fn new(mut cfg: BridgeConfig, domain: Domain, now: Instant, wall: SystemTime) -> Self {
        cfg.agent.host_confirms_writes = true;
        Bridge {
            agent: Agent::new(cfg.agent.clone(), now, wall),
            domain,
            cfg,
            objects: HashMap::new(),
            object_bytes: HashMap::new(),
            by_reader: HashMap::new(),
            by_writer: HashMap::new(),
            ready: HashSet::new(),
            full: Vec::new(),
            rediscovery: None,
            lingering: Vec::new(),
            order: 0,
            events: VecDeque::new(),
            stats: BridgeStats::default(),
            now,
        }
    }

    /// The XRCE session machine.
    pub fn agent(&self) -> &Agent<A> {
        &self.agent
    }

    /// The DDS domain.
    pub fn domain(&self) -> &Domain {
        &self.domain
    }

    /// The counters.
    pub fn stats(&self) -> BridgeStats {
        self.stats
    }

    /// Objects of every client.
    pub fn object_count(&self) -> usize {
        self.objects.len()
    }

    /// Replaces the references (a reloaded file); objects already made stay.
    pub fn set_profiles(&mut self, profiles: Profiles) {
        self.cfg.profiles = profiles;
    }

    fn tick(&mut self, now: Instant) -> Instant {
        self.now = self.now.max(now);
        self.now
    }

    /// An XRCE message from `from`.
    pub fn handle_input(&mut self, from: A, bytes: &[u8], now: Instant) -> Result<(), InputError> {
        let now = self.tick(now);
        let r = self.agent.handle_input(from, bytes, now);
        self.process(now);
        r
    }

    /// An RTPS datagram from `source`.
    pub fn handle_datagram(&mut self, source: Locator, bytes: &[u8], now: Instant) {
        let now = self.tick(now);
        self.domain.handle_datagram(source, bytes, now);
        self.delete_lingering(now);
        self.process(now);
    }

    /// Time passed.
    pub fn handle_timeout(&mut self, now: Instant) {
        let now = self.tick(now);
        if self.agent.poll_timeout().is_some_and(|t| t <= now) {
            self.agent.handle_timeout(now);
        }
        if self.domain.poll_timeout().is_some_and(|t| t <= now) {
            self.domain.handle_timeout(now);
        }
        if self.rediscovery.is_some_and(|t| t <= now) {
            self.rediscovery = None;
            self.flush_held(now);
        }
        // writers held by a full reader: go on if its client now seems dead
        self.release_full(now);
        self.delete_lingering(now);
        self.process(now);
    }

    /// When [`handle_timeout`](Self::handle_timeout) is next needed.
    pub fn poll_timeout(&self) -> Option<Instant> {
        let inboxes = self
            .ready
            .iter()
            .filter_map(|k| match &self.objects.get(k)?.entity {
                Entity::Reader(_, i)
                | Entity::Requester { inbox: i, .. }
                | Entity::Replier { inbox: i, .. } => i.poll_timeout(),
                _ => None,
            });
        // while writers are held, a look each second (see `release_full`)
        let held = (!self.full.is_empty()).then(|| self.now + Duration::from_secs(1));
        [
            self.agent.poll_timeout(),
            self.domain.poll_timeout(),
            self.rediscovery,
            held,
            self.lingering.iter().map(|(_, until)| *until).min(),
        ]
        .into_iter()
        .flatten()
        .chain(inboxes)
        .min()
    }

    /// The next XRCE message: destination and bytes.
    pub fn poll_transmit(&mut self) -> Option<(A, Vec<u8>)> {
        self.agent.poll_transmit()
    }

    /// The next RTPS datagram.
    pub fn poll_datagram(&mut self) -> Option<Datagram> {
        self.domain.poll_transmit()
    }

    /// The next event for the log.
    pub fn poll_event(&mut self) -> Option<BridgeEvent> {
        self.events.pop_front()
    }

    /// Leaves the DDS domain (every entity disposed, the participant says
    /// goodbye: send what [`poll_datagram`](Self::poll_datagram) gives).
    pub fn close(&mut self, now: Instant) {
        self.lingering.clear();
        self.domain.close(now);
        self.objects.clear();
        self.object_bytes.clear();
        self.by_reader.clear();
        self.by_writer.clear();
    }

    /// Acts on what both machines reported until neither has more, then
    /// delivers what READ_DATAs allow.
    fn process(&mut self, now: Instant) {
        loop {
            loop {
                let mut any = false;
                while let Some(e) = self.agent.poll_event() {
                    any = true;
                    self.on_agent(e, now);
                }
                while let Some(e) = self.domain.poll_event() {
                    any = true;
                    self.on_dds(e, now);
                }
                if !any {
                    break;
                }
            }
            self.deliver_all(now);
            if !self.release_full(now) {
                break;
            }
        }
    }

    /// Forgets the full inboxes that drained (or are gone) and lets the
    /// writers they held write again; whether there were any.
    fn release_full(&mut self, now: Instant) -> bool {
        if self.full.is_empty() {
            return false;
        }
        let objects = &self.objects;
        let agent = &self.agent;
        let before = self.full.len();
        // (a reader whose client seems dead holds no writer back: one dead
        // subscriber would stop its topic's writers for good)
        self.full
            .retain(|key| match objects.get(key).map(|o| &o.entity) {
                Some(Entity::Reader(_, i)) => !i.has_room() && !agent.seems_dead(key.0, now),
                _ => false,
            });
        if self.full.len() == before {
            return false;
        }
        self.flush_held(now);
        true
    }

    /// Writes what every output holds, as far as it can.
    fn flush_held(&mut self, now: Instant) {
        let held: Vec<Key> = self
            .objects
            .iter()
            .filter(|(_, o)| match &o.entity {
                Entity::Writer(out)
                | Entity::Requester { out, .. }
                | Entity::Replier { out, .. } => !out.held.is_empty(),
                _ => false,
            })
            .map(|(k, _)| *k)
            .collect();
        for key in held {
            self.flush(key, now);
        }
    }

    fn on_agent(&mut self, e: AgentEvent, now: Instant) {
        match e {
            AgentEvent::ClientCreated {
                client,
                session_id,
                kept,
                ..
            } => {
                if !kept {
                    self.drop_client(client, now);
                }
                self.events.push_back(BridgeEvent::ClientCreated {
                    client,
                    session_id,
                    kept,
                });
                self.events.push_back(BridgeEvent::ClientChanged { client });
            }
            AgentEvent::ClientDeleted { client } => {
                self.drop_client(client, now);
                self.events.push_back(BridgeEvent::ClientDeleted { client });
            }
            AgentEvent::ClientExpired {
                client,
                silent,
                for_client,
            } => self.events.push_back(BridgeEvent::ClientExpired {
                client,
                silent,
                for_client,
            }),
            AgentEvent::ClientRefused { client, status } => self
                .events
                .push_back(BridgeEvent::ClientRefused { client, status }),
            AgentEvent::Create {
                client,
                request,
                object,
                mode,
                reply_stream,
            } => {
                let id = ObjectId::new(request.object_id.id(), object.kind());
                let (status, reason) = match self.create(client, id, object, mode, now) {
                    Ok(s) => (s, None),
                    Err((s, why)) => (s, Some(why)),
                };
                let _ = self
                    .agent
                    .reply_status(client, request, status, reply_stream, now);
                let changed = reason.is_none();
                self.events.push_back(BridgeEvent::Created {
                    client,
                    object: id,
                    status,
                    reason,
                });
                if changed {
                    self.events.push_back(BridgeEvent::ClientChanged { client });
                }
            }
            AgentEvent::Delete {
                client,
                request,
                reply_stream,
            } => {
                let status = if self.objects.contains_key(&(client, request.object_id)) {
                    self.remove(client, request.object_id, now);
                    StatusCode::OK
                } else {
                    StatusCode::ERR_UNKNOWN_REFERENCE
                };
                let _ = self
                    .agent
                    .reply_status(client, request, status, reply_stream, now);
                self.events.push_back(BridgeEvent::Deleted {
                    client,
                    object: request.object_id,
                    status,
                });
                if status == StatusCode::OK {
                    self.events.push_back(BridgeEvent::ClientChanged { client });
                }
            }
            AgentEvent::Write {
                client,
                request,
                data,
                ticket,
            } => self.write(client, request, data, ticket, now),
            AgentEvent::Read { client, read } => self.read(client, read, now),
        }
    }

    fn on_dds(&mut self, e: DdsEvent, now: Instant) {
        match e {
            DdsEvent::Sample { reader, sample } => {
                let Some(&key) = self.by_reader.get(&reader) else {
                    return;
                };
                if sample.kind != ChangeKind::Alive {
                    return;
                }
                let related = sample.related_sample_identity;
                let identity = sample.identity();
                let data = body(sample.into_data());
                let Some(o) = self.objects.get_mut(&key) else {
                    return;
                };
                let (inbox, item) = match &mut o.entity {
                    Entity::Reader(_, inbox) => (inbox, data),
                    Entity::Replier { inbox, .. } => {
                        let mut v = identity_bytes(identity).to_vec();
                        v.extend_from_slice(&data);
                        (inbox, v)
                    }
                    Entity::Requester {
                        inbox,
                        inflight,
                        out,
                        ..
                    } => {
                        let request = related
                            .filter(|r| r.writer == out.writer.guid())
                            .and_then(|r| inflight.remove(&r.sequence_number.0));
                        let Some(request) = request else {
                            self.stats.replies_unmatched += 1;
                            return;
                        };
                        let mut v = Vec::with_capacity(4 + data.len());
                        v.extend_from_slice(&request.request_id.0.to_be_bytes());
                        v.extend_from_slice(&request.object_id.to_bytes());
                        v.extend_from_slice(&data);
                        (inbox, v)
                    }
                    _ => return,
                };
                if inbox.push(item) {
                    self.stats.samples_dropped += 1;
                }
                if inbox.is_full() && !self.full.contains(&key) {
                    self.full.push(key);
                }
                self.ready.insert(key);
            }
            DdsEvent::Writable { writer } => {
                if let Some(&key) = self.by_writer.get(&writer) {
                    self.flush(key, now);
                }
            }
            DdsEvent::TypeMismatch {
                local,
                remote,
                topic,
                local_type,
                remote_type,
            } => {
                if let Some(key) = self.key_of(local) {
                    self.events.push_back(BridgeEvent::Unmatched {
                        client: key.0,
                        object: key.1,
                        why: format!(
                            "topic {topic:?}: type {local_type:?} here, {remote_type:?} at {remote:?}"
                        ),
                    });
                }
            }
            DdsEvent::IncompatibleQos {
                local,
                topic,
                remote,
                reason,
            } => {
                if let Some(key) = self.key_of(local) {
                    self.events.push_back(BridgeEvent::Unmatched {
                        client: key.0,
                        object: key.1,
                        why: format!("topic {topic:?}: QoS incompatible with {remote:?}: {reason}"),
                    });
                }
            }
            _ => {}
        }
    }

    fn key_of(&self, e: crate::dds::Endpoint) -> Option<Key> {
        match e {
            crate::dds::Endpoint::Writer(w) => self.by_writer.get(&w).copied(),
            crate::dds::Endpoint::Reader(r) => self.by_reader.get(&r).copied(),
            _ => None,
        }
    }

    /// Drops every object of `client`.
    fn drop_client(&mut self, client: ClientKey, now: Instant) {
        let ids: Vec<ObjectId> = self
            .objects
            .keys()
            .filter(|k| k.0 == client)
            .map(|k| k.1)
            .collect();
        for id in ids {
            self.remove(client, id, now);
        }
    }

    /// Removes an object and what it contains.
    fn remove(&mut self, client: ClientKey, id: ObjectId, now: Instant) {
        let Some(o) = self.objects.remove(&(client, id)) else {
            return;
        };
        if let Some(b) = self.object_bytes.get_mut(&client) {
            *b = b.saturating_sub(o.variant.representation_len() + OBJECT_OVERHEAD);
            if *b == 0 {
                self.object_bytes.remove(&client);
            }
        }
        let children: Vec<ObjectId> = self
            .objects
            .iter()
            .filter(|(k, c)| k.0 == client && c.parent == Some(id))
            .map(|(k, _)| k.1)
            .collect();
        for c in children {
            self.remove(client, c, now);
        }
        match o.entity {
            Entity::Writer(out) => self.drop_output(out, now),
            Entity::Reader(r, _) => {
                self.by_reader.remove(&r);
                self.domain.delete_reader(r, now);
            }
            Entity::Requester { out, reader, .. } | Entity::Replier { out, reader, .. } => {
                self.drop_output(out, now);
                self.by_reader.remove(&reader);
                self.domain.delete_reader(reader, now);
            }
            _ => {}
        }
    }

    /// Deletes the lingering writers that are done: acknowledged by all
    /// their readers, or out of time.
    fn delete_lingering(&mut self, now: Instant) {
        if self.lingering.is_empty() {
            return;
        }
        let domain = &mut self.domain;
        self.lingering.retain(|(w, until)| {
            let done = now >= *until || domain.participant().is_all_acked(w.guid());
            if done {
                domain.delete_writer(*w, now);
            }
            !done
        });
    }

    /// Deletes a writer; writes it still held are given up (the client
    /// deleted where they were going).
    fn drop_output(&mut self, out: Output, now: Instant) {
        self.by_writer.remove(&out.writer);
        if self.domain.participant().is_all_acked(out.writer.guid()) {
            self.domain.delete_writer(out.writer, now);
        } else {
            self.lingering
                .push((out.writer, crate::time::later(now, WRITER_LINGER)));
        }
        for h in out.held {
            if let Some(t) = h.ticket {
                self.agent.write_done(t, now);
            }
        }
    }

    fn profile(
        &self,
        kind: ObjectKind,
        rep: &Representation,
    ) -> Result<Profile, (StatusCode, String)> {
        match rep {
            Representation::Reference(name) => self
                .cfg
                .profiles
                .get(kind, name)
                .cloned()
                .map_err(|e| (StatusCode::ERR_UNKNOWN_REFERENCE, e.to_string())),
            Representation::Xml(xml) => {
                from_xml(kind, xml).map_err(|e| (StatusCode::ERR_INVALID_DATA, e.to_string()))
            }
            Representation::Binary(blob) => BinaryRepresentation::decode(kind, blob)
                .map(|b| from_binary(&b))
                .map_err(|e| (StatusCode::ERR_INVALID_DATA, e.to_string())),
        }
    }

    fn parent(
        &self,
        client: ClientKey,
        id: ObjectId,
        want: ObjectKind,
    ) -> Result<&Object, (StatusCode, String)> {
        self.objects
            .get(&(client, id))
            .filter(|_| id.kind() == Some(want))
            .ok_or_else(|| {
                (
                    StatusCode::ERR_UNKNOWN_REFERENCE,
                    format!("no {want:?} {:#06x}", id.0),
                )
            })
    }

    /// CREATE with its mode: OK, OK_MATCHED, or the error and why.
    fn create(
        &mut self,
        client: ClientKey,
        id: ObjectId,
        variant: ObjectVariant,
        mode: CreationMode,
        now: Instant,
    ) -> Result<StatusCode, (StatusCode, String)> {
        if let Some(old) = self.objects.get(&(client, id)) {
            let same = old.variant == variant;
            match (mode.reuse, mode.replace) {
                (false, false) => {
                    return Err((StatusCode::ERR_ALREADY_EXISTS, "the object exists".into()))
                }
                (true, _) if same => return Ok(StatusCode::OK_MATCHED),
                (true, false) => {
                    return Err((
                        StatusCode::ERR_MISMATCH,
                        "the object exists with another representation".into(),
                    ))
                }
                _ => self.remove(client, id, now),
            }
        }
        let cost = variant.representation_len() + OBJECT_OVERHEAD;
        let held = self.object_bytes.get(&client).copied().unwrap_or(0);
        if held + cost > self.cfg.max_object_bytes {
            return Err((
                StatusCode::ERR_RESOURCES,
                format!(
                    "the client's objects hold {held} bytes, and this one ({cost}) would pass \
                     the agent's limit of {}",
                    self.cfg.max_object_bytes
                ),
            ));
        }
        let object = self.build(client, &variant, now)?;
        *self.object_bytes.entry(client).or_insert(0) += cost;
        match &object.entity {
            Entity::Writer(out) => {
                self.by_writer.insert(out.writer, (client, id));
            }
            Entity::Reader(r, _) => {
                self.by_reader.insert(*r, (client, id));
            }
            Entity::Requester { out, reader, .. } | Entity::Replier { out, reader, .. } => {
                self.by_writer.insert(out.writer, (client, id));
                self.by_reader.insert(*reader, (client, id));
            }
            _ => {}
        }
        self.objects.insert((client, id), object);
        Ok(StatusCode::OK)
    }

    fn build(
        &mut self,
        client: ClientKey,
        variant: &ObjectVariant,
        now: Instant,
    ) -> Result<Object, (StatusCode, String)> {
        use ObjectVariant as V;
        let kind = variant.kind();
        self.order += 1;
        let order = self.order;
        let obj = |parent, entity| Object {
            parent,
            variant: variant.clone(),
            entity,
            order,
        };
        let dds_err =
            |e: crate::rtps::participant::CreateError| (StatusCode::ERR_DDS_ERROR, e.to_string());
        match variant {
            V::Participant {
                representation,
                domain_id,
            } => {
                self.profile(kind, representation)?;
                let d = u32::try_from(*domain_id).unwrap_or(u32::MAX);
                if d != self.cfg.domain_id && !self.cfg.any_domain {
                    return Err((
                        StatusCode::ERR_INCOMPATIBLE,
                        format!(
                            "domain {domain_id}: this agent's DDS participant is in domain {}",
                            self.cfg.domain_id
                        ),
                    ));
                }
                Ok(obj(None, Entity::Participant))
            }
            V::Topic {
                representation,
                participant_id,
            } => {
                self.parent(client, *participant_id, ObjectKind::Participant)?;
                let Profile::Topic(t) = self.profile(kind, representation)? else {
                    return Err((StatusCode::ERR_INVALID_DATA, "not a topic".into()));
                };
                Ok(obj(Some(*participant_id), Entity::Topic(t)))
            }
            V::Publisher {
                representation,
                participant_id,
            }
            | V::Subscriber {
                representation,
                participant_id,
            } => {
                self.parent(client, *participant_id, ObjectKind::Participant)?;
                let Profile::Group(p) = self.profile(kind, representation)? else {
                    return Err((StatusCode::ERR_INVALID_DATA, "not a group".into()));
                };
                Ok(obj(Some(*participant_id), Entity::Group(p)))
            }
            V::DataWriter {
                representation,
                publisher_id,
            }
            | V::DataReader {
                representation,
                subscriber_id: publisher_id,
            } => {
                let writer = kind == ObjectKind::DataWriter;
                let group_kind = if writer {
                    ObjectKind::Publisher
                } else {
                    ObjectKind::Subscriber
                };
                let group = self.parent(client, *publisher_id, group_kind)?;
                let group_partitions = match &group.entity {
                    Entity::Group(p) => p.clone(),
                    _ => Vec::new(),
                };
                let (Profile::Writer(mut ep) | Profile::Reader(mut ep)) =
                    self.profile(kind, representation)?
                else {
                    return Err((StatusCode::ERR_INVALID_DATA, "not an endpoint".into()));
                };
                if ep.topic.is_none() {
                    // binary: the topic is an object
                    let topic_id = match representation {
                        Representation::Binary(b) => match BinaryRepresentation::decode(kind, b) {
                            Ok(BinaryRepresentation::DataWriter(w)) => w.topic_id,
                            Ok(BinaryRepresentation::DataReader(r)) => r.topic_id,
                            _ => ObjectId::INVALID,
                        },
                        _ => ObjectId::INVALID,
                    };
                    match &self.parent(client, topic_id, ObjectKind::Topic)?.entity {
                        Entity::Topic(t) => ep.topic = Some(t.clone()),
                        _ => return Err((StatusCode::ERR_UNKNOWN_REFERENCE, "no topic".into())),
                    }
                }
                let Some(topic) = ep.topic.clone() else {
                    return Err((StatusCode::ERR_INVALID_DATA, "no topic".into()));
                };
                if ep.qos.partitions.is_empty() {
                    ep.qos.partitions = group_partitions;
                }
                let cfg = EndpointConfig::writer(&topic.name, &topic.type_name)
                    .keyed(topic.keyed)
                    .qos(ep.qos.clone());
                if writer {
                    let w = self.domain.create_writer(cfg, now).map_err(dds_err)?;
                    Ok(obj(
                        Some(*publisher_id),
                        Entity::Writer(Output {
                            writer: w,
                            held: VecDeque::new(),
                        }),
                    ))
                } else {
                    let r = self.domain.create_reader(cfg, now).map_err(dds_err)?;
                    let cap = inbox_cap(&self.cfg, &ep.qos);
                    let keep_all_reliable = ep.qos.history == History::KeepAll
                        && matches!(ep.qos.reliability, Reliability::Reliable(_));
                    let inbox = if keep_all_reliable {
                        read::Inbox::holding(cap, self.cfg.reader_bytes)
                    } else {
                        read::Inbox::new(cap, self.cfg.reader_bytes)
                    };
                    Ok(obj(Some(*publisher_id), Entity::Reader(r, inbox)))
                }
            }
            V::Requester {
                representation,
                participant_id,
            }
            | V::Replier {
                representation,
                participant_id,
            } => {
                self.parent(client, *participant_id, ObjectKind::Participant)?;
                let Profile::Service(s) = self.profile(kind, representation)? else {
                    return Err((StatusCode::ERR_INVALID_DATA, "not a service".into()));
                };
                let requester = kind == ObjectKind::Requester;
                let mut wq = profile::default_qos(true);
                wq.durability = crate::rtps::discovery::Durability::Volatile;
                let mut rq = profile::default_qos(false);
                rq.reliability = wq.reliability;
                let (wt, wty, rt, rty) = if requester {
                    (
                        &s.request_topic,
                        &s.request_type,
                        &s.reply_topic,
                        &s.reply_type,
                    )
                } else {
                    (
                        &s.reply_topic,
                        &s.reply_type,
                        &s.request_topic,
                        &s.request_type,
                    )
                };
                let w = self
                    .domain
                    .create_writer(EndpointConfig::writer(wt, wty).qos(wq), now)
                    .map_err(dds_err)?;
                let r = match self
                    .domain
                    .create_reader(EndpointConfig::reader(rt, rty).qos(rq), now)
                {
                    Ok(r) => r,
                    Err(e) => {
                        self.domain.delete_writer(w, now);
                        return Err(dds_err(e));
                    }
                };
                let out = Output {
                    writer: w,
                    held: VecDeque::new(),
                };
                let inbox = read::Inbox::new(self.cfg.reader_queue, self.cfg.reader_bytes);
                let entity = if requester {
                    Entity::Requester {
                        out,
                        reader: r,
                        inbox,
                        inflight: BTreeMap::new(),
                    }
                } else {
                    Entity::Replier {
                        out,
                        reader: r,
                        inbox,
                    }
                };
                Ok(obj(Some(*participant_id), entity))
            }
            _ => Err((
                StatusCode::ERR_DENIED,
                format!("{kind:?} objects are not supported"),
            )),
        }
    }

    /// WRITE_DATA: into DDS now, or held until the writer has room (a
    /// reliable write keeps its message unacknowledged meanwhile).
    fn write(
        &mut self,
        client: ClientKey,
        request: BaseObjectRequest,
        data: Vec<u8>,
        ticket: Option<WriteTicket>,
        now: Instant,
    ) {
        let key = (client, request.object_id);
        let held = match self.objects.get(&key).map(|o| &o.entity) {
            Some(Entity::Writer(_) | Entity::Requester { .. }) => Held {
                data: encapsulate(&data),
                related: None,
                request,
                ticket,
            },
            Some(Entity::Replier { .. }) => {
                let Some(id) = RtpsIdentity::from_bytes(&data, true) else {
                    self.refused(
                        client,
                        request.object_id,
                        "reply shorter than its sample identity",
                        ticket,
                        now,
                    );
                    return;
                };
                Held {
                    data: encapsulate(&data[24..]),
                    related: Some(id),
                    request,
                    ticket,
                }
            }
            _ => {
                // the client is told (a restored agent that could not make
                // its writer again, say), before its message is acknowledged:
                // it must not take the write for delivered
                self.stats.writes_unknown += 1;
                let _ = self.agent.reply_status(
                    client,
                    request,
                    StatusCode::ERR_UNKNOWN_REFERENCE,
                    StreamId::RELIABLE,
                    now,
                );
                if let Some(t) = ticket {
                    self.agent.write_done(t, now);
                }
                return;
            }
        };
        if let Some(out) = self.output(key) {
            out.held.push_back(held);
        }
        self.flush(key, now);
    }

    fn output(&mut self, key: Key) -> Option<&mut Output> {
        output_of(&mut self.objects, key)
    }

    fn refused(
        &mut self,
        client: ClientKey,
        object: ObjectId,
        reason: &str,
        ticket: Option<WriteTicket>,
        now: Instant,
    ) {
        self.stats.writes_refused += 1;
        self.events.push_back(BridgeEvent::WriteRefused {
            client,
            object,
            reason: reason.into(),
        });
        if let Some(t) = ticket {
            self.agent.write_done(t, now);
        }
    }

    /// Writes what an output holds, in order, while its history has room.
    fn flush(&mut self, key: Key, now: Instant) {
        if self.rediscovery.is_some_and(|t| now < t) {
            return; // held until the readers are found again
        }
        let Some(out) = output_of(&mut self.objects, key) else {
            return;
        };
        if out.held.is_empty() {
            return;
        }
        let writer = out.writer;
        let dead = |k: &Key| self.agent.seems_dead(k.0, now);
        let mut room = room_for(&self.objects, &self.by_reader, &self.domain, writer, dead);
        loop {
            let Some(out) = output_of(&mut self.objects, key) else {
                return;
            };
            let writer = out.writer;
            let Some(h) = out.held.front() else {
                return;
            };
            let mut change = Change::alive(&h.data);
            if let Some(r) = h.related {
                change = change.with_related_sample_identity(r);
            }
            let best_effort = h.ticket.is_none();
            if !best_effort {
                if let Some(r) = room.as_mut() {
                    if let Some(inbox) = r.blocking() {
                        // again when that inbox drains (`release_full`)
                        if !self.full.contains(&inbox) {
                            self.full.push(inbox);
                        }
                        return;
                    }
                    r.take(h.data.len());
                }
            }
            let result = self.domain.write(writer, change, now);
            match result {
                Ok(sn) => {
                    let Some(out) = self.output(key) else {
                        return;
                    };
                    let Some(h) = out.held.pop_front() else {
                        return;
                    };
                    self.stats.writes += 1;
                    if let Some(Object {
                        entity: Entity::Requester { inflight, .. },
                        ..
                    }) = self.objects.get_mut(&key)
                    {
                        inflight.insert(sn.0, h.request);
                        if inflight.len() > MAX_INFLIGHT {
                            inflight.pop_first();
                        }
                    }
                    if let Some(t) = h.ticket {
                        self.agent.write_done(t, now);
                    }
                }
                Err(WriteError::HistoryFull(_)) if !best_effort => return,
                Err(WriteError::HistoryFull(_)) => {
                    // best effort: the client asked for no guarantee
                    self.stats.writes_dropped += 1;
                    if let Some(out) = self.output(key) {
                        out.held.pop_front();
                    }
                }
                Err(e) => {
                    let h = self.output(key).and_then(|o| o.held.pop_front());
                    let ticket = h.and_then(|h| h.ticket);
                    self.refused(key.0, key.1, &e.to_string(), ticket, now);
                }
            }
        }
    }

    /// READ_DATA: starts (or replaces, or cancels) delivery.
    fn read(&mut self, client: ClientKey, read: ReadData, now: Instant) {
        let key = (client, read.request.object_id);
        let inbox = match self.objects.get_mut(&key).map(|o| &mut o.entity) {
            Some(
                Entity::Reader(_, inbox)
                | Entity::Requester { inbox, .. }
                | Entity::Replier { inbox, .. },
            ) => inbox,
            _ => {
                let _ = self.agent.reply_status(
                    client,
                    read.request,
                    StatusCode::ERR_UNKNOWN_REFERENCE,
                    StreamId::RELIABLE,
                    now,
                );
                return;
            }
        };
        inbox.delivery = read::Delivery::start(&read, now);
        inbox.read = inbox.delivery.is_some().then_some(read);
        inbox.wake = None;
        self.ready.insert(key);
        self.events.push_back(BridgeEvent::ClientChanged { client });
    }

    /// What to keep of `client` to serve it again after a restart.
    pub fn client_state(&self, client: ClientKey) -> Option<ClientState<A>> {
        let (session_id, mtu) = self.agent.session(client)?;
        let addr = self.agent.client_address(client)?.clone();
        let mut objects: Vec<(u64, ObjectId, ObjectVariant)> = Vec::new();
        let mut reads = Vec::new();
        for ((c, id), o) in &self.objects {
            if *c != client {
                continue;
            }
            objects.push((o.order, *id, o.variant.clone()));
            if let Entity::Reader(_, i)
            | Entity::Requester { inbox: i, .. }
            | Entity::Replier { inbox: i, .. } = &o.entity
            {
                if let (Some(r), Some(_)) = (&i.read, &i.delivery) {
                    reads.push((o.order, r.clone()));
                }
            }
        }
        objects.sort_by_key(|o| o.0);
        reads.sort_by_key(|r| r.0);
        Some(ClientState {
            client,
            session_id,
            mtu,
            addr,
            objects: objects.into_iter().map(|(_, id, v)| (id, v)).collect(),
            reads: reads.into_iter().map(|(_, r)| r).collect(),
            inputs: self.agent.input_positions(client),
        })
    }

    /// The host keeps its clients' reliable input positions
    /// ([`ClientState::inputs`]) somewhere that outlives it: from now on a
    /// client's message is acknowledged only once DDS took its samples
    /// AND the host [saved](Self::positions_saved) the position that
    /// says so. After each input or timeout, send what
    /// [`poll_datagram`](Self::poll_datagram) and
    /// [`poll_transmit`](Self::poll_transmit) give, save what
    /// [`take_moved_positions`](Self::take_moved_positions) gives, call
    /// [`positions_saved`](Self::positions_saved), and send what
    /// [`poll_transmit`](Self::poll_transmit) gives again (the
    /// ACKNACKs). A host that stops gracefully, having done so, leaves
    /// nothing written twice after its restart; one killed between a DDS
    /// write and the save of its position writes that sample again (at
    /// least once), and one killed later writes nothing twice. Nothing
    /// acknowledged is ever lost.
    pub fn hold_acks_until_saved(&mut self) {
        self.agent.hold_acks_until_saved();
    }

    /// The clients whose reliable input positions moved since the last
    /// call, with the positions ([`Agent::take_moved_positions`]).
    pub fn take_moved_positions(&mut self) -> Vec<(ClientKey, Vec<(StreamId, SeqNum)>)> {
        self.agent.take_moved_positions()
    }

    /// The host saved these positions of `client`: the ACKNACKs they allow
    /// go with the next [`poll_transmit`](Self::poll_transmit).
    pub fn positions_saved(&mut self, client: ClientKey, positions: &[(StreamId, SeqNum)]) {
        self.agent.positions_saved(client, positions);
    }

    /// Serves a client again as [`client_state`](Self::client_state) left
    /// it (at start, after a restart): its session is restored in the
    /// agent machine (no STATUS_AGENT), its objects created again (no
    /// STATUS), its READ_DATA started again. Objects that cannot be made
    /// any more (a references file that changed) come back as errors.
    pub fn restore(&mut self, state: ClientState<A>, now: Instant) -> Vec<(ObjectId, String)> {
        let now = self.tick(now);
        let client = state.client;
        let mut errors = Vec::new();
        if !self
            .agent
            .restore_client(client, state.session_id, state.mtu, state.addr)
        {
            errors.push((
                ObjectId::CLIENT,
                "the agent has no room for the session".into(),
            ));
            return errors;
        }
        self.agent.restore_positions(client, &state.inputs);
        self.drop_client(client, now);
        self.rediscovery = Some(now + REDISCOVERY);
        for (id, v) in state.objects {
            if let Err((_, why)) = self.create(client, id, v, CreationMode::REPLACE, now) {
                errors.push((id, why));
            }
        }
        for r in state.reads {
            self.read(client, r, now);
        }
        // the events of restoring are not news
        self.events
            .retain(|e| !matches!(e, BridgeEvent::ClientChanged { client: c } if *c == client));
        self.process(now);
        errors
    }

    /// Sends what every delivery allows now.
    fn deliver_all(&mut self, now: Instant) {
        let agent = &mut self.agent;
        let stats = &mut self.stats;
        let objects = &mut self.objects;
        let events = &mut self.events;
        self.ready.retain(|key| {
            let Some(o) = objects.get_mut(key) else {
                return false;
            };
            let inbox = match &mut o.entity {
                Entity::Reader(_, i)
                | Entity::Requester { inbox: i, .. }
                | Entity::Replier { inbox: i, .. } => i,
                _ => return false,
            };
            deliver(agent, stats, events, *key, inbox, now);
            inbox.delivery.is_some() && !inbox.queue.is_empty()
        });
    }
}

/// What the holding inboxes a writer is matched with take before one is
/// full: the fewest samples, and the fewest bytes, each with its inbox.
#[derive(Debug, Clone, Copy)]
struct Room {
    samples: (usize, Key),
    bytes: (usize, Key),
}

impl Room {
    /// The inbox that takes nothing more, if one is there.
    fn blocking(&self) -> Option<Key> {
        if self.samples.0 == 0 {
            Some(self.samples.1)
        } else if self.bytes.0 == 0 {
            Some(self.bytes.1)
        } else {
            None
        }
    }

    /// One sample of `len` bytes written.
    fn take(&mut self, len: usize) {
        self.samples.0 -= 1;
        self.bytes.0 = self.bytes.0.saturating_sub(len);
    }
}

/// Room left in the holding inboxes (reliable keep-all readers of this
/// agent) that `writer` is matched with; `None`: no such reader.
/// Samples written reach the inboxes as DDS events a little later, so the
/// writer takes at most this much at a time (bytes: overshot by its last
/// sample at most; an inbox drops samples only at four times that).
fn room_for(
    objects: &HashMap<Key, Object>,
    by_reader: &HashMap<ReaderId, Key>,
    domain: &Domain,
    writer: WriterId,
    dead: impl Fn(&Key) -> bool,
) -> Option<Room> {
    let mut room: Option<Room> = None;
    for g in domain.participant().matched_readers(writer.guid()) {
        let Some(key) = by_reader.get(&ReaderId(g)) else {
            continue;
        };
        if let Some(Object {
            entity: Entity::Reader(_, i),
            ..
        }) = objects.get(key)
        {
            if i.hold && !dead(key) {
                let (n, bytes) = i.room();
                let r = room.get_or_insert(Room {
                    samples: (n, *key),
                    bytes: (bytes, *key),
                });
                if n < r.samples.0 {
                    r.samples = (n, *key);
                }
                if bytes < r.bytes.0 {
                    r.bytes = (bytes, *key);
                }
            }
        }
    }
    room
}

/// Sends what one inbox's delivery allows now.
fn deliver<A: Clone + Eq + Hash>(
    agent: &mut Agent<A>,
    stats: &mut BridgeStats,
    events: &mut VecDeque<BridgeEvent>,
    key: Key,
    inbox: &mut read::Inbox,
    now: Instant,
) {
    let Some(d) = inbox.delivery.as_mut() else {
        return;
    };
    if d.expired(now) {
        inbox.delivery = None;
        return;
    }
    inbox.wake = None;
    if agent.client_silent(key.0, now) {
        // the client answers nothing (dead, or cut off): nothing more is
        // queued for it, what was queued and not sent goes, and the reader
        // keeps only the newest; its next answer lets delivery go on
        let dropped = agent.drop_unsent(key.0) + inbox.trim_for_silence();
        stats.samples_dropped += dropped as u64;
        return;
    }
    while let Some(sample) = inbox.queue.front() {
        let Some(d) = inbox.delivery.as_mut() else {
            break;
        };
        match d.gate(sample.len(), now) {
            read::Gate::Ended => {
                inbox.delivery = None;
                break;
            }
            read::Gate::Wait(t) => {
                inbox.wake = Some(t);
                break;
            }
            read::Gate::Open => {}
        }
        match agent.send_data(key.0, d.request, d.stream, sample, now) {
            Ok(()) => {
                stats.samples_sent += 1;
                let finished = d.sent(sample.len(), now);
                inbox.pop();
                if finished {
                    inbox.delivery = None;
                }
            }
            Err(AgentCommandError::Queue(QueueError::Stream(StreamError::Backlog { .. }))) => break, // again when the client acknowledges
            Err(e) => {
                // too large for a best-effort stream or for all a reliable
                // one queues, or no session
                stats.samples_dropped += 1;
                inbox.pop();
                if let AgentCommandError::Queue(QueueError::Stream(StreamError::TooLarge {
                    len,
                    max,
                    ..
                })) = e
                {
                    if !std::mem::replace(&mut inbox.too_large_reported, true) {
                        events.push_back(BridgeEvent::SampleTooLarge {
                            client: key.0,
                            object: key.1,
                            len,
                            max,
                        });
                    }
                }
            }
        }
    }
}
