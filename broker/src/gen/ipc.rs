//! IPC format strings (manual §3) to Rust types.
//!
//! The input is a list of named formats, one `NAME = FORMAT` a line (a
//! format may go on over several lines while a bracket is open); `#`
//! starts a comment. Each name is what `IPC_defineFormat` or
//! `IPC_defineMsg` would be given, and other formats may use it:
//!
//! ```text
//! # the manual's module1/module2 types
//! T1 = {int, {enum : 3}, [double:2,3], double}
//! T2 = {string, int, <T1:2>, {enum WaitVal, SendVal, ReceiveVal, ListenVal}}
//! ```
//!
//! Formats are parsed by [`courier_wire::format`]. A struct becomes a tuple
//! struct (formats name no fields) whose IPC format name is the definition's
//! name; a struct, enum or pointer target written inline becomes a type
//! named after its place (`T2Field4`); any other format becomes a type
//! alias. Variable arrays take their count from the field the format
//! names (`Vec<T>`), or their shape from the fields it names
//! (`<T:k1,k2>`: `courier::Matrix<T>`, `courier::NdVec<T, N>` for more
//! dimensions); `*!` is `Option<Box<Self>>`.

use std::collections::HashMap;

use courier_wire::format::{self, Format, FormatRegistry, ParseError, Primitive};

use super::error::{GenError, Pos};
use super::model::{self, AliasDef, EnumDef, FieldDef, Item, Module, Prim, StructDef, Ty, TypeRef};
use super::{names, Input};

/// Largest `{enum : max}` written out as variants.
pub const MAX_ENUM: i32 = 1024;

/// One `NAME = FORMAT` definition.
struct Def<'a> {
    name: &'a str,
    name_pos: Pos,
    /// The format text, with comments blanked out (same length).
    text: String,
    /// Byte offset of `text` in the file.
    offset: usize,
    input: &'a Input,
    format: Format,
}

/// Translates the definitions of every input (they share one namespace).
pub fn translate(inputs: &[Input]) -> Result<Module, GenError> {
    let mut defs = Vec::new();
    for input in inputs {
        defs.extend(definitions(input)?);
    }
    let mut seen: HashMap<&str, &Pos> = HashMap::new();
    let mut registry = FormatRegistry::new();
    for d in &defs {
        if let Some(first) = seen.get(d.name) {
            return Err(GenError::Duplicate {
                pos: d.name_pos.clone(),
                name: d.name.to_string(),
                first: (*first).clone(),
            });
        }
        seen.insert(d.name, &d.name_pos);
        if !matches!(d.format, Format::Empty) {
            registry
                .insert(d.name, d.format.clone())
                .map_err(|e| GenError::invalid(d.name_pos.clone(), e.to_string()))?;
        }
    }
    // unknown names, and what only the expansion shows (a count field
    // whose named type is no integer), with the position of the offender
    for d in &defs {
        format::parse_with(&d.text, &registry).map_err(|e| format_error(d, e))?;
    }
    let rust_names: HashMap<&str, String> = defs
        .iter()
        .map(|d| (d.name, names::type_name(d.name)))
        .collect();
    let mut top = Module::default();
    for d in &defs {
        let source = format!("{}:{}", d.input.name, d.name_pos.line);
        top.items
            .extend(items(d.name, &d.format, &d.name_pos, &source, &rust_names)?);
    }
    model::finish(top)
}

/// The items for named format `name` (defined at `pos`, `source` in doc
/// comments): its own type first, then the types of its inline parts.
/// `rust_names` maps the format names it may use to Rust type names.
pub(super) fn items(
    name: &str,
    format: &Format,
    pos: &Pos,
    source: &str,
    rust_names: &HashMap<&str, String>,
) -> Result<Vec<Item>, GenError> {
    let mut cx = Cx {
        name,
        format,
        pos,
        source,
        rust_names,
        extra: Vec::new(),
    };
    let mut out = vec![cx.top()?];
    out.append(&mut cx.extra);
    Ok(out)
}

