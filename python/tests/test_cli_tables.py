"""The `kneebench` CLI's tables from Python: `kneebench sweep --dask` against a LocalCluster
(the same table as the local sweep), its error when the Python package is missing, `--resume`
after a real SIGINT, and the Parquet files of `sweep` and `run` read by pyarrow and polars with
their metadata."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from conftest import kneebench_bin


def cli(*args, env=None, check=True) -> subprocess.CompletedProcess:
    r = subprocess.run(
        [kneebench_bin(), *map(str, args)], capture_output=True, text=True, env=env
    )
    if check:
        assert r.returncode == 0, r.stderr
    return r


def env_with(**kw) -> dict[str, str]:
    env = dict(os.environ)
    env.update({k: str(v) for k, v in kw.items()})
    return env


def same_parquet(a: Path, b: Path) -> None:
    ta, tb = pq.read_table(a), pq.read_table(b)
    assert ta.schema.equals(tb.schema, check_metadata=True)
    assert ta.num_rows == tb.num_rows > 0
    for name in ta.column_names:
        x, y = ta[name].to_numpy(), tb[name].to_numpy()
        if x.dtype == np.float64:
            assert np.array_equal(x.view(np.int64), y.view(np.int64)), name
        else:
            assert list(x) == list(y), name


def test_cli_dask_writes_the_local_table(sweep_spec, tmp_path: Path):
    distributed = pytest.importorskip("distributed")
    spec = sweep_spec(8)
    cli("sweep", spec, "--output", tmp_path / "local.parquet", "--workers", "2")
    cli("sweep", spec, "--output", tmp_path / "local.csv", "--workers", "1")
    env = env_with(KNEEBENCH_PYTHON=sys.executable)
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
    ) as cluster:
        address = cluster.scheduler_address
        r = cli("sweep", spec, "--dask", address, "--output", tmp_path / "dask.parquet",
                "--batch-size", "3", env=env)
        assert f"wrote 8 rows to {tmp_path / 'dask.parquet'} (8 ok, 0 tripped, 0 failed; " \
            f"Dask cluster {address}" in r.stderr, r.stderr
        cli("sweep", spec, "--dask", address, "--output", tmp_path / "dask.csv", env=env)
        # --resume of the finished table: every row is in it, nothing runs, the same table.
        r = cli("sweep", spec, "--dask", address, "--output", tmp_path / "dask.parquet",
                "--resume", env=env)
        assert "wrote 8 rows to" in r.stderr, r.stderr
    same_parquet(tmp_path / "local.parquet", tmp_path / "dask.parquet")
    assert (tmp_path / "dask.csv").read_bytes() == (tmp_path / "local.csv").read_bytes()
    # --dask and local threads do not mix.
    r = cli("sweep", spec, "--dask", "tcp://x:1", "--workers", "2", check=False)
    assert r.returncode == 2 and "cannot be used with" in r.stderr, r.stderr


def test_cli_dask_fails_at_once_when_the_scheduler_refuses_the_connection(sweep_spec, tmp_path):
    """Nothing listens at the address: the connection is refused, and --dask says so at once
    instead of waiting out the Client's 30 s timeout and reporting a TimeoutError."""
    pytest.importorskip("distributed")
    out = tmp_path / "t.parquet"
    r = cli("sweep", sweep_spec(2), "--dask", "tcp://127.0.0.1:1", "--output", out,
            check=False, env=env_with(KNEEBENCH_PYTHON=sys.executable))
    assert r.returncode == 1, r.stderr
    assert "ConnectionRefusedError: no Dask scheduler at tcp://127.0.0.1:1" in r.stderr, r.stderr
    assert not out.exists()


def test_cli_dask_names_what_is_missing(sweep_spec, tmp_path: Path):
    spec = sweep_spec(2)
    out = tmp_path / "t.parquet"
    r = cli("sweep", spec, "--dask", "tcp://127.0.0.1:9", "--output", out, check=False,
            env=env_with(KNEEBENCH_PYTHON=tmp_path / "no-python"))
    assert r.returncode == 1
    assert f"'{tmp_path / 'no-python'}' could not be started" in r.stderr, r.stderr
    assert "KNEEBENCH_PYTHON" in r.stderr
    # An interpreter without site-packages: no kneebench. Isolated (-I: no PYTHONPATH, no
    # user site), so that a kneebench on the test's PYTHONPATH (an unpacked wheel) is not
    # found either.
    bare = tmp_path / "bare-python"
    bare.write_text(f"#!/bin/sh\nexec {sys.executable} -I -S \"$@\"\n")
    bare.chmod(0o755)
    r = cli("sweep", spec, "--dask", "tcp://127.0.0.1:9", "--output", out, check=False,
            env=env_with(KNEEBENCH_PYTHON=bare))
    assert r.returncode == 1
    assert "cannot import kneebench: No module named 'kneebench'" in r.stderr, r.stderr
    # kneebench without distributed: a module that refuses to import ahead of the test's own
    # path (which may be where kneebench is: an unpacked wheel on PYTHONPATH).
    block = tmp_path / "block"
    block.mkdir()
    (block / "distributed.py").write_text("raise ImportError('distributed is not installed')\n")
    path = os.pathsep.join(filter(None, [str(block), os.environ.get("PYTHONPATH")]))
    r = cli("sweep", spec, "--dask", "tcp://127.0.0.1:9", "--output", out, check=False,
            env=env_with(KNEEBENCH_PYTHON=sys.executable, PYTHONPATH=path))
    assert r.returncode == 1
    assert "cannot import distributed: distributed is not installed" in r.stderr, r.stderr
    assert not out.exists()


