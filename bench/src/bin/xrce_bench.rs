//! DDS-XRCE through three relays in one run, with the same Courier
//! clients (`xrce+udp://`): Courier's agent, eProsima's MicroXRCEAgent
//! v2.3.0, and the floor, a minimal UDP relay process that forwards each
//! datagram from one client to the other (no XRCE logic), carrying
//! datagrams of the size of the XRCE messages between bare UDP clients.
//! Printed as one table (see BENCHMARKS.md, "XRCE agents").
//!
//! ```text
//! cargo run --release -p courier-bench --bin xrce_bench -- --quick      # smoke run, < 60 s
//! cargo run --release -p courier-bench --bin xrce_bench                 # full table
//! cargo run --release -p courier-bench --bin xrce_bench -- --eprosima /path/MicroXRCEAgent --reps 3
//! ```
//!
//! The whole run happens inside a private network namespace that has only
//! `lo` (the harness re-executes itself under `unshare -rn`): eProsima's
//! agent runs a Fast DDS participant per client, and its DDS discovery goes
//! through a Fast DDS discovery server on 127.0.0.1 (`fast-discovery-server`
//! from Debian's `fastdds-tools`, with a UDP-only default profile), so
//! every datagram stays on 127.0.0.1. Courier's agent runs in a process of
//! its own (the library of the `xrce-agent` binary, same runtime), its DDS
//! participant on lo with unicast discovery.
//!
//! Rows: round trip of a 16-byte payload between two clients of one agent
//! (client A publishes on `xb_ping`, client B's subscriber republishes on
//! `xb_pong`, A measures), best effort and reliable; throughput of 16 B,
//! reliable (every sequence number checked, in order, nothing lost) and
//! best effort. The measuring role reads the CPU time (utime + stime,
//! /proc/PID/stat) of both clients and of the agent at the start and the
//! end of its measured window: CPU per round trip or per sample.
//!
//! Placement (taskset): both clients on CPU 0, the agent (or relay) on
//! CPU 1 — each agent gets the same one CPU, whatever its threads;
//! `--same-core`: everything on CPU 0.
//!
//! `--state`: instead of the three relays, Courier's agent without and
//! with `--state` (its state file in the temporary directory): what
//! keeping sessions and stream positions durable costs.
//!
//! The roles are usable by hand:
//! ```text
//! xrce_bench courier-agent --port P
//! xrce_bench relay --port P
//! xrce_bench pong --url xrce+udp://127.0.0.1:P [--best-effort] &
//! xrce_bench ping --url xrce+udp://127.0.0.1:P [--best-effort] [--secs S] [--watch PID,PID]
//! xrce_bench pub  --url … [--best-effort] [--secs S] &  xrce_bench sub --url … [--watch PID,PID]
//! xrce_bench udp-pong|udp-ping|udp-pub|udp-sub --port P --datagram BYTES …
//! ```

use std::net::{Ipv4Addr, SocketAddr, UdpSocket};
use std::process::{Command, ExitCode};
use std::time::{Duration, Instant};

use courier::xrce::{BaseObjectRequest, Message, MessageHeader, ObjectId, Payload, RequestId};
use courier::xrce::{StreamId, Submessage};
use courier::{IpcMessage, QueuePolicy, Session};
use futures::StreamExt;

#[allow(dead_code)]
#[path = "../harness.rs"]
mod harness;
#[allow(dead_code)]
#[path = "../xrce_procs.rs"]
mod procs;

use harness::{cpu_ticks, fmt_rate, foreign_load, num, percentile, result_line, Watchdog};
use procs::{cpu_secs, cpu_secs_of, Proc};

/// The sample: a sequence number, a timestamp (ping: ns since the ping
/// process started, echoed by pong) and the payload.
#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "courier::bench::Data")]
struct Data {
    seq: u32,
    ts_ns: u64,
    n: u32,
    #[ipc(len = "n")]
    payload: Vec<u8>,
}

const PING: &str = "xb_ping";
const PONG: &str = "xb_pong";
const DATA: &str = "xb_data";
/// Throughput's way back: the subscriber's "probe seen" and "done".
const CTL: &str = "xb_ctl";

/// Ends a run: pong echoes it and leaves; on `DATA` its `ts_ns` is the
/// count the publisher sent.
const END: u32 = u32::MAX;
/// Throughput's probes, sent until the subscriber has seen one.
const PROBE: u32 = u32::MAX - 1;
/// CTL values.
const CTL_PROBE_SEEN: u32 = 1;
const CTL_DONE: u32 = 2;

const PING_RETRY: Duration = Duration::from_millis(200);
/// A throughput subscriber that got nothing for this long since its last
/// sample stops (what has not come by then is lost).
const SILENCE: Duration = Duration::from_secs(3);
/// … or this long after the publisher's warm-up + measured time.
const LATE: Duration = Duration::from_secs(10);
/// Other processes' CPU use (in CPUs) above which a row is marked busy.
const BUSY: f64 = 0.15;
/// The reliable window of both XRCE streams (the agent's and the
/// client's default), used by the floor's reliable relay traffic too.
const WINDOW: u32 = 16;

const DEFAULT_EPROSIMA: &str = "/work/xrce-build/install/bin/MicroXRCEAgent";
const DISCOVERY_SERVER: &str = "fast-discovery-server";

type Res = Result<(), String>;

// ---------------------------------------------------------------------------
// Role options

struct Opts {
    url: String,
    port: u16,
    size: usize,
    datagram: usize,
    secs: f64,
    warmup: f64,
    best_effort: bool,
    /// Processes whose CPU the measuring role reads: the other client,
    /// then the agent.
    watch: Vec<u32>,
}

fn parse_opts(args: &[String]) -> Result<Opts, String> {
    let mut o = Opts {
        url: String::new(),
        port: 0,
        size: 16,
        datagram: 0,
        secs: 3.0,
        warmup: 0.5,
        best_effort: false,
        watch: Vec::new(),
    };
    let mut it = args.iter();
    while let Some(a) = it.next() {
        let mut val = || {
            it.next()
                .cloned()
                .ok_or_else(|| format!("{a} needs a value"))
        };
        let n = |v: String| -> Result<f64, String> {
            v.parse::<f64>()
                .ok()
                .filter(|x| x.is_finite() && *x >= 0.0)
                .ok_or_else(|| format!("{a} needs a number, not {v:?}"))
        };
        match a.as_str() {
            "--url" => o.url = val()?,
            "--port" => o.port = n(val()?)?.min(65535.0) as u16,
            "--size" => o.size = n(val()?)?.min(60000.0) as usize,
            "--datagram" => o.datagram = n(val()?)?.min(65000.0) as usize,
            "--secs" => o.secs = n(val()?)?,
            "--warmup" => o.warmup = n(val()?)?,
            "--best-effort" => o.best_effort = true,
            "--reliable" => o.best_effort = false,
            "--watch" => {
                o.watch = val()?
                    .split(',')
                    .map(|p| {
                        p.parse::<u32>()
                            .map_err(|_| format!("--watch: bad pid {p:?}"))
                    })
                    .collect::<Result<_, _>>()?
            }
            other => return Err(format!("unknown argument {other:?} (try --help)")),
        }
    }
    Ok(o)
}

