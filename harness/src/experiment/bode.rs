//! The stepped-sine Bode sweep (bench-model.md section 5): a sinusoidal torque on one motor
//! (`GaitReference`'s `SteppedSine` torque channel: 10 N m, 0.05 Hz, x10^(1/30) every 20 s on
//! the bench), the velocities of both sides per torque, with their uncertainty, against the
//! two-mass transfer functions.
//!
//! **Transfer functions** (the plant's linear model, friction off; `s = j w`):
//! `a = I1 s^2 + c1 s + k`, `b = I2 s^2 + c2 s + k`, `D = a b - k^2`;
//! `H1 = omega1/T1 = s b / D`, `H2 = omega2/T1 = s k / D`, `H3 = omega1/T2 = s k / D`,
//! `H4 = omega2/T2 = s a / D` (k the coupling stiffness of the configuration: `springStiffness`,
//! or `directCouplingStiffness` in DA). `T1`, `T2` are the motors' output torques as measured
//! (`testOutputTorque` = `i_HD Km1 i1`, `loadOutputTorque`), so the current loop's lag is not
//! part of the measured ratio. Parameters are the bench FMU's (`actuationInertia`, ...).
//!
//! **Analysis.** For stage `n` (frequency `f0 r^n`, `[n D, (n+1) D)`), a sine of the stage's
//! frequency with an offset and a linear drift is fitted to the torque and to both velocities
//! over the last `max(1, floor(f D fit_fraction))` whole cycles of the stage (the whole stage
//! when it holds less than one cycle). Gain and phase are the ratio of the fitted sines; their
//! standard deviations come from the fits' residuals (least-squares covariance, first-order
//! propagation). The comparison holds for a linear bench: on the plant, run it with
//! `frictionModel` = 0 (Off); Coulomb friction makes the response amplitude dependent.

use std::path::Path;

use super::analysis::{Ratio, SineFit, sine_fit, wrap};
use super::{
    Bench, ExperimentError, RunEnd, Table, Written, column, figure, num, run, set_integers,
    set_reals, write_outputs,
};
use crate::results::plot::PlotLabels;

/// Which motor the sweep drives.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SweepInput {
    /// The test motor (H1, H2).
    Test,
    /// The load motor (H3, H4).
    Load,
}

/// Settings of the sweep.
#[derive(Debug, Clone, PartialEq)]
pub struct BodeConfig {
    /// Driven motor.
    pub input: SweepInput,
    /// Torque amplitude at the output [N m].
    pub amplitude: f64,
    /// First frequency \[Hz\].
    pub start_frequency: f64,
    /// Frequency ratio between stages.
    pub ratio: f64,
    /// Duration of a stage \[s\].
    pub dwell: f64,
    /// Number of stages.
    pub stages: u32,
    /// Fraction of each stage's cycles fitted (the last ones).
    pub fit_fraction: f64,
}

impl Default for BodeConfig {
    fn default() -> Self {
        BodeConfig {
            input: SweepInput::Test,
            amplitude: 10.0,
            start_frequency: 0.05,
            ratio: 10f64.powf(1.0 / 30.0),
            dwell: 20.0,
            // 0.05 Hz ... 10 Hz.
            stages: 70,
            fit_fraction: 0.5,
        }
    }
}

/// One frequency of the sweep.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BodePoint {
    /// Frequency \[Hz\].
    pub frequency: f64,
    /// Measured omega1 / T and omega2 / T.
    pub measured: [Ratio; 2],
    /// The model's (gain dB, phase rad) of the same two.
    pub model: [(f64, f64); 2],
    /// The torque fit (amplitude, residual).
    pub torque: SineFit,
}

