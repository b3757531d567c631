//! The derive input parsed once into a typed AST, with every check that
//! does not need type information. Code generation works from this AST only.

use proc_macro2::Span;
use syn::ext::IdentExt;
use syn::{DeriveInput, GenericArgument, Ident, PathArguments, Type};

use crate::attr::{self, ContainerAttrs, Extensibility, FieldAttrs};
use crate::ctxt::Ctxt;
use crate::names;

/// A struct or enum deriving `IpcMessage`.
pub struct Container<'a> {
    pub ident: &'a Ident,
    pub generics: &'a syn::Generics,
    pub attrs: ContainerAttrs,
    pub data: Data<'a>,
}

pub enum Data<'a> {
    /// Named, tuple and unit structs (a unit struct has no fields).
    Struct(Vec<Field<'a>>),
    /// A fieldless enum.
    Enum(Enum<'a>),
}

pub struct Enum<'a> {
    pub variants: Vec<Variant<'a>>,
    /// `{enum : max}` rather than `{enum A, B, C}`.
    pub numeric: bool,
}

pub struct Variant<'a> {
    pub ident: &'a Ident,
    pub value: i64,
}

/// How a field is written in the format and on the wire.
pub enum Kind<'a> {
    /// Through the field type's own `IpcMessage` impl.
    Plain,
    /// `#[ipc(char)] u8`: IPC `char`.
    Char,
    /// `Option<Box<Self>>`: IPC `*!`.
    SelfPtr,
    /// `Vec<T>`: IPC `<T:k>`; `len` is the index of the length field.
    Vec { elem: &'a Type, len: Option<usize> },
    /// A field with several `len` names, IPC `<T:k1,k2,…>`: a type
    /// implementing `__private::NdField` (`NdVec<T, N>`), checked by the
    /// compiler; `dims` are the indices of the size fields, in order.
    NdVec { dims: Vec<usize> },
}

pub struct Field<'a> {
    /// `self.<member>`.
    pub member: syn::Member,
    /// The field's name (`"0"`, `"1"`, ... for tuple structs).
    pub name: String,
    pub ty: &'a Type,
    pub attrs: FieldAttrs,
    pub kind: Kind<'a>,
    /// Index of the `Vec` (or `NdVec`) field whose length this field holds.
    pub count_for: Option<usize>,
    /// Which dimension of that `NdVec` (0 for a `Vec`).
    pub count_dim: usize,
    /// Member id (CDR mutable extensibility).
    pub id: u32,
    /// `Option<Box<T>>`: an `@optional` member (absent members of a mutable
    /// struct are left out on the wire and decode to `None`).
    pub optional: bool,
    pub span: Span,
}

impl Container<'_> {
    pub fn extensibility(&self) -> Extensibility {
        self.attrs
            .extensibility
            .map_or(Extensibility::Final, |(e, _)| e)
    }
}

const INTEGERS: &[&str] = &["i8", "i16", "i32", "i64", "u8", "u16", "u32", "u64"];

/// Parses and checks the input; problems go to `cx`. Returns `None` if the
/// input cannot be represented at all.
pub fn parse<'a>(cx: &Ctxt, input: &'a DeriveInput) -> Option<Container<'a>> {
    let is_enum = matches!(input.data, syn::Data::Enum(_));
    let attrs = attr::container(cx, &input.attrs, is_enum);

    for p in &input.generics.params {
        if let syn::GenericParam::Lifetime(l) = p {
            cx.error_spanned_by(
                l,
                "`IpcMessage` types own their data (decoding creates them): lifetime parameters are not supported; use owned types such as `String` and `Vec<T>`",
            );
        }
    }

    if let (Some((_, span)), syn::Data::Struct(s)) = (&attrs.name, &input.data) {
        if input.generics.type_params().next().is_some()
            || input.generics.const_params().next().is_some()
        {
            cx.error_at(
                *span,
                "a generic struct has one format per instantiation and is written inline: it cannot have a format `name`",
            );
        } else if s.fields.is_empty() {
            cx.error_at(
                *span,
                "a struct without fields is the empty message (format \"\") and has no format `name`",
            );
        }
    }

    // A named struct's format name is its identifier unless `name` gives another.
    if let (None, syn::Data::Struct(s)) = (&attrs.name, &input.data) {
        let generic = input.generics.type_params().next().is_some()
            || input.generics.const_params().next().is_some();
        if !generic && !s.fields.is_empty() {
            if let Some(problem) = names::format_name_problem(&input.ident.unraw().to_string()) {
                cx.error_spanned_by(
                    &input.ident,
                    format!(
                        "{problem}; a struct's format name is its identifier: give it another with `#[ipc(name = \"...\")]`"
                    ),
                );
            }
        }
    }

    let data = match &input.data {
        syn::Data::Struct(s) => Data::Struct(struct_fields(cx, input, &s.fields)),
        syn::Data::Enum(e) => Data::Enum(enum_variants(cx, input, e, attrs.numeric.is_some())?),
        syn::Data::Union(u) => {
            cx.error_spanned_by(
                u.union_token,
                "`#[derive(IpcMessage)]` does not support unions: IPC formats have no union type; use a struct or a fieldless enum",
            );
            return None;
        }
    };
    Some(Container {
        ident: &input.ident,
        generics: &input.generics,
        attrs,
        data,
    })
}

