//! `fmi2GetRealOutputDerivatives` of order 1 for every Real output of the plant, through the
//! FMU's variable table: each derivative agrees with a central finite difference of the output
//! over two steps of `H / 2` of the plant around the communication point (inputs held, no event
//! in between), for DA, SEA and CSEA, a body stuck by the clutch, a current loop saturated at its
//! supply, a driver in voltage mode past its supply, and the speed-dependent friction laws. The
//! tolerance rejects a wrong derivative: the comparison is checked to fail for the negated and
//! for a 1 % wrong value of every derivative that is not 0.

use super::*;
use crate::model::Access;
use model_description::Causality;

/// The finite-difference interval [s]: short against the stiffest rate (the current loop's
/// 0.25 ms), long against rounding.
const H: f64 = 2e-6;
/// Relative tolerance of the comparison (the central difference's own error is below 1e-5).
const RELATIVE: f64 = 1e-4;

/// A plant after `steps` communication steps of 1 ms with the commands of `configure`, each
/// modulated step by step (so that currents and speeds keep changing).
fn running(configure: impl FnOnce(&mut BenchPlantModel), steps: usize) -> BenchPlantModel {
    let mut m = crate::fmi2::instance::fresh_model::<BenchPlantModel>();
    m.commands.test_current = 3.0;
    m.commands.load_current = -0.5;
    configure(&mut m);
    let base = m.commands;
    m.calculate(0.0).unwrap();
    m.initialize(0.0).unwrap();
    for k in 0..steps {
        let t = k as f64 * 1e-3;
        let (a, b) = (
            1.0 + 0.5 * (std::f64::consts::TAU * 2.0 * t).sin(),
            1.0 + 0.5 * (std::f64::consts::TAU * 3.0 * t).cos(),
        );
        m.commands.test_current = a * base.test_current;
        m.commands.test_voltage = a * base.test_voltage;
        m.commands.load_current = b * base.load_current;
        m.commands.load_voltage = b * base.load_voltage;
        let outcome = m.do_step(t, 1e-3).unwrap();
        assert_eq!(outcome, StepOutcome::Completed);
    }
    m
}

fn real_outputs() -> impl Iterator<Item = (&'static str, u32, fn(&BenchPlantModel) -> f64)> {
    BenchPlantModel::variables().iter().filter_map(|v| {
        match (v.causality == Causality::Output, &v.access) {
            (true, Access::Real(get, _)) => Some((v.name, v.value_reference, *get)),
            _ => None,
        }
    })
}

/// The discrete part of the outputs (mode flags, encoder counts, trip): equal at both ends of
/// the interval means no event inside it.
fn discrete(m: &BenchPlantModel) -> (BenchOutputs, [f64; 2]) {
    let o = m.plant.as_ref().unwrap().outputs();
    let mode = BenchOutputs {
        clutch_engaged: o.clutch_engaged,
        actuation_stuck: o.actuation_stuck,
        load_stuck: o.load_stuck,
        test_driver_saturated: o.test_driver_saturated,
        load_driver_saturated: o.load_driver_saturated,
        hd_surface_clamp_count: o.hd_surface_clamp_count,
        trip_code: o.trip_code,
        ..BenchOutputs::default()
    };
    (mode, [o.actuation_encoder_counts, o.load_encoder_counts])
}

/// Whether `derivative` agrees with the central difference of `minus`, `plus` over `H`.
fn agrees(derivative: f64, minus: f64, plus: f64) -> bool {
    let difference = (plus - minus) / H;
    // Rounding of the values themselves, seen through the difference.
    let floor = 1e3 * f64::EPSILON * (1.0 + minus.abs().max(plus.abs())) / H;
    (difference - derivative).abs() <= RELATIVE * derivative.abs().max(difference.abs()) + floor
}

/// Compares every Real output's derivative at a point with the central difference around it;
/// moves on by 1 ms while the interval holds an event (a count of an encoder, say). Returns
/// the derivatives by name.
fn check(mut m: BenchPlantModel, what: &str) -> Vec<(&'static str, f64)> {
    for attempt in 0..50 {
        let t = 0.3 + attempt as f64 * 1e-3;
        let minus = m.clone();
        let mut point = minus.clone();
        point.do_step(t, 0.5 * H).unwrap();
        let mut plus = point.clone();
        plus.do_step(t + 0.5 * H, 0.5 * H).unwrap();
        if discrete(&minus) != discrete(&plus) || discrete(&minus) != discrete(&point) {
            m.do_step(t, 1e-3).unwrap();
            continue;
        }
        let mut rates = Vec::new();
        let mut discriminated = 0;
        for (name, vr, get) in real_outputs() {
            let d = point
                .output_derivative(vr, 1)
                .unwrap_or_else(|| panic!("{what}: {name} has no derivative"));
            let (y0, y1) = (get(&minus), get(&plus));
            assert!(
                agrees(d, y0, y1),
                "{what}: d {name}/dt = {d:e}, central difference {:e}",
                (y1 - y0) / H
            );
            // The comparison tells a wrong derivative: a sign or 1 % off fails (wherever the
            // derivative stands clear of the rounding floor).
            let floor = 1e3 * f64::EPSILON * (1.0 + y0.abs().max(y1.abs())) / H;
            if d.abs() > 1e3 * floor {
                assert!(!agrees(-d, y0, y1), "{what}: {name}: -d passes");
                assert!(!agrees(1.01 * d, y0, y1), "{what}: {name}: 1.01 d passes");
                discriminated += 1;
            }
            rates.push((name, d));
        }
        assert_eq!(rates.len(), 67, "{what}");
        assert!(
            discriminated >= 30,
            "{what}: {discriminated} outputs discriminated"
        );
        return rates;
    }
    panic!("{what}: no interval without an event in 50 attempts")
}

