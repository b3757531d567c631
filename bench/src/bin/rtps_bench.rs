//! Courier ↔ Courier over the RTPS backend on loopback, next to Cyclone
//! DDS's `ddsperf` in the same run and with the same CPU placement,
//! printed as one table (see BENCHMARKS.md, "RTPS backend vs Cyclone
//! ddsperf").
//!
//! ```text
//! cargo run --release -p courier-bench --bin rtps_bench               # full table
//! cargo run --release -p courier-bench --bin rtps_bench -- --quick    # smoke run, < 30 s
//! cargo run --release -p courier-bench --bin rtps_bench -- --no-ddsperf
//! ```
//!
//! Every measurement runs as two processes (this binary re-executes itself
//! with a role, like zenoh's `z_ping`/`z_pong`), each started under
//! `taskset`: once both on CPU 0, once on CPUs 0 and 1. The roles are
//! usable by hand as a tool:
//!
//! ```text
//! rtps_bench pong --domain 221 [--listener] &
//! rtps_bench ping --domain 221 --size 16 --secs 3 [--listener]
//! rtps_bench sub --domain 222 --secs 3 [--best-effort] &
//! rtps_bench pub --domain 222 --size 65536 --secs 3 [--best-effort]
//! ```
//!
//! Round trips are measured in two modes, each against its ddsperf
//! counterpart. "callback" rows: ping and pong get `--listener` and answer
//! from a `listen` callback on Courier's receive thread, next to ddsperf's
//! `listener` mode (its default). "stream" rows: ping and pong await a
//! `Subscriber` stream in a tokio task, next to ddsperf's `waitset` mode
//! (an application thread woken by the receive thread).
//!
//! Each role prints one `RESULT key=value …` line on stdout. Every session
//! is `rtps://<domain>?interface=lo&peers=127.0.0.1` and every `ddsperf`
//! gets a loopback-only, unicast-only `CYCLONEDDS_URI` ([`CYCLONE_URI`]):
//! nothing is sent to any address outside 127.0.0.0/8.

use std::io::Read;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use courier::{IpcMessage, QueuePolicy, Session};
use futures::StreamExt;

/// The benchmark's sample: a sequence number, a timestamp (ping: ns since
/// the ping process started, echoed back by pong) and a payload.
#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "courier::bench::Data")]
struct Data {
    seq: u32,
    ts_ns: u64,
    n: u32,
    #[ipc(len = "n")]
    payload: Vec<u8>,
}

/// Cyclone DDS configuration for every `ddsperf` run: loopback only,
/// no multicast, unicast discovery at 127.0.0.1 (participant indices
/// 0..=20, like Courier's `peers=127.0.0.1`). Always set explicitly on the
/// child, overriding whatever the environment holds.
const CYCLONE_URI: &str = "<CycloneDDS><Domain id=\"any\"><General><Interfaces>\
<NetworkInterface name=\"lo\"/></Interfaces><AllowMulticast>false</AllowMulticast>\
</General><Discovery><ParticipantIndex>auto</ParticipantIndex>\
<MaxAutoParticipantIndex>20</MaxAutoParticipantIndex><Peers>\
<Peer address=\"127.0.0.1\"/></Peers></Discovery></Domain></CycloneDDS>";

/// Topics: ping → pong on `PING`, back on `PONG`; throughput on `DATA`,
/// and the publisher's final count on `CTL` (reliable).
impl Data {
    /// The first ping: `size` bytes of payload.
    fn ping(size: usize) -> Data {
        Data {
            seq: 0,
            ts_ns: 0,
            n: size as u32,
            payload: vec![0x5a; size],
        }
    }
}

const PING: &str = "bench_ping";
const PONG: &str = "bench_pong";
const DATA: &str = "bench_data";
const CTL: &str = "bench_ctl";

/// Other processes' CPU use (in CPUs) above which a row is marked as
/// measured on a busy machine.
const BUSY: f64 = 0.15;

/// Marks the last ping: pong answers it and exits.
const END: u32 = u32::MAX;

/// How long a ping waits for its pong before sending a new one (only
/// happens while discovery settles).
const PING_RETRY: Duration = Duration::from_millis(200);

fn url(o: &Opts) -> String {
    let mut u = format!("rtps://{}?interface=lo&peers=127.0.0.1", o.domain);
    if o.busy_poll_us > 0 {
        u += &format!("&busy_poll_us={}", o.busy_poll_us);
    }
    if let Some(n) = o.max_message_size {
        u += &format!("&max_message_size={n}");
    }
    if o.listener {
        u += "&receive_thread=true";
    }
    u
}

/// [`CYCLONE_URI`], with Cyclone's `MaxMessageSize` set when given.
fn cyclone_uri(max_message_size: Option<usize>) -> String {
    match max_message_size {
        None => CYCLONE_URI.to_string(),
        Some(n) => CYCLONE_URI.replacen(
            "</General>",
            &format!("<MaxMessageSize>{n}B</MaxMessageSize></General>"),
            1,
        ),
    }
}

// ---------------------------------------------------------------------------
// Command line

struct Opts {
    domain: u32,
    size: usize,
    secs: f64,
    warmup: f64,
    best_effort: bool,
    threads: usize,
    queue: usize,
    busy_poll_us: u64,
    max_message_size: Option<usize>,
    /// ping/pong answer from a callback on the receive thread
    /// (`listen` + `try_publish`), as ddsperf's default listener mode does.
    listener: bool,
}

impl Default for Opts {
    fn default() -> Self {
        Opts {
            domain: 220,
            size: 16,
            secs: 3.0,
            warmup: 0.5,
            best_effort: false,
            threads: 1,
            queue: 4096,
            busy_poll_us: 0,
            max_message_size: None,
            listener: false,
        }
    }
}

fn usage() -> ! {
    println!(
        "usage:\n  rtps_bench [--quick] [--no-ddsperf] [--filter TEXT] [--reps R] [--threads N] [--busy-poll US] \
         [--max-message-size BYTES[,BYTES…]]   whole table (both CPU placements, Courier and ddsperf)\n  \
         rtps_bench ping|pong|pub|sub [--domain D] [--size BYTES] [--secs S] [--warmup S] \
         [--best-effort] [--threads N] [--queue N] [--busy-poll US] [--max-message-size BYTES] \
         [--listener]\n\n\
         rtps_bench floor [--quick] [--reps R]   bare UDP round trips: blocking recv vs tokio (see udp_floor.rs)\n  \
         rtps_bench udp-ping|udp-pong --port P [--tokio|--tokio-readiness] [--secs S] [--warmup S]\n\n\
         Roles print one RESULT line. ping/pub take --size and --secs (measured time after \
         --warmup); pong runs until ping's last sample; sub until pub's final count \
         (give it pub's --secs/--warmup for the steady-state window).\n\
         ping/pong --listener: answer from a `listen` callback on the session's receive thread \
         (default: await a Subscriber stream in a tokio task). The table's rtt \"callback\" rows \
         pair --listener with ddsperf's listener mode, its \"stream\" rows the default with \
         ddsperf's waitset mode.\n\
         --max-message-size sets the largest datagram of Courier and of ddsperf (default: \
         each one's own, 65500 for Courier on loopback and 14720 for Cyclone 0.10, whose \
         fragments are 1344 B). In the table, a list (e.g. 14720,65500) runs every row at each \
         size in turn, the size named in the row.\n\
         Domains 0..=232; sessions use rtps://D?interface=lo&peers=127.0.0.1."
    );
    std::process::exit(2)
}

