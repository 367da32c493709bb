"""Robustness of the package's API: Ctrl-C during a native call, argument checks before anything
runs, the study's scenarios and failed runs, FMUs that `kneebench validate` refuses."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import textwrap
import time
import zipfile
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import kneebench
from conftest import kneebench_bin
from kneebench import KneebenchError

# A child process that runs `CALL` (kneebench imported as `k`), sends itself SIGINT `DELAY`
# seconds after the call starts and prints how it ended: "interrupted <seconds>" or "returned
# <seconds>".
CHILD = """\
import os, signal, threading, time
import kneebench as k
threading.Timer({delay}, lambda: os.kill(os.getpid(), signal.SIGINT)).start()
t0 = time.monotonic()
try:
    {call}
    print("returned", time.monotonic() - t0)
except KeyboardInterrupt:
    print("interrupted", time.monotonic() - t0)
"""


def _interrupted_after(call: str, delay: float, timeout: float = 120) -> float:
    """Seconds from the start of ``call`` to its KeyboardInterrupt in a child process sent
    SIGINT ``delay`` seconds in (fails if the call returned instead)."""
    code = CHILD.format(delay=delay, call=call)
    r = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=timeout
    )
    assert r.returncode == 0, r.stderr
    how, seconds = r.stdout.split()[-2:]
    assert how == "interrupted", r.stdout
    return float(seconds)


@pytest.fixture(scope="module")
def sea_ssp(fmus: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("sea-study")
    kneebench.study(fmus, out, actuators=["SEA"], cycles=2)
    (ssp,) = (out / "scenarios").glob("*.ssp")
    return ssp


def test_ctrl_c_stops_a_run_at_the_next_communication_point(sea_ssp: Path):
    # Uninterrupted this run takes over ten seconds.
    call = f"k.run({str(sea_ssp)!r}, variables=['plant.actuationAngle'], stop_time=8000)"
    assert _interrupted_after(call, 1.5) < 4.5


def test_ctrl_c_stops_a_study(fmus: Path, tmp_path: Path):
    # Three runs of sixty cycles: over ten seconds in all.
    call = f"k.study({str(fmus)!r}, {str(tmp_path)!r}, cycles=60)"
    assert _interrupted_after(call, 1.5) < 4.5


def _long_sweep(sweep_spec) -> Path:
    # 12 points of 200 gait cycles on two threads: about seven seconds.
    return sweep_spec(12, cycles=200)


def test_ctrl_c_stops_a_sweep_and_its_journal_resumes_to_the_same_table(
    sweep_spec, tmp_path: Path
):
    spec = _long_sweep(sweep_spec)
    out = tmp_path / "table.parquet"
    call = f"k.sweep({str(spec)!r}, workers=2, output={str(out)!r})"
    assert _interrupted_after(call, 1.5) < 4.0
    journal = Path(str(out) + ".journal")
    assert journal.exists() and not out.exists()
    resumed = kneebench.sweep(spec, workers=2, output=out, resume=True)
    assert not journal.exists()
    fresh = kneebench.sweep(spec, workers=2)
    pd.testing.assert_frame_equal(resumed, fresh)
    # No row of a stopped run was journaled as failed.
    assert (resumed["status"] == "ok").all()


def test_ctrl_c_stops_an_optimisation_and_its_journal_resumes(
    optimize_spec, tmp_path: Path
):
    spec = optimize_spec()
    # 12 runs of 200 gait cycles on two threads: about six seconds.
    text = spec.read_text().replace("cycles = 2", "cycles = 200").replace(
        "generations = 3", "generations = 1"
    )
    spec.write_text(text)
    out = tmp_path / "opt.parquet"
    call = f"k.optimize({str(spec)!r}, workers=2, output={str(out)!r})"
    assert _interrupted_after(call, 1.5) < 4.0
    assert Path(str(out) + ".journal").exists() and not out.exists()
    resumed = kneebench.optimize(spec, workers=2, output=out, resume=True)
    fresh = kneebench.optimize(spec, workers=2)
    pd.testing.assert_frame_equal(resumed, fresh)


@pytest.mark.parametrize("batch_size", [0, -1])
def test_batch_size_below_one_is_refused_up_front(sweep_spec, optimize_spec, batch_size: int):
    client = object()  # never used: the check comes first
    with pytest.raises(ValueError, match="batch_size must be >= 1"):
        kneebench.sweep(sweep_spec(4), client, batch_size=batch_size)
    with pytest.raises(ValueError, match="batch_size must be >= 1"):
        kneebench.optimize(optimize_spec(), client, batch_size=batch_size)


def test_arguments_are_checked_with_errors_naming_them(fmus: Path, tmp_path: Path, sweep_spec):
    gait = fmus / "GaitReference.fmu"
    with pytest.raises(TypeError, match="params must be a mapping"):
        kneebench.run(gait, params=[("gaitPeriod", 2.0)], stop_time=0.01)  # type: ignore[arg-type]
    with pytest.raises(TypeError, match="variables must be a list of names, not a str"):
        kneebench.run(gait, variables="gaitPhase", stop_time=0.01)
    with pytest.raises(ValueError, match="variables is empty"):
        kneebench.run(gait, variables=[], stop_time=0.01)
    with pytest.raises(TypeError, match="actuators must be a list of names, not a str"):
        kneebench.study(fmus, tmp_path, actuators="SEA", cycles=2)
    with pytest.raises(ValueError, match="actuators is empty"):
        kneebench.study(fmus, tmp_path, actuators=[], cycles=2)
    # Named twice, however spelled: it ran once, without a word.
    with pytest.raises(ValueError, match="actuators names 'sea' more than once"):
        kneebench.study(fmus, tmp_path, actuators=["SEA", "CSEA", "sea"], cycles=2)
    with pytest.raises(KneebenchError, match="actuator SEA given twice"):
        kneebench._native.study(fmus, tmp_path, ["SEA", "sea"], 2, 1.0, "bench-full")
    with pytest.raises(ValueError, match="cycles must be >= 1"):
        kneebench.study(fmus, tmp_path, actuators=["SEA"], cycles=-1)
    # One cycle is the start-up alone, which is not analysed (it was, silently).
    with pytest.raises(ValueError, match="cycles must be >= 2 .given: 1.: the first gait cycle, "
                                         "the start-up, is not analysed"):
        kneebench.study(fmus, tmp_path, actuators=["SEA"], cycles=1)
    with pytest.raises(ValueError, match="workers must be >= 1"):
        kneebench.sweep(sweep_spec(4), workers=-1)


@pytest.mark.parametrize("workers", [1025, 10**8, 2**70])
def test_workers_above_the_bound_raise_before_anything_runs(
    sweep_spec, optimize_spec, tmp_path: Path, workers: int
):
    """A huge ``workers`` tried to start that many threads; above 1024 it raises, and neither
    call writes anything (no journal)."""
    out = tmp_path / "t.parquet"
    with pytest.raises(ValueError, match=f"{workers} worker threads: .* 1 to 1024"):
        kneebench.sweep(sweep_spec(4), workers=workers, output=out)
    with pytest.raises(ValueError, match=f"{workers} worker threads: .* 1 to 1024"):
        kneebench.optimize(optimize_spec(), workers=workers, output=out)
    assert not Path(str(out) + ".journal").exists() and not out.exists()


def test_on_generation_must_be_callable_before_anything_runs(optimize_spec, tmp_path: Path):
    out = tmp_path / "o.parquet"
    with pytest.raises(TypeError, match="on_generation must be callable"):
        kneebench.optimize(optimize_spec(), output=out, on_generation=5)  # type: ignore[arg-type]
    assert not Path(str(out) + ".journal").exists()


def test_the_default_actuators_are_the_scenarios_own(fmus: Path, tmp_path: Path):
    """Without ``actuators`` the harness picks the scenario's (the package keeps no copy)."""
    df = kneebench.study(fmus, tmp_path, cycles=2, scenario="bench-clutch")
    assert list(df.index) == ["SEA", "CSEA"]


