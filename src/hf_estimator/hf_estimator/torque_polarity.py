"""The polarity by the magnet's torque (docs/startup.md "Polarity by a torque pulse"): for a rotor whose d
axis does not saturate enough for the pulses of polarity_test.py (the commissioned asymmetry too small
against the sensor noise, or pulses that resolve it turning the rotor too far), with the estimate aligned on
the saliency axis (mod π) the drive applies a short q̂ current doublet, +I then −I for n samples each. Its
torque 1.5·n_p·ψ_f·i_q turns the rotor forwards when d̂ is the magnet's north and backwards when d̂ is its
south; the doublet's speed returns to zero, leaving the rotor turned by Δ = n_p·k_t·I·(n·T_s)²/J (electrical,
k_t = 1.5·n_p·ψ_f). The estimator then aligns again on its injection and the axis's turn, taken modulo π
(the saliency follows motion unambiguously within ±π/2), gives the pole: forwards, θ̂ was north; backwards,
south. No paper is implemented here: the idea is the "small-motion" commutation search of servo drives (a current
along an assumed axis, the sign of the motion it causes), here with the motion read by the saliency tracker and
the doublet sized from the nameplate's J so that the motion is bounded.

The shaft must be free to turn: a held or braked shaft does not move, and the test then refuses the start
after TRIES doublets (each GROWTH times the last's impulse: a rotor heavier than its J moves at most GROWTH
times the decision margin before the test sees it). The doublet's current follows a PI loop in the θ̂ frame
(the controller's fundamental is frozen during the test), its voltage limited to 0.8·U_dc/√3."""
import math
from typing import NamedTuple

from numba import njit

from drive_common.contract.estimator_states import ALIGNING, HOLD, POLARITY
from drive_common.math.frames import rotate, wrap

from .startup_state import NO_MOTION, enter, hold, turn

TARGET_E_RAD = 0.3
"""The doublet's designed turn of the rotor (electrical): several times the aligned axis's noise."""
TARGET_SHAFT_RAD = math.radians(2.0)
"""...and at most this at the shaft where that leaves at least TARGET_MIN_E_RAD."""
TARGET_MIN_E_RAD = 0.12
"""The least designed turn (electrical): the aligned axis's mean is good to a few hundredths of a radian (its
noise, a tracker still converging); a 1-pole-pair rotor then turns 6.9° at the shaft, a 2-pole-pair one 3.4°."""
BOUND_PER_TARGET = 2.5
"""The stated bound on the shaft's turn before torque, per designed turn: an escalation stops within GROWTH × the
margin (2 × the target), and a creep the injection leaves adds to it."""
MARGIN_PER_TARGET = 0.5
"""The decision margin on the measured turn: this share of the designed one."""
GROWTH = 4.0
"""A doublet that moved the rotor less than the margin is followed by one of this many times its impulse
(I·n²): the current first, up to the test's largest, then the length."""
TRIES = 7
"""The most doublets (GROWTH⁶ ≈ 4000: three decades and more of J above the one designed on); then the start
is refused: the shaft did not turn."""
LOOP_SHARE = 0.5
"""The PI loop's closed-loop rate per sample is this share over (1 + the drive's delay in periods)."""
SETTLE_S = 0.01
"""The alignments before and after a doublet settle this long; the axis is their mean over it."""
VOLTAGE_SHARE = 0.8
"""The doublet's voltage stays within this share of U_dc/√3."""


class TorquePolarityDesign(NamedTuple):
    """The first doublet: ``current_A`` [A] for ``samples`` samples each way, at most ``current_max_A`` in later
    tries; the PI loop's gains ``gain_d``, ``gain_q`` [V/A] and integral share per sample ``integral``; the
    designed turn ``target_e_rad`` and the decision ``margin_rad`` (electrical); ``bound_shaft_deg``: the
    largest turn of the shaft [° mechanical] on any rotor at least as heavy as the J designed on;
    ``torque_Nm``: the largest doublet's torque (friction or a held load beyond about half of it keeps the
    shaft from turning); ``problem``: why the test cannot run ("" where it can)."""
    current_A: float
    samples: int
    current_max_A: float
    gain_d: float
    gain_q: float
    integral: float
    tail_samples: int
    voltage_max_V: float
    target_e_rad: float
    margin_rad: float
    bound_shaft_deg: float
    torque_Nm: float
    problem: str


