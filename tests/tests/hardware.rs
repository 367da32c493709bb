//! The hardware path end to end: `BenchHardware` over UDP against the emulator (`kneebench
//! emulate`'s library) on loopback, in soft real time.
//!
//! * The same SEA system with `BenchPlant` and with `BenchHardware`: the trajectories agree
//!   within a tolerance derived from the encoder quantisation and the timing offsets of a
//!   networked loop (see [`tolerance`]).
//! * Interlocks and injected faults: the trip is found in the first sample that shows the
//!   cause, the safe state is commanded and acknowledged (or, with the link lost, not), no
//!   drive command follows it, the run ends with the documented status and keeps every row.
//!
//! Every real-time run is short (at most 1.2 s): the whole file takes a few seconds.

use std::time::Duration;

use kneebench_harness::bench_protocol::{FaultInjection, reason};
use kneebench_harness::emulator::{EmulatorConfig, EmulatorHandle, EmulatorStats, spawn};
use kneebench_harness::master::Signal;
use kneebench_harness::{
    Fmu, InstanceOptions, LoadOptions, Outcome, Results, RunConfig, RunOutput, Status, System,
};
use kneebench_tests::loop_memory::{beyond_mean, carried, mean_stall, row_stalls, sea_loop_decays};
use kneebench_tests::*;

const H: f64 = 1e-3;

/// The emulator's allowance `d` in the trajectory tolerance: how late its replies may be on an
/// undisturbed host, which the test cannot measure (seconds).
const EMULATOR_ALLOWANCE: f64 = 3e-4;

fn key_path() -> String {
    bench_key_file().1.to_str().unwrap().to_owned()
}

fn emulator(params: &[(&str, &str)]) -> EmulatorHandle {
    let mut config = EmulatorConfig::new("127.0.0.1:0", exported_fmu("BenchPlant"));
    config.key = Some(bench_key_file().2.clone());
    config.parameters = params
        .iter()
        .map(|(n, v)| (n.to_string(), v.to_string()))
        .collect();
    // Real-time scheduling where permitted, as a bench's controller has (else a warning).
    config.realtime_priority = Some(50);
    spawn(config).expect("emulator")
}

/// Open-loop current commands: test motor `a1 sin(2 pi 0.4 t)`, load motor
/// `a2 sin(2 pi 0.8 t)`.
fn signal(amplitude: f64, frequency: f64, stop: f64) -> Signal {
    let n = (stop / H).round() as usize;
    let times: Vec<f64> = (0..=n).map(|k| k as f64 * H).collect();
    let values = times
        .iter()
        .map(|t| amplitude * (std::f64::consts::TAU * frequency * t).sin())
        .collect();
    Signal {
        times,
        values,
        interpolate: false,
    }
}

const RECORDED: [&str; 9] = [
    "actuationAngle",
    "loadAngle",
    "springDeflection",
    "testMotorCurrent",
    "loadMotorCurrent",
    "transducerTorque",
    "testOutputTorque",
    "actuationVelocity",
    "tripCode",
];

/// Runs one bench component `b` (plant or hardware) with the given inputs and parameters.
fn run_bench(
    id: &str,
    params: &[(&str, String)],
    inputs: Vec<(&str, Signal)>,
    stop: f64,
) -> (RunOutput, Option<(i32, f64)>) {
    let fmu = Fmu::load(exported_fmu(id), &LoadOptions::default()).unwrap();
    let mut system = System::new();
    system.add_component("b", fmu).unwrap();
    for (name, value) in params {
        system.set_value_str(&format!("b.{name}"), value).unwrap();
    }
    for (name, s) in inputs {
        system.add_signal(&format!("b.{name}"), s).unwrap();
    }
    let mut rec: Vec<String> = RECORDED.iter().map(|n| format!("b.{n}")).collect();
    if id == "BenchHardware" {
        rec.push("b.maxLateness".into());
        rec.push("b.overrunCount".into());
    }
    let refs: Vec<&str> = rec.iter().map(String::as_str).collect();
    system.record(&refs).unwrap();
    let config = RunConfig {
        stop_time: stop,
        step_size: H,
        ..RunConfig::default()
    };
    let out = system.run(&config).unwrap();
    let extra = col(&out.results, "maxLateness")
        .zip(col(&out.results, "overrunCount"))
        .map(|(l, o)| {
            (
                *o.last().unwrap() as i32,
                l.iter().cloned().fold(0.0, f64::max),
            )
        });
    (out, extra)
}

fn col(r: &Results, name: &str) -> Option<Vec<f64>> {
    r.column(&format!("b.{name}")).or_else(|| r.column(name))
}

fn hardware_params(addr: std::net::SocketAddr) -> Vec<(&'static str, String)> {
    vec![
        ("backend", "1".into()),
        ("pacing", "1".into()),
        ("serverAddress", addr.to_string()),
        ("keyFile", key_path()),
        // Generous for a loaded test machine, as in `drive`: the default 0.8 ms is enforced to
        // the microsecond now, and one slow loopback reply would trip the link watchdog; the
        // deadline itself is tested in bench_link.rs.
        ("replyTimeout", "0.01".into()),
        // The stepping thread in SCHED_FIFO where permitted (else a warning, and the run goes
        // on): a loaded test machine then holds the loop up far less (bench_hardware docs).
        ("realtimePriority", "50".into()),
    ]
}

/// The tolerance of a signal `x` between the plant run and the hardware run:
/// `2 q + max|dx/dt| * 2 (e + d)`, with `q` the quantum of `x` (one encoder count for angles,
/// as both runs floor the same angle but may sit on either side of a count edge), `e` the
/// largest lateness of the hardware run's deadlines (measured by the FMU) and `d` = 0.3 ms the
/// allowance for the loopback round trip and the emulator's processing. Why: the emulator
/// integrates the plant over the wall-time intervals between frames, so each command acts from
/// (its nominal time + the offset with which it arrived) and each sample is taken at (its
/// nominal time + its own offset); a trajectory whose inputs and sampling are shifted by at
/// most `e + d` differs by at most its rate times twice that shift (one for the input, one for
/// the sample).
fn tolerance(x: &[f64], quantum: f64, offset: f64) -> f64 {
    let rate = x
        .windows(2)
        .map(|w| ((w[1] - w[0]) / H).abs())
        .fold(0.0, f64::max);
    2.0 * quantum + rate * 2.0 * offset
}

