"""Cascade field-oriented control as a numba kernel: speed PI → i_q reference, d/q current PIs with
decoupling and anti-windup, inverse Park with the estimated angle, the estimator's injection added,
and the result limited to the inverter's linear range.

The injected HF current is kept out of the current loop's feedback by a notch at the injection
frequency on the estimated-frame currents, so the loop neither cancels nor amplifies it.

The estimator's start-up state (hf_estimator.startup, `estimator_state` z) gates torque: until it
first reports tracking (3), and again while aligning (1) or after a lost lock (4), the current loops
hold zero current (no speed loop, no back-EMF feed-forward, which would be wrong by 2ωψ_f on the wrong
pole); during the polarity test (2) the fundamental is frozen at its integrators so the estimator's
pulses act alone. Hold (0) after tracking keeps torque. Open loop (5), with an I-f start configured
(``if_current_A`` > 0, drive_common.motor.open_loop_start): the controller turns the current itself
(open_loop_step) until the observer agrees, then hands over keeping the torque current. A jump of θ̂
(the estimator turning to the other pole or onto the measured axis) turns the current loops' integrators
and notch states with it, so the stationary-frame voltage does not jump.
"""
import math
from typing import NamedTuple

import numpy as np
from numba import njit

from drive_common.contract import numba_records  # noqa: F401  (controller_block takes records: cached safely)
from drive_common.contract.estimator_states import ALIGNING, LOCK_LOST, OPEN_LOOP, POLARITY, TRACKING
from drive_common.math.current_sensing import bad_currents, corrected_currents
from drive_common.math.filters import slew, sos_step
from drive_common.math.frames import SQRT3, clarke_contract, rotate, wrap
from drive_common.math.pi import pi_limited
from drive_common.math.tables import table_value

# Controller state layout (integrators, filtered speed, torque gate, last θ̂, and the limits the drive's
# protections set: the current limit's foldback [A], the share of braking current cut, foc_controller.protection;
# 0: none; then the I-f start's: open loop on, the ramp's angle and speed, the stabilising loop's filtered speed,
# the lock samples left, the samples the observer agreed, a mode switch pending (+1 to closed loop, −1 to open
# loop); the ramped speed reference [rad/s, mechanical]; torque released (1: the robot's command hold let the
# joint go, foc_controller.command_hold: no torque although the estimator tracks; written by the caller); the
# notch states (d, q) live in a separate array.
(INT_D, INT_Q, INT_SPEED, OMEGA_FILTERED, TORQUE_ALLOWED, LAST_THETA, STARTED, FOLDBACK_A, REGEN_CUT,
 IF_MODE, IF_THETA, IF_RAMP, IF_FILTERED, IF_ALIGN_LEFT, IF_AGREED, IF_SWITCH, SPEED_RAMPED,
 TORQUE_RELEASED) = range(18)
N_STATE = 18
IF_ANGLE_LIMIT_RAD = math.pi / 2.0
"""The stabilising loop turns the I-f current by at most this (π/4 held a rotor's swing from 2 rad at the lock
to a 10 % decay per period on a heavy rotor); a hand-back sets the load angle within IF_HANDBACK_ANGLE_RAD."""
IF_HANDBACK_ANGLE_RAD = math.pi / 4.0
IF_DAMPED_PER_HANDOVER = 0.6
"""The stabilising loop runs during the lock and from this share of the hand-over speed on (the hand-back
speed), where the observer's speed has converged and its angle lies within ±π/2 of the current's; not between
(at the ramp's start an observer drifted 1 rad at rest swung its speed against the rotor's: from 0.3 of the
hand-over speed on the loop turned a light rotor's load angle to 3 rad at 0.4 of it)."""
JUMP_RAD = 0.25
"""A change of θ̂ beyond ω̂·T_s by more than this in one sample is a jump, not tracking."""
ROUNDING_SPARE = 1e-9
"""The fundamental is limited to this share of the linear range inside it (fundamental_scale), so that the sum
with the injection does not reach the range's bound whatever the rounding."""


