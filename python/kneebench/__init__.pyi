"""Type stubs of the kneebench package (see __init__.py for the documentation)."""

import os
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import Any

import pandas as pd
import pyarrow as pa

__version__: str

class KneebenchError(RuntimeError):
    """An error of the kneebench harness, with the Rust message."""

class SpecError(KneebenchError):
    """A sweep spec refused before anything ran (each problem names its line)."""

def run(
    system: str | os.PathLike[str],
    params: Mapping[str, float | int | bool | str] | None = None,
    variables: Iterable[str] | None = None,
    stop_time: float | None = None,
    step: float | None = None,
    *,
    force: bool = False,
    isolate: str = "auto",
    as_arrow: bool = False,
) -> pd.DataFrame | pa.Table: ...
def study(
    fmus: str | os.PathLike[str],
    out: str | os.PathLike[str],
    actuators: Sequence[str] | None = None,
    cycles: int = 4,
    scale: float = 1.0,
    scenario: str = "bench-full",
) -> pd.DataFrame: ...
def sweep_info(spec: str | os.PathLike[str]) -> dict[str, Any]: ...

def ship(client: Any, spec: str | os.PathLike[str]) -> list[str]: ...
def sweep(
    spec: str | os.PathLike[str],
    client: Any = None,
    *,
    workers: int | None = None,
    output: str | os.PathLike[str] | None = None,
    resume: bool = False,
    batch_size: int | None = None,
    retries: int = 2,
) -> pd.DataFrame: ...
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
) -> pd.DataFrame: ...
