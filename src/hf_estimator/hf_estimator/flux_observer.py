"""``flux_observer`` — a back-EMF method for speed: the reduced-order stator-flux observer in estimated
rotor coordinates of Hinkkanen et al., "Observers for sensorless synchronous motor drives: framework
for design and analysis", IEEE Trans. Ind. Appl. 2018 (the design motulator's SpeedFluxObserver
implements), from the commissioned R_s and dead-time voltage (subtracted from the applied voltage at the
phase currents of the period's start, drive_common.math.dead_time) and the nameplate's L_d, L_q, ψ_f. It
injects nothing.

Per period, in the frame θ̂ turning at ω_s (forward Euler, as the reference):
  e = L_d i_d + ψ_f + j L_q i_q − ψ̂_s                (flux error)
  ψ_a = ψ_f + (L_d − L_q) i_d                         (auxiliary flux)
  ε = −Im(e/ψ_a),  ω_s = ω̂ + α_d ε                   (angle correction, α_d = 2α_o)
  dψ̂_s/dt = u − R_s i − jω_s ψ̂_s + k_1 e + k_2 e*,   k_1 = σ_0 + 0.2|ω̂|, k_2 = k_1 ψ_a/ψ_a*,
  σ_0 = ¼ R_s (1/L_d + 1/L_q)
  dθ̂/dt = ω_s,  dω̂/dt = ¼α_d (ω_s − ω̂)              (speed estimate)
The voltage u of a period is the command that acted in it (d + 1 samples old), so sample k completes the
period k − 1 → k before it is read; that voltage, constant in the stationary frame, is turned into the
frame at the period's middle (θ̂ + ω_s T_s/2; at the period's start the angle lags by ω T_s/2, 0.03 rad at
`wang_spmsm`'s rated speed). Below speed the back-EMF carries no angle: the estimate drifts and
the state says HOLD (not observable) while the back-EMF ω̂ψ_f stays below ``observable_backemf_V``
(a share of the rated back-EMF); above it TRACKING. An observer alone cannot start a rotor at rest
(the drive holds zero torque until it tracks): it is the high-speed half of a full-speed drive.
"""
import math
from typing import NamedTuple

import numpy as np
from numba import njit

from drive_common.contract.estimator_states import HOLD, LEADER_BACKEMF, TRACKING
from drive_common.math.dead_time import SMOOTHING_PER_RATED_CURRENT, net_of_dead_time
from drive_common.math.frames import clarke_contract, rotate
from drive_common.motor.open_loop_start import OBSERVER_GAIN_PER_SPEED, observer_gain_rad_s

from .interface import Estimator, check_settings, register, stator_resistance

FLUX_OBSERVER = np.dtype([(name, np.float64) for name in ("theta", "omega", "psi_d", "psi_q", "prev_id", "prev_iq",
                                                            "e_d", "omega_s", "started", "psi_f")])
"""The observer's state: θ̂ [rad], ω̂ [rad/s], ψ̂_s (d, q) [Wb], the previous period's current (d, q) [A],
the d part of its flux error (the q part is not fed back: k_2 = k_1) [Wb], ω_s (estimated rotor frame)
[rad/s], a started flag, and the magnet flux of its model [Wb] (the nameplate's; hf_estimator.if_observer
adapts it)."""
DEFAULTS = {"speed_bandwidth_Hz": 100.0, "observable_backemf_per_rated": 0.05}


class FluxObserverParams(NamedTuple):
    T_s_s: float
    R_s_ohm: float
    L_d_H: float
    L_q_H: float
    psi_f_Wb: float
    alpha_d: float
    """Angle-correction gain 2α_o [rad/s]."""
    sigma_0: float
    """¼ R_s (1/L_d + 1/L_q) [1/s]."""
    observable_backemf_V: float
    dead_time_voltage_V: float
    """Commissioned per-phase dead-time voltage, subtracted from the applied voltage (0: not measured)."""
    dead_time_smoothing_A: float


