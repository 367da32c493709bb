//! FMU state: get/set and serialization continue bit-identically in the same instance, a fresh
//! instance and a fresh process; foreign, truncated and corrupted states are refused. Every
//! model but `BenchHardware` declares and provides FMU state; `BenchHardware` declares none,
//! refuses every FMU-state call, and the harness does not make those calls.

use std::process::Command;

use kneebench_fmu::fmi2::instance::reseal_state;
use kneebench_tests::*;

use fmi2Status::{fmi2Error, fmi2OK};

const OUTPUTS: [u32; 6] = [100, 101, 102, 103, 104, 105];
const H: f64 = 0.001;

/// A run with a non-default parameter, so that the state must carry it.
fn started(f: &Raw) -> RawInstance<'_> {
    let mut i = RawInstance::new(f, "state", &guid_of("GaitReference"));
    // SAFETY: valid component and arrays.
    unsafe {
        assert_eq!(
            (f.set_real)(i.c, [1u32].as_ptr(), 1, [1.7].as_ptr()),
            fmi2OK
        );
        assert_eq!(
            (f.set_integer)(i.c, [8u32].as_ptr(), 1, [7].as_ptr()),
            fmi2OK
        );
    }
    i.initialize(0.0, None);
    i
}

/// Steps from step index k0 for n steps; returns the bits of every output after each step.
fn continue_run(i: &mut RawInstance, k0: u64, n: u64) -> Vec<u64> {
    let mut bits = Vec::new();
    for k in k0..k0 + n {
        assert_eq!(i.step(k as f64 * H, H), fmi2OK, "{}", i.log_text());
        bits.extend(i.reals(&OUTPUTS).iter().map(|v| v.to_bits()));
    }
    bits
}

#[test]
fn get_set_round_trip_continues_bit_identically() {
    let f = Raw::load(&fmu_library());
    let mut i = started(&f);
    continue_run(&mut i, 0, 700);
    let saved = i.serialized_state();
    let first = continue_run(&mut i, 700, 500);
    assert_eq!(i.restore(&saved), fmi2OK, "{}", i.log_text());
    let again = continue_run(&mut i, 700, 500);
    assert_eq!(first, again);

    // In a fresh instance of the same binary.
    let mut fresh = RawInstance::new(&f, "fresh", &guid_of("GaitReference"));
    assert_eq!(fresh.restore(&saved), fmi2OK, "{}", fresh.log_text());
    assert_eq!(continue_run(&mut fresh, 700, 500), first);
}

#[test]
fn serialized_state_continues_bit_identically_in_a_fresh_process() {
    if std::env::var_os("KNEEBENCH_STATE_CHILD").is_some() {
        return; // the child runs `child_process_continues_a_state` only
    }
    let f = Raw::load(&fmu_library());
    let mut i = started(&f);
    continue_run(&mut i, 0, 700);
    let saved = i.serialized_state();
    let expected = continue_run(&mut i, 700, 500);
    let dir = tempfile::tempdir().unwrap();
    let state_file = dir.path().join("state.bin");
    let out_file = dir.path().join("out.bin");
    std::fs::write(&state_file, &saved).unwrap();
    let status = Command::new(std::env::current_exe().unwrap())
        .args([
            "--exact",
            "child_process_continues_a_state",
            "--nocapture",
            "--test-threads=1",
        ])
        .env("KNEEBENCH_STATE_CHILD", &state_file)
        .env("KNEEBENCH_STATE_OUT", &out_file)
        .status()
        .unwrap();
    assert!(status.success());
    let bytes = std::fs::read(&out_file).expect("the child wrote its results");
    let got: Vec<u64> = bytes
        .chunks_exact(8)
        .map(|c| u64::from_le_bytes(c.try_into().unwrap()))
        .collect();
    assert_eq!(got, expected);
}

/// Runs only inside the child process started by the test above.
#[test]
fn child_process_continues_a_state() {
    let (Some(state), Some(out)) = (
        std::env::var_os("KNEEBENCH_STATE_CHILD"),
        std::env::var_os("KNEEBENCH_STATE_OUT"),
    ) else {
        return;
    };
    let f = Raw::load(&fmu_library());
    let mut i = RawInstance::new(&f, "child", &guid_of("GaitReference"));
    assert_eq!(
        i.restore(&std::fs::read(state).unwrap()),
        fmi2OK,
        "{}",
        i.log_text()
    );
    let bits = continue_run(&mut i, 700, 500);
    let bytes: Vec<u8> = bits.iter().flat_map(|b| b.to_le_bytes()).collect();
    std::fs::write(out, bytes).unwrap();
}

