//! `kneebench study`: the DA/SEA/CSEA gait study (the main job).

use std::path::PathBuf;

use anyhow::Context;
use kneebench_harness::study::{
    Actuator, Gait, StudyConfig, markdown_table, plot_study, run_study,
};

/// Arguments of `kneebench study`.
#[derive(Debug, clap::Args)]
#[command(after_help = "\
Examples:
  kneebench export --out out/fmus && kneebench study --fmus out/fmus --out out/study
  kneebench study --fmus out/fmus --out out/big --scale 1.3 --actuators sea   # trips an interlock: exit code 3

Each actuator runs the bench gait (2.5 s, 60 deg, 9 N m; 50 deg for CSEA) in closed loop:
GaitReference -> position loop -> test motor, load-torque reference -> torque loop -> load
motor; CSEA uses the impedance controller and the clutch scheduler. The scenarios are written
as SSP files (<out>/scenarios/*.ssp) that this tool, fmpy and other SSP tools can run. The
first cycle is the start-up and is not analysed. Written: <A>.csv (every signal), tracking.svg,
torques.svg, powers.svg (the last cycle, percent of cycle on the x axis) and report.md.
Exit code 3 when an interlock ended a run (the report names it).")]
pub struct Args {
    /// Directory of the exported FMUs (kneebench export).
    #[arg(long)]
    pub fmus: PathBuf,
    /// Output directory.
    #[arg(long, default_value = "out/study")]
    pub out: PathBuf,
    /// Gait cycles per run.
    #[arg(long, default_value_t = 4)]
    pub cycles: u32,
    /// Multiplies the gait's angle and torque amplitudes.
    #[arg(long, default_value_t = 1.0)]
    pub scale: f64,
    /// Actuators to run (comma-separated: da, sea, csea).
    #[arg(long, value_delimiter = ',', default_value = "da,sea,csea")]
    pub actuators: Vec<String>,
}

/// Runs `kneebench study`.
pub fn run(a: Args) -> anyhow::Result<i32> {
    let actuators = a
        .actuators
        .iter()
        .map(|s| match s.to_ascii_lowercase().as_str() {
            "da" => Ok(Actuator::Da),
            "sea" => Ok(Actuator::Sea),
            "csea" => Ok(Actuator::Csea),
            other => Err(anyhow::anyhow!(
                "unknown actuator '{other}' (da, sea, csea)"
            )),
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    anyhow::ensure!(a.cycles >= 1, "--cycles must be at least 1");
    anyhow::ensure!(
        a.scale.is_finite() && a.scale > 0.0,
        "--scale must be positive"
    );
    let config = StudyConfig {
        fmu_dir: a.fmus,
        out_dir: a.out.clone(),
        cycles: a.cycles,
        scale: a.scale,
        gains: None,
        actuators,
    };
    let runs = run_study(&config)?;
    let period = Gait::bench_default(Actuator::Sea).period;
    let figures = plot_study(&runs, period, &a.out)?;
    let reports: Vec<_> = runs.iter().map(|r| r.report.clone()).collect();
    let table = markdown_table(&reports);
    let report = format!(
        "# Actuator study\n\nGait: period {period} s, knee-angle amplitude {:.1} deg (CSEA {:.1} deg), knee-torque amplitude {:.2} N m; {} cycles per run, the first not analysed; 1 ms steps, Gauss-Seidel.\n\n{table}\nScenarios: {}\n",
        60.0 * a.scale,
        50.0 * a.scale,
        9.0 * a.scale,
        a.cycles,
        runs.iter()
            .map(|r| r.scenario.display().to_string())
            .collect::<Vec<_>>()
            .join(", ")
    );
    let path = a.out.join("report.md");
    std::fs::write(&path, &report).with_context(|| format!("writing {}", path.display()))?;
    println!("{table}");
    for r in &runs {
        println!(
            "results: {}",
            a.out.join(format!("{}.csv", r.report.name)).display()
        );
    }
    for f in &figures {
        println!("figure:  {}", f.display());
    }
    println!("report:  {}", path.display());
    let tripped = reports.iter().any(|r| r.trip.is_some());
    Ok(if tripped {
        super::EXIT_TERMINATED
    } else {
        super::EXIT_OK
    })
}
