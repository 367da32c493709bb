//! Optimisation: differential evolution over a sweep's parameters, to choose an actuator's
//! spring, gear ratio or gains by a metric instead of by eye over a grid.
//!
//! A spec with an `[optimize]` table ([`OptimizeSpec`]) is a sweep whose design is the first
//! generation (the population: at least [`MIN_POPULATION`] points, each parameter with its
//! `min` and `max`). Each later generation is one batch of trial points, one per member, made by
//! DE/rand/1/bin (Storn and Price, *J. Global Optimization* 11, 1997): for member `i`, three
//! other members `a`, `b`, `c` drawn at random give the mutant `a + F (b - c)`; each coordinate
//! of the trial is the mutant's with probability `CR` (one coordinate always is), else the
//! member's. A mutant coordinate beyond a bound is replaced by a uniform draw between the bound
//! and the member's value, so that every trial stays in `[min, max]`; Integer parameters take
//! the nearest whole value. The trial replaces the member when it is at least as good.
//!
//! **Better** follows Deb's rules for constraints (*Comput. Methods Appl. Mech. Engrg.* 186,
//! 2000): a run's violation is the sum of its metrics' distances beyond their constraints, and
//! infinite for a run that tripped an interlock or failed, or whose objective or a constrained
//! metric is NaN; of two runs without violation the one with the better objective wins, else the
//! one with the smaller violation. A tripped run is never an optimum: the interlocks are the
//! bench's safety limits.
//!
//! **Ids and determinism.** Generation `g`'s trial for member `i` is point `g * P + i` (`P` the
//! population), the design's points being generation 0. The draws of generation `g` come from a
//! generator seeded by the spec's seed and `g` alone, and the members are compared in id order,
//! so the points, the rows and the optimum are the same, bit for bit, whatever the number of
//! workers or the order in which they finish. The driver is [`Optimizer`]'s ask and tell (the
//! points of the next generation; their rows): [`run_optimization`] runs each generation on
//! local threads with the sweep's journal (so `--resume` replays the finished rows and runs the
//! rest), and the Python package runs them on a Dask cluster the same way.

use std::collections::BTreeMap;
use std::path::Path;

use super::SweepError;
use super::design::{MAX_POINTS, SplitMix64};
use super::journal::Finished;
use super::runner::{Prepared, SweepOptions};
use super::spec::{Direction, OptimizeSpec, ParameterType, SpecProblem, SweepSpec};
use super::table::{Row, RunStatus, SweepTable, same_bits};

/// The smallest population: DE/rand/1 draws three members other than the one it improves.
pub const MIN_POPULATION: usize = 4;

/// The problems of a spec's `[optimize]` table that need the metric columns and the design:
/// an objective or a constrained metric that is not a metric column, more runs than a sweep
/// may have ([`MAX_POINTS`]), a population below [`MIN_POPULATION`].
pub fn problems(
    optimize: &OptimizeSpec,
    metric_names: &[String],
    population: usize,
    problem: &dyn Fn(usize, String) -> SpecProblem,
) -> Vec<SpecProblem> {
    let mut out = Vec::new();
    let known = |m: &str| metric_names.iter().any(|n| n == m);
    let listing = || metric_names.join(", ");
    if !known(&optimize.objective) {
        out.push(problem(
            optimize.objective_line,
            format!(
                "objective '{}' is not a metric of this spec (its metrics: {})",
                optimize.objective,
                listing()
            ),
        ));
    }
    for c in &optimize.constraints {
        if !known(&c.metric) {
            out.push(problem(
                c.line,
                format!(
                    "constraint on '{}': not a metric of this spec (its metrics: {})",
                    c.metric,
                    listing()
                ),
            ));
        }
    }
    let runs = (population as u128) * (optimize.generations as u128 + 1);
    if runs > MAX_POINTS as u128 {
        out.push(problem(
            optimize.line,
            format!(
                "the optimisation runs {runs} points (population x (generations + 1)); at most \
                 {MAX_POINTS}"
            ),
        ));
    }
    if population < MIN_POPULATION {
        out.push(problem(
            optimize.line,
            format!(
                "the optimisation's population is the design's points: at least \
                 {MIN_POPULATION}, not {population}"
            ),
        ));
    }
    out
}

/// What one generation reached: the best member after it.
#[derive(Debug, Clone, PartialEq)]
pub struct GenerationBest {
    /// The generation (0: the design).
    pub generation: usize,
    /// The best member's point id.
    pub point: u64,
    /// Its objective (NaN if it has none).
    pub objective: f64,
    /// Its violation (0: it meets every constraint; infinite: it tripped or failed).
    pub violation: f64,
}