// ---------------------------------------------------------------------------
// CPU of the processes in a run

/// CPU seconds of this process, the other client and the agent.
#[derive(Clone, Copy)]
struct CpuMark {
    clients: f64,
    agent: f64,
}

/// Reads the CPU of this process plus `watch[0]` (the other client), and of
/// `watch[1]` (the agent). `None` when not asked (`--watch` not given).
fn cpu_mark(watch: &[u32]) -> Option<CpuMark> {
    let me = cpu_secs(std::process::id())?;
    let peer = cpu_secs_of(watch.get(..1)?)?;
    let agent = cpu_secs_of(watch.get(1..2)?)?;
    Some(CpuMark {
        clients: me + peer,
        agent,
    })
}

/// `client_cpu_us=… agent_cpu_us=…` per unit of work over a window.
fn cpu_fields(a: Option<CpuMark>, b: Option<CpuMark>, units: u64) -> String {
    match (a, b) {
        (Some(a), Some(b)) if units > 0 => format!(
            "client_cpu_us={:.3} agent_cpu_us={:.3}",
            (b.clients - a.clients) * 1e6 / units as f64,
            (b.agent - a.agent) * 1e6 / units as f64
        ),
        _ => String::new(),
    }
}

// ---------------------------------------------------------------------------
// Courier XRCE client roles

async fn connect(url: &str, name: &str) -> Result<Session, String> {
    tokio::time::timeout(
        Duration::from_secs(30),
        Session::builder(url)
            .name(format!("{name}-{}", std::process::id()))
            .connect(),
    )
    .await
    .map_err(|_| format!("connect to {url} timed out"))?
    .map_err(|e| format!("connect to {url}: {e}"))
}

fn sample(seq: u32, size: usize) -> Data {
    Data {
        seq,
        ts_ns: 0,
        n: size as u32,
        payload: vec![0x5a; size],
    }
}

async fn publisher(
    s: &Session,
    topic: &str,
    best_effort: bool,
) -> Result<courier::Publisher<Data>, String> {
    let b = s.publisher::<Data>(topic);
    if best_effort {
        b.best_effort()
    } else {
        b.reliable().keep_all()
    }
    .build()
    .await
    .map_err(|e| format!("publisher {topic}: {e}"))
}

async fn subscriber(
    s: &Session,
    topic: &str,
    best_effort: bool,
) -> Result<courier::Subscriber<Data>, String> {
    let b = s.subscriber::<Data>(topic);
    if best_effort {
        b.best_effort()
    } else {
        b.reliable()
    }
    .queue(QueuePolicy::KeepAll(8192))
    .build()
    .await
    .map_err(|e| format!("subscriber {topic}: {e}"))
}

/// ping's RESULT line from the round trips in ns.
fn ping_result(rtts: &mut [u64], secs: f64, retries: u64, cpu: String) -> String {
    rtts.sort_unstable();
    format!(
        "RESULT role=ping n={} secs={secs:.3} median_us={:.2} p99_us={:.2} retries={retries} {cpu}",
        rtts.len(),
        percentile(rtts, 0.5) / 1e3,
        percentile(rtts, 0.99) / 1e3,
    )
}

/// Measures round trips one at a time until `secs` after the warm-up.
/// `send(seq, ts_ns)` sends a ping; `recv()` waits for an echo and returns
/// `(seq, ts_ns)`, or `None` when the retry watchdog fired.
struct RttRun {
    clock: Instant,
    rtts: Vec<u64>,
    measuring_from: Option<Instant>,
    start_cpu: Option<CpuMark>,
    retries: u64,
}

impl RttRun {
    fn new() -> Self {
        RttRun {
            clock: Instant::now(),
            rtts: Vec::with_capacity(1 << 20),
            measuring_from: None,
            start_cpu: None,
            retries: 0,
        }
    }

    /// After each round trip: true when the run is over.
    fn step(&mut self, o: &Opts) -> bool {
        let now = Instant::now();
        match self.measuring_from {
            None if self.rtts.len() > 10
                && now.duration_since(self.clock).as_secs_f64() >= o.warmup =>
            {
                self.rtts.clear();
                self.measuring_from = Some(now);
                self.start_cpu = cpu_mark(&o.watch);
                false
            }
            Some(t) => now.duration_since(t).as_secs_f64() >= o.secs,
            None => false,
        }
    }

    fn now_ns(&self) -> u64 {
        self.clock.elapsed().as_nanos() as u64
    }

    fn result(mut self, o: &Opts) -> String {
        let end_cpu = cpu_mark(&o.watch);
        let secs = self
            .measuring_from
            .map_or(0.0, |t| t.elapsed().as_secs_f64());
        let cpu = cpu_fields(self.start_cpu, end_cpu, self.rtts.len() as u64);
        ping_result(&mut self.rtts, secs, self.retries, cpu)
    }
}

async fn ping(o: &Opts) -> Res {
    let s = connect(&o.url, "ping").await?;
    let p = publisher(&s, PING, o.best_effort).await?;
    let mut pongs = subscriber(&s, PONG, o.best_effort).await?;
    let mut run = RttRun::new();
    let give_up = Instant::now() + Duration::from_secs_f64(o.warmup + o.secs + 60.0);
    let retry = Watchdog::start(PING_RETRY);
    let mut v = sample(0, o.size);
    loop {
        if Instant::now() > give_up {
            return Err("ping: out of time (pong not answering?)".into());
        }
        v.seq = (v.seq + 1) % PROBE;
        v.ts_ns = run.now_ns();
        retry.kick();
        p.publish(&v).await.map_err(|e| format!("ping: {e}"))?;
        let answered = loop {
            let next = tokio::select! {
                biased;
                r = pongs.next() => r,
                _ = retry.expired() => break false,
            };
            match next {
                None => return Err("ping: session closed".into()),
                Some(Err(e)) => return Err(format!("ping: {e}")),
                Some(Ok(r)) if r.value.seq == v.seq => {
                    let rtt = run.now_ns().saturating_sub(r.value.ts_ns);
                    run.rtts.push(rtt);
                    break true;
                }
                Some(Ok(_)) => {} // a late answer to a retried ping
            }
        };
        if !answered {
            run.retries += 1;
        } else if run.step(o) {
            break;
        }
    }
    let line = run.result(o);
    // tell pong to stop; wait (bounded) for its echo so that it got it
    v.seq = END;
    for _ in 0..10 {
        p.publish(&v).await.map_err(|e| format!("ping: {e}"))?;
        let got = tokio::time::timeout(PING_RETRY, async {
            while let Some(Ok(r)) = pongs.next().await {
                if r.value.seq == END {
                    return true;
                }
            }
            false
        })
        .await;
        if got == Ok(true) {
            break;
        }
    }
    println!("{line}");
    s.close().await;
    Ok(())
}

