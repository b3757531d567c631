//! The operation queue: API calls run one at a time, in call order, each
//! first looking its message up; the frames they send to central.

use super::event::{DeliveryId, Event, OpId};
use super::proto::{self, MsgInfo};
use super::replies::Pending;
use super::{Connection, Error, LinkId, MsgLength, Stage};
use crate::ipc::frame::{ClassId, Frame, Header, MsgClass, NO_REF, QUERY_REPLY_INTENT};
use crate::ipc::Writer;

#[derive(Debug)]
pub(super) enum Op {
    ClassInfo(i32),
    NewModuleConnect,
    WaitDirectPort,
    DirectRes(i32),
    VarGet(&'static str),
    RegisterHandler {
        id: i32,
        msg: String,
        hnd: String,
    },
    LimitPending {
        msg: String,
        limit: i32,
    },
    WaitMsg,
    DefineFormat {
        name: String,
        fmt: String,
    },
    DefineMsg {
        name: String,
        len: MsgLength,
        fmt: Option<String>,
    },
    Lookup(String),
    DirectQuery {
        msg: String,
    },
    Deregister {
        msg: String,
        hnd: String,
    },
    Publish {
        op: OpId,
        msg: String,
        data: Vec<u8>,
        parent: i32,
    },
    Query {
        op: OpId,
        msg: String,
        data: Vec<u8>,
        parent: i32,
    },
    Respond {
        delivery: DeliveryId,
        msg: String,
        data: Vec<u8>,
        dispatch: i32,
        parent: i32,
        link: Option<LinkId>,
    },
    Inform {
        msg: &'static str,
        data: Vec<u8>,
    },
    ModuleConnectedQ {
        op: OpId,
        module: String,
    },
    Ask {
        op: OpId,
        ask: crate::ipc::introspect::Ask,
    },
    NumHandlers {
        op: OpId,
        msg: String,
    },
    /// Answered by [`Event::LookedUp`] once `msg` is looked up.
    LookUp {
        op: OpId,
        msg: String,
    },
    NotifyHandlerChange {
        msg: String,
    },
    Close,
}

impl Connection {
    pub(super) fn next_msg_ref(&mut self) -> i32 {
        let r = self.next_ref;
        self.next_ref = self.next_ref.wrapping_add(1);
        if self.next_ref < 1 {
            self.next_ref = 1;
        }
        r
    }

    pub(super) fn send(
        &mut self,
        intent: i32,
        class: MsgClass,
        parent: i32,
        class_data: Vec<u8>,
        data: Vec<u8>,
    ) -> i32 {
        self.send_ref(intent, class, parent, NO_REF, class_data, data, None)
    }

    #[allow(clippy::too_many_arguments)]
    pub(super) fn send_ref(
        &mut self,
        intent: i32,
        class: MsgClass,
        parent: i32,
        dispatch: i32,
        class_data: Vec<u8>,
        data: Vec<u8>,
        msg_ref: Option<i32>,
    ) -> i32 {
        let msg_ref = msg_ref.unwrap_or_else(|| self.next_msg_ref());
        let frame = Frame {
            header: Header {
                class_total: 0,
                msg_total: 0,
                parent_ref: parent,
                intent,
                class_id: ClassId::native(class),
                dispatch_ref: dispatch,
                msg_ref,
            },
            class_data,
            data,
        };
        let (head, data) = frame.into_parts();
        self.transmit.push_back(head);
        self.transmit.extend(data);
        msg_ref
    }

    pub(super) fn send_lookup(&mut self, name: &str, hnd: Option<&str>, parent: i32) -> i32 {
        let mut w = Writer::new();
        w.write_str(name);
        w.write_str(hnd.unwrap_or(""));
        let id = self.msg_info_id;
        self.send(id, MsgClass::Query, parent, Vec::new(), w.into_vec())
    }

    pub(super) fn push_op(&mut self, op: Op) {
        self.ops.push_back(op);
        self.pump();
    }

    pub(super) fn alloc_op(&mut self) -> OpId {
        let id = self.next_op;
        self.next_op += 1;
        id
    }

    /// Runs queued operations until one waits for a reply.
    pub(super) fn pump(&mut self) {
        // Like C, an internal handler that is still running (waiting for its
        // msgInfo lookup) finishes before the next API operation runs.
        while self.blocked.is_none() && self.deliveries.is_empty() {
            if matches!(
                self.stage,
                Stage::Closed | Stage::MsgInfoId | Stage::Formatters(_)
            ) {
                return;
            }
            let Some(op) = self.ops.pop_front() else {
                return;
            };
            // Every op needs the id of one message first.
            let need = proto::op_message(&op);
            if let Some(name) = need {
                if !self.cache.contains_key(&name) && !self.unknown.contains(&name) {
                    // C sends the lookup with the parentRef of the
                    // operation (the dispatch being handled, if any).
                    let parent = proto::op_parent(&op);
                    let r = self.send_lookup(&name, None, parent);
                    self.pending.insert(r, Pending::Lookup(name));
                    self.blocked = Some(r);
                    self.ops.push_front(op);
                    return;
                }
            }
            self.execute(op);
        }
    }

