//! Lexer and parser for IPC format strings (manual §3, ipc.md §9.6).
//!
//! The grammar (`parseFmttrs.c`):
//!
//! ```text
//! fmt    := prim | NAME | INT | '{' fields '}' | '{' 'enum' names '}' | '{' 'enum' ':' INT '}'
//!         | '[' fmt ':' INT (',' INT)* ']' | '[' INT ':' fmt ']'
//!         | '<' fmt ':' INT (',' INT)* '>'      (as a struct field only)
//!         | '*' fmt | '*' '!'                   (*! as a struct field only)
//! fields := ε | fmt (',' fmt)*          names := NAME (',' NAME)*
//! ```

use super::registry::{check_var_dims, DimProblem, FormatRegistry, ResolveError};
use super::{Format, Primitive};

/// Deepest nesting of composite formats (`{`, `[`, `<`, `*`) that [`parse`],
/// [`FormatRegistry::resolve`] and [`decode_formatter`](super::decode_formatter)
/// accept, so that hostile input cannot overflow the stack.
pub const MAX_NESTING: usize = 256;

/// Why a format string could not be parsed. Positions are byte offsets into
/// the format string.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum ParseError {
    /// A token other than the one the grammar needs.
    #[error("at byte {pos}: expected {expected}, found {found}")]
    Unexpected {
        /// Offset of the offending token.
        pos: usize,
        /// What the grammar allows here.
        expected: &'static str,
        /// What was there, e.g. `'}'`, `end of input`, `name 'foo'`.
        found: String,
    },
    /// A number above `i32::MAX` (C keeps every number in an `int`).
    #[error("at byte {pos}: number {text} is too large (at most 2147483647)")]
    NumberTooLarge {
        /// Offset of the number.
        pos: usize,
        /// Its digits (shortened if very long).
        text: String,
    },
    /// `<T:k>` somewhere other than directly inside a struct.
    #[error("at byte {pos}: a variable array '<...>' must be a field of a struct '{{...}}'")]
    VarArrayOutsideStruct {
        /// Offset of the `<`.
        pos: usize,
    },
    /// `*!` somewhere other than directly inside a struct.
    #[error("at byte {pos}: a self pointer '*!' must be a field of a struct '{{...}}'")]
    SelfPointerOutsideStruct {
        /// Offset of the `*`.
        pos: usize,
    },
    /// A variable-array dimension names a field the struct does not have.
    #[error("at byte {pos}: variable array dimension {index} names no field of the enclosing struct, which has {fields} field(s) (dimensions count fields from 1)")]
    DimensionOutOfRange {
        /// Offset of the variable array.
        pos: usize,
        /// The 1-based field index given.
        index: u32,
        /// Number of fields of the enclosing struct.
        fields: usize,
    },
    /// A variable-array dimension names a field that is not an integer.
    #[error("at byte {pos}: variable array dimension {index} names field {index}, which is '{found}', not an integer (byte, ubyte, short, ushort, int, uint, long, ulong)")]
    DimensionNotInteger {
        /// Offset of the variable array.
        pos: usize,
        /// The 1-based field index given.
        index: u32,
        /// The field's format.
        found: String,
    },
    /// Composite formats nested deeper than [`MAX_NESTING`].
    #[error("at byte {pos}: formats nested deeper than {max} levels")]
    TooDeep {
        /// Offset where the limit was hit.
        pos: usize,
        /// The limit.
        max: usize,
    },
    /// [`parse_with`]: a name that is neither a primitive nor in the registry.
    #[error("at byte {pos}: unknown format name '{name}'")]
    UnknownName {
        /// Offset of the name.
        pos: usize,
        /// The name.
        name: String,
    },
    /// [`parse_with`]: a named format whose definition cannot be expanded.
    #[error("at byte {pos}: named format '{name}' cannot be expanded: {source}")]
    Name {
        /// Offset of the name.
        pos: usize,
        /// The name.
        name: String,
        /// What is wrong with its definition.
        source: ResolveError,
    },
    /// [`FormatRegistry::define`] / [`FormatRegistry::insert`]: the name
    /// cannot be used as a format name (empty, a primitive, `enum`, starts
    /// with a digit, or holds white space or one of `{}[]<>,:`).
    #[error("'{name}' cannot be a format name")]
    InvalidName {
        /// The name.
        name: String,
    },
    /// [`FormatRegistry::define`] / [`FormatRegistry::insert`]: a named
    /// format must describe some data (C fails on it when it is used).
    #[error("named format '{name}' has an empty definition")]
    EmptyDefinition {
        /// The name.
        name: String,
    },
}

