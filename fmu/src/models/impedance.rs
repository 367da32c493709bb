//! # ImpedanceController: the CSEA's impedance control (bench model facts, section 6)
//!
//! The bench ran the CSEA with an impedance controller: a virtual stiffness `k_d` and damping
//! `d_d` in series with the spring, realised through the spring's deflection. At each sample
//! (period `samplePeriod`, default 1 ms) it computes
//!
//! ```text
//! tau_d = clip( tau_ff + k_d (theta_ref - theta_load) + d_d (omega_ref - omega_load),
//!               +-desiredTorqueLimit )                          desired interaction torque
//! tau_s = k (theta_act - theta_load)                            spring torque from the deflection
//! i     = PI(tau_d - tau_s) + torqueFeedForwardGain tau_d       current command, saturated
//! ```
//!
//! * `virtualStiffness` `k_d` [N m/rad]: how hard the knee (load side) is pulled toward the
//!   reference angle. The load then sees the series combination of `k_d` and the physical
//!   spring only through the torque loop: a high `k_d` makes the actuator behave like a stiff
//!   position source (tracking, large torques on any load disturbance), a low one lets the load
//!   deviate from the reference and keeps the interaction torque small (compliance). `k_d = 0`
//!   with `d_d = 0` is pure torque control of `tau_ff` (zero-impedance / transparent mode).
//! * `virtualDamping` `d_d` [N m s/rad]: damps the load's motion relative to the reference
//!   velocity; raise it against oscillation of the load side, lower it for a more transparent
//!   actuator.
//! * `torqueFeedForward` (input, N m): added to `tau_d` before the limit, e.g. the knee-torque
//!   reference so the spring carries the expected gait torque without waiting for an error.
//!   Three auxiliary inputs `auxiliary1..3` add to it through `torqueFeedForwardWeight1..3`
//!   (default 0): `tau_ff = torqueFeedForward + sum_i w_i auxiliary_i`, e.g. the reference
//!   velocity and acceleration times the load side's damping and inertia, with no summing
//!   block in the system.
//! * `desiredTorqueLimit` [N m]: clips `tau_d` (default 20 N m, the bench's motor-torque
//!   interlock at the output; the spring reaches its 5 deg interlock at 29.7 N m).
//! * `springStiffness` `k` [N m/rad]: turns the measured deflection into the spring torque; the
//!   identified 340.54 by default. Wire the encoder angles (`actuationEncoderAngle`,
//!   `loadEncoderAngle`) to measure as the bench does, or the plant's exact angles.
//! * Inner torque loop: a PI on `tau_d - tau_s` (gains `torqueKp` [A/(N m)], `torqueKi`
//!   [A/(N m s)]) plus the feed-forward `torqueFeedForwardGain tau_d` [A/(N m)], whose default
//!   `1/(i_HD Km1)` = 1/5.92 is the current that gives `tau_d` at the output. The PI is the
//!   [`PidController`](super::pid::PidController) law (no derivative): clamping or
//!   back-calculation anti-windup, saturation at `outputMin`/`outputMax` (+-15 A, the test
//!   driver), bumpless gain changes and the `hold` input (integrator frozen, output held or
//!   zero, `holdAction`), e.g. from the clutch scheduler while the clutch locks the actuation
//!   side. The inner loop drives the spring torque to `tau_d`.
//!
//! The defaults (`k_d` 200 N m/rad, `d_d` 5 N m s/rad, `torqueKp` 0.5 A/(N m), `torqueKi` 5
//! A/(N m s)) are a stable starting point on the simulated bench, not values from the study
//! (it publishes none for the impedance controller).
//!
//! Sampling, communication steps, direct feedthrough and the FMU-state contents are as for
//! `PidController` (the same sample clock): the samples in `[t, t + h)` run with the inputs
//! held over the step (FMI 2.0's inputs are constant over a step); any step is accepted, also
//! one that crosses instants and ends between two (the clock then waits there for the next
//! instant); at a sample instant the outputs are computed from the inputs just set; between
//! instants they are those of the last executed sample.

use crate::release::Lazy;

