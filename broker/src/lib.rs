//! Courier's servers. Today: `central`, a drop-in replacement for CMU IPC's
//! central server, as a library to embed and as the `central` binary.
//!
//! The protocol lives in [`courier_wire::ipc::central`] (sans-I/O); this
//! crate owns the sockets: TCP on the port (default 1381) and the UNIX socket
//! `/tmp/x_ipc/<port>` the C library prefers on the local host, access
//! control, back-pressure (a connection stops being read while central's
//! queues are over their limit) and clean shutdown.
//!
//! ```no_run
//! # async fn demo() -> Result<(), Box<dyn std::error::Error>> {
//! use courier_broker::CentralServer;
//! let central = CentralServer::builder()
//!     .bind("127.0.0.1".parse()?)
//!     .port(0) // any free port
//!     .spawn()
//!     .await?;
//! println!("central on {}", central.local_addr());
//! // … modules connect with CENTRALHOST=127.0.0.1:<port> …
//! central.shutdown().await;
//! # Ok(()) }
//! ```
#![warn(missing_docs)]

pub mod access;

use std::collections::{HashMap, VecDeque};
use std::io;
use std::net::{IpAddr, Ipv4Addr, SocketAddr};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::SystemTime;

use tokio::io::AsyncReadExt;
use tokio::net::{TcpListener, UnixListener, UnixStream};
use tokio::sync::{watch, Notify};
use tokio::task::JoinHandle;

pub use courier_wire::ipc::central::{
    Central, Config, ConnId, LogOptions, LogTarget, OptionError, Output, Peer, Stats,
};

use access::{AccessControl, Decision};

/// The C central's port.
pub const DEFAULT_PORT: u16 = 1381;

/// Bytes read from a connection at a time.
const READ_CHUNK: usize = 64 * 1024;

/// Where log lines go: called with each line and where central wants it.
pub type LogSink = Arc<dyn Fn(LogTarget, &str) + Send + Sync>;

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
        source: io::Error,
    },
    /// The UNIX socket could not be bound.
    #[error("cannot listen on {path}: {source}")]
    Unix {
        /// The socket path.
        path: PathBuf,
        /// Why.
        source: io::Error,
    },
}

/// Namespace of the builder.
#[derive(Debug)]
pub struct CentralServer;

impl CentralServer {
    /// A builder with the C central's defaults (port 1381 on all
    /// interfaces, no UNIX socket, no access rules, logs to `tracing`).
    pub fn builder() -> Builder {
        Builder {
            port: DEFAULT_PORT,
            bind: IpAddr::V4(Ipv4Addr::UNSPECIFIED),
            unix_socket: false,
            config: Config::default(),
            access: AccessControl::open(),
            sink: Arc::new(|_, line| tracing::info!(target: "central", "{line}")),
        }
    }
}

/// Settings of an embedded central.
pub struct Builder {
    port: u16,
    bind: IpAddr,
    unix_socket: bool,
    config: Config,
    access: AccessControl,
    sink: LogSink,
}

impl std::fmt::Debug for Builder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Builder")
            .field("port", &self.port)
            .field("bind", &self.bind)
            .field("unix_socket", &self.unix_socket)
            .field("config", &self.config)
            .finish_non_exhaustive()
    }
}

impl Builder {
    /// TCP port; 0 picks a free one (see [`CentralHandle::local_addr`]).
    pub fn port(mut self, port: u16) -> Self {
        self.port = port;
        self
    }

    /// Address to listen on (the C central always uses all interfaces).
    pub fn bind(mut self, addr: IpAddr) -> Self {
        self.bind = addr;
        self
    }

    /// Also listen on the UNIX socket `/tmp/x_ipc/<port>`, as the C central
    /// does (C modules use it when `CENTRALHOST` names the local host).
    pub fn unix_socket(mut self, on: bool) -> Self {
        self.unix_socket = on;
        self
    }

    /// Protocol and logging options.
    pub fn config(mut self, config: Config) -> Self {
        self.config = config;
        self
    }

    /// Allow/deny rules checked before any byte is sent to a new connection.
    pub fn access(mut self, access: AccessControl) -> Self {
        self.access = access;
        self
    }

    /// Where log lines go (default: `tracing` at info level).
    pub fn log_sink(mut self, sink: LogSink) -> Self {
        self.sink = sink;
        self
    }

