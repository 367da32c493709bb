//! The bench's experiments (`kneebench experiment`, `kneebench_harness::experiment`) recover
//! the plant's own parameters on `BenchPlant`, run unchanged on `BenchHardware` over the
//! emulator, and refuse to start on the hardware with an interlock disarmed.
//!
//! Schedules are shortened (fewer speeds, stages, angles) so that each test runs in a few
//! seconds; the linear experiments (Bode, calibration, step identification) run the plant
//! with `frictionModel` = 0 (Off), as their module docs say.

use std::sync::{RwLock, RwLockReadGuard, RwLockWriteGuard};

use kneebench_harness::emulator::{EmulatorConfig, spawn};
use kneebench_harness::experiment::{
    Bench, ExperimentError, RunEnd, bode, calibration, map, step, triangle,
};
use kneebench_tests::*;

/// The hardware test paces against the wall clock: it runs alone (write lock), the simulated
/// ones side by side (read locks), so they do not steal its cores.
static REAL_TIME: RwLock<()> = RwLock::new(());

fn simulated() -> RwLockReadGuard<'static, ()> {
    REAL_TIME.read().unwrap_or_else(|p| p.into_inner())
}

fn real_time() -> RwLockWriteGuard<'static, ()> {
    REAL_TIME.write().unwrap_or_else(|p| p.into_inner())
}

fn plant(params: &[(&str, &str)]) -> Bench {
    let params = params
        .iter()
        .map(|(n, v)| (n.to_string(), v.to_string()))
        .collect();
    Bench::load(&exported_fmu("BenchPlant"), params, None).expect("bench")
}

fn assert_files(w: &kneebench_harness::experiment::Written) {
    for f in w.data.iter().chain(&w.figures).chain([&w.markdown]) {
        let len = std::fs::metadata(f).map(|m| m.len()).unwrap_or(0);
        assert!(len > 100, "{} missing or empty", f.display());
    }
    let png = w.figures.iter().find(|f| f.extension().unwrap() == "png");
    let bytes = std::fs::read(png.expect("a PNG")).unwrap();
    assert_eq!(&bytes[1..4], b"PNG");
    let md = std::fs::read_to_string(&w.markdown).unwrap();
    let dir = w.markdown.parent().unwrap();
    // Every linked file of the section exists next to it (relative links).
    for link in md.split("](").skip(1) {
        let target = link.split(')').next().unwrap();
        assert!(dir.join(target).is_file(), "link {target} does not resolve");
    }
}

#[test]
fn map_returns_the_loss_surface_within_2_percent() {
    let _s = simulated();
    // The loss surface alone on the drive: c1 = 0 (the plant adds c1 omega1 separately); the
    // plant's own regenerated-power interlock lifted (the map's braking points exceed 5 W, as
    // on the bench).
    let bench = plant(&[
        ("frictionModel", "3"),
        ("actuationDamping", "0"),
        ("loadRegenPowerLimit", "1000"),
    ]);
    let out = tempfile::tempdir().unwrap();
    let config = map::MapConfig {
        speeds: vec![0.0, 3.0, 50.0, 150.0],
        torques: vec![-9.0, 0.0, 9.0],
        settle: 1.5,
        measure: 0.5,
        ..map::MapConfig::default()
    };
    let r = map::run_map(&bench, &config, out.path()).unwrap();
    assert_eq!(r.end, RunEnd::Completed);
    assert_eq!(r.points.len(), 3 * 7);
    let surface = map::LossSurface::parse(map::DEFAULT_SURFACE).unwrap();
    let mut compared = 0;
    for p in &r.points {
        assert!(
            (p.torque_command - p.load_torque).abs() < 1e-3,
            "load torque {p:?}"
        );
        if p.speed_command == 0.0 {
            assert!(p.relative_difference.is_nan());
            continue;
        }
        // The reference value is computed here from the file, at the measured point.
        let expected = surface.value(p.load_torque, p.speed);
        assert!(
            (p.loss_torque - expected).abs() <= 0.02 * expected.abs(),
            "{p:?}: surface {expected}"
        );
        compared += 1;
    }
    assert_eq!(compared, 18);
    assert_files(&r.written);
}

