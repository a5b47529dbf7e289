"""Kernels and design helpers shared by the estimators: the PI tracking loop, commissioning values and
the HF admittance monitor that measures angle-information strength for every estimator."""
import math
from typing import NamedTuple

import numpy as np
from numba import njit

from foc_controller.discrete import sos_step
from pmsm_plant.frames import rotate
from pmsm_plant.model import incremental_inductances, saturation_saliency_angle


@njit(cache=True)
def pi_tracking_loop(x, i_theta, i_integral, kp, ki, T_s, error):
    """PI + integrator (Wang Fig. 6, Szabó Fig. 3): ω_PI = k_p ε + ∫k_i ε, θ̂ = ∫ω_PI (state in x).

    Returns ω_PI; the integrator state x[i_integral] is the smoother speed estimate. Which one an
    estimator hands the speed loop is its choice: the proportional part carries the demodulation ripple
    (hundreds of rad/s behind a 300 Hz low-pass), which fed to the speed loop and the back-EMF
    decoupling closes an unstable loop through the estimator (shared/notes/hf-demodulation.md §3)."""
    x[i_integral] += T_s * ki * error
    omega = kp * error + x[i_integral]
    x[i_theta] += T_s * omega
    return omega


def loop_gains(gain_per_rad, bandwidth_Hz, damping):
    """PI gains (k_p, k_i) placing the linearised loop ε = g·(θ − θ̂) at ω_n = 2π·bandwidth, ζ:
    s² + g k_p s + g k_i (Wang Eq. 24 with k_h = g)."""
    omega_n = 2.0 * math.pi * bandwidth_Hz
    return 2.0 * damping * omega_n / gain_per_rad, omega_n ** 2 / gain_per_rad


class Commissioning(NamedTuple):
    """What a standstill HF commissioning test measures on the drive's motor: the HF inductances at no
    load, and how load current turns the saliency axis (rotor locked at a known angle, the current
    vector stepped along the q axis up to the current limit and swept a little about it, the HF
    admittance's axis recorded: the cross-saturation shift and how it depends on the d current)."""

    L_dh_H: float
    L_qh_H: float
    saliency_shift_i_q_A: np.ndarray
    """q currents of the tables [A] (uniform grid, ascending)."""
    saliency_shift_rad: np.ndarray
    """Saliency-axis angle from the rotor d axis at those currents [rad, electrical]."""
    convergence_slope: np.ndarray
    """d(saliency-axis angle)/d(rotor angle) with the current vector held still, at those currents:
    1 + i_q·∂δ/∂i_d [1]. It is the slope of every saliency tracker's error signal; at 0 the HF
    admittance no longer tells the rotor angle (the axis turns back as fast as the rotor turns)."""

    @property
    def sigma(self):
        """Σ = ½(1/L_dh + 1/L_qh) [1/H] (shared/notes/hf-demodulation.md)."""
        return 0.5 * (1.0 / self.L_dh_H + 1.0 / self.L_qh_H)

    @property
    def delta(self):
        """Δ = ½(1/L_dh − 1/L_qh) [1/H]."""
        return 0.5 * (1.0 / self.L_dh_H - 1.0 / self.L_qh_H)

    def tracking_current_limit_A(self, min_slope):
        """The largest table current |i_q| [A] up to which the convergence slope stays at or above
        ``min_slope`` on both signs of the current."""
        magnitude = np.abs(self.saliency_shift_i_q_A)
        failing = magnitude[self.convergence_slope < min_slope]
        inside = magnitude < failing.min() if failing.size else np.ones_like(magnitude, dtype=bool)
        return float(magnitude[inside].max())


MIN_CONVERGENCE_SLOPE = 0.75
"""Sensorless operation keeps the current where a saliency tracker keeps three quarters of its loop gain
(on `wang_spmsm`: 5.6 A, 1.22× rated; at 1.5× rated the slope is −0.2)."""


