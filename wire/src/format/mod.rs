//! The CMU IPC format-string language (manual §3, ipc.md §9.6–§9.7).
//!
//! - [`parse`] / [`parse_with`]: format strings to a [`Format`] tree, with the
//!   byte position of the first error ([`ParseError`]).
//! - `Display` for [`Format`]: the canonical string form, which [`parse`] reads
//!   back to the same tree.
//! - [`FormatRegistry`]: named formats (`IPC_defineFormat`) and their
//!   expansion ([`FormatRegistry::resolve`]), and [`equivalent`], the
//!   comparison `IPC_checkMsgFormats` makes.
//! - [`fits`]: whether data of one format reads correctly as another (what
//!   a typed subscriber checks against the format central holds).
//! - [`Format::fixed_wire_size`], [`Format::c_size`], [`Format::c_align`]:
//!   marshalled size of fixed-size formats and the C struct layout on LP64.
//! - [`encode_formatter`] / [`decode_formatter`]: the formatter encoding of the
//!   `format` primitive (ipc.md §9.7).
//!
//! ```
//! use courier_wire::format::{self, Format, Primitive};
//! let f = format::parse("{int, [double:2,3]}").unwrap();
//! assert_eq!(f, Format::Struct(vec![
//!     Format::Primitive(Primitive::Int),
//!     Format::FixedArray { elem: Box::new(Format::Primitive(Primitive::Double)), dims: vec![2, 3] },
//! ]));
//! assert_eq!(f.to_string(), "{int, [double:2,3]}");
//! assert_eq!(f.fixed_wire_size(), Some(52));
//!
//! let mut names = format::FormatRegistry::new();
//! names.define("T1", "{int, {enum : 3}, [double:2,3], double}").unwrap();
//! let t2 = format::parse_with("{string, int, <T1:2>}", &names).unwrap();
//! assert_eq!(t2.to_string(), "{string, int, <{int, {enum : 3}, [double:2,3], double}:2>}");
//! ```
//!
//! # Deviations from the C parser (`parseFmttrs.c`, `lex.c`)
//!
//! - Text after a complete format is an error (C ignores it: `"int int"` is `int` there).
//! - Any Unicode white space separates tokens (C: space, tab and form feed only).
//! - Numbers above `i32::MAX` are an error (C's `atoi` overflows).
//! - `[n:d1,d2]` with a bare byte count `n` as element is accepted as a
//!   multi-dimensional array of `n`-byte elements, so that every tree has a
//!   string form (C accepts only one dimension for a byte-count element, `[d:n]`).
//! - Variable-array dimensions must name an existing integer field of the
//!   enclosing struct (C does not check, and reads 4 bytes at that field).
//! - Unknown names are `Format::Named` for [`parse`], and an error for
//!   [`parse_with`] (C asks central, then fails).

mod fit;
mod parse;
mod print;
mod registry;
mod size;
mod wire;

pub use fit::{fits, Misfit};
pub use parse::{parse, parse_with, ParseError, MAX_NESTING};
pub use registry::{
    equivalent, FormatRegistry, ResolveError, ENUM_BYTES_PER_NODE, MAX_EXPANDED_NODES,
};
pub use wire::{decode_formatter, encode_formatter};

/// A primitive IPC type (ipc.md §9.3), with its formatter code (§9.7).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub enum Primitive {
    /// `char`: 1 byte (code 16).
    Char,
    /// `byte`: 1 byte, signed (code 5).
    Byte,
    /// `ubyte`: 1 byte, unsigned (code 9).
    UByte,
    /// `short`: 2 bytes (code 17).
    Short,
    /// `ushort`: 2 bytes (code 28).
    UShort,
    /// `twobyte`: 2 raw bytes (code 6).
    TwoByte,
    /// `int`: 4 bytes (code 1).
    Int,
    /// `uint`: 4 bytes (code 29).
    UInt,
    /// `boolean`: a 4-byte C int (code 2).
    Boolean,
    /// `float`: 4 bytes (code 3).
    Float,
    /// `double`: 8 bytes (code 4).
    Double,
    /// `long`: 8 bytes as the 64-bit C library sends it (code 18).
    Long,
    /// `ulong`: 8 bytes (code 30).
    ULong,
    /// `string`: `int32` length + bytes, or `0` + `'Z'` for NULL/"" (code 7).
    String,
    /// `format`: a formatter tree (§9.7), internal messages only (code 8).
    Format,
}

