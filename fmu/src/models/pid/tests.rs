use super::*;
use crate::fmi2::instance::fresh_model;

const TS: f64 = 1e-3;

fn settings() -> PidSettings {
    PidSettings {
        kp: 0.0,
        ki: 0.0,
        kd: 0.0,
        derivative_filter_time: 0.0,
        sample_period: TS,
        output_min: -100.0,
        output_max: 100.0,
        anti_windup: AntiWindup::None,
        tracking_time: 0.1,
        feed_forward_gain: 1.0,
        setpoint_weights: [0.0; AUXILIARIES],
        feed_forward_weights: [0.0; AUXILIARIES],
        hold_action: HoldAction::HoldLastOutput,
        reverse_acting: false,
    }
}

/// Runs the law over (setpoint, measurement) pairs; returns the outputs.
fn run(s: &PidSettings, samples: &[(f64, f64)]) -> Vec<PidSignals> {
    let mut state = PidState::default();
    samples
        .iter()
        .map(|&(r, y)| {
            let (sig, next) = pid_sample(
                s,
                &state,
                &PidInputs {
                    setpoint: r,
                    measurement: y,
                    ..PidInputs::default()
                },
            );
            state = next;
            sig
        })
        .collect()
}

fn close(a: f64, b: f64) -> bool {
    (a - b).abs() <= 1e-12 * (1.0 + a.abs().max(b.abs()))
}

fn assert_outputs(got: &[PidSignals], want: &[f64]) {
    assert_eq!(got.len(), want.len());
    for (k, (g, w)) in got.iter().zip(want).enumerate() {
        assert!(close(g.output, *w), "sample {k}: {} vs {w}", g.output);
    }
}

#[test]
fn proportional_sequence() {
    let s = PidSettings {
        kp: 2.0,
        ..settings()
    };
    let got = run(&s, &[(1.0, 0.0), (1.0, 0.25), (-1.0, 0.5)]);
    assert_outputs(&got, &[2.0, 1.5, -3.0]);
    // Reverse acting negates the error.
    let got = run(
        &PidSettings {
            reverse_acting: true,
            ..s
        },
        &[(1.0, 0.0)],
    );
    assert_outputs(&got, &[-2.0]);
}

#[test]
fn integral_sequence_is_forward_euler_of_the_i_term() {
    // ki = 10/s, Ts = 1 ms: u_k = sum_{j<k} 10 * 0.001 * e_j.
    let s = PidSettings {
        ki: 10.0,
        ..settings()
    };
    let got = run(&s, &[(1.0, 0.0), (1.0, 0.0), (3.0, 0.0), (0.0, 0.0)]);
    assert_outputs(&got, &[0.0, 0.01, 0.02, 0.05]);
}

#[test]
fn derivative_on_measurement_with_filter_sequence() {
    // kd = 0.5 s, Tf = 3 ms, Ts = 1 ms: x_k = (3e-3 x_{k-1} + dy_k) / 4e-3, D = -kd x.
    let s = PidSettings {
        kd: 0.5,
        derivative_filter_time: 3e-3,
        ..settings()
    };
    // Measurement ramps 0, 0.001, 0.002, then stays; a setpoint step gives no kick.
    let got = run(&s, &[(0.0, 0.0), (5.0, 0.001), (5.0, 0.002), (5.0, 0.002)]);
    let x1 = 0.001 / 4e-3; // 0.25
    let x2 = (3e-3 * x1 + 0.001) / 4e-3; // 0.4375
    let x3 = (3e-3 * x2) / 4e-3; // 0.328125
    assert_outputs(&got, &[0.0, -0.5 * x1, -0.5 * x2, -0.5 * x3]);
    assert!(close(got[3].output, -0.1640625));
    // Without filter: the backward difference.
    let got = run(
        &PidSettings {
            derivative_filter_time: 0.0,
            ..s
        },
        &[(0.0, 0.0), (0.0, 0.002)],
    );
    assert_outputs(&got, &[0.0, -0.5 * 2.0]);
}

#[test]
fn saturation_clips_and_flags() {
    let s = PidSettings {
        kp: 10.0,
        output_min: -1.0,
        output_max: 2.0,
        ..settings()
    };
    let got = run(&s, &[(0.1, 0.0), (1.0, 0.0), (-1.0, 0.0)]);
    assert_outputs(&got, &[1.0, 2.0, -1.0]);
    assert_eq!(
        got.iter().map(|g| g.saturated).collect::<Vec<_>>(),
        [false, true, true]
    );
    assert!(close(got[1].unsaturated, 10.0));
}

