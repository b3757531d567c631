//! The C-like tokens XDR and IDL share (identifiers, numbers, strings,
//! punctuation; `//` and `/* */` comments), with positions, and a cursor
//! over them for the two parsers.

use super::error::{GenError, Pos};

/// A token.
#[derive(Debug, Clone, PartialEq)]
pub enum Tok {
    /// A name or keyword.
    Ident(String),
    /// An integer literal (decimal, `0x` hex, `0` octal).
    Int(i128),
    /// A floating-point literal, as written.
    Float(String),
    /// A string literal, escapes resolved.
    Str(String),
    /// A character literal.
    Char(char),
    /// Punctuation: one character, or `::`, `<<`, `>>`.
    Punct(&'static str),
    /// A line starting with `#` (without the `#`), when directives are on.
    Directive(String),
    /// XDR `%{ ... %}` code (its text).
    Code(String),
    /// The end of the input.
    Eof,
}

impl Tok {
    /// How an error message shows the token.
    pub fn describe(&self) -> String {
        match self {
            Tok::Ident(s) => format!("`{s}`"),
            Tok::Int(n) => format!("`{n}`"),
            Tok::Float(s) => format!("`{s}`"),
            Tok::Str(s) => format!("string {s:?}"),
            Tok::Char(c) => format!("character {c:?}"),
            Tok::Punct(p) => format!("`{p}`"),
            Tok::Directive(d) => format!("`#{}`", d.trim()),
            Tok::Code(_) => "a `%{ ... %}` code section".into(),
            Tok::Eof => "end of file".into(),
        }
    }
}

/// What the lexer accepts besides the common tokens.
#[derive(Debug, Clone, Copy, Default)]
pub struct Options {
    /// `#...` lines become [`Tok::Directive`] (IDL, and XDR's cpp line marks).
    pub directives: bool,
    /// `%{ ... %}` becomes [`Tok::Code`] (XDR).
    pub code_sections: bool,
}

const PUNCT: &[&str] = &[
    "::", "<<", ">>", "{", "}", "[", "]", "<", ">", "(", ")", ";", ",", ":", "=", "*", "@", "+",
    "-", "/", "%", "|", "&", "^", "~", ".",
];

/// Splits `text` (file `file`) into tokens; the last is [`Tok::Eof`].
pub fn lex(file: &str, text: &str, opts: Options) -> Result<Vec<(Tok, Pos)>, GenError> {
    let b = text.as_bytes();
    let mut out = Vec::new();
    let mut i = 0;
    let mut line_start = true;
    let pos = |i: usize| Pos::at(file, text, i);
    while i < b.len() {
        let c = b[i];
        if c == b'\n' {
            line_start = true;
            i += 1;
            continue;
        }
        if c.is_ascii_whitespace() {
            i += 1;
            continue;
        }
        let start = i;
        let at_line_start = std::mem::replace(&mut line_start, false);
        if text[i..].starts_with("//") {
            i = text[i..].find('\n').map_or(b.len(), |n| i + n);
            continue;
        }
        if text[i..].starts_with("/*") {
            match text[i + 2..].find("*/") {
                Some(n) => i += 2 + n + 2,
                None => {
                    return Err(GenError::Unterminated {
                        pos: pos(b.len()),
                        what: "comment".into(),
                        opened: pos(start),
                        expected: "`*/`".into(),
                    })
                }
            }
            continue;
        }
        if opts.code_sections && text[i..].starts_with("%{") {
            match text[i + 2..].find("%}") {
                Some(n) => {
                    out.push((Tok::Code(text[i + 2..i + 2 + n].to_string()), pos(start)));
                    i += 2 + n + 2;
                }
                None => {
                    return Err(GenError::Unterminated {
                        pos: pos(b.len()),
                        what: "code section".into(),
                        opened: pos(start),
                        expected: "`%}`".into(),
                    })
                }
            }
            continue;
        }
        if opts.directives && c == b'#' && at_line_start {
            let end = text[i..].find('\n').map_or(b.len(), |n| i + n);
            out.push((Tok::Directive(text[i + 1..end].to_string()), pos(start)));
            i = end;
            continue;
        }
        if c.is_ascii_alphabetic() || c == b'_' {
            while i < b.len() && (b[i].is_ascii_alphanumeric() || b[i] == b'_') {
                i += 1;
            }
            out.push((Tok::Ident(text[start..i].to_string()), pos(start)));
            continue;
        }
        if c.is_ascii_digit() || (c == b'.' && b.get(i + 1).is_some_and(u8::is_ascii_digit)) {
            let (tok, end) = number(text, i).map_err(|m| GenError::invalid(pos(start), m))?;
            out.push((tok, pos(start)));
            i = end;
            continue;
        }
        if c == b'"' {
            let (s, end) = quoted(text, i, b'"').map_err(|m| GenError::invalid(pos(start), m))?;
            out.push((Tok::Str(s), pos(start)));
            i = end;
            continue;
        }
        if c == b'\'' {
            let (s, end) = quoted(text, i, b'\'').map_err(|m| GenError::invalid(pos(start), m))?;
            let mut cs = s.chars();
            match (cs.next(), cs.next()) {
                (Some(ch), None) => out.push((Tok::Char(ch), pos(start))),
                _ => {
                    return Err(GenError::invalid(
                        pos(start),
                        "a character literal holds one character",
                    ))
                }
            }
            i = end;
            continue;
        }
        match PUNCT.iter().find(|p| text[i..].starts_with(**p)) {
            Some(p) => {
                out.push((Tok::Punct(p), pos(start)));
                i += p.len();
            }
            None => {
                let ch = text[i..].chars().next().unwrap_or('?');
                return Err(GenError::syntax(pos(start), "a token", format!("{ch:?}")));
            }
        }
    }
    out.push((Tok::Eof, pos(b.len())));
    Ok(out)
}

/// An integer or floating-point literal starting at `i`.
fn number(text: &str, i: usize) -> Result<(Tok, usize), String> {
    let b = text.as_bytes();
    let mut j = i;
    if text[i..].starts_with("0x") || text[i..].starts_with("0X") {
        j += 2;
        while j < b.len() && b[j].is_ascii_hexdigit() {
            j += 1;
        }
        let v = i128::from_str_radix(&text[i + 2..j], 16)
            .map_err(|_| format!("bad hexadecimal number `{}`", &text[i..j]))?;
        return Ok((Tok::Int(v), j));
    }
    while j < b.len() && b[j].is_ascii_digit() {
        j += 1;
    }
    let mut float = false;
    if j < b.len() && b[j] == b'.' {
        float = true;
        j += 1;
        while j < b.len() && b[j].is_ascii_digit() {
            j += 1;
        }
    }
    if j < b.len() && (b[j] == b'e' || b[j] == b'E') {
        let mut k = j + 1;
        if k < b.len() && (b[k] == b'+' || b[k] == b'-') {
            k += 1;
        }
        if k < b.len() && b[k].is_ascii_digit() {
            float = true;
            j = k;
            while j < b.len() && b[j].is_ascii_digit() {
                j += 1;
            }
        }
    }
    let lit = &text[i..j];
    if float {
        // IDL's `d`/`D` suffix (fixed-point) is not taken
        return Ok((Tok::Float(lit.to_string()), j));
    }
    let v = if lit.len() > 1 && lit.starts_with('0') {
        i128::from_str_radix(&lit[1..], 8).map_err(|_| format!("bad octal number `{lit}`"))?
    } else {
        lit.parse::<i128>()
            .map_err(|_| format!("number `{lit}` is too large"))?
    };
    Ok((Tok::Int(v), j))
}

/// A quoted literal starting at `i` (the quote), escapes resolved.
fn quoted(text: &str, i: usize, q: u8) -> Result<(String, usize), String> {
    let mut out = String::new();
    let mut chars = text[i + 1..].char_indices();
    while let Some((k, c)) = chars.next() {
        match c {
            c if c as u32 == u32::from(q) => return Ok((out, i + 1 + k + 1)),
            '\n' => break,
            '\\' => match chars.next() {
                Some((_, 'n')) => out.push('\n'),
                Some((_, 't')) => out.push('\t'),
                Some((_, 'r')) => out.push('\r'),
                Some((_, '0')) => out.push('\0'),
                Some((_, 'x')) => {
                    let hex: String = chars.clone().take(2).map(|(_, c)| c).collect();
                    let v = u8::from_str_radix(&hex, 16)
                        .map_err(|_| format!("bad escape `\\x{hex}`"))?;
                    chars.next();
                    chars.next();
                    out.push(char::from(v));
                }
                Some((_, c)) => out.push(c),
                None => break,
            },
            c => out.push(c),
        }
    }
    Err(format!(
        "unterminated {} literal: expected a closing {} on the same line",
        if q == b'"' { "string" } else { "character" },
        char::from(q)
    ))
}

/// A cursor over tokens, for recursive-descent parsers.
pub struct Cursor {
    toks: Vec<(Tok, Pos)>,
    i: usize,
}

impl Cursor {
    /// A cursor at the first of `toks` (which end with [`Tok::Eof`]).
    pub fn new(toks: Vec<(Tok, Pos)>) -> Self {
        Cursor { toks, i: 0 }
    }

