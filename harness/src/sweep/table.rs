//! The sweep table: one row per point (its id, parameter values, metrics, status and
//! message), written as Parquet (`point` INT64, parameters and metrics DOUBLE, `status` and
//! `message` UTF-8 strings, key-value metadata) or as CSV (round-trip floats).
//!
//! Like every results writer ([`crate::results::csv::CsvFile`],
//! [`crate::results::parquet::ParquetFile`]), the table is written to `<output>.partial` next
//! to the output, synced, and renamed into place: an earlier table at the output stays whole
//! until the new one is complete, and a failed write leaves no half table under its name.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::Path;
use std::sync::Arc;

use parquet::basic::{LogicalType, Repetition, Type as PhysicalType};
use parquet::data_type::{ByteArray, ByteArrayType, DoubleType, Int64Type};
use parquet::file::metadata::KeyValue;
use parquet::file::properties::WriterProperties;
use parquet::file::writer::SerializedFileWriter;
use parquet::schema::types::Type;

use super::SweepError;
use crate::results::ResultsError;
use crate::results::csv::{check_output_path, partial_path};

/// How a run ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RunStatus {
    /// Completed without an interlock trip.
    Ok,
    /// An interlock tripped (the FMU ended the run or its trip code was set).
    Tripped,
    /// The run failed (an FMU error, a refused parameter value, an analysis error).
    Failed,
}

impl RunStatus {
    /// `ok`, `tripped` or `failed`.
    pub fn name(self) -> &'static str {
        match self {
            RunStatus::Ok => "ok",
            RunStatus::Tripped => "tripped",
            RunStatus::Failed => "failed",
        }
    }

    /// The status named `name`.
    pub fn from_name(name: &str) -> Option<RunStatus> {
        match name {
            "ok" => Some(RunStatus::Ok),
            "tripped" => Some(RunStatus::Tripped),
            "failed" => Some(RunStatus::Failed),
            _ => None,
        }
    }
}

/// One run.
#[derive(Debug, Clone, PartialEq)]
pub struct Row {
    /// The point's id (its index in the design).
    pub point: u64,
    /// The parameter values, in spec order.
    pub parameters: Vec<f64>,
    /// The metrics, in [`SweepTable::metric_names`] order (NaN where not available).
    pub metrics: Vec<f64>,
    /// How the run ended.
    pub status: RunStatus,
    /// Why it tripped or failed (empty when ok).
    pub message: String,
}

/// Whether two lists of values are equal bit for bit (NaN equals NaN of the same bits).
pub fn same_bits(a: &[f64], b: &[f64]) -> bool {
    a.len() == b.len() && a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits())
}

impl Row {
    /// Whether two rows are equal bit for bit (NaN equals NaN of the same bits).
    pub fn bit_identical(&self, other: &Row) -> bool {
        self.same_outcome(other) && same_bits(&self.parameters, &other.parameters)
    }

    /// Whether two rows of a point ended the same, bit for bit: point, metrics, status and
    /// message (the parameters aside: a journaled row has none of its own).
    pub fn same_outcome(&self, other: &Row) -> bool {
        self.point == other.point
            && same_bits(&self.metrics, &other.metrics)
            && self.status == other.status
            && self.message == other.message
    }
}

/// The rows of a sweep, sorted by point id.
#[derive(Debug, Clone, PartialEq)]
pub struct SweepTable {
    /// Parameter columns (`component.variable`).
    pub parameter_names: Vec<String>,
    /// Metric columns.
    pub metric_names: Vec<String>,
    /// The rows.
    pub rows: Vec<Row>,
    /// Key-value metadata written with the table (spec fingerprint, system, version).
    pub metadata: Vec<(String, String)>,
}

impl SweepTable {
    /// Every column name in order: `point`, the parameters, the metrics, `status`, `message`.
    pub fn column_names(&self) -> Vec<String> {
        let mut out = vec!["point".to_string()];
        out.extend(self.parameter_names.iter().cloned());
        out.extend(self.metric_names.iter().cloned());
        out.push("status".into());
        out.push("message".into());
        out
    }

