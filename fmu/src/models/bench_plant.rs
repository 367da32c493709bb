//! `BenchPlant`: the knee-actuator bench (DA, SEA, CSEA) as an FMU.
//!
//! The physics is [`super::bench::BenchPlant`]; this module declares its FMU interface once:
//! the parameters (every field of [`BenchParameters`], with its default as start value and its
//! validated range as min/max), the driver and clutch inputs, and every output of
//! [`BenchOutputs`]. [`io_variables`] is the bench's signal interface, shared with any other
//! model that stands for the same bench (the hardware FMU), so a system file runs with either.
//!
//! Outputs are functions of the plant's state at the communication point: the commands set
//! for the next step do not change them (no direct feedthrough), which is what lets a
//! controller and the plant run in a Gauss-Seidel loop without an algebraic loop.

use crate::release::Lazy;
use std::cell::{Cell, RefCell};

use super::bench::{
    BenchInputs, BenchOutputs, BenchParameters, DriverMode, SignalGroup,
    StepOutcome as PlantOutcome, signal_group,
};
use crate::model::{
    Access, EnumerationType, Model, ModelError, Start, StateError, StateReader, StateWriter,
    StepOutcome, Variability, Variable,
};
use crate::registry::ReferenceInputs;

/// The driver and clutch commands of the bench, as FMU inputs.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct BenchCommands {
    /// Test-motor armature voltage set value \[V\] (used in voltage mode).
    pub test_voltage: f64,
    /// Test-motor current set value \[A\] (used in current mode).
    pub test_current: f64,
    /// Load-motor armature voltage set value \[V\] (voltage mode).
    pub load_voltage: f64,
    /// Load-motor current set value \[A\] (current mode).
    pub load_current: f64,
    /// Test driver enabled.
    pub test_enable: bool,
    /// Load driver enabled.
    pub load_enable: bool,
    /// Clutch engaged.
    pub clutch_engage: bool,
    /// Emergency-stop button pressed.
    pub emergency_stop: bool,
}

/// A model that stands for the bench: it has the bench's commands and measurements.
pub trait BenchSignals {
    /// The commands.
    fn commands(&self) -> &BenchCommands;
    /// The commands, to set.
    fn commands_mut(&mut self) -> &mut BenchCommands;
    /// The measurements, to set.
    fn signals_mut(&mut self) -> &mut BenchOutputs;
    /// One measurement, read by `read` from the outputs of `group` (the group of the field
    /// `read` returns, see [`signal_group`]): a model that computes its outputs on demand
    /// computes only that group; one that holds them all reads them.
    fn read_signal<T>(&self, group: SignalGroup, read: fn(&BenchOutputs) -> T) -> T;
}

