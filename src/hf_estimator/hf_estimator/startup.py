"""Start-up and lock supervision, shared by every injecting estimator (docs/startup.md).

The estimator starts knowing nothing of the angle (θ̂ = 0). Its state code is `estimator_state` z
(contract v2): HOLD 0, ALIGNING 1, POLARITY 2, TRACKING 3, LOCK_LOST 4. The controller applies torque
only once TRACKING has been reached (HOLD after it keeps torque; the estimate coasts).

1. Aligning: the estimator's own tracker converges on its own injection to the saliency axis (mod π).
   Aligned once its error, scaled to radians by the estimator's gain and smoothed (2 ms), has stayed
   below ``align_tolerance_rad`` (MOVING_TOLERANCE_FACTOR times more at speed) for ``settle_s``. Then,
   still aligning (the controller holds zero current), the injection stops for ``quiet_s`` so that the
   current loop takes the HF current's residue to zero: pulses from a non-zero current would measure the
   saturation at the wrong operating point. No aligned saliency within ``align_timeout_s``: the start is
   refused, zero voltage, no guess; the reason is the rotor moving where the estimator still observes its
   saliency, or a back-EMF (the tracker's, or the one measured) stands clear of the lock threshold (a load
   turning the shaft), else no saliency (a round
   rotor, L_dh = L_qh, has no angle to find).
2. Polarity: θ̂ held and ω̂ set to 0 (the back-EMF saw no motion; a tracker's integrator may have wound
   up while aligning), the injection replaced by voltage pulses along θ̂,
   + − − + of n samples each, sized for ``pulse_current_per_rated`` × rated current from the
   commissioned L_dh and R_s. The magnet saturates the d axis further when i_d > 0, so the + excursion
   A₊ is larger than the − one A₋. With i_j the d̂ current at the j-th pulse boundary (the computation
   delay accounted), S = −i₀ + 2i₁ − 2i₂ + 2i₃ − i₄ = 2(A₊ − A₋) and T = −i₀ + 2i₁ − 2i₃ + i₄ = 2(A₊ + A₋),
   both free of sensor offsets and of a linear drift. Every other sequence is mirrored, − + + − (S keeps
   its weights, T changes sign): the dead-time loss, which depends on the order of the pulses, then
   cancels from S. What a linear winding's resistance adds to S/T where a pulse is not short against
   L/R (linear_polarity_ratio) is taken off. S/T below −``polarity_margin``: θ̂ is the magnet's south,
   turned by π. Within ±margin
   the pulses found no asymmetry: θ̂ may sit on the q axis (the trackers' unstable equilibrium, where ε
   is zero too), so the test repeats a quarter turn further, up to ``polarity_tries`` times; then the
   start is refused. At speed, where the back-EMF stands ``backemf_polarity_ratio`` × its threshold
   clear, its sign decides instead. A flush of ``flush_s`` with the tracker running on its injection
   follows, still without torque.
3. Tracking, and the lock monitor: the back-EMF in the θ̂ frame is measured from the applied voltage
   (the command d + 1 samples old, the commissioned dead-time loss removed) and the currents,
   e = u − R̂ī − L̂·Δi/T_s (per axis, the HF cancelling), and compared with what the estimate implies,
   (ω̂ΔL i_q, ω̂(ψ_f + ΔL i_d)). A π slip makes the residual 2ωψ_f, an estimate that runs away or stops
   |ω − ω̂|ψ_f; beyond the threshold V_th + ½ max(|ω̂ψ_f|, |e|) (low-passed) for ``lock_persist_s``, the
   lock is lost. (An estimate whose speed only lags, its angle still close, stays within: its residual
   |ω − ω̂|ψ_f is below ½|e| + V_th until ω̂ lags by half the speed and more.)
4. Lock lost: zero torque for ``lost_hold_s``. Where the back-EMF stands clear meanwhile (a rotor
   turning), a straight line fitted to its angle in the stationary frame gives the rotor's speed and
   angle, polarity included, and θ̂, ω̂ restart there. Then a new start-up (an alignment that times out
   counts as another loss), at most ``max_restarts`` times; then it stays at zero torque (refused).
5. Replay (``polarity_from_recording``): an estimator replayed on a recording cannot steer its voltage, so
   neither the quiet time nor the pulses happen. Once aligned it takes the magnet's polarity as the
   recording drive resolved it: θ̂ or θ̂ + π, whichever is nearer the recorded estimate (never its angle
   beyond that choice). Where the recording has not resolved it (no estimate, or its estimator not yet
   tracking: NaN) the back-EMF at speed decides; at standstill the estimator stays aligning, tracking on its
   own loop, until one of the two can tell. Then the flush and tracking as above.
"""
import math
from typing import NamedTuple

