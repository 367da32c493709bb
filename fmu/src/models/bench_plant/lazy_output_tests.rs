//! The plant's outputs computed lazily, by group: read after a step, a set or a restore,
//! they are those of the current state (and an FMU state restores what was read).

use super::*;
use crate::model::Access;
use model_description::Causality;

/// A plant mid-run: moving, currents flowing, energies accumulated.
fn running() -> BenchPlantModel {
    running_in(1)
}

/// A plant of `configuration` (0 DA, 1 SEA, 2 CSEA) mid-run, as [`running`].
pub(super) fn running_in(configuration: i32) -> BenchPlantModel {
    let mut m = crate::fmi2::instance::fresh_model::<BenchPlantModel>();
    m.configuration = configuration;
    m.calculate(0.0).unwrap();
    m.initialize(0.0).unwrap();
    m.commands.test_current = 3.0;
    m.commands.load_current = -0.5;
    for k in 0..300 {
        m.do_step(k as f64 * 1e-3, 1e-3).unwrap();
    }
    m.calculate(0.3).unwrap();
    m
}

/// Every output read through its own group alone (the other groups holding sentinels)
/// equals the value in the full output set: each field is filled by the group its getter
/// names, so a field listed in the wrong group would read a sentinel.
#[test]
fn each_output_is_computed_by_its_own_group() {
    let model = running();
    let full = model.plant.as_ref().unwrap().outputs();
    assert!(full.load_cell_voltage != 0.0 && full.test_mechanical_power != 0.0);
    let sentinel = {
        let mut lazy = model.clone();
        lazy.fresh.set(u8::MAX);
        // Fill the sentinel through the setters: every real -7.5e7, every bool the opposite
        // of its value, every integer 77.
        for v in BenchPlantModel::variables() {
            if v.causality != Causality::Output {
                continue;
            }
            match v.access {
                Access::Real(_, set) => set(&mut lazy, -7.5e7),
                Access::Integer(_, set) => set(&mut lazy, 77),
                Access::Boolean(get, set) => {
                    let b = {
                        let mut probe = model.clone();
                        *probe.outputs.get_mut() = full;
                        probe.fresh.set(u8::MAX);
                        get(&probe)
                    };
                    set(&mut lazy, !b)
                }
                _ => {}
            }
        }
        *lazy.outputs.get_mut()
    };
    let mut checked = 0;
    for v in BenchPlantModel::variables() {
        if v.causality != Causality::Output {
            continue;
        }
        let mut lazy = model.clone();
        *lazy.outputs.get_mut() = sentinel;
        lazy.fresh.set(0);
        let mut reference = model.clone();
        *reference.outputs.get_mut() = full;
        reference.fresh.set(u8::MAX);
        match v.access {
            Access::Real(get, _) => assert_eq!(get(&lazy), get(&reference), "{}", v.name),
            Access::Integer(get, _) => assert_eq!(get(&lazy), get(&reference), "{}", v.name),
            Access::Boolean(get, _) => assert_eq!(get(&lazy), get(&reference), "{}", v.name),
            _ => continue,
        }
        checked += 1;
    }
    assert!(checked > 70, "{checked}");
    // A step makes every group stale again.
    let mut m = model.clone();
    let before = m.read_signal(SignalGroup::Motion, |o| o.actuation_angle);
    m.do_step(0.3, 1e-3).unwrap();
    let after = m.read_signal(SignalGroup::Motion, |o| o.actuation_angle);
    assert_ne!(before, after);
    assert_eq!(after, m.plant.as_ref().unwrap().outputs().actuation_angle);
}

/// Every Real output's derivative as `fmi2GetRealOutputDerivatives` reads it.
fn derivatives(m: &BenchPlantModel) -> Vec<f64> {
    real_output_references()
        .map(|vr| m.output_derivative(vr, 1).unwrap())
        .collect()
}

/// Every Real output's derivative computed afresh from the plant's current state.
fn current_derivatives(m: &BenchPlantModel) -> Vec<f64> {
    let rates = OutputRates {
        commands: BenchCommands::default(),
        rates: m.plant.as_ref().unwrap().output_derivatives(),
    };
    real_output_references()
        .map(|vr| RATE_READERS[vr as usize].unwrap()(&rates))
        .collect()
}

