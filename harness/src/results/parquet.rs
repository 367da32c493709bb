//! The Parquet results file: a [`ResultSink`] writing one float64 column per signal after a
//! `time` column (Integer and Boolean signals as whole numbers), with key-value metadata (the
//! system, its parameters, the kneebench version, the FMUs' GUIDs).
//!
//! Rows are buffered per column as they come (one `Vec<f64>` each, filled in the row's pass)
//! and written in row groups of [`ROW_GROUP_ROWS`] rows by the `parquet` crate's column
//! writer: plain encoding, uncompressed (the values of a recording are mostly full-precision
//! doubles: Snappy saved a fifth of the bytes and no time in the writers bench), no
//! dictionary. Statistics (min and max per row group) are kept for `time` only, so that
//! readers skip row groups by time; the signals' statistics cost a sixth of the writer's own
//! time and no reader needs them. A Parquet file is readable
//! once its footer is written: [`ParquetFile::commit`] closes `<output>.partial` and renames it
//! into place; [`ParquetFile::keep_partial`] closes it where it is, so a failed or stopped
//! run's partial file is a readable table of the rows so far. A crash of the process leaves a
//! partial file without a footer (unreadable); the master's periodic flush is not asked for
//! (one row group per second would fragment the file).

use std::fs::File;
use std::io::{self, BufWriter};
use std::path::{Path, PathBuf};
use std::sync::Arc;

use parquet::basic::{Repetition, Type as PhysicalType};
use parquet::data_type::DoubleType;
use parquet::file::metadata::KeyValue;
use parquet::file::properties::{EnabledStatistics, WriterProperties};
use parquet::file::writer::SerializedFileWriter;
use parquet::schema::types::ColumnPath;
use parquet::schema::types::Type;

use super::csv::partial_path;
use super::{ColumnKind, ResultSink, ResultsError};

/// Rows per row group: a column's buffer of 8192 doubles is 64 KiB, under glibc's threshold
/// for mapping an allocation on its own (128 KiB), so the column buffers and the column
/// writer's are taken from the heap and reused from one row group to the next instead of
/// being mapped and faulted in afresh: `kneebench run` recording every output of the SEA
/// scenario for 100 s takes 2 400 page faults instead of 13 900 with 65 536 rows (53 MB of
/// buffers instead of 6.6 MB), 36 400 with each column handed over in one batch.
pub const ROW_GROUP_ROWS: usize = 8192;

/// The Parquet file sink (see the [module documentation](self)).
pub struct ParquetFile {
    path: PathBuf,
    partial: PathBuf,
    file: Option<File>,
    writer: Option<SerializedFileWriter<BufWriter<File>>>,
    /// `time`, then one buffer per column.
    columns: Vec<Vec<f64>>,
    metadata: Vec<(String, String)>,
    rows: u64,
}

impl std::fmt::Debug for ParquetFile {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ParquetFile")
            .field("path", &self.path)
            .field("rows", &self.rows)
            .finish()
    }
}

impl ParquetFile {
    /// Checks the output path and creates `<path>.partial`; nothing is written to `path`
    /// before [`commit`](Self::commit).
    pub fn create(path: &Path) -> Result<ParquetFile, ResultsError> {
        if path.is_dir() || path.file_name().is_none() {
            return Err(ResultsError::Io {
                path: path.to_path_buf(),
                source: io::Error::new(io::ErrorKind::InvalidInput, "not a file name"),
            });
        }
        let partial = partial_path(path);
        let file = File::create(&partial).map_err(|source| ResultsError::Io {
            path: partial.clone(),
            source,
        })?;
        Ok(ParquetFile {
            path: path.to_path_buf(),
            partial,
            file: Some(file),
            writer: None,
            columns: Vec::new(),
            metadata: Vec::new(),
            rows: 0,
        })
    }

    /// Key-value metadata written into the file (set before the run begins).
    pub fn set_metadata(&mut self, metadata: Vec<(String, String)>) {
        self.metadata = metadata;
    }

    /// The partial file the rows go to until [`commit`](Self::commit).
    pub fn partial_path(&self) -> &Path {
        &self.partial
    }

    /// Rows pushed so far.
    pub fn rows(&self) -> u64 {
        self.rows
    }

    fn err(&self, e: impl std::error::Error + Send + Sync + 'static) -> ResultsError {
        ResultsError::Io {
            path: self.partial.clone(),
            source: io::Error::other(e),
        }
    }

    fn write_group(&mut self) -> Result<(), ResultsError> {
        if self.columns.first().is_none_or(Vec::is_empty) {
            return Ok(());
        }
        let Some(writer) = self.writer.as_mut() else {
            return Ok(());
        };
        let partial = self.partial.clone();
        let err = |e: parquet::errors::ParquetError| ResultsError::Io {
            path: partial.clone(),
            source: io::Error::other(e),
        };
        let mut group = writer.next_row_group().map_err(err)?;
        for values in &mut self.columns {
            let mut col = group.next_column().map_err(err)?.ok_or_else(|| {
                err(parquet::errors::ParquetError::General(
                    "fewer columns than the schema".into(),
                ))
            })?;
            col.typed::<DoubleType>()
                .write_batch(values, None, None)
                .map_err(err)?;
            col.close().map_err(err)?;
            values.clear();
        }
        group.close().map_err(err)?;
        Ok(())
    }

