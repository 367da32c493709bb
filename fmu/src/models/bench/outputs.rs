//! Output values (their first time derivatives are in the sibling module `derivatives`).

use super::mechanics::{CURRENT1, CURRENT2, OMEGA1, OMEGA2, THETA1, THETA2};
use super::{BenchPlant, sensors};

/// Every output of the plant at the current time. Angles in rad and torques in N m at the output
/// (knee) axis unless the name says `motor`; powers in W (positive = into the named element's
/// port from its source: motor power delivered to the shaft, electrical power drawn from the
/// supply); energies in J since the start.
///
/// The doubles come first, in declaration order (`repr(C)`): [`BenchOutputs::reals`] reads
/// them as one array, the FMU's block read of its Real outputs.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
#[repr(C)]
pub struct BenchOutputs {
    /// theta1, actuation-side angle \[rad\].
    pub actuation_angle: f64,
    /// theta2, load-side angle \[rad\].
    pub load_angle: f64,
    /// omega1 [rad/s].
    pub actuation_velocity: f64,
    /// omega2 [rad/s].
    pub load_velocity: f64,
    /// d omega1/dt [rad/s^2].
    pub actuation_acceleration: f64,
    /// d omega2/dt [rad/s^2].
    pub load_acceleration: f64,
    /// theta1 - theta2 \[rad\].
    pub spring_deflection: f64,
    /// Torque in the coupling, k (theta1 - theta2) [N m].
    pub spring_torque: f64,
    /// Test-motor armature current i1 \[A\].
    pub test_motor_current: f64,
    /// Load-motor armature current i2 \[A\].
    pub load_motor_current: f64,
    /// Test-motor armature voltage \[V\].
    pub test_motor_voltage: f64,
    /// Load-motor armature voltage \[V\].
    pub load_motor_voltage: f64,
    /// Test-motor shaft torque Km1 i1 [N m, motor side].
    pub test_motor_torque: f64,
    /// Load-motor shaft torque Km2 i2 [N m, motor side].
    pub load_motor_torque: f64,
    /// Test-motor torque at the output, i_HD Km1 i1 [N m].
    pub test_output_torque: f64,
    /// Load-motor torque at the output, i_RED Km2 i2 [N m].
    pub load_output_torque: f64,
    /// Friction torque acting on the actuation side (incl. clutch) while sliding [N m].
    pub actuation_friction_torque: f64,
    /// Friction torque acting on the load side while sliding [N m].
    pub load_friction_torque: f64,
    /// Actuation encoder angle, quantised \[rad\].
    pub actuation_encoder_angle: f64,
    /// Load encoder angle, quantised \[rad\].
    pub load_encoder_angle: f64,
    /// Actuation encoder count [-].
    pub actuation_encoder_counts: f64,
    /// Load encoder count [-].
    pub load_encoder_counts: f64,
    /// Load-cell raw voltage \[V\].
    pub load_cell_voltage: f64,
    /// Load-cell torque by the bench's calibration [N m].
    pub load_cell_torque: f64,
    /// Torque-transducer raw voltage \[V\].
    pub transducer_voltage: f64,
    /// Torque-transducer torque by the bench's calibration [N m].
    pub transducer_torque: f64,
    /// Test supply divider voltage \[V\].
    pub test_supply_sense_voltage: f64,
    /// Load supply divider voltage \[V\].
    pub load_supply_sense_voltage: f64,
    /// Test current-sensor voltage \[V\].
    pub test_current_sense_voltage: f64,
    /// Load current-sensor voltage \[V\].
    pub load_current_sense_voltage: f64,
    /// P_test = i_HD Km1 i1 omega1 \[W\].
    pub test_mechanical_power: f64,
    /// P_load = i_RED Km2 i2 omega2 \[W\].
    pub load_mechanical_power: f64,
    /// P_HD: all mechanical losses (viscous, friction, clutch), <= 0 \[W\].
    pub loss_power: f64,
    /// Actuation-side part of P_HD \[W\].
    pub actuation_loss_power: f64,
    /// Load-side part of P_HD \[W\].
    pub load_loss_power: f64,
    /// dE_k/dt \[W\].
    pub kinetic_energy_rate: f64,
    /// dE_p/dt \[W\].
    pub potential_energy_rate: f64,
    /// Test driver electrical power V1 i1 \[W\].
    pub test_electrical_power: f64,
    /// Load driver electrical power V2 i2 \[W\] (negative = regenerating).
    pub load_electrical_power: f64,
    /// Power regenerated into the load driver, max(-V2 i2, 0) \[W\].
    pub load_regenerated_power: f64,
    /// Clutch electrical power \[W\].
    pub clutch_power: f64,
    /// Hardware offset power \[W\].
    pub offset_power: f64,
    /// Both drivers' electrical power `V1 i1 + V2 i2` (signed) plus the hardware offset and the
    /// clutch \[W\] (the bench's eq. 70 counts the test driver only).
    pub total_electrical_power: f64,
    /// E_k = (I1 w1^2 + I2 w2^2)/2 \[J\].
    pub kinetic_energy: f64,
    /// E_p = k (theta1 - theta2)^2 / 2 \[J\].
    pub potential_energy: f64,
    /// Integral of P_test \[J\].
    pub test_mechanical_energy: f64,
    /// Integral of max(P_test, 0) \[J\].
    pub test_mechanical_energy_consumed: f64,
    /// Integral of P_load \[J\].
    pub load_mechanical_energy: f64,
    /// Integral of max(P_load, 0) \[J\].
    pub load_mechanical_energy_consumed: f64,
    /// Integral of P_HD \[J\] (<= 0).
    pub loss_energy: f64,
    /// Integral of the actuation-side losses \[J\].
    pub actuation_loss_energy: f64,
    /// Integral of the load-side losses \[J\].
    pub load_loss_energy: f64,
    /// E_k(t) - E_k(0) \[J\].
    pub kinetic_energy_change: f64,
    /// E_p(t) - E_p(0) \[J\].
    pub potential_energy_change: f64,
    /// Integral of V1 i1 \[J\].
    pub test_electrical_energy: f64,
    /// Integral of max(V1 i1, 0) \[J\].
    pub test_electrical_energy_consumed: f64,
    /// Integral of V2 i2 \[J\].
    pub load_electrical_energy: f64,
    /// Integral of max(V2 i2, 0) \[J\].
    pub load_electrical_energy_consumed: f64,
    /// Clutch electrical energy \[J\].
    pub clutch_energy: f64,
    /// Hardware offset energy \[J\].
    pub offset_energy: f64,
    /// Integral of [`Self::total_electrical_power`]: both drivers (signed), the hardware offset
    /// and the clutch \[J\] (the bench's eq. 70 counts the test driver only).
    pub total_electrical_energy: f64,
    /// Integral of the positive part of the total electrical power \[J\].
    pub total_electrical_energy_consumed: f64,
    /// Copper loss of the test motor, integral of R1 i1^2 \[J\].
    pub test_copper_loss_energy: f64,
    /// Copper loss of the load motor \[J\].
    pub load_copper_loss_energy: f64,
    /// Electrical conversion energy of the test motor, integral of Ke1 w_m1 i1 \[J\].
    pub test_back_emf_energy: f64,
    /// Electrical conversion energy of the load motor \[J\].
    pub load_back_emf_energy: f64,
    /// Number of loss-surface evaluations that had to be clamped [-].
    pub hd_surface_clamp_count: f64,
    /// Clutch engaged.
    pub clutch_engaged: bool,
    /// Actuation side held by static friction.
    pub actuation_stuck: bool,
    /// Load side held by static friction.
    pub load_stuck: bool,
    /// Test current loop saturated at the supply.
    pub test_driver_saturated: bool,
    /// Load current loop saturated at the supply.
    pub load_driver_saturated: bool,
    /// The last loss-surface evaluation was clamped.
    pub hd_surface_clamped: bool,
    /// Trip status: 0 running, else [`super::Interlock::code`].
    pub trip_code: i32,
}

