//! The journal of a sweep or an optimisation, and `--resume`.
//!
//! Every finished row is appended to `<output>.journal` (first line: the sweep's
//! [`fingerprint`](super::runner::fingerprint): the version, the spec text but for an
//! optimisation's `generations`, every point's bits, the FMUs' GUIDs, the digests of the
//! system's files; then one line per row, floats as their 64-bit patterns in hex) and flushed. A resumed
//! sweep reads the journal, refuses it if the fingerprint differs, skips the points it holds
//! and runs the rest; a torn last line (the process was killed while writing it) is ignored.
//! The journal is removed once the table is written. `--resume` with no journal continues a
//! finished Parquet table of the same sweep (its fingerprint is in the table's metadata): an
//! optimisation given more generations runs only the new ones.
//!
//! **One sweep per output at a time.** A sweep holds an exclusive lock (`flock`, through
//! [`std::fs::File::try_lock`]) on its journal from before it reads it until it is removed, so
//! that a second sweep into the same output (a CLI and a Python one, two Python ones: with
//! `--resume` each would otherwise take the journal's rows as done and both run every other
//! point) is refused at once ([`SweepError::Busy`]) instead of doubling the work and
//! interleaving the journal. The kernel releases the lock when the process ends, however it
//! ends (a kill included), so a later `--resume` is never blocked by a dead sweep.

use std::collections::BTreeMap;
use std::io::{Read, Seek, SeekFrom, Write};
use std::os::unix::fs::MetadataExt;
use std::path::{Path, PathBuf};

use super::SweepError;
use super::runner::{Prepared, SweepOptions};
use super::table::{Row, RunStatus, SweepTable};

/// `<output>.journal`.
pub fn journal_path(output: &Path) -> PathBuf {
    let mut name = output
        .file_name()
        .map(|n| n.to_os_string())
        .unwrap_or_default();
    name.push(".journal");
    output.with_file_name(name)
}

/// The first words of a journal's first line (its format and version).
pub(crate) const JOURNAL_MAGIC: &str = "kneebench-sweep-journal 1";

fn escape(s: &str) -> String {
    s.replace('\\', "\\\\")
        .replace('\t', "\\t")
        .replace('\n', "\\n")
        .replace('\r', "\\r")
}

fn unescape(s: &str) -> String {
    let mut out = String::new();
    let mut it = s.chars();
    while let Some(c) = it.next() {
        if c == '\\' {
            match it.next() {
                Some('t') => out.push('\t'),
                Some('n') => out.push('\n'),
                Some('r') => out.push('\r'),
                Some(o) => out.push(o),
                None => {}
            }
        } else {
            out.push(c);
        }
    }
    out
}

/// One journal line: a finished row (see the module documentation).
pub fn journal_line(row: &Row) -> String {
    let hex = |v: &[f64]| {
        v.iter()
            .map(|x| format!("{:016x}", x.to_bits()))
            .collect::<Vec<_>>()
            .join(",")
    };
    format!(
        "{}\t{}\t{}\t{}\n",
        row.point,
        row.status.name(),
        hex(&row.metrics),
        escape(&row.message)
    )
}

/// A float written by [`journal_line`]: exactly 16 hex digits (its 64-bit pattern). Anything
/// else (`3ff`, a sign, a `0x`) is not a journal's value: `u64::from_str_radix` alone took
/// `3ff` as the bits 0x3ff, a denormal 5e-321 read back as the metric.
fn parse_bits(h: &str) -> Option<f64> {
    if h.len() != 16 || !h.bytes().all(|b| b.is_ascii_hexdigit()) {
        return None;
    }
    u64::from_str_radix(h, 16).ok().map(f64::from_bits)
}

/// A journal line's row, its parameters left empty (the caller knows them from the point's
/// id); `None` if the line is not a row with `metrics` metrics.
fn parse_journal_line(line: &str, metrics: usize) -> Option<Row> {
    let mut parts = line.splitn(4, '\t');
    let point: u64 = parts.next()?.parse().ok()?;
    let status = RunStatus::from_name(parts.next()?)?;
    let metrics_text = parts.next()?;
    let message = unescape(parts.next()?);
    let values: Vec<f64> = if metrics_text.is_empty() {
        Vec::new()
    } else {
        metrics_text
            .split(',')
            .map(parse_bits)
            .collect::<Option<_>>()?
    };
    if values.len() != metrics {
        return None;
    }
    Some(Row {
        point,
        parameters: Vec::new(),
        metrics: values,
        status,
        message,
    })
}

