//! `GaitReference`: the bench's reference generator (bench model facts, section 5).
//!
//! Two channels, each with its own waveform:
//! - the **motion** channel gives the knee-angle reference and its analytic velocity,
//!   acceleration (and jerk, as the acceleration's output derivative);
//! - the **torque** channel gives the knee-torque reference; the load motor applies the
//!   ground reaction, i.e. the inverted knee torque (`loadTorqueReference = -kneeTorqueReference`).
//!
//! Every output is a closed-form function of time and the parameters, so steps of any size
//! give exact values and the FMU state is just the time.
//!
//! ## Torque scaling
//! `kneeTorqueAmplitude` is the peak of the applied external torque, the ground reaction
//! `loadTorqueReference = -kneeTorqueReference`, for every waveform: for the gait, the
//! normalised series (peak +1.00, minimum -1.94) is divided by 1.93555 (its external peak), so
//! the default 9 N m gives a knee torque between -9 and +4.66 N m. The bench scaled its gait
//! "such that the maximum applied external torque is 9 N m" (bench facts, section 10); the
//! external torque is the inverted knee torque, whose maximum is 1.94 times the series'
//! positive peak, and the largest magnitude reading gives the same scale. The earlier reading
//! (the series' +1.0 peak scaled to 9 N m) had the load motor apply -17.5 N m, above what the
//! bench's 20 N m torque interlocks leave once the load side's own dynamics are added, and
//! at odds with the report that 9 N m was the load the drivers could still brake.

use crate::release::Lazy;
use std::f64::consts::{PI, TAU};

use crate::model::{EnumerationType, Model, ModelError, Start, StepOutcome, Variable};
use crate::registry::ReferenceInputs;

mod sums;

mod series;

pub use series::{
    ANGLE_SERIES, ANGLE_WEIGHTS, HARMONICS, Harmonics, SeriesWeights, TORQUE_EXTERNAL_PEAK,
    TORQUE_SERIES, TORQUE_WEIGHTS, Weights, fourier, fourier_rate, fourier_with,
};
use series::{fourier_from_sums, fourier_rate_from_sums};

/// Value, time derivatives and time integral (from t = 0) of a normalised waveform.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Shape {
    /// s(t).
    pub value: f64,
    /// ds/dt.
    pub d1: f64,
    /// d²s/dt².
    pub d2: f64,
    /// d³s/dt³.
    pub d3: f64,
    /// ∫₀ᵗ s dτ.
    pub integral: f64,
}

/// The waveforms the bench UI offers.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Waveform {
    /// The gait Fourier series of the channel.
    Gait = 1,
    /// A constant (the amplitude).
    Constant = 2,
    /// 0 before `stepTime`, the amplitude from then on.
    Step = 3,
    /// sin(2πt/period).
    Sine = 4,
    /// ½[sin(2πt/period) + sin(4πt/period)].
    DoubleSine = 5,
    /// A triangle of the period, starting at 0 and rising.
    Triangle = 6,
    /// The stepped sine (frequency sweep) of the bench's Bode tests.
    SteppedSine = 7,
}

impl Waveform {
    fn from_i32(v: i32) -> Option<Self> {
        Some(match v {
            1 => Self::Gait,
            2 => Self::Constant,
            3 => Self::Step,
            4 => Self::Sine,
            5 => Self::DoubleSine,
            6 => Self::Triangle,
            7 => Self::SteppedSine,
            _ => return None,
        })
    }
}

/// The last stage of a stepped sine whose waveform [`Sweep::shape`] computes: its integral
/// sums the closed stages one by one, so a time far past the sweep (`t = 1e300`, or `1e4` s
/// at the shortest dwell) took minutes to hours per `fmi2GetReal`. Later stages are refused
/// (the get answers `fmi2Error`, the instance unchanged); a ratio above 1 has passed any
/// bench frequency long before (1.0001^100000 is 2.2e4).
pub const MAX_SWEEP_STAGES: u32 = 100_000;

/// The stepped-sine sweep: frequency f0·rⁿ during stage n = ⌊t/dwell⌋, phase continuous.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sweep {
    /// Start frequency \[Hz\].
    pub start_frequency: f64,
    /// Frequency ratio between stages.
    pub ratio: f64,
    /// Duration of a stage \[s\].
    pub dwell: f64,
}

impl Sweep {
    /// The stage index at time t (t >= 0).
    pub fn stage(&self, t: f64) -> u32 {
        (t.max(0.0) / self.dwell).floor().min(u32::MAX as f64) as u32
    }
    /// The frequency of stage n \[Hz\].
    pub fn frequency(&self, stage: u32) -> f64 {
        // `powi` takes an i32: stages past it (2^31 dwells, 25 days at the shortest) stay at
        // its last, where a wrapped exponent would be negative.
        self.start_frequency * self.ratio.powi(stage.min(i32::MAX as u32) as i32)
    }
    /// The first stage whose frequency exceeds `end` \[Hz\], `None` when none does (a ratio of
    /// 1 above the start, or a stage past `u32`). In closed form: a search stage by stage took
    /// seconds per step for a ratio just above 1 and never ended for a ratio of 1.
    pub fn end_stage(&self, end: f64) -> Option<u32> {
        if self.start_frequency > end {
            return Some(0);
        }
        if self.ratio <= 1.0 {
            return None;
        }
        // ln(end / f0) / ln(r) is the stage to within the rounding of the logarithms; the
        // stage test itself then settles it, as a search stage by stage would.
        let estimate = ((end / self.start_frequency).ln() / self.ratio.ln()).floor();
        // NaN (never from checked parameters) counts as past the last stage, like a huge one.
        if estimate.is_nan() || estimate >= f64::from(i32::MAX - 2) {
            return None;
        }
        let mut stage = (estimate.max(0.0) as u32).saturating_sub(1);
        while stage > 0 && self.frequency(stage - 1) > end {
            stage -= 1;
        }
        while self.frequency(stage) <= end {
            stage += 1;
        }
        Some(stage)
    }
    /// Phase [rad] at the start of stage n.
    fn stage_phase(&self, stage: u32) -> f64 {
        let cycles = if self.ratio == 1.0 {
            self.start_frequency * self.dwell * stage as f64
        } else {
            self.start_frequency * self.dwell * (self.ratio.powi(stage as i32) - 1.0)
                / (self.ratio - 1.0)
        };
        TAU * cycles
    }
    /// The normalised sweep at t: work in proportion to the stage, so a time past
    /// [`MAX_SWEEP_STAGES`] is refused.
    pub fn shape(&self, t: f64) -> Result<Shape, ModelError> {
        let n = self.stage(t);
        if n > MAX_SWEEP_STAGES {
            return Err(ModelError::refused(format!(
                "t = {t} is in stage {n} of the stepped sine, past its last computed stage \
                 {MAX_SWEEP_STAGES} (sweepDwellTime {})",
                self.dwell
            )));
        }
        let f = self.frequency(n);
        let w = TAU * f;
        let phase = self.stage_phase(n) + w * (t - n as f64 * self.dwell);
        let (sin, cos) = phase.sin_cos();
        // The integral sums the closed stages, then the open one.
        let mut integral = 0.0;
        for j in 0..n {
            let wj = TAU * self.frequency(j);
            integral += (self.stage_phase(j).cos() - self.stage_phase(j + 1).cos()) / wj;
        }
        integral += (self.stage_phase(n).cos() - cos) / w;
        Ok(Shape {
            value: sin,
            d1: w * cos,
            d2: -w * w * sin,
            d3: -w * w * w * cos,
            integral,
        })
    }
}

