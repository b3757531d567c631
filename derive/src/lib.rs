//! # courier-derive
//!
//! `#[derive(IpcMessage)]`: the CMU IPC format string, IPC marshalling
//! byte-identical to the C library, and DDS CDR (XCDR1 and XCDR2) for a Rust
//! struct or fieldless enum, all generated at compile time. Use it through
//! the `courier` crate (`use courier::IpcMessage;`), which re-exports both the
//! derive and the trait under that name.
//!
//! ```
//! # use courier_derive::IpcMessage;
//! # use courier_wire::{self as wire, IpcMessage as _};
//! #[derive(IpcMessage, Debug, PartialEq)]
//! # #[ipc(crate = "::courier_wire")]
//! #[ipc(numeric)]
//! enum Status { Wait, Send, Receive, Listen }
//!
//! #[derive(IpcMessage, Debug, PartialEq)]
//! # #[ipc(crate = "::courier_wire")]
//! struct T1 { i1: i32, status: Status, matrix: [[f64; 3]; 2], d1: f64 }
//!
//! #[derive(IpcMessage, Debug, PartialEq)]
//! # #[ipc(crate = "::courier_wire")]
//! struct T2 {
//!     str1: String,
//!     count: i32,
//!     #[ipc(len = "count")]
//!     t1: Vec<T1>,
//!     status: Status,
//! }
//!
//! assert_eq!(T1::FORMAT, "{int, {enum : 3}, [double:2,3], double}");
//! assert_eq!(T2::FORMAT, "{string, int, <T1:2>, {enum : 3}}");
//! let t2 = T2 { str1: "hi".into(), count: 0, t1: vec![], status: Status::Listen };
//! let bytes = wire::ipc::to_vec(&t2);
//! assert_eq!(wire::ipc::from_slice::<T2>(&bytes).unwrap(), t2);
//! ```
//!
//! The type mapping, every `#[ipc(...)]` attribute and the choices the
//! derive makes are documented where users meet them: the `courier`
//! crate's `derive_guide` module.
#![warn(missing_docs)]
#![forbid(unsafe_code)]

use proc_macro::TokenStream;

mod ast;
mod attr;
mod ctxt;
mod expand;
mod names;

/// Derives `IpcMessage`: the type mapping and the `#[ipc(...)]`
/// attributes are in the `courier` crate's `derive_guide` module.
#[proc_macro_derive(IpcMessage, attributes(ipc))]
pub fn derive_ipc_message(input: TokenStream) -> TokenStream {
    let input = syn::parse_macro_input!(input as syn::DeriveInput);
    derive(&input)
        .unwrap_or_else(syn::Error::into_compile_error)
        .into()
}

fn derive(input: &syn::DeriveInput) -> Result<proc_macro2::TokenStream, syn::Error> {
    let cx = ctxt::Ctxt::new();
    let container = ast::parse(&cx, input);
    cx.check()?;
    // `ast::parse` returns `None` only after recording an error.
    Ok(container.map(|c| expand::expand(&c)).unwrap_or_default())
}
