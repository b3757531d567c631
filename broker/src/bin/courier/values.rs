//! The values samples carry: the types the CLI knows by name, how a
//! sample's bytes decode to a dynamic [`Value`] through its format, and
//! how values print (as central's data log does, or as JSON through
//! serde) and parse (JSON, or plain text for a `string`).

use courier::format::{self, Format};
use courier::ipc::value::{Typed, ValueSeed};
use courier::ipc::{ByteOrder, Value};
use courier::IpcMessage;
use serde::de::DeserializeSeed;

use crate::text::hex;

/// The sample `courier ping` sends (DDS type `courier::Ping`).
#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "courier::Ping")]
pub struct Ping {
    pub seq: u32,
    /// Nanoseconds since the Unix epoch when sent.
    pub stamp_ns: u64,
    pub text: String,
}

/// ROS 2's `std_msgs/msg/String` (what `ros2 topic pub /chatter
/// std_msgs/String` sends).
#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "std_msgs::msg::dds_::String_")]
pub struct RosString {
    pub data: String,
}

/// A DDS type the CLI can decode and encode: its CDR goes through the
/// derived Rust type to the IPC encoding of the same format, which the
/// dynamic [`Value`] reads.
#[derive(Debug, Clone, Copy)]
pub struct Known {
    pub type_name: &'static str,
    pub format: &'static str,
    cdr_to_ipc: fn(&[u8]) -> Result<Vec<u8>, String>,
    ipc_to_cdr: fn(&[u8]) -> Result<Vec<u8>, String>,
}

fn cdr_to_ipc<T: IpcMessage>(data: &[u8]) -> Result<Vec<u8>, String> {
    let v: T = courier::cdr::from_slice(data).map_err(|e| e.to_string())?;
    Ok(courier::ipc::to_vec(&v))
}

fn ipc_to_cdr<T: IpcMessage>(data: &[u8]) -> Result<Vec<u8>, String> {
    let v: T = courier::ipc::from_slice(data).map_err(|e| e.to_string())?;
    Ok(courier::cdr::to_vec(&v, courier::cdr::Encoding::Xcdr1Le))
}

const fn known<T: IpcMessage>() -> Known {
    Known {
        type_name: T::TYPE_NAME,
        format: T::FORMAT,
        cdr_to_ipc: cdr_to_ipc::<T>,
        ipc_to_cdr: ipc_to_cdr::<T>,
    }
}

/// The DDS types the CLI knows: its own, ROS 2's string, and the
/// primitives by their DDS names (`int32`, `double`, `string`, … : what a
/// Courier session publishes an `i32` or a `String` as).
pub const KNOWN: &[Known] = &[
    known::<Ping>(),
    known::<RosString>(),
    known::<i8>(),
    known::<u8>(),
    known::<i16>(),
    known::<u16>(),
    known::<i32>(),
    known::<u32>(),
    known::<i64>(),
    known::<u64>(),
    known::<f32>(),
    known::<f64>(),
    known::<bool>(),
    known::<String>(),
];

/// The known type of that DDS name.
pub fn known_type(type_name: &str) -> Option<&'static Known> {
    KNOWN.iter().find(|k| k.type_name == type_name)
}

/// The names of the known types, for messages.
pub fn known_names() -> String {
    KNOWN
        .iter()
        .map(|k| k.type_name)
        .collect::<Vec<_>>()
        .join(", ")
}

impl Known {
    /// Its format, parsed.
    pub fn parsed(&self) -> Format {
        format::parse(self.format).expect("derived formats parse")
    }

    /// A CDR sample of this type as a value of its format.
    pub fn decode(&self, cdr: &[u8]) -> Result<(Format, Value), String> {
        let ipc = (self.cdr_to_ipc)(cdr)?;
        let f = self.parsed();
        let v = Value::from_ipc_bytes(&f, &ipc, ByteOrder::NATIVE).map_err(|e| e.to_string())?;
        Ok((f, v))
    }

    /// A value of its format as a CDR sample.
    pub fn encode(&self, v: &Value) -> Result<Vec<u8>, String> {
        let ipc = v.to_ipc_bytes(&self.parsed()).map_err(|e| e.to_string())?;
        (self.ipc_to_cdr)(&ipc)
    }
}

