//! Sans-I/O state machine of an IPC *module* (client) talking to a C CMU IPC
//! 3.9 central (ipc.md §1–§8), quinn-proto style: no sockets, no clocks.
//!
//! The async shell feeds every byte read from central into
//! [`Connection::receive`], writes whatever [`Connection::poll_transmit`]
//! returns, and reacts to [`Connection::poll_event`].
//!
//! # Ordering model
//! The C API is synchronous: a call that needs a query (a `msgInfo` lookup,
//! `x_ipc_moduleConnectedQ`, …) blocks until its reply arrives. To keep the
//! wire byte-identical (msgRefs are a per-connection counter) API operations
//! are executed strictly in call order from one queue; an operation that
//! needs a reply holds the queue until it arrives. User queries are the
//! exception: like `IPC_queryNotify` they do not hold the queue; the reply is
//! matched by msgRef and reported as [`Event::Reply`].
//!
//! Deliveries are buffered on arrival and processed when the shell calls
//! [`Connection::poll_event`] (C's `IPC_listen`), one at a time: the first
//! delivery to a handler triggers the C module's `msgInfo(msg, handlerName)`
//! lookup before the delivery is reported, and API operations wait until
//! that internal "handler" has finished (C nests handlers the same way).
//! Broadcast deliveries are *not* auto-acked: the shell calls
//! [`Connection::ack`] once the user has taken the message (central keeps at
//! most `capacity` deliveries outstanding until acks come back). Query
//! deliveries are completed by [`Connection::respond`], at any time and in
//! any order (`IPC_delayResponse`). Internal deliveries (`V_watch_*`,
//! connect notifications) are acked by the state machine itself, after
//! processing, as C does.
//!
//! Direct mode (§8), sending side: the first send of a direct message (negative
//! id) runs `x_ipc_directMsgQuery`, raises [`Event::DirectConnect`] for each
//! receiver without a link, subscribes `V_watch_<msg>` to follow changes, and
//! holds the send (and the operations after it) until every link is up or
//! failed — the message is never dropped for want of a receiver list.
//! Frames for links come from [`Connection::poll_direct_transmit`]; bytes
//! read from links (ours or accepted with [`Connection::accept_direct`]) go
//! to [`Connection::receive_direct`]: deliveries (no Success ack on links)
//! and replies to direct queries; [`Connection::respond`] to a direct query
//! answers on the same link. Not implemented: the extra log-var watches C
//! adds in direct mode, and closing links nobody needs any more.

mod proto;

use std::collections::{HashMap, HashSet, VecDeque};
use std::time::Instant;

use super::frame::{
    ClassId, Deframer, Frame, FrameError, Header, MsgClass, NO_REF, QUERY_REPLY_INTENT,
};
use super::{ByteOrder, Reader, Writer};
use crate::format::Format;

pub use proto::MsgInfo;

/// Largest frame body (class data + message data) accepted from central.
pub const DEFAULT_MAX_FRAME: u64 = 64 * 1024 * 1024;

/// Most deliveries buffered before the shell takes them with
/// [`Connection::poll_event`]; central sends at most `capacity` outstanding
/// deliveries plus notifications, so more means a misbehaving peer.
pub const MAX_QUEUED_DELIVERIES: usize = 65_536;

/// `blocked` marker: a direct send waits for its links.
const LINK_WAIT: i32 = i32::MIN + 1;

/// First handler id handed out (C's handler id table counts down from 199).
pub const FIRST_HANDLER_ID: i32 = 199;

/// Classes the C module asks central about during the handshake, in order.
pub const HANDSHAKE_CLASSES: [i32; 10] = [4, 5, 7, 9, 8, 10, 2, 13, 14, 16];

/// Configuration of a module connection.
#[derive(Debug, Clone)]
pub struct ModuleConfig {
    /// Module name (`IPC_connect` argument).
    pub name: String,
    /// Host name reported to central (truncated to 32 bytes as C does).
    pub host_name: String,
    /// `false` = `IPC_connectNoListen`: publishes are not filtered by
    /// `X_IPC_BROADCAST_MSG_VAR`.
    pub listen: bool,
    /// Largest frame body accepted from central.
    pub max_frame: u64,
}

impl ModuleConfig {
    /// A listening module with the default frame limit.
    pub fn new(name: impl Into<String>, host_name: impl Into<String>) -> Self {
        ModuleConfig {
            name: name.into(),
            host_name: host_name.into(),
            listen: true,
            max_frame: DEFAULT_MAX_FRAME,
        }
    }
}

/// Why an operation was refused or the connection failed.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// The connection is closed (or failed).
    #[error("IPC connection is closed")]
    Closed,
    /// A frame header from central was invalid.
    #[error("bad frame from central: {0}")]
    Frame(#[from] FrameError),
    /// Central sent data that could not be decoded.
    #[error("undecodable {what} from central: {detail}")]
    Protocol {
        /// What was being decoded.
        what: &'static str,
        /// The decoder's message.
        detail: String,
    },
    /// Central does not know a message name.
    #[error("message {0:?} is not defined in central")]
    UnknownMessage(String),
    /// Central speaks another major protocol version.
    #[error("central speaks IPC {major}.{minor}, this module 3.9")]
    Version {
        /// Central's major version.
        major: i32,
        /// Central's minor version.
        minor: i32,
    },
    /// The user data does not fit the message's fixed length.
    #[error("message {msg:?} has fixed length {expected}, got {got} bytes")]
    WrongLength {
        /// Message name.
        msg: String,
        /// Fixed length.
        expected: usize,
        /// Given length.
        got: usize,
    },
    /// Unknown delivery or handler handle.
    #[error("unknown handle {0}")]
    UnknownHandle(u64),
}

/// Length discipline of a message (`IPC_defineMsg`'s length argument).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MsgLength {
    /// `IPC_VARIABLE_LENGTH`: body `{int, <byte:1>}`.
    Variable,
    /// Fixed N bytes: body `[byte:N]`.
    Fixed(u32),
    /// No data.
    Empty,
}

/// Handle of a direct (module-to-module) link, §8.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct LinkId(pub u64);

/// One receiver of a direct message (`directMsgHandler`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DirectHandler {
    /// The receiver's handler id (intent of frames sent to it).
    pub intent: i32,
    /// The receiver's listen port.
    pub port: i32,
    /// The receiver's host name.
    pub host: String,
    /// The receiver's module name.
    pub module: String,
}

/// Handle of an API operation (publish, query, …), unique per connection.
pub type OpId = u64;
/// Handle of a delivery awaiting [`Connection::ack`] or [`Connection::respond`].
pub type DeliveryId = u64;

/// Class of a delivery.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DeliveryKind {
    /// A published message (needs [`Connection::ack`]).
    Broadcast,
    /// A query (needs [`Connection::respond`]).
    Query,
}

