//! The gait series' weighted sums, the gait reference's one per-step cost that is arithmetic
//! (see [`gait_sums`]).
//!
//! The plain form is [`Weights::of`] for each of the seven sums. The AVX2 form computes the
//! same products and additions in the same order, four harmonics a vector: the compiler's
//! own vectorisation of the plain form packed the sums two lanes wide with a shuffle per
//! pair, about three times the instructions. Both give the same bits (tested here and by the
//! whole model's `the_avx2_build_of_calculate_is_the_baseline_bit_for_bit`).

use super::{ANGLE_WEIGHTS, HARMONICS, Harmonics, TORQUE_WEIGHTS, Weights};

/// How many sums [`gait_sums`] gives.
pub(super) const GAIT_SUMS: usize = 7;

/// The weights of the seven sums, in the order of [`gait_sums`]: the angle series' value,
/// rate, acceleration, jerk and integral, then the torque series' value and rate.
const GAIT_WEIGHTS: [&Weights; GAIT_SUMS] = [
    &ANGLE_WEIGHTS.value,
    &ANGLE_WEIGHTS.rate,
    &ANGLE_WEIGHTS.acceleration,
    &ANGLE_WEIGHTS.jerk,
    &ANGLE_WEIGHTS.integral,
    &TORQUE_WEIGHTS.value,
    &TORQUE_WEIGHTS.rate,
];

// The vector form reads each weight and harmonic vector as two halves of four.
const _: () = assert!(HARMONICS == 8, "the vector form is written for 8 harmonics");

/// The seven weighted sums of the gait series at `h` (order: [`GAIT_WEIGHTS`]); `WIDE`
/// selects the AVX2 form, which a caller may only choose where the CPU reports AVX2.
#[inline(always)]
pub(super) fn gait_sums<const WIDE: bool>(h: &Harmonics) -> [f64; GAIT_SUMS] {
    #[cfg(target_arch = "x86_64")]
    if WIDE {
        // SAFETY: `WIDE` is true only inside `GaitReference::calculate_wide`, which runs only
        // where the CPU reports AVX2 (`CalculateBuild`), the one feature this form needs.
        return unsafe { wide::gait_sums(h) };
    }
    gait_sums_plain(h)
}

/// The plain form: [`Weights::of`] per sum.
#[inline(always)]
fn gait_sums_plain(h: &Harmonics) -> [f64; GAIT_SUMS] {
    GAIT_WEIGHTS.map(|w| w.of(h))
}

#[cfg(target_arch = "x86_64")]
mod wide {
    use super::{GAIT_SUMS, GAIT_WEIGHTS, Harmonics};
    use core::arch::x86_64::{
        __m256d, _mm_add_sd, _mm_cvtsd_f64, _mm_hadd_pd, _mm_unpackhi_pd, _mm256_add_pd,
        _mm256_castpd256_pd128, _mm256_extractf128_pd, _mm256_loadu_pd, _mm256_mul_pd,
    };

    /// Four doubles of `a` from `at` (0 or 4).
    #[target_feature(enable = "avx2")]
    #[inline]
    fn half(a: &[f64; 8], at: usize) -> __m256d {
        let four: &[f64; 4] = a[at..at + 4].try_into().expect("a half of eight");
        // SAFETY: `four` is four initialised doubles; the load has no alignment requirement.
        unsafe { _mm256_loadu_pd(four.as_ptr()) }
    }

    /// [`super::gait_sums_plain`] four lanes wide: lane n of `a + b` is
    /// `term(n) + term(n + 4)` with `term(n) = w_sin,n sin_n + w_cos,n cos_n`, then
    /// `(lane 0 + lane 1) + (lane 2 + lane 3)`: the operations of `Weights::of`, in its order.
    #[target_feature(enable = "avx2")]
    pub(super) fn gait_sums(h: &Harmonics) -> [f64; GAIT_SUMS] {
        let (sin_low, sin_high) = (half(&h.sin, 0), half(&h.sin, 4));
        let (cos_low, cos_high) = (half(&h.cos, 0), half(&h.cos, 4));
        GAIT_WEIGHTS.map(|w| {
            let low = _mm256_add_pd(
                _mm256_mul_pd(half(&w.sin, 0), sin_low),
                _mm256_mul_pd(half(&w.cos, 0), cos_low),
            );
            let high = _mm256_add_pd(
                _mm256_mul_pd(half(&w.sin, 4), sin_high),
                _mm256_mul_pd(half(&w.cos, 4), cos_high),
            );
            let lanes = _mm256_add_pd(low, high);
            // [lane 0 + lane 1, lane 2 + lane 3], then their sum.
            let pairs = _mm_hadd_pd(
                _mm256_castpd256_pd128(lanes),
                _mm256_extractf128_pd::<1>(lanes),
            );
            _mm_cvtsd_f64(_mm_add_sd(pairs, _mm_unpackhi_pd(pairs, pairs)))
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_vector_sums_are_the_plain_sums_bit_for_bit() {
        if crate::models::bench::plant::no_wide_vectors_here("the plain form") {
            return;
        }
        let mut compared = 0;
        // Harmonics of a dense set of phases, and vectors of arbitrary magnitudes and signs
        // (sums that cancel, so any change of order would show in the last bits).
        for k in 0..4000 {
            let x = f64::from(k) * 0.000_731;
            let h = if k % 2 == 0 {
                Harmonics::at_cycles(x)
            } else {
                Harmonics {
                    sin: std::array::from_fn(|n| ((n + 1) as f64 * x * 7.3).sin() * 1e3),
                    cos: std::array::from_fn(|n| ((n + 3) as f64 * x * 3.1).cos() * 1e-3),
                }
            };
            // SAFETY: AVX2 reported above.
            let wide = unsafe { wide::gait_sums(&h) };
            let plain = gait_sums_plain(&h);
            assert_eq!(wide.map(f64::to_bits), plain.map(f64::to_bits), "k {k}");
            assert_eq!(
                gait_sums::<true>(&h).map(f64::to_bits),
                plain.map(f64::to_bits)
            );
            compared += 1;
        }
        assert_eq!(compared, 4000);
    }

    #[test]
    fn the_sums_are_the_series_weights_of_each_output() {
        let h = Harmonics::at_cycles(0.137);
        let sums = gait_sums::<false>(&h);
        let expected = [
            ANGLE_WEIGHTS.value.of(&h),
            ANGLE_WEIGHTS.rate.of(&h),
            ANGLE_WEIGHTS.acceleration.of(&h),
            ANGLE_WEIGHTS.jerk.of(&h),
            ANGLE_WEIGHTS.integral.of(&h),
            TORQUE_WEIGHTS.value.of(&h),
            TORQUE_WEIGHTS.rate.of(&h),
        ];
        assert_eq!(sums, expected);
        // Not a vacuous comparison: the seven differ.
        for i in 0..GAIT_SUMS {
            for j in 0..i {
                assert_ne!(sums[i], sums[j]);
            }
        }
    }
}