    /// Binds and starts serving.
    pub async fn spawn(self) -> Result<CentralHandle, BindError> {
        let addr = SocketAddr::new(self.bind, self.port);
        let tcp = bind_tcp(addr).map_err(|source| BindError::Tcp { addr, source })?;
        let local = tcp
            .local_addr()
            .map_err(|source| BindError::Tcp { addr, source })?;
        let unix = if self.unix_socket {
            let path = unix_path(local.port());
            let l = bind_unix(&path).map_err(|source| BindError::Unix {
                path: path.clone(),
                source,
            })?;
            Some((l, path))
        } else {
            None
        };
        let (stop_tx, stop_rx) = watch::channel(false);
        let shared = Arc::new(Shared {
            central: Mutex::new(Central::new(self.config)),
            conns: Mutex::new(HashMap::new()),
            next_conn: AtomicU64::new(5),
            sink: self.sink,
            access: self.access,
            stop: stop_rx,
            tasks: Mutex::new(Vec::new()),
        });
        for w in shared.access.warnings() {
            (shared.sink)(
                LogTarget {
                    terminal: true,
                    file: true,
                },
                &format!("WARNING: {w}"),
            );
        }
        let unix_path = unix.as_ref().map(|(_, p)| p.clone());
        let s = shared.clone();
        let accept_tcp = tokio::spawn(async move { s.accept_tcp(tcp).await });
        shared.track(accept_tcp);
        if let Some((l, _)) = unix {
            let s = shared.clone();
            let t = tokio::spawn(async move { s.accept_unix(l).await });
            shared.track(t);
        }
        Ok(CentralHandle {
            shared,
            local,
            unix_path,
            stop: stop_tx,
        })
    }
}

fn bind_tcp(addr: SocketAddr) -> io::Result<TcpListener> {
    let sock = if addr.is_ipv4() {
        tokio::net::TcpSocket::new_v4()?
    } else {
        tokio::net::TcpSocket::new_v6()?
    };
    sock.set_reuseaddr(true)?;
    sock.bind(addr)?;
    sock.listen(128)
}

/// The UNIX socket path the C library uses for a port.
pub fn unix_path(port: u16) -> PathBuf {
    PathBuf::from(format!("/tmp/x_ipc/{port}"))
}

fn bind_unix(path: &Path) -> io::Result<UnixListener> {
    if let Some(dir) = path.parent() {
        if !dir.exists() {
            std::fs::create_dir_all(dir)?;
            use std::os::unix::fs::PermissionsExt;
            let _ = std::fs::set_permissions(dir, std::fs::Permissions::from_mode(0o777));
        }
    }
    // A socket file left by a dead central: remove it if nobody answers.
    if path.exists() {
        match std::os::unix::net::UnixStream::connect(path) {
            Ok(_) => {
                return Err(io::Error::new(
                    io::ErrorKind::AddrInUse,
                    "another central is listening there",
                ))
            }
            Err(_) => std::fs::remove_file(path)?,
        }
    }
    UnixListener::bind(path)
}

/// A running central. Dropping it stops serving (without waiting); prefer
/// [`CentralHandle::shutdown`].
pub struct CentralHandle {
    shared: Arc<Shared>,
    local: SocketAddr,
    unix_path: Option<PathBuf>,
    stop: watch::Sender<bool>,
}

impl std::fmt::Debug for CentralHandle {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("CentralHandle")
            .field("local", &self.local)
            .field("unix_path", &self.unix_path)
            .finish_non_exhaustive()
    }
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

    /// A console command (`status`, `-lmsd`, `close <module>`, …).
    pub fn command(&self, line: &str) {
        self.shared
            .with_central(|c| c.command(line, SystemTime::now()));
    }

    /// Counters of the state machine (queued bytes and their peak, …).
    pub fn stats(&self) -> Stats {
        self.shared.central.lock().unwrap().stats()
    }

    /// Closes every connection and waits until every task has ended.
    pub async fn shutdown(self) {
        let _ = self.stop.send(true);
        loop {
            let tasks: Vec<JoinHandle<()>> =
                std::mem::take(&mut *self.shared.tasks.lock().unwrap());
            if tasks.is_empty() {
                break;
            }
            for t in tasks {
                let _ = t.await;
            }
        }
        if let Some(p) = &self.unix_path {
            let _ = std::fs::remove_file(p);
        }
    }
}

impl Drop for CentralHandle {
    fn drop(&mut self) {
        let _ = self.stop.send(true);
        if let Some(p) = &self.unix_path {
            let _ = std::fs::remove_file(p);
        }
    }
}

/// Either kind of stream's write half.
enum WriteHalf {
    Tcp(tokio::net::tcp::OwnedWriteHalf),
    Unix(tokio::net::unix::OwnedWriteHalf),
}

impl WriteHalf {
    fn try_write(&self, b: &[u8]) -> io::Result<usize> {
        match self {
            WriteHalf::Tcp(w) => w.try_write(b),
            WriteHalf::Unix(w) => w.try_write(b),
        }
    }

