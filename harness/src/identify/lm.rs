//! A small Levenberg-Marquardt solver for bounded nonlinear least squares with a
//! forward-difference Jacobian (each evaluation may be a simulation).

use nalgebra::{DMatrix, DVector};

/// Settings of [`solve`].
#[derive(Debug, Clone, PartialEq)]
pub struct LmOptions {
    /// Most iterations (Jacobian evaluations).
    pub max_iterations: usize,
    /// Stop when an accepted step changes no parameter by more than this fraction of its
    /// value (or lowers the cost by less than 1e-12 of it).
    pub tolerance: f64,
    /// Relative finite-difference step.
    pub difference_step: f64,
}

impl Default for LmOptions {
    fn default() -> Self {
        LmOptions {
            max_iterations: 20,
            tolerance: 1e-7,
            difference_step: 1e-5,
        }
    }
}

/// The result of [`solve`].
#[derive(Debug, Clone, PartialEq)]
pub struct LmResult {
    /// The parameters at the minimum.
    pub params: Vec<f64>,
    /// Residuals there.
    pub residuals: Vec<f64>,
    /// Jacobian of the residuals there (`rows x p`).
    pub jacobian: DMatrix<f64>,
    /// Sum of squared residuals.
    pub cost: f64,
    /// Iterations done.
    pub iterations: usize,
    /// Residual evaluations done.
    pub evaluations: usize,
}

/// A residual function.
type Residuals<'a, E> = dyn FnMut(&[f64]) -> Result<Vec<f64>, E> + 'a;

fn cost(r: &[f64]) -> f64 {
    r.iter().map(|v| v * v).sum()
}

/// Minimises `|f(p)|^2` from `p0` within `[lower, upper]` (element-wise). `f` returns the
/// residuals (always the same number) or an error that ends the solve.
pub fn solve<E>(
    mut f: impl FnMut(&[f64]) -> Result<Vec<f64>, E>,
    p0: &[f64],
    lower: &[f64],
    upper: &[f64],
    options: &LmOptions,
) -> Result<LmResult, E> {
    let p_count = p0.len();
    let clamp = |p: &mut [f64]| {
        for j in 0..p.len() {
            p[j] = p[j].clamp(lower[j], upper[j]);
        }
    };
    let mut p = p0.to_vec();
    clamp(&mut p);
    let mut r = f(&p)?;
    let mut evaluations = 1;
    let mut c = cost(&r);
    let mut lambda = 1e-3;
    let mut iterations = 0;
    let jacobian_at = |f: &mut Residuals<'_, E>,
                       p: &[f64],
                       r: &[f64],
                       evaluations: &mut usize|
     -> Result<DMatrix<f64>, E> {
        let mut j = DMatrix::<f64>::zeros(r.len(), p.len());
        for k in 0..p.len() {
            let mut q = p.to_vec();
            let mut h = options.difference_step * p[k].abs().max(1e-3);
            if q[k] + h > upper[k] {
                h = -h;
            }
            q[k] += h;
            let rk = f(&q)?;
            *evaluations += 1;
            for i in 0..r.len() {
                j[(i, k)] = (rk[i] - r[i]) / h;
            }
        }
        Ok(j)
    };
    while iterations < options.max_iterations {
        iterations += 1;
        let jacobian = jacobian_at(&mut f, &p, &r, &mut evaluations)?;
        let jt = jacobian.transpose();
        let g = &jt * &jacobian;
        let grad = &jt * DVector::from_column_slice(&r);
        let mut improved = false;
        for _ in 0..10 {
            let mut a = g.clone();
            for k in 0..p_count {
                a[(k, k)] += lambda * g[(k, k)].max(1e-12);
            }
            let Some(delta) = a.clone().cholesky().map(|ch| ch.solve(&(-&grad))) else {
                lambda *= 10.0;
                continue;
            };
            let mut q: Vec<f64> = (0..p_count).map(|k| p[k] + delta[k]).collect();
            clamp(&mut q);
            let rq = f(&q)?;
            evaluations += 1;
            let cq = cost(&rq);
            if cq < c {
                let gain = (c - cq) / c.max(f64::MIN_POSITIVE);
                let step = (0..p_count)
                    .map(|k| (q[k] - p[k]).abs() / p[k].abs().max(1e-12))
                    .fold(0.0f64, f64::max);
                p = q;
                r = rq;
                c = cq;
                lambda = (lambda / 3.0).max(1e-9);
                improved = step > options.tolerance && gain > 1e-12;
                break;
            }
            lambda *= 4.0;
        }
        if !improved {
            break;
        }
    }
    // The Jacobian at the final point (the last one may be one step old).
    let jacobian = jacobian_at(&mut f, &p, &r, &mut evaluations)?;
    Ok(LmResult {
        params: p,
        residuals: r,
        jacobian,
        cost: c,
        iterations,
        evaluations,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fits_a_decaying_exponential_from_far_away() {
        let t: Vec<f64> = (0..50).map(|i| i as f64 * 0.1).collect();
        let y: Vec<f64> = t.iter().map(|t| 3.0 * (-1.3 * t).exp() + 0.2).collect();
        let f = |p: &[f64]| -> Result<Vec<f64>, ()> {
            Ok(t.iter()
                .zip(&y)
                .map(|(t, y)| p[0] * (-p[1] * t).exp() + p[2] - y)
                .collect())
        };
        let r = solve(
            f,
            &[1.0, 0.3, 0.0],
            &[0.0, 0.0, -1.0],
            &[10.0, 10.0, 1.0],
            &LmOptions::default(),
        )
        .unwrap();
        assert!((r.params[0] - 3.0).abs() < 1e-6, "{:?}", r.params);
        assert!((r.params[1] - 1.3).abs() < 1e-6);
        assert!((r.params[2] - 0.2).abs() < 1e-6);
        assert!(r.cost < 1e-12);
    }

    #[test]
    fn bounds_hold_and_errors_end_the_solve() {
        let f = |p: &[f64]| -> Result<Vec<f64>, ()> { Ok(vec![p[0] - 5.0]) };
        let r = solve(f, &[0.0], &[-1.0], &[2.0], &LmOptions::default()).unwrap();
        assert_eq!(r.params, vec![2.0]);
        let mut calls = 0;
        let g = |_: &[f64]| -> Result<Vec<f64>, &str> {
            calls += 1;
            if calls > 2 {
                Err("simulation failed")
            } else {
                Ok(vec![1.0])
            }
        };
        assert_eq!(
            solve(g, &[0.0], &[-1.0], &[1.0], &LmOptions::default()).unwrap_err(),
            "simulation failed"
        );
    }
}