fn parse_role_opts(args: &[String]) -> Opts {
    let mut o = Opts::default();
    let mut it = args.iter();
    let num = |v: Option<&String>, what: &str| -> f64 {
        v.and_then(|s| s.parse::<f64>().ok()).unwrap_or_else(|| {
            eprintln!("{what} needs a number");
            std::process::exit(2)
        })
    };
    while let Some(a) = it.next() {
        match a.as_str() {
            "--domain" => o.domain = num(it.next(), "--domain") as u32,
            "--size" => o.size = num(it.next(), "--size") as usize,
            "--secs" => o.secs = num(it.next(), "--secs"),
            "--warmup" => o.warmup = num(it.next(), "--warmup"),
            "--threads" => o.threads = num(it.next(), "--threads") as usize,
            "--queue" => o.queue = num(it.next(), "--queue") as usize,
            "--busy-poll" => o.busy_poll_us = num(it.next(), "--busy-poll") as u64,
            "--max-message-size" => {
                o.max_message_size = Some(num(it.next(), "--max-message-size") as usize)
            }
            "--best-effort" => o.best_effort = true,
            "--reliable" => o.best_effort = false,
            "--listener" => o.listener = true,
            "-h" | "--help" => usage(),
            other => {
                eprintln!("unknown argument {other:?} (try --help)");
                std::process::exit(2)
            }
        }
    }
    o
}

#[path = "../harness.rs"]
mod harness;
use harness::{cpu_ticks, fmt_rate, foreign_load, num, percentile, result_line, Watchdog};

#[path = "../udp_floor.rs"]
mod floor;

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if let Some(r) = args.first().and_then(|role| {
        floor::role(role, &args[1..]).or_else(|| floor::sync_role(role, &args[1..]))
    }) {
        if let Err(e) = r {
            println!("RESULT error={e:?}");
            std::process::exit(1);
        }
        return;
    }
    match args.first().map(String::as_str) {
        Some(role @ ("ping" | "pong" | "pub" | "sub")) => {
            let o = parse_role_opts(&args[1..]);
            let rt = if o.threads <= 1 {
                tokio::runtime::Builder::new_current_thread()
                    .enable_all()
                    .build()
            } else {
                tokio::runtime::Builder::new_multi_thread()
                    .worker_threads(o.threads)
                    .enable_all()
                    .build()
            }
            .expect("tokio runtime");
            // The role runs as a spawned task, not as the `block_on` future:
            // a current-thread runtime polls its I/O driver once more
            // (`epoll_wait(.., 0)`) before it resumes a woken `block_on`
            // future, but runs a woken task straight from its queue.
            let role_name = role.to_string();
            let r = rt.block_on(async move {
                tokio::spawn(async move {
                    match role_name.as_str() {
                        "ping" if o.listener => ping_listener(&o).await,
                        "pong" if o.listener => pong_listener(&o).await,
                        "ping" => ping(&o).await,
                        "pong" => pong(&o).await,
                        "pub" => publish(&o).await,
                        _ => subscribe(&o).await,
                    }
                })
                .await
                .expect("the role's task")
            });
            if let Err(e) = r {
                println!("RESULT role={role} error={e:?}");
                std::process::exit(1);
            }
        }
        _ => orchestrate(&args),
    }
}

// ---------------------------------------------------------------------------
// Roles

type Res = Result<(), String>;

async fn connect(o: &Opts, name: &str) -> Result<Session, String> {
    tokio::time::timeout(
        Duration::from_secs(20),
        Session::builder(url(o))
            .name(format!("{name}-{}", std::process::id()))
            .connect(),
    )
    .await
    .map_err(|_| "connect timed out".to_string())?
    .map_err(|e| format!("connect: {e}"))
}

