//! Fuzzes the parameter-set reader (`ParameterSet::from_xml`, `.ssv`): no input panics it; what
//! it reads is written and reads back equal, with the same content hash. The properties live in
//! `fuzz/properties/readers.rs`, shared with the test suite's bounded run
//! (`tests/tests/readers_fuzz.rs`).

#![no_main]

use libfuzzer_sys::fuzz_target;

#[path = "../properties/readers.rs"]
#[allow(dead_code)]
mod readers;

fuzz_target!(|data: &[u8]| {
    readers::ssv_text(data);
});
