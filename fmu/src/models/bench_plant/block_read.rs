//! The plant's block read of its Real outputs ([`Model::read_reals`]): the fast path of
//! `fmi2GetReal` for this model.
//!
//! Through the getters, each value costs a table lookup, an indirect call, its group's
//! freshness test and a borrow of the outputs: about 14 instructions, for the 67 outputs
//! an importer recording every one reads at every step. A master asks for the same list at
//! every step, so the block read resolves a list once ([`ReadPlan`]: each reference's index
//! in [`BenchOutputs::reals`](crate::models::bench::BenchOutputs::reals) and the groups the
//! list needs) and, while the list is the same, compares it, tests the groups once, borrows
//! once and copies each value by its index. Callgrind, `closed_loop`: every output 9,519 ->
//! 8,784 instructions per step, the analysed signals 6,809 -> 6,673 (docs/performance.md,
//! stop 39).
//!
//! Where each output sits is found from the variables' own accessors, not from a second
//! list: a model whose outputs are all fresh gets a marker through the output's setter (the
//! index is the one double that changed), and a model whose outputs are all stale reads it
//! through the getter (the group is the one freshness bit the read set; the value must be
//! the marker). An output whose accessors do not read one double of one group has no slot,
//! and a call naming it (or any other variable) takes the getters. Test
//! `the_block_read_is_the_getters_bit_for_bit`.

use super::BenchPlantModel;
use crate::model::{Access, Model};
use crate::models::bench::{REAL_OUTPUTS, SignalGroup};
use crate::release::Lazy;
use model_description::Causality;

/// Where a Real output's value is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Slot {
    /// Its index in [`BenchOutputs::reals`](crate::models::bench::BenchOutputs::reals).
    index: u8,
    /// The [`SignalGroup::bit`] of the group that computes it.
    group: u8,
}

const _: () = assert!(REAL_OUTPUTS <= u8::MAX as usize);

/// The slot of each Real output, indexed by value reference (`None` for any other value
/// reference, and for an output that has none).
fn slots() -> Vec<Option<Slot>> {
    let mut table = Vec::new();
    for v in BenchPlantModel::variables() {
        if v.causality != Causality::Output {
            continue;
        }
        let Access::Real(get, set) = v.access else {
            continue;
        };
        if let Some(slot) = probe(get, set) {
            let vr = v.value_reference as usize;
            if table.len() <= vr {
                table.resize(vr + 1, None);
            }
            table[vr] = Some(slot);
        }
    }
    table
}

/// The slot the accessors `get` and `set` of one Real output use (module docs).
fn probe(get: fn(&BenchPlantModel) -> f64, set: fn(&mut BenchPlantModel, f64)) -> Option<Slot> {
    // A value no output holds by default (they are all zero in a model never built).
    const MARKER: f64 = -1.234_567_890_123e-7;
    let mut model = BenchPlantModel::default();
    set(&mut model, MARKER);
    let marked: Vec<usize> = {
        let outputs = model.outputs.borrow();
        let reals = outputs.reals();
        (0..REAL_OUTPUTS)
            .filter(|&i| reals[i].to_bits() == MARKER.to_bits())
            .collect()
    };
    let [index] = marked[..] else {
        return None;
    };
    // Every group stale: the read computes its own (with no plant built, only its bit is set)
    // and must read the marker.
    model.fresh.set(0);
    let read = get(&model);
    let group = model.fresh.get();
    let one_group = SignalGroup::ALL.iter().any(|g| g.bit() == group);
    (one_group && read.to_bits() == MARKER.to_bits()).then_some(Slot {
        index: index as u8,
        group,
    })
}

// SAFETY: a static (Lazy registers its address for the release at unload).
static SLOTS: Lazy<Vec<Option<Slot>>> = unsafe { Lazy::new(slots) };

/// The shortest list read as a block: a block read has a fixed cost (the plan's borrow, the
/// list's comparison, the groups' test, the outputs' borrow) that a short list does not repay
/// (`plant_abi`'s two angles per step: 2,485 -> 2,555 instructions per step through the block
/// read, callgrind); a shorter list takes the getters.
const BLOCK_READ_FROM: usize = 8;

/// The reference list of the last block read, resolved (module docs).
#[derive(Debug, Clone, Default)]
pub(super) struct ReadPlan {
    /// The value references, as last asked for.
    vrs: Vec<u32>,
    /// Whether each of them has a slot (else the getters read the list).
    covered: bool,
    /// The index of each in `BenchOutputs::reals` (when `covered`).
    indices: Vec<u8>,
    /// The [`SignalGroup::bit`]s of the groups they need (when `covered`).
    groups: u8,
    /// `indices` as runs of consecutive indices (when `covered`), or empty where the list has
    /// too many runs for copying them to pay ([`runs_pay`]).
    runs: Vec<Run>,
}

/// Consecutive outputs read into consecutive places: `len` values from index `from` of
/// `BenchOutputs::reals` into the call's values from `to`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Run {
    from: u8,
    to: u8,
    len: u8,
}

