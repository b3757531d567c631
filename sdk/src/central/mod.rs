//! An embedded CMU IPC `central` (cargo feature `central`): the drop-in
//! replacement for CMU IPC's central server as a library, the same one the
//! `central` binary of `courier-broker` runs. A program that hosts it needs
//! no separate process: its own modules connect over an in-process link
//! ([`CentralHandle::session`]), C modules and other processes over TCP.
//! It listens on `127.0.0.1` unless told otherwise ([`Builder::bind`]).
//!
//! The protocol lives in [`courier_wire::ipc::central`] as a sans-I/O state
//! machine; this module is its tokio shell. It owns the sockets — TCP on the
//! port (default 1381) and the UNIX socket `/tmp/x_ipc/<port>` that C modules
//! prefer on the local host — plus [access control](access), back-pressure
//! and clean shutdown.
//!
//! ```
//! # #[tokio::main(flavor = "current_thread")]
//! # async fn main() -> Result<(), Box<dyn std::error::Error>> {
//! use std::time::Duration;
//! use courier::central::{CentralServer, LogSink};
//!
//! let central = CentralServer::builder()
//!     .bind("127.0.0.1".parse()?)
//!     .port(0) // any free port
//!     .log_sink(LogSink::discard())
//!     .spawn()
//!     .await?;
//! let addr = central.local_addr();
//! // Central speaks first: the 4-byte id of x_ipc_msgInfoMsg (ipc.md §4).
//! let mut module = tokio::net::TcpStream::connect(addr).await?;
//! let mut first = [0u8; 4];
//! tokio::time::timeout(
//!     Duration::from_secs(5),
//!     tokio::io::AsyncReadExt::read_exact(&mut module, &mut first),
//! )
//! .await??;
//! // … C modules connect with CENTRALHOST=127.0.0.1:<port> …
//! tokio::time::timeout(Duration::from_secs(5), central.shutdown()).await?;
//! # Ok(()) }
//! ```
//!
//! # How the shell is built
//! One task owns the [`Central`] state machine; nothing else touches it.
//! Per connection, a reader task waits until the socket is readable,
//! takes a 64 KiB buffer from a pool shared by all connections, reads into
//! it and hands it to the central task over a channel; the central task
//! feeds the bytes to [`Central::receive`], puts the buffer back in the
//! pool and gives the reader its go-ahead. While [`Output::PauseRead`] is
//! in force the central task holds the go-ahead back, so the reader stops
//! reading and TCP back-pressure reaches the module; this is how memory
//! stays bounded when a subscriber is slow. An idle connection holds no
//! buffer: its cost is the reader task and a few small tables (about
//! 3 KB per idle module, see BENCHMARKS.md).
//!
//! The frames central produces for one connection while handling a batch
//! of events are written together with one vectored write, directly from
//! the central task. What the socket does not take at once is queued, in
//! order, and a writer task is started for that connection; it waits for
//! room, writes the queue and ends when it is empty (until then later
//! frames join the queue), so idle connections have no writer task.
//!
//! A module of the hosting process can skip the sockets:
//! [`CentralHandle::session`] connects a `Session` over an in-process link,
//! a pair of bounded byte pipes served by the same reader and writer tasks
//! (see [`InProcessStream`]).
//!
//! # Deviations from the C central
//! - `--bind` chooses the listening address; C always listens on all
//!   interfaces.
//! - A stale `/tmp/x_ipc/<port>` is removed only if nobody answers on it;
//!   if another server does, starting fails (C unlinks it unconditionally).
//! - Access control is always compiled in (C needs `ACCESS_CONTROL=1`);
//!   see [`access`] for the rule language and its deviations.
//! - Peers on the UNIX socket are subject to the rules as local clients
//!   (C never checks them).
//! - A rules file named by the operator must exist and be readable
//!   ([`access::RulesFile`]); tcpd takes any missing file as no rules.
//! - The console's `memory` (and the report printed on standard error
//!   when a signal stops central) has C's heading, `Cumulative Memory
//!   Usage:`, then Courier's own counters: C counts its `malloc` calls and
//!   data-message buffers, which Courier does not have.
//! - `status` lists modules by name (C: its hash table's order); `help`
//!   lists the options that work as console commands here (C also lists
//!   `-f -i -s -u`, which do nothing there).
//! - The banner is `Task Control Server 3.9.1 (Courier <version>)` (C:
//!   its build date), and the console prints no `> ` prompt.
pub mod access;
mod console;
mod inproc;
mod server;

pub use console::memory_report;
pub use courier_wire::ipc::central::{
    Central, Config, ConnId, LogOptions, LogTarget, OptionError, Output, Peer, Stats,
};
pub use inproc::InProcessStream;
pub use server::{BindError, Builder, CentralHandle, CentralServer, LogSink};

/// The C central's port (`SERVER_PORT`).
pub const DEFAULT_PORT: u16 = 1381;

/// The directory of the C library's UNIX sockets (`UNIX_DIR_NAME`).
pub const UNIX_SOCKET_DIR: &str = "/tmp/x_ipc";

/// The UNIX socket path the C library uses for a port: `/tmp/x_ipc/<port>`.
pub fn unix_path(port: u16) -> std::path::PathBuf {
    std::path::Path::new(UNIX_SOCKET_DIR).join(port.to_string())
}

/// Keeps memory central freed for its next message instead of handing it
/// back to the kernel at once. With glibc's adaptive defaults, every large
/// message was received into, copied through and sent from memory that
/// the allocator had just returned, so each page of it faulted in anew:
/// ~1000 page faults per routed 1 MiB query, more than half its time
/// (C modules over the UNIX socket: 3.1 ms per round trip, 0.83 ms with
/// this; the C central 2.6 ms). Allocations up to 32 MiB come from the
/// heap, and up to 64 MiB of free heap is kept while traffic goes on;
/// after at least 1 MiB came in, once ten seconds in a row have each
/// brought less than 100 KiB, central gives the free memory back
/// (`malloc_trim`), so RSS returns close to where it was before the burst.
///
/// Process-wide (it sets glibc's `mallopt` parameters; elsewhere it does
/// nothing); call it first thing in `main`, before other threads start, as
/// the `central` binary does.
pub fn keep_freed_memory() {
    crate::sys::alloc::keep_freed_memory()
}
