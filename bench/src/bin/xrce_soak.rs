//! Soak of Courier's XRCE agent (issue 28 item 6): many XRCE clients
//! (Courier sessions over `xrce+udp://`, all in one client process)
//! each publish a small sample at a fixed rate for minutes through one
//! agent process; one more session (in this process) reads them all. Every
//! 10 s the agent's CPU % (utime + stime from /proc/PID/stat) and resident
//! memory (VmRSS from /proc/PID/status) are sampled and printed as a table
//! row, with what was delivered and lost. Both must stay flat.
//!
//! ```text
//! cargo run --release -p courier-bench --bin xrce_soak                       # 200 clients, 10 Hz, 10 min
//! cargo run --release -p courier-bench --bin xrce_soak -- --minutes 1 --clients 50
//! ```
//!
//! Like `xrce_bench`, it runs inside a private network namespace with only
//! `lo` (`unshare -rn`); the agent's DDS participant uses lo with unicast
//! discovery. The agent is on CPU 1, the clients on CPU 0 (`--no-pin`: not
//! placed).

use std::process::{Command, ExitCode};
use std::time::{Duration, Instant};

use courier::{IpcMessage, QueuePolicy, Session};
use futures::StreamExt;

#[allow(dead_code)]
#[path = "../xrce_procs.rs"]
mod procs;

use procs::{cpu_secs, rss_kib, Proc};

/// One client's sample: who, its sequence number, and 16 bytes.
#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "courier::bench::Telemetry")]
struct Telemetry {
    client: u32,
    seq: u32,
    payload: [u8; 16],
}

const TOPIC: &str = "soak_telemetry";
/// Sampling period of the agent's CPU and memory.
const PERIOD: Duration = Duration::from_secs(10);

struct Opts {
    clients: usize,
    hz: f64,
    minutes: f64,
    pin: bool,
    port: u16,
}

fn parse(args: &[String]) -> Result<Opts, String> {
    let mut o = Opts {
        clients: 200,
        hz: 10.0,
        minutes: 10.0,
        pin: true,
        port: 0,
    };
    let mut it = args.iter();
    while let Some(a) = it.next() {
        let mut num = || -> Result<f64, String> {
            it.next()
                .and_then(|v| v.parse::<f64>().ok())
                .filter(|v| v.is_finite() && *v > 0.0)
                .ok_or_else(|| format!("{a} needs a positive number"))
        };
        match a.as_str() {
            "--clients" => o.clients = num()?.min(5000.0) as usize,
            "--hz" => o.hz = num()?.min(1000.0),
            "--minutes" => o.minutes = num()?.min(24.0 * 60.0),
            "--port" => o.port = num()?.min(65535.0) as u16,
            "--no-pin" => o.pin = false,
            "-h" | "--help" => {
                return Err(
                    "usage: xrce_soak [--clients N] [--hz F] [--minutes M] [--no-pin]\n\
                     \x20      xrce_soak clients --port P [--clients N] [--hz F] [--minutes M]"
                        .into(),
                )
            }
            other => return Err(format!("unknown argument {other:?} (try --help)")),
        }
    }
    Ok(o)
}

fn url(port: u16) -> String {
    // a lost agent is noticed after 3 s of silence; keep the default
    format!("xrce+udp://127.0.0.1:{port}")
}

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let r = match args.first().map(String::as_str) {
        Some("courier-agent") => procs::courier_agent_role(&args[1..]),
        Some("clients") => parse(&args[1..]).and_then(|o| runtime()?.block_on(clients(o))),
        _ => return orchestrate(&args),
    };
    match r {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            println!("RESULT error={}", e.replace(' ', "_"));
            eprintln!("xrce_soak: {e}");
            ExitCode::FAILURE
        }
    }
}

fn runtime() -> Result<tokio::runtime::Runtime, String> {
    tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .map_err(|e| e.to_string())
}

