//! Typed `#[ipc(...)]` attributes of containers, fields and variants.

use proc_macro2::Span;
use syn::meta::ParseNestedMeta;
use syn::{Attribute, LitInt, LitStr, Token};

use crate::ctxt::Ctxt;
use crate::names;

/// `#[ipc(extensibility = "...")]`.
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
pub enum Extensibility {
    Final,
    Appendable,
    Mutable,
}

/// Attributes on the struct or enum.
pub struct ContainerAttrs {
    /// `crate = "path"`: where the wire crate is.
    pub krate: Option<syn::Path>,
    /// `name = "..."`: the IPC format name.
    pub name: Option<(String, Span)>,
    /// `type_name = "..."`: the DDS type name.
    pub type_name: Option<String>,
    /// `numeric`: `{enum : max}` instead of `{enum A, B}`.
    pub numeric: Option<Span>,
    /// `extensibility = "final" | "appendable" | "mutable"`.
    pub extensibility: Option<(Extensibility, Span)>,
}

/// Attributes on a field.
pub struct FieldAttrs {
    /// `len = "field"`: the field that holds this `Vec`'s length;
    /// `len = "rows, cols"`: the fields that hold an `NdVec`'s shape.
    pub len: Option<LitStr>,
    /// `char`: this `u8` is an IPC `char`.
    pub char_: Option<Span>,
    /// `key`: a DDS key field.
    pub key: bool,
    /// `must_understand`: sets the XTypes must-understand flag (keys always have it).
    pub must_understand: bool,
    /// `id = N`: the member id (mutable extensibility).
    pub id: Option<(u32, Span)>,
    /// `bound = N`: at most N bytes of a `String`, N elements of a `Vec`.
    pub bound: Option<(u64, Span)>,
}

const CONTAINER_KEYS: &str = "`crate`, `name`, `type_name`, `numeric`, `extensibility`";
const FIELD_KEYS: &str = "`len`, `char`, `key`, `must_understand`, `id`, `bound`";

/// Skips the value of an unknown or misplaced key (`= expr` or `(...)`)
/// so that parsing can go on and report later problems too.
fn skip_value(meta: &ParseNestedMeta<'_>) -> syn::Result<()> {
    if meta.input.peek(Token![=]) {
        let _: syn::Expr = meta.value()?.parse()?;
    } else if meta.input.peek(syn::token::Paren) {
        meta.parse_nested_meta(|m| skip_value(&m))?;
    }
    Ok(())
}

/// Reports a value given to a flag (`#[ipc(key = true)]`), which would
/// otherwise be a bare "expected `,`", and skips it.
fn no_value(cx: &Ctxt, meta: &ParseNestedMeta<'_>) -> syn::Result<()> {
    if meta.input.peek(Token![=]) || meta.input.peek(syn::token::Paren) {
        let name = key_name(meta);
        cx.error_spanned_by(
            &meta.path,
            format!("`{name}` takes no value; write `#[ipc({name})]`"),
        );
        skip_value(meta)?;
    }
    Ok(())
}

