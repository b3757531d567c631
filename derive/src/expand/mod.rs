//! Code generation: the format strings, IPC and CDR code, all from one AST.
//!
//! [`expand`] puts together what the child modules generate for a struct
//! (format string, type information, IPC and CDR code) or a fieldless
//! enum, inside `const _: () = { ... };`.

mod cdr;
mod enums;
mod format;
mod info;
mod ipc;
mod lengths;

use proc_macro2::TokenStream;
use quote::{format_ident, quote};

use crate::ast::{Container, Data, Field, Kind};

/// Expands a checked container into `const _: () = { ... };`.
pub fn expand(c: &Container<'_>) -> TokenStream {
    let krate = match &c.attrs.krate {
        Some(p) => quote!(#p),
        None => wire_path(),
    };
    let body = match &c.data {
        Data::Struct(fields) => expand_struct(c, fields),
        Data::Enum(e) => enums::expand_enum(c, e),
    };
    quote! {
        #[doc(hidden)]
        #[allow(
            non_upper_case_globals,
            unused_variables,
            unused_mut,
            unused_qualifications,
            trivial_casts,
            trivial_numeric_casts,
            clippy::all,
            clippy::pedantic,
            clippy::nursery
        )]
        const _: () = {
            use #krate as __wire;
            #body
        };
    }
}

