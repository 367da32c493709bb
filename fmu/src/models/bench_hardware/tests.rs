use std::time::Duration;

use super::*;
use crate::hardware::calibration::{Calibration, Side};
use crate::hardware::io::{BenchIo, IoError, SimulatedBench};
use crate::hardware::protocol::{AnalogChannel, Command, Sample};
use crate::model::{Causality, model_description};
use crate::models::bench_plant::BenchPlantModel;
use ::model_description::ModelDescription;

fn interface(md: &ModelDescription) -> Vec<String> {
    md.model_variables
        .iter()
        .filter(|v| matches!(v.causality, Some(Causality::Input | Causality::Output)))
        .map(|v| format!("{v:?}"))
        .collect()
}

#[test]
fn inputs_and_outputs_are_the_plants_exactly() {
    let plant = model_description::<BenchPlantModel>();
    let hw = model_description::<BenchHardwareModel>();
    let (a, b) = (interface(&plant), interface(&hw));
    assert!(a.len() >= 8 + 74, "{}", a.len());
    assert_eq!(a, b);
    // Outputs are listed in the same order in the ModelStructure, by name.
    let outputs = |md: &ModelDescription| {
        md.model_structure
            .outputs
            .iter()
            .map(|u| md.model_variables[u.index as usize - 1].name.clone())
            .collect::<Vec<_>>()
    };
    assert_eq!(outputs(&plant), outputs(&hw));
}

#[test]
fn shared_parameters_have_the_plants_reference_unit_and_range() {
    let plant = model_description::<BenchPlantModel>();
    let hw = model_description::<BenchHardwareModel>();
    let mut shared = 0;
    for v in &hw.model_variables {
        if v.value_reference < 400 && v.causality == Some(Causality::Parameter) {
            let Some(pv) = plant.model_variables.iter().find(|p| p.name == v.name) else {
                panic!(
                    "{} is not a plant parameter but has a plant-range reference",
                    v.name
                )
            };
            assert_eq!(pv.value_reference, v.value_reference, "{}", v.name);
            assert_eq!(
                format!("{:?}", pv.kind),
                format!("{:?}", v.kind),
                "{}",
                v.name
            );
            shared += 1;
        } else if v.causality == Some(Causality::Parameter) {
            assert!(
                plant
                    .model_variables
                    .iter()
                    .all(|p| p.value_reference != v.value_reference),
                "{}",
                v.name
            );
        }
    }
    assert!(shared >= 35, "{shared}");
}

fn started(configure: impl FnOnce(&mut BenchHardwareModel)) -> BenchHardwareModel {
    let mut m = crate::fmi2::instance::fresh_model::<BenchHardwareModel>();
    configure(&mut m);
    m.initialize(0.0).unwrap();
    m
}

fn run(m: &mut BenchHardwareModel, n: usize, h: f64) -> Option<(f64, &'static str)> {
    for k in 0..n {
        match m.do_step(k as f64 * h, h).unwrap() {
            StepOutcome::Completed => {}
            StepOutcome::Terminated { at, reason } => return Some((at, reason)),
        }
    }
    None
}

#[test]
fn simulated_bench_at_rest_reads_zero_after_the_tare() {
    let mut m = started(|_| {});
    assert!(m.outputs.transducer_torque.abs() < 1e-12);
    assert!(m.outputs.load_cell_torque.abs() < 1e-9);
    m.commands.test_enable = false;
    m.commands.load_enable = false;
    assert_eq!(run(&mut m, 100, 1e-3), None);
    assert_eq!(m.outputs.actuation_encoder_counts, 0.0);
    assert!(m.outputs.test_motor_current.abs() < 1e-12);
}

#[test]
fn simulated_bench_follows_the_plant() {
    use crate::models::bench::{BenchInputs, BenchPlant};
    let h = 1e-3;
    let mut hw = started(|_| {});
    let mut plant = BenchPlant::new(BenchParameters::default()).unwrap();
    let cal = Calibration::new(&BenchParameters::default());
    for k in 0..1000 {
        let t = k as f64 * h;
        let i1 = 2.0 * (std::f64::consts::TAU * 0.4 * t).sin();
        hw.commands.test_current = i1;
        let inputs = BenchInputs {
            test_command: i1,
            test_enable: true,
            load_enable: true,
            ..BenchInputs::default()
        };
        assert_eq!(hw.do_step(t, h).unwrap(), StepOutcome::Completed);
        plant.step(&inputs, h);
        let (a, b) = (&hw.outputs, plant.outputs());
        assert_eq!(a.actuation_encoder_counts, b.actuation_encoder_counts);
        assert!((a.actuation_angle - b.actuation_angle).abs() < cal.resolution(Side::Actuation));
        assert!((a.test_motor_current - b.test_motor_current).abs() < 1e-12);
    }
    assert!(hw.outputs.actuation_encoder_counts > 1000.0);
}

