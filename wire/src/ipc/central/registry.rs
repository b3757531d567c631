//! Registrations: a module naming itself, messages and handlers
//! (un)registered, message lookups (`msgInfo`), capacities and queue
//! limits.

use std::collections::HashSet;
use std::time::SystemTime;

use super::direct::direct_class;
use super::internal;
use super::log::Kind;
use super::tables::{cost, msg_bytes, DispatchId, Handler, Linked, Status, MSG_BYTES};
use super::{Bad, Central, ConnId, Output};
use crate::ipc::frame::MsgClass;
use crate::ipc::Writer;

impl Central {
    pub(super) fn msg_info(
        &mut self,
        conn: ConnId,
        msg: Option<&str>,
        hnd: Option<&str>,
        out: &mut Writer,
    ) {
        let Some(msg) = msg else {
            out.write_ptr_flag(false);
            return;
        };
        let (mf, rf) = self.parsed(msg);
        let Some(m) = self.msgs.get(msg) else {
            out.write_ptr_flag(false);
            return;
        };
        // A message only subscribed so far has no id: C answers 0.
        let id = m.id.map_or(0, |id| id.0);
        let id = if m.direct && direct_class(m.class) {
            -id.abs()
        } else {
            id
        };
        out.write_ptr_flag(true);
        out.write_i32(id);
        out.write_str(&m.name);
        out.write_i32(m.class as i32);
        internal::write_formatter(out, mf.as_ref());
        internal::write_formatter(out, rf.as_ref());
        if let Some(hn) = hnd {
            let found = self
                .modules
                .get_mut(&conn)
                .and_then(|m| m.handlers.get_mut(hn))
                .map(|h| h.knows_msg = true)
                .is_some();
            if !found {
                self.log_line(Kind::Message, String::new());
                self.log_line(
                    Kind::Message,
                    format!("WARNING: msgInfoHnd: Missing handler: {hn}"),
                );
            }
        }
    }

    /// A module's connect query (`x_ipc_connect`). False if it was
    /// refused: another live module already has its name. The C central
    /// takes such a module in as the same resource (one capacity for both)
    /// and, when either closes, closes both; Courier refuses the second
    /// with one line and closes its connection before answering, so the
    /// module's `IPC_connect` fails and the first goes on undisturbed.
    pub(super) fn on_connect(&mut self, conn: ConnId, module: String, host: String) -> bool {
        let sd = self.modules.get(&conn).map_or(0, |m| m.sd);
        let live = self
            .modules
            .iter()
            .find(|(c, m)| **c != conn && !m.closed && m.name.as_deref() == Some(module.as_str()))
            .map(|(_, m)| (m.sd, m.host.clone()));
        if let Some((other_sd, other_host)) = live {
            self.log_line(
                Kind::Problem,
                format!(
                    "ERROR: refused module {module} on {host} (sd {sd}): a module named \
                     {module} is already connected (on {other_host}, sd {other_sd})"
                ),
            );
            self.outputs.push_back(Output::Close {
                conn,
                reason: format!("a module named {module} is already connected"),
            });
            // Nothing else knows it yet: it goes without a close line.
            self.modules.remove(&conn);
            return false;
        }
        self.log_line(Kind::Always, format!(" Received a new connection: {sd}"));
        self.log_line(Kind::Always, format!("   modName : {module}"));
        self.log_line(Kind::Always, format!("   hostName: {host}"));
        self.central_broadcast(internal::CONNECT_NOTIFY, |w| w.write_str(&module));
        if let Some(m) = self.modules.get_mut(&conn) {
            m.name = Some(module);
            m.host = host;
        }
        self.prune_handshakes();
        true
    }

    pub(super) fn register_message(
        &mut self,
        conn: ConnId,
        name: String,
        class: i32,
        mf: Option<String>,
        rf: Option<String>,
    ) -> Result<(), Bad> {
        let Some(class) = u16::try_from(class).ok().and_then(MsgClass::from_u16) else {
            self.complain(
                conn,
                format!("WARNING: message {name} registered with unknown class {class}; ignored"),
            );
            return Ok(());
        };
        let before = self.msgs.get(&name).map_or(0, |m| {
            MSG_BYTES + name.len() + msg_bytes(&m.msg_format, &m.res_format)
        });
        let after = MSG_BYTES + name.len() + msg_bytes(&mf, &rf);
        if after > before
            && !self.room_for_definition(conn, after - before, &format!("message {name}"))
        {
            return Ok(());
        }
        if let Some(m) = self.msgs.get(&name) {
            if m.internal.is_some() {
                self.complain(
                    conn,
                    format!(
                        "WARNING: a module tried to redefine central's message {name}; ignored"
                    ),
                );
                return Ok(());
            }
            if m.class != MsgClass::HandlerReg {
                self.log_line(
                    Kind::Registration,
                    format!("Registration: Message {name} Found. Updating."),
                );
            }
        }
        self.insert_msg(name.clone(), class, mf, rf, None);
        let m = self.msgs.linked(name.as_str())?;
        if m.class == MsgClass::Broadcast && !m.handlers.is_empty() {
            self.record_broadcast(&name, true);
        }
        let m = self.msgs.linked_mut(name.as_str())?;
        if direct_class(m.class) {
            m.direct = self.config.direct;
            if m.direct || m.notify_handler_change {
                self.register_var(&name);
                self.update_direct_handlers(&name);
            }
        }
        Ok(())
    }

