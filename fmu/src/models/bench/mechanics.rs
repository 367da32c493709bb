//! Linear part of the plant: the two-mass shaft plus both armature circuits, and its exact
//! discretisation.
//!
//! Augmented state `z = [theta1, theta2, w1, w2, i1, i2, u1, u2, f1, f2]`: the six physical
//! states followed by the four inputs held constant over a segment (driver input of each motor,
//! friction torque on each body). Within a segment `z' = M z` with a mode-dependent `M`:
//!
//! * a **stuck** body has its velocity row (and so its angle's rate) zeroed;
//! * a motor row is of **voltage** type, `L i' = u - R i - Ke G w` (voltage mode, or a current
//!   loop saturated at the supply: then `u = +-V_supply`), or of **current-loop** type,
//!   `tau_c i' = u - i` (current mode within the supply, and disabled drivers with `u = 0`).
//!
//! Regular sub-steps use `Phi = exp(M h)` and Van Loan Gramians `integral z^T Q z dt` cached per
//! (mode, h). Partial segments (between events) use a local Taylor expansion
//! `z(t0 + s len) = sum_n s^n c_n`, split into pieces short enough to converge; it is exact to
//! rounding and gives the state at any instant cheaply, which is what event location needs.

use super::BenchParameters;
use nalgebra::{SMatrix, SVector};

pub(crate) const THETA1: usize = 0;
pub(crate) const THETA2: usize = 1;
pub(crate) const OMEGA1: usize = 2;
pub(crate) const OMEGA2: usize = 3;
pub(crate) const CURRENT1: usize = 4;
pub(crate) const CURRENT2: usize = 5;
pub(crate) const DRIVE1: usize = 6;
pub(crate) const DRIVE2: usize = 7;
pub(crate) const FRICTION1: usize = 8;
pub(crate) const FRICTION2: usize = 9;
/// Dimension of the augmented state.
pub(crate) const NZ: usize = 10;
/// Number of packed upper-triangle products of `z`.
pub(crate) const NPACK: usize = NZ * (NZ + 1) / 2;

pub(crate) type AugMatrix = SMatrix<f64, NZ, NZ>;
pub(crate) type AugVector = [f64; NZ];

/// Quadratic integrals accumulated per segment, in this order.
pub(crate) const PRODUCTS: [(usize, usize); 6] = [
    (OMEGA1, OMEGA1),
    (OMEGA2, OMEGA2),
    (CURRENT1, CURRENT1),
    (CURRENT2, CURRENT2),
    (CURRENT1, OMEGA1),
    (CURRENT2, OMEGA2),
];

/// Integrals of one segment: the six products of [`PRODUCTS`] and the two currents.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub(crate) struct SegmentIntegrals {
    pub products: [f64; 6],
    pub current1: f64,
    pub current2: f64,
}

/// Mode of the linear system.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct LinearMode {
    /// Body held by static friction (`w = 0`).
    pub stuck: [bool; 2],
    /// Motor row of voltage type (else current-loop type).
    pub voltage_row: [bool; 2],
}

impl LinearMode {
    pub(crate) fn key(&self) -> u8 {
        (self.stuck[0] as u8)
            | (self.stuck[1] as u8) << 1
            | (self.voltage_row[0] as u8) << 2
            | (self.voltage_row[1] as u8) << 3
    }

    /// Inverse of [`Self::key`].
    pub(crate) fn from_key(key: u8) -> Self {
        Self {
            stuck: [key & 1 != 0, key & 2 != 0],
            voltage_row: [key & 4 != 0, key & 8 != 0],
        }
    }
}

