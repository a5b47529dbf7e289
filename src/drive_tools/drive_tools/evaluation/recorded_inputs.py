"""An estimator's inputs rebuilt from a recording: the measured currents and the voltage that acted before
each sample, with the samples the recorder lost told from those the drive lost (docs/recordings.md, "A
robot's recording").
"""

import numpy as np

from drive_common.contract.log import COLUMN
from drive_common.math.frames import clarke

ANSWER_COLUMNS = ("theta_e_hat", "u_inj_alpha", "state", "injection_amplitude")
"""Log columns of the recording estimator's answer to a sample (rotor_estimate, injection, estimator_state,
estimator_blend): where any is recorded, the drive's estimator took that sample's currents."""
FIT_STEPS = 48
"""Current steps on each side of a gap that the local admittance is fitted on."""
MIN_FIT_STEPS = 12
"""Fewer whole steps around a gap than this: its currents are not rebuilt (the samples stay lost)."""


def replay_inputs(recording):
    """(currents n × 3, the voltage applied in the period before each sample n × 2, whole: n booleans) of a
    Recording (the command of d + 1 samples before, d the recording drive's delay; zero where the inverter
    reported that period at zero volts)."""
    return logged_inputs(recording.log, recording.delay_periods, recording.zero_volts)


def logged_inputs(log, delay_periods, zero_volts=None):
    """replay_inputs of a run's ``log`` (LOG_COLUMNS) with the drive's delay. A sample is whole where its
    currents and the voltage that acted before it are known. A sample whose currents the recorder lost while
    the drive's estimator took them (its answer to that sample is recorded) is rebuilt (rebuilt_currents), so
    replay steps where the drive stepped. Replay steps the estimators over the other lost samples (the drive
    lost them too: the estimator meets the next sample, as a drive node meets a lost message), and the first
    whole sample after a gap carries the voltage of every period since the last whole one, summed (the
    voltages of lost periods where known): the current step it sees is the one that voltage drove, so a fit
    or an integrator of voltage stays consistent across the gap. A lost voltage_command whose injection
    message arrived is rebuilt: that injection plus the fundamental (command less injection) interpolated
    between its neighbours. ``zero_volts`` (per sample: the period from it ran at zero volts) zeroes the
    command that would have acted there, as the drive's estimator node does with `zero_voltage`."""
    currents = log[:, [COLUMN["i_a_meas"], COLUMN["i_b_meas"], COLUMN["i_c_meas"]]]
    voltage = rebuilt_voltage(log[:, [COLUMN["u_alpha"], COLUMN["u_beta"]]],
                              log[:, [COLUMN["u_inj_alpha"], COLUMN["u_inj_beta"]]])
    if zero_volts is not None and zero_volts.any():
        commands = np.flatnonzero(zero_volts) - delay_periods
        voltage[commands[commands >= 0]] = 0.0
    lag = delay_periods + 1
    u_applied = np.zeros((len(voltage), 2))
    u_applied[lag:] = voltage[:-lag]
    answered = np.zeros(len(log), dtype=bool)
    for name in ANSWER_COLUMNS:
        answered |= np.isfinite(log[:, COLUMN[name]])
    currents = rebuilt_currents(currents, u_applied, answered)
    whole = np.isfinite(currents).all(axis=1) & np.isfinite(u_applied).all(axis=1)
    if not whole.all():
        summed = np.cumsum(np.nan_to_num(u_applied), axis=0)
        at = np.nonzero(whole)[0]
        u_applied[at[1:]] = summed[at[1:]] - summed[at[:-1]]
    return np.ascontiguousarray(currents), u_applied, whole


def rebuilt_voltage(voltage, injection):
    """``voltage`` (n × 2) with each lost sample (NaN) whose ``injection`` is known rebuilt as that injection
    plus the fundamental voltage − injection interpolated linearly between the known samples around it."""
    lost = np.isnan(voltage).any(axis=1) & np.isfinite(injection).all(axis=1)
    known = np.isfinite(voltage).all(axis=1) & np.isfinite(injection).all(axis=1)
    if not lost.any() or known.sum() < 2:
        return voltage
    voltage = voltage.copy()
    at, where = np.nonzero(known)[0], np.nonzero(lost)[0]
    for j in range(2):
        fundamental = voltage[at, j] - injection[at, j]
        voltage[where, j] = np.interp(where, at, fundamental) + injection[where, j]
    return voltage


def rebuilt_currents(currents, u_applied, answered):
    """``currents`` (n × 3 [A]) with each gap of lost samples (NaN) that the drive took (``answered``, n
    booleans) rebuilt between the known samples around it: each step follows a local model of the winding
    fitted on the whole steps around the gap, Δi = Y·u + G·i + b per phase (Y the admittance per period to
    ``u_applied`` [V, αβ], G the resistive and back-EMF decay of the αβ current [A] before the step, b the
    rest), and what the model leaves of the known change across the gap is spread evenly over its steps. A gap
    with an unknown voltage in it, at the recording's ends, or with too few whole steps around it stays lost."""
    lost = ~np.isfinite(currents).all(axis=1)
    rebuild = lost & answered
    if not rebuild.any():
        return currents
    currents = currents.copy()
    alpha_beta = np.column_stack(clarke.py_func(*currents.T))
    steps = np.full_like(currents, np.nan)
    steps[1:] = currents[1:] - currents[:-1]
    fit_at = np.isfinite(steps).all(axis=1) & np.isfinite(u_applied).all(axis=1)
    fit_at[1:] &= np.isfinite(alpha_beta[:-1]).all(axis=1)
    for first, end in _gaps(rebuild):
        before, after = first - 1, end
        if before < 0 or after >= len(currents) or lost[before] or lost[after]:
            continue
        if not np.isfinite(u_applied[first:after + 1]).all():
            continue
        window = np.arange(max(1, first - FIT_STEPS), min(len(currents), after + 1 + FIT_STEPS))
        window = window[fit_at[window]]
        if len(window) < MIN_FIT_STEPS:
            continue
        x = np.column_stack((u_applied[window], alpha_beta[window - 1], np.ones(len(window))))
        model = np.linalg.lstsq(x, steps[window], rcond=None)[0]
        level = currents[before].copy()
        predicted = []
        for k in range(first, after + 1):
            step = np.concatenate((u_applied[k], clarke.py_func(*level), (1.0,))) @ model
            predicted.append(step)
            level = level + step
        predicted = np.array(predicted)
        predicted += (currents[after] - currents[before] - predicted.sum(axis=0)) / len(predicted)
        currents[first:after] = currents[before] + np.cumsum(predicted, axis=0)[:-1]
    return currents


def _gaps(mask):
    """(first, end) of each run of true values in ``mask`` (end exclusive)."""
    edges = np.diff(np.concatenate(([0], mask.astype(np.int8), [0])))
    return zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1))
