//! The master's run-time tables: where every value it moves lives (the bus), what each
//! component reads and writes (its ports), and one component at run time.

use std::collections::HashMap;

use super::{Signal, VarRef, VarType};
use crate::instance::{Exchange, FmuError, Instance, Status};
/// The index of a type's buffer: 0 `Real`, 1 `Integer` (and `Enumeration`), 2 `Boolean`.
pub(super) fn ty_index(ty: VarType) -> usize {
    match ty {
        VarType::Real => 0,
        VarType::Integer => 1,
        _ => 2,
    }
}

/// The values the master reads after each step, one flat buffer per type (the "bus"): the
/// values a component's `fmi2Get*` call of one type returns occupy one contiguous range of that
/// type's buffer ([`Ports::out`]); the components' ranges follow each other in declaration
/// order. Booleans are kept as the FMU's `fmi2Boolean` (a C int).
#[derive(Debug, Clone, Default, PartialEq)]
pub(super) struct Bus {
    pub(super) real: Vec<f64>,
    pub(super) int: Vec<i32>,
    pub(super) boolean: Vec<i32>,
}

/// One component's part of the [`Bus`], per type.
pub(super) struct Outs<'a> {
    pub(super) real: &'a mut [f64],
    pub(super) int: &'a mut [i32],
    pub(super) boolean: &'a mut [i32],
}

impl Bus {
    /// A bus of `len` values per type (`Real`, `Integer`, `Boolean`), all zero.
    pub(super) fn new(len: [usize; 3]) -> Bus {
        Bus {
            real: vec![0.0; len[0]],
            int: vec![0; len[1]],
            boolean: vec![0; len[2]],
        }
    }

    /// Every component's part at once (for stepping on threads): `ranges` are the components'
    /// [`Ports::out`] in declaration order, which tile the bus.
    pub(super) fn split(
        &mut self,
        ranges: impl Iterator<Item = [(usize, usize); 3]>,
    ) -> Vec<Outs<'_>> {
        let (mut real, mut int, mut boolean) = (
            self.real.as_mut_slice(),
            self.int.as_mut_slice(),
            self.boolean.as_mut_slice(),
        );
        ranges
            .map(|out| {
                let (r, rest) = std::mem::take(&mut real).split_at_mut(out[0].1 - out[0].0);
                real = rest;
                let (i, rest) = std::mem::take(&mut int).split_at_mut(out[1].1 - out[1].0);
                int = rest;
                let (b, rest) = std::mem::take(&mut boolean).split_at_mut(out[2].1 - out[2].0);
                boolean = rest;
                Outs {
                    real: r,
                    int: i,
                    boolean: b,
                }
            })
            .collect()
    }
}

/// A run of consecutive recorded columns that are consecutive values of one type on the
/// [`Bus`] (start, end): a recorded row is built with one copy per run.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum RowRun {
    /// `Real` values, copied as they are.
    Real(usize, usize),
    /// `Integer` values, converted to `f64`.
    Integer(usize, usize),
    /// `Boolean` values, recorded as 0.0 or 1.0.
    Boolean(usize, usize),
}

/// Groups recorded columns, given as (type index, bus index), into [`RowRun`]s.
pub(super) fn row_runs(columns: &[(usize, usize)]) -> Vec<RowRun> {
    let mut runs: Vec<(usize, usize, usize)> = Vec::new();
    for &(t, k) in columns {
        match runs.last_mut() {
            Some((rt, _, end)) if *rt == t && *end == k => *end += 1,
            _ => runs.push((t, k, k + 1)),
        }
    }
    runs.into_iter()
        .map(|(t, a, b)| match t {
            0 => RowRun::Real(a, b),
            1 => RowRun::Integer(a, b),
            _ => RowRun::Boolean(a, b),
        })
        .collect()
}

/// One copy of consecutive `Real` bus values into the recorded row: `len` values from bus
/// index `bus` to row index `row`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) struct RowCopy {
    pub(super) bus: usize,
    pub(super) row: usize,
    pub(super) len: usize,
}

