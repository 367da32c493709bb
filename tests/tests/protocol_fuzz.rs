//! The bench protocol's decoders under a bounded fuzzing run in the test suite: the frame
//! decoder and the handshake decoder get thousands of generated inputs each (random bytes,
//! valid frames of every type, and their mutations), and the committed seed corpus of the
//! cargo-fuzz targets (`fuzz/seeds/<target>/`) is replayed. The properties are those of the
//! fuzz targets (`protocol::fuzzing`): no panic, nothing silently repaired, no field read
//! before the tag is verified, every datagram accepted or counted.
//!
//! `KNEEBENCH_WRITE_FUZZ_SEEDS=1 cargo test -p kneebench-tests --test protocol_fuzz` rewrites
//! the seeds from the current encoder (after a change of the frame format).

use std::path::PathBuf;

use kneebench_harness::bench_protocol::auth::{Key, TagKey};
use kneebench_harness::bench_protocol::fuzzing::{
    FUZZ_NONCE, FUZZ_SESSION, frame_decoder, fuzz_key, handshake_decoder,
};
use kneebench_harness::bench_protocol::{
    Acknowledge, BenchSetup, Command, FaultInjection, Frame, Hello, Payload, Refusal,
    SafeStateRequest, Sample, SetValueKind, Welcome, reason, refusal, status,
};
use proptest::prelude::*;

fn kind() -> impl Strategy<Value = SetValueKind> {
    prop_oneof![Just(SetValueKind::Voltage), Just(SetValueKind::Current)]
}

fn sample() -> impl Strategy<Value = Sample> {
    (
        any::<u32>(),
        any::<u32>(),
        any::<u64>(),
        0..=status::DEFINED,
        0..=reason::MAX,
        any::<i32>(),
        any::<i32>(),
        proptest::array::uniform6(-1e3f64..1e3),
    )
        .prop_map(|(rq, lc, t, st, r, a, b, analog)| Sample {
            request_sequence: rq,
            last_command_sequence: lc,
            server_time_us: t,
            status: st,
            safe_reason: r,
            test_counts: a,
            load_counts: b,
            analog,
        })
}

fn payload() -> impl Strategy<Value = Payload> {
    prop_oneof![
        (
            -100.0f64..100.0,
            -100.0f64..100.0,
            any::<[bool; 3]>(),
            kind(),
            kind()
        )
            .prop_map(|(a, b, o, k1, k2)| Payload::Command(Command {
                test_set_value: a,
                load_set_value: b,
                test_enable: o[0],
                load_enable: o[1],
                clutch: o[2],
                test_kind: k1,
                load_kind: k2,
            })),
        Just(Payload::Heartbeat),
        sample().prop_map(Payload::Sample),
        sample().prop_map(Payload::SafeStateAck),
        (0..=reason::MAX).prop_map(|r| Payload::SafeState(SafeStateRequest { reason: r })),
        (any::<u32>(), 0.0f64..10.0).prop_map(|(count, d)| Payload::FaultInject(
            FaultInjection::DelayReplies { count, delay_s: d }
        )),
        (any::<[u8; 16]>(), 0u8..=2, kind(), kind()).prop_map(|(n, c, k1, k2)| {
            Payload::Hello(Hello {
                nonce: n,
                setup: BenchSetup {
                    configuration: c,
                    test_kind: k1,
                    load_kind: k2,
                },
            })
        }),
        (
            any::<[u8; 16]>(),
            any::<[u8; 16]>(),
            prop_oneof![Just(0u8), Just(1), Just(2), Just(3), Just(5)]
        )
            .prop_map(|(a, b, l)| Payload::Welcome(Welcome {
                client_nonce: a,
                server_nonce: b,
                latched: l,
            })),
        (1..=refusal::MAX, any::<[u8; 16]>(), "[ -~]{0,80}")
            .prop_map(|(c, n, t)| Payload::Refuse(Refusal::new(c, n, &t))),
        prop_oneof![Just(1u8), Just(2), Just(3), Just(5)]
            .prop_map(|r| Payload::Acknowledge(Acknowledge { reason: r })),
    ]
}

