//! `courier perf pub | sub`: throughput and one-way latency, like
//! Cyclone DDS's `ddsperf pub` / `ddsperf sub` and zenoh's
//! `z_pub_thr` / `z_sub_thr`.
//!
//! On DDS the samples are ddsperf's own: type `KeyedSeq` (`seq`, `@key
//! keyval`, `sequence<octet> baggage`, XCDR1) on ddsperf's topic names
//! (`DDSPerfRDataKS`, or `DDSPerfUDataKS` with `--best-effort`) and QoS
//! (keep-all), so `courier perf sub` measures a `ddsperf pub` and `ddsperf
//! sub` measures a `courier perf pub`. On IPC the same fields travel as
//! the message `DDSPerfRDataKS` with the format `{uint, uint, uint,
//! <ubyte:3>}` (an IPC variable array takes its length from a field).
//!
//! Latency is one way, from each sample's source timestamp (DDS) or the
//! time the publisher stamped into the IPC message, so publisher and
//! subscriber must share a clock (one machine).

use std::cell::RefCell;
use std::collections::HashMap;
use std::time::{Duration, Instant, SystemTime};

use clap::{Args, Subcommand};
use courier::{IpcMessage, RecvError, Session, SessionEvent};
use futures::StreamExt;

use crate::cli::{kind, session_url, Kind};
use crate::connect::connect;
use crate::ping::{publish_acked, Matched};
use crate::pong::Stats;
use crate::stop::{count, run_session, Ended, Stop};
use crate::text::{incompatible_line, out, progress, type_mismatch_line};
use crate::Result;

/// `courier perf`: throughput and latency.
#[derive(Args, Debug)]
pub struct PerfArgs {
    #[command(subcommand)]
    pub mode: PerfMode,
}

impl PerfArgs {
    /// The flags both directions take.
    pub fn common(&self) -> &PerfCommon {
        match &self.mode {
            PerfMode::Pub(o) => &o.common,
            PerfMode::Sub(o) => &o.common,
        }
    }
}

/// What `courier perf` does.
#[derive(Subcommand, Debug)]
pub enum PerfMode {
    /// Publish samples as fast as the readers take them, or at --rate
    /// (like ddsperf pub). IPC: as fast as central takes them; central
    /// queues what a slower subscriber has not taken yet (as C's does), so
    /// the subscriber's latency grows instead
    Pub(PerfPubArgs),
    /// Count samples and report rate, bandwidth, losses and one-way latency
    /// every second (like ddsperf sub)
    Sub(PerfSubArgs),
}

/// Flags both directions take.
#[derive(Args, Debug)]
pub struct PerfCommon {
    /// Session URL (ipc://…, rtps://…, xrce+udp://…)
    #[arg(value_name = "URL", value_parser = session_url)]
    pub url: String,
    /// Topic (default: ddsperf's, DDSPerfRDataKS or DDSPerfUDataKS)
    #[arg(long)]
    pub topic: Option<String>,
    /// Best-effort samples (ddsperf's -u); reliable by default
    #[arg(long)]
    pub best_effort: bool,
    /// Stop after this many seconds
    #[arg(long, value_name = "S", value_parser = positive_secs)]
    pub secs: Option<f64>,
    /// Stop after this many samples
    #[arg(long, value_name = "N", value_parser = crate::cli::at_least_1)]
    pub count: Option<u64>,
    /// Module / participant name, %p this process's id (default:
    /// courier-perf-pub-%p or courier-perf-sub-%p)
    #[arg(long)]
    pub name: Option<String>,
}

/// `courier perf pub`.
#[derive(Args, Debug)]
pub struct PerfPubArgs {
    #[command(flatten)]
    pub common: PerfCommon,
    /// Payload bytes per sample (the `baggage`; ddsperf's -z less its 12-byte header).
    /// On ipc:// the send time travels in its first 8 bytes: latency needs 8 or more
    #[arg(long, value_name = "BYTES", default_value_t = 0, value_parser = clap::value_parser!(u32).range(..=MAX_SIZE as i64))]
    pub size: u32,
    /// Samples per second; 0 publishes as fast as the readers take them
    /// (IPC: as fast as central takes them)
    #[arg(long, value_name = "HZ", default_value_t = 0.0, value_parser = rate, allow_negative_numbers = true)]
    pub rate: f64,
    /// Start once this many readers (subscribing modules on IPC) matched
    #[arg(long, value_name = "N", default_value_t = 1)]
    pub readers: u32,
}

