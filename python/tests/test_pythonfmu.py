"""A PythonFMU export run by the kneebench package, i.e. inside a Python interpreter: the
export's binary uses the interpreter hosting the package. The calling Python threads have
thread states of their own (the harness leaves them alone), the sweep's worker threads do not
(the harness keeps one per worker while it runs; module ``embedded_python`` of the harness).
The lag's step is Python code, so the same recurrence computed here gives the same bits."""

from __future__ import annotations

import math
import os
import subprocess
import sys
import sysconfig
import threading
from pathlib import Path

import numpy as np
import pytest

import kneebench

LAG = """
import math
from pythonfmu import Fmi2Causality, Fmi2Slave, Fmi2Variability, Real


class Lag(Fmi2Slave):
    author = "kneebench tests"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.k = 2.0
        self.tau = 0.125
        self.u = 0.0
        self.y = 0.0
        self.register_variable(Real("k", causality=Fmi2Causality.parameter, variability=Fmi2Variability.tunable))
        self.register_variable(Real("tau", causality=Fmi2Causality.parameter, variability=Fmi2Variability.tunable))
        self.register_variable(Real("u", causality=Fmi2Causality.input))
        self.register_variable(Real("y", causality=Fmi2Causality.output))

    def do_step(self, current_time, step_size):
        a = math.exp(-step_size / self.tau)
        self.y = a * self.y + (1.0 - a) * self.k * self.u
        return True
"""

SSD = """<?xml version="1.0" encoding="UTF-8"?>
<ssd:SystemStructureDescription xmlns:ssd="http://ssp-standard.org/SSP1/SystemStructureDescription" xmlns:ssc="http://ssp-standard.org/SSP1/SystemStructureCommon" version="1.0" name="Lag">
  <ssd:System name="Lag">
    <ssd:Elements>
      <ssd:Component name="lag" source="Lag.fmu" type="application/x-fmu-sharedlibrary">
        <ssd:Connectors>
          <ssd:Connector name="u" kind="input"><ssc:Real/></ssd:Connector>
          <ssd:Connector name="y" kind="output"><ssc:Real/></ssd:Connector>
        </ssd:Connectors>
      </ssd:Component>
    </ssd:Elements>
  </ssd:System>
</ssd:SystemStructureDescription>
"""

SWEEP = """\
system = "lag.ssd"
stop_time = 0.5
step = 0.001

[design]
kind = "grid"

[[parameters]]
name = "lag.k"
values = [1.0, 2.0, 3.0, 4.0, 5.0]

[[parameters]]
name = "lag.u"
values = [0.75]

[[metrics.signals]]
signal = "lag.y"
stats = ["max"]
"""

STEP = 0.001
STOP = 0.5
STEPS = 500


