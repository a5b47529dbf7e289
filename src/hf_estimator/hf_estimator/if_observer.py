"""``if_observer`` — a motor without enough saliency for HF injection, as drives without injection run it
(issue 52 item 3; docs/startup.md "Motors without enough saliency"): the back-EMF observer (``flux_observer``,
Hinkkanen et al. 2018) above its minimum speed; below it the state says OPEN_LOOP and the controller turns
the current itself, I-f (Fatu et al. 2008; foc_controller.control.open_loop_step), handing over to the
observer once its speed agrees. No holding torque at standstill: a scenario that asks for it, for a load or a
dwell below that speed is refused up front (``below_speed_refusal``).

The minimum speed, the I-f current and ramp come from drive_common.motor.open_loop_start (nameplate and
commissioning). State: TRACKING once |ω̂| reaches the hand-over speed, OPEN_LOOP again below the hand-back
speed; θ̂, ω̂ the observer's throughout (in open loop the controller's own angle drives the current)."""
import math
from typing import NamedTuple

import numpy as np
from numba import njit

from drive_common.contract.estimator_states import OPEN_LOOP, TRACKING
from drive_common.math.frames import clarke_contract
from drive_common.motor.open_loop_start import ESTIMATOR, open_loop_start

from .flux_observer import DEFAULTS as OBSERVER_DEFAULTS
from .flux_observer import FluxObserverParams, flux_observer_follow, flux_observer_step, make_flux_observer
from .interface import Estimator, check_settings, register

OBSERVER_BANDWIDTH_HZ = 2.0 * OBSERVER_DEFAULTS["speed_bandwidth_Hz"]
"""The observer's speed_bandwidth_Hz unless set: twice flux_observer's. Alone at speed it follows an acceleration a
with the lag a/(¼α_d²), α_d = 2α_o: a drawn light rotor (acceleration time 14 ms) at the current limit in a
speed step lagged 0.147 rad at 100 Hz, ours' peak target 0.15."""
SPEED_ESTIMATE_PER_BANDWIDTH = 0.5
"""The observer's ω̂ follows ω_s at ¼α_d = α_o/2 (flux_observer): its tracking bandwidth, which the speed
loop stays a cascade step below, is half its speed_bandwidth_Hz (at the whole of it a speed step on a light
rotor overshot by 2×, the observer's angle 0.17 rad off)."""
DWELL_S = 0.02
"""A speed reference that stays below the hand-over speed longer than this (a hold, a low speed, a ramp
slower than the I-f's) asks for what the drive cannot give."""


FLUX_ADAPTATION_RAD_S = 20.0
"""Above its speed the observer's magnet flux ψ_f adapts at this rate to drive its d flux error e_d to zero.
With a ψ_f off by Δψ its correction 2k_1·e_d holds θ̂ off by asin(2k_1·Δψ/(ω·ψ_f)) (k_1 = σ_0 + 0.2|ω|):
0.12 rad measured on a drawn 6-pole-pair motor whose nameplate ψ_f was 8 % low, at 1.5 × its minimum speed;
with e_d driven to zero only the voltage model's error stays, the bound the minimum speed is stated from."""
FLUX_RANGE = (0.7, 1.3)
"""The adapted ψ_f stays within these shares of the nameplate's."""
SETTLED_PER_LOCK = 0.45
"""At this share of the I-f start's first lock (open_loop_start's align_s; its quarter turn starts at ½) the rotor,
pulled onto the current's axis and damped, sits there at rest: the observer is set to the measured current's angle
and zero speed (flux_observer_follow). At rest the back-EMF carries no angle and the observer had drifted
(0.8-0.9 rad on seed 11 motors 1 and 39): moved by the turn from there, it read the rotor's speed with the wrong
sign, and the stabilising loop fed that speed pulled the rotor out of the lock."""
SETTLED_AT_LOCK_END = 0.95
"""And again at this share of the lock, the quarter turn's swing damped (the rotor at rest again): the ramp then starts
from the observer's angle at rest. Set only at SETTLED_PER_LOCK, a rotor started near its d axis' unstable point
(against the current) still swung there at 13-35 rad/s (electrical; drawn motor random_1_0001, from 3.1 rad): the
observer, set at zero speed on a moving rotor, read −97 rad/s at the ramp's start where the rotor turned at
+128, and the stabilising loop fed that speed pulled the rotor out of synchronism (load angle 1.6 rad)."""


class IfObserverParams(NamedTuple):
    obs: FluxObserverParams
    handover_rad_s: float
    handback_rad_s: float
    flux_step: float
    """FLUX_ADAPTATION_RAD_S × T_s."""
    psi_f_low_Wb: float
    psi_f_high_Wb: float
    settled_samples: int
    """SETTLED_PER_LOCK of the first lock [samples] (0: never set)."""
    settled_end_samples: int
    """SETTLED_AT_LOCK_END of the first lock [samples]."""
    current_A: float
    """The I-f current [A]: the measured current's angle is taken where it is at least half of it."""