use super::pid::{
    ANTI_WINDUP_ITEMS, AUXILIARIES, AntiWindup, HoldAction, PidInputs, PidSettings, PidSignals,
    PidState, SampleClock, pid_sample,
};
use crate::model::{
    EnumerationType, Model, ModelError, Start, StateError, StateReader, StateWriter, StepOutcome,
    Variable,
};
use crate::registry::ReferenceInputs;

/// The controller's inputs.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ImpedanceInputs {
    /// theta_ref \[rad\].
    pub angle_reference: f64,
    /// omega_ref [rad/s].
    pub velocity_reference: f64,
    /// tau_ff [N m] (before the auxiliaries).
    pub torque_feed_forward: f64,
    /// Auxiliary signals weighted into tau_ff.
    pub auxiliary: [f64; AUXILIARIES],
    /// theta_act: actuation-side angle \[rad\].
    pub actuation_angle: f64,
    /// theta_load: load-side angle \[rad\].
    pub load_angle: f64,
    /// omega_load [rad/s].
    pub load_velocity: f64,
    /// Hold the inner loop (integrator frozen, output held).
    pub hold: bool,
}

/// What one sample computes.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ImpedanceSignals {
    /// Current command \[A\].
    pub current_command: f64,
    /// tau_d after the limit [N m].
    pub desired_torque: f64,
    /// tau_s = k deflection [N m].
    pub spring_torque: f64,
    /// tau_d - tau_s [N m].
    pub torque_error: f64,
    /// theta_act - theta_load \[rad\].
    pub spring_deflection: f64,
    /// The current command was clipped.
    pub saturated: bool,
}

impl ImpedanceSignals {
    /// Fails naming the first output (by its FMI name) that is NaN or infinite at time `t`:
    /// gains or inputs so large that the law overflows never pass as fmi2OK.
    pub fn check_finite(&self, t: f64) -> Result<(), ModelError> {
        let values = [
            ("currentCommand", self.current_command),
            ("desiredTorque", self.desired_torque),
            ("springTorqueEstimate", self.spring_torque),
            ("torqueError", self.torque_error),
            ("measuredDeflection", self.spring_deflection),
        ];
        match values.iter().find(|(_, v)| !v.is_finite()) {
            None => Ok(()),
            Some((name, v)) => Err(ModelError::new(format!(
                "output {name} is {v} at t = {t} s: the gains or inputs overflow the control law"
            ))),
        }
    }
}

/// The impedance controller's parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImpedanceSettings {
    /// k_d [N m/rad].
    pub virtual_stiffness: f64,
    /// d_d [N m s/rad].
    pub virtual_damping: f64,
    /// k [N m/rad].
    pub spring_stiffness: f64,
    /// |tau_d| limit [N m].
    pub desired_torque_limit: f64,
    /// Weights of the auxiliary inputs in tau_ff [N m per auxiliary unit].
    pub feed_forward_weights: [f64; AUXILIARIES],
    /// The inner PI (setpoint tau_d, measurement tau_s, feed-forward tau_d).
    pub torque_loop: PidSettings,
}

/// One sample: the signals now and the inner loop's state for the next sample.
pub fn impedance_sample(
    s: &ImpedanceSettings,
    state: &PidState,
    input: &ImpedanceInputs,
) -> (ImpedanceSignals, PidState) {
    let feed_forward = input.torque_feed_forward
        + input
            .auxiliary
            .iter()
            .zip(&s.feed_forward_weights)
            .map(|(x, w)| w * x)
            .sum::<f64>();
    let raw = feed_forward
        + s.virtual_stiffness * (input.angle_reference - input.load_angle)
        + s.virtual_damping * (input.velocity_reference - input.load_velocity);
    let desired = raw.max(-s.desired_torque_limit).min(s.desired_torque_limit);
    let deflection = input.actuation_angle - input.load_angle;
    let spring = s.spring_stiffness * deflection;
    let (inner, next): (PidSignals, PidState) = pid_sample(
        &s.torque_loop,
        state,
        &PidInputs {
            setpoint: desired,
            measurement: spring,
            feed_forward: desired,
            auxiliary: [0.0; AUXILIARIES],
            hold: input.hold,
        },
    );
    (
        ImpedanceSignals {
            current_command: inner.output,
            desired_torque: desired,
            spring_torque: spring,
            torque_error: inner.error,
            spring_deflection: deflection,
            saturated: inner.saturated,
        },
        next,
    )
}

