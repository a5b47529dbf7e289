"""Start-up and lock supervision, shared by every injecting estimator (docs/startup.md): the supervisor.
Each job is its own module: the alignment (alignment.py, item 1), the polarity test (polarity_test.py,
items 2 and 5), the lock monitor and what follows a lost lock (lock_monitor.py, items 3 and 4); their
shared state and parameters are startup_state.py.

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

from numba import njit

from drive_common.contract.estimator_states import ALIGNING, HOLD, LOCK_LOST, POLARITY, STATE_NAMES, TRACKING
from drive_common.math.dead_time import SMOOTHING_PER_RATED_CURRENT
from drive_common.motor.commissioning import NAMEPLATE_ONLY

from .alignment import ALIGN_SMOOTHING_S, alignment_step
from .lock_monitor import backemf_residual, lock_step, reacquire_step
from .polarity_test import (
    linear_polarity_ratio,
    polarity_begin,
    polarity_design,
    polarity_step,
    quiet_over,
    winding_step,
)
from .startup_state import (
    NO_MOTION,
    NO_POLARITY,
    NO_SALIENCY,
    NO_SETTLED_AXIS,
    NOT_REFUSED,
    ROTOR_MOVED,
    TOO_MANY_LOSSES,
    StartupParams,
    enter,
    turn,
)
from .torque_polarity import SETTLE_S as TORQUE_SETTLE_S
from .torque_polarity import startup_fields, torque_decide, torque_polarity_design, torque_step

REFUSALS = {NO_SALIENCY: "no saliency found: HF injection cannot tell this rotor's angle (a round rotor?)",
            ROTOR_MOVED: "the rotor turned while aligning (a load driving the shaft?): no still saliency axis "
                         "to align on; start with the shaft held or braked",
            NO_SETTLED_AXIS: "no saliency axis settled while aligning although the motor's L_dh and L_qh differ: too "
                             "weak an angle signal against the sensor noise (the drive's predicted angle error)",
            NO_POLARITY: "no saturation asymmetry on the d axis: the magnet's polarity cannot be told",
            TOO_MANY_LOSSES: "lock lost too often; holding zero torque",
            NO_MOTION: "the shaft did not turn under the polarity test's torque pulses (a brake, a held shaft or a "
                       "load beyond their torque): the magnet's polarity cannot be told; start with the shaft free"}
DEFAULTS = {"align_tolerance_rad": 0.05, "settle_s": 3e-3, "align_timeout_s": 0.1, "quiet_s": 3e-3,
            "pulse_current_per_rated": 0.7, "pulse_s": 5e-4, "pulse_sequences": 2, "polarity_margin": 0.01,
            "polarity_tries": 3, "flush_s": 6e-3, "lock_filter_Hz": 100.0, "lock_persist_s": 5e-3,
            "lost_hold_s": 0.01, "max_restarts": 3, "backemf_polarity_ratio": 3.0, "polarity_from_recording": False,
            "run_refused": False}
"""Start-up settings (estimator settings of every injecting estimator; ``polarity_from_recording``: replay,
item 5). The pulses' current, length, count and margin are these only where the commissioning holds no
saturation asymmetry or the inertia is unknown (polarity_test.polarity_design designs them otherwise).
``run_refused`` (`drive run --force`): run a drive refused before running (the polarity, the angle signal)."""
PULSE_VOLTAGE_MAX_PER_LINEAR = 0.8
"""Polarity pulses use at most this share of the linear voltage range U_dc/√3 (longer pulses beyond)."""
LOCK_RESISTANCE_ERROR = 0.1
LOCK_DEAD_TIME_ERROR = 0.5
"""V_th = this share of R̂·I_rated + this share of the commissioned dead-time voltage (per phase, ×4/3 in
αβ) + 2 % of the rated back-EMF: what the back-EMF model can be wrong by at rated current."""
UNMEASURED_DEAD_TIME_PER_U_DC = 0.02
"""A drive that never measured its dead-time voltage (nameplate only) neither compensates it nor ignores
it: V_th allows the whole of a typical one, 2 % of U_dc (2 µs of dead time at 10 kHz), ×4/3 in αβ."""


def dead_time_uncertainty_V(inverter, commissioning, share):
    """What the back-EMF model's dead-time voltage can be wrong by in αβ [V]: ``share`` of the commissioned
    dead-time voltage ×4/3; a drive that never measured it (nameplate only) neither compensates it nor
    ignores it: a typical whole one, UNMEASURED_DEAD_TIME_PER_U_DC of U_dc (``inverter``'s, when known), ×4/3."""
    if commissioning.source == NAMEPLATE_ONLY and math.isfinite(inverter.U_dc_V):
        return 4.0 / 3.0 * UNMEASURED_DEAD_TIME_PER_U_DC * inverter.U_dc_V
    return share * 4.0 / 3.0 * commissioning.dead_time_voltage_V


def _fixed_pulses(nameplate, commissioning, T_s, inverter, s):
    """(n, pulse_V [V], sequences, margin) of the pulses the settings fix (``pulse_current_per_rated`` of rated
    current in ``pulse_s``, longer where the bus needs; ``pulse_sequences``; ``polarity_margin``): a drive
    whose commissioning holds no saturation asymmetry, or that does not know its inertia."""
    I_p = s["pulse_current_per_rated"] * nameplate.rated_current_A
    u_max = PULSE_VOLTAGE_MAX_PER_LINEAR * inverter.U_dc_V / math.sqrt(3.0)
    resistive = 0.5 * commissioning.R_s_ohm * I_p
    if resistive >= u_max:
        raise ValueError(f"pulse_current_per_rated: {s['pulse_current_per_rated']:g} × rated current needs more "
                         f"than {u_max:.3g} V across R_s alone")
    n = max(2, int(round(s["pulse_s"] / T_s)),
            math.ceil(I_p * commissioning.L_dh_H / (T_s * (u_max - resistive))))
    return n, I_p * commissioning.L_dh_H / (n * T_s) + resistive, int(s["pulse_sequences"]), s["polarity_margin"]


def make_startup(nameplate, commissioning, T_s, inverter, error_gain, settings):
    """StartupParams for an estimator on ``inverter``
    (InverterRating: U_dc, ∞ when unknown, and the drive's whole delay); ``settings``: its checked
    settings (interface.check_settings, DEFAULTS among them), ``error_gain`` its ε per radian."""
    s = settings
    design = polarity_design(nameplate, commissioning, T_s, inverter, s["align_tolerance_rad"],
                             int(s["pulse_sequences"]))
    torque = None
    if design is None:
        n, pulse_V, sequences, margin = _fixed_pulses(nameplate, commissioning, T_s, inverter, s)
    else:
        if design.problem:
            torque = torque_polarity_design(nameplate, commissioning, T_s, inverter)
            if torque.problem and not s["run_refused"]:
                raise ValueError(f"the magnet's polarity cannot be told before torque: {design.problem}; nor by a "
                                 f"torque pulse: {torque.problem}; refused (`drive run --force` runs it anyway)")
            torque = None if torque.problem else torque
        n, pulse_V, sequences, margin = design.n, design.pulse_V, design.sequences, design.margin
    other_decay, other_gain = winding_step(commissioning.R_s_ohm, commissioning.L_dh_H, T_s)
    omega_rated = nameplate.n_p * nameplate.rated_speed_rpm * 2.0 * math.pi / 60.0
    threshold = (LOCK_RESISTANCE_ERROR * commissioning.R_s_ohm * nameplate.rated_current_A
                 + dead_time_uncertainty_V(inverter, commissioning, LOCK_DEAD_TIME_ERROR)
                 + 0.02 * omega_rated * nameplate.psi_f_Wb)

    def samples(seconds):
        return max(1, int(round(seconds / T_s)))
    return StartupParams(
        T_s_s=T_s, delay_periods=int(inverter.delay_periods), error_gain=float(error_gain),
        align_tolerance_rad=s["align_tolerance_rad"],
        settle_samples=samples(max(s["settle_s"], TORQUE_SETTLE_S) if torque else s["settle_s"]),
        align_timeout_samples=samples(s["align_timeout_s"]), quiet_samples=samples(s["quiet_s"]),
        error_smoothing=1.0 - math.exp(-1.0 / samples(ALIGN_SMOOTHING_S)),
        pulse_samples=n, pulse_V=pulse_V, pulse_sequences=sequences,
        polarity_margin=margin, polarity_tries=int(s["polarity_tries"]),
        polarity_linear_ratio=linear_polarity_ratio(commissioning.R_s_ohm, commissioning.L_dh_H, T_s, n,
                                                    sequences, int(inverter.delay_periods)),
        other_decay=other_decay, other_gain=other_gain,
        flush_samples=samples(s["flush_s"]), R_s_ohm=commissioning.R_s_ohm, L_dh_H=commissioning.L_dh_H,
        L_qh_H=commissioning.L_qh_H, delta_L_H=nameplate.L_d_H - nameplate.L_q_H, psi_f_Wb=nameplate.psi_f_Wb,
        dead_time_voltage_V=commissioning.dead_time_voltage_V,
        dead_time_smoothing_A=SMOOTHING_PER_RATED_CURRENT * nameplate.rated_current_A,
        lock_smoothing=1.0 - math.exp(-2.0 * math.pi * s["lock_filter_Hz"] * T_s),
        lock_threshold_V=threshold, lock_persist_samples=samples(s["lock_persist_s"]),
        lost_hold_samples=samples(s["lost_hold_s"]), max_restarts=int(s["max_restarts"]),
        backemf_polarity_ratio=s["backemf_polarity_ratio"],
        polarity_from_recording=bool(s["polarity_from_recording"]),
        **startup_fields(torque))


def fresh_startup(startup):
    """Set a start-up record (STARTUP, zeroed) aligning from sample 0."""
    startup["code"] = ALIGNING
    startup["error"] = 1.0


@njit(cache=True)
def startup_code(x):
    """The start-up's current state code in the estimator state ``x``."""
    return int(x.startup.code)


@njit(cache=True)
def startup_follow(x, p, theta, omega):
    """Set θ̂ (x.theta) and ω̂ (x.omega) to another source's ``theta`` [rad] and ``omega`` [rad/s]
    (the follower of a blend, hf_estimator.full_speed; a test's forced slip), the back-EMF residual turned
    with θ̂."""
    turn(x, p, theta - x.theta)
    x.omega = omega


@njit(cache=True)
def startup_step(x, p, k, sample, i_alpha_beta_A, u_inj_V, eps, observable):
    """Supervise sample k after the estimator's own step: its SAMPLE record (the voltage applied in the
    period before sample k [V]; ``theta_e_encoder``: in replay, the recording drive's own estimate θ̂_e [rad],
    NaN where the bag has none, read only with ``polarity_from_recording``; R_s_ohm: the winding's resistance
    the drive tracks, 0: the commissioned one), the measured currents (α, β) [A], the estimator's injection
    (α, β) for the coming period [V], its ε and observable flag. Hands the sample to the job of the state it
    is in; may turn or hold θ̂ (x.theta) and ω̂ (x.omega). Returns (u_inj_α, u_inj_β, state code)."""
    s = x.startup
    i_alpha, i_beta = i_alpha_beta_A
    u_inj_alpha, u_inj_beta = u_inj_V
    residual = backemf_residual(x, p, k, i_alpha, i_beta, sample.u_applied_alpha, sample.u_applied_beta,
                                sample.R_s_ohm)
    code = int(s.code)
    since = k - int(s.entered)
    if s.refused != NOT_REFUSED:
        return 0.0, 0.0, float(HOLD if s.refused != TOO_MANY_LOSSES else LOCK_LOST)
    if code == ALIGNING:
        if s.quiet > 0.0:
            if not quiet_over(x, p, k):
                return 0.0, 0.0, float(ALIGNING)
            since = 0
            code = POLARITY
        else:
            aligned, u_alpha, u_beta, state = alignment_step(x, p, k, since, u_inj_alpha, u_inj_beta, eps, observable)
            if not aligned:
                return u_alpha, u_beta, state
            if s.moved == 0.0:
                return polarity_begin(x, p, k, u_inj_alpha, u_inj_beta, sample.theta_e_encoder)
            decided, state = torque_decide(x, p, k)
            if not decided:
                return 0.0, 0.0, state
            enter(x, p, k, TRACKING)
            return u_inj_alpha, u_inj_beta, lock_step(x, p, k, residual, observable)
    if code == POLARITY and s.torque_active > 0.5:
        return torque_step(x, p, k, since, i_alpha, i_beta, u_inj_alpha, u_inj_beta)
    if code == POLARITY:
        done, u_alpha, u_beta, state = polarity_step(x, p, k, since, i_alpha, i_beta, u_inj_alpha, u_inj_beta)
        if not done:
            return u_alpha, u_beta, state
        enter(x, p, k, TRACKING)
    elif code == LOCK_LOST:
        return reacquire_step(x, p, k, since, u_inj_alpha, u_inj_beta)
    return u_inj_alpha, u_inj_beta, lock_step(x, p, k, residual, observable)


def startup_summary(startup):
    """What a start-up record (STARTUP) says after a run: {state, refused (reason or None), polarity_ratio,
    flipped, restarts}."""
    return {"state": STATE_NAMES[int(startup["code"])], "refused": REFUSALS.get(int(startup["refused"])),
            "polarity_ratio": float(startup["polarity_ratio"]), "flipped": bool(startup["flipped"]),
            "restarts": int(startup["restarts"])}


def estimator_startup(estimator):
    """startup_summary of a built estimator (hf_estimator.interface.Estimator): its state's ``startup``
    record, or ours' in a blend (``hf``); None if it has none."""
    state = estimator.state[0]
    names = state.dtype.names
    if "startup" in names:
        return startup_summary(state["startup"])
    if "hf" in names:
        return startup_summary(state["hf"]["startup"])
    return None