    pub(super) fn info(&self, name: &str) -> Option<MsgInfo> {
        self.cache.get(name).cloned()
    }

    fn execute(&mut self, op: Op) {
        let name = proto::op_message(&op).unwrap_or_default();
        let known = self.info(&name);
        let unknown = !name.is_empty() && known.is_none() && self.unknown.remove(&name);
        if let Op::LookUp { op, .. } = op {
            // what central said (nothing: it does not know the message)
            let info = known.filter(|i| i.id != 0);
            self.events.push_back(Event::LookedUp { op, info });
            return;
        }
        let info = known.unwrap_or_default();
        if unknown || (info.id == 0 && !name.is_empty()) {
            // Central does not know the message.
            let err = Error::UnknownMessage(name.clone());
            match op {
                Op::Publish { op, .. }
                | Op::Query { op, .. }
                | Op::ModuleConnectedQ { op, .. }
                | Op::Ask { op, .. }
                | Op::NumHandlers { op, .. } => {
                    self.events.push_back(Event::OpFailed { op, error: err })
                }
                Op::Respond {
                    delivery,
                    dispatch,
                    link,
                    ..
                } => {
                    // The query must not keep this module's capacity in
                    // central forever.
                    if link.is_none() {
                        self.send_success(dispatch);
                    }
                    self.events.push_back(Event::ReplyFailed {
                        delivery,
                        error: err,
                    });
                }
                _ => {
                    if matches!(self.stage, Stage::Handshake) {
                        self.fail(err);
                    }
                }
            }
            return;
        }
        let intent = info.id.abs();
        match op {
            Op::ClassInfo(c) => {
                let mut w = Writer::new();
                w.write_i32(c);
                self.query_blocking(intent, w.into_vec(), Op::ClassInfo(c));
            }
            Op::NewModuleConnect => {
                let mut w = Writer::new();
                w.write_str(&self.cfg.name);
                w.write_str(&self.cfg.host_name);
                self.query_blocking(intent, w.into_vec(), Op::NewModuleConnect);
            }
            Op::WaitDirectPort => {
                // Held until announce_direct_port.
                self.ops.push_front(Op::WaitDirectPort);
                self.blocked = Some(i32::MIN);
            }
            Op::DirectRes(port) => {
                let mut w = Writer::new();
                w.write_i32(port);
                w.write_str(&self.cfg.name);
                self.send(intent, MsgClass::Inform, NO_REF, Vec::new(), w.into_vec());
            }
            Op::VarGet(v) => self.query_blocking(intent, Vec::new(), Op::VarGet(v)),
            Op::RegisterHandler { msg, hnd, id } => {
                let mut w = Writer::new();
                w.write_i32(id);
                w.write_str(&msg);
                w.write_str(&hnd);
                self.send(intent, MsgClass::Inform, NO_REF, Vec::new(), w.into_vec());
            }
            Op::Deregister { msg, hnd } => {
                let mut w = Writer::new();
                w.write_i32(0);
                w.write_str(&msg);
                w.write_str(&hnd);
                self.send(intent, MsgClass::Inform, NO_REF, Vec::new(), w.into_vec());
            }
            Op::LimitPending { msg, limit } => {
                let mut w = Writer::new();
                w.write_str(&msg);
                w.write_str(&self.cfg.name);
                w.write_i32(limit);
                self.send(intent, MsgClass::Inform, NO_REF, Vec::new(), w.into_vec());
            }
            Op::WaitMsg => self.query_blocking(intent, Vec::new(), Op::WaitMsg),
            Op::DefineFormat { name, fmt } => {
                let mut w = Writer::new();
                w.write_str(&name);
                w.write_str(&fmt);
                self.send(intent, MsgClass::Inform, NO_REF, Vec::new(), w.into_vec());
            }
            Op::DefineMsg { name, len, fmt } => {
                let mut w = Writer::new();
                w.write_str(&name);
                w.write_i32(MsgClass::Broadcast as i32);
                match len {
                    MsgLength::Variable => w.write_str("{int, <byte:1>}"),
                    MsgLength::Fixed(n) => w.write_str(&format!("[byte:{n}]")),
                    MsgLength::Empty => w.write_str(""),
                }
                w.write_str(fmt.as_deref().unwrap_or(""));
                self.send(intent, MsgClass::Inform, NO_REF, Vec::new(), w.into_vec());
                // No lookup here (C defers it to the first use); a
                // redefinition may change the formats, so forget the cache.
                self.cache.remove(&name);
            }
            Op::Lookup(_) | Op::LookUp { .. } => {}
            Op::DirectQuery { msg } => {
                let mut w = Writer::new();
                w.write_str(&msg);
                self.query_blocking(intent, w.into_vec(), Op::DirectQuery { msg });
            }
            Op::Publish {
                op,
                msg,
                data,
                parent,
            } => {
                if info.id < 0 {
                    self.direct_send(
                        Op::Publish {
                            op,
                            msg,
                            data,
                            parent,
                        },
                        &info,
                    );
                    return;
                }
                if self.cfg.listen && info.class == MsgClass::Broadcast as i32 {
                    if let Some(list) = &self.broadcast_var {
                        if !list.contains(&msg) {
                            self.events.push_back(Event::PublishDropped { op, msg });
                            return;
                        }
                    }
                }
                match proto::wrap(&info, &msg, data) {
                    Ok(body) => {
                        let class =
                            MsgClass::from_u16(info.class as u16).unwrap_or(MsgClass::Broadcast);
                        self.send(intent, class, parent, Vec::new(), body);
                        self.events.push_back(Event::Published { op });
                    }
                    Err((error, _)) => self.events.push_back(Event::OpFailed { op, error }),
                }
            }
            Op::Query {
                op,
                msg,
                data,
                parent,
            } => {
                if info.id < 0 {
                    self.direct_send(
                        Op::Query {
                            op,
                            msg,
                            data,
                            parent,
                        },
                        &info,
                    );
                    return;
                }
                match proto::wrap(&info, &msg, data) {
                    Ok(body) => {
                        let r = self.send(intent, MsgClass::Query, parent, Vec::new(), body);
                        self.pending.insert(r, Pending::UserQuery(op));
                        self.query_refs.insert(op, r);
                    }
                    Err((error, _)) => self.events.push_back(Event::OpFailed { op, error }),
                }
            }
            Op::Respond {
                delivery,
                msg,
                data,
                dispatch,
                parent,
                link,
            } => {
                self.events.push_back(Event::Replied { delivery });
                let body = proto::wrap(&info, &msg, data).unwrap_or_else(|(_, data)| data);
                let mut cd = Writer::new();
                cd.write_str(&msg);
                if let Some(link) = link {
                    // Direct reply: back on the same link, intent -4,
                    // dispatchRef = msgRef = the query's msgRef (§8).
                    let frame = Frame {
                        header: Header {
                            class_total: 0,
                            msg_total: 0,
                            parent_ref: NO_REF,
                            intent: QUERY_REPLY_INTENT,
                            class_id: ClassId::native(MsgClass::Reply),
                            dispatch_ref: dispatch,
                            msg_ref: dispatch,
                        },
                        class_data: cd.into_vec(),
                        data: body,
                    };
                    self.push_direct(link, frame);
                    return;
                }
                self.send_ref(
                    NO_REF,
                    MsgClass::Reply,
                    parent,
                    dispatch,
                    cd.into_vec(),
                    body,
                    Some(NO_REF),
                );
            }
            Op::Inform { data, .. } => {
                self.send(intent, MsgClass::Inform, NO_REF, Vec::new(), data);
            }
            Op::ModuleConnectedQ { op, module } => {
                let mut w = Writer::new();
                w.write_str(&module);
                self.query_blocking(intent, w.into_vec(), Op::ModuleConnectedQ { op, module });
            }
            Op::Ask { op, ask } => {
                let mut w = Writer::new();
                ask.encode(&mut w);
                self.query_blocking(intent, w.into_vec(), Op::Ask { op, ask });
            }
            Op::NumHandlers { op, msg } => {
                let mut w = Writer::new();
                w.write_str(&msg);
                self.query_blocking(intent, w.into_vec(), Op::NumHandlers { op, msg });
            }
            Op::NotifyHandlerChange { msg } => {
                let mut w = Writer::new();
                w.write_str(&msg);
                self.send(intent, MsgClass::Inform, NO_REF, Vec::new(), w.into_vec());
            }
            Op::Close => {
                self.send(intent, MsgClass::Inform, NO_REF, Vec::new(), Vec::new());
                self.stage = Stage::Closed;
                self.events.push_back(Event::Closed(None));
            }
        }
    }

    fn query_blocking(&mut self, intent: i32, data: Vec<u8>, op: Op) {
        let r = self.send(intent, MsgClass::Query, NO_REF, Vec::new(), data);
        self.pending.insert(r, Pending::Internal(op));
        self.blocked = Some(r);
    }
}
