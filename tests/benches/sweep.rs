//! Sweep machinery and results writers: `cargo bench -p kneebench-tests --bench sweep`.
//!
//! Every figure is a ratio of two measurements taken in the same run, interleaved, medians of
//! [`REPEATS`] repeats; the load average of the machine is printed before and after (the
//! figures of a shared machine mean little without it).
//!
//! - **throughput**: [`THROUGHPUT_POINTS`] points of a Latin hypercube over the SEA scenario
//!   (spring stiffness x harmonic-drive ratio, two gait cycles of 2.5 s at 1 kHz per run: the
//!   start-up and one analysed; the study metrics), run by `Prepared::run_points` with 1 and with 2 worker threads; runs per
//!   second and their ratio. Each call includes every worker's loading of the system (once
//!   per call, as `kneebench sweep` does).
//! - **per-point overhead of the sweep machinery**: a whole sweep as `kneebench sweep` runs it
//!   on one worker (the spec parsed and checked against the FMUs, the design, the scenario
//!   written and loaded, the points scheduled, each run's study metrics, its journal line,
//!   the Parquet table written through its partial file) against the bare closed loop: the
//!   same scenario `.ssp` loaded once, then per point a clone of it, its two values set and
//!   two gait cycles of `System::run` recording the same signals. Both are timed at [`SMALL`] and [`LARGE`]
//!   points: the slope (seconds per added point) is each one's per-point cost, the sweep's
//!   overhead is the ratio of the slopes less one; the intercepts are the fixed costs (for the
//!   sweep: spec, scenario, loading), reported with what they add per point at [`LARGE`].
//! - **writers**: the SEA scenario recording every output (about 100 signals) for 10 s at
//!   1 kHz, run once into memory; then the same rows written by the streamed CSV writer and by
//!   the Parquet writer (each encoding on its own thread, the default, and in the caller's),
//!   and by both writers as they were before their speed work (kept in
//!   `sweep/baseline_writers.rs`), each to its partial file, synced and renamed into place (a new file in each repeat:
//!   the previous repeat's is removed before the clock starts, as for the bytes' I/O alone);
//!   wall time (the durable write a user waits for) and the process's CPU time, user and
//!   system (the writer thread's included; without the wait for the disk), each writer's I/O
//!   alone (its file's bytes written at once and synced), and the ratios. `KNEEBENCH_WRITERS_PROFILE=<writer>|none` writes one file and stops, for
//!   instruction counts under callgrind (`valgrind --tool=callgrind <bench binary>`, the
//!   writer's count is the difference with `none`).
//!
//! - **optimize**: an optimisation (`run_optimization`: a population of [`POPULATION`],
//!   [`GENERATIONS`] generations after it, each a batch run by the sweep's workers) against a
//!   sweep of as many points (`run_sweep`, one batch), both on the SEA scenario's gait cycle
//!   with the study metrics, with 1 and 2 workers: runs per second and the optimiser's cost
//!   per run over the sweep's (the selection, the batch per generation, and with 2 workers
//!   the wait at each generation's end for the slower worker).
//!
//! `KNEEBENCH_SWEEP_BENCH_ONLY=throughput|overhead|writers|optimize` runs one part alone.
//! `KNEEBENCH_OVERHEAD_PROFILE=sweep:N|bare:N` runs one sweep (as the overhead part times it)
//! or one bare closed loop of `N` points and stops, for instruction counts under callgrind
//! (`valgrind --tool=callgrind <bench binary>`): the per-point count of each is the difference
//! of two `N` over the difference of the `N`s, the machinery's the sweep's less the bare one's.

use std::path::{Path, PathBuf};
use std::time::Instant;

#[path = "sweep/baseline_writers.rs"]
mod baseline_writers;

use kneebench_harness::master::Value;
use kneebench_harness::package::export_all;
use kneebench_harness::results::ResultSink;
use kneebench_harness::results::csv::CsvFile;
use kneebench_harness::results::parquet::{EncodeOn, ParquetFile};
use kneebench_harness::sweep::{Prepared, SweepOptions, SweepSpec, run_optimization, run_sweep};
use kneebench_harness::{LoadOptions, Results, ssp};
use kneebench_tests::fmu_library;

