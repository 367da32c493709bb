//! The identification's outputs: the parameter set, the Markdown report and the
//! measured-vs-fitted figure.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use super::{Identification, IdentifyError, Status, fmt};
use crate::results::plot::{PlotLabels, plot_signals_with};

fn io(path: &Path, e: impl std::fmt::Display) -> IdentifyError {
    IdentifyError::Write {
        path: path.to_path_buf(),
        message: e.to_string(),
    }
}

/// Writes `<out>/<set name>.ssv`, `<out>/identify.md`, and when refined
/// `<out>/identify-fit.csv` with its figure (`.svg`, `.png`). Returns the files written.
pub fn write_outputs(id: &Identification, out: &Path) -> Result<Vec<PathBuf>, IdentifyError> {
    std::fs::create_dir_all(out).map_err(|e| io(out, e))?;
    let mut written = Vec::new();
    let ssv = out.join(format!("{}.ssv", id.set.name));
    id.set.write_file(&ssv).map_err(|e| io(&ssv, e))?;
    written.push(ssv.clone());
    let mut figure = None;
    if let Some(r) = &id.refinement
        && !r.fit.is_empty()
    {
        let csv = out.join("identify-fit.csv");
        r.fit.write_csv_file(&csv).map_err(|e| io(&csv, e))?;
        written.push(csv);
        for ext in ["svg", "png"] {
            let path = out.join(format!("identify-fit.{ext}"));
            plot_signals_with(
                &r.fit,
                &[
                    "measured w1",
                    "twin w1",
                    "measured w2",
                    "twin w2",
                    "residual tau",
                ],
                &path,
                (1200, 600),
                &PlotLabels {
                    y: "velocity [rad/s], torque residual [N m]".into(),
                    title: "Measured vs identified twin (first log)".into(),
                    ..PlotLabels::default()
                },
            )
            .map_err(|e| io(&path, e))?;
            written.push(path);
        }
        figure = Some("identify-fit.png");
    }
    let md = out.join("identify.md");
    std::fs::write(&md, markdown(id, &ssv, figure)).map_err(|e| io(&md, e))?;
    written.push(md);
    Ok(written)
}

fn markdown(id: &Identification, ssv: &Path, figure: Option<&str>) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "## Identification\n");
    let _ = writeln!(
        s,
        "Logs: {}. Parameter set written: `{}`, {}.\n",
        id.logs
            .iter()
            .map(|p| format!("`{}`", p.display()))
            .collect::<Vec<_>>()
            .join(", "),
        ssv.file_name()
            .map(|f| f.to_string_lossy())
            .unwrap_or_default(),
        id.set.label()
    );
    let _ = writeln!(
        s,
        "Intervals are 95 % (1.96 standard errors, the variance inflated by the residuals' autocorrelation time). \"LS\" is the linear least-squares estimate (inverse dynamics on the smoothed encoder signals), \"refined\" the output-error estimate from simulating the plant over the logged currents.\n"
    );
    let _ = writeln!(
        s,
        "| quantity | parameter | unit | prior | LS | refined | status |\n|---|---|---|---|---|---|---|"
    );
    for e in &id.estimates {
        let ls = if e.linear.is_finite() {
            format!("{} +- {}", fmt(e.linear), fmt(e.linear_ci))
        } else {
            "-".into()
        };
        let refined = e
            .refined
            .map(|(v, ci)| format!("{} +- {}", fmt(v), fmt(ci)))
            .unwrap_or_else(|| "-".into());
        let status = match &e.status {
            Status::Identified => "identified".to_string(),
            Status::NotIdentifiable(why) => format!("**not identifiable**: {why}"),
            Status::Conditional(why) => format!("**conditional** (written): {why}"),
        };
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {ls} | {refined} | {status} |",
            e.quantity.label,
            e.quantity.parameter.unwrap_or("(sensor offset)"),
            e.quantity.unit,
            fmt(e.prior)
        );
    }
    let missing: Vec<_> = id
        .estimates
        .iter()
        .filter(|e| matches!(e.status, Status::NotIdentifiable(_)))
        .collect();
    if !missing.is_empty() {
        let _ = writeln!(
            s,
            "\n### Not identifiable from these logs\n\nThe written set keeps the prior value of each; to identify it, add:\n"
        );
        for e in missing {
            let _ = writeln!(
                s,
                "- {} ({}): {}",
                e.quantity.label, e.quantity.unit, e.quantity.experiment
            );
        }
    }
    let conditional: Vec<_> = id
        .estimates
        .iter()
        .filter(|e| matches!(e.status, Status::Conditional(_)))
        .collect();
    if !conditional.is_empty() {
        let _ = writeln!(
            s,
            "\n### Conditional on held values\n\nFitted and written to the set as part of one fitted function, but not determined on their own (their intervals count the held values' uncertainty); to identify them, add:\n"
        );
        for e in conditional {
            let _ = writeln!(
                s,
                "- {} ({}): {}",
                e.quantity.label, e.quantity.unit, e.quantity.experiment
            );
        }
    }
    let _ = writeln!(
        s,
        "\n### Fit quality\n\n| regression | rows | residual RMS | autocorrelation (samples) | correlated pairs (> 0.9) |\n|---|---|---|---|---|"
    );
    for r in &id.regressions {
        let pairs = r
            .correlated
            .iter()
            .map(|(a, b, c)| format!("{a}/{b} {c:.3}"))
            .collect::<Vec<_>>()
            .join(", ");
        let _ = writeln!(
            s,
            "| {} | {} | {} {} | {:.1} | {} |",
            r.name,
            r.rows,
            fmt(r.residual_rms.0),
            r.residual_rms.1,
            r.inflation,
            if pairs.is_empty() {
                "none".into()
            } else {
                pairs
            }
        );
    }
    if let Some(r) = &id.refinement {
        let pairs = r
            .correlated
            .iter()
            .map(|(a, b, c)| format!("{a}/{b} {c:.3}"))
            .collect::<Vec<_>>()
            .join(", ");
        let _ = writeln!(
            s,
            "\nRefinement: {} adjusted over {:.1} s of logs per simulation; {} iterations, {} simulations; normalised residual RMS {:.4} at the LS estimates, {:.4} refined (autocorrelation {:.1} rows); correlated pairs: {}.",
            r.parameters.join(", "),
            r.simulated_seconds,
            r.iterations,
            r.evaluations,
            r.residual_rms.0,
            r.residual_rms.1,
            r.inflation,
            if pairs.is_empty() {
                "none".into()
            } else {
                pairs
            }
        );
        let _ = writeln!(s, "\nThe simulation's drive:\n");
        for d in &r.drives {
            let _ = writeln!(s, "- {d}");
        }
    }
    if let Some(f) = figure {
        let _ = writeln!(
            s,
            "\n![Measured vs identified twin]({f})\n\n(vector: [identify-fit.svg](identify-fit.svg); data: [identify-fit.csv](identify-fit.csv))"
        );
    }
    if !id.notes.is_empty() {
        let _ = writeln!(s, "\n### Notes\n");
        for n in &id.notes {
            let _ = writeln!(s, "- {n}");
        }
    }
    let _ = writeln!(s, "\nIdentification took {:.2} s.", id.seconds);
    s
}
