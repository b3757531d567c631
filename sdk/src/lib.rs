//! # courier
//!
//! Typed messages for robots: derive [`IpcMessage`] on a struct and get the
//! CMU IPC format string, IPC marshalling byte-identical to the C library,
//! and DDS CDR (XCDR1 and XCDR2), all generated at compile time.
//!
//! ```
//! use courier::IpcMessage;
//!
//! #[derive(IpcMessage, Debug, PartialEq)]
//! #[ipc(numeric)]
//! enum Status { Wait, Send, Receive, Listen }
//!
//! #[derive(IpcMessage, Debug, PartialEq)]
//! struct T1 { i1: i32, status: Status, matrix: [[f64; 3]; 2], d1: f64 }
//!
//! assert_eq!(T1::FORMAT, "{int, {enum : 3}, [double:2,3], double}");
//! let t1 = T1 { i1: 666, status: Status::Send, matrix: [[0.0, 1.0, 2.0], [1.0, 2.0, 3.0]], d1: 3.14 };
//! let bytes = courier::ipc::to_vec(&t1);
//! assert_eq!(bytes.len(), 64);
//! assert_eq!(courier::ipc::from_slice::<T1>(&bytes).unwrap(), t1);
//! let cdr = courier::cdr::to_vec(&t1, courier::cdr::Encoding::Xcdr1Le);
//! assert_eq!(courier::cdr::from_slice::<T1>(&cdr).unwrap(), t1);
//! ```
#![warn(missing_docs)]
#![forbid(unsafe_code)]

pub use courier_derive::IpcMessage;
pub use courier_wire::{cdr, format, ipc, IpcMessage, NamedFormats};

#[doc(hidden)]
pub use courier_wire as __wire;
