//! CMU IPC 3.9 marshalling (ipc.md §9), byte-identical to the 64-bit C library.
//!
//! Two ways in:
//! - typed: any [`IpcMessage`] (usually `#[derive(IpcMessage)]`) with
//!   [`to_vec`] / [`from_slice`], straight from the fields;
//! - dynamic: a [`Value`] marshalled through a parsed
//!   [`Format`](crate::format::Format) (the broker's data log, `courier spy`,
//!   dynamically typed subscribers).
//!
//! ```
//! use courier_wire::ipc;
//! let bytes = ipc::to_vec(&42i32);
//! assert_eq!(bytes, 42i32.to_ne_bytes());
//! assert_eq!(ipc::from_slice::<i32>(&bytes).unwrap(), 42);
//! ```

pub mod central;
mod codec;
pub mod frame;
pub mod introspect;
pub mod module;
pub mod value;

pub use codec::{ByteOrder, Reader, Writer, PRESENT};
pub use value::{
    decode_value, decode_value_prefix, decode_value_with, encode_value, encode_value_with,
    log_data, print_value, print_value_with, EncodeError, PathSegment, PrintOptions, Resolver,
    Value, ValuePath,
};

use crate::IpcMessage;

/// Why IPC data could not be decoded. Offsets are from the start of the data.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum DecodeError {
    /// The data ended before an item was complete.
    #[error("IPC data ends at byte {offset}: {needed} more byte(s) needed, {remaining} left")]
    UnexpectedEnd {
        /// Offset of the incomplete item.
        offset: usize,
        /// Bytes the item needs.
        needed: usize,
        /// Bytes that were left.
        remaining: usize,
    },
    /// Bytes were left over after the value was decoded.
    #[error("{count} unexpected trailing byte(s) after the value at byte {offset}")]
    TrailingBytes {
        /// Offset of the first unread byte.
        offset: usize,
        /// Number of unread bytes.
        count: usize,
    },
    /// A length or element count was negative.
    #[error("negative count {count} at byte {offset}")]
    NegativeCount {
        /// Offset of the count.
        offset: usize,
        /// The count read.
        count: i64,
    },
    /// A length or element count promised more data than the input holds.
    #[error("count {count} at byte {offset} exceeds the {remaining} remaining byte(s)")]
    CountTooLarge {
        /// Offset of the count.
        offset: usize,
        /// The count read.
        count: u64,
        /// Bytes remaining after the count.
        remaining: usize,
    },
    /// A string was not valid UTF-8.
    #[error("string is not valid UTF-8 at byte {offset}")]
    InvalidUtf8 {
        /// Offset of the first invalid byte.
        offset: usize,
    },
    /// A pointer flag was neither `'Z'` nor 0.
    #[error("invalid pointer flag 0x{byte:02x} at byte {offset} (expected 0x5a or 0x00)")]
    InvalidPointerFlag {
        /// Offset of the flag.
        offset: usize,
        /// The byte read.
        byte: u8,
    },
    /// An enum value is outside the enum.
    #[error("value {value} at byte {offset} is not a valid {type_name}")]
    InvalidEnum {
        /// Offset of the value.
        offset: usize,
        /// The value read.
        value: i64,
        /// The Rust or format type.
        type_name: &'static str,
    },
    /// A `char` field held a byte that the Rust type cannot hold.
    #[error("invalid char 0x{byte:02x} at byte {offset}")]
    InvalidChar {
        /// Offset of the byte.
        offset: usize,
        /// The byte read.
        byte: u8,
    },
    /// A variable array's count disagrees with the struct fields that size it.
    #[error(
        "variable array at byte {offset} has {found} elements, but its size fields say {expected}"
    )]
    CountMismatch {
        /// Offset of the array's count.
        offset: usize,
        /// Count from the size fields.
        expected: u64,
        /// Count on the wire.
        found: u64,
    },
    /// A multi-dimensional variable array's size fields do not fit its
    /// elements (or are negative, or too large).
    #[error("variable array at byte {offset}: {error}")]
    Shape {
        /// Offset of the array's count.
        offset: usize,
        /// What is wrong with the shape (boxed: decoders recurse, and
        /// every frame carries room for the error).
        error: Box<crate::ShapeError>,
    },
    /// Nesting deeper than [`MAX_DEPTH`] (recursive formats, self pointers).
    #[error("data nested deeper than {max} levels at byte {offset}")]
    TooDeep {
        /// Offset where the limit was hit.
        offset: usize,
        /// The limit.
        max: usize,
    },
    /// The format cannot be used to decode (e.g. an unresolved named format).
    #[error("format error: {0}")]
    Format(String),
}

/// Deepest nesting the IPC decoders follow, counting each struct and each
/// pointer as one level: a linked-list node (`struct Node { next:
/// Option<Box<Node>> }`) takes two, so about 500 nodes. Deeper data is
/// rejected (`DecodeError::TooDeep`) instead of overflowing the stack; the
/// encoder does not check it.
pub const MAX_DEPTH: usize = 1_000;

/// Marshals `value` as the C library's `IPC_marshall` does: native byte
/// order, no header, no length prefix.
pub fn to_vec<T: IpcMessage>(value: &T) -> Vec<u8> {
    let mut w = Writer::new();
    value.ipc_encode(&mut w);
    w.into_vec()
}

/// Unmarshals a `T` from data in this machine's byte order; all bytes must be used.
pub fn from_slice<T: IpcMessage>(bytes: &[u8]) -> Result<T, DecodeError> {
    from_slice_with_order(bytes, ByteOrder::NATIVE)
}

/// Unmarshals a `T` from data written in `order` (the `classId` data-endian
/// nibble of the frame that carried it); all bytes must be used.
pub fn from_slice_with_order<T: IpcMessage>(
    bytes: &[u8],
    order: ByteOrder,
) -> Result<T, DecodeError> {
    let mut r = Reader::new(bytes, order);
    let v = T::ipc_decode(&mut r)?;
    r.finish()?;
    Ok(v)
}
