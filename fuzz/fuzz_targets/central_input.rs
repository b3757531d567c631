//! Fuzzes the central state machine (`courier_wire::ipc::central::Central`)
//! with what modules may send: the input is a script of steps, each
//! `[op, conn, len_lo, len_hi, bytes…]`. `op % 8`: 0–4 bytes from module
//! `conn % 6` (connecting it first), 5 its disconnect, 6 a console command.
//! A first step with op 7 picks, by its `conn` byte, one of the
//! configurations of the damaged-capture tests (`wire/tests/damage/`).
//! Central must never panic or loop, must say in its log why it closes a
//! connection, must keep its tables in agreement after every step
//! (`Central::check_invariants`), and must free every queued byte and
//! dispatch (but for queries waiting for a handler) when the modules are
//! gone.
#![no_main]

#[path = "../../wire/tests/damage/central.rs"]
mod hostile;

use courier_wire::ipc::central::{Central, Config, ConnId, Peer};
use libfuzzer_sys::fuzz_target;
use std::collections::HashSet;
use std::time::SystemTime;


fuzz_target!(|data: &[u8]| {
    let now = SystemTime::UNIX_EPOCH;
    let mut rest = data;
    let mut central = match rest {
        [p, pick, tail @ ..] if p % 8 == 7 => {
            rest = tail;
            Central::new(hostile::config(*pick, *pick & 0x80 != 0))
        }
        _ => Central::new(Config::default()),
    };
    let mut open = HashSet::new();
    let mut gone = HashSet::new();
    // Not honoured: the fuzzer's module writes whatever it likes.
    let mut paused = HashSet::new();
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
            6 => hostile::console(&mut central, bytes.len(), ["m0", "m1", "m2"], now),
            _ => {}
        }
        // Carries out central's outputs, then checks its invariants.
        hostile::carry_out(&mut central, &mut paused, &mut gone);
    }
    for conn in open {
        if gone.insert(conn) {
            central.disconnect(ConnId(conn), now);
            hostile::carry_out(&mut central, &mut paused, &mut gone);
        }
    }
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
