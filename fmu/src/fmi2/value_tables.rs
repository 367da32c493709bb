//! The per-value-reference tables behind get and set: one getter per Real, Integer and
//! Boolean variable, and one setter per Real and Boolean variable with the conditions a value
//! must meet (the phases it may be set in, its bounds, a whole number where the declaration
//! says so). Built once per model type from its one declaration ([`Model::variables`]), so
//! that a get or a set is an index and a call, with no search.

use crate::model::{Access, Model, Phase, Variable};

/// Reads one Real variable of a model.
pub(super) type RealGetter<M> = fn(&M) -> f64;
/// Reads one Integer or Enumeration variable of a model.
pub(super) type IntegerGetter<M> = fn(&M) -> i32;
/// Reads one Boolean variable of a model.
pub(super) type BooleanGetter<M> = fn(&M) -> bool;

/// The entries `pick` makes of the variables of `M` (getters, setters with their conditions),
/// indexed by value reference (value references are per base type, so each type has its own
/// table).
pub(super) fn vr_table<M: Model, E>(pick: impl Fn(&Variable<M>) -> Option<E>) -> Vec<Option<E>> {
    let mut table = Vec::new();
    for v in M::variables() {
        if let Some(entry) = pick(v) {
            let vr = v.value_reference as usize;
            if table.len() <= vr {
                table.resize_with(vr + 1, || None);
            }
            table[vr] = Some(entry);
        }
    }
    table
}

/// The Real getters of `M` indexed by value reference.
pub(super) fn real_getter_table<M: Model>() -> Vec<Option<RealGetter<M>>> {
    vr_table::<M, _>(|v| match v.access {
        Access::Real(get, _) => Some(get),
        _ => None,
    })
}

/// The Integer and Enumeration getters of `M` indexed by value reference.
pub(super) fn integer_getter_table<M: Model>() -> Vec<Option<IntegerGetter<M>>> {
    vr_table::<M, _>(|v| match v.access {
        Access::Integer(get, _) | Access::Enumeration(get, _) => Some(get),
        _ => None,
    })
}

/// The Boolean getters of `M` indexed by value reference.
pub(super) fn boolean_getter_table<M: Model>() -> Vec<Option<BooleanGetter<M>>> {
    vr_table::<M, _>(|v| match v.access {
        Access::Boolean(get, _) => Some(get),
        _ => None,
    })
}

/// A Real variable's setter and the conditions of a valid set: the table entry of the fast
/// path of `fmi2SetReal`, whose verdict ([`RealSetter::accepts`]) equals the checking path's
/// (settable in the phase, and no [`range_problem`](super::instance::range_problem)) for every value (test
/// `the_real_setters_accept_what_the_checking_path_accepts`).
pub(super) struct RealSetter<M> {
    pub(super) set: fn(&mut M, f64),
    /// The variable's min, at least `-f64::MAX`: `low <= x` is false for NaN and -inf.
    low: f64,
    /// The variable's max, at most `f64::MAX`: `x <= high` is false for NaN and +inf.
    high: f64,
    /// Bit `1 << phase_index(p)` set: settable in phase `p`, any value in range (0 for a value
    /// reference that is no Real variable: such an entry accepts nothing).
    any_value: u8,
    /// Bit `1 << phase_index(p)` set: settable in phase `p`, whole numbers only
    /// ([`Variable::integer_valued`]).
    whole_only: u8,
}

/// Index of `phase` in the `phases` of a setter table entry.
#[inline]
pub(super) fn phase_index(phase: Phase) -> usize {
    match phase {
        Phase::Instantiated => 0,
        Phase::Initialization => 1,
        Phase::Stepping => 2,
    }
}

/// Whether `v` may be set in [instantiated, initialization, stepping].
pub(super) fn settable_phases<M>(v: &Variable<M>) -> [bool; 3] {
    [
        v.settable(Phase::Instantiated),
        v.settable(Phase::Initialization),
        v.settable(Phase::Stepping),
    ]
}