/// Whether the motion channel's waveform gives the angle or the velocity.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MotionQuantity {
    /// The waveform is the knee angle; velocity and acceleration are its derivatives.
    Position = 1,
    /// The waveform is the knee velocity; the angle is its integral from `kneeAngleOffset`.
    Velocity = 2,
}

/// The reference generator. Fields are the FMU's variables (see [`Model::variables`]).
#[derive(Debug, Clone, Default)]
pub struct GaitReference {
    period: f64,
    angle_amplitude: f64,
    angle_offset: f64,
    velocity_amplitude: f64,
    torque_amplitude: f64,
    torque_offset: f64,
    motion_waveform: i32,
    torque_waveform: i32,
    motion_quantity: i32,
    step_time: f64,
    sweep_start_frequency: f64,
    sweep_ratio: f64,
    sweep_dwell: f64,
    sweep_end_frequency: f64,
    stance_start: f64,
    stance_end: f64,
    fade_in_time: f64,

    knee_angle: f64,
    knee_velocity: f64,
    knee_acceleration: f64,
    knee_jerk: f64,
    knee_torque: f64,
    knee_torque_rate: f64,
    load_torque: f64,
    gait_phase: f64,
    stance: bool,
    sweep_frequency: f64,
    harmonics: i32,
    /// Which build of [`Model::calculate`] runs (not a variable).
    build: CalculateBuild,
}

/// Which build of the gait's [`Model::calculate`] runs: the AVX2 one where the CPU has it
/// (the two channels' weighted sums four lanes wide, `floor` one instruction instead of a
/// call), else the baseline one. The same operations in the same order (no fused
/// multiply-add), so both give the same bits (tested).
#[derive(Debug, Clone, Copy)]
struct CalculateBuild {
    /// True only where the CPU reports AVX2 (a soundness condition for `calculate_wide`).
    wide: bool,
}

impl Default for CalculateBuild {
    fn default() -> Self {
        Self {
            wide: crate::models::bench::plant::cpu_has_wide_vectors(),
        }
    }
}

/// Value references (stable; never reuse a retired number).
mod vr {
    pub const PERIOD: u32 = 1;
    pub const ANGLE_AMPLITUDE: u32 = 2;
    pub const ANGLE_OFFSET: u32 = 3;
    pub const VELOCITY_AMPLITUDE: u32 = 4;
    pub const TORQUE_AMPLITUDE: u32 = 5;
    pub const TORQUE_OFFSET: u32 = 6;
    pub const MOTION_WAVEFORM: u32 = 7;
    pub const TORQUE_WAVEFORM: u32 = 8;
    pub const MOTION_QUANTITY: u32 = 9;
    pub const STEP_TIME: u32 = 10;
    pub const SWEEP_START: u32 = 11;
    pub const SWEEP_RATIO: u32 = 12;
    pub const SWEEP_DWELL: u32 = 13;
    pub const SWEEP_END: u32 = 14;
    pub const STANCE_START: u32 = 15;
    pub const STANCE_END: u32 = 16;
    pub const FADE_IN: u32 = 17;
    pub const KNEE_ANGLE: u32 = 100;
    pub const KNEE_VELOCITY: u32 = 101;
    pub const KNEE_ACCELERATION: u32 = 102;
    pub const KNEE_TORQUE: u32 = 103;
    pub const LOAD_TORQUE: u32 = 104;
    pub const GAIT_PHASE: u32 = 105;
    pub const STANCE: u32 = 106;
    pub const SWEEP_FREQUENCY: u32 = 107;
    pub const HARMONICS: u32 = 200;
}

/// Every parameter the outputs depend on (for the ModelStructure's InitialUnknowns).
const ALL_PARAMETERS: &[&str] = &[
    "gaitPeriod",
    "kneeAngleAmplitude",
    "kneeAngleOffset",
    "kneeVelocityAmplitude",
    "kneeTorqueAmplitude",
    "kneeTorqueOffset",
    "motionWaveform",
    "torqueWaveform",
    "motionQuantity",
    "stepTime",
    "sweepStartFrequency",
    "sweepFrequencyRatio",
    "sweepDwellTime",
    "sweepEndFrequency",
    "stanceStart",
    "stanceEnd",
    "fadeInTime",
];