def test_the_clutch_scenario_has_no_da(fmus: Path, tmp_path: Path):
    with pytest.raises(KneebenchError, match="bench-clutch scenario has no DA"):
        kneebench.study(fmus, tmp_path, actuators=["DA"], cycles=2, scenario="bench-clutch")


def test_a_failed_study_run_is_not_a_trip(fmus: Path, tmp_path: Path):
    # Ten times the gait's amplitude: the gait FMU refuses the knee angle.
    df = kneebench.study(fmus, tmp_path, actuators=["SEA"], cycles=2, scale=10.0)
    row = df.loc["SEA"]
    assert row["status"] == "failed"
    assert "run failed" in row["message"] and "kneeAngleAmplitude" in row["message"]
    assert row["trip"] is None and np.isnan(row["trip_time"])
    ok = kneebench.study(fmus, tmp_path / "ok", actuators=["SEA"], cycles=2)
    assert ok.loc["SEA", "status"] == "ok" and ok.loc["SEA", "message"] == ""


def _duplicate_name_fmu(fmus: Path, out: Path) -> Path:
    """GaitReference with its output gaitPhase renamed to another variable's name."""
    with zipfile.ZipFile(fmus / "GaitReference.fmu") as zin, zipfile.ZipFile(out, "w") as zout:
        for info in zin.infolist():
            data = zin.read(info.filename)
            if info.filename == "modelDescription.xml":
                text = data.decode().replace('name="gaitPhase"', 'name="kneeAngleReference"', 1)
                data = text.encode()
            zout.writestr(info, data)
    return out


