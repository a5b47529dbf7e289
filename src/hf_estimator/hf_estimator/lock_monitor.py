"""The start-up's lock monitor (docs/startup.md; startup.py, items 3 and 4): the back-EMF in the θ̂ frame
measured from the applied voltage and the currents against what the estimate implies; a lock lost where they part
for long enough; and, during the hold after a loss, the rotor's angle and speed fitted to its back-EMF."""
import math

from numba import njit

from drive_common.contract.estimator_states import ALIGNING, HOLD, LOCK_LOST, TRACKING
from drive_common.math.dead_time import net_of_dead_time
from drive_common.math.frames import rotate

from .interface import stator_resistance
from .startup_state import (
    TOO_MANY_LOSSES,
    backemf_clear,
    enter,
    lose_lock,
    measured_backemf,
)


@njit(cache=True, _nrt=False, inline='always')
def backemf_residual(x, p, k, i_alpha, i_beta, u_alpha, u_beta, R_s_tracked_ohm):
    """Update the low-passed back-EMF residual (θ̂ frame) with sample k's currents (α, β) [A] and the
    voltage (u_α, u_β) [V] applied in the period before it → its magnitude [V]. e = u − R̂ī − L̂·Δi/T_s per
    axis (the HF cancelling; R̂ the drive's tracked R_s_tracked_ohm [Ω], else the commissioned one), the
    commissioned dead-time loss removed (the voltage net of it kept as ``u_net_alpha``, ``u_net_beta`` for the
    polarity test); residual = e − (ω̂ΔL i_q, ω̂(ψ_f + ΔL i_d))."""
    s = x.startup
    prev_a, prev_b = s.prev_ia, s.prev_ib
    s.prev_ia = i_alpha
    s.prev_ib = i_beta
    u_alpha, u_beta = net_of_dead_time(u_alpha, u_beta, prev_a, prev_b, p.dead_time_voltage_V,
                                       p.dead_time_smoothing_A)
    s.u_net_alpha = u_alpha
    s.u_net_beta = u_beta
    if k < p.delay_periods + 2:
        return 0.0
    omega = x.omega
    angle = x.theta - 0.5 * omega * p.T_s_s
    u_d, u_q = rotate(u_alpha, u_beta, -angle)
    i_d, i_q = rotate(0.5 * (i_alpha + prev_a), 0.5 * (i_beta + prev_b), -angle)
    step_d, step_q = rotate(i_alpha - prev_a, i_beta - prev_b, -angle)
    R_s = stator_resistance(p.R_s_ohm, R_s_tracked_ohm)
    e_d = u_d - R_s * i_d - p.L_dh_H * step_d / p.T_s_s
    e_q = u_q - R_s * i_q - p.L_qh_H * step_q / p.T_s_s
    r_d = e_d - omega * p.delta_L_H * i_q
    r_q = e_q - omega * (p.psi_f_Wb + p.delta_L_H * i_d)
    s.residual_d += p.lock_smoothing * (r_d - s.residual_d)
    s.residual_q += p.lock_smoothing * (r_q - s.residual_q)
    s.e_alpha, s.e_beta = rotate(e_d, e_q, angle)
    return math.hypot(s.residual_d, s.residual_q)


@njit(cache=True, _nrt=False, inline='always')
def lock_step(x, p, k, residual, observable):
    """Tracking or holding: the residual [V] beyond V_th + ½ max(|ω̂ψ_f|, |e|) for lock_persist_samples
    loses the lock (a π slip makes it 2ωψ_f, a runaway estimate |ω − ω̂|ψ_f). → the state code: LOCK_LOST,
    else TRACKING where the estimator observes its saliency, HOLD where not."""
    s = x.startup
    expected = abs(x.omega) * p.psi_f_Wb
    measured = measured_backemf(x, p)
    if residual > p.lock_threshold_V + 0.5 * max(expected, measured):
        s.bad += 1.0
    else:
        s.bad = 0.0
    if s.bad >= p.lock_persist_samples:
        return lose_lock(x, p, k)
    code = TRACKING if observable > 0.5 else HOLD
    s.code = code
    return float(code)


@njit(cache=True, _nrt=False)
def fit_backemf_angle(x, p, since):
    """Add this sample's back-EMF angle (stationary frame, unwrapped) to a straight-line fit over the
    lost-lock hold, when the back-EMF stands clear of its threshold."""
    s = x.startup
    e_alpha, e_beta = s.e_alpha, s.e_beta
    if not backemf_clear(x, p, math.hypot(e_alpha, e_beta)):
        return
    phi = math.atan2(e_beta, e_alpha)
    if s.fit_n == 0.0:
        s.phi_unwrapped = phi
    else:
        step = phi - s.phi_raw
        s.phi_unwrapped += step - 2.0 * math.pi * math.floor((step + math.pi) / (2.0 * math.pi))
    s.phi_raw = phi
    t = float(since)
    s.fit_n += 1.0
    s.fit_t += t
    s.fit_p += s.phi_unwrapped
    s.fit_tp += t * s.phi_unwrapped
    s.fit_tt += t * t


@njit(cache=True, _nrt=False)
def seed_from_backemf(x, p, since):
    """At the end of the lost-lock hold: when the back-EMF stood clear in most of it, its angle's fitted
    line gives the rotor's speed (the slope: the back-EMF turns with the rotor, either way) and angle
    (θ = φ − π/2 turning forwards, φ + π/2 backwards, the magnet's polarity included): θ̂ and ω̂ start
    there. Returns True when seeded."""
    s = x.startup
    n = s.fit_n
    seeded = False
    if n >= 0.8 * p.lost_hold_samples and n >= 3.0:
        det = n * s.fit_tt - s.fit_t ** 2
        if det > 0.0:
            slope = (n * s.fit_tp - s.fit_t * s.fit_p) / det
            phi = (s.fit_p - slope * s.fit_t) / n + slope * since
            omega = slope / p.T_s_s
            theta = phi - math.copysign(0.5 * math.pi, omega)
            turned = theta - x.theta
            x.theta += turned - 2.0 * math.pi * math.floor((turned + math.pi) / (2.0 * math.pi))
            x.omega = omega
            s.residual_d = 0.0
            s.residual_q = 0.0
            seeded = True
    s.fit_n = s.fit_t = s.fit_p = s.fit_tp = s.fit_tt = s.phi_raw = s.phi_unwrapped = 0.0
    return seeded


@njit(cache=True, _nrt=False)
def reacquire_step(x, p, k, since, u_inj_alpha, u_inj_beta):
    """A lost lock, ``since`` samples ago: zero torque for lost_hold_samples while the back-EMF's angle
    is fitted, then θ̂ seeded from it where it stood clear and a new alignment; more than max_restarts
    losses refuse the start. → (u_inj_α, u_inj_β [V], state code)."""
    s = x.startup
    if since < p.lost_hold_samples:
        fit_backemf_angle(x, p, since)
        return u_inj_alpha, u_inj_beta, float(LOCK_LOST)
    seed_from_backemf(x, p, since)
    if s.restarts > p.max_restarts:
        s.refused = TOO_MANY_LOSSES
        return 0.0, 0.0, float(LOCK_LOST)
    enter(x, p, k, ALIGNING)
    return u_inj_alpha, u_inj_beta, float(ALIGNING)
