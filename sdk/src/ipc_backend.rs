//! The CMU IPC backend: one tokio task drives the sans-I/O module state
//! machine (`courier_wire::ipc::module`) over TCP or the UNIX socket
//! `/tmp/x_ipc/<port>`; API calls reach it over a channel.

use std::collections::HashMap;
use std::sync::Arc;
use std::time::{Duration, Instant};

use futures::future::BoxFuture;
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::sync::{mpsc, oneshot};

use crate::backend::{
    Backend, Capabilities, ClientId, Handle, IpcControl, PubId, ServiceId, SubId,
};
use crate::busy_poll::BusyPoll;
use crate::direct_link::LinkWriter;
use crate::error::{ControlError, Failure, OpenError, PublishError};
use crate::hub::{Hub, Listener};
use crate::qos::{PublicationQos, SubscriptionQos, TypeInfo};
use crate::session::{
    ConnectError, Encoding, QueryError, RawReply, RawRequest, RawSample, Reply, ReplyFuture,
    Responder, SampleQueue, SessionEvent, WriteOptions,
};
use courier_wire::ipc::module::{
    Connection, DeliveryId, DeliveryKind, Error as ModError, Event, LinkId, ModuleConfig,
    MsgLength, OpId,
};
use courier_wire::ipc::ByteOrder;

/// The C library's default central port.
pub const DEFAULT_PORT: u16 = 1381;

/// Options of the IPC backend.
#[derive(Debug, Clone)]
#[non_exhaustive]
pub struct IpcOptions {
    /// `false` = `IPC_connectNoListen`.
    pub listen: bool,
    /// How long to keep trying to reach central.
    pub connect_timeout: Duration,
    /// Reconnect after losing central: first wait, doubling up to 5 s.
    pub reconnect: Option<Duration>,
    /// Keep polling for this long after each message instead of sleeping
    /// (see [`crate::busy_poll`]); `None` (the default) never spins.
    pub busy_poll: Option<Duration>,
    /// Opens the connection to central instead of a socket (an in-process
    /// link to an embedded central); `None` = TCP or the UNIX socket.
    pub dial: Option<Dial>,
}

/// A byte stream to central: what a connected socket offers.
pub trait IpcStream: AsyncRead + AsyncWrite + Unpin + Send {}
impl<T: AsyncRead + AsyncWrite + Unpin + Send> IpcStream for T {}

/// A TCP connection of the IPC backend: `TCP_NODELAY`, and what it reads
/// is acknowledged at once every [`QUICK_ACK_EVERY`] bytes
/// (`TCP_QUICKACK`).
///
/// Why the acknowledgement: the C library (central and modules alike) sets
/// 16 KiB socket buffers on its TCP connections, so a C peer sending a large
/// message has at most ~32 KiB unacknowledged before it must wait for an
/// ACK. Our receive buffer is the system's (autotuned, large), so reading
/// that data never opens the window "significantly", and once this side
/// has sent anything (a Success, a reply) Linux treats the connection as
/// interactive and delays the ACK by its 40 ms minimum: each ~32 KiB of a
/// large message from a C peer cost 40 ms (a stream of 64 KiB messages
/// from the C central ran at 23 msg/s, a 1 MiB query took 660 ms).
///
/// Small messages do not need it (the ACK rides on the answer), and an ACK
/// of its own for each of them would cost a packet per message, hence the
/// byte count: a peer can only be stalled with at least its send buffer
/// unacknowledged, and Linux's smallest is 4608 bytes.
struct Tcp {
    s: tokio::net::TcpStream,
    /// Bytes read since the last `TCP_QUICKACK`.
    unacked: usize,
}

/// See [`Tcp`].
const QUICK_ACK_EVERY: usize = 4096;

impl Tcp {
    fn new(s: tokio::net::TcpStream) -> std::io::Result<Tcp> {
        s.set_nodelay(true)?;
        Ok(Tcp { s, unacked: 0 })
    }
}

impl AsyncRead for Tcp {
    fn poll_read(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
        buf: &mut tokio::io::ReadBuf<'_>,
    ) -> std::task::Poll<std::io::Result<()>> {
        let before = buf.filled().len();
        let r = std::pin::Pin::new(&mut self.s).poll_read(cx, buf);
        if let std::task::Poll::Ready(Ok(())) = r {
            self.unacked += buf.filled().len() - before;
            if self.unacked >= QUICK_ACK_EVERY {
                self.unacked = 0;
                quick_ack(&self.s);
            }
        }
        r
    }
}

#[cfg(any(target_os = "linux", target_os = "android"))]
fn quick_ack(s: &tokio::net::TcpStream) {
    // Best effort: failing costs only the delay this avoids.
    let _ = socket2::SockRef::from(s).set_tcp_quickack(true);
}

#[cfg(not(any(target_os = "linux", target_os = "android")))]
fn quick_ack(_: &tokio::net::TcpStream) {}

impl AsyncWrite for Tcp {
    fn poll_write(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
        buf: &[u8],
    ) -> std::task::Poll<std::io::Result<usize>> {
        std::pin::Pin::new(&mut self.s).poll_write(cx, buf)
    }

    fn poll_write_vectored(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
        bufs: &[std::io::IoSlice<'_>],
    ) -> std::task::Poll<std::io::Result<usize>> {
        std::pin::Pin::new(&mut self.s).poll_write_vectored(cx, bufs)
    }

    fn is_write_vectored(&self) -> bool {
        self.s.is_write_vectored()
    }

    fn poll_flush(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
    ) -> std::task::Poll<std::io::Result<()>> {
        std::pin::Pin::new(&mut self.s).poll_flush(cx)
    }

    fn poll_shutdown(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
    ) -> std::task::Poll<std::io::Result<()>> {
        std::pin::Pin::new(&mut self.s).poll_shutdown(cx)
    }
}

/// The future of a [`Dial`] call.
pub type DialFuture = BoxFuture<'static, std::io::Result<Box<dyn IpcStream>>>;

/// Opens a new connection to central; called for the first connection and
/// for every reconnect.
///
/// A dial that fails with [`std::io::ErrorKind::NotConnected`] says that
/// central is gone for good (an embedded central that has stopped): the
/// session does not retry it, neither while connecting nor to reconnect.
/// Any other error is retried as a refused socket connection is.
#[derive(Clone)]
pub struct Dial(Arc<dyn Fn() -> DialFuture + Send + Sync>);

impl Dial {
    /// Wraps a function that opens a stream to central.
    pub fn new<F, Fut>(f: F) -> Self
    where
        F: Fn() -> Fut + Send + Sync + 'static,
        Fut: std::future::Future<Output = std::io::Result<Box<dyn IpcStream>>> + Send + 'static,
    {
        Dial(Arc::new(move || Box::pin(f())))
    }

    fn open(&self) -> DialFuture {
        (self.0)()
    }
}

impl std::fmt::Debug for Dial {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Dial(..)")
    }
}

impl Default for IpcOptions {
    fn default() -> Self {
        IpcOptions {
            listen: true,
            connect_timeout: Duration::from_secs(5),
            reconnect: None,
            busy_poll: None,
            dial: None,
        }
    }
}

type Done<T> = oneshot::Sender<T>;

