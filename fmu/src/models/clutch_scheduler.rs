//! # ClutchScheduler: when the CSEA's clutch locks the actuation side (bench facts, section 4)
//!
//! Decides, at each sample (period `samplePeriod`, default 1 ms), whether the electromagnetic
//! clutch is engaged, and tells the position controller to hold while it is. Outputs
//! `clutchEngage` (wire to the plant's `clutchEngage`), `holdPosition` (wire to the
//! `PidController`'s or `ImpedanceController`'s `hold`) and `timeInState`.
//!
//! ## Modes (`mode`)
//! * `Off`: never engaged (DA and SEA runs, or a CSEA run without clutch).
//! * `GaitPhase` (default, as on the bench): engaged while the input `gaitPhase` (wire the
//!   `GaitReference`'s `gaitPhase`, in [0, 1)) lies in the window `[engageStart, engageEnd)`.
//!   When `engageStart > engageEnd` the window wraps around the end of the cycle (e.g. 0.9 to
//!   0.2 engages from 90 % of one cycle to 20 % of the next). An empty window is refused. The
//!   defaults, 0.10 to 0.40, are the mid-stance part of the default gait where the knee-angle
//!   reference moves slowest (|omega_ref| < 0.3 rad/s at 60 deg amplitude; the angle goes from
//!   15 to 9 deg): the actuation side is locked there and the knee follows only through the
//!   spring.
//! * `LowSpeed` (the adaptive alternative): engages when `|velocityReference|` has stayed
//!   below `engageSpeed` for `engageDelay` (a debounce, so that the brief zero crossing at the
//!   swing's peak does not lock the knee), releases as soon as it rises above `releaseSpeed`
//!   (> `engageSpeed`: hysteresis, no chatter around one threshold).
//!
//! In every mode a switch (either way) also waits until the clutch has been in its current
//! state for `minimumDwell` (0 disables; the first switch of a run does not wait), which
//! protects the clutch from rapid cycling.
//!
//! `holdPosition` equals `clutchEngage` when `holdWhileEngaged` (default) is true, else it is
//! always false (the controller keeps acting against the locked side).
//!
//! ## Sampling and feedthrough
//! As for `PidController` (the same sample clock): the samples in `[t, t + h)` run with the
//! inputs held over the step (FMI 2.0's inputs are constant over a step); any step is
//! accepted, also one that crosses instants and ends between two (the clock then waits there
//! for the next instant); at a sample instant the outputs are the decision of that sample from
//! the inputs just set (direct feedthrough from `gaitPhase` and `velocityReference`); between
//! instants they are those of the last executed sample. The plant samples `clutchEngage` at
//! the start of its step, so a Gauss-Seidel master that steps the reference first gives the
//! clutch the decision for the same instant. Times (delay, dwell, `timeInState`) are counted in
//! whole samples: a duration is reached at the first sample at least that long after its
//! start.

use crate::release::Lazy;

use super::pid::SampleClock;
use crate::model::{
    EnumerationType, Model, ModelError, Start, StateError, StateReader, StateWriter, StepOutcome,
    Variable,
};
use crate::registry::ReferenceInputs;
use model_description::num::num;

/// How the scheduler decides.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ClutchMode {
    /// Never engaged.
    Off = 0,
    /// Engaged inside the gait-phase window.
    GaitPhase = 1,
    /// Engaged at low reference speed, with hysteresis.
    LowSpeed = 2,
}

impl ClutchMode {
    /// From the FMU's enumeration value.
    pub fn from_i32(v: i32) -> Option<Self> {
        match v {
            0 => Some(Self::Off),
            1 => Some(Self::GaitPhase),
            2 => Some(Self::LowSpeed),
            _ => None,
        }
    }
}

