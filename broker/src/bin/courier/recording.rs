//! What a channel of a Courier recording (MCAP) says, written by `courier
//! record` and read by `courier replay`, so that other MCAP tools
//! (Foxglove, the `mcap` CLI, Python's `mcap`) can read it too.
//!
//! A channel is one topic (IPC message) of one type:
//! - recorded on IPC: message encoding `ipc` (the bytes as IPC marshals
//!   them, in the byte order of channel metadata `byte_order`), schema
//!   named after the message, encoding `ipc-format`, whose data is the
//!   message's IPC format string (no schema when central holds none);
//! - recorded on DDS: message encoding `cdr` (the sample with its
//!   encapsulation header, XCDR1 or XCDR2 as the writer sent it), schema
//!   named after the DDS type: encoding `omgidl` with the type in OMG IDL
//!   when Courier knows its layout, else no encoding and no data (the name
//!   alone).
//!
//! Channel metadata: `ipc_format` (the IPC format that lays the samples
//! out, when known: what replay re-encodes through), `dds_type` (DDS),
//! `byte_order` (IPC), `recorded_on` (the URL scheme).

use std::collections::BTreeMap;
use std::fmt::Write as _;

use courier::format::{Format, Primitive};
use courier::ipc::ByteOrder;

/// Message encoding of IPC-marshalled samples.
pub const ENC_IPC: &str = "ipc";
/// Message encoding of DDS samples (CDR with its encapsulation header).
pub const ENC_CDR: &str = "cdr";
/// Schema encoding of an IPC format string.
pub const SCHEMA_IPC_FORMAT: &str = "ipc-format";
/// Schema encoding of OMG IDL text.
pub const SCHEMA_OMGIDL: &str = "omgidl";
/// Schema encoding of a ROS 2 `.msg` definition (ROS 2 bags).
pub const SCHEMA_ROS2MSG: &str = "ros2msg";

/// Channel metadata: the IPC format that lays the samples out.
pub const META_FORMAT: &str = "ipc_format";
/// Channel metadata: the DDS type name (recorded on DDS).
pub const META_TYPE: &str = "dds_type";
/// Channel metadata: the byte order of IPC samples (`little`, `big`).
pub const META_ORDER: &str = "byte_order";
/// Channel metadata: the URL scheme of the session recorded.
pub const META_SCHEME: &str = "recorded_on";

/// A schema: name, encoding, data.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SchemaDesc {
    /// The type's name (IPC: the message's).
    pub name: String,
    /// `ipc-format`, `omgidl`, … (empty: the name alone).
    pub encoding: String,
    /// The schema text.
    pub data: Vec<u8>,
}

/// A channel as `courier record` writes it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ChannelDesc {
    /// The topic (IPC message) name.
    pub topic: String,
    /// The message encoding: [`ENC_IPC`] or [`ENC_CDR`].
    pub encoding: &'static str,
    /// The schema, when there is one.
    pub schema: Option<SchemaDesc>,
    /// `META_*` keys.
    pub metadata: BTreeMap<String, String>,
}

fn order_name(o: ByteOrder) -> &'static str {
    match o {
        ByteOrder::Little => "little",
        ByteOrder::Big => "big",
    }
}

/// The byte order a channel's metadata names (`little` when it names none).
pub fn parse_order(meta: &BTreeMap<String, String>) -> Result<ByteOrder, String> {
    match meta.get(META_ORDER).map(String::as_str) {
        None | Some("little") => Ok(ByteOrder::Little),
        Some("big") => Ok(ByteOrder::Big),
        Some(o) => Err(format!("byte_order {o:?} is neither little nor big")),
    }
}

/// The channel of IPC message `msg`, samples in `order`, laid out as
/// `format` when central holds one.
pub fn ipc_channel(msg: &str, format: Option<&Format>, order: ByteOrder) -> ChannelDesc {
    let mut metadata = BTreeMap::new();
    metadata.insert(META_ORDER.into(), order_name(order).into());
    metadata.insert(META_SCHEME.into(), "ipc".into());
    let schema = format.map(|f| {
        metadata.insert(META_FORMAT.into(), f.to_string());
        SchemaDesc {
            name: msg.to_string(),
            encoding: SCHEMA_IPC_FORMAT.into(),
            data: f.to_string().into_bytes(),
        }
    });
    ChannelDesc {
        topic: msg.to_string(),
        encoding: ENC_IPC,
        schema,
        metadata,
    }
}

/// The channel of DDS topic `topic` of type `type_name`, laid out as
/// `format` (with these top-level field names) when Courier knows it.
pub fn dds_channel(
    scheme: &str,
    topic: &str,
    type_name: &str,
    format: Option<(&Format, &[&str])>,
) -> ChannelDesc {
    let mut metadata = BTreeMap::new();
    metadata.insert(META_TYPE.into(), type_name.to_string());
    metadata.insert(META_SCHEME.into(), scheme.to_string());
    let schema = match format {
        Some((f, names)) => {
            metadata.insert(META_FORMAT.into(), f.to_string());
            SchemaDesc {
                name: type_name.to_string(),
                encoding: SCHEMA_OMGIDL.into(),
                data: omgidl(type_name, f, names).into_bytes(),
            }
        }
        None => SchemaDesc {
            name: type_name.to_string(),
            encoding: String::new(),
            data: Vec::new(),
        },
    };
    ChannelDesc {
        topic: topic.to_string(),
        encoding: ENC_CDR,
        schema: Some(schema),
        metadata,
    }
}

