//! From a bench sample to the FMU's outputs (calibrated, differentiated, integrated; the
//! `bench_hardware` module docs, "Outputs"), and the interlocks of bench-model.md §7 the
//! outputs are checked against.

use super::session::Runtime;
use crate::hardware::calibration::Side;
use crate::hardware::protocol::{AnalogChannel, Command, Sample, status};
use crate::models::bench::{BenchOutputs, BenchParameters, Configuration, DriverMode};

/// The interlock of bench-model.md §7 the outputs violate (code 1-6), or 0.
pub(super) fn interlock(p: &BenchParameters, o: &BenchOutputs) -> i32 {
    if o.spring_deflection.abs() > p.spring_deflection_limit {
        1
    } else if o.transducer_torque.abs() > p.motor_torque_limit {
        // The test motor's torque past the harmonic drive: the shaft torque the transducer
        // measures (the plant's definition; see its documentation).
        2
    } else if o.load_output_torque.abs() > p.motor_torque_limit {
        3
    } else if o.test_motor_current.abs() > p.test_current_limit {
        4
    } else if o.load_motor_current.abs() > p.load_current_limit {
        5
    } else if o.load_regenerated_power > p.load_regen_power_limit {
        6
    } else {
        0
    }
}

pub(super) fn raw_into(o: &mut BenchOutputs, s: &Sample) {
    let a = |c: AnalogChannel| s.analog[c.index()];
    o.load_cell_voltage = a(AnalogChannel::LoadCell);
    o.transducer_voltage = a(AnalogChannel::Transducer);
    o.test_current_sense_voltage = a(AnalogChannel::TestCurrentSense);
    o.load_current_sense_voltage = a(AnalogChannel::LoadCurrentSense);
    o.test_supply_sense_voltage = a(AnalogChannel::TestSupplySense);
    o.load_supply_sense_voltage = a(AnalogChannel::LoadSupplySense);
    o.clutch_engaged = s.has(status::CLUTCH);
}

/// Armature voltage estimate and saturation of one driver.
fn armature(
    enabled: bool,
    kind_is_voltage: bool,
    set_value: f64,
    needed: f64,
    supply: f64,
) -> (f64, bool) {
    if enabled && kind_is_voltage {
        (set_value.clamp(-supply, supply), set_value.abs() >= supply)
    } else {
        (
            needed.clamp(-supply, supply),
            enabled && needed.abs() >= supply,
        )
    }
}

