//! BenchPlant alone over one 2.5 s gait cycle at 1 ms communication steps, driven by recorded
//! inputs through the C ABI of the packaged FMU: real-time factor, and the max angle error
//! against a reference run with a 100 times finer internal step (maxInternalStep 1e-5 s).
//! DA, SEA and CSEA (the CSEA run engages the clutch in stance, gait phase 0.05..0.45).
//!
//! The baseline, measured in the same run: the same cycle as a plain Rust call loop on the
//! plant (`BenchPlant::step` and the motion outputs, no FMI), which must give the same angles
//! bit for bit; "ABI/Rust" is the share the C ABI and the FMU glue add. With
//! `KNEEBENCH_PLANT_ABI_BASELINE` naming another build's `BenchPlant.fmu` (e.g. the previous
//! commit's `kneebench export`; its own GUID is used, so a build whose model description
//! changed still serves), or its `libkneebench_fmu.so` (this build's GUID: only while the
//! description is unchanged), that build runs too, interleaved, and must give the same angles
//! bit for bit; "speed-up" is its wall time over this build's. One more, untimed cycle of each
//! build then reads every Real output after every step, and those must be the same bit for bit
//! too.
//!
//! Run: `cargo bench -p kneebench-tests --bench plant_abi`
//!
//! Instructions per step (repeatable on a noisy machine): `KNEEBENCH_PLANT_ABI_PROFILE=SEA:3
//! valgrind --tool=callgrind --toggle-collect='*plant_abi*profiled*' <bench binary>` runs one
//! cycle of the configuration (DA, SEA or CSEA) to warm up, then 3 cycles through the C ABI
//! inside `profiled` (the function callgrind is told to count: the steps and their four FMI
//! calls, instantiation and initialization included; a cycle is 2,500 steps). With
//! `KNEEBENCH_PLANT_ABI_BASELINE` set, the baseline build is the one profiled. Build the FMU
//! library with `CARGO_PROFILE_RELEASE_STRIP=none` for the plant's function names.

use std::path::Path;
use std::time::Instant;

use kneebench_fmu::models::bench::{
    BenchInputs, BenchOutputs, BenchParameters, BenchPlant, Configuration, SignalGroup, StepOutcome,
};
use kneebench_tests::*;

const H: f64 = 1e-3;
const STEPS: u64 = 2500;
const REPEATS: usize = 15;

/// Recorded inputs of one cycle: current set values shaped like the bench gait (test motor
/// tracking torque, load motor the inverted knee torque), sampled every 1 ms.
fn recorded_inputs() -> Vec<(f64, f64, bool)> {
    use kneebench_fmu::models::gait::{ANGLE_SERIES, TORQUE_SERIES, fourier};
    (0..STEPS)
        .map(|k| {
            let t = k as f64 * H;
            let accel = fourier(&ANGLE_SERIES, t, 2.5).d2 * 60f64.to_radians();
            let knee_torque = 9.0 * fourier(&TORQUE_SERIES, t, 2.5).value;
            // Output torque ~ I1*alpha + knee torque; current = torque / (i_HD Km1).
            let test = (0.825 * accel + knee_torque) / (160.0 * 0.037);
            let load = -knee_torque / (66.0 * 0.114);
            let phase = t / 2.5;
            (
                test.clamp(-3.0, 3.0),
                load.clamp(-2.5, 2.5),
                (0.05..0.45).contains(&phase),
            )
        })
        .collect()
}

fn run_cycle(
    f: &Raw,
    guid: &str,
    configuration: i32,
    internal_step: f64,
    inputs: &[(f64, f64, bool)],
) -> (f64, Vec<f64>) {
    run_cycle_reading(f, guid, configuration, internal_step, inputs, &[300, 301])
}