    /// The current token.
    pub fn peek(&self) -> &Tok {
        &self.toks[self.i.min(self.toks.len() - 1)].0
    }

    /// The token after the current one.
    pub fn peek2(&self) -> &Tok {
        &self.toks[(self.i + 1).min(self.toks.len() - 1)].0
    }

    /// Where the current token is.
    pub fn pos(&self) -> Pos {
        self.toks[self.i.min(self.toks.len() - 1)].1.clone()
    }

    /// Takes the current token.
    pub fn next(&mut self) -> (Tok, Pos) {
        let t = self.toks[self.i.min(self.toks.len() - 1)].clone();
        if self.i < self.toks.len() - 1 {
            self.i += 1;
        }
        t
    }

    /// True (and takes it) if the current token is punctuation `p`.
    pub fn eat(&mut self, p: &str) -> bool {
        if matches!(self.peek(), Tok::Punct(q) if *q == p) {
            self.next();
            true
        } else {
            false
        }
    }

    /// True (and takes it) if the current token is the word `w`.
    pub fn eat_word(&mut self, w: &str) -> bool {
        if matches!(self.peek(), Tok::Ident(s) if s == w) {
            self.next();
            true
        } else {
            false
        }
    }

    /// True if the current token is punctuation `p`.
    pub fn at(&self, p: &str) -> bool {
        matches!(self.peek(), Tok::Punct(q) if *q == p)
    }