#[test]
fn interlocks_trip_latch_and_never_drive_again() {
    // Test motor torque (the shaft torque): the load side held by friction, 5 A x 0.037 x
    // 160 = 29.6 N m winds the spring past 20 N m.
    let mut m = started(|m| m.params.load_static_friction = 100.0);
    m.commands.test_current = 5.0;
    let (at, reason) = run(&mut m, 100, 1e-3).unwrap();
    assert_eq!(m.outputs.trip_code, 2, "{reason}");
    assert!(at <= 0.2, "{at}");
    // Latched: the next step reports the same trip and does nothing.
    assert_eq!(
        m.do_step(at, 1e-3).unwrap(),
        StepOutcome::Terminated { at, reason }
    );
    // Emergency-stop input: trips at the start of the step.
    let mut m = started(|_| {});
    m.commands.emergency_stop = true;
    assert_eq!(run(&mut m, 10, 1e-3), Some((0.0, "emergency stop")));
    assert_eq!(m.outputs.trip_code, 7);
    // Spring deflection: the load side is pushed against a blocked actuation side.
    let mut m2 = started(|m| m.params.motor_torque_limit = 1e3);
    m2.commands.clutch_engage = true;
    m2.commands.load_current = 4.5;
    run(&mut m2, 2000, 1e-3).unwrap();
    assert_eq!(m2.outputs.trip_code, 1);
    // A sensor window that excludes the reading: sensor fault.
    let mut m3 =
        started(|m| m.plausibility.analog[AnalogChannel::TestCurrentSense.index()] = (2.0, 2.7));
    m3.commands.test_current = 3.0;
    run(&mut m3, 100, 1e-3).unwrap();
    assert_eq!(m3.outputs.trip_code, trip::SENSOR);
}

#[test]
fn a_trip_after_overruns_logs_how_late_the_loop_ran() {
    let h = 1e-3;
    // Soft real time: a host stall of 5 ms before the second step makes it 4 ms late or more.
    let mut m = started(|m| m.pacing = 1);
    assert_eq!(m.do_step(0.0, h).unwrap(), StepOutcome::Completed);
    std::thread::sleep(std::time::Duration::from_millis(5));
    assert_eq!(m.do_step(h, h).unwrap(), StepOutcome::Completed);
    m.take_warnings();
    m.commands.emergency_stop = true;
    let outcome = m.do_step(2.0 * h, h).unwrap();
    assert!(
        matches!(outcome, StepOutcome::Terminated { .. }),
        "{outcome:?}"
    );
    let warnings = m.take_warnings().join("\n");
    let stats = m.runtime.0.as_ref().unwrap().pacer.stats;
    assert!(
        stats.overruns >= 1 && stats.max_lateness >= 4e-3,
        "{stats:?}"
    );
    assert!(
        warnings.contains(&format!(
            "pacing before trip 7: {} overruns in {} steps, largest lateness {:.0} us",
            stats.overruns,
            stats.steps,
            stats.max_lateness * 1e6
        )),
        "{warnings}"
    );
    // Without pacing there is no schedule to fall behind: the trip says nothing of it.
    let mut m = started(|_| {});
    m.commands.emergency_stop = true;
    run(&mut m, 1, h).unwrap();
    assert!(m.take_warnings().is_empty());
}