#[test]
fn foreign_truncated_and_corrupted_states_are_refused() {
    let f = Raw::load(&fmu_library());
    let mut i = started(&f);
    continue_run(&mut i, 0, 10);
    let saved = i.serialized_state();
    let guid = guid_of("GaitReference");
    // A state of another model: same layout, another GUID.
    let pos = saved
        .windows(guid.len())
        .position(|w| w == guid.as_bytes())
        .expect("the state embeds the GUID");
    let mut foreign = saved.clone();
    foreign[pos + 1] = if foreign[pos + 1] == b'0' { b'1' } else { b'0' };
    // Unsealed, the change is caught by the checksum; resealed (forged on purpose), by the GUID.
    assert_eq!(i.restore(&foreign), fmi2Error);
    assert!(i.log_text().contains("corrupted"), "{}", i.log_text());
    reseal_state(&mut foreign);
    assert_eq!(i.restore(&foreign), fmi2Error);
    assert!(
        i.log_text().contains("belongs to model"),
        "{}",
        i.log_text()
    );
    // Truncated, bad magic, future version, trailing garbage.
    assert_eq!(i.restore(&saved[..saved.len() - 3]), fmi2Error);
    let mut magic = saved.clone();
    magic[0] = b'X';
    assert_eq!(i.restore(&magic), fmi2Error);
    let mut version = saved.clone();
    version[8] = 99;
    assert_eq!(i.restore(&version), fmi2Error);
    let mut longer = saved.clone();
    longer.push(0);
    assert_eq!(i.restore(&longer), fmi2Error);
    // One bit flipped in any byte (header, times, values, the gait's internal state, the
    // checksum): every change is refused, none restores a plausible wrong state.
    for k in 0..saved.len() {
        let mut flipped = saved.clone();
        flipped[k] ^= 1 << (k % 8);
        assert_eq!(i.restore(&flipped), fmi2Error, "byte {k}");
    }
    assert!(
        i.log_text().contains("corrupted: its checksum is"),
        "{}",
        i.log_text()
    );
    let log = i.log_text();
    for needle in [
        "truncated",
        "bad magic",
        "format version 99",
        "trailing bytes",
    ] {
        assert!(log.contains(needle), "log lacks {needle:?}: {log}");
    }
    // Nothing was lost: the instance continues from where it was.
    assert_eq!(i.step(10.0 * H, H), fmi2OK);
    // A too-small serialization buffer is refused.
    // SAFETY: valid component; the state is freed.
    unsafe {
        let mut st = std::ptr::null_mut();
        assert_eq!((f.get_fmu_state)(i.c, &mut st), fmi2OK);
        let mut buf = [0i8; 4];
        assert_eq!((f.serialize)(i.c, st, buf.as_mut_ptr(), 4), fmi2Error);
        assert_eq!((f.free_fmu_state)(i.c, &mut st), fmi2OK);
    }
}

/// The model description of `identifier` (the binary's own, as exported).
fn description(identifier: &str) -> &'static model_description::ModelDescription {
    &kneebench_fmu::registry::find_by_identifier(identifier)
        .expect("model exists")
        .info()
        .description
}

