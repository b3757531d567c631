//! The CMU IPC `central` server as a sans-I/O state machine (ipc.md §1–§8, §11).
//!
//! [`Central`] owns every routing decision — the message and handler
//! tables, named formats, pending queues, capacity, priorities, queue
//! limits, global variables, direct-mode bookkeeping — and no sockets,
//! threads or clocks. A shell (the `central` binary in `courier-broker`)
//! feeds it what happens on connections and carries out what it asks for:
//!
//! ```text
//!   accept      -> central.connect(conn, peer, now)
//!   bytes read  -> central.receive(conn, &bytes, now)
//!   EOF / error -> central.disconnect(conn, now)
//!   stdin line  -> central.command(line, now)
//!   loop { match central.poll_output() {
//!       Transmit / TransmitBody / Close / Log / PauseRead / ResumeRead } }
//! ```
//!
//! Framing is done here too: `receive` takes raw stream bytes in any
//! split, so tests can replay captured byte streams exactly
//! (`wire/tests/central_replay.rs` replays the C modules of every capture
//! and matches each frame and the C central's log line for line).
//!
//! # Example
//! ```
//! use std::time::SystemTime;
//! use courier_wire::ipc::central::{Central, Config, ConnId, Output, Peer};
//!
//! let mut central = Central::new(Config::default());
//! central.connect(ConnId(5), Peer::Other("test".into()), SystemTime::now());
//! // Central speaks first: the msgInfo id, then two formatter frames.
//! let mut frames = 0;
//! while let Some(out) = central.poll_output() {
//!     if let Output::Transmit { conn, bytes } = out {
//!         assert_eq!(conn, ConnId(5));
//!         assert!(frames > 0 || bytes.len() == 4);
//!         frames += 1;
//!     }
//! }
//! assert_eq!(frames, 3);
//! ```
//!
//! # Deviations from the C central
//! - Message ids and dispatch ids are numbered like C (ids from 199 down,
//!   never 0 or 1; dispatch ids reused last-freed first) but need not be the
//!   same numbers: modules only learn them from replies.
//! - `-r` resends a crashed module's unfinished messages automatically when
//!   a module of the same name subscribes the same handler again (C asks
//!   `Resend <msg> message?` on the terminal for each).
//! - Back-pressure: when more than [`Config::max_queued_bytes`] of message
//!   data wait in pending queues, central stops reading from the modules
//!   that add to them (never from one whose acknowledgements it awaits)
//!   until the queues drain to half; C grows without bound. Past the same
//!   bound, the oldest queries waiting for a first handler of their
//!   message are dropped (C keeps them all).
//! - A module repeating a mistake (foreign acknowledgements, unknown ids)
//!   gets ten warning lines at once, then one a second, and a count of
//!   the rest: it cannot flood the terminal or the log file.
//! - Malformed frames close only the offending connection, with a log line
//!   naming the reason; C may abort.
//! - Log times (`-lt`) are UTC; the `h` (handle summary) option is accepted
//!   and prints nothing; `unlock` answers that IPC modules cannot lock.
//! - The data log decodes internal messages with their own formats when
//!   `-l` lacks `i` (C prints them the same way).
//! - Cut-through ([`Config::cut_through`], off by default): a large message
//!   whose handler can take it at once is forwarded while it still arrives,
//!   instead of after its last byte (C's way). If the sender dies in the
//!   middle, the receiver's frame is completed with zero bytes (it already
//!   has the start), and a warning names both modules.

use std::time::SystemTime;

/// Identifies one accepted connection (chosen by the shell, never reused
/// while the connection is open).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct ConnId(pub u64);

/// Where a connection came from, for logs and `status`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Peer {
    /// A TCP peer: its address as text, e.g. `127.0.0.1:53122`.
    Tcp(String),
    /// A UNIX-domain socket peer.
    Unix,
    /// Anything else (tests).
    Other(String),
}

/// Logging options of `-l` / `-L` (manual §2).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[non_exhaustive]
pub struct LogOptions {
    /// `m`: message traffic.
    pub messages: bool,
    /// `s`: status of IPC (connects, disconnects, registrations).
    pub status: bool,
    /// `t`: the time messages are received by central.
    pub time: bool,
    /// `d`: the data associated with messages.
    pub data: bool,
    /// `i`: ignore logging certain internal messages.
    pub ignore_internal: bool,
    /// `h`: handle time summary of incoming messages.
    pub handle_summary: bool,
    /// `r`: log the reference id as well as the message name.
    pub refs: bool,
    /// `p`: log the reference id of the message's parent.
    pub parent_refs: bool,
    /// `F` (file only): don't flush the file after each line.
    pub no_flush: bool,
    /// `n` (file only): don't prompt the user for comments.
    pub no_prompt: bool,
}

impl LogOptions {
    /// No logging (`-lx`).
    pub const NONE: LogOptions = LogOptions {
        messages: false,
        status: false,
        time: false,
        data: false,
        ignore_internal: false,
        handle_summary: false,
        refs: false,
        parent_refs: false,
        no_flush: false,
        no_prompt: false,
    };

    /// Parses the letters after `-l` (`file == false`) or `-L` (`file ==
    /// true`), as the C central does: no letters = `mstdh`, `x` = none,
    /// otherwise each letter turns one option on (`F` and `n` only for files).
    pub fn parse(letters: &str, file: bool) -> Result<LogOptions, OptionError> {
        let mut o = LogOptions::NONE;
        if letters.is_empty() {
            o.messages = true;
            o.status = true;
            o.time = true;
            o.data = true;
            o.handle_summary = true;
            return Ok(o);
        }
        // Like the C central: letters in either case; an `x` anywhere
        // turns the log off.
        let mut off = false;
        for c in letters.chars() {
            match c.to_ascii_lowercase() {
                'm' => o.messages = true,
                's' => o.status = true,
                't' => o.time = true,
                'd' => o.data = true,
                'i' => o.ignore_internal = true,
                'h' => o.handle_summary = true,
                'r' => o.refs = true,
                'p' => o.parent_refs = true,
                'x' => off = true,
                'f' if file => o.no_flush = true,
                'n' if file => o.no_prompt = true,
                _ => {
                    return Err(OptionError::UnknownLogOption {
                        option: c,
                        flag: if file { 'L' } else { 'l' },
                    })
                }
            }
        }
        if off {
            o = LogOptions::NONE;
        }
        Ok(o)
    }

    /// True if anything at all is logged.
    pub fn any(&self) -> bool {
        self.messages || self.status || self.data || self.time || self.handle_summary
    }
}

/// A bad option given to central (command line or console).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum OptionError {
    /// A letter after `-l`/`-L` that is not a logging option.
    #[error("unknown logging option '{option}' in -{flag} (options: m s t d i h r p x{})", if *flag == 'L' { " F n" } else { "" })]
    UnknownLogOption {
        /// The letter.
        option: char,
        /// `l` or `L`.
        flag: char,
    },
}

/// Configuration of a [`Central`].
#[derive(Debug, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub struct Config {
    /// `-c`: messages go module-to-module; central is only the registry.
    pub direct: bool,
    /// `-r`: resend non-completed messages to a module that crashed and reconnects.
    pub resend_on_reconnect: bool,
    /// `-l`: terminal logging (default `-lmsi`).
    pub terminal_log: LogOptions,
    /// `-L`: file logging (default `-Lx`, none).
    pub file_log: LogOptions,
    /// `-I`: message names not to log.
    pub ignore: Vec<String>,
    /// `-s`: silent running. The shell prints nothing; modules see it as the
    /// terminal log's `quiet` field of `CENTRAL_TERMINAL_LOG_VAR`.
    pub quiet: bool,
    /// Largest frame body (`classTotal + msgTotal`) accepted from a module;
    /// a larger header closes the connection with a log line.
    pub max_frame: u64,
    /// When the messages queued inside central for delivery exceed this many
    /// bytes (their data plus [`DISPATCH_COST`] each, so that empty
    /// messages count too), the shell is asked to stop reading from publishers
    /// ([`Output::PauseRead`]) until the queues drain to half of it: memory
    /// stays bounded and nothing is dropped (TCP back-pressure reaches the
    /// publisher). A module is read on while central waits for something
    /// only it can send: the answer to a query it is handling, or the
    /// Success that lets its own queue move; a module publishing from its
    /// handler of a broadcast is held back like any other, and so is one
    /// publishing while it answers a query, unless a module that waits for
    /// an answer has messages queued (its handler may hold its capacity
    /// while it waits, so that queue could wait for the reply central would
    /// not read); queuing a message for such a module reads answering
    /// modules again.
    ///
    /// Queries and informs waiting for a first handler of their message
    /// wait as long as it takes, as in C, and outlive their sender; they
    /// are a pool of their own with the same bound
    /// ([`Stats::waiting_bytes`]): past it, the oldest of a message are
    /// dropped with a warning, so that a module asking a service that is
    /// down, again and again, cannot grow central without bound.
    pub max_queued_bytes: usize,
    /// Cut-through: a message or reply whose body is at least this many
    /// bytes is forwarded while it still arrives, when its receiver can take
    /// it at once (ready, below its capacity, nothing pending). A routed
    /// round trip then moves each large message once instead of twice in a
    /// row, and central holds no copy of it. `None` (the default, as in C):
    /// every frame is stored whole before it is forwarded. Not used with
    /// data logging or `-r` (both need the whole message). The receiver's
    /// stream follows the sender's: while a sender is slow in the middle of
    /// a relayed message, central's other frames for that receiver wait
    /// behind it, and a sender that dies in the middle leaves the receiver
    /// a frame completed with zero bytes (logged). Use it between modules
    /// that are trusted to send whole messages.
    pub cut_through: Option<usize>,
    /// Send-ahead, by module name: while a module named here handles as
    /// many broadcasts as its capacity allows, up to this many of the
    /// broadcasts queued for it are already written to its socket, so that
    /// it finds its next message waiting when it finishes instead of a
    /// round trip later. Empty (the default, as in C): a delivery leaves
    /// central only when a capacity slot is free.
    ///
    /// Meant for modules that only consume, such as loggers and recorders:
    /// a C module handles queued messages while it waits for a reply
    /// (`IPC_queryResponse`, the first `IPC_publish` of a message, which
    /// looks it up, or `IPC_listen` in a handler), so a handler that waits
    /// would be entered again with a message sent ahead, which capacity 1
    /// exists to prevent.
    ///
    /// The module still gets every message once and in central's order,
    /// and central's bookkeeping and log stay C's: a message sent ahead
    /// counts as pending and is logged as sent when its slot frees. Only
    /// broadcasts from modules go ahead, never a message with a queue limit
    /// (it may be dropped) or to a module with a handler of a message with
    /// a priority (a later message may overtake it); a priority or a limit
    /// set later does not call back what is already written. Nothing goes
    /// ahead for a handler the module has not looked up yet (its first
    /// delivery), so the frames are byte for byte C's. A message for a
    /// handler unsubscribed in the meantime reaches the module, which
    /// discards and acknowledges it (the C library warns), where central
    /// would have deleted it.
    pub send_ahead: BTreeMap<String, usize>,
}

impl Default for Config {
    fn default() -> Self {
        Config {
            direct: false,
            resend_on_reconnect: false,
            terminal_log: LogOptions {
                messages: true,
                status: true,
                ignore_internal: true,
                ..LogOptions::default()
            },
            file_log: LogOptions::default(),
            ignore: Vec::new(),
            quiet: false,
            max_frame: 256 << 20,
            max_queued_bytes: 64 << 20,
            cut_through: None,
            send_ahead: BTreeMap::new(),
        }
    }
}

/// Where a log line goes (the shell writes it to the terminal and/or the log file).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LogTarget {
    /// Print on the terminal (`-l`; suppressed by `-s` in the shell).
    pub terminal: bool,
    /// Append to the log file (`-L`).
    pub file: bool,
}

/// What the state machine asks the shell to do.
#[derive(Debug, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub enum Output {
    /// Write these bytes to the connection, in order.
    Transmit {
        /// The connection.
        conn: ConnId,
        /// Bytes to write.
        bytes: Vec<u8>,
    },
    /// Write `head` and then `body` to the connection: one frame whose
    /// message data (at least [`SPLIT_AT`] bytes) is shared with central's
    /// queues instead of copied into the frame. In order with
    /// [`Output::Transmit`].
    TransmitBody {
        /// The connection.
        conn: ConnId,
        /// The frame's header and class data.
        head: Vec<u8>,
        /// The frame's message data.
        body: Body,
    },
    /// Close the connection (after writing what was queued before).
    Close {
        /// The connection.
        conn: ConnId,
        /// Why, for the shell's log.
        reason: String,
    },
    /// A line for the log, already formatted as the C central prints it
    /// (no trailing newline).
    Log {
        /// Where it goes.
        target: LogTarget,
        /// The text.
        line: String,
    },
    /// Stop reading from this connection until [`Output::ResumeRead`].
    PauseRead {
        /// The connection.
        conn: ConnId,
    },
    /// Resume reading from this connection.
    ResumeRead {
        /// The connection.
        conn: ConnId,
    },
}

impl Output {
    /// The connection and bytes of a [`Transmit`](Output::Transmit) or
    /// [`TransmitBody`](Output::TransmitBody), as one buffer (a shared body
    /// is copied): for shells that write one buffer at a time, and tests.
    pub fn transmitted(self) -> Option<(ConnId, Vec<u8>)> {
        match self {
            Output::Transmit { conn, bytes } => Some((conn, bytes)),
            Output::TransmitBody {
                conn,
                mut head,
                body,
            } => {
                head.extend_from_slice(&body);
                Some((conn, head))
            }
            _ => None,
        }
    }
}

mod body;
mod internal;
mod log;

pub use self::body::Body;

use std::collections::{BTreeMap, HashMap, HashSet, VecDeque};

use self::internal::{Def, Internal};
use self::log::Kind;
use crate::format::{parse, parse_with, Format, FormatRegistry};
use crate::ipc::frame::{
    ClassId, Header, MsgClass, HEADER_SIZE, NO_REF, QUERY_REPLY_INTENT, SPLIT_AT,
};
use crate::ipc::{ByteOrder, Reader, Writer};

/// The module name central uses for itself in logs.
const SERVER_NAME: &str = "X_IPC Server";
/// `DEFAULT_PRIORITY` of `ipc_setMsgPriority`.
const DEFAULT_PRIORITY: i32 = 1;
/// IPC version central reports (`{{3, 9}, direct}`).
const VERSION: (i32, i32) = (3, 9);
/// Most handlers listed in a direct handler list (`MAX_DIRECT_HANDLERS`).
const MAX_DIRECT_HANDLERS: usize = 100;

/// Who sent a dispatch.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Org {
    Central,
    Module(ConnId),
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Status {
    /// Waiting for a handler to exist (a query or inform with none yet).
    NoHandler,
    /// In a module's pending queue.
    Pending,
    /// Delivered; waiting for Success or Reply.
    Attending,
    /// Written to the module ahead of its turn ([`Config::send_ahead`]);
    /// counts as pending until a capacity slot frees.
    Ahead,
}