enum Cmd {
    DefineFormat(String, String, Done<Result<(), OpenError>>),
    Define(String, Option<String>, Done<Result<(), OpenError>>),
    Publish(String, Vec<u8>, Done<Result<(), PublishError>>),
    Subscribe(String, Arc<SampleQueue>, SubId, Done<Result<(), OpenError>>),
    Serve(
        String,
        mpsc::Sender<RawRequest>,
        ServiceId,
        Done<Result<(), OpenError>>,
    ),
    /// A `Subscriber`, `Listener` or `Requests` was dropped: unsubscribe.
    CloseHandle(Handle),
    Query(u64, String, Vec<u8>, Done<Result<RawReply, QueryError>>),
    CancelQuery(u64),
    Ack(u64),
    Respond(u64, String, Vec<u8>, Done<Result<(), PublishError>>),
    /// A query delivery that will not be answered (its `Request` dropped).
    Decline(u64),
    ModuleConnected(String, Done<Result<bool, ControlError>>),
    NumHandlers(String, Done<Result<i32, ControlError>>),
    Inform(InformOp, Done<Result<(), ControlError>>),
    /// Subscribe central's connect/disconnect notifications (once).
    WatchModules,
    /// Direct mode: a peer connected to our listener.
    LinkAccepted(Box<dyn IpcStream>),
    /// Direct mode: our connection to a receiver is up (or failed: None).
    LinkConnected(LinkId, Option<Box<dyn IpcStream>>),
    /// Direct mode: bytes read from a link (empty = closed).
    LinkData(LinkId, Vec<u8>),
    /// A congested link's writer has drained to its limit (the link, for
    /// the logs).
    LinkDrained(LinkId),
    /// Subscribe handler-count changes of a message.
    WatchHandlers(String, Done<Result<(), ControlError>>),
    Close(Done<()>),
}

enum InformOp {
    Capacity(i32),
    Priority(String, i32),
    QueueLength(String, i32),
}

/// A session's connection to an IPC central.
pub struct IpcBackend {
    cmd: mpsc::UnboundedSender<Cmd>,
    addr: String,
    events: Hub<SessionEvent>,
    next_query: std::sync::atomic::AtomicU64,
    /// Handle numbers, shared by every kind.
    next_handle: std::sync::atomic::AtomicU64,
    /// Open publications and clients: the message each names (IPC keeps
    /// nothing for them but the definition).
    names: std::sync::Mutex<HashMap<Handle, Arc<str>>>,
    /// Messages this session defined, with their format: another
    /// publication of the same message shares the definition.
    defined: std::sync::Mutex<HashMap<String, Option<String>>>,
}

impl std::fmt::Debug for IpcBackend {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("IpcBackend")
            .field("central", &self.addr)
            .finish_non_exhaustive()
    }
}

/// `(host, port)` from `ipc://host:port`, `ipc://host`, `ipc://` (then
/// `CENTRALHOST`, then localhost:1381).
pub fn parse_url(url: &str) -> Result<(String, u16), String> {
    let rest = url
        .strip_prefix("ipc://")
        .ok_or_else(|| "expected ipc://host:port".to_string())?;
    let rest = rest.trim_end_matches('/');
    let spec = if rest.is_empty() {
        std::env::var("CENTRALHOST").unwrap_or_else(|_| "localhost".into())
    } else {
        rest.to_string()
    };
    match spec.rsplit_once(':') {
        Some((h, p)) => {
            let port = p
                .parse::<u16>()
                .ok()
                .filter(|p| *p > 0)
                .ok_or_else(|| format!("'{p}' is not a port number"))?;
            Ok((
                if h.is_empty() {
                    "localhost".into()
                } else {
                    h.into()
                },
                port,
            ))
        }
        None => Ok((spec, DEFAULT_PORT)),
    }
}

/// This machine's name, as the C library takes it for the module's host
/// and for choosing the UNIX socket (`localhost` if it cannot be read).
pub fn local_host_name() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname")
        .map(|s| s.trim().to_string())
        .unwrap_or_else(|_| "localhost".into())
}

/// C's rule: the UNIX socket is tried first when the host is this machine's
/// name (exactly, or as a prefix followed by '.').
fn is_local_name(host: &str, local: &str) -> bool {
    host == local || local.strip_prefix(host).is_some_and(|r| r.starts_with('.'))
}

async fn open(host: &str, port: u16) -> std::io::Result<Box<dyn IpcStream>> {
    if is_local_name(host, &local_host_name()) {
        if let Ok(s) = tokio::net::UnixStream::connect(format!("/tmp/x_ipc/{port}")).await {
            return Ok(Box::new(s));
        }
    }
    let s = tokio::net::TcpStream::connect((host, port)).await?;
    Ok(Box::new(Tcp::new(s)?))
}

/// A dial error that no retry can mend (see [`Dial`]).
fn gone_for_good(opts: &IpcOptions, e: &std::io::Error) -> bool {
    opts.dial.is_some() && e.kind() == std::io::ErrorKind::NotConnected
}

/// Opens a connection to central and completes the IPC handshake (with a
/// direct-link listener when central runs with `-c`).
async fn handshake(
    host: &str,
    port: u16,
    name: &str,
    opts: &IpcOptions,
) -> Result<(Connection, Box<dyn IpcStream>, Option<DirectListener>), ConnectError> {
    {
        let host = host.to_string();
        let addr = format!("{host}:{port}");
        let deadline = tokio::time::Instant::now() + opts.connect_timeout;
        let mut attempts = 0;
        let mut io = loop {
            attempts += 1;
            let opened = match &opts.dial {
                Some(d) => d.open().await,
                None => open(&host, port).await,
            };
            match opened {
                Ok(io) => break io,
                Err(e)
                    if gone_for_good(opts, &e)
                        || tokio::time::Instant::now() + Duration::from_millis(200) >= deadline =>
                {
                    return Err(ConnectError::Unreachable {
                        addr,
                        attempts,
                        source: e,
                    })
                }
                Err(_) => tokio::time::sleep(Duration::from_millis(200)).await,
            }
        };
        let mut cfg = ModuleConfig::new(name, local_host_name());
        cfg.listen = opts.listen;
        let mut conn = Connection::new(cfg, Instant::now());
        let mut buf = vec![0u8; 64 * 1024];
        let mut listener: Option<DirectListener> = None;
        let hs = async {
            loop {
                while let Some(b) = conn.poll_transmit() {
                    io.write_all(&b).await.map_err(|e| e.to_string())?;
                }
                match conn.poll_event() {
                    Some(Event::Connected) => return Ok(()),
                    Some(Event::Closed(e)) => {
                        return Err(
                            e.map_or("central closed the connection".into(), |e| e.to_string())
                        )
                    }
                    Some(Event::DirectListenRequested) => {
                        // Like C: the first free port from 8000 (to 9000).
                        let ip = if host == "localhost" || host.starts_with("127.") {
                            "127.0.0.1"
                        } else {
                            "0.0.0.0"
                        };
                        let mut bound = None;
                        for p in 8000..9000u16 {
                            if let Ok(l) = tokio::net::TcpListener::bind((ip, p)).await {
                                bound = Some((l, p));
                                break;
                            }
                        }
                        let (l, p) = bound.ok_or("no free port in 8000..9000 for direct links")?;
                        conn.announce_direct_port(i32::from(p));
                        listener = Some(DirectListener {
                            tcp: l,
                            unix: UnixListenerFile::bind(p),
                        });
                        continue;
                    }
                    Some(_) => continue,
                    None => {}
                }
                while let Some(b) = conn.poll_transmit() {
                    io.write_all(&b).await.map_err(|e| e.to_string())?;
                }
                let n = io.read(&mut buf).await.map_err(|e| e.to_string())?;
                if n == 0 {
                    return Err("central closed the connection".into());
                }
                conn.receive(&buf[..n], Instant::now());
            }
        };
        let res: Result<(), String> = match tokio::time::timeout_at(deadline, hs).await {
            Ok(r) => r,
            Err(_) => Err("no answer within the connect timeout".into()),
        };
        res.map_err(|why| ConnectError::Handshake {
            addr: addr.clone(),
            why,
        })?;
        Ok((conn, io, listener))
    }
}

/// Where this module takes direct links: the TCP port it announced and,
/// as C's `x_ipcDirectResource` does, the UNIX socket `/tmp/x_ipc/<port>`.
struct DirectListener {
    tcp: tokio::net::TcpListener,
    unix: Option<UnixListenerFile>,
}

