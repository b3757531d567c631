//! The links between central's tables that must hold whenever it is not
//! in the middle of a call, checked by [`Central::check_invariants`] for
//! tests and fuzzing.

use std::collections::BTreeMap;
use std::fmt::Write as _;

use super::tables::{awaits_answer, cost, Dispatch, DispatchId, Org, Status};
use super::{Central, ConnId};

impl Central {
    /// Panics, listing each one, if a link between central's tables is
    /// broken. For tests and fuzz targets, after any call: it walks every
    /// table, so it is too slow for a server.
    ///
    /// What it checks:
    /// - message ids: `by_id` and the message table name each other both
    ///   ways;
    /// - dispatch ids: every id handed out is either alive or free, once;
    /// - queues: each id in a module's pending (or sent-ahead) queue is a
    ///   dispatch with that status for a handler of that module, and each
    ///   such dispatch is in its module's queue exactly once;
    /// - every dispatch being handled, queued or sent ahead names a module
    ///   that is connected; each module's `attending`, `answering` and
    ///   `asking` counts match the dispatches;
    /// - every dispatch waiting for a handler is in its message's waiting
    ///   list or kept for `-r`, once, and those lists hold only such
    ///   dispatches;
    /// - handlers: a module's handler is listed by its message once, and a
    ///   message lists only handlers that its modules have;
    /// - the byte counts of [`Stats`](super::Stats) (`queued_bytes`,
    ///   `waiting_bytes`) are the sums over the dispatches they count;
    /// - paused modules are those central asked to pause, and those exist;
    /// - cut-through: a relay's sender and receiver name each other, and
    ///   frames are held only for a module receiving a relay;
    /// - no module stays half-closed, no receive buffer points past its
    ///   end, and the broadcast list names known messages once.
    #[doc(hidden)]
    pub fn check_invariants(&self) {
        let broken = self.broken_invariants();
        assert!(
            broken.is_empty(),
            "central's tables disagree:\n  {}",
            broken.join("\n  ")
        );
    }

    /// Every broken link, described.
    fn broken_invariants(&self) -> Vec<String> {
        let mut out = Vec::new();
        let dense = Dense::new(self, &mut out);
        self.check_msg_ids(&mut out);
        self.check_dispatch_ids(&dense, &mut out);
        self.check_queues(&dense, &mut out);
        self.check_waiting(&dense, &mut out);
        self.check_handlers(&mut out);
        self.check_modules(&mut out);
        self.check_definition_bytes(&mut out);
        out
    }

    /// What definitions hold is what the tables hold.
    fn check_definition_bytes(&self, out: &mut Vec<String>) {
        use super::tables::{msg_bytes, named_format_bytes, MSG_BYTES};
        let msgs: usize = self
            .msgs
            .values()
            .map(|m| MSG_BYTES + m.name.len() + msg_bytes(&m.msg_format, &m.res_format))
            .sum();
        let named: usize = self
            .formats
            .iter()
            .map(|(n, f)| named_format_bytes(n, f))
            .sum();
        if msgs + named != self.definition_bytes {
            out.push(format!(
                "definitions hold {} bytes by the tables, {} by the count",
                msgs + named,
                self.definition_bytes
            ));
        }
    }

    fn check_msg_ids(&self, out: &mut Vec<String>) {
        // Message ids come from blocks of 200 (`alloc_msg_id`): below
        // `id_block * 200`, dense enough to index (hashing every id at
        // every check would cost more than most steps being checked).
        let n = usize::try_from(self.id_block).unwrap_or(0) * 200;
        let mut named: Vec<Option<&String>> = vec![None; n];
        for (id, name) in &self.by_id {
            match usize::try_from(id.0).ok().and_then(|i| named.get_mut(i)) {
                Some(slot) => *slot = Some(name),
                None => out.push(format!("by_id gives {name} id {id}, never handed out")),
            }
        }
        for (name, m) in &self.msgs {
            if *name != m.name {
                out.push(format!("message {name} is filed as {}", m.name));
            }
            let Some(id) = m.id else {
                continue;
            };
            let slot = usize::try_from(id.0).ok().and_then(|i| named.get_mut(i));
            match slot {
                Some(slot) if *slot == Some(name) => *slot = None,
                _ => out.push(format!(
                    "message {name} has id {id}, which by_id gives to {:?}",
                    self.by_id.get(&id)
                )),
            }
        }
        // What is left names a message that does not have the id.
        for (id, name) in named.iter().enumerate() {
            if let Some(name) = name {
                out.push(format!("by_id gives id {id} to {name}, whose id it is not"));
            }
        }
    }