// SAFETY: a static (Lazy registers its address for the release at unload).
static VARIABLES: Lazy<Vec<Variable<GaitReference>>> = unsafe {
    Lazy::new(|| {
        use Start::{Integer, Real};
        type V = Variable<GaitReference>;
        let deg = PI / 180.0;
        vec![
            V::real("gaitPeriod", vr::PERIOD, |m| m.period, |m, v| m.period = v)
                .tunable(Real(2.5))
                .unit("s")
                .range(0.01, 1e4)
                .describe("Period of the gait and of every periodic waveform (frequency = 1/period)"),
            V::real("kneeAngleAmplitude", vr::ANGLE_AMPLITUDE, |m| m.angle_amplitude, |m, v| m.angle_amplitude = v)
                .tunable(Real(60.0 * deg))
                .unit("rad")
                .display("deg")
                .range(0.0, PI)
                .describe("Knee-angle amplitude: the normalised gait angle (peak 1.0) is scaled by it"),
            V::real("kneeAngleOffset", vr::ANGLE_OFFSET, |m| m.angle_offset, |m, v| m.angle_offset = v)
                .tunable(Real(0.0))
                .unit("rad")
                .display("deg")
                .range(-PI, PI)
                .describe("Added to the knee-angle reference (the start angle in velocity mode)"),
            V::real("kneeVelocityAmplitude", vr::VELOCITY_AMPLITUDE, |m| m.velocity_amplitude, |m, v| m.velocity_amplitude = v)
                .tunable(Real(30.0 * deg))
                .unit("rad/s")
                .display("deg/s")
                .range(-10.0, 10.0)
                .describe("Velocity amplitude used when motionQuantity = Velocity"),
            V::real("kneeTorqueAmplitude", vr::TORQUE_AMPLITUDE, |m| m.torque_amplitude, |m, v| m.torque_amplitude = v)
                .tunable(Real(9.0))
                .unit("N.m")
                .range(-200.0, 200.0)
                .describe("Peak of the applied external torque (loadTorqueReference = -kneeTorqueReference); the gait's normalised torque (peak +1.0, min -1.94) is scaled so that its external peak (-min) equals it"),
            V::real("kneeTorqueOffset", vr::TORQUE_OFFSET, |m| m.torque_offset, |m, v| m.torque_offset = v)
                .tunable(Real(0.0))
                .unit("N.m")
                .range(-200.0, 200.0)
                .describe("Added to the knee-torque reference"),
            V::enumeration("motionWaveform", vr::MOTION_WAVEFORM, "Waveform", |m| m.motion_waveform, |m, v| m.motion_waveform = v)
                .tunable(Integer(Waveform::Gait as i32))
                .describe("Waveform of the motion channel"),
            V::enumeration("torqueWaveform", vr::TORQUE_WAVEFORM, "Waveform", |m| m.torque_waveform, |m, v| m.torque_waveform = v)
                .tunable(Integer(Waveform::Gait as i32))
                .describe("Waveform of the torque channel"),
            V::enumeration("motionQuantity", vr::MOTION_QUANTITY, "MotionQuantity", |m| m.motion_quantity, |m, v| m.motion_quantity = v)
                .tunable(Integer(MotionQuantity::Position as i32))
                .describe("Whether the motion waveform is the angle or the velocity"),
            V::real("stepTime", vr::STEP_TIME, |m| m.step_time, |m, v| m.step_time = v)
                .tunable(Real(0.0))
                .unit("s")
                .describe("Time of the step of the Step waveform"),
            V::real("sweepStartFrequency", vr::SWEEP_START, |m| m.sweep_start_frequency, |m, v| m.sweep_start_frequency = v)
                .tunable(Real(0.05))
                .unit("Hz")
                .range(1e-4, 1e3)
                .describe("Stepped sine: frequency of the first stage"),
            V::real("sweepFrequencyRatio", vr::SWEEP_RATIO, |m| m.sweep_ratio, |m, v| m.sweep_ratio = v)
                .tunable(Real(10f64.powf(1.0 / 30.0)))
                .range(1.0, 10.0)
                .describe("Stepped sine: frequency ratio between stages (10^(1/30) on the bench)"),
            V::real("sweepDwellTime", vr::SWEEP_DWELL, |m| m.sweep_dwell, |m, v| m.sweep_dwell = v)
                .tunable(Real(20.0))
                .unit("s")
                .range(1e-3, 1e5)
                .describe("Stepped sine: duration of each stage"),
            V::real("sweepEndFrequency", vr::SWEEP_END, |m| m.sweep_end_frequency, |m, v| m.sweep_end_frequency = v)
                .tunable(Real(0.0))
                .unit("Hz")
                .range(0.0, 1e3)
                .describe("Stepped sine: the run ends (fmi2Discard, terminated) when the next stage would exceed this frequency; 0 = never"),
            V::real("stanceStart", vr::STANCE_START, |m| m.stance_start, |m, v| m.stance_start = v)
                .tunable(Real(0.0))
                .range(0.0, 1.0)
                .describe("Gait phase at which stance begins"),
            V::real("stanceEnd", vr::STANCE_END, |m| m.stance_end, |m, v| m.stance_end = v)
                .tunable(Real(0.6))
                .range(0.0, 1.0)
                .describe("Gait phase at which stance ends (toe-off)"),
            V::real("fadeInTime", vr::FADE_IN, |m| m.fade_in_time, |m, v| m.fade_in_time = v)
                .tunable(Real(0.0))
                .unit("s")
                .range(0.0, 1e3)
                .describe("Soft start: the motion (position mode) and torque references rise from their offsets to full amplitude over this time with a quintic ramp; 0 = none"),
            V::real("kneeAngleReference", vr::KNEE_ANGLE, |m| m.knee_angle, |m, v| m.knee_angle = v)
                .output(ALL_PARAMETERS)
                .unit("rad")
                .display("deg")
                .describe("Knee-angle reference"),
            V::real("kneeVelocityReference", vr::KNEE_VELOCITY, |m| m.knee_velocity, |m, v| m.knee_velocity = v)
                .output(ALL_PARAMETERS)
                .unit("rad/s")
                .display("deg/s")
                .describe("Knee angular velocity reference (analytic derivative)"),
            V::real("kneeAccelerationReference", vr::KNEE_ACCELERATION, |m| m.knee_acceleration, |m, v| m.knee_acceleration = v)
                .output(ALL_PARAMETERS)
                .unit("rad/s2")
                .display("deg/s2")
                .describe("Knee angular acceleration reference (analytic second derivative)"),
            V::real("kneeTorqueReference", vr::KNEE_TORQUE, |m| m.knee_torque, |m, v| m.knee_torque = v)
                .output(ALL_PARAMETERS)
                .unit("N.m")
                .describe("Knee-torque reference (extension positive)"),
            V::real("loadTorqueReference", vr::LOAD_TORQUE, |m| m.load_torque, |m, v| m.load_torque = v)
                .output(ALL_PARAMETERS)
                .unit("N.m")
                .describe("Load-motor torque reference: the ground reaction, -kneeTorqueReference"),
            V::real("gaitPhase", vr::GAIT_PHASE, |m| m.gait_phase, |m, v| m.gait_phase = v)
                .output(ALL_PARAMETERS)
                .describe("Phase of the gait cycle in [0, 1)"),
            V::boolean("stance", vr::STANCE, |m| m.stance, |m, v| m.stance = v)
                .output(ALL_PARAMETERS)
                .describe("True while the gait phase is inside [stanceStart, stanceEnd)"),
            V::real("sweepFrequency", vr::SWEEP_FREQUENCY, |m| m.sweep_frequency, |m, v| m.sweep_frequency = v)
                .output(ALL_PARAMETERS)
                .discrete()
                .unit("Hz")
                .describe("Frequency of the current stepped-sine stage (0 when no channel sweeps)"),
            V::integer("gaitHarmonics", vr::HARMONICS, |m| m.harmonics, |m, v| m.harmonics = v)
                .constant(Integer(HARMONICS as i32))
                .describe("Number of harmonics of the gait Fourier series"),
        ]
    })
};

