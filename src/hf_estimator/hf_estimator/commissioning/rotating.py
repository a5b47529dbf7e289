"""The rotating test (optional, docs/commissioning.md "The rotating test"): the magnet flux ψ_f, the
inertia J and the viscous friction B, which a nameplate often gets wrong or leaves out and the loops need.
The shaft must be free to turn and unloaded. After its standstill commissioning, the drive runs itself
(ours, sensorless) through a speed profile and reads these from its own signals only: its voltage
command, its measured currents, its angle and speed estimates. Plain numpy, once per test.

- ψ_f: at each steady speed the voltage equation in the estimated rotor frame, averaged over the hold
  (the HF injection and the current ripple average out): ū_q = R̂·ī_q + ω̂·L_d·ī_d + ω̂·ψ_f, with the
  command turned back by the angle the controller turned it by and the commissioned dead-time loss
  taken off; ψ_f is fitted over both holds (one slope through the origin).
- B and a constant friction torque τ_c: the torque 1.5·n_p·(ψ̂_f·i_q + (L_d − L_q)·i_d·i_q) held at the
  two speeds.
- J: over the step up from the first speed to the second and the step back down, the torque less friction,
  integrated, over the change of speed: J = (∫_up − ∫_down)(τ̂ − τ_c − B·ω̂_m) dt / (Δω̂_up − Δω̂_down), the
  speed and the integral alike averaged over END_AVERAGE_S at each end (a speed averaged there paired with
  the integral up to its midpoint leaves out the torque of the last half average: 3-15 % of J where the
  speed still moves), each window as long as the step up took to settle. The
  rotor crosses the same speeds both ways in windows of one length, so an error in the friction model
  (τ_c exactly, B mostly) cancels between them: on a light rotor friction's integral over a window is as
  large as J·Δω (J from the step up alone: 5-13 % off with the plant's true torque and speed).

The speed loop must be tuned on a J before J is known. The drive tunes its first pass on the nameplate's J,
or where it gives none on the lightest rotor the rating allows (ASSUMED_RAMP_S: a heavier rotor only makes
that loop and the polarity pulses softer, never unstable); from every pass it fits J to the torque it made
and the speed it got (``inertia_from_log``) and runs again on that J until the J it tuned on and the one it
measured agree within RETUNE_FACTOR (``next_inertia_kgm2``, at most PASSES passes).
"""
import math

import numpy as np

from drive_common.contract.errors import DriveError
from drive_common.contract.estimator_states import TRACKING
from drive_common.contract.log import COLUMN
from drive_common.math.current_sensing import corrected_currents
from drive_common.math.dead_time import SMOOTHING_PER_RATED_CURRENT, dead_time_direction
from drive_common.motor.commissioning import WEAK_SALIENCY_RATIO