#[test]
fn realtime_priority_and_lock_memory_are_honoured_or_refused_with_a_warning() {
    use crate::hardware::realtime::current_policy;
    // On a thread of its own: the test harness's threads keep their scheduling.
    std::thread::spawn(|| {
        let before = current_policy();
        let mut m = started(|m| {
            m.pacing = 1;
            m.realtime_priority = 7;
            m.lock_memory = true;
        });
        assert_eq!(run(&mut m, 3, 1e-3), None);
        let warnings = m.take_warnings().join("\n");
        let rt = m.runtime.0.as_ref().unwrap();
        match &rt.realtime {
            Some(g) => {
                assert_eq!(g.priority, 7);
                assert_eq!(current_policy(), Some((1, 7)));
            }
            None => assert!(warnings.contains("realtimePriority 7"), "{warnings}"),
        }
        let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
        let locked = status
            .lines()
            .find(|l| l.starts_with("VmLck:"))
            .and_then(|l| l.split_whitespace().nth(1)?.parse::<u64>().ok());
        assert!(
            locked.is_some_and(|kb| kb > 0) || warnings.contains("lockMemory"),
            "{locked:?} {warnings}"
        );
        // The thread gets its scheduling back with the instance.
        drop(m);
        assert_eq!(current_policy(), before);
        // Without pacing nothing is asked for.
        let mut m = started(|m| m.realtime_priority = 7);
        assert_eq!(run(&mut m, 3, 1e-3), None);
        assert_eq!(current_policy(), before);
        assert!(m.take_warnings().is_empty());
    })
    .join()
    .unwrap();
}

#[test]
fn consistency_checks_trip_on_a_stuck_reading_and_stay_quiet_on_a_healthy_bench() {
    // A healthy SEA bench winding its spring against a held load side: no trip before the
    // shaft-torque interlock (code 2), the checks quiet all along.
    let mut m = started(|m| {
        m.configuration = 1;
        m.params.load_static_friction = 100.0;
    });
    m.commands.test_current = 4.0;
    let (_, reason) = run(&mut m, 2000, 1e-3).unwrap();
    assert_eq!(m.outputs.trip_code, 2, "{reason}");
    // The same with a tolerance no healthy reading meets: code 12 after exactly the
    // persistence (the transducer is checked before the load cell).
    let mut m = started(|m| {
        m.configuration = 1;
        m.params.load_static_friction = 100.0;
        m.consistency_tolerance = 0.0;
        m.consistency_relative = 0.0;
        m.consistency_persistence = 4;
    });
    m.commands.test_current = 4.0;
    let (at, reason) = run(&mut m, 2000, 1e-3).unwrap();
    assert_eq!(
        m.outputs.trip_code,
        trip::TRANSDUCER_INCONSISTENT,
        "{reason}"
    );
    assert!(at < 0.1, "{at}");
    // DA: no spring check; the load cell pair is the one that trips.
    let mut m = started(|m| {
        m.configuration = 0;
        m.consistency_tolerance = 0.0;
        m.consistency_relative = 0.0;
        m.consistency_persistence = 3;
    });
    m.commands.test_current = 1.0;
    run(&mut m, 100, 1e-3).unwrap();
    assert_eq!(m.outputs.trip_code, trip::LOAD_CELL_INCONSISTENT);
    // Persistence 0: off.
    let mut m = started(|m| {
        m.consistency_tolerance = 0.0;
        m.consistency_relative = 0.0;
        m.consistency_persistence = 0;
    });
    m.commands.test_current = 1.0;
    assert_eq!(run(&mut m, 100, 1e-3), None);
}

/// The simulated bench behind a wall-clock server: its timestamps are the sample times,
/// and the sample of step `late` is taken `delay` s late (as after an overrun).
struct LateBench {
    bench: SimulatedBench,
    reads: usize,
    late: usize,
    delay: f64,
    slip: f64,
    /// Taken off the slip at the sample after the late one: that sample comes less than a
    /// period after the late one (the loop catching up).
    catch_up: f64,
}

impl BenchIo for LateBench {
    fn write(&mut self, t: f64, command: &Command) -> Result<u32, IoError> {
        self.bench.write(t + self.slip, command)
    }
    fn read(&mut self, t: f64) -> Result<Sample, IoError> {
        self.reads += 1;
        if self.reads == self.late {
            self.slip += self.delay;
        }
        if self.reads == self.late + 1 {
            self.slip -= self.catch_up;
        }
        self.bench.read(t + self.slip)
    }
    fn enter_safe_state(
        &mut self,
        t: f64,
        reason: u8,
        timeout: Duration,
    ) -> Result<Sample, IoError> {
        self.bench.enter_safe_state(t + self.slip, reason, timeout)
    }
    fn timestamps_are_wall_time(&self) -> bool {
        true
    }
}

