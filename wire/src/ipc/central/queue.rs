//! Pending queues: a delivery waiting for its module's capacity, with C's
//! queue limits and priorities, and send-ahead
//! ([`Config::send_ahead`](super::Config::send_ahead)).

use std::time::SystemTime;

use super::log::Kind;
use super::tables::{cost, Carry, DispatchId, Module, Org, Status};
use super::{Central, ConnId, DEFAULT_PRIORITY};
use crate::ipc::frame::MsgClass;

impl Central {
    /// `resourcePending`: queue limits (dropping the oldest, with C's
    /// fairness shuffle) and priority order.
    pub(super) fn pend(&mut self, did: DispatchId, now: SystemTime) {
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
        // (Both were found above.)
        let (Some(d), Some(m)) = (self.dispatches.get_mut(&did), self.modules.get_mut(&conn))
        else {
            return;
        };
        d.status = Status::Pending;
        if matches!(d.org, Org::Module(_)) {
            self.queued_by_modules += queued as u64;
        }
        self.stats.queued_bytes += queued;
        self.stats.peak_queued_bytes = self.stats.peak_queued_bytes.max(self.stats.queued_bytes);
        let org = d.org;
        let class = d.class;
        let parent = d.parent_ref;
        let dest = m.name.clone().unwrap_or_default();
        if let Some(slots) = drop_oldest {
            let (Some(&first), Some(&last)) = (slots.first(), slots.last()) else {
                // A limit of 0: nothing may wait.
                self.drop_pending(did, &msg);
                return;
            };
            // Shift every same-message entry up one slot; the new one takes the last.
            let oldest = m.pending[first];
            for w in slots.windows(2) {
                m.pending[w[0]] = m.pending[w[1]];
            }
            m.pending[last] = did;
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

    fn drop_pending(&mut self, did: DispatchId, msg: &str) {
        if let Some(d) = self.dispatches.get(&did) {
            if let Some((conn, _)) = d.hnd {
                if let Some(m) = self.modules.get_mut(&conn) {
                    // the oldest, as a rule: no scan
                    if m.pending.front() == Some(&did) {
                        m.pending.pop_front();
                    } else {
                        m.pending.retain(|x| *x != did);
                    }
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

    pub(super) fn process_pending(&mut self, conn: ConnId, now: SystemTime) {
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

    /// Whether broadcasts may be sent ahead to `m`
    /// ([`Config::send_ahead`](super::Config::send_ahead)): only where no
    /// priority can reorder what waits for it (queue limits are checked per
    /// message in [`Self::send_ahead`]), so that sending early changes
    /// nothing but the time.
    fn may_send_ahead(&self, m: &Module) -> bool {
        let depth = m
            .name
            .as_ref()
            .and_then(|n| self.config.send_ahead.get(n))
            .map_or(0, |&d| d.min(super::MAX_SEND_AHEAD));
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
    /// up to its [`Config::send_ahead`](super::Config::send_ahead) depth;
    /// they stay pending in the bookkeeping and the log until a capacity slot
    /// frees.
    pub(super) fn send_ahead(&mut self, conn: ConnId) {
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
            let Some(m) = self.modules.get_mut(&conn) else {
                return;
            };
            d.status = Status::Ahead;
            self.stats.queued_bytes = self.stats.queued_bytes.saturating_sub(cost(d));
            m.pending.pop_front();
            m.ahead.push_back(did);
            self.write_delivery(did, None);
        }
    }
}
