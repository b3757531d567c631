//! The CMU IPC backend: one tokio task drives the sans-I/O module state
//! machine (`courier_wire::ipc::module`) over TCP or the UNIX socket
//! `/tmp/x_ipc/<port>`; API calls reach it over a channel.

mod connect;
mod direct;
mod driver;
mod events;
mod overflow;
mod reconnect;
mod transport;
mod unix_stream;

pub use transport::IpcStream;

use connect::{dial, gone_for_good, greet, handshake};
use direct::{connect_direct, spawn_accept, DirectListener};
use driver::{Cmd, Done, Driver, InformOp};
use transport::{write_all_vectored, Tcp};
use unix_stream::Unix;

use std::collections::HashMap;
use std::sync::Arc;
use std::time::{Duration, Instant};

use futures::future::BoxFuture;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::sync::{mpsc, oneshot, OwnedSemaphorePermit, Semaphore};

use crate::backend::{
    Backend, Capabilities, ClientId, Handle, IpcControl, PubId, ServiceId, SubId,
};
use crate::busy_poll::BusyPoll;
use crate::direct_link::LinkWriter;
use crate::error::{ControlError, Failure, OpenError, PublishError, TimedOut};
use crate::hub::{Hub, Listener};
use crate::mailbox::{mailbox, Inbox, Mailbox};
use crate::qos::{PublicationQos, SubscriptionQos, TypeInfo};
use crate::session::{
    ConnectError, Encoding, QueryError, RawReply, RawRequest, RawSample, Reply, ReplyFuture,
    Responder, SampleQueue, SessionEvent, WriteOptions,
};
use courier_wire::ipc::introspect::{Answer, Ask};
use courier_wire::ipc::module::{
    Connection, DeliveryId, DeliveryKind, Error as ModError, Event, LinkId, ModuleConfig, MsgInfo,
    MsgLength, OpId,
};
use courier_wire::ipc::ByteOrder;

/// The C library's default central port.
pub const DEFAULT_PORT: u16 = 1381;

/// How long an IPC session waits for central to answer a definition,
/// subscription, lookup or other question before the call fails with a
/// `Timeout` error naming it. Publishing is not bounded by it: a publish
/// waits while central holds this module back for memory.
pub const CENTRAL_ANSWER_TIMEOUT: Duration = Duration::from_secs(10);

/// Options of the IPC backend.
#[derive(Debug, Clone)]
#[non_exhaustive]
pub struct IpcOptions {
    /// `false` = `IPC_connectNoListen`.
    pub listen: bool,
    /// Largest frame sent or taken (a message's data may be
    /// [`FRAME_ROOM`](courier_wire::ipc::module::FRAME_ROOM) less): 256 MiB
    /// by default, as Courier's central takes.
    pub max_frame: u64,
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
            max_frame: courier_wire::ipc::module::DEFAULT_MAX_FRAME,
            connect_timeout: Duration::from_secs(5),
            reconnect: None,
            busy_poll: None,
            dial: None,
        }
    }
}

/// A session's connection to an IPC central.
pub struct IpcBackend {
    cmd: Mailbox<Cmd>,
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
    /// Tells the driver to give up a write central does not take (close).
    stop: Arc<tokio::sync::Notify>,
    /// Reads from central so far (the driver counts them, and a new
    /// connection counts as one).
    central_reads: Arc<std::sync::atomic::AtomicU64>,
    /// `central_reads` when a question that then went unanswered for
    /// [`CENTRAL_ANSWER_TIMEOUT`] was asked (`u64::MAX`: none): while central
    /// has sent nothing since, later questions fail at once rather than
    /// each waiting the bound again behind the first (the connection
    /// answers them in order).
    silent_since: std::sync::atomic::AtomicU64,
    /// The runtime the session was made on: the timer of a question is made
    /// there when it is asked from a thread outside any runtime.
    rt: tokio::runtime::Handle,
}

/// What undoes an operation whose future is dropped half-way (a `timeout`
/// or `select!` cancelled it): posted to the driver on drop, unless
/// [`done`](Undo::done). Without it a cancelled `subscribe` left a
/// subscription nobody reads, whose full queue then held every delivery to
/// the module; a cancelled `serve` kept the message served for ever; a
/// dropped query stayed pending in the driver and the module.
struct Undo<'a> {
    cmd: &'a Mailbox<Cmd>,
    undo: Option<Cmd>,
}

impl<'a> Undo<'a> {
    fn new(cmd: &'a Mailbox<Cmd>, undo: Cmd) -> Self {
        Undo {
            cmd,
            undo: Some(undo),
        }
    }

