//! The agent's half of DDS-XRCE sessions, sans-I/O (`protocols/xrce.md`
//! §2, §6–§11), behaving on the wire as eProsima Micro XRCE-DDS Agent
//! 2.3.0 does: it accepts CREATE_CLIENT and answers STATUS_AGENT, keeps a
//! session with its streams per client key, acknowledges reliable input,
//! retransmits reliable output, rebuilds fragments, answers pings
//! (GET_INFO), TIMESTAMP and the session's DELETE itself, and hands every
//! object request (CREATE, DELETE, WRITE_DATA, READ_DATA) to its host as
//! an [`AgentEvent`]. It knows nothing of DDS: the host answers with
//! [`Agent::reply_status`] and sends samples with [`Agent::send_data`].
//!
//! `A` is the transport address (UDP socket address, TCP connection id,
//! serial address): a session whose id is 0x80 or above is found by the
//! address it was created from, as the eProsima agent does; below 0x80 by
//! the key in every header.
//!
//! Wall-clock time (for TIMESTAMP_REPLY) is the anchor given to
//! [`Agent::new`] or [`Agent::set_wall_clock`] plus the monotonic time
//! since; the agent reads no clock.
//!
//! ```
//! use std::time::{Instant, SystemTime};
//! use courier_wire::xrce::{Agent, AgentConfig, AgentEvent};
//! let now = Instant::now();
//! let mut agent: Agent<&str> = Agent::new(AgentConfig::default(), now, SystemTime::now());
//! // CREATE_CLIENT of `udp_xml_reliable_pubsub` #1, from a client at "a"
//! let create_client = [
//!     0x80, 0, 0, 0, 0, 1, 16, 0, b'X', b'R', b'C', b'E', 1, 0, 1, 0x0F,
//!     0xCC, 0xCC, 0xDD, 0xDD, 0x81, 0, 0xFC, 0x01,
//! ];
//! agent.handle_input("a", &create_client, now).unwrap();
//! assert!(matches!(agent.poll_event(), Some(AgentEvent::ClientCreated { kept: false, .. })));
//! // STATUS_AGENT OK, as captured (#2)
//! let (to, status_agent) = agent.poll_transmit().unwrap();
//! assert_eq!(to, "a");
//! assert_eq!(status_agent[..10], [0x81, 0, 0, 0, 4, 1, 11, 0, 0, 0]);
//! ```

use std::collections::{BTreeMap, BTreeSet, VecDeque};

// Looked up per message, with keys the clients choose: foldhash is seeded
// per process and costs a fraction of SipHash.
use foldhash::{HashMap, HashMapExt};
use std::hash::Hash;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use super::client::CreationMode;
use super::message::{Message, MessageHeader};
use super::object::{
    ActivityInfo, AgentRepresentation, ClientRepresentation, ObjectInfo, ObjectVariant,
};
use super::session::{session_header, single, InputError, QueueError, Streams};
use super::stream::{SeqNum, StreamConfig};
use super::submessage::{
    flags, Data, Info, Payload, ReadData, Status, StatusAgent, Submessage, TimestampReply,
};
use super::types::{
    BaseObjectRequest, ClientKey, ObjectKind, Property, ResultStatus, StatusCode, StreamId, Time,
    COOKIE,
};
use super::SESSION_ID_WITHOUT_CLIENT_KEY;

/// How the agent behaves.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct AgentConfig {
    /// Stream settings; each client's `mtu` is the one it advertises,
    /// capped by this one.
    pub streams: StreamConfig,
    /// Sessions at most. A CREATE_CLIENT beyond takes the place of the
    /// session silent the longest if that one has been silent for
    /// [`evict_after`](Self::evict_after) (a client that died without
    /// DELETE: crashed, powered off, rebooted with a new key); else it
    /// gets `ERR_RESOURCES`.
    pub max_clients: usize,
    /// See [`max_clients`](Self::max_clients).
    pub evict_after: Duration,
    /// A session silent this long is deleted, as by DELETE (`None`: never,
    /// the default: a client that only subscribes best effort may say
    /// nothing for hours, and eProsima's library does not come back from
    /// a deleted session by itself).
    pub client_timeout: Option<Duration>,
    /// Streams of each kind and direction per session.
    pub max_streams: usize,
    /// The smallest MTU a client may advertise (`ERR_INVALID_DATA` below).
    pub min_mtu: u16,
    /// What STATUS_AGENT and INFO say of the agent.
    pub representation: AgentRepresentation,
    /// A reliable message is acknowledged only once the host has
    /// [completed](Agent::write_done) every WRITE_DATA it holds (each
    /// [`AgentEvent::Write`] then carries a [`WriteTicket`]), so a write
    /// the host cannot take yet holds the client back through the
    /// stream's window instead of being lost after its acknowledgement.
    /// Off, a message is acknowledged as soon as it is handed to the host
    /// (eProsima's behaviour).
    pub host_confirms_writes: bool,
}

