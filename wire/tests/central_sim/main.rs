//! The central state machine driven by real module state machines
//! (`ipc::module::Connection`) over the shared simulated network
//! (`courier_wire::sim`): streams cut and joined at random, no sockets, no
//! clocks, fully deterministic. Covers routing, capacity, priorities, queue
//! limits, notifications, direct mode, `-r`, back-pressure, cut-through,
//! send-ahead, logging and hostile input; `end_to_end` runs central and
//! several modules with latency over many seeds. Central's invariants are
//! checked after every input (`CentralNode::check_invariants`).

mod backpressure;
mod c_lines;
mod cut_through;
mod end_to_end;
mod hostile;
mod logging;
mod routing;
mod send_ahead;
mod support;
mod timeouts;
