"""Shipping a sweep's input files to Dask workers that share no file system with the client
(:func:`kneebench.ship` registers :class:`ShipFiles`). Needs ``distributed``."""

from __future__ import annotations

import os
from collections.abc import Mapping
from typing import Any

from distributed import WorkerPlugin


class ShipFiles(WorkerPlugin):
    """A Dask worker plugin that writes a sweep's input files (the spec, its design CSV, the
    system file or the scenario's FMUs; their bytes travel inside the plugin) on every worker,
    at the same absolute paths as on the client, before the worker runs any task; workers that
    join later get them too. For clusters without a shared file system: see :func:`kneebench.ship`."""

    # A name for the scheduler: registering the plugin again replaces it.
    name = "kneebench-ship-files"

    def __init__(self, files: Mapping[str, bytes]):
        self.files = dict(files)

    @classmethod
    def from_spec(cls, spec: str | os.PathLike[str]) -> ShipFiles:
        """The plugin carrying every file the sweep (or optimisation) ``spec`` reads (read now,
        on the client)."""
        from . import _native

        files = {}
        for f in _native.input_files(os.path.abspath(os.fspath(spec))):
            with open(f, "rb") as fh:
                files[os.fspath(f)] = fh.read()
        return cls(files)

    def setup(self, worker: Any = None) -> None:
        """Write the files where they are missing or differ (atomically: a temporary file in
        the same directory, then a rename)."""
        for path, data in self.files.items():
            try:
                with open(path, "rb") as fh:
                    if fh.read() == data:
                        continue
            except OSError:
                pass
            os.makedirs(os.path.dirname(path), exist_ok=True)
            tmp = f"{path}.{os.getpid()}.partial"
            with open(tmp, "wb") as fh:
                fh.write(data)
            os.replace(tmp, path)
