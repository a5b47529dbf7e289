"""The start-up's polarity test (docs/startup.md; startup.py, items 2 and 5): the magnet's polarity on the
aligned axis, from voltage pulses + − − + (every other sequence mirrored) after a quiet time, from the
back-EMF's sign at speed, or in replay from the recording drive's own choice. With i_j the d̂ current at the j-th pulse
boundary, S = −i₀ + 2i₁ − 2i₂ + 2i₃ − i₄ = 2(A₊ − A₋) and T = −i₀ + 2i₁ − 2i₃ + i₄ = 2(A₊ + A₋); the magnet
saturates the d axis further when i_d > 0, so S/T < −margin means θ̂ is the magnet's south.

The pulses are designed from what the commissioning measured (polarity_design, docs/startup.md "Pulses
from the commissioning"): the saturation asymmetry gives the S/T to expect, the sensor noise its spread,
the inertia how far the pulses can turn the rotor when θ̂ is off the d axis."""
import math
from typing import NamedTuple

import numpy as np
from numba import njit

from drive_common.contract.estimator_states import ALIGNING, HOLD, POLARITY
from drive_common.math.frames import rotate, wrap

from .startup_state import (
    NO_POLARITY,
    backemf_clear,
    enter,
    hold,
    measured_backemf,
    turn,
)


@njit(cache=True)
def _sequence_sign(sequence):
    """+1 for the sequences + − − +, −1 for the mirrored − + + − (every other one)."""
    return 1.0 if sequence % 2 == 0 else -1.0