/// How many doubles [`BenchOutputs`] starts with.
pub const REAL_OUTPUTS: usize = 67;

// The doubles are the first REAL_OUTPUTS fields, without a gap: the first field after them
// starts right after the last, and the struct is aligned for doubles.
const _: () = {
    assert!(std::mem::offset_of!(BenchOutputs, actuation_angle) == 0);
    assert!(
        std::mem::offset_of!(BenchOutputs, hd_surface_clamp_count)
            == (REAL_OUTPUTS - 1) * size_of::<f64>()
    );
    assert!(std::mem::offset_of!(BenchOutputs, clutch_engaged) == REAL_OUTPUTS * size_of::<f64>());
    assert!(align_of::<BenchOutputs>() == align_of::<f64>());
};

impl BenchOutputs {
    /// The doubles, `actuation_angle` to `hd_surface_clamp_count` in declaration order.
    pub fn reals(&self) -> &[f64; REAL_OUTPUTS] {
        // SAFETY: `BenchOutputs` is `repr(C)` and its first REAL_OUTPUTS fields are doubles
        // (declared so, and checked above: the first at offset 0, the last at
        // (REAL_OUTPUTS - 1) * 8, the next field right after it, so no other field or padding
        // lies between them); an array of as many doubles has that layout and the struct's
        // alignment. The borrow of `self` bounds the array's.
        unsafe { &*(self as *const BenchOutputs).cast::<[f64; REAL_OUTPUTS]>() }
    }
}

