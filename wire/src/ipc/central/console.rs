//! What central's console shows and does, as data: the messages alive
//! (`display`), the modules (`status`), closing a module (`close`), new
//! options, and the console's own lines; [`Central::stats`] serves
//! `memory`. The commands and their text use only these (`commands.rs`).

use std::time::SystemTime;

use super::log::Kind;
use super::tables::{Org, Status};
use super::{Central, Config, ConnId, LogTarget, Output};
use crate::ipc::frame::MsgClass;

/// A message alive in central, one delivery of it (a dispatch), as the
/// console's `display` lists it.
#[derive(Debug, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub struct DispatchInfo {
    /// Central's number for it (`{id}` in the log with `-lr`).
    pub id: i32,
    /// The class it was sent with (broadcast, query or inform).
    pub class: MsgClass,
    /// The message name.
    pub msg: String,
    /// The module that sent it (`X_IPC Server` for central's own).
    pub from: String,
    /// The module it is for, if a handler was chosen.
    pub to: Option<String>,
    /// Where it is.
    pub state: DispatchState,
}

/// Where a message alive in central is ([`DispatchInfo::state`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum DispatchState {
    /// Delivered; its handler has not finished.
    Active,
    /// Queued for its handler's module.
    Pending,
    /// Queued, and already written to its module
    /// ([`Config::send_ahead`]).
    SentAhead,
    /// A query or inform waiting for a first handler of its message (or,
    /// with `-r`, for its module to come back).
    WaitingForHandler,
}

/// A connected module, as the console's `status` lists it.
#[derive(Debug, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub struct ModuleInfo {
    /// Its connection.
    pub conn: ConnId,
    /// Its name, once its connect query has come.
    pub name: Option<String>,
    /// The host it said it runs on (empty before its connect query).
    pub host: String,
    /// How many messages it handles at once (`IPC_setCapacity`).
    pub capacity: usize,
    /// Messages it is handling.
    pub active: usize,
    /// Messages queued for it (sent ahead or not).
    pub pending: usize,
    /// Its direct-mode listen port, if it announced one.
    pub direct_port: Option<i32>,
}

impl Central {
    /// The messages alive, by id.
    pub fn dispatches(&self) -> Vec<DispatchInfo> {
        let mut ids: Vec<_> = self.dispatches.keys().copied().collect();
        ids.sort_unstable();
        ids.into_iter()
            .filter_map(|id| {
                let d = self.dispatches.get(&id)?;
                Some(DispatchInfo {
                    id: id.0,
                    class: MsgClass::from_u16(d.class).unwrap_or(MsgClass::Unknown),
                    msg: d.msg.clone(),
                    from: self.org_name(d),
                    to: d
                        .hnd
                        .as_ref()
                        .map(|(c, _)| self.module_name(Org::Module(*c))),
                    state: match d.status {
                        Status::Attending => DispatchState::Active,
                        Status::Pending => DispatchState::Pending,
                        Status::Ahead => DispatchState::SentAhead,
                        Status::NoHandler => DispatchState::WaitingForHandler,
                    },
                })
            })
            .collect()
    }

    /// The connected modules, by connection.
    pub fn modules(&self) -> Vec<ModuleInfo> {
        self.modules
            .iter()
            .map(|(c, m)| ModuleInfo {
                conn: *c,
                name: m.name.clone(),
                host: m.host.clone(),
                capacity: m.capacity,
                active: m.attending,
                pending: m.pending.len() + m.ahead.len(),
                direct_port: (m.port >= 0).then_some(m.port),
            })
            .collect()
    }

    /// Closes the module named `name` (the console's `close`), as the C
    /// central does: logged, and its connection closed. False if no
    /// module has that name.
    pub fn close_module_named(&mut self, name: &str, now: SystemTime) -> bool {
        self.clock = now;
        let conn = self
            .modules
            .iter()
            .find(|(_, m)| m.name.as_deref() == Some(name))
            .map(|(c, _)| *c);
        let Some(conn) = conn else {
            return false;
        };
        self.log_line(Kind::Always, format!("close Module: Closing {name}"));
        self.outputs.push_back(Output::Close {
            conn,
            reason: "closed from the console".into(),
        });
        self.close_module(conn, false, now);
        true
    }

    /// Changes the configuration while central runs (the console's
    /// options: `-l`, `-L`, `-I`, `-c`, `-r`). The log variables modules
    /// read follow the new logging options, names in [`Config::ignore`]
    /// are not logged, and every other option takes effect from the next
    /// event on.
    pub fn reconfigure(&mut self, change: impl FnOnce(&mut Config)) {
        change(&mut self.config);
        for name in &self.config.ignore {
            if !self.ignore.contains(name) {
                self.ignore.insert(name.clone());
            }
        }
        self.update_log_vars();
    }

    /// A line for the terminal only (not the log file), in order with
    /// everything else central asks: the console's answers.
    pub fn print(&mut self, line: String) {
        self.outputs.push_back(Output::Log {
            target: LogTarget {
                terminal: true,
                file: false,
            },
            line,
        });
    }
}