fn enum_variants<'a>(
    cx: &Ctxt,
    input: &'a DeriveInput,
    e: &'a syn::DataEnum,
    numeric_attr: bool,
) -> Option<Enum<'a>> {
    if e.variants.is_empty() {
        cx.error_spanned_by(
            &input.ident,
            "an `IpcMessage` enum needs at least one variant (`{enum ...}` cannot be empty)",
        );
        return None;
    }
    let mut variants = Vec::new();
    let mut next: i64 = 0;
    let mut explicit = false;
    for v in &e.variants {
        attr::variant(cx, &v.attrs);
        if !matches!(v.fields, syn::Fields::Unit) {
            cx.error_spanned_by(
                &v.fields,
                format!(
                    "variant `{}` carries data, but `IpcMessage` enums must be fieldless: an IPC `{{enum ...}}` is a bare int32; use a struct with a fieldless enum tag and the data as fields instead",
                    v.ident.unraw()
                ),
            );
        }
        let value = match &v.discriminant {
            None if next > i64::from(i32::MAX) => {
                cx.error_spanned_by(
                    &v.ident,
                    format!(
                        "variant `{}` comes after a variant of value {}, so its implicit value {next} does not fit in an int32 (IPC sends enums as C ints); give it an explicit value below 2147483648, or reorder the variants",
                        v.ident.unraw(),
                        next - 1
                    ),
                );
                next
            }
            None => next,
            Some((_, expr)) => {
                explicit = true;
                match discriminant(expr) {
                    Some(n) if n < 0 => {
                        cx.error_spanned_by(
                            expr,
                            format!(
                                "negative discriminant {n}: IPC enums count from 0 (`{{enum : max}}`); for negative values use an `i32` field instead of an enum"
                            ),
                        );
                        n
                    }
                    Some(n) if n > i64::from(i32::MAX) => {
                        cx.error_spanned_by(
                            expr,
                            "enum discriminants must fit in an int32 (IPC sends enums as C ints)",
                        );
                        n
                    }
                    Some(n) => n,
                    None => {
                        cx.error_spanned_by(
                            expr,
                            "`IpcMessage` needs enum discriminants written as integer literals (e.g. `A = 3`)",
                        );
                        next
                    }
                }
            }
        };
        next = value.saturating_add(1);
        variants.push(Variant {
            ident: &v.ident,
            value,
        });
    }
    Some(Enum {
        variants,
        numeric: numeric_attr || explicit,
    })
}

fn discriminant(e: &syn::Expr) -> Option<i64> {
    match e {
        syn::Expr::Lit(syn::ExprLit {
            lit: syn::Lit::Int(i),
            ..
        }) => i.base10_parse::<i64>().ok(),
        syn::Expr::Unary(syn::ExprUnary {
            op: syn::UnOp::Neg(_),
            expr,
            ..
        }) => discriminant(expr).map(|n| -n),
        syn::Expr::Paren(p) => discriminant(&p.expr),
        syn::Expr::Group(g) => discriminant(&g.expr),
        _ => None,
    }
}

