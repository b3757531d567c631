//! The `courier` CLI as a user runs it: its processes over RTPS on
//! loopback (each test its own domain, leased machine-wide by
//! `courier_tests::domains`, unicast discovery on 127.0.0.1 only) and over
//! IPC through a central embedded in the test (127.0.0.1, port 0); usage
//! errors, bad URLs and a dead central. Every child is killed and reaped
//! when its guard drops, and every wait is bounded. One file per
//! subcommand; the helpers are here.

mod call;
mod echo_pub;
mod list;
mod output;
mod perf;
mod ping_spy;
mod ping_xrce;
mod rates;
mod record;
mod rtt;
mod stopped;
mod usage;

use std::io::{BufRead, BufReader, Read};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

/// Bound of every wait (a passing test takes well under it).
pub const T: Duration = Duration::from_secs(10);

/// A Cyclone DDS 0.10 reader of `topic` (peer type `ty`: msg, keyed or
/// strkeyed; reliable, and `extra` peer flags such as
/// `--transient-local`) for `count` samples, ready, on the domain of
/// `key`: the Courier URL of that domain, and the reader.
pub fn cyclone_reader(
    key: u32,
    topic: &str,
    ty: &str,
    count: u32,
    extra: &[&str],
) -> (String, courier_tests::peers::PeerProcess) {
    let domain = courier_tests::domains::lease(key).to_string();
    let exe = courier_tests::peers::cyclone_peer()
        .unwrap_or_else(|e| panic!("cannot build the Cyclone DDS peer: {e}"));
    let count = count.to_string();
    let mut args = vec![
        "--domain",
        &domain,
        "--topic",
        topic,
        "--type",
        ty,
        "--sub",
        "--reliable",
        "--count",
        &count,
        "--timeout-s",
        "30",
    ];
    args.extend_from_slice(extra);
    let mut sub = courier_tests::peers::PeerProcess::spawn(exe, &args).unwrap();
    sub.expect_line("ready", T).unwrap();
    (url(key), sub)
}

/// A loopback-only RTPS URL (unicast discovery to 127.0.0.1 on `lo`) on
/// the domain leased to `key` (see `courier_tests::domains`).
pub fn url(key: u32) -> String {
    let domain = courier_tests::domains::lease(key);
    format!("rtps://{domain}?interface=lo&peers=127.0.0.1")
}

/// A `courier` process; killed and reaped when dropped.
pub struct Proc {
    child: Child,
    lines: mpsc::Receiver<String>,
    pub seen: Vec<String>,
    err_lines: mpsc::Receiver<String>,
    err_seen: Vec<String>,
}

/// Sends each line `r` gives to a channel, from a thread of its own.
fn lines_of(r: impl Read + Send + 'static) -> mpsc::Receiver<String> {
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        for l in BufReader::new(r).lines().map_while(Result::ok) {
            if tx.send(l).is_err() {
                break;
            }
        }
    });
    rx
}

/// The next line of `lines` starting with `prefix` (lines before it are
/// skipped, and kept in `seen`).
fn expect_in(lines: &mpsc::Receiver<String>, seen: &mut Vec<String>, prefix: &str) -> String {
    let deadline = Instant::now() + T;
    loop {
        match lines.recv_timeout(deadline.saturating_duration_since(Instant::now())) {
            Ok(l) => {
                seen.push(l.clone());
                if l.starts_with(prefix) {
                    return l;
                }
            }
            Err(_) => panic!("no line {prefix:?} within {T:?}; saw {seen:?}"),
        }
    }
}

impl Proc {
    pub fn start(args: &[&str]) -> Proc {
        let mut c = Command::new(env!("CARGO_BIN_EXE_courier"));
        c.args(args);
        Proc::spawn(c)
    }

    /// `courier args` under `nohup`: with SIGHUP ignored.
    pub fn start_nohup(args: &[&str]) -> Proc {
        let mut c = Command::new("nohup");
        c.arg(env!("CARGO_BIN_EXE_courier")).args(args);
        Proc::spawn(c)
    }

    fn spawn(mut c: Command) -> Proc {
        let mut child = c
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .expect("spawn courier");
        let lines = lines_of(child.stdout.take().unwrap());
        let err_lines = lines_of(child.stderr.take().unwrap());
        Proc {
            child,
            lines,
            seen: Vec::new(),
            err_lines,
            err_seen: Vec::new(),
        }
    }

