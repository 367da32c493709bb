//! The harmonic drive's loss surface (bench-model.md section 2, friction model 3), fitted by
//! linear least squares when the logs were recorded with `frictionModel` = HdLossSurface.
//!
//! With that law the actuation side's balance is
//!
//! ```text
//! tau - tau0 = Km1 (i_HD i1) - I1 a1 - c1 w1 + S(x, y)
//! S(x, y) = sum p_ij x^i y^j   (p of the positive set for w1 >= 0, of the negative set below)
//! ```
//!
//! with `x = i_RED Km2 i2` the load torque at the output (Km2 as the load side's regression
//! found it, else the prior) and `y = w1`, both clamped to the plant's box (`hdSurfaceMaxSpeed`,
//! `hdSurfaceMinLoadTorque`, `hdSurfaceMaxLoadTorque`) as the plant clamps them: the fitted
//! function is the twin's. The model is linear in Km1, I1 and the 2 x 21 coefficients; they are
//! fitted together over every log's moving rows (one row in [`STRIDE`]: 44 columns over minutes
//! of logs; neighbouring rows carry the same information after smoothing, and the intervals'
//! inflation uses the strided residuals).
//!
//! **Smoothing.** The regression smooths the encoder angle, the currents and the torque over
//! its own, narrower window ([`IdentifyConfig::surface_window`](super::IdentifyConfig::surface_window),
//! +-12 samples against the other regressions' +-25). A cubic fit over +-m samples attenuates
//! the second derivative of a sinusoid more than its value: at 3.2 Hz, the top of a Bode sweep,
//! the acceleration by 1.9 % over +-25 samples against 0.02 % for the currents, by 0.45 % over
//! +-12. The other regressions absorb that into I1 and Km1 by a percent, which the refinement
//! then removes; here the surface is the small difference between the test motor's torque
//! (`i_HD Km1 i1`, some 45 N m at 150 deg/s) and the shaft's, so a percent on Km1 is four on the
//! surface, and the surface is not refined. The map's steady rows need no heavy smoothing.
//!
//! **What is not separable.** `c1 w1` is the sum of the two sets' `p01` columns: c1 is held at
//! its prior and the surface's `p01` carries the viscous loss beyond it (reported as such). In
//! the steady state Km1 is a polynomial combination of the surface's columns too: it is fixed
//! by the accelerating rows (a Bode sweep of the test motor).
//!
//! **Coefficients the experiment does not excite.** The map holds a few load torques (5 by
//! default) at speeds up to 150 deg/s: with `n` distinct load torques a polynomial in `x` of
//! degree `n` or more is not fixed by them (`x^5` through 5 levels is a combination of
//! `1 ... x^4`), and the noise on the measured `x` only makes such a column nearly, not exactly,
//! a combination of the others. Such a coefficient is reported as not identifiable and held at
//! its prior, and the others are fitted again with it held (backward elimination, one
//! coefficient at a time, the least determined first), so that the written surface is one
//! consistent fit.
//!
//! **Intervals that account for the held coefficients.** A coefficient held at its prior biases
//! the free ones it is correlated with by `S (p_true - p_prior)`, `S = (X_F^T X_F)^-1 X_F^T X_H`
//! the sensitivities of the free estimates to the held ones. An interval conditional on the held
//! values would claim a precision the fit does not have (the truth outside it). The experiment
//! says nothing about a held coefficient, so its prior is taken as uncertain by its own
//! magnitude ([`HELD_PRIOR_RELATIVE_STD`]), and every free estimate's reported interval counts
//! the noise's variance plus `sum_h (S_nh p_h)^2`. A free estimate whose interval so widened
//! stays within [`IdentifyConfig::max_relative_ci`](super::IdentifyConfig::max_relative_ci) of
//! its value is identified; one that leans on the held values beyond it is reported as
//! [`Status::Conditional`]: written to the set (the fitted surface is one function, and its
//! values at the map's points are what the logs determine) but not claimed individually, nor
//! refined. The held set is what the design does not determine (the elimination above, on the
//! noise's intervals); more distinct load torques (`kneebench experiment map --torques`, 7 over
//! the gait's range) determine the whole surface.

