//! The tokio shell around [`Central`]: listeners, the one task that owns
//! the state machine and reads every connection itself (woken through the
//! [`ReadyList`]), and a writer task per connection while central has
//! bytes queued for it that its socket would not take at once.

use std::collections::VecDeque;
use std::io::{self, IoSlice, Write};
use std::net::{IpAddr, Ipv4Addr, SocketAddr};
use std::os::fd::OwnedFd;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll, Waker};
use std::time::{Duration, SystemTime};

use foldhash::{HashMap, HashMapExt};
use tokio::io::unix::AsyncFd;
use tokio::io::Interest;
use tokio::net::{TcpListener, TcpStream, UnixListener, UnixStream};
use tokio::sync::{mpsc, oneshot, watch, Notify};
use tokio::task::{JoinHandle, JoinSet};

use crate::busy_poll::BusyPoll;
use courier_wire::ipc::central::{
    Body, Central, Config, ConnId, LogOptions, LogTarget, Output, Peer, Stats,
};

use super::access::{AccessControl, Client, Decision, HostName, RuleRef};
use super::inproc::{self, InProcessStream, ServerEnd, ServerReader, ServerWriter};
use super::ready::ReadyList;
use super::{unix_path, DEFAULT_PORT};

/// Bytes read from a connection at a time. The buffers come from a pool
/// shared by all connections ([`BufPool`]): a connection holds one only
/// from a read until central has taken the bytes in, so an idle module
/// costs no buffer at all.
const READ_BUF: usize = 64 * 1024;
/// Free read buffers the pool keeps for the next reads; more are freed.
const POOL_KEEP: usize = 8;
/// Batch vectors (of slices to write) kept for reuse, shared by all
/// connections; a vector longer than [`BATCH_KEEP`] (after a burst) is
/// freed instead.
const SPARE_BATCHES: usize = 8;
/// See [`SPARE_BATCHES`].
const BATCH_KEEP: usize = 16;
/// Events handled (or reads made) before the frames they produced are
/// written out.
const BATCH: usize = 64;
/// Reads of one connection in a row before the others' turn.
const READS_PER_TURN: usize = 4;
/// Slices per vectored write.
const IOV: usize = 64;
/// How long shutdown lets writers flush what central queued for them.
const SHUTDOWN_GRACE: Duration = Duration::from_secs(2);
/// How long a closed connection's writer may wait for a peer that does not
/// read before giving its last bytes up.
const CLOSE_LINGER: Duration = Duration::from_secs(10);
/// How long a reverse DNS lookup for access control may take.
const LOOKUP_TIMEOUT: Duration = Duration::from_secs(10);
/// Once [`TRIM_AFTER`] bytes were read since memory was last given back,
/// central checks every [`TRIM_TICK`] how much came in since the previous
/// check. After [`QUIET_TICKS`] checks in a row with less than
/// `TRIM_AFTER / QUIET_TICKS`, the burst is over: it frees its spare
/// buffers and gives free memory back. Ten seconds, so that bursts a few
/// seconds apart find their memory still mapped (giving it back costs a
/// page fault per page at the next burst).
const TRIM_TICK: Duration = Duration::from_secs(1);
/// See [`TRIM_TICK`].
const QUIET_TICKS: u32 = 10;
/// See [`TRIM_TICK`].
const TRIM_AFTER: u64 = 1 << 20;
/// The first connection id, like the C central's first module socket.
const FIRST_CONN: u64 = 5;

/// Where central's log lines go.
///
/// Each [`Output::Log`] line comes with a [`LogTarget`] saying whether it
/// belongs on the terminal (`-l`), in the log file (`-L`), or both. The sink
/// is called from the task that runs the state machine, one line at a time
/// (without a trailing newline), so it should be quick.
pub struct LogSink {
    f: Box<SinkFn>,
    /// Built by [`LogSink::discard`]: nothing will ever see a line.
    discards: bool,
}

type SinkFn = dyn FnMut(LogTarget, &str) + Send;

impl LogSink {
    /// A sink that calls `f` for every line.
    pub fn new(f: impl FnMut(LogTarget, &str) + Send + 'static) -> Self {
        LogSink {
            f: Box::new(f),
            discards: false,
        }
    }

    /// The default: every line as a `tracing` event with target
    /// `courier::central` (terminal lines at `INFO`, file-only lines
    /// at `DEBUG`).
    pub fn tracing() -> Self {
        LogSink::new(|target, line| {
            if target.terminal {
                tracing::info!(target: "courier::central", "{line}");
            } else {
                tracing::debug!(target: "courier::central", "{line}");
            }
        })
    }

    /// Drops every line. Central then does not produce them at all: its
    /// logs start switched off (as with `-lx`), so no line is formatted
    /// per message for nobody.
    pub fn discard() -> Self {
        LogSink {
            discards: true,
            ..LogSink::new(|_, _| {})
        }
    }

    /// Terminal lines to `terminal`, file lines to `file` (either may be
    /// absent), one line each with a newline. The terminal is flushed after
    /// every line; the file too when `flush_file` (the C central's default;
    /// `-LF` turns it off). Write errors are ignored, as the C central does.
    pub fn writers(
        mut terminal: Option<Box<dyn Write + Send>>,
        mut file: Option<Box<dyn Write + Send>>,
        flush_file: bool,
    ) -> Self {
        LogSink::new(move |target, line| {
            if target.terminal {
                if let Some(t) = terminal.as_mut() {
                    let _ = writeln!(t, "{line}");
                    let _ = t.flush();
                }
            }
            if target.file {
                if let Some(f) = file.as_mut() {
                    let _ = writeln!(f, "{line}");
                    if flush_file {
                        let _ = f.flush();
                    }
                }
            }
        })
    }

    fn line(&mut self, target: LogTarget, line: &str) {
        (self.f)(target, line)
    }
}

impl std::fmt::Debug for LogSink {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("LogSink(..)")
    }
}

/// Why central could not start.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum BindError {
    /// The TCP port could not be bound.
    #[error("cannot listen on {addr}: {source}")]
    Tcp {
        /// The address.
        addr: SocketAddr,
        /// Why.
        #[source]
        source: io::Error,
    },
    /// The UNIX socket could not be bound.
    #[error("cannot listen on {path}: {source}")]
    Unix {
        /// The socket path.
        path: PathBuf,
        /// Why.
        #[source]
        source: io::Error,
    },
    /// A builder option's value is wrong.
    #[error("bad {option}: {why}")]
    BadOption {
        /// The builder method.
        option: &'static str,
        /// What is wrong.
        why: String,
    },
}

/// Entry point of the embedding API: [`CentralServer::builder`].
#[derive(Debug)]
pub struct CentralServer;

impl CentralServer {
    /// A builder with the C central's port (1381) on 127.0.0.1 only (the
    /// C central and the `central` binary listen on every interface:
    /// [`Builder::bind`] `0.0.0.0` for that), [`Config::default`], no
    /// access rules, log lines to `tracing`, and **no** UNIX socket (turn
    /// it on with [`Builder::unix_socket`]; the `central` binary does).
    pub fn builder() -> Builder {
        Builder {
            port: DEFAULT_PORT,
            bind: IpAddr::V4(Ipv4Addr::LOCALHOST),
            unix_socket: false,
            config: Config::default(),
            access: AccessControl::open(),
            sink: LogSink::tracing(),
            busy_poll: None,
        }
    }
}

