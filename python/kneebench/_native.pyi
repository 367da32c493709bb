"""Type stubs of the Rust extension module (wrapped by kneebench/__init__.py)."""

from typing import Any

__version__: str

class KneebenchError(RuntimeError): ...
class SpecError(KneebenchError): ...

def run(
    system: str,
    params: list[tuple[str, str]],
    variables: list[str],
    stop_time: float | None = None,
    step: float | None = None,
) -> dict[str, Any]: ...
def study(
    fmus: str, out: str, actuators: list[str], cycles: int, scale: float, scenario: str
) -> list[dict[str, Any]]: ...
def sweep(
    spec: str, workers: int | None = None, output: str | None = None, resume: bool = False
) -> dict[str, Any]: ...
def sweep_info(spec: str) -> dict[str, Any]: ...
def sweep_points(spec: str, ids: list[int]) -> dict[str, Any]: ...
def clear_cache() -> None: ...
def write_sweep_table(
    spec: str,
    output: str,
    point: list[int],
    columns: list[bytes],
    status: list[str],
    message: list[str],
) -> None: ...

STUDY_METRIC_UNITS: dict[str, str]