#[test]
fn sea_run_with_plant_and_hardware_agree_within_the_derived_tolerance() {
    let _real_time = one_real_time_test_at_a_time();
    let stop = 1.2;
    let inputs = || {
        vec![
            ("testCurrentCommand", signal(2.0, 0.4, stop)),
            ("loadCurrentCommand", signal(-0.5, 0.8, stop)),
        ]
    };
    let (plant, _) = run_bench(
        "BenchPlant",
        &[("configuration", "1".into())],
        inputs(),
        stop,
    );
    assert!(
        matches!(plant.outcome, Outcome::Completed { .. }),
        "{:?}",
        plant.outcome
    );
    let res1 = std::f64::consts::TAU / (2000.0 * 160.0);
    let res2 = std::f64::consts::TAU / (2000.0 * 66.0);
    // The calibrated transducer of the plant carries the untared bias m g Lg sin(c).
    let bias = 1.94 * 9.81 * 0.25 * (-0.01f64).sin();
    // Every hardware run must agree with the plant run within the tolerance its own measured
    // lateness gives (a run the host held up by more than the emulator's allowance is run
    // again instead, below).
    // The comparison means something only if each signal moves by more than 5 of those
    // tolerances: a run the host stalled badly (seen once under a load average of 10: 269
    // overruns, 12 ms of lateness) widens the tolerance past that, so it is run again on a
    // fresh emulator, at most three attempts; a run that stays that disturbed fails the test.
    let mut attempt = 0;
    let (emu, hw) = loop {
        attempt += 1;
        let emu = emulator(&[("configuration", "1")]);
        let mut params = hardware_params(emu.addr());
        params.push(("configuration", "1".into()));
        // The reply timeout is kept to the microsecond (not rounded up to the kernel's tick):
        // on a loaded test machine in normal scheduling, replies of a few milliseconds happen.
        // This test compares trajectories (its tolerance uses the measured lateness); the
        // watchdog is tested in bench_link.rs.
        params.push(("replyTimeout", "0.02".into()));
        let (hw, stats) = run_bench("BenchHardware", &params, inputs(), stop);
        assert!(
            matches!(hw.outcome, Outcome::Completed { .. }),
            "{:?}",
            hw.outcome
        );
        let (overruns, max_lateness) = stats.unwrap();
        let offset = max_lateness + EMULATOR_ALLOWANCE;
        eprintln!(
            "hardware run, attempt {attempt}: {overruns} overruns, max lateness {:.0} us",
            max_lateness * 1e6
        );
        assert_eq!(plant.results.len(), hw.results.len());
        let mut too_coarse = Vec::new();
        let mut outside = Vec::new();
        for (name, quantum, shift) in [
            ("actuationAngle", res1, 0.0),
            ("loadAngle", res2, 0.0),
            ("springDeflection", res1 + res2, 0.0),
            ("testMotorCurrent", 1e-9, 0.0),
            ("loadMotorCurrent", 1e-9, 0.0),
            (
                "transducerTorque",
                kneebench_harness::study::SPRING_STIFFNESS * (res1 + res2),
                bias,
            ),
        ] {
            let a = col(&plant.results, name).unwrap();
            let b = col(&hw.results, name).unwrap();
            let tol = tolerance(&a, quantum, offset);
            let worst = a
                .iter()
                .zip(&b)
                .map(|(x, y)| (x - shift - y).abs())
                .fold(0.0, f64::max);
            let range = a.iter().cloned().fold(0.0, |m: f64, x| m.max(x.abs()));
            eprintln!(
                "{name}: worst difference {worst:.3e}, tolerance {tol:.3e}, range {range:.3e}"
            );
            if worst > tol {
                outside.push(format!("{name}: {worst} > {tol}"));
            }
            if range <= 5.0 * tol {
                too_coarse.push(format!("{name}: range {range} vs tolerance {tol}"));
            }
        }
        // The allowance `d` holds for the emulator on an undisturbed host, but the emulator's
        // own delays are not measured: its thread can be held up while the master's deadlines
        // are kept (a CI rehearsal: 139 us of the master's lateness, the currents 5 % past
        // their tolerance). A run outside the tolerance is therefore run again on a fresh
        // emulator, at most three attempts, and the test fails when every attempt is outside:
        // a disagreement of the models repeats in each, a held-up host does not. (With 1 ms
        // as the threshold, a run held up by 0.9 ms failed under a load of 4 busy loops on 2
        // cores.)
        if !outside.is_empty() {
            assert!(
                attempt < 3,
                "three hardware runs outside the tolerance; the last (max lateness {:.0} us): {outside:?}",
                max_lateness * 1e6
            );
            eprintln!(
                "attempt {attempt} outside the tolerance (max lateness {:.0} us): {outside:?}; run again",
                max_lateness * 1e6
            );
            emu.stop().unwrap();
            continue;
        }
        if too_coarse.is_empty() {
            break (emu, hw);
        }
        assert!(
            attempt < 3,
            "three hardware runs too disturbed by the host for the comparison to mean anything (the last: {overruns} overruns, max lateness {:.0} us): {too_coarse:?}",
            max_lateness * 1e6
        );
        emu.stop().unwrap();
    };
    let s = emu.stop().unwrap();
    assert_eq!(s.sessions, 1);
    assert_eq!(s.rejected.rejected(), 0);
    assert!(s.commands_applied as usize >= hw.results.len() - 1);
}