@njit(cache=True, _nrt=False)
def if_observer_step(x, p, k, sample, out):
    """One sample (interface.py) → ``out``: the observer's θ̂_e, ω̂_e, ε, signal (its back-EMF [V]), no
    injection; the state TRACKING above the hand-over speed (hysteresis to the hand-back speed), else
    OPEN_LOOP; above it the observer's ψ_f adapts (FLUX_ADAPTATION_RAD_S); twice, SETTLED_PER_LOCK and
    SETTLED_AT_LOCK_END into the first lock, the observer is set to the measured current's angle at rest. State
    x: ``observer`` (flux_observer's), ``tracking`` (1 above the speed), ``lock_samples`` (samples into the first
    lock; −1 once past it)."""
    flux_observer_step(x.observer, p.obs, k, sample, out)
    if x.lock_samples >= 0.0:
        x.lock_samples += 1.0
        if p.settled_samples <= 0:
            x.lock_samples = -1.0
        elif x.lock_samples == p.settled_samples or x.lock_samples >= p.settled_end_samples:
            i_alpha, i_beta = clarke_contract(sample.i_a, sample.i_b, sample.i_c)
            if i_alpha * i_alpha + i_beta * i_beta >= (0.5 * p.current_A) ** 2:
                flux_observer_follow(x.observer, p.obs, math.atan2(i_beta, i_alpha), 0.0)
            if x.lock_samples >= p.settled_end_samples:
                x.lock_samples = -1.0
    if x.tracking > 0.5:
        psi_f = x.observer.psi_f - p.flux_step * x.observer.e_d
        x.observer.psi_f = min(max(psi_f, p.psi_f_low_Wb), p.psi_f_high_Wb)
    x.theta, x.omega = x.observer.theta, x.observer.omega
    speed = abs(x.omega)
    if speed >= p.handover_rad_s:
        x.tracking = 1.0
    elif speed < p.handback_rad_s:
        x.tracking = 0.0
    out.state = TRACKING if x.tracking > 0.5 else OPEN_LOOP


def plan_for(nameplate, commissioning, inverter):
    """The I-f start the estimator states (open_loop_start at the motor's whole I-f current)."""
    return open_loop_start(nameplate, commissioning, inverter.U_dc_V, math.inf)


@register(ESTIMATOR, "I-f start, then the back-EMF observer above its minimum speed (no injection, no standstill "
                     "torque): for motors without enough saliency",
          "Fatu et al. 2008 (I-f start) with Hinkkanen et al. 2018 (observer)", injects=False, excitation="backemf",
          injection_kind="none")
def make_if_observer(nameplate, T_s, settings, commissioning, inverter):
    s = check_settings(ESTIMATOR, settings, {"speed_bandwidth_Hz": OBSERVER_BANDWIDTH_HZ,
                                             "run_refused": False}, T_s)
    plan = plan_for(nameplate, commissioning, inverter)
    measured = nameplate._replace(L_d_H=commissioning.L_dh_H, L_q_H=commissioning.L_qh_H)
    observer = make_flux_observer(measured, T_s, {"speed_bandwidth_Hz": s["speed_bandwidth_Hz"]}, commissioning,
                                  inverter)
    state = np.zeros(1, np.dtype([("theta", np.float64), ("omega", np.float64), ("tracking", np.float64),
                                  ("lock_samples", np.float64), ("observer", observer.state.dtype)]))
    state["observer"] = observer.state
    settled = int(round(SETTLED_PER_LOCK * plan.align_s / T_s)) if math.isfinite(plan.align_s) else 0
    settled_end = max(int(round(SETTLED_AT_LOCK_END * plan.align_s / T_s)), settled) if settled else 0
    params = IfObserverParams(observer.params, plan.handover_rad_s, plan.handback_rad_s, FLUX_ADAPTATION_RAD_S * T_s,
                              FLUX_RANGE[0] * nameplate.psi_f_Wb, FLUX_RANGE[1] * nameplate.psi_f_Wb, settled,
                              settled_end, plan.current_A)
    return Estimator(ESTIMATOR, if_observer_step, params, state, 0.0,
                     SPEED_ESTIMATE_PER_BANDWIDTH * s["speed_bandwidth_Hz"],
                     injection_note="" if plan.refused else plan.statement(nameplate.n_p))


def below_speed_refusal(scenario, handover_rad_s):
    """"" or why ``scenario`` asks what an I-f start cannot give (one line): its speed reference dwelling below
    the hand-over speed ``handover_rad_s`` (electrical) for more than DWELL_S (standstill torque, a low
    speed), or a load there."""
    speed, load = scenario.schedule()
    n_p = scenario.motor.nameplate.n_p
    below = np.abs(speed) * n_p < handover_rad_s
    rpm = handover_rad_s / n_p * 30.0 / math.pi
    if np.any(below & (np.abs(load) > 0.0)):
        t = float(np.argmax(below & (np.abs(load) > 0.0)) * scenario.T_s)
        return (f"a load at {t:.3g} s while the speed reference is below {rpm:.0f} rpm: this motor has no torque "
                f"control below that speed (I-f start, no saliency for injection)")
    edges = np.flatnonzero(np.diff(np.concatenate(([0], below.astype(np.int8), [0]))))
    for start, stop in zip(edges[::2], edges[1::2]):
        level = speed[start:stop]
        dwell = np.count_nonzero(np.abs(np.diff(level)) == 0.0) * scenario.T_s if level.size > 1 else 0.0
        if dwell > DWELL_S:
            what = "standstill" if np.all(level == 0.0) else f"{np.max(np.abs(level)) * 30.0 / math.pi:.3g} rpm"
            return (f"the speed reference asks for {what} from {start * scenario.T_s:.3g} s, below {rpm:.0f} rpm: "
                    f"this motor works above {rpm:.0f} rpm, no standstill torque (I-f start, no saliency for "
                    f"injection)")
    return ""