use super::log::Log;
use super::{Estimate, Quantity, Regression, Status, lsq, q, regression};

/// One row in this many enters the surface's regression.
pub const STRIDE: usize = 5;

/// The loss surface's term table and polynomial, shared with the `fmu` crate by including its
/// file: the exponents the plant evaluates are the ones the regression's columns use. (The
/// harness reads only the term table.)
#[path = "../../../fmu/src/models/bench/hd_loss.rs"]
#[allow(dead_code)]
mod hd_loss;

/// Exponents (i, j) of the terms `x^i y^j`, in the row order of `hd-loss-surface.csv` (the
/// FMU's `hdLossPositiveSpeed[k]` is the term `k - 1`): the plant's own table.
pub const TERMS: [(u8, u8); 21] = hd_loss::TERM_EXPONENTS;

const EXCITE: &str = "steady motion over the load torques and speeds of the gait's range, both ways, with the loss-surface law active: `kneebench experiment map` (more `--torques` levels for the terms of high order in x)";

/// The 2 x 21 coefficients: positive speed, then negative speed.
pub const COEFFICIENTS: [Quantity; 42] = [
    q(Some("hdLossPositiveSpeed[1]"), "p00+", "N.m", EXCITE),
    q(Some("hdLossPositiveSpeed[2]"), "p10+", "1", EXCITE),
    q(Some("hdLossPositiveSpeed[3]"), "p01+", "N.m.s/rad", EXCITE),
    q(Some("hdLossPositiveSpeed[4]"), "p20+", "(N.m)^-1", EXCITE),
    q(Some("hdLossPositiveSpeed[5]"), "p11+", "s/rad", EXCITE),
    q(
        Some("hdLossPositiveSpeed[6]"),
        "p02+",
        "N.m.(s/rad)^2",
        EXCITE,
    ),
    q(Some("hdLossPositiveSpeed[7]"), "p30+", "(N.m)^-2", EXCITE),
    q(
        Some("hdLossPositiveSpeed[8]"),
        "p21+",
        "(N.m)^-1.s/rad",
        EXCITE,
    ),
    q(Some("hdLossPositiveSpeed[9]"), "p12+", "(s/rad)^2", EXCITE),
    q(
        Some("hdLossPositiveSpeed[10]"),
        "p03+",
        "N.m.(s/rad)^3",
        EXCITE,
    ),
    q(Some("hdLossPositiveSpeed[11]"), "p40+", "(N.m)^-3", EXCITE),
    q(
        Some("hdLossPositiveSpeed[12]"),
        "p31+",
        "(N.m)^-2.s/rad",
        EXCITE,
    ),
    q(
        Some("hdLossPositiveSpeed[13]"),
        "p22+",
        "(N.m)^-1.(s/rad)^2",
        EXCITE,
    ),
    q(Some("hdLossPositiveSpeed[14]"), "p13+", "(s/rad)^3", EXCITE),
    q(
        Some("hdLossPositiveSpeed[15]"),
        "p04+",
        "N.m.(s/rad)^4",
        EXCITE,
    ),
    q(Some("hdLossPositiveSpeed[16]"), "p50+", "(N.m)^-4", EXCITE),
    q(
        Some("hdLossPositiveSpeed[17]"),
        "p41+",
        "(N.m)^-3.s/rad",
        EXCITE,
    ),
    q(
        Some("hdLossPositiveSpeed[18]"),
        "p32+",
        "(N.m)^-2.(s/rad)^2",
        EXCITE,
    ),
    q(
        Some("hdLossPositiveSpeed[19]"),
        "p23+",
        "(N.m)^-1.(s/rad)^3",
        EXCITE,
    ),
    q(Some("hdLossPositiveSpeed[20]"), "p14+", "(s/rad)^4", EXCITE),
    q(
        Some("hdLossPositiveSpeed[21]"),
        "p05+",
        "N.m.(s/rad)^5",
        EXCITE,
    ),
    q(Some("hdLossNegativeSpeed[1]"), "p00-", "N.m", EXCITE),
    q(Some("hdLossNegativeSpeed[2]"), "p10-", "1", EXCITE),
    q(Some("hdLossNegativeSpeed[3]"), "p01-", "N.m.s/rad", EXCITE),
    q(Some("hdLossNegativeSpeed[4]"), "p20-", "(N.m)^-1", EXCITE),
    q(Some("hdLossNegativeSpeed[5]"), "p11-", "s/rad", EXCITE),
    q(
        Some("hdLossNegativeSpeed[6]"),
        "p02-",
        "N.m.(s/rad)^2",
        EXCITE,
    ),
    q(Some("hdLossNegativeSpeed[7]"), "p30-", "(N.m)^-2", EXCITE),
    q(
        Some("hdLossNegativeSpeed[8]"),
        "p21-",
        "(N.m)^-1.s/rad",
        EXCITE,
    ),
    q(Some("hdLossNegativeSpeed[9]"), "p12-", "(s/rad)^2", EXCITE),
    q(
        Some("hdLossNegativeSpeed[10]"),
        "p03-",
        "N.m.(s/rad)^3",
        EXCITE,
    ),
    q(Some("hdLossNegativeSpeed[11]"), "p40-", "(N.m)^-3", EXCITE),
    q(
        Some("hdLossNegativeSpeed[12]"),
        "p31-",
        "(N.m)^-2.s/rad",
        EXCITE,
    ),
    q(
        Some("hdLossNegativeSpeed[13]"),
        "p22-",
        "(N.m)^-1.(s/rad)^2",
        EXCITE,
    ),
    q(Some("hdLossNegativeSpeed[14]"), "p13-", "(s/rad)^3", EXCITE),
    q(
        Some("hdLossNegativeSpeed[15]"),
        "p04-",
        "N.m.(s/rad)^4",
        EXCITE,
    ),
    q(Some("hdLossNegativeSpeed[16]"), "p50-", "(N.m)^-4", EXCITE),
    q(
        Some("hdLossNegativeSpeed[17]"),
        "p41-",
        "(N.m)^-3.s/rad",
        EXCITE,
    ),
    q(
        Some("hdLossNegativeSpeed[18]"),
        "p32-",
        "(N.m)^-2.(s/rad)^2",
        EXCITE,
    ),
    q(
        Some("hdLossNegativeSpeed[19]"),
        "p23-",
        "(N.m)^-1.(s/rad)^3",
        EXCITE,
    ),
    q(Some("hdLossNegativeSpeed[20]"), "p14-", "(s/rad)^4", EXCITE),
    q(
        Some("hdLossNegativeSpeed[21]"),
        "p05-",
        "N.m.(s/rad)^5",
        EXCITE,
    ),
];

