//! The close of a session whose runtime shut down first.
//!
//! A program that drops its last handle and returns from `main` (or never
//! closes) ends its runtime while the driver task still has the session
//! to close: tokio drops the task mid-flight. The writes its
//! `publish().await`s were told are queued may not even be in the writers
//! yet. The driver's `Drop` then closes here, blocking, as a DDS
//! participant deleted at exit does (Cyclone DDS's `dds_delete` lingers
//! too): the queued writes go into the writers, and it waits, at most
//! [`CLOSE_LINGER`], until the reliable readers have acknowledged them,
//! waiting on its sockets with `poll(2)` instead of the reactor that is
//! gone.

use std::os::fd::AsFd;
use std::time::{Duration, Instant};

use super::driver::{Driver, CLOSE_LINGER};
use super::net;

impl Driver {
    /// Lingers without tokio (see the [module docs](self)); true if every
    /// reliable reader has what the writers hold.
    pub(super) fn linger_blocking(&mut self) -> bool {
        let start = Instant::now();
        let until = start + CLOSE_LINGER;
        {
            let mut c = self.shared.lock();
            // writes queued before the close: theirs callers were told Ok
            c.take_commands(start);
            c.st.begin_close(start);
        }
        loop {
            let now = Instant::now();
            let (quiet, full, next) = {
                let mut c = self.shared.lock();
                let flushed = c.turn(now);
                (
                    flushed.is_ok() && c.st.quiet(),
                    flushed.is_err(),
                    c.st.next_wakeup(),
                )
            };
            if quiet || now >= until {
                return quiet;
            }
            let wait = next
                .min(until)
                .saturating_duration_since(now)
                .max(Duration::from_millis(1));
            let mut fds = vec![(self.meta.get_ref().as_fd(), true, false)];
            if let Some(u) = &self.user {
                fds.push((u.get_ref().as_fd(), true, false));
            }
            fds.push((self.send_sock.as_fd(), false, full));
            let Ok(ready) = crate::sys::net::poll(&fds, wait) else {
                return false;
            };
            let readable: Vec<bool> = ready.iter().map(|r| r.0).collect();
            self.read_now(
                readable.first() == Some(&true),
                readable.get(1) == Some(&true),
            );
        }
    }

    /// Reads what waits on the metatraffic socket and, when the driver
    /// reads it, the user data socket.
    fn read_now(&mut self, meta: bool, user: bool) {
        let now = Instant::now();
        let socks = [
            meta.then(|| self.meta.get_ref()),
            self.user.as_ref().filter(|_| user).map(|u| u.get_ref()),
        ];
        let mut c = self.shared.lock();
        for sock in socks.into_iter().flatten() {
            // bounded: a peer that floods us does not hold the exit
            for _ in 0..8 {
                match net::recv_batch_now(sock, &mut self.batch) {
                    Ok(0) | Err(_) => break,
                    Ok(n) => c.receive(&self.batch, n, now),
                }
            }
        }
    }
}
