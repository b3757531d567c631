//! Round trips and throughput through the Session API, routed through a
//! central and direct (module to module), printed as a table — like
//! zenoh's z_ping/z_pong, usable as a tool.
//!
//! ```text
//! cargo run --release -p courier-bench --bin session-bench            # embedded centrals
//! cargo run --release -p courier-bench --bin session-bench -- --url ipc://127.0.0.1:1381
//! ```
//! With `--url` the given central is used for the routed column only (start
//! a second one with `-c` and pass `--direct-url` for the direct column).
//! Every number is the median of three runs after a warm-up.
//!
//! As separate processes, each a current-thread runtime (z_ping/z_pong):
//!
//! ```text
//! session-bench pong --url ipc://127.0.0.1:1381 [--busy-poll <us>] [--embed] [--cut-through <bytes>]
//! session-bench ping --url ipc://127.0.0.1:1381 [--busy-poll <us>] [--embed] [--publish] [--size 4] [--count 20000]
//! ```
//! With `--embed` the role hosts central itself, on the URL's port (and
//! its UNIX socket), and reaches it over an in-process link
//! (`CentralHandle::session`); the other role connects to it as usual.
//! `pong` answers queries on `rtt_ask` with `rtt_answer` and republishes
//! `rtt_ping` as `rtt_pong` (format `{int, <ubyte:1>}`, the same names as
//! the C measuring programs use) until its standard input closes; `ping`
//! times `--count` query round trips (or publish→pong round trips with
//! `--publish`) after a tenth as many for warm-up and prints one line:
//! `query_rtt size=4 n=20000 median_us=.. p99_us=.. mean_us=..`.
//!
//! `session-bench processes` runs those roles as processes through
//! `central` processes and prints a table of 4 B round trips: clients
//! (Courier, Courier with `--busy-poll`, and the C library's when
//! `--c-rtt DIR` names its measuring programs) × centrals (Courier's,
//! Courier's with `--busy-poll`, the C one with `--c-central PATH`, and
//! Courier's hosted by the answering module with `pong --embed`) ×
//! transport (TCP, and the UNIX socket `/tmp/x_ipc/<port>`, which C and
//! Courier modules use when the host is the machine's own name):
//!
//! ```text
//! session-bench processes [--central PATH] [--c-central PATH] [--c-rtt DIR]
//!                         [--publish | --throughput] [--size S] [--count N]
//!                         [--reps R] [--busy-poll US] [--cut-through BYTES]
//!                         [--send-ahead N] [--relay-floor] [--only c-clients]
//! ```
//! `--cut-through` starts Courier's centrals (and the hosted one) with that
//! option; `--send-ahead N` sends up to N broadcasts ahead to the two
//! subscribers of the throughput runs (`rtt_pong` and the C `tput_sub`).
//! The C measuring programs in `--c-rtt DIR` are built outside the
//! repository against the C library: `qrtt_server` / `qrtt_client COUNT
//! SIZE` (query round trips on `rtt_ask`), `prtt b` / `prtt a COUNT SIZE`
//! (publish round trips, `rtt_ping` → `rtt_pong`), `tput_pub COUNT SIZE` /
//! `tput_sub COUNT` (capacity-1 throughput on `tput_data`, timed by the
//! subscriber from its first delivery to its last). The timing one prints a
//! line in the format of `ping`'s; the other runs until its standard input
//! closes.
//!
//! `--relay-floor` adds the relay floor (`ipc_relay_floor.rs`) in each of
//! its shapes. `session-bench relay-sweep [--reps R] [--count N] [--work
//! NS,...] [--one-cpu]` times only the poll-loop and tokio relays, each with
//! the given busy work per frame: what a central's CPU per message costs a
//! round trip, unpinned or with every process on CPU 0.

#[path = "../../../examples/appendix_a.rs"]
mod appendix;
#[path = "../ipc_relay_floor.rs"]
mod relay_floor;

use std::time::{Duration, Instant};

use courier::{IpcMessage, Session};
use courier_broker::{CentralHandle, CentralServer, Config};
use futures::StreamExt;

const T: Duration = Duration::from_secs(30);

/// `{int, <ubyte:1>}`: a payload of any size.
#[derive(IpcMessage, Debug, Clone, PartialEq)]
struct Blob {
    n: i32,
    #[ipc(len = "n")]
    data: Vec<u8>,
}

#[derive(Clone, Copy)]
enum Kind {
    Pub,
    Query,
    Throughput,
}

struct Pair {
    a: Session,
    b: Session,
}

async fn pair(url: &str, tag: &str) -> Pair {
    let a = Session::builder(url)
        .name(format!("bench-a-{tag}"))
        .connect()
        .await
        .expect("connect a");
    let b = Session::builder(url)
        .name(format!("bench-b-{tag}"))
        .connect()
        .await
        .expect("connect b");
    Pair { a, b }
}

static RUN: std::sync::atomic::AtomicU32 = std::sync::atomic::AtomicU32::new(0);

