//! Fuzzes the central state machine (`courier_wire::ipc::central::Central`)
//! with what modules may send: the input is a script of steps, each
//! `[op, conn, len_lo, len_hi, bytes…]`. `op % 8`: 0–4 bytes from module
//! `conn % 6` (connecting it first; once gone, connecting it again under a
//! new id if `conn` has bit 6), 5 its disconnect, 6 a console command,
//! 7 time passing: `len` × 10 ms (up to 11 minutes; no bytes follow), then
//! central's timeouts when due (or early, by `conn`'s bit 3): connections
//! that never said their module name are closed, strangers' log
//! summaries said.
//! A first step with op 7 picks, by its `conn` byte, one of the
//! configurations of the damaged-capture tests (`wire/tests/damage/`), and
//! by its bits 4–5 the handshake timeout (10 s, none, 1 s, 1 ms).
//! Central must never panic or loop, must say in its log why it closes a
//! connection, must keep its tables in agreement after every step
//! (`Central::check_invariants`), and must free every queued byte and
//! dispatch (but for queries waiting for a handler) when the modules are
//! gone.
#![no_main]

#[path = "../../wire/tests/damage/central.rs"]
mod hostile;

use courier_wire::ipc::central::{Central, Config, ConnId, Output, Peer};
use libfuzzer_sys::fuzz_target;
use std::collections::HashSet;
use std::time::{Duration, SystemTime};

/// Central's reason for closing a connection that did not name itself.
const SILENT: &str = "no module name within ";

/// Connections that had not named themselves (strangers): central logs
/// at most 10 of them every 10 s (`STRANGER_BURST`, `STRANGER_WINDOW` of
/// `wire/src/ipc/central/log.rs`) and then says how many it left out.
#[derive(Default)]
struct Strangers {
    /// Connections made so far (more than 10: some lines may be left out).
    connects: u64,
    /// The connections without a module name when the step began, and
    /// the one it connected.
    nameless: HashSet<u64>,
    /// A stranger's close was not logged, and no summary came after it.
    unsaid: bool,
}

/// Whether `lines` has the line `hostile::check_closes_logged` asks for a
/// close for `reason`.
fn said(lines: &[String], reason: &str) -> bool {
    lines.iter().any(|l| match reason {
        "module sent x_ipc_CloseMsg" => {
            l.starts_with("x_ipcClose: Closed Connection Detected from: sd: ")
        }
        "closed from the console" => l.starts_with("close Module: Closing"),
        _ => l.starts_with("ERROR: closing connection ") && l.ends_with(reason),
    })
}