/// The bench's signal interface (inputs at VR 200.., outputs at VR 300..): one table for every
/// model implementing [`BenchSignals`].
pub fn io_variables<M: BenchSignals>() -> Vec<Variable<M>> {
    type V<M> = Variable<M>;
    macro_rules! input_real {
        ($name:literal, $vr:expr, $field:ident, $unit:literal, $desc:literal) => {
            V::<M>::real(
                $name,
                $vr,
                |m| m.commands().$field,
                |m, v| m.commands_mut().$field = v,
            )
            .input(Start::Real(0.0))
            .unit($unit)
            .describe($desc)
        };
    }
    macro_rules! input_bool {
        ($name:literal, $vr:expr, $field:ident, $start:expr, $desc:literal) => {
            V::<M>::boolean(
                $name,
                $vr,
                |m| m.commands().$field,
                |m, v| m.commands_mut().$field = v,
            )
            .input(Start::Boolean($start))
            .describe($desc)
        };
    }
    macro_rules! out_real {
        ($name:literal, $vr:expr, $field:ident, None, $desc:literal) => {
            V::<M>::real(
                $name,
                $vr,
                |m| m.read_signal(const { signal_group(stringify!($field)) }, |o| o.$field),
                |m, v| m.signals_mut().$field = v,
            )
            .output(&[])
            .initial_on_all_knowns()
            .describe($desc)
        };
        ($name:literal, $vr:expr, $field:ident, $unit:literal, $desc:literal) => {
            V::<M>::real(
                $name,
                $vr,
                |m| m.read_signal(const { signal_group(stringify!($field)) }, |o| o.$field),
                |m, v| m.signals_mut().$field = v,
            )
            .output(&[])
            .initial_on_all_knowns()
            .unit($unit)
            .describe($desc)
        };
    }
    macro_rules! out_bool {
        ($name:literal, $vr:expr, $field:ident, $desc:literal) => {
            V::<M>::boolean(
                $name,
                $vr,
                |m| m.read_signal(const { signal_group(stringify!($field)) }, |o| o.$field),
                |m, v| m.signals_mut().$field = v,
            )
            .output(&[])
            .initial_on_all_knowns()
            .describe($desc)
        };
    }
    macro_rules! out_int {
        ($name:literal, $vr:expr, $field:ident, $desc:literal) => {
            V::<M>::integer(
                $name,
                $vr,
                |m| m.read_signal(const { signal_group(stringify!($field)) }, |o| o.$field),
                |m, v| m.signals_mut().$field = v,
            )
            .output(&[])
            .initial_on_all_knowns()
            .describe($desc)
        };
    }
    vec![
        input_real!(
            "testVoltageCommand",
            200,
            test_voltage,
            "V",
            "Test-motor armature voltage set value (voltage mode), saturated at the supply"
        ),
        input_real!(
            "testCurrentCommand",
            201,
            test_current,
            "A",
            "Test-motor current set value (current mode), clipped to the driver's limit"
        ),
        input_real!(
            "loadVoltageCommand",
            202,
            load_voltage,
            "V",
            "Load-motor armature voltage set value (voltage mode), saturated at the supply"
        ),
        input_real!(
            "loadCurrentCommand",
            203,
            load_current,
            "A",
            "Load-motor current set value (current mode), clipped to the driver's limit"
        ),
        input_bool!(
            "testDriverEnable",
            204,
            test_enable,
            true,
            "Test driver enabled (a disabled driver holds zero current)"
        ),
        input_bool!(
            "loadDriverEnable",
            205,
            load_enable,
            true,
            "Load driver enabled"
        ),
        input_bool!(
            "clutchEngage",
            206,
            clutch_engage,
            false,
            "Clutch command: engaged while true"
        ),
        input_bool!(
            "emergencyStop",
            207,
            emergency_stop,
            false,
            "Emergency-stop button: trips the bench at the start of the step"
        ),
        out_real!(
            "actuationAngle",
            300,
            actuation_angle,
            "rad",
            "theta1, actuation-side angle at the knee axis"
        ),
        out_real!(
            "loadAngle",
            301,
            load_angle,
            "rad",
            "theta2, load-side angle"
        ),
        out_real!(
            "actuationVelocity",
            302,
            actuation_velocity,
            "rad/s",
            "omega1"
        ),
        out_real!("loadVelocity", 303, load_velocity, "rad/s", "omega2"),
        out_real!(
            "actuationAcceleration",
            304,
            actuation_acceleration,
            "rad/s2",
            "d omega1/dt"
        ),
        out_real!(
            "loadAcceleration",
            305,
            load_acceleration,
            "rad/s2",
            "d omega2/dt"
        ),
        out_real!(
            "springDeflection",
            306,
            spring_deflection,
            "rad",
            "theta1 - theta2"
        ),
        out_real!(
            "springTorque",
            307,
            spring_torque,
            "N.m",
            "Torque in the coupling, k (theta1 - theta2)"
        ),
        out_real!(
            "testMotorCurrent",
            308,
            test_motor_current,
            "A",
            "Test-motor armature current i1"
        ),
        out_real!(
            "loadMotorCurrent",
            309,
            load_motor_current,
            "A",
            "Load-motor armature current i2"
        ),
        out_real!(
            "testMotorVoltage",
            310,
            test_motor_voltage,
            "V",
            "Test-motor armature voltage"
        ),
        out_real!(
            "loadMotorVoltage",
            311,
            load_motor_voltage,
            "V",
            "Load-motor armature voltage"
        ),
        out_real!(
            "testMotorTorque",
            312,
            test_motor_torque,
            "N.m",
            "Test-motor shaft torque Km1 i1 (motor side)"
        ),
        out_real!(
            "loadMotorTorque",
            313,
            load_motor_torque,
            "N.m",
            "Load-motor shaft torque Km2 i2 (motor side)"
        ),
        out_real!(
            "testOutputTorque",
            314,
            test_output_torque,
            "N.m",
            "Test-motor torque at the output, i_HD Km1 i1"
        ),
        out_real!(
            "loadOutputTorque",
            315,
            load_output_torque,
            "N.m",
            "Load-motor torque at the output, i_RED Km2 i2"
        ),
        out_real!(
            "actuationFrictionTorque",
            316,
            actuation_friction_torque,
            "N.m",
            "Friction torque on the actuation side (incl. clutch) while sliding"
        ),
        out_real!(
            "loadFrictionTorque",
            317,
            load_friction_torque,
            "N.m",
            "Friction torque on the load side while sliding"
        ),
        out_real!(
            "actuationEncoderAngle",
            318,
            actuation_encoder_angle,
            "rad",
            "Actuation encoder angle, quantised to the encoder resolution"
        ),
        out_real!(
            "loadEncoderAngle",
            319,
            load_encoder_angle,
            "rad",
            "Load encoder angle, quantised"
        ),
        out_real!(
            "actuationEncoderCounts",
            320,
            actuation_encoder_counts,
            None,
            "Actuation encoder count"
        ),
        out_real!(
            "loadEncoderCounts",
            321,
            load_encoder_counts,
            None,
            "Load encoder count"
        ),
        out_real!(
            "loadCellVoltage",
            322,
            load_cell_voltage,
            "V",
            "Load-cell raw voltage"
        ),
        out_real!(
            "loadCellTorque",
            323,
            load_cell_torque,
            "N.m",
            "Load-cell torque by the bench's calibration"
        ),
        out_real!(
            "transducerVoltage",
            324,
            transducer_voltage,
            "V",
            "Torque-transducer raw voltage"
        ),
        out_real!(
            "transducerTorque",
            325,
            transducer_torque,
            "N.m",
            "Torque-transducer torque by the bench's calibration"
        ),
        out_real!(
            "testSupplySenseVoltage",
            326,
            test_supply_sense_voltage,
            "V",
            "Test supply voltage-divider reading"
        ),
        out_real!(
            "loadSupplySenseVoltage",
            327,
            load_supply_sense_voltage,
            "V",
            "Load supply voltage-divider reading"
        ),
        out_real!(
            "testCurrentSenseVoltage",
            328,
            test_current_sense_voltage,
            "V",
            "Test current-sensor voltage"
        ),
        out_real!(
            "loadCurrentSenseVoltage",
            329,
            load_current_sense_voltage,
            "V",
            "Load current-sensor voltage"
        ),
        out_bool!("clutchEngaged", 330, clutch_engaged, "Clutch engaged"),
        out_bool!(
            "actuationStuck",
            331,
            actuation_stuck,
            "Actuation side held by static friction"
        ),
        out_bool!(
            "loadStuck",
            332,
            load_stuck,
            "Load side held by static friction"
        ),
        out_bool!(
            "testDriverSaturated",
            333,
            test_driver_saturated,
            "Test current loop saturated at the supply"
        ),
        out_bool!(
            "loadDriverSaturated",
            334,
            load_driver_saturated,
            "Load current loop saturated at the supply"
        ),
        out_real!(
            "testMechanicalPower",
            335,
            test_mechanical_power,
            "W",
            "P_test = i_HD Km1 i1 omega1"
        ),
        out_real!(
            "loadMechanicalPower",
            336,
            load_mechanical_power,
            "W",
            "P_load = i_RED Km2 i2 omega2"
        ),
        out_real!(
            "lossPower",
            337,
            loss_power,
            "W",
            "P_HD: all mechanical losses (viscous, friction, clutch), <= 0"
        ),
        out_real!(
            "actuationLossPower",
            338,
            actuation_loss_power,
            "W",
            "Actuation-side part of P_HD"
        ),
        out_real!(
            "loadLossPower",
            339,
            load_loss_power,
            "W",
            "Load-side part of P_HD"
        ),
        out_real!(
            "kineticEnergyRate",
            340,
            kinetic_energy_rate,
            "W",
            "dE_k/dt"
        ),
        out_real!(
            "potentialEnergyRate",
            341,
            potential_energy_rate,
            "W",
            "dE_p/dt"
        ),
        out_real!(
            "testElectricalPower",
            342,
            test_electrical_power,
            "W",
            "Test driver electrical power V1 i1"
        ),
        out_real!(
            "loadElectricalPower",
            343,
            load_electrical_power,
            "W",
            "Load driver electrical power V2 i2 (negative: regenerating)"
        ),
        out_real!(
            "loadRegeneratedPower",
            344,
            load_regenerated_power,
            "W",
            "Power regenerated into the load driver, max(-V2 i2, 0)"
        ),
        out_real!(
            "clutchPower",
            345,
            clutch_power,
            "W",
            "Clutch electrical power"
        ),
        out_real!(
            "offsetPower",
            346,
            offset_power,
            "W",
            "Hardware offset power"
        ),
        out_real!(
            "totalElectricalPower",
            347,
            total_electrical_power,
            "W",
            "Both drivers' electrical power V1 i1 + V2 i2 (signed) plus the hardware offset and the clutch; the bench's P_el (eq. 70) is testElectricalPower + offsetPower + clutchPower"
        ),
        out_real!(
            "kineticEnergy",
            348,
            kinetic_energy,
            "J",
            "E_k = (I1 w1^2 + I2 w2^2)/2"
        ),
        out_real!(
            "potentialEnergy",
            349,
            potential_energy,
            "J",
            "E_p = k (theta1 - theta2)^2 / 2"
        ),
        out_real!(
            "testMechanicalEnergy",
            350,
            test_mechanical_energy,
            "J",
            "Integral of P_test"
        ),
        out_real!(
            "testMechanicalEnergyConsumed",
            351,
            test_mechanical_energy_consumed,
            "J",
            "Integral of max(P_test, 0)"
        ),
        out_real!(
            "loadMechanicalEnergy",
            352,
            load_mechanical_energy,
            "J",
            "Integral of P_load"
        ),
        out_real!(
            "loadMechanicalEnergyConsumed",
            353,
            load_mechanical_energy_consumed,
            "J",
            "Integral of max(P_load, 0)"
        ),
        out_real!(
            "lossEnergy",
            354,
            loss_energy,
            "J",
            "Integral of P_HD (<= 0)"
        ),
        out_real!(
            "actuationLossEnergy",
            355,
            actuation_loss_energy,
            "J",
            "Integral of the actuation-side losses"
        ),
        out_real!(
            "loadLossEnergy",
            356,
            load_loss_energy,
            "J",
            "Integral of the load-side losses"
        ),
        out_real!(
            "kineticEnergyChange",
            357,
            kinetic_energy_change,
            "J",
            "E_k(t) - E_k(0)"
        ),
        out_real!(
            "potentialEnergyChange",
            358,
            potential_energy_change,
            "J",
            "E_p(t) - E_p(0)"
        ),
        out_real!(
            "testElectricalEnergy",
            359,
            test_electrical_energy,
            "J",
            "Integral of V1 i1"
        ),
        out_real!(
            "testElectricalEnergyConsumed",
            360,
            test_electrical_energy_consumed,
            "J",
            "Integral of max(V1 i1, 0)"
        ),
        out_real!(
            "loadElectricalEnergy",
            361,
            load_electrical_energy,
            "J",
            "Integral of V2 i2"
        ),
        out_real!(
            "loadElectricalEnergyConsumed",
            362,
            load_electrical_energy_consumed,
            "J",
            "Integral of max(V2 i2, 0)"
        ),
        out_real!(
            "clutchEnergy",
            363,
            clutch_energy,
            "J",
            "Clutch electrical energy"
        ),
        out_real!(
            "offsetEnergy",
            364,
            offset_energy,
            "J",
            "Hardware offset energy"
        ),
        out_real!(
            "totalElectricalEnergy",
            365,
            total_electrical_energy,
            "J",
            "Integral of totalElectricalPower: both drivers (V1 i1 + V2 i2, signed), the hardware offset and the clutch; the bench's electrical energy (eq. 70) is testElectricalEnergy + offsetEnergy + clutchEnergy"
        ),
        out_real!(
            "totalElectricalEnergyConsumed",
            366,
            total_electrical_energy_consumed,
            "J",
            "Integral of the positive part of the total electrical power"
        ),
        out_real!(
            "testCopperLossEnergy",
            367,
            test_copper_loss_energy,
            "J",
            "Copper loss of the test motor, integral of R1 i1^2"
        ),
        out_real!(
            "loadCopperLossEnergy",
            368,
            load_copper_loss_energy,
            "J",
            "Copper loss of the load motor"
        ),
        out_real!(
            "testBackEmfEnergy",
            369,
            test_back_emf_energy,
            "J",
            "Electromechanical conversion energy of the test motor, integral of Ke1 w_m1 i1"
        ),
        out_real!(
            "loadBackEmfEnergy",
            370,
            load_back_emf_energy,
            "J",
            "Electromechanical conversion energy of the load motor"
        ),
        out_real!(
            "hdSurfaceClampCount",
            371,
            hd_surface_clamp_count,
            None,
            "Number of loss-surface evaluations clamped to the tested range"
        ),
        out_bool!(
            "hdSurfaceClamped",
            372,
            hd_surface_clamped,
            "The last loss-surface evaluation was clamped"
        ),
        out_int!(
            "tripCode",
            373,
            trip_code,
            "Trip status: 0 running; else the interlock (1 spring deflection, 2 test motor torque, 3 load motor torque, 4 test current, 5 load current, 6 regenerated power, 7 emergency stop)"
        ),
    ]
}

