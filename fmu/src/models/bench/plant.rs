//! The switched, exactly discretised plant: modes, events, energy accounting and state.

use std::sync::Arc;

use super::friction::{Side, SideLaw};
use super::mechanics::{
    Antiderivative, AugMatrix, AugVector, CURRENT1, CURRENT2, DRIVE1, DRIVE2, Discretization,
    FRICTION1, FRICTION2, LinearMode, NZ, OMEGA1, OMEGA2, PIECE_TERMS, SegmentIntegrals, THETA1,
    THETA2, TaylorSegment, poly_eval, poly_eval_many, rate_scale, system_matrix,
};
use super::{
    BenchInputs, BenchParameters, DriverMode, InputError, Interlock, ParameterError, StepOutcome,
};

/// Largest number of located events inside one internal sub-step before switching is frozen
/// for the rest of that sub-step (guards against Zeno chattering at a tangency).
const EVENT_BUDGET: usize = 64;
/// Cached discretisations kept per plant (modes x step sizes).
const CACHE_CAPACITY: usize = 32;
/// Discretisations kept process-wide, shared by every plant (instances, runs, studies).
const SHARED_CACHE_CAPACITY: usize = 256;

/// Key of a shared discretisation: the bits of the system matrix and of the step. Equal keys
/// give bit-identical discretisations, so sharing never changes a result.
type SharedKey = ([u64; NZ * NZ], u64);

/// Exact discretisations already computed in this process. Building one costs ~0.1 ms (the
/// Gramians by doubling), about a hundred plant steps, and every run with the same parameters
/// meets the same few modes; a lookup happens only when a plant's own small cache misses.
static SHARED_DISCRETIZATIONS: std::sync::Mutex<
    Option<std::collections::HashMap<SharedKey, Arc<Discretization>>>,
> = std::sync::Mutex::new(None);

/// Empties the shared cache (the library is being unloaded: `crate::release`).
pub(crate) fn release_shared_discretizations() {
    drop(
        SHARED_DISCRETIZATIONS
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .take(),
    );
}

/// The discretisation of `m` (mode `key`) at step `h`, from the shared cache or built now.
fn shared_discretization(m: &AugMatrix, key: u8, h: f64) -> Arc<Discretization> {
    let mut bits = [0u64; NZ * NZ];
    for (b, v) in bits.iter_mut().zip(m.iter()) {
        *b = v.to_bits();
    }
    let shared_key = (bits, h.to_bits());
    // A poisoned lock only means another thread panicked while holding it; the map itself is
    // always consistent (inserts are single calls), so keep using it.
    let found = SHARED_DISCRETIZATIONS
        .lock()
        .unwrap_or_else(|e| e.into_inner())
        .as_ref()
        .and_then(|map| map.get(&shared_key).cloned());
    if let Some(found) = found {
        return found;
    }
    // Built outside the lock: other plants keep stepping meanwhile.
    let built = Arc::new(Discretization::new(m, key, h));
    let mut guard = SHARED_DISCRETIZATIONS
        .lock()
        .unwrap_or_else(|e| e.into_inner());
    let map = guard.get_or_insert_with(Default::default);
    if map.len() >= SHARED_CACHE_CAPACITY {
        map.clear();
    }
    map.entry(shared_key).or_insert(built).clone()
}

/// Energy integrals since the start [J], signed and positive part ("consumed").
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub(crate) struct EnergyAccount {
    pub test_mechanical: f64,
    pub test_mechanical_consumed: f64,
    pub load_mechanical: f64,
    pub load_mechanical_consumed: f64,
    pub actuation_loss: f64,
    pub load_loss: f64,
    pub test_electrical: f64,
    pub test_electrical_consumed: f64,
    pub load_electrical: f64,
    pub load_electrical_consumed: f64,
    pub clutch: f64,
    pub offset: f64,
    pub total_electrical: f64,
    pub total_electrical_consumed: f64,
    pub test_copper_loss: f64,
    pub load_copper_loss: f64,
    pub test_back_emf: f64,
    pub load_back_emf: f64,
}

impl EnergyAccount {
    pub(crate) const COUNT: usize = 18;

    pub(crate) fn to_array(self) -> [f64; Self::COUNT] {
        [
            self.test_mechanical,
            self.test_mechanical_consumed,
            self.load_mechanical,
            self.load_mechanical_consumed,
            self.actuation_loss,
            self.load_loss,
            self.test_electrical,
            self.test_electrical_consumed,
            self.load_electrical,
            self.load_electrical_consumed,
            self.clutch,
            self.offset,
            self.total_electrical,
            self.total_electrical_consumed,
            self.test_copper_loss,
            self.load_copper_loss,
            self.test_back_emf,
            self.load_back_emf,
        ]
    }

    pub(crate) fn from_array(a: [f64; Self::COUNT]) -> Self {
        Self {
            test_mechanical: a[0],
            test_mechanical_consumed: a[1],
            load_mechanical: a[2],
            load_mechanical_consumed: a[3],
            actuation_loss: a[4],
            load_loss: a[5],
            test_electrical: a[6],
            test_electrical_consumed: a[7],
            load_electrical: a[8],
            load_electrical_consumed: a[9],
            clutch: a[10],
            offset: a[11],
            total_electrical: a[12],
            total_electrical_consumed: a[13],
            test_copper_loss: a[14],
            load_copper_loss: a[15],
            test_back_emf: a[16],
            load_back_emf: a[17],
        }
    }
}

/// Values held constant over a segment.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Held {
    pub mode: LinearMode,
    /// Driver input slot value (voltage or current set value).
    pub drive: [f64; 2],
    /// Current set value of a current-type driver (0 for a disabled one).
    pub reference: [f64; 2],
    /// Whether the motor's driver runs its current loop (current mode or disabled).
    pub current_loop: [bool; 2],
    /// Friction torque applied to each body while sliding (incl. clutch) [N m].
    pub friction: [f64; 2],
    pub laws: [SideLaw; 2],
    /// Static capacity per body against + and - motion [N m].
    pub capacity: [[f64; 2]; 2],
    pub clutch: bool,
}

/// What an event function describes; positive value = happened.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum Event {
    Reversal(usize),
    BreakAway(usize, f64),
    SaturationEnter(usize, f64),
    SaturationExit(usize),
    Trip(Interlock),
}

/// The switching event functions (every event function but the trips, which are always
/// active) in the order of the event list: bit `k` of an active set stands for entry `k`. At
/// most one of a body's reversal and break-aways, and of a motor's saturation exit and entries,
/// is active at a time.
const SWITCHING_EVENTS: [Event; 12] = [
    Event::Reversal(0),
    Event::BreakAway(0, 1.0),
    Event::BreakAway(0, -1.0),
    Event::Reversal(1),
    Event::BreakAway(1, 1.0),
    Event::BreakAway(1, -1.0),
    Event::SaturationExit(0),
    Event::SaturationEnter(0, 1.0),
    Event::SaturationEnter(0, -1.0),
    Event::SaturationExit(1),
    Event::SaturationEnter(1, 1.0),
    Event::SaturationEnter(1, -1.0),
];

/// The active switching event functions of a mode: bit `k` set for `SWITCHING_EVENTS[k]`. A
/// bit set, not a list, on the regular path: it costs no list to build and copy per sub-step.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct ActiveEvents(u16);

impl ActiveEvents {
    /// The active switching events, in list order.
    #[inline(always)]
    fn iter(self) -> impl Iterator<Item = Event> {
        let mut bits = self.0;
        std::iter::from_fn(move || {
            (bits != 0).then(|| {
                let k = bits.trailing_zeros() as usize;
                bits &= bits - 1;
                SWITCHING_EVENTS[k]
            })
        })
    }
}

