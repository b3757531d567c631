//! Courier's servers and tools: the `central` binary (CMU IPC's central
//! server), the `xrce-agent` binary (a DDS-XRCE agent, MicroXRCEAgent's
//! command line), the `courier` CLI, and, as a library, what they are
//! built on: the embedded central, which lives in [`courier::central`]
//! (cargo feature `central` of `courier`) and is re-exported here
//! unchanged; the embeddable XRCE agent, [`xrce_agent::XrceAgent`]; and
//! code generation from IPC formats, XDR and IDL ([`gen`]).
//!
//! ```
//! # #[tokio::main(flavor = "current_thread")]
//! # async fn main() -> Result<(), Box<dyn std::error::Error>> {
//! use std::time::Duration;
//! use courier_broker::{CentralServer, LogSink};
//!
//! let central = CentralServer::builder()
//!     .port(0) // any free port, on 127.0.0.1
//!     .log_sink(LogSink::discard())
//!     .spawn()
//!     .await?;
//! let module = central.session("module1").connect().await?;
//! module.close().await;
//! tokio::time::timeout(Duration::from_secs(5), central.shutdown()).await?;
//! # Ok(()) }
//! ```
#![warn(missing_docs)]
#![deny(unsafe_code)]

pub use courier::central::*;

pub mod gen;
#[cfg(feature = "cli")]
#[doc(hidden)]
pub mod logging;
#[doc(hidden)]
pub mod signals;
pub mod xrce_agent;
mod xrce_state;
