//! The gait's Fourier series (bench model facts, section 5): the coefficients of the knee
//! angle and torque, their precomputed weights, and the series' value, derivatives and
//! integral at an instant, from the harmonics shared by both channels.

use std::f64::consts::TAU;

use super::Shape;

/// Number of harmonics of the gait series.
pub const HARMONICS: usize = 8;

/// Fourier coefficients (a_n, b_n), n = 0..=8, of the normalised knee angle
/// (from `shared/data/gait-fourier.csv`, columns `angle_a`, `angle_b`).
pub const ANGLE_SERIES: [(f64, f64); HARMONICS + 1] = [
    (0.3884, 0.0),
    (-0.07603, -0.326),
    (-0.1943, 0.1141),
    (0.008267, 0.07186),
    (-0.001994, 0.005746),
    (-0.004342, 0.01286),
    (0.003985, 0.002147),
    (-0.0005321, 0.0009002),
    (0.001249, 0.0008244),
];

/// Fourier coefficients (a_n, b_n) of the normalised knee torque
/// (columns `torque_a`, `torque_b` of the same file).
pub const TORQUE_SERIES: [(f64, f64); HARMONICS + 1] = [
    (-0.1507, 0.0),
    (-0.221, -0.3977),
    (0.04218, -0.9473),
    (0.4108, 0.03786),
    (0.01918, -0.1118),
    (0.09149, 0.06741),
    (0.002324, -0.01246),
    (0.002467, 0.01965),
    (0.006651, 0.004735),
];

/// The peak of the applied external (ground-reaction) torque of the normalised gait, i.e. the
/// largest value of `-TORQUE_SERIES` (its minimum -1.93555 lies at 13.3 % of the cycle; the
/// positive peak is +1.0020). The bench scaled its gait "such that the maximum applied external
/// torque is 9 N m", so the gait's torque series is divided by this before `kneeTorqueAmplitude`
/// scales it (see the `gait` module's docs, "Torque scaling"). Checked against the series in the tests.
pub const TORQUE_EXTERNAL_PEAK: f64 = 1.935_554_607_509_505_4;

/// The Fourier series f(x) = a0 + Σ a_n cos(nωx) + b_n sin(nωx), ω = 2π, x = t/period.
pub fn fourier(series: &[(f64, f64); HARMONICS + 1], t: f64, period: f64) -> Shape {
    fourier_with(
        &SeriesWeights::of(series),
        &Harmonics::at(t, period),
        t,
        period,
    )
}

/// `sin(n x)` and `cos(n x)` of the harmonics n = 1..=[`HARMONICS`] at one instant,
/// `x = 2 pi t / T`: shared by the series of both channels. Kept as two vectors (index n - 1)
/// because every output of a series is a weighted sum of them ([`SeriesWeights`]).
#[derive(Debug, Clone, Copy)]
pub struct Harmonics {
    /// sin(n x), index n - 1.
    pub sin: [f64; HARMONICS],
    /// cos(n x), index n - 1.
    pub cos: [f64; HARMONICS],
}

impl Harmonics {
    /// From one `sin_cos` (the angle reduced to one period first so the products start
    /// accurate): the error grows like n * 1e-16, far below the series' own accuracy for
    /// [`HARMONICS`] terms.
    pub fn at(t: f64, period: f64) -> Self {
        Self::at_cycles(t / period)
    }

    /// The same at `cycles = t / T` (callers that have `1 / T` save a division). The
    /// harmonics come from products of lower ones in a tree (2 = 1*1, 3 = 2*1, 4 = 2*2, then
    /// 5..8 = 4*1..4*4), three products deep instead of seven in a chain: the error stays at a
    /// few ulp and the evaluation does not wait on one long dependency chain.
    pub fn at_cycles(cycles: f64) -> Self {
        // x - floor(x) rather than rem_euclid, which is an fmod call.
        let phase = cycles - cycles.floor();
        let (sin1, cos1) = (TAU * phase).sin_cos();
        let mut h = Self {
            sin: [0.0; HARMONICS],
            cos: [1.0; HARMONICS],
        };
        h.sin[0] = sin1;
        h.cos[0] = cos1;
        // (sin a, cos a) * (sin b, cos b) = (sin(a + b), cos(a + b)), harmonics by number.
        let mut n = 2;
        while n <= HARMONICS {
            // Harmonics n..2n-1 from the one at n/2 (a power of two) and those below it.
            let half = n / 2 - 1;
            let (sh, ch) = (h.sin[half], h.cos[half]);
            let (sb, cb) = (2.0 * sh * ch, ch * ch - sh * sh);
            h.sin[n - 1] = sb;
            h.cos[n - 1] = cb;
            for k in 1..n.min(HARMONICS + 1 - n) {
                let (sk, ck) = (h.sin[k - 1], h.cos[k - 1]);
                h.sin[n + k - 1] = sb * ck + cb * sk;
                h.cos[n + k - 1] = cb * ck - sb * sk;
            }
            n *= 2;
        }
        h
    }
}

/// Weights of the two harmonic vectors of [`Harmonics`] for one output of a series.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Weights {
    /// Weight of sin(n x), index n - 1.
    pub sin: [f64; HARMONICS],
    /// Weight of cos(n x), index n - 1.
    pub cos: [f64; HARMONICS],
}

// `Weights::of` and `SeriesWeights::of` pair harmonic n with n + 4.
const _: () = assert!(
    HARMONICS == 8,
    "the partial sums are written for 8 harmonics"
);

