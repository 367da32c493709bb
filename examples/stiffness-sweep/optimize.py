"""Runs the optimisation of optimize.toml (the spring stiffness and gear ratio spending the
least electrical energy per gait cycle while the knee tracks within 0.6 deg RMS) through the
kneebench Python package, prints the best run and each generation's best, and draws every run
in the parameter plane and the best member's energy per generation (optimize.png next to this
file).

    python examples/stiffness-sweep/optimize.py                       # local threads
    python examples/stiffness-sweep/optimize.py --dask tcp://scheduler:8786   # a Dask cluster
    python examples/stiffness-sweep/optimize.py --spec other.toml --figure out.png
"""

from __future__ import annotations

import argparse
import math
import tomllib
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # files only: no display needed
import matplotlib.pyplot as plt  # noqa: E402

import kneebench  # noqa: E402

here = Path(__file__).resolve().parent
parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
parser.add_argument("--spec", type=Path, default=here / "optimize.toml", help="the spec")
parser.add_argument("--figure", type=Path, default=here / "optimize.png")
parser.add_argument("--dask", metavar="ADDRESS", help="a Dask scheduler, e.g. tcp://host:8786")
args = parser.parse_args()

client = None
if args.dask:
    from distributed import Client

    client = Client(args.dask)
runs = kneebench.optimize(args.spec, client=client)
settings, best = runs.attrs["optimize"], runs.attrs["best"]
objective = settings["objective"]
stiffness, ratio = "plant.springStiffness", "plant.harmonicDriveRatio"
print(
    f"{len(runs)} runs: population {settings['population']}, "
    f"{settings['generations']} generations after the design"
)
for g in runs.attrs["history"]:
    standing = "" if g["violation"] == 0 else f" (violation {g['violation']:g})"
    print(f"generation {g['generation']:2d}: best {objective} = {g['objective']:.4f}"
          f" at point {g['point']}{standing}")
print(f"best: point {best['point']} (generation {best['generation']}), feasible: {best['feasible']}")
for name, value in best["parameters"].items():
    print(f"  {name} = {value:.4f}")
print(f"  {objective} = {best['objective']:.4f} J, rms_error_knee = "
      f"{math.degrees(best['metrics']['rms_error_knee']):.3f} deg")

# Which runs met the spec's [[optimize.constraints]] (here the knee's RMS tracking error), by
# the optimiser's rule, from the table: a run that tripped or failed never does.
feasible = runs["status"] == "ok"
with open(args.spec, "rb") as f:
    for c in tomllib.load(f)["optimize"].get("constraints", []):
        feasible &= runs[c["metric"]].between(c.get("min", -math.inf), c.get("max", math.inf))
fig, axes = plt.subplots(1, 2, figsize=(9, 3.4))
ax = axes[0]
shown = ax.scatter(runs.loc[feasible, stiffness], runs.loc[feasible, ratio],
                   c=runs.loc[feasible, "generation"], cmap="viridis", s=14,
                   label="within the constraints")
ax.scatter(runs.loc[~feasible, stiffness], runs.loc[~feasible, ratio], marker="x",
           c="0.6", s=14, label="outside")
ax.scatter([best["parameters"][stiffness]], [best["parameters"][ratio]], marker="*",
           s=160, c="red", edgecolors="k", label="best")
fig.colorbar(shown, ax=ax, label="generation")
ax.set_xlabel("spring stiffness [N m/rad]")
ax.set_ylabel("harmonic-drive ratio")
ax.legend(fontsize=7, loc="lower left")
ax = axes[1]
history = [g for g in runs.attrs["history"] if g["violation"] == 0]
ax.plot([g["generation"] for g in history], [g["objective"] for g in history], marker="o", ms=3)
ax.set_xlabel("generation")
ax.set_ylabel("best feasible energy per cycle [J]")
ax.grid(True, alpha=0.4)
fig.suptitle("Least energy with the knee within 0.6 deg RMS (differential evolution)",
             fontsize=10)
fig.tight_layout()
fig.savefig(args.figure, dpi=80)
print(f"wrote {args.figure}")
