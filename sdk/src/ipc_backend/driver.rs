//! The session's driver task: one tokio task owns the sans-I/O module
//! state machine and its connection, takes commands from the
//! [`Mailbox`](crate::mailbox) and writes what the machine sends.

use super::*;

pub(super) type Done<T> = oneshot::Sender<T>;

/// Where central's answer to an [`Ask`] goes.
pub(super) type AnswerDone = Done<Result<Answer, ControlError>>;

pub(super) enum Cmd {
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
    /// A question about the other modules and messages.
    Ask(Ask, AnswerDone),
    /// The cached msgInfo of a message.
    MsgInfo(String, Done<Result<Option<MsgInfo>, ControlError>>),
    LookUp(String, Done<Result<Option<MsgInfo>, ControlError>>),
    Inform(InformOp, Done<Result<(), ControlError>>),
    /// Subscribe central's connect/disconnect notifications (once).
    WatchModules,
    /// Direct mode: a peer connected to our listener.
    LinkAccepted(Box<dyn IpcStream>),
    /// Direct mode: our connection to a receiver is up (or failed: None).
    LinkConnected(LinkId, Option<Box<dyn IpcStream>>),
    /// Direct mode: bytes read from a link (empty = closed), with the
    /// read's credit (see [`LINK_READS_IN_FLIGHT`]).
    LinkData(LinkId, Vec<u8>, Option<OwnedSemaphorePermit>),
    /// A congested link's writer has drained to its limit (the link, for
    /// the logs).
    LinkDrained(LinkId),
    /// Subscribe handler-count changes of a message.
    WatchHandlers(String, Done<Result<(), ControlError>>),
    Close(Done<()>),
}

pub(super) enum InformOp {
    Capacity(i32),
    Priority(String, i32),
    QueueLength(String, i32),
}

/// Reads of a direct link handed to the driver and not yet delivered to
/// the subscribers' queues; the link's reader waits beyond this.
pub(super) const LINK_READS_IN_FLIGHT: usize = 4;
/// The most one read of a direct link takes.
pub(super) const LINK_READ_SIZE: usize = 64 * 1024;

pub(super) struct Sub {
    pub(super) id: SubId,
    pub(super) msg: String,
    pub(super) hnd: String,
    pub(super) queue: Arc<SampleQueue>,
    /// Samples waiting for room in `queue`.
    pub(super) overflow: super::overflow::Overflow,
    /// Central's format of `msg`, as looked up for the first delivery
    /// (`None`: not yet); samples carry it for the typed layer's check.
    pub(super) format: Option<Option<Arc<str>>>,
}

pub(super) struct Server {
    pub(super) id: ServiceId,
    pub(super) msg: String,
    pub(super) hnd: String,
    pub(super) tx: mpsc::Sender<RawRequest>,
    /// Central's format of the query message, once looked up.
    pub(super) format: Option<Option<Arc<str>>>,
}

/// A definition replayed after a reconnect.
pub(super) enum Def {
    Format(String, String),
    Msg(String, Option<String>),
}

/// Where a query's answer goes.
pub(super) type QueryDone = Done<Result<RawReply, QueryError>>;

