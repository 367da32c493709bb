//! A file sink's writer thread: the caller fills blocks of rows, a thread of the file's own
//! encodes and writes them while the caller fills the next (on two cores the simulation and
//! the encoding overlap). Used by the CSV and Parquet files; each brings its
//! [`BlockEncoder`].
//!
//! - **Back pressure**: a handover waits until the thread takes the block (a rendezvous), so
//!   at most one block is being encoded while one fills: the memory of two blocks. Written
//!   blocks come back emptied for the caller to fill again.
//! - **Flush**: [`Background::flush`] hands the partly filled block over and returns once the
//!   thread has written it and flushed the encoder: the sink's durability promise (every row
//!   pushed so far is in the file) holds as if the caller had written the rows itself.
//! - **Errors are never lost**: the thread ends at its first error; the next handover or flush
//!   finds it ended, and [`Background::join`] returns the error (a panic of the thread is an
//!   error too).
//! - **Nothing writes a file after its sink is gone**: dropping a [`Background`] closes the
//!   channel and waits for the thread, which writes nothing more than the blocks it holds.

use std::io;
use std::path::Path;
use std::sync::mpsc::{Receiver, SyncSender, channel, sync_channel};
use std::thread::JoinHandle;

use super::ResultsError;

/// Where a file's rows are encoded and written (the same bytes either way).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum EncodeOn {
    /// A thread of the file's own, while the caller fills the next block of rows (the
    /// default).
    #[default]
    Thread,
    /// The caller's thread, in the [`push_row`](super::ResultSink::push_row) that fills a
    /// block.
    Caller,
}

/// What a writer thread does with the blocks it is handed.
pub(super) trait BlockEncoder: Send + 'static {
    /// The caller's unit of rows.
    type Block: Send + 'static;
    /// Encodes and writes `block`, leaving it empty (its buffer kept for reuse).
    fn write_block(&mut self, block: &mut Self::Block) -> Result<(), ResultsError>;
    /// Makes every block written so far reach the file (not only a buffer of the process).
    fn flush(&mut self) -> Result<(), ResultsError>;
    /// Ends the file after its last block (a footer, the sync).
    fn finish(self) -> Result<(), ResultsError>;
}

/// Makes an empty block on a writer thread ([`Background::spawn`]).
pub(super) type Prepare<B> = Box<dyn FnOnce() -> B + Send>;

/// What the caller hands the thread.
enum Job<B> {
    /// A full block.
    Block(B),
    /// A block (possibly empty), then a flush, acknowledged.
    Flush(B),
    /// The last block (possibly empty), then [`BlockEncoder::finish`].
    Finish(B),
}

/// A running writer thread (see the [module documentation](self)).
pub(super) struct Background<E: BlockEncoder> {
    jobs: Option<SyncSender<Job<E::Block>>>,
    /// Written blocks, emptied.
    spare: Receiver<E::Block>,
    /// One message per flush done.
    flushed: Receiver<()>,
    thread: Option<JoinHandle<Result<(), ResultsError>>>,
}

impl<E: BlockEncoder> Background<E> {
    /// Starts the thread `name` with `encoder`; the encoder comes back if the thread cannot
    /// start (the caller may then do the work itself). Each of `prepare`, in order, makes an
    /// empty block on the thread before anything else, returned as a written one would be
    /// ([`spare`](Self::spare), [`wait_spare`](Self::wait_spare)): the memory's first touch
    /// (zeroing, page faults) is then the thread's, while the caller does its own work.
    pub(super) fn spawn(
        encoder: E,
        name: &str,
        prepare: Vec<Prepare<E::Block>>,
    ) -> Result<Background<E>, (E, io::Error)> {
        // Rendezvous: a handover waits until the thread takes the block.
        let (jobs, job_rx) = sync_channel::<Job<E::Block>>(0);
        let (spare_tx, spare) = channel();
        let (flushed_tx, flushed) = channel();
        // The encoder goes to the thread once it runs, so that a failed start keeps it.
        let (encoder_tx, encoder_rx) = channel::<E>();
        let spawned = std::thread::Builder::new()
            .name(name.to_string())
            .spawn(move || {
                let Ok(mut encoder) = encoder_rx.recv() else {
                    return Ok(());
                };
                for make in prepare {
                    spare_tx.send(make()).ok();
                }
                for job in job_rx {
                    match job {
                        Job::Block(mut b) => {
                            encoder.write_block(&mut b)?;
                            // The caller may be gone (closing): the block is dropped then.
                            spare_tx.send(b).ok();
                        }
                        Job::Flush(mut b) => {
                            encoder.write_block(&mut b)?;
                            encoder.flush()?;
                            spare_tx.send(b).ok();
                            flushed_tx.send(()).ok();
                        }
                        Job::Finish(mut b) => {
                            encoder.write_block(&mut b)?;
                            return encoder.finish();
                        }
                    }
                }
                // Dropped without being finished: what was written stays written; the
                // encoder's own drop decides what it still hands to the file.
                Ok(())
            });
        let thread = match spawned {
            Ok(thread) => thread,
            Err(e) => return Err((encoder, e)),
        };
        // The thread waits for it: the send cannot fail.
        encoder_tx.send(encoder).ok();
        Ok(Background {
            jobs: Some(jobs),
            spare,
            flushed,
            thread: Some(thread),
        })
    }

