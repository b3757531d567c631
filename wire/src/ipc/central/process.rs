//! A whole frame from a module: its checks, and the internal messages
//! central answers itself (ipc.md §6); user messages go on to routing.

use std::time::SystemTime;

use super::direct::{write_direct_entry, write_direct_list};
use super::internal::{self, Internal};
use super::log::Kind;
use super::tables::{named_format_bytes, DispatchId, Linked, MsgId, Org, MSG_BYTES};
use super::{Bad, Body, Central, ConnId, Output, SERVER_NAME, VERSION};
use crate::ipc::frame::{Header, MsgClass};
use crate::ipc::{introspect, ByteOrder, Reader, Writer};

impl Central {
    pub(super) fn process(
        &mut self,
        conn: ConnId,
        h: Header,
        class_data: &[u8],
        data: Body,
        now: SystemTime,
    ) -> Result<(), Bad> {
        if h.class_id.data_order().is_none() || h.class_id.class_order().is_none() {
            return Err(Bad(format!(
                "frame has an unknown byte-order flag (classId 0x{:08x})",
                h.class_id.0
            )));
        }
        match h.class_id.class() {
            12 => return self.on_success(conn, DispatchId(h.dispatch_ref), now),
            11 => return self.on_reply(conn, h, class_data, data, now),
            _ => {}
        }
        let id = MsgId(h.intent.checked_abs().unwrap_or(0));
        let Some(name) = self.by_id.get(&id).cloned() else {
            let who = self.describe(conn);
            self.complain(
                conn,
                format!(
                    "WARNING: message with unknown id {} (class {}) from {who} ignored",
                    h.intent,
                    h.class_id.class()
                ),
            );
            return Ok(());
        };
        let internal = self.msgs.linked(name.as_str())?.internal.clone();
        match internal {
            Some(kind) => {
                let rid = self.take_ref();
                let r = self.on_internal(conn, h, &name, kind, &data, now, rid);
                self.give_ref(rid);
                r
            }
            None => self.route(conn, h, name, data, now),
        }
    }