/// The study's SEA closed loop (`study::gait_scenario`: gait reference, position PID on the
/// actuation encoder, shaft-torque PID on the transducer, feed-forwards) run twice as an SSP
/// system: once as written, once with the plant component's FMU replaced by `BenchHardware`
/// (`ssp::load_system_replacing`, what `kneebench run --replace plant=BenchHardware.fmu` does;
/// backend Udp and pacing Soft set by item name) pointed at the emulator on loopback,
/// everything else unchanged. The plant's parameters go to the emulator's plant, and stay
/// bound to the hardware component, which declares them all; `tareSamples` = 0 makes the hardware read the torque channels with the
/// published calibration offsets, exactly as the plant's outputs do (the tare is tested
/// elsewhere). The first 1.75 s in real time: the soft start (half a gait period) and the
/// beginning of the swing, where the knee moves fast (up to 2.2 rad/s). The window reaches into
/// the swing so that one period of extra delay (`R h`) stands clear of the sustained tolerance:
/// over the soft start alone (R = 0.81 rad/s) a mean I/O shift of 190 us, what protocol 2's
/// authenticated round trips measure here, already made them equal.
///
/// **Tolerance.** What differs between the two runs, for a recorded signal `x`:
/// * the encoders: both runs floor the same kind of angle, but states that differ slightly
///   may sit on either side of a count edge, and the controllers act on the count they see:
///   `2 q`, `q` one count of `x` (angles), the sum of both sides' counts (deflection) or `k`
///   times that (shaft torque);
/// * the I/O timing. On hardware each command reaches the emulator after its nominal time by
///   the wake-up lateness of the previous deadline, the reply time of the previous sample and
///   the master's work, and each sample is taken after its nominal time by the wake-up
///   lateness and the one-way latency (within the reply time). Over the run this acts as an
///   extra loop delay of about `delta = mean(lastLateness + lastReplyTime) + d`, with the
///   FMU's own per-step measurements and `d` = 50 us for the master's and controllers' work;
///   a trajectory whose input and sampling are shifted by `delta` moves by at most
///   `2 delta max|dx/dt|`. A single stall (a late wake-up or reply of `s_j` at row `j`, from
///   the same measurements) displaces that row's sample beyond that shift by up to
///   `max|dx/dt| (s_j - s_mean)` (the run's mean stall is in `delta`), and holding the
///   previous command for `s_j` displaces the trajectory by up to `max|d2x/dt2| s_j^2 / 2`:
///   `D_j = R max(s_j - s_mean, 0) + A s_j^2 / 2`. The controllers act on the displaced
///   sample and trajectory, so the loop carries the displacement on, fading as its slowest
///   mode does (its **memory**, the decay rate `lambda` from `loop_memory::slowest_decay`: 60.6/s for the
///   actuation angle, through the position loop; 10.6/s for the load angle, the deflection
///   and the torque, through the torque loop, whose modes move the load side). Row `k`
///   therefore allows for `D'_k = max D_j exp(-lambda (k - j) h)` over `j <= k`. The largest,
///   not the sum: the lateness is measured against the fixed schedule, so a run of late rows
///   is one lag that each of its rows' stalls holds whole, not stalls that add up. With each
///   row's own stall alone (and `A s^2 / 2` for the run's largest stall on every row) the bound
///   failed in CI (stop 43: 0.0038 > 0.0032 rad after a 4.6 ms stall) and here in 2 of 3 runs
///   on a loaded host: a run of 25 late rows (1 to 3 ms) left it by up to 30 % in the 10 rows
///   after the last late one;
/// * the emulator's discretisation: it integrates the plant exactly (matrix exponential for a
///   held input) over the wall-time intervals between frames, so it adds nothing beyond the
///   timing above;
/// * the feedback acts on these differences: closing the loop multiplies a disturbance by at
///   most the peak sensitivity `Ms`, taken as 2 (gain margin 2 or more; the study's loops are
///   well damped).
///
/// So row `k` must agree within `Ms (2 q + 2 delta R + D'_k)`, `R` and `A` the
/// largest rate and acceleration of `x` in the plant run (the acceleration from a 10-period
/// stencil, past the encoders' quantisation). For the spring deflection and the shaft torque,
/// two more things: the plant records the true deflection and the hardware the difference of
/// its encoder angles (one count of each side more, outside the loop), and a time shift of
/// either angle disturbs the deflection by that angle's rate until the torque loop rejects it;
/// in the swing the angles move ten times faster than the deflection, so their `R` and `A` are
/// the larger of their own and the angles' (times the stiffness for the torque). With the
/// deflection's own rate alone the bound failed in 1 of about 10 runs, in the swing.
///
/// The test also checks that the comparison can fail: on a host that keeps its deadlines (a
/// mean shift `delta` of 100 us) the sustained part `Ms (2 q + 2 delta R)` is finer than `R h`,
/// what one extra period of delay in the hardware path would make (for the two angles), and
/// every signal moves by more than 5 times its sustained tolerance. A stall widens the rows it
/// is carried into: the kept run prints on what share of the swing's rows (where an angle
/// moves at half its largest rate or more) one period of delay, the angle's rate there times
/// `h`, still exceeds the row's tolerance, for the weaker of the two angles, and the same share
/// as if each stall counted on its own row only, so that the power the memory costs is seen.
///
/// **Disturbed runs.** A busy host widens the tolerance with its mean shift: 240 us already
/// hides one period (seen on CI, and on this machine idle, where a SCHED_FIFO thread's 1 ms
/// sleep overshoots by 80 us median, 1.5 ms at p99 and 13 ms at worst). A host stall of several
/// periods can make the emulated bench stop itself (its protection or its heartbeat watchdog).
/// So the hardware run is tried up to five times on a fresh emulator: a run that ended early
/// having measured its own disturbance (a stall above 5 ms, the watchdog's reason, or a safety
/// interlock's trip after a stall above two periods, the run's largest lateness read from the
/// trip's log, or a trip while the loops still carried half a period of lag or more from the
/// host's stalls at the last recorded row, each beyond the run's mean stall, at the torque
/// loop's decay: seen once, the master up
/// to 0.95 ms behind over 8 rows just before a regenerated-power trip, where the plant run
/// peaks at a quarter of the limit) is run again, one that ended early without it fails the
/// test; a completed run is kept (the least shifted one) and the attempts stop at the first
/// that sees one period of delay. The kept run is always asserted on, with the number of
/// periods its tolerance sees printed. A completed run with a stall above 5 ms is disturbed
/// too: the single-stall terms bound a stall of a few periods (one run left them by 2 % after
/// an 8.9 ms stall); so is one on which one period of delay would show on less than a quarter
/// of the swing. Only when every attempt measured a host that cannot hold a 1 kHz loop
/// (each disturbed, or a mean shift of 2 ms or more) is nothing compared, and the test says
/// so.
#[test]
fn study_sea_closed_loop_with_plant_and_hardware_agree_within_the_derived_tolerance() {
    let _real_time = one_real_time_test_at_a_time();
    use kneebench_harness::Value;
    use kneebench_harness::ssp::{load_system, load_system_replacing};
    use kneebench_harness::study::{
        Actuator, Gait, SPRING_STIFFNESS, StudyGains, gait_scenario, write_ssp,
    };
    let stop = 1.75;
    let mut scenario = gait_scenario(
        Actuator::Sea,
        Gait::bench_full(),
        StudyGains::for_actuator(Actuator::Sea),
        1,
    );
    scenario.stop_time = stop;
    let fmu_dir = exported_fmus().0.path();
    let name = scenario
        .components
        .iter()
        .find(|c| c.fmu == "BenchPlant.fmu")
        .expect("the scenario has a BenchPlant component")
        .name
        .clone();
    let text = |v: &Value| match v {
        Value::Real(x) => format!("{x:?}"),
        Value::Integer(x) => x.to_string(),
        Value::Boolean(x) => x.to_string(),
        Value::String(x) => x.clone(),
    };
    // The emulated bench runs the plant with the scenario's plant parameters.
    let plant_params: Vec<(String, String)> = scenario
        .components
        .iter()
        .find(|c| c.name == name)
        .unwrap()
        .parameters
        .iter()
        .map(|(n, v)| (n.clone(), text(v)))
        .collect();
    let compared = [
        "actuationEncoderAngle",
        "loadEncoderAngle",
        "springDeflection",
        "transducerTorque",
    ];
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("SEA.ssp");
    write_ssp(&scenario, fmu_dir, &path).unwrap();
    // One SSP, run as written and, as `kneebench run SEA.ssp --replace plant=BenchHardware.fmu
    // --param plant.backend=Udp ...` does, with the plant's FMU replaced by the hardware's.
    let run = |replace: Option<&[(&str, String)]>, extra: &[&str]| {
        let mut loaded = match replace {
            None => load_system(&path, &LoadOptions::default()).unwrap(),
            Some(parameters) => {
                let mut loaded = load_system_replacing(
                    &path,
                    &LoadOptions::default(),
                    &[(name.clone(), exported_fmu("BenchHardware"))],
                )
                .unwrap();
                for (n, v) in parameters {
                    loaded
                        .system
                        .set_value_str(&format!("{name}.{n}"), v)
                        .unwrap();
                }
                loaded
            }
        };
        let refs: Vec<String> = compared
            .iter()
            .chain(extra)
            .map(|v| format!("{name}.{v}"))
            .collect();
        let refs: Vec<&str> = refs.iter().map(String::as_str).collect();
        loaded.system.record(&refs).unwrap();
        loaded.system.run(&loaded.config).unwrap()
    };
    let plant = run(None, &[]);
    assert!(
        matches!(plant.outcome, Outcome::Completed { .. }),
        "{:?}",
        plant.outcome
    );
    let plant = plant.results;
    // Per-row stall of a hardware run: wake-up lateness plus reply time (row 0 is the initial
    // sample).
    let stalls = |hw: &Results| row_stalls(hw, &name).expect("the hardware run records its timing");
    let ms = 2.0;
    let res1 = std::f64::consts::TAU / (2000.0 * 160.0);
    let res2 = std::f64::consts::TAU / (2000.0 * 66.0);
    // The largest rate and acceleration of a signal in the plant run (the acceleration from a
    // 10-period stencil, past the encoders' quantisation).
    let rate_and_acceleration = |a: &[f64]| {
        let rate = a
            .windows(2)
            .map(|w| ((w[1] - w[0]) / H).abs())
            .fold(0.0, f64::max);
        let m = 10;
        let accel = a
            .windows(2 * m + 1)
            .map(|w| ((w[2 * m] - 2.0 * w[m] + w[0]) / (m as f64 * H).powi(2)).abs())
            .fold(0.0, f64::max);
        (rate, accel)
    };
    let column = |signal: &str| plant.column(&format!("{name}.{signal}")).unwrap();
    let (rate1, accel1) = rate_and_acceleration(&column("actuationEncoderAngle"));
    let (rate2, accel2) = rate_and_acceleration(&column("loadEncoderAngle"));
    // The mean stall `s_mean` of a hardware run's rows after the initial one, and its mean
    // shift `delta` (that plus the master's work).
    let mean_shift = |stall: &[f64]| mean_stall(stall) + 50e-6;
    // The sustained tolerance of a signal of count `quantum` moving at `rate`, and the smallest
    // whole number of periods of extra delay in the hardware path that it would not hide
    // (`n R h > sustained`) for the slower-reaching of the two angles.
    let sustained_of = |recorded: f64, quantum: f64, rate: f64, delta: f64| {
        recorded + ms * (2.0 * quantum + 2.0 * delta * rate)
    };
    let periods_seen = |delta: f64| {
        [(res1, rate1), (res2, rate2)]
            .iter()
            .map(|&(q, r)| (sustained_of(0.0, q, r, delta) / (r * H)).floor() as u32 + 1)
            .max()
            .unwrap()
    };
    // The mean shift of a host that keeps its deadlines: 50 us of I/O on loopback and the
    // master's work. The comparison itself sees one period of delay there, whatever this host
    // does.
    let quiet_shift = 100e-6;
    assert_eq!(
        periods_seen(quiet_shift),
        1,
        "the tolerance hides one period of delay"
    );
    // How long the loops carry a stall's displacement (the doc comment's "memory"): the
    // actuation angle through the position loop; the load angle, the deflection and the torque
    // through the slower of it and the torque loop, whose modes move the load side.
    let (position_decay, torque_decay) = sea_loop_decays();
    let torque_decay = torque_decay.min(position_decay);
    // Row by row, the larger of the row's own value (a stall, or the displacement it makes) and
    // the carried one decayed by a period.
    let carried = |values: &[f64], decay: f64| carried(values, decay, H);
    // The tolerance of each row of a signal (the doc comment's bound): each stall's
    // displacement (its sample's beyond the mean stall, which the sustained part covers, and
    // its held command's) is carried on.
    let row_tolerances =
        |sustained: f64, rate: f64, accel: f64, stall: &[f64], decay: f64| -> Vec<f64> {
            let displaced: Vec<f64> = beyond_mean(stall)
                .iter()
                .zip(stall)
                .map(|(beyond, s)| rate * beyond + 0.5 * accel * s * s)
                .collect();
            carried(&displaced, decay)
                .iter()
                .map(|d| sustained + ms * d)
                .collect()
        };
    // The share of the swing's rows (where an angle moves at half its largest rate or more, its
    // rate from a 10-period stencil of the plant run) on which one period of extra delay, the
    // angle's rate there times `h`, would leave the row's tolerance, the smaller of the two
    // angles': the power of the comparison with this run's stalls (`memory` false: as if
    // each stall counted on its own row only).
    // The swing's rows of each angle and the angle's rate there, from the plant run once.
    let swing_of = |signal: &str, rate: f64| -> Vec<(usize, f64)> {
        let x = column(signal);
        (5..x.len().saturating_sub(5))
            .map(|k| (k, ((x[k + 5] - x[k - 5]) / (10.0 * H)).abs()))
            .filter(|&(_, local)| local >= 0.5 * rate)
            .collect()
    };
    let angles = [
        (
            res1,
            rate1,
            accel1,
            position_decay,
            swing_of("actuationEncoderAngle", rate1),
        ),
        (
            res2,
            rate2,
            accel2,
            torque_decay,
            swing_of("loadEncoderAngle", rate2),
        ),
    ];
    let seen_share = |stall: &[f64], delta: f64, memory: bool| {
        angles
            .iter()
            .map(|(q, r, a, decay, swing)| {
                let decay = if memory { *decay } else { f64::INFINITY };
                let tol = row_tolerances(sustained_of(0.0, *q, *r, delta), *r, *a, stall, decay);
                let seen = swing
                    .iter()
                    .filter(|&&(k, local)| local * H > tol[k])
                    .count();
                seen as f64 / swing.len().max(1) as f64
            })
            .fold(1.0, f64::min)
    };
    // The hardware run, at most five attempts (the rules: the doc comment's "Disturbed runs").
    const ATTEMPTS: usize = 5;
    let disturbance = HOST_DISTURBANCE;
    let mut best: Option<(Results, EmulatorStats, usize, f64, f64)> = None;
    for attempt in 1..=ATTEMPTS {
        let mut config = EmulatorConfig::new("127.0.0.1:0", exported_fmu("BenchPlant"));
        config.parameters = plant_params.clone();
        // Real-time scheduling where permitted (else a warning): a loaded test machine then
        // disturbs the run less; the tolerance uses what the run measured either way.
        config.realtime_priority = Some(50);
        config.key = Some(bench_key_file().2.clone());
        let emu = spawn(config).expect("emulator");
        let parameters = [
            ("backend", "Udp".to_string()),
            ("pacing", "Soft".to_string()),
            ("serverAddress", emu.addr().to_string()),
            ("keyFile", key_path()),
            ("tareSamples", "0".to_string()),
            // Generous for a loaded test machine: the comparison's tolerance uses the
            // measured reply times, the watchdog is tested elsewhere.
            ("replyTimeout", "0.02".to_string()),
            ("realtimePriority", "50".to_string()),
        ];
        let out = run(
            Some(&parameters),
            &["lastLateness", "lastReplyTime", "overrunCount"],
        );
        let stats = emu.stop().unwrap();
        let stall = stalls(&out.results);
        let largest = stall.iter().cloned().fold(0.0, f64::max);
        if matches!(out.outcome, Outcome::Completed { .. }) {
            let shift = mean_shift(&stall);
            let seen = periods_seen(shift);
            let share = seen_share(&stall, shift, true);
            // The single-stall terms bound a stall of a few periods; one above 5 ms
            // (disturbed, as below) left the bound by 2 % once, at 8.9 ms. A run whose stalls
            // leave less than a quarter of the swing able to show one period of delay compares
            // too little (34-62 % in runs without a stall above 5 ms here).
            let comparable = seen <= 8 && largest <= disturbance && share >= 0.25;
            if comparable && best.as_ref().is_none_or(|b| shift < b.3) {
                best = Some((out.results, stats, attempt, shift, share));
            }
            if comparable && seen == 1 {
                break;
            }
            eprintln!(
                "attempt {attempt}: the host's mean shift of {:.0} us hides {} period(s) of delay, largest stall {:.0} us, one shows on {:.0} % of the swing; run again",
                shift * 1e6,
                seen - 1,
                largest * 1e6,
                share * 100.0
            );
            continue;
        }
        // An interlock's trip after a stall above two periods is the host's too (study_bench.rs
        // saw such trips in CI).
        let interlock = interlock_latched(&stats);
        // The step that tripped is not a recorded row: its lateness is in the trip's log.
        let largest = largest.max(master_lateness(&out.outcome).map_or(0.0, |late| late + H));
        // The lag the loops still carried from the host's stalls at the last recorded row (the
        // slower loop's memory): a run of late rows, none above two periods, was seen to end in
        // the regenerative-power interlock (the master up to 0.95 ms behind over the 8 rows
        // ending 6 rows before the trip).
        let carried_at_end = carried(&beyond_mean(&stall), torque_decay)
            .last()
            .copied()
            .unwrap_or(0.0);
        let disturbed = largest > disturbance
            || (interlock && (largest > 2.0 * H || carried_at_end > 0.5 * H))
            || matches!(stats.safe_reason, Some(r) if r == reason::HEARTBEAT_TIMEOUT);
        assert!(
            disturbed,
            "attempt {attempt}: {:?} (largest stall {:.0} us, {:.0} us carried at the end, bench safe reason {:?}, plant trip {:?})",
            out.outcome,
            largest * 1e6,
            carried_at_end * 1e6,
            stats.safe_reason,
            stats.plant_trip
        );
        eprintln!(
            "attempt {attempt} disturbed by the host (largest stall {:.0} us, bench safe reason {:?}): {:?}; run again",
            largest * 1e6,
            stats.safe_reason,
            out.outcome
        );
    }
    let Some((hw, stats, attempt, delta, share)) = best else {
        // Every attempt measured a host that cannot hold a 1 kHz loop: nothing to compare.
        eprintln!(
            "NOT COMPARED: the host disturbed all {ATTEMPTS} hardware runs (stalls above {:.0} ms or a mean shift above 2 ms)",
            disturbance * 1e3
        );
        return;
    };
    assert_eq!(stats.sessions, 1);
    assert_eq!(stats.rejected.rejected(), 0);
    assert_eq!(plant.len(), hw.len());
    let hw_col = |c: &str| hw.column(&format!("{name}.{c}")).unwrap();
    let stall = stalls(&hw);
    let s_max = stall.iter().cloned().fold(0.0, f64::max);
    eprintln!(
        "hardware run (attempt {attempt}): {} overruns, mean shift {:.0} us, largest stall {:.0} us: the comparison sees {} period(s) of extra delay; one on {:.0} % of the swing ({:.0} % without the memory; stalls carried at {position_decay:.1}/s and {torque_decay:.1}/s)",
        hw_col("overrunCount").last().unwrap(),
        delta * 1e6,
        s_max * 1e6,
        periods_seen(delta),
        share * 100.0,
        seen_share(&stall, delta, false) * 100.0
    );
    let stiffness = SPRING_STIFFNESS;
    // (signal, the count of what the controllers see, what the two runs' records differ by in
    // kind, how much of the angles' motion enters the signal as a disturbance):
    // * the plant records the true spring deflection, the hardware the difference of its
    //   encoder angles, which differ by up to one count of each side whatever the trajectories;
    // * the shaft torque is the transducer's reading of the true deflection in both runs;
    // * a time shift of either angle moves the deflection by that angle's rate times the shift
    //   until the torque loop rejects it, and in the swing the angles move 10 times faster
    //   than the deflection: the deflection's (and the torque's) timing terms use the larger
    //   of its own rate and the angles' (scaled by the stiffness for the torque).
    for (signal, quantum, recorded, angle_share, decay) in [
        ("actuationEncoderAngle", res1, 0.0, 0.0, position_decay),
        ("loadEncoderAngle", res2, 0.0, 0.0, torque_decay),
        (
            "springDeflection",
            res1 + res2,
            res1 + res2,
            1.0,
            torque_decay,
        ),
        (
            "transducerTorque",
            stiffness * (res1 + res2),
            0.0,
            stiffness,
            torque_decay,
        ),
    ] {
        let a = column(signal);
        let b = hw_col(signal);
        let (own_rate, own_accel) = rate_and_acceleration(&a);
        let rate = own_rate.max(angle_share * rate1.max(rate2));
        let accel = own_accel.max(angle_share * accel1.max(accel2));
        let sustained = sustained_of(recorded, quantum, rate, delta);
        let tolerances = row_tolerances(sustained, rate, accel, &stall, decay);
        let (mut worst, mut worst_ratio, mut largest_tol) = (0.0f64, 0.0f64, 0.0f64);
        for (k, ((x, y), &tol)) in a.iter().zip(&b).zip(&tolerances).enumerate() {
            let d = (x - y).abs();
            worst = worst.max(d);
            worst_ratio = worst_ratio.max(d / tol);
            largest_tol = largest_tol.max(tol);
            assert!(d <= tol, "{signal} at row {k}: {d} > {tol}");
        }
        let range = a.iter().cloned().fold(0.0, |m: f64, x| m.max(x.abs()));
        eprintln!(
            "{signal}: worst difference {worst:.3e} ({:.0} % of its row's tolerance), sustained tolerance {sustained:.3e}, largest {largest_tol:.3e}, one period of delay {:.3e}, range {range:.3e}",
            worst_ratio * 100.0,
            rate * H
        );
        // The comparison can fail: on a host that keeps its deadlines, every signal moves by
        // more than 5 times its sustained tolerance.
        let quiet = sustained_of(recorded, quantum, rate, quiet_shift);
        assert!(
            range > 5.0 * quiet,
            "{signal}: range {range} vs sustained tolerance {quiet} on a quiet host"
        );
    }
}

