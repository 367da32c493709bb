//! The controller FMUs (PidController, ImpedanceController, ClutchScheduler) through their C
//! ABI: hand-computed PID sequences (P, I, D with filter, saturation, both anti-windup
//! schemes), a bumpless ki change, the sample-period/step rule (accepted and refused steps),
//! direct feedthrough at sample instants, the impedance law and the clutch scheduler, and FMU
//! state continuing bit-identically.

use kneebench_tests::*;

use fmi2Status::{fmi2Error, fmi2OK};

const H: f64 = 1e-3;

mod pid {
    pub const KP: u32 = 2;
    pub const KI: u32 = 3;
    pub const KD: u32 = 4;
    pub const TF: u32 = 5;
    pub const OUTPUT_MIN: u32 = 7;
    pub const OUTPUT_MAX: u32 = 8;
    pub const ANTI_WINDUP: u32 = 9;
    pub const TRACKING_TIME: u32 = 10;
    pub const PRESET: u32 = 1;
    pub const SETPOINT: u32 = 100;
    pub const MEASUREMENT: u32 = 101;
    pub const HOLD: u32 = 103;
    pub const U: u32 = 200;
    pub const I_TERM: u32 = 203;
    pub const SATURATED: u32 = 207;
}

fn set_reals(i: &RawInstance, vrs: &[u32], values: &[f64]) -> fmi2StatusCode {
    // SAFETY: valid component and arrays of equal length.
    unsafe { (i.f.set_real)(i.c, vrs.as_ptr(), vrs.len(), values.as_ptr()) }
}

fn set_integers(i: &RawInstance, vrs: &[u32], values: &[i32]) -> fmi2StatusCode {
    // SAFETY: as above.
    unsafe { (i.f.set_integer)(i.c, vrs.as_ptr(), vrs.len(), values.as_ptr()) }
}

fn set_booleans(i: &RawInstance, vrs: &[u32], values: &[bool]) -> fmi2StatusCode {
    let v: Vec<fmi2Boolean> = values.iter().map(|b| fmi2Boolean::from(*b)).collect();
    // SAFETY: as above.
    unsafe { (i.f.set_boolean)(i.c, vrs.as_ptr(), vrs.len(), v.as_ptr()) }
}

fn booleans(i: &RawInstance, vrs: &[u32]) -> Vec<bool> {
    let mut out = vec![0; vrs.len()];
    // SAFETY: as above.
    let s = unsafe { (i.f.get_boolean)(i.c, vrs.as_ptr(), vrs.len(), out.as_mut_ptr()) };
    assert_eq!(s, fmi2OK, "{}", i.log_text());
    out.iter().map(|b| *b != 0).collect()
}

fn close(a: f64, b: f64) -> bool {
    (a - b).abs() <= 1e-12 * (1.0 + a.abs().max(b.abs()))
}

/// A PID instance with these (vr, value) Real parameters, initialized at t = 0.
fn pid_instance<'a>(f: &'a Raw, reals: &[(u32, f64)], anti_windup: i32) -> RawInstance<'a> {
    let mut i = RawInstance::new(f, "pid", &guid_of("PidController"));
    assert!(!i.c.is_null(), "{}", i.log_text());
    let (vrs, values): (Vec<u32>, Vec<f64>) = reals.iter().copied().unzip();
    assert_eq!(set_reals(&i, &vrs, &values), fmi2OK, "{}", i.log_text());
    assert_eq!(
        set_integers(&i, &[pid::ANTI_WINDUP], &[anti_windup]),
        fmi2OK
    );
    i.initialize(0.0, None);
    i
}

/// Feeds (setpoint, measurement) per 1 ms step in Gauss-Seidel order (set inputs, get u, step);
/// returns u and the I term at each sample.
fn drive(i: &mut RawInstance, samples: &[(f64, f64)], from: usize) -> Vec<(f64, f64)> {
    samples
        .iter()
        .enumerate()
        .map(|(k, &(r, y))| {
            assert_eq!(
                set_reals(i, &[pid::SETPOINT, pid::MEASUREMENT], &[r, y]),
                fmi2OK
            );
            let v = i.reals(&[pid::U, pid::I_TERM]);
            let t = (from + k) as f64 / 1000.0;
            assert_eq!(i.step(t, H), fmi2OK, "{}", i.log_text());
            (v[0], v[1])
        })
        .collect()
}

