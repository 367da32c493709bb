//! The master's exchange with one component in a co-simulation step: set the inputs, do the
//! step, read the outputs ([`Instance::step_exchange`]).
//!
//! The plain form is the sequence of the single calls ([`Instance::step_exchange_plain`]:
//! [`set_real`](Instance::set_real), [`set_integer`](Instance::set_integer),
//! [`set_boolean_raw`](Instance::set_boolean_raw), [`do_step`](Instance::do_step),
//! [`get_outputs`](Instance::get_outputs)). The fast form, for an in-process instance of a
//! binary without an embedded CPython (every FMU of the bench), makes the same FMI calls in the
//! same order with the same checks in one function: the instance's backend is matched once,
//! not per call, and a failure leaves through one cold exit instead of a `Result` per call.
//! The two give the same values, outcomes, errors and phases (tested, every failure point).

use super::{Backend, FmuError, Instance, Local, Status, mismatch};
use crate::fmi2::{fmi2Boolean, fmi2StatusCode, fmi2True};

/// One component's part of a co-simulation step ([`Instance::step_exchange`]): the inputs set
/// before the step and where the outputs read after it go, per type (`Real`, `Integer`,
/// `Boolean`, in that order; an empty list is left out).
#[derive(Debug)]
pub struct Exchange<'a> {
    /// The value references of the inputs, per type.
    pub in_vrs: &'a [Vec<u32>; 3],
    /// The `Real` input values (as many as `in_vrs[0]`).
    pub real_in: &'a [f64],
    /// The `Integer` input values (as many as `in_vrs[1]`).
    pub int_in: &'a [i32],
    /// The `Boolean` input values as `fmi2Boolean`s (as many as `in_vrs[2]`).
    pub bool_in: &'a [fmi2Boolean],
    /// The value references of the outputs read after a step, per type.
    pub out_vrs: &'a [Vec<u32>; 3],
    /// Where the `Real` outputs go (as many as `out_vrs[0]`).
    pub real_out: &'a mut [f64],
    /// Where the `Integer` outputs go (as many as `out_vrs[1]`).
    pub int_out: &'a mut [i32],
    /// Where the `Boolean` outputs go (as many as `out_vrs[2]`).
    pub bool_out: &'a mut [fmi2Boolean],
}