/// Everything that evolves.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct DynamicState {
    pub time: f64,
    pub z: AugVector,
    pub stuck: [bool; 2],
    pub direction: [f64; 2],
    pub saturation: [f64; 2],
    pub clutch: bool,
    pub trip: Option<(Interlock, f64)>,
    pub energy: EnergyAccount,
    pub clamp_count: u64,
    pub last_clamped: bool,
    pub inputs: BenchInputs,
}

/// The plant (see the module documentation).
#[derive(Debug, Clone)]
pub struct BenchPlant {
    pub(crate) params: BenchParameters,
    pub(crate) state: DynamicState,
    /// System matrix and rate scale of every mode, indexed by [`LinearMode::key`].
    matrices: Box<[(AugMatrix, f64); MODES]>,
    derived: Derived,
    cache: Vec<Arc<Discretization>>,
    /// Index in `cache` of the last discretisation used.
    last_hit: usize,
    /// Whether the step runs its AVX2 build (see [`BenchPlant::step`]). Private: true only
    /// where the CPU has AVX2 (a soundness condition); read through `runs_wide`.
    wide_vectors: bool,
    /// Storage of the Taylor segments of event sub-steps (not state: rebuilt by each use).
    segment_scratch: TaylorSegment,
}

/// Whether this CPU runs the plant's AVX2 build of the step.
pub(crate) fn cpu_has_wide_vectors() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx2")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// Products of parameters used in every step (same expressions as where they are used).
#[derive(Debug, Clone, Copy)]
struct Derived {
    /// Output-side torque per ampere of each motor.
    torque_per_ampere: [f64; 2],
    /// (R, L, Ke*G, supply, current limit) per motor.
    motors: [(f64, f64, f64, f64, f64); 2],
    /// Current-loop voltage gain `L / tau_c` per motor.
    loop_gain: [f64; 2],
    /// (sin, cos) of the calibration phase of the load cell and of the transducer.
    sensor_phases: [(f64, f64); 2],
    /// The friction laws and their static capacities (clutch disengaged) when neither depends
    /// on the state (every model but the loss surface, whose law moves with the load torque).
    static_laws: Option<([SideLaw; 2], [[f64; 2]; 2])>,
}

impl Derived {
    fn of(p: &BenchParameters) -> Self {
        let motors = [
            (
                p.test_motor_resistance,
                p.test_motor_inductance,
                p.test_motor_back_emf_constant * p.harmonic_drive_ratio,
                p.test_supply_voltage,
                p.test_current_limit,
            ),
            (
                p.load_motor_resistance,
                p.load_motor_inductance,
                p.load_motor_back_emf_constant * p.reduction_ratio,
                p.load_supply_voltage,
                p.load_current_limit,
            ),
        ];
        Self {
            torque_per_ampere: [
                p.harmonic_drive_ratio * p.test_motor_torque_constant,
                p.reduction_ratio * p.load_motor_torque_constant,
            ],
            motors,
            loop_gain: [
                motors[0].1 / p.current_loop_time_constant,
                motors[1].1 / p.current_loop_time_constant,
            ],
            sensor_phases: [
                (p.load_cell_phase.sin(), p.load_cell_phase.cos()),
                (p.transducer_phase.sin(), p.transducer_phase.cos()),
            ],
            static_laws: {
                let laws = [
                    SideLaw::of(p, Side::Actuation, 0.0),
                    SideLaw::of(p, Side::Load, 0.0),
                ];
                (!laws.iter().any(|l| matches!(l, SideLaw::Surface { .. }))).then(|| {
                    let capacity = laws.map(|law| [law.capacity(p, 1.0), law.capacity(p, -1.0)]);
                    (laws, capacity)
                })
            },
        }
    }
}

/// Number of linear modes (see [`LinearMode::key`]).
const MODES: usize = 16;

/// `M` and its rate scale for every mode.
fn all_matrices(params: &BenchParameters) -> Box<[(AugMatrix, f64); MODES]> {
    let mut out = Box::new([(AugMatrix::zeros(), 0.0); MODES]);
    for (key, entry) in out.iter_mut().enumerate() {
        let m = system_matrix(params, LinearMode::from_key(key as u8));
        *entry = (m, rate_scale(&m));
    }
    out
}

/// `M z` (the rows of the held inputs are zero).
fn multiply(m: &AugMatrix, z: &AugVector) -> AugVector {
    let mut out = [0.0; NZ];
    for (r, o) in out.iter_mut().enumerate().take(6) {
        let mut acc = m[(r, 0)] * z[0];
        for (c, v) in z.iter().enumerate().skip(1) {
            acc += m[(r, c)] * v;
        }
        *o = acc;
    }
    out
}

fn sign(x: f64) -> f64 {
    if x >= 0.0 { 1.0 } else { -1.0 }
}

impl BenchPlant {
    /// A plant at rest at angle 0, time 0, both bodies held by friction where there is any.
    pub fn new(params: BenchParameters) -> Result<Self, ParameterError> {
        params.validate()?;
        let mut plant = Self {
            matrices: all_matrices(&params),
            derived: Derived::of(&params),
            params,
            state: DynamicState {
                time: 0.0,
                z: [0.0; 10],
                stuck: [false; 2],
                direction: [1.0; 2],
                saturation: [0.0; 2],
                clutch: false,
                trip: None,
                energy: EnergyAccount::default(),
                clamp_count: 0,
                last_clamped: false,
                inputs: BenchInputs::default(),
            },
            cache: Vec::new(),
            last_hit: 0,
            wide_vectors: cpu_has_wide_vectors(),
            segment_scratch: TaylorSegment::default(),
        };
        plant.settle_sticking();
        Ok(plant)
    }

    /// Replaces the parameters; they take effect at the next step. The state is kept.
    pub fn set_parameters(&mut self, params: BenchParameters) -> Result<(), ParameterError> {
        params.validate()?;
        self.matrices = all_matrices(&params);
        self.derived = Derived::of(&params);
        self.params = params;
        self.cache.clear();
        // Friction may have appeared or gone: the outputs read before the next step show it.
        self.settle_sticking();
        Ok(())
    }

    /// The parameters in force.
    pub fn parameters(&self) -> &BenchParameters {
        &self.params
    }

    /// Simulation time \[s\].
    pub fn time(&self) -> f64 {
        self.state.time
    }

    /// The latched trip, if any: interlock and the time it tripped.
    pub fn trip(&self) -> Option<(Interlock, f64)> {
        self.state.trip
    }

    /// Whether the AVX2 builds of the step and the outputs run (the CPU has AVX2 and they were
    /// not turned off); always false off x86-64.
    #[inline(always)]
    pub(super) fn runs_wide(&self) -> bool {
        self.wide_vectors
    }

    /// Runs the baseline build from now on (tests compare the two builds).
    #[cfg(test)]
    pub(super) fn use_baseline_build(&mut self) {
        self.wide_vectors = false;
    }

    /// Advances by the communication step `h` \[s\] with `inputs` held over the step.
    pub fn step(&mut self, inputs: &BenchInputs, h: f64) -> StepOutcome {
        #[cfg(target_arch = "x86_64")]
        if self.runs_wide() {
            // SAFETY: `wide_vectors` is set only where the CPU reports AVX2
            // (`cpu_has_wide_vectors`), the one feature `step_wide` is compiled for.
            return unsafe { self.step_wide(inputs, h) };
        }
        self.step_inline(inputs, h)
    }