static ENUMERATIONS: &[EnumerationType] = &[
    EnumerationType {
        name: "Waveform",
        description: "Reference waveforms of the bench UI",
        items: &[
            ("Gait", 1, "8th-order Fourier gait series of the channel"),
            ("Constant", 2, "The amplitude, constant"),
            (
                "Step",
                3,
                "0 before stepTime, the amplitude from stepTime on",
            ),
            ("Sine", 4, "amplitude*sin(2*pi*t/period)"),
            (
                "DoubleSine",
                5,
                "amplitude/2*(sin(2*pi*t/period) + sin(4*pi*t/period))",
            ),
            (
                "Triangle",
                6,
                "Triangle of the period between -amplitude and amplitude, rising from 0 at t=0",
            ),
            (
                "SteppedSine",
                7,
                "Frequency sweep: sweepStartFrequency*sweepFrequencyRatio^n during stage n of sweepDwellTime",
            ),
        ],
    },
    EnumerationType {
        name: "MotionQuantity",
        description: "What the motion channel's waveform describes",
        items: &[
            ("Position", 1, "The waveform is the knee angle"),
            (
                "Velocity",
                2,
                "The waveform is the knee velocity; the angle is its integral",
            ),
        ],
    },
];

impl GaitReference {
    /// [`Model::calculate`] compiled for AVX2 (see [`CalculateBuild`]).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn calculate_wide(&mut self, t: f64) -> Result<(), ModelError> {
        self.calculate_inline::<true>(t)
    }

    /// The outputs at `t` ([`Model::calculate`]), inlined into each build (`WIDE`: the
    /// AVX2 one, whose gait sums are [`sums::gait_sums`]'s vector form).
    #[inline(always)]
    fn calculate_inline<const WIDE: bool>(&mut self, t: f64) -> Result<(), ModelError> {
        let cycles = t / self.period;

        let harmonics = Harmonics::at_cycles(cycles);
        // The gait series (the common case) evaluated here, both channels' sums at once
        // against the constant weights; `shape` evaluates the same `fourier_with` for it.
        let motion_gait = self.motion_waveform == Waveform::Gait as i32;
        let torque_gait = self.torque_waveform == Waveform::Gait as i32;
        let gait = if motion_gait || torque_gait {
            sums::gait_sums::<WIDE>(&harmonics)
        } else {
            [0.0; sums::GAIT_SUMS]
        };
        let motion = if motion_gait {
            let [value, rate, acceleration, jerk, integral, ..] = gait;
            fourier_from_sums(
                &ANGLE_WEIGHTS,
                [value, rate, acceleration, jerk, integral],
                t,
                self.period,
            )
        } else {
            self.shape(self.motion_waveform, &ANGLE_WEIGHTS, &harmonics, t)?
        };
        // The torque channel needs only value and rate: the gait series skips the rest.
        let (torque_value, torque_rate) = if torque_gait {
            fourier_rate_from_sums(&TORQUE_WEIGHTS, [gait[5], gait[6]], self.period)
        } else {
            let shape = self.shape(self.torque_waveform, &TORQUE_WEIGHTS, &harmonics, t)?;
            (shape.value, shape.d1)
        };
        // The soft start scales the waveforms (not the offsets) by a ramp r(t); the product
        // rule keeps velocity, acceleration and jerk the exact derivatives.
        // In velocity mode the angle is the waveform's exact integral, so the motion channel is
        // not faded there.
        let r = fade_in(t, self.fade_in_time);
        let m = if self.motion_quantity == MotionQuantity::Position as i32 {
            r
        } else {
            [1.0, 0.0, 0.0, 0.0]
        };
        let motion = Shape {
            value: m[0] * motion.value,
            d1: m[1] * motion.value + m[0] * motion.d1,
            d2: m[2] * motion.value + 2.0 * m[1] * motion.d1 + m[0] * motion.d2,
            d3: m[3] * motion.value
                + 3.0 * m[2] * motion.d1
                + 3.0 * m[1] * motion.d2
                + m[0] * motion.d3,
            integral: motion.integral,
        };
        let torque_value_faded = r[0] * torque_value;
        let torque_rate_faded = r[1] * torque_value + r[0] * torque_rate;
        match self.motion_quantity {
            1 => {
                let a = self.angle_amplitude;
                self.knee_angle = self.angle_offset + a * motion.value;
                self.knee_velocity = a * motion.d1;
                self.knee_acceleration = a * motion.d2;
                self.knee_jerk = a * motion.d3;
            }
            2 => {
                let a = self.velocity_amplitude;
                self.knee_angle = self.angle_offset + a * motion.integral;
                self.knee_velocity = a * motion.value;
                self.knee_acceleration = a * motion.d1;
                self.knee_jerk = a * motion.d2;
            }
            other => {
                return Err(ModelError::refused(format!(
                    "motionQuantity {other} is not an item of MotionQuantity"
                )));
            }
        }
        // The amplitude is the external torque's peak (module docs, "Torque scaling").
        let scale = if self.torque_waveform == Waveform::Gait as i32 {
            self.torque_amplitude / TORQUE_EXTERNAL_PEAK
        } else {
            self.torque_amplitude
        };
        self.knee_torque = self.torque_offset + scale * torque_value_faded;
        self.knee_torque_rate = scale * torque_rate_faded;
        self.load_torque = -self.knee_torque;
        self.gait_phase = (cycles - cycles.floor()).clamp(0.0, 1.0 - f64::EPSILON);
        self.stance = if self.stance_start < self.stance_end {
            (self.stance_start..self.stance_end).contains(&self.gait_phase)
        } else {
            self.gait_phase >= self.stance_start || self.gait_phase < self.stance_end
        };
        self.sweep_frequency = if self.sweeping() {
            self.sweep().frequency(self.sweep().stage(t))
        } else {
            0.0
        };
        Ok(())
    }

    fn sweep(&self) -> Sweep {
        Sweep {
            start_frequency: self.sweep_start_frequency,
            ratio: self.sweep_ratio,
            dwell: self.sweep_dwell,
        }
    }

    fn sweeping(&self) -> bool {
        self.motion_waveform == Waveform::SteppedSine as i32
            || self.torque_waveform == Waveform::SteppedSine as i32
    }

    /// The normalised waveform `w` at time t; `series` is the channel's gait series and
    /// `harmonics` its terms at `t` (computed once for both channels).
    fn shape(
        &self,
        w: i32,
        series: &SeriesWeights,
        harmonics: &Harmonics,
        t: f64,
    ) -> Result<Shape, ModelError> {
        let wave = Waveform::from_i32(w).ok_or_else(|| {
            ModelError::refused(format!("waveform {w} is not an item of Waveform"))
        })?;
        let p = self.period;
        let w1 = TAU / p;
        Ok(match wave {
            Waveform::Gait => fourier_with(series, harmonics, t, p),
            Waveform::Constant => Shape {
                value: 1.0,
                integral: t,
                ..Shape::default()
            },
            Waveform::Step => {
                let on = t >= self.step_time;
                Shape {
                    value: if on { 1.0 } else { 0.0 },
                    integral: (t - self.step_time.max(0.0)).max(0.0),
                    ..Shape::default()
                }
            }
            Waveform::Sine => {
                let (s, c) = (w1 * t).sin_cos();
                Shape {
                    value: s,
                    d1: w1 * c,
                    d2: -w1 * w1 * s,
                    d3: -w1 * w1 * w1 * c,
                    integral: (1.0 - c) / w1,
                }
            }
            Waveform::DoubleSine => {
                let (s1, c1) = (w1 * t).sin_cos();
                let w2 = 2.0 * w1;
                let (s2, c2) = (w2 * t).sin_cos();
                Shape {
                    value: 0.5 * (s1 + s2),
                    d1: 0.5 * (w1 * c1 + w2 * c2),
                    d2: -0.5 * (w1 * w1 * s1 + w2 * w2 * s2),
                    d3: -0.5 * (w1.powi(3) * c1 + w2.powi(3) * c2),
                    integral: 0.5 * ((1.0 - c1) / w1 + (1.0 - c2) / w2),
                }
            }
            Waveform::Triangle => triangle(t, p),
            Waveform::SteppedSine => self.sweep().shape(t)?,
        })
    }
}

