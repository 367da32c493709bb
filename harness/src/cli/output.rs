//! The results file of `kneebench run`: CSV, or Parquet for a `.parquet` output.

use std::path::{Path, PathBuf};

use kneebench_harness::results::csv::{
    CsvFile, check_output_path, partial_path, set_aside_partial,
};
use kneebench_harness::results::parquet::ParquetFile;
use kneebench_harness::results::{ColumnKind, ResultSink, ResultsError};

/// The streamed CSV file or the Parquet file, by the output's extension.
#[derive(Debug)]
pub enum OutputFile {
    /// CSV (any extension but `.parquet`).
    Csv(CsvFile),
    /// Parquet.
    Parquet(ParquetFile),
}

impl OutputFile {
    /// Checks `path` and creates its partial file, an earlier run's partial file (its rows)
    /// set aside first and named on standard error.
    pub fn create(path: &Path) -> Result<OutputFile, ResultsError> {
        check_output_path(path)?;
        if let Some(kept) = set_aside_partial(path)? {
            eprintln!(
                "kept an earlier run's rows: {} is now {}",
                partial_path(path).display(),
                kept.display()
            );
        }
        if path
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("parquet"))
        {
            ParquetFile::create(path).map(OutputFile::Parquet)
        } else {
            CsvFile::create(path).map(OutputFile::Csv)
        }
    }

    /// The partial file.
    pub fn partial_path(&self) -> &Path {
        match self {
            OutputFile::Csv(f) => f.partial_path(),
            OutputFile::Parquet(f) => f.partial_path(),
        }
    }

    /// The run's metadata (Parquet keeps it; CSV has no place for it).
    pub fn set_metadata(&mut self, metadata: Vec<(String, String)>) {
        if let OutputFile::Parquet(f) = self {
            f.set_metadata(metadata);
        }
    }

    /// Rows pushed so far.
    pub fn rows(&self) -> u64 {
        match self {
            OutputFile::Csv(f) => f.rows(),
            OutputFile::Parquet(f) => f.rows(),
        }
    }

    /// Renames the file into place.
    pub fn commit(self) -> Result<PathBuf, ResultsError> {
        match self {
            OutputFile::Csv(f) => f.commit(),
            OutputFile::Parquet(f) => f.commit(),
        }
    }

    /// Leaves the rows in the partial file.
    pub fn keep_partial(self) -> Result<PathBuf, ResultsError> {
        match self {
            OutputFile::Csv(f) => f.keep_partial(),
            OutputFile::Parquet(f) => f.keep_partial(),
        }
    }
}

impl ResultSink for OutputFile {
    fn begin(&mut self, names: &[String], kinds: &[ColumnKind]) -> Result<(), ResultsError> {
        match self {
            OutputFile::Csv(f) => f.begin(names, kinds),
            OutputFile::Parquet(f) => f.begin(names, kinds),
        }
    }

    #[inline]
    fn push_row(&mut self, time: f64, values: &[f64]) -> Result<(), ResultsError> {
        match self {
            OutputFile::Csv(f) => f.push_row(time, values),
            OutputFile::Parquet(f) => f.push_row(time, values),
        }
    }

    fn flush(&mut self) -> Result<(), ResultsError> {
        match self {
            OutputFile::Csv(f) => f.flush(),
            OutputFile::Parquet(f) => f.flush(),
        }
    }

    fn wants_periodic_flush(&self) -> bool {
        match self {
            OutputFile::Csv(f) => f.wants_periodic_flush(),
            OutputFile::Parquet(f) => f.wants_periodic_flush(),
        }
    }

    fn expect_rows(&mut self, rows: u64) {
        match self {
            OutputFile::Csv(f) => f.expect_rows(rows),
            OutputFile::Parquet(f) => f.expect_rows(rows),
        }
    }
}
