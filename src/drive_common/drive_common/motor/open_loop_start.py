"""The I-f start of a motor without enough saliency for HF injection (issue 52 item 3; docs/startup.md
"Motors without enough saliency"): a current vector of a stated amplitude turned open loop at a rate the
rotor can follow, up to the back-EMF observer's minimum speed, then closed loop on the observer.

Method: Fatu, Teodorescu, Boldea, Andreescu, Blaabjerg, "I-f starting method with smooth transition to EMF
based motion-sensorless vector control of PM synchronous motor/generator", IEEE PESC 2008 (the current's
angle is the reference, the rotor follows it with a load angle λ, τ = 1.5·n_p·ψ_f·I·sin λ; a stabilising
loop on the measured back-EMF; the hand-over keeps the torque current); the open-loop starts of VESC
(``foc_openloop_current``, lock time then ramp) and MESC (a current vector turned at a set rate) are the
same idea without the stabilising loop.

Everything here comes from the nameplate and the commissioning (R_s, the dead-time voltage, J where the
rotating test measured it), never from the plant:
- the I-f current I_f: rated current, lower where the rotor's swing about its load angle,
  Ω = √(n_p·τ_f/J) (τ_f = 1.5·n_p·ψ_f·I_f), would come within SWING_PER_CURRENT_LOOP of the current loop
  or of the observer's speed estimate, and where the reluctance torque would soften the lock: its stiffness
  1.5·n_p·I_f·(ψ_f − (L_q − L_d)·I_f) kept at least 1 − RELUCTANCE_SHARE of the magnet's (an interior
  magnet's current along d meets the q axis' larger inductance);
- the lock: ALIGN_SWINGS swing periods 2π/Ω at a fixed angle (its second half a quarter turn further, turned
  smoothly over the first swing period of that half), the
  stabilising loop damping the rotor's swing from the observer's speed (the back-EMF of the swing);
- the ramp's acceleration: ACCELERATION_SHARE of τ_f over J (electrical rad/s²), the rest of τ_f the
  stated load margin for friction and load while open loop (load angle asin(ACCELERATION_SHARE) ≈ 17°; the
  ramp's start swings the rotor to twice that, 0.61 rad, well inside ±π/2, without a stabilising loop: at the
  ramp's start the observer, drifted at rest, is worst; the loop takes over again from the hand-back speed);
- the observer's minimum speed: where its angle error bound U_err/(ω_e·ψ_f) reaches OBSERVER_ERROR_BOUND_RAD,
  U_err what its voltage model can be wrong by (hf_estimator.full_speed's: the dead-time voltage ×4/3, 2 % of
  U_dc where never measured, plus 10 % of R_s·I_f), and its angle noise L_q·σ_i/ψ_f (σ_i the commissioned
  sensor noise) within ours' RMS target; at least MIN_HANDOVER_PER_RATED of rated speed. Hand back to I-f
  below HANDBACK_PER_HANDOVER of it;
- refused where the I-f current lies too close to the switches' commutation band (COMMUTATION_MARGIN): there
  the inverter's voltage error is unknown and turns with the current's sign, and the current vector the start
  turns is not the one it commands.
"""
import math
from typing import NamedTuple

from drive_common.math.dead_time import MIN_SMOOTHING_A, SMOOTHING_PER_RATED_CURRENT