/// Parses an IPC format string given on the command line (named formats
/// are refused: the command line has no registry).
pub fn parse_format(s: &str) -> Result<Format, String> {
    let f = format::parse(s).map_err(|e| format!("{s:?} is not an IPC format: {e}"))?;
    if has_named(&f) {
        return Err(format!(
            "{s:?} refers to a named format; spell it out (central sends formats expanded)"
        ));
    }
    Ok(f)
}

fn has_named(f: &Format) -> bool {
    match f {
        Format::Named(_) => true,
        Format::Struct(fs) => fs.iter().any(has_named),
        Format::Pointer(e)
        | Format::FixedArray { elem: e, .. }
        | Format::VarArray { elem: e, .. } => has_named(e),
        _ => false,
    }
}

/// A sample decoded, or its bytes when no format is known for it.
pub enum Decoded {
    Value(Format, Value),
    Bytes(Vec<u8>),
}

/// How a sample prints.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Style {
    /// One line, as central's data log prints data.
    Text,
    /// One JSON document a line (see `courier_wire::ipc::value::Typed`).
    Json,
}

impl Decoded {
    /// IPC bytes through `fmt` (`None`: bytes as they are).
    pub fn ipc(fmt: Option<&Format>, data: &[u8], order: ByteOrder) -> Result<Decoded, String> {
        match fmt {
            Some(f) => Value::from_ipc_bytes(f, data, order)
                .map(|v| Decoded::Value(f.clone(), v))
                .map_err(|e| format!("does not decode as {f}: {e}")),
            None => Ok(Decoded::Bytes(data.to_vec())),
        }
    }

    /// A DDS sample (CDR) laid out as `fmt` (see `cdr_value`).
    pub fn cdr(fmt: &Format, data: &[u8]) -> Result<Decoded, String> {
        crate::cdr_value::decode(fmt, data)
            .map(|v| Decoded::Value(fmt.clone(), v))
            .map_err(|e| format!("does not decode as {fmt}: {e}"))
    }

    /// A DDS sample (CDR) of `type_name`: decoded when the type is known.
    pub fn dds(type_name: Option<&str>, data: &[u8]) -> Result<Decoded, String> {
        match type_name.and_then(known_type) {
            Some(k) => k
                .decode(data)
                .map(|(f, v)| Decoded::Value(f, v))
                .map_err(|e| format!("does not decode as {}: {e}", k.type_name)),
            None => Ok(Decoded::Bytes(data.to_vec())),
        }
    }

    pub fn print(&self, style: Style) -> String {
        match (self, style) {
            (Decoded::Value(f, v), Style::Text) => courier::ipc::print_value(f, v),
            (Decoded::Value(f, v), Style::Json) => serde_json::to_string(&Typed::new(f, v))
                .unwrap_or_else(|e| format!("{{\"error\":{:?}}}", e.to_string())),
            (Decoded::Bytes(b), Style::Text) => hex(b),
            (Decoded::Bytes(b), Style::Json) => {
                let hex: String = b.iter().map(|x| format!("{x:02x}")).collect();
                format!("{{\"hex\":\"{hex}\"}}")
            }
        }
    }
}

/// The serialized key of a dispose or unregister (CDR, encapsulation
/// header first) as a value of the sample's format `fmt`: decoded as the
/// whole format when its bytes are a whole sample (writers that send one),
/// else as the shortest run of `fmt`'s leading fields that its bytes fill
/// exactly (keys are usually the first fields; a format does not say which
/// are keys). `None` when neither fits.
pub fn decode_key(fmt: &Format, data: &[u8]) -> Option<Decoded> {
    if let Ok(d) = Decoded::cdr(fmt, data) {
        return Some(d);
    }
    let Format::Struct(fields) = fmt else {
        return None;
    };
    (1..fields.len()).find_map(|n| Decoded::cdr(&Format::Struct(fields[..n].to_vec()), data).ok())
}