fn struct_fields<'a>(cx: &Ctxt, input: &'a DeriveInput, fields: &'a syn::Fields) -> Vec<Field<'a>> {
    let mut out: Vec<Field<'a>> = Vec::new();
    let mut next_id: u32 = 0;
    for (i, f) in fields.iter().enumerate() {
        let attrs = attr::field(cx, &f.attrs);
        let (member, name) = match &f.ident {
            // `r#type` is the member `type` on the wire and in `len`
            Some(id) => (syn::Member::Named(id.clone()), id.unraw().to_string()),
            None => (syn::Member::Unnamed(syn::Index::from(i)), i.to_string()),
        };
        let kind = field_kind(cx, input, f, &attrs);
        let id = match attrs.id {
            Some((id, _)) => id,
            None => next_id,
        };
        next_id = id.saturating_add(1);
        let optional = matches!(generic_arg(&f.ty, "Option"), Some(Some(inner)) if generic_arg(inner, "Box").is_some());
        if optional && attrs.key {
            cx.error_spanned_by(
                &f.ty,
                format!(
                    "`{name}` cannot be a key field: `Option<Box<T>>` is an optional member (IDL `@optional`), and XTypes forbids optional keys; make the key a plain `T` field"
                ),
            );
        }
        out.push(Field {
            member,
            name,
            ty: &f.ty,
            attrs,
            kind,
            count_for: None,
            count_dim: 0,
            id,
            optional,
            span: syn::spanned::Spanned::span(f),
        });
    }

    // Resolve `len = "..."` and check the length fields.
    for i in 0..out.len() {
        let Some(lit) = out[i].attrs.len.clone() else {
            continue;
        };
        if matches!(out[i].kind, Kind::NdVec { .. }) {
            resolve_dims(cx, input, &mut out, i, &lit);
            continue;
        }
        if !matches!(out[i].kind, Kind::Vec { .. }) {
            continue; // reported in field_kind
        }
        let want = unraw_name(&lit.value());
        if want.contains(',') {
            continue; // several names on a `Vec`: reported in field_kind
        }
        let Some(j) = out.iter().position(|f| f.name == want) else {
            let names: Vec<String> = out
                .iter()
                .filter(|f| is_integer(f.ty) && f.attrs.char_.is_none())
                .map(|f| format!("`{}`", f.name))
                .collect();
            let hint = if names.is_empty() {
                "add an integer field (e.g. `count: i32`) that holds the length".to_string()
            } else {
                format!("integer fields here: {}", names.join(", "))
            };
            cx.error_spanned_by(
                &lit,
                format!(
                    "`len` names `{want}`, but `{}` has no such field; {hint}",
                    input.ident.unraw()
                ),
            );
            continue;
        };
        if j == i || !is_integer(out[j].ty) || out[j].attrs.char_.is_some() {
            let ty = out[j].ty;
            cx.error_spanned_by(
                &lit,
                format!(
                    "length field `{want}` has type `{}`; the length of a variable array must live in an integer field (i8, i16, i32, i64, u8, u16, u32 or u64){}",
                    type_string(ty),
                    unresolved_hint(ty)
                ),
            );
            continue;
        }
        if let Some(other) = out[j].count_for {
            cx.error_spanned_by(
                &lit,
                format!(
                    "field `{want}` already holds the length of `{}`; each variable array needs its own length field",
                    out[other].name
                ),
            );
            continue;
        }
        out[j].count_for = Some(i);
        if let Kind::Vec { len, .. } = &mut out[i].kind {
            *len = Some(j);
        }
    }

    // Member ids must be unique.
    for i in 0..out.len() {
        for j in 0..i {
            if out[i].id == out[j].id {
                let span = out[i].attrs.id.map_or(out[i].span, |(_, s)| s);
                cx.error_at(
                    span,
                    format!(
                        "member id {} of `{}` is already used by `{}`; give each field its own `#[ipc(id = N)]`",
                        out[i].id, out[i].name, out[j].name
                    ),
                );
            }
        }
    }
    out
}

/// Size fields of a C `int` or wider, which hold any dimension of an IPC
/// array (at most `i32::MAX`): C's IPC reads them as `int`.
const DIM_INTEGERS: &[&str] = &["i32", "u32", "i64", "u64"];

