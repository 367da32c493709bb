//! `kneebench study --bench ADDRESS --key FILE`: the study's schedule on a bench, here the
//! emulator on loopback serving the plant with the scenario's parameters, in real time. The
//! plant component is replaced by `BenchHardware` (`ssp::load_system_replacing`, what
//! `kneebench run --replace` does); the run must complete and track as the plant-only study
//! does. A bench built for another actuator refuses the session, naming the setting; a study
//! that names no single actuator is refused before anything runs.

use kneebench_harness::Outcome;
use kneebench_harness::bench_protocol::reason;
use kneebench_harness::emulator::{EmulatorConfig, spawn};
use kneebench_harness::master::Value;
use kneebench_harness::study::{
    Actuator, BenchLink, StudyConfig, StudyScenario, gait_scenario, run_study,
};
use kneebench_tests::loop_memory::{beyond_mean, carried, row_stalls, sea_loop_decays};
use kneebench_tests::{
    HOST_DISTURBANCE, bench_key_file, exported_fmu, exported_fmus, interlock_latched,
    master_lateness, one_real_time_test_at_a_time,
};

fn config(
    out: &std::path::Path,
    bench: Option<BenchLink>,
    actuators: Vec<Actuator>,
) -> StudyConfig {
    StudyConfig {
        fmu_dir: exported_fmus().0.path().to_path_buf(),
        out_dir: out.to_path_buf(),
        scenario: StudyScenario::BenchFull,
        cycles: 2,
        scale: 1.0,
        gains: None,
        actuators,
        overrides: Vec::new(),
        parameter_set: None,
        bench,
    }
}

/// The plant's parameters of the study's scenario for `actuator`, as the emulator takes them.
fn plant_parameters(actuator: Actuator) -> Vec<(String, String)> {
    let study = StudyScenario::BenchFull;
    let scenario = gait_scenario(actuator, study.gait(), study.gains(actuator), 2);
    let plant = scenario
        .components
        .iter()
        .find(|c| c.fmu == "BenchPlant.fmu")
        .unwrap();
    plant
        .parameters
        .iter()
        .map(|(n, v)| {
            let text = match v {
                Value::Real(x) => format!("{x:?}"),
                Value::Integer(x) => x.to_string(),
                Value::Boolean(x) => x.to_string(),
                Value::String(x) => x.clone(),
            };
            (n.clone(), text)
        })
        .collect()
}

fn link(address: std::net::SocketAddr) -> BenchLink {
    BenchLink {
        address: address.to_string(),
        key_file: bench_key_file().1.clone(),
        parameters: vec![
            // The emulated transducer reads the plant's calibrated torque: no tare (tested
            // in hardware.rs).
            ("tareSamples".into(), "0".into()),
            // Generous for a loaded test machine (the watchdog is tested in bench_link.rs).
            ("replyTimeout".into(), "0.02".into()),
            // The master's stepping thread in SCHED_FIFO where permitted (else a warning), as
            // the emulated bench: a loaded test machine then holds the loop up far less.
            ("realtimePriority".into(), "50".into()),
        ],
    }
}

/// The study's communication step \[s\].
const PERIOD: f64 = 1e-3;

