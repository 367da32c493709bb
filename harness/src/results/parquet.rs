//! The Parquet results file: a [`ResultSink`] writing one float64 column per signal after a
//! `time` column (Integer and Boolean signals as whole numbers), with key-value metadata (the
//! system, its parameters, the kneebench version, the FMUs' GUIDs).
//!
//! Rows are buffered per column as they come (one buffer holding every column of the row group,
//! on huge pages when it is big: `column_buffer`; the rows staged and stored eight at a time,
//! a whole cache line of each column: `parquet_group`)
//! and written in row groups of at most [`ROW_GROUP_ROWS`] rows (a run's announced rows shared
//! evenly between as few groups as hold them: `group_rows`): plain encoding, uncompressed (the
//! values of a recording are mostly full-precision doubles: Snappy saved a fifth of the bytes
//! and no time in the writers bench), one data page per column chunk. A chunk whose values
//! take at most 16 distinct values (a flag, a mode, a held parameter) is dictionary-encoded
//! (`parquet_dictionary`): its page then takes a few bytes instead of 8 per row.
//! Statistics (min and max per row group) are kept for `time` only, so that readers skip row
//! groups by time; the signals' statistics cost a sixth of the writer's own time and no reader
//! needs them. A file whose chunks are all plain is the one the `parquet` crate's
//! `SerializedFileWriter` writes without a dictionary, byte for byte (tested), but for one
//! fast path, in the `Encoder`: each signal's page goes to the file straight from the row
//! group's buffer, where the crate's column writer copies every value twice first (`time`
//! still goes through it, for its statistics).
//!
//! **Where the encoding runs** ([`EncodeOn`]): by default a full row group is handed to a
//! thread of the file's own, which encodes and writes it while the run fills the next one
//! (on two cores the simulation and the writer overlap); [`EncodeOn::Caller`] encodes in the
//! [`push_row`](ResultSink::push_row) that fills a group. Both write the same bytes (tested).
//! The handover waits until the thread takes the group (at most one group encoding while one
//! fills: the memory of two groups), and the emptied buffers come back for the next group.
//! The thread starts when it is first needed: a run that announces more rows than a group
//! holds ([`expect_rows`](ResultSink::expect_rows)) starts it before its first row, and it
//! makes and faults in the first group's buffer while the run starts its FMUs and the
//! second's while the run fills the first; otherwise
//! the first full group starts it; a file closed before its first group is full is encoded by
//! the caller, with no thread (and should a thread fail to start, the caller encodes). An
//! error of the thread (a full disk) is returned by the next handover, and by
//! [`commit`](ParquetFile::commit) or [`keep_partial`](ParquetFile::keep_partial): never
//! lost; a panic of the thread is an error too.
//!
//! A Parquet file is readable once its footer is written: [`ParquetFile::commit`] writes the
//! last row group and the footer into `<output>.partial`, syncs it and renames it into place;
//! [`ParquetFile::keep_partial`] closes it where it is, so a failed or stopped run's partial
//! file is a readable table of the rows so far. A file dropped without either keeps the row
//! groups written so far without a footer, and a crash of the process leaves a partial file
//! without a footer (unreadable); the master's periodic flush is not asked for (one row group
//! per second would fragment the file).

use std::fs::File;
use std::io::{self, Write};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use bytes::Bytes;
use parquet::basic::{
    Compression, Encoding, EncodingMask, PageType, Repetition, Type as PhysicalType,
};
use parquet::column::page::{CompressedPage, Page, PageWriter};
use parquet::column::writer::{ColumnCloseResult, ColumnWriter, get_column_writer};
use parquet::errors::ParquetError;
use parquet::file::metadata::page_index::PageIndexBuilder;
use parquet::file::metadata::{
    ColumnChunkMetaData, FileMetaData, KeyValue, OffsetIndexBuilder, PageEncodingStats,
    ParquetMetaDataBuilder, ParquetMetaDataWriter, RowGroupMetaData,
};
use parquet::file::page_index::column_index::ColumnIndexMetaData;
use parquet::file::page_index::offset_index::OffsetIndexMetaData;
use parquet::file::properties::{
    EnabledStatistics, WriterProperties, WriterPropertiesBuilder, WriterPropertiesPtr,
};
use parquet::file::writer::{SerializedPageWriter, TrackedWrite};
use parquet::schema::types::{ColumnDescPtr, ColumnPath, SchemaDescPtr, SchemaDescriptor, Type};

pub use super::background::EncodeOn;
use super::background::{Background, BlockEncoder, Prepare, closed_error};
use super::column_buffer::ColumnBuffer;
use super::csv::{check_output_path, partial_path};
use super::parquet_dictionary::{Dictionary, dictionary_of};
use super::parquet_group::Group;
use super::parquet_sink::FileSink;
use super::{ColumnKind, ResultSink, ResultsError};

/// The most rows a row group takes: a column's page of 8192 doubles is 64 KiB, under glibc's threshold
/// for mapping an allocation on its own (128 KiB), so the column writer's buffers are taken
/// from the heap and reused from one row group to the next instead of being mapped and
/// faulted in afresh (the rows' own buffer, one per group, is reused as a whole):
/// `kneebench run` recording every output of the SEA scenario for 100 s takes 2 400 page faults instead of 13 900 with 65 536 rows (53 MB of
/// buffers instead of 6.6 MB), 36 400 with each column handed over in one batch.
pub const ROW_GROUP_ROWS: usize = 8192;

/// The rows a group begun once `pushed` rows are in takes: [`ROW_GROUP_ROWS`] if the run has
/// announced no rows still to come (or has gone past them), else the rows still announced
/// shared evenly between as few groups as can hold them (10,001 rows: two groups of 5,001
/// and 5,000, not 8,192 and 1,809).
///
/// Even groups make the first group, which the run fills before anything is written, as
/// small as the group count allows: its buffer is faulted in on the run's thread and the
/// writer thread starts on it sooner, so less of the writing is left once the run ends.
fn group_rows(announced: Option<u64>, pushed: u64) -> usize {
    match announced {
        Some(rows) if rows > pushed => {
            let left = rows - pushed;
            let groups = left.div_ceil(ROW_GROUP_ROWS as u64);
            left.div_ceil(groups) as usize
        }
        _ => ROW_GROUP_ROWS,
    }
}

fn io_error(path: &Path, e: impl std::error::Error + Send + Sync + 'static) -> ResultsError {
    ResultsError::Io {
        path: path.to_path_buf(),
        source: io::Error::other(e),
    }
}

