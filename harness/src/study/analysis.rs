//! Per-cycle analysis of a study run: tracking errors, peak torques, energy terms.
//!
//! # Energy terms, as the bench defines them (bench facts, sections 9 and 10)
//! All per gait cycle, averaged over the analysed cycles, in J. Powers at the knee axis,
//! positive into the named element's port from its source.
//! - **test-motor mechanical** (eq. 71): the integral of `w1 x i_HD Km1 i1`, the actuation
//!   encoder's velocity times the test motor's torque at the harmonic drive's output, which is
//!   the torque the load cell (the test motor's reaction) measures. It is taken before the
//!   harmonic drive's losses, as the bench's balance `P_test + P_load + P_HD = dE/dt` needs.
//! - **bench electrical** (eq. 70): the test driver's draw from its 24 V supply, `V1 i1` (a
//!   loss-free PWM driver: supply power equals armature power, regeneration counted
//!   negative as the bidirectional current sensor would), plus the 7 W hardware offset and
//!   the clutch's 6 W while engaged. The load motor's 48 V supply is not in it.
//! - **harmonic-drive loss** `E_HD`: the actuation side's dissipation (viscous c1, friction or
//!   loss surface, clutch slip), <= 0.
//! - **load side**: the load motor's mechanical and electrical energy and the load side's own
//!   dissipation, reported separately.
//! - **E_k, E_p stored** (Table 13): the energy stored and released again within a cycle, the
//!   integral of the positive part of `dE/dt` (a net change over a periodic cycle is zero),
//!   reported next to the net change.
//! - **balance residual**: test + load + losses - dE_k - dE_p, which closes to rounding.

use super::StudyError;
use crate::results::Results;

/// Which columns of the results the analysis reads (the defaults are the names of the kneebench
/// scenarios: components `gait` and `plant`).
#[derive(Debug, Clone, PartialEq)]
pub struct Columns {
    /// Knee-angle reference.
    pub reference: String,
    /// Actuation-side angle (what the test motor's encoder sees).
    pub actuation_angle: String,
    /// Load-side angle (the knee joint of the bench).
    pub load_angle: String,
    /// Test-motor torque at the output.
    pub test_torque: String,
    /// The torque the shaft carries (the transducer's quantity).
    pub shaft_torque: String,
    /// Load-motor torque at the output.
    pub load_torque: String,
    /// Integral of the test motor's mechanical power.
    pub test_mechanical_energy: String,
    /// Integral of its positive part.
    pub test_mechanical_energy_consumed: String,
    /// Integral of the test driver's electrical power.
    pub test_electrical_energy: String,
    /// Integral of the hardware offset power.
    pub offset_energy: String,
    /// Integral of the clutch's electrical power.
    pub clutch_energy: String,
    /// Integral of the load motor's mechanical power.
    pub load_mechanical_energy: String,
    /// Integral of the load driver's electrical power.
    pub load_electrical_energy: String,
    /// Integral of the total electrical power (both drivers, offset, clutch).
    pub electrical_energy: String,
    /// Integral of the actuation side's losses (harmonic drive, friction, clutch), <= 0.
    pub actuation_loss_energy: String,
    /// Integral of the load side's losses, <= 0.
    pub load_loss_energy: String,
    /// E_k(t).
    pub kinetic_energy: String,
    /// E_p(t).
    pub potential_energy: String,
    /// Clutch engaged (0/1).
    pub clutch_engaged: String,
    /// The plant's trip code.
    pub trip_code: String,
}

impl Columns {
    /// Every column the analysis reads.
    pub fn names(&self) -> Vec<String> {
        [
            &self.reference,
            &self.actuation_angle,
            &self.load_angle,
            &self.test_torque,
            &self.shaft_torque,
            &self.load_torque,
            &self.test_mechanical_energy,
            &self.test_mechanical_energy_consumed,
            &self.test_electrical_energy,
            &self.offset_energy,
            &self.clutch_energy,
            &self.load_mechanical_energy,
            &self.load_electrical_energy,
            &self.electrical_energy,
            &self.actuation_loss_energy,
            &self.load_loss_energy,
            &self.kinetic_energy,
            &self.potential_energy,
            &self.clutch_engaged,
            &self.trip_code,
        ]
        .into_iter()
        .cloned()
        .collect()
    }
}

impl Default for Columns {
    fn default() -> Self {
        let p = |n: &str| format!("plant.{n}");
        Columns {
            reference: "gait.kneeAngleReference".into(),
            actuation_angle: p("actuationAngle"),
            load_angle: p("loadAngle"),
            test_torque: p("testOutputTorque"),
            shaft_torque: p("springTorque"),
            load_torque: p("loadOutputTorque"),
            test_mechanical_energy: p("testMechanicalEnergy"),
            test_mechanical_energy_consumed: p("testMechanicalEnergyConsumed"),
            test_electrical_energy: p("testElectricalEnergy"),
            offset_energy: p("offsetEnergy"),
            clutch_energy: p("clutchEnergy"),
            load_mechanical_energy: p("loadMechanicalEnergy"),
            load_electrical_energy: p("loadElectricalEnergy"),
            electrical_energy: p("totalElectricalEnergy"),
            actuation_loss_energy: p("actuationLossEnergy"),
            load_loss_energy: p("loadLossEnergy"),
            kinetic_energy: p("kineticEnergy"),
            potential_energy: p("potentialEnergy"),
            clutch_engaged: p("clutchEngaged"),
            trip_code: p("tripCode"),
        }
    }
}

