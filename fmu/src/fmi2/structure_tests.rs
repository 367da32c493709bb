//! The `ModelStructure/InitialUnknowns` of every model against what the instances do: in
//! initialization mode, each known (an input, or a parameter with `initial="exact"`) is set to
//! several other values, one fresh instance each, and every initial unknown whose value changes
//! must declare a dependency on that known, or on all knowns (no `dependencies` attribute,
//! FMI 2.0 section 2.2.8). `dependencies=""` claims the value depends on no known.

use model_description::{self as md, Causality, Initial, VariableKind};

use super::instance::FmiInstance;
use super::logging::Logger;
use super::types::fmi2Status::fmi2OK;

/// A value of any base type, compared bit for bit.
#[derive(Debug, Clone, PartialEq)]
enum Value {
    Real(u64),
    Integer(i32),
    Boolean(bool),
}

/// A value to give a known.
#[derive(Debug, Clone, Copy)]
enum Candidate {
    Real(f64),
    Integer(i32),
    Boolean(bool),
}

fn read(i: &mut dyn FmiInstance, v: &md::ScalarVariable) -> Option<Value> {
    let vr = [v.value_reference];
    match v.kind {
        VariableKind::Real { .. } => {
            let mut out = [0.0];
            (i.get_real(&vr, &mut out) == fmi2OK).then(|| Value::Real(out[0].to_bits()))
        }
        VariableKind::Integer { .. } | VariableKind::Enumeration { .. } => {
            let mut out = [0];
            (i.get_integer(&vr, &mut out) == fmi2OK).then_some(Value::Integer(out[0]))
        }
        VariableKind::Boolean { .. } => {
            let mut out = [0];
            (i.get_boolean(&vr, &mut out) == fmi2OK).then_some(Value::Boolean(out[0] != 0))
        }
        VariableKind::String { .. } => None,
    }
}

fn write(i: &mut dyn FmiInstance, vr: u32, c: Candidate) -> bool {
    match c {
        Candidate::Real(x) => i.set_real(&[vr], &[x]) == fmi2OK,
        Candidate::Integer(x) => i.set_integer(&[vr], &[x]) == fmi2OK,
        Candidate::Boolean(x) => i.set_boolean(&[vr], &[i32::from(x)]) == fmi2OK,
    }
}

/// Values other than the start value `x` inside the variable's bounds: nearby, far and at the
/// bounds (a dependency may show only away from the default, e.g. an offset multiplied by a
/// zero initial state elsewhere). Whole numbers for a Real that takes only those.
fn candidates(v: &md::ScalarVariable, d: &md::ModelDescription) -> Vec<Candidate> {
    match &v.kind {
        VariableKind::Real {
            attributes, start, ..
        } => {
            let x = start.unwrap_or(0.0);
            let lo = attributes.min.unwrap_or(-1e300);
            let hi = attributes.max.unwrap_or(1e300);
            let whole = v
                .description
                .as_deref()
                .is_some_and(|s| s.ends_with(crate::model::INTEGER_NOTE));
            let step = 0.37 * (x.abs() + 1.0);
            let mut out: Vec<f64> = Vec::new();
            for c in [
                x + step,
                x - step,
                2.0 * x,
                0.5 * x,
                (lo + x) / 2.0,
                (hi + x) / 2.0,
                lo,
                hi,
            ] {
                let c = if whole { c.round() } else { c };
                if c.is_finite() && c != x && (lo..=hi).contains(&c) && !out.contains(&c) {
                    out.push(c);
                }
            }
            out.into_iter().map(Candidate::Real).collect()
        }
        VariableKind::Integer { start, .. } => {
            let x = start.unwrap_or(0);
            let (lo, hi) = match d.items_of(v) {
                Some((_, items)) => (
                    items.iter().map(|i| i.value).min().unwrap_or(x),
                    items.iter().map(|i| i.value).max().unwrap_or(x),
                ),
                None => match &v.kind {
                    VariableKind::Integer { attributes, .. } => (
                        attributes.min.unwrap_or(x.saturating_sub(10)),
                        attributes.max.unwrap_or(x.saturating_add(10)),
                    ),
                    _ => unreachable!(),
                },
            };
            let mut out: Vec<i32> = Vec::new();
            // Every value of a mode (few), else nearby values and the bounds.
            let all: Vec<i32> = if hi - lo <= 8 {
                (lo..=hi).collect()
            } else {
                vec![
                    x.saturating_add(1),
                    x.saturating_sub(1),
                    x.saturating_mul(2),
                    lo,
                    hi,
                ]
            };
            for c in all {
                if c != x && (lo..=hi).contains(&c) && !out.contains(&c) {
                    out.push(c);
                }
            }
            out.into_iter().map(Candidate::Integer).collect()
        }
        VariableKind::Boolean { start, .. } => {
            vec![Candidate::Boolean(!start.unwrap_or(false))]
        }
        _ => Vec::new(),
    }
}

