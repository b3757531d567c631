//! Central's replies: to lookups, to the handshake and other internal
//! queries, and to user queries.

use super::delivery::HandlerKind;
use super::event::{Event, OpId};
use super::ops::Op;
use super::proto;
use super::{class_order, data_order, proto_err, Connection, Error, Stage};
use crate::ipc::frame::{Frame, MsgClass, NO_REF};
use crate::ipc::{ByteOrder, Reader};

/// Whether central's answer to a lookup is a definition, not the
/// placeholder (class `HandlerReg`) it keeps for a message that so far
/// only has handlers.
fn defines(info: &proto::MsgInfo) -> bool {
    info.class != MsgClass::HandlerReg as i32
}

#[derive(Debug)]
pub(super) enum Pending {
    Lookup(String),
    HandlerLookup(u64),
    Internal(Op),
    UserQuery(OpId),
    /// A reply whose message must be looked up before it can be unwrapped.
    ReplyLookup {
        query: OpId,
        reply_msg: String,
        order: ByteOrder,
        data: Vec<u8>,
    },
}

impl Connection {
    pub(super) fn handle_reply(&mut self, f: Frame) -> Result<(), Error> {
        let r = f.header.msg_ref;
        let Some(p) = self.pending.remove(&r) else {
            // Reply to a cancelled query: ignore.
            return Ok(());
        };
        if self.blocked == Some(r) {
            self.blocked = None;
        }
        if let Pending::UserQuery(q) | Pending::ReplyLookup { query: q, .. } = &p {
            self.query_refs.remove(q);
        }
        let order = data_order(&f.header)?;
        match p {
            Pending::Lookup(name) => {
                // Unknown names are not cached (C asks again next time:
                // another module may define the message meanwhile), nor
                // is central's placeholder for a message that only has
                // handlers so far: it is no definition (C's
                // `x_ipc_msgHndFind` asks again while it holds one).
                match proto::decode_msg_info(&f.data, order)?.filter(defines) {
                    Some(info) => {
                        self.cache.insert(name, info);
                    }
                    None => {
                        self.unknown.insert(name);
                    }
                }
            }
            Pending::HandlerLookup(did) => {
                let info = proto::decode_msg_info(&f.data, order)?.filter(defines);
                if let Some(d) = self.deliveries.iter_mut().find(|d| d.id == did) {
                    if let Some(info) = info {
                        // what central says now: a definition made since
                        // an earlier lookup
                        self.cache.insert(d.msg.clone(), info);
                    }
                    d.ready = true;
                }
                self.flush_deliveries();
            }
            Pending::UserQuery(query) => {
                let reply_msg = if f.class_data.is_empty() {
                    String::new()
                } else {
                    let co = class_order(&f.header)?;
                    let mut cr = Reader::new(&f.class_data, co);
                    cr.read_str()
                        .map_err(|e| proto_err("reply class data", e))?
                        .to_string()
                };
                if !reply_msg.is_empty() && !self.cache.contains_key(&reply_msg) {
                    // Like C's msgFind: look the reply message up, then
                    // unmarshall with its format.
                    let r = self.send_lookup(&reply_msg, None, NO_REF);
                    self.query_refs.insert(query, r);
                    self.pending.insert(
                        r,
                        Pending::ReplyLookup {
                            query,
                            reply_msg,
                            order,
                            data: f.data,
                        },
                    );
                } else {
                    let data = match self.cache.get(&reply_msg) {
                        Some(info) => proto::unwrap(info, f.data, order)?,
                        None => f.data,
                    };
                    self.events.push_back(Event::Reply {
                        query,
                        reply_msg,
                        order,
                        data,
                    });
                }
            }
            Pending::ReplyLookup {
                query,
                reply_msg,
                order: data_order,
                data,
            } => {
                if let Some(info) = proto::decode_msg_info(&f.data, order)? {
                    self.cache.insert(reply_msg.clone(), info);
                }
                let data = match self.cache.get(&reply_msg) {
                    Some(info) => proto::unwrap(info, data, data_order)?,
                    None => data,
                };
                self.events.push_back(Event::Reply {
                    query,
                    reply_msg,
                    order: data_order,
                    data,
                });
            }
            Pending::Internal(op) => self.internal_reply(op, &f, order)?,
        }
        self.pump();
        Ok(())
    }