/// The impedance controller FMU.
#[derive(Debug, Clone, Default)]
pub struct ImpedanceController {
    virtual_stiffness: f64,
    virtual_damping: f64,
    spring_stiffness: f64,
    desired_torque_limit: f64,
    torque_kp: f64,
    torque_ki: f64,
    torque_feed_forward_gain: f64,
    feed_forward_weights: [f64; AUXILIARIES],
    output_min: f64,
    output_max: f64,
    sample_period: f64,
    anti_windup: i32,
    tracking_time: f64,
    hold_action: i32,

    inputs: ImpedanceInputs,
    signals: ImpedanceSignals,

    clock: SampleClock,
    state: PidState,
    held: ImpedanceSignals,
}

/// Value references (stable; never reuse a retired number).
mod vr {
    pub const VIRTUAL_STIFFNESS: u32 = 1;
    pub const VIRTUAL_DAMPING: u32 = 2;
    pub const SPRING_STIFFNESS: u32 = 3;
    pub const DESIRED_TORQUE_LIMIT: u32 = 4;
    pub const TORQUE_KP: u32 = 5;
    pub const TORQUE_KI: u32 = 6;
    pub const TORQUE_FEED_FORWARD_GAIN: u32 = 7;
    pub const OUTPUT_MIN: u32 = 8;
    pub const OUTPUT_MAX: u32 = 9;
    pub const SAMPLE_PERIOD: u32 = 10;
    pub const ANTI_WINDUP: u32 = 11;
    pub const TRACKING_TIME: u32 = 12;
    pub const HOLD_ACTION: u32 = 13;
    /// `torqueFeedForwardWeight1..3`.
    pub const FEED_FORWARD_WEIGHT: [u32; 3] = [14, 15, 16];
    pub const ANGLE_REFERENCE: u32 = 100;
    pub const VELOCITY_REFERENCE: u32 = 101;
    pub const TORQUE_FEED_FORWARD: u32 = 102;
    pub const ACTUATION_ANGLE: u32 = 103;
    pub const LOAD_ANGLE: u32 = 104;
    pub const LOAD_VELOCITY: u32 = 105;
    pub const HOLD: u32 = 106;
    /// `auxiliary1..3`.
    pub const AUXILIARY: [u32; 3] = [107, 108, 109];
    pub const CURRENT_COMMAND: u32 = 200;
    pub const DESIRED_TORQUE: u32 = 201;
    pub const SPRING_TORQUE: u32 = 202;
    pub const TORQUE_ERROR: u32 = 203;
    pub const SPRING_DEFLECTION: u32 = 204;
    pub const SATURATED: u32 = 205;
}

const KNOWNS: &[&str] = &[
    "angleReference",
    "velocityReference",
    "torqueFeedForward",
    "actuationAngle",
    "loadAngle",
    "loadVelocity",
    "hold",
    "virtualStiffness",
    "virtualDamping",
    "springStiffness",
    "desiredTorqueLimit",
    "torqueKp",
    "torqueKi",
    "torqueFeedForwardGain",
    "outputMin",
    "outputMax",
    "samplePeriod",
    "antiWindup",
    "trackingTime",
    "holdAction",
    "auxiliary1",
    "auxiliary2",
    "auxiliary3",
    "torqueFeedForwardWeight1",
    "torqueFeedForwardWeight2",
    "torqueFeedForwardWeight3",
];

static ENUMERATIONS: &[EnumerationType] = &[
    EnumerationType {
        name: "AntiWindup",
        description: "Anti-windup scheme of the torque loop's integrator",
        items: ANTI_WINDUP_ITEMS,
    },
    EnumerationType {
        name: "HoldAction",
        description: "What the current command does while hold is true",
        items: &[
            ("HoldLastOutput", 1, "Keep the command of the last sample"),
            ("ZeroOutput", 2, "Command zero current"),
        ],
    },
];