#[test]
fn map_with_viscous_damping_differs_from_the_surface_by_c1_omega() {
    let _s = simulated();
    // With c1 = 12 the drive's loss is the surface plus c1 omega1: the map sees it (the
    // comparison is not blind).
    let bench = plant(&[("frictionModel", "3"), ("loadRegenPowerLimit", "1000")]);
    let out = tempfile::tempdir().unwrap();
    let config = map::MapConfig {
        speeds: vec![50.0],
        torques: vec![0.0],
        settle: 1.5,
        measure: 0.5,
        ..map::MapConfig::default()
    };
    let r = map::run_map(&bench, &config, out.path()).unwrap();
    for p in &r.points {
        let viscous = -12.0 * p.speed;
        assert!(
            (p.loss_torque - (p.surface + viscous)).abs() < 0.02 * viscous.abs(),
            "{p:?}"
        );
        assert!(p.relative_difference.abs() > 0.5, "{p:?}");
    }
}

fn bode_check(input: bode::SweepInput, stages: u32) {
    let bench = plant(&[("frictionModel", "0")]);
    let out = tempfile::tempdir().unwrap();
    let config = bode::BodeConfig {
        input,
        start_frequency: 0.2,
        ratio: 10f64.powf(0.2),
        dwell: 4.0,
        stages,
        ..bode::BodeConfig::default()
    };
    let r = bode::run_bode(&bench, &config, out.path()).unwrap();
    assert_eq!(r.end, RunEnd::Completed);
    assert_eq!(r.points.len(), stages as usize);
    // The reference: the two-mass transfer functions from the plant's default parameters,
    // written out here (I1 0.825, I2 0.605, c1 12, c2 1, k 340.54).
    let col = if input == bode::SweepInput::Test {
        0
    } else {
        2
    };
    for p in &r.points {
        let h = bode::two_mass_response(
            0.825,
            0.605,
            12.0,
            1.0,
            340.54,
            std::f64::consts::TAU * p.frequency,
        );
        for k in 0..2 {
            let (re, im) = h[col + k];
            let m = &p.measured[k];
            let db = m.gain_db() - 20.0 * re.hypot(im).log10();
            let deg =
                kneebench_harness::experiment::analysis::wrap(m.phase - im.atan2(re)).to_degrees();
            assert!(
                db.abs() < 1.0 && deg.abs() < 5.0,
                "{} at {} Hz: {db} dB, {deg} deg",
                r.names[k],
                p.frequency
            );
            assert!(m.gain_db_std().is_finite() && m.phase_std.is_finite());
        }
    }
    assert_files(&r.written);
}

#[test]
fn bode_sweep_of_the_test_motor_matches_h1_h2_within_1_db_and_5_deg() {
    let _s = simulated();
    // 0.2 ... 5 Hz: across the SEA's spring mode (3.8 Hz).
    bode_check(bode::SweepInput::Test, 8);
}

#[test]
fn bode_sweep_of_the_load_motor_matches_h3_h4_within_1_db_and_5_deg() {
    let _s = simulated();
    bode_check(bode::SweepInput::Load, 6);
}

/// The triangle test on the plant with the load driver's braking limit `limit` [W] (the
/// output directory is returned with the result so that its files live on).
fn short_triangle(limit: &str) -> (triangle::TriangleResult, tempfile::TempDir) {
    let bench = plant(&[("loadRegenPowerLimit", limit)]);
    let out = tempfile::tempdir().unwrap();
    let config = triangle::TriangleConfig {
        max_cycles: 20,
        ..triangle::TriangleConfig::default()
    };
    (
        triangle::run_triangle(&bench, &config, out.path()).unwrap(),
        out,
    )
}

