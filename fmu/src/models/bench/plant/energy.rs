//! The plant's energy accounting (bench-model §9): the exact integrals of the powers, losses
//! and their positive parts over a regular sub-step (from the cached Gramians) and over a Taylor
//! segment (by polynomial products), with the polynomial helpers they use.

use super::{BenchPlant, Held, multiply};
use crate::models::bench::mechanics::{
    Antiderivative, AugMatrix, AugVector, CURRENT1, CURRENT2, OMEGA1, OMEGA2, PIECE_TERMS, Piece,
    SegmentIntegrals, THETA1, TaylorSegment, poly_eval, poly_eval_many,
};

/// Energy integrals since the start [J], signed and positive part ("consumed").
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub(crate) struct EnergyAccount {
    pub test_mechanical: f64,
    pub test_mechanical_consumed: f64,
    pub load_mechanical: f64,
    pub load_mechanical_consumed: f64,
    pub actuation_loss: f64,
    pub load_loss: f64,
    pub test_electrical: f64,
    pub test_electrical_consumed: f64,
    pub load_electrical: f64,
    pub load_electrical_consumed: f64,
    pub clutch: f64,
    pub offset: f64,
    pub total_electrical: f64,
    pub total_electrical_consumed: f64,
    pub test_copper_loss: f64,
    pub load_copper_loss: f64,
    pub test_back_emf: f64,
    pub load_back_emf: f64,
}

impl EnergyAccount {
    pub(crate) const COUNT: usize = 18;

    pub(crate) fn to_array(self) -> [f64; Self::COUNT] {
        [
            self.test_mechanical,
            self.test_mechanical_consumed,
            self.load_mechanical,
            self.load_mechanical_consumed,
            self.actuation_loss,
            self.load_loss,
            self.test_electrical,
            self.test_electrical_consumed,
            self.load_electrical,
            self.load_electrical_consumed,
            self.clutch,
            self.offset,
            self.total_electrical,
            self.total_electrical_consumed,
            self.test_copper_loss,
            self.load_copper_loss,
            self.test_back_emf,
            self.load_back_emf,
        ]
    }

    pub(crate) fn from_array(a: [f64; Self::COUNT]) -> Self {
        Self {
            test_mechanical: a[0],
            test_mechanical_consumed: a[1],
            load_mechanical: a[2],
            load_mechanical_consumed: a[3],
            actuation_loss: a[4],
            load_loss: a[5],
            test_electrical: a[6],
            test_electrical_consumed: a[7],
            load_electrical: a[8],
            load_electrical_consumed: a[9],
            clutch: a[10],
            offset: a[11],
            total_electrical: a[12],
            total_electrical_consumed: a[13],
            test_copper_loss: a[14],
            load_copper_loss: a[15],
            test_back_emf: a[16],
            load_back_emf: a[17],
        }
    }
}

impl BenchPlant {
    /// The five reported powers at `z`: test and load mechanical, test and load electrical, total
    /// electrical.
    #[inline(always)]
    pub(super) fn powers(&self, held: &Held, z: &AugVector) -> [f64; 5] {
        self.powers_with(held, z, &self.demands(held, z))
    }

    /// [`Self::powers`] given the voltage demands at `z` ([`Self::demands`]): a current loop's
    /// armature voltage is its demand ([`Self::armature_voltage`]).
    #[inline(always)]
    pub(super) fn powers_with(&self, held: &Held, z: &AugVector, demand: &[f64; 2]) -> [f64; 5] {
        let tpa = self.torque_per_ampere();
        let voltage = |n: usize| Self::armature_voltage_or(held, n, || demand[n]);
        let el1 = voltage(0) * z[CURRENT1];
        let el2 = voltage(1) * z[CURRENT2];
        [
            tpa[0] * z[CURRENT1] * z[OMEGA1],
            tpa[1] * z[CURRENT2] * z[OMEGA2],
            el1,
            el2,
            el1 + el2 + self.constant_power(held),
        ]
    }

