"""``drive bench throughput``: closed-loop samples per second of the one-process runner, per estimator,
and of motulator's signal-injection example when motulator is installed (a side environment is fine).
``drive bench graph``: real-time factor of the lock-step ROS graph."""
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


GRAPH_CONFIGURATIONS = (("composed", "events"), ("composed", "single"), ("separate", "events"))


def graph_throughput(scenario_name=BENCH_SCENARIO, duration_s=0.5, record=False, progress=None):
    """Real-time factor (simulated / wall time) of the lock-step graph per (processes, executor), and
    the wall time per sample and per hop (HOPS_PER_SAMPLE sequential hops close one sample)."""
    from .graph import HOPS_PER_SAMPLE, launch

    results = []
    for processes, executor in GRAPH_CONFIGURATIONS:
        r = launch(scenario_name, duration_s=duration_s, processes=processes, executor=executor,
                   record=record)
        samples = r.scenario.n_samples
        entry = {"processes": processes, "executor": executor, "samples": samples,
                 "wall_time_s": r.wall_time_s, "real_time_factor": r.scenario.duration_s / r.wall_time_s,
                 "us_per_sample": 1e6 * r.wall_time_s / samples,
                 "us_per_hop": 1e6 * r.wall_time_s / samples / HOPS_PER_SAMPLE}
        results.append(entry)
        if progress:
            progress(f"  {processes:9s} {executor:7s} real-time factor {entry['real_time_factor']:.3f} "
                     f"({entry['us_per_sample']:.0f} µs per sample, {entry['us_per_hop']:.0f} µs per hop)")
    return {"benchmark": "graph", "scenario": scenario_name, "duration_s": duration_s, "record": record,
            "sampling_rate_Hz": 1.0 / load_scenario(scenario_name).T_s, "results": results}