/// The plant's clamping box and the load side's torque per ampere.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfaceBox {
    /// `hdSurfaceMaxSpeed` \[rad/s\].
    pub max_speed: f64,
    /// `hdSurfaceMinLoadTorque` [N m].
    pub min_load_torque: f64,
    /// `hdSurfaceMaxLoadTorque` [N m].
    pub max_load_torque: f64,
    /// `i_RED Km2` [N m/A].
    pub load_torque_per_ampere: f64,
}

impl SurfaceBox {
    /// The 42 regressors of a row (load current `i2` \[A\], speed `w1` \[rad/s\]): the terms at
    /// the clamped arguments in the set of the speed's sign, zeros in the other.
    pub fn columns(&self, i2: f64, w1: f64) -> [f64; 42] {
        let x =
            (self.load_torque_per_ampere * i2).clamp(self.min_load_torque, self.max_load_torque);
        let y = w1.clamp(-self.max_speed, self.max_speed);
        let mut out = [0.0; 42];
        let offset = if w1 >= 0.0 { 0 } else { 21 };
        for (k, &(i, j)) in TERMS.iter().enumerate() {
            out[offset + k] = x.powi(i32::from(i)) * y.powi(i32::from(j));
        }
        out
    }
}

/// The actuation side's regression under the loss-surface law: estimates of Km1, I1, c1 (held),
/// Tfr1 (not used) and the 42 coefficients, in that order, and the regression's quality.
/// `rows` yields the (log, row) pairs to use; `prior` gives a quantity's prior value.
#[allow(clippy::too_many_arguments)]
pub(super) fn fit_actuation(
    logs: &[Log],
    rows: &dyn Fn(usize, usize) -> bool,
    actuation: &[Quantity; 4],
    surface_box: &SurfaceBox,
    i_hd: f64,
    tau0: f64,
    window: usize,
    prior: &dyn Fn(&Quantity) -> f64,
    max_relative_ci: f64,
    identified_relative_ci: f64,
) -> Option<(Vec<Estimate>, Regression)> {
    let c1 = prior(&actuation[2]);
    // Columns: Km1, I1, then the coefficients.
    let mut columns: Vec<Vec<f64>> = vec![Vec::new(); 44];
    let mut target = Vec::new();
    for (k, l) in logs.iter().enumerate() {
        // The signals smoothed over this regression's own window (see `IdentifyConfig::
        // surface_window`), the torque as the currents are (the same cubic fit): a raw target
        // against smoothed currents would read the fit's attenuation of the faster components
        // as a torque constant too large.
        let smooth = |x: &[f64]| super::smooth::derivatives(x, l.dt, window);
        let [_, velocity, acceleration] = smooth(&l.angle[0]);
        let [test_current, _, _] = smooth(&l.current[0]);
        let [load_current, _, _] = smooth(&l.current[1]);
        let [torque, _, _] = smooth(&l.torque);
        for i in (0..l.time.len()).step_by(STRIDE) {
            let row = [
                velocity[i],
                acceleration[i],
                test_current[i],
                load_current[i],
                torque[i],
            ];
            if !(l.usable[i] && rows(k, i) && row.iter().all(|v| v.is_finite())) {
                continue;
            }
            columns[0].push(i_hd * test_current[i]);
            columns[1].push(-acceleration[i]);
            for (c, v) in columns[2..]
                .iter_mut()
                .zip(surface_box.columns(load_current[i], velocity[i]))
            {
                c.push(v);
            }
            target.push(torque[i] - tau0 + c1 * velocity[i]);
        }
    }
    if target.len() < 100 {
        return None;
    }
    let priors: Vec<f64> = COEFFICIENTS.iter().map(prior).collect();
    let gram = Gram::new(&columns);
    // Backward elimination: `held[k]` holds coefficient k at its prior.
    let mut held = [false; 42];
    let fit = loop {
        let free: Vec<usize> = (0..44).filter(|&c| c < 2 || !held[c - 2]).collect();
        let y: Vec<f64> = (0..target.len())
            .map(|r| {
                target[r]
                    - (0..42)
                        .filter(|&k| held[k])
                        .map(|k| priors[k] * columns[k + 2][r])
                        .sum::<f64>()
            })
            .collect();
        let cols: Vec<&[f64]> = free.iter().map(|&c| columns[c].as_slice()).collect();
        let f = lsq::fit(&cols, &y);
        // The least determined coefficient: not determined, or the widest relative interval
        // beyond the limit (the noise's: what the design leaves undetermined).
        let worst = free
            .iter()
            .enumerate()
            .filter(|&(_, &c)| c >= 2)
            .map(|(n, &c)| {
                let ci = 1.96 * f.stats.std[n];
                let relative = if f.stats.determined[n] && ci.is_finite() {
                    ci / f.values[n].abs()
                } else {
                    f64::INFINITY
                };
                (c - 2, relative)
            })
            .filter(|&(_, r)| r.is_nan() || r > max_relative_ci)
            .max_by(|a, b| a.1.total_cmp(&b.1));
        match worst {
            Some((k, _)) => held[k] = true,
            None => break (free, f),
        }
    };
    let (free, f) = fit;
    let half_width = half_widths(&gram, &free, &held, &priors, &f);
    let at = |c: usize| free.iter().position(|&x| x == c);
    let estimate = |quantity: Quantity, c: usize| {
        let prior_value = prior(&quantity);
        match at(c) {
            Some(n) => {
                let (value, ci) = (f.values[n], half_width[n]);
                let noise_ci = 1.96 * f.stats.std[n];
                let status = if !f.stats.determined[n] {
                    Status::NotIdentifiable(
                        "its regressor is not excited by these logs, or is a combination of the others"
                            .into(),
                    )
                } else if c < 2 && (noise_ci.is_nan() || noise_ci > max_relative_ci * value.abs()) {
                    Status::NotIdentifiable(format!(
                        "its 95 % interval (+-{}) is wider than {} % of the estimate",
                        super::fmt(noise_ci),
                        100.0 * max_relative_ci
                    ))
                } else if c < 2 && (ci.is_nan() || ci > max_relative_ci * value.abs()) {
                    Status::Conditional(format!(
                        "fitted with the coefficients the map does not excite held at their priors: its 95 % interval is +-{} given them, +-{} counting their uncertainty ({} % of each), wider than {} % of the estimate",
                        super::fmt(noise_ci),
                        super::fmt(ci),
                        100.0 * HELD_PRIOR_RELATIVE_STD,
                        100.0 * max_relative_ci
                    ))
                } else if c >= 2 && (ci.is_nan() || ci > identified_relative_ci * value.abs()) {
                    Status::Conditional(format!(
                        "fitted with the others (those the map does not excite held at their priors), but not within {} % on its own: its 95 % interval is +-{} from the noise, +-{} counting the held coefficients' uncertainty ({} % of each)",
                        100.0 * identified_relative_ci,
                        super::fmt(noise_ci),
                        super::fmt(ci),
                        100.0 * HELD_PRIOR_RELATIVE_STD
                    ))
                } else {
                    Status::Identified
                };
                Estimate {
                    quantity,
                    prior: prior_value,
                    linear: value,
                    linear_ci: ci,
                    refined: None,
                    status,
                }
            }
            None => Estimate::not_identifiable(
                quantity,
                prior_value,
                "the map's box does not excite it apart from the others (not determined, or its 95 % interval is wider than the limit); held at its prior while the other coefficients were fitted",
            ),
        }
    };
    let mut estimates = vec![estimate(actuation[0], 0), estimate(actuation[1], 1)];
    estimates.push(Estimate::not_identifiable(actuation[2], c1, "under the loss-surface law c1 w1 is the sum of the surface's p01 columns: held at its prior, the surface's p01 carries the rest of the viscous loss"));
    estimates.push(Estimate::not_identifiable(
        actuation[3],
        prior(&actuation[3]),
        "not used by the loss-surface law the logs were recorded with",
    ));
    for (k, quantity) in COEFFICIENTS.iter().enumerate() {
        estimates.push(estimate(*quantity, k + 2));
    }
    let labels: Vec<Quantity> = free
        .iter()
        .map(|&c| {
            if c < 2 {
                actuation[c]
            } else {
                COEFFICIENTS[c - 2]
            }
        })
        .collect();
    let r = regression(
        "actuation side (inverse dynamics, loss surface)",
        "N.m",
        &labels,
        &f,
    );
    Some((estimates, r))
}