/// Settings of an embedded central; [`Builder::spawn`] starts it.
#[derive(Debug)]
pub struct Builder {
    port: u16,
    bind: IpAddr,
    unix_socket: bool,
    config: Config,
    access: AccessControl,
    sink: LogSink,
    busy_poll: Option<Duration>,
}

impl Builder {
    /// TCP port; 0 picks a free one (see [`CentralHandle::local_addr`]).
    pub fn port(mut self, port: u16) -> Self {
        self.port = port;
        self
    }

    /// Address to listen on. The default is `127.0.0.1`: an embedded
    /// central is reachable from this machine only unless told otherwise
    /// (`0.0.0.0` for all interfaces, what the `central` binary does by
    /// default, like C's).
    pub fn bind(mut self, addr: IpAddr) -> Self {
        self.bind = addr;
        self
    }

    /// Also listen on the UNIX socket `/tmp/x_ipc/<port>` (with the bound
    /// port), as the C central does: C modules use it when `CENTRALHOST`
    /// names the local host. `/tmp/x_ipc` is created with mode 0777 if
    /// missing; a stale socket file nobody answers on is replaced; the file
    /// is removed at shutdown. Off by default.
    pub fn unix_socket(mut self, on: bool) -> Self {
        self.unix_socket = on;
        self
    }

    /// Protocol and logging options (`-c`, `-r`, `-l`, `-L`, `-I`, limits).
    pub fn config(mut self, config: Config) -> Self {
        self.config = config;
        self
    }

    /// Allow/deny rules, checked before any byte is sent to a new
    /// connection. A refused connection is closed at once and logged as
    /// `WARNING: connection rejected from <peer> (denied by <file>:<line>)`,
    /// once: to the logs that are on (terminal and/or file, like the C
    /// central's own warnings), or as a `tracing` warning when no log is on
    /// (`-lx` without `-L`, `-s`, [`LogSink::discard`]).
    pub fn access(mut self, access: AccessControl) -> Self {
        self.access = access;
        self
    }

    /// Where log lines go (default [`LogSink::tracing`]).
    pub fn log_sink(mut self, sink: LogSink) -> Self {
        self.sink = sink;
        self
    }

    /// Lower latency for CPU: after handling a frame keep polling the
    /// connections for `window` instead of sleeping until the next one
    /// ([`crate::busy_poll`]). Off by default (the C central has no such
    /// mode); effective on a current-thread runtime, which is what the
    /// `central` binary runs (`--busy-poll <µs>`). At most
    /// [`busy_poll::MAX_WINDOW`](crate::busy_poll::MAX_WINDOW) (1 s):
    /// [`spawn`](Self::spawn) refuses a longer one.
    pub fn busy_poll(mut self, window: Duration) -> Self {
        self.busy_poll = Some(window);
        self
    }

    /// Binds the listeners and starts serving on the current tokio runtime.
    pub async fn spawn(self) -> Result<CentralHandle, BindError> {
        if let Some(why) = self
            .busy_poll
            .and_then(|w| crate::busy_poll::check_window(w).err())
        {
            return Err(BindError::BadOption {
                option: "Builder::busy_poll",
                why,
            });
        }
        let addr = SocketAddr::new(self.bind, self.port);
        let tcp = bind_tcp(addr).map_err(|source| BindError::Tcp { addr, source })?;
        let local = tcp
            .local_addr()
            .map_err(|source| BindError::Tcp { addr, source })?;
        let unix = if self.unix_socket {
            let path = unix_path(local.port());
            match bind_unix(&path) {
                Ok(l) => Some((l, path)),
                Err(source) => return Err(BindError::Unix { path, source }),
            }
        } else {
            None
        };
        let unix_path = unix.as_ref().map(|(_, p)| p.clone());

        let (stop_tx, stop_rx) = watch::channel(false);
        let (events_tx, events_rx) = mpsc::unbounded_channel();
        let access = Arc::new(self.access);
        let mut sink = self.sink;
        let mut config = self.config;
        if sink.discards {
            config.terminal_log = LogOptions::default();
            config.file_log = LogOptions::default();
        }
        let target = log_target(&config);
        for w in access.warnings() {
            shell_line(&mut sink, target, &format!("WARNING: {w}"));
        }
        let mut tasks = Vec::new();
        tasks.push(tokio::spawn(Box::pin(accept_loop(
            Listener::Tcp(tcp),
            access.clone(),
            events_tx.clone(),
            stop_rx.clone(),
        ))));
        if let Some((l, _)) = unix {
            tasks.push(tokio::spawn(Box::pin(accept_loop(
                Listener::Unix(l),
                access,
                events_tx.clone(),
                stop_rx.clone(),
            ))));
        }
        // C logs registering its own variables before anything else.
        let mut central = Central::new_at(config, SystemTime::now());
        while let Some(o) = central.poll_output() {
            if let Output::Log { target, line } = o {
                sink.line(target, &line);
            }
        }
        let core = Core {
            central,
            conns: HashMap::new(),
            next_id: FIRST_CONN,
            sink,
            events_tx: events_tx.clone(),
            tasks: JoinSet::new(),
            pool: BufPool::default(),
            ready: Arc::default(),
            to_read: Vec::new(),
            spare_batches: Vec::new(),
            read_total: 0,
            read_at_trim: 0,
            dirty: Vec::new(),
            spin: self.busy_poll.map(BusyPoll::start),
        };
        // Boxed first: the state machine's task is a few kilobytes, which
        // spawning would otherwise copy through several stack frames (the
        // deepest the main thread's stack ever gets).
        let central_task = tokio::spawn(Box::pin(core.run(events_rx, stop_rx)));
        Ok(CentralHandle {
            local,
            unix_path,
            stop: stop_tx,
            events: events_tx,
            central_task: Some(central_task),
            accept_tasks: tasks,
        })
    }
}

/// Where the shell's own lines go, like the C central's `LOG`: on the
/// terminal if terminal logging is on at all, in the file if file logging is.
fn log_target(c: &Config) -> LogTarget {
    LogTarget {
        // `-s`: the shell prints nothing on the terminal.
        terminal: c.terminal_log.any() && !c.quiet,
        file: c.file_log.any(),
    }
}

/// Logs a line of the shell's own (refusals, read errors, rule warnings)
/// exactly once: to the logs that are on (terminal and/or file, as the C
/// central's own warnings go), or, when none is, as a `tracing` warning, so
/// that it is never lost and never printed twice.
fn shell_line(sink: &mut LogSink, target: LogTarget, line: &str) {
    if target.terminal || target.file {
        sink.line(target, line);
    } else {
        tracing::warn!("{line}");
    }
}

fn bind_tcp(addr: SocketAddr) -> io::Result<TcpListener> {
    let sock = if addr.is_ipv4() {
        tokio::net::TcpSocket::new_v4()?
    } else {
        tokio::net::TcpSocket::new_v6()?
    };
    // As C: a restarted central can take the port while old connections
    // linger in TIME_WAIT.
    sock.set_reuseaddr(true)?;
    sock.bind(addr)?;
    sock.listen(1024)
}

