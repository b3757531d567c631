//! CDR (XCDR1 and XCDR2) of a struct: each field as a member of its
//! extensibility (final, appendable with DHEADER, mutable with EMHEADER),
//! the decoding of mutable members in any order, and the key
//! (`cdr_encode_key`) of a keyed struct.

use proc_macro2::TokenStream;
use quote::quote;

use super::{count_value, len_lets, len_var, offset_var, var};
use crate::ast::{Container, Field, Kind};
use crate::attr::Extensibility;

/// The CDR parts of a struct's `IpcMessage` impl.
pub(super) struct StructCodec {
    /// The statements of `cdr_encode` that write the members: one per
    /// field, in definition order, or in member-id order in the key-hash
    /// form (see [`struct_codec`]).
    pub(super) enc: TokenStream,
    /// The body of `cdr_decode` up to building `Self`.
    pub(super) dec: TokenStream,
    /// `cdr_encode_key`, for a struct with key fields.
    pub(super) key_fn: TokenStream,
}

/// Writes field `i`'s value (a count field writes its array's length or
/// dimension).
fn cdr_value(fields: &[Field<'_>], i: usize) -> TokenStream {
    let f = &fields[i];
    let m = &f.member;
    let ty = f.ty;
    if let Some(vec) = f.count_for {
        let n = count_value(fields, vec, f.count_dim);
        return quote!(__wire::IpcMessage::cdr_encode(&(#n as #ty), __w););
    }
    match &f.kind {
        Kind::NdVec { .. } => {
            quote!(__wire::__private::cdr_encode_seq::<<#ty as __wire::__private::NdField>::Elem>(
            __wire::__private::NdField::elems(&self.#m), __w);)
        }
        Kind::Plain | Kind::SelfPtr => quote!(__wire::IpcMessage::cdr_encode(&self.#m, __w);),
        Kind::Char => quote!(__w.write_u8(self.#m);),
        Kind::Vec { elem, len: Some(_) } => {
            let n = len_var(i);
            quote!(__wire::__private::cdr_encode_seq::<#elem>(&self.#m[..#n], __w);)
        }
        Kind::Vec { elem, len: None } => {
            quote!(__wire::__private::cdr_encode_seq::<#elem>(&self.#m[..], __w);)
        }
    }
}

/// Reads a field's value (an `NdVec`'s elements only: [`nd_finish`] builds it).
fn cdr_read(f: &Field<'_>) -> TokenStream {
    let ty = f.ty;
    match &f.kind {
        Kind::NdVec { .. } => {
            quote!(__wire::__private::cdr_decode_seq::<<#ty as __wire::__private::NdField>::Elem>(__r)?)
        }
        Kind::Char => quote!(__r.read_u8()?),
        Kind::Vec { elem, .. } => quote!(__wire::__private::cdr_decode_seq::<#elem>(__r)?),
        Kind::Plain | Kind::SelfPtr => quote!(<#ty as __wire::IpcMessage>::cdr_decode(__r)?),
    }
}

/// `Option<T>` of what a member missing from the data decodes to, `T`
/// being the field's local (an `NdVec`'s elements): its type's default
/// (XTypes), `None` for a type without one.
fn member_default(f: &Field<'_>) -> TokenStream {
    let ty = f.ty;
    match &f.kind {
        Kind::Plain => quote!(<#ty as __wire::IpcMessage>::cdr_default()),
        Kind::SelfPtr => quote!(::core::option::Option::Some(::core::option::Option::None)),
        Kind::Char => quote!(::core::option::Option::Some(0u8)),
        Kind::Vec { .. } | Kind::NdVec { .. } => {
            quote!(::core::option::Option::Some(
                ::core::default::Default::default()
            ))
        }
    }
}

/// The value of a member the data leaves out: its default, or
/// `MissingMember` for a key or a type without default.
fn missing(f: &Field<'_>) -> TokenStream {
    let id = f.id;
    let name = &f.name;
    let err = quote! {
        return ::core::result::Result::Err(__wire::cdr::DecodeError::MissingMember {
            type_name: <Self as __wire::IpcMessage>::TYPE_NAME,
            member: #name,
            id: #id,
        })
    };
    if f.attrs.key {
        return quote!({ #err });
    }
    let d = member_default(f);
    quote! {
        match #d {
            ::core::option::Option::Some(__d) => __d,
            ::core::option::Option::None => #err,
        }
    }
}

/// `cdr_default`: the struct of its members' defaults, if each has one.
pub(super) fn struct_default(fields: &[Field<'_>]) -> TokenStream {
    let lets = fields.iter().enumerate().map(|(i, f)| {
        let v = var(i);
        let ty = f.ty;
        let d = match &f.kind {
            Kind::NdVec { .. } => quote!(__wire::__private::nd_default::<#ty>()),
            _ => member_default(f),
        };
        quote!(let #v: #ty = #d?;)
    });
    let members = fields.iter().map(|f| &f.member);
    let vars = (0..fields.len()).map(var);
    quote! {
        fn cdr_default() -> ::core::option::Option<Self> {
            #(#lets)*
            ::core::option::Option::Some(Self { #(#members: #vars),* })
        }
    }
}

/// `value` written as the member of field `f`.
fn member(f: &Field<'_>, value: TokenStream) -> TokenStream {
    let id = f.id;
    let mu = f.attrs.key || f.attrs.must_understand;
    quote! {
        let __m = __s.begin_member(__w, #id, #mu);
        #value
        __s.end_member(__w, __m);
    }
}

/// The CDR codec of a struct. In the key-hash form the struct is written
/// whole only as (part of) a key member whose type has no key fields of
/// its own: all its members are then keys, and Cyclone DDS puts them in
/// member-id order, scoped to their struct, as it does the key members of
/// the outer struct (idlc sorts the key descriptors by their member-id
/// path, and `DDS_CDR_KEY_SERIALIZATION_KEYHASH` follows that order). So
/// there the members go in member-id order, and are read back so.
pub(super) fn struct_codec(
    c: &Container<'_>,
    fields: &[Field<'_>],
    ext: &TokenStream,
) -> StructCodec {
    let mutable = c.extensibility() == Extensibility::Mutable;
    let each: Vec<TokenStream> = fields
        .iter()
        .enumerate()
        .map(|(i, f)| member(f, cdr_value(fields, i)))
        .collect();
    let all: Vec<usize> = (0..fields.len()).collect();
    let ids = by_id(&all, fields);
    let enc = in_either_order(
        each.clone(),
        ids.iter().map(|i| each[*i].clone()).collect(),
        quote!(__w),
        quote!(),
    );
    let finish = nd_finish(fields);
    let appendable = c.extensibility() == Extensibility::Appendable;
    let in_order = ids.iter().copied().eq(all.iter().copied());
    let dec = if mutable {
        mutable_decode(fields, ext)
    } else {
        let reads = fields.iter().enumerate().map(|(i, f)| {
            if !appendable {
                return plain_read(fields, i);
            }
            // an older writer's data ends before the members it lacks
            let v = var(i);
            let ty = decoded_ty(f);
            let m = missing(f);
            let read = cdr_read(f);
            let read = quote!(if __s.ended(__r) { #m } else { #read });
            if matches!(f.kind, Kind::NdVec { .. }) {
                let o = offset_var(i);
                quote!(let #o = __r.position(); let #v #ty = #read;)
            } else {
                quote!(let #v #ty = #read;)
            }
        });
        quote! {
            let __s = __r.begin_struct(#ext)?;
            #(#reads)*
            __s.end(__r)?;
        }
    };
    // the key-hash form: no member headers (a mutable struct's members
    // cannot be found by id) and the members in member-id order
    let dec = if mutable || !in_order {
        let reads = ids.iter().map(|i| plain_read(fields, *i));
        let mut out: Vec<syn::Ident> = (0..fields.len()).map(var).collect();
        out.extend(
            fields
                .iter()
                .enumerate()
                .filter(|(_, f)| matches!(f.kind, Kind::NdVec { .. }))
                .map(|(i, _)| offset_var(i)),
        );
        quote! {
            let (#(#out,)*) = if __r.is_key_hash_form() {
                let __s = __r.begin_struct(#ext)?;
                #(#reads)*
                __s.end(__r)?;
                (#(#out,)*)
            } else {
                #dec
                (#(#out,)*)
            };
        }
    } else {
        dec
    };
    let dec = quote!(#dec #(#finish)*);
    StructCodec {
        enc,
        dec,
        key_fn: key_fn(fields, ext, mutable),
    }
}

/// Reads field `i` into its local (an `NdVec` also notes where its
/// elements begin), as a member of a final struct.
fn plain_read(fields: &[Field<'_>], i: usize) -> TokenStream {
    let f = &fields[i];
    let v = var(i);
    let ty = decoded_ty(f);
    let read = cdr_read(f);
    if matches!(f.kind, Kind::NdVec { .. }) {
        let o = offset_var(i);
        quote!(let #o = __r.position(); let #v #ty = #read;)
    } else {
        quote!(let #v #ty = #read;)
    }
}

/// `: T` for a decoded field's local; nothing for an `NdVec`, whose local
/// holds its elements until [`nd_finish`].
fn decoded_ty(f: &Field<'_>) -> TokenStream {
    let ty = f.ty;
    match f.kind {
        Kind::NdVec { .. } => quote!(),
        _ => quote!(: #ty),
    }
}

/// Builds each `NdVec` field from its elements and its size fields, once
/// all are read.
fn nd_finish(fields: &[Field<'_>]) -> Vec<TokenStream> {
    fields
        .iter()
        .enumerate()
        .filter_map(|(i, f)| {
            let Kind::NdVec { dims } = &f.kind else {
                return None;
            };
            let ty = f.ty;
            let v = var(i);
            let o = offset_var(i);
            let sizes = dims.iter().map(|j| var(*j));
            Some(quote! {
                let #v: #ty = __wire::__private::cdr_nd::<#ty>(&[#(#sizes as i128),*], #v, #o)?;
            })
        })
        .collect()
}

/// Members of a mutable struct come in any order, unknown ones are
/// skipped unless they must be understood, and a missing one takes its
/// default (a key must come; an optional one is `None`).
fn mutable_decode(fields: &[Field<'_>], ext: &TokenStream) -> TokenStream {
    let decls = fields.iter().enumerate().map(|(i, f)| {
        let v = var(i);
        let ty = f.ty;
        if matches!(f.kind, Kind::NdVec { .. }) {
            let o = offset_var(i);
            quote! {
                let mut #o = 0usize;
                let mut #v = ::core::option::Option::None;
            }
        } else {
            quote!(let mut #v: ::core::option::Option<#ty> = ::core::option::Option::None;)
        }
    });
    let arms = fields.iter().enumerate().map(|(i, f)| {
        let v = var(i);
        let id = f.id;
        let read = cdr_read(f);
        if matches!(f.kind, Kind::NdVec { .. }) {
            let o = offset_var(i);
            quote!(#id => { #o = __r.position(); #v = ::core::option::Option::Some(#read); })
        } else {
            quote!(#id => #v = ::core::option::Option::Some(#read),)
        }
    });
    let unwraps = fields.iter().enumerate().map(|(i, f)| {
        let v = var(i);
        if f.optional {
            // an absent optional member is left out of a mutable struct
            return quote!(let #v = #v.unwrap_or(::core::option::Option::None););
        }
        // a member the writer's version of the type lacks: its default
        let m = missing(f);
        quote! {
            let #v = match #v {
                ::core::option::Option::Some(v) => v,
                ::core::option::Option::None => #m,
            };
        }
    });
    quote! {
        let mut __s = __r.begin_struct(#ext)?;
        #(#decls)*
        while let ::core::option::Option::Some(__m) = __s.next_member(__r)? {
            match __m.id {
                #(#arms)*
                _ => {
                    if __m.must_understand {
                        return ::core::result::Result::Err(__wire::cdr::DecodeError::UnknownMustUnderstand {
                            type_name: <Self as __wire::IpcMessage>::TYPE_NAME,
                            id: __m.id,
                            offset: __r.position(),
                        });
                    }
                }
            }
        }
        __s.end(__r)?;
        #(#unwraps)*
    }
}

/// The type a key field contributes to `Key` and how it is read: what
/// `key_fn` writes for it.
fn key_part(f: &Field<'_>) -> (TokenStream, TokenStream) {
    let ty = f.ty;
    match (&f.kind, f.count_for) {
        (Kind::Plain, None) | (Kind::SelfPtr, _) => (
            quote!(<#ty as __wire::IpcMessage>::Key),
            quote!(<#ty as __wire::IpcMessage>::cdr_decode_key(__r)?),
        ),
        _ => (quote!(#ty), cdr_read(f)),
    }
}

/// `type Key` and `cdr_decode_key`: the key fields (one alone, several as
/// a tuple) read from what `cdr_encode_key` writes; a struct without key
/// fields is its own key.
fn key_decode(fields: &[Field<'_>], ext: &TokenStream, mutable: bool) -> TokenStream {
    let keys: Vec<(usize, &Field<'_>)> = fields
        .iter()
        .enumerate()
        .filter(|(_, f)| f.attrs.key)
        .collect();
    if keys.is_empty() {
        return quote! {
            type Key = Self;
            fn cdr_encode_key_value(__key: &Self, __w: &mut __wire::cdr::Writer) -> bool {
                __wire::IpcMessage::cdr_encode(__key, __w);
                true
            }
            fn cdr_decode_key(__r: &mut __wire::cdr::Reader<'_>) -> ::core::result::Result<Self, __wire::cdr::DecodeError> {
                <Self as __wire::IpcMessage>::cdr_decode(__r)
            }
        };
    }
    let tys: Vec<TokenStream> = keys.iter().map(|(_, f)| key_part(f).0).collect();
    let vars: Vec<syn::Ident> = keys.iter().map(|(i, _)| var(*i)).collect();
    let key_ty = if tys.len() == 1 {
        tys[0].clone()
    } else {
        quote!((#(#tys),*))
    };
    let value = if vars.len() == 1 {
        let v = &vars[0];
        quote!(#v)
    } else {
        quote!((#(#vars),*))
    };
    // the key members in order: definition order, or member-id order in
    // the key-hash form
    let in_order = {
        let read = |k: usize| {
            let (i, f) = keys[k];
            let (v, t) = (var(i), &tys[k]);
            let read = key_part(f).1;
            quote!(let #v: #t = #read;)
        };
        let positions: Vec<usize> = (0..keys.len()).collect();
        let mut by_id: Vec<usize> = positions.clone();
        by_id.sort_by_key(|k| keys[*k].1.id);
        let all: Vec<syn::Ident> = keys.iter().map(|(i, _)| var(*i)).collect();
        // (read into a block each way, then out as a tuple)
        let reads = in_either_order(
            positions.into_iter().map(read).collect(),
            by_id.into_iter().map(read).collect(),
            quote!(__r),
            quote!((#(#all,)*)),
        );
        quote! {
            let __s = __r.begin_struct(#ext)?;
            let (#(#all,)*) = #reads;
            __s.end(__r)?;
        }
    };
    let body = if mutable {
        let decls = keys.iter().zip(&tys).map(|((i, _), t)| {
            let v = var(*i);
            quote!(let mut #v: ::core::option::Option<#t> = ::core::option::Option::None;)
        });
        let arms = keys.iter().map(|(i, f)| {
            let v = var(*i);
            let id = f.id;
            let read = key_part(f).1;
            quote!(#id => #v = ::core::option::Option::Some(#read),)
        });
        let unwraps = keys.iter().map(|(i, f)| {
            let v = var(*i);
            let id = f.id;
            let name = &f.name;
            quote! {
                let #v = match #v {
                    ::core::option::Option::Some(v) => v,
                    ::core::option::Option::None => {
                        return ::core::result::Result::Err(__wire::cdr::DecodeError::MissingMember {
                            type_name: <Self as __wire::IpcMessage>::TYPE_NAME,
                            member: #name,
                            id: #id,
                        })
                    }
                };
            }
        });
        // the key-hash form has no member headers: the key members in order
        quote! {
            let #value = if __r.is_key_hash_form() {
                #in_order
                #value
            } else {
                let mut __s = __r.begin_struct(#ext)?;
                #(#decls)*
                while let ::core::option::Option::Some(__m) = __s.next_member(__r)? {
                    match __m.id {
                        #(#arms)*
                        _ => {}
                    }
                }
                __s.end(__r)?;
                #(#unwraps)*
                #value
            };
        }
    } else {
        in_order
    };
    let encode_value = key_value_encode(&keys, &vars, ext);
    quote! {
        type Key = #key_ty;
        fn cdr_decode_key(__r: &mut __wire::cdr::Reader<'_>) -> ::core::result::Result<Self::Key, __wire::cdr::DecodeError> {
            #body
            ::core::result::Result::Ok(#value)
        }
        #encode_value
    }
}

/// `cdr_encode_key_value`: what `cdr_encode_key` writes, from the key
/// alone (its fields as `cdr_decode_key` returns them): a plain field
/// through its type's `cdr_encode_key_value`, a `Vec` without length
/// field as its sequence, a `char` byte as itself. For a key with a
/// counted `Vec`, its length field or an n-d array the type cannot say
/// (`false`): the length written is the `Vec`'s, not the field's.
fn key_value_encode(
    keys: &[(usize, &Field<'_>)],
    vars: &[syn::Ident],
    ext: &TokenStream,
) -> TokenStream {
    let plain = keys.iter().all(|(_, f)| {
        matches!(
            (&f.kind, f.count_for),
            (Kind::Plain | Kind::Char | Kind::Vec { len: None, .. }, None) | (Kind::SelfPtr, _)
        )
    });
    if !plain {
        return quote! {
            fn cdr_encode_key_value(__key: &Self::Key, __w: &mut __wire::cdr::Writer) -> bool {
                let _ = (__key, __w);
                false
            }
        };
    }
    let bind = if vars.len() == 1 {
        let v = &vars[0];
        quote!(let #v = __key;)
    } else {
        quote!(let (#(#vars),*) = __key;)
    };
    let write = |k: usize| {
        let (f, v) = (keys[k].1, &vars[k]);
        let ty = f.ty;
        let value = match &f.kind {
            Kind::Vec { elem, .. } => {
                quote!(__wire::__private::cdr_encode_seq::<#elem>(&#v[..], __w);)
            }
            Kind::Char => quote!(__w.write_u8(*#v);),
            _ => quote! {
                if !<#ty as __wire::IpcMessage>::cdr_encode_key_value(#v, __w) {
                    return false;
                }
            },
        };
        member(f, value)
    };
    let positions: Vec<usize> = (0..keys.len()).collect();
    let mut by_id = positions.clone();
    by_id.sort_by_key(|k| keys[*k].1.id);
    let writes = in_either_order(
        positions.into_iter().map(write).collect(),
        by_id.into_iter().map(write).collect(),
        quote!(__w),
        quote!(),
    );
    quote! {
        fn cdr_encode_key_value(__key: &Self::Key, __w: &mut __wire::cdr::Writer) -> bool {
            #bind
            let __s = __w.begin_struct(#ext);
            #writes
            __s.end(__w);
            true
        }
    }
}

/// `cdr_encode_key`: the key members only (none for a struct without
/// keys), with `type Key` and `cdr_decode_key` to read them back.
fn key_fn(fields: &[Field<'_>], ext: &TokenStream, mutable: bool) -> TokenStream {
    let decode = key_decode(fields, ext, mutable);
    if !fields.iter().any(|f| f.attrs.key) {
        return decode;
    }
    let key_lens = len_lets(fields, &|i| {
        fields[i].attrs.key || fields.iter().any(|f| f.attrs.key && f.count_for == Some(i))
    });
    let write = |i: usize| {
        let f = &fields[i];
        let m = &f.member;
        let ty = f.ty;
        let value = match (&f.kind, f.count_for) {
            // a key member whose type has keys contributes its key; one without, all of it
            (Kind::Plain, None) | (Kind::SelfPtr, _) => quote! {
                if <#ty as __wire::IpcMessage>::KEYS.is_empty() {
                    __wire::IpcMessage::cdr_encode(&self.#m, __w);
                } else {
                    __wire::IpcMessage::cdr_encode_key(&self.#m, __w);
                }
            },
            _ => cdr_value(fields, i),
        };
        member(f, value)
    };
    let keys: Vec<usize> = (0..fields.len()).filter(|i| fields[*i].attrs.key).collect();
    let writes = in_either_order(
        keys.iter().map(|i| write(*i)).collect(),
        by_id(&keys, fields).into_iter().map(write).collect(),
        quote!(__w),
        quote!(),
    );
    quote! {
        fn cdr_encode_key(&self, __w: &mut __wire::cdr::Writer) {
            #(#key_lens)*
            let __s = __w.begin_struct(#ext);
            #writes
            __s.end(__w);
        }

        #decode
    }
}

/// The fields `keys` (indices into `fields`) in member-id order: the
/// order of the key-hash form (DDS-XTypes 1.3 §7.6.8; Cyclone DDS sorts
/// the keys by member id, scoped to their struct), where the serialized
/// key keeps definition order. The same unless ids are given out of order.
fn by_id(keys: &[usize], fields: &[Field<'_>]) -> Vec<usize> {
    let mut v = keys.to_vec();
    v.sort_by_key(|i| fields[*i].id);
    v
}

/// `decl` (the key members in definition order), or, when the ids put
/// them in another order, `decl` for the serialized key and `by_id` for
/// the key-hash form (`io` is the writer or reader that says which).
/// Each way is a block ending in `tail` (reads bind their variables
/// inside it and give them out through `tail`; writes have none).
fn in_either_order(
    decl: Vec<TokenStream>,
    by_id: Vec<TokenStream>,
    io: TokenStream,
    tail: TokenStream,
) -> TokenStream {
    let same = decl
        .iter()
        .map(ToString::to_string)
        .eq(by_id.iter().map(ToString::to_string));
    if same {
        quote!({ #(#decl)* #tail })
    } else {
        quote! {
            if #io.is_key_hash_form() {
                #(#by_id)*
                #tail
            } else {
                #(#decl)*
                #tail
            }
        }
    }
}