/// Every (initial unknown, known) pair where setting the known in initialization mode changed
/// the unknown although its `InitialUnknowns` entry does not declare the known.
fn undeclared(entry: &'static crate::registry::ModelEntry) -> Vec<String> {
    let d = &entry.info().description;
    let unknowns: Vec<(&md::ScalarVariable, Option<&Vec<u32>>)> = d
        .model_structure
        .initial_unknowns
        .iter()
        .map(|u| {
            (
                &d.model_variables[u.index as usize - 1],
                u.dependencies.as_ref(),
            )
        })
        .collect();
    let mut found = Vec::new();
    for (k, known) in d.model_variables.iter().enumerate() {
        let index = k as u32 + 1;
        let is_known = known.causality == Some(Causality::Input)
            || (known.causality == Some(Causality::Parameter)
                && known.initial == Some(Initial::Exact));
        if !is_known {
            continue;
        }
        for c in candidates(known, d) {
            let mut i = entry.instantiate(Logger::new(None, std::ptr::null_mut(), c"deps", false));
            assert_eq!(i.setup_experiment(0.0, None, None), fmi2OK);
            assert_eq!(
                i.enter_initialization_mode(),
                fmi2OK,
                "{}",
                entry.identifier
            );
            let before: Vec<Option<Value>> =
                unknowns.iter().map(|(u, _)| read(&mut *i, u)).collect();
            if !write(&mut *i, known.value_reference, c) {
                continue;
            }
            for ((u, deps), was) in unknowns.iter().zip(&before) {
                let now = read(&mut *i, u);
                let declared = deps.is_none_or(|d| d.contains(&index));
                if was.is_some() && now.is_some() && now != *was && !declared {
                    found.push(format!(
                        "{}.{} changed when {} was set to {c:?} (declared {:?})",
                        entry.identifier, u.name, known.name, deps
                    ));
                }
            }
        }
    }
    found
}

#[test]
fn every_initial_unknown_declares_the_knowns_that_change_it() {
    let mut found = Vec::new();
    for entry in crate::MODELS.iter() {
        found.extend(undeclared(entry));
    }
    assert!(
        found.is_empty(),
        "{} undeclared dependencies:\n{}",
        found.len(),
        found.join("\n")
    );
}

/// The plant's outputs hold its initial state, computed from every parameter (initial positions,
/// sensor calibrations, supplies, offsets): in initialization mode they depend on all knowns
/// (no `dependencies` attribute), at communication points on no input (`dependencies=""`: the
/// inputs act through the state).
#[test]
fn the_plant_declares_its_initial_unknowns_on_all_knowns() {
    let d = &crate::registry::find_by_identifier("BenchPlant")
        .unwrap()
        .info()
        .description;
    assert!(!d.model_structure.initial_unknowns.is_empty());
    for u in &d.model_structure.initial_unknowns {
        assert_eq!(u.dependencies, None, "{}", u.index);
        assert_eq!(u.dependencies_kind, None, "{}", u.index);
    }
    for u in &d.model_structure.outputs {
        assert_eq!(u.dependencies.as_deref(), Some(&[][..]), "{}", u.index);
    }
    let xml = &crate::registry::find_by_identifier("BenchPlant")
        .unwrap()
        .info()
        .xml;
    let initial = &xml[xml.find("<InitialUnknowns>").unwrap()..];
    let initial = &initial[..initial.find("</InitialUnknowns>").unwrap()];
    assert!(!initial.contains("dependencies"), "{initial}");
}
