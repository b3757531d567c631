//! Central's own memory: resident size of a `central` process idle, with
//! N idle modules connected, and after large messages went through it,
//! for Courier's central and, optionally, a C one in the same run.
//!
//! ```text
//! central-memory [--central PATH] [--c-central PATH] [--floor PATH | --no-floor]
//!                [--modules 40,400] [--large]
//! central-memory --running PID:PORT [--modules ...] [--large]
//! ```
//! `--running` measures a central already running (started by hand, with
//! other options or under a profiler) instead of starting one; it is
//! left running.
//! `--central` defaults to the `central` next to this program (build both
//! with `cargo build --release -p courier-broker -p courier-bench`).
//! Each central is started on a free port with logging off (`-lx -s -u`),
//! then the modules connect one by one over loopback TCP and stay idle.
//! The modules are Courier's sans-I/O module state machine on blocking
//! sockets in this process, so only the central's memory is measured:
//! `VmRSS` (and its anonymous part, `RssAnon`) from `/proc/<pid>/status`,
//! read after a pause for things to settle.
//!
//! `--large`: after the last count, two more modules exchange 20 queries
//! of 1 MiB through central (C central: 64 KiB, it takes seconds per
//! MiB), the two leave, and the resident size is read again 12.5 s later
//! (Courier's central gives memory back after ten quiet seconds).
//!
//! The floor: `tokio-listen-floor` (next to this program, or `--floor`) is
//! started the same way and measured last, a tokio current-thread runtime
//! listening on TCP and a UNIX socket with no IPC at all: what any tokio
//! program of this shape has resident. Its "modules" are bare TCP
//! connections it accepts and holds (no handshake), and it gets no large
//! messages.

use std::net::{TcpListener, TcpStream};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use courier::ipc::module::MsgLength;

#[path = "../client.rs"]
mod client;
use client::Client;

/// How long to let central settle before reading its memory.
const SETTLE: Duration = Duration::from_millis(500);
/// The bound on every wait for central.
const T: Duration = Duration::from_secs(20);

/// What a started program is.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Kind {
    Courier,
    C,
    /// `tokio-listen-floor`: listeners only, no IPC.
    Floor,
}

struct Running {
    child: Child,
    port: u16,
    /// The floor's UNIX socket file, removed when it is stopped.
    socket: Option<PathBuf>,
}

impl Drop for Running {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
        if let Some(s) = &self.socket {
            let _ = std::fs::remove_file(s);
        }
    }
}

fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .map(|a| a.port())
        .unwrap_or_else(|e| fail(&format!("no free port: {e}")))
}

