"""Digital filters and the slew limiter shared by the controller, its supervision and the estimators.

Filters are second-order sections (rows b0 b1 b2 1 a1 a2, as scipy's ``sos``) run in transposed
direct form II by one numba kernel. They are designed here in closed form with numpy, as scipy.signal designs
them (Butterworth by the bilinear transform of the analog prototype, pre-warped; the notch of scipy's
``iirnotch``): importing scipy.signal took 0.73 s, which every drive process paid at its start.
"""
import math

import numpy as np
from numba import njit


def _butterworth_prototype(order):
    """The analog Butterworth prototype's poles (cut-off 1 rad/s, left half plane)."""
    m = np.arange(1 - order, order, 2)
    return -np.exp(1j * np.pi * m / (2 * order))


def _prewarped(frequency_Hz, T_s):
    """The analog angular frequency [rad/s] the bilinear transform maps onto ``frequency_Hz``."""
    return 2.0 / T_s * math.tan(math.pi * frequency_Hz * T_s)


def _bilinear_sos(poles, gain, zeros_at_plus_one, T_s):
    """SOS rows of the analog filter ``gain`` · s^zeros_at_plus_one / Π(s − poles) after the bilinear transform:
    analog zeros at 0 land on z = +1, those at infinity on z = −1; each section takes a conjugate pair (or two
    real poles) and two zeros, +1 ones first; the gain rides on the first section, the sections ordered by their
    poles' distance from the unit circle, farthest first (as scipy's zpk2sos)."""
    fs2 = 2.0 / T_s
    z_poles = (fs2 + poles) / (fs2 - poles)
    k = gain * fs2 ** zeros_at_plus_one / np.prod(fs2 - poles)
    zeros = [1.0] * zeros_at_plus_one + [-1.0] * (len(poles) - zeros_at_plus_one)
    complex_upper = sorted((p for p in z_poles if p.imag > 1e-12 * abs(p)), key=abs)
    real = sorted((p.real for p in z_poles if abs(p.imag) <= 1e-12 * abs(p)), key=abs)
    pairs = [(p, p.conjugate()) for p in complex_upper]
    pairs += [(real[i], real[i + 1]) if i + 1 < len(real) else (real[i],) for i in range(0, len(real), 2)]
    pairs.sort(key=lambda pair: max(abs(p) for p in pair))
    rows = []
    for pair in pairs:
        taken, zeros = zeros[:len(pair)], zeros[len(pair):]
        b = np.real(np.poly(taken))
        a = np.real(np.poly(pair))
        rows.append(np.concatenate([np.pad(b, (0, 3 - b.size)), np.pad(a, (0, 3 - a.size))]))
    sos = np.array(rows)
    sos[0, :3] *= np.real(k)
    return sos


def butterworth_lowpass(order, cutoff_Hz, T_s):
    """Digital Butterworth low-pass (bilinear transform, pre-warped), as SOS rows."""
    warped = _prewarped(cutoff_Hz, T_s)
    return _bilinear_sos(warped * _butterworth_prototype(order), warped ** order, 0, T_s)


def butterworth_bandpass(order, low_Hz, high_Hz, T_s):
    """Digital Butterworth band-pass; ``order`` is the prototype order, as in Wang §III-A."""
    low, high = _prewarped(low_Hz, T_s), _prewarped(high_Hz, T_s)
    bandwidth, centre = high - low, math.sqrt(low * high)
    half = _butterworth_prototype(order) * bandwidth / 2.0
    root = np.sqrt(half ** 2 - centre ** 2)
    return _bilinear_sos(np.concatenate([half + root, half - root]), bandwidth ** order, order, T_s)


def first_order_lowpass(T_f, T_s):
    """1/(s T_f + 1) by the bilinear transform, as one SOS row."""
    b = T_s / (T_s + 2.0 * T_f)
    return np.array([[b, b, 0.0, 1.0, (T_s - 2.0 * T_f) / (T_s + 2.0 * T_f), 0.0]])


def notch(frequency_Hz, quality, T_s):
    """Second-order IIR notch (one SOS row; scipy's ``iirnotch``: −3 dB width frequency/quality); at the Nyquist
    frequency the mean of two samples, which a carrier alternating every sample (hf_estimator.square_wave) cannot
    pass."""
    if frequency_Hz * T_s >= 0.5:
        return np.array([[0.5, 0.5, 0.0, 1.0, 0.0, 0.0]])
    w0 = 2.0 * math.pi * frequency_Hz * T_s
    gain = 1.0 / (1.0 + math.tan(w0 / quality / 2.0))
    return np.array([[gain, -2.0 * gain * math.cos(w0), gain, 1.0, -2.0 * gain * math.cos(w0), 2.0 * gain - 1.0]])


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
