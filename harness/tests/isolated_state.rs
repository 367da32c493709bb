//! FMU state through an isolated instance (the state lives in the host process; the master
//! holds its handle): get, set, update, serialize, deserialize and free behave as in process.

mod common;

use std::time::Duration;

use kneebench_harness::isolate::{HostOptions, Isolation};
use kneebench_harness::{Fmu, InstanceOptions, LoadOptions};

fn x_after(isolation: Isolation) -> Vec<f64> {
    let d = tempfile::tempdir().unwrap();
    let fmu = Fmu::load(
        common::kbtest_fmu(d.path()),
        &LoadOptions {
            isolation,
            host: HostOptions {
                helper: Some(env!("CARGO_BIN_EXE_kneebench-fmu-host").into()),
                call_timeout: Duration::from_secs(60),
            },
            ..LoadOptions::default()
        },
    )
    .unwrap();
    let mut i = fmu.instantiate("s", &InstanceOptions::default()).unwrap();
    assert_eq!(i.is_isolated(), isolation == Isolation::Process);
    i.setup_experiment(None, 0.0, None).unwrap();
    i.enter_initialization_mode().unwrap();
    i.exit_initialization_mode().unwrap();
    let mut seen = Vec::new();
    let mut x = [0.0];
    // u = 1: x counts the steps.
    i.set_real(&[0], &[1.0]).unwrap();
    i.do_step(0.0, 0.1).unwrap();
    let mut saved = i.get_fmu_state().unwrap();
    i.do_step(0.1, 0.1).unwrap();
    i.get_real(&[4], &mut x).unwrap();
    seen.push(x[0]); // 2
    i.set_fmu_state(&saved).unwrap();
    i.get_real(&[4], &mut x).unwrap();
    seen.push(x[0]); // 1 again
    // Through bytes: a fresh state from the serialized one.
    let bytes = i.serialize_fmu_state(&saved).unwrap();
    assert!(!bytes.is_empty());
    let copy = i.deserialize_fmu_state(&bytes).unwrap();
    i.do_step(0.1, 0.1).unwrap();
    i.do_step(0.2, 0.1).unwrap();
    i.update_fmu_state(&mut saved).unwrap(); // now at 3
    i.set_fmu_state(&copy).unwrap();
    i.get_real(&[4], &mut x).unwrap();
    seen.push(x[0]); // 1
    i.set_fmu_state(&saved).unwrap();
    i.get_real(&[4], &mut x).unwrap();
    seen.push(x[0]); // 3
    i.free_fmu_state(copy).unwrap();
    i.free_fmu_state(saved).unwrap();
    seen
}

#[test]
fn fmu_state_round_trips_through_an_isolated_instance_as_in_process() {
    let local = x_after(Isolation::InProcess);
    assert_eq!(local, vec![2.0, 1.0, 1.0, 3.0]);
    assert_eq!(x_after(Isolation::Process), local);
}
