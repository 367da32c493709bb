//! Bounded work per `fmi2DoStep`: every model whose work grows with the communication step
//! refuses a step of more than `MAX_INTERNAL_STEPS_PER_CALL` internal steps with fmi2Error and
//! a log line, changes nothing and stays usable; the gait reference (analytic, the same work
//! for any step) takes any step.

use kneebench_tests::*;

use fmi2Status::{fmi2Error, fmi2OK};

#[test]
fn a_step_beyond_the_models_bound_is_refused_and_the_instance_stays_usable() {
    let f = Raw::load(&fmu_library());
    for (model, largest) in [
        ("BenchPlant", "10 s"),
        ("BenchHardware", "10 s"),
        ("PidController", "10 s"),
        ("ImpedanceController", "10 s"),
        ("ClutchScheduler", "10 s"),
    ] {
        let mut i = RawInstance::new(&f, "bounded", &guid_of(model));
        assert!(!i.c.is_null(), "{model}");
        i.initialize(0.0, None);
        let started = std::time::Instant::now();
        assert_eq!(i.step(0.0, 1e6), fmi2Error, "{model}: {}", i.log_text());
        let log = i.log_text();
        assert!(
            log.contains(&format!(
                "communicationStepSize 1000000 s exceeds this model's largest step per call, {largest} (10000 internal steps"
            )),
            "{model}: {log}"
        );
        // Refused before any work (a 1e6 s step of the plant would take ~1e9 sub-steps).
        assert!(
            started.elapsed() < std::time::Duration::from_secs(5),
            "{model}"
        );
        // Nothing changed: the same communication point, and a step at the bound works.
        assert_eq!(i.step(0.0, 0.001), fmi2OK, "{model}: {}", i.log_text());
        assert_eq!(i.step(0.001, 10.0), fmi2OK, "{model}: {}", i.log_text());
        assert_eq!(i.step(10.001, 10.001), fmi2Error, "{model}");
    }
    let mut gait = RawInstance::new(&f, "analytic", &guid_of("GaitReference"));
    gait.initialize(0.0, None);
    assert_eq!(gait.step(0.0, 1e6), fmi2OK, "{}", gait.log_text());
}

/// The discrete controllers count sample instants in an f64 grid position, exact up to 2^52
/// periods: a step whose grid position lies beyond (here from a saved state whose sample 0 is
/// 10^13 s in the past, 10^16 periods of 1 ms) is refused with fmi2Error and a log line naming
/// the step and the grid, never counted wrongly.
#[test]
fn a_step_beyond_the_sample_grids_exact_range_is_refused_with_a_log_line() {
    let f = Raw::load(&fmu_library());
    let mut i = RawInstance::new(&f, "grid", &guid_of("PidController"));
    i.initialize(0.5, None);
    for k in 0..3 {
        let t = 0.5 + k as f64 * 0.001;
        assert_eq!(i.step(t, 0.001), fmi2OK, "{}", i.log_text());
    }
    // The sample clock in the saved state: period, time of sample 0, next sample index.
    let mut state = i.serialized_state();
    let clock: Vec<u8> = [
        0.001f64.to_le_bytes(),
        0.5f64.to_le_bytes(),
        3u64.to_le_bytes(),
    ]
    .concat();
    let at: Vec<usize> = (0..state.len() - clock.len())
        .filter(|&k| state[k..k + clock.len()] == clock[..])
        .collect();
    assert_eq!(at.len(), 1, "the sample clock in the state: {at:?}");
    let start: f64 = 0.5 - 1e13;
    state[at[0] + 8..at[0] + 16].copy_from_slice(&start.to_le_bytes());
    kneebench_fmu::fmi2::instance::reseal_state(&mut state);
    assert_eq!(i.restore(&state), fmi2OK, "{}", i.log_text());
    let t = 0.5 + 3.0 * 0.001;
    assert_eq!(i.step(t, 0.001), fmi2Error);
    let log = i.log_text();
    assert!(
        log.contains(&format!(
            "the step from t = {t} s by h = 0.001 s is outside the sample grid of period 0.001 s starting at {start} s"
        )),
        "{log}"
    );
}
