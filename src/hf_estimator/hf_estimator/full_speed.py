"""``full_speed`` — the whole speed range: ours (``injection_frame``) at standstill, at low speed and
through zero, the back-EMF observer (``flux_observer``) at speed, blended by measured signal health with
hysteresis both ways (docs/full-speed.md).

Both cores run every sample on the same currents and applied voltage. Two measures of health:
- the back-EMF's, h = |ω̂|ψ_f / U_err, U_err what the voltage model can be wrong by: the commissioned
  dead-time voltage (×4/3 in αβ; 2 % of U_dc where it was never measured) plus RESISTANCE_ERROR × R̂·|ī|
  (ī the low-passed current magnitude), so load raises U_err and the handover moves up in speed;
- the observer's agreement with ours, the low-passed |wrap(θ̂_obs − θ̂_hf)|, wherever both run free: ours'
  angle comes from the saliency, independent of the back-EMF model, so it measures the observer's error.

1. Hand over (the observer's weight w → 1 over ``blend_s``): ours tracking, h above
   ``handover_backemf_ratio`` and the agreement within ``agreement_rad`` for ``agreement_s``; or h
   CLEAR_RATIO times above ``quiet_backemf_ratio``, where the back-EMF stands clear whatever ours says.
   (At low speed the observer's angle correction is slow and it drifts: released early it was 0.15-0.3
   rad off on `wang_spmsm` accelerating through 500 rpm. Handing over on the back-EMF's magnitude alone
   there would hand over that drift.)
2. The injection fades out (its amplitude factor → 0 over ``fade_s``) once w = 1 and h stands above
   ``quiet_backemf_ratio``. Ours then follows the blended angle and speed: without its carrier it has no
   angle of its own (its lock monitor, checking the back-EMF against θ̂, keeps checking the blend).
3. The injection fades back in when h predicted ``lookahead_s`` ahead (from the speed's rate of change)
   falls below ``inject_backemf_ratio``: before it is needed, on the way down and towards zero. Ours runs
   free again ``ready_s`` after its carrier is back at full amplitude.
4. Hand back (w → 0): ours free, and the predicted h below ``handback_backemf_ratio``, or h below
   ``quiet_backemf_ratio`` and the agreement beyond ``disagreement_rad``. With w = 0 the observer follows
   ours (angle, speed, and its flux set to the current model's) while h is below the handover ratio, and
   runs free above it, so that its agreement is measured before it leads. Ours runs the type-3 loop
   (injection_frame item 6): it does not lag the acceleration the back-EMF allows at speed; following, it
   takes the blend's acceleration.
5. A start-up state of ours (aligning, polarity test, lock lost) hands back at once, carrier on.

Outputs: θ̂ = θ̂_hf + w·wrap(θ̂_obs − θ̂_hf), ω̂ the same blend of the two speeds, ε the weighted errors
[rad], signal ours' |Δ̂| [1/H], the state ours' (tracking wherever w > 0), U_h the faded amplitude [V],
w, and the leader (back-EMF where w ≥ ½).
"""
import math
from typing import NamedTuple

import numpy as np
from numba import njit

from drive_common.contract.estimator_records import ESTIMATE
from drive_common.contract.estimator_states import (
    ALIGNING,
    LEADER_BACKEMF,
    LEADER_INJECTION,
    LOCK_LOST,
    POLARITY,
    TRACKING,
)
from drive_common.math.frames import clarke_contract, wrap

from .flux_observer import DEFAULTS as OBSERVER_DEFAULTS
from .flux_observer import FluxObserverParams, flux_observer_follow, flux_observer_step, make_flux_observer
from .injection_frame import DEFAULTS as INJECTION_DEFAULTS
from .injection_frame import InjectionFrameParams, injection_frame_step, make_injection_frame
from .interface import Estimator, check_settings, register
from .startup import dead_time_uncertainty_V, startup_follow

BLEND_FIELDS = ("theta", "omega", "weight", "fade", "ready", "agreement", "agreed", "current", "acceleration",
                "prev_omega", "weight_target", "fade_target")
"""The blend's state: θ̂, ω̂, the observer's weight w and the injection's fade h (and their targets), the
samples since the carrier came back in full, the smoothed |θ̂_obs − θ̂_hf| and the samples it stayed
within agreement, the smoothed current magnitude [A], ω̂'s rate of change [rad/s²] and the previous ω̂."""

BLEND_DEFAULTS = {"handover_backemf_ratio": 3.0, "handback_backemf_ratio": 2.0, "quiet_backemf_ratio": 6.0,
                  "inject_backemf_ratio": 5.0, "agreement_rad": 0.03, "disagreement_rad": 0.06,
                  "agreement_s": 0.02, "blend_s": 0.02, "fade_s": 0.02, "ready_s": 0.03, "lookahead_s": 0.08}