/// The parts in which the plant computes its outputs on demand: an importer that reads a few
/// signals after a step pays only for their part (see [`BenchPlant::fill_outputs`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SignalGroup {
    /// Read off the state: angles, velocities, currents, torques, flags.
    Motion,
    /// The energies: integrals since the start, stored kinetic and potential energy.
    Energy,
    /// The sensors' readings: encoders, load cell, transducer, sense voltages.
    Sensors,
    /// Needing the held mode (friction, driver saturation, voltages): accelerations, voltages,
    /// friction torques, powers.
    Mode,
}

impl SignalGroup {
    /// Every group.
    pub const ALL: [SignalGroup; 4] = [
        SignalGroup::Motion,
        SignalGroup::Energy,
        SignalGroup::Sensors,
        SignalGroup::Mode,
    ];

    /// A distinct bit per group (for freshness masks).
    pub const fn bit(self) -> u8 {
        match self {
            SignalGroup::Motion => 1,
            SignalGroup::Sensors => 2,
            SignalGroup::Mode => 4,
            SignalGroup::Energy => 8,
        }
    }
}

/// Fields of [`BenchOutputs`] filled by [`SignalGroup::Sensors`].
const SENSOR_FIELDS: &[&str] = &[
    "actuation_encoder_angle",
    "load_encoder_angle",
    "actuation_encoder_counts",
    "load_encoder_counts",
    "load_cell_voltage",
    "load_cell_torque",
    "transducer_voltage",
    "transducer_torque",
    "test_supply_sense_voltage",
    "load_supply_sense_voltage",
    "test_current_sense_voltage",
    "load_current_sense_voltage",
];

/// Fields of [`BenchOutputs`] filled by [`SignalGroup::Energy`] (a group of their own: an
/// importer reading the angles, the motion group, copies none of these 23 values).
const ENERGY_FIELDS: &[&str] = &[
    "kinetic_energy",
    "potential_energy",
    "test_mechanical_energy",
    "test_mechanical_energy_consumed",
    "load_mechanical_energy",
    "load_mechanical_energy_consumed",
    "loss_energy",
    "actuation_loss_energy",
    "load_loss_energy",
    "kinetic_energy_change",
    "potential_energy_change",
    "test_electrical_energy",
    "test_electrical_energy_consumed",
    "load_electrical_energy",
    "load_electrical_energy_consumed",
    "clutch_energy",
    "offset_energy",
    "total_electrical_energy",
    "total_electrical_energy_consumed",
    "test_copper_loss_energy",
    "load_copper_loss_energy",
    "test_back_emf_energy",
    "load_back_emf_energy",
];

/// Fields of [`BenchOutputs`] filled by [`SignalGroup::Mode`].
const MODE_FIELDS: &[&str] = &[
    "actuation_acceleration",
    "load_acceleration",
    "test_motor_voltage",
    "load_motor_voltage",
    "actuation_friction_torque",
    "load_friction_torque",
    "test_mechanical_power",
    "load_mechanical_power",
    "loss_power",
    "actuation_loss_power",
    "load_loss_power",
    "kinetic_energy_rate",
    "potential_energy_rate",
    "test_electrical_power",
    "load_electrical_power",
    "load_regenerated_power",
    "total_electrical_power",
];

const fn same(a: &str, b: &str) -> bool {
    let (a, b) = (a.as_bytes(), b.as_bytes());
    if a.len() != b.len() {
        return false;
    }
    let mut i = 0;
    while i < a.len() {
        if a[i] != b[i] {
            return false;
        }
        i += 1;
    }
    true
}

const fn listed(field: &str, list: &[&str]) -> bool {
    let mut i = 0;
    while i < list.len() {
        if same(field, list[i]) {
            return true;
        }
        i += 1;
    }
    false
}

/// The group that fills the [`BenchOutputs`] field named `field` (evaluated at compile time by
/// the variable table).
pub const fn signal_group(field: &str) -> SignalGroup {
    if listed(field, SENSOR_FIELDS) {
        SignalGroup::Sensors
    } else if listed(field, MODE_FIELDS) {
        SignalGroup::Mode
    } else if listed(field, ENERGY_FIELDS) {
        SignalGroup::Energy
    } else {
        SignalGroup::Motion
    }
}

