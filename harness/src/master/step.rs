//! One run: initialization, the step loops (sequential, Jacobi, parallel groups), recording,
//! stop requests and the end of the run; the ticker thread that asks for flushes and keeps the
//! time limit.

use super::plan::{Bus, Outs, RowCopies, Rt, StepEnd, fill_row, steps_at};
use super::{Algorithm, MasterError, Outcome, RunConfig, Signal, System, Value, VarType};
use crate::control::RunControl;
use crate::instance::FmuError;
use crate::results::ResultSink;
use crate::time::Grid;
/// Whether every value is finite (its exponent bits not all ones): one OR over all values,
/// without early exit (a short-circuiting `all` costs a branch per value on the hot path),
/// with only 64-bit AND, ADD and OR per value, which baseline x86-64 (SSE2) vectorizes: the
/// exponent bits plus one exponent unit carry into the sign bit exactly when they are all
/// ones. (A 64-bit equality per value needs SSE4.1: the loop stayed scalar, ~3.6 instructions
/// per value.) Equal to `values.iter().all(|v| v.is_finite())` (tested).
#[inline(always)]
pub(super) fn all_finite(values: &[f64]) -> bool {
    const EXPONENT: u64 = 0x7ff0_0000_0000_0000;
    const ONE: u64 = 1 << 52;
    const SIGN: u64 = 1 << 63;
    values
        .iter()
        .fold(0u64, |any, v| any | ((v.to_bits() & EXPONENT) + ONE))
        & SIGN
        == 0
}

/// Flushes `sink` at the end of a run; a failed flush fails a run that had not failed.
pub(super) fn flushed<S: ResultSink + ?Sized>(sink: &mut S, outcome: Outcome) -> Outcome {
    match (sink.flush(), outcome) {
        (Err(e), Outcome::Completed { .. } | Outcome::Terminated { .. }) => {
            Outcome::Failed(MasterError::Sink(e))
        }
        (_, outcome) => outcome,
    }
}

/// The thread that asks for a flush every second and marks the time limit as passed; it ends
/// when dropped.
pub(super) struct Ticker {
    pub(super) stop: Option<std::sync::mpsc::Sender<()>>,
    pub(super) thread: Option<std::thread::JoinHandle<()>>,
}

impl Ticker {
    /// Starts the thread if there is anything to do (periodic flushes or a deadline).
    pub(super) fn start(
        control: &RunControl,
        flush: bool,
        deadline: Option<std::time::Instant>,
    ) -> Result<Ticker, MasterError> {
        use std::sync::mpsc::RecvTimeoutError;
        use std::time::{Duration, Instant};
        if !flush && deadline.is_none() {
            return Ok(Ticker {
                stop: None,
                thread: None,
            });
        }
        const PERIOD: Duration = Duration::from_secs(1);
        let (tx, rx) = std::sync::mpsc::channel::<()>();
        let control = control.clone();
        let thread = std::thread::Builder::new()
            .name("kneebench-ticker".into())
            .spawn(move || {
                loop {
                    let now = Instant::now();
                    let wait = match deadline {
                        Some(d) if d <= now => {
                            control.request_timeout();
                            return;
                        }
                        Some(d) if !flush => d - now,
                        Some(d) => PERIOD.min(d - now),
                        None => PERIOD,
                    };
                    match rx.recv_timeout(wait) {
                        Err(RecvTimeoutError::Timeout) => {
                            if flush {
                                control.request_flush();
                            }
                        }
                        _ => return,
                    }
                }
            });
        match thread {
            Ok(t) => Ok(Ticker {
                stop: Some(tx),
                thread: Some(t),
            }),
            Err(e) => Err(MasterError::Thread(e)),
        }
    }
}

