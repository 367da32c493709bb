//! Reading and checking an experiment log for identification, and the smoothed signals the
//! regressions use.

use std::path::{Path, PathBuf};

use super::IdentifyError;
use super::resample::{BENCH_SAMPLE_TIME, MAX_INTERPOLATED_GAP, Resampling};
use super::smooth::derivatives;

/// Channels a log must have (names of the bench FMU's outputs; a `plant.` prefix, as
/// `kneebench experiment` writes, is accepted).
pub const REQUIRED: [&str; 5] = [
    "actuationEncoderAngle",
    "loadEncoderAngle",
    "testMotorCurrent",
    "loadMotorCurrent",
    "transducerTorque",
];

/// Channels used when present: the drivers' voltages (the motors' electrical parameters),
/// the flags that exclude rows, and the sensors whose offsets are estimated (the load cell's
/// torque, the current sensors' raw volts).
pub const OPTIONAL: [&str; 8] = [
    "testMotorVoltage",
    "loadMotorVoltage",
    "testDriverSaturated",
    "loadDriverSaturated",
    "tripCode",
    "loadCellTorque",
    "testCurrentSenseVoltage",
    "loadCurrentSenseVoltage",
];

/// The current set value of the motor an experiment drives (`kneebench experiment`'s driving
/// controller `drive`, whose output is the set value in A): used, when present, as the
/// refinement's drive for the motor whose current follows it.
pub const COMMAND: &str = "drive.u";

/// A checked log with its smoothed signals (NaN where the smoothing window does not fit or
/// the row is excluded).
#[derive(Debug, Clone)]
pub struct Log {
    /// The file.
    pub path: PathBuf,
    /// Sample period \[s\].
    pub dt: f64,
    /// Times \[s\]: the log's, or a uniform grid of the bench's clock from the log's first
    /// time when the log was resampled on it.
    pub time: Vec<f64>,
    /// Raw encoder angles, actuation and load side \[rad\].
    pub angle: [Vec<f64>; 2],
    /// Smoothed velocities \[rad/s\].
    pub velocity: [Vec<f64>; 2],
    /// Smoothed accelerations \[rad/s^2\].
    pub acceleration: [Vec<f64>; 2],
    /// Logged (actual) motor currents, test and load \[A\].
    pub current: [Vec<f64>; 2],
    /// Smoothed currents \[A\].
    pub current_smooth: [Vec<f64>; 2],
    /// Current derivatives \[A/s\].
    pub current_rate: [Vec<f64>; 2],
    /// Motor voltages \[V\], when logged.
    pub voltage: [Option<Vec<f64>>; 2],
    /// Transducer (shaft) torque [N m].
    pub torque: Vec<f64>,
    /// The load cell's torque reading [N m], when logged.
    pub load_cell: Option<Vec<f64>>,
    /// The current sensors' raw output, test and load motor \[V\], when logged.
    pub current_sense: [Option<Vec<f64>>; 2],
    /// The logged current set value ([`COMMAND`]), when present.
    pub command: Option<Vec<f64>>,
    /// Rows the regressions may use (not excluded, inside the smoothing window).
    pub usable: Vec<bool>,
    /// What was excluded and why, for the report.
    pub notes: Vec<String>,
}

/// The columns of a CSV log that identification reads, parsed without the others (a log of
/// `kneebench experiment` has some 120 columns; parsing only these is several times faster).
struct Table {
    /// The first column.
    time: Vec<f64>,
    /// Per wanted name, its column if the header has it.
    columns: Vec<Option<Vec<f64>>>,
    /// Where each row is in the file (1-based): its line in a CSV file, its row in Parquet.
    lines: Vec<usize>,
    /// What [`Self::lines`] counts: "line" or "row".
    place: &'static str,
}

/// Reads the wanted columns of a Parquet log (`.parquet`: `kneebench experiment --format
/// parquet`, or any tool's table with a time column).
fn read_parquet_table(path: &Path, wanted: &[String]) -> Result<Table, String> {
    let r = crate::results::parquet_read::read_parquet(path, Some(wanted))
        .map_err(|e| e.to_string())?;
    Ok(Table {
        columns: wanted.iter().map(|w| r.column(w)).collect(),
        lines: (1..=r.len()).collect(),
        time: r.times().to_vec(),
        place: "row",
    })
}

/// Reads the next line of `r` into `buf` (cleared first) and counts it in `line`; false at the
/// end of the file.
fn next_line(
    r: &mut impl std::io::BufRead,
    buf: &mut String,
    line: &mut usize,
) -> Result<bool, String> {
    buf.clear();
    *line += 1;
    let read = r
        .read_line(buf)
        .map_err(|e| format!("line {}: {e}", *line))?;
    Ok(read != 0)
}

