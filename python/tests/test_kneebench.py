"""The kneebench Python package: run/study/sweep, their DataFrames, units and exceptions, the
tables against the CLI's, and a sweep on a real Dask cluster (scheduler and two worker
processes) against the local one."""

from __future__ import annotations

import contextlib
import subprocess
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest

import kneebench
from conftest import kneebench_bin


def assert_bit_identical(a: pd.DataFrame, b: pd.DataFrame) -> None:
    assert list(a.columns) == list(b.columns)
    assert len(a) == len(b)
    for c in a.columns:
        x, y = a[c].to_numpy(), b[c].to_numpy()
        if x.dtype == np.float64:
            assert y.dtype == np.float64, c
            assert np.array_equal(x.view(np.int64), y.view(np.int64)), c
        else:
            assert list(x) == list(y), c

@contextlib.contextmanager
def a_worker_killed_while_busy(client):
    """Kills (SIGKILL) the first of the client's workers as soon as it runs a task, while the
    body runs (which gets the worker's address); asserts afterwards that it was killed."""
    import os
    import signal
    import threading
    import time

    victim = sorted(client.scheduler_info()["workers"])[0]
    pid = client.run(os.getpid)[victim]
    killed = threading.Event()

    def kill_when_busy() -> None:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            if client.processing().get(victim):
                os.kill(pid, signal.SIGKILL)
                killed.set()
                return
            time.sleep(0.005)

    killer = threading.Thread(target=kill_when_busy)
    killer.start()
    try:
        yield victim
    finally:
        killer.join()
    assert killed.is_set(), "the worker was not killed during the sweep"


def test_run_returns_float64_columns_with_units_equal_to_the_cli(fmus: Path, tmp_path: Path):
    gait = fmus / "GaitReference.fmu"
    df = kneebench.run(gait, params={"gaitPeriod": 1.25}, stop_time=2.0, step=0.001)
    assert df.columns[0] == "time"
    assert "kneeAngleReference" in df.columns
    assert all(df[c].dtype == np.float64 for c in df.columns)
    assert len(df) == 2001
    assert df.attrs["units"]["time"] == "s"
    assert df.attrs["units"]["kneeAngleReference"] == "rad"
    assert df.attrs["status"] == "completed"
    csv = tmp_path / "gait.csv"
    subprocess.run(
        [kneebench_bin(), "run", gait, "--stop-time", "2", "--step", "0.001",
         "--param", "gaitPeriod=1.25", "--output", csv, "-q"],
        check=True, capture_output=True,
    )
    cli = pd.read_csv(csv).astype(np.float64)
    assert_bit_identical(df, cli)
    # The period took effect: the reference repeats after 1.25 s.
    ref = df["kneeAngleReference"].to_numpy()
    assert ref[250] == pytest.approx(ref[1500], abs=1e-9)
    sub = kneebench.run(gait, variables=["kneeAngleReference"], stop_time=0.5)
    assert list(sub.columns) == ["time", "kneeAngleReference"]


def test_a_run_an_interlock_ends_keeps_every_row_bit_identical_to_the_cli(
    fmus: Path, tmp_path: Path
):
    # The run announces 2001 rows and ends after 44: the columns, filled in a buffer of 2001
    # slots each, are closed up without a gap (and the frame is the caller's to change).
    plant = fmus / "BenchPlant.fmu"
    params = {"testCurrentCommand": 3.0, "springDeflectionLimit": 0.01}
    df = kneebench.run(plant, params=params, stop_time=2.0)
    assert df.attrs["status"] == "terminated"
    assert "spring deflection above limit" in df.attrs["message"]
    assert 10 < len(df) < 2001
    csv = tmp_path / "tripped.csv"
    done = subprocess.run(
        [kneebench_bin(), "run", plant, "--stop-time", "2", "--output", csv, "-q"]
        + [a for k, v in params.items() for a in ("--param", f"{k}={v}")],
        capture_output=True,
    )
    assert done.returncode == 3, done.stderr
    assert_bit_identical(df, pd.read_csv(csv).astype(np.float64))
    df.iloc[0, 0] = -1.0
    assert df.iloc[0, 0] == -1.0
    assert kneebench.run(plant, params=params, stop_time=2.0)["time"].iloc[0] == 0.0