/// **Disturbed runs.** A host stall of several periods (10 ms ones were seen in CI on a loaded
/// 2-core machine) can make the emulated bench stop itself (its heartbeat watchdog, or its
/// protection after the loop lost track) or the knee leave the tolerance for a moment. Such a
/// run measured its own disturbance (the bench's longest interval between two of the master's
/// frames above 5 ms, or the watchdog's reason) and is run again on a fresh emulator, at most
/// five attempts (three were too few on a host whose 1 ms sleeps stall above 5 ms several
/// times in 9 s). A run a safety interlock ended after a stall above two periods is the host's
/// too (a torque command held for milliseconds), whether the bench's protection or the
/// master's own interlock latched first; the stall is the longer of the bench's longest pause
/// between frames and how far the master fell behind its schedule (its largest lateness plus
/// the period it held the command, logged by `BenchHardware` at the trip). So is one that
/// tripped while the loops still carried half a period of lag or more from the host's stalls
/// at the last recorded row (each row's `lastLateness + lastReplyTime`, carried on at the
/// torque loop's decay, `loop_memory`): a run of late rows, none above two periods, can end in
/// the regenerated-power interlock (seen in hardware.rs's study run); each stall counts beyond
/// the run's mean stall, a steady shift. And so is a completed run whose worst row is within
/// half the tolerance plus what the stalls carried into that row can have displaced the knee
/// (twice the knee's largest rate times the carried stall: the loop's peak sensitivity 2): at
/// 2.33 rad/s a stall of about 1.9 ms carried into the row excuses the tolerance's other half,
/// and no stall excuses a departure larger than it can make. A run without such
/// a measurement is always asserted on; when all five were disturbed, nothing is compared and
/// the test says NOT COMPARED.
#[test]
fn the_sea_study_runs_on_the_emulated_bench_and_tracks_like_the_plant() {
    let _real_time = one_real_time_test_at_a_time();
    let out = tempfile::tempdir().unwrap();
    let simulated = run_study(&config(
        &out.path().join("plant"),
        None,
        vec![Actuator::Sea],
    ))
    .unwrap();
    let knee = |r: &kneebench_harness::Results| r.column("plant.loadEncoderAngle").unwrap();
    let planned = knee(&simulated[0].results);
    // The per-row tolerance of a networked loop is derived and asserted in hardware.rs (at
    // most about 0.6 deg with millisecond stalls); here the whole study path must agree within
    // a degree over two cycles.
    let tolerance = 1f64.to_radians();
    // The knee's largest rate (a one-period difference of the encoder angle: 2.33 rad/s here).
    // A stall `s` beyond the run's mean displaces the knee by up to that rate times `s`, and
    // the loop's feedback multiplies that by at most its peak sensitivity, 2 (hardware.rs's
    // bound, whose memory this uses too).
    let knee_rate = planned
        .windows(2)
        .map(|w| ((w[1] - w[0]) / PERIOD).abs())
        .fold(0.0f64, f64::max);
    let disturbance = HOST_DISTURBANCE;
    let (position_decay, torque_decay) = sea_loop_decays();
    let torque_decay = torque_decay.min(position_decay);
    const ATTEMPTS: usize = 5;
    let mut attempt = 0;
    let (bench_run, stats, worst) = loop {
        attempt += 1;
        let mut emulator = EmulatorConfig::new("127.0.0.1:0", exported_fmu("BenchPlant"));
        emulator.parameters = plant_parameters(Actuator::Sea);
        emulator.key = Some(bench_key_file().2.clone());
        emulator.realtime_priority = Some(50);
        let emu = spawn(emulator).expect("emulator");
        let mut on_bench = run_study(&config(
            &out.path().join(format!("bench-{attempt}")),
            Some(link(emu.addr())),
            vec![Actuator::Sea],
        ))
        .unwrap();
        let stats = emu.stop().unwrap();
        assert_eq!(on_bench.len(), 1);
        let bench_run = on_bench.remove(0);
        let completed = matches!(bench_run.outcome, Outcome::Completed { .. });
        let measured = knee(&bench_run.results);
        // The worst row and its difference from the planned knee.
        let (worst_row, worst) = measured
            .iter()
            .zip(&planned)
            .map(|(x, y)| (x - y).abs())
            .enumerate()
            .fold((0, 0.0f64), |b, (k, d)| if d > b.1 { (k, d) } else { b });
        // The host's stall as either side measured it: the bench's longest pause between two
        // frames, or how far the master fell behind its schedule (a loop whose steps each
        // take a little over a period never pauses long, but holds every command longer; CI
        // saw one fall 3.3 ms behind over a dozen steps while no gap exceeded 1.9 ms). An
        // interlock's trip after a stall above two periods is the host's (CI saw regen-power
        // trips after pauses of 3.8 and 4.7 ms, latched by the bench's protection or the
        // master's own interlock).
        let lag = master_lateness(&bench_run.outcome).map_or(0.0, |late| late + PERIOD);
        let stall = stats.largest_frame_gap.max(lag);
        let interlock = interlock_latched(&stats);
        // Each row's stall beyond the run's mean, carried on at the slower loop's decay
        // (`loop_memory`; empty only for a run that failed before its first row, and the kept
        // run is checked below).
        let row_stall = row_stalls(&bench_run.results, "plant").unwrap_or_default();
        let carried_stall = carried(&beyond_mean(&row_stall), torque_decay, PERIOD);
        // A trip while the loops still carried half a period of lag at the last recorded row
        // (hardware.rs saw a run of late rows, none above two periods, end in the
        // regenerated-power interlock).
        let carried_at_end = carried_stall.last().copied().unwrap_or(0.0);
        let protected = interlock && (stall > 2.0 * PERIOD || carried_at_end > 0.5 * PERIOD);
        // A completed run whose worst row left the tolerance by no more than the stalls
        // carried into that row can have moved it: half the tolerance (the encoders and the
        // steady shift, 0.2 deg in undisturbed runs here) plus the displacement, 2 R c.
        let carried_at_worst = carried_stall.get(worst_row).copied().unwrap_or(0.0);
        let explained = completed
            && worst >= tolerance
            && worst <= 0.5 * tolerance + 2.0 * knee_rate * carried_at_worst;
        let disturbed = stall > disturbance
            || protected
            || explained
            || matches!(stats.safe_reason, Some(r) if r == reason::HEARTBEAT_TIMEOUT);
        if disturbed && attempt == ATTEMPTS && !(completed && worst < tolerance) {
            eprintln!(
                "NOT COMPARED: the host disturbed all {ATTEMPTS} runs (last: longest frame gap {:.0} us, master behind by {:.0} us, {:.0} us carried at the end, {:.0} us into the worst row, knee off by up to {:.2} deg, bench safe reason {:?}, plant trip {:?})",
                stats.largest_frame_gap * 1e6,
                lag * 1e6,
                carried_at_end * 1e6,
                carried_at_worst * 1e6,
                worst.to_degrees(),
                stats.safe_reason,
                stats.plant_trip
            );
            return;
        }
        if (completed && worst < tolerance) || !disturbed {
            assert!(
                completed,
                "attempt {attempt}: {:?} (longest frame gap {:.0} us, master behind by {:.0} us, {:.0} us carried at the end, bench safe reason {:?}, plant trip {:?})",
                bench_run.outcome,
                stats.largest_frame_gap * 1e6,
                lag * 1e6,
                carried_at_end * 1e6,
                stats.safe_reason,
                stats.plant_trip
            );
            assert_eq!(measured.len(), planned.len());
            break (bench_run, stats, worst);
        }
        eprintln!(
            "attempt {attempt} disturbed by the host (longest frame gap {:.0} us, master behind by {:.0} us, {:.0} us carried at the end, {:.0} us into the worst row, bench safe reason {:?}, knee off by up to {:.2} deg): {:?}; run again",
            stats.largest_frame_gap * 1e6,
            lag * 1e6,
            carried_at_end * 1e6,
            carried_at_worst * 1e6,
            stats.safe_reason,
            worst.to_degrees(),
            bench_run.outcome
        );
    };
    assert_eq!(stats.sessions, 1);
    assert_eq!(stats.rejected.rejected(), 0);
    assert!(stats.commands_applied as usize >= bench_run.results.len() - 1);
    // Each row's timing is recorded with the run on the bench, as the pacing counts are.
    let row_stall = row_stalls(&bench_run.results, "plant").expect("each row's timing");
    assert_eq!(row_stall.len(), bench_run.results.len());
    assert!(row_stall.iter().all(|s| s.is_finite() && *s >= 0.0));
    assert!(
        row_stall.iter().any(|s| *s > 0.0),
        "a real-time run takes time"
    );
    assert!(
        worst < tolerance,
        "attempt {attempt} (longest frame gap {:.0} us): knee off by up to {} deg",
        stats.largest_frame_gap * 1e6,
        worst.to_degrees()
    );
    // The energies differ by more than the trajectories: the hardware computes its powers from
    // encoder-differenced velocities and measured currents, the plant from its states
    // (printed, not asserted).
    let energy = |r: &kneebench_harness::study::StudyRun| r.report.energy.test_mechanical;
    eprintln!(
        "attempt {attempt} (longest frame gap {:.0} us, largest row stall {:.0} us; the knee's largest rate {knee_rate:.2} rad/s): knee angle: worst difference {:.3} deg; test-motor mechanical energy per cycle: bench {:.2} J, plant {:.2} J",
        stats.largest_frame_gap * 1e6,
        row_stall.iter().copied().fold(0.0, f64::max) * 1e6,
        worst.to_degrees(),
        energy(&bench_run),
        energy(&simulated[0])
    );
    // The run on the bench recorded its pacing, and the report says it; the twin's has none.
    let pacing = bench_run
        .pacing
        .expect("the run on the bench records its pacing");
    assert!(pacing.largest_lateness > 0.0, "{pacing}");
    // It says when: the row that first recorded the largest lateness, whose own lateness it is.
    let at = pacing
        .largest_lateness_time
        .expect("a real-time run is late somewhere");
    let times = bench_run.results.times();
    let row = times.iter().position(|&t| t == at).expect("a row's time");
    let late = bench_run.results.column("plant.lastLateness").unwrap();
    assert_eq!(late[row], pacing.largest_lateness, "{pacing}");
    assert!(late[..row].iter().all(|&l| l < pacing.largest_lateness));
    assert_eq!(simulated[0].pacing, None);
    let section = kneebench_harness::study::ScenarioSection {
        scenario: bench_run.study,
        runs: std::slice::from_ref(&bench_run),
        figures: &[],
    };
    let report = kneebench_harness::study::write_report(out.path(), &[section], "test").unwrap();
    let text = std::fs::read_to_string(report).unwrap();
    assert!(
        text.contains(&format!("  - pacing on the bench: {pacing}\n")),
        "{text}"
    );
}

