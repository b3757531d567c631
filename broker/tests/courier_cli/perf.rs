//! `courier perf pub|sub` over IPC, and against Cyclone DDS's own
//! `ddsperf` in both directions (Debian's `cyclonedds-tools`, pinned to
//! `lo` with unicast discovery, like every peer of these tests).

use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use crate::{run, url, Central, Proc, T};

/// Cyclone DDS's configuration for `ddsperf`: loopback only, no
/// multicast, unicast discovery at 127.0.0.1 (participant indices 0..=20,
/// like Courier's `peers=127.0.0.1`).
const CYCLONE_URI: &str = "<CycloneDDS><Domain id=\"any\"><General><Interfaces>\
<NetworkInterface name=\"lo\"/></Interfaces><AllowMulticast>false</AllowMulticast>\
</General><Discovery><ParticipantIndex>auto</ParticipantIndex>\
<MaxAutoParticipantIndex>20</MaxAutoParticipantIndex><Peers>\
<Peer address=\"127.0.0.1\"/></Peers></Discovery></Domain></CycloneDDS>";

/// A `ddsperf` process on `domain`; killed and reaped when dropped.
struct Ddsperf(Child);

impl Ddsperf {
    fn start(domain: &str, args: &[&str]) -> Ddsperf {
        let child = Command::new("ddsperf")
            .args(["-i", domain])
            .args(args)
            .env("CYCLONEDDS_URI", CYCLONE_URI)
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap_or_else(|e| {
                panic!("cannot run ddsperf ({e}): install the Debian package cyclonedds-tools")
            });
        Ddsperf(child)
    }

    /// Its whole output, once it has ended (within `T` after its own `-D`).
    fn output(mut self, within: Duration) -> String {
        let deadline = Instant::now() + within;
        while self.0.try_wait().expect("wait ddsperf").is_none() {
            assert!(
                Instant::now() < deadline,
                "ddsperf still running after {within:?}"
            );
            std::thread::sleep(Duration::from_millis(50));
        }
        let child = std::mem::replace(
            &mut self.0,
            Command::new("true").spawn().expect("spawn true"),
        );
        let out = child.wait_with_output().expect("ddsperf output");
        format!(
            "{}{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        )
    }
}

impl Drop for Ddsperf {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// The domain of a `url(..)`.
fn domain(u: &str) -> &str {
    u.trim_start_matches("rtps://").split('?').next().unwrap()
}

/// The number after `key ` in `line`.
fn field(line: &str, key: &str) -> u64 {
    line.split_once(&format!(" {key} "))
        .unwrap_or_else(|| panic!("{key} in {line}"))
        .1
        .split_whitespace()
        .next()
        .unwrap()
        .parse()
        .unwrap_or_else(|e| panic!("{key} in {line}: {e}"))
}

#[test]
fn perf_over_ipc_counts_every_sample_and_its_latency() {
    let c = Central::start();
    let u = c.url.as_str();
    let mut sub = Proc::start(&["perf", "sub", u, "--count", "2000"]);
    sub.expect("receiving DDSPerfRDataKS");
    // pub waits for the subscription, then publishes as fast as it goes
    let (code, out, err) = run(&["perf", "pub", u, "--size", "100", "--count", "2000"]);
    assert_eq!(code, 0, "{out}{err}");
    assert!(out.contains("total sent 2000 in "), "{out}");
    let (code, out, err) = sub.finish();
    assert_eq!(code, Some(0), "{out}{err}");
    let total = out
        .lines()
        .find(|l| l.starts_with("total received"))
        .unwrap_or_else(|| panic!("no total in {out}"));
    assert_eq!(field(total, "received"), 2000, "{total}");
    assert_eq!(field(total, "lost"), 0, "{total}");
    // every IPC sample carries its send time in the baggage
    assert!(total.contains("latency n=2000 "), "{total}");
    // --secs bounds the wait for readers too: nobody reads "nobody"
    let (code, out, err) = run(&[
        "perf",
        "pub",
        u,
        "--topic",
        "nobody",
        "--readers",
        "1",
        "--secs",
        "1",
    ]);
    assert_eq!(
        (code, out.as_str(), err.as_str()),
        (
            1,
            "matched 0\n",
            "courier: no reader of \"nobody\" within --secs 1: nothing was measured\n"
        )
    );
}

#[test]
fn ddsperf_pub_is_measured_by_courier_perf_sub() {
    let u = url(270);
    let mut sub = Proc::start(&["perf", "sub", &u, "--count", "300"]);
    sub.expect("receiving DDSPerfRDataKS");
    // ddsperf writes KeyedSeq samples of 100 bytes on DDSPerfRDataKS
    let dp = Ddsperf::start(domain(&u), &["-D", "8", "pub", "1000Hz", "size", "100"]);
    let (code, out, err) = sub.finish();
    drop(dp);
    assert_eq!(code, Some(0), "{out}{err}");
    let total = out
        .lines()
        .find(|l| l.starts_with("total received"))
        .unwrap_or_else(|| panic!("no total in {out}"));
    assert_eq!(field(total, "received"), 300, "{total}");
    assert_eq!(field(total, "lost"), 0, "{total}");
    assert!(out.contains(" size 100 "), "{out}");
    // Cyclone stamps each sample with its source time
    assert!(total.contains("latency n=300 "), "{total}");
}

#[test]
fn courier_perf_pub_is_measured_by_ddsperf_sub() {
    let u = url(271);
    let dp = Ddsperf::start(domain(&u), &["-D", "6", "sub"]);
    // --readers 1: it starts once ddsperf's reader matched
    let (code, out, err) = run(&[
        "perf", "pub", &u, "--size", "88", "--count", "1000", "--rate", "2000",
    ]);
    assert_eq!(code, 0, "{out}{err}");
    let log = dp.output(T);
    // `[pid] 3.000  size 100 total 1000 lost 0 delta …`: 12 + 88 bytes
    let last = log
        .lines()
        .rfind(|l| l.contains(" size 100 total "))
        .unwrap_or_else(|| panic!("ddsperf saw no samples:\n{log}"));
    assert_eq!(field(last, "total"), 1000, "{log}");
    assert_eq!(field(last, "lost"), 0, "{log}");
}

#[test]
fn perf_usage_errors() {
    let c = Central::start();
    let (code, _, err) = run(&["perf", "pub", &c.url, "--best-effort", "--count", "1"]);
    assert_eq!(code, 2, "{err}");
    assert!(
        err.contains("--best-effort is DDS QoS and needs an rtps:// session"),
        "{err}"
    );
    let (code, _, err) = run(&["perf", "pub", &c.url, "--rate", "-3"]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("is not a rate"), "{err}");
    for secs in ["0", "1e300"] {
        let (code, _, err) = run(&["perf", "sub", &c.url, "--secs", secs]);
        assert_eq!(code, 2, "{err}");
        assert!(
            err.contains("is not a number of seconds above 0 and at most 1e9"),
            "{err}"
        );
    }
    let (code, _, err) = run(&["perf", "pub", &c.url, "--size", "100000000"]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("--size"), "{err}");
    let (code, _, err) = run(&["perf", "bench", &c.url]);
    assert_eq!(code, 2, "{err}");
}
