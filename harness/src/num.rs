//! Numbers in messages: readable and exact.
//!
//! [`Num`] prints a double in the shortest form that parses back to the same value, plainly
//! between 1e-5 and 1e16 (`1`, `0.45`, `0.30000000000000004`) and in exponent form outside
//! (`1e300`, `1.5e-7`), where the plain form would run to hundreds of digits.

use std::fmt;

/// A double formatted for a message (see the module documentation).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Num(pub f64);

/// [`Num`] of a referenced value (for error attributes, which pass fields by reference).
pub fn num(v: &f64) -> Num {
    Num(*v)
}

impl fmt::Display for Num {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let v = self.0;
        let a = v.abs();
        if !v.is_finite() || v == 0.0 || (1e-5..1e16).contains(&a) {
            write!(f, "{v}")
        } else {
            write!(f, "{v:e}")
        }
    }
}

#[cfg(test)]
mod tests {
    use super::Num;

    #[test]
    fn plain_in_the_middle_exponent_at_the_ends_and_always_exact() {
        let cases = [
            (1.0, "1"),
            (0.45, "0.45"),
            (0.1 + 0.2, "0.30000000000000004"),
            (1e300, "1e300"),
            (-1.5e-7, "-1.5e-7"),
            (1e16, "1e16"),
            (123456.5, "123456.5"),
            (f64::NAN, "NaN"),
            (f64::NEG_INFINITY, "-inf"),
            (0.0, "0"),
        ];
        for (v, s) in cases {
            let text = Num(v).to_string();
            assert_eq!(text, s);
            if v.is_finite() {
                assert_eq!(text.parse::<f64>().unwrap(), v);
            }
        }
    }
}
