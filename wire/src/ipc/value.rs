//! A dynamically typed IPC value, marshalled through any parsed format.
//!
//! [`Value`] holds anything an IPC format can describe; [`encode_value`] and
//! [`decode_value`] marshal it through a [`Format`] with the rules of ipc.md §9,
//! byte-identical to the 64-bit C library (`IPC_marshall` / `IPC_unmarshall`).
//! [`print_value`] and [`log_data`] print it the way the C `central` prints
//! message data in its data log (`central -ld`).
//!
//! ```
//! use courier_wire::format::{Format, Primitive};
//! use courier_wire::ipc::{ByteOrder, Value, print_value};
//!
//! // T1 = {int, {enum : 3}, [double:2,3], double} (ipc.md §10 E4)
//! let t1 = Format::Struct(vec![
//!     Format::Primitive(Primitive::Int),
//!     Format::Enum { names: vec![], max: 3 },
//!     Format::FixedArray { elem: Box::new(Format::Primitive(Primitive::Double)), dims: vec![2, 3] },
//!     Format::Primitive(Primitive::Double),
//! ]);
//! let row = |a: f64| Value::Array(vec![Value::Double(a), Value::Double(a + 1.0), Value::Double(a + 2.0)]);
//! let v = Value::Struct(vec![
//!     Value::Int(666),
//!     Value::Enum(1),
//!     Value::Array(vec![row(0.0), row(1.0)]),
//!     Value::Double(std::f64::consts::PI),
//! ]);
//! let bytes = v.to_ipc_bytes(&t1).unwrap();
//! assert_eq!(bytes.len(), 64);
//! assert_eq!(Value::from_ipc_bytes(&t1, &bytes, ByteOrder::NATIVE).unwrap(), v);
//! assert_eq!(print_value(&t1, &v), "{666, 1, [[0.00, 1.00, 2.00], [1.00, 2.00, 3.00]], 3.14}");
//! ```

//!
//! # Deviations from CMU IPC
//!
//! - Decoded data is normalised the way the C decoder normalises it: a
//!   non-zero `boolean` is `true` (re-sent as 1), `""` is NULL, the byte after
//!   a zero string length is ignored (re-sent as `'Z'`), an empty variable
//!   array has no elements (C: a NULL pointer, printed `NULL`).
//! - Stricter than C on input: a pointer flag other than `'Z'` or 0, a
//!   variable-array count that disagrees with its size fields, a string that
//!   runs past the data, nesting deeper than [`MAX_VALUE_DEPTH`], and counts
//!   the remaining bytes cannot hold are errors (C would misread or crash).
//! - `*!` refers to the innermost enclosing struct also from inside an
//!   array (C has no enclosing struct there and crashes).

use core::fmt;

use super::{ByteOrder, DecodeError, Reader, Writer};

/// Deepest nesting of a [`Value`] (each struct, array dimension and pointer
/// is one level) that [`decode_value`] builds, [`encode_value`] accepts and
/// the printer follows.
///
/// This is lower than [`super::MAX_DEPTH`] on purpose: a `Value` is a tree
/// walked recursively (also by `Drop`, `Clone` and `PartialEq`), and at this
/// depth decoding needs about 250 KiB of stack in an optimised build (a
/// tokio worker has 2 MiB); unoptimised builds need about ten times that.
/// A linked list `{int, *!}` uses two levels per node.
pub const MAX_VALUE_DEPTH: usize = 1_000;
use crate::format::{Format, Primitive};

mod print;
#[cfg(feature = "serde")]
mod serde_form;

pub use print::{log_data, print_value, print_value_with, PrintOptions};
#[cfg(feature = "serde")]
#[cfg_attr(docsrs, doc(cfg(feature = "serde")))]
pub use serde_form::{Typed, ValueSeed};

/// A value of any IPC format (ipc.md §9), as [`decode_value`] produces it and
/// [`encode_value`] consumes it.
///
/// Each variant corresponds to one kind of format; integers keep their exact
/// primitive so that a value re-encodes to the same bytes.
///
/// | format | value |
/// |---|---|
/// | empty / NULL format | [`Value::Empty`] |
/// | `char`, `byte`, `ubyte` | [`Value::Char`], [`Value::Byte`], [`Value::UByte`] |
/// | `short`, `ushort`, `twobyte` | [`Value::Short`], [`Value::UShort`], [`Value::TwoByte`] |
/// | `int`, `uint`, `long`, `ulong` | [`Value::Int`], [`Value::UInt`], [`Value::Long`], [`Value::ULong`] |
/// | `float`, `double`, `boolean` | [`Value::Float`], [`Value::Double`], [`Value::Boolean`] |
/// | `string` | [`Value::String`] (`None` = C's NULL, which is also what `""` decodes to); [`Value::Bytes`] for text that is not UTF-8 |
/// | `N` (raw bytes) | [`Value::Bytes`] of length N |
/// | `{a, b, …}` | [`Value::Struct`], one value per field |
/// | `[T:d1,d2,…]` | [`Value::Array`] nested once per dimension: `[T:2,3]` is an array of 2 arrays of 3 |
/// | `<T:k1,k2,…>` | [`Value::VarArray`], flat, row-major: its length is the product of the size fields |
/// | `*T`, `*!` | [`Value::Pointer`] |
/// | `{enum …}` | [`Value::Enum`] (the ordinal; names come from the format) |
/// | `format` | [`Value::Format`] |
/// | named format | the value of its definition |
///
/// Floating-point fields compare with IEEE semantics (`NaN != NaN`).
///
/// With the cargo feature `serde`, values serialize in a self-describing
/// form (`{"Int": 5}`), and in the plain form a person reads and writes
/// with their format: `Typed` and `ValueSeed` in this module.
#[derive(Debug, Clone, PartialEq)]
#[cfg_attr(feature = "serde", derive(::serde::Serialize, ::serde::Deserialize))]
pub enum Value {
    /// No data: the value of the empty (NULL) format.
    Empty,
    /// `char`: one byte.
    Char(u8),
    /// `byte`: one signed byte.
    Byte(i8),
    /// `ubyte`: one unsigned byte.
    UByte(u8),
    /// `short`: 16-bit signed.
    Short(i16),
    /// `ushort`: 16-bit unsigned.
    UShort(u16),
    /// `twobyte`: 16 bits, swapped like a short.
    TwoByte(u16),
    /// `int`: 32-bit signed.
    Int(i32),
    /// `uint`: 32-bit unsigned.
    UInt(u32),
    /// `long`: 64-bit signed (the 64-bit C library's `sizeof(long)`).
    Long(i64),
    /// `ulong`: 64-bit unsigned.
    ULong(u64),
    /// `float`: IEEE-754 single.
    Float(f32),
    /// `double`: IEEE-754 double.
    Double(f64),
    /// `boolean`: a 4-byte C int on the wire; any non-zero value decodes as `true`.
    Boolean(bool),
    /// `string`. `None` is C's NULL; NULL and `""` are the same bytes on the
    /// wire (`0` + `'Z'`) and both decode to `None`.
    String(Option<String>),
    /// Raw bytes: the value of a length format `N` (exactly N bytes), or of a
    /// `string` whose bytes are not UTF-8 (C strings are plain bytes).
    Bytes(Vec<u8>),
    /// `{a, b, …}`: the fields in order.
    Struct(Vec<Value>),
    /// `[T:d1,d2,…]`: `d1` elements, each an array of `d2` elements, and so on;
    /// the innermost elements are values of `T`.
    Array(Vec<Value>),
    /// `<T:k1,k2,…>`: all elements, row-major; their number must equal the
    /// product of the enclosing struct's fields `k1`, `k2`, … (1-based).
    VarArray(Vec<Value>),
    /// `*T` or `*!`: `None` is NULL.
    Pointer(Option<Box<Value>>),
    /// `{enum A, B, C}` / `{enum : max}`: the ordinal. Values outside the enum
    /// are kept (and printed as numbers), as the C library does.
    Enum(i32),
    /// `format`: a formatter tree (ipc.md §9.7), used by IPC's internal
    /// messages; `None` is the NULL formatter.
    Format(Option<Box<Format>>),
}

