//! Busy polling: spend CPU after each message to answer the next one sooner.
//!
//! A process that sleeps in `epoll_wait` between messages pays for being
//! woken up when the next one arrives. On a VM whose idle vCPUs halt that
//! wake-up can be most of a loopback round trip, several times the actual
//! work (measurements in the repository's `BENCHMARKS.md`). [`BusyPoll`] keeps the runtime polling its I/O driver for
//! a *window* after the last activity instead of sleeping, so a reply that
//! arrives within the window is picked up without a wake-up. Outside the
//! window nothing spins and nothing is spent.
//!
//! It is off by default everywhere: `SessionBuilder::busy_poll` turns it on
//! for a session, `central --busy-poll <µs>` (courier-broker) for central.
//!
//! How it spins: a task that, while the window is open, yields to tokio,
//! whose scheduler then polls the I/O driver without blocking
//! (`epoll_wait(.., 0)`), and every few turns calls `sched_yield(2)` too, so
//! that other processes on the same CPU still run: three spinning processes
//! on two vCPUs take turns instead of waiting out a scheduler time slice.
//! This works on a **current-thread** runtime, where the spinning task and the I/O driver
//! share the thread. On a multi-thread runtime an idle worker sleeps in the
//! I/O driver and still has to be woken, so busy polling brings little
//! there.
//!
//! With or without it, a latency-critical loop is best run as a spawned
//! task rather than as the `block_on` future: a current-thread runtime
//! polls its I/O driver once more (`epoll_wait(.., 0)`) before it resumes a
//! woken `block_on` future, while it runs a woken task straight from its
//! queue (the benchmarks do so).

use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use tokio::sync::Notify;

/// The longest window: a session or central that spins longer after each
/// message holds a CPU for nothing (windows of tens of microseconds are what
/// busy polling is for). Longer ones are refused.
pub const MAX_WINDOW: Duration = Duration::from_secs(1);

/// Why `window` is no busy-polling window, if it is not.
pub(crate) fn check_window(window: Duration) -> Result<(), String> {
    if window > MAX_WINDOW {
        return Err(format!(
            "a window of {window:?} is longer than {MAX_WINDOW:?}: it would spin a CPU \
             between messages for nothing (tens of microseconds is what it is for)"
        ));
    }
    Ok(())
}

/// How many busy pollers of this process are spinning right now.
static SPINNING: AtomicUsize = AtomicUsize::new(0);

/// How many busy pollers of this process (sessions' and an embedded
/// central's) are spinning right now rather than waiting for activity: 0
/// once every window since the last message has passed. A diagnostic, and
/// how the tests check that idle busy polling costs nothing.
pub fn spinning() -> usize {
    SPINNING.load(Ordering::Acquire)
}

struct Shared {
    window_ns: u64,
    epoch: Instant,
    /// One more than the nanoseconds since `epoch` of the last activity;
    /// 0 = none yet.
    last: AtomicU64,
    /// The spinner is spinning (not waiting for activity).
    spinning: AtomicBool,
    closed: AtomicBool,
    wake: Notify,
}

impl Shared {
    fn now_ns(&self) -> u64 {
        self.epoch.elapsed().as_nanos() as u64
    }

    fn idle(&self) -> bool {
        match self.last.load(Ordering::Relaxed) {
            0 => true,
            last => self.now_ns().saturating_sub(last - 1) >= self.window_ns,
        }
    }
}

/// A spinning task on the current tokio runtime; it ends when this is
/// dropped. Report activity through [`BusyPoll::activity`] (or an
/// [`Activity`] handle).
pub struct BusyPoll {
    shared: Arc<Shared>,
}

/// A cheap handle that reports activity to a [`BusyPoll`].
#[derive(Clone)]
pub struct Activity {
    shared: Arc<Shared>,
}

impl std::fmt::Debug for BusyPoll {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("BusyPoll")
            .field("window", &Duration::from_nanos(self.shared.window_ns))
            .finish()
    }
}

impl std::fmt::Debug for Activity {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Activity(..)")
    }
}

impl BusyPoll {
    /// Starts spinning for `window` after every activity. Must be called
    /// within a tokio runtime.
    pub fn start(window: Duration) -> BusyPoll {
        if tokio::runtime::Handle::current().runtime_flavor()
            != tokio::runtime::RuntimeFlavor::CurrentThread
        {
            tracing::warn!(
                "busy polling on a multi-thread runtime: an idle worker still sleeps in the \
                 I/O driver, so expect little gain for the CPU it spends; use a current-thread \
                 runtime"
            );
        }
        let shared = Arc::new(Shared {
            window_ns: window.as_nanos().min(u64::MAX as u128) as u64,
            epoch: Instant::now(),
            last: AtomicU64::new(0),
            spinning: AtomicBool::new(false),
            closed: AtomicBool::new(false),
            wake: Notify::new(),
        });
        tokio::spawn(spin(shared.clone()));
        BusyPoll { shared }
    }

