"""Runs the stiffness x gear-ratio sweep (sweep.toml) through the kneebench Python package,
prints energy per cycle and knee tracking error against the two parameters and draws them
(stiffness-sweep.png next to this file).

    python examples/stiffness-sweep/analyse.py                       # local threads
    python examples/stiffness-sweep/analyse.py --dask tcp://scheduler:8786   # a Dask cluster
    python examples/stiffness-sweep/analyse.py --spec other.toml --figure out.png
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # files only: no display needed
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import kneebench  # noqa: E402

here = Path(__file__).resolve().parent
parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
parser.add_argument("--spec", type=Path, default=here / "sweep.toml", help="the sweep spec")
parser.add_argument("--figure", type=Path, default=here / "stiffness-sweep.png")
parser.add_argument("--dask", metavar="ADDRESS", help="a Dask scheduler, e.g. tcp://host:8786")
args = parser.parse_args()

client = None
if args.dask:
    from distributed import Client

    client = Client(args.dask)
table = kneebench.sweep(args.spec, client=client)
print(table["status"].value_counts().to_string())
for _, row in table[table["status"] != "ok"].iterrows():
    print(f"point {row['point']}: {row['status']}: {row['message']}")
table["knee_error_deg"] = np.degrees(table["rms_error_knee"])
for metric in ["bench_electrical_energy", "knee_error_deg"]:
    pivot = table.pivot(
        index="plant.springStiffness", columns="plant.harmonicDriveRatio", values=metric
    )
    print(f"\n{metric} (rows: spring stiffness [N m/rad], columns: harmonic-drive ratio)")
    print(pivot.round(3).to_string())

fig, axes = plt.subplots(1, 2, figsize=(9, 3.4))
for ax, metric, label in [
    (axes[0], "bench_electrical_energy", "bench electrical energy per cycle [J]"),
    (axes[1], "knee_error_deg", "RMS knee tracking error [deg]"),
]:
    for ratio, group in table.groupby("plant.harmonicDriveRatio"):
        ok = group[group["status"] == "ok"]
        ax.plot(ok["plant.springStiffness"], ok[metric], marker="o", ms=3, label=f"i_HD {ratio:g}")
    ax.set_xlabel("spring stiffness [N m/rad]")
    ax.set_ylabel(label)
    ax.grid(True, alpha=0.4)
axes[0].legend(fontsize=8, loc="center right")
fig.suptitle("SEA over the bench gait (tripped runs omitted)", fontsize=10)
fig.tight_layout()
fig.savefig(args.figure, dpi=80)
print(f"wrote {args.figure}")