def test_run_raises_with_the_rust_message(fmus: Path):
    gait = fmus / "GaitReference.fmu"
    with pytest.raises(kneebench.KneebenchError, match="has no variable 'nope'"):
        kneebench.run(gait, params={"nope": 1.0})
    with pytest.raises(kneebench.KneebenchError, match="expected an .fmu, .ssp or .ssd"):
        kneebench.run(fmus / "missing.txt")
    with pytest.raises(kneebench.KneebenchError, match="variables"):
        kneebench.run(gait, variables=["noSuchOutput"])
    with pytest.raises(kneebench.KneebenchError):
        kneebench.run(gait, stop_time=1.0, step=0.3)  # stop time off the step grid


def test_run_refuses_the_values_the_cli_refuses_before_running(fmus: Path):
    # What `kneebench run --param` refuses as a usage error is refused before the run, naming
    # the parameter (not by the FMU as the run starts).
    gait = fmus / "GaitReference.fmu"
    for value, problem in [
        (float("nan"), "NaN is not a finite number"),
        (-1.0, r"-1 is outside \[0, 1000\]"),
    ]:
        with pytest.raises(kneebench.KneebenchError, match=rf"params\['fadeInTime'\]: {problem}"):
            kneebench.run(gait, params={"fadeInTime": value}, stop_time=0.01)
    with pytest.raises(kneebench.KneebenchError, match=r"params\['kneeAngleReference'\]: .*takes no value"):
        kneebench.run(gait, params={"kneeAngleReference": 0.1}, stop_time=0.01)


def test_study_reports_one_row_per_actuator(fmus: Path, tmp_path: Path):
    df = kneebench.study(fmus, tmp_path / "study", actuators=["SEA"], cycles=2)
    assert list(df.index) == ["SEA"]
    sea = df.loc["SEA"]
    assert sea["cycles"] == 1
    assert sea["trip"] is None
    assert 0 < sea["rms_error_knee"] < np.radians(0.7)
    assert sea["bench_electrical_energy"] > 0
    assert abs(sea["balance_residual"]) < 1e-6 * abs(sea["test_mechanical_energy"]) + 1e-9
    with pytest.raises(kneebench.KneebenchError, match="unknown scenario 'x'"):
        kneebench.study(fmus, tmp_path / "s3", actuators=["SEA"], scenario="x")
    with pytest.raises(kneebench.KneebenchError, match="unknown actuator 'XY'"):
        kneebench.study(fmus, tmp_path / "s2", actuators=["XY"])


def test_sweep_equals_the_cli_table_whatever_the_workers(sweep_spec, tmp_path: Path):
    spec = sweep_spec(6)
    one = kneebench.sweep(spec, workers=1)
    two = kneebench.sweep(spec, workers=2)
    assert_bit_identical(one, two)
    assert list(one["point"]) == list(range(6))
    assert set(one["status"]) == {"ok"}
    assert one["rms_error_knee"].nunique() == 6
    out = tmp_path / "cli.parquet"
    subprocess.run(
        [kneebench_bin(), "sweep", spec, "--output", out, "--workers", "2"],
        check=True, capture_output=True,
    )
    table = pq.read_table(out)
    meta = {k.decode(): v.decode() for k, v in table.schema.metadata.items()}
    assert meta["kneebench.system"] == "SEA"
    assert meta["kneebench.guid.plant"].startswith("{")
    cli = table.to_pandas()
    cli["status"] = cli["status"].astype(object)
    cli["message"] = cli["message"].astype(object)
    assert_bit_identical(one.astype({"status": object, "message": object}), cli)


def test_a_bad_spec_raises_spec_error_naming_the_line(sweep_spec, tmp_path: Path):
    spec = sweep_spec(4)
    text = spec.read_text().replace("plant.harmonicDriveRatio", "plant.gearRatio")
    spec.write_text(text)
    with pytest.raises(kneebench.SpecError, match=r"line 15: unknown variable 'plant.gearRatio'"):
        kneebench.sweep(spec)


def test_sweep_on_a_dask_cluster_equals_the_local_table(sweep_spec):
    distributed = pytest.importorskip("distributed")
    spec = sweep_spec(20)
    local = kneebench.sweep(spec, workers=1)
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
    ) as cluster, distributed.Client(cluster) as client:
        assert len(client.scheduler_info()["workers"]) == 2
        table = kneebench.sweep(spec, client=client, batch_size=3)
        # Two worker processes, each its own interpreter and loaded FMUs.
        who = client.run(lambda: __import__("os").getpid())
        assert len(set(who.values())) == 2
    assert_bit_identical(local, table)


