//! IPC marshalling of a struct, straight from its fields: what
//! `ipc_encode` writes and how `ipc_decode` reads each field back (a
//! `Vec`'s count checked against its count field).

use proc_macro2::TokenStream;
use quote::quote;

use super::{count_value, len_var, offset_var, var};
use crate::ast::{Field, Kind};

/// The statements of `ipc_encode` and `ipc_decode`, one or more per field.
pub(super) struct StructCodec {
    pub(super) enc: Vec<TokenStream>,
    pub(super) dec: Vec<TokenStream>,
}

pub(super) fn struct_codec(fields: &[Field<'_>]) -> StructCodec {
    let mut ipc_enc = Vec::new();
    let mut ipc_dec = Vec::new();
    // `NdVec`s are built once every size field has been read
    let mut ipc_post = Vec::new();
    for (i, f) in fields.iter().enumerate() {
        let m = &f.member;
        let ty = f.ty;
        let v = var(i);
        if let Some(vec) = f.count_for {
            let n = count_value(fields, vec, f.count_dim);
            ipc_enc.push(quote!(__wire::IpcMessage::ipc_encode(&(#n as #ty), __w);));
            ipc_dec.push(quote!(let #v: #ty = <#ty as __wire::IpcMessage>::ipc_decode(__r)?;));
            continue;
        }
        match &f.kind {
            Kind::Plain => {
                ipc_enc.push(quote!(__wire::IpcMessage::ipc_encode(&self.#m, __w);));
                ipc_dec.push(quote!(let #v: #ty = <#ty as __wire::IpcMessage>::ipc_decode(__r)?;));
            }
            Kind::Char => {
                ipc_enc.push(quote!(__w.write_u8(self.#m);));
                ipc_dec.push(quote!(let #v: u8 = __r.read_u8()?;));
            }
            Kind::SelfPtr => {
                ipc_enc.push(quote!(__wire::__private::ipc_encode_self_ptr(&self.#m, __w);));
                ipc_dec.push(quote!(let #v: #ty = __wire::__private::ipc_decode_self_ptr(__r)?;));
            }
            Kind::Vec { elem, len } => {
                let n = len_var(i);
                ipc_enc.push(if len.is_some() {
                    quote!(__wire::__private::ipc_encode_vec::<#elem>(&self.#m[..#n], __w);)
                } else {
                    quote!(__wire::__private::ipc_encode_vec::<#elem>(&self.#m[..], __w);)
                });
                match len {
                    Some(j) if *j < i => {
                        let cv = var(*j);
                        ipc_dec.push(quote! {
                            let #v: #ty = {
                                let __offset = __r.position();
                                let __count = __r.read_count(<#elem as __wire::IpcMessage>::IPC_MIN_SIZE)?;
                                if (#cv as i128) != (__count as i128) {
                                    return ::core::result::Result::Err(__wire::ipc::DecodeError::CountMismatch {
                                        offset: __offset,
                                        expected: #cv as u64,
                                        found: __count as u64,
                                    });
                                }
                                <#elem as __wire::IpcMessage>::ipc_decode_vec(__r, __count)?
                            };
                        });
                    }
                    _ => ipc_dec.push(
                        quote!(let #v: #ty = __wire::__private::ipc_decode_vec::<#elem>(__r)?;),
                    ),
                }
            }
            Kind::NdVec { dims } => {
                let elem = quote!(<#ty as __wire::__private::NdField>::Elem);
                let o = offset_var(i);
                let sizes = dims.iter().map(|j| var(*j));
                ipc_enc.push(quote!(__wire::__private::ipc_encode_vec::<#elem>(
                    __wire::__private::NdField::elems(&self.#m), __w);));
                ipc_dec.push(quote! {
                    let #o = __r.position();
                    let #v = __wire::__private::ipc_decode_vec::<#elem>(__r)?;
                });
                ipc_post.push(quote! {
                    let #v: #ty = __wire::__private::ipc_nd::<#ty>(&[#(#sizes as i128),*], #v, #o)?;
                });
            }
        }
    }
    ipc_dec.extend(ipc_post);
    StructCodec {
        enc: ipc_enc,
        dec: ipc_dec,
    }
}
