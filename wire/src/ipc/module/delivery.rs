//! Deliveries: messages for our handlers, buffered on arrival and
//! processed one at a time as C's `IPC_listen` does (first looking the
//! handler up), then reported or handled internally and acknowledged.

use std::collections::HashSet;

use super::event::{DeliveryId, DeliveryKind, Event};
use super::proto;
use super::replies::Pending;
use super::{class_order, data_order, proto_err, Connection, Error, LinkId, MAX_QUEUED_DELIVERIES};
use crate::ipc::frame::{Frame, MsgClass, NO_REF};
use crate::ipc::Reader;

#[derive(Debug)]
pub(super) struct Handler {
    pub(super) msg: String,
    pub(super) name: String,
    /// Central has been told (first delivery lookup done).
    pub(super) known: bool,
    pub(super) kind: HandlerKind,
}

#[derive(Debug, Clone, PartialEq)]
pub(super) enum HandlerKind {
    User,
    BroadcastVar,
    ConnectNotify,
    DisconnectNotify,
    Watch(String),
    DirectWatch(String),
}

#[derive(Debug)]
pub(super) struct PendingDelivery {
    pub(super) id: DeliveryId,
    pub(super) frame: Frame,
    pub(super) msg: String,
    pub(super) ready: bool,
    pub(super) link: Option<LinkId>,
}

impl Connection {
    pub(super) fn handle_delivery(&mut self, f: Frame) -> Result<(), Error> {
        if let Err(detail) = self.inbox_room() {
            return Err(Error::Protocol {
                what: "delivery",
                detail,
            });
        }
        if self.is_user_frame(&f) {
            // Central sends no more than the module's capacity (and what
            // it sends ahead) before the module's acknowledgements. One
            // that did not wait, while a handler lookup went unanswered,
            // took a module to 4 GB in 6 s (audit 22).
            let allowed = self.capacity + super::MAX_SENT_AHEAD;
            if self.central_in_inbox >= allowed {
                return Err(Error::Protocol {
                    what: "delivery",
                    detail: format!(
                        "central sent more than {allowed} deliveries this module has not \
                         taken yet (its capacity {} and {} sent ahead): it does not wait for \
                         acknowledgements",
                        self.capacity,
                        super::MAX_SENT_AHEAD
                    ),
                });
            }
            self.central_in_inbox += 1;
        }
        self.inbox.push_back((f, None));
        Ok(())
    }

    /// Whether `f` is for one of the user's handlers (or one it no longer
    /// has), not one of central's notices.
    pub(super) fn is_user_frame(&self, f: &Frame) -> bool {
        self.handlers
            .get(&f.header.intent)
            .is_none_or(|h| h.kind == HandlerKind::User)
    }

    /// Whether `f` may join the deliveries waiting to be processed: at
    /// most [`MAX_QUEUED_DELIVERIES`] of them.
    pub(super) fn inbox_room(&self) -> Result<(), String> {
        if self.inbox.len() >= MAX_QUEUED_DELIVERIES {
            return Err(format!(
                "more than {MAX_QUEUED_DELIVERIES} unprocessed deliveries"
            ));
        }
        Ok(())
    }

    pub(super) fn start_delivery(&mut self, f: Frame, link: Option<LinkId>) -> Result<(), Error> {
        let hid = f.header.intent;
        let Some(h) = self.handlers.get_mut(&hid) else {
            // A delivery racing an unsubscribe: drop it, but free central's
            // capacity slot for a broadcast as the handler would have.
            if link.is_none() && f.header.class_id.msg_class() != Some(MsgClass::Query) {
                self.send_success(f.header.msg_ref);
            }
            return Ok(());
        };
        let msg = if f.class_data.is_empty() {
            h.msg.clone()
        } else {
            let co = class_order(&f.header)?;
            let mut cr = Reader::new(&f.class_data, co);
            cr.read_str()
                .map_err(|e| proto_err("delivery class data", e))?
                .to_string()
        };
        let id = self.next_delivery;
        self.next_delivery += 1;
        let mut ready = true;
        if !h.known {
            h.known = true;
            ready = false;
            let hnd = h.name.clone();
            let r = self.send_lookup(&msg, Some(&hnd), NO_REF);
            self.pending.insert(r, Pending::HandlerLookup(id));
        }
        self.deliveries.push_back(PendingDelivery {
            id,
            frame: f,
            msg,
            ready,
            link,
        });
        self.flush_deliveries();
        Ok(())
    }

    pub(super) fn flush_deliveries(&mut self) {
        while self.deliveries.front().is_some_and(|d| d.ready) {
            let Some(d) = self.deliveries.pop_front() else {
                return;
            };
            if let Err(e) = self.dispatch(d) {
                self.fail(e);
                return;
            }
        }
    }