/// [`run_cycle`] reading the Real outputs `vrs_out` after every step (the angles, value
/// references 300 and 301, in [`run_cycle`]).
fn run_cycle_reading(
    f: &Raw,
    guid: &str,
    configuration: i32,
    internal_step: f64,
    inputs: &[(f64, f64, bool)],
    vrs_out: &[u32],
) -> (f64, Vec<f64>) {
    let mut i = RawInstance::new(f, "bench", guid);
    // SAFETY: valid component and arrays.
    unsafe {
        assert_eq!(
            (f.set_integer)(i.c, [1u32].as_ptr(), 1, [configuration].as_ptr()),
            fmi2Status::fmi2OK
        );
        assert_eq!(
            (f.set_real)(i.c, [66u32].as_ptr(), 1, [internal_step].as_ptr()),
            fmi2Status::fmi2OK
        );
    }
    i.initialize(0.0, None);
    let clutch = configuration == 2;
    let mut angles = Vec::with_capacity(vrs_out.len() * STEPS as usize);
    let vrs_in = [201u32, 203];
    let vr_clutch = [206u32];
    let mut out = vec![0.0; vrs_out.len()];
    let t0 = Instant::now();
    for (k, &(test, load, stance)) in inputs.iter().enumerate() {
        // SAFETY: valid component and arrays.
        unsafe {
            (f.set_real)(i.c, vrs_in.as_ptr(), 2, [test, load].as_ptr());
            (f.set_boolean)(
                i.c,
                vr_clutch.as_ptr(),
                1,
                [i32::from(clutch && stance)].as_ptr(),
            );
            let s = (f.do_step)(i.c, k as f64 * H, H, 1);
            assert_eq!(s, fmi2Status::fmi2OK, "{}", i.log_text());
            let s = (f.get_real)(i.c, vrs_out.as_ptr(), vrs_out.len(), out.as_mut_ptr());
            assert_eq!(s, fmi2Status::fmi2OK, "{}", i.log_text());
        }
        angles.extend_from_slice(&out);
    }
    (t0.elapsed().as_secs_f64(), angles)
}

/// The same cycle as [`run_cycle`] as a plain Rust call loop: the plant's step and its motion
/// outputs (the group the angles belong to), as the FMU computes them, without FMI.
fn run_cycle_in_rust(configuration: Configuration, inputs: &[(f64, f64, bool)]) -> (f64, Vec<f64>) {
    let params = BenchParameters {
        configuration,
        ..BenchParameters::default()
    };
    let mut plant = BenchPlant::new(params).unwrap();
    let clutch = configuration == Configuration::Csea;
    let mut outputs = BenchOutputs::default();
    let mut angles = Vec::with_capacity(2 * STEPS as usize);
    let t0 = Instant::now();
    for &(test, load, stance) in inputs {
        let step = BenchInputs {
            test_command: test,
            load_command: load,
            test_enable: true,
            load_enable: true,
            clutch_engage: clutch && stance,
            emergency_stop: false,
        };
        assert_eq!(plant.step(&step, H), StepOutcome::Completed);
        plant.fill_outputs(SignalGroup::Motion, &mut outputs);
        angles.extend_from_slice(&[outputs.actuation_angle, outputs.load_angle]);
    }
    (t0.elapsed().as_secs_f64(), angles)
}

/// A previous build to measure in the same run, interleaved with this one:
/// `KNEEBENCH_PLANT_ABI_BASELINE=/path/to/BenchPlant.fmu` or `.../libkneebench_fmu.so` (its
/// angles must be this build's bit for bit).
const BASELINE_VAR: &str = "KNEEBENCH_PLANT_ABI_BASELINE";

/// The baseline build: its binary and the GUID to instantiate it with (the loaded FMU, when
/// given as one, keeps the extracted binary alive).
struct Baseline {
    raw: Raw,
    guid: String,
    _fmu: Option<kneebench_harness::Fmu>,
}

impl Baseline {
    fn load(path: &Path) -> Self {
        let is_fmu = path
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("fmu"));
        if is_fmu {
            let fmu = kneebench_harness::Fmu::load(path, &Default::default())
                .unwrap_or_else(|e| panic!("{BASELINE_VAR}={}: {e}", path.display()));
            Self {
                raw: Raw::load(fmu.binary_path()),
                guid: fmu.model_description().guid.clone(),
                _fmu: Some(fmu),
            }
        } else {
            Self {
                raw: Raw::load(path),
                guid: guid_of("BenchPlant"),
                _fmu: None,
            }
        }
    }
}

/// The median of `times`.
fn median(mut times: Vec<f64>) -> f64 {
    times.sort_by(f64::total_cmp);
    times[times.len() / 2]
}

/// Whether two runs gave the same angles bit for bit.
fn same_bits(a: &[f64], b: &[f64]) -> bool {
    a.len() == b.len() && a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits())
}

/// `runs` cycles of `configuration` through the C ABI: what callgrind counts in profile mode
/// (see the header).
#[inline(never)]
fn profiled(raw: &Raw, guid: &str, configuration: i32, inputs: &[(f64, f64, bool)], runs: usize) {
    for _ in 0..runs {
        std::hint::black_box(run_cycle(raw, guid, configuration, 1e-3, inputs));
    }
}

