//! [`Value`] through serde (cargo feature `serde`), in two forms:
//!
//! - **self-describing**: `Value`, [`Format`] and [`Primitive`] derive
//!   `Serialize` and `Deserialize`; every variant is tagged with its kind
//!   (`{"Int": 5}`), so a value round-trips without its format;
//! - **format-guided** ([`Typed`] out, [`ValueSeed`] in): the plain form a
//!   person writes and reads, with the format saying what each part is.
//!   It is what `courier echo --json` prints and `courier pub` reads.
//!
//! The format-guided form is described on [`Typed`].

use core::fmt;

use serde::de::{self, DeserializeSeed, SeqAccess, Visitor};
use serde::ser::{self, SerializeSeq};
use serde::{Deserializer, Serialize, Serializer};

use super::{prim_name, Value, MAX_VALUE_DEPTH};
use crate::format::{Format, Primitive};

/// What a part of a value is: a format, or the rest of a fixed array's
/// dimensions.
#[derive(Clone, Copy)]
enum Shape<'a> {
    Format(&'a Format),
    /// `dims` left of `[elem:…]` (at least one).
    Array {
        elem: &'a Format,
        dims: &'a [u32],
    },
}

impl<'a> Shape<'a> {
    /// The shape one level into an array of this shape.
    fn element(elem: &'a Format, dims: &'a [u32]) -> Shape<'a> {
        match dims {
            [_, rest @ ..] if !rest.is_empty() => Shape::Array { elem, dims: rest },
            _ => Shape::Format(elem),
        }
    }
}

/// A value with its format, serialized in the format-guided form: the
/// plain form a person writes and reads, with the format saying what each
/// part is ([`ValueSeed`] reads it back). Serializing fails when the value
/// does not fit the format, naming the first part that does not.
///
/// The format-guided form, part by part:
///
/// | format | JSON |
/// |---|---|
/// | integers, `float`, `double` | a number (`NaN` and infinities print as `null`, which reads back as NaN) |
/// | `boolean` | `true` / `false` |
/// | `char` | a one-character string (U+0000 to U+00FF), or its code as a number on input |
/// | `string` | a string (`""` and `null` are both C's NULL); bytes that are not UTF-8 as an array of numbers |
/// | `N` (raw bytes) | an array of N numbers |
/// | `{a, b, …}` | an array, one item per field (IPC formats name no fields) |
/// | `[T:d1,d2]` | nested arrays, one level per dimension |
/// | `<T:k>` | a flat array; the size fields must agree with it when the value is marshalled |
/// | `*T`, `*!` | `null` or the value pointed to |
/// | `{enum A, B}` | the name (`"B"`), or the number when the format has no names or the value is out of range; either on input |
/// | `format` | the format string, `null` for none |
/// | the empty format | `null` |
///
/// Named formats must be expanded first ([`FormatRegistry::resolve`]); the
/// formats central sends are.
///
/// ```
/// use courier_wire::format;
/// use courier_wire::ipc::value::{Typed, ValueSeed};
/// use serde::de::DeserializeSeed;
///
/// let fmt = format::parse("{int, string, {enum Wait, Send}, [double:2]}").unwrap();
/// let json = r#"[666, "hello", "Send", [1.5, 2]]"#;
/// let v = ValueSeed::new(&fmt)
///     .deserialize(&mut serde_json::Deserializer::from_str(json))
///     .unwrap();
/// assert_eq!(serde_json::to_string(&Typed::new(&fmt, &v)).unwrap(),
///            r#"[666,"hello","Send",[1.5,2.0]]"#);
/// ```
///
/// [`FormatRegistry::resolve`]: crate::format::FormatRegistry::resolve
#[derive(Debug, Clone, Copy)]
pub struct Typed<'a> {
    fmt: &'a Format,
    value: &'a Value,
}

impl<'a> Typed<'a> {
    /// `value`, of format `fmt` (named formats expanded).
    pub fn new(fmt: &'a Format, value: &'a Value) -> Self {
        Typed { fmt, value }
    }
}

