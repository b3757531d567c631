//! The records central keeps — dispatches (one per delivery of a
//! message), modules, messages, handlers and global variables — and the
//! allocation of message and dispatch ids, as C numbers them.

use std::borrow::Borrow;
use std::collections::{BTreeMap, HashMap, VecDeque};
use std::fmt;
use std::hash::BuildHasher;
use std::hash::Hash;

use super::internal::{Def, Internal};
use super::log;
use super::small_map::SmallMap;
use super::{Bad, Body, Central, ConnId, Peer, Stats, DEFAULT_PRIORITY};
use crate::format::{parse, parse_with, Format};
use crate::ipc::frame::{ClassId, Header, MsgClass};

/// Central's number for one delivery of a message (C's dispatch): the
/// msgRef of the frame that carries it to its handler, and the dispatchRef
/// of the module's Success or Reply. Central also holds one while it
/// handles an internal message or sends itself one (see
/// [`Central::take_ref`]). Numbered from 0, last freed first.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub(super) struct DispatchId(pub(super) i32);

/// Central's id of a message name (what `x_ipc_msgInfoMsg` answers, and
/// the intent of a frame sending the message): from 199 down, never 0 or 1.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub(super) struct MsgId(pub(super) i32);

impl fmt::Display for DispatchId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        self.0.fmt(f)
    }
}

impl fmt::Display for MsgId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        self.0.fmt(f)
    }
}

/// What a key names, for the error of a broken link.
pub(super) trait Key {
    fn describe(&self) -> String;
}

impl Key for DispatchId {
    fn describe(&self) -> String {
        format!("dispatch {{{}}}", self.0)
    }
}

impl Key for ConnId {
    fn describe(&self) -> String {
        format!("module on connection {}", self.0)
    }
}

impl Key for str {
    fn describe(&self) -> String {
        format!("message {self}")
    }
}

impl Key for MsgId {
    fn describe(&self) -> String {
        format!("message id {}", self.0)
    }
}

/// Looks up an entry that another of central's tables names: a module's
/// queue names dispatches, a dispatch its handler's module, a message id
/// or a handler its message. A missing entry is a bug in central, not in
/// the module; on the paths a module's bytes drive it is an error that
/// closes the connection being handled (with a log line), where an index
/// or `unwrap` would take the whole server down.
pub(super) trait Linked<K: ?Sized, V> {
    fn linked(&self, k: &K) -> Result<&V, Bad>;
    fn linked_mut(&mut self, k: &K) -> Result<&mut V, Bad>;
}

/// The error of a missing entry `k`.
pub(super) fn broken(k: &(impl Key + ?Sized)) -> Bad {
    Bad(format!(
        "internal error: {} is missing from central's tables",
        k.describe()
    ))
}

impl<K, Q, V, S> Linked<Q, V> for HashMap<K, V, S>
where
    K: Eq + Hash + Borrow<Q>,
    Q: Eq + Hash + Key + ?Sized,
    S: BuildHasher,
{
    fn linked(&self, k: &Q) -> Result<&V, Bad> {
        self.get(k).ok_or_else(|| broken(k))
    }

    fn linked_mut(&mut self, k: &Q) -> Result<&mut V, Bad> {
        self.get_mut(k).ok_or_else(|| broken(k))
    }
}

impl<K, Q, V> Linked<Q, V> for BTreeMap<K, V>
where
    K: Ord + Borrow<Q>,
    Q: Ord + Key + ?Sized,
{
    fn linked(&self, k: &Q) -> Result<&V, Bad> {
        self.get(k).ok_or_else(|| broken(k))
    }

    fn linked_mut(&mut self, k: &Q) -> Result<&mut V, Bad> {
        self.get_mut(k).ok_or_else(|| broken(k))
    }
}

/// Who sent a dispatch.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Org {
    Central,
    Module(ConnId),
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Status {
    /// Waiting for a handler to exist (a query or inform with none yet).
    NoHandler,
    /// In a module's pending queue.
    Pending,
    /// Delivered; waiting for Success or Reply.
    Attending,
    /// Written to the module ahead of its turn
    /// ([`Config::send_ahead`](super::Config::send_ahead)); counts as pending
    /// until a capacity slot frees.
    Ahead,
}

