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

mod api;
mod delivery;
mod direct;
mod event;
mod ops;
mod proto;
mod replies;

use std::collections::{HashMap, HashSet, VecDeque};
use std::time::Instant;

use self::delivery::{Handler, PendingDelivery};
use self::ops::Op;
use self::replies::Pending;
use super::frame::{Deframer, Frame, FrameError, Header, QUERY_REPLY_INTENT};
use super::{ByteOrder, Reader};
use crate::format::Format;

pub use self::event::{DeliveryId, DeliveryKind, Event, OpId};
pub use self::proto::MsgInfo;

/// Largest frame body (class data + message data) accepted from central,
/// and the largest message sent: central's own limit
/// ([`central::Config::max_frame`](crate::ipc::central::Config::max_frame)),
/// so that whatever Courier's central forwards, a module takes.
pub const DEFAULT_MAX_FRAME: u64 = 256 * 1024 * 1024;

/// Room a frame needs besides a message's data (class data, the variable
/// length wrapper's count): a message may be [`ModuleConfig::max_frame`]
/// less this.
pub const FRAME_ROOM: u64 = 4096;

/// Most deliveries buffered before the shell takes them with
/// [`Connection::poll_event`]; central sends at most `capacity` outstanding
/// deliveries plus notifications, so more means a misbehaving peer.
pub const MAX_QUEUED_DELIVERIES: usize = 65_536;

/// Deliveries central may send a module beyond its capacity before the
/// module's acknowledgements: what Courier's central sends ahead
/// ([`central::MAX_SEND_AHEAD`](crate::ipc::central::MAX_SEND_AHEAD)), C's
/// none. (Its notices to central's own handlers come on top, bounded by
/// [`MAX_QUEUED_DELIVERIES`].)
pub const MAX_SENT_AHEAD: usize = crate::ipc::central::MAX_SEND_AHEAD;

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
    /// Largest frame body accepted from central or a direct link; a
    /// message sent must leave [`FRAME_ROOM`] below it.
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
    /// A direct link sent what this module cannot take (a bad frame, more
    /// deliveries than it holds, frames past its bound): the link is
    /// closed, nothing else.
    #[error("direct link: {0}")]
    DirectLink(String),
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
    /// The message is larger than a frame may be
    /// ([`ModuleConfig::max_frame`] less [`FRAME_ROOM`]): central (or the
    /// receiving module) would refuse the frame and drop the connection.
    #[error("message {msg:?} of {len} bytes is larger than the {max} bytes a frame may carry")]
    TooLarge {
        /// Message name.
        msg: String,
        /// Its data's size.
        len: usize,
        /// The largest a message's data may be.
        max: u64,
    },
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

/// A link to a receiver's listen address.
#[derive(Debug, Clone)]
struct Link {
    id: LinkId,
    up: bool,
    /// The module it was made for.
    module: String,
}

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
    /// The `pending` key of each user query sent and not yet answered, so
    /// that a cancel finds it at once (a timed-out or dropped query each
    /// cancels one).
    query_refs: HashMap<OpId, i32>,
    /// The direct link each query sent on one went out on (by `pending`
    /// key): only that link may answer it, and central may not.
    reply_links: HashMap<i32, LinkId>,
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
    /// Direct queries of messages that have no handler yet, by message, in
    /// order: sent when central's handler list names one (as a query
    /// through central waits in central for its first handler), or
    /// dropped by [`Connection::cancel_query`].
    awaiting_handler: HashMap<String, Vec<Op>>,
    /// Links to receivers by listen address: the link, whether it is up,
    /// and the module it was made for (another module at that address
    /// later, when the first left and its port was taken again, gets a
    /// link of its own).
    links: HashMap<(String, i32), Link>,
    next_link: u64,
    direct_tx: VecDeque<(LinkId, Vec<u8>)>,
    unknown: HashSet<String>,
    unacked: HashMap<DeliveryId, (DeliveryKind, i32, Option<LinkId>)>,
    /// [`Connection::capacity`].
    capacity: usize,
    /// Frames from central for user handlers in `inbox`.
    central_in_inbox: usize,
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
            query_refs: HashMap::new(),
            reply_links: HashMap::new(),
            handlers: HashMap::new(),
            by_name: HashMap::new(),
            retired: HashMap::new(),
            deliveries: VecDeque::new(),
            inbox: VecDeque::new(),
            link_in: HashMap::new(),
            direct_handlers: HashMap::new(),
            awaiting_handler: HashMap::new(),
            links: HashMap::new(),
            next_link: 1,
            direct_tx: VecDeque::new(),
            unknown: HashSet::new(),
            unacked: HashMap::new(),
            capacity: 1,
            central_in_inbox: 0,
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
            if link.is_none() && self.is_user_frame(&f) {
                // (saturating: a handler made or dropped meanwhile may
                // change what the frame counted as)
                self.central_in_inbox = self.central_in_inbox.saturating_sub(1);
            }
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

    /// Forgets a user query; a late reply is ignored. One not sent yet
    /// (waiting for its message's lookup, or in direct mode for a first
    /// handler) is never sent.
    pub fn cancel_query(&mut self, query: OpId) {
        if let Some(r) = self.query_refs.remove(&query) {
            self.pending.remove(&r);
            self.reply_links.remove(&r);
            return;
        }
        let is_it = |o: &Op| matches!(o, Op::Query { op, .. } if *op == query);
        self.ops.retain(|o| !is_it(o));
        if !self.awaiting_handler.is_empty() {
            for ops in self.awaiting_handler.values_mut() {
                ops.retain(|o| !is_it(o));
            }
            self.awaiting_handler.retain(|_, ops| !ops.is_empty());
        }
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
                    if self.reply_links.contains_key(&h.msg_ref) {
                        // a query sent on a direct link: its answer comes
                        // on that link, not from central
                        return Ok(());
                    }
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
