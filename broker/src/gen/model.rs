//! What the three input languages are translated into before Rust is
//! written: modules of structs, enums, aliases and constants whose field
//! types are already Rust types, and the checks every language needs
//! (unique names, no type containing itself by value).

use std::collections::{BTreeMap, HashMap};

use super::error::{GenError, Pos};

/// A field's type, as `#[derive(IpcMessage)]` reads it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Ty {
    /// `i8`, `u8`, …, `f64`, `bool`, `char` or `String`.
    Prim(Prim),
    /// `[T; n]`.
    Array(Box<Ty>, u32),
    /// `Vec<T>`: an IPC variable array (with its count field) or a CDR sequence.
    Vec(Box<Ty>),
    /// `courier::NdVec<T, N>`: an IPC variable array of `N` > 1 dimensions
    /// (with its size fields).
    NdVec(Box<Ty>, usize),
    /// `Option<Box<T>>`: an IPC pointer, a CDR `@optional` member.
    Boxed(Box<Ty>),
    /// Another generated type.
    Named(TypeRef),
}

/// The primitive Rust types a generated field can have.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Prim {
    /// `i8`.
    I8,
    /// `u8`.
    U8,
    /// `i16`.
    I16,
    /// `u16`.
    U16,
    /// `i32`.
    I32,
    /// `u32`.
    U32,
    /// `i64`.
    I64,
    /// `u64`.
    U64,
    /// `f32`.
    F32,
    /// `f64`.
    F64,
    /// `bool`.
    Bool,
    /// `char` (one Latin-1 byte on the wire).
    Char,
    /// `u8` sent as an IPC `char` (`#[ipc(char)]` on a field; `u8` in arrays).
    CharByte,
    /// `String`.
    String,
}

impl Prim {
    /// The Rust type.
    pub fn rust(self) -> &'static str {
        match self {
            Prim::I8 => "i8",
            Prim::U8 => "u8",
            Prim::I16 => "i16",
            Prim::U16 => "u16",
            Prim::I32 => "i32",
            Prim::U32 => "u32",
            Prim::I64 => "i64",
            Prim::U64 => "u64",
            Prim::F32 => "f32",
            Prim::F64 => "f64",
            Prim::Bool => "bool",
            Prim::Char => "char",
            Prim::CharByte => "u8",
            Prim::String => "String",
        }
    }

    /// True for the integer types a count field may have.
    pub fn is_integer(self) -> bool {
        matches!(
            self,
            Prim::I8
                | Prim::U8
                | Prim::I16
                | Prim::U16
                | Prim::I32
                | Prim::U32
                | Prim::I64
                | Prim::U64
        )
    }
}

/// A generated type by its Rust module path (from the output's top) and name.
#[derive(Debug, Clone, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct TypeRef {
    /// Rust module names from the top of the output.
    pub module: Vec<String>,
    /// The Rust type name.
    pub name: String,
}

/// One output file: items and nested modules.
#[derive(Debug, Clone, Default)]
pub struct Module {
    /// Rust module name (empty for the top).
    pub name: String,
    /// Doc comment lines.
    pub doc: Vec<String>,
    /// What it holds, in output order.
    pub items: Vec<Item>,
}

/// One generated item.
#[derive(Debug, Clone)]
pub enum Item {
    /// `pub mod`.
    Module(Module),
    /// A struct deriving `IpcMessage`.
    Struct(StructDef),
    /// A fieldless enum deriving `IpcMessage`.
    Enum(EnumDef),
    /// `pub type A = T;`.
    Alias(AliasDef),
    /// `pub const A: T = v;`.
    Const(ConstDef),
}

/// XTypes extensibility of a struct's CDR encoding.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Extensibility {
    /// `@final`.
    Final,
    /// `@appendable`.
    Appendable,
    /// `@mutable`.
    Mutable,
}

/// A struct.
#[derive(Debug, Clone)]
pub struct StructDef {
    /// Rust name.
    pub name: String,
    /// Where it is defined.
    pub pos: Pos,
    /// Doc comment lines.
    pub doc: Vec<String>,
    /// `#[ipc(name)]` when the IPC format name is not the Rust name.
    pub format_name: Option<String>,
    /// `#[ipc(type_name)]`.
    pub type_name: Option<String>,
    /// `#[ipc(extensibility)]` (none: final).
    pub extensibility: Option<Extensibility>,
    /// A tuple struct (IPC formats name no fields).
    pub tuple: bool,
    /// The fields.
    pub fields: Vec<FieldDef>,
}

