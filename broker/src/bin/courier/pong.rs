//! Round trips: `courier pong` answers every `courier::Ping` on one topic
//! with the same sample on another, and `courier ping --rtt` measures the
//! round trip, with percentiles (like ddsperf ping/pong, z_ping/z_pong).

use std::cell::{Cell, RefCell};
use std::time::{Duration, Instant};

use courier::{RecvError, Session, SessionEvent};
use futures::StreamExt;

use crate::cli::{kind, Kind, PingArgs, PongArgs};
use crate::connect::{connect, PROGRESS_EVERY};
use crate::ping::{now_ns, publish_acked, Matched};
use crate::stop::{count, run_session, Ended, Stop};
use crate::text::{out, progress};
use crate::values::Ping;
use crate::Result;

pub async fn pong(o: PongArgs, mut stop: Stop) -> Result<Ended> {
    let s = match connect(&o.url, &o.name, &mut stop).await? {
        Ok(s) => s,
        Err(ended) => return Ok(ended),
    };
    let n = Cell::new(0u64);
    let what = || format!("after answering {}", count(n.get(), "ping"));
    run_session(&s, &mut stop, answer(&s, &o, &n), what).await
}

async fn answer(s: &Session, o: &PongArgs, n: &Cell<u64>) -> Result<()> {
    let mut sub = s.subscribe::<Ping>(&o.topic).await?;
    let p = s.publisher::<Ping>(&o.reply_topic).build().await?;
    out("ready");
    let mut tick =
        tokio::time::interval_at(tokio::time::Instant::now() + PROGRESS_EVERY, PROGRESS_EVERY);
    let mut said = 0;
    loop {
        tokio::select! {
            r = sub.next() => match r {
                None | Some(Err(RecvError::Disconnected)) => return Err("the session ended".into()),
                Some(Ok(smp)) => {
                    // `ping --rtt`'s warm-up pings (seq 0) are answered but
                    // not counted: --count N answers N measured pings
                    let counted = smp.value.seq != 0;
                    let last = counted && o.count.is_some_and(|c| n.get() + 1 >= c);
                    let acked = last && kind(&o.url) == Kind::Dds;
                    publish_acked(&p, &smp.value, acked, "the last answer").await?;
                    if counted {
                        n.set(n.get() + 1);
                    }
                    if last {
                        break;
                    }
                }
                Some(Err(e)) => out(format_args!("skipped {e}")),
            },
            _ = tick.tick() => {
                if n.get() != said {
                    said = n.get();
                    out(format_args!("answered {said}"));
                }
            }
        }
    }
    out(format_args!("answered {}", n.get()));
    out("done");
    Ok(())
}

/// Round-trip times in microseconds, and the pings that got no answer.
#[derive(Default)]
pub struct Stats {
    rtts: Vec<u64>,
    lost: u64,
}

impl Stats {
    /// Adds one measurement.
    pub fn push(&mut self, d: Duration) {
        self.rtts.push(d.as_micros() as u64);
    }

    /// `n=100 min=41 p50=55 p90=70 p99=120 max=300 mean=57 lost=0` (µs).
    pub fn line(&self) -> String {
        let mut v = self.rtts.clone();
        v.sort_unstable();
        if v.is_empty() {
            return format!("n=0 lost={}", self.lost);
        }
        // nearest rank
        let pct = |p: usize| v[((v.len() * p).div_ceil(100)).clamp(1, v.len()) - 1];
        let mean = v.iter().sum::<u64>() / v.len() as u64;
        format!(
            "n={} min={} p50={} p90={} p99={} max={} mean={mean} lost={}",
            v.len(),
            v[0],
            pct(50),
            pct(90),
            pct(99),
            v[v.len() - 1],
            self.lost
        )
    }
}

pub async fn rtt(o: PingArgs, mut stop: Stop) -> Result<Ended> {
    let s = match connect(&o.url, &o.name, &mut stop).await? {
        Ok(s) => s,
        Err(ended) => return Ok(ended),
    };
    let all = RefCell::new(Stats::default());
    let what = || {
        let a = all.borrow();
        format!(
            "after {}: {} (us)",
            count(a.rtts.len() as u64, "round trip"),
            a.line()
        )
    };
    run_session(&s, &mut stop, round_trips(&s, &o, &all), what).await
}

