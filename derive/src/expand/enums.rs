//! A fieldless enum: its `{enum A, B}` or `{enum : max}` format, and its
//! value as an int32 in IPC, in CDR and as its own key. Not a CDR
//! primitive: XCDR2 writes a `DHEADER` before a sequence or an array of it.

use proc_macro2::{Literal, TokenStream};
use quote::quote;
use syn::ext::IdentExt;

use super::{generics, info};
use crate::ast::{Container, Enum};

pub(super) fn expand_enum(c: &Container<'_>, e: &Enum<'_>) -> TokenStream {
    let ident = c.ident;
    let g = generics(c);
    let (impl_g, ty_g, where_c) = g.split_for_impl();
    let format = if e.numeric {
        let max = e.variants.iter().map(|v| v.value).max().unwrap_or(0);
        format!("{{enum : {max}}}")
    } else {
        let names: Vec<String> = e
            .variants
            .iter()
            .map(|v| v.ident.unraw().to_string())
            .collect();
        format!("{{enum {}}}", names.join(", "))
    };
    let (type_name, type_name_consts) = info::type_name(c);
    let inherent = if type_name_consts.is_empty() {
        quote!()
    } else {
        quote! {
            #[automatically_derived]
            impl #impl_g #ident #ty_g #where_c { #type_name_consts }
        }
    };
    let idents: Vec<&syn::Ident> = e.variants.iter().map(|v| v.ident).collect();
    let values: Vec<Literal> = e
        .variants
        .iter()
        .map(|v| Literal::i32_suffixed(i32::try_from(v.value).unwrap_or(0)))
        .collect();
    // Reading the value back: the same in IPC and CDR but for the error.
    let decode = |codec: TokenStream| {
        quote! {
            let __offset = __r.position();
            match __r.read_i32()? {
                #(#values => ::core::result::Result::Ok(Self::#idents),)*
                __v => ::core::result::Result::Err(__wire::#codec::DecodeError::InvalidEnum {
                    offset: __offset,
                    value: __v as i64,
                    type_name: <Self as __wire::IpcMessage>::TYPE_NAME,
                }),
            }
        }
    };
    // XTypes: an enum's default is its first enumerator
    let default = idents.first().map(|first| {
        quote! {
            fn cdr_default() -> ::core::option::Option<Self> {
                ::core::option::Option::Some(Self::#first)
            }
        }
    });
    let ipc_decode = decode(quote!(ipc));
    let cdr_decode = decode(quote!(cdr));
    quote! {
        #inherent

        #[automatically_derived]
        impl #impl_g __wire::IpcMessage for #ident #ty_g #where_c {
            const FORMAT: &'static str = #format;
            const TYPE_NAME: &'static str = #type_name;
            const IPC_MIN_SIZE: usize = 4;
            const CDR_MIN_SIZE: usize = 4;
            const CDR_MAX_SIZE: __wire::cdr::MaxSize = __wire::cdr::MaxSize::primitive(4);
            // not a CDR primitive (the default): XCDR2 puts a DHEADER
            // before sequences and arrays of an enum, as Cyclone DDS does
            // (its `is_primitive_type` covers the 1- to 16-byte integers
            // and floats, booleans and wchars, not enums)
            const CDR_PRIMITIVE: bool = false;

            fn ipc_encode(&self, __w: &mut __wire::ipc::Writer) {
                __w.write_i32(match self { #(Self::#idents => #values,)* });
            }

            fn ipc_decode(__r: &mut __wire::ipc::Reader<'_>) -> ::core::result::Result<Self, __wire::ipc::DecodeError> {
                #ipc_decode
            }

            fn cdr_encode(&self, __w: &mut __wire::cdr::Writer) {
                __w.write_i32(match self { #(Self::#idents => #values,)* });
            }

            fn cdr_decode(__r: &mut __wire::cdr::Reader<'_>) -> ::core::result::Result<Self, __wire::cdr::DecodeError> {
                __r.align(4)?;
                #cdr_decode
            }

            fn cdr_encode_key(&self, __w: &mut __wire::cdr::Writer) {
                __wire::IpcMessage::cdr_encode(self, __w);
            }

            #default

            type Key = Self;
            fn cdr_encode_key_value(__key: &Self, __w: &mut __wire::cdr::Writer) -> bool {
                __wire::IpcMessage::cdr_encode(__key, __w);
                true
            }
            fn cdr_decode_key(__r: &mut __wire::cdr::Reader<'_>) -> ::core::result::Result<Self, __wire::cdr::DecodeError> {
                <Self as __wire::IpcMessage>::cdr_decode(__r)
            }
        }
    }
}