/// A row group's buffer lent to its pages: the bytes of its columns as they are in memory,
/// which on a little-endian machine are the plain encoding of the doubles (Parquet's is
/// little endian).
struct GroupBytes(Arc<ColumnBuffer>);

impl AsRef<[u8]> for GroupBytes {
    fn as_ref(&self) -> &[u8] {
        let values: &[f64] = &self.0;
        // SAFETY: the pointer and length describe the initialised doubles of `values` as
        // bytes: an f64 has no padding and every byte is initialised, u8 needs no alignment,
        // and the borrow lives as long as `self`, which owns the buffer.
        unsafe { std::slice::from_raw_parts(values.as_ptr().cast::<u8>(), size_of_val(values)) }
    }
}

/// Writes the file the way the `parquet` crate's `SerializedFileWriter` does (the same
/// bytes, tested against it), with the signals' pages written straight from the row group's
/// buffer: the crate's column writer copies every value twice on its way to the file (into
/// its plain encoder's buffer, then into the page with its levels), which on this machine
/// was a third of the writer's own time. `time` (the one column with statistics) and every
/// column on a big-endian machine go through the crate's column writer.
struct Encoder {
    /// The partial file, behind the crate's byte counter (page offsets) and write buffer.
    sink: Option<TrackedWrite<FileSink>>,
    /// The same file, for the write-back and the final sync.
    file: Arc<File>,
    failure: Arc<Mutex<Option<io::Error>>>,
    schema: SchemaDescPtr,
    props: WriterPropertiesPtr,
    row_groups: Vec<RowGroupMetaData>,
    /// Per row group and column: the page locations (every column has them, as the crate
    /// writes them by default) and the page statistics (none here: `time`'s are per chunk).
    offset_indexes: Vec<Vec<Option<OffsetIndexMetaData>>>,
    column_indexes: Vec<Vec<Option<ColumnIndexMetaData>>>,
    partial: PathBuf,
}

impl Encoder {
    /// Starts the file (its magic bytes) with `schema` and `props`.
    fn start(
        file: File,
        schema: SchemaDescPtr,
        props: WriterPropertiesPtr,
        partial: PathBuf,
    ) -> Result<Encoder, ResultsError> {
        let file = Arc::new(file);
        let failure = Arc::new(Mutex::new(None));
        let mut sink = TrackedWrite::new(FileSink::new(Arc::clone(&file), Arc::clone(&failure)));
        // Parquet's magic bytes, which open the file (and close it, after the footer).
        sink.write_all(b"PAR1").map_err(|e| io_error(&partial, e))?;
        Ok(Encoder {
            sink: Some(sink),
            file,
            failure,
            schema,
            props,
            row_groups: Vec::new(),
            offset_indexes: Vec::new(),
            column_indexes: Vec::new(),
            partial,
        })
    }

    fn sink(&mut self) -> Result<&mut TrackedWrite<FileSink>, ParquetError> {
        self.sink
            .as_mut()
            .ok_or_else(|| ParquetError::General("the Parquet file is closed".into()))
    }

    /// Writes `group` as one row group (nothing if it has no row) and empties it, its buffer
    /// kept.
    fn write_group(&mut self, group: &mut Group) -> Result<(), ResultsError> {
        if group.rows == 0 {
            return Ok(());
        }
        group.settle();
        let rows = std::mem::take(&mut group.rows);
        // The buffer is lent to the pages (no copy) and taken back once they are written;
        // the page writer keeps none of them, so the buffer is never shared by then.
        let buffer = Arc::new(std::mem::take(&mut group.values));
        let written = self.write_row_group(&buffer, group.stride(), rows);
        group.values =
            Arc::try_unwrap(buffer).unwrap_or_else(|shared| ColumnBuffer::on_heap(shared.to_vec()));
        written.map_err(|e| io_error(&self.partial, e))?;
        self.start_writeback()
    }

    /// Writes the first `rows` of each column of `buffer` (`stride` slots per column) as the
    /// next row group.
    fn write_row_group(
        &mut self,
        buffer: &Arc<ColumnBuffer>,
        stride: usize,
        rows: usize,
    ) -> Result<(), ParquetError> {
        let ordinal = i32::try_from(self.row_groups.len())
            .map_err(|_| ParquetError::General("too many row groups".into()))?;
        let file_offset = self.sink()?.bytes_written() as i64;
        let bytes = Bytes::from_owner(GroupBytes(Arc::clone(buffer)));
        let schema = Arc::clone(&self.schema);
        let mut closed = Vec::with_capacity(schema.num_columns());
        for (i, descr) in schema.columns().iter().enumerate() {
            let start = i * stride;
            let values = &buffer[start..start + rows];
            closed.push(if i > 0 && cfg!(target_endian = "little") {
                match dictionary_of(values) {
                    Some(dictionary) => self.write_dictionary(descr, dictionary, rows)?,
                    None => {
                        let page = bytes.slice(start * 8..(start + rows) * 8);
                        self.write_page(descr, page, rows)?
                    }
                }
            } else {
                self.write_column(descr, values)?
            });
        }
        let mut chunks = Vec::with_capacity(closed.len());
        let (mut offsets, mut indexes) = (Vec::new(), Vec::new());
        let mut total_uncompressed = 0;
        for c in closed {
            total_uncompressed += c.metadata.uncompressed_size();
            chunks.push(c.metadata);
            offsets.push(c.offset_index);
            indexes.push(c.column_index);
        }
        let group = RowGroupMetaData::builder(schema)
            .set_column_metadata(chunks)
            .set_total_byte_size(total_uncompressed)
            .set_num_rows(rows as i64)
            .set_sorting_columns(self.props.sorting_columns().cloned())
            .set_ordinal(ordinal)
            .set_file_offset(file_offset)
            .build()?;
        self.row_groups.push(group);
        self.offset_indexes.push(offsets);
        self.column_indexes.push(indexes);
        Ok(())
    }

    /// One column chunk through the crate's column writer (the plain path).
    fn write_column(
        &mut self,
        descr: &ColumnDescPtr,
        values: &[f64],
    ) -> Result<ColumnCloseResult, ParquetError> {
        let props = Arc::clone(&self.props);
        let page_writer = Box::new(SerializedPageWriter::new(self.sink()?));
        let mut writer = get_column_writer(Arc::clone(descr), props, page_writer);
        match &mut writer {
            ColumnWriter::DoubleColumnWriter(w) => {
                w.write_batch(values, None, None)?;
            }
            _ => return Err(ParquetError::General("a column is not float64".into())),
        }
        writer.close()
    }