    /// [`Self::step`] compiled for AVX2: the same operations in the same order (no fused
    /// multiply-add, which would round differently), on wider registers; the regular path of
    /// the step is inlined into it. Bit-identical to the baseline build (tested).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn step_wide(&mut self, inputs: &BenchInputs, h: f64) -> StepOutcome {
        self.step_inline(inputs, h)
    }

    #[inline(always)]
    fn step_inline(&mut self, inputs: &BenchInputs, h: f64) -> StepOutcome {
        if let Some((interlock, time)) = self.state.trip {
            return StepOutcome::Tripped { interlock, time };
        }
        if !(h.is_finite() && h > 0.0) {
            return StepOutcome::Rejected(InputError::StepSize(h));
        }
        if let Err(e) = inputs.validate() {
            return StepOutcome::Rejected(e);
        }
        self.state.inputs = *inputs;
        if inputs.emergency_stop {
            return self.latch(Interlock::EmergencyStop, self.state.time);
        }
        self.state.clutch = inputs.clutch_engage;
        let start = self.state.time;
        // One sub-step when the communication step fits (the common case, no division).
        let substeps = if h <= self.params.max_internal_step {
            1.0
        } else {
            (h / self.params.max_internal_step * (1.0 - 1e-12))
                .ceil()
                .max(1.0)
        };
        let sub_h = if substeps == 1.0 { h } else { h / substeps };
        let n = substeps as u64;
        for k in 0..n {
            if let Err((interlock, time)) = self.substep(sub_h) {
                return self.latch(interlock, time);
            }
            if k + 1 < n {
                self.state.time = start + h * ((k + 1) as f64 / substeps);
            }
        }
        self.state.time = start + h;
        StepOutcome::Completed
    }

    fn latch(&mut self, interlock: Interlock, time: f64) -> StepOutcome {
        self.state.trip = Some((interlock, time));
        self.state.time = time;
        // Safe state: nothing runs any more and the clutch is released. The inputs of the
        // tripping step are kept so the outputs show the values at the trip instant.
        self.state.clutch = false;
        StepOutcome::Tripped { interlock, time }
    }

    fn matrix(&self, mode: LinearMode) -> &(AugMatrix, f64) {
        &self.matrices[mode.key() as usize]
    }

    #[inline(always)]
    fn discretization(&mut self, mode: LinearMode, h: f64) -> usize {
        let key = mode.key();
        // Consecutive sub-steps mostly stay in one mode: try the last hit first.
        if let Some(d) = self.cache.get(self.last_hit)
            && d.key == key
            && d.step == h
        {
            return self.last_hit;
        }
        if let Some(i) = self.cache.iter().position(|d| d.key == key && d.step == h) {
            self.last_hit = i;
            return i;
        }
        if self.cache.len() >= CACHE_CAPACITY {
            self.cache.clear();
        }
        let discretization = shared_discretization(&self.matrix(mode).0, key, h);
        self.cache.push(discretization);
        self.last_hit = self.cache.len() - 1;
        self.last_hit
    }

    /// Output-side torque of each motor per ampere.
    fn torque_per_ampere(&self) -> [f64; 2] {
        self.derived.torque_per_ampere
    }

    /// (R, L, Ke*G, supply, current limit) per motor.
    fn motor(&self, n: usize) -> (f64, f64, f64, f64, f64) {
        self.derived.motors[n]
    }

    /// Voltage the current loop of motor `n` asks for at state `z`.
    fn voltage_demand(&self, held: &Held, n: usize, z: &AugVector) -> f64 {
        let (r, _, ke, _, _) = self.motor(n);
        let (i, w) = (z[CURRENT1 + n], z[OMEGA1 + n]);
        r * i + ke * w + self.derived.loop_gain[n] * (held.reference[n] - i)
    }

    /// Armature voltage applied to motor `n` at state `z`.
    fn armature_voltage(&self, held: &Held, n: usize, z: &AugVector) -> f64 {
        if held.mode.voltage_row[n] {
            held.drive[n]
        } else {
            self.voltage_demand(held, n, z)
        }
    }

    /// Net non-friction torque on body `j` at rest.
    fn drive_torque(&self, j: usize, z: &AugVector) -> f64 {
        let k = self.params.coupling_stiffness();
        let tpa = self.torque_per_ampere();
        let spring = k * (z[THETA1] - z[THETA2]);
        if j == 0 {
            tpa[0] * z[CURRENT1] - spring
        } else {
            tpa[1] * z[CURRENT2] + spring
        }
    }

    /// Builds the held values for the current discrete state and inputs.
    #[inline(always)]
    fn hold(&self) -> Held {
        let inputs = self.state.inputs;
        let p = &self.params;
        let (laws, mut capacity) = match self.derived.static_laws {
            Some(fixed) => fixed,
            None => {
                let load_torque = self.torque_per_ampere()[1] * self.state.z[CURRENT2];
                let laws = [
                    SideLaw::of(p, Side::Actuation, load_torque),
                    SideLaw::of(p, Side::Load, load_torque),
                ];
                let capacity = laws.map(|law| [law.capacity(p, 1.0), law.capacity(p, -1.0)]);
                (laws, capacity)
            }
        };
        if self.state.clutch {
            // The clutch holds the actuation side in both directions.
            let clutch_torque = p.clutch_output_torque();
            capacity[0][0] += clutch_torque;
            capacity[0][1] += clutch_torque;
        }
        let mut held = Held {
            mode: LinearMode {
                stuck: self.state.stuck,
                voltage_row: [false; 2],
            },
            drive: [0.0; 2],
            reference: [0.0; 2],
            current_loop: [true; 2],
            friction: [0.0; 2],
            laws,
            capacity,
            clutch: self.state.clutch,
        };
        for n in 0..2 {
            let (_, _, _, supply, limit) = self.motor(n);
            let (mode, command, enabled) = if n == 0 {
                (p.test_driver_mode, inputs.test_command, inputs.test_enable)
            } else {
                (p.load_driver_mode, inputs.load_command, inputs.load_enable)
            };
            if enabled && mode == DriverMode::Voltage {
                held.current_loop[n] = false;
                held.mode.voltage_row[n] = true;
                held.drive[n] = command.clamp(-supply, supply);
            } else {
                held.reference[n] = if enabled {
                    command.clamp(-limit, limit)
                } else {
                    0.0
                };
                if self.state.saturation[n] != 0.0 {
                    held.mode.voltage_row[n] = true;
                    held.drive[n] = self.state.saturation[n] * supply;
                } else {
                    held.drive[n] = held.reference[n];
                }
            }
        }
        held
    }

    fn has_friction(held: &Held, j: usize) -> bool {
        held.capacity[j][0] > 0.0 && held.capacity[j][1] > 0.0
    }

    /// The stick/slip rule of the module docs applied at the current state: a stuck body breaks
    /// away when the net non-friction torque exceeds its capacity; a body at rest sticks when
    /// the torque is strictly within it; a moving body slides in its direction of motion.
    #[inline(always)]
    fn classify_sticking(&mut self, held: &Held) {
        for j in 0..2 {
            let w = self.state.z[OMEGA1 + j];
            let d = self.drive_torque(j, &self.state.z);
            let can_stick = Self::has_friction(held, j);
            if self.state.stuck[j] {
                if !can_stick || d > held.capacity[j][0] || -d > held.capacity[j][1] {
                    self.state.stuck[j] = false;
                    self.state.direction[j] = sign(d);
                }
            } else if w == 0.0 {
                // Strict: a body that has just broken away sits exactly at its capacity.
                if can_stick && d < held.capacity[j][0] && -d < held.capacity[j][1] {
                    self.state.stuck[j] = true;
                } else {
                    self.state.direction[j] = sign(d);
                }
            } else {
                self.state.direction[j] = sign(w);
            }
            if self.state.stuck[j] {
                self.state.z[OMEGA1 + j] = 0.0;
            }
        }
    }

    /// Applies the stick/slip rule at the current state outside a step, so that the outputs
    /// read before the next step (the t = 0 row above all) show the mode the plant holds: at
    /// rest with friction, a body is stuck (no friction torque, no acceleration), not sliding.
    fn settle_sticking(&mut self) {
        let held = self.hold();
        self.classify_sticking(&held);
    }

    /// Makes the discrete state consistent at the start of a segment and reports an interlock
    /// already beyond its threshold.
    #[inline(always)]
    fn resolve(&mut self) -> Result<Held, (Interlock, f64)> {
        let mut held = self.hold();
        self.classify_sticking(&held);
        held.mode.stuck = self.state.stuck;
        for n in 0..2 {
            if !held.current_loop[n] {
                self.state.saturation[n] = 0.0;
                continue;
            }
            let (_, _, _, supply, _) = self.motor(n);
            let demand = self.voltage_demand(&held, n, &self.state.z);
            let s = self.state.saturation[n];
            let new = if s != 0.0 && s * demand >= supply {
                s
            } else if demand.abs() > supply {
                sign(demand)
            } else {
                0.0
            };
            self.state.saturation[n] = new;
            if new != 0.0 {
                held.mode.voltage_row[n] = true;
                held.drive[n] = new * supply;
            } else {
                held.mode.voltage_row[n] = false;
                held.drive[n] = held.reference[n];
            }
        }
        self.set_friction(&mut held, None);
        self.state.last_clamped = false;
        if held.laws[0].speed_dependent() || held.laws[1].speed_dependent() {
            self.state.last_clamped = self.friction_clamped(&held);
            if self.state.last_clamped {
                self.state.clamp_count += 1;
            }
        }
        let z = self.input_state(&held);
        let demand = self.demands(&held, &z);
        for interlock in Interlock::CHECKED {
            if self.event_value_with(&held, Event::Trip(interlock), &z, &demand) > 0.0 {
                return Err((interlock, self.state.time));
            }
        }
        Ok(held)
    }

    fn friction_clamped(&self, held: &Held) -> bool {
        (0..2).any(|j| {
            !self.state.stuck[j]
                && held.laws[j]
                    .sliding_torque(
                        &self.params,
                        self.state.direction[j],
                        self.state.z[OMEGA1 + j].abs(),
                    )
                    .1
        })
    }

    /// Friction held over the segment: the law at the start speed, or the average of the start
    /// and predicted end speeds (`end`) for speed-dependent laws.
    #[inline(always)]
    fn set_friction(&self, held: &mut Held, end: Option<&AugVector>) {
        let clutch = if held.clutch {
            self.params.clutch_output_torque()
        } else {
            0.0
        };
        for j in 0..2 {
            if self.state.stuck[j] {
                held.friction[j] = 0.0;
                continue;
            }
            let s = self.state.direction[j];
            let law = held.laws[j];
            let start_speed = self.state.z[OMEGA1 + j].abs();
            let mut torque = law.sliding_torque(&self.params, s, start_speed).0;
            if let (Some(z1), true) = (end, law.speed_dependent()) {
                let end_speed = (s * z1[OMEGA1 + j]).max(0.0);
                // The loss surface also moves with the load torque: use its end value too.
                let end_law = match law {
                    SideLaw::Surface { .. } => SideLaw::Surface {
                        load_torque: self.torque_per_ampere()[1] * z1[CURRENT2],
                    },
                    other => other,
                };
                torque = 0.5 * (torque + end_law.sliding_torque(&self.params, s, end_speed).0);
            }
            held.friction[j] = torque - s * if j == 0 { clutch } else { 0.0 };
        }
    }

    #[inline(always)]
    fn input_state(&self, held: &Held) -> AugVector {
        let mut z = self.state.z;
        z[DRIVE1] = held.drive[0];
        z[DRIVE2] = held.drive[1];
        z[FRICTION1] = held.friction[0];
        z[FRICTION2] = held.friction[1];
        z
    }

    #[inline(always)]
    fn event_value(&self, held: &Held, event: Event, z: &AugVector) -> f64 {
        self.event_value_with(held, event, z, &self.demands(held, z))
    }

    /// Voltage demands of both current loops at `z` (see [`Self::voltage_demand`]).
    #[inline]
    fn demands(&self, held: &Held, z: &AugVector) -> [f64; 2] {
        [
            self.voltage_demand(held, 0, z),
            self.voltage_demand(held, 1, z),
        ]
    }

    /// Whether any trip or any of the `active` switching events is positive at `z`. The trips
    /// are checked with constant arguments, so their dispatch folds away.
    #[inline(always)]
    fn any_positive(&self, held: &Held, active: ActiveEvents, z: &AugVector) -> bool {
        let demand = self.demands(held, z);
        Interlock::CHECKED
            .into_iter()
            .any(|i| self.event_value_with(held, Event::Trip(i), z, &demand) > 0.0)
            || active
                .iter()
                .any(|e| self.event_value_with(held, e, z, &demand) > 0.0)
    }

    /// The event function `event` at `z`, given the voltage demands there.
    #[inline(always)]
    fn event_value_with(&self, held: &Held, event: Event, z: &AugVector, demand: &[f64; 2]) -> f64 {
        let p = &self.params;
        let tpa = self.torque_per_ampere();
        match event {
            Event::Reversal(j) => -self.state.direction[j] * z[OMEGA1 + j],
            Event::BreakAway(j, dir) => {
                let d = self.drive_torque(j, z);
                let cap = held.capacity[j][if dir > 0.0 { 0 } else { 1 }];
                dir * d - cap
            }
            Event::SaturationEnter(n, dir) => dir * demand[n] - self.motor(n).3,
            Event::SaturationExit(n) => self.motor(n).3 - self.state.saturation[n] * demand[n],
            Event::Trip(interlock) => match interlock {
                Interlock::SpringDeflection => {
                    (z[THETA1] - z[THETA2]).abs() - p.spring_deflection_limit
                }
                // The test side's torque past the harmonic drive: what the shaft carries
                // (see the module docs for why not i_HD Km1 i1).
                Interlock::TestMotorTorque => {
                    (p.coupling_stiffness() * (z[THETA1] - z[THETA2])).abs() - p.motor_torque_limit
                }
                Interlock::LoadMotorTorque => (tpa[1] * z[CURRENT2]).abs() - p.motor_torque_limit,
                Interlock::TestCurrent => z[CURRENT1].abs() - p.test_current_limit,
                Interlock::LoadCurrent => z[CURRENT2].abs() - p.load_current_limit,
                Interlock::RegenPower => {
                    let voltage = if held.mode.voltage_row[1] {
                        held.drive[1]
                    } else {
                        demand[1]
                    };
                    -voltage * z[CURRENT2] - p.load_regen_power_limit
                }
                Interlock::EmergencyStop => -1.0,
            },
        }
    }

    /// The switching event functions active in the held mode.
    #[inline(always)]
    fn active_events(&self, held: &Held) -> ActiveEvents {
        let mut bits = 0u16;
        for j in 0..2 {
            // Bits 3 j (reversal), 3 j + 1 and 3 j + 2 (break-away up and down).
            if self.state.stuck[j] {
                bits |= 0b110 << (3 * j);
            } else if Self::has_friction(held, j) || held.friction[j] != 0.0 {
                bits |= 0b001 << (3 * j);
            }
        }
        for n in 0..2 {
            // Bits 6 + 3 n (saturation exit), 7 + 3 n and 8 + 3 n (entry up and down).
            if held.current_loop[n] {
                if self.state.saturation[n] != 0.0 {
                    bits |= 0b001 << (6 + 3 * n);
                } else {
                    bits |= 0b110 << (6 + 3 * n);
                }
            }
        }
        ActiveEvents(bits)
    }

    /// Every active event function, the trips first, then the switching events in list order
    /// (an iterator: the event sub-step walks it once per segment without allocating).
    fn event_list(active: ActiveEvents) -> impl Iterator<Item = Event> {
        Interlock::CHECKED
            .into_iter()
            .map(Event::Trip)
            .chain(active.iter())
    }

    /// The five reported powers at `z`: test and load mechanical, test and load electrical, total
    /// electrical.
    #[inline(always)]
    fn powers(&self, held: &Held, z: &AugVector) -> [f64; 5] {
        let tpa = self.torque_per_ampere();
        let el1 = self.armature_voltage(held, 0, z) * z[CURRENT1];
        let el2 = self.armature_voltage(held, 1, z) * z[CURRENT2];
        [
            tpa[0] * z[CURRENT1] * z[OMEGA1],
            tpa[1] * z[CURRENT2] * z[OMEGA2],
            el1,
            el2,
            el1 + el2 + self.constant_power(held),
        ]
    }

    /// Time derivatives of the five reported powers at `z` (constant inputs).
    #[inline(always)]
    fn power_rates(&self, held: &Held, m: &AugMatrix, z: &AugVector) -> [f64; 5] {
        let dz = multiply(m, z);
        let tpa = self.torque_per_ampere();
        let mut electrical = [0.0; 2];
        for (n, e) in electrical.iter_mut().enumerate() {
            let (current, omega) = (CURRENT1 + n, OMEGA1 + n);
            let voltage = self.armature_voltage(held, n, z);
            let voltage_rate = if held.mode.voltage_row[n] {
                0.0
            } else {
                let (r, _, ke, _, _) = self.motor(n);
                let gain = self.derived.loop_gain[n];
                (r - gain) * dz[current] + ke * dz[omega]
            };
            *e = voltage_rate * z[current] + voltage * dz[current];
        }
        [
            tpa[0] * (dz[CURRENT1] * z[OMEGA1] + z[CURRENT1] * dz[OMEGA1]),
            tpa[1] * (dz[CURRENT2] * z[OMEGA2] + z[CURRENT2] * dz[OMEGA2]),
            electrical[0],
            electrical[1],
            electrical[0] + electrical[1],
        ]
    }

    #[inline(always)]
    fn constant_power(&self, held: &Held) -> f64 {
        self.params.hardware_offset_power
            + if held.clutch {
                self.params.clutch_power
            } else {
                0.0
            }
    }

    #[inline(always)]
    fn commit(&mut self, z: AugVector) {
        let start = self.state.z;
        self.state.z = z;
        for j in 0..2 {
            if self.state.stuck[j] {
                self.state.z[OMEGA1 + j] = 0.0;
                self.state.z[THETA1 + j] = start[THETA1 + j];
            }
        }
    }

    /// One internal sub-step of length `h`; returns a trip with its time. The common case (no
    /// event inside the sub-step) uses the cached exact discretisation; a sub-step with an event
    /// goes to [`Self::event_substep`], kept out of line so the common path stays small.
    #[inline(always)]
    fn substep(&mut self, h: f64) -> Result<(), (Interlock, f64)> {
        let start_time = self.state.time;
        let mut held = self.resolve()?;
        let speed_dependent = (0..2).any(|j| !held.mode.stuck[j] && held.laws[j].speed_dependent());
        let active = self.active_events(&held);
        let index = self.discretization(held.mode, h);
        let mut z0 = self.input_state(&held);
        let (mut z1, mut currents) = self.cache[index].advance_with_currents(&z0);
        if speed_dependent {
            self.set_friction(&mut held, Some(&z1));
            z0 = self.input_state(&held);
            (z1, currents) = self.cache[index].advance_with_currents(&z0);
        }
        if self.any_positive(&held, active, &z1) {
            return self.event_substep(held, h, start_time);
        }
        let p0 = self.powers(&held, &z0);
        let p1 = self.powers(&held, &z1);
        let sign_change = p0.iter().zip(p1.iter()).any(|(a, b)| a * b < 0.0);
        let rates = if sign_change {
            let m = &self.matrix(held.mode).0;
            Some((
                self.power_rates(&held, m, &z0),
                self.power_rates(&held, m, &z1),
            ))
        } else {
            None
        };
        let integrals = SegmentIntegrals {
            products: self.cache[index].quadratic_integrals(&z0),
            current1: currents[0],
            current2: currents[1],
        };
        self.accumulate_regular(&held, &z0, &z1, &integrals, (&p0, &p1), rates, h);
        self.commit(z1);
        Ok(())
    }

    /// A sub-step with events: Taylor segments from event to event, each event located on the
    /// exact flow and applied, until the sub-step's end (or a trip). Kept out of line, in the
    /// build the step runs (see [`Self::step`]), so the common path stays small.
    #[inline(always)]
    fn event_substep(
        &mut self,
        first_held: Held,
        h: f64,
        start_time: f64,
    ) -> Result<(), (Interlock, f64)> {
        #[cfg(target_arch = "x86_64")]
        if self.runs_wide() {
            // SAFETY: `wide_vectors` is set only where the CPU reports AVX2
            // (`cpu_has_wide_vectors`), the one feature `event_substep_wide` is compiled for.
            return unsafe { self.event_substep_wide(first_held, h, start_time) };
        }
        self.event_substep_baseline(first_held, h, start_time)
    }

    /// [`Self::event_substep`] compiled for AVX2, as [`Self::step_wide`] is: the same
    /// operations in the same order, the segments' polynomial loops on wider registers.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    #[inline(never)]
    fn event_substep_wide(
        &mut self,
        first_held: Held,
        h: f64,
        start_time: f64,
    ) -> Result<(), (Interlock, f64)> {
        self.event_substep_inline(first_held, h, start_time)
    }

    /// [`Self::event_substep`] in the baseline build.
    #[inline(never)]
    fn event_substep_baseline(
        &mut self,
        first_held: Held,
        h: f64,
        start_time: f64,
    ) -> Result<(), (Interlock, f64)> {
        self.event_substep_inline(first_held, h, start_time)
    }

    #[inline(always)]
    fn event_substep_inline(
        &mut self,
        first_held: Held,
        h: f64,
        start_time: f64,
    ) -> Result<(), (Interlock, f64)> {
        let mut segment = std::mem::take(&mut self.segment_scratch);
        let result = self.event_segments(&mut segment, first_held, h, start_time);
        segment.release_excess();
        self.segment_scratch = segment;
        result
    }

    /// [`Self::event_substep`] with `segment` as the storage of its segments.
    #[inline(always)]
    fn event_segments(
        &mut self,
        segment: &mut TaylorSegment,
        first_held: Held,
        h: f64,
        start_time: f64,
    ) -> Result<(), (Interlock, f64)> {
        let mut remaining = h;
        let mut budget = EVENT_BUDGET;
        let mut elapsed = 0.0;
        let mut next_held = Some(first_held);
        while remaining > 0.0 {
            self.state.time = start_time + elapsed;
            let mut held = match next_held.take() {
                Some(held) => held,
                None => self.resolve()?,
            };
            let speed_dependent =
                (0..2).any(|j| !held.mode.stuck[j] && held.laws[j].speed_dependent());
            let active = self.active_events(&held);
            let (m, rate) = *self.matrix(held.mode);
            let mut z0 = self.input_state(&held);
            segment.rebuild(&m, rate, &z0, remaining);
            if speed_dependent {
                let z1 = segment.state_at(remaining);
                self.set_friction(&mut held, Some(&z1));
                z0 = self.input_state(&held);
                segment.rebuild(&m, rate, &z0, remaining);
            }
            let earliest = if budget > 0 {
                self.earliest_event(&held, Self::event_list(active), segment)
            } else {
                None
            };
            let stop = earliest.map_or(remaining, |(t, _)| t);
            self.accumulate_segment(&held, segment, stop);
            let z1 = segment.state_at(stop);
            self.commit(z1);
            elapsed += stop;
            remaining -= stop;
            match earliest {
                None => break,
                Some((_, event)) => {
                    budget = budget.saturating_sub(1);
                    if let Event::Trip(interlock) = event {
                        return Err((interlock, start_time + elapsed));
                    }
                    self.apply_event(&held, event);
                }
            }
            if remaining <= h * 1e-13 {
                break;
            }
        }
        Ok(())
    }

    #[inline(always)]
    fn apply_event(&mut self, held: &Held, event: Event) {
        match event {
            Event::Reversal(j) => {
                self.state.z[OMEGA1 + j] = 0.0;
                let d = self.drive_torque(j, &self.state.z);
                if Self::has_friction(held, j)
                    && d <= held.capacity[j][0]
                    && -d <= held.capacity[j][1]
                {
                    self.state.stuck[j] = true;
                } else {
                    self.state.direction[j] = sign(d);
                }
            }
            Event::BreakAway(j, dir) => {
                self.state.stuck[j] = false;
                self.state.direction[j] = dir;
            }
            Event::SaturationEnter(n, dir) => self.state.saturation[n] = dir,
            Event::SaturationExit(n) => self.state.saturation[n] = 0.0,
            Event::Trip(_) => {}
        }
    }

    /// Earliest event in the segment: scan the piece ends for a function turning positive, then
    /// locate its root with the Illinois method on the exact flow.
    #[inline(always)]
    fn earliest_event(
        &self,
        held: &Held,
        events: impl Iterator<Item = Event>,
        segment: &TaylorSegment,
    ) -> Option<(f64, Event)> {
        let mut best: Option<(f64, Event)> = None;
        let z0 = segment.state_at(0.0);
        let ends: Vec<(f64, AugVector)> = segment
            .piece_ends()
            .map(|b| (b, segment.state_at(b)))
            .collect();
        for event in events {
            let mut a = 0.0;
            let mut ga = self.event_value(held, event, &z0).min(0.0);
            for (b, zb) in &ends {
                if let Some((t, _)) = best
                    && a >= t
                {
                    break;
                }
                let gb = self.event_value(held, event, zb);
                if gb > 0.0 {
                    let root = self.locate_root(held, event, segment, (a, ga), (*b, gb));
                    if best.is_none_or(|(t, _)| root < t) {
                        best = Some((root, event));
                    }
                    break;
                }
                a = *b;
                ga = gb;
            }
        }
        best
    }

    /// Root of an event function bracketed by `g(a) <= 0 < g(b)`; returns the first time at
    /// which it is positive or zero to within rounding (the right end of the final bracket).
    #[inline(always)]
    fn locate_root(
        &self,
        held: &Held,
        event: Event,
        segment: &TaylorSegment,
        (mut a, mut ga): (f64, f64),
        (mut b, mut gb): (f64, f64),
    ) -> f64 {
        let mut side = 0;
        for _ in 0..200 {
            if b - a <= 4.0 * f64::EPSILON * b.max(1e-300) {
                break;
            }
            let mut t = if gb - ga > 0.0 {
                b - gb * (b - a) / (gb - ga)
            } else {
                0.5 * (a + b)
            };
            if !(t > a && t < b) {
                t = 0.5 * (a + b);
            }
            let g = self.event_value(held, event, &segment.state_at(t));
            if g >= 0.0 {
                b = t;
                gb = g;
                if side == 1 {
                    ga *= 0.5;
                }
                side = 1;
            } else {
                a = t;
                ga = g;
                if side == -1 {
                    gb *= 0.5;
                }
                side = -1;
            }
        }
        b
    }

    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn accumulate_regular(
        &mut self,
        held: &Held,
        z0: &AugVector,
        z1: &AugVector,
        integrals: &SegmentIntegrals,
        (p0, p1): (&[f64; 5], &[f64; 5]),
        rates: Option<([f64; 5], [f64; 5])>,
        h: f64,
    ) {
        let mut electrical = [0.0; 2];
        for (n, e) in electrical.iter_mut().enumerate() {
            let current_integral = if n == 0 {
                integrals.current1
            } else {
                integrals.current2
            };
            *e = if held.mode.voltage_row[n] {
                held.drive[n] * current_integral
            } else {
                let (r, _, ke, _, _) = self.motor(n);
                let gain = self.derived.loop_gain[n];
                (r - gain) * integrals.products[2 + n]
                    + ke * integrals.products[4 + n]
                    + gain * held.reference[n] * current_integral
            };
        }
        let tpa = self.torque_per_ampere();
        let signed = [
            tpa[0] * integrals.products[4],
            tpa[1] * integrals.products[5],
            electrical[0],
            electrical[1],
            electrical[0] + electrical[1] + self.constant_power(held) * h,
        ];
        let mut positive = [0.0; 5];
        for k in 0..5 {
            positive[k] = match rates {
                Some((d0, d1)) if p0[k] * p1[k] < 0.0 => {
                    hermite_positive_part(p0[k], p1[k], d0[k] * h, d1[k] * h, signed[k], h)
                }
                _ if p0[k] > 0.0 || (p0[k] == 0.0 && p1[k] > 0.0) => signed[k],
                _ => 0.0,
            };
        }
        let squares = [integrals.products[0], integrals.products[1]];
        let copper = [integrals.products[2], integrals.products[3]];
        let emf = [integrals.products[4], integrals.products[5]];
        self.add_energy(held, z0, z1, signed, positive, squares, copper, emf, h);
    }

    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn add_energy(
        &mut self,
        held: &Held,
        z0: &AugVector,
        z1: &AugVector,
        signed: [f64; 5],
        positive: [f64; 5],
        squares: [f64; 2],
        copper: [f64; 2],
        emf: [f64; 2],
        duration: f64,
    ) {
        let p = &self.params;
        let (r1, _, ke1, _, _) = self.motor(0);
        let (r2, _, ke2, _, _) = self.motor(1);
        let damping = [p.actuation_damping, p.load_damping];
        let mut loss = [0.0; 2];
        for j in 0..2 {
            let travel = z1[THETA1 + j] - z0[THETA1 + j];
            loss[j] = if held.mode.stuck[j] {
                0.0
            } else {
                -damping[j] * squares[j] + held.friction[j] * travel
            };
        }
        let clutch = if held.clutch {
            p.clutch_power * duration
        } else {
            0.0
        };
        let offset = p.hardware_offset_power * duration;
        let e = &mut self.state.energy;
        e.test_mechanical += signed[0];
        e.test_mechanical_consumed += positive[0];
        e.load_mechanical += signed[1];
        e.load_mechanical_consumed += positive[1];
        e.actuation_loss += loss[0];
        e.load_loss += loss[1];
        e.test_electrical += signed[2];
        e.test_electrical_consumed += positive[2];
        e.load_electrical += signed[3];
        e.load_electrical_consumed += positive[3];
        e.clutch += clutch;
        e.offset += offset;
        e.total_electrical += signed[4];
        e.total_electrical_consumed += positive[4];
        e.test_copper_loss += r1 * copper[0];
        e.load_copper_loss += r2 * copper[1];
        e.test_back_emf += ke1 * emf[0];
        e.load_back_emf += ke2 * emf[1];
    }

    /// Energies over `[0, stop]` of a Taylor segment, positive parts split at sign changes.
    /// Per piece the six products (`w^2`, `i^2`, `i w` per side) are formed once; the powers are
    /// linear in them (`V i = a i^2 + b w i + c i` with the driver's affine voltage law).
    #[inline(always)]
    fn accumulate_segment(&mut self, held: &Held, segment: &TaylorSegment, stop: f64) {
        let tpa = self.torque_per_ampere();
        let mut signed = [0.0; 5];
        let mut positive = [0.0; 5];
        let mut squares = [0.0; 2];
        let mut copper = [0.0; 2];
        let mut emf = [0.0; 2];
        let constant = self.constant_power(held);
        let law = [self.voltage_law(held, 0), self.voltage_law(held, 1)];
        for piece in segment.pieces() {
            if piece.start >= stop {
                break;
            }
            let s_end = ((stop - piece.start) / piece.len).min(1.0);
            let n = piece.terms;
            let degree = 2 * n - 1;
            // weights[k] = integral_0^s_end s^k ds
            let mut weights = [0.0; 2 * PIECE_TERMS];
            let mut power = s_end;
            for (k, weight) in weights[..degree].iter_mut().enumerate() {
                *weight = power / (k + 1) as f64;
                power *= s_end;
            }
            let integral = |p: &[f64]| -> f64 {
                p.iter()
                    .zip(weights.iter())
                    .map(|(c, w)| c * w)
                    .sum::<f64>()
            };
            let mut w = [[0.0; PIECE_TERMS]; 2];
            let mut i = [[0.0; PIECE_TERMS]; 2];
            for (k, c) in piece.coefficients[..n].iter().enumerate() {
                w[0][k] = c[OMEGA1];
                w[1][k] = c[OMEGA2];
                i[0][k] = c[CURRENT1];
                i[1][k] = c[CURRENT2];
            }
            let mut ww = [[0.0; 2 * PIECE_TERMS]; 2];
            let mut ii = [[0.0; 2 * PIECE_TERMS]; 2];
            let mut wi = [[0.0; 2 * PIECE_TERMS]; 2];
            for j in 0..2 {
                square_into(&w[j][..n], &mut ww[j]);
                square_into(&i[j][..n], &mut ii[j]);
                product_into(&i[j][..n], &w[j][..n], &mut wi[j]);
            }
            let mut powers = [[0.0; 2 * PIECE_TERMS]; 5];
            for k in 0..degree {
                let linear = |j: usize| if k < n { i[j][k] } else { 0.0 };
                let el0 = law[0].0 * ii[0][k] + law[0].1 * wi[0][k] + law[0].2 * linear(0);
                let el1 = law[1].0 * ii[1][k] + law[1].1 * wi[1][k] + law[1].2 * linear(1);
                powers[0][k] = tpa[0] * wi[0][k];
                powers[1][k] = tpa[1] * wi[1][k];
                powers[2][k] = el0;
                powers[3][k] = el1;
                powers[4][k] = el0 + el1;
            }
            powers[4][0] += constant;
            for k in 0..5 {
                let p = &powers[k][..degree];
                let part = integral(p);
                signed[k] += piece.len * part;
                positive[k] += piece.len * positive_part(p, s_end, part);
            }
            for j in 0..2 {
                squares[j] += piece.len * integral(&ww[j][..degree]);
                copper[j] += piece.len * integral(&ii[j][..degree]);
                emf[j] += piece.len * integral(&wi[j][..degree]);
            }
        }
        let z0 = segment.state_at(0.0);
        let z1 = segment.state_at(stop);
        self.add_energy(held, &z0, &z1, signed, positive, squares, copper, emf, stop);
    }

    /// Armature voltage of motor `n` as `a i + b w + c` for the held mode.
    #[inline(always)]
    fn voltage_law(&self, held: &Held, n: usize) -> (f64, f64, f64) {
        if held.mode.voltage_row[n] {
            (0.0, 0.0, held.drive[n])
        } else {
            let (r, _, ke, _, _) = self.motor(n);
            let gain = self.derived.loop_gain[n];
            (r - gain, ke, gain * held.reference[n])
        }
    }

    /// Current discrete and continuous values needed for outputs.
    pub(crate) fn held_for_outputs(&self) -> Held {
        let mut held = self.hold();
        held.mode.stuck = self.state.stuck;
        for n in 0..2 {
            if held.current_loop[n] && self.state.saturation[n] != 0.0 {
                held.mode.voltage_row[n] = true;
                held.drive[n] = self.state.saturation[n] * self.motor(n).3;
            }
        }
        self.set_friction(&mut held, None);
        held
    }

    /// `z` with the held inputs and `z' = M z` at the current state.
    pub(crate) fn rates(&self, held: &Held) -> (AugVector, AugVector) {
        let z = self.input_state(held);
        let rate = multiply(&self.matrix(held.mode).0, &z);
        (z, rate)
    }

    /// `M v` for the held mode.
    pub(crate) fn apply_matrix(&self, held: &Held, v: &AugVector) -> AugVector {
        multiply(&self.matrix(held.mode).0, v)
    }

    pub(crate) fn powers_at(&self, held: &Held, z: &AugVector) -> [f64; 5] {
        self.powers(held, z)
    }

    pub(crate) fn armature_voltage_at(&self, held: &Held, n: usize, z: &AugVector) -> f64 {
        self.armature_voltage(held, n, z)
    }

    /// (sin, cos) of the calibration phases of the load cell and of the transducer.
    pub(crate) fn sensor_phases(&self) -> [(f64, f64); 2] {
        self.derived.sensor_phases
    }

    pub(crate) fn output_torque_per_ampere(&self) -> [f64; 2] {
        self.torque_per_ampere()
    }
}

