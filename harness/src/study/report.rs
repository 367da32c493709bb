//! The study's figures and report: `report.md` with every figure embedded (PNG, with the SVG
//! linked), relative paths, angles in degrees, the interlock limits on the torque figure, units
//! and sign conventions, the measured-vs-twin table and each scenario's parameter set.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use super::{StudyError, StudyRun, StudyScenario, compare, comparison_markdown, markdown_table};
use crate::results::Results;
use crate::results::plot::PlotLabels;

/// The bench's torque interlock on either motor [N m] (bench facts, section 7).
pub const TORQUE_INTERLOCK: f64 = 20.0;

/// One curve of a cycle figure: legend, run, column and the factor applied to its values.
pub struct CycleSeries<'a> {
    /// Legend.
    pub legend: String,
    /// The run's results.
    pub results: &'a Results,
    /// The column; `None` draws the constant [`Self::scale`] (a limit line).
    pub column: Option<String>,
    /// Multiplies the column's values (unit conversion), or the constant's value.
    pub scale: f64,
}

/// Plots `series` over the last complete gait cycle of each run, percent of cycle on the x
/// axis, into `out` (`.svg` or `.png`).
pub fn plot_cycle(
    series: &[CycleSeries<'_>],
    period: f64,
    out: &Path,
    labels: &PlotLabels,
) -> Result<(), StudyError> {
    let mut columns: Vec<(String, Vec<f64>)> = Vec::new();
    let mut percent: Vec<f64> = Vec::new();
    for s in series {
        let times = s.results.times();
        let end = times.last().copied().unwrap_or(0.0);
        let cycles = ((end + 1e-9) / period).floor();
        if cycles < 1.0 {
            continue;
        }
        let t0 = (cycles - 1.0) * period;
        let tol = 1e-9 * end.max(1.0);
        let rows: Vec<usize> = (0..times.len())
            .filter(|&i| times[i] >= t0 - tol && times[i] <= t0 + period + tol)
            .collect();
        let values = match &s.column {
            Some(column) => {
                let values = s
                    .results
                    .column(column)
                    .ok_or_else(|| StudyError::MissingColumn(column.to_string()))?;
                rows.iter().map(|&i| s.scale * values[i]).collect()
            }
            None => vec![s.scale; rows.len()],
        };
        if percent.is_empty() {
            percent = rows
                .iter()
                .map(|&i| 100.0 * (times[i] - t0) / period)
                .collect();
        }
        columns.push((s.legend.clone(), values));
    }
    let n = columns
        .iter()
        .map(|(_, v)| v.len())
        .min()
        .unwrap_or(0)
        .min(percent.len());
    let mut table = Results::with_capacity(
        columns.iter().map(|(l, _)| l.clone()).collect(),
        vec![crate::results::ColumnKind::Real; columns.len()],
        n,
    );
    for k in 0..n {
        let row: Vec<f64> = columns.iter().map(|(_, v)| v[k]).collect();
        table.push_row(percent[k], &row);
    }
    let names: Vec<&str> = columns.iter().map(|(l, _)| l.as_str()).collect();
    crate::results::plot::plot_signals_with(&table, &names, out, (1024, 560), labels)?;
    Ok(())
}

/// A figure written twice: `<stem>.png` (embedded in the report) and `<stem>.svg`.
#[derive(Debug, Clone, PartialEq)]
pub struct Figure {
    /// Title (also the image's alternative text).
    pub title: String,
    /// The PNG file.
    pub png: PathBuf,
    /// The SVG file.
    pub svg: PathBuf,
}

/// Draws one scenario's figures over the last gait cycle of each run: knee angle against each
/// actuator's own reference (deg), the shaft and load-motor torques with the interlock limits,
/// and the test motor's mechanical and the bench's electrical power.
pub fn plot_study(runs: &[StudyRun], out_dir: &Path) -> Result<Vec<Figure>, StudyError> {
    // A failed run is not drawn (see [`StudyRun::failure`]).
    let complete: Vec<&StudyRun> = runs
        .iter()
        .filter(|r| r.report.cycles > 0 && r.failure().is_none())
        .collect();
    let Some(first) = complete.first() else {
        return Ok(Vec::new());
    };
    let period = first.gait.period;
    let prefix = first.study.name();
    let deg = 180.0 / std::f64::consts::PI;
    fn column<'a>(legend: String, r: &'a StudyRun, column: &str, scale: f64) -> CycleSeries<'a> {
        CycleSeries {
            legend,
            results: &r.results,
            column: Some(column.to_string()),
            scale,
        }
    }
    let mut figures = Vec::new();
    let mut figure = |name: &str, title: &str, y: &str, series: Vec<CycleSeries<'_>>| {
        let labels = PlotLabels {
            x: "gait cycle [%]".into(),
            y: y.into(),
            title: title.into(),
        };
        let png = out_dir.join(format!("{prefix}-{name}.png"));
        let svg = out_dir.join(format!("{prefix}-{name}.svg"));
        plot_cycle(&series, period, &png, &labels)?;
        plot_cycle(&series, period, &svg, &labels)?;
        figures.push(Figure {
            title: title.to_string(),
            png,
            svg,
        });
        Ok::<(), StudyError>(())
    };
    let mut tracking = Vec::new();
    for r in &complete {
        let a = r.report.name.as_str();
        tracking.push(column(
            format!("{a} reference"),
            r,
            "gait.kneeAngleReference",
            deg,
        ));
        tracking.push(column(
            format!("{a} knee (load side)"),
            r,
            "plant.loadAngle",
            deg,
        ));
    }
    figure(
        "tracking",
        "Knee angle over one gait cycle",
        "knee angle [deg], as the gait series",
        tracking,
    )?;
    let mut torques = Vec::new();
    for r in &complete {
        let a = r.report.name.as_str();
        torques.push(column(
            format!("{a} shaft (transducer)"),
            r,
            "plant.springTorque",
            1.0,
        ));
        torques.push(column(
            format!("{a} load motor"),
            r,
            "plant.loadOutputTorque",
            1.0,
        ));
    }
    for limit in [TORQUE_INTERLOCK, -TORQUE_INTERLOCK] {
        torques.push(CycleSeries {
            legend: format!("interlock {limit:+} N m"),
            results: &first.results,
            column: None,
            scale: limit,
        });
    }
    figure(
        "torques",
        "Shaft and load-motor torques over one gait cycle",
        "torque at the knee axis [N m], extension positive",
        torques,
    )?;
    let mut powers = Vec::new();
    for r in &complete {
        let a = r.report.name.as_str();
        powers.push(column(
            format!("{a} test motor, mechanical"),
            r,
            "plant.testMechanicalPower",
            1.0,
        ));
        powers.push(column(
            format!("{a} test driver, electrical V1 i1"),
            r,
            "plant.testElectricalPower",
            1.0,
        ));
    }
    figure(
        "powers",
        "Test-motor powers over one gait cycle",
        "power [W], positive = drawn by the motor",
        powers,
    )?;
    Ok(figures)
}