    /// One column chunk of one plain page, `page` holding its `rows` values as bytes, with
    /// the metadata the crate's column writer gives such a chunk (no statistics).
    fn write_page(
        &mut self,
        descr: &ColumnDescPtr,
        page: Bytes,
        rows: usize,
    ) -> Result<ColumnCloseResult, ParquetError> {
        let num_values = u32::try_from(rows)
            .map_err(|_| ParquetError::General("too many rows in a row group".into()))?;
        let size = page.len();
        let page = Page::DataPage {
            buf: page,
            num_values,
            encoding: Encoding::PLAIN,
            def_level_encoding: Encoding::RLE,
            rep_level_encoding: Encoding::RLE,
            statistics: None,
        };
        let mut page_writer = SerializedPageWriter::new(self.sink()?);
        let spec = page_writer.write_page(CompressedPage::new(page, size))?;
        page_writer.close()?;
        let mut offset_index = OffsetIndexBuilder::new();
        offset_index.append_row_count(rows as i64);
        offset_index.append_offset_and_size(spec.offset as i64, spec.compressed_size as i32);
        // The crate's writer lists RLE (its levels' encoding) whether or not there are levels.
        let encodings = [Encoding::PLAIN, Encoding::RLE];
        let metadata = ColumnChunkMetaData::builder(Arc::clone(descr))
            .set_compression(Compression::UNCOMPRESSED)
            .set_encodings_mask(EncodingMask::new_from_encodings(encodings.iter()))
            .set_page_encoding_stats(vec![PageEncodingStats {
                page_type: PageType::DATA_PAGE,
                encoding: Encoding::PLAIN,
                count: 1,
            }])
            .set_total_compressed_size(spec.compressed_size as i64)
            .set_total_uncompressed_size(spec.uncompressed_size as i64)
            .set_num_values(i64::from(num_values))
            .set_data_page_offset(spec.offset as i64)
            .set_dictionary_page_offset(None)
            .build()?;
        Ok(ColumnCloseResult {
            bytes_written: spec.bytes_written,
            rows_written: rows as u64,
            metadata,
            bloom_filter: None,
            column_index: None,
            offset_index: Some(offset_index.build()),
        })
    }

    /// One column chunk of a dictionary page and one data page of its `rows` indexes, with
    /// the metadata the crate's column writer gives such a chunk (no statistics).
    fn write_dictionary(
        &mut self,
        descr: &ColumnDescPtr,
        dictionary: Dictionary,
        rows: usize,
    ) -> Result<ColumnCloseResult, ParquetError> {
        let num_values = u32::try_from(rows)
            .map_err(|_| ParquetError::General("too many rows in a row group".into()))?;
        let Dictionary {
            page,
            entries,
            indexes,
        } = dictionary;
        let (page_size, indexes_size) = (page.len(), indexes.len());
        let mut page_writer = SerializedPageWriter::new(self.sink()?);
        let dictionary_page = Page::DictionaryPage {
            buf: Bytes::from(page),
            num_values: entries,
            encoding: Encoding::PLAIN,
            is_sorted: false,
        };
        let dictionary_spec =
            page_writer.write_page(CompressedPage::new(dictionary_page, page_size))?;
        let data_page = Page::DataPage {
            buf: Bytes::from(indexes),
            num_values,
            encoding: Encoding::RLE_DICTIONARY,
            def_level_encoding: Encoding::RLE,
            rep_level_encoding: Encoding::RLE,
            statistics: None,
        };
        let spec = page_writer.write_page(CompressedPage::new(data_page, indexes_size))?;
        page_writer.close()?;
        // The offset index lists the data pages only.
        let mut offset_index = OffsetIndexBuilder::new();
        offset_index.append_row_count(rows as i64);
        offset_index.append_offset_and_size(spec.offset as i64, spec.compressed_size as i32);
        let encodings = [Encoding::PLAIN, Encoding::RLE, Encoding::RLE_DICTIONARY];
        let metadata = ColumnChunkMetaData::builder(Arc::clone(descr))
            .set_compression(Compression::UNCOMPRESSED)
            .set_encodings_mask(EncodingMask::new_from_encodings(encodings.iter()))
            .set_page_encoding_stats(vec![
                PageEncodingStats {
                    page_type: PageType::DICTIONARY_PAGE,
                    encoding: Encoding::PLAIN,
                    count: 1,
                },
                PageEncodingStats {
                    page_type: PageType::DATA_PAGE,
                    encoding: Encoding::RLE_DICTIONARY,
                    count: 1,
                },
            ])
            .set_total_compressed_size(
                (dictionary_spec.compressed_size + spec.compressed_size) as i64,
            )
            .set_total_uncompressed_size(
                (dictionary_spec.uncompressed_size + spec.uncompressed_size) as i64,
            )
            .set_num_values(i64::from(num_values))
            .set_data_page_offset(spec.offset as i64)
            .set_dictionary_page_offset(Some(dictionary_spec.offset as i64))
            .build()?;
        Ok(ColumnCloseResult {
            bytes_written: dictionary_spec.bytes_written + spec.bytes_written,
            rows_written: rows as u64,
            metadata,
            bloom_filter: None,
            column_index: None,
            offset_index: Some(offset_index.build()),
        })
    }

    /// Hands the row groups written so far to the kernel and starts their write to the disk
    /// without waiting for it, so that the sync of [`finish`](Self::finish) waits only for
    /// the last ones: the durable write goes on while the run fills the next groups instead
    /// of all of it after the run (Linux's `sync_file_range`; elsewhere the sync does it all).
    fn start_writeback(&mut self) -> Result<(), ResultsError> {
        if let Some(sink) = self.sink.as_mut() {
            sink.flush().map_err(|e| io_error(&self.partial, e))?;
        }
        #[cfg(target_os = "linux")]
        {
            use std::os::fd::AsRawFd;
            let fd = self.file.as_raw_fd();
            // Its result is not an error of the file: it only starts the write early (a file
            // system may not support it), and a failed write to the disk is reported by the
            // `fsync` of `finish` all the same.
            // SAFETY: a plain system call on the file's open descriptor; offset 0 and length
            // 0 mean the whole file.
            let _ = unsafe { libc::sync_file_range(fd, 0, 0, libc::SYNC_FILE_RANGE_WRITE) };
        }
        Ok(())
    }