/// Differential evolution as ask and tell: [`ask`](Self::ask) gives the next generation's
/// points, [`tell`](Self::tell) takes their rows (see the [module documentation](self)).
#[derive(Debug, Clone)]
pub struct Optimizer {
    settings: OptimizeSpec,
    bounds: Vec<(f64, f64)>,
    integer: Vec<bool>,
    initial: Vec<Vec<f64>>,
    metric_count: usize,
    objective: usize,
    constraints: Vec<(usize, Option<f64>, Option<f64>)>,
    members: Vec<Row>,
    generation: usize,
    asked: Vec<(u64, Vec<f64>)>,
    evaluated: Vec<Row>,
    history: Vec<GenerationBest>,
}

impl Optimizer {
    /// The optimiser of `prepared`'s `[optimize]` table (an error for a spec without one).
    pub fn new(prepared: &Prepared) -> Result<Optimizer, SweepError> {
        Optimizer::from_spec(
            &prepared.spec,
            prepared.design.points.to_rows(),
            &prepared.metric_names,
        )
    }

    /// The optimiser of `spec`'s `[optimize]` table with `initial` as the first generation
    /// (values in spec order) and `metric_names` as the rows' metric columns: what
    /// [`new`](Self::new) does with a prepared sweep's design and metrics.
    pub fn from_spec(
        spec: &SweepSpec,
        initial: Vec<Vec<f64>>,
        metric_names: &[String],
    ) -> Result<Optimizer, SweepError> {
        let settings = spec.optimize.clone().ok_or_else(|| {
            SweepError::Invalid(vec![
                spec.problem(0, "the spec has no [optimize] table: run it as a sweep"),
            ])
        })?;
        let problems = problems(&settings, metric_names, initial.len(), &|line, message| {
            spec.problem(line, message)
        });
        if !problems.is_empty() {
            return Err(SweepError::Invalid(problems));
        }
        let width = spec.parameters.len();
        if let Some((k, point)) = initial.iter().enumerate().find(|(_, p)| p.len() != width) {
            return Err(SweepError::System(format!(
                "optimisation: point {k} has {} values for {width} parameters",
                point.len()
            )));
        }
        let column = |m: &str| metric_names.iter().position(|n| n == m);
        let objective = column(&settings.objective).unwrap_or_default();
        let constraints = settings
            .constraints
            .iter()
            .map(|c| (column(&c.metric).unwrap_or_default(), c.min, c.max))
            .collect();
        let bounds = spec
            .parameters
            .iter()
            .map(|p| {
                (
                    p.min.unwrap_or(f64::NEG_INFINITY),
                    p.max.unwrap_or(f64::INFINITY),
                )
            })
            .collect();
        Ok(Optimizer {
            bounds,
            integer: spec
                .parameters
                .iter()
                .map(|p| p.ty == ParameterType::Integer)
                .collect(),
            initial,
            metric_count: metric_names.len(),
            objective,
            constraints,
            members: Vec::new(),
            generation: 0,
            asked: Vec::new(),
            evaluated: Vec::new(),
            history: Vec::new(),
            settings,
        })
    }

    /// The population (the design's number of points).
    pub fn population(&self) -> usize {
        self.initial.len()
    }

    /// Runs of the whole optimisation: the population times the generations with the design's.
    pub fn total_runs(&self) -> u64 {
        (self.population() * (self.settings.generations + 1)) as u64
    }

    /// The next generation's points (id, values in spec order), the same until their rows
    /// are told; empty once every generation is done.
    pub fn ask(&mut self) -> Vec<(u64, Vec<f64>)> {
        if self.asked.is_empty() && self.generation <= self.settings.generations {
            self.asked = if self.generation == 0 {
                (0u64..)
                    .zip(self.initial.iter().cloned())
                    .collect::<Vec<_>>()
            } else {
                self.trials()
            };
        }
        self.asked.clone()
    }

