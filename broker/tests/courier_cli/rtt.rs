//! `courier ping --rtt` against `courier pong`: round trips with
//! percentiles, over IPC and RTPS.

use crate::{url, Central, Proc};

/// The value of `key=` in a statistics line.
fn stat(line: &str, key: &str) -> u64 {
    line.split_whitespace()
        .find_map(|w| w.strip_prefix(&format!("{key}=")))
        .unwrap_or_else(|| panic!("{key}= in {line}"))
        .parse()
        .unwrap()
}

fn round_trips(u: &str) {
    // --count counts the measured pings, not ping's warm-up ones: pong
    // ends by itself after the 20th, and ping loses none
    let mut pong = Proc::start(&["pong", u, "--count", "20"]);
    pong.expect("ready");
    let mut ping = Proc::start(&["ping", u, "--rtt", "--count", "20", "--size", "64"]);
    ping.expect("ready");
    ping.expect("matched 1");
    let total = ping.expect("total ");
    assert_eq!(stat(&total, "n"), 20, "{total}");
    assert_eq!(stat(&total, "lost"), 0, "{total}");
    let (min, p50, p99, max) = (
        stat(&total, "min"),
        stat(&total, "p50"),
        stat(&total, "p99"),
        stat(&total, "max"),
    );
    assert!(min <= p50 && p50 <= p99 && p99 <= max, "{total}");
    assert!(total.ends_with(" (us)"), "{total}");
    ping.expect("done");
    assert_eq!(ping.wait(), Some(0));
    assert_eq!(pong.expect("answered 20"), "answered 20");
    pong.expect("done");
    assert_eq!(pong.wait(), Some(0));
}

#[test]
fn ping_rtt_through_pong_over_ipc() {
    let c = Central::start();
    round_trips(&c.url);
    // nobody answers: the wait says so, Ctrl-C says how far it got
    let mut ping = Proc::start(&["--progress", "always", "ping", &c.url, "--rtt"]);
    assert_eq!(
        ping.expect_err("courier: no answer"),
        "courier: no answer on \"pong\" for 1 s (is `courier pong` running?)"
    );
    ping.signal(libc::SIGINT);
    assert_eq!(
        ping.expect("interrupted"),
        "interrupted after 0 round trips: n=0 lost=0 (us)"
    );
    assert_eq!(ping.wait(), Some(130));
}

#[test]
fn ping_rtt_through_pong_over_rtps() {
    round_trips(&url(240));
}