/// The getter and setter of a tunable Real parameter.
type TunableAccess = (fn(&BenchPlantModel) -> f64, fn(&mut BenchPlantModel, f64));

/// The bench plant FMU.
#[derive(Debug, Clone, Default)]
pub struct BenchPlantModel {
    params: BenchParameters,
    configuration: i32,
    friction_model: i32,
    test_driver_mode: i32,
    load_driver_mode: i32,
    commands: BenchCommands,
    /// Output values; the groups whose bit is set in `fresh` are those of the current state.
    outputs: RefCell<BenchOutputs>,
    /// The outputs' first derivatives, those of the current state if `fresh` has [`RATES`].
    rates: RefCell<OutputRates>,
    /// [`SignalGroup::bit`]s of the groups of `outputs` computed since the last step, and
    /// [`RATES`] once `rates` is.
    fresh: Cell<u8>,
    /// The reference list of the last block read, resolved (`block_read`).
    read_plan: RefCell<block_read::ReadPlan>,
    start_time: f64,
    /// The physics, built at initialization (and on demand for outputs before it).
    plant: Option<super::bench::BenchPlant>,
    /// Parameters changed since the plant last saw them.
    parameters_changed: bool,
}

impl BenchSignals for BenchPlantModel {
    fn commands(&self) -> &BenchCommands {
        &self.commands
    }
    fn commands_mut(&mut self) -> &mut BenchCommands {
        &mut self.commands
    }
    fn signals_mut(&mut self) -> &mut BenchOutputs {
        self.outputs.get_mut()
    }
    /// Computes the group on its first read after a step: reading the two angles costs a few
    /// loads, not the ~80 outputs.
    fn read_signal<T>(&self, group: SignalGroup, read: fn(&BenchOutputs) -> T) -> T {
        if self.fresh.get() & group.bit() == 0 {
            self.compute_group(group);
        }
        read(&self.outputs.borrow())
    }
}

