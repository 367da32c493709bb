//! Shared analysis of the experiments: linear least squares with the coefficients' covariance,
//! a sine fit with the uncertainty of its amplitude and phase (from the fit residual), and
//! transfer ratios of two fitted sines.

use super::ExperimentError;

/// A linear least-squares fit `y ~ X beta`.
#[derive(Debug, Clone, PartialEq)]
pub struct LeastSquares {
    /// The coefficients `beta`.
    pub coefficients: Vec<f64>,
    /// Their covariance `s^2 (X'X)^-1`, `s^2` the residual variance (row-major, p x p).
    pub covariance: Vec<f64>,
    /// RMS of the residual.
    pub residual_rms: f64,
    /// Degrees of freedom (rows - coefficients).
    pub degrees_of_freedom: usize,
}

impl LeastSquares {
    /// Standard deviation of coefficient `i`.
    pub fn std(&self, i: usize) -> f64 {
        let p = self.coefficients.len();
        self.covariance[i * p + i].max(0.0).sqrt()
    }

    /// Covariance of coefficients `i` and `j`.
    pub fn cov(&self, i: usize, j: usize) -> f64 {
        self.covariance[i * self.coefficients.len() + j]
    }
}

/// Solves the least-squares problem for the design rows `rows` (each of the same length p) and
/// observations `y`, through the normal equations (Cholesky). Refuses fewer rows than
/// coefficients, non-finite values and a rank-deficient design.
pub fn least_squares(rows: &[Vec<f64>], y: &[f64]) -> Result<LeastSquares, ExperimentError> {
    let n = rows.len();
    let p = rows.first().map_or(0, Vec::len);
    if p == 0 || n != y.len() || n < p || rows.iter().any(|r| r.len() != p) {
        return Err(ExperimentError::Analysis(format!(
            "least squares needs at least as many rows as coefficients and one observation per row (rows {n}, coefficients {p}, observations {})",
            y.len()
        )));
    }
    if rows.iter().flatten().chain(y).any(|v| !v.is_finite()) {
        return Err(ExperimentError::Analysis(
            "least squares: a sample is not finite".into(),
        ));
    }
    let mut a = vec![0.0; p * p];
    let mut b = vec![0.0; p];
    for (r, &yi) in rows.iter().zip(y) {
        for i in 0..p {
            b[i] += r[i] * yi;
            for j in 0..p {
                a[i * p + j] += r[i] * r[j];
            }
        }
    }
    let inverse = invert_spd(&a, p).ok_or_else(|| {
        ExperimentError::Analysis("least squares: the design is rank deficient".into())
    })?;
    let beta: Vec<f64> = (0..p)
        .map(|i| (0..p).map(|j| inverse[i * p + j] * b[j]).sum())
        .collect();
    let sse: f64 = rows
        .iter()
        .zip(y)
        .map(|(r, &yi)| {
            let e = yi - r.iter().zip(&beta).map(|(x, c)| x * c).sum::<f64>();
            e * e
        })
        .sum();
    let dof = n - p;
    let variance = if dof > 0 { sse / dof as f64 } else { 0.0 };
    Ok(LeastSquares {
        coefficients: beta,
        covariance: inverse.iter().map(|v| v * variance).collect(),
        residual_rms: (sse / n as f64).sqrt(),
        degrees_of_freedom: dof,
    })
}