    /// Time derivatives of the five reported powers at `z` (constant inputs).
    #[inline(always)]
    pub(super) fn power_rates(&self, held: &Held, m: &AugMatrix, z: &AugVector) -> [f64; 5] {
        let dz = multiply(m, z);
        let tpa = self.torque_per_ampere();
        let mut electrical = [0.0; 2];
        for (n, e) in electrical.iter_mut().enumerate() {
            let (current, omega) = (CURRENT1 + n, OMEGA1 + n);
            let voltage = self.armature_voltage(held, n, z);
            let voltage_rate = if held.mode.voltage_row[n] {
                0.0
            } else {
                let (r, _, ke, _, _) = self.motor(n);
                let gain = self.derived.loop_gain[n];
                (r - gain) * dz[current] + ke * dz[omega]
            };
            *e = voltage_rate * z[current] + voltage * dz[current];
        }
        [
            tpa[0] * (dz[CURRENT1] * z[OMEGA1] + z[CURRENT1] * dz[OMEGA1]),
            tpa[1] * (dz[CURRENT2] * z[OMEGA2] + z[CURRENT2] * dz[OMEGA2]),
            electrical[0],
            electrical[1],
            electrical[0] + electrical[1],
        ]
    }

    #[inline(always)]
    pub(super) fn constant_power(&self, held: &Held) -> f64 {
        self.params.hardware_offset_power
            + if held.clutch {
                self.params.clutch_power
            } else {
                0.0
            }
    }

    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    pub(super) fn accumulate_regular(
        &mut self,
        held: &Held,
        z0: &AugVector,
        z1: &AugVector,
        integrals: &SegmentIntegrals,
        (p0, p1): (&[f64; 5], &[f64; 5]),
        rates: Option<([f64; 5], [f64; 5])>,
        h: f64,
    ) {
        let mut electrical = [0.0; 2];
        for (n, e) in electrical.iter_mut().enumerate() {
            let current_integral = if n == 0 {
                integrals.current1
            } else {
                integrals.current2
            };
            *e = if held.mode.voltage_row[n] {
                held.drive[n] * current_integral
            } else {
                let (r, _, ke, _, _) = self.motor(n);
                let gain = self.derived.loop_gain[n];
                (r - gain) * integrals.products[2 + n]
                    + ke * integrals.products[4 + n]
                    + gain * held.reference[n] * current_integral
            };
        }
        let tpa = self.torque_per_ampere();
        let signed = [
            tpa[0] * integrals.products[4],
            tpa[1] * integrals.products[5],
            electrical[0],
            electrical[1],
            electrical[0] + electrical[1] + self.constant_power(held) * h,
        ];
        let mut positive = [0.0; 5];
        for k in 0..5 {
            positive[k] = match rates {
                Some((d0, d1)) if p0[k] * p1[k] < 0.0 => {
                    hermite_positive_part(p0[k], p1[k], d0[k] * h, d1[k] * h, signed[k], h)
                }
                _ if p0[k] > 0.0 || (p0[k] == 0.0 && p1[k] > 0.0) => signed[k],
                _ => 0.0,
            };
        }
        let squares = [integrals.products[0], integrals.products[1]];
        let copper = [integrals.products[2], integrals.products[3]];
        let emf = [integrals.products[4], integrals.products[5]];
        self.add_energy(held, z0, z1, signed, positive, squares, copper, emf, h);
    }

    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    pub(super) fn add_energy(
        &mut self,
        held: &Held,
        z0: &AugVector,
        z1: &AugVector,
        signed: [f64; 5],
        positive: [f64; 5],
        squares: [f64; 2],
        copper: [f64; 2],
        emf: [f64; 2],
        duration: f64,
    ) {
        let p = &self.params;
        let (r1, _, ke1, _, _) = self.motor(0);
        let (r2, _, ke2, _, _) = self.motor(1);
        let damping = [p.actuation_damping, p.load_damping];
        let mut loss = [0.0; 2];
        for j in 0..2 {
            let travel = z1[THETA1 + j] - z0[THETA1 + j];
            loss[j] = if held.mode.stuck[j] {
                0.0
            } else {
                -damping[j] * squares[j] + held.friction[j] * travel
            };
        }
        let clutch = if held.clutch {
            p.clutch_power * duration
        } else {
            0.0
        };
        let offset = p.hardware_offset_power * duration;
        let e = &mut self.state.energy;
        e.test_mechanical += signed[0];
        e.test_mechanical_consumed += positive[0];
        e.load_mechanical += signed[1];
        e.load_mechanical_consumed += positive[1];
        e.actuation_loss += loss[0];
        e.load_loss += loss[1];
        e.test_electrical += signed[2];
        e.test_electrical_consumed += positive[2];
        e.load_electrical += signed[3];
        e.load_electrical_consumed += positive[3];
        e.clutch += clutch;
        e.offset += offset;
        e.total_electrical += signed[4];
        e.total_electrical_consumed += positive[4];
        e.test_copper_loss += r1 * copper[0];
        e.load_copper_loss += r2 * copper[1];
        e.test_back_emf += ke1 * emf[0];
        e.load_back_emf += ke2 * emf[1];
    }

