//! A log resampled onto the bench's own clock.
//!
//! A master that runs late (a loaded host: a step that took longer than the period, then steps
//! back to back to catch up) still logs its rows at the schedule's times `t0 + k dt`, while the
//! bench took each row's readings when the request reached it. `BenchHardware` records that
//! time as `benchSampleTime` (the bench's clock, to the microsecond over UDP). Read as if on the
//! schedule, such a log has rows a stall apart labelled one period apart, then rows a fraction
//! of a period apart: the finite differences of the angles (the regressions' velocities and
//! accelerations) and the refinement's drive are wrong exactly there, and a few stalls widen
//! the intervals of the slow load side several times (stop 37's identification over the
//! emulated bench).
//!
//! So a log with the column is resampled onto a uniform grid of the bench's clock, from its
//! first sample at the log's first time: each channel linearly interpolated between the two
//! samples around a grid time. The set value `drive.u` is interpolated too: it is sent right
//! after its row's sample (the master's computation, tens of microseconds), so it changes at
//! that sample's bench time, and a grid time near it takes it in proportion. A row the schedule
//! and the bench's clock agree on exactly is taken as it is, bit for bit; a log whose every
//! row agrees is used unchanged. Grid rows inside a gap longer than [`MAX_INTERPOLATED_GAP`]
//! periods (a stall long enough for the motion between its samples to be far from a straight
//! line) are not used by the regressions nor compared by the refinement.
//!
//! The times are compared in whole nanoseconds, so that a clock kept in microseconds and a
//! period of 1 ms land on the grid exactly.

/// The column holding the bench's clock at each row's sample \[s\] (a `plant.` prefix, as the
/// experiments write, is accepted).
pub const BENCH_SAMPLE_TIME: &str = "benchSampleTime";

/// The longest gap between two samples, in periods, that grid rows inside it are interpolated
/// across for use (a longer one's rows are interpolated but not used).
pub const MAX_INTERPOLATED_GAP: f64 = 5.0;

/// The largest bench time accepted \[s\] (about 31 years: its nanoseconds fit an `i64` many
/// times over).
pub const MAX_CLOCK: f64 = 1e9;

/// Periods a bench's clock may span beyond twice a log's rows (a long pause before the first
/// step, say) before it is refused as not the log's.
pub const SPARE_ROWS: i64 = 10_000;

/// Where each row of the bench clock's grid falls among the logged samples.
#[derive(Debug, Clone, PartialEq)]
pub struct Resampling {
    /// Per grid row: where it falls.
    at: Vec<Place>,
    /// The largest gap between consecutive samples \[s\] and the logged row it ends at.
    largest_gap: (f64, usize),
    /// Grid rows inside a gap longer than [`MAX_INTERPOLATED_GAP`] periods.
    inside_long_gaps: usize,
}

/// Where a grid row falls among the logged samples.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Place {
    /// The logged row at or before it.
    row: usize,
    /// How far it is towards the next logged row (0 exactly when the grid time is the row's
    /// sample time).
    fraction: f64,
    /// Whether the gap between the two is longer than [`MAX_INTERPOLATED_GAP`] periods.
    in_long_gap: bool,
}

/// Whole nanoseconds of `seconds` (times of a log: far inside `i64`).
fn nanoseconds(seconds: f64) -> i64 {
    (seconds * 1e9).round() as i64
}

impl Resampling {
    /// The grid of step `dt` \[s\] over the bench's sample times `bench` \[s\], which must be
    /// finite, within [`MAX_CLOCK`] of zero and strictly increasing, and span at most twice
    /// the log's rows and [`SPARE_ROWS`] periods (a clock that is not this log's would make a
    /// grid of any size); otherwise the offending row and what is wrong.
    pub fn plan(bench: &[f64], dt: f64) -> Result<Resampling, (usize, String)> {
        if bench.is_empty() {
            return Err((0, format!("{BENCH_SAMPLE_TIME} has no rows")));
        }
        if let Some(i) = bench.iter().position(|t| !t.is_finite()) {
            return Err((i, format!("{BENCH_SAMPLE_TIME} is {}", bench[i])));
        }
        if let Some(i) = bench.iter().position(|t| t.abs() > MAX_CLOCK) {
            return Err((
                i,
                format!(
                    "{BENCH_SAMPLE_TIME} {} s is beyond {MAX_CLOCK:e} s: not a bench's clock",
                    bench[i]
                ),
            ));
        }
        let step = nanoseconds(dt);
        if step <= 0 {
            return Err((0, format!("the log's period {dt} s is below a nanosecond")));
        }
        let origin = nanoseconds(bench[0]);
        let offsets: Vec<i64> = bench.iter().map(|t| nanoseconds(*t) - origin).collect();
        if let Some(i) = (1..offsets.len()).find(|&i| offsets[i] <= offsets[i - 1]) {
            return Err((
                i,
                format!(
                    "{BENCH_SAMPLE_TIME} {} does not increase (previous {})",
                    bench[i],
                    bench[i - 1]
                ),
            ));
        }
        let last = *offsets.last().unwrap_or(&0);
        let rows = last / step + 1;
        if rows > 2 * offsets.len() as i64 + SPARE_ROWS {
            return Err((
                offsets.len() - 1,
                format!(
                    "{BENCH_SAMPLE_TIME} spans {} s over {} rows of {dt} s: more than twice the rows' time and {SPARE_ROWS} periods, not the clock of this log's samples",
                    last as f64 * 1e-9,
                    offsets.len()
                ),
            ));
        }
        let long = (MAX_INTERPOLATED_GAP * step as f64) as i64;
        let mut at = Vec::with_capacity(offsets.len());
        let mut inside_long_gaps = 0;
        let mut k = 0;
        let mut grid = 0i64;
        while grid <= last {
            while k + 1 < offsets.len() && offsets[k + 1] <= grid {
                k += 1;
            }
            let place = if offsets[k] == grid {
                Place {
                    row: k,
                    fraction: 0.0,
                    in_long_gap: false,
                }
            } else {
                let gap = offsets[k + 1] - offsets[k];
                Place {
                    row: k,
                    fraction: (grid - offsets[k]) as f64 / gap as f64,
                    in_long_gap: gap > long,
                }
            };
            inside_long_gaps += usize::from(place.in_long_gap);
            at.push(place);
            grid += step;
        }
        let largest_gap = (1..offsets.len())
            .map(|i| (offsets[i] - offsets[i - 1], i))
            .max()
            .map_or((0.0, 0), |(gap, i)| (gap as f64 * 1e-9, i));
        Ok(Resampling {
            at,
            largest_gap,
            inside_long_gaps,
        })
    }

