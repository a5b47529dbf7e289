"""The start-up's alignment (docs/startup.md; startup.py, item 1): the estimator's own tracker converges on
its own injection to the saliency axis (mod π). Aligned once its error, scaled to radians by the estimator's gain
and smoothed, has stayed below ``align_tolerance_rad`` (MOVING_TOLERANCE_FACTOR times more at speed) for
settle_samples. Not aligned within align_timeout_samples: the start is refused (the rotor moving; no saliency
seen where the motor's L_dh, L_qh hold none, else an axis that never settled: too weak a signal), or, after a
lost lock, counted as another loss."""
import math

from numba import njit

from drive_common.contract.estimator_states import ALIGNING, HOLD
from drive_common.motor.commissioning import MIN_SALIENCY_RATIO

from .startup_state import (
    NO_SALIENCY,
    NO_SETTLED_AXIS,
    ROTOR_MOVED,
    backemf_clear,
    lose_lock,
)

ALIGN_SMOOTHING_S = 2e-3
"""Time constant of the smoothed error the alignment is judged by."""
MOVING_TOLERANCE_FACTOR = 4.0
"""Re-acquiring a rotor fast enough for its back-EMF to tell the polarity, the alignment tolerance is
this many times wider: the tracker lags an accelerating rotor (a loaded shaft dragged at zero torque),
and the lock monitor checks the result against the back-EMF."""


@njit(cache=True)
def alignment_step(x, p, k, since, u_inj_alpha, u_inj_beta, eps, observable):
    """Sample k, ``since`` samples into the alignment, with the estimator's ε and observable flag →
    (aligned, u_α, u_β [V], state code): aligned, the polarity test begins; else the answer for sample k
    (the estimator's injection while aligning, zero voltage once refused)."""
    s = x.startup
    if observable > 0.5 and p.error_gain != 0.0:
        s.error += p.error_smoothing * (eps / p.error_gain - s.error)
        tolerance = p.align_tolerance_rad
        if backemf_clear(x, p, abs(x.omega) * p.psi_f_Wb):
            tolerance *= MOVING_TOLERANCE_FACTOR
        s.settled = s.settled + 1.0 if abs(s.error) < tolerance else 0.0
    else:
        s.settled = 0.0
    if s.settled == 1.0:
        s.axis_ref = x.theta
        s.axis_sum = 0.0
        s.axis_count = 0.0
        s.axis_time = 0.0
        s.axis_omega = 0.0
    if s.settled >= 1.0:
        turned = x.theta - s.axis_ref
        s.axis_sum += turned - math.pi * math.floor(turned / math.pi + 0.5)
        s.axis_count += 1.0
        s.axis_time += k
        s.axis_omega += x.omega
    if s.settled >= p.settle_samples:
        return True, 0.0, 0.0, float(ALIGNING)
    if since < p.align_timeout_samples:
        return False, u_inj_alpha, u_inj_beta, float(ALIGNING)
    if s.restarts == 0.0:
        moving = backemf_clear(x, p, max(abs(x.omega) * p.psi_f_Wb, math.hypot(s.e_alpha, s.e_beta)))
        salient = abs(1.0 / p.L_dh_H - 1.0 / p.L_qh_H) >= MIN_SALIENCY_RATIO * (1.0 / p.L_dh_H + 1.0 / p.L_qh_H)
        s.refused = ROTOR_MOVED if observable > 0.5 or moving else (NO_SETTLED_AXIS if salient else NO_SALIENCY)
        return False, 0.0, 0.0, float(HOLD)
    return False, u_inj_alpha, u_inj_beta, lose_lock(x, p, k)