    pub(super) fn register_handler(
        &mut self,
        conn: ConnId,
        id: i32,
        msg: String,
        hnd: String,
        now: SystemTime,
    ) -> Result<(), Bad> {
        // The broadcast list before this registration changes it.
        let list_before = self.var_version(internal::BROADCAST_MSG_VAR);
        let class = self.msgs.get(&msg).map(|m| m.class);
        if class.is_none()
            && !self.room_for_definition(
                conn,
                MSG_BYTES + msg.len(),
                &format!("handler {hnd} of message {msg} (not defined yet)"),
            )
        {
            return Ok(());
        }
        let existed = class.is_some_and(|c| c != MsgClass::HandlerReg);
        if class == Some(MsgClass::Broadcast) {
            self.record_broadcast(&msg, true);
        }
        self.placeholder(&msg);
        let module = self.modules.linked_mut(&conn)?;
        let mod_name = module.name.clone();
        if let Some(old) = module.handlers.get_mut(&hnd) {
            // Re-registering a handler (a C module does it when the client
            // data changes, with id 0): like x_ipc_selfRegisterHnd, keep
            // the first id and forget that the module knows the message, so
            // the next delivery names it again. The C central announces the
            // handler list again all the same (registerHandlerHnd).
            old.knows_msg = false;
            let m = self.msgs.linked(msg.as_str())?;
            if m.direct || m.notify_handler_change {
                self.update_direct_handlers(&msg);
            }
            return Ok(());
        }
        // Subscribed again after an unsubscribe: the first id, not the 0
        // the C library sends this time.
        let id = module.retired.remove(&hnd).unwrap_or(id);
        // The message lists the handler, and the module has it.
        self.msgs
            .linked_mut(msg.as_str())?
            .handlers
            .push((conn, hnd.clone()));
        module.handlers.insert(
            hnd.clone(),
            Handler {
                id,
                seq: {
                    self.handler_seq += 1;
                    self.handler_seq
                },
                msg: msg.clone(),
                knows_msg: false,
            },
        );
        if !existed {
            self.record_broadcast(&msg, true);
        }
        // A module's own registrations change the broadcast list it read
        // (the C central sends it none of those changes either); only
        // changes made by others in the meantime make its copy stale.
        let list_after = self.var_version(internal::BROADCAST_MSG_VAR);
        if let (Some(b), Some(a)) = (list_before, list_after) {
            if let Some(m) = self.modules.get_mut(&conn) {
                if let Some(r) = m.vars_read.get_mut(internal::BROADCAST_MSG_VAR) {
                    if *r == b {
                        *r = a;
                    }
                }
            }
        }
        self.catch_up_watch(conn, &msg, &hnd);
        let m = self.msgs.linked(msg.as_str())?;
        if m.direct || m.notify_handler_change {
            self.update_direct_handlers(&msg);
        }
        // Queries and informs that waited for a handler.
        let m = self.msgs.linked_mut(msg.as_str())?;
        let waiting: Vec<DispatchId> = m.waiting.drain(..).collect();
        for did in waiting {
            if let Some(d) = self.dispatches.get_mut(&did) {
                self.stats.waiting_bytes = self.stats.waiting_bytes.saturating_sub(cost(d));
                d.hnd = Some((conn, hnd.clone()));
                self.deliver_or_pend(did, now);
            }
        }
        // -r: deliveries this module had not finished before it crashed.
        if let Some(n) = mod_name {
            for did in self.take_kept(&n, &msg) {
                self.log_line(Kind::Always, format!("Resending {msg} {{{did}}} to {n}"));
                if let Some(d) = self.dispatches.get_mut(&did) {
                    d.hnd = Some((conn, hnd.clone()));
                    self.deliver_or_pend(did, now);
                }
            }
        }
        Ok(())
    }