/// The DDS type name of a ROS 2 message type as ROS 2 bags name it:
/// `std_msgs/msg/String` is `std_msgs::msg::dds_::String_` on the wire.
pub fn ros2_dds_name(ros: &str) -> Option<String> {
    let parts: Vec<&str> = ros.split('/').collect();
    match parts.as_slice() {
        [pkg, kind, name] if !pkg.is_empty() && !name.is_empty() => {
            Some(format!("{pkg}::{kind}::dds_::{name}_"))
        }
        _ => None,
    }
}

/// Top-level field names of the DDS types Courier knows (their IPC formats
/// carry none).
pub fn known_field_names(type_name: &str) -> &'static [&'static str] {
    match type_name {
        "courier::Ping" => &["seq", "stamp_ns", "text"],
        "std_msgs::msg::dds_::String_" => &["data"],
        _ => &[],
    }
}

/// `type_name` (`a::b::T`) laid out as `f` (as `#[derive(IpcMessage)]`
/// lays it out in CDR), in OMG IDL: modules for the scopes, a `@final`
/// struct (XTypes would default to appendable) of
/// the top-level fields (named from `names`, else `f1`, `f2`, …; a format
/// that is not a struct is one field `data`), and a struct or enum for
/// each nested struct or named enum (`T_f2`, …). Only layouts with CDR
/// forms reach here (`cdr_value::check`).
pub fn omgidl(type_name: &str, f: &Format, names: &[&str]) -> String {
    let mut scopes: Vec<&str> = type_name.split("::").filter(|s| !s.is_empty()).collect();
    let name = scopes.pop().unwrap_or("Type").to_string();
    let fields: Vec<Format> = match f {
        Format::Struct(fs) => fs.clone(),
        other => vec![other.clone()],
    };
    let single = !matches!(f, Format::Struct(_));
    let mut defs = Vec::new();
    let mut body = String::new();
    for (i, fld) in fields.iter().enumerate() {
        let fname = if single {
            names.first().copied().unwrap_or("data").to_string()
        } else {
            names
                .get(i)
                .map_or_else(|| format!("f{}", i + 1), |s| s.to_string())
        };
        let (ty, suffix) = idl_type(fld, &format!("{name}_{fname}"), &mut defs);
        let _ = writeln!(body, "  {ty} {fname}{suffix};");
    }
    let mut out = String::new();
    if !scopes.is_empty() {
        let open: Vec<String> = scopes.iter().map(|s| format!("module {s} {{")).collect();
        out.push_str(&open.join(" "));
        out.push('\n');
    }
    for d in defs {
        out.push_str(&d);
    }
    let _ = write!(out, "@final struct {name} {{\n{body}}};\n");
    if !scopes.is_empty() {
        out.push_str(&vec!["};"; scopes.len()].join(" "));
        out.push('\n');
    }
    out
}

/// The IDL type of a field and what follows its name (array bounds);
/// nested definitions go to `defs`, named `name`.
fn idl_type(f: &Format, name: &str, defs: &mut Vec<String>) -> (String, String) {
    match f {
        Format::Primitive(p) => (idl_primitive(*p).to_string(), String::new()),
        Format::Length(n) => ("octet".into(), format!("[{n}]")),
        Format::Struct(fs) => {
            let mut body = String::new();
            for (i, fld) in fs.iter().enumerate() {
                let (t, s) = idl_type(fld, &format!("{name}_f{}", i + 1), defs);
                let _ = writeln!(body, "  {t} f{}{s};", i + 1);
            }
            defs.push(format!("@final struct {name} {{\n{body}}};\n"));
            (name.to_string(), String::new())
        }
        Format::FixedArray { elem, dims } => {
            let (t, s) = idl_type(elem, name, defs);
            let bounds: String = dims.iter().map(|d| format!("[{d}]")).collect();
            (t, format!("{bounds}{s}"))
        }
        Format::VarArray { elem, .. } => {
            let (t, s) = idl_type(elem, name, defs);
            if s.is_empty() {
                (format!("sequence<{t}>"), String::new())
            } else {
                // a sequence of arrays: IDL needs a typedef for the element
                let alias = format!("{name}_elem");
                defs.push(format!("typedef {t} {alias}{s};\n"));
                (format!("sequence<{alias}>"), String::new())
            }
        }
        Format::Enum { names, .. } if !names.is_empty() => {
            defs.push(format!("enum {name} {{ {} }};\n", names.join(", ")));
            (name.to_string(), String::new())
        }
        // `{enum : max}`: a 32-bit value
        Format::Enum { .. } => ("int32".into(), String::new()),
        // `*T`: an optional member, as the derive lays out `Option<Box<T>>`
        Format::Pointer(elem) => {
            let (t, s) = idl_type(elem, name, defs);
            (format!("@optional {t}"), s)
        }
        // no CDR layout (refused before a schema is made); a pointer to
        // the enclosing struct would need a forward declaration the
        // schema does not write
        Format::Empty | Format::SelfPointer | Format::Named(_) => ("octet".into(), "[0]".into()),
    }
}