    /// Whether two tables are equal bit for bit (names and rows; metadata ignored).
    pub fn bit_identical(&self, other: &SweepTable) -> bool {
        self.parameter_names == other.parameter_names
            && self.metric_names == other.metric_names
            && self.rows.len() == other.rows.len()
            && self
                .rows
                .iter()
                .zip(&other.rows)
                .all(|(a, b)| a.bit_identical(b))
    }

    /// Writes the table as CSV (header of [`column_names`](Self::column_names); floats in the
    /// shortest form that reads back to the same bits, NaN as `NaN`; strings quoted when
    /// needed).
    pub fn write_csv(&self, path: &Path) -> Result<(), SweepError> {
        write_then_rename(path, |partial| self.write_csv_to(partial))
    }

    fn write_csv_to(&self, path: &Path) -> Result<File, SweepError> {
        let io = |source| SweepError::Io {
            path: path.to_path_buf(),
            source,
        };
        let mut w = BufWriter::new(File::create(path).map_err(io)?);
        self.check_rows(path)?;
        let header: Vec<String> = self.column_names().iter().map(|n| quote(n)).collect();
        writeln!(w, "{}", header.join(",")).map_err(io)?;
        let mut buf = ryu::Buffer::new();
        for r in &self.rows {
            let mut line = r.point.to_string();
            for v in r.parameters.iter().chain(&r.metrics) {
                line.push(',');
                if v.is_finite() {
                    line.push_str(buf.format_finite(*v));
                } else {
                    line.push_str(&v.to_string());
                }
            }
            line.push(',');
            line.push_str(r.status.name());
            line.push(',');
            line.push_str(&quote(&r.message));
            writeln!(w, "{line}").map_err(io)?;
        }
        w.into_inner().map_err(|e| io(e.into_error()))
    }

    /// Writes the table as one Parquet file (one row group, uncompressed).
    pub fn write_parquet(&self, path: &Path) -> Result<(), SweepError> {
        write_then_rename(path, |partial| self.write_parquet_to(partial))
    }