impl Default for AgentConfig {
    fn default() -> Self {
        AgentConfig {
            streams: StreamConfig {
                mtu: usize::from(u16::MAX),
                ..StreamConfig::agent()
            },
            max_clients: 1024,
            evict_after: Duration::from_secs(60),
            client_timeout: None,
            max_streams: 4,
            min_mtu: 64,
            representation: AgentRepresentation::default(),
            host_confirms_writes: false,
        }
    }
}

/// A reliable WRITE_DATA the host has not completed: hand it back to
/// [`Agent::write_done`] once DDS took the sample (or the host gave it up
/// for good). Until then its message, and every later one of its stream,
/// stays unacknowledged.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct WriteTicket {
    /// The client.
    pub client: ClientKey,
    /// The reliable stream the write came on.
    pub stream: StreamId,
    /// The sequence number of the message that completed it.
    pub seq: SeqNum,
    epoch: u32,
}

/// What the agent hands its host.
#[derive(Debug, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub enum AgentEvent {
    /// A session was created (or, with `kept`, created again with the same
    /// key and session id: its streams start over, its objects stay).
    ClientCreated {
        /// The client.
        client: ClientKey,
        /// Its session id.
        session_id: u8,
        /// CLIENT_Representation properties.
        properties: Option<Vec<Property>>,
        /// Whether the client's objects are kept.
        kept: bool,
    },
    /// A session ended (DELETE of the client, replaced by another session
    /// id, or its address taken by another client, evicted or timed out):
    /// drop its objects.
    ClientDeleted {
        /// The client.
        client: ClientKey,
    },
    /// A session is deleted because its client has said nothing for
    /// `silent`: evicted for a new client at [`AgentConfig::max_clients`],
    /// or past [`AgentConfig::client_timeout`]. [`AgentEvent::ClientDeleted`]
    /// follows.
    ClientExpired {
        /// The client.
        client: ClientKey,
        /// How long it had been silent.
        silent: Duration,
        /// The client it made room for (`None`: timed out).
        for_client: Option<ClientKey>,
    },
    /// A CREATE_CLIENT was refused (the STATUS_AGENT says why).
    ClientRefused {
        /// The client.
        client: ClientKey,
        /// The answer.
        status: StatusCode,
    },
    /// CREATE: answer with [`Agent::reply_status`] on `reply_stream`.
    Create {
        /// The client.
        client: ClientKey,
        /// Request id and object id.
        request: BaseObjectRequest,
        /// What to create.
        object: ObjectVariant,
        /// Creation mode.
        mode: CreationMode,
        /// Built-in reliable 0x80 if the CREATE came on a reliable stream,
        /// else best-effort 0x01.
        reply_stream: StreamId,
    },
    /// DELETE of an object: answer with [`Agent::reply_status`].
    Delete {
        /// The client.
        client: ClientKey,
        /// Request id and object id.
        request: BaseObjectRequest,
        /// Where the STATUS goes.
        reply_stream: StreamId,
    },
    /// WRITE_DATA (FORMAT_DATA) to a writer, requester or replier. The
    /// agent confirms nothing beyond the stream's ACKNACK.
    Write {
        /// The client.
        client: ClientKey,
        /// Request id and writer.
        request: BaseObjectRequest,
        /// The serialized body (for a replier, its SampleIdentity first).
        data: Vec<u8>,
        /// With [`AgentConfig::host_confirms_writes`], for a write on a
        /// reliable stream: what to hand [`Agent::write_done`].
        ticket: Option<WriteTicket>,
    },
    /// READ_DATA: send samples with [`Agent::send_data`] under
    /// `read.request` on `read.preferred_stream_id`; errors go back as a
    /// STATUS on 0x80.
    Read {
        /// The client.
        client: ClientKey,
        /// The request.
        read: ReadData,
    },
}

/// Why a host command failed.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum AgentCommandError {
    /// No session with this key.
    #[error("no XRCE session for client {0:08x}")]
    UnknownClient(u32),
    /// The stream refused the submessage (window and backlog full, or a
    /// best-effort sample larger than the client's MTU).
    #[error(transparent)]
    Queue(#[from] QueueError),
}

#[derive(Debug, Clone)]
struct Proxy<A> {
    session_id: u8,
    addr: A,
    streams: Streams,
    /// Per reliable input stream: messages handed to the host and not yet
    /// acknowledged, with the writes of each the host has not completed.
    pending: BTreeMap<u8, VecDeque<(SeqNum, u32)>>,
    /// Bumped when the streams start over: older tickets are void.
    epoch: u32,
    /// The reliable input positions last given to the host
    /// ([`Agent::take_moved_positions`]).
    reported: Vec<(StreamId, SeqNum)>,
    /// When the client last sent something (or the session was made or
    /// restored).
    last_heard: Instant,
}