    /// Writes the page indexes and the footer (the crate's metadata writer, as its file
    /// writer does) and syncs the file.
    fn finish(mut self) -> Result<(), ResultsError> {
        let partial = self.partial.clone();
        let err = |e: ParquetError| io_error(&partial, e);
        let sink = self
            .sink
            .take()
            .ok_or_else(|| err(ParquetError::General("the Parquet file is closed".into())))?;
        let (groups, columns) = (self.row_groups.len(), self.schema.num_columns());
        let mut index = PageIndexBuilder::new(groups, columns);
        for (g, (offsets, indexes)) in self
            .offset_indexes
            .drain(..)
            .zip(self.column_indexes.drain(..))
            .enumerate()
        {
            for (c, (offset, column)) in offsets.into_iter().zip(indexes).enumerate() {
                if let Some(offset) = offset {
                    index.put_offset_index(offset, g, c);
                }
                if let Some(column) = column {
                    index.put_column_index(column, g, c);
                }
            }
        }
        let num_rows = self.row_groups.iter().map(RowGroupMetaData::num_rows).sum();
        let file_metadata = FileMetaData::new(
            self.props.writer_version().as_num(),
            num_rows,
            Some(self.props.created_by().to_string()),
            self.props.key_value_metadata().cloned(),
            Arc::clone(&self.schema),
            None,
        );
        let metadata = ParquetMetaDataBuilder::new(file_metadata)
            .set_row_groups(std::mem::take(&mut self.row_groups))
            .set_page_index(Some(Arc::new(index.build())))
            .build();
        ParquetMetaDataWriter::new_with_tracked(sink, &metadata)
            .with_write_path_in_schema(self.props.write_path_in_schema())
            .finish()
            .map_err(err)?;
        // The footer writer flushed its buffer as it was dropped: a failure there is here.
        let failure = self
            .failure
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .take();
        if let Some(e) = failure {
            return Err(io_error(&partial, e));
        }
        self.file.sync_all().map_err(|e| io_error(&partial, e))
    }
}

impl BlockEncoder for Encoder {
    type Block = Group;

    fn write_block(&mut self, group: &mut Group) -> Result<(), ResultsError> {
        self.write_group(group)
    }

    /// Nothing to do: a row group is handed to the kernel as it is written, and a file
    /// without its footer is unreadable anyway (the master's periodic flush is not asked for).
    fn flush(&mut self) -> Result<(), ResultsError> {
        Ok(())
    }

    fn finish(self) -> Result<(), ResultsError> {
        Encoder::finish(self)
    }
}

/// Where the row groups go.
enum Writer {
    /// [`EncodeOn::Caller`] (boxed: the crate's writer is large, and the file moves).
    Caller(Box<Encoder>),
    /// [`EncodeOn::Thread`] before its thread is started (see the module documentation).
    Idle(Box<Encoder>),
    /// [`EncodeOn::Thread`], started.
    Thread(Background<Encoder>),
    /// Closed, or failed: the error was returned once; later calls get this message.
    Done(Option<String>),
}

/// The Parquet file sink (see the [module documentation](self)).
pub struct ParquetFile {
    path: PathBuf,
    partial: PathBuf,
    encode_on: EncodeOn,
    /// The partial file until [`begin`](ResultSink::begin) hands it to the writer.
    file: Option<File>,
    writer: Option<Writer>,
    /// The row group being filled: `time`, then one buffer per column.
    columns: Group,
    /// The rows the run announced ([`expect_rows`](ResultSink::expect_rows)), if it did.
    announced: Option<u64>,
    metadata: Vec<(String, String)>,
    rows: u64,
}

impl std::fmt::Debug for ParquetFile {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ParquetFile")
            .field("path", &self.path)
            .field("encode_on", &self.encode_on)
            .field("rows", &self.rows)
            .finish()
    }
}

impl ParquetFile {
    /// Checks the output path and creates `<path>.partial`; nothing is written to `path`
    /// before [`commit`](Self::commit). Row groups are encoded on a thread of the file's own.
    pub fn create(path: &Path) -> Result<ParquetFile, ResultsError> {
        ParquetFile::create_encoding_on(path, EncodeOn::default())
    }

