//! The properties the fuzz targets (`fuzz/fuzz_targets/`) and the test suite's bounded run
//! (`tests/tests/protocol_fuzz.rs`) check on arbitrary input, in one place so that both check
//! the same: no input panics a decoder, nothing is silently repaired (whatever decodes
//! re-encodes to the same bytes), and nothing unauthenticated is accepted.
//!
//! Random bytes almost never carry a valid tag, so each target also runs the input with its
//! tag recomputed under the key: the field decoders behind the tag check get exercised too.

use super::auth::{Key, NONCE_LEN, TAG_LEN, TagKey};
use super::{BenchSetup, ClientHandshake, Frame, HandshakeReply, Payload, Receiver, SetValueKind};

/// The key the fuzz targets authenticate with.
pub fn fuzz_key() -> Key {
    Key::from_bytes([0x42; 32])
}

/// The session and nonce of the fuzzed client handshake.
pub const FUZZ_SESSION: u32 = 7;
/// The client nonce of the fuzzed handshake.
pub const FUZZ_NONCE: [u8; NONCE_LEN] = [1; NONCE_LEN];

/// `data` with its last [`TAG_LEN`] bytes replaced by the tag of the rest under `key` (as is
/// if shorter than a tag).
pub fn with_valid_tag(data: &[u8], key: &TagKey) -> Vec<u8> {
    let mut v = data.to_vec();
    if v.len() >= TAG_LEN {
        let n = v.len() - TAG_LEN;
        let t = key.tag(&v[..n]);
        v[n..].copy_from_slice(&t);
    }
    v
}

fn check_frame(bytes: &[u8], key: &TagKey) {
    let _ = Frame::peek(bytes);
    match Frame::decode(bytes, key) {
        Ok(f) => assert_eq!(f.encode(key), bytes, "a decoded frame re-encodes unchanged"),
        Err(super::DecodeError::ZeroSequence | super::DecodeError::BadPayload(_)) => {
            // Fields are read only behind a verified tag.
            let n = bytes.len() - TAG_LEN;
            assert!(
                key.verify(&bytes[..n], &bytes[n..]),
                "fields read before the tag was verified"
            );
        }
        Err(_) => {}
    }
}

/// The frame decoder and the session receive filter on `data`: as given, and with a valid
/// tag under the session key.
pub fn frame_decoder(data: &[u8]) {
    let key = TagKey::new(b"kneebench fuzz session key");
    check_frame(data, &key);
    check_frame(&with_valid_tag(data, &key), &key);
    let mut rx = Receiver::new(FUZZ_SESSION, key.clone());
    for chunk in data.chunks(super::MAX_FRAME_LEN) {
        let _ = rx.accept(chunk);
        let _ = rx.accept(&with_valid_tag(chunk, &key));
    }
    let c = rx.counters;
    assert_eq!(
        c.accepted + c.rejected(),
        2 * data.chunks(super::MAX_FRAME_LEN).count() as u64,
        "every datagram is accepted or counted as rejected"
    );
}

/// The client's handshake (WELCOME / REFUSE decoding, nonce check) and the server's HELLO
/// decoding on `data`: as given, and with a valid handshake tag.
pub fn handshake_decoder(data: &[u8]) {
    let key = fuzz_key();
    let hk = key.handshake();
    let setup = BenchSetup {
        configuration: 1,
        test_kind: SetValueKind::Current,
        load_kind: SetValueKind::Current,
    };
    for bytes in [data.to_vec(), with_valid_tag(data, &hk)] {
        let mut hs = ClientHandshake::with_nonce(&key, setup, FUZZ_SESSION, FUZZ_NONCE);
        match hs.receive(&bytes) {
            Ok(HandshakeReply::Welcome(s)) => {
                // Only an authentic answer to this very handshake opens a session.
                let f = Frame::decode(&bytes, &hk).expect("an accepted welcome is authentic");
                assert_eq!(f.session, FUZZ_SESSION);
                match f.payload {
                    Payload::Welcome(w) => {
                        assert_eq!(w.client_nonce, FUZZ_NONCE);
                        assert_eq!(w.latched, s.latched);
                    }
                    other => panic!("a session from {other:?}"),
                }
            }
            Ok(HandshakeReply::Refused(r)) => {
                assert_eq!(r.client_nonce, FUZZ_NONCE);
                assert!(r.text().len() <= super::handshake::REFUSE_TEXT_LEN);
            }
            Err(_) => {}
        }
        if let Ok(f) = Frame::decode(&bytes, &hk) {
            assert_eq!(f.encode(&hk), bytes);
            if let Payload::Hello(h) = f.payload {
                let _ = setup.difference(&h.setup);
            }
        }
    }
}
