//! Streamed CSV: [`CsvWriter`] formats rows as they come (one buffered pass, shortest
//! round-trip floats), [`CsvFile`] is the crash-safe file sink of `kneebench run --output`.
//!
//! # The file protocol of [`CsvFile`]
//!
//! - [`CsvFile::create`] checks the output before any row exists: the directory must exist,
//!   the output must not be a directory, and `<output>.partial` (in the same directory) must
//!   be creatable; that file receives every row.
//! - Rows are buffered (64 KiB) and written out by [`ResultSink::flush`], which the master
//!   calls at least once per second of wall time and at the end of the run: a process that
//!   dies leaves `<output>.partial` with every row up to the last flush, each row complete
//!   (a cut line can only be the last one).
//! - By default the rows are formatted on a thread of the file's own ([`EncodeOn`]): a row
//!   pushed is a copy of its values into a block, full blocks are handed to the thread, and
//!   the formatting overlaps the run on another core (`kneebench run` recording every output
//!   of the SEA scenario: about 1.5x less wall time). A flush hands the partly filled block
//!   over and returns once the thread has written it: the promise above is unchanged. The
//!   thread starts with the first full block; a caller in a real-time scheduling class then
//!   (a paced run's stepping thread, which must never wait for a normally scheduled one), or
//!   a thread that cannot start, leaves the formatting in the caller. The bytes are those of
//!   the caller's formatting ([`EncodeOn::Caller`]), tested.
//! - With [`CsvFile::write_through`] every row is handed to the kernel as it is recorded (one
//!   `write` per row): a process killed at any instant, even with SIGKILL, leaves every row
//!   it recorded (not a power loss: that needs the sync of the commit). For paced real-time
//!   runs (the bench at 1 kHz) the cost, a system call per row, is small against the period.
//! - [`CsvFile::commit`] flushes, syncs and renames `<output>.partial` to `<output>` (atomic
//!   within the directory). [`CsvFile::keep_partial`] flushes and leaves the partial file for
//!   a run that failed or was stopped: an earlier `<output>` is never truncated or replaced by
//!   an incomplete run.

use std::ffi::OsString;
use std::fs::File;
use std::io::{self, Write};
use std::path::{Path, PathBuf};

pub use super::background::EncodeOn;
use super::background::{Background, BlockEncoder, closed_error};
use super::{ColumnKind, ResultSink, ResultsError};

/// Bytes gathered before they are handed to the underlying writer (always at the end of a
/// row: the writer only ever receives whole rows).
const BUFFER: usize = 64 * 1024;

/// Formats rows as CSV into a writer: header `time,<names>`, `Real` values in the shortest
/// form that parses back to the same bits, `Integer` and `Boolean` values as integers.
///
/// One pass: each value is formatted straight into the writer's own buffer (no line buffer,
/// no allocation per row or value), and whole rows are handed to the underlying writer once
/// 64 KiB are gathered, so `out` needs no buffering of its own. Reals are written by
/// `push_real` (the Żmij algorithm: the shortest round trip, as ryu, several times
/// faster).
pub struct CsvWriter<W: Write> {
    out: W,
    kinds: Vec<ColumnKind>,
    /// Formatted rows not yet handed to `out`.
    pending: Vec<u8>,
    floats: zmij::Buffer,
}

impl<W: Write> std::fmt::Debug for CsvWriter<W> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("CsvWriter")
            .field("kinds", &self.kinds)
            .finish_non_exhaustive()
    }
}

impl<W: Write> CsvWriter<W> {
    /// A writer into `out` (unbuffered is fine: whole rows are handed to it in blocks of
    /// about 64 KiB, and by [`flush`](Self::flush)).
    pub fn new(out: W) -> CsvWriter<W> {
        CsvWriter {
            out,
            kinds: Vec::new(),
            pending: Vec::with_capacity(BUFFER + 4096),
            floats: zmij::Buffer::new(),
        }
    }

    /// Writes the header line and remembers the column kinds.
    pub fn header(&mut self, names: &[String], kinds: &[ColumnKind]) -> io::Result<()> {
        self.kinds = kinds.to_vec();
        self.pending.extend_from_slice(b"time");
        for n in names {
            self.pending.push(b',');
            self.pending.extend_from_slice(field(n).as_bytes());
        }
        self.pending.push(b'\n');
        self.hand_over_when_full()
    }

    /// Writes one row (`values` has one value per column of the header).
    #[inline]
    pub fn row(&mut self, time: f64, values: &[f64]) -> io::Result<()> {
        push_real(&mut self.pending, &mut self.floats, time);
        for (&v, k) in values.iter().zip(&self.kinds) {
            self.pending.push(b',');
            match k {
                ColumnKind::Real => push_real(&mut self.pending, &mut self.floats, v),
                ColumnKind::Integer | ColumnKind::Boolean => {
                    push_integer(&mut self.pending, v as i64)
                }
            }
        }
        self.pending.push(b'\n');
        self.hand_over_when_full()
    }

    #[inline]
    fn hand_over_when_full(&mut self) -> io::Result<()> {
        if self.pending.len() >= BUFFER {
            self.hand_over()?;
        }
        Ok(())
    }

    /// Hands the pending rows to the underlying writer (a failed write drops them: the run
    /// ends with the error).
    fn hand_over(&mut self) -> io::Result<()> {
        let written = self.out.write_all(&self.pending);
        self.pending.clear();
        written
    }

    /// Hands every row written so far to the underlying writer and flushes it.
    pub fn flush(&mut self) -> io::Result<()> {
        self.hand_over()?;
        self.out.flush()
    }

