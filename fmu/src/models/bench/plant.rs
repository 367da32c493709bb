//! The switched, exactly discretised plant: its state, modes and regular sub-step. The events
//! (their functions, location and the event sub-step) live in [`events`], the energy accounting
//! in [`energy`].

mod energy;
mod events;

use std::sync::Arc;

pub(crate) use energy::EnergyAccount;
use energy::PieceScratch;
use events::Event;

use super::friction::{Side, SideLaw};
use super::mechanics::{
    AugMatrix, AugVector, CURRENT1, CURRENT2, DRIVE1, DRIVE2, Discretization, FRICTION1, FRICTION2,
    LinearMode, NZ, OMEGA1, SegmentIntegrals, THETA1, THETA2, TaylorSegment, rate_scale,
    system_matrix,
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
    /// Output-side load torque the loss-surface law reads, frozen at the segment's start (0
    /// when no law reads it): the friction laws are [`BenchPlant::law`], not copies here.
    pub load_torque: f64,
    /// Static capacity per body against + and - motion [N m].
    pub capacity: [[f64; 2]; 2],
    pub clutch: bool,
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
    /// Working arrays of the segments' energies (not state; see [`PieceScratch`]).
    piece_scratch: PieceScratch,
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

/// For a test comparing an AVX2 build with its baseline: whether this CPU has no AVX2, said on
/// standard error (`only` names what runs then), so that the test skips.
#[cfg(test)]
pub(crate) fn no_wide_vectors_here(only: &str) -> bool {
    let missing = !cpu_has_wide_vectors();
    if missing {
        eprintln!("skipped: this CPU has no AVX2, so only {only} runs");
    }
    missing
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
    /// Whether each side's friction law depends on the speed (a property of the law's kind,
    /// which the parameters alone decide: the loss surface's load torque never changes it).
    speed_dependent: [bool; 2],
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
        let speed_dependent =
            [Side::Actuation, Side::Load].map(|side| SideLaw::of(p, side, 0.0).speed_dependent());
        Self {
            speed_dependent,
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
            piece_scratch: PieceScratch::default(),
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
        self.step_inline::<false>(inputs, h)
    }

    /// [`Self::step`] compiled for AVX2: the same operations in the same order (no fused
    /// multiply-add, which would round differently), on wider registers; the regular path of
    /// the step is inlined into it. Bit-identical to the baseline build (tested).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn step_wide(&mut self, inputs: &BenchInputs, h: f64) -> StepOutcome {
        self.step_inline::<true>(inputs, h)
    }

    /// The step; `WIDE` in its AVX2 build (see [`Self::step_wide`]), where the regular
    /// sub-step's energy sums run on AVX2 registers written out.
    #[inline(always)]
    fn step_inline<const WIDE: bool>(&mut self, inputs: &BenchInputs, h: f64) -> StepOutcome {
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
        // One sub-step when the communication step fits (the common case, no division and no
        // conversion of the count).
        let (substeps, n) = if h <= self.params.max_internal_step {
            (1.0, 1)
        } else {
            let substeps = (h / self.params.max_internal_step * (1.0 - 1e-12))
                .ceil()
                .max(1.0);
            (substeps, substeps as u64)
        };
        let sub_h = if substeps == 1.0 { h } else { h / substeps };
        for k in 0..n {
            if let Err((interlock, time)) = self.substep::<WIDE>(sub_h) {
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
        Self::armature_voltage_or(held, n, || self.voltage_demand(held, n, z))
    }

    /// [`Self::armature_voltage`] with the current loop's voltage demand from `demand`, asked
    /// for only when the loop is in current mode (a caller may already hold it).
    #[inline(always)]
    pub(super) fn armature_voltage_or(held: &Held, n: usize, demand: impl FnOnce() -> f64) -> f64 {
        if held.mode.voltage_row[n] {
            held.drive[n]
        } else {
            demand()
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
        let (load_torque, mut capacity) = match &self.derived.static_laws {
            Some((_, capacity)) => (0.0, *capacity),
            None => {
                let load_torque = self.torque_per_ampere()[1] * self.state.z[CURRENT2];
                let laws = [
                    SideLaw::of(p, Side::Actuation, load_torque),
                    SideLaw::of(p, Side::Load, load_torque),
                ];
                let capacity = laws.map(|law| [law.capacity(p, 1.0), law.capacity(p, -1.0)]);
                (load_torque, capacity)
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
            load_torque,
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

    /// The friction law of body `j` in force over the segment of `held`: the parameters' own
    /// when it does not depend on the state, else the loss surface at `held`'s load torque
    /// (as [`Self::hold`] found it).
    #[inline(always)]
    pub(crate) fn law(&self, held: &Held, j: usize) -> SideLaw {
        match &self.derived.static_laws {
            Some((laws, _)) => laws[j],
            None => SideLaw::of(
                &self.params,
                if j == 0 { Side::Actuation } else { Side::Load },
                held.load_torque,
            ),
        }
    }

    /// Whether the friction law of body `j` depends on the speed (`self.law(held,
    /// j).speed_dependent()` for any `held`: the law's kind is the parameters').
    #[inline(always)]
    pub(crate) fn speed_dependent(&self, j: usize) -> bool {
        self.derived.speed_dependent[j]
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
    /// already beyond its threshold; with the held values, the current loops' voltage demands
    /// at the state ([`Self::demands`]: the segment's start powers read them).
    #[inline(always)]
    fn resolve(&mut self) -> Result<(Held, [f64; 2]), (Interlock, f64)> {
        let mut held = self.hold();
        self.classify_sticking(&held);
        held.mode.stuck = self.state.stuck;
        // The voltage demands at the state (they read the currents, the speeds and the held
        // references, which nothing below changes): both the loops' saturation and the trips
        // read them.
        let demand = self.demands(&held, &self.state.z);
        for n in 0..2 {
            if !held.current_loop[n] {
                self.state.saturation[n] = 0.0;
                continue;
            }
            let (_, _, _, supply, _) = self.motor(n);
            let demand = demand[n];
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
        if self.speed_dependent(0) || self.speed_dependent(1) {
            self.state.last_clamped = self.friction_clamped(&held);
            if self.state.last_clamped {
                self.state.clamp_count += 1;
            }
        }
        // The trips read the angles, the currents and the demands, not the held inputs'
        // entries of the input state: the state itself serves.
        for interlock in Interlock::CHECKED {
            if self.event_value_with(&held, Event::Trip(interlock), &self.state.z, &demand) > 0.0 {
                return Err((interlock, self.state.time));
            }
        }
        Ok((held, demand))
    }

    fn friction_clamped(&self, held: &Held) -> bool {
        (0..2).any(|j| {
            !self.state.stuck[j]
                && self
                    .law(held, j)
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
            let law = self.law(held, j);
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
    fn substep<const WIDE: bool>(&mut self, h: f64) -> Result<(), (Interlock, f64)> {
        let start_time = self.state.time;
        let (mut held, demand0) = self.resolve()?;
        let speed_dependent = (0..2).any(|j| !held.mode.stuck[j] && self.speed_dependent(j));
        let active = self.active_events(&held);
        let index = self.discretization(held.mode, h);
        let mut z0 = self.input_state(&held);
        let (mut z1, mut currents) = self.cache[index].advance_with_currents(&z0);
        if speed_dependent {
            self.set_friction(&mut held, Some(&z1));
            z0 = self.input_state(&held);
            (z1, currents) = self.cache[index].advance_with_currents(&z0);
        }
        // The demands at both ends (the currents, speeds and references they read are those
        // of `z0` and `z1`), read by the end's event check and both ends' powers.
        let demand1 = self.demands(&held, &z1);
        if self.any_positive_with(&held, active, &z1, &demand1) {
            return self.event_substep(held, h, start_time);
        }
        let p0 = self.powers_with(&held, &z0, &demand0);
        let p1 = self.powers_with(&held, &z1, &demand1);
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
            products: self.cache[index].quadratic_integrals::<WIDE>(&z0),
            current1: currents[0],
            current2: currents[1],
        };
        self.accumulate_regular(&held, &z0, &z1, &integrals, (&p0, &p1), rates, h);
        self.commit(z1);
        Ok(())
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

    /// Armature voltage of motor `n` as `a i + b w + c` for the held mode (`a = b = 0` on a
    /// voltage row: the held drive, a saturated loop's supply included).
    pub(crate) fn voltage_law_at(&self, held: &Held, n: usize) -> (f64, f64, f64) {
        self.voltage_law(held, n)
    }

    /// Resistance `R` and output-side back-emf constant `Ke G` of motor `n`.
    pub(crate) fn resistance_and_back_emf(&self, n: usize) -> (f64, f64) {
        let (r, _, ke, _, _) = self.motor(n);
        (r, ke)
    }
}