/// Energy per gait cycle \[J\] by term (module docs: the bench's definitions).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EnergyTerms {
    /// Test motor's mechanical energy (eq. 71), signed.
    pub test_mechanical: f64,
    /// Its positive part.
    pub test_mechanical_consumed: f64,
    /// Test driver's draw from its supply, `V1 i1`, signed.
    pub test_electrical: f64,
    /// The bench's electrical energy (eq. 70): test supply + 7 W offset + clutch.
    pub bench_electrical: f64,
    /// The clutch's electrical energy.
    pub clutch: f64,
    /// Fraction of the cycle the clutch is engaged \[-\].
    pub clutch_engaged_fraction: f64,
    /// Harmonic-drive loss `E_HD`: the actuation side's dissipation (<= 0).
    pub drive_loss: f64,
    /// Load motor's mechanical energy, signed (positive: it drives the shaft).
    pub load_mechanical: f64,
    /// Load driver's electrical energy, signed (its own 48 V supply).
    pub load_electrical: f64,
    /// Load side's dissipation (<= 0).
    pub load_loss: f64,
    /// Both drivers, offset and clutch (the twin's former total), signed.
    pub all_electrical: f64,
    /// Net change of the kinetic energy.
    pub kinetic_change: f64,
    /// Net change of the spring's potential energy.
    pub potential_change: f64,
    /// Kinetic energy stored and released within the cycle: the integral of the positive part
    /// of dE_k/dt (Table 13's E_k).
    pub kinetic_stored: f64,
    /// The same for the spring's potential energy (Table 13's E_p).
    pub potential_stored: f64,
    /// test + load + losses - dE_k - dE_p: zero up to rounding when the terms close.
    pub balance_residual: f64,
}

/// What one actuator's run gives, per gait cycle where it says so.
#[derive(Debug, Clone, PartialEq)]
pub struct ActuatorReport {
    /// Actuator name.
    pub name: String,
    /// Complete cycles analysed: every complete cycle but the first, the start-up, which is
    /// never analysed (0 when an interlock ended the run before the second cycle completed:
    /// the metrics are then NaN).
    pub cycles: usize,
    /// RMS error of the actuation-side angle against the reference \[rad\].
    pub rms_error_actuation: f64,
    /// Maximum error of the actuation-side angle \[rad\].
    pub max_error_actuation: f64,
    /// RMS error of the load-side (knee) angle \[rad\].
    pub rms_error_knee: f64,
    /// Maximum error of the load-side angle \[rad\].
    pub max_error_knee: f64,
    /// Peak |test-motor output torque i_HD Km1 i1| \[N m\].
    pub peak_test_torque: f64,
    /// Peak |shaft torque| over the analysed cycles \[N m\] (what the test-motor torque
    /// interlock watches, over the whole run: the start-up, not analysed, can peak higher).
    pub peak_shaft_torque: f64,
    /// Peak |load-motor output torque| over the analysed cycles \[N m\].
    pub peak_load_torque: f64,
    /// Peak |shaft torque| over every recorded row, the start-up included (up to the trip in
    /// a run an interlock ended) \[N m\]: the margin to the test-motor torque interlock, which
    /// watches the whole run. NaN when the run recorded no row.
    pub whole_run_peak_shaft_torque: f64,
    /// Peak |load-motor output torque| over every recorded row, likewise \[N m\].
    pub whole_run_peak_load_torque: f64,
    /// Energy per cycle by term (NaN when no cycle completed).
    pub energy: EnergyTerms,
    /// The interlock that ended the run, if any, and when.
    pub trip: Option<(String, f64)>,
}

/// Energy stored and released within `values[i0..=i1]`: the sum of the positive increments,
/// i.e. the integral of the positive part of the rate, sampled at the rows.
pub fn stored_energy(values: &[f64], i0: usize, i1: usize) -> f64 {
    values[i0..=i1]
        .windows(2)
        .map(|w| (w[1] - w[0]).max(0.0))
        .sum()
}

/// Interlock names by trip code (the plant's `tripCode` output).
pub fn interlock_name(code: i64) -> &'static str {
    match code {
        1 => "spring deflection",
        2 => "test motor torque",
        3 => "load motor torque",
        4 => "test motor current",
        5 => "load motor current",
        6 => "regenerated power",
        7 => "emergency stop",
        // The hardware FMU's own trips (BenchHardware's `tripCode`).
        8 => "link watchdog",
        9 => "pacing overrun",
        10 => "sensor out of range",
        11 => "bench stopped itself",
        12 => "transducer disagrees with the spring deflection",
        13 => "load cell disagrees with the test-motor current",
        _ => "unknown interlock",
    }
}

impl ActuatorReport {
    /// The report of a run that ended before a cycle could be analysed, with what its rows
    /// still tell: its [`whole_run_peaks`] (the margin to the interlocks) beside
    /// [`Self::unanalysed`]'s NaN metrics.
    pub fn ended_early(
        name: &str,
        trip: Option<(String, f64)>,
        results: &Results,
        columns: &Columns,
    ) -> ActuatorReport {
        let (whole_run_peak_shaft_torque, whole_run_peak_load_torque) =
            whole_run_peaks(results, columns);
        ActuatorReport {
            whole_run_peak_shaft_torque,
            whole_run_peak_load_torque,
            ..ActuatorReport::unanalysed(name, trip)
        }
    }

