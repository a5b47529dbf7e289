"""``drive bench throughput``: closed-loop samples per second of the one-process runner, per estimator,
and of motulator's signal-injection example when motulator is installed (a side environment is fine)."""
import dataclasses
import importlib.util
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from .loop import LOG_COLUMNS
from .runner import build_drive
from .scenario import load_scenario

BENCH_SCENARIO = "wang_100rpm"


def throughput(estimator, samples=1_000_000, chunk=50_000, repeats=3, scenario_name=BENCH_SCENARIO):
    """Samples/s of the compiled closed loop (plant + estimator + controller + logging) on one core.

    The loop is compiled and warmed up first; each of ``repeats`` timed runs continues the same drive for
    ``samples`` samples in chunks that reuse one log buffer, as a long ``drive run`` does between
    progress reports. Reports the best run (as timeit does: the others lost time to the machine) and
    the median.
    """
    scenario = load_scenario(scenario_name, estimator_override=estimator)
    scenario = dataclasses.replace(scenario, duration_s=(repeats * samples + chunk) * scenario.T_s)
    drive = build_drive(scenario)
    log = np.zeros((chunk, len(LOG_COLUMNS)))
    drive.run(0, chunk, log)
    walls = []
    for r in range(repeats):
        first = chunk + r * samples
        start = time.perf_counter()
        for k0 in range(first, first + samples, chunk):
            k1 = min(k0 + chunk, first + samples)
            drive.run(k0, k1, log[:k1 - k0])
        walls.append(time.perf_counter() - start)
    return {"estimator": estimator, "scenario": scenario_name, "samples": samples, "repeats": repeats,
            "wall_time_s": min(walls), "samples_per_second": samples / min(walls),
            "samples_per_second_median": samples / float(np.median(walls))}


MOTULATOR_VENV = Path(__file__).resolve().parents[3] / ".venv-motulator" / "bin" / "python"
"""Where ``./setup.sh --with-motulator`` puts the side environment (motulator needs Python ≥ 3.12)."""


def motulator_python():
    """The interpreter that has motulator: $DRIVE_MOTULATOR_PYTHON, the repository's .venv-motulator,
    or this one; None if none has it."""
    candidates = [os.environ.get("DRIVE_MOTULATOR_PYTHON"), str(MOTULATOR_VENV)]
    for candidate in candidates:
        if candidate and Path(candidate).is_file():
            return candidate
    return sys.executable if importlib.util.find_spec("motulator") else None


def motulator_throughput(python, timeout_s=900.0):
    """Time motulator's 2.2-kW PMSM signal-injection example with ``python`` (drive_bridge.
    motulator_reference); returns its JSON result, or {"error": ...} naming what failed."""
    script = Path(__file__).with_name("motulator_reference.py")
    try:
        proc = subprocess.run([python, str(script)], capture_output=True, text=True, timeout=timeout_s)
    except (OSError, subprocess.TimeoutExpired) as error:
        return {"error": f"{python} {script.name}: {error}"}
    if proc.returncode != 0:
        last = (proc.stderr.strip().splitlines() or ["no output"])[-1]
        return {"error": f"{python} {script.name} exited {proc.returncode}: {last}"}
    return {**json.loads(proc.stdout.strip().splitlines()[-1]), "python": python}