fn bind_unix(path: &Path) -> io::Result<UnixListener> {
    use std::os::unix::fs::PermissionsExt;
    if let Some(dir) = path.parent() {
        match std::fs::create_dir(dir) {
            Ok(()) => {
                // Every user's modules and centrals share the directory.
                std::fs::set_permissions(dir, std::fs::Permissions::from_mode(0o777))?;
            }
            Err(e) if e.kind() == io::ErrorKind::AlreadyExists => {}
            Err(e) => return Err(e),
        }
    }
    // A socket file left by a dead central: remove it if nobody answers.
    if std::fs::symlink_metadata(path).is_ok() {
        if std::os::unix::net::UnixStream::connect(path).is_ok() {
            return Err(io::Error::new(
                io::ErrorKind::AddrInUse,
                "another server is listening there (run without it: central's \
                 --no-unix-socket, or `courier::central::Builder::unix_socket(false)` embedded)",
            ));
        }
        std::fs::remove_file(path)?;
    }
    let l = UnixListener::bind(path)?;
    // Like C (fchmod 0777): other users' modules may connect, and a later
    // central run by someone else may remove a stale file.
    let _ = std::fs::set_permissions(path, std::fs::Permissions::from_mode(0o777));
    Ok(l)
}

/// A running central.
///
/// [`CentralHandle::shutdown`] stops it and waits until everything has
/// ended; dropping the handle stops it too, without waiting (the UNIX socket
/// file is removed at once, the tasks end on their own).
#[derive(Debug)]
pub struct CentralHandle {
    local: SocketAddr,
    unix_path: Option<PathBuf>,
    stop: watch::Sender<bool>,
    events: mpsc::UnboundedSender<Event>,
    central_task: Option<JoinHandle<()>>,
    accept_tasks: Vec<JoinHandle<()>>,
}

impl CentralHandle {
    /// The bound TCP address (with the real port when 0 was asked for).
    pub fn local_addr(&self) -> SocketAddr {
        self.local
    }

    /// The UNIX socket path, if one is served.
    pub fn unix_path(&self) -> Option<&Path> {
        self.unix_path.as_deref()
    }

    /// A console command, as typed on central's standard input (`status`,
    /// `display`, `-lmsd`, `close <module>`, …); its output goes to the log
    /// sink. Returns `false` if central has stopped.
    pub fn command(&self, line: &str) -> bool {
        self.events.send(Event::Command(line.to_string())).is_ok()
    }

    /// A link to this central for a module in this process: a byte stream
    /// like a connected socket, without the loopback (no system call per
    /// frame, and no thread wake-up when both ends run on one thread). The
    /// module on it is an ordinary module to central and to everybody
    /// else. Access control does not apply (the caller already runs in
    /// this process). [`session`](Self::session) builds a `Session` on it.
    ///
    /// Fails with `NotConnected` if central has stopped.
    pub fn connect_in_process(&self) -> io::Result<InProcessStream> {
        link_in_process(&self.events)
    }

    /// A [`Session`](crate::Session) builder for a module of this process,
    /// connected to this central over [`connect_in_process`](Self::connect_in_process)
    /// links. The session lives no longer than this central: once it has
    /// stopped, connecting fails at once with "central has stopped", and a
    /// session built with `reconnect` ends instead of retrying. Everything
    /// else is as for
    /// `Session::builder(url)` with this central's address: direct mode,
    /// options, and how other modules see it.
    ///
    /// ```
    /// # #[tokio::main(flavor = "current_thread")]
    /// # async fn main() -> Result<(), Box<dyn std::error::Error>> {
    /// use courier::central::{CentralServer, LogSink};
    ///
    /// let central = CentralServer::builder()
    ///     .bind("127.0.0.1".parse()?)
    ///     .port(0)
    ///     .log_sink(LogSink::discard())
    ///     .spawn()
    ///     .await?;
    /// let planner = central.session("planner").connect().await?;
    /// assert!(planner.is_module_connected("planner").await?);
    /// planner.close().await;
    /// central.shutdown().await;
    /// # Ok(()) }
    /// ```
    pub fn session(&self, name: impl Into<String>) -> crate::SessionBuilder {
        let host = if self.local.ip().is_unspecified() {
            crate::ipc_backend::local_host_name()
        } else {
            self.local.ip().to_string()
        };
        let events = self.events.clone();
        crate::Session::builder(format!("ipc://{host}:{}", self.local.port()))
            .name(name)
            .dial(move || {
                let link = link_in_process(&events);
                async move { Ok(Box::new(link?) as Box<dyn crate::IpcStream>) }
            })
    }

    /// Counters of the state machine (modules, queued bytes and their
    /// peak, …), or `None` if central has stopped.
    pub async fn stats(&self) -> Option<Stats> {
        let (tx, rx) = oneshot::channel();
        self.events.send(Event::Stats(tx)).ok()?;
        rx.await.ok()
    }

    /// Stops accepting, closes every connection (after writing what central
    /// had queued for it, for at most two seconds), waits until every task
    /// has ended and removes the UNIX socket file.
    pub async fn shutdown(mut self) {
        let _ = self.stop.send(true);
        for t in self.accept_tasks.drain(..) {
            let _ = t.await;
        }
        if let Some(t) = self.central_task.take() {
            if let Err(e) = t.await {
                if e.is_panic() {
                    tracing::error!("central task panicked");
                }
            }
        }
        if let Some(p) = self.unix_path.take() {
            let _ = std::fs::remove_file(p);
        }
    }
}

/// Hands central its end of a new in-process link.
fn link_in_process(events: &mpsc::UnboundedSender<Event>) -> io::Result<InProcessStream> {
    let (module, central) = inproc::link(inproc::PIPE_CAPACITY);
    events
        .send(Event::Accepted(
            Stream::InProcess(central),
            Peer::Other("in-process".into()),
        ))
        .map_err(|_| io::Error::new(io::ErrorKind::NotConnected, "central has stopped"))?;
    Ok(module)
}

impl Drop for CentralHandle {
    fn drop(&mut self) {
        let _ = self.stop.send(true);
        if let Some(p) = self.unix_path.take() {
            let _ = std::fs::remove_file(p);
        }
    }
}

/// What the central task is told.
#[derive(Debug)]
enum Event {
    /// A connection passed access control.
    Accepted(Stream, Peer),
    /// A connection was refused (already closed).
    Refused { peer: String, rule: RuleRef },
    /// Writing failed: the connection is gone.
    WriteFailed { conn: ConnId, error: io::Error },
    /// A console line.
    Command(String),
    /// A request for counters.
    Stats(oneshot::Sender<Stats>),
}

#[derive(Debug)]
enum Stream {
    Tcp(TcpStream),
    Unix(UnixStream),
    InProcess(ServerEnd),
}

enum Listener {
    Tcp(TcpListener),
    Unix(UnixListener),
}

/// How long the accept loop waits after a failed `accept` (out of file
/// descriptors and the like) before it tries again.
const ACCEPT_RETRY: Duration = Duration::from_millis(50);