def commission(machine, i_q_max_A, points=65, d_sweep_A=0.01):
    """The standstill HF test's result on ``machine`` (ideal measurement): tables over ±i_q_max_A (the
    drive's current limit); the d current is swept by ±d_sweep_A about zero for the slope."""
    L_dh, L_qh, _ = incremental_inductances(machine)
    currents = np.linspace(-i_q_max_A, i_q_max_A, points)
    shift = np.array([saturation_saliency_angle(machine, 0.0, i_q) for i_q in currents])
    slope = np.array([1.0 + i_q * (saturation_saliency_angle(machine, d_sweep_A, i_q)
                                   - saturation_saliency_angle(machine, -d_sweep_A, i_q))
                      / (2.0 * d_sweep_A) for i_q in currents])
    return Commissioning(L_dh, L_qh, currents, shift, slope)


@njit(cache=True)
def commissioned_value(i_q, currents, table):
    """A commissioning table (e.g. the saliency shift) at q current i_q, interpolated linearly (held at
    its ends)."""
    n = currents.shape[0]
    if n == 0:
        return 0.0
    position = (i_q - currents[0]) / (currents[n - 1] - currents[0]) * (n - 1)
    if position <= 0.0:
        return table[0]
    if position >= n - 1:
        return table[n - 1]
    j = int(position)
    fraction = position - j
    return table[j] + fraction * (table[j + 1] - table[j])


class MonitorParams(NamedTuple):
    """HF admittance monitor: correlates current steps with the applied injection in its own frame."""

    T_s_s: float
    U_h_V: float
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
    e = θ − θ_inj. Returns (|Δ̂| smoothed, observable flag)."""
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
    scale = 1.0 / (p.T_s_s * p.U_h_V)
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


def make_monitor(T_s, U_h, f_h, delay_periods, commissioning, observable_ratio=0.02,
                 smoothing_Hz=20.0):
    return MonitorParams(T_s_s=T_s, U_h_V=U_h, delay_periods=int(delay_periods),
                         window=max(2, int(round(1.0 / (f_h * T_s)))), sigma_hat=commissioning.sigma,
                         observable_ratio=observable_ratio,
                         smoothing=1.0 - math.exp(-2.0 * math.pi * smoothing_Hz * T_s))


# State layout of the papers' pulsating-injection estimators: θ̂, the PI integrator, then the monitor.
THETA, INTEGRAL, MONITOR = 0, 1, 2


def check_injection_frequency(f_h, T_s):
    if not 0.0 < f_h < 0.5 / T_s:
        raise ValueError(f"frequency_Hz {f_h} must lie between 0 and Nyquist {0.5 / T_s} Hz")


def pulsating_state(monitor, theta_e0, omega_e0):
    """Fresh state for a pulsating-injection estimator with monitor parameters ``monitor``."""
    x = np.zeros(MONITOR + monitor_size(monitor))
    x[THETA] = theta_e0
    x[INTEGRAL] = omega_e0
    return x


@njit(cache=True)
def q_axis_demodulation(z, bandpass, lowpass, i_alpha, i_beta, theta, amplitude, carrier):
    """The q̂-axis demodulation of Wang §II (Eq. 8-11) and Szabó §2.3 (Eq. 15-21): î_q in the θ̂ frame →
    band-pass (state z[0]) → × amplitude·carrier → low-pass (state z[1])."""
    _, i_q = rotate(i_alpha, i_beta, -theta)
    return sos_step(lowpass, z[1], sos_step(bandpass, z[0], i_q) * amplitude * carrier)


@njit(cache=True)
def pulsating_track_and_inject(x, monitor, k, i_alpha, i_beta, carrier, U_h, kp, ki, T_s, error):
    """What the papers' methods do after demodulating ε: the PI tracking loop, the HF admittance
    monitor, and the next injection U_h·carrier along the new d̂ (Wang Eq. 7, Szabó Eq. 6).
    Returns (ω_PI, u_inj_α, u_inj_β, signal, observable)."""
    omega = pi_tracking_loop(x, THETA, INTEGRAL, kp, ki, T_s, error)
    signal, observable = monitor_step(x, MONITOR, monitor, k, i_alpha, i_beta, carrier, x[THETA])
    u_alpha, u_beta = rotate(U_h * carrier, 0.0, x[THETA])
    return omega, u_alpha, u_beta, signal, observable