/// The outputs from a sample (the `bench_hardware` module docs, "Outputs"). `h` is `None` at
/// initialization.
pub(super) fn measure(
    rt: &Runtime,
    s: &Sample,
    applied: &Command,
    h: Option<f64>,
    prev: &BenchOutputs,
    stuck: [bool; 2],
) -> BenchOutputs {
    let p = &rt.p;
    let cal = &rt.cal;
    let mut o = BenchOutputs::default();
    raw_into(&mut o, s);
    let a = |c: AnalogChannel| s.analog[c.index()];
    let [c1, c2] = [rt.encoders[0].total(), rt.encoders[1].total()];
    let th1 = cal.angle(Side::Actuation, c1);
    let th2 = cal.angle(Side::Load, c2);
    o.actuation_encoder_counts = c1 as f64;
    o.load_encoder_counts = c2 as f64;
    o.actuation_encoder_angle = th1;
    o.load_encoder_angle = th2;
    o.actuation_angle = th1;
    o.load_angle = th2;
    // The time since the last sample on the bench's clock (the step size on the simulated
    // bench): the velocities' differences and the energies' trapezoids both span it, so a late
    // sample ends a longer interval and the samples that follow it while the loop catches up
    // end shorter ones.
    let interval = h.map(|h| if rt.dt[0] > 0.0 { rt.dt[0] } else { h });
    let (w1, w2, a1, a2) = match (h, interval) {
        (Some(h), Some(dt)) => {
            // From integer count differences, so that equal movements give exactly zero
            // acceleration whatever rounding the step size carries.
            let [now, before] = rt.delta;
            let dt_before = rt.dt[1];
            if dt < 0.5 * h && dt_before > 0.0 {
                // The loop catching up after a stall: this sample follows the last by much
                // less than a period, too short for its counts to make a velocity (one count
                // over 0.1 ms reads as a speed spike, and the powers and the regenerated-power
                // interlock with it). The window widens to the last two intervals.
                let span = dt + dt_before;
                let w = |side, counts| cal.angle(side, counts) / span;
                let w_before = |side, counts| cal.angle(side, counts) / dt_before;
                let (w1, w2) = (
                    w(Side::Actuation, now[0] + before[0]),
                    w(Side::Load, now[1] + before[1]),
                );
                (
                    w1,
                    w2,
                    (w1 - w_before(Side::Actuation, before[0])) / (0.5 * span),
                    (w2 - w_before(Side::Load, before[1])) / (0.5 * span),
                )
            } else if dt_before == dt || dt_before <= 0.0 {
                (
                    cal.angle(Side::Actuation, now[0]) / dt,
                    cal.angle(Side::Load, now[1]) / dt,
                    cal.angle(Side::Actuation, now[0] - before[0]) / (dt * dt),
                    cal.angle(Side::Load, now[1] - before[1]) / (dt * dt),
                )
            } else {
                let w = |side, counts| cal.angle(side, counts) / dt;
                let w_before = |side, counts| cal.angle(side, counts) / dt_before;
                (
                    w(Side::Actuation, now[0]),
                    w(Side::Load, now[1]),
                    (w(Side::Actuation, now[0]) - w_before(Side::Actuation, before[0])) / dt,
                    (w(Side::Load, now[1]) - w_before(Side::Load, before[1])) / dt,
                )
            }
        }
        _ => (0.0, 0.0, 0.0, 0.0),
    };
    o.actuation_velocity = w1;
    o.load_velocity = w2;
    o.actuation_acceleration = a1;
    o.load_acceleration = a2;
    let k = match p.configuration {
        Configuration::Da => p.direct_coupling_stiffness,
        _ => p.spring_stiffness,
    };
    let defl = th1 - th2;
    o.spring_deflection = defl;
    o.spring_torque = k * defl;
    let i1 = cal.current(a(AnalogChannel::TestCurrentSense));
    let i2 = cal.current(a(AnalogChannel::LoadCurrentSense));
    o.test_motor_current = i1;
    o.load_motor_current = i2;
    o.test_motor_torque = p.test_motor_torque_constant * i1;
    o.load_motor_torque = p.load_motor_torque_constant * i2;
    o.test_output_torque = p.harmonic_drive_ratio * o.test_motor_torque;
    o.load_output_torque = p.reduction_ratio * o.load_motor_torque;
    o.transducer_torque = cal.transducer_torque(a(AnalogChannel::Transducer));
    o.load_cell_torque = cal.load_cell_torque(a(AnalogChannel::LoadCell));
    let wm1 = p.harmonic_drive_ratio * w1;
    let wm2 = p.reduction_ratio * w2;
    let supply1 = cal.supply_voltage(a(AnalogChannel::TestSupplySense));
    let supply2 = cal.supply_voltage(a(AnalogChannel::LoadSupplySense));
    let (v1, sat1) = armature(
        applied.test_enable,
        p.test_driver_mode == DriverMode::Voltage,
        applied.test_set_value,
        p.test_motor_resistance * i1 + p.test_motor_back_emf_constant * wm1,
        supply1,
    );
    let (v2, sat2) = armature(
        applied.load_enable,
        p.load_driver_mode == DriverMode::Voltage,
        applied.load_set_value,
        p.load_motor_resistance * i2 + p.load_motor_back_emf_constant * wm2,
        supply2,
    );
    o.test_motor_voltage = v1;
    o.load_motor_voltage = v2;
    o.test_driver_saturated = sat1;
    o.load_driver_saturated = sat2;
    o.actuation_stuck = stuck[0];
    o.load_stuck = stuck[1];
    o.test_mechanical_power = o.test_output_torque * w1;
    o.load_mechanical_power = o.load_output_torque * w2;
    o.kinetic_energy = 0.5 * (p.actuation_inertia * w1 * w1 + p.load_inertia * w2 * w2);
    o.potential_energy = 0.5 * k * defl * defl;
    o.kinetic_energy_change = o.kinetic_energy;
    o.potential_energy_change = o.potential_energy;
    o.actuation_loss_power =
        p.actuation_inertia * w1 * a1 + o.spring_torque * w1 - o.test_mechanical_power;
    o.load_loss_power = p.load_inertia * w2 * a2 - o.spring_torque * w2 - o.load_mechanical_power;
    o.loss_power = o.actuation_loss_power + o.load_loss_power;
    o.actuation_friction_torque =
        p.actuation_inertia * a1 + p.actuation_damping * w1 + o.spring_torque
            - o.test_output_torque;
    o.load_friction_torque =
        p.load_inertia * a2 + p.load_damping * w2 - o.spring_torque - o.load_output_torque;
    o.test_electrical_power = v1 * i1;
    o.load_electrical_power = v2 * i2;
    o.load_regenerated_power = (-o.load_electrical_power).max(0.0);
    o.clutch_power = if o.clutch_engaged {
        p.clutch_power
    } else {
        0.0
    };
    o.offset_power = p.hardware_offset_power;
    o.total_electrical_power =
        o.test_electrical_power + o.load_electrical_power + o.clutch_power + o.offset_power;
    let copper = [
        p.test_motor_resistance * i1 * i1,
        p.load_motor_resistance * i2 * i2,
    ];
    let emf = [
        p.test_motor_back_emf_constant * wm1 * i1,
        p.load_motor_back_emf_constant * wm2 * i2,
    ];
    if let Some(h) = interval {
        o.kinetic_energy_rate = (o.kinetic_energy - prev.kinetic_energy) / h;
        o.potential_energy_rate = (o.potential_energy - prev.potential_energy) / h;
        let trap = |acc: f64, a: f64, b: f64| acc + 0.5 * h * (a + b);
        let pos = |x: f64| x.max(0.0);
        o.test_mechanical_energy = trap(
            prev.test_mechanical_energy,
            prev.test_mechanical_power,
            o.test_mechanical_power,
        );
        o.test_mechanical_energy_consumed = trap(
            prev.test_mechanical_energy_consumed,
            pos(prev.test_mechanical_power),
            pos(o.test_mechanical_power),
        );
        o.load_mechanical_energy = trap(
            prev.load_mechanical_energy,
            prev.load_mechanical_power,
            o.load_mechanical_power,
        );
        o.load_mechanical_energy_consumed = trap(
            prev.load_mechanical_energy_consumed,
            pos(prev.load_mechanical_power),
            pos(o.load_mechanical_power),
        );
        o.loss_energy = trap(prev.loss_energy, prev.loss_power, o.loss_power);
        o.actuation_loss_energy = trap(
            prev.actuation_loss_energy,
            prev.actuation_loss_power,
            o.actuation_loss_power,
        );
        o.load_loss_energy = trap(
            prev.load_loss_energy,
            prev.load_loss_power,
            o.load_loss_power,
        );
        o.test_electrical_energy = trap(
            prev.test_electrical_energy,
            prev.test_electrical_power,
            o.test_electrical_power,
        );
        o.test_electrical_energy_consumed = trap(
            prev.test_electrical_energy_consumed,
            pos(prev.test_electrical_power),
            pos(o.test_electrical_power),
        );
        o.load_electrical_energy = trap(
            prev.load_electrical_energy,
            prev.load_electrical_power,
            o.load_electrical_power,
        );
        o.load_electrical_energy_consumed = trap(
            prev.load_electrical_energy_consumed,
            pos(prev.load_electrical_power),
            pos(o.load_electrical_power),
        );
        o.clutch_energy = trap(prev.clutch_energy, prev.clutch_power, o.clutch_power);
        o.offset_energy = trap(prev.offset_energy, prev.offset_power, o.offset_power);
        o.total_electrical_energy = trap(
            prev.total_electrical_energy,
            prev.total_electrical_power,
            o.total_electrical_power,
        );
        o.total_electrical_energy_consumed = trap(
            prev.total_electrical_energy_consumed,
            pos(prev.total_electrical_power),
            pos(o.total_electrical_power),
        );
        let prev_copper = [
            p.test_motor_resistance * prev.test_motor_current.powi(2),
            p.load_motor_resistance * prev.load_motor_current.powi(2),
        ];
        let prev_emf = [
            p.test_motor_back_emf_constant
                * p.harmonic_drive_ratio
                * prev.actuation_velocity
                * prev.test_motor_current,
            p.load_motor_back_emf_constant
                * p.reduction_ratio
                * prev.load_velocity
                * prev.load_motor_current,
        ];
        o.test_copper_loss_energy = trap(prev.test_copper_loss_energy, prev_copper[0], copper[0]);
        o.load_copper_loss_energy = trap(prev.load_copper_loss_energy, prev_copper[1], copper[1]);
        o.test_back_emf_energy = trap(prev.test_back_emf_energy, prev_emf[0], emf[0]);
        o.load_back_emf_energy = trap(prev.load_back_emf_energy, prev_emf[1], emf[1]);
    }
    o.trip_code = prev.trip_code;
    o
}