/// Whether copying `runs` runs pays for a list of `values` values. A list read in declaration
/// order (every output, as a recording master asks for them) is one or a few runs: each is one
/// slice copy instead of a load, a bounds check and a store per value. A scattered list (many
/// runs of one) is copied value by value: a copy per run would cost more there.
fn runs_pay(runs: usize, values: usize) -> bool {
    runs * 4 <= values
}

/// The runs of consecutive indices in `indices`.
fn runs_of(indices: &[u8]) -> Vec<Run> {
    let mut runs: Vec<Run> = Vec::new();
    for (to, &from) in indices.iter().enumerate() {
        match runs.last_mut() {
            Some(run)
                if usize::from(run.from) + usize::from(run.len) == usize::from(from)
                    && run.len < u8::MAX =>
            {
                run.len += 1;
            }
            _ => runs.push(Run {
                from,
                to: to as u8,
                len: 1,
            }),
        }
    }
    runs
}

impl ReadPlan {
    /// Resolves `vrs`: `covered` if each of them has a slot. A list that is not is
    /// remembered too, so that asking for it again costs the comparison alone.
    fn resolve(&mut self, vrs: &[u32]) {
        self.vrs.clear();
        self.vrs.extend_from_slice(vrs);
        self.indices.clear();
        self.runs.clear();
        self.groups = 0;
        let slots = &SLOTS[..];
        self.covered = vrs.iter().all(|&vr| match slots.get(vr as usize) {
            Some(Some(slot)) => {
                self.indices.push(slot.index);
                self.groups |= slot.group;
                true
            }
            _ => false,
        });
        // A list longer than a run can say where it goes (`Run::to`) is copied value by value.
        if self.covered && vrs.len() <= usize::from(u8::MAX) {
            let runs = runs_of(&self.indices);
            if runs_pay(runs.len(), self.indices.len()) {
                self.runs = runs;
            }
        }
    }
}

impl BenchPlantModel {
    /// [`Model::read_reals`] for the plant (module docs): `false` for a list shorter than
    /// [`BLOCK_READ_FROM`] or naming a reference that has no slot. The length test is inlined
    /// into the glue's get, so a short list pays no call for it.
    #[inline]
    pub(super) fn read_output_block(&self, vrs: &[u32], out: &mut [f64]) -> bool {
        vrs.len() >= BLOCK_READ_FROM && self.read_long_list(vrs, out)
    }

