//! `kneebench tune`: Ziegler-Nichols starting gains.

use std::path::PathBuf;

use anyhow::bail;
use kneebench_harness::Results;
use kneebench_harness::metrics::{
    MetricsError, reaction_curve, ziegler_nichols_reaction, ziegler_nichols_ultimate,
};
use model_description::num::Num;

/// Arguments of `kneebench tune`.
#[derive(Debug, clap::Args)]
#[command(after_help = "\
Examples:
  kneebench tune --ku 8000 --tu 0.12
  kneebench run out/fmus/BenchPlant.fmu --stop-time 2 --param testCurrentCommand=1 --output open-loop.csv
  kneebench tune --step-response open-loop.csv --signal actuationVelocity --input-step 1.0

Ultimate-gain method: raise a P-only gain until the loop oscillates steadily; that gain is
Ku, the period Tu: kp = 0.6 Ku, Ti = Tu/2, Td = Tu/8. Reaction-curve method: record the
open-loop response to an input step of known size applied at the first row; the tangent at
the steepest point gives the dead time L and time constant T, and the change from the first
row to the mean of the record's last tenth (its final value) the gain K: kp = 1.2 T/(K L),
Ti = 2 L, Td = L/2. Both are starting points for manual refinement, as in the bench study.
Gains are printed in parallel form, u = kp e + ki integral(e) + kd de/dt, to 6 significant
digits. Inputs whose gains overflow (or underflow to zero) are refused (exit code 2).")]
pub struct Args {
    /// Ultimate gain Ku.
    #[arg(long, requires = "tu", conflicts_with = "step_response", value_parser = super::values::positive)]
    pub ku: Option<f64>,
    /// Ultimate period Tu, in seconds.
    #[arg(long, requires = "ku", value_parser = super::values::positive)]
    pub tu: Option<f64>,
    /// Results file (CSV or Parquet) holding an open-loop step response.
    #[arg(long, requires_all = ["signal", "input_step"])]
    pub step_response: Option<PathBuf>,
    /// The response column.
    #[arg(long)]
    pub signal: Option<String>,
    /// Size of the input step.
    #[arg(long, allow_hyphen_values = true, value_parser = super::values::non_zero)]
    pub input_step: Option<f64>,
}

/// Runs `kneebench tune`.
pub fn run(a: Args) -> anyhow::Result<i32> {
    let gains = match (a.ku, a.tu, &a.step_response) {
        (Some(ku), Some(tu), None) => {
            ziegler_nichols_ultimate(ku, tu).map_err(usage("--ku, --tu"))?
        }
        (None, None, Some(path)) => {
            let (results, lines) = Results::read_file_lines(path)?;
            let name = a.signal.as_deref().unwrap_or_default();
            let values = results.column(name).ok_or_else(|| {
                super::Usage(format!(
                    "--signal: no column '{name}' in {}",
                    path.display()
                ))
            })?;
            let all: Vec<usize> = (0..results.len()).collect();
            results.check_rows(path, &lines, &[name], &all)?;
            let curve = reaction_curve(&results.times(), &values, a.input_step.unwrap_or(1.0))?;
            println!(
                "reaction curve: K = {}, L = {} s, T = {} s",
                compact(curve.gain),
                compact(curve.dead_time),
                compact(curve.time_constant)
            );
            ziegler_nichols_reaction(&curve).map_err(usage("--step-response, --input-step"))?
        }
        _ => bail!("give either --ku and --tu, or --step-response with --signal and --input-step"),
    };
    println!("Ziegler-Nichols PID (parallel form):");
    println!("  kp = {}", compact(gains.kp));
    println!("  ki = {}", compact(gains.ki));
    println!("  kd = {}", compact(gains.kd));
    Ok(super::EXIT_OK)
}

/// A usage error (exit code 2) naming `options` for gains the rule cannot give as finite,
/// non-zero numbers ([`MetricsError::Gain`]: the inputs' combination overflows); any other
/// error as it is.
fn usage(options: &'static str) -> impl Fn(MetricsError) -> anyhow::Error {
    move |e| match e {
        MetricsError::Gain { .. } => super::Usage(format!("{options}: {e}")).into(),
        e => e.into(),
    }
}

/// `v` to 6 significant digits, printed in its shortest form: plain between 1e-5 and 1e16,
/// in exponent form outside (a gain of 1e307 printed with `{:.6}` ran to 300 digits).
fn compact(v: f64) -> Num {
    Num(format!("{v:.5e}").parse().unwrap_or(v))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn numbers_print_compactly_to_six_significant_digits() {
        for (v, text) in [
            (6.0, "6"),
            (0.375, "0.375"),
            (4.800000000000001, "4.8"),
            (6e307, "6e307"),
            (1.0 / 3.0, "0.333333"),
            (123456789.0, "123457000"),
            (-2.5e-9, "-2.5e-9"),
        ] {
            assert_eq!(compact(v).to_string(), text);
        }
    }
}