def test_rows_of_a_worker_that_sees_other_fmus_are_refused(
    sweep_spec, fmus: Path, tmp_path: Path, monkeypatch
):
    """The sweep's fingerprint covers the FMUs' bytes (a rebuilt plant keeps its GUID): a
    worker that prepared the sweep from another FMU at the same path gives rows of another
    fingerprint, which the client refuses instead of mixing them into the table; so does the
    journal that records a batch's rows. Here the plant is rebuilt (a zip comment: the same
    model, other bytes) after the client prepared the sweep and before the worker does."""
    distributed = pytest.importorskip("distributed")
    import shutil
    import zipfile

    own = tmp_path / "fmus"
    shutil.copytree(fmus, own)
    spec = tmp_path / "sweep.toml"
    spec.write_text(sweep_spec(2).read_text().replace(str(fmus), str(own)))

    def rebuild_plant(comment: bytes) -> None:
        with zipfile.ZipFile(own / "BenchPlant.fmu", "a") as z:
            z.comment = comment

    real_info = kneebench._native.sweep_info

    def info_then_rebuild(path):
        info = real_info(path)
        rebuild_plant(b"rebuilt")
        return info

    monkeypatch.setattr(kneebench._native, "sweep_info", info_then_rebuild)
    with distributed.LocalCluster(
        n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None
    ) as cluster, distributed.Client(cluster) as client:
        with pytest.raises(kneebench.KneebenchError, match="a worker sees another sweep"):
            kneebench.sweep(spec, client=client, retries=0)
    monkeypatch.undo()
    # The journal of the sweep as it is now refuses rows of the sweep before the rebuild.
    rows = kneebench._native.sweep_points(str(spec), [0])
    rebuild_plant(b"rebuilt again")
    journal = kneebench._native.SweepJournal(str(spec), str(tmp_path / "t.parquet"))
    try:
        with pytest.raises(kneebench.KneebenchError, match="rows of another sweep"):
            journal.record(rows)
    finally:
        journal.close()


def test_rows_that_do_not_say_their_sweep_are_refused(sweep_spec, tmp_path: Path):
    spec = sweep_spec(2)
    rows = kneebench._native.sweep_points(str(spec), [0])
    del rows["fingerprint"]
    journal = kneebench._native.SweepJournal(str(spec), str(tmp_path / "t.parquet"))
    try:
        with pytest.raises(kneebench.KneebenchError, match="rows without 'fingerprint'"):
            journal.record(rows)
        assert journal.pending() == [0, 1]
    finally:
        journal.close()


def test_a_worker_killed_mid_sweep_still_gives_every_row(sweep_spec):
    distributed = pytest.importorskip("distributed")

    # 40 gait cycles per run (100 s simulated, tens of milliseconds each), one point per
    # batch: the sweep lasts long enough to kill a worker while it runs a batch.
    spec = sweep_spec(12, cycles=40)
    local = kneebench.sweep(spec, workers=2)
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
    ) as cluster, distributed.Client(cluster) as client:
        with a_worker_killed_while_busy(client) as victim:
            table = kneebench.sweep(spec, client=client, batch_size=1)
        assert victim not in client.scheduler_info()["workers"]
    assert_bit_identical(local, table)


def test_sweep_and_study_frames_carry_units(sweep_spec, fmus: Path, tmp_path: Path):
    table = kneebench.sweep(sweep_spec(2), workers=1)
    units = table.attrs["units"]
    assert list(units) == list(table.columns)
    assert units["plant.springStiffness"] == "N.m/rad"
    assert units["plant.harmonicDriveRatio"] == ""  # a ratio: the FMU declares no unit
    assert units["rms_error_knee"] == "rad"
    assert units["bench_electrical_energy"] == "J"
    assert units["peak_test_torque"] == "N.m"
    assert units["max(plant.loadOutputTorque)"] == "N.m"
    assert units["trip_time"] == "s"
    study = kneebench.study(fmus, tmp_path / "study", actuators=["SEA"], cycles=2)
    assert study.attrs["units"]["test_mechanical_energy"] == "J"
    assert study.attrs["units"]["rms_error_knee"] == "rad"
    assert set(study.columns) <= set(study.attrs["units"])


def test_exceptions_pickle_as_the_package_classes():
    import pickle

    assert kneebench.KneebenchError.__module__ == "kneebench"
    assert kneebench.SpecError.__module__ == "kneebench"
    assert issubclass(kneebench.SpecError, kneebench.KneebenchError)
    for cls in (kneebench.KneebenchError, kneebench.SpecError):
        e = pickle.loads(pickle.dumps(cls("the message")))
        assert type(e) is cls and str(e) == "the message"


