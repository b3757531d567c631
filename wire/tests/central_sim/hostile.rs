//! Hostile and broken input: frames that break the rules close only their
//! sender, with a log line; mistakes are logged, not fatal, and cannot
//! flood the log; random bytes never panic central.
//!
//! The senders are connections of the test's own to central on the
//! network (`Sim::raw`), their bytes cut as any module's are. Two tests
//! feed a bare `Central` instead: one looks at where each log line goes
//! (terminal or file), which the network's log events do not keep, and
//! one gives each frame its own arrival time, back in time included.

use std::time::SystemTime;

use courier_wire::ipc::central::{Central, Config, ConnId, LogOptions, Output, Peer};
use courier_wire::ipc::frame::{ClassId, MsgClass};
use courier_wire::ipc::module::Event;

use crate::routing::raw_frame;
use crate::support::{define, untimed, Sim};

/// Sends `bytes` on a connection of its own while a module is connected:
/// the reasons central closed connections for, and its log lines.
fn hostile(bytes: &[u8]) -> (Vec<String>, Vec<String>) {
    let mut sim = Sim::new(untimed());
    let ok = sim.connect("bystander");
    let attacker = sim.raw("attacker");
    let (logs, closes) = (sim.logs.len(), sim.closes.len());
    sim.net.write(attacker, bytes);
    sim.pump();
    let closes = sim.closes[closes..]
        .iter()
        .map(|(_, why)| why.clone())
        .collect();
    let logs = sim.logs[logs..].to_vec();
    // Central is still fine for everyone else.
    define(&mut sim, ok, "still", "int");
    sim.pump();
    let op = sim.m(ok).is_module_connected("bystander").unwrap();
    sim.pump();
    assert!(sim.take_events(ok).contains(&Event::ModuleConnected {
        op,
        connected: true
    }));
    (closes, logs)
}

/// `-lx` turns logging off, not the report of a module that sends garbage:
/// the ERROR line still goes to the terminal (and, with `-L`, to the file).
#[test]
fn bad_input_is_reported_with_logging_off() {
    for file in [false, true] {
        let mut config = Config::default();
        config.terminal_log = LogOptions::parse("x", false).unwrap();
        if file {
            config.file_log = LogOptions::parse("m", true).unwrap();
        }
        let mut central = Central::new(config);
        let now = SystemTime::now();
        central.connect(ConnId(7), Peer::Other("attacker".into()), now);
        let mut f = raw_frame(MsgClass::Query, 5, &[]);
        f[4..8].copy_from_slice(&(-8i32).to_be_bytes());
        central.receive(ConnId(7), &f, now);
        central.check_invariants();
        let mut lines = Vec::new();
        while let Some(o) = central.poll_output() {
            if let Output::Log { target, line } = o {
                lines.push((target.terminal, target.file, line));
            }
        }
        // The ERROR line reaches the terminal, and the close line that C
        // prints whatever the options (connections are named by their
        // socket number, from 5, as C's descriptors).
        let shown: Vec<_> = lines.iter().filter(|l| l.0).collect();
        assert_eq!(shown.len(), 2, "{lines:?}");
        assert_eq!(
            shown[1].2,
            "x_ipcClose: Closed Connection Detected from: sd: 5:"
        );
        let (_, to_file, line) = shown[0];
        assert_eq!(*to_file, file, "{lines:?}");
        assert!(
            line.starts_with("ERROR: closing connection 5 (from attacker): ")
                && line.contains("negative length"),
            "{line}"
        );
    }
}

#[test]
fn hostile_frames_close_only_the_offender_with_a_log_line() {
    // Negative length.
    let mut f = raw_frame(MsgClass::Query, 5, &[]);
    f[4..8].copy_from_slice(&(-8i32).to_be_bytes());
    let (c, l) = hostile(&f);
    assert!(c[0].contains("negative length"), "{c:?}");
    assert!(l.iter().any(|x| x.contains("negative length")));
    // Oversized.
    let mut f = raw_frame(MsgClass::Query, 5, &[]);
    f[4..8].copy_from_slice(&i32::MAX.to_be_bytes());
    let (c, _) = hostile(&f);
    assert!(c[0].contains("exceeds the limit"), "{c:?}");
    // Not packed / bad byte order.
    let mut f = raw_frame(MsgClass::Query, 5, &[]);
    f[17] = 4;
    assert!(hostile(&f).0[0].contains("not packed"));
    let mut f = raw_frame(MsgClass::Query, 5, &[]);
    f[16] = 0x77;
    assert!(hostile(&f).0[0].contains("byte-order"));
}