/// The scheduler's parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ClutchSettings {
    /// Mode.
    pub mode: ClutchMode,
    /// Window start (gait phase).
    pub engage_start: f64,
    /// Window end (gait phase).
    pub engage_end: f64,
    /// Engage below this |omega_ref| [rad/s].
    pub engage_speed: f64,
    /// Release above this |omega_ref| [rad/s].
    pub release_speed: f64,
    /// The low-speed condition must last this long before engaging \[s\].
    pub engage_delay: f64,
    /// Minimum time between switches \[s\].
    pub minimum_dwell: f64,
    /// holdPosition follows the clutch.
    pub hold_while_engaged: bool,
    /// Sample period \[s\].
    pub sample_period: f64,
}

impl ClutchSettings {
    /// Whether `phase` (wrapped into [0, 1)) lies in the window.
    pub fn in_window(&self, phase: f64) -> bool {
        let p = phase - phase.floor();
        if self.engage_start < self.engage_end {
            (self.engage_start..self.engage_end).contains(&p)
        } else {
            p >= self.engage_start || p < self.engage_end
        }
    }

    /// Whether `samples` sample periods reach `duration`.
    fn reached(&self, samples: u64, duration: f64) -> bool {
        samples as f64 * self.sample_period >= duration - 1e-9 * self.sample_period
    }
}

/// The scheduler's state between samples.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ClutchState {
    /// Clutch engaged after the last sample.
    pub engaged: bool,
    /// Index of the sample of the last switch (`None`: none yet).
    pub last_switch: Option<u64>,
    /// Index of the first sample of the current run of low-speed samples.
    pub low_since: Option<u64>,
}

/// The outputs of one sample.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ClutchSignals {
    /// Clutch command.
    pub engage: bool,
    /// Hold command for the position controller.
    pub hold: bool,
    /// Time since the last switch (or since the start) \[s\].
    pub time_in_state: f64,
}

/// Sample `n` with the inputs (gait phase, reference velocity): outputs and next state.
pub fn clutch_sample(
    s: &ClutchSettings,
    state: &ClutchState,
    n: u64,
    gait_phase: f64,
    velocity_reference: f64,
) -> (ClutchSignals, ClutchState) {
    let speed = velocity_reference.abs();
    let low = speed < s.engage_speed;
    let low_since = if low {
        Some(state.low_since.unwrap_or(n))
    } else {
        None
    };
    let desired = match s.mode {
        ClutchMode::Off => false,
        ClutchMode::GaitPhase => s.in_window(gait_phase),
        ClutchMode::LowSpeed => {
            if state.engaged {
                speed <= s.release_speed
            } else {
                low_since.is_some_and(|since| s.reached(n - since.min(n), s.engage_delay))
            }
        }
    };
    let dwell_over = state
        .last_switch
        .is_none_or(|k| s.reached(n - k.min(n), s.minimum_dwell));
    let mut next = ClutchState {
        low_since,
        ..*state
    };
    if desired != state.engaged && dwell_over {
        next.engaged = desired;
        next.last_switch = Some(n);
    }
    let in_state = n - next.last_switch.unwrap_or(0).min(n);
    (
        ClutchSignals {
            engage: next.engaged,
            hold: next.engaged && s.hold_while_engaged,
            time_in_state: in_state as f64 * s.sample_period,
        },
        next,
    )
}

/// The clutch scheduler FMU.
#[derive(Debug, Clone, Default)]
pub struct ClutchScheduler {
    mode: i32,
    engage_start: f64,
    engage_end: f64,
    engage_speed: f64,
    release_speed: f64,
    engage_delay: f64,
    minimum_dwell: f64,
    hold_while_engaged: bool,
    sample_period: f64,

    gait_phase: f64,
    velocity_reference: f64,
    signals: ClutchSignals,

    clock: SampleClock,
    state: ClutchState,
    held: ClutchSignals,
}

