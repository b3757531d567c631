//! The one timer of a driver loop around a sans-I/O state machine (the
//! RTPS driver, the XRCE client's, the broker's XRCE agent).
//!
//! A tokio timer makes the runtime wait in `epoll_wait` with a timeout, and
//! the kernel arms and cancels a high-resolution timer for every such wait:
//! on the 2-vCPU VM of BENCHMARKS.md that cost ~0.6 µs per wake-up, 1.2 µs
//! per same-core RTPS round trip (21.4 → 20.2 µs without it). A driver's
//! deadlines (heartbeats, acknowledgements, housekeeping, leases) are
//! milliseconds away and rarely move closer, so on Linux the timer is a
//! `timerfd` that sits in the runtime's epoll set like a socket: armed when
//! the deadline moves earlier, and left alone when it moves later (it then
//! fires early once, the driver finds nothing due and arms it again). A
//! runtime with no timers of its own then waits with no timeout at all,
//! and a loop keeps one timer instead of making one (a timer-wheel insert
//! and removal) per turn.
//!
//! Elsewhere, or when a `timerfd` cannot be made, it is a tokio `Sleep`.

use std::future::Future as _;
use std::pin::Pin;
use std::task::{ready, Context, Poll};
use std::time::Instant;

/// A driver loop's timer: set it to the machine's next deadline before
/// each wait, and wait on [`DriverTimer::poll_fired`] with the loop's other
/// inputs; when it fires, hand the machine the time and let it find what is
/// due (the timer may fire early, never late).
pub struct DriverTimer {
    inner: Inner,
}

enum Inner {
    #[cfg(target_os = "linux")]
    Fd(fd::TimerFd),
    Sleep(Pin<Box<tokio::time::Sleep>>),
}

impl DriverTimer {
    /// A timer that fires at `at` (or a little after).
    pub fn new(at: Instant) -> Self {
        let mut t = Self::quiet();
        t.set(at);
        t
    }

    /// A timer with nothing due yet ([`set`](Self::set) or
    /// [`set_next`](Self::set_next) before the first wait).
    pub fn quiet() -> Self {
        #[cfg(target_os = "linux")]
        match fd::TimerFd::new() {
            Ok(t) => {
                return DriverTimer {
                    inner: Inner::Fd(t),
                }
            }
            Err(e) => tracing::debug!("no timerfd ({e}): a tokio timer instead"),
        }
        DriverTimer {
            inner: Inner::Sleep(Box::pin(tokio::time::sleep(FAR))),
        }
    }

    /// Fires no later than `at`; may fire earlier (after an earlier
    /// deadline that was since given up), so the caller checks what is due.
    pub fn set(&mut self, at: Instant) {
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

    /// Nothing is due: a deadline already given to the kernel may still
    /// fire once (early, as after [`set`](Self::set) to a later one), and
    /// then the timer stays quiet until set again.
    pub fn idle(&mut self) {
        match &mut self.inner {
            #[cfg(target_os = "linux")]
            Inner::Fd(_) => {}
            Inner::Sleep(s) => {
                // a fired `Sleep` stays ready: move it out of the way
                if s.deadline() <= tokio::time::Instant::now() {
                    s.as_mut().reset(tokio::time::Instant::now() + FAR);
                }
            }
        }
    }

    /// [`set`](Self::set) for a machine whose next deadline may be none
    /// ([`idle`](Self::idle)).
    pub fn set_next(&mut self, at: Option<Instant>) {
        match at {
            Some(at) => self.set(at),
            None => self.idle(),
        }
    }

    /// Ready once the timer fired; register the waker otherwise.
    pub fn poll_fired(&mut self, cx: &mut Context<'_>) -> Poll<()> {
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

    /// Waits until the timer fires.
    pub async fn fired(&mut self) {
        std::future::poll_fn(|cx| self.poll_fired(cx)).await
    }
}

#[cfg(target_os = "linux")]
use crate::sys::timerfd as fd;

/// Where an idle tokio-`Sleep` timer is parked.
const FAR: std::time::Duration = std::time::Duration::from_secs(86_400);

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

    #[tokio::test]
    async fn an_idle_timer_stays_quiet_after_it_fired() {
        for fd in [true, false] {
            let mut t = DriverTimer::new(Instant::now());
            if !fd {
                t.inner = Inner::Sleep(Box::pin(tokio::time::sleep_until(Instant::now().into())));
            }
            tokio::time::timeout(Duration::from_secs(5), t.fired())
                .await
                .expect("fired");
            t.set_next(None);
            let quiet = tokio::time::timeout(50 * MS, t.fired()).await;
            assert!(quiet.is_err(), "an idle timer fired (timerfd: {fd})");
            t.set_next(Some(Instant::now() + 10 * MS));
            tokio::time::timeout(Duration::from_secs(5), t.fired())
                .await
                .expect("fired once set again");
        }
    }

    #[cfg(target_os = "linux")]
    #[tokio::test]
    async fn on_linux_it_is_a_timerfd_not_a_tokio_timer() {
        let t = DriverTimer::new(Instant::now() + Duration::from_secs(1));
        assert!(matches!(t.inner, Inner::Fd(_)));
    }
}