fn start(path: &Path, kind: Kind) -> Running {
    let port = free_port();
    let mut cmd = Command::new(path);
    cmd.arg(format!("-p{port}"));
    let mut socket = None;
    match kind {
        Kind::Courier => {
            cmd.args(["-lx", "-s", "-u", "--bind", "127.0.0.1", "--no-unix-socket"]);
        }
        Kind::C => {
            cmd.args(["-lx", "-s", "-u"]);
        }
        Kind::Floor => {
            let s = std::env::temp_dir().join(format!("tokio-listen-floor-{port}.sock"));
            cmd.arg("--unix").arg(&s);
            socket = Some(s);
        }
    }
    let child = cmd
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap_or_else(|e| fail(&format!("cannot start {}: {e}", path.display())));
    let r = Running {
        child,
        port,
        socket,
    };
    let deadline = Instant::now() + T;
    // A bare connection that closes at once: central logs nothing (-lx);
    // the floor holds it.
    while TcpStream::connect(("127.0.0.1", port)).is_err() {
        if Instant::now() > deadline {
            fail(&format!("{} did not start listening", path.display()));
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    r
}

/// (VmRSS, RssAnon) in bytes.
fn rss(pid: u32) -> (u64, u64) {
    std::thread::sleep(SETTLE);
    let status = std::fs::read_to_string(format!("/proc/{pid}/status"))
        .unwrap_or_else(|e| fail(&format!("/proc/{pid}/status: {e}")));
    let field = |name: &str| -> u64 {
        status
            .lines()
            .find_map(|l| l.strip_prefix(name))
            .and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<u64>().ok())
            .map(|kb| kb * 1024)
            .unwrap_or_else(|| fail(&format!("no {name} in /proc/{pid}/status")))
    };
    (field("VmRSS:"), field("RssAnon:"))
}

/// 1 MiB (or `size`) queries between two fresh modules, which then leave.
fn large_messages(port: u16, size: usize, count: usize) {
    let addr = format!("127.0.0.1:{port}");
    let mut b = Client::connect(&addr, "mem-b");
    b.conn
        .define_msg("mem-ask", MsgLength::Variable, None)
        .unwrap();
    b.conn
        .define_msg("mem-answer", MsgLength::Variable, None)
        .unwrap();
    b.conn.subscribe("mem-ask", "HND-mem-ask").unwrap();
    b.sync();
    let server = std::thread::spawn(move || {
        for _ in 0..count {
            let (d, _, data) = b.delivery();
            b.conn.respond(d, "mem-answer", data).unwrap();
            b.flush();
        }
        b.close();
    });
    let mut a = Client::connect(&addr, "mem-a");
    let payload = vec![7u8; size];
    for _ in 0..count {
        a.conn.query("mem-ask", payload.clone(), -1).unwrap();
        assert_eq!(a.reply().len(), size);
    }
    a.close();
    let _ = server.join();
}

struct Row {
    name: String,
    idle: (u64, u64),
    counts: Vec<(usize, (u64, u64))>,
    large: Option<(usize, (u64, u64))>,
}

/// A central to measure: started here (stopped when done) or running.
enum Target<'a> {
    Start { path: &'a Path, kind: Kind },
    Running { pid: u32, port: u16 },
}

fn measure(name: &str, target: Target<'_>, counts: &[usize], large: bool) -> Row {
    let (started, pid, port, kind) = match target {
        Target::Start { path, kind } => {
            let r = start(path, kind);
            let (pid, port) = (r.child.id(), r.port);
            (Some(r), pid, port, kind)
        }
        Target::Running { pid, port } => (None, pid, port, Kind::Courier),
    };
    let idle = rss(pid);
    let addr = format!("127.0.0.1:{port}");
    let mut modules = Vec::new();
    let mut bare = Vec::new();
    let mut at = Vec::new();
    for &n in counts {
        if kind == Kind::Floor {
            while bare.len() < n {
                let s = TcpStream::connect(&addr)
                    .unwrap_or_else(|e| fail(&format!("cannot connect to the floor: {e}")));
                bare.push(s);
            }
        } else {
            while modules.len() < n {
                let mut m = Client::connect(&addr, &format!("idle{}", modules.len()));
                m.sync();
                modules.push(m);
            }
        }
        at.push((n, rss(pid)));
    }
    let large = (large && kind != Kind::Floor).then(|| {
        let size = if kind == Kind::Courier {
            1 << 20
        } else {
            64 << 10
        };
        large_messages(port, size, 20);
        // Courier's central gives memory back after ten quiet seconds.
        std::thread::sleep(Duration::from_secs(12));
        (size, rss(pid))
    });
    drop(modules);
    drop(bare);
    drop(started);
    Row {
        name: name.into(),
        idle,
        counts: at,
        large,
    }
}

fn fail(msg: &str) -> ! {
    eprintln!("central-memory: {msg}");
    std::process::exit(2)
}

fn mb(b: u64) -> String {
    format!("{:.2} MB", b as f64 / 1e6)
}

fn kb(b: f64) -> String {
    format!("{:.1} KB", b / 1e3)
}

fn main() {
    let mut central: Option<PathBuf> = None;
    let mut c_central: Option<PathBuf> = None;
    let mut floor: Option<PathBuf> = None;
    let mut no_floor = false;
    let mut counts = vec![40, 400];
    let mut large = false;
    let mut running: Option<(u32, u16)> = None;
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        let mut value = || {
            args.next()
                .unwrap_or_else(|| fail(&format!("{a} needs a value")))
        };
        match a.as_str() {
            "--central" => central = Some(value().into()),
            "--c-central" => c_central = Some(value().into()),
            "--floor" => floor = Some(value().into()),
            "--no-floor" => no_floor = true,
            "--modules" => {
                let v = value();
                counts = v
                    .split(',')
                    .map(|n| n.trim().parse::<usize>().ok().filter(|&n| n > 0))
                    .collect::<Option<Vec<_>>>()
                    .unwrap_or_else(|| fail(&format!("--modules {v}: want counts like 40,400")));
                counts.sort_unstable();
            }
            "--large" => large = true,
            "--running" => {
                let v = value();
                running = v
                    .split_once(':')
                    .and_then(|(p, q)| Some((p.parse().ok()?, q.parse().ok()?)))
                    .or_else(|| fail(&format!("--running {v}: want PID:PORT")));
            }
            "-h" | "--help" => {
                println!(
                    "usage: central-memory [--central PATH] [--c-central PATH] [--floor PATH | --no-floor] [--modules 40,400] [--large]"
                );
                return;
            }
            other => fail(&format!("unknown argument {other:?} (try --help)")),
        }
    }
    if let Some((pid, port)) = running {
        let row = measure("running", Target::Running { pid, port }, &counts, large);
        print_table(&counts, large, &[row]);
        return;
    }
    let me = std::env::current_exe().unwrap_or_else(|e| fail(&format!("{e}")));
    let central = central.unwrap_or_else(|| me.with_file_name("central"));
    if !central.exists() {
        fail(&format!(
            "{} does not exist (build it: cargo build --release -p courier-broker, or give --central)",
            central.display()
        ));
    }
    let floor =
        (!no_floor).then(|| floor.unwrap_or_else(|| me.with_file_name("tokio-listen-floor")));
    if let Some(f) = floor.as_ref().filter(|f| !f.exists()) {
        fail(&format!(
            "{} does not exist (build it: cargo build --release -p courier-bench, or give --floor or --no-floor)",
            f.display()
        ));
    }
    let courier = Target::Start {
        path: &central,
        kind: Kind::Courier,
    };
    let mut rows = vec![measure("courier", courier, &counts, large)];
    if let Some(c) = &c_central {
        let c = Target::Start {
            path: c,
            kind: Kind::C,
        };
        rows.push(measure("C", c, &counts, large));
    }
    if let Some(f) = &floor {
        let f = Target::Start {
            path: f,
            kind: Kind::Floor,
        };
        rows.push(measure("floor: tokio listener, no IPC", f, &counts, large));
    }
    print_table(&counts, large, &rows);
}

fn print_table(counts: &[usize], large: bool, rows: &[Row]) {
    print!("| central | idle |");
    for n in counts {
        print!(" {n} modules |");
    }
    for n in counts {
        print!(" per module ({n}) |");
    }
    if large {
        print!(" after large queries |");
    }
    println!();
    print!("|---|---|");
    for _ in 0..2 * counts.len() + usize::from(large) {
        print!("---|");
    }
    println!();
    for r in rows {
        print!("| {} | {} ({} anon) |", r.name, mb(r.idle.0), mb(r.idle.1));
        for (_, (v, a)) in &r.counts {
            print!(" {} ({} anon) |", mb(*v), mb(*a));
        }
        for (n, (v, _)) in &r.counts {
            print!(" {} |", kb((*v as f64 - r.idle.0 as f64) / *n as f64));
        }
        match r.large {
            Some((size, (v, a))) => print!(" {} ({} anon; {} KiB) |", mb(v), mb(a), size >> 10),
            None if large => print!(" – |"),
            None => {}
        }
        println!();
    }
}
