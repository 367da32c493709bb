//! The bench's hardware path: I/O behind a trait ([`io`]), the UDP bench protocol
//! ([`protocol`], specified in `docs/bench-protocol.md`), calibration from raw counts and volts
//! to SI units ([`calibration`]) and real-time pacing ([`pacing`]). The `BenchHardware` FMU
//! ([`crate::models::bench_hardware`]) puts them together with the interlocks.

pub mod calibration;
pub mod io;
pub mod pacing;
pub mod protocol;
