//! The plant's events: the event functions (stick-slip, current-loop saturation, interlocks),
//! the set active in each mode, and the event sub-step that locates each on the exact flow and
//! applies it.

use super::{BenchPlant, EVENT_BUDGET, Held, sign};
use crate::models::bench::Interlock;
use crate::models::bench::mechanics::{
    AugVector, CURRENT1, CURRENT2, NZ, OMEGA1, THETA1, THETA2, TaylorSegment,
};

/// Pieces of a segment whose end states [`BenchPlant::earliest_event`] keeps on the stack.
const FEW_PIECES: usize = 8;

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
pub(super) struct ActiveEvents(u16);

impl ActiveEvents {
    /// The active switching events, in list order.
    #[inline(always)]
    pub(super) fn iter(self) -> impl Iterator<Item = Event> {
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

impl BenchPlant {
    #[inline(always)]
    pub(super) fn event_value(&self, held: &Held, event: Event, z: &AugVector) -> f64 {
        self.event_value_with(held, event, z, &self.demands(held, z))
    }

    /// Voltage demands of both current loops at `z` (see [`Self::voltage_demand`]).
    #[inline]
    pub(super) fn demands(&self, held: &Held, z: &AugVector) -> [f64; 2] {
        [
            self.voltage_demand(held, 0, z),
            self.voltage_demand(held, 1, z),
        ]
    }

    /// [`Self::any_positive_with`] with the demands at `z` computed here (the tests' form).
    #[cfg(test)]
    pub(super) fn any_positive(&self, held: &Held, active: ActiveEvents, z: &AugVector) -> bool {
        self.any_positive_with(held, active, z, &self.demands(held, z))
    }

    /// Whether any trip or any of the `active` switching events is positive at `z`, given the
    /// voltage demands there (`demand`, [`Self::demands`]: the caller reuses them). The trips
    /// are checked with constant arguments, so their dispatch folds away.
    ///
    /// Straight-line code, no iterator: every trip is evaluated (a branch-free `|`), then every
    /// switching event ([`Self::positive_switching`]), masked by the active set. The answer is
    /// that of the plain form over [`Self::event_list`] (`any_positive_listed`, tested).
    #[inline(always)]
    pub(super) fn any_positive_with(
        &self,
        held: &Held,
        active: ActiveEvents,
        z: &AugVector,
        demand: &[f64; 2],
    ) -> bool {
        let trip = |i: Interlock| self.event_value_with(held, Event::Trip(i), z, demand) > 0.0;
        if trip(Interlock::SpringDeflection)
            | trip(Interlock::TestMotorTorque)
            | trip(Interlock::LoadMotorTorque)
            | trip(Interlock::TestCurrent)
            | trip(Interlock::LoadCurrent)
            | trip(Interlock::RegenPower)
        {
            return true;
        }
        self.positive_switching(held, z, demand) & active.0 != 0
    }

    /// The bit set of the switching events positive at `z`, every one of the twelve evaluated
    /// (each a few instructions with its event constant, no branch): cheaper than walking the
    /// active set's bits with a dispatch per event, and an inactive event's value is only
    /// masked off by the caller (the functions read the state and `held`, and change nothing).
    #[inline(always)]
    fn positive_switching(&self, held: &Held, z: &AugVector, demand: &[f64; 2]) -> u16 {
        macro_rules! bits {
            ($($k:literal),*) => {
                0 $(| (u16::from(
                    self.event_value_with(held, SWITCHING_EVENTS[$k], z, demand) > 0.0
                ) << $k))*
            };
        }
        bits!(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11)
    }

    /// [`Self::any_positive`] in its plain form: any event of [`Self::event_list`] positive.
    #[cfg(test)]
    pub(super) fn any_positive_listed(
        &self,
        held: &Held,
        active: ActiveEvents,
        z: &AugVector,
    ) -> bool {
        let demand = self.demands(held, z);
        Self::event_list(active).any(|e| self.event_value_with(held, e, z, &demand) > 0.0)
    }

    /// The event function `event` at `z`, given the voltage demands there.
    #[inline(always)]
    pub(super) fn event_value_with(
        &self,
        held: &Held,
        event: Event,
        z: &AugVector,
        demand: &[f64; 2],
    ) -> f64 {
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
    pub(super) fn active_events(&self, held: &Held) -> ActiveEvents {
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
    pub(super) fn event_list(active: ActiveEvents) -> impl Iterator<Item = Event> {
        Interlock::CHECKED
            .into_iter()
            .map(Event::Trip)
            .chain(active.iter())
    }

    /// A sub-step with events: Taylor segments from event to event, each event located on the
    /// exact flow and applied, until the sub-step's end (or a trip). Kept out of line, in the
    /// build the step runs (see [`Self::step`]), so the common path stays small.
    #[inline(always)]
    pub(super) fn event_substep(
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
    pub(super) fn event_substep_wide(
        &mut self,
        first_held: Held,
        h: f64,
        start_time: f64,
    ) -> Result<(), (Interlock, f64)> {
        self.event_substep_inline(first_held, h, start_time)
    }

    /// [`Self::event_substep`] in the baseline build.
    #[inline(never)]
    pub(super) fn event_substep_baseline(
        &mut self,
        first_held: Held,
        h: f64,
        start_time: f64,
    ) -> Result<(), (Interlock, f64)> {
        self.event_substep_inline(first_held, h, start_time)
    }

    #[inline(always)]
    pub(super) fn event_substep_inline(
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
    pub(super) fn event_segments(
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
                None => self.resolve()?.0,
            };
            let speed_dependent = (0..2).any(|j| !held.mode.stuck[j] && self.speed_dependent(j));
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
            let z1 = self.accumulate_segment(&held, segment, stop);
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
    pub(super) fn apply_event(&mut self, held: &Held, event: Event) {
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
    pub(super) fn earliest_event(
        &self,
        held: &Held,
        events: impl Iterator<Item = Event>,
        segment: &TaylorSegment,
    ) -> Option<(f64, Event)> {
        let mut best: Option<(f64, Event)> = None;
        let z0 = segment.states_at(0.0);
        // The states at the piece ends, on the stack for a segment of a few pieces (the
        // usual event sub-step; a heap list for a longer one).
        let mut few = [(0.0, [0.0; NZ]); FEW_PIECES];
        let many: Vec<(f64, AugVector)>;
        let ends: &[(f64, AugVector)] = if segment.pieces().len() <= FEW_PIECES {
            for (end, b) in few.iter_mut().zip(segment.piece_ends()) {
                *end = (b, segment.states_at(b));
            }
            &few[..segment.pieces().len()]
        } else {
            many = segment
                .piece_ends()
                .map(|b| (b, segment.states_at(b)))
                .collect();
            &many
        };
        for event in events {
            let mut a = 0.0;
            let mut ga = self.event_value(held, event, &z0).min(0.0);
            for (b, zb) in ends {
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
    pub(super) fn locate_root(
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
            let g = self.event_value(held, event, &segment.states_at(t));
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
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::models::bench::BenchParameters;

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

    /// The straight-line check of the events at a sub-step's end answers as the plain one over
    /// the event list, for every active set, in states where no event, one trip or one
    /// switching event is positive (both saturation signs, stuck and sliding bodies).
    #[test]
    fn any_positive_is_the_plain_check_over_the_event_list() {
        let mut plant = BenchPlant::new(BenchParameters::default()).unwrap();
        let base = plant.hold();
        let states: Vec<AugVector> = vec![
            [0.0; 10],
            [0.01, 0.0, 0.5, -0.2, 1.0, -0.5, 1.0, -0.5, -0.3, 0.2],
            [0.2, 0.0, 0.5, -0.2, 1.0, -0.5, 1.0, -0.5, -0.3, 0.2],
            [0.0, 0.0, -3.0, 2.0, 14.0, 5.0, 14.0, 5.0, 0.3, -0.2],
            [0.0, 0.0, 30.0, -20.0, 1.0, -0.5, 1.0, -0.5, 0.3, -0.2],
            [0.0, 0.0, 0.0, 0.0, 16.0, 0.0, 16.0, 0.0, 0.0, 0.0],
            [0.0, 0.0, 0.0, 0.0, 0.0, -7.0, 0.0, -7.0, 0.0, 0.0],
            // The load motor driven back at speed: regenerating past its limit, nothing else.
            [0.0, 0.0, 0.0, 20.0, 0.0, -0.5, 0.0, -0.5, 0.0, 0.0],
            [0.05, -0.04, 1e-3, -1e-3, 3.0, 2.0, 3.0, 2.0, 0.0, 0.0],
        ];
        let (mut positive, mut negative) = (0, 0);
        for case in 0..16u32 {
            let mut held = base;
            for n in 0..2 {
                plant.state.direction[n] = if case >> n & 1 == 1 { 1.0 } else { -1.0 };
                plant.state.saturation[n] = match case >> (2 + n) & 1 {
                    0 => 0.0,
                    _ => plant.state.direction[n],
                };
                held.mode.voltage_row[n] = plant.state.saturation[n] != 0.0;
                held.drive[n] = 2.0 * plant.state.direction[n];
                held.reference[n] = -plant.state.direction[n];
            }
            for z in &states {
                for bits in 0..(1u16 << 12) {
                    let active = ActiveEvents(bits);
                    let fast = plant.any_positive(&held, active, z);
                    assert_eq!(
                        fast,
                        plant.any_positive_listed(&held, active, z),
                        "case {case} bits {bits:#b} z {z:?}"
                    );
                    if fast {
                        positive += 1;
                    } else {
                        negative += 1;
                    }
                }
            }
        }
        assert!(
            positive > 1000 && negative > 1000,
            "{positive} / {negative}"
        );
    }

    /// The event functions read only the six state components (angles, speeds, currents),
    /// never the held inputs' entries: the event search evaluates only those
    /// ([`TaylorSegment::states_at`]).
    #[test]
    fn event_functions_read_only_the_state_components() {
        let mut plant = BenchPlant::new(BenchParameters::default()).unwrap();
        let base = plant.hold();
        let z = [0.05, -0.04, 1e-3, -1e-3, 3.0, 2.0, 3.0, 2.0, 0.0, 0.0];
        let mut scrambled = z;
        scrambled[6..].copy_from_slice(&[f64::NAN, -7.5, f64::INFINITY, 1e300]);
        for saturation in [0.0, 1.0, -1.0] {
            plant.state.saturation = [saturation; 2];
            for voltage_row in [false, true] {
                let mut held = base;
                held.mode.voltage_row = [voltage_row; 2];
                let events = Interlock::CHECKED
                    .into_iter()
                    .map(Event::Trip)
                    .chain(SWITCHING_EVENTS);
                for event in events {
                    assert_eq!(
                        plant.event_value(&held, event, &z).to_bits(),
                        plant.event_value(&held, event, &scrambled).to_bits(),
                        "{event:?}"
                    );
                }
            }
        }
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
}