#[test]
fn truncated_internal_data_closes_with_the_reason() {
    // x_ipc_msgInfoMsg with a string length running off the end.
    let mut sim = Sim::new(untimed());
    let t = sim.raw("t");
    sim.pump();
    let greeting = sim.net.read(t);
    let msg_info = i32::from_be_bytes(greeting[..4].try_into().unwrap());
    let mut body = 1000i32.to_le_bytes().to_vec();
    body.extend_from_slice(b"abc");
    let f = raw_frame(MsgClass::Query, msg_info, &body);
    sim.net.write(t, &f);
    sim.pump();
    let closes = &sim.closes;
    assert_eq!(closes.len(), 1);
    assert!(closes[0].1.contains("count 1000"), "{closes:?}");
    assert!(sim.net.is_eof(t), "and the connection is closed");
}

#[test]
fn unknown_ids_and_stray_acks_are_logged_not_fatal() {
    let (c, l) = hostile(&raw_frame(MsgClass::Broadcast, 123_456, &[]));
    assert!(c.is_empty());
    assert!(l.iter().any(|x| x.contains("unknown id 123456")), "{l:?}");
    let mut ack = raw_frame(MsgClass::Success, -1, &[]);
    ack[20..24].copy_from_slice(&42i32.to_be_bytes());
    let (c, l) = hostile(&ack);
    assert!(c.is_empty());
    assert!(l.iter().any(|x| x.contains("Success for unknown")), "{l:?}");
}

/// A module repeating a mistake in a loop (here 10 000 Successes for a
/// dispatch it was never given, and as many frames with an unknown id)
/// gets a burst of lines, then one a second, and a count of the rest, not
/// a line per frame; another module's lines are not affected.
#[test]
fn a_module_repeating_a_mistake_cannot_flood_the_log() {
    let mut central = Central::new(Config::default());
    let t0 = SystemTime::now();
    central.connect(ConnId(7), Peer::Other("looper".into()), t0);
    central.connect(ConnId(8), Peer::Other("other".into()), t0);
    let mut ack = raw_frame(MsgClass::Success, -1, &[]);
    ack[20..24].copy_from_slice(&42i32.to_be_bytes());
    let unknown = raw_frame(MsgClass::Broadcast, 123_456, &[]);
    let problems = |central: &mut Central| {
        let mut lines = Vec::new();
        while let Some(o) = central.poll_output() {
            match o {
                Output::Log { line, .. } => lines.push(line),
                Output::Close { reason, .. } => panic!("closed: {reason}"),
                _ => {}
            }
        }
        lines
    };
    problems(&mut central);
    for i in 0..10_000u32 {
        // 10 000 frames over 5 seconds.
        let now = t0 + std::time::Duration::from_micros(u64::from(i) * 500);
        central.receive(ConnId(7), if i % 2 == 0 { &ack } else { &unknown }, now);
        central.check_invariants();
    }
    let lines = problems(&mut central);
    // 10 at once, then one for each of the 4 further seconds.
    assert_eq!(lines.len(), 10 + 4 + 4, "{lines:#?}");
    let counts: Vec<u64> = lines
        .iter()
        .filter_map(|l| l.strip_prefix("WARNING: "))
        .filter_map(|l| {
            l.split_once(" more problem line(s) about connection 5 (from looper) left out")
        })
        .map(|(n, _)| n.parse().unwrap())
        .collect();
    assert_eq!(counts.len(), 4, "{lines:#?}");
    // The other module is not silenced by the first one's budget.
    central.receive(ConnId(8), &ack, t0 + std::time::Duration::from_secs(5));
    let other = problems(&mut central);
    assert_eq!(other.len(), 1, "{other:?}");
    assert!(other[0].contains("from 6 (from other)"), "{other:?}");
    // Whatever was left out last is said when the module goes.
    let later = t0 + std::time::Duration::from_micros(4_999_900);
    for _ in 0..3 {
        central.receive(ConnId(7), &ack, later);
    }
    assert!(problems(&mut central).is_empty());
    central.disconnect(ConnId(7), later);
    let closing = problems(&mut central);
    let last = closing
        .iter()
        .find_map(|l| {
            l.strip_prefix("WARNING: ")?
                .strip_suffix(" more problem line(s) about connection 5 (from looper) left out")
        })
        .unwrap_or_else(|| panic!("no count when the module went: {closing:#?}"));
    let last: u64 = last.parse().unwrap();
    assert!(last >= 3);
    let printed = (lines.len() - counts.len()) as u64;
    assert_eq!(
        printed + counts.iter().sum::<u64>() + last,
        10_003,
        "every problem printed or counted"
    );
}

