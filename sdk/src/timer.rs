//! Timers: [`Timer`] and its [`Tick`]s.

use futures::Stream;
use std::collections::VecDeque;
use std::pin::Pin;
use std::task::{Context, Poll};
use std::time::Duration;

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
        let period = period.max(Duration::from_nanos(1));
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
