//! The bench link's fault campaign (`docs/bench-protocol.md`; README, "Fault campaign"): every
//! fault the hardware path must survive, each run as a user runs the bench, through the
//! master writing a streamed CSV file (`kneebench run --output`'s sink), against the emulator
//! on loopback with the bench key.
//!
//! For each case [`run_case`] observes, and [`Observation::check`] compares with the case's
//! [`Expected`] reaction:
//! * the master's trip code (from its outcome) and whether the bench confirmed its safe state;
//! * the latency in control periods, counted by the emulator as HEARTBEAT datagrams (one per
//!   control period) between the fault and the master's first SAFE_STATE request; for a
//!   master that is gone, the server watchdog's delay after the last valid frame;
//! * the bench's latch after the case, and that it needs an authenticated acknowledgement: a
//!   fresh session (a master speaking the protocol by hand) inherits it, its drive command is
//!   not applied, an acknowledgement of another reason is refused, the right one clears it
//!   (after the fault is gone, for a fault that persists);
//! * no drive command after the trip (the emulator's counters of drive commands received in
//!   the safe state and after the master's safe-state request);
//! * the file read back: every row the master handed to the sink is on disk, complete, on the
//!   time grid from 0 to the end of the run (a master killed with SIGKILL writes its rows
//!   through, `kneebench run --flush-every-row`: every row it made but possibly the one of its
//!   last exchange).
//!
//! The quick set is `tests/tests/campaign.rs`; the long campaign, every case N times with a
//! table, is `tests/benches/campaign.rs`.

use std::net::UdpSocket;
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::time::{Duration, Instant};

use kneebench_fmu::models::bench_hardware::trip;
use kneebench_harness::bench_protocol::{
    Acknowledge, BenchSetup, ClientHandshake, Command, FaultInjection, HandshakeReply, Key,
    LinkDirection, Payload, SafeStateRequest, Sample, Session, SetValueKind, reason, refusal,
    status,
};
use kneebench_harness::emulator::{EmulatorConfig, EmulatorHandle, EmulatorStats, spawn};
use kneebench_harness::master::Signal;
use kneebench_harness::results::csv::{CsvFile, partial_path};
use kneebench_harness::{Fmu, LoadOptions, Outcome, RunConfig, System};

/// The control period \[s\].
pub const H: f64 = 1e-3;

/// The server's heartbeat timeout (the protocol's default) \[s\].
pub const HEARTBEAT_TIMEOUT: f64 = 0.05;

/// The environment variable that makes a test or benchmark binary the master process of the
/// SIGKILL case ([`child_master_if_asked`]).
pub const CHILD_ENV: &str = "KNEEBENCH_CAMPAIGN_MASTER";

/// What happens to the bench.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Fault {
    /// Injected into the emulator in process during the run.
    Inject(FaultInjection),
    /// The master's process is killed with SIGKILL during the run.
    KillMaster,
    /// The server stops during the run and a new one starts on the same address with the
    /// same state file.
    RestartServer,
}

/// What the bench path must do.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Expected {
    /// The master trips with `code`, `periods.0` to `periods.1` control periods after the
    /// fault; the bench latches `latch`; `confirmed`: the bench acknowledged the master's safe
    /// state (`fmi2Discard`), else the run ends in `fmi2Error` (the link is gone) and the
    /// server's own watchdog or state makes the bench safe.
    Trip {
        /// The master's trip code.
        code: i32,
        /// The latch's reason.
        latch: u8,
        /// Latency bounds in control periods.
        periods: (u64, u64),
        /// Whether the safe state is confirmed to the master.
        confirmed: bool,
    },
    /// The master is gone: the server's watchdog latches (reason 2) `periods.0` to
    /// `periods.1` control periods after the last valid frame.
    Watchdog {
        /// Latency bounds in control periods.
        periods: (u64, u64),
    },
    /// Nothing trips: a fault the link absorbs, or one below what the checks can see
    /// (the case's note says which); the run completes with every row.
    Completes,
}

/// One case of the campaign.
#[derive(Debug, Clone)]
pub struct Case {
    /// Its name in the table.
    pub name: &'static str,
    /// The fault.
    pub fault: Fault,
    /// The reaction it must get.
    pub expected: Expected,
    /// Actuator configuration (0 DA, 1 SEA).
    pub configuration: i32,
    /// The test motor's current ramps (25 A/s) against a load side held by friction, so the
    /// torques grow (a stuck sensor shows); otherwise a steady 0.5 A.
    pub ramp: bool,
    /// Control periods into the run at which the fault comes.
    pub at: u64,
    /// Why the reaction is what it is.
    pub note: &'static str,
}

const TO_CLIENT: LinkDirection = LinkDirection::ToClient;
const TO_SERVER: LinkDirection = LinkDirection::ToServer;

/// A trip that the bench confirms.
const fn trip(code: i32, latch: u8, periods: (u64, u64)) -> Expected {
    Expected::Trip {
        code,
        latch,
        periods,
        confirmed: true,
    }
}

fn case(name: &'static str, fault: FaultInjection, expected: Expected, note: &'static str) -> Case {
    Case {
        name,
        fault: Fault::Inject(fault),
        expected,
        configuration: 0,
        ramp: false,
        at: 150,
        note,
    }
}