impl Drop for Ticker {
    fn drop(&mut self) {
        drop(self.stop.take());
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

pub(super) struct Run<'a> {
    pub(super) sys: &'a System,
    pub(super) grid: Grid,
    pub(super) rts: Vec<Rt>,
    pub(super) bus: Bus,
    pub(super) signals: Vec<Signal>,
    pub(super) row: RowCopies,
    /// The row being recorded (values only, [`RowCopies::len`] of them).
    pub(super) row_buf: Vec<f64>,
    /// Rows handed to the sink.
    pub(super) rows: u64,
    /// The time of the last row handed to the sink.
    pub(super) last_row_time: Option<f64>,
    pub(super) control: RunControl,
    pub(super) allow_nonfinite: bool,
}

pub(super) enum Stop {
    Terminated { comp: usize, time: f64 },
    Failed(MasterError),
}

impl Run<'_> {
    #[cold]
    #[inline(never)]
    pub(super) fn fail(&self, comp: usize, time: f64, e: FmuError) -> Stop {
        Stop::Failed(MasterError::Fmu {
            component: self.sys.components[comp].name.clone(),
            time,
            source: e,
        })
    }

    #[inline]
    pub(super) fn record<S: ResultSink + ?Sized>(
        &mut self,
        sink: &mut S,
        t: f64,
    ) -> Result<(), Stop> {
        self.record_row(sink, t).map_err(Stop::Failed)
    }

    /// Hands the row at `t` to the sink.
    #[inline]
    pub(super) fn record_row<S: ResultSink + ?Sized>(
        &mut self,
        sink: &mut S,
        t: f64,
    ) -> Result<(), MasterError> {
        // Every recorded column a Real and consecutive on the bus: the bus slice is the row.
        if let Some((a, b)) = self.row.whole {
            sink.push_row(t, &self.bus.real[a..b])?;
        } else {
            fill_row(&mut self.row_buf, &self.row, &self.bus);
            sink.push_row(t, &self.row_buf)?;
        }
        self.rows += 1;
        self.last_row_time = Some(t);
        Ok(())
    }

    /// Acts on the pending requests of the control (a flush, a stop) at communication point
    /// `t`, after its row.
    #[cold]
    #[inline(never)]
    pub(super) fn attend<S: ResultSink + ?Sized>(
        &mut self,
        sink: &mut S,
        t: f64,
    ) -> Result<(), Stop> {
        if self.control.take_flush()
            && let Err(e) = sink.flush()
        {
            return Err(Stop::Failed(MasterError::Sink(e)));
        }
        match self.control.stop_reason() {
            Some(reason) => Err(Stop::Failed(MasterError::Stopped {
                reason,
                time: self.last_row_time.unwrap_or(t),
            })),
            None => Ok(()),
        }
    }

    /// Fails with [`MasterError::NonFinite`] when an output of component `i` just read
    /// (values for time `t`) is not finite, unless allowed.
    #[inline(always)]
    pub(super) fn check_finite(&self, i: usize, t: f64) -> Result<(), Stop> {
        let (a, b) = self.rts[i].ports.out[0];
        if self.allow_nonfinite || all_finite(&self.bus.real[a..b]) {
            Ok(())
        } else {
            Err(Stop::Failed(self.nonfinite(i, t)))
        }
    }

    #[cold]
    #[inline(never)]
    pub(super) fn nonfinite(&self, i: usize, t: f64) -> MasterError {
        let (a, b) = self.rts[i].ports.out[0];
        let k = self.bus.real[a..b]
            .iter()
            .position(|v| !v.is_finite())
            .unwrap_or(0);
        let vr = self.rts[i].ports.out_vrs[0][k];
        let md = self.sys.components[i].fmu.model_description();
        let variable = md
            .model_variables
            .iter()
            .find(|v| v.value_reference == vr && VarType::of(v) == VarType::Real)
            .map(|v| v.name.clone())
            .unwrap_or_else(|| format!("(value reference {vr})"));
        MasterError::NonFinite {
            component: self.sys.components[i].name.clone(),
            variable,
            value: self.bus.real[a + k],
            time: t,
        }
    }