    /// Energies over `[0, stop]` of a Taylor segment, positive parts split at sign changes
    /// (per piece [`PieceWork::integrals`]); returns the state at `stop` (which they read).
    #[inline(always)]
    pub(super) fn accumulate_segment(
        &mut self,
        held: &Held,
        segment: &TaylorSegment,
        stop: f64,
    ) -> AugVector {
        let mut signed = [0.0; 5];
        let mut positive = [0.0; 5];
        let mut squares = [0.0; 2];
        let mut copper = [0.0; 2];
        let mut emf = [0.0; 2];
        let laws = self.power_laws(held);
        let mut work = self.piece_scratch.0.take().unwrap_or_default();
        for piece in segment.pieces() {
            if piece.start >= stop {
                break;
            }
            let s_end = ((stop - piece.start) / piece.len).min(1.0);
            let part = work.integrals(piece, s_end, &laws);
            for k in 0..5 {
                signed[k] += piece.len * part.signed[k];
                positive[k] += piece.len * part.positive[k];
            }
            for j in 0..2 {
                squares[j] += piece.len * part.squares[j];
                copper[j] += piece.len * part.copper[j];
                emf[j] += piece.len * part.emf[j];
            }
        }
        self.piece_scratch.0 = Some(work);
        let z0 = segment.state_at(0.0);
        let z1 = segment.state_at(stop);
        self.add_energy(held, &z0, &z1, signed, positive, squares, copper, emf, stop);
        z1
    }

    /// The held mode's power laws: what [`PieceWork`] needs to form the powers of a piece.
    #[inline(always)]
    pub(super) fn power_laws(&self, held: &Held) -> PowerLaws {
        PowerLaws {
            torque_per_ampere: self.torque_per_ampere(),
            voltage: [self.voltage_law(held, 0), self.voltage_law(held, 1)],
            constant: self.constant_power(held),
        }
    }

    /// Armature voltage of motor `n` as `a i + b w + c` for the held mode.
    #[inline(always)]
    pub(super) fn voltage_law(&self, held: &Held, n: usize) -> (f64, f64, f64) {
        if held.mode.voltage_row[n] {
            (0.0, 0.0, held.drive[n])
        } else {
            let (r, _, ke, _, _) = self.motor(n);
            let gain = self.derived.loop_gain[n];
            (r - gain, ke, gain * held.reference[n])
        }
    }
}

/// The powers of a segment as laws in its series: per motor the output-side torque per ampere
/// (mechanical power `tpa i w`) and the armature voltage `a i + b w + c` (electrical power
/// `a i^2 + b w i + c i`), and the constant electrical power (offset, clutch).
#[derive(Debug, Clone, Copy)]
pub(super) struct PowerLaws {
    torque_per_ampere: [f64; 2],
    voltage: [(f64, f64, f64); 2],
    constant: f64,
}

/// One piece's energy integrals over `[0, s_end]` in the piece's own time `s` (to be scaled by
/// its length): the five powers signed and their positive parts, and per side `w^2`, `i^2` and
/// `i w`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct PieceIntegrals {
    signed: [f64; 5],
    positive: [f64; 5],
    squares: [f64; 2],
    copper: [f64; 2],
    emf: [f64; 2],
}

/// The plant's [`PieceWork`], kept between event sub-steps: zeroed once when first used, not
/// per segment (10 KB: a memset per segment cost more than the segment's integrals). Not
/// state: a clone of the plant starts without it (`Clone` gives `None`).
#[derive(Debug, Default)]
pub(super) struct PieceScratch(Option<Box<PieceWork>>);

impl Clone for PieceScratch {
    fn clone(&self) -> Self {
        Self(None)
    }
}

/// The working arrays of [`PieceWork::integrals`]: a piece writes every entry it reads (its
/// `n` terms, its `2 n - 1` products and powers) before reading it, so what an earlier piece
/// (of this segment or an earlier one) left beyond them is never read.
#[derive(Debug)]
pub(super) struct PieceWork {
    weights: [f64; 2 * PIECE_TERMS],
    series: [[f64; 4]; PIECE_TERMS],
    speeds: [[f64; PIECE_TERMS]; 2],
    currents: [[f64; PIECE_TERMS]; 2],
    squares_of: [[f64; 4]; 2 * PIECE_TERMS],
    wi: [[f64; 2 * PIECE_TERMS]; 2],
    /// Lanes (P_test, P_load, P_el1, P_el2) of each power coefficient.
    powers: [[f64; 4]; 2 * PIECE_TERMS],
    /// Lanes (P_total, i1 w1, i2 w2, 0) of each coefficient.
    more: [[f64; 4]; 2 * PIECE_TERMS],
    /// One power's coefficients, gathered from its lane where its positive part needs them.
    gathered: [f64; 2 * PIECE_TERMS],
}