def test_resume_after_sigint_gives_the_uninterrupted_table(sweep_spec, tmp_path: Path):
    spec = sweep_spec(30, cycles=20)
    cli("sweep", spec, "--output", tmp_path / "whole.parquet", "--workers", "2")
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    env = env_with(TMPDIR=tmp)
    out = tmp_path / "t.parquet"
    journal = tmp_path / "t.parquet.journal"
    p = subprocess.Popen(
        [kneebench_bin(), "sweep", spec, "--output", out, "--workers", "2"],
        env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
    )
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline and p.poll() is None:
        if journal.is_file() and journal.read_text().count("\n") >= 4:
            break
        time.sleep(0.01)
    assert p.poll() is None, f"the sweep ended before it was interrupted: {p.stderr.read()}"
    p.send_signal(signal.SIGINT)
    assert p.wait(timeout=120) == 130
    lines = journal.read_text().count("\n")
    assert 4 <= lines < 31, lines  # the header and some rows, not all of them
    stderr = p.stderr.read()
    assert f"{lines - 1} of 30 points done" in stderr and "run again with --resume" in stderr, stderr
    assert not out.exists()
    # The interrupted sweep removed its scenario directory.
    assert not any(d.name.startswith(f"kneebench-sweep-{p.pid}-") for d in tmp.iterdir())
    r = cli("sweep", spec, "--output", out, check=False, env=env)
    assert r.returncode == 1 and "pass --resume" in r.stderr, r.stderr
    cli("sweep", spec, "--output", out, "--workers", "2", "--resume", env=env)
    assert not journal.exists()
    same_parquet(tmp_path / "whole.parquet", out)


def test_sweep_and_run_parquet_read_by_pyarrow_and_polars(sweep_spec, fmus: Path, tmp_path: Path):
    pl = pytest.importorskip("polars")
    spec = sweep_spec(3)
    table = tmp_path / "sweep.parquet"
    cli("sweep", spec, "--output", table)
    arrow = pq.read_table(table)
    meta = {k.decode(): v.decode() for k, v in arrow.schema.metadata.items()}
    assert meta["kneebench.system"] == "SEA"
    assert meta["kneebench.sweep.spec"] == spec.read_text()
    assert len(meta["kneebench.sweep.fingerprint"]) == 64
    assert meta["kneebench.guid.plant"].startswith("{")
    df = pl.read_parquet(table)
    assert df.columns == arrow.column_names
    assert df["point"].to_list() == [0, 1, 2]
    assert df["status"].to_list() == ["ok"] * 3
    for name in arrow.column_names[1:-2]:
        assert df[name].dtype == pl.Float64, name
        assert np.array_equal(df[name].to_numpy().view(np.int64),
                              arrow[name].to_numpy().view(np.int64)), name
    polars_meta = pl.read_parquet_metadata(table)
    assert {k: v for k, v in polars_meta.items() if k.startswith("kneebench.")} == \
        {k: v for k, v in meta.items() if k.startswith("kneebench.")}

    gait = fmus / "GaitReference.fmu"
    run = tmp_path / "run.parquet"
    csv = tmp_path / "run.csv"
    for out in (run, csv):
        cli("run", gait, "--stop-time", "1", "--step", "0.001", "--param", "gaitPeriod=1.25",
            "--output", out, "-q")
    arrow = pq.read_table(run)
    meta = {k.decode(): v.decode() for k, v in arrow.schema.metadata.items()}
    assert meta["kneebench.system"].endswith("GaitReference.fmu")
    # A JSON object, name to the value's text (a String value may hold any character).
    assert json.loads(meta["kneebench.parameters"]) == {"gaitPeriod": "1.25"}
    assert meta["kneebench.version"]
    assert any(k.startswith("kneebench.guid.") and v.startswith("{") for k, v in meta.items())
    df = pl.read_parquet(run)
    assert df.columns[0] == "time" and "kneeAngleReference" in df.columns
    assert all(dt == pl.Float64 for dt in df.dtypes)
    assert df.height == 1001 == arrow.num_rows
    from_csv = pl.read_csv(csv)
    assert from_csv.columns == df.columns
    for name in df.columns:
        assert np.array_equal(df[name].to_numpy().view(np.int64),
                              from_csv[name].cast(pl.Float64).to_numpy().view(np.int64)), name
    polars_meta = pl.read_parquet_metadata(run)
    assert {k: v for k, v in polars_meta.items() if k.startswith("kneebench.")} == \
        {k: v for k, v in meta.items() if k.startswith("kneebench.")}