pub(super) struct Driver {
    pub(super) conn: Connection,
    pub(super) io: Box<dyn IpcStream>,
    pub(super) host: String,
    pub(super) port: u16,
    pub(super) name: String,
    pub(super) opts: IpcOptions,
    pub(super) defs: Vec<Def>,
    pub(super) cmd_tx: Mailbox<Cmd>,
    pub(super) addr: String,
    pub(super) events: Hub<SessionEvent>,
    pub(super) subs: HashMap<i32, Sub>,
    pub(super) servers: HashMap<i32, Server>,
    /// Messages published to this session's servers, which take queries
    /// only (each warned of once).
    pub(super) published_to_servers: std::collections::HashSet<String>,
    pub(super) publishes: HashMap<OpId, Done<Result<(), PublishError>>>,
    /// Queries waiting for their reply, with their key in `query_ops` and
    /// their message name.
    pub(super) queries: HashMap<OpId, (u64, String, QueryDone)>,
    /// Replies handed to the module, by query delivery, with their reply
    /// message name.
    pub(super) replies: HashMap<DeliveryId, (String, Done<Result<(), PublishError>>)>,
    pub(super) query_ops: HashMap<u64, OpId>,
    pub(super) bools: HashMap<OpId, Done<Result<bool, ControlError>>>,
    pub(super) counts: HashMap<OpId, Done<Result<i32, ControlError>>>,
    /// Subscriptions and servers whose registration central has not yet
    /// confirmed (by answering the question asked right after it).
    pub(super) registering: HashMap<OpId, Done<Result<(), OpenError>>>,
    /// Lookups waiting for central's answer.
    pub(super) look_ups: HashMap<OpId, Done<Result<Option<MsgInfo>, ControlError>>>,
    /// `watch_handlers` calls waiting for central's first count.
    pub(super) watch_ops: HashMap<OpId, (String, Done<Result<(), ControlError>>)>,
    /// Questions to central, with the message each asks on.
    pub(super) asks: HashMap<OpId, (&'static str, AnswerDone)>,
    pub(super) closing: Option<Done<()>>,
    pub(super) watching_modules: bool,
    pub(super) links: HashMap<LinkId, LinkWriter>,
    /// Links given frames since the publishes below were last resolved.
    pub(super) touched: Vec<LinkId>,
    /// Publishes the module has sent, resolved once their frames are queued
    /// (see [`Driver::resolve_published`]).
    pub(super) published: Vec<PublishDone>,
    /// Publishes waiting for these congested links to drain.
    pub(super) parked: Vec<(PublishDone, Vec<LinkId>)>,
    /// The credit of the direct-link read whose deliveries are being
    /// handed out (until the next [`Driver::drain_events`] is done).
    pub(super) read_credit: Option<Arc<OwnedSemaphorePermit>>,
    /// The module closed the connection itself: central sent something it
    /// refuses (a frame above its limit, bytes that do not decode).
    pub(super) failed: bool,
    /// Notified when the session closes (or its last handle goes): a write
    /// to central that waits for room then gives up, since central may take
    /// nothing more from this module (its subscribers' queues are full).
    pub(super) stop: Arc<tokio::sync::Notify>,
    /// `Disconnected` was reported and `Reconnected` not since.
    pub(super) reported_down: bool,
    /// A close waits for central's answers to what is outstanding until
    /// then ([`CLOSE_WAIT`]).
    pub(super) close_by: Option<tokio::time::Instant>,
    /// Reads from central, counted (see `IpcBackend::silent_since`).
    pub(super) central_reads: Arc<std::sync::atomic::AtomicU64>,
}

/// How long a close waits for central to answer what is outstanding (a
/// lookup, a question): a central that stopped answering held
/// `Session::close` for ever (audit 22).
const CLOSE_WAIT: std::time::Duration = std::time::Duration::from_secs(5);

impl Drop for Driver {
    /// A driver task dropped before it ended (its runtime was shut down
    /// while the session's handles live on): their streams end and their
    /// waiting calls fail, as when central goes, instead of waiting for
    /// ever. After a normal end this finds nothing left to do.
    fn drop(&mut self) {
        self.fail_all();
    }
}

/// Where a publish's result goes.
pub(super) type PublishDone = Done<Result<(), PublishError>>;

impl Driver {
    pub(super) async fn run(
        mut self,
        mut rx: Inbox<Cmd>,
        mut buf: Vec<u8>,
        spin: Option<BusyPoll>,
    ) {
        let mut closed = false;
        loop {
            if let Some(s) = &spin {
                s.activity();
            }
            if let Err(e) = self.flush().await {
                // a write that failed is a lost connection, as a read that
                // failed (central went away with bytes still to send);
                // given up for a close, it is the end
                if e.kind() != std::io::ErrorKind::Interrupted && self.lost(closed, &mut rx).await {
                    continue;
                }
                break;
            }
            self.drain_events();
            self.read_credit = None;
            if std::mem::take(&mut self.failed) {
                // as if central had gone: the socket is of no more use
                if self.lost(closed, &mut rx).await {
                    continue;
                }
                break;
            }
            if let Err(e) = self.flush().await {
                if e.kind() != std::io::ErrorKind::Interrupted && self.lost(closed, &mut rx).await {
                    continue;
                }
                break;
            }
            self.resolve_published();
            if self.closing.is_some() && !self.conn.is_waiting() {
                break;
            }
            if (closed || self.closing.is_some()) && self.close_by.is_none() {
                self.close_by = Some(tokio::time::Instant::now() + CLOSE_WAIT);
            }
            let close_by = self.close_by;
            tokio::select! {
                cmd = rx.recv() => match cmd {
                    Some(c) => self.command(c),
                    None => {
                        let _ = self.conn.close();
                        closed = true;
                    }
                },
                () = tokio::time::sleep_until(close_by.unwrap_or_else(tokio::time::Instant::now)),
                    if close_by.is_some() =>
                {
                    tracing::warn!(
                        "closing without central's answer to what was outstanding: it did not \
                         answer within {CLOSE_WAIT:?}"
                    );
                    let wait = std::time::Duration::from_millis(100);
                    let _ = tokio::time::timeout(wait, self.flush()).await;
                    break;
                }
                n = self.io.read(&mut buf) => match n {
                    Ok(0) | Err(_) => {
                        if self.lost(closed, &mut rx).await {
                            continue;
                        }
                        break;
                    }
                    Ok(n) => {
                        self.central_reads
                            .fetch_add(1, std::sync::atomic::Ordering::AcqRel);
                        self.conn.receive(&buf[..n], Instant::now());
                    }
                },
            }
            if closed && !self.conn.is_waiting() {
                let _ = self.flush().await;
                break;
            }
        }
        // bounded: a socket central does not read may not take a goodbye
        let _ =
            tokio::time::timeout(std::time::Duration::from_millis(100), self.io.shutdown()).await;
        self.fail_all();
        if let Some(d) = self.closing.take() {
            let _ = d.send(());
        }
    }