/// How a recorded row is built from the [`Bus`] (made once per run from the [`RowRun`]s):
/// every value to its fixed place in a row buffer of `len` values, the `Real`s by runs (one
/// copy each), the few `Integer`s and `Boolean`s one by one (runs of one or two values, where
/// a loop per run costs more than the values), so [`fill_row`] is three tight loops without a
/// branch per run or a push per value.
#[derive(Debug, Clone, Default, PartialEq)]
pub(super) struct RowCopies {
    /// The number of columns.
    pub(super) len: usize,
    /// When every column is a `Real` and the columns are consecutive on the bus: their range
    /// (the bus slice is the row, nothing to copy).
    pub(super) whole: Option<(usize, usize)>,
    /// `Real` values, copied as they are.
    pub(super) real: Vec<RowCopy>,
    /// `Integer` values, converted to `f64`: (bus index, row index).
    pub(super) int: Vec<(usize, usize)>,
    /// `Boolean` values, recorded as 0.0 or 1.0: (bus index, row index).
    pub(super) boolean: Vec<(usize, usize)>,
}

impl RowCopies {
    /// The copies of `runs`, in row order.
    pub(super) fn new(runs: &[RowRun]) -> RowCopies {
        let mut c = RowCopies::default();
        for run in runs {
            match *run {
                RowRun::Real(a, b) => c.real.push(RowCopy {
                    bus: a,
                    row: c.len,
                    len: b - a,
                }),
                RowRun::Integer(a, b) => c.int.extend((a..b).zip(c.len..)),
                RowRun::Boolean(a, b) => c.boolean.extend((a..b).zip(c.len..)),
            }
            let (RowRun::Real(a, b) | RowRun::Integer(a, b) | RowRun::Boolean(a, b)) = *run;
            c.len += b - a;
        }
        if let [RowRun::Real(a, b)] = runs[..] {
            c.whole = Some((a, b));
        }
        c
    }
}

/// What one component reads and writes, as indices (built once per run by [`Plan::new`]).
#[derive(Debug, Clone, Default, PartialEq)]
pub(super) struct Ports {
    /// Value references read after each step, per type (recorded ones first, in recording
    /// order, then the connected ones; each once).
    pub(super) out_vrs: [Vec<u32>; 3],
    /// Where their values go on the bus, per type: (start, end).
    pub(super) out: [(usize, usize); 3],
    /// Value references of the inputs set before each step, per type: the connected ones in
    /// connection order, then the signal-fed ones.
    pub(super) in_vrs: [Vec<u32>; 3],
    /// The bus index of each connected input's source, per type (the first `in_from[t].len()`
    /// entries of `in_vrs[t]`).
    pub(super) in_from: [Vec<usize>; 3],
    /// The signal-fed inputs: (type index, position in `in_vrs[type]`, signal index).
    pub(super) in_signals: Vec<(usize, usize, usize)>,
    /// Whether there are `Integer` or `Boolean` inputs to set.
    pub(super) in_other: bool,
    /// Whether there are `Integer` or `Boolean` inputs or signal-fed inputs to gather.
    pub(super) in_rare: bool,
}

/// The layout of a run: every component's [`Ports`], the bus size and the recorded row.
#[derive(Debug, Clone, PartialEq)]
pub(super) struct Plan {
    /// Per component, in declaration order.
    pub(super) ports: Vec<Ports>,
    /// Bus length per type.
    pub(super) bus_len: [usize; 3],
    /// The recorded columns, as runs of bus values.
    pub(super) row: Vec<RowRun>,
    /// The same runs as copies to their places in the row.
    pub(super) copies: RowCopies,
}

impl Plan {
    /// The layout for `n` components recording `recorded`, with `connections` (source,
    /// destination) and the inputs `fed` by signals (in signal order).
    pub(super) fn new(
        n: usize,
        recorded: &[VarRef],
        connections: &[(VarRef, VarRef)],
        fed: &[&VarRef],
    ) -> Plan {
        let mut ports: Vec<Ports> = vec![Ports::default(); n];
        // Position of each value read per component, type and value reference, in order of
        // first use.
        let mut slots: Vec<HashMap<(usize, u32), usize>> = vec![HashMap::new(); n];
        let mut slot_of = |ports: &mut [Ports], comp: usize, ty: VarType, vr: u32| -> usize {
            let t = ty_index(ty);
            *slots[comp].entry((t, vr)).or_insert_with(|| {
                ports[comp].out_vrs[t].push(vr);
                ports[comp].out_vrs[t].len() - 1
            })
        };
        let rec: Vec<(usize, usize, usize)> = recorded
            .iter()
            .map(|r| {
                (
                    r.comp,
                    ty_index(r.ty),
                    slot_of(&mut ports, r.comp, r.ty, r.vr),
                )
            })
            .collect();
        let sources: Vec<usize> = connections
            .iter()
            .map(|(s, _)| slot_of(&mut ports, s.comp, s.ty, s.vr))
            .collect();
        let mut bus_len = [0; 3];
        for p in &mut ports {
            for ((out, vrs), len) in p.out.iter_mut().zip(&p.out_vrs).zip(&mut bus_len) {
                *out = (*len, *len + vrs.len());
                *len = out.1;
            }
        }
        for ((s, d), slot) in connections.iter().zip(sources) {
            let t = ty_index(s.ty);
            let from = ports[s.comp].out[t].0 + slot;
            let p = &mut ports[d.comp];
            p.in_vrs[t].push(d.vr);
            p.in_from[t].push(from);
        }
        for (k, d) in fed.iter().enumerate() {
            let t = ty_index(d.ty);
            let p = &mut ports[d.comp];
            p.in_signals.push((t, p.in_vrs[t].len(), k));
            p.in_vrs[t].push(d.vr);
        }
        for p in &mut ports {
            p.in_other = !(p.in_vrs[1].is_empty() && p.in_vrs[2].is_empty());
            p.in_rare = p.in_other || !p.in_signals.is_empty();
        }
        let columns: Vec<(usize, usize)> = rec
            .iter()
            .map(|&(c, t, slot)| (t, ports[c].out[t].0 + slot))
            .collect();
        let row = row_runs(&columns);
        Plan {
            ports,
            bus_len,
            copies: RowCopies::new(&row),
            row,
        }
    }
}