/// The outputs' first time derivatives seen through the bench's signal interface: the same
/// variable table ([`io_variables`]) instantiated for this view reads, through each output's
/// own field, its derivative instead of its value. Value and derivative of an output thus share
/// its one declaration (name, value reference, field); no second table maps value references
/// to derivatives.
#[derive(Debug, Clone, Default)]
struct OutputRates {
    /// Unused (the view has no inputs); required by [`BenchSignals`].
    commands: BenchCommands,
    /// The derivatives ([`super::bench::BenchPlant::output_derivatives`]).
    rates: BenchOutputs,
}

impl BenchSignals for OutputRates {
    fn commands(&self) -> &BenchCommands {
        &self.commands
    }
    fn commands_mut(&mut self) -> &mut BenchCommands {
        &mut self.commands
    }
    fn signals_mut(&mut self) -> &mut BenchOutputs {
        &mut self.rates
    }
    fn read_signal<T>(&self, _group: SignalGroup, read: fn(&BenchOutputs) -> T) -> T {
        read(&self.rates)
    }
}

/// The bit of `BenchPlantModel::fresh` that marks the derivatives computed: beside the
/// output groups' bits, so that whatever makes the outputs stale makes them stale too.
const RATES: u8 = 1 << 7;
const _: () = {
    let mut k = 0;
    while k < SignalGroup::ALL.len() {
        assert!(SignalGroup::ALL[k].bit() & RATES == 0);
        k += 1;
    }
};

/// A reader of one output's derivative.
type RateReader = fn(&OutputRates) -> f64;

/// The derivative reader of each Real output, indexed by value reference (`None` for every
/// other value reference): the getters of [`io_variables`] instantiated for [`OutputRates`].
fn rate_readers() -> Vec<Option<RateReader>> {
    let mut readers = Vec::new();
    for v in io_variables::<OutputRates>() {
        if let (crate::model::Causality::Output, Access::Real(get, _)) = (v.causality, v.access) {
            let i = v.value_reference as usize;
            if readers.len() <= i {
                readers.resize(i + 1, None);
            }
            readers[i] = Some(get);
        }
    }
    readers
}

// SAFETY: a static (Lazy registers its address for the release at unload).
static RATE_READERS: Lazy<Vec<Option<RateReader>>> = unsafe { Lazy::new(rate_readers) };

impl BenchPlantModel {
    /// The first time derivative of the Real output `value_reference` at the communication
    /// point (`None` for any other variable, or before the plant exists): read by the output's
    /// own getter from [`super::bench::BenchPlant::output_derivatives`], evaluated once per
    /// communication point.
    fn rate_of(&self, value_reference: u32) -> Option<f64> {
        let get = RATE_READERS
            .get(value_reference as usize)
            .copied()
            .flatten()?;
        let plant = self.plant.as_ref()?;
        if self.fresh.get() & RATES == 0 {
            self.rates.borrow_mut().rates = plant.output_derivatives();
            self.fresh.set(self.fresh.get() | RATES);
        }
        Some(get(&self.rates.borrow()))
    }

    /// Computes the outputs of `group` (once per group and step: out of line, so that a read
    /// of a fresh group, every other read, is a bit test and a load without a stack frame).
    #[cold]
    #[inline(never)]
    fn compute_group(&self, group: SignalGroup) {
        if let Some(plant) = &self.plant {
            plant.fill_outputs(group, &mut self.outputs.borrow_mut());
        }
        self.fresh.set(self.fresh.get() | group.bit());
    }
}

pub(crate) static ENUMERATIONS: &[EnumerationType] = &[
    EnumerationType {
        name: "Configuration",
        description: "Actuator configuration of the bench",
        items: &[
            (
                "DA",
                0,
                "Direct actuation: the spring is blocked; the harmonic drive's stiffness couples the halves",
            ),
            (
                "SEA",
                1,
                "Series elastic actuation: the spring connects actuation and load side",
            ),
            (
                "CSEA",
                2,
                "Clutchable SEA: SEA plus the electromagnetic clutch on the actuation side",
            ),
        ],
    },
    EnumerationType {
        name: "FrictionModel",
        description: "Friction law of the shaft halves (viscous c1, c2 always act)",
        items: &[
            ("Off", 0, "No Coulomb or Stribeck friction"),
            (
                "CoulombViscous",
                1,
                "Coulomb friction with a switched stick/slip state",
            ),
            (
                "Exponential",
                2,
                "Exponential Stribeck-like law, stick/slip as for Coulomb",
            ),
            (
                "HdLossSurface",
                3,
                "Steady-state harmonic-drive loss surface on the actuation side, clamped to the tested range; Coulomb on the load side",
            ),
        ],
    },
    EnumerationType {
        name: "DriverMode",
        description: "What a motor driver's command is",
        items: &[
            (
                "Voltage",
                0,
                "The armature voltage set value (saturated at the supply)",
            ),
            (
                "Current",
                1,
                "The current set value of the driver's current loop (clipped to its limit)",
            ),
        ],
    },
];