    /// Flushes and gives back the underlying writer.
    pub fn into_inner(mut self) -> io::Result<W> {
        self.flush()?;
        Ok(self.out)
    }

    /// The underlying writer.
    pub fn get_ref(&self) -> &W {
        &self.out
    }
}

/// Appends `v` in the shortest form that parses back to the same bits (`-0.0` keeps its
/// sign, subnormals are exact, a whole number keeps a `.0`, exponents from 1e16 and below
/// 1e-5: `1e+16`, `1e-7`); NaN as `NaN` (any NaN: the sign and payload are not kept),
/// infinities as `inf` and `-inf`, which [`str::parse`] and pandas read back.
#[inline]
fn push_real(out: &mut Vec<u8>, floats: &mut zmij::Buffer, v: f64) {
    if v.is_finite() {
        out.extend_from_slice(floats.format_finite(v).as_bytes());
    } else if v.is_nan() {
        out.extend_from_slice(b"NaN");
    } else if v > 0.0 {
        out.extend_from_slice(b"inf");
    } else {
        out.extend_from_slice(b"-inf");
    }
}

/// Appends `v` in decimal.
#[inline]
fn push_integer(out: &mut Vec<u8>, v: i64) {
    // u64::MAX has 20 digits.
    let mut digits = [0u8; 20];
    let mut rest = v.unsigned_abs();
    let mut start = digits.len();
    loop {
        start -= 1;
        digits[start] = b'0' + (rest % 10) as u8;
        rest /= 10;
        if rest == 0 {
            break;
        }
    }
    if v < 0 {
        out.push(b'-');
    }
    out.extend_from_slice(&digits[start..]);
}

/// A CSV field, quoted when it contains a comma, a quote or a line break.
fn field(s: &str) -> std::borrow::Cow<'_, str> {
    if s.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", s.replace('"', "\"\"")).into()
    } else {
        s.into()
    }
}

/// `path` with `.partial` appended to its file name.
pub fn partial_path(path: &Path) -> PathBuf {
    let mut name: OsString = path.file_name().map(OsString::from).unwrap_or_default();
    name.push(".partial");
    path.with_file_name(name)
}

/// Sets aside an earlier run's `<path>.partial` (rows of a run that failed, was stopped or
/// crashed: on the bench, measurements that cannot be taken again) before a new run creates
/// its own: it is renamed `<path>.partial.1` (or the first free `.partial.N`) and that name
/// is returned; `None` when there is none, or it is empty (no row to keep). A name taken
/// since is never replaced: the new name is made as a hard link, which fails if it exists,
/// then the old one is removed (a rename where links are not supported).
pub fn set_aside_partial(path: &Path) -> Result<Option<PathBuf>, ResultsError> {
    let partial = partial_path(path);
    let keep = match std::fs::symlink_metadata(&partial) {
        Ok(m) => m.file_type().is_symlink() || (m.is_file() && m.len() > 0),
        Err(e) if e.kind() == io::ErrorKind::NotFound => false,
        Err(e) => return Err(io_error(&partial, e)),
    };
    if !keep {
        return Ok(None);
    }
    let mut name = partial.clone().into_os_string();
    name.push(".");
    for n in 1..=10_000u32 {
        let mut candidate = name.clone();
        candidate.push(n.to_string());
        let candidate = PathBuf::from(candidate);
        match std::fs::hard_link(&partial, &candidate) {
            Ok(()) => {
                std::fs::remove_file(&partial).map_err(|e| io_error(&partial, e))?;
                return Ok(Some(candidate));
            }
            Err(e) if e.kind() == io::ErrorKind::AlreadyExists => continue,
            Err(_) if std::fs::symlink_metadata(&candidate).is_err() => {
                std::fs::rename(&partial, &candidate).map_err(|e| io_error(&partial, e))?;
                return Ok(Some(candidate));
            }
            Err(e) => return Err(io_error(&candidate, e)),
        }
    }
    Err(io_error(
        &partial,
        io::Error::new(
            io::ErrorKind::AlreadyExists,
            "holds an earlier run's rows and every name `.partial.1` to `.partial.10000` \
             beside it is taken: move them away",
        ),
    ))
}

/// Checks that `path` can take a results file written as `<path>.partial` and renamed into
/// place: a file name in an existing directory, and not an existing directory, device, FIFO
/// or socket (the rename would replace a device such as `/dev/null` with a regular file, and
/// a reader waiting on a FIFO would get nothing).
pub fn check_output_path(path: &Path) -> Result<(), ResultsError> {
    let io_err = |path: &Path, source: io::Error| io_error(path, source);
    if path.is_dir() {
        return Err(io_err(
            path,
            io::Error::new(io::ErrorKind::IsADirectory, "is a directory"),
        ));
    }
    if path.file_name().is_none() {
        return Err(io_err(
            path,
            io::Error::new(io::ErrorKind::InvalidInput, "not a file name"),
        ));
    }
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    match std::fs::metadata(dir) {
        Ok(m) if m.is_dir() => {}
        Ok(_) => {
            return Err(io_err(
                dir,
                io::Error::new(io::ErrorKind::NotADirectory, "not a directory"),
            ));
        }
        Err(e) => return Err(io_err(dir, e)),
    }
    match std::fs::metadata(path) {
        Ok(m) if !m.is_file() => Err(io_err(
            path,
            io::Error::new(
                io::ErrorKind::InvalidInput,
                "exists and is not a regular file (a device, FIFO or socket): kneebench writes \
                 its results beside it and renames them into place, which would replace it",
            ),
        )),
        _ => Ok(()),
    }
}

