//! `courier hz` and `courier bw`: the rate, gaps and sizes of a topic's
//! samples over a sliding window, reported every second (like `ros2 topic
//! hz` and `ros2 topic bw`).

use std::cell::Cell;
use std::collections::VecDeque;
use std::time::{Duration, Instant};

use courier::Session;
use futures::StreamExt;

use crate::cli::{kind, Kind, RateArgs};
use crate::connect::{connect, target, PROGRESS_EVERY};
use crate::dds_type::DdsType;
use crate::stop::{count, run_session, Ended, Stop};
use crate::text::{out, progress};
use crate::wait::Discovery;
use crate::Result;

/// What is reported.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mode {
    /// Rate and intervals.
    Hz,
    /// Bandwidth and sizes.
    Bw,
}

pub async fn run(o: RateArgs, mode: Mode, mut stop: Stop) -> Result<Ended> {
    let s = match connect(&o.url, &o.name, &mut stop).await? {
        Ok(s) => s,
        Err(ended) => return Ok(ended),
    };
    let n = Cell::new(0u64);
    let what = || format!("after {}", count(n.get(), "sample"));
    run_session(&s, &mut stop, measure(&s, &o, mode, &n), what).await
}

/// The last samples: when each arrived and its size.
pub struct Window {
    cap: usize,
    samples: VecDeque<(Instant, usize)>,
}

impl Window {
    pub fn new(cap: usize) -> Self {
        Window {
            cap: cap.max(2),
            samples: VecDeque::new(),
        }
    }

    pub fn push(&mut self, at: Instant, size: usize) {
        if self.samples.len() == self.cap {
            self.samples.pop_front();
        }
        self.samples.push_back((at, size));
    }

    /// The intervals between consecutive samples, in seconds.
    fn intervals(&self) -> Vec<f64> {
        self.samples
            .iter()
            .zip(self.samples.iter().skip(1))
            .map(|(a, b)| (b.0 - a.0).as_secs_f64())
            .collect()
    }

    /// `rate 10.00 Hz min 0.099 s max 0.101 s std dev 0.00050 s window 11
    /// gaps 0`: gaps are intervals longer than `gap` (default twice the
    /// mean interval). `None` until two samples came.
    pub fn hz(&self, gap: Option<Duration>) -> Option<String> {
        let iv = self.intervals();
        if iv.is_empty() {
            return None;
        }
        let n = iv.len() as f64;
        let mean = iv.iter().sum::<f64>() / n;
        let var = iv.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n;
        let min = iv.iter().copied().fold(f64::INFINITY, f64::min);
        let max = iv.iter().copied().fold(0.0, f64::max);
        let limit = gap.map_or(2.0 * mean, |g| g.as_secs_f64());
        let gaps = iv.iter().filter(|x| **x > limit).count();
        let rate = if mean > 0.0 {
            1.0 / mean
        } else {
            f64::INFINITY
        };
        Some(format!(
            "rate {rate:.2} Hz min {min:.3} s max {max:.3} s std dev {:.5} s window {} gaps {gaps}",
            var.sqrt(),
            self.samples.len()
        ))
    }

    /// `bw 1.25 KB/s from 10 samples size mean 125 B min 125 B max 125 B
    /// window 10`. `None` until two samples came.
    pub fn bw(&self) -> Option<String> {
        let (first, last) = (self.samples.front()?, self.samples.back()?);
        let span = (last.0 - first.0).as_secs_f64();
        if self.samples.len() < 2 || span <= 0.0 {
            return None;
        }
        let sizes = self.samples.iter().map(|s| s.1);
        let total: usize = sizes.clone().sum();
        let n = self.samples.len();
        // the bytes of every sample after the first arrived within the span
        let rate = (total - first.1) as f64 / span;
        Some(format!(
            "bw {} from {} size mean {} min {} max {} window {n}",
            bytes_per_sec(rate),
            count(n as u64, "sample"),
            size(total as f64 / n as f64),
            size(sizes.clone().min().unwrap_or(0) as f64),
            size(sizes.max().unwrap_or(0) as f64),
        ))
    }
}