def doublet_turn_e_rad(n_p, psi_f_Wb, J_kgm2, current_A, duration_s):
    """The rotor's turn [rad, electrical] after a current doublet ±``current_A`` of ``duration_s`` each way,
    from rest, without friction: n_p·k_t·I·τ²/J."""
    return n_p * 1.5 * n_p * psi_f_Wb * current_A * duration_s ** 2 / J_kgm2


def torque_polarity_design(plate, commissioning, T_s, inverter):
    """The torque polarity test for a motor (its nameplate ``plate``, refined by the rotating test: J, ψ_f;
    ``commissioning``: R_s, L_dh, L_qh) on ``inverter`` (U_dc, the drive's delay) sampled every T_s [s]."""
    J, psi_f, n_p = plate.J_kgm2, plate.psi_f_Wb, plate.n_p
    if not (math.isfinite(J) and J > 0.0 and psi_f > 0.0):
        return TorquePolarityDesign(0.0, 0, 0.0, 0.0, 0.0, 0.0, 0, 0.0, 0.0, 0.0, math.inf, 0.0,
                                    "the rotor's inertia is unknown: the torque pulse cannot be bounded")
    delay = int(inverter.delay_periods)
    rate = LOOP_SHARE / (1.0 + delay)
    least = math.ceil(4.0 / rate)
    target = min(TARGET_E_RAD, max(TARGET_MIN_E_RAD, n_p * TARGET_SHAFT_RAD))
    current_max = min(plate.rated_current_A, plate.current_limit_A)
    duration = math.sqrt(target * J / (n_p * 1.5 * n_p * psi_f * current_max))
    samples = max(least, math.ceil(duration / T_s))
    current = min(current_max, target * J / (n_p * 1.5 * n_p * psi_f * (samples * T_s) ** 2))
    margin = MARGIN_PER_TARGET * target
    bound_e = BOUND_PER_TARGET * target
    voltage_max = VOLTAGE_SHARE * inverter.U_dc_V / math.sqrt(3.0)
    return TorquePolarityDesign(
        current, samples, current_max, rate * commissioning.L_dh_H / T_s, rate * commissioning.L_qh_H / T_s,
        0.25 * rate, 2 * least, voltage_max, target, margin, math.degrees(bound_e / n_p),
        1.5 * n_p * psi_f * current_max, "")


def startup_fields(design):
    """The StartupParams fields of the torque test (``design``: a TorquePolarityDesign; None: the saturation
    pulses, every field 0)."""
    d = design
    return {"torque_pulse_A": d.current_A if d else 0.0, "torque_pulse_samples": d.samples if d else 0,
            "torque_pulse_max_A": d.current_max_A if d else 0.0, "torque_growth": GROWTH, "torque_tries": TRIES,
            "torque_margin_rad": d.margin_rad if d else 0.0, "torque_gain_d": d.gain_d if d else 0.0,
            "torque_gain_q": d.gain_q if d else 0.0, "torque_integral": d.integral if d else 0.0,
            "torque_tail_samples": d.tail_samples if d else 0, "torque_voltage_max_V": d.voltage_max_V if d else 0.0,
            "torque_bound_shaft_deg": d.bound_shaft_deg if d else 0.0, "torque_max_Nm": d.torque_Nm if d else 0.0}


def torque_polarity_note(startup):
    """What the drive says before running where its start-up (StartupParams) tells the polarity by a torque
    pulse; "" where it does not."""
    if startup.torque_pulse_A <= 0.0:
        return ""
    return (f"the magnet's polarity told by torque pulses on the free shaft (too little saturation asymmetry for "
            f"the d-axis pulses): the shaft turns up to {startup.torque_bound_shaft_deg:.2g}° and back; a brake, a "
            f"held shaft, or friction or a load beyond about {0.5 * startup.torque_max_Nm:.3g} N·m keeps it still "
            f"and the start is refused")


@njit(cache=True)
def doublet(p, tries):
    """(current [A], samples each way) of the doublet of try ``tries`` (GROWTH^tries the first's impulse)."""
    growth = p.torque_growth ** tries
    current = min(p.torque_pulse_A * growth, p.torque_pulse_max_A)
    return current, int(round(p.torque_pulse_samples * math.sqrt(growth * p.torque_pulse_A / current)))