/// How a delivery that takes a capacity slot reaches its module.
#[derive(Debug, Clone, Copy)]
pub(super) enum Carry<'a> {
    /// Its whole frame, now.
    Frame,
    /// Its header and the body's first bytes now, the rest as it arrives
    /// (cut-through): the bytes so far and the body's whole length.
    Relayed(&'a [u8], usize),
    /// It was written ahead of its turn
    /// ([`Config::send_ahead`](super::Config::send_ahead)).
    Ahead,
}

/// The first socket number the C central gives a module: descriptors 0–2
/// are the standard streams, 3 and 4 its TCP and UNIX listeners.
pub(super) const FIRST_SD: i32 = 5;

#[derive(Debug)]
pub(super) struct Dispatch {
    pub(super) msg: String,
    /// The class the sender used (Broadcast, Query, Inform).
    pub(super) class: u16,
    /// The sender's classId (keeps its byte-order flags for forwarding).
    pub(super) class_id: ClassId,
    pub(super) org: Org,
    /// The sending module's name once it has closed (its connection is
    /// gone from the module table, but a reply may still come).
    pub(super) org_gone: Option<String>,
    pub(super) org_ref: i32,
    pub(super) parent_ref: i32,
    pub(super) data: Body,
    /// The handler: module and handler name.
    pub(super) hnd: Option<(ConnId, String)>,
    pub(super) status: Status,
}

/// What central counts for a queued message besides its data, against
/// [`Config::max_queued_bytes`](super::Config::max_queued_bytes): about what
/// its bookkeeping takes (the dispatch record, the message and handler names
/// it carries, its slots in the dispatch table and in a queue).
pub const DISPATCH_COST: usize = 256;

/// What a dispatch holds, as [`Stats::queued_bytes`] and
/// [`Stats::waiting_bytes`] count it.
pub(super) fn cost(d: &Dispatch) -> usize {
    d.data.len() + DISPATCH_COST
}

/// `d` leaves its pending queue (if it was in one): its cost no longer
/// counts as queued.
pub(super) fn unqueue(stats: &mut Stats, d: &Dispatch) {
    if d.status == Status::Pending {
        stats.queued_bytes = stats.queued_bytes.saturating_sub(cost(d));
    }
}

impl Dispatch {
    /// Delivered to `conn` and awaiting its Success or Reply.
    pub(super) fn attending_at(&self, conn: ConnId) -> bool {
        self.status == Status::Attending && self.hnd.as_ref().is_some_and(|(c, _)| *c == conn)
    }
}

#[derive(Debug)]
pub(super) struct Handler {
    pub(super) id: i32,
    /// Registration order.
    pub(super) seq: u64,
    pub(super) msg: String,
    /// The module asked msgInfo with this handler's name: it knows the message.
    pub(super) knows_msg: bool,
}