/// How a hardware run driven step by step ended.
#[derive(Debug)]
struct Ended {
    /// Steps completed with fmi2OK.
    completed: usize,
    /// `Ok(Discard)` status details or the error text.
    result: Result<(i32, f64), String>,
    /// transducerTorque (the shaft torque) after each completed step (and the tripping one).
    torque: Vec<f64>,
    /// (springTorque, loadCellTorque, testOutputTorque) likewise.
    others: Vec<[f64; 3]>,
    /// The emulator's statistics after the run.
    stats: EmulatorStats,
}

/// Runs `BenchHardware` against `emu` through the harness's instance API: test-motor current
/// `current(t)`, `fault` injected (and applied) just before step `at_step`. The FMU's
/// `configuration` is the default (DA) unless given.
fn drive_configured(
    emu: &EmulatorHandle,
    configuration: Option<i32>,
    current: impl Fn(f64) -> f64,
    fault: Option<(usize, FaultInjection)>,
) -> Ended {
    let fmu = Fmu::load(exported_fmu("BenchHardware"), &LoadOptions::default()).unwrap();
    let vr = |n: &str| fmu.variable(n).unwrap().value_reference;
    let others_vr = [
        vr("springTorque"),
        vr("loadCellTorque"),
        vr("testOutputTorque"),
    ];
    let mut i = fmu.instantiate("hw", &InstanceOptions::default()).unwrap();
    i.set_integer(&[400, 402], &[1, 1]).unwrap();
    if let Some(c) = configuration {
        i.set_integer(&[1], &[c]).unwrap();
    }
    i.set_string(&[401, 425], &[&emu.addr().to_string(), &key_path()])
        .unwrap();
    // A 10 ms link watchdog: loopback answers in tens of microseconds, but a descheduled
    // emulator thread on a loaded 2-core machine (load average 7 seen) can take milliseconds,
    // and the reply timeout is now kept to the microsecond, no longer rounded up to the
    // kernel's tick. The watchdog's own timing is tested in bench_link.rs.
    i.set_real(&[404], &[0.01]).unwrap();
    i.setup_experiment(None, 0.0, None).unwrap();
    i.enter_initialization_mode().unwrap();
    i.exit_initialization_mode().unwrap();
    let mut torque = Vec::new();
    let mut others = Vec::new();
    let mut result = None;
    for k in 0..400 {
        let t = k as f64 * H;
        if let Some((at, f)) = fault
            && at == k
        {
            emu.inject(f).unwrap();
        }
        i.set_real(&[201], &[current(t)]).unwrap();
        match i.do_step(t, H) {
            Ok(Status::Ok) | Ok(Status::Warning) => {
                let mut v = [0.0];
                i.get_real(&[325], &mut v).unwrap();
                torque.push(v[0]);
                let mut o = [0.0; 3];
                i.get_real(&others_vr, &mut o).unwrap();
                others.push(o);
            }
            Ok(Status::Discard) => {
                assert!(i.terminated());
                let mut code = [0];
                i.get_integer(&[373], &mut code).unwrap();
                result = Some(Ok((code[0], i.last_successful_time().unwrap())));
                let mut v = [0.0];
                i.get_real(&[325], &mut v).unwrap();
                torque.push(v[0]);
                let mut o = [0.0; 3];
                i.get_real(&others_vr, &mut o).unwrap();
                others.push(o);
                break;
            }
            Err(e) => {
                result = Some(Err(e.to_string()));
                break;
            }
        }
    }
    let completed = torque.len() - usize::from(matches!(result, Some(Ok(_))));
    drop(i);
    std::thread::sleep(Duration::from_millis(20));
    Ended {
        completed,
        result: result.unwrap_or_else(|| Err("no trip".into())),
        torque,
        others,
        stats: emu.stats(),
    }
}