SPEEDS_PER_RATED = (0.1, 0.2)
"""The two held speeds, per rated speed: where ours tracks (docs/results.md) and the back-EMF stands
clear of the dead-time voltage."""
RAMP_END_S, STEP_S, STEP_DOWN_S, DURATION_S = 0.25, 0.6, 1.0, 1.4
HOLD_WINDOWS_S = ((0.35, 0.6), (0.8, 1.0), (1.2, 1.4))
HOLD_SPEEDS_PER_RATED = (SPEEDS_PER_RATED[0], SPEEDS_PER_RATED[1], SPEEDS_PER_RATED[0])
END_AVERAGE_S = 0.02
SETTLED_SHARE = 0.02
"""The step ends where the speed stays within this share of the second hold's for END_AVERAGE_S: a short
window keeps the friction model's error out of J on a light rotor."""
FOLLOW_TOLERANCE = 0.1
"""The test counts only where the drive tracked throughout and held each speed within this share."""
ASSUMED_RAMP_S = 0.003
"""Where the nameplate gives no J, the first pass tunes the speed loop (and sizes the polarity pulses) for the
lightest rotor the rating allows: one that rated torque takes to rated speed in this long (docs/random-motors.md:
3 ms-3 s). On a heavier rotor that loop is slower and the pulses turn it less: it follows the profile late, but
it never hunts, and the pass measures J for the next."""
TEST_SPEED_BANDWIDTH_RAD_S = 20.0
"""The speed loop's bandwidth in every pass: soft, for the test needs no stiffness (the loop scaled to the motor,
on the J measured, hunted on a 22 pole-pair rotor: ω̂ swung by 14 % of the hold's speed)."""
PASSES = 4
"""At most this many passes; each tuned on the J the one before measured."""
RETUNE_FACTOR = 1.25
"""A pass whose measured J lies within this factor of the J it was tuned on is the test's result; else the test
runs again tuned on the J measured (a speed loop on a J off by more settles late, and its step's window takes
friction's error into J)."""
ESCALATION = 30.0
"""Where a pass tracked but moved the rotor too little to measure J (less than MOVED_SHARE of the first speed),
the next pass assumes a rotor this many times heavier, up to HEAVIEST_RAMP_S."""
MOVED_SHARE = 0.1
HEAVIEST_RAMP_S = 10.0
"""The heaviest rotor the test serves: rated torque takes it to rated speed in this long (its profile then
stretched to about 28 s); a pass tuned on it that still does not move the rotor ends the test."""
TRACKED_SHARE = 0.5
"""A pass in which ours tracked less than this share of the test teaches nothing of J: the test ends."""
RIPPLE_SHARE = 0.1
"""The speed, averaged over RIPPLE_AVERAGE_S, may swing by this share of a hold's speed (RMS): beyond, the
loop hunts and the holds are not steady."""
RIPPLE_AVERAGE_S = 0.01


class RotatingTestError(DriveError):
    """The drive did not follow the rotating test's profile: nothing is measured."""


def speed_profile(rated_speed_rpm, timing=(1.0, 0.0)):
    """The test's speed reference: [[t_s, rpm], ...] (linear), from rest; ``timing``: (its times' stretch, each
    step's ramp [s]) of test_timing."""
    stretch, ramp_s = timing
    low, high = (share * rated_speed_rpm for share in SPEEDS_PER_RATED)
    points = [[0.0, 0.0], [0.05, 0.0], [RAMP_END_S, low], [STEP_S, low]]
    points = [[stretch * t, v] for t, v in points]
    up, down = stretch * STEP_S, stretch * STEP_DOWN_S
    return points + [[up + ramp_s, high], [down, high], [down + ramp_s, low], [stretch * DURATION_S, low]]


STEP_TIME_S = 0.1
"""A speed step of the test may take this long at the base timing (half the time to the next hold)."""
STEP_TORQUE_PER_RATED = 0.5
"""A step's reference ramps at the rate this share of rated torque gives the rotor: the speed loop then asks
for about it, not for the current limit, and the acceleration stays one ours' loops follow (they are scaled
to a rated-torque step, drive_common.motor.scaled_loops)."""


def assumed_inertia_kgm2(nameplate, ramp_s=ASSUMED_RAMP_S):
    """J [kg·m²] of a rotor that rated torque takes to rated speed in ``ramp_s``: the first pass's where the
    nameplate has none (ASSUMED_RAMP_S), the heaviest the test serves (HEAVIEST_RAMP_S)."""
    return nameplate.rated_torque_Nm * ramp_s / (nameplate.rated_speed_rpm * math.pi / 30.0)


def test_timing(nameplate, J_kgm2):
    """(stretch ≥ 1, ramp [s]) of a pass on a rotor of inertia ``J_kgm2``: each step of SPEEDS_PER_RATED[0] ×
    rated speed ramps at STEP_TORQUE_PER_RATED of rated torque, and where that ramp takes longer than
    STEP_TIME_S the whole profile is stretched to give it that room (a heavy rotor's test is longer)."""
    step = SPEEDS_PER_RATED[0] * nameplate.rated_speed_rpm * math.pi / 30.0
    ramp_s = J_kgm2 * step / (STEP_TORQUE_PER_RATED * nameplate.rated_torque_Nm)
    return max(1.0, ramp_s / STEP_TIME_S), ramp_s


AT_LIMIT_SHARE = 0.95
"""A q current reference at this share of the test's current limit or more counts as at the limit: the speed loop
asked for all it may (a load or a brake against it)."""


