"""Scores of a run: electrical angle error in steady and transient windows, speed errors, settling.

Windows: the run is cut at every table event (speed or load change). The ``settle_s`` after each
event (and after ``start_s`` at the beginning) is transient; the rest, up to the next event, is steady.
"""
import math

import numpy as np

from drive_common.contract.estimator_states import LOCK_LOST as LOCK_LOST_STATE
from drive_common.contract.estimator_states import TRACKING as TRACKING_STATE
from drive_common.contract.log import COLUMN
from drive_common.math import frames


def wrap(angle):
    """Wrap to (−π, π] for arrays: the plain-Python body of drive_common.math.frames.wrap."""
    return frames.wrap.py_func(angle)


def angle_error(log, n_p):
    """wrap(θ_e − θ̂_e) per sample [rad, electrical]."""
    return wrap(n_p * log[:, COLUMN["theta_m"]] - log[:, COLUMN["theta_e_hat"]])


def windows(scenario):
    """(steady, transient) lists of (t0, t1) intervals."""
    cuts = [scenario.metrics_start_s] + [e for e in scenario.events_s() if e > scenario.metrics_start_s]
    ends = cuts[1:] + [scenario.duration_s]
    steady, transient = [], []
    for i, (t0, t1) in enumerate(zip(cuts, ends)):
        settle = 0.0 if i == 0 else scenario.settle_s
        if settle > 0.0:
            transient.append((t0, min(t0 + settle, t1)))
        if t0 + settle < t1:
            steady.append((t0 + settle, t1))
    return steady, transient


def _mask(t, intervals):
    mask = np.zeros(t.shape, dtype=bool)
    for t0, t1 in intervals:
        mask |= (t >= t0) & (t < t1)
    return mask


def _stats(values):
    if values.size == 0:
        return None, None, None
    return float(np.sqrt(np.mean(values ** 2))), float(np.mean(values)), float(np.max(np.abs(values)))


LOCK_LOST_RAD = np.pi / 2
"""|θ_e − θ̂_e| beyond which the estimate is on the wrong side: the lock is lost (ground truth)."""


def settling_times(scenario, log, band_fraction=0.05, band_min_rad_s=0.1):
    """For each change of the speed reference (a step, or a ramp's end where the reference then holds; a
    corner into another ramp is no end): the time from the change's end until ω_m enters its settled
    envelope and stays in it up to the next event.

    Settled means what the speed does over the window's last half: its mean is within the tolerance
    (``band_fraction`` of the change, at least ``band_min_rad_s``) of the reference, else the step
    "never settled" (``settling_time_s`` None). The envelope is that tolerance, widened to the settled
    mean's offset plus its peak ripple, so ripple alone never reads as unsettled."""
    t = log[:, COLUMN["t"]]
    omega = log[:, COLUMN["omega_m"]]
    events = scenario.events_s() + [scenario.duration_s]
    table = scenario.speed
    results = []
    for i in range(1, len(table.times_s)):
        t_step, target = table.times_s[i], table.values[i]
        step = target - table.values[i - 1]
        ramping_on = table.interpolation == "linear" and i + 1 < len(table.values) and table.values[i + 1] != target
        if step == 0.0 or ramping_on or not 0.0 < t_step < scenario.duration_s:
            continue
        t_next = min(e for e in events if e > t_step)
        inside = (t >= t_step) & (t < t_next)
        last_half = inside & (t >= (t_step + t_next) / 2.0)
        if not last_half.any():
            continue
        tolerance = max(band_fraction * abs(step), band_min_rad_s)
        settled_mean = float(np.mean(omega[last_half]))
        ripple = float(np.max(np.abs(omega[last_half] - settled_mean)))
        offset = abs(settled_mean - target)
        band = max(tolerance, offset + ripple)
        outside = inside & (np.abs(omega - target) > band)
        if offset > tolerance:
            settle = None
        elif not outside.any():
            settle = 0.0
        else:
            settle = float(t[np.nonzero(outside)[0][-1] + 1] - t_step)
        results.append({"t_s": t_step, "from_rad_s": table.values[i - 1], "to_rad_s": target,
                        "tolerance_rad_s": tolerance, "band_rad_s": band, "ripple_rad_s": ripple,
                        "settled_offset_rad_s": offset, "settling_time_s": settle})
    return results


def settling_summary(steps):
    """(worst settling time or None, a note saying why it is None: no step, or a step never settled)."""
    if not steps:
        return None, "no speed step in the run"
    never = [s for s in steps if s["settling_time_s"] is None]
    if never:
        s = never[0]
        return None, (f"never settled after the step at {s['t_s']:g} s (settled offset "
                      f"{s['settled_offset_rad_s']:.3g} rad/s > tolerance {s['tolerance_rad_s']:.3g} rad/s)")
    return max(s["settling_time_s"] for s in steps), None