impl Serialize for Typed<'_> {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        Node {
            shape: Shape::Format(self.fmt),
            value: self.value,
            enclosing: None,
            depth: 0,
        }
        .serialize(s)
    }
}

struct Node<'a> {
    shape: Shape<'a>,
    value: &'a Value,
    /// The innermost struct around this part (what `*!` points to).
    enclosing: Option<&'a Format>,
    depth: usize,
}

fn mismatch<E: ser::Error>(expected: &str, v: &Value) -> E {
    E::custom(format_args!("expected {expected}, found {}", v.kind()))
}

impl Node<'_> {
    fn child<'b>(
        &'b self,
        shape: Shape<'b>,
        value: &'b Value,
        enclosing: Option<&'b Format>,
    ) -> Node<'b> {
        Node {
            shape,
            value,
            enclosing,
            depth: self.depth + 1,
        }
    }
}

impl Serialize for Node<'_> {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        if self.depth > MAX_VALUE_DEPTH {
            return Err(ser::Error::custom(format_args!(
                "value nested deeper than {MAX_VALUE_DEPTH} levels"
            )));
        }
        let v = self.value;
        let fmt = match self.shape {
            Shape::Array { elem, dims } => {
                let Value::Array(items) = v else {
                    return Err(mismatch("array", v));
                };
                let mut seq = s.serialize_seq(Some(items.len()))?;
                for i in items {
                    seq.serialize_element(&self.child(
                        Shape::element(elem, dims),
                        i,
                        self.enclosing,
                    ))?;
                }
                return seq.end();
            }
            Shape::Format(f) => f,
        };
        match (fmt, v) {
            (Format::Empty, Value::Empty) => s.serialize_unit(),
            (Format::Primitive(p), _) => primitive(*p, v, s),
            (Format::Length(_), Value::Bytes(b)) => b.serialize(s),
            (Format::Struct(fields), Value::Struct(items)) => {
                if fields.len() != items.len() {
                    return Err(ser::Error::custom(format_args!(
                        "expected {} fields, found {}",
                        fields.len(),
                        items.len()
                    )));
                }
                let mut seq = s.serialize_seq(Some(items.len()))?;
                for (f, i) in fields.iter().zip(items) {
                    seq.serialize_element(&self.child(Shape::Format(f), i, Some(fmt)))?;
                }
                seq.end()
            }
            (Format::Pointer(_) | Format::SelfPointer, Value::Pointer(None)) => s.serialize_none(),
            (Format::Pointer(target), Value::Pointer(Some(p))) => {
                s.serialize_some(&self.child(Shape::Format(target), p, self.enclosing))
            }
            (Format::SelfPointer, Value::Pointer(Some(p))) => {
                let target = self
                    .enclosing
                    .ok_or_else(|| ser::Error::custom("self pointer `*!` outside a struct"))?;
                s.serialize_some(&self.child(Shape::Format(target), p, self.enclosing))
            }
            (Format::FixedArray { elem, dims }, Value::Array(_)) if !dims.is_empty() => self
                .child(Shape::Array { elem, dims }, v, self.enclosing)
                .serialize(s),
            (Format::VarArray { elem, .. }, Value::VarArray(items)) => {
                let mut seq = s.serialize_seq(Some(items.len()))?;
                for i in items {
                    seq.serialize_element(&self.child(Shape::Format(elem), i, self.enclosing))?;
                }
                seq.end()
            }
            (Format::Enum { names, .. }, Value::Enum(n)) => {
                match usize::try_from(*n).ok().and_then(|i| names.get(i)) {
                    Some(name) => s.serialize_str(name),
                    None => s.serialize_i32(*n),
                }
            }
            (Format::Named(name), _) => Err(ser::Error::custom(format_args!(
                "named format `{name}` not expanded"
            ))),
            (f, v) => Err(mismatch(&super::describe(f), v)),
        }
    }
}