async fn pong(o: &Opts) -> Res {
    let s = connect(&o.url, "pong").await?;
    let p = publisher(&s, PONG, o.best_effort).await?;
    let mut pings = subscriber(&s, PING, o.best_effort).await?;
    let quiet = Watchdog::start(Duration::from_secs_f64(o.warmup + o.secs + 60.0));
    let mut n = 0u64;
    loop {
        let next = tokio::select! {
            biased;
            r = pings.next() => r,
            _ = quiet.expired() => return Err("pong: no ping for too long".into()),
        };
        match next {
            None => return Err("pong: session closed".into()),
            Some(Err(e)) => return Err(format!("pong: {e}")),
            Some(Ok(v)) => {
                p.publish(&v.value)
                    .await
                    .map_err(|e| format!("pong: {e}"))?;
                quiet.kick();
                n += 1;
                if v.value.seq == END {
                    break;
                }
            }
        }
    }
    // let the last echo go out (best effort: twice more, in case)
    if o.best_effort {
        for _ in 0..3 {
            tokio::time::sleep(Duration::from_millis(20)).await;
            p.publish(&sample(END, 0)).await.ok();
        }
    }
    tokio::time::sleep(Duration::from_millis(100)).await;
    println!("RESULT role=pong echoed={n}");
    s.close().await;
    Ok(())
}