/// The input values of one component, set before each of its steps (same layout as
/// [`Ports::in_vrs`]).
#[derive(Debug, Clone, Default, PartialEq)]
pub(super) struct InValues {
    pub(super) real: Vec<f64>,
    pub(super) int: Vec<i32>,
    pub(super) boolean: Vec<i32>,
    /// Per signal-fed input (`Ports::in_signals`), where its signal's search starts
    /// ([`Signal::at_from`]); `None` for a signal whose times are not sorted (always
    /// [`Signal::at`]).
    signal_cursors: Vec<Option<usize>>,
}

impl InValues {
    /// Zeroed buffers for the inputs of `ports`, whose signal-fed inputs take `signals`.
    pub(super) fn for_ports(ports: &Ports, signals: &[Signal]) -> InValues {
        InValues {
            real: vec![0.0; ports.in_vrs[0].len()],
            int: vec![0; ports.in_vrs[1].len()],
            boolean: vec![0; ports.in_vrs[2].len()],
            signal_cursors: ports
                .in_signals
                .iter()
                .map(|&(_, _, s)| signals[s].has_sorted_times().then_some(0))
                .collect(),
        }
    }

    /// Takes the connected inputs from the bus and the signal-fed ones from their signals at
    /// time `t`.
    #[inline(always)]
    pub(super) fn gather(&mut self, ports: &Ports, bus: &Bus, signals: &[Signal], t: f64) {
        for (v, &k) in self.real.iter_mut().zip(&ports.in_from[0]) {
            *v = bus.real[k];
        }
        if ports.in_rare {
            self.gather_rare(ports, bus, signals, t);
        }
    }

    /// The `Integer` and `Boolean` part of [`gather`](Self::gather) and the signal-fed inputs.
    #[inline(never)]
    pub(super) fn gather_rare(&mut self, ports: &Ports, bus: &Bus, signals: &[Signal], t: f64) {
        for (v, &k) in self.int.iter_mut().zip(&ports.in_from[1]) {
            *v = bus.int[k];
        }
        for (v, &k) in self.boolean.iter_mut().zip(&ports.in_from[2]) {
            *v = (bus.boolean[k] != 0) as i32;
        }
        if !ports.in_signals.is_empty() {
            self.sample_signals(ports, signals, t);
        }
    }

    /// The signal-fed inputs at time `t` (rare: single-FMU runs with an input file).
    #[cold]
    #[inline(never)]
    pub(super) fn sample_signals(&mut self, ports: &Ports, signals: &[Signal], t: f64) {
        for (&(ty, k, s), cursor) in ports.in_signals.iter().zip(&mut self.signal_cursors) {
            let signal = &signals[s];
            let x = match cursor {
                Some(cursor) => signal.at_from(t, cursor),
                None => signal.at(t),
            };
            match ty {
                0 => self.real[k] = x,
                1 => self.int[k] = x.round() as i32,
                _ => self.boolean[k] = (x != 0.0) as i32,
            }
        }
    }
}

/// One component at run time: its instance, its [`Ports`] and its input values.
pub(super) struct Rt {
    pub(super) inst: Instance,
    pub(super) multiple: u64,
    pub(super) h: f64,
    pub(super) ports: Ports,
    pub(super) inputs: InValues,
    pub(super) steps: u64,
}

pub(super) enum StepEnd {
    Done,
    Discard,
}