    /// An internal message, handled under the dispatch id `rid`.
    #[allow(clippy::too_many_arguments)]
    fn on_internal(
        &mut self,
        conn: ConnId,
        h: Header,
        name: &str,
        kind: Internal,
        data: &[u8],
        now: SystemTime,
        rid: DispatchId,
    ) -> Result<(), Bad> {
        let order = h.class_id.data_order().unwrap_or(ByteOrder::NATIVE);
        let mut r = Reader::new(data, order);
        let query = h.class_id.class() == MsgClass::Query as u16;
        let logged = self.logs(Kind::Message, name);
        let org_name = self.module_name(Org::Module(conn));
        if logged {
            let to = format!("{SERVER_NAME:<15} (Sent)");
            let line = self.dispatch_line(
                h.class_id.class(),
                name,
                Some(rid),
                &org_name,
                h.parent_ref,
                &to,
                now,
            );
            self.log_line(Kind::Message, line);
            self.log_data_as(name, h.class_id, data, None, true);
        }
        let mut out = Writer::new();
        let mut null_reply = false;
        use Internal::*;
        let lookup = matches!(kind, MsgInfo | HndInfo);
        match kind {
            MsgInfo | HndInfo => {
                let msg = read_opt_str(&mut r)?;
                let hnd = read_opt_str(&mut r)?;
                self.msg_info(conn, msg.as_deref(), hnd.as_deref(), &mut out);
            }
            ClassInfo => {
                let class = r.read_i32()?;
                match internal::class_format(class) {
                    Some(f) => {
                        out.write_ptr_flag(true);
                        out.write_i32(class);
                        internal::write_formatter(&mut out, Some(&internal::fixed(f)));
                    }
                    None => out.write_ptr_flag(false),
                }
            }
            Connect => {
                let module = read_opt_str(&mut r)?.unwrap_or_default();
                let host = read_opt_str(&mut r)?.unwrap_or_default();
                if !self.on_connect(conn, module, host) {
                    return Ok(());
                }
                out.write_i32(VERSION.0);
                out.write_i32(VERSION.1);
                out.write_bool(self.config.direct);
            }
            Wait => {
                out.write_i32(1);
                if let Some(m) = self.modules.get_mut(&conn) {
                    m.ready = true;
                }
                self.reply(conn, h.msg_ref, out.as_bytes());
                if logged {
                    self.log_internal_reply(
                        name,
                        &org_name,
                        (rid, h.parent_ref),
                        h.class_id,
                        out.as_bytes(),
                        now,
                    );
                }
                self.process_pending(conn, now);
                return Ok(());
            }
            RegisterMessage => {
                let n = read_opt_str(&mut r)?.unwrap_or_default();
                let class = r.read_i32()?;
                let mf = read_opt_str(&mut r)?;
                let rf = read_opt_str(&mut r)?;
                self.register_message(conn, n, class, mf, rf)?;
            }
            RegisterNamedForm => {
                let n = read_opt_str(&mut r)?.unwrap_or_default();
                let f = read_opt_str(&mut r)?.unwrap_or_default();
                let before = self
                    .formats
                    .get(&n)
                    .map_or(0, |f| named_format_bytes(&n, f));
                let after = crate::format::parse(&f).map_or(0, |f| named_format_bytes(&n, &f));
                let room = after <= before
                    || self.room_for_definition(conn, after - before, &format!("named format {n}"));
                match room.then(|| self.formats.define(&n, &f)) {
                    None => {}
                    Some(Ok(())) => self.definition_bytes = self.definition_bytes + after - before,
                    Some(Err(e)) => self.complain(
                        conn,
                        format!("WARNING: bad named format {n} = \"{f}\" from {org_name}: {e}"),
                    ),
                }
                for m in self.msgs.values_mut() {
                    m.parsed = None;
                }
            }
            GetNamedForm => {
                let n = read_opt_str(&mut r)?.unwrap_or_default();
                match self.formats.get(&n).cloned() {
                    Some(f) => {
                        let f = self.formats.resolve(&f).unwrap_or(f);
                        internal::write_formatter(&mut out, Some(&f));
                    }
                    None => {
                        self.log_line(Kind::Always, format!("Unknown named format {n} used."));
                        out.write_i32(6); // BadFormat
                    }
                }
            }
            RegisterHandler => {
                let id = r.read_i32()?;
                let msg = read_opt_str(&mut r)?.unwrap_or_default();
                let hnd = read_opt_str(&mut r)?.unwrap_or_default();
                self.register_handler(conn, id, msg, hnd, now)?;
            }
            DeregisterHandler => {
                let _ = r.read_i32()?;
                let msg = read_opt_str(&mut r)?.unwrap_or_default();
                let hnd = read_opt_str(&mut r)?.unwrap_or_default();
                self.deregister_handler(conn, &msg, &hnd);
            }
            DirectRes => {
                let port = r.read_i32()?;
                let n = read_opt_str(&mut r)?.unwrap_or_default();
                let own = self.modules.get(&conn).and_then(|m| m.name.clone());
                if own.as_deref() == Some(n.as_str()) {
                    self.modules.linked_mut(&conn)?.port = port;
                    self.log_line(
                        Kind::Message,
                        format!("Direct Connection Established For: {n} at {port}"),
                    );
                } else {
                    self.log_line(
                        Kind::Message,
                        format!("Direct Connection: Not Made: {n} did not originate call."),
                    );
                }
            }
            DirectInfo => {
                let n = read_opt_str(&mut r)?.unwrap_or_default();
                let list = self.direct_handlers(&n);
                match list.first() {
                    Some(e) => write_direct_entry(&mut out, e),
                    None => null_reply = true,
                }
            }
            DirectMsg => {
                let n = read_opt_str(&mut r)?.unwrap_or_default();
                let list = self.direct_handlers(&n);
                if list.is_empty() {
                    null_reply = true;
                } else {
                    write_direct_list(&mut out, &list);
                }
            }
            ModuleConnected => {
                let n = read_opt_str(&mut r)?.unwrap_or_default();
                let found = self
                    .modules
                    .values()
                    .any(|m| !m.closed && m.name.as_deref() == Some(n.as_str()));
                out.write_i32(found as i32);
            }
            NotifyHandlerChange => {
                let n = read_opt_str(&mut r)?.unwrap_or_default();
                match self.msgs.get_mut(&n) {
                    Some(m) if m.class != MsgClass::HandlerReg => {
                        let first = !m.direct && !m.notify_handler_change;
                        m.notify_handler_change = true;
                        if first {
                            self.register_var(&n);
                            self.update_direct_handlers(&n);
                        }
                    }
                    _ => self.log_line(
                        Kind::Always,
                        format!("Cannot do handler notification before message defined ({n})"),
                    ),
                }
            }
            SetMsgPriority => {
                let n = read_opt_str(&mut r)?.unwrap_or_default();
                let p = r.read_i32()?;
                if self.msgs.contains_key(&n)
                    || self.room_for_definition(
                        conn,
                        MSG_BYTES + n.len(),
                        &format!("priority of message {n} (not defined yet)"),
                    )
                {
                    self.placeholder(&n).priority = p;
                }
            }
            RegisterResource => {
                let cap = r.read_i32()?;
                let res = read_opt_str(&mut r)?.unwrap_or_default();
                self.set_capacity(conn, cap, &res, now)?;
            }
            LimitPending => {
                let msg = read_opt_str(&mut r)?;
                let res = read_opt_str(&mut r)?.unwrap_or_default();
                let limit = r.read_i32()?;
                self.limit_pending(conn, msg, &res, limit)?;
            }
            Close => {
                self.outputs.push_back(Output::Close {
                    conn,
                    reason: "module sent x_ipc_CloseMsg".into(),
                });
                self.close_module(conn, false, now);
                if logged {
                    self.log_done(name, rid, now);
                }
                return Ok(());
            }
            IgnoreLogging => {
                if let Some(n) = read_opt_str(&mut r)? {
                    self.ignore.insert(n);
                }
            }
            ResumeLogging => {
                if let Some(n) = read_opt_str(&mut r)? {
                    self.ignore.remove(&n);
                }
            }
            GetMessages => {
                let mut names: Vec<String> = self
                    .msgs
                    .values()
                    .filter(|m| m.internal.is_none() && m.id.is_some())
                    .map(|m| m.name.clone())
                    .collect();
                names.sort();
                let size = internal::str_list_size(names.len(), 0);
                internal::encode_str_list(&names, size, &mut out);
            }
            MessageInfo => {
                let n = read_opt_str(&mut r)?.unwrap_or_default();
                let d = self.message_details(n);
                introspect::encode_message_details(&d, &mut out);
            }
            Modules => {
                let list = self.module_details();
                introspect::encode_modules(&list, &mut out);
            }
            Ignored | Notify | VarWatch(_) => {}
            VarGet(v) => match self.vars.get(&v) {
                Some(var) => {
                    out.write_bytes(&var.value.clone());
                    self.note_var_read(conn, &v);
                }
                None => null_reply = true,
            },
            VarSet(v) => self.set_var_from(&v, data, order)?,
            VarGetSet(v) => {
                if let Some(var) = self.vars.get(&v) {
                    out.write_bytes(&var.value.clone());
                }
                self.set_var_from(&v, data, order)?;
                self.note_var_read(conn, &v);
            }
        }
        if query {
            let bytes = if null_reply {
                Vec::new()
            } else {
                out.into_vec()
            };
            self.reply(conn, h.msg_ref, &bytes);
            if logged {
                // Named now if this was its connect query.
                let to = self.module_name(Org::Module(conn));
                let refs = (rid, h.parent_ref);
                self.log_internal_reply(name, &to, refs, h.class_id, &bytes, now);
            }
        } else if logged {
            self.log_done(name, rid, now);
        }
        if lookup {
            // A handler looked up: what waits for it may go ahead now,
            // behind the reply.
            self.send_ahead(conn);
        }
        Ok(())
    }
}

/// A string that may be NULL (`n = 0`): `None` for NULL/empty.
pub(super) fn read_opt_str(r: &mut Reader<'_>) -> Result<Option<String>, Bad> {
    let s = r.read_str()?;
    Ok(if s.is_empty() {
        None
    } else {
        Some(s.to_string())
    })
}