/// Probes `DATA` until the subscriber says it saw one (DDS matching inside
/// the agent takes a while), publishes as fast as `publish` returns for
/// warm-up + secs, then the end marker with the count, and waits for the
/// subscriber's "done".
async fn publish(o: &Opts) -> Res {
    let s = connect(&o.url, "pub").await?;
    let p = publisher(&s, DATA, o.best_effort).await?;
    let mut ctl = subscriber(&s, CTL, false).await?;
    let t0 = Instant::now();
    loop {
        p.publish(&sample(PROBE, o.size))
            .await
            .map_err(|e| format!("pub: {e}"))?;
        match tokio::time::timeout(Duration::from_millis(100), ctl.next()).await {
            Ok(Some(Ok(c))) if c.value.seq == CTL_PROBE_SEEN => break,
            Ok(Some(Err(e))) => return Err(format!("pub: {e}")),
            Ok(None) => return Err("pub: session closed".into()),
            _ if t0.elapsed() > Duration::from_secs(30) => {
                return Err("pub: the subscriber saw no probe within 30 s".into())
            }
            _ => {}
        }
    }
    let mut v = sample(0, o.size);
    let start = Instant::now();
    let end = start + Duration::from_secs_f64(o.warmup + o.secs);
    let mut sent: u64 = 0;
    while Instant::now() < end {
        v.seq = sent as u32;
        p.publish(&v).await.map_err(|e| format!("pub: {e}"))?;
        sent += 1;
    }
    let loop_secs = start.elapsed().as_secs_f64();
    let mut fin = sample(END, 0);
    fin.ts_ns = sent;
    // best effort: the marker may be lost, so it goes a few times
    let copies = if o.best_effort { 5 } else { 1 };
    for _ in 0..copies {
        p.publish(&fin).await.map_err(|e| format!("pub: {e}"))?;
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    // stay (and keep the DDS writer) until the subscriber has it all
    let done = tokio::time::timeout(Duration::from_secs(60), async {
        while let Some(r) = ctl.next().await {
            if matches!(r, Ok(ref c) if c.value.seq == CTL_DONE) {
                return true;
            }
        }
        false
    })
    .await;
    println!(
        "RESULT role=pub sent={sent} secs={loop_secs:.3} rate={:.1} done={}",
        sent as f64 / loop_secs,
        done == Ok(true)
    );
    s.close().await;
    Ok(())
}

/// What a throughput subscriber saw, with the CPU over its window
/// [first + warm-up, first + warm-up + secs].
struct ThrCount {
    received: u64,
    /// Samples whose sequence number was not the one expected next.
    out_of_order: u64,
    expect: u32,
    first: Option<Instant>,
    last: Instant,
    win_n: u64,
    win_start_cpu: Option<CpuMark>,
    win_end_cpu: Option<CpuMark>,
    total: Option<u64>,
}

impl ThrCount {
    fn new() -> Self {
        ThrCount {
            received: 0,
            out_of_order: 0,
            expect: 0,
            first: None,
            last: Instant::now(),
            win_n: 0,
            win_start_cpu: None,
            win_end_cpu: None,
            total: None,
        }
    }

    /// One sample with sequence number `seq` (not a probe nor the end).
    fn sample(&mut self, seq: u32, o: &Opts) {
        let now = Instant::now();
        let t0 = *self.first.get_or_insert(now);
        self.last = now;
        self.received += 1;
        if seq != self.expect {
            self.out_of_order += 1;
        }
        self.expect = seq.wrapping_add(1);
        let since = now.duration_since(t0).as_secs_f64();
        if since >= o.warmup && since <= o.warmup + o.secs {
            if self.win_n == 0 {
                self.win_start_cpu = cpu_mark(&o.watch);
            }
            self.win_n += 1;
        } else if since > o.warmup + o.secs && self.win_end_cpu.is_none() {
            self.win_end_cpu = cpu_mark(&o.watch);
        }
    }

    fn done(&self) -> bool {
        self.total.is_some_and(|t| self.received >= t)
    }

    fn result(&mut self, o: &Opts) -> String {
        let Some(t0) = self.first else {
            return "RESULT role=sub error=nothing-received".into();
        };
        let end = self
            .last
            .duration_since(t0)
            .as_secs_f64()
            .min(o.warmup + o.secs);
        if self.win_end_cpu.is_none() {
            self.win_end_cpu = cpu_mark(&o.watch);
        }
        let d = end - o.warmup;
        let rate = if d > 0.05 && self.win_n > 0 {
            self.win_n as f64 / d
        } else {
            self.received as f64 / self.last.duration_since(t0).as_secs_f64().max(1e-9)
        };
        let (sent, lost) = match self.total {
            Some(t) => (t.to_string(), t.saturating_sub(self.received).to_string()),
            None => ("?".into(), "?".into()),
        };
        format!(
            "RESULT role=sub received={} sent={sent} lost={lost} out_of_order={} rate={rate:.1} {}",
            self.received,
            self.out_of_order,
            cpu_fields(self.win_start_cpu, self.win_end_cpu, self.win_n)
        )
    }
}

async fn subscribe(o: &Opts) -> Res {
    let s = connect(&o.url, "sub").await?;
    let mut data = subscriber(&s, DATA, o.best_effort).await?;
    let ctl = publisher(&s, CTL, false).await?;
    let mut c = ThrCount::new();
    let deadline = Instant::now() + Duration::from_secs_f64(o.warmup + o.secs + 90.0);
    let mut stop_at = deadline;
    let mut probe_answered = false;
    loop {
        // a stream that stopped for good (samples lost, the end marker
        // with them) ends the run after SILENCE rather than at the deadline
        // nor later than LATE after the publisher stopped
        let until = match c.first {
            Some(first) => stop_at
                .min(c.last + SILENCE)
                .min(first + Duration::from_secs_f64(o.warmup + o.secs) + LATE),
            None => stop_at,
        };
        let r = tokio::select! {
            biased;
            r = data.next() => r,
            _ = tokio::time::sleep_until(until.into()) => break,
        };
        let smp = match r {
            Some(Ok(smp)) => smp.value,
            Some(Err(e)) => return Err(format!("sub: {e}")),
            None => return Err("sub: session closed".into()),
        };
        match smp.seq {
            PROBE => {
                if !probe_answered || c.received == 0 {
                    ctl.publish(&sample(CTL_PROBE_SEEN, 0))
                        .await
                        .map_err(|e| format!("sub: {e}"))?;
                    probe_answered = true;
                }
            }
            END => {
                c.total = Some(smp.ts_ns);
                // reliable: all of it is in order before the marker;
                // best effort: whatever is still on its way
                stop_at = Instant::now() + Duration::from_millis(300);
            }
            seq => c.sample(seq, o),
        }
        if c.done() {
            break;
        }
    }
    let line = c.result(o);
    ctl.publish(&sample(CTL_DONE, 0))
        .await
        .map_err(|e| format!("sub: {e}"))?;
    tokio::time::sleep(Duration::from_millis(100)).await;
    println!("{line}");
    s.close().await;
    Ok(())
}

// ---------------------------------------------------------------------------
// The floor: a UDP relay and bare UDP clients

/// Registration datagrams (1 byte): client A, client B, and the relay's
/// "both registered".
const REG_A: u8 = b'A';
const REG_B: u8 = b'B';
const REG_OK: u8 = b'R';

/// Forwards every datagram of more than one byte from A to B and from B
/// to A; one-byte datagrams register A or B. No protocol logic at all.
fn relay(o: &Opts) -> Res {
    let s = UdpSocket::bind((Ipv4Addr::LOCALHOST, o.port)).map_err(|e| e.to_string())?;
    println!("ready {}", s.local_addr().map_err(|e| e.to_string())?);
    let (mut a, mut b): (Option<SocketAddr>, Option<SocketAddr>) = (None, None);
    let mut buf = vec![0u8; 65536];
    loop {
        let (n, from) = s.recv_from(&mut buf).map_err(|e| e.to_string())?;
        if n == 1 {
            match buf[0] {
                REG_A => a = Some(from),
                REG_B => b = Some(from),
                _ => continue,
            }
            if let (Some(a), Some(b)) = (a, b) {
                s.send_to(&[REG_OK], a).map_err(|e| e.to_string())?;
                s.send_to(&[REG_OK], b).map_err(|e| e.to_string())?;
            }
            continue;
        }
        let to = if Some(from) == a {
            b
        } else if Some(from) == b {
            a
        } else {
            None
        };
        if let Some(to) = to {
            // a full socket buffer drops, as any UDP relay does
            let _ = s.send_to(&buf[..n], to);
        }
    }
}

/// A bare UDP client of the relay, registered as A or B.
fn udp_client(o: &Opts, me: u8) -> Result<UdpSocket, String> {
    let s = UdpSocket::bind((Ipv4Addr::LOCALHOST, 0)).map_err(|e| e.to_string())?;
    s.connect((Ipv4Addr::LOCALHOST, o.port))
        .map_err(|e| e.to_string())?;
    s.set_read_timeout(Some(Duration::from_millis(100)))
        .map_err(|e| e.to_string())?;
    let t = Instant::now();
    let mut buf = [0u8; 64];
    loop {
        let _ = s.send(&[me]);
        if let Ok(1) = s.recv(&mut buf) {
            if buf[0] == REG_OK {
                return Ok(s);
            }
        }
        if t.elapsed() > Duration::from_secs(30) {
            return Err("the relay did not register both clients within 30 s".into());
        }
    }
}

fn put_seq(buf: &mut [u8], seq: u32) {
    buf[..4].copy_from_slice(&seq.to_le_bytes());
}

fn get_seq(buf: &[u8]) -> u32 {
    u32::from_le_bytes([buf[0], buf[1], buf[2], buf[3]])
}

fn is_timeout(e: &std::io::Error) -> bool {
    matches!(
        e.kind(),
        std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
    )
}

fn udp_ping(o: &Opts) -> Res {
    let s = udp_client(o, REG_A)?;
    s.set_read_timeout(Some(PING_RETRY))
        .map_err(|e| e.to_string())?;
    let mut out = vec![0x5au8; o.datagram.max(8)];
    let mut inp = vec![0u8; 65536];
    let mut run = RttRun::new();
    let mut seq = 0u32;
    let give_up = Instant::now() + Duration::from_secs_f64(o.warmup + o.secs + 60.0);
    loop {
        if Instant::now() > give_up {
            return Err("udp-ping: out of time".into());
        }
        seq = (seq + 1) % PROBE;
        put_seq(&mut out, seq);
        let sent_at = run.now_ns();
        s.send(&out).map_err(|e| e.to_string())?;
        let answered = loop {
            match s.recv(&mut inp) {
                Ok(n) if n >= 4 && get_seq(&inp) == seq => break true,
                Ok(_) => {}
                Err(e) if is_timeout(&e) => break false,
                Err(e) => return Err(e.to_string()),
            }
        };
        if !answered {
            run.retries += 1;
            continue;
        }
        run.rtts.push(run.now_ns() - sent_at);
        if run.step(o) {
            break;
        }
    }
    let line = run.result(o);
    put_seq(&mut out, END);
    for _ in 0..5 {
        s.send(&out).map_err(|e| e.to_string())?;
        if matches!(s.recv(&mut inp), Ok(n) if n >= 4 && get_seq(&inp) == END) {
            break;
        }
    }
    println!("{line}");
    Ok(())
}

fn udp_pong(o: &Opts) -> Res {
    let s = udp_client(o, REG_B)?;
    s.set_read_timeout(Some(Duration::from_secs_f64(o.warmup + o.secs + 60.0)))
        .map_err(|e| e.to_string())?;
    let mut buf = vec![0u8; 65536];
    let mut n_echoed = 0u64;
    loop {
        let n = s.recv(&mut buf).map_err(|e| format!("udp-pong: {e}"))?;
        if n < 4 {
            continue;
        }
        s.send(&buf[..n]).map_err(|e| e.to_string())?;
        n_echoed += 1;
        if get_seq(&buf) == END {
            break;
        }
    }
    println!("RESULT role=pong echoed={n_echoed}");
    Ok(())
}

/// Size of the floor's acknowledgement: an XRCE ACKNACK message (header 4,
/// submessage header 4, body 5).
const ACK_DATAGRAM: usize = 13;

/// The floor's sender. Best effort: as fast as `send` returns. Reliable:
/// go-back-N with the XRCE window ([`WINDOW`] datagrams in flight),
/// cumulative acknowledgements from the receiver, resent after 20 ms
/// without progress. Then the end marker carrying the count, until the
/// receiver confirms it.
fn udp_pub(o: &Opts) -> Res {
    let s = udp_client(o, REG_A)?;
    let mut out = vec![0xa5u8; o.datagram.max(12)];
    let mut inp = vec![0u8; 65536];
    let start = Instant::now();
    let end = start + Duration::from_secs_f64(o.warmup + o.secs);
    let (mut next, mut base) = (0u32, 0u32);
    let read_ack = |s: &UdpSocket, inp: &mut [u8], wait: Duration| -> Result<Option<u32>, String> {
        s.set_read_timeout(Some(wait)).map_err(|e| e.to_string())?;
        match s.recv(inp) {
            Ok(n) if n >= 4 => Ok(Some(get_seq(inp))),
            Ok(_) => Ok(None),
            Err(e) if is_timeout(&e) => Ok(None),
            Err(e) => Err(e.to_string()),
        }
    };
    if o.best_effort {
        while Instant::now() < end {
            put_seq(&mut out, next);
            let _ = s.send(&out);
            next += 1;
        }
    } else {
        s.set_nonblocking(false).map_err(|e| e.to_string())?;
        while Instant::now() < end || base != next {
            if next.wrapping_sub(base) < WINDOW && Instant::now() < end {
                put_seq(&mut out, next);
                s.send(&out).map_err(|e| e.to_string())?;
                next += 1;
                // take acks that are already there, without waiting
                s.set_nonblocking(true).map_err(|e| e.to_string())?;
                while let Ok(n) = s.recv(&mut inp) {
                    if n >= 4 && get_seq(&inp).wrapping_sub(base) <= next.wrapping_sub(base) {
                        base = get_seq(&inp);
                    }
                }
                s.set_nonblocking(false).map_err(|e| e.to_string())?;
                continue;
            }
            match read_ack(&s, &mut inp, Duration::from_millis(20))? {
                Some(a) if a.wrapping_sub(base) <= next.wrapping_sub(base) => base = a,
                Some(_) => {}
                None => {
                    // go back: resend the window
                    for seq in base..next {
                        put_seq(&mut out, seq);
                        s.send(&out).map_err(|e| e.to_string())?;
                    }
                }
            }
        }
    }
    let sent = next as u64;
    let loop_secs = start.elapsed().as_secs_f64();
    put_seq(&mut out, END);
    out[4..12].copy_from_slice(&sent.to_le_bytes());
    let mut confirmed = false;
    for _ in 0..200 {
        s.send(&out).map_err(|e| e.to_string())?;
        if read_ack(&s, &mut inp, Duration::from_millis(50))? == Some(END) {
            confirmed = true;
            break;
        }
    }
    println!(
        "RESULT role=pub sent={sent} secs={loop_secs:.3} rate={:.1} done={confirmed}",
        sent as f64 / loop_secs
    );
    Ok(())
}

/// The floor's receiver: counts in-order datagrams (reliable: drops the
/// others and acknowledges cumulatively every half window).
fn udp_sub(o: &Opts) -> Res {
    let s = udp_client(o, REG_B)?;
    s.set_read_timeout(Some(Duration::from_millis(300)))
        .map_err(|e| e.to_string())?;
    let mut buf = vec![0u8; 65536];
    let mut ack = [0u8; ACK_DATAGRAM];
    let mut c = ThrCount::new();
    let deadline = Instant::now() + Duration::from_secs_f64(o.warmup + o.secs + 90.0);
    let mut since_ack = 0;
    loop {
        if Instant::now() > deadline {
            break;
        }
        let n = match s.recv(&mut buf) {
            Ok(n) => n,
            Err(e) if is_timeout(&e) => {
                if c.total.is_some() || (o.best_effort && c.received > 0) {
                    break;
                }
                continue;
            }
            Err(e) => return Err(e.to_string()),
        };
        if n < 12 {
            continue;
        }
        let seq = get_seq(&buf);
        if seq == END {
            let mut t = [0u8; 8];
            t.copy_from_slice(&buf[4..12]);
            c.total = Some(u64::from_le_bytes(t));
            put_seq(&mut ack, END);
            let _ = s.send(&ack);
            if o.best_effort || c.done() {
                break;
            }
            continue;
        }
        if !o.best_effort && seq != c.expect {
            // out of order: the sender goes back; say where we are
            put_seq(&mut ack, c.expect);
            let _ = s.send(&ack);
            continue;
        }
        c.sample(seq, o);
        since_ack += 1;
        if !o.best_effort && since_ack >= WINDOW / 2 {
            since_ack = 0;
            put_seq(&mut ack, c.expect);
            let _ = s.send(&ack);
        }
    }
    println!("{}", c.result(o));
    Ok(())
}

// ---------------------------------------------------------------------------
// Orchestrator

#[derive(Clone, Copy, PartialEq)]
enum Kind {
    Rtt,
    Thr,
}

#[derive(Clone, Copy)]
struct Case {
    kind: Kind,
    best_effort: bool,
}

impl Case {
    fn name(&self) -> String {
        let q = if self.best_effort {
            "best effort"
        } else {
            "reliable"
        };
        match self.kind {
            Kind::Rtt => format!("rtt 16 B {q}"),
            Kind::Thr => format!("thr 16 B {q}"),
        }
    }
}

const CASES: [Case; 4] = [
    Case {
        kind: Kind::Rtt,
        best_effort: true,
    },
    Case {
        kind: Kind::Rtt,
        best_effort: false,
    },
    Case {
        kind: Kind::Thr,
        best_effort: false,
    },
    Case {
        kind: Kind::Thr,
        best_effort: true,
    },
];

#[derive(Clone, Copy, PartialEq, Debug)]
enum System {
    Courier,
    /// Courier's agent with `--state` (a state file it commits to).
    CourierState,
    Eprosima,
    Floor,
}

/// The state file of a `--state` agent on `port` (removed before and after).
fn state_file(port: u16) -> std::path::PathBuf {
    std::env::temp_dir().join(format!(
        "xrce-bench-state-{}-{port}.redb",
        std::process::id()
    ))
}

/// One run's outcome.
#[derive(Clone, Default)]
struct Outcome {
    /// rtt: median µs; thr: samples/s.
    value: Option<f64>,
    /// rtt: p99 µs.
    p99: Option<f64>,
    /// CPU µs per round trip (rtt) or per sample (thr): clients, agent.
    client_cpu: Option<f64>,
    agent_cpu: Option<f64>,
    /// thr: lost samples and out-of-order deliveries; rtt: retries.
    lost: Option<String>,
    note: Option<String>,
}

fn failed(why: String) -> Outcome {
    eprintln!("  {why}");
    Outcome {
        note: Some("failed (see stderr)".into()),
        ..Outcome::default()
    }
}

struct Orch {
    exe: std::path::PathBuf,
    quick: bool,
    eprosima: Result<std::path::PathBuf, String>,
    pin: bool,
    /// CPUs of the clients and of the agent (`--same-core`: both 0).
    cpus: (&'static str, &'static str),
    /// XRCE message sizes of the 16 B sample: the floor sends these.
    datagram: usize,
}

/// The datagram a Courier client sends for one sample of `size` payload
/// bytes: one WRITE_DATA in FORMAT_DATA behind the short header (the
/// agent's DATA to the reader has the same length).
fn xrce_datagram(size: usize) -> usize {
    let body = courier::cdr::to_vec_headerless(&sample(0, size), courier::cdr::Encoding::Xcdr1Le);
    let m = Message::new(
        MessageHeader::new(0x81, StreamId::RELIABLE, 0),
        vec![Submessage::new(Payload::WriteData(courier::xrce::Data {
            request: BaseObjectRequest {
                request_id: RequestId(0x100),
                object_id: ObjectId(0x15),
            },
            data: body,
        }))],
    );
    m.to_vec().map(|v| v.len()).unwrap_or(0)
}

impl Orch {
    fn cmd(&self, cpu: &str, program: &std::path::Path) -> Command {
        if self.pin {
            let mut c = Command::new("taskset");
            c.arg("-c").arg(cpu).arg(program);
            c
        } else {
            Command::new(program)
        }
    }

    fn times(&self) -> (f64, f64) {
        if self.quick {
            (1.0, 0.3)
        } else {
            (3.0, 0.5)
        }
    }

    /// Starts the agent (or relay) of `sys` on a free port, ready; with the
    /// discovery server eProsima's needs.
    fn start_agent(&self, sys: System) -> Result<(Vec<Proc>, u16), String> {
        let port = procs::free_udp_port()?;
        let mut procs = Vec::new();
        match sys {
            System::Courier | System::CourierState => {
                let mut c = self.cmd(self.cpus.1, &self.exe);
                c.args(["courier-agent", "--port", &port.to_string()]);
                if sys == System::CourierState {
                    let f = state_file(port);
                    let _ = std::fs::remove_file(&f);
                    c.arg("--state").arg(f);
                }
                let mut p = Proc::spawn("courier-agent", c)?;
                p.wait_line("ready", Duration::from_secs(20))?;
                procs.push(p);
            }
            System::Floor => {
                let mut c = self.cmd(self.cpus.1, &self.exe);
                c.args(["relay", "--port", &port.to_string()]);
                let mut p = Proc::spawn("relay", c)?;
                p.wait_line("ready", Duration::from_secs(20))?;
                procs.push(p);
            }
            System::Eprosima => {
                let agent = self.eprosima.clone()?;
                let ds_port = procs::free_udp_port()?;
                let mut ds = self.cmd(self.cpus.1, std::path::Path::new(DISCOVERY_SERVER));
                ds.args(["-i", "0", "-l", "127.0.0.1", "-p", &ds_port.to_string()]);
                let mut dsp = Proc::spawn("fast-discovery-server", ds)?;
                dsp.wait_line("Server is running", Duration::from_secs(20))
                    .map_err(|e| format!("{e} (Debian's fastdds-tools has it)"))?;
                procs.push(dsp);
                let profile = std::env::temp_dir()
                    .join(format!("xrce-bench-fastdds-{}.xml", std::process::id()));
                std::fs::write(&profile, FASTDDS_UDP_ONLY).map_err(|e| e.to_string())?;
                let mut c = self.cmd(self.cpus.1, &agent);
                c.args(["udp4", "-p", &port.to_string(), "-v", "4"])
                    .env("ROS_DISCOVERY_SERVER", format!("127.0.0.1:{ds_port}"))
                    .env("FASTRTPS_DEFAULT_PROFILES_FILE", &profile);
                let mut p = Proc::spawn("MicroXRCEAgent", c)?;
                // at -v 4 it logs `running... | port: P` once its socket is bound
                p.wait_line("running", Duration::from_secs(20))?;
                procs.push(p);
            }
        }
        Ok((procs, port))
    }

    fn run(&self, sys: System, case: Case) -> Outcome {
        match self.try_run(sys, case) {
            Ok(o) => o,
            Err(e) => failed(format!("{:?} {}: {e}", sys, case.name())),
        }
    }

    fn try_run(&self, sys: System, case: Case) -> Result<Outcome, String> {
        let (secs, warmup) = self.times();
        let (agents, port) = self.start_agent(sys)?;
        let agent_pid = agents.last().map(Proc::pid).unwrap_or(0);
        let url = format!("xrce+udp://127.0.0.1:{port}");
        let role = |r: &str| {
            let mut c = self.cmd(self.cpus.0, &self.exe);
            let r = match sys {
                System::Floor => format!("udp-{r}"),
                _ => r.to_string(),
            };
            c.arg(r)
                .args(["--url", &url, "--port", &port.to_string()])
                .args(["--datagram", &self.datagram.to_string()])
                .args(["--secs", &secs.to_string()])
                .args(["--warmup", &warmup.to_string()]);
            if case.best_effort {
                c.arg("--best-effort");
            }
            c
        };
        let (first, second) = match case.kind {
            Kind::Rtt => ("pong", "ping"),
            Kind::Thr => ("pub", "sub"),
        };
        let a = Proc::spawn(first, role(first))?;
        let mut c2 = role(second);
        c2.args(["--watch", &format!("{},{agent_pid}", a.pid())]);
        let b = Proc::spawn(second, c2)?;
        let limit = Duration::from_secs_f64(secs + warmup + 120.0);
        let out_b = b.finish(limit)?;
        let out_a = a.finish(Duration::from_secs(30))?;
        drop(agents);
        if sys == System::CourierState {
            let _ = std::fs::remove_file(state_file(port));
        }
        let (Some(rb), ra) = (result_line(&out_b), result_line(&out_a)) else {
            return Err(format!(
                "no RESULT: {second}: {out_b:?}, {first}: {out_a:?}"
            ));
        };
        if let Some(e) = rb.get("error").or(ra.as_ref().and_then(|r| r.get("error"))) {
            return Err(e.clone());
        }
        let mut o = Outcome {
            client_cpu: num(&rb, "client_cpu_us"),
            agent_cpu: num(&rb, "agent_cpu_us"),
            ..Outcome::default()
        };
        match case.kind {
            Kind::Rtt => {
                o.value = num(&rb, "median_us");
                o.p99 = num(&rb, "p99_us");
                o.lost = rb.get("retries").map(|r| format!("{r} retries"));
            }
            Kind::Thr => {
                o.value = num(&rb, "rate");
                let lost = rb.get("lost").cloned().unwrap_or_else(|| "?".into());
                let ooo = rb.get("out_of_order").cloned().unwrap_or_default();
                o.lost = Some(if case.best_effort {
                    let pct = match (num(&rb, "lost"), num(&rb, "sent")) {
                        (Some(l), Some(s)) if s > 0.0 => format!(" ({:.1} %)", 100.0 * l / s),
                        _ => String::new(),
                    };
                    format!("{lost}{pct}")
                } else {
                    format!("{lost}, {ooo} out of order")
                });
            }
        }
        Ok(o)
    }
}

/// Fast DDS default profile for eProsima's agent: UDPv4 only, no shared
/// memory (the same as `shared/peers/xrce/fastdds_udp_only.xml`).
const FASTDDS_UDP_ONLY: &str = r#"<?xml version="1.0" encoding="UTF-8" ?>
<profiles xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles">
  <transport_descriptors>
    <transport_descriptor><transport_id>udp_only</transport_id><type>UDPv4</type></transport_descriptor>
  </transport_descriptors>
  <participant profile_name="udp_only_participant" is_default_profile="true">
    <rtps>
      <userTransports><transport_id>udp_only</transport_id></userTransports>
      <useBuiltinTransports>false</useBuiltinTransports>
    </rtps>
  </participant>
</profiles>
"#;

/// The run with the median value; a failed run fails the cell.
fn median(mut runs: Vec<Outcome>) -> Outcome {
    if let Some(f) = runs.iter().find(|o| o.note.is_some() || o.value.is_none()) {
        return f.clone();
    }
    runs.sort_by(|a, b| {
        a.value
            .partial_cmp(&b.value)
            .unwrap_or(std::cmp::Ordering::Equal)
    });
    runs[(runs.len() - 1) / 2].clone()
}

fn cell(kind: Kind, o: &Outcome) -> String {
    if let Some(n) = &o.note {
        return n.clone();
    }
    match (kind, o.value) {
        (Kind::Rtt, Some(m)) => format!("{m:.1} µs (p99 {:.1})", o.p99.unwrap_or(f64::NAN)),
        (Kind::Thr, Some(r)) => fmt_rate(r),
        _ => "–".into(),
    }
}

fn cpu_cell(o: &Outcome) -> String {
    match (o.client_cpu, o.agent_cpu, &o.note) {
        (Some(c), Some(a), None) => format!("{c:.1} / {a:.1}"),
        _ => "–".into(),
    }
}

fn usage() -> ExitCode {
    println!(
        "usage:\n  xrce_bench [--quick] [--reps R] [--filter TEXT] [--eprosima PATH] [--no-eprosima] [--no-pin] [--same-core] [--state]\n\
         \x20   the whole table: Courier's agent, eProsima's MicroXRCEAgent and a UDP relay floor, \
         the same Courier clients (runs itself inside `unshare -rn`, a namespace with only lo)\n\
         \x20   --eprosima: MicroXRCEAgent v2.3.0 (default {DEFAULT_EPROSIMA}); needs \
         {DISCOVERY_SERVER} (fastdds-tools) on PATH\n\
         \x20   --no-pin: no taskset (default: clients on CPU 0, the agent on CPU 1); \
         --same-core: all on CPU 0; --state: Courier's agent without and with --state \
         (a state file) instead\n\
         \x20 xrce_bench courier-agent [--state FILE]|relay --port P\n\
         \x20 xrce_bench ping|pong|pub|sub --url xrce+udp://127.0.0.1:P [--best-effort] [--size B] \
         [--secs S] [--warmup S] [--watch PEER_PID,AGENT_PID]\n\
         \x20 xrce_bench udp-ping|udp-pong|udp-pub|udp-sub --port P --datagram BYTES [same options]"
    );
    ExitCode::from(2)
}

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let role = args.first().map(String::as_str).unwrap_or("");
    let rest = args.get(1..).unwrap_or(&[]);
    let r: Result<(), String> = match role {
        "-h" | "--help" => return usage(),
        "courier-agent" => procs::courier_agent_role(rest),
        "relay" | "udp-ping" | "udp-pong" | "udp-pub" | "udp-sub" => {
            parse_opts(rest).and_then(|o| match role {
                "relay" => relay(&o),
                "udp-ping" => udp_ping(&o),
                "udp-pong" => udp_pong(&o),
                "udp-pub" => udp_pub(&o),
                _ => udp_sub(&o),
            })
        }
        "ping" | "pong" | "pub" | "sub" => parse_opts(rest).and_then(|o| {
            let rt = tokio::runtime::Builder::new_current_thread()
                .enable_all()
                .build()
                .map_err(|e| e.to_string())?;
            let role = role.to_string();
            // a spawned task, not the block_on future (see rtps_bench)
            rt.block_on(async move {
                tokio::spawn(async move {
                    match role.as_str() {
                        "ping" => ping(&o).await,
                        "pong" => pong(&o).await,
                        "pub" => publish(&o).await,
                        _ => subscribe(&o).await,
                    }
                })
                .await
                .map_err(|e| e.to_string())?
            })
        }),
        _ => return orchestrate(&args),
    };
    match r {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            println!("RESULT role={role} error={}", e.replace(' ', "_"));
            eprintln!("xrce_bench {role}: {e}");
            ExitCode::FAILURE
        }
    }
}

