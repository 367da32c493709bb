//! Steady-state harmonic-drive loss surface (bench-model.md §2, friction model 3).
//!
//! `tau_HD,ss(x, y) = sum p_ij x^i y^j` (i + j <= 5), separate coefficients for positive and
//! negative speed. The coefficients are plant parameters (`hd_loss_positive_speed`,
//! `hd_loss_negative_speed` of [`BenchParameters`](super::BenchParameters); FMU parameters
//! `hdLossPositiveSpeed[k]`, `hdLossNegativeSpeed[k]`, k = 1..21 in the row order of
//! [`TERM_EXPONENTS`]) whose defaults are copied from `shared/data/hd-loss-surface.csv` (a unit
//! test checks they equal the file), so that `kneebench identify` can fit them to a bench.
//!
//! * `x` is the load torque **at the output (knee) axis**, `i_RED * Km2 * i2` [Nm]. The header
//!   check of the data file is at `x = 0` and so cannot decide the side; the coefficient scaling
//!   does: the `x` terms only matter for |x| of tens of Nm, the gait's output-side load range
//!   (peak external torque 9 Nm, knee torque -9 ... 4.7 Nm), whereas the load-motor shaft torque
//!   never exceeds 6 A x 0.114 Nm/A = 0.68 Nm, where every `x` term would be negligible.
//! * `y` is the actuation-side (output) velocity `omega1` [rad/s].
//! * The value is the signed torque the drive applies to the actuation side [Nm, output side]:
//!   negative for positive speed, so `omega1 * tau_HD,ss <= 0` is the loss power.
//!
//! Outside the tested range the polynomial diverges, so both arguments are clamped to the box
//! `|y| <= max speed` (150 deg/s) and `x_min <= x <= x_max`; every clamped evaluation is counted
//! and reported by the plant (`hd_surface_clamp_count`).

/// Exponent pairs (i, j) of the terms, in the row order of the csv file.
pub(crate) const TERM_EXPONENTS: [(u8, u8); 21] = [
    (0, 0),
    (1, 0),
    (0, 1),
    (2, 0),
    (1, 1),
    (0, 2),
    (3, 0),
    (2, 1),
    (1, 2),
    (0, 3),
    (4, 0),
    (3, 1),
    (2, 2),
    (1, 3),
    (0, 4),
    (5, 0),
    (4, 1),
    (3, 2),
    (2, 3),
    (1, 4),
    (0, 5),
];

/// Default coefficients for `y >= 0` (column `positive_speed` of shared/data/hd-loss-surface.csv).
pub(crate) const DEFAULT_POSITIVE_SPEED: [f64; 21] = [
    -3.218, 0.01472, -12.64, -0.00751, -0.1193, 14.97, -0.0003623, -0.0444, 0.02536, -9.145,
    3.208e-05, 0.0001224, 0.01372, 0.05384, 2.726, 2.842e-06, 0.0001339, -0.0006464, -0.0004289,
    -0.01816, -0.3143,
];

/// Default coefficients for `y < 0` (column `negative_speed` of shared/data/hd-loss-surface.csv).
pub(crate) const DEFAULT_NEGATIVE_SPEED: [f64; 21] = [
    3.307, 0.02794, -9.783, 0.00712, 0.08683, -13.52, -0.0002042, -0.02946, -0.002438, -11.03,
    -3.222e-05, -0.0009243, -0.00336, -0.05656, -4.223, -1.666e-06, 4.649e-05, -0.0001567,
    -0.0006695, -0.0147, -0.595,
];

/// Raw polynomial value (no clamping) with `coefficients` (in the order of [`TERM_EXPONENTS`]).
pub(crate) fn polynomial(x: f64, y: f64, coefficients: &[f64; 21]) -> f64 {
    let mut x_powers = [1.0; 6];
    let mut y_powers = [1.0; 6];
    for n in 1..6 {
        x_powers[n] = x_powers[n - 1] * x;
        y_powers[n] = y_powers[n - 1] * y;
    }
    TERM_EXPONENTS
        .iter()
        .zip(coefficients.iter())
        .map(|(&(i, j), p)| p * x_powers[i as usize] * y_powers[j as usize])
        .sum()
}

/// Gradient `(d/dx, d/dy)` of [`polynomial`] at `(x, y)` (the output derivative of the
/// actuation-side friction torque under the loss surface: the chain rule through the load
/// torque `x` and the speed `y`).
pub(crate) fn polynomial_gradient(x: f64, y: f64, coefficients: &[f64; 21]) -> (f64, f64) {
    let mut x_powers = [1.0; 6];
    let mut y_powers = [1.0; 6];
    for n in 1..6 {
        x_powers[n] = x_powers[n - 1] * x;
        y_powers[n] = y_powers[n - 1] * y;
    }
    let (mut dx, mut dy) = (0.0, 0.0);
    for (&(i, j), p) in TERM_EXPONENTS.iter().zip(coefficients.iter()) {
        let (i, j) = (i as usize, j as usize);
        if i > 0 {
            dx += p * i as f64 * x_powers[i - 1] * y_powers[j];
        }
        if j > 0 {
            dy += p * j as f64 * x_powers[i] * y_powers[j - 1];
        }
    }
    (dx, dy)
}

