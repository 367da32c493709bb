//! Recorded results: one sink interface ([`ResultSink`]) that every writer implements, the
//! in-memory rows ([`Results`]), the streamed CSV writer ([`csv`]), a summary table and plots.
//!
//! The master hands each recorded row to a [`ResultSink`]: time first, then one value per
//! column (`Integer` columns as whole numbers, `Boolean` ones as 0 or 1). [`Results`] keeps the
//! rows in one `Vec<f64>`, [`columns::Columns`] column by column (for data frames);
//! [`csv::CsvWriter`] formats them as they come into a buffered
//! writer; [`csv::CsvFile`] streams them into `<output>.partial` next to the output and renames
//! that file into place when the run is accepted. A columnar writer (Parquet, for example)
//! implements the same trait: [`ResultSink::begin`] gives the schema, [`ResultSink::push_row`]
//! the rows, [`ResultSink::flush`] the points where buffered rows must reach the file.
//!
//! The CSV has the header `time,<names>`; `Real` values are written in the shortest form that
//! parses back to the same bits (the Żmij algorithm: ryu's output, faster), `Integer` and
//! `Boolean` columns as integers (`0`/`1` for booleans).

use std::fmt::Write as _;
use std::io::{self, BufRead, Write};
use std::path::{Path, PathBuf};

/// The type of a recorded column.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ColumnKind {
    /// Real: written as a round-trip float.
    Real,
    /// Integer: written as an integer.
    Integer,
    /// Boolean: written as 0 or 1.
    Boolean,
}

mod background;
mod column_buffer;
pub mod columns;
pub mod csv;
pub mod parquet;
mod parquet_dictionary;
mod parquet_group;
pub mod parquet_read;
mod parquet_sink;

/// Rows for the writers' tests.
#[cfg(test)]
pub(crate) mod test_rows {
    /// Rows whose values cover what a recording holds: NaN, signed zeros, infinities,
    /// subnormals, whole numbers.
    pub(crate) fn row(k: usize, columns: usize) -> (f64, Vec<f64>) {
        let special = [
            f64::NAN,
            -0.0,
            0.0,
            f64::INFINITY,
            f64::NEG_INFINITY,
            5e-324,
        ];
        let values = (0..columns)
            .map(|c| match (k + c) % 7 {
                0 => special[(k / 7 + c) % special.len()],
                1 => (k * c) as f64,
                _ => ((k as f64) * 1e-3 + c as f64).sin() * 1e3,
            })
            .collect();
        (k as f64 * 1e-3, values)
    }
}

/// The error of a bad sample in data row `i` (0-based) of the file `path`: its line when
/// `lines` has it (a CSV), else its 1-based row (a table without lines: Parquet).
fn sample_error(path: &Path, lines: &[usize], i: usize, problem: String) -> ResultsError {
    match lines.get(i) {
        Some(&line) => ResultsError::Csv {
            path: path.to_path_buf(),
            line,
            problem,
        },
        None => ResultsError::Series {
            path: path.to_path_buf(),
            problem: format!("row {}: {problem}", i + 1),
        },
    }
}

/// Whether the file at `path` is Parquet: it begins with Parquet's magic bytes `PAR1`.
fn is_parquet(path: &Path) -> Result<bool, ResultsError> {
    let io_err = |source| ResultsError::Io {
        path: path.to_path_buf(),
        source,
    };
    let mut magic = Vec::with_capacity(4);
    let f = std::fs::File::open(path).map_err(io_err)?;
    io::Read::read_to_end(&mut io::Read::take(f, 4), &mut magic).map_err(io_err)?;
    Ok(magic == b"PAR1")
}

/// Errors of reading, writing and plotting results.
#[derive(Debug, thiserror::Error)]
pub enum ResultsError {
    /// File I/O.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: io::Error,
    },
    /// A malformed CSV file.
    #[error("{}, line {line}: {problem}", path.display())]
    Csv {
        /// The file.
        path: PathBuf,
        /// 1-based line.
        line: usize,
        /// What is wrong.
        problem: String,
    },
    /// A signal name that is not a column.
    #[error("no column named '{0}' (available: {1})")]
    UnknownSignal(String, String),
    /// Drawing failed.
    #[error("plot: {0}")]
    Plot(String),
    /// A time series that cannot be used as one (time not strictly increasing, a value not
    /// finite).
    #[error("{}: {problem}", path.display())]
    Series {
        /// The file.
        path: PathBuf,
        /// What is wrong, with the row and its time.
        problem: String,
    },
    /// The rows in memory could not grow: the allocator refused the room for more rows.
    #[error(
        "out of memory: no room for more than {rows} rows of {columns} columns (time included) \
         in memory; record fewer variables, a shorter run or every n-th row, or write to a file"
    )]
    OutOfMemory {
        /// The rows stored when the allocation failed.
        rows: usize,
        /// The columns of a row, time included.
        columns: usize,
    },
    /// A row whose number of values differs from the number of columns.
    #[error("a row of {got} values for {expected} columns")]
    RowLength {
        /// The number of columns.
        expected: usize,
        /// The number of values given.
        got: usize,
    },
}

