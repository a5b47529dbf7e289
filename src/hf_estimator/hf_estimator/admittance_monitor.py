"""The HF admittance monitor: measures the angle-information strength |Δ̂| for the pulsating-injection
estimators by correlating current steps with the applied injection in its own frame."""
import math
from typing import NamedTuple

from numba import njit

from control_math.frames import rotate


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


# Monitor state layout inside an estimator's x, from a base offset.
MON_PREV_IA, MON_PREV_IB, MON_SUM_D, MON_SUM_Q, MON_SUM_C2, MON_DELTA, MON_COUNT = range(7)
MON_HISTORY = 7
"""Then three ring buffers: issued injection (carrier, angle) per sample, and products (d, q, c²)."""


def monitor_size(p):
    return MON_HISTORY + 2 * (p.delay_periods + 2) + 3 * p.window


@njit(cache=True)
def monitor_step(x, base, p, k, i_alpha, i_beta, carrier_now, angle_now):
    """Update with sample k's currents; record the injection issued now (carrier value c and axis angle).

    The current step i[k] − i[k−1] answers the voltage applied during period k−1, i.e. the injection
    issued at sample k−1−delay. Rotated into that injection's frame and correlated with its carrier
    over one carrier period, it gives D = Σ + Δ cos 2e (in-phase) and Q = Δ sin 2e (quadrature) [1/H],
    e = θ − θ_inj. Returns (|Δ̂| smoothed [1/H], observable flag). State in x from ``base``: MON_PREV_IA
    .. MON_COUNT, then the ring of issued (carrier, angle) × (delay + 2) and the product ring (d, q, c²) ×
    window (monitor_size)."""
    hist = base + MON_HISTORY
    depth = p.delay_periods + 2
    ring = hist + 2 * depth
    slot_now = k % depth
    slot_then = (k - 1 - p.delay_periods) % depth
    carrier_then = x[hist + 2 * slot_then]
    angle_then = x[hist + 2 * slot_then + 1]
    d_alpha = i_alpha - x[base + MON_PREV_IA]
    d_beta = i_beta - x[base + MON_PREV_IB]
    x[base + MON_PREV_IA] = i_alpha
    x[base + MON_PREV_IB] = i_beta
    x[hist + 2 * slot_now] = carrier_now
    x[hist + 2 * slot_now + 1] = angle_now
    if k < p.delay_periods + 1:
        return 0.0, 0.0
    step_d, step_q = rotate(d_alpha, d_beta, -angle_then)
    scale = 1.0 / (p.T_s_s * p.injection_amplitude_V)
    prod_d = carrier_then * step_d * scale
    prod_q = carrier_then * step_q * scale
    c2 = carrier_then * carrier_then
    slot = k % p.window
    x[base + MON_SUM_D] += prod_d - x[ring + 3 * slot]
    x[base + MON_SUM_Q] += prod_q - x[ring + 3 * slot + 1]
    x[base + MON_SUM_C2] += c2 - x[ring + 3 * slot + 2]
    x[ring + 3 * slot] = prod_d
    x[ring + 3 * slot + 1] = prod_q
    x[ring + 3 * slot + 2] = c2
    x[base + MON_COUNT] += 1.0
    if x[base + MON_COUNT] < p.window or x[base + MON_SUM_C2] <= 0.0:
        return 0.0, 0.0
    D = x[base + MON_SUM_D] / x[base + MON_SUM_C2]
    Q = x[base + MON_SUM_Q] / x[base + MON_SUM_C2]
    delta = math.hypot(Q, D - p.sigma_hat)
    x[base + MON_DELTA] += p.smoothing * (delta - x[base + MON_DELTA])
    observable = 1.0 if x[base + MON_DELTA] > p.observable_ratio * p.sigma_hat else 0.0
    return x[base + MON_DELTA], observable


def make_monitor(T_s, injection_amplitude_V, f_h, delay_periods, commissioning, observable_ratio=0.02,
                 smoothing_Hz=20.0):
    return MonitorParams(T_s_s=T_s, injection_amplitude_V=injection_amplitude_V,
                         delay_periods=int(delay_periods), window=max(2, int(round(1.0 / (f_h * T_s)))),
                         sigma_hat=commissioning.sigma,
                         observable_ratio=observable_ratio,
                         smoothing=1.0 - math.exp(-2.0 * math.pi * smoothing_Hz * T_s))
