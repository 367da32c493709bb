//! The results writers as they were before the writers' speed work (commit 4921f0f), kept
//! as the bench's baseline so that every speed-up is a ratio measured in the same run: the
//! CSV writer (ryu, a line buffer copied into a `BufWriter`, integers through `write!`) and
//! the Parquet writer as it was before its row groups were handed to a thread of their own
//! and their durable write started as they are written (commit ee9b036: per-column `Vec`
//! buffers, row groups of 8192 rows, the column writer with statistics for `time` only,
//! encoding in `push_row`, one sync at the end). Both write `<output>.partial`, sync it and rename it
//! into place, as the library's writers do.

use std::fs::File;
use std::io::{self, BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::Arc;

use kneebench_harness::results::ColumnKind;
use kneebench_harness::results::csv::partial_path;
use parquet::basic::{Repetition, Type as PhysicalType};
use parquet::data_type::DoubleType;
use parquet::file::properties::{EnabledStatistics, WriterProperties};
use parquet::file::writer::SerializedFileWriter;
use parquet::schema::types::{ColumnPath, Type};

/// The previous `CsvFile`: `create`, `begin`, `push_row`, `commit`.
pub struct CsvFile {
    path: PathBuf,
    partial: PathBuf,
    out: BufWriter<File>,
    kinds: Vec<ColumnKind>,
    line: Vec<u8>,
    floats: ryu::Buffer,
}

impl CsvFile {
    pub fn create(path: &Path) -> io::Result<CsvFile> {
        let partial = partial_path(path);
        let file = File::create(&partial)?;
        Ok(CsvFile {
            path: path.to_path_buf(),
            partial,
            out: BufWriter::with_capacity(64 * 1024, file),
            kinds: Vec::new(),
            line: Vec::with_capacity(256),
            floats: ryu::Buffer::new(),
        })
    }

    pub fn begin(&mut self, names: &[String], kinds: &[ColumnKind]) -> io::Result<()> {
        self.kinds = kinds.to_vec();
        self.line.clear();
        self.line.extend_from_slice(b"time");
        for n in names {
            self.line.push(b',');
            self.line.extend_from_slice(n.as_bytes());
        }
        self.line.push(b'\n');
        self.out.write_all(&self.line)
    }

    #[inline]
    pub fn push_row(&mut self, time: f64, values: &[f64]) -> io::Result<()> {
        assert_eq!(values.len(), self.kinds.len());
        self.line.clear();
        self.line
            .extend_from_slice(self.floats.format(time).as_bytes());
        for (&v, k) in values.iter().zip(&self.kinds) {
            self.line.push(b',');
            match k {
                ColumnKind::Real => self
                    .line
                    .extend_from_slice(self.floats.format(v).as_bytes()),
                ColumnKind::Integer | ColumnKind::Boolean => {
                    let _ = write!(self.line, "{}", v as i64);
                }
            }
        }
        self.line.push(b'\n');
        self.out.write_all(&self.line)
    }

    pub fn commit(mut self) -> io::Result<PathBuf> {
        self.out.flush()?;
        self.out.get_ref().sync_all()?;
        std::fs::rename(&self.partial, &self.path)?;
        Ok(self.path)
    }
}

/// Rows per row group of the previous Parquet writer.
const ROW_GROUP_ROWS: usize = 8192;

/// The previous `ParquetFile` (before its row groups were encoded on a thread of their own and
/// their durable write started as they are written): `create`, `begin`, `push_row`, `commit`.
pub struct ParquetFile {
    path: PathBuf,
    partial: PathBuf,
    file: Option<File>,
    writer: Option<SerializedFileWriter<BufWriter<File>>>,
    columns: Vec<Vec<f64>>,
}

fn other(e: impl std::error::Error + Send + Sync + 'static) -> io::Error {
    io::Error::other(e)
}

impl ParquetFile {
    pub fn create(path: &Path) -> io::Result<ParquetFile> {
        let partial = partial_path(path);
        let file = File::create(&partial)?;
        Ok(ParquetFile {
            path: path.to_path_buf(),
            partial,
            file: Some(file),
            writer: None,
            columns: Vec::new(),
        })
    }

    pub fn begin(&mut self, names: &[String]) -> io::Result<()> {
        let file = self.file.take().expect("begun once");
        let mut fields = Vec::with_capacity(names.len() + 1);
        for n in std::iter::once("time").chain(names.iter().map(String::as_str)) {
            fields.push(Arc::new(
                Type::primitive_type_builder(n, PhysicalType::DOUBLE)
                    .with_repetition(Repetition::REQUIRED)
                    .build()
                    .map_err(other)?,
            ));
        }
        let schema = Arc::new(
            Type::group_type_builder("results")
                .with_fields(fields)
                .build()
                .map_err(other)?,
        );
        let props = WriterProperties::builder()
            .set_created_by("kneebench baseline".into())
            .set_dictionary_enabled(false)
            .set_statistics_enabled(EnabledStatistics::None)
            .set_column_statistics_enabled(ColumnPath::from("time"), EnabledStatistics::Chunk)
            .build();
        self.writer = Some(
            SerializedFileWriter::new(
                BufWriter::with_capacity(1 << 20, file),
                schema,
                Arc::new(props),
            )
            .map_err(other)?,
        );
        self.columns = (0..=names.len())
            .map(|_| Vec::with_capacity(ROW_GROUP_ROWS))
            .collect();
        Ok(())
    }

    #[inline]
    pub fn push_row(&mut self, time: f64, values: &[f64]) -> io::Result<()> {
        assert_eq!(values.len() + 1, self.columns.len());
        self.columns[0].push(time);
        for (c, &v) in self.columns[1..].iter_mut().zip(values) {
            c.push(v);
        }
        if self.columns[0].len() >= ROW_GROUP_ROWS {
            self.write_group()?;
        }
        Ok(())
    }

    fn write_group(&mut self) -> io::Result<()> {
        if self.columns.first().is_none_or(Vec::is_empty) {
            return Ok(());
        }
        let writer = self.writer.as_mut().expect("begun");
        let mut group = writer.next_row_group().map_err(other)?;
        for values in &mut self.columns {
            let mut col = group.next_column().map_err(other)?.expect("a column");
            col.typed::<DoubleType>()
                .write_batch(values, None, None)
                .map_err(other)?;
            col.close().map_err(other)?;
            values.clear();
        }
        group.close().map_err(other)?;
        Ok(())
    }

    pub fn commit(mut self) -> io::Result<PathBuf> {
        self.write_group()?;
        let w = self.writer.take().expect("begun");
        let file = w
            .into_inner()
            .map_err(other)?
            .into_inner()
            .map_err(|e| e.into_error())?;
        file.sync_all()?;
        std::fs::rename(&self.partial, &self.path)?;
        Ok(self.path)
    }
}
