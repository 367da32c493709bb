"""kneebench.optimize: the frame of every run (its generation, units, the best run and the
history), the ask/tell Optimizer run in this process, refusals (a sweep of an optimisation's
spec, an optimisation of a sweep's), and the same optimisation on a Dask cluster (two worker
processes), from Python and by `kneebench optimize --dask`, against the local one: the same
frame bit for bit and the same table byte for byte."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest

import kneebench
from conftest import kneebench_bin
from test_kneebench import assert_bit_identical

KNEE_MAX = 0.0099  # the constraint of the optimize_spec fixture: rms_error_knee <= KNEE_MAX
OBJECTIVE = "all_electrical_energy"


def without_optimize(spec: Path) -> Path:
    """The same spec as a sweep (its design: the optimisation's first generation)."""
    text = spec.read_text()
    plain = spec.with_name("plain.toml")
    plain.write_text(text[: text.index("[optimize]")])
    return plain


@pytest.fixture(scope="module")
def cluster():
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
    ) as c:
        yield c


def test_optimize_gives_every_run_its_generation_and_the_best_feasible_run(
    optimize_spec, tmp_path: Path
):
    spec = optimize_spec()
    seen: list[dict] = []
    out = tmp_path / "local.parquet"
    df = kneebench.optimize(spec, workers=2, output=out, on_generation=seen.append)
    sweep = kneebench.sweep(without_optimize(spec), workers=1)
    params = ["plant.springStiffness", "plant.harmonicDriveRatio"]
    assert list(df.columns) == ["point", "generation"] + list(sweep.columns[1:])
    assert list(df.attrs["units"]) == list(df.columns)
    assert df.attrs["units"]["generation"] == ""
    assert df.attrs["units"][OBJECTIVE] == "J"
    assert df.attrs["optimize"] == {
        "objective": OBJECTIVE, "direction": "minimize", "population": 6, "generations": 3
    }
    assert list(df["point"]) == list(range(24))
    assert list(df["generation"]) == [p // 6 for p in range(24)]
    assert df["generation"].dtype == np.int64
    assert set(df["status"]) == {"ok"}
    # The first generation is the design: the sweep of the same spec without [optimize].
    assert_bit_identical(df[df["generation"] == 0].drop(columns="generation"), sweep)
    # Later generations stay within [min, max] and try other points.
    assert df[params[0]].between(150, 550).all() and df[params[1]].between(120, 200).all()
    assert df[params[0]].nunique() > 6

    feasible = df[(df["status"] == "ok") & (df["rms_error_knee"] <= KNEE_MAX)]
    expected = feasible.sort_values([OBJECTIVE, "point"], kind="stable").iloc[0]
    best = df.attrs["best"]
    assert best["point"] == expected["point"]
    assert best["generation"] == expected["generation"]
    assert best["parameters"] == {p: expected[p] for p in params}
    assert best["objective"] == expected[OBJECTIVE]
    assert best["metrics"]["rms_error_knee"] == expected["rms_error_knee"]
    assert best["violation"] == 0.0 and best["feasible"] is True
    assert best["status"] == "ok" and best["message"] == ""
    # The constraint matters: the least energy of all runs breaks it, and so does every
    # point of the design (the first generation's best is the least violation).
    assert df.loc[df[OBJECTIVE].idxmin(), "rms_error_knee"] > KNEE_MAX
    assert (sweep["rms_error_knee"] > KNEE_MAX).all()

    history = df.attrs["history"]
    assert seen == history
    assert [h["generation"] for h in history] == [0, 1, 2, 3]
    assert history[0]["violation"] > 0
    assert all(h["violation"] == 0 for h in history[1:])
    assert all(b["objective"] <= a["objective"] for a, b in zip(history[1:], history[2:]))
    assert history[-1]["point"] == best["point"]

    # The table written: the frame without its generation, with the optimisation's metadata;
    # and the same whatever the number of workers.
    table = pq.read_table(out)
    meta = {k.decode(): v.decode() for k, v in table.schema.metadata.items()}
    assert meta["kneebench.optimize.best_point"] == str(best["point"])
    assert meta["kneebench.optimize.best_feasible"] == "true"
    assert meta["kneebench.optimize.objective"] == OBJECTIVE
    assert meta["kneebench.optimize.population"] == "6"
    written = table.to_pandas().astype({"status": object, "message": object})
    assert_bit_identical(df.drop(columns="generation"), written)
    one = kneebench.optimize(spec, workers=1, output=tmp_path / "one.parquet")
    assert_bit_identical(df, one)
    assert (tmp_path / "one.parquet").read_bytes() == out.read_bytes()


def test_the_ask_tell_optimizer_gives_the_local_result(optimize_spec, tmp_path: Path):
    """The native Optimizer (what the Dask driver uses), its points run in this process by
    optimize_points: the same result and table as the local optimize; refusals on the way."""
    spec = str(optimize_spec())
    local = kneebench.optimize(spec, output=tmp_path / "local.parquet")
    out = tmp_path / "asked.parquet"
    opt = kneebench._native.Optimizer(spec, str(out))
    assert opt.total_runs == 24 and not opt.finished
    assert opt.info["population"] == 6
    with pytest.raises(kneebench.KneebenchError, match="0 of 4 generations told"):
        opt.finish()
    points = opt.ask()
    assert [p for p, _ in points] == list(range(6))
    rows = kneebench._native.optimize_points(spec, points)
    assert rows["fingerprint"] == opt.info["fingerprint"]
    with pytest.raises(kneebench.KneebenchError, match="fingerprint"):
        opt.tell({**rows, "fingerprint": "0" * 64})
    moved = [(points[0][0], [v + 1.0 for v in points[0][1]])]
    with pytest.raises(kneebench.KneebenchError, match="other parameter values than asked"):
        opt.tell(kneebench._native.optimize_points(spec, moved))
    with pytest.raises(kneebench.KneebenchError, match="point 6 is not a point of the current"):
        opt.tell(kneebench._native.optimize_points(spec, [(6, points[0][1])]))
    # A batch at a time: journaled, the generation told when its last row is there.
    opt.tell([kneebench._native.optimize_points(spec, points[3:5]),
              kneebench._native.optimize_points(spec, points[:3])])
    assert opt.history == [] and opt.ask() == points[5:]
    journal = tmp_path / "asked.parquet.journal"
    assert len(journal.read_text().splitlines()) == 1 + 5
    opt.tell(kneebench._native.optimize_points(spec, points[5:]))
    assert len(opt.history) == 1
    while points := opt.ask():
        opt.tell(kneebench._native.optimize_points(spec, points))
    assert opt.finished and len(opt.history) == 4
    d = opt.finish()
    assert not journal.exists()
    assert out.read_bytes() == (tmp_path / "local.parquet").read_bytes()
    assert_bit_identical(kneebench._optimization_frame(d), local)
    with pytest.raises(kneebench.KneebenchError, match="finished already"):
        opt.ask()


def test_a_sweep_refuses_an_optimisation_and_the_other_way_round(
    optimize_spec, sweep_spec, tmp_path: Path
):
    spec = optimize_spec()
    refusal = r"this spec optimises \(\[optimize\]\): run it with `kneebench optimize`"
    with pytest.raises(kneebench.SpecError, match=refusal):
        kneebench.sweep(spec)
    with pytest.raises(kneebench.SpecError, match=refusal):
        kneebench.sweep_info(spec)  # the Dask sweep's first step
    with pytest.raises(kneebench.SpecError, match=refusal):
        kneebench._native.sweep_points(str(spec), [0])
    plain = sweep_spec(4)
    with pytest.raises(kneebench.SpecError, match=r"no \[optimize\] table"):
        kneebench.optimize(plain)
    with pytest.raises(kneebench.SpecError, match=r"no \[optimize\] table"):
        kneebench._native.Optimizer(str(plain))
    with pytest.raises(kneebench.SpecError, match=r"no \[optimize\] table"):
        kneebench._native.optimize_points(str(plain), [(0, [300.0, 150.0])])
    # A refused [optimize] table names its line.
    bad = tmp_path / "bad.toml"
    bad.write_text(spec.read_text().replace('objective = "all_electrical_energy"',
                                            'objective = "energy"'))
    with pytest.raises(kneebench.SpecError, match=r"line 27: objective 'energy' is not a metric"):
        kneebench.optimize(bad)
    with pytest.raises(kneebench.KneebenchError, match="resume needs output"):
        kneebench.optimize(spec, client=object(), resume=True)
    # ship() takes an optimisation's spec too.
    files = kneebench._native.input_files(str(spec))
    assert spec in files and any(f.name == "BenchPlant.fmu" for f in files)


def test_optimize_on_a_dask_cluster_equals_the_local_run(optimize_spec, cluster, tmp_path):
    distributed = pytest.importorskip("distributed")
    spec = optimize_spec()
    local = kneebench.optimize(spec, workers=2, output=tmp_path / "local.parquet")
    seen: list[dict] = []
    with distributed.Client(cluster) as client:
        assert len(client.scheduler_info()["workers"]) == 2
        table = kneebench.optimize(spec, client=client, output=tmp_path / "dask.parquet",
                                   batch_size=2, on_generation=seen.append)
        # Default batches too (here one point each), into a CSV.
        csv = kneebench.optimize(spec, client=client, output=tmp_path / "dask.csv")
    assert_bit_identical(local, table)
    assert_bit_identical(local, csv)
    np.testing.assert_equal(table.attrs, local.attrs)  # NaN metrics of the best compare equal
    assert seen == local.attrs["history"]
    assert (tmp_path / "dask.parquet").read_bytes() == (tmp_path / "local.parquet").read_bytes()
    kneebench.optimize(spec, workers=1, output=tmp_path / "local.csv")
    assert (tmp_path / "dask.csv").read_bytes() == (tmp_path / "local.csv").read_bytes()


def test_cli_optimize_dask_prints_and_writes_what_the_local_run_does(
    optimize_spec, cluster, tmp_path: Path
):
    spec = optimize_spec()

    def cli(*args, env=None) -> subprocess.CompletedProcess:
        r = subprocess.run([kneebench_bin(), "optimize", spec, *map(str, args)],
                           capture_output=True, text=True, env=env)
        assert r.returncode == 0, r.stderr
        return r

    local = cli("--output", tmp_path / "local.parquet", "--workers", "2")
    import os

    env = {**os.environ, "KNEEBENCH_PYTHON": sys.executable}
    address = cluster.scheduler_address
    dask = cli("--output", tmp_path / "dask.parquet", "--dask", address, "--batch-size", "4",
               env=env)
    assert (tmp_path / "dask.parquet").read_bytes() == (tmp_path / "local.parquet").read_bytes()
    # The same best run and generations, printed the same.
    assert dask.stdout == local.stdout
    assert dask.stdout.startswith("best: point ")
    generations = [line for line in local.stderr.splitlines() if line.startswith("generation")]
    assert len(generations) == 4
    assert [line for line in dask.stderr.splitlines() if line.startswith("generation")] \
        == generations
    assert f"wrote 24 rows to {tmp_path / 'dask.parquet'} (Dask cluster {address}, " \
        in dask.stderr, dask.stderr
    quiet = cli("--output", tmp_path / "quiet.csv", "--dask", address, "-q", env=env)
    assert "generation" not in quiet.stderr and quiet.stdout == local.stdout
    # --resume of the finished table on Dask: nothing runs, the same table and printout.
    before = (tmp_path / "dask.parquet").read_bytes()
    again = cli("--output", tmp_path / "dask.parquet", "--dask", address, "--resume", env=env)
    assert again.stdout == local.stdout
    assert [line for line in again.stderr.splitlines() if line.startswith("generation")] \
        == generations
    assert (tmp_path / "dask.parquet").read_bytes() == before


def test_a_dask_optimisation_stopped_mid_way_resumes_from_its_journal(
    optimize_spec, cluster, tmp_path: Path
):
    distributed = pytest.importorskip("distributed")
    spec = optimize_spec()
    full = kneebench.optimize(spec, workers=2, output=tmp_path / "full.parquet")
    out = tmp_path / "stopped.parquet"
    journal = tmp_path / "stopped.parquet.journal"

    def stop(g: dict) -> None:
        if g["generation"] == 1:
            raise RuntimeError("enough")

    seen: list[dict] = []
    with distributed.Client(cluster) as client:
        with pytest.raises(RuntimeError, match="enough"):
            kneebench.optimize(spec, client=client, output=out, batch_size=2, on_generation=stop)
        assert not out.exists()
        assert len(journal.read_text().splitlines()) == 1 + 12  # generations 0 and 1
        with pytest.raises(kneebench.KneebenchError, match="pass --resume"):
            kneebench.optimize(spec, client=client, output=out)
        resumed = kneebench.optimize(spec, client=client, output=out, resume=True,
                                     on_generation=seen.append)
    assert not journal.exists()
    assert_bit_identical(resumed, full)
    assert seen == full.attrs["history"]  # the replayed generations reported too
    assert out.read_bytes() == (tmp_path / "full.parquet").read_bytes()


def test_an_exception_of_on_generation_stops_the_optimisation_and_resume_ends_it(
    optimize_spec, tmp_path: Path
):
    spec = optimize_spec()
    full = kneebench.optimize(spec, workers=2, output=tmp_path / "full.parquet")
    out = tmp_path / "stopped.parquet"

    def stop(g: dict) -> None:
        if g["generation"] == 1:
            raise RuntimeError("enough")

    with pytest.raises(RuntimeError, match="enough"):
        kneebench.optimize(spec, workers=2, output=out, on_generation=stop)
    journal = tmp_path / "stopped.parquet.journal"
    assert not out.exists()
    assert len(journal.read_text().splitlines()) == 1 + 12  # generations 0 and 1
    resumed = kneebench.optimize(spec, workers=1, output=out, resume=True)
    assert not journal.exists()
    assert_bit_identical(resumed, full)
    assert out.read_bytes() == (tmp_path / "full.parquet").read_bytes()


def test_resume_continues_a_finished_optimisation_given_more_generations(
    optimize_spec, tmp_path: Path
):
    spec = optimize_spec()
    text = spec.read_text()
    generations = int(text.split("generations = ")[1].split()[0])
    fewer = tmp_path / "fewer.toml"
    fewer.write_text(text.replace(f"generations = {generations}", "generations = 1"))
    full = kneebench.optimize(spec, workers=2, output=tmp_path / "full.parquet")
    out = tmp_path / "continued.parquet"
    kneebench.optimize(fewer, workers=2, output=out)
    continued = kneebench.optimize(spec, workers=1, output=out, resume=True)
    assert_bit_identical(continued, full)
    assert continued.attrs["optimize"]["generations"] == generations
    # More generations than asked: refused, the table kept.
    before = out.read_bytes()
    with pytest.raises(kneebench.KneebenchError, match="beyond this sweep"):
        kneebench.optimize(fewer, workers=1, output=out, resume=True)
    assert out.read_bytes() == before
