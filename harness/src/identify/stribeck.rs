//! The exponential (Stribeck-like) friction law of one side, when the plant runs it
//! (`frictionModel` = Exponential):
//!
//! ```text
//! Tfr(w) = [a0 + a1 e^{-b1 |w|} + a2 (1 - e^{-b2 |w|})] sign(w)      (c w stays beside it)
//! ```
//!
//! It replaces the Coulomb column of the side's inverse-dynamics regression. The model is
//! linear in (Km, I, c, a0, a1, a2) for given decay rates (b1, b2), so they are found by
//! **variable projection**: for each (b1, b2) of a grid the linear parameters are solved by
//! least squares (from normal equations accumulated once per rate, so the grid costs a few
//! passes over the rows; only pairs with `b1 > b2`, the law being symmetric under exchanging
//! the two exponentials), the pair with the smallest residual is refined on a finer grid around
//! it, and the final estimate's statistics come from the full Jacobian (the two rates' columns
//! included) at the optimum ([`lsq::statistics`]), with the same autocorrelation inflation as
//! every regression.
//!
//! What the logs can tell: `a1` and `b1` live below the Stribeck speed (`1/b1`, 0.05 rad/s by
//! default), so only logs with slow steady motion determine them (`kneebench experiment map`
//! with its 3 deg/s rows); `a2` and `b2` need speeds beyond `1/b2` (0.5 rad/s) to be told from
//! the viscous `c`. Otherwise their intervals come out wide and the report says so.

use nalgebra::{DMatrix, DVector};

use super::lsq;

/// The fitted law and its statistics. Parameter order: Km, I, c, a0, a1, b1, a2, b2.
#[derive(Debug, Clone)]
pub struct LawFit {
    /// The estimates.
    pub values: [f64; 8],
    /// Statistics from the full Jacobian at the estimate.
    pub stats: lsq::FitStatistics,
}

/// The rows of one side: the regression's current and acceleration columns (signs included),
/// the smoothed velocity, the side's sign in the balance and the target (shaft torque minus
/// the transducer's offset).
pub struct SideRows<'a> {
    /// `-sign ratio i` per row.
    pub current: &'a [f64],
    /// `sign a` per row.
    pub acceleration: &'a [f64],
    /// The smoothed velocity `w` per row.
    pub velocity: &'a [f64],
    /// +1 or -1: the side's sign in the balance.
    pub sign: f64,
    /// The target per row.
    pub target: &'a [f64],
}

/// Geometric grid of `n` points from `lo` to `hi`.
fn grid(lo: f64, hi: f64, n: usize) -> Vec<f64> {
    (0..n)
        .map(|k| lo * (hi / lo).powf(k as f64 / (n - 1) as f64))
        .collect()
}

/// The six linear columns for rates (b1, b2) at row `i`.
fn columns(r: &SideRows<'_>, i: usize, b1: f64, b2: f64) -> [f64; 6] {
    let w = r.velocity[i];
    let s = r.sign * w.signum();
    [
        r.current[i],
        r.acceleration[i],
        r.sign * w,
        s,
        s * (-b1 * w.abs()).exp(),
        s * (1.0 - (-b2 * w.abs()).exp()),
    ]
}

/// The normal equations of the rows, cached so that a grid of rates costs one pass per rate
/// value (for the columns of each exponential) and one multiply-add pass per pair (their
/// cross product), not a full pass with two exponentials per row and pair.
struct Projector<'a> {
    rows: &'a SideRows<'a>,
    /// |w| and the signed direction `sign sign(w)` per row.
    speed: Vec<f64>,
    direction: Vec<f64>,
    /// X'X and X'y of the four fixed columns (current, acceleration, c, a0), and y'y.
    fixed_gram: [[f64; 4]; 4],
    fixed_rhs: [f64; 4],
    yy: f64,
}