/// `BenchHardware` declares no FMU state (the physical bench cannot be rewound): both flags
/// false in its model description, and every FMU-state function answers fmi2Error with a log
/// line naming the flag, changing nothing (the instance initializes and steps afterwards).
#[test]
fn bench_hardware_declares_no_fmu_state_and_refuses_every_state_call() {
    let cs = description("BenchHardware").co_simulation.clone().unwrap();
    assert_eq!(cs.can_get_and_set_fmu_state, Some(false));
    assert_eq!(cs.can_serialize_fmu_state, Some(false));
    let f = Raw::load(&fmu_library());
    // A real state of another model of the same binary, so that a call that were not refused
    // would still be handed a valid state (and refuse it as foreign).
    let mut gait = RawInstance::new(&f, "gait", &guid_of("GaitReference"));
    gait.initialize(0.0, None);
    let gait_bytes = gait.serialized_state();
    let mut i = RawInstance::new(&f, "hardware", &guid_of("BenchHardware"));
    assert!(!i.c.is_null(), "{}", i.log_text());
    // SAFETY: valid components, buffers and out-pointers; the gait's state is freed by it.
    unsafe {
        let mut gait_state: fmi2FMUstate = std::ptr::null_mut();
        assert_eq!((f.get_fmu_state)(gait.c, &mut gait_state), fmi2OK);
        let mut state: fmi2FMUstate = std::ptr::null_mut();
        assert_eq!((f.get_fmu_state)(i.c, &mut state), fmi2Error);
        assert!(state.is_null());
        assert_eq!((f.set_fmu_state)(i.c, gait_state), fmi2Error);
        assert_eq!((f.free_fmu_state)(i.c, &mut state), fmi2Error);
        let get_and_set = i.log_text();
        let mut size = 0usize;
        assert_eq!((f.serialized_size)(i.c, gait_state, &mut size), fmi2Error);
        assert_eq!(size, 0);
        let mut buf = vec![0u8; gait_bytes.len()];
        assert_eq!(
            (f.serialize)(i.c, gait_state, buf.as_mut_ptr().cast(), buf.len()),
            fmi2Error
        );
        assert_eq!(
            (f.deserialize)(
                i.c,
                gait_bytes.as_ptr().cast(),
                gait_bytes.len(),
                &mut state
            ),
            fmi2Error
        );
        assert!(state.is_null());
        assert_eq!((f.free_fmu_state)(gait.c, &mut gait_state), fmi2OK);
        for function in ["fmi2GetFMUstate", "fmi2SetFMUstate", "fmi2FreeFMUstate"] {
            let line = format!(
                "{function}: not provided: the model description declares canGetAndSetFMUstate=\"false\""
            );
            assert!(get_and_set.contains(&line), "{get_and_set}");
        }
        let log = i.log_text();
        for function in [
            "fmi2SerializedFMUstateSize",
            "fmi2SerializeFMUstate",
            "fmi2DeSerializeFMUstate",
        ] {
            let line = format!(
                "{function}: not provided: the model description declares canSerializeFMUstate=\"false\""
            );
            assert!(log.contains(&line), "{log}");
        }
    }
    // Refused, nothing changed: the instance initializes and steps (simulated backend).
    i.initialize(0.0, None);
    assert_eq!(i.step(0.0, H), fmi2OK, "{}", i.log_text());
}

/// Every other model declares both flags true, and its state round-trips: saved, serialized,
/// deserialized into a fresh instance and restored, the run continues bit for bit.
#[test]
fn the_other_five_declare_fmu_state_and_round_trip_it() {
    let f = Raw::load(&fmu_library());
    let models = [
        "GaitReference",
        "BenchPlant",
        "PidController",
        "ImpedanceController",
        "ClutchScheduler",
    ];
    assert_eq!(models.len() + 1, kneebench_fmu::MODELS.len());
    for model in models {
        let d = description(model);
        let cs = d.co_simulation.clone().unwrap();
        assert_eq!(cs.can_get_and_set_fmu_state, Some(true), "{model}");
        assert_eq!(cs.can_serialize_fmu_state, Some(true), "{model}");
        let outputs = real_outputs(d);
        let run = |i: &mut RawInstance, k0: u64, n: u64| {
            let mut bits = Vec::new();
            for k in k0..k0 + n {
                assert_eq!(i.step(k as f64 * H, H), fmi2OK, "{model}: {}", i.log_text());
                bits.extend(i.reals(&outputs).iter().map(|v| v.to_bits()));
            }
            bits
        };
        let mut i = RawInstance::new(&f, "state", &guid_of(model));
        i.initialize(0.0, None);
        run(&mut i, 0, 20);
        let saved = i.serialized_state();
        let first = run(&mut i, 20, 30);
        assert_eq!(i.restore(&saved), fmi2OK, "{model}: {}", i.log_text());
        assert_eq!(run(&mut i, 20, 30), first, "{model}");
        let mut fresh = RawInstance::new(&f, "fresh", &guid_of(model));
        assert_eq!(
            fresh.restore(&saved),
            fmi2OK,
            "{model}: {}",
            fresh.log_text()
        );
        assert_eq!(run(&mut fresh, 20, 30), first, "{model}");
    }
}