    async fn writable(&self) -> io::Result<()> {
        match self {
            WriteHalf::Tcp(w) => w.writable().await,
            WriteHalf::Unix(w) => w.writable().await,
        }
    }
}

enum ReadHalf {
    Tcp(tokio::net::tcp::OwnedReadHalf),
    Unix(tokio::net::unix::OwnedReadHalf),
}

impl ReadHalf {
    async fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        match self {
            ReadHalf::Tcp(r) => r.read(buf).await,
            ReadHalf::Unix(r) => r.read(buf).await,
        }
    }
}

#[derive(Default)]
struct OutQueue {
    bufs: VecDeque<Vec<u8>>,
    /// The writer task is writing (its front item was taken).
    busy: bool,
    /// Close once the queue is written.
    close: bool,
}

/// The sending side of one connection.
struct Conn {
    writer: WriteHalf,
    queue: Mutex<OutQueue>,
    wake: Notify,
    /// `true` while central asked not to read from this connection.
    paused: watch::Sender<bool>,
    /// Set when central closed the connection: the reader stops.
    closed: watch::Sender<bool>,
}

impl Conn {
    /// Writes now if nothing is queued and the socket takes it, else queues.
    fn send(&self, bytes: Vec<u8>) {
        let mut q = self.queue.lock().unwrap();
        if q.close {
            return;
        }
        let mut off = 0;
        if !q.busy && q.bufs.is_empty() {
            while off < bytes.len() {
                match self.writer.try_write(&bytes[off..]) {
                    Ok(0) => break,
                    Ok(n) => off += n,
                    Err(_) => break,
                }
            }
            if off == bytes.len() {
                return;
            }
        }
        q.bufs.push_back(if off == 0 {
            bytes
        } else {
            bytes[off..].to_vec()
        });
        drop(q);
        self.wake.notify_one();
    }

    fn close(&self) {
        self.queue.lock().unwrap().close = true;
        self.wake.notify_one();
        let _ = self.closed.send(true);
    }

    async fn write_loop(&self) -> io::Result<()> {
        loop {
            let next = {
                let mut q = self.queue.lock().unwrap();
                match q.bufs.pop_front() {
                    Some(b) => {
                        q.busy = true;
                        Some(b)
                    }
                    None => {
                        q.busy = false;
                        if q.close {
                            return Ok(());
                        }
                        None
                    }
                }
            };
            match next {
                Some(b) => {
                    let mut off = 0;
                    while off < b.len() {
                        self.writer.writable().await?;
                        match self.writer.try_write(&b[off..]) {
                            Ok(0) => return Err(io::ErrorKind::WriteZero.into()),
                            Ok(n) => off += n,
                            Err(e) if e.kind() == io::ErrorKind::WouldBlock => {}
                            Err(e) => return Err(e),
                        }
                    }
                }
                None => self.wake.notified().await,
            }
        }
    }
}

struct Shared {
    central: Mutex<Central>,
    conns: Mutex<HashMap<ConnId, Arc<Conn>>>,
    next_conn: AtomicU64,
    sink: LogSink,
    access: AccessControl,
    stop: watch::Receiver<bool>,
    tasks: Mutex<Vec<JoinHandle<()>>>,
}

impl Shared {
    fn track(&self, t: JoinHandle<()>) {
        let mut tasks = self.tasks.lock().unwrap();
        tasks.retain(|t| !t.is_finished());
        tasks.push(t);
    }

    /// Runs `f` on the state machine and carries out its outputs while
    /// still holding the lock, so frames for one connection keep their order.
    fn with_central(&self, f: impl FnOnce(&mut Central)) {
        let mut c = self.central.lock().unwrap();
        f(&mut c);
        while let Some(o) = c.poll_output() {
            self.carry_out(o);
        }
    }

    fn carry_out(&self, o: Output) {
        let conn_of = |id: ConnId| self.conns.lock().unwrap().get(&id).cloned();
        match o {
            Output::Transmit { conn, bytes } => {
                if let Some(c) = conn_of(conn) {
                    c.send(bytes);
                }
            }
            Output::Close { conn, reason } => {
                tracing::debug!(conn = conn.0, %reason, "closing connection");
                if let Some(c) = self.conns.lock().unwrap().remove(&conn) {
                    c.close();
                }
            }
            Output::Log { target, line } => (self.sink)(target, &line),
            Output::PauseRead { conn } => {
                if let Some(c) = conn_of(conn) {
                    let _ = c.paused.send(true);
                }
            }
            Output::ResumeRead { conn } => {
                if let Some(c) = conn_of(conn) {
                    let _ = c.paused.send(false);
                }
            }
            other => tracing::warn!("unhandled central output {other:?}"),
        }
    }