/// A listening UNIX socket whose file is removed when it is dropped.
struct UnixListenerFile {
    listener: tokio::net::UnixListener,
    path: std::path::PathBuf,
}

impl UnixListenerFile {
    /// Listens at `/tmp/x_ipc/<port>`. Like C (`x_ipc_listenAtSocket`) the
    /// directory is created world-writable and a leftover file is replaced;
    /// unlike C a file somebody still answers on is left alone (then only
    /// TCP is offered). `None` (with a warning) when that is not possible:
    /// peers then use TCP, as C ones do when the socket is missing.
    fn bind(port: u16) -> Option<Self> {
        use std::os::unix::fs::PermissionsExt;
        let dir = std::path::Path::new(UNIX_SOCKET_DIR);
        if std::fs::create_dir(dir).is_ok() {
            let _ = std::fs::set_permissions(dir, std::fs::Permissions::from_mode(0o777));
        }
        let path = dir.join(port.to_string());
        if std::os::unix::net::UnixStream::connect(&path).is_ok() {
            tracing::warn!(
                "{} is in use by another process: direct links over TCP only",
                path.display()
            );
            return None;
        }
        let _ = std::fs::remove_file(&path); // stale, from a process that died
        match tokio::net::UnixListener::bind(&path) {
            Ok(listener) => Some(UnixListenerFile { listener, path }),
            Err(e) => {
                tracing::warn!(
                    "cannot listen at {}: {e}; direct links over TCP only",
                    path.display()
                );
                None
            }
        }
    }
}

impl Drop for UnixListenerFile {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.path);
    }
}

/// Directory of C IPC's UNIX sockets (`UNIX_DIR_NAME`).
const UNIX_SOCKET_DIR: &str = "/tmp/x_ipc";

/// Accepts direct links on both sockets until the session's driver is gone
/// (which drops the listeners and removes the UNIX socket's file).
fn spawn_accept(l: DirectListener, tx: mpsc::UnboundedSender<Cmd>) {
    tokio::spawn(async move {
        let DirectListener { tcp, unix } = l;
        loop {
            let accepted: Box<dyn IpcStream> = tokio::select! {
                _ = tx.closed() => break,
                r = tcp.accept() => match r {
                    Ok((s, _)) => match Tcp::new(s) {
                        Ok(s) => Box::new(s),
                        Err(_) => continue,
                    },
                    Err(_) => break,
                },
                r = async {
                    match &unix {
                        Some(u) => u.listener.accept().await,
                        None => std::future::pending().await,
                    }
                } => match r {
                    Ok((s, _)) => Box::new(s),
                    Err(_) => break,
                },
            };
            if tx.send(Cmd::LinkAccepted(accepted)).is_err() {
                break;
            }
        }
        drop(unix);
    });
}

/// Connects to a direct-link receiver as C's `x_ipc_connectAt` does: its
/// UNIX socket first when the host is this machine, else (or when that
/// fails) TCP.
async fn connect_direct(host: &str, port: u16) -> Option<Box<dyn IpcStream>> {
    let local = host == "localhost" || is_local_name(host, &local_host_name());
    if local {
        if let Ok(s) = tokio::net::UnixStream::connect(format!("{UNIX_SOCKET_DIR}/{port}")).await {
            return Some(Box::new(s));
        }
    }
    let host = if local { "127.0.0.1" } else { host };
    let s = tokio::net::TcpStream::connect((host, port)).await.ok()?;
    Some(Box::new(Tcp::new(s).ok()?))
}

/// Writes `bufs` one after the other, with as few system calls as the
/// socket takes (a large message's header and data go out together).
async fn write_all_vectored<W: AsyncWrite + Unpin + ?Sized>(
    w: &mut W,
    bufs: &[Vec<u8>],
) -> std::io::Result<()> {
    /// Slices per call: well under any system's `IOV_MAX`.
    const MAX_SLICES: usize = 64;
    let (mut i, mut off) = (0, 0);
    while i < bufs.len() {
        let slices: Vec<std::io::IoSlice<'_>> = std::iter::once(&bufs[i][off..])
            .chain(bufs[i + 1..].iter().map(|b| &b[..]))
            .take(MAX_SLICES)
            .map(std::io::IoSlice::new)
            .collect();
        let mut n = w.write_vectored(&slices).await?;
        if n == 0 && slices.iter().any(|s| !s.is_empty()) {
            return Err(std::io::ErrorKind::WriteZero.into());
        }
        while i < bufs.len() && off + n >= bufs[i].len() {
            n -= bufs[i].len() - off;
            i += 1;
            off = 0;
        }
        off += n;
    }
    Ok(())
}

impl IpcBackend {
    /// Connects to central and completes the IPC handshake.
    pub async fn connect(url: &str, name: &str, opts: IpcOptions) -> Result<Self, ConnectError> {
        let (host, port) = parse_url(url).map_err(|why| ConnectError::BadUrl {
            url: url.into(),
            why,
        })?;
        let addr = format!("{host}:{port}");
        let (conn, io, listener) = handshake(&host, port, name, &opts).await?;
        let buf = vec![0u8; 64 * 1024];
        let (tx, rx) = mpsc::unbounded_channel();
        let events = Hub::new(crate::hub::DEFAULT_CAPACITY);
        let driver = Driver {
            conn,
            io,
            host,
            port,
            name: name.to_string(),
            opts,
            defs: Vec::new(),
            cmd_tx: tx.clone(),
            addr: addr.clone(),
            events: events.clone(),
            subs: HashMap::new(),
            servers: HashMap::new(),
            publishes: HashMap::new(),
            queries: HashMap::new(),
            replies: HashMap::new(),
            query_ops: HashMap::new(),
            bools: HashMap::new(),
            counts: HashMap::new(),
            closing: None,
            watching_modules: false,
            links: HashMap::new(),
            touched: Vec::new(),
            published: Vec::new(),
            parked: Vec::new(),
        };
        if let Some(l) = listener {
            spawn_accept(l, tx.clone());
        }
        let spin = driver.opts.busy_poll.map(BusyPoll::start);
        tokio::spawn(driver.run(rx, buf, spin));
        Ok(IpcBackend {
            cmd: tx,
            addr,
            events,
            next_query: std::sync::atomic::AtomicU64::new(1),
            next_handle: std::sync::atomic::AtomicU64::new(1),
            names: Default::default(),
            defined: Default::default(),
        })
    }

    fn next_handle(&self) -> u64 {
        self.next_handle
            .fetch_add(1, std::sync::atomic::Ordering::Relaxed)
    }

    fn names(&self) -> std::sync::MutexGuard<'_, HashMap<Handle, Arc<str>>> {
        // every critical section is one map operation
        self.names.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// The message an open publication or client names.
    fn name_of(&self, h: Handle) -> Option<Arc<str>> {
        self.names().get(&h).cloned()
    }

    /// Defines `msg` in central unless this session already did with
    /// the same format.
    async fn define_once(&self, msg: &str, format: Option<&str>) -> Result<(), OpenError> {
        {
            let defined = self.defined.lock().unwrap_or_else(|e| e.into_inner());
            if defined.get(msg).is_some_and(|f| f.as_deref() == format) {
                return Ok(());
            }
        }
        IpcControl::define(self, msg, format).await?;
        self.defined
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .insert(msg.to_string(), format.map(str::to_string));
        Ok(())
    }

    async fn call<T>(&self, f: impl FnOnce(Done<T>) -> Cmd, gone: T) -> T {
        let (tx, rx) = oneshot::channel();
        if self.cmd.send(f(tx)).is_err() {
            return gone;
        }
        rx.await.unwrap_or(gone)
    }

    fn gone<E: Failure>(&self) -> E {
        E::disconnected(self.addr.clone())
    }
}

