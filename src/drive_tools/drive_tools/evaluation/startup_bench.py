"""``drive bench startup``: the start-up from rotor angles over the whole electrical circle, noise seeds,
with and without load (docs/startup.md). Each run is a short scenario: the rotor at rest at angle θ_e,
the estimator told nothing, the speed reference zero for the start-up's budget (``HOLD_S``: a released
brake's load meets a drive told to hold still) and then ramping to ``SPEED_PER_RATED`` of rated speed;
the load opposes that direction (the case where rolling back shows)."""
import math
from typing import NamedTuple

import numpy as np

from drive_common.config.scenario import load_scenario, parse_scenario
from drive_common.motor.motor_file import load_motor
from drive_tools.evaluation.metrics import startup_metrics
from drive_tools.runner.runner import run_scenario

MOTOR_SCENARIOS = {"wang_spmsm": "wang_100rpm", "szabo_ipmsm": "szabo_profile"}
"""The shipped scenario whose injection and controller a shipped motor's bench runs use (any other motor
runs with the drive's own, scaled to it: docs/motors-and-control.md "Loops scaled to the motor")."""
SPEED_PER_RATED = 0.03
HOLD_S = 0.05
RAMP_S = 0.1
DURATION_S = 0.25


class LoadCase(NamedTuple):
    name: str
    load_per_rated: float
    brake: bool
    feedforward: bool = False
    """The robot tells the drive the load's torque (`torque_feedforward`, its gravity model)."""


STANDARD_CASES = (LoadCase("no load", 0.0, False), LoadCase("0.5 rated, brake", 0.5, True),
                  LoadCase("0.5 rated, brake, ff", 0.5, True, True), LoadCase("0.3 rated, active", 0.3, False))
"""The issue's cases: no load; half rated load held by a brake released at first torque, the drive told
nothing of it or told its torque by the robot; a gravity-like 0.3 rated load from t = 0 that moves the
rotor during start-up."""


def bench_scenario(motor, estimator, theta_e_rad, seed, case, settings=None, commissioning="", T_s=None):
    """The scenario of one bench run on ``motor`` (a shipped name, a motor file or a Motor), with the
    ``commissioning`` file given (default: the scenario's lookup), sampled every ``T_s`` (default: the
    shipped scenario's, else 10 kHz)."""
    m = load_motor(motor, "--motor")
    shipped = load_scenario(MOTOR_SCENARIOS[m.name]) if m.shipped else None
    plate = m.nameplate
    speed = SPEED_PER_RATED * plate.rated_speed_rpm
    data = {"motor": m.source, "estimator": {"type": estimator or "injection_frame", "settings": settings or {}},
            "injection": dict(shipped.injection) if shipped else {}, "duration_s": DURATION_S,
            "sampling_period_s": T_s or (shipped.T_s if shipped else 1e-4),
            "speed": {"unit": "rpm", "interpolation": "linear",
                      "points": [[0.0, 0.0], [HOLD_S, 0.0], [HOLD_S + RAMP_S, speed]]},
            "load": {"unit": "rated", "points": [[0.0, case.load_per_rated]]}, "seed": seed,
            "initial": {"theta_m_rad": theta_e_rad / plate.n_p}, "brake": case.brake,
            "metrics": {"settle_s": 0.05}, "controller": dict(shipped.controller) if shipped else {},
            **({"commissioning": str(commissioning)} if commissioning else {})}
    if case.feedforward:
        data["torque_feedforward"] = {"unit": "rated", "points": [[0.0, case.load_per_rated]]}
    return parse_scenario(data, f"startup_{m.name}", "drive bench startup")


def startup_sweep(motor, case, angles=72, seeds=(1, 2, 3), estimator=None, progress=None, commissioning="",
                  T_s=None):
    """One row per (angle, seed): the start-up metrics (metrics.startup_metrics) of a bench run, and
    the summary of them all."""
    rows = []
    total = angles * len(seeds)
    for i in range(angles):
        theta_e = 2.0 * math.pi * i / angles - math.pi
        for seed in seeds:
            scenario = bench_scenario(motor, estimator, theta_e, seed, case, commissioning=commissioning, T_s=T_s)
            result = run_scenario(scenario)
            rows.append({"theta_e_rad": theta_e, "seed": seed, **startup_metrics(scenario, result.log, result.n_p),
                         "refused": (result.startup or {}).get("refused")})
            if progress:
                progress(len(rows) / total)
    return {"motor": load_motor(motor, "--motor").name, "case": case.name, "load_per_rated": case.load_per_rated,
            "brake": case.brake,
            "estimator": estimator or "injection_frame", "runs": len(rows), **summary(rows), "rows": rows}


def summary(rows):
    """Polarity correct fraction, worst |angle error| at first torque, worst rotation against the
    commanded direction [deg mechanical], slowest start-up, lock losses, runs that never started."""
    started = [r for r in rows if r["completed"]]

    def worst(key, scale=1.0):
        values = [abs(r[key]) * scale for r in started if r[key] is not None]
        return float(max(values)) if values else None
    correct = [r["polarity_correct"] for r in started if r["polarity_correct"] is not None]
    return {"polarity_correct_fraction": float(np.mean(correct)) if len(started) == len(rows) and correct
            else (float(np.sum(correct)) / len(rows) if rows else None),
            "angle_error_max_e_rad": worst("angle_error_e_rad"),
            "reverse_rotation_max_m_deg": worst("reverse_rotation_m_rad", 180.0 / math.pi),
            "duration_max_s": worst("duration_s"),
            "lock_lost": int(sum(r["lock_lost"] for r in rows)),
            "not_started": len(rows) - len(started)}