/// Waits until `topic`'s publication in `s` has a matched reader.
async fn await_reader(s: &Session, topic: &str, within: Duration) -> Res {
    let t = Instant::now();
    while s.num_handlers(topic).await.map_err(|e| e.to_string())? < 1 {
        if t.elapsed() > within {
            return Err(format!("no reader of {topic} matched within {within:?}"));
        }
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
    Ok(())
}

/// The round-trip roles' writer of `topic`: reliable, keep-last 1 (as
/// ddsperf's ping and pong).
async fn rtt_publisher(s: &Session, topic: &str) -> Result<courier::Publisher<Data>, String> {
    s.publisher::<Data>(topic)
        .reliable()
        .keep_last(1)
        .build()
        .await
        .map_err(|e| e.to_string())
}

/// ping's RESULT line: the round trips' median, p99, mean, min and max.
fn print_ping_result(size: usize, rtts: &mut [u64], secs: f64, retries: u64, setup_ms: f64) {
    rtts.sort_unstable();
    let n = rtts.len();
    let mean = rtts.iter().sum::<u64>() as f64 / n.max(1) as f64;
    println!(
        "RESULT role=ping size={size} n={n} secs={secs:.3} median_us={:.2} p99_us={:.2} \
         mean_us={:.2} min_us={:.2} max_us={:.2} retries={retries} setup_ms={setup_ms:.0}",
        percentile(rtts, 0.5) / 1e3,
        percentile(rtts, 0.99) / 1e3,
        mean / 1e3,
        percentile(rtts, 0.0) / 1e3,
        percentile(rtts, 1.0) / 1e3,
    );
}

/// Round trips: publish on `PING`, wait for the echo on `PONG`, one at a
/// time; RTT = now − the echoed `ts_ns` (the ping's own clock).
async fn ping(o: &Opts) -> Res {
    let t_setup = Instant::now();
    let s = connect(o, "ping").await?;
    let p = rtt_publisher(&s, PING).await?;
    let mut pongs = s
        .subscriber::<Data>(PONG)
        .reliable()
        .build()
        .await
        .map_err(|e| e.to_string())?;
    await_reader(&s, PING, Duration::from_secs(20)).await?;
    let setup_ms = t_setup.elapsed().as_secs_f64() * 1e3;
    let clock = Instant::now();
    let mut v = Data::ping(o.size);
    let mut rtts: Vec<u64> = Vec::with_capacity(1 << 20);
    let mut retries = 0u64;
    let mut measuring_from: Option<Instant> = None;
    let give_up = Instant::now() + Duration::from_secs_f64(o.warmup + o.secs + 30.0);
    // re-send a ping that got no answer; kept off the measured runtime (see
    // `Watchdog`)
    let retry = Watchdog::start(PING_RETRY);
    loop {
        let now = Instant::now();
        match measuring_from {
            None if rtts.len() > 10 && now.duration_since(clock).as_secs_f64() >= o.warmup => {
                // warm-up done (and pong surely matched): start counting
                rtts.clear();
                measuring_from = Some(now);
            }
            Some(t) if now.duration_since(t).as_secs_f64() >= o.secs => break,
            _ => {}
        }
        if now > give_up {
            return Err("ping: out of time (pong not answering?)".into());
        }
        v.seq = v.seq.wrapping_add(1) % END;
        v.ts_ns = clock.elapsed().as_nanos() as u64;
        retry.kick();
        p.publish(&v).await.map_err(|e| e.to_string())?;
        loop {
            let next = tokio::select! {
                biased;
                r = pongs.next() => r,
                _ = retry.expired() => {
                    retries += 1;
                    break;
                }
            };
            match next {
                None => return Err("ping: session closed".into()),
                Some(Err(e)) => return Err(format!("ping: {e}")),
                Some(Ok(r)) if r.value.seq == v.seq => {
                    let rtt = (clock.elapsed().as_nanos() as u64).saturating_sub(r.value.ts_ns);
                    rtts.push(rtt);
                    break;
                }
                Some(Ok(_)) => {} // a late answer to a retried ping
            }
        }
    }
    let secs = measuring_from.map_or(0.0, |t| t.elapsed().as_secs_f64());
    // tell pong to stop (and wait for its answer, so it is sent)
    v.seq = END;
    p.publish(&v).await.map_err(|e| e.to_string())?;
    let _ = tokio::time::timeout(Duration::from_secs(2), async {
        while let Some(Ok(r)) = pongs.next().await {
            if r.value.seq == END {
                break;
            }
        }
    })
    .await;
    print_ping_result(o.size, &mut rtts, secs, retries, setup_ms);
    s.close().await;
    Ok(())
}

/// The round trips of [`ping`], answered from a callback: each pong's
/// callback, on the session's receive thread, records the round trip and
/// sends the next ping with `try_publish`; the task only starts, retries
/// (while discovery settles) and stops.
async fn ping_listener(o: &Opts) -> Res {
    use std::sync::{Arc, Mutex};
    struct Run {
        v: Data,
        rtts: Vec<u64>,
        measuring_from: Option<Instant>,
        secs: f64,
        finished: bool,
        error: Option<String>,
    }
    let t_setup = Instant::now();
    let s = connect(o, "ping").await?;
    let p = rtt_publisher(&s, PING).await?;
    let clock = Instant::now();
    let run = Arc::new(Mutex::new(Run {
        v: Data::ping(o.size),
        rtts: Vec::with_capacity(1 << 20),
        measuring_from: None,
        secs: 0.0,
        finished: false,
        error: None,
    }));
    let done = Arc::new(tokio::sync::Notify::new());
    let retry = Arc::new(Watchdog::start(PING_RETRY));
    let (warmup, measure) = (o.warmup, o.secs);
    let end_seen = Arc::new(std::sync::atomic::AtomicBool::new(false));
    let on_pong = {
        let (run, done, retry, p, end_seen) = (
            run.clone(),
            done.clone(),
            retry.clone(),
            p.clone(),
            end_seen.clone(),
        );
        move |r: Result<courier::Sample<Data>, courier::RecvError>| {
            let Ok(r) = r else { return };
            if r.value.seq == END {
                end_seen.store(true, std::sync::atomic::Ordering::Relaxed);
                done.notify_one();
                return;
            }
            let mut g = run.lock().unwrap();
            if g.finished || r.value.seq != g.v.seq {
                return; // a late answer to a retried ping
            }
            let t = clock.elapsed().as_nanos() as u64;
            g.rtts.push(t.saturating_sub(r.value.ts_ns));
            let now = Instant::now();
            match g.measuring_from {
                None if g.rtts.len() > 10 && now.duration_since(clock).as_secs_f64() >= warmup => {
                    g.rtts.clear();
                    g.measuring_from = Some(now);
                }
                Some(t0) if now.duration_since(t0).as_secs_f64() >= measure => {
                    g.secs = now.duration_since(t0).as_secs_f64();
                    g.finished = true;
                    done.notify_one();
                    return;
                }
                _ => {}
            }
            g.v.seq = g.v.seq.wrapping_add(1) % END;
            g.v.ts_ns = clock.elapsed().as_nanos() as u64;
            retry.kick();
            if let Err(e) = p.try_publish(&g.v) {
                g.error = Some(e.to_string());
                g.finished = true;
                done.notify_one();
            }
        }
    };
    let pongs = s
        .subscriber::<Data>(PONG)
        .reliable()
        .listen(on_pong)
        .await
        .map_err(|e| e.to_string())?;
    await_reader(&s, PING, Duration::from_secs(20)).await?;
    let setup_ms = t_setup.elapsed().as_secs_f64() * 1e3;
    let give_up = Instant::now() + Duration::from_secs_f64(o.warmup + o.secs + 30.0);
    let mut retries = 0u64;
    loop {
        {
            let mut g = run.lock().unwrap();
            if g.finished {
                break;
            }
            if Instant::now() > give_up {
                return Err("ping: out of time (pong not answering?)".into());
            }
            // the first ping, or again one that got no answer
            g.v.seq = g.v.seq.wrapping_add(1) % END;
            g.v.ts_ns = clock.elapsed().as_nanos() as u64;
            retry.kick();
            p.try_publish(&g.v).map_err(|e| e.to_string())?;
        }
        tokio::select! {
            _ = done.notified() => {}
            _ = retry.expired() => retries += 1,
        }
    }
    let (mut rtts, secs) = {
        let mut g = run.lock().unwrap();
        if let Some(e) = g.error.take() {
            return Err(format!("ping: {e}"));
        }
        (std::mem::take(&mut g.rtts), g.secs)
    };
    // tell pong to stop (and wait for its answer, so it is sent)
    let mut v = Data::ping(o.size);
    v.seq = END;
    p.publish(&v).await.map_err(|e| e.to_string())?;
    let _ = tokio::time::timeout(Duration::from_secs(2), async {
        while !end_seen.load(std::sync::atomic::Ordering::Relaxed) {
            done.notified().await;
        }
    })
    .await;
    drop(pongs);
    print_ping_result(o.size, &mut rtts, secs, retries, setup_ms);
    s.close().await;
    Ok(())
}

/// [`pong`] from a callback: each ping is echoed from the receive thread
/// with `try_publish`.
async fn pong_listener(o: &Opts) -> Res {
    use std::sync::atomic::{AtomicU64, Ordering};
    use std::sync::Arc;
    let s = connect(o, "pong").await?;
    let p = rtt_publisher(&s, PONG).await?;
    let idle = Duration::from_secs_f64(o.warmup + o.secs + 40.0);
    let quiet = Arc::new(Watchdog::start(idle));
    let done = Arc::new(tokio::sync::Notify::new());
    let echoed = Arc::new(AtomicU64::new(0));
    let failed = Arc::new(std::sync::Mutex::new(None::<String>));
    let on_ping = {
        let (p, quiet, done, echoed, failed) = (
            p.clone(),
            quiet.clone(),
            done.clone(),
            echoed.clone(),
            failed.clone(),
        );
        move |r: Result<courier::Sample<Data>, courier::RecvError>| {
            let v = match r {
                Ok(v) => v,
                Err(e) => {
                    *failed.lock().unwrap() = Some(e.to_string());
                    done.notify_one();
                    return;
                }
            };
            if let Err(e) = p.try_publish(&v.value) {
                *failed.lock().unwrap() = Some(e.to_string());
                done.notify_one();
            }
            quiet.kick();
            echoed.fetch_add(1, Ordering::Relaxed);
            if v.value.seq == END {
                done.notify_one();
            }
        }
    };
    let pings = s
        .subscriber::<Data>(PING)
        .reliable()
        .listen(on_ping)
        .await
        .map_err(|e| e.to_string())?;
    tokio::select! {
        _ = done.notified() => {}
        _ = quiet.expired() => return Err("pong: no ping for too long".into()),
    }
    if let Some(e) = failed.lock().unwrap().take() {
        return Err(format!("pong: {e}"));
    }
    // let the last answer go out before leaving
    tokio::time::sleep(Duration::from_millis(50)).await;
    drop(pings);
    println!("RESULT role=pong echoed={}", echoed.load(Ordering::Relaxed));
    s.close().await;
    Ok(())
}

/// Echoes every sample of `PING` on `PONG` until the end marker.
async fn pong(o: &Opts) -> Res {
    let s = connect(o, "pong").await?;
    let p = rtt_publisher(&s, PONG).await?;
    let mut pings = s
        .subscriber::<Data>(PING)
        .reliable()
        .build()
        .await
        .map_err(|e| e.to_string())?;
    let mut n = 0u64;
    // ping gives up after warm-up + secs + 30 s; so does pong, a bit later
    let idle = Duration::from_secs_f64(o.warmup + o.secs + 40.0);
    let quiet = Watchdog::start(idle);
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
                p.publish(&v.value).await.map_err(|e| e.to_string())?;
                quiet.kick();
                n += 1;
                if v.value.seq == END {
                    break;
                }
            }
        }
    }
    // let the last answer go out before leaving
    tokio::time::sleep(Duration::from_millis(50)).await;
    println!("RESULT role=pong echoed={n}");
    s.close().await;
    Ok(())
}

