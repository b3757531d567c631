//! Helpers shared by the `ipc_*` tests (included with `#[path]`): format
//! strings, an independent big-endian encoder used as an oracle, hex and
//! fixture-file reading.
#![allow(dead_code)]

use courier_wire::format::{Format, Primitive};
use courier_wire::ipc::{ByteOrder, Value};

/// Parses a format string with `courier_wire::format::parse` ("" is the empty format).
pub fn fmt(s: &str) -> Format {
    if s.trim().is_empty() {
        return Format::Empty;
    }
    courier_wire::format::parse(s).unwrap_or_else(|e| panic!("{s:?}: {e}"))
}

/// Hex with optional spaces/newlines to bytes.
pub fn hex(s: &str) -> Vec<u8> {
    let h: String = s.chars().filter(|c| c.is_ascii_hexdigit()).collect();
    assert!(h.len() % 2 == 0, "odd hex {s:?}");
    (0..h.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&h[i..i + 2], 16).unwrap())
        .collect()
}

/// One frame of a fixture file (see the files' header comments).
#[derive(Debug)]
pub struct Entry {
    pub comment: String,
    pub format: String,
    pub payload: Option<String>,
    pub frame: Vec<u8>,
}

impl Entry {
    /// (byte order of the message data, message data) from the frame header (ipc.md §2).
    pub fn data(&self) -> (ByteOrder, &[u8]) {
        let word = |i: usize| u32::from_be_bytes(self.frame[i..i + 4].try_into().unwrap());
        let class_total = word(0) as usize;
        let msg_total = word(4) as usize;
        let class_id = word(16);
        let order = ByteOrder::from_nibble(((class_id >> 24) & 0xf) as u8).unwrap();
        let start = 28 + class_total;
        assert_eq!(self.frame.len(), start + msg_total, "{}", self.comment);
        (order, &self.frame[start..])
    }
}

/// Reads a fixture file.
pub fn entries(text: &str) -> Vec<Entry> {
    let mut out = Vec::new();
    let mut comment = String::new();
    let mut format = None;
    let mut payload = None;
    for line in text.lines() {
        if let Some(c) = line.strip_prefix("# [") {
            comment = format!("[{c}");
        } else if let Some(f) = line.strip_prefix("format: ") {
            format = Some(f.to_string());
        } else if let Some(p) = line.strip_prefix("payload: ") {
            payload = Some(p.to_string());
        } else if let Some(h) = line.strip_prefix("frame: ") {
            out.push(Entry {
                comment: comment.clone(),
                format: format.take().unwrap(),
                payload: payload.take(),
                frame: hex(h),
            });
        }
    }
    out
}

/// The user bytes inside a `{int, <byte:1>}` or `[byte:N]` body value.
pub fn inner_bytes(v: &Value) -> Vec<u8> {
    let items = match v {
        Value::Struct(f) => match &f[1] {
            Value::VarArray(items) => items,
            other => panic!("not a var array: {other:?}"),
        },
        Value::Array(items) => items,
        other => panic!("not a byte container: {other:?}"),
    };
    items
        .iter()
        .map(|b| match b {
            Value::Byte(b) => *b as u8,
            other => panic!("not a byte: {other:?}"),
        })
        .collect()
}