/// A struct field.
#[derive(Debug, Clone)]
pub struct FieldDef {
    /// Rust name (unused in tuple structs).
    pub name: String,
    /// Where it is declared.
    pub pos: Pos,
    /// Doc comment lines.
    pub doc: Vec<String>,
    /// Its type.
    pub ty: Ty,
    /// `#[ipc(len = "...")]`: the field (name, or index in a tuple struct)
    /// holding this `Vec`'s length.
    pub len: Option<String>,
    /// `#[ipc(key)]`.
    pub key: bool,
    /// `#[ipc(id = N)]`.
    pub id: Option<u32>,
    /// `#[ipc(must_understand)]`.
    pub must_understand: bool,
    /// `#[ipc(bound = N)]`: a bounded string or sequence.
    pub bound: Option<u32>,
}

impl FieldDef {
    /// A plain field of type `ty`.
    pub fn new(name: String, pos: Pos, ty: Ty) -> Self {
        FieldDef {
            name,
            pos,
            doc: Vec::new(),
            ty,
            len: None,
            key: false,
            id: None,
            must_understand: false,
            bound: None,
        }
    }
}

/// A fieldless enum.
#[derive(Debug, Clone)]
pub struct EnumDef {
    /// Rust name.
    pub name: String,
    /// Where it is defined.
    pub pos: Pos,
    /// Doc comment lines.
    pub doc: Vec<String>,
    /// `#[ipc(type_name)]`.
    pub type_name: Option<String>,
    /// `#[ipc(numeric)]`: `{enum : max}` rather than `{enum A, B}`.
    pub numeric: bool,
    /// Variants: name, explicit value, doc lines.
    pub variants: Vec<(String, Option<i64>, Vec<String>)>,
}

/// `pub type A = T;`.
#[derive(Debug, Clone)]
pub struct AliasDef {
    /// Rust name.
    pub name: String,
    /// Where it is defined.
    pub pos: Pos,
    /// Doc comment lines.
    pub doc: Vec<String>,
    /// What it stands for.
    pub ty: Ty,
}

/// `pub const A: T = v;`.
#[derive(Debug, Clone)]
pub struct ConstDef {
    /// Rust name.
    pub name: String,
    /// Where it is defined.
    pub pos: Pos,
    /// Doc comment lines.
    pub doc: Vec<String>,
    /// Rust type (`i32`, `&str`, a generated alias, …).
    pub ty: String,
    /// Rust expression.
    pub value: String,
}

impl Item {
    fn name_pos(&self) -> (&str, &Pos) {
        match self {
            Item::Module(m) => (&m.name, &DUMMY_POS),
            Item::Struct(s) => (&s.name, &s.pos),
            Item::Enum(e) => (&e.name, &e.pos),
            Item::Alias(a) => (&a.name, &a.pos),
            Item::Const(c) => (&c.name, &c.pos),
        }
    }
}

static DUMMY_POS: Pos = Pos {
    file: String::new(),
    line: 0,
    column: 0,
};

/// Checks the translated output and puts aliases' types in place of their
/// names in fields (the derive must see `Vec`, `Option<Box<..>>` and the
/// integer type of a count field as written).
pub fn finish(mut top: Module) -> Result<Module, GenError> {
    check_names(&top)?;
    let mut aliases = HashMap::new();
    collect_aliases(&top, &mut Vec::new(), &mut aliases);
    inline_aliases(&mut top, &aliases);
    let mut structs = BTreeMap::new();
    collect_structs(&top, &mut Vec::new(), &mut structs);
    check_recursion(&structs)?;
    Ok(top)
}

/// Two items of one module cannot have the same Rust name (types and
/// constants share no namespace in Rust, but distinct names keep the
/// output readable and IPC format names distinct).
fn check_names(m: &Module) -> Result<(), GenError> {
    let mut seen: HashMap<&str, &Item> = HashMap::new();
    for item in &m.items {
        let (name, pos) = item.name_pos();
        if let Some(first) = seen.get(name) {
            let first_pos = first.name_pos().1;
            if !matches!((item, first), (Item::Module(_), Item::Module(_))) {
                return Err(GenError::Duplicate {
                    pos: pos.clone(),
                    name: name.to_string(),
                    first: first_pos.clone(),
                });
            }
        }
        seen.insert(name, item);
        if let Item::Module(sub) = item {
            check_names(sub)?;
        }
    }
    Ok(())
}