/// Resolves `len = "k1, k2, …"` of the `NdVec` field `i`.
fn resolve_dims(
    cx: &Ctxt,
    input: &DeriveInput,
    out: &mut [Field<'_>],
    i: usize,
    lit: &syn::LitStr,
) {
    let names: Vec<String> = lit
        .value()
        .split(',')
        .map(|n| unraw_name(n.trim()))
        .collect();
    if names.iter().any(String::is_empty) {
        cx.error_spanned_by(
            lit,
            format!(
                "`len = {:?}` has an empty field name; write the size fields separated by commas, e.g. `len = \"rows, cols\"`",
                lit.value()
            ),
        );
        return;
    }
    if out[i].attrs.key {
        cx.error_spanned_by(
            lit,
            format!(
                "`{}` cannot be a key field: a multi-dimensional array has no DDS key form",
                out[i].name
            ),
        );
    }
    let mut dims = Vec::new();
    for (d, want) in names.iter().enumerate() {
        let Some(j) = out.iter().position(|f| &f.name == want) else {
            cx.error_spanned_by(
                lit,
                format!(
                    "`len` names `{want}`, but `{}` has no such field",
                    input.ident.unraw()
                ),
            );
            continue;
        };
        let is_dim_integer =
            integer_name(out[j].ty).is_some_and(|n| DIM_INTEGERS.contains(&n.as_str()));
        if j == i || !is_dim_integer {
            let ty = out[j].ty;
            cx.error_spanned_by(
                lit,
                format!(
                    "size field `{want}` has type `{}`; the dimensions of a multi-dimensional array live in i32, u32, i64 or u64 fields (C's IPC reads them as `int`){}",
                    type_string(ty),
                    unresolved_hint(ty)
                ),
            );
            continue;
        }
        if names[..d].contains(want) {
            cx.error_spanned_by(
                lit,
                format!("`len` names `{want}` twice; each dimension needs its own size field"),
            );
            continue;
        }
        if let Some(other) = out[j].count_for {
            cx.error_spanned_by(
                lit,
                format!(
                    "field `{want}` already holds the length of `{}`; each variable array needs its own size fields",
                    out[other].name
                ),
            );
            continue;
        }
        if out[j].attrs.key {
            cx.error_spanned_by(
                lit,
                format!("size field `{want}` cannot be a key field: the array it sizes has no DDS key form"),
            );
        }
        out[j].count_for = Some(i);
        out[j].count_dim = d;
        dims.push(j);
    }
    if let Kind::NdVec { dims: slot } = &mut out[i].kind {
        *slot = dims;
    }
}

fn is_integer(ty: &Type) -> bool {
    integer_name(ty).is_some_and(|n| INTEGERS.contains(&n.as_str()))
}

/// `len = "r#n"` names the field `r#n`, which is `n` everywhere else.
fn unraw_name(name: &str) -> String {
    name.strip_prefix("r#").unwrap_or(name).to_string()
}

fn type_string(ty: &Type) -> String {
    quote::quote!(#ty).to_string().replace(' ', "")
}

/// The primitive type a length field is written as: `u32`, or the same
/// through `std::primitive::u32` / `core::primitive::u32`. Other paths and
/// aliases are not resolved: the derive sees tokens, not types.
fn integer_name(ty: &Type) -> Option<String> {
    match ty {
        Type::Path(p) if p.qself.is_none() => {
            let segs = &p.path.segments;
            if segs.iter().any(|s| !s.arguments.is_none()) {
                return None;
            }
            let names: Vec<String> = segs.iter().map(|s| s.ident.to_string()).collect();
            let name = match names.as_slice() {
                [n] if p.path.leading_colon.is_none() => n,
                [krate, prim, n] if (krate == "std" || krate == "core") && prim == "primitive" => n,
                _ => return None,
            };
            INTEGERS.contains(&name.as_str()).then(|| name.clone())
        }
        Type::Group(g) => integer_name(&g.elem),
        Type::Paren(p) => integer_name(&p.elem),
        _ => None,
    }
}

/// For a length field refused because of how its type is written (an
/// alias, or a path other than `std::primitive::X`): how to write it.
fn unresolved_hint(ty: &Type) -> String {
    const NOT_INTEGERS: &[&str] = &[
        "String", "f32", "f64", "bool", "char", "Vec", "Option", "Box", "NdVec", "Matrix", "usize",
        "isize", "i128", "u128",
    ];
    let Type::Path(p) = ty else {
        return String::new();
    };
    if integer_name(ty).is_some() {
        return String::new(); // understood, but not an integer type that fits
    }
    let Some(last) = p.path.segments.last() else {
        return String::new();
    };
    let last = last.ident.to_string();
    if p.path.segments.len() > 1 || p.path.leading_colon.is_some() {
        let example = if INTEGERS.contains(&last.as_str()) {
            last
        } else {
            "i32".to_string()
        };
        format!(
            "; the derive sees tokens, not types, and does not resolve paths or type aliases: write the integer type by its name (`{example}`, or `std::primitive::{example}`)"
        )
    } else if NOT_INTEGERS.contains(&last.as_str()) {
        String::new()
    } else {
        format!(
            "; if `{last}` is a type alias, write the integer type by its name instead (e.g. `i32`): the derive sees tokens, not types, and does not resolve type aliases"
        )
    }
}

fn is_self_type(input: &DeriveInput, ty: &Type) -> bool {
    match ty {
        Type::Path(p) if p.qself.is_none() && p.path.segments.len() == 1 => {
            let seg = &p.path.segments[0];
            seg.ident == "Self" || seg.ident == input.ident
        }
        Type::Group(g) => is_self_type(input, &g.elem),
        Type::Paren(p) => is_self_type(input, &p.elem),
        _ => false,
    }
}

/// The single type argument of `Name<T>` if `ty` is a path ending in `Name`.
fn generic_arg<'a>(ty: &'a Type, name: &str) -> Option<Option<&'a Type>> {
    let Type::Path(p) = ty else { return None };
    if p.qself.is_some() {
        return None;
    }
    let seg = p.path.segments.last()?;
    if seg.ident != name {
        return None;
    }
    let PathArguments::AngleBracketed(a) = &seg.arguments else {
        return Some(None);
    };
    let mut types = a.args.iter().filter_map(|g| match g {
        GenericArgument::Type(t) => Some(t),
        _ => None,
    });
    Some(types.next())
}

