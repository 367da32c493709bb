//! The Parquet writer's row group: the rows of one group, column by column in one buffer, and
//! how a row gets there from the simulation's thread.
//!
//! **Why rows are staged.** A row touches every column, and the columns are a page apart: a
//! row of the study's 101 columns stored value by value writes 101 cache lines, each a new
//! one every eighth row, and the buffer (6 MB a group) is far larger than the caches. Stored
//! that way, the stores' misses slowed the whole run: `kneebench run` of the SEA scenario for
//! 100 s recording every signal into Parquet took 132 ms of wall time at the fastest of 25
//! interleaved runs, against 102 ms with the same stores sent to the same few cache lines
//! (an experiment, not a writer). So a group stages [`BLOCK_ROWS`] rows row by row (one small
//! buffer, always in the cache) and stores them into the columns a block at a time: each
//! column then takes one whole, aligned cache line per block. On x86-64 those lines are
//! written with non-temporal stores where the buffer is aligned (the mapped buffers of
//! `column_buffer`), which write a whole line without first reading it into the cache and
//! leave the simulation's own data there; elsewhere, and for a buffer on the heap, with
//! ordinary stores. This is the one fast path of the concern; `Group::push_plain` (tests) is the
//! plain one it must equal (test `the_staged_rows_are_the_plain_rows_bit_for_bit`).
//!
//! Measured with this path (25 runs interleaved with 3a7ddd9's build, without it): 108 ms
//! at the fastest against 135 ms, 115 ms against 149 ms at the first quartile, the file byte
//! for byte the same.
//!
//! The staged rows of a block not yet whole reach the columns in [`Group::settle`], which the
//! encoder calls before it reads them.

use super::column_buffer::ColumnBuffer;

/// Rows staged before they are stored in the columns: one 64-byte cache line of doubles.
pub(super) const BLOCK_ROWS: usize = 8;

/// Slots per 4 KiB page: a column's slots in a [`Group`]'s buffer are rounded up to whole pages.
pub(super) const PAGE_SLOTS: usize = 4096 / size_of::<f64>();

/// Slots past a column's pages in a [`Group`]'s buffer, a cache line: so that the columns do
/// not start 4 KiB (or 64 KiB) apart, where the stores of one row would all fall in the same
/// cache sets and evict each other, and each column starts one cache line further into its
/// page than the one before. With the rows' slots rounded up to whole pages first, every
/// group has this layout, whatever its rows: a full group of 8,192 rows had it by its size,
/// and the even groups of an announced run (7,693 rows for 100,001: 61,608 bytes per column)
/// ran the whole `kneebench run` recording every signal 8-10 % slower in wall time without it
/// (25 interleaved runs each).
pub(super) const COLUMN_PADDING: usize = 8;

// A column's slots are whole cache lines, so that each block of every column is one line.
const _: () =
    assert!(PAGE_SLOTS.is_multiple_of(BLOCK_ROWS) && COLUMN_PADDING.is_multiple_of(BLOCK_ROWS));

/// Slots per column of a group buffer of `capacity` rows.
fn column_stride(capacity: usize) -> usize {
    capacity.next_multiple_of(PAGE_SLOTS) + COLUMN_PADDING
}

/// One row group's values, column by column in one buffer: `time`'s slots, then each
/// signal's.
///
/// A row is staged in [`push`](Self::push) and stored with its block (module docs), and the
/// encoder reads each column as one contiguous slice once [`settle`](Self::settle)d. Growing
/// one `Vec` per column instead cost a length and capacity check per value: 12.6 instructions
/// per value against about 4 (callgrind, the writers bench), on the simulation's thread.
///
/// A group takes [`ROW_GROUP_ROWS`](super::parquet::ROW_GROUP_ROWS) rows, or fewer when the run has announced its rows: they
/// are then shared evenly between as few groups as hold them (`group_rows`), and each
/// group's buffer takes the memory (and the kernel's zeroing) of the rows it will hold. Where
/// the groups end depends on the rows announced and pushed alone, never on which buffer is
/// reused, so the writer thread and the caller write the same groups.
pub(super) struct Group {
    /// `width` columns of [`stride`](Self::stride) slots, of which the first `rows` are filled
    /// once the group is settled.
    pub(super) values: ColumnBuffer,
    /// The rows of the block not yet stored, row by row: [`BLOCK_ROWS`] rows of `width`
    /// values (`time` first), of which the first `rows % BLOCK_ROWS` are this block's.
    staged: Box<[f64]>,
    pub(super) width: usize,
    /// Rows a column of the buffer holds (none before it is made).
    pub(super) capacity: usize,
    /// Rows this group takes (at most `capacity`): it is full at this many.
    pub(super) limit: usize,
    pub(super) rows: usize,
}

