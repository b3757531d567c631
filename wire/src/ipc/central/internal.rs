//! The messages central itself handles (ipc.md §6), their formats, and the
//! encoders of central's replies.

use crate::format::{encode_formatter, parse, Format};
use crate::ipc::frame::MsgClass;
use crate::ipc::introspect;
use crate::ipc::Writer;

/// What central does with a message addressed to it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(super) enum Internal {
    MsgInfo,
    HndInfo,
    ClassInfo,
    Connect,
    Wait,
    RegisterMessage,
    RegisterNamedForm,
    GetNamedForm,
    RegisterHandler,
    DeregisterHandler,
    DirectRes,
    DirectInfo,
    DirectMsg,
    ModuleConnected,
    NotifyHandlerChange,
    SetMsgPriority,
    RegisterResource,
    LimitPending,
    Close,
    IgnoreLogging,
    ResumeLogging,
    GetMessages,
    /// `x_ipc_getMessageInfo` (see [`crate::ipc::introspect`]).
    MessageInfo,
    /// `courier_getModules`, Courier's own (see [`crate::ipc::introspect`]).
    Modules,
    /// Accepted and ignored (TCA bookkeeping the IPC API never relies on).
    Ignored,
    /// Broadcast by central (connect/disconnect notifications).
    Notify,
    VarGet(String),
    VarSet(String),
    VarGetSet(String),
    /// `V_watch_<var>`: broadcast by central when the variable changes.
    VarWatch(String),
}

/// One entry of the internal message table.
pub(super) struct Def {
    pub name: &'static str,
    pub class: MsgClass,
    pub msg_format: Option<&'static str>,
    pub res_format: Option<&'static str>,
    pub kind: Internal,
    /// Logged only when `-l` lacks `i` (C's `Add_Message_To_Ignore`).
    pub ignore_log: bool,
}

/// `X_IPC_STR_LIST_FORMAT`.
pub(super) const STR_LIST_FORMAT: &str = "{int, int, <string:2>}";
/// `DIRECT_MSG_FORMAT` with `directMsgHandler` expanded.
pub(super) const DIRECT_MSG_FORMAT: &str = "{int, <{int, int, int, int, string, string}:1>}";
/// `DIRECT_INFO_FORMAT`.
const DIRECT_INFO_FORMAT: &str = "{int, int, int, int, string, string}";
/// The two log variables (`LOG_TYPE` as central sends it).
pub(super) const LOG_VAR_FORMAT: &str =
    "{*int, int, int, int, int, int, int, int, int, int, int, int}";

/// Global variables every C module fetches at connect (ipc.md §6).
pub(super) const TERMINAL_LOG_VAR: &str = "CENTRAL_TERMINAL_LOG_VAR";
pub(super) const FILE_LOG_VAR: &str = "CENTRAL_FILE_LOG_VAR";
pub(super) const TAPPED_MSG_VAR: &str = "X_IPC_TAPPED_MSG_VAR";
pub(super) const BROADCAST_MSG_VAR: &str = "X_IPC_BROADCAST_MSG_VAR";

pub(super) const MSG_INFO: &str = "x_ipc_msgInfoMsg";
pub(super) const CONNECT_NOTIFY: &str = "x_ipc_connectNotify";
pub(super) const DISCONNECT_NOTIFY: &str = "x_ipc_disconnectNotify";
pub(super) const REGISTER_GLOBAL_VAR: &str = "x_ipc_registerGlobalVar";

/// The message-info query and reply formats central sends at connect.
pub(super) const MSG_INFO_QUERY_FORMAT: &str = "{string, string}";
pub(super) const MSG_INFO_REPLY_FORMAT: &str = "*{int, string, int, format, format}";

macro_rules! def {
    ($name:expr, $class:ident, $msg:expr, $res:expr, $kind:expr) => {
        def!($name, $class, $msg, $res, $kind, true)
    };
    ($name:expr, $class:ident, $msg:expr, $res:expr, $kind:expr, $ignore:expr) => {
        Def {
            name: $name,
            class: MsgClass::$class,
            msg_format: $msg,
            res_format: $res,
            kind: $kind,
            ignore_log: $ignore,
        }
    };
}