impl<M> RealSetter<M> {
    /// The entry of a value reference that is no Real variable: it accepts nothing, so a set
    /// naming it takes the checking path, which names the problem.
    fn refusing() -> Self {
        Self {
            set: |_, _| {},
            low: f64::INFINITY,
            high: f64::NEG_INFINITY,
            any_value: 0,
            whole_only: 0,
        }
    }

    /// Whether `x` may be set now (phase index `phase`, [`phase_index`]): settable in the
    /// phase, finite, within the bounds and whole if it must be (the bounds' clamping to the
    /// finite doubles makes the two comparisons the finiteness check too). A variable that
    /// takes any value in range pays one bit test and the two comparisons.
    #[inline(always)]
    pub(super) fn accepts(&self, phase: usize, x: f64) -> bool {
        let bit = 1u8 << phase;
        let in_range = self.low <= x && x <= self.high;
        if self.any_value & bit != 0 {
            return in_range;
        }
        self.whole_only & bit != 0 && in_range && is_whole(x)
    }
}

/// Whether the finite `x` is a whole number, `x.fract() == 0.0`, without the call to `trunc`
/// that `fract` compiles to on x86-64 without SSE4.1 (in the setters' check LLVM evaluated it
/// for every value, whole-number variable or not: ~19 instructions per value). Every double
/// of magnitude 2^52 or more is whole; below it, the conversion to `i64` truncates exactly.
#[inline]
pub(super) fn is_whole(x: f64) -> bool {
    x.abs() >= 4_503_599_627_370_496.0 || (x as i64) as f64 == x
}

#[cfg(test)]
mod whole_number_tests {
    use super::is_whole;

    /// `is_whole` is `fract() == 0.0` for finite values: zeros of both signs, halves, values
    /// next to 2^52 and 2^53 on either side, the largest and the subnormal doubles.
    #[test]
    fn is_whole_is_a_zero_fraction() {
        let two52 = 4_503_599_627_370_496.0f64;
        let mut values = vec![
            0.0,
            -0.0,
            0.5,
            -0.5,
            1.0,
            -1.0,
            3.0,
            2.5,
            1e-300,
            f64::MIN_POSITIVE / 4.0,
            f64::MAX,
            f64::MIN,
            1e300,
            i64::MAX as f64,
            i64::MIN as f64,
            1e19,
            -1e19,
        ];
        for base in [two52, 2.0 * two52] {
            for v in [base, base - 0.5, base - 1.0, base + 1.0, base - 1.5] {
                values.push(v);
                values.push(-v);
                values.push(f64::from_bits(v.to_bits() - 1));
                values.push(f64::from_bits(v.to_bits() + 1));
            }
        }
        let mut whole = 0;
        for x in values {
            assert_eq!(is_whole(x), x.fract() == 0.0, "{x:e}");
            whole += usize::from(is_whole(x));
        }
        assert!(whole > 10, "{whole}");
    }
}

#[cfg(test)]
mod real_setter_tests {
    use super::*;
    use crate::fmi2::instance::range_problem;
    use crate::models::{
        bench_hardware::BenchHardwareModel, bench_plant::BenchPlantModel,
        clutch_scheduler::ClutchScheduler, gait::GaitReference, impedance::ImpedanceController,
        pid::PidController,
    };

    /// Values around every edge the checks have: NaN, the infinities, the largest doubles,
    /// zeros, fractions, and each bound with its neighbours.
    fn probes<M>(v: &Variable<M>) -> Vec<f64> {
        let mut xs = vec![
            f64::NAN,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::MAX,
            f64::MIN,
            0.0,
            -0.0,
            0.5,
            -2.5,
            1.0,
            -1.0,
            3.0,
            1e-300,
            1e300,
            -1e300,
        ];
        for b in [v.min, v.max].into_iter().flatten() {
            if b.is_finite() {
                xs.extend([b, b.next_up(), b.next_down(), b + 0.5, b - 0.5]);
            }
        }
        xs
    }