impl Group {
    /// An empty group of `width` columns (`time` included) of `capacity` rows, its buffer
    /// allocated in full (on huge pages when it is big: [`ColumnBuffer`]).
    pub(super) fn new(width: usize, capacity: usize) -> Group {
        Group {
            values: ColumnBuffer::zeroed(width * column_stride(capacity)),
            staged: vec![0.0; width * BLOCK_ROWS].into_boxed_slice(),
            width,
            capacity,
            limit: capacity,
            rows: 0,
        }
    }

    /// An empty group of `width` columns taking `limit` rows: `reuse`'s buffer if it is one
    /// of as many columns and holds as many rows, else a new one.
    pub(super) fn begun(reuse: Option<Group>, width: usize, limit: usize) -> Group {
        match reuse {
            Some(mut group) if group.width == width && group.capacity >= limit => {
                group.limit = limit;
                group.rows = 0;
                group
            }
            _ => Group::new(width, limit),
        }
    }

    /// A group of `width` columns whose buffer is not made yet (full at once).
    pub(super) fn unmade(width: usize) -> Group {
        Group {
            width,
            ..Group::default()
        }
    }

    /// Slots per column in the buffer.
    pub(super) fn stride(&self) -> usize {
        column_stride(self.capacity)
    }

    /// Stages a row (`values.len() + 1 == width`, checked by the caller) in the next slot
    /// (the group is not full, checked by the caller), and stores its block once whole.
    #[inline]
    pub(super) fn push(&mut self, time: f64, values: &[f64]) {
        let row = self.rows;
        let slot = row % BLOCK_ROWS;
        let width = self.width;
        let staged = &mut self.staged[slot * width..(slot + 1) * width];
        staged[0] = time;
        staged[1..].copy_from_slice(values);
        self.rows += 1;
        if slot == BLOCK_ROWS - 1 {
            self.store_block(row + 1 - BLOCK_ROWS);
        }
    }

    /// Stores the row straight into its slot of every column: the plain path that
    /// [`push`](Self::push) must equal once [`settle`](Self::settle)d.
    #[cfg(test)]
    pub(super) fn push_plain(&mut self, time: f64, values: &[f64]) {
        let row = self.rows;
        let stride = self.stride();
        let mut columns = self.values.chunks_exact_mut(stride);
        if let Some(time_column) = columns.next() {
            time_column[row] = time;
        }
        for (column, &v) in columns.zip(values) {
            column[row] = v;
        }
        self.rows += 1;
    }

    /// Stores the whole staged block in rows `first..first + BLOCK_ROWS` of every column.
    fn store_block(&mut self, first: usize) {
        let (width, stride) = (self.width, self.stride());
        let staged = &self.staged;
        let streamed = lines::can_stream(&self.values);
        for (c, column) in self.values.chunks_exact_mut(stride).enumerate() {
            let mut line = [0.0; BLOCK_ROWS];
            for (j, v) in line.iter_mut().enumerate() {
                *v = staged[j * width + c];
            }
            let slots: &mut [f64; BLOCK_ROWS] = (&mut column[first..first + BLOCK_ROWS])
                .try_into()
                .expect("a block is BLOCK_ROWS slots");
            if streamed {
                lines::stream(slots, line);
            } else {
                *slots = line;
            }
        }
        if streamed {
            lines::fence();
        }
    }

    /// Stores the rows staged since the last whole block (ordinary stores): the columns then
    /// hold every row pushed. Called before the group's columns are read; pushing on after
    /// it is allowed (the block is stored again, whole, with the same values).
    pub(super) fn settle(&mut self) {
        let staged_rows = self.rows % BLOCK_ROWS;
        if staged_rows == 0 {
            return;
        }
        let (width, stride) = (self.width, self.stride());
        let first = self.rows - staged_rows;
        for (c, column) in self.values.chunks_exact_mut(stride).enumerate() {
            for j in 0..staged_rows {
                column[first + j] = self.staged[j * width + c];
            }
        }
    }

    /// Whether the group holds its `limit` rows.
    pub(super) fn is_full(&self) -> bool {
        self.rows >= self.limit
    }
}

impl Default for Group {
    /// A group of no column (before [`begin`](super::ResultSink::begin), and once closed).
    fn default() -> Group {
        Group {
            values: ColumnBuffer::default(),
            staged: Box::default(),
            width: 0,
            capacity: 0,
            limit: 0,
            rows: 0,
        }
    }
}

/// Whole cache lines written without reading them first (module docs): the one place of
/// the writer's non-temporal stores.
mod lines {
    use super::BLOCK_ROWS;