impl ParseError {
    /// The byte offset of the error in the format string, if it has one.
    pub fn pos(&self) -> Option<usize> {
        match self {
            ParseError::Unexpected { pos, .. }
            | ParseError::NumberTooLarge { pos, .. }
            | ParseError::VarArrayOutsideStruct { pos }
            | ParseError::SelfPointerOutsideStruct { pos }
            | ParseError::DimensionOutOfRange { pos, .. }
            | ParseError::DimensionNotInteger { pos, .. }
            | ParseError::TooDeep { pos, .. }
            | ParseError::UnknownName { pos, .. }
            | ParseError::Name { pos, .. } => Some(*pos),
            ParseError::InvalidName { .. } | ParseError::EmptyDefinition { .. } => None,
        }
    }
}

/// Parses a format string. Names that are not primitives become
/// [`Format::Named`]; expand them with [`FormatRegistry::resolve`] or parse
/// with [`parse_with`]. An empty (or all white-space) string is [`Format::Empty`].
///
/// ```
/// use courier_wire::format::{parse, Format, Primitive};
/// assert_eq!(parse("*int").unwrap(), Format::Pointer(Box::new(Format::Primitive(Primitive::Int))));
/// let e = parse("{int, [double:2,3}").unwrap_err();
/// assert_eq!(e.to_string(), "at byte 17: expected ',' or ']' after an array dimension, found '}'");
/// ```
pub fn parse(s: &str) -> Result<Format, ParseError> {
    Parser::new(s, None)?.parse_top()
}

/// Parses a format string, expanding named formats from `registry` as the C
/// parser does; a name met again inside its own expansion stays
/// [`Format::Named`] (recursive formats). Unknown names are an error.
pub fn parse_with(s: &str, registry: &FormatRegistry) -> Result<Format, ParseError> {
    Parser::new(s, Some(registry))?.parse_top()
}

/// True if `s` lexes as one name token: non-empty, not starting with a digit
/// or one of `{}[]<>*!,:`, and holding no white space and none of `{}[]<>,:`.
pub(crate) fn is_name_token(s: &str) -> bool {
    let mut chars = s.chars();
    match chars.next() {
        None => false,
        Some(c) if c.is_ascii_digit() || c.is_whitespace() || is_punct(c) => false,
        Some(_) => chars.all(|c| !c.is_whitespace() && !ends_name(c)),
    }
}

/// True if `s` may name a format in a registry: a name token that is not a
/// primitive and not `enum`.
pub(crate) fn is_format_name(s: &str) -> bool {
    is_name_token(s) && s != "enum" && Primitive::from_name(s).is_none()
}

fn is_punct(c: char) -> bool {
    matches!(c, '{' | '}' | '[' | ']' | '<' | '>' | '*' | '!' | ',' | ':')
}

/// Characters that end a name (`ReadString` in `lex.c`; `*` and `!` do not).
fn ends_name(c: char) -> bool {
    matches!(c, '{' | '}' | '[' | ']' | '<' | '>' | ',' | ':')
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Tok<'a> {
    LBrace,
    RBrace,
    LBrack,
    RBrack,
    Lt,
    Gt,
    Star,
    Bang,
    Comma,
    Colon,
    Int(u32),
    Name(&'a str),
    End,
}

#[derive(Debug, Clone, Copy)]
struct Token<'a> {
    tok: Tok<'a>,
    pos: usize,
}