/// kp = 1, ki = 100/s, limits +-1, Ts 1 ms; error 2 for 3 samples, then -0.5.
fn windup_case(anti_windup: AntiWindup) -> Vec<PidSignals> {
    let s = PidSettings {
        kp: 1.0,
        ki: 100.0,
        output_min: -1.0,
        output_max: 1.0,
        anti_windup,
        tracking_time: 0.01,
        ..settings()
    };
    run(
        &s,
        &[(2.0, 0.0), (2.0, 0.0), (2.0, 0.0), (-0.5, 0.0), (-0.5, 0.0)],
    )
}

#[test]
fn without_anti_windup_the_integral_winds_up() {
    let got = windup_case(AntiWindup::None);
    let i: Vec<f64> = got.iter().map(|g| g.integral).collect();
    // I += 100 * 0.001 * e = 0.2 per sample at e = 2.
    for (g, w) in i.iter().zip([0.0, 0.2, 0.4, 0.6, 0.55]) {
        assert!(close(*g, w), "{i:?}");
    }
    // Sample 3: v = -0.5 + 0.6 = 0.1: the wound-up integral still drives positive.
    assert!(close(got[3].output, 0.1));
}

#[test]
fn clamping_stops_integrating_into_the_limit() {
    let got = windup_case(AntiWindup::Clamping);
    let i: Vec<f64> = got.iter().map(|g| g.integral).collect();
    // Sample 0: v = 2 > 1 and e > 0: no integration; likewise samples 1, 2.
    // Sample 3: v = -0.5 inside the limits: integrates -0.05.
    for (g, w) in i.iter().zip([0.0, 0.0, 0.0, 0.0, -0.05]) {
        assert!(close(*g, w), "{i:?}");
    }
    assert_outputs(&got, &[1.0, 1.0, 1.0, -0.5, -0.55]);
}

#[test]
fn back_calculation_bleeds_the_excess() {
    let got = windup_case(AntiWindup::BackCalculation);
    // I_{k+1} = I_k + Ts (ki e + (u - v)/Tt), Ts/Tt = 0.1.
    // k0: v = 2, u = 1: I1 = 0 + 0.2 + 0.1 * (-1) = 0.1
    // k1: v = 2.1, u = 1: I2 = 0.1 + 0.2 - 0.11 = 0.19
    // k2: v = 2.19, u = 1: I3 = 0.19 + 0.2 - 0.119 = 0.271
    // k3: v = -0.5 + 0.271 = -0.229, unsaturated: I4 = 0.271 - 0.05 = 0.221
    let want_i = [0.0, 0.1, 0.19, 0.271, 0.221];
    for (g, w) in got.iter().zip(want_i) {
        assert!(close(g.integral, w), "{} vs {w}", g.integral);
    }
    assert_outputs(&got, &[1.0, 1.0, 1.0, -0.229, -0.279]);
}

#[test]
fn gain_changes_are_bumpless() {
    let base = PidSettings {
        kp: 2.0,
        ki: 5.0,
        kd: 0.1,
        derivative_filter_time: 2e-3,
        ..settings()
    };
    let inputs = |k: usize| PidInputs {
        setpoint: 1.0,
        measurement: 0.3 * (1.0 - (k as f64 * 0.01).cos()),
        ..PidInputs::default()
    };
    for change in [
        PidSettings { ki: 20.0, ..base },
        PidSettings { kp: 7.0, ..base },
        PidSettings { kd: 0.4, ..base },
        PidSettings {
            kp: 0.5,
            ki: 5.0,
            kd: 0.0,
            ..base
        },
    ] {
        let mut state = PidState::default();
        let mut previous = 0.0;
        for k in 0..200 {
            let s = if k < 100 { base } else { change };
            let (sig, next) = pid_sample(&s, &state, &inputs(k));
            if k >= 1 {
                // Between samples the output moves by far less than the P-term's jump
                // (e.g. 5 * 0.7 = 3.5 for the kp change).
                assert!(
                    (sig.output - previous).abs() < 0.05,
                    "{change:?}: jump {} at sample {k}",
                    sig.output - previous
                );
            }
            if k == 100 {
                // The output at the change equals what the old gains would have given.
                let (old, _) = pid_sample(&base, &state, &inputs(k));
                assert!(close(sig.output, old.output), "{change:?}");
            }
            previous = sig.output;
            state = next;
        }
    }
    // With ki = 0 there is nothing to absorb a kp change: the output follows it.
    let p = PidSettings {
        kp: 1.0,
        ..settings()
    };
    let mut state = PidState::default();
    let input = PidInputs {
        setpoint: 1.0,
        ..PidInputs::default()
    };
    state = pid_sample(&p, &state, &input).1;
    let (sig, _) = pid_sample(&PidSettings { kp: 3.0, ..p }, &state, &input);
    assert!(close(sig.output, 3.0));
}