    async fn accept_tcp(self: Arc<Self>, l: TcpListener) {
        let mut stop = self.stop.clone();
        loop {
            tokio::select! {
                r = l.accept() => match r {
                    Ok((s, addr)) => {
                        if let Decision::Denied(rule) = self.access.check(Some(addr.ip())) {
                            self.refuse(&addr.to_string(), &rule);
                            drop(s);
                            continue;
                        }
                        let _ = s.set_nodelay(true);
                        let (r, w) = s.into_split();
                        self.clone().start(ReadHalf::Tcp(r), WriteHalf::Tcp(w), Peer::Tcp(addr.to_string()));
                    }
                    Err(e) => {
                        tracing::warn!("accept failed: {e}");
                        tokio::time::sleep(std::time::Duration::from_millis(10)).await;
                    }
                },
                _ = stop.changed() => return,
            }
        }
    }

    async fn accept_unix(self: Arc<Self>, l: UnixListener) {
        let mut stop = self.stop.clone();
        loop {
            tokio::select! {
                r = l.accept() => match r {
                    Ok((s, _)) => {
                        if let Decision::Denied(rule) = self.access.check(None) {
                            self.refuse("unix socket", &rule);
                            drop(s);
                            continue;
                        }
                        let (r, w) = UnixStream::into_split(s);
                        self.clone().start(ReadHalf::Unix(r), WriteHalf::Unix(w), Peer::Unix);
                    }
                    Err(e) => {
                        tracing::warn!("accept failed: {e}");
                        tokio::time::sleep(std::time::Duration::from_millis(10)).await;
                    }
                },
                _ = stop.changed() => return,
            }
        }
    }

    fn refuse(&self, peer: &str, rule: &str) {
        (self.sink)(
            LogTarget {
                terminal: true,
                file: true,
            },
            &format!("Access denied: connection from {peer} refused by {rule}"),
        );
    }

    fn start(self: Arc<Self>, r: ReadHalf, w: WriteHalf, peer: Peer) {
        let id = ConnId(self.next_conn.fetch_add(1, Ordering::Relaxed));
        let (paused_tx, paused_rx) = watch::channel(false);
        let (closed_tx, closed_rx) = watch::channel(false);
        let conn = Arc::new(Conn {
            writer: w,
            queue: Mutex::new(OutQueue::default()),
            wake: Notify::new(),
            paused: paused_tx,
            closed: closed_tx,
        });
        self.conns.lock().unwrap().insert(id, conn.clone());
        self.with_central(|c| c.connect(id, peer, SystemTime::now()));
        let s = self.clone();
        let writer = tokio::spawn(async move {
            let mut stop = s.stop.clone();
            let res = tokio::select! {
                r = conn.write_loop() => r,
                _ = stop.changed() => Ok(()),
            };
            if let Err(e) = res {
                tracing::debug!(conn = id.0, "write failed: {e}");
                // The reader notices the broken connection too; make sure.
                let _ = conn.closed.send(true);
            }
        });
        self.track(writer);
        let s = self.clone();
        let reader = tokio::spawn(async move { s.read_loop(id, r, paused_rx, closed_rx).await });
        self.track(reader);
    }

    async fn read_loop(
        self: Arc<Self>,
        id: ConnId,
        mut r: ReadHalf,
        mut paused: watch::Receiver<bool>,
        mut closed: watch::Receiver<bool>,
    ) {
        let mut stop = self.stop.clone();
        let mut buf = vec![0u8; READ_CHUNK];
        loop {
            // Back-pressure: do not read while central says so.
            while *paused.borrow() {
                tokio::select! {
                    r = paused.changed() => if r.is_err() { break },
                    _ = closed.changed() => break,
                    _ = stop.changed() => return,
                }
            }
            if *closed.borrow() {
                break;
            }
            let n = tokio::select! {
                r = r.read(&mut buf) => r,
                _ = closed.changed() => break,
                _ = stop.changed() => return,
            };
            match n {
                Ok(0) => break,
                Err(e) => {
                    // As the C central's perror() puts it.
                    let text = e.to_string();
                    let text = text.split(" (os error").next().unwrap_or(&text);
                    (self.sink)(
                        LogTarget {
                            terminal: true,
                            file: true,
                        },
                        &format!("ERROR: handleDataMsgRecv : {text}"),
                    );
                    break;
                }
                Ok(n) => self.with_central(|c| c.receive(id, &buf[..n], SystemTime::now())),
            }
        }
        self.with_central(|c| c.disconnect(id, SystemTime::now()));
        if let Some(c) = self.conns.lock().unwrap().remove(&id) {
            c.close();
        }
    }
}