/// The min/max of bench parameter `field` ([`BenchParameters::PARAMETER_LIMITS`]) and, for one
/// of [`BenchParameters::INTEGER_PARAMETERS`], whole numbers only: the declaration the plant and
/// the hardware FMU give each bench parameter, from the one list `validate` checks.
pub(crate) fn with_limits<M>(v: Variable<M>, field: &str) -> Variable<M> {
    let (lo, hi) = BenchParameters::PARAMETER_LIMITS
        .iter()
        .find(|(n, _, _)| *n == field)
        .map(|&(_, lo, hi)| (lo, hi))
        .unwrap_or((f64::NEG_INFINITY, f64::INFINITY));
    let v = v.range(lo, hi);
    if BenchParameters::INTEGER_PARAMETERS.contains(&field) {
        v.integer_valued()
    } else {
        v
    }
}

/// Sets the unit of a variable when one is given (the parameter list writes `None` for
/// dimensionless parameters).
pub(crate) fn with_unit<M>(v: Variable<M>, unit: Option<&'static str>) -> Variable<M> {
    match unit {
        Some(u) => v.unit(u),
        None => v,
    }
}

/// Calls `$param!(name, value reference, field of BenchParameters, unit or None, meaning)` for
/// every physical parameter of the bench: the one list that the plant and the hardware FMU
/// (which uses a subset) build their parameter variables from, so names, value references,
/// units and meanings cannot drift apart.
macro_rules! for_each_bench_parameter {
    ($param:ident) => {
        $param!("actuationInertia", 10, actuation_inertia, "kg.m2", "I1: actuation-side inertia at the output axis (identified; contains the reflected test-motor rotor)");
        $param!("loadInertia", 11, load_inertia, "kg.m2", "I2: load-side inertia at the output axis (identified; contains the reflected load-motor rotor)");
        $param!("actuationDamping", 12, actuation_damping, "N.m.s/rad", "c1: actuation-side viscous damping");
        $param!("loadDamping", 13, load_damping, "N.m.s/rad", "c2: load-side viscous damping");
        $param!("springStiffness", 14, spring_stiffness, "N.m/rad", "k: equivalent stiffness of the SEA spring chain (SEA and CSEA); zero decouples the halves");
        $param!("directCouplingStiffness", 15, direct_coupling_stiffness, "N.m/rad", "Coupling stiffness in DA: the harmonic drive's own torsional stiffness");
        $param!("harmonicDriveRatio", 16, harmonic_drive_ratio, None, "i_HD: harmonic-drive ratio");
        $param!("reductionRatio", 17, reduction_ratio, None, "i_RED: planetary-gearbox ratio");
        $param!("actuationStaticFriction", 18, actuation_static_friction, "N.m", "Tfr,static1: actuation-side Coulomb/static friction");
        $param!("loadStaticFriction", 19, load_static_friction, "N.m", "Tfr,static2: load-side Coulomb/static friction");
        $param!("actuationStribeckA0", 20, actuation_stribeck_a0, "N.m", "Exponential law, actuation side: a0 (Coulomb level)");
        $param!("actuationStribeckA1", 21, actuation_stribeck_a1, "N.m", "Exponential law, actuation side: a1 (stiction excess over a0)");
        $param!("actuationStribeckB1", 22, actuation_stribeck_b1, "s/rad", "Exponential law, actuation side: b1 (Stribeck decay rate)");
        $param!("actuationStribeckA2", 23, actuation_stribeck_a2, "N.m", "Exponential law, actuation side: a2 (speed-growth amplitude)");
        $param!("actuationStribeckB2", 24, actuation_stribeck_b2, "s/rad", "Exponential law, actuation side: b2 (speed-growth rate)");
        $param!("loadStribeckA0", 25, load_stribeck_a0, "N.m", "Exponential law, load side: a0");
        $param!("loadStribeckA1", 26, load_stribeck_a1, "N.m", "Exponential law, load side: a1");
        $param!("loadStribeckB1", 27, load_stribeck_b1, "s/rad", "Exponential law, load side: b1");
        $param!("loadStribeckA2", 28, load_stribeck_a2, "N.m", "Exponential law, load side: a2");
        $param!("loadStribeckB2", 29, load_stribeck_b2, "s/rad", "Exponential law, load side: b2");
        $param!("hdSurfaceMaxSpeed", 30, hd_surface_max_speed, "rad/s", "Loss surface: largest |omega1| of the tested range (150 deg/s)");
        $param!("hdSurfaceMinLoadTorque", 31, hd_surface_min_load_torque, "N.m", "Loss surface: smallest load torque of the clamping box");
        $param!("hdSurfaceMaxLoadTorque", 32, hd_surface_max_load_torque, "N.m", "Loss surface: largest load torque of the clamping box");
        $param!("testMotorResistance", 33, test_motor_resistance, "Ohm", "Test motor (EC45 flat) armature resistance");
        $param!("testMotorInductance", 34, test_motor_inductance, "H", "Test motor armature inductance");
        $param!("testMotorTorqueConstant", 35, test_motor_torque_constant, "N.m/A", "Test motor torque constant Km1");
        $param!("testMotorBackEmfConstant", 36, test_motor_back_emf_constant, "V.s/rad", "Test motor back-emf constant Ke1");
        $param!("testMotorRotorInertia", 37, test_motor_rotor_inertia, "kg.m2", "Test motor rotor inertia (informational: contained in I1)");
        $param!("loadMotorResistance", 38, load_motor_resistance, "Ohm", "Load motor (EC60 flat) armature resistance");
        $param!("loadMotorInductance", 39, load_motor_inductance, "H", "Load motor armature inductance");
        $param!("loadMotorTorqueConstant", 40, load_motor_torque_constant, "N.m/A", "Load motor torque constant Km2");
        $param!("loadMotorBackEmfConstant", 41, load_motor_back_emf_constant, "V.s/rad", "Load motor back-emf constant Ke2 (= Km2 for a lossless conversion; the table's 0.145 is not used)");
        $param!("loadMotorRotorInertia", 42, load_motor_rotor_inertia, "kg.m2", "Load motor rotor inertia (informational: contained in I2)");
        $param!("testSupplyVoltage", 43, test_supply_voltage, "V", "Test driver (EPOS 24/5) supply voltage: armature voltage saturates at +-this");
        $param!("loadSupplyVoltage", 44, load_supply_voltage, "V", "Load driver (ESCON 50/5) supply voltage");
        $param!("testCurrentLimit", 45, test_current_limit, "A", "Test driver current limit: set values are clipped; an actual current above it trips");
        $param!("loadCurrentLimit", 46, load_current_limit, "A", "Load driver current limit");
        $param!("currentLoopTimeConstant", 47, current_loop_time_constant, "s", "Time constant of the drivers' closed current loop (current mode)");
        $param!("loadRegenPowerLimit", 48, load_regen_power_limit, "W", "Largest regenerated power the load driver absorbs; above it trips");
        $param!("clutchMotorTorque", 49, clutch_motor_torque, "N.m", "Clutch friction torque at the motor side (x i_HD at the output: 120 N m)");
        $param!("clutchRatedPower", 50, clutch_power, "W", "Electrical power of the clutch while engaged");
        $param!("hardwareOffsetPower", 51, hardware_offset_power, "W", "Continuous hardware offset in the bench's electrical measurements");
        $param!("encoderCountsPerRevolution", 52, encoder_counts_per_revolution, None, "Encoder counts per motor revolution after x4 decoding (500 CPT x 4)");
        $param!("transducerOffset", 53, transducer_offset, "V", "Torque transducer calibration a");
        $param!("transducerGain", 54, transducer_gain, "V", "Torque transducer calibration b");
        $param!("transducerPhase", 55, transducer_phase, "rad", "Torque transducer calibration c");
        $param!("loadCellOffset", 56, load_cell_offset, "V", "Load cell calibration a");
        $param!("loadCellGain", 57, load_cell_gain, "V", "Load cell calibration b");
        $param!("loadCellPhase", 58, load_cell_phase, "rad", "Load cell calibration c");
        $param!("calibrationPendulumMoment", 59, calibration_pendulum_moment, "N.m", "Calibration pendulum moment m g Lg (1.94 kg x 9.81 m/s2 x 0.25 m)");
        $param!("dividerOffset", 60, divider_offset, "V", "Supply divider: V_myRIO = offset + gain V_supply; offset");
        $param!("dividerGain", 61, divider_gain, None, "Supply divider gain");
        $param!("currentSensorOffset", 62, current_sensor_offset, "V", "Current sensor (ACS712-20A) output at zero current");
        $param!("currentSensorSensitivity", 63, current_sensor_sensitivity, "V/A", "Current sensor sensitivity");
        $param!("springDeflectionLimit", 64, spring_deflection_limit, "rad", "Interlock: largest spring deflection |theta1 - theta2| (5 deg)");
        $param!("motorTorqueLimit", 65, motor_torque_limit, "N.m", "Interlock: largest shaft torque k (theta1 - theta2) (the test motor past the harmonic drive) and largest load-motor output torque |i_RED Km2 i2|");
        $param!("maxInternalStep", 66, max_internal_step, "s", "Largest internal integration step; communication steps are split into equal sub-steps no longer than this");
    };
}
pub(crate) use for_each_bench_parameter;