def _current_at(i_q_ref, window, limit_A):
    """(the largest |i_q*| [A] over the samples ``window``, whether it reaches AT_LIMIT_SHARE of ``limit_A``)."""
    peak = float(np.max(np.abs(i_q_ref[window]))) if window.any() else 0.0
    return peak, peak >= AT_LIMIT_SHARE * limit_A


def _why_lost(t, log, limit_A, saliency_ratio):
    """The measured cause of ours losing track in the rotating test, with its figure."""
    state = log[:, COLUMN["state"]]
    first = int(np.argmax((t >= HOLD_WINDOWS_S[0][0]) & (state != TRACKING)))
    before = (t >= t[first] - 0.05 * t[1] / log[1, COLUMN["t"]]) & (t <= t[first])
    peak, at_limit = _current_at(log[:, COLUMN["i_q_ref"]], before, limit_A)
    where = f"at {log[first, COLUMN['t']]:.3f} s, ω̂ {log[first, COLUMN['omega_e_hat']]:.3g} rad/s el."
    if at_limit:
        return f"{where}, the q current at its limit ({peak:.3g} of {limit_A:.3g} A): a load on the shaft"
    if saliency_ratio < WEAK_SALIENCY_RATIO:
        return (f"{where}, the q current {peak:.3g} A below its limit: weak saliency (|Δ|/Σ = {saliency_ratio:.3g} "
                f"< {WEAK_SALIENCY_RATIO:g})")
    return (f"{where}, the q current {peak:.3g} A below its limit {limit_A:.3g} A and |Δ|/Σ = {saliency_ratio:.3g}: "
            f"neither a load nor a weak saliency; ours' loops lost the angle (`drive motor show` prints them)")