def lock_loss(t, error, start_s):
    """Time [s] with |angle error| beyond LOCK_LOST_RAD after ``start_s``, and when it first happened
    (None, None without ground truth)."""
    evaluated = (t >= start_s) & np.isfinite(error)
    if not evaluated.any():
        return None, None
    lost = evaluated & (np.abs(error) > LOCK_LOST_RAD)
    T_s = float(t[1] - t[0]) if t.size > 1 else 0.0
    return float(lost.sum() * T_s), (float(t[np.argmax(lost)]) if lost.any() else None)


def reported_losses(state):
    """How many times a state-code column enters LOCK_LOST."""
    entered = (state == LOCK_LOST_STATE) & np.concatenate(([True], state[:-1] != LOCK_LOST_STATE))
    return int(entered.sum())


def startup_metrics(scenario, log, n_p):
    """The start-up as ``drive run --json`` reports it: ``completed`` (torque was allowed), ``duration_s``
    (when), ``angle_error_e_rad`` then, ``polarity_correct`` (|error| < π/2 then; None without truth),
    ``reverse_rotation_m_rad`` (the largest rotation against the commanded direction from then until the
    reference changes sign, mechanical; the direction is the first non-zero reference's), and
    ``lock_lost`` (times the estimator reported a lost lock)."""
    t = log[:, COLUMN["t"]]
    state = log[:, COLUMN["state"]]
    out = {"completed": False, "duration_s": None, "angle_error_e_rad": None, "polarity_correct": None,
           "reverse_rotation_m_rad": None, "lock_lost": reported_losses(state)}
    tracking = np.nonzero(state == TRACKING_STATE)[0]
    if not tracking.size:
        return out
    first = int(tracking[0])
    error = angle_error(log[first:first + 1], n_p)[0]
    theta = log[:, COLUMN["theta_m"]]
    truth = bool(np.isfinite(error))
    out.update(completed=True, duration_s=float(t[first]), angle_error_e_rad=float(error) if truth else None,
               polarity_correct=bool(abs(error) < np.pi / 2) if truth else None)
    reference = log[:, COLUMN["omega_m_ref"]]
    moving = np.nonzero(reference != 0.0)[0]
    if truth and moving.size:
        direction = np.sign(reference[moving[0]])
        reversed_at = np.nonzero(np.sign(reference[first:]) == -direction)[0]
        end = first + int(reversed_at[0]) if reversed_at.size else len(t)
        against = -direction * (theta[first:end] - theta[first])
        out["reverse_rotation_m_rad"] = float(max(0.0, np.max(against))) if against.size else 0.0
    return out


def angle_scores(log, n_p, steady, start_s):
    """What any recording is scored by, scenario or not: angle error RMS and bias over the ``steady``
    windows ((t0, t1) [s]), its peak after ``start_s``, speed estimation error RMS over the windows, time
    with the lock lost (|error| > π/2) after ``start_s`` and when first, the fraction of samples after
    ``start_s`` the estimator reports tracking, and the lock losses it reported. None where the log has
    no ground truth. Samples a recording lost (NaN) are left out of every figure."""
    t = log[:, COLUMN["t"]]
    error = angle_error(log, n_p)
    known = np.isfinite(error)
    steady_mask = _mask(t, steady) & known
    evaluated = t >= start_s
    rms, bias, _ = _stats(error[steady_mask])
    _, _, peak = _stats(error[evaluated & known])
    speed_estimation_error = log[:, COLUMN["omega_m"]] - log[:, COLUMN["omega_e_hat"]] / n_p
    lock_lost_s, lock_lost_at_s = lock_loss(t, error, start_s)
    state = log[:, COLUMN["state"]]
    reported = evaluated & np.isfinite(state)
    return {"angle_error_rms": rms, "angle_error_bias": bias, "angle_error_peak": peak,
            "speed_error_rms": _stats(speed_estimation_error[steady_mask & np.isfinite(speed_estimation_error)])[0],
            "lock_lost_s": lock_lost_s, "lock_lost_at_s": lock_lost_at_s,
            "observable_fraction": float(np.mean(state[reported] == TRACKING_STATE)) if reported.any() else None,
            "lock_lost": reported_losses(state)}


