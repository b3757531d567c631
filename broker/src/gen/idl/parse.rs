//! The IDL syntax tree and its parser (the OMG IDL 4 subset ROS 2 and
//! Cyclone DDS use), on the tokens of `gen::lex`.

use crate::gen::error::{GenError, Pos};
use crate::gen::lex::{Cursor, Tok};
use crate::gen::model::Prim;

/// A definition at module level.
#[derive(Debug, Clone)]
pub enum Def {
    /// `module NAME { … };`
    Module(String, Pos, Vec<Def>),
    /// `struct NAME { … };`
    Struct(StructAst),
    /// `struct NAME;`
    Forward(String, Pos),
    /// `enum NAME { … };`
    Enum(EnumAst),
    /// `typedef TYPE a, b[3];`
    Typedef(TypeAst, Vec<Declarator>),
    /// `const TYPE NAME = EXPR;`
    Const(Vec<Ann>, TypeAst, String, Pos, Expr),
    /// `#include "NAME"` or `<NAME>`.
    Include(String, Pos),
}

/// An annotation `@name(params)`.
#[derive(Debug, Clone)]
pub struct Ann {
    /// Its name (last component of a scoped name).
    pub name: String,
    /// Where.
    pub pos: Pos,
    /// Parameters: `name = value`, or one unnamed value.
    pub params: Vec<(Option<String>, Expr)>,
}

/// A struct definition.
#[derive(Debug, Clone)]
pub struct StructAst {
    /// Annotations before it.
    pub anns: Vec<Ann>,
    /// Its name.
    pub name: String,
    /// Where.
    pub pos: Pos,
    /// Members.
    pub members: Vec<Member>,
}

/// `TYPE a, b[2];` in a struct.
#[derive(Debug, Clone)]
pub struct Member {
    /// Annotations before it.
    pub anns: Vec<Ann>,
    /// The type.
    pub ty: TypeAst,
    /// Names with their array dimensions.
    pub decls: Vec<Declarator>,
}

/// A name with array dimensions.
#[derive(Debug, Clone)]
pub struct Declarator {
    /// The name.
    pub name: String,
    /// Where.
    pub pos: Pos,
    /// `[n]` bounds.
    pub dims: Vec<Expr>,
}

/// An enum definition.
#[derive(Debug, Clone)]
pub struct EnumAst {
    /// Annotations before it.
    pub anns: Vec<Ann>,
    /// Its name.
    pub name: String,
    /// Where.
    pub pos: Pos,
    /// Enumerators with their annotations.
    pub literals: Vec<(String, Pos, Vec<Ann>)>,
}

/// A type specifier.
#[derive(Debug, Clone)]
pub enum TypeAst {
    /// A primitive.
    Prim(Prim),
    /// `string` or `string<N>`.
    String(Option<Expr>),
    /// `sequence<T>` or `sequence<T, N>`.
    Sequence(Box<TypeAst>, Option<Expr>, Pos),
    /// A scoped name (`a::b::C`, `::a::C`).
    Named(Vec<String>, bool, Pos),
}

/// A constant expression.
#[derive(Debug, Clone)]
pub enum Expr {
    /// Integer literal.
    Int(i128, Pos),
    /// Floating-point literal, as written.
    Float(String, Pos),
    /// String literal (adjacent literals joined).
    Str(String, Pos),
    /// Character literal.
    Char(char, Pos),
    /// `TRUE` / `FALSE`.
    Bool(bool, Pos),
    /// A constant's scoped name.
    Name(Vec<String>, bool, Pos),
    /// `-x`, `+x`, `~x`.
    Unary(&'static str, Box<Expr>, Pos),
    /// `a op b`.
    Binary(&'static str, Box<Expr>, Box<Expr>, Pos),
}

impl Expr {
    /// Where the expression starts.
    pub fn pos(&self) -> &Pos {
        match self {
            Expr::Int(_, p)
            | Expr::Float(_, p)
            | Expr::Str(_, p)
            | Expr::Char(_, p)
            | Expr::Bool(_, p)
            | Expr::Name(_, _, p)
            | Expr::Unary(_, _, p)
            | Expr::Binary(_, _, _, p) => p,
        }
    }
}

/// IDL constructs this generator does not translate, and what to use.
fn unsupported_hint(word: &str) -> Option<&'static str> {
    Some(match word {
        "union" => "#[derive(IpcMessage)] has no unions; use a struct with an enum discriminator and @optional members",
        "wchar" | "wstring" => "wide characters have no IPC or Courier type; use `char` / `string` (UTF-8)",
        "any" | "Object" | "ValueBase" => "dynamic types cannot be generated; use a concrete type",
        "fixed" => "fixed-point numbers have no Courier type; use `double` or an integer",
        "map" => "maps have no Courier type; use a sequence of key/value structs",
        "bitset" | "bitmask" => "bit types have no Courier type; use an unsigned integer",
        "interface" | "valuetype" | "exception" | "native" | "component" | "home" | "eventtype"
        | "abstract" | "local" | "custom" => "only data types (struct, enum, typedef, const) are generated",
        _ => return None,
    })
}

/// The parser.
pub struct Parser {
    c: Cursor,
}

impl Parser {
    /// A parser over `toks`.
    pub fn new(c: Cursor) -> Self {
        Parser { c }
    }

