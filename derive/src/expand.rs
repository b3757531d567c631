//! Code generation: the format strings, IPC and CDR code, all from one AST.

use proc_macro2::{Literal, TokenStream};
use quote::{format_ident, quote, quote_spanned};
use syn::spanned::Spanned;

use crate::ast::{Container, Data, Enum, Field, Kind};
use crate::attr::Extensibility;

/// Expands a checked container into `const _: () = { ... };`.
pub fn expand(c: &Container<'_>) -> TokenStream {
    let krate = match &c.attrs.krate {
        Some(p) => quote!(#p),
        None => quote!(::courier::__wire),
    };
    let body = match &c.data {
        Data::Struct(fields) => expand_struct(c, fields),
        Data::Enum(e) => expand_enum(c, e),
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

/// `TYPE_NAME`: the attribute, or the Rust path (plus `<params>` for generics),
/// as hidden inherent constants when it must be built at compile time.
fn type_name(c: &Container<'_>) -> (TokenStream, TokenStream) {
    let ident = c.ident.to_string();
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

fn ext_tokens(e: Extensibility) -> TokenStream {
    match e {
        Extensibility::Final => quote!(__wire::cdr::Extensibility::Final),
        Extensibility::Appendable => quote!(__wire::cdr::Extensibility::Appendable),
        Extensibility::Mutable => quote!(__wire::cdr::Extensibility::Mutable),
    }
}

fn var(i: usize) -> syn::Ident {
    format_ident!("__f{}", i)
}

fn len_var(i: usize) -> syn::Ident {
    format_ident!("__n{}", i)
}

fn expand_struct(c: &Container<'_>, fields: &[Field<'_>]) -> TokenStream {
    let ident = c.ident;
    let g = generics(c);
    let (impl_g, ty_g, where_c) = g.split_for_impl();
    let is_generic =
        c.generics.type_params().next().is_some() || c.generics.const_params().next().is_some();
    let ext = ext_tokens(c.extensibility());
    let mutable = c.extensibility() == Extensibility::Mutable;

    // ---- format string ----
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
        build = match &f.kind {
            Kind::Plain => {
                let msg = format!(
                    "field `{}` of `{}` has a type with an empty IPC format (an empty message such as `()` or a unit struct), which cannot be a field",
                    f.name, ident
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
        .map_or_else(|| ident.to_string(), |(n, _)| n.clone());
    let (type_name, type_name_consts) = type_name(c);

    let name_consts = if named {
        quote! {
            const FIELD_FORMAT: &'static str = #format_name;
            const FORMAT_NAME: ::core::option::Option<&'static str> = ::core::option::Option::Some(#format_name);
        }
    } else {
        quote!()
    };

    // ---- sizes ----
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
            Kind::Vec { .. } => {
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

    // ---- named formats ----
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

    // ---- keys ----
    let keys: Vec<&str> = fields
        .iter()
        .filter(|f| f.attrs.key)
        .map(|f| f.name.as_str())
        .collect();

    // ---- length of each Vec, capped by its count type and by int32 ----
    let len_lets = |only: &dyn Fn(usize) -> bool| -> Vec<TokenStream> {
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
    };
    let all_lens = len_lets(&|_| true);

    // ---- IPC ----
    let mut ipc_enc = Vec::new();
    let mut ipc_dec = Vec::new();
    for (i, f) in fields.iter().enumerate() {
        let m = &f.member;
        let ty = f.ty;
        let v = var(i);
        if let Some(vec) = f.count_for {
            let n = len_var(vec);
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
        }
    }
    let members: Vec<&syn::Member> = fields.iter().map(|f| &f.member).collect();
    let vars: Vec<syn::Ident> = (0..fields.len()).map(var).collect();

    // ---- CDR ----
    let cdr_value = |i: usize, f: &Field<'_>| -> TokenStream {
        let m = &f.member;
        let ty = f.ty;
        if let Some(vec) = f.count_for {
            let n = len_var(vec);
            return quote!(__wire::IpcMessage::cdr_encode(&(#n as #ty), __w););
        }
        match &f.kind {
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
    };
    let cdr_read = |f: &Field<'_>| -> TokenStream {
        let ty = f.ty;
        match &f.kind {
            Kind::Char => quote!(__r.read_u8()?),
            Kind::Vec { elem, .. } => quote!(__wire::__private::cdr_decode_seq::<#elem>(__r)?),
            Kind::Plain | Kind::SelfPtr => quote!(<#ty as __wire::IpcMessage>::cdr_decode(__r)?),
        }
    };
    let member = |f: &Field<'_>, value: TokenStream| -> TokenStream {
        let id = f.id;
        let mu = f.attrs.key || f.attrs.must_understand;
        quote! {
            let __m = __s.begin_member(__w, #id, #mu);
            #value
            __s.end_member(__w, __m);
        }
    };
    let cdr_enc: Vec<TokenStream> = fields
        .iter()
        .enumerate()
        .map(|(i, f)| member(f, cdr_value(i, f)))
        .collect();
    let cdr_dec = if mutable {
        let decls = fields.iter().enumerate().map(|(i, f)| {
            let v = var(i);
            let ty = f.ty;
            quote!(let mut #v: ::core::option::Option<#ty> = ::core::option::Option::None;)
        });
        let arms = fields.iter().enumerate().map(|(i, f)| {
            let v = var(i);
            let id = f.id;
            let read = cdr_read(f);
            quote!(#id => #v = ::core::option::Option::Some(#read),)
        });
        let unwraps = fields.iter().enumerate().map(|(i, f)| {
            let v = var(i);
            let id = f.id;
            let name = &f.name;
            if f.optional {
                // an absent optional member is left out of a mutable struct
                return quote!(let #v = #v.unwrap_or(::core::option::Option::None););
            }
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
    } else {
        let reads = fields.iter().enumerate().map(|(i, f)| {
            let v = var(i);
            let ty = f.ty;
            let read = cdr_read(f);
            quote!(let #v: #ty = #read;)
        });
        quote! {
            let __s = __r.begin_struct(#ext)?;
            #(#reads)*
            __s.end(__r)?;
        }
    };

    // ---- key ----
    let key_fn = if keys.is_empty() {
        quote!()
    } else {
        let key_lens = len_lets(&|i| {
            fields[i].attrs.key || fields.iter().any(|f| f.attrs.key && f.count_for == Some(i))
        });
        let writes = fields
            .iter()
            .enumerate()
            .filter(|(_, f)| f.attrs.key)
            .map(|(i, f)| {
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
                    _ => cdr_value(i, f),
                };
                member(f, value)
            });
        quote! {
            fn cdr_encode_key(&self, __w: &mut __wire::cdr::Writer) {
                #(#key_lens)*
                let __s = __w.begin_struct(#ext);
                #(#writes)*
                __s.end(__w);
            }
        }
    };

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
            const CDR_BOUNDED: bool = #(#bounded)&&*;
            const CDR_KEY_BOUNDED: bool = #(#key_bounded)&&*;
            const KEYS: &'static [&'static str] = &[#(#keys),*];

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
                #(#cdr_enc)*
                __s.end(__w);
            }

            fn cdr_decode(__r: &mut __wire::cdr::Reader<'_>) -> ::core::result::Result<Self, __wire::cdr::DecodeError> {
                #cdr_dec
                ::core::result::Result::Ok(Self { #(#members: #vars),* })
            }

            #key_fn
        }
    }
}

fn expand_enum(c: &Container<'_>, e: &Enum<'_>) -> TokenStream {
    let ident = c.ident;
    let g = generics(c);
    let (impl_g, ty_g, where_c) = g.split_for_impl();
    let format = if e.numeric {
        let max = e.variants.iter().map(|v| v.value).max().unwrap_or(0);
        format!("{{enum : {max}}}")
    } else {
        let names: Vec<String> = e.variants.iter().map(|v| v.ident.to_string()).collect();
        format!("{{enum {}}}", names.join(", "))
    };
    let (type_name, type_name_consts) = type_name(c);
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
    quote! {
        #inherent

        #[automatically_derived]
        impl #impl_g __wire::IpcMessage for #ident #ty_g #where_c {
            const FORMAT: &'static str = #format;
            const TYPE_NAME: &'static str = #type_name;
            const IPC_MIN_SIZE: usize = 4;
            const CDR_MIN_SIZE: usize = 4;
            const CDR_BOUNDED: bool = true;
            const CDR_PRIMITIVE: bool = true;

            fn ipc_encode(&self, __w: &mut __wire::ipc::Writer) {
                __w.write_i32(match self { #(Self::#idents => #values,)* });
            }

            fn ipc_decode(__r: &mut __wire::ipc::Reader<'_>) -> ::core::result::Result<Self, __wire::ipc::DecodeError> {
                let __offset = __r.position();
                match __r.read_i32()? {
                    #(#values => ::core::result::Result::Ok(Self::#idents),)*
                    __v => ::core::result::Result::Err(__wire::ipc::DecodeError::InvalidEnum {
                        offset: __offset,
                        value: __v as i64,
                        type_name: <Self as __wire::IpcMessage>::TYPE_NAME,
                    }),
                }
            }

            fn cdr_encode(&self, __w: &mut __wire::cdr::Writer) {
                __w.write_i32(match self { #(Self::#idents => #values,)* });
            }

            fn cdr_decode(__r: &mut __wire::cdr::Reader<'_>) -> ::core::result::Result<Self, __wire::cdr::DecodeError> {
                __r.align(4)?;
                let __offset = __r.position();
                match __r.read_i32()? {
                    #(#values => ::core::result::Result::Ok(Self::#idents),)*
                    __v => ::core::result::Result::Err(__wire::cdr::DecodeError::InvalidEnum {
                        offset: __offset,
                        value: __v as i64,
                        type_name: <Self as __wire::IpcMessage>::TYPE_NAME,
                    }),
                }
            }

            fn cdr_encode_key(&self, __w: &mut __wire::cdr::Writer) {
                __wire::IpcMessage::cdr_encode(self, __w);
            }
        }
    }
}