#[test]
fn hold_freezes_integrator_and_output() {
    for action in [HoldAction::HoldLastOutput, HoldAction::ZeroOutput] {
        let s = PidSettings {
            kp: 1.0,
            ki: 100.0,
            hold_action: action,
            ..settings()
        };
        let mut state = PidState::default();
        let mut out = Vec::new();
        for k in 0..6 {
            let input = PidInputs {
                setpoint: 1.0,
                measurement: 0.0,
                feed_forward: 0.0,
                auxiliary: [0.0; AUXILIARIES],
                hold: (2..4).contains(&k),
            };
            let (sig, next) = pid_sample(&s, &state, &input);
            out.push(sig);
            state = next;
        }
        // I: 0, 0.1, 0.2 (held at samples 2, 3), 0.2, 0.3
        let held = match action {
            HoldAction::HoldLastOutput => 1.1,
            HoldAction::ZeroOutput => 0.0,
        };
        assert_outputs(&out, &[1.0, 1.1, held, held, 1.2, 1.3]);
        assert!(!out[2].saturated);
    }
}

#[test]
fn feed_forward_is_scaled_and_added() {
    let s = PidSettings {
        kp: 1.0,
        feed_forward_gain: 0.5,
        ..settings()
    };
    let (sig, _) = pid_sample(
        &s,
        &PidState::default(),
        &PidInputs {
            setpoint: 1.0,
            measurement: 0.0,
            feed_forward: 4.0,
            auxiliary: [0.0; AUXILIARIES],
            hold: false,
        },
    );
    assert!(close(sig.output, 3.0) && close(sig.feed_forward, 2.0));
}

#[test]
fn auxiliaries_enter_the_reference_and_the_feed_forward_by_their_weights() {
    // kp = 2, reverse acting: e = -(r - y) with r = 1 + 0.5*3 - 2*(-1) + 0.25*4 = 5.5,
    // y = 0.5 -> e = -5; P = -10; F = 0.5*2 + (1*3 + 0*(-1) - 3*4) = 1 - 9 = -8; u = -18.
    let s = PidSettings {
        kp: 2.0,
        feed_forward_gain: 0.5,
        setpoint_weights: [0.5, -2.0, 0.25],
        feed_forward_weights: [1.0, 0.0, -3.0],
        reverse_acting: true,
        ..settings()
    };
    let (sig, _) = pid_sample(
        &s,
        &PidState::default(),
        &PidInputs {
            setpoint: 1.0,
            measurement: 0.5,
            feed_forward: 2.0,
            auxiliary: [3.0, -1.0, 4.0],
            hold: false,
        },
    );
    assert!(close(sig.reference, 5.5), "{}", sig.reference);
    assert!(close(sig.error, -5.0) && close(sig.proportional, -10.0));
    assert!(close(sig.feed_forward, -8.0), "{}", sig.feed_forward);
    assert!(close(sig.output, -18.0), "{}", sig.output);
    // Zero weights: the auxiliaries change nothing.
    let (plain, _) = pid_sample(
        &settings(),
        &PidState::default(),
        &PidInputs {
            setpoint: 1.0,
            auxiliary: [3.0, -1.0, 4.0],
            ..Default::default()
        },
    );
    assert!(close(plain.reference, 1.0) && close(plain.output, 0.0));
}

#[test]
fn presets_are_the_published_gain_sets() {
    assert_eq!(preset_gains(0), None);
    assert_eq!(preset_gains(3), Some((2000.0, 300.0, 100.0)));
    assert_eq!(preset_gains(6), Some((6210.0, 0.19, 0.045)));
    let mut m = fresh_model::<PidController>();
    m.preset = 5;
    let s = m.settings().unwrap();
    assert_eq!((s.kp, s.ki, s.kd), (6300.0, 0.22, 0.05));
    m.preset = 99;
    assert!(m.settings().is_err());
}