fn collect_aliases(m: &Module, path: &mut Vec<String>, out: &mut HashMap<TypeRef, Ty>) {
    for item in &m.items {
        match item {
            Item::Alias(a) => {
                out.insert(
                    TypeRef {
                        module: path.clone(),
                        name: a.name.clone(),
                    },
                    a.ty.clone(),
                );
            }
            Item::Module(sub) => {
                path.push(sub.name.clone());
                collect_aliases(sub, path, out);
                path.pop();
            }
            _ => {}
        }
    }
}

/// `ty` with every alias replaced by what it stands for (aliases of
/// aliases too; the frontends refuse cycles of aliases).
fn expand(ty: &Ty, aliases: &HashMap<TypeRef, Ty>, depth: usize) -> Ty {
    if depth > 64 {
        return ty.clone();
    }
    match ty {
        Ty::Prim(_) => ty.clone(),
        Ty::Array(t, n) => Ty::Array(Box::new(expand(t, aliases, depth + 1)), *n),
        Ty::Vec(t) => Ty::Vec(Box::new(expand(t, aliases, depth + 1))),
        Ty::NdVec(t, n) => Ty::NdVec(Box::new(expand(t, aliases, depth + 1)), *n),
        Ty::Boxed(t) => Ty::Boxed(Box::new(expand(t, aliases, depth + 1))),
        Ty::Named(r) => match aliases.get(r) {
            Some(t) => expand(t, aliases, depth + 1),
            None => ty.clone(),
        },
    }
}

fn inline_aliases(m: &mut Module, aliases: &HashMap<TypeRef, Ty>) {
    for item in &mut m.items {
        match item {
            Item::Struct(s) => {
                for f in &mut s.fields {
                    f.ty = expand(&f.ty, aliases, 0);
                }
            }
            Item::Alias(a) => a.ty = expand(&a.ty, aliases, 0),
            Item::Module(sub) => inline_aliases(sub, aliases),
            _ => {}
        }
    }
}

fn collect_structs<'a>(
    m: &'a Module,
    path: &mut Vec<String>,
    out: &mut BTreeMap<TypeRef, &'a StructDef>,
) {
    for item in &m.items {
        match item {
            Item::Struct(s) => {
                out.insert(
                    TypeRef {
                        module: path.clone(),
                        name: s.name.clone(),
                    },
                    s,
                );
            }
            Item::Module(sub) => {
                path.push(sub.name.clone());
                collect_structs(sub, path, out);
                path.pop();
            }
            _ => {}
        }
    }
}

/// The generated types `ty` holds by value (not behind a `Vec` or a box).
fn by_value<'t>(ty: &'t Ty, out: &mut Vec<&'t TypeRef>) {
    match ty {
        Ty::Array(t, _) => by_value(t, out),
        Ty::Named(r) => out.push(r),
        Ty::Prim(_) | Ty::Vec(_) | Ty::NdVec(..) | Ty::Boxed(_) => {}
    }
}

fn check_recursion(structs: &BTreeMap<TypeRef, &StructDef>) -> Result<(), GenError> {
    // depth-first search with the current path; 0 = unseen, 1 = on the
    // path, 2 = done
    fn visit<'a>(
        r: &'a TypeRef,
        structs: &'a BTreeMap<TypeRef, &StructDef>,
        state: &mut HashMap<&'a TypeRef, u8>,
        path: &mut Vec<&'a TypeRef>,
    ) -> Result<(), GenError> {
        let Some((key, s)) = structs.get_key_value(r) else {
            return Ok(());
        };
        match state.get(key).copied().unwrap_or(0) {
            2 => return Ok(()),
            1 => {
                let start = path.iter().position(|p| *p == key).unwrap_or(0);
                let mut names: Vec<&str> = path[start..].iter().map(|p| p.name.as_str()).collect();
                names.push(&key.name);
                let first = structs.get(path[start]).map_or(s, |d| d);
                return Err(GenError::Recursive {
                    pos: first.pos.clone(),
                    name: first.name.clone(),
                    cycle: names.join(" -> "),
                });
            }
            _ => {}
        }
        state.insert(key, 1);
        path.push(key);
        let mut inner = Vec::new();
        for f in &s.fields {
            by_value(&f.ty, &mut inner);
        }
        for t in inner {
            visit(t, structs, state, path)?;
        }
        path.pop();
        state.insert(key, 2);
        Ok(())
    }
    let mut state = HashMap::new();
    for r in structs.keys() {
        visit(r, structs, &mut state, &mut Vec::new())?;
    }
    Ok(())
}