mod vr {
    pub const MODE: u32 = 1;
    pub const ENGAGE_START: u32 = 2;
    pub const ENGAGE_END: u32 = 3;
    pub const ENGAGE_SPEED: u32 = 4;
    pub const RELEASE_SPEED: u32 = 5;
    pub const ENGAGE_DELAY: u32 = 6;
    pub const MINIMUM_DWELL: u32 = 7;
    pub const HOLD_WHILE_ENGAGED: u32 = 8;
    pub const SAMPLE_PERIOD: u32 = 9;
    pub const GAIT_PHASE: u32 = 100;
    pub const VELOCITY_REFERENCE: u32 = 101;
    pub const CLUTCH_ENGAGE: u32 = 200;
    pub const HOLD_POSITION: u32 = 201;
    pub const TIME_IN_STATE: u32 = 202;
}

const KNOWNS: &[&str] = &[
    "gaitPhase",
    "velocityReference",
    "mode",
    "engageStart",
    "engageEnd",
    "engageSpeed",
    "releaseSpeed",
    "engageDelay",
    "minimumDwell",
    "holdWhileEngaged",
    "samplePeriod",
];

static ENUMERATIONS: &[EnumerationType] = &[EnumerationType {
    name: "ClutchMode",
    description: "How the clutch scheduler decides",
    items: &[
        ("Off", 0, "Never engaged"),
        (
            "GaitPhase",
            1,
            "Engaged while the gait phase is in [engageStart, engageEnd) (wrapping around)",
        ),
        (
            "LowSpeed",
            2,
            "Engaged after |velocityReference| stayed below engageSpeed for engageDelay; released above releaseSpeed",
        ),
    ],
}];

// SAFETY: a static (Lazy registers its address for the release at unload).
static VARIABLES: Lazy<Vec<Variable<ClutchScheduler>>> = unsafe {
    Lazy::new(|| {
        use Start::{Boolean, Integer, Real};
        type V = Variable<ClutchScheduler>;
        vec![
        V::enumeration("mode", vr::MODE, "ClutchMode", |m| m.mode, |m, v| m.mode = v)
            .tunable(Integer(ClutchMode::GaitPhase as i32))
            .describe("How the scheduler decides"),
        V::real("engageStart", vr::ENGAGE_START, |m| m.engage_start, |m, v| m.engage_start = v)
            .tunable(Real(0.10))
            .range(0.0, 1.0)
            .describe("GaitPhase mode: gait phase at which the clutch engages"),
        V::real("engageEnd", vr::ENGAGE_END, |m| m.engage_end, |m, v| m.engage_end = v)
            .tunable(Real(0.40))
            .range(0.0, 1.0)
            .describe("GaitPhase mode: gait phase at which it releases (below engageStart: the window wraps)"),
        V::real("engageSpeed", vr::ENGAGE_SPEED, |m| m.engage_speed, |m, v| m.engage_speed = v)
            .tunable(Real(0.3))
            .unit("rad/s")
            .display("deg/s")
            .range(0.0, 100.0)
            .describe("LowSpeed mode: engage when |velocityReference| stays below this"),
        V::real("releaseSpeed", vr::RELEASE_SPEED, |m| m.release_speed, |m, v| m.release_speed = v)
            .tunable(Real(0.45))
            .unit("rad/s")
            .display("deg/s")
            .range(0.0, 100.0)
            .describe("LowSpeed mode: release when |velocityReference| rises above this (>= engageSpeed)"),
        V::real("engageDelay", vr::ENGAGE_DELAY, |m| m.engage_delay, |m, v| m.engage_delay = v)
            .tunable(Real(0.1))
            .unit("s")
            .range(0.0, 1e3)
            .describe("LowSpeed mode: how long the low-speed condition must last before engaging"),
        V::real("minimumDwell", vr::MINIMUM_DWELL, |m| m.minimum_dwell, |m, v| m.minimum_dwell = v)
            .tunable(Real(0.05))
            .unit("s")
            .range(0.0, 1e3)
            .describe("Minimum time in a state before the next switch (0: none)"),
        V::boolean("holdWhileEngaged", vr::HOLD_WHILE_ENGAGED, |m| m.hold_while_engaged, |m, v| m.hold_while_engaged = v)
            .tunable(Boolean(true))
            .describe("holdPosition follows clutchEngage (else it stays false)"),
        V::real("samplePeriod", vr::SAMPLE_PERIOD, |m| m.sample_period, |m, v| m.sample_period = v)
            .parameter(Real(1e-3))
            .unit("s")
            .display("ms")
            .range(1e-6, 10.0)
            .describe("Sample period; a communication step executes the sample instants it reaches, inputs held over the step"),
        V::real("gaitPhase", vr::GAIT_PHASE, |m| m.gait_phase, |m, v| m.gait_phase = v)
            .input(Real(0.0))
            .describe("Phase of the gait cycle in [0, 1) (GaitReference.gaitPhase); other values are wrapped"),
        V::real("velocityReference", vr::VELOCITY_REFERENCE, |m| m.velocity_reference, |m, v| m.velocity_reference = v)
            .input(Real(0.0))
            .unit("rad/s")
            .display("deg/s")
            .describe("Knee-velocity reference (GaitReference.kneeVelocityReference)"),
        V::boolean("clutchEngage", vr::CLUTCH_ENGAGE, |m| m.signals.engage, |m, v| m.signals.engage = v)
            .output(KNOWNS)
            .describe("Clutch command (to BenchPlant.clutchEngage)"),
        V::boolean("holdPosition", vr::HOLD_POSITION, |m| m.signals.hold, |m, v| m.signals.hold = v)
            .output(KNOWNS)
            .describe("Hold command for the position controller while the clutch is engaged (to PidController.hold)"),
        V::real("timeInState", vr::TIME_IN_STATE, |m| m.signals.time_in_state, |m, v| m.signals.time_in_state = v)
            .output(KNOWNS)
            .unit("s")
            .describe("Time since the last switch of the clutch command (since the start before the first)"),
    ]
    })
};