/// How often the accept loop says that `accept` still fails.
const ACCEPT_REPORT_EVERY: Duration = Duration::from_secs(10);

/// What the accept loop says about `accept` failing: once when it starts,
/// once every [`ACCEPT_REPORT_EVERY`] with a count while it lasts, and
/// once when a connection is accepted again (a central at its descriptor
/// limit otherwise logged a line every [`ACCEPT_RETRY`]). A central
/// hovering at the limit (a descriptor freed, taken by the next
/// connection, `accept` failing again) would start and end a bout of
/// failures many times a second: a bout that starts less than
/// [`ACCEPT_REPORT_EVERY`] after the last line is counted silently, and
/// its end is said only if its start or count was.
#[derive(Debug, Default)]
struct AcceptTrouble {
    failing: Option<AcceptBout>,
    /// When the last line was said.
    last_line: Option<std::time::Instant>,
}

#[derive(Debug)]
struct AcceptBout {
    since: std::time::Instant,
    /// Failures since the last line, and in all.
    unsaid: u64,
    total: u64,
    /// Whether a line said this bout.
    said: bool,
}

impl AcceptTrouble {
    fn quiet_at(&self, now: std::time::Instant) -> bool {
        self.last_line
            .is_some_and(|t| now.duration_since(t) < ACCEPT_REPORT_EVERY)
    }

    /// `accept` failed with `e` at `now`: the line to log, if any.
    fn failed(&mut self, e: &io::Error, now: std::time::Instant) -> Option<String> {
        let quiet = self.quiet_at(now);
        let bout = self.failing.get_or_insert(AcceptBout {
            since: now,
            unsaid: 0,
            total: 0,
            said: false,
        });
        bout.total += 1;
        bout.unsaid += 1;
        if quiet {
            return None;
        }
        let line = if bout.said || bout.total > 1 {
            format!(
                "accept still failing: {e}; {} more failure(s) in the last {} s ({} s in all)",
                bout.unsaid,
                self.last_line
                    .map_or(0, |t| now.duration_since(t).as_secs()),
                now.duration_since(bout.since).as_secs()
            )
        } else {
            format!(
                "accept failed: {e}; retrying every {} ms (said again every {} s while it lasts)",
                ACCEPT_RETRY.as_millis(),
                ACCEPT_REPORT_EVERY.as_secs()
            )
        };
        bout.unsaid = 0;
        bout.said = true;
        self.last_line = Some(now);
        Some(line)
    }

    /// A connection was accepted at `now`: the line to log, if `accept`
    /// was failing and that was said.
    fn succeeded(&mut self, now: std::time::Instant) -> Option<String> {
        let bout = self.failing.take()?;
        if !bout.said {
            return None;
        }
        self.last_line = Some(now);
        Some(format!(
            "accepting connections again, after {} failed accept(s) over {} s",
            bout.total,
            now.duration_since(bout.since).as_secs()
        ))
    }
}

async fn accept_loop(
    l: Listener,
    access: Arc<AccessControl>,
    events: mpsc::UnboundedSender<Event>,
    mut stop: watch::Receiver<bool>,
) {
    // Access checks that need a host name run here, off the accept path.
    let mut lookups = JoinSet::new();
    let mut trouble = AcceptTrouble::default();
    loop {
        let accepted = tokio::select! {
            biased;
            _ = stop.changed() => return,
            Some(_) = lookups.join_next(), if !lookups.is_empty() => continue,
            r = accept(&l) => r,
        };
        let (stream, client, peer) = match accepted {
            Ok(a) => {
                if let Some(line) = trouble.succeeded(std::time::Instant::now()) {
                    tracing::warn!("{line}");
                }
                a
            }
            Err(e) => {
                // Out of descriptors and the like: do not spin, and do
                // not say it every time.
                if let Some(line) = trouble.failed(&e, std::time::Instant::now()) {
                    tracing::warn!("{line}");
                }
                tokio::time::sleep(ACCEPT_RETRY).await;
                continue;
            }
        };
        if access.needs_host_name() {
            let access = access.clone();
            let events = events.clone();
            lookups.spawn(async move {
                let a = access.clone();
                let decision = match tokio::time::timeout(
                    LOOKUP_TIMEOUT,
                    tokio::task::spawn_blocking(move || a.check(client)),
                )
                .await
                {
                    Ok(Ok(d)) => d,
                    // Too slow or failed: decide without a host name.
                    _ => access.check_with(client, &mut |_| HostName::Unknown),
                };
                admit(decision, stream, peer, &events);
            });
        } else {
            admit(access.check(client), stream, peer, &events);
        }
    }
}

async fn accept(l: &Listener) -> io::Result<(Stream, Client, Peer)> {
    match l {
        Listener::Tcp(l) => {
            let (s, addr) = l.accept().await?;
            let ip = match addr.ip() {
                IpAddr::V6(v6) => v6.to_ipv4_mapped().map_or(addr.ip(), IpAddr::V4),
                v4 => v4,
            };
            Ok((
                Stream::Tcp(s),
                Client::Ip(ip),
                Peer::Tcp(SocketAddr::new(ip, addr.port()).to_string()),
            ))
        }
        Listener::Unix(l) => {
            let (s, _) = l.accept().await?;
            Ok((Stream::Unix(s), Client::Unix, Peer::Unix))
        }
    }
}

fn admit(decision: Decision, stream: Stream, peer: Peer, events: &mpsc::UnboundedSender<Event>) {
    match decision {
        Decision::Denied(rule) => {
            // Closed before any protocol byte: the peer reads EOF.
            drop(stream);
            let peer = match peer {
                Peer::Tcp(a) => a,
                Peer::Unix => "the UNIX socket".into(),
                Peer::Other(s) => s,
            };
            let _ = events.send(Event::Refused { peer, rule });
        }
        Decision::Allowed(_) => {
            if let Stream::Tcp(s) = &stream {
                let _ = s.set_nodelay(true);
            }
            let _ = events.send(Event::Accepted(stream, peer));
        }
    }
}

/// A module's socket (TCP or UNIX), shared by its reader and writer.
///
/// Registered for read readiness only. tokio's stream types register read
/// and write readiness together, and then every time a module reads what
/// central wrote (freeing send-buffer space) the kernel wakes central for
/// nothing: a wake-up per delivery, on whichever CPU central last ran,
/// between every module and central. Write readiness is asked for only
/// while a write waits for room ([`WriteHalf::writable`]).
struct Sock {
    fd: AsyncFd<OwnedFd>,
    /// TCP (for [`quickack`]).
    tcp: bool,
}

impl Sock {
    fn new(fd: OwnedFd, tcp: bool) -> io::Result<Arc<Sock>> {
        Ok(Arc::new(Sock {
            fd: register(fd, Interest::READABLE)?,
            tcp,
        }))
    }