/// Every case of the campaign.
pub fn cases() -> Vec<Case> {
    use FaultInjection as F;
    let one = (1, 1);
    let client = reason::CLIENT_REQUEST;
    let persistence = (10, 10);
    vec![
        case(
            "reply dropped",
            F::DropReplies { count: 1 },
            trip(8, client, one),
            "no sample within replyTimeout",
        ),
        case(
            "reply delayed 20 ms",
            F::DelayReplies {
                count: 1,
                delay_s: 0.02,
            },
            trip(8, client, one),
            "no sample within replyTimeout; the late one is ignored",
        ),
        case(
            "reply duplicated",
            F::Duplicate {
                direction: TO_CLIENT,
                count: 1,
            },
            Expected::Completes,
            "the copy is refused as a replay (rejectedFrames)",
        ),
        case(
            "master frame duplicated",
            F::Duplicate {
                direction: TO_SERVER,
                count: 1,
            },
            Expected::Completes,
            "the copy is refused as a replay by the server",
        ),
        case(
            "replies reordered",
            F::Reorder {
                direction: TO_CLIENT,
            },
            trip(8, client, one),
            "the held sample misses its deadline; it arrives after the next reply, out of order",
        ),
        case(
            "master frames reordered",
            F::Reorder {
                direction: TO_SERVER,
            },
            trip(8, client, one),
            "a held command: the sample does not confirm it; a held heartbeat: no sample; the late frame is refused as out of order",
        ),
        case(
            "reply corrupted",
            F::Corrupt {
                direction: TO_CLIENT,
                count: 1,
            },
            trip(8, client, one),
            "the tag fails: no valid sample within replyTimeout",
        ),
        case(
            "master frame corrupted",
            F::Corrupt {
                direction: TO_SERVER,
                count: 1,
            },
            trip(8, client, one),
            "the tag fails at the server: the command is not confirmed, or the heartbeat not answered",
        ),
        case(
            "link cut",
            F::Silence,
            Expected::Trip {
                code: 8,
                latch: reason::HEARTBEAT_TIMEOUT,
                periods: one,
                confirmed: false,
            },
            "the master trips at once but cannot confirm; the server's watchdog latches",
        ),
        Case {
            name: "master killed (SIGKILL)",
            fault: Fault::KillMaster,
            expected: Expected::Watchdog { periods: (50, 100) },
            configuration: 0,
            ramp: false,
            at: 1500,
            note: "the server's watchdog (50 ms) latches; rows up to the CSV sink's last flush (once a second) are on disk",
        },
        Case {
            name: "server restarted",
            fault: Fault::RestartServer,
            expected: Expected::Trip {
                code: 8,
                latch: reason::SERVER_RESTART,
                periods: one,
                confirmed: false,
            },
            configuration: 0,
            ramp: false,
            at: 150,
            note: "the new server does not know the session: no sample; it starts latched from its state file",
        },
        Case {
            name: "transducer stuck (SEA)",
            fault: Fault::Inject(F::Stuck { channel: 1 }),
            expected: trip(12, client, (10, 200)),
            configuration: 1,
            ramp: true,
            at: 50,
            note: "consistency: 10 samples after the torque leaves the stuck reading's allowance",
        },
        case(
            "transducer forced to 9 V",
            F::Force {
                channel: 1,
                volts: 9.0,
            },
            trip(10, client, one),
            "outside its plausibility window",
        ),
        case(
            "load cell noise 0.1 V",
            F::Noise {
                channel: 0,
                volts: 0.1,
                seed: 1,
            },
            trip(10, client, (1, 20)),
            "leaves its window (+-0.03 V) in the first sample that draws beyond it",
        ),
        case(
            "load cell noise 2 mV (9.5 N m)",
            F::Noise {
                channel: 0,
                volts: 0.002,
                seed: 1,
            },
            trip(13, client, (10, 400)),
            "consistency with the motor current: 10 disagreeing samples in a row",
        ),
        case(
            "load cell noise 0.1 mV (0.5 N m)",
            F::Noise {
                channel: 0,
                volts: 1e-4,
                seed: 1,
            },
            Expected::Completes,
            "below the consistency allowance (1 N m + 25 %): not detectable, by design",
        ),
        Case {
            name: "transducer offset 20 mV (-11.9 N m, SEA)",
            fault: Fault::Inject(F::Offset {
                channel: 1,
                volts: 0.02,
            }),
            expected: trip(12, client, persistence),
            configuration: 1,
            ramp: false,
            at: 150,
            note: "inside its window; the spring deflection disagrees: 10 samples",
        },
        case(
            "transducer offset 20 mV (DA)",
            F::Offset {
                channel: 1,
                volts: 0.02,
            },
            Expected::Completes,
            "not detectable in DA (no spring to compare with); only the torque interlock's margin shrinks",
        ),
        case(
            "load cell offset 2 mV (9.5 N m)",
            F::Offset {
                channel: 0,
                volts: 0.002,
            },
            trip(13, client, persistence),
            "inside its window; the motor current disagrees: 10 samples",
        ),
        case(
            "test current sensor offset 0.1 V (1 A)",
            F::Offset {
                channel: 2,
                volts: 0.1,
            },
            trip(13, client, persistence),
            "inside its window; the load cell disagrees with the torque it implies: 10 samples",
        ),
        case(
            "test driver fault",
            F::DriverFault { driver: 0 },
            trip(11, reason::BENCH_PROTECTION, one),
            "the driver's fault line: the server stops the bench by itself",
        ),
        case(
            "load driver fault",
            F::DriverFault { driver: 1 },
            trip(11, reason::BENCH_PROTECTION, one),
            "the driver's fault line: the server stops the bench by itself",
        ),
        case(
            "load supply drops to 30 V",
            F::SupplyDrop {
                supply: 1,
                volts: 30.0,
            },
            trip(10, client, one),
            "the divider leaves its window (40-56 V)",
        ),
        case(
            "test supply drops to 12 V",
            F::SupplyDrop {
                supply: 0,
                volts: 12.0,
            },
            trip(10, client, one),
            "the divider leaves its window (18-30 V)",
        ),
        case(
            "test supply drops to 20 V",
            F::SupplyDrop {
                supply: 0,
                volts: 20.0,
            },
            Expected::Completes,
            "inside the window: the drivers still work (saturation flags use the measured supply)",
        ),
    ]
}

