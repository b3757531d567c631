//! Central's answers to what a module asks about the others
//! (`x_ipc_getMessageInfo`, `courier_getModules`; see
//! [`crate::ipc::introspect`]).

use super::Central;
use crate::ipc::introspect::{MessageDetails, ModuleDetails};

impl Central {
    /// What `x_ipc_getMessageInfo` answers of `name`: as C's
    /// `getMsgInfoHnd`, the registered formats, the class, the number of
    /// handlers and the first handler's resource (its module); an unknown
    /// message has only its name (C leaves the rest uninitialised).
    pub(super) fn message_details(&self, name: String) -> MessageDetails {
        let Some(m) = self.msgs.get(&name).filter(|m| m.internal.is_none()) else {
            return MessageDetails {
                name,
                ..MessageDetails::default()
            };
        };
        let resource = m
            .handlers
            .first()
            .and_then(|(conn, _)| self.modules.get(conn))
            .and_then(|module| module.name.clone());
        MessageDetails {
            msg_format: m.msg_format.clone(),
            reply_format: m.res_format.clone(),
            class: m.class as i32,
            resource,
            handlers: i32::try_from(m.handlers.len()).unwrap_or(i32::MAX),
            name,
        }
    }

    /// Every module that finished connecting and has not closed, by name.
    pub(super) fn module_details(&self) -> Vec<ModuleDetails> {
        let mut v: Vec<ModuleDetails> = self
            .modules
            .values()
            .filter(|m| !m.closed)
            .filter_map(|m| {
                Some(ModuleDetails {
                    name: m.name.clone()?,
                    host: m.host.clone(),
                    handlers: i32::try_from(m.handlers.len()).unwrap_or(i32::MAX),
                    waiting: i32::try_from(m.pending.len()).unwrap_or(i32::MAX),
                })
            })
            .collect();
        v.sort_by(|a, b| a.name.cmp(&b.name));
        v
    }
}