/// Publishes as fast as `publish().await` returns for warm-up + secs, then
/// the count on `CTL`.
async fn publish(o: &Opts) -> Res {
    let t_setup = Instant::now();
    let s = connect(o, "pub").await?;
    let b = s.publisher::<Data>(DATA);
    let p = if o.best_effort {
        b.best_effort()
    } else {
        b.reliable()
    }
    .build()
    .await
    .map_err(|e| e.to_string())?;
    let ctl = s
        .publisher::<Data>(CTL)
        .reliable()
        .build()
        .await
        .map_err(|e| e.to_string())?;
    await_reader(&s, DATA, Duration::from_secs(20)).await?;
    await_reader(&s, CTL, Duration::from_secs(20)).await?;
    let setup_ms = t_setup.elapsed().as_secs_f64() * 1e3;
    // the subscriber's side of the match (its SEDP handling) settles too
    tokio::time::sleep(Duration::from_millis(50)).await;
    let mut v = Data {
        seq: 0,
        ts_ns: 0,
        n: o.size as u32,
        payload: vec![0xa5; o.size],
    };
    let start = Instant::now();
    let end = start + Duration::from_secs_f64(o.warmup + o.secs);
    let mut sent: u64 = 0;
    loop {
        v.seq = sent as u32;
        p.publish(&v).await.map_err(|e| e.to_string())?;
        sent += 1;
        if Instant::now() >= end {
            break;
        }
    }
    let loop_secs = start.elapsed().as_secs_f64();
    // One last sample, acknowledged by the reader: ACKs are cumulative, so
    // every earlier sample has then arrived too (reliable). A best-effort
    // writer has no acknowledgements to wait for.
    v.seq = sent as u32;
    if o.best_effort {
        p.publish(&v).await.map_err(|e| e.to_string())?;
    } else {
        p.publish(&v)
            .confirmed_within(Duration::from_secs(30))
            .await
            .map_err(|e| format!("final confirmed publish: {e}"))?;
    }
    sent += 1;
    let total = Data {
        seq: END,
        ts_ns: sent,
        n: 0,
        payload: Vec::new(),
    };
    ctl.publish(&total)
        .confirmed_within(Duration::from_secs(10))
        .await
        .map_err(|e| format!("count on {CTL}: {e}"))?;
    println!(
        "RESULT role=pub size={} sent={sent} secs={loop_secs:.3} rate={:.1} setup_ms={setup_ms:.0}",
        o.size,
        (sent - 1) as f64 / loop_secs
    );
    s.close().await;
    Ok(())
}

/// Counts what arrives on `DATA`; the rate is over the steady-state
/// window [first + warm-up, first + warm-up + secs]; loss is the
/// publisher's count minus what arrived.
async fn subscribe(o: &Opts) -> Res {
    let s = connect(o, "sub").await?;
    let b = s.subscriber::<Data>(DATA);
    let mut data = if o.best_effort {
        b.best_effort()
    } else {
        b.reliable()
    }
    .queue(QueuePolicy::KeepAll(o.queue))
    .build()
    .await
    .map_err(|e| e.to_string())?;
    let mut ctl = s
        .subscriber::<Data>(CTL)
        .reliable()
        .build()
        .await
        .map_err(|e| e.to_string())?;
    let deadline = Instant::now() + Duration::from_secs_f64(o.warmup + o.secs + 60.0);
    let (mut received, mut gaps, mut bytes, mut size) = (0u64, 0u64, 0u64, 0u64);
    let mut expect: Option<u32> = None;
    let mut first: Option<Instant> = None;
    let mut last = Instant::now();
    let (mut win_n, mut win_bytes) = (0u64, 0u64);
    let mut total: Option<u64> = None;
    let mut stop_at = deadline;
    let mut errors = 0u64;
    let mut max_gap = Duration::ZERO;
    loop {
        tokio::select! {
            biased;
            r = data.next() => match r {
                Some(Ok(smp)) => {
                    let now = Instant::now();
                    let t0 = *first.get_or_insert(now);
                    if received > 0 {
                        max_gap = max_gap.max(now.duration_since(last));
                    }
                    last = now;
                    received += 1;
                    let len = smp.value.payload.len() as u64;
                    bytes += len;
                    size = len;
                    let since = now.duration_since(t0).as_secs_f64();
                    if since >= o.warmup && since <= o.warmup + o.secs {
                        win_n += 1;
                        win_bytes += len;
                    }
                    let seq = smp.value.seq;
                    if let Some(e) = expect {
                        if seq != e {
                            gaps += u64::from(seq.wrapping_sub(e));
                        }
                    }
                    expect = Some(seq.wrapping_add(1));
                    if total.is_some_and(|t| received >= t) {
                        break;
                    }
                }
                Some(Err(_)) => errors += 1,
                None => break,
            },
            c = ctl.next(), if total.is_none() => {
                if let Some(Ok(c)) = c {
                    total = Some(c.value.ts_ns);
                    if received >= c.value.ts_ns {
                        break;
                    }
                    // reliable: the rest is in flight or queued; best effort:
                    // whatever is still in the kernel's buffer
                    stop_at = Instant::now()
                        + if o.best_effort {
                            Duration::from_millis(200)
                        } else {
                            Duration::from_secs(10)
                        };
                }
            }
            _ = tokio::time::sleep_until(stop_at.min(deadline).into()) => break,
        }
    }
    let Some(t0) = first else {
        return Err("sub: nothing received".into());
    };
    let win_start = o.warmup;
    let win_end = last.duration_since(t0).as_secs_f64().min(o.warmup + o.secs);
    let (rate, mbps) = if win_end - win_start > 0.05 && win_n > 0 {
        let d = win_end - win_start;
        (win_n as f64 / d, win_bytes as f64 / d / 1e6)
    } else {
        // shorter than the warm-up: the whole run
        let d = last.duration_since(t0).as_secs_f64().max(1e-9);
        (received as f64 / d, bytes as f64 / d / 1e6)
    };
    let sent = total.map_or("?".to_string(), |t| t.to_string());
    let lost = total.map_or("?".to_string(), |t| t.saturating_sub(received).to_string());
    println!(
        "RESULT role=sub size={size} received={received} sent={sent} lost={lost} gaps={gaps} \
         dropped={} rate={rate:.1} mbps={mbps:.3} window_n={win_n} errors={errors} \
         max_gap_ms={:.1}",
        data.dropped(),
        max_gap.as_secs_f64() * 1e3
    );
    s.close().await;
    Ok(())
}