/// Time derivative of [`clamped_torque`] for a load torque changing at `load_torque_rate` and a
/// speed magnitude changing at `speed_rate`: the gradient inside the tested box; an argument
/// clamped to the box's edge is constant there, so it contributes nothing.
#[allow(clippy::too_many_arguments)]
pub(crate) fn clamped_torque_rate(
    load_torque: f64,
    load_torque_rate: f64,
    speed: f64,
    speed_rate: f64,
    direction: f64,
    max_speed: f64,
    load_torque_range: (f64, f64),
    coefficients: &[f64; 21],
) -> f64 {
    let x = load_torque.clamp(load_torque_range.0, load_torque_range.1);
    let magnitude = speed.min(max_speed);
    let (dx, dy) = polynomial_gradient(x, direction * magnitude, coefficients);
    let x_rate = if x == load_torque {
        load_torque_rate
    } else {
        0.0
    };
    let y_rate = if magnitude == speed {
        direction * speed_rate
    } else {
        0.0
    };
    dx * x_rate + dy * y_rate
}

/// Loss-surface torque for motion in `direction` (+1/-1) at speed magnitude `speed` >= 0 and
/// load torque `load_torque`, clamped to the tested box, with the coefficients of that direction
/// (`coefficients`). Returns the torque and whether clamping was needed.
pub(crate) fn clamped_torque(
    load_torque: f64,
    speed: f64,
    direction: f64,
    max_speed: f64,
    load_torque_range: (f64, f64),
    coefficients: &[f64; 21],
) -> (f64, bool) {
    let x = load_torque.clamp(load_torque_range.0, load_torque_range.1);
    let magnitude = speed.min(max_speed);
    let clamped = x != load_torque || magnitude != speed;
    (polynomial(x, direction * magnitude, coefficients), clamped)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The csv lives in the shared directory cloned beside the repository.
    const CSV: &str = include_str!("../../../../../shared/data/hd-loss-surface.csv");

    #[test]
    fn constants_equal_the_data_file() {
        let mut rows = 0;
        for line in CSV.lines() {
            let line = line.trim();
            if line.is_empty() || line.starts_with('#') || line.starts_with("term") {
                continue;
            }
            let fields: Vec<&str> = line.split(',').collect();
            assert_eq!(fields.len(), 3, "{line}");
            let name = fields[0].as_bytes();
            let (i, j) = ((name[1] - b'0'), (name[2] - b'0'));
            let index = TERM_EXPONENTS
                .iter()
                .position(|&e| e == (i, j))
                .expect("term in table");
            assert_eq!(index, rows, "row order");
            assert_eq!(
                DEFAULT_POSITIVE_SPEED[index],
                fields[1].parse::<f64>().unwrap()
            );
            assert_eq!(
                DEFAULT_NEGATIVE_SPEED[index],
                fields[2].parse::<f64>().unwrap()
            );
            rows += 1;
        }
        assert_eq!(rows, 21);
    }

    #[test]
    fn zero_load_reproduces_the_header_check() {
        // Header: at x = 0, surface / i_HD gives the no-load running torque at the motor side.
        let i_hd = 160.0;
        for (y, expected) in [
            (0.33f64, -0.038),
            (-0.33, 0.034),
            (2.29, -0.052),
            (-2.29, 0.054),
        ] {
            let direction: f64 = if y >= 0.0 { 1.0 } else { -1.0 };
            let coefficients = if y >= 0.0 {
                &DEFAULT_POSITIVE_SPEED
            } else {
                &DEFAULT_NEGATIVE_SPEED
            };
            let (torque, clamped) =
                clamped_torque(0.0, y.abs(), direction, 2.618, (-20.0, 20.0), coefficients);
            assert!(!clamped);
            let motor_side = torque / i_hd;
            assert!(
                (motor_side - expected).abs() <= 0.0005 + 1e-12,
                "y = {y}: {motor_side} vs {expected}"
            );
        }
    }

    #[test]
    fn clamping_is_reported() {
        let (p, n) = (&DEFAULT_POSITIVE_SPEED, &DEFAULT_NEGATIVE_SPEED);
        let (inside, c1) = clamped_torque(5.0, 1.0, 1.0, 2.618, (-20.0, 20.0), p);
        assert!(!c1);
        let (outside, c2) = clamped_torque(5.0, 10.0, 1.0, 2.618, (-20.0, 20.0), p);
        assert!(c2);
        assert_eq!(outside, polynomial(5.0, 2.618, p));
        assert_ne!(inside, outside);
        let (_, c3) = clamped_torque(-25.0, 1.0, -1.0, 2.618, (-20.0, 20.0), n);
        assert!(c3);
    }
}
