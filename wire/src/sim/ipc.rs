//! The CMU IPC machines as stream nodes: [`CentralNode`] is the `central`
//! shell around [`Central`] (accepts, reads unless paused, writes, closes),
//! [`ModuleNode`] the module shell around [`Connection`] (connects to
//! central, and in direct mode listens for and connects to other modules).
//! Both report [`IpcEvent`]s, so they share a network as [`IpcNode`]s, or
//! run alone against a test's own stream ends.

use std::collections::{BTreeMap, HashSet, VecDeque};
use std::time::{Instant, SystemTime};

use super::{Node, StreamId, StreamOp};
use crate::ipc::central::{Central, Config, ConnId, Output, Peer};
use crate::ipc::module::{self, Connection, Event, LinkId, ModuleConfig};

/// What the IPC nodes report.
#[derive(Debug, Clone, PartialEq)]
pub enum IpcEvent {
    /// A module's event.
    Module(Event),
    /// A line of central's log, as central formatted it.
    Log(String),
    /// Central closed a connection (a protocol error, or the module said
    /// goodbye).
    Closed {
        /// Central's end.
        stream: StreamId,
        /// Why.
        reason: String,
    },
}

/// Central on the network: it listens at one address, and its
/// connections are the [`ConnId`]s of its stream ends
/// (`ConnId(stream.0)`).
#[derive(Debug)]
pub struct CentralNode {
    /// The machine, for its console API and counters.
    pub central: Central,
    /// Run [`Central::check_invariants`] after every input: see
    /// [`CentralNode::new`].
    pub check_invariants: bool,
    /// Frames written as a header and a shared body
    /// ([`Output::TransmitBody`]; each is one write on the network).
    pub shared_bodies: usize,
    addr: String,
    paused: HashSet<StreamId>,
    ops: VecDeque<StreamOp<String>>,
    events: VecDeque<IpcEvent>,
    t0: Instant,
    wall0: SystemTime,
    /// The time of the last input.
    now: Instant,
    unchecked: usize,
}

impl CentralNode {
    /// A central listening at `addr`, started at `now` (`wall` on the wall
    /// clock, which its logs show).
    ///
    /// With [`check_invariants`](Self::check_invariants) (on by default)
    /// central's tables must agree with each other after every input. The
    /// check walks every table, so its cost grows with the messages
    /// queued: with more than 8 of them it runs once every `dispatches / 8`
    /// inputs, which keeps floods (hundreds of thousands of inputs, a
    /// thousand messages queued) from taking minutes while a broken link
    /// is still caught within a few inputs.
    pub fn new(config: Config, addr: impl Into<String>, now: Instant, wall: SystemTime) -> Self {
        let mut c = CentralNode {
            central: Central::new_at(config, wall),
            check_invariants: true,
            shared_bodies: 0,
            addr: addr.into(),
            paused: HashSet::new(),
            ops: VecDeque::new(),
            events: VecDeque::new(),
            t0: now,
            wall0: wall,
            now,
            unchecked: 0,
        };
        c.drain(now, true);
        c
    }

    /// Whether central asked not to read `stream` (back-pressure).
    pub fn is_paused(&self, stream: StreamId) -> bool {
        self.paused.contains(&stream)
    }

    fn wall(&self, now: Instant) -> SystemTime {
        self.wall0 + now.saturating_duration_since(self.t0)
    }

    /// Carries out central's outputs after an input (`input`) or a call of
    /// the test's; checks the invariants after either.
    fn drain(&mut self, now: Instant, input: bool) {
        self.now = now;
        let mut any = input;
        while let Some(o) = self.central.poll_output() {
            any = true;
            match o {
                o @ (Output::Transmit { .. } | Output::TransmitBody { .. }) => {
                    if matches!(o, Output::TransmitBody { .. }) {
                        self.shared_bodies += 1;
                    }
                    if let Some((conn, bytes)) = o.transmitted() {
                        self.ops.push_back(StreamOp::Write {
                            stream: StreamId(conn.0),
                            bytes,
                        });
                    }
                }
                Output::Log { line, .. } => self.events.push_back(IpcEvent::Log(line)),
                Output::PauseRead { conn } => {
                    self.paused.insert(StreamId(conn.0));
                }
                Output::ResumeRead { conn } => {
                    self.paused.remove(&StreamId(conn.0));
                }
                Output::Close { conn, reason } => {
                    let stream = StreamId(conn.0);
                    self.ops.push_back(StreamOp::Close { stream });
                    self.events.push_back(IpcEvent::Closed { stream, reason });
                    self.paused.remove(&stream);
                    let wall = self.wall(now);
                    self.central.disconnect(conn, wall);
                }
            }
        }
        if self.check_invariants && any {
            self.unchecked += 1;
            if self.unchecked * 8 >= self.central.stats().dispatches {
                self.central.check_invariants();
                self.unchecked = 0;
            }
        }
    }
}