DEFAULTS = {**INJECTION_DEFAULTS, "pll_type": 3, "speed_bandwidth_Hz": OBSERVER_DEFAULTS["speed_bandwidth_Hz"],
            **BLEND_DEFAULTS}
CLEAR_RATIO = 2.0
"""Above this many times the quiet ratio the observer takes over without agreeing with ours (ours may
have lost its angle at speed: voltage limit, a carrier near the fundamental)."""
RESISTANCE_ERROR = 0.1
"""The share of R̂·|ī| the back-EMF model may be wrong by (R_s warms up by 10 % over 25 K)."""
SMOOTHING_S = 0.01
"""Time constant of the current magnitude, the speed's rate of change and the agreement."""


class FullSpeedParams(NamedTuple):
    hf: InjectionFrameParams
    obs: FluxObserverParams
    T_s_s: float
    psi_f_Wb: float
    dead_time_error_V: float
    resistance_error_ohm: float
    smoothing: float
    handover: float
    handback: float
    quiet: float
    inject: float
    agreement_rad: float
    disagreement_rad: float
    agreement_samples: int
    blend_step: float
    fade_step: float
    ready_samples: int
    lookahead_s: float


@njit(cache=True, _nrt=False)
def _slew(value, target, step):
    """``value`` moved towards ``target`` by at most ``step``."""
    return min(value + step, target) if target > value else max(value - step, target)


@njit(cache=True, _nrt=False)
def full_speed_step(x, p, k, sample, out):
    """One sample (interface.py) → ``out``: the blend's θ̂_e, ω̂_e, ours' injection faded, the weighted ε
    [rad], ours' |Δ̂| [1/H], the state, the injection's amplitude [V], the observer's weight and the
    leader. State x: the blend's (BLEND_FIELDS), ours' ``hf`` and the observer's ``observer`` states and
    their estimates of this sample (``hf_out``, ``observer_out``); p: FullSpeedParams."""
    ours, observer, hf, ob = x.hf, x.observer, x.hf_out, x.observer_out
    injection_frame_step(ours, p.hf, k, sample, hf)
    flux_observer_step(observer, p.obs, k, sample, ob)
    hf_state = int(hf.state)

    i_alpha, i_beta = clarke_contract(sample.i_a, sample.i_b, sample.i_c)
    x.current += p.smoothing * (math.hypot(i_alpha, i_beta) - x.current)
    u_err = p.dead_time_error_V + p.resistance_error_ohm * x.current
    omega = x.omega
    if k > 0:
        x.acceleration += p.smoothing * ((omega - x.prev_omega) / p.T_s_s - x.acceleration)
    x.prev_omega = omega
    ahead = omega + x.acceleration * p.lookahead_s
    speed_ahead = 0.0 if ahead * omega <= 0.0 else min(abs(omega), abs(ahead))
    health = abs(omega) * p.psi_f_Wb / u_err
    health_ahead = speed_ahead * p.psi_f_Wb / u_err

    ours_free = x.fade >= 1.0 and x.ready >= p.ready_samples
    observer_free = x.weight > 0.0 or health >= p.handover
    x.agreement += p.smoothing * (abs(wrap(observer.theta - ours.theta)) - x.agreement)
    if ours_free and observer_free and x.agreement < p.agreement_rad:
        x.agreed += 1.0
    else:
        x.agreed = 0.0
    starting = hf_state == ALIGNING or hf_state == POLARITY or hf_state == LOCK_LOST
    if starting:
        x.weight = x.weight_target = 0.0
        x.fade = x.fade_target = 1.0
    else:
        if x.weight_target == 0.0 and hf_state == TRACKING and health > p.handover and (
                x.agreed >= p.agreement_samples or health > CLEAR_RATIO * p.quiet):
            x.weight_target = 1.0
        elif x.weight_target == 1.0 and ours_free and (
                health_ahead < p.handback or health < p.quiet and x.agreement > p.disagreement_rad):
            x.weight_target = 0.0
        if x.weight >= 1.0 and health > p.quiet:
            x.fade_target = 0.0
        elif health_ahead < p.inject:
            x.fade_target = 1.0
        x.weight = _slew(x.weight, x.weight_target, p.blend_step)
        x.fade = _slew(x.fade, x.fade_target, p.fade_step)
    x.ready = x.ready + 1.0 if x.fade >= 1.0 else 0.0

    w = x.weight
    x.theta = ours.theta + w * wrap(observer.theta - ours.theta)
    x.omega = ours.omega + w * (observer.omega - ours.omega)
    if not starting and x.ready < p.ready_samples:
        startup_follow(ours, p.hf.startup, x.theta, x.omega)
        ours.acceleration = x.acceleration
    if w == 0.0 and health < p.handover:
        flux_observer_follow(observer, p.obs, x.theta, x.omega)
    state = hf_state if starting or w == 0.0 else TRACKING
    leader = LEADER_BACKEMF if w >= 0.5 else LEADER_INJECTION
    out.theta_e_hat = x.theta
    out.omega_e_hat = x.omega
    out.u_inj_alpha = x.fade * hf.u_inj_alpha
    out.u_inj_beta = x.fade * hf.u_inj_beta
    out.eps = (1.0 - w) * hf.eps + w * ob.eps
    out.signal = hf.signal
    out.state = state
    out.injection_amplitude = x.fade * p.hf.injection_amplitude_V
    out.observer_weight = w
    out.leader = leader


