#!/usr/bin/env bash
# Instructions per step (callgrind) of the study's closed loop and of the plant through its C
# ABI: the figures docs/performance.md quotes, by one command. An instruction count does not
# move with the load of a shared machine, so two builds compare to the instruction.
#
#   bash scripts/instructions.sh                      # this checkout's FMU binary
#   bash scripts/instructions.sh OTHER.so [MORE.so]   # and other builds' libkneebench_fmu.so
#
# Every figure is (3 runs - 1 run) / 5,000 steps: two more gait cycles of 2,500 steps at 1 ms,
# so start-up and the first run's one-time work cancel. The benches' own profile modes make
# the runs (closed_loop: KNEEBENCH_PROFILE_RUNS, plant_abi: KNEEBENCH_PLANT_ABI_PROFILE); every
# binary runs under the same bench executables, built with line tables into
# $KNEEBENCH_PROFILE_TARGET (default target/profile) so that callgrind_annotate can name lines.
# Slow: about a minute and a half per profiled run (the benches export and load the FMUs under
# valgrind before the counted part), ten runs per binary, two at a time.
set -euo pipefail
cd "$(dirname "$0")/.."

if ! command -v valgrind > /dev/null; then
    echo "instructions.sh: needs valgrind (Debian: apt-get install valgrind)" >&2
    exit 2
fi
for so in "$@"; do
    if [ ! -f "$so" ]; then
        echo "instructions.sh: $so is not a file" >&2
        exit 2
    fi
done

export CARGO_TARGET_DIR="${KNEEBENCH_PROFILE_TARGET:-target/profile}"
export CARGO_PROFILE_RELEASE_STRIP=none CARGO_PROFILE_RELEASE_DEBUG=line-tables-only
export CARGO_PROFILE_BENCH_STRIP=none CARGO_PROFILE_BENCH_DEBUG=line-tables-only
cargo build --release -q -p kneebench-fmu
cargo bench -q -p kneebench-tests --bench closed_loop --bench plant_abi --no-run 2> /dev/null

deps="$CARGO_TARGET_DIR/release/deps"
newest() { ls -t "$deps"/"$1"-* | grep -v '\.d$' | head -n 1; }
closed_loop=$(newest closed_loop)
plant_abi=$(newest plant_abi)
own="$CARGO_TARGET_DIR/release/libkneebench_fmu.so"
# The benches load deps/libkneebench_fmu.so first; each binary measured is copied there (a new
# file: cargo hard-links it to the build's own) and this build's is put back at the end.
under_test="$deps/libkneebench_fmu.so"
trap 'cp --remove-destination "$own" "$under_test"' EXIT

# Instructions of one profiled run: collected <toggle> <exe> VAR=value...
collected() {
    local toggle=$1 exe=$2
    shift 2
    env "$@" valgrind --tool=callgrind --callgrind-out-file=/dev/null --toggle-collect="$toggle" \
        "$exe" 2>&1 > /dev/null | sed -n 's/.*Collected : //p'
}

# (3 runs - 1 run) / 5,000: per_step <toggle> <exe> <VAR=value, @RUNS@ for the run count>...
per_step() {
    local toggle=$1 exe=$2
    shift 2
    local one three scratch first
    # The two runs side by side (instruction counts do not depend on the load): half the wait
    # on a machine with two cores or more. A failed run leaves its count empty (checked below).
    scratch=$(mktemp)
    collected "$toggle" "$exe" "${@//@RUNS@/1}" > "$scratch" &
    first=$!
    three=$(collected "$toggle" "$exe" "${@//@RUNS@/3}")
    wait "$first" || true
    one=$(cat "$scratch")
    rm -f "$scratch"
    if [ -z "$one" ] || [ -z "$three" ]; then
        echo "instructions.sh: a profiled run of $exe failed" >&2
        exit 1
    fi
    echo $(((three - one) / 5000))
}

printf '%-40s %10s %10s %10s %10s %10s\n' "libkneebench_fmu.so" "loop" "loop every" "plant DA" "plant SEA" "plant CSEA"
for so in "$own" "$@"; do
    cp --remove-destination "$so" "$under_test"
    loop=$(per_step '*closed_loop*profiled*' "$closed_loop" KNEEBENCH_PROFILE_RUNS=@RUNS@)
    every=$(per_step '*closed_loop*profiled*' "$closed_loop" KNEEBENCH_PROFILE_RUNS=@RUNS@ \
        KNEEBENCH_PROFILE_EVERY_OUTPUT=1)
    plant=()
    for configuration in DA SEA CSEA; do
        plant+=("$(per_step '*plant_abi*profiled*' "$plant_abi" \
            KNEEBENCH_PLANT_ABI_PROFILE="$configuration:@RUNS@")")
    done
    name=$so
    [ "$so" = "$own" ] && name="this checkout"
    printf '%-40s %10s %10s %10s %10s %10s\n' "$name" "$loop" "$every" "${plant[@]}"
done
echo "instructions per step: the SEA closed loop recording the analysed signals (loop) and every"
echo "output (loop every); BenchPlant alone through its C ABI, one gait cycle of recorded inputs"