from numba import njit

from control_math.dead_time import SMOOTHING_PER_RATED_CURRENT, dead_time_direction
from control_math.frames import inverse_clarke, rotate, wrap
from drive_interface.estimator_states import ALIGNING, HOLD, LOCK_LOST, POLARITY, STATE_NAMES, TRACKING
from motor_params.commissioning import NAMEPLATE_ONLY

NOT_REFUSED, NO_SALIENCY, NO_POLARITY, TOO_MANY_LOSSES, ROTOR_MOVED = 0, 1, 2, 3, 4
REFUSALS = {NO_SALIENCY: "no saliency found: HF injection cannot tell this rotor's angle (a round rotor?)",
            ROTOR_MOVED: "the rotor turned while aligning (a load driving the shaft?): no still saliency axis "
                         "to align on; start with the shaft held or braked",
            NO_POLARITY: "no saturation asymmetry on the d axis: the magnet's polarity cannot be told",
            TOO_MANY_LOSSES: "lock lost too often; holding zero torque"}

(CODE, ENTERED, SETTLED, ERROR, THETA_HELD, INTEGRAL_HELD, SCORE, SPAN, TRIES, REFUSED, RESTARTS,
 RESIDUAL_D, RESIDUAL_Q, PREV_IA, PREV_IB, BAD, POLARITY_RATIO, FLIPPED, HELD_AT, QUIET, E_ALPHA,
 E_BETA, FIT_N, FIT_T, FIT_P, FIT_TP, FIT_TT, PHI_RAW, PHI_UNWRAPPED) = range(29)
HISTORY = 29
"""Then the ring of issued commands (α, β) × (d + 2)."""
THETA, INTEGRAL = 0, 1
"""Every estimator keeps θ̂ at x[0] and its speed integrator (ω̂) at x[1]."""

DEFAULTS = {"align_tolerance_rad": 0.05, "settle_s": 3e-3, "align_timeout_s": 0.1, "quiet_s": 3e-3,
            "pulse_current_per_rated": 0.7, "pulse_s": 5e-4, "pulse_sequences": 2, "polarity_margin": 0.01,
            "polarity_tries": 3,
            "flush_s": 6e-3, "lock_filter_Hz": 100.0, "lock_persist_s": 5e-3, "lost_hold_s": 0.01,
            "max_restarts": 3, "backemf_polarity_ratio": 3.0, "slip_at_s": -1.0, "slip_rad": math.pi,
            "polarity_from_recording": False}