    /// The table's verdict is the checking path's (settable in the phase, no range problem)
    /// for every Real variable, phase and probe; a value reference that is no Real variable
    /// accepts nothing.
    fn fast_path_is_the_checking_path<M: Model>() -> usize {
        let table = real_setter_table::<M>();
        let mut checked = 0;
        for v in M::variables() {
            if !matches!(v.access, Access::Real(..)) {
                continue;
            }
            let e = &table[v.value_reference as usize];
            for phase in [Phase::Instantiated, Phase::Initialization, Phase::Stepping] {
                for x in probes(v) {
                    let plain = v.settable(phase) && range_problem(v, x).is_none();
                    assert_eq!(
                        e.accepts(phase_index(phase), x),
                        plain,
                        "{} {} = {x:e} in {phase:?}",
                        M::IDENTIFIER,
                        v.name
                    );
                    checked += usize::from(plain);
                }
            }
        }
        let real = |vr: usize| {
            M::variables()
                .iter()
                .any(|v| v.value_reference as usize == vr && matches!(v.access, Access::Real(..)))
        };
        for (vr, e) in table.iter().enumerate().filter(|(vr, _)| !real(*vr)) {
            for phase in 0..3 {
                for x in [0.0, 1.0, -1.0] {
                    assert!(!e.accepts(phase, x), "{} vr {vr}", M::IDENTIFIER);
                }
            }
        }
        checked
    }

    #[test]
    fn the_real_setters_accept_what_the_checking_path_accepts() {
        let accepted = [
            fast_path_is_the_checking_path::<GaitReference>(),
            fast_path_is_the_checking_path::<BenchPlantModel>(),
            fast_path_is_the_checking_path::<BenchHardwareModel>(),
            fast_path_is_the_checking_path::<PidController>(),
            fast_path_is_the_checking_path::<ImpedanceController>(),
            fast_path_is_the_checking_path::<ClutchScheduler>(),
        ];
        // Each model has Real variables that accept some probes.
        assert!(accepted.iter().all(|&n| n > 10), "{accepted:?}");
    }
}

/// A Boolean variable's setter and the phases it may be set in (any value is valid).
pub(super) struct BooleanSetter<M> {
    pub(super) set: fn(&mut M, bool),
    /// Settable in [instantiated, initialization, stepping].
    pub(super) phases: [bool; 3],
}

/// The Boolean setters of `M` indexed by value reference.
pub(super) fn boolean_setter_table<M: Model>() -> Vec<Option<BooleanSetter<M>>> {
    vr_table::<M, _>(|v| match v.access {
        Access::Boolean(_, set) => Some(BooleanSetter {
            set,
            phases: settable_phases(v),
        }),
        _ => None,
    })
}

/// The Real setters of `M` indexed by value reference (a [`RealSetter::refusing`] entry where
/// a value reference is no Real variable).
pub(super) fn real_setter_table<M: Model>() -> Vec<RealSetter<M>> {
    vr_table::<M, _>(|v| match v.access {
        Access::Real(_, set) => {
            let phases = settable_phases(v)
                .iter()
                .enumerate()
                .fold(0u8, |bits, (i, &settable)| bits | (u8::from(settable) << i));
            Some(RealSetter {
                set,
                low: v.min.unwrap_or(f64::NEG_INFINITY).max(-f64::MAX),
                high: v.max.unwrap_or(f64::INFINITY).min(f64::MAX),
                any_value: if v.integer_valued { 0 } else { phases },
                whole_only: if v.integer_valued { phases } else { 0 },
            })
        }
        _ => None,
    })
    .into_iter()
    .map(|e| e.unwrap_or_else(RealSetter::refusing))
    .collect()
}