async fn round_trips(s: &Session, o: &PingArgs, all: &RefCell<Stats>) -> Result<()> {
    let mut ev = s.events();
    let mut replies = s.subscribe::<Ping>(&o.reply_topic).await?;
    let p = s.publisher::<Ping>(&o.topic).build().await?;
    // an XRCE agent tells its clients nothing of the readers matched:
    // warm up without knowing whether a pong is there
    let xrce = s.xrce().is_ok();
    if !xrce {
        s.watch_handlers(&o.topic).await?;
    }
    out("ready");
    let text = "x".repeat(o.size as usize);
    let timeout = Duration::from_millis(o.timeout);
    // a pong first: its subscription, then (DDS) its publication matched
    // with our reader, shown by an answer to a warm-up ping (seq 0, not
    // counted)
    let mut matched = Matched(None);
    let mut n = if xrce {
        1
    } else {
        s.num_handlers(&o.topic).await?.unsigned_abs()
    };
    let started = Instant::now();
    let mut warm_up = tokio::time::interval(Duration::from_millis(100));
    let mut prog =
        tokio::time::interval_at(tokio::time::Instant::now() + PROGRESS_EVERY, PROGRESS_EVERY);
    loop {
        tokio::select! {
            _ = warm_up.tick(), if n > 0 => {
                p.publish(&Ping { seq: 0, stamp_ns: now_ns(), text: String::new() }).await?;
            }
            _ = prog.tick() => progress(format_args!(
                "no answer on {:?} for {} s (is `courier pong` running?)",
                o.reply_topic,
                started.elapsed().as_secs()
            )),
            Some(e) = ev.next() => {
                if let SessionEvent::HandlersChanged { msg, count } = e {
                    if msg == o.topic {
                        n = count.unsigned_abs();
                        matched.set(n as usize);
                    }
                }
            }
            r = replies.next() => match r {
                None | Some(Err(RecvError::Disconnected)) => return Err("the session ended".into()),
                Some(Ok(smp)) if smp.value.seq == 0 => break,
                _ => {}
            },
        }
    }
    if matched.0.is_none() && !xrce {
        matched.set(n as usize);
    }
    let period = o.period.map(Duration::from_millis);
    let mut second = Stats::default();
    let mut report = Instant::now() + Duration::from_secs(1);
    let mut seq = 0u32;
    loop {
        seq = seq.wrapping_add(1).max(1);
        let sent = Instant::now();
        p.publish(&Ping {
            seq,
            stamp_ns: now_ns(),
            text: text.clone(),
        })
        .await?;
        let answered = tokio::time::timeout(timeout, async {
            loop {
                match replies.next().await {
                    None | Some(Err(RecvError::Disconnected)) => return Err("the session ended"),
                    Some(Ok(smp)) if smp.value.seq == seq => return Ok(()),
                    // a late answer to an earlier ping, or a warm-up one
                    _ => {}
                }
            }
        })
        .await;
        match answered {
            Ok(r) => {
                r?;
                let us = sent.elapsed().as_micros() as u64;
                second.rtts.push(us);
                all.borrow_mut().rtts.push(us);
            }
            Err(_) => {
                second.lost += 1;
                all.borrow_mut().lost += 1;
            }
        }
        if Instant::now() >= report {
            out(format_args!("rtt {} (us)", second.line()));
            second = Stats::default();
            report = Instant::now() + Duration::from_secs(1);
        }
        let done = all.borrow().rtts.len() as u64 + all.borrow().lost;
        if o.count.is_some_and(|c| done >= c) {
            break;
        }
        if let Some(d) = period {
            tokio::time::sleep(d.saturating_sub(sent.elapsed())).await;
        }
    }
    out(format_args!("total {} (us)", all.borrow().line()));
    out("done");
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percentiles_by_nearest_rank() {
        let s = Stats {
            rtts: (1..=100).rev().collect(),
            lost: 2,
        };
        assert_eq!(
            s.line(),
            "n=100 min=1 p50=50 p90=90 p99=99 max=100 mean=50 lost=2"
        );
        let one = Stats {
            rtts: vec![7],
            lost: 0,
        };
        assert_eq!(
            one.line(),
            "n=1 min=7 p50=7 p90=7 p99=7 max=7 mean=7 lost=0"
        );
        assert_eq!(Stats::default().line(), "n=0 lost=0");
    }
}