/// Relative standard uncertainty of a held coefficient's prior: the experiment says nothing
/// about it, so it is taken as uncertain by its own magnitude (one standard deviation = 100 %
/// of the prior). A truth within a few tens of percent of the prior is then well inside the
/// widened intervals; a prior of zero adds nothing (no scale to go by).
pub const HELD_PRIOR_RELATIVE_STD: f64 = 1.0;

/// The Gram matrix `X^T X` of all 44 columns (Km1, I1, the coefficients), computed once: the
/// sensitivities of the free estimates to the held coefficients are solved from its blocks.
struct Gram {
    g: Vec<Vec<f64>>,
}

impl Gram {
    fn new(columns: &[Vec<f64>]) -> Self {
        let p = columns.len();
        let mut g = vec![vec![0.0; p]; p];
        for a in 0..p {
            for b in a..p {
                let v: f64 = columns[a].iter().zip(&columns[b]).map(|(x, y)| x * y).sum();
                g[a][b] = v;
                g[b][a] = v;
            }
        }
        Gram { g }
    }

    /// `S = (X_F^T X_F)^-1 X_F^T X_H`: how far each free estimate moves per unit of each held
    /// coefficient (`free.len() x held.len()`); `None` when the free columns' block is singular.
    fn sensitivities(&self, free: &[usize], held: &[usize]) -> Option<nalgebra::DMatrix<f64>> {
        use nalgebra::DMatrix;
        let scale = |c: usize| self.g[c][c].sqrt();
        if free.iter().chain(held).any(|&c| scale(c) == 0.0) {
            return None;
        }
        // Column-scaled blocks (the columns differ by orders of magnitude: x^5 against 1).
        let gff = DMatrix::from_fn(free.len(), free.len(), |a, b| {
            self.g[free[a]][free[b]] / (scale(free[a]) * scale(free[b]))
        });
        let gfh = DMatrix::from_fn(free.len(), held.len(), |a, h| {
            self.g[free[a]][held[h]] / (scale(free[a]) * scale(held[h]))
        });
        let s = gff.cholesky()?.solve(&gfh);
        Some(DMatrix::from_fn(free.len(), held.len(), |a, h| {
            s[(a, h)] * scale(held[h]) / scale(free[a])
        }))
    }
}