/// Trip codes of a stop that the host's timing causes (bench-model.md's trip table): the
/// master's link watchdog (8) and the bench stopping itself (11).
const HOST_TRIP_CODES: [i32; 2] = [8, 11];

/// Whether the host explains how `e` ended: the bench measured a pause above
/// [`HOST_DISTURBANCE`] between the master's frames, or the run ended the way a stall ends it.
/// Not once the run reached `link_fault_at`, the step of an injected link fault (dropped,
/// delayed or no replies): that fault makes the same pause and the same trip itself, and
/// what follows it is the test's to judge.
fn host_explains(e: &Ended, link_fault_at: Option<usize>) -> bool {
    if link_fault_at.is_some_and(|k| e.completed >= k) {
        return false;
    }
    e.stats.largest_frame_gap > HOST_DISTURBANCE
        || match &e.result {
            Ok((code, _)) => HOST_TRIP_CODES.contains(code),
            Err(text) => ended_by_host(text),
        }
}

/// [`drive_configured`] on a fresh emulator of the plant with `params`, run again (at most five
/// attempts) while the run did not end as `expected` and the host explains it
/// ([`host_explains`]). A run that ended otherwise is returned for the caller's assertions to
/// report; `None`, said as `NOT COMPARED`, when the host disturbed every attempt.
fn drive_undisturbed(
    params: &[(&str, &str)],
    configuration: Option<i32>,
    current: impl Fn(f64) -> f64,
    fault: Option<(usize, FaultInjection)>,
    expected: impl Fn(&Ended) -> bool,
) -> Option<(EmulatorHandle, Ended)> {
    let attempts = 5;
    for attempt in 1..=attempts {
        let emu = emulator(params);
        let e = drive_configured(&emu, configuration, &current, fault);
        let link_fault_at = fault.and_then(|(k, f)| {
            matches!(
                f,
                FaultInjection::DropReplies { .. }
                    | FaultInjection::DelayReplies { .. }
                    | FaultInjection::Silence
            )
            .then_some(k)
        });
        if expected(&e) || !host_explains(&e, link_fault_at) {
            return Some((emu, e));
        }
        eprintln!(
            "attempt {attempt} disturbed by the host (a pause of {:.0} us, {:?}); run again",
            e.stats.largest_frame_gap * 1e6,
            e.result
        );
    }
    eprintln!("NOT COMPARED: the host disturbed all {attempts} attempts");
    None
}

