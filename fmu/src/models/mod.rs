//! The bench models: plain Rust structs that know nothing of C.

pub mod gait;
