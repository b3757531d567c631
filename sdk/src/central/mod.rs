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
//! One task owns the [`Central`] state machine; nothing else touches it,
//! and it reads every connection itself. Each connection has a waker that
//! puts it on a ready list; the central task polls the connection's socket
//! with that waker, and when the socket turns readable the reactor wakes
//! the central task through it. The central task then takes a 64 KiB
//! buffer from a pool shared by all connections, reads into it, feeds the
//! bytes to [`Central::receive`], writes what that produced and puts the
//! buffer back: a 4 B message costs one task wake-up, one `read` and one
//! `sendmsg`, with no hand-off between tasks. While [`Output::PauseRead`]
//! is in force the central task does not read the connection, so TCP
//! back-pressure reaches the module; this is how memory stays bounded when
//! a subscriber is slow. A connection is read at most four times in a row
//! and a batch makes at most 64 reads before its frames are written, so a
//! busy module does not starve the others. An idle connection holds no
//! buffer and no task: its cost is its socket's registration, its waker
//! and a few small tables (see BENCHMARKS.md).
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
//! a pair of bounded byte pipes read by the same central task and served by
//! the same writer tasks (see [`InProcessStream`]).
//!
//! # Deviations from the C central
//! This is the one list of where Courier's central (this module, the
//! `central` program of `courier-broker`, and the routing machine
//! `courier_wire::ipc::central` under both) differs from the C central of
//! CMU IPC 3.9.1. Everything not listed here — log and data-log lines,
//! console wording, frames, ids as modules see them — was compared with the
//! C central on the same C programs and matches it.
//!
//! **Start-up, command line and console** (the `central` program):
//! - The banner is `Task Control Server 3.9.1 (Courier <version>)` (C: its
//!   build date), and the console prints no `> ` prompt.
//! - Unknown options and bad values are errors (exit status 2, one line on
//!   stderr naming the flag and the value); C warns and goes on.
//! - `-v` prints the version and exits 0 wherever it appears (C: only as
//!   the first argument, exiting 1); `-p0` listens on a free port (printed
//!   in `Expecting 1 on port <port>`); `-d` (C's debugging flag) turns on
//!   debug diagnostics on stderr.
//! - Without `-f` the file log is `x_ipc.log.<seconds since 1970>` as in
//!   C, but its header time is UTC, as are log times (`-lt`); the comment
//!   prompt of file logging (`-L` without `n`) is shown only when standard
//!   input is a terminal, and only at start; `-s` also silences the
//!   `Logging File Name:` / `Logging to` lines.
//! - SIGINT, SIGTERM and SIGHUP stop central cleanly with exit status 0,
//!   the file log flushed (C aborts with status 1 on SIGINT and SIGTERM,
//!   and has no SIGHUP handler: a hangup, such as the terminal of an ssh
//!   session closing, kills it outright, without these lines, losing what
//!   `-LF` had not flushed). A SIGHUP ignored when central starts (`nohup
//!   central`) stays ignored, as in C. The lines are C's: the memory report
//!   on stderr (unless `-s`), then `Central Abort : Signal <n>` in the log
//!   when messages are logged, else on stderr; `quit` ends with `Central
//!   Quit`, as in C.
//! - A console line that is not UTF-8 is read with U+FFFD in place of
//!   the bytes that do not decode (so it is answered as an unknown
//!   command); C takes the bytes as they are.
//! - The console's `memory` (and that report) has C's heading,
//!   `Cumulative Memory Usage:`, then Courier's own counters: C counts its
//!   `malloc` calls and data-message buffers, which Courier does not have.
//! - `status` lists modules sorted by name (C: its hash table's order);
//!   `help` lists the options that work as console commands here (C also
//!   lists `-f -i -s -u`, which do nothing there) and words `-I` as taking
//!   a message name, which is what the console's `-I` takes here (C's
//!   help line says a file name); the `h` log option
//!   (handle summary) is accepted and prints nothing; `unlock` answers that
//!   IPC modules cannot lock.
//!
//! **Sockets and access control** (this module's server):
//! - `--bind` chooses the listening address; C always listens on all
//!   interfaces.
//! - A stale `/tmp/x_ipc/<port>` is removed only if nobody answers on it;
//!   if another server does, starting fails (C unlinks it unconditionally).
//! - Access control is always compiled in (C needs `ACCESS_CONTROL=1`);
//!   see [`access`] for the rule language and its own deviations. Peers on
//!   the UNIX socket are subject to the rules as local clients (C never
//!   checks them).
//! - A rules file named by the operator (`--hosts-allow`, `--hosts-deny`)
//!   must exist and be readable, else starting fails (exit status 2, one
//!   line naming the file and the OS error); a missing default
//!   `/etc/hosts.allow` or `/etc/hosts.deny` gives one warning line saying
//!   which rules are not in force. tcpd, which C links, silently takes a
//!   missing file as no rules.
//! - tcpd reads both rules files at every connection (and resolves their
//!   host names then); central reads a file again at the first connection
//!   after its size, times or inode changed, and resolves its host names
//!   when its text changed. A file that disappears, becomes unreadable or now
//!   holds a malformed rule for `central` leaves the rules last read from
//!   it in force, with one warning naming the file (a `tracing` event,
//!   which the `central` program prints on stderr); tcpd would take a
//!   missing file as no rules. A default file that did not exist
//!   at start is read once it appears.
//!
//! **Modules and routing** (the machine in `courier_wire::ipc::central`):
//! - A module connecting with the name of a live module is refused: one
//!   `ERROR: refused module …` line, its connection closed before the
//!   connect reply (its `IPC_connect` fails). C takes it in as the same
//!   resource (one capacity for both, deliveries to the second held until
//!   the first finishes) and, when either closes, closes both.
//! - A connection that closes is closed, whoever it is. C closes a module
//!   by its name, so a connection that leaves before naming itself closes
//!   the first module still called `**NEWMOD**` — possibly another module
//!   in the middle of connecting (a port probe can make C's central drop a
//!   real module that way).
//! - Message ids and dispatch ids are numbered like C's (message ids from
//!   199 down, never 0 or 1; dispatch ids reused last-freed first) but need
//!   not be the same numbers: modules only learn them from replies.
//! - `-r` resends a crashed module's unfinished messages automatically when
//!   a module of the same name subscribes the same handler again (C asks
//!   `Resend <msg> message?` on the terminal for each). What it keeps is
//!   bounded apart by [`Config::max_queued_bytes`]: past it, the oldest
//!   kept messages are dropped with a warning (C keeps them all, for
//!   module names that may never come back).
//! - Back-pressure: when more than [`Config::max_queued_bytes`] of message
//!   data wait in pending queues, central stops reading from the modules
//!   that add to them (never from one whose acknowledgements it awaits)
//!   until the queues drain to half; C grows without bound. Past the same
//!   bound, the oldest queries waiting for a first handler of their
//!   message are dropped (C keeps them all).
//! - Definitions (messages, also those only subscribed so far, and named
//!   formats) outlive their module as in C, but hold at most
//!   [`Config::max_definition_bytes`] (64 MiB) all together: past it a new
//!   one is refused with a `WARNING: … refused: definitions hold …` line,
//!   where C grows without end.
//! - Malformed frames close only the offending connection, with a log line
//!   naming the reason; C may abort or stall.
//! - A module repeating a mistake (foreign acknowledgements, unknown ids)
//!   gets ten warning lines at once, then one a second, and a count of
//!   the rest: it cannot flood the terminal or the log file. Connections
//!   that close before naming themselves (probes, peers sending garbage
//!   in a loop) are logged as C logs them for the first ten of every
//!   10 s; the rest are counted in one line when the 10 s are over (said
//!   then, not at the next connection).
//! - A connection that has not said its module name (`IPC_connect`)
//!   within [`Config::handshake_timeout`] (10 s; `central
//!   --handshake-timeout`) is closed with a `WARNING: closing connection
//!   … did not say its module name` line and C's close line. C keeps such
//!   connections for ever, so silent ones (a probe that never closes, a
//!   peer that is no IPC module) could hold every file descriptor and
//!   lock modules out. `--handshake-timeout 0` keeps C's way.
//! - A connection whose large frame (16 KiB or more, or one forwarded as it
//!   arrives) has had no byte for [`Config::frame_stall_timeout`] (30 s;
//!   `central --frame-stall-timeout`) is closed with a `WARNING: closing
//!   connection … stopped arriving` line: it held room other large frames
//!   wait for ([`Config::max_frames_in_progress`]), or, cut through, its
//!   receiver's other deliveries. Time central does not read it does not
//!   count. C waits for the rest for ever; `--frame-stall-timeout 0` keeps
//!   that.
//! - A failed `accept` (too many open files) is said when it starts,
//!   every 10 s while it lasts, and when it ends; a log file (`-f`) that
//!   cannot be written any more is said once on stderr and logging to it
//!   stops. C says nothing of either.
//! - `x_ipc_getMessages` (`IPC_printMessages`-style listings) answers the
//!   messages modules defined, sorted by name. C answers every entry of
//!   its message table not ignored for logging, in hash-table order: also
//!   central's own internal messages outside its ignore set, and messages
//!   only subscribed, never defined.
//! - `x_ipc_getMessageInfo` on a message subscribed but never defined
//!   answers it with no formats, its handler count and first handler's
//!   module; C's central dereferences the missing definition and dies
//!   (SIGSEGV). An unknown name is answered with the name only (C leaves
//!   the other fields uninitialised).
//! - `courier_getModules`, a query of Courier's own (what `courier list`
//!   asks), lists the connected modules; the C central has no such query.
//! - Cut-through ([`Config::cut_through`], off by default): a large message
//!   whose handler can take it at once is forwarded while it still
//!   arrives, instead of after its last byte (C's way). If the sender dies
//!   in the middle, the receiver's frame is completed with zero bytes (it
//!   already has the start), and a warning names both modules.
//! - Send-ahead ([`Config::send_ahead`], per module, off by default) writes
//!   queued broadcasts to a module before it finished the one it handles;
//!   C never does.
//!
//! **Logs**:
//! - With `-l` without `i`, the data of central's own log variables shows
//!   a null pointer as `*0` (C prints the pointer's address as an int).
//! - Lines about two events that reach central at the same moment from
//!   different modules (a `Reply` and a `Done`, say) may come in the other
//!   order; C's order there depends on its `select` loop too. When that
//!   order decides whether a module is still busy with a delivery, the
//!   same data is logged as `(Pending)` and later `Resource m --> m
//!   (Sent)` where C logged `(Sent)` at once, or the other way round: e.g.
//!   with `-l`, the broadcast of `X_IPC_BROADCAST_MSG_VAR` that follows a
//!   module's two registrations back to back, when the other modules'
//!   `Done` for the previous broadcast is taken in after them (central
//!   reads every frame a connection has before the next connection's).
//!
pub mod access;
mod console;
mod inproc;
mod ready;
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