/// A parsed IPC format (ipc.md §9.6).
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub enum Format {
    /// No data: the empty or NULL format (formatter code -1).
    Empty,
    /// A primitive.
    Primitive(Primitive),
    /// `N`: N raw bytes (e.g. `5`).
    Length(u32),
    /// `{a, b, …}`.
    Struct(Vec<Format>),
    /// `*T`.
    Pointer(Box<Format>),
    /// `*!`: pointer to the enclosing struct (inside a struct only).
    SelfPointer,
    /// `[T:d1,d2,…]` (or the old `[d:T]`), row-major.
    FixedArray {
        /// Element format.
        elem: Box<Format>,
        /// Dimensions.
        dims: Vec<u32>,
    },
    /// `<T:k1,k2,…>` (inside a struct only): the count is the product of the
    /// enclosing struct's fields number k1, k2, … (1-based).
    VarArray {
        /// Element format.
        elem: Box<Format>,
        /// 1-based indices of the struct fields that hold the dimensions.
        dims: Vec<u32>,
    },
    /// `{enum A, B, C}` (names given) or `{enum : max}` (names empty).
    Enum {
        /// The symbolic names, in value order; empty for the `: max` form.
        names: Vec<String>,
        /// The largest value (names.len() - 1 for the symbolic form).
        max: i32,
    },
    /// A named format (`IPC_defineFormat`), resolved through a registry.
    Named(String),
}

impl Format {
    /// Whether it refers to named formats anywhere (central answers a
    /// message's format with its names unexpanded).
    pub fn names_formats(&self) -> bool {
        match self {
            Format::Named(_) => true,
            Format::Struct(fs) => fs.iter().any(Format::names_formats),
            Format::Pointer(e)
            | Format::FixedArray { elem: e, .. }
            | Format::VarArray { elem: e, .. } => e.names_formats(),
            _ => false,
        }
    }
}

impl Primitive {
    /// Every primitive, in formatter-code order.
    pub const ALL: [Primitive; 15] = [
        Primitive::Int,
        Primitive::Boolean,
        Primitive::Float,
        Primitive::Double,
        Primitive::Byte,
        Primitive::TwoByte,
        Primitive::String,
        Primitive::Format,
        Primitive::UByte,
        Primitive::Char,
        Primitive::Short,
        Primitive::Long,
        Primitive::UShort,
        Primitive::UInt,
        Primitive::ULong,
    ];

    /// The name in format strings (case-sensitive, as in C: `Boolean` is not a primitive).
    pub const fn name(self) -> &'static str {
        match self {
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

    /// The primitive with this exact (case-sensitive) name.
    pub fn from_name(name: &str) -> Option<Primitive> {
        Self::ALL.iter().copied().find(|p| p.name() == name)
    }

    /// The formatter code (`formatters.h`, ipc.md §9.3).
    pub const fn code(self) -> i32 {
        match self {
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

    /// The primitive with this formatter code. The matrix types (10–15,
    /// 19, 21–27) and `X_IPC_REF_PTR` (20) are not IPC-API primitives: `None`.
    pub fn from_code(code: i32) -> Option<Primitive> {
        Self::ALL.iter().copied().find(|p| p.code() == code)
    }

    /// Marshalled size in bytes, or `None` for the variable-size `string` and `format`.
    pub const fn wire_size(self) -> Option<usize> {
        match self {
            Primitive::Char | Primitive::Byte | Primitive::UByte => Some(1),
            Primitive::Short | Primitive::UShort | Primitive::TwoByte => Some(2),
            Primitive::Int | Primitive::UInt | Primitive::Boolean | Primitive::Float => Some(4),
            Primitive::Double | Primitive::Long | Primitive::ULong => Some(8),
            Primitive::String | Primitive::Format => None,
        }
    }

    /// Size of the C type on LP64 (`string` and `format` are pointers: 8).
    pub const fn c_size(self) -> usize {
        match self.wire_size() {
            Some(n) => n,
            None => 8,
        }
    }

    /// True for the integer types a variable array may take a dimension
    /// from: `byte ubyte short ushort int uint long ulong`.
    ///
    /// The C library reads 4 bytes (an `int`) at the dimension field
    /// whatever its type, so only `int` and `uint` are read exactly there;
    /// the narrower and wider types are accepted as integers all the same.
    pub const fn is_integer(self) -> bool {
        matches!(
            self,
            Primitive::Byte
                | Primitive::UByte
                | Primitive::Short
                | Primitive::UShort
                | Primitive::Int
                | Primitive::UInt
                | Primitive::Long
                | Primitive::ULong
        )
    }
}

impl core::fmt::Display for Primitive {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(self.name())
    }
}
