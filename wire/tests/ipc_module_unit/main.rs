//! Behaviour of the sans-I/O IPC module beyond the C replay: publish
//! filtering by `X_IPC_BROADCAST_MSG_VAR`, deliveries and acks, queries and
//! out-of-order replies, split input, hostile input, direct links.
//!
//! `scripted`: the module runs as a `ModuleNode` on the shared simulated
//! network and the test plays central at the other end of its connection,
//! its frames cut into pieces and delayed at random, over several seeds.
//! `direct`: the direct-link API the shell calls (`accept_direct`,
//! `direct_link_up`, `poll_direct_transmit`, …), driven by hand, since
//! those calls and their order are what is tested (`ModuleNode` makes them
//! itself; `central_sim`'s end-to-end test runs them on the network).

mod direct;
mod script;
mod scripted;
