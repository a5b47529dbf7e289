"""The start-up's lock monitor (docs/startup.md; startup.py, items 3 and 4): the back-EMF in the θ̂ frame
measured from the applied voltage and the currents against what the estimate implies; a lock lost where they part
for long enough; and, during the hold after a loss, the rotor's angle and speed fitted to its back-EMF."""
import math

from numba import njit

from control_math.dead_time import dead_time_direction
from control_math.frames import inverse_clarke, rotate
from drive_interface.estimator_states import ALIGNING, HOLD, LOCK_LOST, TRACKING

from .startup_state import (
    BAD,
    CODE,
    E_ALPHA,
    E_BETA,
    FIT_N,
    FIT_P,
    FIT_T,
    FIT_TP,
    FIT_TT,
    INTEGRAL,
    PHI_RAW,
    PHI_UNWRAPPED,
    PREV_IA,
    PREV_IB,
    REFUSED,
    RESIDUAL_D,
    RESIDUAL_Q,
    RESTARTS,
    THETA,
    TOO_MANY_LOSSES,
    backemf_clear,
    enter,
    lose_lock,
)


@njit(cache=True)
def backemf_residual(x, p, k, i_alpha, i_beta, u_alpha, u_beta):
    """Update the low-passed back-EMF residual (θ̂ frame) with sample k's currents (α, β) [A] and the
    voltage (u_α, u_β) [V] applied in the period before it → its magnitude [V]. e = u − R̂ī − L̂·Δi/T_s per
    axis (the HF cancelling), the commissioned dead-time loss removed; residual = e − (ω̂ΔL i_q,
    ω̂(ψ_f + ΔL i_d))."""
    b = p.base
    prev_a, prev_b = x[b + PREV_IA], x[b + PREV_IB]
    x[b + PREV_IA] = i_alpha
    x[b + PREV_IB] = i_beta
    if k < p.delay_periods + 2:
        return 0.0
    if p.dead_time_voltage_V != 0.0:
        start_a, start_b, start_c = inverse_clarke(prev_a, prev_b)
        loss_alpha, loss_beta = dead_time_direction(start_a, start_b, start_c, p.dead_time_smoothing_A)
        u_alpha -= p.dead_time_voltage_V * loss_alpha
        u_beta -= p.dead_time_voltage_V * loss_beta
    omega = x[INTEGRAL]
    angle = x[THETA] - 0.5 * omega * p.T_s_s
    u_d, u_q = rotate(u_alpha, u_beta, -angle)
    i_d, i_q = rotate(0.5 * (i_alpha + prev_a), 0.5 * (i_beta + prev_b), -angle)
    step_d, step_q = rotate(i_alpha - prev_a, i_beta - prev_b, -angle)
    e_d = u_d - p.R_s_ohm * i_d - p.L_dh_H * step_d / p.T_s_s
    e_q = u_q - p.R_s_ohm * i_q - p.L_qh_H * step_q / p.T_s_s
    r_d = e_d - omega * p.delta_L_H * i_q
    r_q = e_q - omega * (p.psi_f_Wb + p.delta_L_H * i_d)
    x[b + RESIDUAL_D] += p.lock_smoothing * (r_d - x[b + RESIDUAL_D])
    x[b + RESIDUAL_Q] += p.lock_smoothing * (r_q - x[b + RESIDUAL_Q])
    x[b + E_ALPHA], x[b + E_BETA] = rotate(e_d, e_q, angle)
    return math.hypot(x[b + RESIDUAL_D], x[b + RESIDUAL_Q])


