//! Fuzzes the SSP archive reader (`ssp::read_file_within`) on arbitrary bytes as an `.ssp`
//! file, within a small archive budget: no input panics it or extracts past the budget; the
//! description of an archive read round-trips. The properties live in
//! `fuzz/properties/readers.rs`, shared with the test suite's bounded run
//! (`tests/tests/readers_fuzz.rs`).

#![no_main]

use libfuzzer_sys::fuzz_target;

#[path = "../properties/readers.rs"]
#[allow(dead_code)]
mod readers;

fuzz_target!(|data: &[u8]| {
    readers::ssp_archive(data);
});
