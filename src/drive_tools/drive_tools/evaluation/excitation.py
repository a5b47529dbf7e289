"""What a recording's HF excitation is, measured from its `injection` topic, and whether an estimator's own
carrier is in it (docs/recordings.md, "Which estimators a recording measures").

The injection is reduced to a signed carrier along its own axis: per AXIS_BLOCK_S, the principal axis of
the injected voltage, its sign chained from block to block (an axis that turns with the rotor keeps its
sign), the voltage projected on it. A pulsating injection then is a scalar carrier; a rotating one leaves
half its energy across the axis.
"""
import math

import numpy as np

AXIS_BLOCK_S = 1e-3
"""The injection axis is taken per block this long (a rotor at rated speed turns it less than π/2)."""
MATCH_WINDOW_S = 0.05
"""The carrier is compared with an estimator's own in windows this long."""
MIN_CARRIER_FRACTION = 0.8
"""A demodulating estimator is measured when at least this share of the recorded carrier's energy is a sine
at its frequency (median over the windows; a square wave at it holds 0.81)..."""
MAX_CARRIER_PHASE_RAD = 0.35
"""...in the carrier phase it demodulates with, within this (mod π: a carrier of opposite sign is the same
injection on the axis turned by π)."""
QUIET_PER_PEAK = 1e-3
"""Blocks whose energy is below this share of the largest block's carry no injection."""


def signed_carrier(u, T_s):
    """(carrier c [V] per sample, injected-energy share off the axis) of an injection u (n × 2) [V]."""
    n = len(u)
    block = max(2, int(round(AXIS_BLOCK_S / T_s)))
    blocks = -(-n // block)
    padded = np.zeros((blocks * block, 2))
    padded[:n] = np.nan_to_num(u)
    v = padded.reshape(blocks, block, 2)
    xx, yy, xy = (v[..., 0] ** 2).sum(1), (v[..., 1] ** 2).sum(1), (v[..., 0] * v[..., 1]).sum(1)
    energy = xx + yy
    live = energy > QUIET_PER_PEAK * energy.max() if energy.size and energy.max() > 0.0 else np.zeros(blocks, bool)
    doubled = np.arctan2(2.0 * xy, xx - yy)
    if live.any():
        doubled = np.interp(np.arange(blocks), np.nonzero(live)[0], np.unwrap(doubled[live]))
    axis = np.repeat(0.5 * doubled, block)[:n]
    c = padded[:n, 0] * np.cos(axis) + padded[:n, 1] * np.sin(axis)
    total = float((padded ** 2).sum())
    across = 1.0 - float((c ** 2).sum()) / total if total > 0.0 else 0.0
    return c, across


def describe_excitation(c, across, T_s):
    """{kind, frequency_Hz, amplitude_V, across_axis} of a recorded injection, measured from its signed
    carrier ``c`` [V] and energy share ``across`` its axis (signed_carrier): kind ``none``, ``rotating`` (a
    third or more of its energy across its axis), ``square`` or ``pulsating_sine`` (by the carrier's crest
    factor); the frequency is the carrier's spectral peak."""
    rms = float(np.sqrt(np.mean(c ** 2))) if c.size else 0.0
    if rms == 0.0:
        return {"kind": "none", "frequency_Hz": 0.0, "amplitude_V": 0.0, "across_axis": 0.0}
    spectrum = np.abs(np.fft.rfft(c - c.mean()))
    frequency = float(np.fft.rfftfreq(len(c), T_s)[int(np.argmax(spectrum))])
    peak = float(np.percentile(np.abs(c), 99.0))
    kind = "rotating" if across > 1.0 / 3.0 else "square" if peak / rms < 1.2 else "pulsating_sine"
    return {"kind": kind, "frequency_Hz": frequency, "amplitude_V": peak, "across_axis": across}


def carrier_match(recorded_carrier, requested, frequency_Hz, T_s, scored):
    """How much of the recorded injection (its signed carrier [V], signed_carrier) is an estimator's own
    carrier: (median share of the recorded carrier's energy that is a sine at ``frequency_Hz``, median
    phase difference [rad, mod π] between that sine and the carrier the estimator asked for wherever it
    injected), over MATCH_WINDOW_S windows of the ``scored`` samples (bool, n); the phase is None when the
    estimator never injected, the share 0 when no window has a recorded injection."""
    length = max(2, int(round(MATCH_WINDOW_S / T_s)))
    own = _phasors(signed_carrier(requested, T_s)[0], frequency_Hz, T_s, np.ones(len(scored), bool), length)
    doubled = sum((z / abs(z)) ** 2 for z, _ in own if z != 0.0)
    found = _phasors(recorded_carrier, frequency_Hz, T_s, scored, length)
    if not found:
        return 0.0, None
    shares = [2.0 * abs(z) ** 2 / (length * energy) for z, energy in found]
    if not own or doubled == 0.0:
        return float(np.median(shares)), None
    phases = [0.5 * abs(np.angle(z ** 2 * np.conj(doubled))) for z, _ in found]
    return float(np.median(shares)), float(np.median(phases))


def _phasors(c, frequency_Hz, T_s, mask, length):
    """[(Σ c·e^(−jωt), Σ c²)] of the windows of ``length`` samples wholly in ``mask`` where c has energy."""
    out = []
    for start in range(0, len(c) - length + 1, length):
        part = slice(start, start + length)
        energy = float(c[part] @ c[part])
        if mask[part].all() and energy > 0.0:
            turn = np.exp(-2j * math.pi * frequency_Hz * T_s * np.arange(start, start + length))
            out.append((complex(c[part] @ turn), energy))
    return out
