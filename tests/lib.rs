//! Shared helpers for Courier integration tests.

pub mod peers;