// ---------------------------------------------------------------------------
// Orchestrator

#[derive(Clone, Copy, PartialEq)]
enum Kind {
    /// Round trips. `listener`: Courier's ping/pong answer from a `listen`
    /// callback on the receive thread (`--listener`) and ddsperf runs in
    /// `listener` mode; otherwise Courier awaits a `Subscriber` stream in a
    /// tokio task and ddsperf runs in `waitset` mode.
    Rtt {
        listener: bool,
    },
    Thr {
        best_effort: bool,
    },
}

#[derive(Clone, Copy)]
struct Case {
    kind: Kind,
    size: usize,
}

impl Case {
    fn name(&self) -> String {
        let sz = if self.size >= 1 << 20 {
            format!("{} MiB", self.size >> 20)
        } else if self.size >= 1024 {
            format!("{} KiB", self.size / 1024)
        } else {
            format!("{} B", self.size)
        };
        match self.kind {
            Kind::Rtt { listener: true } => format!("rtt {sz} callback"),
            Kind::Rtt { listener: false } => format!("rtt {sz} stream"),
            Kind::Thr { best_effort: false } => format!("thr {sz} reliable"),
            Kind::Thr { best_effort: true } => format!("thr {sz} best effort"),
        }
    }
}

/// CPU placement: (first process, second process).
#[derive(Clone, Copy)]
struct Placement {
    name: &'static str,
    cpus: (&'static str, &'static str),
}

const PLACEMENTS: [Placement; 2] = [
    Placement {
        name: "same-core",
        cpus: ("0", "0"),
    },
    Placement {
        name: "cross-core",
        cpus: ("0", "1"),
    },
];

/// One side's outcome.
#[derive(Default, Clone)]
struct Outcome {
    /// RTT: median µs; throughput: samples/s.
    value: Option<f64>,
    /// RTT: p99 µs; throughput: MB/s of payload.
    second: Option<f64>,
    /// Lost samples (throughput) / ping retries (RTT), and the total.
    lost: Option<(u64, u64)>,
    /// Why there is no number.
    note: Option<String>,
    /// Lowest and highest value over the runs (with `--reps` > 1).
    range: Option<(f64, f64)>,
}

/// The run with the median value (the lower middle one of an even count);
/// with several runs it carries the range of all of them, and a reliable
/// row's lost count is the largest any run saw. A failed run makes the
/// whole cell failed.
fn median_outcome(kind: Kind, mut runs: Vec<Outcome>) -> Outcome {
    if let Some(failed) = runs.iter().find(|o| o.note.is_some() || o.value.is_none()) {
        return failed.clone();
    }
    runs.sort_by(|a, b| {
        a.value
            .partial_cmp(&b.value)
            .unwrap_or(std::cmp::Ordering::Equal)
    });
    let values: Vec<f64> = runs.iter().filter_map(|o| o.value).collect();
    let worst_lost = runs.iter().filter_map(|o| o.lost).max_by_key(|l| l.0);
    let mut m = runs[(runs.len() - 1) / 2].clone();
    if runs.len() > 1 {
        m.range = Some((values[0], values[values.len() - 1]));
        if !matches!(kind, Kind::Thr { best_effort: true }) {
            m.lost = worst_lost;
        }
    }
    m
}

struct Orchestrator {
    exe: std::path::PathBuf,
    quick: bool,
    ddsperf: Result<String, String>,
    domain: u32,
    threads: usize,
    busy_poll_us: u64,
    /// Largest datagram, for both Courier and Cyclone; `None`: each one's default.
    max_message_size: Option<usize>,
}

/// Domains 220..=230, in turn: every run gets one the run before did not use.
fn next_domain(d: &mut u32) -> u32 {
    *d = if *d >= 230 { 220 } else { *d + 1 };
    *d
}

/// Runs `first` and `second` (started 50 ms apart, `second` first) and
/// returns their stdout; kills them if they take longer than `limit`.
fn run_pair(second: Command, first: Command, limit: Duration) -> Result<(String, String), String> {
    fn spawn(mut c: Command) -> Result<Child, String> {
        c.stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .stdin(Stdio::null())
            .spawn()
            .map_err(|e| format!("cannot start {c:?}: {e}"))
    }
    let mut b = spawn(second)?;
    std::thread::sleep(Duration::from_millis(50));
    let mut a = match spawn(first) {
        Ok(a) => a,
        Err(e) => {
            let _ = b.kill();
            let _ = b.wait();
            return Err(e);
        }
    };
    // drain the pipes on threads so that a chatty child never blocks
    let collect = |c: &mut Child| {
        let mut out = c.stdout.take().expect("piped");
        let mut err = c.stderr.take().expect("piped");
        let o = std::thread::spawn(move || {
            let mut s = String::new();
            let _ = out.read_to_string(&mut s);
            s
        });
        let e = std::thread::spawn(move || {
            let mut s = String::new();
            let _ = err.read_to_string(&mut s);
            s
        });
        (o, e)
    };
    let (ao, ae) = collect(&mut a);
    let (bo, be) = collect(&mut b);
    let t = Instant::now();
    let mut timed_out = false;
    for c in [&mut a, &mut b] {
        loop {
            match c.try_wait() {
                Ok(Some(_)) => break,
                Ok(None) if t.elapsed() < limit => std::thread::sleep(Duration::from_millis(10)),
                _ => {
                    timed_out = true;
                    let _ = c.kill();
                    let _ = c.wait();
                    break;
                }
            }
        }
    }
    let join = |h: std::thread::JoinHandle<String>| h.join().unwrap_or_default();
    let (ao, ae, bo, be) = (join(ao), join(ae), join(bo), join(be));
    if timed_out {
        return Err(format!(
            "timed out after {limit:?}\n--- first stdout ---\n{ao}\n--- first stderr ---\n{ae}\n\
             --- second stdout ---\n{bo}\n--- second stderr ---\n{be}"
        ));
    }
    if std::env::var_os("RTPS_BENCH_VERBOSE").is_some() {
        eprintln!("--- first ---\n{ao}{ae}--- second ---\n{bo}{be}");
    }
    Ok((ao, bo))
}

