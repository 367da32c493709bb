"""kneebench from Python: run the bench's FMUs and SSP systems, the DA/SEA/CSEA study,
parameter sweeps and optimisations, locally or on a Dask cluster, with the results as pandas
DataFrames.

The simulations run in Rust (the kneebench harness) with the GIL released; errors are raised
as :class:`KneebenchError` (:class:`SpecError` for a refused sweep spec) carrying the Rust
message.
"""

from __future__ import annotations

import atexit
import math
import numbers
import os
import sysconfig
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

from . import _native
from ._native import KneebenchError, SpecError

if TYPE_CHECKING:
    import pyarrow as pa

__all__ = [
    "KneebenchError",
    "SpecError",
    "optimize",
    "run",
    "ship",
    "study",
    "sweep",
    "sweep_info",
    "__version__",
]
__version__: str = _native.__version__

# The FMU host executable the wheel ships next to the native module (`scripts/test.sh` copies
# it in before maturin builds the wheel).
_FMU_HOST = os.path.join(os.path.dirname(os.path.abspath(__file__)), "kneebench-fmu-host")


def _fmu_host() -> str | None:
    """The host of isolated FMUs: the shipped one, unless ``KNEEBENCH_FMU_HOST`` names another
    (``None`` lets the harness find it, and name where it looked when it cannot)."""
    if os.environ.get("KNEEBENCH_FMU_HOST") or not os.path.isfile(_FMU_HOST):
        return None
    return _FMU_HOST


def _libpython() -> list[str]:
    """This interpreter's shared libpython, if it has one: preloaded by the host of an
    isolated FMU, whose PythonFMU binary leaves every ``Py*`` symbol to its host."""
    if not sysconfig.get_config_var("Py_ENABLE_SHARED"):
        return []
    lib = os.path.join(
        sysconfig.get_config_var("LIBDIR") or "", sysconfig.get_config_var("LDLIBRARY") or ""
    )
    return [lib] if os.path.isfile(lib) else []
# The sweep a Dask worker keeps prepared between batches holds a scenario and extracted FMUs
# in temporary directories: removed when the interpreter exits.
atexit.register(_native.clear_cache)


def _text(value: Any) -> str:
    """A parameter value as the text the harness reads (``kneebench run --param`` reads the
    same): a bool (``numpy.bool_`` too) as ``true``/``false``; an integer (any
    ``numbers.Integral``: ``int``, ``numpy.int64``) in decimal; any other real number
    (``numbers.Real``: ``float``, ``numpy.float64``, ``numpy.float32``, ``Fraction``) as the
    shortest text of its value as a float, a whole number without a fraction (``1.0`` ->
    ``1``, which an Integer or Enumeration variable takes and a Real reads as the same value;
    ``1.5`` stays ``1.5``, which an Integer refuses); anything else (a ``str``) as ``str()``
    gives it."""
    if isinstance(value, (bool, np.bool_)):
        return "true" if value else "false"
    if isinstance(value, numbers.Integral):
        return str(int(value))
    if isinstance(value, numbers.Real):
        x = float(value)
        # Below 2**53 every whole float is an exact int; "-0" keeps the sign of -0.0 for a Real.
        if x.is_integer() and abs(x) < 2**53:
            return str(int(x)) if math.copysign(1.0, x) > 0 else f"-{int(-x)}"
        return repr(x)
    return str(value)


def _pyarrow() -> Any:
    """The ``pyarrow`` module, or an ImportError saying what needs it."""
    try:
        import pyarrow
    except ImportError as e:
        raise ImportError(
            "as_arrow=True needs pyarrow: pip install pyarrow (or kneebench[arrow])"
        ) from e
    return pyarrow


def _columns(names: Sequence[str], columns: Sequence[bytes]) -> dict[str, np.ndarray]:
    return {n: np.frombuffer(c, dtype="<f8").copy() for n, c in zip(names, columns)}


def _names(what: str, names: Iterable[str] | None) -> list[str] | None:
    """``names`` as a list (``None`` stays ``None``): a single ``str`` is refused (a list of
    names is needed, ``["x"]``, not ``"x"``), and so is an empty list."""
    if names is None:
        return None
    if isinstance(names, (str, bytes)):
        raise TypeError(f"{what} must be a list of names, not a str: [{names!r}]")
    out = list(names)
    for n in out:
        if not isinstance(n, str):
            raise TypeError(f"{what}: a name must be a str, not {type(n).__name__}: {n!r}")
    if not out:
        raise ValueError(f"{what} is empty: leave it out (None) for the default")
    return out