#[test]
fn a_bench_built_for_another_actuator_refuses_the_session_naming_the_setting() {
    let _real_time = one_real_time_test_at_a_time();
    let mut emulator = EmulatorConfig::new("127.0.0.1:0", exported_fmu("BenchPlant"));
    emulator.parameters = plant_parameters(Actuator::Da);
    emulator.key = Some(bench_key_file().2.clone());
    let emu = spawn(emulator).expect("emulator");
    let out = tempfile::tempdir().unwrap();
    let runs = run_study(&config(
        out.path(),
        Some(link(emu.addr())),
        vec![Actuator::Sea],
    ))
    .unwrap();
    let stats = emu.stop().unwrap();
    // The study reports the run as failed at initialisation with the bench's reason, not as
    // an interlock trip (the CLI exits with code 1 and report.md names the failure).
    let e = match &runs[0].outcome {
        Outcome::Failed(e) => format!("{e:?}"),
        other => panic!("{other:?}"),
    };
    assert!(
        e.contains("configuration differs: bench DA, client SEA"),
        "{e}"
    );
    assert_eq!(runs[0].report.trip, None);
    let (failure, _) = runs[0].failure().expect("the run failed");
    assert!(failure.contains("configuration differs"), "{failure}");
    assert_eq!(stats.drive_commands_applied_total, 0);
}

