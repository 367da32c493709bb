"""fmpy cross-checks of kneebench FMUs (the project's oracle).

    python scripts/fmpy_check.py validate FMU...
        Prints the problems fmpy's validator finds (nothing when the FMU is valid); exit 1 if any.
    python scripts/fmpy_check.py simulate FMU STOP STEP OUT.csv [INPUTS.csv]
        Co-simulates FMU with fmpy on the grid 0, STEP, ..., STOP (output interval = STEP),
        inputs from INPUTS.csv (time column first), and writes every output to OUT.csv with
        round-trip (repr) floats.
    python scripts/fmpy_check.py derivatives FMU [NAME=VALUE...]
        For an FMU declaring maxOutputDerivativeOrder >= 1: after 0.3 s of 1 ms steps (inputs
        NAME=VALUE set first), asks fmi2GetRealOutputDerivatives of order 1 for every Real output
        one by one and compares each answer with the central difference of the output over two
        steps of 1e-6 s around the point (relative 1e-4); prints one line per FMU and every
        refusal or mismatch; exit 1 if any.
"""
import sys

import shutil
import tempfile

import numpy as np
from fmpy import extract, read_model_description, simulate_fmu
from fmpy.fmi2 import FMU2Slave
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


def derivatives(path, *settings):
    md = read_model_description(path)
    order = md.coSimulation.maxOutputDerivativeOrder or 0
    name = md.coSimulation.modelIdentifier
    reals = [v for v in md.modelVariables if v.causality == "output" and v.type == "Real"]
    if order < 1:
        print(f"{name}: maxOutputDerivativeOrder={order}: none promised")
        return 0
    by_name = {v.name: v for v in md.modelVariables}
    unzipdir = extract(path, unzipdir=tempfile.mkdtemp())
    fmu = FMU2Slave(guid=md.guid, unzipDirectory=unzipdir, modelIdentifier=name, instanceName="d")
    bad = []
    try:
        fmu.instantiate()
        fmu.setupExperiment(startTime=0.0)
        fmu.enterInitializationMode()
        fmu.exitInitializationMode()
        for setting in settings:
            key, value = setting.split("=")
            fmu.setReal([by_name[key].valueReference], [float(value)])
        t, h = 0.0, 2e-6
        for _ in range(300):
            fmu.doStep(t, 1e-3)
            t += 1e-3
        vrs = [v.valueReference for v in reals]
        for _attempt in range(50):
            minus = fmu.getReal(vrs)
            fmu.doStep(t, h / 2)
            rates, refused = [], []
            for v in reals:
                try:
                    rates.append(fmu.getRealOutputDerivatives([v.valueReference], [1])[0])
                except Exception as e:  # fmpy raises on a status other than fmi2OK
                    rates.append(None)
                    refused.append(f"{v.name} ({e})")
            fmu.doStep(t + h / 2, h / 2)
            t += h
            plus = fmu.getReal(vrs)
            if refused:
                bad += [f"{name}: order 1 refused for {r}" for r in refused]
                break
            # A piecewise-constant output (an encoder) that stepped inside the interval: move on.
            if any(d == 0.0 and y0 != y1 for d, y0, y1 in zip(rates, minus, plus)):
                fmu.doStep(t, 1e-3)
                t += 1e-3
                continue
            for v, d, y0, y1 in zip(reals, rates, minus, plus):
                fd = (y1 - y0) / h
                floor = 1e3 * np.finfo(float).eps * (1.0 + max(abs(y0), abs(y1))) / h
                if abs(fd - d) > 1e-4 * max(abs(d), abs(fd)) + floor:
                    bad.append(f"{name}: d {v.name}/dt = {d!r}, central difference {fd!r}")
            break
        else:
            bad.append(f"{name}: no interval without an event")
        print(f"{name}: maxOutputDerivativeOrder={order}: {len(reals)} Real outputs, {len(bad)} problems")
        for b in bad:
            print(b)
    finally:
        fmu.terminate()
        fmu.freeInstance()
        shutil.rmtree(unzipdir, ignore_errors=True)
    return 1 if bad else 0


if __name__ == "__main__":
    cmd, args = sys.argv[1], sys.argv[2:]
    if cmd == "validate":
        sys.exit(validate(args))
    elif cmd == "simulate":
        sys.exit(simulate(*args))
    elif cmd == "derivatives":
        sys.exit(derivatives(*args))
    else:
        sys.exit(f"unknown command {cmd}")