impl Node for CentralNode {
    type Addr = String;
    type Event = IpcEvent;
    fn address(&self) -> String {
        self.addr.clone()
    }
    fn poll_event(&mut self) -> Option<IpcEvent> {
        self.events.pop_front()
    }
    fn handle_timeout(&mut self, now: Instant) {
        let wall = self.wall(now);
        self.central.handle_timeout(wall);
        self.drain(now, true);
    }
    fn poll_timeout(&self) -> Option<Instant> {
        let at = self.central.next_timeout()?;
        let after = at.duration_since(self.wall0).unwrap_or_default();
        Some(self.t0 + after)
    }
    fn listens(&self, at: &String) -> bool {
        *at == self.addr
    }
    fn handle_accept(&mut self, stream: StreamId, from: String, now: Instant) {
        let wall = self.wall(now);
        self.central
            .connect(ConnId(stream.0), Peer::Tcp(from), wall);
        self.drain(now, true);
    }
    fn handle_stream(&mut self, stream: StreamId, bytes: &[u8], now: Instant) {
        let wall = self.wall(now);
        self.central.receive(ConnId(stream.0), bytes, wall);
        self.drain(now, true);
    }
    fn handle_eof(&mut self, stream: StreamId, now: Instant) {
        let wall = self.wall(now);
        self.central.disconnect(ConnId(stream.0), wall);
        self.paused.remove(&stream);
        self.ops.push_back(StreamOp::Close { stream });
        self.drain(now, true);
    }
    fn reads_stream(&self, stream: StreamId) -> bool {
        !self.paused.contains(&stream)
    }
    fn poll_stream(&mut self) -> Option<StreamOp<String>> {
        if self.ops.is_empty() {
            // What the test's calls (console, reconfigure) made.
            self.drain(self.now, false);
        }
        self.ops.pop_front()
    }
}

/// Token of the connect to central; a direct link's is its [`LinkId`]
/// (from 1).
const CENTRAL: u64 = 0;

/// A module on the network: it connects to central at once, and in direct
/// mode (`central -c`) listens at `<host name>:<port>` for other modules'
/// links and opens its own to theirs.
#[derive(Debug)]
pub struct ModuleNode {
    /// The machine, for the IPC API (publish, subscribe, query, …).
    pub conn: Connection,
    addr: String,
    port: i32,
    central: Option<StreamId>,
    listening: bool,
    links: BTreeMap<StreamId, LinkId>,
    ops: VecDeque<StreamOp<String>>,
    refused: bool,
    /// The connection is over: close the socket once written.
    closing: bool,
    closed: bool,
}

impl ModuleNode {
    /// A module connecting to central at `central`; in direct mode it
    /// listens on `port` of its host name.
    pub fn new(cfg: ModuleConfig, central: impl Into<String>, port: i32, now: Instant) -> Self {
        let addr = format!("{}:{port}", cfg.host_name);
        ModuleNode {
            conn: Connection::new(cfg, now),
            addr,
            port,
            central: None,
            listening: false,
            links: BTreeMap::new(),
            ops: [StreamOp::Connect {
                to: central.into(),
                token: CENTRAL,
            }]
            .into(),
            refused: false,
            closing: false,
            closed: false,
        }
    }

    /// Its end of the connection to central, once connected.
    pub fn central_stream(&self) -> Option<StreamId> {
        self.central
    }

    /// Hangs up `stream` (a link, or central's).
    fn hang_up(&mut self, stream: StreamId) {
        self.links.remove(&stream);
        self.ops.push_back(StreamOp::Close { stream });
    }
}