    /// The connection to central is lost (closed by central, or by the
    /// module over what central sent): reconnects if asked to and the
    /// session is not closing (`true`: go on with the new connection),
    /// else lets what waits know (`false`: the driver ends).
    async fn lost(&mut self, closed: bool, rx: &mut Inbox<Cmd>) -> bool {
        if let Some(first) = self
            .opts
            .reconnect
            .filter(|_| self.closing.is_none() && !closed)
        {
            if self.reconnect(first, rx).await {
                return true;
            }
        }
        self.conn.handle_eof();
        self.drain_events();
        false
    }

    pub(super) async fn flush(&mut self) -> std::io::Result<()> {
        let mut out = Vec::new();
        while let Some(b) = self.conn.poll_transmit() {
            out.push(b);
        }
        let stop = self.stop.clone();
        tokio::select! {
            biased;
            r = write_all_vectored(&mut self.io, &out) => r?,
            () = stop.notified() => {
                return Err(std::io::Error::new(
                    std::io::ErrorKind::Interrupted,
                    "the session closed while central was taking nothing from it",
                ));
            }
        }
        // never waits: each link has a writer task of its own
        while let Some((link, b)) = self.conn.poll_direct_transmit() {
            if let Some(w) = self.links.get(&link) {
                if w.send(b) {
                    if !self.touched.contains(&link) {
                        self.touched.push(link);
                    }
                } else {
                    // its writer ended (the peer left): link anew next time
                    self.links.remove(&link);
                    self.conn.direct_link_closed(link);
                }
            } else {
                tracing::debug!(?link, "a frame for a direct link that closed meanwhile");
            }
        }
        Ok(())
    }

