//! The bench's hardware path: I/O behind a trait ([`io`]), the UDP bench protocol
//! ([`protocol`], specified in `docs/bench-protocol.md`), calibration from raw counts and volts
//! to SI units ([`calibration`]), cross-checks between sensors ([`consistency`]), real-time pacing ([`pacing`]) and the operating system's
//! real-time support it uses ([`realtime`]). The `BenchHardware` FMU
//! ([`crate::models::bench_hardware`]) puts them together with the interlocks.

pub mod calibration;
pub mod consistency;
pub mod io;
pub mod pacing;
pub mod protocol;
pub mod realtime;