fn shorten(s: &str) -> String {
    const MAX: usize = 40;
    if s.chars().count() <= MAX {
        s.to_string()
    } else {
        let mut t: String = s.chars().take(MAX).collect();
        t.push('…');
        t
    }
}

fn describe(t: Tok<'_>) -> String {
    match t {
        Tok::LBrace => "'{'".into(),
        Tok::RBrace => "'}'".into(),
        Tok::LBrack => "'['".into(),
        Tok::RBrack => "']'".into(),
        Tok::Lt => "'<'".into(),
        Tok::Gt => "'>'".into(),
        Tok::Star => "'*'".into(),
        Tok::Bang => "'!'".into(),
        Tok::Comma => "','".into(),
        Tok::Colon => "':'".into(),
        Tok::Int(n) => format!("number {n}"),
        Tok::Name(s) => format!("name '{}'", shorten(s)),
        Tok::End => "end of input".into(),
    }
}

fn lex(s: &str) -> Result<Vec<Token<'_>>, ParseError> {
    let mut toks = Vec::new();
    let mut it = s.char_indices().peekable();
    while let Some((pos, c)) = it.next() {
        let tok = match c {
            c if c.is_whitespace() => continue,
            '{' => Tok::LBrace,
            '}' => Tok::RBrace,
            '[' => Tok::LBrack,
            ']' => Tok::RBrack,
            '<' => Tok::Lt,
            '>' => Tok::Gt,
            '*' => Tok::Star,
            '!' => Tok::Bang,
            ',' => Tok::Comma,
            ':' => Tok::Colon,
            '0'..='9' => {
                let mut end = pos + 1;
                while let Some(&(p, d)) = it.peek() {
                    if !d.is_ascii_digit() {
                        break;
                    }
                    end = p + 1;
                    it.next();
                }
                let text = &s[pos..end];
                match text.parse::<u32>() {
                    Ok(n) if n <= i32::MAX as u32 => Tok::Int(n),
                    _ => {
                        return Err(ParseError::NumberTooLarge {
                            pos,
                            text: shorten(text),
                        })
                    }
                }
            }
            _ => {
                let mut end = pos + c.len_utf8();
                while let Some(&(p, d)) = it.peek() {
                    if d.is_whitespace() || ends_name(d) {
                        break;
                    }
                    end = p + d.len_utf8();
                    it.next();
                }
                Tok::Name(&s[pos..end])
            }
        };
        toks.push(Token { tok, pos });
    }
    toks.push(Token {
        tok: Tok::End,
        pos: s.len(),
    });
    Ok(toks)
}

struct Parser<'a> {
    toks: Vec<Token<'a>>,
    i: usize,
    registry: Option<&'a FormatRegistry>,
}

impl<'a> Parser<'a> {
    fn new(s: &'a str, registry: Option<&'a FormatRegistry>) -> Result<Self, ParseError> {
        Ok(Parser {
            toks: lex(s)?,
            i: 0,
            registry,
        })
    }

