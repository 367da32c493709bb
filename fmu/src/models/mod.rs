//! The bench models: plain Rust structs that know nothing of C.

pub mod bench;
pub mod bench_hardware;
pub mod bench_plant;
pub mod clutch_scheduler;
pub mod gait;
pub mod impedance;
pub mod pid;