    /// Resolves the publishes the module has sent, but for those whose
    /// frames went to a link that is congested now: they wait until it
    /// drains (back-pressure on the publishers of that link alone).
    pub(super) fn resolve_published(&mut self) {
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
    pub(super) fn release_parked(&mut self) {
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
    pub(super) fn link_writer(
        &self,
        link: LinkId,
        w: tokio::io::WriteHalf<Box<dyn IpcStream>>,
    ) -> LinkWriter {
        let (drained, failed) = (self.cmd_tx.clone(), self.cmd_tx.clone());
        LinkWriter::spawn(
            w,
            move || {
                // once per congestion of the link
                let _ = drained.post(Cmd::LinkDrained(link));
            },
            move || {
                // an empty read is how a link's end reaches the driver
                let _ = failed.post(Cmd::LinkData(link, Vec::new(), None));
            },
        )
    }

    /// Reads a direct link on its own task, feeding the driver. Each read
    /// takes a credit first, given back once what it delivered is in the
    /// subscribers' queues: a sender faster than its subscribers is held
    /// back by TCP, and what this session keeps of a link is bounded.
    pub(super) fn spawn_link_reader(
        &self,
        link: LinkId,
        mut r: tokio::io::ReadHalf<Box<dyn IpcStream>>,
    ) {
        let tx = self.cmd_tx.clone();
        let credits = Arc::new(Semaphore::new(LINK_READS_IN_FLIGHT));
        tokio::spawn(async move {
            let mut buf = vec![0u8; LINK_READ_SIZE];
            loop {
                let credit = tokio::select! {
                    c = credits.clone().acquire_owned() => c.ok(),
                    _ = tx.closed() => None,
                };
                let Some(credit) = credit else { break };
                let n = r.read(&mut buf).await.unwrap_or(0);
                let data = Cmd::LinkData(link, buf[..n].to_vec(), Some(credit));
                if tx.send(data).await.is_err() || n == 0 {
                    break;
                }
            }
        });
    }

    /// Unsubscribes the subscription or service of `h` (its
    /// `Subscriber`, `Listener` or `Requests` was dropped).
    /// A subscription or server of `msg` was registered: `d` is answered
    /// once central has it, by asking central a question right after the
    /// registration (central takes a module's frames in order). Before, a
    /// `subscribe().await` returned when the registration was queued here,
    /// and another module asking `num_handlers` at once could still get 0
    /// and its publish go nowhere.
    fn registered(&mut self, msg: &str, d: Done<Result<(), OpenError>>) {
        match self.conn.num_handlers(msg) {
            Ok(op) => {
                self.registering.insert(op, d);
            }
            // the registration itself was taken: nothing to wait for
            Err(_) => {
                let _ = d.send(Ok(()));
            }
        }
    }

    /// The handler name of a new subscription or server of `m`: the
    /// lowest `HND-<m>-courier<n>` none of the session's live ones has. A
    /// name is reused once its subscription is gone (central, and the
    /// module, keep an unsubscribed handler's record for its name, so new
    /// names for each subscribe-and-drop grew both without bound).
    fn free_handler_name(&self, m: &str) -> String {
        let subs = self.subs.values().filter(|s| s.msg == m).map(|s| &s.hnd);
        let servers = self.servers.values().filter(|s| s.msg == m).map(|s| &s.hnd);
        let used: std::collections::HashSet<&String> = subs.chain(servers).collect();
        (1u64..)
            .map(|n| format!("HND-{m}-courier{n}"))
            .find(|h| !used.contains(h))
            .unwrap_or_default()
    }

    pub(super) fn close_handle(&mut self, h: Handle) {
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

    pub(super) fn command(&mut self, c: Cmd) {
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
                let hnd = self.free_handler_name(&m);
                match self.conn.subscribe(&m, &hnd) {
                    Ok(h) => {
                        self.registered(&m, d);
                        self.subs.insert(
                            h,
                            Sub {
                                id,
                                msg: m,
                                hnd,
                                queue,
                                overflow: Default::default(),
                                format: None,
                            },
                        );
                    }
                    Err(e) => {
                        let _ = d.send(Err(refused(&m)(e)));
                    }
                }
            }
            // one server per message and session, as on DDS: a second
            // would share its queries with the first at random
            Cmd::Serve(m, _, _, d) if self.servers.values().any(|s| s.msg == m) => {
                let _ = d.send(Err(OpenError::AlreadyServed(m)));
            }
            Cmd::Serve(m, tx, id, d) => {
                let hnd = self.free_handler_name(&m);
                match self.conn.subscribe(&m, &hnd) {
                    Ok(h) => {
                        self.registered(&m, d);
                        self.servers.insert(
                            h,
                            Server {
                                id,
                                msg: m,
                                hnd,
                                tx,
                                format: None,
                            },
                        );
                    }
                    Err(e) => {
                        let _ = d.send(Err(refused(&m)(e)));
                    }
                }
            }
            Cmd::Query(key, m, data, d) => match self.conn.query(&m, data, -1) {
                Ok(op) => {
                    self.queries.insert(op, (key, m, d));
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
            Cmd::Ask(a, d) => {
                let what = a.message();
                match self.conn.ask_central(a) {
                    Ok(op) => {
                        self.asks.insert(op, (what, d));
                    }
                    Err(e) => {
                        let _ = d.send(Err(refused(what)(e)));
                    }
                }
            }
            Cmd::MsgInfo(m, d) => {
                let _ = d.send(Ok(self.conn.msg_info(&m).cloned()));
            }
            Cmd::LookUp(m, d) => match self.conn.look_up(&m) {
                Ok(op) => {
                    self.look_ups.insert(op, d);
                }
                Err(e) => {
                    let _ = d.send(Err(refused(&format!("look_up({m})"))(e)));
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
            Cmd::LinkData(link, bytes, credit) => {
                // held by what these bytes deliver (see `deliver`)
                self.read_credit = credit.map(Arc::new);
                if bytes.is_empty() {
                    self.links.remove(&link);
                    self.conn.direct_link_closed(link);
                    self.release_parked();
                } else if let Err(e) = self.conn.receive_direct(link, &bytes) {
                    tracing::warn!("direct link dropped: {e}");
                    self.links.remove(&link);
                    self.conn.direct_link_closed(link);
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
            Cmd::WatchHandlers(m, d) => match self.conn.subscribe_handler_change(&m) {
                // answered once central said whether it knows the message
                Ok(Some(op)) => {
                    self.watch_ops.insert(op, (m, d));
                }
                Ok(None) => {
                    let _ = d.send(Ok(()));
                }
                Err(e) => {
                    let _ = d.send(Err(refused(&m)(e)));
                }
            },
            Cmd::Close(d) => {
                let _ = self.conn.close();
                self.closing = Some(d);
            }
        }
    }
}