    fn peek(&self) -> Token<'a> {
        self.peek_at(0)
    }

    fn peek_at(&self, k: usize) -> Token<'a> {
        let last = self.toks.len() - 1;
        self.toks[(self.i + k).min(last)]
    }

    fn next(&mut self) -> Token<'a> {
        let t = self.peek();
        if self.i < self.toks.len() - 1 {
            self.i += 1;
        }
        t
    }

    fn expect(
        &mut self,
        want: Tok<'static>,
        expected: &'static str,
    ) -> Result<Token<'a>, ParseError> {
        let t = self.next();
        if t.tok == want {
            Ok(t)
        } else {
            Err(unexpected(t, expected))
        }
    }

    fn parse_top(mut self) -> Result<Format, ParseError> {
        if self.peek().tok == Tok::End {
            return Ok(Format::Empty);
        }
        let f = self.format(false, 0)?;
        let t = self.next();
        if t.tok != Tok::End {
            return Err(unexpected(t, "end of input after the format"));
        }
        Ok(f)
    }

    fn enter(&self, pos: usize, depth: usize) -> Result<usize, ParseError> {
        if depth >= MAX_NESTING {
            Err(ParseError::TooDeep {
                pos,
                max: MAX_NESTING,
            })
        } else {
            Ok(depth + 1)
        }
    }

    fn format(&mut self, in_struct: bool, depth: usize) -> Result<Format, ParseError> {
        let t = self.next();
        match t.tok {
            Tok::LBrace => {
                let depth = self.enter(t.pos, depth)?;
                if self.peek().tok == Tok::Name("enum") {
                    self.next();
                    self.enumeration()
                } else {
                    self.structure(depth)
                }
            }
            Tok::LBrack => {
                let depth = self.enter(t.pos, depth)?;
                self.fixed_array(depth)
            }
            Tok::Lt => {
                if !in_struct {
                    return Err(ParseError::VarArrayOutsideStruct { pos: t.pos });
                }
                let depth = self.enter(t.pos, depth)?;
                let elem = self.format(false, depth)?;
                self.expect(
                    Tok::Colon,
                    "':' after the element format of a variable array",
                )?;
                let dims = self.dims(Tok::Gt, "',' or '>' after a variable array dimension")?;
                Ok(Format::VarArray {
                    elem: Box::new(elem),
                    dims,
                })
            }
            Tok::Star => {
                if self.peek().tok == Tok::Bang {
                    self.next();
                    if !in_struct {
                        return Err(ParseError::SelfPointerOutsideStruct { pos: t.pos });
                    }
                    return Ok(Format::SelfPointer);
                }
                let depth = self.enter(t.pos, depth)?;
                Ok(Format::Pointer(Box::new(self.format(false, depth)?)))
            }
            Tok::Int(n) => Ok(Format::Length(n)),
            Tok::Name(name) => self.name(t.pos, name, depth),
            _ => Err(unexpected(t, "a format")),
        }
    }

    fn name(&mut self, pos: usize, name: &str, depth: usize) -> Result<Format, ParseError> {
        if let Some(p) = Primitive::from_name(name) {
            return Ok(Format::Primitive(p));
        }
        let Some(reg) = self.registry else {
            return Ok(Format::Named(name.to_string()));
        };
        if reg.get(name).is_none() {
            return Err(ParseError::UnknownName {
                pos,
                name: shorten(name),
            });
        }
        reg.expand_name(name, depth)
            .map_err(|source| ParseError::Name {
                pos,
                name: shorten(name),
                source,
            })
    }

    /// After `{enum`.
    fn enumeration(&mut self) -> Result<Format, ParseError> {
        let t = self.next();
        let f = match t.tok {
            Tok::Colon => {
                let n = self.next();
                match n.tok {
                    Tok::Int(max) => Format::Enum {
                        names: Vec::new(),
                        max: max as i32,
                    },
                    _ => {
                        return Err(unexpected(
                            n,
                            "the largest enum value (a number) after '{enum :'",
                        ))
                    }
                }
            }
            Tok::Name(first) => {
                let mut names = vec![first.to_string()];
                while self.peek().tok == Tok::Comma {
                    self.next();
                    let n = self.next();
                    match n.tok {
                        Tok::Name(s) => names.push(s.to_string()),
                        _ => return Err(unexpected(n, "an enum value name after ','")),
                    }
                }
                let max = i32::try_from(names.len() - 1).unwrap_or(i32::MAX);
                Format::Enum { names, max }
            }
            _ => return Err(unexpected(t, "':' or an enum value name after '{enum'")),
        };
        self.expect(Tok::RBrace, "'}' to close the enum")?;
        Ok(f)
    }

    /// After `{` (not an enum).
    fn structure(&mut self, depth: usize) -> Result<Format, ParseError> {
        let mut fields = Vec::new();
        let mut starts = Vec::new();
        if self.peek().tok == Tok::RBrace {
            self.next();
            return Ok(Format::Struct(fields));
        }
        loop {
            starts.push(self.peek().pos);
            fields.push(self.format(true, depth)?);
            let t = self.next();
            match t.tok {
                Tok::Comma => {}
                Tok::RBrace => break,
                _ => return Err(unexpected(t, "',' or '}' after a struct field")),
            }
        }
        for (f, &pos) in fields.iter().zip(&starts) {
            if let Format::VarArray { dims, .. } = f {
                check_var_dims(&fields, dims, self.registry.is_none()).map_err(|p| match p {
                    DimProblem::OutOfRange { index } => ParseError::DimensionOutOfRange {
                        pos,
                        index,
                        fields: fields.len(),
                    },
                    DimProblem::NotInteger { index, found } => {
                        ParseError::DimensionNotInteger { pos, index, found }
                    }
                })?;
            }
        }
        Ok(Format::Struct(fields))
    }

    /// After `[`.
    fn fixed_array(&mut self, depth: usize) -> Result<Format, ParseError> {
        if let Tok::Int(n) = self.peek().tok {
            // `[n:T]` (old form), or `[n:d1,d2,…]` (n-byte elements).
            self.next();
            self.expect(
                Tok::Colon,
                "':' after the size of an old-style array '[n:format]'",
            )?;
            if let (Tok::Int(d), Tok::Comma) = (self.peek().tok, self.peek_at(1).tok) {
                self.next();
                self.next();
                let mut dims = vec![d];
                dims.extend(self.dims(Tok::RBrack, "',' or ']' after an array dimension")?);
                return Ok(Format::FixedArray {
                    elem: Box::new(Format::Length(n)),
                    dims,
                });
            }
            let elem = self.format(false, depth)?;
            self.expect(Tok::RBrack, "']' after the element format of '[n:format]'")?;
            return Ok(Format::FixedArray {
                elem: Box::new(elem),
                dims: vec![n],
            });
        }
        let elem = self.format(false, depth)?;
        self.expect(Tok::Colon, "':' after the element format of an array")?;
        let dims = self.dims(Tok::RBrack, "',' or ']' after an array dimension")?;
        Ok(Format::FixedArray {
            elem: Box::new(elem),
            dims,
        })
    }

    fn dims(&mut self, close: Tok<'static>, after: &'static str) -> Result<Vec<u32>, ParseError> {
        let mut dims = Vec::new();
        loop {
            let t = self.next();
            match t.tok {
                Tok::Int(n) => dims.push(n),
                _ => return Err(unexpected(t, "an array dimension (a number)")),
            }
            let t = self.next();
            if t.tok == close {
                return Ok(dims);
            }
            if t.tok != Tok::Comma {
                return Err(unexpected(t, after));
            }
        }
    }
}

fn unexpected(t: Token<'_>, expected: &'static str) -> ParseError {
    ParseError::Unexpected {
        pos: t.pos,
        expected,
        found: describe(t.tok),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn p(s: &str) -> Format {
        parse(s).unwrap_or_else(|e| panic!("{s:?}: {e}"))
    }

    #[test]
    fn lexer_names_and_numbers() {
        assert!(is_name_token("T1"));
        assert!(is_name_token("a*b!"));
        assert!(!is_name_token("1a"));
        assert!(!is_name_token("*a"));
        assert!(!is_name_token("a b"));
        assert!(!is_name_token(""));
        assert_eq!(p("12"), Format::Length(12));
        assert_eq!(p(" \t\n int \u{a0}"), Format::Primitive(Primitive::Int));
    }

    #[test]
    fn errors_have_positions() {
        let e = parse("{int, [double:2,3}").unwrap_err();
        assert_eq!(e.pos(), Some(17));
        let e = parse("{int,").unwrap_err();
        assert_eq!(
            e.to_string(),
            "at byte 5: expected a format, found end of input"
        );
        let e = parse("int int").unwrap_err();
        assert_eq!(
            e.to_string(),
            "at byte 4: expected end of input after the format, found name 'int'"
        );
    }
}
