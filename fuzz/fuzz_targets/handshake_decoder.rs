//! Fuzzes the bench protocol's handshake: the client's reading of WELCOME and REFUSE frames
//! (only an authentic answer carrying its own nonce opens a session) and the decoding of
//! HELLO frames, as given and with a valid handshake tag. The properties live in
//! `protocol::fuzzing`, shared with the test suite's bounded run.

#![no_main]

use libfuzzer_sys::fuzz_target;

#[path = "../../fmu/src/hardware/protocol/mod.rs"]
#[allow(dead_code, missing_docs, unused_imports)] // the targets use part of the module
mod protocol;

fuzz_target!(|data: &[u8]| {
    protocol::fuzzing::handshake_decoder(data);
});