/// The rows of the finished table at `output`, to continue it (an optimisation given more
/// generations; a sweep whose table is complete runs nothing). Only a Parquet table can be
/// continued: it carries the sweep's fingerprint in its metadata, and it must be this one's
/// (the same spec but for an optimisation's `generations`, the same points, the same FMUs).
/// Its names must be this sweep's, and every point's id accepted by `known` (an optimisation
/// asked for fewer generations than the table holds is refused). A CSV table carries no
/// fingerprint and is refused.
fn finished_rows(
    output: &Path,
    prepared: &Prepared,
    known: &dyn Fn(u64) -> bool,
) -> Result<BTreeMap<u64, Row>, SweepError> {
    let bad = |message: String| SweepError::Table {
        path: output.to_path_buf(),
        message,
    };
    let parquet = output
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("parquet"));
    if !parquet {
        return Err(bad(
            "--resume found a finished table and no journal; a CSV table carries no fingerprint \
             to check it against this spec, so it cannot be continued: leave out --resume to run \
             afresh, or write Parquet (--output *.parquet) to be able to continue"
                .into(),
        ));
    }
    let table = SweepTable::read_parquet(output, prepared.design.names.len())?;
    let theirs = table
        .metadata
        .iter()
        .find(|(k, _)| k == "kneebench.sweep.fingerprint")
        .map(|(_, v)| v.as_str());
    match theirs {
        None => {
            return Err(bad(
                "the finished table has no kneebench.sweep.fingerprint in its metadata (not \
                 written by kneebench sweep or optimize), so it cannot be continued: leave out \
                 --resume to run afresh"
                    .into(),
            ));
        }
        Some(f) if f != prepared.fingerprint => {
            return Err(bad(
                "the finished table belongs to another sweep (the spec but for an \
                 optimisation's generations, its points, the system file or the FMUs changed, \
                 or another kneebench wrote it): leave out --resume to run afresh"
                    .into(),
            ));
        }
        Some(_) => {}
    }
    if table.parameter_names != prepared.design.names || table.metric_names != prepared.metric_names
    {
        return Err(bad(
            "the finished table's columns are not this sweep's".into()
        ));
    }
    let mut rows = BTreeMap::new();
    for row in table.rows {
        if !known(row.point) {
            return Err(bad(format!(
                "point {} of the finished table is beyond this sweep (an optimisation can be \
                 continued with more generations, not fewer)",
                row.point
            )));
        }
        rows.insert(row.point, row);
    }
    Ok(rows)
}

/// The journal at `path` opened for reading and writing (created if there is none) and locked
/// for this sweep alone, and whether it was there before (an empty file counts as none: a
/// journal always has its header, so an empty one is a sweep's that had only just created it).
/// A journal locked by another sweep, in this process or another, is refused
/// ([`SweepError::Busy`]). The lock is taken on the file the path names when it is held: a
/// journal removed (its sweep finished) or replaced between the opening and the locking is
/// opened again.
fn lock(path: &Path) -> Result<(std::fs::File, bool), SweepError> {
    let io = |source| SweepError::Io {
        path: path.to_path_buf(),
        source,
    };
    loop {
        let file = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .open(path)
            .map_err(io)?;
        match file.try_lock() {
            Ok(()) => {}
            Err(std::fs::TryLockError::WouldBlock) => {
                return Err(SweepError::Busy {
                    path: path.to_path_buf(),
                });
            }
            Err(std::fs::TryLockError::Error(source)) => return Err(io(source)),
        }
        let held = file.metadata().map_err(io)?;
        match std::fs::metadata(path) {
            Ok(named) if named.dev() == held.dev() && named.ino() == held.ino() => {
                return Ok((file, held.len() > 0));
            }
            Ok(_) => continue,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => continue,
            Err(e) => return Err(io(e)),
        }
    }
}

/// The journal of a sweep or an optimisation written to `output`: `<output>.journal`, one line
/// per finished row after the fingerprint (see the module documentation).
pub(crate) struct Journal {
    path: PathBuf,
    file: std::fs::File,
}