    /// The report of a run with no cycle to analyse: no cycle, every metric NaN, `trip` as
    /// given.
    pub fn unanalysed(name: &str, trip: Option<(String, f64)>) -> ActuatorReport {
        let nan = f64::NAN;
        ActuatorReport {
            name: name.to_string(),
            cycles: 0,
            rms_error_actuation: nan,
            max_error_actuation: nan,
            rms_error_knee: nan,
            max_error_knee: nan,
            peak_test_torque: nan,
            peak_shaft_torque: nan,
            peak_load_torque: nan,
            whole_run_peak_shaft_torque: nan,
            whole_run_peak_load_torque: nan,
            energy: EnergyTerms {
                test_mechanical: nan,
                test_mechanical_consumed: nan,
                test_electrical: nan,
                bench_electrical: nan,
                clutch: nan,
                clutch_engaged_fraction: nan,
                drive_loss: nan,
                load_mechanical: nan,
                load_electrical: nan,
                load_loss: nan,
                all_electrical: nan,
                kinetic_change: nan,
                potential_change: nan,
                kinetic_stored: nan,
                potential_stored: nan,
                balance_residual: nan,
            },
            trip,
        }
    }
}

/// The sum of no terms, as `Iterator::sum` gives it for `f64` (the analysis's running sums start
/// from it, so that each equals the `sum` of its terms in the same order, bit for bit).
fn empty_sum() -> f64 {
    std::iter::empty::<f64>().sum()
}

/// The peak |shaft torque| and |load-motor output torque| over every row of `results`, the
/// start-up included (the margin to the interlocks, which watch the whole run); NaN for a run
/// that recorded no row or lacks the column (a missing column is named by [`analyse`]).
pub fn whole_run_peaks(results: &Results, columns: &Columns) -> (f64, f64) {
    let peak = |name: &str| match results.column_index(name) {
        Some(c) if !results.is_empty() => results.rows().fold(0.0f64, |m, r| m.max(r[c].abs())),
        _ => f64::NAN,
    };
    (peak(&columns.shaft_torque), peak(&columns.load_torque))
}