    /// Takes the rows of the asked points (in any order; each asked id once, with the asked
    /// values) and selects the next members.
    pub fn tell(&mut self, rows: Vec<Row>) -> Result<(), SweepError> {
        let mut by_id: BTreeMap<u64, Row> = BTreeMap::new();
        for row in rows {
            let point = row.point;
            if by_id.insert(point, row).is_some() {
                return Err(SweepError::System(format!(
                    "optimisation: point {point} told twice"
                )));
            }
        }
        if self.asked.is_empty() {
            return Err(SweepError::System(
                "optimisation: rows told before their points were asked".into(),
            ));
        }
        let mut told = Vec::with_capacity(self.asked.len());
        for (id, values) in &self.asked {
            let row = by_id.remove(id).ok_or_else(|| {
                SweepError::System(format!("optimisation: no row for point {id}"))
            })?;
            if !same_bits(&row.parameters, values) {
                return Err(SweepError::System(format!(
                    "optimisation: point {id}'s row has other parameter values than asked"
                )));
            }
            if row.metrics.len() != self.metric_count {
                return Err(SweepError::System(format!(
                    "optimisation: point {id}'s row has {} metrics, not the spec's {}",
                    row.metrics.len(),
                    self.metric_count
                )));
            }
            told.push(row);
        }
        if let Some(extra) = by_id.keys().next() {
            return Err(SweepError::System(format!(
                "optimisation: point {extra} was not asked"
            )));
        }
        if self.generation == 0 {
            self.members = told.clone();
        } else {
            let replaced: Vec<bool> = self
                .members
                .iter()
                .zip(&told)
                .map(|(member, trial)| at_least_as_good(self.fitness(trial), self.fitness(member)))
                .collect();
            for ((member, trial), replace) in self.members.iter_mut().zip(&told).zip(replaced) {
                if replace {
                    *member = trial.clone();
                }
            }
        }
        self.evaluated.extend(told);
        let best = self
            .best_of(&self.members)
            .map(|r| {
                let (violation, _) = self.fitness(r);
                GenerationBest {
                    generation: self.generation,
                    point: r.point,
                    objective: r.metrics[self.objective],
                    violation,
                }
            })
            .ok_or_else(|| SweepError::System("optimisation: no member".into()))?;
        self.history.push(best);
        self.generation += 1;
        self.asked.clear();
        Ok(())
    }

    /// Whether every generation has been run and told.
    pub fn finished(&self) -> bool {
        self.generation > self.settings.generations
    }

    /// The best member after each generation told so far.
    pub fn history(&self) -> &[GenerationBest] {
        &self.history
    }

    /// Every row told so far, in the order told (generation by generation, by id).
    pub fn evaluated(&self) -> &[Row] {
        &self.evaluated
    }

    /// The best row told so far (Deb's rules; of equals, the smallest id), with its violation
    /// (0 if it meets every constraint).
    pub fn best(&self) -> Option<(&Row, f64)> {
        self.best_of(&self.evaluated)
            .map(|r| (r, self.fitness(r).0))
    }

    /// The settings.
    pub fn settings(&self) -> &OptimizeSpec {
        &self.settings
    }

    /// A run's (violation, objective as minimised): see the module documentation.
    fn fitness(&self, row: &Row) -> (f64, f64) {
        let value = row.metrics.get(self.objective).copied().unwrap_or(f64::NAN);
        let objective = match self.settings.direction {
            Direction::Minimize => value,
            Direction::Maximize => -value,
        };
        if row.status != RunStatus::Ok || objective.is_nan() {
            return (f64::INFINITY, objective);
        }
        let mut violation = 0.0;
        for &(k, lo, hi) in &self.constraints {
            let v = row.metrics.get(k).copied().unwrap_or(f64::NAN);
            if v.is_nan() {
                return (f64::INFINITY, objective);
            }
            violation +=
                lo.map_or(0.0, |lo| (lo - v).max(0.0)) + hi.map_or(0.0, |hi| (v - hi).max(0.0));
        }
        (violation, objective)
    }

    fn best_of<'a>(&self, rows: &'a [Row]) -> Option<&'a Row> {
        let mut best: Option<(&Row, (f64, f64))> = None;
        for r in rows {
            let f = self.fitness(r);
            let replace = match best {
                None => true,
                Some((b, fb)) => better(f, fb) || (!better(fb, f) && r.point < b.point),
            };
            if replace {
                best = Some((r, f));
            }
        }
        best.map(|(r, _)| r)
    }

    /// Generation `self.generation`'s trial points (DE/rand/1/bin).
    fn trials(&self) -> Vec<(u64, Vec<f64>)> {
        let n = self.members.len();
        let g = self.generation as u64;
        let s = &self.settings;
        let mut rng = SplitMix64::new(s.seed ^ g.wrapping_mul(0xd1b5_4a32_d192_ed03));
        let mut out = Vec::with_capacity(n);
        for (i, member) in self.members.iter().enumerate() {
            let mut pick = |taken: &[usize]| loop {
                let r = rng.below(n as u64) as usize;
                if !taken.contains(&r) {
                    break r;
                }
            };
            let a = pick(&[i]);
            let b = pick(&[i, a]);
            let c = pick(&[i, a, b]);
            let (xa, xb, xc) = (
                &self.members[a].parameters,
                &self.members[b].parameters,
                &self.members[c].parameters,
            );
            let x = &member.parameters;
            let forced = rng.below(x.len() as u64) as usize;
            let mut trial = Vec::with_capacity(x.len());
            for j in 0..x.len() {
                // Both draws are made for every coordinate, whatever the outcome, so that a
                // coordinate's draws do not depend on the one before.
                let cross = rng.next_f64() < s.crossover || j == forced;
                let u = rng.next_f64();
                let (lo, hi) = self.bounds[j];
                let mut v = if cross {
                    xa[j] + s.differential_weight * (xb[j] - xc[j])
                } else {
                    x[j]
                };
                if v < lo {
                    v = lo + u * (x[j] - lo);
                } else if v > hi {
                    v = hi - u * (hi - x[j]);
                }
                if self.integer[j] {
                    v = v.round().clamp(lo.ceil(), hi.floor());
                }
                trial.push(v);
            }
            out.push((g * n as u64 + i as u64, trial));
        }
        out
    }
}