/// How a delivery that takes a capacity slot reaches its module.
#[derive(Debug, Clone, Copy)]
enum Carry<'a> {
    /// Its whole frame, now.
    Frame,
    /// Its header and the body's first bytes now, the rest as it arrives
    /// (cut-through): the bytes so far and the body's whole length.
    Relayed(&'a [u8], usize),
    /// It was written ahead of its turn ([`Config::send_ahead`]).
    Ahead,
}

#[derive(Debug)]
struct Dispatch {
    msg: String,
    /// The class the sender used (Broadcast, Query, Inform).
    class: u16,
    /// The sender's classId (keeps its byte-order flags for forwarding).
    class_id: ClassId,
    org: Org,
    org_ref: i32,
    parent_ref: i32,
    data: Body,
    /// The handler: module and handler name.
    hnd: Option<(ConnId, String)>,
    status: Status,
}

/// What central counts for a queued message besides its data, against
/// [`Config::max_queued_bytes`]: about what its bookkeeping takes (the
/// dispatch record, the message and handler names it carries, its slots in
/// the dispatch table and in a queue).
pub const DISPATCH_COST: usize = 256;

/// What a dispatch holds, as [`Stats::queued_bytes`] and
/// [`Stats::waiting_bytes`] count it.
fn cost(d: &Dispatch) -> usize {
    d.data.len() + DISPATCH_COST
}

/// `d` leaves its pending queue (if it was in one): its cost no longer
/// counts as queued.
fn unqueue(stats: &mut Stats, d: &Dispatch) {
    if d.status == Status::Pending {
        stats.queued_bytes = stats.queued_bytes.saturating_sub(cost(d));
    }
}

impl Dispatch {
    /// Delivered to `conn` and awaiting its Success or Reply.
    fn attending_at(&self, conn: ConnId) -> bool {
        self.status == Status::Attending && self.hnd.as_ref().is_some_and(|(c, _)| *c == conn)
    }
}

#[derive(Debug)]
struct Handler {
    id: i32,
    /// Registration order.
    seq: u64,
    msg: String,
    /// The module asked msgInfo with this handler's name: it knows the message.
    knows_msg: bool,
}

#[derive(Debug)]
struct Module {
    peer: Peer,
    /// Bytes received and not yet framed; `rx_pos` is where unread data starts.
    rx: Vec<u8>,
    rx_pos: usize,
    name: Option<String>,
    host: String,
    /// `x_ipc_waitMsg` answered: deliveries may flow.
    ready: bool,
    capacity: usize,
    attending: usize,
    /// Of the deliveries it is handling, those whose sender waits for an
    /// answer (queries): while it has one, central keeps reading it.
    answering: usize,
    /// Its queries whose reply has not come (delivered, queued or waiting
    /// for a handler): while it has one, a handler of its may be blocked
    /// on someone else's answer.
    asking: usize,
    pending: VecDeque<i32>,
    /// Broadcasts sent ahead of their turn, oldest first; they come before
    /// everything in `pending`.
    ahead: VecDeque<i32>,
    msg_limits: Vec<(String, i32)>,
    pending_limit: Option<i32>,
    /// Direct-mode listen port (-1 = none).
    port: i32,
    /// Handlers by name.
    handlers: BTreeMap<String, Handler>,
    /// Ids of handlers this module unsubscribed, by name. A C module
    /// subscribes the same handler again with id 0 and expects deliveries
    /// under the id it registered first (`x_ipc_deregisterHnd` keeps the
    /// record; `x_ipc_selfRegisterHnd` finds it and keeps its id).
    retired: BTreeMap<String, i32>,
    /// The version of each variable this module last read (`V_get_…`) or
    /// was sent (`V_watch_…`).
    vars_read: BTreeMap<String, u64>,
    paused: bool,
    closed: bool,
    /// Its problem lines (unknown ids, foreign acknowledgements …), so
    /// that a misbehaving module cannot flood the log.
    problems: log::ProblemBudget,
    /// A frame from this module being forwarded while it arrives.
    relay: Option<Relay>,
    /// The module whose frame is being forwarded to this one: every other
    /// frame for this module waits in `held` until that one is complete.
    relay_from: Option<ConnId>,
    held: Vec<(Vec<u8>, Option<Body>)>,
    /// A large frame is being received into `rx` (from its start, with
    /// `rx_pos` 0) and ends at this length: `rx` takes no bytes beyond it,
    /// so that the frame's buffer becomes its [`Body`] without a copy.
    big_end: Option<usize>,
}

/// A frame body passing through central as it arrives (cut-through).
#[derive(Debug)]
struct Relay {
    /// Where the body goes.
    to: ConnId,
    /// Body bytes still to come from the sender.
    remaining: usize,
    /// Body bytes in all.
    total: usize,
    msg: String,
    /// A reply: its bookkeeping (`on_reply`) is done once it has passed.
    reply: Option<(Header, Option<String>)>,
}

impl Module {
    /// A delivery would go out now rather than wait in `pending`.
    fn takes_delivery_now(&self) -> bool {
        self.ready
            && self.attending < self.capacity
            && self.pending.is_empty()
            && self.ahead.is_empty()
    }
}

#[derive(Debug)]
struct Msg {
    /// Central's id; 0 for a name only known from a subscription.
    id: i32,
    name: String,
    class: MsgClass,
    msg_format: Option<String>,
    res_format: Option<String>,
    /// Parsed (and named-format expanded) formats, cached.
    parsed: Option<(Option<Format>, Option<Format>)>,
    /// Handlers in subscription order (oldest first).
    handlers: Vec<(ConnId, String)>,
    /// Dispatches waiting for a first handler.
    waiting: VecDeque<i32>,
    priority: i32,
    direct: bool,
    notify_handler_change: bool,
    internal: Option<Internal>,
}

#[derive(Debug)]
struct Var {
    format: Format,
    value: Vec<u8>,
    /// Bumped at every change, so a module's watch can tell whether the
    /// value it read is still current.
    version: u64,
}

/// Counters for `memory` and tests.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
#[non_exhaustive]
pub struct Stats {
    /// Modules connected now.
    pub modules: usize,
    /// Dispatches alive (pending, attending or waiting for a handler).
    pub dispatches: usize,
    /// Of those, queries and informs waiting for a first handler of their
    /// message. As in C, they outlive the module that sent them: a handler
    /// that registers later gets them (and a reply to a module gone is
    /// dropped with a log line).
    pub waiting_for_handler: usize,
    /// What those queries and informs hold: their data plus
    /// [`DISPATCH_COST`] each. Bounded apart from `queued_bytes` by the same
    /// [`Config::max_queued_bytes`]: past it, the oldest of a message are
    /// dropped.
    pub waiting_bytes: usize,
    /// Queries and informs dropped because too many waited for a handler.
    pub dropped_waiting: u64,
    /// What pending queues hold: message data plus [`DISPATCH_COST`] per
    /// message, so that a flood of empty messages is bounded too.
    pub queued_bytes: usize,
    /// Most `queued_bytes` ever seen.
    pub peak_queued_bytes: usize,
    /// Messages dropped by queue limits (`limitPending`).
    pub dropped: u64,
    /// Frames received from modules.
    pub frames_in: u64,
}

/// The IPC central server's state.
#[derive(Debug)]
pub struct Central {
    config: Config,
    outputs: VecDeque<Output>,
    modules: BTreeMap<ConnId, Module>,
    msgs: HashMap<String, Msg>,
    by_id: HashMap<i32, String>,
    next_ids: Vec<i32>,
    id_block: i32,
    formats: FormatRegistry,
    /// Named formats as registered (strings), for `getNamedForm`.
    vars: BTreeMap<String, Var>,
    broadcast_msgs: Vec<String>,
    broadcast_size: usize,
    dispatches: HashMap<i32, Dispatch>,
    free_dispatch: Vec<i32>,
    next_dispatch: i32,
    ignore: HashSet<String>,
    /// Dispatches kept for `-r`, by module name.
    orphans: HashMap<String, Vec<i32>>,
    stats: Stats,
    memory_paused: HashSet<ConnId>,
    /// Of those, modules held back while they answer a query.
    answer_paused: HashSet<ConnId>,
    handler_seq: u64,
    msg_info_query: Format,
    msg_info_reply: Format,
    /// The time of the event being handled, for what central sends of
    /// its own accord (variable broadcasts) and logs with `-t`.
    clock: SystemTime,
}

/// Why a frame from a module could not be handled.
#[derive(Debug)]
struct Bad(String);

impl<E: std::fmt::Display> From<E> for Bad {
    fn from(e: E) -> Bad {
        Bad(e.to_string())
    }
}

impl Central {
    /// A central with no modules.
    pub fn new(config: Config) -> Self {
        Self::new_at(config, SystemTime::UNIX_EPOCH)
    }

    /// A central with no modules, started at `now`: the time its start-up
    /// log lines carry with `-lt` (C logs registering its own variables).
    pub fn new_at(config: Config, now: SystemTime) -> Self {
        let mut c = Central {
            ignore: config.ignore.iter().cloned().collect(),
            config,
            outputs: VecDeque::new(),
            modules: BTreeMap::new(),
            msgs: HashMap::new(),
            by_id: HashMap::new(),
            next_ids: Vec::new(),
            id_block: 0,
            formats: FormatRegistry::new(),
            vars: BTreeMap::new(),
            broadcast_msgs: Vec::new(),
            broadcast_size: 0,
            dispatches: HashMap::new(),
            free_dispatch: Vec::new(),
            next_dispatch: 0,
            orphans: HashMap::new(),
            stats: Stats::default(),
            memory_paused: HashSet::new(),
            answer_paused: HashSet::new(),
            handler_seq: 0,
            msg_info_query: internal::fixed(internal::MSG_INFO_QUERY_FORMAT),
            msg_info_reply: internal::fixed(internal::MSG_INFO_REPLY_FORMAT),
            clock: now,
        };
        let _ = c
            .formats
            .define("directMsgHandler", "{int, int, int, int, string, string}");
        for d in internal::table() {
            c.register_internal(d);
        }
        // C's order (logged when `-l` lacks `i`): both log variables
        // registered, then set; the tapped and broadcast lists each
        // registered and set.
        c.register_var(internal::TERMINAL_LOG_VAR);
        c.register_var(internal::FILE_LOG_VAR);
        c.update_log_vars();
        for var in [internal::TERMINAL_LOG_VAR, internal::FILE_LOG_VAR] {
            let value = c.vars[var].value.clone();
            c.central_inform(&format!("V_set_{var}"), value, |_, _| {});
        }
        let empty = c.str_list_value(&[], 0);
        for var in [internal::TAPPED_MSG_VAR, internal::BROADCAST_MSG_VAR] {
            c.register_var(var);
            c.set_var_by_central(var, empty.clone());
        }
        // C opens its log file after this (`Start_File_Logging`): these
        // lines reach the terminal only.
        c.outputs.retain_mut(|o| match o {
            Output::Log { target, .. } => {
                target.file = false;
                target.terminal
            }
            _ => true,
        });
        c
    }

    /// The configuration.
    pub fn config(&self) -> &Config {
        &self.config
    }

    /// Counters (modules, dispatches, queued bytes and their peak, drops).
    pub fn stats(&self) -> Stats {
        let mut s = self.stats;
        s.modules = self.modules.len();
        s.dispatches = self.dispatches.len();
        s.waiting_for_handler = self.msgs.values().map(|m| m.waiting.len()).sum();
        s
    }

    /// Central's id for a message name (what `x_ipc_msgInfoMsg` answers,
    /// without the direct-mode sign), if the message is known.
    pub fn message_id(&self, name: &str) -> Option<i32> {
        self.msgs.get(name).map(|m| m.id).filter(|id| *id != 0)
    }

    /// The names of the connected modules (those that completed the connect query).
    pub fn module_names(&self) -> Vec<String> {
        self.modules
            .values()
            .filter_map(|m| m.name.clone())
            .collect()
    }

    // ----- ids ---------------------------------------------------------

    fn alloc_msg_id(&mut self) -> i32 {
        loop {
            if let Some(id) = self.next_ids.pop() {
                if id >= 2 {
                    return id;
                }
                continue;
            }
            // C's id table grows by 200 and hands out the highest id first.
            let lo = self.id_block * 200;
            self.id_block += 1;
            self.next_ids = (lo..lo + 200).collect();
        }
    }

    /// A dispatch id, last freed first (as C's `dispatchAllocate`).
    fn take_ref(&mut self) -> i32 {
        self.free_dispatch.pop().unwrap_or_else(|| {
            let id = self.next_dispatch;
            self.next_dispatch += 1;
            id
        })
    }

    /// C gives every message a dispatch, the internal ones central handles
    /// and the informs it sends itself included, and frees it once
    /// handled; with `-lr` the log shows its id. Central holds an id from
    /// the same pool while it handles one, so that the ids it logs, and
    /// gives the modules' messages, follow C's.
    fn give_ref(&mut self, id: i32) {
        self.free_dispatch.push(id);
    }

    fn alloc_dispatch(&mut self, d: Dispatch) -> i32 {
        let id = self.take_ref();
        if let (Org::Module(asker), true) = (d.org, awaits_answer(d.class)) {
            if let Some(m) = self.modules.get_mut(&asker) {
                m.asking += 1;
            }
        }
        self.dispatches.insert(id, d);
        id
    }

    fn free_dispatch_id(&mut self, id: i32) -> Option<Dispatch> {
        let d = self.dispatches.remove(&id)?;
        unqueue(&mut self.stats, &d);
        if let (Org::Module(asker), true) = (d.org, awaits_answer(d.class)) {
            if let Some(m) = self.modules.get_mut(&asker) {
                m.asking = m.asking.saturating_sub(1);
            }
        }
        self.give_ref(id);
        Some(d)
    }

    // ----- message table -------------------------------------------------

    fn register_internal(&mut self, d: Def) {
        if !d.ignore_log || matches!(d.kind, Internal::Notify) {
            // logged unless -I
        }
        if d.ignore_log {
            self.ignore.insert(d.name.to_string());
        }
        self.insert_msg(
            d.name.to_string(),
            d.class,
            d.msg_format.map(str::to_string),
            d.res_format.map(str::to_string),
            Some(d.kind),
        );
    }

    fn insert_msg(
        &mut self,
        name: String,
        class: MsgClass,
        msg_format: Option<String>,
        res_format: Option<String>,
        internal: Option<Internal>,
    ) -> i32 {
        if let Some(m) = self.msgs.get_mut(&name) {
            let id = if m.id == 0 { 0 } else { m.id };
            let was_placeholder = m.class == MsgClass::HandlerReg;
            m.class = class;
            m.msg_format = msg_format;
            m.res_format = res_format;
            m.parsed = None;
            if internal.is_some() {
                m.internal = internal;
            }
            let id = if id == 0 {
                let id = self.alloc_msg_id();
                self.msgs.get_mut(&name).unwrap().id = id;
                self.by_id.insert(id, name.clone());
                id
            } else {
                id
            };
            if was_placeholder && class != MsgClass::Broadcast {
                self.record_broadcast(&name, false);
            }
            return id;
        }
        let id = self.alloc_msg_id();
        self.by_id.insert(id, name.clone());
        self.msgs.insert(
            name.clone(),
            Msg {
                id,
                name,
                class,
                msg_format,
                res_format,
                parsed: None,
                handlers: Vec::new(),
                waiting: VecDeque::new(),
                priority: DEFAULT_PRIORITY,
                direct: false,
                notify_handler_change: false,
                internal,
            },
        );
        id
    }

