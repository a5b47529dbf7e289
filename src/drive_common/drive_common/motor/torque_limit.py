"""The torque a drive holds without a sensor at low speed, and the current angle that gives the most torque
per ampere (MTPA), from what its commissioning measured (docs/motors-and-control.md "MTPA and the sensorless
torque limit").

The torque model is the motor's flux linearised about the i_d = 0 axis the commissioning measured along
(first order in i_d, the saliency table's cross-saturation included):
  ψ_d = ψ_d0(i_q) + L_dh·i_d,  ψ_d0(i_q) = ψ_f + ∫₀^i_q L_dq di,  ψ_q = L_qh·i_q + L_dq(i_q)·i_d,
  L_dq(i_q) = −½·tan 2δ(i_q)·(L_qh − L_dh)  (δ: the saliency axis of the incremental inductances),
  τ = 1.5·n_p·(ψ_d·i_q − ψ_q·i_d).
MTPA is the current angle that maximises τ at each current magnitude: for constant inductances the closed
form of Morimoto et al. 1990 (IEEE Trans. Ind. Appl. 26(5)), i_d = (ψ_f − √(ψ_f² + 8(L_q − L_d)²|i|²)) /
(4(L_q − L_d)) (``mtpa_d_current_A``); with the measured cross-saturation, found numerically over the angle,
as motulator computes its MTPA locus for saturated machines.
"""
import math
from typing import NamedTuple

import numpy as np

from drive_common.motor.commissioning import MIN_CONVERGENCE_SLOPE, SALIENCY_RETAINED, held_up_to

MTPA_MIN_GAIN = 0.05
"""MTPA is used where its torque model gives at least this much more torque than i_d = 0 at the sensorless
current: a smaller gain is within the model's own error (first order in i_d: 1-8 % on interior magnets,
TORQUE_TOLERANCE) and does not pay for running the estimators away from the i_d = 0 operating points the
commissioning measured (0.09 % on wang_spmsm, whose saliency is the magnet's saturation; 1.8 % on
szabo_ipmsm)."""
PATH_POINTS = 33
"""Current magnitudes of the MTPA table the controller interpolates (uniform from 0 to the table's end)."""
ANGLE_POINTS = 721
"""Current angles searched per magnitude, from the q axis to MAX_ANGLE_RAD towards −d."""
MAX_ANGLE_RAD = 0.25 * math.pi
"""MTPA of a PMSM lies between the q axis and 45° towards −d (the synchronous reluctance limit)."""
TORQUE_TOLERANCE = 0.10
"""The stated torque matches the plant's within this share on a random draw of interior-magnet motors
(test/test_torque_limit.py: the model is first order in i_d and leaves out the q axis's own saturation)."""
BOUNDS = ("the saliency left at that current", "the angle signal's slope under load", "the loaded test",
          "the motor's current limit", "the controller's current limit", "the bus",
          "the largest current commissioning measured the saliency at", "ours' angle error predicted at that current")
"""What can set the sensorless current, in the order the lines say them."""


class MtpaPath(NamedTuple):
    """The MTPA current path: d current [A] at each current magnitude [A] (i_d ≤ 0 for L_q > L_d), and the
    torque it gives there over i_d = 0's, less 1, at the table's end."""

    current_A: np.ndarray
    d_current_A: np.ndarray
    gain: float


class SensorlessTorque(NamedTuple):
    """The torque a drive holds sensorless at low speed: at ``current_A`` [A] (set by ``bound``, one of
    BOUNDS), ``torque_Nm`` [N·m] on its current path (MTPA where ``mtpa``, else i_d = 0; ``d_current_A`` [A]),
    ``torque_zero_d_Nm`` at i_d = 0 at the same current, the motor's ``rated_torque_Nm``, and ``why`` (the
    figures of the bound)."""

    current_A: float
    torque_Nm: float
    torque_zero_d_Nm: float
    d_current_A: float
    rated_torque_Nm: float
    mtpa: bool
    bound: str
    why: str

    @property
    def rated_share(self):
        """The torque per rated torque [1]."""
        return self.torque_Nm / self.rated_torque_Nm

    def line(self):
        """One line: the torque, its share of rated, the current, the path and why."""
        path = (f"MTPA, i_d {self.d_current_A:+.3g} A; {self.torque_zero_d_Nm:.3g} N·m at i_d = 0" if self.mtpa
                else "i_d = 0")
        return (f"sensorless torque limit {self.torque_Nm:.3g} N·m ({100.0 * self.rated_share:.0f} % of rated) at "
                f"{self.current_A:.3g} A ({path}): set by {self.bound}{f' ({self.why})' if self.why else ''}")

    def as_dict(self):
        """The figures as a mapping (SI units in the keys), for --json and /diagnostics."""
        return {**self._asdict(), "rated_share": self.rated_share, "line": self.line()}