def test_an_fmu_that_validate_refuses_is_refused_unless_forced(fmus: Path, tmp_path: Path):
    fmu = _duplicate_name_fmu(fmus, tmp_path / "dup.fmu")
    with pytest.raises(KneebenchError, match='"kneeAngleReference" is not unique.*force=True'):
        kneebench.run(fmu, stop_time=0.01)
    df = kneebench.run(fmu, stop_time=0.01, force=True)
    assert len(df) > 0


def test_results_that_do_not_fit_in_memory_raise_instead_of_aborting(fmus: Path):
    # Under a 1.5 GB address-space limit, 1e8 rows of 9 columns cannot be kept: the run ends
    # with an error naming the rows and columns (it aborted the interpreter).
    import resource

    def limit() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (1_500_000_000, 1_500_000_000))

    code = textwrap.dedent(f"""\
        import kneebench
        try:
            kneebench.run({str(fmus / "GaitReference.fmu")!r}, stop_time=100000)
            print("returned")
        except kneebench.KneebenchError as e:
            print("raised", e)
        """)
    r = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=300,
        preexec_fn=limit,
    )
    assert r.returncode == 0, (r.returncode, r.stderr[-2000:])
    assert r.stdout.startswith("raised"), r.stdout
    assert "out of memory" in r.stdout and "rows of 9 columns" in r.stdout, r.stdout


def test_a_window_after_the_runs_end_is_refused(fmus: Path, tmp_path: Path):
    spec = tmp_path / "late.toml"
    spec.write_text(textwrap.dedent(f"""\
        system = "SEA"
        fmus = "{fmus}"
        cycles = 2
        [design]
        kind = "grid"
        [[parameters]]
        name = "plant.springStiffness"
        values = [300.0, 400.0]
        [[metrics.signals]]
        signal = "plant.springDeflection"
        stats = ["max"]
        from = 1000.0
        """))
    with pytest.raises(kneebench.SpecError, match="line 12: window from 1000 s starts after"):
        kneebench.sweep(spec)


