//! Named formats (`IPC_defineFormat`), their expansion, and format equality
//! as `IPC_checkMsgFormats` decides it.

use std::collections::BTreeMap;

use super::parse::{is_format_name, parse, ParseError, MAX_NESTING};
use super::Format;

/// Most format nodes one expansion of named formats may produce, so that
/// definitions that double at every level (`A = {B, B}`, `B = {C, C}`, …)
/// cannot exhaust memory. An enum counts one node more per
/// [`ENUM_BYTES_PER_NODE`] bytes of its names (each copy of a named enum
/// holds its names again: 10 KB of names doubled 19 times were 5 GB).
pub const MAX_EXPANDED_NODES: usize = 1 << 20;

/// Bytes of enum names that count as one node of [`MAX_EXPANDED_NODES`].
pub const ENUM_BYTES_PER_NODE: usize = 64;

/// Why a format's named references could not be expanded, or why the
/// expanded format is not a valid IPC format.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum ResolveError {
    /// A name that is neither a primitive nor defined in the registry.
    #[error("unknown format name '{name}'")]
    UnknownName {
        /// The name.
        name: String,
    },
    /// Nesting (composites plus named expansions) deeper than [`MAX_NESTING`].
    #[error("format nested deeper than {max} levels")]
    TooDeep {
        /// The limit.
        max: usize,
    },
    /// The expansion would exceed [`MAX_EXPANDED_NODES`] nodes.
    #[error("expanded format has more than {max} nodes")]
    TooLarge {
        /// The limit.
        max: usize,
    },
    /// A variable array that is not a field of a struct.
    #[error("a variable array '<...>' must be a field of a struct")]
    VarArrayOutsideStruct,
    /// A self pointer that is not a field of a struct.
    #[error("a self pointer '*!' must be a field of a struct")]
    SelfPointerOutsideStruct,
    /// [`Format::Empty`] inside a composite format (it only means "no data" at the top).
    #[error("the empty format cannot be part of another format")]
    EmptyInComposite,
    /// A variable-array dimension names a field the struct does not have.
    #[error("variable array dimension {index} names no field of the enclosing struct, which has {fields} field(s)")]
    DimensionOutOfRange {
        /// The 1-based field index.
        index: u32,
        /// Number of fields of the struct.
        fields: usize,
    },
    /// A variable-array dimension names a field that is not an integer.
    #[error("variable array dimension {index} names field '{found}', which is not an integer")]
    DimensionNotInteger {
        /// The 1-based field index.
        index: u32,
        /// The field's format.
        found: String,
    },
}

/// A problem with one variable array's dimensions (shared by the parser and
/// the expander, which report it with and without a position).
pub(crate) enum DimProblem {
    OutOfRange { index: u32 },
    NotInteger { index: u32, found: String },
}

/// Checks that every dimension of a variable array names an integer field
/// of `fields` (1-based). `allow_named` accepts unexpanded names, whose type
/// is not known yet.
pub(crate) fn check_var_dims(
    fields: &[Format],
    dims: &[u32],
    allow_named: bool,
) -> Result<(), DimProblem> {
    for &index in dims {
        let i = index as usize;
        if i == 0 || i > fields.len() {
            return Err(DimProblem::OutOfRange { index });
        }
        match &fields[i - 1] {
            Format::Primitive(p) if p.is_integer() => {}
            Format::Named(_) if allow_named => {}
            other => {
                let mut found = other.to_string();
                if found.len() > 60 {
                    let mut cut = 60;
                    while !found.is_char_boundary(cut) {
                        cut -= 1;
                    }
                    found.truncate(cut);
                    found.push('…');
                }
                return Err(DimProblem::NotInteger { index, found });
            }
        }
    }
    Ok(())
}

/// Named formats: what `IPC_defineFormat` registers with central, and what
/// central expands when it parses a message format.
///
/// Definitions are stored as parsed, with their own named references
/// unexpanded (the C library also parses a definition only when it is used);
/// [`resolve`](Self::resolve) and [`parse_with`](super::parse_with) expand them.
///
/// ```
/// use courier_wire::format::{parse, FormatRegistry};
/// let mut reg = FormatRegistry::new();
/// reg.define("Point", "{double, double}").unwrap();
/// reg.define("List", "{Point, *List}").unwrap();
/// let f = reg.resolve(&parse("{int, List}").unwrap()).unwrap();
/// assert_eq!(f.to_string(), "{int, {{double, double}, *List}}");
/// ```
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct FormatRegistry {
    formats: BTreeMap<String, Format>,
}

impl FormatRegistry {
    /// An empty registry.
    pub fn new() -> Self {
        Self::default()
    }

