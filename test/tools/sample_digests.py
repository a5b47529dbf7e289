"""Digests of the samples the drive computes, to check that a change of the code's shape changes no sample:
every shipped scenario × every estimator in one process (shortened), a few in the ROS graph (composed) and
through the bridge (pty, lock-step). Run before and after a change on the same machine and compare:
``python test/tools/sample_digests.py > before.json`` … ``diff before.json after.json``."""
import dataclasses
import hashlib
import json
import os
import sys

import numpy as np

DURATION_S = float(os.environ.get("DIGEST_DURATION_S", "0.3"))


def digest(log):
    return hashlib.sha256(np.ascontiguousarray(log, dtype=np.float64).tobytes()).hexdigest()[:16]


def graph_log(launch, name):
    """The log of ``name`` run DURATION_S in the composed graph: launch takes one drive's record (DriveSpec)
    since the launcher has GraphOptions, its keywords before (at bcad1f6 and earlier)."""
    launcher = sys.modules[launch.__module__]
    if hasattr(launcher, "GraphOptions"):
        return launch(launcher.DriveSpec(name, duration_s=DURATION_S)).log
    return launch(name, duration_s=DURATION_S).log


def main():
    try:
        from drive_common.config.scenario import load_scenario, scenario_names
        from drive_tools.launch.launcher import launch
        from drive_tools.runner.bridge_loop import run_through_bridge
        from drive_tools.runner.runner import run_scenario
    except ImportError:  # the code before the six packages (at 94c82e6 and earlier)
        from drive_launch.launcher import launch
        from drive_runner.bridge_loop import run_through_bridge
        from drive_runner.runner import run_scenario
        from drive_scenarios.scenario import load_scenario, scenario_names
    from hf_estimator.interface import estimator_names

    out = {}
    for name in scenario_names():
        base = load_scenario(name)
        for estimator in estimator_names():
            scenario = dataclasses.replace(base, estimator=estimator, duration_s=min(base.duration_s, DURATION_S))
            try:
                out[f"run {name} {estimator}"] = digest(run_scenario(scenario).log)
            except Exception as error:  # a refused combination is a result too
                out[f"run {name} {estimator}"] = f"refused: {type(error).__name__}"
            print(f"run {name} {estimator}", file=sys.stderr)
    for name in ("wang_100rpm", "szabo_profile"):
        scenario = dataclasses.replace(load_scenario(name), duration_s=DURATION_S)
        out[f"bridge {name}"] = digest(run_through_bridge(scenario, "pty").log)
    if os.environ.get("DIGEST_GRAPH", "1") == "1":
        for name in ("wang_100rpm", "szabo_profile"):
            out[f"graph {name}"] = digest(graph_log(launch, name))
    json.dump(out, sys.stdout, indent=1, sort_keys=True)
    print()


if __name__ == "__main__":
    main()