impl BenchPlant {
    /// All outputs at the current time (state at the end of the last step, inputs of that step).
    pub fn outputs(&self) -> BenchOutputs {
        let mut out = BenchOutputs::default();
        for group in SignalGroup::ALL {
            self.fill_outputs(group, &mut out);
        }
        out
    }

    /// Writes the fields of `group` (see [`signal_group`]) into `out`.
    pub fn fill_outputs(&self, group: SignalGroup, out: &mut BenchOutputs) {
        #[cfg(target_arch = "x86_64")]
        if self.runs_wide() {
            // SAFETY: `wide_vectors` is set only where the CPU reports AVX2, the one feature
            // `fill_outputs_wide` is compiled for.
            return unsafe { self.fill_outputs_wide(group, out) };
        }
        self.fill_outputs_inline(group, out)
    }

    /// [`Self::fill_outputs`] compiled for AVX2 (same operations, no fused multiply-add; see
    /// [`BenchPlant::step`]).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn fill_outputs_wide(&self, group: SignalGroup, out: &mut BenchOutputs) {
        self.fill_outputs_inline(group, out)
    }

    #[inline(always)]
    fn fill_outputs_inline(&self, group: SignalGroup, out: &mut BenchOutputs) {
        match group {
            SignalGroup::Motion => self.fill_motion(out),
            SignalGroup::Energy => self.fill_energy(out),
            SignalGroup::Sensors => self.fill_sensors(out),
            SignalGroup::Mode => self.fill_mode(out),
        }
    }

    #[inline(always)]
    fn fill_motion(&self, o: &mut BenchOutputs) {
        let p = &self.params;
        let z = &self.state.z;
        let tpa = self.output_torque_per_ampere();
        let deflection = z[THETA1] - z[THETA2];
        o.actuation_angle = z[THETA1];
        o.load_angle = z[THETA2];
        o.actuation_velocity = z[OMEGA1];
        o.load_velocity = z[OMEGA2];
        o.spring_deflection = deflection;
        o.spring_torque = p.coupling_stiffness() * deflection;
        o.test_motor_current = z[CURRENT1];
        o.load_motor_current = z[CURRENT2];
        o.test_motor_torque = p.test_motor_torque_constant * z[CURRENT1];
        o.load_motor_torque = p.load_motor_torque_constant * z[CURRENT2];
        o.test_output_torque = tpa[0] * z[CURRENT1];
        o.load_output_torque = tpa[1] * z[CURRENT2];
        o.clutch_engaged = self.state.clutch;
        o.actuation_stuck = self.state.stuck[0];
        o.load_stuck = self.state.stuck[1];
        o.test_driver_saturated = self.state.saturation[0] != 0.0;
        o.load_driver_saturated = self.state.saturation[1] != 0.0;
        o.clutch_power = if self.state.clutch {
            p.clutch_power
        } else {
            0.0
        };
        o.offset_power = p.hardware_offset_power;
        o.hd_surface_clamp_count = self.state.clamp_count as f64;
        o.hd_surface_clamped = self.state.last_clamped;
        o.trip_code = self.state.trip.map_or(0, |(i, _)| i.code());
    }

    #[inline(always)]
    fn fill_energy(&self, o: &mut BenchOutputs) {
        let p = &self.params;
        let z = &self.state.z;
        let deflection = z[THETA1] - z[THETA2];
        let e = &self.state.energy;
        let kinetic =
            0.5 * (p.actuation_inertia * z[OMEGA1].powi(2) + p.load_inertia * z[OMEGA2].powi(2));
        let potential = 0.5 * p.coupling_stiffness() * deflection * deflection;
        o.kinetic_energy = kinetic;
        o.potential_energy = potential;
        o.test_mechanical_energy = e.test_mechanical;
        o.test_mechanical_energy_consumed = e.test_mechanical_consumed;
        o.load_mechanical_energy = e.load_mechanical;
        o.load_mechanical_energy_consumed = e.load_mechanical_consumed;
        o.loss_energy = e.actuation_loss + e.load_loss;
        o.actuation_loss_energy = e.actuation_loss;
        o.load_loss_energy = e.load_loss;
        o.kinetic_energy_change = kinetic;
        o.potential_energy_change = potential;
        o.test_electrical_energy = e.test_electrical;
        o.test_electrical_energy_consumed = e.test_electrical_consumed;
        o.load_electrical_energy = e.load_electrical;
        o.load_electrical_energy_consumed = e.load_electrical_consumed;
        o.clutch_energy = e.clutch;
        o.offset_energy = e.offset;
        o.total_electrical_energy = e.total_electrical;
        o.total_electrical_energy_consumed = e.total_electrical_consumed;
        o.test_copper_loss_energy = e.test_copper_loss;
        o.load_copper_loss_energy = e.load_copper_loss;
        o.test_back_emf_energy = e.test_back_emf;
        o.load_back_emf_energy = e.load_back_emf;
    }

    #[inline(always)]
    fn fill_sensors(&self, o: &mut BenchOutputs) {
        let p = &self.params;
        let z = &self.state.z;
        let tpa = self.output_torque_per_ampere();
        let spring_torque = p.coupling_stiffness() * (z[THETA1] - z[THETA2]);
        let (enc1_counts, enc1) = sensors::encoder(
            z[THETA1],
            p.harmonic_drive_ratio,
            p.encoder_counts_per_revolution,
        );
        let (enc2_counts, enc2) = sensors::encoder(
            z[THETA2],
            p.reduction_ratio,
            p.encoder_counts_per_revolution,
        );
        let moment = p.calibration_pendulum_moment;
        let phases = self.sensor_phases();
        let load_cell_voltage = sensors::calibrated_sensor_voltage_at_phase(
            tpa[0] * z[CURRENT1],
            p.load_cell_offset,
            p.load_cell_gain,
            phases[0],
            moment,
        );
        let transducer_voltage = sensors::calibrated_sensor_voltage_at_phase(
            spring_torque,
            p.transducer_offset,
            p.transducer_gain,
            phases[1],
            moment,
        );
        o.actuation_encoder_angle = enc1;
        o.load_encoder_angle = enc2;
        o.actuation_encoder_counts = enc1_counts;
        o.load_encoder_counts = enc2_counts;
        o.load_cell_voltage = load_cell_voltage;
        o.load_cell_torque = sensors::calibrated_sensor_torque(
            load_cell_voltage,
            p.load_cell_offset,
            p.load_cell_gain,
            moment,
        );
        o.transducer_voltage = transducer_voltage;
        o.transducer_torque = sensors::calibrated_sensor_torque(
            transducer_voltage,
            p.transducer_offset,
            p.transducer_gain,
            moment,
        );
        o.test_supply_sense_voltage = sensors::divider_voltage(p, p.test_supply_voltage);
        o.load_supply_sense_voltage = sensors::divider_voltage(p, p.load_supply_voltage);
        o.test_current_sense_voltage = sensors::current_sensor_voltage(p, z[CURRENT1]);
        o.load_current_sense_voltage = sensors::current_sensor_voltage(p, z[CURRENT2]);
    }

    #[inline(always)]
    fn fill_mode(&self, o: &mut BenchOutputs) {
        let p = &self.params;
        let held = self.held_for_outputs();
        let (z, rate) = self.rates(&held);
        let k = p.coupling_stiffness();
        let powers = self.powers_at(&held, &z);
        let deflection = z[THETA1] - z[THETA2];
        let friction = [
            if self.state.stuck[0] {
                0.0
            } else {
                held.friction[0]
            },
            if self.state.stuck[1] {
                0.0
            } else {
                held.friction[1]
            },
        ];
        let loss = [
            -p.actuation_damping * z[OMEGA1] * z[OMEGA1] + friction[0] * z[OMEGA1],
            -p.load_damping * z[OMEGA2] * z[OMEGA2] + friction[1] * z[OMEGA2],
        ];
        o.actuation_acceleration = rate[OMEGA1];
        o.load_acceleration = rate[OMEGA2];
        o.test_motor_voltage = self.armature_voltage_at(&held, 0, &z);
        o.load_motor_voltage = self.armature_voltage_at(&held, 1, &z);
        o.actuation_friction_torque = friction[0];
        o.load_friction_torque = friction[1];
        o.test_mechanical_power = powers[0];
        o.load_mechanical_power = powers[1];
        o.loss_power = loss[0] + loss[1];
        o.actuation_loss_power = loss[0];
        o.load_loss_power = loss[1];
        o.kinetic_energy_rate = p.actuation_inertia * z[OMEGA1] * rate[OMEGA1]
            + p.load_inertia * z[OMEGA2] * rate[OMEGA2];
        o.potential_energy_rate = k * deflection * (z[OMEGA1] - z[OMEGA2]);
        o.test_electrical_power = powers[2];
        o.load_electrical_power = powers[3];
        o.load_regenerated_power = (-powers[3]).max(0.0);
        o.total_electrical_power = powers[4];
    }
}