impl Orchestrator {
    fn taskset(&self, cpu: &str, program: &std::path::Path) -> Command {
        let mut c = Command::new("taskset");
        c.arg("-c").arg(cpu).arg(program);
        c
    }

    fn courier(&mut self, case: Case, pl: Placement) -> Outcome {
        let (secs, warmup) = if self.quick { (0.3, 0.2) } else { (3.0, 0.5) };
        let domain = next_domain(&mut self.domain);
        let role = |r: &str| {
            let mut c = self.taskset(
                if r == "ping" || r == "pub" {
                    pl.cpus.0
                } else {
                    pl.cpus.1
                },
                &self.exe,
            );
            c.arg(r)
                .args(["--domain", &domain.to_string()])
                .args(["--size", &case.size.to_string()])
                .args(["--secs", &secs.to_string()])
                .args(["--warmup", &warmup.to_string()])
                .args(["--threads", &self.threads.to_string()])
                .args(["--busy-poll", &self.busy_poll_us.to_string()]);
            if let Some(n) = self.max_message_size {
                c.args(["--max-message-size", &n.to_string()]);
            }
            match case.kind {
                Kind::Thr { best_effort: true } => {
                    c.arg("--best-effort");
                }
                Kind::Rtt { listener: true } => {
                    c.arg("--listener");
                }
                Kind::Rtt { listener: false } | Kind::Thr { best_effort: false } => {}
            }
            c
        };
        let limit = Duration::from_secs_f64(secs + warmup + 60.0);
        let (first, second) = match case.kind {
            Kind::Rtt { .. } => (role("ping"), role("pong")),
            Kind::Thr { .. } => (role("pub"), role("sub")),
        };
        let (a, b) = match run_pair(second, first, limit) {
            Ok(x) => x,
            Err(e) => {
                eprintln!("courier {} {}: {e}", case.name(), pl.name);
                return Outcome {
                    note: Some("failed (see stderr)".into()),
                    ..Outcome::default()
                };
            }
        };
        let fail = |which: &str, out: &str| {
            eprintln!(
                "courier {} {}: no result from {which}:\n{out}",
                case.name(),
                pl.name
            );
            Outcome {
                note: Some("failed (see stderr)".into()),
                ..Outcome::default()
            }
        };
        match case.kind {
            Kind::Rtt { .. } => {
                let Some(m) = result_line(&a).filter(|m| !m.contains_key("error")) else {
                    return fail("ping", &a);
                };
                Outcome {
                    value: num(&m, "median_us"),
                    second: num(&m, "p99_us"),
                    lost: Some((
                        num(&m, "retries").unwrap_or(0.0) as u64,
                        num(&m, "n").unwrap_or(0.0) as u64,
                    )),
                    note: None,
                    range: None,
                }
            }
            Kind::Thr { .. } => {
                let Some(m) = result_line(&b).filter(|m| !m.contains_key("error")) else {
                    return fail("sub", &b);
                };
                if result_line(&a).is_none_or(|m| m.contains_key("error")) {
                    return fail("pub", &a);
                }
                let lost = match (num(&m, "lost"), num(&m, "sent")) {
                    (Some(l), Some(s)) => Some((l as u64, s as u64)),
                    _ => None,
                };
                Outcome {
                    value: num(&m, "rate"),
                    second: num(&m, "mbps"),
                    lost,
                    note: None,
                    range: None,
                }
            }
        }
    }

    fn ddsperf(&mut self, case: Case, pl: Placement) -> Outcome {
        let bin = match &self.ddsperf {
            Ok(b) => b.clone(),
            Err(why) => {
                return Outcome {
                    note: Some(why.clone()),
                    ..Outcome::default()
                }
            }
        };
        // ddsperf prints its statistics once a second, counted from its
        // start. ping sends its first ping only after one second (its 1 Hz
        // fallback timer), so its first useful line ends at 2 s; sub's
        // first line holds discovery. Default: the lines ending at 3..=5 s
        // (round trips) and 2..=4 s (throughput). Quick: the single line
        // at 2 s (round trips) and 1 s (throughput, discovery included).
        let (dur, from): (f64, f64) = match (case.kind, self.quick) {
            (Kind::Rtt { .. }, false) => (5.0, 3.0),
            (Kind::Rtt { .. }, true) => (2.0, 2.0),
            (Kind::Thr { .. }, false) => (4.0, 2.0),
            (Kind::Thr { .. }, true) => (1.0, 1.0),
        };
        let domain = next_domain(&mut self.domain);
        // KS topic: `size` counts its 12 fixed bytes (seq, key, length), so
        // size + 12 carries `size` octets, as Courier's payload does.
        let size = (case.size + 12).to_string();
        let cmd = |cpu: &str, dur: f64, mode: &[&str]| {
            let mut c = self.taskset(cpu, std::path::Path::new(&bin));
            c.env("CYCLONEDDS_URI", cyclone_uri(self.max_message_size))
                .args(["-i", &domain.to_string()])
                .args(["-D", &format!("{dur:.2}")]);
            if matches!(case.kind, Kind::Thr { best_effort: true }) {
                c.arg("-u");
            }
            c.args(mode);
            c
        };
        // The second process starts 50 ms before the first: pong outlives
        // ping and pub outlives sub, so the intervals used are complete.
        let (first, second) = match case.kind {
            // triggering mode, given explicitly to both sides
            Kind::Rtt { listener } => {
                let trigger = if listener { "listener" } else { "waitset" };
                (
                    cmd(pl.cpus.0, dur + 0.05, &["ping", "size", &size, trigger]),
                    cmd(pl.cpus.1, dur + 0.15, &["pong", trigger]),
                )
            }
            Kind::Thr { .. } => (
                cmd(pl.cpus.0, dur + 0.1, &["pub", "size", &size]),
                cmd(pl.cpus.1, dur + 0.05, &["sub"]),
            ),
        };
        let (a, b) = match run_pair(second, first, Duration::from_secs_f64(dur + 30.0)) {
            Ok(x) => x,
            Err(e) => {
                eprintln!("ddsperf {} {}: {e}", case.name(), pl.name);
                return Outcome {
                    note: Some("failed (see stderr)".into()),
                    ..Outcome::default()
                };
            }
        };
        let parsed = match case.kind {
            Kind::Rtt { .. } => parse_ddsperf_ping(&a, from, dur),
            Kind::Thr { .. } => parse_ddsperf_sub(&b, from, dur, case.size),
        };
        parsed.unwrap_or_else(|| {
            eprintln!(
                "ddsperf {} {}: no usable output\n--- first ---\n{a}\n--- second ---\n{b}",
                case.name(),
                pl.name
            );
            Outcome {
                note: Some("no output (see stderr)".into()),
                ..Outcome::default()
            }
        })
    }
}