    /// Whether the lines of `buffer`'s blocks can be streamed: on x86-64, with the buffer
    /// starting on a cache line (every block then is one line, as a column's slots are whole
    /// lines).
    #[inline]
    pub(super) fn can_stream(buffer: &[f64]) -> bool {
        cfg!(target_arch = "x86_64") && (buffer.as_ptr() as usize).is_multiple_of(64)
    }

    /// Writes `line` to `slots`, one cache line, without reading it into the cache.
    #[inline]
    pub(super) fn stream(slots: &mut [f64; BLOCK_ROWS], line: [f64; BLOCK_ROWS]) {
        #[cfg(target_arch = "x86_64")]
        {
            use std::arch::x86_64::{_mm_loadu_pd, _mm_stream_pd};
            let to = slots.as_mut_ptr();
            let from = line.as_ptr();
            for k in (0..BLOCK_ROWS).step_by(2) {
                // SAFETY: SSE2 is part of x86-64. `to.add(k)` and `from.add(k)` point to two
                // doubles inside `slots` and `line` (k + 1 < BLOCK_ROWS); `to` is on a 16-byte
                // boundary (the caller checked the buffer is on a cache line, and a block
                // starts a whole number of lines into it), as `_mm_stream_pd` requires.
                unsafe { _mm_stream_pd(to.add(k), _mm_loadu_pd(from.add(k))) };
            }
        }
        #[cfg(not(target_arch = "x86_64"))]
        {
            *slots = line;
        }
    }

    /// Orders the streamed lines before every later store: the group's handover to the
    /// writer thread (a release) then publishes them, as it does ordinary stores.
    #[inline]
    pub(super) fn fence() {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: SSE is part of x86-64; a fence has no other effect.
        unsafe {
            std::arch::x86_64::_mm_sfence()
        };
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::results::parquet::ROW_GROUP_ROWS;

    /// The values of row `r`, column `c` of the tests: distinct, and not all representable
    /// in fewer bits.
    fn value(r: usize, c: usize) -> f64 {
        (r as f64 + 0.1) * (c as f64 + 1.0).sqrt() - c as f64
    }

    /// The staged path (through whole blocks, streamed into a mapped buffer or stored into one
    /// on the heap, and the settled rest) leaves every slot of every column with the plain
    /// path's bits, whatever the rows (a block's edges, a group's limit), the width and a
    /// reused group.
    #[test]
    fn the_staged_rows_are_the_plain_rows_bit_for_bit() {
        // 102 columns of a full group take a mapped buffer (streamed on x86-64), 3 one on the
        // heap (not on a cache line in general: stored).
        for width in [1, 2, 3, 102] {
            let mut streamed_at_least_once = false;
            for rows in [0, 1, 7, 8, 9, 15, 16, 17, 100, 1001, ROW_GROUP_ROWS] {
                let mut staged = Group::new(width, ROW_GROUP_ROWS);
                let mut plain = Group::new(width, ROW_GROUP_ROWS);
                for pass in 0..2 {
                    if pass == 1 {
                        // The same groups reused, as the writer does.
                        staged = Group::begun(Some(staged), width, ROW_GROUP_ROWS);
                        plain = Group::begun(Some(plain), width, ROW_GROUP_ROWS);
                    }
                    for r in 0..rows {
                        let row: Vec<f64> = (1..width).map(|c| value(r + pass * 7, c)).collect();
                        let time = value(r + pass * 7, 0);
                        staged.push(time, &row);
                        plain.push_plain(time, &row);
                    }
                    staged.settle();
                    streamed_at_least_once |= lines::can_stream(&staged.values) && rows >= 8;
                    assert_eq!(staged.rows, plain.rows);
                    let differs = staged
                        .values
                        .iter()
                        .zip(plain.values.iter())
                        .position(|(a, b)| a.to_bits() != b.to_bits());
                    assert_eq!(
                        differs, None,
                        "width {width}, rows {rows}, pass {pass}: slot differs"
                    );
                }
            }
            if width == 102 && cfg!(all(target_arch = "x86_64", target_os = "linux")) {
                assert!(streamed_at_least_once, "the streamed path was not taken");
            }
        }
    }

    /// Settling twice, or pushing on after settling, changes no slot: the block is stored
    /// again whole with the same values.
    #[test]
    fn pushing_on_after_a_settle_keeps_every_row() {
        let width = 102;
        let mut staged = Group::new(width, 64);
        let mut plain = Group::new(width, 64);
        for r in 0..21 {
            let row: Vec<f64> = (1..width).map(|c| value(r, c)).collect();
            staged.push(value(r, 0), &row);
            plain.push_plain(value(r, 0), &row);
            if r % 5 == 0 {
                staged.settle();
                staged.settle();
            }
        }
        staged.settle();
        assert!(
            staged
                .values
                .iter()
                .zip(plain.values.iter())
                .all(|(a, b)| a.to_bits() == b.to_bits())
        );
    }
}
