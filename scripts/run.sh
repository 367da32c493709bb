#!/usr/bin/env bash
# The main job: build, export every FMU, and run the DA/SEA/CSEA gait study on the default
# bench scenario (results CSV, figures over one gait cycle, the comparison table).
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
cd "$root"
out=${1:-$root/out}
cargo build --release --locked --workspace --bins --lib
bin=target/release/kneebench
"$bin" export --out "$out/fmus"
status=0
"$bin" study --fmus "$out/fmus" --out "$out/study" || status=$?
echo "FMUs:      $out/fmus"
echo "Scenarios: $out/study/scenarios"
echo "Report:    $out/study/report.md"
exit "$status"
