//! `--parallel` gives exactly the sequential Gauss-Seidel results on the study's closed loops
//! (DA, SEA, CSEA, one gait cycle at the study's step): the groups that step concurrently
//! follow every connection of the sequential order, so each FMU is called with the same
//! inputs in the same state, and every recorded value has the same bits.

use kneebench_harness::package::export_all;
use kneebench_harness::study::{StudyScenario, gait_scenario, write_ssp};
use kneebench_harness::{Algorithm, LoadOptions, Outcome, Results, ssp};
use kneebench_tests::fmu_library;

fn bits(r: &Results) -> Vec<Vec<u64>> {
    r.rows()
        .map(|row| row.iter().map(|v| v.to_bits()).collect())
        .collect()
}

#[test]
fn parallel_gauss_seidel_is_bit_identical_to_sequential_on_da_sea_and_csea() {
    let dir = tempfile::tempdir().unwrap();
    let fmus = dir.path().join("fmus");
    export_all(&fmu_library(), &fmus).expect("export");
    let runs = StudyScenario::ALL
        .into_iter()
        .flat_map(|s| s.actuators().iter().map(move |&a| (s, a)));
    for (study, actuator) in runs {
        let scenario = gait_scenario(actuator, study.gait(), study.gains(actuator), 1);
        let path = dir
            .path()
            .join(format!("{}.ssp", study.file_stem(actuator)));
        write_ssp(&scenario, &fmus, &path).unwrap();
        let loaded = ssp::load_system(&path, &LoadOptions::default()).unwrap();
        assert_eq!(loaded.config.algorithm, Algorithm::GaussSeidel);
        let (order, _) = loaded.system.dependency_order().unwrap();
        let groups = loaded
            .system
            .parallel_groups(&order, Algorithm::GaussSeidel);
        let sequential = loaded.system.run(&loaded.config).unwrap();
        let mut config = loaded.config.clone();
        config.parallel = true;
        let parallel = loaded.system.run(&config).unwrap();
        for out in [&sequential, &parallel] {
            assert!(
                matches!(out.outcome, Outcome::Completed { .. }),
                "{actuator:?}: {:?}",
                out.outcome
            );
        }
        assert!(sequential.results.len() > 1000, "{actuator:?}");
        assert_eq!(sequential.results.names(), parallel.results.names());
        assert!(
            bits(&sequential.results) == bits(&parallel.results),
            "{actuator:?}: parallel rows differ from sequential ones (groups {groups:?})"
        );
        assert_eq!(
            sequential.steps_per_component, parallel.steps_per_component,
            "{actuator:?}"
        );
    }
}