def mtpa_d_current_A(current_A, psi_f_Wb, L_d_H, L_q_H):
    """Morimoto et al. 1990's MTPA d current [A] at the current magnitude ``current_A`` [A] for constant
    inductances [H] and magnet flux [Wb]: 0 for a round rotor."""
    difference = L_q_H - L_d_H
    if difference == 0.0:
        return 0.0
    return (psi_f_Wb - math.sqrt(psi_f_Wb ** 2 + 8.0 * difference ** 2 * current_A ** 2)) / (4.0 * difference)


def _cross_inductance(commissioning):
    """(q currents [A], L_dq [H] there, ψ_d0 [Wb] relative to ψ_f) of the commissioned saliency table."""
    currents = np.asarray(commissioning.saliency_shift_i_q_A, dtype=float)
    shift = np.clip(np.asarray(commissioning.saliency_shift_rad, dtype=float), -0.7, 0.7)
    L_dq = -0.5 * np.tan(2.0 * shift) * (commissioning.L_qh_H - commissioning.L_dh_H)
    steps = 0.5 * (L_dq[1:] + L_dq[:-1]) * np.diff(currents)
    flux = np.concatenate([[0.0], np.cumsum(steps)])
    return currents, L_dq, flux - np.interp(0.0, currents, flux)


def torque_Nm(plate, commissioning, i_d_A, i_q_A):
    """τ [N·m] of the module's torque model at (i_d, i_q) [A] (arrays or numbers) for the nameplate ``plate``
    (ψ_f the rotating test's where it ran) and the ``commissioning`` record."""
    psi_f = commissioning.refined(plate).psi_f_Wb
    currents, L_dq, flux = _cross_inductance(commissioning)
    i_d, i_q = np.asarray(i_d_A, dtype=float), np.asarray(i_q_A, dtype=float)
    cross = np.interp(i_q, currents, L_dq)
    psi_d = psi_f + np.interp(i_q, currents, flux) + commissioning.L_dh_H * i_d
    psi_q = commissioning.L_qh_H * i_q + cross * i_d
    return 1.5 * plate.n_p * (psi_d * i_q - psi_q * i_d)


def mtpa_path(plate, commissioning, current_A):
    """The MtpaPath up to ``current_A`` [A]: at each magnitude the angle of the largest torque_Nm."""
    magnitudes = np.linspace(0.0, current_A, PATH_POINTS)
    angles = np.linspace(0.0, MAX_ANGLE_RAD, ANGLE_POINTS)
    i_d = -np.outer(magnitudes, np.sin(angles))
    i_q = np.outer(magnitudes, np.cos(angles))
    torque = torque_Nm(plate, commissioning, i_d, i_q)
    best = np.argmax(torque, axis=1)
    d_current = i_d[np.arange(len(magnitudes)), best]
    zero_d = float(torque[-1, 0])
    gain = float(torque[-1, best[-1]] / zero_d - 1.0) if zero_d > 0.0 else 0.0
    return MtpaPath(magnitudes, d_current, gain)


def mtpa_gains(plate, commissioning):
    """MTPA gives at least MTPA_MIN_GAIN more torque than i_d = 0 at the motor's sensorless current (its
    nameplate limit, at most where the commissioned tables keep the angle signal): the rule the controller's
    and the estimators' builders both follow."""
    if commissioning is None:
        return False
    current = min(plate.current_limit_A, commissioning.tracking_current_limit_A())
    return current > 0.0 and mtpa_path(plate, commissioning, current).gain >= MTPA_MIN_GAIN


def controller_path(plate, commissioning, current_A):
    """The MTPA path the controller runs up to ``current_A`` [A] where mtpa_gains, else None (i_d = 0)."""
    if current_A <= 0.0 or not mtpa_gains(plate, commissioning):
        return None
    return mtpa_path(plate, commissioning, current_A)


def shift_along(commissioning, path):
    """``commissioning`` with its saliency-shift table moved to the MtpaPath ``path`` (None: unchanged; its end at
    least the table's largest current): the d current
    i_d(i_q) there turns the saliency axis by i_d·∂δ/∂i_d = i_d·(F − 1)/i_q (F the table's convergence slope
    1 + i_q·∂δ/∂i_d), so the estimators subtract the axis where the current is."""
    if path is None:
        return commissioning
    currents = np.asarray(commissioning.saliency_shift_i_q_A, dtype=float)
    q_on_path = np.sqrt(np.maximum(path.current_A ** 2 - path.d_current_A ** 2, 0.0))
    d_current = np.interp(np.abs(currents), q_on_path, path.d_current_A)
    slope_per_current = np.divide(np.asarray(commissioning.convergence_slope) - 1.0, currents,
                                  out=np.zeros_like(currents), where=currents != 0.0)
    return commissioning._replace(saliency_shift_rad=commissioning.saliency_shift_rad
                                  + d_current * slope_per_current)