/// Where recorded rows go: the one interface of every results writer.
///
/// The master calls [`begin`](Self::begin) once, before the first row, then
/// [`push_row`](Self::push_row) for every recorded row in time order, and
/// [`flush`](Self::flush) at least once per second of wall time when
/// [`wants_periodic_flush`](Self::wants_periodic_flush) says so, and once at the end of every
/// run, whatever its outcome. An error of the sink ends the run (the outcome names it).
pub trait ResultSink {
    /// The columns (time excluded): names and kinds, one each.
    fn begin(&mut self, names: &[String], kinds: &[ColumnKind]) -> Result<(), ResultsError>;
    /// One row: its time and one value per column.
    fn push_row(&mut self, time: f64, values: &[f64]) -> Result<(), ResultsError>;
    /// Makes every row pushed so far durable against a crash of the process (written to the
    /// file, not only buffered).
    fn flush(&mut self) -> Result<(), ResultsError>;
    /// Whether the master should call [`flush`](Self::flush) every second of wall time during
    /// the run (a file does; memory does not).
    fn wants_periodic_flush(&self) -> bool {
        false
    }

    /// Told before the first row how many rows the run will push at most (a hint: the run may
    /// end earlier). A sink may reserve room for them.
    ///
    /// Required, with no default, so that a sink wrapping another cannot drop the hint
    /// unnoticed: `kneebench run`'s output file once did, and its Parquet file then made its
    /// second row-group buffer on the run's thread instead of its writer's.
    fn expect_rows(&mut self, rows: u64);
}

/// A sink that keeps only the [`SignalSummary`] of every column (bounded memory).
///
/// The minima, maxima and last values are kept column by column, so that a row's update is
/// two passes the compiler vectorises (packed min and max, then a copy); the summaries are
/// made when asked for.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RunningSummary {
    names: Vec<String>,
    min: Vec<f64>,
    max: Vec<f64>,
    last: Vec<f64>,
    rows: u64,
}

impl RunningSummary {
    /// An empty summary (the columns come with [`ResultSink::begin`]).
    pub fn new() -> RunningSummary {
        RunningSummary::default()
    }

    /// Min, max and last value of every column so far.
    pub fn summaries(&self) -> Vec<SignalSummary> {
        self.names
            .iter()
            .zip(&self.min)
            .zip(&self.max)
            .zip(&self.last)
            .map(|(((name, &min), &max), &last)| SignalSummary {
                name: name.clone(),
                min,
                max,
                last,
            })
            .collect()
    }

    /// Rows seen.
    pub fn rows(&self) -> u64 {
        self.rows
    }
}

/// Folds `v` into a column's running `min` and `max`: a NaN changes neither (both comparisons
/// are false), and a zero of the other sign than an equal extreme does not replace it. Written
/// as comparisons rather than [`f64::min`] (whose choice between equal zeros is unspecified) so
/// that [`RunningSummary`] and [`Results::summary`] agree bit for bit, and so that a row's
/// update compiles to packed min and max instructions.
#[inline(always)]
fn fold_extremes(min: &mut f64, max: &mut f64, v: f64) {
    // Selects stored unconditionally: a conditional store would keep the loop scalar.
    *min = if v < *min { v } else { *min };
    *max = if v > *max { v } else { *max };
}

impl ResultSink for RunningSummary {
    fn begin(&mut self, names: &[String], _kinds: &[ColumnKind]) -> Result<(), ResultsError> {
        self.names = names.to_vec();
        self.min = vec![f64::INFINITY; names.len()];
        self.max = vec![f64::NEG_INFINITY; names.len()];
        self.last = vec![f64::NAN; names.len()];
        Ok(())
    }

    fn push_row(&mut self, _time: f64, values: &[f64]) -> Result<(), ResultsError> {
        if values.len() != self.names.len() {
            return Err(ResultsError::RowLength {
                expected: self.names.len(),
                got: values.len(),
            });
        }
        for ((min, max), &v) in self.min.iter_mut().zip(&mut self.max).zip(values) {
            fold_extremes(min, max, v);
        }
        self.last.copy_from_slice(values);
        self.rows += 1;
        Ok(())
    }