fn main() {
    let dir = tempfile::tempdir().unwrap();
    let fmus = kneebench_harness::package::export_all(&fmu_library(), dir.path()).unwrap();
    let plant = fmus.iter().find(|f| f.identifier == "BenchPlant").unwrap();
    let fmu = kneebench_harness::Fmu::load(&plant.path, &Default::default()).unwrap();
    let raw = Raw::load(fmu.binary_path());
    let guid = fmu.model_description().guid.clone();
    let baseline = std::env::var_os(BASELINE_VAR).map(|path| Baseline::load(Path::new(&path)));
    let inputs = recorded_inputs();
    // Every Real output's value reference (for the baseline's bit-for-bit check of them all).
    let real_outputs = real_outputs(fmu.model_description());
    if let Ok(profile) = std::env::var("KNEEBENCH_PLANT_ABI_PROFILE") {
        let (name, runs) = profile
            .split_once(':')
            .expect("KNEEBENCH_PLANT_ABI_PROFILE is CONFIGURATION:RUNS, e.g. SEA:3");
        let code = match name {
            "DA" => Configuration::Da,
            "SEA" => Configuration::Sea,
            "CSEA" => Configuration::Csea,
            other => panic!("KNEEBENCH_PLANT_ABI_PROFILE: no configuration {other}"),
        }
        .as_i32();
        let runs: usize = runs.parse().expect("KNEEBENCH_PLANT_ABI_PROFILE: runs");
        let (raw, guid) = match &baseline {
            Some(b) => (&b.raw, b.guid.as_str()),
            None => (&raw, guid.as_str()),
        };
        run_cycle(raw, guid, code, 1e-3, &inputs);
        profiled(raw, guid, code, &inputs, runs);
        return;
    }
    println!(
        "BenchPlant, one 2.5 s gait cycle, 1 ms steps, recorded inputs, C ABI (median of {REPEATS}, interleaved)"
    );
    print!(
        "{:<6} {:>10} {:>12} {:>12} {:>10}",
        "config", "wall [ms]", "x real time", "Rust x r.t.", "ABI/Rust"
    );
    if baseline.is_some() {
        print!(" {:>15} {:>9}", "baseline x r.t.", "speed-up");
    }
    println!(" {:>22}", "max angle error [rad]");
    for (name, configuration) in [
        ("DA", Configuration::Da),
        ("SEA", Configuration::Sea),
        ("CSEA", Configuration::Csea),
    ] {
        let code = configuration.as_i32();
        let (_, reference) = run_cycle(&raw, &guid, code, 1e-5, &inputs);
        let (mut abi, mut rust, mut previous) = (Vec::new(), Vec::new(), Vec::new());
        let mut angles = Vec::new();
        for _ in 0..REPEATS {
            let (t, a) = run_cycle(&raw, &guid, code, 1e-3, &inputs);
            abi.push(t);
            angles = a;
            let (t, a) = run_cycle_in_rust(configuration, &inputs);
            rust.push(t);
            assert!(
                same_bits(&angles, &a),
                "{name}: the C ABI and the Rust call loop differ"
            );
            if let Some(baseline) = &baseline {
                let (t, a) = run_cycle(&baseline.raw, &baseline.guid, code, 1e-3, &inputs);
                previous.push(t);
                assert!(
                    same_bits(&angles, &a),
                    "{name}: this build and the baseline differ"
                );
            }
        }
        if let Some(baseline) = &baseline {
            // Every Real output, not only the angles, bit for bit (one untimed cycle each).
            let (_, ours) = run_cycle_reading(&raw, &guid, code, 1e-3, &inputs, &real_outputs);
            let (_, theirs) = run_cycle_reading(
                &baseline.raw,
                &baseline.guid,
                code,
                1e-3,
                &inputs,
                &real_outputs,
            );
            if let Some(k) = (0..ours.len()).find(|&k| ours[k].to_bits() != theirs[k].to_bits()) {
                panic!(
                    "{name}: this build and the baseline differ at step {} in output {}: {} vs {}",
                    k / real_outputs.len(),
                    real_outputs[k % real_outputs.len()],
                    ours[k],
                    theirs[k]
                );
            }
        }
        let error = angles
            .iter()
            .zip(&reference)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        let (wall, rust_wall) = (median(abi), median(rust));
        print!(
            "{name:<6} {:>10.3} {:>12.0} {:>12.0} {:>10.2}",
            wall * 1e3,
            2.5 / wall,
            2.5 / rust_wall,
            wall / rust_wall,
        );
        if baseline.is_some() {
            let previous_wall = median(previous);
            print!(
                " {:>15.0} {:>9.2}",
                2.5 / previous_wall,
                previous_wall / wall
            );
        }
        println!(" {error:>22.2e}");
    }
}