def _check_followed(t, log, omega_m, rated_speed_rad_s, limit_A, saliency_ratio, J_assumed):
    """RotatingTestError unless the estimator tracked from the first hold on and each hold's speed lies
    within FOLLOW_TOLERANCE of its reference; its message names the cause measured (the q current against the
    test's ``limit_A``, the commissioned ``saliency_ratio``, the speed's swing) and its figure."""
    tracking = log[t >= HOLD_WINDOWS_S[0][0], COLUMN["state"]] == TRACKING
    if not tracking.all():
        lost = 100.0 * (1.0 - tracking.mean())
        raise RotatingTestError(f"the rotating test: the estimator stopped tracking for {lost:.0f} % of the test "
                                f"({_why_lost(t, log, limit_A, saliency_ratio)}): ψ_f and J not measured")
    per = max(1, int(round(RIPPLE_AVERAGE_S / (t[1] - t[0]))))
    for (a, b), share in zip(HOLD_WINDOWS_S, HOLD_SPEEDS_PER_RATED):
        window = (t >= a) & (t < b)
        hold = omega_m[window]
        held, wanted = float(np.mean(hold)), share * rated_speed_rad_s
        if abs(held - wanted) > FOLLOW_TOLERANCE * wanted:
            peak, at_limit = _current_at(log[:, COLUMN["i_q_ref"]], window, limit_A)
            cause = (f"the q current at its limit ({peak:.3g} of {limit_A:.3g} A): a load or a brake on the shaft"
                     if at_limit else f"the q current {peak:.3g} A, below its limit {limit_A:.3g} A: the speed loop "
                                      f"did not settle within the hold")
            raise RotatingTestError(f"the rotating test: the shaft held {held:.3g} rad/s where {wanted:.3g} rad/s "
                                    f"was asked ({cause}): ψ_f and J not measured")
        ripple = float(np.std(hold[:len(hold) // per * per].reshape(-1, per).mean(axis=1)))
        if ripple > RIPPLE_SHARE * wanted:
            J = ("tuned on the J the pass before measured, the first pass on the lightest rotor the rating "
                 "allows" if J_assumed else "tuned on the J the pass before measured, the first on the nameplate's")
            raise RotatingTestError(f"the rotating test: the speed swung by {ripple:.3g} rad/s RMS about "
                                    f"{wanted:.3g} rad/s, more than {RIPPLE_SHARE:g} of it (the speed loop hunts; "
                                    f"{J}): ψ_f and J not measured")


def _tracked_span(state):
    """The samples of the longest run in which ours tracked (a boolean mask)."""
    tracking = np.concatenate([[False], state == TRACKING, [False]])
    edges = np.flatnonzero(np.diff(tracking.astype(int)))
    starts, ends = edges[::2], edges[1::2]
    mask = np.zeros(state.shape, dtype=bool)
    if starts.size:
        longest = int(np.argmax(ends - starts))
        mask[starts[longest]:ends[longest]] = True
    return mask


def inertia_from_log(log, nameplate, T_s, psi_f_Wb=None):
    """J [kg·m²] fitted to a pass's log (drive_common.contract.log columns) over the longest span ours tracked,
    whatever the speed loop did there: the torque 1.5·n_p·(ψ_f·i_q + (L_d − L_q)·i_d·i_q) (``psi_f_Wb``, else
    the nameplate's; its L_d, L_q) integrated equals J·(ω̂_m − ω̂_m(0)) + τ_c·t + B·∫ω̂_m dt + c, fitted by
    least squares (integrated, the speed estimate's noise enters once, not differentiated). NaN where the
    speed moved less than MOVED_SHARE of the first held speed (nothing to measure J by), None where ours
    tracked less than TRACKED_SHARE of the test (no J would make it track)."""
    t, n_p = log[:, COLUMN["t"]], nameplate.n_p
    psi_f_Wb = nameplate.psi_f_Wb if psi_f_Wb is None else psi_f_Wb
    span = _tracked_span(log[:, COLUMN["state"]]) & (t >= RAMP_END_S * 0.2)
    if np.count_nonzero(span) < TRACKED_SHARE * t.size:
        return None
    i_d, i_q = log[span, COLUMN["i_d"]], log[span, COLUMN["i_q"]]
    omega_m = log[span, COLUMN["omega_e_hat"]] / n_p
    torque = 1.5 * n_p * (psi_f_Wb * i_q + (nameplate.L_d_H - nameplate.L_q_H) * i_d * i_q)
    wanted = SPEEDS_PER_RATED[0] * nameplate.rated_speed_rpm * math.pi / 30.0
    if np.ptp(omega_m) < MOVED_SHARE * wanted:
        return math.nan
    design = np.column_stack([omega_m - omega_m[0], t[span] - t[span][0], np.cumsum(omega_m) * T_s,
                              np.ones_like(omega_m)])
    (J, *_), *_ = np.linalg.lstsq(design, np.cumsum(torque) * T_s, rcond=None)
    return float(J) if J > 0.0 else math.nan


def next_inertia_kgm2(J_tuned_kgm2, J_measured_kgm2, last, heaviest_kgm2=math.inf):
    """The J the next pass tunes on, or None: the test is done (the pass's J within RETUNE_FACTOR of the one it
    was tuned on, the ``last`` pass, or a pass that taught nothing of J). ``J_measured_kgm2``: the pass's J
    (None: ours did not track; NaN: the rotor did not move, the next pass assumes one ESCALATION times heavier,
    up to ``heaviest_kgm2``)."""
    if last or J_measured_kgm2 is None:
        return None
    if not math.isfinite(J_measured_kgm2):
        return None if J_tuned_kgm2 >= heaviest_kgm2 else min(J_tuned_kgm2 * ESCALATION, heaviest_kgm2)
    ratio = J_measured_kgm2 / J_tuned_kgm2
    return None if 1.0 / RETUNE_FACTOR <= ratio <= RETUNE_FACTOR else J_measured_kgm2


def _settled_s(t, omega_m, target):
    """The first instant after the step from which ω̂_m, averaged over END_AVERAGE_S (the estimate is
    noisy sample by sample), stays within SETTLED_SHARE of ``target`` for END_AVERAGE_S (the second
    hold's start when it never does)."""
    T_s = t[1] - t[0]
    need = max(1, int(round(END_AVERAGE_S / T_s)))
    smooth = np.convolve(omega_m, np.ones(need) / need, mode="same")
    inside = (t >= STEP_S) & (np.abs(smooth - target) <= SETTLED_SHARE * abs(target))
    run = 0
    for k in np.nonzero(t >= STEP_S)[0]:
        run = run + 1 if inside[k] else 0
        if run == need:
            return float(t[k - need + 1])
    return HOLD_WINDOWS_S[1][0]


def rotating_estimates(log, nameplate, commissioning, T_s, delay_periods, stretch=1.0):
    """{psi_f_Wb, J_kgm2, B_Nms, friction_Nm, speeds_rad_s} from the test's log (drive_common.contract.log
    columns), the drive's ``nameplate`` (L_d, L_q, n_p) and ``commissioning`` record (R_s, dead time,
    sensor calibration), sampled every ``T_s`` with the controller's ``delay_periods``, its profile
    ``stretch`` times the base timing (its windows read on t / stretch)."""
    t = log[:, COLUMN["t"]] / stretch
    n_p = nameplate.n_p
    omega_e = log[:, COLUMN["omega_e_hat"]]
    limit = min(nameplate.current_limit_A, commissioning.tracking_current_limit_A())
    _check_followed(t, log, omega_e / n_p, nameplate.rated_speed_rpm * math.pi / 30.0, limit,
                    abs(commissioning.delta / commissioning.sigma), not math.isfinite(nameplate.J_kgm2))
    angle = log[:, COLUMN["theta_e_hat"]] + (delay_periods + 0.5) * omega_e * T_s
    c, s = np.cos(angle), np.sin(angle)
    u_a, u_b = log[:, COLUMN["u_alpha"]], log[:, COLUMN["u_beta"]]
    phases = corrected_currents.py_func(*(log[:, COLUMN[f"i_{x}_meas"]] for x in "abc"), commissioning.calibration())
    loss_a, loss_b = dead_time_direction.py_func(*phases, SMOOTHING_PER_RATED_CURRENT * nameplate.rated_current_A)
    u_a = u_a - commissioning.dead_time_voltage_V * loss_a
    u_b = u_b - commissioning.dead_time_voltage_V * loss_b
    u_q = -s * u_a + c * u_b
    i_d, i_q = log[:, COLUMN["i_d"]], log[:, COLUMN["i_q"]]
    holds = [(t >= a) & (t < b) for a, b in HOLD_WINDOWS_S]
    emf = np.array([np.mean(u_q[w] - commissioning.R_s_ohm * i_q[w] - omega_e[w] * nameplate.L_d_H * i_d[w])
                    for w in holds])
    speeds_e = np.array([np.mean(omega_e[w]) for w in holds])
    psi_f = float(np.dot(emf, speeds_e) / np.dot(speeds_e, speeds_e))
    torque = 1.5 * n_p * (psi_f * i_q + (nameplate.L_d_H - nameplate.L_q_H) * i_d * i_q)
    held = np.array([np.mean(torque[w]) for w in holds])
    speeds_m = speeds_e / n_p
    (B, friction), *_ = np.linalg.lstsq(np.column_stack([speeds_m, np.ones_like(speeds_m)]), held, rcond=None)
    B, friction = float(B), float(friction)
    omega_m = omega_e / n_p
    length = _settled_s(t, omega_m, speeds_m[1]) + END_AVERAGE_S - STEP_S
    accelerating = np.cumsum(torque - friction - B * omega_m) * T_s
    impulse, gained = [], []
    for at in (STEP_S, STEP_DOWN_S):
        start = (t >= at - END_AVERAGE_S) & (t < at)
        end = (t >= at + length - END_AVERAGE_S) & (t < at + length)
        gained.append(float(np.mean(omega_m[end]) - np.mean(omega_m[start])))
        impulse.append(float(np.mean(accelerating[end]) - np.mean(accelerating[start])))
    J = (impulse[0] - impulse[1]) / (gained[0] - gained[1])
    return {"psi_f_Wb": psi_f, "J_kgm2": J, "B_Nms": B, "friction_Nm": friction,
            "speeds_rad_s": [float(w) for w in speeds_m]}