/// The crash-safe CSV file sink (see the [module documentation](self)).
pub struct CsvFile {
    path: PathBuf,
    partial: PathBuf,
    out: Out,
    rows: u64,
    /// Flush after every row ([`CsvFile::write_through`]).
    write_through: bool,
    encode_on: EncodeOn,
    /// Whether the caller runs in a real-time scheduling class (a field so that tests can
    /// stand in for a paced run).
    caller_is_realtime: fn() -> bool,
}

impl std::fmt::Debug for CsvFile {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("CsvFile")
            .field("path", &self.path)
            .field("rows", &self.rows)
            .field("write_through", &self.write_through)
            .field("encode_on", &self.encode_on)
            .finish_non_exhaustive()
    }
}

/// Where a [`CsvFile`]'s rows are formatted.
enum Out {
    /// In [`push_row`](ResultSink::push_row): before [`begin`](ResultSink::begin), with
    /// write-through or [`EncodeOn::Caller`], in a real-time caller, or when the writer
    /// thread could not start.
    Caller(CsvWriter<File>),
    /// Gathered in blocks for the writer thread.
    Blocks(Blocks),
    /// Closed, or failed: the error was returned once; later calls get this message.
    Done(Option<String>),
}

/// The rows of [`Out::Blocks`]: the block being filled, and who formats the full ones.
struct Blocks {
    /// Row after row: `time`, then the values.
    block: Vec<f64>,
    /// Values per row, `time` included.
    width: usize,
    writer: BlockWriter,
}

/// Who formats [`Blocks`].
enum BlockWriter {
    /// Nobody yet: the thread starts with the first full block, unless the caller is then in a
    /// real-time class (a paced run: its stepping thread must never wait for a normally
    /// scheduled one), which formats its rows itself from then on.
    NotStarted(CsvWriter<File>),
    /// The writer thread.
    Thread(Background<CsvEncoder>),
}

/// Values per block handed to the writer thread (64 KiB of rows, at least one row): a
/// handover per 80 rows of 100 signals, and a flush waits for at most about two blocks'
/// formatting (~0.5 ms at 100 signals).
const BLOCK_VALUES: usize = 8 * 1024;

/// An empty block for rows of `width` values: room for [`BLOCK_VALUES`], at least one row.
fn empty_block(width: usize) -> Vec<f64> {
    Vec::with_capacity(BLOCK_VALUES.max(width))
}

/// Formats the rows of `block` (`width` values each) into `writer` and empties it.
fn format_block(
    writer: &mut CsvWriter<File>,
    block: &mut Vec<f64>,
    width: usize,
) -> io::Result<()> {
    for row in block.chunks_exact(width) {
        writer.row(row[0], &row[1..])?;
    }
    block.clear();
    Ok(())
}

/// The writer thread's side of a [`CsvFile`]: formats the blocks of rows into the file.
struct CsvEncoder {
    writer: CsvWriter<File>,
    width: usize,
    partial: PathBuf,
}

impl CsvEncoder {
    fn io(&self, source: io::Error) -> ResultsError {
        io_error(&self.partial, source)
    }
}

impl BlockEncoder for CsvEncoder {
    type Block = Vec<f64>;

    fn write_block(&mut self, block: &mut Vec<f64>) -> Result<(), ResultsError> {
        format_block(&mut self.writer, block, self.width).map_err(|e| self.io(e))
    }

    fn flush(&mut self) -> Result<(), ResultsError> {
        self.writer.flush().map_err(|e| self.io(e))
    }

    fn finish(mut self) -> Result<(), ResultsError> {
        self.flush()?;
        self.writer.get_ref().sync_all().map_err(|e| self.io(e))
    }
}

fn io_error(partial: &Path, source: io::Error) -> ResultsError {
    ResultsError::Io {
        path: partial.to_path_buf(),
        source,
    }
}

/// Whether the calling thread runs in a real-time scheduling class (`SCHED_FIFO`, `SCHED_RR`):
/// a paced run's stepping thread, which the bench hardware FMU raises at its first step.
fn caller_is_realtime() -> bool {
    crate::emulator::realtime::current_policy()
        .is_some_and(|(policy, _)| policy == 1 || policy == 2)
}

impl CsvFile {
    /// Checks the output path and creates `<path>.partial`; nothing is written to `path`
    /// before [`commit`](Self::commit). Rows are formatted on a thread of the file's own
    /// (see [`encoding_on`](Self::encoding_on)).
    pub fn create(path: &Path) -> Result<CsvFile, ResultsError> {
        let io_err = |path: &Path, source: io::Error| io_error(path, source);
        check_output_path(path)?;
        let partial = partial_path(path);
        let file = File::create(&partial).map_err(|e| io_err(&partial, e))?;
        Ok(CsvFile {
            path: path.to_path_buf(),
            partial,
            out: Out::Caller(CsvWriter::new(file)),
            rows: 0,
            write_through: false,
            encode_on: EncodeOn::default(),
            caller_is_realtime,
        })
    }

    /// The same file, every row handed to the kernel as it is recorded (see the module
    /// documentation): what a kill of the process leaves is every row recorded. Rows are
    /// then formatted in the caller's thread.
    pub fn write_through(mut self, on: bool) -> CsvFile {
        self.write_through = on;
        self
    }

    /// The same file, its rows formatted where `encode_on` says (the same bytes either way;
    /// set before [`begin`](ResultSink::begin)). On a thread of its own (the default), a row
    /// pushed is a copy of its values, and the formatting overlaps the run on another core;
    /// a caller in a real-time scheduling class at the first full block (a paced run)
    /// formats its rows itself all the same.
    pub fn encoding_on(mut self, encode_on: EncodeOn) -> CsvFile {
        self.encode_on = encode_on;
        self
    }

