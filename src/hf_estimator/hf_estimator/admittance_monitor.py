"""The HF admittance monitor: measures the angle-information strength |Δ̂| for the pulsating-injection
estimators by correlating current steps with the applied injection in its own frame."""
import math
from typing import NamedTuple

import numpy as np
from numba import njit

from drive_common.math.frames import rotate

from .interface import MAX_CARRIER_SAMPLES, MAX_DELAY_PERIODS, ring_capacity


class MonitorParams(NamedTuple):
    """HF admittance monitor: correlates current steps with the applied injection in its own frame."""

    T_s_s: float
    injection_amplitude_V: float
    delay_periods: int
    window: int
    """Samples averaged: one carrier period (rounded)."""
    sigma_hat: float
    """Commissioned Σ [1/H]: the in-phase admittance a round rotor would show."""
    observable_ratio: float
    """|Δ̂|/Σ̂ below this is reported as low observability."""
    smoothing: float
    """First-order smoothing factor per sample of the reported |Δ̂|."""


MONITOR = np.dtype([*[(name, np.float64) for name in ("prev_ia", "prev_ib", "sum_d", "sum_q", "sum_c2", "delta",
                                                      "count")],
                    ("issued", np.float64, (MAX_DELAY_PERIODS + 2, 2)),
                    ("products", np.float64, (MAX_CARRIER_SAMPLES, 3))])
"""The monitor's state: the previous currents [A], the sliding sums of the products (d, q, c²) and their
count, the smoothed |Δ̂| [1/H], the ring of issued injections (carrier, angle) of the last delay + 2
samples and the ring of products (d, q, c²) of one carrier period (the rings' first entries used)."""


@njit(cache=True, _nrt=False)
def monitor_step(m, p, k, i_alpha, i_beta, carrier_now, angle_now):
    """Update the monitor state ``m`` (monitor_dtype) with sample k's currents; record the injection
    issued now (carrier value c and axis angle).

    The current step i[k] − i[k−1] answers the voltage applied during period k−1, i.e. the injection
    issued at sample k−1−delay. Rotated into that injection's frame and correlated with its carrier
    over one carrier period, it gives D = Σ + Δ cos 2e (in-phase) and Q = Δ sin 2e (quadrature) [1/H],
    e = θ − θ_inj. Returns (|Δ̂| smoothed [1/H], observable flag)."""
    depth = p.delay_periods + 2
    then = m.issued[(k - 1 - p.delay_periods) % depth]
    carrier_then, angle_then = then[0], then[1]
    d_alpha = i_alpha - m.prev_ia
    d_beta = i_beta - m.prev_ib
    m.prev_ia = i_alpha
    m.prev_ib = i_beta
    now = m.issued[k % depth]
    now[0] = carrier_now
    now[1] = angle_now
    if k < p.delay_periods + 1:
        return 0.0, 0.0
    step_d, step_q = rotate(d_alpha, d_beta, -angle_then)
    scale = 1.0 / (p.T_s_s * p.injection_amplitude_V)
    prod_d = carrier_then * step_d * scale
    prod_q = carrier_then * step_q * scale
    c2 = carrier_then * carrier_then
    old = m.products[k % p.window]
    m.sum_d += prod_d - old[0]
    m.sum_q += prod_q - old[1]
    m.sum_c2 += c2 - old[2]
    old[0] = prod_d
    old[1] = prod_q
    old[2] = c2
    m.count += 1.0
    if m.count < p.window or m.sum_c2 <= 0.0:
        return 0.0, 0.0
    D = m.sum_d / m.sum_c2
    Q = m.sum_q / m.sum_c2
    delta = math.hypot(Q, D - p.sigma_hat)
    m.delta += p.smoothing * (delta - m.delta)
    observable = 1.0 if m.delta > p.observable_ratio * p.sigma_hat else 0.0
    return m.delta, observable


def make_monitor(T_s, injection_amplitude_V, f_h, delay_periods, commissioning, observable_ratio=0.02,
                 smoothing_Hz=20.0):
    window = max(2, int(round(1.0 / (f_h * T_s))))
    ring_capacity(window, delay_periods)
    return MonitorParams(T_s_s=T_s, injection_amplitude_V=injection_amplitude_V,
                         delay_periods=int(delay_periods), window=window,
                         sigma_hat=commissioning.sigma,
                         observable_ratio=observable_ratio,
                         smoothing=1.0 - math.exp(-2.0 * math.pi * smoothing_Hz * T_s))
