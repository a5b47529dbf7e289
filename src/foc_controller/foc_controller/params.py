"""Controller parameters for a motor known by its nameplate and inverter rating: the motor values are
the nameplate's, the gains Szabó Table 2 or the bandwidth/damping rule of ``tuning``."""
import math

import numpy as np

from drive_common.contract.settings import Key, read_keys, shown
from drive_common.math.filters import notch
from drive_common.motor.open_loop_start import (
    AGREEMENT_PER_SPEED,
    DAMPING_FILTER_PER_SWING,
    DAMPING_GAIN,
    open_loop_start,
)
from drive_common.motor.torque_limit import controller_path

from .control import ControllerParams
from .speed_margin import (
    SPEED_GAIN_MARGIN_DB,
    SPEED_PHASE_MARGIN_DEG,
    SpeedEstimate,
    SpeedLoopPlant,
    margins,
)
from .tuning import SZABO_TABLE2, current_pi_gains_any_bandwidth, speed_pi_gains

SETTINGS = (
    Key("gains", "", choices=("rule", "szabo_table2"), default="rule"),
    Key("current_bandwidth_rad_s", "rad/s", 0.0, default=2.0 * math.pi * 250.0),
    Key("current_damping", "", 0.0, default=0.8),
    Key("speed_bandwidth_rad_s", "rad/s", 0.0, default=40.0),
    Key("speed_to_estimator_ratio", "", 0.0, 1.0, default=0.25),
    Key("speed_damping", "", 0.0, default=1.0),
    Key("current_limit_A", "A", 0.0, default=None, nullable=True, doc="at most the nameplate's current limit"),
    Key("decoupling", "", choices=(True, False), default=True),
    Key("delay_compensation", "", choices=(True, False), default=True),
    Key("hf_notch_quality", "", 0.0, default=1.0),
    Key("speed_filter_Hz", "Hz", 0.0, low_inclusive=True, default=100.0, doc="below Nyquist; 0: none"),
    Key("speed_limit_rad_s", "rad/s", 0.0, infinite=True, default=math.inf),
    Key("speed_ramp_rad_s2", "rad/s²", 0.0, infinite=True, default=math.inf,
        doc="the speed reference's largest slope (mechanical; ∞: none); unset, the estimator's tracked acceleration"),
    Key("mtpa", "", choices=(True, False), default=True,
        doc="the most torque per ampere where it gains (drive_common.motor.torque_limit); false: i_d = 0"),
)
"""The controller's settings (a scenario's or drive configuration's ``controller:``, the node's
``controller.*`` parameters), each declared once (drive_common.contract.settings.Key)."""
SETTING = {key.name: key for key in SETTINGS}
DEFAULTS = {key.name: key.default for key in SETTINGS}


DELAY_LAG_AT_BANDWIDTH_RAD = 0.25
"""With 'rule' gains the current loops' ω_n is kept at or below this over the loop delay (d + ½)·T_s: at
the open loop's crossover (≈ 2ζω_n) the delay then costs ≤ 0.4 rad (23°) of phase. At d = 1 the default
250 Hz stays; blocks of N samples (d = N) lower it (docs/architecture.md "Block transport")."""
CURRENT_TO_SPEED_RATIO = 4.0
"""With 'rule' gains the speed loop's ω_n stays this many times below the current loops'."""
CURRENT_LAG_AT_SPEED_CROSSOVER_RAD = 0.4
"""With 'rule' gains the speed loop's ω_n is also kept at or below this over 2ζ_s times the current loops'
lag seen from the speed loop, 2ζ_c/ω_c + (d + ½)·T_s (their closed loop's and the delay's): at the speed
loop's crossover (≈ 2ζ_s ω_n) the current loops then cost ≤ 0.4 rad (23°) of its phase, beside the
estimator's lag. Blocks slow the current loops (d = N) while the estimator's cap keeps the speed loop
where it was: blocks of 10 at 10 kHz made the speed loop ring at 7 Hz (docs/motors-and-control.md)."""
SPEED_FILTER_PER_TRACKING = 1.25
"""Unless set, the speed estimate's filter sits at least this many times above the estimator's tracking
bandwidth: a filter below it adds lag inside a speed loop scaled to that bandwidth (a light robot joint
at 20 kHz, tracking 116 Hz and its speed loop at 182 rad/s, hunted at 55 Hz behind the 100 Hz default:
0.066 rad RMS; 0.011 at 145 Hz; docs/motors-and-control.md). The default's 100 Hz stays for tracking up
to 80 Hz."""