/// Positive part of a power that changes sign inside a regular sub-step of length `h`, from a
/// cubic Hermite model of the power (end values `p0`, `p1`, end slopes times h `m0`, `m1`): the
/// model's positive part, plus the model's error against the exact signed integral `signed`
/// shared in proportion to the time the power is positive.
fn hermite_positive_part(p0: f64, p1: f64, m0: f64, m1: f64, signed: f64, h: f64) -> f64 {
    const SAMPLES: usize = 32;
    let mut positive = 0.0;
    let mut positive_samples = 0;
    for k in 0..SAMPLES {
        let s = (k as f64 + 0.5) / SAMPLES as f64;
        let (s2, s3) = (s * s, s * s * s);
        let value = (2.0 * s3 - 3.0 * s2 + 1.0) * p0
            + (s3 - 2.0 * s2 + s) * m0
            + (-2.0 * s3 + 3.0 * s2) * p1
            + (s3 - s2) * m1;
        if value > 0.0 {
            positive += value;
            positive_samples += 1;
        }
    }
    let model_total = h * (0.5 * (p0 + p1) + (m0 - m1) / 12.0);
    let fraction = positive_samples as f64 / SAMPLES as f64;
    (h * positive / SAMPLES as f64 + (signed - model_total) * fraction).max(0.0)
}