def _ordered(settings):
    """ValueError unless the thresholds leave room for hysteresis both ways."""
    s = settings
    if not s["handback_backemf_ratio"] < s["handover_backemf_ratio"] < s["quiet_backemf_ratio"]:
        raise ValueError("handback_backemf_ratio < handover_backemf_ratio < quiet_backemf_ratio must hold, not "
                         f"{s['handback_backemf_ratio']:g}, {s['handover_backemf_ratio']:g}, "
                         f"{s['quiet_backemf_ratio']:g}")
    if not s["handback_backemf_ratio"] < s["inject_backemf_ratio"] < s["quiet_backemf_ratio"]:
        raise ValueError("inject_backemf_ratio must lie between handback_backemf_ratio and quiet_backemf_ratio, "
                         f"not {s['inject_backemf_ratio']:g}")
    if not s["agreement_rad"] < s["disagreement_rad"]:
        raise ValueError(f"agreement_rad {s['agreement_rad']:g} must lie below disagreement_rad "
                         f"{s['disagreement_rad']:g}")


@register("full_speed", "ours at low speed and through zero, the back-EMF observer at speed, blended by "
                        "measured signal health with hysteresis; the injection fades out where the observer "
                        "leads",
          "ours (docs/full-speed.md), with Hinkkanen et al. 2018 for the observer", excitation="any",
          injection_kind="alternating")
def make_full_speed(nameplate, T_s, settings, commissioning, inverter):
    s = check_settings("full_speed", settings, DEFAULTS, T_s)
    _ordered(s)
    ours = make_injection_frame(nameplate, T_s, {key: s[key] for key in INJECTION_DEFAULTS}, commissioning,
                                inverter)
    observer = make_flux_observer(nameplate, T_s, {"speed_bandwidth_Hz": s["speed_bandwidth_Hz"]}, commissioning,
                                  inverter)
    dead_time_error = dead_time_uncertainty_V(inverter, commissioning, 1.0)

    def samples(seconds):
        return max(1, int(round(seconds / T_s)))
    params = FullSpeedParams(
        hf=ours.params, obs=observer.params, T_s_s=T_s, psi_f_Wb=nameplate.psi_f_Wb,
        dead_time_error_V=max(dead_time_error, 1e-6),
        resistance_error_ohm=RESISTANCE_ERROR * commissioning.R_s_ohm,
        smoothing=1.0 - math.exp(-T_s / SMOOTHING_S), handover=s["handover_backemf_ratio"],
        handback=s["handback_backemf_ratio"], quiet=s["quiet_backemf_ratio"], inject=s["inject_backemf_ratio"],
        agreement_rad=s["agreement_rad"], disagreement_rad=s["disagreement_rad"],
        agreement_samples=samples(s["agreement_s"]), blend_step=T_s / s["blend_s"], fade_step=T_s / s["fade_s"],
        ready_samples=samples(s["ready_s"]), lookahead_s=s["lookahead_s"])
    state = np.zeros(1, np.dtype([*[(name, np.float64) for name in BLEND_FIELDS], ("hf", ours.state.dtype),
                                  ("observer", observer.state.dtype), ("hf_out", ESTIMATE),
                                  ("observer_out", ESTIMATE)]))
    state["fade"] = state["fade_target"] = 1.0
    state["ready"] = params.ready_samples
    state["hf"] = ours.state
    state["observer"] = observer.state
    return Estimator("full_speed", full_speed_step, params, state, ours.injection_frequency_Hz,
                     ours.tracking_bandwidth_Hz, injection_amplitude_V=ours.injection_amplitude_V,
                     injection_note=ours.injection_note, tracking_loop=ours.tracking_loop)
