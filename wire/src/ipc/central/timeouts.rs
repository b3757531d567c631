//! What central does when time passes with nothing arriving: a connection
//! that never said its module name is closed
//! ([`Config::handshake_timeout`](super::Config::handshake_timeout)), so is
//! one whose large frame stopped arriving half way
//! ([`Config::frame_stall_timeout`](super::Config::frame_stall_timeout)),
//! and the count of strangers' connections whose lines were left out is
//! said when its window is over, not only at the next connection.
//!
//! The shell asks [`Central::next_timeout`] after each turn and calls
//! [`Central::handle_timeout`] when that time comes (early calls are
//! harmless).

use std::time::SystemTime;

use super::log::Kind;
use super::{Central, ConnId, Output};

impl Central {
    /// When [`handle_timeout`](Self::handle_timeout) next has something
    /// to do (it may then find nothing: a connection named itself in the
    /// meantime). `None`: nothing is waiting for time.
    pub fn next_timeout(&self) -> Option<SystemTime> {
        let handshake = self.handshakes.front().map(|&(at, _)| at);
        let summary = self.strangers.due();
        [handshake, summary, self.stall_check]
            .into_iter()
            .flatten()
            .min()
    }

    /// Time has come to `now`: closes the connections that have not named
    /// themselves within the handshake timeout, and says what the
    /// strangers' budget left out in a window that is over.
    pub fn handle_timeout(&mut self, now: SystemTime) {
        self.clock = now;
        while let Some(&(at, conn)) = self.handshakes.front() {
            if at > now {
                break;
            }
            self.handshakes.pop_front();
            if self.nameless(conn) {
                self.close_silent(conn, now);
            }
        }
        if self.stall_check.is_some_and(|at| at <= now) {
            self.check_stalls(now);
        }
        self.stranger_summary(now);
    }

    /// `conn` started receiving a large frame, or forwarding one as it
    /// arrives: it is watched for stalling
    /// ([`Config::frame_stall_timeout`](super::Config::frame_stall_timeout)).
    pub(super) fn watch_frame(&mut self, conn: ConnId, now: SystemTime) {
        let Some(limit) = self.config.frame_stall_timeout else {
            return;
        };
        let Some(m) = self.modules.get_mut(&conn) else {
            return;
        };
        m.frame_progress = now;
        if !self.stall_watch.contains(&conn) {
            self.stall_watch.push(conn);
        }
        if self.stall_check.is_none() {
            self.stall_check = Some(now.checked_add(limit).unwrap_or(now));
        }
    }

    /// Closes the watched connections whose frame has had no byte for
    /// the stall timeout, forgets those whose frame is over, and says
    /// when to look again.
    fn check_stalls(&mut self, now: SystemTime) {
        self.stall_check = None;
        let Some(limit) = self.config.frame_stall_timeout else {
            self.stall_watch.clear();
            return;
        };
        let mut stalled = Vec::new();
        let mut next: Option<SystemTime> = None;
        self.stall_watch.retain(|&conn| {
            let Some(m) = self.modules.get_mut(&conn) else {
                return false;
            };
            if m.closed || (m.big_end.is_none() && m.relay.is_none()) {
                return false;
            }
            if m.paused {
                // central does not read it: its peer is not late
                m.frame_progress = now;
            }
            let due = m.frame_progress.checked_add(limit).unwrap_or(now);
            if due <= now {
                stalled.push(conn);
                return false;
            }
            next = Some(next.map_or(due, |n| n.min(due)));
            true
        });
        self.stall_check = next;
        for conn in stalled {
            self.close_stalled(conn, limit, now);
        }
    }

    fn close_stalled(&mut self, conn: ConnId, limit: std::time::Duration, now: SystemTime) {
        let Some(m) = self.modules.get(&conn) else {
            return;
        };
        let (what, got, total) = match (&m.relay, m.big_end) {
            (Some(r), _) => (
                "message (forwarded as it came)",
                r.total - r.remaining,
                r.total,
            ),
            (None, Some(end)) => ("frame", m.rx.len(), end),
            (None, None) => return,
        };
        let secs = limit.as_secs_f64();
        let why = format!(
            "its {what} of {total} bytes stopped arriving ({got} received, none in {secs} s)"
        );
        self.close_saying(conn, "WARNING", why, now);
    }

    /// A new connection has [`Config::handshake_timeout`] to name itself.
    ///
    /// [`Config::handshake_timeout`]: super::Config::handshake_timeout
    pub(super) fn expect_name(&mut self, conn: ConnId, now: SystemTime) {
        let Some(limit) = self.config.handshake_timeout else {
            return;
        };
        self.prune_handshakes();
        let at = now.checked_add(limit).unwrap_or(now);
        self.handshakes.push_back((at, conn));
    }

    /// Drops the entries at the front of those that named themselves or
    /// left, so that [`next_timeout`](Self::next_timeout) names a
    /// stranger's deadline (modules name themselves in about the order
    /// they connect, so the queue stays as long as the strangers in it).
    pub(super) fn prune_handshakes(&mut self) {
        while let Some(&(_, c)) = self.handshakes.front() {
            if self.nameless(c) {
                break;
            }
            self.handshakes.pop_front();
        }
    }

    fn nameless(&self, conn: ConnId) -> bool {
        self.modules
            .get(&conn)
            .is_some_and(|m| !m.closed && m.name.is_none())
    }

    fn close_silent(&mut self, conn: ConnId, now: SystemTime) {
        let secs = self
            .config
            .handshake_timeout
            .map_or(0.0, |d| d.as_secs_f64());
        if let Some(m) = self.modules.get_mut(&conn) {
            m.timed_out = true;
        }
        if !self.stranger_quiet(conn) {
            let who = self.describe(conn);
            self.log_line(
                Kind::Problem,
                format!(
                    "WARNING: closing connection {who}: it did not say its module name \
                     (IPC_connect) within {secs} s"
                ),
            );
        }
        self.outputs.push_back(Output::Close {
            conn,
            reason: format!("no module name within {secs} s"),
        });
        self.close_module(conn, false, now);
    }
}
