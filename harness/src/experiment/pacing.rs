//! How a run on `BenchHardware` kept its schedule: the FMU's pacing and link counts recorded
//! with every experiment's run on the hardware and the study's on the bench, read back from
//! the rows ([`Pacing`]), and each row's lateness and reply time and the bench's clock recorded
//! beside them.

use super::STEP;
use crate::master::{MasterError, System};
use crate::results::Results;

/// The `BenchHardware` locals recorded after the outputs in every run on the hardware: how the
/// run kept its schedule and how its link fared ([`Pacing`]), each row's own timing (how late
/// its step's deadline was, `lastLateness`, and how long its sample took to arrive,
/// `lastReplyTime`: where in the run the host held the loop up, which a row's difference from
/// the simulated twin or a trip can then be read against), and the bench's clock at each row's
/// sample (`benchSampleTime`: `kneebench identify` resamples the log on it).
const PACING_LOCALS: [&str; 7] = [
    "plant.overrunCount",
    "plant.maxLateness",
    "plant.rejectedFrames",
    "plant.staleReplies",
    "plant.lastLateness",
    "plant.lastReplyTime",
    "plant.benchSampleTime",
];

/// How a run on `BenchHardware` kept its control period and how its link fared: the FMU's own
/// counts (`overrunCount`, `maxLateness`, `rejectedFrames`, `staleReplies`), recorded with the
/// run (in its raw file too). A loop that fell a period or more behind its schedule (steps
/// that took longer than the period, then ran back to back to catch up) sent the bench its
/// commands at uneven intervals, not every 1 ms ([`Pacing::kept_schedule`]): the rows are
/// logged at the schedule's times, the bench moved in real time.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pacing {
    /// Steps that reached their deadline already late (the period's work took longer).
    pub overruns: u64,
    /// How far behind its deadline the latest step continued \[s\].
    pub largest_lateness: f64,
    /// When: the time of the first row that recorded [`Self::largest_lateness`] \[s\] (on the
    /// runs' shared time axis when several are side by side); `None` when no step was late.
    pub largest_lateness_time: Option<f64>,
    /// Frames from the bench the FMU rejected (unauthenticated, malformed, replayed, ...).
    pub rejected_frames: u64,
    /// Replies that came too late for their request and were ignored.
    pub stale_replies: u64,
}

impl Pacing {
    /// The pacing of the runs recorded in `run`: its `plant.<local>` columns, or the
    /// `<prefix>.plant.<local>` columns of several runs side by side (the step experiment's
    /// `open.` and `closed.`), the counts added up and the largest lateness of all. `None`
    /// when `run` holds none (a run on the simulated bench).
    pub fn of(run: &Results) -> Option<Pacing> {
        let columns = |local: &str| -> Vec<Vec<f64>> {
            let name = format!("plant.{local}");
            let prefixed = format!(".{name}");
            run.names()
                .iter()
                .filter(|c| **c == name || c.ends_with(&prefixed))
                .filter_map(|c| run.column(c))
                .collect()
        };
        // Every local is a running count or maximum: a column's largest value is its last.
        let largest = |values: &[f64]| values.iter().copied().fold(0.0, f64::max);
        let lateness = columns("maxLateness");
        if lateness.is_empty() {
            return None;
        }
        let count = |local: &str| {
            columns(local)
                .iter()
                .map(|values| largest(values))
                .sum::<f64>() as u64
        };
        let largest_lateness = lateness
            .iter()
            .map(|values| largest(values))
            .fold(0.0, f64::max);
        // The running maximum first reaches its final value at the row of the latest step.
        let largest_lateness_time = (largest_lateness > 0.0)
            .then(|| {
                lateness.iter().find_map(|values| {
                    let k = values.iter().position(|&v| v >= largest_lateness)?;
                    Some(run.row(k)[0])
                })
            })
            .flatten();
        Some(Pacing {
            overruns: count("overrunCount"),
            largest_lateness,
            largest_lateness_time,
            rejected_frames: count("rejectedFrames"),
            stale_replies: count("staleReplies"),
        })
    }

    /// Whether every step continued less than one control period ([`STEP`]) after its
    /// deadline: the loop never fell a whole period behind its schedule.
    pub fn kept_schedule(&self) -> bool {
        self.largest_lateness < STEP
    }

    /// What a run that did not keep its schedule ([`Self::kept_schedule`]) means for its
    /// rows, one sentence (no final stop); `None` for one that did.
    pub fn schedule_warning(&self) -> Option<String> {
        (!self.kept_schedule()).then(|| {
            format!(
                "the loop fell up to {:.1} ms behind its {} ms schedule (steps that took longer \
                 than the period, then ran back to back to catch up): the bench got its commands \
                 at uneven intervals, while the rows are logged at the schedule's times",
                self.largest_lateness * 1e3,
                STEP * 1e3
            )
        })
    }
}

