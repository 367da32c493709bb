//! The sample grid of a discrete controller: which sample instants a communication step
//! executes (the `pid` module docs, "Sampling, communication steps and direct feedthrough").
//! Shared by `PidController`, `ImpedanceController` and `ClutchScheduler`.

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
    #[inline]
    pub fn outputs_at<S>(&self, t: f64, held: S, sample: impl FnOnce(u64) -> S) -> S {
        if self.period == 0.0 || self.is_next_sample_instant(t) {
            sample(self.next)
        } else {
            held
        }
    }

    /// Executes the samples of the step `[t, t + h)` in order: `sample(index, state)` gives
    /// the sample's outputs and the next state; the last outputs become `held`. A step may end
    /// between two instants (the clock then waits for the next one). Refuses a step outside the
    /// grid's exact range (not finite, before sample 0, beyond 2^52 periods) without changing
    /// anything.
    #[inline]
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
    /// (outside the grid's exact range; the `pid` module docs, "Sampling").
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

    /// [`Self::samples_in_step`] for any step, at grid positions `a` and `b` of its ends: the
    /// instants `next..` up to (not including) the first one at or after the end. A step may
    /// start and end anywhere on or between instants (the `pid` module docs, "Sampling"); only
    /// positions the grid cannot count exactly are refused.
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
        // First instant at or after the end (an instant within the tolerance of the end belongs
        // to the next step): the step executes the instants next..end_index.
        let end_index = (b - SAMPLE_TOLERANCE).ceil().max(0.0) as u64;
        Ok(end_index.saturating_sub(self.next))
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

#[cfg(test)]
mod tests {
    use super::*;

    const TS: f64 = 1e-3;

    /// Runs the steps `(t, h)` in order on a clock of period 1 ms from 0; returns the sample
    /// indices each step executed and the clock after them.
    fn executed(steps: &[(f64, f64)]) -> (Vec<Vec<u64>>, SampleClock) {
        let mut clock = SampleClock::new(TS, 0.0);
        let (mut state, mut held) = (0u64, 0u64);
        let out = steps
            .iter()
            .map(|&(t, h)| {
                let mut run = Vec::new();
                clock
                    .run_step(t, h, &mut state, &mut held, |index, &n| {
                        run.push(index);
                        (index, n + 1)
                    })
                    .unwrap_or_else(|e| panic!("step ({t}, {h}): {e}"));
                assert_eq!(
                    state, clock.next,
                    "every executed instant advances the state once"
                );
                run
            })
            .collect();
        (out, clock)
    }

    #[test]
    fn steps_on_the_grid_and_within_one_period_count_as_before() {
        let c = SampleClock::new(TS, 0.0);
        assert_eq!(c.samples_in_step(0.0, 1e-3).unwrap(), 1);
        assert_eq!(c.samples_in_step(0.0, 5e-3).unwrap(), 5);
        // Sub-steps: the first half executes the instant at its start, the second none.
        assert_eq!(c.samples_in_step(0.0, 0.5e-3).unwrap(), 1);
        let c1 = SampleClock { next: 1, ..c };
        assert_eq!(c1.samples_in_step(0.5e-3, 0.5e-3).unwrap(), 0);
        // Decimal times count as on the grid.
        let c3 = SampleClock { next: 3, ..c };
        assert_eq!(c3.samples_in_step(0.003, 0.002).unwrap(), 2);
        // An instant within the tolerance of the end belongs to the next step.
        assert_eq!(c.samples_in_step(0.0, 2e-3 + 1e-10).unwrap(), 2);
        assert_eq!(c.samples_in_step(0.0, 2e-3 - 1e-10).unwrap(), 2);
    }

    /// Steps that cross instants and end between two execute the instants in `[t, t + h)`
    /// (an instant at the start is executed, one at the end belongs to the next step) and
    /// leave the clock between two instants.
    #[test]
    fn steps_off_the_grid_execute_the_instants_they_reach() {
        let c = SampleClock::new(TS, 0.0);
        // From 0 by 1.5 ms: the instants 0 and 1 ms.
        assert_eq!(c.samples_in_step(0.0, 1.5e-3).unwrap(), 2);
        // From between two instants across the next one.
        let c1 = SampleClock { next: 1, ..c };
        assert_eq!(c1.samples_in_step(0.5e-3, 1e-3).unwrap(), 1);

        let h = 1.5e-3;
        let steps: Vec<(f64, f64)> = (0..6).map(|k| (k as f64 * h, h)).collect();
        let (runs, clock) = executed(&steps);
        // [0, 1.5): 0 and 1 ms; [1.5, 3): 2 ms (3 ms is the next step's start); [3, 4.5): 3
        // and 4 ms; [4.5, 6): 5 ms; ...
        let want: [&[u64]; 6] = [&[0, 1], &[2], &[3, 4], &[5], &[6, 7], &[8]];
        assert_eq!(runs, want);
        assert_eq!(clock.next, 9);

        let h = 2.5e-3;
        let steps: Vec<(f64, f64)> = (0..4).map(|k| (k as f64 * h, h)).collect();
        let (runs, clock) = executed(&steps);
        let want: [&[u64]; 4] = [&[0, 1, 2], &[3, 4], &[5, 6, 7], &[8, 9]];
        assert_eq!(runs, want);
        assert_eq!(clock.next, 10);

        // Mixed sizes, with a step of whole periods from off the grid and a step within one
        // period: every instant exactly once, in order.
        let steps = [
            (0.0, 0.3e-3),
            (0.3e-3, 1.5e-3),
            (1.8e-3, 2e-3),
            (3.8e-3, 0.1e-3),
            (3.9e-3, 0.1e-3),
            (4e-3, 2.7e-3),
        ];
        let (runs, clock) = executed(&steps);
        let want: [&[u64]; 6] = [&[0], &[1], &[2, 3], &[], &[], &[4, 5, 6]];
        assert_eq!(runs, want);
        assert_eq!(clock.next, 7);
    }

    /// Between two instants the outputs are those of the last executed sample; at the next
    /// instant, a fresh sample of that index.
    #[test]
    fn after_a_step_off_the_grid_the_outputs_hold_until_the_next_instant() {
        let (_, clock) = executed(&[(0.0, 1.5e-3)]);
        assert_eq!(clock.next, 2);
        assert!(!clock.is_next_sample_instant(1.5e-3));
        assert_eq!(clock.outputs_at(1.5e-3, 1, |k| k + 100), 1);
        let (_, clock) = executed(&[(0.0, 1.5e-3), (1.5e-3, 1.5e-3)]);
        assert!(clock.is_next_sample_instant(3e-3));
        assert_eq!(clock.outputs_at(3e-3, 2, |k| k + 100), 103);
    }

    #[test]
    fn positions_the_grid_cannot_count_are_refused_before_anything_changes() {
        let c = SampleClock::new(TS, 0.0);
        for (t, h) in [
            (f64::NAN, 1e-3),
            (0.0, f64::INFINITY),
            (-1e-3, 1e-3),
            (0.0, 2f64.powi(52) * TS * 1.5),
        ] {
            let e = c.samples_in_step(t, h).unwrap_err();
            assert!(e.is_refused(), "{e}");
            assert!(e.message.contains("outside the sample grid"), "{e}");
            let mut d = c;
            let (mut state, mut held) = (0u64, 0u64);
            assert!(
                d.run_step(t, h, &mut state, &mut held, |k, &n| (k, n + 1))
                    .is_err()
            );
            assert_eq!((d, state, held), (c, 0, 0), "nothing changed");
        }
    }
}
