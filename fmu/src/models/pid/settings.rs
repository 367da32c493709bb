//! What shapes the PID law: the anti-windup and hold enumerations, the bench's gain presets
//! and the checked settings of one controller.

use super::law::AUXILIARIES;
use crate::model::ModelError;
use model_description::num::num;

/// The items of the `AntiWindup` enumeration (the values of [`AntiWindup`]), for every model
/// whose integrator offers the schemes.
pub const ANTI_WINDUP_ITEMS: &[(&str, i32, &str)] = &[
    ("None", AntiWindup::None as i32, "Plain integration"),
    (
        "Clamping",
        AntiWindup::Clamping as i32,
        "Conditional integration: skip integrator steps that drive a saturated output further",
    ),
    (
        "BackCalculation",
        AntiWindup::BackCalculation as i32,
        "Back-calculation: the saturation excess bleeds the integral off with trackingTime",
    ),
];

/// Anti-windup scheme of the integrator (the `pid` module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AntiWindup {
    /// Plain integration.
    None = 0,
    /// Conditional integration: no step that drives a saturated output further.
    Clamping = 1,
    /// Back-calculation with the tracking time constant.
    BackCalculation = 2,
}

impl AntiWindup {
    /// From the FMU's enumeration value.
    pub fn from_i32(v: i32) -> Option<Self> {
        match v {
            0 => Some(Self::None),
            1 => Some(Self::Clamping),
            2 => Some(Self::BackCalculation),
            _ => None,
        }
    }
}

/// What the output does while `hold` is true.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum HoldAction {
    /// Keep the output of the last sample.
    HoldLastOutput = 1,
    /// Output zero.
    ZeroOutput = 2,
}

impl HoldAction {
    /// From the FMU's enumeration value.
    pub fn from_i32(v: i32) -> Option<Self> {
        match v {
            1 => Some(Self::HoldLastOutput),
            2 => Some(Self::ZeroOutput),
            _ => None,
        }
    }
}

/// One gain set of the bench, an item of the `preset` enumeration.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GainPreset {
    /// Item name.
    pub name: &'static str,
    /// Item value.
    pub value: i32,
    /// Item description.
    pub description: &'static str,
    /// (kp, ki, kd).
    pub gains: (f64, f64, f64),
}

/// The gain sets of the bench (bench facts, section 6) as the `preset` enumeration; value 0 is
/// `Custom`.
pub const PRESETS: [GainPreset; 10] = [
    GainPreset {
        name: "SteadyStateVelocityTestMotor",
        value: 1,
        description: "Steady-state velocity tests, test motor (velocity loop): kp 350, ki 100, kd 0",
        gains: (350.0, 100.0, 0.0),
    },
    GainPreset {
        name: "SteadyStateVelocityLoadMotor",
        value: 2,
        description: "Steady-state velocity tests, load motor (torque loop): kp 1.5, ki 0.5, kd 0.2",
        gains: (1.5, 0.5, 0.2),
    },
    GainPreset {
        name: "GaitExperimentTestMotor",
        value: 3,
        description: "Gait experiment on the bench, test motor (position loop): kp 2000, ki 300, kd 100",
        gains: (2000.0, 300.0, 100.0),
    },
    GainPreset {
        name: "GaitExperimentLoadMotor",
        value: 4,
        description: "Gait experiment on the bench, load motor (torque loop): kp 1, ki 10, kd 0.3",
        gains: (1.0, 10.0, 0.3),
    },
    GainPreset {
        name: "GaitSimulationDaTestMotor",
        value: 5,
        description: "Gait simulation DA, test motor (position loop): kp 6300, ki 0.22, kd 0.05",
        gains: (6300.0, 0.22, 0.05),
    },
    GainPreset {
        name: "GaitSimulationSeaTestMotor",
        value: 6,
        description: "Gait simulation SEA, test motor (position loop): kp 6210, ki 0.19, kd 0.045",
        gains: (6210.0, 0.19, 0.045),
    },
    GainPreset {
        name: "GaitSimulationCseaTestMotor",
        value: 7,
        description: "Gait simulation CSEA, test motor (position loop): kp 6210, ki 0.27, kd 0",
        gains: (6210.0, 0.27, 0.0),
    },
    GainPreset {
        name: "GaitSimulationDaLoadMotor",
        value: 8,
        description: "Gait simulation DA, load motor (torque loop): kp 100, ki 1, kd 0",
        gains: (100.0, 1.0, 0.0),
    },
    GainPreset {
        name: "GaitSimulationSeaLoadMotor",
        value: 9,
        description: "Gait simulation SEA, load motor (torque loop): kp 100, ki 1, kd 0",
        gains: (100.0, 1.0, 0.0),
    },
    GainPreset {
        name: "GaitSimulationCseaLoadMotor",
        value: 10,
        description: "Gait simulation CSEA, load motor (torque loop): kp 100, ki 1, kd 0",
        gains: (100.0, 1.0, 0.0),
    },
];

