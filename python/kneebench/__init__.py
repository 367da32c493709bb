"""kneebench from Python: run the bench's FMUs and SSP systems, the DA/SEA/CSEA study and
parameter sweeps, locally or on a Dask cluster, with the results as pandas DataFrames.

The simulations run in Rust (the kneebench harness) with the GIL released; errors are raised
as :class:`KneebenchError` (:class:`SpecError` for a refused sweep spec) carrying the Rust
message.
"""

from __future__ import annotations

import atexit
import math
import os
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import numpy as np
import pandas as pd

from . import _native
from ._native import KneebenchError, SpecError

__all__ = [
    "KneebenchError",
    "SpecError",
    "run",
    "ship",
    "study",
    "sweep",
    "sweep_info",
    "__version__",
]
__version__: str = _native.__version__
# The sweep a Dask worker keeps prepared between batches holds a scenario and extracted FMUs
# in temporary directories: removed when the interpreter exits.
atexit.register(_native.clear_cache)


def _text(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return repr(value)
    return str(value)


def _columns(names: Sequence[str], columns: Sequence[bytes]) -> dict[str, np.ndarray]:
    return {n: np.frombuffer(c, dtype="<f8").copy() for n, c in zip(names, columns)}


def run(
    system: str | os.PathLike[str],
    params: Mapping[str, Any] | None = None,
    variables: Iterable[str] | None = None,
    stop_time: float | None = None,
    step: float | None = None,
) -> pd.DataFrame:
    """Run an FMU (``.fmu``) or an SSP system (``.ssp``/``.ssd``) and return its results.

    ``params`` sets parameters or start values before initialisation (``variable`` for an
    FMU, ``component.variable`` for a system); ``variables`` chooses the recorded columns
    (default: every output). The DataFrame has a ``time`` column [s] and one float64 column
    per signal; ``df.attrs["units"]`` maps each column to its unit (``""`` when it has none),
    ``df.attrs["status"]`` is ``"completed"`` or ``"terminated"`` (an FMU ended the run, e.g.
    an interlock; ``df.attrs["message"]`` says why). A failed run raises KneebenchError.
    """
    p = [(k, _text(v)) for k, v in (params or {}).items()]
    r = _native.run(os.fspath(system), p, list(variables or []), stop_time, step)
    df = pd.DataFrame(_columns(r["names"], r["columns"]))
    df.attrs["units"] = dict(zip(r["names"], r["units"]))
    df.attrs["status"] = r["status"]
    df.attrs["message"] = r["message"]
    return df


def study(
    fmus: str | os.PathLike[str],
    out: str | os.PathLike[str],
    actuators: Sequence[str] = ("DA", "SEA", "CSEA"),
    cycles: int = 4,
    scale: float = 1.0,
    scenario: str = "bench-full",
) -> pd.DataFrame:
    """Run the gait study (the bench's gait on each actuator, FMUs from ``fmus``; scenarios
    and CSV results written under ``out``) and return one row per actuator: tracking errors
    [rad], peak torques [N m], energy terms per gait cycle [J] (the columns of a sweep's study
    metrics), and the interlock trip if any (``trip``, ``trip_time`` [s]). ``scenario`` is
    ``bench-full`` (the 60 deg gait, DA/SEA/CSEA) or ``bench-clutch`` (50 deg, SEA/CSEA under
    impedance control). ``df.attrs["units"]`` maps each column to its unit (``1`` for a count
    or a fraction)."""
    reports = _native.study(
        os.fspath(fmus), os.fspath(out), list(actuators), cycles, scale, scenario
    )
    df = pd.DataFrame(reports).set_index("actuator")
    df.attrs["units"] = {**_native.STUDY_METRIC_UNITS, "trip": ""}
    return df


def _frame(d: Mapping[str, Any]) -> pd.DataFrame:
    data: dict[str, Any] = {"point": np.asarray(d["point"], dtype=np.int64)}
    data.update(_columns(d["names"], d["columns"]))
    data["status"] = list(d["status"])
    data["message"] = list(d["message"])
    df = pd.DataFrame(data)
    _set_units(df, d)
    return df


def _set_units(df: pd.DataFrame, d: Mapping[str, Any]) -> None:
    units = {"point": ""}
    units.update(zip(list(d["parameters"]) + list(d["metrics"]), d["units"]))
    units.update(status="", message="")
    df.attrs["units"] = units


def sweep_info(spec: str | os.PathLike[str]) -> dict[str, Any]:
    """Check a sweep spec against its system (raises SpecError naming each bad line) and
    return ``{"points", "parameters", "metrics", "units", "fingerprint", "files"}``
    (``files``: the absolute paths the sweep reads: the spec, its design CSV, the system file
    or the scenario's FMUs)."""
    return dict(_native.sweep_info(os.path.abspath(os.fspath(spec))))


def _run_batch(spec: str, ids: list[int]) -> dict[str, Any]:
    """One batch of a distributed sweep, run on a Dask worker (needs the wheel, and the spec
    and the FMUs at the same absolute paths as on the client: a shared path or :func:`ship`)."""
    from kneebench import _native as native

    return dict(native.sweep_points(spec, ids))


def ship(client: Any, spec: str | os.PathLike[str]) -> list[str]:
    """Send a sweep's input files to the workers of ``client`` (a ``dask.distributed.Client``)
    for clusters without a shared file system: every worker, present and future, writes them
    at the same absolute paths as on this machine (:class:`kneebench.shipping.ShipFiles`).
    Returns the paths.
    Call it before :func:`sweep`; the paths must be writable on the workers."""
    from .shipping import ShipFiles

    plugin = ShipFiles.from_spec(spec)
    client.register_plugin(plugin, name=ShipFiles.name)
    return sorted(plugin.files)


def sweep(
    spec: str | os.PathLike[str],
    client: Any = None,
    *,
    workers: int | None = None,
    output: str | os.PathLike[str] | None = None,
    resume: bool = False,
    batch_size: int | None = None,
    retries: int = 2,
) -> pd.DataFrame:
    """Run a sweep and return its table: ``point``, one column per parameter, one per metric,
    ``status`` (``ok``/``tripped``/``failed``) and ``message``, sorted by point;
    ``df.attrs["units"]`` maps each column to its unit (the FMUs' unit names, ``""`` for
    none). ``output`` (``.parquet`` or CSV) writes the same table as ``kneebench sweep``.

    Without ``client`` the points run on ``workers`` local threads (default: every core), with
    a journal next to ``output`` for ``resume``. With a ``dask.distributed.Client`` the points
    are sent in batches (``batch_size``, default: about four batches per worker) to the
    cluster's workers; the spec and the FMUs must be at the same absolute paths there (a
    shared file system, or :func:`ship` first). ``retries`` is how many times Dask reruns a
    batch whose task raised an exception (a worker that cannot load an FMU, say); a batch whose
    worker died is rescheduled by the scheduler, up to its
    ``distributed.scheduler.allowed-failures`` setting (default 3), whatever ``retries`` says.
    Points still without a row raise KneebenchError naming them. The table equals the local
    one bit for bit.
    """
    path = os.path.abspath(os.fspath(spec))
    if client is None:
        out = None if output is None else os.fspath(output)
        return _frame(_native.sweep(path, workers, out, resume))
    if resume:
        raise KneebenchError("resume is for local sweeps (a Dask sweep keeps no journal)")
    info = _native.sweep_info(path)
    n = int(info["points"])
    if batch_size is None:
        n_workers = max(1, len(client.scheduler_info().get("workers", {})))
        batch_size = max(1, math.ceil(n / (4 * n_workers)))
    batches = [list(range(i, min(i + batch_size, n))) for i in range(0, n, batch_size)]
    futures = client.map(
        _run_batch, [path] * len(batches), batches, pure=False, retries=retries
    )
    from distributed import wait

    wait(futures)
    parts = []
    missing: list[int] = []
    errors: list[str] = []
    for fut, ids in zip(futures, batches):
        if fut.status != "finished":
            missing.extend(ids)
            try:
                errors.append(repr(fut.exception()))
            except Exception as e:  # noqa: BLE001 - the worker's error, whatever it is
                errors.append(repr(e))
            continue
        d = fut.result()
        if d["fingerprint"] != info["fingerprint"]:
            raise KneebenchError(
                "a worker sees another sweep (the spec, its points or the FMUs' GUIDs differ): "
                f"fingerprint {d['fingerprint']} != {info['fingerprint']}"
            )
        parts.append(d)
    if missing:
        raise KneebenchError(
            f"{len(missing)} points without a row: {missing}; first error: "
            f"{errors[0] if errors else 'unknown'}"
        )
    table = pd.concat([_frame(d) for d in parts], ignore_index=True)
    table = table.sort_values("point", kind="stable").reset_index(drop=True)
    _set_units(table, {**info, "units": info["units"]})
    if output is not None:
        names = list(info["parameters"]) + list(info["metrics"])
        _native.write_sweep_table(
            path,
            os.fspath(output),
            [int(p) for p in table["point"]],
            [np.ascontiguousarray(table[c].to_numpy(dtype="<f8")).tobytes() for c in names],
            [str(s) for s in table["status"]],
            [str(m) for m in table["message"]],
        )
    return table