SENSED_SPEED = SpeedEstimate()
"""The speed estimate of a sensor: no tracking loop."""
MARGIN_SEARCH_FLOOR = 0.05
MARGIN_SEARCH_STEPS = 24
"""speed_gains_within_margins bisects the bandwidth's logarithm this many times (to 0.01 % of it)."""
IF_AGREEMENT_S = 0.01
"""The I-f start hands over once the observer's speed has agreed with the ramp's this long at least (longer where its
flux error decays slower, open_loop_start.OpenLoopStart.observer_settle_s)."""


def make_controller_params(nameplate, inverter, T_s, settings=None, injection_frequency_Hz=0.0,
                           speed_estimate=SENSED_SPEED, commissioning=None, open_loop=False):
    """ControllerParams for a motor with this ``nameplate`` (drive_common.motor.nameplate.Nameplate) on an
    ``inverter`` (InverterRating; its delay_periods the whole delay d from sample to applied command,
    blocks included) at sampling period T_s; R_s of the current loops comes from the
    ``commissioning`` record when given, else the nameplate. Their inductances stay the nameplate's:
    the commissioned ones are incremental at no load (for the estimators), and the loops' gains tuned on
    them overshoot the current limit further in a speed reversal (docs/commissioning.md §1).

    settings keys (all optional): gains ('rule' or 'szabo_table2'), current_bandwidth_rad_s,
    current_damping, speed_bandwidth_rad_s, speed_to_estimator_ratio, speed_damping, current_limit_A,
    decoupling, delay_compensation, hf_notch_quality, speed_filter_Hz (0: none; unset, at least
    SPEED_FILTER_PER_TRACKING × the estimator's bandwidth), speed_limit_rad_s
    (mechanical, clamps the speed reference; ∞: none), speed_ramp_rad_s2 (mechanical, the speed reference's
    largest slope while the speed loop runs; ∞: none), mtpa (the MTPA table up to the current
    limit from the ``commissioning`` record, drive_common.motor.torque_limit.controller_path; false or
    none: i_d = 0). With 'rule' gains the current bandwidth is capped
    for the loop delay (DELAY_LAG_AT_BANDWIDTH_RAD) and the speed bandwidth a cascade step below it
    (CURRENT_TO_SPEED_RATIO) and within the current loops' lag (CURRENT_LAG_AT_SPEED_CROSSOVER_RAD). The
    notch sits at the estimator's injection frequency. With 'rule' gains the speed loop is kept a cascade
    step below the angle estimator (``speed_estimate``, speed_margin.SpeedEstimate): its bandwidth is at most
    speed_to_estimator_ratio · 2π · its tracking bandwidth
    (a speed loop faster than the estimate it is fed makes the drive chase its own estimation lag), and at most
    the bandwidth whose loop, the current loop, the rotor and the estimator's tracking loop included, keeps its
    phase and gain margins (speed_margin).
    ``open_loop``: with the I-f start of drive_common.motor.open_loop_start (an estimator that says OPEN_LOOP
    below its speed); ValueError where that start refuses the motor.
    """
    s = check_settings(settings, T_s)
    tracking_bandwidth_Hz = speed_estimate.bandwidth_Hz
    if "speed_filter_Hz" not in (settings or {}) and math.isfinite(tracking_bandwidth_Hz):
        s["speed_filter_Hz"] = max(s["speed_filter_Hz"], SPEED_FILTER_PER_TRACKING * tracking_bandwidth_Hz)
    m = nameplate
    if commissioning is not None:
        m = m._replace(R_s_ohm=commissioning.R_s_ohm)
    current_bandwidth = min(s["current_bandwidth_rad_s"],
                            DELAY_LAG_AT_BANDWIDTH_RAD / ((inverter.delay_periods + 0.5) * T_s))
    if s["gains"] == "szabo_table2":
        d, q, w = SZABO_TABLE2["d"], SZABO_TABLE2["q"], SZABO_TABLE2["speed"]
    elif s["gains"] == "rule":
        d = current_pi_gains_any_bandwidth(m.L_d_H, m.R_s_ohm, current_bandwidth, s["current_damping"])
        q = current_pi_gains_any_bandwidth(m.L_q_H, m.R_s_ohm, current_bandwidth, s["current_damping"])
        current_lag_s = 2.0 * s["current_damping"] / current_bandwidth + (inverter.delay_periods + 0.5) * T_s
        speed_bandwidth = min(_capped_speed_bandwidth(s, tracking_bandwidth_Hz),
                              current_bandwidth / CURRENT_TO_SPEED_RATIO,
                              CURRENT_LAG_AT_SPEED_CROSSOVER_RAD / (2.0 * s["speed_damping"] * current_lag_s))
        plant = speed_loop_plant(m, inverter, T_s, q, speed_filter_gain(s["speed_filter_Hz"], T_s), speed_estimate)
        w = speed_gains_within_margins(plant, speed_bandwidth, s["speed_damping"])
    i_max = s["current_limit_A"] if s["current_limit_A"] is not None else m.current_limit_A
    if i_max > m.current_limit_A:
        raise ValueError(f"controller: current_limit_A: {i_max:g} A exceeds the motor's limit "
                         f"{m.current_limit_A:g} A (its nameplate)")
    delay = inverter.delay_periods + 0.5 if s["delay_compensation"] else 0.0
    if injection_frequency_Hz > 0.0:
        sos = notch(injection_frequency_Hz, s["hf_notch_quality"], T_s)
    else:
        sos = np.zeros((0, 6))
    path = controller_path(m, commissioning, float(i_max)) if s["mtpa"] else None
    start = {}
    if open_loop:
        plan = open_loop_start(m, commissioning, inverter.U_dc_V, current_bandwidth)
        if plan.refused:
            raise ValueError(plan.refused)
        start = {"if_current_A": plan.current_A, "if_acceleration_rad_s2": plan.acceleration_rad_s2,
                 "if_handover_rad_s": plan.handover_rad_s, "if_align_samples": int(round(plan.align_s / T_s)),
                 "if_agree_samples": max(1, int(round(max(IF_AGREEMENT_S, plan.observer_settle_s) / T_s))),
                 "if_damping_filter_rad_s": DAMPING_FILTER_PER_SWING * plan.swing_rad_s,
                 "if_damping_gain": DAMPING_GAIN, "if_agreement": AGREEMENT_PER_SPEED}
    return ControllerParams(
        T_s_s=T_s, n_p=m.n_p, R_s_ohm=m.R_s_ohm, L_d_H=m.L_d_H, L_q_H=m.L_q_H, psi_f_Wb=m.psi_f_Wb,
        U_dc_V=inverter.U_dc_V, kp_d=d.kp, ki_d=d.ki, kp_q=q.kp, ki_q=q.ki,
        kp_speed=w.kp, ki_speed=w.ki, i_max_A=float(i_max), decoupling=bool(s["decoupling"]),
        delay_compensation_periods=float(delay), hf_notch_sos=np.ascontiguousarray(sos),
        speed_filter_gain=speed_filter_gain(s["speed_filter_Hz"], T_s),
        speed_limit_rad_s=float(s["speed_limit_rad_s"]), speed_ramp_rad_s2=float(s["speed_ramp_rad_s2"]),
        mtpa_current_A=np.ascontiguousarray(path.current_A if path else np.zeros(0)),
        mtpa_d_current_A=np.ascontiguousarray(path.d_current_A if path else np.zeros(0)), **start)


