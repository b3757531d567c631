//! What central does as time passes with nothing arriving: a connection
//! that never says its module name is closed after
//! `Config::handshake_timeout` (C's central keeps it for ever, so silent
//! connections could hold every file descriptor), so is one whose large
//! frame stops arriving half way (`Config::frame_stall_timeout`), and the
//! count of strangers left out of the log is said when its window is
//! over, not only when the next connection comes.

use std::time::{Duration, SystemTime};

use courier_wire::ipc::central::{Central, Config, ConnId, Output, Peer};
use courier_wire::ipc::frame::MsgClass;

use crate::routing::raw_frame;
use crate::support::{define, Sim};

fn config(timeout: Option<Duration>) -> Config {
    let mut c = Config::default();
    c.handshake_timeout = timeout;
    c
}

#[test]
fn a_connection_that_never_names_itself_is_closed_after_the_timeout() {
    assert_eq!(
        Config::default().handshake_timeout,
        Some(Duration::from_secs(10))
    );
    let mut sim = Sim::new(Config::default());
    let module = sim.connect("bystander");
    let start = sim.net.now();
    let _silent = sim.raw("prober");
    // Some bytes, but never a whole frame, let alone IPC_connect.
    let half = sim.raw("half");
    sim.net.write(half, &[0, 0, 0]);
    sim.pump();
    let reasons: Vec<&str> = sim.closes.iter().map(|(_, why)| why.as_str()).collect();
    assert_eq!(
        reasons,
        ["no module name within 10 s", "no module name within 10 s"],
        "{:#?}",
        sim.logs
    );
    assert!(sim.net.now() - start >= Duration::from_secs(10));
    let warned: Vec<&String> = sim
        .logs
        .iter()
        .filter(|l| l.contains("did not say its module name"))
        .collect();
    assert_eq!(warned.len(), 2, "{:#?}", sim.logs);
    assert!(
        warned[0].starts_with("WARNING: closing connection 6 (from prober): it did not say its module name (IPC_connect) within 10 s"),
        "{}",
        warned[0]
    );
    // The named module was left alone and central still serves it.
    define(&mut sim, module, "after", "int");
    sim.pump();
    assert!(sim.central().message_id("after").is_some());
    assert_eq!(sim.closes.len(), 2);
    sim.central().check_invariants();
}

#[test]
fn named_modules_and_the_c_setting_never_time_out() {
    // With the timeout off (C's behaviour), a silent connection stays.
    let mut sim = Sim::new(config(None));
    let _silent = sim.raw("prober");
    sim.pump();
    sim.net.run_for(Duration::from_secs(3600));
    assert!(sim.closes.is_empty(), "{:?}", sim.closes);
    assert_eq!(sim.central().next_timeout(), None);

    // A module that named itself is never closed by the timeout, however
    // long it stays quiet.
    let mut sim = Sim::new(config(Some(Duration::from_millis(500))));
    let m = sim.connect("quiet");
    sim.net.run_for(Duration::from_secs(3600));
    sim.pump();
    assert!(sim.closes.is_empty(), "{:?}", sim.closes);
    define(&mut sim, m, "later", "int");
    sim.pump();
    assert!(sim.central().message_id("later").is_some());
}

fn drain(c: &mut Central) -> (Vec<String>, Vec<ConnId>) {
    let (mut lines, mut closed) = (Vec::new(), Vec::new());
    while let Some(o) = c.poll_output() {
        match o {
            Output::Log { line, .. } => lines.push(line),
            Output::Close { conn, .. } => closed.push(conn),
            _ => {}
        }
    }
    (lines, closed)
}

/// A flood of silent connections: the first ten are logged, the rest are
/// closed all the same and counted in one line at the end of the window,
/// without waiting for another connection to come.
#[test]
fn silent_floods_are_closed_and_counted_when_the_window_ends() {
    let t0 = SystemTime::UNIX_EPOCH + Duration::from_secs(1_000_000);
    let mut central = Central::new_at(Config::default(), t0);
    drain(&mut central);
    assert_eq!(central.next_timeout(), None);
    for i in 0..30u64 {
        central.connect(ConnId(100 + i), Peer::Other("prober".into()), t0);
    }
    drain(&mut central);
    let due = t0 + Duration::from_secs(10);
    assert_eq!(central.next_timeout(), Some(due));
    // Early: nothing happens.
    central.handle_timeout(due - Duration::from_millis(1));
    let (lines, closed) = drain(&mut central);
    assert!(lines.is_empty() && closed.is_empty(), "{lines:?}");
    central.handle_timeout(due);
    let (mut lines, closed) = drain(&mut central);
    assert_eq!(closed.len(), 30);
    // The strangers' window started with the first line about them.
    let window_end = due + Duration::from_secs(10);
    assert_eq!(central.next_timeout(), Some(window_end));
    central.handle_timeout(window_end);
    lines.extend(drain(&mut central).0);
    let warnings = lines
        .iter()
        .filter(|l| l.contains("did not say its module name"))
        .count();
    assert_eq!(warnings, 10, "{lines:#?}");
    assert_eq!(
        lines.last().map(String::as_str),
        Some(
            "WARNING: … and 20 more connection(s) closed for not naming themselves in time \
             in the last 10 s (their lines left out: at most 10 such connections are logged every 10 s)"
        ),
        "{lines:#?}"
    );
    for c in closed {
        central.disconnect(c, window_end);
    }
    assert_eq!(central.next_timeout(), None);
    central.check_invariants();
}

