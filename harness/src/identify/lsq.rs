//! Linear least squares with the statistics an identification reports: standard errors
//! (inflated for correlated residuals), parameter correlations, and which parameters the data
//! do not determine.

use nalgebra::{DMatrix, DVector};

/// Eigenvalues of the column-scaled normal matrix below this fraction of the largest are
/// treated as zero: the directions they span are not determined by the data.
const RANK_TOLERANCE: f64 = 1e-10;

/// Statistics of a least-squares estimate.
#[derive(Debug, Clone, PartialEq)]
pub struct FitStatistics {
    /// Standard error of each parameter (NaN where not determined).
    pub std: Vec<f64>,
    /// Whether each parameter is determined by the data (its column is excited and not a
    /// combination of the others').
    pub determined: Vec<bool>,
    /// Correlation matrix of the estimates (row-major, `p x p`; NaN where not determined).
    pub correlation: Vec<Vec<f64>>,
    /// RMS of the residuals.
    pub residual_rms: f64,
    /// Rows used.
    pub rows: usize,
    /// Variance inflation for correlated residuals: the integrated autocorrelation time of
    /// the residuals in samples (1 for white residuals).
    pub inflation: f64,
}

/// A linear fit `y ~ X p`.
#[derive(Debug, Clone, PartialEq)]
pub struct LinearFit {
    /// Estimates (NaN where not determined).
    pub values: Vec<f64>,
    /// Their statistics.
    pub stats: FitStatistics,
}

/// Integrated autocorrelation time of `r` in samples: `1 + 2 sum rho_k`, summed while
/// `rho_k` > 0.05 (at most `len / 10` lags); at least 1.
pub fn autocorrelation_time(r: &[f64]) -> f64 {
    let n = r.len();
    if n < 20 {
        return 1.0;
    }
    let mean = r.iter().sum::<f64>() / n as f64;
    let var: f64 = r.iter().map(|x| (x - mean).powi(2)).sum();
    if var == 0.0 {
        return 1.0;
    }
    let mut tau = 1.0;
    let mut lag = 1;
    while lag < n / 10 {
        let c: f64 = (0..n - lag)
            .map(|i| (r[i] - mean) * (r[i + lag] - mean))
            .sum();
        let rho = c / var;
        if rho < 0.05 {
            break;
        }
        tau += 2.0 * rho;
        // Long lags: step coarser (the sum is smooth), counting each skipped lag.
        let stride = (lag / 16).max(1);
        if stride > 1 {
            tau += 2.0 * rho * (stride - 1) as f64;
        }
        lag += stride;
    }
    tau.max(1.0)
}

/// Scaled normal matrix, its pseudo-inverse and which parameters it determines.
struct Normal {
    scale: Vec<f64>,
    pinv: DMatrix<f64>,
    determined: Vec<bool>,
}

fn normal(x: &DMatrix<f64>) -> Normal {
    let p = x.ncols();
    let scale: Vec<f64> = (0..p).map(|j| x.column(j).norm()).collect();
    let mut g = x.transpose() * x;
    for i in 0..p {
        for j in 0..p {
            let s = scale[i] * scale[j];
            g[(i, j)] = if s > 0.0 { g[(i, j)] / s } else { 0.0 };
        }
    }
    let eig = g.symmetric_eigen();
    let largest = eig.eigenvalues.iter().cloned().fold(0.0f64, f64::max);
    let mut pinv = DMatrix::<f64>::zeros(p, p);
    let mut null_weight = vec![0.0f64; p];
    for k in 0..p {
        let l = eig.eigenvalues[k];
        let v = eig.eigenvectors.column(k);
        if largest > 0.0 && l > RANK_TOLERANCE * largest {
            pinv += (v * v.transpose()) / l;
        } else {
            for j in 0..p {
                null_weight[j] += v[j] * v[j];
            }
        }
    }
    let determined = (0..p)
        .map(|j| scale[j] > 0.0 && null_weight[j] < 1e-6)
        .collect();
    Normal {
        scale,
        pinv,
        determined,
    }
}

/// Statistics of an estimate whose residuals are `r` and whose Jacobian (of the model
/// output with respect to the parameters) is `x` (`rows x p`).
pub fn statistics(x: &DMatrix<f64>, r: &[f64]) -> FitStatistics {
    let n = normal(x);
    statistics_with(&n, x.ncols(), r)
}