fn primitive<S: Serializer>(p: Primitive, v: &Value, s: S) -> Result<S::Ok, S::Error> {
    match (p, v) {
        (Primitive::Char, Value::Char(c)) => s.serialize_char(char::from(*c)),
        (Primitive::Byte, Value::Byte(x)) => s.serialize_i8(*x),
        (Primitive::UByte, Value::UByte(x)) => s.serialize_u8(*x),
        (Primitive::Short, Value::Short(x)) => s.serialize_i16(*x),
        (Primitive::UShort, Value::UShort(x)) | (Primitive::TwoByte, Value::TwoByte(x)) => {
            s.serialize_u16(*x)
        }
        (Primitive::Int, Value::Int(x)) => s.serialize_i32(*x),
        (Primitive::UInt, Value::UInt(x)) => s.serialize_u32(*x),
        (Primitive::Long, Value::Long(x)) => s.serialize_i64(*x),
        (Primitive::ULong, Value::ULong(x)) => s.serialize_u64(*x),
        (Primitive::Float, Value::Float(x)) => s.serialize_f32(*x),
        (Primitive::Double, Value::Double(x)) => s.serialize_f64(*x),
        (Primitive::Boolean, Value::Boolean(b)) => s.serialize_bool(*b),
        (Primitive::String, Value::String(t)) => s.serialize_str(t.as_deref().unwrap_or("")),
        (Primitive::String, Value::Bytes(b)) => b.serialize(s),
        (Primitive::Format, Value::Format(None)) => s.serialize_unit(),
        (Primitive::Format, Value::Format(Some(f))) => s.collect_str(f),
        _ => Err(mismatch(prim_name(p), v)),
    }
}

/// Reads a [`Value`] of a format from the format-guided form (see
/// [`Typed`]): `ValueSeed::new(&fmt).deserialize(d)`.
///
/// Numbers must fit the primitive they are read as; structs and fixed
/// arrays must have exactly their number of items. Variable arrays are
/// taken as given: marshalling checks them against their size fields.
#[derive(Debug, Clone, Copy)]
pub struct ValueSeed<'a> {
    fmt: &'a Format,
}

impl<'a> ValueSeed<'a> {
    /// A seed for values of `fmt` (named formats expanded).
    pub fn new(fmt: &'a Format) -> Self {
        ValueSeed { fmt }
    }
}

impl<'de> DeserializeSeed<'de> for ValueSeed<'_> {
    type Value = Value;
    fn deserialize<D: Deserializer<'de>>(self, d: D) -> Result<Value, D::Error> {
        Seed {
            shape: Shape::Format(self.fmt),
            enclosing: None,
            depth: 0,
        }
        .deserialize(d)
    }
}

#[derive(Clone, Copy)]
struct Seed<'a> {
    shape: Shape<'a>,
    enclosing: Option<&'a Format>,
    depth: usize,
}

impl<'a> Seed<'a> {
    fn child(&self, shape: Shape<'a>, enclosing: Option<&'a Format>) -> Seed<'a> {
        Seed {
            shape,
            enclosing,
            depth: self.depth + 1,
        }
    }
}

impl<'de> DeserializeSeed<'de> for Seed<'_> {
    type Value = Value;
    fn deserialize<D: Deserializer<'de>>(self, d: D) -> Result<Value, D::Error> {
        if self.depth > MAX_VALUE_DEPTH {
            return Err(de::Error::custom(format_args!(
                "value nested deeper than {MAX_VALUE_DEPTH} levels"
            )));
        }
        match self.shape {
            Shape::Format(Format::Pointer(_) | Format::SelfPointer) => d.deserialize_option(self),
            _ => d.deserialize_any(self),
        }
    }
}