    fn flush(&mut self) -> Result<(), ResultsError> {
        Ok(())
    }

    /// Nothing to reserve: a summary's memory does not grow with the rows.
    fn expect_rows(&mut self, _rows: u64) {}
}

/// A sink that may be absent: `None` takes every row and keeps nothing (a summary nobody will
/// print, for example), `Some` is the sink itself.
impl<S: ResultSink> ResultSink for Option<S> {
    fn begin(&mut self, names: &[String], kinds: &[ColumnKind]) -> Result<(), ResultsError> {
        self.as_mut().map_or(Ok(()), |s| s.begin(names, kinds))
    }

    #[inline]
    fn push_row(&mut self, time: f64, values: &[f64]) -> Result<(), ResultsError> {
        self.as_mut().map_or(Ok(()), |s| s.push_row(time, values))
    }

    fn flush(&mut self) -> Result<(), ResultsError> {
        self.as_mut().map_or(Ok(()), |s| s.flush())
    }

    fn wants_periodic_flush(&self) -> bool {
        self.as_ref().is_some_and(|s| s.wants_periodic_flush())
    }

    fn expect_rows(&mut self, rows: u64) {
        if let Some(s) = self.as_mut() {
            s.expect_rows(rows);
        }
    }
}

/// Two sinks fed the same rows (a file and a [`RunningSummary`], for example).
#[derive(Debug)]
pub struct Tee<A, B>(pub A, pub B);

impl<A: ResultSink, B: ResultSink> ResultSink for Tee<A, B> {
    fn begin(&mut self, names: &[String], kinds: &[ColumnKind]) -> Result<(), ResultsError> {
        self.0.begin(names, kinds)?;
        self.1.begin(names, kinds)
    }

    #[inline]
    fn push_row(&mut self, time: f64, values: &[f64]) -> Result<(), ResultsError> {
        self.0.push_row(time, values)?;
        self.1.push_row(time, values)
    }

    fn flush(&mut self) -> Result<(), ResultsError> {
        self.0.flush()?;
        self.1.flush()
    }

    fn wants_periodic_flush(&self) -> bool {
        self.0.wants_periodic_flush() || self.1.wants_periodic_flush()
    }

    fn expect_rows(&mut self, rows: u64) {
        self.0.expect_rows(rows);
        self.1.expect_rows(rows);
    }
}

/// Rows reserved up front by [`Results::with_capacity`] at most (the rest grows on demand), so
/// a long run never reserves gigabytes it may not fill.
pub const MAX_RESERVED_ROWS: usize = 1 << 16;

impl ResultSink for Results {
    fn begin(&mut self, names: &[String], kinds: &[ColumnKind]) -> Result<(), ResultsError> {
        if !self.data.is_empty() && (self.names != names || self.kinds != kinds) {
            return Err(ResultsError::RowLength {
                expected: self.names.len(),
                got: names.len(),
            });
        }
        self.names = names.to_vec();
        self.kinds = kinds.to_vec();
        Ok(())
    }

    #[inline]
    fn push_row(&mut self, time: f64, values: &[f64]) -> Result<(), ResultsError> {
        if values.len() != self.names.len() {
            return Err(ResultsError::RowLength {
                expected: self.names.len(),
                got: values.len(),
            });
        }
        let stride = self.stride();
        if self.data.capacity() - self.data.len() < stride {
            self.try_grow(stride)?;
        }
        self.data.push(time);
        self.data.extend_from_slice(values);
        Ok(())
    }

    fn flush(&mut self) -> Result<(), ResultsError> {
        Ok(())
    }

    /// Reserves room for `rows` more rows (at most [`MAX_RESERVED_ROWS`]; more rows grow the
    /// buffer): without it a run's rows grew the buffer by doubling, whose reallocations and
    /// copies cost as much per recorded row as the master's own work on a step.
    fn expect_rows(&mut self, rows: u64) {
        let rows = usize::try_from(rows)
            .unwrap_or(usize::MAX)
            .min(MAX_RESERVED_ROWS);
        self.data.reserve(rows.saturating_mul(self.stride()));
    }
}

/// Recorded rows: time plus one value per named column.
#[derive(Debug, Clone, PartialEq)]
pub struct Results {
    names: Vec<String>,
    kinds: Vec<ColumnKind>,
    data: Vec<f64>,
}

/// Minimum, maximum and final value of one column.
#[derive(Debug, Clone, PartialEq)]
pub struct SignalSummary {
    /// Column name.
    pub name: String,
    /// Minimum (NaN values ignored).
    pub min: f64,
    /// Maximum (NaN values ignored).
    pub max: f64,
    /// Value in the last row.
    pub last: f64,
}