/// Something the shell must know about.
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
pub enum Event {
    /// Central answered `newModuleConnect` with `direct = 1`: open a listener
    /// and call [`Connection::announce_direct_port`].
    DirectListenRequested,
    /// The handshake is complete (`IPC_connect` returned).
    Connected,
    /// A message for one of our handlers.
    Delivery {
        /// Handle for [`Connection::ack`] / [`Connection::respond`].
        delivery: DeliveryId,
        /// Our handler id (the frame's intent).
        handler: i32,
        /// Message name.
        msg: String,
        /// Broadcast or query.
        kind: DeliveryKind,
        /// Central's dispatch id.
        dispatch_ref: i32,
        /// Parent ref of the frame.
        parent_ref: i32,
        /// Byte order of `data`.
        order: ByteOrder,
        /// User bytes, unwrapped from the message format.
        data: Vec<u8>,
    },
    /// Reply to a [`Connection::query`].
    Reply {
        /// The query's handle.
        query: OpId,
        /// Reply message name (class data).
        reply_msg: String,
        /// Byte order of `data`.
        order: ByteOrder,
        /// User bytes, unwrapped according to the reply message's format
        /// when it is known to this module, else the raw body.
        data: Vec<u8>,
    },
    /// A publish was executed and sent to central.
    Published {
        /// The publish's handle.
        op: OpId,
    },
    /// A publish was dropped because no module subscribes the message
    /// (C's `x_ipcBroadcast` does this silently).
    PublishDropped {
        /// The publish's handle.
        op: OpId,
        /// Message name.
        msg: String,
    },
    /// A message for one of our handlers whose body does not hold together
    /// (its variable-length wrapper disagrees with itself). It was not
    /// delivered; central was told it is done (a Success), so the sender of
    /// a query gets no reply. The connection is unharmed: one bad sender
    /// must not cut a module off from everyone else.
    Undeliverable {
        /// Our handler id.
        handler: i32,
        /// Message name.
        msg: String,
        /// Published or queried.
        kind: DeliveryKind,
        /// What was wrong with it.
        error: Error,
    },
    /// An operation failed (e.g. its message is unknown to central).
    OpFailed {
        /// The operation's handle.
        op: OpId,
        /// Why.
        error: Error,
    },
    /// Answer of [`Connection::is_module_connected`].
    ModuleConnected {
        /// The operation's handle.
        op: OpId,
        /// Whether the module is connected.
        connected: bool,
    },
    /// Answer of [`Connection::num_handlers`].
    NumHandlers {
        /// The operation's handle.
        op: OpId,
        /// Handler count.
        count: i32,
    },
    /// `x_ipc_connectNotify`: a module connected.
    ModuleConnect(String),
    /// `x_ipc_disconnectNotify`: a module disconnected.
    ModuleDisconnect(String),
    /// `V_watch_<msg>`: the handler count of `msg` changed.
    HandlerChange {
        /// Message name.
        msg: String,
        /// New handler count.
        count: i32,
    },
    /// Direct mode: connect to a receiver's listener (TCP, or the UNIX socket
    /// `/tmp/x_ipc/<port>` when `host` is our host name), then call
    /// [`Connection::direct_link_up`] or [`Connection::direct_link_failed`].
    /// Sends of direct messages wait until then (nothing is lost).
    DirectConnect {
        /// The link's handle.
        link: LinkId,
        /// Receiver's reported host name.
        host: String,
        /// Receiver's listen port.
        port: i32,
        /// Receiver's module name.
        module: String,
    },
    /// The connection failed or was closed; nothing more will happen.
    Closed(Option<Error>),
}

#[derive(Debug)]
enum Stage {
    /// Waiting for the raw 4-byte msgInfo id.
    MsgInfoId,
    /// Waiting for the two formatter frames.
    Formatters(u8),
    /// Handshake running through the op queue.
    Handshake,
    /// Connected.
    Ready,
    /// Closed.
    Closed,
}

#[derive(Debug)]
struct Handler {
    msg: String,
    name: String,
    /// Central has been told (first delivery lookup done).
    known: bool,
    kind: HandlerKind,
}

#[derive(Debug, Clone, PartialEq)]
enum HandlerKind {
    User,
    BroadcastVar,
    ConnectNotify,
    DisconnectNotify,
    Watch(String),
    DirectWatch(String),
}

#[derive(Debug)]
enum Op {
    ClassInfo(i32),
    NewModuleConnect,
    WaitDirectPort,
    DirectRes(i32),
    VarGet(&'static str),
    RegisterHandler {
        id: i32,
        msg: String,
        hnd: String,
    },
    LimitPending {
        msg: String,
        limit: i32,
    },
    WaitMsg,
    DefineFormat {
        name: String,
        fmt: String,
    },
    DefineMsg {
        name: String,
        len: MsgLength,
        fmt: Option<String>,
    },
    Lookup(String),
    DirectQuery {
        msg: String,
    },
    Deregister {
        msg: String,
        hnd: String,
    },
    Publish {
        op: OpId,
        msg: String,
        data: Vec<u8>,
        parent: i32,
    },
    Query {
        op: OpId,
        msg: String,
        data: Vec<u8>,
        parent: i32,
    },
    Respond {
        msg: String,
        data: Vec<u8>,
        dispatch: i32,
        parent: i32,
        link: Option<LinkId>,
    },
    Inform {
        msg: &'static str,
        data: Vec<u8>,
    },
    ModuleConnectedQ {
        op: OpId,
        module: String,
    },
    NumHandlers {
        op: OpId,
        msg: String,
    },
    NotifyHandlerChange {
        msg: String,
    },
    Close,
}

#[derive(Debug)]
enum Pending {
    Lookup(String),
    HandlerLookup(u64),
    Internal(Op),
    UserQuery(OpId),
    /// A reply whose message must be looked up before it can be unwrapped.
    ReplyLookup {
        query: OpId,
        reply_msg: String,
        order: ByteOrder,
        data: Vec<u8>,
    },
}

#[derive(Debug)]
struct PendingDelivery {
    id: DeliveryId,
    frame: Frame,
    msg: String,
    ready: bool,
    link: Option<LinkId>,
}

/// The module side of one connection to central.
#[derive(Debug)]
pub struct Connection {
    cfg: ModuleConfig,
    stage: Stage,
    /// The 4-byte msgInfo id that opens central's stream, as it arrives.
    prefix: Vec<u8>,
    /// Central's frames.
    deframer: Deframer,
    msg_info_id: i32,
    next_ref: i32,
    next_handler: i32,
    next_op: u64,
    next_delivery: u64,
    cache: HashMap<String, MsgInfo>,
    ops: VecDeque<Op>,
    blocked: Option<i32>,
    pending: HashMap<i32, Pending>,
    handlers: HashMap<i32, Handler>,
    by_name: HashMap<(String, String), i32>,
    /// Ids of unsubscribed handlers, kept for the same (message, handler
    /// name): central keeps a handler's record and its first id, and
    /// delivers to that id if it is subscribed again (`x_ipc_deregisterHnd`
    /// only unlinks it). Never given to another handler.
    retired: HashMap<(String, String), i32>,
    deliveries: VecDeque<PendingDelivery>,
    inbox: VecDeque<(Frame, Option<LinkId>)>,
    link_in: HashMap<LinkId, Deframer>,
    direct_handlers: HashMap<String, Vec<DirectHandler>>,
    links: HashMap<(String, i32), (LinkId, bool)>,
    next_link: u64,
    direct_tx: VecDeque<(LinkId, Vec<u8>)>,
    unknown: HashSet<String>,
    unacked: HashMap<DeliveryId, (DeliveryKind, i32, Option<LinkId>)>,
    broadcast_var: Option<HashSet<String>>,
    /// Messages central counted handlers for that no list from it has
    /// named yet (see [`Connection::set_broadcast_list`]).
    counted: HashSet<String>,
    class_formats: Vec<(i32, Option<Format>)>,
    direct: bool,
    transmit: VecDeque<Vec<u8>>,
    events: VecDeque<Event>,
    connect_subscribed: bool,
    disconnect_subscribed: bool,
}

impl Connection {
    /// Starts a connection; central speaks first (§4), so nothing is sent
    /// until [`receive`](Self::receive) got the msgInfo id and formatters.
    pub fn new(mut cfg: ModuleConfig, _now: Instant) -> Self {
        let mut cut = cfg.host_name.len().min(32);
        while !cfg.host_name.is_char_boundary(cut) {
            cut -= 1;
        }
        cfg.host_name.truncate(cut);
        let max_frame = cfg.max_frame;
        Connection {
            cfg,
            stage: Stage::MsgInfoId,
            prefix: Vec::with_capacity(4),
            deframer: Deframer::new(max_frame),
            msg_info_id: 0,
            next_ref: 1,
            next_handler: FIRST_HANDLER_ID,
            next_op: 1,
            next_delivery: 1,
            cache: HashMap::new(),
            ops: VecDeque::new(),
            blocked: None,
            pending: HashMap::new(),
            handlers: HashMap::new(),
            by_name: HashMap::new(),
            retired: HashMap::new(),
            deliveries: VecDeque::new(),
            inbox: VecDeque::new(),
            link_in: HashMap::new(),
            direct_handlers: HashMap::new(),
            links: HashMap::new(),
            next_link: 1,
            direct_tx: VecDeque::new(),
            unknown: HashSet::new(),
            unacked: HashMap::new(),
            broadcast_var: None,
            counted: HashSet::new(),
            class_formats: Vec::new(),
            direct: false,
            transmit: VecDeque::new(),
            events: VecDeque::new(),
            connect_subscribed: false,
            disconnect_subscribed: false,
        }
    }

