"""``sensored``: passes the encoder's angle and speed through, injects nothing. It validates the plant
and the controller without an estimator in the loop."""
from typing import NamedTuple

import numpy as np
from numba import njit

from drive_interface.estimator_states import LEADER_ENCODER

from .interface import Estimator, check_settings, register


class SensoredParams(NamedTuple):
    n_p: int


@njit(cache=True)
def sensored_step(x, z, p, k, i_a, i_b, i_c, u_applied_alpha, u_applied_beta, theta_e_encoder, omega_e_encoder):
    """One sample (interface.py): the encoder's θ_e, ω_e passed through, no injection, ε 0, signal 1,
    state tracking (an encoder needs no start-up). No state."""
    return theta_e_encoder, omega_e_encoder, 0.0, 0.0, 0.0, 1.0, 3.0, 0.0, 0.0, float(LEADER_ENCODER)


@register("sensored", "encoder pass-through (no injection): validates plant and controller", "none",
          injects=False, excitation="encoder",
          injection_kind="none")
def make_sensored(nameplate, T_s, settings, commissioning, inverter):
    check_settings("sensored", settings, {}, T_s)
    return Estimator("sensored", sensored_step, SensoredParams(nameplate.n_p),
                     np.zeros(1), np.zeros((1, 1, 2)), 0.0)