impl Results {
    /// Empty results with the given columns (time excluded) and room for `rows` rows (at most
    /// [`MAX_RESERVED_ROWS`] are reserved; more rows grow the buffer).
    pub fn with_capacity(names: Vec<String>, kinds: Vec<ColumnKind>, rows: usize) -> Results {
        assert_eq!(names.len(), kinds.len());
        let stride = names.len() + 1;
        Results {
            names,
            kinds,
            data: Vec::with_capacity(rows.min(MAX_RESERVED_ROWS).saturating_mul(stride)),
        }
    }

    /// Makes room for `additional` more values (growing the buffer as `reserve` does), or
    /// [`ResultsError::OutOfMemory`] when the allocator refuses it (instead of the abort of an
    /// infallible allocation: a run whose rows do not fit in memory ends with an error).
    fn try_grow(&mut self, additional: usize) -> Result<(), ResultsError> {
        self.data
            .try_reserve(additional)
            .map_err(|_| ResultsError::OutOfMemory {
                rows: self.len(),
                columns: self.stride(),
            })
    }

    /// Starts a new row at time `t` (followed by one value per column: [`push_value`](Self::push_value),
    /// [`push_values`](Self::push_values), [`push_values_from`](Self::push_values_from)).
    #[inline]
    pub fn push_time(&mut self, t: f64) {
        self.data.push(t);
    }

    /// Appends the next value of the current row.
    #[inline]
    pub fn push_value(&mut self, v: f64) {
        self.data.push(v);
    }

    /// Appends the next values of the current row (several columns at once).
    #[inline]
    pub fn push_values(&mut self, values: &[f64]) {
        self.data.extend_from_slice(values);
    }

    /// Appends the next values of the current row from an iterator (several columns at once).
    #[inline]
    pub fn push_values_from(&mut self, values: impl IntoIterator<Item = f64>) {
        self.data.extend(values);
    }

    /// Appends a whole row.
    pub fn push_row(&mut self, t: f64, values: &[f64]) {
        assert_eq!(values.len(), self.names.len());
        self.data.push(t);
        self.data.extend_from_slice(values);
    }

    /// Column names (time excluded).
    pub fn names(&self) -> &[String] {
        &self.names
    }

    /// Column kinds (time excluded).
    pub fn kinds(&self) -> &[ColumnKind] {
        &self.kinds
    }

    fn stride(&self) -> usize {
        self.names.len() + 1
    }

    /// Number of rows.
    pub fn len(&self) -> usize {
        self.data.len() / self.stride()
    }

    /// Whether there is no row.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Row `i`: time first, then the columns.
    pub fn row(&self, i: usize) -> &[f64] {
        let s = self.stride();
        &self.data[i * s..(i + 1) * s]
    }

    /// All rows.
    pub fn rows(&self) -> impl Iterator<Item = &[f64]> {
        self.data.chunks_exact(self.stride())
    }

    /// The time column.
    pub fn times(&self) -> Vec<f64> {
        self.rows().map(|r| r[0]).collect()
    }

    /// The time of the last row.
    pub fn last_time(&self) -> Option<f64> {
        if self.is_empty() {
            None
        } else {
            Some(self.row(self.len() - 1)[0])
        }
    }

    /// A column by name (`"time"` gives the time column).
    pub fn column(&self, name: &str) -> Option<Vec<f64>> {
        let j = self.column_index(name)?;
        Some(self.rows().map(|r| r[j]).collect())
    }

    /// The index of column `name` in a [`row`](Self::row) (0: `time`), to read it in place.
    pub fn column_index(&self, name: &str) -> Option<usize> {
        if name == "time" {
            Some(0)
        } else {
            Some(self.names.iter().position(|n| n == name)? + 1)
        }
    }

    /// Keeps only the named columns, in the given order.
    pub fn select(&self, names: &[&str]) -> Result<Results, ResultsError> {
        let idx: Vec<usize> = names
            .iter()
            .map(|n| {
                self.names.iter().position(|x| x == n).ok_or_else(|| {
                    ResultsError::UnknownSignal(n.to_string(), self.names.join(", "))
                })
            })
            .collect::<Result<_, _>>()?;
        let mut out = Results::with_capacity(
            idx.iter().map(|&i| self.names[i].clone()).collect(),
            idx.iter().map(|&i| self.kinds[i]).collect(),
            self.len(),
        );
        for r in self.rows() {
            out.push_time(r[0]);
            for &i in &idx {
                out.push_value(r[i + 1]);
            }
        }
        Ok(out)
    }

