//! Losing central: failing what waits, reconnecting with backoff and
//! restoring definitions and subscriptions.

use super::driver::Def;
use super::*;

impl Driver {
    /// Central went away: fail what waits, reconnect with backoff, then
    /// define and subscribe everything again. `false` if the session was
    /// closed meanwhile or central is gone for good (see [`Dial`]).
    pub(super) async fn reconnect(&mut self, first: Duration, rx: &mut Inbox<Cmd>) -> bool {
        self.fail_pending();
        self.links.clear();
        self.broadcast(SessionEvent::Disconnected);
        self.reported_down = true;
        let mut wait = first;
        loop {
            let sleep = tokio::time::sleep(wait);
            tokio::pin!(sleep);
            loop {
                tokio::select! {
                    _ = &mut sleep => break,
                    cmd = rx.recv() => if !self.take_while_down(cmd) {
                        return false;
                    },
                }
            }
            // No connection while the dial runs (it retries a refused
            // connection for up to the connect timeout): what comes fails
            // at once, as during the wait above, instead of queueing
            // behind the attempt (a control loop's publishes waited ~5 s).
            let dialled = {
                let (host, port, opts) = (self.host.clone(), self.port, self.opts.clone());
                let deadline = crate::deadline::after(opts.connect_timeout);
                let attempt = async move { dial(&host, port, &opts, deadline).await };
                tokio::pin!(attempt);
                loop {
                    tokio::select! {
                        r = &mut attempt => break r,
                        cmd = rx.recv() => if !self.take_while_down(cmd) {
                            return false;
                        },
                    }
                }
            };
            // Connected: what comes now waits for the handshake (within
            // the connect timeout), then goes to the new connection.
            let connected = match dialled {
                Ok(io) => {
                    let deadline = crate::deadline::after(self.opts.connect_timeout);
                    greet(io, &self.host, self.port, &self.name, &self.opts, deadline).await
                }
                Err(e) => Err(e),
            };
            match connected {
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
                            // the new central's definition may differ
                            let sub = super::driver::Sub {
                                format: None,
                                ..sub
                            };
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
                    // a new central (or the same, back): not the silent one
                    self.central_reads
                        .fetch_add(1, std::sync::atomic::Ordering::AcqRel);
                    self.broadcast(SessionEvent::Reconnected);
                    self.reported_down = false;
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

    /// A command (`None`: the last handle is gone) while there is no
    /// connection: `false` when the session ends.
    fn take_while_down(&mut self, cmd: Option<Cmd>) -> bool {
        match cmd {
            None => false,
            Some(Cmd::Close(d)) => {
                self.closing = Some(d);
                false
            }
            Some(other) => {
                self.reject(other);
                true
            }
        }
    }

    /// A command while there is no connection.
    pub(super) fn reject(&mut self, c: Cmd) {
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
            Cmd::Ask(_, d) => {
                let _ = d.send(Err(ControlError::Disconnected(addr)));
            }
            Cmd::MsgInfo(_, d) | Cmd::LookUp(_, d) => {
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
    pub(super) fn fail_pending(&mut self) {
        let addr = &self.addr;
        let waiting = self.publishes.drain().map(|(_, d)| d);
        let sent = self.published.drain(..);
        let parked = self.parked.drain(..).map(|(d, _)| d);
        for d in waiting.chain(sent).chain(parked) {
            let _ = d.send(Err(PublishError::Disconnected(addr.clone())));
        }
        for (_, (_, msg, d)) in self.queries.drain() {
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
        for (_, d) in self.registering.drain() {
            let _ = d.send(Err(OpenError::Disconnected(addr.clone())));
        }
        for (_, d) in self.look_ups.drain() {
            let _ = d.send(Err(ControlError::Disconnected(addr.clone())));
        }
        for (_, (_, d)) in self.watch_ops.drain() {
            let _ = d.send(Err(ControlError::Disconnected(addr.clone())));
        }
        for (_, (_, d)) in self.asks.drain() {
            let _ = d.send(Err(ControlError::Disconnected(addr.clone())));
        }
    }

    /// The connection is gone: every waiter learns it at once.
    pub(super) fn fail_all(&mut self) {
        self.fail_pending();
        for (_, s) in self.subs.drain() {
            s.queue.close();
        }
        // their channels close: the `Requests` streams end with Disconnected
        self.servers.clear();
        // once: a reconnect that gave up has said it already
        if !std::mem::replace(&mut self.reported_down, true) {
            self.broadcast(SessionEvent::Disconnected);
        }
        self.events.close();
    }
}