@njit(cache=True, _nrt=False)
def flux_observer_step(x, p, k, sample, out):
    """One sample (interface.py): the currents and the voltage applied in the period before → ``out``:
    θ̂_e, ω̂_e, no injection, ε [rad], signal the back-EMF |ω̂|ψ_f [V], the state code, weight 1. State x:
    FLUX_OBSERVER."""
    i_alpha, i_beta = clarke_contract(sample.i_a, sample.i_b, sample.i_c)
    u_applied_alpha, u_applied_beta = sample.u_applied_alpha, sample.u_applied_beta
    if x.started > 0.5:
        prev_alpha, prev_beta = rotate(x.prev_id, x.prev_iq, x.theta)
        u_applied_alpha, u_applied_beta = net_of_dead_time(u_applied_alpha, u_applied_beta, prev_alpha, prev_beta,
                                                           p.dead_time_voltage_V, p.dead_time_smoothing_A)
        e_d, w_s = x.e_d, x.omega_s
        u_d, u_q = rotate(u_applied_alpha, u_applied_beta, -(x.theta + 0.5 * p.T_s_s * w_s))
        k_1 = p.sigma_0 + OBSERVER_GAIN_PER_SPEED * abs(x.omega)
        # ψ_a is real here, so k_2 = k_1 and k_1 e + k_2 e* = 2 k_1 Re(e).
        R_s = stator_resistance(p.R_s_ohm, sample.R_s_ohm)
        d_psi_d = u_d - R_s * x.prev_id + w_s * x.psi_q + 2.0 * k_1 * e_d
        d_psi_q = u_q - R_s * x.prev_iq - w_s * x.psi_d
        x.psi_d += p.T_s_s * d_psi_d
        x.psi_q += p.T_s_s * d_psi_q
        x.theta += p.T_s_s * w_s
        x.omega += p.T_s_s * 0.25 * p.alpha_d * (w_s - x.omega)
    i_d, i_q = rotate(i_alpha, i_beta, -x.theta)
    e_d = p.L_d_H * i_d + x.psi_f - x.psi_d
    e_q = p.L_q_H * i_q - x.psi_q
    psi_a = x.psi_f + (p.L_d_H - p.L_q_H) * i_d
    eps = -e_q / psi_a if psi_a != 0.0 else 0.0
    x.e_d = e_d
    x.omega_s = x.omega + p.alpha_d * eps
    x.prev_id, x.prev_iq = i_d, i_q
    x.started = 1.0
    backemf = abs(x.omega) * p.psi_f_Wb
    state = TRACKING if backemf > p.observable_backemf_V else HOLD
    out.theta_e_hat = x.theta
    out.omega_e_hat = x.omega
    out.u_inj_alpha = 0.0
    out.u_inj_beta = 0.0
    out.eps = eps
    out.signal = backemf
    out.state = state
    out.injection_amplitude = 0.0
    out.observer_weight = 1.0
    out.leader = LEADER_BACKEMF


@njit(cache=True, _nrt=False)
def flux_observer_follow(x, p, theta, omega):
    """Set the observer's θ̂ and ω̂ to another source's ``theta`` [rad] and ``omega`` [rad/s] (the follower of
    a blend, hf_estimator.full_speed), and its flux to the current model's in that frame (L_d i_d + ψ_f,
    L_q i_q; flux error zero): released, it starts where the leader is instead of from the flux it
    integrated without its own angle correction (which would turn θ̂ at once by its q error)."""
    i_d, i_q = rotate(x.prev_id, x.prev_iq, x.theta - theta)
    x.prev_id, x.prev_iq = i_d, i_q
    x.psi_d = p.L_d_H * i_d + x.psi_f
    x.psi_q = p.L_q_H * i_q
    x.e_d = 0.0
    x.theta = theta
    x.omega = omega
    x.omega_s = omega


@register("flux_observer", "back-EMF: reduced-order stator-flux observer in estimated rotor coordinates, "
                           "speed-adaptive gain; no injection (tracks at speed only)",
          "Hinkkanen et al. 2018, IEEE TIA, 'Observers for sensorless synchronous motor drives'",
          injects=False, excitation="backemf", injection_kind="none")
def make_flux_observer(nameplate, T_s, settings, commissioning, inverter):
    s = check_settings("flux_observer", settings, DEFAULTS, T_s)
    alpha_o = 2.0 * math.pi * float(s["speed_bandwidth_Hz"])
    omega_rated = nameplate.n_p * nameplate.rated_speed_rpm * math.pi / 30.0
    params = FluxObserverParams(
        T_s_s=T_s, R_s_ohm=commissioning.R_s_ohm, L_d_H=nameplate.L_d_H, L_q_H=nameplate.L_q_H,
        psi_f_Wb=nameplate.psi_f_Wb, alpha_d=2.0 * alpha_o,
        sigma_0=observer_gain_rad_s(commissioning.R_s_ohm, nameplate.L_d_H, nameplate.L_q_H, 0.0),
        observable_backemf_V=float(s["observable_backemf_per_rated"]) * omega_rated * nameplate.psi_f_Wb,
        dead_time_voltage_V=commissioning.dead_time_voltage_V,
        dead_time_smoothing_A=SMOOTHING_PER_RATED_CURRENT * nameplate.rated_current_A)
    state = np.zeros(1, FLUX_OBSERVER)
    state["psi_d"] = state["psi_f"] = nameplate.psi_f_Wb
    return Estimator("flux_observer", flux_observer_step, params, state, 0.0,
                     float(s["speed_bandwidth_Hz"]))