impl Value {
    /// A short name of the variant's kind, as used in error messages (`"int"`, `"string"`, `"struct"`, …).
    pub fn kind(&self) -> &'static str {
        match self {
            Value::Empty => "no data",
            Value::Char(_) => "char",
            Value::Byte(_) => "byte",
            Value::UByte(_) => "ubyte",
            Value::Short(_) => "short",
            Value::UShort(_) => "ushort",
            Value::TwoByte(_) => "twobyte",
            Value::Int(_) => "int",
            Value::UInt(_) => "uint",
            Value::Long(_) => "long",
            Value::ULong(_) => "ulong",
            Value::Float(_) => "float",
            Value::Double(_) => "double",
            Value::Boolean(_) => "boolean",
            Value::String(_) => "string",
            Value::Bytes(_) => "bytes",
            Value::Struct(_) => "struct",
            Value::Array(_) => "array",
            Value::VarArray(_) => "variable array",
            Value::Pointer(_) => "pointer",
            Value::Enum(_) => "enum",
            Value::Format(_) => "format",
        }
    }

    /// The value of an integer-like variant (every integer kind, `char`,
    /// `twobyte`, `enum`), as used for the size fields of variable arrays.
    pub fn as_integer(&self) -> Option<i128> {
        Some(match *self {
            Value::Char(v) => v.into(),
            Value::Byte(v) => v.into(),
            Value::UByte(v) => v.into(),
            Value::Short(v) => v.into(),
            Value::UShort(v) => v.into(),
            Value::TwoByte(v) => v.into(),
            Value::Int(v) => v.into(),
            Value::UInt(v) => v.into(),
            Value::Long(v) => v.into(),
            Value::ULong(v) => v.into(),
            Value::Enum(v) => v.into(),
            _ => return None,
        })
    }

    /// The text of a `string` value (`None` for NULL, non-UTF-8 bytes and other kinds).
    pub fn as_str(&self) -> Option<&str> {
        match self {
            Value::String(Some(s)) => Some(s),
            _ => None,
        }
    }

    /// The value of a `float` or `double`, or of an integer kind converted to `f64`.
    pub fn as_f64(&self) -> Option<f64> {
        match *self {
            Value::Float(x) => Some(x.into()),
            Value::Double(x) => Some(x),
            _ => self.as_integer().map(|n| n as f64),
        }
    }

    /// The fields of a struct or the elements of an array or variable array.
    pub fn as_slice(&self) -> Option<&[Value]> {
        match self {
            Value::Struct(v) | Value::Array(v) | Value::VarArray(v) => Some(v),
            _ => None,
        }
    }

    /// Marshals the value through `fmt` as `IPC_marshall` does (native byte
    /// order, no header). Named formats are not resolved; use
    /// [`encode_value_with`] for formats that refer to names.
    pub fn to_ipc_bytes(&self, fmt: &Format) -> Result<Vec<u8>, EncodeError> {
        let mut w = Writer::new();
        encode_value(fmt, self, &mut w)?;
        Ok(w.into_vec())
    }

    /// Unmarshals a value of format `fmt` from data written in `order` (the
    /// frame's data-endian nibble); all bytes must be used.
    pub fn from_ipc_bytes(
        fmt: &Format,
        bytes: &[u8],
        order: ByteOrder,
    ) -> Result<Value, DecodeError> {
        let mut r = Reader::new(bytes, order);
        let v = decode_value(fmt, &mut r)?;
        r.finish()?;
        Ok(v)
    }
}

macro_rules! value_from {
    ($($t:ty => $variant:ident),* $(,)?) => {$(
        impl From<$t> for Value {
            #[doc = concat!("`", stringify!($t), "` as [`Value::", stringify!($variant), "`].")]
            fn from(v: $t) -> Value {
                Value::$variant(v)
            }
        }
    )*};
}

value_from! {
    i8 => Byte, i16 => Short, u16 => UShort, i32 => Int, u32 => UInt,
    i64 => Long, u64 => ULong, f32 => Float, f64 => Double, bool => Boolean,
}

impl From<&str> for Value {
    /// A `string` value (`""` is sent as NULL).
    fn from(s: &str) -> Value {
        Value::String(Some(s.to_owned()))
    }
}

impl From<String> for Value {
    /// A `string` value (`""` is sent as NULL).
    fn from(s: String) -> Value {
        Value::String(Some(s))
    }
}

/// One step of the path to a part of a [`Value`], for error messages.
#[derive(Debug, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub enum PathSegment {
    /// Field number `n` of a struct, 1-based as in IPC var-array size references.
    Field(usize),
    /// Element `i` (0-based) of an array dimension or variable array.
    Element(usize),
    /// The target of a pointer.
    Pointee,
}

/// Where in a [`Value`] an [`EncodeError`] happened, outermost step first.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct ValuePath(pub Vec<PathSegment>);