/// The `clients` role: `--clients` sessions, each publishing reliably at
/// `--hz` for `--minutes`; prints `RESULT sent=N failed=F`.
async fn clients(o: Opts) -> Result<(), String> {
    let period = Duration::from_secs_f64(1.0 / o.hz);
    let mut sessions = Vec::with_capacity(o.clients);
    for i in 0..o.clients {
        let s = tokio::time::timeout(
            Duration::from_secs(30),
            Session::builder(url(o.port))
                .name(format!("soak-{i}"))
                .connect(),
        )
        .await
        .map_err(|_| format!("client {i}: connect timed out"))?
        .map_err(|e| format!("client {i}: {e}"))?;
        let p = s
            .publisher::<Telemetry>(TOPIC)
            .reliable()
            .keep_all()
            .build()
            .await
            .map_err(|e| format!("client {i}: {e}"))?;
        sessions.push((s, p));
    }
    println!("connected {}", sessions.len());
    let end = Instant::now() + Duration::from_secs_f64(o.minutes * 60.0);
    let mut tasks = tokio::task::JoinSet::new();
    for (i, (s, p)) in sessions.into_iter().enumerate() {
        // spread the clients over the period
        let offset = period.mul_f64(i as f64 / o.clients as f64);
        tasks.spawn(async move {
            tokio::time::sleep(offset).await;
            let mut tick = tokio::time::interval(period);
            tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
            let mut v = Telemetry {
                client: i as u32,
                seq: 0,
                payload: [0x5a; 16],
            };
            let (mut sent, mut failed) = (0u64, 0u64);
            while Instant::now() < end {
                tick.tick().await;
                match p.publish(&v).await {
                    Ok(()) => sent += 1,
                    Err(e) => {
                        failed += 1;
                        eprintln!("client {i}: {e}");
                    }
                }
                v.seq += 1;
            }
            // the last one confirmed: every earlier one reached the agent
            let _ = p
                .publish(&v)
                .confirmed_within(Duration::from_secs(10))
                .await
                .map(|()| sent += 1)
                .map_err(|_| failed += 1);
            s.close().await;
            (sent, failed)
        });
    }
    let (mut sent, mut failed) = (0u64, 0u64);
    while let Some(r) = tasks.join_next().await {
        let (s, f) = r.map_err(|e| e.to_string())?;
        sent += s;
        failed += f;
    }
    println!("RESULT sent={sent} failed={failed}");
    Ok(())
}

/// What the reading session counted.
#[derive(Default, Clone, Copy)]
struct Counts {
    delivered: u64,
    /// Samples skipped: a sequence number past the one expected.
    gaps: u64,
    /// Samples at or before one already seen.
    repeated: u64,
}

fn orchestrate(args: &[String]) -> ExitCode {
    let o = match parse(args) {
        Ok(o) => o,
        Err(e) => {
            eprintln!("{e}");
            return ExitCode::from(2);
        }
    };
    if o.pin && Command::new("taskset").arg("-V").output().is_err() {
        eprintln!("taskset (util-linux) not found: give --no-pin");
        return ExitCode::FAILURE;
    }
    if let Some(code) = procs::enter_private_netns(args) {
        return code;
    }
    match runtime().and_then(|rt| rt.block_on(soak(&o))) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("xrce_soak: {e}");
            ExitCode::FAILURE
        }
    }
}

fn cmd(o: &Opts, cpu: &str) -> Result<Command, String> {
    let exe = std::env::current_exe().map_err(|e| e.to_string())?;
    Ok(if o.pin {
        let mut c = Command::new("taskset");
        c.arg("-c").arg(cpu).arg(exe);
        c
    } else {
        Command::new(exe)
    })
}