/// The comparison table of `runs` ([`markdown_table`]) followed by one line per failed run
/// ([`StudyRun::failure`]) saying why it failed: a failed run has no column of the table (its
/// values would be NaN, and its failure no interlock trip). Without a run that did not fail,
/// only those lines.
pub fn runs_markdown(runs: &[StudyRun]) -> String {
    let mut s = String::new();
    let analysed: Vec<_> = runs
        .iter()
        .filter(|r| r.failure().is_none())
        .map(|r| r.report.clone())
        .collect();
    if !analysed.is_empty() {
        s.push_str(&markdown_table(&analysed));
    }
    for r in runs {
        if let Some((why, at)) = r.failure() {
            if !s.is_empty() {
                s.push('\n');
            }
            let _ = writeln!(
                s,
                "**{}: the run failed** at t = {} s (not analysed; not an interlock trip): {why}",
                r.report.name,
                model_description::num::Num(at)
            );
        }
    }
    s
}

/// `path` relative to `base` when it lies inside it (report links), else as it is.
fn relative<'a>(path: &'a Path, base: &Path) -> &'a Path {
    path.strip_prefix(base).unwrap_or(path)
}

/// One scenario's runs and figures, for the report.
pub struct ScenarioSection<'a> {
    /// The scenario.
    pub scenario: StudyScenario,
    /// Its runs.
    pub runs: &'a [StudyRun],
    /// Its figures.
    pub figures: &'a [Figure],
}

