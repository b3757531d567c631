//! Type information besides the format: the DDS type name, the CDR
//! extensibility, the smallest encoded sizes, the largest key-hash form of
//! a value and of its key (one `cdr::MaxSize` measures it in XCDR1 and in
//! XCDR2: the derive composes its fields' and the constructors lay each
//! version out), and the key fields.

use proc_macro2::{TokenStream, TokenTree};
use quote::quote;
use syn::ext::IdentExt;

use crate::ast::{Container, Field, Kind};
use crate::attr::Extensibility;

/// `TYPE_NAME`: the attribute, or the Rust path (plus `<params>` for generics),
/// as hidden inherent constants when it must be built at compile time.
pub(super) fn type_name(c: &Container<'_>) -> (TokenStream, TokenStream) {
    // `r#type` is the type `type`
    let ident = c.ident.unraw().to_string();
    if let Some(t) = &c.attrs.type_name {
        return (quote!(#t), quote!());
    }
    // Type and const parameters in declaration order: `Buf<4>` and `Buf<8>`
    // lay their data out differently, so they must not share a name (DDS
    // would match their endpoints).
    let params: Vec<TokenStream> = c
        .generics
        .params
        .iter()
        .filter_map(|p| match p {
            syn::GenericParam::Type(t) => {
                let p = &t.ident;
                Some(quote!(push_str(<#p as __wire::IpcMessage>::TYPE_NAME)))
            }
            syn::GenericParam::Const(k) => Some(const_param_name(k)),
            syn::GenericParam::Lifetime(_) => None,
        })
        .collect();
    let base = quote!(::core::concat!(::core::module_path!(), "::", #ident));
    if params.is_empty() {
        return (base, quote!());
    }
    let mut build = quote!(__wire::__private::ConstStr::new().push_str(#base).push_str("<"));
    for (i, p) in params.iter().enumerate() {
        if i > 0 {
            build = quote!(#build.push_str(", "));
        }
        build = quote!(#build.#p);
    }
    build = quote!(#build.push_str(">"));
    let consts = quote! {
        const __COURIER_TYPE_NAME: __wire::__private::ConstStr = #build;
        const __COURIER_TYPE_NAME_REF: &'static __wire::__private::ConstStr = &Self::__COURIER_TYPE_NAME;
        const __COURIER_TYPE_NAME_STR: &'static str = Self::__COURIER_TYPE_NAME_REF.as_str();
    };
    (quote!(Self::__COURIER_TYPE_NAME_STR), consts)
}

/// The `ConstStr` call that appends a const parameter's value: Rust's
/// const parameters are integers, `bool` or `char`.
fn const_param_name(k: &syn::ConstParam) -> TokenStream {
    let n = &k.ident;
    let prim = match &k.ty {
        syn::Type::Path(p) if p.qself.is_none() => {
            p.path.segments.last().map(|s| s.ident.to_string())
        }
        _ => None,
    };
    match prim.as_deref() {
        Some("bool") => quote!(push_bool(#n)),
        Some("char") => quote!(push_char(#n)),
        Some("i8" | "i16" | "i32" | "i64" | "i128" | "isize") => quote!(push_i128(#n as i128)),
        _ => quote!(push_u128(#n as u128)),
    }
}

pub(super) fn ext_tokens(e: Extensibility) -> TokenStream {
    match e {
        Extensibility::Final => quote!(__wire::cdr::Extensibility::Final),
        Extensibility::Appendable => quote!(__wire::cdr::Extensibility::Appendable),
        Extensibility::Mutable => quote!(__wire::cdr::Extensibility::Mutable),
    }
}

/// The terms of a struct's size constants, one per field (after a first
/// neutral one): `IPC_MIN_SIZE` and `CDR_MIN_SIZE` add them up;
/// `CDR_MAX_SIZE` lays out every field, `CDR_KEY_MAX_SIZE` the key fields,
/// one `MaxSize::then` the next. For XCDR2 in member-id order (the order
/// of the key-hash form: a key member whose type has no key fields makes
/// all its members keys, which Cyclone DDS orders by member id too); for
/// XCDR1 in definition order, as Cyclone DDS measures the XCDR1 key
/// (idlc's `DDS_TOPIC_FIXED_KEY`, Cyclone DDS 11's
/// `dds_stream_key_size`), though it writes the XCDR1 key-hash form in
/// member-id order as well. The two differ only when `#[ipc(id = ..)]`
/// puts the fields out of order (`MaxSize::per_version` then combines
/// the two layouts).
pub(super) struct Sizes {
    pub(super) ipc_min: Vec<TokenStream>,
    pub(super) cdr_min: Vec<TokenStream>,
    pub(super) max_size: TokenStream,
    pub(super) key_max_size: TokenStream,
}

/// Whether `tokens` name `Self` or the struct `ident` (`Vec<Self>`,
/// `Vec<Box<Tree>>` in `struct Tree`).
fn mentions(tokens: TokenStream, ident: &syn::Ident) -> bool {
    tokens.into_iter().any(|t| match t {
        TokenTree::Ident(i) => i == "Self" || i == *ident,
        TokenTree::Group(g) => mentions(g.stream(), ident),
        _ => false,
    })
}

/// The `MaxSize` of field `f` written whole in the key-hash form, as
/// `cdr_encode` writes it (a length field as its integer type), in struct
/// `ident`.
fn field_max_size(f: &Field<'_>, ident: &syn::Ident) -> TokenStream {
    let ty = f.ty;
    let max = quote!(__wire::cdr::MaxSize);
    let bound = f.attrs.bound.map(|(n, _)| n as usize);
    match (&f.kind, bound) {
        // `bound` is on a `String` (the parser refuses it elsewhere)
        (Kind::Plain, Some(n)) if f.count_for.is_none() => quote!(#max::bounded_string(#n)),
        (Kind::Plain, _) => quote!(__wire::__private::max_size::<#ty>()),
        (Kind::Char, _) => quote!(#max::primitive(1)),
        // a sequence at its bound: DHEADER unless the elements are
        // primitive, count, elements; one of the struct itself nests
        // without end (and its constant would depend on itself)
        (Kind::Vec { elem, .. }, Some(n)) if !mentions(quote!(#elem), ident) => {
            quote!(__wire::__private::bounded_seq_max_size::<#elem>(#n))
        }
        // unbounded sequences and pointers (`Option<Box<Self>>` must not
        // make the constant depend on itself either)
        (Kind::Vec { .. } | Kind::NdVec { .. } | Kind::SelfPtr, _) => quote!(#max::UNBOUNDED),
    }
}

/// What key field `f` contributes to the key-hash form, as `cdr_encode_key`
/// writes it: a plain field whose type has key fields its key, any other
/// field all of it.
fn key_field_max_size(f: &Field<'_>, ident: &syn::Ident) -> TokenStream {
    let ty = f.ty;
    match (&f.kind, f.count_for, f.attrs.bound) {
        (Kind::Plain, None, None) => quote!(__wire::__private::key_member_max_size::<#ty>()),
        _ => field_max_size(f, ident),
    }
}

/// `a.then(b).then(c)…` of `terms`, `MaxSize::EMPTY` for none.
fn layout(terms: impl IntoIterator<Item = TokenStream>) -> TokenStream {
    let mut out = quote!(__wire::cdr::MaxSize::EMPTY);
    for t in terms {
        out = quote!(#out.then(#t));
    }
    out
}

/// The `MaxSize` of `fields` laid out in definition order for XCDR1 and
/// in member-id order for XCDR2 (see [`Sizes`]), each field measured by
/// `size`.
fn layout_per_version(
    fields: &[&Field<'_>],
    size: impl Fn(&Field<'_>) -> TokenStream,
) -> TokenStream {
    let by_id = {
        let mut v = fields.to_vec();
        v.sort_by_key(|f| f.id);
        v
    };
    let in_order = by_id.iter().map(|f| f.id).eq(fields.iter().map(|f| f.id));
    let xcdr2 = layout(by_id.iter().map(|f| size(f)));
    if in_order {
        xcdr2
    } else {
        let xcdr1 = layout(fields.iter().map(|f| size(f)));
        quote!(__wire::cdr::MaxSize::per_version(#xcdr1, #xcdr2))
    }
}

pub(super) fn sizes(fields: &[Field<'_>], ident: &syn::Ident) -> Sizes {
    let mut ipc_min = vec![quote!(0usize)];
    let mut cdr_min = vec![quote!(0usize)];
    for f in fields {
        let ty = f.ty;
        match &f.kind {
            Kind::Plain => {
                ipc_min.push(quote!(<#ty as __wire::IpcMessage>::IPC_MIN_SIZE));
                cdr_min.push(quote!(<#ty as __wire::IpcMessage>::CDR_MIN_SIZE));
            }
            Kind::Char | Kind::SelfPtr => {
                ipc_min.push(quote!(1usize));
                cdr_min.push(quote!(1usize));
            }
            Kind::Vec { .. } | Kind::NdVec { .. } => {
                ipc_min.push(quote!(4usize));
                cdr_min.push(quote!(4usize));
            }
        }
    }
    // the key-hash form writes the members in member-id order; XCDR1's
    // maximum is measured in definition order (see `Sizes`)
    let all: Vec<&Field<'_>> = fields.iter().collect();
    let keys: Vec<&Field<'_>> = all.iter().copied().filter(|f| f.attrs.key).collect();
    Sizes {
        ipc_min,
        cdr_min,
        max_size: layout_per_version(&all, |f| field_max_size(f, ident)),
        key_max_size: layout_per_version(&keys, |f| key_field_max_size(f, ident)),
    }
}

/// `KEYS`: the names of the key fields (`#[ipc(key)]`), in order.
pub(super) fn keys<'a>(fields: &'a [Field<'_>]) -> Vec<&'a str> {
    fields
        .iter()
        .filter(|f| f.attrs.key)
        .map(|f| f.name.as_str())
        .collect()
}