    /// The next line on stdout starting with `prefix` (lines before it are
    /// skipped).
    pub fn expect(&mut self, prefix: &str) -> String {
        expect_in(&self.lines, &mut self.seen, prefix)
    }

    /// The next line on stderr starting with `prefix`.
    pub fn expect_err(&mut self, prefix: &str) -> String {
        expect_in(&self.err_lines, &mut self.err_seen, prefix)
    }

    pub fn signal(&self, sig: i32) {
        let pid = i32::try_from(self.child.id()).unwrap();
        assert_eq!(unsafe { libc::kill(pid, sig) }, 0);
    }

    /// Waits for the exit (at most `T`): the exit code, and what it printed
    /// on stdout and stderr (beyond the lines already taken).
    pub fn finish(mut self) -> (Option<i32>, String, String) {
        let code = self.wait();
        let rest = |rx: &mpsc::Receiver<String>| {
            let mut s = String::new();
            // the readers end with the pipes, which closed at the exit
            while let Ok(l) = rx.recv_timeout(T) {
                s.push_str(&l);
                s.push('\n');
            }
            s
        };
        (code, rest(&self.lines), rest(&self.err_lines))
    }

    /// The exit code, waiting at most `T`.
    pub fn wait(&mut self) -> Option<i32> {
        let deadline = Instant::now() + T;
        while Instant::now() < deadline {
            if let Ok(Some(st)) = self.child.try_wait() {
                return st.code();
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        panic!("courier did not exit within {T:?}; saw {:?}", self.seen)
    }
}

impl Drop for Proc {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Runs `courier args` to its end (at most `T`): exit code, stdout, stderr.
pub fn run(args: &[&str]) -> (i32, String, String) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_courier"))
        .args(args)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let deadline = Instant::now() + T;
    let status = loop {
        if let Some(st) = child.try_wait().unwrap() {
            break st;
        }
        if Instant::now() >= deadline {
            let _ = child.kill();
            let _ = child.wait();
            panic!("courier {args:?} did not exit within {T:?}");
        }
        std::thread::sleep(Duration::from_millis(10));
    };
    // what these print fits in a pipe: it was all written before the exit
    let (mut out, mut err) = (String::new(), String::new());
    child
        .stdout
        .take()
        .unwrap()
        .read_to_string(&mut out)
        .unwrap();
    child
        .stderr
        .take()
        .unwrap()
        .read_to_string(&mut err)
        .unwrap();
    (status.code().unwrap_or(-1), out, err)
}

/// Courier's central, embedded in the test on 127.0.0.1 (port 0), with the
/// runtime it runs on; `url` is its session URL.
pub struct Central {
    pub rt: tokio::runtime::Runtime,
    pub handle: Option<courier_broker::CentralHandle>,
    pub url: String,
}

impl Central {
    pub fn start() -> Central {
        let rt = tokio::runtime::Runtime::new().unwrap();
        let handle = rt.block_on(async {
            courier_broker::CentralServer::builder()
                .bind("127.0.0.1".parse().unwrap())
                .port(0)
                .log_sink(courier_broker::LogSink::discard())
                .spawn()
                .await
                .unwrap()
        });
        let url = format!("ipc://{}", handle.local_addr());
        Central {
            rt,
            handle: Some(handle),
            url,
        }
    }

    /// A module of this test connected to it.
    pub fn session(&self, name: &str) -> courier::Session {
        let h = self.handle.as_ref().unwrap();
        self.rt.block_on(async {
            tokio::time::timeout(T, h.session(name).connect())
                .await
                .unwrap()
                .unwrap()
        })
    }
}

impl Drop for Central {
    fn drop(&mut self) {
        if let Some(h) = self.handle.take() {
            self.rt.block_on(async {
                let _ = tokio::time::timeout(T, h.shutdown()).await;
            });
        }
    }
}

/// Waits until `msg` has at least `n` handlers in central, as `s` sees it.
pub fn await_handlers(c: &Central, s: &courier::Session, msg: &str, n: i32) {
    c.rt.block_on(async {
        tokio::time::timeout(T, async {
            while s.num_handlers(msg).await.unwrap() < n {
                tokio::time::sleep(Duration::from_millis(10)).await;
            }
        })
        .await
        .expect("handlers within T")
    });
}