fn key_name(meta: &ParseNestedMeta<'_>) -> String {
    let p = &meta.path;
    quote::quote!(#p).to_string().replace(' ', "")
}

/// Reports a key given twice (`#[ipc(char, char)]`, or across two
/// `#[ipc(...)]` attributes): the second would silently win.
fn duplicate(cx: &Ctxt, meta: &ParseNestedMeta<'_>, seen: &mut Vec<String>) {
    let name = key_name(meta);
    if seen.contains(&name) {
        cx.error_spanned_by(&meta.path, format!("duplicate `ipc` attribute `{name}`"));
    } else {
        seen.push(name);
    }
}

fn ipc_attrs(attrs: &[Attribute]) -> impl Iterator<Item = &Attribute> {
    attrs.iter().filter(|a| a.path().is_ident("ipc"))
}

/// Parses the container's `#[ipc(...)]` attributes.
pub fn container(cx: &Ctxt, attrs: &[Attribute], is_enum: bool) -> ContainerAttrs {
    let mut out = ContainerAttrs {
        krate: None,
        name: None,
        type_name: None,
        numeric: None,
        extensibility: None,
    };
    let mut seen: Vec<String> = Vec::new();
    for attr in ipc_attrs(attrs) {
        let r = attr.parse_nested_meta(|meta| {
            duplicate(cx, &meta, &mut seen);
            if meta.path.is_ident("crate") {
                let s: LitStr = meta.value()?.parse()?;
                match s.parse::<syn::Path>() {
                    Ok(p) => out.krate = Some(p),
                    Err(_) => cx.error_spanned_by(
                        &s,
                        "`crate` must be a path to the wire crate, e.g. `crate = \"::courier::__wire\"` or `crate = \"::courier_wire\"`",
                    ),
                }
            } else if meta.path.is_ident("name") {
                let s: LitStr = meta.value()?.parse()?;
                let v = s.value();
                if let Some(problem) = names::format_name_problem(&v) {
                    cx.error_spanned_by(&s, problem);
                } else if is_enum {
                    cx.error_spanned_by(
                        &meta.path,
                        "`name` applies to structs: enums are written inline (`{enum ...}`) and have no format name",
                    );
                } else {
                    out.name = Some((v, s.span()));
                }
            } else if meta.path.is_ident("type_name") {
                let s: LitStr = meta.value()?.parse()?;
                if s.value().is_empty() {
                    cx.error_spanned_by(&s, "`type_name` must not be empty");
                } else {
                    out.type_name = Some(s.value());
                }
            } else if meta.path.is_ident("numeric") {
                no_value(cx, &meta)?;
                if !is_enum {
                    cx.error_spanned_by(
                        &meta.path,
                        "`numeric` applies to fieldless enums (it selects the `{enum : max}` form)",
                    );
                }
                out.numeric = Some(meta.path.require_ident()?.span());
            } else if meta.path.is_ident("extensibility") {
                let s: LitStr = meta.value()?.parse()?;
                let e = match s.value().as_str() {
                    "final" => Some(Extensibility::Final),
                    "appendable" => Some(Extensibility::Appendable),
                    "mutable" => Some(Extensibility::Mutable),
                    _ => None,
                };
                match e {
                    None => cx.error_spanned_by(
                        &s,
                        "`extensibility` must be \"final\", \"appendable\" or \"mutable\"",
                    ),
                    Some(_) if is_enum => cx.error_spanned_by(
                        &meta.path,
                        "`extensibility` applies to structs: an enum is always encoded as an int32",
                    ),
                    Some(e) => out.extensibility = Some((e, s.span())),
                }
            } else if matches!(key_name(&meta).as_str(), "len" | "char" | "key" | "must_understand" | "id" | "bound") {
                cx.error_spanned_by(
                    &meta.path,
                    format!(
                        "`{}` is a field attribute: put `#[ipc({})]` on a field, not on the {}",
                        key_name(&meta),
                        key_name(&meta),
                        if is_enum { "enum" } else { "struct" }
                    ),
                );
                skip_value(&meta)?;
            } else {
                cx.error_spanned_by(
                    &meta.path,
                    format!(
                        "unknown `ipc` attribute `{}`; expected one of {CONTAINER_KEYS}",
                        key_name(&meta)
                    ),
                );
                skip_value(&meta)?;
            }
            Ok(())
        });
        if let Err(e) = r {
            cx.syn_error(e);
        }
    }
    out
}

/// Parses a field's `#[ipc(...)]` attributes.
pub fn field(cx: &Ctxt, attrs: &[Attribute]) -> FieldAttrs {
    let mut out = FieldAttrs {
        len: None,
        char_: None,
        key: false,
        must_understand: false,
        id: None,
        bound: None,
    };
    let mut seen: Vec<String> = Vec::new();
    for attr in ipc_attrs(attrs) {
        let r = attr.parse_nested_meta(|meta| {
            duplicate(cx, &meta, &mut seen);
            if meta.path.is_ident("len") {
                out.len = Some(meta.value()?.parse()?);
            } else if meta.path.is_ident("char") {
                no_value(cx, &meta)?;
                out.char_ = Some(meta.path.require_ident()?.span());
            } else if meta.path.is_ident("key") {
                no_value(cx, &meta)?;
                out.key = true;
            } else if meta.path.is_ident("must_understand") {
                no_value(cx, &meta)?;
                out.must_understand = true;
            } else if meta.path.is_ident("id") {
                let n: LitInt = meta.value()?.parse()?;
                match n.base10_parse::<u32>() {
                    Ok(v) if v <= 0x0fff_ffff => out.id = Some((v, n.span())),
                    _ => cx.error_spanned_by(&n, "member `id` must be an integer from 0 to 0x0fffffff (28 bits)"),
                }
            } else if meta.path.is_ident("bound") {
                let n: LitInt = meta.value()?.parse()?;
                match n.base10_parse::<u64>() {
                    Ok(v) if (1..=0x7fff_ffff).contains(&v) => out.bound = Some((v, n.span())),
                    _ => cx.error_spanned_by(&n, "`bound` must be an integer from 1 to 2147483647 (IDL `string<N>`, `sequence<T, N>`)"),
                }
            } else if matches!(
                key_name(&meta).as_str(),
                "crate" | "name" | "type_name" | "numeric" | "extensibility"
            ) {
                cx.error_spanned_by(
                    &meta.path,
                    format!(
                        "`{}` is a container attribute: put it on the struct or enum, not on a field",
                        key_name(&meta)
                    ),
                );
                skip_value(&meta)?;
            } else {
                cx.error_spanned_by(
                    &meta.path,
                    format!(
                        "unknown `ipc` field attribute `{}`; expected one of {FIELD_KEYS}",
                        key_name(&meta)
                    ),
                );
                skip_value(&meta)?;
            }
            Ok(())
        });
        if let Err(e) = r {
            cx.syn_error(e);
        }
    }
    out
}

/// Enum variants take no `#[ipc(...)]` attributes.
pub fn variant(cx: &Ctxt, attrs: &[Attribute]) {
    for attr in ipc_attrs(attrs) {
        cx.error_spanned_by(
            attr,
            "enum variants take no `#[ipc(...)]` attributes; give an explicit discriminant (`A = 5`) to set its value",
        );
    }
}