/// Seconds per operation. Every run uses fresh message names, so no
/// subscription of an earlier run is still being torn down.
async fn run(p: &Pair, kind: Kind, size: usize, count: usize) -> f64 {
    let n = RUN.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let (ping, pong, ask, answer) = (
        format!("ping{n}"),
        format!("pong{n}"),
        format!("ask{n}"),
        format!("answer{n}"),
    );
    for m in [&ping, &pong, &ask, &answer] {
        p.a.define::<Blob>(m).await.expect("define");
    }
    let payload = Blob {
        n: size as i32,
        data: vec![7u8; size],
    };
    match kind {
        Kind::Pub => {
            let mut pings = p.b.subscribe::<Blob>(&ping).await.unwrap();
            let mut pongs = p.a.subscribe::<Blob>(&pong).await.unwrap();
            p.a.num_handlers(&ping).await.unwrap();
            p.b.num_handlers(&pong).await.unwrap();
            let b = p.b.clone();
            let pong2 = pong.clone();
            let echo = tokio::spawn(async move {
                for _ in 0..count {
                    let s = pings.next().await.unwrap().unwrap();
                    b.publish(&pong2, &s.value).await.unwrap();
                }
            });
            // The broadcast lists settle before timing.
            tokio::time::sleep(Duration::from_millis(50)).await;
            let start = Instant::now();
            for _ in 0..count {
                p.a.publish(&ping, &payload).await.unwrap();
                tokio::time::timeout(T, pongs.next())
                    .await
                    .unwrap()
                    .unwrap()
                    .unwrap();
            }
            let secs = start.elapsed().as_secs_f64();
            echo.await.unwrap();
            secs / count as f64
        }
        Kind::Query => {
            let mut reqs = p.b.serve::<Blob, Blob>(&ask, &answer).await.unwrap();
            p.a.num_handlers(&ask).await.unwrap();
            let srv = tokio::spawn(async move {
                for _ in 0..count {
                    let r = reqs.next().await.unwrap().unwrap();
                    let v = r.value.clone();
                    r.reply(&v).await.unwrap();
                }
            });
            let start = Instant::now();
            for _ in 0..count {
                let r: Blob = p.a.query(&ask, &payload).timeout(T).await.unwrap();
                assert_eq!(r.data.len(), size);
            }
            let secs = start.elapsed().as_secs_f64();
            srv.await.unwrap();
            secs / count as f64
        }
        Kind::Throughput => {
            let mut pings = p.b.subscribe::<Blob>(&ping).await.unwrap();
            p.a.num_handlers(&ping).await.unwrap();
            tokio::time::sleep(Duration::from_millis(50)).await;
            let recv = tokio::spawn(async move {
                for _ in 0..count {
                    tokio::time::timeout(T, pings.next())
                        .await
                        .unwrap()
                        .unwrap()
                        .unwrap();
                }
                Instant::now()
            });
            let start = Instant::now();
            for _ in 0..count {
                p.a.publish(&ping, &payload).await.unwrap();
            }
            let end = recv.await.unwrap();
            (end - start).as_secs_f64() / count as f64
        }
    }
}

/// One loopback TCP round trip, no protocol (the reference for direct mode).
async fn raw_tcp_rtt(count: usize) -> f64 {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let l = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = l.local_addr().unwrap();
    let echo = tokio::spawn(async move {
        let (mut s, _) = l.accept().await.unwrap();
        s.set_nodelay(true).unwrap();
        let mut b = [0u8; 4];
        for _ in 0..count {
            s.read_exact(&mut b).await.unwrap();
            s.write_all(&b).await.unwrap();
        }
    });
    let mut s = tokio::net::TcpStream::connect(addr).await.unwrap();
    s.set_nodelay(true).unwrap();
    let mut b = [0u8; 4];
    let start = Instant::now();
    for _ in 0..count {
        s.write_all(&b).await.unwrap();
        s.read_exact(&mut b).await.unwrap();
    }
    let secs = start.elapsed().as_secs_f64();
    echo.await.unwrap();
    secs / count as f64
}

async fn median(p: &Pair, kind: Kind, size: usize, count: usize) -> f64 {
    run(p, kind, size, (count / 10).max(1)).await;
    let mut v = Vec::new();
    for _ in 0..3 {
        v.push(run(p, kind, size, count).await);
    }
    v.sort_by(f64::total_cmp);
    v[1]
}

/// How a role's process runs.
#[derive(Clone, Copy)]
struct RoleOpts {
    /// Busy polling of the session (and of the embedded central).
    spin: Option<Duration>,
    /// Host central in this process, on the URL's port, and reach it over
    /// an in-process link (`CentralHandle::session`).
    embed: bool,
    /// The embedded central's `Config::cut_through`.
    cut_through: Option<usize>,
    /// The embedded central's `Config::send_ahead` for the subscribers.
    send_ahead: usize,
}

/// The role's session, and the central it hosts with `--embed` (dropping
/// it stops central).
async fn role_session(url: &str, name: &str, o: RoleOpts) -> (Session, Option<CentralHandle>) {
    let (mut b, central) = if o.embed {
        let (_, port) = courier::ipc_backend::parse_url(url).expect("an ipc:// URL");
        let mut config = Config::default();
        config.cut_through = o.cut_through;
        if o.send_ahead > 0 {
            config.send_ahead = SUBSCRIBERS
                .iter()
                .map(|m| (m.to_string(), o.send_ahead))
                .collect();
        }
        let mut c = CentralServer::builder()
            .bind([127, 0, 0, 1].into())
            .port(port)
            .config(config)
            .log_sink(courier_broker::LogSink::discard());
        if let Some(w) = o.spin {
            c = c.busy_poll(w);
        }
        let c = c.spawn().await.expect("start the embedded central");
        (c.session(name), Some(c))
    } else {
        (Session::builder(url).name(name), None)
    };
    if let Some(w) = o.spin {
        b = b.busy_poll(w);
    }
    let s = b.connect().await.expect("connect");
    for m in ["rtt_ask", "rtt_answer", "rtt_ping", "rtt_pong", "rtt_flood"] {
        s.define::<Blob>(m).await.expect("define");
    }
    (s, central)
}

async fn pong(url: &str, o: RoleOpts) {
    let (s, _central) = role_session(url, "rtt_pong", o).await;
    let mut reqs = s
        .serve::<Blob, Blob>("rtt_ask", "rtt_answer")
        .await
        .unwrap();
    let mut pings = s.subscribe::<Blob>("rtt_ping").await.unwrap();
    let mut flood = s.subscribe::<Blob>("rtt_flood").await.unwrap();
    println!("ready");
    // Ends when standard input closes (the parent went away).
    let (tx, mut stdin_closed) = tokio::sync::oneshot::channel::<()>();
    std::thread::spawn(move || {
        use std::io::Read;
        let mut b = [0u8; 64];
        while matches!(std::io::stdin().read(&mut b), Ok(n) if n > 0) {}
        let _ = tx.send(());
    });
    loop {
        tokio::select! {
            r = reqs.next() => match r {
                Some(Ok(r)) => {
                    let v = r.value.clone();
                    r.reply(&v).await.unwrap();
                }
                _ => break,
            },
            f = flood.next() => if f.is_none() { break },
            p = pings.next() => match p {
                Some(Ok(p)) => s.publish("rtt_pong", &p.value).await.unwrap(),
                _ => break,
            },
            _ = &mut stdin_closed => break,
        }
    }
    s.close().await;
}

