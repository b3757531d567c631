//! What central does when time passes with nothing arriving: a connection
//! that never said its module name is closed
//! ([`Config::handshake_timeout`](super::Config::handshake_timeout)), and
//! the count of strangers' connections whose lines were left out is said
//! when its window is over, not only at the next connection.
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
        match (handshake, summary) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
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
        self.stranger_summary(now);
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
