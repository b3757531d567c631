//! Fuzzes the IPC module state machine (`courier_wire::ipc::module::Connection`)
//! with what its peers may send: the input is a script of steps, each
//! `[op, arg, len_lo, len_hi, bytes…]`. `op % 4`: 0 bytes from central,
//! 1 bytes from direct link `arg % 3` (accepted on first use), 2 one of the
//! program's calls (`wire/tests/damage/module.rs`), 3 central hangs up. The
//! module must never panic or loop: a malformed central stream closes the
//! connection with an event, a malformed direct link returns an error, and
//! calls on a closed connection return errors.
#![no_main]

#[path = "../../wire/tests/damage/module.rs"]
mod calls;

use courier_wire::ipc::module::{Connection, DeliveryKind, Event, LinkId, ModuleConfig};
use libfuzzer_sys::fuzz_target;
use std::collections::HashMap;
use std::time::Instant;

fn settle(c: &mut Connection) {
    for _ in 0..10_000 {
        let mut moved = c.poll_transmit().is_some() || c.poll_direct_transmit().is_some();
        while let Some(e) = c.poll_event() {
            moved = true;
            match e {
                Event::Delivery {
                    delivery,
                    kind: DeliveryKind::Broadcast,
                    ..
                } => {
                    let _ = c.ack(delivery);
                }
                Event::Delivery {
                    delivery,
                    kind: DeliveryKind::Query,
                    ..
                } => {
                    let _ = c.respond(delivery, "message1", 1i32.to_le_bytes().to_vec());
                }
                Event::DirectListenRequested => c.announce_direct_port(40000),
                _ => {}
            }
        }
        if !moved {
            return;
        }
    }
    panic!("the module never settles");
}

fuzz_target!(|data: &[u8]| {
    let now = Instant::now();
    let mut c = Connection::new(ModuleConfig::new("fuzzed", "localhost"), now);
    let mut links: HashMap<u8, LinkId> = HashMap::new();
    let mut rest = data;
    while rest.len() >= 4 {
        let (op, arg) = (rest[0] % 4, rest[1]);
        let len = (u16::from_le_bytes([rest[2], rest[3]]) as usize).min(rest.len() - 4);
        let bytes = &rest[4..4 + len];
        rest = &rest[4 + len..];
        match op {
            0 => c.receive(bytes, now),
            1 => {
                let link = *links.entry(arg % 3).or_insert_with(|| c.accept_direct());
                if c.receive_direct(link, bytes).is_err() {
                    // The shell drops the socket.
                    c.direct_link_failed(link);
                    links.remove(&(arg % 3));
                }
            }
            2 => {
                let _ = calls::api_call(&mut c, arg as usize);
            }
            _ => c.handle_eof(),
        }
        settle(&mut c);
    }
    c.handle_eof();
    settle(&mut c);
    for what in 0..calls::CALLS {
        let _ = calls::api_call(&mut c, what);
    }
    settle(&mut c);
});