/// The soft-start ramp over `duration` and its first three time derivatives: the quintic
/// 10x^3 - 15x^4 + 6x^5 (x = t/duration), whose first and second derivatives vanish at both
/// ends, so a faded reference has a continuous acceleration. 1 (and zero derivatives) for a
/// zero duration or after the ramp.
pub fn fade_in(t: f64, duration: f64) -> [f64; 4] {
    if duration <= 0.0 || t >= duration {
        return [1.0, 0.0, 0.0, 0.0];
    }
    if t <= 0.0 {
        return [0.0; 4];
    }
    let x = t / duration;
    let d = duration;
    [
        x * x * x * (10.0 - 15.0 * x + 6.0 * x * x),
        30.0 * x * x * (1.0 - x) * (1.0 - x) / d,
        60.0 * x * (1.0 - 3.0 * x + 2.0 * x * x) / (d * d),
        (60.0 - 360.0 * x + 360.0 * x * x) / (d * d * d),
    ]
}

/// The triangle wave of period p, in [-1, 1], 0 and rising at t = 0.
pub fn triangle(t: f64, p: f64) -> Shape {
    let cycles = (t / p).floor();
    let r = t - cycles * p; // time into the current period, [0, p)
    let q = p / 4.0;
    let (value, d1, integral) = if r < q {
        (r / q, 1.0 / q, 2.0 * r * r / p)
    } else if r < 3.0 * q {
        let u = r - q;
        (1.0 - u / q, -1.0 / q, p / 8.0 + u - 2.0 * u * u / p)
    } else {
        let v = r - p;
        (v / q, 1.0 / q, 2.0 * v * v / p)
    };
    Shape {
        value,
        d1,
        d2: 0.0,
        d3: 0.0,
        integral,
    }
}

impl ReferenceInputs for GaitReference {}

impl Model for GaitReference {
    const IDENTIFIER: &'static str = "GaitReference";
    const DESCRIPTION: &'static str = "Reference generator of the knee-actuator bench: gait (8th-order Fourier series), constant, step, sine, double sine, triangle and stepped-sine references for the test motor's knee angle and the load motor's torque";
    const MAX_OUTPUT_DERIVATIVE_ORDER: u32 = 1;
    const DEFAULT_EXPERIMENT: (f64, f64, f64) = (0.0, 5.0, 1e-3);

