//! Rows recorded column by column in memory: the layout a data frame holds (pandas keeps a
//! frame of floats as one block, column after column), so that handing a run's results to
//! Python takes no transposition and no copy.
//!
//! [`Results`](super::Results) keeps rows one after the other, which suits reading a row and
//! the CSV; turning 100 columns of 100,001 rows into columns then took a strided pass over
//! all the rows per column and a copy of every value, on top of the copy to Python and
//! NumPy's own. [`Columns`] stores each value of a row at its place in its column instead (one
//! store per value, as the Parquet writer's row group does), in one buffer of `stride` slots
//! per column; [`Columns::into_column_major`] closes the gaps and gives the buffer away.

use super::{ColumnKind, ResultSink, ResultsError};

/// Slots per column reserved before the run announces its rows.
const INITIAL_STRIDE: usize = 1024;

/// Recorded rows, column by column (see the [module documentation](self)).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Columns {
    names: Vec<String>,
    kinds: Vec<ColumnKind>,
    rows: usize,
    /// Slots per column in `values`.
    stride: usize,
    /// `time`'s slots, then each column's: `(names.len() + 1) * stride` values.
    values: Vec<f64>,
}

/// Rows as one buffer of columns without gaps, from [`Columns::into_column_major`].
#[derive(Debug, Clone, PartialEq)]
pub struct ColumnMajor {
    /// The columns' names, `time` excluded.
    pub names: Vec<String>,
    /// The columns' kinds, `time` excluded.
    pub kinds: Vec<ColumnKind>,
    /// Rows (values per column).
    pub rows: usize,
    /// `time`'s `rows` values, then each column's.
    pub values: Vec<f64>,
}

impl Columns {
    /// No rows, no columns yet (they come with [`ResultSink::begin`]).
    pub fn new() -> Columns {
        Columns::default()
    }

    /// Rows stored.
    pub fn len(&self) -> usize {
        self.rows
    }

    /// Whether no row is stored.
    pub fn is_empty(&self) -> bool {
        self.rows == 0
    }

    /// The columns' names (`time` excluded).
    pub fn names(&self) -> &[String] {
        &self.names
    }

    /// Column `j` (0: `time`, then the named columns in order), `None` past the last.
    pub fn column(&self, j: usize) -> Option<&[f64]> {
        (j <= self.names.len()).then(|| &self.values[j * self.stride..j * self.stride + self.rows])
    }

    /// The rows as one buffer of columns without gaps (the gaps of unused slots closed in
    /// place, no second buffer).
    pub fn into_column_major(mut self) -> ColumnMajor {
        let (rows, stride) = (self.rows, self.stride);
        if stride != rows {
            for j in 1..=self.names.len() {
                self.values
                    .copy_within(j * stride..j * stride + rows, j * rows);
            }
            self.values.truncate((self.names.len() + 1) * rows);
        }
        ColumnMajor {
            names: self.names,
            kinds: self.kinds,
            rows,
            values: self.values,
        }
    }

    /// Moves the columns into a buffer of `stride` slots each (`stride >= rows`), or returns
    /// [`ResultsError::OutOfMemory`] with everything kept.
    fn restride(&mut self, stride: usize) -> Result<(), ResultsError> {
        let width = self.names.len() + 1;
        let out_of_memory = || ResultsError::OutOfMemory {
            rows: self.rows,
            columns: width,
        };
        let len = width.checked_mul(stride).ok_or_else(out_of_memory)?;
        let mut values = zeroed(len).ok_or_else(out_of_memory)?;
        // Before `begin` has sized it there is nothing to move.
        let filled = if self.stride == 0 { 0 } else { width };
        for j in 0..filled {
            let from = j * self.stride;
            values[j * stride..j * stride + self.rows]
                .copy_from_slice(&self.values[from..from + self.rows]);
        }
        self.values = values;
        self.stride = stride;
        Ok(())
    }
}

/// `len` zeroed doubles, or `None` when the allocator refuses them. Taken zeroed from the
/// allocator (`calloc`), so a big buffer comes as pages the kernel zeroes when first written,
/// not written twice.
fn zeroed(len: usize) -> Option<Vec<f64>> {
    if len == 0 {
        return Some(Vec::new());
    }
    let layout = std::alloc::Layout::array::<f64>(len).ok()?;
    // SAFETY: `layout` has a non-zero size (len > 0, f64 is 8 bytes).
    let ptr = unsafe { std::alloc::alloc_zeroed(layout) }.cast::<f64>();
    if ptr.is_null() {
        return None;
    }
    // SAFETY: `ptr` was allocated by the global allocator with the layout of `len` doubles
    // (so capacity `len`), and all-zero bytes are the double 0.0: the `len` values are
    // initialised.
    Some(unsafe { Vec::from_raw_parts(ptr, len, len) })
}

impl ResultSink for Columns {
    fn begin(&mut self, names: &[String], kinds: &[ColumnKind]) -> Result<(), ResultsError> {
        if self.rows > 0 && (self.names != names || self.kinds != kinds) {
            return Err(ResultsError::RowLength {
                expected: self.names.len(),
                got: names.len(),
            });
        }
        if self.rows == 0 {
            self.names = names.to_vec();
            self.kinds = kinds.to_vec();
            self.stride = 0;
            self.values = Vec::new();
            self.restride(INITIAL_STRIDE)?;
        }
        Ok(())
    }

