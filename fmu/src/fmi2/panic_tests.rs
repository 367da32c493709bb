//! A panic inside a model, through the exported C functions: the gets, sets and `fmi2DoStep`
//! call their instance methods without a `catch_unwind` of their own (`export` module docs),
//! so each method must catch it: the call answers `fmi2Error` with a log line naming the
//! panic, the instance enters the error state (a step is then refused), and `fmi2Reset`
//! recovers it. A panic that escaped a method would unwind into an `extern "C"` function,
//! which aborts this test process.

use std::sync::LazyLock;

use super::export::{
    fmi2DoStep, fmi2GetBoolean, fmi2GetInteger, fmi2GetReal, fmi2Reset, fmi2SetBoolean, fmi2SetReal,
};
use super::instance::FmiInstance;
use super::logging::Logger;
use super::types::fmi2Component;
use super::types::fmi2Status::{self, fmi2Error, fmi2OK};
use crate::model::{Model, ModelError, Start, StepOutcome, Variable};
use crate::registry::{ModelEntry, ReferenceInputs};

/// A model that panics where its input `x` says: 5 in `do_step`, 7 in `calculate`, 13, 14
/// and 15 in the getters of `y`, `flag` and `count`, 16 in the setter of `on`; and the setter
/// of `x` panics for 99.
#[derive(Debug, Default, Clone)]
struct Panicky {
    x: f64,
    y: f64,
    on: bool,
}

static VARIABLES: LazyLock<Vec<Variable<Panicky>>> = LazyLock::new(|| {
    type V = Variable<Panicky>;
    vec![
        V::real(
            "x",
            1,
            |m| m.x,
            |m, v| {
                assert!(v != 99.0, "the setter of x panics");
                m.x = v;
            },
        )
        .input(Start::Real(0.0)),
        V::real(
            "y",
            2,
            |m| {
                assert!(m.x != 13.0, "the getter of y panics");
                m.y
            },
            |m, v| m.y = v,
        )
        .output(&["x"]),
        V::boolean(
            "flag",
            1,
            |m| {
                assert!(m.x != 14.0, "the getter of flag panics");
                m.on
            },
            |m, v| m.on = v,
        )
        .output(&["x"]),
        V::integer(
            "count",
            1,
            |m| {
                assert!(m.x != 15.0, "the getter of count panics");
                1
            },
            |_, _| {},
        )
        .output(&["x"]),
        V::boolean(
            "on",
            2,
            |m| m.on,
            |m, v| {
                assert!(m.x != 16.0, "the setter of on panics");
                m.on = v;
            },
        )
        .input(Start::Boolean(false)),
    ]
});

impl Model for Panicky {
    const IDENTIFIER: &'static str = "Panicky";
    const DESCRIPTION: &'static str = "A test model that panics on demand";

    fn variables() -> &'static [Variable<Self>] {
        &VARIABLES
    }

    fn initialize(&mut self, _start_time: f64) -> Result<(), ModelError> {
        Ok(())
    }

    fn calculate(&mut self, _t: f64) -> Result<(), ModelError> {
        assert!(self.x != 7.0, "calculate panics");
        self.y = 2.0 * self.x;
        Ok(())
    }

    fn do_step(&mut self, _t: f64, _h: f64) -> Result<StepOutcome, ModelError> {
        assert!(self.x != 5.0, "the step panics");
        Ok(StepOutcome::Completed)
    }

    fn documentation() -> &'static str {
        ""
    }
}

impl ReferenceInputs for Panicky {}

static PANICKY: ModelEntry = ModelEntry::of::<Panicky>();

/// A Panicky instance at its first communication point, behind a component pointer as
/// `fmi2Instantiate` makes it; its input `x` is `x`.
fn stepping(x: f64) -> fmi2Component {
    let mut i = PANICKY.instantiate(Logger::new(None, std::ptr::null_mut(), c"test", false));
    assert_eq!(i.setup_experiment(0.0, None, None), fmi2OK);
    assert_eq!(i.enter_initialization_mode(), fmi2OK);
    assert_eq!(i.set_real(&[1], &[x]), fmi2OK);
    assert_eq!(i.exit_initialization_mode(), fmi2OK);
    Box::into_raw(Box::new(i)).cast()
}