    /// The socket, for socket2's (safe) system calls.
    fn sock(&self) -> socket2::SockRef<'_> {
        socket2::SockRef::from(self.fd.get_ref())
    }

    /// Reads into a buffer of the pool (held only once there is something
    /// to read) if the socket is readable; otherwise `cx` is woken when it
    /// becomes so.
    fn poll_read(&self, cx: &mut Context<'_>, pool: &BufPool) -> Poll<io::Result<Vec<u8>>> {
        loop {
            let mut ready = match self.fd.poll_read_ready(cx) {
                Poll::Ready(r) => r?,
                Poll::Pending => return Poll::Pending,
            };
            let mut buf = pool.take();
            let n = match crate::sys::net::read_spare(self.fd.get_ref(), &mut buf) {
                Ok(n) => n,
                Err(e) => {
                    pool.put(buf);
                    match e.kind() {
                        io::ErrorKind::WouldBlock => {
                            ready.clear_ready();
                            continue;
                        }
                        io::ErrorKind::Interrupted => continue,
                        _ => return Poll::Ready(Err(e)),
                    }
                }
            };
            if n > 0 && n < buf.capacity() {
                // A short read emptied the socket: wait for the next event
                // instead of asking again and hearing EAGAIN (as tokio's
                // own streams do). Data that came since raises a new one.
                ready.clear_ready();
            }
            if self.tcp && n >= QUICKACK_MIN {
                quickack(&self.sock());
            }
            return Poll::Ready(Ok(buf));
        }
    }

    /// One non-blocking vectored write (`MSG_NOSIGNAL`: a peer that went
    /// away is an error, not a signal).
    fn try_write_vectored(&self, bufs: &[IoSlice<'_>]) -> io::Result<usize> {
        self.sock()
            .send_vectored_with_flags(bufs, libc::MSG_NOSIGNAL | libc::MSG_DONTWAIT)
    }

    /// Waits until the socket has room, through a registration for write
    /// readiness that lives only as long as the wait ([`register_for_room`]).
    async fn writable(&self) -> io::Result<()> {
        let _ready = register_for_room(self.fd.get_ref())?.writable().await?;
        Ok(())
    }
}

use crate::sys::net::{register, register_for_room};

/// Any kind of stream's write half.
enum WriteHalf {
    Sock(Arc<Sock>),
    InProcess(ServerWriter),
}

impl WriteHalf {
    fn try_write_vectored(&self, bufs: &[IoSlice<'_>]) -> io::Result<usize> {
        match self {
            WriteHalf::Sock(s) => s.try_write_vectored(bufs),
            WriteHalf::InProcess(w) => w.try_write_vectored(bufs),
        }
    }

    async fn writable(&self) -> io::Result<()> {
        match self {
            WriteHalf::Sock(s) => s.writable().await,
            WriteHalf::InProcess(w) => w.writable().await,
        }
    }
}

enum ReadHalf {
    Sock(Arc<Sock>),
    InProcess(ServerReader),
}

impl ReadHalf {
    /// The next bytes, in a buffer of `pool` (empty: end of stream), if
    /// there are any; otherwise `cx` is woken when there are.
    fn poll_read(&mut self, cx: &mut Context<'_>, pool: &BufPool) -> Poll<io::Result<Vec<u8>>> {
        match self {
            ReadHalf::Sock(s) => s.poll_read(cx, pool),
            ReadHalf::InProcess(r) => loop {
                if r.poll_readable(cx).is_pending() {
                    return Poll::Pending;
                }
                let mut buf = pool.take();
                match r.try_read_spare(&mut buf) {
                    Ok(_) => return Poll::Ready(Ok(buf)),
                    Err(e) => {
                        pool.put(buf);
                        if e.kind() != io::ErrorKind::WouldBlock {
                            return Poll::Ready(Err(e));
                        }
                    }
                }
            },
        }
    }
}

/// Reads at least this long turn on [`quickack`]; shorter ones leave the ACK
/// to ride on the answer. A small frame fits a C module's send buffer many
/// times over, so its sender never waits for that ACK, while the syscall and
/// the bare ACK segment cost ~8 µs of a 4 B query round trip (measured: C
/// clients through central, 114 → 106 µs over TCP).
const QUICKACK_MIN: usize = 2048;

/// Acknowledge at once instead of delaying the ACK. A C module's 16 KiB send
/// buffer holds less than one loopback segment, so with delayed ACKs every
/// buffer-full of a large message waits 40 ms for the ACK (measured: the C
/// `throughput1` sent 8 messages/s of 256 KiB through central instead of
/// ~2 500). Linux clears the flag again by itself, so it is set after every
/// read of [`QUICKACK_MIN`] bytes or more (one cheap syscall).
fn quickack(s: &socket2::SockRef<'_>) {
    // best effort: failing costs only the delay this avoids
    let _ = s.set_tcp_quickack(true);
}

/// What the central task shares with a connection's writer task, while
/// one runs.
struct Shared {
    half: WriteHalf,
    /// Batches the central task could not write at once, in order.
    queue: Mutex<WriteQueue>,
    /// Signalled when central closes the connection, so that a writer
    /// stuck on a peer that does not read gives up after [`CLOSE_LINGER`].
    closing: Notify,
}

/// Writes waiting for room in the socket. A writer task exists only while
/// there are some (`writer`); an idle connection has none. Whoever sees
/// `writer` false under the lock may write directly: everything queued
/// before is on the wire.
#[derive(Default)]
struct WriteQueue {
    chunks: VecDeque<Chunks>,
    writer: bool,
}

impl Shared {
    fn queue(&self) -> std::sync::MutexGuard<'_, WriteQueue> {
        // Nothing panics while holding it; the queue stays consistent.
        self.queue.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Central closed the connection: a writer finishes what is queued
    /// (or gives up after [`CLOSE_LINGER`]) and ends.
    fn close(&self) {
        self.closing.notify_one();
    }
}

/// Read buffers for all connections: taken for a read, put back once
/// central has taken the bytes in.
#[derive(Default)]
struct BufPool {
    free: Mutex<Vec<Vec<u8>>>,
}

impl BufPool {
    /// An empty buffer with room for [`READ_BUF`] bytes. A new one is not
    /// zeroed (reads go to its spare capacity), so only the pages bytes
    /// land on are ever touched.
    fn take(&self) -> Vec<u8> {
        let got = self.free.lock().unwrap_or_else(|e| e.into_inner()).pop();
        got.unwrap_or_else(|| Vec::with_capacity(READ_BUF))
    }

    fn put(&self, mut buf: Vec<u8>) {
        buf.clear();
        let mut free = self.free.lock().unwrap_or_else(|e| e.into_inner());
        if free.len() < POOL_KEEP {
            free.push(buf);
        }
    }
}

/// Bytes to write: a frame, or a frame's header, or a large message's
/// data shared with central's queues.
enum Buf {
    Own(Vec<u8>),
    Shared(Body),
}

impl std::ops::Deref for Buf {
    type Target = [u8];

    fn deref(&self) -> &[u8] {
        match self {
            Buf::Own(v) => v,
            Buf::Shared(b) => b,
        }
    }
}

/// Frames to write: `bufs[idx][off..]` then the rest of `bufs`.
struct Chunks {
    bufs: Vec<Buf>,
    idx: usize,
    off: usize,
}

impl Chunks {
    fn done(&self) -> bool {
        self.idx >= self.bufs.len()
    }

