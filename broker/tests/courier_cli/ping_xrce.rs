//! `courier ping` over `xrce+udp://`, through Courier's XRCE agent
//! embedded in the test (UDP 127.0.0.1 port 0; its DDS participant on
//! `lo`, unicast, in a leased domain): publisher to subscriber, and round
//! trips through `courier pong`. An agent tells its clients nothing of
//! matched readers, so neither side prints `matched`.

use courier::rtps_backend::RtpsOptions;
use courier_broker::xrce_agent::{Transport, XrceAgent};

use crate::Proc;

/// The agent, its runtime, and the session URL of its clients.
fn agent(key: u32) -> (tokio::runtime::Runtime, XrceAgent, String) {
    agent_at(key, "127.0.0.1:0")
}

/// [`agent`] on UDP `addr`.
fn agent_at(key: u32, addr: &str) -> (tokio::runtime::Runtime, XrceAgent, String) {
    let domain = courier_tests::domains::lease(key);
    let mut o = RtpsOptions::default();
    o.domain = domain;
    o.interface = Some("lo".into());
    o.peers = vec!["127.0.0.1".into()];
    o.multicast = false;
    let rt = tokio::runtime::Runtime::new().unwrap();
    let a = rt
        .block_on(
            XrceAgent::builder()
                .transport(Transport::Udp(addr.parse().unwrap()))
                .rtps(o)
                .spawn(),
        )
        .unwrap();
    let url = format!("xrce+udp://{}?domain={domain}", a.udp_addrs()[0]);
    (rt, a, url)
}

#[test]
fn ping_publisher_to_subscriber_over_xrce() {
    let (rt, a, u) = agent(272);
    let mut sub = Proc::start(&["ping", &u, "--subscribe", "--count", "3", "--name", "rx"]);
    sub.expect("ready");
    let mut publ = Proc::start(&["ping", &u, "--publish", "--period", "50", "--name", "tx"]);
    publ.expect("ready");
    for _ in 0..3 {
        sub.expect("received ");
    }
    sub.expect("done");
    assert_eq!(sub.wait(), Some(0));
    drop(publ);
    rt.block_on(a.shutdown());
}

#[test]
fn ping_rtt_through_pong_over_xrce() {
    let (rt, a, u) = agent(273);
    let mut pong = Proc::start(&["pong", &u]);
    pong.expect("ready");
    let mut ping = Proc::start(&["ping", &u, "--rtt", "--count", "20", "--size", "64"]);
    ping.expect("ready");
    let total = ping.expect("total ");
    assert!(total.starts_with("total n=20 "), "{total}");
    assert!(total.contains(" lost=0 "), "{total}");
    ping.expect("done");
    assert_eq!(ping.wait(), Some(0));
    assert!(
        !ping.seen.iter().any(|l| l.starts_with("matched")),
        "an XRCE session knows no matches: {:?}",
        ping.seen
    );
    drop(pong);
    rt.block_on(a.shutdown());
}

/// `echo`, `spy` and `hz` over XRCE name the type (the agent creates a typed
/// DDS reader) and the topics (a client learns nothing of discovery).
#[test]
fn echo_spy_and_hz_over_xrce_name_their_type() {
    let (rt, a, u) = agent(274);
    let mut echo = Proc::start(&[
        "echo",
        &u,
        "ping",
        "--type",
        "courier::Ping",
        "--count",
        "2",
    ]);
    let mut hz = Proc::start(&["hz", &u, "ping", "--type", "courier::Ping", "--count", "4"]);
    let mut spy = Proc::start(&[
        "spy",
        &u,
        "--topic",
        "ping",
        "--type",
        "courier::Ping",
        "--count",
        "2",
    ]);
    spy.expect("ready");
    let mut publ = Proc::start(&["ping", &u, "--publish", "--period", "100", "--size", "3"]);
    publ.expect("ready");
    let first = echo.expect("{");
    assert!(
        first.starts_with("{1, ") && first.ends_with(", \"xxx\"}"),
        "{first}"
    );
    let line = spy.expect("sample ");
    assert!(
        line.starts_with("sample ping courier::Ping from ? ") && line.ends_with(", \"xxx\"}"),
        "{line}"
    );
    assert_eq!(echo.wait(), Some(0));
    assert_eq!(spy.wait(), Some(0));
    let rate = hz.expect("rate ");
    assert!(rate.contains(" window 4 "), "{rate}");
    assert_eq!(hz.wait(), Some(0));
    drop(publ);
    // without a type, or with a pattern: usage errors that say why
    let (code, _, err) = crate::run(&["echo", &u, "ping"]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("give --type TYPE"), "{err}");
    // what an XRCE client cannot see, it says instead of listing nothing
    let (code, _, err) = crate::run(&["list", &u]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("list the DDS side (rtps://…)"), "{err}");
    let (code, _, err) = crate::run(&["record", &u, "ping", "-o", "/nonexistent/x.mcap"]);
    assert_eq!(code, 2, "{err}");
    assert!(
        err.contains("record the same topics on the DDS side"),
        "{err}"
    );
    let (code, _, err) = crate::run(&["bw", &u, "ping"]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("give --type TYPE"), "{err}");
    let (code, _, err) = crate::run(&["spy", &u, "--topic", "p*", "--type", "courier::Ping"]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("patterns cannot be matched"), "{err}");
    rt.block_on(a.shutdown());
}