impl Rt {
    pub(super) fn new(
        inst: Instance,
        multiple: u64,
        h: f64,
        ports: Ports,
        signals: &[Signal],
    ) -> Rt {
        Rt {
            inst,
            multiple,
            h,
            inputs: InValues::for_ports(&ports, signals),
            ports,
            steps: 0,
        }
    }

    /// Takes the input values (see [`InValues::gather`]).
    #[inline(always)]
    pub(super) fn gather(&mut self, bus: &Bus, signals: &[Signal], t: f64) {
        self.inputs.gather(&self.ports, bus, signals, t);
    }

    /// Reads the outputs into the component's part of the bus.
    #[inline(always)]
    pub(super) fn read(&mut self, bus: &mut Bus) -> Result<(), FmuError> {
        let [(a, b), (c, d), (e, f)] = self.ports.out;
        self.read_into(Outs {
            real: &mut bus.real[a..b],
            int: &mut bus.int[c..d],
            boolean: &mut bus.boolean[e..f],
        })
    }

    /// Reads the outputs into `out` (the component's part of the bus): one
    /// [`Instance::get_outputs`] for the three types.
    #[inline(always)]
    pub(super) fn read_into(&mut self, out: Outs<'_>) -> Result<(), FmuError> {
        let [real, int, boolean] = &self.ports.out_vrs;
        self.inst
            .get_outputs([real, int, boolean], out.real, out.int, out.boolean)
    }

    /// Sets the input values.
    #[inline(always)]
    pub(super) fn write(&mut self) -> Result<(), FmuError> {
        self.inst
            .set_real(&self.ports.in_vrs[0], &self.inputs.real)?;
        if self.ports.in_other {
            self.write_other()?;
        }
        Ok(())
    }

    /// The `Integer` and `Boolean` part of [`write`](Self::write).
    #[inline(never)]
    pub(super) fn write_other(&mut self) -> Result<(), FmuError> {
        self.inst
            .set_integer(&self.ports.in_vrs[1], &self.inputs.int)?;
        self.inst
            .set_boolean_raw(&self.ports.in_vrs[2], &self.inputs.boolean)?;
        Ok(())
    }

    /// Sets the inputs, steps from `t` and reads the outputs onto the bus.
    #[inline(always)]
    pub(super) fn step_read(&mut self, bus: &mut Bus, t: f64) -> Result<StepEnd, FmuError> {
        let [(a, b), (c, d), (e, f)] = self.ports.out;
        self.step_read_into(
            Outs {
                real: &mut bus.real[a..b],
                int: &mut bus.int[c..d],
                boolean: &mut bus.boolean[e..f],
            },
            t,
        )
    }

    /// [`step_read`](Self::step_read) into the component's part of the bus `out` (also on a
    /// thread): one [`Instance::step_exchange`] (the inputs set, the step counted and done,
    /// the outputs read unless the step was discarded).
    #[inline(always)]
    pub(super) fn step_read_into(&mut self, out: Outs<'_>, t: f64) -> Result<StepEnd, FmuError> {
        let (p, v) = (&self.ports, &self.inputs);
        let x = Exchange {
            in_vrs: &p.in_vrs,
            real_in: &v.real,
            int_in: &v.int,
            bool_in: &v.boolean,
            out_vrs: &p.out_vrs,
            real_out: out.real,
            int_out: out.int,
            bool_out: out.boolean,
        };
        match self.inst.step_exchange(x, t, self.h, &mut self.steps)? {
            Status::Discard => Ok(StepEnd::Discard),
            Status::Ok | Status::Warning => Ok(StepEnd::Done),
        }
    }
}

/// Whether a component stepping every `multiple` base steps steps at base step `n` (no
/// division for the common `multiple == 1`: a 64-bit division per component and step is a
/// measurable part of a small system's step).
#[inline(always)]
pub(super) fn steps_at(n: u64, multiple: u64) -> bool {
    multiple == 1 || n.is_multiple_of(multiple)
}

/// Fills `values` (a row buffer of [`RowCopies::len`] values) with the recorded values on `bus`.
#[inline]
pub(super) fn fill_row(values: &mut [f64], copies: &RowCopies, bus: &Bus) {
    for c in &copies.real {
        values[c.row..c.row + c.len].copy_from_slice(&bus.real[c.bus..c.bus + c.len]);
    }
    for &(k, r) in &copies.int {
        values[r] = f64::from(bus.int[k]);
    }
    for &(k, r) in &copies.boolean {
        values[r] = f64::from(u8::from(bus.boolean[k] != 0));
    }
}
