//! OMG IDL (the subset ROS 2's rosidl and Cyclone DDS's idlc read) to Rust
//! types.
//!
//! Read: `module`s (nested, re-opened), `struct`s (and forward
//! declarations), `enum`s (`@value` gives explicit values), `typedef`s
//! (with array declarators), `const`s with constant expressions, the
//! integer, floating-point, `boolean`, `octet`, `char` and `int8`…`uint64`
//! types, `string` and `string<N>`, `sequence<T>` and `sequence<T, N>`,
//! arrays `T a[n][m]`, `#include "…"` / `<…>` (searched next to the
//! including file, in its parent directories, then in the `-I`
//! directories; each file once), `#pragma` (skipped), `//` and `/* */`
//! comments, and the annotations `@key`, `@id`, `@optional`,
//! `@must_understand`, `@final`, `@appendable`, `@mutable`,
//! `@extensibility(…)`, `@value` and `@verbatim` (whose text becomes doc
//! comments); other annotations (`@default`, `@unit`, `@range`, `@topic`,
//! …) do not change the encoding and are skipped.
//!
//! Modules become `pub mod`s (snake case), structs get
//! `#[ipc(type_name = "pkg::msg::Name")]` (or ROS 2's
//! `pkg::msg::dds_::Name_` with [`Options::ros2_names`](super::Options)),
//! sequences become `Vec<T>` (a CDR sequence; such a struct has no IPC
//! form, since IPC counts arrays with a field), `@optional` members
//! `Option<Box<T>>`, bounds of strings and sequences `#[ipc(bound = N)]`
//! (publishing refuses a longer value, a subscriber refuses to take one;
//! the bound of an array's elements is a doc comment only). Structs are final unless annotated otherwise, as idlc and
//! ROS 2 have them.
//!
//! Refused with the place and a hint: `union`, inheritance, `wchar`,
//! `wstring`, `long double`, `any`, `fixed`, `map`, bit sets, interfaces,
//! sequences of sequences and arrays of sequences (a `Vec` is a direct field
//! only), `@optional` sequences, structs without members, and any
//! preprocessor directive but `#include` and `#pragma`.

mod parse;

use std::collections::{HashMap, HashSet};
use std::path::{Component, Path, PathBuf};

use parse::{Ann, Def, EnumAst, Expr, Parser, StructAst, TypeAst};

use super::error::{GenError, Pos};
use super::lex::{self, Cursor};
use super::model::{
    self, AliasDef, ConstDef, EnumDef, Extensibility, FieldDef, Item, Module, Prim, StructDef, Ty,
    TypeRef,
};
use super::{names, Input, Loader, Options};

/// Deepest nesting of `#include`s.
pub const MAX_INCLUDE_DEPTH: usize = 64;

/// A constant's value.
#[derive(Debug, Clone, PartialEq)]
enum Val {
    Int(i128),
    Float(f64),
    Bool(bool),
    Str(String),
    Char(char),
}

#[derive(Debug, Clone)]
enum Kind {
    Module,
    Struct {
        defined: bool,
    },
    Enum,
    /// The type, and the bound of a bounded string or sequence.
    Typedef(Ty, Option<u32>),
    Const(Val),
}

#[derive(Debug, Clone)]
struct Sym {
    kind: Kind,
    pos: Pos,
    rust: TypeRef,
}

/// Translates `inputs` and what they include.
pub fn translate(
    inputs: &[Input],
    loader: &dyn Loader,
    options: &Options,
) -> Result<Module, GenError> {
    let mut tr = Tr {
        loader,
        options,
        syms: HashMap::new(),
        files: HashSet::new(),
        top: Module::default(),
    };
    for input in inputs {
        let path = normalize(Path::new(&input.path));
        if tr.files.insert(path.clone()) {
            tr.file(input, &path, &[], 0)?;
        }
    }
    let mut top = tr.top;
    name_clashing_formats(&mut top);
    model::finish(top)
}

struct Tr<'a> {
    loader: &'a dyn Loader,
    options: &'a Options,
    syms: HashMap<Vec<String>, Sym>,
    files: HashSet<PathBuf>,
    top: Module,
}

