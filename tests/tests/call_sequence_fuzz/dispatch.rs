//! [`Case::make`]: each call made through the raw C ABI, with the status the oracle expects
//! of it.

use std::ffi::{CString, c_char, c_int};
use std::ptr::{null, null_mut};

use kneebench_tests::*;
use model_description::Causality;

use fmi2Status::{fmi2Discard, fmi2Error, fmi2OK};

use crate::UNKNOWN_VR;
use crate::calls::{At, Call, Categories, Nulls, StatusFn, Value};
use crate::case::{Case, Expect, Observation, Slot, instantiate};
use crate::library::{Ty, live};
use crate::oracle::{F, Machine, S, bad_step};
use crate::values::{boolean_value, integer_value, null_component_call, real_value, string_value};

impl<'l> Case<'l> {
    /// Makes the call; returns its status and what the oracle expected of it (and moves the
    /// oracle on for an accepted call).
    pub(crate) fn make(&mut self, call: &Call, before: &Observation) -> (fmi2StatusCode, Expect) {
        let lib = self.lib;
        let f = &lib.raw;
        let c = self.inst.c;
        let s = self.m.s;
        // SAFETY (every call below): `c` is the live fuzzed instance; every array holds the
        // count passed with it or is deliberately NULL; every out-pointer is valid or
        // deliberately NULL; state pointers are NULL, live, freed while no live state has
        // their address (checked under the lock), or never made (compared, not dereferenced,
        // by the glue).
        unsafe {
            match call {
                Call::SetDebugLogging { on, categories } => {
                    let names: Vec<CString> = kneebench_fmu::model::LOG_CATEGORIES
                        .iter()
                        .map(|(n, _)| cstr(n))
                        .collect();
                    let (ptrs, n, ok): (Vec<*const c_char>, usize, bool) = match categories {
                        Categories::All => (vec![], 0, true),
                        Categories::Known(k) => (
                            k.iter()
                                .map(|i| names[*i as usize % names.len()].as_ptr())
                                .collect(),
                            k.len(),
                            true,
                        ),
                        Categories::Unknown => {
                            (vec![names[0].as_ptr(), c"logNothing".as_ptr()], 2, false)
                        }
                        Categories::NullArray => (vec![], 2, false),
                        Categories::NullName => (vec![names[0].as_ptr(), null()], 2, false),
                    };
                    let array = if ptrs.is_empty() {
                        null()
                    } else {
                        ptrs.as_ptr()
                    };
                    let status = (f.set_debug_logging)(c, fmi2Boolean::from(*on), n, array);
                    let want = if ok { fmi2OK } else { fmi2Error };
                    (
                        status,
                        self.expect(F::SetDebugLogging, || Expect::Exactly(want)),
                    )
                }
                Call::SetupExperiment {
                    tolerance,
                    start,
                    stop,
                } => {
                    let status = (f.setup_experiment)(
                        c,
                        fmi2Boolean::from(tolerance.is_some()),
                        tolerance.unwrap_or(0.0),
                        *start,
                        fmi2Boolean::from(stop.is_some()),
                        stop.unwrap_or(0.0),
                    );
                    let ok = start.is_finite()
                        && stop.is_none_or(|e| e.is_finite() && e >= *start)
                        && tolerance.is_none_or(|t| t.is_finite() && t > 0.0);
                    let e = self.expect(F::SetupExperiment, || {
                        Expect::Exactly(if ok { fmi2OK } else { fmi2Error })
                    });
                    if matches!(e, Expect::Exactly(fmi2OK)) {
                        self.m.stop = *stop;
                        self.m.time = *start;
                    }
                    (status, e)
                }
                Call::EnterInitializationMode => {
                    let status = (f.enter_initialization_mode)(c);
                    let e = self.expect(F::EnterInitializationMode, || Expect::Exactly(fmi2OK));
                    if !matches!(e, Expect::Refused) {
                        self.m.s = S::Initialization;
                    }
                    (status, e)
                }
                Call::ExitInitializationMode => {
                    // The model may find its parameters inconsistent: then it stays in
                    // initialization mode, unchanged.
                    let status = (f.exit_initialization_mode)(c);
                    let e = self.expect(F::ExitInitializationMode, || {
                        Expect::OneOf(&[fmi2OK, fmi2Error])
                    });
                    if !matches!(e, Expect::Refused) && status == fmi2OK {
                        self.m.s = S::StepComplete;
                    }
                    (status, e)
                }
                Call::Terminate => {
                    let status = (f.terminate)(c);
                    let e = self.expect(F::Terminate, || Expect::Exactly(fmi2OK));
                    if !matches!(e, Expect::Refused) {
                        self.m.s = S::Terminated;
                    }
                    (status, e)
                }
                Call::Reset => {
                    let status = (f.reset)(c);
                    let e = self.expect(F::Reset, || Expect::Exactly(fmi2OK));
                    self.m = Machine::fresh();
                    if status == fmi2OK {
                        self.check_pristine("fmi2Reset");
                    }
                    (status, e)
                }
                Call::Get { ty, refs, nulls } => {
                    let vrs = self.resolve(*ty, refs, false);
                    let n = vrs.len();
                    let vr_ptr = if matches!(nulls, Nulls::Refs | Nulls::Both) && n > 0 {
                        null()
                    } else {
                        vrs.as_ptr()
                    };
                    let null_values = matches!(nulls, Nulls::Values | Nulls::Both) && n > 0;
                    let known = vrs.iter().all(|vr| self.meta.find(*ty, *vr).is_some());
                    let nulled = vr_ptr.is_null() || null_values;
                    let want = if !nulled && known && before.computes() {
                        fmi2OK
                    } else {
                        fmi2Error
                    };
                    let mut reals = vec![0.0f64; n];
                    let mut ints = vec![0i32; n];
                    let mut strings: Vec<fmi2String> = vec![null(); n];
                    let status = match ty {
                        Ty::Real => {
                            (f.get_real)(c, vr_ptr, n, out_or_null(null_values, &mut reals))
                        }
                        Ty::Integer => {
                            (f.get_integer)(c, vr_ptr, n, out_or_null(null_values, &mut ints))
                        }
                        Ty::Boolean => {
                            (f.get_boolean)(c, vr_ptr, n, out_or_null(null_values, &mut ints))
                        }
                        Ty::String => {
                            (f.get_string)(c, vr_ptr, n, out_or_null(null_values, &mut strings))
                        }
                    };
                    let e = self.expect(F::Get, || Expect::Exactly(want));
                    if matches!(e, Expect::Exactly(fmi2OK)) && status == fmi2OK {
                        // The values are those of the get of every variable.
                        for (k, vr) in vrs.iter().enumerate() {
                            let index = self.meta.vrs(*ty).iter().position(|x| x == vr).unwrap();
                            let same = match ty {
                                Ty::Real => {
                                    before.reals.as_ref().unwrap().1[index] == reals[k].to_bits()
                                }
                                Ty::Integer => {
                                    before.integers.as_ref().unwrap().1[index] == ints[k]
                                }
                                Ty::Boolean => {
                                    before.booleans.as_ref().unwrap().1[index] == ints[k]
                                }
                                Ty::String => {
                                    before.strings.as_ref().unwrap().1[index]
                                        == read_cstr(strings[k])
                                }
                            };
                            if !same {
                                self.fail(format!(
                                    "{call:?}: value reference {vr} reads differently from the get of every variable"
                                ));
                            }
                        }
                    }
                    (status, e)
                }
                Call::Set {
                    ty,
                    refs,
                    values,
                    nulls,
                } => {
                    let vrs = self.resolve(*ty, refs, true);
                    let n = vrs.len();
                    let vr_ptr = if matches!(nulls, Nulls::Refs | Nulls::Both) && n > 0 {
                        null()
                    } else {
                        vrs.as_ptr()
                    };
                    let null_values = matches!(nulls, Nulls::Values | Nulls::Both) && n > 0;
                    let phase = s.phase();
                    let mut ok = !vr_ptr.is_null() && !null_values;
                    let mut reals = Vec::with_capacity(n);
                    let mut ints = Vec::with_capacity(n);
                    let mut owned: Vec<Option<CString>> = Vec::with_capacity(n);
                    for (k, vr) in vrs.iter().enumerate() {
                        let var = self.meta.find(*ty, *vr);
                        let value = values.get(k).copied().unwrap_or(Value::Start);
                        match var {
                            Some(v) => ok &= v.settable(phase),
                            None => ok = false,
                        }
                        match ty {
                            Ty::Real => {
                                let x = real_value(var, value);
                                if let Some(v) = var {
                                    ok &= x.is_finite()
                                        && !(v.whole && x.fract() != 0.0)
                                        && v.min.is_none_or(|lo| x >= lo)
                                        && v.max.is_none_or(|hi| x <= hi);
                                }
                                reals.push(x);
                            }
                            Ty::Integer => {
                                let x = integer_value(var, value);
                                if let Some(v) = var {
                                    ok &= v.min.is_none_or(|lo| f64::from(x) >= lo)
                                        && v.max.is_none_or(|hi| f64::from(x) <= hi);
                                }
                                ints.push(x);
                            }
                            Ty::Boolean => ints.push(boolean_value(var, value)),
                            Ty::String => {
                                let text = string_value(var, value);
                                ok &= text
                                    .as_ref()
                                    .is_some_and(|t| std::str::from_utf8(t.as_bytes()).is_ok());
                                owned.push(text);
                            }
                        }
                    }
                    let strings: Vec<fmi2String> = owned
                        .iter()
                        .map(|t| t.as_ref().map_or(null(), |t| t.as_ptr()))
                        .collect();
                    let status = match ty {
                        Ty::Real => (f.set_real)(
                            c,
                            vr_ptr,
                            n,
                            if null_values { null() } else { reals.as_ptr() },
                        ),
                        Ty::Integer => (f.set_integer)(
                            c,
                            vr_ptr,
                            n,
                            if null_values { null() } else { ints.as_ptr() },
                        ),
                        Ty::Boolean => (f.set_boolean)(
                            c,
                            vr_ptr,
                            n,
                            if null_values { null() } else { ints.as_ptr() },
                        ),
                        Ty::String => (f.set_string)(
                            c,
                            vr_ptr,
                            n,
                            if null_values {
                                null()
                            } else {
                                strings.as_ptr()
                            },
                        ),
                    };
                    let want = if ok { fmi2OK } else { fmi2Error };
                    (status, self.expect(F::Set, || Expect::Exactly(want)))
                }
                Call::GetRealOutputDerivatives {
                    refs,
                    orders,
                    nulls,
                } => {
                    let vrs = self.resolve(Ty::Real, refs, false);
                    let n = vrs.len();
                    let mut orders = orders.clone();
                    orders.resize(n, 1);
                    let mut out = vec![0.0; n];
                    let nulled =
                        matches!(nulls, Nulls::Refs | Nulls::Both | Nulls::Values) && n > 0;
                    let status = (f.get_real_output_derivatives)(
                        c,
                        if matches!(nulls, Nulls::Refs | Nulls::Both) && n > 0 {
                            null()
                        } else {
                            vrs.as_ptr()
                        },
                        n,
                        orders.as_ptr(),
                        if matches!(nulls, Nulls::Values | Nulls::Both) && n > 0 {
                            null_mut()
                        } else {
                            out.as_mut_ptr()
                        },
                    );
                    let order = self.meta.derivative_order;
                    let plausible = vrs.iter().zip(&orders).all(|(vr, o)| {
                        self.meta
                            .find(Ty::Real, *vr)
                            .is_some_and(|v| v.causality == Causality::Output)
                            && (1..=order).contains(o)
                    });
                    let e = self.expect(F::GetRealOutputDerivatives, || {
                        if nulled || !plausible {
                            Expect::Exactly(fmi2Error)
                        } else if n == 0 {
                            // Nothing asked: the outputs are computed (or refused) only.
                            Expect::Exactly(if before.computes() { fmi2OK } else { fmi2Error })
                        } else {
                            // A model provides the derivatives of some outputs only.
                            Expect::OneOf(&[fmi2OK, fmi2Error])
                        }
                    });
                    (status, e)
                }
                Call::SetRealInputDerivatives { refs } => {
                    let vrs = self.resolve(Ty::Real, refs, true);
                    let n = vrs.len();
                    let orders = vec![1; n];
                    let values = vec![0.0; n];
                    let status = (f.set_real_input_derivatives)(
                        c,
                        vrs.as_ptr(),
                        n,
                        orders.as_ptr(),
                        values.as_ptr(),
                    );
                    (
                        status,
                        self.expect(F::SetRealInputDerivatives, || Expect::Exactly(fmi2Error)),
                    )
                }
                Call::GetDirectionalDerivative => {
                    let (vu, vk) = ([UNKNOWN_VR], [UNKNOWN_VR]);
                    let (dk, mut du) = ([1.0], [0.0]);
                    let status = (f.get_directional_derivative)(
                        c,
                        vu.as_ptr(),
                        1,
                        vk.as_ptr(),
                        1,
                        dk.as_ptr(),
                        du.as_mut_ptr(),
                    );
                    (
                        status,
                        self.expect(F::GetDirectionalDerivative, || Expect::Exactly(fmi2Error)),
                    )
                }
                Call::DoStep { at, h } => {
                    let now = self.m.time;
                    let t = match at {
                        At::Now => now,
                        At::Near => now + now.abs().max(1.0) * 1e-12,
                        At::Later => now + now.abs().max(1.0) * 1e-3,
                        At::Earlier => now - now.abs().max(1.0) * 1e-3,
                        At::Zero => 0.0,
                        At::Nan => f64::NAN,
                        At::Inf => f64::INFINITY,
                    };
                    let status = (f.do_step)(c, t, *h, fmi2True);
                    let bad = bad_step(&self.m, t, *h);
                    let e = self.expect(F::DoStep, || {
                        if bad {
                            Expect::Exactly(fmi2Error)
                        } else {
                            Expect::OneOf(&[fmi2OK, fmi2Discard, fmi2Error])
                        }
                    });
                    if !matches!(e, Expect::Refused) && !bad {
                        if status == fmi2OK {
                            self.m.time = t + h;
                            self.check_time(call);
                        } else if status == fmi2Discard {
                            self.m.s = S::StepFailed;
                            self.m.terminated = true;
                            let at = self.last_successful_time(call);
                            if !(at >= t - 1e-9 * t.abs().max(1.0)
                                && at <= t + h + 1e-9 * (t + h).abs().max(1.0))
                            {
                                self.fail(format!(
                                    "{call:?}: discarded at {at}, outside [{t}, {}]",
                                    t + h
                                ));
                            }
                            self.m.time = at;
                        }
                    }
                    (status, e)
                }
                Call::CancelStep => {
                    let status = (f.cancel_step)(c);
                    (
                        status,
                        self.expect(F::CancelStep, || Expect::Exactly(fmi2Error)),
                    )
                }
                Call::Status {
                    function,
                    kind,
                    null_value,
                } => {
                    let mut st = fmi2OK;
                    let mut real = f64::NAN;
                    let mut int = -7;
                    let mut boolean = -7;
                    let mut string: fmi2String = null();
                    let status = match function {
                        StatusFn::Status => {
                            (f.get_status)(c, *kind, if *null_value { null_mut() } else { &mut st })
                        }
                        StatusFn::Real => (f.get_real_status)(
                            c,
                            *kind,
                            if *null_value { null_mut() } else { &mut real },
                        ),
                        StatusFn::Integer => (f.get_integer_status)(
                            c,
                            *kind,
                            if *null_value { null_mut() } else { &mut int },
                        ),
                        StatusFn::Boolean => (f.get_boolean_status)(
                            c,
                            *kind,
                            if *null_value {
                                null_mut()
                            } else {
                                &mut boolean
                            },
                        ),
                        StatusFn::String => (f.get_string_status)(
                            c,
                            *kind,
                            if *null_value { null_mut() } else { &mut string },
                        ),
                    };
                    let answered = match function {
                        StatusFn::Real => *kind == fmi2StatusKind::fmi2LastSuccessfulTime as c_int,
                        StatusFn::Boolean => *kind == fmi2StatusKind::fmi2Terminated as c_int,
                        _ => false,
                    };
                    let want = if *null_value {
                        fmi2Error
                    } else if answered {
                        fmi2OK
                    } else {
                        fmi2Discard
                    };
                    let e = self.expect(F::GetStatus, || Expect::Exactly(want));
                    if matches!(e, Expect::Exactly(fmi2OK)) && status == fmi2OK {
                        match function {
                            StatusFn::Real if real.to_bits() != self.m.time.to_bits() => {
                                self.fail(format!(
                                    "fmi2LastSuccessfulTime is {real}, the oracle's time {}",
                                    self.m.time
                                ));
                            }
                            StatusFn::Boolean if boolean != c_int::from(self.m.terminated) => {
                                self.fail(format!(
                                    "fmi2Terminated is {boolean}, the oracle's {}",
                                    self.m.terminated
                                ));
                            }
                            _ => {}
                        }
                    }
                    (status, e)
                }
                Call::GetFmuState { slot, null_out } => self.get_state(*slot, *null_out, before),
                Call::SetFmuState { slot } => self.set_state(*slot),
                Call::FreeFmuState { slot, null_out } => self.free_state(*slot, *null_out, false),
                Call::SerializedSize { slot, null_size } => {
                    let live = self.live_checked(*slot);
                    let mut size = 0usize;
                    let status = (f.serialized_size)(
                        c,
                        self.ptrs[*slot],
                        if *null_size { null_mut() } else { &mut size },
                    );
                    drop(live);
                    let ok = !null_size && matches!(self.slots[*slot], Slot::Live { .. });
                    let want = if ok { fmi2OK } else { fmi2Error };
                    (
                        status,
                        self.state_expect(|| self.expect(F::FmuState, || Expect::Exactly(want))),
                    )
                }
                Call::Serialize { slot, buffer } => self.serialize(*slot, *buffer),
                Call::Deserialize {
                    blob,
                    damage,
                    slot,
                    null_out,
                } => self.deserialize(*blob, damage, *slot, *null_out),
                Call::PeerState { slot } => {
                    let Some(peer) = self.peer.as_ref().map(|p| p.c) else {
                        return (fmi2OK.into(), Expect::Exactly(fmi2OK));
                    };
                    self.other_state(
                        peer,
                        *slot,
                        self.meta.identifier,
                        Machine {
                            s: S::StepComplete,
                            ..Machine::fresh()
                        },
                    )
                }
                Call::ForeignState { slot } => {
                    let foreign = self.foreign.c;
                    self.other_state(foreign, *slot, self.foreign_id, Machine::fresh())
                }
                Call::Dangle { slot, pick } => self.dangle(*slot, *pick),
                Call::NullComponent { function } => {
                    let status = null_component_call(f, *function, &self.meta.guid);
                    (status, Expect::Exactly(fmi2Error))
                }
                Call::FreeAndInstantiate { twice } => {
                    {
                        let _live = live();
                        (f.free_instance)(c);
                        if *twice {
                            // Harmless: the instance registry no longer has it.
                            (f.free_instance)(c);
                        }
                        self.inst.c = null_mut();
                    }
                    self.inst = instantiate(self.lib, "fuzzed", self.meta.identifier);
                    self.m = Machine::fresh();
                    self.check_pristine("a new instance");
                    (fmi2OK.into(), Expect::Exactly(fmi2OK))
                }
                Call::Version => {
                    let v = read_cstr((self.lib.version)());
                    let p = read_cstr((self.lib.types_platform)());
                    if v != "2.0" || p != "default" {
                        self.fail(format!("version {v:?}, types platform {p:?}"));
                    }
                    (fmi2OK.into(), Expect::Exactly(fmi2OK))
                }
            }
        }
    }
}

/// The output array of a get, or NULL when the case passes NULL for it.
fn out_or_null<T>(null: bool, values: &mut [T]) -> *mut T {
    if null {
        null_mut()
    } else {
        values.as_mut_ptr()
    }
}