"""Start-up settings (estimator settings of every injecting estimator; slip_* force a slip of θ̂, a test;
``polarity_from_recording``: replay, item 5)."""
ALIGN_SMOOTHING_S = 2e-3
"""Time constant of the smoothed error the alignment is judged by."""
MOVING_TOLERANCE_FACTOR = 4.0
"""Re-acquiring a rotor fast enough for its back-EMF to tell the polarity, the alignment tolerance is
this many times wider: the tracker lags an accelerating rotor (a loaded shaft dragged at zero torque),
and the lock monitor checks the result against the back-EMF."""
PULSE_VOLTAGE_MAX_PER_LINEAR = 0.8
"""Polarity pulses use at most this share of the linear voltage range U_dc/√3 (longer pulses beyond)."""
LOCK_RESISTANCE_ERROR = 0.1
LOCK_DEAD_TIME_ERROR = 0.5
"""V_th = this share of R̂·I_rated + this share of the commissioned dead-time voltage (per phase, ×4/3 in
αβ) + 2 % of the rated back-EMF: what the back-EMF model can be wrong by at rated current."""
UNMEASURED_DEAD_TIME_PER_U_DC = 0.02
"""A drive that never measured its dead-time voltage (nameplate only) neither compensates it nor ignores
it: V_th allows the whole of a typical one, 2 % of U_dc (2 µs of dead time at 10 kHz), ×4/3 in αβ."""


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
    """S/T that a linear R–L gives the pulses (linear_polarity_ratio), taken off the measured one."""
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
    slip_at_sample: int
    slip_rad: float
    polarity_from_recording: bool


def dead_time_uncertainty_V(inverter, commissioning, share):
    """What the back-EMF model's dead-time voltage can be wrong by in αβ [V]: ``share`` of the commissioned
    dead-time voltage ×4/3; a drive that never measured it (nameplate only) neither compensates it nor
    ignores it: a typical whole one, UNMEASURED_DEAD_TIME_PER_U_DC of U_dc (``inverter``'s, when known), ×4/3."""
    if commissioning.source == NAMEPLATE_ONLY and math.isfinite(inverter.U_dc_V):
        return 4.0 / 3.0 * UNMEASURED_DEAD_TIME_PER_U_DC * inverter.U_dc_V
    return share * 4.0 / 3.0 * commissioning.dead_time_voltage_V


@njit(cache=True)
def startup_size(p):
    """Entries of the start-up state in an estimator's x."""
    return HISTORY


def make_startup(base, nameplate, commissioning, T_s, inverter, error_gain, settings):
    """StartupParams for an estimator whose start-up state begins at x[base], on ``inverter``
    (InverterRating: U_dc, ∞ when unknown, and the drive's whole delay); ``settings``: its checked
    settings (interface.check_settings, DEFAULTS among them), ``error_gain`` its ε per radian."""
    s = settings
    I_p = s["pulse_current_per_rated"] * nameplate.rated_current_A
    u_max = PULSE_VOLTAGE_MAX_PER_LINEAR * inverter.U_dc_V / math.sqrt(3.0)
    resistive = 0.5 * commissioning.R_s_ohm * I_p
    if resistive >= u_max:
        raise ValueError(f"pulse_current_per_rated: {s['pulse_current_per_rated']:g} × rated current needs more "
                         f"than {u_max:.3g} V across R_s alone")
    n = max(2, int(round(s["pulse_s"] / T_s)),
            math.ceil(I_p * commissioning.L_dh_H / (T_s * (u_max - resistive))))
    pulse_V = I_p * commissioning.L_dh_H / (n * T_s) + resistive
    omega_rated = nameplate.n_p * nameplate.rated_speed_rpm * 2.0 * math.pi / 60.0
    threshold = (LOCK_RESISTANCE_ERROR * commissioning.R_s_ohm * nameplate.rated_current_A
                 + dead_time_uncertainty_V(inverter, commissioning, LOCK_DEAD_TIME_ERROR)
                 + 0.02 * omega_rated * nameplate.psi_f_Wb)

    def samples(seconds):
        return max(1, int(round(seconds / T_s)))
    return StartupParams(
        base=base, T_s_s=T_s, delay_periods=int(inverter.delay_periods), error_gain=float(error_gain),
        align_tolerance_rad=s["align_tolerance_rad"], settle_samples=samples(s["settle_s"]),
        align_timeout_samples=samples(s["align_timeout_s"]), quiet_samples=samples(s["quiet_s"]),
        error_smoothing=1.0 - math.exp(-1.0 / samples(ALIGN_SMOOTHING_S)),
        pulse_samples=n, pulse_V=pulse_V, pulse_sequences=int(s["pulse_sequences"]),
        polarity_margin=s["polarity_margin"], polarity_tries=int(s["polarity_tries"]),
        polarity_linear_ratio=linear_polarity_ratio(commissioning.R_s_ohm, commissioning.L_dh_H, T_s, n,
                                                    int(s["pulse_sequences"]), int(inverter.delay_periods)),
        flush_samples=samples(s["flush_s"]), R_s_ohm=commissioning.R_s_ohm, L_dh_H=commissioning.L_dh_H,
        L_qh_H=commissioning.L_qh_H, delta_L_H=nameplate.L_d_H - nameplate.L_q_H, psi_f_Wb=nameplate.psi_f_Wb,
        dead_time_voltage_V=commissioning.dead_time_voltage_V,
        dead_time_smoothing_A=SMOOTHING_PER_RATED_CURRENT * nameplate.rated_current_A,
        lock_smoothing=1.0 - math.exp(-2.0 * math.pi * s["lock_filter_Hz"] * T_s),
        lock_threshold_V=threshold, lock_persist_samples=samples(s["lock_persist_s"]),
        lost_hold_samples=samples(s["lost_hold_s"]), max_restarts=int(s["max_restarts"]),
        backemf_polarity_ratio=s["backemf_polarity_ratio"],
        slip_at_sample=int(round(s["slip_at_s"] / T_s)) if s["slip_at_s"] >= 0.0 else -1,
        slip_rad=s["slip_rad"], polarity_from_recording=bool(s["polarity_from_recording"]))