/// Analyses one run with gait period `period`: every complete cycle after the first, which is
/// the start-up (the gait's fade-in) and is never analysed. A run whose second cycle did not
/// complete has nothing to analyse: with a trip code in its results (an interlock) its report
/// is [`ActuatorReport::unanalysed`] naming the trip, with the [`whole_run_peaks`]; without one it is
/// [`StudyError::NoCycle`] (the run was too short: the caller knows whether it failed or was
/// ended by an interlock the results do not show). Cycles that hold no recorded row (a run
/// recorded more sparsely than once per cycle) are [`StudyError::NoRows`].
///
/// The rows are read in place, the analysed ones in one pass (each row's columns lie side by
/// side), every running sum and extreme taken over the same rows in the same order as the
/// definitions (a `sum`, a `fold`) would: the report is theirs bit for bit (the test
/// `one_pass_analysis_equals_the_definitions_bit_for_bit`).
pub fn analyse(
    name: &str,
    results: &Results,
    period: f64,
    columns: &Columns,
) -> Result<ActuatorReport, StudyError> {
    let col = |n: &str| {
        results
            .column_index(n)
            .ok_or_else(|| StudyError::MissingColumn(n.to_string()))
    };
    let end = results.last_time().unwrap_or(0.0);
    let complete = ((end + 1e-9) / period).floor() as usize;
    let trip_code = col(&columns.trip_code)?;
    let trip = results
        .rows()
        .find(|r| r[trip_code] != 0.0)
        .map(|r| (interlock_name(r[trip_code] as i64).to_string(), r[0]));
    // Cycle 0 is the start-up: the analysis needs cycle 1 complete.
    if complete < 2 {
        return match trip {
            Some(trip) => Ok(ActuatorReport::ended_early(
                name,
                Some(trip),
                results,
                columns,
            )),
            None => Err(StudyError::NoCycle { period, end }),
        };
    }
    let (whole_run_peak_shaft_torque, whole_run_peak_load_torque) =
        whole_run_peaks(results, columns);
    let first = 1;
    let (t0, t1) = (first as f64 * period, complete as f64 * period);
    let tol = 1e-9 * t1.max(1.0);
    let analysed = |t: f64| t >= t0 - tol && t <= t1 + tol;
    // The analysed rows: those whose time is in the window (all rows from the first to the
    // last of them when the times increase, as a run's do).
    let (mut i0, mut i1, mut count) = (None, 0, 0usize);
    for (i, r) in results.rows().enumerate() {
        if analysed(r[0]) {
            i0.get_or_insert(i);
            i1 = i;
            count += 1;
        }
    }
    let Some(i0) = i0 else {
        return Err(StudyError::NoRows {
            period,
            from: t0,
            to: t1,
        });
    };
    // Looked up in the order the report was first defined in (the first missing one named).
    let reference = col(&columns.reference)?;
    let actuation_angle = col(&columns.actuation_angle)?;
    let load_angle = col(&columns.load_angle)?;
    let test_mechanical_energy = col(&columns.test_mechanical_energy)?;
    let test_electrical_energy = col(&columns.test_electrical_energy)?;
    let clutch_energy = col(&columns.clutch_energy)?;
    let actuation_loss_energy = col(&columns.actuation_loss_energy)?;
    let load_mechanical_energy = col(&columns.load_mechanical_energy)?;
    let load_loss_energy = col(&columns.load_loss_energy)?;
    let kinetic = col(&columns.kinetic_energy)?;
    let potential = col(&columns.potential_energy)?;
    let engaged = col(&columns.clutch_engaged)?;
    let test_mechanical_energy_consumed = col(&columns.test_mechanical_energy_consumed)?;
    let offset_energy = col(&columns.offset_energy)?;
    let load_electrical_energy = col(&columns.load_electrical_energy)?;
    let electrical_energy = col(&columns.electrical_energy)?;
    let test_torque = col(&columns.test_torque)?;
    let shaft_torque = col(&columns.shaft_torque)?;
    let load_torque = col(&columns.load_torque)?;

    // One pass over rows i0..=i1. Over the analysed rows: the tracking errors' squares (summed)
    // and magnitudes (their maximum), the torques' peaks, the rows with the clutch engaged
    // (each row stands for the step that follows it, so the last analysed row, which closes
    // the window, is not counted); over every pair of consecutive rows: the energies' rises.
    let (mut square_a, mut square_k) = (empty_sum(), empty_sum());
    let (mut max_a, mut max_k) = (0.0f64, 0.0f64);
    let (mut peak_test, mut peak_shaft, mut peak_load) = (0.0f64, 0.0f64, 0.0f64);
    let mut engaged_rows = 0usize;
    let (mut kinetic_rise, mut potential_rise) = (empty_sum(), empty_sum());
    let mut previous: Option<&[f64]> = None;
    // Every index is within a row (`column_index` gives them so): said once here, so that the
    // compiler drops the check of each read below (a fifth of the pass's instructions).
    let width = results.names().len() + 1;
    let read = [
        reference,
        actuation_angle,
        load_angle,
        test_torque,
        shaft_torque,
        load_torque,
        engaged,
        kinetic,
        potential,
    ];
    if let Some(c) = read.iter().find(|&&c| c >= width) {
        return Err(StudyError::MissingColumn(format!(
            "#{c} (a row holds {width} values)"
        )));
    }
    for (i, r) in results.rows().enumerate().skip(i0).take(i1 - i0 + 1) {
        if analysed(r[0]) {
            let e = r[reference] - r[actuation_angle];
            square_a += e * e;
            max_a = max_a.max(e.abs());
            let e = r[reference] - r[load_angle];
            square_k += e * e;
            max_k = max_k.max(e.abs());
            peak_test = peak_test.max(r[test_torque].abs());
            peak_shaft = peak_shaft.max(r[shaft_torque].abs());
            peak_load = peak_load.max(r[load_torque].abs());
            if i != i1 && r[engaged] != 0.0 {
                engaged_rows += 1;
            }
        }
        if let Some(p) = previous {
            kinetic_rise += (r[kinetic] - p[kinetic]).max(0.0);
            potential_rise += (r[potential] - p[potential]).max(0.0);
        }
        previous = Some(r);
    }
    let rms = |square: f64| (square / count as f64).sqrt();
    let (row0, row1) = (results.row(i0), results.row(i1));
    let n = (complete - first) as f64;
    let per_cycle = |c: usize| (row1[c] - row0[c]) / n;
    let test_mechanical = per_cycle(test_mechanical_energy);
    let test_electrical = per_cycle(test_electrical_energy);
    let clutch = per_cycle(clutch_energy);
    let drive_loss = per_cycle(actuation_loss_energy);
    let load_mechanical = per_cycle(load_mechanical_energy);
    let load_loss = per_cycle(load_loss_energy);
    let kinetic_change = per_cycle(kinetic);
    let potential_change = per_cycle(potential);
    let energy = EnergyTerms {
        test_mechanical,
        test_mechanical_consumed: per_cycle(test_mechanical_energy_consumed),
        test_electrical,
        bench_electrical: test_electrical + per_cycle(offset_energy) + clutch,
        clutch,
        clutch_engaged_fraction: engaged_rows as f64 / (count - 1).max(1) as f64,
        drive_loss,
        load_mechanical,
        load_electrical: per_cycle(load_electrical_energy),
        load_loss,
        all_electrical: per_cycle(electrical_energy),
        kinetic_change,
        potential_change,
        kinetic_stored: kinetic_rise / n,
        potential_stored: potential_rise / n,
        balance_residual: test_mechanical + load_mechanical + drive_loss + load_loss
            - kinetic_change
            - potential_change,
    };
    Ok(ActuatorReport {
        name: name.to_string(),
        cycles: complete - first,
        rms_error_actuation: rms(square_a),
        max_error_actuation: max_a,
        rms_error_knee: rms(square_k),
        max_error_knee: max_k,
        peak_test_torque: peak_test,
        peak_shaft_torque: peak_shaft,
        peak_load_torque: peak_load,
        whole_run_peak_shaft_torque,
        whole_run_peak_load_torque,
        energy,
        trip,
    })
}