impl Default for PieceWork {
    fn default() -> Self {
        Self::new()
    }
}

impl PieceWork {
    #[inline(always)]
    pub(super) fn new() -> Self {
        Self {
            weights: [0.0; 2 * PIECE_TERMS],
            series: [[0.0; 4]; PIECE_TERMS],
            speeds: [[0.0; PIECE_TERMS]; 2],
            currents: [[0.0; PIECE_TERMS]; 2],
            squares_of: [[0.0; 4]; 2 * PIECE_TERMS],
            wi: [[0.0; 2 * PIECE_TERMS]; 2],
            powers: [[0.0; 4]; 2 * PIECE_TERMS],
            more: [[0.0; 4]; 2 * PIECE_TERMS],
            gathered: [0.0; 2 * PIECE_TERMS],
        }
    }

    /// Forms the piece's products and powers: the four series (w1, w2, i1, i2) side by side
    /// and their squares as lanes (`squares_of[k]` = (w1^2, w2^2, i1^2, i2^2)_k), the products
    /// `wi[j]` = i_j w_j each from its own two series (`product_into`), the powers from them
    /// (`V i = a i^2 + b w i + c i` with the driver's affine voltage law) into the lanes of
    /// `powers` and `more`; and `weights[k]` = integral_0^s_end s^k ds. Returns the degree + 1.
    #[inline(always)]
    fn form(&mut self, piece: &Piece, s_end: f64, laws: &PowerLaws) -> usize {
        let n = piece.terms;
        let degree = 2 * n - 1;
        let mut power = s_end;
        for (k, weight) in self.weights[..degree].iter_mut().enumerate() {
            *weight = power / (k + 1) as f64;
            power *= s_end;
        }
        for (k, c) in piece.coefficients[..n].iter().enumerate() {
            self.series[k] = [c[OMEGA1], c[OMEGA2], c[CURRENT1], c[CURRENT2]];
            self.speeds[0][k] = c[OMEGA1];
            self.speeds[1][k] = c[OMEGA2];
            self.currents[0][k] = c[CURRENT1];
            self.currents[1][k] = c[CURRENT2];
        }
        square_lanes(&self.series[..n], &mut self.squares_of);
        for j in 0..2 {
            product_into(
                &self.currents[j][..n],
                &self.speeds[j][..n],
                &mut self.wi[j],
            );
        }
        let (tpa, law) = (laws.torque_per_ampere, laws.voltage);
        for k in 0..degree {
            let linear = |j: usize| if k < n { self.series[k][2 + j] } else { 0.0 };
            let [_, _, ii0, ii1] = self.squares_of[k];
            let (wi0, wi1) = (self.wi[0][k], self.wi[1][k]);
            let el0 = law[0].0 * ii0 + law[0].1 * wi0 + law[0].2 * linear(0);
            let el1 = law[1].0 * ii1 + law[1].1 * wi1 + law[1].2 * linear(1);
            self.powers[k] = [tpa[0] * wi0, tpa[1] * wi1, el0, el1];
            self.more[k] = [el0 + el1, wi0, wi1, 0.0];
        }
        self.more[0][0] += laws.constant;
        degree
    }

