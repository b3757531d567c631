//! Shared helpers for Courier integration tests.

pub mod domains;
pub mod netns;
pub mod peers;