fn orchestrate(args: &[String]) -> ExitCode {
    let mut quick = false;
    let mut reps = 1usize;
    let mut filter: Option<String> = None;
    let mut eprosima: Option<String> = None;
    let mut no_eprosima = false;
    let mut pin = true;
    let mut same_core = false;
    let mut state = false;
    let mut it = args.iter();
    while let Some(a) = it.next() {
        match a.as_str() {
            "--quick" => quick = true,
            "--no-pin" => pin = false,
            "--same-core" => same_core = true,
            "--state" => state = true,
            "--no-eprosima" => no_eprosima = true,
            "--reps" => match it.next().and_then(|s| s.parse().ok()).filter(|&r| r >= 1) {
                Some(r) => reps = r,
                None => {
                    eprintln!("--reps needs a number ≥ 1");
                    return usage();
                }
            },
            "--filter" => filter = it.next().cloned(),
            "--eprosima" => match it.next() {
                Some(p) => eprosima = Some(p.clone()),
                None => {
                    eprintln!("--eprosima needs the path of MicroXRCEAgent");
                    return usage();
                }
            },
            other => {
                eprintln!("unknown argument {other:?}");
                return usage();
            }
        }
    }
    let eprosima = if no_eprosima {
        Err("skipped (--no-eprosima)".to_string())
    } else {
        let p = std::path::PathBuf::from(eprosima.as_deref().unwrap_or(DEFAULT_EPROSIMA));
        if !p.is_file() {
            Err(format!(
                "eProsima's MicroXRCEAgent not found at {} (give --eprosima PATH; it is built \
                 outside the repository, see BENCHMARKS.md)",
                p.display()
            ))
        } else if Command::new(DISCOVERY_SERVER).arg("-h").output().is_err() {
            Err(format!(
                "{DISCOVERY_SERVER} not on PATH (Debian's fastdds-tools): eProsima's agent \
                 needs it for DDS discovery on lo"
            ))
        } else {
            Ok(p)
        }
    };
    if let Err(e) = &eprosima {
        eprintln!("eProsima column: {e}");
    }
    if pin && Command::new("taskset").arg("-V").output().is_err() {
        eprintln!("taskset (util-linux) not found: give --no-pin");
        return ExitCode::FAILURE;
    }
    if let Some(code) = procs::enter_private_netns(args) {
        return code;
    }
    let exe = match std::env::current_exe() {
        Ok(e) => e,
        Err(e) => {
            eprintln!("cannot find my own executable: {e}");
            return ExitCode::FAILURE;
        }
    };
    let orch = Orch {
        exe,
        quick,
        eprosima,
        pin,
        cpus: if same_core { ("0", "0") } else { ("0", "1") },
        datagram: xrce_datagram(16),
    };
    let started = Instant::now();
    let mut rows = Vec::new();
    let systems: &[System] = if state {
        &[System::Courier, System::CourierState]
    } else {
        &[System::Courier, System::Eprosima, System::Floor]
    };
    for case in CASES {
        let name = case.name();
        if filter.as_ref().is_some_and(|f| !name.contains(f.as_str())) {
            continue;
        }
        let mut runs: Vec<Vec<Outcome>> = vec![Vec::new(); systems.len()];
        let mut foreign: Option<f64> = None;
        for _ in 0..reps {
            for (i, &sys) in systems.iter().enumerate() {
                if sys == System::Eprosima {
                    if let Err(e) = &orch.eprosima {
                        runs[i].push(Outcome {
                            note: Some(e.split(" (").next().unwrap_or(e).to_string()),
                            ..Outcome::default()
                        });
                        continue;
                    }
                }
                let t = Instant::now();
                let s0 = cpu_ticks();
                let o = orch.run(sys, case);
                let f = foreign_load(s0, cpu_ticks(), t.elapsed().as_secs_f64());
                if let Some(f) = f {
                    foreign = Some(foreign.map_or(f, |g: f64| g.max(f)));
                }
                eprintln!(
                    "{name} {sys:?}: {} cpu {} lost {} ({:.1} s; other processes {})",
                    cell(case.kind, &o),
                    cpu_cell(&o),
                    o.lost.as_deref().unwrap_or("–"),
                    t.elapsed().as_secs_f64(),
                    f.map_or("?".into(), |f| format!("{f:.2} CPU"))
                );
                runs[i].push(o);
            }
        }
        let outs: Vec<Outcome> = runs.into_iter().map(median).collect();
        rows.push((name, case, outs, foreign));
    }
    if state {
        print_state_table(&orch, rows, reps, started.elapsed().as_secs_f64());
    } else {
        print_table(&orch, rows, reps, started.elapsed().as_secs_f64());
    }
    ExitCode::SUCCESS
}