    fn placeholder(&mut self, name: &str) {
        if !self.msgs.contains_key(name) {
            self.msgs.insert(
                name.to_string(),
                Msg {
                    id: 0,
                    name: name.to_string(),
                    class: MsgClass::HandlerReg,
                    msg_format: None,
                    res_format: None,
                    parsed: None,
                    handlers: Vec::new(),
                    waiting: VecDeque::new(),
                    priority: DEFAULT_PRIORITY,
                    direct: false,
                    notify_handler_change: false,
                    internal: None,
                },
            );
        }
    }

    fn register_var(&mut self, var: &str) {
        if self.vars.contains_key(var) {
            return;
        }
        // `centralRegisterVar` sends central `x_ipc_registerGlobalVar`
        // ({varName, format}) and logs it.
        let mut w = Writer::new();
        w.write_str(var);
        w.write_str(&internal::var_format(var));
        self.central_inform(internal::REGISTER_GLOBAL_VAR, w.into_vec(), |c, _| {
            c.add_var(var)
        });
    }

    fn add_var(&mut self, var: &str) {
        let format = internal::fixed(&internal::var_format(var));
        self.vars.insert(
            var.to_string(),
            Var {
                format,
                value: Vec::new(),
                version: 0,
            },
        );
        for (name, class, mf, rf, kind) in internal::var_defs(var) {
            self.ignore.insert(name.clone());
            self.insert_msg(name, class, mf, rf, Some(kind));
        }
    }

    /// Parsed formats of a message (named formats expanded as C does when
    /// it parses at lookup time; an unknown name stays `Named`).
    fn parsed(&mut self, name: &str) -> (Option<Format>, Option<Format>) {
        let reg = &self.formats;
        let Some(m) = self.msgs.get_mut(name) else {
            return (None, None);
        };
        if m.parsed.is_none() {
            let p = |s: &Option<String>| -> Option<Format> {
                let s = s.as_deref()?;
                if s.is_empty() {
                    return None;
                }
                parse_with(s, reg).or_else(|_| parse(s)).ok()
            };
            m.parsed = Some((p(&m.msg_format), p(&m.res_format)));
        }
        m.parsed.clone().unwrap_or((None, None))
    }

    // ----- output helpers --------------------------------------------------

    fn transmit(&mut self, conn: ConnId, bytes: Vec<u8>) {
        self.transmit_parts(conn, bytes, None);
    }

    /// A frame: `head`, then `body` if any.
    fn transmit_parts(&mut self, conn: ConnId, head: Vec<u8>, body: Option<Body>) {
        let Some(m) = self.modules.get_mut(&conn) else {
            return;
        };
        if m.closed {
            return;
        }
        if m.relay_from.is_some() {
            // Not in the middle of the frame being forwarded to it.
            m.held.push((head, body));
        } else {
            self.outputs.push_back(match body {
                None => Output::Transmit { conn, bytes: head },
                Some(body) => Output::TransmitBody { conn, head, body },
            });
        }
    }

    /// A frame carrying `data`: a large one shares it
    /// ([`Output::TransmitBody`]), a small one is one buffer.
    fn transmit_frame(&mut self, conn: ConnId, header: Header, class_data: &[u8], data: &Body) {
        if data.len() >= SPLIT_AT {
            let head = Self::head(header, class_data, &[], data.len());
            self.transmit_parts(conn, head, Some(data.clone()));
        } else {
            let f = Self::frame(header, class_data, data);
            self.transmit(conn, f);
        }
    }

    /// Bytes of the frame being forwarded to `conn` (never held).
    fn transmit_relayed(&mut self, conn: ConnId, bytes: Vec<u8>) {
        if self.modules.get(&conn).is_some_and(|m| !m.closed) {
            self.outputs.push_back(Output::Transmit { conn, bytes });
        }
    }

    fn frame(header: Header, class_data: &[u8], data: &[u8]) -> Vec<u8> {
        Self::head(header, class_data, data, data.len())
    }

    /// A frame's header and class data followed by `data`, which is the
    /// whole body (`data_len` bytes) or, for a relayed frame, its start.
    fn head(header: Header, class_data: &[u8], data: &[u8], data_len: usize) -> Vec<u8> {
        let mut h = header;
        h.class_total = class_data.len() as i32;
        h.msg_total = data_len as i32;
        let mut out = Vec::with_capacity(HEADER_SIZE + class_data.len() + data.len());
        out.extend_from_slice(&h.encode());
        out.extend_from_slice(class_data);
        out.extend_from_slice(data);
        out
    }

    /// `centralReply`: parentRef 0, intent -4, class 0, dispatchRef 0.
    fn reply(&mut self, conn: ConnId, msg_ref: i32, data: &[u8]) {
        let h = Header {
            class_total: 0,
            msg_total: 0,
            parent_ref: 0,
            intent: QUERY_REPLY_INTENT,
            class_id: ClassId::native(MsgClass::Unknown),
            dispatch_ref: 0,
            msg_ref,
        };
        let f = Self::frame(h, &[], data);
        self.transmit(conn, f);
    }

    fn log_line(&mut self, kind: Kind, line: String) {
        let target = LogTarget {
            terminal: kind == Kind::Problem || kind.enabled(&self.config.terminal_log),
            file: kind.enabled(&self.config.file_log),
        };
        if target.terminal || target.file {
            self.outputs.push_back(Output::Log { target, line });
        }
    }

    /// Options of whichever log is the more verbose (ref/parent/time fields).
    fn opts(&self) -> LogOptions {
        if self.config.terminal_log.any() {
            self.config.terminal_log
        } else {
            self.config.file_log
        }
    }

    /// Whether a `kind` line about `msg` goes anywhere: its kind is on in
    /// some log, and `msg` is not ignored (`-i` / `-I`). Checked before a
    /// line is formatted, so that a central with logging off (`-lx`) does
    /// no formatting work per message.
    fn logs(&self, kind: Kind, msg: &str) -> bool {
        let o = self.opts();
        (kind.enabled(&self.config.terminal_log) || kind.enabled(&self.config.file_log))
            && !(self.ignore.contains(msg)
                && (o.ignore_internal || self.config.ignore.iter().any(|n| n == msg)))
    }

    /// `dispatchUpdateAndDisplay1`'s common layout:
    /// `Class      msg {ref}:     origin {parent} --> <to><time>`.
    #[allow(clippy::too_many_arguments)]
    fn dispatch_line(
        &self,
        class: u16,
        msg: &str,
        did: Option<i32>,
        org: &str,
        parent: i32,
        to: &str,
        now: SystemTime,
    ) -> String {
        let o = self.opts();
        format!(
            "{:<9} {:>15}{}: {:>10}{} --> {to}{}",
            log::class_name(class),
            msg,
            did.map(|d| log::ref_id(&o, d)).unwrap_or_default(),
            org,
            log::parent_id(&o, parent),
            log::time(&o, now)
        )
    }

    fn module_name(&self, org: Org) -> String {
        match org {
            Org::Central => SERVER_NAME.to_string(),
            Org::Module(c) => self
                .modules
                .get(&c)
                .and_then(|m| m.name.clone())
                // A module not named yet (before its connect query).
                .unwrap_or_else(|| "**NEWMOD**".to_string()),
        }
    }

    fn log_data(&mut self, msg: &str, class_id: ClassId, data: &[u8], reply_of: Option<&str>) {
        self.log_data_as(msg, class_id, data, reply_of, false)
    }

    /// `internal`: the data is an internal message's own format (its
    /// msgFormat), not a user message body.
    fn log_data_as(
        &mut self,
        msg: &str,
        class_id: ClassId,
        data: &[u8],
        reply_of: Option<&str>,
        internal: bool,
    ) {
        if !Kind::Data.enabled(&self.config.terminal_log)
            && !Kind::Data.enabled(&self.config.file_log)
        {
            return;
        }
        let name = reply_of.unwrap_or(msg).to_string();
        let (mf, rf) = self.parsed(&name);
        let (mf, rf) = if internal { (None, mf) } else { (mf, rf) };
        self.log_decoded(&name, &mf, &rf, data, class_id);
    }

    /// The data lines of `data`, decoded as [`decode_user`] does.
    fn log_decoded(
        &mut self,
        name: &str,
        mf: &Option<Format>,
        rf: &Option<Format>,
        data: &[u8],
        class_id: ClassId,
    ) {
        let order = class_id.data_order().unwrap_or(ByteOrder::NATIVE);
        let text = match decode_user(mf, rf, data, order, &self.formats) {
            Ok(Some(t)) => t,
            Ok(None) => return,
            Err(e) => format!("    <cannot decode {name}: {e}>"),
        };
        for line in text.trim_end_matches('\n').split('\n') {
            self.log_line(Kind::Data, line.to_string());
        }
    }

    // ----- connection events ---------------------------------------------

    /// A module connected: queues the 4-byte msgInfo id and the two
    /// formatter frames central speaks first (ipc.md §4).
    pub fn connect(&mut self, conn: ConnId, peer: Peer, now: SystemTime) {
        self.clock = now;
        self.modules.insert(
            conn,
            Module {
                peer,
                rx: Vec::new(),
                rx_pos: 0,
                name: None,
                host: String::new(),
                ready: false,
                capacity: 1,
                attending: 0,
                answering: 0,
                asking: 0,
                pending: VecDeque::new(),
                ahead: VecDeque::new(),
                msg_limits: Vec::new(),
                pending_limit: None,
                port: -1,
                handlers: BTreeMap::new(),
                retired: BTreeMap::new(),
                vars_read: BTreeMap::new(),
                paused: false,
                closed: false,
                problems: log::ProblemBudget::default(),
                relay: None,
                relay_from: None,
                held: Vec::new(),
                big_end: None,
            },
        );
        let id = self.msgs.get(internal::MSG_INFO).map_or(0, |m| m.id);
        self.transmit(conn, id.to_be_bytes().to_vec());
        for f in [self.msg_info_query.clone(), self.msg_info_reply.clone()] {
            let mut w = Writer::new();
            internal::write_formatter(&mut w, Some(&f));
            let h = Header {
                class_total: 0,
                msg_total: 0,
                parent_ref: 0,
                intent: 0,
                class_id: ClassId::native(MsgClass::Unknown),
                dispatch_ref: 0,
                msg_ref: 0,
            };
            let fr = Self::frame(h, &[], w.as_bytes());
            self.transmit(conn, fr);
        }
    }

    /// Bytes arrived on a connection (any split of the stream).
    pub fn receive(&mut self, conn: ConnId, bytes: &[u8], now: SystemTime) {
        self.clock = now;
        let Some(m) = self.modules.get_mut(&conn) else {
            return;
        };
        if m.closed {
            return;
        }
        let mut bytes = self.relay_bytes(conn, bytes);
        loop {
            let Some(m) = self.modules.get_mut(&conn) else {
                return;
            };
            match m.big_end {
                // A large frame's buffer takes its own bytes only.
                Some(end) => {
                    let k = (end - m.rx.len()).min(bytes.len());
                    m.rx.extend_from_slice(&bytes[..k]);
                    bytes = &bytes[k..];
                    if m.rx.len() == end {
                        m.big_end = None;
                    }
                }
                None => {
                    m.rx.extend_from_slice(bytes);
                    bytes = &[];
                }
            }
            if !self.take_frames(conn, now) {
                return;
            }
            if bytes.is_empty() {
                break;
            }
        }
        if let Some(m) = self.modules.get_mut(&conn) {
            if m.rx_pos == m.rx.len() {
                m.rx.clear();
                m.rx_pos = 0;
                if m.rx.capacity() > 1 << 20 {
                    m.rx.shrink_to(64 << 10);
                }
            } else if m.rx_pos > 0 {
                m.rx.drain(..m.rx_pos);
                m.rx_pos = 0;
            }
        }
        self.check_memory(conn);
    }

    /// Processes the whole frames at the front of `conn`'s receive buffer.
    /// False if the connection was closed.
    fn take_frames(&mut self, conn: ConnId, now: SystemTime) -> bool {
        loop {
            let Some(m) = self.modules.get_mut(&conn) else {
                return false;
            };
            if m.closed {
                return false;
            }
            let avail = m.rx.len() - m.rx_pos;
            if avail < HEADER_SIZE {
                return true;
            }
            let header = match Header::decode(&m.rx[m.rx_pos..]) {
                Ok(h) => h,
                Err(e) => {
                    self.protocol_error(conn, e.to_string(), now);
                    return false;
                }
            };
            let n = match header.body_len(self.config.max_frame) {
                Ok(n) => n,
                Err(e) => {
                    self.protocol_error(conn, e.to_string(), now);
                    return false;
                }
            };
            if avail < HEADER_SIZE + n {
                if self.try_relay(conn, header, n, now) {
                    // Everything read so far belonged to the frame.
                    self.modules.get_mut(&conn).unwrap().big_end = None;
                    return true;
                }
                let m = self.modules.get_mut(&conn).unwrap();
                if n < SPLIT_AT {
                    m.rx.reserve(HEADER_SIZE + n - avail);
                } else if m.big_end.is_none() {
                    // Its own buffer, of its exact size (`max_frame` bounds it).
                    let mut frame = Vec::with_capacity(HEADER_SIZE + n);
                    frame.extend_from_slice(&m.rx[m.rx_pos..]);
                    m.rx = frame;
                    m.rx_pos = 0;
                    m.big_end = Some(HEADER_SIZE + n);
                }
                return true;
            }
            let start = m.rx_pos + HEADER_SIZE;
            let c = header.class_total as usize;
            let class_data = m.rx[start..start + c].to_vec();
            let data = if m.rx_pos == 0 && start + n == m.rx.len() && n - c >= SPLIT_AT {
                // The frame is the whole buffer: its data stays where it is.
                Body::in_frame(std::mem::take(&mut m.rx), start + c..start + n)
            } else {
                m.rx_pos = start + n;
                Body::from(&m.rx[start + c..start + n])
            };
            self.stats.frames_in += 1;
            if let Err(Bad(e)) = self.process(conn, header, &class_data, data, now) {
                self.protocol_error(conn, e, now);
                return false;
            }
        }
    }

    // ----- cut-through ---------------------------------------------------------