    fn check_dispatch_ids(&self, dense: &Dense<'_>, out: &mut Vec<String>) {
        let mut free = vec![false; dense.len()];
        for id in &self.free_dispatch {
            match dense.index(*id) {
                None => out.push(format!("dispatch id {id} is free but was never handed out")),
                Some(i) if free[i] => out.push(format!("dispatch id {id} is free twice")),
                Some(i) => free[i] = true,
            }
            if dense.get(*id).is_some() {
                out.push(format!("dispatch id {id} is free and alive"));
            }
        }
        let free = free.iter().filter(|f| **f).count();
        if self.dispatches.len() + free != dense.len() {
            out.push(format!(
                "{} dispatch id(s) handed out, {} alive and {free} free: some were not given \
                 back",
                dense.len(),
                self.dispatches.len(),
            ));
        }
    }

    fn check_queues(&self, dense: &Dense<'_>, out: &mut Vec<String>) {
        // Which module queues each dispatch.
        let mut queued: Vec<Option<ConnId>> = vec![None; dense.len()];
        for (conn, m) in &self.modules {
            for (list, status) in [(&m.pending, Status::Pending), (&m.ahead, Status::Ahead)] {
                for id in list {
                    if let Some(slot) = dense.index(*id).map(|i| &mut queued[i]) {
                        if let Some(other) = slot.replace(*conn) {
                            out.push(format!(
                                "dispatch {id} is queued for {} and for {}",
                                other.0, conn.0
                            ));
                        }
                    }
                    match dense.get(*id) {
                        None => out.push(format!(
                            "module {} queues dispatch {id}, which does not exist",
                            conn.0
                        )),
                        Some(d) if d.status != status => out.push(format!(
                            "module {} queues dispatch {id} as {status:?}, which is {:?}",
                            conn.0, d.status
                        )),
                        Some(d) if d.hnd.as_ref().map(|h| h.0) != Some(*conn) => out.push(format!(
                            "module {} queues dispatch {id}, whose handler is {:?}",
                            conn.0, d.hnd
                        )),
                        Some(_) => {}
                    }
                }
            }
        }
        // Per module: attending, answering, asking.
        let mut counts: BTreeMap<ConnId, (usize, usize, usize)> = BTreeMap::new();
        let mut queued_bytes = 0;
        for (id, d) in dense.iter() {
            if let (Org::Module(c), true) = (d.org, awaits_answer(d.class)) {
                counts.entry(c).or_default().2 += 1;
            }
            if d.status == Status::NoHandler {
                continue;
            }
            let Some((conn, _)) = &d.hnd else {
                out.push(format!("dispatch {id} is {:?} without a handler", d.status));
                continue;
            };
            if !self.modules.contains_key(conn) {
                out.push(format!(
                    "dispatch {id} is {:?} at module {}, which is gone",
                    d.status, conn.0
                ));
            }
            match d.status {
                Status::Pending => queued_bytes += cost(d),
                Status::Attending => {
                    let c = counts.entry(*conn).or_default();
                    c.0 += 1;
                    c.1 += usize::from(awaits_answer(d.class));
                }
                _ => {}
            }
            let in_queue = dense.index(id).and_then(|i| queued[i]);
            if matches!(d.status, Status::Pending | Status::Ahead) && in_queue != Some(*conn) {
                out.push(format!(
                    "dispatch {id} is {:?} at module {} but not in its queue",
                    d.status, conn.0
                ));
            }
        }
        for (conn, m) in &self.modules {
            let (attending, answering, asking) = counts.get(conn).copied().unwrap_or_default();
            if (m.attending, m.answering, m.asking) != (attending, answering, asking) {
                out.push(format!(
                    "module {} counts {} attending ({} answering) and {} asked, the dispatches \
                     {attending} ({answering}) and {asking}",
                    conn.0, m.attending, m.answering, m.asking
                ));
            }
        }
        if self.stats.queued_bytes != queued_bytes {
            out.push(format!(
                "queued_bytes is {}, the pending dispatches hold {queued_bytes}",
                self.stats.queued_bytes
            ));
        }
    }