    /// Whether the handshake has completed and the connection is open.
    pub fn is_connected(&self) -> bool {
        matches!(self.stage, Stage::Ready)
    }

    /// Whether central runs in direct mode (`central -c`).
    pub fn is_direct(&self) -> bool {
        self.direct
    }

    /// The cached `msgInfo` of a message, if looked up.
    pub fn msg_info(&self, name: &str) -> Option<&MsgInfo> {
        self.cache.get(name)
    }

    /// Class formats central reported during the handshake.
    pub fn class_formats(&self) -> &[(i32, Option<Format>)] {
        &self.class_formats
    }

    /// Whether the connection waits for input from central before it can
    /// make progress (an internal query or a handler lookup is outstanding).
    pub fn is_waiting(&self) -> bool {
        self.blocked.is_some() || !self.deliveries.is_empty()
    }

    /// Whether deliveries wait to be processed by [`poll_event`](Self::poll_event).
    pub fn has_pending_deliveries(&self) -> bool {
        !self.inbox.is_empty()
    }

    /// Whether [`poll_transmit`](Self::poll_transmit) has bytes.
    pub fn has_transmit(&self) -> bool {
        !self.transmit.is_empty()
    }

    /// Next bytes to write to central, in order. A large message's data
    /// comes as a buffer of its own after its header's (it is not copied
    /// behind it, see [`Frame::into_parts`]): a vectored write sends them
    /// together.
    pub fn poll_transmit(&mut self) -> Option<Vec<u8>> {
        self.transmit.pop_front()
    }

    /// Next event for the shell.
    ///
    /// Deliveries are processed here, one at a time, as C's `IPC_listen`
    /// does: the first delivery to a handler sends the `msgInfo(msg,
    /// handler)` lookup and is reported once its reply arrived.
    pub fn poll_event(&mut self) -> Option<Event> {
        loop {
            if let Some(e) = self.events.pop_front() {
                return Some(e);
            }
            if !self.deliveries.is_empty() || matches!(self.stage, Stage::Closed) {
                return None;
            }
            let (f, link) = self.inbox.pop_front()?;
            if let Err(e) = self.start_delivery(f, link) {
                self.fail(e);
            }
            self.pump();
        }
    }

    /// No timers: query timeouts are the shell's job ([`cancel_query`](Self::cancel_query)).
    pub fn poll_timeout(&self) -> Option<Instant> {
        None
    }

    /// Forgets a user query; a late reply is ignored.
    pub fn cancel_query(&mut self, query: OpId) {
        self.pending
            .retain(|_, p| !matches!(p, Pending::UserQuery(q) | Pending::ReplyLookup { query: q, .. } if *q == query));
    }

    /// Feeds bytes read from central, in any split.
    pub fn receive(&mut self, mut bytes: &[u8], _now: Instant) {
        if matches!(self.stage, Stage::MsgInfoId) {
            let take = (4 - self.prefix.len()).min(bytes.len());
            self.prefix.extend_from_slice(&bytes[..take]);
            bytes = &bytes[take..];
            let Ok(id) = <[u8; 4]>::try_from(&self.prefix[..]) else {
                return;
            };
            self.msg_info_id = i32::from_be_bytes(id);
            self.stage = Stage::Formatters(0);
        }
        while !matches!(self.stage, Stage::Closed) {
            let res = match self.deframer.next(&mut bytes) {
                Ok(Some(frame)) => self.handle_frame(frame),
                Ok(None) => return,
                Err(e) => Err(e.into()),
            };
            if let Err(e) = res {
                self.fail(e);
            }
        }
    }

    /// Central closed the stream (EOF).
    pub fn handle_eof(&mut self) {
        if !matches!(self.stage, Stage::Closed) {
            self.stage = Stage::Closed;
            self.events.push_back(Event::Closed(None));
        }
    }

    fn fail(&mut self, e: Error) {
        self.stage = Stage::Closed;
        self.deframer.reset();
        self.ops.clear();
        self.events.push_back(Event::Closed(Some(e)));
    }

    fn handle_frame(&mut self, f: Frame) -> Result<(), Error> {
        match self.stage {
            Stage::Formatters(k) => {
                // Contents are fixed by the protocol ({string, string} and
                // *{int, string, int, format, format}); decode to validate.
                let order = data_order(&f.header)?;
                let mut r = Reader::new(&f.data, order);
                crate::format::decode_formatter(&mut r).map_err(|e| proto_err("formatter", e))?;
                if k == 0 {
                    self.stage = Stage::Formatters(1);
                } else {
                    self.stage = Stage::Handshake;
                    for c in HANDSHAKE_CLASSES {
                        self.ops.push_back(Op::ClassInfo(c));
                    }
                    self.ops.push_back(Op::NewModuleConnect);
                    self.pump();
                }
                Ok(())
            }
            _ => {
                let h = f.header;
                if h.intent == QUERY_REPLY_INTENT {
                    self.handle_reply(f)
                } else if h.intent >= 0 {
                    self.handle_delivery(f)
                } else {
                    Err(Error::Protocol {
                        what: "frame",
                        detail: format!("unexpected intent {}", h.intent),
                    })
                }
            }
        }
    }

    // ---- outgoing frames -------------------------------------------------

    fn next_msg_ref(&mut self) -> i32 {
        let r = self.next_ref;
        self.next_ref = self.next_ref.wrapping_add(1);
        if self.next_ref < 1 {
            self.next_ref = 1;
        }
        r
    }

    fn send(
        &mut self,
        intent: i32,
        class: MsgClass,
        parent: i32,
        class_data: Vec<u8>,
        data: Vec<u8>,
    ) -> i32 {
        self.send_ref(intent, class, parent, NO_REF, class_data, data, None)
    }

    #[allow(clippy::too_many_arguments)]
    fn send_ref(
        &mut self,
        intent: i32,
        class: MsgClass,
        parent: i32,
        dispatch: i32,
        class_data: Vec<u8>,
        data: Vec<u8>,
        msg_ref: Option<i32>,
    ) -> i32 {
        let msg_ref = msg_ref.unwrap_or_else(|| self.next_msg_ref());
        let frame = Frame {
            header: Header {
                class_total: 0,
                msg_total: 0,
                parent_ref: parent,
                intent,
                class_id: ClassId::native(class),
                dispatch_ref: dispatch,
                msg_ref,
            },
            class_data,
            data,
        };
        let (head, data) = frame.into_parts();
        self.transmit.push_back(head);
        self.transmit.extend(data);
        msg_ref
    }

    fn send_lookup(&mut self, name: &str, hnd: Option<&str>, parent: i32) -> i32 {
        let mut w = Writer::new();
        w.write_str(name);
        w.write_str(hnd.unwrap_or(""));
        let id = self.msg_info_id;
        self.send(id, MsgClass::Query, parent, Vec::new(), w.into_vec())
    }

    // ---- op queue --------------------------------------------------------

    fn push_op(&mut self, op: Op) {
        self.ops.push_back(op);
        self.pump();
    }

    fn alloc_op(&mut self) -> OpId {
        let id = self.next_op;
        self.next_op += 1;
        id
    }