fn ratio(a: &Outcome, b: &Outcome) -> Option<f64> {
    match (a.value, b.value, a.note.is_none() && b.note.is_none()) {
        (Some(x), Some(y), true) if y > 0.0 => Some(x / y),
        _ => None,
    }
}

/// The goals of issue 28: round trip ≤ 0.2× eProsima's and ≤ 1.5× the
/// floor; throughput ≥ 10× eProsima's.
fn goal(case: Case, vs_eprosima: Option<f64>, vs_floor: Option<f64>) -> String {
    let (kind, best_effort) = (case.kind, case.best_effort);
    let met = |ok: bool| if ok { "met" } else { "NOT met" };
    match kind {
        Kind::Rtt => format!(
            "≤ 0.2× eProsima {}; ≤ 1.5× floor {}",
            vs_eprosima.map_or("–", |r| met(r <= 0.2)),
            vs_floor.map_or("–", |r| met(r <= 1.5))
        ),
        Kind::Thr if best_effort => "– (the goal is for reliable)".into(),
        Kind::Thr => format!(
            "≥ 10× eProsima {}",
            vs_eprosima.map_or("–", |r| met(r >= 10.0))
        ),
    }
}

type Row = (String, Case, Vec<Outcome>, Option<f64>);

/// How the run was made, for a table's heading.
fn conditions(orch: &Orch, reps: usize, secs: f64) -> String {
    let load = std::fs::read_to_string("/proc/loadavg").unwrap_or_default();
    format!(
        "{}; {}; {}; {} CPUs; loadavg {}; {secs:.0} s",
        if orch.quick {
            "--quick: short smoke run, not for comparison"
        } else {
            "default durations"
        },
        if reps > 1 {
            format!("median of {reps} alternating runs")
        } else {
            "one run each".into()
        },
        match (orch.pin, orch.cpus.1) {
            (false, _) => "not pinned",
            (true, "0") => "clients and agent on CPU 0",
            (true, _) => "clients on CPU 0, agent on CPU 1",
        },
        std::thread::available_parallelism().map_or(0, |n| n.get()),
        load.split_whitespace()
            .take(3)
            .collect::<Vec<_>>()
            .join(" "),
    )
}

