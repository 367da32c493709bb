//! The importer's calls, their arguments, and the proptest strategies that choose them.

use std::ffi::c_int;

use proptest::prelude::*;

use crate::library::Ty;
use crate::values::NULL_COMPONENT_CALLS;
use crate::{MAX_CALLS, SLOTS, UNKNOWN_VR};

// ---------------------------------------------------------------------------------------------
// The calls.

/// A value reference of a get or set.
#[derive(Debug, Clone)]
pub(crate) enum Ref {
    /// The n-th variable of the call's type (modulo their number).
    Var(u16),
    /// The n-th variable of any type (modulo their number): usually another type's.
    AnyVar(u16),
    /// The previous reference of the list again (the first variable if none).
    Again,
    /// A raw value reference (mostly unknown).
    Raw(u32),
}

/// A value of a set, resolved against the variable it is for.
#[derive(Debug, Clone, Copy)]
pub(crate) enum Value {
    Start,
    Min,
    Max,
    Mid,
    BelowMin,
    AboveMax,
    Fraction,
    Nan,
    Inf,
    NegInf,
    Huge,
    NegHuge,
    Zero,
    One,
    Tiny,
}

/// Which array arguments of a get or set are NULL.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Nulls {
    None,
    Refs,
    Values,
    Both,
}

/// The categories of `fmi2SetDebugLogging`.
#[derive(Debug, Clone)]
pub(crate) enum Categories {
    /// None: every category.
    All,
    /// Declared categories, by index (modulo their number).
    Known(Vec<u8>),
    /// A declared one and one that is not.
    Unknown,
    /// NULL with a non-zero count.
    NullArray,
    /// A NULL name in the array.
    NullName,
}

/// The communication point of a step, relative to the instance's.
#[derive(Debug, Clone, Copy)]
pub(crate) enum At {
    Now,
    /// Within the glue's tolerance.
    Near,
    Later,
    Earlier,
    Zero,
    Nan,
    Inf,
}

/// The buffer of `fmi2SerializeFMUstate`.
#[derive(Debug, Clone, Copy)]
pub(crate) enum Buffer {
    Exact,
    Larger,
    Short(u16),
    Null,
}

/// What is done to serialized bytes before they are deserialized.
#[derive(Debug, Clone)]
pub(crate) enum Damage {
    None,
    Truncate(u16),
    Flip(u16, u8),
    Append(Vec<u8>),
    Garbage(Vec<u8>),
    Empty,
    /// NULL bytes with a non-zero size.
    Null,
    /// The state code forged (0..=6 valid, else not), resealed.
    Code(u8),
    /// The communication point forged to NaN, resealed.
    NanTime,
}

/// A status function.
#[derive(Debug, Clone, Copy)]
pub(crate) enum StatusFn {
    Status,
    Real,
    Integer,
    Boolean,
    String,
}

/// One call of the importer.
#[derive(Debug, Clone)]
pub(crate) enum Call {
    SetDebugLogging {
        on: bool,
        categories: Categories,
    },
    SetupExperiment {
        tolerance: Option<f64>,
        start: f64,
        stop: Option<f64>,
    },
    EnterInitializationMode,
    ExitInitializationMode,
    Terminate,
    Reset,
    Get {
        ty: Ty,
        refs: Vec<Ref>,
        nulls: Nulls,
    },
    Set {
        ty: Ty,
        refs: Vec<Ref>,
        values: Vec<Value>,
        nulls: Nulls,
    },
    GetRealOutputDerivatives {
        refs: Vec<Ref>,
        orders: Vec<i32>,
        nulls: Nulls,
    },
    SetRealInputDerivatives {
        refs: Vec<Ref>,
    },
    GetDirectionalDerivative,
    DoStep {
        at: At,
        h: f64,
    },
    CancelStep,
    Status {
        function: StatusFn,
        kind: c_int,
        null_value: bool,
    },
    GetFmuState {
        slot: usize,
        null_out: bool,
    },
    SetFmuState {
        slot: usize,
    },
    FreeFmuState {
        slot: usize,
        null_out: bool,
    },
    SerializedSize {
        slot: usize,
        null_size: bool,
    },
    Serialize {
        slot: usize,
        buffer: Buffer,
    },
    Deserialize {
        blob: usize,
        damage: Damage,
        slot: usize,
        null_out: bool,
    },
    /// A live state of another instance of the same model into a slot.
    PeerState {
        slot: usize,
    },
    /// A live state of another model into a slot.
    ForeignState {
        slot: usize,
    },
    /// A live slot freed through a copy of its pointer (the slot keeps the dangling pointer);
    /// an empty one given a freed address or one never made.
    Dangle {
        slot: usize,
        pick: u8,
    },
    /// Function number `function` of [`NULL_COMPONENT_CALLS`] with a NULL component.
    NullComponent {
        function: usize,
    },
    /// `fmi2FreeInstance` (twice if `twice`), then a new instance.
    FreeAndInstantiate {
        twice: bool,
    },
    /// `fmi2GetVersion` and `fmi2GetTypesPlatform`.
    Version,
}

