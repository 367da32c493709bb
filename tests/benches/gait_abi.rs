//! Cost of the C ABI: GaitReference stepped through the FMI functions of its packaged FMU (as
//! an importer does: fmi2DoStep, then fmi2GetReal and fmi2GetBoolean of every output) against a
//! plain Rust call of the same model in the same run.
//!
//! Run: `cargo bench -p kneebench-tests --bench gait_abi`

use std::hint::black_box;
use std::time::Instant;

use kneebench_fmu::fmi2::types::fmi2Status;
use kneebench_fmu::model::{Access, Model};
use kneebench_fmu::models::gait::GaitReference;
use kneebench_tests::*;

const STEPS: u64 = 200_000;
const H: f64 = 1e-3;
const REPEATS: usize = 9;

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() {
    let dir = tempfile::tempdir().unwrap();
    let fmus = kneebench_harness::package::export_all(&fmu_library(), dir.path()).unwrap();
    let gait = fmus
        .iter()
        .find(|f| f.identifier == "GaitReference")
        .unwrap();
    let fmu = kneebench_harness::Fmu::load(&gait.path, &Default::default()).unwrap();
    let raw = Raw::load(fmu.binary_path());

    let reals: Vec<u32> = vec![100, 101, 102, 103, 104, 105, 107];
    let booleans: Vec<u32> = vec![106];

    let mut abi = Vec::new();
    let mut plain = Vec::new();
    for _ in 0..REPEATS {
        // Through the C ABI.
        let mut i = RawInstance::new(&raw, "bench", &guid_of("GaitReference"));
        i.initialize(0.0, None);
        let mut out = vec![0.0; reals.len()];
        let mut flags = vec![0; booleans.len()];
        let t0 = Instant::now();
        for k in 0..STEPS {
            // SAFETY: valid component and arrays.
            unsafe {
                let s = (raw.do_step)(i.c, k as f64 * H, H, 1);
                debug_assert_eq!(s, fmi2Status::fmi2OK);
                (raw.get_real)(i.c, reals.as_ptr(), reals.len(), out.as_mut_ptr());
                (raw.get_boolean)(i.c, booleans.as_ptr(), booleans.len(), flags.as_mut_ptr());
            }
            black_box(&out);
            black_box(&flags);
        }
        abi.push(t0.elapsed().as_secs_f64() * 1e9 / STEPS as f64);

        // The same work as plain Rust calls.
        let mut m = kneebench_fmu::fmi2::instance::fresh_model::<GaitReference>();
        m.initialize(0.0).unwrap();
        let getters: Vec<fn(&GaitReference) -> f64> = GaitReference::variables()
            .iter()
            .filter(|v| reals.contains(&v.value_reference))
            .filter_map(|v| match v.access {
                Access::Real(g, _) => Some(g),
                _ => None,
            })
            .collect();
        let flag_getters: Vec<fn(&GaitReference) -> bool> = GaitReference::variables()
            .iter()
            .filter(|v| booleans.contains(&v.value_reference))
            .filter_map(|v| match v.access {
                Access::Boolean(g, _) => Some(g),
                _ => None,
            })
            .collect();
        let t0 = Instant::now();
        for k in 0..STEPS {
            let t = k as f64 * H;
            black_box(m.do_step(t, H).unwrap());
            m.calculate(t + H).unwrap();
            for (o, g) in out.iter_mut().zip(&getters) {
                *o = g(&m);
            }
            for (o, g) in flags.iter_mut().zip(&flag_getters) {
                *o = i32::from(g(&m));
            }
            black_box(&out);
            black_box(&flags);
        }
        plain.push(t0.elapsed().as_secs_f64() * 1e9 / STEPS as f64);
    }
    let (a, p) = (median(abi), median(plain));
    println!("GaitReference, {STEPS} steps of {H} s, median of {REPEATS} runs");
    println!("  plain Rust call          {p:8.1} ns/step");
    println!("  C ABI (packaged FMU)     {a:8.1} ns/step");
    println!(
        "  C ABI overhead           {:8.1} ns/step  (target < 50)  ratio {:.2}x",
        a - p,
        a / p
    );
}