    /// The final path.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The partial file the rows go to until [`commit`](Self::commit).
    pub fn partial_path(&self) -> &Path {
        &self.partial
    }

    /// Rows pushed so far.
    pub fn rows(&self) -> u64 {
        self.rows
    }

    fn io(&self, source: io::Error) -> ResultsError {
        io_error(&self.partial, source)
    }

    /// Ends the file with `error` (returned now; later calls say an earlier write failed).
    fn fail(&mut self, error: ResultsError) -> ResultsError {
        self.out = Out::Done(Some(error.to_string()));
        error
    }

    /// The outcome of the writer thread, which has ended early (a failed write).
    fn thread_ended(&mut self) -> ResultsError {
        let error = match std::mem::replace(&mut self.out, Out::Done(None)) {
            Out::Blocks(Blocks {
                writer: BlockWriter::Thread(background),
                ..
            }) => background.failure(&self.partial, "CSV"),
            _ => self.io(io::Error::other("the CSV writer thread ended early")),
        };
        self.fail(error)
    }

    /// Hands the full block over: to the thread, started with the first block unless the
    /// caller is in a real-time class or the thread cannot start (the caller then formats).
    fn hand_over(&mut self) -> Result<(), ResultsError> {
        let Out::Blocks(blocks) = &mut self.out else {
            unreachable!("called with blocks")
        };
        if let BlockWriter::Thread(background) = &blocks.writer {
            let full = std::mem::take(&mut blocks.block);
            if !background.send(full) {
                return Err(self.thread_ended());
            }
            // The thread has taken the block: the one before is back (or this is the first).
            blocks.block = background
                .spare()
                .unwrap_or_else(|| empty_block(blocks.width));
            return Ok(());
        }
        let Out::Blocks(Blocks {
            mut block,
            width,
            writer: BlockWriter::NotStarted(writer),
        }) = std::mem::replace(&mut self.out, Out::Done(None))
        else {
            unreachable!("matched above")
        };
        if (self.caller_is_realtime)() {
            return self.format_here(writer, block, width);
        }
        let encoder = CsvEncoder {
            writer,
            width,
            partial: self.partial.clone(),
        };
        // A thread that cannot start hands the writer back: the caller formats.
        match Background::spawn(encoder, "csv-writer", Vec::new()) {
            Ok(background) => {
                let sent = background.send(std::mem::take(&mut block));
                self.out = Out::Blocks(Blocks {
                    block: empty_block(width),
                    width,
                    writer: BlockWriter::Thread(background),
                });
                if !sent {
                    return Err(self.thread_ended());
                }
                Ok(())
            }
            Err((encoder, _)) => self.format_here(encoder.writer, block, width),
        }
    }

    /// Formats `block` with `writer` in the caller, and every later row too.
    fn format_here(
        &mut self,
        mut writer: CsvWriter<File>,
        mut block: Vec<f64>,
        width: usize,
    ) -> Result<(), ResultsError> {
        let formatted = format_block(&mut writer, &mut block, width);
        self.out = Out::Caller(writer);
        formatted.map_err(|e| {
            let e = self.io(e);
            self.fail(e)
        })
    }

    /// Writes every row so far and ends the writer (its thread joined); `sync`: and syncs
    /// the file. A file that failed before: its error again, except for `keep_partial`
    /// (`sync` false), for which the rows written before the failure stay in the file.
    fn close(&mut self, sync: bool) -> Result<(), ResultsError> {
        match std::mem::replace(&mut self.out, Out::Done(None)) {
            Out::Caller(mut w) => {
                w.flush().map_err(|e| self.io(e))?;
                if sync {
                    w.get_ref().sync_all().map_err(|e| self.io(e))?;
                }
                Ok(())
            }
            Out::Blocks(Blocks {
                mut block,
                width,
                writer: BlockWriter::NotStarted(mut w),
                ..
            }) => {
                format_block(&mut w, &mut block, width).map_err(|e| self.io(e))?;
                // Closed as a caller-formatted file (which leaves it done).
                self.out = Out::Caller(w);
                self.close(sync)
            }
            Out::Blocks(Blocks {
                block,
                writer: BlockWriter::Thread(background),
                ..
            }) => {
                if sync {
                    background.finish(block, &self.partial)
                } else if background.flush(block) {
                    background.join(&self.partial)
                } else {
                    Err(background.failure(&self.partial, "CSV"))
                }
            }
            Out::Done(Some(_)) if !sync => Ok(()),
            Out::Done(error) => Err(closed_error(&self.partial, "CSV", error.as_deref())),
        }
    }

    /// Flushes, syncs the file to disk and renames it into place; returns the final path.
    pub fn commit(mut self) -> Result<PathBuf, ResultsError> {
        self.close(true)?;
        std::fs::rename(&self.partial, &self.path).map_err(|source| ResultsError::Io {
            path: self.path.clone(),
            source,
        })?;
        Ok(self.path.clone())
    }

    /// Flushes and leaves the rows in the partial file (a failed or stopped run); returns its
    /// path. After a write that failed (its error already returned), the rows written before
    /// it stay there.
    pub fn keep_partial(mut self) -> Result<PathBuf, ResultsError> {
        self.close(false)?;
        Ok(self.partial.clone())
    }
}

/// A file dropped without [`CsvFile::commit`] or [`CsvFile::keep_partial`] (a run that ended
/// with an error) still hands its buffered rows to the partial file, as a `BufWriter` would;
/// an error then has nowhere to go.
impl Drop for CsvFile {
    fn drop(&mut self) {
        let _ = self.close(false);
    }
}