    pub(super) fn deregister_handler(&mut self, conn: ConnId, msg: &str, hnd: &str) {
        let Some(module) = self.modules.get_mut(&conn) else {
            return;
        };
        // As in C, only a handler of `msg` is found: one of another message
        // stays, or `msg` would keep listing a handler the module has not.
        match module.handlers.get(hnd) {
            None => return,
            Some(h) if h.msg != msg => {
                let (theirs, who) = (h.msg.clone(), self.describe(conn));
                self.complain(
                    conn,
                    format!(
                        "WARNING: {who} unsubscribed handler {hnd} from {msg}, but it handles \
                         {theirs}; ignored"
                    ),
                );
                return;
            }
            Some(_) => {}
        }
        let Some(old) = module.handlers.remove(hnd) else {
            return;
        };
        module.retired.insert(hnd.to_string(), old.id);
        if let Some(m) = self.msgs.get_mut(msg) {
            m.handlers.retain(|(c, n)| !(*c == conn && n == hnd));
        }
        // Deliveries queued for the handler cannot be handled any more: one
        // pass over the module's queue, one log line (a subscriber that
        // leaves tens of thousands behind held central for seconds, a scan
        // of the queue and a line per message)
        let stale: HashSet<DispatchId> = self
            .dispatches
            .iter()
            .filter(|(_, d)| {
                d.status == Status::Pending
                    && d.hnd.as_ref().is_some_and(|(c, n)| *c == conn && n == hnd)
            })
            .map(|(id, _)| *id)
            .collect();
        if !stale.is_empty() {
            if let Some(m) = self.modules.get_mut(&conn) {
                m.pending.retain(|x| !stale.contains(x));
            }
            let n = stale.len();
            for id in stale {
                self.free_dispatch_id(id);
            }
            let what = if n == 1 { "message" } else { "messages" };
            self.log_line(
                Kind::Status,
                format!("Deleted pending {msg} ({n} {what}): its handler {hnd} was unsubscribed"),
            );
        }
        self.handlers_changed(msg);
    }

    /// After handlers of `msg` changed: broadcast list and watch variable.
    fn handlers_changed(&mut self, msg: &str) {
        let Some(m) = self.msgs.get(msg) else {
            return;
        };
        let unlisted = m.class == MsgClass::Broadcast && m.handlers.is_empty();
        let watched = m.direct || m.notify_handler_change;
        if unlisted {
            self.record_broadcast(msg, false);
        }
        if watched {
            self.update_direct_handlers(msg);
        }
    }

    pub(super) fn set_capacity(
        &mut self,
        conn: ConnId,
        cap: i32,
        res: &str,
        now: SystemTime,
    ) -> Result<(), Bad> {
        self.modules.linked(&conn)?;
        let mut cap = cap;
        if cap < 1 {
            self.log_line(Kind::Status, String::new());
            self.log_line(
                Kind::Status,
                format!("WARNING: Capacity of {}:{res} set to 1", conn.0),
            );
            cap = 1;
        }
        if self.modules.linked(&conn)?.name.as_deref() != Some(res) {
            self.log_line(
                Kind::Status,
                format!(
                    "WARNING: resource {res} is not module {}; capacity applied to the module",
                    conn.0
                ),
            );
        }
        let m = self.modules.linked_mut(&conn)?;
        if m.capacity != cap as usize {
            m.capacity = cap as usize;
            self.log_line(Kind::Status, String::new());
            self.log_line(
                Kind::Status,
                format!("WARNING: Capacity of {}:{res} changed to {cap}", conn.0),
            );
        }
        // Like C, a larger capacity is used from the next completion on.
        let _ = now;
        Ok(())
    }

    pub(super) fn limit_pending(
        &mut self,
        conn: ConnId,
        msg: Option<String>,
        res: &str,
        limit: i32,
    ) -> Result<(), Bad> {
        // The resource is named after its module; prefer the sender's own.
        let target = if self.modules.get(&conn).and_then(|m| m.name.as_deref()) == Some(res) {
            Some(conn)
        } else {
            self.modules
                .iter()
                .find(|(_, m)| m.name.as_deref() == Some(res))
                .map(|(c, _)| *c)
        };
        let Some(target) = target else {
            self.log_line(
                Kind::Status,
                format!("ERROR: Non-existent resource {res}; Pending limit not applied"),
            );
            return Ok(());
        };
        let m = self.modules.linked_mut(&target)?;
        match msg {
            None => m.pending_limit = Some(limit),
            Some(msg) => {
                if let Some(e) = m.msg_limits.iter_mut().find(|(n, _)| *n == msg) {
                    if e.1 != limit {
                        let old = e.1;
                        e.1 = limit;
                        self.log_line(
                            Kind::Status,
                            format!("WARNING: Changing pending message limit of {msg} from {old} to {limit}"),
                        );
                    }
                } else {
                    m.msg_limits.push((msg, limit));
                }
            }
        }
        Ok(())
    }
}

impl Central {
    /// Whether definitions may take `more` bytes
    /// ([`Config::max_definition_bytes`](super::Config::max_definition_bytes));
    /// if not, says so on behalf of `conn` (`what`: what is refused).
    pub(super) fn room_for_definition(&mut self, conn: ConnId, more: usize, what: &str) -> bool {
        if self.definition_bytes + more <= self.config.max_definition_bytes {
            return true;
        }
        let held = self.definition_bytes;
        let max = self.config.max_definition_bytes;
        self.complain(
            conn,
            format!(
                "WARNING: {what} refused: definitions hold {held} bytes, and {more} more \
                 would pass the {max} central keeps (max_definition_bytes)"
            ),
        );
        false
    }
}
