#!/usr/bin/env bash
# The main job: build, export every FMU, and simulate the default bench scenario.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
cd "$root"
out=${1:-$root/out}
cargo build --release --locked --workspace --bins --lib
bin=target/release/kneebench
"$bin" export --out "$out/fmus"
"$bin" run "$out/fmus/GaitReference.fmu" --stop-time 5 --step 0.001 --output "$out/gait.csv"
"$bin" plot "$out/gait.csv" --signals kneeAngleReference,kneeVelocityReference,loadTorqueReference --out "$out/gait.svg"
echo "FMUs:    $out/fmus"
echo "Results: $out/gait.csv"
echo "Plot:    $out/gait.svg"
