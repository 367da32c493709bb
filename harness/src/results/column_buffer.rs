//! The Parquet writer's row-group buffer: zeroed doubles, on transparent huge pages where the
//! kernel gives them.
//!
//! A full row group of 101 columns (8,200 slots each) is 6.6 MB; the study's full recording
//! of 10,001 rows is two groups of about 4 MB (measured below before the groups were made
//! even, with one group of 6.6 MB). Fresh
//! memory is faulted in one 4 KiB page at a time as the rows fill it: 1,620 faults per buffer,
//! which on this machine's virtual CPUs cost more than filling it (a fresh process filling one
//! buffer: 8-20 ms against 1.6-3.5 ms on huge pages, at load 6; `kneebench run` of the SEA
//! scenario for 100 s into a Parquet file: 4,740 page faults and 191-203 ms of CPU time
//! before, 1,515 and 183-187 ms after, four runs each interleaved). On
//! Linux a buffer of [`MAPPED_FROM`] bytes or more is therefore mapped on its own, aligned to
//! 2 MiB and advised `MADV_HUGEPAGE`: the kernel then faults it in 2 MiB at a time (5 faults
//! instead of 1,620) where transparent huge pages are enabled (`madvise` or `always`), and in
//! 4 KiB pages as before where they are not; and it is faulted in when it is allocated
//! (`MADV_POPULATE_WRITE`), so that the run's rows do not stop for it. Smaller buffers, other
//! systems and a failed
//! mapping use a `Vec`. Either way the buffer is the same zeroed `[f64]`, so the file's bytes
//! cannot depend on it (tested in `parquet`'s byte-identity tests, which use both).

use std::ops::{Deref, DerefMut};

/// Buffers of at least this many bytes are mapped on huge pages (half a huge page: a smaller
/// buffer would waste more than it saves).
pub(super) const MAPPED_FROM: usize = HUGE_PAGE / 2;

/// The size and alignment of an x86-64 / AArch64 (4 KiB granule) transparent huge page.
const HUGE_PAGE: usize = 2 << 20;

/// Zeroed doubles (see the [module documentation](self)).
pub(super) struct ColumnBuffer(Storage);

enum Storage {
    Heap(Vec<f64>),
    #[cfg(target_os = "linux")]
    Mapped(mapped::Mapping),
}

impl ColumnBuffer {
    /// `len` zeroed doubles: mapped on huge pages from [`MAPPED_FROM`] bytes on Linux, else
    /// (or if the mapping fails) on the heap.
    pub(super) fn zeroed(len: usize) -> ColumnBuffer {
        #[cfg(target_os = "linux")]
        if len.saturating_mul(size_of::<f64>()) >= MAPPED_FROM
            && let Some(mapping) = mapped::Mapping::new(len)
        {
            return ColumnBuffer(Storage::Mapped(mapping));
        }
        ColumnBuffer::on_heap(vec![0.0; len])
    }

    /// `values` as a buffer, on the heap.
    pub(super) fn on_heap(values: Vec<f64>) -> ColumnBuffer {
        ColumnBuffer(Storage::Heap(values))
    }

    /// Whether the buffer is a mapping of its own (on huge pages where the kernel has them).
    #[cfg(test)]
    pub(super) fn is_mapped(&self) -> bool {
        !matches!(self.0, Storage::Heap(_))
    }

    /// Whether the buffer's pages were faulted in when it was made.
    #[cfg(test)]
    pub(super) fn is_populated(&self) -> bool {
        match &self.0 {
            Storage::Heap(_) => false,
            #[cfg(target_os = "linux")]
            Storage::Mapped(mapping) => mapping.populated,
        }
    }
}

impl Default for ColumnBuffer {
    /// An empty buffer.
    fn default() -> ColumnBuffer {
        ColumnBuffer::on_heap(Vec::new())
    }
}

impl Deref for ColumnBuffer {
    type Target = [f64];

    fn deref(&self) -> &[f64] {
        match &self.0 {
            Storage::Heap(values) => values,
            #[cfg(target_os = "linux")]
            Storage::Mapped(mapping) => mapping.values(),
        }
    }
}

impl DerefMut for ColumnBuffer {
    fn deref_mut(&mut self) -> &mut [f64] {
        match &mut self.0 {
            Storage::Heap(values) => values,
            #[cfg(target_os = "linux")]
            Storage::Mapped(mapping) => mapping.values_mut(),
        }
    }
}

#[cfg(target_os = "linux")]
mod mapped {
    use std::ptr::NonNull;

    use super::HUGE_PAGE;

    /// An anonymous private mapping holding `len` doubles from a 2 MiB boundary.
    pub(super) struct Mapping {
        /// The first double, at a 2 MiB boundary inside the mapping.
        values: NonNull<f64>,
        len: usize,
        /// The mapping as `mmap` returned it (unmapped whole on drop).
        base: NonNull<libc::c_void>,
        mapped_len: usize,
        /// Whether the kernel faulted the pages in when it was made (Linux 5.14 and later).
        #[cfg_attr(not(test), allow(dead_code, reason = "read by the tests"))]
        pub(super) populated: bool,
    }