    /// Writes as much as the socket takes now; `Ok(true)` when all is written.
    fn try_write(&mut self, w: &WriteHalf) -> io::Result<bool> {
        while !self.done() {
            let mut iov = [IoSlice::new(&[]); IOV];
            let mut n = 0;
            for (i, b) in self.bufs[self.idx..].iter().take(IOV).enumerate() {
                let s = if i == 0 { &b[self.off..] } else { &b[..] };
                iov[n] = IoSlice::new(s);
                n += 1;
            }
            match w.try_write_vectored(&iov[..n]) {
                Ok(0) => return Err(io::ErrorKind::WriteZero.into()),
                Ok(k) => self.advance(k),
                Err(e) if e.kind() == io::ErrorKind::WouldBlock => return Ok(false),
                Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                Err(e) => return Err(e),
            }
        }
        Ok(true)
    }

    fn advance(&mut self, mut k: usize) {
        while k > 0 && !self.done() {
            let rest = self.bufs[self.idx].len() - self.off;
            if k >= rest {
                k -= rest;
                self.idx += 1;
                self.off = 0;
            } else {
                self.off += k;
                k = 0;
            }
        }
        // Skip empty frames so `done` is exact.
        while !self.done() && self.bufs[self.idx].len() == self.off {
            self.idx += 1;
            self.off = 0;
        }
    }
}

/// Writes the queued batches of a connection, then ends; started by the
/// central task when a write could not be completed at once
/// ([`Core::flush`]).
async fn writer_task(conn: ConnId, shared: Arc<Shared>, events: mpsc::UnboundedSender<Event>) {
    let mut deadline: Option<tokio::time::Instant> = None;
    loop {
        let next = {
            let mut q = shared.queue();
            let next = q.chunks.pop_front();
            if next.is_none() {
                // Under the lock: from now on central writes directly.
                q.writer = false;
                q.chunks = VecDeque::new();
            }
            next
        };
        let Some(mut chunks) = next else { return };
        loop {
            match chunks.try_write(&shared.half) {
                Ok(true) => break,
                Ok(false) => {}
                Err(error) => {
                    // `writer` stays set: nothing more is written.
                    let _ = events.send(Event::WriteFailed { conn, error });
                    return;
                }
            }
            let ready = match deadline {
                None => tokio::select! {
                    r = shared.half.writable() => r,
                    _ = shared.closing.notified() => {
                        deadline = Some(tokio::time::Instant::now() + CLOSE_LINGER);
                        Ok(())
                    }
                },
                Some(d) => match tokio::time::timeout_at(d, shared.half.writable()).await {
                    Ok(r) => r,
                    Err(_) => {
                        tracing::debug!(
                            conn = conn.0,
                            "closed connection not reading; dropped its last bytes"
                        );
                        return;
                    }
                },
            };
            if let Err(error) = ready {
                let _ = events.send(Event::WriteFailed { conn, error });
                return;
            }
        }
    }
    // Dropping the last write half sends FIN once the reader is gone too.
}

/// The central task's view of one connection.
struct ConnState {
    shared: Arc<Shared>,
    /// Read by the central task itself, when `waker` says it may be
    /// readable ([`ReadyList`]).
    read: ReadHalf,
    /// Puts this connection on the ready list.
    waker: Waker,
    /// Frames produced in the current batch, not yet written.
    batch: Vec<Buf>,
    /// Central asked not to read from this connection.
    paused: bool,
}

struct Core {
    central: Central,
    conns: HashMap<ConnId, ConnState>,
    next_id: u64,
    sink: LogSink,
    events_tx: mpsc::UnboundedSender<Event>,
    tasks: JoinSet<()>,
    /// Read buffers, held only from a read until central took the bytes in.
    pool: BufPool,
    /// Connections that may have bytes to read.
    ready: Arc<ReadyList>,
    /// Connections to read next (taken from `ready`).
    to_read: Vec<ConnId>,
    /// Empty batch vectors for the next connections that write, so that
    /// an idle connection holds none.
    spare_batches: Vec<Vec<Buf>>,
    /// Bytes read in all (wrapping) and when memory was last given back
    /// ([`TRIM_TICK`]).
    read_total: u64,
    read_at_trim: u64,
    /// Connections with frames in their batch.
    dirty: Vec<ConnId>,
    /// Busy polling after activity, when configured.
    spin: Option<BusyPoll>,
}

/// The monotonic time of `at` on the wall clock (now if it has passed).
fn instant_of(at: SystemTime) -> std::time::Instant {
    let left = at.duration_since(SystemTime::now()).unwrap_or_default();
    std::time::Instant::now() + left
}

impl Core {
    async fn run(
        mut self,
        mut events: mpsc::UnboundedReceiver<Event>,
        mut stop: watch::Receiver<bool>,
    ) {
        // Ticks once a second from when TRIM_AFTER bytes were read until
        // memory is given back; `mark` is `read_total` at the last tick,
        // `quiet` the ticks in a row that found little read since.
        // A `timerfd` where there is one: while it is armed (during traffic)
        // the runtime still waits in `epoll_wait` with no timeout, so no
        // kernel timer is armed and cancelled around every wait.
        let mut trim = crate::driver_timer::DriverTimer::quiet();
        let mut trim_armed = false;
        let mut mark = 0u64;
        let mut quiet = 0u32;
        // Central's own deadlines (connections that must name themselves,
        // the strangers' log window): `due` is what the timer is set to.
        let mut timer = crate::driver_timer::DriverTimer::quiet();
        let mut due: Option<SystemTime> = None;
        // One wait for the stop signal for the whole loop: a `changed()`
        // made anew each turn registered and removed a waiter per message.
        let stopped = stop.changed();
        tokio::pin!(stopped);
        loop {
            tokio::select! {
                biased;
                _ = &mut stopped => break,
                ev = events.recv() => {
                    let Some(ev) = ev else { break };
                    if let Some(s) = &self.spin {
                        s.activity();
                    }
                    self.handle(ev);
                    // Take what else is ready, then write once per connection.
                    for _ in 1..BATCH {
                        match events.try_recv() {
                            Ok(ev) => self.handle(ev),
                            Err(_) => break,
                        }
                    }
                    self.flush_all();
                }
                () = std::future::poll_fn(|cx| self.ready.poll_take(cx, &mut self.to_read)) => {
                    if let Some(s) = &self.spin {
                        s.activity();
                    }
                    let more = self.read_ready();
                    self.flush_all();
                    if more {
                        // Connections with more to read wait on the list:
                        // let the writers and the I/O driver run first.
                        tokio::task::yield_now().await;
                    }
                }
                () = std::future::poll_fn(|cx| trim.poll_fired(cx)), if trim_armed => {
                    let read = self.read_total.wrapping_sub(mark);
                    let busy = read >= TRIM_AFTER / u64::from(QUIET_TICKS);
                    mark = self.read_total;
                    quiet = if busy { 0 } else { quiet + 1 };
                    if quiet < QUIET_TICKS {
                        trim.set(std::time::Instant::now() + TRIM_TICK);
                    } else {
                        trim_armed = false;
                        self.give_memory_back();
                    }
                }
                () = std::future::poll_fn(|cx| timer.poll_fired(cx)), if due.is_some() => {
                    due = None;
                    self.central.handle_timeout(SystemTime::now());
                    self.drain();
                    self.flush_all();
                }
                Some(r) = self.tasks.join_next(), if !self.tasks.is_empty() => {
                    if let Err(e) = r {
                        if e.is_panic() {
                            tracing::error!("a connection task panicked");
                        }
                    }
                }
            }
            let next = self.central.next_timeout();
            if next != due {
                due = next;
                timer.set_next(next.map(instant_of));
            }
            let since_trim = self.read_total.wrapping_sub(self.read_at_trim);
            if !trim_armed && since_trim >= TRIM_AFTER {
                trim.set(std::time::Instant::now() + TRIM_TICK);
                (trim_armed, mark, quiet) = (true, self.read_total, 0);
            }
        }
        self.shutdown().await;
    }