    /// The piece's integrals over `[0, s_end]`: each lane's weighted coefficients summed in
    /// order, four lanes at once, and the bounds of [`positive_part`] likewise; the plain form,
    /// one polynomial after the other, is [`Self::integrals_plain`] (bit for bit, tested).
    #[inline(always)]
    pub(super) fn integrals(
        &mut self,
        piece: &Piece,
        s_end: f64,
        laws: &PowerLaws,
    ) -> PieceIntegrals {
        let degree = self.form(piece, s_end, laws);
        // `Sum` of f64 starts at -0.0: so do these, for the same bits.
        let mut squares = [-0.0; 4];
        let mut powers = [-0.0; 4];
        let mut more = [-0.0; 4];
        for k in 0..degree {
            let w = self.weights[k];
            let (s, p, m) = (&self.squares_of[k], &self.powers[k], &self.more[k]);
            for l in 0..4 {
                squares[l] += s[l] * w;
                powers[l] += p[l] * w;
                more[l] += m[l] * w;
            }
        }
        let mut bound_powers = [0.0; 4];
        let mut bound_more = [0.0; 4];
        let mut power = 1.0;
        for k in 1..degree {
            power *= s_end;
            let (p, m) = (&self.powers[k], &self.more[k]);
            for l in 0..4 {
                bound_powers[l] += p[l].abs() * power;
                bound_more[l] += m[l].abs() * power;
            }
        }
        let signed = [powers[0], powers[1], powers[2], powers[3], more[0]];
        let bounds = [
            bound_powers[0],
            bound_powers[1],
            bound_powers[2],
            bound_powers[3],
            bound_more[0],
        ];
        let mut positive = [0.0; 5];
        for k in 0..5 {
            let (lanes, l) = if k < 4 {
                (&self.powers, k)
            } else {
                (&self.more, 0)
            };
            positive[k] = match signed_part(lanes[0][l], bounds[k], signed[k]) {
                Some(part) => part,
                None => {
                    for (c, lane) in self.gathered[..degree].iter_mut().zip(&lanes[..degree]) {
                        *c = lane[l];
                    }
                    positive_integral(&self.gathered[..degree], s_end)
                }
            };
        }
        PieceIntegrals {
            signed,
            positive,
            squares: [squares[0], squares[1]],
            copper: [squares[2], squares[3]],
            emf: [more[1], more[2]],
        }
    }

    /// [`Self::integrals`] in its plain form: each power's coefficients gathered into a
    /// polynomial, integrated and its positive part taken by [`positive_part`], one after the
    /// other, as the segment's energies were before the lanes.
    #[cfg(test)]
    pub(super) fn integrals_plain(
        &mut self,
        piece: &Piece,
        s_end: f64,
        laws: &PowerLaws,
    ) -> PieceIntegrals {
        let degree = self.form(piece, s_end, laws);
        let weights = &self.weights[..degree];
        let integral = |p: &[f64]| -> f64 {
            p.iter()
                .zip(weights.iter())
                .map(|(c, w)| c * w)
                .sum::<f64>()
        };
        let lane = |lanes: &[[f64; 4]], l: usize| -> Vec<f64> {
            lanes[..degree].iter().map(|c| c[l]).collect()
        };
        let polys = [
            lane(&self.powers, 0),
            lane(&self.powers, 1),
            lane(&self.powers, 2),
            lane(&self.powers, 3),
            lane(&self.more, 0),
        ];
        let signed: [f64; 5] = std::array::from_fn(|k| integral(&polys[k]));
        let positive = std::array::from_fn(|k| positive_part(&polys[k], s_end, signed[k]));
        let squares = &self.squares_of[..degree];
        PieceIntegrals {
            signed,
            positive,
            squares: [0, 1].map(|j| lane_integral(squares, weights, j)),
            copper: [2, 3].map(|j| lane_integral(squares, weights, j)),
            emf: [0, 1].map(|j| integral(&self.wi[j][..degree])),
        }
    }
}

/// The integral of lane `l` of the polynomials `p` (lane `l` of `p[k]` is the coefficient of
/// `s^k`) given `weights[k]`, the integral of `s^k`: the weighted coefficients summed in order.
#[cfg(test)]
fn lane_integral<const LANES: usize>(p: &[[f64; LANES]], weights: &[f64], l: usize) -> f64 {
    p.iter()
        .zip(weights.iter())
        .map(|(c, w)| c[l] * w)
        .sum::<f64>()
}

/// Positive part of a power that changes sign inside a regular sub-step of length `h`, from a
/// cubic Hermite model of the power (end values `p0`, `p1`, end slopes times h `m0`, `m1`): the
/// model's positive part, plus the model's error against the exact signed integral `signed`
/// shared in proportion to the time the power is positive.
fn hermite_positive_part(p0: f64, p1: f64, m0: f64, m1: f64, signed: f64, h: f64) -> f64 {
    const SAMPLES: usize = 32;
    let mut positive = 0.0;
    let mut positive_samples = 0;
    for k in 0..SAMPLES {
        let s = (k as f64 + 0.5) / SAMPLES as f64;
        let (s2, s3) = (s * s, s * s * s);
        let value = (2.0 * s3 - 3.0 * s2 + 1.0) * p0
            + (s3 - 2.0 * s2 + s) * m0
            + (-2.0 * s3 + 3.0 * s2) * p1
            + (s3 - s2) * m1;
        if value > 0.0 {
            positive += value;
            positive_samples += 1;
        }
    }
    let model_total = h * (0.5 * (p0 + p1) + (m0 - m1) / 12.0);
    let fraction = positive_samples as f64 / SAMPLES as f64;
    (h * positive / SAMPLES as f64 + (signed - model_total) * fraction).max(0.0)
}