/// `courier perf sub`.
#[derive(Args, Debug)]
pub struct PerfSubArgs {
    #[command(flatten)]
    pub common: PerfCommon,
}

/// The largest `--size`: what fits an IPC message and a DDS sample with
/// room to spare.
const MAX_SIZE: u32 = 64 * 1024 * 1024;

fn positive_secs(s: &str) -> std::result::Result<f64, String> {
    match s.parse::<f64>() {
        // (a billion seconds is 31 years: longer would overflow the clock)
        Ok(v) if v > 0.0 && v <= 1e9 => Ok(v),
        _ => Err(format!(
            "{s:?} is not a number of seconds above 0 and at most 1e9"
        )),
    }
}

fn rate(s: &str) -> std::result::Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if v >= 0.0 && v.is_finite() => Ok(v),
        _ => Err(format!(
            "{s:?} is not a rate in samples per second (0 or more)"
        )),
    }
}

/// ddsperf's `KeyedSeq` (its `ddsperf_types.idl`): the samples of its
/// `…KS` topics.
#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "KeyedSeq")]
pub struct KeyedSeq {
    pub seq: u32,
    #[ipc(key)]
    pub keyval: u32,
    pub baggage: Vec<u8>,
}

/// The same fields as an IPC message (an IPC variable array needs a
/// length field), with the publisher's clock in front of the baggage.
#[derive(IpcMessage, Debug, Clone, PartialEq)]
pub struct IpcSeq {
    pub seq: u32,
    pub keyval: u32,
    pub n: u32,
    /// The first 8 bytes: nanoseconds since the Unix epoch when sent
    /// (little-endian), when there is room for them.
    #[ipc(len = "n")]
    pub baggage: Vec<u8>,
}

/// What both sample types offer `perf`.
trait PerfSample: IpcMessage + Send + Sync + 'static {
    fn new(seq: u32, baggage: Vec<u8>) -> Self;
    fn seq(&self) -> u32;
    fn keyval(&self) -> u32;
    fn size(&self) -> usize;
    /// When it was sent, if the sample says.
    fn stamp(&self) -> Option<SystemTime>;
}

impl PerfSample for KeyedSeq {
    fn new(seq: u32, baggage: Vec<u8>) -> Self {
        KeyedSeq {
            seq,
            keyval: 0,
            baggage,
        }
    }
    fn seq(&self) -> u32 {
        self.seq
    }
    fn keyval(&self) -> u32 {
        self.keyval
    }
    fn size(&self) -> usize {
        // ddsperf counts seq, keyval and the baggage's length
        12 + self.baggage.len()
    }
    fn stamp(&self) -> Option<SystemTime> {
        None
    }
}

impl PerfSample for IpcSeq {
    fn new(seq: u32, mut baggage: Vec<u8>) -> Self {
        if baggage.len() >= 8 {
            let ns = crate::ping::now_ns();
            baggage[..8].copy_from_slice(&ns.to_le_bytes());
        }
        IpcSeq {
            seq,
            keyval: 0,
            n: baggage.len() as u32,
            baggage,
        }
    }
    fn seq(&self) -> u32 {
        self.seq
    }
    fn keyval(&self) -> u32 {
        self.keyval
    }
    fn size(&self) -> usize {
        12 + self.baggage.len()
    }
    fn stamp(&self) -> Option<SystemTime> {
        let b: [u8; 8] = self.baggage.get(..8)?.try_into().ok()?;
        Some(SystemTime::UNIX_EPOCH + Duration::from_nanos(u64::from_le_bytes(b)))
    }
}

/// The topic: `--topic`, else ddsperf's for the reliability asked.
fn topic(o: &PerfCommon) -> String {
    o.topic
        .clone()
        .unwrap_or_else(|| format!("DDSPerf{}DataKS", if o.best_effort { 'U' } else { 'R' }))
}