    fn internal_reply(&mut self, op: Op, f: &Frame, order: ByteOrder) -> Result<(), Error> {
        let mut rd = Reader::new(&f.data, order);
        match op {
            Op::ClassInfo(_)
                if !f.data.is_empty()
                    && rd.read_ptr_flag().map_err(|e| proto_err("classInfo", e))? =>
            {
                let c = rd.read_i32().map_err(|e| proto_err("classInfo", e))?;
                let fmt = crate::format::decode_formatter(&mut rd)
                    .map_err(|e| proto_err("classInfo", e))?;
                self.class_formats.push((c, fmt));
            }
            Op::NewModuleConnect => {
                let e = |e| proto_err("newModuleConnect reply", e);
                let major = rd.read_i32().map_err(e)?;
                let minor = rd.read_i32().map_err(e)?;
                let direct = rd.read_i32().map_err(e)?;
                if major != 3 {
                    return Err(Error::Version { major, minor });
                }
                self.direct = direct != 0;
                let mut next = Vec::new();
                if self.direct {
                    self.events.push_back(Event::DirectListenRequested);
                    next.push(Op::WaitDirectPort);
                }
                for v in [
                    "V_get_CENTRAL_TERMINAL_LOG_VAR",
                    "V_get_CENTRAL_FILE_LOG_VAR",
                    "V_get_X_IPC_TAPPED_MSG_VAR",
                    "V_get_X_IPC_BROADCAST_MSG_VAR",
                ] {
                    next.push(Op::VarGet(v));
                }
                let id = self.alloc_handler(
                    "V_watch_X_IPC_BROADCAST_MSG_VAR",
                    "V_watch_X_IPC_BROADCAST_MSG_VAR",
                    HandlerKind::BroadcastVar,
                );
                next.push(Op::RegisterHandler {
                    id,
                    msg: "V_watch_X_IPC_BROADCAST_MSG_VAR".into(),
                    hnd: "V_watch_X_IPC_BROADCAST_MSG_VAR".into(),
                });
                next.push(Op::LimitPending {
                    msg: "X_IPC_BROADCAST_MSG_VAR".into(),
                    limit: 1,
                });
                next.push(Op::WaitMsg);
                for op in next.into_iter().rev() {
                    self.ops.push_front(op);
                }
            }
            Op::VarGet("V_get_X_IPC_BROADCAST_MSG_VAR") => {
                self.set_broadcast_list(proto::decode_str_list(&f.data, order)?);
            }
            Op::WaitMsg => {
                self.stage = Stage::Ready;
                self.events.push_back(Event::Connected);
            }
            Op::Ask { op, ask } => {
                let answer = ask
                    .decode(&f.data, order)
                    .map_err(|e| proto_err(ask.message(), e))?;
                self.events.push_back(Event::CentralAnswer { op, answer });
            }
            Op::ModuleConnectedQ { op, .. } => {
                let v = rd
                    .read_i32()
                    .map_err(|e| proto_err("moduleConnectedQ reply", e))?;
                self.events.push_back(Event::ModuleConnected {
                    op,
                    connected: v != 0,
                });
            }
            Op::DirectQuery { msg } => {
                let list = proto::decode_direct_handlers(&f.data, order)?;
                let empty = list.is_empty();
                self.set_direct_handlers(&msg, list);
                let w = format!("V_watch_{msg}");
                if !self.by_name.contains_key(&(w.clone(), w.clone())) {
                    if empty {
                        // A handler that registers between this answer and
                        // the watch below would be reported to nobody (and
                        // a query waiting for it would wait forever): ask
                        // again once the watch is in place. Central handles
                        // this connection's messages in order, so every
                        // registration is either in that answer or watched.
                        self.ops.push_front(Op::DirectQuery { msg: msg.clone() });
                    }
                    let id = self.alloc_handler(&w, &w, HandlerKind::DirectWatch(msg));
                    self.ops.push_front(Op::RegisterHandler {
                        id,
                        msg: w.clone(),
                        hnd: w,
                    });
                }
            }
            Op::NumHandlers { op, msg } => {
                let count = if f.data.is_empty() {
                    0
                } else {
                    rd.read_i32()
                        .map_err(|e| proto_err("directMsgQuery reply", e))?
                };
                if count > 0 {
                    if let Some(list) = &mut self.broadcast_var {
                        list.insert(msg.clone());
                    }
                    self.counted.insert(msg);
                } else {
                    self.counted.remove(&msg);
                }
                self.events.push_back(Event::NumHandlers { op, count });
            }
            _ => {}
        }
        Ok(())
    }
}