impl Weights {
    /// `Σ sin_n w_sin,n + cos_n w_cos,n` in four independent partial sums, harmonics n and
    /// n + 4 in one (the additions do not wait on one another, and neighbouring lanes pack
    /// into one vector operation).
    #[inline(always)]
    pub(super) fn of(&self, h: &Harmonics) -> f64 {
        let term = |n: usize| self.sin[n] * h.sin[n] + self.cos[n] * h.cos[n];
        let lanes: [f64; 4] = std::array::from_fn(|n| term(n) + term(n + 4));
        (lanes[0] + lanes[1]) + (lanes[2] + lanes[3])
    }
}

/// A Fourier series rearranged so that each output is one weighted sum of the harmonics
/// (`k = 2 pi / T`, `n` the harmonic number, `(a_n, b_n)` the coefficients):
/// - value `a_0 + Σ a_n cos + b_n sin`;
/// - rate `k Σ n (b_n cos - a_n sin)`;
/// - acceleration `-k² Σ n² (a_n cos + b_n sin)`;
/// - jerk `-k³ Σ n³ (b_n cos - a_n sin)`;
/// - integral from 0 `a_0 t + (1/k) [Σ (a_n sin - b_n cos) / n + Σ b_n / n]`.
///
/// The weights are the coefficients times the powers of n (computed once per series, at
/// compile time for the gait's two), so no output re-multiplies them per step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SeriesWeights {
    /// a_0.
    pub mean: f64,
    /// Of the value.
    pub value: Weights,
    /// Of the rate, before the factor k.
    pub rate: Weights,
    /// Of the acceleration, before the factor k².
    pub acceleration: Weights,
    /// Of the jerk, before the factor k³.
    pub jerk: Weights,
    /// Of the integral, before the factor 1/k.
    pub integral: Weights,
    /// Σ b_n / n: the integral's constant, before the factor 1/k.
    pub integral_constant: f64,
}

impl SeriesWeights {
    /// The weights of `series` ((a_n, b_n), n = 0..=[`HARMONICS`]).
    pub const fn of(series: &[(f64, f64); HARMONICS + 1]) -> Self {
        let zero = Weights {
            sin: [0.0; HARMONICS],
            cos: [0.0; HARMONICS],
        };
        let mut w = Self {
            mean: series[0].0,
            value: zero,
            rate: zero,
            acceleration: zero,
            jerk: zero,
            integral: zero,
            integral_constant: 0.0,
        };
        let mut i = 0;
        while i < HARMONICS {
            let (a, b) = series[i + 1];
            let n = (i + 1) as f64;
            w.value.sin[i] = b;
            w.value.cos[i] = a;
            w.rate.sin[i] = -n * a;
            w.rate.cos[i] = n * b;
            w.acceleration.sin[i] = -n * n * b;
            w.acceleration.cos[i] = -n * n * a;
            w.jerk.sin[i] = n * n * n * a;
            w.jerk.cos[i] = -n * n * n * b;
            w.integral.sin[i] = a / n;
            w.integral.cos[i] = -b / n;
            i += 1;
        }
        // Minus the cosine weights summed exactly as `Weights::of` sums them at cos = 1, so
        // the integral is exactly 0 at t = 0 (and at every whole cycle).
        let c = &w.integral.cos;
        w.integral_constant = -(((c[0] + c[4]) + (c[1] + c[5])) + ((c[2] + c[6]) + (c[3] + c[7])));
        w
    }
}

/// The knee-angle series' weights.
pub const ANGLE_WEIGHTS: SeriesWeights = SeriesWeights::of(&ANGLE_SERIES);
/// The knee-torque series' weights.
pub const TORQUE_WEIGHTS: SeriesWeights = SeriesWeights::of(&TORQUE_SERIES);

/// [`fourier`] from precomputed [`Harmonics`] of the same `t` and `period` and the series'
/// [`SeriesWeights`] (inlined, so the two channels' sums can overlap).
#[inline(always)]
pub fn fourier_with(weights: &SeriesWeights, harmonics: &Harmonics, t: f64, period: f64) -> Shape {
    let sums = [
        weights.value.of(harmonics),
        weights.rate.of(harmonics),
        weights.acceleration.of(harmonics),
        weights.jerk.of(harmonics),
        weights.integral.of(harmonics),
    ];
    fourier_from_sums(weights, sums, t, period)
}

/// [`fourier_with`] from its five weighted sums (value, rate, acceleration, jerk and
/// integral, each [`Weights::of`] the harmonics), however they were computed.
#[inline(always)]
pub(super) fn fourier_from_sums(
    weights: &SeriesWeights,
    sums: [f64; 5],
    t: f64,
    period: f64,
) -> Shape {
    let [value, rate, acceleration, jerk, integral] = sums;
    let k = TAU / period;
    let inverse_k = period * (1.0 / TAU);
    Shape {
        value: weights.mean + value,
        d1: k * rate,
        d2: k * k * acceleration,
        d3: k * k * k * jerk,
        integral: weights.mean * t + inverse_k * (integral + weights.integral_constant),
    }
}

/// Value and rate of the series only (what the torque channel uses): `(f, df/dt)`.
#[inline]
pub fn fourier_rate(weights: &SeriesWeights, harmonics: &Harmonics, period: f64) -> (f64, f64) {
    fourier_rate_from_sums(
        weights,
        [weights.value.of(harmonics), weights.rate.of(harmonics)],
        period,
    )
}

/// [`fourier_rate`] from its two weighted sums (value and rate).
#[inline(always)]
pub(super) fn fourier_rate_from_sums(
    weights: &SeriesWeights,
    [value, rate]: [f64; 2],
    period: f64,
) -> (f64, f64) {
    (weights.mean + value, TAU / period * rate)
}
