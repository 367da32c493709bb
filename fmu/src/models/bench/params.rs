//! Parameters of the bench plant with the identified values of bench-model.md as defaults.

use super::{Configuration, DriverMode, FrictionModel, hd_loss};
use thiserror::Error;

/// A parameter set was rejected by [`BenchParameters::validate`].
#[derive(Debug, Clone, PartialEq, Error)]
pub enum ParameterError {
    /// A value is NaN or infinite.
    #[error("parameter `{name}` must be finite, got {value}")]
    NotFinite {
        /// Field name.
        name: &'static str,
        /// Offending value.
        value: f64,
    },
    /// A value lies outside its admissible range.
    #[error("parameter `{name}` = {value} is outside [{min}, {max}]")]
    OutOfRange {
        /// Field name.
        name: &'static str,
        /// Offending value.
        value: f64,
        /// Smallest admissible value.
        min: f64,
        /// Largest admissible value.
        max: f64,
    },
    /// A count kept as a Real ([`BenchParameters::INTEGER_PARAMETERS`]) is not a whole number.
    #[error("parameter `{name}` = {value} must be an integer")]
    NotInteger {
        /// Field name.
        name: &'static str,
        /// Offending value.
        value: f64,
    },
    /// Two values contradict each other.
    #[error("inconsistent parameters: {0}")]
    Inconsistent(&'static str),
}

/// Every physical and numerical parameter of the plant. Angles in rad, torques in Nm at the
/// output (knee) axis unless a name says `motor`.
#[derive(Debug, Clone, PartialEq)]
pub struct BenchParameters {
    /// Actuator configuration (DA, SEA, CSEA).
    pub configuration: Configuration,
    /// Friction law (see [`FrictionModel`]).
    pub friction_model: FrictionModel,
    /// Test-motor driver mode.
    pub test_driver_mode: DriverMode,
    /// Load-motor driver mode.
    pub load_driver_mode: DriverMode,
    /// I1: actuation-side inertia at the output axis [kg m^2] (identified; contains the
    /// reflected test-motor rotor).
    pub actuation_inertia: f64,
    /// I2: load-side inertia at the output axis [kg m^2] (identified; contains the reflected
    /// load-motor rotor).
    pub load_inertia: f64,
    /// c1: actuation-side viscous damping [N m s/rad].
    pub actuation_damping: f64,
    /// c2: load-side viscous damping [N m s/rad].
    pub load_damping: f64,
    /// k: equivalent stiffness of the SEA spring chain [N m/rad] (SEA and CSEA). Zero decouples
    /// the halves (used to test each half alone).
    pub spring_stiffness: f64,
    /// Torsional stiffness of the coupling in DA [N m/rad]: the blocked spring leaves the harmonic
    /// drive's own stiffness (1.3e4 N m/rad) between the halves.
    pub direct_coupling_stiffness: f64,
    /// i_HD: harmonic-drive ratio [-].
    pub harmonic_drive_ratio: f64,
    /// i_RED: planetary-gearbox ratio [-].
    pub reduction_ratio: f64,
    /// Tfr,static1: actuation-side Coulomb/static friction [N m] (Coulomb model and stiction).
    pub actuation_static_friction: f64,
    /// Tfr,static2: load-side Coulomb/static friction [N m].
    pub load_static_friction: f64,
    /// Exponential law, actuation side: a0 (Coulomb level) [N m].
    pub actuation_stribeck_a0: f64,
    /// Exponential law, actuation side: a1 (stiction excess over a0) [N m].
    pub actuation_stribeck_a1: f64,
    /// Exponential law, actuation side: b1 (Stribeck decay rate) [s/rad].
    pub actuation_stribeck_b1: f64,
    /// Exponential law, actuation side: a2 (speed-growth amplitude) [N m].
    pub actuation_stribeck_a2: f64,
    /// Exponential law, actuation side: b2 (speed-growth rate) [s/rad].
    pub actuation_stribeck_b2: f64,
    /// Exponential law, load side: a0 [N m].
    pub load_stribeck_a0: f64,
    /// Exponential law, load side: a1 [N m].
    pub load_stribeck_a1: f64,
    /// Exponential law, load side: b1 [s/rad].
    pub load_stribeck_b1: f64,
    /// Exponential law, load side: a2 [N m].
    pub load_stribeck_a2: f64,
    /// Exponential law, load side: b2 [s/rad].
    pub load_stribeck_b2: f64,
    /// Loss surface: largest |omega1| of the tested range [rad/s] (150 deg/s).
    pub hd_surface_max_speed: f64,
    /// Loss surface: smallest load torque of the clamping box [N m, output side].
    pub hd_surface_min_load_torque: f64,
    /// Loss surface: largest load torque of the clamping box [N m, output side].
    pub hd_surface_max_load_torque: f64,
    /// Loss surface (friction model `HdLossSurface`), `omega1 >= 0`: the coefficients `p_ij` of
    /// `x^i y^j` (x load torque [N m, output side], y = omega1 \[rad/s\], value [N m, output
    /// side]) in the row order of `shared/data/hd-loss-surface.csv` (p00, p10, p01, p20, p11,
    /// p02, ..., p05), which gives the defaults.
    pub hd_loss_positive_speed: [f64; 21],
    /// Loss surface, `omega1 < 0`: coefficients as [`Self::hd_loss_positive_speed`].
    pub hd_loss_negative_speed: [f64; 21],
    /// Test motor (EC45 flat) armature resistance \[Ohm\].
    pub test_motor_resistance: f64,
    /// Test motor armature inductance \[H\].
    pub test_motor_inductance: f64,
    /// Test motor torque constant Km1 [N m/A].
    pub test_motor_torque_constant: f64,
    /// Test motor back-emf constant Ke1 [V s/rad].
    pub test_motor_back_emf_constant: f64,
    /// Test motor rotor inertia [kg m^2], informational: already contained in I1.
    pub test_motor_rotor_inertia: f64,
    /// Load motor (EC60 flat) armature resistance \[Ohm\].
    pub load_motor_resistance: f64,
    /// Load motor armature inductance \[H\].
    pub load_motor_inductance: f64,
    /// Load motor torque constant Km2 [N m/A].
    pub load_motor_torque_constant: f64,
    /// Load motor back-emf constant Ke2 [V s/rad]. Default 0.114 = Km2: a motor converts power
    /// losslessly between its electrical and mechanical ports (Ke = Km in SI units); the
    /// table's 0.145 would make the motor return 27 % more electrical power than it absorbs
    /// mechanically (module docs, "Fidelity against the bench").
    pub load_motor_back_emf_constant: f64,
    /// Load motor rotor inertia [kg m^2], informational: already contained in I2.
    pub load_motor_rotor_inertia: f64,
    /// Test driver (EPOS 24/5) supply voltage \[V\]: armature voltage saturates at +-this.
    pub test_supply_voltage: f64,
    /// Load driver (ESCON 50/5) supply voltage \[V\].
    pub load_supply_voltage: f64,
    /// Test driver current limit \[A\]: current set values are clipped to it; the actual current
    /// exceeding it trips the `TestCurrent` interlock.
    pub test_current_limit: f64,
    /// Load driver current limit \[A\].
    pub load_current_limit: f64,
    /// Time constant of the drivers' closed current loop in current mode \[s\].
    pub current_loop_time_constant: f64,
    /// Largest regenerated (braking) power the load driver absorbs \[W\]; above it trips.
    pub load_regen_power_limit: f64,
    /// Clutch friction torque at the motor side [N m]; the output-side holding torque is this
    /// times i_HD (0.75 x 160 = 120 N m).
    pub clutch_motor_torque: f64,
    /// Electrical power of the clutch while engaged \[W\].
    pub clutch_power: f64,
    /// Continuous hardware offset in the bench's electrical measurements \[W\].
    pub hardware_offset_power: f64,
    /// Encoder counts per motor revolution after x4 decoding [-] (500 CPT x 4).
    pub encoder_counts_per_revolution: f64,
    /// Torque transducer calibration a \[V\].
    pub transducer_offset: f64,
    /// Torque transducer calibration b \[V\].
    pub transducer_gain: f64,
    /// Torque transducer calibration c \[rad\].
    pub transducer_phase: f64,
    /// Load cell calibration a \[V\].
    pub load_cell_offset: f64,
    /// Load cell calibration b \[V\].
    pub load_cell_gain: f64,
    /// Load cell calibration c \[rad\].
    pub load_cell_phase: f64,
    /// Calibration pendulum moment m*g*Lg [N m] (1.94 kg x 9.81 m/s^2 x 0.25 m).
    pub calibration_pendulum_moment: f64,
    /// Supply divider: V_myRIO = offset + gain * V_supply; offset \[V\].
    pub divider_offset: f64,
    /// Supply divider gain [V/V].
    pub divider_gain: f64,
    /// Current sensor (ACS712-20A) output at zero current \[V\].
    pub current_sensor_offset: f64,
    /// Current sensor sensitivity [V/A].
    pub current_sensor_sensitivity: f64,
    /// Interlock: largest spring deflection |theta1 - theta2| \[rad\] (5 deg).
    pub spring_deflection_limit: f64,
    /// Interlock: largest output-side motor torque |i_HD Km1 i1|, |i_RED Km2 i2| [N m].
    pub motor_torque_limit: f64,
    /// Largest internal integration step \[s\]; communication steps are split into equal
    /// sub-steps no longer than this.
    pub max_internal_step: f64,
}

impl Default for BenchParameters {
    fn default() -> Self {
        Self {
            configuration: Configuration::Sea,
            friction_model: FrictionModel::CoulombViscous,
            test_driver_mode: DriverMode::Current,
            load_driver_mode: DriverMode::Current,
            actuation_inertia: 0.825,
            load_inertia: 0.605,
            actuation_damping: 12.0,
            load_damping: 1.0,
            spring_stiffness: 340.54,
            direct_coupling_stiffness: 1.3e4,
            harmonic_drive_ratio: 160.0,
            reduction_ratio: 66.0,
            actuation_static_friction: 5.0,
            load_static_friction: 0.35,
            // Fit documented in the module docs: a0 + a1 = Tfr,static, 20 % Stribeck drop,
            // a2 = a1 (1 - J(b1 W)) / (1 - J(b2 W)) at W = 30 deg x 2 pi x 0.5 Hz.
            actuation_stribeck_a0: 4.0,
            actuation_stribeck_a1: 1.0,
            actuation_stribeck_b1: 20.0,
            actuation_stribeck_a2: 1.117927,
            actuation_stribeck_b2: 2.0,
            load_stribeck_a0: 0.28,
            load_stribeck_a1: 0.07,
            load_stribeck_b1: 20.0,
            load_stribeck_a2: 0.07825489,
            load_stribeck_b2: 2.0,
            hd_surface_max_speed: 150f64.to_radians(),
            hd_surface_min_load_torque: -10.0,
            hd_surface_max_load_torque: 15.0,
            hd_loss_positive_speed: hd_loss::DEFAULT_POSITIVE_SPEED,
            hd_loss_negative_speed: hd_loss::DEFAULT_NEGATIVE_SPEED,
            test_motor_resistance: 0.608,
            test_motor_inductance: 4.63e-4,
            test_motor_torque_constant: 0.037,
            test_motor_back_emf_constant: 0.037,
            test_motor_rotor_inertia: 1.81e-5,
            load_motor_resistance: 1.1,
            load_motor_inductance: 8.64e-4,
            load_motor_torque_constant: 0.114,
            load_motor_back_emf_constant: 0.114,
            load_motor_rotor_inertia: 1.21e-4,
            test_supply_voltage: 24.0,
            load_supply_voltage: 48.0,
            test_current_limit: 15.0,
            load_current_limit: 6.0,
            current_loop_time_constant: 2.5e-4,
            load_regen_power_limit: 5.0,
            clutch_motor_torque: 0.75,
            clutch_power: 6.0,
            hardware_offset_power: 7.0,
            encoder_counts_per_revolution: 2000.0,
            transducer_offset: 0.245,
            transducer_gain: -0.008,
            transducer_phase: -0.01,
            load_cell_offset: 5.43,
            load_cell_gain: 0.001,
            load_cell_phase: 0.019,
            calibration_pendulum_moment: 1.94 * 9.81 * 0.25,
            divider_offset: 0.002,
            divider_gain: 0.139,
            current_sensor_offset: 2.5,
            current_sensor_sensitivity: 0.1,
            spring_deflection_limit: 5f64.to_radians(),
            motor_torque_limit: 20.0,
            max_internal_step: 1e-3,
        }
    }
}

/// The smallest magnitude of a torque sensor's calibration gain b \[V\] that
/// [`BenchParameters::validate`] accepts (the reason is given there).
pub const MIN_SENSOR_GAIN: f64 = 1e-6;

impl BenchParameters {
    /// Sensible (min, max) of every real-valued parameter, by field name. `validate` enforces
    /// these; the FMU declares them as min/max attributes.
    pub const PARAMETER_LIMITS: &'static [(&'static str, f64, f64)] = &[
        ("actuation_inertia", 1e-3, 100.0),
        ("load_inertia", 1e-3, 100.0),
        ("actuation_damping", 0.0, 1e3),
        ("load_damping", 0.0, 1e3),
        ("spring_stiffness", 0.0, 1e5),
        ("direct_coupling_stiffness", 1.0, 1e6),
        ("harmonic_drive_ratio", 1.0, 1e3),
        ("reduction_ratio", 1.0, 1e3),
        ("actuation_static_friction", 0.0, 100.0),
        ("load_static_friction", 0.0, 100.0),
        ("actuation_stribeck_a0", 0.0, 100.0),
        ("actuation_stribeck_a1", 0.0, 100.0),
        ("actuation_stribeck_b1", 0.0, 1e4),
        ("actuation_stribeck_a2", 0.0, 100.0),
        ("actuation_stribeck_b2", 0.0, 1e4),
        ("load_stribeck_a0", 0.0, 100.0),
        ("load_stribeck_a1", 0.0, 100.0),
        ("load_stribeck_b1", 0.0, 1e4),
        ("load_stribeck_a2", 0.0, 100.0),
        ("load_stribeck_b2", 0.0, 1e4),
        ("hd_surface_max_speed", 0.0, 2.618),
        ("hd_surface_min_load_torque", -50.0, 0.0),
        ("hd_surface_max_load_torque", 0.0, 50.0),
        ("test_motor_resistance", 1e-3, 100.0),
        ("test_motor_inductance", 1e-6, 1.0),
        ("test_motor_torque_constant", 1e-4, 10.0),
        ("test_motor_back_emf_constant", 0.0, 10.0),
        ("test_motor_rotor_inertia", 0.0, 1.0),
        ("load_motor_resistance", 1e-3, 100.0),
        ("load_motor_inductance", 1e-6, 1.0),
        ("load_motor_torque_constant", 1e-4, 10.0),
        ("load_motor_back_emf_constant", 0.0, 10.0),
        ("load_motor_rotor_inertia", 0.0, 1.0),
        ("test_supply_voltage", 0.0, 1e3),
        ("load_supply_voltage", 0.0, 1e3),
        ("test_current_limit", 0.0, 1e3),
        ("load_current_limit", 0.0, 1e3),
        ("current_loop_time_constant", 1e-6, 0.1),
        ("load_regen_power_limit", 0.0, 1e6),
        ("clutch_motor_torque", 0.0, 100.0),
        ("clutch_power", 0.0, 1e3),
        ("hardware_offset_power", 0.0, 1e3),
        ("encoder_counts_per_revolution", 1.0, 1e9),
        ("transducer_offset", -10.0, 10.0),
        ("transducer_gain", -10.0, 10.0),
        ("transducer_phase", -1.0, 1.0),
        ("load_cell_offset", -10.0, 10.0),
        ("load_cell_gain", -10.0, 10.0),
        ("load_cell_phase", -1.0, 1.0),
        ("calibration_pendulum_moment", 1e-6, 1e3),
        ("divider_offset", -10.0, 10.0),
        ("divider_gain", -10.0, 10.0),
        ("current_sensor_offset", -10.0, 10.0),
        ("current_sensor_sensitivity", -10.0, 10.0),
        ("spring_deflection_limit", 0.0, 10.0),
        ("motor_torque_limit", 0.0, 1e4),
        ("max_internal_step", 1e-7, 1.0),
    ];

    /// The real-valued fields that only take whole numbers (counts kept as Reals, so that
    /// parameter files writing `2000.0` keep working): `validate` refuses a fraction, and the FMUs
    /// declare them integer-valued (`fmi2SetReal` refuses a fraction at once).
    pub const INTEGER_PARAMETERS: &'static [&'static str] = &["encoder_counts_per_revolution"];

    /// Value of a real-valued field by name (the names of [`Self::PARAMETER_LIMITS`]).
    pub fn real(&self, name: &str) -> Option<f64> {
        self.real_fields()
            .iter()
            .find(|(n, _)| *n == name)
            .map(|&(_, v)| v)
    }

    fn real_fields(&self) -> [(&'static str, f64); 57] {
        [
            ("actuation_inertia", self.actuation_inertia),
            ("load_inertia", self.load_inertia),
            ("actuation_damping", self.actuation_damping),
            ("load_damping", self.load_damping),
            ("spring_stiffness", self.spring_stiffness),
            ("direct_coupling_stiffness", self.direct_coupling_stiffness),
            ("harmonic_drive_ratio", self.harmonic_drive_ratio),
            ("reduction_ratio", self.reduction_ratio),
            ("actuation_static_friction", self.actuation_static_friction),
            ("load_static_friction", self.load_static_friction),
            ("actuation_stribeck_a0", self.actuation_stribeck_a0),
            ("actuation_stribeck_a1", self.actuation_stribeck_a1),
            ("actuation_stribeck_b1", self.actuation_stribeck_b1),
            ("actuation_stribeck_a2", self.actuation_stribeck_a2),
            ("actuation_stribeck_b2", self.actuation_stribeck_b2),
            ("load_stribeck_a0", self.load_stribeck_a0),
            ("load_stribeck_a1", self.load_stribeck_a1),
            ("load_stribeck_b1", self.load_stribeck_b1),
            ("load_stribeck_a2", self.load_stribeck_a2),
            ("load_stribeck_b2", self.load_stribeck_b2),
            ("hd_surface_max_speed", self.hd_surface_max_speed),
            (
                "hd_surface_min_load_torque",
                self.hd_surface_min_load_torque,
            ),
            (
                "hd_surface_max_load_torque",
                self.hd_surface_max_load_torque,
            ),
            ("test_motor_resistance", self.test_motor_resistance),
            ("test_motor_inductance", self.test_motor_inductance),
            (
                "test_motor_torque_constant",
                self.test_motor_torque_constant,
            ),
            (
                "test_motor_back_emf_constant",
                self.test_motor_back_emf_constant,
            ),
            ("test_motor_rotor_inertia", self.test_motor_rotor_inertia),
            ("load_motor_resistance", self.load_motor_resistance),
            ("load_motor_inductance", self.load_motor_inductance),
            (
                "load_motor_torque_constant",
                self.load_motor_torque_constant,
            ),
            (
                "load_motor_back_emf_constant",
                self.load_motor_back_emf_constant,
            ),
            ("load_motor_rotor_inertia", self.load_motor_rotor_inertia),
            ("test_supply_voltage", self.test_supply_voltage),
            ("load_supply_voltage", self.load_supply_voltage),
            ("test_current_limit", self.test_current_limit),
            ("load_current_limit", self.load_current_limit),
            (
                "current_loop_time_constant",
                self.current_loop_time_constant,
            ),
            ("load_regen_power_limit", self.load_regen_power_limit),
            ("clutch_motor_torque", self.clutch_motor_torque),
            ("clutch_power", self.clutch_power),
            ("hardware_offset_power", self.hardware_offset_power),
            (
                "encoder_counts_per_revolution",
                self.encoder_counts_per_revolution,
            ),
            ("transducer_offset", self.transducer_offset),
            ("transducer_gain", self.transducer_gain),
            ("transducer_phase", self.transducer_phase),
            ("load_cell_offset", self.load_cell_offset),
            ("load_cell_gain", self.load_cell_gain),
            ("load_cell_phase", self.load_cell_phase),
            (
                "calibration_pendulum_moment",
                self.calibration_pendulum_moment,
            ),
            ("divider_offset", self.divider_offset),
            ("divider_gain", self.divider_gain),
            ("current_sensor_offset", self.current_sensor_offset),
            (
                "current_sensor_sensitivity",
                self.current_sensor_sensitivity,
            ),
            ("spring_deflection_limit", self.spring_deflection_limit),
            ("motor_torque_limit", self.motor_torque_limit),
            ("max_internal_step", self.max_internal_step),
        ]
    }

    /// These parameters with the four enumeration parameters applied, given as the FMI Integer
    /// values the models hold (`configuration`, `frictionModel`, `testDriverMode`,
    /// `loadDriverMode`); the first one that is no item of its enumeration is named with its
    /// value, e.g. `configuration 7`.
    pub fn with_enumerations(
        &self,
        configuration: i32,
        friction_model: i32,
        test_driver_mode: i32,
        load_driver_mode: i32,
    ) -> Result<BenchParameters, String> {
        let mut p = self.clone();
        p.configuration = Configuration::from_i32(configuration)
            .ok_or_else(|| format!("configuration {configuration}"))?;
        p.friction_model = FrictionModel::from_i32(friction_model)
            .ok_or_else(|| format!("frictionModel {friction_model}"))?;
        p.test_driver_mode = DriverMode::from_i32(test_driver_mode)
            .ok_or_else(|| format!("testDriverMode {test_driver_mode}"))?;
        p.load_driver_mode = DriverMode::from_i32(load_driver_mode)
            .ok_or_else(|| format!("loadDriverMode {load_driver_mode}"))?;
        Ok(p)
    }

    /// Checks every value is finite and inside [`Self::PARAMETER_LIMITS`], and that the
    /// parameters are consistent (sensor gains of at least `MIN_SENSOR_GAIN`, 1e-6 V, whole
    /// numbers for [`Self::INTEGER_PARAMETERS`]).
    pub fn validate(&self) -> Result<(), ParameterError> {
        let fields = self.real_fields();
        debug_assert_eq!(fields.len(), Self::PARAMETER_LIMITS.len());
        for ((name, value), &(limit_name, min, max)) in fields.iter().zip(Self::PARAMETER_LIMITS) {
            debug_assert_eq!(*name, limit_name);
            if !value.is_finite() {
                return Err(ParameterError::NotFinite {
                    name,
                    value: *value,
                });
            }
            if *value < min || *value > max {
                return Err(ParameterError::OutOfRange {
                    name,
                    value: *value,
                    min,
                    max,
                });
            }
        }
        for (name, coefficients) in [
            ("hd_loss_positive_speed", &self.hd_loss_positive_speed),
            ("hd_loss_negative_speed", &self.hd_loss_negative_speed),
        ] {
            if let Some(&value) = coefficients.iter().find(|c| !c.is_finite()) {
                return Err(ParameterError::NotFinite { name, value });
            }
        }
        // The calibration gain b is the sensor's voltage swing over the calibration pendulum
        // (published: -8 mV and 1 mV); the myRIO resolves about 5 mV (12 bits over +-10 V), so
        // a gain under a microvolt could never have been calibrated. The bound also keeps the
        // conversion back to torque, (m g Lg / b)(V - a) with m g Lg <= 1e3 N m, finite: a
        // subnormal gain made it inf * 0 = NaN.
        if self.transducer_gain.abs() < MIN_SENSOR_GAIN
            || self.load_cell_gain.abs() < MIN_SENSOR_GAIN
        {
            return Err(ParameterError::Inconsistent(
                "sensor calibration gains must be at least 1e-6 V in magnitude",
            ));
        }
        for (name, value) in fields {
            if Self::INTEGER_PARAMETERS.contains(&name) && value.fract() != 0.0 {
                return Err(ParameterError::NotInteger { name, value });
            }
        }
        if self.hd_surface_min_load_torque >= self.hd_surface_max_load_torque {
            return Err(ParameterError::Inconsistent(
                "loss-surface load-torque range is empty",
            ));
        }
        Ok(())
    }

    /// The loss surface's coefficients for motion in `direction` (+1: `omega1 >= 0`, -1).
    pub fn hd_loss_coefficients(&self, direction: f64) -> &[f64; 21] {
        if direction >= 0.0 {
            &self.hd_loss_positive_speed
        } else {
            &self.hd_loss_negative_speed
        }
    }

    /// Coupling stiffness between the halves for the configured actuator [N m/rad].
    pub fn coupling_stiffness(&self) -> f64 {
        match self.configuration {
            Configuration::Da => self.direct_coupling_stiffness,
            Configuration::Sea | Configuration::Csea => self.spring_stiffness,
        }
    }

    /// Clutch holding torque at the output axis [N m] (motor-side torque x i_HD).
    pub fn clutch_output_torque(&self) -> f64 {
        self.clutch_motor_torque * self.harmonic_drive_ratio
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_validate_and_limits_cover_every_field() {
        let p = BenchParameters::default();
        assert_eq!(p.validate(), Ok(()));
        assert_eq!(
            p.real_fields().len(),
            BenchParameters::PARAMETER_LIMITS.len()
        );
        for (name, _, _) in BenchParameters::PARAMETER_LIMITS {
            assert!(p.real(name).is_some(), "{name}");
        }
        assert_eq!(p.clutch_output_torque(), 120.0);
    }

    #[test]
    fn invalid_values_are_rejected() {
        let mut p = BenchParameters {
            actuation_inertia: -1.0,
            ..BenchParameters::default()
        };
        assert!(matches!(
            p.validate(),
            Err(ParameterError::OutOfRange { .. })
        ));
        p.actuation_inertia = f64::NAN;
        assert!(matches!(
            p.validate(),
            Err(ParameterError::NotFinite { .. })
        ));
        let q = BenchParameters {
            encoder_counts_per_revolution: 2000.5,
            ..BenchParameters::default()
        };
        assert!(matches!(
            q.validate(),
            Err(ParameterError::NotInteger {
                name: "encoder_counts_per_revolution",
                ..
            })
        ));
        for gain in [0.0, -0.0, 5e-324, f64::MIN_POSITIVE, -9.9e-7] {
            for transducer in [false, true] {
                let mut g = BenchParameters::default();
                if transducer {
                    g.transducer_gain = gain;
                } else {
                    g.load_cell_gain = gain;
                }
                assert!(
                    matches!(g.validate(), Err(ParameterError::Inconsistent(_))),
                    "{gain:e}, transducer {transducer}"
                );
            }
        }
        let smallest = BenchParameters {
            transducer_gain: -MIN_SENSOR_GAIN,
            load_cell_gain: MIN_SENSOR_GAIN,
            ..BenchParameters::default()
        };
        assert_eq!(smallest.validate(), Ok(()));
        let mut r = BenchParameters::default();
        r.hd_loss_negative_speed[20] = f64::INFINITY;
        assert_eq!(
            r.validate(),
            Err(ParameterError::NotFinite {
                name: "hd_loss_negative_speed",
                value: f64::INFINITY
            })
        );
    }
}