fn size(b: f64) -> String {
    if b < 1000.0 {
        format!("{b:.0} B")
    } else if b < 1e6 {
        format!("{:.2} KB", b / 1e3)
    } else {
        format!("{:.2} MB", b / 1e6)
    }
}

fn bytes_per_sec(b: f64) -> String {
    format!("{}/s", size(b))
}

async fn measure(s: &Session, o: &RateArgs, mode: Mode, n: &Cell<u64>) -> Result<()> {
    let mut ev = s.events();
    let mut sub = match &o.type_name {
        Some(t) => {
            let ty = DdsType::new(o.format.as_ref(), Some(t))?;
            s.subscribe_raw_as(&o.topic, &ty.type_info()).await?
        }
        None => s.subscribe_raw(&o.topic).await?,
    };
    let started = Instant::now();
    let until = o
        .duration
        .map(|d| courier_wire::time::later(started, Duration::from_secs(d)));
    let mut window = Window::new(o.window as usize);
    let gap = o.gap.map(Duration::from_millis);
    let mut found = Discovery::default();
    let mut tick =
        tokio::time::interval_at(tokio::time::Instant::now() + PROGRESS_EVERY, PROGRESS_EVERY);
    // samples since the last report
    let mut fresh = 0u64;
    let report = |w: &Window| match mode {
        Mode::Hz => w.hz(gap),
        Mode::Bw => w.bw(),
    };
    loop {
        let sleep = async {
            match until {
                Some(t) => tokio::time::sleep_until(t.into()).await,
                None => std::future::pending().await,
            }
        };
        tokio::select! {
            _ = sleep => break,
            smp = sub.recv() => {
                let Some(smp) = smp else {
                    return Err("the session ended".into());
                };
                window.push(Instant::now(), smp.data.len());
                n.set(n.get() + 1);
                fresh += 1;
                if o.count.is_some_and(|c| n.get() >= c) {
                    break;
                }
            }
            Some(e) = ev.next() => found.update(&e),
            _ = tick.tick() => {
                if n.get() == 0 {
                    let secs = started.elapsed().as_secs();
                    match kind(&o.url) {
                        Kind::Dds => progress(format_args!(
                            "no sample of {:?} for {secs} s: {}",
                            o.topic,
                            found.summary(&o.topic, true)
                        )),
                        Kind::Ipc => progress(format_args!(
                            "no message {:?} from {} for {secs} s",
                            o.topic,
                            target(&o.url)
                        )),
                    }
                } else if fresh == 0 {
                    out("no new samples");
                } else if let Some(line) = report(&window) {
                    fresh = 0;
                    out(line);
                }
            }
        }
    }
    if fresh > 0 {
        if let Some(line) = report(&window) {
            out(line);
        }
    } else if n.get() == 0 {
        // the end says so, whether or not progress went to stderr
        out(format_args!(
            "no samples in {} s",
            started.elapsed().as_secs()
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reports_over_the_window() {
        let t0 = Instant::now();
        let mut w = Window::new(4);
        assert_eq!(w.hz(None), None);
        assert_eq!(w.bw(), None);
        for (i, ms) in [0u64, 100, 200, 300, 900].into_iter().enumerate() {
            w.push(t0 + Duration::from_millis(ms), 100 + i);
        }
        // the window keeps 4 samples: 100, 200, 300, 900 ms
        assert_eq!(
            w.hz(None).unwrap(),
            "rate 3.75 Hz min 0.100 s max 0.600 s std dev 0.23570 s window 4 gaps 1"
        );
        assert!(w
            .hz(Some(Duration::from_secs(1)))
            .unwrap()
            .ends_with("gaps 0"));
        // 102+103+104 bytes after the first in 0.8 s
        assert_eq!(
            w.bw().unwrap(),
            "bw 386 B/s from 4 samples size mean 102 B min 101 B max 104 B window 4"
        );
        assert_eq!(size(1500.0), "1.50 KB");
        assert_eq!(size(2.5e6), "2.50 MB");
    }
}