/// `integral_0^{s_end} max(p(s), 0) ds` given the signed integral `signed`: when
/// `|p(0)|` exceeds the bound `sum_k>0 |p_k| s_end^k` on the change over the piece the sign is
/// fixed, else [`positive_integral`].
#[cfg(test)]
fn positive_part(p: &[f64], s_end: f64, signed: f64) -> f64 {
    let mut bound = 0.0;
    let mut power = 1.0;
    for c in &p[1..] {
        power *= s_end;
        bound += c.abs() * power;
    }
    signed_part(p[0], bound, signed).unwrap_or_else(|| positive_integral(p, s_end))
}

/// The positive part of a piece's power when its sign is fixed over the piece (its start value
/// `start` exceeds `bound`, the bound on its change): `signed` or 0; `None` when the sign may
/// change ([`positive_integral`] then).
#[inline(always)]
fn signed_part(start: f64, bound: f64, signed: f64) -> Option<f64> {
    if start.abs() > bound * (1.0 + 1e-12) || bound == 0.0 {
        Some(if start > 0.0 { signed } else { 0.0 })
    } else {
        None
    }
}

/// The four polynomials of `series` (coefficient `k` of each in lane `k`'s four entries)
/// squared, lane by lane, into `out[..2 series.len() - 1]`: each cross term once, doubled. A
/// lane's sums are taken in the order a one-polynomial square takes them ([`square_into`]), so
/// each lane is that square bit for bit; the four lanes make one vector operation.
#[inline(always)]
fn square_lanes(series: &[[f64; 4]], out: &mut [[f64; 4]]) {
    let n = series.len();
    out[..2 * n - 1].fill([0.0; 4]);
    for (k, x) in series.iter().enumerate() {
        let diagonal = &mut out[2 * k];
        for l in 0..4 {
            diagonal[l] += x[l] * x[l];
        }
        let twice = x.map(|v| 2.0 * v);
        for (o, y) in out[2 * k + 1..k + n].iter_mut().zip(&series[k + 1..]) {
            for l in 0..4 {
                o[l] += twice[l] * y[l];
            }
        }
    }
}

/// `out[..2 a.len() - 1] = a * a` (polynomial square: each cross term once, doubled): the
/// plain form of one lane of [`square_lanes`].
#[cfg(test)]
fn square_into(a: &[f64], out: &mut [f64]) {
    let n = a.len();
    out[..2 * n - 1].fill(0.0);
    for (k, x) in a.iter().enumerate() {
        out[2 * k] += x * x;
        let twice = 2.0 * x;
        for (o, y) in out[2 * k + 1..k + n].iter_mut().zip(&a[k + 1..]) {
            *o += twice * y;
        }
    }
}

/// `out[..a.len() + b.len() - 1] = a * b` (polynomial product): each output the sum of its
/// terms in the order of `a`'s coefficients.
#[inline(always)]
fn product_into(a: &[f64], b: &[f64], out: &mut [f64]) {
    out[..a.len() + b.len() - 1].fill(0.0);
    for (k, x) in a.iter().enumerate() {
        for (o, y) in out[k..k + b.len()].iter_mut().zip(b) {
            *o += x * y;
        }
    }
}

/// Root of `p` bracketed by values of opposite signs at `a` and `b`, by the Illinois method to
/// a bracket of `1e-10` of the interval: misplacing the split point by `d` misattributes only
/// about `|p'| d^2 / 2` of area, far below rounding here.
#[inline(always)]
fn polynomial_root(p: &[f64], (mut a, mut pa): (f64, f64), (mut b, mut pb): (f64, f64)) -> f64 {
    let tolerance = 1e-10 * (b - a);
    let mut side = 0;
    for _ in 0..100 {
        if b - a <= tolerance {
            break;
        }
        let mut t = b - pb * (b - a) / (pb - pa);
        if !(t > a && t < b) {
            t = 0.5 * (a + b);
        }
        let pt = poly_eval(p, t);
        if pt == 0.0 {
            return t;
        }
        if (pt > 0.0) == (pa > 0.0) {
            a = t;
            pa = pt;
            if side == -1 {
                pb *= 0.5;
            }
            side = -1;
        } else {
            b = t;
            pb = pt;
            if side == 1 {
                pa *= 0.5;
            }
            side = 1;
        }
    }
    0.5 * (a + b)
}

