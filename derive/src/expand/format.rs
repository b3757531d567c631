//! A struct's IPC format string (`{int, <double:1>, Named}`), built at
//! compile time from its fields' formats, its format name (a struct is a
//! named format, `IPC_defineFormat`), and the named formats it uses.

use proc_macro2::TokenStream;
use quote::{quote, quote_spanned};
use syn::ext::IdentExt;
use syn::spanned::Spanned;

use crate::ast::{Container, Field, Kind};

/// What a struct's format takes.
pub(super) struct StructFormat {
    /// Compile-time checks on the field types (run while the format is built).
    pub(super) checks: Vec<TokenStream>,
    /// The `ConstStr` expression that builds `FORMAT`.
    pub(super) build: TokenStream,
    /// `FIELD_FORMAT` and `FORMAT_NAME`, for a named struct.
    pub(super) name_consts: TokenStream,
    /// The body of `named_formats`.
    pub(super) named_formats: TokenStream,
}

pub(super) fn struct_format(c: &Container<'_>, fields: &[Field<'_>]) -> StructFormat {
    let ident = c.ident;
    let is_generic =
        c.generics.type_params().next().is_some() || c.generics.const_params().next().is_some();
    let mut checks = Vec::new();
    let mut build = quote!(__wire::__private::ConstStr::new());
    if !fields.is_empty() {
        build = quote!(#build.push_str("{"));
    }
    for (i, f) in fields.iter().enumerate() {
        if i > 0 {
            build = quote!(#build.push_str(", "));
        }
        let ty = f.ty;
        // a `Vec`'s element: an empty format would leave `<:1>` in the
        // format (arrays `[T; N]` and pointers `Option<Box<T>>` of such a
        // type are refused by their own formats, in courier-wire)
        if let Kind::Vec { elem, .. } = &f.kind {
            let msg = format!(
                "field `{}` of `{}` is a `Vec` of `{}`, whose IPC format is empty (an empty message such as `()` or a unit struct): IPC variable arrays cannot hold it",
                f.name,
                ident.unraw(),
                quote!(#elem).to_string().replace(' ', "")
            );
            checks.push(quote_spanned! {elem.span()=>
                if <#elem as __wire::IpcMessage>::FIELD_FORMAT.is_empty() {
                    ::core::panic!(#msg);
                }
            });
        }
        build = match &f.kind {
            Kind::Plain => {
                let msg = format!(
                    "field `{}` of `{}` has a type with an empty IPC format (an empty message such as `()` or a unit struct), which cannot be a field",
                    f.name,
                    ident.unraw()
                );
                checks.push(quote_spanned! {ty.span()=>
                    if <#ty as __wire::IpcMessage>::FIELD_FORMAT.is_empty() {
                        ::core::panic!(#msg);
                    }
                });
                quote!(#build.push_str(<#ty as __wire::IpcMessage>::FIELD_FORMAT))
            }
            Kind::Char => quote!(#build.push_str("char")),
            Kind::SelfPtr => quote!(#build.push_str("*!")),
            Kind::Vec { elem, len } => {
                let k = format!(":{}>", len.map_or(0, |j| j + 1));
                quote!(#build.push_str("<").push_str(<#elem as __wire::IpcMessage>::FIELD_FORMAT).push_str(#k))
            }
            Kind::NdVec { dims } => {
                let n = dims.len();
                let msg = format!(
                    "field `{}` of `{}` names {n} size fields in `len`, but its type has a different number of dimensions",
                    f.name,
                    ident.unraw()
                );
                checks.push(quote_spanned! {ty.span()=>
                    if <#ty as __wire::__private::NdField>::DIMS != #n {
                        ::core::panic!(#msg);
                    }
                });
                let ks: Vec<String> = dims.iter().map(|j| (j + 1).to_string()).collect();
                let k = format!(":{}>", ks.join(","));
                quote!(#build.push_str("<").push_str(<<#ty as __wire::__private::NdField>::Elem as __wire::IpcMessage>::FIELD_FORMAT).push_str(#k))
            }
        };
    }
    if !fields.is_empty() {
        build = quote!(#build.push_str("}"));
    }

    // A unit struct is the empty message (format "", like `()`): never named.
    let named = !fields.is_empty() && !is_generic;
    let format_name = c
        .attrs
        .name
        .as_ref()
        .map_or_else(|| ident.unraw().to_string(), |(n, _)| n.clone());

    let name_consts = if named {
        quote! {
            const FIELD_FORMAT: &'static str = #format_name;
            const FORMAT_NAME: ::core::option::Option<&'static str> = ::core::option::Option::Some(#format_name);
        }
    } else {
        quote!()
    };

    let mut nested = Vec::new();
    for f in fields {
        let ty = f.ty;
        match &f.kind {
            Kind::Plain if f.count_for.is_none() => {
                nested.push(quote!(<#ty as __wire::IpcMessage>::named_formats(__out);))
            }
            Kind::Vec { elem, .. } => {
                nested.push(quote!(<#elem as __wire::IpcMessage>::named_formats(__out);))
            }
            Kind::NdVec { .. } => nested.push(quote!(
                <<#ty as __wire::__private::NdField>::Elem as __wire::IpcMessage>::named_formats(__out);
            )),
            _ => {}
        }
    }
    let named_formats = if named {
        quote! {
            if __out.insert(#format_name, <Self as __wire::IpcMessage>::FORMAT) {
                #(#nested)*
            }
        }
    } else {
        quote!(#(#nested)*)
    };
    StructFormat {
        checks,
        build,
        name_consts,
        named_formats,
    }
}