#[test]
fn disconnect_mid_frame_is_logged() {
    let mut sim = Sim::new(Config::default());
    let t = sim.raw("t");
    let f = raw_frame(MsgClass::Query, 5, &[1, 2, 3, 4]);
    sim.net.write(t, &f[..20]);
    sim.net.close(t);
    sim.pump();
    assert!(
        sim.logs
            .iter()
            .any(|l| l.contains("in the middle of a frame (20 byte(s)")),
        "{:?}",
        sim.logs
    );
    assert_eq!(sim.central().stats().modules, 0);
}

#[test]
fn random_bytes_never_panic() {
    // A cheap deterministic fuzz: xorshift bytes, sometimes with a valid
    // header prefix, cut as the network cuts them; central's invariants
    // are checked after every piece and after the disconnect.
    let mut x: u64 = 0x9e37_79b9_7f4a_7c15;
    for round in 0..2000 {
        let mut sim = Sim::new(Config::default());
        let fuzz = sim.raw("fuzz");
        let n = (round % 200) + 1;
        let mut b = Vec::with_capacity(n);
        for _ in 0..n {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            b.push(x as u8);
        }
        if round % 2 == 0 && b.len() >= 28 {
            let body = (b.len() - 28) as i32;
            b[0..4].copy_from_slice(&0i32.to_be_bytes());
            b[4..8].copy_from_slice(&body.to_be_bytes());
            b[16..20].copy_from_slice(&ClassId::native(MsgClass::Query).0.to_be_bytes());
            let id = [182i32, 171, 173, 166, 164, 168, 162, 147, 144, 199, 195][round % 11];
            b[12..16].copy_from_slice(&id.to_be_bytes());
        }
        sim.net.write(fuzz, &b);
        sim.net.close(fuzz);
        sim.pump();
        assert_eq!(sim.central().stats().modules, 0, "round {round}");
    }
}

/// A peer that connects, sends a bad frame (or nothing) and closes, in a
/// loop, with a new connection each time: each connection has a budget of
/// its own, so only a central-wide bound keeps the log from getting two
/// lines per attempt. The first connections are logged as before; the
/// rest are counted and the count is said once the interval is over.
#[test]
fn connection_flood_from_nameless_peers_is_bounded_and_counted() {
    use std::time::Duration;
    let t0 = SystemTime::UNIX_EPOCH + Duration::from_secs(1_000_000);
    let mut central = Central::new_at(Config::default(), t0);
    while central.poll_output().is_some() {}
    let mut lines = Vec::new();
    let drain = |c: &mut Central, lines: &mut Vec<String>| {
        while let Some(o) = c.poll_output() {
            if let Output::Log { line, .. } = o {
                lines.push(line);
            }
        }
    };
    let mut bad = raw_frame(MsgClass::Query, 5, &[0; 40]);
    bad[4..8].copy_from_slice(&(-8i32).to_be_bytes());
    // 1000 connections in 5 s, every other one sending a bad frame.
    for i in 0..1000u64 {
        let now = t0 + Duration::from_millis(5 * i);
        let conn = ConnId(100 + i);
        central.connect(conn, Peer::Other("prober".into()), now);
        if i % 2 == 0 {
            central.receive(conn, &bad, now);
        }
        central.disconnect(conn, now);
        drain(&mut central, &mut lines);
    }
    central.check_invariants();
    // The first connections are logged as before.
    assert!(
        lines[0].starts_with("ERROR: closing connection 5 (from prober): ")
            && lines[0].contains("negative length"),
        "{lines:?}"
    );
    assert_eq!(
        lines[1],
        "x_ipcClose: Closed Connection Detected from: sd: 5:"
    );
    assert!(
        lines.len() <= 30,
        "{} lines for 1000 connections: {:?}",
        lines.len(),
        &lines[..lines.len().min(40)]
    );
    // Once the interval is over, the next connection (a module) says how
    // many were left out.
    let later = t0 + Duration::from_secs(11);
    central.connect(ConnId(5000), Peer::Other("module".into()), later);
    drain(&mut central, &mut lines);
    let summary: Vec<&String> = lines
        .iter()
        .filter(|l| l.contains(" more connection"))
        .collect();
    assert_eq!(summary.len(), 1, "{lines:?}");
    let shown = lines
        .iter()
        .filter(|l| l.contains("Closed Connection Detected"))
        .count() as u64;
    let counted: u64 = summary[0]
        .split(' ')
        .filter_map(|w| w.parse::<u64>().ok())
        .take(2)
        .sum();
    assert!(
        summary[0].contains("closed for bad frames"),
        "{}",
        summary[0]
    );
    assert_eq!(shown + counted, 1000, "{}", summary[0]);
    // A new interval: strangers are logged again.
    let conn = ConnId(6000);
    central.connect(conn, Peer::Other("late".into()), later);
    central.receive(conn, &bad, later);
    drain(&mut central, &mut lines);
    assert!(
        lines
            .last()
            .unwrap()
            .starts_with("x_ipcClose: Closed Connection Detected"),
        "{lines:?}"
    );
}

