//! The formatter encoding (ipc.md §9.7; `x_ipc_FORMAT_Trans_Encode1` /
//! `x_ipc_FORMAT_Trans_Decode1` in `primFmttrs.c`): how a value of the
//! primitive type `format` travels, e.g. in `x_ipc_msgInfoMsg` replies.
//!
//! Every integer is an `int32` in the sender's byte order:
//!
//! | class | node | then |
//! |---:|---|---|
//! | -1 | NULL formatter (top level only) | nothing |
//! | 0 | primitive | formatter code |
//! | 1 | byte count | the count |
//! | 2 | struct | fields + 1, each field's formatter |
//! | 3 | pointer | `'Z'` and the pointee's formatter, or `0` for a self pointer |
//! | 4, 5 | fixed / variable array | dims + 2, the element's formatter, the dims |
//! | 6 | bad format | nothing |
//! | 7 | name | a string |
//! | 8 | enum | names + 2, the maximum, the names as strings |

use super::parse::MAX_NESTING;
use super::{Format, Primitive};
use crate::ipc::{DecodeError, Reader, Writer, PRESENT};

const NULL: i32 = -1;
const PRIMITIVE: i32 = 0;
const LENGTH: i32 = 1;
const STRUCT: i32 = 2;
const POINTER: i32 = 3;
const FIXED_ARRAY: i32 = 4;
const VAR_ARRAY: i32 = 5;
const BAD_FORMAT: i32 = 6;
const NAMED: i32 = 7;
const ENUM: i32 = 8;

/// Fewest bytes one nested formatter takes (its class), for bounding counts.
const MIN_FORMATTER: usize = 4;

/// Appends the formatter encoding of `f`. `None` and [`Format::Empty`] are
/// the NULL formatter, `int32 -1`.
///
/// ```
/// use courier_wire::{format, ipc::Writer};
/// let mut w = Writer::new();
/// format::encode_formatter(Some(&format::parse("{string, string}").unwrap()), &mut w);
/// assert_eq!(w.len(), 24);
/// ```
///
/// Byte counts and dimensions above `i32::MAX` (which no format string can
/// hold) are written as their two's-complement `int32`, as a C `int` would
/// hold them. [`Format::Empty`] inside a composite is written as `-1`, which
/// C cannot read (Courier's [`decode_formatter`] reads it back as `Empty`).
pub fn encode_formatter(f: Option<&Format>, w: &mut Writer) {
    match f {
        None => w.write_i32(NULL),
        Some(f) => encode(f, w),
    }
}

fn encode(f: &Format, w: &mut Writer) {
    match f {
        Format::Empty => w.write_i32(NULL),
        Format::Primitive(p) => {
            w.write_i32(PRIMITIVE);
            w.write_i32(p.code());
        }
        Format::Length(n) => {
            w.write_i32(LENGTH);
            w.write_u32(*n);
        }
        Format::Struct(fields) => {
            w.write_i32(STRUCT);
            w.write_len(fields.len().saturating_add(1));
            for field in fields {
                encode(field, w);
            }
        }
        Format::Pointer(inner) => {
            w.write_i32(POINTER);
            w.write_u8(PRESENT);
            encode(inner, w);
        }
        Format::SelfPointer => {
            w.write_i32(POINTER);
            w.write_u8(0);
        }
        Format::FixedArray { elem, dims } | Format::VarArray { elem, dims } => {
            let class = if matches!(f, Format::FixedArray { .. }) {
                FIXED_ARRAY
            } else {
                VAR_ARRAY
            };
            w.write_i32(class);
            w.write_len(dims.len().saturating_add(2));
            encode(elem, w);
            for &d in dims {
                w.write_u32(d);
            }
        }
        Format::Named(name) => {
            w.write_i32(NAMED);
            w.write_str(name);
        }
        Format::Enum { names, max } => {
            w.write_i32(ENUM);
            w.write_len(names.len().saturating_add(2));
            w.write_i32(*max);
            for n in names {
                w.write_str(n);
            }
        }
    }
}

