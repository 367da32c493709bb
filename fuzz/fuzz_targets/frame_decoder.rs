//! Fuzzes the bench protocol's frame decoder and session receive filter: no input may panic,
//! any frame that decodes re-encodes to exactly the same bytes (nothing is silently
//! repaired), no field is read before the tag is verified, every datagram is accepted or
//! counted. The properties live in `protocol::fuzzing`, shared with the test suite's bounded
//! run (`tests/tests/protocol_fuzz.rs`).

#![no_main]

use libfuzzer_sys::fuzz_target;

#[path = "../../fmu/src/hardware/protocol/mod.rs"]
#[allow(dead_code, missing_docs, unused_imports)] // the targets use part of the module
mod protocol;

fuzz_target!(|data: &[u8]| {
    protocol::fuzzing::frame_decoder(data);
});
