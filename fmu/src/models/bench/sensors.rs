//! Sensor models (bench-model.md §8) for a running bench.
//!
//! * Encoders: incremental, `counts = floor(theta_motor * N / 2 pi)` with `theta_motor = G theta`
//!   and `N` counts per motor revolution (default 500 CPT x 4 = 2000); the reported angle is
//!   `counts * 2 pi / (N G)` at the output axis (resolution 2 pi / (2000 x 160) = 1.96e-5 rad on
//!   the actuation side, 2 pi / (2000 x 66) = 4.76e-5 rad on the load side).
//! * Torque transducer: measures the shaft torque on the load side, i.e. the spring torque
//!   `k (theta1 - theta2)`. Load cell: the test-motor reaction torque, i.e. the test motor's
//!   output-side torque `i_HD Km1 i1` (the housing reacts what the gear transmits; rotor inertia
//!   is part of I1).
//! * Both follow the pendulum calibration `V = a + b sin(theta + c)`, `T = m g Lg sin(theta)`.
//!   For a running bench the sensors are linear in torque; expanding `sin(theta + c)` for the
//!   small calibration angles gives the raw voltage `V = a + b sin(c) + b cos(c) T / (m g Lg)`.
//!   The bench converts back with the published `T = (m g Lg / b)(V - a)`, which drops `c`, so
//!   the calibrated torque output carries exactly the bias the real bench reading has
//!   (`T cos(c) + m g Lg sin(c)`: -0.048 N m for the transducer, +0.090 N m for the load cell).
//! * Supply divider: `V = 0.002 + 0.139 V_supply` for each driver supply (ideal supplies).
//! * Current sensors (ACS712-20A): `V = 2.5 + 0.1 i`, clipped to the sensor's 0..5 V output.

use super::BenchParameters;

/// Encoder angle at the output axis for a true angle `theta` behind a gear ratio `ratio`.
pub(crate) fn encoder(theta: f64, ratio: f64, counts_per_rev: f64) -> (f64, f64) {
    let per_radian = counts_per_rev * ratio / std::f64::consts::TAU;
    let counts = (theta * per_radian).floor();
    (counts, counts / per_radian)
}

/// Raw voltage of a pendulum-calibrated torque sensor for torque `torque`, phase `c`.
#[cfg(test)]
pub(crate) fn calibrated_sensor_voltage(torque: f64, a: f64, b: f64, c: f64, moment: f64) -> f64 {
    calibrated_sensor_voltage_at_phase(torque, a, b, (c.sin(), c.cos()), moment)
}

/// Raw voltage of a pendulum-calibrated torque sensor for torque `torque`, with the
/// calibration phase `c` given as `(sin c, cos c)`.
pub(crate) fn calibrated_sensor_voltage_at_phase(
    torque: f64,
    a: f64,
    b: f64,
    (sin_c, cos_c): (f64, f64),
    moment: f64,
) -> f64 {
    a + b * sin_c + b * cos_c * torque / moment
}

/// The bench's published conversion back to torque, `T = (m g Lg / b)(V - a)`.
pub(crate) fn calibrated_sensor_torque(voltage: f64, a: f64, b: f64, moment: f64) -> f64 {
    moment / b * (voltage - a)
}

/// Supply-divider voltage read by the myRIO.
pub(crate) fn divider_voltage(p: &BenchParameters, supply: f64) -> f64 {
    p.divider_offset + p.divider_gain * supply
}

/// ACS712 output voltage for current `current`, clipped to 0..5 V.
pub(crate) fn current_sensor_voltage(p: &BenchParameters, current: f64) -> f64 {
    (p.current_sensor_offset + p.current_sensor_sensitivity * current).clamp(0.0, 5.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn encoder_resolution_and_quantisation() {
        let step = std::f64::consts::TAU / (2000.0 * 160.0);
        let (counts, angle) = encoder(10.4 * step, 160.0, 2000.0);
        assert_eq!(counts, 10.0);
        assert!((angle - 10.0 * step).abs() < 1e-18);
        let (counts, _) = encoder(-0.2 * step, 160.0, 2000.0);
        assert_eq!(counts, -1.0);
    }

    #[test]
    fn calibration_round_trip_has_the_documented_bias() {
        let p = BenchParameters::default();
        let moment = p.calibration_pendulum_moment;
        let torque = 12.0;
        let v = calibrated_sensor_voltage(
            torque,
            p.transducer_offset,
            p.transducer_gain,
            p.transducer_phase,
            moment,
        );
        let back = calibrated_sensor_torque(v, p.transducer_offset, p.transducer_gain, moment);
        let expected = torque * p.transducer_phase.cos() + moment * p.transducer_phase.sin();
        assert!((back - expected).abs() < 1e-12);
        assert!((divider_voltage(&p, 24.0) - (0.002 + 0.139 * 24.0)).abs() < 1e-15);
        assert_eq!(current_sensor_voltage(&p, 1.0), 2.6);
        assert_eq!(current_sensor_voltage(&p, 40.0), 5.0);
    }
}
