//! Timers: [`Timer`] and its [`Tick`]s.

use futures::Stream;
use std::collections::VecDeque;
use std::pin::Pin;
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

/// A timer `Stream` (IPC_addTimer): ticks at fixed instants, skipping none.
#[derive(Debug)]
pub struct Timer {
    interval: tokio::time::Interval,
    remaining: Option<u64>,
    queued: VecDeque<Tick>,
}

impl Timer {
    pub(crate) fn new(period: Duration, count: Option<u64>) -> Timer {
        // at most ~30 years (tokio's own "far future"): `Duration::MAX`
        // means "never" and must not overflow the clock
        let period = period.clamp(Duration::from_nanos(1), FAR);
        let mut interval = tokio::time::interval_at(tokio::time::Instant::now() + period, period);
        interval.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Burst);
        Timer {
            interval,
            remaining: count,
            queued: VecDeque::new(),
        }
    }
}

impl Stream for Timer {
    type Item = Tick;
    fn poll_next(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<Option<Tick>> {
        if self.remaining == Some(0) {
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
            Poll::Pending => Poll::Pending,
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
}
