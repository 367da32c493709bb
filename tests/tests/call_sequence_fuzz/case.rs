//! One case: the fuzzed instance with its oracle, what an importer can read of it, the
//! running and checking of each call, and the final recovery.

use std::ffi::c_int;
use std::ptr::{null, null_mut};

use kneebench_tests::*;

use fmi2Status::{fmi2Error, fmi2OK};

use crate::calls::{Call, Ref};
use crate::library::{Library, Meta, Ty, live, meta};
use crate::oracle::{F, Machine, S, allowed};
use crate::{SLOTS, UNKNOWN_VR, needs_a_bench_link};

// ---------------------------------------------------------------------------------------------
// Observation: everything an importer can read of an instance.

/// The readable variables of an instance by type (statuses and values; f64 by bits) and its
/// serialized FMU state (for models that provide one).
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) struct Observation {
    /// Gets of every variable of each type, in declaration order (none where no get is
    /// allowed).
    pub(crate) reals: Option<(c_int, Vec<u64>)>,
    pub(crate) integers: Option<(c_int, Vec<i32>)>,
    pub(crate) booleans: Option<(c_int, Vec<i32>)>,
    pub(crate) strings: Option<(c_int, Vec<String>)>,
    /// The serialized FMU state.
    bytes: Option<Vec<u8>>,
}

impl Observation {
    /// Where two observations differ, briefly.
    pub(crate) fn difference(&self, other: &Observation) -> String {
        let mut out = Vec::new();
        if self.reals != other.reals {
            out.push(format!("reals {:?} -> {:?}", self.reals, other.reals));
        }
        if self.integers != other.integers {
            out.push(format!(
                "integers {:?} -> {:?}",
                self.integers, other.integers
            ));
        }
        if self.booleans != other.booleans {
            out.push(format!(
                "booleans {:?} -> {:?}",
                self.booleans, other.booleans
            ));
        }
        if self.strings != other.strings {
            out.push(format!("strings {:?} -> {:?}", self.strings, other.strings));
        }
        if self.bytes != other.bytes {
            let (a, b) = (
                self.bytes.as_deref().unwrap_or(&[]),
                other.bytes.as_deref().unwrap_or(&[]),
            );
            let at = a.iter().zip(b).position(|(x, y)| x != y);
            out.push(format!(
                "state bytes ({} -> {} bytes, first difference at {at:?})",
                a.len(),
                b.len()
            ));
        }
        out.join("; ")
    }

    /// Whether the model's outputs could be computed (a get of every Real answered OK).
    pub(crate) fn computes(&self) -> bool {
        self.reals.as_ref().is_some_and(|(s, _)| *s == 0)
    }
}

// ---------------------------------------------------------------------------------------------
// One case.

/// What a state slot holds.
#[derive(Debug, Clone)]
pub(crate) enum Slot {
    Null,
    /// A live state of `model`, taken from an instance the oracle knew as `machine`, which
    /// read as `observation` then (when taken from the fuzzed instance).
    Live {
        model: &'static str,
        machine: Machine,
        observation: Option<Observation>,
    },
    /// A freed state's address.
    Dead,
    /// A non-NULL pointer this binary never made.
    Never,
}

/// Serialized bytes and what they hold.
#[derive(Clone)]
pub(crate) struct Blob {
    pub(crate) bytes: Vec<u8>,
    pub(crate) model: &'static str,
    pub(crate) machine: Machine,
    pub(crate) observation: Option<Observation>,
}