    /// The operation ended (either way): nothing to undo.
    fn done(mut self) {
        self.undo = None;
    }
}

impl Drop for Undo<'_> {
    fn drop(&mut self) {
        if let Some(c) = self.undo.take() {
            // (commands are taken in order: after the operation's own)
            let _ = self.cmd.post(c);
        }
    }
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
    // the scheme is case-insensitive, as in every URL
    let rest = match url.get(..6) {
        Some(s) if s.eq_ignore_ascii_case("ipc://") => &url[6..],
        _ => return Err("expected ipc://host:port".to_string()),
    };
    let rest = rest.trim_end_matches('/');
    let spec = if rest.is_empty() {
        std::env::var("CENTRALHOST").unwrap_or_else(|_| "localhost".into())
    } else {
        rest.to_string()
    };
    let port = |p: &str| {
        p.parse::<u16>()
            .ok()
            .filter(|p| *p > 0)
            .ok_or_else(|| format!("'{p}' is not a port number"))
    };
    // an IPv6 address in brackets: [::1], [::1]:1381
    if let Some(v6) = spec.strip_prefix('[') {
        let (host, after) = v6
            .split_once(']')
            .ok_or_else(|| format!("'{spec}': '[' without its ']'"))?;
        let port = match after {
            "" => DEFAULT_PORT,
            a => port(
                a.strip_prefix(':')
                    .ok_or_else(|| format!("'{spec}': expected :port after the ']'"))?,
            )?,
        };
        return Ok((host.to_string(), port));
    }
    if spec.matches(':').count() > 1 {
        return Err(format!(
            "'{spec}': an IPv6 address goes in brackets, as in ipc://[::1]:1381"
        ));
    }
    match spec.rsplit_once(':') {
        Some((h, p)) => Ok((
            if h.is_empty() {
                "localhost".into()
            } else {
                h.into()
            },
            port(p)?,
        )),
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

impl IpcBackend {
    /// Connects to central and completes the IPC handshake.
    pub async fn connect(url: &str, name: &str, opts: IpcOptions) -> Result<Self, ConnectError> {
        let (host, port) = parse_url(url).map_err(|why| ConnectError::BadUrl {
            url: url.into(),
            why,
        })?;
        let addr = host_port(&host, port);
        let (conn, io, listener) = handshake(&host, port, name, &opts).await?;
        let buf = vec![0u8; 64 * 1024];
        let (tx, rx) = mailbox(crate::mailbox::CAPACITY);
        let events = Hub::new(crate::hub::DEFAULT_CAPACITY);
        let stop = Arc::new(tokio::sync::Notify::new());
        let central_reads = Arc::new(std::sync::atomic::AtomicU64::new(0));
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
            published_to_servers: Default::default(),
            publishes: HashMap::new(),
            queries: HashMap::new(),
            replies: HashMap::new(),
            query_ops: HashMap::new(),
            bools: HashMap::new(),
            counts: HashMap::new(),
            registering: HashMap::new(),
            watch_ops: HashMap::new(),
            look_ups: HashMap::new(),
            asks: HashMap::new(),
            closing: None,
            watching_modules: false,
            links: HashMap::new(),
            touched: Vec::new(),
            published: Vec::new(),
            parked: Vec::new(),
            read_credit: None,
            failed: false,
            stop: stop.clone(),
            reported_down: false,
            close_by: None,
            central_reads: central_reads.clone(),
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
            stop,
            central_reads,
            silent_since: std::sync::atomic::AtomicU64::new(u64::MAX),
            rt: tokio::runtime::Handle::current(),
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
        if self.cmd.send(f(tx)).await.is_err() {
            return gone;
        }
        rx.await.unwrap_or(gone)
    }

    /// [`call`](Self::call) for an operation central answers: an error
    /// naming `what` after [`CENTRAL_ANSWER_TIMEOUT`] without one (audit 22:
    /// a central that stopped answering left `subscriber().build()`,
    /// `courier echo` and `courier list` waiting for ever, printing nothing).
    /// The operation stays queued in the connection, which waits for
    /// central's answer before anything else; the caller undoes it.
    async fn ask<T, E: Failure + TimedOut>(
        &self,
        what: impl FnOnce() -> String,
        f: impl FnOnce(Done<Result<T, E>>) -> Cmd,
    ) -> Result<T, E> {
        use std::sync::atomic::Ordering::{Acquire, Release};
        let gone = Err(self.gone());
        let reads = self.central_reads.load(Acquire);
        let silent = self.silent_since.load(Acquire) == reads;
        let bound = if silent {
            Duration::ZERO
        } else {
            CENTRAL_ANSWER_TIMEOUT
        };
        // (the timer is made on the session's runtime: a plain thread
        // awaiting this has none)
        let timed = {
            let _in = tokio::runtime::Handle::try_current()
                .is_err()
                .then(|| self.rt.enter());
            tokio::time::timeout(bound, self.call(f, gone))
        };
        match timed.await {
            Ok(r) => r,
            Err(_) if silent => Err(E::timed_out(
                format!(
                    "{} (central has sent nothing since an earlier question went unanswered)",
                    what()
                ),
                CENTRAL_ANSWER_TIMEOUT,
            )),
            Err(_) => {
                // (an answer that came meanwhile moved `central_reads` on:
                // the mark then says nothing)
                self.silent_since.store(reads, Release);
                Err(E::timed_out(what(), CENTRAL_ANSWER_TIMEOUT))
            }
        }
    }

    /// [`ask`](Self::ask) opening `handle`: closed again if the call is
    /// dropped before its answer, or times out (the close goes after it).
    async fn open(
        &self,
        handle: Handle,
        what: impl FnOnce() -> String,
        f: impl FnOnce(Done<Result<(), OpenError>>) -> Cmd,
    ) -> Result<(), OpenError> {
        let undo = Undo::new(&self.cmd, Cmd::CloseHandle(handle));
        let r = self.ask(what, f).await;
        if !matches!(r, Err(OpenError::Timeout { .. })) {
            undo.done();
        }
        r
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
        named(msg)?;
        if let Some(what) = qos.beyond_ipc() {
            return Err(unsupported(format!("{what} (publication {msg})")));
        }
        ipc_format(msg, ty)?;
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
        ty: Option<&TypeInfo>,
        qos: &SubscriptionQos,
        queue: Arc<SampleQueue>,
    ) -> Result<SubId, OpenError> {
        named(msg)?;
        if let Some(what) = qos.beyond_ipc() {
            return Err(unsupported(format!("{what} (subscription {msg})")));
        }
        if let Some(ty) = ty {
            ipc_format(msg, ty)?;
        }
        let id = SubId(self.next_handle());
        self.open(
            Handle::Subscription(id),
            || format!("the subscription to {msg} (central)"),
            |d| Cmd::Subscribe(msg.into(), queue, id, d),
        )
        .await
        .map(|()| id)
    }

    async fn open_service(
        &self,
        msg: &str,
        req: &TypeInfo,
        resp: &TypeInfo,
        queue: usize,
    ) -> Result<(ServiceId, mpsc::Receiver<RawRequest>), OpenError> {
        named(msg)?;
        ipc_format(msg, req)?;
        ipc_format(msg, resp)?;
        let (tx, rx) = mpsc::channel(queue.max(1));
        let id = ServiceId(self.next_handle());
        self.open(
            Handle::Service(id),
            || format!("the service {msg} (central)"),
            |d| Cmd::Serve(msg.into(), tx, id, d),
        )
        .await
        .map(|()| (id, rx))
    }

    async fn open_client(
        &self,
        msg: &str,
        req: &TypeInfo,
        resp: &TypeInfo,
    ) -> Result<ClientId, OpenError> {
        named(msg)?;
        ipc_format(msg, req)?;
        ipc_format(msg, resp)?;
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
        // a query dropped before its answer is given up: the driver and the
        // module forget it (else 300 000 dropped queries held 140 MB)
        let undo = Undo::new(&self.cmd, Cmd::CancelQuery(key));
        if self
            .cmd
            .send(Cmd::Query(key, msg.to_string(), data, tx))
            .await
            .is_err()
        {
            undo.done();
            return Err(QueryError::Disconnected(msg.to_string()));
        }
        let answered = |r: Result<Result<RawReply, QueryError>, _>| {
            r.unwrap_or_else(|_| Err(QueryError::Disconnected(msg.to_string())))
        };
        let mut rx = rx;
        let deadline = crate::deadline::after(timeout);
        // central holds a query nobody serves until a server comes: to say
        // so rather than "no reply", ask central who serves it shortly
        // before the deadline (one more question, on this path only; asked
        // after it, a slow central made the query overshoot its timeout)
        let asked = (timeout / 10).min(Duration::from_secs(1));
        let ask_at = deadline - asked;
        if let Ok(r) = tokio::time::timeout_at(ask_at, &mut rx).await {
            undo.done();
            return answered(r);
        }
        // `None`: central said nothing until the deadline
        let handlers = tokio::select! {
            r = &mut rx => {
                undo.done();
                return answered(r);
            }
            n = IpcControl::num_handlers(self, &msg) => Some(n.ok()),
            () = tokio::time::sleep_until(deadline) => None,
        };
        if let Ok(r) = tokio::time::timeout_at(deadline, &mut rx).await {
            undo.done();
            return answered(r);
        }
        // given up: central and the module forget it
        drop(undo);
        let msg = msg.to_string();
        Err(match handlers {
            Some(Some(0)) => QueryError::NoResponder { msg, timeout },
            None if !asked.is_zero() => QueryError::CentralSilent {
                msg,
                timeout,
                asked,
            },
            _ => QueryError::Timeout { msg, timeout },
        })
    }

    fn close_handle(&self, handle: Handle) {
        match handle {
            Handle::Publication(_) | Handle::Client(_) => {
                self.names().remove(&handle);
            }
            _ => {
                // one per handle
                let _ = self.cmd.post(Cmd::CloseHandle(handle));
            }
        }
    }

    fn events(&self) -> Listener<SessionEvent> {
        if !self.events.has_listeners() {
            // central reports module (dis)connections only when asked
            // the driver subscribes once; one per `events()` call
            let _ = self.cmd.post(Cmd::WatchModules);
        }
        self.events.listen()
    }

    async fn close(&self) {
        self.stop.notify_one();
        self.call(Cmd::Close, ()).await
    }

    fn ipc(&self) -> Option<&dyn IpcControl> {
        Some(self)
    }
}

#[async_trait::async_trait]
impl IpcControl for IpcBackend {
    async fn define_format(&self, name: &str, format: &str) -> Result<(), OpenError> {
        self.ask(
            || format!("the named format {name} (central)"),
            |d| Cmd::DefineFormat(name.into(), format.into(), d),
        )
        .await
    }

    async fn define(&self, msg: &str, format: Option<&str>) -> Result<(), OpenError> {
        self.ask(
            || format!("the definition of {msg} (central)"),
            |d| Cmd::Define(msg.into(), format.map(str::to_string), d),
        )
        .await
    }

    async fn is_module_connected(&self, module: &str) -> Result<bool, ControlError> {
        self.ask(
            || format!("whether module {module} is connected (central)"),
            |d| Cmd::ModuleConnected(module.into(), d),
        )
        .await
    }

    async fn num_handlers(&self, msg: &str) -> Result<i32, ControlError> {
        self.ask(
            || format!("the handler count of {msg} (central)"),
            |d| Cmd::NumHandlers(msg.into(), d),
        )
        .await
    }

    async fn watch_handlers(&self, msg: &str) -> Result<(), ControlError> {
        self.ask(
            || format!("watching the handlers of {msg} (central)"),
            |d| Cmd::WatchHandlers(msg.into(), d),
        )
        .await
    }

    async fn set_capacity(&self, n: i32) -> Result<(), ControlError> {
        at_least("set_capacity", n, 1)?;
        self.ask(
            || format!("set_capacity({n}) (central)"),
            |d| Cmd::Inform(InformOp::Capacity(n), d),
        )
        .await
    }

    async fn set_priority(&self, msg: &str, priority: i32) -> Result<(), ControlError> {
        at_least(&format!("set_priority({msg})"), priority, 0)?;
        self.ask(
            || format!("set_priority({msg}) (central)"),
            |d| Cmd::Inform(InformOp::Priority(msg.into(), priority), d),
        )
        .await
    }

    async fn set_queue_length(&self, msg: &str, n: i32) -> Result<(), ControlError> {
        at_least(&format!("set_queue_length({msg})"), n, 1)?;
        self.ask(
            || format!("set_queue_length({msg}) (central)"),
            |d| Cmd::Inform(InformOp::QueueLength(msg.into(), n), d),
        )
        .await
    }

    async fn ask_central(&self, ask: Ask) -> Result<Answer, ControlError> {
        let what = format!("{ask:?} (central)");
        self.ask(|| what, |d| Cmd::Ask(ask, d)).await
    }

    async fn message_info(&self, msg: &str) -> Result<Option<MsgInfo>, ControlError> {
        self.ask(
            || format!("the definition of {msg} (central)"),
            |d| Cmd::MsgInfo(msg.into(), d),
        )
        .await
    }

    async fn look_up(&self, msg: &str) -> Result<Option<MsgInfo>, ControlError> {
        self.ask(
            || format!("the lookup of {msg} (central)"),
            |d| Cmd::LookUp(msg.into(), d),
        )
        .await
    }
}

/// `host:port`, an IPv6 address in brackets (`[::1]:1381`), as URLs and
/// socket addresses write it.
pub(crate) fn host_port(host: &str, port: u16) -> String {
    if host.contains(':') {
        format!("[{host}]:{port}")
    } else {
        format!("{host}:{port}")
    }
}

/// A message needs a name (C's `IPC_Null_Argument` for an empty one).
fn named(msg: &str) -> Result<(), OpenError> {
    if msg.is_empty() {
        return Err(OpenError::BadName {
            name: String::new(),
            why: "a message needs a name (C: IPC_Null_Argument)",
        });
    }
    Ok(())
}

/// C's range checks (`IPC_setCapacity`, `IPC_setMsgQueueLength`: at
/// least 1; `IPC_setMsgPriority`: at least 0): refused before anything is
/// sent, as C returns `IPC_Argument_Out_Of_Range`.
fn at_least(what: &str, value: i32, min: i32) -> Result<(), ControlError> {
    if value < min {
        return Err(ControlError::OutOfRange {
            what: what.to_string(),
            value: value.into(),
            min: min.into(),
        });
    }
    Ok(())
}

impl Drop for IpcBackend {
    fn drop(&mut self) {
        self.stop.notify_one();
        let (tx, _) = oneshot::channel();
        let _ = self.cmd.post(Cmd::Close(tx));
    }
}

/// The IPC side of one query delivery: answered or declined through the
/// driver.
struct IpcReply {
    cmd: Mailbox<Cmd>,
    delivery: DeliveryId,
    addr: String,
}

impl Reply for IpcReply {
    fn reply(self: Box<Self>, reply_msg: &str, data: Vec<u8>) -> ReplyFuture {
        let (tx, rx) = oneshot::channel();
        // one per query delivery (sent at once: a reply future dropped
        // unpolled must not leave the delivery unanswered)
        let sent = self
            .cmd
            .post(Cmd::Respond(self.delivery, reply_msg.to_string(), data, tx));
        let addr = self.addr;
        Box::pin(async move {
            sent.map_err(|_| PublishError::Disconnected(addr.clone()))?;
            rx.await.unwrap_or(Err(PublishError::Disconnected(addr)))
        })
    }

    fn decline(self: Box<Self>) {
        let _ = self.cmd.post(Cmd::Decline(self.delivery));
    }
}

/// Refuses a type whose format IPC cannot carry: a `Vec` field without
/// `#[ipc(len = "…")]` has the format `<T:0>` (a DDS sequence, CDR only),
/// which names no count field, so neither central nor a C module could
/// read it.
fn ipc_format(msg: &str, ty: &TypeInfo) -> Result<(), OpenError> {
    let Some(f) = ty.format else {
        return Ok(());
    };
    match courier_wire::format::parse(f) {
        Ok(_) => Ok(()),
        Err(e) => {
            let hint = if f.contains(":0>") {
                "; a Vec field needs #[ipc(len = \"count\")] (an integer field that holds its length) to go over IPC"
            } else {
                ""
            };
            Err(unsupported(format!(
                "{msg} as {} (its IPC format {f:?} is not one: {e}{hint})",
                ty.type_name
            )))
        }
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

#[cfg(test)]
mod tests {
    use super::*;

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
        assert_eq!(parse_url("IPC://h:1").unwrap(), ("h".into(), 1));
        assert_eq!(parse_url("ipc://[::1]:1400").unwrap(), ("::1".into(), 1400));
        assert_eq!(parse_url("ipc://[::1]").unwrap(), ("::1".into(), 1381));
        assert!(parse_url("ipc://::1").unwrap_err().contains("in brackets"));
        assert!(parse_url("ipc://[::1")
            .unwrap_err()
            .contains("without its ']'"));
        assert!(parse_url("ipc://[::1]x")
            .unwrap_err()
            .contains(":port after"));
        // and back, as errors name it
        assert_eq!(host_port("::1", 1381), "[::1]:1381");
        assert_eq!(host_port("central.local", 1381), "central.local:1381");
    }

    #[test]
    fn local_names() {
        assert!(is_local_name("vm", "vm"));
        assert!(is_local_name("vm", "vm.example.org"));
        assert!(!is_local_name("v", "vm"));
        assert!(!is_local_name("127.0.0.1", "vm"));
    }
}