def _seconds(what: str, value: float | None) -> float | None:
    """``value`` as a ``float`` (any ``numbers.Real``, numpy's too; ``None`` passes): a bool or
    another type raises TypeError naming ``what`` (``True`` ran as 1 s)."""
    if value is None:
        return None
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
        raise TypeError(f"{what} must be a real number, not {type(value).__name__}")
    return float(value)


def _at_least_one(what: str, value: int | None) -> int | None:
    """``value`` as an ``int`` (any ``numbers.Integral``, a ``numpy.int64`` too; ``None`` passes):
    another type raises TypeError, a value below 1 ValueError, each naming ``what``."""
    if value is None:
        return None
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Integral):
        raise TypeError(f"{what} must be an int, not {type(value).__name__}")
    if value < 1:
        raise ValueError(f"{what} must be >= 1 (given: {value})")
    return int(value)


def _workers(workers: int | None) -> int | None:
    """Refuses ``workers`` below 1 (as :func:`_at_least_one`) and above the harness's bound
    (``_native.MAX_WORKERS``, 1024: each is a thread loading its own copy of the system), both
    with a ValueError (a bad argument, as every other), before anything runs."""
    workers = _at_least_one("workers", workers)
    if workers is not None and workers > _native.MAX_WORKERS:
        raise ValueError(
            f"{workers} worker threads: a sweep or an optimisation runs on 1 to "
            f"{_native.MAX_WORKERS}"
        )
    return workers


# The most times a batch whose task raised is run again on a cluster: each retry reruns the whole
# batch, and a batch that failed this often fails for good (its worker cannot load an FMU, say).
_MAX_RETRIES = 100


def _retries(retries: int) -> int:
    """``retries`` as an ``int`` (any ``numbers.Integral``), from 0 to ``_MAX_RETRIES``:
    another type raises TypeError, a value outside the range ValueError, before anything
    runs (with or without a client). Dask took any value: a negative one, a float or a str
    failed (or not) only once the batches were sent."""
    if isinstance(retries, (bool, np.bool_)) or not isinstance(retries, numbers.Integral):
        raise TypeError(f"retries must be an int, not {type(retries).__name__}")
    if not 0 <= retries <= _MAX_RETRIES:
        raise ValueError(f"retries must be 0 to {_MAX_RETRIES} (given: {retries})")
    return int(retries)


def _cluster_arguments(client: Any, workers: int | None, batch_size: int | None) -> None:
    """Refuses what a sweep or an optimisation would silently ignore: ``workers`` (local
    threads) with a ``client``, ``batch_size`` (batches sent to a cluster) without one (both
    ValueError), and a ``client`` that is not a ``dask.distributed.Client`` (TypeError: an
    address string is refused, connect with ``Client(address)`` first)."""
    if client is None:
        if batch_size is not None:
            raise ValueError(
                "batch_size is for a Dask client's batches: a local run (client=None) has none"
            )
        return
    if workers is not None:
        raise ValueError(
            "workers is for a local run (client=None): on a Dask cluster its own workers "
            "run the points (leave workers out)"
        )
    try:
        from distributed import Client
    except ImportError:
        Client = None
    if Client is None or not isinstance(client, Client):
        hint = (
            f" (connect first: client=distributed.Client({client!r}))"
            if isinstance(client, str)
            else ""
        )
        raise TypeError(
            f"client must be a dask.distributed.Client (or None for local threads), not "
            f"{type(client).__name__}{hint}"
        )