#[derive(Debug)]
pub(super) struct Module {
    pub(super) peer: Peer,
    /// The number the log calls its socket (`sd`): as the C central's file
    /// descriptors, the lowest not in use from [`FIRST_SD`] on, so a
    /// number comes back once its module is gone.
    pub(super) sd: i32,
    /// Bytes received and not yet framed; `rx_pos` is where unread data starts.
    pub(super) rx: Vec<u8>,
    pub(super) rx_pos: usize,
    pub(super) name: Option<String>,
    pub(super) host: String,
    /// `x_ipc_waitMsg` answered: deliveries may flow.
    pub(super) ready: bool,
    pub(super) capacity: usize,
    pub(super) attending: usize,
    /// Of the deliveries it is handling, those whose sender waits for an
    /// answer (queries): while it has one, central keeps reading it.
    pub(super) answering: usize,
    /// Its queries whose reply has not come (delivered, queued or waiting
    /// for a handler): while it has one, a handler of its may be blocked
    /// on someone else's answer.
    pub(super) asking: usize,
    pub(super) pending: VecDeque<DispatchId>,
    /// Broadcasts sent ahead of their turn, oldest first; they come before
    /// everything in `pending`.
    pub(super) ahead: VecDeque<DispatchId>,
    pub(super) msg_limits: Vec<(String, i32)>,
    pub(super) pending_limit: Option<i32>,
    /// Direct-mode listen port (-1 = none).
    pub(super) port: i32,
    /// Handlers by name.
    pub(super) handlers: SmallMap<String, Handler>,
    /// Ids of handlers this module unsubscribed, by name. A C module
    /// subscribes the same handler again with id 0 and expects deliveries
    /// under the id it registered first (`x_ipc_deregisterHnd` keeps the
    /// record; `x_ipc_selfRegisterHnd` finds it and keeps its id).
    pub(super) retired: SmallMap<String, i32>,
    /// The version of each variable this module last read (`V_get_…`) or
    /// was sent (`V_watch_…`).
    pub(super) vars_read: SmallMap<String, u64>,
    pub(super) paused: bool,
    /// Not read while it waits for room for a large frame
    /// ([`Config::max_frames_in_progress`](super::Config::max_frames_in_progress)).
    pub(super) frame_wait: bool,
    pub(super) closed: bool,
    /// Its problem lines (unknown ids, foreign acknowledgements …), so
    /// that a misbehaving module cannot flood the log.
    pub(super) problems: log::ProblemBudget,
    /// Before it has a name: whether central-wide budget for lines about
    /// such connections ([`log::StrangerBudget`]) left its lines out
    /// (`Some(true)`), let them through, or has not been asked yet.
    pub(super) quiet: Option<bool>,
    /// Closed by central for not naming itself in time
    /// ([`Config::handshake_timeout`](super::Config::handshake_timeout)).
    pub(super) timed_out: bool,
    /// A frame from this module being forwarded while it arrives.
    pub(super) relay: Option<Relay>,
    /// The module whose frame is being forwarded to this one: every other
    /// frame for this module waits in `held` until that one is complete.
    pub(super) relay_from: Option<ConnId>,
    pub(super) held: Vec<(Vec<u8>, Option<Body>)>,
    /// A large frame is being received into `rx` (from its start, with
    /// `rx_pos` 0) and ends at this length: `rx` takes no bytes beyond it,
    /// so that the frame's buffer becomes its [`Body`] without a copy.
    pub(super) big_end: Option<usize>,
    /// When bytes of the large or relayed frame in progress last arrived
    /// (or central last resumed reading it): see
    /// [`Config::frame_stall_timeout`](super::Config::frame_stall_timeout).
    pub(super) frame_progress: std::time::SystemTime,
}

/// A frame body passing through central as it arrives (cut-through).
#[derive(Debug)]
pub(super) struct Relay {
    /// Where the body goes.
    pub(super) to: ConnId,
    /// Body bytes still to come from the sender.
    pub(super) remaining: usize,
    /// Body bytes in all.
    pub(super) total: usize,
    pub(super) msg: String,
    /// A reply: its bookkeeping (`on_reply`) is done once it has passed.
    pub(super) reply: Option<(Header, Option<String>)>,
}

impl Module {
    /// A delivery would go out now rather than wait in `pending`.
    pub(super) fn takes_delivery_now(&self) -> bool {
        self.ready
            && self.attending < self.capacity
            && self.pending.is_empty()
            && self.ahead.is_empty()
    }
}

#[derive(Debug)]
pub(super) struct Msg {
    /// Central's id; none for a name only known from a subscription.
    pub(super) id: Option<MsgId>,
    pub(super) name: String,
    pub(super) class: MsgClass,
    pub(super) msg_format: Option<String>,
    pub(super) res_format: Option<String>,
    /// Parsed (and named-format expanded) formats, cached.
    pub(super) parsed: Option<(Option<Format>, Option<Format>)>,
    /// Handlers in subscription order (oldest first).
    pub(super) handlers: Vec<(ConnId, String)>,
    /// Dispatches waiting for a first handler.
    pub(super) waiting: VecDeque<DispatchId>,
    pub(super) priority: i32,
    pub(super) direct: bool,
    pub(super) notify_handler_change: bool,
    pub(super) internal: Option<Internal>,
}