    /// Runs queued operations until one waits for a reply.
    fn pump(&mut self) {
        // Like C, an internal handler that is still running (waiting for its
        // msgInfo lookup) finishes before the next API operation runs.
        while self.blocked.is_none() && self.deliveries.is_empty() {
            if matches!(
                self.stage,
                Stage::Closed | Stage::MsgInfoId | Stage::Formatters(_)
            ) {
                return;
            }
            let Some(op) = self.ops.pop_front() else {
                return;
            };
            // Every op needs the id of one message first.
            let need = proto::op_message(&op);
            if let Some(name) = need {
                if !self.cache.contains_key(&name) && !self.unknown.contains(&name) {
                    // C sends the lookup with the parentRef of the
                    // operation (the dispatch being handled, if any).
                    let parent = proto::op_parent(&op);
                    let r = self.send_lookup(&name, None, parent);
                    self.pending.insert(r, Pending::Lookup(name));
                    self.blocked = Some(r);
                    self.ops.push_front(op);
                    return;
                }
            }
            self.execute(op);
        }
    }

    fn info(&self, name: &str) -> Option<MsgInfo> {
        self.cache.get(name).cloned()
    }

    fn execute(&mut self, op: Op) {
        let name = proto::op_message(&op).unwrap_or_default();
        let known = self.info(&name);
        let unknown = !name.is_empty() && known.is_none() && self.unknown.remove(&name);
        let info = known.unwrap_or_default();
        if unknown || (info.id == 0 && !name.is_empty()) {
            // Central does not know the message.
            let err = Error::UnknownMessage(name.clone());
            match op {
                Op::Publish { op, .. }
                | Op::Query { op, .. }
                | Op::ModuleConnectedQ { op, .. }
                | Op::NumHandlers { op, .. } => {
                    self.events.push_back(Event::OpFailed { op, error: err })
                }
                _ => {
                    if matches!(self.stage, Stage::Handshake) {
                        self.fail(err);
                    }
                }
            }
            return;
        }
        let intent = info.id.abs();
        match op {
            Op::ClassInfo(c) => {
                let mut w = Writer::new();
                w.write_i32(c);
                self.query_blocking(intent, w.into_vec(), Op::ClassInfo(c));
            }
            Op::NewModuleConnect => {
                let mut w = Writer::new();
                w.write_str(&self.cfg.name);
                w.write_str(&self.cfg.host_name);
                self.query_blocking(intent, w.into_vec(), Op::NewModuleConnect);
            }
            Op::WaitDirectPort => {
                // Held until announce_direct_port.
                self.ops.push_front(Op::WaitDirectPort);
                self.blocked = Some(i32::MIN);
            }
            Op::DirectRes(port) => {
                let mut w = Writer::new();
                w.write_i32(port);
                w.write_str(&self.cfg.name);
                self.send(intent, MsgClass::Inform, NO_REF, Vec::new(), w.into_vec());
            }
            Op::VarGet(v) => self.query_blocking(intent, Vec::new(), Op::VarGet(v)),
            Op::RegisterHandler { msg, hnd, id } => {
                let mut w = Writer::new();
                w.write_i32(id);
                w.write_str(&msg);
                w.write_str(&hnd);
                self.send(intent, MsgClass::Inform, NO_REF, Vec::new(), w.into_vec());
            }
            Op::Deregister { msg, hnd } => {
                let mut w = Writer::new();
                w.write_i32(0);
                w.write_str(&msg);
                w.write_str(&hnd);
                self.send(intent, MsgClass::Inform, NO_REF, Vec::new(), w.into_vec());
            }
            Op::LimitPending { msg, limit } => {
                let mut w = Writer::new();
                w.write_str(&msg);
                w.write_str(&self.cfg.name);
                w.write_i32(limit);
                self.send(intent, MsgClass::Inform, NO_REF, Vec::new(), w.into_vec());
            }
            Op::WaitMsg => self.query_blocking(intent, Vec::new(), Op::WaitMsg),
            Op::DefineFormat { name, fmt } => {
                let mut w = Writer::new();
                w.write_str(&name);
                w.write_str(&fmt);
                self.send(intent, MsgClass::Inform, NO_REF, Vec::new(), w.into_vec());
            }
            Op::DefineMsg { name, len, fmt } => {
                let mut w = Writer::new();
                w.write_str(&name);
                w.write_i32(MsgClass::Broadcast as i32);
                match len {
                    MsgLength::Variable => w.write_str("{int, <byte:1>}"),
                    MsgLength::Fixed(n) => w.write_str(&format!("[byte:{n}]")),
                    MsgLength::Empty => w.write_str(""),
                }
                w.write_str(fmt.as_deref().unwrap_or(""));
                self.send(intent, MsgClass::Inform, NO_REF, Vec::new(), w.into_vec());
                // No lookup here (C defers it to the first use); a
                // redefinition may change the formats, so forget the cache.
                self.cache.remove(&name);
            }
            Op::Lookup(_) => {}
            Op::DirectQuery { msg } => {
                let mut w = Writer::new();
                w.write_str(&msg);
                self.query_blocking(intent, w.into_vec(), Op::DirectQuery { msg });
            }
            Op::Publish {
                op,
                msg,
                data,
                parent,
            } => {
                if info.id < 0 {
                    self.direct_send(
                        Op::Publish {
                            op,
                            msg,
                            data,
                            parent,
                        },
                        &info,
                    );
                    return;
                }
                if self.cfg.listen && info.class == MsgClass::Broadcast as i32 {
                    if let Some(list) = &self.broadcast_var {
                        if !list.contains(&msg) {
                            self.events.push_back(Event::PublishDropped { op, msg });
                            return;
                        }
                    }
                }
                match proto::wrap(&info, &msg, data) {
                    Ok(body) => {
                        let class =
                            MsgClass::from_u16(info.class as u16).unwrap_or(MsgClass::Broadcast);
                        self.send(intent, class, parent, Vec::new(), body);
                        self.events.push_back(Event::Published { op });
                    }
                    Err((error, _)) => self.events.push_back(Event::OpFailed { op, error }),
                }
            }
            Op::Query {
                op,
                msg,
                data,
                parent,
            } => {
                if info.id < 0 {
                    self.direct_send(
                        Op::Query {
                            op,
                            msg,
                            data,
                            parent,
                        },
                        &info,
                    );
                    return;
                }
                match proto::wrap(&info, &msg, data) {
                    Ok(body) => {
                        let r = self.send(intent, MsgClass::Query, parent, Vec::new(), body);
                        self.pending.insert(r, Pending::UserQuery(op));
                    }
                    Err((error, _)) => self.events.push_back(Event::OpFailed { op, error }),
                }
            }
            Op::Respond {
                msg,
                data,
                dispatch,
                parent,
                link,
            } => {
                let body = proto::wrap(&info, &msg, data).unwrap_or_else(|(_, data)| data);
                let mut cd = Writer::new();
                cd.write_str(&msg);
                if let Some(link) = link {
                    // Direct reply: back on the same link, intent -4,
                    // dispatchRef = msgRef = the query's msgRef (§8).
                    let frame = Frame {
                        header: Header {
                            class_total: 0,
                            msg_total: 0,
                            parent_ref: NO_REF,
                            intent: QUERY_REPLY_INTENT,
                            class_id: ClassId::native(MsgClass::Reply),
                            dispatch_ref: dispatch,
                            msg_ref: dispatch,
                        },
                        class_data: cd.into_vec(),
                        data: body,
                    };
                    self.push_direct(link, frame);
                    return;
                }
                self.send_ref(
                    NO_REF,
                    MsgClass::Reply,
                    parent,
                    dispatch,
                    cd.into_vec(),
                    body,
                    Some(NO_REF),
                );
            }
            Op::Inform { data, .. } => {
                self.send(intent, MsgClass::Inform, NO_REF, Vec::new(), data);
            }
            Op::ModuleConnectedQ { op, module } => {
                let mut w = Writer::new();
                w.write_str(&module);
                self.query_blocking(intent, w.into_vec(), Op::ModuleConnectedQ { op, module });
            }
            Op::NumHandlers { op, msg } => {
                let mut w = Writer::new();
                w.write_str(&msg);
                self.query_blocking(intent, w.into_vec(), Op::NumHandlers { op, msg });
            }
            Op::NotifyHandlerChange { msg } => {
                let mut w = Writer::new();
                w.write_str(&msg);
                self.send(intent, MsgClass::Inform, NO_REF, Vec::new(), w.into_vec());
            }
            Op::Close => {
                self.send(intent, MsgClass::Inform, NO_REF, Vec::new(), Vec::new());
                self.stage = Stage::Closed;
                self.events.push_back(Event::Closed(None));
            }
        }
    }