pub async fn run(a: PerfArgs, stop: Stop) -> Result<Ended> {
    match a.mode {
        PerfMode::Pub(o) if kind(&o.common.url) == Kind::Ipc => publish::<IpcSeq>(o, stop).await,
        PerfMode::Pub(o) => publish::<KeyedSeq>(o, stop).await,
        PerfMode::Sub(o) if kind(&o.common.url) == Kind::Ipc => subscribe::<IpcSeq>(o, stop).await,
        PerfMode::Sub(o) => subscribe::<KeyedSeq>(o, stop).await,
    }
}

/// Counts of one reporting period, or of the whole run.
#[derive(Default)]
struct Tally {
    samples: u64,
    bytes: u64,
    lost: u64,
}

impl Tally {
    fn add(&mut self, bytes: usize) {
        self.samples += 1;
        self.bytes += bytes as u64;
    }

    /// `123456 samples/s 15.80 Mbit/s` over `secs`.
    fn rate(&self, secs: f64) -> String {
        let secs = secs.max(1e-9);
        format!(
            "{:.0} samples/s {:.2} Mbit/s",
            self.samples as f64 / secs,
            self.bytes as f64 * 8.0 / secs / 1e6
        )
    }
}

async fn publish<T: PerfSample>(o: PerfPubArgs, mut stop: Stop) -> Result<Ended> {
    let c = &o.common;
    let name = c.name.as_deref().unwrap_or("courier-perf-pub-%p");
    let s = match connect(&c.url, name, &mut stop).await? {
        Ok(s) => s,
        Err(ended) => return Ok(ended),
    };
    let total = RefCell::new(Tally::default());
    let what = || format!("after {} sent", count(total.borrow().samples, "sample"));
    run_session(&s, &mut stop, send::<T>(&s, &o, &total), what).await
}

async fn send<T: PerfSample>(s: &Session, o: &PerfPubArgs, total: &RefCell<Tally>) -> Result<()> {
    let c = &o.common;
    let topic = topic(c);
    let mut b = s.publisher::<T>(&topic).keep_all();
    b = if c.best_effort {
        b.best_effort()
    } else {
        b.reliable()
    };
    // listening first: what the endpoint's creation reports is not missed
    let mut ev = s.events();
    let p = b.build().await?;
    // an XRCE agent tells its clients nothing of the readers matched
    let xrce = s.xrce().is_ok();
    let mut matched = Matched(None);
    if !xrce && o.readers > 0 {
        s.watch_handlers(&topic).await?;
        let mut n = s.num_handlers(&topic).await?.unsigned_abs();
        matched.set(n as usize);
        let waiting = Instant::now();
        // --secs bounds the whole run, the wait for readers included
        let give_up = async {
            match c.secs {
                Some(x) => tokio::time::sleep(Duration::from_secs_f64(x)).await,
                None => std::future::pending().await,
            }
        };
        tokio::pin!(give_up);
        while n < o.readers {
            tokio::select! {
                _ = &mut give_up => {
                    return Err(format!(
                        "{} of {topic:?} within --secs {}: nothing was measured",
                        if n == 0 { "no reader".to_string() } else { format!("only {n} of {} readers", o.readers) },
                        c.secs.unwrap_or_default()
                    )
                    .into());
                }
                Some(e) = ev.next() => match e {
                    SessionEvent::HandlersChanged { msg, count } if msg == topic => {
                        n = count.unsigned_abs();
                        matched.set(n as usize);
                    }
                    SessionEvent::IncompatibleQos { msg, remote, reason } if msg == topic => {
                        out(incompatible_line(remote, &reason))
                    }
                    SessionEvent::TypeMismatch { topic: t, remote, local_type, remote_type } if t == topic => {
                        out(type_mismatch_line(remote, &local_type, &remote_type))
                    }
                    _ => {}
                },
                _ = tokio::time::sleep(Duration::from_secs(2)) => progress(format_args!(
                    "waiting for {} on {topic:?} for {} s ({} so far)",
                    count(u64::from(o.readers), "reader"),
                    waiting.elapsed().as_secs(),
                    n
                )),
            }
        }
    }
    out(format_args!(
        "publishing {topic} size {} {}",
        o.size,
        if o.rate > 0.0 {
            format!("at {} Hz", o.rate)
        } else {
            match kind(&c.url) {
                Kind::Ipc => "as fast as central takes them".to_owned(),
                _ => "as fast as the readers take them".to_owned(),
            }
        }
    ));
    if kind(&c.url) == Kind::Ipc && o.size < 8 {
        eprintln!(
            "courier perf: no latency with --size {} on ipc://: the send time travels in the \
             first 8 bytes of the payload (--size 8 or more)",
            o.size
        );
    }
    let baggage = vec![0u8; o.size as usize];
    let started = Instant::now();
    let end = c.secs.map(|x| started + Duration::from_secs_f64(x));
    let mut period = Tally::default();
    let mut period_start = started;
    let mut seq = 0u32;
    let reliable_dds = !c.best_effort && kind(&c.url) == Kind::Dds;
    loop {
        // at --rate, wait for the next sample's time (a late publisher
        // catches up in a burst, as ddsperf does)
        if o.rate > 0.0 {
            let due = started + Duration::from_secs_f64(f64::from(seq) / o.rate);
            let now = Instant::now();
            if due > now {
                tokio::time::sleep(due - now).await;
            }
        }
        seq = seq.wrapping_add(1);
        let v = T::new(seq, baggage.clone());
        let last = c.count.is_some_and(|n| u64::from(seq) >= n)
            || end.is_some_and(|e| Instant::now() >= e);
        publish_acked(&p, &v, last && reliable_dds, format!("sample {seq}")).await?;
        period.add(v.size());
        total.borrow_mut().add(v.size());
        let now = Instant::now();
        if now >= period_start + Duration::from_secs(1) || last {
            let secs = (now - period_start).as_secs_f64();
            out(format_args!("sent {}", period.rate(secs)));
            period = Tally::default();
            period_start = now;
        }
        if last {
            break;
        }
    }
    let t = total.borrow();
    out(format_args!(
        "total sent {} in {:.2} s: {}",
        t.samples,
        started.elapsed().as_secs_f64(),
        t.rate(started.elapsed().as_secs_f64())
    ));
    out("done");
    Ok(())
}