    /// A burst of traffic is over ([`TRIM_TICK`]): frees the spare read buffers and batch
    /// vectors, and hands free heap back to the kernel when the process
    /// keeps it ([`super::keep_freed_memory`]).
    fn give_memory_back(&mut self) {
        self.read_at_trim = self.read_total;
        self.pool
            .free
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .clear();
        self.spare_batches = Vec::new();
        crate::sys::alloc::give_back();
        tracing::debug!("burst over: spare buffers freed, free memory given back");
    }

    async fn shutdown(mut self) {
        self.flush_all();
        // Dropping the states closes every connection: readers stop,
        // writers write what is queued and end.
        for (_, st) in self.conns.drain() {
            st.shared.close();
        }
        let tasks = &mut self.tasks;
        let drained = tokio::time::timeout(SHUTDOWN_GRACE, async {
            while tasks.join_next().await.is_some() {}
        })
        .await;
        if drained.is_err() {
            tracing::warn!("shutdown: some connections did not take their data in time");
        }
        self.tasks.shutdown().await;
    }

    fn handle(&mut self, ev: Event) {
        let now = SystemTime::now();
        match ev {
            Event::Accepted(stream, peer) => self.accepted(stream, peer, now),
            Event::Refused { peer, rule } => {
                self.log(&format!(
                    "WARNING: connection rejected from {peer} (denied by {rule})"
                ));
            }
            Event::WriteFailed { conn, error } => {
                if !self.conns.contains_key(&conn) {
                    return;
                }
                tracing::debug!(conn = conn.0, "write failed: {error}");
                self.gone(conn, now);
            }
            Event::Command(line) => {
                super::console::command(&mut self.central, &line, now);
                self.drain();
            }
            Event::Stats(reply) => {
                let _ = reply.send(self.central.stats());
            }
        }
    }

    fn accepted(&mut self, stream: Stream, peer: Peer, now: SystemTime) {
        let conn = ConnId(self.next_id);
        self.next_id += 1;
        let fd = match stream {
            Stream::Tcp(s) => s.into_std().map(|s| (OwnedFd::from(s), true)),
            Stream::Unix(s) => s.into_std().map(|s| (OwnedFd::from(s), false)),
            Stream::InProcess(e) => {
                return self.serve(
                    conn,
                    ReadHalf::InProcess(e.reader),
                    WriteHalf::InProcess(e.writer),
                    peer,
                    now,
                );
            }
        };
        match fd.and_then(|(fd, tcp)| Sock::new(fd, tcp)) {
            Ok(sock) => self.serve(
                conn,
                ReadHalf::Sock(sock.clone()),
                WriteHalf::Sock(sock),
                peer,
                now,
            ),
            Err(e) => self.log(&format!("WARNING: cannot serve a new connection: {e}")),
        }
    }

    /// Hands an accepted connection to the state machine; it is read from
    /// this task ([`Core::read_ready`]).
    fn serve(&mut self, conn: ConnId, r: ReadHalf, w: WriteHalf, peer: Peer, now: SystemTime) {
        let shared = Arc::new(Shared {
            half: w,
            queue: Mutex::default(),
            closing: Notify::new(),
        });
        self.conns.insert(
            conn,
            ConnState {
                shared,
                read: r,
                waker: self.ready.waker(conn),
                batch: Vec::new(),
                paused: false,
            },
        );
        self.central.connect(conn, peer, now);
        self.drain();
        // The first poll registers for readiness (or finds bytes).
        self.ready.push(conn);
    }

    /// Reads the connections on the ready list, [`BATCH`] reads at most
    /// (and [`READS_PER_TURN`] per connection) before what they produced
    /// is written. `true` if some were put back on the list with more to
    /// read.
    fn read_ready(&mut self) -> bool {
        let ids = std::mem::take(&mut self.to_read);
        let mut reads = 0;
        let mut more = false;
        for (i, &conn) in ids.iter().enumerate() {
            if reads >= BATCH {
                for &c in &ids[i..] {
                    self.ready.push(c);
                }
                more = true;
                break;
            }
            let (n, again) = self.read_conn(conn);
            reads += n;
            more |= again;
        }
        self.to_read = ids;
        more
    }

    /// Reads what `conn` has and hands it to the state machine, until the
    /// socket has nothing more (its waker is then registered) or
    /// [`READS_PER_TURN`] reads were made (it is then put back on the
    /// ready list, behind the others). Returns the reads made and whether
    /// it was put back.
    fn read_conn(&mut self, conn: ConnId) -> (usize, bool) {
        for n in 0..READS_PER_TURN {
            let Some(st) = self.conns.get_mut(&conn) else {
                return (n, false);
            };
            if st.paused {
                // `ResumeRead` puts it back on the list.
                return (n, false);
            }
            let mut cx = Context::from_waker(&st.waker);
            let now = SystemTime::now();
            match st.read.poll_read(&mut cx, &self.pool) {
                Poll::Pending => return (n, false),
                Poll::Ready(Ok(buf)) if buf.is_empty() => {
                    self.pool.put(buf);
                    self.gone(conn, now);
                    return (n, false);
                }
                Poll::Ready(Ok(buf)) => self.data(conn, buf, now),
                Poll::Ready(Err(e)) => {
                    if e.kind() != io::ErrorKind::ConnectionReset {
                        self.log(&format!(
                            "WARNING: read error on connection {}: {e}",
                            conn.0
                        ));
                    }
                    self.gone(conn, now);
                    return (n + 1, false);
                }
            }
        }
        self.ready.push(conn);
        (READS_PER_TURN, true)
    }

    fn data(&mut self, conn: ConnId, buf: Vec<u8>, now: SystemTime) {
        self.read_total = self.read_total.wrapping_add(buf.len() as u64);
        self.central.receive(conn, &buf, now);
        self.pool.put(buf);
        self.drain();
    }

    /// EOF or a broken connection.
    fn gone(&mut self, conn: ConnId, now: SystemTime) {
        self.central.disconnect(conn, now);
        self.close(conn);
        self.drain();
    }

    /// A line of the shell's own (refusals, read errors), logged once
    /// ([`shell_line`]).
    fn log(&mut self, line: &str) {
        let target = log_target(self.central.config());
        shell_line(&mut self.sink, target, line);
    }

    /// Carries out every output of the state machine.
    fn drain(&mut self) {
        while let Some(o) = self.central.poll_output() {
            self.apply(o);
        }
    }