/// The 95 % half widths of the free estimates (`free` indexes the 44 columns, `held` the 42
/// coefficients): the noise's `1.96 std` widened by the held coefficients' prior uncertainty
/// ([`HELD_PRIOR_RELATIVE_STD`]) propagated through the sensitivities, so that an interval is
/// not conditional on held values that may be wrong. NaN where the fit does not determine the
/// estimate.
fn half_widths(
    gram: &Gram,
    free: &[usize],
    held: &[bool; 42],
    priors: &[f64],
    f: &lsq::LinearFit,
) -> Vec<f64> {
    let noise: Vec<f64> = f.stats.std.iter().map(|s| 1.96 * s).collect();
    let held_columns: Vec<usize> = (0..42).filter(|&k| held[k]).map(|k| k + 2).collect();
    if held_columns.is_empty() || f.stats.determined.iter().any(|d| !d) {
        // Nothing held, or a free coefficient not determined (it is held next: the widths
        // of this fit are not reported).
        return noise;
    }
    let Some(s) = gram.sensitivities(free, &held_columns) else {
        return vec![f64::NAN; free.len()];
    };
    (0..free.len())
        .map(|n| {
            let held_variance: f64 = held_columns
                .iter()
                .enumerate()
                .map(|(h, &c)| (s[(n, h)] * HELD_PRIOR_RELATIVE_STD * priors[c - 2]).powi(2))
                .sum();
            let std = noise[n] / 1.96;
            1.96 * (std * std + held_variance).sqrt()
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::experiment::map::{DEFAULT_SURFACE, LossSurface};

    /// A held coefficient whose column nearly equals a free one's: the free estimate absorbs
    /// the held prior's error (here 20 % of it), far outside its noise-only interval; the
    /// widened interval holds it, and equals `1.96 sqrt(std^2 + (S p_h)^2)` with `S` the
    /// regression of the held column on the free ones.
    #[test]
    fn intervals_count_the_uncertainty_of_the_held_coefficients() {
        let rows = 4000;
        let mut state = 0x2545_f491_4f6c_dd1du64;
        let mut uniform = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        let mut columns: Vec<Vec<f64>> = (0..44)
            .map(|_| (0..rows).map(|_| uniform()).collect())
            .collect();
        // Coefficient 1 (column 3) is coefficient 0's column (column 2) plus a little.
        columns[3] = (0..rows)
            .map(|r| columns[2][r] + 0.05 * uniform())
            .collect();
        let truth: Vec<f64> = (0..44).map(|c| 1.0 + 0.1 * c as f64).collect();
        let y_true: Vec<f64> = (0..rows)
            .map(|r| (0..44).map(|c| truth[c] * columns[c][r]).sum::<f64>() + 1e-3 * uniform())
            .collect();
        let mut held = [false; 42];
        held[1] = true;
        // The held coefficient's prior: the truth is 1.2 times it.
        let mut priors: Vec<f64> = truth[2..].to_vec();
        priors[1] = truth[3] / 1.2;
        let free: Vec<usize> = (0..44).filter(|&c| c != 3).collect();
        let y: Vec<f64> = (0..rows)
            .map(|r| y_true[r] - priors[1] * columns[3][r])
            .collect();
        let cols: Vec<&[f64]> = free.iter().map(|&c| columns[c].as_slice()).collect();
        let f = lsq::fit(&cols, &y);
        let gram = Gram::new(&columns);
        let widened = half_widths(&gram, &free, &held, &priors, &f);
        // Coefficient 0 is free column 2.
        let n = 2;
        let error = (f.values[n] - truth[2]).abs();
        let noise = 1.96 * f.stats.std[n];
        assert!(error > 10.0 * noise, "{error} {noise}");
        assert!(error < widened[n], "{error} {}", widened[n]);
        // S from an independent regression of the held column on the free ones.
        let s = lsq::fit(&cols, &columns[3]).values[n];
        let expected = 1.96 * (f.stats.std[n].powi(2) + (s * priors[1]).powi(2)).sqrt();
        assert!(
            (widened[n] - expected).abs() <= 1e-9 * expected,
            "{} {expected}",
            widened[n]
        );
        // A column independent of the held one (up to the sample's chance correlation, about
        // 1/sqrt(rows)) is widened far less.
        let m = 10;
        assert!(
            widened[m] < 0.1 * widened[n],
            "{} {}",
            widened[m],
            widened[n]
        );
        // Nothing held: the noise's intervals.
        let all: Vec<usize> = (0..44).collect();
        let f = lsq::fit(&columns, &y_true);
        let plain = half_widths(&gram, &all, &[false; 42], &priors, &f);
        for (w, s) in plain.iter().zip(&f.stats.std) {
            assert_eq!(*w, 1.96 * s);
        }
    }

    #[test]
    fn terms_and_names_follow_the_data_file() {
        let surface = LossSurface::parse(DEFAULT_SURFACE).unwrap();
        assert_eq!(surface.terms.len(), 21);
        for (k, &((i, j), _, _)) in surface.terms.iter().enumerate() {
            assert_eq!(TERMS[k], (i as u8, j as u8));
            assert_eq!(COEFFICIENTS[k].label, format!("p{i}{j}+"));
            assert_eq!(COEFFICIENTS[21 + k].label, format!("p{i}{j}-"));
            assert_eq!(
                COEFFICIENTS[k].parameter,
                Some(format!("hdLossPositiveSpeed[{}]", k + 1).as_str())
            );
        }
    }

    #[test]
    fn columns_reproduce_the_surface_with_the_plant_clamping() {
        let surface = LossSurface::parse(DEFAULT_SURFACE).unwrap();
        let b = SurfaceBox {
            max_speed: 2.618,
            min_load_torque: -10.0,
            max_load_torque: 15.0,
            load_torque_per_ampere: 66.0 * 0.114,
        };
        let coefficients: Vec<f64> = surface
            .terms
            .iter()
            .map(|t| t.1)
            .chain(surface.terms.iter().map(|t| t.2))
            .collect();
        for (i2, w1, x, y) in [
            (0.5, 1.0, 0.5 * 7.524, 1.0),
            (-1.0, -2.0, -7.524, -2.0),
            (3.0, 4.0, 15.0, 2.618),
            (-2.0, -3.0, -10.0, -2.618),
        ] {
            let c = b.columns(i2, w1);
            let value: f64 = c.iter().zip(&coefficients).map(|(a, p)| a * p).sum();
            let expected = surface.value(x, y);
            assert!(
                (value - expected).abs() <= 1e-9 * expected.abs().max(1.0),
                "{value} {expected}"
            );
        }
    }
}
