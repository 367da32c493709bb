//! The bench hardware FMU's variables: the plant's signal interface and shared parameters,
//! the hardware's own parameters (value references 400 and up), and its enumerations.

use crate::release::Lazy;

use super::{BenchHardwareModel, DEFAULT_REPLY_TIMEOUT};
use crate::hardware::calibration::Plausibility;
use crate::hardware::consistency::ConsistencyCheck;
use crate::hardware::protocol::AnalogChannel;
use crate::model::{EnumerationType, Start, Variable};
use crate::models::bench::BenchParameters;
use crate::models::bench_plant::{
    for_each_bench_parameter, io_variables, unit_of, with_limits, with_unit,
};

// SAFETY: a static (Lazy registers its address for the release at unload).
pub(super) static ENUMERATIONS: Lazy<Vec<EnumerationType>> = unsafe {
    Lazy::new(|| {
        let mut v = crate::models::bench_plant::ENUMERATIONS.to_vec();
        v.push(EnumerationType {
            name: "Backend",
            description: "Where the bench's I/O is",
            items: &[
                (
                    "Simulated",
                    0,
                    "The plant physics in process, through its raw sensors",
                ),
                (
                    "Udp",
                    1,
                    "A real-time I/O server (bench controller or `kneebench emulate`) over UDP",
                ),
            ],
        });
        v.push(EnumerationType {
            name: "Pacing",
            description: "How fmi2DoStep keeps time",
            items: &[
                ("None", 0, "As fast as possible (Simulated backend only)"),
                (
                    "Soft",
                    1,
                    "Real time; overruns are counted and logged as warnings",
                ),
                ("Hard", 2, "Real time; an overrun trips the bench"),
            ],
        });
        v
    })
};

/// The plant parameters the hardware FMU declares too (see `for_each_bench_parameter`).
const SHARED_PARAMETERS: &[&str] = &[
    "actuationInertia",
    "loadInertia",
    "actuationDamping",
    "loadDamping",
    "springStiffness",
    "directCouplingStiffness",
    "harmonicDriveRatio",
    "reductionRatio",
    "testMotorResistance",
    "testMotorTorqueConstant",
    "testMotorBackEmfConstant",
    "loadMotorResistance",
    "loadMotorTorqueConstant",
    "loadMotorBackEmfConstant",
    "testSupplyVoltage",
    "loadSupplyVoltage",
    "testCurrentLimit",
    "loadCurrentLimit",
    "loadRegenPowerLimit",
    "clutchRatedPower",
    "hardwareOffsetPower",
    "encoderCountsPerRevolution",
    "transducerOffset",
    "transducerGain",
    "transducerPhase",
    "loadCellOffset",
    "loadCellGain",
    "loadCellPhase",
    "calibrationPendulumMoment",
    "dividerOffset",
    "dividerGain",
    "currentSensorOffset",
    "currentSensorSensitivity",
    "springDeflectionLimit",
    "motorTorqueLimit",
];