    fn query_blocking(&mut self, intent: i32, data: Vec<u8>, op: Op) {
        let r = self.send(intent, MsgClass::Query, NO_REF, Vec::new(), data);
        self.pending.insert(r, Pending::Internal(op));
        self.blocked = Some(r);
    }

    // ---- incoming --------------------------------------------------------

    fn handle_reply(&mut self, f: Frame) -> Result<(), Error> {
        let r = f.header.msg_ref;
        let Some(p) = self.pending.remove(&r) else {
            // Reply to a cancelled query: ignore.
            return Ok(());
        };
        if self.blocked == Some(r) {
            self.blocked = None;
        }
        let order = data_order(&f.header)?;
        match p {
            Pending::Lookup(name) => {
                let info = proto::decode_msg_info(&f.data, order)?;
                // Unknown names are not cached (C asks again next time:
                // another module may define the message meanwhile).
                match info {
                    Some(info) => {
                        self.cache.insert(name, info);
                    }
                    None => {
                        self.unknown.insert(name);
                    }
                }
            }
            Pending::HandlerLookup(did) => {
                let info = proto::decode_msg_info(&f.data, order)?;
                if let Some(d) = self.deliveries.iter_mut().find(|d| d.id == did) {
                    if let Some(info) = info {
                        self.cache.entry(d.msg.clone()).or_insert(info);
                    }
                    d.ready = true;
                }
                self.flush_deliveries();
            }
            Pending::UserQuery(query) => {
                let reply_msg = if f.class_data.is_empty() {
                    String::new()
                } else {
                    let co = class_order(&f.header)?;
                    let mut cr = Reader::new(&f.class_data, co);
                    cr.read_str()
                        .map_err(|e| proto_err("reply class data", e))?
                        .to_string()
                };
                if !reply_msg.is_empty() && !self.cache.contains_key(&reply_msg) {
                    // Like C's msgFind: look the reply message up, then
                    // unmarshall with its format.
                    let r = self.send_lookup(&reply_msg, None, NO_REF);
                    self.pending.insert(
                        r,
                        Pending::ReplyLookup {
                            query,
                            reply_msg,
                            order,
                            data: f.data,
                        },
                    );
                } else {
                    let data = match self.cache.get(&reply_msg) {
                        Some(info) => proto::unwrap(info, f.data, order)?,
                        None => f.data,
                    };
                    self.events.push_back(Event::Reply {
                        query,
                        reply_msg,
                        order,
                        data,
                    });
                }
            }
            Pending::ReplyLookup {
                query,
                reply_msg,
                order: data_order,
                data,
            } => {
                if let Some(info) = proto::decode_msg_info(&f.data, order)? {
                    self.cache.insert(reply_msg.clone(), info);
                }
                let data = match self.cache.get(&reply_msg) {
                    Some(info) => proto::unwrap(info, data, data_order)?,
                    None => data,
                };
                self.events.push_back(Event::Reply {
                    query,
                    reply_msg,
                    order: data_order,
                    data,
                });
            }
            Pending::Internal(op) => self.internal_reply(op, &f, order)?,
        }
        self.pump();
        Ok(())
    }

    fn internal_reply(&mut self, op: Op, f: &Frame, order: ByteOrder) -> Result<(), Error> {
        let mut rd = Reader::new(&f.data, order);
        match op {
            Op::ClassInfo(_)
                if !f.data.is_empty()
                    && rd.read_ptr_flag().map_err(|e| proto_err("classInfo", e))? =>
            {
                let c = rd.read_i32().map_err(|e| proto_err("classInfo", e))?;
                let fmt = crate::format::decode_formatter(&mut rd)
                    .map_err(|e| proto_err("classInfo", e))?;
                self.class_formats.push((c, fmt));
            }
            Op::NewModuleConnect => {
                let e = |e| proto_err("newModuleConnect reply", e);
                let major = rd.read_i32().map_err(e)?;
                let minor = rd.read_i32().map_err(e)?;
                let direct = rd.read_i32().map_err(e)?;
                if major != 3 {
                    return Err(Error::Version { major, minor });
                }
                self.direct = direct != 0;
                let mut next = Vec::new();
                if self.direct {
                    self.events.push_back(Event::DirectListenRequested);
                    next.push(Op::WaitDirectPort);
                }
                for v in [
                    "V_get_CENTRAL_TERMINAL_LOG_VAR",
                    "V_get_CENTRAL_FILE_LOG_VAR",
                    "V_get_X_IPC_TAPPED_MSG_VAR",
                    "V_get_X_IPC_BROADCAST_MSG_VAR",
                ] {
                    next.push(Op::VarGet(v));
                }
                let id = self.alloc_handler(
                    "V_watch_X_IPC_BROADCAST_MSG_VAR",
                    "V_watch_X_IPC_BROADCAST_MSG_VAR",
                    HandlerKind::BroadcastVar,
                );
                next.push(Op::RegisterHandler {
                    id,
                    msg: "V_watch_X_IPC_BROADCAST_MSG_VAR".into(),
                    hnd: "V_watch_X_IPC_BROADCAST_MSG_VAR".into(),
                });
                next.push(Op::LimitPending {
                    msg: "X_IPC_BROADCAST_MSG_VAR".into(),
                    limit: 1,
                });
                next.push(Op::WaitMsg);
                for op in next.into_iter().rev() {
                    self.ops.push_front(op);
                }
            }
            Op::VarGet("V_get_X_IPC_BROADCAST_MSG_VAR") => {
                self.set_broadcast_list(proto::decode_str_list(&f.data, order)?);
            }
            Op::WaitMsg => {
                self.stage = Stage::Ready;
                self.events.push_back(Event::Connected);
            }
            Op::ModuleConnectedQ { op, .. } => {
                let v = rd
                    .read_i32()
                    .map_err(|e| proto_err("moduleConnectedQ reply", e))?;
                self.events.push_back(Event::ModuleConnected {
                    op,
                    connected: v != 0,
                });
            }
            Op::DirectQuery { msg } => {
                let list = proto::decode_direct_handlers(&f.data, order)?;
                self.set_direct_handlers(&msg, list);
                let w = format!("V_watch_{msg}");
                if !self.by_name.contains_key(&(w.clone(), w.clone())) {
                    let id = self.alloc_handler(&w, &w, HandlerKind::DirectWatch(msg));
                    self.ops.push_front(Op::RegisterHandler {
                        id,
                        msg: w.clone(),
                        hnd: w,
                    });
                }
            }
            Op::NumHandlers { op, msg } => {
                let count = if f.data.is_empty() {
                    0
                } else {
                    rd.read_i32()
                        .map_err(|e| proto_err("directMsgQuery reply", e))?
                };
                if count > 0 {
                    if let Some(list) = &mut self.broadcast_var {
                        list.insert(msg.clone());
                    }
                    self.counted.insert(msg);
                } else {
                    self.counted.remove(&msg);
                }
                self.events.push_back(Event::NumHandlers { op, count });
            }
            _ => {}
        }
        Ok(())
    }

    fn handle_delivery(&mut self, f: Frame) -> Result<(), Error> {
        if self.inbox.len() >= MAX_QUEUED_DELIVERIES {
            return Err(Error::Protocol {
                what: "delivery",
                detail: format!("more than {MAX_QUEUED_DELIVERIES} unprocessed deliveries"),
            });
        }
        self.inbox.push_back((f, None));
        Ok(())
    }