    /// Writes the CSV (header `time,<names>`) through [`csv::CsvWriter`].
    pub fn write_csv(&self, w: impl Write) -> io::Result<()> {
        let mut out = csv::CsvWriter::new(w);
        out.header(&self.names, &self.kinds)?;
        for r in self.rows() {
            out.row(r[0], &r[1..])?;
        }
        out.into_inner().map(drop)
    }

    /// Writes the CSV to a file: streamed into `<path>.partial`, renamed into place when
    /// complete (an earlier file at `path` survives a failed write).
    pub fn write_csv_file(&self, path: impl AsRef<Path>) -> Result<(), ResultsError> {
        let mut file = csv::CsvFile::create(path.as_ref())?;
        file.begin(&self.names, &self.kinds)?;
        for r in self.rows() {
            file.push_row(r[0], &r[1..])?;
        }
        file.commit().map(drop)
    }

    /// Writes the table as Parquet (a float64 column per signal after `time`, `metadata` as the
    /// file's key-value metadata): streamed into `<path>.partial`, renamed into place when
    /// complete. [`parquet_read::read_parquet`] reads it back bit for bit.
    pub fn write_parquet_file(
        &self,
        path: impl AsRef<Path>,
        metadata: Vec<(String, String)>,
    ) -> Result<(), ResultsError> {
        let mut file = parquet::ParquetFile::create(path.as_ref())?;
        file.set_metadata(metadata);
        file.begin(&self.names, &self.kinds)?;
        for r in self.rows() {
            file.push_row(r[0], &r[1..])?;
        }
        file.commit().map(drop)
    }

    /// Reads a results file, Parquet or CSV by its content (a Parquet file begins with its
    /// magic bytes `PAR1`, whatever its name): [`parquet_read::read_parquet`] or
    /// [`read_csv_file`](Self::read_csv_file). What `kneebench run --output` writes, in
    /// either format, reads back here.
    pub fn read_file(path: impl AsRef<Path>) -> Result<Results, ResultsError> {
        Results::read_file_lines(path).map(|(results, _)| results)
    }

    /// Reads a CSV with a header whose first column is time (any name). Every value is read as
    /// a float; columns whose values are all integers are marked [`ColumnKind::Integer`].
    pub fn read_csv_file(path: impl AsRef<Path>) -> Result<Results, ResultsError> {
        Results::read_csv_file_lines(path).map(|(results, _)| results)
    }

    /// [`read_file`](Self::read_file), with the 1-based line of each data row of a CSV
    /// ([`read_csv_file_lines`](Self::read_csv_file_lines)); none for Parquet, whose errors
    /// name rows.
    pub fn read_file_lines(path: impl AsRef<Path>) -> Result<(Results, Vec<usize>), ResultsError> {
        let path = path.as_ref();
        if is_parquet(path)? {
            Ok((parquet_read::read_parquet(path, None)?, Vec::new()))
        } else {
            Results::read_csv_file_lines(path)
        }
    }