/// The trip was acknowledged and nothing was driven after it.
fn assert_safe(stats: &EmulatorStats) {
    assert!(stats.safe_state_requests >= 1, "{stats:?}");
    assert!(stats.safe_state_acks >= 1, "{stats:?}");
    assert_eq!(stats.drive_commands_after_safe_request, 0, "{stats:?}");
    assert!(stats.safe_reason.is_some(), "{stats:?}");
}

#[test]
fn motor_torque_interlock_trips_in_the_first_violating_sample() {
    let _real_time = one_real_time_test_at_a_time();
    // The load side held by friction, the emulated plant's own torque interlock out of the way:
    // the test motor winds the spring and the hardware FMU's interlock (on the transducer's
    // shaft torque) must act.
    let Some((_emu, e)) = drive_undisturbed(
        &[("loadStaticFriction", "100"), ("motorTorqueLimit", "100")],
        None,
        |t| 25.0 * t,
        None,
        |e| matches!(e.result, Ok((2, _))),
    ) else {
        return;
    };
    let (code, at) = e.result.clone().unwrap();
    assert_eq!(code, 2, "{e:?}");
    let n = e.torque.len();
    assert!(
        e.torque[n - 1].abs() > 20.0 && e.torque[n - 2].abs() <= 20.0,
        "{e:?}"
    );
    // Tripped at the end of the step whose sample first showed it: within one period.
    assert!((at - n as f64 * H).abs() < 1e-9, "{at} {n}");
    assert!(e.completed > 150);
    assert_safe(&e.stats);
    assert_eq!(e.stats.safe_reason, Some(reason::CLIENT_REQUEST));
}

