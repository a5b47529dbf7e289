"""The start-up's state and parameters, shared by its jobs (docs/startup.md): the slots it keeps in an
estimator's x from ``p.base`` on, StartupParams, and the moves every job makes: entering a state, turning
or holding θ̂, counting a lost lock."""
from typing import NamedTuple

from numba import njit

from control_math.frames import rotate
from drive_interface.estimator_states import LOCK_LOST

(CODE, ENTERED, SETTLED, ERROR, THETA_HELD, INTEGRAL_HELD, SCORE, SPAN, TRIES, REFUSED, RESTARTS,
 RESIDUAL_D, RESIDUAL_Q, PREV_IA, PREV_IB, BAD, POLARITY_RATIO, FLIPPED, HELD_AT, QUIET, E_ALPHA,
 E_BETA, FIT_N, FIT_T, FIT_P, FIT_TP, FIT_TT, PHI_RAW, PHI_UNWRAPPED) = range(29)
"""Slots after p.base. The supervisor's: CODE, ENTERED, REFUSED, RESTARTS and the held θ̂ (THETA_HELD,
INTEGRAL_HELD, HELD_AT); the alignment's: SETTLED, ERROR, QUIET; the polarity test's: SCORE, SPAN, TRIES,
POLARITY_RATIO, FLIPPED; the lock monitor's: RESIDUAL_D/Q, PREV_IA/IB, BAD, E_ALPHA/BETA and the lost-lock
fit FIT_* and PHI_*."""
SLOTS = 29
THETA, INTEGRAL = 0, 1
"""Every estimator keeps θ̂ at x[0] and its speed integrator (ω̂) at x[1]."""
NOT_REFUSED, NO_SALIENCY, NO_POLARITY, TOO_MANY_LOSSES, ROTOR_MOVED = 0, 1, 2, 3, 4
"""Why a start-up was refused (REFUSED slot)."""


class StartupParams(NamedTuple):
    base: int
    """Index of the start-up state in the estimator's x."""
    T_s_s: float
    delay_periods: int
    error_gain: float
    """The estimator's ε per radian of angle error (0: it cannot align)."""
    align_tolerance_rad: float
    settle_samples: int
    align_timeout_samples: int
    quiet_samples: int
    error_smoothing: float
    pulse_samples: int
    pulse_V: float
    pulse_sequences: int
    polarity_margin: float
    polarity_linear_ratio: float
    """S/T that a linear R–L gives the pulses (polarity_test.linear_polarity_ratio), taken off the measured one."""
    polarity_tries: int
    flush_samples: int
    R_s_ohm: float
    L_dh_H: float
    L_qh_H: float
    delta_L_H: float
    """Nameplate L_d − L_q (the apparent saliency in the back-EMF's cross terms)."""
    psi_f_Wb: float
    dead_time_voltage_V: float
    dead_time_smoothing_A: float
    lock_smoothing: float
    lock_threshold_V: float
    lock_persist_samples: int
    lost_hold_samples: int
    max_restarts: int
    backemf_polarity_ratio: float
    polarity_from_recording: bool


@njit(cache=True)
def enter(x, p, k, code):
    """Enter state ``code`` at sample k."""
    b = p.base
    x[b + CODE] = code
    x[b + ENTERED] = k
    x[b + SETTLED] = 0.0
    x[b + ERROR] = 1.0
    x[b + BAD] = 0.0


@njit(cache=True)
def turn(x, p, angle):
    """θ̂ turned by ``angle`` [rad]; the back-EMF residual, kept in the θ̂ frame, turned with it."""
    b = p.base
    x[THETA] += angle
    x[b + RESIDUAL_D], x[b + RESIDUAL_Q] = rotate(x[b + RESIDUAL_D], x[b + RESIDUAL_Q], -angle)


@njit(cache=True)
def hold(x, p, k):
    """Keep θ̂ at the held angle turning at the held speed, and the integrator at the held speed → θ̂."""
    b = p.base
    x[INTEGRAL] = x[b + INTEGRAL_HELD]
    x[THETA] = x[b + THETA_HELD] + x[b + INTEGRAL_HELD] * (k - x[b + HELD_AT]) * p.T_s_s
    return x[THETA]


@njit(cache=True)
def lose_lock(x, p, k):
    """Enter LOCK_LOST at sample k, counting the loss → the state code."""
    enter(x, p, k, LOCK_LOST)
    x[p.base + RESTARTS] += 1.0
    return float(LOCK_LOST)


@njit(cache=True)
def backemf_clear(x, p, backemf_V):
    """Whether a back-EMF [V] stands clear enough of the lock threshold to tell motion and polarity."""
    return backemf_V > p.backemf_polarity_ratio * p.lock_threshold_V