/// `Some(unit)` from a unit literal of the parameter list, `None` from `None`.
macro_rules! unit_of {
    (None) => {
        None
    };
    ($unit:literal) => {
        Some($unit)
    };
}
pub(crate) use unit_of;

// SAFETY: a static (Lazy registers its address for the release at unload).
static VARIABLES: Lazy<Vec<Variable<BenchPlantModel>>> = unsafe {
    Lazy::new(|| {
        type V = Variable<BenchPlantModel>;
        let d = BenchParameters::default();
        let mut v: Vec<V> = Vec::new();
        // A tunable parameter of the plant: a change reaches the physics at the next step.
        macro_rules! param {
            ($name:literal, $vr:expr, $field:ident, $unit:tt, $desc:literal) => {{
                let var = V::real(
                    $name,
                    $vr,
                    |m| m.params.$field,
                    |m, x| {
                        m.params.$field = x;
                        m.parameters_changed = true;
                    },
                )
                .tunable(Start::Real(d.$field))
                .describe($desc);
                v.push(with_unit(
                    with_limits(var, stringify!($field)),
                    unit_of!($unit),
                ));
            }};
        }
        v.extend([
            V::enumeration(
                "configuration",
                1,
                "Configuration",
                |m| m.configuration,
                |m, v| m.configuration = v,
            )
            .parameter(Start::Integer(d.configuration.as_i32()))
            .describe("Actuator configuration: DA, SEA or CSEA"),
            V::enumeration(
                "frictionModel",
                2,
                "FrictionModel",
                |m| m.friction_model,
                |m, v| m.friction_model = v,
            )
            .parameter(Start::Integer(d.friction_model.as_i32()))
            .describe("Friction law"),
            V::enumeration(
                "testDriverMode",
                3,
                "DriverMode",
                |m| m.test_driver_mode,
                |m, v| m.test_driver_mode = v,
            )
            .parameter(Start::Integer(d.test_driver_mode.as_i32()))
            .describe("Test-motor driver: voltage or current command"),
            V::enumeration(
                "loadDriverMode",
                4,
                "DriverMode",
                |m| m.load_driver_mode,
                |m, v| m.load_driver_mode = v,
            )
            .parameter(Start::Integer(d.load_driver_mode.as_i32()))
            .describe("Load-motor driver: voltage or current command"),
        ]);
        for_each_bench_parameter!(param);
        // The loss surface's 2 x 21 coefficients (friction model HdLossSurface), at value
        // references 500 + k and 530 + k. Names in the FMI 2.0 structured form of an array
        // element, `hdLossPositiveSpeed[n]`, n = k + 1 = 1..21 (1-based, as Modelica tools write
        // them), in the row order of shared/data/hd-loss-surface.csv; the description names the
        // term. No unit attribute: each term has its own unit N.m/(N.m)^i/(rad/s)^j, which an
        // importer could only convert by 21 unit definitions of fractional meaning; the surface
        // is an empirical fit in fixed units (x in N.m, y in rad/s, value in N.m), stated in
        // each description.
        macro_rules! hd_loss_coefficient {
            ($k:literal, $n:literal, $i:literal, $j:literal) => {{
                v.push(
                    V::real(
                        concat!("hdLossPositiveSpeed[", $n, "]"),
                        500 + $k,
                        |m| m.params.hd_loss_positive_speed[$k],
                        |m, x| {
                            m.params.hd_loss_positive_speed[$k] = x;
                            m.parameters_changed = true;
                        },
                    )
                    .tunable(Start::Real(d.hd_loss_positive_speed[$k]))
                    .describe(concat!(
                        "Loss surface for omega1 >= 0: p", $i, $j, ", the coefficient of x^", $i,
                        " y^", $j, " (x load torque at the output in N.m, y = omega1 in rad/s, surface in N.m: unit N.m/(N.m)^",
                        $i, "/(rad/s)^", $j, ")"
                    )),
                );
                v.push(
                    V::real(
                        concat!("hdLossNegativeSpeed[", $n, "]"),
                        530 + $k,
                        |m| m.params.hd_loss_negative_speed[$k],
                        |m, x| {
                            m.params.hd_loss_negative_speed[$k] = x;
                            m.parameters_changed = true;
                        },
                    )
                    .tunable(Start::Real(d.hd_loss_negative_speed[$k]))
                    .describe(concat!(
                        "Loss surface for omega1 < 0: p", $i, $j, ", the coefficient of x^", $i,
                        " y^", $j, " (x load torque at the output in N.m, y = omega1 in rad/s, surface in N.m: unit N.m/(N.m)^",
                        $i, "/(rad/s)^", $j, ")"
                    )),
                );
            }};
        }
        hd_loss_coefficient!(0, 1, 0, 0);
        hd_loss_coefficient!(1, 2, 1, 0);
        hd_loss_coefficient!(2, 3, 0, 1);
        hd_loss_coefficient!(3, 4, 2, 0);
        hd_loss_coefficient!(4, 5, 1, 1);
        hd_loss_coefficient!(5, 6, 0, 2);
        hd_loss_coefficient!(6, 7, 3, 0);
        hd_loss_coefficient!(7, 8, 2, 1);
        hd_loss_coefficient!(8, 9, 1, 2);
        hd_loss_coefficient!(9, 10, 0, 3);
        hd_loss_coefficient!(10, 11, 4, 0);
        hd_loss_coefficient!(11, 12, 3, 1);
        hd_loss_coefficient!(12, 13, 2, 2);
        hd_loss_coefficient!(13, 14, 1, 3);
        hd_loss_coefficient!(14, 15, 0, 4);
        hd_loss_coefficient!(15, 16, 5, 0);
        hd_loss_coefficient!(16, 17, 4, 1);
        hd_loss_coefficient!(17, 18, 3, 2);
        hd_loss_coefficient!(18, 19, 2, 3);
        hd_loss_coefficient!(19, 20, 1, 4);
        hd_loss_coefficient!(20, 21, 0, 5);
        v.extend(io_variables::<BenchPlantModel>());
        v
    })
};

