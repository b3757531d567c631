//! The canonical string form of a [`Format`].

use core::fmt::{self, Display, Formatter, Write};

use super::Format;

/// Prints the canonical form: `{int, {enum : 3}, [double:2,3], double}`,
/// `<T:1,2>`, `*int`, `*!`, `{enum A, B}`: ", " between struct fields and
/// enum names, no spaces inside array brackets, `{enum : N}` for enums
/// without names. [`Format::Empty`] prints as the empty string.
///
/// A fixed array of byte counts prints in the old form `[d:n]` when it has
/// one dimension (the new form `[n:d]` would read back as the old one) and
/// as `[n:d1,d2]` otherwise.
///
/// [`parse`](super::parse) reads the output back to an equal tree, for every
/// tree that `parse` or [`decode_formatter`](super::decode_formatter) can
/// produce and whose names are name tokens. Trees with no string form
/// (`Empty` inside a composite, an array without dimensions, an enum with a
/// negative maximum) print something that does not parse.
impl Display for Format {
    fn fmt(&self, f: &mut Formatter<'_>) -> fmt::Result {
        match self {
            Format::Empty => Ok(()),
            Format::Primitive(p) => f.write_str(p.name()),
            Format::Length(n) => write!(f, "{n}"),
            Format::Struct(fields) => {
                f.write_char('{')?;
                for (i, field) in fields.iter().enumerate() {
                    if i > 0 {
                        f.write_str(", ")?;
                    }
                    field.fmt(f)?;
                }
                f.write_char('}')
            }
            Format::Pointer(inner) => {
                f.write_char('*')?;
                inner.fmt(f)
            }
            Format::SelfPointer => f.write_str("*!"),
            Format::FixedArray { elem, dims } => {
                if let (Format::Length(n), [d]) = (elem.as_ref(), dims.as_slice()) {
                    return write!(f, "[{d}:{n}]");
                }
                write!(f, "[{elem}:")?;
                write_dims(f, dims)?;
                f.write_char(']')
            }
            Format::VarArray { elem, dims } => {
                write!(f, "<{elem}:")?;
                write_dims(f, dims)?;
                f.write_char('>')
            }
            Format::Enum { names, max } => {
                if names.is_empty() {
                    write!(f, "{{enum : {max}}}")
                } else {
                    f.write_str("{enum ")?;
                    for (i, n) in names.iter().enumerate() {
                        if i > 0 {
                            f.write_str(", ")?;
                        }
                        f.write_str(n)?;
                    }
                    f.write_char('}')
                }
            }
            Format::Named(n) => f.write_str(n),
        }
    }
}

fn write_dims(f: &mut Formatter<'_>, dims: &[u32]) -> fmt::Result {
    for (i, d) in dims.iter().enumerate() {
        if i > 0 {
            f.write_char(',')?;
        }
        write!(f, "{d}")?;
    }
    Ok(())
}