def run(
    system: str | os.PathLike[str],
    params: Mapping[str, Any] | None = None,
    variables: Iterable[str] | None = None,
    stop_time: float | None = None,
    step: float | None = None,
    *,
    force: bool = False,
    isolate: str = "auto",
    as_arrow: bool = False,
) -> pd.DataFrame | pa.Table:
    """Run an FMU (``.fmu``) or an SSP system (``.ssp``/``.ssd``) and return its results.

    ``params`` (a mapping, name to value) sets parameters or start values before
    initialisation (``variable`` for an FMU, ``component.variable`` for a system). A value
    is a number, a bool or a str (an item's name for an Enumeration); numpy scalars are
    numbers too (``numpy.float64``, ``numpy.int64``, ``numpy.bool_``), and a whole-number
    float is taken by an Integer or Enumeration variable (``1.0``, as a sweep table's Integer
    column holds it; ``1.5`` raises KneebenchError). A String variable takes a ``str`` only:
    a number or a bool for one raises KneebenchError (``1.0`` was set as the text ``"1"``).
    ``variables`` (a list of names; a single ``str``, an empty list or a name given twice
    raises) chooses the recorded columns
    (default, ``None``: every output). ``stop_time`` and ``step`` (real numbers: a bool raises
    TypeError) default to the FMU's or the
    system's DefaultExperiment (an FMU's tolerance is passed to ``fmi2SetupExperiment``, as
    ``kneebench run`` does). The DataFrame has a ``time`` column [s] and one float64
    column per signal; ``df.attrs["units"]`` maps each column to its unit (``""`` when it has
    none), ``df.attrs["status"]`` is ``"completed"`` or ``"terminated"`` (an FMU ended the
    run, e.g. an interlock; ``df.attrs["message"]`` says why). With ``as_arrow=True`` the
    same columns come as a ``pyarrow.Table`` (pyarrow needed: ``pip install pyarrow``) whose
    fields carry their unit as metadata (``table.field(name).metadata[b"unit"]``) and whose
    schema metadata holds ``kneebench.status`` and ``kneebench.message``. A failed run
    raises KneebenchError, and so does an FMU with a problem ``kneebench validate`` reports (a
    variable name that is not unique, say) unless ``force=True`` (``kneebench run --force``).
    Ctrl-C (SIGINT) stops the run at its next communication point and raises
    KeyboardInterrupt.

    ``isolate`` is where the FMUs' binaries run, as ``kneebench run --isolate``: ``"auto"``
    (the default) runs an FMU that kneebench did not generate (a PythonFMU export, another
    tool's) in a host process of its own, so that its crash, ``exit()`` or hang is a
    KneebenchError naming it instead of the end of this interpreter; ``"always"`` isolates
    kneebench's own FMUs too, ``"never"`` runs every FMU in this process (faster per step;
    a PythonFMU export then runs on this interpreter and its threads). The host is the
    ``kneebench-fmu-host`` shipped next to this package (``KNEEBENCH_FMU_HOST`` names another);
    an isolated host preloads this interpreter's shared libpython, which a PythonFMU export
    needs (its slave's third-party imports need ``PYTHONPATH`` in the host's environment).
    """
    if isolate not in _native.ISOLATE_NAMES:
        *rest, last = (f"'{n}'" for n in _native.ISOLATE_NAMES)
        raise ValueError(f"isolate must be {', '.join(rest)} or {last}, not {isolate!r}")
    if params is not None and not isinstance(params, Mapping):
        raise TypeError(
            f"params must be a mapping of names to values (a dict), not {type(params).__name__}"
        )
    for k in params or {}:
        if not isinstance(k, str):
            raise TypeError(f"params: a name must be a str, not {type(k).__name__}: {k!r}")
    stop_time = _seconds("stop_time", stop_time)
    step = _seconds("step", step)
    names = _names("variables", variables)
    if names is not None:
        twice = sorted({n for n in names if names.count(n) > 1})
        if twice:
            raise ValueError(f"variables names {', '.join(map(repr, twice))} more than once")
    if as_arrow:
        pa = _pyarrow()
    # Each value's text, and whether it was a number or a bool (a String variable refuses one:
    # 1.0 would be set as the text "1").
    p = [
        (k, _text(v), isinstance(v, (bool, np.bool_, numbers.Real)))
        for k, v in (params or {}).items()
    ]
    r = _native.run(
        os.fspath(system),
        p,
        names or [],
        stop_time,
        step,
        bool(force),
        isolate,
        _fmu_host(),
        _libpython(),
    )
    # ``values`` holds one row per column (time first) in the buffer the run filled: each row
    # is a column of the table, and the transpose is the frame's one block of floats, both
    # taken without a copy.
    if as_arrow:
        fields = [
            pa.field(n, pa.float64(), metadata={"unit": u})
            for n, u in zip(r["names"], r["units"])
        ]
        meta = {"kneebench.status": r["status"], "kneebench.message": r["message"]}
        arrays = [pa.array(column) for column in r["values"]]
        return pa.Table.from_arrays(arrays, schema=pa.schema(fields, metadata=meta))
    df = pd.DataFrame(r["values"].T, columns=r["names"], copy=False)
    df.attrs["units"] = dict(zip(r["names"], r["units"]))
    df.attrs["status"] = r["status"]
    df.attrs["message"] = r["message"]
    return df


