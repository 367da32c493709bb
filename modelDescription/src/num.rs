//! Numbers in messages, compact and exact: the one formatting of a double that the FMUs' log
//! messages and the harness's errors share (both crates depend on this one).
//!
//! [`Num`] prints a double in the shortest form that parses back to the same value (`{}` of an
//! `f64`), plainly between 1e-5 and 1e16 in magnitude (`1`, `0.45`, `0.30000000000000004`) and
//! in exponent form outside (`1e300`, `1.5e-7`, `5e-324`), where the plain form would run to
//! hundreds of digits. Zero, NaN and the infinities print as `{}` prints them.

use std::borrow::Borrow;
use std::fmt;

/// A double formatted for a message (see the module documentation).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Num(pub f64);

/// [`Num`] of a value or of a reference to one (error attributes pass fields by reference).
pub fn num(v: impl Borrow<f64>) -> Num {
    Num(*v.borrow())
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
    use super::{Num, num};

    #[test]
    fn plain_in_the_middle_exponent_at_the_ends_and_always_exact() {
        let cases = [
            (1.0, "1"),
            (20.0, "20"),
            (0.45, "0.45"),
            (0.001, "0.001"),
            (0.1 + 0.2, "0.30000000000000004"),
            (1e6, "1000000"),
            (123456.5, "123456.5"),
            (1e300, "1e300"),
            (-1e300, "-1e300"),
            (-1.5e-7, "-1.5e-7"),
            (1.5e-6, "1.5e-6"),
            (5e-324, "5e-324"),
            (1e16, "1e16"),
            (f64::NAN, "NaN"),
            (f64::NEG_INFINITY, "-inf"),
            (0.0, "0"),
            (-0.0, "-0"),
        ];
        for (v, s) in cases {
            let text = Num(v).to_string();
            assert_eq!(text, s, "{v:e}");
            // By value and by reference alike.
            assert_eq!(num(v).to_string(), s);
            let by_reference: &f64 = &v;
            assert_eq!(num(by_reference).to_string(), s);
            if v.is_finite() {
                assert_eq!(text.parse::<f64>().unwrap().to_bits(), v.to_bits());
            }
        }
    }
}