impl fmt::Display for ValuePath {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.0.is_empty() {
            return f.write_str("value");
        }
        for (i, s) in self.0.iter().enumerate() {
            if i > 0 {
                f.write_str(" > ")?;
            }
            match s {
                PathSegment::Field(n) => write!(f, "field {n}")?,
                PathSegment::Element(n) => write!(f, "element {n}")?,
                PathSegment::Pointee => f.write_str("pointee")?,
            }
        }
        Ok(())
    }
}

/// Why a [`Value`] could not be marshalled through a format.
///
/// Every variant names the path to the offending part, e.g.
/// `field 3: expected int, found string`.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum EncodeError {
    /// The value's kind does not fit the format.
    #[error("{path}: expected {expected}, found {found}")]
    Mismatch {
        /// Where.
        path: ValuePath,
        /// What the format asks for.
        expected: String,
        /// The kind of value given ([`Value::kind`]).
        found: &'static str,
    },
    /// A struct, fixed array or raw-byte value has the wrong number of items.
    #[error("{path}: expected {expected} {what}, found {found}")]
    WrongLength {
        /// Where.
        path: ValuePath,
        /// `"fields"`, `"elements"` or `"bytes"`.
        what: &'static str,
        /// Number the format asks for.
        expected: u64,
        /// Number given.
        found: u64,
    },
    /// A variable array's length disagrees with the struct fields that size it.
    #[error("{path}: variable array has {found} element(s), but its size fields say {expected}")]
    CountMismatch {
        /// Where.
        path: ValuePath,
        /// Product of the size fields.
        expected: u64,
        /// Elements in the value.
        found: u64,
    },
    /// A string or count does not fit the 32-bit length of the wire.
    #[error("{path}: length {len} does not fit an IPC int32 count")]
    TooLong {
        /// Where.
        path: ValuePath,
        /// The length.
        len: u64,
    },
    /// The value is nested deeper than [`MAX_VALUE_DEPTH`].
    #[error("{path}: value nested deeper than {max} levels")]
    TooDeep {
        /// Where.
        path: ValuePath,
        /// The limit.
        max: usize,
    },
    /// The format cannot be used (unresolved named format, `*!` or `<…>`
    /// outside a struct, bad size-field reference).
    #[error("{path}: {message}")]
    Format {
        /// Where.
        path: ValuePath,
        /// What is wrong.
        message: String,
    },
}

impl EncodeError {
    fn path_mut(&mut self) -> &mut ValuePath {
        match self {
            EncodeError::Mismatch { path, .. }
            | EncodeError::WrongLength { path, .. }
            | EncodeError::CountMismatch { path, .. }
            | EncodeError::TooLong { path, .. }
            | EncodeError::TooDeep { path, .. }
            | EncodeError::Format { path, .. } => path,
        }
    }

    /// The path to the part of the value that failed.
    pub fn path(&self) -> &ValuePath {
        match self {
            EncodeError::Mismatch { path, .. }
            | EncodeError::WrongLength { path, .. }
            | EncodeError::CountMismatch { path, .. }
            | EncodeError::TooLong { path, .. }
            | EncodeError::TooDeep { path, .. }
            | EncodeError::Format { path, .. } => path,
        }
    }

    /// Adds a step while the error travels outwards (segments are collected
    /// innermost first and reversed once at the top).
    fn within(mut self, seg: PathSegment) -> Self {
        self.path_mut().0.push(seg);
        self
    }

    fn finish(mut self) -> Self {
        self.path_mut().0.reverse();
        self
    }

    fn format(message: impl Into<String>) -> Self {
        EncodeError::Format {
            path: ValuePath::default(),
            message: message.into(),
        }
    }
}

/// Resolves the name of a named format (`IPC_defineFormat`) to its definition.
pub type Resolver<'r, 'f> = &'r dyn Fn(&str) -> Option<&'f Format>;

/// How many named formats may refer to each other before a definition is reached.
const MAX_NAME_CHAIN: usize = 64;

fn prim_name(p: Primitive) -> &'static str {
    match p {
        Primitive::Char => "char",
        Primitive::Byte => "byte",
        Primitive::UByte => "ubyte",
        Primitive::Short => "short",
        Primitive::UShort => "ushort",
        Primitive::TwoByte => "twobyte",
        Primitive::Int => "int",
        Primitive::UInt => "uint",
        Primitive::Boolean => "boolean",
        Primitive::Float => "float",
        Primitive::Double => "double",
        Primitive::Long => "long",
        Primitive::ULong => "ulong",
        Primitive::String => "string",
        Primitive::Format => "format",
    }
}

/// Wire size of a fixed-size primitive; `None` for `string` and `format`.
fn prim_size(p: Primitive) -> Option<usize> {
    Some(match p {
        Primitive::Char | Primitive::Byte | Primitive::UByte => 1,
        Primitive::Short | Primitive::UShort | Primitive::TwoByte => 2,
        Primitive::Int | Primitive::UInt | Primitive::Boolean | Primitive::Float => 4,
        Primitive::Double | Primitive::Long | Primitive::ULong => 8,
        Primitive::String | Primitive::Format => return None,
    })
}

fn describe(f: &Format) -> String {
    match f {
        Format::Empty => "no data".into(),
        Format::Primitive(p) => prim_name(*p).into(),
        Format::Length(n) => format!("{n} raw bytes"),
        Format::Struct(fs) => format!("struct of {} fields", fs.len()),
        Format::Pointer(_) | Format::SelfPointer => "pointer".into(),
        Format::FixedArray { .. } => "array".into(),
        Format::VarArray { .. } => "variable array".into(),
        Format::Enum { .. } => "enum".into(),
        Format::Named(n) => format!("named format {n}"),
    }
}

/// Shared by encoder, decoder and printer: named-format resolution and the
/// stack of enclosing struct formats (for `*!`).
struct Ctx<'r, 'f> {
    resolve: Option<Resolver<'r, 'f>>,
    structs: Vec<&'f Format>,
}

impl<'r, 'f> Ctx<'r, 'f> {
    fn new(resolve: Option<Resolver<'r, 'f>>) -> Self {
        Ctx {
            resolve,
            structs: Vec::new(),
        }
    }

    /// Follows named formats until a definition; errors on unknown names and
    /// on chains of names that never reach a definition.
    fn resolve_named(&self, mut f: &'f Format) -> Result<&'f Format, String> {
        for _ in 0..MAX_NAME_CHAIN {
            match f {
                Format::Named(name) => {
                    f = self
                        .resolve
                        .and_then(|r| r(name))
                        .ok_or_else(|| format!("unknown named format `{name}`"))?;
                }
                _ => return Ok(f),
            }
        }
        Err("named formats refer to each other without reaching a definition".into())
    }

    fn self_target(&self) -> Result<&'f Format, String> {
        self.structs
            .last()
            .copied()
            .ok_or_else(|| "self pointer `*!` outside a struct".to_string())
    }