const REPEATS: usize = 7;
/// Points of the throughput measurement.
const THROUGHPUT_POINTS: usize = 400;
/// The smaller sweep of the per-point measurement.
const SMALL: usize = 40;
/// The larger sweep of the per-point measurement.
const LARGE: usize = 240;
/// The optimisation's population.
const POPULATION: usize = 8;
/// The optimisation's generations after the design's.
const GENERATIONS: usize = 24;

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn load_average() -> String {
    std::fs::read_to_string("/proc/loadavg")
        .map(|s| s.split_whitespace().take(3).collect::<Vec<_>>().join(" "))
        .unwrap_or_else(|_| "unknown".into())
}

/// The spec text: SEA, two gait cycles (the first, the start-up, is not analysed), `points` Latin-hypercube points.
fn spec_text(fmus: &Path, points: usize) -> String {
    format!(
        "system = \"SEA\"\nfmus = \"{}\"\ncycles = 2\n[design]\nkind = \"latin-hypercube\"\npoints = {points}\nseed = 1\n\
         [[parameters]]\nname = \"plant.springStiffness\"\nmin = 250.0\nmax = 450.0\n\
         [[parameters]]\nname = \"plant.harmonicDriveRatio\"\nmin = 140.0\nmax = 180.0\n",
        fmus.display()
    )
}

fn prepare(dir: &Path, fmus: &Path, points: usize) -> Prepared {
    let path = dir.join(format!("sweep{points}.toml"));
    std::fs::write(&path, spec_text(fmus, points)).unwrap();
    Prepared::new(SweepSpec::from_file(&path).unwrap()).unwrap()
}

/// `kneebench sweep SPEC --output OUT.parquet --workers 1`, in process: seconds.
fn timed_sweep(dir: &Path, fmus: &Path, points: usize) -> f64 {
    let out = dir.join(format!("table{points}.parquet"));
    let t = Instant::now();
    let p = prepare(dir, fmus, points);
    let options = SweepOptions {
        workers: 1,
        progress: false,
        resume: false,
    };
    let table = run_sweep(&p, Some(&out), &options).unwrap();
    let s = t.elapsed().as_secs_f64();
    assert_eq!(table.rows.len(), points);
    assert!(table.rows.iter().all(|r| r.status.name() == "ok"));
    s
}

/// The bare closed loop over the same points: the scenario loaded once, then per point a
/// clone of it, its values set and `System::run`: seconds.
fn timed_bare(p: &Prepared, points: usize) -> f64 {
    let t = Instant::now();
    let mut loaded = ssp::load_system(&p.system_file, &LoadOptions::default()).unwrap();
    let refs: Vec<&str> = p.recorded.iter().map(String::as_str).collect();
    loaded.system.record(&refs).unwrap();
    for point in p.design.points.iter().take(points) {
        // A clone per point, as the sweep's runner does: each run starts from the loaded
        // system's own values.
        let mut system = loaded.system.clone();
        for (name, v) in p.design.names.iter().zip(point) {
            system.set_value(name, Value::Real(*v)).unwrap();
        }
        let out = system.run(&p.config).unwrap();
        assert!(out.results.len() > 2000);
    }
    t.elapsed().as_secs_f64()
}

fn main() {
    let dir = tempfile::tempdir().unwrap();
    let fmus: PathBuf = dir.path().join("fmus");
    export_all(&fmu_library(), &fmus).unwrap();
    if let Ok(profile) = std::env::var("KNEEBENCH_OVERHEAD_PROFILE") {
        overhead_profile(dir.path(), &fmus, &profile);
        return;
    }
    println!("load average before: {}", load_average());
    let only = std::env::var("KNEEBENCH_SWEEP_BENCH_ONLY")
        .ok()
        .filter(|o| !o.is_empty());
    let part = |name: &str| only.as_deref().is_none_or(|o| o == name);

    let p = prepare(dir.path(), &fmus, THROUGHPUT_POINTS);
    if part("throughput") {
        throughput(&p);
    }
    if part("overhead") {
        overhead(dir.path(), &fmus);
    }
    if part("writers") {
        writers(dir.path(), &p);
    }
    if part("optimize") {
        optimize(dir.path(), &fmus);
    }
    println!("load average after: {}", load_average());
}

