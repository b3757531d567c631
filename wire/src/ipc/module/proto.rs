//! Private encoders/decoders of the internal messages the module needs.
//! (To be merged with the central's `ipc::internal` once that exists.)

use std::collections::HashSet;

use super::{proto_err, DirectHandler, Error, Op};
use crate::format::{decode_formatter, Format, Primitive};
use crate::ipc::{ByteOrder, Reader, Writer};

/// A `x_ipc_msgInfoMsg` reply: what central knows about a message.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct MsgInfo {
    /// Central's id; negative = direct message; 0 = unknown to central.
    pub id: i32,
    /// Message name.
    pub name: String,
    /// Message class (15 = broadcast, 3 = query, …).
    pub class: i32,
    /// Wire format of the body (`{int, <byte:1>}`, `[byte:N]`, none).
    pub msg_format: Option<Format>,
    /// The user's format (resFormat).
    pub res_format: Option<Format>,
}

/// The message an operation needs the id of.
pub(super) fn op_message(op: &Op) -> Option<String> {
    let s: &str = match op {
        Op::ClassInfo(_) => "x_ipc_classInfoMsg",
        Op::NewModuleConnect => "x_ipc_newModuleConnectMsg",
        Op::WaitDirectPort => return None,
        Op::DirectRes(_) => "x_ipc_directResMsg",
        Op::VarGet(v) => v,
        Op::RegisterHandler { .. } => "x_ipc_registerHandlerMsg",
        Op::LimitPending { .. } => "x_ipc_limitPendingMsg",
        Op::WaitMsg => "x_ipc_waitMsg",
        Op::DefineFormat { .. } => "x_ipc_registerNamedFormMsg",
        Op::DefineMsg { .. } => "x_ipc_registerMessageMsg",
        Op::Lookup(n) | Op::LookUp { msg: n, .. } => n,
        Op::DirectQuery { .. } => "x_ipc_directMsgQuery",
        Op::Deregister { .. } => "x_ipc_deregisterHandlerMsg",
        Op::Publish { msg, .. } | Op::Query { msg, .. } | Op::Respond { msg, .. } => msg,
        Op::Inform { msg, .. } => msg,
        Op::ModuleConnectedQ { .. } => "x_ipc_moduleConnectedQ",
        Op::Ask { ask, .. } => ask.message(),
        Op::NumHandlers { .. } => "x_ipc_directMsgQuery",
        Op::NotifyHandlerChange { .. } => "x_ipc_notifyHandlerChange",
        Op::Close => "x_ipc_CloseMsg",
    };
    Some(s.to_string())
}

/// The parentRef an operation's frames (and its lookup) carry.
pub(super) fn op_parent(op: &Op) -> i32 {
    match op {
        Op::Publish { parent, .. } | Op::Query { parent, .. } | Op::Respond { parent, .. } => {
            *parent
        }
        _ => crate::ipc::frame::NO_REF,
    }
}

enum Body {
    Empty,
    Variable,
    Fixed(usize),
    Raw,
}

fn body_kind(info: &MsgInfo) -> Body {
    match &info.msg_format {
        None | Some(Format::Empty) => Body::Empty,
        Some(Format::Struct(f))
            if f.len() == 2
                && f[0] == Format::Primitive(Primitive::Int)
                && matches!(&f[1], Format::VarArray { elem, dims }
                    if **elem == Format::Primitive(Primitive::Byte) && dims == &[1]) =>
        {
            Body::Variable
        }
        Some(Format::FixedArray { elem, dims })
            if **elem == Format::Primitive(Primitive::Byte) && dims.len() == 1 =>
        {
            Body::Fixed(dims[0] as usize)
        }
        Some(_) => Body::Raw,
    }
}

