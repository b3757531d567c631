//! The `courier` CLI as a user runs it: `ping` publisher and subscriber
//! processes, `spy` watching them, over RTPS on loopback (each test its own
//! domain, leased machine-wide by `courier_tests::domains`, unicast discovery on 127.0.0.1 only) and over IPC
//! through an embedded central; usage errors. Every child is killed and
//! reaped when its guard drops, and every wait is bounded.

use std::io::{BufRead, BufReader, Read};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

/// Bound of every wait (a passing test takes well under it).
const T: Duration = Duration::from_secs(10);

/// A loopback-only RTPS URL (unicast discovery to 127.0.0.1 on `lo`) on
/// the domain leased to `key` (see `courier_tests::domains`).
fn url(key: u32) -> String {
    let domain = courier_tests::domains::lease(key);
    format!("rtps://{domain}?interface=lo&peers=127.0.0.1")
}

/// A `courier` process; killed and reaped when dropped.
struct Proc {
    child: Child,
    lines: mpsc::Receiver<String>,
    seen: Vec<String>,
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
    fn start(args: &[&str]) -> Proc {
        let mut child = Command::new(env!("CARGO_BIN_EXE_courier"))
            .args(args)
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
    fn expect(&mut self, prefix: &str) -> String {
        expect_in(&self.lines, &mut self.seen, prefix)
    }

    /// The next line on stderr starting with `prefix`.
    fn expect_err(&mut self, prefix: &str) -> String {
        expect_in(&self.err_lines, &mut self.err_seen, prefix)
    }

    fn signal(&self, sig: i32) {
        let pid = i32::try_from(self.child.id()).unwrap();
        assert_eq!(unsafe { libc::kill(pid, sig) }, 0);
    }

    /// The exit code, waiting at most `T`.
    fn wait(&mut self) -> Option<i32> {
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
fn run(args: &[&str]) -> (i32, String, String) {
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

#[test]
fn ping_publisher_to_ping_subscriber() {
    let u = url(200);
    let mut sub = Proc::start(&["ping", &u, "--subscribe", "--count", "3", "--name", "rx"]);
    sub.expect("ready");
    let mut publ = Proc::start(&[
        "ping",
        &u,
        "--publish",
        "--period",
        "50",
        "--size",
        "10",
        "--name",
        "tx",
    ]);
    publ.expect("ready");
    publ.expect("matched 1");
    let mut seqs = Vec::new();
    for _ in 0..3 {
        let l = sub.expect("received ");
        // received <seq> from <32 hex digits> 10 B
        let f: Vec<&str> = l.split_whitespace().collect();
        assert_eq!((f.len(), f[2], f[4], f[5]), (6, "from", "10", "B"), "{l}");
        assert_eq!(f[3].len(), 32, "{l}");
        seqs.push(f[1].parse::<u32>().unwrap());
    }
    assert!(
        seqs.windows(2).all(|w| w[1] == w[0] + 1),
        "in order: {seqs:?}"
    );
    assert!(sub.seen.iter().any(|l| l == "matched 1"), "{:?}", sub.seen);
    sub.expect("done");
    assert_eq!(sub.wait(), Some(0));
    // the subscriber left: the publisher counts down
    publ.expect("matched 0");
}

#[test]
fn spy_prints_discovery_decoded_samples_and_a_clean_leave() {
    let u = url(201);
    let mut spy = Proc::start(&["spy", &u, "--type", "courier::*", "--duration", "20"]);
    spy.expect("ready");
    let mut publ = Proc::start(&[
        "ping",
        &u,
        "--publish",
        "--period",
        "50",
        "--topic",
        "chatter",
        "--strength",
        "3",
        "--name",
        "talker",
    ]);
    publ.expect("ready");
    // participant found <prefix> name=talker unicast=127.0.0.1:<port>,... multicast=-
    let p = spy.expect("participant found ");
    assert!(p.contains(" name=talker "), "{p}");
    assert!(p.contains(" unicast=127.0.0.1:"), "{p}");
    assert!(p.ends_with(" multicast=-"), "{p}");
    let prefix = p.split_whitespace().nth(2).unwrap().to_string();
    assert_eq!(prefix.len(), 24, "{p}");
    let e = spy.expect("publication found ");
    let guid = e.split_whitespace().nth(2).unwrap().to_string();
    assert!(guid.starts_with(&prefix), "{e}");
    for want in [
        " topic=chatter ",
        " type=courier::Ping ",
        " reliability=reliable ",
        " durability=volatile ",
        " history=keep-all ",
        " deadline=infinite ",
        " ownership=exclusive(3) ",
        " partitions=[]",
    ] {
        assert!(e.contains(want), "{want} in {e}");
    }
    // sample <topic> <type> from <writer> <bytes> B: <decoded>
    let s = spy.expect("sample chatter courier::Ping from ");
    let f: Vec<&str> = s.split_whitespace().collect();
    assert_eq!((f[4], f[6]), (guid.as_str(), "B:"), "{s}");
    assert!(s.contains(": courier::Ping { seq: "), "{s}");
    spy.expect("sample chatter courier::Ping from ");
    // Ctrl-C: the publisher closes its session, so the spy sees it leave at
    // once (a goodbye, not a lease expiry); it says what it interrupted and
    // exits 130, as a shell reports Ctrl-C
    publ.signal(libc::SIGINT);
    let i = publ.expect("interrupted");
    assert!(
        i.starts_with("interrupted after ") && i.ends_with(" samples sent"),
        "{i}"
    );
    assert_eq!(publ.wait(), Some(130));
    assert_eq!(
        spy.expect("publication lost "),
        format!("publication lost {guid}")
    );
    assert_eq!(
        spy.expect("participant lost "),
        format!("participant lost {prefix} goodbye")
    );
    spy.signal(libc::SIGTERM);
    assert!(spy.expect("interrupted").starts_with("interrupted after "));
    assert_eq!(spy.wait(), Some(143));
}

#[test]
fn deadlines_and_incompatible_qos_are_reported() {
    let u = url(202);
    let mut sub = Proc::start(&[
        "ping",
        &u,
        "--subscribe",
        "--deadline",
        "100",
        "--count",
        "2",
        "--name",
        "rx",
    ]);
    sub.expect("ready");
    // nothing comes: a miss every deadline, counted
    sub.expect("deadline missed 1");
    sub.expect("deadline missed 2");
    // a publisher offering a longer deadline than requested does not match
    let mut slow = Proc::start(&[
        "ping",
        &u,
        "--publish",
        "--deadline",
        "1000",
        "--period",
        "50",
        "--name",
        "slow",
    ]);
    let i = slow.expect("incompatible ");
    assert!(i.contains("deadline"), "{i}");
    let i = sub.expect("incompatible ");
    assert!(i.contains("deadline"), "{i}");
    sub.expect("matched 0");
    drop(slow);
    // one offering a shorter one does
    let mut fast = Proc::start(&[
        "ping",
        &u,
        "--publish",
        "--deadline",
        "50",
        "--period",
        "20",
        "--name",
        "fast",
    ]);
    fast.expect("matched 1");
    sub.expect("matched 1");
    sub.expect("received ");
    sub.expect("received ");
    sub.expect("done");
    assert_eq!(sub.wait(), Some(0));
}

#[test]
fn a_counted_publisher_finishes_while_a_spy_watches() {
    // the spy's readers are best effort and never acknowledge: the last
    // sample (which waits for every reliable reader's acknowledgement) and
    // the publisher's keep-all history must not wait for them
    let u = url(203);
    let mut spy = Proc::start(&["spy", &u, "--duration", "20"]);
    spy.expect("ready");
    let started = Instant::now();
    let mut publ = Proc::start(&["ping", &u, "--publish", "--period", "100", "--count", "5"]);
    publ.expect("matched 1");
    publ.expect("sent 5");
    publ.expect("done");
    assert_eq!(publ.wait(), Some(0));
    assert!(
        started.elapsed() < Duration::from_secs(4),
        "took {:?}",
        started.elapsed()
    );
    spy.expect("sample ping courier::Ping ");
}

#[test]
fn ping_over_ipc_through_central() {
    let rt = tokio::runtime::Runtime::new().unwrap();
    let central = rt.block_on(async {
        courier_broker::CentralServer::builder()
            .bind("127.0.0.1".parse().unwrap())
            .port(0)
            .spawn()
            .await
            .unwrap()
    });
    let u = format!("ipc://{}", central.local_addr());
    let mut sub = Proc::start(&["ping", &u, "--subscribe", "--count", "2", "--name", "rx"]);
    sub.expect("ready");
    let mut publ = Proc::start(&["ping", &u, "--publish", "--period", "50", "--name", "tx"]);
    publ.expect("ready");
    publ.expect("matched 1");
    // IPC does not say who sent it
    assert_eq!(sub.expect("received ").split_whitespace().nth(3), Some("?"));
    sub.expect("received ");
    sub.expect("done");
    assert_eq!(sub.wait(), Some(0));
    publ.expect("matched 0");
    drop(publ);
    // DDS QoS on IPC: refused, not ignored
    for flag in [
        &["--publish", "--strength", "3"][..],
        &["--subscribe", "--deadline", "100"][..],
        &["--subscribe", "--best-effort"][..],
    ] {
        let mut args = vec!["ping", u.as_str()];
        args.extend_from_slice(flag);
        let (code, _, err) = run(&args);
        assert_eq!(code, 2, "{args:?}: {err}");
        assert!(err.contains(&format!("{} is DDS QoS", flag[1])), "{err}");
    }
    // spy needs a DDS backend: a clear error, exit 1
    let (code, _, err) = run(&["spy", &u]);
    assert_eq!(code, 1, "{err}");
    assert!(err.contains("pattern subscriptions"), "{err}");
    assert!(err.contains("rtps://"), "{err}");
    rt.block_on(central.shutdown());
}

#[test]
fn usage_errors_name_the_problem() {
    let u = url(204);
    let u = u.as_str();
    for (args, want) in [
        (&["fly"][..], "unrecognized subcommand 'fly'"),
        (&["pnig"][..], "a similar subcommand exists: 'ping'"),
        (
            &["ping", u][..],
            "the following required arguments were not provided",
        ),
        (
            &["ping", u, "--publish", "--subscribe"][..],
            "'--publish' cannot be used with '--subscribe'",
        ),
        (
            &["ping", u, "--publish", "--colour", "red"][..],
            "unexpected argument '--colour'",
        ),
        (
            &["ping", u, "--publsh"][..],
            "a similar argument exists: '--publish'",
        ),
        (
            &["ping", u, "--publish", "--period", "soon"][..],
            "invalid value 'soon' for '--period <MS>'",
        ),
        (
            &["ping", u, "--publish", "--period=0"][..],
            "invalid value '0' for '--period <MS>'",
        ),
        (
            &["ping", u, "--subscribe", "--count", "0"][..],
            "invalid value '0' for '--count <N>'",
        ),
        (
            &["ping", u, "--publish=yes"][..],
            "unexpected value 'yes' for '--publish'",
        ),
        (
            &["ping", u, "--publish", "--exclusive"][..],
            "'--publish' cannot be used with '--exclusive'",
        ),
        (&["ping", u, u, "--publish"][..], "unexpected argument"),
        (
            &["ping", "--publish"][..],
            "the following required arguments were not provided",
        ),
        (
            &["spy", u, "--count"][..],
            "a value is required for '--count <N>'",
        ),
        (
            &["spy", u, "--duration", "-1"][..],
            "unexpected argument '-1'",
        ),
        (
            &["spy", u, "--frobnicate"][..],
            "unexpected argument '--frobnicate'",
        ),
        (
            &["spy", u, "--topic", "a", "--topic", "b"][..],
            "--topic takes one fnmatch pattern",
        ),
        (
            &[
                "ping",
                "rtps://999?interface=lo&peers=127.0.0.1",
                "--publish",
            ][..],
            "domain 999 is above 232",
        ),
        (&["completions", "tcsh"][..], "invalid value 'tcsh'"),
    ] {
        let (code, out, err) = run(args);
        assert_eq!(code, 2, "{args:?}: {err}");
        assert!(err.starts_with("error: "), "{args:?}: {err}");
        assert!(err.contains(want), "{args:?}: {want:?} in {err}");
        assert!(out.is_empty(), "{args:?}: {out}");
    }
    // no command at all: the help, as a usage error
    let (code, _, err) = run(&[]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("Commands:"), "{err}");
    for (args, want) in [
        (&["--help"][..], "spy"),
        (&["help"][..], "ping"),
        (&["ping", "--help"][..], "--min-separation"),
        (&["spy", "-h"][..], "participant found|changed"),
        (
            &["--version"][..],
            concat!("courier ", env!("CARGO_PKG_VERSION")),
        ),
        (&["ping", "--version"][..], "courier-ping "),
        (&["completions", "bash"][..], "_courier()"),
        (&["completions", "zsh"][..], "#compdef courier"),
    ] {
        let (code, out, err) = run(args);
        assert_eq!(code, 0, "{args:?}: {err}");
        assert!(out.contains(want), "{args:?}: {want:?} in {out}");
    }
}

/// Every session URL is checked before anything connects, and a bad one
/// names the schemes this program knows.
#[test]
fn bad_urls_are_usage_errors_naming_the_known_schemes() {
    for (url, want) in [
        (
            "foo://x",
            "invalid value 'foo://x' for '<URL>': unknown scheme \"foo\" in \"foo://x\"; \
             known schemes: ipc, rtps",
        ),
        (
            "localhost:1381",
            "no scheme in \"localhost:1381\"; a session URL is SCHEME://…, known schemes: ipc, rtps",
        ),
        ("ipc://h:0", "bad IPC URL: '0' is not a port number"),
        ("rtps://x", "domain \"x\" is not a number"),
        (
            "rtps://1?interface=lo&colour=red",
            "unknown option \"colour\"",
        ),
    ] {
        for cmd in [&["ping", url, "--publish"][..], &["spy", url][..]] {
            let (code, _, err) = run(cmd);
            assert_eq!(code, 2, "{cmd:?}: {err}");
            assert!(err.contains(want), "{cmd:?}: {want:?} in {err}");
        }
    }
}

/// A free port of 127.0.0.1 that nobody listens on (bound, then closed).
fn dead_port() -> u16 {
    let l = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    l.local_addr().unwrap().port()
}

/// A central that is not there: the wait shows what it waits for (with
/// `--progress always`, as on a terminal), Ctrl-C says it interrupted the
/// connect and exits 130, and giving up names the address and what to
/// check. A host name that does not resolve fails at once.
#[test]
fn a_dead_central_is_reported_where_it_was_looked_for() {
    let port = dead_port();
    let u = format!("ipc://127.0.0.1:{port}");
    let mut waiting = Proc::start(&["--progress", "always", "ping", &u, "--subscribe"]);
    assert_eq!(
        waiting.expect_err("courier: connecting"),
        format!("courier: connecting to central at 127.0.0.1:{port} for 1 s (is central running?)")
    );
    waiting.signal(libc::SIGINT);
    let i = waiting.expect("interrupted");
    assert!(
        i.starts_with(&format!(
            "interrupted while connecting to central at 127.0.0.1:{port} ("
        )),
        "{i}"
    );
    assert_eq!(waiting.wait(), Some(130));
    let (code, out, err) = run(&["ping", &u, "--subscribe"]);
    assert_eq!(code, 1, "{err}");
    assert!(out.is_empty(), "{out}");
    let want = format!("courier: cannot connect to central at 127.0.0.1:{port} (");
    assert!(err.starts_with(&want), "{want:?} in {err}");
    assert!(
        err.trim_end()
            .ends_with("Connection refused (os error 111); is central running there?"),
        "{err}"
    );
    // no progress unless asked for (stderr is not a terminal here)
    assert_eq!(err.lines().count(), 1, "{err}");
    // a label of 64 bytes: glibc refuses the name without asking a name
    // server, so nothing leaves this machine
    let host = "a".repeat(64);
    let started = Instant::now();
    let (code, _, err) = run(&["ping", &format!("ipc://{host}:1381"), "--subscribe"]);
    assert_eq!(code, 1, "{err}");
    assert!(
        err.starts_with(&format!(
            "courier: cannot connect to central at {host}:1381: cannot resolve \"{host}\""
        )),
        "{err}"
    );
    assert!(started.elapsed() < Duration::from_secs(2), "retried: {err}");
}