def compute_metrics(result, steady_windows=None):
    """The metrics dictionary printed by ``drive run`` (SI units: rad, rad/s, s). ``steady_windows``:
    the (t0, t1) intervals [s] to score instead of the scenario's (no transient windows then)."""
    scenario, log, n_p = result.scenario, result.log, result.n_p
    t = log[:, COLUMN["t"]]
    error = angle_error(log, n_p)
    steady, transient = windows(scenario) if steady_windows is None else (list(steady_windows), [])
    steady_mask = _mask(t, steady)
    scores = angle_scores(log, n_p, steady, scenario.metrics_start_s)
    _, _, peak_steady = _stats(error[steady_mask])
    _, _, peak_transient = _stats(error[_mask(t, transient)])
    speed_tracking_error = log[:, COLUMN["omega_m_ref"]] - log[:, COLUMN["omega_m"]]
    steps = settling_times(scenario, log)
    settling_time, settling_note = settling_summary(steps)
    startup = startup_metrics(scenario, log, n_p)
    startup["refused"] = (getattr(result, "startup", None) or {}).get("refused")
    per_window = []
    for t0, t1 in steady:
        w_rms, w_bias, w_peak = _stats(error[_mask(t, [(t0, t1)])])
        per_window.append({"t0_s": t0, "t1_s": t1, "angle_error_rms": w_rms,
                           "angle_error_bias": w_bias, "angle_error_peak": w_peak})
    return {
        "scenario": scenario.name,
        "motor": scenario.motor.name,
        "estimator": result.estimator,
        "duration_s": scenario.duration_s,
        "samples": int(log.shape[0]),
        "current_limit_A": result.current_limit_A,
        "angle_error_rms": scores["angle_error_rms"],
        "angle_error_bias": scores["angle_error_bias"],
        "angle_error_peak": scores["angle_error_peak"],
        "angle_error_peak_steady": peak_steady,
        "angle_error_peak_transient": peak_transient,
        "speed_error_rms": scores["speed_error_rms"],
        "speed_tracking_error_rms": _stats(speed_tracking_error[steady_mask])[0],
        "settling_time_s": settling_time,
        "settling_note": settling_note,
        "speed_steps": steps,
        "lock_lost_s": scores["lock_lost_s"],
        "lock_lost_at_s": scores["lock_lost_at_s"],
        "observable_fraction": scores["observable_fraction"],
        "startup": startup,
        "lock_lost": startup["lock_lost"],
        "steady_windows": per_window,
        "wall_time_s": result.wall_time_s,
        "samples_per_second": log.shape[0] / result.wall_time_s if result.wall_time_s > 0 else None,
    }


def supervision_faults(result):
    """The speed supervision's faults of a run (foc_controller.supervision), from what the drive knows: the
    current reference's magnitude against its limit, the command against the shaft at the drive's speed ramp,
    each fault naming the torque limit it stated."""
    from foc_controller.supervision import speed_supervision
    log, plate = result.log, result.scenario.motor.nameplate
    stated = (result.sensorless_torque or {}).get("line", "")
    return speed_supervision(log[:, COLUMN["t"]], log[:, COLUMN["omega_m_ref"]], log[:, COLUMN["omega_e_hat"]],
                             np.hypot(log[:, COLUMN["i_d_ref"]], log[:, COLUMN["i_q_ref"]]), log[:, COLUMN["state"]],
                             (result.n_p, plate.rated_speed_rpm * math.pi / 30.0, result.current_limit_A, stated,
                              result.speed_ramp_rad_s2))


def configuration_warnings(result):
    """What the drive says of its configuration before anything went wrong: the sensorless current limit
    below rated current, a weak saliency (drive_common.motor.commissioning.WEAK_SALIENCY_RATIO) under injection,
    and a rated load step that may outrun ours' tracking where its loops are scaled to the motor and the
    sampling rate caps them (drive_common.motor.scaled_loops)."""
    from drive_common.motor.scaled_loops import scaled_loops
    from hf_estimator.build import SCALED_TRACKING

    scenario, lines = result.scenario, []
    plate = scenario.motor.nameplate
    if result.current_limit_A < plate.rated_current_A:
        lines.append(f"current limit {result.current_limit_A:.3g} A is below the rated {plate.rated_current_A:g} A "
                     f"(the saliency tracker's limit, measured at commissioning): rated load cannot be held")
    facts = result.estimator_facts or {}
    if result.commissioning is not None and facts.get("injection_frequency_Hz"):
        lines += [note for note in (result.commissioning.weak_saliency_note(),) if note]
    if (result.commissioning is not None and scenario.estimator in SCALED_TRACKING
            and "pll_bandwidth_Hz" not in scenario.estimator_settings):
        loops = scaled_loops(result.commissioning.refined(plate), scenario.motor.inverter, scenario.T_s)
        if loops.largest_tracked_load_step_per_rated < 1.0:
            lines.append(f"a rated load step may outrun ours' angle tracking (steps above "
                         f"{loops.largest_tracked_load_step_per_rated:.2f} × rated torque at {1.0 / scenario.T_s:.0f} "
                         f"Hz sampling; faster sampling raises the limit)")
    return lines