impl ResultSink for CsvFile {
    fn begin(&mut self, names: &[String], kinds: &[ColumnKind]) -> Result<(), ResultsError> {
        if names.len() != kinds.len() {
            return Err(ResultsError::RowLength {
                expected: names.len(),
                got: kinds.len(),
            });
        }
        let Out::Caller(writer) = &mut self.out else {
            return Err(self.io(io::Error::other("the CSV file was begun twice")));
        };
        if let Err(e) = writer.header(names, kinds) {
            let e = self.io(e);
            return Err(self.fail(e));
        }
        if self.write_through || self.encode_on == EncodeOn::Caller {
            return Ok(());
        }
        let Out::Caller(writer) = std::mem::replace(&mut self.out, Out::Done(None)) else {
            unreachable!("matched above")
        };
        let width = names.len() + 1;
        self.out = Out::Blocks(Blocks {
            block: empty_block(width),
            width,
            writer: BlockWriter::NotStarted(writer),
        });
        Ok(())
    }

    #[inline]
    fn push_row(&mut self, time: f64, values: &[f64]) -> Result<(), ResultsError> {
        match &mut self.out {
            Out::Blocks(blocks) => {
                if values.len() + 1 != blocks.width {
                    return Err(ResultsError::RowLength {
                        expected: blocks.width - 1,
                        got: values.len(),
                    });
                }
                blocks.block.push(time);
                blocks.block.extend_from_slice(values);
                self.rows += 1;
                // Full when the next row would make the block grow (a block's capacity is
                // what `empty_block` gave it: the thread hands it back with it).
                if blocks.block.len() + blocks.width > blocks.block.capacity() {
                    self.hand_over()?;
                }
                Ok(())
            }
            Out::Caller(writer) => {
                if values.len() != writer.kinds.len() {
                    return Err(ResultsError::RowLength {
                        expected: writer.kinds.len(),
                        got: values.len(),
                    });
                }
                self.rows += 1;
                let mut written = writer.row(time, values);
                if self.write_through && written.is_ok() {
                    written = writer.flush();
                }
                written.map_err(|e| {
                    let e = self.io(e);
                    self.fail(e)
                })
            }
            Out::Done(error) => Err(closed_error(&self.partial, "CSV", error.as_deref())),
        }
    }

    fn flush(&mut self) -> Result<(), ResultsError> {
        let flushed = match &mut self.out {
            Out::Caller(writer) => writer.flush(),
            Out::Blocks(Blocks {
                block,
                width,
                writer: BlockWriter::NotStarted(writer),
                ..
            }) => format_block(writer, block, *width).and_then(|()| writer.flush()),
            Out::Blocks(Blocks {
                block,
                width,
                writer: BlockWriter::Thread(background),
            }) => {
                if !background.flush(std::mem::take(block)) {
                    return Err(self.thread_ended());
                }
                *block = background.spare().unwrap_or_else(|| empty_block(*width));
                Ok(())
            }
            Out::Done(error) => return Err(closed_error(&self.partial, "CSV", error.as_deref())),
        };
        flushed.map_err(|e| {
            let e = self.io(e);
            self.fail(e)
        })
    }

    fn wants_periodic_flush(&self) -> bool {
        true
    }

    /// Nothing to reserve: the rows go out in blocks of a fixed size, whatever the run's
    /// length.
    fn expect_rows(&mut self, _rows: u64) {}
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::results::Results;

    #[test]
    fn write_through_puts_every_row_in_the_file_as_it_is_recorded() {
        let dir = tempfile::tempdir().unwrap();
        let names = ["x".to_string()];
        let kinds = [ColumnKind::Real];
        let on_disk = |f: &CsvFile| std::fs::read_to_string(f.partial_path()).unwrap();
        let mut through = CsvFile::create(&dir.path().join("a.csv"))
            .unwrap()
            .write_through(true);
        let mut buffered = CsvFile::create(&dir.path().join("b.csv")).unwrap();
        for f in [&mut through, &mut buffered] {
            f.begin(&names, &kinds).unwrap();
            f.push_row(0.0, &[1.5]).unwrap();
            f.push_row(0.001, &[2.5]).unwrap();
        }
        // Nothing flushed yet: the buffered file holds nothing, the written-through one
        // every row (what a SIGKILL of the process would leave).
        assert_eq!(on_disk(&through), "time,x\n0.0,1.5\n0.001,2.5\n");
        assert_eq!(on_disk(&buffered), "");
    }

    #[test]
    fn floats_round_trip_and_integers_stay_integers() {
        let mut w = CsvWriter::new(Vec::new());
        let kinds = [ColumnKind::Real, ColumnKind::Integer, ColumnKind::Boolean];
        let names: Vec<String> = ["a,b", "i", "flag"].iter().map(|s| s.to_string()).collect();
        w.header(&names, &kinds).unwrap();
        let values = [
            0.1 + 0.2,
            1e-300,
            -0.0,
            f64::MAX,
            f64::MIN_POSITIVE,
            5e-324,
            f64::INFINITY,
            f64::NEG_INFINITY,
            1.0,
        ];
        for (k, &v) in values.iter().enumerate() {
            w.row(k as f64 * 1e-3, &[v, -(k as f64), (k % 2) as f64])
                .unwrap();
        }
        let text = String::from_utf8(w.into_inner().unwrap()).unwrap();
        assert!(text.starts_with("time,\"a,b\",i,flag\n0.0,0.30000000000000004,0,0\n"));
        let back = Results::read_csv(text.as_bytes(), Path::new("mem")).unwrap();
        let col = back.column("a,b").unwrap();
        for (a, b) in values.iter().zip(&col) {
            assert_eq!(a.to_bits(), b.to_bits(), "{a}");
        }
        assert_eq!(back.column("i").unwrap()[3], -3.0);
    }

