//! First time derivatives of every Real output at the current time (what
//! `fmi2GetRealOutputDerivatives` of order 1 answers, FMI 2.0 sections 4.2.1/4.3.1).
//!
//! Each derivative is exact for the model's own equations at the communication point, with the
//! inputs of the last step held and the plant's current mode (stick/slip, driver saturation,
//! clutch) kept:
//!
//! * **state and linear outputs**: the state's rate `z' = M z` of the held mode; an output
//!   linear in `z` (angles, velocities, currents, torques, the calibrated load cell and
//!   transducer with their gains `b cos(c) / (m g Lg)`) has the same combination of `z'`;
//! * **products** (powers `V i`, `i_G Km i w`, losses `-c w^2 + T w`, energies `I w^2 / 2`,
//!   `k d^2 / 2` and their rates) by the product rule; an armature voltage is affine in the
//!   state, `V = a i + b w + c` (`a = b = 0` on a voltage row), so `V' = a i' + b w'`;
//! * **accelerations**: `z'' = M z'`, with the friction input's own rate in `z'`;
//! * **friction** while sliding: Coulomb friction is constant (0); the exponential law and the
//!   loss surface by the chain rule through `|w|` (and the load torque for the surface; an
//!   argument clamped to the tested box is constant there);
//! * **an energy integral's derivative is its power**: the integrand at the communication
//!   point (`max(P, 0)` for a "consumed" energy, `R i^2` for copper loss, `Ke G w i` for the
//!   back-emf energy, the clutch's and the offset's constant powers);
//! * **piecewise constant between events: 0** (almost everywhere): the quantised encoder
//!   angles and counts, the clamp counter, the clutch and offset powers, the supply-divider
//!   readings (of the constant supplies), a current-sensor reading clipped at its rail;
//! * **a stuck body** has speed 0 with derivative 0 (its rows of `M` are zero), **a saturated
//!   driver** a constant voltage (a voltage row: `V' = 0`);
//! * **a tripped bench** is latched: no output changes any more, every derivative is 0.
//!
//! The derivatives come as a [`BenchOutputs`] of the same fields as the values (each Real field
//! its output's derivative), built by one struct literal naming every field: a new output does
//! not compile until its derivative is stated here, and the FMU reads value and derivative of an
//! output through the same field of its one variable declaration.

use super::mechanics::{CURRENT1, CURRENT2, FRICTION1, FRICTION2, OMEGA1, OMEGA2, THETA1, THETA2};
use super::{BenchOutputs, BenchPlant};

/// First time derivatives of the outputs: a [`BenchOutputs`] whose every Real field holds the
/// derivative of the output of that name (see [`BenchPlant::output_derivatives`]); the Boolean
/// flags and the Integer trip code are no Real outputs and hold `false` and 0.
pub type BenchOutputDerivatives = BenchOutputs;

