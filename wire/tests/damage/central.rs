//! What the damaged-capture tests (`central_replay.rs`) and the
//! `central_input` fuzz target (`fuzz/`, which includes this file) share:
//! the configurations of central worth damaging, and carrying out central's
//! outputs as a shell does, checking that it says why it closes a
//! connection.
#![allow(dead_code)]

use std::collections::HashSet;
use std::time::SystemTime;

use courier_wire::ipc::central::{Central, Config, ConnId, LogOptions, Output};

/// Central's configurations worth damaging, by `pick % 6`: C's defaults,
/// `-r`, data logging with times, cut-through of everything above 16 bytes,
/// send-ahead to every module, and tiny memory and frame bounds; direct
/// mode (`-c`) with any of them.
pub fn config(pick: u8, direct: bool) -> Config {
    let mut c = Config::default();
    c.direct = direct;
    c.terminal_log = LogOptions::parse("msid", false).unwrap();
    match pick % 6 {
        0 => {}
        1 => c.resend_on_reconnect = true,
        2 => c.terminal_log = LogOptions::parse("mstid", false).unwrap(),
        3 => c.cut_through = Some(16),
        4 => {
            let captured = [
                "module1", "module2", "module3", "wiretest", "receiver", "sender",
            ];
            let fuzzed = ["m0", "m1", "m2", "m3", "m4", "m5"];
            for m in captured.into_iter().chain(fuzzed) {
                c.send_ahead.insert(m.to_string(), 4);
            }
        }
        _ => {
            c.max_queued_bytes = 64;
            c.max_frame = 200;
        }
    }
    c
}

/// Every connection central closed (`closes`: connection, reason) has its
/// line among the log `lines` central wrote with it: bad input names the
/// connection and the fault, whatever the log options; a module's own
/// goodbye and a close from the console are logged when logging is on.
/// Callers that make more than ten connections that never name
/// themselves within 10 s must leave those past the tenth out: central
/// logs ten such strangers a window and then one line with the count of
/// the rest (`STRANGER_BURST` in `wire/src/ipc/central/log.rs`; the
/// `central_input` fuzz target does so).
pub fn check_closes_logged(central: &Central, lines: &[String], closes: &[(u64, String)]) {
    let logging = central.config().terminal_log.any() || central.config().file_log.any();
    for (conn, reason) in closes {
        assert!(
            !reason.is_empty(),
            "connection {conn} closed without a reason"
        );
        let normal = reason == "module sent x_ipc_CloseMsg" || reason == "closed from the console";
        let said = lines.iter().any(|l| match reason.as_str() {
            // Lines name a connection by its socket number (C's file
            // descriptor, reused), not by the shell's id.
            "module sent x_ipc_CloseMsg" => {
                l.starts_with("x_ipcClose: Closed Connection Detected from: sd: ")
            }
            "closed from the console" => l.starts_with("close Module: Closing"),
            _ => l.starts_with("ERROR: closing connection ") && l.ends_with(reason),
        });
        assert!(
            said || (normal && !logging),
            "connection {conn} closed ({reason}) without its log line: {lines:#?}"
        );
    }
}

/// Carries out what central asks, as a shell does: connections it closes
/// join `gone` and are disconnected (each checked to have its log line),
/// and `paused` follows its pause and resume requests. Fails if central
/// never stops producing output, or if its tables disagree afterwards
/// ([`Central::check_invariants`]).
pub fn carry_out(central: &mut Central, paused: &mut HashSet<u64>, gone: &mut HashSet<u64>) {
    let mut lines = Vec::new();
    let mut closes = Vec::new();
    let mut guard = 0usize;
    while let Some(o) = central.poll_output() {
        guard += 1;
        assert!(guard < 1_000_000, "central keeps producing output");
        match o {
            Output::Close { conn, reason } => {
                gone.insert(conn.0);
                closes.push((conn.0, reason));
            }
            Output::Log { line, .. } => lines.push(line),
            Output::PauseRead { conn } => {
                paused.insert(conn.0);
            }
            Output::ResumeRead { conn } => {
                paused.remove(&conn.0);
            }
            _ => {}
        }
    }
    check_closes_logged(central, &lines, &closes);
    for (conn, _) in closes {
        central.disconnect(ConnId(conn), SystemTime::UNIX_EPOCH);
    }
    central.check_invariants();
}

/// What an operator does at the console, by `what % 12`, through central's
/// console API (the console's text is the shell's, `courier::central`):
/// `status`, `display`, `memory`, `help`, `close` of one of `names`, a
/// close of a module nobody runs, and the options `-lmsid`, `-Lx`, `-r`,
/// `-lx`.
pub fn console(central: &mut Central, what: usize, names: [&str; 3], now: SystemTime) {
    match what % 12 {
        0 => drop(central.modules()),
        1 => drop(central.dispatches()),
        2 => drop(central.stats()),
        3 => central.print("The following are central commands:".into()),
        4..=6 => drop(central.close_module_named(names[what % 12 - 4], now)),
        7 => drop(central.close_module_named("nobody-runs-this", now)),
        8 => central.reconfigure(|c| c.terminal_log = LogOptions::parse("msid", false).unwrap()),
        9 => central.reconfigure(|c| c.file_log = LogOptions::parse("x", true).unwrap()),
        10 => central.reconfigure(|c| c.resend_on_reconnect = true),
        _ => central.reconfigure(|c| c.terminal_log = LogOptions::parse("x", false).unwrap()),
    }
}