    /// Parses `format` and registers it under `name`, replacing an earlier
    /// definition (as `IPC_defineFormat` does). Names it uses need not be
    /// defined yet.
    pub fn define(&mut self, name: &str, format: &str) -> Result<(), ParseError> {
        if !is_format_name(name) {
            return Err(ParseError::InvalidName {
                name: name.to_string(),
            });
        }
        let f = parse(format)?;
        self.insert(name, f)
    }

    /// Registers an already parsed format under `name`, replacing an
    /// earlier definition. The empty format cannot be named.
    pub fn insert(&mut self, name: &str, format: Format) -> Result<(), ParseError> {
        if !is_format_name(name) {
            return Err(ParseError::InvalidName {
                name: name.to_string(),
            });
        }
        if format == Format::Empty {
            return Err(ParseError::EmptyDefinition {
                name: name.to_string(),
            });
        }
        self.formats.insert(name.to_string(), format);
        Ok(())
    }

    /// The definition registered under `name`, unexpanded.
    pub fn get(&self, name: &str) -> Option<&Format> {
        self.formats.get(name)
    }

    /// True if `name` is defined.
    pub fn contains(&self, name: &str) -> bool {
        self.formats.contains_key(name)
    }

    /// Removes the definition of `name`, returning it.
    pub fn remove(&mut self, name: &str) -> Option<Format> {
        self.formats.remove(name)
    }

    /// Number of named formats.
    pub fn len(&self) -> usize {
        self.formats.len()
    }

    /// True if no format is defined.
    pub fn is_empty(&self) -> bool {
        self.formats.is_empty()
    }

    /// The defined names and their (unexpanded) formats, in name order.
    pub fn iter(&self) -> impl Iterator<Item = (&str, &Format)> {
        self.formats.iter().map(|(k, v)| (k.as_str(), v))
    }

    /// Expands every named reference in `f` by its definition, recursively,
    /// as the C parser does at parse time. A name met again inside its own
    /// expansion stays [`Format::Named`] (recursive types such as lists).
    ///
    /// The result is also checked: variable arrays and self pointers only as
    /// struct fields, variable-array dimensions naming integer fields,
    /// [`Format::Empty`] only at the top, nesting within [`MAX_NESTING`].
    pub fn resolve(&self, f: &Format) -> Result<Format, ResolveError> {
        if *f == Format::Empty {
            return Ok(Format::Empty);
        }
        Expander::new(self).expand(f, 0, false)
    }

    /// [`equivalent`] with this registry.
    pub fn equivalent(&self, a: &Format, b: &Format) -> bool {
        equivalent(a, b, self)
    }

    /// Expansion of `name` for the parser, at nesting `depth`.
    pub(crate) fn expand_name(&self, name: &str, depth: usize) -> Result<Format, ResolveError> {
        Expander::new(self).expand(&Format::Named(name.to_string()), depth, false)
    }
}

/// True if `a` and `b` are the same format as `IPC_checkMsgFormats` decides
/// it (`formatsEqual` in `formatters.c`, applied to formats whose names were
/// expanded when they were parsed).
///
/// Both formats are expanded with `registry`; then they are equal if they
/// have the same shape node for node:
/// - primitives by formatter code (`int` ≠ `uint`, `long` ≠ `ulong`,
///   `byte` ≠ `char`), byte counts by count;
/// - structs field by field, with the same number of fields;
/// - fixed and variable arrays by element format and by the exact list of
///   dimensions: `[int:2,3]` ≠ `[[int:3]:2]` ≠ `[int:6]`, although all three
///   marshal the same bytes;
/// - pointers by pointee; self pointers equal self pointers;
/// - enums by maximum value *and* by the list of names:
///   `{enum : 3}` ≠ `{enum A, B, C, D}`, `{enum A, B}` ≠ `{enum a, b}`;
/// - names left after expansion (recursive references) by name;
/// - the empty format equals only itself (both NULL in C).
///
/// A format that cannot be expanded (unknown name, invalid) equals nothing,
/// as C's `BadFormat` does.
pub fn equivalent(a: &Format, b: &Format, registry: &FormatRegistry) -> bool {
    match (registry.resolve(a), registry.resolve(b)) {
        (Ok(x), Ok(y)) => x == y,
        _ => false,
    }
}

struct Expander<'r> {
    registry: &'r FormatRegistry,
    stack: Vec<&'r str>,
    nodes: usize,
}

impl<'r> Expander<'r> {
    fn new(registry: &'r FormatRegistry) -> Self {
        Expander {
            registry,
            stack: Vec::new(),
            nodes: 0,
        }
    }

    fn deeper(depth: usize) -> Result<usize, ResolveError> {
        if depth >= MAX_NESTING {
            Err(ResolveError::TooDeep { max: MAX_NESTING })
        } else {
            Ok(depth + 1)
        }
    }