impl BenchPlant {
    /// First time derivatives of every Real output at the current time (see the module
    /// documentation for the rule of each kind of output).
    pub fn output_derivatives(&self) -> BenchOutputDerivatives {
        if self.state.trip.is_some() {
            // Latched: every further step returns the trip, the outputs stay as they are.
            return BenchOutputs::default();
        }
        let p = &self.params;
        let held = self.held_for_outputs();
        let (z, rate) = self.rates(&held);
        let k = p.coupling_stiffness();
        let tpa = self.output_torque_per_ampere();
        let stuck = self.state.stuck;

        // Friction while sliding (as `fill_mode` reports it) and its rate.
        let load_torque_rate = tpa[1] * rate[CURRENT2];
        let mut friction = [0.0; 2];
        let mut friction_rate = [0.0; 2];
        for j in 0..2 {
            if stuck[j] {
                continue;
            }
            let (w, s) = (z[OMEGA1 + j], self.state.direction[j]);
            // d|w|/dt, with the sliding direction as the sign at w = 0 (breaking away).
            let speed_rate = if w == 0.0 { s } else { w.signum() } * rate[OMEGA1 + j];
            friction[j] = held.friction[j];
            friction_rate[j] =
                self.law(&held, j)
                    .sliding_torque_rate(p, s, w.abs(), speed_rate, load_torque_rate);
        }
        // z'' = M z', the friction inputs of z' at their own rates.
        let mut dz = rate;
        dz[FRICTION1] = friction_rate[0];
        dz[FRICTION2] = friction_rate[1];
        let accel_rate = self.apply_matrix(&held, &dz);

        // Velocities, currents and the rates of both (`d` = omega or current, `dd` its rate).
        let (w, dw, ddw) = (
            [z[OMEGA1], z[OMEGA2]],
            [rate[OMEGA1], rate[OMEGA2]],
            [accel_rate[OMEGA1], accel_rate[OMEGA2]],
        );
        let (i, di) = ([z[CURRENT1], z[CURRENT2]], [rate[CURRENT1], rate[CURRENT2]]);
        let deflection = z[THETA1] - z[THETA2];
        let deflection_rate = rate[THETA1] - rate[THETA2];

        // Powers (the values the power outputs report) and their rates.
        let powers = self.powers_at(&held, &z);
        let mut voltage_rate = [0.0; 2];
        let mut electrical_rate = [0.0; 2];
        let mut mechanical_rate = [0.0; 2];
        let mut loss = [0.0; 2];
        let mut loss_rate = [0.0; 2];
        let damping = [p.actuation_damping, p.load_damping];
        for n in 0..2 {
            let (a, b, _) = self.voltage_law_at(&held, n);
            voltage_rate[n] = a * di[n] + b * dw[n];
            let voltage = self.armature_voltage_at(&held, n, &z);
            electrical_rate[n] = voltage_rate[n] * i[n] + voltage * di[n];
            mechanical_rate[n] = tpa[n] * (di[n] * w[n] + i[n] * dw[n]);
            loss[n] = -damping[n] * w[n] * w[n] + friction[n] * w[n];
            loss_rate[n] =
                -2.0 * damping[n] * w[n] * dw[n] + friction_rate[n] * w[n] + friction[n] * dw[n];
        }
        let inertia = [p.actuation_inertia, p.load_inertia];
        let kinetic_rate = inertia[0] * w[0] * dw[0] + inertia[1] * w[1] * dw[1];
        let kinetic_rate_rate = inertia[0] * (dw[0] * dw[0] + w[0] * ddw[0])
            + inertia[1] * (dw[1] * dw[1] + w[1] * ddw[1]);
        let potential_rate = k * deflection * deflection_rate;
        let potential_rate_rate =
            k * (deflection_rate * (w[0] - w[1]) + deflection * (dw[0] - dw[1]));

        // Sensors: the calibrated load cell and transducer are affine in their torques.
        let moment = p.calibration_pendulum_moment;
        let phases = self.sensor_phases();
        let test_torque_rate = tpa[0] * di[0];
        let spring_torque_rate = k * deflection_rate;
        let cell_voltage_rate = p.load_cell_gain * phases[0].1 / moment * test_torque_rate;
        let transducer_voltage_rate = p.transducer_gain * phases[1].1 / moment * spring_torque_rate;
        let current_sense_rate = |n: usize| {
            let raw = p.current_sensor_offset + p.current_sensor_sensitivity * i[n];
            if raw > 0.0 && raw < 5.0 {
                p.current_sensor_sensitivity * di[n]
            } else {
                0.0 // clipped at a rail
            }
        };
        let (r1, ke1) = self.resistance_and_back_emf(0);
        let (r2, ke2) = self.resistance_and_back_emf(1);
        let clutch_power = if self.state.clutch {
            p.clutch_power
        } else {
            0.0
        };

        BenchOutputs {
            actuation_angle: rate[THETA1],
            load_angle: rate[THETA2],
            actuation_velocity: dw[0],
            load_velocity: dw[1],
            actuation_acceleration: ddw[0],
            load_acceleration: ddw[1],
            spring_deflection: deflection_rate,
            spring_torque: spring_torque_rate,
            test_motor_current: di[0],
            load_motor_current: di[1],
            test_motor_voltage: voltage_rate[0],
            load_motor_voltage: voltage_rate[1],
            test_motor_torque: p.test_motor_torque_constant * di[0],
            load_motor_torque: p.load_motor_torque_constant * di[1],
            test_output_torque: test_torque_rate,
            load_output_torque: tpa[1] * di[1],
            actuation_friction_torque: friction_rate[0],
            load_friction_torque: friction_rate[1],
            // Quantised: constant between count changes.
            actuation_encoder_angle: 0.0,
            load_encoder_angle: 0.0,
            actuation_encoder_counts: 0.0,
            load_encoder_counts: 0.0,
            load_cell_voltage: cell_voltage_rate,
            load_cell_torque: moment / p.load_cell_gain * cell_voltage_rate,
            transducer_voltage: transducer_voltage_rate,
            transducer_torque: moment / p.transducer_gain * transducer_voltage_rate,
            // Dividers of the constant supplies.
            test_supply_sense_voltage: 0.0,
            load_supply_sense_voltage: 0.0,
            test_current_sense_voltage: current_sense_rate(0),
            load_current_sense_voltage: current_sense_rate(1),
            // Not Real outputs: no derivative.
            clutch_engaged: false,
            actuation_stuck: false,
            load_stuck: false,
            test_driver_saturated: false,
            load_driver_saturated: false,
            test_mechanical_power: mechanical_rate[0],
            load_mechanical_power: mechanical_rate[1],
            loss_power: loss_rate[0] + loss_rate[1],
            actuation_loss_power: loss_rate[0],
            load_loss_power: loss_rate[1],
            kinetic_energy_rate: kinetic_rate_rate,
            potential_energy_rate: potential_rate_rate,
            test_electrical_power: electrical_rate[0],
            load_electrical_power: electrical_rate[1],
            load_regenerated_power: if powers[3] < 0.0 {
                -electrical_rate[1]
            } else {
                0.0
            },
            // Constant while the clutch holds its state / always.
            clutch_power: 0.0,
            offset_power: 0.0,
            total_electrical_power: electrical_rate[0] + electrical_rate[1],
            kinetic_energy: kinetic_rate,
            potential_energy: potential_rate,
            // Energy integrals: their integrands.
            test_mechanical_energy: powers[0],
            test_mechanical_energy_consumed: powers[0].max(0.0),
            load_mechanical_energy: powers[1],
            load_mechanical_energy_consumed: powers[1].max(0.0),
            loss_energy: loss[0] + loss[1],
            actuation_loss_energy: loss[0],
            load_loss_energy: loss[1],
            kinetic_energy_change: kinetic_rate,
            potential_energy_change: potential_rate,
            test_electrical_energy: powers[2],
            test_electrical_energy_consumed: powers[2].max(0.0),
            load_electrical_energy: powers[3],
            load_electrical_energy_consumed: powers[3].max(0.0),
            clutch_energy: clutch_power,
            offset_energy: p.hardware_offset_power,
            total_electrical_energy: powers[4],
            total_electrical_energy_consumed: powers[4].max(0.0),
            test_copper_loss_energy: r1 * i[0] * i[0],
            load_copper_loss_energy: r2 * i[1] * i[1],
            test_back_emf_energy: ke1 * w[0] * i[0],
            load_back_emf_energy: ke2 * w[1] * i[1],
            // A counter.
            hd_surface_clamp_count: 0.0,
            hd_surface_clamped: false,
            trip_code: 0,
        }
    }
}