impl Journal {
    /// Starts the journal of `prepared` for `output`. An existing journal is refused without
    /// `resume` (one without a complete row, from a sweep that ended before its first row, is
    /// taken as none); with it, its rows are returned (their parameters empty, each id accepted by
    /// `known`, else the line is refused) and the journal is rewritten with the complete rows
    /// only (a torn last line, from a kill while it was written, is dropped: that point runs
    /// again). A journal of another fingerprint is refused. With `resume` and no journal, a
    /// finished table at `output` is continued: its rows are returned ([`finished_rows`]) and
    /// journaled. The journal is locked for this sweep alone first: one that another sweep
    /// holds is refused ([`SweepError::Busy`]; see the module documentation).
    pub(crate) fn open(
        output: &Path,
        resume: bool,
        prepared: &Prepared,
        known: &dyn Fn(u64) -> bool,
    ) -> Result<(Journal, BTreeMap<u64, Row>), SweepError> {
        let path = journal_path(output);
        let (mut file, existed) = lock(&path)?;
        match Journal::fill(&mut file, existed, output, resume, prepared, known) {
            Ok(rows) => Ok((Journal { path, file }, rows)),
            Err(e) => {
                // A journal this call created (it found none) goes with the refusal.
                if !existed {
                    let _ = std::fs::remove_file(&path);
                }
                Err(e)
            }
        }
    }

    /// [`open`](Self::open)'s work once the journal is locked: its rows (or a finished
    /// table's), written back to it after the header.
    fn fill(
        file: &mut std::fs::File,
        existed: bool,
        output: &Path,
        resume: bool,
        prepared: &Prepared,
        known: &dyn Fn(u64) -> bool,
    ) -> Result<BTreeMap<u64, Row>, SweepError> {
        let path = journal_path(output);
        let bad = |message: String| SweepError::Journal {
            path: path.clone(),
            message,
        };
        let io = |source| SweepError::Io {
            path: path.clone(),
            source,
        };
        let header = prepared.journal_header();
        let mut rows = BTreeMap::new();
        let mut text = String::new();
        if existed {
            file.read_to_string(&mut text).map_err(io)?;
        }
        // A journal without a complete row (a sweep that failed or was killed before its
        // first row ended) holds nothing to resume: it is taken as none, so that it does not
        // block the next run (which had to be told --resume, or to remove it, for nothing).
        let holds_rows = text
            .split_inclusive('\n')
            .skip(1)
            .any(|l| l.ends_with('\n'));
        if existed && holds_rows {
            if !resume {
                return Err(bad(
                    "an unfinished sweep's journal exists: pass --resume (resume=True in \
                     Python) to continue it, or remove it"
                        .into(),
                ));
            }
            let mut lines = text.split_inclusive('\n');
            if lines.next().unwrap_or("").trim_end() != header.trim_end() {
                return Err(bad(
                    "belongs to another sweep (the spec, its points, the system file or the \
                     FMUs changed, or another kneebench wrote it); remove it to start afresh"
                        .into(),
                ));
            }
            for (i, line) in lines.enumerate() {
                let Some(line) = line.strip_suffix('\n') else {
                    break;
                };
                let row = parse_journal_line(line, prepared.metric_names.len())
                    .ok_or_else(|| bad(format!("line {} is not a row of this sweep", i + 2)))?;
                if !known(row.point) {
                    return Err(bad(format!(
                        "line {}: point {} is beyond this sweep (an optimisation can be \
                         continued with more generations, not fewer)",
                        i + 2,
                        row.point
                    )));
                }
                rows.insert(row.point, row);
            }
        } else if resume && output.exists() {
            rows = finished_rows(output, prepared, known)?;
        }
        text = header;
        for r in rows.values() {
            text.push_str(&journal_line(r));
        }
        // Rewritten in place, through the locked file (a new file would not be locked).
        file.set_len(0).map_err(io)?;
        file.seek(SeekFrom::Start(0)).map_err(io)?;
        file.write_all(text.as_bytes()).map_err(io)?;
        Ok(rows)
    }

    /// Appends a finished row.
    pub(crate) fn record(&mut self, row: &Row) -> Result<(), SweepError> {
        self.file
            .write_all(journal_line(row).as_bytes())
            .map_err(|source| SweepError::Io {
                path: self.path.clone(),
                source,
            })
    }

    /// Removes the journal (its table is written), then lets its lock go: a sweep that opened
    /// it meanwhile finds it gone once it holds the lock, and starts afresh ([`lock`]).
    pub(crate) fn remove(self) -> Result<(), SweepError> {
        let removed = std::fs::remove_file(&self.path).map_err(|source| SweepError::Io {
            path: self.path,
            source,
        });
        drop(self.file);
        removed
    }
}