fn assert_sequence(got: &[(f64, f64)], want_u: &[f64]) {
    for (k, ((u, _), w)) in got.iter().zip(want_u).enumerate() {
        assert!(close(*u, *w), "sample {k}: u {u} vs {w}");
    }
}

#[test]
fn pid_hand_computed_p_i_d_sequences() {
    let f = Raw::load(&fmu_library());
    // P: kp 2.
    let mut i = pid_instance(&f, &[(pid::KP, 2.0), (pid::KI, 0.0), (pid::KD, 0.0)], 0);
    let got = drive(&mut i, &[(1.0, 0.0), (1.0, 0.25), (-1.0, 0.5)], 0);
    assert_sequence(&got, &[2.0, 1.5, -3.0]);
    // I: ki 10/s, forward Euler of the I term.
    let mut i = pid_instance(&f, &[(pid::KP, 0.0), (pid::KI, 10.0), (pid::KD, 0.0)], 0);
    let got = drive(&mut i, &[(1.0, 0.0), (1.0, 0.0), (3.0, 0.0), (0.0, 0.0)], 0);
    assert_sequence(&got, &[0.0, 0.01, 0.02, 0.05]);
    // D on the measurement, Tf 3 ms: x_k = (3e-3 x_{k-1} + dy) / 4e-3, D = -kd x.
    let mut i = pid_instance(
        &f,
        &[
            (pid::KP, 0.0),
            (pid::KI, 0.0),
            (pid::KD, 0.5),
            (pid::TF, 3e-3),
        ],
        0,
    );
    let got = drive(
        &mut i,
        &[(0.0, 0.0), (5.0, 0.001), (5.0, 0.002), (5.0, 0.002)],
        0,
    );
    assert_sequence(&got, &[0.0, -0.125, -0.21875, -0.1640625]);
}

#[test]
fn pid_saturation_and_both_anti_windup_schemes() {
    let f = Raw::load(&fmu_library());
    let params = [
        (pid::KP, 1.0),
        (pid::KI, 100.0),
        (pid::KD, 0.0),
        (pid::OUTPUT_MIN, -1.0),
        (pid::OUTPUT_MAX, 1.0),
        (pid::TRACKING_TIME, 0.01),
    ];
    let inputs = [(2.0, 0.0), (2.0, 0.0), (2.0, 0.0), (-0.5, 0.0), (-0.5, 0.0)];
    // Clamping: no integration into the limit.
    let mut i = pid_instance(&f, &params, 1);
    let got = drive(&mut i, &inputs[..1], 0);
    assert!(booleans(&i, &[pid::SATURATED])[0]);
    let got = [got, drive(&mut i, &inputs[1..], 1)].concat();
    assert_sequence(&got, &[1.0, 1.0, 1.0, -0.5, -0.55]);
    // Back-calculation, Ts/Tt = 0.1: I = 0, 0.1, 0.19, 0.271, 0.221.
    let mut i = pid_instance(&f, &params, 2);
    let got = drive(&mut i, &inputs, 0);
    assert_sequence(&got, &[1.0, 1.0, 1.0, -0.229, -0.279]);
    for ((_, integral), w) in got.iter().zip([0.0, 0.1, 0.19, 0.271, 0.221]) {
        assert!(close(*integral, w), "{integral} vs {w}");
    }
    // No anti-windup: the wound-up integral keeps the output positive after the reversal.
    let mut i = pid_instance(&f, &params, 0);
    let got = drive(&mut i, &inputs, 0);
    assert_sequence(&got, &[1.0, 1.0, 1.0, 0.1, 0.05]);
}