@njit(cache=True)
def polarity_coefficients(m, n, length, sequences):
    """(S, T) weights of the d̂ current at pulse-clock sample m (module docstring)."""
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
def pulse_sign(since, n):
    """+1 or −1: the sign of the polarity pulse issued at pulse-clock sample ``since``."""
    quarter = (since % (4 * n)) // n
    return (1.0 if quarter == 0 or quarter == 3 else -1.0) * _sequence_sign(since // (4 * n))


def winding_step(R_s_ohm, L_H, T_s):
    """(a, b) of a linear R–L winding held at a voltage u for one period: i ← a·i + b·u [A]."""
    a = math.exp(-R_s_ohm * T_s / L_H)
    return a, ((1.0 - a) / R_s_ohm if R_s_ohm > 0.0 else T_s / L_H)


def linear_polarity_ratio(R_s_ohm, L_H, T_s, n, sequences, delay_periods):
    """S/T of the polarity pulses (n samples each, ``sequences`` of them, the drive's whole delay) on a
    linear R–L winding: the share the resistance gives where a pulse is not short against L/R (−0.03 at
    R·n·T_s/L ≈ 1.2, a 20 W gimbal motor, as large as its saturation's), not the magnet's. The test takes
    it off the measured S/T."""
    a, gain = winding_step(R_s_ohm, L_H, T_s)
    length, i, score, span = 4 * n, 0.0, 0.0, 0.0
    for k in range(sequences * length + delay_periods + 1):
        w_s, w_t = polarity_coefficients(k - delay_periods, n, length, sequences)
        score += w_s * i
        span += w_t * i
        issued = k - delay_periods
        i = a * i + gain * (pulse_sign(issued, n) if 0 <= issued < sequences * length else 0.0)
    return score / span


@njit(cache=True)
def polarity_begin(x, p, k, u_inj_alpha, u_inj_beta, theta_e_recorded):
    """The axis aligned at sample k: θ̂ and ω̂ held; at speed (or in replay, with the recording drive's
    estimate θ̂_e [rad], NaN where it has none) the polarity is decided at once, else the injection stops
    for the quiet time before the pulses. At speed: the tracker's speed and the measured back-EMF both clear
    of the lock threshold (a tracker wound up while aligning a still rotor leaves the measured one at
    noise, whose sign tells nothing). → (u_α, u_β [V], state code)."""
    s = x.startup
    s.theta_held = x.theta
    if p.torque_pulse_A > 0.0 and s.axis_count > 0.0:
        s.theta_held = s.axis_ref + s.axis_sum / s.axis_count
        s.held_time = s.axis_time / s.axis_count
        s.held_omega = s.axis_omega / s.axis_count
    s.omega_held = x.omega
    s.held_at = k
    s.score = 0.0
    s.span = 0.0
    at_speed = backemf_clear(x, p, min(abs(x.omega) * p.psi_f_Wb, measured_backemf(x, p)))
    recorded = p.polarity_from_recording and theta_e_recorded == theta_e_recorded
    if p.polarity_from_recording and not recorded and not at_speed:
        return u_inj_alpha, u_inj_beta, float(ALIGNING)
    if at_speed or recorded:
        if recorded:
            flip = abs(wrap(theta_e_recorded - x.theta)) > 0.5 * math.pi
        else:
            backemf_q = s.residual_q + x.omega * p.psi_f_Wb
            flip = backemf_q * x.omega < 0.0
        s.flipped = 1.0 if flip else 0.0
        s.polarity_ratio = 0.0
        if flip:
            turn(x, p, math.pi)
        enter(x, p, k - p.pulse_sequences * 4 * p.pulse_samples - p.delay_periods - 1, POLARITY)
        return u_inj_alpha, u_inj_beta, float(POLARITY)
    s.omega_held = 0.0
    s.quiet = k + 1.0
    return 0.0, 0.0, float(ALIGNING)


@njit(cache=True)
def quiet_over(x, p, k):
    """During the quiet time before the pulses (θ̂ held, zero voltage): whether it is over at sample k,
    then the test entered."""
    s = x.startup
    hold(x, p, k)
    if k - (s.quiet - 1.0) < p.quiet_samples:
        return False
    s.quiet = 0.0
    s.score = 0.0
    s.span = 0.0
    s.torque_active = 1.0 if p.torque_pulse_A > 0.0 else 0.0
    enter(x, p, k, POLARITY)
    return True


@njit(cache=True)
def polarity_step(x, p, k, since, i_alpha, i_beta, u_inj_alpha, u_inj_beta):
    """Sample k, ``since`` samples into the test: pulses issued and the d̂ current scored, the decision
    (θ̂ turned by π for the south; no asymmetry: a quarter turn and another try, refused after
    polarity_tries), then the flush on the estimator's injection. The voltage applied in the period before
    sample k beside the pulses, net of the commissioned dead-time loss (``u_net_alpha``, ``u_net_beta``, left
    by the lock monitor's backemf_residual), drives a linear R–L model of the d̂ current from the first pulse
    on, which is taken off the scored current: the controller's fundamental frozen at a voltage the
    dead-time zone ate while aligning (−0.08 V on a 20 kHz robot joint) acts in full once the pulses'
    currents leave that zone, and neither its exponential rise nor the dead-time loss at the pulses' zero
    crossings cancels from S where L/R is short. → (done: the flush is over, u_α, u_β [V], state code)."""
    s = x.startup
    length = 4 * p.pulse_samples
    issue_end = p.pulse_sequences * length
    decide_at = issue_end + p.delay_periods
    if since <= decide_at:
        axis = hold(x, p, k)
        i_d, _ = rotate(i_alpha, i_beta, -axis)
        acting = since - 1 - p.delay_periods
        if acting < 0:
            s.other_current = 0.0
        else:
            u_d, _ = rotate(s.u_net_alpha, s.u_net_beta, -axis)
            pulse = pulse_sign(acting, p.pulse_samples) * p.pulse_V if acting < issue_end else 0.0
            s.other_current = p.other_decay * s.other_current + p.other_gain * (u_d - pulse)
        i_d -= s.other_current
        w_s, w_t = polarity_coefficients(since - p.delay_periods, p.pulse_samples, length, p.pulse_sequences)
        s.score += w_s * i_d
        s.span += w_t * i_d
        if since < issue_end:
            sign = pulse_sign(since, p.pulse_samples)
            u_alpha, u_beta = rotate(sign * p.pulse_V, 0.0, axis + s.omega_held * p.T_s_s)
            return False, u_alpha, u_beta, float(POLARITY)
        if since < decide_at:
            return False, 0.0, 0.0, float(POLARITY)
        ratio = s.score / s.span - p.polarity_linear_ratio if s.span > 0.0 else 0.0
        s.polarity_ratio = ratio
        if abs(ratio) < p.polarity_margin:
            s.tries += 1.0
            if s.tries >= p.polarity_tries:
                s.refused = NO_POLARITY
                return False, 0.0, 0.0, float(HOLD)
            s.theta_held += 0.5 * math.pi
            turn(x, p, 0.5 * math.pi)
            s.quiet = k + 1.0
            enter(x, p, k, ALIGNING)
            return False, 0.0, 0.0, float(ALIGNING)
        s.flipped = 1.0 if ratio < 0.0 else 0.0
        if ratio < 0.0:
            turn(x, p, math.pi)
        return False, u_inj_alpha, u_inj_beta, float(POLARITY)
    if since < decide_at + p.flush_samples:
        return False, u_inj_alpha, u_inj_beta, float(POLARITY)
    return True, 0.0, 0.0, float(POLARITY)


PULSE_CURRENT_MAX_PER_RATED = 1.0
"""Designed pulses reach at most rated current: the commissioning measured the asymmetry there."""
PULSE_CURRENT_STEP = 0.85
"""A pulse current that turns the rotor too far is lowered by this factor at a time."""
MAX_SEQUENCES = 32
"""The most pulse sequences (of 4 pulses) a test averages."""
DECISION_Z = 3.0
"""The decision margin is half the expected S/T and stands this many noise σ clear: a wrong pole needs noise
of 3 × 3 σ (one-sided probability 1e-19), a retry a quarter turn further 3 σ (1.3e-3; it then tries the
other axes, polarity_tries in all)."""
ANGLE_UNCERTAINTY_PER_TOLERANCE = 2.0
"""The modulo-π estimate may be off the d axis by this many alignment tolerances while pulsing (the
smoothed error is below one tolerance; one fit's noise is not)."""
SUBSTEPS = 16


class PolarityDesign(NamedTuple):
    """The polarity pulses: n samples each at ``pulse_V`` [V] reaching ``pulse_current_A``, ``sequences`` of
    them, the decision ``margin`` on S/T; what to expect: ``expected_ratio`` (the magnet's S/T), its noise σ
    ``noise_ratio``, the rotor's largest turn during them ``motion_e_rad`` [rad, electrical]; ``problem``:
    why the polarity cannot be told ("" where it can)."""
    n: int
    pulse_V: float
    pulse_current_A: float
    sequences: int
    margin: float
    expected_ratio: float
    noise_ratio: float
    motion_e_rad: float
    problem: str


def pulse_currents(winding, pulses, asymmetry):
    """The d̂ current [A] at each sample of a pulse train on a winding (R_s [Ω], L [H], I_rated [A], T_s [s])
    whose incremental inductance falls with magnetising current as the commissioning measured it between
    ±I_rated: L(i) = L·(1 − ½·asymmetry·i/I_rated); ``pulses``: (n, pulse_V, sequences, delay_periods)."""
    R, L, I_rated, T_s = winding
    n, pulse_V, sequences, delay = pulses
    issue_end = sequences * 4 * n
    out = np.zeros(issue_end + delay + 1)
    i, h = 0.0, T_s / SUBSTEPS
    for k in range(len(out)):
        out[k] = i
        issued = k - delay
        u = pulse_sign(issued, n) * pulse_V if 0 <= issued < issue_end else 0.0
        for _ in range(SUBSTEPS):
            i += h * (u - R * i) / (L * max(0.2, 1.0 - 0.5 * asymmetry * i / I_rated))
    return out


def _sums(currents, n, sequences, delay):
    """(S, T, Σ w_S²) of the first ``sequences`` sequences of a pulse train's currents."""
    score = span = weight = 0.0
    for k in range(sequences * 4 * n + delay + 1):
        w_s, w_t = polarity_coefficients(k - delay, n, 4 * n, sequences)
        score += w_s * currents[k]
        span += w_t * currents[k]
        weight += w_s * w_s
    return score, span, weight


def rotor_motion_e_rad(currents, rotor, T_s):
    """The largest turn [rad, electrical] of a rotor at rest under a pulse train's d̂ currents when θ̂ is
    ``e`` off the d axis; ``rotor``: (n_p, ψ_f [Wb], L_d − L_q [H], J [kg·m²], e [rad]). Torque
    1.5 n_p sin e (ψ_f i + ΔL cos e · i²)."""
    n_p, psi_f, delta_L, J, e = rotor
    torque = 1.5 * n_p * math.sin(e) * (psi_f * currents + delta_L * math.cos(e) * currents ** 2)
    speed = np.cumsum(torque) * T_s / J
    return float(n_p * np.max(np.abs(np.cumsum(speed) * T_s)))


def polarity_design(plate, commissioning, T_s, inverter, align_tolerance_rad, least_sequences):
    """The polarity pulses for a motor (its nameplate ``plate``, refined by the rotating test) from its
    commissioning: the largest pulse current up to rated current whose pulses turn the rotor (electrical) less
    than the alignment tolerance ``align_tolerance_rad`` (the test's axis stays as aligned), the shortest
    pulses the bus allows (0.8 U_dc/√3), and the fewest sequences (at least ``least_sequences``, even) whose
    noise leaves the expected S/T DECISION_Z σ clear of the margin, half of it. None where the commissioning
    holds no asymmetry or noise, or the inertia is unknown (the fixed pulses of DEFAULTS then). A
    PolarityDesign with ``problem`` set where no pulses can tell the polarity."""
    asymmetry, J = commissioning.saturation_asymmetry, plate.J_kgm2
    if not (math.isfinite(asymmetry) and math.isfinite(J) and commissioning.sensor_noise_A > 0.0):
        return None
    R, L, delay = commissioning.R_s_ohm, commissioning.L_dh_H, int(inverter.delay_periods)
    u_max = 0.8 * inverter.U_dc_V / math.sqrt(3.0)
    rotor = (plate.n_p, plate.psi_f_Wb, plate.L_d_H - plate.L_q_H, J, ANGLE_UNCERTAINTY_PER_TOLERANCE *
             align_tolerance_rad)
    first = max(2, least_sequences + least_sequences % 2)
    current, largest = PULSE_CURRENT_MAX_PER_RATED * min(plate.rated_current_A, plate.current_limit_A), None
    while current > 0.05 * plate.rated_current_A:
        resistive = 0.5 * R * current
        if resistive >= u_max:
            current *= PULSE_CURRENT_STEP
            continue
        n = max(2, math.ceil(current * L / (T_s * (u_max - resistive))))
        pulses = (n, current * L / (n * T_s) + resistive, MAX_SEQUENCES, delay)
        saturated = pulse_currents((R, L, plate.rated_current_A, T_s), pulses, asymmetry)
        linear = pulse_currents((R, L, plate.rated_current_A, T_s), pulses, 0.0)
        for sequences in range(first, MAX_SEQUENCES + 1, 2):
            score, span, weight = _sums(saturated, n, sequences, delay)
            score_linear, span_linear, _ = _sums(linear, n, sequences, delay)
            expected = float(abs(score / span - score_linear / span_linear))
            noise = float(commissioning.sensor_noise_A * math.sqrt(weight) / abs(span))
            if 0.5 * expected >= DECISION_Z * noise:
                break
        motion = rotor_motion_e_rad(saturated[:sequences * 4 * n + delay + 1], rotor, T_s)
        design = PolarityDesign(n, pulses[1], current, sequences, 0.5 * expected, expected, noise, motion, "")
        largest = largest or design
        if motion <= align_tolerance_rad:
            if design.margin >= DECISION_Z * noise:
                return design
            limited = " (larger ones turn the rotor too far)" if design is not largest else ""
            return design._replace(problem=(
                f"saturation asymmetry {100.0 * asymmetry:.2g} % (commissioned) gives the polarity pulses an S/T of "
                f"{expected:.2g} against noise σ {noise:.2g} ({sequences} sequences of {current:.3g} A{limited}; "
                f"{2.0 * DECISION_Z:g} σ wanted)"))
        current *= PULSE_CURRENT_STEP
    if largest is None:
        return PolarityDesign(0, u_max, 0.0, 0, 0.0, 0.0, math.inf, math.inf, (
            f"saturation asymmetry {100.0 * asymmetry:.2g} % (commissioned), but the bus's {u_max:.3g} V drive no "
            f"pulse current through R_s"))
    return largest._replace(problem=(
        f"saturation asymmetry {100.0 * asymmetry:.2g} % (commissioned): pulses that resolve it against the sensor "
        f"noise ({largest.sequences} sequences of {largest.pulse_current_A:.3g} A) turn the rotor "
        f"{largest.motion_e_rad:.2g} rad, more than the alignment tolerance {align_tolerance_rad:g} rad "
        f"(J {J:.3g} kg·m²)"))