/// Per rate: e^{-b|w|} per row, its cross products with the fixed columns and with y, and
/// its sum and sum of squares (the exponential columns are `s e` and `s (1 - e)`).
struct RateColumn {
    e: Vec<f64>,
    /// sum s e x_j for the fixed columns, sum s e y, sum e^2, sum e.
    with_fixed: [f64; 4],
    with_y: f64,
    squares: f64,
    sum: f64,
    /// sum s x_j (fixed) and sum s y: for the `1 - e` column.
    s_with_fixed: [f64; 4],
    s_with_y: f64,
}

impl<'a> Projector<'a> {
    fn new(rows: &'a SideRows<'a>) -> Self {
        let n = rows.target.len();
        let speed: Vec<f64> = rows.velocity.iter().map(|w| w.abs()).collect();
        let direction: Vec<f64> = rows
            .velocity
            .iter()
            .map(|w| rows.sign * w.signum())
            .collect();
        let mut fixed_gram = [[0.0; 4]; 4];
        let mut fixed_rhs = [0.0; 4];
        let mut yy = 0.0;
        for i in 0..n {
            let x = Self::fixed(rows, &direction, i);
            let y = rows.target[i];
            for a in 0..4 {
                fixed_rhs[a] += x[a] * y;
                for b in 0..4 {
                    fixed_gram[a][b] += x[a] * x[b];
                }
            }
            yy += y * y;
        }
        Projector {
            rows,
            speed,
            direction,
            fixed_gram,
            fixed_rhs,
            yy,
        }
    }

    fn fixed(rows: &SideRows<'_>, direction: &[f64], i: usize) -> [f64; 4] {
        [
            rows.current[i],
            rows.acceleration[i],
            rows.sign * rows.velocity[i],
            direction[i],
        ]
    }

    fn rate(&self, b: f64) -> RateColumn {
        let mut c = RateColumn {
            e: Vec::with_capacity(self.speed.len()),
            with_fixed: [0.0; 4],
            with_y: 0.0,
            squares: 0.0,
            sum: 0.0,
            s_with_fixed: [0.0; 4],
            s_with_y: 0.0,
        };
        for i in 0..self.speed.len() {
            let e = (-b * self.speed[i]).exp();
            let s = self.direction[i];
            let x = Self::fixed(self.rows, &self.direction, i);
            let y = self.rows.target[i];
            for (j, xj) in x.iter().enumerate() {
                c.with_fixed[j] += s * e * xj;
                c.s_with_fixed[j] += s * xj;
            }
            c.with_y += s * e * y;
            c.s_with_y += s * y;
            // s^2 = 1 (a moving row) or 0 (w = 0 exactly, which the moving mask excludes).
            c.squares += s * s * e * e;
            c.sum += s * s * e;
            c.e.push(e);
        }
        c
    }

    /// Residual sum of squares of the linear solve with the Stribeck column of `one` and the
    /// growth column of `two`, and the solution (Km, I, c, a0, a1, a2).
    fn solve(&self, one: &RateColumn, two: &RateColumn) -> (f64, [f64; 6]) {
        let mut gram = DMatrix::<f64>::zeros(6, 6);
        let mut rhs = DVector::<f64>::zeros(6);
        for a in 0..4 {
            for b in 0..4 {
                gram[(a, b)] = self.fixed_gram[a][b];
            }
            rhs[a] = self.fixed_rhs[a];
            // Column 4: s e1. Column 5: s (1 - e2).
            gram[(a, 4)] = one.with_fixed[a];
            gram[(a, 5)] = two.s_with_fixed[a] - two.with_fixed[a];
            gram[(4, a)] = gram[(a, 4)];
            gram[(5, a)] = gram[(a, 5)];
        }
        let mut cross = 0.0;
        let mut moving = 0.0;
        for i in 0..one.e.len() {
            let s2 = self.direction[i] * self.direction[i];
            cross += s2 * one.e[i] * two.e[i];
            moving += s2;
        }
        gram[(4, 4)] = one.squares;
        gram[(5, 5)] = moving - 2.0 * two.sum + two.squares;
        gram[(4, 5)] = one.sum - cross;
        gram[(5, 4)] = gram[(4, 5)];
        rhs[4] = one.with_y;
        rhs[5] = two.s_with_y - two.with_y;
        // Scaled to unit diagonal: the columns differ by orders of magnitude.
        let d: Vec<f64> = (0..6)
            .map(|a| {
                let g = gram[(a, a)];
                if g > 0.0 { 1.0 / g.sqrt() } else { 0.0 }
            })
            .collect();
        let scaled = DMatrix::from_fn(6, 6, |a, b| gram[(a, b)] * d[a] * d[b]);
        let b = DVector::from_fn(6, |a, _| rhs[a] * d[a]);
        let Some(solution) = scaled.cholesky().map(|c| c.solve(&b)) else {
            return (f64::INFINITY, [f64::NAN; 6]);
        };
        let p: [f64; 6] = std::array::from_fn(|a| solution[a] * d[a]);
        // rss = y'y - 2 p'X'y + p'X'X p
        let pv = DVector::from_column_slice(&p);
        let rss = self.yy - 2.0 * pv.dot(&rhs) + pv.dot(&(&gram * &pv));
        (rss, p)
    }

