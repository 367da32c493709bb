//! Stage 2: output-error refinement by simulating the plant FMU over the logged currents.

use super::log::Log;
use super::{Estimate, IdentifyConfig, IdentifyError, Status, lm, lsq};
use crate::Fmu;
use crate::master::{Outcome, RunConfig, Signal, System, Value};
use crate::params::ParameterSet;
use crate::results::{ColumnKind, Results};

/// The parameters the refinement adjusts (when the linear stage identified them).
pub const REFINED: [&str; 9] = [
    "testMotorTorqueConstant",
    "loadMotorTorqueConstant",
    "actuationInertia",
    "actuationDamping",
    "actuationStaticFriction",
    "loadInertia",
    "loadDamping",
    "loadStaticFriction",
    "springStiffness",
];

/// Every residual row uses one sample in this many (the simulation is at the log's rate).
const STRIDE: usize = 5;

/// What the refinement did.
#[derive(Debug, Clone)]
pub struct Refinement {
    /// The parameters adjusted.
    pub parameters: Vec<&'static str>,
    /// Levenberg-Marquardt iterations.
    pub iterations: usize,
    /// Simulations run (each over every log's window).
    pub evaluations: usize,
    /// Seconds of log simulated per evaluation.
    pub simulated_seconds: f64,
    /// RMS of the normalised residuals at the linear estimates and after refinement.
    pub residual_rms: (f64, f64),
    /// Variance inflation applied (autocorrelation time of the residuals, rows).
    pub inflation: f64,
    /// Per log, what drove each motor in the simulation.
    pub drives: Vec<String>,
    /// Pairs of refined estimates correlated beyond 0.9.
    pub correlated: Vec<(&'static str, &'static str, f64)>,
    /// Measured and fitted signals over the first log's window: columns `measured w1`,
    /// `twin w1`, `measured w2`, `twin w2`, `measured tau`, `twin tau`, `residual tau`.
    pub fit: Results,
}

struct Window<'a> {
    log: &'a Log,
    rows: usize,
    scale: [f64; 3],
    /// The currents fed to the plant: the logged set value for the motor it drives, else the
    /// reading smoothed over [`IdentifyConfig::drive_window`]. (A reading's noise is the
    /// sensor's, not the drive's; fed to the open-loop simulation it drives the lightly damped
    /// load side into a random walk and biases the fit.)
    drive: [Vec<f64>; 2],
    /// Which sides are fed the logged set value.
    commanded: [bool; 2],
}

fn measured(l: &Log, i: usize, tau0: f64) -> [f64; 3] {
    [l.velocity[0][i], l.velocity[1][i], l.torque[i] - tau0]
}

const RECORDED: [&str; 3] = [
    "plant.actuationVelocity",
    "plant.loadVelocity",
    "plant.springTorque",
];

/// Simulates one log's window with `values` set on the plant; the recorded columns (or None
/// when the run ended early).
fn simulate(
    fmu: &Fmu,
    w: &Window<'_>,
    values: &[(String, Value)],
    text_values: &[(String, String)],
) -> Result<Option<[Vec<f64>; 3]>, IdentifyError> {
    let sim = |e: crate::MasterError| IdentifyError::Simulation(e.to_string());
    let mut s = System::new();
    s.add_component("plant", fmu.clone()).map_err(sim)?;
    for (n, v) in values {
        s.set_value(&format!("plant.{n}"), v.clone()).map_err(sim)?;
    }
    for (n, v) in text_values {
        s.set_value_str(&format!("plant.{n}"), v).map_err(sim)?;
    }
    let l = w.log;
    // The current at the end of a step is what the driver was set to over it (the current
    // loop settles in a fraction of the step): the set value over [t_k, t_k+1) is the logged
    // current at t_k+1.
    for (input, side) in [
        ("plant.testCurrentCommand", 0),
        ("plant.loadCurrentCommand", 1),
    ] {
        s.add_signal(
            input,
            Signal {
                times: l.time[..w.rows].iter().map(|t| t - l.dt).collect(),
                values: w.drive[side].clone(),
                interpolate: false,
            },
        )
        .map_err(sim)?;
    }
    s.record(&RECORDED).map_err(sim)?;
    let out = s
        .run(&RunConfig {
            start_time: l.time[0],
            stop_time: l.time[w.rows - 1],
            step_size: l.dt,
            ..RunConfig::default()
        })
        .map_err(sim)?;
    if !matches!(out.outcome, Outcome::Completed { .. }) || out.results.len() != w.rows {
        return Ok(None);
    }
    let col = |n: &str| out.results.column(n).expect("recorded");
    Ok(Some([col(RECORDED[0]), col(RECORDED[1]), col(RECORDED[2])]))
}

