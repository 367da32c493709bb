//! Real-time pacing of `fmi2DoStep`: sleep until an absolute deadline on the monotonic clock.
//!
//! The deadline of the step ending at FMU time `t_end` is `origin + (t_end - t_start)`, where
//! `origin` is the monotonic instant of the first step's start. Deadlines are never
//! accumulated from `sleep(h)` calls, so a late wake-up does not shift later deadlines: the
//! loop catches up instead of drifting. The wait is hybrid: an absolute sleep on the
//! monotonic clock (`clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME)` on Linux, see
//! [`super::realtime`]) until `spin` before the deadline, then a spin (with `spin_loop` hints)
//! for the rest, because a sleep wakes up late by the kernel's timer slack (50 us by default on
//! Linux for a normal thread) plus the scheduling latency. An absolute sleep (rather than
//! `sleep(deadline - now)`) is not lengthened by a preemption between reading the clock and
//! going to sleep.
//!
//! An **overrun** is a step that reaches its deadline already late: the work of the period
//! (master, controller, I/O) took longer than the period. [`PacingMode::Soft`] counts and
//! reports it; [`PacingMode::Hard`] makes it a trip (the "control period missed" watchdog).
//! The **lateness** of a step is how far after its deadline the step continued (wake-up jitter
//! for steps that slept, the overrun for steps that did not).

use std::time::Duration;

use super::realtime::{now_ns, sleep_until_ns};

/// How `fmi2DoStep` keeps time.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PacingMode {
    /// As fast as possible (simulated backend only).
    None,
    /// Real time; overruns are counted and logged as warnings.
    Soft,
    /// Real time; an overrun trips the bench.
    Hard,
}

impl PacingMode {
    /// From the FMU's enumeration value (0 None, 1 Soft, 2 Hard).
    pub fn from_i32(v: i32) -> Option<Self> {
        match v {
            0 => Some(Self::None),
            1 => Some(Self::Soft),
            2 => Some(Self::Hard),
            _ => None,
        }
    }
}

/// What one wait found.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Wait {
    /// Seconds after the deadline the step continued (0 with no pacing).
    pub lateness: f64,
    /// The deadline had passed before the wait began.
    pub overrun: bool,
}

/// Pacing statistics of a run.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct PacingStats {
    /// Steps paced.
    pub steps: u64,
    /// Overruns.
    pub overruns: u64,
    /// Lateness of the last step \[s\].
    pub last_lateness: f64,
    /// Largest lateness \[s\].
    pub max_lateness: f64,
}

/// Sleeps until absolute deadlines.
#[derive(Debug, Clone)]
pub struct Pacer {
    mode: PacingMode,
    spin_ns: u64,
    /// Monotonic nanoseconds and FMU time of the first step's start.
    origin: Option<(u64, f64)>,
    /// The statistics so far.
    pub stats: PacingStats,
}

impl Pacer {
    /// A pacer in `mode`, spinning the last `spin` before each deadline.
    pub fn new(mode: PacingMode, spin: Duration) -> Self {
        Self {
            mode,
            spin_ns: u64::try_from(spin.as_nanos()).unwrap_or(u64::MAX),
            origin: None,
            stats: PacingStats::default(),
        }
    }

    /// The mode.
    pub fn mode(&self) -> PacingMode {
        self.mode
    }

    /// Marks the start of the step beginning at FMU time `t` (the first call fixes the origin).
    pub fn start(&mut self, t: f64) {
        if self.origin.is_none() && self.mode != PacingMode::None {
            self.origin = Some((now_ns(), t));
        }
    }

    /// The deadline of FMU time `t_end` on the monotonic clock \[ns\] (see
    /// [`super::realtime::now_ns`]), once the origin is fixed. FMU time is rounded to the
    /// nanosecond.
    pub fn deadline_ns(&self, t_end: f64) -> Option<u64> {
        let (origin, t0) = self.origin?;
        Some(origin + ((t_end - t0).max(0.0) * 1e9).round() as u64)
    }

    /// Waits until the deadline of FMU time `t_end`.
    pub fn wait(&mut self, t_end: f64) -> Wait {
        let Some(deadline) = self.deadline_ns(t_end) else {
            return Wait {
                lateness: 0.0,
                overrun: false,
            };
        };
        self.stats.steps += 1;
        let now = now_ns();
        let overrun = now > deadline;
        if !overrun {
            if deadline - now > self.spin_ns {
                sleep_until_ns(deadline - self.spin_ns);
            }
            while now_ns() < deadline {
                std::hint::spin_loop();
            }
        }
        let lateness = now_ns().saturating_sub(deadline) as f64 * 1e-9;
        if overrun {
            self.stats.overruns += 1;
        }
        self.stats.last_lateness = lateness;
        self.stats.max_lateness = self.stats.max_lateness.max(lateness);
        Wait { lateness, overrun }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Instant;

    #[test]
    fn deadlines_are_absolute_and_overruns_counted() {
        let mut p = Pacer::new(PacingMode::Soft, Duration::from_micros(200));
        let h = 2e-3;
        p.start(0.0);
        let begin = Instant::now();
        for k in 1..=10 {
            p.wait(k as f64 * h);
            // Never early: each wait ends at or after its absolute deadline.
            assert!(begin.elapsed().as_secs_f64() >= k as f64 * h - 1e-4);
        }
        // A step whose work takes several periods overruns; later deadlines stay absolute.
        std::thread::sleep(Duration::from_secs_f64(4.0 * h));
        let before = p.stats.overruns;
        assert!(p.wait(11.0 * h).overrun);
        assert_eq!(p.stats.overruns, before + 1);
        p.wait(40.0 * h);
        assert!(begin.elapsed().as_secs_f64() >= 40.0 * h - 1e-4);
        assert_eq!(p.stats.steps, 12);
        assert!(p.stats.max_lateness >= 2.0 * h);
    }

    #[test]
    fn no_pacing_never_waits() {
        let mut p = Pacer::new(PacingMode::None, Duration::ZERO);
        p.start(0.0);
        let begin = Instant::now();
        assert!(!p.wait(100.0).overrun);
        assert!(begin.elapsed() < Duration::from_millis(50));
        assert_eq!(p.stats.steps, 0);
    }
}