/// The internal messages in the order the C central registers them
/// (`serverMessagesInitialize`), each with its `_OLD` alias.
pub(super) fn table() -> Vec<Def> {
    use Internal::*;
    let s = Some;
    vec![
        def!(
            MSG_INFO,
            Query,
            s(MSG_INFO_QUERY_FORMAT),
            s(MSG_INFO_REPLY_FORMAT),
            MsgInfo
        ),
        def!(
            "msgInfoMsg",
            Query,
            s(MSG_INFO_QUERY_FORMAT),
            s(MSG_INFO_REPLY_FORMAT),
            MsgInfo
        ),
        def!(
            "x_ipc_getMessages",
            Query,
            None,
            s(STR_LIST_FORMAT),
            GetMessages
        ),
        def!(
            introspect::GET_MESSAGE_INFO,
            Query,
            s(introspect::MESSAGE_INFO_QUERY_FORMAT),
            s(introspect::MESSAGE_INFO_REPLY_FORMAT),
            MessageInfo,
            // C ignores x_ipc_getMessages a second time instead of this one
            // (comServer.c), so its log shows these queries
            false
        ),
        def!(
            introspect::GET_MODULES,
            Query,
            None,
            s(introspect::MODULES_REPLY_FORMAT),
            Modules
        ),
        def!(
            "x_ipc_hndInfoMsg",
            Query,
            s("{string, string}"),
            s("{string, string}"),
            HndInfo
        ),
        def!(
            "hndInfoMsg",
            Query,
            s("{string, string}"),
            s("{string, string}"),
            HndInfo
        ),
        def!(
            "x_ipc_moduleProvides",
            Inform,
            s(STR_LIST_FORMAT),
            None,
            Ignored
        ),
        def!(
            "x_ipc_moduleRequires",
            Inform,
            s(STR_LIST_FORMAT),
            None,
            Ignored
        ),
        def!(
            "x_ipc_newModuleConnectMsg",
            Query,
            s("{string, string}"),
            s("{{int, int}, boolean}"),
            Connect
        ),
        def!(
            "newModuleConnectMsg",
            Query,
            s("{string, string}"),
            s("{{int, int}, boolean}"),
            Connect
        ),
        def!(
            "x_ipc_classInfoMsg",
            Query,
            s("int"),
            s("*{int, format}"),
            ClassInfo
        ),
        def!(
            "classInfoMsg",
            Query,
            s("int"),
            s("*{int, format}"),
            ClassInfo
        ),
        def!(
            "ipc_setMsgPriority",
            Inform,
            s("{string, int}"),
            None,
            SetMsgPriority,
            false
        ),
        def!(
            "x_ipc_registerMessageMsg",
            Inform,
            s("{string, int, string, string}"),
            None,
            RegisterMessage
        ),
        def!(
            "registerMessageMsg",
            Inform,
            s("{string, int, string, string}"),
            None,
            RegisterMessage
        ),
        def!(
            "x_ipc_registerHandlerMsg",
            Inform,
            s("{int, string, string}"),
            None,
            RegisterHandler
        ),
        def!(
            "registerHandlerMsg",
            Inform,
            s("{int, string, string}"),
            None,
            RegisterHandler
        ),
        def!(
            "x_ipc_deregisterHandlerMsg",
            Inform,
            s("{int, string, string}"),
            None,
            DeregisterHandler
        ),
        def!(
            "deregisterHandlerMsg",
            Inform,
            s("{int, string, string}"),
            None,
            DeregisterHandler
        ),
        def!(
            "x_ipc_registerNamedFormMsg",
            Inform,
            s("{string, string}"),
            None,
            RegisterNamedForm
        ),
        def!(
            "registerNamedFormMsg",
            Inform,
            s("{string, string}"),
            None,
            RegisterNamedForm
        ),
        def!(
            "x_ipc_getNamedFormMsg",
            Query,
            s("string"),
            s("format"),
            GetNamedForm
        ),
        def!("x_ipc_waitMsg", Query, None, s("int"), Wait),
        def!("waitMsg", Query, None, s("int"), Wait),
        def!(
            "x_ipc_ignoreLogging",
            Inform,
            s("string"),
            None,
            IgnoreLogging
        ),
        def!("ignoreLogging", Inform, s("string"), None, IgnoreLogging),
        def!(
            "x_ipc_resumeLogging",
            Inform,
            s("string"),
            None,
            ResumeLogging
        ),
        def!("resumeLogging", Inform, s("string"), None, ResumeLogging),
        def!("x_ipc_CloseMsg", Inform, None, None, Close),
        def!("x_ipcCloseMsg", Inform, None, None, Close),
        def!(
            "x_ipc_directResMsg",
            Inform,
            s("{int, string}"),
            None,
            DirectRes
        ),
        def!("directResMsg", Inform, s("{int, string}"), None, DirectRes),
        def!(
            "x_ipc_directInfoMsg",
            Query,
            s("string"),
            s(DIRECT_INFO_FORMAT),
            DirectInfo
        ),
        def!(
            "directInfoMsg",
            Query,
            s("string"),
            s(DIRECT_INFO_FORMAT),
            DirectInfo
        ),
        def!(
            "x_ipc_directMsgQuery",
            Query,
            s("string"),
            s(DIRECT_MSG_FORMAT),
            DirectMsg
        ),
        def!(CONNECT_NOTIFY, Broadcast, s("string"), None, Notify),
        def!(DISCONNECT_NOTIFY, Broadcast, s("string"), None, Notify),
        def!(
            "x_ipc_moduleConnectedQ",
            Query,
            s("string"),
            s("int"),
            ModuleConnected
        ),
        def!(
            "x_ipc_notifyHandlerChange",
            Inform,
            s("string"),
            None,
            NotifyHandlerChange
        ),
        def!(
            "x_ipc_registerResourceMsg",
            Inform,
            s("{int, string}"),
            None,
            RegisterResource
        ),
        def!(
            "registerResourceMsg",
            Inform,
            s("{int, string}"),
            None,
            RegisterResource
        ),
        def!(
            "x_ipc_limitPendingMsg",
            Inform,
            s("{string, string, int}"),
            None,
            LimitPending
        ),
        def!(
            "limitPendingMsg",
            Inform,
            s("{string, string, int}"),
            None,
            LimitPending
        ),
        def!(
            REGISTER_GLOBAL_VAR,
            Inform,
            s("{string, string}"),
            None,
            Ignored
        ),
    ]
}

