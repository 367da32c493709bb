"""Dask's cost per task for a kneebench sweep, against the runs themselves (the figures behind
the README's estimate for large machines and clusters).

    .venv/bin/python python/benches/dask_overhead.py [FMU_DIR]

A LocalCluster of two worker processes (one thread each) runs the same sweep (SEA, one gait
cycle per run, Latin hypercube) with one point per task and with one task per worker,
interleaved with the runs alone (`_native.sweep_points` of every point in this process, the
sweep prepared: the per-run cost), medians of REPEATS. Per-task overhead = (T[batch 1] -
T[batch N/2]) x 2 workers / (extra tasks): what each task adds to a worker's time and the
scheduler's (the scheduler runs in this process, on the same two cores). A worker prepares
the sweep (spec, scenario, FMUs loaded) for its first batch and keeps it for the next ones;
the warm-up sweep pays that. FMU_DIR defaults to a fresh `kneebench export`
(target/release/kneebench).
"""

from __future__ import annotations

import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import distributed

import kneebench

POINTS = 48
REPEATS = 5
ROOT = Path(__file__).resolve().parents[2]

SPEC = """\
system = "SEA"
fmus = "{fmus}"
cycles = 2
[design]
kind = "latin-hypercube"
points = {points}
seed = 3
[[parameters]]
name = "plant.springStiffness"
min = 250.0
max = 450.0
[[parameters]]
name = "plant.harmonicDriveRatio"
min = 140.0
max = 180.0
"""


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        if len(sys.argv) > 1:
            fmus = Path(sys.argv[1]).resolve()
        else:
            fmus = Path(tmp) / "fmus"
            exe = Path(os.environ.get("CARGO_TARGET_DIR", ROOT / "target")) / "release" / "kneebench"
            subprocess.run([exe, "export", "--out", fmus], check=True, capture_output=True)
        spec = Path(tmp) / "sweep.toml"
        spec.write_text(SPEC.format(fmus=fmus, points=POINTS))
        print(f"load average before: {os.getloadavg()}")
        times: dict[str, list[float]] = {"runs": [], "batch1": [], "batchN": []}
        with distributed.LocalCluster(
            n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
        ) as cluster, distributed.Client(cluster) as client:
            reference = kneebench.sweep(spec, workers=2)
            kneebench.sweep(spec, client=client, batch_size=POINTS // 2)  # warm the workers
            kneebench._native.sweep_points(str(spec), [0])  # prepare the sweep here
            for _ in range(REPEATS):
                t = time.perf_counter()
                kneebench._native.sweep_points(str(spec), list(range(POINTS)))
                times["runs"].append(time.perf_counter() - t)
                for key, batch in [("batch1", 1), ("batchN", POINTS // 2)]:
                    t = time.perf_counter()
                    table = kneebench.sweep(spec, client=client, batch_size=batch)
                    times[key].append(time.perf_counter() - t)
                    assert table.equals(reference)
        m = {k: statistics.median(v) for k, v in times.items()}
        tasks1, tasksN = POINTS, 2
        per_task = (m["batch1"] - m["batchN"]) * 2 / (tasks1 - tasksN)
        per_run = m["runs"] / POINTS
        print(
            f"{POINTS} runs of two gait cycles: alone, one thread {m['runs'] * 1e3:.0f} ms "
            f"({per_run * 1e3:.2f} ms per run); 2 Dask workers, 1 point per task "
            f"{m['batch1'] * 1e3:.0f} ms; Dask, {POINTS // 2} points per task "
            f"{m['batchN'] * 1e3:.0f} ms; per-task overhead {per_task * 1e3:.1f} ms "
            f"(= {per_task / per_run:.1f} runs)"
        )
        print(f"load average after: {os.getloadavg()}")


if __name__ == "__main__":
    main()