class ControllerParams(NamedTuple):
    """Discrete-time controller settings; every motor quantity here is an estimate (nameplate)."""

    T_s_s: float
    n_p: int
    R_s_ohm: float
    L_d_H: float
    L_q_H: float
    psi_f_Wb: float
    U_dc_V: float
    kp_d: float
    ki_d: float
    kp_q: float
    ki_q: float
    kp_speed: float
    ki_speed: float
    i_max_A: float
    decoupling: bool
    delay_compensation_periods: float
    """The voltage is applied this many periods after sampling on average (1.5 with a one-period
    delay and ZOH); the inverse Park turns by ω̂_e times that. 0 disables."""
    hf_notch_sos: np.ndarray
    """Notch SOS at the injection frequency (one row), or an empty (0 × 6) array."""
    speed_filter_gain: float
    """First-order smoothing per sample of the estimated speed before any use (1 = no filter)."""
    speed_limit_rad_s: float
    """The mechanical speed reference is clamped to ±this (∞: no limit)."""
    speed_ramp_rad_s2: float
    """While the speed loop runs, its reference moves by at most this slope [rad/s², mechanical] from the shaft's
    estimated speed at torque's start (∞: no ramp)."""
    mtpa_current_A: np.ndarray
    """Current magnitudes of the MTPA table [A] (drive_common.motor.torque_limit); empty: i_d* = 0."""
    mtpa_d_current_A: np.ndarray
    """The MTPA d current at each magnitude [A] (≤ 0 where L_q > L_d)."""
    if_current_A: float = 0.0
    """The I-f start's current [A] (0: none; drive_common.motor.open_loop_start)."""
    if_acceleration_rad_s2: float = 0.0
    if_handover_rad_s: float = 0.0
    if_align_samples: int = 0
    if_agree_samples: int = 0
    if_damping_filter_rad_s: float = 0.0
    if_damping_gain: float = 0.0
    if_agreement: float = 0.0
    """The ramp's acceleration, the hand-over speed (electrical), the first lock and the agreement wanted
    [samples], the stabilising loop's c [rad/s] and k, the observer's speed within this share of the ramp's."""


@njit(cache=True)
def within(x, y, limit):
    """|(x, y)| ≤ limit, compared in squares (no root)."""
    return limit > 0.0 and x * x + y * y <= limit * limit


@njit(cache=True)
def fundamental_scale(u_alpha, u_beta, u_inj_alpha, u_inj_beta, limit):
    """The largest s in [0, 1] with |s·u + u_inj| ≤ ``limit`` [V]: the share of the fundamental voltage u (αβ
    [V]) the linear range leaves beside this period's injection u_inj (αβ [V]), the two added as vectors (a
    q-axis fundamental beside a d-axis carrier has √(limit² − |u_inj|²), not limit − |u_inj|); 0 where the
    injection alone reaches the limit."""
    if within(u_alpha + u_inj_alpha, u_beta + u_inj_beta, limit):
        return 1.0
    a = u_alpha * u_alpha + u_beta * u_beta
    b = u_alpha * u_inj_alpha + u_beta * u_inj_beta
    c = u_inj_alpha * u_inj_alpha + u_inj_beta * u_inj_beta - limit * limit
    if c >= 0.0 or a <= 0.0:
        return 0.0
    return min(max((math.sqrt(b * b - a * c) - b) / a, 0.0), 1.0)


@njit(cache=True, _nrt=False)
def ramped_reference(x, c, omega_m_ref, omega_m_hat, torque):
    """The speed reference [rad/s, mechanical] the speed loop follows: ``omega_m_ref`` reached at most at
    ``c.speed_ramp_rad_s2`` from x[SPEED_RAMPED]; without ``torque`` the ramp waits at the shaft's estimated speed
    ``omega_m_hat`` (torque starts from where the shaft is) and the reference is returned as it is."""
    if not torque:
        x[SPEED_RAMPED] = omega_m_hat
        return omega_m_ref
    x[SPEED_RAMPED] = slew(x[SPEED_RAMPED], omega_m_ref, c.speed_ramp_rad_s2 * c.T_s_s)
    return x[SPEED_RAMPED]