#[test]
fn a_parameter_set_through_the_variable_table_takes_effect_at_once() {
    use crate::model::Access;
    let set = |m: &mut PidController, name: &str, value: f64| {
        let v = PidController::variables()
            .iter()
            .find(|v| v.name == name)
            .unwrap();
        let Access::Real(_, setter) = v.access else {
            panic!("{name} is not a Real")
        };
        setter(m, value);
    };
    let mut m = fresh_model::<PidController>();
    set(&mut m, "ki", 0.0);
    set(&mut m, "kd", 0.0);
    m.initialize(0.0).unwrap();
    m.inputs.setpoint = 2.0;
    m.do_step(0.0, 1e-3).unwrap();
    assert_eq!(m.signals.output, 2.0, "kp 1");
    // The settings are cached between steps; a setter must refresh them.
    set(&mut m, "kp", 3.0);
    m.do_step(1e-3, 1e-3).unwrap();
    assert_eq!(m.signals.output, 6.0, "kp 3");
    set(&mut m, "outputMax", 5.0);
    m.do_step(2e-3, 1e-3).unwrap();
    assert_eq!(m.signals.output, 5.0, "limit 5");
}

/// The fast check (one sum) answers as the naming check for every pair of outputs taking
/// special values: non-finite ones (alone, or two that cancel into NaN) and finite ones whose
/// sum overflows (then the naming check finds every output finite: Ok).
#[test]
fn the_finiteness_check_agrees_with_the_naming_one() {
    let specials = [
        f64::NAN,
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::MAX,
        f64::MIN,
        f64::MIN_POSITIVE / 2.0,
        -0.0,
        1.5,
    ];
    fn slot(s: &mut PidSignals, field: usize) -> &mut f64 {
        match field {
            0 => &mut s.output,
            1 => &mut s.reference,
            2 => &mut s.error,
            3 => &mut s.proportional,
            4 => &mut s.integral,
            5 => &mut s.derivative,
            6 => &mut s.feed_forward,
            _ => &mut s.unsaturated,
        }
    }
    let mut overflowing = 0;
    for (a, b) in (0..8).flat_map(|a| (0..8).map(move |b| (a, b))) {
        for x in specials {
            for y in specials {
                let mut s = PidSignals::default();
                *slot(&mut s, a) = x;
                *slot(&mut s, b) = y;
                // With a == b the field holds y.
                let finite = y.is_finite() && (a == b || x.is_finite());
                let fast = s.check_finite(1.0).map_err(|e| e.message);
                let plain = s.not_finite(1.0).map_err(|e| e.message);
                assert_eq!(fast, plain, "fields {a} {b}, {x} {y}");
                assert_eq!(fast.is_ok(), finite, "fields {a} {b}, {x} {y}");
                if finite && a != b && !(x + y).is_finite() {
                    overflowing += 1;
                }
            }
        }
    }
    assert!(overflowing > 0, "sums that overflow are among the cases");
}

#[test]
fn an_overflowing_law_answers_an_error_naming_the_output() {
    let mut m = fresh_model::<PidController>();
    m.kp = 1.0;
    m.ki = 0.0;
    m.kd = 0.0;
    m.initialize(0.0).unwrap();
    m.inputs.setpoint = 1e308;
    m.inputs.measurement = -1e308;
    let e = m.calculate(0.0).unwrap_err();
    assert!(e.message.contains("output error is inf at t = 0 s"), "{e}");
    let e = m.do_step(0.0, 1e-3).unwrap_err();
    assert!(
        e.message.contains("output error is inf at t = 0.001 s"),
        "{e}"
    );
    // The step has advanced the controller: a genuine failure, not a refusal.
    assert!(!e.is_refused());
}

#[test]
fn model_steps_samples_and_holds_between_them() {
    let mut m = fresh_model::<PidController>();
    m.kp = 1.0;
    m.ki = 0.0;
    m.kd = 0.0;
    m.initialize(0.0).unwrap();
    m.inputs.setpoint = 2.0;
    m.calculate(0.0).unwrap();
    assert_eq!(m.signals.output, 2.0, "feedthrough at a sample instant");
    m.do_step(0.0, 0.5e-3).unwrap();
    m.inputs.setpoint = 3.0;
    m.calculate(0.5e-3).unwrap();
    assert_eq!(m.signals.output, 2.0, "held between instants");
    m.do_step(0.5e-3, 0.5e-3).unwrap();
    m.calculate(1e-3).unwrap();
    assert_eq!(m.signals.output, 3.0, "feedthrough at the next instant");
    m.do_step(1e-3, 2e-3).unwrap();
    assert_eq!(m.clock.next, 3);
    // A step across an instant ending between two: the samples at 3 and 4 ms from the inputs
    // of 3 ms, the output of the one at 4 ms held at 4.5 ms.
    m.inputs.setpoint = 5.0;
    m.do_step(3e-3, 1.5e-3).unwrap();
    assert_eq!(m.clock.next, 5);
    assert_eq!(m.signals.output, 5.0);
    m.inputs.setpoint = 6.0;
    m.calculate(4.5e-3).unwrap();
    assert_eq!(m.signals.output, 5.0, "held between instants");
    m.do_step(4.5e-3, 0.5e-3).unwrap();
    m.calculate(5e-3).unwrap();
    assert_eq!(m.signals.output, 6.0, "feedthrough at the next instant");
}