    /// Passes the start of `bytes` on if a frame from `conn` is being
    /// forwarded; returns what follows that frame.
    fn relay_bytes<'a>(&mut self, conn: ConnId, bytes: &'a [u8]) -> &'a [u8] {
        let Some(r) = self.modules.get_mut(&conn).and_then(|m| m.relay.as_mut()) else {
            return bytes;
        };
        let k = r.remaining.min(bytes.len());
        r.remaining -= k;
        let (to, done) = (r.to, r.remaining == 0);
        if k > 0 {
            self.transmit_relayed(to, bytes[..k].to_vec());
        }
        if done {
            self.finish_relay(conn);
        }
        &bytes[k..]
    }

    /// Starts forwarding the frame whose header (and class data) is at the
    /// front of `conn`'s receive buffer, if [`Config::cut_through`] allows it
    /// and its receiver can take it now. True if it did: the buffer's bytes
    /// have gone out with the frame's new header.
    fn try_relay(&mut self, conn: ConnId, h: Header, n: usize, now: SystemTime) -> bool {
        let Some(min) = self.config.cut_through else {
            return false;
        };
        let data_log = Kind::Data.enabled(&self.config.terminal_log)
            || Kind::Data.enabled(&self.config.file_log);
        if n < min || data_log || self.config.resend_on_reconnect {
            return false;
        }
        let Some(m) = self.modules.get(&conn) else {
            return false;
        };
        let c = h.class_total as usize;
        let avail = m.rx.len() - m.rx_pos;
        if m.relay.is_some() || avail < HEADER_SIZE + c {
            return false;
        }
        if h.class_id.data_order().is_none() || h.class_id.class_order().is_none() {
            // `process` closes the connection once the frame is whole.
            return false;
        }
        let start = m.rx_pos + HEADER_SIZE;
        let class_data = m.rx[start..start + c].to_vec();
        let first = m.rx[start + c..].to_vec();
        let total = n - c;
        let class = h.class_id.class();
        let started = match class {
            11 => self.relay_reply(conn, h, &class_data, &first, total),
            3 | 6 | 15 => self.relay_delivery(conn, h, &first, total, now),
            _ => false,
        };
        if started {
            let m = self.modules.get_mut(&conn).unwrap();
            m.rx_pos = m.rx.len();
            self.stats.frames_in += 1;
        }
        started
    }

    /// A receiver that can take a relayed frame now.
    fn can_take_relay(&self, from: ConnId, to: ConnId) -> bool {
        from != to
            && self
                .modules
                .get(&to)
                .is_some_and(|m| !m.closed && m.relay_from.is_none())
    }

    fn relay_delivery(
        &mut self,
        conn: ConnId,
        h: Header,
        first: &[u8],
        total: usize,
        now: SystemTime,
    ) -> bool {
        let class = h.class_id.class();
        let Some(name) = h
            .intent
            .checked_abs()
            .and_then(|id| self.by_id.get(&id))
            .cloned()
        else {
            return false;
        };
        let Some(msg) = self.msgs.get(&name) else {
            return false;
        };
        if msg.internal.is_some() {
            return false;
        }
        let hnd = match (class, msg.handlers.as_slice()) {
            (15, [only]) => only.clone(),
            (3 | 6, [.., last]) => last.clone(),
            _ => return false,
        };
        let Some(to) = self.modules.get(&hnd.0) else {
            return false;
        };
        let free = to.takes_delivery_now() && to.handlers.contains_key(&hnd.1);
        if !free || !self.can_take_relay(conn, hnd.0) {
            return false;
        }
        let did = self.alloc_dispatch(Dispatch {
            msg: name.clone(),
            class,
            class_id: h.class_id,
            org: Org::Module(conn),
            org_ref: h.msg_ref,
            parent_ref: h.parent_ref,
            // Never stored: it passes through.
            data: Body::empty(),
            hnd: Some(hnd.clone()),
            status: Status::NoHandler,
        });
        self.start_relay(conn, hnd.0, name, total - first.len(), total, None);
        self.attend_as(did, false, now, Carry::Relayed(first, total));
        true
    }

    fn relay_reply(
        &mut self,
        conn: ConnId,
        h: Header,
        class_data: &[u8],
        first: &[u8],
        total: usize,
    ) -> bool {
        let did = h.dispatch_ref;
        let Some(d) = self.dispatches.get(&did).filter(|d| d.attending_at(conn)) else {
            return false;
        };
        let Org::Module(org) = d.org else {
            return false;
        };
        if !self.can_take_relay(conn, org) {
            return false;
        }
        let reply_name = if class_data.is_empty() {
            None
        } else {
            let order = h.class_id.class_order().unwrap_or(ByteOrder::NATIVE);
            match read_opt_str(&mut Reader::new(class_data, order)) {
                Ok(n) => n,
                // `on_reply` reports it once the frame is whole.
                Err(_) => return false,
            }
        };
        let msg = d.msg.clone();
        let header = Self::reply_header(&h, did, d.org_ref);
        let head = Self::head(header, class_data, first, total);
        let remaining = total - first.len();
        self.start_relay(conn, org, msg, remaining, total, Some((h, reply_name)));
        self.transmit_relayed(org, head);
        true
    }

    fn start_relay(
        &mut self,
        from: ConnId,
        to: ConnId,
        msg: String,
        remaining: usize,
        total: usize,
        reply: Option<(Header, Option<String>)>,
    ) {
        self.modules.get_mut(&to).unwrap().relay_from = Some(from);
        self.modules.get_mut(&from).unwrap().relay = Some(Relay {
            to,
            remaining,
            total,
            msg,
            reply,
        });
    }

    /// The relayed frame from `conn` has passed: frames held for its
    /// receiver go out, and a reply's bookkeeping is done.
    fn finish_relay(&mut self, conn: ConnId) {
        let Some(r) = self.modules.get_mut(&conn).and_then(|m| m.relay.take()) else {
            return;
        };
        if let Some(to) = self.modules.get_mut(&r.to) {
            to.relay_from = None;
            let held = std::mem::take(&mut to.held);
            for (head, body) in held {
                self.transmit_parts(r.to, head, body);
            }
        }
        if let Some((h, reply_name)) = r.reply {
            let now = self.clock;
            self.reply_done(conn, h, reply_name, None, now);
        }
    }

    /// The sender of a relayed frame is gone: its receiver already has the
    /// start, so the frame is completed with zeros to keep the stream whole.
    fn abandon_relay(&mut self, conn: ConnId) {
        let Some(r) = self.modules.get(&conn).and_then(|m| m.relay.as_ref()) else {
            return;
        };
        let (to, remaining, total, msg) = (r.to, r.remaining, r.total, r.msg.clone());
        let from = self.describe(conn);
        let dest = self.describe(to);
        self.log_line(
            Kind::Problem,
            format!(
                "WARNING: connection {from} ended in the middle of {msg} ({} of {total} bytes \
                 forwarded); the rest went to {dest} as zero bytes",
                total - remaining
            ),
        );
        if remaining > 0 {
            self.transmit_relayed(to, vec![0; remaining]);
        }
        if let Some(r) = self.modules.get_mut(&conn).and_then(|m| m.relay.as_mut()) {
            r.remaining = 0;
        }
        self.finish_relay(conn);
    }

    fn protocol_error(&mut self, conn: ConnId, why: String, now: SystemTime) {
        let who = self.describe(conn);
        self.log_line(
            Kind::Problem,
            format!("ERROR: closing connection {who}: {why}"),
        );
        self.outputs.push_back(Output::Close { conn, reason: why });
        self.close_module(conn, false, now);
    }

    /// A line about something `conn` did wrong, within its
    /// [`log::ProblemBudget`]: a module repeating a mistake in a loop gets
    /// a burst of lines, then one a second, and a count of the rest.
    fn complain(&mut self, conn: ConnId, line: String) {
        let now = self.clock;
        let allowed = match self.modules.get_mut(&conn) {
            Some(m) => m.problems.allow(now),
            None => Some(0),
        };
        if let Some(left_out) = allowed {
            self.report_left_out(conn, left_out);
            self.log_line(Kind::Problem, line);
        }
    }

    fn report_left_out(&mut self, conn: ConnId, left_out: u64) {
        if left_out > 0 {
            let who = self.describe(conn);
            self.log_line(
                Kind::Problem,
                format!("WARNING: {left_out} more problem line(s) about connection {who} left out"),
            );
        }
    }

    fn describe(&self, conn: ConnId) -> String {
        match self.modules.get(&conn) {
            Some(m) => {
                let peer = match &m.peer {
                    Peer::Tcp(a) => a.clone(),
                    Peer::Unix => "unix socket".into(),
                    Peer::Other(s) => s.clone(),
                };
                match &m.name {
                    Some(n) => format!("{} ({n} from {peer})", conn.0),
                    None => format!("{} (from {peer})", conn.0),
                }
            }
            None => conn.0.to_string(),
        }
    }

    /// The connection ended (EOF, error, or after [`Output::Close`]).
    pub fn disconnect(&mut self, conn: ConnId, now: SystemTime) {
        self.clock = now;
        if !self.modules.contains_key(&conn) {
            return;
        }
        let partial = self.modules.get(&conn).map_or(0, |m| m.rx.len() - m.rx_pos);
        if partial > 0 {
            let who = self.describe(conn);
            self.log_line(
                Kind::Problem,
                format!("WARNING: connection {who} closed in the middle of a frame ({partial} byte(s) discarded)"),
            );
        }
        self.close_module(conn, true, now);
    }

    /// `x_ipcCloseMod`: forget a module, its handlers and its deliveries.
    /// `eof`: the connection ended without `x_ipc_CloseMsg` (C logs that
    /// path differently).
    fn close_module(&mut self, conn: ConnId, eof: bool, now: SystemTime) {
        let _ = now;
        let Some(m) = self.modules.get_mut(&conn) else {
            return;
        };
        if m.closed {
            self.modules.remove(&conn);
            return;
        }
        m.closed = true;
        let left_out = m.problems.take_suppressed();
        let name = m.name.clone();
        let host = m.host.clone();
        self.report_left_out(conn, left_out);
        // A frame it was sending through: its receiver needs the rest.
        self.abandon_relay(conn);
        if eof {
            // handleDataMsgRecv
            self.log_line(
                Kind::Status,
                format!("Closed Connection Detected from: sd: {}: ", conn.0),
            );
            if let Some(n) = &name {
                self.log_line(Kind::Always, format!(" Closing {n} on {host}"));
            }
        } else {
            // x_ipcCloseHnd
            self.log_line(
                Kind::Always,
                format!(
                    "x_ipcClose: Closed Connection Detected from: sd: {}:",
                    conn.0
                ),
            );
            if let Some(n) = &name {
                self.log_line(Kind::Always, format!("x_ipcClose: Closing {n} on {host}"));
            }
        }
        if let Some(n) = &name {
            self.log_line(Kind::Always, format!("close Module: Closing {n}"));
        }
        // Its handlers go away (`moduleClean`): watch variables of the
        // affected messages are updated in subscription order, then the
        // broadcast list is cleaned in its own order (`cleanBroadcast`).
        let mut hnds: Vec<(u64, String, String)> = self.modules[&conn]
            .handlers
            .iter()
            .map(|(hn, h)| (h.seq, hn.clone(), h.msg.clone()))
            .collect();
        hnds.sort();
        let mut changed: Vec<String> = Vec::new();
        for (_, hn, msg) in &hnds {
            if let Some(mm) = self.msgs.get_mut(msg) {
                mm.handlers.retain(|(c, n)| !(*c == conn && n == hn));
                if (mm.direct || mm.notify_handler_change) && !changed.contains(msg) {
                    changed.push(msg.clone());
                }
            }
        }
        // Deliveries it was handling, then those it had pending, in order.
        let mut mine: Vec<i32> = self
            .dispatches
            .iter()
            .filter(|(_, d)| d.attending_at(conn))
            .map(|(id, _)| *id)
            .collect();
        mine.sort_unstable();
        // C (resourceDelete) only reports when something was being handled.
        let report = !mine.is_empty();
        mine.extend(self.modules[&conn].ahead.iter().copied());
        mine.extend(self.modules[&conn].pending.iter().copied());
        for id in mine {
            let keep = self.config.resend_on_reconnect && name.is_some();
            let d = self.dispatches.get_mut(&id).unwrap();
            unqueue(&mut self.stats, d);
            if keep {
                d.status = Status::NoHandler;
                let msg = d.msg.clone();
                self.orphans
                    .entry(name.clone().unwrap())
                    .or_default()
                    .push(id);
                self.log_line(
                    Kind::Status,
                    format!(
                        "Keeping {msg} {{{id}}} to resend when {} reconnects",
                        name.as_deref().unwrap_or("?")
                    ),
                );
            } else {
                let msg = d.msg.clone();
                self.free_dispatch_id(id);
                if report {
                    let o = self.opts();
                    self.log_line(
                        Kind::Always,
                        format!("Clearing handler for message {msg}{}", log::ref_id(&o, id)),
                    );
                }
            }
        }
        for msg in changed {
            self.update_direct_handlers(&msg);
        }
        self.clean_broadcast();
        self.memory_paused.remove(&conn);
        self.answer_paused.remove(&conn);
        self.modules.remove(&conn);
        if let Some(n) = name {
            self.central_broadcast(internal::DISCONNECT_NOTIFY, |w| w.write_str(&n));
        }
    }

    // ----- frame processing ----------------------------------------------

    fn process(
        &mut self,
        conn: ConnId,
        h: Header,
        class_data: &[u8],
        data: Body,
        now: SystemTime,
    ) -> Result<(), Bad> {
        if h.class_id.data_order().is_none() || h.class_id.class_order().is_none() {
            return Err(Bad(format!(
                "frame has an unknown byte-order flag (classId 0x{:08x})",
                h.class_id.0
            )));
        }
        match h.class_id.class() {
            12 => return self.on_success(conn, h.dispatch_ref, now),
            11 => return self.on_reply(conn, h, class_data, data, now),
            _ => {}
        }
        let id = h.intent.checked_abs().unwrap_or(0);
        let Some(name) = self.by_id.get(&id).cloned() else {
            let who = self.describe(conn);
            self.complain(
                conn,
                format!(
                    "WARNING: message with unknown id {} (class {}) from {who} ignored",
                    h.intent,
                    h.class_id.class()
                ),
            );
            return Ok(());
        };
        let internal = self.msgs.get(&name).and_then(|m| m.internal.clone());
        match internal {
            Some(kind) => {
                let rid = self.take_ref();
                let r = self.on_internal(conn, h, &name, kind, &data, now, rid);
                self.give_ref(rid);
                r
            }
            None => {
                self.route(conn, h, name, data, now);
                Ok(())
            }
        }
    }

    /// An internal message, handled under the dispatch id `rid`.
    #[allow(clippy::too_many_arguments)]
    fn on_internal(
        &mut self,
        conn: ConnId,
        h: Header,
        name: &str,
        kind: Internal,
        data: &[u8],
        now: SystemTime,
        rid: i32,
    ) -> Result<(), Bad> {
        let order = h.class_id.data_order().unwrap_or(ByteOrder::NATIVE);
        let mut r = Reader::new(data, order);
        let query = h.class_id.class() == MsgClass::Query as u16;
        let logged = self.logs(Kind::Message, name);
        let org_name = self.module_name(Org::Module(conn));
        if logged {
            let to = format!("{SERVER_NAME:<15} (Sent)");
            let line = self.dispatch_line(
                h.class_id.class(),
                name,
                Some(rid),
                &org_name,
                h.parent_ref,
                &to,
                now,
            );
            self.log_line(Kind::Message, line);
            self.log_data_as(name, h.class_id, data, None, true);
        }
        let mut out = Writer::new();
        let mut null_reply = false;
        use Internal::*;
        let lookup = matches!(kind, MsgInfo | HndInfo);
        match kind {
            MsgInfo | HndInfo => {
                let msg = read_opt_str(&mut r)?;
                let hnd = read_opt_str(&mut r)?;
                self.msg_info(conn, msg.as_deref(), hnd.as_deref(), &mut out);
            }
            ClassInfo => {
                let class = r.read_i32()?;
                match internal::class_format(class) {
                    Some(f) => {
                        out.write_ptr_flag(true);
                        out.write_i32(class);
                        internal::write_formatter(&mut out, Some(&internal::fixed(f)));
                    }
                    None => out.write_ptr_flag(false),
                }
            }
            Connect => {
                let module = read_opt_str(&mut r)?.unwrap_or_default();
                let host = read_opt_str(&mut r)?.unwrap_or_default();
                self.on_connect(conn, module, host);
                out.write_i32(VERSION.0);
                out.write_i32(VERSION.1);
                out.write_bool(self.config.direct);
            }
            Wait => {
                out.write_i32(1);
                if let Some(m) = self.modules.get_mut(&conn) {
                    m.ready = true;
                }
                self.reply(conn, h.msg_ref, out.as_bytes());
                if logged {
                    self.log_internal_reply(
                        name,
                        &org_name,
                        (rid, h.parent_ref),
                        h.class_id,
                        out.as_bytes(),
                        now,
                    );
                }
                self.process_pending(conn, now);
                return Ok(());
            }
            RegisterMessage => {
                let n = read_opt_str(&mut r)?.unwrap_or_default();
                let class = r.read_i32()?;
                let mf = read_opt_str(&mut r)?;
                let rf = read_opt_str(&mut r)?;
                self.register_message(conn, n, class, mf, rf);
            }
            RegisterNamedForm => {
                let n = read_opt_str(&mut r)?.unwrap_or_default();
                let f = read_opt_str(&mut r)?.unwrap_or_default();
                if let Err(e) = self.formats.define(&n, &f) {
                    self.complain(
                        conn,
                        format!("WARNING: bad named format {n} = \"{f}\" from {org_name}: {e}"),
                    );
                }
                for m in self.msgs.values_mut() {
                    m.parsed = None;
                }
            }
            GetNamedForm => {
                let n = read_opt_str(&mut r)?.unwrap_or_default();
                match self.formats.get(&n).cloned() {
                    Some(f) => {
                        let f = self.formats.resolve(&f).unwrap_or(f);
                        internal::write_formatter(&mut out, Some(&f));
                    }
                    None => {
                        self.log_line(Kind::Always, format!("Unknown named format {n} used."));
                        out.write_i32(6); // BadFormat
                    }
                }
            }
            RegisterHandler => {
                let id = r.read_i32()?;
                let msg = read_opt_str(&mut r)?.unwrap_or_default();
                let hnd = read_opt_str(&mut r)?.unwrap_or_default();
                self.register_handler(conn, id, msg, hnd, now);
            }
            DeregisterHandler => {
                let _ = r.read_i32()?;
                let msg = read_opt_str(&mut r)?.unwrap_or_default();
                let hnd = read_opt_str(&mut r)?.unwrap_or_default();
                self.deregister_handler(conn, &msg, &hnd);
            }
            DirectRes => {
                let port = r.read_i32()?;
                let n = read_opt_str(&mut r)?.unwrap_or_default();
                let own = self.modules.get(&conn).and_then(|m| m.name.clone());
                if own.as_deref() == Some(n.as_str()) {
                    self.modules.get_mut(&conn).unwrap().port = port;
                    self.log_line(
                        Kind::Message,
                        format!("Direct Connection Established For: {n} at {port}"),
                    );
                } else {
                    self.log_line(
                        Kind::Message,
                        format!("Direct Connection: Not Made: {n} did not originate call."),
                    );
                }
            }
            DirectInfo => {
                let n = read_opt_str(&mut r)?.unwrap_or_default();
                let list = self.direct_handlers(&n);
                match list.first() {
                    Some(e) => write_direct_entry(&mut out, e),
                    None => null_reply = true,
                }
            }
            DirectMsg => {
                let n = read_opt_str(&mut r)?.unwrap_or_default();
                let list = self.direct_handlers(&n);
                if list.is_empty() {
                    null_reply = true;
                } else {
                    write_direct_list(&mut out, &list);
                }
            }
            ModuleConnected => {
                let n = read_opt_str(&mut r)?.unwrap_or_default();
                let found = self
                    .modules
                    .values()
                    .any(|m| !m.closed && m.name.as_deref() == Some(n.as_str()));
                out.write_i32(found as i32);
            }
            NotifyHandlerChange => {
                let n = read_opt_str(&mut r)?.unwrap_or_default();
                match self.msgs.get_mut(&n) {
                    Some(m) if m.class != MsgClass::HandlerReg => {
                        let first = !m.direct && !m.notify_handler_change;
                        m.notify_handler_change = true;
                        if first {
                            self.register_var(&n);
                            self.update_direct_handlers(&n);
                        }
                    }
                    _ => self.log_line(
                        Kind::Always,
                        format!("Cannot do handler notification before message defined ({n})"),
                    ),
                }
            }
            SetMsgPriority => {
                let n = read_opt_str(&mut r)?.unwrap_or_default();
                let p = r.read_i32()?;
                self.placeholder(&n);
                self.msgs.get_mut(&n).unwrap().priority = p;
            }
            RegisterResource => {
                let cap = r.read_i32()?;
                let res = read_opt_str(&mut r)?.unwrap_or_default();
                self.set_capacity(conn, cap, &res, now);
            }
            LimitPending => {
                let msg = read_opt_str(&mut r)?;
                let res = read_opt_str(&mut r)?.unwrap_or_default();
                let limit = r.read_i32()?;
                self.limit_pending(conn, msg, &res, limit);
            }
            Close => {
                self.outputs.push_back(Output::Close {
                    conn,
                    reason: "module sent x_ipc_CloseMsg".into(),
                });
                self.close_module(conn, false, now);
                if logged {
                    self.log_done(name, rid, now);
                }
                return Ok(());
            }
            IgnoreLogging => {
                if let Some(n) = read_opt_str(&mut r)? {
                    self.ignore.insert(n);
                }
            }
            ResumeLogging => {
                if let Some(n) = read_opt_str(&mut r)? {
                    self.ignore.remove(&n);
                }
            }
            GetMessages => {
                let mut names: Vec<String> = self
                    .msgs
                    .values()
                    .filter(|m| m.internal.is_none() && m.id != 0)
                    .map(|m| m.name.clone())
                    .collect();
                names.sort();
                let size = internal::str_list_size(names.len(), 0);
                internal::encode_str_list(&names, size, &mut out);
            }
            Ignored | Notify | VarWatch(_) => {}
            VarGet(v) => match self.vars.get(&v) {
                Some(var) => {
                    out.write_bytes(&var.value.clone());
                    self.note_var_read(conn, &v);
                }
                None => null_reply = true,
            },
            VarSet(v) => self.set_var_from(&v, data, order)?,
            VarGetSet(v) => {
                if let Some(var) = self.vars.get(&v) {
                    out.write_bytes(&var.value.clone());
                }
                self.set_var_from(&v, data, order)?;
                self.note_var_read(conn, &v);
            }
        }
        if query {
            let bytes = if null_reply {
                Vec::new()
            } else {
                out.into_vec()
            };
            self.reply(conn, h.msg_ref, &bytes);
            if logged {
                // Named now if this was its connect query.
                let to = self.module_name(Org::Module(conn));
                let refs = (rid, h.parent_ref);
                self.log_internal_reply(name, &to, refs, h.class_id, &bytes, now);
            }
        } else if logged {
            self.log_done(name, rid, now);
        }
        if lookup {
            // A handler looked up: what waits for it may go ahead now,
            // behind the reply.
            self.send_ahead(conn);
        }
        Ok(())
    }

    /// `  Done    <msg>:<time>`: an internal message handled.
    fn log_done(&mut self, name: &str, rid: i32, now: SystemTime) {
        let o = self.opts();
        let line = format!(
            "  Done    {name:>15}{}:{}",
            log::ref_id(&o, rid),
            log::time(&o, now)
        );
        self.log_line(Kind::Message, line);
    }

    /// `  Reply  <msg>: X_IPC Server --> <module>  <time>` and the reply's
    /// data, decoded with the internal message's reply format.
    fn log_internal_reply(
        &mut self,
        name: &str,
        to: &str,
        (rid, parent): (i32, i32),
        class_id: ClassId,
        reply: &[u8],
        now: SystemTime,
    ) {
        let o = self.opts();
        let line = format!(
            "  Reply  {:>15}{}: {:>10} --> {:<15}{}{}",
            name,
            log::ref_id(&o, rid),
            SERVER_NAME,
            to,
            log::parent_id(&o, parent),
            log::time(&o, now)
        );
        self.log_line(Kind::Message, line);
        if reply.is_empty() || !self.logs(Kind::Data, name) {
            return;
        }
        let (_, rf) = self.parsed(name);
        self.log_decoded(name, &None, &rf, reply, class_id);
    }

    fn msg_info(&mut self, conn: ConnId, msg: Option<&str>, hnd: Option<&str>, out: &mut Writer) {
        let Some(msg) = msg else {
            out.write_ptr_flag(false);
            return;
        };
        if !self.msgs.contains_key(msg) {
            out.write_ptr_flag(false);
            return;
        }
        let (mf, rf) = self.parsed(msg);
        let m = &self.msgs[msg];
        let id = if m.direct && direct_class(m.class) {
            -m.id.abs()
        } else {
            m.id
        };
        out.write_ptr_flag(true);
        out.write_i32(id);
        out.write_str(&m.name);
        out.write_i32(m.class as i32);
        internal::write_formatter(out, mf.as_ref());
        internal::write_formatter(out, rf.as_ref());
        if let Some(hn) = hnd {
            let found = self
                .modules
                .get_mut(&conn)
                .and_then(|m| m.handlers.get_mut(hn))
                .map(|h| h.knows_msg = true)
                .is_some();
            if !found {
                self.log_line(Kind::Message, String::new());
                self.log_line(
                    Kind::Message,
                    format!("WARNING: msgInfoHnd: Missing handler: {hn}"),
                );
            }
        }
    }

    fn on_connect(&mut self, conn: ConnId, module: String, host: String) {
        self.log_line(
            Kind::Always,
            format!(" Received a new connection: {}", conn.0),
        );
        self.log_line(Kind::Always, format!("   modName : {module}"));
        self.log_line(Kind::Always, format!("   hostName: {host}"));
        self.central_broadcast(internal::CONNECT_NOTIFY, |w| w.write_str(&module));
        if let Some(m) = self.modules.get_mut(&conn) {
            m.name = Some(module);
            m.host = host;
        }
    }

    fn register_message(
        &mut self,
        conn: ConnId,
        name: String,
        class: i32,
        mf: Option<String>,
        rf: Option<String>,
    ) {
        let Some(class) = u16::try_from(class).ok().and_then(MsgClass::from_u16) else {
            self.complain(
                conn,
                format!("WARNING: message {name} registered with unknown class {class}; ignored"),
            );
            return;
        };
        if let Some(m) = self.msgs.get(&name) {
            if m.internal.is_some() {
                self.complain(
                    conn,
                    format!(
                        "WARNING: a module tried to redefine central's message {name}; ignored"
                    ),
                );
                return;
            }
            if m.class != MsgClass::HandlerReg {
                self.log_line(
                    Kind::Status,
                    format!("Registration: Message {name} Found. Updating."),
                );
            }
        }
        self.insert_msg(name.clone(), class, mf, rf, None);
        let m = self.msgs.get_mut(&name).unwrap();
        if m.class == MsgClass::Broadcast && !m.handlers.is_empty() {
            self.record_broadcast(&name, true);
        }
        let m = self.msgs.get_mut(&name).unwrap();
        if direct_class(m.class) {
            m.direct = self.config.direct;
            if m.direct || m.notify_handler_change {
                self.register_var(&name);
                self.update_direct_handlers(&name);
            }
        }
    }

    fn register_handler(
        &mut self,
        conn: ConnId,
        id: i32,
        msg: String,
        hnd: String,
        now: SystemTime,
    ) {
        // The broadcast list before this registration changes it.
        let list_before = self.var_version(internal::BROADCAST_MSG_VAR);
        let existed = self
            .msgs
            .get(&msg)
            .is_some_and(|m| m.class != MsgClass::HandlerReg);
        if existed && self.msgs[&msg].class == MsgClass::Broadcast {
            self.record_broadcast(&msg, true);
        }
        self.placeholder(&msg);
        let Some(module) = self.modules.get_mut(&conn) else {
            return;
        };
        let mod_name = module.name.clone();
        if let Some(old) = module.handlers.get_mut(&hnd) {
            // Re-registering a handler (a C module does it when the client
            // data changes, with id 0): like x_ipc_selfRegisterHnd, keep
            // the first id and forget that the module knows the message, so
            // the next delivery names it again. The C central announces the
            // handler list again all the same (registerHandlerHnd).
            old.knows_msg = false;
            let m = &self.msgs[&msg];
            if m.direct || m.notify_handler_change {
                self.update_direct_handlers(&msg);
            }
            return;
        }
        // Subscribed again after an unsubscribe: the first id, not the 0
        // the C library sends this time.
        let id = module.retired.remove(&hnd).unwrap_or(id);
        module.handlers.insert(
            hnd.clone(),
            Handler {
                id,
                seq: {
                    self.handler_seq += 1;
                    self.handler_seq
                },
                msg: msg.clone(),
                knows_msg: false,
            },
        );
        self.msgs
            .get_mut(&msg)
            .unwrap()
            .handlers
            .push((conn, hnd.clone()));
        if !existed {
            self.record_broadcast(&msg, true);
        }
        // A module's own registrations change the broadcast list it read
        // (the C central sends it none of those changes either); only
        // changes made by others in the meantime make its copy stale.
        let list_after = self.var_version(internal::BROADCAST_MSG_VAR);
        if let (Some(b), Some(a)) = (list_before, list_after) {
            if let Some(m) = self.modules.get_mut(&conn) {
                if let Some(r) = m.vars_read.get_mut(internal::BROADCAST_MSG_VAR) {
                    if *r == b {
                        *r = a;
                    }
                }
            }
        }
        self.catch_up_watch(conn, &msg, &hnd);
        let m = &self.msgs[&msg];
        if m.direct || m.notify_handler_change {
            self.update_direct_handlers(&msg);
        }
        // Queries and informs that waited for a handler.
        let waiting: Vec<i32> = self.msgs.get_mut(&msg).unwrap().waiting.drain(..).collect();
        for did in waiting {
            if let Some(d) = self.dispatches.get_mut(&did) {
                self.stats.waiting_bytes = self.stats.waiting_bytes.saturating_sub(cost(d));
                d.hnd = Some((conn, hnd.clone()));
                self.deliver_or_pend(did, now);
            }
        }
        // -r: deliveries this module had not finished before it crashed.
        if let Some(n) = mod_name {
            if let Some(list) = self.orphans.get_mut(&n) {
                let (mine, rest): (Vec<i32>, Vec<i32>) = list
                    .drain(..)
                    .partition(|id| self.dispatches.get(id).is_some_and(|d| d.msg == msg));
                *list = rest;
                for did in mine {
                    self.log_line(Kind::Always, format!("Resending {msg} {{{did}}} to {n}"));
                    if let Some(d) = self.dispatches.get_mut(&did) {
                        d.hnd = Some((conn, hnd.clone()));
                        self.deliver_or_pend(did, now);
                    }
                }
            }
        }
    }

    fn deregister_handler(&mut self, conn: ConnId, msg: &str, hnd: &str) {
        let Some(module) = self.modules.get_mut(&conn) else {
            return;
        };
        let Some(old) = module.handlers.remove(hnd) else {
            return;
        };
        module.retired.insert(hnd.to_string(), old.id);
        if let Some(m) = self.msgs.get_mut(msg) {
            m.handlers.retain(|(c, n)| !(*c == conn && n == hnd));
        }
        // Deliveries queued for the handler cannot be handled any more.
        let stale: Vec<i32> = self
            .dispatches
            .iter()
            .filter(|(_, d)| {
                d.status == Status::Pending
                    && d.hnd.as_ref().is_some_and(|(c, n)| *c == conn && n == hnd)
            })
            .map(|(id, _)| *id)
            .collect();
        for id in stale {
            if let Some(m) = self.modules.get_mut(&conn) {
                m.pending.retain(|x| *x != id);
            }
            self.free_dispatch_id(id);
            self.log_line(
                Kind::Status,
                format!("Deleted pending {msg} {{{id}}}: its handler {hnd} was unsubscribed"),
            );
        }
        self.handlers_changed(msg);
    }

    /// After handlers of `msg` changed: broadcast list and watch variable.
    fn handlers_changed(&mut self, msg: &str) {
        let Some(m) = self.msgs.get(msg) else {
            return;
        };
        if m.class == MsgClass::Broadcast && m.handlers.is_empty() {
            self.record_broadcast(msg, false);
        }
        let m = &self.msgs[msg];
        if m.direct || m.notify_handler_change {
            self.update_direct_handlers(msg);
        }
    }

    fn set_capacity(&mut self, conn: ConnId, cap: i32, res: &str, now: SystemTime) {
        if !self.modules.contains_key(&conn) {
            return;
        }
        let mut cap = cap;
        if cap < 1 {
            self.log_line(Kind::Status, String::new());
            self.log_line(
                Kind::Status,
                format!("WARNING: Capacity of {}:{res} set to 1", conn.0),
            );
            cap = 1;
        }
        let m = self.modules.get_mut(&conn).unwrap();
        if m.name.as_deref() != Some(res) {
            self.log_line(
                Kind::Status,
                format!(
                    "WARNING: resource {res} is not module {}; capacity applied to the module",
                    conn.0
                ),
            );
        }
        let m = self.modules.get_mut(&conn).unwrap();
        if m.capacity != cap as usize {
            m.capacity = cap as usize;
            self.log_line(Kind::Status, String::new());
            self.log_line(
                Kind::Status,
                format!("WARNING: Capacity of {}:{res} changed to {cap}", conn.0),
            );
        }
        // Like C, a larger capacity is used from the next completion on.
        let _ = now;
    }

    fn limit_pending(&mut self, conn: ConnId, msg: Option<String>, res: &str, limit: i32) {
        // The resource is named after its module; prefer the sender's own.
        let target = if self.modules.get(&conn).and_then(|m| m.name.as_deref()) == Some(res) {
            Some(conn)
        } else {
            self.modules
                .iter()
                .find(|(_, m)| m.name.as_deref() == Some(res))
                .map(|(c, _)| *c)
        };
        let Some(target) = target else {
            self.log_line(
                Kind::Status,
                format!("ERROR: Non-existent resource {res}; Pending limit not applied"),
            );
            return;
        };
        let m = self.modules.get_mut(&target).unwrap();
        match msg {
            None => m.pending_limit = Some(limit),
            Some(msg) => {
                if let Some(e) = m.msg_limits.iter_mut().find(|(n, _)| *n == msg) {
                    if e.1 != limit {
                        let old = e.1;
                        e.1 = limit;
                        self.log_line(
                            Kind::Status,
                            format!("WARNING: Changing pending message limit of {msg} from {old} to {limit}"),
                        );
                    }
                } else {
                    m.msg_limits.push((msg, limit));
                }
            }
        }
    }

    // ----- routing -----------------------------------------------------------

    fn route(&mut self, conn: ConnId, h: Header, name: String, data: Body, now: SystemTime) {
        let class = h.class_id.class();
        let org = Org::Module(conn);
        match class {
            15 => {
                let hnds = self.msgs[&name].handlers.clone();
                for hnd in hnds {
                    let did = self.alloc_dispatch(Dispatch {
                        msg: name.clone(),
                        class,
                        class_id: h.class_id,
                        org,
                        org_ref: h.msg_ref,
                        parent_ref: h.parent_ref,
                        data: data.clone(),
                        hnd: Some(hnd),
                        status: Status::NoHandler,
                    });
                    self.deliver_or_pend(did, now);
                }
            }
            3 | 6 => {
                let hnd = self.msgs[&name].handlers.last().cloned();
                let did = self.alloc_dispatch(Dispatch {
                    msg: name.clone(),
                    class,
                    class_id: h.class_id,
                    org,
                    org_ref: h.msg_ref,
                    parent_ref: h.parent_ref,
                    data,
                    hnd: hnd.clone(),
                    status: Status::NoHandler,
                });
                if hnd.is_some() {
                    self.deliver_or_pend(did, now);
                } else {
                    self.msgs.get_mut(&name).unwrap().waiting.push_back(did);
                    self.bound_waiting(conn, &name, did);
                    if self.logs(Kind::Message, &name) {
                        let to = format!("Resource {name:<6} (Pending)");
                        let org_name = self.module_name(org);
                        let line = self.dispatch_line(
                            class,
                            &name,
                            Some(did),
                            &org_name,
                            h.parent_ref,
                            &to,
                            now,
                        );
                        self.log_line(Kind::Message, line);
                    }
                }
            }
            other => {
                let who = self.describe(conn);
                self.complain(
                    conn,
                    format!(
                        "WARNING: {name} sent with class {} ({other}) by {who}: not supported by IPC; ignored",
                        log::class_name(other)
                    ),
                );
            }
        }
    }

    /// Central's own broadcast (`centralBroadcast`): notifications and
    /// `V_watch_*` updates.
    fn central_broadcast(&mut self, name: &str, write: impl FnOnce(&mut Writer)) {
        let mut w = Writer::new();
        write(&mut w);
        self.central_broadcast_bytes(name, w.into_vec());
    }

    fn central_broadcast_bytes(&mut self, name: &str, bytes: Vec<u8>) {
        let Some(m) = self.msgs.get(name) else {
            return;
        };
        let hnds = m.handlers.clone();
        if hnds.is_empty() {
            return;
        }
        // Watchers of a variable now know its current value.
        if let Some(var) = name.strip_prefix("V_watch_") {
            for (conn, _) in &hnds {
                self.note_var_read(*conn, var);
            }
        }
        let data = Body::from(bytes);
        for hnd in hnds {
            self.central_deliver(name, data.clone(), hnd);
        }
    }

    /// One delivery of central's own broadcast `name` to handler `hnd`.
    fn central_deliver(&mut self, name: &str, data: Body, hnd: (ConnId, String)) {
        let did = self.alloc_dispatch(Dispatch {
            msg: name.to_string(),
            class: MsgClass::Broadcast as u16,
            class_id: ClassId::native(MsgClass::Broadcast),
            org: Org::Central,
            org_ref: NO_REF,
            parent_ref: NO_REF,
            data,
            hnd: Some(hnd),
            status: Status::NoHandler,
        });
        self.deliver_or_pend(did, self.clock);
    }

    fn deliver_or_pend(&mut self, did: i32, now: SystemTime) {
        let Some(d) = self.dispatches.get(&did) else {
            return;
        };
        let Some((conn, _)) = d.hnd.clone() else {
            return;
        };
        let Some(m) = self.modules.get(&conn) else {
            self.free_dispatch_id(did);
            return;
        };
        if m.takes_delivery_now() {
            self.attend(did, false, now);
        } else {
            self.pend(did, now);
        }
    }

    fn attend(&mut self, did: i32, from_pending: bool, now: SystemTime) {
        self.attend_as(did, from_pending, now, Carry::Frame)
    }

    /// A delivery takes one of its module's capacity slots: it is written
    /// (as `carry` says), counted and logged.
    fn attend_as(&mut self, did: i32, from_pending: bool, now: SystemTime, carry: Carry<'_>) {
        let Some(d) = self.dispatches.get_mut(&did) else {
            return;
        };
        let Some((conn, hnd_name)) = d.hnd.clone() else {
            return;
        };
        unqueue(&mut self.stats, d);
        d.status = Status::Attending;
        let (msg, class, class_id, org, parent_ref, data) = (
            d.msg.clone(),
            d.class,
            d.class_id,
            d.org,
            d.parent_ref,
            d.data.clone(),
        );
        let Some(m) = self.modules.get_mut(&conn) else {
            return;
        };
        m.attending += 1;
        if awaits_answer(class) {
            m.answering += 1;
        }
        if !m.handlers.contains_key(&hnd_name) {
            return;
        }
        let dest = m.name.clone().unwrap_or_default();
        match carry {
            Carry::Frame => self.write_delivery(did, None),
            Carry::Relayed(first, total) => self.write_delivery(did, Some((first, total))),
            Carry::Ahead => {}
        }
        if self.logs(Kind::Message, &msg) {
            let o = self.opts();
            let line = if from_pending {
                format!(
                    "{:<9} {:>15}{}: Resource {} --> {:<15} (Sent){}",
                    log::class_name(class),
                    msg,
                    log::ref_id(&o, did),
                    dest,
                    dest,
                    log::time(&o, now)
                )
            } else {
                let to = format!("{dest:<15} (Sent)");
                let org_name = self.module_name(org);
                self.dispatch_line(class, &msg, Some(did), &org_name, parent_ref, &to, now)
            };
            self.log_line(Kind::Message, line);
            self.log_data(&msg, class_id, &data, None);
        }
    }

    /// Writes delivery `did` to its handler's module. `relayed`: the body's
    /// first bytes and its whole length, for a frame forwarded while it
    /// arrives (the rest follows by [`Self::relay_bytes`]).
    fn write_delivery(&mut self, did: i32, relayed: Option<(&[u8], usize)>) {
        let Some(d) = self.dispatches.get(&did) else {
            return;
        };
        let Some((conn, hnd_name)) = d.hnd.as_ref() else {
            return;
        };
        let Some(m) = self.modules.get(conn) else {
            return;
        };
        let Some(hnd) = m.handlers.get(hnd_name) else {
            return;
        };
        let conn = *conn;
        let mut cd = Writer::new();
        if !hnd.knows_msg {
            cd.write_str(&d.msg);
        }
        let header = Header {
            class_total: 0,
            msg_total: 0,
            parent_ref: d.parent_ref,
            intent: hnd.id,
            class_id: ClassId(
                (d.class_id.0 & 0x0fff_0000)
                    | (ClassId::native(MsgClass::Unknown).0 & 0xf000_0000)
                    | d.class as u32,
            ),
            dispatch_ref: NO_REF,
            msg_ref: did,
        };
        let resume = m.paused;
        match relayed {
            None => {
                let data = d.data.clone();
                self.transmit_frame(conn, header, cd.as_bytes(), &data);
            }
            Some((first, total)) => {
                let f = Self::head(header, cd.as_bytes(), first, total);
                self.transmit_relayed(conn, f);
            }
        }
        if resume {
            // Its acknowledgements must be read.
            self.resume_read(conn);
        }
    }

    /// Central reads `conn` again before the queues have drained: what it
    /// sends is now waited for.
    fn resume_read(&mut self, conn: ConnId) {
        if let Some(m) = self.modules.get_mut(&conn) {
            if m.paused {
                m.paused = false;
                self.memory_paused.remove(&conn);
                self.answer_paused.remove(&conn);
                self.outputs.push_back(Output::ResumeRead { conn });
            }
        }
    }

    /// `resourcePending`: queue limits (dropping the oldest, with C's
    /// fairness shuffle) and priority order.
    fn pend(&mut self, did: i32, now: SystemTime) {
        let Some(d) = self.dispatches.get(&did) else {
            return;
        };
        let Some((conn, hnd_name)) = d.hnd.clone() else {
            return;
        };
        let msg = d.msg.clone();
        let queued = cost(d);
        let Some(m) = self.modules.get(&conn) else {
            return;
        };
        let hnd_msg = m
            .handlers
            .get(&hnd_name)
            .map_or(msg.clone(), |h| h.msg.clone());
        let limit = m
            .msg_limits
            .iter()
            .find(|(n, _)| *n == hnd_msg)
            .map(|x| x.1);
        // Only a queue with a limit needs scanning (keeps pending O(1)).
        let drop_oldest = match limit {
            Some(l) => {
                let same: Vec<usize> = m
                    .pending
                    .iter()
                    .enumerate()
                    .filter(|(_, id)| self.dispatches.get(id).is_some_and(|x| x.msg == hnd_msg))
                    .map(|(i, _)| i)
                    .collect();
                (l as i64 <= same.len() as i64).then_some(same)
            }
            None => None,
        };
        let drop_oldest = drop_oldest.or_else(|| match m.pending_limit {
            Some(l) if l as i64 <= m.pending.len() as i64 => Some((0..m.pending.len()).collect()),
            _ => None,
        });
        let priority = self.msgs.get(&msg).map_or(DEFAULT_PRIORITY, |x| x.priority);
        let d = self.dispatches.get_mut(&did).unwrap();
        d.status = Status::Pending;
        self.stats.queued_bytes += queued;
        self.stats.peak_queued_bytes = self.stats.peak_queued_bytes.max(self.stats.queued_bytes);
        let org = d.org;
        let class = d.class;
        let parent = d.parent_ref;
        let m = self.modules.get_mut(&conn).unwrap();
        let dest = m.name.clone().unwrap_or_default();
        if let Some(slots) = drop_oldest {
            if slots.is_empty() {
                // A limit of 0: nothing may wait.
                let _ = m;
                self.drop_pending(did, &msg);
                return;
            }
            // Shift every same-message entry up one slot; the new one takes the last.
            let oldest = m.pending[slots[0]];
            for w in slots.windows(2) {
                m.pending[w[0]] = m.pending[w[1]];
            }
            m.pending[*slots.last().unwrap()] = did;
            self.drop_pending(oldest, &msg);
        } else if priority != DEFAULT_PRIORITY && !m.pending.is_empty() {
            let pos = m
                .pending
                .iter()
                .position(|id| {
                    let p = self
                        .dispatches
                        .get(id)
                        .and_then(|x| self.msgs.get(&x.msg))
                        .map_or(DEFAULT_PRIORITY, |x| x.priority);
                    priority > p
                })
                .unwrap_or(m.pending.len());
            m.pending.insert(pos, did);
        } else {
            m.pending.push_back(did);
        }
        if self.logs(Kind::Message, &msg) {
            let to = format!("Resource {dest:<6} (Pending)");
            let org_name = self.module_name(org);
            let line = self.dispatch_line(class, &msg, Some(did), &org_name, parent, &to, now);
            self.log_line(Kind::Message, line);
        }
        // The queue waits for the module's Success (or its waitMsg): read it.
        self.resume_read(conn);
        self.unblock_askers(conn);
        self.send_ahead(conn);
    }

    /// A message was queued for `conn`. If a handler of `conn` may be
    /// waiting for an answer, the queue may wait on a module held back
    /// while it answers a query: read those again (see [`Self::check_memory`]).
    fn unblock_askers(&mut self, conn: ConnId) {
        if self.answer_paused.is_empty() || self.modules.get(&conn).is_none_or(|m| m.asking == 0) {
            return;
        }
        let paused: Vec<ConnId> = self.answer_paused.drain().collect();
        for c in paused {
            self.resume_read(c);
        }
    }

    fn drop_pending(&mut self, did: i32, msg: &str) {
        if let Some(d) = self.dispatches.get(&did) {
            if let Some((conn, _)) = d.hnd {
                if let Some(m) = self.modules.get_mut(&conn) {
                    m.pending.retain(|x| *x != did);
                }
            }
        }
        self.free_dispatch_id(did);
        self.stats.dropped += 1;
        if self.logs(Kind::Status, msg) {
            self.log_line(
                Kind::Status,
                format!("PENDING LIMIT: Deleted message {msg} {{{did}}}"),
            );
        }
    }

    fn process_pending(&mut self, conn: ConnId, now: SystemTime) {
        loop {
            let Some(m) = self.modules.get_mut(&conn) else {
                return;
            };
            if !m.ready || m.attending >= m.capacity {
                break;
            }
            if let Some(did) = m.ahead.pop_front() {
                // Already in the module's socket: it only takes its slot.
                self.attend_as(did, true, now, Carry::Ahead);
            } else if let Some(did) = m.pending.pop_front() {
                self.attend(did, true, now);
            } else {
                break;
            }
        }
        self.send_ahead(conn);
        self.check_memory_resume();
    }

    /// Whether broadcasts may be sent ahead to `m` ([`Config::send_ahead`]):
    /// only where no priority can reorder what waits for it (queue limits
    /// are checked per message in [`Self::send_ahead`]), so that sending
    /// early changes nothing but the time.
    fn may_send_ahead(&self, m: &Module) -> bool {
        let depth = m
            .name
            .as_ref()
            .and_then(|n| self.config.send_ahead.get(n))
            .copied()
            .unwrap_or(0);
        m.ahead.len() < depth
            && m.ready
            && !m.closed
            && m.attending >= m.capacity
            && m.pending_limit.is_none()
            && m.handlers.values().all(|h| {
                self.msgs
                    .get(&h.msg)
                    .is_none_or(|x| x.priority == DEFAULT_PRIORITY)
            })
    }

    /// Writes the oldest broadcasts pending for `conn` ahead of their turn,
    /// up to its [`Config::send_ahead`] depth; they stay pending in the
    /// bookkeeping and the log until a capacity slot frees.
    fn send_ahead(&mut self, conn: ConnId) {
        loop {
            let Some(m) = self.modules.get(&conn) else {
                return;
            };
            if !self.may_send_ahead(m) {
                return;
            }
            let Some(&did) = m.pending.front() else {
                return;
            };
            let Some(d) = self.dispatches.get_mut(&did) else {
                return;
            };
            // Queries and informs wait for a slot: only a broadcast's
            // handler acknowledges it by a Success alone. A message with a
            // queue limit waits too: the limit may drop it. So do central's
            // own broadcasts (notifications, `V_watch_…`): they change what
            // the module knows, and come when they would in C.
            let limited = d.hnd.as_ref().is_some_and(|(_, hn)| {
                let name = m.handlers.get(hn).map_or(&d.msg, |h| &h.msg);
                m.msg_limits.iter().any(|(n, _)| n == name)
            });
            let from_module = matches!(d.org, Org::Module(_));
            // Nor before the module has looked the handler up (msgInfo on
            // its first delivery): the C library handles queued messages
            // while it waits for that reply, and one that comes without the
            // message name, for a handler not resolved yet, fails its
            // sanity check and is lost.
            let resolved = d
                .hnd
                .as_ref()
                .and_then(|(_, hn)| m.handlers.get(hn))
                .is_some_and(|h| h.knows_msg);
            if d.class != MsgClass::Broadcast as u16 || limited || !from_module || !resolved {
                return;
            }
            d.status = Status::Ahead;
            self.stats.queued_bytes = self.stats.queued_bytes.saturating_sub(cost(d));
            let m = self.modules.get_mut(&conn).unwrap();
            m.pending.pop_front();
            m.ahead.push_back(did);
            self.write_delivery(did, None);
        }
    }

    fn on_success(&mut self, conn: ConnId, did: i32, now: SystemTime) -> Result<(), Bad> {
        // A module that finishes a message sent ahead before the ones it
        // was given earlier (it handles them concurrently): the message
        // takes its slot now, so that it is logged as sent before done.
        let ahead = self.modules.get(&conn).and_then(|m| {
            let d = self.dispatches.get(&did)?;
            let here = d.hnd.as_ref().is_some_and(|(c, _)| *c == conn);
            (d.status == Status::Ahead && here).then(|| m.ahead.iter().position(|x| *x == did))?
        });
        if let Some(i) = ahead {
            self.modules.get_mut(&conn).unwrap().ahead.remove(i);
            self.attend_as(did, true, now, Carry::Ahead);
        }
        let ok = self
            .dispatches
            .get(&did)
            .is_some_and(|d| d.attending_at(conn));
        if !ok {
            let who = self.describe(conn);
            self.complain(
                conn,
                format!(
                    "WARNING: Success for unknown or foreign dispatch {did} from {who} ignored"
                ),
            );
            return Ok(());
        }
        let d = self.free_dispatch_id(did).unwrap();
        if self.logs(Kind::Message, &d.msg) {
            let word = if d.class == 6 || d.class == 15 {
                "Done    "
            } else {
                "Success "
            };
            let o = self.opts();
            let line = format!(
                "  {word}{:>15}{}:{}",
                d.msg,
                log::ref_id(&o, did),
                log::time(&o, now)
            );
            self.log_line(Kind::Message, line);
        }
        self.handled(conn, d.class);
        self.process_pending(conn, now);
        Ok(())
    }

    fn on_reply(
        &mut self,
        conn: ConnId,
        h: Header,
        class_data: &[u8],
        data: Body,
        now: SystemTime,
    ) -> Result<(), Bad> {
        let did = h.dispatch_ref;
        let ok = self
            .dispatches
            .get(&did)
            .is_some_and(|d| d.attending_at(conn));
        if !ok {
            let who = self.describe(conn);
            self.complain(
                conn,
                format!("WARNING: Reply for unknown or foreign dispatch {did} from {who} ignored"),
            );
            return Ok(());
        }
        let reply_name = if class_data.is_empty() {
            None
        } else {
            let order = h.class_id.class_order().unwrap_or(ByteOrder::NATIVE);
            read_opt_str(&mut Reader::new(class_data, order))?
        };
        let d = &self.dispatches[&did];
        if let Org::Module(org) = d.org {
            if self.modules.get(&org).is_some_and(|m| !m.closed) {
                let header = Self::reply_header(&h, did, d.org_ref);
                self.transmit_frame(org, header, class_data, &data);
            }
        }
        self.reply_done(conn, h, reply_name, Some(&data), now);
        Ok(())
    }

    /// The header of a reply forwarded to the module that asked.
    fn reply_header(h: &Header, did: i32, org_ref: i32) -> Header {
        Header {
            class_total: 0,
            msg_total: 0,
            parent_ref: h.parent_ref,
            intent: QUERY_REPLY_INTENT,
            class_id: h.class_id,
            dispatch_ref: did,
            msg_ref: org_ref,
        }
    }

    /// What follows a reply once it has gone to the asking module: the
    /// query is complete, its log lines, and the responder takes its next.
    /// `data`: the reply's body, for the data log (`None` when it was
    /// forwarded while it arrived, which data logging rules out).
    fn reply_done(
        &mut self,
        conn: ConnId,
        h: Header,
        reply_name: Option<String>,
        data: Option<&[u8]>,
        now: SystemTime,
    ) {
        let did = h.dispatch_ref;
        let Some(d) = self.free_dispatch_id(did) else {
            return;
        };
        let responder = self.module_name(Org::Module(conn));
        let org_alive = match d.org {
            Org::Module(c) => self.modules.get(&c).is_some_and(|m| !m.closed),
            Org::Central => false,
        };
        if self.logs(Kind::Message, &d.msg) {
            let o = self.opts();
            let line = format!(
                "  Reply  {:>15}{}: {:>10} --> {:<15}{}{}",
                d.msg,
                log::ref_id(&o, did),
                responder,
                self.module_name(d.org),
                log::parent_id(&o, d.parent_ref),
                log::time(&o, now)
            );
            self.log_line(Kind::Message, line);
            if !org_alive {
                let dead = self.module_name(d.org);
                self.log_line(
                    Kind::Message,
                    format!("WARNING: Reply Ignored for dead module: {dead}"),
                );
            }
            if let Some(data) = data {
                let rn = reply_name.clone().unwrap_or(d.msg.clone());
                self.log_data(&d.msg, h.class_id, data, Some(&rn));
            }
        }
        self.handled(conn, d.class);
        self.process_pending(conn, now);
    }

    /// `conn` finished handling a delivery of class `class`.
    fn handled(&mut self, conn: ConnId, class: u16) {
        if let Some(m) = self.modules.get_mut(&conn) {
            m.attending = m.attending.saturating_sub(1);
            if awaits_answer(class) {
                m.answering = m.answering.saturating_sub(1);
            }
        }
    }

    // ----- variables ---------------------------------------------------------

    fn set_var_from(&mut self, var: &str, data: &[u8], order: ByteOrder) -> Result<(), Bad> {
        let Some(v) = self.vars.get(var) else {
            return Ok(());
        };
        // Validate, then store in central's own byte order.
        let value = crate::ipc::decode_value(&v.format, &mut Reader::new(data, order))?;
        let mut w = Writer::new();
        crate::ipc::encode_value(&v.format, &value, &mut w)?;
        self.set_var(var, w.into_vec());
        Ok(())
    }

    /// Central setting a variable of its own accord (the broadcast list, a
    /// direct handler list): the C central sends itself `V_set_<var>` and
    /// logs it like a module's, around the broadcasts it causes.
    fn set_var_by_central(&mut self, var: &str, bytes: Vec<u8>) {
        let name = format!("V_set_{var}");
        self.central_inform(&name, bytes, |c, bytes| c.set_var(var, bytes));
    }

    /// An inform central sends itself (`V_set_…`, `x_ipc_registerGlobalVar`):
    /// logged as C logs it, `Inform` (with `data`) before what `act` does
    /// with `data` and `Done` after, under a dispatch id of its own.
    fn central_inform(&mut self, name: &str, data: Vec<u8>, act: impl FnOnce(&mut Self, Vec<u8>)) {
        let rid = self.take_ref();
        let logged = self.logs(Kind::Message, name);
        if logged {
            let to = format!("{SERVER_NAME:<15} (Sent)");
            let class = MsgClass::Inform as u16;
            let line =
                self.dispatch_line(class, name, Some(rid), SERVER_NAME, NO_REF, &to, self.clock);
            self.log_line(Kind::Message, line);
            self.log_data_as(name, ClassId::native(MsgClass::Inform), &data, None, true);
        }
        act(self, data);
        if logged {
            self.log_done(name, rid, self.clock);
        }
        self.give_ref(rid);
    }

    fn set_var(&mut self, var: &str, bytes: Vec<u8>) {
        if let Some(v) = self.vars.get_mut(var) {
            v.value = bytes.clone();
            v.version += 1;
        }
        self.central_broadcast_bytes(&format!("V_watch_{var}"), bytes);
    }

    fn var_version(&self, var: &str) -> Option<u64> {
        self.vars.get(var).map(|v| v.version)
    }

    /// `conn` now has the current value of `var` (read or sent to it).
    fn note_var_read(&mut self, conn: ConnId, var: &str) {
        let version = self.vars.get(var).map_or(0, |v| v.version);
        if let Some(m) = self.modules.get_mut(&conn) {
            m.vars_read.insert(var.to_string(), version);
        }
    }

    /// A module subscribed `V_watch_<var>` (handler `hnd`) after reading
    /// `<var>`: if others changed the value in between, the change was
    /// broadcast before the module watched, so it gets the current value
    /// now. A C module starts exactly so (`V_get_X_IPC_BROADCAST_MSG_VAR`,
    /// then the watch), and the C central leaves the gap open: a message
    /// subscribed by another module in it stays unknown to the new module,
    /// whose C library then never publishes it.
    fn catch_up_watch(&mut self, conn: ConnId, watch: &str, hnd: &str) {
        let Some(var) = watch.strip_prefix("V_watch_") else {
            return;
        };
        let Some(v) = self.vars.get(var) else {
            return;
        };
        let read = self.modules.get(&conn).and_then(|m| m.vars_read.get(var));
        if read.is_none_or(|r| *r == v.version) {
            return;
        }
        let data = Body::from(&v.value[..]);
        self.central_deliver(watch, data, (conn, hnd.to_string()));
    }

    fn str_list_value(&self, items: &[String], size: usize) -> Vec<u8> {
        let mut w = Writer::new();
        internal::encode_str_list(items, size, &mut w);
        w.into_vec()
    }

    /// `recordBroadcast`: keep `X_IPC_BROADCAST_MSG_VAR` = names of
    /// broadcast messages that have handlers, and tell everyone.
    fn record_broadcast(&mut self, name: &str, active: bool) {
        let present = self.broadcast_msgs.iter().any(|n| n == name);
        if active == present {
            return;
        }
        if active {
            self.broadcast_msgs.push(name.to_string());
            self.broadcast_size =
                internal::str_list_size(self.broadcast_msgs.len(), self.broadcast_size);
        } else {
            self.broadcast_msgs.retain(|n| n != name);
        }
        let v = self.str_list_value(&self.broadcast_msgs.clone(), self.broadcast_size);
        self.set_var_by_central(internal::BROADCAST_MSG_VAR, v);
    }

    fn clean_broadcast(&mut self) {
        let names = self.broadcast_msgs.clone();
        for n in names {
            if self.msgs.get(&n).is_some_and(|m| m.handlers.is_empty()) {
                self.record_broadcast(&n, false);
            }
        }
    }

    fn update_log_vars(&mut self) {
        for (var, o, file) in [
            (internal::TERMINAL_LOG_VAR, self.config.terminal_log, false),
            (internal::FILE_LOG_VAR, self.config.file_log, true),
        ] {
            let mut w = Writer::new();
            let on = o.any();
            w.write_ptr_flag(on);
            if on {
                w.write_i32(0);
            }
            // The fields of the C central's LOG_TYPE after its FILE pointer:
            // messages, status, time, data, summary, refId, parentId,
            // quiet, flush, ignore, ignoreNow.
            for b in [
                o.messages,
                o.status,
                o.time,
                o.data,
                o.handle_summary,
                o.refs,
                o.parent_refs,
                !file && self.config.quiet,
                !(file && o.no_flush),
                // A log that is off keeps C's default (ignore on).
                o.ignore_internal || !on,
                false,
            ] {
                w.write_i32(b as i32);
            }
            if let Some(v) = self.vars.get_mut(var) {
                v.value = w.into_vec();
            }
        }
    }

    // ----- direct mode ---------------------------------------------------------

    fn direct_handlers(&self, msg: &str) -> Vec<DirectEntry> {
        let Some(m) = self.msgs.get(msg) else {
            return Vec::new();
        };
        if m.handlers.len() > MAX_DIRECT_HANDLERS {
            return Vec::new();
        }
        let list: Vec<&(ConnId, String)> = if m.class == MsgClass::Broadcast {
            m.handlers.iter().rev().collect()
        } else {
            m.handlers.last().into_iter().collect()
        };
        list.into_iter()
            .filter_map(|(c, hn)| {
                let md = self.modules.get(c)?;
                Some(DirectEntry {
                    intent: md.handlers.get(hn)?.id,
                    port: md.port,
                    host: md.host.clone(),
                    module: md.name.clone().unwrap_or_default(),
                })
            })
            .collect()
    }

    /// `updateDirectHandlers`: `V_watch_<msg>` = its handler list.
    fn update_direct_handlers(&mut self, msg: &str) {
        self.register_var(msg);
        let list = self.direct_handlers(msg);
        let mut w = Writer::new();
        write_direct_list(&mut w, &list);
        self.set_var_by_central(msg, w.into_vec());
    }

    // ----- back-pressure ---------------------------------------------------------

    fn check_memory(&mut self, conn: ConnId) {
        if self.stats.queued_bytes <= self.config.max_queued_bytes {
            return;
        }
        let Some(m) = self.modules.get(&conn) else {
            return;
        };
        if m.paused || m.closed {
            return;
        }
        // Reading stops only where nothing in central waits for what the
        // module has not sent yet: none of its own queue waits for a
        // capacity slot its Success or Reply would free, and no queue can
        // be stuck behind its answer to a query. A module that publishes
        // while it handles a broadcast (a pipeline) is stopped, and so is
        // one publishing while it answers a query, as long as no module
        // that waits for an answer (maybe in a handler, holding its
        // capacity) has anything queued; when one does, it is read again
        // (`unblock_askers`). Its asker then waits for the reply until the
        // queues drain, which they can: whatever is queued is for modules
        // whose handlers wait for nobody.
        let own_queue_empty = m.pending.is_empty() && m.ahead.is_empty();
        let answering = m.attending > 0 && m.answering > 0;
        let may_pause = m.attending == 0
            || (own_queue_empty
                && (!answering
                    || self
                        .modules
                        .values()
                        .all(|x| x.asking == 0 || (x.pending.is_empty() && x.ahead.is_empty()))));
        if may_pause {
            let m = self.modules.get_mut(&conn).unwrap();
            m.paused = true;
            self.memory_paused.insert(conn);
            if answering {
                self.answer_paused.insert(conn);
            }
            self.outputs.push_back(Output::PauseRead { conn });
        }
    }

    fn check_memory_resume(&mut self) {
        if self.memory_paused.is_empty()
            || self.stats.queued_bytes > self.config.max_queued_bytes / 2
        {
            return;
        }
        let paused: Vec<ConnId> = self.memory_paused.drain().collect();
        self.answer_paused.clear();
        for conn in paused {
            if let Some(m) = self.modules.get_mut(&conn) {
                if m.paused {
                    m.paused = false;
                    self.outputs.push_back(Output::ResumeRead { conn });
                }
            }
        }
    }

    /// A query or inform of `msg` from `conn` (`added`) joined those waiting for a
    /// first handler. Past [`Config::max_queued_bytes`] of them, the oldest
    /// of `msg` are dropped (the new one last), as a queue limit drops the
    /// oldest: their askers may have given up long ago, and a handler that
    /// comes gets the newest. Pausing the asker instead would stop a
    /// module's whole connection for one message nobody serves, and would
    /// hide its hang-up until a handler comes.
    fn bound_waiting(&mut self, conn: ConnId, msg: &str, added: i32) {
        self.stats.waiting_bytes += cost(&self.dispatches[&added]);
        while self.stats.waiting_bytes > self.config.max_queued_bytes {
            let Some(did) = self.msgs.get_mut(msg).and_then(|m| m.waiting.pop_front()) else {
                break;
            };
            let Some(d) = self.free_dispatch_id(did) else {
                continue;
            };
            self.stats.waiting_bytes = self.stats.waiting_bytes.saturating_sub(cost(&d));
            self.stats.dropped_waiting += 1;
            let asker = self.module_name(d.org);
            let limit = self.config.max_queued_bytes;
            self.complain(
                conn,
                format!(
                    "WARNING: {} {msg} {{{did}}} from {asker} dropped: more than {limit} bytes of \
                     queries wait for a handler",
                    log::class_name(d.class)
                ),
            );
        }
    }

    // ----- console -------------------------------------------------------------

    /// A console command line (`help`, `display`, `status`, `memory`,
    /// `close <module>`, `unlock <resource>`, or an option such as `-lmsd`).
    pub fn command(&mut self, line: &str, now: SystemTime) {
        self.clock = now;
        let mut words = line.split_whitespace();
        let Some(cmd) = words.next() else {
            return;
        };
        let arg = words.next();
        let say = |c: &mut Central, s: String| {
            c.outputs.push_back(Output::Log {
                target: LogTarget {
                    terminal: true,
                    file: false,
                },
                line: s,
            })
        };
        match (cmd, arg) {
            ("help", _) | ("?", _) => {
                for l in [
                    "The following are central commands:",
                    "  help: print this message",
                    "  display: display the active and pending messages",
                    "  status: display the known modules and their status",
                    "  memory: display total memory usage",
                    "  close <module>: close a connection to a module",
                    "  unlock <resource>: unlock a locked resource",
                    "The following command line options can also be used as commands:",
                    "  -v: display server version information",
                    "  -l<options>: logging onto terminal (m s t d i h r p x)",
                    "  -L<options>: logging into file (as -l, plus F n)",
                    "  -I<msgName>: ignore logging this message",
                    "  -c: use direct connections for messages defined from now on",
                    "  -r: resend non-completed messages when modules crash and reconnect",
                ] {
                    say(self, l.to_string());
                }
            }
            ("display", _) => {
                let mut ids: Vec<i32> = self.dispatches.keys().copied().collect();
                ids.sort_unstable();
                say(self, format!("{} message(s) active or pending:", ids.len()));
                for id in ids {
                    let d = &self.dispatches[&id];
                    let dest = d
                        .hnd
                        .as_ref()
                        .map(|(c, _)| self.module_name(Org::Module(*c)))
                        .unwrap_or_else(|| "(no handler)".into());
                    let st = match d.status {
                        Status::Attending => "Active",
                        Status::Pending => "Pending",
                        Status::Ahead => "Pending (sent ahead)",
                        Status::NoHandler => "Waiting for a handler",
                    };
                    let line = format!(
                        "  {{{id}}} {:<9} {:>15}: {:>10} --> {:<15} {st}",
                        log::class_name(d.class),
                        d.msg,
                        self.module_name(d.org),
                        dest
                    );
                    say(self, line);
                }
            }
            ("status", _) => {
                let lines: Vec<String> = self
                    .modules
                    .iter()
                    .map(|(c, m)| {
                        format!(
                            "  Module {} on {} (sd {}): capacity {}, active {}, pending {}{}",
                            m.name.as_deref().unwrap_or("<connecting>"),
                            if m.host.is_empty() { "?" } else { &m.host },
                            c.0,
                            m.capacity,
                            m.attending,
                            m.pending.len() + m.ahead.len(),
                            if m.port >= 0 {
                                format!(", direct port {}", m.port)
                            } else {
                                String::new()
                            }
                        )
                    })
                    .collect();
                say(self, format!("{} module(s) connected:", lines.len()));
                for l in lines {
                    say(self, l);
                }
            }
            ("memory", _) => {
                let s = self.stats();
                say(self, "Cumulative Memory Usage:".into());
                say(
                    self,
                    format!(
                        "  Messages queued: {} dispatch(es), {} byte(s) pending (peak {})",
                        s.dispatches, s.queued_bytes, s.peak_queued_bytes
                    ),
                );
                say(
                    self,
                    format!(
                        "  Waiting for a handler: {} message(s), {} byte(s), {} dropped",
                        s.waiting_for_handler, s.waiting_bytes, s.dropped_waiting
                    ),
                );
                say(
                    self,
                    format!(
                        "  Modules: {}, messages defined: {}, frames received: {}, dropped by limits: {}",
                        s.modules,
                        self.msgs.len(),
                        s.frames_in,
                        s.dropped
                    ),
                );
            }
            ("close", Some(name)) => {
                let conn = self
                    .modules
                    .iter()
                    .find(|(_, m)| m.name.as_deref() == Some(name))
                    .map(|(c, _)| *c);
                match conn {
                    Some(c) => {
                        self.log_line(Kind::Always, format!("close Module: Closing {name}"));
                        self.outputs.push_back(Output::Close {
                            conn: c,
                            reason: "closed from the console".into(),
                        });
                        self.close_module(c, false, now);
                    }
                    None => say(self, format!("Can not find {name} to close.")),
                }
            }
            ("close", None) => say(self, "usage: close <module>".into()),
            ("unlock", Some(name)) => say(
                self,
                format!("Resource {name} is not locked (IPC modules cannot lock resources)"),
            ),
            ("unlock", None) => say(self, "usage: unlock <resource>".into()),
            ("quit", _) => say(self, "use Ctrl-C (SIGINT) to stop central".into()),
            (opt, _) if opt.starts_with('-') => {
                // A line may hold several options (`-lm -Lx`), as in C.
                for word in line.split_whitespace() {
                    if let Err(e) = self.apply_option(word) {
                        say(self, e);
                    }
                }
            }
            (other, _) => say(self, format!("Unknown command '{other}' (type help)")),
        }
    }

    /// An option given as a console command.
    fn apply_option(&mut self, opt: &str) -> Result<(), String> {
        let (flag, rest) = opt.split_at(opt.len().min(2));
        match flag {
            "-v" => {
                let v = format!(
                    "Task Control Server {}.{}.1 (Courier {})",
                    VERSION.0,
                    VERSION.1,
                    env!("CARGO_PKG_VERSION")
                );
                self.outputs.push_back(Output::Log {
                    target: LogTarget {
                        terminal: true,
                        file: false,
                    },
                    line: v,
                });
            }
            "-l" => {
                self.config.terminal_log =
                    LogOptions::parse(rest, false).map_err(|e| e.to_string())?;
                self.update_log_vars();
            }
            "-L" => {
                self.config.file_log = LogOptions::parse(rest, true).map_err(|e| e.to_string())?;
                self.update_log_vars();
            }
            "-I" if !rest.is_empty() => {
                self.config.ignore.push(rest.to_string());
                self.ignore.insert(rest.to_string());
            }
            "-c" => self.config.direct = true,
            "-r" => self.config.resend_on_reconnect = true,
            "-s" | "-u" | "-p" | "-f" => {
                return Err(format!(
                    "option {flag} can only be given on the command line"
                ))
            }
            _ => return Err(format!("Unknown option '{opt}' (type help)")),
        }
        Ok(())
    }

    /// The next thing the shell must do, if any.
    pub fn poll_output(&mut self) -> Option<Output> {
        self.outputs.pop_front()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn message_ids_are_never_0_or_1() {
        let mut c = Central::new(Config::default());
        let ids: Vec<i32> = (0..1000).map(|_| c.alloc_msg_id()).collect();
        assert!(ids.iter().all(|i| *i >= 2));
        let unique: HashSet<i32> = ids.iter().copied().collect();
        assert_eq!(unique.len(), ids.len());
    }
}

