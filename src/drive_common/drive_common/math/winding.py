"""The drive's estimate of its winding's temperature from the currents it measures (I²t), and the stator
resistance of the warm winding (docs/protections.md): τ dΔT̂/dt = ΔT_rated (R̂_s(T̂)/R̂_s(T_a + ΔT_rated))
(|i|/I_rated)² − ΔT̂, R̂_s(T̂) of copper from the R_s measured at ambient. Shared by the drive's protections
(foc_controller.protection, which folds the current limit back on it) and the estimator node, which runs it
on the same currents for the R̂_s of its resistive drop. No rclpy."""
import math
from typing import NamedTuple

import numpy as np
from numba import njit

from drive_common.contract.settings import Key, read_keys

from .copper import copper_resistance
from .frames import clarke

WINDING_KEYS = (
    Key("thermal_time_constant_s", "s", 0.0, 1e5, default=300.0, doc="the winding's τ = R_th C_th"),
    Key("rise_at_rated_K", "K", 0.0, 500.0, default=80.0, doc="the winding's steady rise at rated current"),
    Key("ambient_degC", "°C", -60.0, 150.0, low_inclusive=True, default=40.0),
)
"""The winding's figures as a drive configuration's ``protection:`` gives them, declared once
(drive_common.contract.settings.Key); without them the drive assumes a winding rising 80 K at rated current in a
40 °C ambient, τ = 5 min."""
RISE_HAT, R_S_IN_USE = 0, 1
"""The winding state's layout (the first entries of foc_controller.protection's state): ΔT̂ [K]; the R̂_s
[Ω] handed to the estimators (0: the commissioned one)."""
R_S_STEP = 0.01
"""The estimators' resistive drop follows R̂_s(T̂) in steps of this share (a winding warmed by 2.5 K): a run
too short to warm it keeps the commissioned R_s."""


class WindingParams(NamedTuple):
    """The winding as the drive knows it (SI; temperatures in °C)."""

    T_s_s: float
    R_s_ohm: float
    """Stator resistance at the ambient temperature (commissioning or nameplate)."""
    rated_current_A: float
    thermal_time_constant_s: float
    rise_at_rated_K: float
    ambient_degC: float


def winding_params(rated_current_A, R_s_ohm, T_s, settings=None):
    """WindingParams of a motor with this rated current [A] and R_s at ambient [Ω], sampled every T_s [s];
    ``settings``: a drive configuration's ``protection:`` (its winding keys read through WINDING_KEYS, the
    others left to the caller)."""
    given = {key.name: settings[key.name] for key in WINDING_KEYS if key.name in (settings or {})}
    s = read_keys(given, WINDING_KEYS, "protection.")
    return WindingParams(T_s, R_s_ohm, rated_current_A, *(s[key.name] for key in WINDING_KEYS))


def winding_state():
    """A fresh winding state: at ambient, the commissioned R_s in use."""
    return np.zeros(2)


@njit(cache=True)
def resistance_at(p, T_degC):
    """R̂_s [Ω] at the winding temperature T [°C] (copper)."""
    return copper_resistance(p.R_s_ohm, p.ambient_degC, T_degC)


@njit(cache=True)
def winding_estimate(s, p):
    """(T̂ [°C], R̂_s [Ω]) of the winding state s."""
    T = p.ambient_degC + s[RISE_HAT]
    return T, resistance_at(p, T)


@njit(cache=True, _nrt=False)
def winding_block(s, p, currents, n):
    """n samples of phase currents (n × 3, measured [A]; a sample not finite is skipped) heat the winding
    estimate of the state s sample by sample; R̂_s moves R_S_IN_USE by steps of R_S_STEP. Returns T̂ [°C]."""
    R_rated = resistance_at(p, p.ambient_degC + p.rise_at_rated_K)
    for i in range(n):
        i_alpha, i_beta = clarke(currents[i, 0], currents[i, 1], currents[i, 2])
        if not (math.isfinite(i_alpha) and math.isfinite(i_beta)):
            continue
        R = winding_estimate(s, p)[1]
        heat = p.rise_at_rated_K * (R / R_rated) * (i_alpha * i_alpha + i_beta * i_beta) / p.rated_current_A ** 2
        s[RISE_HAT] += p.T_s_s / p.thermal_time_constant_s * (heat - s[RISE_HAT])
    T, R = winding_estimate(s, p)
    R_used = s[R_S_IN_USE] if s[R_S_IN_USE] > 0.0 else p.R_s_ohm
    if abs(R - R_used) > R_S_STEP * R_used:
        s[R_S_IN_USE] = R
    return T
