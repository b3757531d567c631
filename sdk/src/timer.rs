//! Timers: [`Timer`] and its [`Tick`]s.

use crate::session_end::SessionEnd;
use futures::Stream;
use std::collections::VecDeque;
use std::pin::Pin;
use std::sync::Arc;
use std::task::{Context, Poll};
use std::time::Duration;

/// The longest period: longer ones are this (they never fire in practice).
const FAR: Duration = Duration::from_secs(30 * 365 * 86_400);

/// A timer tick: when it was due and when it fired.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Tick {
    /// The scheduled instant.
    pub scheduled: tokio::time::Instant,
    /// The instant the timer fired.
    pub fired: tokio::time::Instant,
}

/// A timer `Stream` (IPC_addTimer): ticks at fixed instants, `period`
/// apart. A tick that cannot fire in time (the task was busy, the process
/// stopped) fires once, late, and the instants missed meanwhile are
/// skipped: the next tick is the next instant still to come, so a control
/// loop that was held up does not send a burst of stale commands when it
/// resumes (C IPC's timers reschedule from when they fired, so they skip
/// too). [`Tick::scheduled`] says which instant a tick stands for.
/// It ends when its session is closed.
#[derive(Debug)]
#[must_use = "a timer ticks only for whoever reads it; dropping it removes it"]
pub struct Timer {
    interval: tokio::time::Interval,
    remaining: Option<u64>,
    queued: VecDeque<Tick>,
    end: Option<(Arc<SessionEnd>, u64)>,
}

impl Timer {
    /// A timer of the session whose timers `end` ends.
    pub(crate) fn of_session(end: &Arc<SessionEnd>, period: Duration, count: Option<u64>) -> Timer {
        let mut t = Timer::new(period, count);
        let id = end.next_id();
        t.end = Some((end.clone(), id));
        t
    }

    pub(crate) fn new(period: Duration, count: Option<u64>) -> Timer {
        // at most ~30 years (tokio's own "far future"): `Duration::MAX`
        // means "never" and must not overflow the clock
        let period = period.clamp(Duration::from_nanos(1), FAR);
        let mut interval = tokio::time::interval_at(tokio::time::Instant::now() + period, period);
        interval.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
        Timer {
            interval,
            remaining: count,
            queued: VecDeque::new(),
            end: None,
        }
    }
}

impl Drop for Timer {
    fn drop(&mut self) {
        if let Some((end, id)) = &self.end {
            end.forget(*id);
        }
    }
}

impl Stream for Timer {
    type Item = Tick;
    fn poll_next(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<Option<Tick>> {
        if self.remaining == Some(0) || self.end.as_ref().is_some_and(|(e, _)| e.ended()) {
            return Poll::Ready(None);
        }
        if let Some(t) = self.queued.pop_front() {
            return Poll::Ready(Some(t));
        }
        match self.interval.poll_tick(cx) {
            Poll::Ready(scheduled) => {
                if let Some(n) = self.remaining.as_mut() {
                    *n -= 1;
                }
                Poll::Ready(Some(Tick {
                    scheduled,
                    fired: tokio::time::Instant::now(),
                }))
            }
            Poll::Pending => {
                if let Some((end, id)) = &self.end {
                    if !end.wait(*id, cx) {
                        return Poll::Ready(None);
                    }
                }
                Poll::Pending
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use futures::StreamExt;

    #[tokio::test]
    async fn a_period_of_duration_max_is_never_and_does_not_overflow_the_clock() {
        let mut t = Timer::new(Duration::MAX, None);
        let next = tokio::time::timeout(Duration::from_millis(20), t.next()).await;
        assert!(next.is_err(), "{next:?}");
        let mut once = Timer::new(Duration::MAX, Some(1));
        assert!(tokio::time::timeout(Duration::from_millis(20), once.next())
            .await
            .is_err());
    }

    /// A timer held up for ten periods fires once, late, then goes on at
    /// the next instant to come: no burst of the missed ticks (audit 15:
    /// 750 stale commands in 12 ms after a 15 s stop).
    #[tokio::test(start_paused = true)]
    async fn a_late_timer_fires_once_and_skips_what_it_missed() {
        let period = Duration::from_millis(20);
        let start = tokio::time::Instant::now();
        let mut t = Timer::new(period, None);
        tokio::time::advance(Duration::from_millis(205)).await;
        let late = t.next().await.expect("a tick");
        assert_eq!(late.scheduled, start + period);
        // nothing more is due now
        assert_eq!(futures::FutureExt::now_or_never(t.next()), None);
        let next = t.next().await.expect("a tick");
        assert_eq!(next.scheduled, start + Duration::from_millis(220));
    }

    /// A session's close ends its timers at once, also one waiting for a
    /// tick far away, and those made after it.
    #[tokio::test]
    async fn ending_the_session_ends_its_timers_and_wakes_the_waiting() {
        let end = Arc::new(SessionEnd::default());
        let mut far = Timer::of_session(&end, Duration::from_secs(3600), None);
        let mut fast = Timer::of_session(&end, Duration::from_millis(1), None);
        assert!(fast.next().await.is_some());
        let waiting = tokio::spawn(async move { far.next().await });
        tokio::time::sleep(Duration::from_millis(20)).await;
        end.end();
        let got = tokio::time::timeout(Duration::from_secs(5), waiting).await;
        assert!(matches!(got, Ok(Ok(None))), "{got:?}");
        assert_eq!(fast.next().await, None);
        let mut later = Timer::of_session(&end, Duration::from_millis(1), None);
        assert_eq!(later.next().await, None);
        assert!(end.nobody_waits());
    }
}