/// The sweep's points.
#[derive(Debug, Clone, PartialEq)]
pub struct BodeResult {
    /// One per completed stage.
    pub points: Vec<BodePoint>,
    /// Names of the two transfer functions (`H1`, `H2` or `H3`, `H4`).
    pub names: [&'static str; 2],
    /// How the run ended.
    pub end: RunEnd,
    /// What was written.
    pub written: Written,
}

/// The two-mass model's velocity responses per torque at `w` [rad/s] for the bench's
/// parameters: [H1, H2, H3, H4] as complex (re, im).
pub fn two_mass(bench: &Bench, w: f64) -> Result<[(f64, f64); 4], ExperimentError> {
    let i1 = bench.real("actuationInertia")?;
    let i2 = bench.real("loadInertia")?;
    let c1 = bench.real("actuationDamping")?;
    let c2 = bench.real("loadDamping")?;
    let k = if bench.real("configuration")? == 0.0 {
        bench.real("directCouplingStiffness")?
    } else {
        bench.real("springStiffness")?
    };
    Ok(two_mass_response(i1, i2, c1, c2, k, w))
}

/// [H1, H2, H3, H4] of the two-mass model (module docs) at `w` [rad/s].
pub fn two_mass_response(i1: f64, i2: f64, c1: f64, c2: f64, k: f64, w: f64) -> [(f64, f64); 4] {
    let mul = |x: (f64, f64), y: (f64, f64)| (x.0 * y.0 - x.1 * y.1, x.0 * y.1 + x.1 * y.0);
    let div = |x: (f64, f64), y: (f64, f64)| {
        let d = y.0 * y.0 + y.1 * y.1;
        ((x.0 * y.0 + x.1 * y.1) / d, (x.1 * y.0 - x.0 * y.1) / d)
    };
    let s = (0.0, w);
    let a = (k - i1 * w * w, c1 * w);
    let b = (k - i2 * w * w, c2 * w);
    let ab = mul(a, b);
    let d = (ab.0 - k * k, ab.1);
    let h1 = div(mul(s, b), d);
    let h2 = div(mul(s, (k, 0.0)), d);
    let h4 = div(mul(s, a), d);
    [h1, h2, h2, h4]
}

/// The most stages of a sweep: 100, the [`MAX_RUN_ROWS`](super::MAX_RUN_ROWS) rows one run
/// records at the default 20 s dwell (20 000 rows a stage at the 1 ms step). More are of no
/// use at the default ratio 10^(1/30): from the default 0.05 Hz, stage 100 is at 100 Hz, ten
/// samples a period at the 1 ms step, about the fewest the sine fits can use. The sweep's
/// length (`dwell x stages`) is bounded by `MAX_RUN_ROWS` too.
pub const MAX_STAGES: u32 = 100;

/// Runs the sweep on `bench` and writes its files into `out`.
pub fn run_bode(
    bench: &Bench,
    config: &BodeConfig,
    out: &Path,
) -> Result<BodeResult, ExperimentError> {
    bench.check_armed()?;
    let ok = |v: f64| v.is_finite() && v > 0.0;
    if !(ok(config.amplitude)
        && ok(config.start_frequency)
        && config.ratio.is_finite()
        && config.ratio >= 1.0
        && ok(config.dwell)
        && (1..=MAX_STAGES).contains(&config.stages)
        && config.fit_fraction > 0.0
        && config.fit_fraction <= 1.0)
    {
        return Err(ExperimentError::Invalid(format!(
            "bode: amplitude, start frequency and dwell must be positive, the ratio >= 1, 1 to {MAX_STAGES} stages, fit fraction in (0, 1]"
        )));
    }
    // Before the bench is touched: dwell x stages, the run's length.
    super::check_length(
        &format!(
            "the sweep ({} stages of {} s)",
            config.stages,
            model_description::num::Num(config.dwell)
        ),
        config.dwell * f64::from(config.stages),
    )?;
    // Each stage's sine fit takes the last `fit_fraction` of its dwell: too short a dwell ran
    // the whole sweep and then failed its analysis.
    let fit_samples = (config.dwell * config.fit_fraction / super::STEP).floor();
    if fit_samples < super::analysis::SINE_FIT_MIN_SAMPLES as f64 {
        return Err(ExperimentError::Invalid(format!(
            "bode: a stage's fit window (the last {} of its {} s dwell) holds {fit_samples} \
             samples at the {} s step; the sine fit needs at least {}: lengthen --dwell",
            model_description::num::Num(config.fit_fraction),
            model_description::num::Num(config.dwell),
            model_description::num::Num(super::STEP),
            super::analysis::SINE_FIT_MIN_SAMPLES
        )));
    }
    let (per_amp, command, limit, names, torque_column) = match config.input {
        SweepInput::Test => (
            bench.test_torque_per_ampere()?,
            "plant.testCurrentCommand",
            bench.real("testCurrentLimit")?,
            ["H1", "H2"],
            "plant.testOutputTorque",
        ),
        SweepInput::Load => (
            bench.load_torque_per_ampere()?,
            "plant.loadCurrentCommand",
            bench.real("loadCurrentLimit")?,
            ["H3", "H4"],
            "plant.loadOutputTorque",
        ),
    };
    if config.amplitude / per_amp > limit {
        return Err(ExperimentError::Invalid(format!(
            "bode: {} N m needs {:.2} A, above the driver's {limit} A",
            config.amplitude,
            config.amplitude / per_amp
        )));
    }
    let mut system = bench.system()?;
    system.add_component("gait", bench.companion("GaitReference")?)?;
    set_integers(&mut system, "gait", &[("torqueWaveform", 7)])?;
    set_reals(
        &mut system,
        "gait",
        &[
            ("kneeTorqueAmplitude", config.amplitude),
            ("sweepStartFrequency", config.start_frequency),
            ("sweepFrequencyRatio", config.ratio),
            ("sweepDwellTime", config.dwell),
        ],
    )?;
    // A gain: the PID with zero gains passes feedForwardGain x feedForward.
    system.add_component("drive", bench.companion("PidController")?)?;
    set_reals(
        &mut system,
        "drive",
        &[
            ("kp", 0.0),
            ("ki", 0.0),
            ("kd", 0.0),
            ("feedForwardGain", 1.0 / per_amp),
            ("outputMin", -limit),
            ("outputMax", limit),
        ],
    )?;
    system.connect("gait.kneeTorqueReference", "drive.feedForward")?;
    system.connect("drive.u", command)?;
    let stop = config.dwell * f64::from(config.stages);
    let (output, end) = run(bench, &mut system, stop)?;
    let r = &output.results;
    let times = r.times();
    let torque = column(r, torque_column)?;
    let w1 = column(r, "plant.actuationVelocity")?;
    let w2 = column(r, "plant.loadVelocity")?;
    let last = times.last().copied().unwrap_or(0.0);
    let mut points = Vec::new();
    for n in 0..config.stages {
        let f = config.start_frequency * config.ratio.powi(n as i32);
        let (s0, s1) = (f64::from(n) * config.dwell, f64::from(n + 1) * config.dwell);
        if s1 > last + 1e-9 {
            break;
        }
        let cycles = (f * config.dwell * config.fit_fraction).floor().max(1.0);
        let a = (s1 - cycles / f).max(s0);
        let rows: Vec<usize> = (0..times.len())
            .filter(|&i| times[i] > a + 1e-9 && times[i] <= s1 + 1e-9)
            .collect();
        let pick = |v: &[f64]| rows.iter().map(|&i| v[i]).collect::<Vec<_>>();
        let t = pick(&times);
        let u = sine_fit(&t, &pick(&torque), f)?;
        let y1 = sine_fit(&t, &pick(&w1), f)?;
        let y2 = sine_fit(&t, &pick(&w2), f)?;
        let h = two_mass(bench, std::f64::consts::TAU * f)?;
        let (m1, m2) = match config.input {
            SweepInput::Test => (h[0], h[1]),
            SweepInput::Load => (h[2], h[3]),
        };
        let polar = |c: (f64, f64)| (20.0 * c.0.hypot(c.1).log10(), c.1.atan2(c.0));
        points.push(BodePoint {
            frequency: f,
            measured: [Ratio::of(&y1, &u), Ratio::of(&y2, &u)],
            model: [polar(m1), polar(m2)],
            torque: u,
        });
    }
    if points.is_empty() {
        return Err(ExperimentError::Run(format!(
            "bode: no stage completed ({end})"
        )));
    }
    let written = write_bode(bench, config, &points, names, &end, r, out)?;
    Ok(BodeResult {
        points,
        names,
        end,
        written,
    })
}

fn write_bode(
    bench: &Bench,
    config: &BodeConfig,
    points: &[BodePoint],
    names: [&str; 2],
    end: &RunEnd,
    run: &crate::Results,
    out: &Path,
) -> Result<Written, ExperimentError> {
    let mut columns = Vec::new();
    for h in names {
        for what in [
            "gain [dB]",
            "gain std [dB]",
            "model gain [dB]",
            "phase [deg]",
            "phase std [deg]",
            "model phase [deg]",
        ] {
            columns.push(format!("{h} {what}"));
        }
    }
    columns.push("frequency [Hz]".into());
    let rows = points
        .iter()
        .map(|p| {
            let mut row = Vec::new();
            for k in 0..2 {
                let m = &p.measured[k];
                row.extend([
                    m.gain_db(),
                    m.gain_db_std(),
                    p.model[k].0,
                    m.phase.to_degrees(),
                    m.phase_std.to_degrees(),
                    p.model[k].1.to_degrees(),
                ]);
            }
            row.push(p.frequency);
            (p.frequency.log10(), row)
        })
        .collect();
    let table = Table {
        x: "log10(frequency [Hz])".into(),
        names: columns.clone(),
        rows,
    };
    let gain_series = [
        columns[0].as_str(),
        columns[2].as_str(),
        columns[6].as_str(),
        columns[8].as_str(),
    ];
    let phase_series = [
        columns[3].as_str(),
        columns[5].as_str(),
        columns[9].as_str(),
        columns[11].as_str(),
    ];
    let phase_figures = figure(
        &table.to_results(),
        &phase_series,
        out,
        "bode-phase",
        &PlotLabels {
            x: "log10(frequency [Hz])".into(),
            y: "phase [deg]".into(),
            title: "Bode sweep: phase, measured and model".into(),
        },
    );
    let mut worst = (0.0f64, 0.0f64);
    for p in points {
        for k in 0..2 {
            worst.0 = worst.0.max((p.measured[k].gain_db() - p.model[k].0).abs());
            worst.1 = worst
                .1
                .max(wrap(p.measured[k].phase - p.model[k].1).to_degrees().abs());
        }
    }
    let mut body = format!(
        "Stepped-sine sweep on `{}`: {} N m on the {} motor, {} Hz x {:.5} every {} s, {} stages ({} completed). {} = omega1/T, {} = omega2/T [rad/(s N m)]; the model is the two-mass transfer function with the bench FMU's parameters (linear: friction not included). Largest difference to the model: {} dB, {} deg. Uncertainties are one standard deviation from the sine fits' residuals.\n\n![phase](bode-phase.png) (vector: [bode-phase.svg](bode-phase.svg))\n\n",
        bench.path().display(),
        config.amplitude,
        match config.input {
            SweepInput::Test => "test",
            SweepInput::Load => "load",
        },
        config.start_frequency,
        config.ratio,
        config.dwell,
        config.stages,
        points.len(),
        names[0],
        names[1],
        num(worst.0, 3),
        num(worst.1, 2),
    );
    if let RunEnd::Tripped { time, reason } = end {
        body.push_str(&format!(
            "**The run was ended at {time:.3} s: {reason}.**\n\n"
        ));
    }
    body.push_str(&format!(
        "| f [Hz] | {a} [dB] | model | {a} phase [deg] | model | {b} [dB] | model | {b} phase [deg] | model |\n|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n",
        a = names[0],
        b = names[1]
    ));
    for p in points {
        let cell = |k: usize| {
            let m = &p.measured[k];
            format!(
                "{} +- {} | {} | {} +- {} | {}",
                num(m.gain_db(), 2),
                num(m.gain_db_std(), 2),
                num(p.model[k].0, 2),
                num(m.phase.to_degrees(), 1),
                num(m.phase_std.to_degrees(), 1),
                num(p.model[k].1.to_degrees(), 1)
            )
        };
        body.push_str(&format!(
            "| {} | {} | {} |\n",
            num(p.frequency, 4),
            cell(0),
            cell(1)
        ));
    }
    let mut written = write_outputs(
        bench,
        out,
        "bode",
        "Stepped-sine Bode sweep",
        run,
        &table,
        &gain_series,
        &PlotLabels {
            x: "log10(frequency [Hz])".into(),
            y: "gain [dB rad/(s N m)]".into(),
            title: "Bode sweep: gain, measured and model".into(),
        },
        &body,
    )?;
    written.figures.extend(phase_figures?);
    Ok(written)
}