    /// [`read_csv_file`](Self::read_csv_file), with the 1-based line of the file that each
    /// data row was read from (comments, blank lines and the header are not rows), for errors
    /// that name where a bad sample is ([`check_rows`](Self::check_rows)).
    pub fn read_csv_file_lines(
        path: impl AsRef<Path>,
    ) -> Result<(Results, Vec<usize>), ResultsError> {
        let path = path.as_ref();
        let f = std::fs::File::open(path).map_err(|source| ResultsError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Results::read_csv_lines(io::BufReader::new(f), path)
    }

    /// Reads a CSV from a reader (`path` is used in error messages).
    pub fn read_csv(r: impl BufRead, path: &Path) -> Result<Results, ResultsError> {
        Results::read_csv_lines(r, path).map(|(results, _)| results)
    }

    /// [`read_csv`](Self::read_csv), with the 1-based line of each data row.
    pub fn read_csv_lines(
        r: impl BufRead,
        path: &Path,
    ) -> Result<(Results, Vec<usize>), ResultsError> {
        let csv_err = |line: usize, problem: String| ResultsError::Csv {
            path: path.to_path_buf(),
            line,
            problem,
        };
        let mut lines = r.lines().enumerate();
        let header = loop {
            match lines.next() {
                None => return Err(csv_err(1, "empty file".into())),
                Some((i, l)) => {
                    let l = l.map_err(|e| csv_err(i + 1, e.to_string()))?;
                    if !l.trim().is_empty() && !l.starts_with('#') {
                        break l;
                    }
                }
            }
        };
        let cols: Vec<String> = split_csv(&header)
            .into_iter()
            .map(|s| s.trim().to_string())
            .collect();
        if cols.is_empty() {
            return Err(csv_err(1, "no columns".into()));
        }
        let names = cols[1..].to_vec();
        let mut res =
            Results::with_capacity(names.clone(), vec![ColumnKind::Real; names.len()], 1024);
        let mut integral = vec![true; names.len()];
        let mut row_lines = Vec::new();
        for (i, l) in lines {
            let l = l.map_err(|e| csv_err(i + 1, e.to_string()))?;
            if l.trim().is_empty() || l.starts_with('#') {
                continue;
            }
            row_lines.push(i + 1);
            let fields = split_csv(&l);
            if fields.len() != cols.len() {
                return Err(csv_err(
                    i + 1,
                    format!("{} fields, the header has {}", fields.len(), cols.len()),
                ));
            }
            for (j, f) in fields.iter().enumerate() {
                let f = f.trim();
                let v: f64 = match f {
                    "true" | "True" => 1.0,
                    "false" | "False" => 0.0,
                    _ => f
                        .parse()
                        .map_err(|_| csv_err(i + 1, format!("'{f}' is not a number")))?,
                };
                if j > 0 && (f.contains(['.', 'e', 'E']) || f.parse::<i64>().is_err()) {
                    integral[j - 1] = false;
                }
                res.data.push(v);
            }
        }
        for (k, int) in res.kinds.iter_mut().zip(integral) {
            if int {
                *k = ColumnKind::Integer;
            }
        }
        Ok((res, row_lines))
    }

    /// Checks rows read from the file `path` ([`read_csv_file_lines`](Self::read_csv_file_lines)
    /// gives `lines`; [`read_file_lines`](Self::read_file_lines) none for Parquet): every time
    /// finite and strictly increasing, and, in the rows whose indices `rows` holds, the
    /// columns `names` finite. The error names the file and the line of the first bad sample
    /// (its row, in a file without lines).
    pub fn check_rows(
        &self,
        path: &Path,
        lines: &[usize],
        names: &[&str],
        rows: &[usize],
    ) -> Result<(), ResultsError> {
        self.check_times(path, lines)?;
        self.check_values(path, lines, names, rows)
    }

    /// The time part of [`check_rows`](Self::check_rows): every time finite and strictly
    /// increasing.
    pub fn check_times(&self, path: &Path, lines: &[usize]) -> Result<(), ResultsError> {
        let err = |i: usize, problem: String| sample_error(path, lines, i, problem);
        let mut previous: Option<f64> = None;
        for (i, r) in self.rows().enumerate() {
            let t = r[0];
            if !t.is_finite() {
                return Err(err(i, format!("the time {t} is not finite")));
            }
            if let Some(p) = previous
                && t <= p
            {
                return Err(err(
                    i,
                    format!("the time {t} is not after the previous row's {p}"),
                ));
            }
            previous = Some(t);
        }
        Ok(())
    }

    /// The value part of [`check_rows`](Self::check_rows): in the rows whose indices `rows`
    /// holds, the columns `names` finite.
    pub fn check_values(
        &self,
        path: &Path,
        lines: &[usize],
        names: &[&str],
        rows: &[usize],
    ) -> Result<(), ResultsError> {
        let err = |i: usize, problem: String| sample_error(path, lines, i, problem);
        let columns: Vec<(&str, usize)> = names
            .iter()
            .map(|&n| {
                let j = if n == "time" {
                    Some(0)
                } else {
                    self.names.iter().position(|c| c == n).map(|j| j + 1)
                };
                j.map(|j| (n, j)).ok_or_else(|| {
                    ResultsError::UnknownSignal(n.to_string(), self.names.join(", "))
                })
            })
            .collect::<Result<_, _>>()?;
        for &i in rows {
            if i >= self.len() {
                continue;
            }
            let r = self.row(i);
            if let Some((name, j)) = columns.iter().find(|(_, j)| !r[*j].is_finite()) {
                return Err(err(
                    i,
                    format!("{name} = {} is not finite (t = {})", r[*j], r[0]),
                ));
            }
        }
        Ok(())
    }

    /// Checks that the rows form a usable time series, as `kneebench run --inputs` needs: at
    /// least one row, every time and value finite, time strictly increasing. `path` names the
    /// source in the error ([`check_rows`](Self::check_rows) checks chosen columns and rows,
    /// naming the line).
    pub fn check_series(&self, path: &Path) -> Result<(), ResultsError> {
        let err = |problem: String| ResultsError::Series {
            path: path.to_path_buf(),
            problem,
        };
        if self.is_empty() {
            return Err(err("no data rows".into()));
        }
        let mut previous = f64::NEG_INFINITY;
        for (i, r) in self.rows().enumerate() {
            let t = r[0];
            if !t.is_finite() {
                return Err(err(format!("data row {}: time {t} is not finite", i + 1)));
            }
            if let Some(j) = r[1..].iter().position(|v| !v.is_finite()) {
                return Err(err(format!(
                    "data row {} (t = {t}): {} = {} is not finite",
                    i + 1,
                    self.names[j],
                    r[j + 1]
                )));
            }
            if t <= previous {
                return Err(err(format!(
                    "data row {} (t = {t}): time is not strictly increasing (previous row: t = {previous})",
                    i + 1
                )));
            }
            previous = t;
        }
        Ok(())
    }

    /// Minimum, maximum and final value of every column.
    pub fn summary(&self) -> Vec<SignalSummary> {
        (0..self.names.len())
            .map(|j| {
                let mut min = f64::INFINITY;
                let mut max = f64::NEG_INFINITY;
                let mut last = f64::NAN;
                for r in self.rows() {
                    let v = r[j + 1];
                    fold_extremes(&mut min, &mut max, v);
                    last = v;
                }
                SignalSummary {
                    name: self.names[j].clone(),
                    min,
                    max,
                    last,
                }
            })
            .collect()
    }

    /// The summary as an aligned text table.
    pub fn summary_table(&self) -> String {
        summary_table(&self.summary())
    }
}

/// Summaries as an aligned text table: signal, min, max, final.
pub fn summary_table(s: &[SignalSummary]) -> String {
    let w = s
        .iter()
        .map(|x| x.name.len())
        .chain(std::iter::once(6))
        .max()
        .unwrap_or(6);
    let mut out = format!(
        "{:<w$}  {:>14}  {:>14}  {:>14}\n",
        "signal", "min", "max", "final"
    );
    for x in s {
        let _ = writeln!(
            out,
            "{:<w$}  {:>14}  {:>14}  {:>14}",
            x.name,
            fmt_num(x.min),
            fmt_num(x.max),
            fmt_num(x.last)
        );
    }
    out
}

fn fmt_num(v: f64) -> String {
    if v.is_infinite() || v.is_nan() {
        format!("{v}")
    } else if v != 0.0 && (v.abs() >= 1e6 || v.abs() < 1e-4) {
        format!("{v:.6e}")
    } else {
        format!("{v:.6}")
    }
}

fn split_csv(line: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut cur = String::new();
    let mut quoted = false;
    let mut chars = line.trim_end_matches('\r').chars().peekable();
    while let Some(c) = chars.next() {
        match (c, quoted) {
            ('"', true) if chars.peek() == Some(&'"') => {
                cur.push('"');
                chars.next();
            }
            ('"', _) => quoted = !quoted,
            (',', false) => out.push(std::mem::take(&mut cur)),
            _ => cur.push(c),
        }
    }
    out.push(cur);
    out
}

pub mod plot;

#[cfg(test)]
mod tests {
    use super::*;