// SAFETY: a static (Lazy registers its address for the release at unload).
pub(super) static VARIABLES: Lazy<Vec<Variable<BenchHardwareModel>>> = unsafe {
    Lazy::new(|| {
        type V = Variable<BenchHardwareModel>;
        let d = BenchParameters::default();
        macro_rules! window {
            ($name:literal, $vr:expr, $ch:expr, $end:tt, $desc:literal) => {
                V::real(
                    $name,
                    $vr,
                    |m| m.plausibility.analog[$ch as usize].$end,
                    |m, v| m.plausibility.analog[$ch as usize].$end = v,
                )
                .parameter(Start::Real(Plausibility::DEFAULT.analog[$ch as usize].$end))
                .unit("V")
                .range(-10.0, 10.0)
                .describe($desc)
            };
        }
        macro_rules! local {
            (real $name:literal, $vr:expr, $field:ident, $unit:literal, $desc:literal) => {
                V::real($name, $vr, |m| m.$field, |m, v| m.$field = v)
                    .discrete()
                    .unit($unit)
                    .describe($desc)
            };
            (int $name:literal, $vr:expr, $field:ident, $desc:literal) => {
                V::integer($name, $vr, |m| m.$field, |m, v| m.$field = v)
                    .discrete()
                    .describe($desc)
            };
        }
        use AnalogChannel as A;
        let mut v = vec![
        V::enumeration(
            "configuration",
            1,
            "Configuration",
            |m| m.configuration,
            |m, v| m.configuration = v,
        )
        .parameter(Start::Integer(d.configuration.as_i32()))
        .describe("Actuator configuration the bench is set up in (spring stiffness used; simulated backend)"),
        V::enumeration(
            "frictionModel",
            2,
            "FrictionModel",
            |m| m.friction_model,
            |m, v| m.friction_model = v,
        )
        .parameter(Start::Integer(d.friction_model.as_i32()))
        .describe("Friction law of the simulated backend"),
        V::enumeration(
            "testDriverMode",
            3,
            "DriverMode",
            |m| m.test_driver_mode,
            |m, v| m.test_driver_mode = v,
        )
        .parameter(Start::Integer(d.test_driver_mode.as_i32()))
        .describe("Test driver's configured mode: which command input is sent (the server refuses a mismatch)"),
        V::enumeration(
            "loadDriverMode",
            4,
            "DriverMode",
            |m| m.load_driver_mode,
            |m, v| m.load_driver_mode = v,
        )
        .parameter(Start::Integer(d.load_driver_mode.as_i32()))
        .describe("Load driver's configured mode"),
        V::enumeration("backend", 400, "Backend", |m| m.backend, |m, v| m.backend = v)
            .parameter(Start::Integer(0))
            .describe("I/O backend: Simulated (in process) or Udp (bench I/O server)"),
        V::string(
            "serverAddress",
            401,
            |m| &m.server_address,
            |m, v| m.server_address = v.to_owned(),
        )
        .parameter(Start::String("127.0.0.1:47000"))
        .describe("host:port of the bench I/O server (Udp backend)"),
        V::enumeration("pacing", 402, "Pacing", |m| m.pacing, |m, v| m.pacing = v)
            .parameter(Start::Integer(0))
            .describe("Pacing: None, Soft or Hard real time"),
        V::integer(
            "tareSamples",
            403,
            |m| m.tare_samples,
            |m, v| m.tare_samples = v,
        )
        .parameter(Start::Integer(50))
        .range(0.0, 100_000.0)
        .describe("Samples averaged at initialization for the zero of the torque channels (0: published offsets)"),
        V::real("replyTimeout", 404, |m| m.reply_timeout, |m, v| m.reply_timeout = v)
            .parameter(Start::Real(DEFAULT_REPLY_TIMEOUT))
            .unit("s")
            .range(1e-5, 1.0)
            .describe("Link watchdog: longest wait for a sample after the deadline (default 0.8 ms: 0.8 of the default 1 ms period; keep below the control period, see the documentation)"),
        V::real(
            "safeStateTimeout",
            405,
            |m| m.safe_state_timeout,
            |m, v| m.safe_state_timeout = v,
        )
        .parameter(Start::Real(0.05))
        .unit("s")
        .range(1e-4, 10.0)
        .describe("Longest wait for the safe state's acknowledgement (the request is repeated every replyTimeout)"),
        V::real("spinMargin", 406, |m| m.spin_margin, |m, v| m.spin_margin = v)
            .parameter(Start::Real(5e-5))
            .unit("s")
            .range(0.0, 0.01)
            .describe("Pacing spins (instead of sleeping) this long before each deadline"),
        V::integer(
            "realtimePriority",
            408,
            |m| m.realtime_priority,
            |m, v| m.realtime_priority = v,
        )
        .parameter(Start::Integer(0))
        .range(0.0, 99.0)
        .describe("Pacing Soft/Hard: SCHED_FIFO priority (1-99) of the thread calling fmi2DoStep, from the first step to the end of the instance or a trip; 0 leaves the scheduling alone. Refused (no CAP_SYS_NICE or RLIMIT_RTPRIO): a warning, the run goes on"),
        V::boolean(
            "lockMemory",
            409,
            |m| m.lock_memory,
            |m, v| m.lock_memory = v,
        )
        .parameter(Start::Boolean(false))
        .describe("Pacing Soft/Hard: lock the importer process's pages in memory (mlockall, process-wide, not undone) at initialization. Refused: a warning"),
        V::string(
            "keyFile",
            425,
            |m| &m.key_file,
            |m, v| m.key_file = v.to_owned(),
        )
        .parameter(Start::String(""))
        .describe("Udp backend: the bench's key file (`kneebench key new FILE`; readable by its owner only). Empty: the public loopback key, allowed only for a server on this machine"),
        V::boolean(
            "acknowledgeSafeState",
            426,
            |m| m.acknowledge_safe_state,
            |m, v| m.acknowledge_safe_state = v,
        )
        .parameter(Start::Boolean(false))
        .describe("Udp backend: at initialization, clear a safe state the bench latched in an earlier session (a trip, its watchdog, the button) by an explicit acknowledgement. Set it only after checking the bench; false: such a latch fails the initialization"),
        V::real(
            "maxEncoderSpeed",
            407,
            |m| m.plausibility.max_speed,
            |m, v| m.plausibility.max_speed = v,
        )
        .parameter(Start::Real(Plausibility::DEFAULT.max_speed))
        .unit("rad/s")
        .range(0.0, 1e4)
        .describe("Plausibility: fastest output-axis speed; a larger encoder jump is a sensor fault"),
        V::real(
            "consistencyTolerance",
            422,
            |m| m.consistency_tolerance,
            |m, v| m.consistency_tolerance = v,
        )
        .parameter(Start::Real(ConsistencyCheck::DEFAULT_TOLERANCE))
        .unit("N.m")
        .range(0.0, 100.0)
        .describe("Sensor consistency: absolute allowance between the transducer and k x encoder deflection (SEA, CSEA), and between the load cell and i_HD Km1 x test current"),
        V::real(
            "consistencyRelativeTolerance",
            423,
            |m| m.consistency_relative,
            |m, v| m.consistency_relative = v,
        )
        .parameter(Start::Real(ConsistencyCheck::DEFAULT_RELATIVE))
        .range(0.0, 10.0)
        .describe("Sensor consistency: allowance per N m of the larger of the two torques compared"),
        V::integer(
            "consistencyPersistence",
            424,
            |m| m.consistency_persistence,
            |m, v| m.consistency_persistence = v,
        )
        .parameter(Start::Integer(ConsistencyCheck::DEFAULT_PERSISTENCE as i32))
        .range(0.0, 100_000.0)
        .describe("Sensor consistency: consecutive disagreeing samples that trip (code 12 transducer, 13 load cell); 0 turns the checks off"),
        window!("loadCellVoltageMin", 410, A::LoadCell, 0, "Plausibility window of the load cell, low end"),
        window!("loadCellVoltageMax", 411, A::LoadCell, 1, "Load cell, high end"),
        window!("transducerVoltageMin", 412, A::Transducer, 0, "Torque transducer, low end"),
        window!("transducerVoltageMax", 413, A::Transducer, 1, "Torque transducer, high end"),
        window!("testCurrentSenseVoltageMin", 414, A::TestCurrentSense, 0, "Test current sensor, low end"),
        window!("testCurrentSenseVoltageMax", 415, A::TestCurrentSense, 1, "Test current sensor, high end"),
        window!("loadCurrentSenseVoltageMin", 416, A::LoadCurrentSense, 0, "Load current sensor, low end"),
        window!("loadCurrentSenseVoltageMax", 417, A::LoadCurrentSense, 1, "Load current sensor, high end"),
        window!("testSupplySenseVoltageMin", 418, A::TestSupplySense, 0, "Test supply divider, low end (18 V supply)"),
        window!("testSupplySenseVoltageMax", 419, A::TestSupplySense, 1, "Test supply divider, high end (30 V)"),
        window!("loadSupplySenseVoltageMin", 420, A::LoadSupplySense, 0, "Load supply divider, low end (40 V)"),
        window!("loadSupplySenseVoltageMax", 421, A::LoadSupplySense, 1, "Load supply divider, high end (56 V)"),
        local!(int "overrunCount", 450, overrun_count, "Pacing overruns so far"),
        local!(real "lastLateness", 451, last_lateness, "s", "Lateness of the last step's deadline"),
        local!(real "maxLateness", 452, max_lateness, "s", "Largest lateness so far"),
        local!(int "rejectedFrames", 453, rejected_frames, "Frames from the server rejected (unauthenticated, malformed, replayed, out of order, wrong version or session)"),
        local!(int "staleReplies", 454, stale_replies, "Replies that came too late for their request and were ignored"),
        local!(real "lastReplyTime", 455, last_reply_time, "s", "How long the last step's sample took to arrive after its request"),
        local!(real "maxReplyTime", 456, max_reply_time, "s", "Longest reply time so far"),
        local!(real "benchSampleTime", 457, bench_sample_time, "s", "The bench's clock when it took the last sample, since the session began (Udp: the server's, to the microsecond; Simulated: the simulated bench's time): when the loop ran late, the true time of the row's readings, which identification resamples on"),
    ];
        // The plant's parameters that the measurements need (calibration, conversions, limits),
        // from the plant's own list: same name, value reference, unit, range and meaning; fixed
        // here, as the bench is set up once per run.
        macro_rules! param {
            ($name:literal, $vr:expr, $field:ident, $unit:tt, $desc:literal) => {
                if SHARED_PARAMETERS.contains(&$name) {
                    let var = V::real($name, $vr, |m| m.params.$field, |m, x| m.params.$field = x)
                        .parameter(Start::Real(d.$field))
                        .describe($desc);
                    v.push(with_unit(
                        with_limits(var, stringify!($field)),
                        unit_of!($unit),
                    ));
                }
            };
        }
        for_each_bench_parameter!(param);
        v.extend(io_variables::<BenchHardwareModel>());
        v
    })
};