fn statistics_with(n: &Normal, p: usize, r: &[f64]) -> FitStatistics {
    let rows = r.len();
    let rss: f64 = r.iter().map(|v| v * v).sum();
    let dof = rows.saturating_sub(p).max(1) as f64;
    let inflation = autocorrelation_time(r);
    let sigma2 = rss / dof * inflation;
    let cov = |i: usize, j: usize| sigma2 * n.pinv[(i, j)] / (n.scale[i] * n.scale[j]);
    let std: Vec<f64> = (0..p)
        .map(|j| {
            if n.determined[j] {
                cov(j, j).sqrt()
            } else {
                f64::NAN
            }
        })
        .collect();
    let correlation = (0..p)
        .map(|i| {
            (0..p)
                .map(|j| {
                    if n.determined[i] && n.determined[j] {
                        cov(i, j) / (std[i] * std[j])
                    } else {
                        f64::NAN
                    }
                })
                .collect()
        })
        .collect();
    FitStatistics {
        std,
        determined: n.determined.clone(),
        correlation,
        residual_rms: (rss / rows.max(1) as f64).sqrt(),
        rows,
        inflation,
    }
}

/// Fits `y ~ X p` (`columns` are the columns of X, all of `y`'s length: owned, or borrowed
/// from a larger set without copying).
pub fn fit<C: AsRef<[f64]>>(columns: &[C], y: &[f64]) -> LinearFit {
    let p = columns.len();
    let rows = y.len();
    let x = DMatrix::from_fn(rows, p, |i, j| columns[j].as_ref()[i]);
    let n = normal(&x);
    let b = DVector::from_fn(p, |j, _| {
        if n.scale[j] > 0.0 {
            x.column(j).dot(&DVector::from_column_slice(y)) / n.scale[j]
        } else {
            0.0
        }
    });
    let scaled = &n.pinv * b;
    let values: Vec<f64> = (0..p)
        .map(|j| {
            if n.determined[j] {
                scaled[j] / n.scale[j]
            } else {
                f64::NAN
            }
        })
        .collect();
    let used: Vec<f64> = values
        .iter()
        .map(|v| if v.is_finite() { *v } else { 0.0 })
        .collect();
    let r: Vec<f64> = (0..rows)
        .map(|i| y[i] - (0..p).map(|j| x[(i, j)] * used[j]).sum::<f64>())
        .collect();
    LinearFit {
        values,
        stats: statistics_with(&n, p, &r),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A small deterministic generator of standard normal noise (xorshift + Box-Muller).
    pub(crate) fn noise(n: usize, seed: u64) -> Vec<f64> {
        let mut s = seed.max(1);
        let mut u = || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            ((s >> 11) as f64 + 0.5) / (1u64 << 53) as f64
        };
        (0..n)
            .map(|_| (-2.0 * u().ln()).sqrt() * (2.0 * std::f64::consts::PI * u()).cos())
            .collect()
    }

    #[test]
    fn recovers_a_line_with_an_honest_interval() {
        let n = 2000;
        let x: Vec<f64> = (0..n).map(|i| (i as f64 * 0.01).sin()).collect();
        let e = noise(n, 7);
        let y: Vec<f64> = (0..n).map(|i| 2.0 * x[i] + 0.5 + 0.1 * e[i]).collect();
        let f = fit(&[x.clone(), vec![1.0; n]], &y);
        assert!((f.values[0] - 2.0).abs() < 3.0 * f.stats.std[0]);
        assert!((f.values[1] - 0.5).abs() < 3.0 * f.stats.std[1]);
        // White noise: the expected standard error of the slope, ~0.1 / sqrt(n/2).
        assert!(
            f.stats.std[0] > 0.002 && f.stats.std[0] < 0.006,
            "{:?}",
            f.stats
        );
        assert!(f.stats.inflation < 1.5);
        assert!((f.stats.residual_rms - 0.1).abs() < 0.01);
    }

    #[test]
    fn unexcited_and_collinear_columns_are_not_determined() {
        let n = 500;
        let x: Vec<f64> = (0..n).map(|i| i as f64).collect();
        let y: Vec<f64> = x.iter().map(|v| 3.0 * v).collect();
        let f = fit(
            &[x.clone(), vec![0.0; n], x.iter().map(|v| 2.0 * v).collect()],
            &y,
        );
        assert_eq!(f.stats.determined, vec![false, false, false]);
        let g = fit(&[x.clone(), vec![0.0; n]], &y);
        assert_eq!(g.stats.determined, vec![true, false]);
        assert!((g.values[0] - 3.0).abs() < 1e-12);
        assert!(g.values[1].is_nan());
    }

    #[test]
    fn correlated_residuals_widen_the_interval() {
        let n = 4000;
        let e = noise(n, 3);
        // A moving average over 20 samples: autocorrelation time about 20.
        let smooth: Vec<f64> = (0..n)
            .map(|i| e[i.saturating_sub(19)..=i].iter().sum::<f64>() / 20f64.sqrt())
            .collect();
        let tau = autocorrelation_time(&smooth[20..]);
        assert!(tau > 10.0 && tau < 40.0, "{tau}");
        assert!(autocorrelation_time(&e) < 1.3);
    }
}