    /// Fewest bytes a value of `f` takes on the wire (0 if unknown), to bound
    /// element counts before allocating.
    fn min_size(&self, f: &'f Format, depth: usize) -> usize {
        if depth > 32 {
            return 0;
        }
        match f {
            Format::Empty => 0,
            Format::Primitive(Primitive::String) => 5,
            Format::Primitive(Primitive::Format) => 4,
            Format::Primitive(p) => prim_size(*p).unwrap_or(0),
            Format::Length(n) => *n as usize,
            Format::Struct(fs) => fs
                .iter()
                .fold(0usize, |a, x| a.saturating_add(self.min_size(x, depth + 1))),
            Format::Pointer(_) | Format::SelfPointer => 1,
            Format::FixedArray { elem, dims } => {
                dims.iter().fold(self.min_size(elem, depth + 1), |a, d| {
                    a.saturating_mul(*d as usize)
                })
            }
            Format::VarArray { .. } => 4,
            Format::Enum { .. } => 4,
            Format::Named(_) => match self.resolve_named(f) {
                Ok(g) => self.min_size(g, depth + 1),
                Err(_) => 0,
            },
        }
    }
}

// ---------------------------------------------------------------------------
// Encoding
// ---------------------------------------------------------------------------

/// Marshals `v` through `fmt` into `w` (ipc.md §9: packed, native byte order).
///
/// The value must match the format; the error names the path to the part
/// that does not. On error `w` is left as it was. Named formats are not
/// resolved (see [`encode_value_with`]).
pub fn encode_value(fmt: &Format, v: &Value, w: &mut Writer) -> Result<(), EncodeError> {
    encode_impl(fmt, v, w, None)
}

/// [`encode_value`] for formats that refer to named formats, which `resolve`
/// looks up (e.g. `&|name| registry.get(name)`).
pub fn encode_value_with<'f, 'g: 'f>(
    fmt: &'f Format,
    v: &Value,
    w: &mut Writer,
    resolve: &dyn Fn(&str) -> Option<&'g Format>,
) -> Result<(), EncodeError> {
    let shorten = |n: &str| -> Option<&'f Format> { resolve(n) };
    encode_impl(fmt, v, w, Some(&shorten))
}

fn encode_impl<'f>(
    fmt: &'f Format,
    v: &Value,
    w: &mut Writer,
    resolve: Option<Resolver<'_, 'f>>,
) -> Result<(), EncodeError> {
    let start = w.len();
    let mut enc = Encoder {
        ctx: Ctx::new(resolve),
        w,
        depth: 0,
    };
    match enc.enc(fmt, v) {
        Ok(()) => Ok(()),
        Err(e) => {
            let mut buf = core::mem::take(enc.w).into_vec();
            buf.truncate(start);
            *enc.w = Writer::from_vec(buf);
            Err(e.finish())
        }
    }
}

struct Encoder<'a, 'r, 'f> {
    ctx: Ctx<'r, 'f>,
    w: &'a mut Writer,
    depth: usize,
}

fn mismatch(f: &Format, v: &Value) -> EncodeError {
    EncodeError::Mismatch {
        path: ValuePath::default(),
        expected: describe(f),
        found: v.kind(),
    }
}

fn checked_len(n: usize) -> Result<i32, EncodeError> {
    i32::try_from(n).map_err(|_| EncodeError::TooLong {
        path: ValuePath::default(),
        len: n as u64,
    })
}

impl<'a, 'r, 'f> Encoder<'a, 'r, 'f> {
    fn enter(&mut self) -> Result<(), EncodeError> {
        if self.depth >= MAX_VALUE_DEPTH {
            return Err(EncodeError::TooDeep {
                path: ValuePath::default(),
                max: MAX_VALUE_DEPTH,
            });
        }
        self.depth += 1;
        Ok(())
    }

    fn enc(&mut self, f: &'f Format, v: &Value) -> Result<(), EncodeError> {
        match f {
            Format::Empty => match v {
                Value::Empty => Ok(()),
                _ => Err(mismatch(f, v)),
            },
            Format::Primitive(p) => self.prim(*p, f, v),
            Format::Length(n) => match v {
                Value::Bytes(b) if b.len() as u64 == u64::from(*n) => {
                    self.w.write_bytes(b);
                    Ok(())
                }
                Value::Bytes(b) => Err(EncodeError::WrongLength {
                    path: ValuePath::default(),
                    what: "bytes",
                    expected: (*n).into(),
                    found: b.len() as u64,
                }),
                _ => Err(mismatch(f, v)),
            },
            Format::Struct(fields) => {
                let Value::Struct(vals) = v else {
                    return Err(mismatch(f, v));
                };
                if vals.len() != fields.len() {
                    return Err(EncodeError::WrongLength {
                        path: ValuePath::default(),
                        what: "fields",
                        expected: fields.len() as u64,
                        found: vals.len() as u64,
                    });
                }
                self.enter()?;
                self.ctx.structs.push(f);
                let res = self.fields(fields, vals);
                self.ctx.structs.pop();
                self.depth -= 1;
                res
            }
            Format::Pointer(inner) => self.pointer(inner, f, v),
            Format::SelfPointer => {
                let target = self.ctx.self_target().map_err(EncodeError::format)?;
                self.pointer(target, f, v)
            }
            Format::FixedArray { elem, dims } => {
                self.enter()?;
                let res = self.fixed(elem, dims, v);
                self.depth -= 1;
                res
            }
            Format::VarArray { .. } => {
                Err(EncodeError::format("variable array `<…>` outside a struct"))
            }
            Format::Enum { .. } => match v {
                Value::Enum(e) => {
                    self.w.write_i32(*e);
                    Ok(())
                }
                _ => Err(mismatch(f, v)),
            },
            Format::Named(_) => {
                let g = self.ctx.resolve_named(f).map_err(EncodeError::format)?;
                self.enc(g, v)
            }
        }
    }

