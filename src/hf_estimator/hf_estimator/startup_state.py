"""The start-up's state and parameters, shared by its jobs (docs/startup.md): STARTUP, the record it
keeps as the ``startup`` field of an estimator's state (whose ``theta`` and ``omega`` are θ̂ and ω̂),
StartupParams, and the moves every job makes: entering a state, turning or holding θ̂, counting a lost
lock."""
import math
from typing import NamedTuple

import numpy as np
from numba import njit

from drive_common.contract.estimator_states import LOCK_LOST
from drive_common.math.frames import rotate

STARTUP = np.dtype([(name, np.float64) for name in (
    "code", "entered", "refused", "restarts", "theta_held", "omega_held", "held_at",
    "settled", "error", "quiet",
    "score", "span", "tries", "polarity_ratio", "flipped", "other_current",
    "residual_d", "residual_q", "prev_ia", "prev_ib", "u_net_alpha", "u_net_beta", "bad", "e_alpha", "e_beta",
    "fit_n", "fit_t", "fit_p", "fit_tp", "fit_tt", "phi_raw", "phi_unwrapped",
    "axis_ref", "axis_sum", "axis_count", "torque_active", "moved", "pi_d", "pi_q", "charge", "first_turn",
    "axis_time", "axis_omega", "held_time", "held_omega", "doublet_at")])
"""The supervisor's: the state code, the sample it was entered at, why the start was refused, the lost
locks counted, θ̂ and ω̂ held (and since when); the alignment's: samples settled, the smoothed error
[rad], the quiet time's start + 1; the polarity test's: S, T, tries, S/T, whether θ̂ was turned by π and
the d̂ current the voltage beside its pulses drives (a linear winding's) [A]; the lock monitor's: the
back-EMF residual (θ̂ frame) [V], the previous currents, the voltage applied before this sample net of the
dead-time loss [V], samples beyond the threshold, the back-EMF (αβ) [V], and the lost-lock fit of its
angle (FIT sums, φ raw and unwrapped); the alignment's axis over its settled samples (the first θ̂, the sum of
θ̂ less it mod π, the count); the torque polarity test's (torque_polarity.py): a doublet under way, one done
awaiting the alignment after it (1: the first of a pair, 2: the mirrored one), its PI loop's integrators (d̂,
q̂) [V], the q̂ current summed over the doublet [A·samples], the first doublet's turn [rad]; the alignment's sums
of the sample index and of ω̂ over its settled samples, the held axis's mean sample and ω̂ [rad/s], the sample
of the doublet's middle."""
NOT_REFUSED, NO_SALIENCY, NO_POLARITY, TOO_MANY_LOSSES, ROTOR_MOVED, NO_SETTLED_AXIS, NO_MOTION = 0, 1, 2, 3, 4, 5, 6
"""Why a start-up was refused (its ``refused`` field)."""


class StartupParams(NamedTuple):
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
    other_decay: float
    other_gain: float
    """(a, b) of the linear winding the voltage beside the pulses drives: i ← a·i + b·u (winding_step)."""
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
    torque_pulse_A: float
    """The torque polarity test's first doublet current [A] (torque_polarity.py); 0: the saturation pulses."""
    torque_pulse_samples: int
    torque_pulse_max_A: float
    torque_growth: float
    torque_tries: int
    torque_margin_rad: float
    torque_gain_d: float
    torque_gain_q: float
    torque_integral: float
    torque_tail_samples: int
    torque_voltage_max_V: float
    torque_bound_shaft_deg: float
    torque_max_Nm: float


@njit(cache=True)
def enter(x, p, k, code):
    """Enter state ``code`` at sample k."""
    s = x.startup
    s.code = code
    s.entered = k
    s.settled = 0.0
    s.error = 1.0
    s.bad = 0.0


@njit(cache=True)
def turn(x, p, angle):
    """θ̂ turned by ``angle`` [rad]; the back-EMF residual, kept in the θ̂ frame, turned with it."""
    s = x.startup
    x.theta += angle
    s.residual_d, s.residual_q = rotate(s.residual_d, s.residual_q, -angle)


@njit(cache=True)
def hold(x, p, k):
    """Keep θ̂ at the held angle turning at the held speed, and the integrator at the held speed → θ̂."""
    s = x.startup
    x.omega = s.omega_held
    x.theta = s.theta_held + s.omega_held * (k - s.held_at) * p.T_s_s
    return x.theta


@njit(cache=True)
def lose_lock(x, p, k):
    """Enter LOCK_LOST at sample k, counting the loss → the state code."""
    enter(x, p, k, LOCK_LOST)
    x.startup.restarts += 1.0
    return float(LOCK_LOST)


@njit(cache=True)
def measured_backemf(x, p):
    """The back-EMF [V] the lock monitor measured (low-passed, θ̂ frame): its residual plus what ω̂ implies."""
    s = x.startup
    return math.hypot(s.residual_d, s.residual_q + x.omega * p.psi_f_Wb)


@njit(cache=True)
def backemf_clear(x, p, backemf_V):
    """Whether a back-EMF [V] stands clear enough of the lock threshold to tell motion and polarity."""
    return backemf_V > p.backemf_polarity_ratio * p.lock_threshold_V
