//! What the module state machine reports, handed out: deliveries to
//! subscribers and servers, operation results, central's notices.

use super::*;

impl Driver {
    pub(super) fn broadcast(&self, e: SessionEvent) {
        self.events.send(e);
    }

    pub(super) fn drain_events(&mut self) {
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
                    if let Some((key, _, d)) = self.queries.remove(&query) {
                        self.query_ops.remove(&key);
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
                    if let Some((key, msg, d)) = self.queries.remove(&op) {
                        self.query_ops.remove(&key);
                        let source = refused(&msg)(error.clone());
                        let _ = d.send(Err(query_refused(msg, source)));
                    }
                    if let Some(d) = self.bools.remove(&op) {
                        let _ = d.send(Err(refused("is_module_connected")(error.clone())));
                    }
                    if let Some((what, d)) = self.asks.remove(&op) {
                        let _ = d.send(Err(refused(what)(error.clone())));
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
                Event::CentralAnswer { op, answer } => {
                    if let Some((_, d)) = self.asks.remove(&op) {
                        let _ = d.send(Ok(answer));
                    }
                }
                Event::LookedUp { op, info } => {
                    if let Some(d) = self.look_ups.remove(&op) {
                        let _ = d.send(Ok(info));
                    }
                }
                Event::NumHandlers { op, count } => {
                    if let Some(d) = self.counts.remove(&op) {
                        let _ = d.send(Ok(count));
                    } else if let Some(d) = self.registering.remove(&op) {
                        let _ = d.send(Ok(()));
                    } else if let Some((msg, d)) = self.watch_ops.remove(&op) {
                        // as C's IPC_subscribeHandlerChange: a message
                        // central does not know is an error, not a watch
                        // that never reports
                        let known = self.conn.msg_info(&msg).is_some_and(|i| i.id != 0);
                        if !known {
                            // undone, so that a watch after the definition
                            // registers anew
                            let w = format!("V_watch_{msg}");
                            let _ = self.conn.unsubscribe(&w, &w);
                        }
                        let _ = d.send(if known {
                            Ok(())
                        } else {
                            Err(ControlError::Central {
                                what: format!("watch_handlers({msg}): define the message first"),
                                source: courier_wire::ipc::module::Error::UnknownMessage(msg),
                            })
                        });
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
                Event::Closed(None) => {}
                Event::Closed(Some(e)) => {
                    // the module gave up on what central sent: say why, as
                    // nothing else will (the session ends, or reconnects)
                    tracing::error!(central = %self.addr, "closing the connection to central: {e}");
                    self.failed = true;
                }
                Event::DirectConnect {
                    link, host, port, ..
                } => {
                    let tx = self.cmd_tx.clone();
                    tokio::spawn(async move {
                        let s = match u16::try_from(port) {
                            Ok(p) => connect_direct(&host, p).await,
                            Err(_) => None,
                        };
                        // one per link
                        let _ = tx.post(Cmd::LinkConnected(link, s));
                    });
                }
                _ => {}
            }
        }
    }

    pub(super) fn deliver(
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
                let Some(sub) = self.subs.get_mut(&handler) else {
                    let _ = self.conn.ack(delivery);
                    // (else an unsubscribe crossed it)
                    let served = self.servers.values().any(|s| s.msg == msg);
                    if served && self.published_to_servers.insert(msg.clone()) {
                        tracing::warn!(
                            "{msg} was published to this session, which serves it (takes \
                             queries) and does not subscribe to it: dropped, and every later \
                             publish of it (its publisher wants query(), or this session \
                             subscribe())"
                        );
                    }
                    return;
                };
                // Acknowledged once queued for the subscriber: central's
                // capacity then counts what this module has not yet taken
                // in, and one Subscriber the user does not poll does not
                // stall the others. A full queue (keep-all) acknowledges
                // only when there is room again: back-pressure to central
                // (and, in direct mode, to the link through its credit).
                let conn = &self.conn;
                let format = sub.format.get_or_insert_with(|| {
                    let info = conn.msg_info(&msg)?;
                    info.res_format.as_ref().map(|f| Arc::from(f.to_string()))
                });
                let mut s = RawSample::new(msg, data);
                s.order = order;
                s.type_name = format.clone();
                let credit = self.read_credit.clone();
                let was_waiting = sub.overflow.is_waiting();
                if sub
                    .overflow
                    .push(&sub.queue, s, delivery, credit, &self.cmd_tx)
                {
                    let _ = self.conn.ack(delivery);
                } else if sub.overflow.waiting_from_central()
                    > self.conn.capacity() + courier_wire::ipc::module::MAX_SENT_AHEAD
                {
                    // central does not wait for acknowledgements: a protocol
                    // breach, not data to keep without end
                    tracing::error!(
                        central = %self.addr,
                        "closing the connection to central: it sent {} deliveries for a full \
                         subscription of {} without waiting for their acknowledgements (this \
                         module's capacity is {})",
                        sub.overflow.waiting_from_central(),
                        sub.msg,
                        self.conn.capacity()
                    );
                    self.failed = true;
                } else if !was_waiting {
                    // the first held back: everything of the session waits
                    let full = SessionEvent::SubscriberFull {
                        msg: sub.msg.clone(),
                        queued: sub.queue.len(),
                    };
                    tracing::warn!(
                        "the queue of a subscription of {} is full: this session takes \
                         nothing more from central until it is read",
                        sub.msg
                    );
                    self.broadcast(full);
                }
            }
            DeliveryKind::Query => {
                // A query that raced a re-`serve` goes to the live server.
                let key = if self.servers.contains_key(&handler) {
                    Some(handler)
                } else {
                    self.servers
                        .iter()
                        .find(|(_, s)| s.msg == msg)
                        .map(|(k, _)| *k)
                };
                let srv = key.and_then(|k| self.servers.get_mut(&k));
                let Some(srv) = srv else {
                    tracing::warn!("query {msg} for a handler that is gone: declined");
                    let _ = self.conn.decline(delivery);
                    return;
                };
                let conn = &self.conn;
                let format = srv
                    .format
                    .get_or_insert_with(|| {
                        let info = conn.msg_info(&msg)?;
                        info.res_format.as_ref().map(|f| Arc::from(f.to_string()))
                    })
                    .clone();
                let r = RawRequest {
                    msg,
                    data,
                    order,
                    format,
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
}