/// What the seed expects, for error messages.
fn expecting(shape: Shape<'_>) -> String {
    match shape {
        Shape::Array { dims, .. } => format!("an array of {}", dims[0]),
        Shape::Format(f) => match f {
            Format::Empty => "null (no data)".into(),
            Format::Primitive(Primitive::Char) => {
                "a one-character string or a number 0..=255".into()
            }
            Format::Primitive(Primitive::String) => "a string".into(),
            Format::Primitive(Primitive::Format) => "a format string or null".into(),
            Format::Primitive(Primitive::Boolean) => "true or false".into(),
            Format::Primitive(Primitive::Float | Primitive::Double) => "a number".into(),
            Format::Primitive(p) => format!("an integer ({})", prim_name(*p)),
            Format::Length(n) => format!("an array of {n} bytes"),
            Format::Struct(fs) => format!("an array of {} fields", fs.len()),
            Format::Pointer(_) | Format::SelfPointer => "null or a value".into(),
            Format::FixedArray { dims, .. } => {
                format!("an array of {}", dims.first().copied().unwrap_or(0))
            }
            Format::VarArray { .. } => "an array".into(),
            Format::Enum { names, max } if names.is_empty() => {
                format!("an enum value 0..={max}")
            }
            Format::Enum { names, .. } => format!("one of {}", names.join(", ")),
            Format::Named(n) => format!("a value of named format `{n}` (not expanded)"),
        },
    }
}

fn int_value<E: de::Error>(p: Primitive, n: i128) -> Result<Value, E> {
    let out = |_| E::custom(format_args!("{n} is out of range for {}", prim_name(p)));
    Ok(match p {
        Primitive::Char => Value::Char(u8::try_from(n).map_err(out)?),
        Primitive::Byte => Value::Byte(i8::try_from(n).map_err(out)?),
        Primitive::UByte => Value::UByte(u8::try_from(n).map_err(out)?),
        Primitive::Short => Value::Short(i16::try_from(n).map_err(out)?),
        Primitive::UShort => Value::UShort(u16::try_from(n).map_err(out)?),
        Primitive::TwoByte => Value::TwoByte(u16::try_from(n).map_err(out)?),
        Primitive::Int => Value::Int(i32::try_from(n).map_err(out)?),
        Primitive::UInt => Value::UInt(u32::try_from(n).map_err(out)?),
        Primitive::Long => Value::Long(i64::try_from(n).map_err(out)?),
        Primitive::ULong => Value::ULong(u64::try_from(n).map_err(out)?),
        Primitive::Float => Value::Float(n as f32),
        Primitive::Double => Value::Double(n as f64),
        Primitive::Boolean => Value::Boolean(n != 0),
        Primitive::String | Primitive::Format => {
            return Err(E::invalid_type(
                de::Unexpected::Other("a number"),
                &prim_name(p),
            ))
        }
    })
}