@njit(cache=True)
def startup_reset(x, p):
    """Fresh start-up state: aligning from sample 0."""
    b = p.base
    for j in range(startup_size(p)):
        x[b + j] = 0.0
    x[b + CODE] = ALIGNING
    x[b + ERROR] = 1.0


@njit(cache=True)
def startup_code(x, p):
    """The current state code."""
    return int(x[p.base + CODE])


@njit(cache=True)
def _enter(x, p, k, code):
    """Enter state ``code`` at sample k."""
    b = p.base
    x[b + CODE] = code
    x[b + ENTERED] = k
    x[b + SETTLED] = 0.0
    x[b + ERROR] = 1.0
    x[b + BAD] = 0.0


@njit(cache=True)
def _turn(x, p, angle):
    """θ̂ turned by ``angle``; the back-EMF residual, kept in the θ̂ frame, turned with it."""
    b = p.base
    x[THETA] += angle
    x[b + RESIDUAL_D], x[b + RESIDUAL_Q] = rotate(x[b + RESIDUAL_D], x[b + RESIDUAL_Q], -angle)


@njit(cache=True)
def startup_follow(x, p, theta, omega):
    """Set θ̂ (x[0]) and its integrator (x[1]) to another source's ``theta`` [rad] and ``omega`` [rad/s]
    (the follower of a blend, hf_estimator.full_speed), the back-EMF residual turned with θ̂."""
    _turn(x, p, theta - x[THETA])
    x[INTEGRAL] = omega


@njit(cache=True)
def _backemf_residual(x, p, k, i_alpha, i_beta, u_alpha, u_beta):
    """Update the low-passed back-EMF residual (θ̂ frame) with sample k and the voltage (u_α, u_β) [V]
    applied in the period before it → its magnitude [V]."""
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
def _fit_backemf_angle(x, p, since):
    """Add this sample's back-EMF angle (stationary frame, unwrapped) to a straight-line fit over the
    lost-lock hold, when the back-EMF stands clear of its threshold."""
    b = p.base
    e_alpha, e_beta = x[b + E_ALPHA], x[b + E_BETA]
    if math.hypot(e_alpha, e_beta) <= p.backemf_polarity_ratio * p.lock_threshold_V:
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
def _seed_from_backemf(x, p, since):
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
            turn = theta - x[THETA]
            x[THETA] += turn - 2.0 * math.pi * math.floor((turn + math.pi) / (2.0 * math.pi))
            x[INTEGRAL] = omega
            x[b + RESIDUAL_D] = 0.0
            x[b + RESIDUAL_Q] = 0.0
            seeded = True
    for j in range(FIT_N, PHI_UNWRAPPED + 1):
        x[b + j] = 0.0
    return seeded