    fn close(&mut self) -> Result<(), ResultsError> {
        self.write_group()?;
        if let Some(w) = self.writer.take() {
            let inner = w.into_inner().map_err(|e| self.err(e))?;
            let file = inner.into_inner().map_err(|e| self.err(e.into_error()))?;
            file.sync_all().map_err(|e| self.err(e))?;
        } else if let Some(f) = self.file.take() {
            // No row was ever begun: an empty table of just `time`.
            self.file = Some(f);
            self.begin(&[], &[])?;
            return self.close();
        }
        Ok(())
    }

    /// Writes the last row group and the footer, syncs, renames into place; returns the path.
    pub fn commit(mut self) -> Result<PathBuf, ResultsError> {
        self.close()?;
        std::fs::rename(&self.partial, &self.path).map_err(|source| ResultsError::Io {
            path: self.path.clone(),
            source,
        })?;
        Ok(self.path.clone())
    }

    /// Closes the partial file (readable, with the rows so far) and returns its path.
    pub fn keep_partial(mut self) -> Result<PathBuf, ResultsError> {
        self.close()?;
        Ok(self.partial.clone())
    }
}

impl ResultSink for ParquetFile {
    fn begin(&mut self, names: &[String], kinds: &[ColumnKind]) -> Result<(), ResultsError> {
        if names.len() != kinds.len() {
            return Err(ResultsError::RowLength {
                expected: names.len(),
                got: kinds.len(),
            });
        }
        let Some(file) = self.file.take() else {
            return Err(ResultsError::Io {
                path: self.partial.clone(),
                source: io::Error::other("the Parquet file was begun twice"),
            });
        };
        let mut fields = Vec::with_capacity(names.len() + 1);
        for n in std::iter::once("time").chain(names.iter().map(String::as_str)) {
            fields.push(Arc::new(
                Type::primitive_type_builder(n, PhysicalType::DOUBLE)
                    .with_repetition(Repetition::REQUIRED)
                    .build()
                    .map_err(|e| self.err(e))?,
            ));
        }
        let schema = Arc::new(
            Type::group_type_builder("results")
                .with_fields(fields)
                .build()
                .map_err(|e| self.err(e))?,
        );
        let mut kv: Vec<KeyValue> = vec![KeyValue::new(
            "kneebench.version".to_string(),
            env!("CARGO_PKG_VERSION").to_string(),
        )];
        kv.extend(
            self.metadata
                .iter()
                .map(|(k, v)| KeyValue::new(k.clone(), v.clone())),
        );
        let props = WriterProperties::builder()
            .set_created_by(format!("kneebench {}", env!("CARGO_PKG_VERSION")))
            .set_key_value_metadata(Some(kv))
            .set_dictionary_enabled(false)
            .set_statistics_enabled(EnabledStatistics::None)
            .set_column_statistics_enabled(ColumnPath::from("time"), EnabledStatistics::Chunk)
            .build();
        let writer = SerializedFileWriter::new(
            BufWriter::with_capacity(1 << 20, file),
            schema,
            Arc::new(props),
        )
        .map_err(|e| self.err(e))?;
        self.writer = Some(writer);
        // One buffer each, at its full size now (`vec![v; n]` clones, and a clone of an empty
        // Vec drops its capacity: the buffers would grow by reallocation, row by row).
        self.columns = (0..=names.len())
            .map(|_| Vec::with_capacity(ROW_GROUP_ROWS))
            .collect();
        Ok(())
    }

    #[inline]
    fn push_row(&mut self, time: f64, values: &[f64]) -> Result<(), ResultsError> {
        if values.len() + 1 != self.columns.len() {
            return Err(ResultsError::RowLength {
                expected: self.columns.len().saturating_sub(1),
                got: values.len(),
            });
        }
        self.columns[0].push(time);
        for (c, &v) in self.columns[1..].iter_mut().zip(values) {
            c.push(v);
        }
        self.rows += 1;
        if self.columns[0].len() >= ROW_GROUP_ROWS {
            self.write_group()?;
        }
        Ok(())
    }

    fn flush(&mut self) -> Result<(), ResultsError> {
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use parquet::file::reader::{FileReader, SerializedFileReader};

    /// Row groups of ROW_GROUP_ROWS rows (the last one shorter), min and max of `time` in
    /// each (what readers skip row groups by), no statistics for the signals.
    #[test]
    fn row_groups_carry_the_time_range_only() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("r.parquet");
        let mut f = ParquetFile::create(&path).unwrap();
        f.begin(&["x".to_string()], &[ColumnKind::Real]).unwrap();
        let rows = 2 * ROW_GROUP_ROWS + 5;
        for k in 0..rows {
            f.push_row(k as f64, &[-(k as f64)]).unwrap();
        }
        f.commit().unwrap();
        let reader = SerializedFileReader::new(File::open(&path).unwrap()).unwrap();
        let groups = reader.metadata().row_groups();
        let lengths: Vec<i64> = groups.iter().map(|g| g.num_rows()).collect();
        let full = ROW_GROUP_ROWS as i64;
        assert_eq!(lengths, [full, full, 5]);
        for (i, g) in groups.iter().enumerate() {
            let first = (i * ROW_GROUP_ROWS) as f64;
            let last = first + lengths[i] as f64 - 1.0;
            match g.column(0).statistics() {
                Some(parquet::file::statistics::Statistics::Double(s)) => {
                    assert_eq!((s.min_opt(), s.max_opt()), (Some(&first), Some(&last)));
                }
                other => panic!("time statistics of row group {i}: {other:?}"),
            }
            assert!(g.column(1).statistics().is_none(), "row group {i}");
        }
    }
}