def speed_filter_gain(speed_filter_Hz, T_s):
    """The speed estimate's first-order filter as a per-sample gain (1: none, at 0 Hz)."""
    return 1.0 - math.exp(-2.0 * math.pi * speed_filter_Hz * T_s) if speed_filter_Hz > 0.0 else 1.0


def speed_loop_plant(motor, inverter, T_s, current_gains, filter_gain, speed_estimate):
    """speed_margin.SpeedLoopPlant of the speed loop of ``motor`` (a Nameplate: R_s, L_q, n_p, ψ_f, J, B) behind
    ``inverter``'s delay (d + ½)·T_s, its q current loop's ``current_gains`` (PIGains), the speed filter's per-sample
    ``filter_gain`` and the ``speed_estimate`` (speed_margin.SpeedEstimate) it is fed."""
    return SpeedLoopPlant(current_gains.kp, current_gains.ki, motor.R_s_ohm, motor.L_q_H,
                          (inverter.delay_periods + 0.5) * T_s, 1.5 * motor.n_p * motor.psi_f_Wb, motor.J_kgm2,
                          motor.B_Nms if math.isfinite(motor.B_Nms) else 0.0, speed_estimate.tracking_loop(),
                          filter_gain, T_s)


def speed_gains_within_margins(plant, speed_bandwidth_rad_s, damping):
    """speed_pi_gains at ``speed_bandwidth_rad_s`` (ζ ``damping``) on ``plant`` (speed_margin.SpeedLoopPlant), or at
    the largest bandwidth below it whose loop keeps SPEED_PHASE_MARGIN_DEG and SPEED_GAIN_MARGIN_DB (bisected on a
    log scale down to MARGIN_SEARCH_FLOOR of it, or to where friction alone would give the PI's k_p; that floor where
    none does)."""
    def gains(bandwidth):
        return speed_pi_gains(plant.J_kgm2, plant.B_Nms, plant.k_t_Nm_per_A, bandwidth, damping)

    def kept(bandwidth):
        g = gains(bandwidth)
        found = margins(plant, g.kp, g.ki)
        return found.phase_margin_deg >= SPEED_PHASE_MARGIN_DEG and found.gain_margin_db >= SPEED_GAIN_MARGIN_DB

    if kept(speed_bandwidth_rad_s):
        return gains(speed_bandwidth_rad_s)
    floor = max(MARGIN_SEARCH_FLOOR * speed_bandwidth_rad_s, 1.01 * plant.B_Nms / (2.0 * damping * plant.J_kgm2))
    if floor >= speed_bandwidth_rad_s:
        return gains(speed_bandwidth_rad_s)
    low, high = math.log(floor), math.log(speed_bandwidth_rad_s)
    for _ in range(MARGIN_SEARCH_STEPS):
        middle = 0.5 * (low + high)
        low, high = (middle, high) if kept(math.exp(middle)) else (low, middle)
    return gains(math.exp(low))


