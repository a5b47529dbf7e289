"""Digital filters and the slew limiter shared by the controller, its supervision and the estimators.

Filters are second-order sections (rows b0 b1 b2 1 a1 a2, as scipy's ``sos``) run in transposed
direct form II by one numba kernel; they are designed once in Python with scipy, imported where a filter
is designed (scipy.signal takes over a second to import, which every `drive` command would pay).
"""
import math

import numpy as np
from numba import njit


def butterworth_lowpass(order, cutoff_Hz, T_s):
    """Digital Butterworth low-pass (bilinear transform, pre-warped), as SOS rows."""
    from scipy import signal
    return signal.butter(order, cutoff_Hz, btype="lowpass", fs=1.0 / T_s, output="sos")


def butterworth_bandpass(order, low_Hz, high_Hz, T_s):
    """Digital Butterworth band-pass; ``order`` is the prototype order, as in Wang §III-A."""
    from scipy import signal
    return signal.butter(order, [low_Hz, high_Hz], btype="bandpass", fs=1.0 / T_s, output="sos")


def notch(frequency_Hz, quality, T_s):
    """Second-order IIR notch (one SOS row); at the Nyquist frequency the mean of two samples, which a carrier
    alternating every sample (hf_estimator.square_wave) cannot pass."""
    if frequency_Hz * T_s >= 0.5:
        return np.array([[0.5, 0.5, 0.0, 1.0, 0.0, 0.0]])
    from scipy import signal
    b, a = signal.iirnotch(frequency_Hz, quality, fs=1.0 / T_s)
    return signal.tf2sos(b, a)


@njit(cache=True, _nrt=False)
def sos_step(sos, z, x):
    """Filter one sample x through the sections ``sos`` with state ``z`` (n_sections × 2)."""
    for s in range(sos.shape[0]):
        y = sos[s, 0] * x + z[s, 0]
        z[s, 0] = sos[s, 1] * x - sos[s, 4] * y + z[s, 1]
        z[s, 1] = sos[s, 2] * x - sos[s, 5] * y
        x = y
    return x


@njit(cache=True, _nrt=False)
def slew(value, target, step):
    """``value`` moved toward ``target`` by at most ``step`` (≥ 0; ∞: ``target`` itself)."""
    if step == math.inf:
        return target
    return value + min(max(target - value, -step), step)