def study(
    fmus: str | os.PathLike[str],
    out: str | os.PathLike[str],
    actuators: Sequence[str] | None = None,
    cycles: int = 4,
    scale: float = 1.0,
    scenario: str = "bench-full",
) -> pd.DataFrame:
    """Run the gait study (the bench's gait on each actuator, FMUs from ``fmus``; scenarios
    and CSV results written under ``out``) and return one row per actuator: ``status``
    (``ok``; ``tripped``: an interlock ended the run, ``trip`` names it and ``trip_time`` [s]
    says when; ``failed``: the run failed, ``message`` says why, its metrics are those of the
    rows before the failure and ``trip`` is ``None``), ``message``, tracking errors [rad], peak
    torques [N m], energy terms per gait cycle [J] (the columns of a sweep's study metrics).
    ``scenario`` is ``bench-full`` (the 60 deg gait, DA/SEA/CSEA) or ``bench-clutch`` (50 deg,
    SEA/CSEA under impedance control: it has no DA). ``actuators`` is a list of the
    scenario's actuators (default, ``None``: all of the scenario's; a single ``str``, an
    empty list, an actuator the scenario lacks or one named twice, however spelled, raises).
    ``cycles`` is the gait cycles per run, at least 2: the first, the start-up (the gait fades
    in), is not analysed, the metrics are per cycle over the others. ``df.attrs["units"]``
    maps each column to its unit (``1`` for a count or a fraction). Ctrl-C (SIGINT) stops the
    running run at its next communication point and raises KeyboardInterrupt."""
    # None: the scenario's own actuators (the harness knows them).
    names = _names("actuators", actuators)
    if names is not None:
        folded = [n.casefold() for n in names]
        twice = [n for k, n in enumerate(names) if n.casefold() in folded[:k]]
        if twice:
            raise ValueError(f"actuators names {twice[0]!r} more than once (each runs once)")
    cycles = _at_least_one("cycles", cycles)
    if cycles is not None and cycles < 2:
        raise ValueError(
            f"cycles must be >= 2 (given: {cycles}): the first gait cycle, the start-up, is not "
            "analysed"
        )
    if isinstance(scale, (bool, np.bool_)) or not isinstance(scale, numbers.Real):
        raise TypeError(f"scale must be a real number, not {type(scale).__name__}")
    reports = _native.study(
        os.fspath(fmus), os.fspath(out), names, cycles, float(scale), scenario
    )
    df = pd.DataFrame(reports).set_index("actuator")
    df.attrs["units"] = {**_native.STUDY_METRIC_UNITS, "trip": "", "status": "", "message": ""}
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
    """Check a sweep spec against its system (raises SpecError naming each bad line, or for a
    spec with ``[optimize]``: see :func:`optimize`) and return ``{"points", "parameters",
    "metrics", "units", "fingerprint", "files"}`` (``files``: the absolute paths the sweep
    reads: the spec, its design CSV, the system file or the scenario's FMUs)."""
    return dict(_native.sweep_info(os.path.abspath(os.fspath(spec))))


def _run_batch(spec: str, ids: list[int]) -> dict[str, Any]:
    """One batch of a distributed sweep, run on a Dask worker (needs the wheel, and the spec
    and the FMUs at the same absolute paths as on the client: a shared path or :func:`ship`)."""
    from kneebench import _native as native

    return dict(native.sweep_points(spec, ids))


def _run_optimize_batch(spec: str, points: list[tuple[int, list[float]]]) -> dict[str, Any]:
    """One batch of a generation of a distributed optimisation, run on a Dask worker (the
    points' ids and parameter values; the same needs as :func:`_run_batch`)."""
    from kneebench import _native as native

    return dict(native.optimize_points(spec, points))