/// Wraps user bytes into the message body (§9.1), moving them when the
/// body is the bytes themselves; an error gives them back.
pub(super) fn wrap(info: &MsgInfo, msg: &str, data: Vec<u8>) -> Result<Vec<u8>, (Error, Vec<u8>)> {
    Ok(match body_kind(info) {
        Body::Empty => Vec::new(),
        Body::Variable => {
            let mut w = Writer::with_capacity(8 + data.len());
            w.write_len(data.len());
            w.write_len(data.len());
            w.write_bytes(&data);
            w.into_vec()
        }
        Body::Fixed(n) => {
            if data.len() != n {
                let got = data.len();
                return Err((
                    Error::WrongLength {
                        msg: msg.into(),
                        expected: n,
                        got,
                    },
                    data,
                ));
            }
            data
        }
        Body::Raw => data,
    })
}

/// Unwraps a received body into the user bytes, in place.
pub(super) fn unwrap(
    info: &MsgInfo,
    mut body: Vec<u8>,
    order: ByteOrder,
) -> Result<Vec<u8>, Error> {
    match body_kind(info) {
        Body::Variable => {
            let e = |e| proto_err("variable-length body", e);
            let mut r = Reader::new(&body, order);
            let len = r.read_i32().map_err(e)?;
            let count = r.read_count(1).map_err(e)?;
            if len < 0 || len as usize != count {
                return Err(Error::Protocol {
                    what: "variable-length body",
                    detail: format!("length {len} disagrees with count {count}"),
                });
            }
            r.take(count).map_err(e)?;
            r.finish().map_err(e)?;
            // What is left is exactly the `count` bytes after the two ints.
            body.drain(..8);
            Ok(body)
        }
        _ => Ok(body),
    }
}

/// Decodes a msgInfo reply `*{int, string, int, format, format}`; `None` = NULL.
pub(super) fn decode_msg_info(data: &[u8], order: ByteOrder) -> Result<Option<MsgInfo>, Error> {
    let e = |e| proto_err("msgInfo reply", e);
    let mut r = Reader::new(data, order);
    if data.is_empty() || !r.read_ptr_flag().map_err(e)? {
        return Ok(None);
    }
    let id = r.read_i32().map_err(e)?;
    let name = r.read_str().map_err(e)?.to_string();
    let class = r.read_i32().map_err(e)?;
    let msg_format = decode_formatter(&mut r).map_err(e)?;
    let res_format = decode_formatter(&mut r).map_err(e)?;
    Ok(Some(MsgInfo {
        id,
        name,
        class,
        msg_format,
        res_format,
    }))
}

/// Decodes a STR_LIST `{int length, int size, <string:2>}`: the first
/// `length` names.
pub(super) fn decode_str_list(data: &[u8], order: ByteOrder) -> Result<HashSet<String>, Error> {
    let e = |e| proto_err("string list", e);
    let mut r = Reader::new(data, order);
    let mut out = HashSet::new();
    if data.is_empty() {
        return Ok(out);
    }
    let length = r.read_i32().map_err(e)?;
    let _size = r.read_i32().map_err(e)?;
    let count = r.read_count(5).map_err(e)?;
    for i in 0..count {
        let s = r.read_str().map_err(e)?;
        if (i as i64) < length as i64 && !s.is_empty() {
            out.insert(s.to_string());
        }
    }
    Ok(out)
}

/// Decodes `{int n, <directMsgHandler:1>}` (or an empty reply = none).
pub(super) fn decode_direct_handlers(
    data: &[u8],
    order: ByteOrder,
) -> Result<Vec<DirectHandler>, Error> {
    let e = |e| proto_err("direct handler list", e);
    let mut out = Vec::new();
    if data.is_empty() {
        return Ok(out);
    }
    let mut r = Reader::new(data, order);
    let _n = r.read_i32().map_err(e)?;
    let count = r.read_count(4 * 4 + 5 + 5).map_err(e)?;
    for _ in 0..count {
        let intent = r.read_i32().map_err(e)?;
        let _read_sd = r.read_i32().map_err(e)?;
        let _write_sd = r.read_i32().map_err(e)?;
        let port = r.read_i32().map_err(e)?;
        let host = r.read_str().map_err(e)?.to_string();
        let module = r.read_str().map_err(e)?.to_string();
        out.push(DirectHandler {
            intent,
            port,
            host,
            module,
        });
    }
    Ok(out)
}