/// What the log of a run that did not keep its schedule is still good for, one clause (no
/// capital, no final stop): the experiment's section and `kneebench experiment`'s warning say it
/// in these words.
pub const LATE_LOG_USE: &str = "as a log for `kneebench identify` the run is usable as it is: \
     identification resamples it on the bench's clock (`plant.benchSampleTime`)";

/// Records the [`Pacing`] locals, each row's lateness and reply time, and the bench's sample
/// clock (`benchSampleTime`) of the `BenchHardware` component `plant` after what `system` records now (every output by
/// default): the experiments' runs and the study's on the bench.
pub(crate) fn record_pacing(system: &mut System) -> Result<(), MasterError> {
    system.record_also(&PACING_LOCALS)
}

impl std::fmt::Display for Pacing {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} overruns of the {} ms period, largest lateness {:.0} us{}; {} frames rejected, \
             {} stale replies",
            self.overruns,
            STEP * 1e3,
            self.largest_lateness * 1e6,
            self.largest_lateness_time
                .map(|t| format!(" at t = {t:.3} s"))
                .unwrap_or_default(),
            self.rejected_frames,
            self.stale_replies
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::results::ColumnKind;

    fn table(names: &[&str], rows: &[&[f64]]) -> Results {
        let mut r = Results::with_capacity(
            names.iter().map(|n| n.to_string()).collect(),
            vec![ColumnKind::Real; names.len()],
            rows.len(),
        );
        for (k, row) in rows.iter().enumerate() {
            r.push_row(k as f64 * STEP, row);
        }
        r
    }

    #[test]
    fn pacing_is_read_from_the_hardware_locals_and_added_up_over_runs() {
        // The simulated bench records none of the locals.
        let plant = table(&["plant.actuationAngle"], &[&[0.0], &[1.0]]);
        assert_eq!(Pacing::of(&plant), None);
        // One run: the running counts' last values.
        let names = [
            "plant.actuationAngle",
            "plant.overrunCount",
            "plant.maxLateness",
            "plant.rejectedFrames",
            "plant.staleReplies",
        ];
        let one = table(
            &names,
            &[
                &[0.0, 0.0, 2e-5, 0.0, 0.0],
                &[0.1, 2.0, 4.5e-4, 1.0, 3.0],
                &[0.2, 2.0, 4.5e-4, 1.0, 3.0],
            ],
        );
        let p = Pacing::of(&one).unwrap();
        assert_eq!(
            p,
            Pacing {
                overruns: 2,
                largest_lateness: 4.5e-4,
                // The row that first recorded it (the second, at 1 ms), not a later one.
                largest_lateness_time: Some(STEP),
                rejected_frames: 1,
                stale_replies: 3
            }
        );
        assert!(p.kept_schedule());
        assert_eq!(
            p.to_string(),
            "2 overruns of the 1 ms period, largest lateness 450 us at t = 0.001 s; 1 frames \
             rejected, 3 stale replies"
        );
        // A run that was never late says no time.
        let on_time = table(&names[1..3], &[&[0.0, 0.0], &[0.0, 0.0]]);
        let p = Pacing::of(&on_time).unwrap();
        assert_eq!(p.largest_lateness_time, None);
        assert_eq!(
            p.to_string(),
            "0 overruns of the 1 ms period, largest lateness 0 us; 0 frames rejected, 0 stale \
             replies"
        );
        // Two runs side by side (the step experiment): counts added, the larger lateness.
        let mut both: Vec<String> = names.iter().map(|n| format!("open.{n}")).collect();
        both.extend(names.iter().map(|n| format!("closed.{n}")));
        let both: Vec<&str> = both.iter().map(String::as_str).collect();
        let two = table(
            &both,
            &[
                &[0.0, 1.0, 1e-4, 0.0, 0.0, 0.0, 5.0, 2e-4, 2.0, 0.0],
                &[0.0, 1.0, 3e-4, 0.0, 0.0, 0.0, 5.0, 2e-4, 2.0, 0.0],
                &[0.0, 1.0, 3e-4, 0.0, 0.0, 0.0, 5.0, 1.2e-3, 2.0, 0.0],
            ],
        );
        let p = Pacing::of(&two).unwrap();
        assert_eq!((p.overruns, p.rejected_frames, p.stale_replies), (6, 2, 0));
        assert_eq!(p.largest_lateness, 1.2e-3);
        // When: in the closed run, whose maximum came later than the open run's.
        assert_eq!(p.largest_lateness_time, Some(2.0 * STEP));
        // A whole period late is a command held two periods: not the 1 ms loop any more.
        assert!(!p.kept_schedule());
        // A column that only ends like a local (another component's) is not one.
        let other = table(&["gait.maxLateness"], &[&[1.0]]);
        assert_eq!(Pacing::of(&other), None);
    }
}
