"""``conventional`` — Wang et al. 2019 §II (Fig. 2, Eq. 7-11), pulsating sinusoidal injection
U_h cos ω_h t on the estimated d̂ axis: î_q → 4th-order Butterworth band-pass (600-1200 Hz) → × 2 sin ω_h t
→ low-pass → PI tracking loop. This module also holds what ``improved`` (§III) shares with it.

Where the paper is silent: the low-pass is 2nd-order Butterworth; the band-pass is scipy's Butterworth
band-pass of prototype order 2 (overall order 4); the carriers are evaluated at the sampling instant
(no delay compensation, as in the paper). The speed handed to the speed loop is the PI's integrator
state: the PI output carries the fundamental current that ×2 sin ω_h t moves to ω_h and the low-pass
passes (docs/hf-demodulation.md §3), and fed to the speed loop it destabilised every closed-loop run.
PLL bandwidth 20 Hz. The PI gains place the linearised loop (Eq. 24) at the requested bandwidth for
the physical gain ε ≈ 2(U_h/ω_h)Δ·(θ − θ̂), Δ = ½(1/L_dh − 1/L_qh), from the commissioned HF
inductances: Eq. (22)'s k_h = U_h/(ω_h L_dh) is not the slope of ε (it is zero on a round rotor, see
docs/hf-demodulation.md §1), and tuning for it would measure a mistuning rather than the method. With no
commissioned saliency (|Δ|/Σ below 1 %, ``Commissioning.salient``; or L_dh > L_qh, which the method
does not assume) there is nothing to lock to: the gains are zero. Settings A_p and T_i_s (from
`drive tune pll`) replace that rule by k_p = A_p, k_i = A_p/T_i.
"""
import math
from collections.abc import Callable
from typing import NamedTuple

import numpy as np
from numba import njit

from drive_common.contract.settings import shown
from drive_common.math.filters import butterworth_bandpass, butterworth_lowpass
from drive_common.math.frames import clarke_contract

from .admittance_monitor import MonitorParams, make_monitor
from .interface import Estimator, check_settings, register
from .outputs import write_injecting_estimate
from .pll_model import aligned_demodulation_phase
from .pulsating import (
    pulsating_state,
    pulsating_track_and_inject,
    q_axis_demodulation,
)
from .startup import DEFAULTS as STARTUP_DEFAULTS
from .startup import make_startup, startup_step
from .startup_state import StartupParams
from .tracking_loop import loop_gains

DEFAULTS = {"frequency_Hz": 900.0, "amplitude_V": 5.0, "demodulation_amplitude": 2.0,
            "lowpass_Hz": 300.0, "lowpass_order": 2, "bandpass_Hz": [600.0, 1200.0],
            "bandpass_order": 2, "pll_bandwidth_Hz": 20.0, "pll_damping": 0.8, "A_p": None, "T_i_s": None,
            "observable_ratio": 0.02, "demodulation": "paper", **STARTUP_DEFAULTS}
DEMODULATIONS = ("paper", "aligned")
"""``demodulation``: the paper's carrier, evaluated at the sampling instant; or ``aligned`` (ours): turned
by the lag of the sampled HF current (command delay, zero-order hold, R-L, band-pass) so that the
demodulation keeps its whole gain (pll_model.aligned_demodulation_phase)."""


class WangParams(NamedTuple):
    T_s_s: float
    omega_h_rad_s: float
    injection_amplitude_V: float
    demodulation_amplitude: float
    demodulation_phase_rad: float
    kp: float
    ki: float
    lowpass: np.ndarray
    bandpass: np.ndarray
    monitor: MonitorParams
    startup: StartupParams


@njit(cache=True, _nrt=False)
def conventional_step(x, p, k, sample, out):
    """One sample (interface.py) → ``out``: θ̂_e, ω̂_e = the PI integrator, the injection, ε [A], signal
    |Δ̂| [1/H], the start-up's state. State x (pulsating.py): its filters are the band-pass and the
    low-pass; p: WangParams."""
    t = k * p.T_s_s
    i_alpha, i_beta = clarke_contract(sample.i_a, sample.i_b, sample.i_c)
    eps = q_axis_demodulation(x.filters, p.bandpass, p.lowpass, i_alpha, i_beta, x.theta,
                              p.demodulation_amplitude, math.sin(p.omega_h_rad_s * t + p.demodulation_phase_rad))
    wang_answer(x, p, k, sample, out, i_alpha, i_beta, eps)


