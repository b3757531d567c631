//! The `courier` CLI as a user runs it: `ping` publisher and subscriber
//! processes, `spy` watching them, over RTPS on loopback (each test its own
//! domain) and over IPC through an embedded central; usage errors.

use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

const T: Duration = Duration::from_secs(20);

fn url(domain: u32) -> String {
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

    fn wait(&mut self) -> Option<i32> {
        let deadline = Instant::now() + T;
        while Instant::now() < deadline {
            if let Ok(Some(st)) = self.child.try_wait() {
                return st.code();
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        panic!("courier did not exit; saw {:?}", self.seen)
    }
}

impl Drop for Proc {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn run(args: &[&str]) -> (i32, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_courier"))
        .args(args)
        .output()
        .unwrap();
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
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
    sub.expect("done");
    assert_eq!(sub.wait(), Some(0));
}

#[test]
fn spy_prints_discovery_and_decoded_samples() {
    let u = url(201);
    let mut spy = Proc::start(&["spy", &u, "--type", "courier::*", "--count", "2"]);
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
    let p = spy.expect("participant found ");
    assert!(p.contains(" name=talker "), "{p}");
    assert!(p.contains("unicast=127.0.0.1:"), "{p}");
    let e = spy.expect("publication found ");
    for want in [
        "topic=chatter",
        "type=courier::Ping",
        "reliability=reliable",
        "durability=volatile",
        "ownership=exclusive(3)",
    ] {
        assert!(e.contains(want), "{want} in {e}");
    }
    let s = spy.expect("sample chatter courier::Ping from ");
    assert!(s.contains(": courier::Ping { seq: "), "{s}");
    spy.expect("sample chatter");
    assert_eq!(spy.wait(), Some(0));
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
    sub.expect("received ");
    sub.expect("received ");
    assert_eq!(sub.wait(), Some(0));
    drop(publ);
    // spy needs a DDS backend: a clear error, exit 1
    let (code, err) = run(&["spy", &u]);
    assert_eq!(code, 1, "{err}");
    assert!(err.contains("pattern subscriptions"), "{err}");
    rt.block_on(central.shutdown());
}

#[test]
fn usage_errors_name_the_problem() {
    for (args, want) in [
        (&[][..], "no command given"),
        (&["fly"][..], "unknown command \"fly\""),
        (&["ping", "rtps://0"][..], "--publish and --subscribe"),
        (
            &["ping", "rtps://0", "--publish", "--colour", "red"][..],
            "unknown option \"--colour\"",
        ),
        (
            &["ping", "rtps://0", "--publish", "--period", "soon"][..],
            "--period \"soon\"",
        ),
        (&["ping", "--publish"][..], "no session URL"),
        (&["spy", "rtps://0", "--count"][..], "--count needs a value"),
    ] {
        let (code, err) = run(args);
        assert_eq!(code, 64, "{args:?}: {err}");
        assert!(err.contains(want), "{args:?}: {want:?} in {err}");
        assert!(err.contains("usage: courier"), "{args:?}: {err}");
    }
    let (code, err) = run(&["ping", "rtps://999", "--publish"]);
    assert_eq!(code, 1, "{err}");
    assert!(err.contains("232"), "{err}");
    let out = Command::new(env!("CARGO_BIN_EXE_courier"))
        .args(["ping", "--help"])
        .output()
        .unwrap();
    assert!(out.status.success());
    assert!(String::from_utf8_lossy(&out.stdout).contains("--min-separation"));
}
