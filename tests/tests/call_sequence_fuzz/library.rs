//! The private copy of the FMU binary, the lock of its live FMU states, and the models as the
//! model descriptions declare them.

use std::ffi::c_char;
use std::sync::{Mutex, MutexGuard, OnceLock, PoisonError};

use kneebench_tests::*;
use model_description::{Causality, Variability, VariableKind};

use crate::MODELS;

// ---------------------------------------------------------------------------------------------
// The private binary and the lock of its instances and states.

/// The private copy of the FMU binary and its functions.
pub(crate) struct Library {
    /// The FMI functions.
    pub(crate) raw: Raw,
    /// `fmi2GetVersion`.
    pub(crate) version: unsafe extern "C" fn() -> *const c_char,
    /// `fmi2GetTypesPlatform`.
    pub(crate) types_platform: unsafe extern "C" fn() -> *const c_char,
    /// Keeps the second handle (of the version functions) open.
    _lib: libloading::Library,
}

/// The binary, copied once per test process and loaded from the copy (the copy's file is
/// removed at once: the loaded mapping stays valid).
pub(crate) fn library() -> &'static Library {
    static LIBRARY: OnceLock<Library> = OnceLock::new();
    LIBRARY.get_or_init(|| {
        let dir = tempfile::tempdir().unwrap();
        let copy = dir.path().join("CallSequenceFuzz.so");
        std::fs::copy(fmu_library(), &copy).unwrap();
        let raw = Raw::load(&copy);
        // SAFETY: the kneebench binary again (the same handle); the two functions take no
        // arguments and return static C strings (fmi2GetVersionTYPE, fmi2GetTypesPlatformTYPE).
        let (lib, version, types_platform) = unsafe {
            let lib = libloading::Library::new(&copy).unwrap();
            let version: unsafe extern "C" fn() -> *const c_char =
                *lib.get(b"fmi2GetVersion\0").unwrap();
            let types_platform: unsafe extern "C" fn() -> *const c_char =
                *lib.get(b"fmi2GetTypesPlatform\0").unwrap();
            (lib, version, types_platform)
        };
        Library {
            raw,
            version,
            types_platform,
            _lib: lib,
        }
    })
}

/// The addresses of the live FMU states of the private binary (a mirror of its registry),
/// locked around every call that makes or frees an instance or a state.
static LIVE: Mutex<Vec<usize>> = Mutex::new(Vec::new());

/// The lock of [`LIVE`]; a test that failed while holding it leaves it consistent (every
/// update follows the call it mirrors).
pub(crate) fn live() -> MutexGuard<'static, Vec<usize>> {
    LIVE.lock().unwrap_or_else(PoisonError::into_inner)
}

// ---------------------------------------------------------------------------------------------
// What the model description says.

/// A base type, numbered as the glue numbers them.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Ty {
    Real = 0,
    Integer = 1,
    Boolean = 2,
    String = 3,
}

/// One variable of the model description.
#[derive(Debug, Clone)]
pub(crate) struct Var {
    pub(crate) vr: u32,
    ty: Ty,
    pub(crate) causality: Causality,
    variability: Variability,
    pub(crate) min: Option<f64>,
    pub(crate) max: Option<f64>,
    pub(crate) whole: bool,
    pub(crate) start_real: f64,
    pub(crate) start_string: String,
}

impl Var {
    /// Whether the glue lets an importer set it in `phase` (0 instantiated, 1 initialization,
    /// 2 stepping): the standard's rules for causality and variability.
    pub(crate) fn settable(&self, phase: usize) -> bool {
        match (self.causality, self.variability) {
            (_, Variability::Constant) => false,
            (Causality::Parameter, Variability::Fixed) => phase < 2,
            (Causality::Parameter, Variability::Tunable) | (Causality::Input, _) => true,
            _ => false,
        }
    }
}

/// A model as the fuzzer sees it.
pub(crate) struct Meta {
    pub(crate) identifier: &'static str,
    pub(crate) guid: String,
    pub(crate) vars: Vec<Var>,
    /// Indices into `vars`, per [`Ty`].
    pub(crate) of_type: [Vec<usize>; 4],
    /// `canGetAndSetFMUstate` and `canSerializeFMUstate` (equal for every model).
    pub(crate) states: bool,
    /// `maxOutputDerivativeOrder`.
    pub(crate) derivative_order: i32,
}

impl Meta {
    fn of(identifier: &'static str) -> Meta {
        let entry = kneebench_fmu::registry::find_by_identifier(identifier).expect("model");
        let info = entry.info();
        let md = &info.description;
        let cs = md.co_simulation.clone().expect("co-simulation");
        assert_eq!(
            cs.can_get_and_set_fmu_state, cs.can_serialize_fmu_state,
            "{identifier}: the fuzzer assumes both state flags equal"
        );
        let mut vars = Vec::new();
        for v in &md.model_variables {
            let (ty, min, max, start_real, start_string) = match &v.kind {
                VariableKind::Real {
                    attributes, start, ..
                } => (
                    Ty::Real,
                    attributes.min,
                    attributes.max,
                    start.unwrap_or(0.0),
                    String::new(),
                ),
                VariableKind::Integer {
                    attributes, start, ..
                } => (
                    Ty::Integer,
                    attributes.min.map(f64::from),
                    attributes.max.map(f64::from),
                    f64::from(start.unwrap_or(0)),
                    String::new(),
                ),
                VariableKind::Enumeration {
                    min, max, start, ..
                } => (
                    Ty::Integer,
                    min.map(f64::from),
                    max.map(f64::from),
                    f64::from(start.unwrap_or(0)),
                    String::new(),
                ),
                VariableKind::Boolean { start, .. } => (
                    Ty::Boolean,
                    None,
                    None,
                    f64::from(u8::from(start.unwrap_or(false))),
                    String::new(),
                ),
                VariableKind::String { start, .. } => (
                    Ty::String,
                    None,
                    None,
                    0.0,
                    start.clone().unwrap_or_default(),
                ),
            };
            vars.push(Var {
                vr: v.value_reference,
                ty,
                causality: v.causality.unwrap_or(Causality::Local),
                variability: v.variability.unwrap_or(Variability::Continuous),
                min,
                max,
                whole: v.is_integer_valued(),
                start_real,
                start_string,
            });
        }
        let mut of_type: [Vec<usize>; 4] = Default::default();
        for (i, v) in vars.iter().enumerate() {
            of_type[v.ty as usize].push(i);
        }
        Meta {
            identifier,
            guid: info.guid.clone(),
            vars,
            of_type,
            states: cs.can_get_and_set_fmu_state == Some(true),
            derivative_order: cs.max_output_derivative_order.unwrap_or(0) as i32,
        }
    }

    /// The variable with value reference `vr` of type `ty`.
    pub(crate) fn find(&self, ty: Ty, vr: u32) -> Option<&Var> {
        self.of_type[ty as usize]
            .iter()
            .map(|&i| &self.vars[i])
            .find(|v| v.vr == vr)
    }

    /// The value references of every variable of type `ty`, in declaration order.
    pub(crate) fn vrs(&self, ty: Ty) -> Vec<u32> {
        self.of_type[ty as usize]
            .iter()
            .map(|&i| self.vars[i].vr)
            .collect()
    }
}

/// The models' descriptions, built once.
pub(crate) fn meta(identifier: &str) -> &'static Meta {
    static METAS: OnceLock<Vec<Meta>> = OnceLock::new();
    METAS
        .get_or_init(|| MODELS.iter().map(|(id, _)| Meta::of(id)).collect())
        .iter()
        .find(|m| m.identifier == identifier)
        .expect("a fuzzed model")
}