/// What the status of a call may be.
#[derive(Debug)]
pub(crate) enum Expect {
    /// Out of sequence: `fmi2Error`, nothing changed, a log line saying so.
    Refused,
    /// Not provided by the model (its FMU-state functions): like [`Expect::Refused`].
    NotProvided,
    /// This status; on `fmi2Error` nothing changed.
    Exactly(fmi2Status),
    /// Any of these; on `fmi2Error` nothing changed.
    OneOf(&'static [fmi2Status]),
}

/// The fuzzed instance with its oracle, the other instances and the importer's variables.
pub(crate) struct Case<'l> {
    pub(crate) lib: &'l Library,
    pub(crate) meta: &'static Meta,
    pub(crate) inst: RawInstance<'l>,
    /// Another instance of the same model, initialized (models with FMU state only).
    pub(crate) peer: Option<RawInstance<'l>>,
    /// An instance of another model.
    pub(crate) foreign: RawInstance<'l>,
    pub(crate) foreign_id: &'static str,
    pub(crate) m: Machine,
    pub(crate) ptrs: [fmi2FMUstate; SLOTS],
    pub(crate) slots: [Slot; SLOTS],
    pub(crate) blobs: Vec<Blob>,
    /// Addresses of freed states.
    pub(crate) dead: Vec<usize>,
    /// A buffer whose address is never a state.
    pub(crate) never: Box<[u8; 64]>,
    /// How a fresh instance of the model reads.
    pristine: Observation,
    /// The calls made so far with their statuses, for the failure message.
    pub(crate) trace: Vec<String>,
}

/// Instantiates `identifier` (under the lock: an instance's address must not be another's
/// freed one while a double free is checked).
pub(crate) fn instantiate<'l>(lib: &'l Library, name: &str, identifier: &str) -> RawInstance<'l> {
    let _live = live();
    let i = RawInstance::new(&lib.raw, name, &guid_of(identifier));
    assert!(!i.c.is_null(), "{identifier}: {}", i.log_text());
    i
}

impl Drop for Case<'_> {
    fn drop(&mut self) {
        // Free the states still live (the instances free themselves), and the instances under
        // the lock.
        let mut live = live();
        for k in 0..SLOTS {
            if matches!(self.slots[k], Slot::Live { .. }) {
                // SAFETY: a live state of this binary, freed through an instance that provides
                // FMU state (the foreign one always does).
                let was = self.ptrs[k] as usize;
                let s = unsafe { (self.lib.raw.free_fmu_state)(self.foreign.c, &mut self.ptrs[k]) };
                if s == fmi2OK {
                    live.retain(|&p| p != was);
                }
            }
        }
        for i in [
            Some(&mut self.inst),
            self.peer.as_mut(),
            Some(&mut self.foreign),
        ]
        .into_iter()
        .flatten()
        {
            if !i.c.is_null() {
                // SAFETY: a live instance, freed once.
                unsafe { (self.lib.raw.free_instance)(i.c) };
                i.c = null_mut();
            }
        }
    }
}

impl<'l> Case<'l> {
    pub(crate) fn new(
        lib: &'l Library,
        identifier: &'static str,
        foreign_id: &'static str,
    ) -> Case<'l> {
        let meta = meta(identifier);
        let inst = instantiate(lib, "fuzzed", identifier);
        let foreign = instantiate(lib, "foreign", foreign_id);
        let mut peer = meta.states.then(|| {
            let mut p = instantiate(lib, "peer", identifier);
            p.initialize(0.0, None);
            p
        });
        let mut case = Case {
            lib,
            meta,
            inst,
            peer: None,
            foreign,
            foreign_id,
            m: Machine::fresh(),
            ptrs: [null_mut(); SLOTS],
            slots: std::array::from_fn(|_| Slot::Null),
            blobs: Vec::new(),
            dead: Vec::new(),
            never: Box::new([0; 64]),
            pristine: Observation {
                reals: None,
                integers: None,
                booleans: None,
                strings: None,
                bytes: None,
            },
            trace: Vec::new(),
        };