/// Why the fast exchange stopped: what the plain calls would have returned as an error.
enum Fail {
    /// Value references and values of different lengths: (function, refs, values).
    Mismatch(&'static str, usize, usize),
    /// A call returned an error status.
    Call(&'static str, fmi2StatusCode),
}

/// Whether a status is `fmi2OK`, `fmi2Warning` or `fmi2Discard` (what `Instance::check`
/// accepts; the FMU's C int read as a number, a negative one refused as well).
#[inline(always)]
fn accepted(s: fmi2StatusCode) -> bool {
    (s.0 as u32) <= 2
}

impl Local {
    /// The fast exchange (see the module documentation): the calls of
    /// [`Instance::step_exchange_plain`] for an instance without a Python thread state.
    #[inline(always)]
    fn exchange(
        &mut self,
        x: Exchange<'_>,
        current_time: f64,
        step_size: f64,
        steps: &mut u64,
    ) -> Result<Status, Fail> {
        let (c, id) = (self.c, self.id);
        // One set or get: the length check, the call (skipped for an empty list), marked in
        // progress as the plain call marks it, and its status check.
        macro_rules! call {
            ($name:literal, $f:ident, $vrs:expr, $values:expr, $ptr:ident) => {{
                let (vrs, values): (&[u32], _) = ($vrs, $values);
                if vrs.len() != values.len() {
                    return Err(Fail::Mismatch($name, vrs.len(), values.len()));
                }
                if !vrs.is_empty() {
                    let s = {
                        let _call = crate::inflight::Call::enter(id, &$name);
                        // SAFETY: arrays of the given length; a valid component.
                        unsafe { (self.f.$f)(c, vrs.as_ptr(), vrs.len(), values.$ptr()) }
                    };
                    if !accepted(s) {
                        return Err(Fail::Call($name, s));
                    }
                }
            }};
        }
        call!("fmi2SetReal", set_real, &x.in_vrs[0], x.real_in, as_ptr);
        call!(
            "fmi2SetInteger",
            set_integer,
            &x.in_vrs[1],
            x.int_in,
            as_ptr
        );
        call!(
            "fmi2SetBoolean",
            set_boolean,
            &x.in_vrs[2],
            x.bool_in,
            as_ptr
        );
        *steps += 1;
        let s = {
            let _call = crate::inflight::Call::enter(id, &"fmi2DoStep");
            // SAFETY: a valid component (after fmi2Fatal the master makes no more calls).
            unsafe { (self.f.do_step)(c, current_time, step_size, fmi2True) }
        };
        let status = match s.0 {
            0 => Status::Ok,
            1 => Status::Warning,
            2 => return Ok(Status::Discard),
            _ => return Err(Fail::Call("fmi2DoStep", s)),
        };
        call!(
            "fmi2GetReal",
            get_real,
            &x.out_vrs[0],
            x.real_out,
            as_mut_ptr
        );
        call!(
            "fmi2GetInteger",
            get_integer,
            &x.out_vrs[1],
            x.int_out,
            as_mut_ptr
        );
        call!(
            "fmi2GetBoolean",
            get_boolean,
            &x.out_vrs[2],
            x.bool_out,
            as_mut_ptr
        );
        Ok(status)
    }
}

impl Instance {
    /// One component's part of a co-simulation step, as the master makes it: sets the inputs
    /// of `x` (`fmi2SetReal`, `fmi2SetInteger`, `fmi2SetBoolean`), increments `steps`, calls
    /// `fmi2DoStep` from `current_time` over `step_size` and, unless the FMU discarded the
    /// step, reads the outputs into `x` (`fmi2GetReal`, `fmi2GetInteger`, `fmi2GetBoolean`).
    ///
    /// The same calls, outcome and errors as
    /// [`step_exchange_plain`](Self::step_exchange_plain): `Ok` with `fmi2DoStep`'s status
    /// ([`Status::Discard`]: the step was not done and no output was read), or the first
    /// error (a set's or a get's non-error status is not reported).
    #[inline]
    pub fn step_exchange(
        &mut self,
        x: Exchange<'_>,
        current_time: f64,
        step_size: f64,
        steps: &mut u64,
    ) -> Result<Status, FmuError> {
        match &mut self.backend {
            Backend::Local(l) if l.python.is_none() => {
                match l.exchange(x, current_time, step_size, steps) {
                    Ok(s) => Ok(s),
                    Err(f) => Err(self.exchange_failed(f)),
                }
            }
            _ => self.step_exchange_plain(x, current_time, step_size, steps),
        }
    }

    /// [`step_exchange`](Self::step_exchange) as the sequence of the single calls: the
    /// reference the fast form must equal, and the form for an isolated instance or a binary
    /// with an embedded CPython.
    pub fn step_exchange_plain(
        &mut self,
        x: Exchange<'_>,
        current_time: f64,
        step_size: f64,
        steps: &mut u64,
    ) -> Result<Status, FmuError> {
        self.set_real(&x.in_vrs[0], x.real_in)?;
        self.set_integer(&x.in_vrs[1], x.int_in)?;
        self.set_boolean_raw(&x.in_vrs[2], x.bool_in)?;
        *steps += 1;
        let status = self.do_step(current_time, step_size)?;
        if status != Status::Discard {
            let [real, int, boolean] = x.out_vrs;
            self.get_outputs(
                [real.as_slice(), int, boolean],
                x.real_out,
                x.int_out,
                x.bool_out,
            )?;
        }
        Ok(status)
    }

    /// The error of a failed fast exchange: the one the plain call would have given.
    #[cold]
    #[inline(never)]
    fn exchange_failed(&mut self, f: Fail) -> FmuError {
        match f {
            Fail::Mismatch(function, refs, values) => mismatch(function, refs, values),
            Fail::Call(function, s) => self.error(function, s),
        }
    }
}
