//! Log lines in the C central's layout (`dispatchUpdateAndDisplay1` in
//! dispatch.c, `Log_Time`/`Log_RefId`/`Log_ParentId` in logging.c).

use std::time::{SystemTime, UNIX_EPOCH};

use super::LogOptions;

/// Which `LOG_*` macro a line corresponds to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Kind {
    /// `LOG`: printed whenever the log is on at all.
    Always,
    /// `LOG_MESSAGE`: message traffic (`m`).
    Message,
    /// `LOG_STATUS`: status (`s`).
    Status,
    /// Data lines (`d`, only with `m`).
    Data,
    /// Courier's own `ERROR:`/`WARNING:` lines about bad input or a
    /// misbehaving module: on the terminal even when logging is off (`-lx`;
    /// `-s` still silences the terminal), and in the log file when there is
    /// one.
    Problem,
}

impl Kind {
    pub(super) fn enabled(self, o: &LogOptions) -> bool {
        match self {
            Kind::Always => o.any(),
            Kind::Message => o.messages,
            Kind::Status => o.status,
            Kind::Data => o.messages && o.data,
            Kind::Problem => o.any(),
        }
    }
}

/// `" {%d}"` when the log wants reference ids.
pub(super) fn ref_id(o: &LogOptions, id: i32) -> String {
    if o.refs {
        format!(" {{{id}}}")
    } else {
        String::new()
    }
}

/// `" {%d}"` when the log wants parent ids.
pub(super) fn parent_id(o: &LogOptions, id: i32) -> String {
    if o.parent_refs {
        format!(" {{{id}}}")
    } else {
        String::new()
    }
}

/// `Log_Time(1)`: `%3d:%02d:%02d.%02d` (UTC; the C central uses local time).
pub(super) fn time(o: &LogOptions, now: SystemTime) -> String {
    if !o.time {
        return String::new();
    }
    let d = now.duration_since(UNIX_EPOCH).unwrap_or_default();
    let secs = d.as_secs() % 86_400;
    format!(
        "{:>3}:{:02}:{:02}.{:02}",
        secs / 3600,
        (secs / 60) % 60,
        secs % 60,
        d.subsec_millis() / 10
    )
}

/// The class name `x_ipc_messageClassName` prints.
pub(super) fn class_name(class: u16) -> &'static str {
    match class {
        3 => "Query",
        4 => "Goal",
        5 => "Command",
        6 => "Inform",
        7 => "Exception",
        11 => "Reply",
        12 => "Success",
        13 => "Failure",
        15 => "Broadcast",
        16 => "MultiQuery",
        _ => "Unknown",
    }
}