    fn prim(&mut self, p: Primitive, f: &Format, v: &Value) -> Result<(), EncodeError> {
        let w = &mut *self.w;
        match (p, v) {
            (Primitive::Char, Value::Char(x)) => w.write_u8(*x),
            (Primitive::Byte, Value::Byte(x)) => w.write_i8(*x),
            (Primitive::UByte, Value::UByte(x)) => w.write_u8(*x),
            (Primitive::Short, Value::Short(x)) => w.write_i16(*x),
            (Primitive::UShort, Value::UShort(x)) => w.write_u16(*x),
            (Primitive::TwoByte, Value::TwoByte(x)) => w.write_u16(*x),
            (Primitive::Int, Value::Int(x)) => w.write_i32(*x),
            (Primitive::UInt, Value::UInt(x)) => w.write_u32(*x),
            (Primitive::Long, Value::Long(x)) => w.write_i64(*x),
            (Primitive::ULong, Value::ULong(x)) => w.write_u64(*x),
            (Primitive::Float, Value::Float(x)) => w.write_f32(*x),
            (Primitive::Double, Value::Double(x)) => w.write_f64(*x),
            (Primitive::Boolean, Value::Boolean(x)) => w.write_bool(*x),
            (Primitive::String, Value::String(s)) => {
                write_cstr(w, s.as_deref().map(str::as_bytes).unwrap_or_default())?
            }
            (Primitive::String, Value::Bytes(b)) => write_cstr(w, b)?,
            (Primitive::Format, Value::Format(x)) => {
                crate::format::encode_formatter(x.as_deref(), w)
            }
            _ => return Err(mismatch(f, v)),
        }
        Ok(())
    }

    fn pointer(&mut self, target: &'f Format, f: &Format, v: &Value) -> Result<(), EncodeError> {
        let Value::Pointer(p) = v else {
            return Err(mismatch(f, v));
        };
        match p {
            None => {
                self.w.write_ptr_flag(false);
                Ok(())
            }
            Some(inner) => {
                self.enter()?;
                self.w.write_ptr_flag(true);
                let res = self
                    .enc(target, inner)
                    .map_err(|e| e.within(PathSegment::Pointee));
                self.depth -= 1;
                res
            }
        }
    }

    fn fixed(&mut self, elem: &'f Format, dims: &[u32], v: &Value) -> Result<(), EncodeError> {
        let Some((&d, rest)) = dims.split_first() else {
            return self.enc(elem, v);
        };
        let Value::Array(items) = v else {
            return Err(EncodeError::Mismatch {
                path: ValuePath::default(),
                expected: "array".into(),
                found: v.kind(),
            });
        };
        if items.len() as u64 != u64::from(d) {
            return Err(EncodeError::WrongLength {
                path: ValuePath::default(),
                what: "elements",
                expected: d.into(),
                found: items.len() as u64,
            });
        }
        for (i, it) in items.iter().enumerate() {
            self.fixed(elem, rest, it)
                .map_err(|e| e.within(PathSegment::Element(i)))?;
        }
        Ok(())
    }

    fn fields(&mut self, fields: &'f [Format], vals: &[Value]) -> Result<(), EncodeError> {
        for (i, (ff, fv)) in fields.iter().zip(vals).enumerate() {
            let res = match self.ctx.resolve_named(ff) {
                Ok(Format::VarArray { elem, dims }) => self.var_array(elem, dims, fields, vals, fv),
                Ok(_) => self.enc(ff, fv),
                Err(m) => Err(EncodeError::format(m)),
            };
            res.map_err(|e| e.within(PathSegment::Field(i + 1)))?;
        }
        Ok(())
    }

    fn var_array(
        &mut self,
        elem: &'f Format,
        dims: &[u32],
        fields: &[Format],
        vals: &[Value],
        v: &Value,
    ) -> Result<(), EncodeError> {
        let Value::VarArray(items) = v else {
            return Err(EncodeError::Mismatch {
                path: ValuePath::default(),
                expected: "variable array".into(),
                found: v.kind(),
            });
        };
        let expected = var_count(dims, fields.len(), |k| {
            vals.get(k).and_then(Value::as_integer)
        })
        .map_err(EncodeError::format)?;
        if items.len() as u64 != expected {
            return Err(EncodeError::CountMismatch {
                path: ValuePath::default(),
                expected,
                found: items.len() as u64,
            });
        }
        self.w.write_i32(checked_len(items.len())?);
        self.enter()?;
        let mut res = Ok(());
        for (i, it) in items.iter().enumerate() {
            if let Err(e) = self.enc(elem, it) {
                res = Err(e.within(PathSegment::Element(i)));
                break;
            }
        }
        self.depth -= 1;
        res
    }
}

fn write_cstr(w: &mut Writer, b: &[u8]) -> Result<(), EncodeError> {
    if b.is_empty() {
        w.write_i32(0);
        w.write_u8(super::PRESENT);
    } else {
        w.write_i32(checked_len(b.len())?);
        w.write_bytes(b);
    }
    Ok(())
}

/// Product of the size fields `dims` (1-based indices into a struct of
/// `nfields` fields) whose values `get` returns (index 0-based); `None` from
/// `get` means "not an integer".
fn var_count(
    dims: &[u32],
    nfields: usize,
    mut get: impl FnMut(usize) -> Option<i128>,
) -> Result<u64, String> {
    let mut product: i128 = 1;
    for &k in dims {
        let idx = (k as usize).wrapping_sub(1);
        if k == 0 || idx >= nfields {
            return Err(format!(
                "variable array size field {k} is not a field of the enclosing struct ({nfields} fields)"
            ));
        }
        let n =
            get(idx).ok_or_else(|| format!("variable array size field {k} is not an integer"))?;
        product = product.saturating_mul(n);
    }
    if !(0..=i128::from(i32::MAX)).contains(&product) {
        return Err(format!(
            "variable array size fields give {product} elements, outside 0..=2147483647"
        ));
    }
    Ok(product as u64)
}

// ---------------------------------------------------------------------------
// Decoding
// ---------------------------------------------------------------------------

/// Unmarshals a value of format `fmt` from `r` (ipc.md §9), in the reader's
/// byte order. Named formats are not resolved (see [`decode_value_with`]).
///
/// Hostile input is safe: counts and lengths are checked against the
/// remaining bytes before anything is allocated, nesting is limited to
/// [`MAX_VALUE_DEPTH`] (reported as [`DecodeError::TooDeep`]), and nothing panics. Trailing bytes are
/// left in the reader (check with [`Reader::finish`]).
pub fn decode_value(fmt: &Format, r: &mut Reader<'_>) -> Result<Value, DecodeError> {
    Decoder {
        ctx: Ctx::new(None),
        depth: 0,
        zero_sized_budget: MAX_ZERO_SIZED_ELEMENTS,
        kept_elements: usize::MAX,
    }
    .dec(fmt, r)
}

