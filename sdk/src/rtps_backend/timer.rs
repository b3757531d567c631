//! The driver's one timer.
//!
//! A tokio timer makes the runtime wait in `epoll_wait` with a timeout, and
//! the kernel arms and cancels a high-resolution timer for every such wait:
//! on the 2-vCPU VM of BENCHMARKS.md that cost ~0.6 µs per wake-up, 1.2 µs
//! per same-core round trip (21.4 → 20.2 µs without it). The driver's
//! deadlines (heartbeats, housekeeping, leases) are tens of milliseconds
//! away and rarely move closer, so on Linux the driver keeps them in a
//! `timerfd` that sits in the runtime's epoll set like a socket: armed when
//! the deadline moves earlier, and left alone when it moves later (it then
//! fires early once, the driver finds nothing due and arms it again). A
//! runtime with no timers of its own then waits with no timeout at all.
//!
//! Elsewhere, or when a `timerfd` cannot be made, it is a tokio `Sleep`.

use std::future::Future as _;
use std::pin::Pin;
use std::task::{ready, Context, Poll};
use std::time::Instant;

pub(super) struct DriverTimer {
    inner: Inner,
}

enum Inner {
    #[cfg(target_os = "linux")]
    Fd(fd::TimerFd),
    Sleep(Pin<Box<tokio::time::Sleep>>),
}

impl DriverTimer {
    /// A timer that fires at `at` (or a little after).
    pub(super) fn new(at: Instant) -> Self {
        #[cfg(target_os = "linux")]
        match fd::TimerFd::new() {
            Ok(mut t) => {
                t.set(at);
                return DriverTimer {
                    inner: Inner::Fd(t),
                };
            }
            Err(e) => tracing::debug!("no timerfd ({e}): the RTPS driver uses a tokio timer"),
        }
        DriverTimer {
            inner: Inner::Sleep(Box::pin(tokio::time::sleep_until(at.into()))),
        }
    }

    /// Fires no later than `at`; may fire earlier (after an earlier
    /// deadline that was since given up), so the caller checks what is due.
    pub(super) fn set(&mut self, at: Instant) {
        match &mut self.inner {
            #[cfg(target_os = "linux")]
            Inner::Fd(t) => t.set(at),
            Inner::Sleep(s) => {
                let at = tokio::time::Instant::from(at);
                if s.deadline() != at {
                    s.as_mut().reset(at);
                }
            }
        }
    }

    pub(super) fn poll_fired(&mut self, cx: &mut Context<'_>) -> Poll<()> {
        match &mut self.inner {
            #[cfg(target_os = "linux")]
            Inner::Fd(t) => t.poll_fired(cx),
            Inner::Sleep(s) => {
                ready!(s.as_mut().poll(cx));
                // fired: stays ready until set again, as the timerfd does not
                // (the driver always sets it before waiting)
                Poll::Ready(())
            }
        }
    }

    #[cfg(test)]
    pub(super) async fn fired(&mut self) {
        std::future::poll_fn(|cx| self.poll_fired(cx)).await
    }
}

#[cfg(target_os = "linux")]
use crate::sys::timerfd as fd;

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    const MS: Duration = Duration::from_millis(1);

    #[tokio::test]
    async fn fires_at_its_deadline_and_not_before() {
        let t0 = Instant::now();
        let mut t = DriverTimer::new(t0 + 30 * MS);
        t.fired().await;
        assert!(t0.elapsed() >= 30 * MS, "fired after {:?}", t0.elapsed());
    }

    #[tokio::test]
    async fn an_earlier_deadline_is_armed_at_once() {
        let t0 = Instant::now();
        let mut t = DriverTimer::new(t0 + Duration::from_secs(60));
        t.set(t0 + 20 * MS);
        tokio::time::timeout(Duration::from_secs(5), t.fired())
            .await
            .expect("the earlier deadline fired");
        assert!(t0.elapsed() >= 20 * MS);
    }

    #[tokio::test]
    async fn a_later_deadline_never_makes_it_late() {
        // moving the deadline later may wake the driver early (it then finds
        // nothing due and sets the timer again), never after the deadline
        let t0 = Instant::now();
        let mut t = DriverTimer::new(t0 + 10 * MS);
        t.set(t0 + 40 * MS);
        t.fired().await;
        let first = t0.elapsed();
        assert!(first >= 10 * MS);
        if first < 40 * MS {
            t.set(t0 + 40 * MS);
            t.fired().await;
        }
        assert!(t0.elapsed() >= 40 * MS);
    }

    #[tokio::test]
    async fn a_deadline_already_past_fires_at_once_and_again_when_set_again() {
        let t0 = Instant::now();
        let mut t = DriverTimer::new(t0);
        tokio::time::timeout(Duration::from_secs(5), t.fired())
            .await
            .expect("fired");
        t.set(Instant::now());
        tokio::time::timeout(Duration::from_secs(5), t.fired())
            .await
            .expect("fired again");
    }

    #[cfg(target_os = "linux")]
    #[tokio::test]
    async fn on_linux_it_is_a_timerfd_not_a_tokio_timer() {
        let t = DriverTimer::new(Instant::now() + Duration::from_secs(1));
        assert!(matches!(t.inner, Inner::Fd(_)));
    }
}