/// Large frames half sent on many connections hold central's memory only
/// up to `max_frames_in_progress` (audit 20: 8 connections each holding
/// 200 MiB of a 255 MiB frame took central to 1.6 GB): a connection that
/// starts one past it is read no more until a frame in progress completes,
/// then goes on; the first frame always proceeds.
#[test]
fn large_frames_in_progress_are_bounded_all_connections_together() {
    // (untimed: the network's clock must not run out the strangers' 10 s)
    let mut config = untimed();
    config.max_frames_in_progress = 100_000;
    let mut sim = Sim::new(config);
    let frame = raw_frame(MsgClass::Query, 5, &vec![7u8; 60_000]);
    let (a, b, c) = (sim.raw("a"), sim.raw("b"), sim.raw("c"));
    let paused = |sim: &mut Sim, s: courier_wire::sim::StreamId| sim.node().is_paused(s.peer());
    for s in [a, b, c] {
        sim.net.write(s, &frame[..30_000]);
        sim.pump();
    }
    assert!(!paused(&mut sim, a), "the first frame proceeds");
    assert!(
        paused(&mut sim, b) && paused(&mut sim, c),
        "no room for more"
    );
    assert_eq!(sim.central().stats().frames_waited, 2);
    // b and c go on writing: nothing of it is read
    sim.net.write(b, &frame[30_000..]);
    sim.pump();
    assert!(paused(&mut sim, b));
    // a's frame completes (a stranger's query: refused, and a goes): room
    sim.net.write(a, &frame[30_000..]);
    sim.pump();
    assert!(
        !paused(&mut sim, b),
        "b is read again and its frame goes on"
    );
}

/// Definitions outlive their module (as in C), so modules defining ever
/// new messages grew central without end (audit 20: 20 × 10 000
/// definitions with 4 KB formats made 979 MB). Past
/// `max_definition_bytes` a new definition, subscription to an unknown
/// message or named format is refused with a warning; what is defined
/// stays usable, and redefining it with no more bytes is taken.
#[test]
fn definitions_are_bounded_in_bytes() {
    let mut config = untimed();
    let base = Central::new(config.clone()).stats().definition_bytes;
    config.max_definition_bytes = base + 20_000;
    let mut sim = Sim::new(config);
    let m = sim.connect("definer");
    let format = format!("{{{}int}}", "int, ".repeat(200)); // 1006 bytes
    for i in 0..40 {
        define(&mut sim, m, &format!("m{i}"), &format);
    }
    sim.pump();
    let held = sim.central().stats().definition_bytes;
    assert!(held <= base + 20_000, "{held}");
    assert!(held > base + 15_000, "{held}");
    assert!(sim.central().message_id("m0").is_some());
    assert!(sim.central().message_id("m39").is_none());
    let refused: Vec<&String> = sim
        .logs
        .iter()
        .filter(|l| l.contains("refused: definitions hold"))
        .collect();
    assert!(
        refused
            .first()
            .is_some_and(|l| l.starts_with("WARNING: message m")
                && l.ends_with("central keeps (max_definition_bytes)")),
        "{:#?}",
        sim.logs
    );
    // subscriptions to messages nobody defined are refused too, once
    // they fill what is left (from another module: the definer's warnings
    // are past their budget)
    let other = sim.connect("other");
    for i in 0..10 {
        sim.m(other)
            .subscribe(&format!("unknown{i}"), &format!("HND-{i}"))
            .unwrap();
    }
    sim.pump();
    assert!(sim.central().stats().definition_bytes <= base + 20_000);
    assert!(
        sim.logs
            .iter()
            .any(|l| l.contains("handler HND-9 of message unknown9 (not defined yet) refused")),
        "{:#?}",
        sim.logs
    );
    // what is defined is served: redefined alike, subscribed, published
    define(&mut sim, m, "m0", &format);
    let reader = sim.connect("reader");
    sim.m(reader).subscribe("m0", "HND-m0").unwrap();
    sim.pump();
    sim.m(m).publish("m0", vec![0u8; 201 * 4], -1).unwrap();
    sim.pump();
    assert_eq!(sim.deliveries(reader).len(), 1);
    assert!(sim.central().stats().definition_bytes <= base + 20_000);
    sim.central().check_invariants();
}