    /// Every float the writer formats parses back to the same bits (NaN to a NaN), over the
    /// special values and a million random bit patterns (every exponent, subnormals, both
    /// signs), and the text is ryu's (the previous formatter) but for the `+` of a positive
    /// exponent.
    #[test]
    fn reals_are_written_as_the_shortest_round_trip() {
        let mut floats = zmij::Buffer::new();
        let mut previous = ryu::Buffer::new();
        let text = |v: f64, floats: &mut zmij::Buffer| {
            let mut out = Vec::new();
            push_real(&mut out, floats, v);
            String::from_utf8(out).unwrap()
        };
        let cases = [
            (0.0, "0.0"),
            (-0.0, "-0.0"),
            (1.0, "1.0"),
            (0.1 + 0.2, "0.30000000000000004"),
            (5e-324, "5e-324"),
            (-2.2250738585072e-308, "-2.2250738585072e-308"),
            (f64::MAX, "1.7976931348623157e+308"),
            (1e16, "1e+16"),
            (1e15, "1000000000000000.0"),
            (1e-5, "0.00001"),
            (1e-7, "1e-7"),
            (f64::NAN, "NaN"),
            (-f64::NAN, "NaN"),
            (f64::INFINITY, "inf"),
            (f64::NEG_INFINITY, "-inf"),
        ];
        for (v, expected) in cases {
            assert_eq!(text(v, &mut floats), expected);
        }
        // xorshift64*: every bit pattern is as likely.
        let mut state = 0x9E37_79B9_7F4A_7C15_u64;
        for _ in 0..1_000_000 {
            state ^= state >> 12;
            state ^= state << 25;
            state ^= state >> 27;
            let v = f64::from_bits(state.wrapping_mul(0x2545_F491_4F6C_DD1D));
            let written = text(v, &mut floats);
            let back: f64 = written.parse().unwrap();
            if v.is_nan() {
                assert!(back.is_nan(), "{written}");
                continue;
            }
            assert_eq!(back.to_bits(), v.to_bits(), "{written}");
            let before = previous.format(v);
            match before.split_once('e') {
                Some((m, e)) if !e.starts_with('-') => assert_eq!(written, format!("{m}e+{e}")),
                _ => assert_eq!(written, before),
            }
        }
    }

    #[test]
    fn integers_are_written_in_decimal() {
        for v in [0, 1, -1, 9, 10, -10, 1234567890, i64::MAX, i64::MIN] {
            let mut out = Vec::new();
            push_integer(&mut out, v);
            assert_eq!(String::from_utf8(out).unwrap(), v.to_string());
        }
    }

    /// Rows reach the underlying writer only whole, in blocks, and all of them by `flush`.
    #[test]
    fn rows_are_handed_over_whole() {
        let mut w = CsvWriter::new(Vec::new());
        w.header(&["x".to_string()], &[ColumnKind::Real]).unwrap();
        let mut expected = String::from("time,x\n");
        for k in 0..20_000 {
            let t = k as f64 * 1e-3;
            w.row(t, &[t.sin()]).unwrap();
            expected.push_str(&format!(
                "{},{}\n",
                ryu::Buffer::new().format(t),
                ryu::Buffer::new().format(t.sin())
            ));
            let handed = w.get_ref();
            assert!(handed.is_empty() || handed.ends_with(b"\n"));
        }
        assert!(!w.get_ref().is_empty());
        assert_eq!(
            String::from_utf8(w.into_inner().unwrap()).unwrap(),
            expected
        );
    }