#[test]
fn pid_ki_change_mid_run_is_bumpless() {
    let f = Raw::load(&fmu_library());
    let mut i = pid_instance(&f, &[(pid::KP, 2.0), (pid::KI, 5.0), (pid::KD, 0.0)], 1);
    let inputs: Vec<(f64, f64)> = (0..400)
        .map(|k| (1.0, 0.4 * (1.0 - (k as f64 * 0.005).cos())))
        .collect();
    let before = drive(&mut i, &inputs[..200], 0);
    // At t = 0.2 s: ki x 8 (then kp x 3, through the C ABI between steps).
    assert_eq!(set_reals(&i, &[pid::KI], &[40.0]), fmi2OK);
    let after = drive(&mut i, &inputs[200..300], 200);
    assert_eq!(set_reals(&i, &[pid::KP], &[6.0]), fmi2OK);
    let later = drive(&mut i, &inputs[300..], 300);
    let u: Vec<f64> = [before, after, later]
        .concat()
        .iter()
        .map(|p| p.0)
        .collect();
    for k in 1..u.len() {
        // The output moves smoothly (the kp change alone would jump by 4 e, about 3.4).
        assert!(
            (u[k] - u[k - 1]).abs() < 0.05,
            "jump {} at sample {k}",
            u[k] - u[k - 1]
        );
    }
}

#[test]
fn pid_accepts_any_step_and_holds_the_output_between_instants() {
    let f = Raw::load(&fmu_library());
    let mut i = pid_instance(&f, &[(pid::KP, 1.0), (pid::KI, 0.0), (pid::KD, 0.0)], 1);
    // Feedthrough at a sample instant: u follows the setpoint just set.
    assert_eq!(set_reals(&i, &[pid::SETPOINT], &[2.0]), fmi2OK);
    assert_eq!(i.reals(&[pid::U])[0], 2.0);
    // Half-period sub-steps: between instants the output is held.
    assert_eq!(i.step(0.0, 0.5e-3), fmi2OK);
    assert_eq!(set_reals(&i, &[pid::SETPOINT], &[3.0]), fmi2OK);
    assert_eq!(
        i.reals(&[pid::U])[0],
        2.0,
        "zero-order hold between samples"
    );
    assert_eq!(i.step(0.5e-3, 0.5e-3), fmi2OK);
    assert_eq!(
        i.reals(&[pid::U])[0],
        3.0,
        "feedthrough at the next instant"
    );
    // A variable step of whole periods.
    assert_eq!(i.step(1e-3, 4e-3), fmi2OK);
    // 1.5 periods from an instant: the samples at 5 and 6 ms from the inputs of 5 ms, the
    // output of the one at 6 ms held at 6.5 ms.
    assert_eq!(set_reals(&i, &[pid::SETPOINT], &[4.0]), fmi2OK);
    assert_eq!(i.step(5e-3, 1.5e-3), fmi2OK, "{}", i.log_text());
    assert_eq!(set_reals(&i, &[pid::SETPOINT], &[5.0]), fmi2OK);
    assert_eq!(i.reals(&[pid::U])[0], 4.0, "held at 6.5 ms");
    // From between two instants across the next one (7 ms), ending between two again.
    assert_eq!(i.step(6.5e-3, 1e-3), fmi2OK, "{}", i.log_text());
    assert_eq!(
        i.reals(&[pid::U])[0],
        5.0,
        "the sample at 7 ms, held at 7.5 ms"
    );
    assert_eq!(i.step(7.5e-3, 0.5e-3), fmi2OK);
    assert_eq!(set_reals(&i, &[pid::SETPOINT], &[6.0]), fmi2OK);
    assert_eq!(i.reals(&[pid::U])[0], 6.0, "feedthrough at 8 ms");
}

/// Value references of a model's variables of one causality, by base type.
struct Variables {
    /// Real variables with their bounds (min, max).
    reals: Vec<(u32, Option<f64>, Option<f64>)>,
    /// Integer and Enumeration variables.
    integers: Vec<u32>,
    /// Boolean variables.
    booleans: Vec<u32>,
}

/// `identifier`'s variables of this causality.
fn variables_of(identifier: &str, causality: model_description::Causality) -> Variables {
    use model_description::VariableKind as K;
    let mut out = Variables {
        reals: Vec::new(),
        integers: Vec::new(),
        booleans: Vec::new(),
    };
    let info = kneebench_fmu::registry::find_by_identifier(identifier)
        .expect("model exists")
        .info();
    for v in &info.description.model_variables {
        if v.causality != Some(causality) {
            continue;
        }
        match &v.kind {
            K::Real { attributes, .. } => {
                out.reals
                    .push((v.value_reference, attributes.min, attributes.max))
            }
            K::Integer { .. } | K::Enumeration { .. } => out.integers.push(v.value_reference),
            K::Boolean { .. } => out.booleans.push(v.value_reference),
            K::String { .. } => panic!("{identifier}: a String {causality:?}"),
        }
    }
    out
}

