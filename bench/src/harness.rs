//! What the benchmark harnesses share: percentiles, the RESULT lines
//! their roles print, a timeout kept off the measured runtime, and the
//! machine's load while a row runs.

use std::collections::HashMap;
use std::time::{Duration, Instant};

pub fn percentile(sorted: &[u64], p: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    let i = ((sorted.len() as f64 - 1.0) * p).round() as usize;
    sorted[i] as f64
}

/// A timeout for the round-trip roles, kept off the measured runtime.
///
/// A tokio timer would be measured with the library: while one is pending
/// the runtime waits in `epoll_wait` with a timeout, and the kernel arms and
/// cancels a timer for each wait (~0.6 µs per wake-up on the VM of
/// BENCHMARKS.md). ddsperf keeps its timers on threads of their own too.
/// Here a thread checks every quarter of `limit` whether [`Watchdog::kick`]
/// was called since its last look; after `limit` without one,
/// [`Watchdog::expired`] completes (once per expiry).
pub struct Watchdog {
    shared: std::sync::Arc<WatchdogShared>,
}

#[derive(Default)]
struct WatchdogShared {
    kicks: std::sync::atomic::AtomicU64,
    fired: std::sync::atomic::AtomicBool,
    stop: std::sync::atomic::AtomicBool,
    waker: futures::task::AtomicWaker,
}

impl Watchdog {
    pub fn start(limit: Duration) -> Self {
        use std::sync::atomic::Ordering::Relaxed;
        let shared = std::sync::Arc::new(WatchdogShared::default());
        let s = shared.clone();
        std::thread::spawn(move || {
            let step = limit / 4;
            let mut seen = s.kicks.load(Relaxed);
            let mut quiet_since = Instant::now();
            while !s.stop.load(Relaxed) {
                std::thread::sleep(step);
                let k = s.kicks.load(Relaxed);
                if k != seen {
                    seen = k;
                    quiet_since = Instant::now();
                } else if quiet_since.elapsed() >= limit {
                    quiet_since = Instant::now();
                    s.fired.store(true, Relaxed);
                    s.waker.wake();
                }
            }
        });
        Watchdog { shared }
    }

    pub fn kick(&self) {
        self.shared
            .kicks
            .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    }

    pub async fn expired(&self) {
        std::future::poll_fn(|cx| {
            self.shared.waker.register(cx.waker());
            if self
                .shared
                .fired
                .swap(false, std::sync::atomic::Ordering::Relaxed)
            {
                std::task::Poll::Ready(())
            } else {
                std::task::Poll::Pending
            }
        })
        .await
    }
}

impl Drop for Watchdog {
    fn drop(&mut self) {
        self.shared
            .stop
            .store(true, std::sync::atomic::Ordering::Relaxed);
    }
}

pub fn result_line(out: &str) -> Option<HashMap<String, String>> {
    let line = out.lines().rev().find(|l| l.starts_with("RESULT "))?;
    Some(
        line.split_whitespace()
            .skip(1)
            .filter_map(|kv| kv.split_once('='))
            .map(|(k, v)| (k.to_string(), v.to_string()))
            .collect(),
    )
}

pub fn num(m: &HashMap<String, String>, k: &str) -> Option<f64> {
    m.get(k).and_then(|v| v.parse().ok())
}

/// CPU time in clock ticks (USER_HZ): busy time of the whole machine
/// (/proc/stat) and this process's own plus its waited-for children's
/// (/proc/self/stat). What is busy beyond ours is someone else's load.
pub fn cpu_ticks() -> Option<(u64, u64)> {
    let stat = std::fs::read_to_string("/proc/stat").ok()?;
    let cpu: Vec<u64> = stat
        .lines()
        .next()?
        .split_whitespace()
        .skip(1)
        .filter_map(|v| v.parse().ok())
        .collect();
    // user nice system idle iowait irq softirq steal
    let busy = cpu.get(..8)?.iter().sum::<u64>() - cpu[3] - cpu[4];
    let me = std::fs::read_to_string("/proc/self/stat").ok()?;
    // fields after the command: state (3), ppid (4), …, utime (14), stime,
    // cutime, cstime (17)
    let f: Vec<&str> = me.rsplit_once(')')?.1.split_whitespace().collect();
    let mut ours = 0;
    for v in f.get(11..15)? {
        ours += v.parse::<u64>().ok()?;
    }
    Some((busy, ours))
}

/// Other processes' CPU use between two [`cpu_ticks`] snapshots, in CPUs.
pub fn foreign_load(a: Option<(u64, u64)>, b: Option<(u64, u64)>, secs: f64) -> Option<f64> {
    let ((b0, o0), (b1, o1)) = (a?, b?);
    let ticks = (b1 - b0).saturating_sub(o1 - o0) as f64;
    Some(ticks / 100.0 / secs.max(1e-3))
}

/// A rate in samples per second, as the tables print it.
pub fn fmt_rate(r: f64) -> String {
    if r >= 1e6 {
        format!("{:.2} M/s", r / 1e6)
    } else if r >= 1e3 {
        format!("{:.1} k/s", r / 1e3)
    } else {
        format!("{r:.0} /s")
    }
}
