//! Fuzzes the SSD reader (`ssp::read_ssd_with`) on arbitrary text, its parameter bindings
//! resolving to the text itself and to an empty set: no input panics it; what it reads is
//! written and reads back equal. The properties live in `fuzz/properties/readers.rs`, shared
//! with the test suite's bounded run (`tests/tests/readers_fuzz.rs`).

#![no_main]

use libfuzzer_sys::fuzz_target;

#[path = "../properties/readers.rs"]
#[allow(dead_code)]
mod readers;

fuzz_target!(|data: &[u8]| {
    readers::ssd_text(data);
});