/// `integral_0^{s_end} max(p(s), 0) ds` given the signed integral `signed`: when
/// `|p(0)|` exceeds the bound `sum_k>0 |p_k| s_end^k` on the change over the piece the sign is
/// fixed, else [`positive_integral`].
#[inline(always)]
fn positive_part(p: &[f64], s_end: f64, signed: f64) -> f64 {
    let mut bound = 0.0;
    let mut power = 1.0;
    for c in &p[1..] {
        power *= s_end;
        bound += c.abs() * power;
    }
    let start = p[0];
    if start.abs() > bound * (1.0 + 1e-12) || bound == 0.0 {
        if start > 0.0 { signed } else { 0.0 }
    } else {
        positive_integral(p, s_end)
    }
}

/// `out[..2 a.len() - 1] = a * a` (polynomial square: each cross term once, doubled).
#[inline(always)]
fn square_into(a: &[f64], out: &mut [f64]) {
    let n = a.len();
    out[..2 * n - 1].fill(0.0);
    for (k, x) in a.iter().enumerate() {
        if *x == 0.0 {
            continue;
        }
        out[2 * k] += x * x;
        let twice = 2.0 * x;
        for (o, y) in out[2 * k + 1..k + n].iter_mut().zip(&a[k + 1..]) {
            *o += twice * y;
        }
    }
}

