//! Smoothing and differentiation of uniformly sampled signals: a local cubic least-squares fit
//! over a sliding window (Savitzky-Golay), which gives the value, first and second derivative
//! at the window's centre. It stands in for the bench's cubic-spline fit of the encoder angle:
//! both are piecewise cubic least-squares fits; the sliding window has a fixed, known noise
//! gain and needs no knot placement.

use nalgebra::DMatrix;

/// Convolution weights of a cubic fit over `2 m + 1` samples at spacing `dt`: rows give the
/// value, the first and the second derivative at the centre.
fn weights(m: usize, dt: f64) -> [Vec<f64>; 3] {
    let n = 2 * m + 1;
    let mut a = DMatrix::<f64>::zeros(n, 4);
    for i in 0..n {
        let x = i as f64 - m as f64;
        for j in 0..4 {
            a[(i, j)] = x.powi(j as i32);
        }
    }
    // (A^T A)^-1 A^T: row j gives the coefficient of x^j.
    let ata = a.transpose() * &a;
    let inv = ata
        .try_inverse()
        .expect("the normal matrix of a cubic on >= 4 distinct points is invertible");
    let pinv = inv * a.transpose();
    let row = |j: usize, scale: f64| (0..n).map(|i| pinv[(j, i)] * scale).collect::<Vec<_>>();
    [row(0, 1.0), row(1, 1.0 / dt), row(2, 2.0 / (dt * dt))]
}

/// Value, first and second derivative of `x` (sampled every `dt`) by a cubic fit over
/// `2 m + 1` samples; the first and last `m` samples have none (NaN). `m >= 2`.
pub fn derivatives(x: &[f64], dt: f64, m: usize) -> [Vec<f64>; 3] {
    let m = m.max(2);
    let w = weights(m, dt);
    let mut out = [
        vec![f64::NAN; x.len()],
        vec![f64::NAN; x.len()],
        vec![f64::NAN; x.len()],
    ];
    if x.len() < 2 * m + 1 {
        return out;
    }
    for c in m..x.len() - m {
        let window = &x[c - m..=c + m];
        for (k, wk) in w.iter().enumerate() {
            out[k][c] = wk.iter().zip(window).map(|(a, b)| a * b).sum();
        }
    }
    out
}

/// Solves the least-squares problem `min |A p - y|` (small dense helper for tests).
#[cfg(test)]
pub(crate) fn lstsq(a: &DMatrix<f64>, y: &nalgebra::DVector<f64>) -> nalgebra::DVector<f64> {
    a.clone()
        .svd(true, true)
        .solve(y, 1e-12)
        .expect("svd solve")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cubics_are_differentiated_exactly() {
        let dt = 1e-3;
        let x: Vec<f64> = (0..200)
            .map(|i| {
                let t = i as f64 * dt;
                1.0 + 2.0 * t - 3.0 * t * t + 4.0 * t * t * t
            })
            .collect();
        let [v, d1, d2] = derivatives(&x, dt, 10);
        for i in 10..190 {
            let t = i as f64 * dt;
            assert!((v[i] - x[i]).abs() < 1e-9);
            assert!((d1[i] - (2.0 - 6.0 * t + 12.0 * t * t)).abs() < 1e-7, "{i}");
            assert!((d2[i] - (-6.0 + 24.0 * t)).abs() < 1e-4, "{i}");
        }
        assert!(v[5].is_nan() && d2[195].is_nan());
        let a = DMatrix::from_row_slice(3, 1, &[1.0, 2.0, 3.0]);
        let y = nalgebra::DVector::from_row_slice(&[2.0, 4.0, 6.0]);
        assert!((lstsq(&a, &y)[0] - 2.0).abs() < 1e-12);
    }

    #[test]
    fn a_sine_through_a_quantiser_keeps_its_acceleration() {
        let dt = 1e-3;
        let q = 2e-5;
        let w = 2.0 * std::f64::consts::PI;
        let x: Vec<f64> = (0..3000)
            .map(|i| ((0.2 * (w * i as f64 * dt).sin()) / q).round() * q)
            .collect();
        let [_, _, acc] = derivatives(&x, dt, 25);
        let mut worst = 0.0f64;
        for (i, a) in acc.iter().enumerate().take(2975).skip(25) {
            let exact = -0.2 * w * w * (w * i as f64 * dt).sin();
            worst = worst.max((a - exact).abs());
        }
        // 7.9 rad/s^2 amplitude: the quantisation leaves a few percent.
        assert!(worst < 0.3, "{worst}");
    }
}