/// Writes `report.md` into `out_dir`; every path in it is relative to `out_dir`.
pub fn write_report(
    out_dir: &Path,
    sections: &[ScenarioSection<'_>],
    command: &str,
) -> Result<PathBuf, StudyError> {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "# Actuator study: DA, SEA and CSEA on the bench's gait\n"
    );
    let _ = writeln!(s, "Reproduce with `{command}`.\n");
    s.push_str(CONVENTIONS);
    // Failed runs have no results to compare (see [`StudyRun::failure`]).
    let all: Vec<&StudyRun> = sections
        .iter()
        .flat_map(|x| x.runs.iter())
        .filter(|r| r.failure().is_none())
        .collect();
    for section in sections {
        let Some(first) = section.runs.first() else {
            continue;
        };
        let g = first.gait;
        let _ = writeln!(
            s,
            "## Scenario `{}`\n\nGait: period {} s, knee-angle amplitude {:.1} deg, peak external (ground-reaction) torque {:.2} N m; 1 ms steps, Gauss-Seidel; the first cycle is the start-up and is not analysed.\n",
            section.scenario.name(),
            g.period,
            g.angle_amplitude.to_degrees(),
            g.torque_amplitude,
        );
        s.push_str(&runs_markdown(section.runs));
        s.push('\n');
        for f in section.figures {
            let _ = writeln!(
                s,
                "![{}]({})\n\n[SVG]({})\n",
                f.title,
                relative(&f.png, out_dir).display(),
                relative(&f.svg, out_dir).display()
            );
        }
        let _ = writeln!(s, "Runs (scenario, results, parameter set SHA-256):\n");
        for r in section.runs {
            let _ = writeln!(
                s,
                "- {}{}: [{}]({}), [{}]({}), `{}`",
                r.report.name,
                if r.failure().is_some() {
                    " (run failed)"
                } else {
                    ""
                },
                relative(&r.scenario, out_dir).display(),
                relative(&r.scenario, out_dir).display(),
                relative(&r.csv, out_dir).display(),
                relative(&r.csv, out_dir).display(),
                r.parameters_hash
            );
            if let Some(set) = &r.plant_set {
                let _ = writeln!(s, "  - plant parameter set: {set}");
            }
            let differences = super::tuning_differences(r.actuator, &r.parameters);
            if !differences.is_empty() {
                let list = differences
                    .iter()
                    .map(|(name, assumed, value)| {
                        format!("`plant.{name}` {value} (tuned for {assumed})")
                    })
                    .collect::<Vec<_>>()
                    .join(", ");
                let _ = writeln!(
                    s,
                    "  - **this plant differs from the one the study's controller weights were derived for, in {list}.** Unless the controllers' model-based weights (feed-forward and setpoint weights, output limits) were set for this plant with `--param`, its tracking and energy are those of the study's controllers on this plant, not of controllers tuned for it"
                );
            }
            if !r.unapplied.is_empty() {
                let _ = writeln!(
                    s,
                    "  - not applied on the bench (the twin's own parameters, no variables of BenchHardware): {}",
                    r.unapplied.join(", ")
                );
            }
            if let Some(p) = &r.pacing {
                let _ = writeln!(s, "  - pacing on the bench: {p}");
                if let Some(w) = p.schedule_warning() {
                    let _ = writeln!(s, "  - **warning: {w}**");
                }
            }
        }
        s.push('\n');
        let _ = writeln!(
            s,
            "<details><summary>Parameters of {} (the SSPs' bindings; unlisted: the FMUs' defaults)</summary>\n\n```text",
            section.scenario.name()
        );
        for r in section.runs {
            let _ = writeln!(s, "# {}", r.report.name);
            for line in &r.parameters {
                let _ = writeln!(s, "{line}");
            }
        }
        let _ = writeln!(s, "```\n\n</details>\n");
    }
    let rows = compare(&all);
    let _ = writeln!(
        s,
        "## The twin against the bench\n\nEach value the bench published (bench facts, section 10) next to the twin's value for the same experiment, from the runs above. Nothing is fitted to these tables.\n"
    );
    s.push_str(&comparison_markdown(&rows));
    s.push('\n');
    s.push_str(RESIDUALS);
    let path = out_dir.join("report.md");
    std::fs::write(&path, s).map_err(|e| StudyError::Fmu {
        path: path.clone(),
        message: e.to_string(),
    })?;
    Ok(path)
}