/// `out[..a.len() + b.len() - 1] = a * b` (polynomial product).
#[inline(always)]
fn product_into(a: &[f64], b: &[f64], out: &mut [f64]) {
    out[..a.len() + b.len() - 1].fill(0.0);
    for (k, x) in a.iter().enumerate() {
        if *x == 0.0 {
            continue;
        }
        for (o, y) in out[k..k + b.len()].iter_mut().zip(b) {
            *o += x * y;
        }
    }
}

/// Root of `p` bracketed by values of opposite signs at `a` and `b`, by the Illinois method to
/// a bracket of `1e-10` of the interval: misplacing the split point by `d` misattributes only
/// about `|p'| d^2 / 2` of area, far below rounding here.
#[inline(always)]
fn polynomial_root(p: &[f64], (mut a, mut pa): (f64, f64), (mut b, mut pb): (f64, f64)) -> f64 {
    let tolerance = 1e-10 * (b - a);
    let mut side = 0;
    for _ in 0..100 {
        if b - a <= tolerance {
            break;
        }
        let mut t = b - pb * (b - a) / (pb - pa);
        if !(t > a && t < b) {
            t = 0.5 * (a + b);
        }
        let pt = poly_eval(p, t);
        if pt == 0.0 {
            return t;
        }
        if (pt > 0.0) == (pa > 0.0) {
            a = t;
            pa = pt;
            if side == -1 {
                pb *= 0.5;
            }
            side = -1;
        } else {
            b = t;
            pb = pt;
            if side == 1 {
                pa *= 0.5;
            }
            side = 1;
        }
    }
    0.5 * (a + b)
}