    #[inline]
    fn push_row(&mut self, time: f64, values: &[f64]) -> Result<(), ResultsError> {
        if values.len() != self.names.len() {
            return Err(ResultsError::RowLength {
                expected: self.names.len(),
                got: values.len(),
            });
        }
        if self.rows == self.stride {
            self.restride(self.stride.saturating_mul(2).max(INITIAL_STRIDE))?;
        }
        let row = self.rows;
        let mut columns = self.values.chunks_exact_mut(self.stride);
        if let Some(time_column) = columns.next() {
            time_column[row] = time;
        }
        for (column, &v) in columns.zip(values) {
            column[row] = v;
        }
        self.rows += 1;
        Ok(())
    }

    fn flush(&mut self) -> Result<(), ResultsError> {
        Ok(())
    }

    /// Room for all `rows` at once, so that no column moves during the run (room refused is
    /// not an error here: the columns then grow as rows come).
    fn expect_rows(&mut self, rows: u64) {
        if let Ok(rows) = usize::try_from(rows)
            && rows > self.stride
            && !self.names.is_empty()
        {
            let _ = self.restride(rows);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::results::Results;
    use crate::results::test_rows;

    fn names(n: usize) -> (Vec<String>, Vec<ColumnKind>) {
        let names = (0..n).map(|j| format!("c{j}")).collect();
        let kinds = (0..n)
            .map(|j| match j % 3 {
                0 => ColumnKind::Real,
                1 => ColumnKind::Integer,
                _ => ColumnKind::Boolean,
            })
            .collect();
        (names, kinds)
    }

    /// The columns hold the values `Results` holds, bit for bit, whether the run announced
    /// its rows exactly, too few (the columns grow) or too many (it ended early).
    #[test]
    fn the_columns_are_the_rows_bit_for_bit() {
        let rows: Vec<(f64, Vec<f64>)> = (0..2_500).map(|k| test_rows::row(k, 7)).collect();
        let (names, kinds) = names(7);
        let mut plain = Results::with_capacity(Vec::new(), Vec::new(), 0);
        plain.begin(&names, &kinds).unwrap();
        for (t, v) in &rows {
            ResultSink::push_row(&mut plain, *t, v).unwrap();
        }
        for announced in [None, Some(2_500), Some(100), Some(10_000)] {
            let mut columns = Columns::new();
            columns.begin(&names, &kinds).unwrap();
            if let Some(n) = announced {
                columns.expect_rows(n);
            }
            for (t, v) in &rows {
                columns.push_row(*t, v).unwrap();
            }
            assert_eq!(columns.len(), 2_500);
            for j in 0..=7 {
                let want: Vec<u64> = plain.rows().map(|r| r[j].to_bits()).collect();
                let got: Vec<u64> = columns
                    .column(j)
                    .unwrap()
                    .iter()
                    .map(|v| v.to_bits())
                    .collect();
                assert_eq!(got, want, "column {j}, announced {announced:?}");
            }
            assert!(columns.column(8).is_none());
            let major = columns.clone().into_column_major();
            assert_eq!((major.rows, major.values.len()), (2_500, 8 * 2_500));
            for j in 0..=7 {
                assert_eq!(
                    major.values[j * 2_500..(j + 1) * 2_500]
                        .iter()
                        .map(|v| v.to_bits())
                        .collect::<Vec<_>>(),
                    columns
                        .column(j)
                        .unwrap()
                        .iter()
                        .map(|v| v.to_bits())
                        .collect::<Vec<_>>(),
                );
            }
            assert_eq!((major.names, major.kinds), (names.clone(), kinds.clone()));
        }
    }

    #[test]
    fn a_row_of_the_wrong_length_and_other_columns_are_refused() {
        let (names, kinds) = names(3);
        let mut columns = Columns::new();
        columns.begin(&names, &kinds).unwrap();
        let e = columns.push_row(0.0, &[1.0, 2.0]).unwrap_err();
        assert!(
            matches!(
                e,
                ResultsError::RowLength {
                    expected: 3,
                    got: 2
                }
            ),
            "{e:?}"
        );
        columns.push_row(0.0, &[1.0, 2.0, 3.0]).unwrap();
        let (other, other_kinds) = names_of(&["x"]);
        assert!(columns.begin(&other, &other_kinds).is_err());
        assert_eq!(columns.column(3), Some(&[3.0][..]));
        let empty = Columns::new().into_column_major();
        assert_eq!((empty.rows, empty.values.len()), (0, 0));
    }

    fn names_of(n: &[&str]) -> (Vec<String>, Vec<ColumnKind>) {
        (
            n.iter().map(|s| s.to_string()).collect(),
            vec![ColumnKind::Real; n.len()],
        )
    }

    /// Room the allocator refuses is an error naming the rows, with the rows kept; an
    /// announcement the allocator refuses is ignored.
    #[test]
    fn refused_room_keeps_the_rows() {
        let (names, kinds) = names(2);
        let mut columns = Columns::new();
        columns.begin(&names, &kinds).unwrap();
        columns.push_row(0.5, &[1.0, 2.0]).unwrap();
        columns.expect_rows(u64::MAX / 4);
        let e = columns.restride(usize::MAX / 64).unwrap_err();
        assert!(
            matches!(
                e,
                ResultsError::OutOfMemory {
                    rows: 1,
                    columns: 3
                }
            ),
            "{e:?}"
        );
        columns.push_row(1.5, &[3.0, 4.0]).unwrap();
        assert_eq!(columns.column(0), Some(&[0.5, 1.5][..]));
        assert_eq!(columns.column(2), Some(&[2.0, 4.0][..]));
    }
}