/// A variable message: name, class, message format, reply format, handler.
pub(super) type VarDef = (String, MsgClass, Option<String>, Option<String>, Internal);

/// The messages of a global variable (`centralRegisterVar`, globalVar.c).
pub(super) fn var_defs(var: &str) -> [VarDef; 4] {
    let f = |s: &str| Some(s.to_string());
    let fmt = var_format(var);
    [
        (
            format!("V_get_{var}"),
            MsgClass::Query,
            None,
            f(&fmt),
            Internal::VarGet(var.into()),
        ),
        (
            format!("V_set_{var}"),
            MsgClass::Inform,
            f(&fmt),
            None,
            Internal::VarSet(var.into()),
        ),
        (
            format!("V_get_set_{var}"),
            MsgClass::Query,
            f(&fmt),
            f(&fmt),
            Internal::VarGetSet(var.into()),
        ),
        (
            format!("V_watch_{var}"),
            MsgClass::Broadcast,
            f(&fmt),
            None,
            Internal::VarWatch(var.into()),
        ),
    ]
}

/// The format text central's `x_ipc_registerGlobalVar` carries for a
/// variable, as the C central writes it (and its data log prints it): the
/// log variables' `LOG_TYPE` without spaces, a handler list through the
/// named format `directMsgHandler`, not expanded.
pub(super) fn var_format_text(var: &str) -> &'static str {
    match var {
        TERMINAL_LOG_VAR | FILE_LOG_VAR => "{*int,int,int,int,int,int,int,int,int,int,int,int}",
        TAPPED_MSG_VAR | BROADCAST_MSG_VAR => STR_LIST_FORMAT,
        _ => "{int, <directMsgHandler: 1>}",
    }
}

/// The format of a variable: the four built-in ones, else a handler list.
pub(super) fn var_format(var: &str) -> String {
    match var {
        TERMINAL_LOG_VAR | FILE_LOG_VAR => LOG_VAR_FORMAT.into(),
        TAPPED_MSG_VAR | BROADCAST_MSG_VAR => STR_LIST_FORMAT.into(),
        _ => DIRECT_MSG_FORMAT.into(),
    }
}

/// The class-data format central registers for a class (`classInitialize`),
/// as the C central answers `x_ipc_classInfoMsg`.
pub(super) fn class_format(class: i32) -> Option<&'static str> {
    const MON: &str = "{{int, {int, int}}, {int, {int, int}}, *{int, int, int, int, int}}";
    Some(match class {
        2 | 13 => "string",
        4 | 7 | 9 | 14 => "int",
        5 | 16 => "{int, int}",
        8 | 10 => MON,
        _ => return None,
    })
}

/// Parses one of the constant formats above.
pub(super) fn fixed(s: &str) -> Format {
    parse(s).unwrap_or(Format::Empty)
}

/// A STR_LIST `{int length, int size, <string:2>}`: `size` grows in steps
/// of 4 as in C; unused slots are NULL strings.
pub(super) fn encode_str_list(items: &[String], size: usize, w: &mut Writer) {
    w.write_i32(items.len() as i32);
    w.write_i32(size as i32);
    w.write_len(size);
    for i in 0..size {
        w.write_str(items.get(i).map(String::as_str).unwrap_or(""));
    }
}

/// The STR_LIST capacity C would have after `len` pushes.
pub(super) fn str_list_size(len: usize, current: usize) -> usize {
    let mut size = current;
    while size < len {
        size += 4;
    }
    size
}

/// A formatter, or NULL.
pub(super) fn write_formatter(w: &mut Writer, f: Option<&Format>) {
    encode_formatter(f, w);
}
