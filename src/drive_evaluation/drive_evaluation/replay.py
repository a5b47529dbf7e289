"""``drive bench replay``: estimators run on a recording's measured currents and applied voltages,
scored against the recording's ground truth.

What replay measures: how each estimator demodulates and tracks the currents the motor really drew.
What it cannot: the estimator under test does not steer the recorded excitation. Every method
superimposes its own injection, and the paper methods inject along their own estimated axis. The
recorded currents therefore answer the recorded estimator's injection, not theirs. The
``excitation_mismatch`` column says how far each estimator's requested injection is from the one that
was applied (0: the same excitation, so a faithful replay). Closed-loop comparison is `drive run`.
"""
import dataclasses
import math
import time

import numpy as np

from drive_bags.common import BagError
from drive_bags.reader import bag_result, has_ground_truth
from drive_interface.log import COLUMN
from drive_runner.loop import replay_samples
from drive_runner.runner import RunResult, build_drive

from .metrics import angle_error, compute_metrics

MAX_APPLICABLE_MISMATCH = 0.2
"""Replay measures an estimator when the injection it asks for is within this relative RMS of the
recorded one (its currents then answer an excitation close to its own)."""
TIMED_RUNS = 3
"""Each estimator replays the bag this many times from its fresh state; the fastest run is reported."""
OUTPUTS = ("theta_e_hat", "omega_e_hat", "u_inj_alpha", "u_inj_beta", "eps", "signal", "state")
LOCK_BAND_RAD = math.pi / 8
"""Time to lock: from the start until |angle error| stays within this band to the end. Every saliency
tracker's error signal goes as sin 2Δθ; within π/8 its slope is still ≥ 0.71 of the small-signal one."""


def replay_inputs(recorded, path):
    """(currents n × 3, the voltage applied in the period before each sample n × 2) from a recorded log
    (the command of d + 1 samples before, d the recorded drive's delay); a BagError names what is
    missing."""
    log = recorded.log
    currents = log[:, [COLUMN["i_a_meas"], COLUMN["i_b_meas"], COLUMN["i_c_meas"]]]
    voltage = log[:, [COLUMN["u_alpha"], COLUMN["u_beta"]]]
    injection = log[:, [COLUMN["u_inj_alpha"], COLUMN["u_inj_beta"]]]
    for name, values in (("currents", currents), ("voltage_command", voltage), ("injection", injection)):
        missing = int(np.isnan(values[:, 0]).sum())
        if missing:
            raise BagError(f"{path}: {name}: {missing} of {len(values)} samples missing; replay needs "
                           f"every one")
    lag = recorded.scenario.drive_delay_periods() + 1
    u_applied = np.zeros((len(voltage), 2))
    u_applied[lag:] = voltage[:-lag]
    return np.ascontiguousarray(currents), u_applied


def replay(path, estimators, steady_windows=None, recorded=None):
    """Replay each estimator on the bag (``recorded``: its RunResult when already read), scored over
    ``steady_windows`` ((t0, t1) [s]; None: the scenario's); returns (recorded RunResult, [entry dict],
    [replayed RunResult])."""
    recorded = recorded or bag_result(path)
    currents, u_applied = replay_inputs(recorded, path)
    truth = has_ground_truth(recorded.log)
    theta_m = np.ascontiguousarray(recorded.log[:, COLUMN["theta_m"]])
    omega_m = np.ascontiguousarray(recorded.log[:, COLUMN["omega_m"]])
    applied = recorded.log[:, [COLUMN["u_inj_alpha"], COLUMN["u_inj_beta"]]]
    entries, results = [], []
    for name in estimators:
        scenario = dataclasses.replace(recorded.scenario, estimator=name, estimator_settings={})
        drive = build_drive(scenario)
        e, calibration = drive.estimator, drive.commissioning.calibration()
        n_p = recorded.n_p
        out = np.zeros((len(currents), len(OUTPUTS)))
        replay_samples(e.step, e.x.copy(), e.z.copy(), e.params, n_p, currents[:2], u_applied[:2], theta_m[:2],
                       omega_m[:2], calibration, out[:2])
        wall = math.inf
        for _ in range(TIMED_RUNS):
            x, z = e.x.copy(), e.z.copy()
            start = time.perf_counter()
            replay_samples(e.step, x, z, e.params, n_p, currents, u_applied, theta_m, omega_m, calibration, out)
            wall = min(wall, time.perf_counter() - start)
        log = recorded.log.copy()
        for j, column in enumerate(OUTPUTS):
            log[:, COLUMN[column]] = out[:, j]
        result = RunResult(scenario, name, log, wall, recorded.current_limit_A)
        metrics = compute_metrics(result, steady_windows)
        mismatch = _relative_rms(out[:, 2:4] - applied, applied)
        entry = {"estimator": name, "samples": len(currents), "samples_per_second": len(currents) / wall,
                 "excitation_mismatch": mismatch, "observable_fraction": metrics["observable_fraction"],
                 "not_applicable": _not_applicable(mismatch, out[:, 2:4])}
        if truth:
            scored = ("angle_error_rms", "angle_error_bias", "angle_error_peak", "speed_error_rms")
            entry.update({key: metrics[key] for key in scored})
            entry["time_to_lock_s"] = time_to_lock(result)
        entries.append(entry)
        results.append(result)
    return recorded, entries, results


def time_to_lock(result):
    """Seconds until |θ_e − θ̂_e| stays within LOCK_BAND_RAD to the end; None if it never does."""
    outside = np.abs(angle_error(result.log, result.n_p)) > LOCK_BAND_RAD
    if outside[-1]:
        return None
    t = result.log[:, COLUMN["t"]]
    return float(t[np.nonzero(outside)[0][-1] + 1]) if outside.any() else 0.0


def _relative_rms(difference, reference):
    """RMS of ``difference`` over RMS of ``reference``; 0 when both are zero, None when only the
    reference is."""
    scale = float(np.sqrt(np.mean(reference ** 2)))
    spread = float(np.sqrt(np.mean(difference ** 2)))
    if scale > 0.0:
        return spread / scale
    return 0.0 if spread == 0.0 else None


def _not_applicable(mismatch, requested):
    """Why replay on this bag does not measure an estimator (None when it does): the bag has no
    injection and the estimator needs one, or its injection differs from the recorded one."""
    if mismatch is None:
        return "the recording has no injection and this estimator needs one"
    if mismatch > MAX_APPLICABLE_MISMATCH:
        return f"its injection differs from the recorded one (excitation mismatch {mismatch:.2f})"
    return None