    fn start_delivery(&mut self, f: Frame, link: Option<LinkId>) -> Result<(), Error> {
        let hid = f.header.intent;
        let Some(h) = self.handlers.get_mut(&hid) else {
            // A delivery racing an unsubscribe: drop it, but free central's
            // capacity slot for a broadcast as the handler would have.
            if link.is_none() && f.header.class_id.msg_class() != Some(MsgClass::Query) {
                self.send_success(f.header.msg_ref);
            }
            return Ok(());
        };
        let msg = if f.class_data.is_empty() {
            h.msg.clone()
        } else {
            let co = class_order(&f.header)?;
            let mut cr = Reader::new(&f.class_data, co);
            cr.read_str()
                .map_err(|e| proto_err("delivery class data", e))?
                .to_string()
        };
        let id = self.next_delivery;
        self.next_delivery += 1;
        let mut ready = true;
        if !h.known {
            h.known = true;
            ready = false;
            let hnd = h.name.clone();
            let r = self.send_lookup(&msg, Some(&hnd), NO_REF);
            self.pending.insert(r, Pending::HandlerLookup(id));
        }
        self.deliveries.push_back(PendingDelivery {
            id,
            frame: f,
            msg,
            ready,
            link,
        });
        self.flush_deliveries();
        Ok(())
    }

    fn flush_deliveries(&mut self) {
        while self.deliveries.front().is_some_and(|d| d.ready) {
            let Some(d) = self.deliveries.pop_front() else {
                return;
            };
            if let Err(e) = self.dispatch(d) {
                self.fail(e);
                return;
            }
        }
    }

    fn dispatch(&mut self, mut d: PendingDelivery) -> Result<(), Error> {
        let h = d.frame.header;
        let order = data_order(&h)?;
        let kind = match h.class_id.msg_class() {
            Some(MsgClass::Query) => DeliveryKind::Query,
            _ => DeliveryKind::Broadcast,
        };
        let hk = self.handlers.get(&h.intent).map(|x| x.kind.clone());
        // A user handler gets the body itself; central's own messages are
        // small and read from the frame below.
        let body = if matches!(hk, Some(HandlerKind::User) | None) {
            std::mem::take(&mut d.frame.data)
        } else {
            d.frame.data.clone()
        };
        let data = match self.cache.get(&d.msg) {
            Some(info) => proto::unwrap(info, body, order),
            None => Ok(body),
        };
        let data = match (data, &hk) {
            (Ok(data), _) => data,
            (Err(error), Some(HandlerKind::User) | None) => {
                // No Success on direct links (§8).
                if d.link.is_none() {
                    self.send_success(h.msg_ref);
                }
                self.events.push_back(Event::Undeliverable {
                    handler: h.intent,
                    msg: d.msg,
                    kind,
                    error,
                });
                return Ok(());
            }
            // Central's own messages must be right.
            (Err(e), _) => return Err(e),
        };
        match hk {
            Some(HandlerKind::User) | None => {
                self.unacked.insert(d.id, (kind, h.msg_ref, d.link));
                self.events.push_back(Event::Delivery {
                    delivery: d.id,
                    handler: h.intent,
                    msg: d.msg,
                    kind,
                    dispatch_ref: h.msg_ref,
                    parent_ref: h.parent_ref,
                    order,
                    data,
                });
                return Ok(());
            }
            Some(HandlerKind::BroadcastVar) => {
                self.set_broadcast_list(proto::decode_str_list(&d.frame.data, order)?);
            }
            Some(HandlerKind::ConnectNotify) | Some(HandlerKind::DisconnectNotify) => {
                let mut r = Reader::new(&d.frame.data, order);
                let m = r
                    .read_str()
                    .map_err(|e| proto_err("connect notification", e))?
                    .to_string();
                self.events
                    .push_back(if hk == Some(HandlerKind::ConnectNotify) {
                        Event::ModuleConnect(m)
                    } else {
                        Event::ModuleDisconnect(m)
                    });
            }
            Some(HandlerKind::DirectWatch(msg)) => {
                let list = proto::decode_direct_handlers(&d.frame.data, order)?;
                let count = list.len() as i32;
                self.set_direct_handlers(&msg, list);
                self.events.push_back(Event::HandlerChange { msg, count });
            }
            Some(HandlerKind::Watch(msg)) => {
                let mut r = Reader::new(&d.frame.data, order);
                let count = if d.frame.data.is_empty() {
                    0
                } else {
                    r.read_i32().map_err(|e| proto_err("V_watch", e))?
                };
                self.events.push_back(Event::HandlerChange { msg, count });
            }
        }
        if kind == DeliveryKind::Broadcast && d.link.is_none() {
            self.send_success(h.msg_ref);
        }
        Ok(())
    }

    fn send_success(&mut self, dispatch: i32) {
        self.send_ref(
            NO_REF,
            MsgClass::Success,
            dispatch,
            dispatch,
            Vec::new(),
            Vec::new(),
            Some(NO_REF),
        );
    }

    fn alloc_handler(&mut self, msg: &str, hnd: &str, kind: HandlerKind) -> i32 {
        let key = (msg.to_string(), hnd.to_string());
        if let Some(id) = self.by_name.get(&key) {
            return *id;
        }
        let id = match self.retired.remove(&key) {
            Some(id) => id,
            None => {
                let mut id = self.next_handler;
                while self.handlers.contains_key(&id)
                    || self.retired.values().any(|&r| r == id)
                    || id < 2
                {
                    id = if id < 2 { i32::MAX } else { id - 1 };
                }
                self.next_handler = id - 1;
                id
            }
        };
        self.handlers.insert(
            id,
            Handler {
                msg: msg.into(),
                name: hnd.into(),
                known: false,
                kind,
            },
        );
        self.by_name.insert((msg.into(), hnd.into()), id);
        id
    }

    // ---- API -------------------------------------------------------------

    fn check_open(&self) -> Result<(), Error> {
        if matches!(self.stage, Stage::Closed) {
            Err(Error::Closed)
        } else {
            Ok(())
        }
    }

    /// Reports the direct listener's port (after [`Event::DirectListenRequested`]):
    /// sends `x_ipc_directResMsg {port, name}` and continues the handshake.
    pub fn announce_direct_port(&mut self, port: i32) {
        if let Some(pos) = self
            .ops
            .iter()
            .position(|o| matches!(o, Op::WaitDirectPort))
        {
            self.ops[pos] = Op::DirectRes(port);
            if self.blocked == Some(i32::MIN) {
                self.blocked = None;
            }
            self.pump();
        }
    }

    /// Bytes to write on a direct link (§8).
    pub fn poll_direct_transmit(&mut self) -> Option<(LinkId, Vec<u8>)> {
        self.direct_tx.pop_front()
    }

    /// Takes central's list of subscribed broadcasts, keeping the messages
    /// it counted handlers for ([`num_handlers`](Self::num_handlers)) until
    /// a list names them.
    ///
    /// Central sends us its list updates one at a time, each after we
    /// acknowledged the previous one, while it answers a count at once: a
    /// count can be newer than the lists still on their way. A publish that
    /// trusted such a list after being told "1 handler" was dropped
    /// unsent. Keeping a counted message costs at worst broadcasts central
    /// discards, until a count of 0 or a list naming it ends the keeping.
    fn set_broadcast_list(&mut self, mut list: HashSet<String>) {
        self.counted.retain(|m| !list.contains(m));
        list.extend(self.counted.iter().cloned());
        self.broadcast_var = Some(list);
    }

    fn push_direct(&mut self, link: LinkId, frame: Frame) {
        let (head, data) = frame.into_parts();
        self.direct_tx.push_back((link, head));
        if let Some(data) = data {
            self.direct_tx.push_back((link, data));
        }
    }

