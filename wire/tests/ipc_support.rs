//! Helpers shared by the `ipc_*` tests (included with `#[path]`): a small
//! format-string parser for test data, an independent big-endian encoder
//! used as an oracle, hex and fixture-file reading.
#![allow(dead_code)]

use courier_wire::format::{Format, Primitive};
use courier_wire::ipc::{ByteOrder, Value};

/// Parses the IPC format grammar of ipc.md §9.6 (test data only; the real
/// parser is `courier_wire::format::parse`).
pub fn fmt(s: &str) -> Format {
    let toks = lex(s);
    let mut p = P { t: &toks, i: 0 };
    if toks.is_empty() {
        return Format::Empty;
    }
    let f = p.fmt();
    assert_eq!(p.i, toks.len(), "trailing tokens in {s:?}");
    f
}

fn lex(s: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut cur = String::new();
    for c in s.chars() {
        if c.is_alphanumeric() || c == '_' {
            cur.push(c);
        } else {
            if !cur.is_empty() {
                out.push(std::mem::take(&mut cur));
            }
            if !c.is_whitespace() {
                out.push(c.to_string());
            }
        }
    }
    if !cur.is_empty() {
        out.push(cur);
    }
    out
}

struct P<'a> {
    t: &'a [String],
    i: usize,
}

impl P<'_> {
    fn peek(&self) -> &str {
        self.t.get(self.i).map(String::as_str).unwrap_or("")
    }
    fn next(&mut self) -> String {
        let s = self.peek().to_string();
        self.i += 1;
        s
    }
    fn expect(&mut self, s: &str) {
        let n = self.next();
        assert_eq!(n, s);
    }
    fn ints(&mut self) -> Vec<u32> {
        let mut v = vec![self.next().parse().unwrap()];
        while self.peek() == "," {
            self.next();
            v.push(self.next().parse().unwrap());
        }
        v
    }
    fn fmt(&mut self) -> Format {
        let t = self.next();
        match t.as_str() {
            "{" => {
                if self.peek() == "enum" {
                    self.next();
                    if self.peek() == ":" {
                        self.next();
                        let max = self.next().parse().unwrap();
                        self.expect("}");
                        return Format::Enum { names: vec![], max };
                    }
                    let mut names = vec![self.next()];
                    while self.peek() == "," {
                        self.next();
                        names.push(self.next());
                    }
                    self.expect("}");
                    let max = names.len() as i32 - 1;
                    return Format::Enum { names, max };
                }
                let mut fs = vec![self.fmt()];
                while self.peek() == "," {
                    self.next();
                    fs.push(self.fmt());
                }
                self.expect("}");
                Format::Struct(fs)
            }
            "[" => {
                if self.peek().chars().all(|c| c.is_ascii_digit()) {
                    let d = self.next().parse().unwrap();
                    self.expect(":");
                    let e = self.fmt();
                    self.expect("]");
                    return Format::FixedArray {
                        elem: Box::new(e),
                        dims: vec![d],
                    };
                }
                let e = self.fmt();
                self.expect(":");
                let dims = self.ints();
                self.expect("]");
                Format::FixedArray {
                    elem: Box::new(e),
                    dims,
                }
            }
            "<" => {
                let e = self.fmt();
                self.expect(":");
                let dims = self.ints();
                self.expect(">");
                Format::VarArray {
                    elem: Box::new(e),
                    dims,
                }
            }
            "*" => {
                if self.peek() == "!" {
                    self.next();
                    Format::SelfPointer
                } else {
                    Format::Pointer(Box::new(self.fmt()))
                }
            }
            s if s.chars().all(|c| c.is_ascii_digit()) => Format::Length(s.parse().unwrap()),
            s => match prim(s) {
                Some(p) => Format::Primitive(p),
                None => Format::Named(s.to_string()),
            },
        }
    }
}

fn prim(s: &str) -> Option<Primitive> {
    Some(match s {
        "char" => Primitive::Char,
        "byte" => Primitive::Byte,
        "ubyte" => Primitive::UByte,
        "short" => Primitive::Short,
        "ushort" => Primitive::UShort,
        "twobyte" => Primitive::TwoByte,
        "int" => Primitive::Int,
        "uint" => Primitive::UInt,
        "boolean" => Primitive::Boolean,
        "float" => Primitive::Float,
        "double" => Primitive::Double,
        "long" => Primitive::Long,
        "ulong" => Primitive::ULong,
        "string" => Primitive::String,
        "format" => Primitive::Format,
        _ => return None,
    })
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
