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

from drive_common.math.filters import sos_step
from drive_common.math.frames import clarke_contract

from .conventional import DEFAULTS, WangVariant, make_wang, wang_answer
from .interface import register


@njit(cache=True, _nrt=False)
def improved_step(x, p, k, sample, out):
    """One sample (interface.py) → ``out``: θ̂_e, ω̂_e = the PI integrator, the injection, ε [A] of Eq. 22,
    signal |Δ̂| [1/H], the start-up's state. State x (pulsating.py): its filters are the α and the β
    low-pass; p: WangParams."""
    t = k * p.T_s_s
    z = x.filters
    i_alpha, i_beta = clarke_contract(sample.i_a, sample.i_b, sample.i_c)
    modulation = p.demodulation_amplitude * math.sin(p.omega_h_rad_s * t + p.demodulation_phase_rad)
    i_alpha_l = sos_step(p.lowpass, z[0], i_alpha * modulation)
    i_beta_l = sos_step(p.lowpass, z[1], i_beta * modulation)
    eps = i_beta_l * math.cos(x.theta) - i_alpha_l * math.sin(x.theta)
    wang_answer(x, p, k, sample, out, i_alpha, i_beta, eps)


@register("improved", "d̂ injection, αβ × 2 sin ω_h t, 300 Hz low-pass, two-phase PLL (faithful)",
          "Wang et al. 2019, §III, Fig. 3, 5(b), 6, Eq. (16)-(24)")
def make_improved(nameplate, T_s, settings, commissioning, inverter):
    defaults = {**DEFAULTS, "pll_bandwidth_Hz": 10.0}
    return make_wang(WangVariant("improved", improved_step, defaults, bandpass_used=False), nameplate, settings, T_s,
                     commissioning, inverter)


@register("improved_aligned", "improved with its demodulation carrier in phase with the sampled HF current "
                             "(ours: the paper's method as it performs when tuned)",
          "Wang et al. 2019, §III; the carrier alignment is ours (docs/pll-tuning.md)")
def make_improved_aligned(nameplate, T_s, settings, commissioning, inverter):
    defaults = {**DEFAULTS, "pll_bandwidth_Hz": 10.0, "demodulation": "aligned"}
    return make_wang(WangVariant("improved_aligned", improved_step, defaults, bandpass_used=False), nameplate,
                     settings, T_s, commissioning, inverter)
