//! Cross-checks between sensors that measure the same torque two ways, so that a sensor stuck
//! at a value inside its plausibility window is found.
//!
//! A plausibility window (`calibration::Plausibility`) only sees readings that are impossible;
//! an amplifier that freezes, a broken wire pulled to mid-rail or a seized ADC channel keeps
//! reporting a believable value. The bench measures two torques twice:
//!
//! * **Torque transducer vs spring deflection** (SEA and CSEA): the transducer sits in series
//!   with the spring on the load side, so it carries the spring torque `k (theta1 - theta2)`,
//!   which the two encoders give independently (`k` the configuration's stiffness). Not in DA,
//!   where the blocked spring's deflection is below the encoders' resolution.
//! * **Load cell vs test-motor current**: the load cell measures the test motor's reaction
//!   torque, `i_HD Km1 i1`, which the current sensor gives independently.
//!
//! A pair disagrees when `|measured - expected| > tolerance + relative * max(|measured|,
//! |expected|)`; a disagreement in `persistence` consecutive samples is a sensor fault (a
//! latched trip). Defaults and their derivation are on the `BenchHardware` documentation page
//! ("Sensor consistency").

/// Which cross-check failed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Inconsistency {
    /// The torque transducer disagrees with `k` times the encoders' spring deflection.
    Transducer {
        /// The transducer's torque [N m].
        measured: f64,
        /// `k (theta1 - theta2)` [N m].
        expected: f64,
    },
    /// The load cell disagrees with `i_HD Km1` times the measured test-motor current.
    LoadCell {
        /// The load cell's torque [N m].
        measured: f64,
        /// `i_HD Km1 i1` [N m].
        expected: f64,
    },
}

impl std::fmt::Display for Inconsistency {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Inconsistency::Transducer { measured, expected } => write!(
                f,
                "torque transducer reads {measured:.3} N m, the spring deflection gives {expected:.3} N m"
            ),
            Inconsistency::LoadCell { measured, expected } => write!(
                f,
                "load cell reads {measured:.3} N m, the test-motor current gives {expected:.3} N m"
            ),
        }
    }
}

/// The cross-checks' limits and their persistence counters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ConsistencyCheck {
    /// Absolute allowance [N m].
    pub tolerance: f64,
    /// Allowance per N m of the larger of the two torques.
    pub relative: f64,
    /// Consecutive disagreeing samples that make a fault (0: the checks are off).
    pub persistence: u32,
    /// Consecutive disagreeing samples so far: transducer, load cell.
    run: [u32; 2],
}

impl ConsistencyCheck {
    /// The defaults of the `BenchHardware` parameters.
    pub const DEFAULT_TOLERANCE: f64 = 1.0;
    /// Default relative allowance.
    pub const DEFAULT_RELATIVE: f64 = 0.25;
    /// Default persistence \[samples\].
    pub const DEFAULT_PERSISTENCE: u32 = 10;

    /// Checks with these limits, counters at zero.
    pub fn new(tolerance: f64, relative: f64, persistence: u32) -> Self {
        Self {
            tolerance,
            relative,
            persistence,
            run: [0; 2],
        }
    }

    /// The largest disagreement allowed between `a` and `b`.
    pub fn allowance(&self, a: f64, b: f64) -> f64 {
        self.tolerance + self.relative * a.abs().max(b.abs())
    }

    /// Whether `a` and `b` disagree.
    pub fn disagree(&self, a: f64, b: f64) -> bool {
        // A non-finite reading disagrees.
        let difference = (a - b).abs();
        let allowance = self.allowance(a, b);
        !(difference.is_finite() && allowance.is_finite()) || difference > allowance
    }

    /// Consecutive disagreeing samples so far (transducer, load cell).
    pub fn runs(&self) -> [u32; 2] {
        self.run
    }

    /// Takes one sample: `transducer` is (measured, expected) when the configuration has a
    /// spring, `load_cell` likewise. Returns the fault once a pair has disagreed in
    /// `persistence` consecutive samples (the transducer first when both have).
    pub fn update(
        &mut self,
        transducer: Option<(f64, f64)>,
        load_cell: (f64, f64),
    ) -> Option<Inconsistency> {
        if self.persistence == 0 {
            return None;
        }
        let pairs = [transducer, Some(load_cell)];
        for (k, pair) in pairs.into_iter().enumerate() {
            self.run[k] = match pair {
                Some((m, e)) if self.disagree(m, e) => self.run[k].saturating_add(1),
                _ => 0,
            };
        }
        if self.run[0] >= self.persistence
            && let Some((measured, expected)) = transducer
        {
            return Some(Inconsistency::Transducer { measured, expected });
        }
        if self.run[1] >= self.persistence {
            let (measured, expected) = load_cell;
            return Some(Inconsistency::LoadCell { measured, expected });
        }
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_disagreement_trips_after_exactly_the_persistence() {
        let mut c = ConsistencyCheck::new(1.0, 0.25, 3);
        // Within the allowance: 10 vs 12 is 2 <= 1 + 0.25 * 12 = 4.
        for _ in 0..10 {
            assert_eq!(c.update(Some((10.0, 12.0)), (0.0, 0.0)), None);
        }
        // Two disagreeing samples, one good one: the count starts again.
        assert_eq!(c.update(Some((2.0, 8.0)), (0.0, 0.0)), None);
        assert_eq!(c.update(Some((2.0, 8.0)), (0.0, 0.0)), None);
        assert_eq!(c.update(Some((2.0, 3.0)), (0.0, 0.0)), None);
        assert_eq!(c.runs(), [0, 0]);
        assert_eq!(c.update(Some((2.0, 8.0)), (0.0, 0.0)), None);
        assert_eq!(c.update(Some((2.0, 8.0)), (0.0, 0.0)), None);
        assert_eq!(
            c.update(Some((2.0, 8.0)), (0.0, 0.0)),
            Some(Inconsistency::Transducer {
                measured: 2.0,
                expected: 8.0
            })
        );
        // The load cell pair, with no spring (DA).
        let mut c = ConsistencyCheck::new(1.0, 0.25, 2);
        assert_eq!(c.update(None, (0.5, 5.0)), None);
        assert!(matches!(
            c.update(None, (0.5, 5.0)),
            Some(Inconsistency::LoadCell { .. })
        ));
        // A NaN disagrees; persistence 0 turns the checks off.
        let mut c = ConsistencyCheck::new(1.0, 0.25, 1);
        assert!(c.update(None, (f64::NAN, 0.0)).is_some());
        let mut off = ConsistencyCheck::new(1.0, 0.25, 0);
        assert_eq!(off.update(Some((0.0, 100.0)), (0.0, 100.0)), None);
    }
}
