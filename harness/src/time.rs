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

/// Ticks per second: the tick is 1 ns.
pub const TICKS_PER_SECOND: u64 = 1_000_000_000;

/// Why a time grid could not be built.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum GridError {
    /// Step size not positive or not finite.
    #[error("step size {0} must be positive and finite")]
    BadStep(f64),
    /// Step size not a whole number of nanoseconds.
    #[error("step size {0} s is not a whole number of nanoseconds (the master's tick)")]
    StepNotOnTicks(f64),
    /// Start or stop time not finite, or stop before start.
    #[error("stop time {stop} must be finite and not before start time {start}")]
    BadInterval {
        /// Start time.
        start: f64,
        /// Stop time.
        stop: f64,
    },
    /// `stop - start` is not a whole number of steps.
    #[error(
        "stop time {stop} is not on the grid: (stop - start) / step = {steps} is not a whole number of steps of {step} s"
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
    if r > (1u64 << 62) as f64 {
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
        let step_ticks = seconds_to_ticks(step)
            .filter(|&t| t > 0)
            .ok_or(GridError::StepNotOnTicks(step))?;
        let steps = (stop - start) / step;
        let n = steps.round();
        // Relative tolerance: decimal stop times such as 0.3 with step 0.1 give 2.9999999999999996.
        if (steps - n).abs() > 1e-9 * n.max(1.0) {
            return Err(GridError::StopOffGrid { stop, step, steps });
        }
        Ok(Grid {
            start,
            step_ticks,
            n_steps: n as u64,
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

#[cfg(test)]
mod tests {
    use super::*;

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