    /// The pair (b1, b2) with b1 > b2 of the grids with the smallest residual.
    fn best(&self, b1s: &[f64], b2s: &[f64]) -> Option<(f64, f64, f64)> {
        let ones: Vec<RateColumn> = b1s.iter().map(|b| self.rate(*b)).collect();
        let twos: Vec<RateColumn> = b2s.iter().map(|b| self.rate(*b)).collect();
        let mut best: Option<(f64, f64, f64)> = None;
        for (one, &b1) in ones.iter().zip(b1s) {
            // The law is symmetric under exchanging the two exponentials (with a1 -> -a2,
            // a2 -> -a1 and a0 shifted): the Stribeck drop is the faster one, b1 > b2.
            for (two, &b2) in twos.iter().zip(b2s).filter(|(_, b2)| **b2 < b1) {
                let (rss, _) = self.solve(one, two);
                if rss.is_finite() && best.is_none_or(|(v, _, _)| rss < v) {
                    best = Some((rss, b1, b2));
                }
            }
        }
        best
    }
}

/// Fits the side's balance with the exponential law. `None` when no rate pair gives a
/// solvable system (the logs do not excite the columns).
pub fn fit(r: &SideRows<'_>) -> Option<LawFit> {
    let projector = Projector::new(r);
    // Coarse: Stribeck speeds 5 mrad/s .. 1 rad/s, growth speeds 0.05 .. 10 rad/s.
    let (_, b1, b2) = projector.best(&grid(1.0, 200.0, 16), &grid(0.1, 20.0, 16))?;
    // Fine: a factor 1.42 (one coarse step) either side, 2 % steps.
    let (_, b1, b2) = projector.best(
        &grid(b1 / 1.42, b1 * 1.42, 36),
        &grid(b2 / 1.42, b2 * 1.42, 36),
    )?;
    let (_, p) = projector.solve(&projector.rate(b1), &projector.rate(b2));
    let values = [p[0], p[1], p[2], p[3], p[4], b1, p[5], b2];
    let rows = r.target.len();
    let jacobian = DMatrix::from_fn(rows, 8, |i, j| {
        let x = columns(r, i, b1, b2);
        let w = r.velocity[i].abs();
        let s = r.sign * r.velocity[i].signum();
        match j {
            0..=4 => x[j],
            5 => -p[4] * s * w * (-b1 * w).exp(),
            6 => x[5],
            _ => p[5] * s * w * (-b2 * w).exp(),
        }
    });
    let residual: Vec<f64> = (0..rows)
        .map(|i| {
            let x = columns(r, i, b1, b2);
            r.target[i] - x.iter().zip(&p).map(|(a, b)| a * b).sum::<f64>()
        })
        .collect();
    Some(LawFit {
        values,
        stats: lsq::statistics(&jacobian, &residual),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    const TRUTH: [f64; 8] = [0.037 * 50.0, 0.8, 10.0, 4.0, 1.0, 20.0, 1.1, 2.0];

    /// Rows at speeds from 2 mrad/s to 3 rad/s both ways (as a map experiment's constant-speed
    /// holds give), noise-free, of the law `TRUTH`: (current, acceleration, velocity, target).
    fn synthetic() -> [Vec<f64>; 4] {
        let truth = TRUTH;
        let sign = -1.0;
        let mut current = Vec::new();
        let mut acceleration = Vec::new();
        let mut velocity = Vec::new();
        let mut target = Vec::new();
        let mut k = 0u32;
        for speed in grid(0.002, 3.0, 60) {
            for direction in [-1.0, 1.0] {
                for _ in 0..20 {
                    k += 1;
                    let w = direction * speed;
                    // Varying current and acceleration so that Km and I are determined.
                    let i = 2.0 * (0.37 * k as f64).sin();
                    let a = 3.0 * (0.11 * k as f64).cos();
                    let x0 = -sign * 50.0 * i;
                    let x1 = sign * a;
                    let s = sign * w.signum();
                    let law = truth[3]
                        + truth[4] * (-truth[5] * w.abs()).exp()
                        + truth[6] * (1.0 - (-truth[7] * w.abs()).exp());
                    let y = truth[0] / 50.0 * x0 + truth[1] * x1 + truth[2] * sign * w + s * law;
                    current.push(x0);
                    acceleration.push(x1);
                    velocity.push(w);
                    target.push(y);
                }
            }
        }
        [current, acceleration, velocity, target]
    }

    /// The fit returns the law.
    #[test]
    fn a_known_law_is_recovered_from_steady_speeds() {
        let truth = TRUTH;
        let sign = -1.0;
        let [current, acceleration, velocity, target] = synthetic();
        let rows = SideRows {
            current: &current,
            acceleration: &acceleration,
            velocity: &velocity,
            sign,
            target: &target,
        };
        let f = fit(&rows).unwrap();
        let expected = [
            truth[0] / 50.0,
            truth[1],
            truth[2],
            truth[3],
            truth[4],
            truth[5],
            truth[6],
            truth[7],
        ];
        for (j, (v, t)) in f.values.iter().zip(expected).enumerate() {
            // The grid's 2 % step bounds the rates; the linear parameters follow them.
            assert!((v - t).abs() <= 0.02 * t.abs(), "parameter {j}: {v} vs {t}");
        }
        assert!(f.stats.determined.iter().all(|d| *d));
    }

    /// The cached normal equations give what a plain least-squares fit of the six columns
    /// gives, at rates away from the truth (a nonzero residual).
    #[test]
    fn the_cached_projection_equals_a_plain_fit() {
        let [current, acceleration, velocity, mut target] = synthetic();
        for (k, y) in target.iter_mut().enumerate() {
            *y += 0.05 * (1.7 * k as f64).sin();
        }
        let rows = SideRows {
            current: &current,
            acceleration: &acceleration,
            velocity: &velocity,
            sign: -1.0,
            target: &target,
        };
        let (b1, b2) = (13.0, 3.1);
        let projector = Projector::new(&rows);
        let (rss, p) = projector.solve(&projector.rate(b1), &projector.rate(b2));
        let cols: Vec<Vec<f64>> = (0..6)
            .map(|j| {
                (0..target.len())
                    .map(|i| columns(&rows, i, b1, b2)[j])
                    .collect()
            })
            .collect();
        let plain = lsq::fit(&cols, &target);
        for (a, b) in p.iter().zip(&plain.values) {
            assert!((a - b).abs() <= 1e-6 * b.abs().max(1.0), "{a} vs {b}");
        }
        let plain_rss = plain.stats.residual_rms.powi(2) * target.len() as f64;
        assert!(
            (rss - plain_rss).abs() <= 1e-6 * plain_rss,
            "{rss} vs {plain_rss}"
        );
    }
}