async fn soak(o: &Opts) -> Result<(), String> {
    let port = procs::free_udp_port()?;
    let mut c = cmd(o, "1")?;
    c.args(["courier-agent", "--port", &port.to_string()]);
    let mut agent = Proc::spawn("courier-agent", c)?;
    agent.wait_line("ready", Duration::from_secs(20))?;
    let agent_pid = agent.pid();

    let reader = Session::builder(url(port))
        .name("soak-reader")
        .connect()
        .await
        .map_err(|e| format!("reader: {e}"))?;
    let mut sub = reader
        .subscriber::<Telemetry>(TOPIC)
        .reliable()
        .queue(QueuePolicy::KeepAll(1 << 16))
        .build()
        .await
        .map_err(|e| format!("reader: {e}"))?;

    let mut c = cmd(o, "0")?;
    c.args(["clients", "--port", &port.to_string()])
        .args(["--clients", &o.clients.to_string()])
        .args(["--hz", &o.hz.to_string()])
        .args(["--minutes", &o.minutes.to_string()]);
    let mut clients = Proc::spawn("clients", c)?;
    let connect_limit = Duration::from_secs(60 + o.clients as u64 / 2);
    let t_conn = Instant::now();
    // read `connected` on a thread (it blocks); meanwhile keep reading samples
    let (tx, rx) = tokio::sync::oneshot::channel();
    let waiter = std::thread::spawn(move || {
        let r = clients.wait_line("connected", connect_limit);
        let _ = tx.send(r);
        clients
    });
    let mut expect: Vec<u32> = vec![0; o.clients];
    let mut c = Counts::default();
    let mut on_sample = |t: &Telemetry, c: &mut Counts| {
        c.delivered += 1;
        let Some(e) = expect.get_mut(t.client as usize) else {
            return;
        };
        if t.seq > *e {
            c.gaps += u64::from(t.seq - *e);
        } else if t.seq < *e {
            c.repeated += 1;
        }
        *e = t.seq.max(*e) + 1;
    };
    tokio::pin!(rx);
    loop {
        tokio::select! {
            r = &mut rx => {
                r.map_err(|_| "clients: waiter ended".to_string())??;
                break;
            }
            s = sub.next() => match s {
                Some(Ok(s)) => on_sample(&s.value, &mut c),
                Some(Err(e)) => return Err(format!("reader: {e}")),
                None => return Err("reader: session closed".into()),
            },
        }
    }
    let clients = waiter.join().map_err(|_| "waiter panicked".to_string())?;
    eprintln!(
        "{} clients connected in {:.1} s",
        o.clients,
        t_conn.elapsed().as_secs_f64()
    );

    let load0 = std::fs::read_to_string("/proc/loadavg").unwrap_or_default();
    let started = Instant::now();
    let end = started + Duration::from_secs_f64(o.minutes * 60.0);
    let mut rows = Vec::new();
    let mut last_cpu = cpu_secs(agent_pid).ok_or("agent gone")?;
    let mut last_t = Instant::now();
    let mut last_c = c;
    let mut next_sample = started + PERIOD;
    let header = "| t (s) | agent CPU % | agent RSS (MiB) | delivered in 10 s | delivered total | gaps | repeated |";
    println!("{header}\n|---|---|---|---|---|---|---|");
    // the last row at `end` (the clients stop then)
    while next_sample <= end + Duration::from_millis(500) {
        tokio::select! {
            s = sub.next() => match s {
                Some(Ok(s)) => on_sample(&s.value, &mut c),
                Some(Err(e)) => return Err(format!("reader: {e}")),
                None => return Err("reader: session closed".into()),
            },
            _ = tokio::time::sleep_until(next_sample.into()) => {
                let now = Instant::now();
                let cpu = cpu_secs(agent_pid).ok_or("the agent died")?;
                let rss = rss_kib(agent_pid).ok_or("the agent died")?;
                let pct = (cpu - last_cpu) / now.duration_since(last_t).as_secs_f64() * 100.0;
                let row = (
                    now.duration_since(started).as_secs_f64(),
                    pct,
                    rss as f64 / 1024.0,
                    c.delivered - last_c.delivered,
                    c,
                );
                println!(
                    "| {:.0} | {:.1} | {:.1} | {} | {} | {} | {} |",
                    row.0, row.1, row.2, row.3, c.delivered, c.gaps, c.repeated
                );
                rows.push(row);
                (last_cpu, last_t, last_c) = (cpu, now, c);
                next_sample += PERIOD;
            }
        }
    }
    // the clients send their last samples confirmed and leave: wait for
    // their count, reading what is still on its way
    let (tx, rx) = tokio::sync::oneshot::channel();
    std::thread::spawn(move || {
        let _ = tx.send(clients.finish(Duration::from_secs(60)));
    });
    tokio::pin!(rx);
    let out = loop {
        tokio::select! {
            r = &mut rx => break r.map_err(|_| "clients: waiter ended".to_string())??,
            s = sub.next() => match s {
                Some(Ok(s)) => on_sample(&s.value, &mut c),
                Some(Err(e)) => return Err(format!("reader: {e}")),
                None => return Err("reader: session closed".into()),
            },
        }
    };
    let line = out
        .lines()
        .rev()
        .find(|l| l.starts_with("RESULT "))
        .ok_or_else(|| format!("clients printed no RESULT: {out:?}"))?;
    let field = |k: &str| -> Option<u64> {
        line.split_whitespace()
            .find_map(|kv| kv.strip_prefix(k)?.strip_prefix('=')?.parse().ok())
    };
    let (Some(sent), failed) = (field("sent"), field("failed").unwrap_or(0)) else {
        return Err(format!("clients: {line}"));
    };
    // what is still queued in the agent
    let drain_end = Instant::now() + Duration::from_secs(10);
    while c.delivered < sent {
        match tokio::time::timeout_at(drain_end.into(), sub.next()).await {
            Ok(Some(Ok(s))) => on_sample(&s.value, &mut c),
            _ => break,
        }
    }
    reader.close().await;
    drop(agent);
    summary(o, &rows, sent, failed, c, &load0);
    Ok(())
}