        case.pristine = case.observe();
        // Seed bytes: a fresh instance's state, an initialized peer's, another model's.
        if let Some(bytes) = case.pristine.bytes.clone() {
            case.blobs.push(Blob {
                bytes,
                model: identifier,
                machine: Machine::fresh(),
                observation: Some(case.pristine.clone()),
            });
        }
        if let Some(p) = peer.as_mut() {
            let bytes = serialized_state_locked(p);
            case.blobs.push(Blob {
                bytes,
                model: identifier,
                machine: Machine {
                    s: S::StepComplete,
                    ..Machine::fresh()
                },
                observation: None,
            });
        }
        let bytes = serialized_state_locked(&mut case.foreign);
        case.blobs.push(Blob {
            bytes,
            model: foreign_id,
            machine: Machine::fresh(),
            observation: None,
        });
        case.peer = peer;
        case
    }

    /// Panics with the trace of the case so far.
    #[track_caller]
    pub(crate) fn fail(&self, what: String) -> ! {
        panic!(
            "{}: {what}\ncalls so far:\n  {}\nlog of the last call:\n{}",
            self.meta.identifier,
            self.trace.join("\n  "),
            self.inst.log_text()
        );
    }

    /// The serialized state of the fuzzed instance (its model provides FMU state).
    fn state_bytes(&mut self) -> Vec<u8> {
        let lib = self.lib;
        let f = &lib.raw;
        let mut live = live();
        // SAFETY: a live instance; out-pointers and the buffer are valid for the calls.
        unsafe {
            let mut state: fmi2FMUstate = null_mut();
            let s = (f.get_fmu_state)(self.inst.c, &mut state);
            if s != fmi2OK {
                drop(live);
                self.fail(format!("observing: fmi2GetFMUstate answered {s:?}"));
            }
            live.push(state as usize);
            let mut size = 0usize;
            assert_eq!((f.serialized_size)(self.inst.c, state, &mut size), fmi2OK);
            let mut bytes = vec![0u8; size];
            assert_eq!(
                (f.serialize)(self.inst.c, state, bytes.as_mut_ptr().cast(), size),
                fmi2OK
            );
            let address = state as usize;
            assert_eq!((f.free_fmu_state)(self.inst.c, &mut state), fmi2OK);
            live.retain(|&p| p != address);
            assert!(state.is_null());
            bytes
        }
    }

    /// Everything readable now: gets of every variable (where the oracle allows a get),
    /// then the serialized state (after the gets, which compute the outputs a state holds).
    pub(crate) fn observe(&mut self) -> Observation {
        let mut o = Observation {
            reals: None,
            integers: None,
            booleans: None,
            strings: None,
            bytes: None,
        };
        if allowed(F::Get, self.m.s) {
            let lib = self.lib;
            let f = &lib.raw;
            let c = self.inst.c;
            // SAFETY: a live instance; arrays of the references' length.
            unsafe {
                let vrs = self.meta.vrs(Ty::Real);
                let mut v = vec![0.0f64; vrs.len()];
                let s = (f.get_real)(c, vrs.as_ptr(), vrs.len(), v.as_mut_ptr());
                o.reals = Some((s.0, v.iter().map(|x| x.to_bits()).collect()));
                let vrs = self.meta.vrs(Ty::Integer);
                let mut v = vec![0; vrs.len()];
                let s = (f.get_integer)(c, vrs.as_ptr(), vrs.len(), v.as_mut_ptr());
                o.integers = Some((s.0, v));
                let vrs = self.meta.vrs(Ty::Boolean);
                let mut v = vec![0; vrs.len()];
                let s = (f.get_boolean)(c, vrs.as_ptr(), vrs.len(), v.as_mut_ptr());
                o.booleans = Some((s.0, v));
                let vrs = self.meta.vrs(Ty::String);
                let mut v: Vec<fmi2String> = vec![null(); vrs.len()];
                let s = (f.get_string)(c, vrs.as_ptr(), vrs.len(), v.as_mut_ptr());
                let strings = if s == fmi2OK {
                    v.iter().map(|&p| read_cstr(p)).collect()
                } else {
                    Vec::new()
                };
                o.strings = Some((s.0, strings));
            }
        }
        if self.meta.states {
            o.bytes = Some(self.state_bytes());
        }
        o
    }

    /// The value references of a call's list.
    pub(crate) fn resolve(&self, ty: Ty, refs: &[Ref], settable_only: bool) -> Vec<u32> {
        let of_type = &self.meta.of_type[ty as usize];
        let mut out: Vec<u32> = Vec::with_capacity(refs.len());
        for r in refs {
            let vr = match r {
                Ref::Var(n) if !of_type.is_empty() => {
                    self.meta.vars[of_type[*n as usize % of_type.len()]].vr
                }
                Ref::Var(_) => UNKNOWN_VR,
                Ref::AnyVar(n) => self.meta.vars[*n as usize % self.meta.vars.len()].vr,
                Ref::Again => out.last().copied().unwrap_or_else(|| {
                    of_type
                        .first()
                        .map_or(UNKNOWN_VR, |&i| self.meta.vars[i].vr)
                }),
                Ref::Raw(vr) => *vr,
            };
            let vr = if settable_only && needs_a_bench_link(self.meta.identifier, vr) {
                UNKNOWN_VR
            } else {
                vr
            };
            out.push(vr);
        }
        out
    }

    /// Whether the state functions are provided; `Expect::NotProvided` otherwise.
    pub(crate) fn state_expect(&self, provided: impl FnOnce() -> Expect) -> Expect {
        if self.meta.states {
            provided()
        } else {
            Expect::NotProvided
        }
    }

    /// Runs one call: checks its status against the oracle and what it changed, and moves the
    /// oracle on.
    pub(crate) fn run(&mut self, call: &Call) {
        let before = self.observe();
        let m = self.m;
        self.inst.log.clear();
        let (status, expect) = self.make(call, &before);
        let Some(known) = status.status() else {
            self.fail(format!(
                "{call:?} answered an undefined fmi2Status {}",
                status.0
            ));
        };
        self.trace.push(format!("{call:?} -> {known:?}"));
        let log = self.inst.log_text();
        if log.contains("internal error (panic)") {
            self.fail(format!("{call:?} panicked inside the FMU"));
        }
        if matches!(known, fmi2Status::fmi2Fatal | fmi2Status::fmi2Pending) {
            self.fail(format!("{call:?} answered {known:?}"));
        }
        let sequence_refusal = log.contains("not allowed in state");
        match expect {
            Expect::Refused | Expect::NotProvided => {
                let needle = if matches!(expect, Expect::Refused) {
                    "not allowed in state"
                } else {
                    "not provided"
                };
                // The gets and sets check their arrays (and `fmi2SetString` its strings) before
                // the state (export.rs: a NULL takes the checking path that names it); either
                // reason is a refusal.
                let named_argument = matches!(call, Call::Get { .. } | Call::Set { .. })
                    && (log.contains("is NULL") || log.contains("is not UTF-8"));
                if known != fmi2Error || !(log.contains(needle) || named_argument) {
                    self.fail(format!(
                        "{call:?} in {:?} must be refused with fmi2Error and a log line \
                         saying \"{needle}\", got {known:?}",
                        m.s
                    ));
                }
                self.m = m;
                self.unchanged(call, &before);
            }
            Expect::Exactly(want) => {
                if known != want {
                    self.fail(format!(
                        "{call:?} in {:?}: expected {want:?}, got {known:?}",
                        m.s
                    ));
                }
            }
            Expect::OneOf(set) => {
                if !set.contains(&known) {
                    self.fail(format!(
                        "{call:?} in {:?}: expected one of {set:?}, got {known:?}",
                        m.s
                    ));
                }
            }
        }
        if !matches!(expect, Expect::Refused) && sequence_refusal {
            self.fail(format!(
                "{call:?} in {:?} is allowed by the table, but the FMU refused it for the state",
                m.s
            ));
        }
        if known == fmi2Error && !matches!(expect, Expect::Refused | Expect::NotProvided) {
            if matches!(call, Call::DoStep { .. }) {
                // A refused step changes nothing; a step that failed inside the model after it
                // changed moves the instance to the error state.
                let after = self.observe();
                if after != before {
                    self.probe_error_state(call);
                    self.m.s = S::Error;
                }
            } else {
                self.unchanged(call, &before);
            }
        }
    }

    /// Checks that the instance reads as `before`.
    #[track_caller]
    fn unchanged(&mut self, call: &Call, before: &Observation) {
        let after = self.observe();
        if after != *before {
            self.fail(format!(
                "{call:?} answered fmi2Error but changed the instance: {}",
                before.difference(&after)
            ));
        }
    }

    /// Checks that the instance is in the error state: a status call is refused for the
    /// state, naming it.
    fn probe_error_state(&mut self, call: &Call) {
        self.inst.log.clear();
        let mut b = 0;
        // SAFETY: a live instance and a valid out-pointer.
        let s = unsafe {
            (self.lib.raw.get_boolean_status)(
                self.inst.c,
                fmi2StatusKind::fmi2Terminated as c_int,
                &mut b,
            )
        };
        if s != fmi2Error || !self.inst.log_text().contains("not allowed in state error") {
            self.fail(format!(
                "{call:?} answered fmi2Error and changed the instance, but it is not in the \
                 error state (probe answered {s:?})"
            ));
        }
    }

    /// `Expect::Refused` when `f` is not allowed in the oracle's state, else `in_sequence()`.
    pub(crate) fn expect(&self, f: F, in_sequence: impl FnOnce() -> Expect) -> Expect {
        if allowed(f, self.m.s) {
            in_sequence()
        } else {
            Expect::Refused
        }
    }

    /// After `what`, the instance reads as a fresh one (where it can be read).
    pub(crate) fn check_pristine(&mut self, what: &str) {
        let now = self.observe();
        if now != self.pristine {
            let diff = self.pristine.difference(&now);
            self.fail(format!(
                "after {what} the instance does not read as a fresh one: {diff}"
            ));
        }
    }

    /// `fmi2LastSuccessfulTime` (allowed in the oracle's state).
    pub(crate) fn last_successful_time(&mut self, call: &Call) -> f64 {
        let mut t = f64::NAN;
        // SAFETY: a live instance and a valid out-pointer.
        let s = unsafe {
            (self.lib.raw.get_real_status)(
                self.inst.c,
                fmi2StatusKind::fmi2LastSuccessfulTime as c_int,
                &mut t,
            )
        };
        if s != fmi2OK {
            self.fail(format!("after {call:?}: fmi2GetRealStatus answered {s:?}"));
        }
        t
    }

    /// After a completed step, `fmi2LastSuccessfulTime` is the oracle's `t + h`.
    pub(crate) fn check_time(&mut self, call: &Call) {
        let t = self.last_successful_time(call);
        if t.to_bits() != self.m.time.to_bits() {
            self.fail(format!(
                "after {call:?}: fmi2LastSuccessfulTime {t}, expected {}",
                self.m.time
            ));
        }
    }

    /// Property 4: whatever came before, `fmi2Reset` gives an instance that reads as a fresh
    /// one and that initializes and steps normally.
    pub(crate) fn recover(&mut self) {
        let lib = self.lib;
        let f = &lib.raw;
        let c = self.inst.c;
        self.trace.push("-- recovery".into());
        self.inst.log.clear();
        // SAFETY: a live instance.
        let s = unsafe { (f.reset)(c) };
        if s != fmi2OK {
            self.fail(format!("fmi2Reset after the sequence answered {s:?}"));
        }
        self.m = Machine::fresh();
        self.check_pristine("the final fmi2Reset");
        // SAFETY: a live instance.
        unsafe {
            let steps = [
                (f.setup_experiment)(c, fmi2False, 0.0, 0.0, fmi2True, 1.0),
                (f.enter_initialization_mode)(c),
                (f.exit_initialization_mode)(c),
                (f.do_step)(c, 0.0, 1e-3, fmi2True),
                (f.do_step)(c, 1e-3, 1e-3, fmi2True),
                (f.do_step)(c, 2e-3, 1e-3, fmi2True),
                (f.terminate)(c),
            ];
            if steps.iter().any(|s| *s != fmi2OK) {
                self.fail(format!(
                    "after fmi2Reset, setup, initialization, three steps and terminate answered \
                     {steps:?}"
                ));
            }
        }
    }
}

/// [`RawInstance::serialized_state`] with the state made and freed under the lock.
fn serialized_state_locked(i: &mut RawInstance) -> Vec<u8> {
    let _live = live();
    i.serialized_state()
}