fn field_kind<'a>(
    cx: &Ctxt,
    input: &DeriveInput,
    f: &'a syn::Field,
    attrs: &FieldAttrs,
) -> Kind<'a> {
    let ty = &f.ty;
    let mut kind = Kind::Plain;
    if let Some(elem) = generic_arg(ty, "Vec") {
        match elem {
            Some(elem) => {
                check_type(cx, input, elem);
                // without `len`: a DDS `sequence<T>` (CDR only: its IPC
                // format `<T:0>` names no count field, so IPC refuses it)
                kind = Kind::Vec { elem, len: None };
            }
            None => cx.error_spanned_by(ty, "`Vec` needs its element type"),
        }
    } else if let Some(Some(inner)) = generic_arg(ty, "Option") {
        match generic_arg(inner, "Box") {
            Some(Some(b)) if is_self_type(input, b) => kind = Kind::SelfPtr,
            _ => check_type(cx, input, ty),
        }
    } else {
        check_type(cx, input, ty);
    }
    // (`Matrix<T>` is left to the compiler: users have their own types of that name)
    if attrs.len.is_none() && matches!(generic_arg(ty, "NdVec"), Some(Some(_))) {
        cx.error_spanned_by(
            ty,
            "an `NdVec` is IPC `<T:k1,k2,…>`: name the fields that hold its shape, one per dimension, e.g. `#[ipc(len = \"rows, cols\")]`",
        );
    }
    if let Some(lit) = &attrs.len {
        if lit.value().contains(',') {
            if matches!(kind, Kind::Vec { .. }) {
                cx.error_spanned_by(
                    lit,
                    "a `Vec` has one dimension, so `len` names one field; for `<T:k1,k2,…>` use `courier::NdVec<T, N>` (`courier::Matrix<T>` for two dimensions)",
                );
            } else {
                kind = Kind::NdVec { dims: Vec::new() };
            }
        } else if !matches!(kind, Kind::Vec { .. }) {
            cx.error_spanned_by(
                lit,
                "`len` applies only to `Vec<T>` fields (IPC variable arrays), or with several fields to `NdVec<T, N>`",
            );
        }
    }
    if let Some((_, span)) = attrs.bound {
        if !matches!(kind, Kind::Vec { .. }) && !is_string(ty) {
            cx.error_at(
                span,
                "`bound` applies to `String` and `Vec<T>` fields (IDL `string<N>`, `sequence<T, N>`); an array's length is its type's",
            );
        }
    }
    if let Some(span) = attrs.char_ {
        if is_u8(ty) {
            kind = Kind::Char;
        } else {
            cx.error_at(
                span,
                "`char` applies to `u8` fields (IPC `char`); for arrays of characters use `[char; N]`",
            );
        }
    }
    kind
}

fn is_u8(ty: &Type) -> bool {
    matches!(ty, Type::Path(p) if p.qself.is_none() && p.path.is_ident("u8"))
}