#[derive(Debug)]
pub(super) struct Var {
    pub(super) format: Format,
    pub(super) value: Vec<u8>,
    /// Bumped at every change, so a module's watch can tell whether the
    /// value it read is still current.
    pub(super) version: u64,
}

/// A delivery of this class has a sender waiting for its answer (a query),
/// as opposed to a broadcast or inform, which nobody waits for.
pub(super) fn awaits_answer(class: u16) -> bool {
    class != MsgClass::Broadcast as u16 && class != MsgClass::Inform as u16
}

impl Central {
    pub(super) fn alloc_msg_id(&mut self) -> MsgId {
        loop {
            if let Some(id) = self.next_ids.pop() {
                if id >= 2 {
                    return MsgId(id);
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
    pub(super) fn take_ref(&mut self) -> DispatchId {
        self.free_dispatch.pop().unwrap_or_else(|| {
            let id = DispatchId(self.next_dispatch);
            self.next_dispatch += 1;
            id
        })
    }

    /// C gives every message a dispatch, the internal ones central handles
    /// and the informs it sends itself included, and frees it once
    /// handled; with `-lr` the log shows its id. Central holds an id from
    /// the same pool while it handles one, so that the ids it logs, and
    /// gives the modules' messages, follow C's.
    pub(super) fn give_ref(&mut self, id: DispatchId) {
        self.free_dispatch.push(id);
    }

    pub(super) fn alloc_dispatch(&mut self, d: Dispatch) -> DispatchId {
        let id = self.take_ref();
        if let (Org::Module(asker), true) = (d.org, awaits_answer(d.class)) {
            if let Some(m) = self.modules.get_mut(&asker) {
                m.asking += 1;
            }
        }
        self.dispatches.insert(id, d);
        id
    }

    pub(super) fn free_dispatch_id(&mut self, id: DispatchId) -> Option<Dispatch> {
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

    pub(super) fn register_internal(&mut self, d: Def) {
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

    /// Defines message `name` (or defines it again): a new one, or one
    /// only known from a subscription, gets an id.
    pub(super) fn insert_msg(
        &mut self,
        name: String,
        class: MsgClass,
        msg_format: Option<String>,
        res_format: Option<String>,
        internal: Option<Internal>,
    ) -> MsgId {
        let existed = self.msgs.contains_key(&name);
        self.definition_bytes = self.definition_bytes + msg_bytes(&msg_format, &res_format)
            - self
                .msgs
                .get(&name)
                .map_or(0, |m| msg_bytes(&m.msg_format, &m.res_format));
        let m = self.placeholder(&name);
        let was_placeholder = existed && m.class == MsgClass::HandlerReg;
        let known = m.id;
        m.class = class;
        m.msg_format = msg_format;
        m.res_format = res_format;
        m.parsed = None;
        if internal.is_some() {
            m.internal = internal;
        }
        let id = match known {
            Some(id) => id,
            None => {
                let id = self.alloc_msg_id();
                self.by_id.insert(id, name.clone());
                if let Some(m) = self.msgs.get_mut(&name) {
                    m.id = Some(id);
                }
                id
            }
        };
        if was_placeholder && class != MsgClass::Broadcast {
            self.record_broadcast(&name, false);
        }
        id
    }

    /// Message `name`, created without an id (class `HandlerReg`) if it
    /// is not known: a subscription or a priority may come before the
    /// message is defined.
    pub(super) fn placeholder(&mut self, name: &str) -> &mut Msg {
        if !self.msgs.contains_key(name) {
            self.definition_bytes += MSG_BYTES + name.len();
        }
        self.msgs.entry(name.to_string()).or_insert_with(|| Msg {
            id: None,
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
        })
    }

    /// Parsed formats of a message (named formats expanded as C does when
    /// it parses at lookup time; an unknown name stays `Named`).
    ///
    /// Kept for the next lookup unless named formats made it much larger
    /// than its strings ([`CACHED_NODES`]): three bytes naming a format
    /// that doubles at every level expand to a million nodes, which every
    /// message defined so would have kept.
    pub(super) fn parsed(&mut self, name: &str) -> (Option<Format>, Option<Format>) {
        let reg = &self.formats;
        let Some(m) = self.msgs.get_mut(name) else {
            return (None, None);
        };
        if let Some(p) = &m.parsed {
            return p.clone();
        }
        let p = |s: &Option<String>| -> Option<Format> {
            let s = s.as_deref()?;
            if s.is_empty() {
                return None;
            }
            parse_with(s, reg).or_else(|_| parse(s)).ok()
        };
        let parsed = (p(&m.msg_format), p(&m.res_format));
        let nodes =
            parsed.0.as_ref().map_or(0, node_count) + parsed.1.as_ref().map_or(0, node_count);
        let source = m.msg_format.as_ref().map_or(0, String::len)
            + m.res_format.as_ref().map_or(0, String::len);
        if nodes <= CACHED_NODES.max(source) {
            m.parsed = Some(parsed.clone());
        }
        parsed
    }
}

/// What a message's entry takes besides its name and formats
/// ([`Config::max_definition_bytes`](super::Config::max_definition_bytes)):
/// its record, its places in the name and id tables, its parsed formats
/// and the allocator's share. Measured (audit 23): 231 000 messages of
/// short names and formats took central 241 MB, about 1 KB each beyond
/// their strings; 256 made the bound count a quarter of what it held.
pub(super) const MSG_BYTES: usize = 1024;

/// What a message's formats take.
pub(super) fn msg_bytes(mf: &Option<String>, rf: &Option<String>) -> usize {
    mf.as_ref().map_or(0, String::len) + rf.as_ref().map_or(0, String::len)
}

/// What a named format takes: its name, nodes and bookkeeping.
pub(super) fn named_format_bytes(name: &str, f: &Format) -> usize {
    MSG_BYTES / 2 + name.len() + node_count(f) * std::mem::size_of::<Format>()
}

/// Nodes of a parsed format central keeps for the next lookup, at least:
/// more if its strings are longer than that (see [`Central::parsed`]).
const CACHED_NODES: usize = 4096;

/// The nodes of a format, an enum's names counting as
/// [`MAX_EXPANDED_NODES`](crate::format::MAX_EXPANDED_NODES) counts them.
fn node_count(f: &Format) -> usize {
    1 + match f {
        Format::Enum { names, .. } => {
            names
                .iter()
                .map(|n| n.len() + std::mem::size_of::<String>())
                .sum::<usize>()
                / crate::format::ENUM_BYTES_PER_NODE
        }
        Format::Struct(fields) => fields.iter().map(node_count).sum(),
        Format::Pointer(inner) => node_count(inner),
        Format::FixedArray { elem, .. } | Format::VarArray { elem, .. } => node_count(elem),
        Format::Empty
        | Format::Primitive(_)
        | Format::Length(_)
        | Format::SelfPointer
        | Format::Named(_) => 0,
    }
}

#[cfg(test)]
mod tests {
    use super::super::Config;
    use super::*;

    /// A message whose three-byte format names a definition that doubles
    /// at every level is answered, but its 262 143-node expansion is not
    /// kept (each such message kept one); an ordinary one is.
    #[test]
    fn expansions_much_larger_than_their_strings_are_not_kept() {
        let mut c = Central::new(Config::default());
        c.formats.define("L0", "{int, int}").unwrap();
        for k in 1..=16 {
            c.formats
                .define(&format!("L{k}"), &format!("{{L{0}, L{0}}}", k - 1))
                .unwrap();
        }
        c.insert_msg(
            "big".into(),
            MsgClass::Inform,
            Some("L16".into()),
            None,
            None,
        );
        c.insert_msg(
            "small".into(),
            MsgClass::Inform,
            Some("{int, L2}".into()),
            None,
            None,
        );
        let (big, _) = c.parsed("big");
        assert_eq!(big.as_ref().map(node_count), Some(262_143));
        assert!(c.msgs["big"].parsed.is_none());
        let (small, _) = c.parsed("small");
        assert_eq!(small.as_ref().map(node_count), Some(17));
        assert!(c.msgs["small"].parsed.is_some());
        // and a kept one is what a new lookup gives
        assert_eq!(c.parsed("small").0, small);
    }
}