/// `a` strictly better than `b` (violation, objective as minimised).
fn better(a: (f64, f64), b: (f64, f64)) -> bool {
    if a.0 == 0.0 && b.0 == 0.0 {
        a.1 < b.1
    } else {
        a.0 < b.0
    }
}

/// `a` at least as good as `b`: the trial's test for replacing a member.
fn at_least_as_good(a: (f64, f64), b: (f64, f64)) -> bool {
    !better(b, a)
}

/// A finished optimisation.
#[derive(Debug)]
pub struct Optimization {
    /// Every run, sorted by point id (generation `point / population`), with the sweep's
    /// metadata and the optimisation's (`kneebench.optimize.*`: objective, direction,
    /// population, generations, best point).
    pub table: SweepTable,
    /// The best run.
    pub best: Row,
    /// Its violation (0: it meets every constraint).
    pub violation: f64,
    /// The best member after each generation.
    pub history: Vec<GenerationBest>,
}

/// Runs the optimisation of `prepared` (a spec with `[optimize]`) on local threads, each
/// generation one batch, writing every run's row to `output` (`.parquet`, else CSV) when given,
/// with the sweep's journal for `--resume`; `on_generation` sees each generation's best as it
/// is selected, and an error it returns ends the optimisation with that error (the journal
/// kept for `--resume`). A number of workers outside `1..=`[`MAX_WORKERS`](super::runner::MAX_WORKERS)
/// is refused before anything is written.
pub fn run_optimization(
    prepared: &Prepared,
    output: Option<&Path>,
    options: &SweepOptions,
    on_generation: &mut dyn FnMut(&GenerationBest) -> Result<(), SweepError>,
) -> Result<Optimization, SweepError> {
    super::runner::check_workers(options.workers)?;
    let mut run = JournaledOptimization::start(prepared, output, options)?;
    loop {
        let todo = run.pending(on_generation)?;
        if todo.is_empty() {
            break;
        }
        prepared.run_batch(&todo, options.workers, &mut |row| {
            prepared.unless_stopped()?;
            run.record(row)
        })?;
        let missing: Vec<u64> = todo
            .iter()
            .map(|(id, _)| *id)
            .filter(|id| !run.has_row(*id))
            .collect();
        if !missing.is_empty() {
            return Err(SweepError::Missing(missing));
        }
    }
    run.finish(output)
}

/// An optimisation's runs as they come, journaled when the table goes to a file: the local
/// [`run_optimization`], or a driver that runs the points elsewhere (the Python package's Dask
/// optimisation), with the same journal, `--resume` (a finished Parquet table continued with
/// more generations too) and table. `P` holds the prepared sweep (a reference, or an `Arc`).
pub struct JournaledOptimization<P: std::borrow::Borrow<Prepared>> {
    prepared: P,
    optimizer: Optimizer,
    finished: Finished,
}

impl<P: std::borrow::Borrow<Prepared>> JournaledOptimization<P> {
    /// Starts the optimisation of `prepared` (an error for a spec without `[optimize]`): with
    /// `output`, its journal, whose rows (or, with `options.resume` and no journal, a finished
    /// Parquet table's) are taken as done.
    pub fn start(
        prepared: P,
        output: Option<&Path>,
        options: &SweepOptions,
    ) -> Result<JournaledOptimization<P>, SweepError> {
        let p: &Prepared = prepared.borrow();
        let optimizer = Optimizer::new(p)?;
        let total = optimizer.total_runs();
        let finished = Finished::start(p, output, options, total, &|id| id < total)?;
        Ok(JournaledOptimization {
            prepared,
            optimizer,
            finished,
        })
    }

    /// The current generation's points without a row (id, values in spec order). A
    /// generation whose rows are all there is told first, its best handed to `on_generation`
    /// (an error it returns is returned); empty once every generation is told.
    pub fn pending(
        &mut self,
        on_generation: &mut dyn FnMut(&GenerationBest) -> Result<(), SweepError>,
    ) -> Result<Vec<(u64, Vec<f64>)>, SweepError> {
        loop {
            let asked = self.optimizer.ask();
            if asked.is_empty() {
                return Ok(Vec::new());
            }
            let missing: Vec<(u64, Vec<f64>)> = asked
                .iter()
                .filter(|(id, _)| !self.finished.rows.contains_key(id))
                .cloned()
                .collect();
            if !missing.is_empty() {
                return Ok(missing);
            }
            let rows = asked
                .into_iter()
                .map(|(id, values)| {
                    let mut row = self.finished.rows[&id].clone();
                    // A journaled row has no parameters of its own: they are the asked ones.
                    row.parameters = values;
                    row
                })
                .collect();
            self.optimizer.tell(rows)?;
            if let Some(best) = self.optimizer.history().last() {
                on_generation(best)?;
            }
        }
    }