async fn subscribe<T: PerfSample>(o: PerfSubArgs, mut stop: Stop) -> Result<Ended> {
    let c = &o.common;
    let name = c.name.as_deref().unwrap_or("courier-perf-sub-%p");
    let s = match connect(&c.url, name, &mut stop).await? {
        Ok(s) => s,
        Err(ended) => return Ok(ended),
    };
    let total = RefCell::new(Tally::default());
    let what = || {
        let t = total.borrow();
        format!(
            "after {} received, {} lost",
            count(t.samples, "sample"),
            t.lost
        )
    };
    run_session(&s, &mut stop, receive::<T>(&s, c, &total), what).await
}

/// The next sequence number expected of each publisher and key.
#[derive(Default)]
struct Expected(HashMap<(Option<courier::Guid>, u32), u32>);

impl Expected {
    /// How many samples went missing before `seq` (a publisher that
    /// starts over, or a sample older than expected, counts none).
    fn lost_before(&mut self, source: Option<courier::Guid>, key: u32, seq: u32) -> u64 {
        let next = self.0.entry((source, key)).or_insert(seq);
        let lost = seq.saturating_sub(*next);
        *next = seq.wrapping_add(1);
        u64::from(lost)
    }
}

async fn receive<T: PerfSample>(s: &Session, c: &PerfCommon, total: &RefCell<Tally>) -> Result<()> {
    let topic = topic(c);
    let mut b = s.subscriber::<T>(&topic);
    b = if c.best_effort {
        b.best_effort()
    } else {
        b.reliable()
    };
    let mut ev = s.events();
    let mut sub = b.build().await?;
    out(format_args!("receiving {topic}"));
    let started = Instant::now();
    let end = c
        .secs
        .map(|x| tokio::time::Instant::now() + Duration::from_secs_f64(x));
    let mut expected = Expected::default();
    let mut period = Tally::default();
    let mut latency = Stats::default();
    let mut all_latency = Stats::default();
    let mut tick = tokio::time::interval_at(
        tokio::time::Instant::now() + Duration::from_secs(1),
        Duration::from_secs(1),
    );
    let mut period_start = Instant::now();
    let mut size = 0;
    loop {
        tokio::select! {
            r = sub.next() => match r {
                None | Some(Err(RecvError::Disconnected)) => return Err("the session ended".into()),
                Some(Ok(smp)) => {
                    let v = &smp.value;
                    let lost = expected.lost_before(smp.source, v.keyval(), v.seq());
                    period.lost += lost;
                    total.borrow_mut().lost += lost;
                    size = v.size();
                    period.add(size);
                    total.borrow_mut().add(size);
                    if let Some(sent) = smp.source_time.or_else(|| v.stamp()) {
                        if let Ok(d) = smp.received.duration_since(sent) {
                            latency.push(d);
                            all_latency.push(d);
                        }
                    }
                    if c.count.is_some_and(|n| total.borrow().samples >= n) {
                        break;
                    }
                }
                Some(Err(e)) => out(format_args!("skipped {e}")),
            },
            Some(e) = ev.next() => match e {
                SessionEvent::IncompatibleQos { msg, remote, reason } if msg == topic => {
                    out(incompatible_line(remote, &reason))
                }
                SessionEvent::TypeMismatch { topic: t, remote, local_type, remote_type } if t == topic => {
                    out(type_mismatch_line(remote, &local_type, &remote_type))
                }
                _ => {}
            },
            _ = tick.tick() => {
                let now = Instant::now();
                report(&period, &latency, size, (now - period_start).as_secs_f64());
                period = Tally::default();
                latency = Stats::default();
                period_start = now;
            }
            _ = async { tokio::time::sleep_until(end.unwrap()).await }, if end.is_some() => break,
        }
    }
    if period.samples > 0 {
        report(
            &period,
            &latency,
            size,
            period_start.elapsed().as_secs_f64(),
        );
    }
    let t = total.borrow();
    let secs = started.elapsed().as_secs_f64();
    out(format_args!(
        "total received {} lost {} in {secs:.2} s: {} latency {} (us)",
        t.samples,
        t.lost,
        t.rate(secs),
        all_latency.line()
    ));
    out("done");
    Ok(())
}

