//! Sensor offsets beyond the transducer's `tau0` (which the spring's regression gives):
//! whatever the logs can show.
//!
//! * **Load cell** (`loadCellTorque`, the test motor's reaction torque `i_HD Km1 i1` read
//!   through the pendulum calibration, bench-model.md section 8): `T_lc = g (i_HD i1) + T0`,
//!   linear in `(g, T0)` over every row. `T0` is its torque offset (on the plant `m g Lg sin c`
//!   of the load cell's calibration phase, 0.090 N m); `g` is Km1 as the load cell sees it
//!   (Km1 cos c), not reported again. Reported, not a plant parameter (the calibration's `a`,
//!   `b`, `c` are; the pendulum experiment fits them).
//! * **Current sensors** (ACS712, `testCurrentSenseVoltage`, `loadCurrentSenseVoltage`):
//!   `V = a + s i` against the driver's own current reading (bench-model.md section 8: "checked
//!   against the driver's own current reading"), over the rows of both sensors, since the FMU
//!   models both with one pair (`currentSensorOffset`, `currentSensorSensitivity`, which this
//!   sets). Rows where the sensor's 0..5 V output is within 50 mV of a rail are left out (a
//!   clipped reading says nothing of the offset).
//! * **Encoder zeros**: not identifiable from any `kneebench experiment` log. The encoders are
//!   incremental (they count from their position at power-up) and nothing else in the logs is
//!   absolute; the pendulum calibration (`kneebench experiment calibration`) finds the
//!   actuation encoder's zero against gravity (its fitted c).
//!
//! Both regressions use the smoothed currents (the readings' noise would bias the slopes).

use super::log::Log;
use super::{Estimate, Quantity, Regression, estimates_of, lsq, q, regression};

const LOAD_CELL: [Quantity; 2] = [
    q(
        None,
        "load-cell torque per test-motor ampere (i_HD Km1 cos c), not reported",
        "N.m/A",
        "any log with the load cell's torque and a varying test-motor current",
    ),
    q(
        None,
        "load-cell torque offset",
        "N.m",
        "any log with the load cell's torque `loadCellTorque` and a varying test-motor current (every `kneebench experiment` log has them)",
    ),
];

const CURRENT_SENSORS: [Quantity; 2] = [
    q(
        Some("currentSensorOffset"),
        "current-sensor offset (output at 0 A)",
        "V",
        "a log with the current sensors' volts (`testCurrentSenseVoltage`, `loadCurrentSenseVoltage`) and the drivers' current readings",
    ),
    q(
        Some("currentSensorSensitivity"),
        "current-sensor sensitivity",
        "V/A",
        "a log with the current sensors' volts and varying currents",
    ),
];

const ENCODER_ZEROS: [Quantity; 2] = [
    q(
        None,
        "actuation encoder zero offset",
        "rad",
        "an absolute reference: the pendulum calibration `kneebench experiment calibration` (its fitted c is the encoder's zero against the hanging pendulum)",
    ),
    q(
        None,
        "load encoder zero offset",
        "rad",
        "an absolute reference for the load side (a mechanical stop or index pulse; no `kneebench experiment` logs one)",
    ),
];

/// Distance from the current sensor's 0 V and 5 V rails within which a reading is clipped \[V\].
const RAIL_MARGIN: f64 = 0.05;

/// The sensor offsets' estimates (load cell, current sensors, encoder zeros) and regressions,
/// and notes for the sensors not logged. `i_hd` is the harmonic drive's ratio.
pub(super) fn sensor_offsets(
    logs: &[Log],
    i_hd: f64,
    prior: &dyn Fn(&Quantity) -> f64,
    max_relative_ci: f64,
) -> (Vec<Estimate>, Vec<Regression>, Vec<String>) {
    let mut estimates = Vec::new();
    let mut regressions = Vec::new();
    let mut notes = Vec::new();

    // Load cell.
    let (mut x, mut y) = (vec![Vec::new(), Vec::new()], Vec::new());
    for l in logs {
        let Some(t) = &l.load_cell else { continue };
        for (i, torque) in t.iter().enumerate() {
            if l.usable[i] && l.current_smooth[0][i].is_finite() {
                x[0].push(i_hd * l.current_smooth[0][i]);
                x[1].push(1.0);
                y.push(*torque);
            }
        }
    }
    if y.len() >= 100 {
        let f = lsq::fit(&x, &y);
        let e = estimates_of(&LOAD_CELL, &f, prior, max_relative_ci);
        estimates.push(e[1].clone());
        regressions.push(regression(
            "load cell: T_lc = g (i_HD i1) + T0",
            "N.m",
            &LOAD_CELL,
            &f,
        ));
    } else {
        notes.push("load cell: no log has `loadCellTorque`; its offset is not estimated".into());
        estimates.extend(Estimate::none_identifiable(
            &LOAD_CELL[1..],
            prior,
            "the load cell's torque is not logged",
        ));
    }

    // Current sensors, both in one regression.
    let (mut x, mut y) = (vec![Vec::new(), Vec::new()], Vec::new());
    for l in logs {
        for side in 0..2 {
            let Some(v) = &l.current_sense[side] else {
                continue;
            };
            for (i, volts) in v.iter().enumerate() {
                let current = l.current_smooth[side][i];
                if l.usable[i]
                    && current.is_finite()
                    && *volts > RAIL_MARGIN
                    && *volts < 5.0 - RAIL_MARGIN
                {
                    x[0].push(1.0);
                    x[1].push(current);
                    y.push(*volts);
                }
            }
        }
    }
    if y.len() >= 100 {
        let f = lsq::fit(&x, &y);
        estimates.extend(estimates_of(&CURRENT_SENSORS, &f, prior, max_relative_ci));
        regressions.push(regression(
            "current sensors: V = a + s i (driver's reading)",
            "V",
            &CURRENT_SENSORS,
            &f,
        ));
    } else {
        notes.push(
            "current sensors: no log has their volts (`testCurrentSenseVoltage`, `loadCurrentSenseVoltage`); not estimated"
                .into(),
        );
        estimates.extend(Estimate::none_identifiable(
            &CURRENT_SENSORS,
            prior,
            "the current sensors' volts are not logged",
        ));
    }

    estimates.extend(Estimate::none_identifiable(
        &ENCODER_ZEROS,
        prior,
        "the encoders are incremental (they count from their position at power-up) and the logs hold no absolute angle",
    ));
    (estimates, regressions, notes)
}