    /// Whether every grid row is a logged row in order: the bench's clock agrees with the
    /// schedule exactly, and the log is used as it is.
    pub fn is_identity(&self, rows: usize) -> bool {
        self.at.len() == rows
            && self
                .at
                .iter()
                .enumerate()
                .all(|(j, p)| p.row == j && p.fraction == 0.0)
    }

    /// Grid rows.
    pub fn len(&self) -> usize {
        self.at.len()
    }

    /// Whether the grid has no row (never: the first sample is on it).
    pub fn is_empty(&self) -> bool {
        self.at.is_empty()
    }

    /// The largest gap between consecutive samples \[s\] and the logged row it ends at.
    pub fn largest_gap(&self) -> (f64, usize) {
        self.largest_gap
    }

    /// Grid rows inside a gap longer than [`MAX_INTERPOLATED_GAP`] periods.
    pub fn inside_long_gaps(&self) -> usize {
        self.inside_long_gaps
    }

    /// A logged channel on the grid: interpolated between the samples around each grid time,
    /// the sample itself where the grid time is its time. `logged` has a value per logged row
    /// (the length of the clock planned on); a shorter one is a caller's error and panics.
    pub fn apply(&self, logged: &[f64]) -> Vec<f64> {
        self.at
            .iter()
            .map(|p| {
                let k = p.row;
                if p.fraction == 0.0 {
                    logged[k]
                } else {
                    logged[k] + p.fraction * (logged[k + 1] - logged[k])
                }
            })
            .collect()
    }