    /// An earlier run's partial file is set aside under the first free `.partial.N`, never
    /// replaced; an empty one or none is left to the new run.
    #[test]
    fn an_earlier_partial_file_is_set_aside() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("r.csv");
        let partial = partial_path(&out);
        assert_eq!(set_aside_partial(&out).unwrap(), None);
        std::fs::write(&partial, "").unwrap();
        assert_eq!(set_aside_partial(&out).unwrap(), None);
        std::fs::write(&partial, "time\n0\n").unwrap();
        std::fs::write(dir.path().join("r.csv.partial.1"), "taken").unwrap();
        let kept = set_aside_partial(&out).unwrap().unwrap();
        assert_eq!(kept, dir.path().join("r.csv.partial.2"));
        assert_eq!(std::fs::read_to_string(&kept).unwrap(), "time\n0\n");
        assert_eq!(
            std::fs::read_to_string(dir.path().join("r.csv.partial.1")).unwrap(),
            "taken"
        );
        assert!(!partial.exists());
        // The new run's file starts from nothing; the kept rows stay.
        let mut f = CsvFile::create(&out).unwrap();
        f.begin(&["x".into()], &[ColumnKind::Real]).unwrap();
        f.push_row(0.0, &[1.0]).unwrap();
        f.commit().unwrap();
        assert_eq!(std::fs::read_to_string(&kept).unwrap(), "time\n0\n");
    }

    #[test]
    fn a_dropped_file_keeps_its_rows_in_the_partial_file() {
        let d = tempfile::tempdir().unwrap();
        let mut f = CsvFile::create(&d.path().join("r.csv")).unwrap();
        let partial = f.partial_path().to_path_buf();
        f.begin(&["x".to_string()], &[ColumnKind::Real]).unwrap();
        f.push_row(0.0, &[1.5]).unwrap();
        drop(f);
        assert_eq!(
            std::fs::read_to_string(partial).unwrap(),
            "time,x\n0.0,1.5\n"
        );
    }

    #[test]
    fn the_partial_file_is_renamed_only_on_commit() {
        let d = tempfile::tempdir().unwrap();
        let out = d.path().join("r.csv");
        std::fs::write(&out, "earlier\n").unwrap();
        let names = vec!["x".to_string()];
        let mut f = CsvFile::create(&out).unwrap();
        assert_eq!(f.partial_path(), d.path().join("r.csv.partial"));
        f.begin(&names, &[ColumnKind::Real]).unwrap();
        f.push_row(0.0, &[1.5]).unwrap();
        let partial = f.keep_partial().unwrap();
        assert_eq!(std::fs::read_to_string(&out).unwrap(), "earlier\n");
        assert_eq!(
            std::fs::read_to_string(&partial).unwrap(),
            "time,x\n0.0,1.5\n"
        );
        let mut f = CsvFile::create(&out).unwrap();
        f.begin(&names, &[ColumnKind::Real]).unwrap();
        f.push_row(0.0, &[2.5]).unwrap();
        assert_eq!(f.commit().unwrap(), out);
        assert_eq!(std::fs::read_to_string(&out).unwrap(), "time,x\n0.0,2.5\n");
        assert!(!partial.exists());
    }

    #[test]
    fn a_bad_output_path_is_refused_before_any_row() {
        let d = tempfile::tempdir().unwrap();
        let e = CsvFile::create(&d.path().join("missing/r.csv")).unwrap_err();
        assert!(e.to_string().contains("missing"), "{e}");
        let e = CsvFile::create(d.path()).unwrap_err();
        assert!(e.to_string().contains("directory"), "{e}");
        let mut f = CsvFile::create(&d.path().join("r.csv")).unwrap();
        f.begin(&["x".to_string()], &[ColumnKind::Real]).unwrap();
        assert!(matches!(
            f.push_row(0.0, &[1.0, 2.0]),
            Err(ResultsError::RowLength {
                expected: 1,
                got: 2
            })
        ));
    }

    /// An output that exists and is not a regular file (a FIFO here; a device such as
    /// `/dev/null` alike) is refused by both writers and the sweep's table before anything is
    /// written, and is left as it was: the rename into place would have replaced it.
    #[test]
    fn a_device_or_fifo_output_is_refused_and_left_alone() {
        use std::os::unix::fs::FileTypeExt;
        let d = tempfile::tempdir().unwrap();
        let fifo = d.path().join("pipe.csv");
        let c = std::ffi::CString::new(fifo.as_os_str().as_encoded_bytes()).unwrap();
        // SAFETY: a valid NUL-terminated path; mkfifo only creates the node.
        assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
        let e = CsvFile::create(&fifo).unwrap_err();
        assert!(e.to_string().contains("not a regular file"), "{e}");
        let e = crate::results::parquet::ParquetFile::create(&fifo).unwrap_err();
        assert!(e.to_string().contains("not a regular file"), "{e}");
        let e = check_output_path(Path::new("/dev/null")).unwrap_err();
        assert!(e.to_string().contains("not a regular file"), "{e}");
        assert!(std::fs::metadata(&fifo).unwrap().file_type().is_fifo());
        assert!(!partial_path(&fifo).exists());
        check_output_path(&d.path().join("new.csv")).unwrap();
    }

    /// Rows with what a recording holds (NaN, signed zeros, infinities, subnormals, whole
    /// numbers), `columns` values each; the second column an Integer, the third a Boolean.
    fn kinds_and_row(k: usize, columns: usize) -> (Vec<ColumnKind>, f64, Vec<f64>) {
        let (time, mut values) = crate::results::test_rows::row(k, columns);
        let mut kinds = vec![ColumnKind::Real; columns];
        if columns > 2 {
            (kinds[1], values[1]) = (ColumnKind::Integer, k as f64 - 7.0);
            (kinds[2], values[2]) = (ColumnKind::Boolean, (k % 2) as f64);
        }
        (kinds, time, values)
    }

    /// Writes `rows` rows of `columns` values formatted where `encode_on` says; committed or
    /// kept partial. The file's bytes.
    fn written(
        dir: &Path,
        encode_on: EncodeOn,
        rows: usize,
        columns: usize,
        commit: bool,
    ) -> Vec<u8> {
        let out = dir.join(format!("{encode_on:?}.csv"));
        let mut f = CsvFile::create(&out).unwrap().encoding_on(encode_on);
        let names: Vec<String> = (0..columns).map(|c| format!("c{c}")).collect();
        f.begin(&names, &kinds_and_row(0, columns).0).unwrap();
        for k in 0..rows {
            let (_, t, v) = kinds_and_row(k, columns);
            f.push_row(t, &v).unwrap();
        }
        let path = if commit {
            f.commit().unwrap()
        } else {
            f.keep_partial().unwrap()
        };
        std::fs::read(path).unwrap()
    }

    /// The writer thread writes the caller's bytes: no row, one, a block's worth give or
    /// take one, several blocks; committed and kept partial.
    #[test]
    fn the_writer_thread_writes_the_callers_bytes() {
        let dir = tempfile::tempdir().unwrap();
        let columns = 9;
        let block_rows = BLOCK_VALUES / (columns + 1);
        for rows in [
            0,
            1,
            block_rows - 1,
            block_rows,
            block_rows + 1,
            5 * block_rows + 17,
        ] {
            for commit in [true, false] {
                let thread = written(dir.path(), EncodeOn::Thread, rows, columns, commit);
                let caller = written(dir.path(), EncodeOn::Caller, rows, columns, commit);
                assert!(
                    thread.len() > 10 && thread == caller,
                    "{rows} rows, commit {commit}"
                );
            }
        }
        // A row wider than a block is a block of its own.
        let wide = BLOCK_VALUES + 3;
        let thread = written(dir.path(), EncodeOn::Thread, 5, wide, true);
        assert_eq!(thread, written(dir.path(), EncodeOn::Caller, 5, wide, true));
    }

    /// A flush puts every row pushed so far in the partial file, from the writer thread as
    /// from the caller's: what a kill of the process after it leaves.
    #[test]
    fn a_flush_puts_every_row_so_far_in_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let mut f = CsvFile::create(&dir.path().join("f.csv")).unwrap();
        f.begin(&["x".to_string()], &[ColumnKind::Real]).unwrap();
        let lines = |f: &CsvFile| {
            std::fs::read_to_string(f.partial_path())
                .unwrap()
                .lines()
                .count()
        };
        for (k, rows) in [3, BLOCK_VALUES, 1].into_iter().scan(0, |n, r| {
            *n += r;
            Some((r, *n))
        }) {
            for i in 0..k {
                f.push_row(i as f64, &[0.5]).unwrap();
            }
            f.flush().unwrap();
            assert_eq!(lines(&f), rows + 1, "after {rows} rows");
        }
    }

    /// A write that fails on the writer thread (`/dev/full`: no space left) is returned by a
    /// later handover or by the flush, then every later call, the commit included, is an
    /// error too: never an Ok over lost rows.
    #[test]
    fn a_failed_write_is_returned_never_lost() {
        let dir = tempfile::tempdir().unwrap();
        let full_disk = || {
            let mut f = CsvFile::create(&dir.path().join("full.csv")).unwrap();
            let dev_full = std::fs::OpenOptions::new()
                .write(true)
                .open("/dev/full")
                .unwrap();
            f.out = Out::Caller(CsvWriter::new(dev_full));
            f.begin(
                &["a".to_string(), "b".to_string(), "c".to_string()],
                &[ColumnKind::Real; 3],
            )
            .unwrap();
            f
        };
        let no_space = |e: &ResultsError| {
            let text = format!("{e}: {:?}", std::error::Error::source(e));
            assert!(text.contains("No space left"), "{text}");
        };
        // Blocks of BLOCK_VALUES / 4 rows: the thread's first write (64 KiB of text) fails
        // within its second block; a later handover finds the thread ended.
        let mut f = full_disk();
        let failed = (0..8 * BLOCK_VALUES)
            .find_map(|k| f.push_row(k as f64, &[1.0, 2.0, 3.0]).err())
            .expect("a failed write is returned by a push");
        no_space(&failed);
        let later = f.push_row(0.0, &[1.0, 2.0, 3.0]).unwrap_err().to_string();
        assert!(later.contains("an earlier write failed"), "{later}");
        let later = f.commit().unwrap_err().to_string();
        assert!(later.contains("an earlier write failed"), "{later}");
        // Rows short of a block: the flush returns it; keep_partial then keeps the partial
        // file (a failed run's rows written before the failure), the error already returned.
        let mut f = full_disk();
        f.push_row(0.0, &[1.0, 2.0, 3.0]).unwrap();
        no_space(&f.flush().unwrap_err());
        assert_eq!(
            f.keep_partial().unwrap(),
            dir.path().join("full.csv.partial")
        );
        // A failure that keep_partial's own flush meets is its error.
        let mut f = full_disk();
        f.push_row(0.0, &[1.0, 2.0, 3.0]).unwrap();
        no_space(&f.keep_partial().unwrap_err());
        // The caller's formatting latches its failure the same way.
        let mut f = full_disk().encoding_on(EncodeOn::Caller);
        f.out = Out::Caller(CsvWriter::new(
            std::fs::OpenOptions::new()
                .write(true)
                .open("/dev/full")
                .unwrap(),
        ));
        f.begin(&["a".to_string()], &[ColumnKind::Real]).unwrap();
        no_space(&f.flush().unwrap_err());
        let later = f.push_row(0.0, &[1.0]).unwrap_err().to_string();
        assert!(later.contains("an earlier write failed"), "{later}");
    }

    /// A caller in a real-time class when the first block is full (a paced run) formats its
    /// rows itself from then on, and starts no thread: the same bytes.
    #[test]
    fn a_realtime_caller_formats_its_own_rows() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("rt.csv");
        let mut f = CsvFile::create(&out).unwrap();
        f.caller_is_realtime = || true;
        let columns = 5;
        let names: Vec<String> = (0..columns).map(|c| format!("c{c}")).collect();
        f.begin(&names, &kinds_and_row(0, columns).0).unwrap();
        let rows = 3 * BLOCK_VALUES / (columns + 1);
        for k in 0..rows {
            let (_, t, v) = kinds_and_row(k, columns);
            f.push_row(t, &v).unwrap();
            assert_eq!(
                matches!(f.out, Out::Caller(_)),
                6 * (k + 1) > BLOCK_VALUES - 6,
                "row {k}"
            );
        }
        let rt = std::fs::read(f.commit().unwrap()).unwrap();
        assert_eq!(
            rt,
            written(dir.path(), EncodeOn::Caller, rows, columns, true)
        );
    }

    /// The check of the caller's scheduling class: normal here, real-time inside a
    /// `SCHED_FIFO` thread where the system grants one (CAP_SYS_NICE or RLIMIT_RTPRIO).
    #[test]
    fn the_realtime_check_sees_the_callers_class() {
        std::thread::spawn(|| {
            assert!(!caller_is_realtime());
            match crate::emulator::realtime::RealtimeThread::enter(1) {
                Ok(rt) => {
                    assert!(caller_is_realtime());
                    drop(rt);
                    assert!(!caller_is_realtime());
                }
                Err(e) => {
                    eprintln!("SCHED_FIFO not granted here ({e}): only the normal class checked")
                }
            }
        })
        .join()
        .unwrap();
    }
}
