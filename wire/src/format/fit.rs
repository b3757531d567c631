//! Whether data marshalled by one format reads correctly as another: what a
//! subscriber checks before it decodes a message whose format central holds
//! (the C library decodes by the sender's format and never checks the
//! reader's type; a mismatch of equal size then reads as wrong values).
//!
//! [`fits`] is looser than [`equivalent`](super::equivalent) (C's
//! `IPC_checkMsgFormats`): it asks only whether every value lands in a field
//! of the same kind and size, so that a reader's `uint` takes a C `int`, an
//! enum an `int`, and `[int:2,3]` the same bytes as `[int:6]`. It refuses
//! what would decode to wrong values or fail: `int` read as `float`, a
//! `double` as a `long`, a field too many or too few.

use core::fmt;

use super::{Format, Primitive};

/// Where and how two formats differ (see [`fits`]).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Misfit {
    /// The path to the first difference: `field 2`, `field 3, element`, …;
    /// empty at the top.
    pub at: String,
    /// What the data's format has there.
    pub theirs: String,
    /// What the reader's format has there.
    pub ours: String,
}

impl fmt::Display for Misfit {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let at = if self.at.is_empty() {
            "the top"
        } else {
            &self.at
        };
        write!(
            f,
            "at {at}, the data has {} where the reader has {}",
            shown(&self.theirs),
            shown(&self.ours)
        )
    }
}

fn shown(s: &str) -> &str {
    if s.is_empty() {
        "no data"
    } else {
        s
    }
}

/// Checks that data marshalled as `theirs` reads as `ours`, both expanded
/// ([`FormatRegistry::resolve`](super::FormatRegistry::resolve)): the same
/// shape, each primitive of the same kind and size (1-, 2-, 4- and 8-byte
/// integers, `boolean` and enums as 4-byte integers, `float`, `double`,
/// `string`), fixed arrays by element and total count, variable arrays by
/// element and dimension fields, a one-field struct as its field.
pub fn fits(theirs: &Format, ours: &Format) -> Result<(), Misfit> {
    let mut path = Vec::new();
    fit(theirs, ours, &mut path)
}

/// What a primitive (or enum) reads as: a value of this kind takes any of
/// its kind.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Kind {
    Int(usize),
    Float,
    Double,
    String,
    Formatter,
}

fn kind(f: &Format) -> Option<Kind> {
    Some(match f {
        Format::Enum { .. } => Kind::Int(4),
        Format::Primitive(p) => match p {
            Primitive::Float => Kind::Float,
            Primitive::Double => Kind::Double,
            Primitive::String => Kind::String,
            Primitive::Format => Kind::Formatter,
            p => Kind::Int(p.wire_size()?),
        },
        _ => return None,
    })
}

/// `[T:d1,d2]` and `[[T:d2]:d1]` as one element and a total count.
fn flat(f: &Format) -> Option<(&Format, u64)> {
    let Format::FixedArray { elem, dims } = f else {
        return None;
    };
    let n = dims.iter().map(|&d| u64::from(d)).product::<u64>();
    Some(match flat(elem) {
        Some((e, m)) => (e, n * m),
        None => (elem, n),
    })
}

