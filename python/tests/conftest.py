"""Fixtures of the kneebench package's tests: the exported FMUs (by the kneebench binary the
test command built) and sweep and optimisation specs written next to them."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def kneebench_bin() -> Path:
    target = Path(os.environ.get("CARGO_TARGET_DIR", ROOT / "target"))
    exe = Path(os.environ.get("KNEEBENCH_BIN", target / "release" / "kneebench"))
    if not exe.is_file():
        pytest.fail(f"{exe} missing: build it with cargo build --release -p kneebench-harness")
    return exe


@pytest.fixture(scope="session")
def fmus(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("fmus")
    subprocess.run([kneebench_bin(), "export", "--out", out], check=True, capture_output=True)
    return out


SWEEP = """\
system = "SEA"
fmus = "{fmus}"
cycles = {cycles}

[design]
kind = "latin-hypercube"
points = {points}
seed = 5

[[parameters]]
name = "plant.springStiffness"
min = 250.0
max = 450.0

[[parameters]]
name = "plant.harmonicDriveRatio"
min = 140.0
max = 180.0

[[metrics.signals]]
signal = "plant.loadOutputTorque"
stats = ["max", "rms"]
from = 2.5
"""


@pytest.fixture()
def sweep_spec(fmus: Path, tmp_path: Path):
    def make(points: int, cycles: int = 2) -> Path:
        p = tmp_path / f"sweep{points}-{cycles}.toml"
        p.write_text(SWEEP.format(fmus=fmus, points=points, cycles=cycles))
        return p

    return make


# An optimisation of the sweep's two parameters (two gait cycles per run, the first the
# start-up, six members, three generations after the design: 24 runs of a fraction of a
# second in all): the least
# electrical energy with the knee's RMS tracking error within a bound that the design's
# points all break and that the unconstrained minimum of these runs breaks too.
OPTIMIZE = """\
system = "SEA"
fmus = "{fmus}"
cycles = 2

[design]
kind = "latin-hypercube"
points = 6
seed = 5

[[parameters]]
name = "plant.springStiffness"
min = 150.0
max = 550.0

[[parameters]]
name = "plant.harmonicDriveRatio"
min = 120.0
max = 200.0

[metrics]
study = true
[[metrics.signals]]
signal = "plant.loadOutputTorque"
stats = ["max", "rms"]

[optimize]
objective = "all_electrical_energy"
direction = "minimize"
generations = 3
seed = 3

[[optimize.constraints]]
metric = "rms_error_knee"
max = {knee_max}
"""


@pytest.fixture()
def optimize_spec(fmus: Path, tmp_path: Path):
    def make(knee_max: float = 0.0099) -> Path:
        p = tmp_path / f"optimize-{knee_max}.toml"
        p.write_text(OPTIMIZE.format(fmus=fmus, knee_max=knee_max))
        return p

    return make
