"""``drive bench throughput``: closed-loop samples per second of the one-process runner, per estimator."""
import dataclasses
import time

import numpy as np

from .loop import LOG_COLUMNS
from .runner import build_drive
from .scenario import load_scenario

BENCH_SCENARIO = "wang_100rpm"


def throughput(estimator, samples=1_000_000, chunk=50_000, scenario_name=BENCH_SCENARIO):
    """Samples/s of the compiled closed loop (plant + estimator + controller + logging) on one core.

    The loop is compiled and warmed up first; the timed part runs ``samples`` samples in chunks that
    reuse one log buffer, as a long ``drive run`` does between progress reports.
    """
    scenario = load_scenario(scenario_name, estimator_override=estimator)
    scenario = dataclasses.replace(scenario, duration_s=(samples + chunk) * scenario.T_s)
    drive = build_drive(scenario)
    log = np.zeros((chunk, len(LOG_COLUMNS)))
    drive.run(0, chunk, log)
    start = time.perf_counter()
    for k0 in range(chunk, chunk + samples, chunk):
        k1 = min(k0 + chunk, chunk + samples)
        drive.run(k0, k1, log[:k1 - k0])
    wall = time.perf_counter() - start
    return {"estimator": estimator, "scenario": scenario_name, "samples": samples,
            "wall_time_s": wall, "samples_per_second": samples / wall}