/// The system matrix `M` of the augmented state for `mode`.
pub(crate) fn system_matrix(p: &BenchParameters, mode: LinearMode) -> AugMatrix {
    let mut m = AugMatrix::zeros();
    let k = p.coupling_stiffness();
    let (i1, i2) = (p.actuation_inertia, p.load_inertia);
    m[(THETA1, OMEGA1)] = 1.0;
    m[(THETA2, OMEGA2)] = 1.0;
    if !mode.stuck[0] {
        m[(OMEGA1, THETA1)] = -k / i1;
        m[(OMEGA1, THETA2)] = k / i1;
        m[(OMEGA1, OMEGA1)] = -p.actuation_damping / i1;
        m[(OMEGA1, CURRENT1)] = p.harmonic_drive_ratio * p.test_motor_torque_constant / i1;
        m[(OMEGA1, FRICTION1)] = 1.0 / i1;
    }
    if !mode.stuck[1] {
        m[(OMEGA2, THETA2)] = -k / i2;
        m[(OMEGA2, THETA1)] = k / i2;
        m[(OMEGA2, OMEGA2)] = -p.load_damping / i2;
        m[(OMEGA2, CURRENT2)] = p.reduction_ratio * p.load_motor_torque_constant / i2;
        m[(OMEGA2, FRICTION2)] = 1.0 / i2;
    }
    let motors = [
        (
            CURRENT1,
            OMEGA1,
            DRIVE1,
            p.test_motor_resistance,
            p.test_motor_inductance,
            p.test_motor_back_emf_constant * p.harmonic_drive_ratio,
        ),
        (
            CURRENT2,
            OMEGA2,
            DRIVE2,
            p.load_motor_resistance,
            p.load_motor_inductance,
            p.load_motor_back_emf_constant * p.reduction_ratio,
        ),
    ];
    for (n, &(row, omega, drive, r, l, ke_out)) in motors.iter().enumerate() {
        if mode.voltage_row[n] {
            m[(row, row)] = -r / l;
            m[(row, omega)] = -ke_out / l;
            m[(row, drive)] = 1.0 / l;
        } else {
            let tau = p.current_loop_time_constant;
            m[(row, row)] = -1.0 / tau;
            m[(row, drive)] = 1.0 / tau;
        }
    }
    m
}

/// Rate scale of `M` used to size Taylor pieces: largest diagonal magnitude plus the largest
/// geometric mean of a symmetric off-diagonal pair (an estimate of the spectral radius that is
/// insensitive to the units of the states).
pub(crate) fn rate_scale(m: &AugMatrix) -> f64 {
    let mut diagonal: f64 = 0.0;
    let mut coupling: f64 = 0.0;
    for i in 0..NZ {
        diagonal = diagonal.max(m[(i, i)].abs());
        for j in (i + 1)..NZ {
            coupling = coupling.max((m[(i, j)] * m[(j, i)]).abs().sqrt());
        }
    }
    diagonal + 2.0 * coupling + 1.0
}

/// Cached exact discretisation of one (mode, h).
#[derive(Debug, Clone)]
pub(crate) struct Discretization {
    pub key: u8,
    pub step: f64,
    /// Rows 0..6 of `exp(M h)`.
    pub transition: [[f64; NZ]; 6],
    /// Rows of `integral_0^h exp(M t) dt` for the two currents.
    pub current_integrals: [[f64; NZ]; 2],
    /// Packed Gramians: `integral z_a z_b dt = sum_k gram[k] * packed(z0)[k]`.
    pub gramians: [[f64; NPACK]; 6],
}

/// Packed upper-triangle products `z_i z_j`, `i <= j`.
pub(crate) fn packed_products(z: &AugVector) -> [f64; NPACK] {
    let mut out = [0.0; NPACK];
    let mut k = 0;
    for i in 0..NZ {
        for j in i..NZ {
            out[k] = z[i] * z[j];
            k += 1;
        }
    }
    out
}

impl Discretization {
    pub(crate) fn new(m: &AugMatrix, key: u8, h: f64) -> Self {
        // exp of M extended by two integrator rows q1' = i1, q2' = i2.
        let mut ext = SMatrix::<f64, 12, 12>::zeros();
        ext.fixed_view_mut::<NZ, NZ>(0, 0).copy_from(m);
        ext[(NZ, CURRENT1)] = 1.0;
        ext[(NZ + 1, CURRENT2)] = 1.0;
        let e = (ext * h).exp();
        let mut transition = [[0.0; NZ]; 6];
        for (r, row) in transition.iter_mut().enumerate() {
            for (c, v) in row.iter_mut().enumerate() {
                *v = e[(r, c)];
            }
        }
        let mut current_integrals = [[0.0; NZ]; 2];
        for (r, row) in current_integrals.iter_mut().enumerate() {
            for (c, v) in row.iter_mut().enumerate() {
                *v = e[(NZ + r, c)];
            }
        }
        // Van Loan: exp([[-M^T, Q], [0, M]] h) = [[., F12], [0, Phi]], Gramian = Phi^T F12.
        let mut gramians = [[0.0; NPACK]; 6];
        for (g, &(a, b)) in gramians.iter_mut().zip(PRODUCTS.iter()) {
            let mut big = SMatrix::<f64, 20, 20>::zeros();
            big.fixed_view_mut::<NZ, NZ>(0, 0)
                .copy_from(&(-m.transpose()));
            big.fixed_view_mut::<NZ, NZ>(NZ, NZ).copy_from(m);
            big[(a, NZ + b)] += 0.5;
            big[(b, NZ + a)] += 0.5;
            let e = (big * h).exp();
            let f12 = e.fixed_view::<NZ, NZ>(0, NZ).into_owned();
            let phi = e.fixed_view::<NZ, NZ>(NZ, NZ).into_owned();
            let full = phi.transpose() * f12;
            let mut k = 0;
            for i in 0..NZ {
                for j in i..NZ {
                    g[k] = if i == j {
                        full[(i, i)]
                    } else {
                        full[(i, j)] + full[(j, i)]
                    };
                    k += 1;
                }
            }
        }
        Self {
            key,
            step: h,
            transition,
            current_integrals,
            gramians,
        }
    }

