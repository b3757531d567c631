//! The CMU IPC format-string language (manual §3, ipc.md §9.6–§9.7).
//!
//! ```
//! use courier_wire::format::{self, Format, Primitive};
//! let f = format::parse("{int, [double:2,3]}").unwrap();
//! assert_eq!(f, Format::Struct(vec![
//!     Format::Primitive(Primitive::Int),
//!     Format::FixedArray { elem: Box::new(Format::Primitive(Primitive::Double)), dims: vec![2, 3] },
//! ]));
//! assert_eq!(f.to_string(), "{int, [double:2,3]}");
//! ```

/// A primitive IPC type (ipc.md §9.3), with its formatter code (§9.7).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
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