/// An independent big-endian encoder (test oracle; no named formats, no
/// consistency checks): what a big-endian C host would send.
pub fn encode_be(f: &Format, v: &Value, enclosing: Option<&Format>, out: &mut Vec<u8>) {
    match (f, v) {
        (Format::Empty, Value::Empty) => {}
        (Format::Primitive(_), _) => match v {
            Value::Char(x) | Value::UByte(x) => out.push(*x),
            Value::Byte(x) => out.push(*x as u8),
            Value::Short(x) => out.extend(x.to_be_bytes()),
            Value::UShort(x) | Value::TwoByte(x) => out.extend(x.to_be_bytes()),
            Value::Int(x) => out.extend(x.to_be_bytes()),
            Value::UInt(x) => out.extend(x.to_be_bytes()),
            Value::Long(x) => out.extend(x.to_be_bytes()),
            Value::ULong(x) => out.extend(x.to_be_bytes()),
            Value::Float(x) => out.extend(x.to_be_bytes()),
            Value::Double(x) => out.extend(x.to_be_bytes()),
            Value::Boolean(x) => out.extend((*x as i32).to_be_bytes()),
            Value::String(None) => out.extend([0, 0, 0, 0, b'Z']),
            Value::String(Some(s)) if s.is_empty() => out.extend([0, 0, 0, 0, b'Z']),
            Value::String(Some(s)) => {
                out.extend((s.len() as i32).to_be_bytes());
                out.extend(s.as_bytes());
            }
            Value::Bytes(b) => {
                out.extend((b.len() as i32).to_be_bytes());
                out.extend(b);
            }
            Value::Format(f) => formatter_be(f.as_deref(), out),
            other => panic!("primitive {other:?}"),
        },
        (Format::Length(_), Value::Bytes(b)) => out.extend(b),
        (Format::Struct(fs), Value::Struct(vs)) => {
            for (ff, fv) in fs.iter().zip(vs) {
                if let (Format::VarArray { elem, .. }, Value::VarArray(items)) = (ff, fv) {
                    out.extend((items.len() as i32).to_be_bytes());
                    for it in items {
                        encode_be(elem, it, Some(f), out);
                    }
                } else {
                    encode_be(ff, fv, Some(f), out);
                }
            }
        }
        (Format::Pointer(_) | Format::SelfPointer, Value::Pointer(None)) => out.push(0),
        (Format::Pointer(t), Value::Pointer(Some(x))) => {
            out.push(b'Z');
            encode_be(t, x, None, out);
        }
        (Format::SelfPointer, Value::Pointer(Some(x))) => {
            out.push(b'Z');
            let t = enclosing.unwrap();
            encode_be(t, x, None, out);
        }
        (Format::FixedArray { elem, dims }, _) => {
            fn rec(elem: &Format, n: usize, v: &Value, enc: Option<&Format>, out: &mut Vec<u8>) {
                if n == 0 {
                    return encode_be(elem, v, enc, out);
                }
                let Value::Array(items) = v else {
                    panic!("array")
                };
                for it in items {
                    rec(elem, n - 1, it, enc, out);
                }
            }
            rec(elem, dims.len(), v, enclosing, out);
        }
        (Format::Enum { .. }, Value::Enum(e)) => out.extend(e.to_be_bytes()),
        _ => panic!("encode_be: {f:?} / {v:?}"),
    }
}

fn code(p: Primitive) -> i32 {
    match p {
        Primitive::Int => 1,
        Primitive::Boolean => 2,
        Primitive::Float => 3,
        Primitive::Double => 4,
        Primitive::Byte => 5,
        Primitive::TwoByte => 6,
        Primitive::String => 7,
        Primitive::Format => 8,
        Primitive::UByte => 9,
        Primitive::Char => 16,
        Primitive::Short => 17,
        Primitive::Long => 18,
        Primitive::UShort => 28,
        Primitive::UInt => 29,
        Primitive::ULong => 30,
    }
}

/// The formatter encoding of ipc.md §9.7, big-endian (test oracle).
pub fn formatter_be(f: Option<&Format>, out: &mut Vec<u8>) {
    let int = |out: &mut Vec<u8>, x: i32| out.extend(x.to_be_bytes());
    let Some(f) = f else {
        return int(out, -1);
    };
    match f {
        Format::Empty => int(out, -1),
        Format::Primitive(p) => {
            int(out, 0);
            int(out, code(*p));
        }
        Format::Length(n) => {
            int(out, 1);
            int(out, *n as i32);
        }
        Format::Struct(fs) => {
            int(out, 2);
            int(out, fs.len() as i32 + 1);
            for x in fs {
                formatter_be(Some(x), out);
            }
        }
        Format::Pointer(t) => {
            int(out, 3);
            out.push(b'Z');
            formatter_be(Some(t), out);
        }
        Format::SelfPointer => {
            int(out, 3);
            out.push(0);
        }
        Format::FixedArray { elem, dims } | Format::VarArray { elem, dims } => {
            int(
                out,
                if matches!(f, Format::FixedArray { .. }) {
                    4
                } else {
                    5
                },
            );
            int(out, dims.len() as i32 + 2);
            formatter_be(Some(elem), out);
            for d in dims {
                int(out, *d as i32);
            }
        }
        Format::Named(n) => {
            int(out, 7);
            encode_be(
                &Format::Primitive(Primitive::String),
                &Value::String(Some(n.clone())),
                None,
                out,
            );
        }
        Format::Enum { names, max } => {
            int(out, 8);
            int(out, names.len() as i32 + 2);
            int(out, *max);
            for n in names {
                encode_be(
                    &Format::Primitive(Primitive::String),
                    &Value::String(Some(n.clone())),
                    None,
                    out,
                );
            }
        }
    }
}
