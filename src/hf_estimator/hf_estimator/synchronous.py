"""``synchronous`` — Szabó & Veszprémi §2.2-2.3: injection û_dh = u_h sin ω_h t on d̂ (Eq. 6, d̂ row
only, 'in most of the cases only û_dh is injected'), î_qh from the estimated frame (Eq. 15) through a
band-pass, phase detector × u* cos ω_h t (Eq. 20), first-order low-pass T_f (Eq. 21, 39), PI
A_p(1 + 1/(sT_i)) (Eq. 22) on the error 0 − î_qhf, and an integrator to θ̂.

Defaults are Table 2 (A_p 4853, T_i 136 ms, T_f 0.53 ms) with 1500 Hz, 40 V, u* = 1 (§3). Where the
paper is silent: the band-pass of Fig. 3 has no stated parameters; we use a 2nd-order Butterworth
band-pass from f_h/√2 to f_h·√2 (without one, the fundamental q current leaks through T_f at f_h into a
PI of gain 4853). The carriers are evaluated at the sampling instant (no delay compensation): at
1500 Hz and 10 kHz the sampled q̂ current lags the paper's by ω_h·1.5·T_s = 81°, so the phase detector
keeps cos 81° ≈ 0.16 of its gain (``pll_model`` carrier model). ``demodulation: aligned`` (ours, not the
paper's) turns the demodulation carrier by that lag, computed from the commissioned R_s, the commissioned
L_dh, L_qh, the band-pass and the inverter delay.
"""
import math
from typing import NamedTuple

import numpy as np
from numba import njit

from drive_common.math.filters import butterworth_bandpass, first_order_lowpass
from drive_common.math.frames import clarke_contract

from .admittance_monitor import MonitorParams, make_monitor
from .conventional import demodulation_phase
from .interface import Estimator, check_settings, register
from .outputs import write_injecting_estimate
from .pulsating import (
    pulsating_state,
    pulsating_track_and_inject,
    q_axis_demodulation,
)
from .startup import DEFAULTS as STARTUP_DEFAULTS
from .startup import make_startup, startup_step
from .startup_state import StartupParams

DEFAULTS = {"frequency_Hz": 1500.0, "amplitude_V": 40.0, "u_star": 1.0, "A_p": 4853.0,
            "T_i_s": 0.136, "T_f_s": 0.53e-3, "bandpass_ratio": math.sqrt(2.0),
            "observable_ratio": 0.02, "demodulation": "paper", **STARTUP_DEFAULTS}


class SynchronousParams(NamedTuple):
    T_s_s: float
    omega_h_rad_s: float
    injection_amplitude_V: float
    u_star: float
    kp: float
    ki: float
    lowpass: np.ndarray
    bandpass: np.ndarray
    demodulation_phase_rad: float
    monitor: MonitorParams
    startup: StartupParams


@njit(cache=True, _nrt=False)
def synchronous_step(x, p, k, sample, out):
    """One sample (interface.py) → ``out``: θ̂_e, ω̂_e = the PI output, the injection, ε = −î_qhf [A], signal
    |Δ̂| [1/H], the start-up's state. State x (pulsating.py): its filters are the band-pass and the T_f
    low-pass; p: SynchronousParams."""
    t = k * p.T_s_s
    i_alpha, i_beta = clarke_contract(sample.i_a, sample.i_b, sample.i_c)
    i_qhf = q_axis_demodulation(x.filters, p.bandpass, p.lowpass, i_alpha, i_beta, x.theta, p.u_star,
                                math.cos(p.omega_h_rad_s * t + p.demodulation_phase_rad))
    omega, u_alpha, u_beta, signal_strength, observable = pulsating_track_and_inject(
        x, p, k, (i_alpha, i_beta), math.sin(p.omega_h_rad_s * t), -i_qhf)
    u_alpha, u_beta, state = startup_step(x, p.startup, k, sample, (i_alpha, i_beta), (u_alpha, u_beta),
                                          -i_qhf, observable)
    write_injecting_estimate(out, x.theta, omega, (u_alpha, u_beta), -i_qhf, signal_strength, state,
                             p.injection_amplitude_V)


@register("synchronous", "d̂ sine injection, q̂ phase detector, T_f low-pass, PI (faithful; "
                        "demodulation: aligned is ours)", "Szabó & Veszprémi, §2.2-2.3, Eq. (6), (15)-(22), Table 2")
def make_synchronous(nameplate, T_s, settings, commissioning, inverter, name="synchronous", defaults=DEFAULTS):
    s = check_settings(name, settings, defaults, T_s)
    f_h, injection_amplitude_V = float(s["frequency_Hz"]), float(s["amplitude_V"])
    ratio = float(s["bandpass_ratio"])
    bandpass = butterworth_bandpass(1, f_h / ratio, min(f_h * ratio, 0.49 / T_s), T_s)
    delay_periods = inverter.delay_periods
    phase = demodulation_phase("synchronous", s["demodulation"], commissioning, T_s, delay_periods, f_h, bandpass)
    monitor = make_monitor(T_s, injection_amplitude_V, f_h, delay_periods, commissioning, s["observable_ratio"])
    gain = float(s["u_star"]) * injection_amplitude_V * commissioning.delta / (2.0 * math.pi * f_h)
    startup = make_startup(nameplate, commissioning, T_s, inverter, gain if commissioning.salient() else 0.0, s)
    params = SynchronousParams(
        T_s_s=T_s, omega_h_rad_s=2.0 * math.pi * f_h, injection_amplitude_V=injection_amplitude_V,
        u_star=float(s["u_star"]),
        kp=float(s["A_p"]), ki=float(s["A_p"]) / float(s["T_i_s"]),
        lowpass=first_order_lowpass(float(s["T_f_s"]), T_s),
        bandpass=bandpass, demodulation_phase_rad=phase,
        monitor=monitor, startup=startup)
    omega_n = math.sqrt(abs(gain) * params.ki)
    return Estimator(name, synchronous_step, params, pulsating_state(), f_h, omega_n / (2.0 * math.pi))


@register("synchronous_aligned", "synchronous with its demodulation carrier in phase with the sampled q̂ "
                                "current (ours: the paper's method as it performs when tuned)",
          "Szabó & Veszprémi, §2.2-2.3; the carrier alignment is ours (docs/pll-tuning.md)")
def make_synchronous_aligned(nameplate, T_s, settings, commissioning, inverter):
    return make_synchronous(nameplate, T_s, settings, commissioning, inverter, "synchronous_aligned",
                            {**DEFAULTS, "demodulation": "aligned"})
