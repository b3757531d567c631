//! XDR files, as CMU IPC's `xdrgen` reads them (manual appendix B), to
//! Rust types.
//!
//! The language is xdrgen's: `typedef` declarations, `struct NAME { … };`
//! (fields may be anonymous `struct { … }` or `enum { … }`), `enum NAME {
//! … };`, `ipc_type NAME;` and `ipc_type NAME = "FORMAT";`, fixed arrays
//! `[n]` and variable arrays `<>` (one or more dimensions), strings
//! (`string s<>`, the last `<>` being the string's own), and `//`, `/* */`
//! comments. Types are as xdrgen maps them to IPC formats:
//!
//! | XDR | Rust | IPC |
//! |---|---|---|
//! | `int`, `unsigned int` | `i32`, `u32` | `int`, `uint` |
//! | `float`, `double` | `f32`, `f64` | `float`, `double` |
//! | `char` | `char` | `char` |
//! | `unsigned char`, `opaque` | `u8` | `ubyte` (xdrgen writes `uchar`, which IPC does not know) |
//! | `bool` | `#[ipc(char)] u8` | `char` (xdrgen's format for the one-byte C++ `bool`) |
//! | `string s<>` | `String` | `string` |
//! | `T a[n][m]` | `[[T; m]; n]` | `[T:n,m]` |
//! | `T a<>` | `Vec<T>`, counted by the field before it | `<T:k>` |
//! | `T a<><>` | `courier::Matrix<T>`, sized by the two fields before it | `<T:k1,k2>` |
//! | `T a<><><>` | `courier::NdVec<T, 3>`, sized by the three fields before it | `<T:k1,k2,k3>` |
//! | `enum { A, B }` | enum | `{enum A, B}` |
//! | `enum { A = 2, B }` | `i32` alias and constants | `int` |
//! | `ipc_type X;` | `X`, which the including code must provide | |
//! | `ipc_type X = "fmt";` | as the IPC format `fmt` | `fmt` |
//!
//! A variable array of n dimensions must follow the n `int` or `unsigned
//! int` fields that hold its dimensions, in order, as xdrgen requires. Not
//! supported: what xdrgen refuses (`union`, `const`, `hyper`, optional data
//! `*`). `%{ … %}` code sections hold C and are skipped.

use std::collections::HashMap;

use courier_wire::format;

use super::error::{GenError, Pos};
use super::lex::{self, Cursor, Tok};
use super::model::{
    self, AliasDef, ConstDef, EnumDef, FieldDef, Item, Module, Prim, StructDef, Ty, TypeRef,
};
use super::{ipc, names, Input};

/// An XDR type specifier.
#[derive(Debug, Clone)]
enum XType {
    Int,
    UInt,
    Float,
    Double,
    Bool,
    UChar,
    Char,
    String,
    Named(String, Pos),
    Struct(Vec<Decl>),
    Enum(Vec<Entry>),
}

/// An enum entry: name, value if given, position.
type Entry = (String, Option<i128>, Pos);

#[derive(Debug, Clone)]
enum Dims {
    None,
    /// `[n][m]`: the bounds.
    Fixed(Vec<u32>),
    /// `<>…<>`: the maxima (ignored, as by xdrgen).
    Var(Vec<Option<i128>>),
}

/// `TYPE NAME DIMS`.
#[derive(Debug, Clone)]
struct Decl {
    name: String,
    pos: Pos,
    ty: XType,
    dims: Dims,
    /// `string s<N>`: the string's own bound.
    string_bound: Option<i128>,
}

enum Def {
    Typedef(Decl),
    Struct(String, Pos, Vec<Decl>),
    Enum(String, Pos, Vec<Entry>),
    Ipc(String, Pos, Option<(String, Pos)>),
}

/// Translates the definitions of every input (one namespace).
pub fn translate(inputs: &[Input]) -> Result<Module, GenError> {
    let mut defs = Vec::new();
    for input in inputs {
        let toks = lex::lex(
            &input.path,
            &input.text,
            lex::Options {
                directives: true,
                code_sections: true,
            },
        )?;
        let mut p = Parser {
            c: Cursor::new(toks),
        };
        while *p.c.peek() != Tok::Eof {
            if let Some(d) = p.definition()? {
                defs.push((input, d));
            }
        }
    }
    let mut rust_names: HashMap<&str, String> = HashMap::new();
    let mut first: HashMap<&str, &Pos> = HashMap::new();
    for (_, d) in &defs {
        let (name, pos) = match d {
            Def::Typedef(decl) => (decl.name.as_str(), &decl.pos),
            Def::Struct(n, p, _) | Def::Enum(n, p, _) | Def::Ipc(n, p, _) => (n.as_str(), p),
        };
        if let Some(f) = first.get(name) {
            return Err(GenError::Duplicate {
                pos: pos.clone(),
                name: name.to_string(),
                first: (*f).clone(),
            });
        }
        first.insert(name, pos);
        rust_names.insert(name, names::type_name(name));
    }
    let mut top = Module::default();
    for (input, d) in &defs {
        let cx = Cx {
            rust_names: &rust_names,
            file: &input.name,
        };
        cx.definition(d, &mut top.items)?;
    }
    model::finish(top)
}