#[async_trait::async_trait]
impl Backend for IpcBackend {
    fn capabilities(&self) -> Capabilities {
        let mut c = Capabilities::new("ipc://", Encoding::Ipc);
        c.untyped_publications = true;
        c.reply_names = true;
        c.named_formats = true;
        c
    }

    async fn open_publication(
        &self,
        msg: &str,
        ty: &TypeInfo,
        qos: &PublicationQos,
    ) -> Result<PubId, OpenError> {
        if let Some(what) = qos.beyond_ipc() {
            return Err(unsupported(format!("{what} (publication {msg})")));
        }
        // untyped: a message somebody else defines
        if !ty.is_untyped() {
            self.define_once(msg, ty.format).await?;
        }
        let id = PubId(self.next_handle());
        self.names().insert(Handle::Publication(id), Arc::from(msg));
        Ok(id)
    }

    async fn open_subscription(
        &self,
        msg: &str,
        _ty: Option<&TypeInfo>,
        qos: &SubscriptionQos,
        queue: Arc<SampleQueue>,
    ) -> Result<SubId, OpenError> {
        if let Some(what) = qos.beyond_ipc() {
            return Err(unsupported(format!("{what} (subscription {msg})")));
        }
        let id = SubId(self.next_handle());
        let g = Err(self.gone());
        self.call(|d| Cmd::Subscribe(msg.into(), queue, id, d), g)
            .await?;
        Ok(id)
    }

    async fn open_service(
        &self,
        msg: &str,
        _req: &TypeInfo,
        _resp: &TypeInfo,
        queue: usize,
    ) -> Result<(ServiceId, mpsc::Receiver<RawRequest>), OpenError> {
        let (tx, rx) = mpsc::channel(queue.max(1));
        let id = ServiceId(self.next_handle());
        let g = Err(self.gone());
        self.call(|d| Cmd::Serve(msg.into(), tx, id, d), g).await?;
        Ok((id, rx))
    }

    async fn open_client(
        &self,
        msg: &str,
        _req: &TypeInfo,
        _resp: &TypeInfo,
    ) -> Result<ClientId, OpenError> {
        let id = ClientId(self.next_handle());
        self.names().insert(Handle::Client(id), Arc::from(msg));
        Ok(id)
    }

    async fn write(
        &self,
        publication: PubId,
        data: Vec<u8>,
        opts: WriteOptions,
    ) -> Result<(), PublishError> {
        let msg = self
            .name_of(Handle::Publication(publication))
            .ok_or_else(|| PublishError::NoPublication(format!("{publication:?} (closed)")))?;
        if opts.confirm.is_some() {
            return Err(PublishError::Unsupported {
                what: format!("a confirmed publish ({msg})"),
                backend: "ipc://",
            });
        }
        let g = Err(self.gone());
        self.call(|d| Cmd::Publish(msg.to_string(), data, d), g)
            .await
    }

    async fn query(
        &self,
        client: ClientId,
        data: Vec<u8>,
        timeout: Duration,
    ) -> Result<RawReply, QueryError> {
        let Some(msg) = self.name_of(Handle::Client(client)) else {
            return Err(QueryError::Disconnected(format!("{client:?} (closed)")));
        };
        let key = self
            .next_query
            .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let (tx, rx) = oneshot::channel();
        if self
            .cmd
            .send(Cmd::Query(key, msg.to_string(), data, tx))
            .is_err()
        {
            return Err(QueryError::Disconnected(msg.to_string()));
        }
        match tokio::time::timeout(timeout, rx).await {
            Ok(Ok(r)) => r,
            Ok(Err(_)) => Err(QueryError::Disconnected(msg.to_string())),
            Err(_) => {
                let _ = self.cmd.send(Cmd::CancelQuery(key));
                Err(QueryError::Timeout {
                    msg: msg.to_string(),
                    timeout,
                })
            }
        }
    }

    fn close_handle(&self, handle: Handle) {
        match handle {
            Handle::Publication(_) | Handle::Client(_) => {
                self.names().remove(&handle);
            }
            _ => {
                let _ = self.cmd.send(Cmd::CloseHandle(handle));
            }
        }
    }

    fn events(&self) -> Listener<SessionEvent> {
        if !self.events.has_listeners() {
            // central reports module (dis)connections only when asked
            let _ = self.cmd.send(Cmd::WatchModules);
        }
        self.events.listen()
    }

    async fn close(&self) {
        self.call(Cmd::Close, ()).await
    }

    fn ipc(&self) -> Option<&dyn IpcControl> {
        Some(self)
    }
}

#[async_trait::async_trait]
impl IpcControl for IpcBackend {
    async fn define_format(&self, name: &str, format: &str) -> Result<(), OpenError> {
        let g = Err(self.gone());
        self.call(|d| Cmd::DefineFormat(name.into(), format.into(), d), g)
            .await
    }

    async fn define(&self, msg: &str, format: Option<&str>) -> Result<(), OpenError> {
        let g = Err(self.gone());
        self.call(
            |d| Cmd::Define(msg.into(), format.map(str::to_string), d),
            g,
        )
        .await
    }

    async fn is_module_connected(&self, module: &str) -> Result<bool, ControlError> {
        let g = Err(self.gone());
        self.call(|d| Cmd::ModuleConnected(module.into(), d), g)
            .await
    }

    async fn num_handlers(&self, msg: &str) -> Result<i32, ControlError> {
        let g = Err(self.gone());
        self.call(|d| Cmd::NumHandlers(msg.into(), d), g).await
    }

    async fn watch_handlers(&self, msg: &str) -> Result<(), ControlError> {
        let g = Err(self.gone());
        self.call(|d| Cmd::WatchHandlers(msg.into(), d), g).await
    }

    async fn set_capacity(&self, n: i32) -> Result<(), ControlError> {
        let g = Err(self.gone());
        self.call(|d| Cmd::Inform(InformOp::Capacity(n), d), g)
            .await
    }

    async fn set_priority(&self, msg: &str, priority: i32) -> Result<(), ControlError> {
        let g = Err(self.gone());
        self.call(
            |d| Cmd::Inform(InformOp::Priority(msg.into(), priority), d),
            g,
        )
        .await
    }

    async fn set_queue_length(&self, msg: &str, n: i32) -> Result<(), ControlError> {
        let g = Err(self.gone());
        self.call(|d| Cmd::Inform(InformOp::QueueLength(msg.into(), n), d), g)
            .await
    }
}

impl Drop for IpcBackend {
    fn drop(&mut self) {
        let (tx, _) = oneshot::channel();
        let _ = self.cmd.send(Cmd::Close(tx));
    }
}

struct Sub {
    id: SubId,
    msg: String,
    hnd: String,
    queue: Arc<SampleQueue>,
}

struct Server {
    id: ServiceId,
    msg: String,
    hnd: String,
    tx: mpsc::Sender<RawRequest>,
}

/// A definition replayed after a reconnect.
enum Def {
    Format(String, String),
    Msg(String, Option<String>),
}

struct Driver {
    conn: Connection,
    io: Box<dyn IpcStream>,
    host: String,
    port: u16,
    name: String,
    opts: IpcOptions,
    defs: Vec<Def>,
    cmd_tx: mpsc::UnboundedSender<Cmd>,
    addr: String,
    events: Hub<SessionEvent>,
    subs: HashMap<i32, Sub>,
    servers: HashMap<i32, Server>,
    publishes: HashMap<OpId, Done<Result<(), PublishError>>>,
    /// Queries waiting for their reply, with their message name.
    queries: HashMap<OpId, (String, Done<Result<RawReply, QueryError>>)>,
    /// Replies handed to the module, by query delivery, with their reply
    /// message name.
    replies: HashMap<DeliveryId, (String, Done<Result<(), PublishError>>)>,
    query_ops: HashMap<u64, OpId>,
    bools: HashMap<OpId, Done<Result<bool, ControlError>>>,
    counts: HashMap<OpId, Done<Result<i32, ControlError>>>,
    closing: Option<Done<()>>,
    watching_modules: bool,
    links: HashMap<LinkId, LinkWriter>,
    /// Links given frames since the publishes below were last resolved.
    touched: Vec<LinkId>,
    /// Publishes the module has sent, resolved once their frames are queued
    /// (see [`Driver::resolve_published`]).
    published: Vec<PublishDone>,
    /// Publishes waiting for these congested links to drain.
    parked: Vec<(PublishDone, Vec<LinkId>)>,
}