    fn variables() -> &'static [Variable<Self>] {
        &VARIABLES
    }

    fn enumerations() -> &'static [EnumerationType] {
        ENUMERATIONS
    }

    fn initialize(&mut self, _start_time: f64) -> Result<(), ModelError> {
        if self.stance_start == self.stance_end {
            return Err(ModelError::refused(
                "stanceStart equals stanceEnd: the stance window would be empty",
            ));
        }
        Ok(())
    }

    fn calculate(&mut self, t: f64) -> Result<(), ModelError> {
        #[cfg(target_arch = "x86_64")]
        if self.build.wide {
            // SAFETY: `build.wide` is true only where the CPU reports AVX2
            // (`CalculateBuild::default`), the one feature `calculate_wide` is compiled for.
            return unsafe { self.calculate_wide(t) };
        }
        self.calculate_inline::<false>(t)
    }

    fn do_step(&mut self, t: f64, h: f64) -> Result<StepOutcome, ModelError> {
        // The outputs are closed-form in time: only the end of a sweep can interrupt a step.
        if self.sweeping() && self.sweep_end_frequency > 0.0 {
            let sweep = self.sweep();
            let end = t + h;
            let Some(stage) = sweep.end_stage(self.sweep_end_frequency) else {
                return Ok(StepOutcome::Completed);
            };
            let stop_at = stage as f64 * sweep.dwell;
            if stop_at <= t {
                return Ok(StepOutcome::Terminated {
                    at: t,
                    reason: "the stepped-sine sweep passed sweepEndFrequency",
                });
            }
            if stop_at < end {
                return Ok(StepOutcome::Terminated {
                    at: stop_at,
                    reason: "the stepped-sine sweep reached sweepEndFrequency",
                });
            }
        }
        Ok(StepOutcome::Completed)
    }

    fn output_derivative(&self, value_reference: u32, order: u32) -> Option<f64> {
        if order != 1 {
            return None;
        }
        match value_reference {
            vr::KNEE_ANGLE => Some(self.knee_velocity),
            vr::KNEE_VELOCITY => Some(self.knee_acceleration),
            vr::KNEE_ACCELERATION => Some(self.knee_jerk),
            vr::KNEE_TORQUE => Some(self.knee_torque_rate),
            vr::LOAD_TORQUE => Some(-self.knee_torque_rate),
            vr::GAIT_PHASE => Some(1.0 / self.period),
            vr::SWEEP_FREQUENCY => Some(0.0),
            _ => None,
        }
    }

    fn documentation() -> &'static str {
        include_str!("gait.html")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fourier_recurrence_matches_direct_evaluation() {
        // Every output of both series against term-by-term evaluation with one sin_cos per
        // harmonic, at times over many periods.
        let close = |fast: f64, direct: f64, scale: f64, what: &str| {
            assert!(
                (fast - direct).abs() <= 1e-13 * direct.abs().max(scale),
                "{what}: {fast} vs {direct}"
            );
        };
        for (series, weights) in [
            (&ANGLE_SERIES, &ANGLE_WEIGHTS),
            (&TORQUE_SERIES, &TORQUE_WEIGHTS),
        ] {
            for &t in &[0.0, 0.3, 1.2345, 2.5, 17.77, 1234.5678, 98765.4321] {
                for period in [2.5, 1.0, 0.7] {
                    let fast = fourier(series, t, period);
                    let phase = (t / period).rem_euclid(1.0);
                    let mut direct = Shape {
                        value: series[0].0,
                        integral: series[0].0 * t,
                        ..Shape::default()
                    };
                    for (n, &(a, b)) in series.iter().enumerate().skip(1) {
                        let k = TAU * n as f64 / period;
                        let (sin, cos) = (TAU * n as f64 * phase).sin_cos();
                        direct.value += a * cos + b * sin;
                        direct.d1 += k * (b * cos - a * sin);
                        direct.d2 -= k * k * (a * cos + b * sin);
                        direct.d3 += k * k * k * (a * sin - b * cos);
                        direct.integral += (a * sin + b * (1.0 - cos)) / k;
                    }
                    let k = TAU / period;
                    let what = format!("t {t} period {period}");
                    close(fast.value, direct.value, 1.0, &format!("value {what}"));
                    close(fast.d1, direct.d1, k, &format!("d1 {what}"));
                    close(fast.d2, direct.d2, k * k * 10.0, &format!("d2 {what}"));
                    close(fast.d3, direct.d3, k * k * k * 100.0, &format!("d3 {what}"));
                    close(
                        fast.integral,
                        direct.integral,
                        1.0,
                        &format!("integral {what}"),
                    );
                    // The integral starts at exactly 0 (the velocity-mode angle starts at
                    // its offset).
                    if t == 0.0 {
                        assert_eq!(fast.integral, 0.0, "integral at 0, period {period}");
                    }
                    // The torque channel's value-and-rate path is the same arithmetic.
                    let harmonics = Harmonics::at(t, period);
                    let full = fourier_with(weights, &harmonics, t, period);
                    let (value, rate) = fourier_rate(weights, &harmonics, period);
                    assert_eq!(
                        (value.to_bits(), rate.to_bits()),
                        (full.value.to_bits(), full.d1.to_bits())
                    );
                }
            }
        }
    }
    use crate::fmi2::instance::fresh_model;

    fn model() -> GaitReference {
        fresh_model::<GaitReference>()
    }

    /// Parses shared/data/gait-fourier.csv (the spec's table) independently of the constants.
    fn table() -> Vec<[f64; 5]> {
        include_str!("../../../../shared/data/gait-fourier.csv")
            .lines()
            .filter(|l| !l.starts_with('#') && !l.starts_with('n'))
            .map(|l| {
                let v: Vec<f64> = l.split(',').map(|x| x.trim().parse().unwrap()).collect();
                [v[0], v[1], v[2], v[3], v[4]]
            })
            .collect()
    }

    #[test]
    fn constants_equal_the_coefficient_table() {
        let t = table();
        assert_eq!(t.len(), HARMONICS + 1);
        for (n, row) in t.iter().enumerate() {
            assert_eq!(row[0], n as f64);
            assert_eq!((row[1], row[2]), ANGLE_SERIES[n], "angle n={n}");
            assert_eq!((row[3], row[4]), TORQUE_SERIES[n], "torque n={n}");
        }
    }

    #[test]
    fn series_matches_the_table_at_many_points() {
        let t = table();
        for i in 0..=1000 {
            let x = i as f64 / 1000.0;
            let direct = |ca: usize, cb: usize| {
                t.iter()
                    .map(|r| r[ca] * (TAU * r[0] * x).cos() + r[cb] * (TAU * r[0] * x).sin())
                    .sum::<f64>()
            };
            let a = fourier(&ANGLE_SERIES, x * 2.5, 2.5).value;
            let q = fourier(&TORQUE_SERIES, x * 2.5, 2.5).value;
            assert!((a - direct(1, 2)).abs() < 1e-12, "angle at x={x}");
            assert!((q - direct(3, 4)).abs() < 1e-12, "torque at x={x}");
        }
    }

    #[test]
    fn normalised_gait_has_the_documented_extremes() {
        let (mut amax, mut amin, mut tmax, mut tmin, mut at) =
            (f64::MIN, f64::MAX, f64::MIN, f64::MAX, 0.0);
        for i in 0..10000 {
            let x = i as f64 / 10000.0;
            let a = fourier(&ANGLE_SERIES, x, 1.0).value;
            let q = fourier(&TORQUE_SERIES, x, 1.0).value;
            if a > amax {
                amax = a;
                at = x;
            }
            amin = amin.min(a);
            tmax = tmax.max(q);
            tmin = tmin.min(q);
        }
        assert!(
            (amax - 1.0).abs() < 0.01 && (at - 0.715).abs() < 0.01,
            "{amax} at {at}"
        );
        assert!((amin - 0.10).abs() < 0.01, "{amin}");
        assert!(
            (tmax - 1.0).abs() < 0.01 && (tmin + 1.94).abs() < 0.01,
            "{tmax} {tmin}"
        );
    }

    fn outputs(m: &mut GaitReference, t: f64) -> [f64; 6] {
        m.calculate(t).unwrap();
        [
            m.knee_angle,
            m.knee_velocity,
            m.knee_acceleration,
            m.knee_jerk,
            m.knee_torque,
            m.knee_torque_rate,
        ]
    }

    fn check_derivatives(m: &mut GaitReference, times: &[f64]) {
        let h = 1e-6;
        for &t in times {
            let lo = outputs(m, t - h);
            let hi = outputs(m, t + h);
            let mid = outputs(m, t);
            for (k, (d_idx, name)) in [(1, "velocity"), (2, "acceleration"), (3, "jerk")]
                .iter()
                .enumerate()
            {
                let fd = (hi[k] - lo[k]) / (2.0 * h);
                let scale = 1.0 + mid[*d_idx].abs();
                assert!(
                    (fd - mid[*d_idx]).abs() < 1e-5 * scale,
                    "{name} at t={t}: fd {fd} vs {}",
                    mid[*d_idx]
                );
            }
            let fd = (hi[4] - lo[4]) / (2.0 * h);
            assert!(
                (fd - mid[5]).abs() < 1e-5 * (1.0 + mid[5].abs()),
                "torque rate at t={t}"
            );
        }
    }

    #[test]
    fn analytic_derivatives_agree_with_finite_differences() {
        let times: Vec<f64> = (0..50).map(|i| 0.013 + i as f64 * 0.0917).collect();
        for wave in [
            Waveform::Gait,
            Waveform::Sine,
            Waveform::DoubleSine,
            Waveform::SteppedSine,
        ] {
            let mut m = model();
            m.motion_waveform = wave as i32;
            m.torque_waveform = wave as i32;
            m.sweep_dwell = 0.7; // several stages within the sampled times
            check_derivatives(&mut m, &times);
            m.fade_in_time = 2.0; // the ramp's product rule too
            check_derivatives(&mut m, &times);
        }
    }

    #[test]
    fn velocity_mode_angle_is_the_integral_of_velocity() {
        for wave in [
            Waveform::Gait,
            Waveform::Constant,
            Waveform::Step,
            Waveform::Sine,
            Waveform::DoubleSine,
            Waveform::Triangle,
            Waveform::SteppedSine,
        ] {
            let mut m = model();
            m.motion_quantity = MotionQuantity::Velocity as i32;
            m.motion_waveform = wave as i32;
            m.sweep_dwell = 0.9;
            m.angle_offset = 0.1;
            // Trapezoidal integration of the velocity on a fine grid.
            let (n, t_end) = (200_000, 4.3);
            let dt = t_end / n as f64;
            // Mid-interval, so that the trapezoid rule integrates the jump exactly.
            m.step_time = 20_000.5 * dt;
            let mut angle = 0.1;
            let mut prev = outputs(&mut m, 0.0)[1];
            for i in 1..=n {
                let v = outputs(&mut m, i as f64 * dt)[1];
                angle += 0.5 * (prev + v) * dt;
                prev = v;
            }
            let exact = outputs(&mut m, t_end)[0];
            assert!((angle - exact).abs() < 1e-6, "{wave:?}: {angle} vs {exact}");
        }
    }

    #[test]
    fn one_period_later_every_output_repeats() {
        for wave in [
            Waveform::Gait,
            Waveform::Sine,
            Waveform::DoubleSine,
            Waveform::Triangle,
        ] {
            let mut m = model();
            m.motion_waveform = wave as i32;
            m.torque_waveform = wave as i32;
            for i in 0..100 {
                let t = 0.0371 * i as f64;
                m.calculate(t).unwrap();
                let a = (
                    m.knee_angle,
                    m.knee_velocity,
                    m.knee_acceleration,
                    m.load_torque,
                    m.gait_phase,
                    m.stance,
                );
                m.calculate(t + m.period).unwrap();
                let b = (
                    m.knee_angle,
                    m.knee_velocity,
                    m.knee_acceleration,
                    m.load_torque,
                    m.gait_phase,
                    m.stance,
                );
                assert!(
                    (a.0 - b.0).abs() < 1e-12
                        && (a.1 - b.1).abs() < 1e-11
                        && (a.2 - b.2).abs() < 1e-10,
                    "{wave:?} t={t}"
                );
                assert!(
                    (a.3 - b.3).abs() < 1e-12 && (a.4 - b.4).abs() < 1e-9 && a.5 == b.5,
                    "{wave:?} t={t}"
                );
            }
        }
    }

    #[test]
    fn default_gait_has_the_bench_scaling_and_inverted_load_torque() {
        let mut m = model();
        let mut peak = f64::MIN;
        for i in 0..25_000 {
            m.calculate(i as f64 * 1e-4).unwrap();
            peak = peak.max(m.knee_angle);
            assert_eq!(m.load_torque, -m.knee_torque);
        }
        assert!((peak.to_degrees() - 60.0).abs() < 0.1, "peak {peak}");
    }

    /// The default gait's external torque (the load motor's reference) peaks at exactly the
    /// amplitude, 9 N m, and the knee torque stays within [-9, 4.66] N m; other waveforms keep
    /// their plain amplitude.
    #[test]
    fn the_torque_amplitude_is_the_external_torque_peak() {
        // The constant is the series' minimum: Newton on the derivative from the densest sample.
        let (mut x, mut lowest) = (0.0, f64::MAX);
        for i in 0..100_000 {
            let xi = i as f64 / 100_000.0;
            let v = fourier(&TORQUE_SERIES, xi, 1.0).value;
            if v < lowest {
                (x, lowest) = (xi, v);
            }
        }
        for _ in 0..20 {
            let s = fourier(&TORQUE_SERIES, x, 1.0);
            x -= s.d1 / s.d2;
        }
        let minimum = fourier(&TORQUE_SERIES, x, 1.0).value;
        assert!((minimum + TORQUE_EXTERNAL_PEAK).abs() < 1e-14, "{minimum}");
        let mut m = model();
        let (mut external, mut knee_max) = (f64::MIN, f64::MIN);
        for i in 0..250_000 {
            m.calculate(i as f64 * 1e-5).unwrap();
            external = external.max(m.load_torque);
            knee_max = knee_max.max(m.knee_torque);
        }
        assert!((external - 9.0).abs() < 1e-6, "external peak {external}");
        assert!(
            (knee_max - 9.0 * 1.00202 / TORQUE_EXTERNAL_PEAK).abs() < 1e-3,
            "{knee_max}"
        );
        m.torque_waveform = Waveform::Sine as i32;
        m.calculate(2.5 / 4.0).unwrap();
        assert!((m.knee_torque - 9.0).abs() < 1e-12, "{}", m.knee_torque);
    }

    #[test]
    fn triangle_is_continuous_and_bounded() {
        let p = 2.0;
        let mut prev = triangle(0.0, p);
        assert_eq!(prev.value, 0.0);
        for i in 1..=4000 {
            let s = triangle(i as f64 * 1e-3, p);
            assert!(s.value.abs() <= 1.0 + 1e-12);
            assert!((s.value - prev.value).abs() <= 2.0 * 1e-3 * 2.0 + 1e-12);
            assert!((s.integral - prev.integral).abs() <= 1.1e-3);
            prev = s;
        }
    }

    #[test]
    fn stepped_sine_frequency_steps_by_the_ratio_every_dwell() {
        let s = Sweep {
            start_frequency: 0.05,
            ratio: 10f64.powf(1.0 / 30.0),
            dwell: 20.0,
        };
        assert_eq!(s.stage(19.999), 0);
        assert_eq!(s.stage(20.0), 1);
        assert!((s.frequency(30) - 0.5).abs() < 1e-12);
        // Phase is continuous at a stage boundary.
        let a = s.shape(20.0 - 1e-9).unwrap().value;
        let b = s.shape(20.0 + 1e-9).unwrap().value;
        assert!((a - b).abs() < 1e-7);
    }

    /// A time far past the sweep is refused at once, not summed stage by stage (found by
    /// tests/tests/call_sequence_fuzz.rs: `t = 1e300` ran 4e9 stages per get, `1e9` 5e7);
    /// the last computed stage is still computed, and the refusal changes nothing.
    #[test]
    fn a_stepped_sine_far_past_its_last_stage_is_refused_at_once() {
        for waveform in ["motion", "torque"] {
            let mut m = model();
            if waveform == "motion" {
                m.motion_waveform = Waveform::SteppedSine as i32;
            } else {
                m.torque_waveform = Waveform::SteppedSine as i32;
            }
            m.sweep_dwell = 0.5;
            let last = f64::from(MAX_SWEEP_STAGES) * 0.5;
            assert!(m.calculate(last).is_ok(), "{waveform}");
            let before = m.knee_angle.to_bits();
            // Without the bound the first is computed (1e5 stages), the last hangs.
            for t in [last + 0.5, 1e9, 1e300] {
                let e = m.calculate(t).expect_err(waveform);
                assert!(
                    e.is_refused() && e.message.contains("past its last"),
                    "{e:?}"
                );
            }
            assert_eq!(m.knee_angle.to_bits(), before, "{waveform}");
        }
    }

    #[test]
    fn sweep_terminates_at_the_stage_that_passes_the_end_frequency() {
        let mut m = model();
        m.torque_waveform = Waveform::SteppedSine as i32;
        m.sweep_dwell = 1.0;
        m.sweep_start_frequency = 1.0;
        m.sweep_ratio = 2.0;
        m.sweep_end_frequency = 4.0; // stages 0,1,2 at 1,2,4 Hz; stage 3 (8 Hz) is past the end
        assert_eq!(m.do_step(0.0, 2.5).unwrap(), StepOutcome::Completed);
        assert_eq!(
            m.do_step(2.5, 1.0).unwrap(),
            StepOutcome::Terminated {
                at: 3.0,
                reason: "the stepped-sine sweep reached sweepEndFrequency"
            }
        );
    }

    /// The end stage in closed form equals the search stage by stage, and a ratio of 1 (or
    /// one so close to 1 that the end is millions of stages away) neither hangs nor ends early.
    #[test]
    fn the_end_stage_is_found_without_walking_the_stages() {
        let walk = |s: &Sweep, end: f64| {
            let mut stage = 0;
            while s.frequency(stage) <= end {
                stage += 1;
            }
            stage
        };
        for (f0, ratio, end) in [
            (0.05, 10f64.powf(1.0 / 30.0), 20.0),
            (1.0, 2.0, 4.0),
            (1.0, 2.0, 3.999_999),
            (0.3, 1.6, 0.3),
            (0.3, 1.6, 0.1),
            (1e-4, 1.001, 1e3),
            (0.05, 10.0, 1e3),
        ] {
            let s = Sweep {
                start_frequency: f0,
                ratio,
                dwell: 1.0,
            };
            assert_eq!(s.end_stage(end), Some(walk(&s, end)), "{f0} {ratio} {end}");
        }
        let mut m = model();
        m.motion_waveform = Waveform::SteppedSine as i32;
        m.sweep_start_frequency = 0.05;
        m.sweep_end_frequency = 1.0;
        m.sweep_ratio = 1.0;
        assert_eq!(m.do_step(0.0, 1e-3).unwrap(), StepOutcome::Completed);
        m.sweep_ratio = 1.000_000_1; // the end is about 30 million stages away
        let s = m.sweep();
        let stage = s.end_stage(1.0).unwrap();
        assert!(s.frequency(stage) > 1.0 && s.frequency(stage - 1) <= 1.0);
        assert_eq!(m.do_step(0.0, 1e-3).unwrap(), StepOutcome::Completed);
    }

    #[test]
    fn stance_window_wraps_around() {
        let mut m = model();
        m.stance_start = 0.9;
        m.stance_end = 0.2;
        m.calculate(0.95 * m.period).unwrap();
        assert!(m.stance);
        m.calculate(0.5 * m.period).unwrap();
        assert!(!m.stance);
    }

    /// Every output of the model, as bits (to compare the two builds of `calculate`).
    fn all_output_bits(m: &GaitReference) -> [u64; 10] {
        [
            m.knee_angle,
            m.knee_velocity,
            m.knee_acceleration,
            m.knee_jerk,
            m.knee_torque,
            m.knee_torque_rate,
            m.load_torque,
            m.gait_phase,
            m.sweep_frequency,
            f64::from(u8::from(m.stance)),
        ]
        .map(f64::to_bits)
    }

    #[test]
    fn the_avx2_build_of_calculate_is_the_baseline_bit_for_bit() {
        if crate::models::bench::plant::no_wide_vectors_here("the baseline build") {
            return;
        }
        let mut compared = 0;
        for motion in 1..=7 {
            for torque in [1, 4, 6] {
                for quantity in [1, 2] {
                    for fade in [0.0, 1.3] {
                        let mut wide = model();
                        wide.motion_waveform = motion;
                        wide.torque_waveform = torque;
                        wide.motion_quantity = quantity;
                        wide.fade_in_time = fade;
                        wide.period = 2.5;
                        wide.step_time = 0.7;
                        assert!(wide.build.wide);
                        let mut baseline = wide.clone();
                        baseline.build.wide = false;
                        for k in 0..400 {
                            // Irregular instants over two periods, and negative and
                            // whole-cycle ones.
                            let t =
                                -0.3 + f64::from(k) * 0.013_7 + (f64::from(k) * 0.37).sin() * 1e-3;
                            for t in [t, 2.5 * f64::from(k % 3)] {
                                wide.calculate(t).unwrap();
                                baseline.calculate(t).unwrap();
                                assert_eq!(
                                    all_output_bits(&wide),
                                    all_output_bits(&baseline),
                                    "motion {motion} torque {torque} quantity {quantity} fade {fade} t {t}"
                                );
                                compared += 1;
                            }
                        }
                    }
                }
            }
        }
        assert_eq!(compared, 7 * 3 * 2 * 2 * 800);
    }
}