fn read_table(path: &Path, wanted: &[String]) -> Result<Table, String> {
    if path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("parquet"))
    {
        return read_parquet_table(path, wanted);
    }
    let f = std::fs::File::open(path).map_err(|e| e.to_string())?;
    let mut r = std::io::BufReader::with_capacity(1 << 20, f);
    let mut buf = String::new();
    let mut line = 0usize;
    let header = loop {
        if !next_line(&mut r, &mut buf, &mut line)? {
            return Err("empty file".into());
        }
        let l = buf.trim();
        if !l.is_empty() && !l.starts_with('#') {
            break l
                .split(',')
                .map(|s| s.trim().trim_matches('"').to_string())
                .collect::<Vec<_>>();
        }
    };
    let index: Vec<Option<usize>> = wanted
        .iter()
        .map(|w| header.iter().position(|h| h == w))
        .collect();
    let mut table = Table {
        time: Vec::new(),
        columns: index.iter().map(|i| i.map(|_| Vec::new())).collect(),
        lines: Vec::new(),
        place: "line",
    };
    // Field position -> slot in `columns`.
    let mut slot = vec![None; header.len()];
    for (k, i) in index.iter().enumerate() {
        if let Some(i) = i {
            slot[*i] = Some(k);
        }
    }
    let parse = |f: &str, line: usize, name: &str| -> Result<f64, String> {
        match f.trim() {
            "true" | "True" => Ok(1.0),
            "false" | "False" => Ok(0.0),
            t => t
                .parse()
                .map_err(|_| format!("line {line}: {name} '{t}' is not a number")),
        }
    };
    while next_line(&mut r, &mut buf, &mut line)? {
        let l = buf.trim_end();
        if l.trim().is_empty() || l.starts_with('#') {
            continue;
        }
        let mut count = 0;
        for (j, field) in l.split(',').enumerate() {
            count += 1;
            if j == 0 {
                table.time.push(parse(field, line, &header[0])?);
            } else if let Some(Some(k)) = slot.get(j) {
                let v = parse(field, line, &header[j])?;
                table.columns[*k].as_mut().expect("a found column").push(v);
            }
        }
        if count != header.len() {
            return Err(format!(
                "line {line}: {count} fields, the header has {}",
                header.len()
            ));
        }
        table.lines.push(line);
    }
    Ok(table)
}

