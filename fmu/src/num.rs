//! Compact numbers in log messages: `{}` of an `f64` writes every digit (hundreds for 5e-324
//! or 1e300), so values far from 1 are written in exponent form; the others exactly as `{}`
//! writes them, so ordinary messages read as before.

use std::fmt;

/// An `f64` displayed compactly (module docs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Num(pub f64);

/// `v`, displayed compactly (module docs).
pub fn num(v: f64) -> Num {
    Num(v)
}

impl fmt::Display for Num {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let v = self.0;
        if !v.is_finite() || v == 0.0 || (1e-5..1e16).contains(&v.abs()) {
            write!(f, "{v}")
        } else {
            write!(f, "{v:e}")
        }
    }
}

#[cfg(test)]
mod tests {
    use super::num;

    #[test]
    fn extreme_values_are_short_and_ordinary_ones_unchanged() {
        for (v, want) in [
            (5e-324, "5e-324"),
            (-1e300, "-1e300"),
            (1.5e-6, "1.5e-6"),
            (1e16, "1e16"),
            (0.0, "0"),
            (-0.0, "-0"),
            (20.0, "20"),
            (1e6, "1000000"),
            (0.001, "0.001"),
            (0.1 + 0.2, "0.30000000000000004"),
            (f64::NAN, "NaN"),
            (f64::NEG_INFINITY, "-inf"),
        ] {
            assert_eq!(num(v).to_string(), want, "{v:e}");
        }
    }
}