// SAFETY: a static (Lazy registers its address for the release at unload).
static VARIABLES: Lazy<Vec<Variable<ImpedanceController>>> = unsafe {
    Lazy::new(|| {
        use Start::{Boolean, Integer, Real};
        type V = Variable<ImpedanceController>;
        vec![
        V::real("virtualStiffness", vr::VIRTUAL_STIFFNESS, |m| m.virtual_stiffness, |m, v| m.virtual_stiffness = v)
            .tunable(Real(200.0))
            .unit("N.m/rad")
            .range(0.0, 1e6)
            .describe("k_d: virtual stiffness between the reference angle and the load angle"),
        V::real("virtualDamping", vr::VIRTUAL_DAMPING, |m| m.virtual_damping, |m, v| m.virtual_damping = v)
            .tunable(Real(5.0))
            .unit("N.m.s/rad")
            .range(0.0, 1e6)
            .describe("d_d: virtual damping between the reference velocity and the load velocity"),
        V::real("springStiffness", vr::SPRING_STIFFNESS, |m| m.spring_stiffness, |m, v| m.spring_stiffness = v)
            .tunable(Real(340.54))
            .unit("N.m/rad")
            .range(0.0, 1e7)
            .describe("k: stiffness that turns the measured deflection into the spring torque"),
        V::real("desiredTorqueLimit", vr::DESIRED_TORQUE_LIMIT, |m| m.desired_torque_limit, |m, v| m.desired_torque_limit = v)
            .tunable(Real(20.0))
            .unit("N.m")
            .range(0.0, 1e4)
            .describe("Limit of |tau_d|"),
        V::real("torqueKp", vr::TORQUE_KP, |m| m.torque_kp, |m, v| m.torque_kp = v)
            .tunable(Real(0.5))
            .describe("Torque loop proportional gain [A/(N m)]"),
        V::real("torqueKi", vr::TORQUE_KI, |m| m.torque_ki, |m, v| m.torque_ki = v)
            .tunable(Real(5.0))
            .describe("Torque loop integral gain [A/(N m s)]"),
        V::real("torqueFeedForwardWeight1", vr::FEED_FORWARD_WEIGHT[0], |m| m.feed_forward_weights[0], |m, v| m.feed_forward_weights[0] = v)
            .tunable(Real(0.0))
            .describe("Weight of auxiliary1 in tau_ff (N m per auxiliary unit)"),
        V::real("torqueFeedForwardWeight2", vr::FEED_FORWARD_WEIGHT[1], |m| m.feed_forward_weights[1], |m, v| m.feed_forward_weights[1] = v)
            .tunable(Real(0.0))
            .describe("Weight of auxiliary2 in tau_ff"),
        V::real("torqueFeedForwardWeight3", vr::FEED_FORWARD_WEIGHT[2], |m| m.feed_forward_weights[2], |m, v| m.feed_forward_weights[2] = v)
            .tunable(Real(0.0))
            .describe("Weight of auxiliary3 in tau_ff"),
        V::real("torqueFeedForwardGain", vr::TORQUE_FEED_FORWARD_GAIN, |m| m.torque_feed_forward_gain, |m, v| m.torque_feed_forward_gain = v)
            .tunable(Real(1.0 / (160.0 * 0.037)))
            .describe("Current per N m of tau_d added to the command [A/(N m)]: 1/(i_HD Km1)"),
        V::real("outputMin", vr::OUTPUT_MIN, |m| m.output_min, |m, v| m.output_min = v)
            .tunable(Real(-15.0))
            .unit("A")
            .describe("Lower limit of the current command"),
        V::real("outputMax", vr::OUTPUT_MAX, |m| m.output_max, |m, v| m.output_max = v)
            .tunable(Real(15.0))
            .unit("A")
            .describe("Upper limit of the current command"),
        V::real("samplePeriod", vr::SAMPLE_PERIOD, |m| m.sample_period, |m, v| m.sample_period = v)
            .parameter(Real(1e-3))
            .unit("s")
            .display("ms")
            .range(1e-6, 10.0)
            .describe("Sample period Ts; a communication step executes the sample instants it reaches, inputs held over the step"),
        V::enumeration("antiWindup", vr::ANTI_WINDUP, "AntiWindup", |m| m.anti_windup, |m, v| m.anti_windup = v)
            .tunable(Integer(AntiWindup::Clamping as i32))
            .describe("Anti-windup scheme of the torque loop"),
        V::real("trackingTime", vr::TRACKING_TIME, |m| m.tracking_time, |m, v| m.tracking_time = v)
            .tunable(Real(0.05))
            .unit("s")
            .range(1e-9, 1e6)
            .describe("Back-calculation tracking time constant"),
        V::enumeration("holdAction", vr::HOLD_ACTION, "HoldAction", |m| m.hold_action, |m, v| m.hold_action = v)
            .tunable(Integer(HoldAction::HoldLastOutput as i32))
            .describe("Current command while hold is true"),
        V::real("angleReference", vr::ANGLE_REFERENCE, |m| m.inputs.angle_reference, |m, v| m.inputs.angle_reference = v)
            .input(Real(0.0))
            .unit("rad")
            .display("deg")
            .describe("theta_ref: knee-angle reference"),
        V::real("velocityReference", vr::VELOCITY_REFERENCE, |m| m.inputs.velocity_reference, |m, v| m.inputs.velocity_reference = v)
            .input(Real(0.0))
            .unit("rad/s")
            .display("deg/s")
            .describe("omega_ref: knee-velocity reference"),
        V::real("torqueFeedForward", vr::TORQUE_FEED_FORWARD, |m| m.inputs.torque_feed_forward, |m, v| m.inputs.torque_feed_forward = v)
            .input(Real(0.0))
            .unit("N.m")
            .describe("tau_ff: torque added to the desired interaction torque (e.g. the knee-torque reference)"),
        V::real("auxiliary1", vr::AUXILIARY[0], |m| m.inputs.auxiliary[0], |m, v| m.inputs.auxiliary[0] = v)
            .input(Real(0.0))
            .describe("Auxiliary signal 1, added to tau_ff times torqueFeedForwardWeight1"),
        V::real("auxiliary2", vr::AUXILIARY[1], |m| m.inputs.auxiliary[1], |m, v| m.inputs.auxiliary[1] = v)
            .input(Real(0.0))
            .describe("Auxiliary signal 2, added to tau_ff times torqueFeedForwardWeight2"),
        V::real("auxiliary3", vr::AUXILIARY[2], |m| m.inputs.auxiliary[2], |m, v| m.inputs.auxiliary[2] = v)
            .input(Real(0.0))
            .describe("Auxiliary signal 3, added to tau_ff times torqueFeedForwardWeight3"),
        V::real("actuationAngle", vr::ACTUATION_ANGLE, |m| m.inputs.actuation_angle, |m, v| m.inputs.actuation_angle = v)
            .input(Real(0.0))
            .unit("rad")
            .display("deg")
            .describe("theta_act: measured actuation-side angle (encoder)"),
        V::real("loadAngle", vr::LOAD_ANGLE, |m| m.inputs.load_angle, |m, v| m.inputs.load_angle = v)
            .input(Real(0.0))
            .unit("rad")
            .display("deg")
            .describe("theta_load: measured load-side angle (encoder)"),
        V::real("loadVelocity", vr::LOAD_VELOCITY, |m| m.inputs.load_velocity, |m, v| m.inputs.load_velocity = v)
            .input(Real(0.0))
            .unit("rad/s")
            .display("deg/s")
            .describe("omega_load: measured load-side velocity"),
        V::boolean("hold", vr::HOLD, |m| m.inputs.hold, |m, v| m.inputs.hold = v)
            .input(Boolean(false))
            .describe("While true at a sample: torque-loop integrator frozen, command held (holdAction)"),
        V::real("currentCommand", vr::CURRENT_COMMAND, |m| m.signals.current_command, |m, v| m.signals.current_command = v)
            .output(KNOWNS)
            .unit("A")
            .describe("Test-motor current command, saturated, updated at sample instants"),
        V::real("desiredTorque", vr::DESIRED_TORQUE, |m| m.signals.desired_torque, |m, v| m.signals.desired_torque = v)
            .output(KNOWNS)
            .unit("N.m")
            .describe("tau_d: desired interaction (spring) torque after the limit"),
        V::real("springTorqueEstimate", vr::SPRING_TORQUE, |m| m.signals.spring_torque, |m, v| m.signals.spring_torque = v)
            .output(KNOWNS)
            .unit("N.m")
            .describe("tau_s = k (theta_act - theta_load)"),
        V::real("torqueError", vr::TORQUE_ERROR, |m| m.signals.torque_error, |m, v| m.signals.torque_error = v)
            .output(KNOWNS)
            .unit("N.m")
            .describe("tau_d - tau_s"),
        V::real("measuredDeflection", vr::SPRING_DEFLECTION, |m| m.signals.spring_deflection, |m, v| m.signals.spring_deflection = v)
            .output(KNOWNS)
            .unit("rad")
            .display("deg")
            .describe("theta_act - theta_load"),
        V::boolean("saturated", vr::SATURATED, |m| m.signals.saturated, |m, v| m.signals.saturated = v)
            .output(KNOWNS)
            .describe("The current command was clipped at the last sample"),
    ]
    })
};