@njit(cache=True)
def torque_step(x, p, k, since, i_alpha, i_beta, u_inj_alpha, u_inj_beta):
    """Sample k, ``since`` samples into a doublet (θ̂ held): the PI loop's voltage (u_α, u_β) [V] for i_d̂ = 0
    and i_q̂ = ±I (−∓I for the mirrored second doublet of a pair), then a tail whose first half's q̂ current brings
    the measured ∫i_q̂ back to zero (the rotor's speed k_t·∫i_q dt/J with it, whatever the loop's error) and whose
    second half's is zero; after it
    the estimator aligns again (its injection back) and torque_decide judges the turn. → (u_α, u_β, state)."""
    s = x.startup
    axis = hold(x, p, k)
    current, n = doublet(p, s.tries)
    sign = 1.0 if s.moved == 0.0 else -1.0
    if since == 0:
        s.pi_d = 0.0
        s.pi_q = 0.0
        s.charge = 0.0
    end = 2 * n + p.torque_tail_samples
    if since >= end:
        s.torque_active = 0.0
        s.moved += 1.0
        x.omega = 0.0
        enter(x, p, k, ALIGNING)
        return u_inj_alpha, u_inj_beta, float(ALIGNING)
    if since == n:
        s.doublet_at = k
    i_d, i_q = rotate(i_alpha, i_beta, -axis)
    s.charge += i_q
    balance_end = 2 * n + p.torque_tail_samples // 2
    if since < 2 * n:
        reference = sign * (current if since < n else -current)
    elif since < balance_end:
        reference = min(max(-s.charge / (balance_end - since), -current), current)
    else:
        reference = 0.0
    e_d, e_q = -i_d, reference - i_q
    s.pi_d += p.torque_integral * p.torque_gain_d * e_d
    s.pi_q += p.torque_integral * p.torque_gain_q * e_q
    u_d = p.torque_gain_d * e_d + s.pi_d
    u_q = p.R_s_ohm * reference + p.torque_gain_q * e_q + s.pi_q
    magnitude = math.hypot(u_d, u_q)
    if magnitude > p.torque_voltage_max_V:
        u_d *= p.torque_voltage_max_V / magnitude
        u_q *= p.torque_voltage_max_V / magnitude
    u_alpha, u_beta = rotate(u_d, u_q, axis)
    return u_alpha, u_beta, float(POLARITY)


@njit(cache=True)
def axis_turn(angle):
    """An angle [rad] taken modulo π into [−π/2, π/2): the turn of an axis."""
    return angle - math.pi * math.floor(angle / math.pi + 0.5)


@njit(cache=True)
def torque_decide(x, p, k):
    """Aligned again after a doublet at sample k: the axis's turn since the held axis (mod π, the mean over the
    settled samples; the held axis kept on the first's end), less the creep of a rotor the injection or the
    doublet left turning (ω̂'s mean over each alignment, before the doublet's middle and after it) → (decided,
    state code). After the first doublet of
    a pair the turn is kept and the mirrored one follows after the quiet time; after the mirrored one, half the
    difference of the two turns (a creep of the rotor at rest, the same in both, cancels; the rotor is back
    where it was): forwards beyond the margin, θ̂'s end nearer the north is kept, backwards θ̂ goes to the other
    end; within the margin another pair GROWTH times stronger, or, after TRIES pairs, the start is refused (the
    shaft did not turn)."""
    s = x.startup
    count = max(s.axis_count, 1.0)
    axis, at, omega = s.axis_ref + s.axis_sum / count, s.axis_time / count, s.axis_omega / count
    moved = axis_turn(axis - s.theta_held)
    creep = (s.held_omega * (s.doublet_at - s.held_time) + omega * (at - s.doublet_at)) * p.T_s_s
    turned = moved - creep
    s.theta_held += moved
    s.held_time = at
    s.held_omega = omega
    s.held_at = k
    s.omega_held = 0.0
    if s.moved < 1.5:
        s.first_turn = turned
        s.quiet = k + 1.0
        return False, float(ALIGNING)
    s.moved = 0.0
    forwards = 0.5 * (s.first_turn - turned)
    s.polarity_ratio = forwards
    if abs(forwards) < p.torque_margin_rad:
        s.tries += 1.0
        if s.tries >= p.torque_tries:
            s.refused = NO_MOTION
            return False, float(HOLD)
        s.quiet = k + 1.0
        return False, float(ALIGNING)
    north = s.theta_held + (0.0 if forwards > 0.0 else math.pi)
    flip = abs(wrap(x.theta - north)) > 0.5 * math.pi
    s.flipped = 1.0 if flip else 0.0
    if flip:
        turn(x, p, math.pi)
    return True, float(POLARITY)
