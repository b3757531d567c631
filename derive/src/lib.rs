//! `#[derive(IpcMessage)]`.
use proc_macro::TokenStream;

/// Derives `courier_wire::IpcMessage`.
#[proc_macro_derive(IpcMessage, attributes(ipc))]
pub fn derive_ipc_message(input: TokenStream) -> TokenStream {
    let _ = input;
    TokenStream::new()
}
