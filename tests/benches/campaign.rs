//! The long fault campaign: every case of `kneebench_tests::campaign` run N times through the
//! master into a CSV file against the emulator (in real time, on loopback), and a table of
//! what the bench path did: the expected reaction, the trip codes observed, the latency in
//! control periods (min / median / max), the latch and its acknowledgement, and the rows on
//! disk.
//!
//! ```text
//! cargo bench -p kneebench-tests --bench campaign                        # 10 runs a case
//! KNEEBENCH_CAMPAIGN_RUNS=3 cargo bench -p kneebench-tests --bench campaign
//! KNEEBENCH_CAMPAIGN_CASES=supply cargo bench -p kneebench-tests --bench campaign   # names containing it
//! ```
//!
//! A run the host disturbed (a link trip the fault does not cause, a trip before the fault)
//! is counted in the `disturbed` column and not judged; every other run is checked as the
//! quick set (`tests/tests/campaign.rs`) checks it, and a failed check is printed and makes
//! the program exit with status 1. The SIGKILL case runs this same program as the master
//! process (`campaign::CHILD_ENV`).

use std::collections::BTreeMap;

use kneebench_tests::campaign::{self, Bench, Expected, Fault};

fn median(v: &mut [u64]) -> Option<u64> {
    v.sort_unstable();
    v.get(v.len() / 2).copied()
}

fn expected_text(e: &Expected) -> String {
    match *e {
        Expected::Trip {
            code,
            latch,
            periods,
            confirmed,
        } => format!(
            "trip {code}, latch {latch}, {}-{} periods{}",
            periods.0,
            periods.1,
            if confirmed { "" } else { ", unconfirmed" }
        ),
        Expected::Watchdog { periods } => {
            format!("watchdog latch 2, {}-{} periods", periods.0, periods.1)
        }
        Expected::Completes => "completes".into(),
    }
}

/// `value xN` for each distinct value, in order.
fn counted<T: Ord + std::fmt::Display>(values: impl IntoIterator<Item = T>) -> String {
    let mut m = BTreeMap::new();
    for v in values {
        *m.entry(v).or_insert(0u32) += 1;
    }
    m.iter()
        .map(|(v, n)| format!("{v} x{n}"))
        .collect::<Vec<_>>()
        .join(", ")
}

fn main() {
    if campaign::child_master_if_asked() {
        return;
    }
    let runs: usize = std::env::var("KNEEBENCH_CAMPAIGN_RUNS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(10);
    let filter = std::env::var("KNEEBENCH_CAMPAIGN_CASES").unwrap_or_default();
    let dir = tempfile::tempdir().unwrap();
    let bench = Bench::in_dir(dir.path());
    let exe = std::env::current_exe().unwrap();
    let child = move || std::process::Command::new(&exe);
    println!(
        "fault campaign: {runs} runs a case, replyTimeout 10 ms, heartbeat timeout 50 ms, 1 kHz soft real time"
    );
    println!();
    println!(
        "| case | expected | observed codes | latency [periods] min / median / max | latch (acknowledged) | rows on disk | runs ok / disturbed |"
    );
    println!("|---|---|---|---|---|---|---|");
    let mut failures = Vec::new();
    for case in campaign::cases()
        .into_iter()
        .filter(|c| c.name.contains(&filter))
    {
        let mut codes = Vec::new();
        let mut periods = Vec::new();
        let mut latches = Vec::new();
        let mut rows = Vec::new();
        let (mut ok, mut disturbed) = (0, 0);
        for _ in 0..runs {
            let obs = campaign::run_case(&bench, &case, &child);
            if let Some(why) = &obs.disturbed {
                eprintln!("{}: a disturbed run, not judged: {why}", case.name);
                disturbed += 1;
                continue;
            }
            codes.push(match (obs.code, case.fault) {
                (Some(c), _) => c.to_string(),
                (None, Fault::KillMaster) => "(killed)".into(),
                (None, _) => "none".into(),
            });
            periods.extend(obs.periods);
            latches.push(match (obs.latch, &obs.acknowledgement) {
                (Some(l), Ok(())) => format!("{l} (yes)"),
                (Some(l), Err(_)) => format!("{l} (NO)"),
                (None, _) => "none".into(),
            });
            rows.push((
                obs.file.is_ok(),
                obs.rows_on_disk,
                obs.rows_run.unwrap_or(0),
            ));
            match obs.check(&case) {
                Ok(()) => ok += 1,
                Err(e) => failures.push(e),
            }
        }
        let latency = match median(&mut periods) {
            Some(mid) => format!("{} / {mid} / {}", periods[0], periods[periods.len() - 1]),
            None => "-".into(),
        };
        // Rows on disk over the runs: all that the master made, or how many of how many.
        let span = |v: Vec<u64>| {
            let (lo, hi) = (v.iter().min().copied(), v.iter().max().copied());
            match (lo, hi) {
                (Some(lo), Some(hi)) if lo == hi => lo.to_string(),
                (Some(lo), Some(hi)) => format!("{lo}-{hi}"),
                _ => "-".into(),
            }
        };
        let bad = rows.iter().filter(|r| !r.0).count();
        let disk = span(rows.iter().map(|r| r.1).collect());
        let rows_text = if rows.iter().all(|r| r.1 == r.2) {
            format!("all ({disk})")
        } else {
            format!("{disk} of {}", span(rows.iter().map(|r| r.2).collect()))
        } + &if bad > 0 {
            format!(", {bad} BAD")
        } else {
            String::new()
        };
        println!(
            "| {} | {} | {} | {latency} | {} | {rows_text} | {ok} / {disturbed} |",
            case.name,
            expected_text(&case.expected),
            counted(codes),
            counted(latches),
        );
    }
    println!();
    println!("notes:");
    for case in campaign::cases()
        .into_iter()
        .filter(|c| c.name.contains(&filter))
    {
        println!("- {}: {}", case.name, case.note);
    }
    if !failures.is_empty() {
        eprintln!("\n{} failed checks:", failures.len());
        for f in &failures {
            eprintln!("  {f}");
        }
        std::process::exit(1);
    }
}