    /// The running summary (what `kneebench run` prints) is the in-memory one bit for bit, and
    /// both are the extremes of the non-NaN values and the last value, whatever the values:
    /// NaN, signed zeros, infinities, subnormals, and a column that is only NaN.
    #[test]
    fn the_running_summary_is_the_summary_of_the_rows() {
        let columns = 9;
        let names: Vec<String> = (0..=columns).map(|c| format!("c{c}")).collect();
        let kinds = vec![ColumnKind::Real; names.len()];
        let mut running = RunningSummary::new();
        let mut all = Results::with_capacity(Vec::new(), Vec::new(), 0);
        running.begin(&names, &kinds).unwrap();
        ResultSink::begin(&mut all, &names, &kinds).unwrap();
        for k in 0..60 {
            let (t, mut values) = test_rows::row(k, columns);
            values.push(f64::NAN);
            running.push_row(t, &values).unwrap();
            ResultSink::push_row(&mut all, t, &values).unwrap();
        }
        let bits = |s: &SignalSummary| (s.min.to_bits(), s.max.to_bits(), s.last.to_bits());
        let from_rows = all.summary();
        let kept = running.summaries();
        assert_eq!(running.rows(), 60);
        assert_eq!(kept.len(), names.len());
        for (j, (a, b)) in kept.iter().zip(&from_rows).enumerate() {
            assert_eq!(a.name, b.name);
            assert_eq!(bits(a), bits(b), "column {j}");
            let mut finite: Vec<f64> = all
                .rows()
                .map(|r| r[j + 1])
                .filter(|v| !v.is_nan())
                .collect();
            finite.sort_by(f64::total_cmp);
            let last = all.rows().last().unwrap()[j + 1];
            assert_eq!(a.last.to_bits(), last.to_bits(), "column {j}");
            match (finite.first(), finite.last()) {
                (Some(&lo), Some(&hi)) => assert!(a.min == lo && a.max == hi, "column {j}"),
                _ => assert!(a.min == f64::INFINITY && a.max == f64::NEG_INFINITY),
            }
        }
        assert!(
            running
                .push_row(0.0, &[0.0])
                .is_err_and(|e| matches!(e, ResultsError::RowLength { .. }))
        );
    }