/// The instance behind a component of [`stepping`].
fn instance<'a>(c: fmi2Component) -> &'a mut Box<dyn FmiInstance> {
    // SAFETY: made by `stepping`, not yet freed; one thread.
    unsafe { &mut *c.cast::<Box<dyn FmiInstance>>() }
}

/// What the instance logged since the last call.
fn log(c: fmi2Component) -> String {
    let mut captured = instance(c).logger().captured.lock().unwrap();
    std::mem::take(&mut *captured).join("\n")
}

/// Calls `call` on an instance whose `x` is `x`: it must answer fmi2Error and log `message`
/// as a caught panic of `function`, leave the instance in the error state (a step is refused
/// as out of sequence), from which `fmi2Reset` recovers.
fn panics(x: f64, function: &str, message: &str, call: impl FnOnce(fmi2Component) -> fmi2Status) {
    let c = stepping(x);
    assert_eq!(call(c), fmi2Error, "{function}");
    let logged = log(c);
    assert!(
        logged.contains(&format!("{function}: internal error (panic): {message}")),
        "{function}: {logged}"
    );
    // SAFETY: a live component of `stepping`.
    assert_eq!(unsafe { fmi2DoStep(c, 0.0, 1e-3, 1) }, fmi2Error);
    assert!(log(c).contains("not allowed in state error"), "{function}");
    // SAFETY: as above.
    assert_eq!(unsafe { fmi2Reset(c) }, fmi2OK, "{function}");
    // SAFETY: made by `stepping` (Box::into_raw), freed once.
    drop(unsafe { Box::from_raw(c.cast::<Box<dyn FmiInstance>>()) });
}

#[test]
fn a_panic_in_a_get_a_set_or_a_step_is_caught_by_the_instance() {
    let vr = [1u32];
    let mut real = [0.0f64];
    let mut int = [0i32];
    // SAFETY (every call): a live component of `stepping`, and arrays of one element.
    panics(5.0, "fmi2DoStep", "the step panics", |c| unsafe {
        fmi2DoStep(c, 0.0, 1e-3, 1)
    });
    panics(7.0, "fmi2GetReal", "calculate panics", |c| unsafe {
        fmi2GetReal(c, [2].as_ptr(), 1, real.as_mut_ptr())
    });
    panics(13.0, "fmi2GetReal", "the getter of y panics", |c| unsafe {
        fmi2GetReal(c, [2].as_ptr(), 1, real.as_mut_ptr())
    });
    panics(
        14.0,
        "fmi2GetBoolean",
        "the getter of flag panics",
        |c| unsafe { fmi2GetBoolean(c, vr.as_ptr(), 1, int.as_mut_ptr()) },
    );
    panics(
        15.0,
        "fmi2GetInteger",
        "the getter of count panics",
        |c| unsafe { fmi2GetInteger(c, vr.as_ptr(), 1, int.as_mut_ptr()) },
    );
    panics(0.0, "fmi2SetReal", "the setter of x panics", |c| unsafe {
        fmi2SetReal(c, vr.as_ptr(), 1, [99.0].as_ptr())
    });
    panics(
        16.0,
        "fmi2SetBoolean",
        "the setter of on panics",
        |c| unsafe { fmi2SetBoolean(c, [2].as_ptr(), 1, [1].as_ptr()) },
    );
    // Without a panic the same calls succeed.
    let c = stepping(1.0);
    // SAFETY: as above.
    unsafe {
        assert_eq!(fmi2GetReal(c, [2].as_ptr(), 1, real.as_mut_ptr()), fmi2OK);
        assert_eq!(real, [2.0]);
        assert_eq!(fmi2DoStep(c, 0.0, 1e-3, 1), fmi2OK);
        drop(Box::from_raw(c.cast::<Box<dyn FmiInstance>>()));
    }
}
