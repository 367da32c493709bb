//! The master's integer time base.
//!
//! Time is an integer count of **ticks of 1 ns** ([`TICKS_PER_SECOND`]) from the start time.
//! The base step, every component's step and the run's length are whole numbers of ticks, and
//! the communication point of macro step `n` is computed from integers as
//!
//! ```text
//! t(n) = start + (n * base_step_ticks) as f64 / 1e9
//! ```
//!
//! never by accumulating `t += h`. The division of two exactly representable integers is
//! correctly rounded, so `t(n)` is the double nearest to the decimal time (`t(300)` with a 1 ms
//! step is exactly `0.3`, not `0.30000000000000004`), 1e6 steps of 1 ms end at exactly
//! `1000.0`, and the run has exactly `(stop - start) / h` steps. A step size that is not a
//! whole number of nanoseconds (within 1e-6 ns) is refused, as is a stop time not on the grid.
//! The step size handed to `fmi2DoStep` is the component's step in ticks divided by 1e9 (the
//! double nearest to the decimal step), the same value at every step.
//!
//! The range is bounded so the integers never overflow: the step and the run's length
//! (`stop - start`) are each at most [`MAX_TICKS`] (2^62 ns, about 146 years), and the times
//! must be resolvable: doubles near the start and stop times must be spaced at most a
//! thousandth of the step apart (a run at 1 ms steps may reach about 8.6e9 s). Anything
//! beyond is refused with a [`GridError`] that says which bound.

use model_description::num::num;

/// Ticks per second: the tick is 1 ns.
pub const TICKS_PER_SECOND: u64 = 1_000_000_000;

/// The largest step and run length, in ticks: 2^62 ns (about 146 years). Step counts,
/// products of step multiples and ticks, and tick sums stay far from `u64` overflow.
pub const MAX_TICKS: u64 = 1 << 62;

/// The finest spacing of doubles allowed near the run's times, as a fraction of the step.
const RESOLUTION: f64 = 1e-3;

/// Why a time grid could not be built.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum GridError {
    /// Step size not positive or not finite.
    #[error("step size {} must be positive and finite", num(.0))]
    BadStep(f64),
    /// A step or a run longer than [`MAX_TICKS`].
    #[error(
        "{what} {} s is beyond the master's time range (at most 2^62 ns, about 146 years)",
        num(.seconds)
    )]
    OutOfRange {
        /// What: "step size" or "stop - start".
        what: &'static str,
        /// The duration in seconds.
        seconds: f64,
    },
    /// Times so large that doubles near them are spaced too coarsely for the step.
    #[error(
        "times near {} s are {} s apart in double precision: too coarse for a step of {} s",
        num(.time),
        num(.spacing),
        num(.step)
    )]
    TooCoarse {
        /// The start or stop time.
        time: f64,
        /// The spacing of doubles there.
        spacing: f64,
        /// The step.
        step: f64,
    },
    /// Step size not a whole number of nanoseconds.
    #[error("step size {} s is not a whole number of nanoseconds (the master's tick)", num(.0))]
    StepNotOnTicks(f64),
    /// Start or stop time not finite, or stop before start.
    #[error("stop time {} must be finite and not before start time {}", num(.stop), num(.start))]
    BadInterval {
        /// Start time.
        start: f64,
        /// Stop time.
        stop: f64,
    },
    /// `stop - start` is not a whole number of steps.
    #[error(
        "stop time {} is not on the grid: (stop - start) / step = {} is not a whole number of steps of {} s",
        num(.stop),
        num(.steps),
        num(.step)
    )]
    StopOffGrid {
        /// Stop time.
        stop: f64,
        /// Step size.
        step: f64,
        /// The quotient.
        steps: f64,
    },
}

/// Converts seconds to whole ticks, refusing values that are not (within 1e-6 tick).
pub fn seconds_to_ticks(seconds: f64) -> Option<u64> {
    if !seconds.is_finite() || seconds < 0.0 {
        return None;
    }
    let t = seconds * TICKS_PER_SECOND as f64;
    let r = t.round();
    if r > MAX_TICKS as f64 {
        return None;
    }
    if (t - r).abs() <= 1e-6_f64.max(r * 1e-12) {
        Some(r as u64)
    } else {
        None
    }
}

/// A fixed-step grid: `n_steps` base steps of `step_ticks` from `start`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Grid {
    /// Start time in seconds.
    pub start: f64,
    /// The base step in ticks.
    pub step_ticks: u64,
    /// Number of base steps in the run.
    pub n_steps: u64,
}

