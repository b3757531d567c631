//! What the damaged-stream module test (`ipc_module_replay.rs`) and the
//! `ipc_module_input` fuzz target (`fuzz/`, which includes this file)
//! share: the calls a module's program makes between what it receives.
#![allow(dead_code)]

use courier_wire::ipc::module::{Connection, Error, MsgLength};

/// How many different calls [`api_call`] makes.
pub const CALLS: usize = 10;

/// The program's call number `what % CALLS`. Any may fail once the
/// connection is broken; none may panic.
pub fn api_call(c: &mut Connection, what: usize) -> Result<(), Error> {
    match what % CALLS {
        0 => c.subscribe("message1", "HND-m1").map(drop),
        1 => c.subscribe("query1", "HND-q1").map(drop),
        2 => c
            .publish("message1", 42i32.to_le_bytes().to_vec(), -1)
            .map(drop),
        3 => c.query("query1", vec![0u8; 64], -1).map(drop),
        4 => c.unsubscribe("message1", "HND-m1"),
        5 => c.set_capacity(2),
        6 => c.num_handlers("message1").map(drop),
        7 => c.define_msg("message2", MsgLength::Variable, Some("string")),
        8 => c.define_format("T1", "{int, {enum : 3}, [double:2,3], double}"),
        _ => c.subscribe_handler_change("message1").map(drop),
    }
}