    fn expand(
        &mut self,
        f: &Format,
        depth: usize,
        in_struct: bool,
    ) -> Result<Format, ResolveError> {
        self.nodes += 1;
        if self.nodes > MAX_EXPANDED_NODES {
            return Err(ResolveError::TooLarge {
                max: MAX_EXPANDED_NODES,
            });
        }
        Ok(match f {
            Format::Empty => return Err(ResolveError::EmptyInComposite),
            Format::Enum { names, .. } => {
                let bytes: usize = names
                    .iter()
                    .map(|n| n.len() + std::mem::size_of::<String>())
                    .sum();
                self.nodes += bytes / ENUM_BYTES_PER_NODE;
                if self.nodes > MAX_EXPANDED_NODES {
                    return Err(ResolveError::TooLarge {
                        max: MAX_EXPANDED_NODES,
                    });
                }
                f.clone()
            }
            Format::Primitive(_) | Format::Length(_) => f.clone(),
            Format::SelfPointer => {
                if !in_struct {
                    return Err(ResolveError::SelfPointerOutsideStruct);
                }
                Format::SelfPointer
            }
            Format::Named(name) => {
                if self.stack.contains(&name.as_str()) {
                    return Ok(f.clone());
                }
                let Some((key, def)) = self.registry.formats.get_key_value(name.as_str()) else {
                    return Err(ResolveError::UnknownName { name: name.clone() });
                };
                let depth = Self::deeper(depth)?;
                self.stack.push(key.as_str());
                // A definition is a format string of its own: it is parsed
                // outside any struct.
                let r = self.expand(def, depth, false);
                self.stack.pop();
                r?
            }
            Format::Struct(fields) => {
                let depth = Self::deeper(depth)?;
                let mut out = Vec::with_capacity(fields.len());
                for field in fields {
                    out.push(self.expand(field, depth, true)?);
                }
                for field in &out {
                    if let Format::VarArray { dims, .. } = field {
                        check_var_dims(&out, dims, false).map_err(|p| match p {
                            DimProblem::OutOfRange { index } => ResolveError::DimensionOutOfRange {
                                index,
                                fields: out.len(),
                            },
                            DimProblem::NotInteger { index, found } => {
                                ResolveError::DimensionNotInteger { index, found }
                            }
                        })?;
                    }
                }
                Format::Struct(out)
            }
            Format::Pointer(inner) => {
                let depth = Self::deeper(depth)?;
                Format::Pointer(Box::new(self.expand(inner, depth, false)?))
            }
            Format::FixedArray { elem, dims } => {
                let depth = Self::deeper(depth)?;
                Format::FixedArray {
                    elem: Box::new(self.expand(elem, depth, false)?),
                    dims: dims.clone(),
                }
            }
            Format::VarArray { elem, dims } => {
                if !in_struct {
                    return Err(ResolveError::VarArrayOutsideStruct);
                }
                let depth = Self::deeper(depth)?;
                Format::VarArray {
                    elem: Box::new(self.expand(elem, depth, false)?),
                    dims: dims.clone(),
                }
            }
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `L0 = base`, `Lk = {L(k-1), L(k-1)}`: `Ln` expands to 2^n copies.
    fn doubling(base: &str, levels: usize) -> FormatRegistry {
        let mut reg = FormatRegistry::new();
        reg.define("L0", base).unwrap();
        for k in 1..=levels {
            reg.define(&format!("L{k}"), &format!("{{L{0}, L{0}}}", k - 1))
                .unwrap();
        }
        reg
    }

    #[test]
    fn definitions_that_double_are_refused_past_the_node_bound() {
        let reg = doubling("{int, int}", 30);
        assert_eq!(
            reg.resolve(&Format::Named("L30".into())),
            Err(ResolveError::TooLarge {
                max: MAX_EXPANDED_NODES
            })
        );
        // well within it: expanded
        assert!(reg.resolve(&Format::Named("L10".into())).is_ok());
    }

    /// Each copy of a named enum holds its names again: 12 KB of names
    /// doubled 13 times was 100 MB from one lookup, within the node bound
    /// (16 384 nodes). The names count now.
    #[test]
    fn enum_names_count_toward_the_bound() {
        let names: Vec<String> = (0..100)
            .map(|i| format!("N{i}_{}", "x".repeat(96)))
            .collect();
        let reg = doubling(&format!("{{enum {}}}", names.join(", ")), 13);
        assert_eq!(
            reg.resolve(&Format::Named("L13".into())),
            Err(ResolveError::TooLarge {
                max: MAX_EXPANDED_NODES
            })
        );
        // a few copies are fine
        let f = reg.resolve(&Format::Named("L3".into())).unwrap();
        let Format::Struct(fields) = f else {
            panic!("{f:?}")
        };
        assert_eq!(fields.len(), 2);
    }
}