impl<'de> Visitor<'de> for Seed<'_> {
    type Value = Value;

    fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&expecting(self.shape))
    }

    fn visit_bool<E: de::Error>(self, b: bool) -> Result<Value, E> {
        match self.shape {
            Shape::Format(Format::Primitive(Primitive::Boolean)) => Ok(Value::Boolean(b)),
            _ => Err(E::invalid_type(de::Unexpected::Bool(b), &self)),
        }
    }

    fn visit_i64<E: de::Error>(self, n: i64) -> Result<Value, E> {
        self.visit_i128(n.into())
    }

    fn visit_u64<E: de::Error>(self, n: u64) -> Result<Value, E> {
        self.visit_i128(n.into())
    }

    fn visit_i128<E: de::Error>(self, n: i128) -> Result<Value, E> {
        match self.shape {
            Shape::Format(Format::Primitive(Primitive::String | Primitive::Format)) => {
                Err(E::invalid_type(de::Unexpected::Other("a number"), &self))
            }
            Shape::Format(Format::Primitive(p)) => int_value(*p, n),
            Shape::Format(Format::Enum { .. }) => i32::try_from(n)
                .map(Value::Enum)
                .map_err(|_| E::custom(format_args!("{n} is out of range for an enum"))),
            _ => Err(E::invalid_type(de::Unexpected::Other("a number"), &self)),
        }
    }

    fn visit_f64<E: de::Error>(self, x: f64) -> Result<Value, E> {
        match self.shape {
            Shape::Format(Format::Primitive(Primitive::Double)) => Ok(Value::Double(x)),
            Shape::Format(Format::Primitive(Primitive::Float)) => Ok(Value::Float(x as f32)),
            // 3.0 for an int: take it when it is a whole number
            Shape::Format(Format::Primitive(_) | Format::Enum { .. })
                if x.fract() == 0.0 && x.abs() < 1e38 =>
            {
                self.visit_i128(x as i128)
            }
            _ => Err(E::invalid_type(de::Unexpected::Float(x), &self)),
        }
    }

    fn visit_str<E: de::Error>(self, t: &str) -> Result<Value, E> {
        match self.shape {
            Shape::Format(Format::Primitive(Primitive::String)) => {
                Ok(Value::String((!t.is_empty()).then(|| t.to_string())))
            }
            Shape::Format(Format::Primitive(Primitive::Char)) => {
                let mut cs = t.chars();
                match (cs.next(), cs.next()) {
                    (Some(c), None) if u32::from(c) <= 0xff => Ok(Value::Char(c as u8)),
                    _ => Err(E::invalid_value(de::Unexpected::Str(t), &self)),
                }
            }
            Shape::Format(Format::Primitive(Primitive::Format)) => crate::format::parse(t)
                .map(|f| Value::Format(Some(Box::new(f))))
                .map_err(|e| E::custom(format_args!("format {t:?}: {e}"))),
            Shape::Format(Format::Enum { names, .. }) => names
                .iter()
                .position(|n| n == t)
                .map(|i| Value::Enum(i as i32))
                .ok_or_else(|| E::invalid_value(de::Unexpected::Str(t), &self)),
            Shape::Format(Format::Length(_)) => Ok(Value::Bytes(t.as_bytes().to_vec())),
            _ => Err(E::invalid_type(de::Unexpected::Str(t), &self)),
        }
    }

    fn visit_unit<E: de::Error>(self) -> Result<Value, E> {
        match self.shape {
            Shape::Format(Format::Empty) => Ok(Value::Empty),
            Shape::Format(Format::Primitive(Primitive::String)) => Ok(Value::String(None)),
            Shape::Format(Format::Primitive(Primitive::Format)) => Ok(Value::Format(None)),
            Shape::Format(Format::Primitive(Primitive::Double)) => Ok(Value::Double(f64::NAN)),
            Shape::Format(Format::Primitive(Primitive::Float)) => Ok(Value::Float(f32::NAN)),
            _ => Err(E::invalid_type(de::Unexpected::Unit, &self)),
        }
    }

    fn visit_none<E: de::Error>(self) -> Result<Value, E> {
        match self.shape {
            Shape::Format(Format::Pointer(_) | Format::SelfPointer) => Ok(Value::Pointer(None)),
            _ => self.visit_unit(),
        }
    }

    fn visit_some<D: Deserializer<'de>>(self, d: D) -> Result<Value, D::Error> {
        let target = match self.shape {
            Shape::Format(Format::Pointer(t)) => &**t,
            Shape::Format(Format::SelfPointer) => self
                .enclosing
                .ok_or_else(|| de::Error::custom("self pointer `*!` outside a struct"))?,
            _ => return Seed { ..self }.deserialize(d),
        };
        let v = self
            .child(Shape::Format(target), self.enclosing)
            .deserialize(d)?;
        Ok(Value::Pointer(Some(Box::new(v))))
    }

    fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<Value, A::Error> {
        match self.shape {
            Shape::Array { elem, dims } => {
                let n = dims[0] as usize;
                let v = items(&mut seq, Some((n, "elements")), |_| {
                    self.child(Shape::element(elem, dims), self.enclosing)
                })?;
                Ok(Value::Array(v))
            }
            Shape::Format(f) => match f {
                Format::Struct(fields) => {
                    let v = items(&mut seq, Some((fields.len(), "fields")), |i| {
                        self.child(Shape::Format(&fields[i]), Some(f))
                    })?;
                    Ok(Value::Struct(v))
                }
                Format::FixedArray { elem, dims } if !dims.is_empty() => Seed {
                    shape: Shape::Array { elem, dims },
                    ..self
                }
                .visit_seq(seq),
                Format::VarArray { elem, .. } => {
                    let v = items(&mut seq, None, |_| {
                        self.child(Shape::Format(elem), self.enclosing)
                    })?;
                    Ok(Value::VarArray(v))
                }
                Format::Length(n) => {
                    let v = items(&mut seq, Some((*n as usize, "bytes")), |_| {
                        self.child(Shape::Format(&UBYTE), None)
                    })?;
                    Ok(Value::Bytes(v.iter().map(byte).collect()))
                }
                Format::Primitive(Primitive::String) => {
                    let v = items(&mut seq, None, |_| self.child(Shape::Format(&UBYTE), None))?;
                    Ok(Value::Bytes(v.iter().map(byte).collect()))
                }
                _ => Err(de::Error::invalid_type(de::Unexpected::Seq, &self)),
            },
        }
    }
}