impl ImpedanceController {
    /// The settings, checked.
    pub fn settings(&self) -> Result<ImpedanceSettings, ModelError> {
        let torque_loop = PidSettings {
            kp: self.torque_kp,
            ki: self.torque_ki,
            kd: 0.0,
            derivative_filter_time: 0.0,
            sample_period: self.sample_period,
            output_min: self.output_min,
            output_max: self.output_max,
            anti_windup: AntiWindup::from_i32(self.anti_windup).ok_or_else(|| {
                ModelError::refused(format!("antiWindup {} is not an item", self.anti_windup))
            })?,
            tracking_time: self.tracking_time,
            feed_forward_gain: self.torque_feed_forward_gain,
            setpoint_weights: [0.0; AUXILIARIES],
            feed_forward_weights: [0.0; AUXILIARIES],
            hold_action: HoldAction::from_i32(self.hold_action).ok_or_else(|| {
                ModelError::refused(format!("holdAction {} is not an item", self.hold_action))
            })?,
            reverse_acting: false,
        };
        torque_loop.validate()?;
        let s = ImpedanceSettings {
            virtual_stiffness: self.virtual_stiffness,
            virtual_damping: self.virtual_damping,
            spring_stiffness: self.spring_stiffness,
            desired_torque_limit: self.desired_torque_limit,
            feed_forward_weights: self.feed_forward_weights,
            torque_loop,
        };
        if ![
            s.virtual_stiffness,
            s.virtual_damping,
            s.spring_stiffness,
            s.desired_torque_limit,
        ]
        .iter()
        .all(|x| x.is_finite() && *x >= 0.0)
        {
            return Err(ModelError::refused(
                "virtualStiffness, virtualDamping, springStiffness and desiredTorqueLimit must be finite and not negative",
            ));
        }
        if !s.feed_forward_weights.iter().all(|w| w.is_finite()) {
            return Err(ModelError::refused(
                "torqueFeedForwardWeight1..3 must be finite",
            ));
        }
        Ok(s)
    }
}