/// The inputs held over the `k`-th interval of 1.5 ms.
fn interval_inputs(k: usize) -> PidInputs {
    let x = k as f64;
    PidInputs {
        setpoint: 2.0 * (0.7 * x).sin(),
        measurement: (0.31 * x).cos(),
        feed_forward: 0.1 * (0.5 * x).sin(),
        auxiliary: [0.01 * x, (0.2 * x).sin(), 0.3 * (0.9 * x).cos()],
        hold: k % 17 == 5,
    }
}

/// A PID with every part of the law active (P, I with back-calculation, filtered D,
/// saturation, feed-forward, auxiliary weights), initialized at 0.
fn busy_pid() -> PidController {
    let mut m = fresh_model::<PidController>();
    m.kp = 3.0;
    m.ki = 40.0;
    m.kd = 0.02;
    m.derivative_filter_time = 3e-3;
    m.output_min = -2.0;
    m.output_max = 2.0;
    m.anti_windup = AntiWindup::BackCalculation as i32;
    m.tracking_time = 0.05;
    m.setpoint_weights = [0.5, 0.2, 0.0];
    m.feed_forward_weights = [0.1, 0.0, 0.3];
    m.initialize(0.0).unwrap();
    m
}

/// A run with steps of 1.5 ms (each crossing a sample instant, every other one ending between
/// two) gives, at every one of its communication points, bit for bit the outputs, state and
/// clock of a run with 0.5 ms steps whose inputs are held over the same 1.5 ms: the same
/// samples from the same inputs. At 0, 3, 6 ms, ... (sample instants) the outputs are the
/// fresh sample from the inputs just set, at 1.5, 4.5 ms, ... the last executed sample's.
#[test]
fn steps_off_the_grid_equal_shorter_steps_with_the_inputs_held_over_them() {
    const H: f64 = 1.5e-3;
    const SUB: f64 = 0.5e-3;
    let (mut a, mut b) = (busy_pid(), busy_pid());
    let (mut saturated, mut held) = (0, 0);
    for k in 0..400 {
        let t = k as f64 * H;
        a.inputs = interval_inputs(k);
        b.inputs = interval_inputs(k);
        a.calculate(t).unwrap();
        b.calculate(t).unwrap();
        assert_eq!(
            a.signals, b.signals,
            "outputs at {t} s, the inputs just set"
        );
        a.do_step(t, H).unwrap();
        for j in 0..3 {
            let tj = t + j as f64 * SUB;
            b.calculate(tj).unwrap();
            b.do_step(tj, SUB).unwrap();
        }
        assert_eq!(
            a.signals, b.signals,
            "outputs at the end of the step from {t} s"
        );
        assert_eq!(
            (a.state, a.clock.next),
            (b.state, b.clock.next),
            "from {t} s"
        );
        saturated += usize::from(a.signals.saturated);
        held += usize::from(a.inputs.hold);
    }
    // 400 steps of 1.5 periods: 600 samples; the run saturates and holds at times.
    assert_eq!(a.clock.next, 600);
    assert!(saturated > 10 && held > 10, "{saturated} {held}");
}

#[test]
fn model_refuses_inconsistent_limits() {
    let mut m = fresh_model::<PidController>();
    m.output_min = 5.0;
    m.output_max = 1.0;
    assert!(m.initialize(0.0).is_err_and(|e| e.is_refused()));
}

#[test]
fn state_round_trips() {
    let mut m = fresh_model::<PidController>();
    m.initialize(0.0).unwrap();
    m.inputs.setpoint = 1.0;
    m.do_step(0.0, 3e-3).unwrap();
    let mut w = StateWriter::default();
    m.save_internal(&mut w);
    let mut n = fresh_model::<PidController>();
    n.load_internal(&mut StateReader::new(&w.bytes)).unwrap();
    assert_eq!(n.state, m.state);
    assert_eq!(n.clock, m.clock);
    assert_eq!(n.held, m.held);
}