/// The file being translated: where includes are searched from, and its
/// name in doc comments.
struct FileCx<'a> {
    path: &'a Path,
    doc_name: &'a str,
    depth: usize,
}

/// `a/./b/../c` as `a/c`, so that one file included by two spellings is
/// read once.
fn normalize(p: &Path) -> PathBuf {
    let mut out = PathBuf::new();
    for c in p.components() {
        match c {
            Component::CurDir => {}
            Component::ParentDir if out.file_name().is_some() => {
                out.pop();
            }
            other => out.push(other),
        }
    }
    out
}

fn first_str<'a>(anns: &'a [Ann], name: &str) -> Option<&'a Ann> {
    anns.iter().find(|a| a.name == name)
}

impl Tr<'_> {
    fn file(
        &mut self,
        input: &Input,
        path: &Path,
        scope: &[String],
        depth: usize,
    ) -> Result<(), GenError> {
        let toks = lex::lex(
            &input.path,
            &input.text,
            lex::Options {
                directives: true,
                code_sections: false,
            },
        )?;
        let defs = Parser::new(Cursor::new(toks)).file()?;
        let fcx = FileCx {
            path,
            doc_name: &input.name,
            depth,
        };
        self.defs(&defs, scope, &fcx)
    }

    fn defs(&mut self, defs: &[Def], scope: &[String], fcx: &FileCx<'_>) -> Result<(), GenError> {
        for d in defs {
            self.def(d, scope, fcx)?;
        }
        Ok(())
    }

    fn rust_module(&self, scope: &[String]) -> Vec<String> {
        scope.iter().map(|s| names::field_name(s)).collect()
    }

    /// The Rust module for IDL scope `scope`, created on first use.
    fn module_mut(&mut self, scope: &[String]) -> &mut Module {
        let mut m = &mut self.top;
        for s in scope {
            let name = names::field_name(s);
            let i = match m
                .items
                .iter()
                .position(|it| matches!(it, Item::Module(x) if x.name == name))
            {
                Some(i) => i,
                None => {
                    m.items.push(Item::Module(Module {
                        name,
                        doc: vec![format!("IDL module `{s}`.")],
                        items: Vec::new(),
                    }));
                    m.items.len() - 1
                }
            };
            let Item::Module(next) = &mut m.items[i] else {
                unreachable!("position() found a module")
            };
            m = next;
        }
        m
    }

    fn declare(
        &mut self,
        scope: &[String],
        name: &str,
        pos: &Pos,
        kind: Kind,
        rust_name: String,
    ) -> Result<(), GenError> {
        let mut full = scope.to_vec();
        full.push(name.to_string());
        if let Some(old) = self.syms.get(&full) {
            let ok = matches!(
                (&old.kind, &kind),
                (Kind::Module, Kind::Module)
                    | (Kind::Struct { defined: false }, Kind::Struct { .. })
            ) || matches!(
                (&old.kind, &kind),
                (Kind::Struct { .. }, Kind::Struct { defined: false })
            );
            if !ok {
                return Err(GenError::Duplicate {
                    pos: pos.clone(),
                    name: full.join("::"),
                    first: old.pos.clone(),
                });
            }
            if matches!(kind, Kind::Struct { defined: false }) || matches!(kind, Kind::Module) {
                return Ok(());
            }
        }
        let rust = TypeRef {
            module: self.rust_module(scope),
            name: rust_name,
        };
        self.syms.insert(
            full,
            Sym {
                kind,
                pos: pos.clone(),
                rust,
            },
        );
        Ok(())
    }

    fn lookup(&self, path: &[String], absolute: bool, scope: &[String]) -> Option<&Sym> {
        if absolute {
            return self.syms.get(path);
        }
        (0..=scope.len()).rev().find_map(|k| {
            let mut full = scope[..k].to_vec();
            full.extend_from_slice(path);
            self.syms.get(&full)
        })
    }

    fn dds_name(&self, scope: &[String], name: &str) -> String {
        let ros = self.options.ros2_names
            && scope.len() >= 2
            && matches!(scope[1].as_str(), "msg" | "srv" | "action");
        if ros {
            format!("{}::{}::dds_::{name}_", scope[0], scope[1])
        } else {
            let mut p = scope.to_vec();
            p.push(name.to_string());
            p.join("::")
        }
    }

    fn def(&mut self, d: &Def, scope: &[String], fcx: &FileCx<'_>) -> Result<(), GenError> {
        match d {
            Def::Include(name, pos) => self.include(name, pos, scope, fcx),
            Def::Module(name, pos, defs) => {
                self.declare(scope, name, pos, Kind::Module, names::field_name(name))?;
                let mut inner = scope.to_vec();
                inner.push(name.clone());
                self.module_mut(&inner);
                self.defs(defs, &inner, fcx)
            }
            Def::Forward(name, pos) => self.declare(
                scope,
                name,
                pos,
                Kind::Struct { defined: false },
                names::type_name(name),
            ),
            Def::Struct(s) => self.structure(s, scope, fcx),
            Def::Enum(e) => self.enumeration(e, scope, fcx),
            Def::Typedef(ty, decls) => {
                for decl in decls {
                    let (base, notes, bound) = self.ty(ty, scope)?;
                    // a bound of the elements of an array alias is not the alias's
                    let bound = bound.filter(|_| decl.dims.is_empty());
                    let t = self.with_dims(base, &decl.dims, scope, &decl.pos)?;
                    let rust = names::type_name(&decl.name);
                    self.declare(
                        scope,
                        &decl.name,
                        &decl.pos,
                        Kind::Typedef(t.clone(), bound),
                        rust.clone(),
                    )?;
                    let mut doc = vec![format!(
                        "IDL typedef `{}` ({}:{}).",
                        self.idl_name(scope, &decl.name),
                        fcx.doc_name,
                        decl.pos.line
                    )];
                    doc.extend(notes);
                    self.module_mut(scope).items.push(Item::Alias(AliasDef {
                        name: rust,
                        pos: decl.pos.clone(),
                        doc,
                        ty: t,
                    }));
                }
                Ok(())
            }
            Def::Const(anns, ty, name, pos, value) => {
                self.constant(anns, ty, name, pos, value, scope, fcx)
            }
        }
    }

    fn idl_name(&self, scope: &[String], name: &str) -> String {
        let mut p = scope.to_vec();
        p.push(name.to_string());
        p.join("::")
    }

    fn include(
        &mut self,
        name: &str,
        pos: &Pos,
        scope: &[String],
        fcx: &FileCx<'_>,
    ) -> Result<(), GenError> {
        if fcx.depth >= MAX_INCLUDE_DEPTH {
            return Err(GenError::invalid(
                pos.clone(),
                format!("#include nested deeper than {MAX_INCLUDE_DEPTH} files"),
            ));
        }
        let mut dirs: Vec<PathBuf> = fcx
            .path
            .ancestors()
            .skip(1)
            .map(Path::to_path_buf)
            .collect();
        dirs.extend(self.loader_dirs());
        let found = dirs
            .iter()
            .map(|d| normalize(&d.join(name)))
            .find(|p| self.loader.exists(p));
        let Some(path) = found else {
            let looked: Vec<String> = dirs
                .iter()
                .map(|d| {
                    if d.as_os_str().is_empty() {
                        ".".to_string()
                    } else {
                        d.display().to_string()
                    }
                })
                .collect();
            return Err(GenError::Include {
                pos: pos.clone(),
                name: name.to_string(),
                looked: looked.join(", "),
            });
        };
        if !self.files.insert(path.clone()) {
            return Ok(());
        }
        let text = self.loader.load(&path).map_err(|source| GenError::Read {
            path: path.clone(),
            source,
        })?;
        let input = Input {
            path: path.display().to_string(),
            name: name.to_string(),
            text,
        };
        self.file(&input, &path, scope, fcx.depth + 1)
    }

    fn loader_dirs(&self) -> Vec<PathBuf> {
        self.loader.include_dirs()
    }

    /// A bound or dimension: a positive integer constant.
    fn bound(&self, e: &Expr, scope: &[String], what: &str) -> Result<u32, GenError> {
        let v = self.eval(e, scope)?;
        match v {
            Val::Int(n) if n > 0 && n <= i128::from(i32::MAX) => Ok(n as u32),
            other => Err(GenError::BadBound {
                pos: e.pos().clone(),
                found: show(&other),
                why: format!("{what} must be an integer from 1 to 2147483647"),
            }),
        }
    }

    /// The Rust type of a type specifier, notes for doc comments, and the
    /// bound of a bounded string or sequence (`#[ipc(bound = N)]`).
    fn ty(
        &self,
        t: &TypeAst,
        scope: &[String],
    ) -> Result<(Ty, Vec<String>, Option<u32>), GenError> {
        Ok(match t {
            TypeAst::Prim(p) => (Ty::Prim(*p), Vec::new(), None),
            TypeAst::String(None) => (Ty::Prim(Prim::String), Vec::new(), None),
            TypeAst::String(Some(b)) => {
                let n = self.bound(b, scope, "a string bound")?;
                (
                    Ty::Prim(Prim::String),
                    vec![format!("At most {n} bytes (`string<{n}>`).")],
                    Some(n),
                )
            }
            TypeAst::Sequence(elem, bound, pos) => {
                let (e, _, _) = self.ty(elem, scope)?;
                if matches!(e, Ty::Vec(_)) {
                    return Err(GenError::unsupported(
                        pos.clone(),
                        "a sequence of sequences",
                        "#[derive(IpcMessage)] takes a Vec only as a direct field; wrap the inner \
                         sequence in a struct",
                    ));
                }
                match bound {
                    Some(b) => {
                        let n = self.bound(b, scope, "a sequence bound")?;
                        (
                            Ty::Vec(Box::new(e)),
                            vec![format!("At most {n} elements (`sequence<…, {n}>`).")],
                            Some(n),
                        )
                    }
                    None => (Ty::Vec(Box::new(e)), Vec::new(), None),
                }
            }
            TypeAst::Named(path, absolute, pos) => {
                let written = format!("{}{}", if *absolute { "::" } else { "" }, path.join("::"));
                let Some(sym) = self.lookup(path, *absolute, scope) else {
                    return Err(GenError::UnknownType {
                        pos: pos.clone(),
                        name: written,
                    });
                };
                match &sym.kind {
                    Kind::Struct { .. } | Kind::Enum => {
                        (Ty::Named(sym.rust.clone()), Vec::new(), None)
                    }
                    Kind::Typedef(t, bound) => (t.clone(), Vec::new(), *bound),
                    Kind::Module | Kind::Const(_) => {
                        return Err(GenError::invalid(
                            pos.clone(),
                            format!(
                                "`{written}` is a {}, not a type",
                                if matches!(sym.kind, Kind::Module) {
                                    "module"
                                } else {
                                    "constant"
                                }
                            ),
                        ))
                    }
                }
            }
        })
    }

    fn with_dims(
        &self,
        mut t: Ty,
        dims: &[Expr],
        scope: &[String],
        pos: &Pos,
    ) -> Result<Ty, GenError> {
        if !dims.is_empty() && matches!(t, Ty::Vec(_)) {
            return Err(GenError::unsupported(
                pos.clone(),
                "an array of sequences",
                "#[derive(IpcMessage)] takes a Vec only as a direct field; wrap the sequence in a struct",
            ));
        }
        let mut ns = Vec::new();
        for d in dims {
            ns.push(self.bound(d, scope, "an array dimension")?);
        }
        for n in ns.into_iter().rev() {
            t = Ty::Array(Box::new(t), n);
        }
        Ok(t)
    }

    fn structure(
        &mut self,
        s: &StructAst,
        scope: &[String],
        fcx: &FileCx<'_>,
    ) -> Result<(), GenError> {
        let rust = names::type_name(&s.name);
        self.declare(
            scope,
            &s.name,
            &s.pos,
            Kind::Struct { defined: true },
            rust.clone(),
        )?;
        if s.members.is_empty() {
            return Err(GenError::unsupported(
                s.pos.clone(),
                format!("the struct `{}` without members", s.name),
                "an empty struct is the empty message and cannot be a field; add a member \
                 (ROS 2 adds `uint8 structure_needs_at_least_one_member`)",
            ));
        }
        let mut extensibility = None;
        for a in &s.anns {
            let e = match a.name.as_str() {
                "final" => Some(Extensibility::Final),
                "appendable" => Some(Extensibility::Appendable),
                "mutable" => Some(Extensibility::Mutable),
                "extensibility" => match a.params.first().map(|p| &p.1) {
                    Some(Expr::Name(n, _, _)) if n.len() == 1 => match n[0].as_str() {
                        "FINAL" => Some(Extensibility::Final),
                        "APPENDABLE" => Some(Extensibility::Appendable),
                        "MUTABLE" => Some(Extensibility::Mutable),
                        _ => None,
                    },
                    _ => None,
                }
                .map(Some)
                .ok_or_else(|| {
                    GenError::invalid(
                        a.pos.clone(),
                        "@extensibility takes FINAL, APPENDABLE or MUTABLE",
                    )
                })?,
                "autoid" => {
                    if matches!(a.params.first().map(|p| &p.1), Some(Expr::Name(n, _, _)) if n.last().is_some_and(|x| x == "HASH"))
                    {
                        return Err(GenError::unsupported(
                            a.pos.clone(),
                            "`@autoid(HASH)`",
                            "member ids count from 0 (or from @id); give explicit @id values",
                        ));
                    }
                    None
                }
                _ => None,
            };
            if e.is_some() {
                extensibility = e;
            }
        }
        let mut doc = vec![format!(
            "IDL struct `{}` ({}:{}).",
            self.idl_name(scope, &s.name),
            fcx.doc_name,
            s.pos.line
        )];
        verbatim(&s.anns, &mut doc, true);
        let mut fields = Vec::new();
        let mut seen: HashMap<&str, &Pos> = HashMap::new();
        for m in &s.members {
            for decl in &m.decls {
                if let Some(first) = seen.get(decl.name.as_str()) {
                    return Err(GenError::Duplicate {
                        pos: decl.pos.clone(),
                        name: format!("{}.{}", s.name, decl.name),
                        first: (*first).clone(),
                    });
                }
                seen.insert(&decl.name, &decl.pos);
                let (base, notes, bound) = self.ty(&m.ty, scope)?;
                let mut t = self.with_dims(base, &decl.dims, scope, &decl.pos)?;
                // a field's own bound; an array's elements' is not checked
                let element_bound = bound.filter(|_| !decl.dims.is_empty());
                let bound = bound.filter(|_| decl.dims.is_empty());
                let mut fd = FieldDef::new(
                    names::field_name(&decl.name),
                    decl.pos.clone(),
                    Ty::Prim(Prim::Bool),
                );
                verbatim(&m.anns, &mut fd.doc, false);
                fd.doc.extend(notes);
                if fd.name.trim_start_matches("r#") != decl.name {
                    fd.doc.push(format!("`{}` in the IDL.", decl.name));
                }
                for a in &m.anns {
                    match a.name.as_str() {
                        "key" => fd.key = true,
                        "must_understand" => fd.must_understand = true,
                        "id" => {
                            let v = a
                                .params
                                .first()
                                .map(|p| self.eval(&p.1, scope))
                                .transpose()?;
                            match v {
                                Some(Val::Int(n)) if (0..=0x0fff_ffff).contains(&n) => {
                                    fd.id = Some(n as u32)
                                }
                                _ => {
                                    return Err(GenError::invalid(
                                        a.pos.clone(),
                                        "@id takes an integer from 0 to 0x0fffffff",
                                    ))
                                }
                            }
                        }
                        "optional" => {
                            if matches!(t, Ty::Vec(_)) {
                                return Err(GenError::unsupported(
                                    a.pos.clone(),
                                    "an @optional sequence",
                                    "an empty sequence already says \"none\"; drop @optional",
                                ));
                            }
                            t = Ty::Boxed(Box::new(t));
                        }
                        _ => {}
                    }
                }
                match (bound, element_bound) {
                    (Some(n), _) if matches!(t, Ty::Prim(Prim::String) | Ty::Vec(_)) => {
                        fd.bound = Some(n)
                    }
                    (Some(n), _) => fd.doc.push(format!(
                        "The bound {n} is not checked (`#[ipc(bound)]` takes no optional member)."
                    )),
                    (None, Some(n)) => fd.doc.push(format!(
                        "The bound {n} of each element is not checked (`#[ipc(bound)]` is a field's own)."
                    )),
                    (None, None) => {}
                }
                fd.ty = t;
                fields.push(fd);
            }
        }
        let type_name = Some(self.dds_name(scope, &s.name));
        self.module_mut(scope).items.push(Item::Struct(StructDef {
            name: rust,
            pos: s.pos.clone(),
            doc,
            format_name: None,
            type_name,
            extensibility,
            tuple: false,
            fields,
        }));
        Ok(())
    }

    fn enumeration(
        &mut self,
        e: &EnumAst,
        scope: &[String],
        fcx: &FileCx<'_>,
    ) -> Result<(), GenError> {
        let rust = names::type_name(&e.name);
        self.declare(scope, &e.name, &e.pos, Kind::Enum, rust.clone())?;
        let mut doc = vec![format!(
            "IDL enum `{}` ({}:{}).",
            self.idl_name(scope, &e.name),
            fcx.doc_name,
            e.pos.line
        )];
        verbatim(&e.anns, &mut doc, true);
        let mut variants = Vec::new();
        let mut seen: HashMap<&str, &Pos> = HashMap::new();
        for (name, pos, anns) in &e.literals {
            if let Some(first) = seen.get(name.as_str()) {
                return Err(GenError::Duplicate {
                    pos: pos.clone(),
                    name: format!("{}::{name}", e.name),
                    first: (*first).clone(),
                });
            }
            seen.insert(name, pos);
            let mut value = None;
            if let Some(a) = first_str(anns, "value") {
                match a.params.first().map(|p| self.eval(&p.1, scope)).transpose()? {
                    Some(Val::Int(n)) if (0..=i128::from(i32::MAX)).contains(&n) => value = Some(n as i64),
                    _ => {
                        return Err(GenError::unsupported(
                            a.pos.clone(),
                            "this @value",
                            "enum values must be integers from 0 to 2147483647 (IPC enums count from 0)",
                        ))
                    }
                }
            }
            let mut vdoc = Vec::new();
            verbatim(anns, &mut vdoc, false);
            variants.push((names::verbatim(name), value, vdoc));
        }
        let type_name = Some(self.dds_name(scope, &e.name));
        self.module_mut(scope).items.push(Item::Enum(EnumDef {
            name: rust,
            pos: e.pos.clone(),
            doc,
            type_name,
            numeric: false,
            variants,
        }));
        Ok(())
    }

    #[allow(clippy::too_many_arguments)]
    fn constant(
        &mut self,
        anns: &[Ann],
        ty: &TypeAst,
        name: &str,
        pos: &Pos,
        value: &Expr,
        scope: &[String],
        fcx: &FileCx<'_>,
    ) -> Result<(), GenError> {
        let (t, _, _) = self.ty(ty, scope)?;
        let v = self.eval(value, scope)?;
        let bad = |want: &str| {
            GenError::invalid(
                value.pos().clone(),
                format!("constant `{name}` is {want}, but its value is {}", show(&v)),
            )
        };
        let (rust_ty, lit, v) = match (&t, &v) {
            (Ty::Prim(p), Val::Int(n)) if p.is_integer() => {
                let (lo, hi) = int_range(*p);
                if *n < lo || *n > hi {
                    return Err(bad(&format!("a {} ({lo} to {hi})", p.rust())));
                }
                (p.rust().to_string(), n.to_string(), v.clone())
            }
            (Ty::Prim(p @ (Prim::F32 | Prim::F64)), Val::Int(_) | Val::Float(_)) => {
                let f = match v {
                    Val::Int(n) => n as f64,
                    Val::Float(f) => f,
                    _ => unreachable!("matched above"),
                };
                (p.rust().to_string(), float_lit(f), Val::Float(f))
            }
            (Ty::Prim(Prim::Bool), Val::Bool(b)) => ("bool".into(), b.to_string(), v.clone()),
            (Ty::Prim(Prim::Char), Val::Char(c)) => ("char".into(), format!("{c:?}"), v.clone()),
            (Ty::Prim(Prim::String), Val::Str(s)) => ("&str".into(), format!("{s:?}"), v.clone()),
            (Ty::Prim(p), _) => return Err(bad(&format!("a {}", p.rust()))),
            _ => {
                return Err(GenError::unsupported(
                    pos.clone(),
                    format!("the type of constant `{name}`"),
                    "constants are integers, floating-point numbers, booleans, chars or strings",
                ))
            }
        };
        let rust = names::verbatim(name);
        self.declare(scope, name, pos, Kind::Const(v), rust.clone())?;
        let mut doc = vec![format!(
            "IDL constant `{}` ({}:{}).",
            self.idl_name(scope, name),
            fcx.doc_name,
            pos.line
        )];
        verbatim(anns, &mut doc, true);
        self.module_mut(scope).items.push(Item::Const(ConstDef {
            name: rust,
            pos: pos.clone(),
            doc,
            ty: rust_ty,
            value: lit,
        }));
        Ok(())
    }

    fn eval(&self, e: &Expr, scope: &[String]) -> Result<Val, GenError> {
        let overflow = |p: &Pos| GenError::invalid(p.clone(), "constant expression overflows");
        Ok(match e {
            Expr::Int(n, _) => Val::Int(*n),
            Expr::Float(f, p) => Val::Float(
                f.parse()
                    .map_err(|_| GenError::invalid(p.clone(), format!("bad number `{f}`")))?,
            ),
            Expr::Str(s, _) => Val::Str(s.clone()),
            Expr::Char(c, _) => Val::Char(*c),
            Expr::Bool(b, _) => Val::Bool(*b),
            Expr::Name(path, abs, p) => match self.lookup(path, *abs, scope) {
                Some(Sym {
                    kind: Kind::Const(v),
                    ..
                }) => v.clone(),
                _ => {
                    return Err(GenError::invalid(
                        p.clone(),
                        format!(
                            "`{}` is no constant defined before this point",
                            path.join("::")
                        ),
                    ))
                }
            },
            Expr::Unary(op, x, p) => match (*op, self.eval(x, scope)?) {
                ("-", Val::Int(n)) => Val::Int(n.checked_neg().ok_or_else(|| overflow(p))?),
                ("-", Val::Float(f)) => Val::Float(-f),
                ("+", v @ (Val::Int(_) | Val::Float(_))) => v,
                ("~", Val::Int(n)) => Val::Int(!n),
                (op, v) => {
                    return Err(GenError::invalid(
                        p.clone(),
                        format!("`{op}` does not apply to {}", show(&v)),
                    ))
                }
            },
            Expr::Binary(op, a, b, p) => {
                let (a, b) = (self.eval(a, scope)?, self.eval(b, scope)?);
                match (a, b) {
                    (Val::Int(x), Val::Int(y)) => Val::Int(
                        match *op {
                            "+" => x.checked_add(y),
                            "-" => x.checked_sub(y),
                            "*" => x.checked_mul(y),
                            "/" => x.checked_div(y),
                            "%" => x.checked_rem(y),
                            "|" => Some(x | y),
                            "&" => Some(x & y),
                            "^" => Some(x ^ y),
                            "<<" => u32::try_from(y)
                                .ok()
                                .filter(|s| *s < 64)
                                .and_then(|s| x.checked_shl(s)),
                            ">>" => u32::try_from(y)
                                .ok()
                                .filter(|s| *s < 64)
                                .and_then(|s| x.checked_shr(s)),
                            _ => None,
                        }
                        .ok_or_else(|| overflow(p))?,
                    ),
                    (x @ (Val::Int(_) | Val::Float(_)), y @ (Val::Int(_) | Val::Float(_))) => {
                        let f = |v: Val| match v {
                            Val::Int(n) => n as f64,
                            Val::Float(f) => f,
                            _ => 0.0,
                        };
                        let (x, y) = (f(x), f(y));
                        Val::Float(match *op {
                            "+" => x + y,
                            "-" => x - y,
                            "*" => x * y,
                            "/" => x / y,
                            _ => {
                                return Err(GenError::invalid(
                                    p.clone(),
                                    format!("`{op}` does not apply to floating-point numbers"),
                                ))
                            }
                        })
                    }
                    (x, _) => {
                        return Err(GenError::invalid(
                            p.clone(),
                            format!("`{op}` does not apply to {}", show(&x)),
                        ))
                    }
                }
            }
        })
    }
}