#[test]
fn triangle_test_recovers_the_configured_braking_limit_within_one_increment() {
    let _s = simulated();
    for (limit, text) in [(5.0, "5"), (3.0, "3")] {
        let (r, _dir) = short_triangle(text);
        let (torque, _, reason) = r.trip.clone().expect("the braking limit trips");
        assert!(reason.contains("regenerated power"), "{reason}");
        // The configured limit lies between the last complete cycle's peak and the tripping
        // cycle's (one increment of 0.5 N m apart).
        let (below, above) = r.limit_bracket;
        assert!(
            below < limit && limit <= above,
            "{limit} W: {below} .. {above}"
        );
        // The cycles before the trip ran below the limit, each one increment up.
        let complete: Vec<_> = r.cycles.iter().filter(|c| c.complete).collect();
        assert!(complete.iter().all(|c| c.peak_regenerated_power < limit));
        assert_eq!(complete.last().unwrap().torque + 0.5, torque);
        assert_files(&r.written);
    }
    // A lower limit trips at a lower torque.
    let (t5, t3) = (
        short_triangle("5").0.trip.unwrap().0,
        short_triangle("3").0.trip.unwrap().0,
    );
    assert!(t3 < t5, "{t3} vs {t5}");
}

#[test]
fn calibration_recovers_a_b_c_within_1_percent() {
    let _s = simulated();
    let bench = plant(&[("frictionModel", "0")]);
    let out = tempfile::tempdir().unwrap();
    let config = calibration::CalibrationConfig {
        angles: (-4..=4).map(|k| f64::from(k * 10).to_radians()).collect(),
        ..calibration::CalibrationConfig::default()
    };
    let r = calibration::run_calibration(&bench, &config, out.path()).unwrap();
    assert_eq!(r.end, RunEnd::Completed);
    // The plant's sensors are linear in torque (the small-angle form of the calibration):
    // V = a + b sin(c) + b cos(c) sin(theta). What the pendulum identifies is therefore
    // a' = a + b sin(c), b' = b cos(c), c' = 0 (module docs); a', b' within 1 % of a, b.
    for (fit, (a, b, c)) in [
        (&r.transducer, (0.245, -0.008, -0.01f64)),
        (&r.load_cell, (5.43, 0.001, 0.019f64)),
    ] {
        let (a_eff, b_eff) = (a + b * c.sin(), b * c.cos());
        assert!((fit.a - a_eff).abs() <= 0.01 * a.abs(), "{fit:?}");
        assert!((fit.b - b_eff).abs() <= 0.01 * b.abs(), "{fit:?}");
        assert!((fit.a - a).abs() <= 0.01 * a.abs() && (fit.b - b).abs() <= 0.01 * b.abs());
        // c' = 0 to 1 % of the published |c| plus the fit's resolution.
        assert!(
            fit.c.abs() < 0.01 * c.abs() + 3.0 * fit.std.2 + 1e-3,
            "{fit:?}"
        );
    }
    assert_files(&r.written);
}

#[test]
fn step_identifies_damping_and_inertia_and_measures_the_position_step() {
    let _s = simulated();
    let bench = plant(&[("frictionModel", "0")]);
    let out = tempfile::tempdir().unwrap();
    let r = step::run_step(&bench, &step::StepConfig::default(), out.path()).unwrap();
    assert_eq!(r.ends, [RunEnd::Completed, RunEnd::Completed]);
    // c1 + c2 = 13 N m s/rad, I1 + I2 = 1.43 kg m^2.
    assert!((r.damping - 13.0).abs() < 0.02 * 13.0, "{r:?}");
    assert!((r.inertia - 1.43).abs() < 0.02 * 1.43, "{r:?}");
    let zn = r.ziegler_nichols.as_ref().expect("ZN gains");
    assert!(zn.kp > 0.0 && zn.ki > 0.0 && zn.kd > 0.0);
    let m = &r.position;
    let (rise, settle) = (
        m.rise_time.expect("rises"),
        m.settling_time.expect("settles"),
    );
    assert!(rise > 0.0 && settle >= rise && m.peak_time > 0.0 && m.overshoot < 0.5);
    assert_files(&r.written);
    // With friction the open-loop gain drops (the same code sees it).
    let with_friction = plant(&[]);
    let r = step::run_step(&with_friction, &step::StepConfig::default(), out.path()).unwrap();
    assert!(r.damping > 15.0, "{}", r.damping);
    // The raw run as Parquet: the same rows, the bench named in the file's metadata, the
    // section links it.
    let csv = kneebench_harness::Results::read_csv_file(out.path().join("step.csv")).unwrap();
    let parquet_out = tempfile::tempdir().unwrap();
    let r = step::run_step(
        &plant(&[]).with_raw_format(kneebench_harness::experiment::RawFormat::Parquet),
        &step::StepConfig::default(),
        parquet_out.path(),
    )
    .unwrap();
    assert_files(&r.written);
    let path = parquet_out.path().join("step.parquet");
    assert!(r.written.data.contains(&path));
    let read = kneebench_harness::results::parquet_read::read_parquet(&path, None).unwrap();
    assert_eq!(read.names(), csv.names());
    assert_eq!(read.len(), csv.len());
    let name = "plant.actuationEncoderAngle";
    assert_eq!(read.column(name), csv.column(name));
    let bytes = std::fs::read(&path).unwrap();
    let text = String::from_utf8_lossy(&bytes);
    assert!(text.contains("kneebench.bench_guid") && text.contains("kneebench.experiment"));
}