/// An optimisation and a sweep of as many runs (see the module documentation).
fn optimize(dir: &Path, fmus: &Path) {
    let runs = POPULATION * (GENERATIONS + 1);
    let metrics = "[metrics]\nstudy = true\n";
    let spec = |name: &str, text: String| {
        let path = dir.join(name);
        std::fs::write(&path, text).unwrap();
        Prepared::new(SweepSpec::from_file(&path).unwrap()).unwrap()
    };
    let optimization = spec(
        "optimize.toml",
        format!(
            "{}{metrics}[optimize]\nobjective = \"rms_error_knee\"\ngenerations = {GENERATIONS}\n\
             seed = 2\n[[optimize.constraints]]\nmetric = \"all_electrical_energy\"\nmax = 85.0\n",
            spec_text(fmus, POPULATION)
        ),
    );
    let sweep = spec("same.toml", format!("{}{metrics}", spec_text(fmus, runs)));
    let mut rate = [[Vec::new(), Vec::new()], [Vec::new(), Vec::new()]];
    for _ in 0..REPEATS {
        for (k, workers) in [1usize, 2].into_iter().enumerate() {
            let options = SweepOptions {
                workers,
                progress: false,
                resume: false,
            };
            let t = Instant::now();
            let o = run_optimization(&optimization, None, &options, &mut |_| Ok(())).unwrap();
            rate[0][k].push(runs as f64 / t.elapsed().as_secs_f64());
            assert_eq!(o.table.rows.len(), runs);
            let t = Instant::now();
            let table = run_sweep(&sweep, None, &options).unwrap();
            rate[1][k].push(runs as f64 / t.elapsed().as_secs_f64());
            assert_eq!(table.rows.len(), runs);
        }
    }
    let [[o1, o2], [s1, s2]] = rate.map(|r| r.map(median));
    println!(
        "optimisation ({POPULATION} x {} generations = {runs} runs of two gait cycles) vs a sweep \
         of {runs} points: 1 worker {o1:.1} vs {s1:.1} runs/s (cost per run {:+.1} %), 2 workers \
         {o2:.1} vs {s2:.1} runs/s ({:+.1} %); 2 workers over 1: optimisation {:.2}x, sweep {:.2}x",
        GENERATIONS + 1,
        (s1 / o1 - 1.0) * 100.0,
        (s2 / o2 - 1.0) * 100.0,
        o2 / o1,
        s2 / s1
    );
}

fn throughput(p: &Prepared) {
    let ids: Vec<u64> = (0..THROUGHPUT_POINTS as u64).collect();
    let mut rate = [Vec::new(), Vec::new()];
    for _ in 0..REPEATS {
        for (k, workers) in [1usize, 2].into_iter().enumerate() {
            let t = Instant::now();
            p.run_points(&ids, workers, &mut |_| Ok(())).unwrap();
            rate[k].push(ids.len() as f64 / t.elapsed().as_secs_f64());
        }
    }
    let (r1, r2) = (median(rate[0].clone()), median(rate[1].clone()));
    println!(
        "throughput ({THROUGHPUT_POINTS} runs of two 2.5 s gait cycles): 1 worker {r1:.1} runs/s \
         ({:.2} ms per run), 2 workers {r2:.1} runs/s, ratio {:.2}",
        1e3 / r1,
        r2 / r1
    );
}

/// One sweep or one bare closed loop of `sweep:N` or `bare:N` points (see the module
/// documentation), for instruction counts.
fn overhead_profile(dir: &Path, fmus: &Path, profile: &str) {
    let parsed = profile
        .split_once(':')
        .and_then(|(what, n)| Some((what, n.parse::<usize>().ok()?)));
    match parsed {
        Some(("sweep", n)) => {
            timed_sweep(dir, fmus, n);
        }
        Some(("bare", n)) => {
            timed_bare(&prepare(dir, fmus, n), n);
        }
        _ => panic!("KNEEBENCH_OVERHEAD_PROFILE={profile}: expected sweep:N or bare:N"),
    }
}

