#!/usr/bin/env bash
# The whole test suite: formatting, lints, the API docs (no broken links), every Rust test (unit, integration, end-to-end with
# the fmpy oracle) and the Python package's pytest suite (its wheel built by maturin into the venv).
# Installs what it needs (the pinned Python venv) first.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
cd "$root"
export KNEEBENCH_PYTHON=$("$root/scripts/setup-python.sh")
echo "== cargo fmt --check"
cargo fmt --all -- --check
echo "== cargo clippy"
cargo clippy --workspace --all-targets --locked -- -D warnings
echo "== cargo doc"
RUSTDOCFLAGS="-D warnings" cargo doc --workspace --no-deps --locked --quiet
echo "== cargo test"
log=$(mktemp)
# The suite's own cache of extracted FMU binaries (README "Loading"), so that the tests neither
# read nor fill the user's cache; removed with the log at the end.
export KNEEBENCH_CACHE_DIR=$(mktemp -d)
trap 'rm -f "$log"; rm -rf "$KNEEBENCH_CACHE_DIR"' EXIT
# Every test binary runs even after one fails, so that a red run names all its failures (the
# exit status is still cargo's: nonzero when anything failed).
# The Python package is selected although it has no Rust tests (cargo builds nothing of it
# here): its dependencies' features (pyo3's syn, numpy's num-complex) then unify into this
# build, and with the feature reuse-test-build (python/Cargo.toml) the maturin build below
# resolves the harness exactly as this one did and reuses its compiled units (23 s where it
# rebuilt the harness and its dependency graph in 115-190 s).
# The peer comparison (tests/peers) is excluded: a benchmark with no tests, whose fmi-rs
# would turn on codecs of `zip` in the harness under test that the shipped `kneebench` lacks.
cargo test --workspace --exclude kneebench-peers --locked --release --no-fail-fast 2>&1 | tee "$log"
echo "== python package (maturin wheel into the venv, pytest)"
# The kneebench binaries and the FMU library next to them (the Python tests compare with the
# CLI and export the FMUs with it), then the wheel of python/ built by the pinned maturin and
# installed into the venv. The binaries are the ones `cargo test` built for the harness's
# integration tests, and the library the one it built for the tests crate (in deps/, not next
# to them): a separate `cargo build` of those packages resolves their dependencies' features
# without the dev-dependencies' and rebuilt about two minutes of the dependency graph.
target_dir=${CARGO_TARGET_DIR:-$root/target}
for bin in kneebench kneebench-fmu-host; do
    [ -x "$target_dir/release/$bin" ] || { echo "cargo test built no $target_dir/release/$bin" >&2; exit 1; }
done
cp "$target_dir/release/deps/libkneebench_fmu.so" "$target_dir/release/libkneebench_fmu.so"
rm -rf "$target_dir/wheels"
# The FMU host of isolated FMUs ships in the wheel next to the native module
# (kneebench.run(..., isolate="auto"), the default).
install -m 0755 "$target_dir/release/kneebench-fmu-host" python/kneebench/kneebench-fmu-host
"$KNEEBENCH_PYTHON" -m maturin build --release --locked --quiet --features reuse-test-build -i "$KNEEBENCH_PYTHON" -m python/Cargo.toml -o "$target_dir/wheels" >&2
"$KNEEBENCH_PYTHON" -m pip install --quiet --disable-pip-version-check --no-deps --force-reinstall "$target_dir"/wheels/kneebench-*.whl
"$KNEEBENCH_PYTHON" -m pytest python/tests -q -p no:cacheprovider 2>&1 | tee -a "$log"
# One closing line for the whole suite (cargo prints one per test binary, pytest one).
awk '/^test result:/ { p += $4; f += $6; i += $8 }
     /^[0-9]+ (passed|failed)/ { for (k = 1; k < NF; k++) { n = $k + 0; w = $(k + 1); sub(/[,;]$/, "", w);
       if (w == "passed") p += n; else if (w == "failed") f += n; else if (w == "skipped") i += n } }
     END { printf "%d passed, %d failed, %d skipped\n", p, f, i }' "$log"