type Row = (f64, f64, f64, u64, Counts);

fn summary(o: &Opts, rows: &[Row], sent: u64, failed: u64, c: Counts, load0: &str) {
    let load1 = std::fs::read_to_string("/proc/loadavg").unwrap_or_default();
    let first3 = |s: &str| s.split_whitespace().take(3).collect::<Vec<_>>().join(" ");
    println!(
        "\n{} clients × {} Hz for {} min through Courier's agent ({} expected samples/s); \
         sent {sent} (publish errors {failed}), delivered {}, lost {}, gaps {}, repeated {}; \
         loadavg at start {}, at end {}",
        o.clients,
        o.hz,
        o.minutes,
        o.clients as f64 * o.hz,
        c.delivered,
        sent.saturating_sub(c.delivered),
        c.gaps,
        c.repeated,
        first3(load0),
        first3(&load1)
    );
    // flat: the second half against the first (the first row is warm-up)
    let steady: Vec<&Row> = rows.iter().skip(1).collect();
    if steady.len() >= 4 {
        let half = steady.len() / 2;
        let mean =
            |r: &[&Row], f: fn(&Row) -> f64| r.iter().map(|x| f(x)).sum::<f64>() / r.len() as f64;
        let (c1, c2) = (
            mean(&steady[..half], |r| r.1),
            mean(&steady[half..], |r| r.1),
        );
        let (m1, m2) = (
            mean(&steady[..half], |r| r.2),
            mean(&steady[half..], |r| r.2),
        );
        let rss_last = steady.last().map_or(0.0, |r| r.2);
        let rss_max = steady.iter().map(|r| r.2).fold(0.0, f64::max);
        println!(
            "agent CPU: mean {c1:.1} % in the first half, {c2:.1} % in the second; RSS: mean \
             {m1:.1} MiB then {m2:.1} MiB, last {rss_last:.1} MiB, highest {rss_max:.1} MiB"
        );
    }
}