impl ReferenceInputs for ImpedanceController {
    fn reference_inputs() -> Option<String> {
        // A documented open-loop run: the reference is a 0.4 Hz sine of 0.5 rad (velocity its
        // derivative), torque feed-forward 2 N m from 1 s; the "measured" load angle lags the
        // reference (0.45 rad, 0.1 s late) and the actuation angle leads the load by a
        // deflection of 0.02 sin(2 pi 1.3 t) rad; hold from 3.0 s to 3.4 s. Every 1 ms.
        let mut csv = String::from(
            "time,angleReference,velocityReference,torqueFeedForward,actuationAngle,loadAngle,loadVelocity,hold\n",
        );
        let w = std::f64::consts::TAU * 0.4;
        for k in 0..=5000 {
            let t = k as f64 / 1000.0;
            let r = 0.5 * (w * t).sin();
            let rv = 0.5 * w * (w * t).cos();
            let ff = if k >= 1000 { 2.0 } else { 0.0 };
            let load = 0.45 * (w * (t - 0.1)).sin();
            let load_v = 0.45 * w * (w * (t - 0.1)).cos();
            let act = load + 0.02 * (std::f64::consts::TAU * 1.3 * t).sin();
            let hold = u8::from((3000..3400).contains(&k));
            csv.push_str(&format!(
                "{t:?},{r:?},{rv:?},{ff:?},{act:?},{load:?},{load_v:?},{hold}\n"
            ));
        }
        Some(csv)
    }
}