/// `integral_0^{s_end} max(p(s), 0) ds`, splitting at sign changes found on a 16-point scan
/// (each root by [`polynomial_root`]).
#[inline(always)]
fn positive_integral(p: &[f64], s_end: f64) -> f64 {
    const SCAN: usize = 16;
    let points: [f64; SCAN + 1] = std::array::from_fn(|k| {
        if k == 0 {
            0.0
        } else {
            s_end * k as f64 / SCAN as f64
        }
    });
    // `p` and its antiderivative at every scan point, evaluated side by side (bit for bit each
    // point's own Horner chain); an integral between two points is the difference of theirs.
    let values = poly_eval_many(p, &points);
    let anti = Antiderivative::of(p);
    let primitives = anti.at_many(&points);
    let mut total = 0.0;
    for k in 1..=SCAN {
        let (a, pa, fa) = (points[k - 1], values[k - 1], primitives[k - 1]);
        let (b, pb, fb) = (points[k], values[k], primitives[k]);
        if pa * pb < 0.0 {
            let root = polynomial_root(p, (a, pa), (b, pb));
            let at_root = anti.at(root);
            let first = at_root - fa;
            let second = fb - at_root;
            total += first.max(0.0) + second.max(0.0);
        } else {
            let part = fb - fa;
            if pa > 0.0 || pb > 0.0 {
                total += part.max(0.0);
            }
        }
    }
    total
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn polynomial_square_matches_the_product() {
        let a = [0.3, -1.5, 0.0, 2.25, 1e-9];
        let (mut square, mut product) = ([0.0; 9], [0.0; 9]);
        square_into(&a, &mut square);
        product_into(&a, &a, &mut product);
        for (s, p) in square.iter().zip(&product) {
            assert!((s - p).abs() <= 1e-15 * p.abs().max(1.0), "{s} vs {p}");
        }
        assert_eq!(square[0], 0.09);
        assert_eq!(square[8], 1e-18);
    }

    /// Each lane of the four-lane square is the plain square of that lane's polynomial bit for
    /// bit: zeros (a stuck body's speed series), negative zeros, mixed magnitudes, every length
    /// a piece can have. (The products `i w` are the plain `product_into` itself.)
    #[test]
    #[allow(clippy::needless_range_loop)] // a lane index names the lane in the assertions
    fn the_lanes_are_the_plain_products_bit_for_bit() {
        let value = |k: usize, l: usize| -> f64 {
            match (k * 7 + l * 3) % 6 {
                0 => 0.0,
                1 => -0.0,
                2 => (k as f64 + 1.0).powi(-3) * if l.is_multiple_of(2) { 1.0 } else { -1.0 },
                3 => 1e-300 * (l as f64 + 1.0),
                4 => 3.7e5 / (k as f64 + l as f64 + 1.0),
                _ => -0.1 * (k as f64).sin() + 1e-17 * l as f64,
            }
        };
        for n in 1..=PIECE_TERMS {
            let series: Vec<[f64; 4]> = (0..n)
                .map(|k| std::array::from_fn(|l| value(k, l)))
                .collect();
            let mut squares = [[f64::NAN; 4]; 2 * PIECE_TERMS];
            square_lanes(&series, &mut squares);
            let lane = |l: usize| series.iter().map(|s| s[l]).collect::<Vec<f64>>();
            for l in 0..4 {
                let mut plain = vec![f64::NAN; 2 * n - 1];
                square_into(&lane(l), &mut plain);
                for (k, p) in plain.iter().enumerate() {
                    assert_eq!(
                        squares[k][l].to_bits(),
                        p.to_bits(),
                        "square n {n} lane {l} k {k}"
                    );
                }
            }
        }
    }

    /// The lane form of a piece's integrals, on working arrays reused from piece to piece and
    /// segment to segment, is the plain one on fresh arrays bit for bit: every mode of DA and
    /// SEA, voltage and current-loop laws, states whose powers keep or change sign inside a
    /// piece (both branches of the positive part), stuck bodies (zero series), every piece of
    /// segments cut at the piece ends and inside pieces.
    #[test]
    fn piece_integrals_are_the_plain_form_bit_for_bit() {
        use crate::models::bench::mechanics::{LinearMode, rate_scale, system_matrix};
        use crate::models::bench::{BenchParameters, Configuration};
        let states: [AugVector; 4] = [
            [0.1, -0.05, 0.3, -0.2, 2.0, -1.0, 12.0, 0.5, -5.0, 0.35],
            [0.0, -0.0, 0.0, 1e-7, -0.0, 3.5, 0.0, -24.0, 0.0, 0.0],
            [-3e-3, 2.9e-3, -1.5, 0.8, -1.4, 0.55, -24.0, 4.8, 2.5, -1.3],
            [0.02, -0.01, 1e-3, -2e-3, 1e-3, -1e-3, 1.0, -1.0, 0.0, 0.0],
        ];
        let laws = [
            PowerLaws {
                torque_per_ampere: [5.92, 7.524],
                voltage: [(0.0, 0.0, 12.0), (-0.3, 0.9, 1.5)],
                constant: 4.5,
            },
            PowerLaws {
                torque_per_ampere: [5.92, 7.524],
                voltage: [(-2.1, 0.37, -0.4), (0.0, 0.0, -0.0)],
                constant: 0.0,
            },
        ];
        let (mut pieces, mut sign_changes) = (0, 0);
        // One working set for every piece of every segment, as the plant keeps it (what a
        // longer earlier piece left must not be read); the plain form's starts zeroed each time.
        let mut fast = PieceWork::new();
        for configuration in [Configuration::Da, Configuration::Sea] {
            let params = BenchParameters {
                configuration,
                ..BenchParameters::default()
            };
            for key in 0..16u8 {
                let m = system_matrix(&params, LinearMode::from_key(key));
                for z0 in &states {
                    for duration in [1e-3, 3.7e-2] {
                        let segment = TaylorSegment::new(&m, rate_scale(&m), z0, duration);
                        for law in &laws {
                            for stop in [duration, 0.61 * duration] {
                                for piece in segment.pieces() {
                                    if piece.start >= stop {
                                        break;
                                    }
                                    let s_end = ((stop - piece.start) / piece.len).min(1.0);
                                    let a = fast.integrals(piece, s_end, law);
                                    let b = PieceWork::new().integrals_plain(piece, s_end, law);
                                    let bits = |r: &PieceIntegrals| -> Vec<u64> {
                                        [&r.signed[..], &r.positive, &r.squares, &r.copper, &r.emf]
                                            .concat()
                                            .iter()
                                            .map(|v| v.to_bits())
                                            .collect()
                                    };
                                    assert_eq!(bits(&a), bits(&b), "key {key} z0 {z0:?}");
                                    pieces += 1;
                                    sign_changes += (0..5)
                                        .filter(|&k| {
                                            a.positive[k] != 0.0 && a.positive[k] != a.signed[k]
                                        })
                                        .count();
                                }
                            }
                        }
                    }
                }
            }
        }
        assert!(
            pieces > 1000 && sign_changes > 50,
            "{pieces} pieces, {sign_changes}"
        );
    }

    #[test]
    fn positive_integral_splits_at_the_roots() {
        // p(s) = (s - 0.3)(s - 0.7) = s^2 - s + 0.21 (positive outside the roots);
        // antiderivative P(s) = s^3/3 - s^2/2 + 0.21 s.
        let anti = |s: f64| s * s * s / 3.0 - s * s / 2.0 + 0.21 * s;
        let p = [0.21, -1.0, 1.0];
        let exact = (anti(0.3) - anti(0.0)) + (anti(1.0) - anti(0.7));
        assert!((positive_integral(&p, 1.0) - exact).abs() < 1e-15);
        // Negated: positive only between the roots.
        let q = [-0.21, 1.0, -1.0];
        let exact = -(anti(0.7) - anti(0.3));
        assert!((positive_integral(&q, 1.0) - exact).abs() < 1e-15);
        // A root very close to a scan point and a tangent-like steep polynomial.
        let r = [-0.0625, 0.0, 0.0, 0.0, 1.0]; // s^4 - 0.5^4, root at 0.5
        let exact = (0.2 - 0.0625) - (0.5f64.powi(5) / 5.0 - 0.0625 * 0.5);
        assert!((positive_integral(&r, 1.0) - exact).abs() < 1e-15);
        assert!((polynomial_root(&r, (0.4, -0.0369), (0.6, 0.0671)) - 0.5).abs() < 1e-10);
    }
}