    /// Every definition up to the end of the file.
    pub fn file(&mut self) -> Result<Vec<Def>, GenError> {
        let mut defs = Vec::new();
        while *self.c.peek() != Tok::Eof {
            self.definition(&mut defs)?;
        }
        Ok(defs)
    }

    fn definition(&mut self, out: &mut Vec<Def>) -> Result<(), GenError> {
        if let Tok::Directive(d) = self.c.peek().clone() {
            let pos = self.c.pos();
            self.c.next();
            return directive(&d, pos, out);
        }
        let anns = self.annotations()?;
        let (tok, pos) = self.c.next();
        let Tok::Ident(w) = tok else {
            return Err(GenError::syntax(
                pos,
                "`module`, `struct`, `enum`, `typedef` or `const`",
                tok.describe(),
            ));
        };
        match w.as_str() {
            "module" => {
                let (name, npos) = self.c.ident("a module name")?;
                let open = self.c.expect("{")?;
                let mut defs = Vec::new();
                while !self.c.at("}") && *self.c.peek() != Tok::Eof {
                    self.definition(&mut defs)?;
                }
                self.c.close("}", &format!("module `{name}`"), &open)?;
                self.c.expect(";")?;
                out.push(Def::Module(name, npos, defs));
            }
            "struct" => {
                let (name, npos) = self.c.ident("a struct name")?;
                if self.c.at(":") {
                    return Err(GenError::unsupported(
                        self.c.pos(),
                        format!("struct inheritance (`{name} : …`)"),
                        "#[derive(IpcMessage)] has no inheritance; make the base a first member",
                    ));
                }
                if self.c.eat(";") {
                    out.push(Def::Forward(name, npos));
                    return Ok(());
                }
                let open = self.c.expect("{")?;
                let mut members = Vec::new();
                while !self.c.at("}") && *self.c.peek() != Tok::Eof {
                    members.push(self.member()?);
                }
                self.c.close("}", &format!("struct `{name}`"), &open)?;
                self.c.expect(";")?;
                out.push(Def::Struct(StructAst {
                    anns,
                    name,
                    pos: npos,
                    members,
                }));
            }
            "enum" => {
                let (name, npos) = self.c.ident("an enum name")?;
                let open = self.c.expect("{")?;
                let mut literals = Vec::new();
                loop {
                    if *self.c.peek() == Tok::Eof {
                        self.c.close("}", &format!("enum `{name}`"), &open)?;
                    }
                    let a = self.annotations()?;
                    let (l, lpos) = self.c.ident("an enumerator")?;
                    literals.push((l, lpos, a));
                    if !self.c.eat(",") {
                        break;
                    }
                }
                self.c.close("}", &format!("enum `{name}`"), &open)?;
                self.c.expect(";")?;
                out.push(Def::Enum(EnumAst {
                    anns,
                    name,
                    pos: npos,
                    literals,
                }));
            }
            "typedef" => {
                let ty = self.type_spec()?;
                let decls = self.declarators()?;
                self.c.expect(";")?;
                out.push(Def::Typedef(ty, decls));
            }
            "const" => {
                let ty = self.type_spec()?;
                let (name, npos) = self.c.ident("a constant name")?;
                self.c.expect("=")?;
                let value = self.expr()?;
                self.c.expect(";")?;
                out.push(Def::Const(anns, ty, name, npos, value));
            }
            other => {
                if let Some(hint) = unsupported_hint(other) {
                    return Err(GenError::unsupported(pos, format!("IDL `{other}`"), hint));
                }
                return Err(GenError::syntax(
                    pos,
                    "`module`, `struct`, `enum`, `typedef` or `const`",
                    format!("`{other}`"),
                ));
            }
        }
        Ok(())
    }

    fn member(&mut self) -> Result<Member, GenError> {
        let anns = self.annotations()?;
        let ty = self.type_spec()?;
        let decls = self.declarators()?;
        self.c.expect(";")?;
        Ok(Member { anns, ty, decls })
    }