/// Reads and checks a log: every required channel present, time strictly increasing and
/// uniformly sampled, no NaN or infinity, long enough for the smoothing window `m` and the
/// regressions. Rows with a saturated driver or a tripped interlock are excluded with a note.
/// A log with the bench's clock ([`BENCH_SAMPLE_TIME`], strictly increasing) that differs
/// from its schedule is resampled onto a uniform grid of that clock ([`Resampling`]), with a
/// note.
pub fn read(path: &Path, m: usize) -> Result<Log, IdentifyError> {
    let bad = |problem: String| IdentifyError::Log {
        path: path.to_path_buf(),
        problem,
    };
    let mut wanted: Vec<String> = Vec::new();
    for n in REQUIRED.iter().chain(&OPTIONAL) {
        wanted.push(format!("plant.{n}"));
        wanted.push(n.to_string());
    }
    wanted.push(COMMAND.to_string());
    wanted.push(format!("plant.{BENCH_SAMPLE_TIME}"));
    wanted.push(BENCH_SAMPLE_TIME.to_string());
    let table = read_table(path, &wanted).map_err(bad)?;
    let find = |name: &str| -> Option<Vec<f64>> {
        let k = wanted.iter().position(|w| *w == format!("plant.{name}"))?;
        table.columns[k]
            .clone()
            .or_else(|| table.columns[k + 1].clone())
    };
    let missing: Vec<&str> = REQUIRED
        .iter()
        .copied()
        .filter(|n| find(n).is_none())
        .collect();
    if !missing.is_empty() {
        return Err(bad(format!(
            "missing channels: {} (a log of `kneebench experiment` on BenchPlant or BenchHardware has them)",
            missing.join(", ")
        )));
    }
    let mut time = table.time.clone();
    let line = |i: usize| table.lines[i];
    let place = table.place;
    let min_rows = 2 * m + 1 + 200;
    if time.len() < min_rows {
        return Err(bad(format!(
            "too short: {} rows, identification needs at least {min_rows} (the smoothing window of {} samples plus 200)",
            time.len(),
            2 * m + 1
        )));
    }
    for (i, t) in time.iter().enumerate() {
        if !t.is_finite() {
            return Err(bad(format!("{place} {}: time is {t}", line(i))));
        }
        if i > 0 && *t <= time[i - 1] {
            return Err(bad(format!(
                "{place} {}: time {t} does not increase (previous {})",
                line(i),
                time[i - 1]
            )));
        }
    }
    let dt = (time[time.len() - 1] - time[0]) / (time.len() - 1) as f64;
    if let Some(i) = (1..time.len()).find(|&i| ((time[i] - time[i - 1]) - dt).abs() > 1e-6 * dt) {
        return Err(bad(format!(
            "{place} {}: sampling is not uniform (step {} s, the log's mean {dt} s)",
            line(i),
            time[i] - time[i - 1]
        )));
    }
    // A channel's column (if the log has it), refused at the first NaN or infinity.
    let checked =
        |name: &str, column: Option<Vec<f64>>| -> Result<Option<Vec<f64>>, IdentifyError> {
            if let Some(v) = &column
                && let Some(i) = v.iter().position(|x| !x.is_finite())
            {
                return Err(bad(format!("{place} {}: {name} is {}", line(i), v[i])));
            }
            Ok(column)
        };
    let get = |name: &str| checked(name, find(name));
    let req = |name: &str| -> Result<Vec<f64>, IdentifyError> {
        get(name).map(|v| v.expect("required channels were checked"))
    };
    let mut angle = [req(REQUIRED[0])?, req(REQUIRED[1])?];
    let mut current = [req(REQUIRED[2])?, req(REQUIRED[3])?];
    let mut torque = req(REQUIRED[4])?;
    let mut voltage = [get(OPTIONAL[0])?, get(OPTIONAL[1])?];
    let mut load_cell = get(OPTIONAL[5])?;
    let mut current_sense = [get(OPTIONAL[6])?, get(OPTIONAL[7])?];
    let command_column = wanted.iter().position(|w| w == COMMAND);
    let mut command = checked(
        COMMAND,
        command_column.and_then(|k| table.columns[k].clone()),
    )?;
    let bench_time = get(BENCH_SAMPLE_TIME)?;
    let mut n = time.len();
    let mut usable = vec![true; n];
    let mut notes = Vec::new();
    for (flag, what) in [
        (OPTIONAL[2], "test driver saturated"),
        (OPTIONAL[3], "load driver saturated"),
        (OPTIONAL[4], "interlock tripped"),
    ] {
        let Some(v) = get(flag)? else { continue };
        let mut i = 0;
        while i < n {
            if v[i] != 0.0 {
                let start = i;
                while i < n && v[i] != 0.0 {
                    usable[i] = false;
                    i += 1;
                }
                notes.push(format!(
                    "{}: {place}s {}-{} (t = {:.3}-{:.3} s) excluded: {what}",
                    path.display(),
                    line(start),
                    line(i - 1),
                    time[start],
                    time[i - 1]
                ));
            }
            i += 1;
        }
    }
    // On the bench's clock when the log has it and it differs from the schedule.
    if let Some(bench) = &bench_time {
        let plan = Resampling::plan(bench, dt)
            .map_err(|(i, why)| bad(format!("{place} {}: {why}", line(i))))?;
        if !plan.is_identity(n) {
            let on_grid = |v: &mut Vec<f64>| *v = plan.apply(v);
            angle.iter_mut().for_each(on_grid);
            current.iter_mut().for_each(on_grid);
            on_grid(&mut torque);
            voltage.iter_mut().flatten().for_each(on_grid);
            load_cell.iter_mut().for_each(on_grid);
            current_sense.iter_mut().flatten().for_each(on_grid);
            command.iter_mut().for_each(on_grid);
            usable = plan.usable(&usable);
            let (gap, ends) = plan.largest_gap();
            let mut note = format!(
                "{}: resampled onto the bench's clock ({BENCH_SAMPLE_TIME}): {n} rows logged on the schedule, {} rows of {:.3} ms on the clock; the longest gap between samples {:.2} ms ({place} {})",
                path.display(),
                plan.len(),
                dt * 1e3,
                gap * 1e3,
                line(ends)
            );
            if plan.inside_long_gaps() > 0 {
                note.push_str(&format!(
                    "; {} rows inside gaps longer than {MAX_INTERPOLATED_GAP} periods not used",
                    plan.inside_long_gaps()
                ));
            }
            notes.push(note);
            n = plan.len();
            time = (0..n).map(|j| time[0] + j as f64 * dt).collect();
            if n < min_rows {
                return Err(bad(format!(
                    "too short on the bench's clock: {n} rows, identification needs at least {min_rows}"
                )));
            }
        }
    }
    let [_, v1, a1] = derivatives(&angle[0], dt, m);
    let [_, v2, a2] = derivatives(&angle[1], dt, m);
    let [i1, di1, _] = derivatives(&current[0], dt, m);
    let [i2, di2, _] = derivatives(&current[1], dt, m);
    // A row next to an excluded one has excluded samples in its window.
    let mut near = usable.clone();
    for (i, _) in usable.iter().enumerate().filter(|(_, u)| !**u) {
        for flag in near
            .iter_mut()
            .take((i + m + 1).min(n))
            .skip(i.saturating_sub(m))
        {
            *flag = false;
        }
    }
    for (i, u) in near.iter_mut().enumerate() {
        *u &= v1[i].is_finite();
    }
    if near.iter().filter(|u| **u).count() < 200 {
        return Err(bad(
            "fewer than 200 usable rows after excluding saturated and tripped segments".into(),
        ));
    }
    Ok(Log {
        path: path.to_path_buf(),
        dt,
        time,
        angle,
        velocity: [v1, v2],
        acceleration: [a1, a2],
        current,
        current_smooth: [i1, i2],
        current_rate: [di1, di2],
        voltage,
        torque,
        load_cell,
        current_sense,
        command,
        usable: near,
        notes,
    })
}