    pub(super) fn execute<S: ResultSink + ?Sized>(
        &mut self,
        config: &RunConfig,
        order: &[usize],
        groups: &[Vec<usize>],
        sink: &mut S,
        record_every: u64,
    ) -> Outcome {
        let t0 = self.grid.start;
        if let Err(stop) = self.initialize(config, order) {
            return self.finish(stop, sink);
        }
        if let Err(stop) = self.record(sink, t0).and_then(|_| {
            if self.control.pending() != 0 {
                self.attend(sink, t0)
            } else {
                Ok(())
            }
        }) {
            return self.finish(stop, sink);
        }
        // The step loop is chosen once per run.
        let r = match (config.parallel, config.algorithm) {
            (true, _) => self.step_loop(config, sink, record_every, |run, n, t| {
                run.step_parallel(groups, n, t)
            }),
            (false, Algorithm::GaussSeidel) => {
                self.step_loop(config, sink, record_every, |run, n, t| {
                    run.step_gauss_seidel(order, n, t)
                })
            }
            (false, Algorithm::Jacobi) => {
                self.step_loop(config, sink, record_every, |run, n, t| {
                    run.step_jacobi(order, n, t)
                })
            }
        };
        if let Err(stop) = r {
            return self.finish(stop, sink);
        }
        for i in 0..self.rts.len() {
            let _ = self.rts[i].inst.terminate();
        }
        Outcome::Completed {
            stop_time: self.grid.stop(),
        }
    }

    /// Every macro step with `step`, recording every `record_every`-th row and reporting
    /// progress.
    #[inline(always)]
    pub(super) fn step_loop<S: ResultSink + ?Sized>(
        &mut self,
        config: &RunConfig,
        sink: &mut S,
        record_every: u64,
        mut step: impl FnMut(&mut Self, u64, f64) -> Result<(), Stop>,
    ) -> Result<(), Stop> {
        let total = self.grid.n_steps;
        let stride = (total / 200).max(1);
        // The next step counts (n + 1) to record at and to report progress at.
        let mut next_row = record_every;
        let mut next_progress = stride;
        let mut t = self.grid.time(0);
        for n in 0..total {
            step(self, n, t)?;
            let done = n + 1;
            t = self.grid.time(done);
            if done == next_row {
                next_row = next_row.saturating_add(record_every);
                self.record(sink, t)?;
            }
            if self.control.pending() != 0 {
                self.attend(sink, t)?;
            }
            if done == next_progress {
                next_progress = next_progress.saturating_add(stride);
                if let Some(p) = &config.progress {
                    p(done, total);
                }
            }
        }
        Ok(())
    }

    pub(super) fn finish<S: ResultSink + ?Sized>(&mut self, stop: Stop, sink: &mut S) -> Outcome {
        // The row at the terminating component's last successful time, read before any
        // instance is terminated.
        let last_row = match &stop {
            Stop::Terminated { comp, time } => self.last_row(*comp, *time, sink),
            Stop::Failed(_) => Ok(()),
        };
        // Terminate the healthy instances; Drop frees every instance.
        for rt in &mut self.rts {
            if rt.inst.phase() == crate::instance::Phase::StepComplete {
                let _ = rt.inst.terminate();
            }
        }
        match (stop, last_row) {
            (Stop::Terminated { comp, time }, Ok(())) => Outcome::Terminated {
                component: self.sys.components[comp].name.clone(),
                last_successful_time: time,
                last_row_time: self.last_row_time.unwrap_or(self.grid.start),
                messages: self.rts[comp]
                    .inst
                    .take_messages()
                    .into_iter()
                    .map(|m| m.message)
                    .collect(),
            },
            (Stop::Terminated { .. }, Err(e)) | (Stop::Failed(e), _) => Outcome::Failed(e),
        }
    }