    fn declarators(&mut self) -> Result<Vec<Declarator>, GenError> {
        let mut out = Vec::new();
        loop {
            let (name, pos) = self.c.ident("a name")?;
            let mut dims = Vec::new();
            while self.c.eat("[") {
                dims.push(self.expr()?);
                self.c.expect("]")?;
            }
            out.push(Declarator { name, pos, dims });
            if !self.c.eat(",") {
                return Ok(out);
            }
        }
    }

    fn annotations(&mut self) -> Result<Vec<Ann>, GenError> {
        let mut out = Vec::new();
        while self.c.at("@") {
            let pos = self.c.pos();
            self.c.next();
            let (mut name, _) = self.c.ident("an annotation name")?;
            while self.c.eat("::") {
                name = self.c.ident("an annotation name")?.0;
            }
            let mut params = Vec::new();
            if self.c.at("(") {
                let open = self.c.expect("(")?;
                while !self.c.at(")") && *self.c.peek() != Tok::Eof {
                    let named = matches!(self.c.peek(), Tok::Ident(_))
                        && matches!(self.c.peek2(), Tok::Punct("="));
                    let key = if named {
                        let k = self.c.ident("a parameter name")?.0;
                        self.c.expect("=")?;
                        Some(k)
                    } else {
                        None
                    };
                    params.push((key, self.expr()?));
                    if !self.c.eat(",") {
                        break;
                    }
                }
                self.c.close(")", &format!("annotation `@{name}`"), &open)?;
            }
            out.push(Ann { name, pos, params });
        }
        Ok(out)
    }

    fn type_spec(&mut self) -> Result<TypeAst, GenError> {
        let pos = self.c.pos();
        let absolute = self.c.eat("::");
        let (w, _) = self.c.ident("a type")?;
        if absolute {
            return self.scoped(vec![w], true, pos);
        }
        let prim = |p| Ok(TypeAst::Prim(p));
        match w.as_str() {
            "short" | "int16" => prim(Prim::I16),
            "long" => {
                if self.c.eat_word("long") {
                    prim(Prim::I64)
                } else if matches!(self.c.peek(), Tok::Ident(d) if d == "double") {
                    Err(GenError::unsupported(
                        pos,
                        "`long double`",
                        "Rust has no 128-bit float; use `double`",
                    ))
                } else {
                    prim(Prim::I32)
                }
            }
            "unsigned" => {
                if self.c.eat_word("short") {
                    prim(Prim::U16)
                } else if self.c.eat_word("long") {
                    if self.c.eat_word("long") {
                        prim(Prim::U64)
                    } else {
                        prim(Prim::U32)
                    }
                } else {
                    Err(self.c.error("`short` or `long` after `unsigned`"))
                }
            }
            "int8" => prim(Prim::I8),
            "uint8" | "octet" => prim(Prim::U8),
            "uint16" => prim(Prim::U16),
            "int32" => prim(Prim::I32),
            "uint32" => prim(Prim::U32),
            "int64" => prim(Prim::I64),
            "uint64" => prim(Prim::U64),
            "float" => prim(Prim::F32),
            "double" => prim(Prim::F64),
            "boolean" => prim(Prim::Bool),
            "char" => prim(Prim::Char),
            "string" => {
                let bound = if self.c.eat("<") {
                    let e = self.expr_no_gt()?;
                    self.c.expect(">")?;
                    Some(e)
                } else {
                    None
                };
                Ok(TypeAst::String(bound))
            }
            "sequence" => {
                self.c.expect("<")?;
                let elem = self.type_spec()?;
                let bound = if self.c.eat(",") {
                    Some(self.expr_no_gt()?)
                } else {
                    None
                };
                if self.c.at(">>") {
                    return Err(GenError::unsupported(
                        self.c.pos(),
                        "a sequence of sequences",
                        "#[derive(IpcMessage)] takes a Vec only as a direct field; wrap the inner \
                         sequence in a struct",
                    ));
                }
                self.c.expect(">")?;
                Ok(TypeAst::Sequence(Box::new(elem), bound, pos))
            }
            other => {
                if let Some(hint) = unsupported_hint(other) {
                    return Err(GenError::unsupported(pos, format!("IDL `{other}`"), hint));
                }
                self.scoped(vec![w], false, pos)
            }
        }
    }

    fn scoped(
        &mut self,
        mut path: Vec<String>,
        absolute: bool,
        pos: Pos,
    ) -> Result<TypeAst, GenError> {
        while self.c.eat("::") {
            path.push(self.c.ident("a name after `::`")?.0);
        }
        Ok(TypeAst::Named(path, absolute, pos))
    }

