//! `check_lengths`: each `Vec` with a length field against what that
//! field's type can say (the encoders send no more than that), each
//! bounded `String` or `Vec` against its bound, and the fields whose types
//! check lengths (or chars) of their own.

use proc_macro2::TokenStream;
use quote::quote;

use crate::ast::{Field, Kind};

/// `CHECKS_LENGTHS` and `check_lengths` of a struct.
pub(super) struct Lengths {
    pub(super) checks: TokenStream,
    pub(super) body: Vec<TokenStream>,
}

pub(super) fn lengths(fields: &[Field<'_>]) -> Lengths {
    // a length field of its own: always something to check
    let mut flags = vec![quote!(false)];
    let mut body = Vec::new();
    for f in fields {
        if f.count_for.is_some() {
            continue;
        }
        let m = &f.member;
        let ty = f.ty;
        if let Some((bound, _)) = f.attrs.bound {
            // a `String`'s bytes (CDR counts them, without the NUL) or a
            // `Vec`'s elements: `len()` of either
            let (field, unit) = (
                &f.name,
                if matches!(f.kind, Kind::Vec { .. }) {
                    "elements"
                } else {
                    "bytes"
                },
            );
            flags.push(quote!(true));
            body.push(quote! {
                if self.#m.len() as u64 > #bound {
                    return ::core::result::Result::Err(__wire::LengthError::Bound {
                        field: #field,
                        len: self.#m.len(),
                        unit: #unit,
                        bound: #bound,
                    });
                }
            });
        }
        match &f.kind {
            Kind::Plain => {
                let field = &f.name;
                flags.push(quote!(<#ty as __wire::IpcMessage>::CHECKS_LENGTHS));
                body.push(quote! {
                    if <#ty as __wire::IpcMessage>::CHECKS_LENGTHS {
                        __wire::IpcMessage::check_lengths(&self.#m)
                            .map_err(|__e| __e.in_field(#field))?;
                    }
                });
            }
            Kind::Vec { elem, len } => {
                if let Some(j) = len {
                    flags.push(quote!(true));
                    let count = &fields[*j];
                    let cty = count.ty;
                    let (field, count_name) = (&f.name, &count.name);
                    let cty_name = quote!(#cty).to_string().replace(' ', "");
                    body.push(quote! {
                        let __max = ::core::cmp::min(<#cty>::MAX as u64, 0x7fff_ffff_u64);
                        if self.#m.len() as u64 > __max {
                            return ::core::result::Result::Err(__wire::LengthError::Count {
                                field: #field,
                                count: #count_name,
                                count_type: #cty_name,
                                len: self.#m.len(),
                                max: __max,
                            });
                        }
                    });
                }
                // `true`, not the element's constant: a `Vec<Self>` (or
                // of a type holding a `Vec` of this one) would make the
                // constant depend on itself
                flags.push(quote!(true));
                let field = &f.name;
                body.push(quote! {
                    if <#elem as __wire::IpcMessage>::CHECKS_LENGTHS {
                        for __e in self.#m.iter() {
                            __wire::IpcMessage::check_lengths(__e)
                                .map_err(|__e| __e.in_field(#field))?;
                        }
                    }
                });
            }
            Kind::NdVec { .. } => {
                let elem = quote!(<#ty as __wire::__private::NdField>::Elem);
                flags.push(quote!(true));
                let field = &f.name;
                body.push(quote! {
                    if <#elem as __wire::IpcMessage>::CHECKS_LENGTHS {
                        for __e in ::core::convert::AsRef::<[#elem]>::as_ref(&self.#m) {
                            __wire::IpcMessage::check_lengths(__e)
                                .map_err(|__e| __e.in_field(#field))?;
                        }
                    }
                });
            }
            // a pointer to the struct itself: walked, but it cannot decide
            // the constant it is part of
            Kind::SelfPtr => body.push(quote! {
                if let ::core::option::Option::Some(__p) = &self.#m {
                    __wire::IpcMessage::check_lengths(&**__p)?;
                }
            }),
            Kind::Char => {}
        }
    }
    Lengths {
        checks: quote!(#(#flags)||*),
        body,
    }
}