/// `--state`: what keeping clients' sessions and stream positions in a
/// state file costs, Courier's agent without and with it.
fn print_state_table(orch: &Orch, rows: Vec<Row>, reps: usize, secs: f64) {
    println!(
        "\nXRCE over UDP on lo, the same Courier clients through Courier's agent without and \
         with --state ({})\n",
        conditions(orch, reps, secs)
    );
    println!(
        "| measurement | Courier agent | Courier agent --state | --state / without | \
         CPU µs without (clients / agent) | CPU µs --state | lost without | lost --state |"
    );
    println!("|---|---|---|---|---|---|---|---|");
    for (name, case, o, foreign) in &rows {
        let r = ratio(&o[1], &o[0]).map_or("–".into(), |x| format!("{x:.2}×"));
        let mark = if foreign.is_some_and(|f| f > BUSY) {
            " ⚠"
        } else {
            ""
        };
        let l = |o: &Outcome| o.lost.clone().unwrap_or_else(|| "–".into());
        println!(
            "| {name}{mark} | {} | {} | {r} | {} | {} | {} | {} |",
            cell(case.kind, &o[0]),
            cell(case.kind, &o[1]),
            cpu_cell(&o[0]),
            cpu_cell(&o[1]),
            l(&o[0]),
            l(&o[1])
        );
    }
    println!(
        "\nrtt: median round trip (p99) of a 16-byte payload, one in flight; thr: samples/s \
         received in steady state (reliable: lost and out of order must be 0). --state / \
         without: above 1.0× is slower for rtt, below 1.0× is slower for thr. --state commits \
         each reliable stream's position before its ACKNACK (one commit per turn of the \
         agent's loop)."
    );
}