    /// An expression inside `<…>`, where `>` closes (no shifts or
    /// comparisons at the top).
    fn expr_no_gt(&mut self) -> Result<Expr, GenError> {
        self.additive()
    }

    /// A constant expression (IDL 4 §7.4.1.4.3, without comparison).
    pub fn expr(&mut self) -> Result<Expr, GenError> {
        self.binary(0)
    }

    fn binary(&mut self, level: usize) -> Result<Expr, GenError> {
        const LEVELS: &[&[&str]] = &[&["|"], &["^"], &["&"], &["<<", ">>"]];
        if level == LEVELS.len() {
            return self.additive();
        }
        let mut lhs = self.binary(level + 1)?;
        loop {
            let Some(op) = LEVELS[level].iter().copied().find(|op| self.c.at(op)) else {
                return Ok(lhs);
            };
            let pos = self.c.pos();
            self.c.next();
            let rhs = self.binary(level + 1)?;
            lhs = Expr::Binary(op, Box::new(lhs), Box::new(rhs), pos);
        }
    }

    fn additive(&mut self) -> Result<Expr, GenError> {
        let mut lhs = self.multiplicative()?;
        loop {
            let Some(op) = ["+", "-"].into_iter().find(|op| self.c.at(op)) else {
                return Ok(lhs);
            };
            let pos = self.c.pos();
            self.c.next();
            let rhs = self.multiplicative()?;
            lhs = Expr::Binary(op, Box::new(lhs), Box::new(rhs), pos);
        }
    }

    fn multiplicative(&mut self) -> Result<Expr, GenError> {
        let mut lhs = self.unary()?;
        loop {
            let Some(op) = ["*", "/", "%"].into_iter().find(|op| self.c.at(op)) else {
                return Ok(lhs);
            };
            let pos = self.c.pos();
            self.c.next();
            let rhs = self.unary()?;
            lhs = Expr::Binary(op, Box::new(lhs), Box::new(rhs), pos);
        }
    }

    fn unary(&mut self) -> Result<Expr, GenError> {
        let pos = self.c.pos();
        for op in ["-", "+", "~"] {
            if self.c.eat(op) {
                return Ok(Expr::Unary(op, Box::new(self.unary()?), pos));
            }
        }
        self.primary()
    }

    fn primary(&mut self) -> Result<Expr, GenError> {
        let pos = self.c.pos();
        let absolute = self.c.eat("::");
        let (tok, _) = self.c.next();
        Ok(match tok {
            Tok::Int(n) => Expr::Int(n, pos),
            Tok::Float(f) => Expr::Float(f, pos),
            Tok::Char(c) => Expr::Char(c, pos),
            Tok::Str(mut s) => {
                // adjacent string literals are one
                while let Tok::Str(more) = self.c.peek().clone() {
                    self.c.next();
                    s.push_str(&more);
                }
                Expr::Str(s, pos)
            }
            Tok::Ident(w) if w == "TRUE" && !absolute => Expr::Bool(true, pos),
            Tok::Ident(w) if w == "FALSE" && !absolute => Expr::Bool(false, pos),
            Tok::Ident(w) => {
                let mut path = vec![w];
                while self.c.eat("::") {
                    path.push(self.c.ident("a name after `::`")?.0);
                }
                Expr::Name(path, absolute, pos)
            }
            Tok::Punct("(") => {
                let e = self.expr()?;
                self.c.expect(")")?;
                e
            }
            other => {
                return Err(GenError::syntax(
                    pos,
                    "a constant expression",
                    other.describe(),
                ))
            }
        })
    }
}

/// `#include` becomes a definition; `#pragma` is skipped; other
/// preprocessor directives are refused.
fn directive(d: &str, pos: Pos, out: &mut Vec<Def>) -> Result<(), GenError> {
    let d = d.trim();
    let (word, rest) = d.split_once(char::is_whitespace).unwrap_or((d, ""));
    match word {
        "include" => {
            let rest = rest.trim();
            let name = rest
                .strip_prefix('"')
                .and_then(|r| r.strip_suffix('"'))
                .or_else(|| rest.strip_prefix('<').and_then(|r| r.strip_suffix('>')));
            match name {
                Some(n) if !n.is_empty() => {
                    out.push(Def::Include(n.to_string(), pos));
                    Ok(())
                }
                _ => Err(GenError::syntax(
                    pos,
                    "`#include \"FILE\"` or `#include <FILE>`",
                    format!("`#{d}`"),
                )),
            }
        }
        "pragma" => Ok(()),
        _ => Err(GenError::unsupported(
            pos,
            format!("the directive `#{word}`"),
            "courier gen reads `#include` and skips `#pragma`; run other preprocessor \
             directives through cpp first",
        )),
    }
}