    /// Records the row at `time`, the last successful time of component `comp` that ended
    /// the run, when it is after the last row: `comp`'s outputs read now, the others' as
    /// they are.
    pub(super) fn last_row<S: ResultSink + ?Sized>(
        &mut self,
        comp: usize,
        time: f64,
        sink: &mut S,
    ) -> Result<(), MasterError> {
        if self.last_row_time.is_some_and(|last| time <= last) || !time.is_finite() {
            return Ok(());
        }
        if let Err(source) = self.rts[comp].read(&mut self.bus) {
            return Err(MasterError::Fmu {
                component: self.sys.components[comp].name.clone(),
                time,
                source,
            });
        }
        let (a, b) = self.rts[comp].ports.out[0];
        if !self.allow_nonfinite && !all_finite(&self.bus.real[a..b]) {
            return Err(self.nonfinite(comp, time));
        }
        self.record_row(sink, time)
    }

    pub(super) fn initialize(&mut self, config: &RunConfig, order: &[usize]) -> Result<(), Stop> {
        let t0 = self.grid.start;
        let stop = self.grid.stop();
        for i in 0..self.rts.len() {
            let r = self.rts[i]
                .inst
                .setup_experiment(config.tolerance, t0, Some(stop))
                .and_then(|_| self.apply_values(i));
            r.map_err(|e| self.fail(i, t0, e))?;
        }
        for i in 0..self.rts.len() {
            let r = self.rts[i].inst.enter_initialization_mode();
            r.map_err(|e| self.fail(i, t0, e))?;
        }
        for i in 0..self.rts.len() {
            let r = self.rts[i].read(&mut self.bus);
            r.map_err(|e| self.fail(i, t0, e))?;
        }
        for &i in order {
            let rt = &mut self.rts[i];
            rt.gather(&self.bus, &self.signals, t0);
            let r = rt.write().and_then(|_| rt.read(&mut self.bus));
            r.map_err(|e| self.fail(i, t0, e))?;
        }
        for i in 0..self.rts.len() {
            let r = self.rts[i].inst.exit_initialization_mode();
            r.map_err(|e| self.fail(i, t0, e))?;
        }
        for &i in order {
            let r = self.rts[i].read(&mut self.bus);
            r.map_err(|e| self.fail(i, t0, e))?;
            self.check_finite(i, t0)?;
        }
        Ok(())
    }

    pub(super) fn apply_values(&mut self, i: usize) -> Result<(), FmuError> {
        let inst = &mut self.rts[i].inst;
        for (r, v) in &self.sys.components[i].values {
            match v {
                Value::Real(x) => inst.set_real(&[r.vr], &[*x])?,
                Value::Integer(x) => inst.set_integer(&[r.vr], &[*x])?,
                Value::Boolean(x) => inst.set_boolean_raw(&[r.vr], &[*x as i32])?,
                Value::String(x) => inst.set_string(&[r.vr], &[x.as_str()])?,
            };
        }
        Ok(())
    }

    #[cold]
    #[inline(never)]
    pub(super) fn discarded(&mut self, i: usize, t: f64) -> Stop {
        let inst = &mut self.rts[i].inst;
        if inst.terminated() {
            let time = inst.last_successful_time().unwrap_or(t);
            Stop::Terminated { comp: i, time }
        } else {
            let messages = inst.take_messages();
            Stop::Failed(MasterError::StepDiscarded {
                component: self.sys.components[i].name.clone(),
                time: t,
                messages,
            })
        }
    }

    /// Steps component `i` from `t` (its inputs gathered): outputs onto the bus.
    #[inline(always)]
    pub(super) fn step_one(&mut self, i: usize, n: u64, t: f64) -> Result<(), Stop> {
        match self.rts[i].step_read(&mut self.bus, t) {
            Ok(StepEnd::Done) => self.check_finite_after_step(i, n),
            Ok(StepEnd::Discard) => Err(self.discarded(i, t)),
            Err(e) => Err(self.fail(i, t, e)),
        }
    }