    /// `read_file` reads Parquet by its magic bytes whatever the file's name, CSV otherwise:
    /// the same rows from both formats.
    #[test]
    fn read_file_tells_parquet_from_csv_by_content() {
        let dir = tempfile::tempdir().unwrap();
        let names = vec!["x".to_string(), "flag".to_string()];
        let kinds = vec![ColumnKind::Real, ColumnKind::Real];
        let mut r = Results::with_capacity(Vec::new(), Vec::new(), 0);
        ResultSink::begin(&mut r, &names, &kinds).unwrap();
        for k in 0..20 {
            r.push_row(k as f64 * 0.5, &[(k as f64).sin(), f64::from(k > 9)]);
        }
        let (csv, parquet) = (dir.path().join("r.csv"), dir.path().join("r.dat"));
        r.write_csv_file(&csv).unwrap();
        r.write_parquet_file(dir.path().join("r.parquet"), Vec::new())
            .unwrap();
        std::fs::rename(dir.path().join("r.parquet"), &parquet).unwrap();
        let (a, b) = (
            Results::read_file(&csv).unwrap(),
            Results::read_file(&parquet).unwrap(),
        );
        assert_eq!(a.names(), b.names());
        assert_eq!(a.times(), b.times());
        for n in &names {
            assert_eq!(a.column(n), b.column(n), "{n}");
        }
        let e = Results::read_file(dir.path().join("none.csv")).unwrap_err();
        assert!(e.to_string().contains("none.csv"), "{e}");
    }

    /// The rows a run announces are stored without growing the buffer (the buffer is never
    /// moved), and the reservation is capped.
    #[test]
    fn expected_rows_are_stored_without_reallocating() {
        let names = vec!["a".to_string(), "b".to_string()];
        let kinds = vec![ColumnKind::Real, ColumnKind::Boolean];
        let mut r = Results::with_capacity(Vec::new(), Vec::new(), 0);
        r.begin(&names, &kinds).unwrap();
        r.expect_rows(1000);
        assert!(r.data.capacity() >= 1000 * 3, "{}", r.data.capacity());
        let start = r.data.as_ptr();
        for i in 0..1000 {
            ResultSink::push_row(&mut r, i as f64, &[1.0, 0.0]).unwrap();
        }
        assert_eq!(r.data.as_ptr(), start, "the buffer was reallocated");
        assert_eq!(r.len(), 1000);
        let mut big = Results::with_capacity(Vec::new(), Vec::new(), 0);
        big.begin(&names, &kinds).unwrap();
        big.expect_rows(u64::MAX);
        assert!(big.data.capacity() < 2 * MAX_RESERVED_ROWS * 3);
    }

    /// Room the allocator refuses is an error naming the rows and columns, not an abort, and
    /// the rows stored so far stay.
    #[test]
    fn refused_room_is_an_out_of_memory_error() {
        let names = vec!["a".to_string(), "b".to_string()];
        let kinds = vec![ColumnKind::Real, ColumnKind::Real];
        let mut r = Results::with_capacity(Vec::new(), Vec::new(), 0);
        r.begin(&names, &kinds).unwrap();
        ResultSink::push_row(&mut r, 0.0, &[1.0, 2.0]).unwrap();
        let e = r.try_grow(usize::MAX / 2).unwrap_err();
        assert!(
            matches!(
                e,
                ResultsError::OutOfMemory {
                    rows: 1,
                    columns: 3
                }
            ),
            "{e:?}"
        );
        assert!(e.to_string().contains("1 rows of 3 columns"), "{e}");
        assert_eq!(r.len(), 1);
        r.try_grow(3).unwrap();
        ResultSink::push_row(&mut r, 1.0, &[3.0, 4.0]).unwrap();
        assert_eq!(r.column("b"), Some(vec![2.0, 4.0]));
    }
}