/// What one run of a case showed.
#[derive(Debug, Clone)]
pub struct Observation {
    /// The master's trip code (`None`: it completed, or it was killed).
    pub code: Option<i32>,
    /// Whether the bench confirmed the master's safe state (`None`: no trip).
    pub confirmed: Option<bool>,
    /// Control periods from the fault to the master's safe-state request (HEARTBEATs the
    /// server saw); for a killed master, the watchdog's delay after its last frame.
    pub periods: Option<u64>,
    /// The server watchdog's delay after the last valid frame \[periods\], if it latched.
    pub watchdog_periods: Option<u64>,
    /// The bench's latch after the case.
    pub latch: Option<u8>,
    /// Checked by a fresh session: the latch is inherited, a drive command is not applied, an
    /// acknowledgement of another reason is refused and the right one clears it. `Err` says
    /// what failed.
    pub acknowledgement: Result<(), String>,
    /// Drive commands the master sent after its own safe-state request (a correct master
    /// sends none; those that crossed the bench's own entry into the safe state, sent before
    /// the master could know, are not counted here: the bench ignored them).
    pub drive_after_safe: u64,
    /// The bench's outputs after the case drive nothing (both drivers off, the clutch out).
    pub outputs_safe: bool,
    /// Rows in the file read back.
    pub rows_on_disk: u64,
    /// Rows the master handed to the sink (`None`: killed, unknown).
    pub rows_run: Option<u64>,
    /// What is wrong with the file, if anything (rows off the grid, a cut row, missing rows).
    pub file: Result<(), String>,
    /// Frames the server refused.
    pub refused: u64,
    /// Frames the master refused (its `rejectedFrames` in the file's last row).
    pub master_refused: Option<u64>,
    /// The run was disturbed by the host (a trip before the fault, or a link trip the fault
    /// does not cause): it says nothing about the case and is run again.
    pub disturbed: Option<String>,
    /// The outcome's text, for failures.
    pub detail: String,
}

impl Default for Observation {
    fn default() -> Self {
        Self {
            code: None,
            confirmed: None,
            periods: None,
            watchdog_periods: None,
            latch: None,
            acknowledgement: Err("not checked".into()),
            drive_after_safe: 0,
            outputs_safe: false,
            rows_on_disk: 0,
            rows_run: None,
            file: Err("not read".into()),
            refused: 0,
            master_refused: None,
            disturbed: None,
            detail: String::new(),
        }
    }
}

impl Observation {
    /// Compares with what `case` expects; `Err` lists every difference.
    pub fn check(&self, case: &Case) -> Result<(), String> {
        let mut wrong = Vec::new();
        let within =
            |p: Option<u64>, (lo, hi): (u64, u64)| p.is_some_and(|p| (lo..=hi).contains(&p));
        match case.expected {
            Expected::Trip {
                code,
                latch,
                periods,
                confirmed,
            } => {
                if self.code != Some(code) {
                    wrong.push(format!("trip code {:?}, expected {code}", self.code));
                }
                if self.confirmed != Some(confirmed) {
                    wrong.push(format!(
                        "safe state confirmed {:?}, expected {confirmed}",
                        self.confirmed
                    ));
                }
                if !within(self.periods, periods) {
                    wrong.push(format!(
                        "latency {:?} periods, expected {} to {}",
                        self.periods, periods.0, periods.1
                    ));
                }
                if self.latch != Some(latch) {
                    wrong.push(format!("latch {:?}, expected {latch}", self.latch));
                }
            }
            Expected::Watchdog { periods } => {
                if !within(self.periods, periods) {
                    wrong.push(format!(
                        "watchdog after {:?} periods, expected {} to {}",
                        self.periods, periods.0, periods.1
                    ));
                }
                if self.latch != Some(reason::HEARTBEAT_TIMEOUT) {
                    wrong.push(format!("latch {:?}, expected 2", self.latch));
                }
            }
            Expected::Completes => {
                if self.code.is_some() || self.latch.is_some() {
                    wrong.push(format!(
                        "tripped: code {:?}, latch {:?}",
                        self.code, self.latch
                    ));
                }
            }
        }
        if !matches!(case.expected, Expected::Completes)
            && let Err(e) = &self.acknowledgement
        {
            wrong.push(format!("acknowledgement: {e}"));
        }
        if self.drive_after_safe != 0 {
            wrong.push(format!(
                "{} drive commands after the master's safe-state request",
                self.drive_after_safe
            ));
        }
        if !matches!(case.expected, Expected::Completes) && !self.outputs_safe {
            wrong.push("the bench's outputs still drive after the case".into());
        }
        if let Err(e) = &self.file {
            wrong.push(format!("file: {e}"));
        }
        if wrong.is_empty() {
            Ok(())
        } else {
            Err(format!(
                "{}: {} ({})",
                case.name,
                wrong.join("; "),
                self.detail
            ))
        }
    }
}