def check_settings(settings, T_s=None):
    """The defaults with ``settings`` applied; KeyError for an unknown key, ValueError naming the key
    whose value is unusable (wrong type, not finite, out of range). ``T_s``: the sampling period, which
    bounds the filter frequencies by Nyquist."""
    unknown = set(settings or {}) - set(DEFAULTS)
    if unknown:
        raise KeyError(f"controller: unknown setting(s) {', '.join(sorted(map(str, unknown)))} "
                       f"(known: {', '.join(sorted(DEFAULTS))})")
    try:
        s = read_keys(settings or {}, SETTINGS)
        if T_s and s["speed_filter_Hz"] >= 0.5 / T_s:
            raise ValueError(f"speed_filter_Hz: must lie below Nyquist, {0.5 / T_s:g} Hz, "
                             f"not {shown(s['speed_filter_Hz'])}")
    except ValueError as error:
        raise ValueError(f"controller: {error}") from None
    return s


def check_speed_limit(value):
    """A speed limit must be a positive number of rad/s (∞ allowed); otherwise ValueError naming it."""
    return SETTING["speed_limit_rad_s"].read(value)


def _capped_speed_bandwidth(s, tracking_bandwidth_Hz):
    """The speed-loop bandwidth used with 'rule' gains (s: the merged settings): the requested one,
    capped a cascade step below the estimator's tracking loop."""
    return min(float(s["speed_bandwidth_rad_s"]),
               float(s["speed_to_estimator_ratio"]) * 2.0 * math.pi * tracking_bandwidth_Hz)
