//! Shared helpers for slipguard's cross-crate integration tests.
