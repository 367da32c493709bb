//! The Parquet file's byte sink under the `parquet` crate's writers: writes go to the partial
//! file, the first failure is kept (the crate's footer writer flushes its buffer as it is
//! dropped, where a failure cannot be returned: `Encoder::finish` reports it from here), and
//! short writes are held for the next long one ([`Held`]).

use std::fs::File;
use std::io::{self, Write};
use std::sync::{Arc, Mutex};

/// The writes [`Held`] keeps for the next one: shorter than this many bytes.
const SMALL_WRITE: usize = 4096;

/// Short writes (a page header, a dictionary column's page: under [`SMALL_WRITE`] bytes) held
/// and written with the next long one (a plain page, which the crate's buffer passes
/// straight through) in one vectored call: a row group of 100 plain columns then takes about
/// 100 system calls instead of 200. The bytes reach the writer in the order they came.
#[derive(Default)]
struct Held(Vec<u8>);

impl Held {
    /// Takes `buf`: held if it is short, else written after the held bytes. How much of `buf`
    /// was taken, as [`Write::write`] says it (possibly none while the held bytes go out).
    fn write(&mut self, out: &mut impl Write, buf: &[u8]) -> io::Result<usize> {
        if buf.len() < SMALL_WRITE && self.0.len() < SMALL_WRITE {
            self.0.extend_from_slice(buf);
            return Ok(buf.len());
        }
        while !self.0.is_empty() {
            let parts = [io::IoSlice::new(&self.0), io::IoSlice::new(buf)];
            let n = out.write_vectored(&parts)?;
            if n == 0 {
                return Err(io::ErrorKind::WriteZero.into());
            }
            if n <= self.0.len() {
                self.0.drain(..n);
            } else {
                let of_buf = n - self.0.len();
                self.0.clear();
                return Ok(of_buf);
            }
        }
        out.write(buf)
    }

    /// Writes the held bytes (they are dropped if that fails: the file is unusable then).
    fn flush(&mut self, out: &mut impl Write) -> io::Result<()> {
        let written = out.write_all(&self.0);
        self.0.clear();
        written
    }
}

/// The partial file as the `parquet` crate's sink: writes go to the file through [`Held`],
/// and the first failed write is kept in `failure`. Held bytes are written by `flush` and on
/// drop (the crate's footer writer flushes its own buffer into this sink as it is dropped,
/// without flushing the sink).
pub(super) struct FileSink {
    file: Arc<File>,
    failure: Arc<Mutex<Option<io::Error>>>,
    held: Held,
}

impl FileSink {
    /// A sink writing to `file`, keeping its first failure in `failure`.
    pub(super) fn new(file: Arc<File>, failure: Arc<Mutex<Option<io::Error>>>) -> FileSink {
        FileSink {
            file,
            failure,
            held: Held::default(),
        }
    }

    /// Keeps `e` if it is the first failure. An interrupted call is not one: it is retried
    /// (`write_all`, the crate's buffer) and loses nothing.
    fn remember(&self, e: &io::Error) {
        if e.kind() == io::ErrorKind::Interrupted {
            return;
        }
        let mut failure = self.failure.lock().unwrap_or_else(|p| p.into_inner());
        if failure.is_none() {
            *failure = Some(io::Error::new(e.kind(), e.to_string()));
        }
    }
}

impl Write for FileSink {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        self.held
            .write(&mut &*self.file, buf)
            .inspect_err(|e| self.remember(e))
    }

    fn flush(&mut self) -> io::Result<()> {
        self.held
            .flush(&mut &*self.file)
            .inspect_err(|e| self.remember(e))
    }
}

impl Drop for FileSink {
    /// The held bytes, written; a failure is kept for `finish`.
    fn drop(&mut self) {
        if !self.held.0.is_empty() {
            let _ = self.flush();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use parquet::file::writer::TrackedWrite;

    /// A writer that takes at most `most` bytes per call, across the slices of a vectored
    /// call: every partial-write branch of [`Held`] runs.
    struct Trickle {
        written: Vec<u8>,
        most: usize,
        calls: usize,
    }

    impl Write for Trickle {
        fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
            self.write_vectored(&[io::IoSlice::new(buf)])
        }

        fn write_vectored(&mut self, bufs: &[io::IoSlice<'_>]) -> io::Result<usize> {
            self.calls += 1;
            let mut taken = 0;
            for b in bufs {
                let n = b.len().min(self.most - taken);
                self.written.extend_from_slice(&b[..n]);
                taken += n;
                if taken == self.most {
                    break;
                }
            }
            Ok(taken)
        }

        fn flush(&mut self) -> io::Result<()> {
            Ok(())
        }
    }

    /// Whatever the writer takes per call, the bytes come out whole and in order; with a
    /// writer that takes everything, a short write and the long one after it take one call.
    #[test]
    fn held_bytes_go_out_whole_and_in_order() {
        let writes: Vec<Vec<u8>> = [22, 9_000, 5, 3, 10_000, 17, 4_095, 4_096, 1]
            .iter()
            .enumerate()
            .map(|(k, &n)| (0..n).map(|i| (k * 31 + i) as u8).collect())
            .collect();
        let all: Vec<u8> = writes.concat();
        for most in [1, 3, 7, 22, 100, 5_000, usize::MAX] {
            let mut out = Trickle {
                written: Vec::new(),
                most,
                calls: 0,
            };
            let mut held = Held::default();
            for w in &writes {
                let mut rest = &w[..];
                while !rest.is_empty() {
                    let n = held.write(&mut out, rest).unwrap();
                    rest = &rest[n..];
                }
            }
            held.flush(&mut out).unwrap();
            assert!(out.written == all, "at most {most} bytes per call");
            if most == usize::MAX {
                // 22 + 9,000; 5 + 3 + 10,000; 17 + 4,095 + 4,096; 1 at the flush.
                assert_eq!(out.calls, 4);
            }
        }
    }

    /// The footer writer's last flush happens as it is dropped, where its error cannot be
    /// returned: the sink keeps it for `finish` to return.
    #[test]
    fn a_failed_write_on_drop_is_kept() {
        let file = std::fs::OpenOptions::new()
            .write(true)
            .open("/dev/full")
            .unwrap();
        let failure = Arc::new(Mutex::new(None));
        {
            let mut w = TrackedWrite::new(FileSink::new(Arc::new(file), Arc::clone(&failure)));
            w.write_all(b"the footer's tail").unwrap();
        }
        let kept = failure.lock().unwrap().take().expect("the failure is kept");
        assert!(kept.to_string().contains("No space left"), "{kept}");
    }
}