/// `[pid] T  host:pid size S mean Xus min Xus 50% Xus 90% Xus 99% Xus max Xus cnt N`:
/// ddsperf's per-second round-trip statistics. Its latencies are *half* the
/// round trip (`update_roundtrip (…, (tnow - ts) / 2, …)`), its percentiles
/// are over the first 20 000 round trips of each second. We take, over the
/// intervals ending in [from, to], the median of the per-interval 50% and
/// 99% values, doubled into a round trip.
fn parse_ddsperf_ping(out: &str, from: f64, to: f64) -> Option<Outcome> {
    let (mut p50, mut p99, mut cnt) = (Vec::new(), Vec::new(), 0u64);
    for l in out.lines() {
        let t: Vec<&str> = l.split_whitespace().collect();
        if t.len() < 4 || !t.contains(&"mean") || !t.contains(&"cnt") {
            continue;
        }
        let Some(ts) = t.get(1).and_then(|s| s.parse::<f64>().ok()) else {
            continue;
        };
        if ts < from - 0.05 || ts > to + 0.05 {
            continue;
        }
        let after = |k: &str| -> Option<f64> {
            let i = t.iter().position(|x| *x == k)?;
            t.get(i + 1)?.trim_end_matches("us").parse().ok()
        };
        if let (Some(a), Some(b)) = (after("50%"), after("99%")) {
            p50.push(2.0 * a);
            p99.push(2.0 * b);
            cnt += after("cnt").unwrap_or(0.0) as u64;
        }
    }
    let med = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    if p50.is_empty() {
        return None;
    }
    Some(Outcome {
        value: Some(med(&mut p50)),
        second: Some(med(&mut p99)),
        lost: Some((0, cnt)),
        note: None,
        range: None,
    })
}

/// `[pid] T  size S total N lost L delta D lost l rate R kS/s M Mb/s (…)`:
/// ddsperf's per-second receive statistics. Rate = Σ delta / (time between
/// the line before the window and its last line); loss = its total lost
/// (sequence gaps seen by the subscriber) and its total received.
fn parse_ddsperf_sub(out: &str, from: f64, to: f64, payload: usize) -> Option<Outcome> {
    let mut prev_ts = 0.0;
    let (mut n, mut t_start, mut t_end) = (0u64, None, 0.0);
    let (mut total, mut lost) = (0u64, 0u64);
    for l in out.lines() {
        let t: Vec<&str> = l.split_whitespace().collect();
        if !t.contains(&"total") || !t.contains(&"delta") {
            continue;
        }
        let Some(ts) = t.get(1).and_then(|s| s.parse::<f64>().ok()) else {
            continue;
        };
        let after = |k: &str, nth: usize| -> Option<u64> {
            let i = t.iter().enumerate().filter(|(_, x)| **x == k).nth(nth)?.0;
            t.get(i + 1)?.parse().ok()
        };
        total = after("total", 0)?;
        lost = after("lost", 0)?;
        if ts >= from - 0.05 && ts <= to + 0.05 {
            t_start.get_or_insert(prev_ts);
            t_end = ts;
            n += after("delta", 0)?;
        }
        prev_ts = ts;
    }
    let d = t_end - t_start?;
    if d <= 0.0 {
        return None;
    }
    let rate = n as f64 / d;
    Some(Outcome {
        value: Some(rate),
        second: Some(rate * payload as f64 / 1e6),
        lost: Some((lost, total + lost)),
        note: None,
        range: None,
    })
}

fn find_ddsperf() -> Result<String, String> {
    let paths = std::env::var_os("PATH").unwrap_or_default();
    for dir in std::env::split_paths(&paths) {
        let p = dir.join("ddsperf");
        if p.is_file() {
            return Ok(p.to_string_lossy().into_owned());
        }
    }
    Err("ddsperf not installed".into())
}

fn cell(kind: Kind, o: &Outcome) -> String {
    if let Some(n) = &o.note {
        return n.clone();
    }
    let range = match (kind, o.range) {
        (_, None) => String::new(),
        (Kind::Rtt { .. }, Some((lo, hi))) => format!(" [runs {lo:.1}–{hi:.1}]"),
        (Kind::Thr { .. }, Some((lo, hi))) => format!(" [runs {}–{}]", fmt_rate(lo), fmt_rate(hi)),
    };
    match (kind, o.value, o.second) {
        (Kind::Rtt { .. }, Some(m), Some(p)) => format!("{m:.1} µs (p99 {p:.1}){range}"),
        (Kind::Thr { .. }, Some(r), Some(mb)) => {
            format!("{} = {mb:.1} MB/s{range}", fmt_rate(r))
        }
        _ => "–".into(),
    }
}

fn lost_cell(kind: Kind, o: &Outcome) -> String {
    match (kind, o.lost, &o.note) {
        (_, _, Some(_)) | (_, None, _) => "–".into(),
        (Kind::Rtt { .. }, Some((retries, _)), _) if retries > 0 => format!("{retries} retries"),
        (Kind::Rtt { .. }, Some(_), _) => "0".into(),
        (Kind::Thr { best_effort: false }, Some((l, _)), _) => l.to_string(),
        (Kind::Thr { best_effort: true }, Some((l, t)), _) => {
            format!("{l} ({:.1} %)", 100.0 * l as f64 / t.max(1) as f64)
        }
    }
}