fn rate(rates: &[(&str, f64)], name: &str) -> f64 {
    rates.iter().find(|(n, _)| *n == name).unwrap().1
}

/// The outputs that move (not 0) in a moving bench, at least these many.
fn moving(rates: &[(&str, f64)]) -> usize {
    rates.iter().filter(|(_, d)| *d != 0.0).count()
}

#[test]
fn every_real_output_has_its_derivative_in_every_configuration() {
    for (configuration, name) in [(0, "DA"), (1, "SEA"), (2, "CSEA")] {
        let m = running(|m| m.configuration = configuration, 300);
        let rates = check(m, name);
        assert!(moving(&rates) >= 45, "{name}: {}", moving(&rates));
        // Piecewise constant: 0.
        for constant in [
            "actuationEncoderAngle",
            "loadEncoderCounts",
            "offsetPower",
            "testSupplySenseVoltage",
            "hdSurfaceClampCount",
        ] {
            assert_eq!(rate(&rates, constant), 0.0, "{name}: {constant}");
        }
        // An energy integral's derivative is its power, the value of the power output.
        let o = running(|m| m.configuration = configuration, 300);
        let values = o.plant.as_ref().unwrap().outputs();
        let d = o.plant.as_ref().unwrap().output_derivatives();
        assert_eq!(d.test_mechanical_energy, values.test_mechanical_power);
        assert_eq!(d.total_electrical_energy, values.total_electrical_power);
        assert_eq!(d.kinetic_energy, values.kinetic_energy_rate);
        assert_eq!(d.loss_energy, values.loss_power);
    }
}

#[test]
fn a_body_held_by_the_clutch_has_speed_and_speed_rate_zero() {
    let m = running(
        |m| {
            m.configuration = 2;
            m.commands.clutch_engage = true;
        },
        300,
    );
    assert!(m.plant.as_ref().unwrap().outputs().actuation_stuck);
    let rates = check(m, "CSEA, clutch engaged");
    for name in [
        "actuationAngle",
        "actuationVelocity",
        "actuationAcceleration",
        "actuationFrictionTorque",
        "actuationLossPower",
    ] {
        assert_eq!(rate(&rates, name), 0.0, "{name}");
    }
    assert!(rate(&rates, "loadVelocity") != 0.0);
}

#[test]
fn a_saturated_driver_has_a_constant_voltage() {
    // A 2 V supply cannot drive the 10 A the loop asks for: saturated at +2 V.
    let m = running(
        |m| {
            m.params.test_supply_voltage = 2.0;
            m.commands.test_current = 10.0;
        },
        300,
    );
    assert!(m.plant.as_ref().unwrap().outputs().test_driver_saturated);
    let rates = check(m, "saturated test driver");
    assert_eq!(rate(&rates, "testMotorVoltage"), 0.0);
    assert!(rate(&rates, "testMotorCurrent") != 0.0);
    // The load driver's loop is not saturated: its voltage moves with the current and speed.
    assert!(rate(&rates, "loadMotorVoltage") != 0.0);
}

#[test]
fn voltage_mode_and_speed_dependent_friction_have_their_derivatives() {
    // Test driver in voltage mode, commanded past its (lowered) supply: held at 3 V; load
    // driver in voltage mode within its supply.
    let m = running(
        |m| {
            m.test_driver_mode = 0;
            m.load_driver_mode = 0;
            m.params.test_supply_voltage = 3.0;
            m.commands.test_voltage = 5.0;
            m.commands.load_voltage = -1.0;
        },
        100,
    );
    let rates = check(m, "voltage mode");
    assert_eq!(rate(&rates, "testMotorVoltage"), 0.0);
    assert_eq!(rate(&rates, "loadMotorVoltage"), 0.0);
    for (friction_model, name) in [(2, "exponential"), (3, "loss surface")] {
        let m = running(
            |m| {
                m.friction_model = friction_model;
                m.commands.test_current = 1.0;
            },
            300,
        );
        let o = m.plant.as_ref().unwrap().outputs();
        assert!(!o.actuation_stuck && !o.hd_surface_clamped, "{name}");
        let rates = check(m, name);
        assert!(rate(&rates, "actuationFrictionTorque") != 0.0, "{name}");
    }
}