    fn apply(&mut self, o: Output) {
        match o {
            Output::Transmit { conn, bytes } => self.queue(conn, bytes, None),
            Output::TransmitBody { conn, head, body } => self.queue(conn, head, Some(body)),
            Output::Close { conn, reason } => {
                tracing::debug!(conn = conn.0, %reason, "closing connection");
                self.close(conn);
                // The state machine forgets the module on disconnect.
                self.central.disconnect(conn, SystemTime::now());
            }
            Output::Log { target, line } => self.sink.line(target, &line),
            Output::PauseRead { conn } => {
                if let Some(st) = self.conns.get_mut(&conn) {
                    st.paused = true;
                }
            }
            Output::ResumeRead { conn } => {
                if let Some(st) = self.conns.get_mut(&conn) {
                    if std::mem::replace(&mut st.paused, false) {
                        self.ready.push(conn);
                    }
                }
            }
            other => tracing::warn!("unhandled central output {other:?}"),
        }
    }

    /// Adds a frame to `conn`'s batch.
    fn queue(&mut self, conn: ConnId, head: Vec<u8>, body: Option<Body>) {
        if let Some(st) = self.conns.get_mut(&conn) {
            if st.batch.is_empty() {
                self.dirty.push(conn);
                if st.batch.capacity() == 0 {
                    st.batch = self.spare_batches.pop().unwrap_or_default();
                }
            }
            st.batch.push(Buf::Own(head));
            st.batch.extend(body.map(Buf::Shared));
        }
    }

    /// Writes what is queued for `conn`, then forgets it (dropping its read
    /// half): a writer task finishes the queue and ends.
    fn close(&mut self, conn: ConnId) {
        self.flush(conn);
        if let Some(st) = self.conns.remove(&conn) {
            st.shared.close();
        }
    }

    fn flush_all(&mut self) {
        while let Some(conn) = self.dirty.pop() {
            self.flush(conn);
        }
    }

    fn flush(&mut self, conn: ConnId) {
        let Some(st) = self.conns.get_mut(&conn) else {
            return;
        };
        if st.batch.is_empty() {
            return;
        }
        let mut chunks = Chunks {
            bufs: std::mem::take(&mut st.batch),
            idx: 0,
            off: 0,
        };
        chunks.advance(0);
        let mut q = st.shared.queue();
        if q.writer {
            // Behind what the writer task has still to write.
            q.chunks.push_back(chunks);
            return;
        }
        // No writer: everything before is on the wire, so writing here
        // keeps the order and saves a task wake-up.
        match chunks.try_write(&st.shared.half) {
            Ok(true) => {
                drop(q);
                if chunks.bufs.capacity() <= BATCH_KEEP && self.spare_batches.len() < SPARE_BATCHES
                {
                    chunks.bufs.clear();
                    self.spare_batches.push(chunks.bufs);
                }
                return;
            }
            Ok(false) => {}
            Err(error) => {
                // Reported like a writer task's failure; nothing more is
                // written (`writer` stays set, with no writer task).
                q.writer = true;
                let _ = self.events_tx.send(Event::WriteFailed { conn, error });
                return;
            }
        }
        q.chunks.push_back(chunks);
        q.writer = true;
        drop(q);
        self.tasks
            .spawn(writer_task(conn, st.shared.clone(), self.events_tx.clone()));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn accept_failures_are_said_once_then_every_ten_seconds_then_recovery() {
        use std::time::Instant;
        let t0 = Instant::now();
        let e = io::Error::from_raw_os_error(24);
        let mut t = AcceptTrouble::default();
        assert!(t.succeeded(t0).is_none(), "nothing to say when all is well");
        // 10 s of EMFILE, one failure every 50 ms: 201 failures.
        let mut lines = Vec::new();
        for i in 0..=200u32 {
            if let Some(l) = t.failed(&e, t0 + ACCEPT_RETRY * i) {
                lines.push(l);
            }
        }
        assert_eq!(lines.len(), 2, "{lines:?}");
        assert!(
            lines[0].starts_with("accept failed: Too many open files")
                && lines[0].contains("retrying every 50 ms"),
            "{lines:?}"
        );
        assert!(
            lines[1].starts_with("accept still failing: Too many open files")
                && lines[1].ends_with("; 200 more failure(s) in the last 10 s (10 s in all)"),
            "{lines:?}"
        );
        let back = t.succeeded(t0 + Duration::from_secs(12)).unwrap();
        assert_eq!(
            back,
            "accepting connections again, after 201 failed accept(s) over 12 s"
        );
        assert!(t.succeeded(t0 + Duration::from_secs(13)).is_none());
        // Hovering at the limit: bouts that start and end every 50 ms
        // are counted, with a line every 10 s at most.
        let mut lines = Vec::new();
        for i in 0..400u32 {
            let now = t0 + Duration::from_secs(12) + ACCEPT_RETRY * i;
            lines.extend(if i % 2 == 0 {
                t.failed(&e, now)
            } else {
                t.succeeded(now)
            });
        }
        assert_eq!(lines.len(), 2, "{lines:?}");
        assert!(lines[0].starts_with("accept failed: "), "{lines:?}");
        assert!(
            lines[1].starts_with("accepting connections again, after 1 "),
            "{lines:?}"
        );
        // Long after, a new bout is said at once.
        let e2 = t.failed(&e, t0 + Duration::from_secs(60)).unwrap();
        assert!(e2.starts_with("accept failed: "), "{e2}");
    }

    #[test]
    fn chunks_advance_across_frames() {
        let mut c = Chunks {
            bufs: vec![
                Buf::Own(vec![1, 2, 3]),
                Buf::Own(vec![]),
                Buf::Shared(Body::from(vec![4, 5])),
            ],
            idx: 0,
            off: 0,
        };
        c.advance(2);
        assert_eq!((c.idx, c.off), (0, 2));
        c.advance(1);
        assert_eq!((c.idx, c.off), (2, 0), "the empty frame is skipped");
        assert!(!c.done());
        c.advance(2);
        assert!(c.done());
        let mut empty = Chunks {
            bufs: vec![Buf::Own(vec![])],
            idx: 0,
            off: 0,
        };
        empty.advance(0);
        assert!(empty.done());
    }

    #[test]
    fn writer_sink_routes_lines_by_target() {
        #[derive(Clone, Default)]
        struct Shared(Arc<std::sync::Mutex<Vec<u8>>>);
        impl Write for Shared {
            fn write(&mut self, b: &[u8]) -> io::Result<usize> {
                self.0.lock().unwrap().extend_from_slice(b);
                Ok(b.len())
            }
            fn flush(&mut self) -> io::Result<()> {
                Ok(())
            }
        }
        let (t, f) = (Shared::default(), Shared::default());
        let mut sink = LogSink::writers(Some(Box::new(t.clone())), Some(Box::new(f.clone())), true);
        let target = |terminal, file| LogTarget { terminal, file };
        sink.line(target(true, false), "term");
        sink.line(target(false, true), "file");
        sink.line(target(true, true), "both");
        assert_eq!(&*t.0.lock().unwrap(), b"term\nboth\n");
        assert_eq!(&*f.0.lock().unwrap(), b"file\nboth\n");
        // Absent writers drop their lines.
        let mut sink = LogSink::writers(None, None, false);
        sink.line(target(true, true), "nowhere");
    }
}