/// The comparison table in Markdown (also readable as plain text in a terminal).
pub fn markdown_table(reports: &[ActuatorReport]) -> String {
    let mut s = String::new();
    s.push_str("| | ");
    s.push_str(
        &reports
            .iter()
            .map(|r| r.name.clone())
            .collect::<Vec<_>>()
            .join(" | "),
    );
    s.push_str(" |\n|---|");
    s.push_str(&"---:|".repeat(reports.len()));
    s.push('\n');
    let deg = 180.0 / std::f64::consts::PI;
    let row = |s: &mut String, label: &str, f: &dyn Fn(&ActuatorReport) -> String| {
        s.push_str(&format!("| {label} |"));
        for r in reports {
            s.push_str(&format!(" {} |", f(r)));
        }
        s.push('\n');
    };
    row(&mut s, "cycles analysed", &|r| r.cycles.to_string());
    row(&mut s, "RMS tracking error, actuation side [deg]", &|r| {
        format!("{:.3}", r.rms_error_actuation * deg)
    });
    row(&mut s, "max tracking error, actuation side [deg]", &|r| {
        format!("{:.3}", r.max_error_actuation * deg)
    });
    row(&mut s, "RMS tracking error, knee (load side) [deg]", &|r| {
        format!("{:.3}", r.rms_error_knee * deg)
    });
    row(&mut s, "max tracking error, knee (load side) [deg]", &|r| {
        format!("{:.3}", r.max_error_knee * deg)
    });
    row(&mut s, "peak test-motor torque i_HD Km1 i1 [N m]", &|r| {
        format!("{:.2}", r.peak_test_torque)
    });
    row(
        &mut s,
        "peak shaft (transducer) torque, analysed cycles [N m]",
        &|r| format!("{:.2}", r.peak_shaft_torque),
    );
    row(
        &mut s,
        "peak shaft torque, whole run with the start-up [N m], interlock 20",
        &|r| format!("{:.2}", r.whole_run_peak_shaft_torque),
    );
    row(
        &mut s,
        "peak load-motor torque at the output, analysed cycles [N m]",
        &|r| format!("{:.2}", r.peak_load_torque),
    );
    row(
        &mut s,
        "peak load-motor torque, whole run with the start-up [N m], interlock 20",
        &|r| format!("{:.2}", r.whole_run_peak_load_torque),
    );
    let e = |s: &mut String, label: &str, f: &dyn Fn(&EnergyTerms) -> f64| {
        row(s, label, &|r| format!("{:.3}", f(&r.energy)));
    };
    e(&mut s, "test-motor mechanical energy per cycle [J]", &|e| {
        e.test_mechanical
    });
    e(&mut s, "... positive part (motoring) [J]", &|e| {
        e.test_mechanical_consumed
    });
    e(
        &mut s,
        "test-motor supply energy V1 i1 per cycle [J]",
        &|e| e.test_electrical,
    );
    e(
        &mut s,
        "bench electrical energy per cycle: test supply + 7 W offset + clutch [J]",
        &|e| e.bench_electrical,
    );
    e(&mut s, "... of which the clutch [J]", &|e| e.clutch);
    row(&mut s, "clutch engaged [% of the cycle]", &|r| {
        format!("{:.1}", 100.0 * r.energy.clutch_engaged_fraction)
    });
    e(&mut s, "harmonic-drive loss E_HD per cycle [J]", &|e| {
        e.drive_loss
    });
    e(&mut s, "load-motor mechanical energy per cycle [J]", &|e| {
        e.load_mechanical
    });
    e(&mut s, "load-side loss per cycle [J]", &|e| e.load_loss);
    e(
        &mut s,
        "load-motor electrical energy (48 V supply) per cycle [J]",
        &|e| e.load_electrical,
    );
    e(&mut s, "E_k stored and released per cycle [J]", &|e| {
        e.kinetic_stored
    });
    e(&mut s, "E_p stored and released per cycle [J]", &|e| {
        e.potential_stored
    });
    row(&mut s, "net dE_k / dE_p per cycle [J]", &|r| {
        format!(
            "{:.1e} / {:.1e}",
            r.energy.kinetic_change, r.energy.potential_change
        )
    });
    row(&mut s, "balance residual per cycle [J]", &|r| {
        format!("{:.1e}", r.energy.balance_residual)
    });
    row(&mut s, "interlock trip", &|r| match &r.trip {
        None => "none".into(),
        Some((name, t)) => format!("{name} at {t:.4} s"),
    });
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    /// On a sinusoidal motion theta = A sin(w t) with inertia I, E_k = I A^2 w^2 cos^2(w t) / 2
    /// rises from 0 to its peak twice per cycle: stored and released per cycle is I A^2 w^2,
    /// while the net change is zero. The same for a spring deflection with E_p.
    #[test]
    fn stored_energy_of_a_sinusoid_is_twice_the_peak() {
        let (inertia, amplitude, period) = (1.43, 60f64.to_radians(), 2.5);
        let w = std::f64::consts::TAU / period;
        let steps = 2500;
        let kinetic: Vec<f64> = (0..=steps)
            .map(|k| {
                let t = period * k as f64 / steps as f64;
                0.5 * inertia * (amplitude * w * (w * t).cos()).powi(2)
            })
            .collect();
        let expected = inertia * amplitude * amplitude * w * w;
        let stored = stored_energy(&kinetic, 0, steps);
        assert!(
            (stored - expected).abs() < 1e-9 * expected,
            "{stored} vs {expected}"
        );
        assert!((kinetic[steps] - kinetic[0]).abs() < 1e-12);
        // A phase that does not put the peaks on the samples: the sampled sum misses only
        // what lies between the samples around each turning point, O(h^2).
        let shifted: Vec<f64> = (0..=steps)
            .map(|k| {
                let t = period * (k as f64 + 0.37) / steps as f64;
                0.5 * inertia * (amplitude * w * (w * t).cos()).powi(2)
            })
            .collect();
        let stored = stored_energy(&shifted, 0, steps);
        assert!(
            (stored - expected).abs() < 1e-5 * expected,
            "{stored} vs {expected}"
        );
    }

    /// Synthetic results of `end` seconds at 10 ms with gait period 1 s: the reference is 0,
    /// the knee angle 1 rad off during the first cycle (the start-up) and 0.5 rad after it;
    /// the test motor's mechanical energy grows by 3 J per cycle after the start-up's 10 J;
    /// the trip code turns to `trip` (nonzero) from `trip_at` on.
    fn results(end: f64, trip: f64, trip_at: f64) -> Results {
        let columns = Columns::default();
        let names = columns.names();
        let kinds = vec![crate::results::ColumnKind::Real; names.len()];
        let mut r = Results::with_capacity(names.clone(), kinds, 0);
        let steps = (end / 0.01).round() as usize;
        for k in 0..=steps {
            let t = k as f64 * 0.01;
            let row: Vec<f64> = names
                .iter()
                .map(|n| {
                    let start_up = t < 1.0;
                    if *n == columns.load_angle || *n == columns.actuation_angle {
                        if start_up { 1.0 } else { 0.5 }
                    } else if *n == columns.test_mechanical_energy {
                        if start_up {
                            10.0 * t
                        } else {
                            10.0 + 3.0 * (t - 1.0)
                        }
                    } else if *n == columns.trip_code && t >= trip_at {
                        trip
                    } else if *n == columns.shaft_torque {
                        // The start-up peaks higher than the analysed cycles.
                        if start_up { -16.0 } else { 11.0 }
                    } else {
                        0.0
                    }
                })
                .collect();
            r.push_row(t, &row);
        }
        r
    }

    /// The first cycle, the start-up, is never analysed: with three complete cycles the
    /// errors and energies are those of the last two; with one (a run of `cycles = 1`, or a
    /// period longer than the run's) there is nothing to analyse, an error naming why (the
    /// start-up was analysed silently), unless an interlock ended the run (its report names it,
    /// every metric NaN).
    #[test]
    fn the_start_up_cycle_is_never_analysed() {
        let columns = Columns::default();
        let r = analyse("x", &results(3.0, 0.0, f64::INFINITY), 1.0, &columns).unwrap();
        // The peaks: the analysed cycles' and, for the interlocks' margin, the whole run's.
        assert_eq!(r.peak_shaft_torque, 11.0);
        assert_eq!(r.whole_run_peak_shaft_torque, 16.0);
        assert_eq!(r.cycles, 2);
        assert_eq!((r.rms_error_knee, r.max_error_knee), (0.5, 0.5));
        assert!(
            (r.energy.test_mechanical - 3.0).abs() < 1e-12,
            "{}",
            r.energy.test_mechanical
        );
        assert_eq!(r.trip, None);
        for end in [1.0, 1.5, 1.99] {
            match analyse("x", &results(end, 0.0, f64::INFINITY), 1.0, &columns) {
                Err(e @ StudyError::NoCycle { .. }) => assert!(
                    e.to_string().contains(&format!(
                        "the run ended at {end} s, before the end of its second gait cycle at 2 s"
                    )),
                    "{e}"
                ),
                other => panic!("{end}: {other:?}"),
            }
        }
        let r = analyse("x", &results(1.5, 2.0, 1.2), 1.0, &columns).unwrap();
        assert_eq!(r.cycles, 0);
        assert_eq!(r.trip, Some(("test motor torque".to_string(), 1.2)));
        assert!(r.rms_error_knee.is_nan() && r.energy.test_mechanical.is_nan());
        // The margin to the interlocks is the whole run's, even with nothing analysed.
        assert!(r.peak_shaft_torque.is_nan());
        assert_eq!(r.whole_run_peak_shaft_torque, 16.0);
        assert_eq!(r.whole_run_peak_load_torque, 0.0);
    }

    /// The analysis as first defined: every column copied out of the rows, the analysed rows
    /// listed, each metric a `sum` or a `fold` of its own (the reference of the one-pass
    /// [`analyse`]).
    fn analyse_by_definition(
        name: &str,
        results: &Results,
        period: f64,
        columns: &Columns,
    ) -> Result<ActuatorReport, StudyError> {
        let col = |n: &str| {
            results
                .column(n)
                .ok_or_else(|| StudyError::MissingColumn(n.to_string()))
        };
        let times = results.times();
        let end = times.last().copied().unwrap_or(0.0);
        let complete = ((end + 1e-9) / period).floor() as usize;
        let trip = col(&columns.trip_code)?
            .iter()
            .zip(&times)
            .find(|(c, _)| **c != 0.0)
            .map(|(c, t)| (interlock_name(*c as i64).to_string(), *t));
        // A missing column is NaN here and named by the analysis below, as in `analyse`.
        let whole_run_peak = |n: &str| match results.column(n) {
            Some(c) if !c.is_empty() => c.iter().fold(0.0f64, |m, v| m.max(v.abs())),
            _ => f64::NAN,
        };
        let whole_run_peak_shaft_torque = whole_run_peak(&columns.shaft_torque);
        let whole_run_peak_load_torque = whole_run_peak(&columns.load_torque);
        if complete < 2 {
            return match trip {
                Some(trip) => Ok(ActuatorReport {
                    whole_run_peak_shaft_torque,
                    whole_run_peak_load_torque,
                    ..ActuatorReport::unanalysed(name, Some(trip))
                }),
                None => Err(StudyError::NoCycle { period, end }),
            };
        }
        let first = 1;
        let (t0, t1) = (first as f64 * period, complete as f64 * period);
        let tol = 1e-9 * t1.max(1.0);
        let rows: Vec<usize> = (0..times.len())
            .filter(|&i| times[i] >= t0 - tol && times[i] <= t1 + tol)
            .collect();
        let (i0, i1) = (rows[0], rows[rows.len() - 1]);
        let reference = col(&columns.reference)?;
        let errors = |angle: &[f64]| {
            let e: Vec<f64> = rows.iter().map(|&i| reference[i] - angle[i]).collect();
            let rms = (e.iter().map(|x| x * x).sum::<f64>() / e.len() as f64).sqrt();
            (rms, e.iter().fold(0.0f64, |m, x| m.max(x.abs())))
        };
        let (rms_a, max_a) = errors(&col(&columns.actuation_angle)?);
        let (rms_k, max_k) = errors(&col(&columns.load_angle)?);
        let peak = |c: &[f64]| rows.iter().fold(0.0f64, |m, &i| m.max(c[i].abs()));
        let n = (complete - first) as f64;
        let per_cycle = |name: &str| -> Result<f64, StudyError> {
            let c = col(name)?;
            Ok((c[i1] - c[i0]) / n)
        };
        let test_mechanical = per_cycle(&columns.test_mechanical_energy)?;
        let test_electrical = per_cycle(&columns.test_electrical_energy)?;
        let clutch = per_cycle(&columns.clutch_energy)?;
        let drive_loss = per_cycle(&columns.actuation_loss_energy)?;
        let load_mechanical = per_cycle(&columns.load_mechanical_energy)?;
        let load_loss = per_cycle(&columns.load_loss_energy)?;
        let kinetic = col(&columns.kinetic_energy)?;
        let potential = col(&columns.potential_energy)?;
        let kinetic_change = (kinetic[i1] - kinetic[i0]) / n;
        let potential_change = (potential[i1] - potential[i0]) / n;
        let engaged = col(&columns.clutch_engaged)?;
        let engaged_rows = rows[..rows.len() - 1]
            .iter()
            .filter(|&&i| engaged[i] != 0.0)
            .count();
        let energy = EnergyTerms {
            test_mechanical,
            test_mechanical_consumed: per_cycle(&columns.test_mechanical_energy_consumed)?,
            test_electrical,
            bench_electrical: test_electrical + per_cycle(&columns.offset_energy)? + clutch,
            clutch,
            clutch_engaged_fraction: engaged_rows as f64 / (rows.len() - 1).max(1) as f64,
            drive_loss,
            load_mechanical,
            load_electrical: per_cycle(&columns.load_electrical_energy)?,
            load_loss,
            all_electrical: per_cycle(&columns.electrical_energy)?,
            kinetic_change,
            potential_change,
            kinetic_stored: stored_energy(&kinetic, i0, i1) / n,
            potential_stored: stored_energy(&potential, i0, i1) / n,
            balance_residual: test_mechanical + load_mechanical + drive_loss + load_loss
                - kinetic_change
                - potential_change,
        };
        Ok(ActuatorReport {
            name: name.to_string(),
            cycles: complete - first,
            rms_error_actuation: rms_a,
            max_error_actuation: max_a,
            rms_error_knee: rms_k,
            max_error_knee: max_k,
            peak_test_torque: peak(&col(&columns.test_torque)?),
            peak_shaft_torque: peak(&col(&columns.shaft_torque)?),
            peak_load_torque: peak(&col(&columns.load_torque)?),
            whole_run_peak_shaft_torque,
            whole_run_peak_load_torque,
            energy,
            trip,
        })
    }

    /// Every number of a report as bits (NaN compares by its bits: the sweep's columns, its
    /// cycles and trip time included), with the trip's name.
    fn bits(r: &ActuatorReport) -> (Vec<u64>, Option<String>) {
        (
            crate::sweep::runner::study_metric_values(r)
                .iter()
                .chain([
                    &r.whole_run_peak_shaft_torque,
                    &r.whole_run_peak_load_torque,
                ])
                .map(|v| v.to_bits())
                .collect(),
            r.trip.as_ref().map(|(n, _)| n.clone()),
        )
    }

    /// Rows of every analysed column with values that exercise each metric: signed zeros,
    /// flat stretches, the clutch switching, pseudo-random wiggles; `times` gives each row's
    /// time (a run's increase; these need not).
    fn wiggly(times: &[f64], nan_at: Option<usize>, trip_at: Option<usize>) -> Results {
        let names = Columns::default().names();
        let kinds = vec![crate::results::ColumnKind::Real; names.len()];
        let mut r = Results::with_capacity(names.clone(), kinds, times.len());
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        for (k, &t) in times.iter().enumerate() {
            let row: Vec<f64> = (0..names.len())
                .map(|j| {
                    state = state
                        .wrapping_mul(6_364_136_223_846_793_005)
                        .wrapping_add(1_442_695_040_888_963_407);
                    let noise = (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5;
                    let v = match names[j].as_str() {
                        "plant.tripCode" => match trip_at {
                            Some(at) if k >= at => 2.0,
                            _ => 0.0,
                        },
                        "plant.clutchEngaged" => f64::from(u8::from(noise > 0.1)),
                        // Flat stretches and signed zeros: rises of +-0.
                        "plant.potentialEnergy" if k % 7 < 3 => -0.0,
                        _ => (t * (j + 1) as f64).sin() * 3.0 + noise,
                    };
                    if nan_at == Some(k) && j == 2 {
                        f64::NAN
                    } else {
                        v
                    }
                })
                .collect();
            r.push_row(t, &row);
        }
        r
    }

    /// The one-pass analysis gives the definitions' report bit for bit (and their errors): on
    /// runs of several lengths and periods, with a trip, with a NaN, with times that do not
    /// increase, and with a column missing.
    #[test]
    fn one_pass_analysis_equals_the_definitions_bit_for_bit() {
        let columns = Columns::default();
        let grid = |end: f64, h: f64| -> Vec<f64> {
            (0..=(end / h).round() as usize)
                .map(|k| k as f64 * h)
                .collect()
        };
        let mut cases: Vec<(Results, f64)> = Vec::new();
        for (end, h, period) in [
            (5.0, 0.001, 2.5),
            (5.0, 0.001, 1.25),
            (7.3, 0.01, 2.5),
            (2.0, 0.5, 1.0),
            (3.0, 1.0, 1.0),
            (1.9, 0.01, 1.0),
        ] {
            cases.push((wiggly(&grid(end, h), None, None), period));
            cases.push((wiggly(&grid(end, h), Some(1200), Some(3000)), period));
            cases.push((wiggly(&grid(end, h), None, Some(1)), period));
        }
        // Times out of order: the analysed rows are not one run of rows.
        let mut shuffled = grid(4.0, 0.01);
        shuffled.swap(150, 20);
        shuffled.swap(300, 390);
        shuffled.swap(120, 250);
        cases.push((wiggly(&shuffled, None, None), 1.0));
        let mut checked = 0;
        for (results, period) in &cases {
            let one = analyse("x", results, *period, &columns);
            let defined = analyse_by_definition("x", results, *period, &columns);
            match (&one, &defined) {
                (Ok(a), Ok(b)) => {
                    assert_eq!(bits(a), bits(b), "period {period}");
                    checked += 1;
                }
                (Err(a), Err(b)) => assert_eq!(a.to_string(), b.to_string()),
                _ => panic!("{one:?} vs {defined:?}"),
            }
        }
        assert!(checked >= 15, "{checked}");
        // A missing column: the same one named.
        let mut fewer = columns.clone();
        fewer.offset_energy = "plant.nothing".into();
        fewer.potential_energy = "plant.nothingEither".into();
        let results = &cases[0].0;
        assert_eq!(
            analyse("x", results, 2.5, &fewer).unwrap_err().to_string(),
            analyse_by_definition("x", results, 2.5, &fewer)
                .unwrap_err()
                .to_string()
        );
        // The shaft torque (a whole-run peak's column too) missing along with an earlier
        // column: both name the earlier one.
        let mut fewer = columns.clone();
        fewer.reference = "plant.noReference".into();
        fewer.shaft_torque = "plant.noShaft".into();
        let one = analyse("x", results, 2.5, &fewer).unwrap_err().to_string();
        assert_eq!(
            one,
            analyse_by_definition("x", results, 2.5, &fewer)
                .unwrap_err()
                .to_string()
        );
        assert!(one.contains("plant.noReference"), "{one}");
    }

    /// Analysed cycles without a recorded row (a run recorded once every 1.5 periods) are an
    /// error naming them (was: a panic indexing the empty list of analysed rows).
    #[test]
    fn cycles_without_a_recorded_row_are_an_error() {
        let results = results(0.0, 0.0, f64::INFINITY);
        let mut sparse =
            Results::with_capacity(results.names().to_vec(), results.kinds().to_vec(), 3);
        let zeros = vec![0.0; results.names().len()];
        for t in [0.0, 0.75, 2.25] {
            sparse.push_row(t, &zeros);
        }
        let e = analyse("x", &sparse, 1.0, &Columns::default()).unwrap_err();
        assert!(
            matches!(e, StudyError::NoRows { .. })
                && e.to_string().contains("from 1 s to 2 s (period 1 s)"),
            "{e}"
        );
    }
}