@njit(cache=True, _nrt=False)
def stabilising_angle(c, filtered):
    """The stabilising loop's turn φ = −k·ṽ_f of the I-f current [rad], within ±IF_ANGLE_LIMIT_RAD, from ``filtered``
    (x[IF_FILTERED], the rotor's speed less the ramp's through 1/(s + c))."""
    return min(max(-c.if_damping_gain * filtered, -IF_ANGLE_LIMIT_RAD), IF_ANGLE_LIMIT_RAD)


@njit(cache=True, _nrt=False)
def open_loop_step(x, c, state, theta_e_hat, omega_e_hat, omega_e_ref):
    """The I-f start (Fatu et al. 2008, drive_common.motor.open_loop_start) for one period: → (whether the
    current is turned open loop, its angle [rad], the frame's speed [rad/s]). Entered when the estimator says
    OPEN_LOOP: from rest with a lock at θ̂ for ``if_align_samples``, its second half a quarter turn further,
    turned smoothly over a quarter of the lock (open_loop_start.ALIGN_SWINGS; a rotor at the first lock's
    unstable point, its d axis against the current, is pulled off it); from
    closed loop with the load angle that keeps the torque current (asin(∫speed/I_f)). The ramp slews its
    speed to ``omega_e_ref`` at ``if_acceleration_rad_s2``. During the lock the stabilising loop turns the
    current's angle by φ = −k·ṽ (ṽ the rotor's speed by the observer, the back-EMF of its swing, through
    1/(s + c)), and again from IF_DAMPED_PER_HANDOVER of the hand-over speed; between, φ decays: the
    swing from the ramp's start stays within 2·asin(ACCELERATION_SHARE) (open_loop_start). As φ moves, the
    current integrators turn with the frame by −Δφ: open loop they hold the back-EMF (not fed forward), which is
    fixed to the rotor, not to the frame (docs/startup.md). Hands over
    (x[IF_SWITCH] = 1, x[INT_SPEED] the torque current I_f·sin(θ_if − θ̂)) once the estimator tracks, the
    ramp is at the hand-over speed and the observer's speed agrees for ``if_agree_samples``."""
    if x[IF_MODE] < 0.5:
        if state != OPEN_LOOP:
            return False, theta_e_hat, omega_e_hat
        x[IF_MODE] = 1.0
        x[IF_FILTERED] = 0.0
        x[IF_AGREED] = 0.0
        x[IF_SWITCH] = -1.0 if x[TORQUE_ALLOWED] > 0.5 else 0.0
        if x[TORQUE_ALLOWED] > 0.5:
            share = min(max(x[INT_SPEED] / c.if_current_A, -math.sin(IF_HANDBACK_ANGLE_RAD)),
                        math.sin(IF_HANDBACK_ANGLE_RAD))
            x[IF_THETA] = theta_e_hat + math.asin(share)
            x[IF_RAMP] = x[OMEGA_FILTERED]
            x[IF_ALIGN_LEFT] = 0.0
        else:
            x[IF_THETA] = theta_e_hat
            x[IF_RAMP] = 0.0
            x[IF_ALIGN_LEFT] = c.if_align_samples
        x[TORQUE_ALLOWED] = 0.0
    if x[IF_ALIGN_LEFT] > 0.0:
        x[IF_ALIGN_LEFT] -= 1.0
        turned = c.if_align_samples // 2 - x[IF_ALIGN_LEFT]
        turn = max(c.if_align_samples // 4, 1)
        if 0.0 < turned <= turn:
            x[IF_THETA] += 0.25 * math.pi * (math.cos(math.pi * (turned - 1.0) / turn)
                                              - math.cos(math.pi * turned / turn))
    else:
        x[IF_RAMP] = slew(x[IF_RAMP], omega_e_ref, c.if_acceleration_rad_s2 * c.T_s_s)
    ramp = x[IF_RAMP]
    lead = wrap(x[IF_THETA] + ramp * c.T_s_s - theta_e_hat)
    observed = x[IF_ALIGN_LEFT] > 0.0 or (abs(ramp) >= IF_DAMPED_PER_HANDOVER * c.if_handover_rad_s and abs(
        omega_e_hat) >= IF_DAMPED_PER_HANDOVER * c.if_handover_rad_s and abs(lead) < 0.5 * math.pi)
    swing = omega_e_hat - ramp if observed else 0.0
    phi_before = stabilising_angle(c, x[IF_FILTERED])
    x[IF_FILTERED] += c.T_s_s * (swing - c.if_damping_filter_rad_s * x[IF_FILTERED])
    x[IF_THETA] += ramp * c.T_s_s
    phi = stabilising_angle(c, x[IF_FILTERED])
    x[INT_D], x[INT_Q] = rotate(x[INT_D], x[INT_Q], phi_before - phi)
    theta = x[IF_THETA] + phi
    lead = wrap(theta - theta_e_hat)
    if (state == TRACKING and x[IF_ALIGN_LEFT] <= 0.0 and abs(ramp) >= c.if_handover_rad_s
            and abs(omega_e_hat - ramp) < c.if_agreement * abs(ramp) and abs(lead) < 0.5 * math.pi):
        x[IF_AGREED] += 1.0
    else:
        x[IF_AGREED] = 0.0
    if x[IF_AGREED] >= c.if_agree_samples:
        x[IF_MODE] = 0.0
        x[TORQUE_ALLOWED] = 1.0
        x[IF_SWITCH] = 1.0
        x[INT_SPEED] = c.if_current_A * math.sin(lead)
        return False, theta_e_hat, omega_e_hat
    return True, theta, ramp


@njit(cache=True, _nrt=False)
def controller_step(x, z_notch, c, inputs, estimate, calibration, out):
    """One control period from sample k: ``inputs`` (a DRIVE_INPUT record, drive_common.contract.drive_records:
    the measured phase currents [A], corrected here by the commissioned ``calibration``, the speed reference
    ω*_m [rad/s] and the robot's torque feed-forward [N·m], added to the speed loop's output as τ_ff/k̂_t,
    k̂_t = 1.5 p ψ_f from the nameplate, once torque is allowed) and ``estimate`` (an ESTIMATE record: θ̂_e
    [rad], ω̂_e [rad/s] electrical, the injection [V, αβ], the state code; a non-finite code reads as hold)
    → ``out`` (a COMMAND record): the stator voltage command (u_α, u_β) [V] for the next period, the
    (HF-rejected) feedback currents i_d, i_q and the references i_d*, i_q* [A]. State x: INT_D .. REGEN_CUT
    (the speed filter and the jump detector start from the first sample's estimate); z_notch: the notch
    sections of d (z_notch[0]) and q (z_notch[1]). The speed loop's current limit is i_max less the
    protections' foldback x[FOLDBACK_A]; a braking current (i_q* against ω̂_e, regenerating) at most
    (1 − x[REGEN_CUT]) of it (the DC-link over-voltage controller). The speed loop's output is a current
    magnitude: with an MTPA table it is split into i_d* (the table's) and i_q* of the same magnitude
    (drive_common.motor.torque_limit), else it is i_q* (i_d* = 0). With a speed ramp (c.speed_ramp_rad_s2
    finite) the speed loop follows ω*_m through ramped_reference.

    The estimated speed is low-pass filtered once and that value feeds the speed loop, the back-EMF
    decoupling and the delay compensation: a raw PLL speed in the feed-forward closes a fast loop
    through the estimator (docs/hf-demodulation.md §3)."""
    i_a, i_b, i_c = corrected_currents(inputs.i_a_A, inputs.i_b_A, inputs.i_c_A, calibration)
    theta_e_hat, omega_e_hat = estimate.theta_e_hat, estimate.omega_e_hat
    u_inj_alpha, u_inj_beta = estimate.u_inj_alpha, estimate.u_inj_beta
    state = int(estimate.state) if math.isfinite(estimate.state) else 0
    if x[STARTED] == 0.0:
        x[STARTED] = 1.0
        x[OMEGA_FILTERED] = omega_e_hat
        x[LAST_THETA] = theta_e_hat
    open_loop, omega_frame = False, omega_e_hat
    omega_m_ref = min(max(inputs.omega_m_ref_rad_s, -c.speed_limit_rad_s), c.speed_limit_rad_s)
    if c.if_current_A > 0.0:
        open_loop, theta_e_hat, omega_frame = open_loop_step(x, c, state, theta_e_hat, omega_e_hat,
                                                             c.n_p * omega_m_ref)
    if open_loop:
        pass
    elif state == TRACKING:
        x[TORQUE_ALLOWED] = 1.0 - x[TORQUE_RELEASED]
    elif state == ALIGNING or state == POLARITY or state == LOCK_LOST:
        x[TORQUE_ALLOWED] = 0.0
    jump = theta_e_hat - x[LAST_THETA] - omega_frame * c.T_s_s
    jump = jump - 2.0 * math.pi * math.floor((jump + math.pi) / (2.0 * math.pi))
    if abs(jump) > JUMP_RAD:
        x[INT_D], x[INT_Q] = rotate(x[INT_D], x[INT_Q], -jump)
        for j in range(z_notch.shape[1]):
            for m in range(z_notch.shape[2]):
                z_notch[0, j, m], z_notch[1, j, m] = rotate(z_notch[0, j, m], z_notch[1, j, m], -jump)
    x[LAST_THETA] = theta_e_hat
    i_alpha, i_beta = clarke_contract(i_a, i_b, i_c)
    i_d, i_q = rotate(i_alpha, i_beta, -theta_e_hat)
    if c.hf_notch_sos.shape[0] > 0:
        i_d = sos_step(c.hf_notch_sos, z_notch[0], i_d)
        i_q = sos_step(c.hf_notch_sos, z_notch[1], i_q)

    x[OMEGA_FILTERED] += c.speed_filter_gain * (omega_e_hat - x[OMEGA_FILTERED])
    omega_e_hat = omega_frame if open_loop else x[OMEGA_FILTERED]
    omega_m_hat = omega_e_hat / c.n_p
    torque = x[TORQUE_ALLOWED] > 0.5 and not open_loop
    if x[IF_SWITCH] != 0.0 and c.decoupling:
        # the back-EMF feed-forward starts (+1) or stops (−1): the integrators take it over, the voltage stays
        x[INT_D] += x[IF_SWITCH] * omega_e_hat * c.L_q_H * i_q
        x[INT_Q] -= x[IF_SWITCH] * omega_e_hat * (c.L_d_H * i_d + c.psi_f_Wb)
    if math.isfinite(c.speed_ramp_rad_s2):
        omega_m_ref = ramped_reference(x, c, omega_m_ref, omega_m_hat, torque)
    if torque:
        i_limit = max(c.i_max_A - x[FOLDBACK_A], 0.0)
        if x[IF_SWITCH] > 0.0:
            x[INT_SPEED] -= c.kp_speed * (omega_m_ref - omega_m_hat) + inputs.tau_feedforward_Nm / (
                1.5 * c.n_p * c.psi_f_Wb)
        i_q_ref = pi_limited(x, INT_SPEED, c.kp_speed, c.ki_speed, c.T_s_s, omega_m_ref - omega_m_hat,
                             i_limit, inputs.tau_feedforward_Nm / (1.5 * c.n_p * c.psi_f_Wb))
        braking = (1.0 - x[REGEN_CUT]) * i_limit
        if i_q_ref * omega_e_hat < 0.0 and abs(i_q_ref) > braking:
            held = math.copysign(braking, i_q_ref)
            x[INT_SPEED] += held - i_q_ref
            i_q_ref = held
    else:
        x[INT_SPEED] = 0.0
        i_q_ref = 0.0
    x[IF_SWITCH] = 0.0
    i_d_ref = c.if_current_A if open_loop else 0.0
    if c.mtpa_current_A.shape[0] > 0 and i_q_ref != 0.0:
        i_d_ref = table_value(abs(i_q_ref), c.mtpa_current_A, c.mtpa_d_current_A)
        i_q_ref = math.copysign(math.sqrt(max(i_q_ref * i_q_ref - i_d_ref * i_d_ref, 0.0)), i_q_ref)

    e_d = i_d_ref - i_d
    e_q = i_q_ref - i_q
    frozen = state == POLARITY
    if frozen:
        e_d = 0.0
        e_q = 0.0
    u_d = c.kp_d * e_d + x[INT_D]
    u_q = c.kp_q * e_q + x[INT_Q]
    if c.decoupling and torque:
        u_d -= omega_e_hat * c.L_q_H * i_q
        u_q += omega_e_hat * (c.L_d_H * i_d + c.psi_f_Wb)

    u_max = c.U_dc_V / SQRT3
    inside = (1.0 - ROUNDING_SPARE) * u_max
    theta_v = theta_e_hat + c.delay_compensation_periods * omega_e_hat * c.T_s_s
    u_alpha, u_beta = rotate(u_d, u_q, theta_v)
    scale = fundamental_scale(u_alpha, u_beta, u_inj_alpha, u_inj_beta, inside)
    x[INT_D] += c.T_s_s * c.ki_d * e_d + (scale - 1.0) * u_d
    x[INT_Q] += c.T_s_s * c.ki_q * e_q + (scale - 1.0) * u_q
    u_alpha = scale * u_alpha + u_inj_alpha
    u_beta = scale * u_beta + u_inj_beta
    if not within(u_alpha, u_beta, inside):
        total = math.hypot(u_alpha, u_beta)
        if total > u_max:
            u_alpha *= u_max / total
            u_beta *= u_max / total
    out.u_alpha_V, out.u_beta_V = u_alpha, u_beta
    out.i_d_A, out.i_q_A, out.i_d_ref_A, out.i_q_ref_A = i_d, i_q, i_d_ref, i_q_ref


@njit(cache=True, _nrt=False, inline='always')
def controller_block(x, z_notch, c, n, inputs, estimates, sensing, out):
    """n consecutive samples of ``controller_step``: ``inputs`` (n DRIVE_INPUT records), ``estimates`` (n
    ESTIMATE records), ``sensing`` (drive_common.math.current_sensing.CurrentSensing) → ``out`` (n COMMAND
    records). A sample with currents not finite or beyond the trip, or a non-finite estimate or injection,
    gets zero voltage and leaves the state untouched. Returns the number of such bad samples."""
    bad = 0
    for i in range(n):
        s = inputs[i]
        e = estimates[i]
        if bad_currents(s.i_a_A, s.i_b_A, s.i_c_A, sensing.trip_A) or not (
                math.isfinite(e.theta_e_hat) and math.isfinite(e.omega_e_hat) and math.isfinite(e.u_inj_alpha)
                and math.isfinite(e.u_inj_beta)):
            bad += 1
            o = out[i]
            o.u_alpha_V = o.u_beta_V = o.i_d_A = o.i_q_A = o.i_d_ref_A = o.i_q_ref_A = 0.0
            continue
        controller_step(x, z_notch, c, s, e, sensing.calibration, out[i])
    return bad


def estimated_torque(c, i_d, i_q):
    """τ̂_e = 1.5 p (ψ_f i_q + (L_d − L_q) i_d i_q) from the nameplate [N·m]."""
    return 1.5 * c.n_p * (c.psi_f_Wb * i_q + (c.L_d_H - c.L_q_H) * i_d * i_q)


def controller_state(c):
    """Fresh (integrator state, notch state) arrays for ControllerParams c: no torque until the estimator
    reports tracking."""
    x = np.zeros(N_STATE)
    return x, np.zeros((2, max(c.hf_notch_sos.shape[0], 1), 2))