/// Where a publish's result goes.
type PublishDone = Done<Result<(), PublishError>>;

/// The IPC side of one query delivery: answered or declined through the
/// driver.
struct IpcReply {
    cmd: mpsc::UnboundedSender<Cmd>,
    delivery: DeliveryId,
    addr: String,
}

impl Reply for IpcReply {
    fn reply(self: Box<Self>, reply_msg: &str, data: Vec<u8>) -> ReplyFuture {
        let (tx, rx) = oneshot::channel();
        let sent = self
            .cmd
            .send(Cmd::Respond(self.delivery, reply_msg.to_string(), data, tx));
        let addr = self.addr;
        Box::pin(async move {
            sent.map_err(|_| PublishError::Disconnected(addr.clone()))?;
            rx.await.unwrap_or(Err(PublishError::Disconnected(addr)))
        })
    }

    fn decline(self: Box<Self>) {
        let _ = self.cmd.send(Cmd::Decline(self.delivery));
    }
}

fn unsupported(what: String) -> OpenError {
    OpenError::Unsupported {
        what,
        backend: "ipc://",
    }
}

/// Central's refusal of an operation on `what`, as the operation's error.
fn refused<E: Failure>(what: &str) -> impl FnOnce(ModError) -> E + '_ {
    move |e| E::central(what, e)
}

/// A query that could not be sent.
fn query_refused(msg: String, source: PublishError) -> QueryError {
    match source {
        PublishError::Disconnected(_) => QueryError::Disconnected(msg),
        source => QueryError::Refused { msg, source },
    }
}

static HANDLER_SEQ: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(1);

impl Driver {
    async fn run(
        mut self,
        mut rx: mpsc::UnboundedReceiver<Cmd>,
        mut buf: Vec<u8>,
        spin: Option<BusyPoll>,
    ) {
        let mut closed = false;
        loop {
            if let Some(s) = &spin {
                s.activity();
            }
            if self.flush().await.is_err() {
                break;
            }
            self.drain_events();
            if self.flush().await.is_err() {
                break;
            }
            self.resolve_published();
            if self.closing.is_some() && !self.conn.is_waiting() {
                break;
            }
            tokio::select! {
                cmd = rx.recv() => match cmd {
                    Some(c) => self.command(c),
                    None => {
                        let _ = self.conn.close();
                        closed = true;
                    }
                },
                n = self.io.read(&mut buf) => match n {
                    Ok(0) | Err(_) => {
                        if let Some(first) = self.opts.reconnect.filter(|_| self.closing.is_none() && !closed) {
                            if self.reconnect(first, &mut rx).await {
                                continue;
                            }
                        }
                        self.conn.handle_eof();
                        self.drain_events();
                        break;
                    }
                    Ok(n) => self.conn.receive(&buf[..n], Instant::now()),
                },
            }
            if closed && !self.conn.is_waiting() {
                let _ = self.flush().await;
                break;
            }
        }
        let _ = self.io.shutdown().await;
        self.fail_all();
        if let Some(d) = self.closing.take() {
            let _ = d.send(());
        }
    }

    async fn flush(&mut self) -> std::io::Result<()> {
        let mut out = Vec::new();
        while let Some(b) = self.conn.poll_transmit() {
            out.push(b);
        }
        write_all_vectored(&mut self.io, &out).await?;
        // never waits: each link has a writer task of its own
        while let Some((link, b)) = self.conn.poll_direct_transmit() {
            if let Some(w) = self.links.get(&link) {
                if w.send(b) {
                    if !self.touched.contains(&link) {
                        self.touched.push(link);
                    }
                } else {
                    self.links.remove(&link);
                }
            }
        }
        Ok(())
    }

    /// Resolves the publishes the module has sent, but for those whose
    /// frames went to a link that is congested now: they wait until it
    /// drains (back-pressure on the publishers of that link alone).
    fn resolve_published(&mut self) {
        let congested: Vec<LinkId> = self
            .touched
            .drain(..)
            .filter(|l| self.links.get(l).is_some_and(LinkWriter::congested))
            .collect();
        for d in self.published.drain(..) {
            if congested.is_empty() {
                let _ = d.send(Ok(()));
            } else {
                self.parked.push((d, congested.clone()));
            }
        }
    }

    /// Lets go the parked publishes whose links are all uncongested (or
    /// gone) now.
    fn release_parked(&mut self) {
        let links = &self.links;
        for (_, ls) in self.parked.iter_mut() {
            ls.retain(|l| links.get(l).is_some_and(LinkWriter::congested));
        }
        let (done, waiting): (Vec<_>, Vec<_>) = std::mem::take(&mut self.parked)
            .into_iter()
            .partition(|(_, ls)| ls.is_empty());
        self.parked = waiting;
        for (d, _) in done {
            let _ = d.send(Ok(()));
        }
    }

    /// The writer task of a new direct link.
    fn link_writer(&self, link: LinkId, w: tokio::io::WriteHalf<Box<dyn IpcStream>>) -> LinkWriter {
        let (drained, failed) = (self.cmd_tx.clone(), self.cmd_tx.clone());
        LinkWriter::spawn(
            w,
            move || {
                let _ = drained.send(Cmd::LinkDrained(link));
            },
            move || {
                // an empty read is how a link's end reaches the driver
                let _ = failed.send(Cmd::LinkData(link, Vec::new()));
            },
        )
    }

    /// Reads a direct link on its own task, feeding the driver.
    fn spawn_link_reader(&self, link: LinkId, mut r: tokio::io::ReadHalf<Box<dyn IpcStream>>) {
        let tx = self.cmd_tx.clone();
        tokio::spawn(async move {
            let mut buf = vec![0u8; 64 * 1024];
            loop {
                let n = r.read(&mut buf).await.unwrap_or(0);
                if tx.send(Cmd::LinkData(link, buf[..n].to_vec())).is_err() || n == 0 {
                    break;
                }
            }
        });
    }

    /// Unsubscribes the subscription or service of `h` (its
    /// `Subscriber`, `Listener` or `Requests` was dropped).
    fn close_handle(&mut self, h: Handle) {
        let found = match h {
            Handle::Subscription(id) => self
                .subs
                .iter()
                .find(|(_, s)| s.id == id)
                .map(|(k, s)| (*k, s.msg.clone(), s.hnd.clone())),
            Handle::Service(id) => self
                .servers
                .iter()
                .find(|(_, s)| s.id == id)
                .map(|(k, s)| (*k, s.msg.clone(), s.hnd.clone())),
            _ => None,
        };
        if let Some((k, msg, hnd)) = found {
            self.subs.remove(&k);
            self.servers.remove(&k);
            let _ = self.conn.unsubscribe(&msg, &hnd);
        }
    }

