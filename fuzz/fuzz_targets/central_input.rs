//! Fuzzes the central state machine (`courier_wire::ipc::central::Central`)
//! with what modules may send: the input is a script of steps, each
//! `[op, conn, len_lo, len_hi, bytes…]`. `op % 8`: 0–4 bytes from module
//! `conn % 6` (connecting it first), 5 its disconnect, 6 a console command;
//! a first step with op 7 picks, by its `conn` byte, a configuration (direct mode, `-r`, data
//! logging, cut-through, send-ahead, tiny memory and frame bounds). Central
//! must never panic, must say in its log why it closes a connection, must
//! free every queued byte when the modules are gone, and must still accept
//! a module afterwards.
#![no_main]

use courier_wire::ipc::central::{Central, Config, ConnId, LogOptions, Output, Peer};
use libfuzzer_sys::fuzz_target;
use std::collections::HashSet;
use std::time::SystemTime;

const COMMANDS: &[&str] = &[
    "status", "display", "memory", "help", "close m0", "close m1", "unlock m0", "-lmsid",
    "-Lx", "-r", "-lx",
];

fn config(pick: u8) -> Config {
    let mut c = Config::default();
    c.terminal_log = LogOptions::parse("msid", false).unwrap();
    c.direct = pick & 0x80 != 0;
    match pick % 6 {
        0 => {}
        1 => c.resend_on_reconnect = true,
        2 => c.terminal_log = LogOptions::parse("mstid", false).unwrap(),
        3 => c.cut_through = Some(16),
        4 => {
            for i in 0..6 {
                c.send_ahead.insert(format!("m{i}"), 4);
            }
        }
        _ => {
            c.max_queued_bytes = 64;
            c.max_frame = 200;
        }
    }
    c
}

fn drain(central: &mut Central, gone: &mut HashSet<u64>) {
    let now = SystemTime::UNIX_EPOCH;
    let mut lines = Vec::new();
    let mut closes = Vec::new();
    while let Some(o) = central.poll_output() {
        match o {
            Output::Close { conn, reason } => closes.push((conn, reason)),
            Output::Log { line, .. } => lines.push(line),
            _ => {}
        }
    }
    for (conn, reason) in closes {
        assert!(!reason.is_empty());
        let c = conn.0;
        let said = lines.iter().any(|l| match reason.as_str() {
            "module sent x_ipc_CloseMsg" => {
                l.starts_with(&format!("x_ipcClose: Closed Connection Detected from: sd: {c}:"))
            }
            "closed from the console" => l.starts_with("close Module: Closing"),
            _ => l.starts_with(&format!("ERROR: closing connection {c} ")) && l.ends_with(&reason),
        });
        assert!(said, "connection {c} closed ({reason}) without its log line");
        gone.insert(conn.0);
        central.disconnect(conn, now);
    }
}

fuzz_target!(|data: &[u8]| {
    let now = SystemTime::UNIX_EPOCH;
    let mut rest = data;
    let mut central = match rest {
        [p, pick, tail @ ..] if p % 8 == 7 => {
            rest = tail;
            Central::new(config(*pick))
        }
        _ => Central::new(Config::default()),
    };
    let mut open = HashSet::new();
    let mut gone = HashSet::new();
    while rest.len() >= 4 {
        let (op, conn) = (rest[0] % 8, (rest[1] % 6) as u64);
        let len = (u16::from_le_bytes([rest[2], rest[3]]) as usize).min(rest.len() - 4);
        let bytes = &rest[4..4 + len];
        rest = &rest[4 + len..];
        match op {
            0..=4 => {
                if gone.contains(&conn) {
                    continue;
                }
                if open.insert(conn) {
                    central.connect(ConnId(conn), Peer::Other(format!("m{conn}")), now);
                }
                central.receive(ConnId(conn), bytes, now);
            }
            5 => {
                if open.contains(&conn) && gone.insert(conn) {
                    central.disconnect(ConnId(conn), now);
                }
            }
            6 => central.command(COMMANDS[bytes.len() % COMMANDS.len()], now),
            _ => {}
        }
        drain(&mut central, &mut gone);
    }
    for conn in open {
        if gone.insert(conn) {
            central.disconnect(ConnId(conn), now);
            drain(&mut central, &mut gone);
        }
    }
    let s = central.stats();
    assert_eq!(s.modules, 0);
    assert_eq!(s.queued_bytes, 0, "bytes still queued after every module left");
    if !central.config().resend_on_reconnect {
        assert_eq!(s.dispatches, s.waiting_for_handler, "dispatches leaked");
    }
});