def _default_batch_size(client: Any, n: int) -> int:
    """About four batches of ``n`` points per worker of ``client``."""
    n_workers = max(1, len(client.scheduler_info().get("workers", {})))
    return max(1, math.ceil(n / (4 * n_workers)))


def _run_on_cluster(
    client: Any,
    task: Callable[[str, Any], dict[str, Any]],
    spec: str,
    batches: Sequence[Any],
    ids: Sequence[Sequence[int]],
    fingerprint: str,
    retries: int,
    on_part: Callable[[dict[str, Any]], None] | None = None,
) -> list[dict[str, Any]]:
    """Runs ``task(spec, batch)`` for every batch on the workers of ``client`` and returns
    their rows dicts (in batch order), each checked against ``fingerprint`` and handed to
    ``on_part`` as it comes back (a journal). ``ids`` are the batches' point ids: those of
    batches that never came back (their worker died more often than the scheduler allows, or
    their task raised ``retries + 1`` times) are named in the KneebenchError raised."""
    from distributed import as_completed

    futures = client.map(task, [spec] * len(batches), batches, pure=False, retries=retries)
    index = {f.key: k for k, f in enumerate(futures)}
    parts: list[dict[str, Any] | None] = [None] * len(futures)
    missing: list[int] = []
    errors: list[str] = []
    for fut in as_completed(futures):
        k = index[fut.key]
        if fut.status != "finished":
            missing.extend(ids[k])
            try:
                errors.append(repr(fut.exception()))
            except Exception as e:  # noqa: BLE001 - the worker's error, whatever it is
                errors.append(repr(e))
            continue
        d = fut.result()
        if d["fingerprint"] != fingerprint:
            raise KneebenchError(
                "a worker sees another sweep (the spec, its points, the FMUs' GUIDs or the system's "
                "files differ): "
                f"fingerprint {d['fingerprint']} != {fingerprint}"
            )
        if on_part is not None:
            on_part(d)
        parts[k] = d
    if missing:
        raise KneebenchError(
            f"{len(missing)} points without a row: {sorted(missing)}; first error: "
            f"{errors[0] if errors else 'unknown'}"
        )
    return [d for d in parts if d is not None]


