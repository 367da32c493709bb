"""Runs the stiffness x gear-ratio sweep (sweep.toml) through the kneebench Python package and
prints energy per cycle and knee tracking error against the two parameters; with matplotlib
installed it also draws them (stiffness-sweep.png).

    python examples/stiffness-sweep/analyse.py            # local threads
    python examples/stiffness-sweep/analyse.py tcp://scheduler:8786   # a Dask cluster
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

import kneebench

here = Path(__file__).resolve().parent
client = None
if len(sys.argv) > 1:
    from distributed import Client

    client = Client(sys.argv[1])
table = kneebench.sweep(here / "sweep.toml", client=client)
print(table["status"].value_counts().to_string())
table["knee_error_deg"] = np.degrees(table["rms_error_knee"])
for metric in ["bench_electrical_energy", "knee_error_deg"]:
    pivot = table.pivot(
        index="plant.springStiffness", columns="plant.harmonicDriveRatio", values=metric
    )
    print(f"\n{metric} (rows: spring stiffness [N m/rad], columns: harmonic-drive ratio)")
    print(pivot.round(3).to_string())
try:
    import matplotlib.pyplot as plt
except ImportError:
    sys.exit(0)
fig, axes = plt.subplots(1, 2, figsize=(10, 4))
for ax, metric, label in [
    (axes[0], "bench_electrical_energy", "bench electrical energy per cycle [J]"),
    (axes[1], "knee_error_deg", "RMS knee tracking error [deg]"),
]:
    for ratio, group in table.groupby("plant.harmonicDriveRatio"):
        ax.plot(group["plant.springStiffness"], group[metric], marker="o", label=f"i_HD {ratio:g}")
    ax.set_xlabel("spring stiffness [N m/rad]")
    ax.set_ylabel(label)
    ax.grid(True)
axes[0].legend()
fig.tight_layout()
fig.savefig(here / "stiffness-sweep.png", dpi=120)
print(f"wrote {here / 'stiffness-sweep.png'}")