fn overhead(dir: &Path, fmus: &Path) {
    let (mut sweep, mut bare) = ([Vec::new(), Vec::new()], [Vec::new(), Vec::new()]);
    let p_large = prepare(dir, fmus, LARGE);
    for _ in 0..REPEATS {
        for (k, n) in [SMALL, LARGE].into_iter().enumerate() {
            sweep[k].push(timed_sweep(dir, fmus, n));
            // The bare runs take the first n points of the larger design (the smaller design's
            // points differ, but every point runs the same cycle).
            bare[k].push(timed_bare(&p_large, n));
        }
    }
    let [s_small, s_large] = sweep.map(median);
    let [b_small, b_large] = bare.map(median);
    let span = (LARGE - SMALL) as f64;
    let (s_slope, b_slope) = ((s_large - s_small) / span, (b_large - b_small) / span);
    let (s_fixed, b_fixed) = (
        s_small - s_slope * SMALL as f64,
        b_small - b_slope * SMALL as f64,
    );
    println!(
        "per point: sweep machinery {:.3} ms, bare System::run {:.3} ms (two gait cycles), \
         overhead {:+.1} %; fixed costs: sweep {:.1} ms (spec, scenario, loading), bare {:.1} ms \
         (loading), i.e. {:+.1} % per point at {LARGE} points; sweeps of {SMALL}/{LARGE} points \
         {:.1}/{:.1} ms, bare {:.1}/{:.1} ms",
        s_slope * 1e3,
        b_slope * 1e3,
        (s_slope / b_slope - 1.0) * 100.0,
        s_fixed * 1e3,
        b_fixed * 1e3,
        (s_large / b_large - 1.0) * 100.0,
        s_small * 1e3,
        s_large * 1e3,
        b_small * 1e3,
        b_large * 1e3,
    );
    // The measure is against one cycle: the runs take two (one cycle alone is the
    // start-up, which the study's metrics refuse), so the same machinery cost is put against
    // half a bare run (the metrics' share, which grows with the rows, is counted in full).
    let per_run = |total: f64, bare: f64| (total - bare) / (bare / 2.0) * 100.0;
    println!(
        "against one gait cycle (the issue's measure): overhead {:+.1} % per point, {:+.1} % \
         with the fixed costs spread over {LARGE} points",
        per_run(s_slope, b_slope),
        per_run(s_large / LARGE as f64, b_large / LARGE as f64),
    );
}

/// The writers compared by [`writers`], in the order they are run in each repeat.
const WRITERS: [&str; 6] = [
    "CSV before",
    "CSV caller",
    "CSV",
    "Parquet before",
    "Parquet caller",
    "Parquet",
];

/// The file writer `k` of [`WRITERS`] writes in `dir`.
fn output_of(k: usize, dir: &Path) -> PathBuf {
    let name = [
        "before.csv",
        "caller.csv",
        "w.csv",
        "before.parquet",
        "caller.parquet",
        "w.parquet",
    ];
    dir.join(name[k])
}

/// Writes `results` through writer `k` of [`WRITERS`] into `dir` (partial file, sync, rename):
/// the file's path.
fn write_with(k: usize, results: &Results, dir: &Path) -> PathBuf {
    let names = results.names();
    let path = output_of(k, dir);
    let rows = || results.rows().map(|r| (r[0], &r[1..]));
    match k {
        0 => {
            let mut f = baseline_writers::CsvFile::create(&path).unwrap();
            f.begin(names, results.kinds()).unwrap();
            for (t, v) in rows() {
                f.push_row(t, v).unwrap();
            }
            f.commit().unwrap()
        }
        1 => {
            let mut f = CsvFile::create(&path)
                .unwrap()
                .encoding_on(EncodeOn::Caller);
            write(results, &mut f);
            f.commit().unwrap()
        }
        2 => {
            let mut f = CsvFile::create(&path).unwrap();
            write(results, &mut f);
            f.commit().unwrap()
        }
        3 => {
            let mut f = baseline_writers::ParquetFile::create(&path).unwrap();
            f.begin(names).unwrap();
            for (t, v) in rows() {
                f.push_row(t, v).unwrap();
            }
            f.commit().unwrap()
        }
        4 => {
            let mut f = ParquetFile::create_encoding_on(&path, EncodeOn::Caller).unwrap();
            write(results, &mut f);
            f.commit().unwrap()
        }
        _ => {
            let mut f = ParquetFile::create(&path).unwrap();
            write(results, &mut f);
            f.commit().unwrap()
        }
    }
}

/// CPU time of the process so far, (user, system) seconds: what a writer costs, its own
/// thread's included, without the wait for the disk (the sync) that the wall time holds.
fn process_cpu() -> (f64, f64) {
    // SAFETY: getrusage fills the struct it is given; all zeros is a valid value of it.
    let mut u: libc::rusage = unsafe { std::mem::zeroed() };
    // SAFETY: as above.
    unsafe { libc::getrusage(libc::RUSAGE_SELF, &mut u) };
    let s = |t: libc::timeval| t.tv_sec as f64 + t.tv_usec as f64 * 1e-6;
    (s(u.ru_utime), s(u.ru_stime))
}

