//! What a module can ask central about everyone else: the C central's
//! `x_ipc_getMessages` (every message name) and `x_ipc_getMessageInfo`
//! (one message's formats, class and handlers), and Courier's own
//! `courier_getModules` (every connected module), with the encoders central
//! answers with and the decoders a module reads the answers with.
//!
//! The C central knows the first two (`centralMsg.h`,
//! `X_IPC_MESSAGES_QUERY`, `X_IPC_MESSAGE_INFO_QUERY`); it answers the
//! third as it answers any message nobody defined, so a module learns that
//! its central is not Courier's from that failure.

use super::{ByteOrder, DecodeError, Reader, Writer};

/// `X_IPC_MESSAGES_QUERY`: no query data, a string list back.
pub const GET_MESSAGES: &str = "x_ipc_getMessages";
/// `X_IPC_MESSAGE_INFO_QUERY`: the message name, its details back.
pub const GET_MESSAGE_INFO: &str = "x_ipc_getMessageInfo";
/// Courier's central only: no query data, the modules back.
pub const GET_MODULES: &str = "courier_getModules";

/// `X_IPC_MESSAGE_INFO_QUERY_FORMAT`.
pub const MESSAGE_INFO_QUERY_FORMAT: &str = "{string}";
/// `X_IPC_MESSAGE_INFO_QUERY_REPLY`: name, message format, reply format,
/// class, the first handler's resource (module), number of handlers.
pub const MESSAGE_INFO_REPLY_FORMAT: &str = "{string,string,string,int,string,int}";
/// [`GET_MODULES`]' reply: how many, then each module's name, host,
/// number of handlers and messages waiting for it.
pub const MODULES_REPLY_FORMAT: &str = "{int, <{string, string, int, int}:1>}";

/// What central says of one message (`x_ipc_getMessageInfo`).
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct MessageDetails {
    /// The message's name.
    pub name: String,
    /// The format of its frames' body as registered (`None`: no format, or
    /// unknown message). For a message defined with `IPC_defineMsg` (C) or
    /// `Session::define` (Courier) this is the wrapper,
    /// `{int, <byte:1>}` for variable length or `[byte:N]` for fixed: the
    /// data's own format is then [`reply_format`](Self::reply_format).
    pub msg_format: Option<String>,
    /// The second format central holds (its `resFormat`): for a query
    /// registered as such, its reply's format; for a message defined with
    /// `IPC_defineMsg`, the format of its data (what `courier echo` decodes
    /// by).
    pub reply_format: Option<String>,
    /// Its class (`MsgClass` number: 6 publish/inform, 4 query, … ; 0 when
    /// central does not know the message).
    pub class: i32,
    /// The resource (module) of its first handler.
    pub resource: Option<String>,
    /// How many handlers subscribe it.
    pub handlers: i32,
}

/// One module connected to central (`courier_getModules`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ModuleDetails {
    /// Its name (`IPC_connect`'s argument).
    pub name: String,
    /// The host it said it runs on.
    pub host: String,
    /// How many handlers it registered.
    pub handlers: i32,
    /// How many messages central holds for it.
    pub waiting: i32,
}

/// A question for central ([`crate::ipc::module::Connection::ask_central`]).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Ask {
    /// Every message's name ([`GET_MESSAGES`]).
    Messages,
    /// One message's details ([`GET_MESSAGE_INFO`]).
    MessageDetails(String),
    /// Every connected module ([`GET_MODULES`], Courier's central only).
    Modules,
}

impl Ask {
    /// The message central answers it on.
    pub fn message(&self) -> &'static str {
        match self {
            Ask::Messages => GET_MESSAGES,
            Ask::MessageDetails(_) => GET_MESSAGE_INFO,
            Ask::Modules => GET_MODULES,
        }
    }

    /// The query's data.
    pub fn encode(&self, w: &mut Writer) {
        if let Ask::MessageDetails(name) = self {
            w.write_str(name);
        }
    }

    /// Reads central's reply to it.
    pub fn decode(&self, data: &[u8], order: ByteOrder) -> Result<Answer, DecodeError> {
        Ok(match self {
            Ask::Messages => Answer::Messages(decode_messages(data, order)?),
            Ask::MessageDetails(_) => Answer::MessageDetails(decode_message_details(data, order)?),
            Ask::Modules => Answer::Modules(decode_modules(data, order)?),
        })
    }
}

/// Central's answer to an [`Ask`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Answer {
    /// Every message's name, as central lists them.
    Messages(Vec<String>),
    /// One message's details.
    MessageDetails(MessageDetails),
    /// Every connected module, by name.
    Modules(Vec<ModuleDetails>),
}

fn opt(s: &str) -> Option<String> {
    (!s.is_empty()).then(|| s.to_owned())
}

/// Writes `x_ipc_getMessageInfo`'s reply.
pub fn encode_message_details(d: &MessageDetails, w: &mut Writer) {
    w.write_str(&d.name);
    w.write_str(d.msg_format.as_deref().unwrap_or(""));
    w.write_str(d.reply_format.as_deref().unwrap_or(""));
    w.write_i32(d.class);
    w.write_str(d.resource.as_deref().unwrap_or(""));
    w.write_i32(d.handlers);
}