/// A value given on the command line, of format `fmt`: JSON (see
/// `courier_wire::ipc::value::ValueSeed`), or, for a format a JSON string
/// fits (`string`, `char`, an enum's name, `format`), the text itself when
/// it is not JSON: `hello world`, `Send`. The same holds for a struct
/// whose only field takes text (`{string}`, ROS 2's `std_msgs/String`),
/// which also takes a JSON string (`"hello"` for `["hello"]`).
pub fn parse_value(fmt: &Format, text: &str) -> Result<Value, String> {
    let mut de = serde_json::Deserializer::from_str(text);
    let json = ValueSeed::new(fmt)
        .deserialize(&mut de)
        .and_then(|v| de.end().map(|()| v));
    let e = match json {
        Ok(v) => return Ok(v),
        Err(e) => e,
    };
    // the text the value stands for: all of it when it is not JSON, the
    // string when it is a JSON string given for a struct around one
    let bare = if e.is_syntax() || e.is_eof() {
        Some(text.to_string())
    } else if matches!(fmt, Format::Struct(_)) {
        serde_json::from_str::<String>(text).ok()
    } else {
        None
    };
    match bare.and_then(|t| as_text(fmt, t)) {
        Some(j) => ValueSeed::new(fmt)
            .deserialize(j)
            .map_err(|e| format!("{text:?} is not a value of {fmt}: {e}")),
        None => Err(format!("{text:?} is not a value of {fmt}: {e}")),
    }
}

/// The JSON `text` stands for as a value of `fmt`, when `fmt` takes text:
/// a string for a `string`, `char`, enum or `format`, inside one array for
/// each struct of one field around one.
fn as_text(fmt: &Format, text: String) -> Option<serde_json::Value> {
    match fmt {
        Format::Primitive(
            format::Primitive::String | format::Primitive::Char | format::Primitive::Format,
        )
        | Format::Enum { .. } => Some(serde_json::Value::String(text)),
        Format::Struct(fields) if fields.len() == 1 => {
            as_text(&fields[0], text).map(|v| serde_json::Value::Array(vec![v]))
        }
        _ => None,
    }
}