impl BenchPlantModel {
    /// The parameters with the enumeration parameters applied.
    fn parameters(&self) -> Result<BenchParameters, ModelError> {
        self.params
            .with_enumerations(
                self.configuration,
                self.friction_model,
                self.test_driver_mode,
                self.load_driver_mode,
            )
            .map_err(ModelError::refused)
    }

    /// A model holding `params` and this model's enumerations, and nothing else: what the
    /// tunable parameters' own getters and setters read and write.
    fn parameter_view(&self, params: BenchParameters) -> Self {
        Self {
            params,
            configuration: self.configuration,
            friction_model: self.friction_model,
            test_driver_mode: self.test_driver_mode,
            load_driver_mode: self.load_driver_mode,
            ..Self::default()
        }
    }

    /// The getter and setter of every tunable Real parameter, in declaration order.
    fn tunable_accessors() -> impl Iterator<Item = TunableAccess> {
        Self::variables().iter().filter_map(|v| match v.access {
            Access::Real(get, set) if v.variability == Variability::Tunable => Some((get, set)),
            _ => None,
        })
    }

    /// The tunable Real parameters' values in `params`, in declaration order.
    fn tunable_values(&self, params: &BenchParameters) -> Vec<f64> {
        let view = self.parameter_view(params.clone());
        Self::tunable_accessors()
            .map(|(get, _)| get(&view))
            .collect()
    }

    fn build(&mut self) -> Result<(), ModelError> {
        let p = self.parameters()?;
        let plant =
            super::bench::BenchPlant::new(p).map_err(|e| ModelError::refused(e.to_string()))?;
        self.plant = Some(plant);
        self.outputs_changed();
        self.parameters_changed = false;
        Ok(())
    }

    /// The plant's state changed: every output, and the derivatives, are recomputed on their
    /// next read.
    fn outputs_changed(&mut self) {
        self.fresh.set(0);
    }
}

/// The plant's inputs from the FMU's commands: each driver gets the command of its mode.
fn plant_inputs(c: &BenchCommands, p: &BenchParameters) -> BenchInputs {
    let pick = |mode: DriverMode, voltage: f64, current: f64| match mode {
        DriverMode::Voltage => voltage,
        DriverMode::Current => current,
    };
    BenchInputs {
        test_command: pick(p.test_driver_mode, c.test_voltage, c.test_current),
        load_command: pick(p.load_driver_mode, c.load_voltage, c.load_current),
        test_enable: c.test_enable,
        load_enable: c.load_enable,
        clutch_engage: c.clutch_engage,
        emergency_stop: c.emergency_stop,
    }
}