fn int_range(p: Prim) -> (i128, i128) {
    match p {
        Prim::I8 => (i8::MIN.into(), i8::MAX.into()),
        Prim::U8 => (0, u8::MAX.into()),
        Prim::I16 => (i16::MIN.into(), i16::MAX.into()),
        Prim::U16 => (0, u16::MAX.into()),
        Prim::I32 => (i32::MIN.into(), i32::MAX.into()),
        Prim::U32 => (0, u32::MAX.into()),
        Prim::I64 => (i64::MIN.into(), i64::MAX.into()),
        _ => (0, u64::MAX.into()),
    }
}

fn float_lit(f: f64) -> String {
    let s = format!("{f:?}");
    if s.contains(['.', 'e', 'E']) || !f.is_finite() {
        s
    } else {
        format!("{s}.0")
    }
}

fn show(v: &Val) -> String {
    match v {
        Val::Int(n) => n.to_string(),
        Val::Float(f) => float_lit(*f),
        Val::Bool(b) => if *b { "TRUE" } else { "FALSE" }.to_string(),
        Val::Str(s) => format!("the string {s:?}"),
        Val::Char(c) => format!("the character {c:?}"),
    }
}

/// `@verbatim(language = "comment", text = "…")` as doc lines (after a
/// blank line when `separate`).
fn verbatim(anns: &[Ann], doc: &mut Vec<String>, separate: bool) {
    for a in anns.iter().filter(|a| a.name == "verbatim") {
        let lang = a
            .params
            .iter()
            .find(|(k, _)| k.as_deref() == Some("language"))
            .map(|(_, v)| v);
        if !matches!(lang, Some(Expr::Str(l, _)) if l == "comment") {
            continue;
        }
        let Some((_, Expr::Str(text, _))) =
            a.params.iter().find(|(k, _)| k.as_deref() == Some("text"))
        else {
            continue;
        };
        if separate && !doc.is_empty() {
            doc.push(String::new());
        }
        doc.extend(text.trim_end().lines().map(|l| l.trim_end().to_string()));
    }
}

/// Two structs of one Rust name (in different modules) would register the
/// same IPC format name: give those their IDL path (`pkg/msg/Name`).
fn name_clashing_formats(top: &mut Module) {
    fn count(m: &Module, out: &mut HashMap<String, usize>) {
        for it in &m.items {
            match it {
                Item::Struct(s) => *out.entry(s.name.clone()).or_default() += 1,
                Item::Module(sub) => count(sub, out),
                _ => {}
            }
        }
    }
    fn rename(m: &mut Module, path: &mut Vec<String>, counts: &HashMap<String, usize>) {
        for it in &mut m.items {
            match it {
                Item::Struct(s) if counts.get(&s.name).is_some_and(|n| *n > 1) => {
                    let mut p = path.clone();
                    p.push(s.name.clone());
                    s.format_name = Some(p.join("/"));
                }
                Item::Module(sub) => {
                    path.push(sub.name.clone());
                    rename(sub, path, counts);
                    path.pop();
                }
                _ => {}
            }
        }
    }
    let mut counts = HashMap::new();
    count(top, &mut counts);
    rename(top, &mut Vec::new(), &counts);
}