/// The gains (kp, ki, kd) of preset `value`, `None` for `Custom` (0) or an unknown value.
pub fn preset_gains(value: i32) -> Option<(f64, f64, f64)> {
    PRESETS.iter().find(|p| p.value == value).map(|p| p.gains)
}

/// Everything that shapes one PID sample (parameters, after the preset is applied).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PidSettings {
    /// Proportional gain.
    pub kp: f64,
    /// Integral gain [1/s].
    pub ki: f64,
    /// Derivative gain \[s\].
    pub kd: f64,
    /// Derivative filter time constant Tf \[s\] (0: plain backward difference).
    pub derivative_filter_time: f64,
    /// Sample period Ts \[s\].
    pub sample_period: f64,
    /// Lower output limit.
    pub output_min: f64,
    /// Upper output limit.
    pub output_max: f64,
    /// Anti-windup scheme.
    pub anti_windup: AntiWindup,
    /// Back-calculation tracking time constant \[s\].
    pub tracking_time: f64,
    /// Factor of the feed-forward input.
    pub feed_forward_gain: f64,
    /// Weights of the auxiliary inputs in the reference.
    pub setpoint_weights: [f64; AUXILIARIES],
    /// Weights of the auxiliary inputs in the feed-forward term.
    pub feed_forward_weights: [f64; AUXILIARIES],
    /// Output while held.
    pub hold_action: HoldAction,
    /// Error = measurement - setpoint (a plant whose measurement falls when u rises).
    pub reverse_acting: bool,
}

impl PidSettings {
    /// Checks the settings together.
    pub fn validate(&self) -> Result<(), ModelError> {
        let finite = [
            self.kp,
            self.ki,
            self.kd,
            self.derivative_filter_time,
            self.sample_period,
            self.output_min,
            self.output_max,
            self.tracking_time,
            self.feed_forward_gain,
        ]
        .iter()
        .chain(&self.setpoint_weights)
        .chain(&self.feed_forward_weights)
        .all(|x| x.is_finite());
        if !finite {
            return Err(ModelError::refused("PID settings must be finite"));
        }
        if self.sample_period <= 0.0 {
            return Err(ModelError::refused(format!(
                "samplePeriod {} must be positive",
                num(self.sample_period)
            )));
        }
        if self.output_min > self.output_max {
            return Err(ModelError::refused(format!(
                "outputMin {} is above outputMax {}",
                num(self.output_min),
                num(self.output_max)
            )));
        }
        if self.derivative_filter_time < 0.0 {
            return Err(ModelError::refused(format!(
                "derivativeFilterTime {} must not be negative",
                num(self.derivative_filter_time)
            )));
        }
        if self.anti_windup == AntiWindup::BackCalculation && self.tracking_time <= 0.0 {
            return Err(ModelError::refused(format!(
                "trackingTime {} must be positive for back-calculation",
                num(self.tracking_time)
            )));
        }
        Ok(())
    }
}