def test_errors_raised_on_a_dask_worker_reach_the_client_as_their_class(sweep_spec):
    distributed = pytest.importorskip("distributed")
    spec = str(sweep_spec(3))
    bad = Path(spec).with_name("bad.toml")
    bad.write_text(Path(spec).read_text().replace("plant.harmonicDriveRatio", "plant.nope"))
    with distributed.LocalCluster(
        n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None
    ) as cluster, distributed.Client(cluster) as client:
        worker_pid = list(client.run(__import__("os").getpid).values())[0]
        assert worker_pid != __import__("os").getpid()
        fut = client.submit(kneebench._native.sweep_points, spec, [7], pure=False)
        with pytest.raises(kneebench.KneebenchError, match="point 7 is not in the design"):
            fut.result()
        assert type(fut.exception()) is kneebench.KneebenchError
        fut = client.submit(kneebench._native.sweep_points, str(bad), [0], pure=False)
        with pytest.raises(kneebench.SpecError, match="unknown variable 'plant.nope'"):
            fut.result()


def test_points_that_never_come_back_are_named_and_resume_runs_only_them(
    sweep_spec, tmp_path: Path
):
    """A worker killed while it runs a batch, with the scheduler allowed no failure: the
    batch never comes back, and the error names its points. The rows that came back are in
    the journal next to ``output``; ``resume`` on another cluster runs only the named points
    and the table equals the local one."""
    distributed = pytest.importorskip("distributed")
    import dask
    import re

    spec = sweep_spec(12, cycles=40)
    out = tmp_path / "t.parquet"
    journal = tmp_path / "t.parquet.journal"
    with dask.config.set({"distributed.scheduler.allowed-failures": 0}), distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
    ) as cluster, distributed.Client(cluster) as client:
        with a_worker_killed_while_busy(client), pytest.raises(
            kneebench.KneebenchError, match=r"points without a row: \["
        ) as e:
            kneebench.sweep(spec, client=client, batch_size=3, retries=0, output=out)
    named = [int(x) for x in re.search(r"\[([0-9, ]+)\]", str(e.value)).group(1).split(",")]
    # Whole batches of three, each named once, and not all of them (the other worker's rows
    # came back).
    batches = {p // 3 for p in named}
    assert sorted(named) == [p for b in sorted(batches) for p in range(3 * b, 3 * b + 3)], named
    assert 0 < len(named) < 12, named
    assert "KilledWorker" in str(e.value)
    # The journal holds every other row (marked here, so that a rerun would show).
    assert not out.exists()
    header, *rows = journal.read_text().splitlines()
    assert sorted(int(r.split("\t")[0]) for r in rows) == sorted(set(range(12)) - set(named))
    journal.write_text(
        "\n".join([header] + ["\t".join(r.split("\t")[:3] + ["from the journal"]) for r in rows])
        + "\n"
    )
    local = kneebench.sweep(spec, workers=2)
    local.loc[~local["point"].isin(named), "message"] = "from the journal"
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
    ) as cluster, distributed.Client(cluster) as client:
        with pytest.raises(kneebench.KneebenchError, match="pass --resume"):
            kneebench.sweep(spec, client=client, output=out)
        table = kneebench.sweep(spec, client=client, batch_size=3, output=out, resume=True)
    assert not journal.exists()
    assert_bit_identical(local, table)
    assert_bit_identical(local, kneebench.sweep(spec, workers=1, output=out, resume=True))


def test_ship_sends_the_sweeps_files_to_the_workers(sweep_spec, fmus: Path, tmp_path: Path):
    """The spec and the FMUs reach the workers inside the plugin: they are deleted on this
    machine after being read, and the workers write them back before running the sweep."""
    distributed = pytest.importorskip("distributed")
    import shutil

    from kneebench.shipping import ShipFiles

    own = tmp_path / "shipped"
    shutil.copytree(fmus, own / "fmus")
    spec = own / "sweep.toml"
    spec.write_text(sweep_spec(4).read_text().replace(str(fmus), str(own / "fmus")))
    local = kneebench.sweep(spec, workers=1)
    plugin = ShipFiles.from_spec(spec)
    assert sorted(plugin.files) == sorted(
        [str(spec)]
        + [str(own / "fmus" / f) for f in
           ["BenchPlant.fmu", "GaitReference.fmu", "PidController.fmu"]]
    ), sorted(plugin.files)
    shutil.rmtree(own)
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
    ) as cluster, distributed.Client(cluster) as client:
        client.register_plugin(plugin, name=ShipFiles.name)
        assert spec.is_file() and (own / "fmus" / "BenchPlant.fmu").is_file()
        table = kneebench.sweep(spec, client=client, batch_size=1)
        assert sorted(kneebench.ship(client, spec)) == sorted(plugin.files)
    assert_bit_identical(local, table)