/// `integral_0^{s_end} max(p(s), 0) ds`, splitting at sign changes found on a 16-point scan
/// (each root by [`polynomial_root`]).
#[inline(always)]
fn positive_integral(p: &[f64], s_end: f64) -> f64 {
    const SCAN: usize = 16;
    let points: [f64; SCAN + 1] = std::array::from_fn(|k| {
        if k == 0 {
            0.0
        } else {
            s_end * k as f64 / SCAN as f64
        }
    });
    // `p` and its antiderivative at every scan point, evaluated side by side (bit for bit each
    // point's own Horner chain); an integral between two points is the difference of theirs.
    let values = poly_eval_many(p, &points);
    let anti = Antiderivative::of(p);
    let primitives = anti.at_many(&points);
    let mut total = 0.0;
    for k in 1..=SCAN {
        let (a, pa, fa) = (points[k - 1], values[k - 1], primitives[k - 1]);
        let (b, pb, fb) = (points[k], values[k], primitives[k]);
        if pa * pb < 0.0 {
            let root = polynomial_root(p, (a, pa), (b, pb));
            let at_root = anti.at(root);
            let first = at_root - fa;
            let second = fb - at_root;
            total += first.max(0.0) + second.max(0.0);
        } else {
            let part = fb - fa;
            if pa > 0.0 || pb > 0.0 {
                total += part.max(0.0);
            }
        }
    }
    total
}