@pytest.fixture(scope="module")
def lag_fmu(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("pythonfmu")
    (d / "Lag.py").write_text(LAG)
    subprocess.run(
        [sys.executable, "-m", "pythonfmu", "build", "-f", d / "Lag.py", "--dest", d],
        check=True,
        capture_output=True,
    )
    (d / "lag.ssd").write_text(SSD)
    (d / "sweep.toml").write_text(SWEEP)
    return d / "Lag.fmu"


def lag(k: float, u: float) -> np.ndarray:
    """The model's recurrence, row 0 (after initialisation) to row STEPS."""
    a = math.exp(-STEP / 0.125)
    y, ys = 0.0, [0.0]
    for _ in range(STEPS):
        y = a * y + (1.0 - a) * k * u
        ys.append(y)
    return np.array(ys)


def bits(x: np.ndarray) -> np.ndarray:
    return np.asarray(x, dtype=np.float64).view(np.int64)


def test_a_pythonfmu_export_runs_on_the_callers_python_threads(lag_fmu: Path):
    expected = {k: lag(k, 0.75) for k in (2.0, 3.0)}
    results: dict[float, np.ndarray] = {}

    def one(k: float) -> None:
        # force: the export's model description lacks an InitialUnknown that `kneebench
        # validate` asks for (refused without force, as `kneebench run` without --force).
        # isolate="never": in this process, on the calling thread (the default runs a
        # foreign FMU in a host process: test_a_pythonfmu_export_runs_isolated_by_default).
        df = kneebench.run(
            lag_fmu,
            params={"k": k, "u": 0.75},
            stop_time=STOP,
            step=STEP,
            force=True,
            isolate="never",
        )
        assert df.attrs["status"] == "completed"
        results[k] = df["y"].to_numpy()

    # The main thread and another Python thread at once, each with its own thread state.
    other = threading.Thread(target=one, args=(3.0,))
    other.start()
    one(2.0)
    other.join(timeout=120)
    assert not other.is_alive()
    for k, y in expected.items():
        assert y[-1] > 0.5 * k * 0.75
        assert np.array_equal(bits(results[k]), bits(y)), k


def test_a_pythonfmu_export_sweeps_on_worker_threads(lag_fmu: Path):
    spec = lag_fmu.parent / "sweep.toml"
    one = kneebench.sweep(spec, workers=1)
    two = kneebench.sweep(spec, workers=2)
    assert list(one["status"]) == ["ok"] * 5
    for c in ("lag.k", "max(lag.y)"):
        assert np.array_equal(bits(one[c]), bits(two[c])), c
    # The lag rises monotonically under a constant input: its maximum is its last value.
    for k, top in zip(two["lag.k"], two["max(lag.y)"]):
        assert bits(top) == bits(lag(k, 0.75)[-1]), k


def test_a_pythonfmu_export_runs_isolated_by_default_with_the_same_bits(lag_fmu: Path):
    # The default isolate="auto" runs the export in the kneebench-fmu-host shipped in the
    # wheel, which preloads this interpreter's libpython: the same recurrence, bit for bit.
    df = kneebench.run(lag_fmu, params={"k": 3.0, "u": 0.75}, stop_time=STOP, step=STEP, force=True)
    assert df.attrs["status"] == "completed"
    assert np.array_equal(bits(df["y"].to_numpy()), bits(lag(3.0, 0.75)))


CRASH = """
import os
from pythonfmu import Fmi2Causality, Fmi2Slave, Real


class Crash(Fmi2Slave):
    author = "kneebench tests"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.y = 0.0
        self.register_variable(Real("y", causality=Fmi2Causality.output))

    def do_step(self, current_time, step_size):
        if current_time >= 0.1:
            os.abort()
        self.y = current_time
        return True
"""


def test_a_crashing_foreign_fmu_raises_instead_of_killing_the_interpreter(tmp_path: Path):
    # A PythonFMU export that aborts its process at t = 0.1 s. By default (isolate="auto", as
    # `kneebench run`) it crashes its host process and the run raises KneebenchError naming
    # the signal; in this process (isolate="never", before: always) it ends the interpreter.
    (tmp_path / "Crash.py").write_text(CRASH)
    subprocess.run(
        [sys.executable, "-m", "pythonfmu", "build", "-f", tmp_path / "Crash.py", "--dest", tmp_path],
        check=True,
        capture_output=True,
    )
    code = """\
import sys, kneebench
try:
    kneebench.run(sys.argv[1], stop_time=0.5, step=0.001, force=True, isolate=sys.argv[2])
    print("returned")
except kneebench.KneebenchError as e:
    print("raised", e)
"""
    fmu = str(tmp_path / "Crash.fmu")
    r = subprocess.run(
        [sys.executable, "-c", code, fmu, "auto"], capture_output=True, text=True, timeout=120
    )
    assert r.returncode == 0, (r.returncode, r.stderr[-2000:])
    assert r.stdout.startswith("raised"), r.stdout
    assert "crashed (signal 6, SIGABRT)" in r.stdout, r.stdout
    r = subprocess.run(
        [sys.executable, "-c", code, fmu, "never"], capture_output=True, text=True, timeout=120
    )
    assert r.returncode == -6, (r.returncode, r.stdout, r.stderr[-2000:])


def test_isolate_is_checked_before_anything_runs(lag_fmu: Path):
    with pytest.raises(ValueError, match="isolate must be 'auto', 'always' or 'never'"):
        kneebench.run(lag_fmu, stop_time=STOP, force=True, isolate="sometimes")



TOLERANCE = """
from pythonfmu import DefaultExperiment, Fmi2Causality, Fmi2Slave, Real


class Tolerance(Fmi2Slave):
    author = "kneebench tests"
    default_experiment = DefaultExperiment(start_time=0.0, stop_time=0.01, step_size=0.001, tolerance=2.5e-5)

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.tol = -1.0
        self.register_variable(Real("tol", causality=Fmi2Causality.output))

    def setup_experiment(self, start_time, stop_time, tolerance):
        self.tol = -1.0 if tolerance is None else tolerance

    def do_step(self, current_time, step_size):
        return True
"""


def test_run_passes_the_default_experiments_tolerance_as_the_cli_does(tmp_path: Path):
    # An export that outputs the tolerance fmi2SetupExperiment gave it (-1 for none): the
    # package's run passed none where `kneebench run` passes the DefaultExperiment's.
    from conftest import kneebench_bin

    (tmp_path / "Tolerance.py").write_text(TOLERANCE)
    subprocess.run(
        [sys.executable, "-m", "pythonfmu", "build", "-f", tmp_path / "Tolerance.py", "--dest", tmp_path],
        check=True,
        capture_output=True,
    )
    fmu = tmp_path / "Tolerance.fmu"
    csv = tmp_path / "tol.csv"
    # The export leaves libpython's symbols to its host: the CLI preloads this Python's.
    libpython = Path(sysconfig.get_config_var("LIBDIR")) / sysconfig.get_config_var("LDLIBRARY")
    r = subprocess.run(
        [kneebench_bin(), "run", fmu, "--force", "--preload", libpython, "--output", csv, "-q"],
        capture_output=True,
        text=True,
        env={**os.environ, "PYTHONHOME": sys.base_prefix},
    )
    assert r.returncode == 0, r.stderr
    cli = np.loadtxt(csv, delimiter=",", skiprows=1)
    assert cli[-1, 1] == 2.5e-5, cli
    df = kneebench.run(fmu, force=True)
    assert df.attrs["status"] == "completed"
    assert list(df["tol"]) == list(cli[:, 1])