impl<A> Proxy<A> {
    fn reset_streams(&mut self) {
        self.streams.reset();
        self.pending.clear();
        self.epoch = self.epoch.wrapping_add(1);
    }

    /// Acknowledges what the host has completed on `stream`; whether the
    /// acknowledged position moved.
    fn advance(&mut self, stream: StreamId) -> bool {
        let mut moved = false;
        let q = self.pending.entry(stream.0).or_default();
        while let Some(&(seq, n)) = q.front() {
            if n > 0 {
                break;
            }
            q.pop_front();
            moved |= self.streams.confirm_through(stream, seq);
        }
        if q.is_empty() {
            moved |= self.streams.confirm_all(stream);
        }
        moved
    }
}

/// The agent side of every client session.
#[derive(Debug, Clone)]
pub struct Agent<A> {
    cfg: AgentConfig,
    clients: BTreeMap<u32, Proxy<A>>,
    by_addr: HashMap<A, u32>,
    transmits: VecDeque<(A, Vec<u8>)>,
    /// Sessions that may have something to send: touched by an input or a
    /// command, or with a HEARTBEAT due. [`Agent::poll_transmit`] looks at
    /// these only, so that the work per message does not grow with the
    /// number of clients.
    dirty: BTreeSet<u32>,
    events: VecDeque<AgentEvent>,
    now: Instant,
    wall: (Instant, SystemTime),
    /// The host saves reliable input positions
    /// ([`Agent::hold_acks_until_saved`]).
    hold_acks: bool,
    /// Sessions whose reliable input positions may have moved since
    /// [`Agent::take_moved_positions`] last looked.
    touched: BTreeSet<u32>,
}

fn to_time(wall: SystemTime) -> Time {
    let d = wall.duration_since(UNIX_EPOCH).unwrap_or_default();
    Time {
        seconds: d.as_secs() as i32,
        nanoseconds: d.subsec_nanos(),
    }
}

impl<A: Clone + Eq + Hash> Agent<A> {
    /// An agent with no sessions; `wall` is the wall-clock time at `now`.
    pub fn new(cfg: AgentConfig, now: Instant, wall: SystemTime) -> Self {
        Agent {
            cfg,
            clients: BTreeMap::new(),
            by_addr: HashMap::new(),
            transmits: VecDeque::new(),
            dirty: BTreeSet::new(),
            events: VecDeque::new(),
            now,
            wall: (now, wall),
            hold_acks: false,
            touched: BTreeSet::new(),
        }
    }

    /// The host keeps every session's reliable input positions (the last
    /// message of each stream it handled: with
    /// [`AgentConfig::host_confirms_writes`], wrote) somewhere that
    /// outlives it, to give them back after a restart
    /// ([`Agent::restore_positions`]). From now on an ACKNACK acknowledges
    /// nothing the host has not saved: take what moved with
    /// [`take_moved_positions`](Self::take_moved_positions), save it, and
    /// say so with [`positions_saved`](Self::positions_saved) (the
    /// ACKNACKs then go with the next [`poll_transmit`](Self::poll_transmit)).
    /// A client is thus never told a message is acknowledged that a
    /// restarted agent would take as new: nothing is handed on twice,
    /// except what the host handed on and could not save before it died.
    pub fn hold_acks_until_saved(&mut self) {
        self.hold_acks = true;
        for p in self.clients.values_mut() {
            p.streams.hold_acks_until_saved();
        }
    }

    /// `key`'s input positions may have moved: noted only for a host that
    /// keeps them (audit 23: without `--state` nothing took the notes, and
    /// every client key ever seen stayed, about 10 bytes each, 1.2 million
    /// sessions in 4 minutes making 10 MB).
    fn touch(&mut self, key: u32) {
        if self.hold_acks {
            self.touched.insert(key);
        }
    }

    /// Every session's reliable input positions that moved since the last
    /// call (a session created again gives its new, often empty, list).
    /// Nothing unless the host keeps them
    /// ([`hold_acks_until_saved`](Self::hold_acks_until_saved)).
    pub fn take_moved_positions(&mut self) -> Vec<(ClientKey, Vec<(StreamId, SeqNum)>)> {
        let mut moved = Vec::new();
        for k in std::mem::take(&mut self.touched) {
            let Some(p) = self.clients.get_mut(&k) else {
                continue;
            };
            let now = p.streams.input_positions();
            if now != p.reported {
                p.reported.clone_from(&now);
                moved.push((ClientKey::from(k), now));
            }
        }
        moved
    }

