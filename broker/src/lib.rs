//! Courier's servers and tools. The IPC `central` server lands here.
#![warn(missing_docs)]