#[test]
fn a_tripped_run_through_the_master_keeps_every_row_up_to_the_trip() {
    let _real_time = one_real_time_test_at_a_time();
    // As in the interlock test above: the load side held, the test motor winds the spring.
    // A run that the host stopped first (a stall above HOST_DISTURBANCE: the link watchdog, or
    // the bench stopping itself) is not the interlock's trip: run again on a fresh emulator.
    let attempts = 5;
    for attempt in 1..=attempts {
        let emu = emulator(&[("loadStaticFriction", "100"), ("motorTorqueLimit", "100")]);
        let stop = 0.4;
        let ramp = signal(1.0, 0.0, stop);
        let ramp = Signal {
            values: ramp.times.iter().map(|t| 25.0 * t).collect(),
            ..ramp
        };
        let (out, _) = run_bench(
            "BenchHardware",
            &hardware_params(emu.addr()),
            vec![("testCurrentCommand", ramp)],
            stop,
        );
        let gap = emu.stats().largest_frame_gap;
        let (at, last_row, reason) = match &out.outcome {
            Outcome::Terminated {
                last_successful_time,
                last_row_time,
                messages,
                ..
            } => (
                *last_successful_time,
                *last_row_time,
                messages.last().cloned().unwrap_or_default(),
            ),
            Outcome::Failed(e) if gap > HOST_DISTURBANCE || ended_by_host(&e.to_string()) => {
                eprintln!("attempt {attempt} disturbed by the host: {e}; run again");
                continue;
            }
            other => panic!("expected a terminated run, got {other:?}"),
        };
        if gap > HOST_DISTURBANCE || ended_by_host(&reason) {
            eprintln!(
                "attempt {attempt} disturbed by the host (a pause of {:.0} us; {reason}); run again",
                gap * 1e6
            );
            continue;
        }
        let times = out.results.times();
        for (k, t) in times.iter().enumerate() {
            assert!((t - k as f64 * H).abs() < 1e-9, "row {k} at {t}");
        }
        assert!((last_row - times.last().unwrap()).abs() < 1e-12);
        assert!(
            at >= last_row && at - last_row <= H + 1e-9,
            "{at} {last_row}"
        );
        // The interlock's trip, not an earlier stop: the shaft torque passes 20 N m late in
        // the ramp.
        assert!(
            reason.ends_with("test motor torque outside limit"),
            "{reason}"
        );
        assert!(at > 0.15, "{at}: {reason}");
        assert_eq!(emu.stats().drive_commands_after_safe_request, 0);
        return;
    }
    eprintln!("NOT COMPARED: the host disturbed all {attempts} attempts");
}

#[test]
fn injected_faults_trip_within_one_period_with_the_documented_status() {
    let _real_time = one_real_time_test_at_a_time();
    let k = 150;
    let tk = k as f64 * H;
    let steady = |_t: f64| 0.5;
    // (fault, trip code, trip time): found in the sample at the end of step k, except a
    // missing reply, which ends the run at the start of step k (no new sample).
    let cases = [
        (FaultInjection::EmergencyStop, 7, tk + H),
        (
            FaultInjection::Force {
                channel: 1,
                volts: 9.0,
            },
            10,
            tk + H,
        ),
        (FaultInjection::DropReplies { count: 1 }, 8, tk),
        (
            FaultInjection::DelayReplies {
                count: 1,
                delay_s: 0.02,
            },
            8,
            tk,
        ),
    ];
    for (fault, code, time) in cases {
        let Some((_emu, e)) = drive_undisturbed(&[], None, steady, Some((k, fault)), |e| {
            e.result == Ok((code, time))
        }) else {
            continue;
        };
        assert_eq!(e.result, Ok((code, time)), "{fault:?}: {e:?}");
        assert_eq!(e.completed, k, "{fault:?}");
        assert_safe(&e.stats);
        if code == 7 {
            assert_eq!(e.stats.safe_reason, Some(reason::EMERGENCY_STOP));
        } else {
            assert_eq!(e.stats.safe_reason, Some(reason::CLIENT_REQUEST));
        }
    }
    // The link lost for good: the safe state cannot be confirmed: fmi2Error.
    let Some((emu, e)) =
        drive_undisturbed(&[], None, steady, Some((k, FaultInjection::Silence)), |e| {
            e.completed == k
                && e.result
                    .as_ref()
                    .is_err_and(|t| t.contains("NOT confirmed"))
        })
    else {
        return;
    };
    let text = e.result.clone().unwrap_err();
    assert!(text.contains("NOT confirmed"), "{text}");
    assert_eq!(e.completed, k);
    assert_eq!(e.stats.safe_state_acks, 0);
    assert_eq!(e.stats.drive_commands_after_safe_request, 0);
    // The server's own watchdog puts the bench in the safe state after its heartbeat timeout.
    std::thread::sleep(Duration::from_millis(120));
    assert_eq!(emu.stats().safe_reason, Some(reason::HEARTBEAT_TIMEOUT));
}