    /// Keeps a run's row (journaled first): it must be a point of the current generation
    /// with the asked values, bit for bit.
    pub fn record(&mut self, row: Row) -> Result<(), SweepError> {
        // The asked points where they stand, not a copy per row (asked first if need be).
        if self.optimizer.asked.is_empty() {
            self.optimizer.ask();
        }
        match self.optimizer.asked.iter().find(|(id, _)| *id == row.point) {
            Some((_, values)) if same_bits(values, &row.parameters) => self.finished.record(row),
            Some(_) => Err(SweepError::System(format!(
                "optimisation: point {}'s row has other parameter values than asked",
                row.point
            ))),
            None => Err(SweepError::System(format!(
                "optimisation: point {} is not a point of the current generation",
                row.point
            ))),
        }
    }

    /// Whether point `id` has a row.
    pub fn has_row(&self, id: u64) -> bool {
        self.finished.rows.contains_key(&id)
    }

    /// The optimiser (its history, whether it is finished).
    pub fn optimizer(&self) -> &Optimizer {
        &self.optimizer
    }

    /// The finished optimisation (every generation told: see [`pending`](Self::pending)),
    /// its table written to `output` when given and the journal removed.
    pub fn finish(self, output: Option<&Path>) -> Result<Optimization, SweepError> {
        let optimization = self.optimizer.finish(self.prepared.borrow())?;
        self.finished.end(&optimization.table, output)?;
        Ok(optimization)
    }
}

