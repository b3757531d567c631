//! Type information besides the format: the DDS type name, the CDR
//! extensibility, the smallest encoded sizes, whether the CDR form (and
//! the key's) is bounded, and the key fields.

use proc_macro2::TokenStream;
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
    let params: Vec<&syn::Ident> = c.generics.type_params().map(|t| &t.ident).collect();
    let base = quote!(::core::concat!(::core::module_path!(), "::", #ident));
    if params.is_empty() {
        return (base, quote!());
    }
    let mut build = quote!(__wire::__private::ConstStr::new().push_str(#base).push_str("<"));
    for (i, p) in params.iter().enumerate() {
        if i > 0 {
            build = quote!(#build.push_str(", "));
        }
        build = quote!(#build.push_str(<#p as __wire::IpcMessage>::TYPE_NAME));
    }
    build = quote!(#build.push_str(">"));
    let consts = quote! {
        const __COURIER_TYPE_NAME: __wire::__private::ConstStr = #build;
        const __COURIER_TYPE_NAME_REF: &'static __wire::__private::ConstStr = &Self::__COURIER_TYPE_NAME;
        const __COURIER_TYPE_NAME_STR: &'static str = Self::__COURIER_TYPE_NAME_REF.as_str();
    };
    (quote!(Self::__COURIER_TYPE_NAME_STR), consts)
}

pub(super) fn ext_tokens(e: Extensibility) -> TokenStream {
    match e {
        Extensibility::Final => quote!(__wire::cdr::Extensibility::Final),
        Extensibility::Appendable => quote!(__wire::cdr::Extensibility::Appendable),
        Extensibility::Mutable => quote!(__wire::cdr::Extensibility::Mutable),
    }
}

/// The terms of a struct's size constants, one per field (after a first
/// neutral one): `IPC_MIN_SIZE` and `CDR_MIN_SIZE` add them up,
/// `CDR_BOUNDED` and `CDR_KEY_BOUNDED` require them all.
pub(super) struct Sizes {
    pub(super) ipc_min: Vec<TokenStream>,
    pub(super) cdr_min: Vec<TokenStream>,
    pub(super) bounded: Vec<TokenStream>,
    pub(super) key_bounded: Vec<TokenStream>,
}

pub(super) fn sizes(fields: &[Field<'_>]) -> Sizes {
    let mut ipc_min = vec![quote!(0usize)];
    let mut cdr_min = vec![quote!(0usize)];
    let mut bounded = vec![quote!(true)];
    let mut key_bounded = vec![quote!(true)];
    for f in fields {
        let ty = f.ty;
        let b = match &f.kind {
            Kind::Plain => {
                ipc_min.push(quote!(<#ty as __wire::IpcMessage>::IPC_MIN_SIZE));
                cdr_min.push(quote!(<#ty as __wire::IpcMessage>::CDR_MIN_SIZE));
                quote!(<#ty as __wire::IpcMessage>::CDR_BOUNDED)
            }
            Kind::Char => {
                ipc_min.push(quote!(1usize));
                cdr_min.push(quote!(1usize));
                quote!(true)
            }
            Kind::SelfPtr => {
                ipc_min.push(quote!(1usize));
                cdr_min.push(quote!(1usize));
                quote!(false)
            }
            Kind::Vec { .. } | Kind::NdVec { .. } => {
                ipc_min.push(quote!(4usize));
                cdr_min.push(quote!(4usize));
                quote!(false)
            }
        };
        if f.attrs.key {
            key_bounded.push(match (&f.kind, f.count_for) {
                (Kind::Plain, None) => quote! {
                    (if <#ty as __wire::IpcMessage>::KEYS.is_empty() {
                        <#ty as __wire::IpcMessage>::CDR_BOUNDED
                    } else {
                        <#ty as __wire::IpcMessage>::CDR_KEY_BOUNDED
                    })
                },
                _ => b.clone(),
            });
        }
        bounded.push(b);
    }
    Sizes {
        ipc_min,
        cdr_min,
        bounded,
        key_bounded,
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
