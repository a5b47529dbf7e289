"""``sensored``: passes the encoder's angle and speed through, injects nothing. It validates the plant
and the controller without an estimator in the loop."""
from typing import NamedTuple

import numpy as np
from numba import njit

from drive_common.contract.estimator_states import LEADER_ENCODER, TRACKING

from .interface import Estimator, check_settings, register


class SensoredParams(NamedTuple):
    n_p: int


SENSORED = np.dtype([("theta", np.float64), ("omega", np.float64)])
"""Its state: the last angle [rad] and speed [rad/s] passed through."""


@njit(cache=True, _nrt=False)
def sensored_step(x, p, k, sample, out):
    """One sample (interface.py) → ``out``: the encoder's θ_e, ω_e passed through, no injection, ε 0,
    signal 1, state tracking (an encoder needs no start-up)."""
    x.theta = sample.theta_e_encoder
    x.omega = sample.omega_e_encoder
    out.theta_e_hat = x.theta
    out.omega_e_hat = x.omega
    out.u_inj_alpha = 0.0
    out.u_inj_beta = 0.0
    out.eps = 0.0
    out.signal = 1.0
    out.state = TRACKING
    out.injection_amplitude = 0.0
    out.observer_weight = 0.0
    out.leader = LEADER_ENCODER


@register("sensored", "encoder pass-through (no injection): validates plant and controller", "none",
          injects=False, excitation="encoder",
          injection_kind="none")
def make_sensored(nameplate, T_s, settings, commissioning, inverter):
    check_settings("sensored", settings, {}, T_s)
    return Estimator("sensored", sensored_step, SensoredParams(nameplate.n_p), np.zeros(1, SENSORED), 0.0)