/// The named formats of one input, in file order, as parsed (named
/// references unexpanded): what the generated types' formats must be
/// equivalent to.
pub fn formats(input: &Input) -> Result<Vec<(String, Format)>, GenError> {
    Ok(definitions(input)?
        .into_iter()
        .map(|d| (d.name.to_string(), d.format))
        .collect())
}

/// A wire parse error at its place in the file.
fn format_error(d: &Def<'_>, e: ParseError) -> GenError {
    let pos = Pos::at(
        &d.input.path,
        &d.input.text,
        d.offset + e.pos().unwrap_or(0),
    );
    match e {
        ParseError::UnknownName { name, .. } => GenError::UnknownType { pos, name },
        other => {
            let msg = other.to_string();
            // "at byte 17: expected ..." -> "expected ..."
            let message = match (other.pos(), msg.split_once(": ")) {
                (Some(_), Some((_, rest))) => rest.to_string(),
                _ => msg,
            };
            GenError::Format { pos, message }
        }
    }
}

/// Splits a file into its definitions and parses each format.
fn definitions(input: &Input) -> Result<Vec<Def<'_>>, GenError> {
    let text = &input.text;
    // comments blanked out, so that offsets stay those of the file
    let mut clean = String::with_capacity(text.len());
    for line in text.split_inclusive('\n') {
        match line.find('#') {
            Some(i) => {
                clean.push_str(&line[..i]);
                for c in line[i..].chars() {
                    clean.push(if c == '\n' { '\n' } else { ' ' });
                    // keep byte offsets: pad multi-byte characters
                    for _ in 1..c.len_utf8() {
                        clean.push(' ');
                    }
                }
            }
            None => clean.push_str(line),
        }
    }
    let bytes = clean.as_bytes();
    let mut defs = Vec::new();
    let mut i = 0;
    while i < bytes.len() {
        if bytes[i].is_ascii_whitespace() {
            i += 1;
            continue;
        }
        let start = i;
        let line_end = clean[i..].find('\n').map_or(clean.len(), |n| i + n);
        let Some(eq) = clean[i..line_end].find('=').map(|n| i + n) else {
            return Err(GenError::syntax(
                Pos::at(&input.path, text, start),
                "a definition `NAME = FORMAT`",
                format!("`{}`", clean[start..line_end].trim_end()),
            ));
        };
        let name = clean[start..eq].trim_end();
        let name_pos = Pos::at(&input.path, text, start);
        if name.is_empty() || name.contains(char::is_whitespace) {
            return Err(GenError::syntax(
                name_pos,
                "a format name (one word) before `=`",
                format!("`{}`", clean[start..eq].trim_end()),
            ));
        }
        // the format runs to the end of the line, or further while a
        // bracket is open
        let body = eq + 1;
        let mut depth: i64 = 0;
        let mut j = body;
        while j < bytes.len() {
            match bytes[j] {
                b'{' | b'[' | b'<' => depth += 1,
                b'}' | b']' | b'>' => depth -= 1,
                b'\n' if depth <= 0 => break,
                _ => {}
            }
            j += 1;
        }
        let ftext = clean[body..j].to_string();
        let mut def = Def {
            name: &text[start..start + name.len()],
            name_pos,
            text: ftext,
            offset: body,
            input,
            format: Format::Empty,
        };
        def.format = format::parse(&def.text).map_err(|e| format_error(&def, e))?;
        defs.push(def);
        i = j;
    }
    Ok(defs)
}

/// Translation of one definition; inline composites go to `extra`.
struct Cx<'a> {
    name: &'a str,
    format: &'a Format,
    pos: &'a Pos,
    source: &'a str,
    rust_names: &'a HashMap<&'a str, String>,
    extra: Vec<Item>,
}