/// `courier pub` over XRCE: the agent says nothing of readers, so pub
/// says it cannot wait for them and publishes at once (it used to fail
/// with "watching handlers is not available"); echo decodes what it sends.
#[test]
fn pub_and_echo_over_xrce() {
    let (rt, a, u) = agent(275);
    let args = ["--format", "int", "--type", "Seven"];
    let mut echo = Proc::start(&[&["echo", &u, "t", "--count", "2"][..], &args].concat());
    let mut publ = Proc::start(
        &[
            &["pub", &u, "t", "7", "--rate", "10", "--count", "0"][..],
            &args,
        ]
        .concat(),
    );
    publ.expect("ready");
    publ.expect("sent 1");
    assert_eq!(echo.expect(""), "7");
    assert_eq!(echo.expect(""), "7");
    assert_eq!(echo.wait(), Some(0));
    drop(publ);
    rt.block_on(a.shutdown());
}

/// `courier pub` on XRCE without --type publishes courier::Ping, as on
/// rtps:// and as `pub --help` says: a Ping's JSON goes out as one, text
/// that is no Ping is a usage error that says the type was the default
/// and names --type. With the type named, a struct of one string takes
/// plain text (ROS 2's std_msgs/String).
#[test]
fn pub_over_xrce_defaults_to_ping_and_takes_plain_text() {
    let (rt, a, u) = agent(276);
    let mut echo = Proc::start(&[
        "echo",
        &u,
        "pings",
        "--type",
        "courier::Ping",
        "--count",
        "1",
    ]);
    let mut publ = Proc::start(&[
        "pub",
        &u,
        "pings",
        r#"[1, 2, "x"]"#,
        "--rate",
        "10",
        "--count",
        "0",
    ]);
    publ.expect("ready");
    publ.expect("sent 1");
    assert_eq!(echo.expect(""), r#"{1, 2, "x"}"#);
    assert_eq!(echo.wait(), Some(0));
    drop(publ);
    let (code, out, err) = crate::run(&["pub", &u, "chatter", "hello"]);
    assert_eq!((code, out.as_str()), (2, ""), "{err}");
    assert!(
        err.starts_with("error: \"hello\" is not a value of {uint, ulong, string}: ")
            && err.contains("; without --type the type is courier::Ping")
            && err.contains("name another with --type"),
        "{err}"
    );
    let ros = "std_msgs::msg::dds_::String_";
    let mut echo = Proc::start(&["echo", &u, "chatter", "--type", ros, "--count", "1"]);
    let mut publ = Proc::start(&[
        "pub", &u, "chatter", "hello", "--type", ros, "--rate", "10", "--count", "0",
    ]);
    publ.expect("ready");
    publ.expect("sent 1");
    assert_eq!(echo.expect(""), r#"{"hello"}"#);
    assert_eq!(echo.wait(), Some(0));
    drop(publ);
    rt.block_on(a.shutdown());
}

/// An agent that goes away and comes back is said on stderr, one line
/// each way, while the command goes on (audit 16: a 2.5 min outage showed
/// nothing).
#[test]
fn an_agent_outage_is_said_on_stderr() {
    let (rt, a, u) = agent(277);
    let addr = a.udp_addrs()[0];
    let mut publ = Proc::start(&["ping", &u, "--publish", "--period", "50", "--name", "tx"]);
    publ.expect("ready");
    rt.block_on(a.shutdown());
    let lost = publ.expect_err("courier: the agent at ");
    assert!(lost.contains("stopped answering"), "{lost}");
    // the same address again: the session comes back (made anew: this
    // agent has no --state)
    let (rt2, a2, _) = agent_at(277, &addr.to_string());
    let back = publ.expect_err("courier: the ");
    assert!(
        back.contains("answers again") || back.contains("made again"),
        "{back}"
    );
    drop(publ);
    rt2.block_on(a2.shutdown());
    drop(rt);
}