    /// State at the end of the step.
    pub(crate) fn advance(&self, z: &AugVector) -> AugVector {
        let mut out = *z;
        for (r, row) in self.transition.iter().enumerate() {
            out[r] = row.iter().zip(z.iter()).map(|(a, b)| a * b).sum();
        }
        out
    }

    /// Integrals over the step starting at `z`.
    pub(crate) fn integrals(&self, z: &AugVector) -> SegmentIntegrals {
        let packed = packed_products(z);
        let mut products = [0.0; 6];
        for (p, g) in products.iter_mut().zip(self.gramians.iter()) {
            *p = g.iter().zip(packed.iter()).map(|(a, b)| a * b).sum();
        }
        let dot = |row: &[f64; NZ]| row.iter().zip(z.iter()).map(|(a, b)| a * b).sum();
        SegmentIntegrals {
            products,
            current1: dot(&self.current_integrals[0]),
            current2: dot(&self.current_integrals[1]),
        }
    }
}

/// Largest number of Taylor terms per piece.
const MAX_TERMS: usize = 48;

/// One piece of a Taylor-expanded segment: `z(start + s len) = sum_n s^n coefficients[n]`.
#[derive(Debug, Clone)]
pub(crate) struct Piece {
    pub start: f64,
    pub len: f64,
    pub terms: usize,
    pub coefficients: [AugVector; MAX_TERMS],
}

impl Piece {
    pub(crate) fn eval(&self, s: f64) -> AugVector {
        let mut out = self.coefficients[self.terms - 1];
        for n in (0..self.terms - 1).rev() {
            for (o, c) in out.iter_mut().zip(self.coefficients[n].iter()) {
                *o = *o * s + c;
            }
        }
        out
    }

    /// Polynomial (in s) of component `index`.
    pub(crate) fn component(&self, index: usize) -> Vec<f64> {
        self.coefficients[..self.terms]
            .iter()
            .map(|c| c[index])
            .collect()
    }
}

/// A segment `[0, duration]` of the linear flow from `z0`, as Taylor pieces.
#[derive(Debug, Clone)]
pub(crate) struct TaylorSegment {
    pub pieces: Vec<Piece>,
}

impl TaylorSegment {
    pub(crate) fn new(m: &AugMatrix, rate: f64, z0: &AugVector, duration: f64) -> Self {
        let mut count = ((duration * rate / 2.0).ceil() as usize).clamp(1, 1_000_000);
        'retry: loop {
            let pieces_wanted = count;
            let len = duration / pieces_wanted as f64;
            let mut pieces = Vec::with_capacity(pieces_wanted);
            let mut z = *z0;
            for p in 0..pieces_wanted {
                let mut piece = Piece {
                    start: p as f64 * len,
                    len,
                    terms: 1,
                    coefficients: [[0.0; NZ]; MAX_TERMS],
                };
                piece.coefficients[0] = z;
                let scale = z.iter().fold(0.0f64, |a, v| a.max(v.abs())).max(1e-300);
                let mut small_in_a_row = 0;
                let mut converged = false;
                for n in 1..MAX_TERMS {
                    let prev = piece.coefficients[n - 1];
                    let mut next = [0.0; NZ];
                    for (r, v) in next.iter_mut().enumerate() {
                        let mut acc = 0.0;
                        for (c, pv) in prev.iter().enumerate() {
                            acc += m[(r, c)] * pv;
                        }
                        *v = acc * len / n as f64;
                    }
                    piece.coefficients[n] = next;
                    piece.terms = n + 1;
                    let size = next.iter().fold(0.0f64, |a, v| a.max(v.abs()));
                    if size <= 1e-18 * scale {
                        small_in_a_row += 1;
                        if small_in_a_row >= 2 {
                            converged = true;
                            break;
                        }
                    } else {
                        small_in_a_row = 0;
                    }
                }
                if !converged {
                    count *= 2;
                    continue 'retry;
                }
                z = piece.eval(1.0);
                pieces.push(piece);
            }
            return Self { pieces };
        }
    }

    fn locate(&self, t: f64) -> (&Piece, f64) {
        let len = self.pieces[0].len;
        let index = ((t / len) as usize).min(self.pieces.len() - 1);
        let piece = &self.pieces[index];
        (piece, ((t - piece.start) / len).clamp(0.0, 1.0))
    }

    /// State at time `t` in `[0, duration]`.
    pub(crate) fn state_at(&self, t: f64) -> AugVector {
        let (piece, s) = self.locate(t);
        piece.eval(s)
    }

    /// Ends of the pieces (for sign-change scanning), excluding 0.
    pub(crate) fn piece_ends(&self) -> impl Iterator<Item = f64> + '_ {
        self.pieces.iter().map(|p| p.start + p.len)
    }
}