    /// A peer connected to our direct listener: returns the link's handle
    /// for [`receive_direct`](Self::receive_direct).
    pub fn accept_direct(&mut self) -> LinkId {
        let link = LinkId(self.next_link);
        self.next_link += 1;
        self.link_in.insert(link, Deframer::new(self.cfg.max_frame));
        link
    }

    /// Bytes read from a direct link (accepted or connected), in any split:
    /// deliveries to our handlers (no Success ack is sent for them) and
    /// replies to our direct queries. A malformed stream closes only the
    /// link: the error is returned and the shell drops the socket.
    pub fn receive_direct(&mut self, link: LinkId, mut bytes: &[u8]) -> Result<(), Error> {
        let mut d = self
            .link_in
            .remove(&link)
            .unwrap_or_else(|| Deframer::new(self.cfg.max_frame));
        loop {
            let frame = match d.next(&mut bytes) {
                Ok(Some(f)) => f,
                Ok(None) => break,
                Err(e) => return Err(Error::Frame(e)),
            };
            if frame.header.intent == QUERY_REPLY_INTENT {
                self.handle_reply(frame)?;
            } else if self.inbox.len() >= MAX_QUEUED_DELIVERIES {
                return Err(Error::Protocol {
                    what: "direct delivery",
                    detail: format!("more than {MAX_QUEUED_DELIVERIES} unprocessed deliveries"),
                });
            } else {
                self.inbox.push_back((frame, Some(link)));
            }
        }
        self.link_in.insert(link, d);
        Ok(())
    }

    /// The shell connected direct link `link`: queued sends proceed.
    pub fn direct_link_up(&mut self, link: LinkId) {
        for (id, up) in self.links.values_mut() {
            if *id == link {
                *up = true;
            }
        }
        if self.blocked == Some(LINK_WAIT) {
            self.blocked = None;
            self.pump();
        }
    }

    /// The shell could not connect `link`: its receivers are skipped (as C
    /// does after a failed connect); queued sends proceed to the others.
    pub fn direct_link_failed(&mut self, link: LinkId) {
        let dead: Vec<(String, i32)> = self
            .links
            .iter()
            .filter(|(_, (id, _))| *id == link)
            .map(|(k, _)| k.clone())
            .collect();
        for k in &dead {
            self.links.remove(k);
            for list in self.direct_handlers.values_mut() {
                list.retain(|h| (h.host.as_str(), h.port) != (k.0.as_str(), k.1));
            }
        }
        self.direct_link_up(link);
    }

    fn set_direct_handlers(&mut self, msg: &str, list: Vec<DirectHandler>) {
        for h in &list {
            let key = (h.host.clone(), h.port);
            if !self.links.contains_key(&key) {
                let link = LinkId(self.next_link);
                self.next_link += 1;
                self.links.insert(key, (link, false));
                self.events.push_back(Event::DirectConnect {
                    link,
                    host: h.host.clone(),
                    port: h.port,
                    module: h.module.clone(),
                });
            }
        }
        self.direct_handlers.insert(msg.to_string(), list);
    }

    /// Sends a direct publish/query, first learning the receivers and
    /// waiting for their links, so that no message is lost.
    fn direct_send(&mut self, op: Op, info: &MsgInfo) {
        let (op_id, msg, data, parent, query) = match op {
            Op::Publish {
                op,
                msg,
                data,
                parent,
            } => (op, msg, data, parent, false),
            Op::Query {
                op,
                msg,
                data,
                parent,
            } => (op, msg, data, parent, true),
            other => {
                self.ops.push_front(other);
                return;
            }
        };
        let rebuild = |msg: String, data: Vec<u8>| {
            if query {
                Op::Query {
                    op: op_id,
                    msg,
                    data,
                    parent,
                }
            } else {
                Op::Publish {
                    op: op_id,
                    msg,
                    data,
                    parent,
                }
            }
        };
        let Some(list) = self.direct_handlers.get(&msg).cloned() else {
            self.ops.push_front(rebuild(msg.clone(), data));
            self.ops.push_front(Op::DirectQuery { msg });
            return;
        };
        let links: Vec<(LinkId, bool)> = list
            .iter()
            .filter_map(|h| self.links.get(&(h.host.clone(), h.port)).copied())
            .collect();
        if links.iter().any(|(_, up)| !up) {
            self.ops.push_front(rebuild(msg, data));
            self.blocked = Some(LINK_WAIT);
            return;
        }
        if list.is_empty() {
            // C: "No handlers for direct message"; reported, not silent.
            self.events
                .push_back(Event::PublishDropped { op: op_id, msg });
            return;
        }
        let body = match proto::wrap(info, &msg, data) {
            Ok(b) => b,
            Err((error, _)) => {
                self.events.push_back(Event::OpFailed { op: op_id, error });
                return;
            }
        };
        let msg_ref = self.next_msg_ref();
        let class = if query {
            MsgClass::Query
        } else {
            MsgClass::from_u16(info.class as u16).unwrap_or(MsgClass::Broadcast)
        };
        // Last handler first (C walks the list backwards); a query goes to
        // the first handler only.
        let targets: Vec<&DirectHandler> = if query {
            list.iter().take(1).collect()
        } else {
            list.iter().rev().collect()
        };
        for h in targets {
            let Some((link, _)) = self.links.get(&(h.host.clone(), h.port)).copied() else {
                continue;
            };
            let frame = Frame {
                header: Header {
                    class_total: 0,
                    msg_total: 0,
                    parent_ref: parent,
                    intent: h.intent,
                    class_id: ClassId::native(class),
                    dispatch_ref: NO_REF,
                    msg_ref,
                },
                class_data: Vec::new(),
                data: body.clone(),
            };
            self.push_direct(link, frame);
        }
        if query {
            self.pending.insert(msg_ref, Pending::UserQuery(op_id));
        } else {
            self.events.push_back(Event::Published { op: op_id });
        }
    }

    /// `IPC_defineFormat`: `x_ipc_registerNamedFormMsg {name, fmt}`.
    pub fn define_format(&mut self, name: &str, fmt: &str) -> Result<(), Error> {
        self.check_open()?;
        self.push_op(Op::DefineFormat {
            name: name.into(),
            fmt: fmt.into(),
        });
        Ok(())
    }

    /// `IPC_defineMsg`: `x_ipc_registerMessageMsg`, then a lookup.
    pub fn define_msg(
        &mut self,
        name: &str,
        len: MsgLength,
        user_format: Option<&str>,
    ) -> Result<(), Error> {
        self.check_open()?;
        self.push_op(Op::DefineMsg {
            name: name.into(),
            len,
            fmt: user_format.map(Into::into),
        });
        Ok(())
    }

    /// `IPC_subscribe`: registers handler `handler_name` for `msg`; returns
    /// its id (C's table: 199, 198, … descending). Re-subscribing the same
    /// name returns the same id and sends nothing.
    pub fn subscribe(&mut self, msg: &str, handler_name: &str) -> Result<i32, Error> {
        self.check_open()?;
        if let Some(id) = self
            .by_name
            .get(&(msg.to_string(), handler_name.to_string()))
        {
            return Ok(*id);
        }
        let id = self.alloc_handler(msg, handler_name, HandlerKind::User);
        self.push_op(Op::RegisterHandler {
            id,
            msg: msg.into(),
            hnd: handler_name.into(),
        });
        Ok(id)
    }

    /// `IPC_unsubscribe`: `x_ipc_deregisterHandlerMsg {0, msg, hnd}`.
    pub fn unsubscribe(&mut self, msg: &str, handler_name: &str) -> Result<(), Error> {
        self.check_open()?;
        let key = (msg.to_string(), handler_name.to_string());
        if let Some(id) = self.by_name.remove(&key) {
            self.handlers.remove(&id);
            self.retired.insert(key, id);
        }
        self.push_op(Op::Deregister {
            msg: msg.into(),
            hnd: handler_name.into(),
        });
        Ok(())
    }