fn print_table(orch: &Orch, rows: Vec<Row>, reps: usize, secs: f64) {
    println!(
        "\nXRCE over UDP on lo, the same Courier clients through Courier's agent, eProsima's \
         MicroXRCEAgent v2.3.0, and a UDP relay floor (floor datagrams {} B; {})\n",
        orch.datagram,
        conditions(orch, reps, secs)
    );
    println!(
        "| measurement | Courier agent | eProsima agent | relay floor | Courier / eProsima | \
         Courier / floor | goal |"
    );
    println!("|---|---|---|---|---|---|---|");
    let mut busy = false;
    for (name, case, o, foreign) in &rows {
        let vs_e = ratio(&o[0], &o[1]);
        let vs_f = ratio(&o[0], &o[2]);
        let r = |x: Option<f64>| x.map_or("–".into(), |x| format!("{x:.2}×"));
        let mark = if foreign.is_some_and(|f| f > BUSY) {
            busy = true;
            " ⚠"
        } else {
            ""
        };
        println!(
            "| {name}{mark} | {} | {} | {} | {} | {} | {} |",
            cell(case.kind, &o[0]),
            cell(case.kind, &o[1]),
            cell(case.kind, &o[2]),
            r(vs_e),
            r(vs_f),
            goal(*case, vs_e, vs_f)
        );
    }
    println!(
        "\nCPU per round trip (rtt) or per sample (thr), µs: both clients / the agent \
         (utime + stime from /proc over the measured window); and what was lost\n"
    );
    println!(
        "| measurement | Courier agent | eProsima agent | relay floor | lost: Courier | \
         lost: eProsima | lost: floor |"
    );
    println!("|---|---|---|---|---|---|---|");
    for (name, _, o, _) in &rows {
        let l = |o: &Outcome| o.lost.clone().unwrap_or_else(|| "–".into());
        println!(
            "| {name} | {} | {} | {} | {} | {} | {} |",
            cpu_cell(&o[0]),
            cpu_cell(&o[1]),
            cpu_cell(&o[2]),
            l(&o[0]),
            l(&o[1]),
            l(&o[2])
        );
    }
    println!(
        "\nrtt: median round trip (p99) of a 16-byte payload, one in flight, client A → agent → \
         client B → agent → A; retries: pings re-sent after {} ms without an answer. thr: \
         samples/s received in steady state; reliable lost = sent − received, out of order = \
         samples not the next sequence number (both must be 0). Floor: bare UDP clients and a \
         relay process forwarding each datagram as it is; reliable floor = go-back-N in a \
         {WINDOW}-datagram window with cumulative acknowledgements of {ACK_DATAGRAM} B.",
        PING_RETRY.as_millis()
    );
    if busy {
        println!(
            "⚠: other processes used more than {BUSY} CPU during this row (see stderr): \
             re-run on an idle machine."
        );
    }
}