fn idl_primitive(p: Primitive) -> &'static str {
    match p {
        Primitive::Char => "char",
        Primitive::Byte => "int8",
        Primitive::UByte => "uint8",
        Primitive::Short => "int16",
        Primitive::UShort | Primitive::TwoByte => "uint16",
        Primitive::Int => "int32",
        Primitive::UInt => "uint32",
        Primitive::Long => "int64",
        Primitive::ULong => "uint64",
        Primitive::Float => "float",
        Primitive::Double => "double",
        Primitive::Boolean => "boolean",
        Primitive::String | Primitive::Format => "string",
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use courier::IpcMessage;

    fn fmt(s: &str) -> Format {
        courier::format::parse(s).unwrap()
    }

    #[test]
    fn known_types_get_idl_with_their_field_names() {
        let f = fmt(crate::values::Ping::FORMAT);
        assert_eq!(
            omgidl("courier::Ping", &f, known_field_names("courier::Ping")),
            "module courier {\n\
             @final struct Ping {\n  uint32 seq;\n  uint64 stamp_ns;\n  string text;\n};\n};\n"
        );
        assert_eq!(
            omgidl(
                "std_msgs::msg::dds_::String_",
                &fmt("string"),
                known_field_names("std_msgs::msg::dds_::String_")
            ),
            "module std_msgs { module msg { module dds_ {\n\
             @final struct String_ {\n  string data;\n};\n}; }; };\n"
        );
    }

    #[test]
    fn nested_layouts_get_definitions() {
        let f = fmt("{int, <{double, double}:1>, [ushort:2,3], {enum Wait, Send}, 4, <[int:2]:1>}");
        assert_eq!(
            omgidl("Path", &f, &[]),
            "@final struct Path_f2 {\n  double f1;\n  double f2;\n};\n\
             enum Path_f4 { Wait, Send };\n\
             typedef int32 Path_f6_elem[2];\n\
             @final struct Path {\n  int32 f1;\n  sequence<Path_f2> f2;\n  uint16 f3[2][3];\n  \
             Path_f4 f4;\n  octet f5[4];\n  sequence<Path_f6_elem> f6;\n};\n"
        );
    }

    /// A pointer is an optional member, as the derive writes
    /// `Option<Box<T>>` (it was a placeholder `octet f[0]`).
    #[test]
    fn pointers_are_optional_members() {
        let f = fmt("{int, *{double, double}, *int}");
        assert_eq!(
            omgidl("Scan", &f, &[]),
            "@final struct Scan_f2 {\n  double f1;\n  double f2;\n};\n\
             @final struct Scan {\n  int32 f1;\n  @optional Scan_f2 f2;\n  @optional int32 f3;\n};\n"
        );
    }

    #[test]
    fn channels_say_encoding_schema_and_metadata() {
        let f = fmt("{int, string}");
        let c = ipc_channel("status", Some(&f), ByteOrder::Little);
        assert_eq!((c.topic.as_str(), c.encoding), ("status", "ipc"));
        let s = c.schema.unwrap();
        assert_eq!(
            (s.name.as_str(), s.encoding.as_str()),
            ("status", "ipc-format")
        );
        assert_eq!(s.data, b"{int, string}");
        assert_eq!(c.metadata[META_FORMAT], "{int, string}");
        assert_eq!(parse_order(&c.metadata), Ok(ByteOrder::Little));
        let raw = ipc_channel("raw", None, ByteOrder::Big);
        assert!(raw.schema.is_none() && !raw.metadata.contains_key(META_FORMAT));
        assert_eq!(parse_order(&raw.metadata), Ok(ByteOrder::Big));
        let d = dds_channel("rtps", "t", "x::Y", None);
        let s = d.schema.unwrap();
        assert_eq!(
            (s.name.as_str(), s.encoding.as_str(), s.data.len()),
            ("x::Y", "", 0)
        );
        assert_eq!(d.metadata[META_TYPE], "x::Y");
        assert_eq!(
            ros2_dds_name("std_msgs/msg/String").as_deref(),
            Some("std_msgs::msg::dds_::String_")
        );
        assert_eq!(ros2_dds_name("String"), None);
        let mut bad = BTreeMap::new();
        bad.insert(META_ORDER.to_string(), "middle".to_string());
        assert!(parse_order(&bad).unwrap_err().contains("\"middle\""));
    }
}