def test_a_second_sweep_into_an_output_being_swept_is_refused(sweep_spec, tmp_path: Path):
    # A CLI sweep (12 points of 200 gait cycles on one thread: over ten seconds) and a Python
    # one resuming into the same output at once: the Python one is refused while the CLI holds
    # the journal (both ran every point the journal lacked, each rewriting it). Killed, the
    # CLI's lock goes with its process: the output resumes from its journal.
    spec = _long_sweep(sweep_spec)
    out = tmp_path / "table.parquet"
    journal = Path(str(out) + ".journal")
    cli = subprocess.Popen(
        [kneebench_bin(), "sweep", spec, "--output", out, "--workers", "1"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    try:
        deadline = time.monotonic() + 60
        while not (journal.exists() and journal.read_text().count("\n") >= 2):
            assert cli.poll() is None, cli.stderr.read() if cli.stderr else ""
            assert time.monotonic() < deadline, "no row journaled in a minute"
            time.sleep(0.05)
        with pytest.raises(KneebenchError, match="another sweep is running into this output"):
            kneebench.sweep(spec, workers=1, output=out, resume=True)
        assert cli.poll() is None, "the CLI sweep ended before the second was refused"
    finally:
        cli.kill()
        cli.wait()
    done = journal.read_text().count("\n") - 1
    assert 1 <= done < 12
    resumed = kneebench._native.SweepJournal(str(spec), str(out), True)
    assert len(resumed.pending()) == 12 - done


def test_a_thread_that_cannot_start_raises_instead_of_panicking(fmus: Path):
    # RUST_MIN_STACK asks every Rust thread of the child for a stack larger than the address
    # space: the run's thread cannot start, which is a KneebenchError (it was a PanicException).
    code = textwrap.dedent(f"""\
        import kneebench
        try:
            kneebench.run({str(fmus / "GaitReference.fmu")!r}, stop_time=0.01)
            print("returned")
        except kneebench.KneebenchError as e:
            print("raised", e)
        """)
    env = dict(os.environ, RUST_MIN_STACK=str(1 << 50))
    r = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120, env=env
    )
    assert r.returncode == 0, (r.returncode, r.stderr[-2000:])
    assert r.stdout.startswith("raised cannot start a thread for the run"), r.stdout


def test_parameter_values_are_read_as_numbers_whatever_their_python_type():
    """numpy scalars are numbers (numpy 2's repr, ``np.float64(300.0)``, was passed as the
    text), a whole-number float is written without a fraction (an Integer takes it), every
    other real as the shortest text of its float value."""
    from fractions import Fraction

    text = kneebench._text
    assert text(np.linspace(100, 500, 3)[1]) == "300"
    assert text(np.float64(0.1)) == "0.1" == text(0.1)
    assert text(np.float32(0.1)) == repr(float(np.float32(0.1))) == "0.10000000149011612"
    assert text(1.0) == "1" and text(np.float64(-2.0)) == "-2"
    assert text(-0.0) == "-0" and text(0.0) == "0"
    assert text(1.5) == "1.5" and text(2.0**60) == "1.152921504606847e+18"
    assert text(float("nan")) == "nan" and text(float("-inf")) == "-inf"
    assert text(np.int64(3)) == "3" == text(3)
    assert text(Fraction(1, 4)) == "0.25"
    assert text(np.True_) == "true" and text(False) == "false"
    assert text("Exponential") == "Exponential"


def test_run_takes_numpy_floats_and_whole_floats_for_integer_variables(fmus: Path):
    plant = fmus / "BenchPlant.fmu"
    stiffness = np.linspace(100, 500, 3)[1]  # np.float64(300.0)
    for params in ({"springStiffness": stiffness}, {"frictionModel": 2.0},
                   {"frictionModel": np.float64(0.0), "springStiffness": np.float32(250.5)},
                   {"frictionModel": np.int64(3)}):
        df = kneebench.run(plant, params=params, stop_time=0.01)
        assert df.attrs["status"] == "completed", params
    with pytest.raises(KneebenchError, match="'1.5'"):
        kneebench.run(plant, params={"frictionModel": 1.5}, stop_time=0.01)


def test_run_refuses_params_names_and_times_of_other_types(fmus: Path):
    """A parameter's name is a str and the times are real numbers, else TypeError naming
    the argument: a name of another type raised "'int' object is not an instance of 'str'",
    and a bool time ran as 1 s (``step=True``)."""
    gait = fmus / "GaitReference.fmu"
    with pytest.raises(TypeError, match=r"params: a name must be a str, not int: 1$"):
        kneebench.run(gait, params={1: 2.0}, stop_time=0.01)
    for name in ("stop_time", "step"):
        for bad in (True, np.True_, "1", [1.0]):
            with pytest.raises(TypeError, match=f"^{name} must be a real number, not "
                                                f"{type(bad).__name__}$"):
                kneebench.run(gait, **{name: bad})
    # numpy numbers are numbers.
    df = kneebench.run(gait, stop_time=np.int64(1), step=np.float64(0.001))
    assert len(df) == 1001


def test_run_refuses_a_variable_named_twice(fmus: Path):
    gait = fmus / "GaitReference.fmu"
    with pytest.raises(ValueError, match="'gaitPhase' more than once"):
        kneebench.run(gait, variables=["gaitPhase", "kneeAngleReference", "gaitPhase"],
                      stop_time=0.01)


def test_run_as_arrow_gives_the_same_columns_units_and_status(fmus: Path):
    pa = pytest.importorskip("pyarrow")
    gait = fmus / "GaitReference.fmu"
    args = dict(params={"gaitPeriod": 1.25}, stop_time=0.5, step=0.01)
    df = kneebench.run(gait, **args)
    table = kneebench.run(gait, **args, as_arrow=True)
    assert isinstance(table, pa.Table)
    assert table.column_names == list(df.columns)
    for name in df.columns:
        field = table.schema.field(name)
        assert field.type == pa.float64()
        assert field.metadata[b"unit"].decode() == df.attrs["units"][name]
        assert np.array_equal(table[name].to_numpy().view(np.int64),
                              df[name].to_numpy().view(np.int64)), name
    meta = table.schema.metadata
    assert meta[b"kneebench.status"].decode() == df.attrs["status"] == "completed"
    assert meta[b"kneebench.message"].decode() == df.attrs["message"]


def test_cluster_arguments_are_refused_where_they_would_be_ignored(
    sweep_spec, optimize_spec, tmp_path: Path
):
    """``client`` must be a Client (an address string raised AttributeError deep inside),
    ``workers`` is for a local run (it was ignored with a client), ``batch_size`` for a
    cluster's (it was ignored without one); nothing runs or is written."""
    distributed = pytest.importorskip("distributed")
    spec, opt = sweep_spec(4), optimize_spec()
    out = tmp_path / "t.parquet"
    for call in (kneebench.sweep, kneebench.optimize):
        s = spec if call is kneebench.sweep else opt
        with pytest.raises(TypeError, match=r"client must be a dask\.distributed\.Client .*, not "
                                            r"str \(connect first: client=distributed\.Client"):
            call(s, "tcp://127.0.0.1:8786", output=out)
        with pytest.raises(ValueError, match="batch_size is for a Dask client's batches"):
            call(s, batch_size=2, output=out)
        # A Client that is never connected: the check comes before any use of it.
        client = distributed.Client.__new__(distributed.Client)
        with pytest.raises(ValueError, match="workers is for a local run"):
            call(s, client, workers=4, output=out)
    with pytest.raises(TypeError, match="ship needs a dask.distributed.Client"):
        kneebench.ship(None, spec)
    with pytest.raises(TypeError, match="client must be a dask.distributed.Client"):
        kneebench.ship("tcp://127.0.0.1:8786", spec)
    assert not out.exists() and not Path(str(out) + ".journal").exists()


def test_int_arguments_take_numpy_integers():
    assert kneebench._at_least_one("workers", np.int64(3)) == 3
    assert type(kneebench._at_least_one("workers", np.int64(3))) is int
    with pytest.raises(TypeError, match="cycles must be an int, not float"):
        kneebench._at_least_one("cycles", 2.0)
    with pytest.raises(TypeError, match="cycles must be an int, not bool"):
        kneebench._at_least_one("cycles", np.True_)


def test_the_stubs_declare_the_runtime_signatures():
    """Every public function of ``__init__.pyi`` has the runtime's parameters: names, kinds and
    defaults, in order (and every public name of ``__all__`` is in the stub)."""
    import ast
    import inspect

    stub = Path(kneebench.__file__).with_name("__init__.pyi")
    tree = ast.parse(stub.read_text())
    defs = {n.name: n for n in tree.body if isinstance(n, ast.FunctionDef)}
    declared = set(defs) | {n.name for n in tree.body if isinstance(n, ast.ClassDef)} | {
        n.target.id for n in tree.body if isinstance(n, ast.AnnAssign)
    }
    assert set(kneebench.__all__) <= declared, set(kneebench.__all__) - declared
    for name, node in defs.items():
        runtime = inspect.signature(getattr(kneebench, name))
        a = node.args
        positional = a.posonlyargs + a.args
        defaults = [inspect.Parameter.empty] * (len(positional) - len(a.defaults)) + [
            ast.literal_eval(d) for d in a.defaults
        ]
        kw_defaults = [
            inspect.Parameter.empty if d is None else ast.literal_eval(d) for d in a.kw_defaults
        ]
        in_stub = [(p.arg, "positional", d) for p, d in zip(positional, defaults)] + [
            (p.arg, "keyword", d) for p, d in zip(a.kwonlyargs, kw_defaults)
        ]
        kind = {inspect.Parameter.KEYWORD_ONLY: "keyword"}
        at_runtime = [
            (p.name, kind.get(p.kind, "positional"), p.default)
            for p in runtime.parameters.values()
        ]
        assert in_stub == at_runtime, name


@pytest.mark.parametrize(
    "retries, error, message",
    [
        (-1, ValueError, r"retries must be 0 to 100 \(given: -1\)"),
        (101, ValueError, r"retries must be 0 to 100 \(given: 101\)"),
        (10**30, ValueError, r"retries must be 0 to 100"),
        (1.5, TypeError, "retries must be an int, not float"),
        ("2", TypeError, "retries must be an int, not str"),
        (True, TypeError, "retries must be an int, not bool"),
    ],
)
def test_retries_outside_0_to_100_or_not_an_int_raise_before_anything_runs(
    sweep_spec, optimize_spec, tmp_path: Path, retries, error, message
):
    """``retries`` (how often Dask reruns a batch that raised) was handed to Dask as given;
    with or without a client, a bad one raises before anything runs or is written."""
    out = tmp_path / "t.parquet"
    with pytest.raises(error, match=message):
        kneebench.sweep(sweep_spec(4), retries=retries, output=out)
    with pytest.raises(error, match=message):
        kneebench.optimize(optimize_spec(), retries=retries, output=out)
    assert not out.exists() and not Path(str(out) + ".journal").exists()
    assert kneebench._retries(np.int64(0)) == 0 and kneebench._retries(100) == 100


def test_a_number_for_a_string_variable_is_refused(fmus: Path):
    """A number or a bool for a String variable raises: ``1.0`` was set as the text ``"1"``
    (the text a whole float is written as, for an Integer), ``True`` as ``"true"``. A str is
    set as it is."""
    hardware = fmus / "BenchHardware.fmu"
    for value in (1.0, 1, 1.5, np.float64(2.0), True):
        with pytest.raises(
            KneebenchError,
            match=r"params\['serverAddress'\]: .* is a number \(or bool\) and "
            r"'[^']*serverAddress' is a String variable: give its value as a str",
        ):
            kneebench.run(hardware, params={"serverAddress": value}, stop_time=0.01)
    df = kneebench.run(hardware, params={"serverAddress": "1"}, stop_time=0.01)
    assert df.attrs["status"] == "completed"


GAIT_SSD = """<?xml version="1.0" encoding="UTF-8"?>
<ssd:SystemStructureDescription xmlns:ssd="http://ssp-standard.org/SSP1/SystemStructureDescription" version="1.0" name="Gait">
  <ssd:System name="Gait">
    <ssd:Elements>
      <ssd:Component name="gait" source="Gait.fmu" type="application/x-fmu-sharedlibrary"/>
    </ssd:Elements>
  </ssd:System>
</ssd:SystemStructureDescription>
"""

GAIT_SWEEP = """\
system = "gait.ssd"
stop_time = 0.05
step = 0.01

[design]
kind = "grid"

[[parameters]]
name = "gait.kneeAngleAmplitude"
values = [0.5, 1.0]

[[metrics.signals]]
signal = "gait.kneeAngleReference"
stats = ["max"]
"""


def test_a_rebuilt_fmu_beside_an_ssd_is_not_served_from_the_batch_cache(
    fmus: Path, tmp_path: Path
):
    """A worker keeps the sweep it prepared for the next batch while the spec and its files are
    unchanged: an .ssd's own FMUs are among those files (the cache watched only the spec, its
    CSV and the system file, so a rebuilt FMU next to an .ssd kept being run from the old
    prepared sweep, fingerprint and all)."""
    fmu = tmp_path / "Gait.fmu"
    shutil.copy(fmus / "GaitReference.fmu", fmu)
    (tmp_path / "gait.ssd").write_text(GAIT_SSD)
    spec = tmp_path / "sweep.toml"
    spec.write_text(GAIT_SWEEP)
    kneebench._native.clear_cache()
    first = kneebench._native.sweep_points(str(spec), [0])
    assert first["fingerprint"] == kneebench._native.sweep_info(str(spec))["fingerprint"]
    # The FMU rebuilt: the same model, its archive other bytes (one more file).
    with zipfile.ZipFile(fmu, "a") as z:
        z.writestr("documentation/rebuilt.txt", "rebuilt")
    rebuilt = kneebench._native.sweep_info(str(spec))["fingerprint"]
    assert rebuilt != first["fingerprint"]
    again = kneebench._native.sweep_points(str(spec), [0])
    assert again["fingerprint"] == rebuilt
    kneebench._native.clear_cache()
