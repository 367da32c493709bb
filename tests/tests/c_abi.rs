//! Our C types and exported functions against the official FMI 2.0 headers (shipped with fmpy):
//! a C program assigns every exported symbol to the header's function-pointer typedef (compiled
//! with -Werror), links against the FMU binary, prints the C layout of the FMI types, and runs
//! GaitReference through those pointers.

use std::collections::HashMap;
use std::mem::{offset_of, size_of};
use std::process::Command;

use kneebench_tests::*;

fn compile_and_run() -> HashMap<String, String> {
    let lib = fmu_library();
    let headers = fmpy_dir().join("c-code");
    let dir = tempfile::tempdir().unwrap();
    let exe = dir.path().join("abi_check");
    let out = Command::new("cc")
        .args([
            "-std=c99",
            "-Wall",
            "-Wextra",
            "-Werror",
            "-Wno-unused-parameter",
            "-o",
        ])
        .arg(&exe)
        .arg(repo_root().join("tests/c/abi_check.c"))
        .arg(format!("-I{}", headers.display()))
        .arg(&lib)
        .arg(format!("-Wl,-rpath,{}", lib.parent().unwrap().display()))
        .output()
        .expect("run cc");
    assert!(
        out.status.success(),
        "compiling against the official headers failed:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let run = Command::new(&exe)
        .arg(guid_of("GaitReference"))
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&run.stdout).into_owned();
    assert!(run.status.success(), "abi_check failed:\n{stdout}");
    assert!(!stdout.contains("bad-environment"), "{stdout}");
    stdout
        .lines()
        .filter_map(|l| l.split_once(' '))
        .map(|(k, v)| (k.to_string(), v.to_string()))
        .collect()
}

#[test]
fn exported_functions_match_the_official_headers_and_run() {
    let c = compile_and_run();
    let n = |k: &str| -> usize { c[k].parse().unwrap_or_else(|_| panic!("{k}: {}", c[k])) };

    // Layout of the hand-written Rust types equals the C layout.
    assert_eq!(n("sizeof_fmi2Boolean"), size_of::<fmi2Boolean>());
    assert_eq!(n("sizeof_fmi2Integer"), size_of::<fmi2Integer>());
    assert_eq!(n("sizeof_fmi2Real"), size_of::<fmi2Real>());
    assert_eq!(
        n("sizeof_fmi2ValueReference"),
        size_of::<fmi2ValueReference>()
    );
    assert_eq!(n("sizeof_fmi2Status"), size_of::<fmi2Status>());
    assert_eq!(n("sizeof_fmi2Type"), size_of::<fmi2Type>());
    assert_eq!(n("sizeof_fmi2StatusKind"), size_of::<fmi2StatusKind>());
    assert_eq!(n("sizeof_fmi2Byte"), size_of::<fmi2Byte>());
    assert_eq!(
        n("sizeof_fmi2CallbackFunctions"),
        size_of::<fmi2CallbackFunctions>()
    );
    assert_eq!(
        n("offsetof_logger"),
        offset_of!(fmi2CallbackFunctions, logger)
    );
    assert_eq!(
        n("offsetof_allocateMemory"),
        offset_of!(fmi2CallbackFunctions, allocateMemory)
    );
    assert_eq!(
        n("offsetof_freeMemory"),
        offset_of!(fmi2CallbackFunctions, freeMemory)
    );
    assert_eq!(
        n("offsetof_stepFinished"),
        offset_of!(fmi2CallbackFunctions, stepFinished)
    );
    assert_eq!(
        n("offsetof_componentEnvironment"),
        offset_of!(fmi2CallbackFunctions, componentEnvironment)
    );
    assert_eq!(n("sizeof_fmi2EventInfo"), size_of::<fmi2EventInfo>());
    assert_eq!(
        n("offsetof_nextEventTime"),
        offset_of!(fmi2EventInfo, nextEventTime)
    );
    assert_eq!(n("value_fmi2OK"), fmi2Status::fmi2OK as usize);
    assert_eq!(n("value_fmi2Pending"), fmi2Status::fmi2Pending as usize);
    assert_eq!(
        n("value_fmi2CoSimulation"),
        fmi2Type::fmi2CoSimulation as usize
    );
    assert_eq!(
        n("value_fmi2Terminated"),
        fmi2StatusKind::fmi2Terminated as usize
    );
    assert_eq!(
        n("value_fmi2LastSuccessfulTime"),
        fmi2StatusKind::fmi2LastSuccessfulTime as usize
    );
    assert_eq!(c["platform"], "default");
    assert_eq!(c["version"], "2.0");

    // The run through the header's pointer types.
    assert_eq!(
        c["early_doStep"], "3",
        "doStep before initialization is fmi2Error"
    );
    for k in ["setup", "enter", "exit", "terminate", "derivative_status"] {
        assert_eq!(c[k], "0", "{k}");
    }
    assert_eq!(c["terminated_status"], "0 0");
    let last: Vec<&str> = c["last_status"].split(' ').collect();
    assert_eq!(last[0], "0");
    assert!((last[1].parse::<f64>().unwrap() - 2.5).abs() < 1e-12);
    assert_eq!(
        c["dostep_status_kind"], "2",
        "fmi2DoStepStatus is fmi2Discard"
    );
    assert_eq!(c["directional"], "3", "directional derivatives are refused");
    // After exactly one gait period the angle is back to its start value and matches the
    // model's plain Rust evaluation.
    let values: Vec<f64> = c["values"].split(' ').map(|v| v.parse().unwrap()).collect();
    let angle0 = 60f64.to_radians()
        * kneebench_fmu::models::gait::fourier(
            &kneebench_fmu::models::gait::ANGLE_SERIES,
            0.0,
            2.5,
        )
        .value;
    assert!(
        (values[0] - angle0).abs() < 1e-12,
        "{} vs {angle0}",
        values[0]
    );
    let d: f64 = c["derivative"].parse().unwrap();
    assert_eq!(d, values[1], "d(angle)/dt is the velocity output");
    // Every refusal was logged through the importer's logger with its environment.
    assert!(n("messages") >= 2, "messages: {}", c["messages"]);
    assert!(c.contains_key("done"));
}