@njit(cache=True)
def lock_step(x, p, k, residual, observable):
    """Tracking or holding: the residual [V] beyond V_th + ½ max(|ω̂ψ_f|, |e|) for lock_persist_samples
    loses the lock (a π slip makes it 2ωψ_f, a runaway estimate |ω − ω̂|ψ_f). → the state code: LOCK_LOST,
    else TRACKING where the estimator observes its saliency, HOLD where not."""
    b = p.base
    expected = abs(x[INTEGRAL]) * p.psi_f_Wb
    measured = math.hypot(x[b + RESIDUAL_D], x[b + RESIDUAL_Q] + x[INTEGRAL] * p.psi_f_Wb)
    if residual > p.lock_threshold_V + 0.5 * max(expected, measured):
        x[b + BAD] += 1.0
    else:
        x[b + BAD] = 0.0
    if x[b + BAD] >= p.lock_persist_samples:
        return lose_lock(x, p, k)
    code = TRACKING if observable > 0.5 else HOLD
    x[b + CODE] = code
    return float(code)


@njit(cache=True)
def fit_backemf_angle(x, p, since):
    """Add this sample's back-EMF angle (stationary frame, unwrapped) to a straight-line fit over the
    lost-lock hold, when the back-EMF stands clear of its threshold."""
    b = p.base
    e_alpha, e_beta = x[b + E_ALPHA], x[b + E_BETA]
    if not backemf_clear(x, p, math.hypot(e_alpha, e_beta)):
        return
    phi = math.atan2(e_beta, e_alpha)
    if x[b + FIT_N] == 0.0:
        x[b + PHI_UNWRAPPED] = phi
    else:
        step = phi - x[b + PHI_RAW]
        x[b + PHI_UNWRAPPED] += step - 2.0 * math.pi * math.floor((step + math.pi) / (2.0 * math.pi))
    x[b + PHI_RAW] = phi
    t = float(since)
    x[b + FIT_N] += 1.0
    x[b + FIT_T] += t
    x[b + FIT_P] += x[b + PHI_UNWRAPPED]
    x[b + FIT_TP] += t * x[b + PHI_UNWRAPPED]
    x[b + FIT_TT] += t * t


@njit(cache=True)
def seed_from_backemf(x, p, since):
    """At the end of the lost-lock hold: when the back-EMF stood clear in most of it, its angle's fitted
    line gives the rotor's speed (the slope: the back-EMF turns with the rotor, either way) and angle
    (θ = φ − π/2 turning forwards, φ + π/2 backwards, the magnet's polarity included): θ̂ and ω̂ start
    there. Returns True when seeded."""
    b = p.base
    n = x[b + FIT_N]
    seeded = False
    if n >= 0.8 * p.lost_hold_samples and n >= 3.0:
        det = n * x[b + FIT_TT] - x[b + FIT_T] ** 2
        if det > 0.0:
            slope = (n * x[b + FIT_TP] - x[b + FIT_T] * x[b + FIT_P]) / det
            phi = (x[b + FIT_P] - slope * x[b + FIT_T]) / n + slope * since
            omega = slope / p.T_s_s
            theta = phi - math.copysign(0.5 * math.pi, omega)
            turned = theta - x[THETA]
            x[THETA] += turned - 2.0 * math.pi * math.floor((turned + math.pi) / (2.0 * math.pi))
            x[INTEGRAL] = omega
            x[b + RESIDUAL_D] = 0.0
            x[b + RESIDUAL_Q] = 0.0
            seeded = True
    for j in range(FIT_N, PHI_UNWRAPPED + 1):
        x[b + j] = 0.0
    return seeded


@njit(cache=True)
def reacquire_step(x, p, k, since, u_inj_alpha, u_inj_beta):
    """A lost lock, ``since`` samples ago: zero torque for lost_hold_samples while the back-EMF's angle
    is fitted, then θ̂ seeded from it where it stood clear and a new alignment; more than max_restarts
    losses refuse the start. → (u_inj_α, u_inj_β [V], state code)."""
    if since < p.lost_hold_samples:
        fit_backemf_angle(x, p, since)
        return u_inj_alpha, u_inj_beta, float(LOCK_LOST)
    seed_from_backemf(x, p, since)
    if x[p.base + RESTARTS] > p.max_restarts:
        x[p.base + REFUSED] = TOO_MANY_LOSSES
        return 0.0, 0.0, float(LOCK_LOST)
    enter(x, p, k, ALIGNING)
    return u_inj_alpha, u_inj_beta, float(ALIGNING)