impl Model for ImpedanceController {
    const IDENTIFIER: &'static str = "ImpedanceController";
    const DESCRIPTION: &'static str = "Impedance controller of the CSEA knee actuator: virtual stiffness and damping in series with the spring, realised through the measured spring deflection by an inner PI torque loop with feed-forward; output the test-motor current command";
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
        self.state = PidState::default();
        self.held = ImpedanceSignals::default();
        Ok(())
    }

    fn calculate(&mut self, t: f64) -> Result<(), ModelError> {
        let s = self.settings()?;
        self.signals = self.clock.outputs_at(t, self.held, |_| {
            impedance_sample(&s, &self.state, &self.inputs).0
        });
        self.signals.check_finite(t)
    }

    fn max_step_size(&self) -> f64 {
        self.clock.max_step_size()
    }

    fn do_step(&mut self, t: f64, h: f64) -> Result<StepOutcome, ModelError> {
        let s = self.settings()?;
        self.clock
            .run_step(t, h, &mut self.state, &mut self.held, |_, state| {
                impedance_sample(&s, state, &self.inputs)
            })?;
        self.signals = self.held;
        self.signals.check_finite(t + h)?;
        Ok(StepOutcome::Completed)
    }

    fn save_internal(&self, w: &mut StateWriter) {
        self.clock.save(w);
        self.state.save(w);
        let h = &self.held;
        for x in [
            h.current_command,
            h.desired_torque,
            h.spring_torque,
            h.torque_error,
            h.spring_deflection,
        ] {
            w.f64(x);
        }
        w.bool(h.saturated);
    }

    fn load_internal(&mut self, r: &mut StateReader<'_>) -> Result<(), StateError> {
        self.clock = SampleClock::load(r)?;
        self.state = PidState::load(r)?;
        self.held = ImpedanceSignals {
            current_command: r.f64()?,
            desired_torque: r.f64()?,
            spring_torque: r.f64()?,
            torque_error: r.f64()?,
            spring_deflection: r.f64()?,
            saturated: r.bool()?,
        };
        Ok(())
    }

    fn documentation() -> &'static str {
        // SAFETY: a static (Lazy registers its address for the release at unload).
        static HTML: Lazy<String> =
            unsafe { Lazy::new(|| crate::model::module_doc_html(include_str!("impedance.rs"))) };
        &HTML
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fmi2::instance::fresh_model;

    fn close(a: f64, b: f64) -> bool {
        (a - b).abs() <= 1e-12 * (1.0 + a.abs().max(b.abs()))
    }

    fn model() -> ImpedanceController {
        let mut m = fresh_model::<ImpedanceController>();
        m.virtual_stiffness = 100.0;
        m.virtual_damping = 2.0;
        m.spring_stiffness = 300.0;
        m.desired_torque_limit = 10.0;
        m.torque_kp = 0.5;
        m.torque_ki = 20.0;
        m.torque_feed_forward_gain = 0.2;
        m.output_min = -4.0;
        m.output_max = 4.0;
        m.initialize(0.0).unwrap();
        m
    }

    #[test]
    fn an_overflowing_law_answers_an_error_naming_the_output() {
        let mut m = model();
        m.inputs.actuation_angle = 1e308;
        m.inputs.load_angle = -1e308;
        let e = m.calculate(0.0).unwrap_err();
        assert!(
            e.message
                .contains("output springTorqueEstimate is inf at t = 0 s"),
            "{e}"
        );
        let e = m.do_step(0.0, 1e-3).unwrap_err();
        assert!(e.message.contains("is inf at t = 0.001 s"), "{e}");
    }

    #[test]
    fn auxiliaries_add_to_the_torque_feed_forward() {
        // tau_d = tau_ff + 2*3 - 0.5*4 + k_d (0.05 - 0.01) + d_d (0.5 - 0.1), with tau_ff = 1.
        let mut m = model();
        m.feed_forward_weights = [2.0, -0.5, 0.0];
        m.inputs = ImpedanceInputs {
            angle_reference: 0.05,
            velocity_reference: 0.5,
            torque_feed_forward: 1.0,
            auxiliary: [3.0, 4.0, 100.0],
            actuation_angle: 0.02,
            load_angle: 0.01,
            load_velocity: 0.1,
            hold: false,
        };
        m.calculate(0.0).unwrap();
        let virtual_part = m.virtual_stiffness * 0.04 + m.virtual_damping * 0.4;
        assert!(
            close(m.signals.desired_torque, 1.0 + 6.0 - 2.0 + virtual_part),
            "{}",
            m.signals.desired_torque
        );
    }

    #[test]
    fn hand_computed_sequence() {
        let mut m = model();
        // Sample 0: tau_d = 100 (0.05 - 0.01) + 2 (0.5 - 0.1) = 4.8 N m;
        // tau_s = 300 (0.02 - 0.01) = 3 N m; e = 1.8; i = 0.5 e + 0 + 0.2 tau_d = 0.9 + 0.96.
        m.inputs = ImpedanceInputs {
            angle_reference: 0.05,
            velocity_reference: 0.5,
            torque_feed_forward: 0.0,
            auxiliary: [0.0; AUXILIARIES],
            actuation_angle: 0.02,
            load_angle: 0.01,
            load_velocity: 0.1,
            hold: false,
        };
        m.calculate(0.0).unwrap();
        assert!(close(m.signals.desired_torque, 4.8));
        assert!(close(m.signals.spring_torque, 3.0));
        assert!(close(m.signals.torque_error, 1.8));
        assert!(close(m.signals.spring_deflection, 0.01));
        assert!(close(m.signals.current_command, 1.86), "{:?}", m.signals);
        m.do_step(0.0, 1e-3).unwrap();
        // Integral after sample 0: 20 * 1e-3 * 1.8 = 0.036 A.
        // Sample 1: feed-forward 1 N m: tau_d = 5.8, same spring: e = 2.8,
        // i = 1.4 + 0.036 + 1.16 = 2.596.
        m.inputs.torque_feed_forward = 1.0;
        m.calculate(1e-3).unwrap();
        assert!(close(m.signals.current_command, 2.596), "{:?}", m.signals);
        m.do_step(1e-3, 1e-3).unwrap();
        // Sample 2: tau_d clipped at 10; tau_s = 0: e = 10, i = 5 + 0.092 + 2 > 4: saturated.
        m.inputs.torque_feed_forward = 50.0;
        m.inputs.actuation_angle = 0.01;
        m.calculate(2e-3).unwrap();
        assert!(close(m.signals.desired_torque, 10.0));
        assert!(close(m.signals.current_command, 4.0) && m.signals.saturated);
        m.do_step(2e-3, 1e-3).unwrap();
        // Clamping: the integral did not grow at the saturated sample (still 0.092).
        assert!(close(m.state.integral, 0.092), "{}", m.state.integral);
    }

    #[test]
    fn zero_impedance_is_torque_control_of_the_feed_forward() {
        let mut m = model();
        m.virtual_stiffness = 0.0;
        m.virtual_damping = 0.0;
        m.torque_ki = 0.0;
        m.inputs.torque_feed_forward = 3.0;
        m.inputs.angle_reference = 1.0;
        m.inputs.actuation_angle = 0.01; // 3 N m in the spring: no error
        m.calculate(0.0).unwrap();
        assert!(close(m.signals.torque_error, 0.0));
        assert!(close(m.signals.current_command, 0.6));
    }

    #[test]
    fn hold_freezes_the_command() {
        let mut m = model();
        m.inputs.angle_reference = 0.01;
        m.do_step(0.0, 1e-3).unwrap();
        let before = m.signals.current_command;
        m.inputs.hold = true;
        m.inputs.angle_reference = 0.05;
        m.calculate(1e-3).unwrap();
        assert_eq!(m.signals.current_command, before);
        m.do_step(1e-3, 2e-3).unwrap();
        assert_eq!(m.signals.current_command, before);
    }

    #[test]
    fn a_step_off_the_grid_runs_its_samples_and_bad_settings_are_refused() {
        let mut m = model();
        m.inputs.angle_reference = 0.01;
        // The samples at 0 and 1 ms, with the inputs held.
        m.do_step(0.0, 1.5e-3).unwrap();
        assert_eq!(m.clock.next, 2);
        let mut n = model();
        n.inputs.angle_reference = 0.01;
        n.do_step(0.0, 2e-3).unwrap();
        assert_eq!((m.state, m.held), (n.state, n.held));
        m.virtual_damping = -1.0;
        assert!(m.settings().is_err());
    }
}