/// Where the campaign finds its FMUs and key.
#[derive(Debug, Clone)]
pub struct Bench {
    /// `BenchPlant.fmu`, served by the emulator.
    pub plant: PathBuf,
    /// `BenchHardware.fmu`, run by the master.
    pub hardware: PathBuf,
    /// The bench key file (mode 0600) and its key.
    pub key_file: PathBuf,
    /// The key.
    pub key: Key,
    /// A scratch directory for the result files and the emulator's state.
    pub dir: PathBuf,
}

impl Bench {
    /// The suite's exported FMUs and bench key ([`crate::exported_fmu`],
    /// [`crate::bench_key_file`]), with `dir` as the scratch directory.
    pub fn in_dir(dir: &Path) -> Bench {
        let (_, key_file, key) = crate::bench_key_file();
        Bench {
            plant: crate::exported_fmu("BenchPlant"),
            hardware: crate::exported_fmu("BenchHardware"),
            key_file: key_file.clone(),
            key: key.clone(),
            dir: dir.to_path_buf(),
        }
    }
}

fn emulator_config(bench: &Bench, case: &Case, bind: &str, state: &Path) -> EmulatorConfig {
    let mut config = EmulatorConfig::new(bind, &bench.plant);
    config.key = Some(bench.key.clone());
    config.heartbeat_timeout = Duration::from_secs_f64(HEARTBEAT_TIMEOUT);
    config.state_file = Some(state.to_path_buf());
    // The flood of refusals some cases cause is counted; lines on stderr would only be noise.
    config.log_rejections = false;
    config.parameters = vec![("configuration".into(), case.configuration.to_string())];
    if case.ramp {
        // The load side held by friction, the plant's own torque interlock out of the way
        // (as in tests/tests/hardware.rs): the test motor winds the spring.
        config
            .parameters
            .push(("loadStaticFriction".into(), "100".into()));
        config
            .parameters
            .push(("motorTorqueLimit".into(), "100".into()));
    }
    config
}

/// The system a master runs: `BenchHardware` as component `b` over UDP, soft real time,
/// the test motor's current command and the trip code recorded.
pub fn master_system(
    hardware: &Path,
    server: &str,
    key_file: &Path,
    configuration: i32,
    ramp: bool,
    stop: f64,
    safe_state_timeout: f64,
) -> Result<(System, RunConfig), String> {
    let e = |e: &dyn std::fmt::Display| e.to_string();
    let fmu = Fmu::load(hardware, &LoadOptions::default()).map_err(|x| e(&x))?;
    let mut system = System::new();
    system.add_component("b", fmu).map_err(|x| e(&x))?;
    for (name, value) in [
        ("backend", "1".to_owned()),
        ("pacing", "1".to_owned()),
        ("serverAddress", server.to_owned()),
        ("keyFile", key_file.display().to_string()),
        // A 10 ms link watchdog, as in tests/tests/hardware.rs: a descheduled emulator on a
        // loaded 2-core machine takes milliseconds now and then; the deadline itself is
        // tested in bench_link.rs.
        ("replyTimeout", "0.01".to_owned()),
        ("safeStateTimeout", safe_state_timeout.to_string()),
        ("configuration", configuration.to_string()),
    ] {
        system
            .set_value_str(&format!("b.{name}"), &value)
            .map_err(|x| e(&x))?;
    }
    let n = (stop / H).round() as usize;
    let times: Vec<f64> = (0..=n).map(|k| k as f64 * H).collect();
    let values = times
        .iter()
        .map(|t| if ramp { 25.0 * t } else { 0.5 })
        .collect();
    system
        .add_signal(
            "b.testCurrentCommand",
            Signal {
                times,
                values,
                interpolate: false,
            },
        )
        .map_err(|x| e(&x))?;
    system
        .record(&[
            "b.actuationAngle",
            "b.transducerTorque",
            "b.loadCellTorque",
            "b.testMotorCurrent",
            "b.tripCode",
            "b.rejectedFrames",
        ])
        .map_err(|x| e(&x))?;
    let config = RunConfig {
        stop_time: stop,
        step_size: H,
        ..RunConfig::default()
    };
    Ok((system, config))
}