    fn check_waiting(&self, dense: &Dense<'_>, out: &mut Vec<String>) {
        let mut seen = vec![false; dense.len()];
        let mut waiting_bytes = 0;
        // `msg`: the message whose own list holds `id` (its dispatches
        // count as waiting bytes); `None` for those kept for `-r`.
        let mut visit = |msg: Option<&String>, id: DispatchId, out: &mut Vec<String>| {
            let what = || match msg {
                Some(m) => format!("message {m}"),
                None => "the -r list".to_string(),
            };
            match dense.index(id).map(|i| &mut seen[i]) {
                Some(s) if *s => {
                    out.push(format!("dispatch {id} waits twice (again in {})", what()))
                }
                Some(s) => *s = true,
                None => {}
            }
            match dense.get(id) {
                None => out.push(format!("{} waits for dispatch {id}, which is gone", what())),
                Some(d) if d.status != Status::NoHandler => out.push(format!(
                    "{} waits for dispatch {id}, which is {:?}",
                    what(),
                    d.status
                )),
                Some(d) if msg.is_some_and(|n| *n != d.msg) => out.push(format!(
                    "{} waits for dispatch {id} of message {}",
                    what(),
                    d.msg
                )),
                Some(d) if msg.is_some() => waiting_bytes += cost(d),
                Some(_) => {}
            }
        };
        for m in self.msgs.values() {
            for id in &m.waiting {
                visit(Some(&m.name), *id, out);
            }
        }
        let mut kept_bytes = 0;
        for (_, id) in self.kept.iter() {
            visit(None, id, out);
            kept_bytes += dense.get(id).map_or(0, cost);
        }
        if self.stats.kept_bytes != kept_bytes {
            out.push(format!(
                "kept_bytes is {}, the dispatches kept for -r hold {kept_bytes}",
                self.stats.kept_bytes
            ));
        }
        for (id, d) in dense.iter() {
            let listed = dense.index(id).is_some_and(|i| seen[i]);
            if d.status == Status::NoHandler && !listed {
                out.push(format!(
                    "dispatch {id} of {} waits for a handler but is in no list",
                    d.msg
                ));
            }
        }
        if self.stats.waiting_bytes != waiting_bytes {
            out.push(format!(
                "waiting_bytes is {}, the waiting dispatches hold {waiting_bytes}",
                self.stats.waiting_bytes
            ));
        }
    }

    fn check_handlers(&self, out: &mut Vec<String>) {
        // Every module's handlers, sorted (the tables are B-trees), with
        // how many times a message lists each.
        let all: Vec<(ConnId, &str, &str)> = self
            .modules
            .iter()
            .flat_map(|(c, m)| {
                m.handlers
                    .iter()
                    .map(move |(hn, h)| (*c, hn.as_str(), h.msg.as_str()))
            })
            .collect();
        let mut listed = vec![0usize; all.len()];
        for (name, msg) in &self.msgs {
            for (conn, hn) in &msg.handlers {
                match all.binary_search_by(|(c, n, _)| (c, *n).cmp(&(conn, hn.as_str()))) {
                    Ok(i) if all[i].2 == name => listed[i] += 1,
                    _ => out.push(format!(
                        "message {name} lists handler {hn} of module {}, which has no such \
                         handler",
                        conn.0
                    )),
                }
            }
        }
        for ((conn, hn, msg), n) in all.iter().zip(listed) {
            if n != 1 {
                out.push(format!(
                    "handler {hn} of module {} (for {msg}) is listed {n} time(s)",
                    conn.0
                ));
            }
        }
        let mut names: Vec<&String> = self.broadcast_msgs.iter().collect();
        names.sort_unstable();
        for w in names.windows(2) {
            if w[0] == w[1] {
                out.push(format!("broadcast list names {} twice", w[0]));
            }
        }
        for n in names {
            if !self.msgs.contains_key(n) {
                out.push(format!("broadcast list names unknown message {n}"));
            }
        }
    }