/// The format of one byte of raw bytes or of a non-UTF-8 string.
static UBYTE: Format = Format::Primitive(Primitive::UByte);

/// The items of a sequence, each read with `seed(index)`; with `exact`,
/// exactly that many (and what they are, for the error).
fn items<'de, 'a, A: SeqAccess<'de>>(
    seq: &mut A,
    exact: Option<(usize, &str)>,
    seed: impl Fn(usize) -> Seed<'a>,
) -> Result<Vec<Value>, A::Error> {
    let cap = seq.size_hint().unwrap_or(0).min(4096);
    let mut v = Vec::with_capacity(exact.map_or(cap, |(n, _)| n.min(4096)));
    loop {
        if let Some((n, what)) = exact {
            if v.len() == n {
                if seq.next_element::<de::IgnoredAny>()?.is_some() {
                    return Err(de::Error::custom(format_args!(
                        "expected {n} {what}, found {} or more",
                        n + 1
                    )));
                }
                return Ok(v);
            }
        }
        match seq.next_element_seed(seed(v.len()))? {
            Some(x) => v.push(x),
            None => break,
        }
    }
    match exact {
        Some((n, what)) => Err(de::Error::custom(format_args!(
            "expected {n} {what}, found {}",
            v.len()
        ))),
        None => Ok(v),
    }
}