@njit(cache=True)
def _polarity_coefficients(m, n, length, sequences):
    """(S, T) weights of the d̂ current at pulse-clock sample m (module docstring, item 2)."""
    c_s = (-1.0, 2.0, -2.0, 2.0, -1.0)
    c_t = (-1.0, 2.0, 0.0, -2.0, 1.0)
    if m < 0 or m % n != 0 or m > sequences * length:
        return 0.0, 0.0
    w_s, w_t = 0.0, 0.0
    if m > 0 and m % length == 0:
        w_s += c_s[4]
        w_t += c_t[4] * _sequence_sign(m // length - 1)
    if m < sequences * length:
        j = (m % length) // n
        w_s += c_s[j]
        w_t += c_t[j] * _sequence_sign(m // length)
    return w_s, w_t


@njit(cache=True)
def _sequence_sign(sequence):
    """+1 for the sequences + − − +, −1 for the mirrored − + + − (every other one)."""
    return 1.0 if sequence % 2 == 0 else -1.0


@njit(cache=True)
def _pulse_sign(since, n):
    """+1 or −1: the sign of the polarity pulse issued at pulse-clock sample ``since``."""
    quarter = (since % (4 * n)) // n
    return (1.0 if quarter == 0 or quarter == 3 else -1.0) * _sequence_sign(since // (4 * n))


def linear_polarity_ratio(R_s_ohm, L_H, T_s, n, sequences, delay_periods):
    """S/T of the polarity pulses (n samples each, ``sequences`` of them, the drive's whole delay) on a
    linear R–L winding: the share the resistance gives where a pulse is not short against L/R (−0.03 at
    R·n·T_s/L ≈ 1.2, a 20 W gimbal motor, as large as its saturation's), not the magnet's. The start-up
    takes it off the measured S/T (module docstring, item 2)."""
    a = math.exp(-R_s_ohm * T_s / L_H)
    gain = (1.0 - a) / R_s_ohm if R_s_ohm > 0.0 else T_s / L_H
    length, i, score, span = 4 * n, 0.0, 0.0, 0.0
    for k in range(sequences * length + delay_periods + 1):
        w_s, w_t = _polarity_coefficients(k - delay_periods, n, length, sequences)
        score += w_s * i
        span += w_t * i
        issued = k - delay_periods
        i = a * i + gain * (_pulse_sign(issued, n) if 0 <= issued < sequences * length else 0.0)
    return score / span


@njit(cache=True)
def _hold(x, p, k):
    """Keep θ̂ at the held angle turning at the held speed, and the integrator at the held speed."""
    b = p.base
    x[INTEGRAL] = x[b + INTEGRAL_HELD]
    x[THETA] = x[b + THETA_HELD] + x[b + INTEGRAL_HELD] * (k - x[b + HELD_AT]) * p.T_s_s
    return x[THETA]


@njit(cache=True)
def _lost(x, p, k):
    """Enter LOCK_LOST, counting the loss."""
    _enter(x, p, k, LOCK_LOST)
    x[p.base + RESTARTS] += 1.0
    return float(LOCK_LOST)


@njit(cache=True)
def startup_step(x, p, k, i_alpha, i_beta, u_applied_alpha, u_applied_beta, u_inj_alpha, u_inj_beta, eps,
                 observable, theta_e_recorded):
    """Supervise sample k after the estimator's own step: the measured currents (α, β) [A], the voltage
    applied in the period before sample k [V], the estimator's injection for the coming period [V], its ε
    and observable flag; ``theta_e_recorded``: in replay, the recording drive's own estimate θ̂_e [rad] (NaN
    where the bag has none), read only with ``polarity_from_recording``. May turn or hold θ̂ (x[0]) and its
    integrator (x[1]). Returns (u_inj_α, u_inj_β, state code)."""
    b = p.base
    if k == p.slip_at_sample:
        _turn(x, p, p.slip_rad)
    residual = _backemf_residual(x, p, k, i_alpha, i_beta, u_applied_alpha, u_applied_beta)
    code = int(x[b + CODE])
    since = k - int(x[b + ENTERED])
    if x[b + REFUSED] != NOT_REFUSED:
        return 0.0, 0.0, float(HOLD if x[b + REFUSED] != TOO_MANY_LOSSES else LOCK_LOST)

    if code == ALIGNING:
        if x[b + QUIET] > 0.0:
            _hold(x, p, k)
            if k - (x[b + QUIET] - 1.0) < p.quiet_samples:
                return 0.0, 0.0, float(ALIGNING)
            x[b + QUIET] = 0.0
            _enter(x, p, k, POLARITY)
            since = 0
            code = POLARITY
        else:
            if observable > 0.5 and p.error_gain != 0.0:
                x[b + ERROR] += p.error_smoothing * (eps / p.error_gain - x[b + ERROR])
                tolerance = p.align_tolerance_rad
                if abs(x[INTEGRAL]) * p.psi_f_Wb > p.backemf_polarity_ratio * p.lock_threshold_V:
                    tolerance *= MOVING_TOLERANCE_FACTOR
                x[b + SETTLED] = x[b + SETTLED] + 1.0 if abs(x[b + ERROR]) < tolerance else 0.0
            else:
                x[b + SETTLED] = 0.0
            if x[b + SETTLED] < p.settle_samples:
                if since < p.align_timeout_samples:
                    return u_inj_alpha, u_inj_beta, float(ALIGNING)
                if x[b + RESTARTS] == 0.0:
                    clear = p.backemf_polarity_ratio * p.lock_threshold_V
                    backemf = math.hypot(x[b + E_ALPHA], x[b + E_BETA])
                    moving = max(abs(x[INTEGRAL]) * p.psi_f_Wb, backemf) > clear
                    x[b + REFUSED] = ROTOR_MOVED if observable > 0.5 or moving else NO_SALIENCY
                    return 0.0, 0.0, float(HOLD)
                return u_inj_alpha, u_inj_beta, _lost(x, p, k)
            x[b + THETA_HELD] = x[THETA]
            x[b + INTEGRAL_HELD] = x[INTEGRAL]
            x[b + HELD_AT] = k
            x[b + SCORE] = 0.0
            x[b + SPAN] = 0.0
            at_speed = abs(x[INTEGRAL]) * p.psi_f_Wb > p.backemf_polarity_ratio * p.lock_threshold_V
            recorded = p.polarity_from_recording and theta_e_recorded == theta_e_recorded
            if p.polarity_from_recording and not recorded and not at_speed:
                return u_inj_alpha, u_inj_beta, float(ALIGNING)
            if at_speed or recorded:
                if recorded:
                    flip = abs(wrap(theta_e_recorded - x[THETA])) > 0.5 * math.pi
                else:
                    backemf_q = x[b + RESIDUAL_Q] + x[INTEGRAL] * p.psi_f_Wb
                    flip = backemf_q * x[INTEGRAL] < 0.0
                x[b + FLIPPED] = 1.0 if flip else 0.0
                x[b + POLARITY_RATIO] = 0.0
                if flip:
                    _turn(x, p, math.pi)
                _enter(x, p, k - p.pulse_sequences * 4 * p.pulse_samples - p.delay_periods - 1, POLARITY)
                return u_inj_alpha, u_inj_beta, float(POLARITY)
            x[b + INTEGRAL_HELD] = 0.0
            x[b + QUIET] = k + 1.0
            return 0.0, 0.0, float(ALIGNING)

    if code == POLARITY:
        length = 4 * p.pulse_samples
        issue_end = p.pulse_sequences * length
        decide_at = issue_end + p.delay_periods
        if since <= decide_at:
            axis = _hold(x, p, k)
            i_d, _ = rotate(i_alpha, i_beta, -axis)
            w_s, w_t = _polarity_coefficients(since - p.delay_periods, p.pulse_samples, length, p.pulse_sequences)
            x[b + SCORE] += w_s * i_d
            x[b + SPAN] += w_t * i_d
            if since < issue_end:
                sign = _pulse_sign(since, p.pulse_samples)
                u_alpha, u_beta = rotate(sign * p.pulse_V, 0.0, axis + x[b + INTEGRAL_HELD] * p.T_s_s)
                return u_alpha, u_beta, float(POLARITY)
            if since < decide_at:
                return 0.0, 0.0, float(POLARITY)
            ratio = x[b + SCORE] / x[b + SPAN] - p.polarity_linear_ratio if x[b + SPAN] > 0.0 else 0.0
            x[b + POLARITY_RATIO] = ratio
            if abs(ratio) < p.polarity_margin:
                x[b + TRIES] += 1.0
                if x[b + TRIES] >= p.polarity_tries:
                    x[b + REFUSED] = NO_POLARITY
                    return 0.0, 0.0, float(HOLD)
                x[b + THETA_HELD] += 0.5 * math.pi
                _turn(x, p, 0.5 * math.pi)
                x[b + QUIET] = k + 1.0
                _enter(x, p, k, ALIGNING)
                return 0.0, 0.0, float(ALIGNING)
            x[b + FLIPPED] = 1.0 if ratio < 0.0 else 0.0
            if ratio < 0.0:
                _turn(x, p, math.pi)
            return u_inj_alpha, u_inj_beta, float(POLARITY)
        if since < decide_at + p.flush_samples:
            return u_inj_alpha, u_inj_beta, float(POLARITY)
        _enter(x, p, k, TRACKING)
        code = TRACKING

    if code == LOCK_LOST:
        if since < p.lost_hold_samples:
            _fit_backemf_angle(x, p, since)
            return u_inj_alpha, u_inj_beta, float(LOCK_LOST)
        _seed_from_backemf(x, p, since)
        if x[b + RESTARTS] > p.max_restarts:
            x[b + REFUSED] = TOO_MANY_LOSSES
            return 0.0, 0.0, float(LOCK_LOST)
        _enter(x, p, k, ALIGNING)
        return u_inj_alpha, u_inj_beta, float(ALIGNING)

    # TRACKING or HOLD: the lock monitor.
    expected = abs(x[INTEGRAL]) * p.psi_f_Wb
    measured = math.hypot(x[b + RESIDUAL_D], x[b + RESIDUAL_Q] + x[INTEGRAL] * p.psi_f_Wb)
    if residual > p.lock_threshold_V + 0.5 * max(expected, measured):
        x[b + BAD] += 1.0
    else:
        x[b + BAD] = 0.0
    if x[b + BAD] >= p.lock_persist_samples:
        return u_inj_alpha, u_inj_beta, _lost(x, p, k)
    code = TRACKING if observable > 0.5 else HOLD
    x[b + CODE] = code
    return u_inj_alpha, u_inj_beta, float(code)


def startup_summary(x, p):
    """What the start-up state says after a run: {state, refused (reason or None), polarity_ratio,
    flipped, lock_losses, tracking_since_sample}."""
    b = p.base
    refused = int(x[b + REFUSED])
    return {"state": STATE_NAMES[int(x[b + CODE])], "refused": REFUSALS.get(refused),
            "polarity_ratio": float(x[b + POLARITY_RATIO]), "flipped": bool(x[b + FLIPPED]),
            "restarts": int(x[b + RESTARTS])}



def estimator_startup(estimator):
    """startup_summary of a built estimator (hf_estimator.interface.Estimator), None if it has no start-up."""
    p = getattr(estimator.params, "startup", None)
    return None if p is None else startup_summary(estimator.x, p)
