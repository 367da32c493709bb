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