/// Strangers that close by themselves: the count of those left out comes
/// when the window ends (central asks for that time), not at the next
/// connection, which may never come.
#[test]
fn the_strangers_summary_comes_when_its_window_ends() {
    let t0 = SystemTime::UNIX_EPOCH + Duration::from_secs(1_000_000);
    let mut central = Central::new_at(config(None), t0);
    drain(&mut central);
    for i in 0..25u64 {
        let conn = ConnId(100 + i);
        let now = t0 + Duration::from_millis(i);
        central.connect(conn, Peer::Other("prober".into()), now);
        central.disconnect(conn, now);
    }
    drain(&mut central);
    let due = t0 + Duration::from_secs(10);
    assert_eq!(central.next_timeout(), Some(due));
    central.handle_timeout(due);
    let (lines, _) = drain(&mut central);
    assert_eq!(lines.len(), 1, "{lines:#?}");
    assert!(
        lines[0].contains("15 more connection(s) closed before naming themselves"),
        "{}",
        lines[0]
    );
    assert_eq!(central.next_timeout(), None);
}

/// A large frame half sent and then nothing (audit 20): its connection
/// held its share of `max_frames_in_progress`, and larger frames from
/// others waited, for as long as it stayed open. It is closed after
/// `frame_stall_timeout` without a byte; one that keeps sending is not,
/// however slowly.
#[test]
fn a_large_frame_that_stops_arriving_is_closed_and_frees_its_room() {
    assert_eq!(
        Config::default().frame_stall_timeout,
        Some(Duration::from_secs(30))
    );
    let mut c = config(None);
    c.max_frames_in_progress = 130_000; // two of the frames below
    let mut sim = Sim::with(c, 1, courier_wire::sim::StreamFaults::none(), None);
    let bystander = sim.connect("bystander");
    let frame = raw_frame(MsgClass::Query, 5, &vec![7u8; 60_000]);
    let (slow, stalled, waiter) = (sim.raw("slow"), sim.raw("stalled"), sim.raw("waiter"));
    let start = sim.net.now();
    sim.net.write(slow, &frame[..20_000]);
    sim.net.write(stalled, &frame[..30_000]);
    sim.net.run_for(Duration::from_secs(1));
    sim.net.write(waiter, &frame[..20_000]);
    sim.net.run_for(Duration::from_secs(1));
    let paused = |sim: &mut Sim, s: courier_wire::sim::StreamId| sim.node().is_paused(s.peer());
    assert!(paused(&mut sim, waiter), "no room for a third frame");
    // `slow` sends a little every 20 s: never 30 s without a byte
    for k in 1..3 {
        sim.net.run_for(Duration::from_secs(20));
        sim.net
            .write(slow, &frame[20_000 + 10 * (k - 1)..20_000 + 10 * k]);
    }
    sim.net.run_for(Duration::from_secs(5));
    sim.collect();
    let reasons: Vec<&str> = sim.closes.iter().map(|(_, why)| why.as_str()).collect();
    assert_eq!(
        reasons,
        ["its frame of 60028 bytes stopped arriving (30000 received, none in 30 s)"],
        "{:#?}",
        sim.logs
    );
    assert!(sim.net.now() - start >= Duration::from_secs(30));
    let warned: Vec<&String> = sim
        .logs
        .iter()
        .filter(|l| l.contains("stopped arriving"))
        .collect();
    assert_eq!(warned.len(), 1, "{:#?}", sim.logs);
    assert!(
        warned[0].starts_with("WARNING: closing connection")
            && warned[0].contains("(from stalled)"),
        "{}",
        warned[0]
    );
    // its room went to the waiter, which is read again
    assert!(!paused(&mut sim, waiter), "the waiter is read again");
    // the slow one is still open (40 s since its frame started), and
    // named modules are served
    assert!(sim.closes.iter().all(|(c, _)| *c != slow.peer()));
    define(&mut sim, bystander, "after", "int");
    sim.pump();
    assert!(sim.central().message_id("after").is_some());
    sim.central().check_invariants();
}

#[test]
fn frames_never_stall_out_with_the_c_setting() {
    let mut c = config(None);
    c.frame_stall_timeout = None;
    let mut sim = Sim::new(c);
    let s = sim.raw("stalled");
    let frame = raw_frame(MsgClass::Query, 5, &vec![7u8; 60_000]);
    sim.net.write(s, &frame[..30_000]);
    sim.pump();
    sim.net.run_for(Duration::from_secs(3600));
    assert!(sim.closes.is_empty(), "{:?}", sim.closes);
    assert_eq!(sim.central().next_timeout(), None);
}