fn writers(dir: &Path, p: &Prepared) {
    let mut full = ssp::load_system(&p.system_file, &LoadOptions::default()).unwrap();
    full.config.stop_time = 10.0;
    let results: Results = full.system.run(&full.config).unwrap().results;
    if let Ok(k) = std::env::var("KNEEBENCH_WRITERS_PROFILE") {
        // One file by one writer (or none: "none"), for instruction counts under callgrind:
        // the writer's count is this run's less the run with "none".
        if let Some(k) = WRITERS.iter().position(|w| w.eq_ignore_ascii_case(&k)) {
            write_with(k, &results, dir);
        }
        return;
    }
    let n = WRITERS.len();
    let series = || vec![Vec::new(); n];
    let (mut wall, mut user, mut system) = (series(), series(), series());
    let mut files = Vec::new();
    for _ in 0..REPEATS {
        files.clear();
        for k in 0..n {
            // Each repeat writes a new file, as a first run does: replacing the previous
            // repeat's file would free its pages inside the timed rename (about 1 ms for the
            // Parquet file and 2-4 ms for the CSV one on /dev/shm), a cost of the file
            // replaced, not of the writer.
            let _ = std::fs::remove_file(output_of(k, dir));
            let (t, (u, s)) = (Instant::now(), process_cpu());
            files.push(write_with(k, &results, dir));
            let (u2, s2) = process_cpu();
            wall[k].push(t.elapsed().as_secs_f64());
            user[k].push(u2 - u);
            system[k].push(s2 - s);
        }
    }
    // The file system's share: each file's bytes written at once and synced (every writer
    // syncs its file before renaming it into place).
    let bytes: Vec<Vec<u8>> = files.iter().map(|f| std::fs::read(f).unwrap()).collect();
    let mut io = series();
    for _ in 0..REPEATS {
        for (k, b) in bytes.iter().enumerate() {
            let path = dir.join(format!("io{k}"));
            let _ = std::fs::remove_file(&path);
            let t = Instant::now();
            let mut f = std::fs::File::create(&path).unwrap();
            std::io::Write::write_all(&mut f, b).unwrap();
            f.sync_all().unwrap();
            io[k].push(t.elapsed().as_secs_f64());
        }
    }
    let medians = |v: Vec<Vec<f64>>| v.into_iter().map(median).collect::<Vec<f64>>();
    let (wall, user, system, io) = (medians(wall), medians(user), medians(system), medians(io));
    let cpu: Vec<f64> = user.iter().zip(&system).map(|(u, s)| u + s).collect();
    println!(
        "writers ({} signals x {} rows; wall time, of which the bytes' write and sync alone; \
         the process's CPU time, user + system as the kernel splits it by its tick samples):",
        results.names().len(),
        results.len()
    );
    for k in 0..n {
        println!(
            "  {:<15} {:6.1} ms ({:5.1} MB; I/O alone {:5.1} ms), CPU {:5.1} ms ({:4.1} + {:4.1})",
            WRITERS[k],
            wall[k] * 1e3,
            bytes[k].len() as f64 / 1e6,
            io[k] * 1e3,
            cpu[k] * 1e3,
            user[k] * 1e3,
            system[k] * 1e3,
        );
    }
    let ratio = |a: usize, b: usize| (wall[a] / wall[b], cpu[a] / cpu[b]);
    for (what, a, b) in [
        ("Parquet vs CSV", 2, 5),
        ("Parquet vs CSV caller", 1, 5),
        ("Parquet vs CSV before", 0, 5),
        ("CSV vs CSV before", 0, 2),
        ("CSV vs CSV caller", 1, 2),
        ("Parquet vs Parquet before", 3, 5),
        ("Parquet vs Parquet caller", 4, 5),
    ] {
        let (w, c) = ratio(a, b);
        println!("  {what:<26} {w:4.2}x faster (CPU time: {c:4.2}x)");
    }
    // The physical ceiling of "Parquet vs CSV": the CSV writer's wall time over the Parquet
    // file's bytes alone, written at once and synced (a writer that cost nothing).
    println!(
        "  ceiling of Parquet vs CSV (CSV wall / Parquet bytes' I/O alone): {:4.2}x",
        wall[2] / io[5]
    );
}

/// Pushes `results` into `sink` as `System::run` does: begun, the rows announced, each row.
fn write(results: &Results, sink: &mut dyn ResultSink) {
    sink.begin(results.names(), results.kinds()).unwrap();
    sink.expect_rows(results.len() as u64);
    for row in results.rows() {
        sink.push_row(row[0], &row[1..]).unwrap();
    }
    sink.flush().unwrap();
}