/// Reads one formatter; `Ok(None)` for the NULL formatter (`int32 -1`).
///
/// Bounded: every count is checked against the remaining input before
/// anything is allocated, and nesting deeper than [`MAX_NESTING`] is
/// rejected. A pointer flag other than 0 means "pointee follows", as in C.
/// A bad format (class 6), unknown classes and primitive codes that are
/// not IPC-API primitives (matrices, `X_IPC_REF_PTR`) are
/// [`DecodeError::Format`]; negative counts, sizes and dimensions are
/// [`DecodeError::NegativeCount`].
pub fn decode_formatter(r: &mut Reader<'_>) -> Result<Option<Format>, DecodeError> {
    match decode(r, 0)? {
        Format::Empty => Ok(None),
        f => Ok(Some(f)),
    }
}

fn non_negative(offset: usize, n: i32) -> Result<u32, DecodeError> {
    u32::try_from(n).map_err(|_| DecodeError::NegativeCount {
        offset,
        count: n as i64,
    })
}

/// Reads an array-size word (`extra` + number of items) and checks that
/// the items, `min_size` bytes or more each, can follow.
fn read_items(r: &mut Reader<'_>, extra: i32, min_size: usize) -> Result<usize, DecodeError> {
    let offset = r.position();
    let size = r.read_i32()?;
    let n = size
        .checked_sub(extra)
        .filter(|n| *n >= 0)
        .ok_or(DecodeError::NegativeCount {
            offset,
            count: size as i64 - extra as i64,
        })?;
    r.check_count(offset, n as i64, min_size)
}

fn decode(r: &mut Reader<'_>, depth: usize) -> Result<Format, DecodeError> {
    let offset = r.position();
    let class = r.read_i32()?;
    let nested = |r: &Reader<'_>| {
        if depth >= MAX_NESTING {
            Err(DecodeError::TooDeep {
                offset: r.position(),
                max: MAX_NESTING,
            })
        } else {
            Ok(depth + 1)
        }
    };
    Ok(match class {
        NULL => Format::Empty,
        PRIMITIVE => {
            let at = r.position();
            let code = r.read_i32()?;
            Format::Primitive(Primitive::from_code(code).ok_or_else(|| {
                DecodeError::Format(format!(
                    "formatter at byte {offset}: primitive code {code} at byte {at} is not an IPC primitive"
                ))
            })?)
        }
        LENGTH => {
            let at = r.position();
            Format::Length(non_negative(at, r.read_i32()?)?)
        }
        STRUCT => {
            let n = read_items(r, 1, MIN_FORMATTER)?;
            let depth = nested(r)?;
            let mut fields = Vec::with_capacity(n);
            for _ in 0..n {
                fields.push(decode(r, depth)?);
            }
            Format::Struct(fields)
        }
        POINTER => {
            if r.read_u8()? == 0 {
                Format::SelfPointer
            } else {
                let depth = nested(r)?;
                Format::Pointer(Box::new(decode(r, depth)?))
            }
        }
        FIXED_ARRAY | VAR_ARRAY => {
            let at = r.position();
            let n = read_items(r, 2, 4)?;
            if n == 0 {
                return Err(DecodeError::Format(format!(
                    "formatter at byte {offset}: array without dimensions (size word at byte {at})"
                )));
            }
            let depth = nested(r)?;
            let elem = Box::new(decode(r, depth)?);
            // Re-check now that the element has been read.
            r.check_count(r.position(), n as i64, 4)?;
            let mut dims = Vec::with_capacity(n);
            for _ in 0..n {
                let at = r.position();
                dims.push(non_negative(at, r.read_i32()?)?);
            }
            if class == FIXED_ARRAY {
                Format::FixedArray { elem, dims }
            } else {
                Format::VarArray { elem, dims }
            }
        }
        NAMED => Format::Named(r.read_str()?.to_string()),
        ENUM => {
            let n = read_items(r, 2, 4)?;
            let max = r.read_i32()?;
            r.check_count(r.position(), n as i64, 5)?;
            let mut names = Vec::with_capacity(n);
            for _ in 0..n {
                names.push(r.read_str()?.to_string());
            }
            Format::Enum { names, max }
        }
        BAD_FORMAT => {
            return Err(DecodeError::Format(format!(
                "formatter at byte {offset} is a bad format (class 6): the sender could not parse its format string"
            )))
        }
        other => {
            return Err(DecodeError::Format(format!(
                "formatter at byte {offset} has unknown class {other}"
            )))
        }
    })
}