ESTIMATOR = "if_observer"
"""The estimator of such a start (hf_estimator.if_observer): the back-EMF observer, open loop below its speed."""
ACCELERATION_SHARE = 0.3
"""The share of the I-f torque the ramp's acceleration takes; 1 − it is the load margin while open loop."""
SWING_PER_CURRENT_LOOP = 0.25
"""The rotor's swing frequency Ω at most this share of the current loop's bandwidth,"""
OBSERVER_SPEED_BANDWIDTH_RAD_S = 0.5 * 2.0 * math.pi * 100.0
"""and of the observer's speed estimate (it follows at α_o/2, α_o = 2π·100 Hz, hf_estimator.flux_observer's
default), which feeds the stabilising loop: on a light rotor whose Ω was 198 rad/s the loop, fed a lagging
speed, left the swing undamped and the observer never agreed."""
OBSERVER_ERROR_BOUND_RAD = 0.1
"""The back-EMF observer leads once its angle error bound U_err/(ω_e·ψ_f) is within this: two thirds of ours'
peak target. The bound is a ripple's peak (the dead-time voltage at no load, where the current crosses zero
all the time): at 1.5 × the speed of a bound of 0.15 rad a drawn 16-pole-pair round rotor ran at 0.03 rad
RMS, at 1.5 × that of 0.1 rad within ours' 0.02."""
OBSERVER_NOISE_RMS_RAD = 0.02
"""Its angle noise L_q·σ_i/ψ_f must lie within ours' RMS target, or the observer cannot meet it at any speed."""
RELUCTANCE_SHARE = 0.3
MIN_HANDOVER_PER_RATED = 0.02
MAX_HANDOVER_PER_RATED = 0.4
"""A minimum speed above this share of rated speed is refused: the motor would hardly run (and its own
experiments, a speed step to twice 1.2 × that speed, would pass rated speed)."""
HANDBACK_PER_HANDOVER = 0.6
RESISTANCE_ERROR = 0.1
UNMEASURED_DEAD_TIME_PER_U_DC = 0.02
ALIGN_SWINGS = 4.0
"""The first lock lasts this many swing periods 2π/Ω (the stabilising loop settles it), half at a fixed
angle, half a quarter turn further, turned as ¼π·(1 − cos(π·t/T)) over T = a quarter of the lock: a step of a
quarter turn swung a heavy rotor (seed 11 motor 1, acceleration time 2.6 s) ±1.5 rad about the new angle, the
observer, drifted at rest, read the swing's speed with the wrong sign and the stabilising loop pulled the rotor
out of the lock; turned so, the rotor followed the turn within 0.15 rad and the load angle stayed within 1 rad
through the lock and the ramp."""
DAMPING_FILTER_PER_SWING = 3.0
DAMPING_GAIN = 4.0
"""The stabilising loop during the lock: the current's angle retarded by φ = −k·ṽ, ṽ the rotor's speed
through 1/(s + c), c = DAMPING_FILTER_PER_SWING·Ω, k = DAMPING_GAIN: the linearised swing's characteristic
polynomial s³ + c·s² + Ω²(1 + k)·s + Ω²·c = (s + Ω)(s² + 2Ω·s + 3Ω²), damping 0.58, for any Ω. (From the q
voltage of the current's frame instead of the observer, the swing of a heavy rotor did not decay.)"""
COMMUTATION_MARGIN = 4.0
"""The I-f current at least this many times the switches' commutation band (drive_common.math.dead_time: the
larger of MIN_SMOOTHING_A and SMOOTHING_PER_RATED_CURRENT of rated current, the band the drive assumes for its
dead-time model): each phase current then lies within the band for at most 2·asin(1/4)/π ≈ 16 % of the
period. Measured on seeds 11 and 29 (every motor the I-f start ran, 2026-11-28): the five at 0.1-2.5 × the band
failed (light rotors whose swing rule cut I_f to 1-2 % of rated current: the true current fell to half of I_f,
the load angle past π/2, or the observer over target); the nine that worked lay at 7 × or more."""
AGREEMENT_PER_SPEED = 0.2
"""The hand-over waits for the observer's speed within this share of the ramp's,"""
OBSERVER_GAIN_PER_SPEED = 0.2
"""for as long as the observer's flux error takes to decay SETTLE_DECAYS times at the hand-over speed: that error
decays at its gain k_1 = σ_0 + 0.2·|ω| (hf_estimator.flux_observer's, which takes this constant; Hinkkanen et al.
2018; σ_0 = ¼R_s(1/L_d + 1/L_q)), and what the voltage model's error built into it below that speed, where k_1 is
smallest, is still there at the hand-over: random_1_0051 handed over with its observer 0.19 rad behind the rotor
(0.15 rad 20 ms later)."""
SETTLE_DECAYS = 3.0


def observer_gain_rad_s(R_s_ohm, L_d_H, L_q_H, omega_e_rad_s):
    """The back-EMF observer's gain k_1 = σ_0 + OBSERVER_GAIN_PER_SPEED·|ω| [1/s] at electrical speed
    ``omega_e_rad_s``, σ_0 = ¼R_s(1/L_d + 1/L_q): the rate its flux error decays at (hf_estimator.flux_observer)."""
    return 0.25 * R_s_ohm * (1.0 / L_d_H + 1.0 / L_q_H) + OBSERVER_GAIN_PER_SPEED * abs(omega_e_rad_s)


class OpenLoopStart(NamedTuple):
    """An I-f start, SI units, speeds and accelerations electrical."""

    current_A: float
    torque_Nm: float
    acceleration_rad_s2: float
    swing_rad_s: float
    handover_rad_s: float
    handback_rad_s: float
    align_s: float
    observer_error_V: float
    load_margin_Nm: float
    observer_settle_s: float
    """How long the observer's speed must agree with the ramp's before the hand-over [s]."""
    refused: str
    """"" or why this motor cannot be started so (one line)."""

    def handover_rpm(self, n_p):
        """The hand-over speed in mechanical rpm."""
        return self.handover_rad_s / n_p * 30.0 / math.pi

    def statement(self, n_p):
        """What the drive says before acting."""
        return (f"works above {self.handover_rpm(n_p):.0f} rpm, no standstill torque (I-f start at "
                f"{self.current_A:.3g} A, {self.acceleration_rad_s2 / n_p * 30.0 / math.pi:.4g} rpm/s, then the "
                f"back-EMF observer)")


