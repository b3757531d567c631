//! Courier's XRCE client (a `Session` over `xrce+udp://`) ⇄ Courier's
//! `xrce-agent` ⇄ Fast DDS 2.9 (Debian's, `fastdds_peer` through
//! `courier_tests::peers`, pinned to 127.0.0.1 with unicast discovery), in
//! both directions: what the XRCE session writes a Fast DDS reader gets,
//! and what a Fast DDS writer writes the XRCE session reads, samples
//! larger than the XRCE MTU included.
//!
//! The agent's DDS participant is on `lo`, unicast to 127.0.0.1, multicast
//! off, in a domain leased machine-wide (`courier_tests::domains`); its
//! XRCE socket binds 127.0.0.1 port 0. Every wait is bounded.

use std::net::SocketAddr;

use courier::Session;
use courier_broker::xrce_agent::{Transport, XrceAgent};
use courier_tests::peers::{fastdds_peer, msg_sample_line, payload, PeerProcess};
use futures::StreamExt;

mod xrce_client;
use xrce_client::{rtps, runtime, Msg, T};

/// The agent (UDP on 127.0.0.1:0) and a session of it in `domain`.
fn agent_and_session(rt: &tokio::runtime::Runtime, domain: u32) -> (XrceAgent, Session) {
    let a = rt
        .block_on(
            XrceAgent::builder()
                .transport(Transport::Udp(SocketAddr::from(([127, 0, 0, 1], 0))))
                .rtps(rtps(domain))
                .spawn(),
        )
        .unwrap();
    let url = format!("xrce+udp://{}?domain={domain}", a.udp_addrs()[0]);
    let s = rt
        .block_on(async { tokio::time::timeout(T, Session::builder(url).connect()).await })
        .unwrap()
        .unwrap();
    (a, s)
}

/// The Fast DDS peer with this command line (words separated by spaces).
fn fastdds(args: &str) -> PeerProcess {
    let exe = fastdds_peer().unwrap_or_else(|e| panic!("cannot build the Fast DDS peer: {e}"));
    let args: Vec<&str> = args.split_whitespace().collect();
    PeerProcess::spawn(exe, &args).unwrap_or_else(|e| panic!("{e}"))
}

#[test]
fn an_xrce_session_writes_to_fast_dds() {
    let d = courier_tests::domains::lease(1);
    let rt = runtime();
    let (a, s) = agent_and_session(&rt, d);
    let mut sub = fastdds(&format!(
        "--domain {d} --topic xrce_to_fastdds --type msg --sub --reliable --transient-local \
         --keep-all --count 5 --timeout-s 60"
    ));
    sub.expect_line("ready", T).unwrap();
    let p = rt
        .block_on(
            s.publisher::<Msg>("xrce_to_fastdds")
                .reliable()
                .transient_local()
                .keep_all()
                .build(),
        )
        .unwrap();
    sub.expect_line("matched 1", T)
        .unwrap_or_else(|e| panic!("{e}: {}", sub.stderr()));
    // 40 bytes fit one XRCE message; 1500 are fragmented on the way to the agent
    let sizes = [40, 1500, 40, 1500, 40];
    for (i, size) in sizes.iter().enumerate() {
        let seq = i as u32 + 1;
        let m = Msg {
            seq,
            text: "xrce".into(),
            payload: payload(seq, *size),
        };
        rt.block_on(async { p.publish(&m).confirmed_within(T).await })
            .unwrap();
    }
    for (i, size) in sizes.iter().enumerate() {
        let line = sub.expect_line("sample", T).unwrap();
        assert_eq!(
            line,
            msg_sample_line(i as u32 + 1, "xrce", *size),
            "{}",
            sub.stderr()
        );
    }
    sub.expect_line("done", T).unwrap();
    rt.block_on(s.close());
    rt.block_on(a.shutdown());
}

#[test]
fn fast_dds_writes_to_an_xrce_session() {
    let d = courier_tests::domains::lease(2);
    let rt = runtime();
    let (a, s) = agent_and_session(&rt, d);
    let mut sub = rt
        .block_on(s.subscriber::<Msg>("fastdds_to_xrce").reliable().build())
        .unwrap();
    let mut publ = fastdds(&format!(
        "--domain {d} --topic fastdds_to_xrce --type msg --pub --reliable --count 5 \
         --size 40,1500 --wait-match 1 --text fdds --linger-ms 3000 --timeout-s 60"
    ));
    for want in 1..=5u32 {
        let got = rt
            .block_on(async { tokio::time::timeout(T, sub.next()).await })
            .unwrap_or_else(|_| panic!("sample {want}: {}", publ.stderr()))
            .unwrap()
            .unwrap()
            .value;
        let size = if want % 2 == 1 { 40 } else { 1500 };
        assert_eq!(got.seq, want);
        assert_eq!(got.text, format!("fdds-{want}"));
        assert_eq!(got.payload, payload(want, size));
    }
    publ.expect_line("acked", T).unwrap();
    publ.kill();
    rt.block_on(s.close());
    rt.block_on(a.shutdown());
}