    fn command(&mut self, c: Cmd) {
        match c {
            Cmd::DefineFormat(n, f, d) => {
                let _ = d.send(self.conn.define_format(&n, &f).map_err(refused(&n)));
                self.defs.push(Def::Format(n, f));
            }
            Cmd::Define(m, f, d) => {
                let _ = d.send(
                    self.conn
                        .define_msg(&m, MsgLength::Variable, f.as_deref())
                        .map_err(refused(&m)),
                );
                self.defs.push(Def::Msg(m, f));
            }
            Cmd::Publish(m, data, d) => match self.conn.publish(&m, data, -1) {
                Ok(op) => {
                    self.publishes.insert(op, d);
                }
                Err(e) => {
                    let _ = d.send(Err(refused(&m)(e)));
                }
            },
            Cmd::CloseHandle(h) => self.close_handle(h),
            Cmd::Subscribe(m, queue, id, d) => {
                let hnd = format!(
                    "HND-{m}-courier{}",
                    HANDLER_SEQ.fetch_add(1, std::sync::atomic::Ordering::Relaxed)
                );
                let _ = d.send(match self.conn.subscribe(&m, &hnd) {
                    Ok(h) => {
                        self.subs.insert(
                            h,
                            Sub {
                                id,
                                msg: m,
                                hnd,
                                queue,
                            },
                        );
                        Ok(())
                    }
                    Err(e) => Err(refused(&m)(e)),
                });
            }
            Cmd::Serve(m, tx, id, d) => {
                let hnd = format!(
                    "HND-{m}-courier{}",
                    HANDLER_SEQ.fetch_add(1, std::sync::atomic::Ordering::Relaxed)
                );
                let _ = d.send(match self.conn.subscribe(&m, &hnd) {
                    Ok(h) => {
                        self.servers.insert(
                            h,
                            Server {
                                id,
                                msg: m,
                                hnd,
                                tx,
                            },
                        );
                        Ok(())
                    }
                    Err(e) => Err(refused(&m)(e)),
                });
            }
            Cmd::Query(key, m, data, d) => match self.conn.query(&m, data, -1) {
                Ok(op) => {
                    self.queries.insert(op, (m, d));
                    self.query_ops.insert(key, op);
                }
                Err(e) => {
                    let source = refused(&m)(e);
                    let _ = d.send(Err(query_refused(m, source)));
                }
            },
            Cmd::CancelQuery(key) => {
                if let Some(op) = self.query_ops.remove(&key) {
                    self.queries.remove(&op);
                    self.conn.cancel_query(op);
                }
            }
            Cmd::Ack(delivery) => {
                let _ = self.conn.ack(delivery);
            }
            Cmd::Respond(delivery, reply, data, d) => {
                match self.conn.respond(delivery, &reply, data) {
                    Ok(()) => {
                        self.replies.insert(delivery, (reply, d));
                    }
                    Err(e) => {
                        let _ = d.send(Err(refused(&reply)(e)));
                    }
                }
            }
            Cmd::Decline(delivery) => {
                // unknown: answered already, or of a connection since lost
                let _ = self.conn.decline(delivery);
            }
            Cmd::ModuleConnected(m, d) => match self.conn.is_module_connected(&m) {
                Ok(op) => {
                    self.bools.insert(op, d);
                }
                Err(e) => {
                    let _ = d.send(Err(refused(&format!("is_module_connected({m})"))(e)));
                }
            },
            Cmd::NumHandlers(m, d) => match self.conn.num_handlers(&m) {
                Ok(op) => {
                    self.counts.insert(op, d);
                }
                Err(e) => {
                    let _ = d.send(Err(refused(&format!("num_handlers({m})"))(e)));
                }
            },
            Cmd::Inform(op, d) => {
                let (what, r) = match op {
                    InformOp::Capacity(n) => {
                        ("set_capacity".to_string(), self.conn.set_capacity(n))
                    }
                    InformOp::Priority(m, p) => {
                        (format!("set_priority({m})"), self.conn.set_priority(&m, p))
                    }
                    InformOp::QueueLength(m, n) => (
                        format!("set_queue_length({m})"),
                        self.conn.set_queue_length(&m, n),
                    ),
                };
                let _ = d.send(r.map_err(refused(&what)));
            }
            Cmd::LinkAccepted(stream) => {
                let link = self.conn.accept_direct();
                let (r, w) = tokio::io::split(stream);
                let w = self.link_writer(link, w);
                self.links.insert(link, w);
                self.spawn_link_reader(link, r);
            }
            Cmd::LinkConnected(link, Some(stream)) => {
                let (r, w) = tokio::io::split(stream);
                let w = self.link_writer(link, w);
                self.links.insert(link, w);
                self.spawn_link_reader(link, r);
                self.conn.direct_link_up(link);
            }
            Cmd::LinkConnected(link, None) => self.conn.direct_link_failed(link),
            Cmd::LinkData(link, bytes) => {
                if bytes.is_empty() {
                    self.links.remove(&link);
                    self.release_parked();
                } else if let Err(e) = self.conn.receive_direct(link, &bytes) {
                    tracing::warn!("direct link dropped: {e}");
                    self.links.remove(&link);
                    self.release_parked();
                }
            }
            Cmd::LinkDrained(link) => {
                tracing::trace!(?link, "direct link drained");
                self.release_parked();
            }
            Cmd::WatchModules => {
                if !self.watching_modules {
                    self.watching_modules = true;
                    let _ = self.conn.subscribe_connect();
                    let _ = self.conn.subscribe_disconnect();
                }
            }
            Cmd::WatchHandlers(m, d) => {
                let _ = d.send(
                    self.conn
                        .subscribe_handler_change(&m)
                        .map(|_| ())
                        .map_err(refused(&m)),
                );
            }
            Cmd::Close(d) => {
                let _ = self.conn.close();
                self.closing = Some(d);
            }
        }
    }

    fn broadcast(&self, e: SessionEvent) {
        self.events.send(e);
    }

    fn drain_events(&mut self) {
        while let Some(e) = self.conn.poll_event() {
            match e {
                Event::Delivery {
                    delivery,
                    handler,
                    msg,
                    kind,
                    order,
                    data,
                    ..
                } => self.deliver(delivery, handler, msg, kind, order, data),
                Event::Reply {
                    query,
                    reply_msg,
                    order,
                    data,
                } => {
                    self.query_ops.retain(|_, op| *op != query);
                    if let Some((_, d)) = self.queries.remove(&query) {
                        let _ = d.send(Ok((reply_msg, data, order)));
                    }
                }
                Event::Published { op } => {
                    // resolved once its frames are queued (direct links)
                    if let Some(d) = self.publishes.remove(&op) {
                        self.published.push(d);
                    }
                }
                Event::PublishDropped { op, msg } => {
                    // As C: a broadcast nobody subscribes to is not sent.
                    tracing::debug!(%msg, "not sent: central lists no subscriber for it");
                    if let Some(d) = self.publishes.remove(&op) {
                        let _ = d.send(Ok(()));
                    }
                }
                Event::Replied { delivery } => {
                    if let Some((_, d)) = self.replies.remove(&delivery) {
                        let _ = d.send(Ok(()));
                    }
                }
                Event::ReplyFailed { delivery, error } => {
                    // declined by the module: this module keeps receiving
                    match self.replies.remove(&delivery) {
                        Some((reply, d)) => {
                            let _ = d.send(Err(refused(&reply)(error)));
                        }
                        None => tracing::warn!("a reply was declined: {error}"),
                    }
                }
                Event::OpFailed { op, error } => {
                    if let Some(d) = self.publishes.remove(&op) {
                        let _ = d.send(Err(refused("a publish")(error.clone())));
                    }
                    if let Some((msg, d)) = self.queries.remove(&op) {
                        let source = refused(&msg)(error.clone());
                        let _ = d.send(Err(query_refused(msg, source)));
                    }
                    if let Some(d) = self.bools.remove(&op) {
                        let _ = d.send(Err(refused("is_module_connected")(error.clone())));
                    }
                    if let Some(d) = self.counts.remove(&op) {
                        let _ = d.send(Err(refused("num_handlers")(error)));
                    }
                }
                Event::ModuleConnected { op, connected } => {
                    if let Some(d) = self.bools.remove(&op) {
                        let _ = d.send(Ok(connected));
                    }
                }
                Event::NumHandlers { op, count } => {
                    if let Some(d) = self.counts.remove(&op) {
                        let _ = d.send(Ok(count));
                    }
                }
                Event::ModuleConnect(m) => self.broadcast(SessionEvent::ModuleConnected(m)),
                Event::ModuleDisconnect(m) => self.broadcast(SessionEvent::ModuleDisconnected(m)),
                Event::HandlerChange { msg, count } => {
                    self.broadcast(SessionEvent::HandlersChanged { msg, count })
                }
                Event::Undeliverable {
                    handler,
                    msg,
                    kind,
                    error,
                } => {
                    // Counted where the user looks for lost samples.
                    if let Some(sub) = self.subs.get(&handler) {
                        sub.queue.count_dropped();
                    }
                    tracing::warn!(
                        msg = %msg,
                        ?kind,
                        "dropped a message whose body does not hold together: {error}"
                    );
                }
                Event::Closed(_) => {}
                Event::DirectConnect {
                    link, host, port, ..
                } => {
                    let tx = self.cmd_tx.clone();
                    tokio::spawn(async move {
                        let s = match u16::try_from(port) {
                            Ok(p) => connect_direct(&host, p).await,
                            Err(_) => None,
                        };
                        let _ = tx.send(Cmd::LinkConnected(link, s));
                    });
                }
                _ => {}
            }
        }
    }