    /// Hands a full block over. `false`: the thread has ended (its error by [`join`](Self::join)).
    pub(super) fn send(&self, block: E::Block) -> bool {
        self.jobs
            .as_ref()
            .is_some_and(|jobs| jobs.send(Job::Block(block)).is_ok())
    }

    /// A block the thread has written and emptied (or prepared), if one is back.
    pub(super) fn spare(&self) -> Option<E::Block> {
        self.spare.try_recv().ok()
    }

    /// The next block the thread prepares or empties, waiting for it; `None` if the thread
    /// has ended (its error by [`join`](Self::join)).
    pub(super) fn wait_spare(&self) -> Option<E::Block> {
        self.spare.recv().ok()
    }

    /// Hands `block` over and waits until it is written and flushed. `false`: the thread has
    /// ended (its error by [`join`](Self::join)).
    pub(super) fn flush(&self, block: E::Block) -> bool {
        self.jobs
            .as_ref()
            .is_some_and(|jobs| jobs.send(Job::Flush(block)).is_ok())
            && self.flushed.recv().is_ok()
    }

    /// Hands the last block over and waits for the thread to finish the file: its outcome.
    pub(super) fn finish(mut self, last: E::Block, partial: &Path) -> Result<(), ResultsError> {
        if let Some(jobs) = self.jobs.take() {
            // A send fails only if the thread has ended: the join says why.
            jobs.send(Job::Finish(last)).ok();
        }
        self.join(partial)
    }

    /// Why the thread ended before it was told to (a handover or flush found it gone): its
    /// error, a panic included; `kind` ("CSV", "Parquet") names it should it have none.
    pub(super) fn failure(self, partial: &Path, kind: &str) -> ResultsError {
        match self.join(partial) {
            Err(e) => e,
            Ok(()) => ResultsError::Io {
                path: partial.to_path_buf(),
                source: io::Error::other(format!("the {kind} writer thread ended early")),
            },
        }
    }

    /// The thread's outcome once it has ended (the channel closed: it ends after the blocks it
    /// holds); a panic of the thread is an error.
    pub(super) fn join(mut self, partial: &Path) -> Result<(), ResultsError> {
        self.jobs = None;
        match self.thread.take().map(JoinHandle::join) {
            Some(Ok(result)) => result,
            Some(Err(_)) => Err(ResultsError::Io {
                path: partial.to_path_buf(),
                source: io::Error::other("the writer thread panicked"),
            }),
            None => Ok(()),
        }
    }
}

/// The error of a call on a file sink (`kind`: "CSV", "Parquet") that is closed, or whose
/// writer failed (`failure`: that first error, already returned once).
pub(super) fn closed_error(partial: &Path, kind: &str, failure: Option<&str>) -> ResultsError {
    ResultsError::Io {
        path: partial.to_path_buf(),
        source: io::Error::other(match failure {
            Some(e) => format!("an earlier write failed: {e}"),
            None => format!("the {kind} file is closed"),
        }),
    }
}

impl<E: BlockEncoder> Drop for Background<E> {
    /// Closes the channel and waits for the thread: nothing writes the file after this.
    fn drop(&mut self) {
        self.jobs = None;
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}
