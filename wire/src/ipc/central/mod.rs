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
//!   stdin line  -> the shell's console (`courier::central`), through the console API
//!   loop { match central.poll_output() {
//!       Transmit / TransmitBody / Close / Log / PauseRead / ResumeRead } }
//! ```
//!
//! A console is data and actions here ([`Central::dispatches`],
//! [`Central::modules`], [`Central::close_module_named`],
//! [`Central::reconfigure`], [`Central::print`]); the commands and their
//! text are the shell's (`courier::central`'s console), written against
//! those alone.
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
//! Kept in one list, with the server's and the `central` program's, in
//! the `courier` crate's `courier::central` documentation (source:
//! `sdk/src/central/mod.rs`).

mod body;
mod config;
mod conn;
mod console;
mod direct;
mod internal;
mod introspect;
mod invariants;
mod log;
mod memory;
mod process;
mod queue;
mod registry;
mod relay;
mod resend;
mod routing;
mod small_map;
mod tables;
mod timeouts;
mod vars;

pub use self::body::Body;
pub use self::config::{Config, LogOptions, OptionError, MAX_SEND_AHEAD};
pub use self::console::{DispatchInfo, DispatchState, ModuleInfo};
pub use self::tables::DISPATCH_COST;

use std::collections::{BTreeMap, VecDeque};

// Looked up for every frame: foldhash (seeded per process, so names a
// peer picks cannot be aimed at one bucket) costs a fraction of SipHash.
use foldhash::{HashMap, HashMapExt, HashSet, HashSetExt};
use std::time::SystemTime;

use self::tables::{Dispatch, DispatchId, Module, Msg, MsgId, Var};
use crate::format::{Format, FormatRegistry};

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
    /// message data (at least [`SPLIT_AT`](crate::ipc::frame::SPLIT_AT)
    /// bytes) is shared with central's queues instead of copied into the
    /// frame. In order with [`Output::Transmit`].
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

/// The module name central uses for itself in logs.
const SERVER_NAME: &str = "X_IPC Server";
/// `DEFAULT_PRIORITY` of `ipc_setMsgPriority`.
const DEFAULT_PRIORITY: i32 = 1;
/// IPC version central reports (`{{3, 9}, direct}`).
/// The IPC protocol version central speaks (major, minor): CMU IPC 3.9.
pub const VERSION: (i32, i32) = (3, 9);
/// Most handlers listed in a direct handler list (`MAX_DIRECT_HANDLERS`).
const MAX_DIRECT_HANDLERS: usize = 100;

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
    /// Times a connection waited for room for a large frame
    /// ([`Config::max_frames_in_progress`]).
    pub frames_waited: u64,
    /// Deliveries kept for `-r`
    /// ([`Config::resend_on_reconnect`]) until a module of the name of
    /// the one that died with them unfinished handles their message again.
    pub kept_for_resend: usize,
    /// What those hold, counted as [`waiting_bytes`](Self::waiting_bytes)
    /// is. Bounded apart by the same [`Config::max_queued_bytes`]: past
    /// it, the oldest are dropped.
    pub kept_bytes: usize,
    /// Kept deliveries dropped because too many were kept.
    pub dropped_kept: u64,
    /// What pending queues hold: message data plus [`DISPATCH_COST`] per
    /// message, so that a flood of empty messages is bounded too.
    pub queued_bytes: usize,
    /// Most `queued_bytes` ever seen.
    pub peak_queued_bytes: usize,
    /// Messages dropped by queue limits (`limitPending`).
    pub dropped: u64,
    /// Frames received from modules.
    pub frames_in: u64,
    /// Message names central knows: its own, those defined by modules, and
    /// those only subscribed so far.
    pub messages: usize,
    /// Bytes the definitions hold
    /// ([`Config::max_definition_bytes`]).
    pub definition_bytes: usize,
}