    /// [`create`](Self::create), the row groups encoded where `encode_on` says.
    pub fn create_encoding_on(
        path: &Path,
        encode_on: EncodeOn,
    ) -> Result<ParquetFile, ResultsError> {
        check_output_path(path)?;
        let partial = partial_path(path);
        let file = File::create(&partial).map_err(|source| ResultsError::Io {
            path: partial.clone(),
            source,
        })?;
        Ok(ParquetFile {
            path: path.to_path_buf(),
            partial,
            encode_on,
            file: Some(file),
            writer: None,
            columns: Group::default(),
            announced: None,
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

    /// The rows the group begun now takes ([`group_rows`]).
    fn next_group_rows(&self) -> usize {
        group_rows(self.announced, self.rows)
    }

    fn err(&self, e: impl std::error::Error + Send + Sync + 'static) -> ResultsError {
        io_error(&self.partial, e)
    }

    /// Writes the row group filled so far (a full one, in [`push_row`](ResultSink::push_row)).
    fn write_group(&mut self) -> Result<(), ResultsError> {
        let _ = self.start_thread(Vec::new());
        let (width, limit) = (self.columns.width, self.next_group_rows());
        match self.writer.as_mut() {
            Some(Writer::Caller(encoder)) => {
                let result = encoder.write_group(&mut self.columns);
                match &result {
                    // The group is lost either way (the file is unusable past a failed
                    // write): its buffers are emptied as the thread's path leaves them.
                    Err(e) => {
                        self.columns.rows = 0;
                        self.writer = Some(Writer::Done(Some(e.to_string())));
                    }
                    Ok(()) => {
                        let written = std::mem::take(&mut self.columns);
                        self.columns = Group::begun(Some(written), width, limit);
                    }
                }
                result
            }
            Some(Writer::Thread(background)) => {
                // A written group's buffers, else new ones.
                if background.send(std::mem::take(&mut self.columns)) {
                    // The thread has taken the group: the one before is back (or the one it
                    // made, or none: this is the first), so two groups are all the memory
                    // there is.
                    self.columns = Group::begun(background.spare(), width, limit);
                    return Ok(());
                }
                self.columns = Group::unmade(width);
                // The thread ended: its error.
                let Some(Writer::Thread(background)) = self.writer.take() else {
                    unreachable!("matched above")
                };
                let error = background.failure(&self.partial, "Parquet");
                self.writer = Some(Writer::Done(Some(error.to_string())));
                Err(error)
            }
            Some(Writer::Done(error)) => {
                Err(closed_error(&self.partial, "Parquet", error.as_deref()))
            }
            Some(Writer::Idle(_)) => unreachable!("started above"),
            None => Ok(()),
        }
    }

    /// Starts the writer thread of an [`Writer::Idle`] file, which first makes the groups
    /// `prepare` gives, in order; whether it started now (with them). A thread that cannot
    /// start leaves the caller encoding.
    fn start_thread(&mut self, prepare: Vec<Prepare<Group>>) -> bool {
        if !matches!(self.writer, Some(Writer::Idle(_))) {
            return false;
        }
        let Some(Writer::Idle(encoder)) = self.writer.take() else {
            unreachable!("matched above")
        };
        let (writer, started) = match Background::spawn(*encoder, "parquet-writer", prepare) {
            Ok(background) => (Writer::Thread(background), true),
            Err((encoder, _)) => (Writer::Caller(Box::new(encoder)), false),
        };
        self.writer = Some(writer);
        started
    }

    /// Room for the next row in a full group: the group's buffer made if it is not yet (the
    /// writer thread's first prepared one when it runs: [`expect_rows`](ResultSink::expect_rows)),
    /// else the group written and a new one begun.
    fn make_room(&mut self) -> Result<(), ResultsError> {
        if self.columns.capacity == 0 {
            let prepared = match &self.writer {
                Some(Writer::Thread(background)) => background.wait_spare(),
                _ => None,
            };
            // A thread that ended without it: made here (its error comes at the next handover).
            self.columns = Group::begun(prepared, self.columns.width, self.next_group_rows());
            Ok(())
        } else {
            self.write_group()
        }
    }

    /// Writes the last row group and the footer, syncs.
    fn close(&mut self) -> Result<(), ResultsError> {
        if self.writer.is_none() {
            // No row was ever begun: an empty table of just `time`.
            self.begin(&[], &[])?;
        }
        let last = std::mem::take(&mut self.columns);
        match self.writer.replace(Writer::Done(None)) {
            Some(Writer::Caller(mut encoder) | Writer::Idle(mut encoder)) => {
                let mut last = last;
                encoder.write_group(&mut last)?;
                encoder.finish()
            }
            Some(Writer::Thread(background)) => background.finish(last, &self.partial),
            Some(Writer::Done(error)) => {
                Err(closed_error(&self.partial, "Parquet", error.as_deref()))
            }
            None => unreachable!("begun above"),
        }
    }

    /// The file's schema (`time`, then `names`, float64 each) and properties (the metadata,
    /// plain encoding, statistics for `time` only), before the settings of speed alone.
    fn layout(
        &self,
        names: &[String],
    ) -> Result<(Arc<Type>, WriterPropertiesBuilder), ResultsError> {
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
            .set_column_statistics_enabled(ColumnPath::from("time"), EnabledStatistics::Chunk);
        Ok((schema, props))
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

impl Drop for ParquetFile {
    /// Dropped unclosed (a run that failed with an error): the writer thread, if any, writes
    /// the group it holds and ends, so that nothing writes the file after it is dropped.
    fn drop(&mut self) {
        if let Some(Writer::Thread(background)) = self.writer.take() {
            let _ = background.join(&self.partial);
        }
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
            return Err(self.err(io::Error::other("the Parquet file was begun twice")));
        };
        let (schema, props) = self.layout(names)?;
        let props = props
            // A column's values go to its encoder in one piece: in mini-batches (1024 by
            // default) its buffer grows by doubling, copying the page three more times.
            .set_write_batch_size(ROW_GROUP_ROWS)
            .build();
        let encoder = Encoder::start(
            file,
            Arc::new(SchemaDescriptor::new(schema)),
            Arc::new(props),
            self.partial.clone(),
        )?;
        self.writer = Some(match self.encode_on {
            EncodeOn::Caller => Writer::Caller(Box::new(encoder)),
            EncodeOn::Thread => Writer::Idle(Box::new(encoder)),
        });
        // Made for the rows the run announces, or at its first row.
        self.columns = Group::unmade(names.len() + 1);
        Ok(())
    }

    #[inline]
    fn push_row(&mut self, time: f64, values: &[f64]) -> Result<(), ResultsError> {
        if values.len() + 1 != self.columns.width {
            return Err(ResultsError::RowLength {
                expected: self.columns.width.saturating_sub(1),
                got: values.len(),
            });
        }
        if self.columns.is_full() {
            self.make_room()?;
        }
        self.columns.push(time, values);
        self.rows += 1;
        Ok(())
    }

    fn flush(&mut self) -> Result<(), ResultsError> {
        Ok(())
    }

    /// A run of more rows than one group holds starts the writer thread now, before its
    /// first step, and the thread makes and faults in the first two groups' buffers: the
    /// first while the run instantiates and initializes its FMUs (its first row takes it
    /// from the thread), the second while the run fills the first. Handing the first group
    /// over then allocates nothing, and the run's thread never waits for the kernel to zero
    /// a buffer (up to 20 ms on this machine's virtual CPUs when the host backs fresh huge
    /// pages) unless its first row comes before the thread has made the first one.
    ///
    /// The groups are made for the rows announced (`group_rows`: shared evenly between as
    /// few groups as hold them), each buffer for its group's rows alone. A run of one group,
    /// or a file encoded by the caller, has its buffer made here.
    fn expect_rows(&mut self, rows: u64) {
        let width = self.columns.width;
        if width == 0 || self.announced.is_some() {
            return;
        }
        self.announced = Some(rows.saturating_add(self.rows));
        let unmade = self.columns.capacity == 0;
        let first = if unmade {
            self.next_group_rows()
        } else {
            self.columns.limit
        };
        let second = self.rows + first as u64;
        let mut first_on_thread = false;
        if self.announced > Some(second) {
            let rows = group_rows(self.announced, second);
            let mut prepare: Vec<Prepare<Group>> = Vec::with_capacity(2);
            if unmade {
                prepare.push(Box::new(move || Group::new(width, first)));
            }
            prepare.push(Box::new(move || Group::new(width, rows)));
            first_on_thread = self.start_thread(prepare) && unmade;
        }
        if unmade && !first_on_thread {
            self.columns = Group::new(width, first);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use parquet::file::reader::{FileReader, SerializedFileReader};

    /// The groups of a run that announced its rows: as few as hold them, even (one row apart
    /// at most), none over [`ROW_GROUP_ROWS`]; past the announcement, full groups.
    #[test]
    fn announced_rows_make_as_few_even_groups_as_hold_them() {
        let groups_of = |announced: u64| {
            let (mut pushed, mut groups) = (0, Vec::new());
            while pushed < announced {
                let rows = group_rows(Some(announced), pushed);
                groups.push(rows);
                pushed += rows as u64;
            }
            groups
        };
        let full = ROW_GROUP_ROWS;
        assert_eq!(groups_of(10_001), [5_001, 5_000]);
        assert_eq!(groups_of(full as u64), [full]);
        assert_eq!(groups_of(full as u64 + 1), [full / 2 + 1, full / 2]);
        assert_eq!(groups_of(5), [5]);
        for announced in [
            1,
            2,
            999,
            8_191,
            8_192,
            8_193,
            16_384,
            16_385,
            100_001,
            1 << 20,
        ] {
            let groups = groups_of(announced);
            assert_eq!(
                groups.len() as u64,
                announced.div_ceil(full as u64),
                "{announced}"
            );
            assert_eq!(
                groups.iter().sum::<usize>() as u64,
                announced,
                "{announced}"
            );
            let (min, max) = (groups.iter().min(), groups.iter().max());
            assert!(max.unwrap() - min.unwrap() <= 1, "{announced}: {groups:?}");
            assert!(*max.unwrap() <= full, "{announced}");
        }
        assert_eq!(group_rows(Some(10), 10), full);
        assert_eq!(group_rows(Some(10), 25), full);
        assert_eq!(group_rows(None, 0), full);
    }

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

#[cfg(test)]
mod thread_tests {
    use super::*;
    use std::io::BufWriter;

    use parquet::data_type::DoubleType;
    use parquet::file::writer::SerializedFileWriter;

    use crate::results::test_rows::row;

    fn write(path: &Path, encode_on: EncodeOn, rows: usize, columns: usize, commit: bool) {
        write_announced(path, encode_on, rows, columns, commit, true);
    }

    /// [`write`], the rows announced first as the master does (`announce`) or not (a
    /// library caller may not).
    fn write_announced(
        path: &Path,
        encode_on: EncodeOn,
        rows: usize,
        columns: usize,
        commit: bool,
        announce: bool,
    ) {
        let mut f = ParquetFile::create_encoding_on(path, encode_on).unwrap();
        f.set_metadata(vec![("kneebench.system".into(), "test".into())]);
        let names: Vec<String> = (0..columns).map(|c| format!("c{c}")).collect();
        f.begin(&names, &vec![ColumnKind::Real; columns]).unwrap();
        if announce {
            // A run of more than a group starts the writer thread now, which makes the
            // first two buffers.
            f.expect_rows(rows as u64);
        }
        assert_eq!(
            matches!(f.writer, Some(Writer::Thread(_))),
            announce && encode_on == EncodeOn::Thread && rows > ROW_GROUP_ROWS,
            "{rows} rows, {encode_on:?}, announced {announce}"
        );
        for k in 0..rows {
            let (t, v) = row(k, columns);
            f.push_row(t, &v).unwrap();
        }
        if commit {
            f.commit().unwrap();
        } else {
            f.keep_partial().unwrap();
        }
    }

    /// The groups are made for the rows announced (even groups, each buffer for its group's
    /// rows alone), and a run going on past the rows it announced still writes every row, in
    /// full groups again.
    #[test]
    fn groups_are_made_for_the_rows_announced() {
        use super::super::parquet_group::{COLUMN_PADDING, PAGE_SLOTS};
        use parquet::file::reader::{FileReader, SerializedFileReader};
        use parquet::record::RowAccessor;
        let dir = tempfile::tempdir().unwrap();
        let begun = |encode_on, announced: u64| {
            let name = format!("{encode_on:?}-{announced}.parquet");
            let mut f = ParquetFile::create_encoding_on(&dir.path().join(name), encode_on).unwrap();
            f.begin(&["x".to_string()], &[ColumnKind::Real]).unwrap();
            f.expect_rows(announced);
            f
        };
        for encode_on in [EncodeOn::Thread, EncodeOn::Caller] {
            let f = begun(encode_on, 100);
            assert_eq!((f.columns.capacity, f.columns.limit), (100, 100));
            // 100 rows take a page per column, and a cache line past it.
            assert_eq!(f.columns.values.len(), 2 * (PAGE_SLOTS + COLUMN_PADDING));

            // One row more than a group holds: two even groups, 4,105 and 4,104 rows.
            let announced = ROW_GROUP_ROWS + 17;
            let (first, second) = (announced.div_ceil(2), announced / 2);
            let mut f = begun(encode_on, announced as u64);
            // The writer thread makes the first group's buffer too, while the run starts its
            // FMUs: the caller holds none before its first row (the caller encoding makes it).
            let made_by_caller = if encode_on == EncodeOn::Thread {
                0
            } else {
                first
            };
            assert_eq!(f.columns.capacity, made_by_caller, "{encode_on:?}");
            f.push_row(0.0, &[1.0]).unwrap();
            assert_eq!((f.columns.capacity, f.columns.limit), (first, first));
            for k in 1..=first {
                f.push_row(k as f64, &[1.0]).unwrap();
            }
            // The caller reuses its buffer; the thread made one for the last group's rows.
            let capacity = if encode_on == EncodeOn::Thread {
                second
            } else {
                first
            };
            assert_eq!((f.columns.capacity, f.columns.limit), (capacity, second));

            // 10 announced, 25 pushed: groups of 10 then a full one.
            let mut f = begun(encode_on, 10);
            for k in 0..25 {
                f.push_row(k as f64, &[k as f64]).unwrap();
            }
            assert_eq!(f.columns.limit, ROW_GROUP_ROWS, "{encode_on:?}");
            let path = f.commit().unwrap();
            let file = SerializedFileReader::new(File::open(&path).unwrap()).unwrap();
            let groups: Vec<i64> = file
                .metadata()
                .row_groups()
                .iter()
                .map(RowGroupMetaData::num_rows)
                .collect();
            assert_eq!(groups, [10, 15], "{encode_on:?}");
            let read: Vec<f64> = file
                .get_row_iter(None)
                .unwrap()
                .map(|r| r.unwrap().get_double(1).unwrap())
                .collect();
            assert_eq!(read, (0..25).map(f64::from).collect::<Vec<_>>());
        }
    }

    /// A run that announces its rows takes no page fault on its own thread to store them: the
    /// writer thread's two buffers are made and faulted in before the first row (where the
    /// kernel populates a mapping on request, Linux 5.14 and later), so that a run pacing the
    /// real bench is not stopped by the kernel zeroing (or compacting) pages for its rows.
    /// Counted with the thread's own minor faults: 1,600 per buffer without it.
    #[test]
    #[cfg(target_os = "linux")]
    fn storing_the_rows_of_an_announced_run_faults_in_no_page() {
        let minor_faults = || {
            // SAFETY: getrusage writes the struct it is given, zeroed beforehand.
            let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
            assert_eq!(
                unsafe { libc::getrusage(libc::RUSAGE_THREAD, &mut usage) },
                0
            );
            usage.ru_minflt
        };
        if !Group::new(102, ROW_GROUP_ROWS).values.is_populated() {
            eprintln!("skipped: this kernel does not populate a mapping on request");
            return;
        }
        let dir = tempfile::tempdir().unwrap();
        let mut f = ParquetFile::create(&dir.path().join("t.parquet")).unwrap();
        let names: Vec<String> = (0..101).map(|c| format!("c{c}")).collect();
        f.begin(&names, &[ColumnKind::Real; 101]).unwrap();
        let rows = 2 * ROW_GROUP_ROWS + 100;
        f.expect_rows(rows as u64);
        let row = vec![1.5; 101];
        let before = minor_faults();
        for k in 0..rows {
            f.push_row(k as f64, &row).unwrap();
        }
        let faults = minor_faults() - before;
        f.commit().unwrap();
        // A few for the handovers' own bookkeeping; a buffer faulted in by its rows is 1,600.
        assert!(faults < 100, "{faults} page faults storing {rows} rows");
    }

    /// The writer thread's file equals the caller's encoding of the same rows byte for byte
    /// (so every value reads back with the same bits), committed or kept partial, for full row
    /// groups, a short last one, and no row at all; the thread started before the first row
    /// (the rows announced) or by the first full group (not announced), or never (fewer
    /// rows than a group).
    #[test]
    fn the_writer_thread_writes_the_callers_bytes() {
        let dir = tempfile::tempdir().unwrap();
        for (rows, commit, announce) in [
            (3 * ROW_GROUP_ROWS + 17, true, true),
            (3 * ROW_GROUP_ROWS + 17, true, false),
            (2 * ROW_GROUP_ROWS, false, true),
            (2 * ROW_GROUP_ROWS, false, false),
            (ROW_GROUP_ROWS, true, true),
            (ROW_GROUP_ROWS + 17, true, true),
            (5, true, true),
            (0, true, true),
        ] {
            let thread = dir.path().join("thread.parquet");
            let caller = dir.path().join("caller.parquet");
            write_announced(&thread, EncodeOn::Thread, rows, 13, commit, announce);
            // Announced rows make even groups, unannounced ones full groups: the caller's
            // file is written the same way.
            write_announced(&caller, EncodeOn::Caller, rows, 13, commit, announce);
            let read = |p: &Path| {
                let p = if commit {
                    p.to_path_buf()
                } else {
                    partial_path(p)
                };
                std::fs::read(p).unwrap()
            };
            let (a, b) = (read(&thread), read(&caller));
            assert!(
                a.len() > 8 && a == b,
                "{rows} rows, commit {commit}, announced {announce}"
            );
        }
    }

    /// The plain path: the `parquet` crate's column writer with its default batches, through a
    /// 1 MiB buffer, in the caller's thread, no early write-back, one sync at the end.
    fn write_plain(path: &Path, rows: usize, columns: usize) {
        let mut f = ParquetFile::create(path).unwrap();
        f.set_metadata(vec![("kneebench.system".into(), "test".into())]);
        let names: Vec<String> = (0..columns).map(|c| format!("c{c}")).collect();
        let (schema, props) = f.layout(&names).unwrap();
        let file = File::create(&f.partial).unwrap();
        let mut w = SerializedFileWriter::new(
            BufWriter::with_capacity(1 << 20, file),
            schema,
            Arc::new(props.build()),
        )
        .unwrap();
        let mut group: Vec<Vec<f64>> = vec![Vec::new(); columns + 1];
        let flush = |group: &mut Vec<Vec<f64>>, w: &mut SerializedFileWriter<BufWriter<File>>| {
            if group[0].is_empty() {
                return;
            }
            let mut g = w.next_row_group().unwrap();
            for values in group.iter_mut() {
                let mut col = g.next_column().unwrap().unwrap();
                col.typed::<DoubleType>()
                    .write_batch(values, None, None)
                    .unwrap();
                col.close().unwrap();
                values.clear();
            }
            g.close().unwrap();
        };
        // The groups of a run that announced its rows, as `write` does.
        let mut group_start = 0;
        for k in 0..rows {
            let (t, v) = row(k, columns);
            group[0].push(t);
            for (c, x) in group[1..].iter_mut().zip(v) {
                c.push(x);
            }
            if group[0].len() == group_rows(Some(rows as u64), group_start) {
                flush(&mut group, &mut w);
                group_start = k as u64 + 1;
            }
        }
        flush(&mut group, &mut w);
        w.into_inner()
            .unwrap()
            .into_inner()
            .unwrap()
            .sync_all()
            .unwrap();
        std::fs::rename(&f.partial, path).unwrap();
        // The ParquetFile only lent its path and layout: never begun, nothing to close.
        f.file = None;
    }

    /// The fast paths (the signals' pages written straight from the row group's buffer, one
    /// batch per column, the small write buffer, the early write-back, the thread) write the
    /// plain path's bytes: the crate's own file and column writers.
    #[test]
    fn the_fast_paths_write_the_plain_bytes() {
        // 101 signals take a buffer mapped on huge pages (the fast path), the 3 of
        // `the_writer_thread_keeps_every_bit` one on the heap.
        #[cfg(target_os = "linux")]
        assert!(
            Group::new(102, ROW_GROUP_ROWS).values.is_mapped()
                && !Group::new(4, ROW_GROUP_ROWS).values.is_mapped()
        );
        let dir = tempfile::tempdir().unwrap();
        for rows in [2 * ROW_GROUP_ROWS + 1000, 7] {
            let plain = dir.path().join("plain.parquet");
            write_plain(&plain, rows, 101);
            let plain = std::fs::read(&plain).unwrap();
            for encode_on in [EncodeOn::Thread, EncodeOn::Caller] {
                let fast = dir.path().join("fast.parquet");
                write(&fast, encode_on, rows, 101, true);
                assert!(
                    std::fs::read(&fast).unwrap() == plain,
                    "{rows} rows, {encode_on:?}"
                );
            }
        }
    }

    /// The row groups' values as the `parquet` crate reads them back: every bit of the rows.
    #[test]
    fn the_writer_thread_keeps_every_bit() {
        use parquet::file::reader::SerializedFileReader;
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("t.parquet");
        let rows = ROW_GROUP_ROWS + 3;
        write(&path, EncodeOn::Thread, rows, 3, true);
        let read = rows_as_bits(&SerializedFileReader::new(File::open(&path).unwrap()).unwrap());
        assert_eq!(read.len(), rows);
        for (k, got) in read.iter().enumerate() {
            let (t, v) = row(k, 3);
            let want: Vec<u64> = std::iter::once(t).chain(v).map(f64::to_bits).collect();
            assert_eq!(got, &want, "row {k}");
        }
    }

    /// Every row of the file as the crate's record reader gives it, each value's bits.
    fn rows_as_bits(
        reader: &parquet::file::serialized_reader::SerializedFileReader<File>,
    ) -> Vec<Vec<u64>> {
        use parquet::file::reader::FileReader;
        use parquet::record::Field;
        reader
            .get_row_iter(None)
            .unwrap()
            .map(|record| {
                record
                    .unwrap()
                    .get_column_iter()
                    .map(|(_, f)| match f {
                        Field::Double(x) => x.to_bits(),
                        other => panic!("{other:?}"),
                    })
                    .collect()
            })
            .collect()
    }

    /// Columns of few values (a constant, a flag, a three-level chatter, signed zeros and a
    /// NaN) are dictionary-encoded, chunk by chunk (a column varying in one row group only is
    /// plain there), and every row reads back bit for bit through the crate's reader, page
    /// index included; the file is smaller than its plain twin by about those columns.
    #[test]
    fn few_valued_columns_are_dictionaries_and_keep_every_bit() {
        use parquet::file::reader::{FileReader, SerializedFileReader};
        use parquet::file::serialized_reader::ReadOptionsBuilder;
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("d.parquet");
        let rows = 2 * ROW_GROUP_ROWS + 100;
        let values = |k: usize| {
            [
                7.25,
                f64::from(k % 1000 < 300),
                [-1.0, 0.0, 1.0][k % 3],
                [0.0, -0.0, f64::NAN][(k / 5) % 3],
                (k as f64).sin(),
                // Constant in the first row group, varying after.
                if k < ROW_GROUP_ROWS { 3.0 } else { k as f64 },
            ]
        };
        let names: Vec<String> = (0..6).map(|c| format!("c{c}")).collect();
        let mut f = ParquetFile::create_encoding_on(&path, EncodeOn::Thread).unwrap();
        f.begin(&names, &[ColumnKind::Real; 6]).unwrap();
        for k in 0..rows {
            f.push_row(k as f64, &values(k)).unwrap();
        }
        f.commit().unwrap();
        let options = ReadOptionsBuilder::new().with_page_index().build();
        let reader =
            SerializedFileReader::new_with_options(File::open(&path).unwrap(), options).unwrap();
        let metadata = reader.metadata();
        for (g, group) in metadata.row_groups().iter().enumerate() {
            let dictionaries: Vec<bool> = (1..7)
                .map(|c| group.column(c).dictionary_page_offset().is_some())
                .collect();
            let last = g == 0;
            assert_eq!(
                dictionaries,
                [true, true, true, true, false, last],
                "group {g}"
            );
            let indexes = metadata.page_index_for_row_group(g);
            for c in 0..7 {
                let index = indexes.offset_index(c).unwrap();
                let chunk = group.column(c);
                assert_eq!(index.page_locations().len(), 1);
                assert_eq!(
                    index.page_locations()[0].offset,
                    chunk.data_page_offset(),
                    "group {g} column {c}"
                );
            }
        }
        let read = rows_as_bits(&reader);
        assert_eq!(read.len(), rows);
        for (k, got) in read.iter().enumerate() {
            let want: Vec<u64> = std::iter::once(k as f64)
                .chain(values(k))
                .map(f64::to_bits)
                .collect();
            assert_eq!(got, &want, "row {k}");
        }
        // Plain, the four few-valued columns and the fifth's first chunk would take 8 bytes
        // per value.
        let plain_bytes = rows * 7 * 8;
        let size = std::fs::metadata(&path).unwrap().len() as usize;
        assert!(size < plain_bytes - 4 * rows * 8, "{size} of {plain_bytes}");
    }

    /// A file whose writes fail (`/dev/full`: no space left) with `columns` columns.
    fn full_disk(dir: &Path, encode_on: EncodeOn, columns: usize) -> ParquetFile {
        let mut f = ParquetFile::create_encoding_on(&dir.join("full.parquet"), encode_on).unwrap();
        f.file = Some(
            std::fs::OpenOptions::new()
                .write(true)
                .open("/dev/full")
                .unwrap(),
        );
        let names: Vec<String> = (0..columns).map(|c| format!("c{c}")).collect();
        f.begin(&names, &vec![ColumnKind::Real; columns]).unwrap();
        f
    }

    fn assert_no_space(e: &ResultsError) {
        let text = format!("{e}: {:?}", std::error::Error::source(e));
        assert!(text.contains("No space left"), "{text}");
    }

    /// A write that fails on the writer thread is returned by the handover of the next row
    /// group (the first group's write fails; the caller learns it when it hands over the
    /// second), in the caller's thread by the push of the row after the first group's last
    /// (a full group is written when the next row needs its room); then the commit is an
    /// error too: never an Ok over lost rows.
    #[test]
    fn a_failed_write_is_returned_never_lost() {
        let dir = tempfile::tempdir().unwrap();
        for (encode_on, failing_group) in [(EncodeOn::Thread, 2), (EncodeOn::Caller, 1)] {
            let mut f = full_disk(dir.path(), encode_on, 3);
            let failing_row = failing_group * ROW_GROUP_ROWS;
            for k in 0..failing_row {
                f.push_row(k as f64, &[1.0, 2.0, 3.0]).unwrap();
            }
            let e = f.push_row(0.0, &[1.0, 2.0, 3.0]).unwrap_err();
            assert_no_space(&e);
            f.push_row(0.0, &[1.0, 2.0, 3.0]).unwrap();
            let later = f.commit().unwrap_err().to_string();
            assert!(later.contains("an earlier write failed"), "{later}");
        }
        // The error of the last group, written by commit, is commit's.
        for encode_on in [EncodeOn::Thread, EncodeOn::Caller] {
            let mut f = full_disk(dir.path(), encode_on, 3);
            f.push_row(0.0, &[1.0, 2.0, 3.0]).unwrap();
            assert_no_space(&f.keep_partial().unwrap_err());
        }
    }
}