    /// The host saved these positions of `client`
    /// ([`hold_acks_until_saved`](Self::hold_acks_until_saved)): the
    /// ACKNACKs they allow go with the next
    /// [`poll_transmit`](Self::poll_transmit).
    pub fn positions_saved(&mut self, client: ClientKey, positions: &[(StreamId, SeqNum)]) {
        let k = u32::from(client);
        let Some(p) = self.clients.get_mut(&k) else {
            return;
        };
        let mut any = false;
        for &(id, seq) in positions {
            any |= p.streams.saved_through(id, seq);
        }
        if any {
            self.dirty.insert(k);
        }
    }

    /// A session's reliable input positions now: the last message each
    /// stream handled and confirmed, by stream id (a restored stream still
    /// waiting for the client's HEARTBEAT gives the position it was
    /// restored with, if any).
    pub fn input_positions(&self, client: ClientKey) -> Vec<(StreamId, SeqNum)> {
        self.clients
            .get(&u32::from(client))
            .map(|p| p.streams.input_positions())
            .unwrap_or_default()
    }

    /// Gives a [restored](Self::restore_client) session the reliable input
    /// positions its host kept (as
    /// [`take_moved_positions`](Self::take_moved_positions) or
    /// [`input_positions`](Self::input_positions) gave them before the
    /// restart): those streams go on from there, so that what the client
    /// sends again because its acknowledgement never came is known as
    /// handled already, acknowledged and not handed on a second time.
    /// Streams without a position take the client's from its HEARTBEAT.
    pub fn restore_positions(&mut self, client: ClientKey, positions: &[(StreamId, SeqNum)]) {
        let k = u32::from(client);
        if let Some(p) = self.clients.get_mut(&k) {
            p.streams.restore_inputs(positions);
            p.reported = p.streams.input_positions();
        }
    }

    /// Sets the wall-clock time at `now` (after the host's clock moved).
    pub fn set_wall_clock(&mut self, now: Instant, wall: SystemTime) {
        self.wall = (now, wall);
    }

    fn wall_at(&self, now: Instant) -> SystemTime {
        self.wall.1 + now.saturating_duration_since(self.wall.0)
    }

