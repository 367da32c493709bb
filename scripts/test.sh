#!/usr/bin/env bash
# The whole test suite: formatting, lints, every Rust test (unit, integration, end-to-end with
# the fmpy oracle). Installs what it needs (the pinned Python venv) first.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
cd "$root"
export KNEEBENCH_PYTHON=$("$root/scripts/setup-python.sh")
echo "== cargo fmt --check"
cargo fmt --all -- --check
echo "== cargo clippy"
cargo clippy --workspace --all-targets --locked -- -D warnings
echo "== cargo test"
cargo test --workspace --locked --release