fn ty() -> impl Strategy<Value = Ty> {
    prop_oneof![
        4 => Just(Ty::Real),
        2 => Just(Ty::Integer),
        2 => Just(Ty::Boolean),
        1 => Just(Ty::String),
    ]
}

fn reference() -> impl Strategy<Value = Ref> {
    prop_oneof![
        8 => any::<u16>().prop_map(Ref::Var),
        1 => any::<u16>().prop_map(Ref::AnyVar),
        1 => Just(Ref::Again),
        1 => prop_oneof![
            Just(0u32),
            Just(UNKNOWN_VR),
            Just(u32::MAX),
            Just(1u32 << 16),
            0u32..600,
        ]
        .prop_map(Ref::Raw),
    ]
}

fn references() -> impl Strategy<Value = Vec<Ref>> {
    prop::collection::vec(reference(), 0..5)
}

fn value() -> impl Strategy<Value = Value> {
    use Value::*;
    prop_oneof![
        6 => Just(Start),
        2 => Just(Mid),
        1 => prop::sample::select(vec![
            Min, Max, BelowMin, AboveMax, Fraction, Nan, Inf, NegInf, Huge, NegHuge, Zero, One,
            Tiny,
        ]),
        2 => prop::sample::select(vec![Min, Max, Zero, One]),
    ]
}

fn nulls() -> impl Strategy<Value = Nulls> {
    prop_oneof![
        12 => Just(Nulls::None),
        1 => prop::sample::select(vec![Nulls::Refs, Nulls::Values, Nulls::Both]),
    ]
}

fn time_value() -> impl Strategy<Value = f64> {
    prop::sample::select(vec![
        0.0,
        1.5,
        -2.0,
        -0.0,
        1e9,
        1e300,
        f64::NAN,
        f64::INFINITY,
        f64::NEG_INFINITY,
    ])
}

fn step_size() -> impl Strategy<Value = f64> {
    prop_oneof![
        8 => prop::sample::select(vec![1e-3, 2e-3, 1e-2]),
        2 => prop::sample::select(vec![
            0.1,
            0.0,
            -0.0,
            -1e-3,
            f64::NAN,
            f64::INFINITY,
            f64::NEG_INFINITY,
            1e300,
            1e9,
            f64::MAX,
            5e-324,
            1e-300,
        ]),
    ]
}

fn slot() -> impl Strategy<Value = usize> {
    0..SLOTS
}

fn damage() -> impl Strategy<Value = Damage> {
    prop_oneof![
        4 => Just(Damage::None),
        1 => any::<u16>().prop_map(Damage::Truncate),
        1 => (any::<u16>(), 1u8..).prop_map(|(at, x)| Damage::Flip(at, x)),
        1 => prop::collection::vec(any::<u8>(), 1..9).prop_map(Damage::Append),
        1 => prop::collection::vec(any::<u8>(), 0..64).prop_map(Damage::Garbage),
        1 => Just(Damage::Empty),
        1 => Just(Damage::Null),
        3 => prop::sample::select(vec![0u8, 1, 2, 3, 4, 5, 6, 7, 255]).prop_map(Damage::Code),
        1 => Just(Damage::NanTime),
    ]
}