impl Node for ModuleNode {
    type Addr = String;
    type Event = IpcEvent;
    fn address(&self) -> String {
        self.addr.clone()
    }
    fn poll_event(&mut self) -> Option<IpcEvent> {
        if std::mem::take(&mut self.refused) {
            self.closing = true;
            return Some(IpcEvent::Module(Event::Closed(Some(module::Error::Closed))));
        }
        let e = self.conn.poll_event()?;
        match &e {
            Event::DirectListenRequested => {
                self.listening = true;
                self.conn.announce_direct_port(self.port);
            }
            Event::DirectConnect {
                link, host, port, ..
            } => self.ops.push_back(StreamOp::Connect {
                to: format!("{host}:{port}"),
                token: link.0,
            }),
            Event::Closed(_) => self.closing = true,
            _ => {}
        }
        Some(IpcEvent::Module(e))
    }
    fn listens(&self, at: &String) -> bool {
        self.listening && *at == self.addr
    }
    fn handle_accept(&mut self, stream: StreamId, _from: String, _now: Instant) {
        let link = self.conn.accept_direct();
        self.links.insert(stream, link);
    }
    fn handle_connect(&mut self, token: u64, stream: Option<StreamId>, _now: Instant) {
        match (token, stream) {
            (CENTRAL, Some(s)) => self.central = Some(s),
            (CENTRAL, None) => self.refused = true,
            (link, Some(s)) => {
                self.links.insert(s, LinkId(link));
                self.conn.direct_link_up(LinkId(link));
            }
            (link, None) => self.conn.direct_link_failed(LinkId(link)),
        }
    }
    fn handle_stream(&mut self, stream: StreamId, bytes: &[u8], now: Instant) {
        if self.central == Some(stream) {
            self.conn.receive(bytes, now);
        } else if let Some(&link) = self.links.get(&stream) {
            if self.conn.receive_direct(link, bytes).is_err() {
                self.hang_up(stream);
            }
        }
    }
    fn handle_eof(&mut self, stream: StreamId, _now: Instant) {
        if self.central == Some(stream) {
            self.conn.handle_eof();
            if !std::mem::replace(&mut self.closed, true) {
                self.hang_up(stream);
            }
        } else if self.links.contains_key(&stream) {
            self.hang_up(stream);
        }
    }
    fn poll_stream(&mut self) -> Option<StreamOp<String>> {
        if let Some(op) = self.ops.pop_front() {
            return Some(op);
        }
        if let Some(stream) = self.central {
            if let Some(bytes) = self.conn.poll_transmit() {
                return Some(StreamOp::Write { stream, bytes });
            }
        }
        while let Some((link, bytes)) = self.conn.poll_direct_transmit() {
            // (A link that failed or closed: its bytes go nowhere.)
            if let Some((&stream, _)) = self.links.iter().find(|(_, l)| **l == link) {
                return Some(StreamOp::Write { stream, bytes });
            }
        }
        match self.central {
            Some(stream) if self.closing && !std::mem::replace(&mut self.closed, true) => {
                Some(StreamOp::Close { stream })
            }
            _ => None,
        }
    }
}

/// Central or a module: the nodes of an IPC network.
// A simulated network has one central: its size is not worth a box that
// every test would have to write.
#[allow(clippy::large_enum_variant)]
#[derive(Debug)]
pub enum IpcNode {
    /// The central server.
    Central(CentralNode),
    /// A module.
    Module(ModuleNode),
}

impl IpcNode {
    /// The central, if this is it.
    pub fn central(&mut self) -> Option<&mut CentralNode> {
        match self {
            IpcNode::Central(c) => Some(c),
            IpcNode::Module(_) => None,
        }
    }

    /// The module, if this is one.
    pub fn module(&mut self) -> Option<&mut ModuleNode> {
        match self {
            IpcNode::Module(m) => Some(m),
            IpcNode::Central(_) => None,
        }
    }
}

/// `each!(node, n => expr)`: `expr` on whichever node it is.
macro_rules! each {
    ($node:expr, $n:ident => $e:expr) => {
        match $node {
            IpcNode::Central($n) => $e,
            IpcNode::Module($n) => $e,
        }
    };
}

impl Node for IpcNode {
    type Addr = String;
    type Event = IpcEvent;
    fn address(&self) -> String {
        each!(self, n => n.address())
    }
    fn poll_event(&mut self) -> Option<IpcEvent> {
        each!(self, n => n.poll_event())
    }
    fn handle_timeout(&mut self, now: Instant) {
        each!(self, n => n.handle_timeout(now))
    }
    fn poll_timeout(&self) -> Option<Instant> {
        each!(self, n => n.poll_timeout())
    }
    fn listens(&self, at: &String) -> bool {
        each!(self, n => n.listens(at))
    }
    fn handle_accept(&mut self, stream: StreamId, from: String, now: Instant) {
        each!(self, n => n.handle_accept(stream, from, now))
    }
    fn handle_connect(&mut self, token: u64, stream: Option<StreamId>, now: Instant) {
        each!(self, n => n.handle_connect(token, stream, now))
    }
    fn handle_stream(&mut self, stream: StreamId, bytes: &[u8], now: Instant) {
        each!(self, n => n.handle_stream(stream, bytes, now))
    }
    fn handle_eof(&mut self, stream: StreamId, now: Instant) {
        each!(self, n => n.handle_eof(stream, now))
    }
    fn reads_stream(&self, stream: StreamId) -> bool {
        each!(self, n => n.reads_stream(stream))
    }
    fn poll_stream(&mut self) -> Option<StreamOp<String>> {
        each!(self, n => n.poll_stream())
    }
}
