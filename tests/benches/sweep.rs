//! Sweep machinery and results writers: `cargo bench -p kneebench-tests --bench sweep`.
//!
//! - **throughput**: 200 points of a Latin hypercube over the SEA scenario (spring stiffness x
//!   harmonic-drive ratio, two gait cycles at 1 kHz per run, the study metrics), run by
//!   `Prepared::run_points` with 1 and with 2 worker threads, interleaved, [`REPEATS`] times;
//!   runs per second and their ratio (medians). Each call includes every worker's loading of
//!   the system (once per call, as `kneebench sweep` does).
//! - **per-point overhead**: `Prepared::run_point` (a fresh system from the loaded SSP, the
//!   point's values, the run, the metrics) against `System::run` of the same loaded system
//!   with the same recorded columns (the bare closed-loop run), one point, interleaved.
//! - **writers**: the SEA scenario recording every output (100 signals) for 10 s at 1 kHz,
//!   run once into memory; then the same rows written by the streamed CSV writer and by the
//!   Parquet writer, interleaved; seconds each and their ratio.

use std::path::{Path, PathBuf};
use std::time::Instant;

use kneebench_harness::package::export_all;
use kneebench_harness::results::ResultSink;
use kneebench_harness::results::csv::CsvFile;
use kneebench_harness::results::parquet::ParquetFile;
use kneebench_harness::sweep::{Prepared, SweepSpec};
use kneebench_harness::{LoadOptions, Results, ssp};
use kneebench_tests::fmu_library;

const REPEATS: usize = 7;

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn spec(fmus: &Path, points: usize) -> Prepared {
    let text = format!(
        "system = \"SEA\"\nfmus = \"{}\"\ncycles = 2\n[design]\nkind = \"latin-hypercube\"\npoints = {points}\nseed = 1\n\
         [[parameters]]\nname = \"plant.springStiffness\"\nmin = 250.0\nmax = 450.0\n\
         [[parameters]]\nname = \"plant.harmonicDriveRatio\"\nmin = 140.0\nmax = 180.0\n",
        fmus.display()
    );
    Prepared::new(SweepSpec::parse(&text, Path::new("bench.toml"), fmus).unwrap()).unwrap()
}

fn main() {
    let dir = tempfile::tempdir().unwrap();
    let fmus: PathBuf = dir.path().join("fmus");
    export_all(&fmu_library(), &fmus).unwrap();

    let p = spec(&fmus, 200);
    let ids: Vec<u64> = (0..200).collect();
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
        "throughput: 1 worker {r1:.1} runs/s, 2 workers {r2:.1} runs/s, ratio {:.2} (runs of 5 s simulated)",
        r2 / r1
    );

    let loaded = ssp::load_system(&p.system_file, &LoadOptions::default()).unwrap();
    let mut bare_system = ssp::load_system(&p.system_file, &LoadOptions::default()).unwrap();
    let refs: Vec<&str> = p.recorded.iter().map(String::as_str).collect();
    bare_system.system.record(&refs).unwrap();
    let (mut point, mut bare) = (Vec::new(), Vec::new());
    for _ in 0..REPEATS * 4 {
        let t = Instant::now();
        let row = p.run_point(&loaded, 0);
        point.push(t.elapsed().as_secs_f64());
        assert_eq!(row.status.name(), "ok");
        let t = Instant::now();
        bare_system.system.run(&p.config).unwrap();
        bare.push(t.elapsed().as_secs_f64());
    }
    // Minima as well as medians: on a loaded machine single runs are descheduled for
    // milliseconds, and the minimum is each side's undisturbed cost.
    let min = |v: &[f64]| v.iter().copied().fold(f64::INFINITY, f64::min);
    let (mp, mb) = (min(&point), min(&bare));
    let (tp, tb) = (median(point), median(bare));
    println!(
        "per point: run_point {:.3} ms (min {:.3}), bare System::run {:.3} ms (min {:.3}), overhead {:+.1} % (of the minima {:+.1} %)",
        tp * 1e3,
        mp * 1e3,
        tb * 1e3,
        mb * 1e3,
        (tp - tb) / tb * 100.0,
        (mp - mb) / mb * 100.0
    );

    let mut full = ssp::load_system(&p.system_file, &LoadOptions::default()).unwrap();
    full.config.stop_time = 10.0;
    let results: Results = full.system.run(&full.config).unwrap().results;
    let (mut csv, mut parquet) = (Vec::new(), Vec::new());
    for _ in 0..REPEATS {
        let path = dir.path().join("w.csv");
        let t = Instant::now();
        let mut f = CsvFile::create(&path).unwrap();
        write(&results, &mut f);
        f.commit().unwrap();
        csv.push(t.elapsed().as_secs_f64());
        let path = dir.path().join("w.parquet");
        let t = Instant::now();
        let mut f = ParquetFile::create(&path).unwrap();
        write(&results, &mut f);
        f.commit().unwrap();
        parquet.push(t.elapsed().as_secs_f64());
    }
    let (tc, tq) = (median(csv), median(parquet));
    println!(
        "writers ({} signals x {} rows): CSV {:.1} ms, Parquet {:.1} ms, Parquet {:.1}x faster",
        results.names().len(),
        results.len(),
        tc * 1e3,
        tq * 1e3,
        tc / tq
    );
}

fn write(results: &Results, sink: &mut dyn ResultSink) {
    sink.begin(results.names(), results.kinds()).unwrap();
    for row in results.rows() {
        sink.push_row(row[0], &row[1..]).unwrap();
    }
    sink.flush().unwrap();
}