impl ReferenceInputs for BenchPlantModel {
    fn reference_inputs() -> Option<String> {
        // A documented open-loop run: current-mode sinusoids on both motors (test motor
        // 0.6 A at 0.4 Hz, load motor -0.3 A at 0.8 Hz), clutch engaged from 1.0 s to 1.5 s,
        // sampled at every 1 ms communication point (so importers that interpolate inputs
        // linearly and those that hold them apply the same values).
        let mut csv = String::from("time,testCurrentCommand,loadCurrentCommand,clutchEngage\n");
        for k in 0..=5000 {
            let t = k as f64 / 1000.0;
            let i1 = 0.6 * (std::f64::consts::TAU * 0.4 * t).sin();
            let i2 = -0.3 * (std::f64::consts::TAU * 0.8 * t).sin();
            let clutch = u8::from((1.0..1.5).contains(&t));
            csv.push_str(&format!("{t:?},{i1:?},{i2:?},{clutch}\n"));
        }
        Some(csv)
    }
}

impl Model for BenchPlantModel {
    const IDENTIFIER: &'static str = "BenchPlant";
    const DESCRIPTION: &'static str = "Knee-actuator test bench (DA, SEA, CSEA): two-mass shaft with test and load motors, drivers, friction, clutch, sensors, safety interlocks and energy accounting";
    const MAX_OUTPUT_DERIVATIVE_ORDER: u32 = 1;
    const DEFAULT_EXPERIMENT: (f64, f64, f64) = (0.0, 5.0, 1e-3);

    fn variables() -> &'static [Variable<Self>] {
        &VARIABLES
    }

    fn enumerations() -> &'static [EnumerationType] {
        ENUMERATIONS
    }

    fn initialize(&mut self, start_time: f64) -> Result<(), ModelError> {
        // Built first: parameters the plant refuses leave the instance as it was, start time
        // included (found by tests/tests/call_sequence_fuzz).
        self.build()?;
        self.start_time = start_time;
        Ok(())
    }

    fn calculate(&mut self, _t: f64) -> Result<(), ModelError> {
        // Before initialization the outputs show the initial state of the current parameters.
        if self.plant.is_none()
            || self.parameters_changed && self.plant.as_ref().is_some_and(|p| p.time() == 0.0)
        {
            self.build()?;
        }
        // The outputs themselves are computed by group when read (`read_signal`).
        Ok(())
    }

    /// [`MAX_INTERNAL_STEPS_PER_CALL`](crate::model::MAX_INTERNAL_STEPS_PER_CALL) internal
    /// integration steps of `maxInternalStep`.
    fn max_step_size(&self) -> f64 {
        crate::model::MAX_INTERNAL_STEPS_PER_CALL * self.params.max_internal_step
    }

    /// The outputs' block read (`block_read`).
    #[inline]
    fn read_reals(&self, vrs: &[u32], out: &mut [f64]) -> bool {
        self.read_output_block(vrs, out)
    }

    fn do_step(&mut self, _t: f64, h: f64) -> Result<StepOutcome, ModelError> {
        if self.parameters_changed {
            let p = self.parameters()?;
            let plant = self
                .plant
                .as_mut()
                .ok_or_else(|| ModelError::new("the plant was not initialized"))?;
            plant
                .set_parameters(p)
                .map_err(|e| ModelError::refused(format!("tunable parameters refused: {e}")))?;
            self.parameters_changed = false;
        }
        let Some(plant) = self.plant.as_mut() else {
            return Err(ModelError::new("the plant was not initialized"));
        };
        let inputs = plant_inputs(&self.commands, plant.parameters());
        let outcome = plant.step(&inputs, h);
        // The outputs are computed when they are read (`read_signal`), not after every step.
        self.outputs_changed();
        match outcome {
            PlantOutcome::Completed => Ok(StepOutcome::Completed),
            PlantOutcome::Tripped { interlock, time } => Ok(StepOutcome::Terminated {
                at: self.start_time + time,
                reason: interlock.name(),
            }),
            PlantOutcome::Rejected(e) => Err(ModelError::refused(e.to_string())),
        }
    }

    /// Every Real output has a first derivative, read through its own variable declaration
    /// from [`BenchPlant::output_derivatives`](super::bench::BenchPlant::output_derivatives).
    fn output_derivative(&self, value_reference: u32, order: u32) -> Option<f64> {
        if order != 1 {
            return None;
        }
        self.rate_of(value_reference)
    }

    fn save_internal(&self, w: &mut StateWriter) {
        w.f64(self.start_time);
        w.bool(self.parameters_changed);
        // Formerly "outputs stale"; outputs are always recomputed after a restore.
        w.bool(true);
        match &self.plant {
            Some(plant) => {
                w.bool(true);
                let mut bytes = Vec::new();
                plant.encode_state(&mut bytes);
                w.u32(bytes.len() as u32);
                w.bytes.extend_from_slice(&bytes);
                // A tunable change waiting for the next step: the plant runs on the values
                // in force until then, which the variables no longer hold.
                if self.parameters_changed {
                    for value in self.tunable_values(plant.parameters()) {
                        w.f64(value);
                    }
                }
            }
            None => w.bool(false),
        }
    }

    fn load_internal(&mut self, r: &mut StateReader<'_>) -> Result<(), StateError> {
        self.start_time = r.f64()?;
        let changed = r.bool()?;
        r.bool()?;
        if r.bool()? {
            let len = r.u32()? as usize;
            let mut bytes = r.take(len)?;
            let p = if changed {
                // The plant restarts on the values in force when the state was taken; the
                // variables keep the pending ones, applied at the next step as before.
                let mut in_force = self.parameter_view(self.params.clone());
                for (_, set) in Self::tunable_accessors() {
                    set(&mut in_force, r.f64()?);
                }
                in_force.parameters()
            } else {
                self.parameters()
            }
            .map_err(|e| StateError(e.message))?;
            let mut plant =
                super::bench::BenchPlant::new(p).map_err(|e| StateError(e.to_string()))?;
            plant
                .decode_state(&mut bytes)
                .map_err(|e| StateError(e.to_string()))?;
            self.plant = Some(plant);
        } else {
            self.plant = None;
        }
        self.outputs_changed();
        self.parameters_changed = changed;
        Ok(())
    }

    fn documentation() -> &'static str {
        // SAFETY: a static (Lazy registers its address for the release at unload).
        static HTML: Lazy<String> =
            unsafe { Lazy::new(|| crate::model::module_doc_html(include_str!("bench/mod.rs"))) };
        &HTML
    }
}

#[cfg(test)]
mod lazy_output_tests;

#[cfg(test)]
mod derivative_tests;

mod block_read;