def estimator_commissioning(plate, commissioning, controller_settings):
    """The commissioning record the estimators run on under the controller's ``controller_settings`` (a
    scenario's ``controller:``): its saliency shift on the MTPA path where the controller runs one
    (shift_along), else ``commissioning`` itself."""
    if not controller_settings.get("mtpa", True) or not mtpa_gains(plate, commissioning):
        return commissioning
    end = float(np.max(np.abs(commissioning.saliency_shift_i_q_A)))
    return shift_along(commissioning, mtpa_path(plate, commissioning, end))


def tracking_bound(commissioning, current_A):
    """(bound, why) of a sensorless current ``current_A`` [A] the commissioned tables or the loaded test set
    (the one of them whose own limit it is), with its figures; None where none of them does."""
    currents = commissioning.saliency_shift_i_q_A
    ratio = None if commissioning.saliency_ratio is None else np.abs(commissioning.saliency_ratio)
    candidates = [(held_up_to(currents, commissioning.convergence_slope, MIN_CONVERGENCE_SLOPE), BOUNDS[1],
                   f"the convergence slope falls to {MIN_CONVERGENCE_SLOPE:g}")]
    if ratio is not None:
        candidates.append((held_up_to(currents, ratio, SALIENCY_RETAINED * ratio[np.argmin(np.abs(currents))]),
                           BOUNDS[0], f"|Δ|/Σ falls to {100.0 * SALIENCY_RETAINED:.0f} % of its no-load value"))
    if math.isfinite(commissioning.loaded_test_current_A):
        candidates.append((commissioning.loaded_test_current_A, BOUNDS[2],
                           "ours lost its angle under larger loads with the shaft held"))
    end = float(np.max(np.abs(currents)))
    for limit, bound, why in candidates:
        if limit < end and abs(limit - current_A) <= 1e-6 * max(current_A, 1e-6):
            return bound, why
    if abs(end - current_A) <= 1e-6 * max(current_A, 1e-6):
        return BOUNDS[6], (f"its tables end at {end:.3g} A: commissioning keeps each DC level and its HF ripple "
                           f"within the current limit and what the bus drives")
    return None


def sensorless_torque(plate, commissioning, current_A, path, bound):
    """SensorlessTorque at the controller's current limit ``current_A`` [A] on ``path`` (MtpaPath or None:
    i_d = 0); ``bound``: (bound, why) of that current."""
    d_current = float(np.interp(current_A, path.current_A, path.d_current_A)) if path is not None else 0.0
    q_current = math.sqrt(max(current_A ** 2 - d_current ** 2, 0.0))
    torque = float(torque_Nm(plate, commissioning, d_current, q_current))
    zero_d = float(torque_Nm(plate, commissioning, 0.0, current_A))
    return SensorlessTorque(float(current_A), torque, zero_d, d_current, plate.rated_torque_Nm, path is not None,
                            *bound)


def current_bound(plate, commissioning, inverter, current_A, injecting, estimator_bound=None):
    """(bound, why) of the controller's current limit ``current_A`` [A]: the estimator's own limit
    ``estimator_bound`` ((bound, why, limit [A]) it states, or None) where it is that current, the commissioned
    tables (for an injecting estimator), the bus at standstill (U_dc/√3 over R_s), the nameplate's limit, else the
    controller's own setting."""
    if estimator_bound is not None and abs(estimator_bound[2] - current_A) <= 1e-6 * max(current_A, 1e-6):
        return estimator_bound[0], estimator_bound[1]
    tables = tracking_bound(commissioning, current_A) if injecting else None
    if tables and (tables[0] != BOUNDS[6] or current_A < plate.current_limit_A * (1.0 - 1e-9)):
        return tables
    bus_A = inverter.U_dc_V / math.sqrt(3.0) / commissioning.R_s_ohm
    if current_A >= bus_A:
        return BOUNDS[5], f"{inverter.U_dc_V:g} V drives {bus_A:.3g} A through R_s {commissioning.R_s_ohm:.3g} Ω"
    if current_A >= plate.current_limit_A * (1.0 - 1e-9):
        return BOUNDS[3], f"{plate.current_limit_A:.3g} A on its nameplate"
    return BOUNDS[4], "its setting current_limit_A"