/// [`decode_value_with`] that keeps only the first `max_elements` array
/// elements of the whole value and steps over the others: arrays come out
/// shorter than on the wire. For printing a value that is cut short anyway,
/// as [`log_data`] does after five lines (each element prints at least one
/// character, so 400 elements fill them): a 1 MiB array then costs no
/// more than its first elements. The reader ends where a full decode
/// would, and malformed input fails as it would.
pub fn decode_value_prefix<'f, 'g: 'f>(
    fmt: &'f Format,
    r: &mut Reader<'_>,
    resolve: &dyn Fn(&str) -> Option<&'g Format>,
    max_elements: usize,
) -> Result<Value, DecodeError> {
    let shorten = |n: &str| -> Option<&'f Format> { resolve(n) };
    Decoder {
        ctx: Ctx::new(Some(&shorten)),
        depth: 0,
        zero_sized_budget: MAX_ZERO_SIZED_ELEMENTS,
        kept_elements: max_elements,
    }
    .dec(fmt, r)
}

/// [`decode_value`] for formats that refer to named formats, which `resolve` looks up.
pub fn decode_value_with<'f, 'g: 'f>(
    fmt: &'f Format,
    r: &mut Reader<'_>,
    resolve: &dyn Fn(&str) -> Option<&'g Format>,
) -> Result<Value, DecodeError> {
    decode_value_prefix(fmt, r, resolve, usize::MAX)
}

struct Decoder<'r, 'f> {
    ctx: Ctx<'r, 'f>,
    depth: usize,
    /// Elements that take no bytes on the wire (e.g. of format `0` or
    /// `[int:0]`) still cost memory; this many may be decoded in total.
    zero_sized_budget: usize,
    /// Array elements still to keep; later ones are stepped over
    /// ([`decode_value_prefix`]).
    kept_elements: usize,
}

/// How many elements that take no wire bytes one decode may create.
const MAX_ZERO_SIZED_ELEMENTS: usize = 1 << 16;

macro_rules! bulk {
    ($bytes:expr, $order:expr, $t:ty, $map:expr) => {{
        const N: usize = core::mem::size_of::<$t>();
        let order = $order;
        $bytes
            .chunks_exact(N)
            .map(|c| {
                let mut a = [0u8; N];
                a.copy_from_slice(c);
                ($map)(match order {
                    ByteOrder::Little => <$t>::from_le_bytes(a),
                    ByteOrder::Big => <$t>::from_be_bytes(a),
                })
            })
            .collect::<Vec<Value>>()
    }};
}

/// Decodes `n` fixed-size primitives in one pass over one slice.
fn bulk_prims(p: Primitive, n: usize, r: &mut Reader<'_>) -> Result<Vec<Value>, DecodeError> {
    let size = prim_size(p).unwrap_or(1);
    let offset = r.position();
    let n = r.check_count(offset, n as i64, size)?;
    let order = r.order();
    let b = r.take(n * size)?;
    Ok(match p {
        Primitive::Char => b.iter().map(|&x| Value::Char(x)).collect(),
        Primitive::Byte => b.iter().map(|&x| Value::Byte(x as i8)).collect(),
        Primitive::UByte => b.iter().map(|&x| Value::UByte(x)).collect(),
        Primitive::Short => bulk!(b, order, i16, Value::Short),
        Primitive::UShort => bulk!(b, order, u16, Value::UShort),
        Primitive::TwoByte => bulk!(b, order, u16, Value::TwoByte),
        Primitive::Int => bulk!(b, order, i32, Value::Int),
        Primitive::UInt => bulk!(b, order, u32, Value::UInt),
        Primitive::Float => bulk!(b, order, f32, Value::Float),
        Primitive::Double => bulk!(b, order, f64, Value::Double),
        Primitive::Long => bulk!(b, order, i64, Value::Long),
        Primitive::ULong => bulk!(b, order, u64, Value::ULong),
        Primitive::Boolean => bulk!(b, order, i32, |x: i32| Value::Boolean(x != 0)),
        Primitive::String | Primitive::Format => Vec::new(),
    })
}

impl<'r, 'f> Decoder<'r, 'f> {
    /// Checks that `n` elements of at least `min_size` wire bytes can follow
    /// before they are allocated; zero-size elements draw on a fixed budget.
    fn check_count(
        &mut self,
        r: &Reader<'_>,
        n: usize,
        min_size: usize,
    ) -> Result<usize, DecodeError> {
        if min_size > 0 {
            return r.check_count(r.position(), n as i64, min_size);
        }
        match self.zero_sized_budget.checked_sub(n) {
            Some(left) => {
                self.zero_sized_budget = left;
                Ok(n)
            }
            None => Err(DecodeError::CountTooLarge {
                offset: r.position(),
                count: n as u64,
                remaining: r.remaining(),
            }),
        }
    }