/// Waits until every message in `msgs` has a handler (`pong` subscribed).
async fn wait_for_handlers(s: &Session, msgs: &[&str]) {
    let t0 = Instant::now();
    for msg in msgs {
        while s.num_handlers(msg).await.unwrap() < 1 {
            assert!(t0.elapsed() < T, "nobody handles {msg}: is `pong` running?");
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
    }
}

/// One-way throughput: `count` messages on `rtt_flood` (which `pong`
/// takes at capacity 1, each acknowledged to central), then one query: its
/// answer comes after central delivered every message before it.
async fn flood(url: &str, o: RoleOpts, size: usize, count: usize) {
    let (s, _central) = role_session(url, "rtt_flood", o).await;
    wait_for_handlers(&s, &["rtt_flood", "rtt_ask"]).await;
    let payload = Blob {
        n: size as i32,
        data: vec![7u8; size],
    };
    let mut rates = Vec::new();
    for round in 0..2 {
        let n = if round == 0 { count / 10 } else { count };
        let start = Instant::now();
        for _ in 0..n {
            s.publish("rtt_flood", &payload).await.unwrap();
        }
        let _: Blob = s.query("rtt_ask", &payload).timeout(T).await.unwrap();
        rates.push(n as f64 / start.elapsed().as_secs_f64());
    }
    println!(
        "throughput size={size} n={count} msgs_per_s={:.0}",
        rates[1]
    );
    s.close().await;
}

async fn ping(url: &str, o: RoleOpts, publish: bool, size: usize, count: usize) {
    let (s, _central) = role_session(url, "rtt_ping", o).await;
    let target = if publish { "rtt_ping" } else { "rtt_ask" };
    let mut pongs = s.subscribe::<Blob>("rtt_pong").await.unwrap();
    wait_for_handlers(&s, &[target]).await;
    let payload = Blob {
        n: size as i32,
        data: vec![7u8; size],
    };
    let mut rtts = Vec::with_capacity(count);
    for i in 0..count / 10 + count {
        let start = Instant::now();
        if publish {
            s.publish("rtt_ping", &payload).await.unwrap();
            tokio::time::timeout(T, pongs.next())
                .await
                .expect("pong within 30 s")
                .unwrap()
                .unwrap();
        } else {
            let r: Blob = s.query("rtt_ask", &payload).timeout(T).await.unwrap();
            assert_eq!(r.data.len(), size);
        }
        if i >= count / 10 {
            rtts.push(start.elapsed().as_secs_f64() * 1e6);
        }
    }
    rtts.sort_by(f64::total_cmp);
    let mean = rtts.iter().sum::<f64>() / rtts.len() as f64;
    println!(
        "{} size={size} n={count} median_us={:.1} p99_us={:.1} mean_us={mean:.1}",
        if publish { "publish_rtt" } else { "query_rtt" },
        rtts[rtts.len() / 2],
        rtts[rtts.len() * 99 / 100],
    );
    s.close().await;
}

/// The subscribers of the throughput runs: Courier's `pong` and the C
/// library's `tput_sub` (`--send-ahead`).
const SUBSCRIBERS: [&str; 2] = ["rtt_pong", "tput_sub"];

/// `ping`/`pong`: a role per process, each on a current-thread runtime.
fn role(role: &str, mut args: impl Iterator<Item = String>) {
    let mut url = String::from("ipc://127.0.0.1:1381");
    let mut spin = None;
    let mut embed = false;
    let mut cut_through = None;
    let mut send_ahead = 0;
    let mut publish = false;
    let mut throughput = false;
    let mut size = 4usize;
    let mut count = 20_000usize;
    let num = |flag: &str, v: Option<String>| -> u64 {
        match v.as_deref().map(str::parse::<u64>) {
            Some(Ok(n)) if n > 0 => n,
            _ => {
                eprintln!("{flag} needs a positive number (got {v:?})");
                std::process::exit(2)
            }
        }
    };
    while let Some(a) = args.next() {
        match a.as_str() {
            "--url" => url = args.next().unwrap_or_default(),
            "--busy-poll" => spin = Some(Duration::from_micros(num(&a, args.next()))),
            "--embed" => embed = true,
            "--cut-through" => cut_through = Some(num(&a, args.next()) as usize),
            "--send-ahead" => send_ahead = num(&a, args.next()) as usize,
            "--publish" if role == "ping" => publish = true,
            "--throughput" if role == "ping" => throughput = true,
            "--size" if role == "ping" => size = num(&a, args.next()) as usize,
            "--count" if role == "ping" => count = num(&a, args.next()) as usize,
            other => {
                eprintln!("{role}: unknown argument {other:?} (try --help)");
                std::process::exit(2);
            }
        }
    }
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    // Spawned, not run as the `block_on` future: a current-thread runtime
    // polls its I/O driver once more (`epoll_wait(.., 0)`) before it
    // resumes a woken `block_on` future, but runs a woken task at once.
    let role = role.to_string();
    let o = RoleOpts {
        spin,
        embed,
        cut_through,
        send_ahead,
    };
    rt.block_on(async move {
        tokio::spawn(async move {
            match role.as_str() {
                "pong" => pong(&url, o).await,
                _ if throughput => flood(&url, o, size, count).await,
                _ => ping(&url, o, publish, size, count).await,
            }
        })
        .await
        .expect("the role's task")
    });
    rt.shutdown_background();
}

fn main() {
    let mut args = std::env::args().skip(1);
    match std::env::args().nth(1).as_deref() {
        Some(r @ ("ping" | "pong")) => {
            args.next();
            role(r, args)
        }
        Some("processes") => {
            args.next();
            processes::table(args)
        }
        Some("relay-sweep") => {
            args.next();
            processes::sweep(args)
        }
        Some(r @ ("relay" | "raw-pong" | "raw-ping")) => {
            args.next();
            match r {
                "relay" => relay_floor::relay(args),
                "raw-pong" => relay_floor::raw_pong(args),
                _ => relay_floor::raw_ping(args),
            }
        }
        _ => tables(args),
    }
}

#[tokio::main(flavor = "multi_thread", worker_threads = 2)]
async fn tables(mut args: impl Iterator<Item = String>) {
    let mut url = None;
    let mut direct_url = None;
    let mut quick = false;
    while let Some(a) = args.next() {
        match a.as_str() {
            "--url" => url = args.next(),
            "--direct-url" => direct_url = args.next(),
            "--quick" => quick = true,
            "-h" | "--help" => {
                println!(
                    "usage: session-bench [--url ipc://H:P] [--direct-url ipc://H:P] [--quick]\n\
                     \x20      session-bench pong [--url ipc://H:P] [--busy-poll US] [--embed] [--cut-through BYTES] [--send-ahead N]\n\
                     \x20      session-bench ping [--url ipc://H:P] [--busy-poll US] [--embed] [--publish] [--size S] [--count N]"
                );
                return;
            }
            other => {
                eprintln!("unknown argument {other:?} (try --help)");
                std::process::exit(2);
            }
        }
    }
    let mut centrals = Vec::new();
    let start = |direct: bool| async move {
        let mut cfg = Config::default();
        cfg.direct = direct;
        CentralServer::builder()
            .bind([127, 0, 0, 1].into())
            .port(0)
            .config(cfg)
            .spawn()
            .await
            .expect("start central")
    };
    let routed_url = match url {
        Some(u) => u,
        None => {
            let c = start(false).await;
            let u = format!("ipc://{}", c.local_addr());
            centrals.push(c);
            u
        }
    };
    let direct_url = match direct_url {
        Some(u) => u,
        None => {
            let c = start(true).await;
            let u = format!("ipc://{}", c.local_addr());
            centrals.push(c);
            u
        }
    };
    let q = if quick { 10 } else { 1 };
    let routed = pair(&routed_url, "r").await;
    let direct = pair(&direct_url, "d").await;
    let mut tcp: Vec<f64> = Vec::new();
    for _ in 0..3 {
        tcp.push(raw_tcp_rtt(5000 / q).await);
    }
    tcp.sort_by(f64::total_cmp);
    println!("| case | routed (via central) | direct |");
    println!("|---|---|---|");
    println!(
        "| raw loopback TCP round trip, 4 B (reference) | | {:.1} µs |",
        tcp[1] * 1e6
    );
    let cases: [(&str, Kind, usize, usize); 6] = [
        ("publish->publish RTT, 4 B", Kind::Pub, 4, 2000),
        ("publish->publish RTT, 1 MiB", Kind::Pub, 1 << 20, 100),
        ("query->reply RTT, 4 B", Kind::Query, 4, 2000),
        ("query->reply RTT, 1 MiB", Kind::Query, 1 << 20, 100),
        ("one-way throughput, 4 B", Kind::Throughput, 4, 20_000),
        (
            "one-way throughput, 64 KiB",
            Kind::Throughput,
            64 << 10,
            2000,
        ),
    ];
    for (name, kind, size, count) in cases {
        let count = (count / q).max(5);
        let r = median(&routed, kind, size, count).await;
        let d = median(&direct, kind, size, count).await;
        let cell = |s: f64| match kind {
            Kind::Throughput => format!("{:.0} msg/s ({:.1} MB/s)", 1.0 / s, size as f64 / s / 1e6),
            _ => format!("{:.1} µs", s * 1e6),
        };
        println!("| {name} | {} | {} |", cell(r), cell(d));
    }
    for s in [routed.a, routed.b, direct.a, direct.b] {
        s.close().await;
    }
    for c in centrals {
        c.shutdown().await;
    }
    let _ = appendix::appendix_a;
}

/// `session-bench processes`: every module and central its own process.
mod processes {
    use std::io::Read;
    use std::net::{Ipv4Addr, TcpListener};
    use std::path::{Path, PathBuf};
    use std::process::{Child, Command, Stdio};
    use std::time::{Duration, Instant};

    use super::relay_floor::Kind;

    /// A child process that is killed and reaped when dropped.
    struct Proc(Child);

    impl Drop for Proc {
        /// SIGTERM first (Courier's central then removes its UNIX socket
        /// file), SIGKILL after a second.
        fn drop(&mut self) {
            let _ = Command::new("kill")
                .args(["-TERM", &self.0.id().to_string()])
                .stderr(Stdio::null())
                .status();
            let t0 = Instant::now();
            while t0.elapsed() < Duration::from_secs(1) {
                if let Ok(Some(_)) = self.0.try_wait() {
                    return;
                }
                std::thread::sleep(Duration::from_millis(10));
            }
            let _ = self.0.kill();
            let _ = self.0.wait();
        }
    }

    fn free_port() -> u16 {
        let l = TcpListener::bind((Ipv4Addr::LOCALHOST, 0)).expect("bind a free port");
        l.local_addr().unwrap().port()
    }

    #[derive(Clone, Copy, PartialEq)]
    enum Clients {
        Courier,
        CourierSpin,
        C,
    }

    #[derive(Clone, Copy, PartialEq)]
    enum Centrals {
        Courier,
        CourierSpin,
        C,
        /// Courier's central embedded in the answering module's process
        /// (`pong --embed`), which reaches it over an in-process link.
        Hosted,
    }

    struct Setup {
        central: PathBuf,
        c_central: Option<PathBuf>,
        c_rtt: Option<PathBuf>,
        publish: bool,
        throughput: bool,
        size: usize,
        count: usize,
        spin_us: u64,
        /// `--cut-through` for Courier's centrals.
        cut_through: Option<usize>,
        /// `--send-ahead` for Courier's centrals.
        send_ahead: Option<usize>,
    }

    fn start_central(s: &Setup, which: Centrals, port: u16) -> Option<Proc> {
        let (bin, spin) = match which {
            Centrals::Courier => (&s.central, false),
            Centrals::CourierSpin => (&s.central, true),
            Centrals::C => (s.c_central.as_ref().unwrap(), false),
            Centrals::Hosted => return None,
        };
        let mut cmd = Command::new(bin);
        cmd.arg(format!("-p{port}")).args(["-lx", "-s", "-u"]);
        if which != Centrals::C {
            cmd.args(["--bind", "127.0.0.1"]);
        }
        if spin {
            cmd.arg(format!("--busy-poll={}", s.spin_us));
        }
        if let (Some(n), true) = (s.cut_through, which != Centrals::C) {
            cmd.arg(format!("--cut-through={n}"));
        }
        if let (Some(n), true) = (s.send_ahead, which != Centrals::C) {
            for m in super::SUBSCRIBERS {
                cmd.arg(format!("--send-ahead={m}={n}"));
            }
        }
        let child = cmd
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap_or_else(|e| panic!("cannot start {}: {e}", bin.display()));
        let p = Proc(child);
        wait_listening(port, true);
        Some(p)
    }

    /// Waits until central listens on `port`, without connecting to it: a
    /// probe connection that closes before saying who it is makes the C
    /// central close a module by the name `**NEWMOD**` (its close goes by
    /// name), which is any other module still connecting: the answering
    /// module then never subscribes and the run hangs. TCP from
    /// `/proc/net/tcp`; with `unix`, the UNIX socket by its file too.
    fn wait_listening(port: u16, unix: bool) {
        let t0 = Instant::now();
        let socket = format!("/tmp/x_ipc/{port}");
        while !(listening_tcp(port) && (!unix || Path::new(&socket).exists())) {
            assert!(
                t0.elapsed() < Duration::from_secs(5),
                "central did not listen on {port}"
            );
            std::thread::sleep(Duration::from_millis(10));
        }
    }

    /// The round trip's median (µs) or the throughput (messages/s).
    fn median_of(out: &str) -> Option<f64> {
        out.split_whitespace()
            .find_map(|w| {
                w.strip_prefix("median_us=")
                    .or_else(|| w.strip_prefix("msgs_per_s="))
            })
            .and_then(|v| v.parse().ok())
    }

    /// One run's result: the median round trip in µs (or messages/s), and
    /// for C clients the central process's CPU time per message in µs
    /// (all its threads, from `/proc/<pid>/task/*/schedstat`).
    struct Sample {
        value: f64,
        cpu_us: Option<f64>,
    }

    /// CPU time (ns) a process's threads have used so far.
    fn cpu_ns(pid: u32) -> Option<u64> {
        let mut total = 0;
        for t in std::fs::read_dir(format!("/proc/{pid}/task")).ok()? {
            let st = std::fs::read_to_string(t.ok()?.path().join("schedstat")).ok()?;
            total += st.split_whitespace().next()?.parse::<u64>().ok()?;
        }
        Some(total)
    }

    /// Warm-up messages the C measuring programs send before the timed ones.
    const C_WARM_UP: usize = 200;

    /// One run: the median round trip in µs.
    fn run(s: &Setup, central: Centrals, clients: Clients, host: &str) -> Option<Sample> {
        let port = free_port();
        let r = run_on(s, central, clients, host, port);
        // the C central leaves its socket file behind
        let _ = std::fs::remove_file(format!("/tmp/x_ipc/{port}"));
        r
    }

    fn run_on(
        s: &Setup,
        central: Centrals,
        clients: Clients,
        host: &str,
        port: u16,
    ) -> Option<Sample> {
        let _central = start_central(s, central, port);
        let central_pid = _central.as_ref().map(|p| p.0.id());
        let me = std::env::current_exe().unwrap();
        let url = format!("ipc://{host}:{port}");
        let spin = format!("{}", s.spin_us);
        let count = s.count.to_string();
        let (server, client) = match clients {
            Clients::Courier | Clients::CourierSpin => {
                let mut pong = Command::new(&me);
                if central == Centrals::Hosted {
                    let url = format!("ipc://127.0.0.1:{port}");
                    pong.args(["pong", "--url", &url, "--embed"]);
                    if let Some(n) = s.cut_through {
                        pong.args(["--cut-through", &n.to_string()]);
                    }
                    if let Some(n) = s.send_ahead {
                        pong.args(["--send-ahead", &n.to_string()]);
                    }
                } else {
                    pong.args(["pong", "--url", &url]);
                }
                let mut ping = Command::new(&me);
                let size = s.size.to_string();
                ping.args(["ping", "--url", &url, "--count", &count, "--size", &size]);
                if s.publish {
                    ping.arg("--publish");
                }
                if s.throughput {
                    ping.arg("--throughput");
                }
                if clients == Clients::CourierSpin {
                    pong.args(["--busy-poll", &spin]);
                    ping.args(["--busy-poll", &spin]);
                }
                (pong, ping)
            }
            Clients::C => {
                let dir = s.c_rtt.as_ref().unwrap();
                let size = s.size.to_string();
                let (mut srv, mut cli) = if s.throughput {
                    // The publisher waits for the subscriber, which times
                    // from its first delivery to its last.
                    let mut p = Command::new(dir.join("tput_pub"));
                    p.args([&count, &size]);
                    let mut t = Command::new(dir.join("tput_sub"));
                    t.arg(&count);
                    (p, t)
                } else if s.publish {
                    let mut b = Command::new(dir.join("prtt"));
                    b.arg("b");
                    let mut a = Command::new(dir.join("prtt"));
                    a.args(["a", &count, &size]);
                    (b, a)
                } else {
                    let mut a = Command::new(dir.join("qrtt_client"));
                    a.args([&count, &size]);
                    (Command::new(dir.join("qrtt_server")), a)
                };
                srv.env("CENTRALHOST", format!("{host}:{port}"));
                cli.env("CENTRALHOST", format!("{host}:{port}"));
                (srv, cli)
            }
        };
        let mut server = server;
        let _server = Proc(
            server
                .stdin(Stdio::piped())
                .stdout(Stdio::null())
                .stderr(Stdio::null())
                .spawn()
                .expect("start the answering module"),
        );
        if central == Centrals::Hosted {
            wait_listening(port, false);
        }
        // Subscribed before the timing side starts (see below).
        std::thread::sleep(Duration::from_millis(300));
        let mut client = client;
        let cpu0 = central_pid.and_then(cpu_ns);
        let mut c = client
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .expect("start the timing module");
        // The C library can miss the first update of the list of
        // subscribed messages (a broadcast that arrives while it waits for a
        // reply is applied only by a later IPC_listen), and then never
        // publishes: such a run hangs and is given up.
        let t0 = Instant::now();
        loop {
            match c.try_wait() {
                Ok(Some(_)) => break,
                Ok(None) if t0.elapsed() < Duration::from_secs(30) => {
                    std::thread::sleep(Duration::from_millis(20))
                }
                _ => {
                    let _ = c.kill();
                    let _ = c.wait();
                    eprintln!(
                        "a run did not finish in 30 s; left out ({} clients, {} central, {url})",
                        match clients {
                            Clients::Courier => "Courier",
                            Clients::CourierSpin => "busy-polling Courier",
                            Clients::C => "C",
                        },
                        match central {
                            Centrals::Courier => "Courier",
                            Centrals::CourierSpin => "busy-polling Courier",
                            Centrals::C => "C",
                            Centrals::Hosted => "hosted Courier",
                        },
                    );
                    return None;
                }
            }
        }
        let cpu1 = central_pid.and_then(cpu_ns);
        let mut out = String::new();
        let _ = c.stdout.take().unwrap().read_to_string(&mut out);
        let cpu_us = match (clients, cpu0, cpu1) {
            (Clients::C, Some(a), Some(b)) if !s.throughput => {
                Some((b - a) as f64 / 1e3 / (s.count + C_WARM_UP) as f64)
            }
            _ => None,
        };
        median_of(&out).map(|value| Sample { value, cpu_us })
    }

    /// The relay floor on one transport (see `ipc_relay_floor.rs`): the
    /// median round trip in µs.
    fn relay_run(s: &Setup, unix: bool, kind: Kind) -> Option<f64> {
        relay_run_with(s.count, s.size, unix, kind, 0)
    }

    /// [`relay_run`] with `work_ns` of busy work per frame in the relay.
    fn relay_run_with(
        count: usize,
        size: usize,
        unix: bool,
        kind: Kind,
        work_ns: u64,
    ) -> Option<f64> {
        let me = std::env::current_exe().unwrap();
        let port = free_port();
        let path = format!("/tmp/courier-relay-{}-{port}", std::process::id());
        let addr: Vec<String> = if unix {
            vec!["--unix".into(), path.clone()]
        } else {
            vec!["--tcp".into(), port.to_string()]
        };
        let spawn = |args: &[&str], out: Stdio| {
            Command::new(&me)
                .args(args)
                .args(&addr)
                .stdin(Stdio::null())
                .stdout(out)
                .stderr(Stdio::null())
                .spawn()
                .expect("start a relay-floor process")
        };
        let work = work_ns.to_string();
        let _relay = Proc(spawn(
            &["relay", "--kind", kind.arg(), "--work-ns", &work],
            Stdio::null(),
        ));
        let t0 = Instant::now();
        let listening = || {
            // A probe connection would be taken for the answering end.
            if unix {
                std::path::Path::new(&path).exists()
            } else {
                listening_tcp(port)
            }
        };
        while !listening() {
            if t0.elapsed() > Duration::from_secs(5) {
                return None;
            }
            std::thread::sleep(Duration::from_millis(10));
        }
        let _pong = Proc(spawn(&["raw-pong"], Stdio::null()));
        std::thread::sleep(Duration::from_millis(100));
        let count = count.to_string();
        let size = size.to_string();
        let ping = spawn(
            &["raw-ping", "--count", &count, "--size", &size],
            Stdio::piped(),
        );
        let out = ping.wait_with_output().ok()?;
        let _ = std::fs::remove_file(&path);
        median_of(&String::from_utf8_lossy(&out.stdout))
    }

    /// `session-bench relay-sweep`: the poll and tokio relays with and
    /// without busy work per frame, on both transports, in alternating
    /// rounds: what a microsecond of a central's CPU per message costs a
    /// round trip, and what the tokio shape costs against the poll shape.
    pub fn sweep(mut args: impl Iterator<Item = String>) {
        let usage = "usage: session-bench relay-sweep [--reps R] [--count N] \
                     [--work NS[,NS...]] [--one-cpu]";
        let (mut reps, mut count, mut works, mut one_cpu) =
            (9usize, 3000usize, vec![0u64, 5000], false);
        let fail = |m: String| -> ! {
            eprintln!("relay-sweep: {m}; {usage}");
            std::process::exit(2)
        };
        while let Some(a) = args.next() {
            let mut num = |what: &str| -> usize {
                let v = args.next();
                v.as_deref()
                    .and_then(|v| v.parse().ok())
                    .filter(|&n| n > 0)
                    .unwrap_or_else(|| fail(format!("{what} needs a positive number (got {v:?})")))
            };
            match a.as_str() {
                "--reps" => reps = num("--reps"),
                "--count" => count = num("--count"),
                "--work" => {
                    let v = args.next().unwrap_or_default();
                    works = v
                        .split(',')
                        .map(|w| {
                            w.parse().unwrap_or_else(|_| {
                                fail(format!("--work {v:?}: nanoseconds, comma-separated"))
                            })
                        })
                        .collect();
                }
                "--one-cpu" => one_cpu = true,
                "-h" | "--help" => {
                    println!("{usage}");
                    return;
                }
                other => fail(format!("unknown argument {other:?}")),
            }
        }
        if one_cpu {
            // Every process this one starts inherits the mask.
            // SAFETY: a zeroed cpu_set_t is valid; CPU_SET writes inside it.
            let r = unsafe {
                let mut set: libc::cpu_set_t = std::mem::zeroed();
                libc::CPU_SET(0, &mut set);
                libc::sched_setaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &set)
            };
            if r != 0 {
                fail(format!(
                    "cannot pin to CPU 0: {}",
                    std::io::Error::last_os_error()
                ));
            }
        }
        let kinds = [Kind::Poll, Kind::Tokio];
        let mut cells: Vec<(bool, Kind, u64, Vec<f64>)> = Vec::new();
        for unix in [true, false] {
            for &w in &works {
                for k in kinds {
                    cells.push((unix, k, w, Vec::new()));
                }
            }
        }
        for _ in 0..reps {
            for (unix, k, w, got) in cells.iter_mut() {
                got.extend(relay_run_with(count, 4, *unix, *k, *w));
            }
        }
        println!(
            "relay round trip, 4 B frames between raw ends, {}; median of {reps} runs of {count} round trips, alternating\n",
            if one_cpu { "all processes on CPU 0" } else { "unpinned" }
        );
        println!("| relay | transport | busy work per frame | round trip | quartiles of the runs | vs no work |");
        println!("|---|---|---|---|---|---|");
        let med = |v: &[f64], q: usize| {
            let mut v = v.to_vec();
            v.sort_by(f64::total_cmp);
            v.get(v.len() * q / 4).copied()
        };
        for (unix, k, w, got) in &cells {
            let base = cells
                .iter()
                .find(|c| c.0 == *unix && c.1 == *k && c.2 == 0)
                .and_then(|c| med(&c.3, 2));
            let (Some(m), Some(lo), Some(hi)) = (med(got, 2), med(got, 1), med(got, 3)) else {
                continue;
            };
            println!(
                "| {} | {} | {:.1} µs | {m:.1} µs | {lo:.1}–{hi:.1} µs | {} |",
                k.arg(),
                if *unix { "UNIX socket" } else { "TCP" },
                *w as f64 / 1e3,
                base.filter(|_| *w > 0)
                    .map(|b| format!(
                        "{:+.1} µs for +{:.1} µs of CPU per round trip",
                        m - b,
                        2.0 * *w as f64 / 1e3
                    ))
                    .unwrap_or_else(|| "–".into())
            );
        }
    }

    /// Whether `port` is in LISTEN state on 127.0.0.1 or on every address
    /// (the C central's) — read from `/proc/net/tcp`, so that no probe
    /// connection is made.
    fn listening_tcp(port: u16) -> bool {
        let wanted = [
            format!("0100007F:{port:04X}"),
            format!("00000000:{port:04X}"),
        ];
        std::fs::read_to_string("/proc/net/tcp").is_ok_and(|t| {
            t.lines().any(|l| {
                let f: Vec<&str> = l.split_whitespace().collect();
                f.len() > 3 && wanted.contains(&f[1].to_string()) && f[3] == "0A"
            })
        })
    }

    pub fn table(mut args: impl Iterator<Item = String>) {
        let mut s = Setup {
            central: std::env::current_exe().unwrap().with_file_name("central"),
            c_central: None,
            c_rtt: None,
            publish: false,
            throughput: false,
            size: 4,
            count: 5000,
            spin_us: 200,
            cut_through: None,
            send_ahead: None,
        };
        let mut reps = 5usize;
        let mut relay = false;
        let mut only: Option<String> = None;
        let usage = "usage: session-bench processes [--central PATH] [--c-central PATH] \
                     [--c-rtt DIR] [--publish | --throughput] [--size S] [--count N] \
                     [--reps R] [--busy-poll US] [--cut-through BYTES] [--send-ahead N] \
                     [--relay-floor] [--only c-clients]";
        let num = |v: Option<String>| -> usize {
            match v.as_deref().map(str::parse::<usize>) {
                Some(Ok(n)) if n > 0 => n,
                _ => {
                    eprintln!("a positive number is needed (got {v:?}); {usage}");
                    std::process::exit(2)
                }
            }
        };
        while let Some(a) = args.next() {
            match a.as_str() {
                "--central" => s.central = args.next().unwrap_or_default().into(),
                "--c-central" => s.c_central = args.next().map(PathBuf::from),
                "--c-rtt" => s.c_rtt = args.next().map(PathBuf::from),
                "--publish" => s.publish = true,
                "--throughput" => s.throughput = true,
                "--size" => s.size = num(args.next()),
                "--count" => s.count = num(args.next()),
                "--reps" => reps = num(args.next()),
                "--busy-poll" => s.spin_us = num(args.next()) as u64,
                "--cut-through" => s.cut_through = Some(num(args.next())),
                "--send-ahead" => s.send_ahead = Some(num(args.next())),
                "--relay-floor" => relay = true,
                "--only" => only = args.next(),
                "-h" | "--help" => {
                    println!("{usage}");
                    return;
                }
                other => {
                    eprintln!("unknown argument {other:?}; {usage}");
                    std::process::exit(2);
                }
            }
        }
        for p in [Some(&s.central), s.c_central.as_ref()]
            .into_iter()
            .flatten()
        {
            if !Path::new(p).is_file() {
                eprintln!(
                    "no central at {} (build it: cargo build --release -p courier-broker)",
                    p.display()
                );
                std::process::exit(2);
            }
        }
        let mut centrals = vec![Centrals::Courier, Centrals::CourierSpin];
        if s.c_central.is_some() {
            centrals.push(Centrals::C);
        }
        centrals.push(Centrals::Hosted);
        let mut clients = vec![Clients::Courier, Clients::CourierSpin];
        if s.c_rtt.is_some() {
            clients.push(Clients::C);
        }
        // `--only c-clients`: the plain centrals with C clients, the cells
        // issue 30's goal is about (and the relay floor's).
        if only.as_deref() == Some("c-clients") {
            clients.retain(|c| *c == Clients::C);
            centrals.retain(|c| matches!(c, Centrals::Courier | Centrals::C));
        }
        let host = courier::ipc_backend::local_host_name();
        let what = if s.throughput {
            "one-way throughput (messages/s) at capacity 1"
        } else if s.publish {
            "publish->handler->publish round trip"
        } else {
            "query->reply round trip"
        };
        let cut = s
            .cut_through
            .map(|n| format!("; Courier's centrals with --cut-through {n}"))
            .unwrap_or_default();
        println!(
            "{what}, {} B, separate processes, unpinned; median of {reps} runs of {} messages each{cut}\n",
            s.size, s.count
        );
        let name_c = |c: Centrals| match c {
            Centrals::Courier => "Courier central".to_string(),
            Centrals::CourierSpin => format!("Courier central --busy-poll {}", s.spin_us),
            Centrals::C => "C central".to_string(),
            Centrals::Hosted => "Courier central in the handler's process".to_string(),
        };
        let name_m = |c: Clients| match c {
            Clients::Courier => "Courier".to_string(),
            Clients::CourierSpin => format!("Courier, busy_poll {} µs", s.spin_us),
            Clients::C => "C library".to_string(),
        };
        print!("| clients | transport |");
        for c in &centrals {
            print!(" {} |", name_c(*c));
        }
        println!();
        println!("|---|---|{}", "---|".repeat(centrals.len()));
        let mut floors: Vec<String> = Vec::new();
        let mut pairs: Vec<String> = Vec::new();
        for (transport, h) in [("TCP", "127.0.0.1"), ("UNIX socket", host.as_str())] {
            // Runs alternate between the cells, so drift hits all alike.
            // Only a Courier module can host central.
            let cells: Vec<(Clients, Centrals)> = clients
                .iter()
                .flat_map(|m| centrals.iter().map(move |c| (*m, *c)))
                .filter(|&(m, c)| !(m == Clients::C && c == Centrals::Hosted))
                .collect();
            let mut got: Vec<Vec<f64>> = vec![Vec::new(); cells.len()];
            let mut cpu: Vec<Vec<f64>> = vec![Vec::new(); cells.len()];
            // Per relay kind (`Kind::ALL`), and per round the
            // tokio relay against the poll relay.
            let mut floor: Vec<Vec<f64>> = vec![Vec::new(); Kind::ALL.len()];
            let mut tokio_vs_poll: Vec<f64> = Vec::new();
            // Each run of a cell against the C-client C-central run of the
            // same round (seconds apart): drift between rounds cancels.
            let mut paired: Vec<Vec<f64>> = vec![Vec::new(); cells.len()];
            let c_ref = cells
                .iter()
                .position(|&(m, c)| m == Clients::C && c == Centrals::C);
            for _ in 0..reps {
                let mut round: Vec<Option<f64>> = vec![None; cells.len()];
                for (i, (m, c)) in cells.iter().enumerate() {
                    if let Some(v) = run(&s, *c, *m, h) {
                        got[i].push(v.value);
                        cpu[i].extend(v.cpu_us);
                        round[i] = Some(v.value);
                    }
                }
                if let Some(r) = c_ref.and_then(|i| round[i]) {
                    for (i, v) in round.iter().enumerate() {
                        if let Some(v) = v {
                            paired[i].push(v / r);
                        }
                    }
                }
                if relay && !s.throughput {
                    let r: Vec<Option<f64>> = Kind::ALL
                        .iter()
                        .map(|&k| relay_run(&s, transport != "TCP", k))
                        .collect();
                    for (f, v) in floor.iter_mut().zip(&r) {
                        f.extend(*v);
                    }
                    let at = |k| r[Kind::ALL.iter().position(|&x| x == k).unwrap()];
                    if let (Some(p), Some(t)) = (at(Kind::Poll), at(Kind::Tokio)) {
                        tokio_vs_poll.push(t / p);
                    }
                }
            }
            let med = |v: &mut Vec<f64>| {
                v.sort_by(f64::total_cmp);
                v.get(v.len() / 2).copied()
            };
            let meds: Vec<Option<f64>> = got.iter_mut().map(med).collect();
            let cpus: Vec<Option<f64>> = cpu.iter_mut().map(med).collect();
            let kinds: Vec<Option<f64>> = floor.iter_mut().map(med).collect();
            // The threads relay last: the C-client rows below are against it.
            for (k, f) in Kind::ALL.iter().zip(&kinds).skip(1) {
                if let Some(f) = f {
                    floors.push(format!("| {} | {transport} | {f:.1} µs |", k.describe()));
                }
            }
            if !tokio_vs_poll.is_empty() {
                let v = &mut tokio_vs_poll;
                v.sort_by(f64::total_cmp);
                floors.push(format!(
                    "| tokio relay / poll relay, paired per round | {transport} | {:.3}× (quartiles {:.3}–{:.3}×) |",
                    v[v.len() / 2],
                    v[v.len() / 4],
                    v[(v.len() * 3) / 4]
                ));
            }
            if let Some(f) = kinds[0] {
                floors.push(format!(
                    "| {} (the floor below) | {transport} | {f:.1} µs |",
                    Kind::Threads.describe()
                ));
                for (i, &(m, c)) in cells.iter().enumerate() {
                    if m != Clients::C || c == Centrals::Hosted {
                        continue;
                    }
                    if let Some(v) = meds[i] {
                        floors.push(format!(
                            "| C clients, {} | {transport} | {v:.1} µs ({:.2}× floor){} |",
                            name_c(c),
                            v / f,
                            cpus[i]
                                .map(|u| format!("; central CPU {u:.1} µs per round trip"))
                                .unwrap_or_default()
                        ));
                    }
                }
            }
            for (i, &(m, c)) in cells.iter().enumerate() {
                if Some(i) == c_ref || paired[i].is_empty() {
                    continue;
                }
                let v = &mut paired[i];
                v.sort_by(f64::total_cmp);
                let below = v.iter().filter(|&&x| x <= 1.0).count();
                pairs.push(format!(
                    "| {} clients, {} | {transport} | {:.3}× | {:.3}–{:.3}× | {below} of {} |",
                    name_m(m),
                    name_c(c),
                    v[v.len() / 2],
                    v[v.len() / 4],
                    v[(v.len() * 3) / 4],
                    v.len()
                ));
            }
            let reference = c_ref.and_then(|i| meds[i]);
            for m in &clients {
                print!("| {} | {transport} |", name_m(*m));
                // Throughput: against the C central with the same clients.
                let reference = if s.throughput {
                    cells
                        .iter()
                        .position(|&x| x == (*m, Centrals::C))
                        .and_then(|i| meds[i])
                } else {
                    reference
                };
                for c in &centrals {
                    let Some(i) = cells.iter().position(|x| *x == (*m, *c)) else {
                        print!(" — |");
                        continue;
                    };
                    match (meds[i], reference) {
                        (Some(v), Some(r)) if s.throughput => {
                            print!(" {v:.0} msg/s ({:.2}×) |", v / r)
                        }
                        (Some(v), None) if s.throughput => print!(" {v:.0} msg/s |"),
                        (Some(v), Some(r)) => print!(" {v:.1} µs ({:.2}×) |", v / r),
                        (Some(v), None) => print!(" {v:.1} µs |"),
                        (None, _) => print!(" failed |"),
                    }
                }
                println!();
            }
        }
        if !pairs.is_empty() && !s.throughput {
            println!("\neach run against the C-client C-central run of the same round (median of the {reps} per-round ratios, their quartiles, and the rounds at or below 1.0×)\n");
            println!("| cell | transport | paired ratio | quartiles | rounds ≤ 1.0× |");
            println!("|---|---|---|---|---|");
            for l in &pairs {
                println!("{l}");
            }
        }
        if !floors.is_empty() {
            println!("\nthe relay floor: a process with no IPC logic relaying the same round trip's frames between two raw ends (median of {reps}), and the C-client cells against it\n");
            println!("| what | transport | round trip |");
            println!("|---|---|---|");
            for l in &floors {
                println!("{l}");
            }
        }
        if s.throughput && s.c_central.is_some() {
            println!("\n(×: against the same clients through the C central on the same transport)");
        } else if s.c_central.is_some() && s.c_rtt.is_some() {
            println!("\n(×: against C clients through the C central on the same transport)");
        }
    }
}
