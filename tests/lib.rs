//! Shared helpers for Courier integration tests.