/// The trip code a run's outcome reports: the FMU's log names the trip (`simulation ended at
/// t = ...: <trip name>`, or `trip <code> (...)` in an error).
pub fn trip_code(outcome: &Outcome) -> Option<i32> {
    let texts: Vec<String> = match outcome {
        Outcome::Completed { .. } => return None,
        Outcome::Terminated { messages, .. } => messages.clone(),
        Outcome::Failed(e) => vec![e.to_string()],
    };
    if matches!(outcome, Outcome::Failed(_)) {
        for text in &texts {
            for rest in text.split("trip ").skip(1) {
                let digits: String = rest.chars().take_while(char::is_ascii_digit).collect();
                if let Ok(code) = digits.parse()
                    && rest[digits.len()..].starts_with(" (")
                {
                    return Some(code);
                }
            }
        }
    }
    // The most specific trip name the log holds.
    (1..=13)
        .filter(|&c| texts.iter().any(|t| t.contains(trip::name(c))))
        .max_by_key(|&c| trip::name(c).len())
}

/// A result file read back.
#[derive(Debug, Clone, Default)]
pub struct FileRows {
    /// Complete rows, row `k` at `k h`.
    pub rows: u64,
    /// The last row's values by column name.
    pub last: Vec<(String, f64)>,
}

impl FileRows {
    /// The last row's value of `column`.
    pub fn last_value(&self, column: &str) -> Option<f64> {
        self.last.iter().find(|(n, _)| n == column).map(|(_, v)| *v)
    }
}

/// Reads a result file back: `Ok` if every row is complete and row `k` is at `k h`.
pub fn read_rows(path: &Path) -> Result<FileRows, String> {
    let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let mut lines = text.split_inclusive('\n');
    let header = lines.next().ok_or("empty file")?;
    let names: Vec<&str> = header.trim_end().split(',').collect();
    let columns = names.len();
    let mut rows = 0u64;
    let mut last = Vec::new();
    for line in lines {
        if !line.ends_with('\n') {
            return Err(format!("row {rows} is cut: `{line}`"));
        }
        let fields: Vec<&str> = line.trim_end().split(',').collect();
        if fields.len() != columns {
            return Err(format!(
                "row {rows} has {} of {columns} fields",
                fields.len()
            ));
        }
        let t: f64 = fields[0]
            .parse()
            .map_err(|_| format!("row {rows}: time `{}`", fields[0]))?;
        if (t - rows as f64 * H).abs() > 1e-9 {
            return Err(format!(
                "row {rows} at t = {t}, expected {}",
                rows as f64 * H
            ));
        }
        last = names
            .iter()
            .zip(&fields)
            .map(|(n, v)| (n.to_string(), v.parse().unwrap_or(f64::NAN)))
            .collect();
        rows += 1;
    }
    Ok(FileRows { rows, last })
}

/// Waits until the run is `at` control periods in (the first drive command marks its first
/// period) and returns the emulator's HEARTBEAT counts at the run's start and now; `None` if
/// the bench latched first (the host disturbed the run) or the run did not get there in time.
fn wait_for_period(emu: &EmulatorHandle, at: u64, patience: Duration) -> Option<(u64, u64)> {
    let end = Instant::now() + patience;
    let mut start = None;
    while Instant::now() < end {
        let s = emu.stats();
        if s.safe_reason.is_some() {
            return None;
        }
        match start {
            // Where the run began as the serving thread recorded it: this thread may see the
            // first drive command periods late on a loaded machine.
            None if s.drive_commands_applied_total > 0 => {
                start = Some(s.heartbeats_at_first_drive.unwrap_or(s.heartbeats_seen))
            }
            Some(h0) if s.heartbeats_seen >= h0 + at => return Some((h0, s.heartbeats_seen)),
            _ => {}
        }
        std::thread::sleep(Duration::from_micros(100));
    }
    None
}

/// Waits until the emulator latched or `patience` passed.
fn wait_for_latch(emu: &EmulatorHandle, patience: Duration) -> EmulatorStats {
    let end = Instant::now() + patience;
    loop {
        let s = emu.stats();
        if s.safe_reason.is_some() || Instant::now() > end {
            return s;
        }
        std::thread::sleep(Duration::from_millis(1));
    }
}

/// The command a master that ignores the latch would send: both drivers on, the clutch in.
const DRIVE: Command = Command {
    test_set_value: 1.0,
    load_set_value: -0.5,
    test_enable: true,
    load_enable: true,
    clutch: true,
    test_kind: SetValueKind::Current,
    load_kind: SetValueKind::Current,
};

/// A session opened by hand with the bench's key (the SEA setup, both drivers in current
/// mode) on a fresh socket connected to `server`, whose receives wait up to 200 ms: for tests
/// that speak the protocol frame by frame.
pub fn hand_session(server: std::net::SocketAddr, key: &Key) -> (UdpSocket, Session) {
    let socket = UdpSocket::bind("127.0.0.1:0").expect("bind");
    socket
        .set_read_timeout(Some(Duration::from_millis(200)))
        .expect("read timeout");
    socket.connect(server).expect("connect");
    let setup = BenchSetup {
        configuration: 1,
        test_kind: SetValueKind::Current,
        load_kind: SetValueKind::Current,
    };
    let mut hs = ClientHandshake::new(key, setup).expect("handshake");
    socket.send(hs.hello()).expect("hello");
    let mut buf = [0u8; 256];
    let n = socket.recv(&mut buf).expect("the server's answer to hello");
    let HandshakeReply::Welcome(session) = hs.receive(&buf[..n]).expect("a valid answer") else {
        panic!("the session was refused");
    };
    (socket, *session)
}