#[cfg(test)]
mod root_tests {
    use super::*;

    /// The event list as it was built before the active set: the trips, then per body its two
    /// break-aways (stuck) or its reversal (sliding with friction), then per current loop its
    /// saturation exit (saturated) or its two entries.
    fn listed_events(plant: &BenchPlant, held: &Held) -> Vec<Event> {
        let mut list: Vec<Event> = Interlock::CHECKED.into_iter().map(Event::Trip).collect();
        for j in 0..2 {
            if plant.state.stuck[j] {
                list.push(Event::BreakAway(j, 1.0));
                list.push(Event::BreakAway(j, -1.0));
            } else if BenchPlant::has_friction(held, j) || held.friction[j] != 0.0 {
                list.push(Event::Reversal(j));
            }
        }
        for n in 0..2 {
            if held.current_loop[n] {
                if plant.state.saturation[n] != 0.0 {
                    list.push(Event::SaturationExit(n));
                } else {
                    list.push(Event::SaturationEnter(n, 1.0));
                    list.push(Event::SaturationEnter(n, -1.0));
                }
            }
        }
        list
    }

    /// The active set lists the same events in the same order (the order decides which of two
    /// events at the same instant is applied first) in every combination of stuck bodies,
    /// friction, current loops and saturation.
    #[test]
    fn the_active_set_lists_the_events_in_list_order() {
        let mut plant = BenchPlant::new(BenchParameters::default()).unwrap();
        let base = plant.hold();
        let mut checked = 0;
        for case in 0..(1u32 << 12) {
            let bit = |k: u32| case >> k & 1 == 1;
            let mut held = base;
            for j in 0..2 {
                let k = 6 * j as u32;
                plant.state.stuck[j] = bit(k);
                held.capacity[j] = if bit(k + 1) { [0.5, 0.7] } else { [0.0, 0.7] };
                held.friction[j] = if bit(k + 2) { -0.2 } else { 0.0 };
                held.current_loop[j] = bit(k + 3);
                plant.state.saturation[j] = match (bit(k + 4), bit(k + 5)) {
                    (false, _) => 0.0,
                    (true, up) => {
                        if up {
                            1.0
                        } else {
                            -1.0
                        }
                    }
                };
            }
            let listed = listed_events(&plant, &held);
            assert_eq!(
                BenchPlant::event_list(plant.active_events(&held)).collect::<Vec<_>>(),
                listed,
                "case {case:#b}"
            );
            checked += listed.len();
        }
        assert!(checked > 7 << 12, "{checked}");
    }

    #[test]
    fn polynomial_square_matches_the_product() {
        let a = [0.3, -1.5, 0.0, 2.25, 1e-9];
        let (mut square, mut product) = ([0.0; 9], [0.0; 9]);
        square_into(&a, &mut square);
        product_into(&a, &a, &mut product);
        for (s, p) in square.iter().zip(&product) {
            assert!((s - p).abs() <= 1e-15 * p.abs().max(1.0), "{s} vs {p}");
        }
        assert_eq!(square[0], 0.09);
        assert_eq!(square[8], 1e-18);
    }

    #[test]
    fn positive_integral_splits_at_the_roots() {
        // p(s) = (s - 0.3)(s - 0.7) = s^2 - s + 0.21 (positive outside the roots);
        // antiderivative P(s) = s^3/3 - s^2/2 + 0.21 s.
        let anti = |s: f64| s * s * s / 3.0 - s * s / 2.0 + 0.21 * s;
        let p = [0.21, -1.0, 1.0];
        let exact = (anti(0.3) - anti(0.0)) + (anti(1.0) - anti(0.7));
        assert!((positive_integral(&p, 1.0) - exact).abs() < 1e-15);
        // Negated: positive only between the roots.
        let q = [-0.21, 1.0, -1.0];
        let exact = -(anti(0.7) - anti(0.3));
        assert!((positive_integral(&q, 1.0) - exact).abs() < 1e-15);
        // A root very close to a scan point and a tangent-like steep polynomial.
        let r = [-0.0625, 0.0, 0.0, 0.0, 1.0]; // s^4 - 0.5^4, root at 0.5
        let exact = (0.2 - 0.0625) - (0.5f64.powi(5) / 5.0 - 0.0625 * 0.5);
        assert!((positive_integral(&r, 1.0) - exact).abs() < 1e-15);
        assert!((polynomial_root(&r, (0.4, -0.0369), (0.6, 0.0671)) - 0.5).abs() < 1e-10);
    }
}
