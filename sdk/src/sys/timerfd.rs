//! A monotonic `timerfd` registered with tokio: a driver loop's timer on
//! Linux (three system calls libc has and std does not).

use std::io;
use std::os::fd::{AsRawFd, FromRawFd, OwnedFd};
use std::task::{ready, Context, Poll};
use std::time::{Duration, Instant};

use tokio::io::unix::AsyncFd;
use tokio::io::Interest;

/// A monotonic `timerfd`, non-blocking, registered for readability.
pub(crate) struct TimerFd {
    fd: AsyncFd<OwnedFd>,
    /// The expiry the kernel holds, while it has not fired.
    armed: Option<Instant>,
}

impl TimerFd {
    pub(crate) fn new() -> io::Result<Self> {
        // SAFETY: plain system call; the descriptor is owned below.
        let raw = unsafe {
            libc::timerfd_create(
                libc::CLOCK_MONOTONIC,
                libc::TFD_NONBLOCK | libc::TFD_CLOEXEC,
            )
        };
        if raw < 0 {
            return Err(io::Error::last_os_error());
        }
        // SAFETY: `raw` is a fresh descriptor nothing else owns.
        let owned = unsafe { OwnedFd::from_raw_fd(raw) };
        // SAFETY: the `AsyncFd` owns the descriptor, which stays open and
        // the same until it is dropped (nothing hands it out).
        let fd = unsafe { AsyncFd::register_with_interest(owned, Interest::READABLE) }
            .map_err(|e| e.into_parts().1)?;
        Ok(TimerFd { fd, armed: None })
    }

    /// Arms the timer for `at` unless it already fires at or before it.
    pub(crate) fn set(&mut self, at: Instant) {
        if self.armed.is_some_and(|armed| armed <= at) {
            return;
        }
        // relative to the clock now (read only when arming): std's
        // `Instant` is CLOCK_MONOTONIC here, but its value is not
        // exposed; a zero value would disarm, so at least 1 ns
        let d = at
            .saturating_duration_since(Instant::now())
            .max(Duration::from_nanos(1));
        let spec = libc::itimerspec {
            it_interval: libc::timespec {
                tv_sec: 0,
                tv_nsec: 0,
            },
            it_value: libc::timespec {
                tv_sec: d.as_secs().min(i64::MAX as u64) as libc::time_t,
                tv_nsec: libc::c_long::from(d.subsec_nanos() as i32),
            },
        };
        // SAFETY: valid descriptor and pointers for the call's duration.
        let r =
            unsafe { libc::timerfd_settime(self.fd.as_raw_fd(), 0, &spec, std::ptr::null_mut()) };
        // cannot fail with a valid descriptor and value; if it did, the
        // driver would wake early (never late), as with `armed = None`
        self.armed = (r == 0).then_some(at);
    }

    pub(crate) fn poll_fired(&mut self, cx: &mut Context<'_>) -> Poll<()> {
        loop {
            let mut guard = match ready!(self.fd.poll_read_ready(cx)) {
                Ok(g) => g,
                // only while the runtime shuts down, which drops the
                // driver next
                Err(_) => return Poll::Pending,
            };
            let mut n = [0u8; 8];
            // SAFETY: reads 8 bytes into a buffer of 8.
            let r = unsafe { libc::read(self.fd.as_raw_fd(), n.as_mut_ptr().cast(), n.len()) };
            if r == 8 {
                self.armed = None;
                return Poll::Ready(());
            }
            // EAGAIN: not expired yet (readiness was stale)
            guard.clear_ready();
        }
    }
}