/// Inverse of a symmetric positive definite matrix by Cholesky; `None` when it is not (to a
/// relative pivot of 1e-12).
fn invert_spd(a: &[f64], p: usize) -> Option<Vec<f64>> {
    let mut l = vec![0.0; p * p];
    let scale = (0..p).map(|i| a[i * p + i]).fold(0.0f64, f64::max);
    for i in 0..p {
        for j in 0..=i {
            let mut s = a[i * p + j];
            for k in 0..j {
                s -= l[i * p + k] * l[j * p + k];
            }
            if i == j {
                if s <= 1e-12 * scale {
                    return None;
                }
                l[i * p + i] = s.sqrt();
            } else {
                l[i * p + j] = s / l[j * p + j];
            }
        }
    }
    // Columns of L^-1, then (L^-1)' L^-1.
    let mut li = vec![0.0; p * p];
    for c in 0..p {
        for i in c..p {
            let mut s = if i == c { 1.0 } else { 0.0 };
            for k in c..i {
                s -= l[i * p + k] * li[k * p + c];
            }
            li[i * p + c] = s / l[i * p + i];
        }
    }
    let mut inv = vec![0.0; p * p];
    for i in 0..p {
        for j in 0..p {
            inv[i * p + j] = (i.max(j)..p).map(|k| li[k * p + i] * li[k * p + j]).sum();
        }
    }
    Some(inv)
}

/// A sinusoid fitted at a known frequency: `y = offset + drift (t - t_mid) + A sin(w t + phi)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SineFit {
    /// Frequency \[Hz\] (given).
    pub frequency: f64,
    /// Amplitude A (>= 0).
    pub amplitude: f64,
    /// Standard deviation of A (from the fit residual).
    pub amplitude_std: f64,
    /// Phase phi \[rad\], in (-pi, pi].
    pub phase: f64,
    /// Standard deviation of phi \[rad\].
    pub phase_std: f64,
    /// Mean value.
    pub offset: f64,
    /// RMS of the residual.
    pub residual_rms: f64,
}

/// The fewest samples [`sine_fit`] fits (amplitude, phase, offset and drift, and one more).
pub const SINE_FIT_MIN_SAMPLES: usize = 5;

/// Fits a sinusoid of `frequency` \[Hz\] with an offset and a linear drift to `(times, values)`.
pub fn sine_fit(times: &[f64], values: &[f64], frequency: f64) -> Result<SineFit, ExperimentError> {
    if !(frequency.is_finite() && frequency > 0.0) {
        return Err(ExperimentError::Analysis(format!(
            "sine fit: frequency {frequency} must be positive"
        )));
    }
    if times.len() != values.len() || times.len() < SINE_FIT_MIN_SAMPLES {
        return Err(ExperimentError::Analysis(format!(
            "sine fit needs at least {SINE_FIT_MIN_SAMPLES} samples (got {})",
            times.len()
        )));
    }
    let w = std::f64::consts::TAU * frequency;
    let t_mid = 0.5 * (times[0] + times[times.len() - 1]);
    let rows: Vec<Vec<f64>> = times
        .iter()
        .map(|&t| {
            let (s, c) = (w * t).sin_cos();
            vec![s, c, 1.0, t - t_mid]
        })
        .collect();
    let fit = least_squares(&rows, values)?;
    let (a, b) = (fit.coefficients[0], fit.coefficients[1]);
    let amplitude = a.hypot(b);
    let (vaa, vbb, vab) = (fit.cov(0, 0), fit.cov(1, 1), fit.cov(0, 1));
    let (amplitude_std, phase_std) = if amplitude > 0.0 {
        let a2 = amplitude * amplitude;
        (
            ((a * a * vaa + b * b * vbb + 2.0 * a * b * vab) / a2)
                .max(0.0)
                .sqrt(),
            ((b * b * vaa + a * a * vbb - 2.0 * a * b * vab) / (a2 * a2))
                .max(0.0)
                .sqrt(),
        )
    } else {
        (vaa.max(vbb).max(0.0).sqrt(), f64::INFINITY)
    };
    Ok(SineFit {
        frequency,
        amplitude,
        amplitude_std,
        // a sin + b cos = A sin(wt + phi), A cos phi = a, A sin phi = b.
        phase: b.atan2(a),
        phase_std,
        offset: fit.coefficients[2],
        residual_rms: fit.residual_rms,
    })
}