    /// The sessions' client keys.
    pub fn clients(&self) -> impl Iterator<Item = ClientKey> + '_ {
        self.clients.keys().map(|k| ClientKey::from(*k))
    }

    /// Bytes held in every session's streams, and in messages waiting to
    /// go; bounded by the configuration (clients × streams × window).
    pub fn buffered_bytes(&self) -> usize {
        self.transmits.iter().map(|t| t.1.len()).sum::<usize>()
            + self
                .clients
                .values()
                .map(|p| p.streams.buffered())
                .sum::<usize>()
    }

    /// Restores a session the agent had before it restarted (its host kept
    /// `key`, `session_id`, the MTU and the address): no STATUS_AGENT, no
    /// event. Its streams take the client's position from what the client
    /// sends first (a reliable stream from its HEARTBEAT or ACKNACK), so a
    /// client that goes on with its old session, as eProsima's does, is
    /// served again; reliable input streams whose positions the host kept
    /// go on from them instead ([`Agent::restore_positions`]). Without
    /// them, messages handed to the host before the restart but not
    /// acknowledged come again (at least once). Best-effort output starts
    /// from sequence number 0 again: a client drops best-effort messages
    /// until their numbers pass the last one it took. Reliable output not
    /// yet acknowledged is gone with the old process. False if the agent
    /// is full or the key is 0.
    pub fn restore_client(&mut self, key: ClientKey, session_id: u8, mtu: u16, addr: A) -> bool {
        let k = u32::from(key);
        if k == 0 || (!self.clients.contains_key(&k) && !self.room_for(key)) {
            return false;
        }
        self.remove_client(k);
        self.events
            .retain(|e| !matches!(e, AgentEvent::ClientDeleted { client } if *client == key));
        let mut streams = Streams::new(
            session_header(session_id, key),
            StreamConfig {
                mtu: usize::from(mtu).min(self.cfg.streams.mtu),
                ..self.cfg.streams
            },
            self.cfg.max_streams,
        );
        streams.set_deferred(self.cfg.host_confirms_writes);
        streams.set_resync();
        if self.hold_acks {
            streams.hold_acks_until_saved();
        }
        self.dirty.insert(k);
        self.clients.insert(
            k,
            Proxy {
                session_id,
                addr: addr.clone(),
                streams,
                pending: BTreeMap::new(),
                epoch: 0,
                reported: Vec::new(),
                last_heard: self.now,
            },
        );
        self.bind(k, addr);
        true
    }

    /// A session's id and MTU (what [`Agent::restore_client`] needs besides
    /// the key and address).
    pub fn session(&self, client: ClientKey) -> Option<(u8, u16)> {
        self.clients.get(&u32::from(client)).map(|p| {
            (
                p.session_id,
                u16::try_from(p.streams.config().mtu).unwrap_or(u16::MAX),
            )
        })
    }

    /// How long `client` has said nothing (`None`: no such session).
    pub fn silent_for(&self, client: ClientKey, now: Instant) -> Option<Duration> {
        let p = self.clients.get(&u32::from(client))?;
        Some(now.saturating_duration_since(p.last_heard))
    }

    /// Whether `client` has said nothing for [`AgentConfig::evict_after`]
    /// (it died without DELETE, most likely): a reader of its holds no
    /// writer back any longer.
    pub fn seems_dead(&self, client: ClientKey, now: Instant) -> bool {
        self.silent_for(client, now)
            .is_some_and(|d| d >= self.cfg.evict_after)
    }

    /// The address a client's messages go to.
    pub fn client_address(&self, client: ClientKey) -> Option<&A> {
        self.clients.get(&u32::from(client)).map(|p| &p.addr)
    }

    fn tick(&mut self, now: Instant) -> Instant {
        self.now = self.now.max(now);
        self.now
    }

    fn send(&mut self, to: &A, header: MessageHeader, sub: Submessage) {
        if let Ok(m) = single(header, sub) {
            self.transmits.push_back((to.clone(), m));
        }
    }

    fn info(&self, request: BaseObjectRequest, in_session: bool) -> Submessage {
        Submessage::new(Payload::Info(Info {
            request,
            result: ResultStatus {
                status: StatusCode::OK,
                implementation_status: in_session.into(),
            },
            info: ObjectInfo {
                config: Some(ObjectVariant::Agent(self.cfg.representation.clone())),
                activity: Some(ActivityInfo::Agent {
                    availability: 1,
                    locators: Vec::new(),
                }),
            },
        }))
    }

    /// Takes one message from `from`.
    pub fn handle_input(&mut self, from: A, bytes: &[u8], now: Instant) -> Result<(), InputError> {
        let now = self.tick(now);
        let msg = Message::decode(bytes)?;
        let h = msg.header;
        let first = msg.submessages.first().map(|s| s.payload.clone());
        if h.session_id & !SESSION_ID_WITHOUT_CLIENT_KEY == 0 {
            // outside a session: CREATE_CLIENT or a ping
            return match first {
                Some(Payload::CreateClient(rep)) => {
                    self.create_client(from, rep);
                    Ok(())
                }
                Some(Payload::GetInfo(g)) => {
                    let known = self.by_addr.contains_key(&from);
                    let sub = self.info(g.request, known);
                    self.send(&from, h, sub);
                    Ok(())
                }
                _ => Err(InputError::Unexpected {
                    what: first.as_ref().map_or("empty message", |p| p.id().name()),
                    stream: h.stream_id.0,
                }),
            };
        }
        let key = match h.client_key {
            Some(k) => Some(u32::from(k)),
            None => self.by_addr.get(&from).copied(),
        };
        let Some(key) = key.filter(|k| self.clients.contains_key(k)) else {
            return self.unknown_client(from, h, first);
        };
        let proxy_session = self.clients.get(&key).map(|p| p.session_id);
        if proxy_session != Some(h.session_id) {
            return Err(InputError::WrongSession {
                expected: proxy_session.unwrap_or(0),
                got: h.session_id,
            });
        }
        if h.client_key.is_some() {
            self.bind(key, from);
        }
        self.dirty.insert(key);
        self.touch(key);
        let Some(proxy) = self.clients.get_mut(&key) else {
            return Ok(());
        };
        proxy.last_heard = now;
        let arrival = proxy.streams.receive(msg, bytes.len(), now);
        if self.cfg.host_confirms_writes {
            for (stream, seq) in &arrival.handed {
                proxy
                    .pending
                    .entry(stream.0)
                    .or_default()
                    .push_back((*seq, 0));
            }
        }
        let mut result = arrival.errors.into_iter().next().map_or(Ok(()), Err);
        for ((stream, sub), origin) in arrival.subs.into_iter().zip(arrival.origins) {
            let r = self.on_submessage(key, stream, origin, sub, now);
            result = result.and(r);
        }
        self.dirty.insert(key);
        if let Some(p) = self.clients.get_mut(&key) {
            let mut replies = arrival.replies;
            for id in arrival.ack_later {
                p.advance(id);
                replies.extend(p.streams.acknack_for(id, now));
            }
            let addr = p.addr.clone();
            self.transmits
                .extend(replies.into_iter().map(|m| (addr.clone(), m)));
        }
        result
    }

    fn unknown_client(
        &mut self,
        from: A,
        h: MessageHeader,
        first: Option<Payload>,
    ) -> Result<(), InputError> {
        match first {
            // the session's DELETE is confirmed even when the session is gone
            Some(Payload::Delete(r)) if r.object_id.kind_bits() == ObjectKind::Client as u8 => {
                let result = ResultStatus::default();
                let sub = Submessage::new(Payload::Status(Status { request: r, result }));
                self.send(&from, h, sub);
                Ok(())
            }
            Some(Payload::GetInfo(g)) => {
                let sub = self.info(g.request, false);
                self.send(&from, h, sub);
                Ok(())
            }
            _ => Err(InputError::UnknownClient {
                session_id: h.session_id,
            }),
        }
    }

    fn bind(&mut self, key: u32, addr: A) {
        self.dirty.insert(key);
        if let Some(p) = self.clients.get_mut(&key) {
            if p.addr != addr {
                self.by_addr.remove(&p.addr);
                p.addr = addr.clone();
            }
        }
        self.by_addr.insert(addr, key);
    }

    /// Whether a new session fits: below `max_clients`, or by evicting
    /// the session silent the longest if it has been for `evict_after`.
    fn room_for(&mut self, newcomer: ClientKey) -> bool {
        if self.clients.len() < self.cfg.max_clients {
            return true;
        }
        let now = self.now;
        let oldest = self
            .clients
            .iter()
            .min_by_key(|(_, p)| p.last_heard)
            .map(|(k, p)| (*k, now.saturating_duration_since(p.last_heard)));
        match oldest {
            Some((k, silent)) if silent >= self.cfg.evict_after => {
                self.expire(k, silent, Some(newcomer));
                true
            }
            _ => false,
        }
    }

    fn expire(&mut self, key: u32, silent: Duration, for_client: Option<ClientKey>) {
        self.events.push_back(AgentEvent::ClientExpired {
            client: ClientKey::from(key),
            silent,
            for_client,
        });
        self.remove_client(key);
    }

    fn remove_client(&mut self, key: u32) {
        self.touched.remove(&key);
        if let Some(p) = self.clients.remove(&key) {
            if self.by_addr.get(&p.addr) == Some(&key) {
                self.by_addr.remove(&p.addr);
            }
            self.events.push_back(AgentEvent::ClientDeleted {
                client: ClientKey::from(key),
            });
        }
    }

    fn create_client(&mut self, from: A, rep: ClientRepresentation) {
        let key = u32::from(rep.client_key);
        let reply_header = session_header(rep.session_id, rep.client_key);
        let status = if key == 0 || rep.cookie != COOKIE || rep.mtu < self.cfg.min_mtu {
            StatusCode::ERR_INVALID_DATA
        } else if rep.version.first() != Some(&1) {
            StatusCode::ERR_INCOMPATIBLE
        } else if !self.clients.contains_key(&key) && !self.room_for(rep.client_key) {
            StatusCode::ERR_RESOURCES
        } else {
            StatusCode::OK
        };
        if status != StatusCode::OK {
            self.events.push_back(AgentEvent::ClientRefused {
                client: rep.client_key,
                status,
            });
        }
        if status == StatusCode::OK {
            if let Some(&old) = self.by_addr.get(&from).filter(|&&k| k != key) {
                self.remove_client(old);
            }
            let kept = self
                .clients
                .get(&key)
                .is_some_and(|p| p.session_id == rep.session_id);
            if kept {
                self.dirty.insert(key);
                self.touch(key);
                let now = self.now;
                if let Some(p) = self.clients.get_mut(&key) {
                    p.reset_streams();
                    p.last_heard = now;
                }
            } else {
                self.remove_client(key);
                let mut streams = Streams::new(
                    reply_header,
                    StreamConfig {
                        mtu: usize::from(rep.mtu).min(self.cfg.streams.mtu),
                        ..self.cfg.streams
                    },
                    self.cfg.max_streams,
                );
                streams.set_deferred(self.cfg.host_confirms_writes);
                if self.hold_acks {
                    streams.hold_acks_until_saved();
                }
                self.dirty.insert(key);
                self.touch(key);
                self.clients.insert(
                    key,
                    Proxy {
                        session_id: rep.session_id,
                        addr: from.clone(),
                        streams,
                        pending: BTreeMap::new(),
                        epoch: 0,
                        reported: Vec::new(),
                        last_heard: self.now,
                    },
                );
            }
            self.bind(key, from.clone());
            self.events.push_back(AgentEvent::ClientCreated {
                client: rep.client_key,
                session_id: rep.session_id,
                properties: rep.properties.clone(),
                kept,
            });
        }
        let sub = Submessage::new(Payload::StatusAgent(StatusAgent {
            result: ResultStatus {
                status,
                implementation_status: 0,
            },
            agent: self.cfg.representation.clone(),
        }));
        self.send(&from, reply_header, sub);
    }

    fn on_submessage(
        &mut self,
        key: u32,
        stream: StreamId,
        origin: Option<SeqNum>,
        sub: Submessage,
        now: Instant,
    ) -> Result<(), InputError> {
        let client = ClientKey::from(key);
        let reply_stream = if stream.is_reliable() {
            StreamId::RELIABLE
        } else {
            StreamId::BEST_EFFORT
        };
        let sub_flags = sub.flags;
        let format = sub.data_format();
        let event = match sub.payload {
            Payload::Create(c) => AgentEvent::Create {
                client,
                request: c.request,
                object: c.object,
                mode: CreationMode::from_flags(sub_flags),
                reply_stream,
            },
            Payload::Delete(r) if r.object_id.kind_bits() == ObjectKind::Client as u8 => {
                let status = Submessage::new(Payload::Status(Status {
                    request: r,
                    result: ResultStatus::default(),
                }));
                if let Some(p) = self.clients.get(&key) {
                    let (addr, header) = (p.addr.clone(), p.streams.header());
                    self.send(&addr, header, status);
                }
                self.remove_client(key);
                return Ok(());
            }
            Payload::Delete(request) => AgentEvent::Delete {
                client,
                request,
                reply_stream,
            },
            Payload::WriteData(d) if format == flags::FORMAT_DATA => AgentEvent::Write {
                client,
                request: d.request,
                data: d.data,
                ticket: self.ticket(key, stream, origin),
            },
            Payload::WriteData(_) => return Err(InputError::DataFormat(format)),
            Payload::ReadData(read) => AgentEvent::Read { client, read },
            Payload::GetInfo(g) => {
                let info = self.info(g.request, true);
                self.dirty.insert(key);
                if let Some(p) = self.clients.get_mut(&key) {
                    let _ = p.streams.send_control(info);
                }
                return Ok(());
            }
            Payload::Timestamp(t) => {
                let at = to_time(self.wall_at(now));
                let reply = Submessage::new(Payload::TimestampReply(TimestampReply {
                    transmit: at,
                    receive: at,
                    originate: t,
                }));
                self.dirty.insert(key);
                if let Some(p) = self.clients.get_mut(&key) {
                    let _ = p.streams.send_control(reply);
                }
                return Ok(());
            }
            Payload::Reset => {
                self.dirty.insert(key);
                if let Some(p) = self.clients.get_mut(&key) {
                    p.reset_streams();
                }
                return Ok(());
            }
            p => {
                return Err(InputError::Unexpected {
                    what: p.id().name(),
                    stream: stream.0,
                })
            }
        };
        self.events.push_back(event);
        Ok(())
    }

    /// A ticket for a write completed by message `origin` of reliable
    /// `stream`, counted against that message.
    fn ticket(
        &mut self,
        key: u32,
        stream: StreamId,
        origin: Option<SeqNum>,
    ) -> Option<WriteTicket> {
        if !self.cfg.host_confirms_writes || !stream.is_reliable() {
            return None;
        }
        let seq = origin?;
        self.dirty.insert(key);
        let p = self.clients.get_mut(&key)?;
        let entry = p
            .pending
            .get_mut(&stream.0)?
            .iter_mut()
            .find(|(s, _)| *s == seq)?;
        entry.1 += 1;
        Some(WriteTicket {
            client: ClientKey::from(key),
            stream,
            seq,
            epoch: p.epoch,
        })
    }

    /// The host completed a write ([`AgentEvent::Write::ticket`]): DDS took
    /// the sample, or the host gave it up for good (its writer deleted).
    /// Once every write of a message and of those before it is completed,
    /// the message is acknowledged (an ACKNACK goes out at once). False for
    /// a ticket of a session that is gone or started over.
    pub fn write_done(&mut self, ticket: WriteTicket, now: Instant) -> bool {
        self.tick(now);
        self.dirty.insert(u32::from(ticket.client));
        self.touch(u32::from(ticket.client));
        let Some(p) = self.clients.get_mut(&u32::from(ticket.client)) else {
            return false;
        };
        if p.epoch != ticket.epoch {
            return false;
        }
        let Some(entry) = p
            .pending
            .get_mut(&ticket.stream.0)
            .and_then(|q| q.iter_mut().find(|(s, n)| *s == ticket.seq && *n > 0))
        else {
            return false;
        };
        entry.1 -= 1;
        if p.advance(ticket.stream) {
            if let Some(m) = p.streams.acknack_for(ticket.stream, now) {
                let addr = p.addr.clone();
                self.transmits.push_back((addr, m));
            }
        }
        true
    }

    /// Writes handed to the host and not yet [completed](Self::write_done).
    pub fn writes_pending(&self) -> usize {
        self.clients
            .values()
            .flat_map(|p| p.pending.values())
            .flatten()
            .map(|(_, n)| *n as usize)
            .sum()
    }

    fn proxy(&mut self, client: ClientKey) -> Result<&mut Proxy<A>, AgentCommandError> {
        self.dirty.insert(u32::from(client));
        self.clients
            .get_mut(&u32::from(client))
            .ok_or(AgentCommandError::UnknownClient(client.into()))
    }

    fn queue(
        &mut self,
        client: ClientKey,
        stream: StreamId,
        sub: Submessage,
    ) -> Result<(), AgentCommandError> {
        let p = self.proxy(client)?;
        if stream == StreamId::NONE {
            p.streams.send_control(sub).map_err(QueueError::from)?;
        } else {
            let bytes = p.streams.encode(&sub).map_err(QueueError::from)?;
            p.streams.push(stream, bytes, None, false)?;
        }
        Ok(())
    }

    /// Answers a CREATE, DELETE or READ_DATA: STATUS on `stream`.
    pub fn reply_status(
        &mut self,
        client: ClientKey,
        request: BaseObjectRequest,
        status: StatusCode,
        stream: StreamId,
        now: Instant,
    ) -> Result<(), AgentCommandError> {
        self.tick(now);
        let sub = Submessage::new(Payload::Status(Status {
            request,
            result: ResultStatus {
                status,
                implementation_status: 0,
            },
        }));
        self.queue(client, stream, sub)
    }

    /// Sends a sample (DATA, FORMAT_DATA) for the READ_DATA `read` (its
    /// request id and object) on `stream`. A reliable stream fragments what
    /// does not fit the client's MTU; a best-effort stream refuses it.
    pub fn send_data(
        &mut self,
        client: ClientKey,
        read: BaseObjectRequest,
        stream: StreamId,
        data: &[u8],
        now: Instant,
    ) -> Result<(), AgentCommandError> {
        self.tick(now);
        let sub = Submessage::new(Payload::Data(Data {
            request: read,
            data: data.to_vec(),
        }));
        self.queue(client, stream, sub)
    }

    /// Whether `client` has answered nothing for
    /// [`StreamConfig::silent_after`] while reliable messages waited for it
    /// (it died without DELETE, or its link is down): what is for it is
    /// best not queued further ([`drop_unsent`](Self::drop_unsent)).
    pub fn client_silent(&self, client: ClientKey, now: Instant) -> bool {
        self.clients
            .get(&u32::from(client))
            .is_some_and(|p| p.streams.is_silent(now))
    }

    /// Drops what `client`'s reliable streams queue beyond their windows,
    /// never sent: how many submessages.
    pub fn drop_unsent(&mut self, client: ClientKey) -> usize {
        self.clients
            .get_mut(&u32::from(client))
            .map_or(0, |p| p.streams.drop_unsent())
    }

    /// Time passed; HEARTBEATs that are due go out with the next
    /// [`poll_transmit`](Self::poll_transmit).
    pub fn handle_timeout(&mut self, now: Instant) {
        self.tick(now);
        for (k, p) in &self.clients {
            if p.streams.poll_timeout().is_some_and(|t| t <= now) {
                self.dirty.insert(*k);
            }
        }
        if let Some(limit) = self.cfg.client_timeout {
            let silent: Vec<(u32, Duration)> = self
                .clients
                .iter()
                .map(|(k, p)| (*k, now.saturating_duration_since(p.last_heard)))
                .filter(|(_, d)| *d >= limit)
                .collect();
            for (k, d) in silent {
                self.expire(k, d, None);
            }
        }
    }

    /// When [`handle_timeout`](Self::handle_timeout) is next needed.
    pub fn poll_timeout(&self) -> Option<Instant> {
        let expiry = self.cfg.client_timeout.and_then(|limit| {
            self.clients
                .values()
                .map(|p| crate::time::later(p.last_heard, limit))
                .min()
        });
        self.clients
            .values()
            .filter_map(|p| p.streams.poll_timeout())
            .chain(expiry)
            .min()
    }

    /// The next message: its destination and bytes.
    pub fn poll_transmit(&mut self) -> Option<(A, Vec<u8>)> {
        if let Some(t) = self.transmits.pop_front() {
            return Some(t);
        }
        let now = self.now;
        while let Some(&k) = self.dirty.first() {
            if let Some(p) = self.clients.get_mut(&k) {
                if let Some(m) = p.streams.poll_transmit(now) {
                    return Some((p.addr.clone(), m));
                }
            }
            self.dirty.remove(&k);
        }
        None
    }

    /// The next event for the host.
    pub fn poll_event(&mut self) -> Option<AgentEvent> {
        self.events.pop_front()
    }
}