def observer_error_V(plate, commissioning, U_dc_V, current_A):
    """What the back-EMF observer's voltage model can be wrong by [V] at ``current_A``."""
    if commissioning.dead_time_voltage_V > 0.0:
        dead_time = 4.0 / 3.0 * commissioning.dead_time_voltage_V
    else:
        dead_time = 4.0 / 3.0 * UNMEASURED_DEAD_TIME_PER_U_DC * (U_dc_V if math.isfinite(U_dc_V) else 0.0)
    return dead_time + RESISTANCE_ERROR * commissioning.R_s_ohm * current_A


def open_loop_start(plate, commissioning, U_dc_V, current_bandwidth_rad_s):
    """The I-f start (OpenLoopStart) of a motor known by ``plate`` (its nameplate refined by the commissioning:
    J where the rotating test measured it) and ``commissioning`` on a bus of ``U_dc_V`` with current loops of
    ``current_bandwidth_rad_s``; ``refused`` names what is missing."""
    n_p, psi_f = plate.n_p, plate.psi_f_Wb
    omega_rated = n_p * plate.rated_speed_rpm * math.pi / 30.0
    current = min(plate.rated_current_A, plate.current_limit_A)
    if abs(plate.L_q_H - plate.L_d_H) > 0.0:
        current = min(current, RELUCTANCE_SHARE * psi_f / abs(plate.L_q_H - plate.L_d_H))
    J = plate.J_kgm2
    refused = ""
    if not math.isfinite(J) or J <= 0.0:
        refused = ("the I-f start needs the rotor's inertia to set its ramp: give nameplate.J_kgm2 (the rotating "
                   "test needs the saliency this motor lacks)")
        J = math.nan
    else:
        swing_max = SWING_PER_CURRENT_LOOP * min(current_bandwidth_rad_s, OBSERVER_SPEED_BANDWIDTH_RAD_S)
        current = min(current, swing_max ** 2 * J / (1.5 * n_p ** 2 * psi_f))
    torque = 1.5 * n_p * psi_f * current
    swing = math.sqrt(n_p * torque / J) if math.isfinite(J) else math.nan
    u_err = observer_error_V(plate, commissioning, U_dc_V, current)
    handover = max(u_err / (OBSERVER_ERROR_BOUND_RAD * psi_f), MIN_HANDOVER_PER_RATED * omega_rated)
    noise = plate.L_q_H * commissioning.sensor_noise_A / psi_f
    if not refused and noise > OBSERVER_NOISE_RMS_RAD:
        refused = (f"the back-EMF observer's angle noise L_q·σ_i/ψ_f {noise:.3f} rad exceeds ours' target "
                   f"{OBSERVER_NOISE_RMS_RAD:g} rad at any speed")
    band = max(MIN_SMOOTHING_A, SMOOTHING_PER_RATED_CURRENT * plate.rated_current_A)
    if not refused and current < COMMUTATION_MARGIN * band:
        refused = (f"the I-f current {current:.3g} A (the most the rotor's swing, the current limit and the reluctance "
                   f"torque allow) lies within {COMMUTATION_MARGIN:g} × the switches' commutation band {band:.3g} A, "
                   f"where the inverter's voltage error is unknown: the current vector cannot be turned reliably")
    if not refused and handover > MAX_HANDOVER_PER_RATED * omega_rated:
        refused = (f"the back-EMF observer needs {handover / omega_rated:.0%} of rated speed for an angle error "
                   f"within {OBSERVER_ERROR_BOUND_RAD:g} rad ({u_err:.3g} V of voltage error against ψ_f "
                   f"{psi_f:.3g} Wb)")
    acceleration = ACCELERATION_SHARE * n_p * torque / J if math.isfinite(J) else math.nan
    return OpenLoopStart(current_A=current, torque_Nm=torque, acceleration_rad_s2=acceleration, swing_rad_s=swing,
                         handover_rad_s=handover, handback_rad_s=HANDBACK_PER_HANDOVER * handover,
                         align_s=ALIGN_SWINGS * 2.0 * math.pi / swing if math.isfinite(swing) else math.nan,
                         observer_error_V=u_err, load_margin_Nm=(1.0 - ACCELERATION_SHARE) * torque,
                         observer_settle_s=SETTLE_DECAYS / observer_gain_rad_s(commissioning.R_s_ohm, plate.L_d_H,
                                                                                 plate.L_q_H, handover),
                         refused=refused)