fn orchestrate(args: &[String]) {
    let (floor_only, args) = match args.first().map(String::as_str) {
        Some("floor") => (true, &args[1..]),
        _ => (false, args),
    };
    let mut quick = false;
    let mut no_ddsperf = false;
    let mut filter: Option<String> = None;
    let mut threads = 1;
    let mut busy_poll_us = 0;
    let mut reps: usize = 1;
    // `None`: each library's own default datagram size
    let mut max_message_sizes: Vec<Option<usize>> = vec![None];
    let mut it = args.iter();
    while let Some(a) = it.next() {
        match a.as_str() {
            "--quick" => quick = true,
            "--reps" => {
                reps = it
                    .next()
                    .and_then(|s| s.parse().ok())
                    .filter(|&r| r >= 1)
                    .unwrap_or_else(|| usage())
            }
            "--busy-poll" => {
                busy_poll_us = it
                    .next()
                    .and_then(|s| s.parse().ok())
                    .unwrap_or_else(|| usage())
            }
            "--max-message-size" => {
                max_message_sizes = it
                    .next()
                    .map(|s| {
                        s.split(',')
                            .map(|n| n.trim().parse().ok().map(Some))
                            .collect()
                    })
                    .and_then(|v: Option<Vec<_>>| v.filter(|v| !v.is_empty()))
                    .unwrap_or_else(|| usage())
            }
            "--no-ddsperf" => no_ddsperf = true,
            "--filter" => filter = it.next().cloned(),
            "--threads" => {
                threads = it
                    .next()
                    .and_then(|s| s.parse().ok())
                    .unwrap_or_else(|| usage())
            }
            _ => usage(),
        }
    }
    let ddsperf = if no_ddsperf {
        Err("skipped (--no-ddsperf)".to_string())
    } else {
        find_ddsperf()
    };
    if Command::new("taskset").arg("-V").output().is_err() {
        eprintln!("rtps_bench needs taskset (util-linux) to place the processes");
        std::process::exit(1);
    }
    let exe = std::env::current_exe().expect("own path");
    if floor_only {
        floor::table(&exe, reps, quick);
        return;
    }
    let mut orch = Orchestrator {
        exe,
        quick,
        ddsperf,
        domain: 229,
        threads,
        busy_poll_us,
        max_message_size: None,
    };
    let cases = [
        Case {
            kind: Kind::Rtt { listener: true },
            size: 16,
        },
        Case {
            kind: Kind::Rtt { listener: true },
            size: 4096,
        },
        Case {
            kind: Kind::Rtt { listener: false },
            size: 16,
        },
        Case {
            kind: Kind::Rtt { listener: false },
            size: 4096,
        },
        Case {
            kind: Kind::Thr { best_effort: false },
            size: 16,
        },
        Case {
            kind: Kind::Thr { best_effort: false },
            size: 64 << 10,
        },
        // large samples: a burst of fragments longer than the reader's
        // socket buffer (1 MiB asked for by both), repaired by NACK_FRAG
        Case {
            kind: Kind::Thr { best_effort: false },
            size: 1 << 20,
        },
        Case {
            kind: Kind::Thr { best_effort: false },
            size: 8 << 20,
        },
        Case {
            kind: Kind::Thr { best_effort: true },
            size: 16,
        },
        Case {
            kind: Kind::Thr { best_effort: true },
            size: 64 << 10,
        },
    ];
    let started = Instant::now();
    let mut rows = Vec::new();
    // every datagram size in turn, each row named with its own when one is set
    let runs = max_message_sizes
        .iter()
        .flat_map(|&mm| cases.iter().map(move |&c| (mm, c)));
    for (mm, case) in runs {
        orch.max_message_size = mm;
        for pl in PLACEMENTS {
            let name = match mm {
                Some(n) => format!("{} {}, {n} B datagrams", case.name(), pl.name),
                None => format!("{} {}", case.name(), pl.name),
            };
            if filter.as_ref().is_some_and(|f| !name.contains(f.as_str())) {
                continue;
            }
            // Courier and ddsperf alternate, `reps` runs each
            let (mut cs, mut ds) = (Vec::new(), Vec::new());
            let mut foreign: Option<f64> = None;
            for _ in 0..reps {
                let t = Instant::now();
                let s0 = cpu_ticks();
                let c = orch.courier(case, pl);
                let tc = t.elapsed().as_secs_f64();
                let s1 = cpu_ticks();
                let d = orch.ddsperf(case, pl);
                let td = t.elapsed().as_secs_f64() - tc;
                let s2 = cpu_ticks();
                // the busiest phase of all
                for f in [foreign_load(s0, s1, tc), foreign_load(s1, s2, td)]
                    .into_iter()
                    .flatten()
                {
                    foreign = Some(foreign.map_or(f, |g| g.max(f)));
                }
                eprintln!(
                    "{name}: Courier {} in {tc:.1} s, ddsperf {} in {td:.1} s; other processes: {}",
                    cell(case.kind, &c),
                    cell(case.kind, &d),
                    foreign.map_or("?".into(), |f| format!("{f:.2} CPU")),
                );
                cs.push(c);
                ds.push(d);
            }
            let (c, d) = (median_outcome(case.kind, cs), median_outcome(case.kind, ds));
            let name = if foreign.is_some_and(|f| f > BUSY) {
                format!("{name} ⚠")
            } else {
                name
            };
            rows.push((name, case.kind, c, d));
        }
    }
    println!(
        "\nRTPS on loopback, Courier ↔ Courier vs Cyclone ddsperf ↔ ddsperf ({}; {}; {}; {} CPUs \
         online; {:.0} s)\n",
        match &max_message_sizes[..] {
            [None] => "each one's default datagram size (Courier 65500 B on loopback, \
                     Cyclone 14720 B)"
                .to_string(),
            sizes => format!(
                "datagrams of at most the row's size for both libraries: {}",
                sizes
                    .iter()
                    .map(|m| m.map_or("each one's default".into(), |n| format!("{n} B")))
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        },
        if quick {
            "--quick: short smoke run, not for comparison"
        } else {
            "default durations"
        },
        if reps > 1 {
            format!("median of {reps} alternating runs, their range in brackets")
        } else {
            "one run each".to_string()
        },
        std::thread::available_parallelism().map_or(0, |n| n.get()),
        started.elapsed().as_secs_f64()
    );
    println!("| measurement | Courier | ddsperf | ratio | goal | lost: Courier | lost: ddsperf |");
    println!("|---|---|---|---|---|---|---|");
    let busy_rows = rows.iter().any(|r| r.0.ends_with('⚠'));
    for (name, kind, c, d) in rows {
        let (ratio, goal) = match (c.value, d.value, c.note.is_none() && d.note.is_none()) {
            (Some(cv), Some(dv), true) => {
                let r = cv / dv;
                match kind {
                    Kind::Rtt { .. } => (
                        format!("{r:.2}×"),
                        format!("≤ 1.0× {}", if r <= 1.0 { "met" } else { "NOT met" }),
                    ),
                    Kind::Thr { .. } => (
                        format!("{r:.2}×"),
                        format!("≥ 1.0× {}", if r >= 1.0 { "met" } else { "NOT met" }),
                    ),
                }
            }
            _ => (
                "–".into(),
                match kind {
                    Kind::Rtt { .. } => "≤ 1.0× (no comparison)".into(),
                    Kind::Thr { .. } => "≥ 1.0× (no comparison)".into(),
                },
            ),
        };
        println!(
            "| {name} | {} | {} | {ratio} | {goal} | {} | {} |",
            cell(kind, &c),
            cell(kind, &d),
            lost_cell(kind, &c),
            lost_cell(kind, &d)
        );
    }
    println!(
        "\nrtt: median round trip (p99), one request in flight; callback: Courier answers \
         from `listen` callbacks on its receive thread (--listener), ddsperf in listener mode; \
         stream: Courier awaits a Subscriber stream in a tokio task, ddsperf in waitset mode. thr: samples/s received \
         in steady state, MB/s = samples/s × payload bytes. ratio = Courier / ddsperf. \
         lost (thr): samples sent but never received (best effort: % of sent); \
         lost (rtt): pings re-sent after {} ms without an answer.",
        PING_RETRY.as_millis()
    );
    if busy_rows {
        println!(
            "⚠: other processes used more than {BUSY} CPU during this row (see stderr): \
             the numbers are not comparable; re-run on an idle machine."
        );
    }
}