    // SAFETY: the mapping is owned by this value alone (no other pointer to it escapes except
    // through borrows of `self`), so moving it to or sharing it with another thread is the same
    // as for a `Vec<f64>`.
    unsafe impl Send for Mapping {}
    // SAFETY: as above; `&Mapping` gives only shared reads.
    unsafe impl Sync for Mapping {}

    impl Mapping {
        /// `len` zeroed doubles, or `None` if the kernel refuses the mapping.
        pub(super) fn new(len: usize) -> Option<Mapping> {
            let bytes = len.checked_mul(size_of::<f64>())?;
            let used = bytes.checked_next_multiple_of(HUGE_PAGE)?;
            // One huge page more, so that a 2 MiB boundary with `used` bytes after it lies
            // inside; the pages of the slack are never touched, so they take no memory.
            let mapped_len = used.checked_add(HUGE_PAGE)?;
            // SAFETY: a new anonymous private mapping (no address hint, no file): it aliases
            // nothing, and the kernel fills it with zeros.
            let base = unsafe {
                libc::mmap(
                    std::ptr::null_mut(),
                    mapped_len,
                    libc::PROT_READ | libc::PROT_WRITE,
                    libc::MAP_PRIVATE | libc::MAP_ANONYMOUS,
                    -1,
                    0,
                )
            };
            if base == libc::MAP_FAILED {
                return None;
            }
            let base = NonNull::new(base)?;
            let start = (base.as_ptr() as usize).next_multiple_of(HUGE_PAGE);
            let offset = start - base.as_ptr() as usize;
            // SAFETY: `offset < HUGE_PAGE`, so `[offset, offset + used)` lies inside the
            // mapping of `used + HUGE_PAGE` bytes.
            let values = unsafe { base.as_ptr().cast::<u8>().add(offset) };
            // Only advice: where the kernel has no transparent huge pages it returns EINVAL
            // and the buffer is faulted in 4 KiB pages, as any other memory.
            // SAFETY: the range lies inside this process's own mapping (above).
            unsafe { libc::madvise(values.cast(), used, libc::MADV_HUGEPAGE) };
            // Faulted in now, before the run, rather than by the run's first row (a row
            // touches every column, so every page of the buffer at once: milliseconds of
            // zeroing, and of compaction where the kernel must make a huge page, in the
            // middle of a run that may be pacing the real bench). Before Linux 5.14 this is
            // EINVAL and the first row faults the pages in.
            // SAFETY: as above; the pages are this mapping's, writable, and zeroed.
            let populated =
                unsafe { libc::madvise(values.cast(), used, libc::MADV_POPULATE_WRITE) };
            Some(Mapping {
                values: NonNull::new(values.cast::<f64>())?,
                len,
                base,
                mapped_len,
                populated: populated == 0,
            })
        }

        pub(super) fn values(&self) -> &[f64] {
            // SAFETY: `values` points to `len` doubles inside the mapping, aligned (a 2 MiB
            // boundary), initialised (zeros from the kernel, then only doubles written through
            // `values_mut`), and borrowed no longer than `self`, which owns the mapping.
            unsafe { std::slice::from_raw_parts(self.values.as_ptr(), self.len) }
        }

        pub(super) fn values_mut(&mut self) -> &mut [f64] {
            // SAFETY: as in `values`, and the `&mut self` borrow makes this the only
            // reference to them.
            unsafe { std::slice::from_raw_parts_mut(self.values.as_ptr(), self.len) }
        }
    }

    impl Drop for Mapping {
        fn drop(&mut self) {
            // SAFETY: the mapping `mmap` returned, unmapped once; no borrow of it outlives
            // `self`.
            unsafe { libc::munmap(self.base.as_ptr(), self.mapped_len) };
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_buffer_is_zeroed_doubles_that_keep_what_is_written() {
        for len in [
            0,
            1,
            1000,
            MAPPED_FROM / 8 - 1,
            MAPPED_FROM / 8,
            3 * HUGE_PAGE / 8 + 5,
        ] {
            let mut buffer = ColumnBuffer::zeroed(len);
            assert_eq!(buffer.len(), len);
            assert!(buffer.iter().all(|&v| v.to_bits() == 0), "len {len}");
            for (k, v) in buffer.iter_mut().enumerate() {
                *v = k as f64 * 0.5;
            }
            assert!(buffer.iter().enumerate().all(|(k, &v)| v == k as f64 * 0.5));
            let moved = std::thread::spawn(move || buffer.iter().sum::<f64>())
                .join()
                .unwrap();
            assert_eq!(moved, (0..len).map(|k| k as f64 * 0.5).sum::<f64>());
        }
    }

    #[test]
    #[cfg(target_os = "linux")]
    fn a_big_buffer_is_mapped_from_a_huge_page_boundary_and_a_small_one_is_not() {
        let big = ColumnBuffer::zeroed(MAPPED_FROM / 8);
        assert!(big.is_mapped());
        assert_eq!(big.as_ptr() as usize % HUGE_PAGE, 0);
        assert!(!ColumnBuffer::zeroed(MAPPED_FROM / 8 - 1).is_mapped());
        assert!(!ColumnBuffer::default().is_mapped());
    }
}