@njit(cache=True, _nrt=False)
def wang_answer(x, p, k, sample, out, i_alpha, i_beta, eps):
    """What ``conventional`` and ``improved`` do with their ε: track it, monitor the admittance, inject
    U_h cos ω_h t on the new d̂ (Wang Eq. 7), supervise the start-up, answer θ̂ and the PI integrator."""
    t = k * p.T_s_s
    _, u_alpha, u_beta, signal, observable = pulsating_track_and_inject(
        x, p, k, (i_alpha, i_beta), math.cos(p.omega_h_rad_s * t), eps)
    u_alpha, u_beta, state = startup_step(x, p.startup, k, sample, (i_alpha, i_beta), (u_alpha, u_beta),
                                          eps, observable)
    write_injecting_estimate(out, x.theta, x.omega, (u_alpha, u_beta), eps, signal, state, p.injection_amplitude_V)


def demodulation_phase(name, demodulation, commissioning, T_s, delay_periods, f_h, bandpass):
    """The demodulation carrier's phase [rad] for the setting ``demodulation`` (DEMODULATIONS) of
    estimator ``name``; ValueError naming the setting for another value."""
    if demodulation not in DEMODULATIONS:
        raise ValueError(f"estimator {name}: setting demodulation: {shown(demodulation)} is not one of "
                         f"{', '.join(DEMODULATIONS)}")
    if demodulation == "paper":
        return 0.0
    return aligned_demodulation_phase(commissioning.R_s_ohm, commissioning.L_dh_H, commissioning.L_qh_H, T_s,
                                      delay_periods, 2.0 * math.pi * f_h, bandpass)


class WangVariant(NamedTuple):
    """One of Wang's estimators: its registered name, step kernel and default settings; ``bandpass_used``: the
    band-pass precedes the demodulation (not in ``improved``)."""

    name: str
    step: Callable
    defaults: dict
    bandpass_used: bool = True


def make_wang(variant, nameplate, settings, T_s, commissioning, inverter):
    """A Wang estimator (``conventional``, ``improved`` or their aligned variants: WangVariant) with its
    settings."""
    name, step, defaults, bandpass_used = variant
    s = check_settings(name, settings, defaults, T_s)
    f_h, injection_amplitude_V = float(s["frequency_Hz"]), float(s["amplitude_V"])
    gain = s["demodulation_amplitude"] * injection_amplitude_V * commissioning.delta / (2.0 * math.pi * f_h)
    salient = gain > 0.0 and commissioning.salient()
    kp, ki = loop_gains(gain, s["pll_bandwidth_Hz"], s["pll_damping"]) if salient else (0.0, 0.0)
    if (s["A_p"] is None) != (s["T_i_s"] is None):
        raise ValueError("A_p and T_i_s go together (both from `drive tune pll`, or neither)")
    if s["A_p"] is not None:
        kp, ki = float(s["A_p"]), float(s["A_p"]) / float(s["T_i_s"])
    low, high = s["bandpass_Hz"]
    bandpass = butterworth_bandpass(s["bandpass_order"], low, high, T_s)
    delay_periods = inverter.delay_periods
    phase = demodulation_phase(name, s["demodulation"], commissioning, T_s, delay_periods, f_h,
                               bandpass if bandpass_used else np.zeros((0, 6)))
    monitor = make_monitor(T_s, injection_amplitude_V, f_h, delay_periods, commissioning, s["observable_ratio"])
    startup = make_startup(nameplate, commissioning, T_s, inverter, gain if salient else 0.0, s)
    params = WangParams(
        T_s_s=T_s, omega_h_rad_s=2.0 * math.pi * f_h, injection_amplitude_V=injection_amplitude_V,
        demodulation_amplitude=float(s["demodulation_amplitude"]), demodulation_phase_rad=phase, kp=kp, ki=ki,
        lowpass=butterworth_lowpass(s["lowpass_order"], s["lowpass_Hz"], T_s), bandpass=bandpass,
        monitor=monitor, startup=startup)
    return Estimator(name, step, params, pulsating_state(), f_h, float(s["pll_bandwidth_Hz"]))


@register("conventional", "d̂ injection, band-pass, q̂ demodulation, low-pass, PI (faithful)",
          "Wang et al. 2019, §II, Fig. 2, Eq. (7)-(11)")
def make_conventional(nameplate, T_s, settings, commissioning, inverter):
    return make_wang(WangVariant("conventional", conventional_step, DEFAULTS), nameplate, settings, T_s,
                     commissioning, inverter)


@register("conventional_aligned", "conventional with its demodulation carrier in phase with the sampled q̂ "
                                 "current (ours: the paper's method as it performs when tuned)",
          "Wang et al. 2019, §II; the carrier alignment is ours (docs/pll-tuning.md)")
def make_conventional_aligned(nameplate, T_s, settings, commissioning, inverter):
    variant = WangVariant("conventional_aligned", conventional_step, {**DEFAULTS, "demodulation": "aligned"})
    return make_wang(variant, nameplate, settings, T_s, commissioning, inverter)
