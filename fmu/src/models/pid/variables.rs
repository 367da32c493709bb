//! The PID controller FMU's variables: value references, enumerations and the variable table.

use crate::release::Lazy;

use super::PidController;
use super::settings::{ANTI_WINDUP_ITEMS, AntiWindup, HoldAction, PRESETS};
use crate::model::{EnumerationType, Start, Variable};

/// Value references (stable; never reuse a retired number).
mod vr {
    pub const PRESET: u32 = 1;
    pub const KP: u32 = 2;
    pub const KI: u32 = 3;
    pub const KD: u32 = 4;
    pub const DERIVATIVE_FILTER_TIME: u32 = 5;
    pub const SAMPLE_PERIOD: u32 = 6;
    pub const OUTPUT_MIN: u32 = 7;
    pub const OUTPUT_MAX: u32 = 8;
    pub const ANTI_WINDUP: u32 = 9;
    pub const TRACKING_TIME: u32 = 10;
    pub const FEED_FORWARD_GAIN: u32 = 11;
    pub const HOLD_ACTION: u32 = 12;
    pub const REVERSE_ACTING: u32 = 13;
    /// `setpointWeight1..3`.
    pub const SETPOINT_WEIGHT: [u32; 3] = [14, 15, 16];
    /// `feedForwardWeight1..3`.
    pub const FEED_FORWARD_WEIGHT: [u32; 3] = [17, 18, 19];
    pub const SETPOINT: u32 = 100;
    pub const MEASUREMENT: u32 = 101;
    pub const FEED_FORWARD: u32 = 102;
    pub const HOLD: u32 = 103;
    /// `auxiliary1..3`.
    pub const AUXILIARY: [u32; 3] = [104, 105, 106];
    pub const U: u32 = 200;
    pub const ERROR: u32 = 201;
    pub const P_TERM: u32 = 202;
    pub const I_TERM: u32 = 203;
    pub const D_TERM: u32 = 204;
    pub const FEED_FORWARD_TERM: u32 = 205;
    pub const U_UNSATURATED: u32 = 206;
    pub const SATURATED: u32 = 207;
    pub const REFERENCE: u32 = 208;
}

/// Inputs and parameters every output depends on.
const KNOWNS: &[&str] = &[
    "setpoint",
    "measurement",
    "feedForward",
    "hold",
    "preset",
    "kp",
    "ki",
    "kd",
    "derivativeFilterTime",
    "samplePeriod",
    "outputMin",
    "outputMax",
    "antiWindup",
    "trackingTime",
    "feedForwardGain",
    "holdAction",
    "reverseActing",
    "auxiliary1",
    "auxiliary2",
    "auxiliary3",
    "setpointWeight1",
    "setpointWeight2",
    "setpointWeight3",
    "feedForwardWeight1",
    "feedForwardWeight2",
    "feedForwardWeight3",
];

// SAFETY: a static (Lazy registers its address for the release at unload).
static PRESET_ITEMS: Lazy<Vec<(&'static str, i32, &'static str)>> = unsafe {
    Lazy::new(|| {
        let mut items = vec![(
            "Custom",
            0,
            "Use the kp, ki and kd parameters (the default)",
        )];
        items.extend(PRESETS.iter().map(|p| (p.name, p.value, p.description)));
        items
    })
};

// SAFETY: a static (Lazy registers its address for the release at unload).
pub(super) static ENUMERATIONS: Lazy<Vec<EnumerationType>> = unsafe {
    Lazy::new(|| {
        vec![
            EnumerationType {
                name: "PidPreset",
                description: "Gain sets the bench used (bench facts, section 6); units: see the documentation",
                items: PRESET_ITEMS.as_slice(),
            },
            EnumerationType {
                name: "AntiWindup",
                description: "Anti-windup scheme of the PID's integrator",
                items: ANTI_WINDUP_ITEMS,
            },
            EnumerationType {
                name: "HoldAction",
                description: "What the PID's output does while hold is true",
                items: &[
                    ("HoldLastOutput", 1, "Keep the output of the last sample"),
                    ("ZeroOutput", 2, "Output zero"),
                ],
            },
        ]
    })
};