/// Every output of `i` (Real, Integer, Boolean) as bits.
fn output_bits(i: &mut RawInstance, outputs: &Variables) -> Vec<u64> {
    let vrs: Vec<u32> = outputs.reals.iter().map(|v| v.0).collect();
    let mut bits: Vec<u64> = i.reals(&vrs).iter().map(|x| x.to_bits()).collect();
    let mut ints = vec![0; outputs.integers.len()];
    // SAFETY: valid component and arrays of equal length.
    let s = unsafe {
        (i.f.get_integer)(
            i.c,
            outputs.integers.as_ptr(),
            ints.len(),
            ints.as_mut_ptr(),
        )
    };
    assert_eq!(s, fmi2OK, "{}", i.log_text());
    bits.extend(ints.iter().map(|&n| n as u64));
    bits.extend(booleans(i, &outputs.booleans).into_iter().map(u64::from));
    bits
}

/// Each controller stepped by 1.5 ms (crossing sample instants, every other step ending between
/// two) gives, at every communication point, bit for bit the outputs of an instance stepped by
/// 0.5 ms whose inputs are held over the same 1.5 ms intervals: the same samples from the same
/// inputs (FMI 2.0's inputs are constant over a step). Checked after the inputs are set (at
/// 0, 3, 6 ms, ... the fresh sample from them) and after each step.
#[test]
fn steps_off_the_grid_equal_half_period_steps_with_the_same_held_inputs() {
    use model_description::Causality;
    const STEP: f64 = 1.5e-3;
    const SUB: f64 = 0.5e-3;
    let f = Raw::load(&fmu_library());
    for model in ["PidController", "ImpedanceController", "ClutchScheduler"] {
        let inputs = variables_of(model, Causality::Input);
        let outputs = variables_of(model, Causality::Output);
        assert!(
            inputs.integers.is_empty(),
            "{model}: Integer inputs are not driven here"
        );
        let make = |name: &str| {
            let mut i = RawInstance::new(&f, name, &guid_of(model));
            assert!(!i.c.is_null(), "{}", i.log_text());
            i.initialize(0.0, None);
            i
        };
        let (mut a, mut b) = (make("long"), make("short"));
        let mut changes = 0;
        let mut previous = Vec::new();
        for k in 0..300 {
            let t = k as f64 * STEP;
            // The inputs of the interval [t, t + 1.5 ms), inside their bounds.
            let (vrs, values): (Vec<u32>, Vec<f64>) = inputs
                .reals
                .iter()
                .enumerate()
                .map(|(j, &(vr, min, max))| {
                    let s = (0.37 * k as f64 + 1.3 * j as f64).sin();
                    let v = match (min, max) {
                        (Some(lo), Some(hi)) => lo + (hi - lo) * (0.5 + 0.49 * s),
                        _ => 0.5 * s,
                    };
                    (vr, v)
                })
                .unzip();
            let flags: Vec<bool> = (0..inputs.booleans.len()).map(|_| k % 13 == 4).collect();
            for i in [&a, &b] {
                assert_eq!(set_reals(i, &vrs, &values), fmi2OK, "{model}");
                assert_eq!(set_booleans(i, &inputs.booleans, &flags), fmi2OK, "{model}");
            }
            let now = output_bits(&mut a, &outputs);
            assert_eq!(now, output_bits(&mut b, &outputs), "{model} at {t} s");
            assert_eq!(a.step(t, STEP), fmi2OK, "{model}: {}", a.log_text());
            for j in 0..3 {
                let tj = t + j as f64 * SUB;
                let _ = output_bits(&mut b, &outputs);
                assert_eq!(b.step(tj, SUB), fmi2OK, "{model}: {}", b.log_text());
            }
            let end = output_bits(&mut a, &outputs);
            assert_eq!(
                end,
                output_bits(&mut b, &outputs),
                "{model} at the end of the step from {t} s"
            );
            changes += usize::from(end != previous);
            previous = end;
        }
        assert!(
            changes > 100,
            "{model}: the outputs changed at {changes} of 300 points"
        );
    }
}