struct Parser {
    c: Cursor,
}

impl Parser {
    fn definition(&mut self) -> Result<Option<Def>, GenError> {
        let (tok, pos) = self.c.next();
        match tok {
            Tok::Code(_) => Ok(None),
            Tok::Directive(d) => Err(GenError::unsupported(
                pos,
                format!("the directive `#{}`", d.trim()),
                "courier gen does not run the C preprocessor; remove it or run the file through cpp first",
            )),
            Tok::Ident(w) if w == "typedef" => {
                let d = self.decl()?;
                self.c.expect(";")?;
                Ok(Some(Def::Typedef(d)))
            }
            Tok::Ident(w) if w == "struct" => {
                let (name, pos) = self.c.ident("a struct name")?;
                let fields = self.struct_body(&format!("struct `{name}`"))?;
                self.c.expect(";")?;
                Ok(Some(Def::Struct(name, pos, fields)))
            }
            Tok::Ident(w) if w == "enum" => {
                let (name, pos) = self.c.ident("an enum name")?;
                let entries = self.enum_body(&format!("enum `{name}`"))?;
                self.c.expect(";")?;
                Ok(Some(Def::Enum(name, pos, entries)))
            }
            Tok::Ident(w) if w == "ipc_type" => {
                let (name, pos) = self.c.ident("a type name")?;
                let format = if self.c.eat("=") {
                    let p = self.c.pos();
                    match self.c.next().0 {
                        Tok::Str(s) => Some((s, p)),
                        other => {
                            return Err(GenError::syntax(
                                p,
                                "an IPC format string in quotes",
                                other.describe(),
                            ))
                        }
                    }
                } else {
                    None
                };
                self.c.expect(";")?;
                Ok(Some(Def::Ipc(name, pos, format)))
            }
            Tok::Ident(w) => {
                unsupported_word(&w, &pos)?;
                Err(GenError::syntax(
                    pos,
                    "`typedef`, `struct`, `enum`, `ipc_type` or `%{`",
                    format!("`{w}`"),
                ))
            }
            other => Err(GenError::syntax(
                pos,
                "`typedef`, `struct`, `enum`, `ipc_type` or `%{`",
                other.describe(),
            )),
        }
    }

    fn struct_body(&mut self, what: &str) -> Result<Vec<Decl>, GenError> {
        let open = self.c.expect("{")?;
        let mut fields = Vec::new();
        if self.c.eat_word("void") {
            self.c.expect(";")?;
        } else {
            while !matches!(self.c.peek(), Tok::Punct("}") | Tok::Eof | Tok::Code(_)) {
                fields.push(self.decl()?);
                self.c.expect(";")?;
            }
        }
        if matches!(self.c.peek(), Tok::Code(_)) {
            self.c.next();
        }
        self.c.close("}", what, &open)?;
        Ok(fields)
    }

    fn enum_body(&mut self, what: &str) -> Result<Vec<Entry>, GenError> {
        let open = self.c.expect("{")?;
        let mut entries = Vec::new();
        loop {
            if *self.c.peek() == Tok::Eof {
                self.c.close("}", what, &open)?;
            }
            let (name, pos) = self.c.ident("an enum identifier")?;
            let value = if self.c.eat("=") {
                Some(self.int()?.0)
            } else {
                None
            };
            entries.push((name, value, pos));
            if !self.c.eat(",") {
                break;
            }
        }
        self.c.close("}", what, &open)?;
        Ok(entries)
    }

    fn int(&mut self) -> Result<(i128, Pos), GenError> {
        let pos = self.c.pos();
        let neg = self.c.eat("-");
        match self.c.peek().clone() {
            Tok::Int(n) => {
                self.c.next();
                Ok((if neg { -n } else { n }, pos))
            }
            Tok::Ident(w) => Err(GenError::unsupported(
                pos,
                format!("the constant name `{w}` as a value"),
                "xdrgen takes only integer literals here (it has no `const`)",
            )),
            other => Err(GenError::syntax(pos, "an integer", other.describe())),
        }
    }