impl Optimizer {
    /// The finished optimisation's table, best run and history (an error before every
    /// generation is told: the optimiser can go on).
    pub fn finish(&self, prepared: &Prepared) -> Result<Optimization, SweepError> {
        if !self.finished() {
            return Err(SweepError::System(format!(
                "optimisation: {} of {} generations told",
                self.history.len(),
                self.settings.generations + 1
            )));
        }
        let (best, violation) = self
            .best()
            .map(|(r, v)| (r.clone(), v))
            .ok_or_else(|| SweepError::System("optimisation: no run".into()))?;
        let s = &self.settings;
        let mut table = prepared.empty_table();
        table.metadata.extend([
            (
                "kneebench.optimize.objective".to_string(),
                s.objective.clone(),
            ),
            (
                "kneebench.optimize.direction".to_string(),
                s.direction.name().to_string(),
            ),
            (
                "kneebench.optimize.population".to_string(),
                self.population().to_string(),
            ),
            (
                "kneebench.optimize.generations".to_string(),
                s.generations.to_string(),
            ),
            (
                "kneebench.optimize.best_point".to_string(),
                best.point.to_string(),
            ),
            (
                "kneebench.optimize.best_feasible".to_string(),
                (violation == 0.0).to_string(),
            ),
        ]);
        let mut rows = self.evaluated.clone();
        rows.sort_by_key(|r| r.point);
        table.rows = rows;
        Ok(Optimization {
            table,
            best,
            violation,
            history: self.history.clone(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A spec of `dims` parameters `c.x0`, `c.x1`, ... in `[lo, hi]` with `[optimize]` lines
    /// `optimize` (the system file is never opened: the optimiser is run on closed forms).
    fn spec(dims: usize, lo: f64, hi: f64, optimize: &str) -> SweepSpec {
        let mut text = String::from(
            "system = \"none.ssp\"\n[design]\nkind = \"random\"\npoints = 4\nseed = 1\n",
        );
        for d in 0..dims {
            text.push_str(&format!(
                "[[parameters]]\nname = \"c.x{d}\"\nmin = {lo:?}\nmax = {hi:?}\n"
            ));
        }
        text.push_str("[[metrics.signals]]\nsignal = \"c.y\"\nstats = [\"mean\"]\n");
        text.push_str("[optimize]\n");
        text.push_str(optimize);
        SweepSpec::parse(&text, Path::new("spec.toml"), Path::new(".")).unwrap()
    }

    fn uniform(n: usize, dims: usize, lo: f64, hi: f64, seed: u64) -> Vec<Vec<f64>> {
        let mut rng = SplitMix64::new(seed);
        (0..n)
            .map(|_| (0..dims).map(|_| lo + (hi - lo) * rng.next_f64()).collect())
            .collect()
    }

    fn names(n: &[&str]) -> Vec<String> {
        n.iter().map(|s| s.to_string()).collect()
    }

    /// A closed-form run: a point's metrics and status.
    type Evaluate = dyn Fn(&[f64]) -> (Vec<f64>, RunStatus);

    /// Runs the optimiser to the end, each point's row from `evaluate` (its metrics and
    /// status), the rows of a generation told in the order `order` gives.
    fn optimise(o: &mut Optimizer, evaluate: &Evaluate, order: &dyn Fn(&mut Vec<Row>)) {
        loop {
            let asked = o.ask();
            if asked.is_empty() {
                break;
            }
            let mut rows: Vec<Row> = asked
                .into_iter()
                .map(|(point, parameters)| {
                    let (metrics, status) = evaluate(&parameters);
                    Row {
                        point,
                        parameters,
                        metrics,
                        status,
                        message: String::new(),
                    }
                })
                .collect();
            order(&mut rows);
            o.tell(rows).unwrap();
        }
        assert!(o.finished());
    }

    /// What the optimiser cannot use is an error, not a panic: a first generation whose
    /// points have another number of values than the parameters (the trials indexed past
    /// them), rows told with another number of metrics than the spec's (the generation's best
    /// indexed its objective past them). Nothing is taken from a refused tell.
    #[test]
    fn points_and_rows_of_another_width_are_refused() {
        let s = spec(2, 0.0, 1.0, "objective = \"f\"\ngenerations = 1\n");
        let mut short = uniform(4, 2, 0.0, 1.0, 1);
        short[2].pop();
        let e = Optimizer::from_spec(&s, short, &names(&["f"])).unwrap_err();
        assert!(
            e.to_string()
                .contains("point 2 has 1 values for 2 parameters"),
            "{e}"
        );
        let mut o = Optimizer::from_spec(&s, uniform(4, 2, 0.0, 1.0, 1), &names(&["f"])).unwrap();
        let rows = |metrics: Vec<f64>, o: &mut Optimizer| -> Vec<Row> {
            o.ask()
                .into_iter()
                .map(|(point, parameters)| Row {
                    point,
                    parameters,
                    metrics: metrics.clone(),
                    status: RunStatus::Ok,
                    message: String::new(),
                })
                .collect()
        };
        for metrics in [vec![], vec![1.0, 2.0]] {
            let told = rows(metrics.clone(), &mut o);
            let e = o.tell(told).unwrap_err();
            assert!(
                e.to_string().contains(&format!(
                    "point 0's row has {} metrics, not the spec's 1",
                    metrics.len()
                )),
                "{e}"
            );
        }
        let told = rows(vec![0.5], &mut o);
        o.tell(told).unwrap();
        assert_eq!(o.history().len(), 1);
    }

    fn bowl(x: &[f64]) -> (Vec<f64>, RunStatus) {
        let f = (x[0] - 1.0).powi(2) + (x[1] + 2.0).powi(2) + (x[2] - 0.5).powi(2);
        (vec![f], RunStatus::Ok)
    }

    #[test]
    fn it_finds_the_minimum_of_a_quadratic_bowl() {
        let s = spec(
            3,
            -5.0,
            5.0,
            "objective = \"f\"\ngenerations = 80\nseed = 3\n",
        );
        let mut o = Optimizer::from_spec(&s, uniform(20, 3, -5.0, 5.0, 9), &names(&["f"])).unwrap();
        assert_eq!(o.total_runs(), 20 * 81);
        optimise(&mut o, &bowl, &|_| {});
        let (best, violation) = o.best().unwrap();
        assert_eq!(violation, 0.0);
        let x = &best.parameters;
        assert!(best.metrics[0] < 1e-8, "{best:?}");
        assert!(
            (x[0] - 1.0).abs() < 1e-4 && (x[1] + 2.0).abs() < 1e-4 && (x[2] - 0.5).abs() < 1e-4
        );
        // The best member never gets worse from one generation to the next, and improves.
        let h = o.history();
        assert_eq!(h.len(), 81);
        assert!(h.windows(2).all(|w| w[1].objective <= w[0].objective));
        assert!(
            h[80].objective < h[0].objective * 1e-6,
            "{:?} {:?}",
            h[0],
            h[80]
        );
        // Every point is evaluated once, ids 0.. in order of generation.
        let ids: Vec<u64> = o.evaluated().iter().map(|r| r.point).collect();
        assert_eq!(ids, (0..20 * 81).collect::<Vec<u64>>());
    }

    #[test]
    fn the_result_does_not_depend_on_the_order_rows_are_told() {
        let s = spec(
            3,
            -5.0,
            5.0,
            "objective = \"f\"\ngenerations = 10\nseed = 5\n",
        );
        let initial = uniform(8, 3, -5.0, 5.0, 2);
        let mut a = Optimizer::from_spec(&s, initial.clone(), &names(&["f"])).unwrap();
        let mut b = Optimizer::from_spec(&s, initial, &names(&["f"])).unwrap();
        optimise(&mut a, &bowl, &|_| {});
        // Reversed and rotated: as workers finishing in any order would give them.
        optimise(&mut b, &bowl, &|rows| {
            rows.reverse();
            rows.rotate_left(3);
        });
        assert_eq!(a.history(), b.history());
        let mut rb = b.evaluated().to_vec();
        rb.sort_by_key(|r| r.point);
        assert_eq!(a.evaluated().len(), rb.len());
        assert!(
            a.evaluated()
                .iter()
                .zip(&rb)
                .all(|(x, y)| x.bit_identical(y))
        );
        // Another seed draws other trials (the seed is used).
        let s2 = spec(
            3,
            -5.0,
            5.0,
            "objective = \"f\"\ngenerations = 10\nseed = 6\n",
        );
        let mut c = Optimizer::from_spec(&s2, uniform(8, 3, -5.0, 5.0, 2), &names(&["f"])).unwrap();
        optimise(&mut c, &bowl, &|_| {});
        assert_ne!(a.evaluated()[8].parameters, c.evaluated()[8].parameters);
    }

    #[test]
    fn constraints_follow_debs_rules() {
        // min x^2 + y^2 subject to x + y >= 1: the optimum is (0.5, 0.5), f = 0.5, on the
        // constraint; the unconstrained minimum (0, 0) is infeasible.
        let s = spec(
            2,
            -2.0,
            2.0,
            "objective = \"f\"\ngenerations = 120\nseed = 1\n\
             [[optimize.constraints]]\nmetric = \"g\"\nmin = 1.0\n",
        );
        let mut o =
            Optimizer::from_spec(&s, uniform(16, 2, -2.0, 2.0, 4), &names(&["f", "g"])).unwrap();
        optimise(
            &mut o,
            &|x| (vec![x[0] * x[0] + x[1] * x[1], x[0] + x[1]], RunStatus::Ok),
            &|_| {},
        );
        let (best, violation) = o.best().unwrap();
        assert_eq!(violation, 0.0, "{best:?}");
        assert!(best.metrics[1] >= 1.0);
        assert!((best.metrics[0] - 0.5).abs() < 1e-4, "{best:?}");
        // Of two infeasible runs the smaller violation wins; a feasible one beats both.
        assert!(better((0.1, 9.0), (0.2, 0.0)));
        assert!(better((0.0, 9.0), (0.1, 0.0)));
        assert!(!better((f64::INFINITY, -1e9), (0.5, 0.0)));
        assert!(at_least_as_good((0.0, 1.0), (0.0, 1.0)));
    }

    #[test]
    fn a_tripped_or_failed_run_never_wins() {
        // The objective is lowest where the run trips (x0 < 0) or fails (NaN, x0 > 4): the
        // optimum is the best run that did neither, at x0 = 0.
        let s = spec(
            1,
            -5.0,
            5.0,
            "objective = \"f\"\ngenerations = 30\nseed = 2\n",
        );
        let mut o = Optimizer::from_spec(&s, uniform(8, 1, -5.0, 5.0, 3), &names(&["f"])).unwrap();
        optimise(
            &mut o,
            &|x| {
                if x[0] < 0.0 {
                    (vec![x[0] - 100.0], RunStatus::Tripped)
                } else if x[0] > 4.0 {
                    (vec![f64::NAN], RunStatus::Failed)
                } else {
                    (vec![x[0]], RunStatus::Ok)
                }
            },
            &|_| {},
        );
        let (best, violation) = o.best().unwrap();
        assert_eq!(best.status, RunStatus::Ok);
        assert_eq!(violation, 0.0);
        assert!(o.evaluated().iter().any(|r| r.status == RunStatus::Tripped));
        assert!(
            best.parameters[0] >= 0.0 && best.parameters[0] < 0.05,
            "{best:?}"
        );
        // With every run tripped, the best is infeasible and says so.
        let mut all =
            Optimizer::from_spec(&s, uniform(8, 1, -5.0, 5.0, 3), &names(&["f"])).unwrap();
        optimise(&mut all, &|x| (vec![x[0]], RunStatus::Tripped), &|_| {});
        assert_eq!(all.best().unwrap().1, f64::INFINITY);
    }

    #[test]
    fn maximize_turns_the_objective_around() {
        let s = spec(
            1,
            -3.0,
            3.0,
            "objective = \"f\"\ndirection = \"maximize\"\ngenerations = 40\nseed = 8\n",
        );
        let mut o = Optimizer::from_spec(&s, uniform(6, 1, -3.0, 3.0, 5), &names(&["f"])).unwrap();
        optimise(
            &mut o,
            &|x| (vec![1.0 - (x[0] - 2.0).powi(2)], RunStatus::Ok),
            &|_| {},
        );
        let (best, _) = o.best().unwrap();
        assert!((best.parameters[0] - 2.0).abs() < 1e-3, "{best:?}");
    }

    #[test]
    fn trials_stay_in_bounds_and_integer_parameters_are_whole() {
        // A narrow box with the optimum outside it pushes mutants beyond the bounds.
        let mut s = spec(
            2,
            0.0,
            10.0,
            "objective = \"f\"\ngenerations = 25\nseed = 4\n",
        );
        s.parameters[1].ty = ParameterType::Integer;
        s.parameters[1].min = Some(1.5);
        s.parameters[1].max = Some(7.5);
        let initial = vec![
            vec![0.5, 2.0],
            vec![9.5, 7.0],
            vec![5.0, 3.0],
            vec![2.0, 6.0],
            vec![7.0, 4.0],
        ];
        let mut o = Optimizer::from_spec(&s, initial, &names(&["f"])).unwrap();
        optimise(&mut o, &|x| (vec![-x[0] + x[1]], RunStatus::Ok), &|_| {});
        for r in &o.evaluated()[5..] {
            let (x, k) = (r.parameters[0], r.parameters[1]);
            assert!((0.0..=10.0).contains(&x), "{r:?}");
            assert!((2.0..=7.0).contains(&k) && k.fract() == 0.0, "{r:?}");
        }
        let (best, _) = o.best().unwrap();
        assert!(
            best.parameters[0] > 9.9 && best.parameters[1] == 2.0,
            "{best:?}"
        );
    }

    #[test]
    fn rows_that_do_not_answer_the_points_asked_are_refused() {
        let s = spec(1, 0.0, 1.0, "objective = \"f\"\ngenerations = 1\n");
        let mut o = Optimizer::from_spec(&s, uniform(4, 1, 0.0, 1.0, 1), &names(&["f"])).unwrap();
        let row = |point: u64, x: f64| Row {
            point,
            parameters: vec![x],
            metrics: vec![x],
            status: RunStatus::Ok,
            message: String::new(),
        };
        let e = o.tell(vec![row(0, 0.5)]).unwrap_err();
        assert!(
            e.to_string().contains("before their points were asked"),
            "{e}"
        );
        let asked = o.ask();
        assert_eq!(asked, o.ask(), "asking again gives the same points");
        let rows = |skip: usize| -> Vec<Row> {
            asked
                .iter()
                .skip(skip)
                .map(|(id, v)| row(*id, v[0]))
                .collect()
        };
        let e = o.tell(rows(1)).unwrap_err();
        assert!(e.to_string().contains("no row for point 0"), "{e}");
        let mut extra = rows(0);
        extra.push(row(9, 0.5));
        let e = o.tell(extra).unwrap_err();
        assert!(e.to_string().contains("point 9 was not asked"), "{e}");
        let mut twice = rows(0);
        twice.push(row(asked[0].0, asked[0].1[0]));
        let e = o.tell(twice).unwrap_err();
        assert!(e.to_string().contains("told twice"), "{e}");
        let mut changed = rows(0);
        changed[2].parameters[0] += 1e-9;
        let e = o.tell(changed).unwrap_err();
        assert!(e.to_string().contains("other parameter values"), "{e}");
        // Nothing was taken by the refused calls: the right rows are.
        o.tell(rows(0)).unwrap();
        assert_eq!(o.history().len(), 1);
        assert!(!o.finished());
    }

    #[test]
    fn a_spec_that_cannot_be_optimised_is_refused_naming_the_line() {
        let s = spec(
            1,
            0.0,
            1.0,
            "objective = \"energy\"\ngenerations = 1\n\
             [[optimize.constraints]]\nmetric = \"rms\"\nmax = 1.0\n",
        );
        let e = Optimizer::from_spec(&s, uniform(3, 1, 0.0, 1.0, 1), &names(&["f"]))
            .unwrap_err()
            .to_string();
        let lines: Vec<&str> = e.lines().collect();
        assert_eq!(
            lines,
            [
                "spec.toml, line 14: objective 'energy' is not a metric of this spec (its metrics: f)",
                "spec.toml, line 16: constraint on 'rms': not a metric of this spec (its metrics: f)",
                "spec.toml, line 13: the optimisation's population is the design's points: at least 4, not 3",
            ]
        );
        // More runs than a sweep may have.
        let s = spec(1, 0.0, 1.0, "objective = \"f\"\ngenerations = 10000\n");
        let e = Optimizer::from_spec(&s, uniform(1001, 1, 0.0, 1.0, 1), &names(&["f"]))
            .unwrap_err()
            .to_string();
        assert_eq!(
            e,
            "spec.toml, line 13: the optimisation runs 10011001 points (population x \
             (generations + 1)); at most 10000000"
        );
    }
}