impl Grid {
    /// Builds the grid for `[start, stop]` with base step `step` seconds.
    pub fn new(start: f64, stop: f64, step: f64) -> Result<Grid, GridError> {
        if !(step.is_finite() && step > 0.0) {
            return Err(GridError::BadStep(step));
        }
        if !(start.is_finite() && stop.is_finite() && stop >= start) {
            return Err(GridError::BadInterval { start, stop });
        }
        if step * TICKS_PER_SECOND as f64 > MAX_TICKS as f64 {
            return Err(GridError::OutOfRange {
                what: "step size",
                seconds: step,
            });
        }
        let length = stop - start;
        if length * TICKS_PER_SECOND as f64 > MAX_TICKS as f64 {
            return Err(GridError::OutOfRange {
                what: "stop - start",
                seconds: length,
            });
        }
        for time in [start, stop] {
            let spacing = ulp(time);
            if spacing > step * RESOLUTION {
                return Err(GridError::TooCoarse {
                    time,
                    spacing,
                    step,
                });
            }
        }
        let step_ticks = seconds_to_ticks(step)
            .filter(|&t| t > 0)
            .ok_or(GridError::StepNotOnTicks(step))?;
        let steps = length / step;
        let n = steps.round();
        // Relative tolerance: decimal stop times such as 0.3 with step 0.1 give 2.9999999999999996.
        if (steps - n).abs() > 1e-9 * n.max(1.0) {
            return Err(GridError::StopOffGrid { stop, step, steps });
        }
        // n * step_ticks is within MAX_TICKS (checked above, up to the rounding of the
        // quotient): checked again in integers so `time` can never overflow.
        let n_steps = n as u64;
        match n_steps.checked_mul(step_ticks) {
            Some(total) if total <= MAX_TICKS.saturating_add(step_ticks) => {}
            _ => {
                return Err(GridError::OutOfRange {
                    what: "stop - start",
                    seconds: length,
                });
            }
        }
        Ok(Grid {
            start,
            step_ticks,
            n_steps,
        })
    }

    /// The time of communication point `n` (in base steps), from integers.
    #[inline]
    pub fn time(&self, n: u64) -> f64 {
        self.start + (n * self.step_ticks) as f64 / TICKS_PER_SECOND as f64
    }

    /// The base step in seconds (the double nearest to the decimal step).
    pub fn step(&self) -> f64 {
        self.step_ticks as f64 / TICKS_PER_SECOND as f64
    }

    /// The end time `t(n_steps)`.
    pub fn stop(&self) -> f64 {
        self.time(self.n_steps)
    }
}

/// The spacing of doubles at `x` (the distance to the next double away from zero).
fn ulp(x: f64) -> f64 {
    let a = x.abs();
    f64::from_bits(a.to_bits() + 1) - a
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn times_beyond_the_range_or_the_resolution_are_refused() {
        let range = |r: Result<Grid, GridError>| match r {
            Err(GridError::OutOfRange { what, .. }) => what,
            other => panic!("{other:?}"),
        };
        assert_eq!(range(Grid::new(0.0, 1e300, 0.1)), "stop - start");
        assert_eq!(range(Grid::new(-1e300, 1e300, 1e9)), "stop - start");
        assert_eq!(range(Grid::new(0.0, 1e10, 1e10)), "step size");
        // 146 years of 1 s steps fit; the last time is exact.
        let g = Grid::new(0.0, 4.6e9, 1.0).unwrap();
        assert_eq!(g.stop(), 4.6e9);
        assert!(matches!(
            Grid::new(1e20, 1e20 + 1.0, 1e-3),
            Err(GridError::TooCoarse { .. })
        ));
        assert!(matches!(
            Grid::new(0.0, 1e10, 1e-3),
            Err(GridError::OutOfRange { .. })
        ));
        assert!(Grid::new(0.0, 1e6, 1e-3).is_ok());
        let e = Grid::new(0.0, 1e300, 0.1).unwrap_err().to_string();
        assert_eq!(
            e,
            "stop - start 1e300 s is beyond the master's time range (at most 2^62 ns, about 146 years)"
        );
    }

    #[test]
    fn a_million_millisecond_steps_end_at_1000() {
        let g = Grid::new(0.0, 1000.0, 1e-3).unwrap();
        assert_eq!(g.n_steps, 1_000_000);
        assert_eq!(g.stop(), 1000.0);
        assert_eq!(g.time(300), 0.3);
        assert_eq!(g.time(1), 0.001);
    }

    #[test]
    fn off_grid_is_refused() {
        assert!(matches!(
            Grid::new(0.0, 1.0, 0.3),
            Err(GridError::StopOffGrid { .. })
        ));
        assert!(matches!(
            Grid::new(0.0, 1.0, 1e-10),
            Err(GridError::StepNotOnTicks(_))
        ));
        assert!(Grid::new(0.0, 0.3, 0.1).is_ok());
    }
}