    pub(super) fn dispatch(&mut self, mut d: PendingDelivery) -> Result<(), Error> {
        let h = d.frame.header;
        let order = data_order(&h)?;
        let kind = match h.class_id.msg_class() {
            Some(MsgClass::Query) => DeliveryKind::Query,
            _ => DeliveryKind::Broadcast,
        };
        let hk = self.handlers.get(&h.intent).map(|x| x.kind.clone());
        // A user handler gets the body itself; central's own messages are
        // small and read from the frame below.
        let body = if matches!(hk, Some(HandlerKind::User) | None) {
            std::mem::take(&mut d.frame.data)
        } else {
            d.frame.data.clone()
        };
        let data = match self.cache.get(&d.msg) {
            Some(info) => proto::unwrap(info, body, order),
            None => Ok(body),
        };
        let data = match (data, &hk) {
            (Ok(data), _) => data,
            (Err(error), Some(HandlerKind::User) | None) => {
                // No Success on direct links (§8).
                let error = match (d.link, error) {
                    (None, e) => {
                        self.send_success(h.msg_ref);
                        e
                    }
                    // (the data came from a direct link, not from central)
                    (Some(_), Error::Protocol { what, detail }) => {
                        Error::DirectLink(format!("undecodable {what}: {detail}"))
                    }
                    (Some(_), e) => e,
                };
                self.events.push_back(Event::Undeliverable {
                    handler: h.intent,
                    msg: d.msg,
                    kind,
                    error,
                });
                return Ok(());
            }
            // Central's own messages must be right.
            (Err(e), _) => return Err(e),
        };
        match hk {
            Some(HandlerKind::User) | None => {
                self.unacked.insert(d.id, (kind, h.msg_ref, d.link));
                self.events.push_back(Event::Delivery {
                    delivery: d.id,
                    handler: h.intent,
                    msg: d.msg,
                    kind,
                    dispatch_ref: h.msg_ref,
                    parent_ref: h.parent_ref,
                    order,
                    data,
                });
                return Ok(());
            }
            Some(HandlerKind::BroadcastVar) => {
                self.set_broadcast_list(proto::decode_str_list(&d.frame.data, order)?);
            }
            Some(HandlerKind::ConnectNotify) | Some(HandlerKind::DisconnectNotify) => {
                let mut r = Reader::new(&d.frame.data, order);
                let m = r
                    .read_str()
                    .map_err(|e| proto_err("connect notification", e))?
                    .to_string();
                self.events
                    .push_back(if hk == Some(HandlerKind::ConnectNotify) {
                        Event::ModuleConnect(m)
                    } else {
                        Event::ModuleDisconnect(m)
                    });
            }
            Some(HandlerKind::DirectWatch(msg)) => {
                let list = proto::decode_direct_handlers(&d.frame.data, order)?;
                let count = list.len() as i32;
                self.set_direct_handlers(&msg, list);
                self.events.push_back(Event::HandlerChange { msg, count });
            }
            Some(HandlerKind::Watch(msg)) => {
                let mut r = Reader::new(&d.frame.data, order);
                let count = if d.frame.data.is_empty() {
                    0
                } else {
                    r.read_i32().map_err(|e| proto_err("V_watch", e))?
                };
                self.events.push_back(Event::HandlerChange { msg, count });
            }
        }
        if kind == DeliveryKind::Broadcast && d.link.is_none() {
            self.send_success(h.msg_ref);
        }
        Ok(())
    }

    pub(super) fn send_success(&mut self, dispatch: i32) {
        self.send_ref(
            NO_REF,
            MsgClass::Success,
            dispatch,
            dispatch,
            Vec::new(),
            Vec::new(),
            Some(NO_REF),
        );
    }

    pub(super) fn alloc_handler(&mut self, msg: &str, hnd: &str, kind: HandlerKind) -> i32 {
        let key = (msg.to_string(), hnd.to_string());
        if let Some(id) = self.by_name.get(&key) {
            return *id;
        }
        let id = match self.retired.remove(&key) {
            Some(id) => id,
            None => {
                let mut id = self.next_handler;
                while self.handlers.contains_key(&id)
                    || self.retired.values().any(|&r| r == id)
                    || id < 2
                {
                    id = if id < 2 { i32::MAX } else { id - 1 };
                }
                self.next_handler = id - 1;
                id
            }
        };
        self.handlers.insert(
            id,
            Handler {
                msg: msg.into(),
                name: hnd.into(),
                known: false,
                kind,
            },
        );
        self.by_name.insert((msg.into(), hnd.into()), id);
        id
    }

    /// Takes central's list of subscribed broadcasts, keeping the messages
    /// it counted handlers for ([`num_handlers`](Self::num_handlers)) until
    /// a list names them.
    ///
    /// Central sends us its list updates one at a time, each after we
    /// acknowledged the previous one, while it answers a count at once: a
    /// count can be newer than the lists still on their way. A publish that
    /// trusted such a list after being told "1 handler" was dropped
    /// unsent. Keeping a counted message costs at worst broadcasts central
    /// discards, until a count of 0 or a list naming it ends the keeping.
    pub(super) fn set_broadcast_list(&mut self, mut list: HashSet<String>) {
        self.counted.retain(|m| !list.contains(m));
        list.extend(self.counted.iter().cloned());
        self.broadcast_var = Some(list);
    }
}
