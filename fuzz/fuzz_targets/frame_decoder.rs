//! Fuzzes the bench protocol's frame decoder and receive filter: no input may panic, and any
//! frame that decodes re-encodes to exactly the same bytes (nothing is silently repaired).

#![no_main]

use libfuzzer_sys::fuzz_target;

#[path = "../../fmu/src/hardware/protocol.rs"]
#[allow(dead_code, missing_docs)]
mod protocol;

fuzz_target!(|data: &[u8]| {
    if let Ok(frame) = protocol::Frame::decode(data) {
        assert_eq!(frame.encode(), data);
    }
    let mut rx = protocol::Receiver::new(0);
    for chunk in data.chunks(protocol::MAX_FRAME_LEN.max(1)) {
        let _ = rx.accept(chunk);
    }
});