    fn deliver(
        &mut self,
        delivery: u64,
        handler: i32,
        msg: String,
        kind: DeliveryKind,
        order: ByteOrder,
        data: Vec<u8>,
    ) {
        match kind {
            DeliveryKind::Broadcast => {
                let Some(sub) = self.subs.get(&handler) else {
                    let _ = self.conn.ack(delivery);
                    return;
                };
                // Acknowledged once queued for the subscriber: central's
                // capacity then counts what this module has not yet taken
                // in, and one Subscriber the user does not poll does not
                // stall the others. A full queue (keep-all) acknowledges
                // only when there is room again: back-pressure to central.
                let mut s = RawSample::new(msg, data);
                s.order = order;
                match sub.queue.push(s) {
                    Ok(()) => {
                        let _ = self.conn.ack(delivery);
                    }
                    Err(s) => {
                        let q = sub.queue.clone();
                        let cmd = self.cmd_tx.clone();
                        tokio::spawn(async move {
                            q.push_wait(s).await;
                            let _ = cmd.send(Cmd::Ack(delivery));
                        });
                    }
                }
            }
            DeliveryKind::Query => {
                // A query that raced a re-`serve` goes to the live server.
                let srv = self
                    .servers
                    .get(&handler)
                    .or_else(|| self.servers.values().find(|s| s.msg == msg));
                let Some(srv) = srv else {
                    tracing::warn!("query {msg} for a handler that is gone: declined");
                    let _ = self.conn.decline(delivery);
                    return;
                };
                let r = RawRequest {
                    msg,
                    data,
                    order,
                    respond: Responder::new(IpcReply {
                        cmd: self.cmd_tx.clone(),
                        delivery,
                        addr: self.addr.clone(),
                    }),
                };
                let tx = srv.tx.clone();
                if let Err(mpsc::error::TrySendError::Full(r)) = tx.try_send(r) {
                    tokio::spawn(async move {
                        let _ = tx.send(r).await;
                    });
                }
            }
        }
    }

    /// Central went away: fail what waits, reconnect with backoff, then
    /// define and subscribe everything again. `false` if the session was
    /// closed meanwhile or central is gone for good (see [`Dial`]).
    async fn reconnect(&mut self, first: Duration, rx: &mut mpsc::UnboundedReceiver<Cmd>) -> bool {
        self.fail_pending();
        self.links.clear();
        self.broadcast(SessionEvent::Disconnected);
        let mut wait = first;
        loop {
            let sleep = tokio::time::sleep(wait);
            tokio::pin!(sleep);
            loop {
                tokio::select! {
                    _ = &mut sleep => break,
                    cmd = rx.recv() => match cmd {
                        None => return false,
                        Some(Cmd::Close(d)) => {
                            self.closing = Some(d);
                            return false;
                        }
                        Some(other) => self.reject(other),
                    },
                }
            }
            match handshake(&self.host, self.port, &self.name, &self.opts).await {
                Ok((conn, io, listener)) => {
                    self.conn = conn;
                    self.io = io;
                    if let Some(l) = listener {
                        spawn_accept(l, self.cmd_tx.clone());
                    }
                    for d in &self.defs {
                        let _ = match d {
                            Def::Format(n, f) => self.conn.define_format(n, f),
                            Def::Msg(m, f) => {
                                self.conn.define_msg(m, MsgLength::Variable, f.as_deref())
                            }
                        };
                    }
                    for (_, sub) in std::mem::take(&mut self.subs) {
                        if let Ok(h) = self.conn.subscribe(&sub.msg, &sub.hnd) {
                            self.subs.insert(h, sub);
                        }
                    }
                    for (_, srv) in std::mem::take(&mut self.servers) {
                        if let Ok(h) = self.conn.subscribe(&srv.msg, &srv.hnd) {
                            self.servers.insert(h, srv);
                        }
                    }
                    if self.watching_modules {
                        let _ = self.conn.subscribe_connect();
                        let _ = self.conn.subscribe_disconnect();
                    }
                    self.broadcast(SessionEvent::Reconnected);
                    return true;
                }
                Err(ConnectError::Unreachable { source, .. })
                    if gone_for_good(&self.opts, &source) =>
                {
                    tracing::warn!(
                        "central {} is gone for good ({source}); not reconnecting",
                        self.addr
                    );
                    return false;
                }
                Err(e) => {
                    tracing::debug!("reconnect to {} failed: {e}", self.addr);
                    wait = (wait * 2).min(Duration::from_secs(5));
                }
            }
        }
    }

    /// A command while there is no connection.
    fn reject(&mut self, c: Cmd) {
        let addr = self.addr.clone();
        match c {
            Cmd::DefineFormat(n, f, d) => {
                self.defs.push(Def::Format(n, f));
                let _ = d.send(Ok(()));
            }
            Cmd::Define(m, f, d) => {
                self.defs.push(Def::Msg(m, f));
                let _ = d.send(Ok(()));
            }
            Cmd::Publish(_, _, d) | Cmd::Respond(_, _, _, d) => {
                let _ = d.send(Err(PublishError::Disconnected(addr)));
            }
            Cmd::Subscribe(_, _, _, d) | Cmd::Serve(_, _, _, d) => {
                let _ = d.send(Err(OpenError::Disconnected(addr)));
            }
            Cmd::Inform(_, d) | Cmd::WatchHandlers(_, d) => {
                let _ = d.send(Err(ControlError::Disconnected(addr)));
            }
            Cmd::Query(_, m, _, d) => {
                let _ = d.send(Err(QueryError::Disconnected(m)));
            }
            Cmd::ModuleConnected(_, d) => {
                let _ = d.send(Err(ControlError::Disconnected(addr)));
            }
            Cmd::NumHandlers(_, d) => {
                let _ = d.send(Err(ControlError::Disconnected(addr)));
            }
            Cmd::WatchModules => self.watching_modules = true,
            Cmd::Close(d) => self.closing = Some(d),
            // dropped while disconnected: not subscribed again
            Cmd::CloseHandle(h) => {
                self.subs.retain(|_, s| Handle::Subscription(s.id) != h);
                self.servers.retain(|_, s| Handle::Service(s.id) != h);
            }
            Cmd::CancelQuery(_) | Cmd::Ack(_) | Cmd::Decline(_) | Cmd::LinkAccepted(_) => {}
            Cmd::LinkConnected(..) | Cmd::LinkData(..) | Cmd::LinkDrained(_) => {}
        }
    }