const CONVENTIONS: &str = "\
## Units and sign conventions

- Angles in degrees in this report (rad in the CSV files), torques in N m at the knee axis,
  energies in J per 2.5 s gait cycle, averaged over the analysed cycles.
- Torques: positive = knee extension (bench facts). Angles follow the bench's gait series as
  published: its peak (60 deg at 71.5 % of the cycle) is the swing's flexion. The gait's knee
  torque is the actuator's (internal) torque; the load motor applies the ground reaction, its
  inverse, whose peak is the scenario's external torque (9 N m).
- Powers are positive into the named element from its source: the test motor's mechanical
  energy is positive while it drives the shaft, negative while it brakes; losses are negative
  (energy leaving the mechanics). `P_test + P_load + P_HD + P_load-side loss = dE_k/dt +
  dE_p/dt`; the table's balance residual checks it per cycle.
- Test-motor mechanical energy (eq. 71): actuation velocity times the test motor's torque at the
  harmonic drive's output, `i_HD Km1 i1` (what the load cell, the motor's reaction, measures),
  before the drive's losses. Bench electrical energy (eq. 70): the test driver's draw from its
  24 V supply (`V1 i1`, a loss-free driver), plus the 7 W hardware offset and the clutch's 6 W
  while engaged; the load motor's 48 V supply is reported separately.
- E_k and E_p stored: the energy stored and released again within a cycle (the integral of the
  positive part of dE/dt); their net change over a periodic cycle is zero and is shown beside.
- Interlocks (section 7): the test-motor torque interlock watches the shaft torque past the
  harmonic drive (the transducer's quantity), the load-motor one its output torque, both at
  20 N m (drawn on the torque figure); spring deflection 5 deg; load-driver regeneration 5 W.

";

const RESIDUALS: &str = "\
What the ratios say (the plant's documentation page, section \"Fidelity against the bench\",
argues each point):
- The harmonic-drive loss is the twin's actuation-side friction (c1 = 12 N m s/rad, Tfr1 = 5 N m,
  identified on the bench's gait) and agrees. The published steady-state loss surface
  (`data/hd-loss-surface.csv`) integrated over the same gait gives only about -18 J, so Table 13's
  E_HD cannot come from the surface alone.
- The test motor's mechanical energy is short because the load side gives energy back: over a
  gait cycle the knee absorbs energy, so the ground reaction does net positive work on the shaft.
  The bench's balance (64.76 J in, 51.57 J lost in the drive) would need the load side to absorb
  about 13 J, which the specified ground reaction cannot. Reversed, the ground reaction would
  bring the test motor's energy to 0.83-0.92 of Table 14 but make the load driver brake 6-14 W
  against its 5 W limit on the 60 deg gait the bench ran: the sign is left as the facts' frames
  give it, with the evidence on the plant's page.
- The electrical energy is short by more than the mechanical: the twin's test motor converts
  with copper losses only (R1 = 0.608 Ohm) through a loss-free driver.
- E_k stored with the identified inertias (I1 + I2 = 1.43 kg m^2) is 7.3-7.8 J per cycle (the
  table above); Table 13's 40 J would need about 5 times that inertia.
";
