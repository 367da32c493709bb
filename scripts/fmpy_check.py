"""fmpy cross-checks of kneebench FMUs (the project's oracle).

    python scripts/fmpy_check.py validate FMU...
        Prints the problems fmpy's validator finds (nothing when the FMU is valid); exit 1 if any.
    python scripts/fmpy_check.py simulate FMU STOP STEP OUT.csv [INPUTS.csv]
        Co-simulates FMU with fmpy on the grid 0, STEP, ..., STOP (output interval = STEP),
        inputs from INPUTS.csv (time column first), and writes every output to OUT.csv with
        round-trip (repr) floats.
"""
import sys

import numpy as np
from fmpy import read_model_description, simulate_fmu
from fmpy.validation import validate_fmu


def validate(paths):
    bad = 0
    for path in paths:
        problems = validate_fmu(path)
        for p in problems:
            print(f"{path}: {p}")
        bad += len(problems)
    return 1 if bad else 0


def simulate(path, stop, step, out, inputs=None):
    md = read_model_description(path)
    outputs = [v.name for v in md.modelVariables if v.causality == "output"]
    kwargs = {}
    if inputs:
        data = np.genfromtxt(inputs, delimiter=",", names=True, deletechars="")
        kwargs["input"] = data
    result = simulate_fmu(
        path,
        fmi_type="CoSimulation",
        start_time=0.0,
        stop_time=float(stop),
        step_size=float(step),
        output_interval=float(step),
        output=outputs,
        **kwargs,
    )
    with open(out, "w") as f:
        f.write(",".join(["time"] + outputs) + "\n")
        for row in result:
            f.write(",".join(repr(float(row[n])) for n in ["time"] + outputs) + "\n")
    return 0


if __name__ == "__main__":
    cmd, args = sys.argv[1], sys.argv[2:]
    if cmd == "validate":
        sys.exit(validate(args))
    elif cmd == "simulate":
        sys.exit(simulate(*args))
    else:
        sys.exit(f"unknown command {cmd}")