    /// Operations waiting for central fail at once.
    fn fail_pending(&mut self) {
        let addr = &self.addr;
        let waiting = self.publishes.drain().map(|(_, d)| d);
        let sent = self.published.drain(..);
        let parked = self.parked.drain(..).map(|(d, _)| d);
        for d in waiting.chain(sent).chain(parked) {
            let _ = d.send(Err(PublishError::Disconnected(addr.clone())));
        }
        for (_, (msg, d)) in self.queries.drain() {
            let _ = d.send(Err(QueryError::Disconnected(msg)));
        }
        for (_, (_, d)) in self.replies.drain() {
            let _ = d.send(Err(PublishError::Disconnected(addr.clone())));
        }
        self.query_ops.clear();
        for (_, d) in self.bools.drain() {
            let _ = d.send(Err(ControlError::Disconnected(addr.clone())));
        }
        for (_, d) in self.counts.drain() {
            let _ = d.send(Err(ControlError::Disconnected(addr.clone())));
        }
    }

    /// The connection is gone: every waiter learns it at once.
    fn fail_all(&mut self) {
        self.fail_pending();
        for (_, s) in self.subs.drain() {
            s.queue.close();
        }
        // their channels close: the `Requests` streams end with Disconnected
        self.servers.clear();
        self.broadcast(SessionEvent::Disconnected);
        self.events.close();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Takes at most `step` bytes per write, vectored.
    struct Trickle {
        got: Vec<u8>,
        step: usize,
        calls: usize,
    }

    impl AsyncWrite for Trickle {
        fn poll_write(
            self: std::pin::Pin<&mut Self>,
            cx: &mut std::task::Context<'_>,
            buf: &[u8],
        ) -> std::task::Poll<std::io::Result<usize>> {
            self.poll_write_vectored(cx, &[std::io::IoSlice::new(buf)])
        }

        fn poll_write_vectored(
            mut self: std::pin::Pin<&mut Self>,
            _: &mut std::task::Context<'_>,
            bufs: &[std::io::IoSlice<'_>],
        ) -> std::task::Poll<std::io::Result<usize>> {
            self.calls += 1;
            let mut n = 0;
            for b in bufs {
                let k = b.len().min(self.step - n);
                self.got.extend_from_slice(&b[..k]);
                n += k;
                if n == self.step {
                    break;
                }
            }
            std::task::Poll::Ready(Ok(n))
        }

        fn is_write_vectored(&self) -> bool {
            true
        }

        fn poll_flush(
            self: std::pin::Pin<&mut Self>,
            _: &mut std::task::Context<'_>,
        ) -> std::task::Poll<std::io::Result<()>> {
            std::task::Poll::Ready(Ok(()))
        }

        fn poll_shutdown(
            self: std::pin::Pin<&mut Self>,
            _: &mut std::task::Context<'_>,
        ) -> std::task::Poll<std::io::Result<()>> {
            std::task::Poll::Ready(Ok(()))
        }
    }

    #[tokio::test]
    async fn vectored_writes_keep_every_byte_in_order_across_partial_writes() {
        let bufs: Vec<Vec<u8>> = [0usize, 28, 0, 1, 70_000, 3, 0]
            .iter()
            .enumerate()
            .map(|(i, &n)| (0..n).map(|k| (k * 7 + i) as u8).collect())
            .collect();
        let whole = bufs.concat();
        for step in [1, 5, 28, 29, 4096, 1 << 20] {
            let mut w = Trickle {
                got: Vec::new(),
                step,
                calls: 0,
            };
            write_all_vectored(&mut w, &bufs).await.unwrap();
            assert_eq!(w.got, whole, "step {step}");
            if step == 1 << 20 {
                assert_eq!(w.calls, 1, "one call when the socket takes it all");
            }
        }
        let many: Vec<Vec<u8>> = (0..200u8).map(|i| vec![i; 3]).collect();
        let mut w = Trickle {
            got: Vec::new(),
            step: 1 << 20,
            calls: 0,
        };
        write_all_vectored(&mut w, &many).await.unwrap();
        assert_eq!(w.got, many.concat());
        assert_eq!(w.calls, 4, "64 slices per call");
    }

    /// Whether the kernel would acknowledge at once (`TCP_QUICKACK` read
    /// back: not in its "interactive" delayed-ACK mode).
    #[cfg(target_os = "linux")]
    fn acks_at_once(s: &tokio::net::TcpStream) -> bool {
        socket2::SockRef::from(s).tcp_quickack().unwrap()
    }

    /// Drives `ours` (read through `read`) into Linux's interactive mode
    /// with a few small exchanges, then has the peer send `big` bytes and
    /// reads them; returns whether `ours` acknowledges at once afterwards,
    /// and whether it did after the small exchanges.
    #[cfg(target_os = "linux")]
    async fn after_exchanges<S: AsyncRead + AsyncWrite + Unpin>(
        ours: &mut S,
        peer: &mut tokio::net::TcpStream,
        big: usize,
        probe: impl Fn(&S) -> bool,
    ) -> (bool, bool) {
        let mut buf = vec![0u8; 64 * 1024];
        for _ in 0..5 {
            peer.write_all(&[1; 48]).await.unwrap();
            ours.read_exact(&mut buf[..48]).await.unwrap();
            ours.write_all(&[2; 28]).await.unwrap();
            peer.read_exact(&mut buf[..28]).await.unwrap();
        }
        let small = probe(ours);
        peer.write_all(&vec![3; big]).await.unwrap();
        ours.read_exact(&mut buf[..big]).await.unwrap();
        (small, probe(ours))
    }

    /// The C library's 16 KiB send buffers stall on our delayed ACKs (see
    /// [`Tcp`]); the exchange below puts a plain socket in the mode that
    /// delays them, so that the check on `Tcp` cannot pass vacuously.
    #[cfg(target_os = "linux")]
    #[tokio::test]
    async fn tcp_reads_of_bulk_data_are_acknowledged_at_once() {
        let l = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
        let addr = l.local_addr().unwrap();
        let pair = || async {
            let s = tokio::net::TcpStream::connect(addr).await.unwrap();
            let (peer, _) = l.accept().await.unwrap();
            peer.set_nodelay(true).unwrap();
            (s, peer)
        };
        // The kernel leaves the delayed-ACK mode by itself when its 40 ms
        // timer fires; a test thread descheduled that long on a loaded
        // machine would see that, so a few attempts are allowed.
        for _ in 0..5 {
            let (plain, mut peer) = pair().await;
            plain.set_nodelay(true).unwrap();
            let mut plain = plain;
            let (_, plain_after) = after_exchanges(&mut plain, &mut peer, 8192, acks_at_once).await;

            let (s, mut peer) = pair().await;
            let mut ours = Tcp::new(s).unwrap();
            let (small, after) =
                after_exchanges(&mut ours, &mut peer, 8192, |t: &Tcp| acks_at_once(&t.s)).await;
            if plain_after || small {
                continue;
            }
            assert!(after, "bulk data read through Tcp left the ACK delayed");
            return;
        }
        panic!(
            "the exchange never left a plain socket (or Tcp after small messages) in \
             delayed-ACK mode: this test would check nothing"
        );
    }

    #[test]
    fn urls() {
        assert_eq!(
            parse_url("ipc://127.0.0.1:1400").unwrap(),
            ("127.0.0.1".into(), 1400)
        );
        assert_eq!(parse_url("ipc://host").unwrap(), ("host".into(), 1381));
        assert!(parse_url("tcp://x").unwrap_err().contains("ipc://"));
        assert!(parse_url("ipc://h:0").unwrap_err().contains("not a port"));
        assert!(parse_url("ipc://h:99999")
            .unwrap_err()
            .contains("not a port"));
    }

    #[test]
    fn local_names() {
        assert!(is_local_name("vm", "vm"));
        assert!(is_local_name("vm", "vm.example.org"));
        assert!(!is_local_name("v", "vm"));
        assert!(!is_local_name("127.0.0.1", "vm"));
    }
}
