//! `kneebench metrics`: step-response quality and tracking error of recorded signals.

use std::path::PathBuf;

use kneebench_harness::Results;
use kneebench_harness::metrics::{step_metrics, tracking_error};

/// Arguments of `kneebench metrics`.
#[derive(Debug, clap::Args)]
#[command(after_help = "\
Examples:
  kneebench metrics open-loop.csv --signal actuationVelocity --from 0
  kneebench metrics open-loop.csv --signal actuationVelocity --target 0.02 --from 0
  kneebench metrics out/study/SEA.csv --signal plant.actuationAngle --reference gait.kneeAngleReference --from 2.5

With --target (or neither option), the signal is treated as a step response starting at
--from: rise time to 90 %, settling time in a 5 % band, overshoot and peak time (the bench
study's measures). With --reference, the RMS and maximum tracking error against that signal.")]
pub struct Args {
    /// Results file: CSV (first column time) or Parquet, as `kneebench run` writes them.
    pub results: PathBuf,
    /// The response signal (column name).
    #[arg(long)]
    pub signal: String,
    /// The reference signal to compute the tracking error against.
    #[arg(long, conflicts_with = "target")]
    pub reference: Option<String>,
    /// The step's target value (default: the last sample).
    #[arg(long, allow_hyphen_values = true, value_parser = super::values::finite)]
    pub target: Option<f64>,
    /// Time of the step, in seconds; earlier rows are ignored.
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true, value_parser = super::values::finite)]
    pub from: f64,
}

/// Runs `kneebench metrics`.
pub fn run(a: Args) -> anyhow::Result<i32> {
    let (results, lines) = Results::read_file_lines(&a.results)?;
    // A name that is no column is a usage error (exit code 2).
    let column = |name: &str| {
        results
            .column(name)
            .ok_or_else(|| super::Usage(format!("no column '{name}' in {}", a.results.display())))
    };
    let times = results.times();
    // A NaN time would fail `>= from` and so be dropped silently: times are checked first.
    results.check_times(&a.results, &lines)?;
    let keep: Vec<usize> = (0..times.len()).filter(|&i| times[i] >= a.from).collect();
    if keep.len() < 2 {
        eprintln!(
            "error: --from {}: fewer than two rows of {} at or after it ({})",
            a.from,
            a.results.display(),
            match times.last() {
                Some(t) => format!("the last is at t = {t}"),
                None => "it has no rows".to_string(),
            }
        );
        return Ok(super::EXIT_USAGE);
    }
    let used: Vec<&str> = std::iter::once(a.signal.as_str())
        .chain(a.reference.as_deref())
        .collect();
    // Unknown names are reported by `column` below, with the file.
    if used.iter().all(|n| results.column(n).is_some()) {
        results.check_values(&a.results, &lines, &used, &keep)?;
    }
    let pick = |v: &[f64]| keep.iter().map(|&i| v[i]).collect::<Vec<f64>>();
    let signal = pick(&column(&a.signal)?);
    if let Some(reference) = &a.reference {
        let reference = pick(&column(reference)?);
        let (rms, max) = tracking_error(&reference, &signal)?;
        println!("tracking error of {} (from t = {}):", a.signal, a.from);
        println!("  RMS  {rms:.6e}");
        println!("  max  {max:.6e}");
        return Ok(super::EXIT_OK);
    }
    let m = step_metrics(&pick(&times), &signal, a.target)?;
    let opt = |v: Option<f64>| v.map_or("not reached".to_string(), |v| format!("{v:.6} s"));
    println!("step response of {} from t = {}:", a.signal, m.step_time);
    println!("  initial value   {:.6}", m.initial_value);
    println!("  final value     {:.6}", m.final_value);
    println!("  rise time 90 %  {}", opt(m.rise_time));
    println!("  settling 5 %    {}", opt(m.settling_time));
    println!("  overshoot       {:.2} %", 100.0 * m.overshoot);
    println!("  peak time       {:.6} s", m.peak_time);
    Ok(super::EXIT_OK)
}
