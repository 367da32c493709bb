//! The master's recorded rows when it records every output (its default), against a plain
//! reference gather: the same FMUs driven through the public `Instance` API, each output read
//! with an `fmi2Get*` call of its own after every step and written to its column as the
//! recording rule says (`Real` as it is, `Integer` as a double, `Boolean` as 0.0 or 1.0). The
//! master reads each component's outputs of one type in one call onto its bus and builds the
//! row by copies planned once per run (`master::plan::RowCopies`, `Instance::get_outputs`):
//! the rows must be the same bit for bit, in this process and with every instance in a host
//! process of its own.
//!
//! The system: the gait reference (`Real` and `Boolean` outputs) and the bench plant (`Real`,
//! `Boolean` and `Integer` outputs, in an interleaved order), unconnected, so the reference
//! needs no input propagation; the plant is driven by its parameters' defaults.

use kneebench_harness::time::Grid;
use kneebench_harness::{
    Fmu, Instance, InstanceOptions, Isolation, LoadOptions, Outcome, RunConfig, System,
};
use kneebench_tests::exported_fmu;
use model_description::{Causality, VariableKind};

const COMPONENTS: [(&str, &str); 2] = [("gait", "GaitReference"), ("plant", "BenchPlant")];

/// One recorded column: the component's index, the value reference and its type.
#[derive(Clone, Copy)]
enum Column {
    Real(usize, u32),
    Integer(usize, u32),
    Boolean(usize, u32),
}

fn load(identifier: &str, isolation: Isolation) -> Fmu {
    let options = LoadOptions {
        isolation,
        ..LoadOptions::default()
    };
    Fmu::load(exported_fmu(identifier), &options).unwrap()
}

/// Every output of every component, in declaration order (the master's default columns).
fn columns(fmus: &[Fmu]) -> Vec<Column> {
    let mut out = Vec::new();
    for (c, fmu) in fmus.iter().enumerate() {
        for v in &fmu.model_description().model_variables {
            if v.causality != Some(Causality::Output) {
                continue;
            }
            let vr = v.value_reference;
            out.push(match v.kind {
                VariableKind::Real { .. } => Column::Real(c, vr),
                VariableKind::Integer { .. } | VariableKind::Enumeration { .. } => {
                    Column::Integer(c, vr)
                }
                VariableKind::Boolean { .. } => Column::Boolean(c, vr),
                VariableKind::String { .. } => continue,
            });
        }
    }
    out
}

/// The row of the instances' current outputs, one `fmi2Get*` call per value.
fn reference_row(instances: &mut [Instance], columns: &[Column]) -> Vec<f64> {
    columns
        .iter()
        .map(|&c| match c {
            Column::Real(i, vr) => {
                let mut v = [0.0];
                instances[i].get_real(&[vr], &mut v).unwrap();
                v[0]
            }
            Column::Integer(i, vr) => {
                let mut v = [0];
                instances[i].get_integer(&[vr], &mut v).unwrap();
                f64::from(v[0])
            }
            Column::Boolean(i, vr) => {
                let mut v = [false];
                instances[i].get_boolean(&[vr], &mut v).unwrap();
                if v[0] { 1.0 } else { 0.0 }
            }
        })
        .collect()
}

/// The reference run: initialization, row 0, then per step every instance stepped and the
/// row read; time first in every row.
fn reference(fmus: &[Fmu], config: &RunConfig, columns: &[Column]) -> Vec<Vec<f64>> {
    let grid = Grid::new(config.start_time, config.stop_time, config.step_size).unwrap();
    let mut instances: Vec<Instance> = fmus
        .iter()
        .zip(COMPONENTS)
        .map(|(f, (name, _))| f.instantiate(name, &InstanceOptions::default()).unwrap())
        .collect();
    for inst in &mut instances {
        inst.setup_experiment(None, grid.start, Some(grid.stop()))
            .unwrap();
        inst.enter_initialization_mode().unwrap();
    }
    for inst in &mut instances {
        inst.exit_initialization_mode().unwrap();
    }
    let row = |t: f64, instances: &mut [Instance]| {
        let mut r = vec![t];
        r.extend(reference_row(instances, columns));
        r
    };
    let mut rows = vec![row(grid.time(0), &mut instances)];
    for n in 0..grid.n_steps {
        for inst in &mut instances {
            inst.do_step(grid.time(n), grid.step()).unwrap();
        }
        rows.push(row(grid.time(n + 1), &mut instances));
    }
    for inst in &mut instances {
        inst.terminate().unwrap();
    }
    rows
}

fn bits(rows: &[Vec<f64>]) -> Vec<Vec<u64>> {
    rows.iter()
        .map(|r| r.iter().map(|v| v.to_bits()).collect())
        .collect()
}

#[test]
fn rows_of_every_output_are_the_per_value_reads_bit_for_bit() {
    let config = RunConfig {
        stop_time: 1.5,
        step_size: 1e-3,
        ..RunConfig::default()
    };
    for isolation in [Isolation::InProcess, Isolation::Process] {
        let fmus: Vec<Fmu> = COMPONENTS
            .iter()
            .map(|(_, id)| load(id, isolation))
            .collect();
        let columns = columns(&fmus);
        let mut system = System::new();
        for ((name, _), fmu) in COMPONENTS.iter().zip(&fmus) {
            system.add_component(name, fmu.clone()).unwrap();
        }
        let out = system.run(&config).unwrap();
        assert!(
            matches!(out.outcome, Outcome::Completed { .. }),
            "{:?}",
            out.outcome
        );
        assert_eq!(out.results.names().len(), columns.len());
        let master: Vec<Vec<f64>> = out.results.rows().map(<[f64]>::to_vec).collect();
        let reference = reference(&fmus, &config, &columns);
        assert_eq!(master.len(), 1501);
        // The case is not trivial: every type is recorded, types interleave, and the
        // Booleans and Integers take more than one value.
        let kinds = |pick: fn(&Column) -> bool| -> Vec<usize> {
            (0..columns.len()).filter(|&k| pick(&columns[k])).collect()
        };
        let booleans = kinds(|c| matches!(c, Column::Boolean(..)));
        let integers = kinds(|c| matches!(c, Column::Integer(..)));
        assert!(!booleans.is_empty() && !integers.is_empty());
        assert!(
            booleans
                .iter()
                .any(|&k| reference.iter().any(|r| r[k + 1] != reference[0][k + 1])),
            "no Boolean output changes"
        );
        assert_eq!(
            bits(&master),
            bits(&reference),
            "isolation {isolation:?}: the master's rows differ from the per-value reads"
        );
    }
}
