//! Reading a results table from Parquet: the files `kneebench run --output x.parquet` writes,
//! and logs of other tools (pandas, polars, pyarrow) with a time column and numeric columns.
//!
//! Accepted: flat schemas whose columns are DOUBLE, FLOAT, INT32, INT64 or BOOLEAN (read as
//! `f64`), required or optional without nulls; a column named `time` (else the first column)
//! is the time. Compression: none, Snappy (pandas' and pyarrow's default) and Zstandard
//! (polars' default). Anything else is refused with the file and the column, never read
//! wrongly.

use std::fs::File;
use std::path::Path;

use parquet::basic::Type as PhysicalType;
use parquet::column::reader::{ColumnReader, ColumnReaderImpl};
use parquet::data_type::DataType;
use parquet::file::reader::{FileReader, SerializedFileReader};

use super::{ColumnKind, Results, ResultsError};

/// Rows read per batch from a column chunk.
const BATCH: usize = 8192;

/// Reads the Parquet file at `path` into [`Results`]: its time column and, of the others, the
/// ones named in `only` (every one when `None`; a name in `only` that the file lacks is left
/// out, as a CSV reader that selects columns would). Values are `f64`; booleans read 0/1.
///
/// Errors: the file cannot be opened or is not Parquet, a nested schema, a column of another
/// type (strings, decimals...), a null, or columns of different lengths.
pub fn read_parquet(path: &Path, only: Option<&[String]>) -> Result<Results, ResultsError> {
    let bad = |problem: String| ResultsError::Series {
        path: path.to_path_buf(),
        problem,
    };
    let file = File::open(path).map_err(|source| ResultsError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let reader = SerializedFileReader::new(file).map_err(|e| bad(format!("not Parquet: {e}")))?;
    let schema = reader.metadata().file_metadata().schema_descr_ptr();
    let columns = schema.columns();
    if columns.is_empty() {
        return Err(bad("no columns".into()));
    }
    for c in columns {
        if c.max_rep_level() > 0 || c.path().parts().len() != 1 {
            return Err(bad(format!(
                "column '{}' is nested or repeated: only flat tables of numbers are read",
                c.path()
            )));
        }
    }
    let names: Vec<String> = columns.iter().map(|c| c.name().to_string()).collect();
    let time_index = names.iter().position(|n| n == "time").unwrap_or(0);
    let selected: Vec<usize> = (0..names.len())
        .filter(|&i| i != time_index)
        .filter(|&i| only.is_none_or(|o| o.iter().any(|n| *n == names[i])))
        .collect();
    let mut data: Vec<Vec<f64>> = vec![Vec::new(); selected.len() + 1];
    for g in 0..reader.num_row_groups() {
        let group = reader
            .get_row_group(g)
            .map_err(|e| bad(format!("row group {g}: {e}")))?;
        let rows = usize::try_from(group.metadata().num_rows())
            .map_err(|_| bad(format!("row group {g}: a negative row count")))?;
        for (slot, &i) in std::iter::once(&time_index).chain(&selected).enumerate() {
            let reader = group
                .get_column_reader(i)
                .map_err(|e| bad(format!("column '{}': {e}", names[i])))?;
            let optional = columns[i].max_def_level() > 0;
            let values = read_column(reader, rows, optional)
                .map_err(|problem| bad(format!("column '{}': {problem}", names[i])))?;
            data[slot].extend(values);
        }
    }
    let n = data[0].len();
    let out_names: Vec<String> = selected.iter().map(|&i| names[i].clone()).collect();
    let mut results = Results::with_capacity(
        out_names.clone(),
        vec![ColumnKind::Real; out_names.len()],
        n,
    );
    let mut row = vec![0.0; selected.len()];
    for (r, &time) in data[0].iter().enumerate() {
        for (v, column) in row.iter_mut().zip(&data[1..]) {
            *v = column[r];
        }
        results.push_row(time, &row);
    }
    Ok(results)
}

/// All `rows` values of one column chunk as `f64`.
fn read_column(reader: ColumnReader, rows: usize, optional: bool) -> Result<Vec<f64>, String> {
    match reader {
        ColumnReader::DoubleColumnReader(r) => read_typed(r, rows, optional, |v: f64| v),
        ColumnReader::FloatColumnReader(r) => read_typed(r, rows, optional, f64::from),
        ColumnReader::Int32ColumnReader(r) => read_typed(r, rows, optional, f64::from),
        // Exact up to 2^53; counters and flags are far below.
        ColumnReader::Int64ColumnReader(r) => read_typed(r, rows, optional, |v: i64| v as f64),
        ColumnReader::BoolColumnReader(r) => {
            read_typed(r, rows, optional, |v: bool| f64::from(u8::from(v)))
        }
        other => Err(format!(
            "of physical type {}: only numbers and booleans are read",
            physical_type(&other)
        )),
    }
}

fn physical_type(reader: &ColumnReader) -> PhysicalType {
    match reader {
        ColumnReader::BoolColumnReader(_) => PhysicalType::BOOLEAN,
        ColumnReader::Int32ColumnReader(_) => PhysicalType::INT32,
        ColumnReader::Int64ColumnReader(_) => PhysicalType::INT64,
        ColumnReader::Int96ColumnReader(_) => PhysicalType::INT96,
        ColumnReader::FloatColumnReader(_) => PhysicalType::FLOAT,
        ColumnReader::DoubleColumnReader(_) => PhysicalType::DOUBLE,
        ColumnReader::ByteArrayColumnReader(_) => PhysicalType::BYTE_ARRAY,
        ColumnReader::FixedLenByteArrayColumnReader(_) => PhysicalType::FIXED_LEN_BYTE_ARRAY,
    }
}

fn read_typed<T: DataType>(
    mut reader: ColumnReaderImpl<T>,
    rows: usize,
    optional: bool,
    convert: impl Fn(T::T) -> f64,
) -> Result<Vec<f64>, String>
where
    T::T: Copy,
{
    let mut out = Vec::with_capacity(rows);
    let mut values: Vec<T::T> = Vec::with_capacity(BATCH);
    let mut levels: Vec<i16> = Vec::with_capacity(BATCH);
    while out.len() < rows {
        values.clear();
        levels.clear();
        let want = BATCH.min(rows - out.len());
        let (records, read_values, _) = reader
            .read_records(
                want,
                if optional { Some(&mut levels) } else { None },
                None,
                &mut values,
            )
            .map_err(|e| e.to_string())?;
        if records == 0 {
            return Err(format!(
                "{} values for {rows} rows in its row group",
                out.len()
            ));
        }
        if read_values != records {
            return Err(format!("a null in row {}", out.len() + read_values + 1));
        }
        out.extend(values.iter().map(|&v| convert(v)));
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::results::ResultSink;
    use crate::results::parquet::ParquetFile;

    fn written(dir: &Path) -> std::path::PathBuf {
        let path = dir.join("r.parquet");
        let mut f = ParquetFile::create(&path).unwrap();
        f.begin(
            &["a".to_string(), "b".to_string()],
            &[ColumnKind::Real, ColumnKind::Integer],
        )
        .unwrap();
        for k in 0..20_000 {
            let t = k as f64 * 1e-3;
            f.push_row(t, &[t.sin(), (k % 7) as f64]).unwrap();
        }
        f.commit().unwrap()
    }

    #[test]
    fn what_the_writer_wrote_reads_back_bit_for_bit() {
        let dir = tempfile::tempdir().unwrap();
        let path = written(dir.path());
        let r = read_parquet(&path, None).unwrap();
        assert_eq!(r.names(), ["a", "b"]);
        assert_eq!(r.len(), 20_000);
        let a = r.column("a").unwrap();
        for (k, (t, v)) in r.times().iter().zip(&a).enumerate() {
            assert_eq!(t.to_bits(), (k as f64 * 1e-3).to_bits());
            assert_eq!(v.to_bits(), t.sin().to_bits());
        }
        assert_eq!(r.column("b").unwrap()[8], 1.0);
        let only = read_parquet(&path, Some(&["b".to_string()])).unwrap();
        assert_eq!(only.names(), ["b"]);
    }

    #[test]
    fn not_parquet_and_missing_files_are_refused_with_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("x.parquet");
        std::fs::write(&path, b"time,a\n0,1\n").unwrap();
        let e = read_parquet(&path, None).unwrap_err().to_string();
        assert!(e.contains("x.parquet") && e.contains("not Parquet"), "{e}");
        let e = read_parquet(&dir.path().join("none.parquet"), None)
            .unwrap_err()
            .to_string();
        assert!(e.contains("none.parquet"), "{e}");
    }
}