    /// Runs `f` one nesting level deeper, failing past [`MAX_VALUE_DEPTH`].
    fn nested<T>(
        &mut self,
        r: &mut Reader<'_>,
        f: impl FnOnce(&mut Self, &mut Reader<'_>) -> Result<T, DecodeError>,
    ) -> Result<T, DecodeError> {
        if self.depth >= MAX_VALUE_DEPTH {
            return Err(DecodeError::TooDeep {
                offset: r.position(),
                max: MAX_VALUE_DEPTH,
            });
        }
        self.depth += 1;
        let res = f(self, r);
        self.depth -= 1;
        res
    }

    fn dec(&mut self, f: &'f Format, r: &mut Reader<'_>) -> Result<Value, DecodeError> {
        match f {
            Format::Empty => Ok(Value::Empty),
            Format::Primitive(p) => self.prim(*p, r),
            Format::Length(n) => Ok(Value::Bytes(r.take(*n as usize)?.to_vec())),
            Format::Struct(fields) => self.nested(r, |d, r| {
                d.ctx.structs.push(f);
                let res = d.fields(fields, r);
                d.ctx.structs.pop();
                res
            }),
            Format::Pointer(inner) => self.pointer(inner, r),
            Format::SelfPointer => {
                let target = self.ctx.self_target().map_err(DecodeError::Format)?;
                self.pointer(target, r)
            }
            Format::FixedArray { elem, dims } => self.nested(r, |d, r| d.fixed(elem, dims, r)),
            Format::VarArray { .. } => Err(DecodeError::Format(
                "variable array `<…>` outside a struct".into(),
            )),
            Format::Enum { .. } => Ok(Value::Enum(r.read_i32()?)),
            Format::Named(_) => {
                let g = self.ctx.resolve_named(f).map_err(DecodeError::Format)?;
                self.dec(g, r)
            }
        }
    }

    fn prim(&mut self, p: Primitive, r: &mut Reader<'_>) -> Result<Value, DecodeError> {
        Ok(match p {
            Primitive::Char => Value::Char(r.read_u8()?),
            Primitive::Byte => Value::Byte(r.read_i8()?),
            Primitive::UByte => Value::UByte(r.read_u8()?),
            Primitive::Short => Value::Short(r.read_i16()?),
            Primitive::UShort => Value::UShort(r.read_u16()?),
            Primitive::TwoByte => Value::TwoByte(r.read_u16()?),
            Primitive::Int => Value::Int(r.read_i32()?),
            Primitive::UInt => Value::UInt(r.read_u32()?),
            Primitive::Long => Value::Long(r.read_i64()?),
            Primitive::ULong => Value::ULong(r.read_u64()?),
            Primitive::Float => Value::Float(r.read_f32()?),
            Primitive::Double => Value::Double(r.read_f64()?),
            Primitive::Boolean => Value::Boolean(r.read_bool()?),
            Primitive::String => {
                let n = r.read_count(1)?;
                if n == 0 {
                    // C writes one filler byte ('Z') after a zero length and ignores it.
                    r.take(1)?;
                    Value::String(None)
                } else {
                    let b = r.take(n)?;
                    match core::str::from_utf8(b) {
                        Ok(s) => Value::String(Some(s.to_owned())),
                        Err(_) => Value::Bytes(b.to_vec()),
                    }
                }
            }
            Primitive::Format => Value::Format(crate::format::decode_formatter(r)?.map(Box::new)),
        })
    }

    fn pointer(&mut self, target: &'f Format, r: &mut Reader<'_>) -> Result<Value, DecodeError> {
        if !r.read_ptr_flag()? {
            return Ok(Value::Pointer(None));
        }
        self.nested(r, |d, r| {
            Ok(Value::Pointer(Some(Box::new(d.dec(target, r)?))))
        })
    }

    /// `n` elements of `elem`, with a one-pass fast path for fixed-size primitives.
    fn elements(
        &mut self,
        elem: &'f Format,
        n: usize,
        r: &mut Reader<'_>,
    ) -> Result<Vec<Value>, DecodeError> {
        let resolved = self.ctx.resolve_named(elem).map_err(DecodeError::Format)?;
        let keep = n.min(self.kept_elements);
        self.kept_elements -= keep;
        if let Format::Primitive(p) = resolved {
            if let Some(size) = prim_size(*p) {
                r.check_count(r.position(), n as i64, size)?;
                let out = bulk_prims(*p, keep, r)?;
                r.take((n - keep) * size)?;
                return Ok(out);
            }
        }
        let n = self.check_count(r, n, self.ctx.min_size(resolved, 0))?;
        let mut out = Vec::with_capacity(keep);
        for i in 0..n {
            let v = self.dec(resolved, r)?;
            if i < keep {
                out.push(v);
            }
        }
        Ok(out)
    }

    fn fixed(
        &mut self,
        elem: &'f Format,
        dims: &[u32],
        r: &mut Reader<'_>,
    ) -> Result<Value, DecodeError> {
        match dims {
            [] => self.dec(elem, r),
            [d] => Ok(Value::Array(self.elements(elem, *d as usize, r)?)),
            [d, rest @ ..] => {
                let row = rest.iter().fold(self.ctx.min_size(elem, 0), |a, x| {
                    a.saturating_mul(*x as usize)
                });
                let n = self.check_count(r, *d as usize, row)?;
                let mut out = Vec::with_capacity(n);
                for _ in 0..n {
                    out.push(self.nested(r, |d, r| d.fixed(elem, rest, r))?);
                }
                Ok(Value::Array(out))
            }
        }
    }

    fn fields(&mut self, fields: &'f [Format], r: &mut Reader<'_>) -> Result<Value, DecodeError> {
        let mut vals: Vec<Value> = Vec::with_capacity(fields.len());
        // Variable arrays whose size fields come later: (dims, count offset, count).
        let mut deferred: Vec<(&[u32], usize, u64)> = Vec::new();
        for (i, ff) in fields.iter().enumerate() {
            let ff = self.ctx.resolve_named(ff).map_err(DecodeError::Format)?;
            if let Format::VarArray { elem, dims } = ff {
                let offset = r.position();
                let count = r.read_i32()?;
                if count < 0 {
                    return Err(DecodeError::NegativeCount {
                        offset,
                        count: count.into(),
                    });
                }
                let count = count as u64;
                if dims.iter().all(|&k| k >= 1 && (k as usize) <= i) {
                    let expected = var_count(dims, fields.len(), |k| {
                        vals.get(k).and_then(Value::as_integer)
                    })
                    .map_err(DecodeError::Format)?;
                    if expected != count {
                        return Err(DecodeError::CountMismatch {
                            offset,
                            expected,
                            found: count,
                        });
                    }
                } else {
                    deferred.push((dims, offset, count));
                }
                let items = self.nested(r, |d, r| d.elements(elem, count as usize, r))?;
                vals.push(Value::VarArray(items));
            } else {
                vals.push(self.dec(ff, r)?);
            }
        }
        for (dims, offset, count) in deferred {
            let expected = var_count(dims, fields.len(), |k| {
                vals.get(k).and_then(Value::as_integer)
            })
            .map_err(DecodeError::Format)?;
            if expected != count {
                return Err(DecodeError::CountMismatch {
                    offset,
                    expected,
                    found: count,
                });
            }
        }
        Ok(Value::Struct(vals))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn p(p: Primitive) -> Format {
        Format::Primitive(p)
    }

    #[test]
    fn accessors_and_conversions() {
        let v = Value::Struct(vec![
            7i32.into(),
            "ab".into(),
            2.5f32.into(),
            Value::Enum(3),
        ]);
        let f = v.as_slice().unwrap();
        assert_eq!(f[0].as_integer(), Some(7));
        assert_eq!(f[1].as_str(), Some("ab"));
        assert_eq!(f[2].as_f64(), Some(2.5));
        assert_eq!(f[3].as_f64(), Some(3.0));
        assert_eq!(Value::from(u64::MAX).as_integer(), Some(u64::MAX.into()));
        assert_eq!(Value::String(None).as_str(), None);
    }

    #[test]
    fn error_paths_name_the_field() {
        let f = Format::Struct(vec![
            p(Primitive::Int),
            p(Primitive::Int),
            p(Primitive::Int),
        ]);
        let v = Value::Struct(vec![Value::Int(1), Value::Int(2), Value::String(None)]);
        let e = v.to_ipc_bytes(&f).unwrap_err();
        assert_eq!(e.to_string(), "field 3: expected int, found string");
    }

    #[test]
    fn nested_error_path() {
        let f = Format::Struct(vec![Format::FixedArray {
            elem: Box::new(Format::Pointer(Box::new(p(Primitive::Int)))),
            dims: vec![2],
        }]);
        let v = Value::Struct(vec![Value::Array(vec![
            Value::Pointer(None),
            Value::Pointer(Some(Box::new(Value::Long(3)))),
        ])]);
        let e = v.to_ipc_bytes(&f).unwrap_err();
        assert_eq!(
            e.to_string(),
            "field 1 > element 1 > pointee: expected int, found long"
        );
    }

    #[test]
    fn writer_restored_on_error() {
        let mut w = Writer::new();
        w.write_u8(7);
        let f = Format::Struct(vec![p(Primitive::Int), p(Primitive::Int)]);
        let v = Value::Struct(vec![Value::Int(1), Value::Boolean(true)]);
        assert!(encode_value(&f, &v, &mut w).is_err());
        assert_eq!(w.as_bytes(), &[7]);
    }

    #[test]
    fn var_array_count_must_match_fields() {
        let f = Format::Struct(vec![
            p(Primitive::Int),
            Format::VarArray {
                elem: Box::new(p(Primitive::Int)),
                dims: vec![1],
            },
        ]);
        let v = Value::Struct(vec![Value::Int(2), Value::VarArray(vec![Value::Int(1)])]);
        assert!(matches!(
            v.to_ipc_bytes(&f),
            Err(EncodeError::CountMismatch {
                expected: 2,
                found: 1,
                ..
            })
        ));
        // On the wire: field says 2, count says 1.
        let bytes = [2, 0, 0, 0, 1, 0, 0, 0, 9, 0, 0, 0];
        assert!(matches!(
            Value::from_ipc_bytes(&f, &bytes, ByteOrder::Little),
            Err(DecodeError::CountMismatch {
                offset: 4,
                expected: 2,
                found: 1
            })
        ));
    }

    #[test]
    fn size_field_after_the_array_is_checked_at_struct_end() {
        let f = Format::Struct(vec![
            Format::VarArray {
                elem: Box::new(p(Primitive::UByte)),
                dims: vec![2],
            },
            p(Primitive::Int),
        ]);
        let v = Value::Struct(vec![Value::VarArray(vec![Value::UByte(5)]), Value::Int(1)]);
        let b = v.to_ipc_bytes(&f).unwrap();
        assert_eq!(Value::from_ipc_bytes(&f, &b, ByteOrder::NATIVE).unwrap(), v);
        let mut bad = b.clone();
        let n = bad.len();
        bad[n - 4..].copy_from_slice(&3i32.to_ne_bytes());
        assert!(matches!(
            Value::from_ipc_bytes(&f, &bad, ByteOrder::NATIVE),
            Err(DecodeError::CountMismatch {
                expected: 3,
                found: 1,
                ..
            })
        ));
    }

    #[test]
    fn hostile_counts_do_not_allocate() {
        let f = Format::Struct(vec![
            p(Primitive::Int),
            Format::VarArray {
                elem: Box::new(p(Primitive::Double)),
                dims: vec![1],
            },
        ]);
        let bytes = [0xff, 0xff, 0xff, 0x7f, 0xff, 0xff, 0xff, 0x7f, 1, 2, 3];
        assert!(matches!(
            Value::from_ipc_bytes(&f, &bytes, ByteOrder::Little),
            Err(DecodeError::CountTooLarge { .. })
        ));
        let big = Format::FixedArray {
            elem: Box::new(p(Primitive::String)),
            dims: vec![u32::MAX, u32::MAX],
        };
        assert!(Value::from_ipc_bytes(&big, &[0; 16], ByteOrder::Little).is_err());
    }

    #[test]
    fn deep_self_pointer_is_limited() {
        let f = Format::Struct(vec![p(Primitive::UByte), Format::SelfPointer]);
        let mut bytes = Vec::new();
        for _ in 0..(MAX_VALUE_DEPTH + 10) {
            bytes.extend_from_slice(&[1, b'Z']);
        }
        bytes.extend_from_slice(&[1, 0]);
        let r = std::thread::Builder::new()
            .stack_size(8 << 20)
            .spawn(move || Value::from_ipc_bytes(&f, &bytes, ByteOrder::Little).map(|_| ()))
            .unwrap()
            .join()
            .unwrap();
        assert!(matches!(r, Err(DecodeError::TooDeep { .. })));
    }

    #[test]
    fn named_formats_resolve() {
        let list = Format::Struct(vec![
            p(Primitive::Int),
            Format::Pointer(Box::new(Format::Named("list".into()))),
        ]);
        let top = Format::Named("list".into());
        let resolve = |n: &str| (n == "list").then_some(&list);
        let v = Value::Struct(vec![
            Value::Int(1),
            Value::Pointer(Some(Box::new(Value::Struct(vec![
                Value::Int(2),
                Value::Pointer(None),
            ])))),
        ]);
        let mut w = Writer::new();
        encode_value_with(&top, &v, &mut w, &resolve).unwrap();
        assert_eq!(w.as_bytes(), [1, 0, 0, 0, b'Z', 2, 0, 0, 0, 0]);
        let mut r = Reader::new(w.as_bytes(), ByteOrder::Little);
        assert_eq!(decode_value_with(&top, &mut r, &resolve).unwrap(), v);
        assert!(matches!(
            v.to_ipc_bytes(&top),
            Err(EncodeError::Format { .. })
        ));
        let mut r = Reader::new(&[1], ByteOrder::Little);
        assert!(matches!(
            decode_value(&top, &mut r),
            Err(DecodeError::Format(_))
        ));
    }

    #[test]
    fn non_utf8_strings_round_trip_as_bytes() {
        let f = p(Primitive::String);
        let b = [2, 0, 0, 0, 0xe9, 0x41];
        let v = Value::from_ipc_bytes(&f, &b, ByteOrder::Little).unwrap();
        assert_eq!(v, Value::Bytes(vec![0xe9, 0x41]));
        assert_eq!(v.to_ipc_bytes(&f).unwrap(), b);
    }
}