fn fit(theirs: &Format, ours: &Format, path: &mut Vec<String>) -> Result<(), Misfit> {
    let misfit = |path: &[String]| Misfit {
        at: path.join(", "),
        theirs: theirs.to_string(),
        ours: ours.to_string(),
    };
    // a one-field struct marshals as its field
    match (theirs, ours) {
        (Format::Struct(a), b) if a.len() == 1 && !matches!(b, Format::Struct(_)) => {
            return fit(&a[0], b, path);
        }
        (a, Format::Struct(b)) if b.len() == 1 && !matches!(a, Format::Struct(_)) => {
            return fit(a, &b[0], path);
        }
        _ => {}
    }
    if let (Some(a), Some(b)) = (kind(theirs), kind(ours)) {
        return if a == b { Ok(()) } else { Err(misfit(path)) };
    }
    match (theirs, ours) {
        (Format::Empty, Format::Empty) | (Format::SelfPointer, Format::SelfPointer) => Ok(()),
        (Format::Length(a), Format::Length(b)) if a == b => Ok(()),
        // `n` raw bytes and an array of n one-byte values
        (Format::Length(n), arr @ Format::FixedArray { .. })
        | (arr @ Format::FixedArray { .. }, Format::Length(n))
            if flat(arr)
                .is_some_and(|(e, m)| m == u64::from(*n) && kind(e) == Some(Kind::Int(1))) =>
        {
            Ok(())
        }
        (Format::Named(a), Format::Named(b)) if a == b => Ok(()),
        (Format::Struct(a), Format::Struct(b)) => {
            if a.len() != b.len() {
                return Err(misfit(path));
            }
            for (i, (x, y)) in a.iter().zip(b).enumerate() {
                inside(format!("field {}", i + 1), x, y, path)?;
            }
            Ok(())
        }
        (Format::Pointer(a), Format::Pointer(b)) => inside("pointee".into(), a, b, path),
        (Format::VarArray { elem: a, dims: x }, Format::VarArray { elem: b, dims: y })
            if x == y =>
        {
            inside("element".into(), a, b, path)
        }
        (Format::FixedArray { .. }, Format::FixedArray { .. }) => {
            match (flat(theirs), flat(ours)) {
                (Some((a, n)), Some((b, m))) if n == m => inside("element".into(), a, b, path),
                _ => Err(misfit(path)),
            }
        }
        _ => Err(misfit(path)),
    }
}

/// [`fit`] one step down, `step` naming it in the path.
fn inside(
    step: String,
    theirs: &Format,
    ours: &Format,
    path: &mut Vec<String>,
) -> Result<(), Misfit> {
    path.push(step);
    fit(theirs, ours, path)?;
    path.pop();
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::format::parse;

    fn check(theirs: &str, ours: &str) -> Result<(), String> {
        fits(&parse(theirs).unwrap(), &parse(ours).unwrap()).map_err(|m| m.to_string())
    }

    #[test]
    fn same_kind_and_size_fits() {
        for (a, b) in [
            ("int", "int"),
            ("int", "uint"),
            ("int", "{enum : 3}"),
            ("{enum A, B}", "{enum : 7}"),
            ("boolean", "int"),
            ("long", "ulong"),
            ("byte", "char"),
            ("short", "twobyte"),
            ("{int, double}", "{uint, double}"),
            ("[int:2,3]", "[[int:3]:2]"),
            ("[int:6]", "[int:2,3]"),
            ("{int}", "int"),
            ("string", "{string}"),
            ("{int, <double:1>}", "{uint, <double:1>}"),
            ("*{int, string}", "*{int, string}"),
            ("{int, *!}", "{int, *!}"),
            ("4", "[ubyte:4]"),
            ("[char:2,3]", "6"),
            ("", ""),
        ] {
            assert_eq!(check(a, b), Ok(()), "{a} as {b}");
        }
    }

    #[test]
    fn another_kind_or_size_names_where() {
        for (a, b, want) in [
            (
                "int",
                "float",
                "at the top, the data has int where the reader has float",
            ),
            (
                "{int, int}",
                "{int, int, int}",
                "at the top, the data has {int, int} where the reader has {int, int, int}",
            ),
            (
                "{string, {int, double}}",
                "{string, {int, long}}",
                "at field 2, field 2, the data has double where the reader has long",
            ),
            (
                "[int:2,3]",
                "[int:5]",
                "at the top, the data has [int:2,3] where the reader has [int:5]",
            ),
            (
                "{int, <float:1>}",
                "{int, <double:1>}",
                "at field 2, element, the data has float where the reader has double",
            ),
            (
                "{int, int, <byte:1,2>}",
                "{int, int, <byte:2>}",
                "at field 3, the data has <byte:1,2> where the reader has <byte:2>",
            ),
            (
                "short",
                "int",
                "at the top, the data has short where the reader has int",
            ),
            (
                "int",
                "",
                "at the top, the data has int where the reader has no data",
            ),
            (
                "*int",
                "int",
                "at the top, the data has *int where the reader has int",
            ),
            (
                "4",
                "int",
                "at the top, the data has 4 where the reader has int",
            ),
        ] {
            assert_eq!(check(a, b), Err(want.to_string()), "{a} as {b}");
        }
    }
}
