//! Back-pressure
//! ([`Config::max_queued_bytes`](super::Config::max_queued_bytes)): reading
//! paused and resumed, and the bound on queries waiting for a first handler.

use super::log;
use super::tables::{cost, DispatchId, Linked};
use super::{Bad, Central, ConnId, Output};

/// At most one "holds modules back" line this often.
pub(super) const MEMORY_LINE_EVERY: std::time::Duration = std::time::Duration::from_secs(10);

impl Central {
    /// Central reads `conn` again before the queues have drained: what it
    /// sends is now waited for.
    pub(super) fn resume_read(&mut self, conn: ConnId) {
        if let Some(m) = self.modules.get_mut(&conn) {
            if m.paused {
                m.paused = false;
                m.frame_progress = self.clock;
                self.memory_paused.remove(&conn);
                self.answer_paused.remove(&conn);
                if !m.frame_wait {
                    self.outputs.push_back(Output::ResumeRead { conn });
                }
            }
        }
    }

    /// Whether a large frame of `len` bytes may start now: the frames in
    /// progress leave room for it, or there are none.
    pub(super) fn room_for_frame(&self, len: usize) -> bool {
        let held = self.frames_in_progress();
        held == 0 || (held + len) as u64 <= self.config.max_frames_in_progress
    }

    /// Bytes of the large frames being received, all connections together.
    fn frames_in_progress(&self) -> usize {
        self.modules.values().filter_map(|m| m.big_end).sum()
    }

    /// `conn` starts a large frame without room for it: it is read no more
    /// until a frame in progress completes or its connection goes.
    pub(super) fn wait_for_frame_room(&mut self, conn: ConnId, len: usize) {
        let Some(m) = self.modules.get_mut(&conn) else {
            return;
        };
        if m.frame_wait {
            return;
        }
        m.frame_wait = true;
        let paused = m.paused;
        self.frame_waiters.push((conn, len));
        self.stats.frames_waited += 1;
        if !paused {
            self.outputs.push_back(Output::PauseRead { conn });
        }
    }

    /// Reads again, in the order they came, the connections waiting for
    /// room for a large frame that there is room for now (each checks
    /// again when its frame goes on).
    pub(super) fn wake_frame_waiters(&mut self) {
        if self.frame_waiters.is_empty() {
            return;
        }
        let mut held = self.frames_in_progress();
        let max = self.config.max_frames_in_progress;
        let mut still = Vec::new();
        for (conn, len) in std::mem::take(&mut self.frame_waiters) {
            let Some(m) = self.modules.get_mut(&conn) else {
                continue;
            };
            if held > 0 && (held + len) as u64 > max {
                still.push((conn, len));
                continue;
            }
            held += len;
            m.frame_wait = false;
            if !m.paused {
                self.outputs.push_back(Output::ResumeRead { conn });
            }
        }
        self.frame_waiters = still;
    }

    /// A message was queued for `conn`. If a handler of `conn` may be
    /// waiting for an answer, the queue may wait on a module held back
    /// while it answers a query: read those again (see [`Self::check_memory`]).
    pub(super) fn unblock_askers(&mut self, conn: ConnId) {
        if self.answer_paused.is_empty() || self.modules.get(&conn).is_none_or(|m| m.asking == 0) {
            return;
        }
        let paused: Vec<ConnId> = self.answer_paused.drain().collect();
        for c in paused {
            self.resume_read(c);
        }
    }

    pub(super) fn check_memory(&mut self, conn: ConnId) {
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
        if let (true, Some(m)) = (may_pause, self.modules.get_mut(&conn)) {
            m.paused = true;
            let first = self.memory_paused.is_empty();
            self.memory_paused.insert(conn);
            if first {
                self.say_paused();
            }
            if answering {
                self.answer_paused.insert(conn);
            }
            self.outputs.push_back(Output::PauseRead { conn });
        }
    }

    /// The first module held back for memory: one line that says so and
    /// names the module with the longest queue (often one that stopped
    /// reading): every module that sends more waits now, its traffic and
    /// queries with it, until the queues drain to half.
    fn say_paused(&mut self) {
        let Some(again) = self.memory_said.admit(self.clock) else {
            return;
        };
        let since = if again > 0 {
            format!(" (and {again} time(s) since the last such line)")
        } else {
            String::new()
        };
        let longest = self
            .modules
            .iter()
            .map(|(c, m)| (m.pending.len() + m.ahead.len(), *c))
            .max();
        let whom = match longest {
            Some((n, c)) if n > 0 => format!(
                "; the longest queue ({n} message(s)) is for {}, which may have stopped reading",
                self.describe(c)
            ),
            _ => String::new(),
        };
        self.log_line(
            log::Kind::Problem,
            format!(
                "WARNING: central holds {} bytes for modules, more than {} (max_queued_bytes): \
                 it stops reading the modules that send more until its queues drain to \
                 half{whom}{since}",
                self.stats.queued_bytes, self.config.max_queued_bytes
            ),
        );
    }

    pub(super) fn check_memory_resume(&mut self) {
        if self.memory_paused.is_empty()
            || self.stats.queued_bytes > self.config.max_queued_bytes / 2
        {
            return;
        }
        let paused: Vec<ConnId> = self.memory_paused.drain().collect();
        self.answer_paused.clear();
        // (said for the hold that was said: once in a while)
        if self.memory_said.all_said() {
            self.log_line(
                log::Kind::Problem,
                format!(
                    "WARNING: central's queues are down to {} bytes: reading every module \
                     again ({} were held back)",
                    self.stats.queued_bytes,
                    paused.len()
                ),
            );
        }
        for conn in paused {
            if let Some(m) = self.modules.get_mut(&conn) {
                if m.paused {
                    m.paused = false;
                    m.frame_progress = self.clock;
                    if !m.frame_wait {
                        self.outputs.push_back(Output::ResumeRead { conn });
                    }
                }
            }
        }
    }

    /// A query or inform of `msg` from `conn` (`added`) joined those waiting
    /// for a first handler. Past
    /// [`Config::max_queued_bytes`](super::Config::max_queued_bytes) of them,
    /// the oldest of `msg` are dropped (the new one last), as a queue limit
    /// drops the oldest: their askers may have given up long ago, and a
    /// handler that comes gets the newest. Pausing the asker instead would
    /// stop a module's whole connection for one message nobody serves, and
    /// would hide its hang-up until a handler comes.
    pub(super) fn bound_waiting(
        &mut self,
        conn: ConnId,
        msg: &str,
        added: DispatchId,
    ) -> Result<(), Bad> {
        self.stats.waiting_bytes += cost(self.dispatches.linked(&added)?);
        while self.stats.waiting_bytes > self.config.max_queued_bytes {
            let Some(did) = self.msgs.get_mut(msg).and_then(|m| m.waiting.pop_front()) else {
                break;
            };
            let Some(d) = self.free_dispatch_id(did) else {
                continue;
            };
            self.stats.waiting_bytes = self.stats.waiting_bytes.saturating_sub(cost(&d));
            self.stats.dropped_waiting += 1;
            let asker = self.org_name(&d);
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
        Ok(())
    }
}
