//! The argument checks of `fmi2DoStep`: the plain checks, which name the first problem
//! ([`problem`]), and the fast test of the per-step path ([`fits`]), which accepts only
//! arguments the plain checks accept (test `a_step_that_fits_passes_every_check`), so that a
//! step with ordinary arguments costs a few comparisons, and any other step gets the plain
//! checks' verdict and message.

use model_description::num::num;

use super::instance::{TIME_TOLERANCE, same_time};

/// Why `fmi2DoStep(t, h)` is refused, the first of: `t` or `h` not finite, `h` not positive,
/// the step's end `t + h` not finite, `h` above the model's largest step `max`, `t` not the
/// instance's time `time` (within [`TIME_TOLERANCE`]), the step ending after the `stopTime`
/// `stop`; or `None`.
pub(super) fn problem(t: f64, h: f64, time: f64, stop: Option<f64>, max: f64) -> Option<String> {
    if !(t.is_finite() && h.is_finite()) {
        return Some(format!(
            "currentCommunicationPoint {} and communicationStepSize {} must be finite",
            num(t),
            num(h)
        ));
    }
    if h <= 0.0 {
        return Some(format!("communicationStepSize {} must be positive", num(h)));
    }
    if !(t + h).is_finite() {
        // The instance's time would overflow to infinity, which no state or output can hold.
        return Some(format!(
            "the step from {} by {} s ends past the largest representable time",
            num(t),
            num(h)
        ));
    }
    if h > max {
        return Some(format!(
            "communicationStepSize {} s exceeds this model's largest step per call, {} s ({} internal steps with the current parameters); split the step",
            num(h),
            num(max),
            crate::model::MAX_INTERNAL_STEPS_PER_CALL
        ));
    }
    if !same_time(t, time) {
        return Some(format!(
            "currentCommunicationPoint {} is not the last communication point {}",
            num(t),
            num(time)
        ));
    }
    if let Some(stop) = stop
        && t + h > stop
        && !same_time(t + h, stop)
    {
        return Some(format!(
            "the step to {} ends after the stopTime {} given in fmi2SetupExperiment",
            num(t + h),
            num(stop)
        ));
    }
    None
}

/// Whether [`problem`] certainly finds none: `t` within [`TIME_TOLERANCE`] of `time` (then
/// `t` is finite, and [`same_time`], whose tolerance is at least that, holds), `h` positive
/// and finite and at most `max`, the step's end finite and by `stop`. False for some
/// arguments that pass (a `t` within the relative tolerance only, a step ending just after
/// `stop`): those take the plain checks.
#[inline(always)]
pub(super) fn fits(t: f64, h: f64, time: f64, stop: Option<f64>, max: f64) -> bool {
    (t - time).abs() <= TIME_TOLERANCE
        && h > 0.0
        && h <= max
        // With t finite (the first test), a finite end implies a finite h.
        && t + h <= f64::MAX
        && stop.is_none_or(|stop| t + h <= stop)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Values around every edge of the checks: NaN, the infinities, the largest and smallest
    /// doubles, zeros of both signs, and the tolerance.
    fn values(around: f64) -> Vec<f64> {
        let mut v = vec![
            f64::NAN,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::MAX,
            f64::MIN,
            f64::MIN_POSITIVE,
            0.0,
            -0.0,
            1e-3,
            1.0,
            around,
        ];
        for d in [TIME_TOLERANCE, 1e-3, 1.0] {
            for x in [around + d, around - d] {
                v.extend([x, x.next_up(), x.next_down()]);
            }
        }
        v.extend([around.next_up(), around.next_down()]);
        v
    }

    /// A step whose end overflows to infinity is refused by both checks (found by
    /// tests/tests/call_sequence_fuzz: GaitReference, which has no largest step, took a step
    /// of f64::MAX from 1e300; its time became infinite and its FMU state could not be set
    /// again).
    #[test]
    fn a_step_whose_end_overflows_is_refused() {
        for (t, h) in [(1e300, f64::MAX), (f64::MAX, f64::MAX / 1e15)] {
            assert!(!fits(t, h, t, None, f64::INFINITY));
            let why = problem(t, h, t, None, f64::INFINITY).expect("refused");
            assert!(why.contains("largest representable time"), "{why}");
        }
        assert_eq!(problem(1e300, 1e300, 1e300, None, f64::INFINITY), None);
    }

    /// Every combination of probes: the fast test accepts only arguments the plain checks
    /// accept, and accepts the ordinary step (t the instance's time, a positive finite h up
    /// to the model's largest step, no stop time or one not passed).
    #[test]
    fn a_step_that_fits_passes_every_check() {
        let mut fitting = 0;
        let mut tried = 0;
        for time in [0.0, 2.5, 1e6, 1e300, -3.0] {
            for t in values(time) {
                for h in values(1e-3) {
                    for max in [f64::INFINITY, 10.0, 1e-3, 1e-4, f64::NAN] {
                        let ends = t + h;
                        let mut stops = vec![None, Some(f64::INFINITY), Some(f64::NAN)];
                        if ends.is_finite() {
                            stops.extend(values(ends).into_iter().map(Some));
                        }
                        for stop in stops {
                            tried += 1;
                            if fits(t, h, time, stop, max) {
                                fitting += 1;
                                assert_eq!(
                                    problem(t, h, time, stop, max),
                                    None,
                                    "t {t:e} h {h:e} time {time:e} stop {stop:?} max {max:e}"
                                );
                            }
                        }
                    }
                }
            }
        }
        assert!(
            fitting > 1000 && fitting < tried / 2,
            "{fitting} of {tried}"
        );
        for (time, h, stop, max) in [
            (0.0, 1e-3, None, f64::INFINITY),
            (2.5, 1e-3, Some(10.0), 10.0),
            (1e6, 1e-3, Some(1e6 + 1e-3), 1e-3),
        ] {
            assert!(fits(time, h, time, stop, max), "{time} {h} {stop:?} {max}");
        }
    }
}