fn session_key() -> TagKey {
    TagKey::new(b"kneebench fuzz session key")
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 4000, ..ProptestConfig::default() })]

    #[test]
    fn the_frame_decoder_takes_any_bytes(data in proptest::collection::vec(any::<u8>(), 0..260)) {
        frame_decoder(&data);
    }

    #[test]
    fn the_handshake_decoder_takes_any_bytes(data in proptest::collection::vec(any::<u8>(), 0..260)) {
        handshake_decoder(&data);
    }

    /// Well-formed headers with random payloads of the right length, tagged: every field
    /// decoder sees arbitrary values (random bytes alone rarely get past the header).
    #[test]
    fn every_payload_decoder_takes_any_fields(
        ty in 1u8..=10,
        session in any::<u32>(),
        sequence in any::<u32>(),
        fill in proptest::collection::vec(any::<u8>(), 84),
        sparse in any::<bool>(),
    ) {
        use kneebench_harness::bench_protocol::FrameType;
        let len = FrameType::from_u8(ty).unwrap().payload_len();
        let mut bytes = vec![b'K', b'N', b'B', b'P', 2, ty];
        bytes.extend_from_slice(&(len as u16).to_be_bytes());
        bytes.extend_from_slice(&session.to_be_bytes());
        bytes.extend_from_slice(&sequence.to_be_bytes());
        // Sparse payloads (mostly zeros) reach the checks behind the reserved fields.
        bytes.extend(fill[..len].iter().map(|&b| if sparse && b % 4 != 0 { 0 } else { b }));
        bytes.extend_from_slice(&[0; 16]);
        let tagged = kneebench_harness::bench_protocol::fuzzing::with_valid_tag(&bytes, &session_key());
        frame_decoder(&tagged);
        let hk = fuzz_key().handshake();
        handshake_decoder(&kneebench_harness::bench_protocol::fuzzing::with_valid_tag(&bytes, &hk));
    }

    #[test]
    fn valid_frames_round_trip_and_every_mutation_is_refused(
        payload in payload(),
        session in 1u32..,
        sequence in 1u32..,
        flip in any::<(usize, u8)>(),
        cut in any::<usize>(),
    ) {
        let key = session_key();
        let f = Frame { session, sequence, payload };
        let bytes = f.encode(&key);
        prop_assert_eq!(Frame::decode(&bytes, &key), Ok(f));
        frame_decoder(&bytes);
        handshake_decoder(&bytes);
        // Any changed bit, any truncation: refused (a 128-bit tag is not forged by chance).
        let mut m = bytes.clone();
        let bit = flip.1 | 1;
        let at = flip.0 % m.len();
        m[at] ^= bit;
        prop_assert!(Frame::decode(&m, &key).is_err());
        frame_decoder(&m);
        let short = &bytes[..cut % bytes.len()];
        prop_assert!(Frame::decode(short, &key).is_err());
        frame_decoder(short);
    }
}

fn seeds_dir(target: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../fuzz/seeds")
        .join(target)
}

/// The seeds: one valid frame of every type (under the targets' keys, answering the fuzzed
/// handshake where it is one), and a few near misses.
fn seeds() -> Vec<(&'static str, String, Vec<u8>)> {
    let sk = session_key();
    let hk = fuzz_key().handshake();
    let s = Sample {
        request_sequence: 3,
        last_command_sequence: 2,
        server_time_us: 1000,
        status: status::TEST_ENABLED,
        safe_reason: 0,
        test_counts: -5,
        load_counts: 7,
        analog: [5.4, 0.25, 2.5, 2.5, 3.3, 6.7],
    };
    let frames = [
        (
            "command",
            Payload::Command(Command::safe(SetValueKind::Current, SetValueKind::Current)),
        ),
        ("heartbeat", Payload::Heartbeat),
        ("sample", Payload::Sample(s)),
        (
            "safe_state",
            Payload::SafeState(SafeStateRequest { reason: 1 }),
        ),
        ("safe_state_ack", Payload::SafeStateAck(s)),
        (
            "fault",
            Payload::FaultInject(FaultInjection::Force {
                channel: 1,
                volts: 9.0,
            }),
        ),
        (
            "acknowledge",
            Payload::Acknowledge(Acknowledge { reason: 2 }),
        ),
    ];
    let mut out = Vec::new();
    for (name, p) in frames {
        let b = Frame {
            session: FUZZ_SESSION,
            sequence: 5,
            payload: p,
        }
        .encode(&sk);
        out.push(("frame_decoder", name.to_string(), b.clone()));
        out.push((
            "frame_decoder",
            format!("{name}_truncated"),
            b[..b.len() - 3].to_vec(),
        ));
    }
    let mut v1 = vec![b'K', b'N', b'B', b'P', 1, 2, 0, 0, 0, 0, 0, 7, 0, 0, 0, 1];
    v1.extend_from_slice(&[0x12, 0x34, 0x56, 0x78]);
    out.push(("frame_decoder", "version_1_heartbeat".into(), v1));
    let hs = [
        (
            "welcome",
            Payload::Welcome(Welcome {
                client_nonce: FUZZ_NONCE,
                server_nonce: [2; 16],
                latched: 2,
            }),
        ),
        (
            "refuse",
            Payload::Refuse(Refusal::new(
                refusal::SETUP,
                FUZZ_NONCE,
                "configuration differs: bench SEA, client DA",
            )),
        ),
        (
            "hello",
            Payload::Hello(Hello {
                nonce: FUZZ_NONCE,
                setup: BenchSetup {
                    configuration: 2,
                    test_kind: SetValueKind::Voltage,
                    load_kind: SetValueKind::Current,
                },
            }),
        ),
        (
            "welcome_other_nonce",
            Payload::Welcome(Welcome {
                client_nonce: [9; 16],
                server_nonce: [2; 16],
                latched: 0,
            }),
        ),
    ];
    for (name, p) in hs {
        let b = Frame {
            session: FUZZ_SESSION,
            sequence: 1,
            payload: p,
        }
        .encode(&hk);
        out.push(("handshake_decoder", name.to_string(), b));
    }
    let wrong = Frame {
        session: FUZZ_SESSION,
        sequence: 1,
        payload: hs_welcome(),
    }
    .encode(&Key::from_bytes([7; 32]).handshake());
    out.push(("handshake_decoder", "welcome_wrong_key".into(), wrong));
    out
}