/// Where the wire crate is, without `#[ipc(crate = "...")]`: through the
/// `courier` crate under the name the user's `Cargo.toml` gives it
/// (`courier2 = { package = "courier", ... }` gives `::courier2::__wire`),
/// else `courier-wire` under its name, else `::courier::__wire`.
///
/// Inside the `courier` package (its examples and doctests, where
/// `proc-macro-crate` answers "itself") the crate is `::courier`, as
/// before; the same for `courier-wire`.
fn wire_path() -> TokenStream {
    use proc_macro_crate::{crate_name, FoundCrate};
    let found = |name: &str| match crate_name(name) {
        Ok(FoundCrate::Name(n)) => Some(format_ident!("{}", n)),
        Ok(FoundCrate::Itself) => Some(format_ident!("{}", name.replace('-', "_"))),
        Err(_) => None,
    };
    if let Some(courier) = found("courier") {
        quote!(::#courier::__wire)
    } else if let Some(wire) = found("courier-wire") {
        quote!(::#wire)
    } else {
        quote!(::courier::__wire)
    }
}

/// Generics of the impls: every type parameter gets an `IpcMessage` bound.
fn generics(c: &Container<'_>) -> syn::Generics {
    let mut g = c.generics.clone();
    let params: Vec<syn::Ident> = g.type_params().map(|t| t.ident.clone()).collect();
    if !params.is_empty() {
        let wc = g.make_where_clause();
        for p in params {
            wc.predicates
                .push(syn::parse_quote!(#p: __wire::IpcMessage));
        }
    }
    g
}

/// The local that holds field `i` while it is decoded.
fn var(i: usize) -> syn::Ident {
    format_ident!("__f{}", i)
}

/// The local that holds the length sent for `Vec` field `i`.
fn len_var(i: usize) -> syn::Ident {
    format_ident!("__n{}", i)
}

/// The local that holds where `NdVec` field `i`'s elements began.
fn offset_var(i: usize) -> syn::Ident {
    format_ident!("__o{}", i)
}

/// What a size field writes: the length sent for `Vec` field `array`, or
/// dimension `dim` of `NdVec` field `array` (never above `i32::MAX`, which
/// every size field type of an `NdVec` holds).
fn count_value(fields: &[Field<'_>], array: usize, dim: usize) -> TokenStream {
    match &fields[array].kind {
        Kind::NdVec { .. } => {
            let m = &fields[array].member;
            quote!(__wire::__private::NdField::dim(&self.#m, #dim))
        }
        _ => {
            let n = len_var(array);
            quote!(#n)
        }
    }
}

/// The length of each `Vec` field with a count field (those `only` takes),
/// capped by its count type and by int32: the length both encoders send,
/// so that the count never disagrees with the data.
fn len_lets(fields: &[Field<'_>], only: &dyn Fn(usize) -> bool) -> Vec<TokenStream> {
    fields
        .iter()
        .enumerate()
        .filter_map(|(i, f)| {
            let Kind::Vec { len: Some(j), .. } = &f.kind else {
                return None;
            };
            if !only(i) {
                return None;
            }
            let m = &f.member;
            let cty = fields[*j].ty;
            let n = len_var(i);
            Some(quote! {
                let #n: usize = ::core::cmp::min(
                    self.#m.len() as u64,
                    ::core::cmp::min(<#cty>::MAX as u64, 0x7fff_ffff_u64),
                ) as usize;
            })
        })
        .collect()
}

fn expand_struct(c: &Container<'_>, fields: &[Field<'_>]) -> TokenStream {
    let ident = c.ident;
    let g = generics(c);
    let (impl_g, ty_g, where_c) = g.split_for_impl();
    let ext = info::ext_tokens(c.extensibility());
    let format::StructFormat {
        checks,
        build,
        name_consts,
        named_formats,
    } = format::struct_format(c, fields);
    let (type_name, type_name_consts) = info::type_name(c);
    let info::Sizes {
        ipc_min,
        cdr_min,
        max_size,
        key_max_size,
    } = info::sizes(fields, ident);
    let keys = info::keys(fields);
    let lengths::Lengths {
        checks: checks_lengths,
        body: check_lengths,
    } = lengths::lengths(fields);
    let all_lens = len_lets(fields, &|_| true);
    let ipc::StructCodec {
        enc: ipc_enc,
        dec: ipc_dec,
    } = ipc::struct_codec(fields);
    let cdr::StructCodec {
        enc: cdr_enc,
        dec: cdr_dec,
        key_fn,
    } = cdr::struct_codec(c, fields, &ext);
    let members: Vec<&syn::Member> = fields.iter().map(|f| &f.member).collect();
    let vars: Vec<syn::Ident> = (0..fields.len()).map(var).collect();
    let cdr_default = cdr::struct_default(fields);

    quote! {
        #[automatically_derived]
        impl #impl_g #ident #ty_g #where_c {
            const __COURIER_FORMAT: __wire::__private::ConstStr = {
                #(#checks)*
                #build
            };
            const __COURIER_FORMAT_REF: &'static __wire::__private::ConstStr = &Self::__COURIER_FORMAT;
            const __COURIER_FORMAT_STR: &'static str = Self::__COURIER_FORMAT_REF.as_str();
            #type_name_consts
        }

        #[automatically_derived]
        impl #impl_g __wire::IpcMessage for #ident #ty_g #where_c {
            const FORMAT: &'static str = Self::__COURIER_FORMAT_STR;
            #name_consts
            const TYPE_NAME: &'static str = #type_name;
            const EXTENSIBILITY: __wire::cdr::Extensibility = #ext;
            const IPC_MIN_SIZE: usize = #(#ipc_min)+*;
            const CDR_MIN_SIZE: usize = #(#cdr_min)+*;
            const CDR_MAX_SIZE: __wire::cdr::MaxSize = #max_size;
            const CDR_KEY_MAX_SIZE: __wire::cdr::MaxSize = #key_max_size;
            const KEYS: &'static [&'static str] = &[#(#keys),*];
            const CHECKS_LENGTHS: bool = #checks_lengths;

            fn check_lengths(&self) -> ::core::result::Result<(), __wire::LengthError> {
                #(#check_lengths)*
                ::core::result::Result::Ok(())
            }

            fn named_formats(__out: &mut __wire::NamedFormats) {
                #named_formats
            }

            fn ipc_encode(&self, __w: &mut __wire::ipc::Writer) {
                #(#all_lens)*
                #(#ipc_enc)*
            }

            fn ipc_decode(__r: &mut __wire::ipc::Reader<'_>) -> ::core::result::Result<Self, __wire::ipc::DecodeError> {
                // Every struct level counts towards the reader's depth limit, so that
                // recursion through `Vec<Self>` is bounded too (an error abandons the
                // reader, so the early returns need not restore the depth).
                __r.enter()?;
                #(#ipc_dec)*
                __r.leave();
                ::core::result::Result::Ok(Self { #(#members: #vars),* })
            }

            fn cdr_encode(&self, __w: &mut __wire::cdr::Writer) {
                #(#all_lens)*
                let __s = __w.begin_struct(#ext);
                #cdr_enc
                __s.end(__w);
            }

            fn cdr_decode(__r: &mut __wire::cdr::Reader<'_>) -> ::core::result::Result<Self, __wire::cdr::DecodeError> {
                #cdr_dec
                ::core::result::Result::Ok(Self { #(#members: #vars),* })
            }

            #cdr_default

            #key_fn
        }
    }
}