    /// [`Self::read_output_block`] of a list of [`BLOCK_READ_FROM`] references or more.
    #[inline(never)]
    fn read_long_list(&self, vrs: &[u32], out: &mut [f64]) -> bool {
        if out.len() != vrs.len() {
            return false;
        }
        let mut plan = self.read_plan.borrow_mut();
        if plan.vrs[..] != *vrs {
            plan.resolve(vrs);
        }
        if !plan.covered {
            return false;
        }
        let stale = plan.groups & !self.fresh.get();
        if stale != 0 {
            for group in SignalGroup::ALL {
                if stale & group.bit() != 0 {
                    self.compute_group(group);
                }
            }
        }
        let outputs = self.outputs.borrow();
        let reals = outputs.reals();
        if plan.runs.is_empty() {
            for (o, &index) in out.iter_mut().zip(&plan.indices) {
                *o = reals[usize::from(index)];
            }
        } else {
            for run in &plan.runs {
                let (from, to, len) = (
                    usize::from(run.from),
                    usize::from(run.to),
                    usize::from(run.len),
                );
                out[to..to + len].copy_from_slice(&reals[from..from + len]);
            }
        }
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::models::bench_plant::lazy_output_tests::running_in;

    /// A Real output's value reference, name and getter.
    type RealOutput = (u32, &'static str, fn(&BenchPlantModel) -> f64);

    /// The Real outputs of the plant.
    fn real_outputs() -> Vec<RealOutput> {
        BenchPlantModel::variables()
            .iter()
            .filter(|v| v.causality == Causality::Output)
            .filter_map(|v| match v.access {
                Access::Real(get, _) => Some((v.value_reference, v.name, get)),
                _ => None,
            })
            .collect()
    }

    /// Every Real output has a slot, each its own double.
    #[test]
    fn every_real_output_has_a_slot_of_its_own() {
        let outputs = real_outputs();
        assert!(outputs.len() > 60, "{}", outputs.len());
        let mut indices = Vec::new();
        for (vr, name, _) in &outputs {
            let slot = SLOTS
                .get(*vr as usize)
                .copied()
                .flatten()
                .unwrap_or_else(|| panic!("{name} has no slot"));
            indices.push(slot.index);
        }
        indices.sort_unstable();
        indices.dedup();
        assert_eq!(indices.len(), outputs.len(), "two outputs share a double");
    }

    /// Runs join consecutive indices only, and each value lands where its index says.
    #[test]
    fn runs_are_the_consecutive_stretches_of_the_indices() {
        let runs = runs_of(&[3, 4, 5, 9, 2, 3, 3]);
        let run = |from, to, len| Run { from, to, len };
        assert_eq!(
            runs,
            vec![run(3, 0, 3), run(9, 3, 1), run(2, 4, 2), run(3, 6, 1)]
        );
        assert!(runs_of(&[]).is_empty());
        assert!(runs_pay(2, 8) && !runs_pay(3, 8));
    }

    /// The outputs asked for in declaration order (a recording master's list) are copied as
    /// runs, a scattered list value by value: both paths of the block read are taken (and the
    /// test below compares each with the getters).
    #[test]
    fn a_list_in_declaration_order_is_copied_as_runs() {
        let all: Vec<u32> = real_outputs().iter().map(|o| o.0).collect();
        let mut plan = ReadPlan::default();
        plan.resolve(&all);
        assert!(plan.covered);
        assert!(
            !plan.runs.is_empty() && plan.runs.len() * 4 <= all.len(),
            "{} runs for {} outputs",
            plan.runs.len(),
            all.len()
        );
        let scattered: Vec<u32> = (0..all.len())
            .map(|k| all[(k * 37 + 11) % all.len()])
            .collect();
        plan.resolve(&scattered);
        assert!(plan.covered && plan.runs.is_empty());
        // Longer than a run's place can say: covered, copied by index.
        let long: Vec<u32> = all.iter().cycle().take(300).copied().collect();
        plan.resolve(&long);
        assert!(plan.covered && plan.runs.is_empty());
        let model = running_in(1);
        let mut block = vec![f64::NAN; long.len()];
        assert!(model.read_output_block(&long, &mut block));
        let getters = real_outputs();
        for (vr, value) in long.iter().zip(&block) {
            let (_, name, get) = getters.iter().find(|o| o.0 == *vr).unwrap();
            assert_eq!(value.to_bits(), get(&model).to_bits(), "{name}");
        }
    }

    /// The block read equals the getters bit for bit: every output, in each configuration,
    /// mid-run and right after a step (every group stale), read all at once, in reverse, in a
    /// scattered order of repeats and in lists of the shortest length read as a block; a
    /// shorter list, or one naming anything else, is left to the getters.
    #[test]
    fn the_block_read_is_the_getters_bit_for_bit() {
        let outputs = real_outputs();
        let getter = |vr: u32| outputs.iter().find(|o| o.0 == vr).unwrap();
        // `vrs` read as a block on a copy of `model`, against each getter on another copy.
        let check = |model: &BenchPlantModel, vrs: &[u32], what: &str| {
            let mut block = vec![f64::NAN; vrs.len()];
            assert!(model.clone().read_output_block(vrs, &mut block), "{what}");
            let plain = model.clone();
            for (k, vr) in vrs.iter().enumerate() {
                let (_, name, get) = getter(*vr);
                assert_eq!(block[k].to_bits(), get(&plain).to_bits(), "{what}: {name}");
            }
        };
        for configuration in 0..3 {
            let mut model = running_in(configuration);
            for step in 0..3 {
                if step > 0 {
                    model.do_step(0.3 + step as f64 * 1e-3, 1e-3).unwrap();
                    model.calculate(0.3 + step as f64 * 1e-3).unwrap();
                }
                let all: Vec<u32> = outputs.iter().map(|o| o.0).collect();
                let reversed: Vec<u32> = all.iter().rev().copied().collect();
                let scattered: Vec<u32> = (0..all.len() * 2)
                    .map(|k| all[(k * 37 + 11) % all.len()])
                    .collect();
                let mut calls = vec![all.clone(), reversed, scattered];
                calls.extend(all.chunks_exact(BLOCK_READ_FROM).map(<[u32]>::to_vec));
                // Each call on a model as the step left it, so every group's first read is in
                // the call.
                for vrs in &calls {
                    check(
                        &model,
                        vrs,
                        &format!("configuration {configuration}, step {step}"),
                    );
                }
                // Values and references of different lengths: left to the getters.
                assert!(
                    !model
                        .clone()
                        .read_output_block(&all, &mut vec![0.0; all.len() - 1])
                );
                let short = &all[..BLOCK_READ_FROM - 1];
                assert!(!model.clone().read_output_block(short, &mut [0.0; 7]));
            }
            // Any other reference: the getters' path (which refuses an unknown one).
            let parameter = BenchPlantModel::variables()
                .iter()
                .find(|v| {
                    v.causality == Causality::Parameter && matches!(v.access, Access::Real(..))
                })
                .unwrap()
                .value_reference;
            let first: Vec<u32> = outputs[..BLOCK_READ_FROM].iter().map(|o| o.0).collect();
            let with = |extra: u32| [&first[..], &[extra]].concat();
            let mut out = vec![0.0; BLOCK_READ_FROM + 1];
            assert!(!model.read_output_block(&with(parameter), &mut out));
            assert!(!model.read_output_block(&with(u32::MAX), &mut out));
            // After a refused list, and after another list, a list is read afresh.
            let reversed: Vec<u32> = first.iter().rev().copied().collect();
            for _ in 0..2 {
                check(&model, &reversed, "after a refused list");
                assert!(!model.read_output_block(&with(parameter), &mut out));
                check(&model, &first, "after a refused list");
                check(&model, &reversed, "after another list");
            }
        }
    }
}