/// A sensor stuck at an in-range value (the emulator's stuck-channel fault holds the reading it
/// has) passes the plausibility windows; the consistency checks find it. The load side is held
/// by friction and the test motor's current ramps, so the shaft and motor torques grow while
/// the stuck reading does not. The trip must come exactly `consistencyPersistence` (10)
/// samples after the first sample whose disagreement exceeds the documented allowance
/// `1 N m + 0.25 max(|a|, |b|)` (computed here from the recorded outputs), with its own code,
/// the safe state acknowledged and no drive command after it.
#[test]
fn a_sensor_stuck_inside_its_window_trips_the_consistency_interlock() {
    let _real_time = one_real_time_test_at_a_time();
    let k = 50;
    let persistence = 10;
    let allowance = |a: f64, b: f64| 1.0 + 0.25 * a.abs().max(b.abs());
    // (configuration, stuck channel, trip code, which recorded pair: transducer vs spring
    // torque, or load cell vs test output torque)
    for (configuration, channel, code) in [(1, 1u8, 12), (2, 1, 12), (0, 0, 13), (1, 0, 13)] {
        let Some((_emu, e)) = drive_undisturbed(
            &[
                ("configuration", &configuration.to_string()),
                ("loadStaticFriction", "100"),
                ("motorTorqueLimit", "100"),
            ],
            Some(configuration),
            |t| 25.0 * t,
            Some((k, FaultInjection::Stuck { channel })),
            |e| matches!(e.result, Ok((c, _)) if c == code),
        ) else {
            continue;
        };
        let what = format!("configuration {configuration}, channel {channel}");
        let (got, at) = e.result.clone().unwrap_or_else(|m| panic!("{what}: {m}"));
        assert_eq!(got, code, "{what}: {e:?}");
        // The pairs as the FMU compared them, sample n at the end of step n.
        let pair = |n: usize| {
            let [spring, load_cell, output] = e.others[n];
            if channel == 1 {
                (e.torque[n], spring)
            } else {
                (load_cell, output)
            }
        };
        // The stuck reading stays put from the sample of step k on.
        let (stuck, _) = pair(k);
        assert!((k..e.others.len()).all(|n| pair(n).0 == stuck), "{what}");
        let first = (0..e.others.len())
            .find(|&n| {
                let (a, b) = pair(n);
                (a - b).abs() > allowance(a, b)
            })
            .unwrap_or_else(|| panic!("{what}: no disagreement recorded: {e:?}"));
        assert!(
            first >= k,
            "{what}: disagreement before the fault at {first}"
        );
        // The trip is in the sample of step first + persistence - 1, at its end.
        let trip_step = first + persistence - 1;
        assert_eq!(e.others.len(), trip_step + 1, "{what}: {e:?}");
        assert!(
            (at - (trip_step + 1) as f64 * H).abs() < 1e-9,
            "{what}: {at} vs step {trip_step}"
        );
        assert_eq!(e.completed, trip_step, "{what}");
        // The torque kept growing: the sensor was stuck in range, not out of its window.
        let (a, b) = pair(trip_step);
        assert!((a - b).abs() > 1.0, "{what}: {a} {b}");
        assert_safe(&e.stats);
        assert_eq!(e.stats.safe_reason, Some(reason::CLIENT_REQUEST), "{what}");
    }
}

#[test]
fn malformed_and_replayed_frames_to_the_emulator_are_counted_and_ignored() {
    let _real_time = one_real_time_test_at_a_time();
    use kneebench_harness::bench_protocol::{
        BenchSetup, ClientHandshake, Command, HandshakeReply, Payload, SetValueKind,
    };
    let emu = emulator(&[]);
    let socket = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
    socket
        .set_read_timeout(Some(Duration::from_millis(200)))
        .unwrap();
    let setup = BenchSetup {
        configuration: 1,
        test_kind: SetValueKind::Current,
        load_kind: SetValueKind::Current,
    };
    let mut hs = ClientHandshake::new(&bench_key_file().2, setup).unwrap();
    socket.send_to(hs.hello(), emu.addr()).unwrap();
    let mut buf = [0u8; 256];
    let n = socket.recv(&mut buf).unwrap();
    let HandshakeReply::Welcome(mut session) = hs.receive(&buf[..n]).unwrap() else {
        panic!("refused")
    };
    let drive = Command {
        test_set_value: 1.0,
        load_set_value: 0.0,
        test_enable: true,
        load_enable: true,
        clutch: false,
        test_kind: SetValueKind::Current,
        load_kind: SetValueKind::Current,
    };
    let (first_seq, first) = session.tx.frame(Payload::Command(drive));
    socket.send_to(&first, emu.addr()).unwrap();
    // Replay, truncation, corruption and a wrong version: none is applied.
    socket.send_to(&first, emu.addr()).unwrap();
    let (_, second) = session.tx.frame(Payload::Command(drive));
    socket.send_to(&second[..10], emu.addr()).unwrap();
    let mut corrupt = second.clone();
    corrupt[20] ^= 0xFF;
    socket.send_to(&corrupt, emu.addr()).unwrap();
    let mut version = second.clone();
    version[4] = 9;
    socket.send_to(&version, emu.addr()).unwrap();
    let (_, hb) = session.tx.frame(Payload::Heartbeat);
    socket.send_to(&hb, emu.addr()).unwrap();
    // The version refusal comes first (unauthenticated: the client cannot check it), then
    // the sample.
    let sample = loop {
        let n = socket.recv(&mut buf).unwrap();
        if let Ok(f) = session.rx.accept(&buf[..n]) {
            break f;
        }
    };
    match sample.payload {
        Payload::Sample(s) => assert_eq!(s.last_command_sequence, first_seq),
        other => panic!("{other:?}"),
    }
    let s = emu.stop().unwrap();
    assert_eq!(s.commands_applied, 1);
    assert_eq!(s.rejected.replayed, 1);
    assert_eq!(s.rejected.truncated, 1);
    assert_eq!(s.rejected.unauthenticated, 1);
    assert_eq!(s.rejected.wrong_version, 1);
    assert_eq!(s.version_refusals, 1);
}