impl ClutchScheduler {
    /// The settings, checked.
    pub fn settings(&self) -> Result<ClutchSettings, ModelError> {
        let s = ClutchSettings {
            mode: ClutchMode::from_i32(self.mode)
                .ok_or_else(|| ModelError::refused(format!("mode {} is not an item", self.mode)))?,
            engage_start: self.engage_start,
            engage_end: self.engage_end,
            engage_speed: self.engage_speed,
            release_speed: self.release_speed,
            engage_delay: self.engage_delay,
            minimum_dwell: self.minimum_dwell,
            hold_while_engaged: self.hold_while_engaged,
            sample_period: self.sample_period,
        };
        if s.mode == ClutchMode::GaitPhase && s.engage_start == s.engage_end {
            return Err(ModelError::refused(
                "engageStart equals engageEnd: the engagement window would be empty",
            ));
        }
        if s.release_speed < s.engage_speed {
            return Err(ModelError::refused(format!(
                "releaseSpeed {} is below engageSpeed {}: the hysteresis must not be inverted",
                num(s.release_speed),
                num(s.engage_speed)
            )));
        }
        if s.sample_period.is_nan() || s.sample_period <= 0.0 {
            return Err(ModelError::refused("samplePeriod must be positive"));
        }
        Ok(s)
    }
}

impl ReferenceInputs for ClutchScheduler {
    fn reference_inputs() -> Option<String> {
        // A documented run of the default scheduler (GaitPhase, window 0.10-0.40): the gait
        // phase of a 2.5 s cycle and the default gait's knee-velocity reference (60 deg, from
        // GaitReference), every 1 ms.
        use super::gait::{ANGLE_SERIES, fourier};
        let mut csv = String::from("time,gaitPhase,velocityReference\n");
        for k in 0..=5000 {
            let t = k as f64 / 1000.0;
            let x = t / 2.5;
            let phase = x - x.floor();
            let v = 60f64.to_radians() * fourier(&ANGLE_SERIES, t, 2.5).d1;
            csv.push_str(&format!("{t:?},{phase:?},{v:?}\n"));
        }
        Some(csv)
    }
}