/// Reads `x_ipc_getMessageInfo`'s reply.
pub fn decode_message_details(
    data: &[u8],
    order: ByteOrder,
) -> Result<MessageDetails, DecodeError> {
    let mut r = Reader::new(data, order);
    let name = r.read_str()?.to_owned();
    let msg_format = opt(r.read_str()?);
    let reply_format = opt(r.read_str()?);
    let class = r.read_i32()?;
    let resource = opt(r.read_str()?);
    let handlers = r.read_i32()?;
    Ok(MessageDetails {
        name,
        msg_format,
        reply_format,
        class,
        resource,
        handlers,
    })
}

/// Writes [`GET_MODULES`]' reply.
pub fn encode_modules(modules: &[ModuleDetails], w: &mut Writer) {
    // the count field, then the variable array with its own count
    w.write_len(modules.len());
    w.write_len(modules.len());
    for m in modules {
        w.write_str(&m.name);
        w.write_str(&m.host);
        w.write_i32(m.handlers);
        w.write_i32(m.waiting);
    }
}

/// Reads [`GET_MODULES`]' reply; a count the data cannot hold is an error,
/// not an allocation.
pub fn decode_modules(data: &[u8], order: ByteOrder) -> Result<Vec<ModuleDetails>, DecodeError> {
    let mut r = Reader::new(data, order);
    let field = r.read_i32()?;
    // each module takes at least two empty strings (5 bytes each) and two ints
    let n = r.read_count(18)?;
    if u64::try_from(field).ok() != Some(n as u64) {
        return Err(DecodeError::CountMismatch {
            offset: 4,
            expected: field.max(0) as u64,
            found: n as u64,
        });
    }
    let mut out = Vec::with_capacity(n);
    for _ in 0..n {
        out.push(ModuleDetails {
            name: r.read_str()?.to_owned(),
            host: r.read_str()?.to_owned(),
            handlers: r.read_i32()?,
            waiting: r.read_i32()?,
        });
    }
    Ok(out)
}

/// Reads `x_ipc_getMessages`' reply (`X_IPC_STR_LIST_FORMAT`: `{int length,
/// int size, <string:2>}`; an empty reply is an empty list), in central's
/// order.
pub fn decode_messages(data: &[u8], order: ByteOrder) -> Result<Vec<String>, DecodeError> {
    if data.is_empty() {
        return Ok(Vec::new());
    }
    let mut r = Reader::new(data, order);
    let length = r.read_i32()?;
    let _size = r.read_i32()?;
    let count = r.read_count(5)?;
    let mut out = Vec::with_capacity(count);
    for i in 0..count {
        let s = r.read_str()?;
        if (i as i64) < i64::from(length) && !s.is_empty() {
            out.push(s.to_owned());
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::format;
    use crate::ipc::{decode_value, print_value};

    /// The replies are laid out as their format strings say: the generic
    /// decoder reads what the encoders write.
    #[test]
    fn replies_follow_their_formats() {
        let d = MessageDetails {
            name: "m".into(),
            msg_format: Some("int".into()),
            reply_format: None,
            class: 6,
            resource: Some("mod".into()),
            handlers: 2,
        };
        let mut w = Writer::new();
        encode_message_details(&d, &mut w);
        let bytes = w.into_vec();
        // golden: "m", "int", NULL, 6, "mod", 2 (little-endian)
        assert_eq!(
            bytes,
            [
                1, 0, 0, 0, b'm', 3, 0, 0, 0, b'i', b'n', b't', 0, 0, 0, 0, b'Z', 6, 0, 0, 0, 3, 0,
                0, 0, b'm', b'o', b'd', 2, 0, 0, 0
            ]
        );
        let f = format::parse(MESSAGE_INFO_REPLY_FORMAT).unwrap();
        let v = decode_value(&f, &mut Reader::new(&bytes, ByteOrder::Little)).unwrap();
        assert_eq!(print_value(&f, &v), r#"{"m", "int", "NULL", 6, "mod", 2}"#);
        assert_eq!(
            decode_message_details(&bytes, ByteOrder::Little).unwrap(),
            d
        );

        let mods = vec![
            ModuleDetails {
                name: "a".into(),
                host: "h".into(),
                handlers: 1,
                waiting: 0,
            },
            ModuleDetails {
                name: "b".into(),
                host: String::new(),
                handlers: 0,
                waiting: 3,
            },
        ];
        let mut w = Writer::new();
        encode_modules(&mods, &mut w);
        let bytes = w.into_vec();
        let f = format::parse(MODULES_REPLY_FORMAT).unwrap();
        let v = decode_value(&f, &mut Reader::new(&bytes, ByteOrder::Little)).unwrap();
        assert_eq!(
            print_value(&f, &v),
            r#"{2, <{"a", "h", 1, 0}, {"b", "NULL", 0, 3}>}"#
        );
        assert_eq!(decode_modules(&bytes, ByteOrder::Little).unwrap(), mods);
    }

    #[test]
    fn damaged_replies_are_errors() {
        assert!(decode_message_details(&[1, 0, 0], ByteOrder::Little).is_err());
        // a count of 2^31-1 modules in 4 bytes
        assert!(decode_modules(
            &[0xff, 0xff, 0xff, 0x7f, 0xff, 0xff, 0xff, 0x7f],
            ByteOrder::Little
        )
        .is_err());
        assert!(decode_modules(&[1, 0, 0, 0, 0, 0, 0, 0], ByteOrder::Little).is_err());
        assert!(decode_messages(&[1, 0, 0, 0, 9, 0, 0, 0, 5, 0, 0, 0], ByteOrder::Little).is_err());
        assert_eq!(
            decode_messages(&[], ByteOrder::Little).unwrap(),
            Vec::<String>::new()
        );
    }
}