    /// `IPC_publish`: wraps `data` per the message's format; the outcome is
    /// [`Event::Published`], [`Event::PublishDropped`] or [`Event::OpFailed`].
    /// `parent_ref` is the dispatch being handled (or -1). An owned `data`
    /// (a `Vec<u8>`) goes into the frame without being copied.
    pub fn publish(
        &mut self,
        msg: &str,
        data: impl Into<Vec<u8>>,
        parent_ref: i32,
    ) -> Result<OpId, Error> {
        self.check_open()?;
        let op = self.alloc_op();
        self.push_op(Op::Publish {
            op,
            msg: msg.into(),
            data: data.into(),
            parent: parent_ref,
        });
        Ok(op)
    }

    /// `IPC_queryNotify`/`IPC_queryResponse`: the answer comes as
    /// [`Event::Reply`]. `data` as in [`publish`](Self::publish).
    pub fn query(
        &mut self,
        msg: &str,
        data: impl Into<Vec<u8>>,
        parent_ref: i32,
    ) -> Result<OpId, Error> {
        self.check_open()?;
        let op = self.alloc_op();
        self.push_op(Op::Query {
            op,
            msg: msg.into(),
            data: data.into(),
            parent: parent_ref,
        });
        Ok(op)
    }

    /// `IPC_respond`: answers query delivery `delivery` with `reply_msg`
    /// (any time later, in any order: `IPC_delayResponse`).
    pub fn respond(
        &mut self,
        delivery: DeliveryId,
        reply_msg: &str,
        data: impl Into<Vec<u8>>,
    ) -> Result<(), Error> {
        self.check_open()?;
        let Some((kind, dispatch, link)) = self.unacked.get(&delivery).copied() else {
            return Err(Error::UnknownHandle(delivery));
        };
        if kind != DeliveryKind::Query {
            return Err(Error::UnknownHandle(delivery));
        }
        self.unacked.remove(&delivery);
        self.push_op(Op::Respond {
            msg: reply_msg.into(),
            data: data.into(),
            dispatch,
            parent: dispatch,
            link,
        });
        Ok(())
    }

    /// Sends the Success ack of a broadcast delivery ("handler returned"),
    /// freeing a capacity slot in central.
    pub fn ack(&mut self, delivery: DeliveryId) -> Result<(), Error> {
        self.check_open()?;
        match self.unacked.get(&delivery).copied() {
            Some((DeliveryKind::Broadcast, dispatch, link)) => {
                self.unacked.remove(&delivery);
                // No Success on direct links (§8).
                if link.is_none() {
                    self.send_success(dispatch);
                }
                Ok(())
            }
            _ => Err(Error::UnknownHandle(delivery)),
        }
    }

    /// `IPC_setCapacity`: `x_ipc_registerResourceMsg {n, name}`.
    pub fn set_capacity(&mut self, n: i32) -> Result<(), Error> {
        self.check_open()?;
        let mut w = Writer::new();
        w.write_i32(n);
        w.write_str(&self.cfg.name);
        self.push_op(Op::Inform {
            msg: "x_ipc_registerResourceMsg",
            data: w.into_vec(),
        });
        Ok(())
    }

    /// `IPC_setMsgPriority`: `ipc_setMsgPriority {msg, p}`.
    pub fn set_priority(&mut self, msg: &str, priority: i32) -> Result<(), Error> {
        self.check_open()?;
        let mut w = Writer::new();
        w.write_str(msg);
        w.write_i32(priority);
        self.push_op(Op::Inform {
            msg: "ipc_setMsgPriority",
            data: w.into_vec(),
        });
        Ok(())
    }

    /// `IPC_setMsgQueueLength`: `x_ipc_limitPendingMsg {msg, name, n}`.
    pub fn set_queue_length(&mut self, msg: &str, n: i32) -> Result<(), Error> {
        self.check_open()?;
        self.push_op(Op::LimitPending {
            msg: msg.into(),
            limit: n,
        });
        Ok(())
    }

    /// `IPC_isModuleConnected`: answer in [`Event::ModuleConnected`].
    pub fn is_module_connected(&mut self, module: &str) -> Result<OpId, Error> {
        self.check_open()?;
        let op = self.alloc_op();
        self.push_op(Op::ModuleConnectedQ {
            op,
            module: module.into(),
        });
        Ok(op)
    }

    /// `IPC_numHandlers`: answer in [`Event::NumHandlers`].
    pub fn num_handlers(&mut self, msg: &str) -> Result<OpId, Error> {
        self.check_open()?;
        let op = self.alloc_op();
        self.push_op(Op::NumHandlers {
            op,
            msg: msg.into(),
        });
        Ok(op)
    }

    /// `IPC_subscribeConnect`: [`Event::ModuleConnect`] for each module connecting.
    pub fn subscribe_connect(&mut self) -> Result<(), Error> {
        self.check_open()?;
        if !self.connect_subscribed {
            self.connect_subscribed = true;
            let m = "x_ipc_connectNotify";
            let id = self.alloc_handler(m, m, HandlerKind::ConnectNotify);
            self.push_op(Op::RegisterHandler {
                id,
                msg: m.into(),
                hnd: m.into(),
            });
        }
        Ok(())
    }

    /// `IPC_subscribeDisconnect`: [`Event::ModuleDisconnect`] for each module leaving.
    pub fn subscribe_disconnect(&mut self) -> Result<(), Error> {
        self.check_open()?;
        if !self.disconnect_subscribed {
            self.disconnect_subscribed = true;
            let m = "x_ipc_disconnectNotify";
            let id = self.alloc_handler(m, m, HandlerKind::DisconnectNotify);
            self.push_op(Op::RegisterHandler {
                id,
                msg: m.into(),
                hnd: m.into(),
            });
        }
        Ok(())
    }

    /// `IPC_subscribeHandlerChange`: the first time for `msg`, sends
    /// `x_ipc_notifyHandlerChange msg`, a `x_ipc_directMsgQuery` (its answer
    /// is reported as [`Event::NumHandlers`] with the returned id) and a
    /// `V_watch_<msg>` subscription (later changes: [`Event::HandlerChange`]).
    /// Further calls for the same message send nothing and return `None`,
    /// as in C.
    pub fn subscribe_handler_change(&mut self, msg: &str) -> Result<Option<OpId>, Error> {
        self.check_open()?;
        let w = format!("V_watch_{msg}");
        let key = (w.clone(), w.clone());
        if self.by_name.contains_key(&key) {
            return Ok(None);
        }
        let op = self.alloc_op();
        self.push_op(Op::Lookup(msg.into()));
        self.push_op(Op::NotifyHandlerChange { msg: msg.into() });
        self.push_op(Op::NumHandlers {
            op,
            msg: msg.into(),
        });
        let id = self.alloc_handler(&w, &w, HandlerKind::Watch(msg.into()));
        self.push_op(Op::RegisterHandler {
            id,
            msg: w.clone(),
            hnd: w,
        });
        Ok(Some(op))
    }

    /// `IPC_disconnect`: `x_ipc_CloseMsg`, then the shell closes the socket
    /// once [`poll_transmit`](Self::poll_transmit) is drained.
    pub fn close(&mut self) -> Result<(), Error> {
        self.check_open()?;
        self.push_op(Op::Close);
        Ok(())
    }
}

fn data_order(h: &Header) -> Result<ByteOrder, Error> {
    h.class_id.data_order().ok_or(Error::Protocol {
        what: "classId",
        detail: format!("unknown data byte order in 0x{:08x}", h.class_id.0),
    })
}

fn class_order(h: &Header) -> Result<ByteOrder, Error> {
    h.class_id.class_order().ok_or(Error::Protocol {
        what: "classId",
        detail: format!("unknown class byte order in 0x{:08x}", h.class_id.0),
    })
}

fn proto_err(what: &'static str, e: impl std::fmt::Display) -> Error {
    Error::Protocol {
        what,
        detail: e.to_string(),
    }
}