def ship(client: Any, spec: str | os.PathLike[str]) -> list[str]:
    """Send a sweep's (or an optimisation's) input files to the workers of ``client`` (a
    ``dask.distributed.Client``) for clusters without a shared file system: every worker,
    present and future, writes them at the same absolute paths as on this machine
    (:class:`kneebench.shipping.ShipFiles`). Returns the paths. Another ``client`` (``None``,
    an address string) raises TypeError.
    Call it before :func:`sweep` or :func:`optimize`; the paths must be writable on the
    workers."""
    from .shipping import ShipFiles

    if client is None:
        raise TypeError("ship needs a dask.distributed.Client, not None")
    _cluster_arguments(client, None, None)
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

    Without ``client`` the points run on ``workers`` local threads (default: every core). With
    a ``dask.distributed.Client`` the points
    are sent in batches (``batch_size``, default: about four batches per worker) to the
    cluster's workers; the spec and the FMUs must be at the same absolute paths there (a
    shared file system, or :func:`ship` first). ``retries`` is how many times Dask reruns a
    batch whose task raised an exception (a worker that cannot load an FMU, say), an int from 0
    to 100 (another type raises TypeError, another value ValueError, with or without a
    client); a batch whose worker died is rescheduled by the scheduler, up to its
    ``distributed.scheduler.allowed-failures`` setting (default 3), whatever ``retries`` says.
    Points still without a row raise KneebenchError naming them. The table equals the local
    one bit for bit. A spec with an ``[optimize]`` table raises SpecError: run it with
    :func:`optimize`.

    Either way, with ``output`` every finished row is journaled next to it (on Dask, as each
    batch comes back), so that an interrupted sweep (a killed client, Ctrl-C, points without a
    row) continues with ``resume=True`` running only the points the journal lacks (and a
    finished Parquet ``output`` of the same sweep runs nothing); ``resume`` needs ``output``.
    One sweep at a time writes to an ``output``: while another (a ``kneebench sweep``, or a
    sweep of this or another interpreter) holds its journal, this one raises KneebenchError
    ("another sweep is running into this output") before running anything; the journal's lock
    goes with that sweep's end, a killed process's included. Locally, Ctrl-C (SIGINT) stops the running points at their next communication point and
    raises KeyboardInterrupt, the journal keeping the rows finished before it. ``workers`` and
    ``batch_size`` must be at least 1 and ``workers`` at most 1024 (ValueError); ``workers``
    is for a local run and ``batch_size`` for a cluster's: either with the other raises
    ValueError, and a ``client`` that is not a ``dask.distributed.Client`` (an address
    string, say: connect with ``Client(address)`` first) TypeError.
    """
    workers = _workers(workers)
    batch_size = _at_least_one("batch_size", batch_size)
    retries = _retries(retries)
    path = os.path.abspath(os.fspath(spec))
    out = None if output is None else os.fspath(output)
    if resume and out is None:
        raise KneebenchError("resume needs output: the journal is next to it")
    _cluster_arguments(client, workers, batch_size)
    if client is None:
        return _frame(_native.sweep(path, workers, out, resume))
    info = _native.sweep_info(path)
    journal = None if out is None else _native.SweepJournal(path, out, resume)
    try:
        todo = list(range(int(info["points"]))) if journal is None else journal.pending()
        if batch_size is None:
            batch_size = _default_batch_size(client, len(todo))
        batches = [todo[i : i + batch_size] for i in range(0, len(todo), batch_size)]
        parts = _run_on_cluster(
            client,
            _run_batch,
            path,
            batches,
            batches,
            info["fingerprint"],
            retries,
            None if journal is None else journal.record,
        )
        if journal is not None:
            table = _frame(journal.finish())
    finally:
        # The journal's lock goes now, not when a traceback holding this frame is dropped.
        if journal is not None:
            journal.close()
    if journal is None:
        table = pd.concat([_frame(d) for d in parts], ignore_index=True)
        table = table.sort_values("point", kind="stable").reset_index(drop=True)
    _set_units(table, {**info, "units": info["units"]})
    return table


def _history_entry(g: Sequence[Any]) -> dict[str, Any]:
    """A generation's best member, ``(generation, point, objective, violation)``, as a dict."""
    generation, point, objective, violation = g
    return {
        "generation": int(generation),
        "point": int(point),
        "objective": float(objective),
        "violation": float(violation),
    }


