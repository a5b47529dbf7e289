"""How well a sensorless joint knows its position (issue 54): a motor's shaft behind a simulated end stop is homed
against it (foc_controller.position: the stop found by current), then moved back and forth by the position loop,
a constant load (gravity) on for the second half; the estimated joint position θ̂_m − θ_zero is compared with the
plant's truth θ_m − (θ_stop + offset) at every sample. The drive knows the nameplate and its commissioning, never
the stop's angle. ``python -m drive_tools.evaluation.position_drift --random N --seed S`` prints the table of
docs/robot.md ("Position").
"""
import argparse
import json
import math
import re
import sys
import tempfile
from pathlib import Path
from typing import NamedTuple

import numpy as np

from drive_common.config.motor_experiments import ExperimentOptions, experiment_document
from drive_common.config.scenario import parse_scenario
from drive_common.contract.estimator_states import HOLD, TRACKING
from drive_common.contract.log import COLUMN, LOG_COLUMNS
from drive_common.motor.motor_file import load_motor
from foc_controller.command_hold import HOLD_GAIN_PER_SPEED_ZERO
from foc_controller.position import FAILED, HARD_STOP, Homing, HomingSettings, position_speed, search_acceleration

from ..runner.runner import build_drive

PEAK_ERROR_E_RAD = 0.15
"""The drive's peak electrical angle error target (motor_bench.PEAK_TARGET_RAD): a homed position is good to this
over n_p at each instant, so its drift between two instants to twice that."""


class DriftOptions(NamedTuple):
    """The run: the search at ``search_per_rated`` of rated speed, the stop found at ``stop_current_per_rated`` of
    rated current, the joint's zero ``offset_rad`` inward from the stop, the back-off, the stop's distance from the
    start ``stop_from_start_rad``, the moves (joint positions [rad], inward positive), the load (share of rated
    torque, on from half the run), the sampling period [s] and how many samples the position loop's (and homing's)
    speed reference holds (as a node's block)."""

    search_per_rated: float = 0.03
    stop_current_per_rated: float = 0.3
    offset_rad: float = 1.0
    backoff_rad: float = 0.5
    stop_from_start_rad: float = 1.0
    moves_rad: tuple = (1.0, -0.5, 2.0, 0.0, 1.0)
    load_per_rated: float = 0.2
    T_s: float = 1e-4
    loop_samples: int = 10


def drift_scenario(motor, commissioning, direction, options, duration_s):
    """The Scenario of the run: the motor at rest, its end stop ``stop_from_start_rad`` from the start in
    ``direction`` (±1), the load on from half the run."""
    document = experiment_document("standstill_hold", motor, ExperimentOptions(options.T_s,
                                                                               commissioning=str(commissioning)))
    theta_0 = document["initial"]["theta_m_rad"]
    side = "high_rad" if direction > 0 else "low_rad"
    document.update(duration_s=duration_s,
                    speed={"unit": "rad_s", "points": [[0.0, 0.0]]},
                    load={"unit": "rated", "points": [[0.0, 0.0], [0.5 * duration_s, direction
                                                                    * options.load_per_rated]]},
                    end_stop={side: theta_0 + direction * options.stop_from_start_rad})
    return parse_scenario(document, motor.name, f"position drift on {motor.name}", None, "", motor.source, "motor")


def drift_run(motor_ref, commissioning, direction=1.0, options=None):
    """Home and move ``motor_ref`` (its commissioning file ``commissioning``) against a stop in ``direction``; a row:
    n_p, when it homed [s], the homing error, the drift (end − homed) and the peak deviation during the moves of the
    joint position's error against the truth [rad, mechanical], and ``failed`` (why, or empty)."""
    options = options or DriftOptions()
    motor = load_motor(motor_ref, "position drift")
    plate = motor.nameplate
    probe = build_drive(drift_scenario(motor, commissioning, direction, options, 1.0))
    c = probe.controller
    gain = HOLD_GAIN_PER_SPEED_ZERO * c.ki_speed / c.kp_speed
    rated = plate.rated_speed_rpm * math.pi / 30.0
    limit = 0.1 * rated
    search = options.search_per_rated * rated
    settle_s = max(0.5, 6.0 / gain)
    reach_s = options.stop_from_start_rad / search + settle_s + 0.5
    scenario = drift_scenario(motor, commissioning, direction, options,
                              reach_s + settle_s * (len(options.moves_rad) + 1))
    drive = build_drive(scenario)
    current = options.stop_current_per_rated * plate.rated_current_A
    settings = HomingSettings(HARD_STOP, direction, search, current, -direction * options.offset_rad,
                              options.backoff_rad)
    known = probe.commissioning.refined(plate)
    homing = Homing(settings, gain, limit,
                    search_acceleration(known.J_kgm2, 1.5 * known.n_p * known.psi_f_Wb, current))
    return _run(drive, homing, (gain, limit, settle_s), options, plate.n_p)


