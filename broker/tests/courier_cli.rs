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
}

impl Proc {
    fn start(args: &[&str]) -> Proc {
        let mut child = Command::new(env!("CARGO_BIN_EXE_courier"))
            .args(args)
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .expect("spawn courier");
        let out = child.stdout.take().unwrap();
        let (tx, rx) = mpsc::channel();
        std::thread::spawn(move || {
            for l in BufReader::new(out).lines().map_while(Result::ok) {
                if tx.send(l).is_err() {
                    break;
                }
            }
        });
        Proc {
            child,
            lines: rx,
            seen: Vec::new(),
        }
    }

    /// The next line starting with `prefix` (lines before it are skipped).
    fn expect(&mut self, prefix: &str) -> String {
        let deadline = Instant::now() + T;
        loop {
            match self
                .lines
                .recv_timeout(deadline.saturating_duration_since(Instant::now()))
            {
                Ok(l) => {
                    self.seen.push(l.clone());
                    if l.starts_with(prefix) {
                        return l;
                    }
                }
                Err(_) => panic!("no line {prefix:?} within {T:?}; saw {:?}", self.seen),
            }
        }
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
        " partitions=[] ",
        // a final type: XCDR1, what Fast DDS 2.9 reads too
        " representation=[XCDR1]",
    ] {
        assert!(e.contains(want), "{want} in {e}");
    }
    // sample <topic> <type> from <writer> <bytes> B <encapsulation>: <decoded>
    let s = spy.expect("sample chatter courier::Ping from ");
    let f: Vec<&str> = s.split_whitespace().collect();
    assert_eq!(
        (f[4], f[6], f[7], f[8]),
        (guid.as_str(), "B", "XCDR1", "CDR_LE:"),
        "{s}"
    );
    assert!(s.contains(": courier::Ping { seq: "), "{s}");
    spy.expect("sample chatter courier::Ping from ");
    // Ctrl-C: the publisher closes its session, so the spy sees it leave at
    // once (a goodbye, not a lease expiry)
    publ.signal(libc::SIGINT);
    publ.expect("interrupted");
    assert_eq!(publ.wait(), Some(0));
    assert_eq!(
        spy.expect("publication lost "),
        format!("publication lost {guid}")
    );
    assert_eq!(
        spy.expect("participant lost "),
        format!("participant lost {prefix} goodbye")
    );
    spy.signal(libc::SIGTERM);
    spy.expect("interrupted");
    assert_eq!(spy.wait(), Some(0));
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
        assert_eq!(code, 64, "{args:?}: {err}");
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
        (&[][..], "no command given"),
        (&["fly"][..], "unknown command \"fly\""),
        (&["ping", u][..], "--publish and --subscribe"),
        (
            &["ping", u, "--publish", "--subscribe"][..],
            "--publish and --subscribe",
        ),
        (
            &["ping", u, "--publish", "--colour", "red"][..],
            "unknown option \"--colour\"",
        ),
        (
            &["ping", u, "--publish", "--period", "soon"][..],
            "--period \"soon\"",
        ),
        (
            &["ping", u, "--publish", "--period=0"][..],
            "--period must be at least 1 ms",
        ),
        (
            &["ping", u, "--subscribe", "--count", "0"][..],
            "--count must be at least 1",
        ),
        (
            &["ping", u, "--publish=yes"][..],
            "--publish takes no value",
        ),
        (
            &["ping", u, "--publish", "--exclusive"][..],
            "--exclusive is for --subscribe",
        ),
        (&["ping", u, u, "--publish"][..], "unexpected argument"),
        (&["ping", "--publish"][..], "no session URL"),
        (&["spy", u, "--count"][..], "--count needs a value"),
        (&["spy", u, "--duration", "-1"][..], "--duration \"-1\""),
        (
            &["spy", u, "--frobnicate"][..],
            "unknown option \"--frobnicate\"",
        ),
    ] {
        let (code, out, err) = run(args);
        assert_eq!(code, 64, "{args:?}: {err}");
        assert!(err.contains(want), "{args:?}: {want:?} in {err}");
        assert!(err.contains("usage: courier"), "{args:?}: {err}");
        assert!(out.is_empty(), "{args:?}: {out}");
    }
    let (code, _, err) = run(&[
        "ping",
        "rtps://999?interface=lo&peers=127.0.0.1",
        "--publish",
    ]);
    assert_eq!(code, 1, "{err}");
    assert!(err.contains("232"), "{err}");
    for (args, want) in [
        (&["--help"][..], "spy <url>"),
        (&["help"][..], "ping <url>"),
        (&["ping", "--help"][..], "--min-separation"),
        (&["spy", "-h"][..], "participant found|changed"),
    ] {
        let (code, out, err) = run(args);
        assert_eq!(code, 0, "{args:?}: {err}");
        assert!(out.contains(want), "{args:?}: {want:?} in {out}");
    }
}