    /// The window.
    pub fn window(&self) -> Duration {
        Duration::from_nanos(self.shared.window_ns)
    }

    /// Something happened (a message was sent or received): keep polling
    /// for the window from now.
    pub fn activity(&self) {
        activity(&self.shared)
    }

    /// A handle for other tasks to report activity with.
    pub fn handle(&self) -> Activity {
        Activity {
            shared: self.shared.clone(),
        }
    }
}

impl Activity {
    /// See [`BusyPoll::activity`].
    pub fn activity(&self) {
        activity(&self.shared)
    }
}

fn activity(s: &Shared) {
    s.last.store(s.now_ns() + 1, Ordering::Relaxed);
    if !s.spinning.load(Ordering::Acquire) {
        // A stored permit if the spinner is not waiting yet: no lost wake-up.
        s.wake.notify_one();
    }
}

impl Drop for BusyPoll {
    fn drop(&mut self) {
        self.shared.closed.store(true, Ordering::Release);
        self.shared.wake.notify_one();
    }
}

/// Reactor polls between two `sched_yield`s. Measured with three spinning
/// processes on two vCPUs (`session-bench processes`, 4 B query, UNIX
/// socket): yielding every turn 42.9 µs, every 2nd 41.0, 4th 31.2, 8th
/// 25.2, 16th 32.3; never yielding 420 µs (a process sharing the CPU waits
/// out a scheduler time slice).
const YIELD_EVERY: u32 = 8;

impl Shared {
    /// Marks the spinner spinning or waiting, keeping [`SPINNING`] in step.
    fn set_spinning(&self, on: bool) {
        if self.spinning.swap(on, Ordering::AcqRel) != on {
            if on {
                SPINNING.fetch_add(1, Ordering::AcqRel);
            } else {
                SPINNING.fetch_sub(1, Ordering::AcqRel);
            }
        }
    }
}

/// Counts the spinner out of [`SPINNING`] however its task ends (closed,
/// or dropped with its runtime while spinning).
struct Parked(Arc<Shared>);

impl Drop for Parked {
    fn drop(&mut self) {
        self.0.set_spinning(false);
    }
}

async fn spin(s: Arc<Shared>) {
    let _parked = Parked(s.clone());
    // activity before this task first ran: it spins from the start, and
    // says so (else `spinning()` would count it out while it spins)
    if !s.idle() {
        s.set_spinning(true);
    }
    let mut turns = 0u32;
    loop {
        if s.closed.load(Ordering::Acquire) {
            return;
        }
        if s.idle() {
            s.set_spinning(false);
            // Activity between the check and the store above left a permit.
            if s.idle() {
                s.wake.notified().await;
            }
            s.set_spinning(true);
            continue;
        }
        turns = turns.wrapping_add(1);
        if turns % YIELD_EVERY == 0 {
            std::thread::yield_now();
        }
        tokio::task::yield_now().await;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Waits (bounded) until `f` holds.
    async fn eventually(what: &str, f: impl Fn() -> bool) {
        let deadline = tokio::time::Instant::now() + Duration::from_secs(10);
        while !f() {
            assert!(tokio::time::Instant::now() < deadline, "never: {what}");
            tokio::time::sleep(Duration::from_millis(1)).await;
        }
    }

    /// The spinner spins after activity, stops once the window has passed,
    /// and ends when the `BusyPoll` is dropped. Checked by waiting for each
    /// state, not by sleeping a set time, so that a loaded machine cannot
    /// make it fail: a window of a minute cannot pass unseen, and one of
    /// 20 ms must pass.
    #[tokio::test(flavor = "current_thread")]
    async fn spins_only_within_the_window_and_ends_when_dropped() {
        let long = BusyPoll::start(Duration::from_secs(60));
        let spinning = |bp: &BusyPoll| bp.shared.spinning.load(Ordering::Acquire);
        tokio::time::sleep(Duration::from_millis(10)).await;
        assert!(!spinning(&long), "no spinning before any activity");
        long.handle().activity();
        eventually("spinning after activity", || spinning(&long)).await;

        let short = BusyPoll::start(Duration::from_millis(20));
        let h = short.handle();
        h.activity();
        eventually("spinning after activity", || spinning(&short)).await;
        eventually("stopped after the window", || !spinning(&short)).await;
        short.activity();
        eventually("spinning again", || spinning(&short)).await;

        let weak = Arc::downgrade(&short.shared);
        drop(h);
        drop(short);
        eventually("the spinner task ended", || weak.upgrade().is_none()).await;
        drop(long);
    }
}