#[test]
fn pid_hold_and_presets_through_the_c_abi() {
    let f = Raw::load(&fmu_library());
    let mut i = pid_instance(&f, &[(pid::KP, 1.0), (pid::KI, 100.0), (pid::KD, 0.0)], 1);
    let first = drive(&mut i, &[(1.0, 0.0), (1.0, 0.0)], 0);
    assert_sequence(&first, &[1.0, 1.1]);
    assert_eq!(set_booleans(&i, &[pid::HOLD], &[true]), fmi2OK);
    let held = drive(&mut i, &[(5.0, 0.0), (5.0, 0.0)], 2);
    assert_sequence(&held, &[1.1, 1.1]);
    assert_eq!(set_booleans(&i, &[pid::HOLD], &[false]), fmi2OK);
    // Released: the frozen integral (0.2) resumes with the current error.
    let released = drive(&mut i, &[(1.0, 0.0)], 4);
    assert_sequence(&released, &[1.2]);
    // A preset overrides kp/ki/kd: GaitExperimentTestMotor = 2000 / 300 / 100.
    assert_eq!(set_integers(&i, &[pid::PRESET], &[3]), fmi2OK);
    assert_eq!(set_integers(&i, &[pid::PRESET], &[42]), fmi2Error);
}

#[test]
fn pid_state_continues_bit_identically_in_a_fresh_instance() {
    let f = Raw::load(&fmu_library());
    let params = [(pid::KP, 3.0), (pid::KI, 40.0), (pid::KD, 0.02)];
    let mut a = pid_instance(&f, &params, 2);
    let inputs: Vec<(f64, f64)> = (0..600).map(|k| (1.0, (k as f64 * 0.01).sin())).collect();
    drive(&mut a, &inputs[..300], 0);
    let saved = a.serialized_state();
    let expected = drive(&mut a, &inputs[300..], 300);
    let mut b = RawInstance::new(&f, "fresh", &guid_of("PidController"));
    assert_eq!(b.restore(&saved), fmi2OK, "{}", b.log_text());
    let got = drive(&mut b, &inputs[300..], 300);
    let bits = |v: &[(f64, f64)]| -> Vec<u64> { v.iter().map(|p| p.0.to_bits()).collect() };
    assert_eq!(bits(&got), bits(&expected));
}

#[test]
fn impedance_controller_hand_computed_through_the_c_abi() {
    let f = Raw::load(&fmu_library());
    let mut i = RawInstance::new(&f, "impedance", &guid_of("ImpedanceController"));
    assert!(!i.c.is_null(), "{}", i.log_text());
    // k_d 100, d_d 2, k 300, limit 10, kp 0.5, ki 20, ff gain 0.2, +-4 A.
    assert_eq!(
        set_reals(
            &i,
            &[1, 2, 3, 4, 5, 6, 7, 8, 9],
            &[100.0, 2.0, 300.0, 10.0, 0.5, 20.0, 0.2, -4.0, 4.0]
        ),
        fmi2OK,
        "{}",
        i.log_text()
    );
    i.initialize(0.0, None);
    // theta_ref 0.05, omega_ref 0.5, tau_ff 0, theta_act 0.02, theta_load 0.01, omega_load 0.1.
    assert_eq!(
        set_reals(
            &i,
            &[100, 101, 102, 103, 104, 105],
            &[0.05, 0.5, 0.0, 0.02, 0.01, 0.1]
        ),
        fmi2OK
    );
    // tau_d = 4.8, tau_s = 3, e = 1.8: i = 0.9 + 0 + 0.96.
    let v = i.reals(&[200, 201, 202, 203, 204]);
    for (got, want) in v.iter().zip([1.86, 4.8, 3.0, 1.8, 0.01]) {
        assert!(close(*got, want), "{v:?}");
    }
    assert_eq!(i.step(0.0, H), fmi2OK);
    assert_eq!(set_reals(&i, &[102], &[1.0]), fmi2OK);
    // tau_d = 5.8, e = 2.8: i = 1.4 + 0.036 + 1.16.
    assert!(close(i.reals(&[200])[0], 2.596));
    // 1.5 periods: the samples at 1 and 2 ms from these inputs.
    assert_eq!(i.step(1e-3, 1.5e-3), fmi2OK, "{}", i.log_text());
}