// SAFETY: a static (Lazy registers its address for the release at unload).
pub(super) static VARIABLES: Lazy<Vec<Variable<PidController>>> = unsafe {
    Lazy::new(|| {
        use Start::{Boolean, Integer, Real};
        type V = Variable<PidController>;
        // A parameter of the settings: its setter also drops the cached checked settings.
        macro_rules! setting {
        (enumeration $name:literal, $vr:expr, $type_name:literal, $($field:tt)+) => {
            V::enumeration($name, $vr, $type_name, |m| m.$($field)+, |m, v| {
                m.$($field)+ = v;
                m.cached_settings = None;
            })
        };
        ($kind:ident, $name:literal, $vr:expr, $($field:tt)+) => {
            V::$kind($name, $vr, |m| m.$($field)+, |m, v| {
                m.$($field)+ = v;
                m.cached_settings = None;
            })
        };
    }
        vec![
        setting!(enumeration "preset", vr::PRESET, "PidPreset", preset)
            .tunable(Integer(0))
            .describe("Gain set: Custom uses kp, ki, kd; any other item is a gain set of the bench and ignores them"),
        setting!(real, "kp", vr::KP, kp)
            .tunable(Real(1.0))
            .describe("Proportional gain (Custom preset); output unit per error unit"),
        setting!(real, "ki", vr::KI, ki)
            .tunable(Real(1.0))
            .describe("Integral gain (Custom preset); output unit per error unit and second"),
        setting!(real, "kd", vr::KD, kd)
            .tunable(Real(0.01))
            .describe("Derivative gain on the measurement (Custom preset); output unit times second per measurement unit"),
        setting!(real, "derivativeFilterTime", vr::DERIVATIVE_FILTER_TIME, derivative_filter_time)
            .tunable(Real(0.005))
            .unit("s")
            .range(0.0, 1e3)
            .describe("Time constant Tf of the first-order filter of the measurement's derivative (0: backward difference)"),
        setting!(real, "samplePeriod", vr::SAMPLE_PERIOD, sample_period)
            .parameter(Real(1e-3))
            .unit("s")
            .display("ms")
            .range(1e-6, 10.0)
            .describe("Sample period Ts (the myRIO's control period); a communication step executes the sample instants it reaches, inputs held over the step"),
        setting!(real, "outputMin", vr::OUTPUT_MIN, output_min)
            .tunable(Real(-15.0))
            .describe("Lower output limit (default: the test driver's -15 A)"),
        setting!(real, "outputMax", vr::OUTPUT_MAX, output_max)
            .tunable(Real(15.0))
            .describe("Upper output limit (default: the test driver's 15 A)"),
        setting!(enumeration "antiWindup", vr::ANTI_WINDUP, "AntiWindup", anti_windup)
            .tunable(Integer(AntiWindup::Clamping as i32))
            .describe("Anti-windup scheme"),
        setting!(real, "trackingTime", vr::TRACKING_TIME, tracking_time)
            .tunable(Real(0.05))
            .unit("s")
            .range(1e-9, 1e6)
            .describe("Back-calculation tracking time constant Tt"),
        setting!(real, "feedForwardGain", vr::FEED_FORWARD_GAIN, feed_forward_gain)
            .tunable(Real(1.0))
            .describe("Factor of the feedForward input (e.g. 1/(i_RED Km2) for a torque reference in N m to A)"),
        setting!(real, "setpointWeight1", vr::SETPOINT_WEIGHT[0], setpoint_weights[0])
            .tunable(Real(0.0))
            .describe("Weight of auxiliary1 in the reference r (setpoint unit per auxiliary unit)"),
        setting!(real, "setpointWeight2", vr::SETPOINT_WEIGHT[1], setpoint_weights[1])
            .tunable(Real(0.0))
            .describe("Weight of auxiliary2 in the reference r"),
        setting!(real, "setpointWeight3", vr::SETPOINT_WEIGHT[2], setpoint_weights[2])
            .tunable(Real(0.0))
            .describe("Weight of auxiliary3 in the reference r"),
        setting!(real, "feedForwardWeight1", vr::FEED_FORWARD_WEIGHT[0], feed_forward_weights[0])
            .tunable(Real(0.0))
            .describe("Weight of auxiliary1 in the feed-forward term (output unit per auxiliary unit)"),
        setting!(real, "feedForwardWeight2", vr::FEED_FORWARD_WEIGHT[1], feed_forward_weights[1])
            .tunable(Real(0.0))
            .describe("Weight of auxiliary2 in the feed-forward term"),
        setting!(real, "feedForwardWeight3", vr::FEED_FORWARD_WEIGHT[2], feed_forward_weights[2])
            .tunable(Real(0.0))
            .describe("Weight of auxiliary3 in the feed-forward term"),
        setting!(enumeration "holdAction", vr::HOLD_ACTION, "HoldAction", hold_action)
            .tunable(Integer(HoldAction::HoldLastOutput as i32))
            .describe("Output while hold is true"),
        setting!(boolean, "reverseActing", vr::REVERSE_ACTING, reverse_acting)
            .tunable(Boolean(false))
            .describe("Error = measurement - setpoint, for a plant whose measurement falls when u rises"),
        V::real("setpoint", vr::SETPOINT, |m| m.inputs.setpoint, |m, v| m.inputs.setpoint = v)
            .input(Real(0.0))
            .describe("Setpoint r (the loop's quantity: rad, rad/s or N m at the knee axis)"),
        V::real("measurement", vr::MEASUREMENT, |m| m.inputs.measurement, |m, v| m.inputs.measurement = v)
            .input(Real(0.0))
            .describe("Measurement y, same unit as the setpoint"),
        V::real("feedForward", vr::FEED_FORWARD, |m| m.inputs.feed_forward, |m, v| m.inputs.feed_forward = v)
            .input(Real(0.0))
            .describe("Feed-forward input, added to the output times feedForwardGain"),
        V::real("auxiliary1", vr::AUXILIARY[0], |m| m.inputs.auxiliary[0], |m, v| m.inputs.auxiliary[0] = v)
            .input(Real(0.0))
            .describe("Auxiliary reference signal 1, weighted into the reference and the feed-forward"),
        V::real("auxiliary2", vr::AUXILIARY[1], |m| m.inputs.auxiliary[1], |m, v| m.inputs.auxiliary[1] = v)
            .input(Real(0.0))
            .describe("Auxiliary reference signal 2"),
        V::real("auxiliary3", vr::AUXILIARY[2], |m| m.inputs.auxiliary[2], |m, v| m.inputs.auxiliary[2] = v)
            .input(Real(0.0))
            .describe("Auxiliary reference signal 3"),
        V::boolean("hold", vr::HOLD, |m| m.inputs.hold, |m, v| m.inputs.hold = v)
            .input(Boolean(false))
            .describe("While true at a sample: integrator frozen and output held (holdAction)"),
        V::real("u", vr::U, |m| m.signals.output, |m, v| m.signals.output = v)
            .output(KNOWNS)
            .describe("Controller output (driver command: A in current mode, V in voltage mode), saturated, updated at sample instants"),
        V::real("reference", vr::REFERENCE, |m| m.signals.reference, |m, v| m.signals.reference = v)
            .output(KNOWNS)
            .describe("Reference r = setpoint + weighted auxiliaries, the quantity the loop tracks"),
        V::real("error", vr::ERROR, |m| m.signals.error, |m, v| m.signals.error = v)
            .output(KNOWNS)
            .describe("Error e = setpoint - measurement (negated when reverseActing)"),
        V::real("pTerm", vr::P_TERM, |m| m.signals.proportional, |m, v| m.signals.proportional = v)
            .output(KNOWNS)
            .describe("Proportional term kp e"),
        V::real("iTerm", vr::I_TERM, |m| m.signals.integral, |m, v| m.signals.integral = v)
            .output(KNOWNS)
            .describe("Integral term (its value, in output units)"),
        V::real("dTerm", vr::D_TERM, |m| m.signals.derivative, |m, v| m.signals.derivative = v)
            .output(KNOWNS)
            .describe("Derivative term on the filtered measurement derivative"),
        V::real("feedForwardTerm", vr::FEED_FORWARD_TERM, |m| m.signals.feed_forward, |m, v| m.signals.feed_forward = v)
            .output(KNOWNS)
            .describe("feedForwardGain times feedForward"),
        V::real("uUnsaturated", vr::U_UNSATURATED, |m| m.signals.unsaturated, |m, v| m.signals.unsaturated = v)
            .output(KNOWNS)
            .describe("P + I + D + feed-forward before saturation"),
        V::boolean("saturated", vr::SATURATED, |m| m.signals.saturated, |m, v| m.signals.saturated = v)
            .output(KNOWNS)
            .describe("The output was clipped at outputMin or outputMax at the last sample"),
    ]
    })
};