    fn type_spec(&mut self) -> Result<XType, GenError> {
        let (tok, pos) = self.c.next();
        let w = match tok {
            Tok::Ident(w) => w,
            Tok::Punct("*") => {
                return Err(GenError::unsupported(
                    pos,
                    "optional data (`*`)",
                    "xdrgen does not implement it; use a variable-length array `<>`",
                ))
            }
            other => return Err(GenError::syntax(pos, "a type", other.describe())),
        };
        Ok(match w.as_str() {
            "int" => XType::Int,
            "float" => XType::Float,
            "double" => XType::Double,
            "bool" => XType::Bool,
            "char" => XType::Char,
            "opaque" => XType::UChar,
            "string" => XType::String,
            "unsigned" => {
                if self.c.eat_word("int") {
                    XType::UInt
                } else if self.c.eat_word("char") {
                    XType::UChar
                } else {
                    return Err(self.c.error("`int` or `char` after `unsigned`"));
                }
            }
            "struct" => XType::Struct(self.struct_body("anonymous struct")?),
            "enum" => XType::Enum(self.enum_body("anonymous enum")?),
            _ => {
                unsupported_word(&w, &pos)?;
                XType::Named(w, pos)
            }
        })
    }

    fn decl(&mut self) -> Result<Decl, GenError> {
        let ty = self.type_spec()?;
        let (name, pos) = self.c.ident("a field or type name")?;
        let mut dims = Dims::None;
        if self.c.at("[") {
            let mut fixed = Vec::new();
            while self.c.eat("[") {
                let (n, p) = self.int()?;
                match u32::try_from(n) {
                    Ok(v) if v > 0 && i32::try_from(v).is_ok() => fixed.push(v),
                    _ => {
                        return Err(GenError::BadBound {
                            pos: p,
                            found: n.to_string(),
                            why: "a fixed-length array needs a length from 1 to 2147483647".into(),
                        })
                    }
                }
                self.c.expect("]")?;
            }
            dims = Dims::Fixed(fixed);
        }
        let mut var = Vec::new();
        while self.c.at("<") {
            self.c.next();
            let max = if self.c.at(">") {
                None
            } else {
                Some(self.int()?.0)
            };
            self.c.expect(">")?;
            var.push(max);
        }
        let mut string_bound = None;
        if matches!(ty, XType::String) {
            // the last <> is the string's own
            match var.pop() {
                Some(b) => string_bound = b,
                None => {
                    return Err(self
                        .c
                        .error("`<>` after a string (strings are variable-length in XDR)"))
                }
            }
        }
        if !var.is_empty() {
            if let Dims::Fixed(_) = dims {
                return Err(GenError::unsupported(
                    pos,
                    format!("mixing fixed and variable dimensions in `{name}`"),
                    "xdrgen forbids it; make the element a struct: `struct { T data[5]; } x<>;`",
                ));
            }
            dims = Dims::Var(var);
        }
        Ok(Decl {
            name,
            pos,
            ty,
            dims,
            string_bound,
        })
    }
}

/// XDR words xdrgen reserves but does not implement.
fn unsupported_word(w: &str, pos: &Pos) -> Result<(), GenError> {
    let hint = match w {
        "union" | "switch" | "case" | "default" => {
            "xdrgen does not implement unions (IPC has no union type); use a struct with an enum tag"
        }
        "const" => "xdrgen does not implement `const`; write the number",
        "hyper" => "xdrgen does not implement 8-byte integers; use `int` or `double`",
        "short" | "long" => "xdrgen has no `short` or `long` type; use `int`",
        _ => return Ok(()),
    };
    Err(GenError::unsupported(
        pos.clone(),
        format!("XDR `{w}`"),
        hint,
    ))
}

struct Cx<'a> {
    rust_names: &'a HashMap<&'a str, String>,
    file: &'a str,
}