#[test]
fn a_bench_study_must_name_one_actuator() {
    let out = tempfile::tempdir().unwrap();
    let address = "127.0.0.1:9".parse().unwrap();
    for actuators in [Vec::new(), vec![Actuator::Sea, Actuator::Csea]] {
        let e = run_study(&config(out.path(), Some(link(address)), actuators))
            .unwrap_err()
            .to_string();
        assert!(e.contains("one actuator"), "{e}");
    }
    // Nothing ran: no scenario was written.
    assert!(!out.path().join("scenarios").exists());
}

#[test]
fn the_masters_lateness_is_read_from_its_trip_log() {
    let ended = |messages: &[&str]| Outcome::Terminated {
        component: "plant".into(),
        last_successful_time: 1.0,
        last_row_time: 1.0,
        messages: messages.iter().map(|m| m.to_string()).collect(),
    };
    let late = ended(&[
        "fmi2DoStep: overrun at t = 0.1: the step reached its deadline 416 us late (1 overruns so far)",
        "fmi2DoStep: pacing before trip 11: 20 overruns in 1621 steps, largest lateness 3316 us",
        "fmi2DoStep: simulation ended at t = 1.621: the bench stopped itself (server watchdog or protection)",
    ]);
    assert_eq!(master_lateness(&late), Some(3316e-6));
    let on_time = ended(&["fmi2DoStep: simulation ended at t = 1: emergency stop"]);
    assert_eq!(master_lateness(&on_time), None);
    assert_eq!(
        master_lateness(&Outcome::Completed { stop_time: 5.0 }),
        None
    );
}