/// A master speaking the protocol by hand.
struct RawMaster {
    socket: UdpSocket,
    session: Session,
}

impl RawMaster {
    /// Opens a session (asking again while the last master's session is still live).
    fn connect(emu: &EmulatorHandle, key: &Key, configuration: i32) -> Result<Self, String> {
        let socket = UdpSocket::bind("127.0.0.1:0").map_err(|e| e.to_string())?;
        socket
            .set_read_timeout(Some(Duration::from_millis(20)))
            .map_err(|e| e.to_string())?;
        let setup = BenchSetup {
            configuration: configuration as u8,
            test_kind: SetValueKind::Current,
            load_kind: SetValueKind::Current,
        };
        let end = Instant::now() + Duration::from_secs(2);
        let mut buf = [0u8; 256];
        while Instant::now() < end {
            let mut hs = ClientHandshake::new(key, setup).map_err(|e| e.to_string())?;
            socket
                .send_to(hs.hello(), emu.addr())
                .map_err(|e| e.to_string())?;
            while let Ok(n) = socket.recv(&mut buf) {
                match hs.receive(&buf[..n]) {
                    Ok(HandshakeReply::Welcome(session)) => {
                        socket.connect(emu.addr()).map_err(|e| e.to_string())?;
                        return Ok(Self {
                            socket,
                            session: *session,
                        });
                    }
                    Ok(HandshakeReply::Refused(r)) if r.code == refusal::BUSY => break,
                    Ok(HandshakeReply::Refused(r)) => return Err(r.text().to_owned()),
                    Err(_) => {}
                }
            }
        }
        Err("no session within 2 s".into())
    }

    fn send(&mut self, payload: Payload) -> u32 {
        let (seq, bytes) = self.session.tx.frame(payload);
        let _ = self.socket.send(&bytes);
        seq
    }

    fn ask(&mut self, payload: Payload) -> Result<Sample, String> {
        let seq = self.send(payload);
        let mut buf = [0u8; 256];
        let end = Instant::now() + Duration::from_secs(1);
        while Instant::now() < end {
            let Ok(n) = self.socket.recv(&mut buf) else {
                continue;
            };
            if let Ok(f) = self.session.rx.accept(&buf[..n])
                && let Payload::Sample(s) | Payload::SafeStateAck(s) = f.payload
                && s.request_sequence == seq
            {
                return Ok(s);
            }
        }
        Err(format!("no answer to {payload:?}"))
    }
}

/// The latch `latch` holds for a new session until it is acknowledged: see [`Observation`].
/// `persists`: the fault that latched it is still there (a driver fault), so the right
/// acknowledgement is refused until the fault is cleared.
fn verify_latch(
    emu: &EmulatorHandle,
    key: &Key,
    configuration: i32,
    latch: u8,
    persists: bool,
) -> Result<(), String> {
    let mut m = RawMaster::connect(emu, key, configuration)?;
    if m.session.latched != latch {
        return Err(format!(
            "a new session inherits latch {}, expected {latch}",
            m.session.latched
        ));
    }
    let applied = emu.stats().drive_commands_applied_total;
    m.send(Payload::Command(DRIVE));
    let s = m.ask(Payload::Heartbeat)?;
    if !s.has(status::SAFE_STATE) || s.last_command_sequence != 0 {
        return Err(format!("a drive command acted on the latched bench: {s:?}"));
    }
    if emu.stats().drive_commands_applied_total != applied {
        return Err("a drive command was applied while latched".into());
    }
    let other = if latch == reason::CLIENT_REQUEST {
        reason::HEARTBEAT_TIMEOUT
    } else {
        reason::CLIENT_REQUEST
    };
    if !m
        .ask(Payload::Acknowledge(Acknowledge { reason: other }))?
        .has(status::SAFE_STATE)
    {
        return Err(format!(
            "an acknowledgement of reason {other} cleared latch {latch}"
        ));
    }
    if persists {
        if !m
            .ask(Payload::Acknowledge(Acknowledge { reason: latch }))?
            .has(status::SAFE_STATE)
        {
            return Err("acknowledged while the fault persists".into());
        }
        emu.inject(FaultInjection::Clear)
            .map_err(|e| e.to_string())?;
    }
    if m.ask(Payload::Acknowledge(Acknowledge { reason: latch }))?
        .has(status::SAFE_STATE)
    {
        return Err("the right acknowledgement did not clear the latch".into());
    }
    m.send(Payload::SafeState(SafeStateRequest {
        reason: reason::SESSION_END,
    }));
    Ok(())
}

/// Builds the command that starts this binary as the master process of the SIGKILL case
/// (the test binary runs one ignored test, the benchmark a flag); [`CHILD_ENV`] is set on it.
pub type ChildCommand<'a> = &'a dyn Fn() -> std::process::Command;

/// If [`CHILD_ENV`] is set, runs the master it describes into its output file (until killed)
/// and returns true.
pub fn child_master_if_asked() -> bool {
    let Ok(spec) = std::env::var(CHILD_ENV) else {
        return false;
    };
    let f: Vec<&str> = spec.split('\n').collect();
    let [hardware, server, key_file, output, configuration] = f[..] else {
        panic!("{CHILD_ENV}: five lines expected, got `{spec}`");
    };
    let (system, config) = master_system(
        Path::new(hardware),
        server,
        Path::new(key_file),
        configuration.parse().expect("configuration"),
        false,
        20.0,
        0.05,
    )
    .expect("master system");
    // Every row to the kernel as it is recorded (`kneebench run --flush-every-row`), so the
    // kill leaves every row the master recorded.
    let mut sink = CsvFile::create(Path::new(output))
        .expect("output")
        .write_through(true);
    let summary = system.run_into(&config, &mut sink);
    panic!("the master was not killed: {summary:?}");
}