/// Rejects types that have no IPC form, with a hint about what to use.
fn check_type(cx: &Ctxt, input: &DeriveInput, ty: &Type) {
    match ty {
        Type::Reference(_) => cx.error_spanned_by(
            ty,
            "references cannot be decoded into: use an owned type (`String` for `&str`, `Vec<T>` with `#[ipc(len)]` for `&[T]`, `T` or `Box<T>` for `&T`)",
        ),
        Type::Ptr(_) => cx.error_spanned_by(
            ty,
            "raw pointers have no IPC encoding: use `Option<Box<T>>` for an IPC pointer `*T`",
        ),
        Type::Tuple(_) => cx.error_spanned_by(
            ty,
            "tuples have no IPC format: use a struct (IPC `{...}`) that derives `IpcMessage`",
        ),
        Type::Slice(_) => cx.error_spanned_by(
            ty,
            "slices have no IPC form: use `Vec<T>` with `#[ipc(len = \"count\")]` or a fixed array `[T; N]`",
        ),
        Type::BareFn(_) | Type::TraitObject(_) | Type::ImplTrait(_) | Type::Never(_) | Type::Infer(_) => {
            cx.error_spanned_by(ty, "this type has no IPC format: use plain data (numbers, `String`, arrays, structs)")
        }
        Type::Array(a) => {
            if generic_arg(&a.elem, "Vec").is_some() {
                cx.error_spanned_by(
                    &a.elem,
                    "a `Vec` can only be a direct struct field (IPC variable arrays `<T:k>` take their length from a field of the enclosing struct)",
                );
            } else {
                check_type(cx, input, &a.elem);
            }
        }
        Type::Group(g) => check_type(cx, input, &g.elem),
        Type::Paren(p) => check_type(cx, input, &p.elem),
        Type::Path(p) if p.qself.is_none() => {
            let Some(seg) = p.path.segments.last() else { return };
            let name = seg.ident.to_string();
            match name.as_str() {
                "usize" | "isize" => cx.error_spanned_by(
                    ty,
                    format!(
                        "`{name}` has no fixed size on the wire: use `{}32` (IPC `{}int`) or `{}64` (IPC `{}long`)",
                        &name[..1],
                        if name == "usize" { "u" } else { "" },
                        &name[..1],
                        if name == "usize" { "u" } else { "" },
                    ),
                ),
                "i128" | "u128" => cx.error_spanned_by(
                    ty,
                    "IPC has no 128-bit integers: use `i64`/`u64` (IPC `long`/`ulong`) or an array `[u64; 2]`",
                ),
                "str" => cx.error_spanned_by(ty, "use `String` for an IPC `string`"),
                "HashMap" | "BTreeMap" | "HashSet" | "BTreeSet" | "IndexMap" | "IndexSet" => cx.error_spanned_by(
                    ty,
                    format!(
                        "`{name}` has no IPC format: use a `Vec` of key/value structs with `#[ipc(len = \"count\")]`"
                    ),
                ),
                "VecDeque" | "LinkedList" | "BinaryHeap" => cx.error_spanned_by(
                    ty,
                    format!("`{name}` has no IPC format: use a `Vec` field with `#[ipc(len = \"count\")]`"),
                ),
                "Vec" => cx.error_spanned_by(
                    ty,
                    "a `Vec` can only be a direct struct field (IPC variable arrays `<T:k>` take their length from a field of the enclosing struct)",
                ),
                "Option" => match generic_arg(ty, "Option").flatten() {
                    Some(inner) if generic_arg(inner, "Box").is_some() => check_type(cx, input, inner),
                    Some(inner) if is_string(inner) => {}
                    _ => cx.error_spanned_by(
                        ty,
                        "`Option<T>` maps to IPC only as `Option<Box<T>>` (pointer `*T`, NULL = `None`) or `Option<String>` (`string`, NULL = `None`)",
                    ),
                },
                "Box" => {
                    if let Some(Some(inner)) = generic_arg(ty, "Box") {
                        if !is_self_type(input, inner) {
                            check_type(cx, input, inner);
                        }
                    }
                }
                _ => {}
            }
        }
        _ => {}
    }
}

fn is_string(ty: &Type) -> bool {
    matches!(ty, Type::Path(p) if p.qself.is_none() && p.path.segments.last().is_some_and(|s| s.ident == "String"))
}