/// A sample's bytes for `spy`: decoded when the type is one the CLI
/// knows (`courier::Ping` as a Rust value, ROS 2's `String_` and the rest
/// as central's data log prints a value), else the first 64 bytes in hex
/// (`…` when there are more), `-` when there are none.
pub fn sample_text(type_name: &str, data: &[u8]) -> String {
    if type_name == Ping::TYPE_NAME {
        if let Ok(p) = courier::cdr::from_slice::<Ping>(data) {
            return format!(
                "courier::Ping {{ seq: {}, stamp_ns: {}, text: {:?} }}",
                p.seq, p.stamp_ns, p.text
            );
        }
    }
    match Decoded::dds(Some(type_name), data) {
        Ok(d @ Decoded::Value(..)) => format!("{type_name} {}", d.print(Style::Text)),
        _ => hex(data),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn samples_print_decoded_or_as_bounded_hex() {
        let p = Ping {
            seq: 7,
            stamp_ns: 9,
            text: "hi".into(),
        };
        let data = courier::cdr::to_vec(&p, courier::cdr::Encoding::Xcdr1Le);
        assert_eq!(
            sample_text("courier::Ping", &data),
            "courier::Ping { seq: 7, stamp_ns: 9, text: \"hi\" }"
        );
        // an unknown type (or one that does not decode): hex, 64 bytes at most
        assert_eq!(sample_text("x::Y", &[0xab, 0x01]), "ab01");
        assert_eq!(sample_text("courier::Ping", &[0xab]), "ab");
        assert_eq!(sample_text("x::Y", &[]), "-");
        // XCDR2 decodes too, and the encapsulation says which it is
        let x2 = courier::cdr::to_vec(&p, courier::cdr::Encoding::Xcdr2Le);
        assert_eq!(
            sample_text("courier::Ping", &x2),
            "courier::Ping { seq: 7, stamp_ns: 9, text: \"hi\" }"
        );
        use crate::text::encapsulation_text;
        assert_eq!(encapsulation_text(&x2), "XCDR2 CDR2_LE");
        assert_eq!(encapsulation_text(&data), "XCDR1 CDR_LE");
        assert_eq!(encapsulation_text(&[0x00, 0x0b, 0, 0]), "XCDR2 PL_CDR2_LE");
        assert_eq!(encapsulation_text(&[0x00, 0x09]), "XCDR2 D_CDR2_LE");
        assert_eq!(encapsulation_text(&[0x80, 0x01]), "unknown(0x8001)");
        assert_eq!(encapsulation_text(&[]), "-");
        // ROS 2's String_ (what `ros2 topic pub /chatter std_msgs/String` sends)
        let ros = courier::cdr::to_vec(
            &RosString {
                data: "hello".into(),
            },
            courier::cdr::Encoding::Xcdr1Le,
        );
        assert_eq!(
            sample_text("std_msgs::msg::dds_::String_", &ros),
            "std_msgs::msg::dds_::String_ {\"hello\"}"
        );
        // the same sample through the dynamic value
        let d = Decoded::dds(Some("courier::Ping"), &data).unwrap();
        assert_eq!(d.print(Style::Text), "{7, 9, \"hi\"}");
        assert_eq!(d.print(Style::Json), "[7,9,\"hi\"]");
        let d = Decoded::dds(Some("x::Y"), &[1, 2]).unwrap();
        assert_eq!(d.print(Style::Json), "{\"hex\":\"0102\"}");
        assert!(Decoded::dds(Some("courier::Ping"), &[1]).is_err());
    }

    #[test]
    fn known_types_round_trip_through_values() {
        let k = known_type("courier::Ping").unwrap();
        let v = parse_value(&k.parsed(), r#"[3, 4, "x"]"#).unwrap();
        let cdr = k.encode(&v).unwrap();
        let p: Ping = courier::cdr::from_slice(&cdr).unwrap();
        assert_eq!((p.seq, p.stamp_ns, p.text.as_str()), (3, 4, "x"));
        assert!(known_type("std_msgs::msg::dds_::String_").is_some());
    }

    #[test]
    fn values_from_the_command_line() {
        let s = parse_format("string").unwrap();
        assert_eq!(
            parse_value(&s, "hello world").unwrap(),
            Value::from("hello world")
        );
        assert_eq!(
            parse_value(&s, "\"quoted\"").unwrap(),
            Value::from("quoted")
        );
        let i = parse_format("{int, double}").unwrap();
        assert_eq!(
            parse_value(&i, "[1, 2.5]").unwrap(),
            Value::Struct(vec![Value::Int(1), Value::Double(2.5)])
        );
        let e = parse_format("{enum Wait, Send}").unwrap();
        assert_eq!(parse_value(&e, "Send").unwrap(), Value::Enum(1));
        assert_eq!(parse_value(&e, "1").unwrap(), Value::Enum(1));
        let err = parse_value(&e, "Sned").unwrap_err();
        assert!(err.contains("expected one of Wait, Send"), "{err}");
        let c = parse_format("char").unwrap();
        assert_eq!(parse_value(&c, "x").unwrap(), Value::Char(b'x'));
        let e = parse_value(&i, "1 2").unwrap_err();
        assert!(e.contains("is not a value of {int, double}"), "{e}");
        // a struct whose only field takes text (ROS 2's std_msgs/String):
        // plain text, a JSON string, or JSON as the struct
        let ros = known_type("std_msgs::msg::dds_::String_").unwrap().parsed();
        for text in ["hello world", "\"hello world\"", "[\"hello world\"]"] {
            assert_eq!(
                parse_value(&ros, text).unwrap(),
                Value::Struct(vec![Value::from("hello world")]),
                "{text}"
            );
        }
        let nested = parse_format("{{enum Wait, Send}}").unwrap();
        assert_eq!(
            parse_value(&nested, "Send").unwrap(),
            Value::Struct(vec![Value::Enum(1)])
        );
        // a struct of more fields takes JSON only
        let e = parse_value(&known_type("courier::Ping").unwrap().parsed(), "hello").unwrap_err();
        assert!(
            e.starts_with("\"hello\" is not a value of {uint, ulong, string}: "),
            "{e}"
        );
        let e = parse_format("{int, T1}").unwrap_err();
        assert!(e.contains("named format"), "{e}");
        let e = parse_format("{int").unwrap_err();
        assert!(e.contains("is not an IPC format"), "{e}");
    }
}