    /// A syntax error at the current token.
    pub fn error(&self, expected: &str) -> GenError {
        GenError::syntax(self.pos(), expected, self.peek().describe())
    }

    /// Takes punctuation `p`, or fails naming `p`.
    pub fn expect(&mut self, p: &str) -> Result<Pos, GenError> {
        let pos = self.pos();
        if self.eat(p) {
            Ok(pos)
        } else {
            Err(self.error(&format!("`{p}`")))
        }
    }

    /// Takes an identifier.
    pub fn ident(&mut self, what: &str) -> Result<(String, Pos), GenError> {
        match self.peek().clone() {
            Tok::Ident(s) => {
                let p = self.pos();
                self.next();
                Ok((s, p))
            }
            _ => Err(self.error(what)),
        }
    }

    /// `}` expected to close `what` opened at `opened`: an unterminated
    /// error at the end of the file, a syntax error elsewhere.
    pub fn close(&mut self, p: &str, what: &str, opened: &Pos) -> Result<(), GenError> {
        if self.eat(p) {
            return Ok(());
        }
        if *self.peek() == Tok::Eof {
            return Err(GenError::Unterminated {
                pos: self.pos(),
                what: what.to_string(),
                opened: opened.clone(),
                expected: format!("`{p}`"),
            });
        }
        Err(self.error(&format!("`{p}`")))
    }
}
