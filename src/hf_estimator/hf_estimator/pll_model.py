"""Szabó & Veszprémi §2.4: the dynamic model of the synchronous-injection PLL, for tuning its PI.

The loop (Fig. 4): angle error → G_1 = 1 (Eq. 23, sin α cos α ≈ α) → process G_p(s) (Eq. 34-37, the
envelope of the q̂ HF current when the d- and q-direction R-L circuits are hit by a sine step, Eq. 24-33)
→ gain K (Eq. 38) → loop filter 1/(sT_f + 1) → PI A_p(1 + 1/(sT_i)) (Eq. 22) → integrator 1/s → θ̂.
Eq. (39) writes the open loop as G_o = −K·A_p(…)·G_p/(sT_f+1)/s. K (Eq. 38) is negative here
(sin(φ_d + φ*) ≈ sin(−π/2) for inductive circuits), so −K = |K| and ``open_loop`` returns
L(s) = |K|·A_p(1 + 1/(sT_i))·G_p(s)/(s(sT_f + 1)), read with the usual negative feedback.
"""
import cmath
import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import brentq


@dataclass(frozen=True)
class PllProcess:
    """G_p(s) = (p1 s² + p2 s + p3)/((s − λ_d)(s − λ_q)) and K of Eq. (34)-(38)."""

    p1: float
    p2: float
    p3: float
    lambda_d: float
    lambda_q: float
    K: float
    c_S: float
    """c of Eq. (30): |1/z_d − 1/z_q| at ω_h, the DC gain of G_p [S]."""
    phi_star_rad: float

    def G_p(self, s):
        return (self.p1 * s * s + self.p2 * s + self.p3) / ((s - self.lambda_d) * (s - self.lambda_q))


def pll_process(R_ohm, L_d_H, L_q_H, f_h_Hz, u_h_V, u_star):
    """G_p and K from the motor's R, L_d, L_q and the injection (Szabó Eq. 24-38). ValueError for a
    round rotor (L_d = L_q): the q̂ current then carries no angle information (§2.3, case 2)."""
    if L_d_H == L_q_H:
        raise ValueError(f"L_d = L_q = {L_d_H:g} H: no saliency, so the PLL has no angle signal to track")
    omega_h = 2.0 * math.pi * f_h_Hz
    y_d, y_q = 1.0 / complex(R_ohm, omega_h * L_d_H), 1.0 / complex(R_ohm, omega_h * L_q_H)
    i_d, phi_d = abs(y_d), cmath.phase(y_d)
    i_q, phi_q = abs(y_q), cmath.phase(y_q)
    c = math.sqrt(i_d ** 2 + i_q ** 2 - 2.0 * i_d * i_q * math.cos(phi_q - phi_d))  # Eq. (30)
    phi_star = math.atan(-i_q * math.sin(phi_q - phi_d) / (i_d + i_q * math.cos(phi_q - phi_d)))  # Eq. (31)
    lambda_d, lambda_q = -R_ohm / L_d_H, -R_ohm / L_q_H  # Eq. (25)
    S = math.sin(phi_d + phi_star)
    a, b = i_d * math.sin(phi_d) / S, i_q * math.sin(phi_q) / S  # Eq. (33)
    p1 = -a + b + c  # Eq. (35)
    p2 = a * lambda_q - b * lambda_d - c * lambda_d - c * lambda_q  # Eq. (36)
    p3 = c * lambda_d * lambda_q  # Eq. (37)
    K = 0.5 * u_h_V * u_star * S  # Eq. (38)
    return PllProcess(p1, p2, p3, lambda_d, lambda_q, K, c, phi_star)


def open_loop(process, A_p, T_i_s, T_f_s, omega):
    """L(jω) of the PLL (Eq. 39, sign as in the module docstring) at the angular frequencies ω."""
    s = 1j * np.asarray(omega, dtype=float)
    return abs(process.K) * A_p * _pi(s, T_i_s) * process.G_p(s) / (s * (s * T_f_s + 1.0))


