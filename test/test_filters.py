"""The closed-form filter designs (drive_common.math.filters) against scipy.signal's, over a random draw of orders,
frequencies and sampling periods: the same frequency response, and sections the kernel runs stably."""
import math

import numpy as np
import pytest
from scipy import signal

from drive_common.math import filters

pytestmark = pytest.mark.unit
DRAWS = 200
RESPONSE_TOLERANCE = 1e-9
"""Largest difference of the complex frequency responses (gain 1 in the pass band): rounding only."""


def response(sos):
    return signal.sosfreqz(sos, worN=np.linspace(1e-3, math.pi * 0.999, 1000))[1]


def draws():
    rng = np.random.default_rng(20261129)
    for _ in range(DRAWS):
        T_s = 10 ** rng.uniform(-5.3, -3.3)
        yield rng, T_s, 1.0 / T_s


def test_butterworth_low_and_band_pass_respond_as_scipys():
    for rng, T_s, fs in draws():
        order = int(rng.integers(1, 7))
        cutoff = fs * 10 ** rng.uniform(-3.0, math.log10(0.45))
        ours = filters.butterworth_lowpass(order, cutoff, T_s)
        assert ours.shape == ((order + 1) // 2, 6)
        scipys = signal.butter(order, cutoff, fs=fs, output="sos")
        assert np.max(np.abs(response(ours) - response(scipys))) < RESPONSE_TOLERANCE, (order, cutoff, fs)
        order = int(rng.integers(1, 5))
        low = fs * 10 ** rng.uniform(-3.0, math.log10(0.3))
        high = min(low * 10 ** rng.uniform(0.05, 1.5), 0.49 * fs)
        ours = filters.butterworth_bandpass(order, low, high, T_s)
        assert ours.shape == (order, 6)
        scipys = signal.butter(order, [low, high], btype="bandpass", fs=fs, output="sos")
        assert np.max(np.abs(response(ours) - response(scipys))) < RESPONSE_TOLERANCE, (order, low, high)
        assert np.all(np.abs(np.roots(ours[-1, 3:])) < 1.0), "poles inside the unit circle"


def test_notch_and_first_order_lowpass_respond_as_scipys():
    for rng, T_s, fs in draws():
        frequency, quality = fs * rng.uniform(1e-3, 0.499), 10 ** rng.uniform(-0.5, 1.5)
        b, a = signal.iirnotch(frequency, quality, fs=fs)
        ours = filters.notch(frequency, quality, T_s)
        assert np.max(np.abs(response(ours) - response(signal.tf2sos(b, a)))) < RESPONSE_TOLERANCE
        T_f = 10 ** rng.uniform(-5.0, -1.0)
        b, a = signal.bilinear([1.0], [T_f, 1.0], fs=fs)
        ours = filters.first_order_lowpass(T_f, T_s)
        assert np.max(np.abs(response(ours) - response(signal.tf2sos(b, a)))) < RESPONSE_TOLERANCE


def test_a_notch_at_the_nyquist_frequency_is_the_mean_of_two_samples():
    z = np.zeros((1, 2))
    out = [filters.sos_step(filters.notch(5000.0, 2.0, 1e-4), z, (-1.0) ** k) for k in range(6)]
    assert out[1:] == pytest.approx([0.0] * 5, abs=1e-15)