    fn write_parquet_to(&self, path: &Path) -> Result<File, SweepError> {
        let err = |e: parquet::errors::ParquetError| SweepError::Table {
            path: path.to_path_buf(),
            message: e.to_string(),
        };
        let prim = |name: &str, t: PhysicalType, logical: Option<LogicalType>| {
            Type::primitive_type_builder(name, t)
                .with_repetition(Repetition::REQUIRED)
                .with_logical_type(logical)
                .build()
                .map(Arc::new)
        };
        let mut fields = vec![prim("point", PhysicalType::INT64, None).map_err(err)?];
        for n in self.parameter_names.iter().chain(&self.metric_names) {
            fields.push(prim(n, PhysicalType::DOUBLE, None).map_err(err)?);
        }
        for n in ["status", "message"] {
            fields.push(prim(n, PhysicalType::BYTE_ARRAY, Some(LogicalType::String)).map_err(err)?);
        }
        let schema = Arc::new(
            Type::group_type_builder("sweep")
                .with_fields(fields)
                .build()
                .map_err(err)?,
        );
        let props = WriterProperties::builder()
            .set_created_by(format!("kneebench {}", env!("CARGO_PKG_VERSION")))
            .set_key_value_metadata(Some(
                self.metadata
                    .iter()
                    .map(|(k, v)| KeyValue::new(k.clone(), v.clone()))
                    .collect(),
            ))
            .build();
        let file = File::create(path).map_err(|source| SweepError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        self.check_rows(path)?;
        let mut writer = SerializedFileWriter::new(BufWriter::new(file), schema, Arc::new(props))
            .map_err(err)?;
        let mut group = writer.next_row_group().map_err(err)?;
        let points: Vec<i64> = self.rows.iter().map(|r| r.point as i64).collect();
        let mut col = group.next_column().map_err(err)?.ok_or_else(|| {
            err(parquet::errors::ParquetError::General(
                "missing column".into(),
            ))
        })?;
        col.typed::<Int64Type>()
            .write_batch(&points, None, None)
            .map_err(err)?;
        col.close().map_err(err)?;
        let n_par = self.parameter_names.len();
        for k in 0..n_par + self.metric_names.len() {
            let values: Vec<f64> = self
                .rows
                .iter()
                .map(|r| {
                    if k < n_par {
                        r.parameters[k]
                    } else {
                        r.metrics[k - n_par]
                    }
                })
                .collect();
            let mut col = group.next_column().map_err(err)?.ok_or_else(|| {
                err(parquet::errors::ParquetError::General(
                    "missing column".into(),
                ))
            })?;
            col.typed::<DoubleType>()
                .write_batch(&values, None, None)
                .map_err(err)?;
            col.close().map_err(err)?;
        }
        for k in 0..2 {
            let values: Vec<ByteArray> = self
                .rows
                .iter()
                .map(|r| {
                    ByteArray::from(if k == 0 {
                        r.status.name()
                    } else {
                        r.message.as_str()
                    })
                })
                .collect();
            let mut col = group.next_column().map_err(err)?.ok_or_else(|| {
                err(parquet::errors::ParquetError::General(
                    "missing column".into(),
                ))
            })?;
            col.typed::<ByteArrayType>()
                .write_batch(&values, None, None)
                .map_err(err)?;
            col.close().map_err(err)?;
        }
        group.close().map_err(err)?;
        let inner = writer.into_inner().map_err(err)?;
        inner.into_inner().map_err(|e| SweepError::Io {
            path: path.to_path_buf(),
            source: e.into_error(),
        })
    }

    /// Reads a table that [`write_parquet`](Self::write_parquet) wrote: `point`, the DOUBLE
    /// columns (the first `parameter_count` of them the parameters, the rest the metrics),
    /// `status` and `message`, with its key-value metadata. Values read back bit for bit.
    ///
    /// Errors: the file cannot be opened or is not Parquet, or its columns are not those of a
    /// sweep table (fewer than `parameter_count` value columns, another type or order, an
    /// unknown status).
    pub fn read_parquet(path: &Path, parameter_count: usize) -> Result<SweepTable, SweepError> {
        use parquet::file::reader::{FileReader, SerializedFileReader};
        use parquet::record::RowAccessor;
        let bad = |message: String| SweepError::Table {
            path: path.to_path_buf(),
            message,
        };
        let file = File::open(path).map_err(|source| SweepError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        let reader =
            SerializedFileReader::new(file).map_err(|e| bad(format!("not Parquet: {e}")))?;
        let meta = reader.metadata().file_metadata();
        let metadata: Vec<(String, String)> = meta
            .key_value_metadata()
            .map(|kv| {
                kv.iter()
                    .map(|k| (k.key.clone(), k.value.clone().unwrap_or_default()))
                    .collect()
            })
            .unwrap_or_default();
        let columns = meta.schema_descr().columns().to_vec();
        let names: Vec<String> = columns.iter().map(|c| c.name().to_string()).collect();
        let types: Vec<PhysicalType> = columns.iter().map(|c| c.physical_type()).collect();
        let n = names.len();
        let shape = n >= 3 + parameter_count
            && names[0] == "point"
            && types[0] == PhysicalType::INT64
            && names[n - 2] == "status"
            && names[n - 1] == "message"
            && types[n - 2..]
                .iter()
                .all(|t| *t == PhysicalType::BYTE_ARRAY)
            && types[1..n - 2].iter().all(|t| *t == PhysicalType::DOUBLE)
            && columns
                .iter()
                .all(|c| c.max_def_level() == 0 && c.max_rep_level() == 0);
        if !shape {
            return Err(bad(format!(
                "not a sweep table of {parameter_count} parameters (its columns: {})",
                names.join(", ")
            )));
        }
        let mut table = SweepTable {
            parameter_names: names[1..1 + parameter_count].to_vec(),
            metric_names: names[1 + parameter_count..n - 2].to_vec(),
            rows: Vec::new(),
            metadata,
        };
        let rows = reader
            .get_row_iter(None)
            .map_err(|e| bad(format!("rows: {e}")))?;
        for (i, record) in rows.enumerate() {
            let at = |e: parquet::errors::ParquetError| bad(format!("row {}: {e}", i + 1));
            let record = record.map_err(at)?;
            let values = (1..n - 2)
                .map(|k| record.get_double(k))
                .collect::<Result<Vec<f64>, _>>()
                .map_err(at)?;
            let status = record.get_string(n - 2).map_err(at)?;
            table.rows.push(Row {
                point: u64::try_from(record.get_long(0).map_err(at)?)
                    .map_err(|_| bad(format!("row {}: a negative point id", i + 1)))?,
                parameters: values[..parameter_count].to_vec(),
                metrics: values[parameter_count..].to_vec(),
                status: RunStatus::from_name(status)
                    .ok_or_else(|| bad(format!("row {}: unknown status '{status}'", i + 1)))?,
                message: record.get_string(n - 1).map_err(at)?.clone(),
            });
        }
        Ok(table)
    }

    /// Refuses a row whose values do not fit the columns.
    fn check_rows(&self, path: &Path) -> Result<(), SweepError> {
        let (np, nm) = (self.parameter_names.len(), self.metric_names.len());
        match self
            .rows
            .iter()
            .find(|r| r.parameters.len() != np || r.metrics.len() != nm)
        {
            Some(r) => Err(SweepError::Table {
                path: path.to_path_buf(),
                message: format!(
                    "point {}: {} parameters and {} metrics for {np} and {nm} columns",
                    r.point,
                    r.parameters.len(),
                    r.metrics.len()
                ),
            }),
            None => Ok(()),
        }
    }

    /// Writes Parquet for a `.parquet` path, CSV otherwise.
    pub fn write(&self, path: &Path) -> Result<(), SweepError> {
        if path
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("parquet"))
        {
            self.write_parquet(path)
        } else {
            self.write_csv(path)
        }
    }
}

/// Checks that a table can be written to `path` (see [`check_output_path`]), before a sweep
/// runs and again when its table is written.
pub(crate) fn check_table_path(path: &Path) -> Result<(), SweepError> {
    check_output_path(path).map_err(|e| match e {
        ResultsError::Io { path, source } => SweepError::Io { path, source },
        other => SweepError::Table {
            path: path.to_path_buf(),
            message: other.to_string(),
        },
    })
}

/// Writes a table through `<path>.partial` (`write` creates and fills it, returning the file),
/// syncs it and renames it to `path`; the partial file is removed if anything fails.
fn write_then_rename(
    path: &Path,
    write: impl FnOnce(&Path) -> Result<File, SweepError>,
) -> Result<(), SweepError> {
    check_table_path(path)?;
    let partial = partial_path(path);
    let done = write(&partial).and_then(|file| {
        file.sync_all().map_err(|source| SweepError::Io {
            path: partial.clone(),
            source,
        })?;
        drop(file);
        std::fs::rename(&partial, path).map_err(|source| SweepError::Io {
            path: path.to_path_buf(),
            source,
        })
    });
    if done.is_err() && partial.is_file() {
        let _ = std::fs::remove_file(&partial);
    }
    done
}

fn quote(s: &str) -> String {
    if s.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use parquet::file::reader::{FileReader, SerializedFileReader};

    fn table() -> SweepTable {
        SweepTable {
            parameter_names: vec!["plant.springStiffness".into()],
            metric_names: vec!["rms_error_knee".into()],
            rows: vec![
                Row {
                    point: 0,
                    parameters: vec![0.1],
                    metrics: vec![1.0 / 3.0],
                    status: RunStatus::Ok,
                    message: String::new(),
                },
                Row {
                    point: 1,
                    parameters: vec![2.5],
                    metrics: vec![f64::NAN],
                    status: RunStatus::Failed,
                    message: "plant: \"bad\", value".into(),
                },
            ],
            metadata: vec![("kneebench.version".into(), "0.1.0".into())],
        }
    }

    #[test]
    fn parquet_round_trips_values_strings_and_metadata() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("t.parquet");
        let t = table();
        t.write_parquet(&path).unwrap();
        let reader = SerializedFileReader::new(File::open(&path).unwrap()).unwrap();
        let meta = reader.metadata().file_metadata();
        assert_eq!(meta.num_rows(), 2);
        let kv = meta.key_value_metadata().unwrap();
        assert!(
            kv.iter()
                .any(|k| k.key == "kneebench.version" && k.value.as_deref() == Some("0.1.0"))
        );
        let rows: Vec<_> = reader
            .get_row_iter(None)
            .unwrap()
            .map(|r| r.unwrap())
            .collect();
        use parquet::record::RowAccessor;
        assert_eq!(rows[0].get_long(0).unwrap(), 0);
        assert_eq!(
            rows[0].get_double(2).unwrap().to_bits(),
            (1.0f64 / 3.0).to_bits()
        );
        assert!(rows[1].get_double(2).unwrap().is_nan());
        assert_eq!(rows[1].get_string(3).unwrap(), "failed");
        assert_eq!(rows[1].get_string(4).unwrap(), "plant: \"bad\", value");
    }