fn hs_welcome() -> Payload {
    Payload::Welcome(Welcome {
        client_nonce: FUZZ_NONCE,
        server_nonce: [3; 16],
        latched: 0,
    })
}

#[test]
fn the_committed_fuzz_seeds_are_current_and_replay_cleanly() {
    let write = std::env::var("KNEEBENCH_WRITE_FUZZ_SEEDS").is_ok_and(|v| v == "1");
    let mut count = 0;
    for (target, name, bytes) in seeds() {
        let path = seeds_dir(target).join(format!("{name}.bin"));
        if write {
            std::fs::create_dir_all(path.parent().unwrap()).unwrap();
            std::fs::write(&path, &bytes).unwrap();
        }
        let committed = std::fs::read(&path).unwrap_or_else(|e| {
            panic!(
                "{}: {e}; KNEEBENCH_WRITE_FUZZ_SEEDS=1 writes the seeds",
                path.display()
            )
        });
        assert_eq!(
            committed,
            bytes,
            "{}: not the current encoder's bytes; KNEEBENCH_WRITE_FUZZ_SEEDS=1 rewrites the seeds",
            path.display()
        );
        count += 1;
    }
    // Every file of the seed directories replays through its target (seeds added by hand or
    // crashes minimized by cargo fuzz and committed as regressions included).
    let mut replayed = 0;
    for (target, run) in [
        ("frame_decoder", frame_decoder as fn(&[u8])),
        ("handshake_decoder", handshake_decoder),
    ] {
        for entry in std::fs::read_dir(seeds_dir(target)).unwrap() {
            let bytes = std::fs::read(entry.unwrap().path()).unwrap();
            run(&bytes);
            replayed += 1;
        }
    }
    assert!(replayed >= count, "{replayed} < {count}");
    assert!(count >= 20);
}

#[test]
fn the_fuzzed_handshake_accepts_its_welcome_and_refuses_the_others() {
    use kneebench_harness::bench_protocol::{ClientHandshake, HandshakeReply};
    let setup = BenchSetup {
        configuration: 1,
        test_kind: SetValueKind::Current,
        load_kind: SetValueKind::Current,
    };
    let seed = |n: &str| {
        seeds()
            .into_iter()
            .find(|(_, name, _)| name == n)
            .unwrap()
            .2
    };
    let mut hs = ClientHandshake::with_nonce(&fuzz_key(), setup, FUZZ_SESSION, FUZZ_NONCE);
    assert!(matches!(
        hs.receive(&seed("welcome")),
        Ok(HandshakeReply::Welcome(_))
    ));
    let mut hs = ClientHandshake::with_nonce(&fuzz_key(), setup, FUZZ_SESSION, FUZZ_NONCE);
    assert!(hs.receive(&seed("welcome_other_nonce")).is_err());
    assert!(hs.receive(&seed("welcome_wrong_key")).is_err());
    assert!(matches!(
        hs.receive(&seed("refuse")),
        Ok(HandshakeReply::Refused(_))
    ));
}