fn real_output_references() -> impl Iterator<Item = u32> {
    BenchPlantModel::variables().iter().filter_map(|v| {
        match (v.causality == Causality::Output, &v.access) {
            (true, Access::Real(..)) => Some(v.value_reference),
            _ => None,
        }
    })
}

/// The derivatives are evaluated once per communication point: read after a new input and a
/// step, or after an FMU state is restored, they are those of the new state, not the ones
/// read before.
#[test]
fn derivatives_read_again_after_a_step_or_a_restore_are_those_of_the_new_state() {
    let mut m = running();
    let saved = {
        let mut w = StateWriter::default();
        m.save_internal(&mut w);
        w.bytes
    };
    let before = derivatives(&m);
    assert_eq!(before.len(), 67);
    assert_eq!(before, current_derivatives(&m));
    assert_eq!(derivatives(&m), before, "read twice at one point");

    m.commands.test_current = -4.0;
    m.do_step(0.3, 1e-3).unwrap();
    let after = derivatives(&m);
    assert_eq!(after, current_derivatives(&m));
    let changed = before.iter().zip(&after).filter(|(b, a)| b != a).count();
    assert!(changed > 30, "{changed} derivatives changed over the step");

    m.load_internal(&mut StateReader::new(&saved)).unwrap();
    assert_eq!(derivatives(&m), before, "after the restore");
}

/// Every Real variable's value, by its bits.
fn reals(m: &BenchPlantModel) -> Vec<u64> {
    BenchPlantModel::variables()
        .iter()
        .filter_map(|v| match v.access {
            Access::Real(get, _) => Some(get(m).to_bits()),
            _ => None,
        })
        .collect()
}

/// A state taken while a tunable change waits for the next step restores the plant on the
/// values in force then (the outputs read as they did), and the change still reaches the
/// physics at the next step (found by `tests/tests/call_sequence_fuzz`: the plant was
/// rebuilt on the pending values, `offsetPower` 7 W before the restore, 500 W after).
#[test]
fn a_state_taken_with_a_change_pending_restores_the_values_in_force() {
    let mut m = running();
    let set_offset = BenchPlantModel::variables()
        .iter()
        .find_map(|v| match v.access {
            Access::Real(_, set) if v.name == "hardwareOffsetPower" => Some(set),
            _ => None,
        })
        .unwrap();
    let in_force = m.params.hardware_offset_power;
    set_offset(&mut m, in_force + 493.0);
    m.calculate(0.3).unwrap();
    let before = reals(&m);
    let saved = {
        let mut w = StateWriter::default();
        m.save_internal(&mut w);
        w.bytes
    };
    let mut twin = m.clone();

    m.do_step(0.3, 1e-3).unwrap();
    m.calculate(0.301).unwrap();
    assert_ne!(reals(&m), before, "the step applied the change");
    m.load_internal(&mut StateReader::new(&saved)).unwrap();
    m.calculate(0.3).unwrap();
    assert_eq!(reals(&m), before, "restored as taken");

    for model in [&mut m, &mut twin] {
        model.do_step(0.3, 1e-3).unwrap();
        model.calculate(0.301).unwrap();
    }
    assert_eq!(
        reals(&m),
        reals(&twin),
        "the pending change reaches the next step"
    );
    let offset_power = BenchPlantModel::variables()
        .iter()
        .find_map(|v| match v.access {
            Access::Real(get, _) if v.name == "offsetPower" => Some(get),
            _ => None,
        })
        .unwrap();
    assert_eq!(offset_power(&twin), in_force + 493.0);
}

/// Parameters the plant refuses at `fmi2ExitInitializationMode` leave the instance as it was,
/// its start time included (found by `tests/tests/call_sequence_fuzz`: the start time was
/// stored before the plant was built, so a refused exit changed the FMU state).
#[test]
fn a_refused_initialization_changes_nothing() {
    let mut m = crate::fmi2::instance::fresh_model::<BenchPlantModel>();
    m.params.load_cell_gain = 0.0;
    let saved = |m: &BenchPlantModel| {
        let mut w = StateWriter::default();
        m.save_internal(&mut w);
        w.bytes
    };
    let before = saved(&m);
    let e = m
        .initialize(5.0)
        .expect_err("a zero calibration gain is refused");
    assert!(
        e.is_refused() && e.message.contains("calibration gains"),
        "{e:?}"
    );
    assert_eq!(saved(&m), before);
}
