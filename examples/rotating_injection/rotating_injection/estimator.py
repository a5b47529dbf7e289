"""``rotating_injection``: rotating-carrier HF injection, P. L. Jansen and R. D. Lorenz, "Transducerless
position and velocity estimation in induction and salient AC machines", IEEE Trans. Ind. Appl. 31(2),
1995: a carrier U_h e^{jω_h t} turning in the stationary frame; a salient rotor answers with a negative-sequence
current whose phase carries 2θ_e.

Demodulated from current steps (as a sampled drive sees the carrier): over the period before sample k the
carrier that acted is u = U_h e^{jφ}, φ = ω_h T_s (k − 1 − d), d the drive's delay, and the step it drives is
Δi = T_s (Σ u + Δ e^{j2θ} ū) (Σ, Δ = ½(1/L_dh ± 1/L_qh), resistance and back-EMF left out at low speed).
Heterodyned, z = Δi e^{jφ} = T_s U_h (Σ e^{j2φ} + Δ e^{j2θ}); its mean over one carrier period (N samples,
f_h = f_s/N) keeps T_s U_h Δ e^{j2θ}. The error ε = Im(z̄ e^{−j2θ̂})/(T_s U_h Δ) = sin 2(θ − θ̂) drives a PI
tracking loop (gain 2 per rad). The drive's own start-up (alignment, polarity test, lock supervision) runs
after each step, as for every injecting estimator, through the plugin interface."""
import math
from typing import NamedTuple

import numpy as np
from numba import njit

from drive_common.math.frames import clarke_contract
from hf_estimator.interface import Estimator, check_settings, register
from hf_estimator.outputs import write_injecting_estimate
from hf_estimator.startup import DEFAULTS as STARTUP_DEFAULTS
from hf_estimator.startup import fresh_startup, make_startup, startup_step
from hf_estimator.startup_state import STARTUP, StartupParams
from hf_estimator.tracking_loop import loop_gains

MAX_CARRIER_SAMPLES = 64
DEFAULTS = {"frequency_Hz": 1000.0, "amplitude_V": 10.0, "pll_bandwidth_Hz": 20.0, "pll_damping": 0.8,
            **STARTUP_DEFAULTS}
ROTATING = np.dtype([("theta", np.float64), ("omega", np.float64), ("startup", STARTUP),
                     ("i_alpha", np.float64), ("i_beta", np.float64), ("z_re", np.float64, MAX_CARRIER_SAMPLES),
                     ("z_im", np.float64, MAX_CARRIER_SAMPLES), ("sum_re", np.float64), ("sum_im", np.float64),
                     ("integral", np.float64), ("started", np.float64)])
"""Its state: θ̂ [rad], ω̂ [rad/s], the start-up's record, the last currents (α, β) [A], the heterodyned
steps of the last carrier period and their sums [A], the PI integrator [rad/s], a started flag."""


class RotatingParams(NamedTuple):
    T_s_s: float
    omega_h_rad_s: float
    injection_amplitude_V: float
    carrier_samples: int
    delay_periods: int
    step_per_rad: float
    """T_s U_h Δ [A]: |z̄| of a salient rotor."""
    kp: float
    ki: float
    startup: StartupParams


@njit(cache=True)
def rotating_step(x, p, k, sample, out):
    """One sample (hf_estimator.interface) → ``out``: θ̂_e, ω̂_e, the next carrier, ε = sin 2(θ − θ̂),
    signal |z̄|/(T_s U_h |Δ|) (1 for the commissioned saliency), the start-up's state."""
    i_alpha, i_beta = clarke_contract(sample.i_a, sample.i_b, sample.i_c)
    n = p.carrier_samples
    slot = k % n
    phi = p.omega_h_rad_s * p.T_s_s * (k - 1 - p.delay_periods)
    d_alpha, d_beta = (i_alpha - x.i_alpha, i_beta - x.i_beta) if x.started else (0.0, 0.0)
    c, s = math.cos(phi), math.sin(phi)
    z_re, z_im = d_alpha * c - d_beta * s, d_alpha * s + d_beta * c
    x.sum_re += z_re - x.z_re[slot]
    x.sum_im += z_im - x.z_im[slot]
    x.z_re[slot], x.z_im[slot] = z_re, z_im
    x.i_alpha, x.i_beta, x.started = i_alpha, i_beta, 1.0
    mean_re, mean_im = x.sum_re / n, x.sum_im / n
    c2, s2 = math.cos(2.0 * x.theta), math.sin(2.0 * x.theta)
    eps = (mean_im * c2 - mean_re * s2) / p.step_per_rad if p.step_per_rad != 0.0 else 0.0
    signal = math.hypot(mean_re, mean_im) / abs(p.step_per_rad) if p.step_per_rad != 0.0 else 0.0
    x.integral += p.ki * eps * p.T_s_s
    x.omega = x.integral
    x.theta += (x.integral + p.kp * eps) * p.T_s_s
    angle = p.omega_h_rad_s * p.T_s_s * k
    u_alpha = p.injection_amplitude_V * math.cos(angle)
    u_beta = p.injection_amplitude_V * math.sin(angle)
    u_alpha, u_beta, state = startup_step(x, p.startup, k, sample, (i_alpha, i_beta), (u_alpha, u_beta), eps,
                                          signal > 0.5 and k >= n)
    write_injecting_estimate(out, x.theta, x.omega, (u_alpha, u_beta), eps, signal, state, p.injection_amplitude_V)


@register("rotating_injection", "rotating carrier U_h e^{jω_h t}, negative-sequence current steps heterodyned, "
          "PI tracking (a plugin: examples/rotating_injection)",
          "Jansen & Lorenz 1995, IEEE TIA 31(2)", injection_kind="rotating", excitation="carrier")
def make_rotating(nameplate, T_s, settings, commissioning, inverter):
    """The estimator for a motor known by its nameplate and commissioning record (hf_estimator.interface)."""
    s = check_settings("rotating_injection", settings, DEFAULTS, T_s)
    n = int(round(1.0 / (T_s * s["frequency_Hz"])))
    if not 2 < n <= MAX_CARRIER_SAMPLES:
        raise ValueError(f"estimator rotating_injection: frequency_Hz: {s['frequency_Hz']:g} Hz is "
                         f"{1.0 / (T_s * s['frequency_Hz']):.3g} samples per period; it needs 3 to "
                         f"{MAX_CARRIER_SAMPLES}")
    f_h, amplitude = 1.0 / (n * T_s), float(s["amplitude_V"])
    step_per_rad = T_s * amplitude * commissioning.delta
    salient = commissioning.salient() and step_per_rad != 0.0
    kp, ki = loop_gains(2.0, s["pll_bandwidth_Hz"], s["pll_damping"]) if salient else (0.0, 0.0)
    startup = make_startup(nameplate, commissioning, T_s, inverter, 2.0 if salient else 0.0, s)
    params = RotatingParams(T_s, 2.0 * math.pi * f_h, amplitude, n, int(inverter.delay_periods),
                            step_per_rad if salient else 0.0, kp, ki, startup)
    state = np.zeros(1, ROTATING)
    fresh_startup(state[0]["startup"])
    return Estimator("rotating_injection", rotating_step, params, state, f_h, float(s["pll_bandwidth_Hz"]))