    /// [`check_finite`](Self::check_finite) for component `i` after its step from base step
    /// `n`.
    #[inline(always)]
    pub(super) fn check_finite_after_step(&self, i: usize, n: u64) -> Result<(), Stop> {
        let (a, b) = self.rts[i].ports.out[0];
        if self.allow_nonfinite || all_finite(&self.bus.real[a..b]) {
            Ok(())
        } else {
            let end = self.grid.time(n + self.rts[i].multiple);
            Err(Stop::Failed(self.nonfinite(i, end)))
        }
    }

    #[inline(always)]
    pub(super) fn step_gauss_seidel(
        &mut self,
        order: &[usize],
        n: u64,
        t: f64,
    ) -> Result<(), Stop> {
        for &i in order {
            let rt = &mut self.rts[i];
            if !steps_at(n, rt.multiple) {
                continue;
            }
            rt.gather(&self.bus, &self.signals, t);
            self.step_one(i, n, t)?;
        }
        Ok(())
    }

    #[inline(always)]
    pub(super) fn step_jacobi(&mut self, order: &[usize], n: u64, t: f64) -> Result<(), Stop> {
        for &i in order {
            let rt = &mut self.rts[i];
            if steps_at(n, rt.multiple) {
                rt.gather(&self.bus, &self.signals, t);
            }
        }
        for &i in order {
            if !steps_at(n, self.rts[i].multiple) {
                continue;
            }
            self.step_one(i, n, t)?;
        }
        Ok(())
    }

    pub(super) fn step_parallel(
        &mut self,
        groups: &[Vec<usize>],
        n: u64,
        t: f64,
    ) -> Result<(), Stop> {
        for group in groups {
            let due: Vec<usize> = group
                .iter()
                .copied()
                .filter(|&i| steps_at(n, self.rts[i].multiple))
                .collect();
            for &i in &due {
                self.rts[i].gather(&self.bus, &self.signals, t);
            }
            let results: Vec<(usize, Result<StepEnd, FmuError>)> = if due.len() <= 1 {
                due.iter()
                    .map(|&i| (i, self.rts[i].step_read(&mut self.bus, t)))
                    .collect()
            } else {
                let ranges: Vec<[(usize, usize); 3]> =
                    self.rts.iter().map(|rt| rt.ports.out).collect();
                let outs = self.bus.split(ranges.into_iter());
                let mut work: Vec<(usize, &mut Rt, Outs<'_>)> = self
                    .rts
                    .iter_mut()
                    .zip(outs)
                    .enumerate()
                    .filter(|(i, _)| due.contains(i))
                    .map(|(i, (rt, out))| (i, rt, out))
                    .collect();
                // A thread that cannot start (a process limit) ends the run with an error
                // once the started ones are done: `spawn` would panic.
                let mut not_started = None;
                let results = std::thread::scope(|s| {
                    let handles: Vec<_> = work
                        .drain(..)
                        .filter_map(|(i, rt, out)| {
                            std::thread::Builder::new()
                                .spawn_scoped(s, move || (i, rt.step_read_into(out, t)))
                                .map_err(|e| not_started.get_or_insert(e))
                                .ok()
                        })
                        .collect();
                    handles
                        .into_iter()
                        .map(|h| h.join().expect("a stepping thread panicked"))
                        .collect()
                });
                if let Some(e) = not_started {
                    return Err(Stop::Failed(MasterError::SteppingThread(e)));
                }
                results
            };
            for (i, r) in results {
                match r {
                    Ok(StepEnd::Done) => self.check_finite_after_step(i, n)?,
                    Ok(StepEnd::Discard) => return Err(self.discarded(i, t)),
                    Err(e) => return Err(self.fail(i, t, e)),
                }
            }
        }
        Ok(())
    }
}