/// Runs one case once (see the module docs).
pub fn run_case(bench: &Bench, case: &Case, child: ChildCommand) -> Observation {
    static COUNTER: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
    let n = COUNTER.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let output = bench.dir.join(format!("case-{n}.csv"));
    let state = bench.dir.join(format!("case-{n}.state"));
    let emu = match spawn(emulator_config(bench, case, "127.0.0.1:0", &state)) {
        Ok(e) => e,
        Err(e) => {
            return Observation {
                disturbed: Some(format!("emulator: {e}")),
                ..Observation::default()
            };
        }
    };
    let addr = emu.addr();
    let mut obs = Observation::default();
    let emu = Mutex::new(Some(emu));
    let stop = if case.ramp { 0.4 } else { 0.6 };
    if case.fault == Fault::KillMaster {
        run_killed(bench, case, child, &emu, &output, &mut obs);
    } else {
        let safe_timeout = if case.fault == Fault::RestartServer {
            // Long enough for the new server to be up and see the requests.
            0.5
        } else {
            0.05
        };
        let (system, config) = match master_system(
            &bench.hardware,
            &addr.to_string(),
            &bench.key_file,
            case.configuration,
            case.ramp,
            stop,
            safe_timeout,
        ) {
            Ok(x) => x,
            Err(e) => {
                obs.disturbed = Some(e);
                return obs;
            }
        };
        let mut sink = match CsvFile::create(&output) {
            Ok(s) => s,
            Err(e) => {
                obs.file = Err(e.to_string());
                return obs;
            }
        };
        let injected = std::thread::scope(|scope| {
            let injector = scope.spawn(|| inject(bench, case, &emu, &state));
            let summary = system.run_into(&config, &mut sink);
            (injector.join().unwrap_or(false), summary)
        });
        let (injected, summary) = injected;
        drop(system);
        let summary = match summary {
            Ok(s) => s,
            Err(e) => {
                obs.disturbed = Some(format!("the run did not start: {e}"));
                return obs;
            }
        };
        if !injected {
            obs.disturbed = Some(format!("no fault injected: {:?}", summary.outcome));
        }
        obs.code = trip_code(&summary.outcome);
        obs.confirmed = match &summary.outcome {
            Outcome::Completed { .. } => None,
            Outcome::Terminated { .. } => Some(true),
            Outcome::Failed(_) => Some(false),
        };
        obs.detail = format!("{:?}", summary.outcome);
        obs.rows_run = Some(summary.rows);
        let kept = match summary.outcome {
            Outcome::Failed(_) => sink.keep_partial(),
            _ => sink.commit(),
        };
        match kept {
            Ok(path) => {
                obs.file = read_rows(&path).and_then(|file| {
                    obs.rows_on_disk = file.rows;
                    obs.master_refused = file.last_value("b.rejectedFrames").map(|v| v as u64);
                    if file.rows == summary.rows {
                        Ok(())
                    } else {
                        Err(format!(
                            "{} rows on disk of {} run",
                            file.rows, summary.rows
                        ))
                    }
                });
            }
            Err(e) => obs.file = Err(e.to_string()),
        }
    }
    let Some(emu) = emu.into_inner().unwrap_or_else(|p| p.into_inner()) else {
        obs.disturbed = Some("the emulator did not restart".into());
        return obs;
    };
    // The bench after the case: the watchdog has had its time.
    let s = if matches!(case.expected, Expected::Completes) {
        std::thread::sleep(Duration::from_millis(20));
        emu.stats()
    } else {
        wait_for_latch(&emu, Duration::from_secs(1))
    };
    obs.latch = s.safe_reason;
    obs.drive_after_safe = s.drive_commands_after_safe_request;
    obs.outputs_safe = !s.outputs.is_some_and(|c| c.drives());
    obs.refused = s.rejected.rejected() + s.foreign_frames;
    obs.watchdog_periods = match (s.safe_reason, s.latched_at) {
        (Some(reason::HEARTBEAT_TIMEOUT), Some(at)) => {
            Some(((at - s.last_valid_time) / H).round().max(0.0) as u64)
        }
        _ => None,
    };
    obs.periods = match case.fault {
        Fault::KillMaster => obs.watchdog_periods,
        // The new server counts from its start: the master's heartbeats it saw before the
        // master's safe-state request (0: it was lost in the restart; the trip is then in
        // that period).
        Fault::RestartServer => s.heartbeats_at_safe_request.map(|h| h.max(1)),
        // A run that completes has no trip (its SAFE_STATE is the release at the end).
        Fault::Inject(_) if obs.code.is_none() => None,
        Fault::Inject(_) => s
            .heartbeats_at_safe_request
            .map(|h| h.saturating_sub(s.heartbeats_at_fault)),
    };
    if obs.disturbed.is_none() {
        let link_case = matches!(case.expected, Expected::Trip { code: 8, .. });
        let watchdog_case = matches!(
            case.expected,
            Expected::Watchdog { .. }
                | Expected::Trip {
                    latch: reason::HEARTBEAT_TIMEOUT,
                    ..
                }
        );
        if obs.code == Some(trip::LINK) && !link_case {
            obs.disturbed = Some("a link trip the fault does not cause (host stall)".into());
        } else if s.safe_reason == Some(reason::HEARTBEAT_TIMEOUT) && !watchdog_case {
            // The master stalled for the whole heartbeat timeout (50 ms): the server stopped
            // the bench by itself, which the fault does not cause.
            obs.disturbed = Some("the server's watchdog stopped the bench (host stall)".into());
        }
    }
    obs.acknowledgement = match s.safe_reason {
        None => Err("nothing latched".into()),
        Some(latch) => {
            let persists = matches!(
                case.fault,
                Fault::Inject(FaultInjection::DriverFault { .. })
            );
            if !persists {
                // The link faults go (a silent emulator answers no new session either).
                let _ = emu.inject(FaultInjection::Clear);
            }
            verify_latch(&emu, &bench.key, case.configuration, latch, persists)
        }
    };
    let _ = emu.stop();
    let _ = std::fs::remove_file(&output);
    let _ = std::fs::remove_file(partial_path(&output));
    obs
}

