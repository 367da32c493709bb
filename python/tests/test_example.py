"""examples/stiffness-sweep runs: its analysis script on a shortened copy of its spec (two
stiffness levels x two ratios instead of 9 x 5) prints its tables and draws its figure."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from conftest import ROOT

EXAMPLE = ROOT / "examples" / "stiffness-sweep"


def test_the_stiffness_sweep_example_runs_and_draws_its_figure(fmus: Path, tmp_path: Path):
    text = (EXAMPLE / "sweep.toml").read_text()
    short = text
    for old, new in [
        ('fmus = "../../out/fmus"', f'fmus = "{fmus}"'),
        ("levels = 9", "levels = 2"),
        ("values = [120.0, 140.0, 160.0, 180.0, 200.0]", "values = [140.0, 180.0]"),
    ]:
        assert old in short, old
        short = short.replace(old, new)
    spec = tmp_path / "short.toml"
    spec.write_text(short)
    figure = tmp_path / "figure.png"
    r = subprocess.run(
        [sys.executable, EXAMPLE / "analyse.py", "--spec", spec, "--figure", figure],
        capture_output=True, text=True, timeout=600,
    )
    assert r.returncode == 0, r.stderr
    assert "bench_electrical_energy (rows: spring stiffness" in r.stdout
    assert "knee_error_deg" in r.stdout
    # The 2 x 2 table: rows 150 and 550 N m/rad, columns 140 and 180.
    assert "550.0" in r.stdout and "180.0" in r.stdout, r.stdout
    assert figure.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert f"wrote {figure}" in r.stdout


def test_the_optimisation_example_runs_and_draws_its_figure(fmus: Path, tmp_path: Path):
    """optimize.py on a shortened copy of optimize.toml (population 4, 2 generations)."""
    text = (EXAMPLE / "optimize.toml").read_text()
    short = text
    for old, new in [
        ('fmus = "../../out/fmus"', f'fmus = "{fmus}"'),
        ("points = 8", "points = 4"),
        ("generations = 20", "generations = 2"),
    ]:
        assert old in short, old
        short = short.replace(old, new)
    spec = tmp_path / "short.toml"
    spec.write_text(short)
    figure = tmp_path / "figure.png"
    r = subprocess.run(
        [sys.executable, EXAMPLE / "optimize.py", "--spec", spec, "--figure", figure],
        capture_output=True, text=True, timeout=600,
    )
    assert r.returncode == 0, r.stderr
    assert "12 runs: population 4, 2 generations after the design" in r.stdout, r.stdout
    assert "generation  2: best all_electrical_energy = " in r.stdout, r.stdout
    assert "  plant.springStiffness = " in r.stdout and "rms_error_knee = " in r.stdout
    assert figure.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert f"wrote {figure}" in r.stdout