#[test]
fn clutch_scheduler_through_the_c_abi() {
    let f = Raw::load(&fmu_library());
    let mut i = RawInstance::new(&f, "clutch", &guid_of("ClutchScheduler"));
    assert!(!i.c.is_null(), "{}", i.log_text());
    // LowSpeed mode, no delay, no dwell: hysteresis between 0.3 and 0.5 rad/s.
    assert_eq!(set_integers(&i, &[1], &[2]), fmi2OK);
    assert_eq!(set_reals(&i, &[4, 5, 6, 7], &[0.3, 0.5, 0.0, 0.0]), fmi2OK);
    i.initialize(0.0, None);
    let speeds = [1.0, 0.2, 0.4, 0.6, 0.4, -0.1];
    let want = [false, true, true, false, false, true];
    for (k, (v, w)) in speeds.iter().zip(want).enumerate() {
        assert_eq!(set_reals(&i, &[101], &[*v]), fmi2OK);
        assert_eq!(booleans(&i, &[200, 201]), [w, w], "sample {k}");
        assert_eq!(i.step(k as f64 * H, H), fmi2OK);
    }
    // Switch to the gait-phase window (tunable), with wrap-around 0.9 -> 0.2.
    assert_eq!(set_integers(&i, &[1], &[1]), fmi2OK);
    assert_eq!(set_reals(&i, &[2, 3], &[0.9, 0.2]), fmi2OK);
    for (k, (phase, w)) in [(0.5, false), (0.95, true), (0.1, true), (0.3, false)]
        .iter()
        .enumerate()
    {
        assert_eq!(set_reals(&i, &[100], &[*phase]), fmi2OK);
        assert_eq!(booleans(&i, &[200])[0], *w, "phase {phase}");
        assert_eq!(i.step((6 + k) as f64 * H, H), fmi2OK);
    }
}

/// fmpy's `simulate_fmu` (a foreign master) runs each controller with a constant output
/// interval of 1.5 ms and 2.5 ms, steps that cross sample instants and end between two (the
/// controllers declare `canHandleVariableCommunicationStepSize`), with a ramp on every Real
/// input: every communication point is reached and every output is finite.
#[test]
fn fmpy_simulates_the_controllers_at_output_intervals_off_the_sample_grid() {
    let script = r#"
import sys
import numpy as np
from fmpy import read_model_description, simulate_fmu
path, dt = sys.argv[1], float(sys.argv[2])
md = read_model_description(path)
reals = [v.name for v in md.modelVariables if v.causality == "input" and v.type == "Real"]
flags = [v.name for v in md.modelVariables if v.causality == "input" and v.type == "Boolean"]
outputs = [v.name for v in md.modelVariables if v.causality == "output"]
rows = [(t,) + tuple(x for _ in reals) + tuple(False for _ in flags)
        for t, x in [(0.0, 0.0), (0.02, 0.5)]]
signals = np.array(rows, dtype=[("time", np.float64)] + [(n, np.float64) for n in reals]
                   + [(n, np.bool_) for n in flags])
r = simulate_fmu(path, stop_time=0.02, output_interval=dt, validate=True, input=signals,
                 output=outputs)
# The points k dt before the stop time, then the stop time (a shorter last step).
want = [k * dt for k in range(round(0.02 / dt) + 1) if k * dt < 0.02 - 1e-12] + [0.02]
assert len(r) == len(want), (len(r), list(r["time"]))
assert np.allclose(r["time"], want, rtol=0, atol=1e-12), list(r["time"])
for name in outputs:
    assert np.all(np.isfinite(r[name].astype(np.float64))), name
print(len(r), r["time"][-1])
"#;
    for model in ["PidController", "ImpedanceController", "ClutchScheduler"] {
        let path = exported_fmu(model);
        for dt in ["0.0015", "0.0025"] {
            let out = run_python(script, &[&path.display().to_string(), dt]);
            assert!(!out.trim().is_empty(), "{model} at {dt}: {out}");
        }
    }
}
