//! Global variables (`V_get_…`, `V_set_…`, `V_watch_…`): central's own
//! (the log options, the tapped and broadcast message lists) and those
//! modules register, and the broadcasts that follow a change.

use super::internal;
use super::log::Kind;
use super::tables::Var;
use super::{Bad, Body, Central, ConnId, SERVER_NAME};
use crate::ipc::frame::{ClassId, MsgClass, NO_REF};
use crate::ipc::{ByteOrder, Reader, Writer};

impl Central {
    pub(super) fn register_var(&mut self, var: &str) {
        if self.vars.contains_key(var) {
            return;
        }
        // `centralRegisterVar` sends central `x_ipc_registerGlobalVar`
        // ({varName, format}) and logs it.
        let mut w = Writer::new();
        w.write_str(var);
        w.write_str(internal::var_format_text(var));
        self.central_inform(internal::REGISTER_GLOBAL_VAR, w.into_vec(), |c, _| {
            c.add_var(var)
        });
    }

    fn add_var(&mut self, var: &str) {
        let format = internal::fixed(&internal::var_format(var));
        self.vars.insert(
            var.to_string(),
            Var {
                format,
                value: Vec::new(),
                version: 0,
            },
        );
        for (name, class, mf, rf, kind) in internal::var_defs(var) {
            self.ignore.insert(name.clone());
            self.insert_msg(name, class, mf, rf, Some(kind));
        }
    }

    pub(super) fn set_var_from(
        &mut self,
        var: &str,
        data: &[u8],
        order: ByteOrder,
    ) -> Result<(), Bad> {
        let Some(v) = self.vars.get(var) else {
            return Ok(());
        };
        // Validate, then store in central's own byte order.
        let value = crate::ipc::decode_value(&v.format, &mut Reader::new(data, order))?;
        let mut w = Writer::new();
        crate::ipc::encode_value(&v.format, &value, &mut w)?;
        self.set_var(var, w.into_vec());
        Ok(())
    }

    /// Central setting a variable of its own accord (the broadcast list, a
    /// direct handler list): the C central sends itself `V_set_<var>` and
    /// logs it like a module's, around the broadcasts it causes.
    pub(super) fn set_var_by_central(&mut self, var: &str, bytes: Vec<u8>) {
        let name = format!("V_set_{var}");
        self.central_inform(&name, bytes, |c, bytes| c.set_var(var, bytes));
    }

    /// An inform central sends itself (`V_set_…`, `x_ipc_registerGlobalVar`):
    /// logged as C logs it, `Inform` (with `data`) before what `act` does
    /// with `data` and `Done` after, under a dispatch id of its own.
    pub(super) fn central_inform(
        &mut self,
        name: &str,
        data: Vec<u8>,
        act: impl FnOnce(&mut Self, Vec<u8>),
    ) {
        let rid = self.take_ref();
        let logged = self.logs(Kind::Message, name);
        if logged {
            let to = format!("{SERVER_NAME:<15} (Sent)");
            let class = MsgClass::Inform as u16;
            let line =
                self.dispatch_line(class, name, Some(rid), SERVER_NAME, NO_REF, &to, self.clock);
            self.log_line(Kind::Message, line);
            self.log_data_as(name, ClassId::native(MsgClass::Inform), &data, None, true);
        }
        act(self, data);
        if logged {
            self.log_done(name, rid, self.clock);
        }
        self.give_ref(rid);
    }

    fn set_var(&mut self, var: &str, bytes: Vec<u8>) {
        if let Some(v) = self.vars.get_mut(var) {
            v.value = bytes.clone();
            v.version += 1;
        }
        self.central_broadcast_bytes(&format!("V_watch_{var}"), bytes);
    }

    pub(super) fn var_version(&self, var: &str) -> Option<u64> {
        self.vars.get(var).map(|v| v.version)
    }

    /// `conn` now has the current value of `var` (read or sent to it).
    pub(super) fn note_var_read(&mut self, conn: ConnId, var: &str) {
        let version = self.vars.get(var).map_or(0, |v| v.version);
        if let Some(m) = self.modules.get_mut(&conn) {
            m.vars_read.insert(var.to_string(), version);
        }
    }

    /// A module subscribed `V_watch_<var>` (handler `hnd`) after reading
    /// `<var>`: if others changed the value in between, the change was
    /// broadcast before the module watched, so it gets the current value
    /// now. A C module starts exactly so (`V_get_X_IPC_BROADCAST_MSG_VAR`,
    /// then the watch), and the C central leaves the gap open: a message
    /// subscribed by another module in it stays unknown to the new module,
    /// whose C library then never publishes it.
    pub(super) fn catch_up_watch(&mut self, conn: ConnId, watch: &str, hnd: &str) {
        let Some(var) = watch.strip_prefix("V_watch_") else {
            return;
        };
        let Some(v) = self.vars.get(var) else {
            return;
        };
        let read = self.modules.get(&conn).and_then(|m| m.vars_read.get(var));
        if read.is_none_or(|r| *r == v.version) {
            return;
        }
        let data = Body::from(&v.value[..]);
        self.central_deliver(watch, data, (conn, hnd.to_string()));
    }

    pub(super) fn str_list_value(&self, items: &[String], size: usize) -> Vec<u8> {
        let mut w = Writer::new();
        internal::encode_str_list(items, size, &mut w);
        w.into_vec()
    }

    /// `recordBroadcast`: keep `X_IPC_BROADCAST_MSG_VAR` = names of
    /// broadcast messages that have handlers, and tell everyone.
    pub(super) fn record_broadcast(&mut self, name: &str, active: bool) {
        let present = self.broadcast_msgs.iter().any(|n| n == name);
        if active == present {
            return;
        }
        if active {
            self.broadcast_msgs.push(name.to_string());
            self.broadcast_size =
                internal::str_list_size(self.broadcast_msgs.len(), self.broadcast_size);
        } else {
            self.broadcast_msgs.retain(|n| n != name);
        }
        let v = self.str_list_value(&self.broadcast_msgs.clone(), self.broadcast_size);
        self.set_var_by_central(internal::BROADCAST_MSG_VAR, v);
    }

    pub(super) fn clean_broadcast(&mut self) {
        let names = self.broadcast_msgs.clone();
        for n in names {
            if self.msgs.get(&n).is_some_and(|m| m.handlers.is_empty()) {
                self.record_broadcast(&n, false);
            }
        }
    }

    pub(super) fn update_log_vars(&mut self) {
        for (var, o, file) in [
            (internal::TERMINAL_LOG_VAR, self.config.terminal_log, false),
            (internal::FILE_LOG_VAR, self.config.file_log, true),
        ] {
            let mut w = Writer::new();
            let on = o.any();
            w.write_ptr_flag(on);
            if on {
                w.write_i32(0);
            }
            // The fields of the C central's LOG_TYPE after its FILE pointer:
            // messages, status, time, data, summary, refId, parentId,
            // quiet, flush, ignore, ignoreNow.
            for b in [
                o.messages,
                o.status,
                o.time,
                o.data,
                o.handle_summary,
                o.refs,
                o.parent_refs,
                !file && self.config.quiet,
                !(file && o.no_flush),
                // A log that is off keeps C's default (ignore on).
                o.ignore_internal || !on,
                false,
            ] {
                w.write_i32(b as i32);
            }
            if let Some(v) = self.vars.get_mut(var) {
                v.value = w.into_vec();
            }
        }
    }
}
