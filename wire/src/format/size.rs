//! Sizes: marshalled size of fixed-size formats and the C data-structure
//! layout (`x_ipc_dataStructureSize`, `x_ipc_alignField` on LP64 x86-64).

use super::{Format, Primitive};

/// Size of a C pointer on LP64.
const PTR: usize = 8;
/// Size of a C enum with gcc (always an `int`, whatever the maximum).
const ENUM: usize = 4;

impl Format {
    /// The marshalled size in bytes when it is the same for every value:
    /// the format holds no `string`, `format`, pointer, self pointer,
    /// variable array or (unexpanded or recursive) name. `long`/`ulong`
    /// count 8 bytes and enums 4, as the 64-bit C library sends them;
    /// [`Format::Empty`] is 0. `None` also on arithmetic overflow.
    ///
    /// ```
    /// use courier_wire::format::parse;
    /// assert_eq!(parse("{char, double, short}").unwrap().fixed_wire_size(), Some(11));
    /// assert_eq!(parse("{int, string}").unwrap().fixed_wire_size(), None);
    /// ```
    pub fn fixed_wire_size(&self) -> Option<usize> {
        match self {
            Format::Empty => Some(0),
            Format::Primitive(p) => p.wire_size(),
            Format::Length(n) => Some(*n as usize),
            Format::Struct(fields) => fields
                .iter()
                .try_fold(0usize, |acc, f| acc.checked_add(f.fixed_wire_size()?)),
            Format::FixedArray { elem, dims } => {
                elem.fixed_wire_size()?.checked_mul(element_count(dims)?)
            }
            Format::Enum { .. } => Some(4),
            Format::Pointer(_)
            | Format::SelfPointer
            | Format::VarArray { .. }
            | Format::Named(_) => None,
        }
    }

    /// Size in bytes of the C data structure the format describes, as the
    /// 64-bit x86 C library computes it (`x_ipc_dataStructureSize` with
    /// `ALIGN_LONGEST`): pointers, strings and variable arrays are 8-byte
    /// pointers, enums 4-byte ints, and struct fields are padded as
    /// [`c_align`](Self::c_align) says. `None` if the format holds a name
    /// (resolve it first) or the size overflows.
    ///
    /// ```
    /// use courier_wire::format::parse;
    /// assert_eq!(parse("{char, double, short}").unwrap().c_size(), Some(24));
    /// ```
    pub fn c_size(&self) -> Option<usize> {
        match self {
            Format::Empty => Some(0),
            Format::Primitive(p) => Some(p.c_size()),
            Format::Length(n) => Some(*n as usize),
            Format::Pointer(_) | Format::SelfPointer | Format::VarArray { .. } => Some(PTR),
            Format::Enum { .. } => Some(ENUM),
            Format::FixedArray { elem, dims } => elem.c_size()?.checked_mul(element_count(dims)?),
            Format::Named(_) => None,
            Format::Struct(fields) => {
                let own = self.c_align()?;
                let mut size = 0usize;
                for (i, f) in fields.iter().enumerate() {
                    size = size.checked_add(f.c_size()?)?;
                    // `x_ipc_alignField`: pad to the next field's alignment,
                    // or after the last field to the struct's own.
                    let next = match fields.get(i + 1) {
                        Some(n) => n.c_align()?,
                        None => own,
                    };
                    size = align_up(size, next)?;
                }
                Some(size)
            }
        }
    }

    /// Alignment in bytes the C library assumes for the format as a struct
    /// field (`x_ipc_mostRestrictiveElement` with `ALIGN_LONGEST`): a
    /// primitive's size, 8 for pointers, 4 for enums, an array's element
    /// alignment, a struct's largest field alignment.
    ///
    /// Quirk kept from C: a byte count `n` aligns to `n` (so `{char, 3}` is
    /// 6 bytes in C's view); a byte count of 0 (where C divides by zero) and
    /// an empty struct or [`Format::Empty`] count as 1. `None` if the format
    /// holds a name.
    pub fn c_align(&self) -> Option<usize> {
        match self {
            Format::Empty => Some(1),
            Format::Primitive(p) => Some(p.c_size()),
            Format::Length(n) => Some((*n as usize).max(1)),
            Format::Pointer(_) | Format::SelfPointer | Format::VarArray { .. } => Some(PTR),
            Format::Enum { .. } => Some(ENUM),
            Format::FixedArray { elem, .. } => elem.c_align(),
            Format::Named(_) => None,
            Format::Struct(fields) => fields
                .iter()
                .try_fold(1usize, |m, f| Some(m.max(f.c_align()?))),
        }
    }
}

impl Primitive {
    /// Alignment of the C type on LP64 x86-64 (equal to its size).
    pub const fn c_align(self) -> usize {
        self.c_size()
    }
}

fn element_count(dims: &[u32]) -> Option<usize> {
    dims.iter()
        .try_fold(1usize, |acc, &d| acc.checked_mul(d as usize))
}

fn align_up(n: usize, a: usize) -> Option<usize> {
    let a = a.max(1);
    match n % a {
        0 => Some(n),
        r => n.checked_add(a - r),
    }
}

#[cfg(test)]
mod tests {
    use crate::format::parse;

    fn sizes(s: &str) -> (Option<usize>, Option<usize>, Option<usize>) {
        let f = parse(s).unwrap();
        (f.fixed_wire_size(), f.c_size(), f.c_align())
    }

    #[test]
    fn c_layout() {
        assert_eq!(
            sizes("{char, double, short}"),
            (Some(11), Some(24), Some(8))
        );
        assert_eq!(
            sizes("{int, {enum : 3}, [double:2,3], double}"),
            (Some(64), Some(64), Some(8))
        );
        assert_eq!(sizes("{char, short}"), (Some(3), Some(4), Some(2)));
        assert_eq!(sizes("{int, string}"), (None, Some(16), Some(8)));
        assert_eq!(sizes("{int, <byte:1>}"), (None, Some(16), Some(8)));
        assert_eq!(sizes("{int, *!}"), (None, Some(16), Some(8)));
        assert_eq!(sizes("{char, {char, int}}"), (Some(6), Some(12), Some(4)));
        assert_eq!(sizes("[char:3]"), (Some(3), Some(3), Some(1)));
        assert_eq!(sizes("{long, char}"), (Some(9), Some(16), Some(8)));
        assert_eq!(sizes("{char, 3}"), (Some(4), Some(6), Some(3)));
        assert_eq!(sizes("{}"), (Some(0), Some(0), Some(1)));
        assert_eq!(sizes(""), (Some(0), Some(0), Some(1)));
        assert_eq!(sizes("{int, T}"), (None, None, None));
        assert_eq!(sizes("[int:2147483647,2147483647,2147483647]").0, None);
    }
}