/// One `directMsgHandler` entry.
#[derive(Debug, Clone)]
struct DirectEntry {
    intent: i32,
    port: i32,
    host: String,
    module: String,
}

fn write_direct_entry(w: &mut Writer, e: &DirectEntry) {
    w.write_i32(e.intent);
    w.write_i32(0);
    w.write_i32(0);
    w.write_i32(e.port);
    w.write_str(&e.host);
    w.write_str(&e.module);
}

fn write_direct_list(w: &mut Writer, list: &[DirectEntry]) {
    w.write_i32(list.len() as i32);
    w.write_len(list.len());
    for e in list {
        write_direct_entry(w, e);
    }
}

/// `DIRECT_MSG(msg)`: classes that may go module to module.
/// A delivery of this class has a sender waiting for its answer (a query),
/// as opposed to a broadcast or inform, which nobody waits for.
fn awaits_answer(class: u16) -> bool {
    class != MsgClass::Broadcast as u16 && class != MsgClass::Inform as u16
}

fn direct_class(c: MsgClass) -> bool {
    matches!(c, MsgClass::Broadcast | MsgClass::Inform | MsgClass::Query)
}

/// A string that may be NULL (`n = 0`): `None` for NULL/empty.
fn read_opt_str(r: &mut Reader<'_>) -> Result<Option<String>, Bad> {
    let s = r.read_str()?;
    Ok(if s.is_empty() {
        None
    } else {
        Some(s.to_string())
    })
}