/// One call, weighted so that sequences reach every state: initialization and steps are
/// frequent, the rest mixed in.
fn call() -> impl Strategy<Value = Call> {
    prop_oneof![
        2 => (any::<bool>(), prop_oneof![
            2 => Just(Categories::All),
            2 => prop::collection::vec(any::<u8>(), 1..3).prop_map(Categories::Known),
            1 => Just(Categories::Unknown),
            1 => Just(Categories::NullArray),
            1 => Just(Categories::NullName),
        ])
            .prop_map(|(on, categories)| Call::SetDebugLogging { on, categories }),
        4 => (
            prop::option::weighted(0.2, prop::sample::select(vec![1e-6, 0.0, -1.0, f64::NAN])),
            prop_oneof![3 => Just(0.0), 1 => time_value()],
            prop::option::weighted(0.4, prop_oneof![
                3 => prop::sample::select(vec![0.05, 1.0, 1e300]),
                1 => time_value(),
            ]),
        )
            .prop_map(|(tolerance, start, stop)| Call::SetupExperiment {
                tolerance,
                start,
                stop,
            }),
        9 => Just(Call::EnterInitializationMode),
        9 => Just(Call::ExitInitializationMode),
        2 => Just(Call::Terminate),
        2 => Just(Call::Reset),
        10 => (ty(), references(), nulls())
            .prop_map(|(ty, refs, nulls)| Call::Get { ty, refs, nulls }),
        10 => (ty(), references(), prop::collection::vec(value(), 4), nulls()).prop_map(
            |(ty, refs, mut values, nulls)| {
                values.truncate(refs.len());
                Call::Set {
                    ty,
                    refs,
                    values,
                    nulls,
                }
            }
        ),
        2 => (
            references(),
            prop::collection::vec(prop::sample::select(vec![1, 1, 0, 2, -1]), 4),
            nulls(),
        )
            .prop_map(|(refs, mut orders, nulls)| {
                orders.truncate(refs.len());
                Call::GetRealOutputDerivatives {
                    refs,
                    orders,
                    nulls,
                }
            }),
        1 => references().prop_map(|refs| Call::SetRealInputDerivatives { refs }),
        1 => Just(Call::GetDirectionalDerivative),
        14 => (
            prop_oneof![
                8 => Just(At::Now),
                1 => Just(At::Near),
                1 => prop::sample::select(vec![At::Later, At::Earlier, At::Zero, At::Nan, At::Inf]),
            ],
            step_size(),
        )
            .prop_map(|(at, h)| Call::DoStep { at, h }),
        1 => Just(Call::CancelStep),
        4 => (
            prop::sample::select(vec![
                StatusFn::Status,
                StatusFn::Real,
                StatusFn::Integer,
                StatusFn::Boolean,
                StatusFn::String,
            ]),
            prop_oneof![3 => 0..4, 1 => prop::sample::select(vec![-1, 4, 99, c_int::MIN])],
            prop::bool::weighted(0.1),
        )
            .prop_map(|(function, kind, null_value)| Call::Status {
                function,
                kind,
                null_value,
            }),
        3 => (slot(), prop::bool::weighted(0.1))
            .prop_map(|(slot, null_out)| Call::GetFmuState { slot, null_out }),
        3 => slot().prop_map(|slot| Call::SetFmuState { slot }),
        2 => (slot(), prop::bool::weighted(0.1))
            .prop_map(|(slot, null_out)| Call::FreeFmuState { slot, null_out }),
        1 => (slot(), prop::bool::weighted(0.2))
            .prop_map(|(slot, null_size)| Call::SerializedSize { slot, null_size }),
        2 => (slot(), prop_oneof![
            4 => Just(Buffer::Exact),
            1 => Just(Buffer::Larger),
            1 => any::<u16>().prop_map(Buffer::Short),
            1 => Just(Buffer::Null),
        ])
            .prop_map(|(slot, buffer)| Call::Serialize { slot, buffer }),
        3 => (any::<u8>().prop_map(usize::from), damage(), slot(), prop::bool::weighted(0.05))
            .prop_map(|(blob, damage, slot, null_out)| Call::Deserialize {
                blob,
                damage,
                slot,
                null_out,
            }),
        1 => slot().prop_map(|slot| Call::PeerState { slot }),
        1 => slot().prop_map(|slot| Call::ForeignState { slot }),
        1 => (slot(), any::<u8>()).prop_map(|(slot, pick)| Call::Dangle { slot, pick }),
        1 => (0..NULL_COMPONENT_CALLS).prop_map(|function| Call::NullComponent { function }),
        1 => any::<bool>().prop_map(|twice| Call::FreeAndInstantiate { twice }),
        1 => Just(Call::Version),
    ]
}

pub(crate) fn calls() -> impl Strategy<Value = Vec<Call>> {
    prop::collection::vec(call(), 1..=MAX_CALLS)
}