/// A progress bar of `total` runs on stderr, at `done` already, if `show`.
pub(crate) fn progress_bar(show: bool, total: u64, done: u64) -> Option<indicatif::ProgressBar> {
    if !show {
        return None;
    }
    let pb = indicatif::ProgressBar::new(total);
    pb.set_draw_target(indicatif::ProgressDrawTarget::stderr());
    if let Ok(style) = indicatif::ProgressStyle::with_template(
        "{elapsed_precise} [{bar:40}] {pos}/{len} runs ({eta} left)",
    ) {
        pb.set_style(style.progress_chars("=> "));
    }
    pb.set_position(done);
    Some(pb)
}

/// The finished rows of a sweep or an optimisation, kept as they come: journaled (when the
/// table goes to a file) and counted on the progress bar.
pub(crate) struct Finished {
    /// The rows so far, by point id (a resumed journal's first, their parameters empty).
    pub(crate) rows: BTreeMap<u64, Row>,
    journal: Option<Journal>,
    bar: Option<indicatif::ProgressBar>,
}

impl Finished {
    /// Starts the rows of `total` runs of `prepared`: with `output`, its journal (see
    /// [`Journal::open`]: ids accepted by `known`), and a progress bar if the options ask.
    pub(crate) fn start(
        prepared: &Prepared,
        output: Option<&Path>,
        options: &SweepOptions,
        total: u64,
        known: &dyn Fn(u64) -> bool,
    ) -> Result<Finished, SweepError> {
        let (journal, rows) = match output {
            Some(out) => {
                prepared.check_output(out)?;
                super::table::check_table_path(out)?;
                let (j, rows) = Journal::open(out, options.resume, prepared, known)?;
                (Some(j), rows)
            }
            None => (None, BTreeMap::new()),
        };
        let bar = progress_bar(options.progress, total, rows.len() as u64);
        Ok(Finished { rows, journal, bar })
    }

    /// Keeps a finished row: journaled first, so that a kill after this loses nothing.
    /// A second row for a point is not journaled again: it is ignored when it equals the
    /// first bit for bit (its metrics, status and message), and refused otherwise.
    pub(crate) fn record(&mut self, row: Row) -> Result<(), SweepError> {
        if let Some(first) = self.rows.get(&row.point) {
            return if row.same_outcome(first) {
                Ok(())
            } else {
                Err(SweepError::System(format!(
                    "point {}: a second row that differs from the first",
                    row.point
                )))
            };
        }
        if let Some(j) = &mut self.journal {
            j.record(&row)?;
        }
        if let Some(pb) = &self.bar {
            pb.inc(1);
        }
        self.rows.insert(row.point, row);
        Ok(())
    }

    /// Ends the run: `table` written to `output` (if given) and then the journal removed.
    pub(crate) fn end(self, table: &SweepTable, output: Option<&Path>) -> Result<(), SweepError> {
        if let Some(pb) = self.bar {
            pb.finish_and_clear();
        }
        if let Some(out) = output {
            table.write(out)?;
        }
        match self.journal {
            Some(j) => j.remove(),
            None => Ok(()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A journal row's metrics are 16 hex digits each, as `journal_line` writes them; a
    /// shorter or longer field, a sign or a `0x` is not a row (was: `3ff` read as 5e-321).
    #[test]
    fn journal_metrics_must_be_sixteen_hex_digits() {
        let row = Row {
            point: 3,
            parameters: Vec::new(),
            metrics: vec![1.0, f64::NAN, -0.0],
            status: RunStatus::Tripped,
            message: "a\tb\nc".into(),
        };
        let line = journal_line(&row);
        let back = parse_journal_line(line.trim_end_matches('\n'), 3).unwrap();
        assert!(back.same_outcome(&row), "{back:?}");
        for bad in [
            "3ff",
            "+3ff0000000000000",
            "0x3ff00000000000",
            "3ff00000000000000",
            "",
        ] {
            assert!(
                parse_journal_line(&format!("0\tok\t{bad}\t"), 1).is_none(),
                "{bad} accepted"
            );
        }
        assert_eq!(
            parse_journal_line("0\tok\t3FF0000000000000\t", 1)
                .unwrap()
                .metrics,
            [1.0]
        );
    }
}