/// Array elements decoded for a data log line: more than its five lines
/// of at most 80 columns can show (each element takes a character).
const LOGGED_ELEMENTS: usize = 4096;

/// Decodes a message body for the data log: the wire body (`{int,
/// <byte:1>}`, `[byte:N]` or the format itself) and then the user format.
fn decode_user(
    msg_format: &Option<Format>,
    res_format: &Option<Format>,
    data: &[u8],
    order: ByteOrder,
    reg: &FormatRegistry,
) -> Result<Option<String>, String> {
    let Some(user) = res_format.as_ref().or(msg_format.as_ref()) else {
        return Ok(None);
    };
    if *user == Format::Empty {
        return Ok(None);
    }
    let inner: &[u8] = match msg_format {
        Some(Format::Struct(f))
            if f.len() == 2 && matches!(f[1], Format::VarArray { .. }) && res_format.is_some() =>
        {
            let mut r = Reader::new(data, order);
            let _len = r.read_i32().map_err(|e| e.to_string())?;
            let n = r.read_count(1).map_err(|e| e.to_string())?;
            r.take(n).map_err(|e| e.to_string())?
        }
        _ => data,
    };
    let resolve = |n: &str| reg.get(n);
    let mut r = Reader::new(inner, order);
    // The log shows five lines: the first elements of a large array do.
    let v = crate::ipc::decode_value_prefix(user, &mut r, &resolve, LOGGED_ELEMENTS)
        .map_err(|e| e.to_string())?;
    Ok(Some(crate::ipc::log_data(user, &v)))
}