impl Cx<'_> {
    fn source(&self, pos: &Pos) -> String {
        format!("{}:{}", self.file, pos.line)
    }

    fn definition(&self, d: &Def, out: &mut Vec<Item>) -> Result<(), GenError> {
        match d {
            Def::Struct(name, pos, fields) => {
                let doc = vec![format!("XDR struct `{name}` ({}).", self.source(pos))];
                self.structure(name, pos, doc, fields, out)
            }
            Def::Enum(name, pos, entries) => {
                let doc = vec![format!("XDR enum `{name}` ({}).", self.source(pos))];
                self.enumeration(
                    &self.rust_names[name.as_str()],
                    name,
                    pos,
                    doc,
                    entries,
                    out,
                );
                Ok(())
            }
            Def::Typedef(decl) => {
                let name = &decl.name;
                let doc = vec![format!(
                    "XDR typedef `{name}` ({}).",
                    self.source(&decl.pos)
                )];
                match (&decl.ty, &decl.dims) {
                    (XType::Struct(fields), Dims::None) => {
                        self.structure(name, &decl.pos, doc, fields, out)
                    }
                    (XType::Enum(entries), Dims::None) => {
                        self.enumeration(
                            &self.rust_names[name.as_str()],
                            name,
                            &decl.pos,
                            doc,
                            entries,
                            out,
                        );
                        Ok(())
                    }
                    (_, Dims::Var(_)) => Err(GenError::invalid(
                        decl.pos.clone(),
                        format!(
                            "variable-length array `{name}` declared outside a struct (IPC takes \
                             its length from a field of the enclosing struct)"
                        ),
                    )),
                    _ => {
                        let rust = self.rust_names[name.as_str()].clone();
                        let mut extra = Vec::new();
                        let ty = self.field_ty(decl, &format!("{rust}Item"), &mut extra)?;
                        out.push(Item::Alias(AliasDef {
                            name: rust,
                            pos: decl.pos.clone(),
                            doc,
                            ty,
                        }));
                        out.append(&mut extra);
                        Ok(())
                    }
                }
            }
            Def::Ipc(name, pos, None) => {
                let _ = (name, pos);
                // provided by the code that includes the output
                Ok(())
            }
            Def::Ipc(name, pos, Some((text, fpos))) => {
                let f = format::parse(text).map_err(|e| GenError::Format {
                    pos: fpos.clone(),
                    message: e.to_string(),
                })?;
                let source = format!("{} `ipc_type`", self.source(pos));
                out.extend(ipc::items(name, &f, pos, &source, self.rust_names)?);
                Ok(())
            }
        }
    }

    fn structure(
        &self,
        name: &str,
        pos: &Pos,
        doc: Vec<String>,
        fields: &[Decl],
        out: &mut Vec<Item>,
    ) -> Result<(), GenError> {
        let rust = self
            .rust_names
            .get(name)
            .cloned()
            .unwrap_or_else(|| name.to_string());
        let mut extra = Vec::new();
        let mut fds: Vec<FieldDef> = Vec::new();
        let mut seen: HashMap<&str, &Pos> = HashMap::new();
        for (i, f) in fields.iter().enumerate() {
            if let Some(first) = seen.get(f.name.as_str()) {
                return Err(GenError::Duplicate {
                    pos: f.pos.clone(),
                    name: f.name.clone(),
                    first: (*first).clone(),
                });
            }
            seen.insert(&f.name, &f.pos);
            let inner = format!("{rust}{}", names::type_name(&f.name));
            let ty = self.field_ty(f, &inner, &mut extra)?;
            let mut fd = FieldDef::new(names::field_name(&f.name), f.pos.clone(), ty);
            if fd.name.trim_start_matches("r#") != f.name {
                fd.doc.push(format!("`{}` in the XDR file.", f.name));
            }
            if let Some(max) = f.string_bound {
                match (u32::try_from(max), &f.dims) {
                    (Ok(n), Dims::None) if (1..=0x7fff_ffff).contains(&n) => fd.bound = Some(n),
                    _ => fd
                        .doc
                        .push(format!("Strings of at most {max} bytes (not checked).")),
                }
            }
            if let Dims::Var(v) = &f.dims {
                // xdrgen: an array of n dimensions is sized by the n fields
                // before it, in order, each an int or unsigned int
                let sizes = i.checked_sub(v.len()).map(|j| &fields[j..i]).filter(|cs| {
                    cs.iter()
                        .all(|c| matches!((&c.ty, &c.dims), (XType::Int | XType::UInt, Dims::None)))
                });
                let Some(sizes) = sizes else {
                    return Err(GenError::invalid(
                        f.pos.clone(),
                        if v.len() == 1 {
                            format!(
                                "variable-length array `{}` is not preceded by the int or unsigned \
                                 int field that holds its length",
                                f.name
                            )
                        } else {
                            format!(
                                "{}-dimensional variable-length array `{}` is not preceded by the \
                                 {} int or unsigned int fields that hold its dimensions",
                                v.len(),
                                f.name,
                                v.len()
                            )
                        },
                    ));
                };
                let names: Vec<String> = sizes.iter().map(|c| names::field_name(&c.name)).collect();
                fd.len = Some(names.join(", "));
                // `T x<N>`: a one-dimensional array's bound is the field's
                if let [Some(max)] = v.as_slice() {
                    // XDR bounds fit a u32; the derive takes up to i32::MAX
                    match u32::try_from(*max) {
                        Ok(n) if (1..=0x7fff_ffff).contains(&n) => fd.bound = Some(n),
                        _ => fd
                            .doc
                            .push(format!("At most {max} elements (not checked).")),
                    }
                } else if let Some(Some(max)) = v.first() {
                    fd.doc.push(format!(
                        "At most {max} elements in its first dimension (not checked)."
                    ));
                }
            }
            fds.push(fd);
        }
        out.push(Item::Struct(StructDef {
            format_name: (rust != name).then(|| name.to_string()),
            // the same in every module that includes the generated file
            type_name: Some(name.to_string()),
            name: rust,
            pos: pos.clone(),
            doc,
            extensibility: None,
            tuple: false,
            fields: fds,
        }));
        out.append(&mut extra);
        Ok(())
    }

    /// An enum: a Rust enum if no entry has a value, else an `i32` alias
    /// and a constant for each entry (IPC format `int`, as xdrgen).
    /// `type_name` is the enum's DDS type name: its name in the XDR file.
    fn enumeration(
        &self,
        rust: &str,
        type_name: &str,
        pos: &Pos,
        mut doc: Vec<String>,
        entries: &[Entry],
        out: &mut Vec<Item>,
    ) {
        if entries.iter().all(|e| e.1.is_none()) {
            out.push(Item::Enum(EnumDef {
                name: rust.to_string(),
                pos: pos.clone(),
                doc,
                type_name: Some(type_name.to_string()),
                numeric: false,
                variants: entries
                    .iter()
                    .map(|(n, _, _)| (names::verbatim(n), None, Vec::new()))
                    .collect(),
            }));
            return;
        }
        doc.push("Its entries have values, so IPC sees an `int` (as xdrgen writes it).".into());
        out.push(Item::Alias(AliasDef {
            name: rust.to_string(),
            pos: pos.clone(),
            doc,
            ty: Ty::Prim(Prim::I32),
        }));
        let mut next: i128 = 0;
        for (n, v, p) in entries {
            let value = v.unwrap_or(next);
            next = value + 1;
            out.push(Item::Const(ConstDef {
                name: names::verbatim(n),
                pos: p.clone(),
                doc: vec![format!("`{n}` of `{rust}`.")],
                ty: rust.to_string(),
                value: value.to_string(),
            }));
        }
    }

    /// The Rust type of a declaration with its dimensions; an anonymous
    /// struct or enum becomes the type `inner`.
    fn field_ty(&self, d: &Decl, inner: &str, extra: &mut Vec<Item>) -> Result<Ty, GenError> {
        let elem = match &d.ty {
            XType::Int => Ty::Prim(Prim::I32),
            XType::UInt => Ty::Prim(Prim::U32),
            XType::Float => Ty::Prim(Prim::F32),
            XType::Double => Ty::Prim(Prim::F64),
            XType::Bool => Ty::Prim(Prim::CharByte),
            XType::UChar => Ty::Prim(Prim::U8),
            XType::Char => Ty::Prim(Prim::Char),
            XType::String => Ty::Prim(Prim::String),
            XType::Named(n, p) => match self.rust_names.get(n.as_str()) {
                Some(r) => Ty::Named(TypeRef {
                    module: Vec::new(),
                    name: r.clone(),
                }),
                None => {
                    return Err(GenError::UnknownType {
                        pos: p.clone(),
                        name: n.clone(),
                    })
                }
            },
            XType::Struct(fields) => {
                let doc = vec![format!("Field `{}` ({}).", d.name, self.source(&d.pos))];
                self.structure(inner, &d.pos, doc, fields, extra)?;
                Ty::Named(TypeRef {
                    module: Vec::new(),
                    name: inner.to_string(),
                })
            }
            XType::Enum(entries) => {
                let doc = vec![format!("Field `{}` ({}).", d.name, self.source(&d.pos))];
                self.enumeration(inner, inner, &d.pos, doc, entries, extra);
                Ty::Named(TypeRef {
                    module: Vec::new(),
                    name: inner.to_string(),
                })
            }
        };
        Ok(match &d.dims {
            Dims::None => elem,
            Dims::Fixed(ns) => ns
                .iter()
                .rev()
                .fold(elem, |t, n| Ty::Array(Box::new(t), *n)),
            Dims::Var(v) if v.len() == 1 => Ty::Vec(Box::new(elem)),
            Dims::Var(v) => Ty::NdVec(Box::new(elem), v.len()),
        })
    }
}