/// The IPC central server's state.
#[derive(Debug)]
pub struct Central {
    config: Config,
    outputs: VecDeque<Output>,
    /// Boxed: a B-tree node holds eleven entries, most of them empty.
    modules: BTreeMap<ConnId, Box<Module>>,
    msgs: HashMap<String, Msg>,
    by_id: HashMap<MsgId, String>,
    next_ids: Vec<i32>,
    id_block: i32,
    /// Named formats as registered, for `getNamedForm`.
    formats: FormatRegistry,
    vars: BTreeMap<String, Var>,
    broadcast_msgs: Vec<String>,
    broadcast_size: usize,
    dispatches: HashMap<DispatchId, Dispatch>,
    free_dispatch: Vec<DispatchId>,
    next_dispatch: i32,
    ignore: HashSet<String>,
    /// Dispatches kept for `-r`, by module name.
    kept: resend::Kept,
    stats: Stats,
    memory_paused: HashSet<ConnId>,
    /// Connections waiting for room for a large frame
    /// ([`Config::max_frames_in_progress`]).
    frame_waiters: Vec<(ConnId, usize)>,
    /// Bytes ever queued for messages a module sent (not central's own
    /// broadcasts): whether a read added any (see `receive`).
    queued_by_modules: u64,
    /// What definitions hold ([`Config::max_definition_bytes`]).
    definition_bytes: usize,
    /// Of those, modules held back while they answer a query.
    answer_paused: HashSet<ConnId>,
    /// When central last said it holds modules back for memory, and how
    /// many times it did so since without saying (a slow subscriber makes
    /// it hold and release over and over).
    memory_said: crate::throttle::Throttle,
    /// Lines about connections that never named themselves (probes,
    /// hostile peers), bounded central-wide.
    strangers: log::StrangerBudget,
    /// Connections that must name themselves by then, in connect order
    /// (entries of those that did are dropped as they reach the front).
    handshakes: VecDeque<(SystemTime, ConnId)>,
    /// Connections receiving a large or relayed frame, and when the next
    /// of them may have stalled
    /// ([`Config::frame_stall_timeout`](Config::frame_stall_timeout)).
    stall_watch: Vec<ConnId>,
    stall_check: Option<SystemTime>,
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
            kept: resend::Kept::default(),
            stats: Stats::default(),
            memory_paused: HashSet::new(),
            queued_by_modules: 0,
            definition_bytes: 0,
            frame_waiters: Vec::new(),
            answer_paused: HashSet::new(),
            memory_said: crate::throttle::Throttle::new(memory::MEMORY_LINE_EVERY),
            strangers: log::StrangerBudget::default(),
            handshakes: VecDeque::new(),
            stall_watch: Vec::new(),
            stall_check: None,
            handler_seq: 0,
            msg_info_query: internal::fixed(internal::MSG_INFO_QUERY_FORMAT),
            msg_info_reply: internal::fixed(internal::MSG_INFO_REPLY_FORMAT),
            clock: now,
        };
        let _ = c
            .formats
            .define("directMsgHandler", "{int, int, int, int, string, string}");
        c.definition_bytes = c
            .formats
            .iter()
            .map(|(n, f)| tables::named_format_bytes(n, f))
            .sum();
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
            let value = c.vars.get(var).map(|v| v.value.clone()).unwrap_or_default();
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
        s.kept_for_resend = self.kept.len();
        s.messages = self.msgs.len();
        s.definition_bytes = self.definition_bytes;
        s
    }

    /// Central's id for a message name (what `x_ipc_msgInfoMsg` answers,
    /// without the direct-mode sign), if the message is known.
    pub fn message_id(&self, name: &str) -> Option<i32> {
        self.msgs.get(name).and_then(|m| m.id).map(|id| id.0)
    }

    /// The names of the connected modules (those that completed the connect query).
    pub fn module_names(&self) -> Vec<String> {
        self.modules
            .values()
            .filter_map(|m| m.name.clone())
            .collect()
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
        let ids: Vec<i32> = (0..1000).map(|_| c.alloc_msg_id().0).collect();
        assert!(ids.iter().all(|i| *i >= 2));
        let unique: HashSet<i32> = ids.iter().copied().collect();
        assert_eq!(unique.len(), ids.len());
    }

    /// A module's receive buffer grows for a burst and is given back once
    /// the burst is taken in: an idle module keeps little.
    #[test]
    fn receive_buffer_shrinks_back_after_a_burst() {
        use crate::ipc::module::{Connection, ModuleConfig, MsgLength};
        use std::time::Instant;
        let now = SystemTime::now();
        let mut c = Central::new(Config::default());
        let mut m = Connection::new(ModuleConfig::new("burst", "localhost"), Instant::now());
        let conn = ConnId(5);
        c.connect(conn, Peer::Other("test".into()), now);
        // Each side's output to the other until both are quiet.
        let pump = |c: &mut Central, m: &mut Connection, hold: bool| -> Vec<u8> {
            let mut held = Vec::new();
            loop {
                let mut moved = false;
                while let Some(o) = c.poll_output() {
                    match o {
                        Output::Transmit { bytes, .. } => {
                            m.receive(&bytes, Instant::now());
                            moved = true;
                        }
                        Output::TransmitBody { head, body, .. } => {
                            m.receive(&head, Instant::now());
                            m.receive(&body, Instant::now());
                            moved = true;
                        }
                        _ => {}
                    }
                }
                while m.poll_event().is_some() {}
                while let Some(b) = m.poll_transmit() {
                    if hold {
                        held.extend_from_slice(&b);
                    } else {
                        c.receive(conn, &b, now);
                    }
                    moved = true;
                }
                if !moved || hold {
                    return held;
                }
            }
        };
        pump(&mut c, &mut m, false);
        m.define_msg("burst", MsgLength::Variable, None).unwrap();
        // Its first frame (a query central answers) 300 times, in one read.
        let burst = pump(&mut c, &mut m, true).repeat(300);
        assert!(burst.len() > 16 * 1024, "{} bytes", burst.len());
        c.receive(conn, &burst, now);
        let answers = std::iter::from_fn(|| c.poll_output())
            .filter(|o| matches!(o, Output::Transmit { .. }))
            .count();
        assert_eq!(answers, 300);
        assert!(!c.modules[&conn].closed);
        let rx = &c.modules[&conn].rx;
        assert_eq!(rx.capacity(), 0, "nothing kept once taken in");
    }
}