    #[test]
    fn read_parquet_gives_back_what_write_parquet_wrote_bit_for_bit() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("t.parquet");
        let mut t = table();
        // A NaN with its sign set (x86's 0/0) and a message across lines keep their bits.
        t.rows[1].metrics[0] = f64::from_bits(0xfff8_0000_0000_0000);
        t.rows[1].message.push_str("\nsecond line");
        t.write_parquet(&path).unwrap();
        let back = SweepTable::read_parquet(&path, 1).unwrap();
        assert!(back.bit_identical(&t));
        assert_eq!(back.parameter_names, t.parameter_names);
        assert_eq!(back.metadata, t.metadata);
        // Two value columns read as parameters: the names say which.
        let two = SweepTable::read_parquet(&path, 2).unwrap();
        assert!(two.metric_names.is_empty());
        assert_eq!(two.rows[0].parameters, [0.1, 1.0 / 3.0]);
        // Not a sweep table of 3 parameters, not a sweep table, not Parquet, no file.
        let e = SweepTable::read_parquet(&path, 3).unwrap_err().to_string();
        assert!(
            e.contains(
                "not a sweep table of 3 parameters (its columns: point, \
                 plant.springStiffness, rms_error_knee, status, message)"
            ),
            "{e}"
        );
        let results = dir.path().join("r.parquet");
        let mut f = crate::results::parquet::ParquetFile::create(&results).unwrap();
        use crate::results::ResultSink;
        f.begin(&["a".to_string()], &[crate::results::ColumnKind::Real])
            .unwrap();
        f.push_row(0.0, &[1.0]).unwrap();
        f.commit().unwrap();
        let e = SweepTable::read_parquet(&results, 0)
            .unwrap_err()
            .to_string();
        assert!(e.contains("not a sweep table of 0 parameters"), "{e}");
        let csv = dir.path().join("t.csv");
        t.write_csv(&csv).unwrap();
        let e = SweepTable::read_parquet(&csv, 1).unwrap_err().to_string();
        assert!(e.contains("not Parquet"), "{e}");
        let e = SweepTable::read_parquet(&dir.path().join("none.parquet"), 1)
            .unwrap_err()
            .to_string();
        assert!(e.contains("none.parquet"), "{e}");
    }

    #[test]
    fn a_failed_write_keeps_the_earlier_table_and_leaves_no_partial_file() {
        let dir = tempfile::tempdir().unwrap();
        for name in ["t.parquet", "t.csv"] {
            let path = dir.path().join(name);
            let t = table();
            t.write(&path).unwrap();
            let before = std::fs::read(&path).unwrap();
            assert!(!partial_path(&path).exists());
            // A row whose metrics do not fit the columns: the Parquet writer refuses it; the
            // CSV one is made to fail by a directory where its partial file would go.
            let mut bad = t.clone();
            if name.ends_with(".parquet") {
                bad.rows[1].metrics.clear();
                bad.metric_names.push("extra".into());
            } else {
                std::fs::create_dir(partial_path(&path)).unwrap();
            }
            assert!(bad.write(&path).is_err(), "{name}");
            assert_eq!(std::fs::read(&path).unwrap(), before, "{name}");
            if name.ends_with(".parquet") {
                assert!(!partial_path(&path).exists(), "{name}");
            }
        }
    }

    #[test]
    fn csv_quotes_messages_and_keeps_bits() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("t.csv");
        table().write_csv(&path).unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        assert_eq!(
            text,
            "point,plant.springStiffness,rms_error_knee,status,message\n\
             0,0.1,0.3333333333333333,ok,\n\
             1,2.5,NaN,failed,\"plant: \"\"bad\"\", value\"\n"
        );
    }
}