    /// Which grid rows may be used, from the logged rows': both samples around a grid time
    /// usable (only the sample itself where the grid time is its time), and the gap between
    /// them no longer than [`MAX_INTERPOLATED_GAP`] periods.
    pub fn usable(&self, logged: &[bool]) -> Vec<bool> {
        self.at
            .iter()
            .map(|p| logged[p.row] && (p.fraction == 0.0 || (logged[p.row + 1] && !p.in_long_gap)))
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Bench times in microseconds, as the UDP link gives them.
    fn micros(us: &[u64]) -> Vec<f64> {
        us.iter().map(|u| *u as f64 * 1e-6).collect()
    }

    #[test]
    fn a_clock_that_agrees_with_the_schedule_is_the_log_itself() {
        // From any origin, in microseconds or on the simulated bench's float times.
        let bench = micros(&(0..500).map(|k| 123_456 + 1000 * k).collect::<Vec<_>>());
        let r = Resampling::plan(&bench, 1e-3).unwrap();
        assert!(r.is_identity(500));
        let values: Vec<f64> = (0..500).map(|k| (k as f64 * 0.37).sin()).collect();
        assert_eq!(r.apply(&values), values);
        let float_times: Vec<f64> = (0..500).map(|k| 0.25 + k as f64 * 1e-3).collect();
        assert!(
            Resampling::plan(&float_times, 1e-3)
                .unwrap()
                .is_identity(500)
        );
        // One microsecond off is not the schedule.
        let mut off = bench.clone();
        off[250] += 1e-6;
        assert!(!Resampling::plan(&off, 1e-3).unwrap().is_identity(500));
    }

    #[test]
    fn a_stall_and_its_catch_up_are_put_back_on_the_bench_clock() {
        // The rows' samples: on the schedule to 3 ms, then a 2.8 ms stall, then three steps
        // back to back, 0.1 ms apart, then on the (late) schedule again.
        let bench = micros(&[0, 1000, 2000, 3000, 5800, 5900, 6000, 7000, 8000]);
        let r = Resampling::plan(&bench, 1e-3).unwrap();
        assert_eq!(r.len(), 9);
        assert!(!r.is_identity(9));
        let (gap, ends_at) = r.largest_gap();
        assert!(
            (gap - 2.8e-3).abs() < 1e-15 && ends_at == 4,
            "{gap} {ends_at}"
        );
        assert_eq!(r.inside_long_gaps(), 0);
        // A ramp in bench time, logged at the samples, is the ramp on the grid.
        let ramp: Vec<f64> = bench.iter().map(|t| 2.0 + 50.0 * t).collect();
        let on_grid = r.apply(&ramp);
        for (j, v) in on_grid.iter().enumerate() {
            let expected = 2.0 + 50.0 * (j as f64 * 1e-3);
            assert!(
                (v - expected).abs() < 1e-12,
                "row {j}: {v} against {expected}"
            );
        }
        // Exact at the rows the clock and the grid share.
        for j in [0, 1, 2, 3, 6, 7, 8] {
            let k = bench
                .iter()
                .position(|t| (t - j as f64 * 1e-3).abs() < 1e-12)
                .unwrap();
            assert_eq!(on_grid[j].to_bits(), ramp[k].to_bits(), "row {j}");
        }
        // Read on the schedule instead, the ramp's slope is wrong around the stall.
        let schedule_slope = (ramp[4] - ramp[3]) / 1e-3;
        assert!((schedule_slope - 140.0).abs() < 1e-9, "{schedule_slope}");
        let grid_slope = (on_grid[4] - on_grid[3]) / 1e-3;
        assert!((grid_slope - 50.0).abs() < 1e-9, "{grid_slope}");
    }

    #[test]
    fn usable_rows_need_both_samples_and_a_short_gap() {
        let bench = micros(&[0, 1000, 2000, 3000, 10_000, 11_000, 12_000]);
        let r = Resampling::plan(&bench, 1e-3).unwrap();
        assert_eq!(r.len(), 13);
        // Grid 4-9 ms lie inside the 7 ms gap: interpolated, not used.
        assert_eq!(r.inside_long_gaps(), 6);
        let all = vec![true; 7];
        let u = r.usable(&all);
        let expected: Vec<bool> = (0..13).map(|j| !(4..=9).contains(&j)).collect();
        assert_eq!(u, expected);
        // An excluded sample excludes the grid rows interpolated from it.
        let mut some = all.clone();
        some[1] = false;
        let u = r.usable(&some);
        assert!(u[0] && !u[1] && u[2]);
        // With samples half-way, an excluded one touches both grid rows around it.
        let half = micros(&[0, 500, 1500, 2500, 3000]);
        let r = Resampling::plan(&half, 1e-3).unwrap();
        let mut flags = vec![true; 5];
        flags[2] = false;
        assert_eq!(r.usable(&flags), vec![true, false, false, true]);
    }

    #[test]
    fn a_clock_that_does_not_increase_or_is_not_finite_is_refused_with_its_row() {
        let (row, why) = Resampling::plan(&micros(&[0, 1000, 1000, 3000]), 1e-3).unwrap_err();
        assert_eq!(row, 2);
        assert!(why.contains("does not increase"), "{why}");
        let (row, why) = Resampling::plan(&[0.0, 1e-3, f64::NAN], 1e-3).unwrap_err();
        assert_eq!(row, 2);
        assert!(why.contains("NaN"), "{why}");
        let (row, why) = Resampling::plan(&[0.0, 2e-3, 1e-3], 1e-3).unwrap_err();
        assert_eq!(row, 2);
        assert!(why.contains("does not increase"), "{why}");
        assert!(
            Resampling::plan(&[], 1e-3)
                .unwrap_err()
                .1
                .contains("no rows")
        );
        assert!(
            Resampling::plan(&[0.0, 1e-3], f64::NAN)
                .unwrap_err()
                .1
                .contains("below a nanosecond")
        );
        // Times whose nanoseconds would not fit, and a clock that would make a huge grid.
        let (row, why) = Resampling::plan(&[0.0, 1e-3, 1e19], 1e-3).unwrap_err();
        assert_eq!(row, 2);
        assert!(why.contains("not a bench's clock"), "{why}");
        let (row, why) = Resampling::plan(&[0.0, 1e-3, 1e6], 1e-3).unwrap_err();
        assert_eq!(row, 2);
        assert!(why.contains("more than twice"), "{why}");
        // Twice the rows' time and more is still a clock (a master that lost half its rows'
        // time, a pause before the first step).
        assert_eq!(
            Resampling::plan(&micros(&[0, 2000, 4000, 5000]), 1e-3)
                .unwrap()
                .len(),
            6
        );
        assert_eq!(Resampling::plan(&[0.0, 10.0], 1e-3).unwrap().len(), 10_001);
    }
}