impl Model for ClutchScheduler {
    const IDENTIFIER: &'static str = "ClutchScheduler";
    const DESCRIPTION: &'static str = "Clutch scheduler of the CSEA knee actuator: engages the clutch by gait phase (stance window, wrapping) or by low reference speed with hysteresis, debounce and minimum dwell, and tells the position controller to hold while locked";
    const DEFAULT_EXPERIMENT: (f64, f64, f64) = (0.0, 5.0, 1e-3);

    fn variables() -> &'static [Variable<Self>] {
        &VARIABLES
    }

    fn enumerations() -> &'static [EnumerationType] {
        ENUMERATIONS
    }

    fn initialize(&mut self, start_time: f64) -> Result<(), ModelError> {
        self.settings()?;
        self.clock = SampleClock::new(self.sample_period, start_time);
        self.state = ClutchState::default();
        self.held = ClutchSignals::default();
        Ok(())
    }

    fn calculate(&mut self, t: f64) -> Result<(), ModelError> {
        let s = self.settings()?;
        self.signals = self.clock.outputs_at(t, self.held, |index| {
            clutch_sample(
                &s,
                &self.state,
                index,
                self.gait_phase,
                self.velocity_reference,
            )
            .0
        });
        Ok(())
    }

    fn max_step_size(&self) -> f64 {
        self.clock.max_step_size()
    }

    fn do_step(&mut self, t: f64, h: f64) -> Result<StepOutcome, ModelError> {
        let s = self.settings()?;
        let (phase, velocity) = (self.gait_phase, self.velocity_reference);
        self.clock
            .run_step(t, h, &mut self.state, &mut self.held, |index, state| {
                clutch_sample(&s, state, index, phase, velocity)
            })?;
        self.signals = self.held;
        Ok(StepOutcome::Completed)
    }

    fn save_internal(&self, w: &mut StateWriter) {
        self.clock.save(w);
        w.bool(self.state.engaged);
        for index in [self.state.last_switch, self.state.low_since] {
            w.bool(index.is_some());
            w.u64(index.unwrap_or(0));
        }
        w.bool(self.held.engage);
        w.bool(self.held.hold);
        w.f64(self.held.time_in_state);
    }

    fn load_internal(&mut self, r: &mut StateReader<'_>) -> Result<(), StateError> {
        self.clock = SampleClock::load(r)?;
        let engaged = r.bool()?;
        let mut index = || -> Result<Option<u64>, StateError> {
            let some = r.bool()?;
            let v = r.u64()?;
            Ok(some.then_some(v))
        };
        let last_switch = index()?;
        let low_since = index()?;
        self.state = ClutchState {
            engaged,
            last_switch,
            low_since,
        };
        self.held = ClutchSignals {
            engage: r.bool()?,
            hold: r.bool()?,
            time_in_state: r.f64()?,
        };
        Ok(())
    }

    fn documentation() -> &'static str {
        // SAFETY: a static (Lazy registers its address for the release at unload).
        static HTML: Lazy<String> = unsafe {
            Lazy::new(|| crate::model::module_doc_html(include_str!("clutch_scheduler.rs")))
        };
        &HTML
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fmi2::instance::fresh_model;

    fn settings(mode: ClutchMode) -> ClutchSettings {
        ClutchSettings {
            mode,
            engage_start: 0.1,
            engage_end: 0.4,
            engage_speed: 0.3,
            release_speed: 0.5,
            engage_delay: 0.0,
            minimum_dwell: 0.0,
            hold_while_engaged: true,
            sample_period: 1e-3,
        }
    }

    /// Runs samples 0.. over (phase, velocity); returns the engage outputs.
    fn run(s: &ClutchSettings, inputs: &[(f64, f64)]) -> Vec<bool> {
        let mut state = ClutchState::default();
        inputs
            .iter()
            .enumerate()
            .map(|(n, &(p, v))| {
                let (sig, next) = clutch_sample(s, &state, n as u64, p, v);
                assert_eq!(sig.hold, sig.engage);
                state = next;
                sig.engage
            })
            .collect()
    }

    #[test]
    fn gait_phase_window_with_and_without_wrap() {
        let s = settings(ClutchMode::GaitPhase);
        let phases = [0.05, 0.1, 0.39, 0.4, 0.95, 1.2];
        let got = run(&s, &phases.map(|p| (p, 0.0)));
        assert_eq!(got, [false, true, true, false, false, true]);
        let wrap = ClutchSettings {
            engage_start: 0.9,
            engage_end: 0.2,
            ..s
        };
        let got = run(&wrap, &[0.5, 0.9, 0.99, 0.0, 0.19, 0.2].map(|p| (p, 0.0)));
        assert_eq!(got, [false, true, true, true, true, false]);
    }

    #[test]
    fn low_speed_hysteresis() {
        let s = settings(ClutchMode::LowSpeed);
        // Speeds: high, below engage, between thresholds (stays engaged), above release,
        // between (stays released), below (engages), negative speeds use |v|.
        let v = [1.0, 0.2, 0.4, 0.6, 0.4, -0.1, -0.45, -0.55];
        let got = run(&s, &v.map(|v| (0.0, v)));
        assert_eq!(got, [false, true, true, false, false, true, true, false]);
    }

    #[test]
    fn engage_delay_debounces_short_low_speed_episodes() {
        let s = ClutchSettings {
            engage_delay: 3e-3,
            ..settings(ClutchMode::LowSpeed)
        };
        // Two low samples (too short), then five: engages at the 4th low sample (3 ms after
        // the first).
        let v = [0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0];
        let got = run(&s, &v.map(|v| (0.0, v)));
        assert_eq!(got, [false, false, false, false, false, false, true, true]);
    }

    #[test]
    fn minimum_dwell_delays_switches() {
        let s = ClutchSettings {
            minimum_dwell: 2e-3,
            ..settings(ClutchMode::GaitPhase)
        };
        // The first switch does not wait (sample 0); out of the window at sample 1 (1 ms
        // after the switch: waits), released at sample 2; back in at sample 3 (1 ms: waits),
        // engaged at sample 4.
        let got = run(&s, &[0.2, 0.5, 0.5, 0.2, 0.2, 0.2].map(|p| (p, 0.0)));
        assert_eq!(got, [true, true, false, false, true, true]);
    }

    #[test]
    fn hold_output_can_be_disabled_and_off_never_engages() {
        let mut s = settings(ClutchMode::GaitPhase);
        s.hold_while_engaged = false;
        let (sig, _) = clutch_sample(&s, &ClutchState::default(), 0, 0.2, 0.0);
        assert!(sig.engage && !sig.hold);
        let off = settings(ClutchMode::Off);
        assert_eq!(run(&off, &[(0.2, 0.0); 3]), [false; 3]);
    }

    #[test]
    fn model_feedthrough_state_and_refusals() {
        let mut m = fresh_model::<ClutchScheduler>();
        m.initialize(0.0).unwrap();
        m.gait_phase = 0.2;
        m.calculate(0.0).unwrap();
        assert!(m.signals.engage && m.signals.hold, "feedthrough");
        m.do_step(0.0, 0.1).unwrap();
        m.gait_phase = 0.5;
        m.calculate(0.1).unwrap();
        // 100 ms after the switch at sample 0 the 50 ms dwell is over: released at once.
        assert!(!m.signals.engage && !m.signals.hold);
        let mut w = StateWriter::default();
        m.save_internal(&mut w);
        let mut n = fresh_model::<ClutchScheduler>();
        n.load_internal(&mut StateReader::new(&w.bytes)).unwrap();
        assert_eq!((n.state, n.clock, n.held), (m.state, m.clock, m.held));
        // A step across an instant ending between two runs its samples (at 100 and 101 ms).
        m.do_step(0.1, 1.5e-3).unwrap();
        assert_eq!(m.clock.next, 102);
        m.engage_start = 0.4;
        m.engage_end = 0.4;
        assert!(m.settings().is_err());
        m.engage_end = 0.5;
        m.release_speed = 0.1;
        assert!(m.settings().is_err());
    }
}
