//! Recorded results: a buffer of rows, CSV output, a summary table and plots.
//!
//! Rows are buffered in one `Vec<f64>` (time first, then one value per column) and written at
//! the end of a run, never per step. The CSV has the header `time,<names>`; `Real` values are
//! written with Rust's shortest round-trip formatting (`{:?}`: parsing the text gives back the
//! same bits), `Integer` and `Boolean` columns as integers (`0`/`1` for booleans).

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
    /// Empty results with the given columns (time excluded) and room for `rows` rows.
    pub fn with_capacity(names: Vec<String>, kinds: Vec<ColumnKind>, rows: usize) -> Results {
        assert_eq!(names.len(), kinds.len());
        let stride = names.len() + 1;
        Results {
            names,
            kinds,
            data: Vec::with_capacity(rows.saturating_mul(stride)),
        }
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
        let j = if name == "time" {
            0
        } else {
            self.names.iter().position(|n| n == name)? + 1
        };
        Some(self.rows().map(|r| r[j]).collect())
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

    /// Writes the CSV (header `time,<names>`).
    pub fn write_csv(&self, mut w: impl Write) -> io::Result<()> {
        let mut line = String::with_capacity(32 * self.stride());
        line.push_str("time");
        for n in &self.names {
            line.push(',');
            line.push_str(&csv_field(n));
        }
        line.push('\n');
        w.write_all(line.as_bytes())?;
        for r in self.rows() {
            line.clear();
            let _ = write!(line, "{:?}", r[0]);
            for (v, k) in r[1..].iter().zip(&self.kinds) {
                line.push(',');
                match k {
                    ColumnKind::Real => {
                        let _ = write!(line, "{v:?}");
                    }
                    _ => {
                        let _ = write!(line, "{}", *v as i64);
                    }
                }
            }
            line.push('\n');
            w.write_all(line.as_bytes())?;
        }
        w.flush()
    }

    /// Writes the CSV to a file.
    pub fn write_csv_file(&self, path: impl AsRef<Path>) -> Result<(), ResultsError> {
        let path = path.as_ref();
        let io_err = |source| ResultsError::Io {
            path: path.to_path_buf(),
            source,
        };
        let f = std::fs::File::create(path).map_err(io_err)?;
        self.write_csv(io::BufWriter::with_capacity(1 << 20, f))
            .map_err(io_err)
    }

    /// Reads a CSV with a header whose first column is time (any name). Every value is read as
    /// a float; columns whose values are all integers are marked [`ColumnKind::Integer`].
    pub fn read_csv_file(path: impl AsRef<Path>) -> Result<Results, ResultsError> {
        let path = path.as_ref();
        let f = std::fs::File::open(path).map_err(|source| ResultsError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Results::read_csv(io::BufReader::new(f), path)
    }

    /// Reads a CSV from a reader (`path` is used in error messages).
    pub fn read_csv(r: impl BufRead, path: &Path) -> Result<Results, ResultsError> {
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
        for (i, l) in lines {
            let l = l.map_err(|e| csv_err(i + 1, e.to_string()))?;
            if l.trim().is_empty() || l.starts_with('#') {
                continue;
            }
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
        Ok(res)
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
                    if !v.is_nan() {
                        min = min.min(v);
                        max = max.max(v);
                    }
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
        let s = self.summary();
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
        for x in &s {
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

fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
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

/// Plotting chosen signals against time, as SVG or PNG.
pub mod plot {
    use super::{Results, ResultsError};
    use plotters::prelude::*;
    use std::path::Path;
    use std::sync::Once;

    /// The font used for all text: DejaVu Sans Mono, embedded (see `assets/DejaVu-LICENSE.txt`),
    /// so plotting needs no system font library.
    static FONT: &[u8] = include_bytes!("../assets/DejaVuSansMono.ttf");

    fn register_font() {
        static ONCE: Once = Once::new();
        ONCE.call_once(|| {
            for style in [FontStyle::Normal, FontStyle::Bold] {
                let _ = plotters::style::register_font("sans-serif", style, FONT);
            }
        });
    }

    /// Plots `signals` (column names) of `results` against time into `out`; the format follows
    /// the extension (`.svg` or `.png`). `size` is in pixels.
    pub fn plot_signals(
        results: &Results,
        signals: &[&str],
        out: &Path,
        size: (u32, u32),
    ) -> Result<(), ResultsError> {
        plot_signals_with(results, signals, out, size, &PlotLabels::default())
    }

    /// Axis labels and title of a plot.
    #[derive(Debug, Clone, PartialEq)]
    pub struct PlotLabels {
        /// Label of the x axis (the results' first column).
        pub x: String,
        /// Label of the y axis (empty: none).
        pub y: String,
        /// Title above the chart (empty: none).
        pub title: String,
    }

    impl Default for PlotLabels {
        fn default() -> Self {
            PlotLabels {
                x: "time [s]".into(),
                y: String::new(),
                title: String::new(),
            }
        }
    }

    /// [`plot_signals`] with axis labels and a title: the first column need not be time (a
    /// gait cycle in percent, for example).
    pub fn plot_signals_with(
        results: &Results,
        signals: &[&str],
        out: &Path,
        size: (u32, u32),
        labels: &PlotLabels,
    ) -> Result<(), ResultsError> {
        let ext = out
            .extension()
            .and_then(|e| e.to_str())
            .map(|e| e.to_ascii_lowercase());
        match ext.as_deref() {
            Some("svg") => draw(
                SVGBackend::new(out, size).into_drawing_area(),
                results,
                signals,
                labels,
            ),
            Some("png") => draw(
                BitMapBackend::new(out, size).into_drawing_area(),
                results,
                signals,
                labels,
            ),
            _ => Err(ResultsError::Plot(format!(
                "unknown plot format for '{}': use .svg or .png",
                out.display()
            ))),
        }
    }

    fn draw<DB: DrawingBackend>(
        root: DrawingArea<DB, plotters::coord::Shift>,
        results: &Results,
        signals: &[&str],
        labels: &PlotLabels,
    ) -> Result<(), ResultsError>
    where
        DB::ErrorType: 'static,
    {
        register_font();
        let e = |x: &dyn std::fmt::Display| ResultsError::Plot(x.to_string());
        let times = results.times();
        let mut series = Vec::new();
        for s in signals {
            let col = results.column(s).ok_or_else(|| {
                ResultsError::UnknownSignal(s.to_string(), results.names().join(", "))
            })?;
            series.push((s.to_string(), col));
        }
        let (t0, t1) = match (times.first(), times.last()) {
            (Some(&a), Some(&b)) if b > a => (a, b),
            (Some(&a), _) => (a, a + 1.0),
            _ => (0.0, 1.0),
        };
        let finite = series
            .iter()
            .flat_map(|(_, c)| c.iter().copied())
            .filter(|v| v.is_finite());
        let (mut lo, mut hi) = finite.fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), v| {
            (l.min(v), h.max(v))
        });
        if !lo.is_finite() {
            (lo, hi) = (0.0, 1.0);
        }
        if hi - lo < 1e-12 * (1.0 + lo.abs()) {
            lo -= 0.5;
            hi += 0.5;
        }
        let pad = (hi - lo) * 0.05;
        root.fill(&WHITE).map_err(|x| e(&x))?;
        let mut builder = ChartBuilder::on(&root);
        if !labels.title.is_empty() {
            builder.caption(&labels.title, ("sans-serif", 18));
        }
        let mut chart = builder
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(70)
            .build_cartesian_2d(t0..t1, (lo - pad)..(hi + pad))
            .map_err(|x| e(&x))?;
        chart
            .configure_mesh()
            .x_desc(labels.x.as_str())
            .y_desc(labels.y.as_str())
            .label_style(("sans-serif", 14))
            .draw()
            .map_err(|x| e(&x))?;
        for (k, (name, col)) in series.iter().enumerate() {
            let color = Palette99::pick(k).to_rgba();
            chart
                .draw_series(LineSeries::new(
                    times
                        .iter()
                        .copied()
                        .zip(col.iter().copied())
                        .filter(|(_, v)| v.is_finite()),
                    color.stroke_width(2),
                ))
                .map_err(|x| e(&x))?
                .label(name.clone())
                .legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(2))
                });
        }
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .label_font(("sans-serif", 14))
            .draw()
            .map_err(|x| e(&x))?;
        root.present().map_err(|x| e(&x))?;
        Ok(())
    }
}
