"""``improved`` — Wang et al. 2019 §III (Fig. 3, 5(b), 6, Eq. 16-24): the same d̂ injection as
``conventional``, then i_αβ × 2 sin ω_h t → low-pass (300 Hz), no band-pass → two-phase PLL with
ε = i_βl cos θ̂ − i_αl sin θ̂ (Eq. 22).

Where the paper is silent, as ``conventional`` (its module docstring), except the PLL bandwidth: 10 Hz.
Its ε carries Σ/Δ ≈ 15 times more leaked HF than signal (docs/hf-demodulation.md §2-3); at 20 Hz the
ripple in θ̂ and the current loop sustained an oscillation of several hundred Hz, and 10 Hz is the
fastest that held lock in our closed-loop runs.
"""
import math

from numba import njit

from control_math.filters import sos_step
from control_math.frames import clarke_contract
from drive_interface.estimator_states import LEADER_INJECTION

from .conventional import DEFAULTS, make_wang
from .interface import register
from .pulsating import INTEGRAL, THETA, pulsating_track_and_inject
from .startup import startup_step


@njit(cache=True)
def improved_step(x, z, p, k, i_a, i_b, i_c, u_applied_alpha, u_applied_beta, theta_e_encoder, omega_e_encoder):
    """One sample (interface.py): currents i_a, i_b, i_c [A] → (θ̂_e, ω̂_e = the PI integrator, u_inj_α,
    u_inj_β, ε [A] of Eq. 22, |Δ̂| [1/H], start-up state code). State x: θ̂, the PI integrator, the
    admittance monitor, the start-up (pulsating.py); z: the α low-pass z[0] and the β low-pass z[1];
    p: WangParams."""
    t = k * p.T_s_s
    i_alpha, i_beta = clarke_contract(i_a, i_b, i_c)
    modulation = p.demodulation_amplitude * math.sin(p.omega_h_rad_s * t + p.demodulation_phase_rad)
    i_alpha_l = sos_step(p.lowpass, z[0], i_alpha * modulation)
    i_beta_l = sos_step(p.lowpass, z[1], i_beta * modulation)
    eps = i_beta_l * math.cos(x[THETA]) - i_alpha_l * math.sin(x[THETA])
    _, u_alpha, u_beta, signal, observable = pulsating_track_and_inject(
        x, p.monitor, k, i_alpha, i_beta, math.cos(p.omega_h_rad_s * t), p.injection_amplitude_V, p.kp, p.ki, p.T_s_s,
        eps)
    u_alpha, u_beta, state = startup_step(x, p.startup, k, i_alpha, i_beta, u_applied_alpha, u_applied_beta, u_alpha,
                                          u_beta, eps, observable, theta_e_encoder)
    return (x[THETA], x[INTEGRAL], u_alpha, u_beta, eps, signal, state, p.injection_amplitude_V, 0.0,
            float(LEADER_INJECTION))


@register("improved", "d̂ injection, αβ × 2 sin ω_h t, 300 Hz low-pass, two-phase PLL (faithful)",
          "Wang et al. 2019, §III, Fig. 3, 5(b), 6, Eq. (16)-(24)")
def make_improved(nameplate, T_s, settings, commissioning, inverter):
    defaults = {**DEFAULTS, "pll_bandwidth_Hz": 10.0}
    return make_wang("improved", improved_step, defaults, nameplate, settings, T_s, commissioning, inverter,
                     bandpass_used=False)


@register("improved_aligned", "improved with its demodulation carrier in phase with the sampled HF current "
                             "(ours: the paper's method as it performs when tuned)",
          "Wang et al. 2019, §III; the carrier alignment is ours (docs/pll-tuning.md)")
def make_improved_aligned(nameplate, T_s, settings, commissioning, inverter):
    defaults = {**DEFAULTS, "pll_bandwidth_Hz": 10.0, "demodulation": "aligned"}
    return make_wang("improved_aligned", improved_step, defaults, nameplate, settings, T_s, commissioning,
                     inverter, bandpass_used=False)