fn residuals(
    fmu: &Fmu,
    windows: &[Window<'_>],
    values: &[(String, Value)],
    text_values: &[(String, String)],
    tau0: f64,
) -> Result<Vec<f64>, IdentifyError> {
    let mut r = Vec::new();
    for w in windows {
        let sim = simulate(fmu, w, values, text_values)?;
        // Channel by channel, so that the residuals' autocorrelation is that of each signal.
        for k in 0..3 {
            for i in (0..w.rows).step_by(STRIDE) {
                if !w.log.usable[i] {
                    continue;
                }
                let m = measured(w.log, i, tau0);
                let twin = sim.as_ref().map_or(f64::NAN, |s| s[k][i]);
                // A run that ended early (an interlock) scores as far off.
                let d = if twin.is_finite() {
                    (twin - m[k]) / w.scale[k]
                } else {
                    1e3
                };
                r.push(d);
            }
        }
    }
    Ok(r)
}

/// Refines the mechanical estimates by output error; updates `estimates` in place.
pub(super) fn refine(
    fmu: &Fmu,
    logs: &[Log],
    estimates: &mut [Estimate],
    prior: &ParameterSet,
    tau0: f64,
    config: &IdentifyConfig,
) -> Result<Refinement, IdentifyError> {
    // Fixed values: the prior, with every identified linear estimate over it.
    let mut fixed: Vec<(String, Value)> = prior
        .assignments()
        .into_iter()
        .filter(|(n, _)| config.plant_parameter(n).is_none())
        .collect();
    let mut set_fixed = |name: &str, v: f64| match fixed.iter_mut().find(|(n, _)| n == name) {
        Some(slot) => slot.1 = Value::Real(v),
        None => fixed.push((name.to_string(), Value::Real(v))),
    };
    let mut free: Vec<(usize, &'static str)> = Vec::new();
    for (k, e) in estimates.iter().enumerate() {
        // Conditional estimates (the loss surface's coefficients fitted with others held)
        // enter the simulated plant as they enter the written set, but are not refined.
        let (Some(p), true) = (e.quantity.parameter, e.status.is_written()) else {
            continue;
        };
        set_fixed(p, e.linear);
        if let Some(&name) = REFINED.iter().find(|n| **n == p)
            && e.status == Status::Identified
            && e.linear > 0.0
        {
            free.push((k, name));
        }
    }
    let windows: Vec<Window<'_>> = logs
        .iter()
        .map(|l| {
            let rows = ((config.refine_seconds / l.dt).round() as usize + 1).min(l.time.len());
            let mut scale = [0.0f64; 3];
            let mut count = 0usize;
            for i in 0..rows {
                if l.usable[i] {
                    let m = measured(l, i, tau0);
                    for k in 0..3 {
                        scale[k] += m[k] * m[k];
                    }
                    count += 1;
                }
            }
            let scale = scale.map(|s| (s / count.max(1) as f64).sqrt().max(1e-6));
            let rms = |v: &[f64]| (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt();
            // The set value drives the side whose reading follows it (within 10 % RMS).
            let commanded = [0, 1].map(|side| {
                l.command.as_ref().is_some_and(|c| {
                    let diff: Vec<f64> = (0..rows).map(|i| l.current[side][i] - c[i]).collect();
                    let level = rms(&l.current[side][..rows]);
                    level > 0.0 && rms(&diff) <= 0.1 * level
                })
            });
            let drive = [0, 1].map(|side| {
                if commanded[side] {
                    let c = l.command.as_ref().expect("commanded");
                    // The set value applied over a step is the one logged at its end: the
                    // experiments run Gauss-Seidel with the driving controller upstream of
                    // the plant, so the plant's input over [t_k, t_k+1) is the controller's
                    // output after its step to t_k+1.
                    return c[..rows].to_vec();
                }
                let [smooth, _, _] =
                    super::smooth::derivatives(&l.current[side][..rows], l.dt, config.drive_window);
                smooth
                    .iter()
                    .zip(&l.current[side])
                    .map(|(s, raw)| if s.is_finite() { *s } else { *raw })
                    .collect()
            });
            Window {
                log: l,
                rows,
                scale,
                drive,
                commanded,
            }
        })
        .filter(|w| w.rows > 2 * STRIDE)
        .collect();
    let simulated_seconds = windows.iter().map(|w| w.rows as f64 * w.log.dt).sum();
    let text = config.plant_parameters.clone();
    let with = |p: &[f64]| -> Vec<(String, Value)> {
        let mut v = fixed.clone();
        for ((_, name), x) in free.iter().zip(p) {
            if let Some(slot) = v.iter_mut().find(|(n, _)| n == name) {
                slot.1 = Value::Real(*x);
            }
        }
        v
    };
    let p0: Vec<f64> = free.iter().map(|(k, _)| estimates[*k].linear).collect();
    let before = residuals(fmu, &windows, &with(&p0), &text, tau0)?;
    let rms = |r: &[f64]| (r.iter().map(|x| x * x).sum::<f64>() / r.len().max(1) as f64).sqrt();
    // Bounds: a factor of 3 around the linear estimate, inside the FMU's admissible values.
    let lower: Vec<f64> = p0.iter().map(|v| (v / 3.0).max(1e-6)).collect();
    let upper: Vec<f64> = p0.iter().map(|v| v * 3.0).collect();
    let result = lm::solve(
        |p| residuals(fmu, &windows, &with(p), &text, tau0),
        &p0,
        &lower,
        &upper,
        &lm::LmOptions {
            max_iterations: 12,
            tolerance: 1e-4,
            difference_step: 1e-4,
        },
    )?;
    let stats = lsq::statistics(&result.jacobian, &result.residuals);
    let mut correlated = Vec::new();
    for (a, (ka, _)) in free.iter().enumerate() {
        let e = &mut estimates[*ka];
        let ci = 1.96 * stats.std[a];
        let v = result.params[a];
        e.refined = Some((v, ci));
        if !stats.determined[a] || ci.is_nan() || ci > config.max_relative_ci * v.abs() {
            e.status = Status::NotIdentifiable(format!(
                "the refinement does not determine it (95 % interval +-{})",
                super::fmt(ci)
            ));
        }
        for (b, (kb, _)) in free.iter().enumerate().skip(a + 1) {
            let c = stats.correlation[a][b];
            if c.abs() > 0.9 {
                correlated.push((
                    estimates[*ka].quantity.label,
                    estimates[*kb].quantity.label,
                    c,
                ));
            }
        }
    }
    // The figure's data: the first window at the refined values.
    let values = with(&result.params);
    let fit = match windows.first() {
        Some(w) => {
            let sim = simulate(fmu, w, &values, &text)?;
            let names = [
                "measured w1",
                "twin w1",
                "measured w2",
                "twin w2",
                "measured tau",
                "twin tau",
                "residual tau",
            ];
            let mut r = Results::with_capacity(
                names.iter().map(|s| s.to_string()).collect(),
                vec![ColumnKind::Real; names.len()],
                w.rows,
            );
            for i in 0..w.rows {
                let m = measured(w.log, i, tau0);
                let t = sim
                    .as_ref()
                    .map_or([f64::NAN; 3], |s| [s[0][i], s[1][i], s[2][i]]);
                r.push_row(
                    w.log.time[i],
                    &[m[0], t[0], m[1], t[1], m[2], t[2], m[2] - t[2]],
                );
            }
            r
        }
        None => Results::with_capacity(Vec::new(), Vec::new(), 0),
    };
    let drives = windows
        .iter()
        .map(|w| {
            let what = |side: usize| {
                if w.commanded[side] {
                    format!("the logged set value {}", super::log::COMMAND)
                } else {
                    format!(
                        "its current reading smoothed over {} samples",
                        2 * config.drive_window + 1
                    )
                }
            };
            format!(
                "{}: test motor {}, load motor {}",
                w.log.path.display(),
                what(0),
                what(1)
            )
        })
        .collect();
    Ok(Refinement {
        drives,
        parameters: free.iter().map(|(_, n)| *n).collect(),
        iterations: result.iterations,
        evaluations: result.evaluations + 1,
        simulated_seconds,
        residual_rms: (rms(&before), rms(&result.residuals)),
        inflation: stats.inflation,
        correlated,
        fit,
    })
}