    fn check_modules(&self, out: &mut Vec<String>) {
        for (conn, m) in &self.modules {
            let mut what = String::new();
            if m.closed {
                what.push_str(" is closed but still kept;");
            }
            if m.paused != self.memory_paused.contains(conn) {
                let _ = write!(
                    what,
                    " is {}paused, against the list of paused modules;",
                    if m.paused { "" } else { "not " }
                );
            }
            if m.rx_pos > m.rx.len() {
                let _ = write!(what, " reads at {} of {} bytes;", m.rx_pos, m.rx.len());
            }
            if let Some(end) = m.big_end {
                if m.rx_pos != 0 || m.rx.len() >= end {
                    let _ = write!(
                        what,
                        " fills a large frame to {end} with {} bytes from {};",
                        m.rx.len(),
                        m.rx_pos
                    );
                }
            }
            if let Some(r) = &m.relay {
                if r.remaining == 0 {
                    what.push_str(" relays a finished frame;");
                }
                if let Some(to) = self.modules.get(&r.to) {
                    if to.relay_from != Some(*conn) {
                        let _ = write!(
                            what,
                            " relays to {}, which takes from {:?};",
                            r.to.0, to.relay_from
                        );
                    }
                }
            }
            match m.relay_from {
                Some(from) => {
                    let to = self
                        .modules
                        .get(&from)
                        .and_then(|f| f.relay.as_ref())
                        .map(|r| r.to);
                    if to != Some(*conn) {
                        let _ = write!(
                            what,
                            " takes a relay from {}, which sends none here;",
                            from.0
                        );
                    }
                }
                None if !m.held.is_empty() => what.push_str(" holds frames without a relay;"),
                None => {}
            }
            if !what.is_empty() {
                out.push(format!("module {}{}", conn.0, what.trim_end_matches(';')));
            }
        }
        for conn in &self.memory_paused {
            if !self.modules.contains_key(conn) {
                out.push(format!("paused module {} is gone", conn.0));
            }
        }
        for conn in &self.answer_paused {
            if !self.memory_paused.contains(conn) {
                out.push(format!(
                    "module {} is held back while it answers but not paused",
                    conn.0
                ));
            }
        }
    }
}

/// The dispatches by id. Dispatch ids are small and dense
/// (`0..next_dispatch`), so a vector indexes them without hashing: that
/// keeps the checks cheap enough to run after every step of a simulation
/// with thousands of messages queued.
struct Dense<'a> {
    slots: Vec<Option<&'a Dispatch>>,
}

impl<'a> Dense<'a> {
    fn new(c: &'a Central, out: &mut Vec<String>) -> Self {
        let n = usize::try_from(c.next_dispatch).unwrap_or(0);
        let mut slots = vec![None; n];
        for (id, d) in &c.dispatches {
            match usize::try_from(id.0).ok().filter(|i| *i < n) {
                Some(i) => slots[i] = Some(d),
                None => out.push(format!(
                    "dispatch id {id} is alive but was never handed out"
                )),
            }
        }
        Dense { slots }
    }

    /// Ids handed out so far.
    fn len(&self) -> usize {
        self.slots.len()
    }

    /// Where `id` is in vectors of [`len`](Self::len) marks, if it was
    /// handed out.
    fn index(&self, id: DispatchId) -> Option<usize> {
        // (Plain comparisons: this runs for every id at every check.)
        if id.0 >= 0 && (id.0 as usize) < self.slots.len() {
            Some(id.0 as usize)
        } else {
            None
        }
    }

    /// The dispatches alive, by id.
    fn iter(&self) -> impl Iterator<Item = (DispatchId, &'a Dispatch)> + '_ {
        // `len` came from an `i32`, so every index fits one.
        (0..self.slots.len()).filter_map(|i| Some((DispatchId(i as i32), self.slots[i]?)))
    }

    fn get(&self, id: DispatchId) -> Option<&'a Dispatch> {
        self.index(id).and_then(|i| self.slots[i])
    }
}