/// `hostile::carry_out` at `now` (not at the epoch), for steps that may
/// time connections out: a connection is closed for not naming itself
/// only in a timeout step (`timeouts`); its line is a warning, or left out
/// with the strangers'. A stranger's close may go unlogged once more than
/// 10 connections were made, and then the strangers' summary must come in
/// a later step. The other closes are checked by
/// `hostile::check_closes_logged`.
fn carry_out(
    central: &mut Central,
    paused: &mut HashSet<u64>,
    gone: &mut HashSet<u64>,
    strangers: &mut Strangers,
    timeouts: bool,
    now: SystemTime,
) {
    let mut lines = Vec::new();
    let mut closes = Vec::new();
    let mut silent = Vec::new();
    let mut guard = 0usize;
    while let Some(o) = central.poll_output() {
        guard += 1;
        assert!(guard < 1_000_000, "central keeps producing output");
        match o {
            Output::Close { conn, reason } => {
                gone.insert(conn.0);
                if reason.starts_with(SILENT) {
                    assert!(timeouts, "connection {} timed out outside handle_timeout", conn.0);
                    silent.push(conn.0);
                } else {
                    closes.push((conn.0, reason));
                }
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
    if lines.iter().any(|l| l.contains("(their lines left out: ")) {
        strangers.unsaid = false;
    }
    let (quiet, checked): (Vec<_>, Vec<_>) = closes.iter().cloned().partition(|(c, reason)| {
        strangers.connects > 10 && strangers.nameless.contains(c) && !said(&lines, reason)
    });
    let warned = lines
        .iter()
        .filter(|l| l.starts_with("WARNING: closing connection ") && l.contains("did not say its module name"))
        .count();
    assert!(
        warned == silent.len() || (warned < silent.len() && strangers.connects > 10),
        "{} connections timed out, {warned} warnings: {lines:#?}",
        silent.len()
    );
    strangers.unsaid |= !quiet.is_empty() || warned < silent.len();
    hostile::check_closes_logged(central, &lines, &checked);
    for conn in closes.iter().map(|c| c.0).chain(silent) {
        central.disconnect(ConnId(conn), now);
    }
    central.check_invariants();
}

fuzz_target!(|data: &[u8]| {
    let mut now = SystemTime::UNIX_EPOCH;
    let mut rest = data;
    let mut central = match rest {
        [p, pick, tail @ ..] if p % 8 == 7 => {
            rest = tail;
            let mut c = hostile::config(*pick, *pick & 0x80 != 0);
            c.handshake_timeout = [
                Some(Duration::from_secs(10)),
                None,
                Some(Duration::from_secs(1)),
                Some(Duration::from_millis(1)),
            ][usize::from(*pick >> 4 & 3)];
            Central::new(c)
        }
        _ => Central::new(Config::default()),
    };
    let mut open = HashSet::new();
    let mut gone = HashSet::new();
    // Connection ids by slot: a slot whose connection is gone connects
    // again under a new id (`conn` bit 6), so that more than six
    // connections come and go (strangers' log budget, reconnections).
    let mut ids: [u64; 6] = [0, 1, 2, 3, 4, 5];
    let mut strangers = Strangers::default();
    // Not honoured: the fuzzer's module writes whatever it likes.
    let mut paused = HashSet::new();
    while rest.len() >= 4 {
        let (op, slot) = (rest[0] % 8, usize::from(rest[1] % 6));
        let (early, again) = (rest[1] & 8 != 0, rest[1] & 0x40 != 0);
        let mut conn = ids[slot];
        strangers.nameless = central
            .modules()
            .iter()
            .filter(|m| m.name.is_none())
            .map(|m| m.conn.0)
            .collect();
        let wanted = u16::from_le_bytes([rest[2], rest[3]]);
        let len = if op == 7 { 0 } else { (wanted as usize).min(rest.len() - 4) };
        let bytes = &rest[4..4 + len];
        rest = &rest[4 + len..];
        match op {
            0..=4 => {
                if gone.contains(&conn) {
                    if !again {
                        continue;
                    }
                    ids[slot] += 6;
                    conn = ids[slot];
                }
                if open.insert(conn) {
                    central.connect(ConnId(conn), Peer::Other(format!("m{slot}")), now);
                    strangers.connects += 1;
                    strangers.nameless.insert(conn);
                }
                central.receive(ConnId(conn), bytes, now);
            }
            5 => {
                if open.contains(&conn) && gone.insert(conn) {
                    central.disconnect(ConnId(conn), now);
                }
            }
            6 => hostile::console(&mut central, bytes.len(), ["m0", "m1", "m2"], now),
            _ => {
                now += Duration::from_millis(10 * u64::from(wanted));
                if early || central.next_timeout().is_some_and(|t| t <= now) {
                    central.handle_timeout(now);
                }
                carry_out(&mut central, &mut paused, &mut gone, &mut strangers, true, now);
                continue;
            }
        }
        // Carries out central's outputs, then checks its invariants.
        carry_out(&mut central, &mut paused, &mut gone, &mut strangers, false, now);
    }
    for conn in open {
        if gone.insert(conn) {
            central.disconnect(ConnId(conn), now);
            carry_out(&mut central, &mut paused, &mut gone, &mut strangers, false, now);
        }
    }
    // Nothing is left to time out; what is due is said: the strangers'
    // summary for every close whose line was left out.
    if let Some(t) = central.next_timeout() {
        central.handle_timeout(t.max(now));
        strangers.nameless.clear();
        carry_out(&mut central, &mut paused, &mut gone, &mut strangers, true, now);
    }
    assert!(!strangers.unsaid, "a stranger's close was neither logged nor summarized");
    let s = central.stats();
    assert_eq!(s.modules, 0);
    assert_eq!(
        s.queued_bytes, 0,
        "bytes still queued after every module left"
    );
    if !central.config().resend_on_reconnect {
        assert_eq!(s.dispatches, s.waiting_for_handler, "dispatches leaked");
    }
});