impl Cx<'_> {
    fn pos(&self) -> Pos {
        self.pos.clone()
    }

    fn top(&mut self) -> Result<Item, GenError> {
        let name = self.name;
        let rust = self
            .rust_names
            .get(name)
            .cloned()
            .unwrap_or_else(|| names::type_name(name));
        let doc = vec![format!(
            "IPC format `{name}` ({}): `{}`.",
            self.source, self.format
        )];
        Ok(match self.format {
            Format::Empty => Item::Struct(StructDef {
                name: rust,
                pos: self.pos(),
                doc: vec![format!(
                    "IPC format `{name}` ({}): the empty format (no data).",
                    self.source
                )],
                format_name: None,
                type_name: Some(name.to_string()),
                extensibility: None,
                tuple: true,
                fields: Vec::new(),
            }),
            Format::Struct(fields) => {
                let format_name = (rust != name).then(|| name.to_string());
                Item::Struct(self.structure(rust, format_name, name, doc, fields)?)
            }
            Format::Enum { names, max } => {
                Item::Enum(self.enumeration(rust, name, doc, names, *max)?)
            }
            other => {
                let ty = self.ty(other, &format!("{rust}Item"), &rust)?;
                Item::Alias(AliasDef {
                    name: rust,
                    pos: self.pos(),
                    doc,
                    ty,
                })
            }
        })
    }

    /// A struct `name` whose DDS type name is `type_name` (the format's
    /// name, or for an inline part its Rust name: the same in every module
    /// that includes the generated file).
    fn structure(
        &mut self,
        name: String,
        format_name: Option<String>,
        type_name: &str,
        doc: Vec<String>,
        fields: &[Format],
    ) -> Result<StructDef, GenError> {
        let mut out = Vec::new();
        for (i, f) in fields.iter().enumerate() {
            let inner = format!("{name}Field{}", i + 1);
            let (ty, len) = match f {
                Format::VarArray { elem, dims } if dims.len() == 1 => {
                    let elem = self.ty(elem, &inner, &name)?;
                    (Ty::Vec(Box::new(elem)), Some((dims[0] - 1).to_string()))
                }
                Format::VarArray { elem, dims } => {
                    // `NdVec` size fields hold any dimension: C reads them as `int`
                    for &k in dims {
                        let sized_by = &fields[k as usize - 1];
                        if !matches!(
                            sized_by,
                            Format::Primitive(
                                Primitive::Int
                                    | Primitive::UInt
                                    | Primitive::Long
                                    | Primitive::ULong
                            )
                        ) {
                            return Err(GenError::unsupported(
                                self.pos(),
                                format!(
                                    "the variable array `{f}` sized by field {k} of format `{sized_by}`"
                                ),
                                "the size fields of a multi-dimensional array must be `int`, \
                                 `uint`, `long` or `ulong` (C's IPC reads them as `int`)",
                            ));
                        }
                    }
                    let elem = self.ty(elem, &inner, &name)?;
                    let names: Vec<String> = dims.iter().map(|k| (k - 1).to_string()).collect();
                    (
                        Ty::NdVec(Box::new(elem), dims.len()),
                        Some(names.join(", ")),
                    )
                }
                other => (self.ty(other, &inner, &name)?, None),
            };
            let mut fd = FieldDef::new(i.to_string(), self.pos(), ty);
            fd.len = len;
            out.push(fd);
        }
        Ok(StructDef {
            name,
            pos: self.pos(),
            doc,
            format_name,
            type_name: Some(type_name.to_string()),
            extensibility: None,
            tuple: true,
            fields: out,
        })
    }

    /// An enum `name` whose DDS type name is `type_name` (as for
    /// [`Cx::structure`]).
    fn enumeration(
        &self,
        name: String,
        type_name: &str,
        doc: Vec<String>,
        variants: &[String],
        max: i32,
    ) -> Result<EnumDef, GenError> {
        let numeric = variants.is_empty();
        let variants = if numeric {
            if max > MAX_ENUM {
                return Err(GenError::unsupported(
                    self.pos(),
                    format!("`{{enum : {max}}}`"),
                    format!(
                        "an enum is generated with one variant per value, at most {}; use `int`",
                        MAX_ENUM + 1
                    ),
                ));
            }
            (0..=max)
                .map(|v| (format!("V{v}"), None, Vec::new()))
                .collect()
        } else {
            variants
                .iter()
                .map(|v| (names::verbatim(v), None, Vec::new()))
                .collect()
        };
        Ok(EnumDef {
            name,
            pos: self.pos(),
            doc,
            type_name: Some(type_name.to_string()),
            numeric,
            variants,
        })
    }

    /// The Rust type of format `f`; an inline struct or enum becomes the
    /// type `inner`; `*!` points at `this`.
    fn ty(&mut self, f: &Format, inner: &str, this: &str) -> Result<Ty, GenError> {
        Ok(match f {
            Format::Primitive(p) => Ty::Prim(self.prim(*p)?),
            Format::Length(n) => {
                return Err(GenError::unsupported(
                    self.pos(),
                    format!("the raw byte count `{n}`"),
                    format!("write `[ubyte:{n}]` for {n} bytes"),
                ))
            }
            Format::Struct(fields) => {
                let doc = vec![format!("Part of `{this}`: `{f}`.")];
                let s = self.structure(inner.to_string(), None, inner, doc, fields)?;
                self.extra.push(Item::Struct(s));
                Ty::Named(local(inner))
            }
            Format::Enum { names, max } => {
                let doc = vec![format!("Part of `{this}`: `{f}`.")];
                let e = self.enumeration(inner.to_string(), inner, doc, names, *max)?;
                self.extra.push(Item::Enum(e));
                Ty::Named(local(inner))
            }
            Format::Pointer(t) => Ty::Boxed(Box::new(self.ty(t, inner, this)?)),
            Format::SelfPointer => Ty::Boxed(Box::new(Ty::Named(local(this)))),
            Format::FixedArray { elem, dims } => {
                let mut t = self.ty(elem, inner, this)?;
                for d in dims.iter().rev() {
                    t = Ty::Array(Box::new(t), *d);
                }
                t
            }
            Format::VarArray { .. } => {
                // the parser allows variable arrays only as struct fields,
                // which `structure` handles
                return Err(GenError::unsupported(
                    self.pos(),
                    format!("the variable array `{f}` outside a struct"),
                    "make it a field of a struct `{int, <T:1>}`",
                ));
            }
            Format::Named(n) => match self.rust_names.get(n.as_str()) {
                Some(r) => Ty::Named(local(r)),
                None => {
                    return Err(GenError::UnknownType {
                        pos: self.pos(),
                        name: n.clone(),
                    })
                }
            },
            Format::Empty => {
                return Err(GenError::invalid(
                    self.pos(),
                    "the empty format cannot be part of another format",
                ))
            }
        })
    }

    fn prim(&self, p: Primitive) -> Result<Prim, GenError> {
        Ok(match p {
            Primitive::Char => Prim::Char,
            Primitive::Byte => Prim::I8,
            Primitive::UByte => Prim::U8,
            Primitive::Short => Prim::I16,
            Primitive::UShort => Prim::U16,
            Primitive::Int => Prim::I32,
            Primitive::UInt => Prim::U32,
            Primitive::Boolean => Prim::Bool,
            Primitive::Float => Prim::F32,
            Primitive::Double => Prim::F64,
            Primitive::Long => Prim::I64,
            Primitive::ULong => Prim::U64,
            Primitive::String => Prim::String,
            Primitive::TwoByte | Primitive::Format => {
                return Err(GenError::unsupported(
                    self.pos(),
                    format!("the IPC primitive `{p}`"),
                    "#[derive(IpcMessage)] has no Rust type for it; use `short` or `ushort` \
                     for two bytes",
                ))
            }
        })
    }
}

fn local(name: &str) -> TypeRef {
    TypeRef {
        module: Vec::new(),
        name: name.to_string(),
    }
}