def _pi(s, T_i_s):
    """1 + 1/(sT_i); 1 for T_i = ∞ (a P controller)."""
    return 1.0 if math.isinf(T_i_s) else 1.0 + 1.0 / (s * T_i_s)


@dataclass(frozen=True)
class Margins:
    crossover_rad_s: float
    phase_margin_deg: float
    gain_margin_dB: float
    """∞ when the phase never reaches −180° (no phase crossover)."""


def margins(process, A_p, T_i_s, T_f_s, omega_max=1e6):
    """Gain crossover, phase margin and gain margin of the PLL loop."""
    def magnitude_minus_one(w):
        return abs(open_loop(process, A_p, T_i_s, T_f_s, w)) - 1.0

    crossover = brentq(magnitude_minus_one, 1e-3, omega_max)
    phase_margin = 180.0 + math.degrees(loop_phase(process, A_p, T_i_s, T_f_s, crossover))
    grid = np.logspace(-1, math.log10(omega_max), 20000)
    phase = loop_phase(process, A_p, T_i_s, T_f_s, grid)
    below = np.nonzero(phase <= -math.pi)[0]
    if below.size == 0:
        return Margins(crossover, phase_margin, math.inf)
    w180 = brentq(lambda w: loop_phase(process, A_p, T_i_s, T_f_s, w) + math.pi,
                  grid[max(below[0] - 1, 0)], grid[below[0]])
    gain_margin = -20.0 * math.log10(abs(open_loop(process, A_p, T_i_s, T_f_s, w180)))
    return Margins(crossover, phase_margin, gain_margin)


def loop_phase(process, A_p, T_i_s, T_f_s, omega):
    """Phase of L(jω) from its factors (so it is continuous): PI, integrator, G_p, T_f."""
    w = np.asarray(omega, dtype=float)
    s = 1j * w
    pi_phase = np.angle(_pi(s, T_i_s))
    plant = np.angle(process.p1 * s * s + process.p2 * s + process.p3) - np.angle(s - process.lambda_d) \
        - np.angle(s - process.lambda_q)
    return pi_phase - math.pi / 2.0 + plant - np.arctan(w * T_f_s)


def tune_pi(process, T_f_s, phase_margin_deg, crossover_rad_s):
    """A_p and T_i putting the crossover at ``crossover_rad_s`` with ``phase_margin_deg``: the PI's
    phase lag −atan(1/(ω_c T_i)) makes up the margin, its gain the magnitude. ValueError when the loop
    without PI already has less margin than asked (a PI only takes phase away)."""
    w = crossover_rad_s
    rest = loop_phase(process, 1.0, math.inf, T_f_s, w)
    lag = -math.pi + math.radians(phase_margin_deg) - rest
    if lag >= 0.0:
        available = 180.0 + math.degrees(rest)
        raise ValueError(f"--phase-margin: {phase_margin_deg:g}° at {w:g} rad/s is not reachable with a PI; "
                         f"the loop without it has {available:.1f}°")
    T_i = 1.0 / (w * math.tan(-lag))
    A_p = 1.0 / abs(open_loop(process, 1.0, T_i, T_f_s, w))
    return A_p, T_i


def highest_crossover(process, T_f_s, phase_margin_deg, pi_zero_ratio=10.0, omega_max=1e6):
    """The highest crossover where ``phase_margin_deg`` holds with the PI zero ``pi_zero_ratio`` below it
    (a PI lag of atan(1/ratio))."""
    lag = math.atan(1.0 / pi_zero_ratio)

    def excess(w):
        phase = loop_phase(process, 1.0, math.inf, T_f_s, w) - lag
        return 180.0 + math.degrees(phase) - phase_margin_deg

    grid = np.logspace(0, math.log10(omega_max), 4000)
    values = np.array([excess(w) for w in grid])
    if values[0] <= 0.0:
        raise ValueError(f"--phase-margin: {phase_margin_deg:g}° is not reachable at any crossover")
    last = np.nonzero(values > 0.0)[0][-1]
    if last == len(grid) - 1:
        return grid[-1]
    return brentq(excess, grid[last], grid[last + 1])