/// The injector of an in-process run: waits for the case's period and applies the fault;
/// false if the run was disturbed first.
fn inject(bench: &Bench, case: &Case, emu: &Mutex<Option<EmulatorHandle>>, state: &Path) -> bool {
    let patience = Duration::from_secs(10);
    let reached = {
        let guard = emu.lock().unwrap_or_else(|p| p.into_inner());
        let Some(e) = guard.as_ref() else {
            return false;
        };
        wait_for_period(e, case.at, patience).is_some()
    };
    if !reached {
        return false;
    }
    match case.fault {
        Fault::Inject(f) => emu
            .lock()
            .is_ok_and(|e| e.as_ref().is_some_and(|e| e.inject(f).is_ok())),
        Fault::RestartServer => {
            let mut guard = emu.lock().unwrap_or_else(|p| p.into_inner());
            let Some(old) = guard.take() else {
                return false;
            };
            let addr = old.addr().to_string();
            // The old server goes away (its socket closed), a new one takes the address.
            let _ = old.stop();
            match spawn(emulator_config(bench, case, &addr, state)) {
                Ok(new) => {
                    *guard = Some(new);
                    true
                }
                Err(_) => false,
            }
        }
        Fault::KillMaster => false,
    }
}

/// The emulator's count of heartbeats once it has stopped changing (the master is gone; at
/// most a second).
fn settled_heartbeats(emu: &EmulatorHandle) -> u64 {
    let end = Instant::now() + Duration::from_secs(1);
    let mut last = emu.stats().heartbeats_seen;
    loop {
        std::thread::sleep(Duration::from_millis(20));
        let now = emu.stats().heartbeats_seen;
        if now == last || Instant::now() > end {
            return now;
        }
        last = now;
    }
}

/// The SIGKILL case: the master is a child process, killed `case.at` periods into its run.
fn run_killed(
    bench: &Bench,
    case: &Case,
    child: ChildCommand,
    emu: &Mutex<Option<EmulatorHandle>>,
    output: &Path,
    obs: &mut Observation,
) {
    let guard = emu.lock().unwrap_or_else(|p| p.into_inner());
    let Some(e) = guard.as_ref() else {
        return;
    };
    let spec = [
        bench.hardware.display().to_string(),
        e.addr().to_string(),
        bench.key_file.display().to_string(),
        output.display().to_string(),
        case.configuration.to_string(),
    ]
    .join("\n");
    let mut command = child();
    command
        .env(CHILD_ENV, spec)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null());
    let mut process = match command.spawn() {
        Ok(p) => p,
        Err(err) => {
            obs.disturbed = Some(format!("master process: {err}"));
            return;
        }
    };
    let reached = wait_for_period(e, case.at, Duration::from_secs(30));
    // SIGKILL: no destructor, no release frame, no last flush.
    let _ = process.kill();
    let _ = process.wait();
    let Some((h0, _)) = reached else {
        obs.disturbed = Some("the master's run was disturbed before the kill".into());
        return;
    };
    // The rows the master had made: one a period, from the row at 0 to the last heartbeat.
    // The emulator publishes its statistics after answering, so the master may have recorded
    // a row whose heartbeat is not counted yet: read them once they have stopped changing.
    let made = settled_heartbeats(e).saturating_sub(h0) + 1;
    obs.rows_run = Some(made);
    obs.detail = format!("killed after about {made} rows");
    let partial = partial_path(output);
    obs.file = read_rows(&partial).and_then(|file| {
        obs.rows_on_disk = file.rows;
        // The row of the last heartbeat may not have been recorded yet when the kill came
        // (the master records a row after its step's exchange): every other row must be on
        // disk.
        match file.rows {
            n if n > made => Err(format!("{n} rows on disk, more than the {made} made")),
            n if n + 1 < made => Err(format!(
                "{n} rows on disk of the {made} the master made before the kill"
            )),
            _ => Ok(()),
        }
    });
}
