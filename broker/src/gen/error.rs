//! What can go wrong while generating: every error names the file, line
//! and column it is about.

use std::fmt;
use std::path::PathBuf;

/// A place in an input file (1-based line and column; the column counts
/// characters).
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub struct Pos {
    /// The file as the user named it (or as an `#include` found it).
    pub file: String,
    /// 1-based line.
    pub line: u32,
    /// 1-based column, in characters.
    pub column: u32,
}

impl Pos {
    /// The position `offset` bytes into `text`, a file named `file`.
    pub fn at(file: &str, text: &str, offset: usize) -> Pos {
        let mut offset = offset.min(text.len());
        while !text.is_char_boundary(offset) {
            offset -= 1;
        }
        let before = &text[..offset];
        let line = before.matches('\n').count() + 1;
        let line_start = before.rfind('\n').map_or(0, |i| i + 1);
        let column = text[line_start..offset].chars().count() + 1;
        Pos {
            file: file.to_string(),
            line: u32::try_from(line).unwrap_or(u32::MAX),
            column: u32::try_from(column).unwrap_or(u32::MAX),
        }
    }

    /// `line:column`, without the file (for a second position in the same file).
    pub fn line_column(&self) -> String {
        format!("{}:{}", self.line, self.column)
    }
}

impl fmt::Display for Pos {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}:{}:{}", self.file, self.line, self.column)
    }
}

/// Why `courier gen` could not turn its input into Rust.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum GenError {
    /// An input file (or an included one) could not be read.
    #[error("cannot read {}: {source}", path.display())]
    Read {
        /// The file.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// The text does not follow the input language's grammar.
    #[error("{pos}: expected {expected}, found {found}")]
    Syntax {
        /// Where.
        pos: Pos,
        /// What the grammar allows here.
        expected: String,
        /// What was there.
        found: String,
    },
    /// An IPC format string the format parser of `courier_wire` refuses.
    #[error("{pos}: bad IPC format: {message}")]
    Format {
        /// Where (the offending byte of the format string).
        pos: Pos,
        /// The parser's message, without its byte offset.
        message: String,
    },
    /// A brace, bracket or comment opened and never closed.
    #[error("{pos}: unterminated {what} (opened at {}): expected {expected}, found end of file", opened.line_column())]
    Unterminated {
        /// The end of the file.
        pos: Pos,
        /// What was left open, e.g. "struct `Foo`".
        what: String,
        /// Where it was opened.
        opened: Pos,
        /// What would have closed it.
        expected: String,
    },
    /// A name that is no type known at that point.
    #[error("{pos}: unknown type `{name}`")]
    UnknownType {
        /// Where it is used.
        pos: Pos,
        /// The name as written.
        name: String,
    },
    /// An array or sequence bound that is not a positive integer.
    #[error("{pos}: bad array bound {found}: {why}")]
    BadBound {
        /// Where.
        pos: Pos,
        /// The bound as written or evaluated.
        found: String,
        /// What a bound must be.
        why: String,
    },
    /// A type that contains itself by value, so has no finite size.
    #[error("{pos}: recursive type `{name}` contains itself by value ({cycle}); break the cycle with a sequence, an @optional member or a pointer")]
    Recursive {
        /// Where the type is defined.
        pos: Pos,
        /// The type.
        name: String,
        /// The chain of types, e.g. `A -> B -> A`.
        cycle: String,
    },
    /// A name defined twice in one scope.
    #[error("{pos}: duplicate name `{name}` (first defined at {first})")]
    Duplicate {
        /// The second definition.
        pos: Pos,
        /// The name.
        name: String,
        /// The first definition.
        first: Pos,
    },
    /// A construct of the input language that Courier's types cannot
    /// express (or this generator does not read).
    #[error("{pos}: {what} is not supported: {hint}")]
    Unsupported {
        /// Where.
        pos: Pos,
        /// The construct.
        what: String,
        /// What to do instead.
        hint: String,
    },
    /// An `#include` whose file was found nowhere.
    #[error("{pos}: cannot find included file \"{name}\" (looked in {looked})")]
    Include {
        /// The directive.
        pos: Pos,
        /// The file named.
        name: String,
        /// The directories searched, comma-separated.
        looked: String,
    },
    /// Anything else the input gets wrong (a constant of the wrong type, a
    /// variable array without its count field, …).
    #[error("{pos}: {message}")]
    Invalid {
        /// Where.
        pos: Pos,
        /// What is wrong.
        message: String,
    },
}

impl GenError {
    /// A syntax error at `pos`.
    pub(crate) fn syntax(pos: Pos, expected: impl Into<String>, found: impl Into<String>) -> Self {
        GenError::Syntax {
            pos,
            expected: expected.into(),
            found: found.into(),
        }
    }

    /// An unsupported construct at `pos`.
    pub(crate) fn unsupported(pos: Pos, what: impl Into<String>, hint: impl Into<String>) -> Self {
        GenError::Unsupported {
            pos,
            what: what.into(),
            hint: hint.into(),
        }
    }

    /// Any other problem at `pos`.
    pub(crate) fn invalid(pos: Pos, message: impl Into<String>) -> Self {
        GenError::Invalid {
            pos,
            message: message.into(),
        }
    }
}