def _optimization_frame(d: Mapping[str, Any]) -> pd.DataFrame:
    """The DataFrame of a finished optimisation (the dict of ``_native.optimize`` or
    ``_native.Optimizer.finish``)."""
    df = _frame(d)
    population = int(d["population"])
    df.insert(1, "generation", df["point"] // population)
    units = df.attrs["units"]
    units["generation"] = ""
    df.attrs["units"] = {c: units.get(c, "") for c in df.columns}
    point = int(d["best_point"])
    (at,) = np.flatnonzero(df["point"].to_numpy() == point)
    row = df.iloc[int(at)]
    violation = float(d["violation"])
    df.attrs["optimize"] = {
        "objective": d["objective"],
        "direction": d["direction"],
        "population": population,
        "generations": int(d["generations"]),
    }
    df.attrs["best"] = {
        "point": point,
        "generation": point // population,
        "parameters": {n: float(row[n]) for n in d["parameters"]},
        "metrics": {n: float(row[n]) for n in d["metrics"]},
        "objective": float(row[d["objective"]]),
        "violation": violation,
        "feasible": violation == 0.0,
        "status": str(row["status"]),
        "message": str(row["message"]),
    }
    df.attrs["history"] = [_history_entry(g) for g in d["history"]]
    return df


def optimize(
    spec: str | os.PathLike[str],
    client: Any = None,
    *,
    workers: int | None = None,
    output: str | os.PathLike[str] | None = None,
    resume: bool = False,
    batch_size: int | None = None,
    retries: int = 2,
    on_generation: Callable[[dict[str, Any]], None] | None = None,
) -> pd.DataFrame:
    """Run an optimisation (a sweep spec with an ``[optimize]`` table: differential evolution
    over its parameters, the design as the first generation; see ``kneebench optimize``) and
    return every run, sorted by point: the columns of :func:`sweep`'s frame with
    ``generation`` (``point // population``) after ``point``. A spec without ``[optimize]``
    raises SpecError.

    ``df.attrs`` holds ``units`` (as :func:`sweep`), ``optimize`` (``objective``,
    ``direction``, ``population``, ``generations``), ``best``: the best run (Deb's rules: a
    run within every constraint beats one outside, and a tripped or failed run never wins)
    as ``{"point", "generation", "parameters": {name: value}, "metrics": {name: value},
    "objective": its objective's value, "violation": how far outside the constraints (0
    within, infinite for a tripped or failed run), "feasible": violation == 0, "status",
    "message"}``, and ``history``: the best member after each generation, a list of
    ``{"generation", "point", "objective", "violation"}``. ``on_generation`` is called with
    each of these as its generation ends; an exception it raises stops the optimisation and
    is raised (locally, the journal is kept for ``resume``).

    Without ``client`` the generations run on ``workers`` local threads (default: every
    core); ``output`` (``.parquet`` or CSV) is written as ``kneebench optimize`` writes it,
    with a journal next to it for ``resume``; ``resume`` without a journal continues the
    finished Parquet ``output`` of the same spec given more ``generations`` (only the new
    generations run). With a ``dask.distributed.Client`` each
    generation's points are sent in batches (``batch_size``, default: about four batches per
    worker) to the workers, as :func:`sweep` sends a sweep's (``retries``, the spec and the
    FMUs at the same absolute paths or :func:`ship`), and its rows gathered before the next
    generation is made. With ``output`` each batch's rows are journaled as they come back,
    so that ``resume`` works as locally (an interrupted run, a killed client, a finished
    table given more generations); ``on_generation`` then also sees the generations replayed
    from the journal. ``resume`` needs ``output``. The frame and the table written are the
    same, bit for bit, whether run locally or on Dask. As for :func:`sweep`, an ``output``
    that another sweep or optimisation is writing to raises KneebenchError before anything
    runs. Locally, Ctrl-C (SIGINT) stops the
    running points at their next communication point and raises KeyboardInterrupt, the
    journal kept for ``resume``. ``workers`` and ``batch_size`` must be at least 1 and
    ``workers`` at most 1024 (ValueError), ``retries`` 0 to 100 (as for :func:`sweep`),
    ``workers`` is for a local run and ``batch_size`` for a cluster's (either with the other:
    ValueError), ``client`` a
    ``dask.distributed.Client`` and ``on_generation`` callable (TypeError), all checked
    before anything runs.
    """
    workers = _workers(workers)
    batch_size = _at_least_one("batch_size", batch_size)
    retries = _retries(retries)
    if on_generation is not None and not callable(on_generation):
        raise TypeError(
            f"on_generation must be callable (or None), not {type(on_generation).__name__}"
        )
    path = os.path.abspath(os.fspath(spec))
    out = None if output is None else os.fspath(output)
    if resume and out is None:
        raise KneebenchError("resume needs output: the journal is next to it")
    _cluster_arguments(client, workers, batch_size)
    if client is None:
        report = None
        if on_generation is not None:

            def report(*g: Any) -> None:
                on_generation(_history_entry(g))

        return _optimization_frame(_native.optimize(path, workers, out, resume, report))
    optimizer = _native.Optimizer(path, out, resume)
    fingerprint = optimizer.info["fingerprint"]
    reported = 0

    def report_told() -> None:
        # Every generation told since the last call: replayed from the journal, or just run.
        nonlocal reported
        history = optimizer.history
        if on_generation is not None:
            for g in history[reported:]:
                on_generation(_history_entry(g))
        reported = len(history)

    try:
        while points := optimizer.ask():
            report_told()
            size = (
                batch_size if batch_size is not None else _default_batch_size(client, len(points))
            )
            batches = [points[i : i + size] for i in range(0, len(points), size)]
            ids = [[int(p[0]) for p in b] for b in batches]
            _run_on_cluster(
                client,
                _run_optimize_batch,
                path,
                batches,
                ids,
                fingerprint,
                retries,
                optimizer.tell,
            )
        report_told()
        return _optimization_frame(optimizer.finish())
    finally:
        # The journal's lock goes now, not when a traceback holding this frame is dropped.
        optimizer.close()
