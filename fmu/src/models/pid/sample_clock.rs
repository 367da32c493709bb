//! The sample grid of a discrete controller: which sample instants a communication step
//! executes, and which steps are refused (the `pid` module docs, "Sampling, communication steps
//! and direct feedthrough").

use crate::model::{ModelError, StateError, StateReader, StateWriter};
use model_description::num::num;

/// A sample instant is "at" a time within this fraction of the sample period.
pub const SAMPLE_TOLERANCE: f64 = 1e-6;

/// The sample grid of a discrete controller: instants `start + n period`, and the index of the
/// next instant not executed yet. Shared by the bench's controllers.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct SampleClock {
    /// Sample period Ts \[s\].
    pub period: f64,
    /// Time of sample 0 \[s\].
    pub start: f64,
    /// Index of the next sample instant to execute.
    pub next: u64,
    /// `1 / period`, set by [`SampleClock::new`] and [`SampleClock::load`] (a multiplication on
    /// every step instead of divisions; 0 means "divide").
    pub rate: f64,
}

impl SampleClock {
    /// A clock of period `period` whose sample 0 is at `start`.
    pub fn new(period: f64, start: f64) -> Self {
        Self {
            period,
            start,
            next: 0,
            rate: 1.0 / period,
        }
    }

    /// Position of `t` on the grid, in sample periods.
    fn position(&self, t: f64) -> f64 {
        if self.rate != 0.0 {
            (t - self.start) * self.rate
        } else {
            (t - self.start) / self.period
        }
    }

    /// The largest step whose samples [`SampleClock::run_step`] executes in one call:
    /// [`MAX_INTERNAL_STEPS_PER_CALL`](crate::model::MAX_INTERNAL_STEPS_PER_CALL) periods
    /// (unbounded before the clock has a period).
    pub fn max_step_size(&self) -> f64 {
        if self.period > 0.0 {
            crate::model::MAX_INTERNAL_STEPS_PER_CALL * self.period
        } else {
            f64::INFINITY
        }
    }

    /// Whether `t` is the next sample instant (to be executed by the next step).
    #[inline]
    pub fn is_next_sample_instant(&self, t: f64) -> bool {
        (self.position(t) - self.next as f64).abs() <= SAMPLE_TOLERANCE
    }

    /// The outputs at communication point `t`: a fresh sample from the inputs now when `t` is
    /// the next sample instant (or before initialization, when the clock has no period),
    /// else `held`, the outputs of the last executed sample. `sample` gets the sample index.
    ///
    /// The next [`SampleClock::run_step`] executes the same sample index again, and this
    /// result is deliberately not kept for it: a master that reads the outputs after each
    /// step (this project's master, Gauss-Seidel or Jacobi, and fmpy's loop) gets here the
    /// sample from the inputs of the step just done, and sets new inputs before the step that
    /// executes it. A memo keyed on the index, the inputs, the state and the settings hit 0
    /// of 315,000 PID samples in the closed-loop bench and cost instructions (README,
    /// Performance, issue 16).
    pub fn outputs_at<S>(&self, t: f64, held: S, sample: impl FnOnce(u64) -> S) -> S {
        if self.period == 0.0 || self.is_next_sample_instant(t) {
            sample(self.next)
        } else {
            held
        }
    }

    /// Executes the samples of the step `[t, t + h)` in order: `sample(index, state)` gives
    /// the sample's outputs and the next state; the last outputs become `held`. Refuses a step
    /// off the sample grid without changing anything.
    pub fn run_step<S, X>(
        &mut self,
        t: f64,
        h: f64,
        state: &mut X,
        held: &mut S,
        mut sample: impl FnMut(u64, &X) -> (S, X),
    ) -> Result<(), ModelError> {
        let count = self.samples_in_step(t, h)?;
        for _ in 0..count {
            let (signals, next) = sample(self.next, state);
            *state = next;
            *held = signals;
            self.next += 1;
        }
        Ok(())
    }

    /// How many sample instants the step `[t, t + h)` executes, or why the step is refused
    /// (the `pid` module docs, "Sampling").
    #[inline]
    pub fn samples_in_step(&self, t: f64, h: f64) -> Result<u64, ModelError> {
        let a = self.position(t);
        let b = self.position(t + h);
        // The common case, one period from the next instant (inside the grid's range): the
        // general rule gives 1.
        let next = self.next as f64;
        if (a - next).abs() <= SAMPLE_TOLERANCE
            && (b - next - 1.0).abs() <= SAMPLE_TOLERANCE
            && b <= 2f64.powi(52)
        {
            return Ok(1);
        }
        self.samples_in_general_step(a, b, t, h)
    }

    /// [`Self::samples_in_step`] for any step, at grid positions `a` and `b` of its ends.
    fn samples_in_general_step(&self, a: f64, b: f64, t: f64, h: f64) -> Result<u64, ModelError> {
        if !(a.is_finite() && b.is_finite()) || b > 2f64.powi(52) || a < -SAMPLE_TOLERANCE {
            return Err(ModelError::refused(format!(
                "the step from t = {} s by h = {} s is outside the sample grid of period {} s starting at {} s",
                num(t),
                num(h),
                num(self.period),
                num(self.start)
            )));
        }
        let on_grid = |x: f64| (x - x.round()).abs() <= SAMPLE_TOLERANCE;
        // First instant at or after the end: executed instants are next..end_index.
        let end_index = (b - SAMPLE_TOLERANCE).ceil().max(0.0) as u64;
        let count = end_index.saturating_sub(self.next);
        // Instants strictly inside (t, t + h).
        let first_after_start = (a + SAMPLE_TOLERANCE).floor().max(-1.0) as i64 + 1;
        let interior = (end_index as i64 - first_after_start).max(0);
        let whole_periods = on_grid(a) && on_grid(b);
        if interior > 0 && !whole_periods {
            return Err(ModelError::refused(format!(
                "communication step h = {} s from t = {} s does not fit the sample period Ts = {} s: \
                 a step must either span whole sample periods from a sample instant or stay within \
                 one sample period (no sample instant strictly inside the step); this one crosses \
                 {interior} sample instant(s) and {}",
                num(h),
                num(t),
                num(self.period),
                if on_grid(a) {
                    "ends between two instants"
                } else {
                    "starts between two instants"
                }
            )));
        }
        Ok(count)
    }

    /// Writes the clock.
    pub fn save(&self, w: &mut StateWriter) {
        w.f64(self.period);
        w.f64(self.start);
        w.u64(self.next);
    }

    /// Reads what [`SampleClock::save`] wrote.
    pub fn load(r: &mut StateReader<'_>) -> Result<Self, StateError> {
        let period = r.f64()?;
        let start = r.f64()?;
        let next = r.u64()?;
        Ok(Self {
            period,
            start,
            next,
            rate: 1.0 / period,
        })
    }
}