/// The ratio of two fitted sines (output over input) at one frequency: gain, phase and their
/// standard deviations (independent errors, first order).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ratio {
    /// |Y| / |U|.
    pub gain: f64,
    /// Relative standard deviation of the gain.
    pub gain_relative_std: f64,
    /// arg Y - arg U \[rad\], wrapped to (-pi, pi].
    pub phase: f64,
    /// Standard deviation of the phase \[rad\].
    pub phase_std: f64,
}

impl Ratio {
    /// Output `y` over input `u`.
    pub fn of(y: &SineFit, u: &SineFit) -> Ratio {
        let rel = |f: &SineFit| f.amplitude_std / f.amplitude;
        Ratio {
            gain: y.amplitude / u.amplitude,
            gain_relative_std: rel(y).hypot(rel(u)),
            phase: wrap(y.phase - u.phase),
            phase_std: y.phase_std.hypot(u.phase_std),
        }
    }

    /// Gain in dB.
    pub fn gain_db(&self) -> f64 {
        20.0 * self.gain.log10()
    }

    /// Standard deviation of the gain in dB.
    pub fn gain_db_std(&self) -> f64 {
        20.0 / std::f64::consts::LN_10 * self.gain_relative_std
    }
}

/// Wraps an angle to (-pi, pi].
pub fn wrap(x: f64) -> f64 {
    use std::f64::consts::{PI, TAU};
    let y = (x + PI).rem_euclid(TAU) - PI;
    if y == -PI { PI } else { y }
}

/// Mean of `values[range]` (NaN for an empty range).
pub fn mean(values: &[f64]) -> f64 {
    values.iter().sum::<f64>() / values.len() as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn least_squares_recovers_a_line_and_refuses_rank_deficiency() {
        let rows: Vec<Vec<f64>> = (0..10).map(|i| vec![1.0, i as f64]).collect();
        let y: Vec<f64> = (0..10).map(|i| 2.0 + 0.5 * i as f64).collect();
        let fit = least_squares(&rows, &y).unwrap();
        assert!((fit.coefficients[0] - 2.0).abs() < 1e-12);
        assert!((fit.coefficients[1] - 0.5).abs() < 1e-12);
        assert!(fit.residual_rms < 1e-12);
        let flat: Vec<Vec<f64>> = (0..10).map(|_| vec![1.0, 1.0]).collect();
        assert!(least_squares(&flat, &y).is_err());
        assert!(least_squares(&rows[..1], &y[..1]).is_err());
    }

    #[test]
    fn sine_fit_recovers_amplitude_and_phase_and_its_uncertainty_tracks_noise() {
        let f = 1.3;
        let t: Vec<f64> = (0..2000).map(|i| i as f64 * 1e-3).collect();
        let clean: Vec<f64> = t
            .iter()
            .map(|t| 0.7 + 0.1 * t + 2.0 * (std::f64::consts::TAU * f * t + 0.4).sin())
            .collect();
        let fit = sine_fit(&t, &clean, f).unwrap();
        assert!((fit.amplitude - 2.0).abs() < 1e-9, "{fit:?}");
        assert!((fit.phase - 0.4).abs() < 1e-9);
        assert!(fit.amplitude_std < 1e-9);
        // A deterministic "noise" of RMS 0.05: the standard deviations grow to its order
        // over sqrt(n).
        let noisy: Vec<f64> = clean
            .iter()
            .enumerate()
            .map(|(i, v)| v + 0.05 * 2f64.sqrt() * ((i as f64) * 2.399_963).sin())
            .collect();
        let fit = sine_fit(&t, &noisy, f).unwrap();
        let expected = 0.05 * (2.0 / 2000.0f64).sqrt();
        assert!(fit.amplitude_std > 0.5 * expected && fit.amplitude_std < 2.0 * expected);
        assert!((fit.amplitude - 2.0).abs() < 5.0 * expected);
        let u = sine_fit(&t, &clean, f).unwrap();
        let r = Ratio::of(&fit, &u);
        assert!((r.gain_db()).abs() < 0.01 && r.phase.abs() < 0.01);
    }
}