def _run(drive, homing, loop, options, n_p):
    """Run ``drive`` (runner.Drive) block by block: homing once tracking, then the moves; the row of drift_run."""
    gain, limit, settle_s = loop
    scenario = drive.scenario
    n, N, T_s = scenario.n_samples, options.loop_samples, scenario.T_s
    log = np.zeros((n, len(LOG_COLUMNS)))
    homed_k = None
    direction = homing.settings.direction
    for k0 in range(0, n, N):
        k1 = min(k0 + N, n)
        drive.run(k0, k1, log[k0:k1])
        row = log[k1 - 1]
        estimate = (row[COLUMN["theta_e_hat"]] / n_p, row[COLUMN["omega_e_hat"]] / n_p)
        if homed_k is None:
            if homing.state == "not_homed" and row[COLUMN["state"]] == TRACKING:
                homing.start()
            if homing.active:
                speed = homing.reference(N * T_s, estimate, row[COLUMN["i_q"]])
                homed_k = k1 if homing.homed else None
            else:
                speed = 0.0
            if homing.state == FAILED:
                return {"n_p": n_p, "failed": homing.reason}
        elif row[COLUMN["state"]] not in (HOLD, TRACKING):
            return {"n_p": n_p, "failed": f"lost: estimator state {int(row[COLUMN['state']])} at {row[0]:.2f} s, the "
                                          f"homed position with it"}
        else:
            move = min(int((k0 - homed_k) * T_s / settle_s), len(options.moves_rad) - 1)
            target = homing.theta_zero - direction * options.moves_rad[move]
            speed = position_speed(target, 0.0, estimate[0], gain, limit)
        drive.speed_ref[k1:k1 + N] = speed
    if homed_k is None:
        return {"n_p": n_p, "failed": "not homed by the end of the run"}
    stop = scenario.end_stop["high_rad" if direction > 0 else "low_rad"]
    estimated = log[homed_k:, COLUMN["theta_e_hat"]] / n_p - homing.theta_zero
    truth = log[homed_k:, COLUMN["theta_m"]] - (stop + homing.settings.offset_rad)
    error = estimated - truth
    return {"n_p": n_p, "homed_at_s": homed_k * T_s, "homing_error_rad": float(error[0]),
            "drift_rad": float(error[-1] - error[0]), "peak_deviation_rad": float(np.max(np.abs(error - error[0]))),
            "tolerance_rad": 2.0 * PEAK_ERROR_E_RAD / n_p, "failed": ""}


def drawn_rows(count, seed, folder):
    """The rows of the first ``count`` motors of the draw ``seed`` with more than one pole pair, each commissioned
    as `drive bench motors` does (files in ``folder``) and run against a stop, alternately above and below: a row
    with ``failed`` "refused: ..." where the drive or its commissioning refuses the motor."""
    from .motor_bench import NOT_APPLICABLE, RefusedForSaliency, _commission
    from .random_motors import draw_motor, write_motor_files
    rows, index = [], 0
    while len(rows) < count:
        drawn = draw_motor(seed, index)
        index += 1
        if drawn.figures["n_p"] < 2:
            continue
        path = write_motor_files([drawn], Path(folder))[0]
        commissioning = Path(folder) / f"{drawn.name}_commissioning.yaml"
        direction = 1.0 if len(rows) % 2 == 0 else -1.0
        try:
            first = parse_scenario(experiment_document("standstill_hold", load_motor(str(path), "position drift"),
                                                       ExperimentOptions(commissioning="nameplate")),
                                   drawn.name, drawn.name, None, "", str(path), "motor")
            _commission(first, commissioning, {"tests": []})
            row = drift_run(str(path), commissioning, direction)
        except (*NOT_APPLICABLE, RefusedForSaliency) as error:
            row = {"n_p": drawn.figures["n_p"], "failed": f"refused: {' '.join(str(error).split())}"}
        rows.append({"motor": drawn.name, "direction": direction, **row})
    return rows


def main(argv=None):
    """``python -m drive_tools.evaluation.position_drift --random N --seed S [--json]``: drawn_rows as a table (or
    JSON)."""
    parser = argparse.ArgumentParser(prog="position_drift")
    parser.add_argument("--random", type=int, default=6)
    parser.add_argument("--seed", type=int, default=3)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as folder:
        rows = drawn_rows(args.random, args.seed, folder)
    if args.json:
        print(json.dumps(rows, indent=1))
        return 0
    print("| motor | n_p | stop | homed at [s] | homing error [mrad] | drift [mrad] | peak during moves [mrad] "
          "| tolerance [mrad] |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        side = "above" if r["direction"] > 0 else "below"
        if r["failed"]:
            print(f"| {r['motor']} | {r['n_p']} | {side} | {_short(r['failed'], r['motor'])} | | | | |")
            continue
        print(f"| {r['motor']} | {r['n_p']} | {side} | {r['homed_at_s']:.2f} | {1e3 * r['homing_error_rad']:.1f} | "
              f"{1e3 * r['drift_rad']:.1f} | {1e3 * r['peak_deviation_rad']:.1f} | {1e3 * r['tolerance_rad']:.0f} |")
    return 0


def _short(reason, motor):
    """A table's few words of a refusal: its parts naming the motor or a file dropped, cut at the first number."""
    parts = [p.strip() for p in reason.split(": ") if motor not in p and "/" not in p]
    return re.split(r"\d", ": ".join(parts))[0].rstrip(" :(")


if __name__ == "__main__":
    sys.exit(main())