#[test]
fn a_late_sample_does_not_read_as_a_speed_jump() {
    let mut m = started(|_| {});
    let p = m.runtime.0.as_ref().unwrap().p.clone();
    let mut sim = p.clone();
    sim.spring_deflection_limit = 10.0;
    sim.motor_torque_limit = 1e4;
    let rt = m.runtime.0.as_mut().unwrap();
    rt.io = Box::new(LateBench {
        bench: SimulatedBench::new(sim).unwrap(),
        reads: 0,
        late: 400,
        delay: 2e-3,
        slip: 0.0,
        catch_up: 0.0,
    });
    rt.server_us = 0;
    // A steady current: the shaft turns at a nearly constant speed (about 50 counts per
    // period) by step 300.
    m.commands.test_current = 3.0;
    let h = 1e-3;
    let mut speeds = Vec::new();
    let mut energy = Vec::new();
    for k in 0..402 {
        assert_eq!(m.do_step(k as f64 * h, h).unwrap(), StepOutcome::Completed);
        speeds.push(m.outputs.actuation_velocity);
        energy.push(m.outputs.test_electrical_energy);
    }
    let (before, late) = (speeds[398], speeds[399]);
    assert!(before > 0.1, "{before}");
    // The late sample covers 3 ms of motion; its speed is still the shaft's.
    assert!((late - before).abs() < 0.1 * before, "{before} {late}");
    // And 3 ms of the driver's energy: the power is nearly steady, the interval three times
    // a period.
    let (period, late_interval) = (energy[398] - energy[397], energy[399] - energy[398]);
    assert!(period > 0.0, "{period}");
    assert!(
        (late_interval / period - 3.0).abs() < 0.1,
        "{period} {late_interval}"
    );
}

#[test]
fn a_sample_right_after_a_late_one_does_not_read_as_a_speed_spike() {
    let mut m = started(|_| {});
    let p = m.runtime.0.as_ref().unwrap().p.clone();
    let mut sim = p.clone();
    sim.spring_deflection_limit = 10.0;
    sim.motor_torque_limit = 1e4;
    let h = 1e-3;
    let rt = m.runtime.0.as_mut().unwrap();
    rt.io = Box::new(LateBench {
        bench: SimulatedBench::new(sim).unwrap(),
        reads: 0,
        late: 400,
        delay: 2e-3,
        slip: 0.0,
        // The next sample 0.1 ms after the late one.
        catch_up: 0.9e-3,
    });
    rt.server_us = 0;
    m.commands.test_current = 3.0;
    let mut speeds = Vec::new();
    let mut bench_times = Vec::new();
    for k in 0..402 {
        assert_eq!(m.do_step(k as f64 * h, h).unwrap(), StepOutcome::Completed);
        speeds.push(m.outputs.actuation_velocity);
        bench_times.push(m.bench_sample_time);
    }
    // `benchSampleTime` is the bench's clock at each sample: on the schedule until the late
    // one (the row at 400 ms read at 402 ms), then 0.1 ms after it (the row at 401 ms).
    for (k, expected) in [(398, 0.399), (399, 0.402), (400, 0.4021), (401, 0.4031)] {
        assert!(
            (bench_times[k] - expected).abs() < 1e-9,
            "step {k}: {} against {expected}",
            bench_times[k]
        );
    }
    let (before, caught_up) = (speeds[398], speeds[400]);
    assert!(before > 0.1, "{before}");
    // About 5 counts in 0.1 ms: a one-count error alone would be 20 %.
    assert!(
        (caught_up - before).abs() < 0.05 * before,
        "{before} {caught_up}"
    );
}

#[test]
fn udp_backend_needs_pacing_and_a_state_after_start_is_not_restorable() {
    let mut m = crate::fmi2::instance::fresh_model::<BenchHardwareModel>();
    m.backend = 1;
    assert!(m.initialize(0.0).unwrap_err().message.contains("pacing"));
    let m = started(|_| {});
    let mut w = StateWriter::default();
    m.save_internal(&mut w);
    let mut fresh = BenchHardwareModel::default();
    assert!(
        fresh
            .load_internal(&mut StateReader::new(&w.bytes))
            .is_err()
    );
}