/// Coefficients of the product of two polynomials.
pub(crate) fn poly_mul(a: &[f64], b: &[f64]) -> Vec<f64> {
    let mut out = vec![0.0; a.len() + b.len() - 1];
    for (i, x) in a.iter().enumerate() {
        if *x == 0.0 {
            continue;
        }
        for (j, y) in b.iter().enumerate() {
            out[i + j] += x * y;
        }
    }
    out
}

/// `integral_{s0}^{s1} p(s) ds`.
pub(crate) fn poly_integral(p: &[f64], s0: f64, s1: f64) -> f64 {
    let mut hi = 0.0;
    let mut lo = 0.0;
    for (n, c) in p.iter().enumerate().rev() {
        let k = (n + 1) as f64;
        hi = hi * s1 + c / k;
        lo = lo * s0 + c / k;
    }
    hi * s1 - lo * s0
}

/// Value of a polynomial at `s`.
pub(crate) fn poly_eval(p: &[f64], s: f64) -> f64 {
    p.iter().rev().fold(0.0, |acc, c| acc * s + c)
}

/// Linear combination of polynomials `sum_k w_k p_k` plus a constant.
pub(crate) fn poly_combine(parts: &[(f64, &[f64])], constant: f64) -> Vec<f64> {
    let len = parts.iter().map(|(_, p)| p.len()).max().unwrap_or(1).max(1);
    let mut out = vec![0.0; len];
    out[0] = constant;
    for (w, p) in parts {
        for (o, c) in out.iter_mut().zip(p.iter()) {
            *o += w * c;
        }
    }
    out
}

/// Converts a state slice to the fixed array type.
pub(crate) fn to_vector(z: &AugVector) -> SVector<f64, NZ> {
    SVector::<f64, NZ>::from_column_slice(z)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn test_mode() -> LinearMode {
        LinearMode {
            stuck: [false, false],
            voltage_row: [true, false],
        }
    }

    #[test]
    fn taylor_segment_matches_the_matrix_exponential() {
        let p = BenchParameters::default();
        let m = system_matrix(&p, test_mode());
        let z0 = [0.1, -0.05, 0.3, -0.2, 2.0, -1.0, 12.0, 0.5, -5.0, 0.35];
        let h = 1e-3;
        let d = Discretization::new(&m, 0, h);
        let exact = d.advance(&z0);
        let taylor = TaylorSegment::new(&m, rate_scale(&m), &z0, h).state_at(h);
        for k in 0..NZ {
            assert!(
                (exact[k] - taylor[k]).abs() < 1e-12 * (1.0 + exact[k].abs()),
                "{k}"
            );
        }
        let reference = (m * h).exp() * to_vector(&z0);
        for k in 0..NZ {
            assert!((exact[k] - reference[k]).abs() < 1e-12 * (1.0 + exact[k].abs()));
        }
    }

    #[test]
    fn gramians_match_taylor_product_integrals() {
        let p = BenchParameters::default();
        let m = system_matrix(&p, test_mode());
        let z0 = [0.1, -0.05, 0.3, -0.2, 2.0, -1.0, 12.0, 0.5, -5.0, 0.35];
        let h = 1e-3;
        let cached = Discretization::new(&m, 0, h).integrals(&z0);
        let segment = TaylorSegment::new(&m, rate_scale(&m), &z0, h);
        for (k, &(a, b)) in PRODUCTS.iter().enumerate() {
            let mut total = 0.0;
            for piece in &segment.pieces {
                let prod = poly_mul(&piece.component(a), &piece.component(b));
                total += piece.len * poly_integral(&prod, 0.0, 1.0);
            }
            assert!(
                (total - cached.products[k]).abs() < 1e-12 * (1e-6 + total.abs()),
                "{k}"
            );
        }
    }
}