/// The byte of a `ubyte` value read for raw bytes.
fn byte(v: &Value) -> u8 {
    match v {
        Value::UByte(b) => *b,
        _ => 0,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::format::parse;
    use crate::ipc::ByteOrder;

    fn from_json(fmt: &str, json: &str) -> Result<Value, String> {
        let f = parse(fmt).unwrap();
        ValueSeed::new(&f)
            .deserialize(&mut serde_json::Deserializer::from_str(json))
            .map_err(|e| e.to_string())
    }

    fn to_json(fmt: &str, v: &Value) -> String {
        let f = parse(fmt).unwrap();
        serde_json::to_string(&Typed::new(&f, v)).unwrap()
    }

    /// JSON → value → IPC bytes → value → JSON gives the same JSON.
    fn round_trip(fmt: &str, json: &str) {
        let f = parse(fmt).unwrap();
        let v = from_json(fmt, json).unwrap_or_else(|e| panic!("{fmt}: {json}: {e}"));
        let bytes = v.to_ipc_bytes(&f).unwrap();
        let back = Value::from_ipc_bytes(&f, &bytes, ByteOrder::NATIVE).unwrap();
        assert_eq!(back, v, "{fmt}");
        let compact: serde_json::Value = serde_json::from_str(json).unwrap();
        assert_eq!(to_json(fmt, &back), compact.to_string(), "{fmt}");
    }

    #[test]
    fn the_manual_formats_round_trip_through_json() {
        round_trip("int", "-7");
        round_trip(
            "{int, {enum : 3}, [double:2,3], double}",
            "[666,1,[[0.5,1.0,2.0],[1.0,2.0,3.0]],3.25]",
        );
        round_trip(
            "{string, int, <{int, double}:2>, {enum WaitVal, SendVal}}",
            r#"["Hello",2,[[1,0.5],[2,1.5]],"SendVal"]"#,
        );
        round_trip(
            "{char, byte, ubyte, short, ushort, uint, long, ulong, float, boolean}",
            r#"["x",-1,255,-300,65535,4000000000,-9000000000,18000000000000000000,0.5,true]"#,
        );
        round_trip("{int, *!}", "[1,[2,[3,null]]]");
        round_trip("*{string, [int:2]}", r#"["a",[1,2]]"#);
        round_trip("*int", "null");
        round_trip("5", "[1,2,3,4,5]");
        round_trip("{int, int, <ubyte:1,2>}", "[2,2,[1,2,3,4]]");
        round_trip("{format, string}", r#"["{int, [double:2,3]}",""]"#);
    }

    #[test]
    fn plain_json_is_forgiving_where_it_is_unambiguous() {
        // an integer where a double goes, a whole double where an int goes,
        // a name or a number for an enum, a code for a char, null for NULL
        assert_eq!(from_json("double", "2").unwrap(), Value::Double(2.0));
        assert_eq!(from_json("int", "3.0").unwrap(), Value::Int(3));
        assert_eq!(from_json("{enum A, B}", "1").unwrap(), Value::Enum(1));
        assert_eq!(from_json("char", "65").unwrap(), Value::Char(b'A'));
        assert_eq!(from_json("string", "null").unwrap(), Value::String(None));
        assert_eq!(from_json("string", "\"\"").unwrap(), Value::String(None));
        // non-UTF-8 text goes out and comes back as bytes
        let v = Value::Bytes(vec![0xff, 0x41]);
        assert_eq!(to_json("string", &v), "[255,65]");
        assert_eq!(from_json("string", "[255,65]").unwrap(), v);
        // an out-of-range enum prints as its number
        assert_eq!(to_json("{enum A, B}", &Value::Enum(7)), "7");
        // NaN prints as null and reads back as NaN
        assert_eq!(to_json("double", &Value::Double(f64::NAN)), "null");
        assert!(matches!(from_json("double", "null"), Ok(Value::Double(x)) if x.is_nan()));
    }

    #[test]
    fn errors_say_what_was_expected() {
        for (fmt, json, want) in [
            ("ubyte", "256", "256 is out of range for ubyte"),
            ("int", "\"x\"", "expected an integer (int)"),
            ("int", "1.5", "expected an integer (int)"),
            ("{int, string}", "[1]", "expected 2 fields, found 1"),
            (
                "{int, string}",
                "[1, \"a\", 3]",
                "expected 2 fields, found 3 or more",
            ),
            ("[int:2]", "[1, 2, 3]", "expected 2 elements"),
            ("{enum A, B}", "\"C\"", "one of A, B"),
            ("char", "\"ab\"", "one-character string"),
            ("boolean", "1.5", "true or false"),
            (
                "{int, string}",
                "[1, 2]",
                "invalid type: a number, expected a string",
            ),
            ("{int, *!}", "[1, [2, 3]]", "expected an array of 2 fields"),
            ("3", "[1, 2]", "expected 3 bytes, found 2"),
        ] {
            let e = from_json(fmt, json)
                .err()
                .unwrap_or_else(|| panic!("{fmt} {json} decoded"));
            assert!(e.contains(want), "{fmt} {json}: {want:?} in {e:?}");
        }
        // a value that does not fit its format is refused when printing
        let f = parse("{int, string}").unwrap();
        let bad = Value::Struct(vec![Value::Int(1), Value::Int(2)]);
        let e = serde_json::to_string(&Typed::new(&f, &bad)).unwrap_err();
        assert!(e.to_string().contains("expected string, found int"), "{e}");
    }

    #[test]
    fn the_self_describing_form_round_trips_without_a_format() {
        let v = Value::Struct(vec![
            Value::Int(1),
            Value::String(None),
            Value::Pointer(Some(Box::new(Value::Double(0.5)))),
            Value::Format(Some(Box::new(parse("{int, <char:1>}").unwrap()))),
        ]);
        let j = serde_json::to_string(&v).unwrap();
        assert!(j.starts_with(r#"{"Struct":[{"Int":1},"#), "{j}");
        assert_eq!(serde_json::from_str::<Value>(&j).unwrap(), v);
    }
}
