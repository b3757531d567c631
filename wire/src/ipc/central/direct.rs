//! Direct mode (`-c`, ipc.md §8): the handler lists modules connect to
//! each other by, kept in `V_watch_<msg>` variables.

use super::{Central, ConnId, MAX_DIRECT_HANDLERS};
use crate::ipc::frame::MsgClass;
use crate::ipc::Writer;

impl Central {
    pub(super) fn direct_handlers(&self, msg: &str) -> Vec<DirectEntry> {
        let Some(m) = self.msgs.get(msg) else {
            return Vec::new();
        };
        if m.handlers.len() > MAX_DIRECT_HANDLERS {
            return Vec::new();
        }
        let list: Vec<&(ConnId, String)> = if m.class == MsgClass::Broadcast {
            m.handlers.iter().rev().collect()
        } else {
            m.handlers.last().into_iter().collect()
        };
        list.into_iter()
            .filter_map(|(c, hn)| {
                let md = self.modules.get(c)?;
                Some(DirectEntry {
                    intent: md.handlers.get(hn)?.id,
                    port: md.port,
                    host: md.host.clone(),
                    module: md.name.clone().unwrap_or_default(),
                })
            })
            .collect()
    }

    /// `updateDirectHandlers`: `V_watch_<msg>` = its handler list.
    pub(super) fn update_direct_handlers(&mut self, msg: &str) {
        self.register_var(msg);
        let list = self.direct_handlers(msg);
        let mut w = Writer::new();
        write_direct_list(&mut w, &list);
        self.set_var_by_central(msg, w.into_vec());
    }
}

/// One `directMsgHandler` entry.
#[derive(Debug, Clone)]
pub(super) struct DirectEntry {
    intent: i32,
    port: i32,
    host: String,
    module: String,
}

pub(super) fn write_direct_entry(w: &mut Writer, e: &DirectEntry) {
    w.write_i32(e.intent);
    w.write_i32(0);
    w.write_i32(0);
    w.write_i32(e.port);
    w.write_str(&e.host);
    w.write_str(&e.module);
}

pub(super) fn write_direct_list(w: &mut Writer, list: &[DirectEntry]) {
    w.write_i32(list.len() as i32);
    w.write_len(list.len());
    for e in list {
        write_direct_entry(w, e);
    }
}

/// `DIRECT_MSG(msg)`: classes that may go module to module.
pub(super) fn direct_class(c: MsgClass) -> bool {
    matches!(c, MsgClass::Broadcast | MsgClass::Inform | MsgClass::Query)
}