#[test]
fn step_runs_unchanged_against_the_hardware_over_the_emulator() {
    let _rt = real_time();
    let mut config = EmulatorConfig::new("127.0.0.1:0", exported_fmu("BenchPlant"));
    config.parameters = vec![("frictionModel".into(), "0".into())];
    config.realtime_priority = Some(50);
    let emu = spawn(config).expect("emulator");
    let params = [
        ("backend", "1".to_string()),
        ("pacing", "1".to_string()),
        ("serverAddress", emu.addr().to_string()),
        ("tareSamples", "0".to_string()),
        // Generous for a loaded test machine (the watchdog is tested in hardware.rs).
        ("replyTimeout", "0.02".to_string()),
        ("realtimePriority", "50".to_string()),
    ];
    let bench = Bench::load(
        &exported_fmu("BenchHardware"),
        params
            .iter()
            .map(|(n, v)| (n.to_string(), v.clone()))
            .collect(),
        None,
    )
    .unwrap();
    let out = tempfile::tempdir().unwrap();
    let step_config = step::StepConfig {
        duration: 0.8,
        ..step::StepConfig::default()
    };
    let r = step::run_step(&bench, &step_config, out.path()).unwrap();
    assert_eq!(r.ends, [RunEnd::Completed, RunEnd::Completed]);
    // The velocities are encoder differences over a networked loop: the identification
    // within 10 %, the step reached.
    assert!((r.damping - 13.0).abs() < 0.1 * 13.0, "{r:?}");
    assert!((r.inertia - 1.43).abs() < 0.1 * 1.43, "{r:?}");
    assert!(r.position.rise_time.is_some(), "{:?}", r.position);
    assert_files(&r.written);
}

#[test]
fn experiments_refuse_to_start_on_the_hardware_with_an_interlock_disarmed() {
    let _s = simulated();
    let cases = [
        ("motorTorqueLimit", "25", "motorTorqueLimit"),
        ("loadRegenPowerLimit", "0", "loadRegenPowerLimit"),
        ("springDeflectionLimit", "0.2", "springDeflectionLimit"),
        ("consistencyPersistence", "0", "consistencyPersistence"),
    ];
    for (name, value, named) in cases {
        let bench = Bench::load(
            &exported_fmu("BenchHardware"),
            vec![(name.to_string(), value.to_string())],
            None,
        )
        .unwrap();
        let out = tempfile::tempdir().unwrap();
        let e = step::run_step(&bench, &step::StepConfig::default(), out.path()).unwrap_err();
        assert!(
            matches!(&e, ExperimentError::NotArmed(p) if p.iter().any(|s| s.contains(named))),
            "{e}"
        );
        // Nothing ran: no file was written.
        assert_eq!(std::fs::read_dir(out.path()).unwrap().count(), 0);
        let e = map::run_map(&bench, &map::MapConfig::default(), out.path()).unwrap_err();
        assert!(matches!(e, ExperimentError::NotArmed(_)), "{e}");
    }
    // Armed at the defaults: the check passes (the simulated backend then runs the step).
    let bench = Bench::load(&exported_fmu("BenchHardware"), vec![], None).unwrap();
    bench.check_armed().unwrap();
    // And the plant has no such check.
    plant(&[("motorTorqueLimit", "25")]).check_armed().unwrap();
}