/// One line a second: `received 1000 samples/s 0.10 Mbit/s lost 0 size 12
/// latency n=… p50=… (us)`.
fn report(t: &Tally, latency: &Stats, size: usize, secs: f64) {
    out(format_args!(
        "received {} lost {} size {size} latency {} (us)",
        t.rate(secs),
        t.lost,
        latency.line()
    ));
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn losses_are_gaps_per_publisher_and_key() {
        let mut e = Expected::default();
        let a = Some(courier::Guid([1; 16]));
        assert_eq!(e.lost_before(a, 0, 5), 0, "the first sample sets the start");
        assert_eq!(e.lost_before(a, 0, 6), 0);
        assert_eq!(e.lost_before(a, 0, 9), 2);
        assert_eq!(e.lost_before(a, 1, 1), 0, "each key its own count");
        assert_eq!(e.lost_before(None, 0, 3), 0, "each publisher its own count");
        assert_eq!(e.lost_before(a, 0, 4), 0, "a restart is no loss");
        assert_eq!(e.lost_before(a, 0, 5), 0);
    }

    /// ddsperf's `KeyedSeq` in XCDR1, as Cyclone writes it: the CDR_LE
    /// encapsulation header, seq, keyval, then the baggage as a sequence
    /// (length, bytes).
    #[test]
    fn keyed_seq_is_laid_out_as_ddsperf_lays_it_out() {
        let v = KeyedSeq {
            seq: 7,
            keyval: 0x0102_0304,
            baggage: vec![0xaa, 0xbb],
        };
        assert_eq!(
            courier::cdr::to_vec(&v, courier::cdr::Encoding::Xcdr1Le),
            [0, 1, 0, 0, 7, 0, 0, 0, 4, 3, 2, 1, 2, 0, 0, 0, 0xaa, 0xbb]
        );
        assert_eq!(<KeyedSeq as IpcMessage>::TYPE_NAME, "KeyedSeq");
    }

    #[test]
    fn ipc_messages_carry_the_send_time() {
        let v = IpcSeq::new(1, vec![0; 16]);
        let d = SystemTime::now()
            .duration_since(v.stamp().unwrap())
            .unwrap();
        assert!(d < Duration::from_secs(60));
        assert_eq!(IpcSeq::new(1, vec![0; 4]).stamp(), None);
        assert_eq!(
            <IpcSeq as IpcMessage>::FORMAT,
            "{uint, uint, uint, <ubyte:3>}"
        );
    }
}
