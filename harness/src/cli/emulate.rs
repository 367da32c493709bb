//! `kneebench emulate`: serve the UDP bench protocol with the plant running in real time.

use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::sync::atomic::AtomicBool;

use anyhow::{Context, bail};
use kneebench_harness::bench_protocol::{FaultInjection, Key, LinkDirection};
use kneebench_harness::emulator::{self, EmulatorConfig, EmulatorStats};
use kneebench_harness::load::{ArchiveLimits, extract_and_parse};
use kneebench_harness::params::parameter_value;
use model_description::num::Num;

/// Arguments of `kneebench emulate`.
#[derive(Debug, clap::Args)]
#[command(after_help = "\
Examples:
  kneebench emulate --bind 127.0.0.1:47000 --fmu out/fmus/BenchPlant.fmu --duration 60   # loopback: public key
  kneebench emulate --new-key lab.key --bind 0.0.0.0:47000 --fmu out/fmus/BenchPlant.fmu --duration 60
  kneebench emulate --key lab.key --bind 127.0.0.1:0 --fmu out/fmus/BenchPlant.fmu --param configuration=2 --fault stuck:1 --duration 60
Without a key the emulator serves only on a loopback address (the public loopback key, which
authenticates nothing); on any other address it needs --key or --new-key.
Faults (--fault, repeatable; also injectable at run time by FaultInject frames of the
authenticated session):
  drop:N          drop the next N replies
  delay:N:SECONDS send the next N replies SECONDS late
  stuck:CH        hold channel CH (0 load cell, 1 transducer, 2/3 test/load current sensor,
                  4/5 test/load supply divider, 6/7 test/load encoder) at its present value
  force:CH:VOLTS  force analog channel CH to VOLTS
  estop           press the emergency-stop button
  silence         answer nothing (the link is lost)
  duplicate:DIR:N the link duplicates the next N frames of direction DIR (to-client: the
                  replies, to-server: the master's frames)
  reorder:DIR     the link swaps the next two frames of direction DIR
  corrupt:DIR:N   the link corrupts (one byte) the next N frames of direction DIR
  noise:CH:SIGMA[:SEED]  Gaussian noise of SIGMA volts on analog channel CH (repeatable
                  with the same SEED, default 1)
  offset:CH:VOLTS add VOLTS to analog channel CH
  driver:D        driver D (0 test, 1 load) faults: the bench stops itself
  supply:S:VOLTS  supply S (0 test, 1 load) drops to VOLTS
--no-faults makes the emulator refuse fault-injection frames (counted), as a bench server
does; --state FILE keeps the latch across restarts (a restart under a live session latches).")]
pub struct Args {
    /// Address to serve on (port 0: an ephemeral port, printed at start).
    #[arg(long, default_value = "127.0.0.1:47000")]
    pub bind: String,
    /// The BenchPlant FMU (from `kneebench export`).
    #[arg(long, default_value = "BenchPlant.fmu")]
    pub fmu: PathBuf,
    /// A plant parameter, NAME=VALUE (repeatable; a mode by its item's name), checked against
    /// the FMU (name, finite value inside [min, max], item) before the emulator starts.
    #[arg(long = "param", value_name = "NAME=VALUE")]
    pub params: Vec<String>,
    /// The bench key file (from `kneebench key new`; readable by its owner only).
    #[arg(long, value_name = "FILE", conflicts_with = "new_key")]
    pub key: Option<PathBuf>,
    /// Create a new key file (mode 0600) and serve with it.
    #[arg(long, value_name = "FILE")]
    pub new_key: Option<PathBuf>,
    /// Heartbeat timeout in seconds: silence after which the server enters the safe state.
    #[arg(long, default_value_t = 0.05, value_parser = heartbeat_timeout)]
    pub heartbeat_timeout: f64,
    /// A fault in force from the start (see below; repeatable).
    #[arg(long = "fault", value_name = "FAULT", conflicts_with = "no_faults")]
    pub faults: Vec<String>,
    /// Refuse fault-injection frames (counted and logged), as a bench server does.
    #[arg(long)]
    pub no_faults: bool,
    /// Keep the latch and whether a session is live in FILE: a restart keeps the latch, and
    /// one under a live session latches (reason: server restart).
    #[arg(long, value_name = "FILE")]
    pub state: Option<PathBuf>,
    /// Stop after this many seconds, more than 0 and at most a year (default: run until
    /// interrupted).
    #[arg(long, value_parser = duration)]
    pub duration: Option<f64>,
    /// Serve from a SCHED_FIFO thread of this priority (1-99; needs CAP_SYS_NICE or root; a
    /// refusal is reported and the emulator runs with normal scheduling).
    #[arg(long, value_name = "PRIORITY", value_parser = clap::value_parser!(i32).range(1..=99))]
    pub realtime_priority: Option<i32>,
}

/// Parses a `--fault` argument.
pub fn parse_fault(text: &str) -> anyhow::Result<FaultInjection> {
    let parts: Vec<&str> = text.split(':').collect();
    let num = |i: usize| -> anyhow::Result<f64> {
        parts
            .get(i)
            .with_context(|| format!("fault `{text}`: missing field {i}"))?
            .parse::<f64>()
            .with_context(|| format!("fault `{text}`: field {i} is not a number"))
    };
    Ok(match parts[0] {
        "drop" => FaultInjection::DropReplies {
            count: num(1)? as u32,
        },
        "delay" => FaultInjection::DelayReplies {
            count: num(1)? as u32,
            delay_s: num(2)?,
        },
        "stuck" => FaultInjection::Stuck {
            channel: num(1)? as u8,
        },
        "force" => FaultInjection::Force {
            channel: num(1)? as u8,
            volts: num(2)?,
        },
        "estop" => FaultInjection::EmergencyStop,
        "silence" => FaultInjection::Silence,
        "duplicate" => FaultInjection::Duplicate {
            direction: direction(text, parts.get(1))?,
            count: num(2)? as u32,
        },
        "reorder" => FaultInjection::Reorder {
            direction: direction(text, parts.get(1))?,
        },
        "corrupt" => FaultInjection::Corrupt {
            direction: direction(text, parts.get(1))?,
            count: num(2)? as u32,
        },
        "noise" => FaultInjection::Noise {
            channel: analog(text, num(1)?)?,
            volts: match num(2)? {
                v if v.is_finite() && v >= 0.0 => v,
                _ => bail!(
                    "fault `{text}`: the noise's SIGMA must be a finite, non-negative number of volts"
                ),
            },
            seed: if parts.len() > 3 { num(3)? as u32 } else { 1 },
        },
        "offset" => FaultInjection::Offset {
            channel: analog(text, num(1)?)?,
            volts: match num(2)? {
                v if v.is_finite() => v,
                _ => bail!("fault `{text}`: the offset must be a finite number of volts"),
            },
        },
        "driver" => FaultInjection::DriverFault {
            driver: side(text, num(1)?)?,
        },
        "supply" => FaultInjection::SupplyDrop {
            supply: side(text, num(1)?)?,
            volts: match num(2)? {
                v if (0.0..=100.0).contains(&v) => v,
                _ => bail!("fault `{text}`: the supply must be 0 to 100 V"),
            },
        },
        other => bail!("unknown fault `{other}`"),
    })
}

/// A link direction of a fault argument.
fn direction(text: &str, field: Option<&&str>) -> anyhow::Result<LinkDirection> {
    match field.copied() {
        Some("to-client") => Ok(LinkDirection::ToClient),
        Some("to-server") => Ok(LinkDirection::ToServer),
        _ => bail!("fault `{text}`: the direction must be `to-client` or `to-server`"),
    }
}

/// An analog channel (0-5) of a fault argument.
fn analog(text: &str, channel: f64) -> anyhow::Result<u8> {
    match channel {
        c if c.fract() == 0.0 && (0.0..6.0).contains(&c) => Ok(c as u8),
        _ => bail!("fault `{text}`: the analog channel must be 0 to 5"),
    }
}

/// A driver or supply (0 test, 1 load) of a fault argument.
fn side(text: &str, which: f64) -> anyhow::Result<u8> {
    if which == 0.0 {
        Ok(0)
    } else if which == 1.0 {
        Ok(1)
    } else {
        bail!("fault `{text}`: 0 (test) or 1 (load)")
    }
}

/// The longest `--duration` \[s\]: a year.
const MAX_DURATION: f64 = 365.0 * 86400.0;

/// Parses `--heartbeat-timeout`: a positive number of seconds, at most the protocol's 0.1 s.
fn heartbeat_timeout(text: &str) -> Result<f64, String> {
    let s = super::values::finite(text)
        .ok()
        .filter(|s| *s > 0.0)
        .ok_or("must be a positive number of seconds")?;
    if s > 0.1 {
        return Err("must not exceed 0.1 s (docs/bench-protocol.md, §7)".into());
    }
    Ok(s)
}

/// Parses `--duration`: a number of seconds above 0 and up to [`MAX_DURATION`] (0 served for
/// no time at all; without the option the emulator runs until interrupted).
fn duration(text: &str) -> Result<f64, String> {
    super::values::positive(text)
        .ok()
        .filter(|d| *d <= MAX_DURATION)
        .ok_or_else(|| {
            format!(
                "must be a number of seconds above 0 and at most {MAX_DURATION} (a year); without --duration the emulator runs until interrupted"
            )
        })
}

/// The `--param NAME=VALUE` arguments checked against the plant FMU's model description
/// ([`parameter_value`]: a parameter of the FMU, a value of its type, finite, inside the
/// declared `[min, max]`, one of the items), each refusal a usage error (exit code 2) naming
/// the parameter and the bounds or items; the values as the emulator reads them (a mode given
/// by its item's name as the item's value).
fn checked_parameters(fmu: &Path, params: &[String]) -> anyhow::Result<Vec<(String, String)>> {
    let pairs = params
        .iter()
        .map(|p| super::name_value(p))
        .collect::<anyhow::Result<Vec<_>>>()?;
    if pairs.is_empty() {
        return Ok(pairs);
    }
    let (_dir, md) = extract_and_parse(fmu, &ArchiveLimits::default())
        .with_context(|| format!("reading {}", fmu.display()))?;
    pairs
        .into_iter()
        .map(|(name, text)| match parameter_value(&md, &name, &text) {
            Ok(value) => Ok((name, value.to_text())),
            Err(e) => Err(super::Usage(format!("--param {e}")).into()),
        })
        .collect()
}

/// What the emulator did, for its exit: one line per counter, `  name  value`, the frames
/// rejected by the causes docs/bench-protocol.md section 5 names (it printed the statistics'
/// Rust debug form).
fn summary(s: &EmulatorStats) -> String {
    use kneebench_harness::bench_protocol::reason;
    let reason_name = |r: u8| match r {
        reason::CLIENT_REQUEST => "the master's request",
        reason::HEARTBEAT_TIMEOUT => "heartbeat watchdog",
        reason::EMERGENCY_STOP => "emergency stop",
        reason::SESSION_END => "session end",
        reason::BENCH_PROTECTION => "bench protection",
        reason::SERVER_RESTART => "server restart",
        _ => "unknown",
    };
    let latch = |r: Option<u8>| match r {
        Some(r) => format!("{r} ({})", reason_name(r)),
        None => "none".to_string(),
    };
    let onoff = |on: bool| if on { "enabled" } else { "disabled" };
    let r = &s.rejected;
    let lines: Vec<(&str, String)> = vec![
        ("sessions begun", s.sessions.to_string()),
        ("last session", s.session.to_string()),
        (
            "commands applied (last session)",
            s.commands_applied.to_string(),
        ),
        (
            "commands applied (all sessions)",
            s.commands_applied_total.to_string(),
        ),
        (
            "drive commands applied",
            s.drive_commands_applied_total.to_string(),
        ),
        (
            "commands refused (set-value kind)",
            s.commands_refused.to_string(),
        ),
        (
            "drive commands in the safe state",
            s.drive_commands_in_safe_state.to_string(),
        ),
        (
            "drive commands after a safe-state request",
            s.drive_commands_after_safe_request.to_string(),
        ),
        ("safe-state requests", s.safe_state_requests.to_string()),
        (
            "safe-state acknowledgements sent",
            s.safe_state_acks.to_string(),
        ),
        ("samples sent", s.samples_sent.to_string()),
        (
            "replies dropped or held by faults",
            s.replies_dropped.to_string(),
        ),
        ("heartbeats seen", s.heartbeats_seen.to_string()),
        ("frames accepted", r.accepted.to_string()),
        (
            "frames rejected: wrong version",
            r.wrong_version.to_string(),
        ),
        ("frames rejected: truncated", r.truncated.to_string()),
        ("frames rejected: malformed", r.malformed.to_string()),
        (
            "frames rejected: wrong session",
            r.wrong_session.to_string(),
        ),
        ("frames rejected: foreign", s.foreign_frames.to_string()),
        (
            "frames rejected: unauthenticated",
            r.unauthenticated.to_string(),
        ),
        ("frames rejected: replayed", r.replayed.to_string()),
        ("frames rejected: out of order", r.out_of_order.to_string()),
        ("sequence numbers skipped (gaps)", r.gaps.to_string()),
        (
            "handshakes refused: bench busy",
            s.busy_refusals.to_string(),
        ),
        (
            "handshakes refused: bench setup",
            s.setup_refusals.to_string(),
        ),
        (
            "HELLOs replayed (not answered)",
            s.replayed_hellos.to_string(),
        ),
        (
            "HELLOs dropped (table or budget)",
            s.handshakes_dropped.to_string(),
        ),
        ("version refusals sent", s.version_refusals.to_string()),
        ("latches acknowledged", s.acknowledgements.to_string()),
        (
            "acknowledgements refused",
            s.acknowledgements_refused.to_string(),
        ),
        ("faults injected", s.faults_injected.to_string()),
        (
            "fault frames refused (--no-faults)",
            s.fault_frames_refused.to_string(),
        ),
        ("link faults applied", s.link_faults_applied.to_string()),
        ("rejection log lines", s.log_lines.to_string()),
        ("safe state latched", latch(s.safe_reason)),
        (
            "safe state since (plant time)",
            s.safe_since
                .map_or("-".to_string(), |t| format!("{} s", Num(t))),
        ),
        ("latch restored at start", latch(s.restored_latch)),
        (
            "plant trip code",
            s.plant_trip.map_or("none".to_string(), |c| c.to_string()),
        ),
        (
            "plant time (last session)",
            format!("{} s", Num(s.plant_time)),
        ),
        (
            "largest gap between frames",
            format!("{} s", Num(s.largest_frame_gap)),
        ),
        (
            "outputs held",
            match &s.outputs {
                Some(c) => format!(
                    "test {} ({}), load {} ({}), clutch {}",
                    Num(c.test_set_value),
                    onoff(c.test_enable),
                    Num(c.load_set_value),
                    onoff(c.load_enable),
                    if c.clutch { "engaged" } else { "released" }
                ),
                None => "none".to_string(),
            },
        ),
        (
            "real-time priority",
            match s.realtime_priority {
                0 => "none (normal scheduling)".to_string(),
                p => format!("SCHED_FIFO {p}"),
            },
        ),
    ];
    let width = lines.iter().map(|(n, _)| n.len()).max().unwrap_or(0);
    let mut out = String::from("kneebench emulate: stopped\n");
    for (name, value) in lines {
        out.push_str(&format!("  {name:<width$}  {value}\n"));
    }
    out
}

/// Runs `kneebench emulate`.
pub fn run(args: Args) -> anyhow::Result<i32> {
    let mut config = EmulatorConfig::new(args.bind.clone(), args.fmu.clone());
    // Checked before anything starts or is written (a new key file): the FMU refused a value
    // as the emulator prepared its first plant instance (exit code 1).
    config.parameters = checked_parameters(&args.fmu, &args.params)?;
    // Checked by its parser too (a value set in code is checked here).
    if let Err(e) = heartbeat_timeout(&args.heartbeat_timeout.to_string()) {
        bail!("--heartbeat-timeout {}: {e}", args.heartbeat_timeout);
    }
    config.heartbeat_timeout = std::time::Duration::from_secs_f64(args.heartbeat_timeout);
    // Faults are read before a new key file is written: a bad one is a usage error (exit code
    // 2) that leaves nothing behind.
    for f in &args.faults {
        match parse_fault(f) {
            Ok(fault) => config.faults.push(fault),
            Err(e) => return Err(super::Usage(format!("--fault {e:#}")).into()),
        }
    }
    config.key = match (&args.key, &args.new_key) {
        // A key file refused (weak key, readable by others, another user's, no such file) is
        // an argument problem, found before anything starts.
        (Some(path), _) => {
            Some(Key::load_file(path).map_err(|e| super::Usage(format!("--key {e}")))?)
        }
        (None, Some(path)) => {
            let key = Key::create_file(path)?;
            eprintln!(
                "kneebench emulate: wrote a new bench key to {} (mode 0600)",
                path.display()
            );
            Some(key)
        }
        (None, None) => None,
    };
    // Serving off loopback without a key is an argument problem (exit code 2), as is a bind
    // address that does not resolve.
    if let Err(e) = emulator::check_bind(&args.bind, config.key.as_ref()) {
        return Err(super::Usage(format!("--bind {}: {e}", args.bind)).into());
    }
    config.realtime_priority = args.realtime_priority;
    config.refuse_fault_frames = args.no_faults;
    config.state_file = args.state.clone();
    let stop = std::sync::Arc::new(AtomicBool::new(false));
    let stats = Mutex::new(EmulatorStats::default());
    if let Some(d) = args.duration {
        if let Err(e) = duration(&d.to_string()) {
            bail!("--duration {d}: {e}");
        }
        let stop = stop.clone();
        std::thread::spawn(move || {
            std::thread::sleep(std::time::Duration::from_secs_f64(d));
            stop.store(true, std::sync::atomic::Ordering::SeqCst);
        });
    }
    emulator::run(config, &stop, &stats, |addr| {
        eprintln!("kneebench emulate: serving the bench protocol on {addr}");
    })
    .with_context(|| format!("emulator on {}", args.bind))?;
    if let Ok(s) = stats.lock() {
        eprint!("{}", summary(&s));
    }
    Ok(super::EXIT_OK)
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Debug, clap::Parser)]
    struct Cli {
        #[command(flatten)]
        args: Args,
    }

    #[test]
    fn realtime_priority_is_parsed_and_bounded() {
        let cli = Cli::try_parse_from(["emulate", "--realtime-priority", "80"]).unwrap();
        assert_eq!(cli.args.realtime_priority, Some(80));
        let cli = Cli::try_parse_from(["emulate"]).unwrap();
        assert_eq!(cli.args.realtime_priority, None);
        for bad in ["0", "100", "-3", "high"] {
            assert!(
                Cli::try_parse_from(["emulate", "--realtime-priority", bad]).is_err(),
                "{bad}"
            );
        }
    }

    #[test]
    fn durations_out_of_range_are_refused_before_anything_starts() {
        for bad in ["nan", "inf", "-1", "1e300", "0", "-0"] {
            let bad = &format!("--duration={bad}");
            // Refused while parsing (a usage error, exit code 2), before anything starts.
            let e = Cli::try_parse_from([
                "emulate",
                "--fmu",
                "missing.fmu",
                "--bind",
                "127.0.0.1:0",
                bad,
            ])
            .unwrap_err();
            assert_eq!(e.exit_code(), 2, "{bad}: {e}");
            let e = e.to_string();
            assert!(
                e.contains("--duration") && e.contains("must be a number of seconds"),
                "{bad}: {e}"
            );
        }
    }

    #[test]
    fn a_key_is_needed_off_loopback_and_key_files_are_checked() {
        let dir = tempfile::tempdir().unwrap();
        let fmu = dir.path().join("missing.fmu");
        let args = |extra: &[&str]| {
            let mut v = vec!["emulate", "--fmu", fmu.to_str().unwrap(), "--duration", "1"];
            v.extend_from_slice(extra);
            Cli::try_parse_from(v).unwrap().args
        };
        let e = run(args(&["--bind", "0.0.0.0:0"])).unwrap_err().to_string();
        assert!(e.contains("without a key"), "{e}");
        // A key created on the spot is private and accepted (the missing FMU fails next).
        let key = dir.path().join("bench.key");
        let e = run(args(&[
            "--bind",
            "0.0.0.0:0",
            "--new-key",
            key.to_str().unwrap(),
        ]))
        .unwrap_err()
        .to_string();
        assert!(!e.contains("without a key"), "{e}");
        assert!(key.exists());
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            std::fs::set_permissions(&key, std::fs::Permissions::from_mode(0o644)).unwrap();
            let e = run(args(&[
                "--bind",
                "0.0.0.0:0",
                "--key",
                key.to_str().unwrap(),
            ]))
            .unwrap_err()
            .to_string();
            assert!(e.contains("chmod 600"), "{e}");
        }
        // A key file holding the public loopback key or 64 zeros is refused, saying why.
        for (name, text, says) in [
            (
                "loopback.key",
                Key::loopback().to_hex(),
                "public loopback development key",
            ),
            ("zero.key", "0".repeat(64), "all its 32 bytes are 0x00"),
        ] {
            let path = dir.path().join(name);
            std::fs::write(&path, format!("{text}\n")).unwrap();
            #[cfg(unix)]
            {
                use std::os::unix::fs::PermissionsExt;
                std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o600)).unwrap();
            }
            let e = run(args(&[
                "--bind",
                "0.0.0.0:0",
                "--key",
                path.to_str().unwrap(),
            ]))
            .unwrap_err()
            .to_string();
            assert!(e.contains(says), "{e}");
        }
        // Nor is a key that is no secret, given in code, a key off loopback.
        let e = kneebench_harness::emulator::check_bind("0.0.0.0:0", Some(&Key::loopback()))
            .unwrap_err()
            .to_string();
        assert!(e.contains("with a key that is no secret"), "{e}");
        kneebench_harness::emulator::check_bind("127.0.0.1:0", Some(&Key::loopback())).unwrap();
        assert!(
            Cli::try_parse_from(["emulate", "--key", "a", "--new-key", "b"]).is_err(),
            "--key and --new-key together"
        );
    }

    /// The exit summary is one line per counter, named (the frame rejections as the protocol
    /// names them), not the statistics' debug dump; every counter's value is in it.
    #[test]
    fn the_summary_has_one_named_line_per_counter() {
        use kneebench_harness::bench_protocol::Counters;
        let mut s = EmulatorStats {
            sessions: 101,
            session: 102,
            commands_applied: 103,
            commands_applied_total: 104,
            drive_commands_applied_total: 105,
            commands_refused: 106,
            drive_commands_in_safe_state: 107,
            drive_commands_after_safe_request: 108,
            safe_state_requests: 109,
            safe_state_acks: 110,
            samples_sent: 111,
            replies_dropped: 112,
            foreign_frames: 113,
            busy_refusals: 114,
            setup_refusals: 115,
            version_refusals: 116,
            acknowledgements: 117,
            acknowledgements_refused: 118,
            faults_injected: 119,
            log_lines: 120,
            fault_frames_refused: 121,
            heartbeats_seen: 122,
            link_faults_applied: 123,
            replayed_hellos: 124,
            handshakes_dropped: 125,
            rejected: Counters {
                accepted: 201,
                truncated: 202,
                wrong_version: 203,
                unauthenticated: 204,
                malformed: 205,
                wrong_session: 206,
                replayed: 207,
                out_of_order: 208,
                gaps: 209,
            },
            safe_reason: Some(2),
            plant_trip: Some(6),
            plant_time: 12.5,
            ..EmulatorStats::default()
        };
        let text = summary(&s);
        assert!(!text.contains('{') && !text.contains("Counters"), "{text}");
        for n in (101..=125).chain(201..=209) {
            assert_eq!(
                text.lines()
                    .filter(|l| l.split_whitespace().last() == Some(&n.to_string()))
                    .count(),
                1,
                "{n}: {text}"
            );
        }
        for line in [
            "frames rejected: wrong version     203",
            "frames rejected: unauthenticated   204",
            "frames rejected: out of order      208",
            "safe state latched                 2 (heartbeat watchdog)",
            "plant trip code                    6",
            "plant time (last session)          12.5 s",
        ] {
            let (name, value) = line.split_at(line.find("  ").unwrap());
            assert!(
                text.lines()
                    .any(|l| l.trim_start().starts_with(name)
                        && l.trim_end().ends_with(value.trim())),
                "no '{line}' in:\n{text}"
            );
        }
        // Every line is `  name  value`.
        for l in text.lines().skip(1) {
            assert!(l.starts_with("  ") && l.trim().contains("  "), "{l}");
        }
        s.rejected = Counters::default();
        assert!(summary(&s).contains("frames rejected: replayed"));
    }

    #[test]
    fn faults_parse_and_bad_ones_are_named() {
        assert!(matches!(
            parse_fault("stuck:1").unwrap(),
            FaultInjection::Stuck { channel: 1 }
        ));
        let e = parse_fault("sideways").unwrap_err().to_string();
        assert!(e.contains("unknown fault `sideways`"), "{e}");
        assert_eq!(
            parse_fault("corrupt:to-server:3").unwrap(),
            FaultInjection::Corrupt {
                direction: LinkDirection::ToServer,
                count: 3
            }
        );
        assert_eq!(
            parse_fault("noise:0:0.002").unwrap(),
            FaultInjection::Noise {
                channel: 0,
                volts: 0.002,
                seed: 1
            }
        );
        assert_eq!(
            parse_fault("supply:1:20").unwrap(),
            FaultInjection::SupplyDrop {
                supply: 1,
                volts: 20.0
            }
        );
        for (bad, says) in [
            ("reorder:sideways", "to-client"),
            ("noise:6:0.1", "0 to 5"),
            ("noise:1:-1", "non-negative"),
            ("offset:1:inf", "finite"),
            ("driver:2", "0 (test) or 1 (load)"),
            ("supply:0:500", "0 to 100 V"),
        ] {
            let e = parse_fault(bad).unwrap_err().to_string();
            assert!(e.contains(says), "{bad}: {e}");
        }
        assert!(
            Cli::try_parse_from(["emulate", "--no-faults", "--fault", "estop"]).is_err(),
            "--no-faults with --fault"
        );
        let args = Cli::try_parse_from(["emulate", "--no-faults", "--state", "bench.state"])
            .unwrap()
            .args;
        assert!(args.no_faults);
        assert_eq!(args.state, Some(PathBuf::from("bench.state")));
        let args = Cli::try_parse_from(["emulate"]).unwrap().args;
        assert!(!args.no_faults && args.state.is_none());
    }
}
