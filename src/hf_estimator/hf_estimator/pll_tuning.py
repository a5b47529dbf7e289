"""Tuning the tracking PI of the pulsating-injection estimators from the loop models of ``pll_model``:
each estimator's mapping onto the models, both models of its loop, the PI for a requested margin and
crossover, and `synchronous`'s largest loop filter for a request. The closed-loop check that measures
the result runs in the one-process runner (drive_tools.evaluation.pll_check)."""
import dataclasses
import math

from .interface import make_estimator
from .pll_model import (
    carrier_loop,
    carrier_path,
    fastest_pi,
    highest_crossover,
    margins,
    pll_process,
    sos_response,
    szabo_loop,
    tune_pi,
)

MAPPINGS = {
    "synchronous": "Szabó's own loop (Fig. 4): u_h sin ω_h t on d̂, î_q̂ band-pass, × u* cos ω_h t, "
                   "1/(sT_f + 1), PI A_p(1 + 1/(sT_i)), integrator",
    "conventional": "Szabó's loop with Wang's parts: U_h cos ω_h t on d̂, î_q̂ band-pass, × 2 sin ω_h t "
                    "(u* = 2), Butterworth low-pass in place of 1/(sT_f + 1), PI k_p = A_p, k_i = A_p/T_i",
    "improved": "not of Szabó's form: α and β are demodulated and low-passed before the rotation by θ̂ "
                "(Eq. 22), so the loop also sees the d admittance through 1 − F (a high-pass Szabó's model "
                "lacks); only the carrier model covers it",
}


@dataclasses.dataclass(frozen=True)
class PllDesign:
    motor: str
    estimator: object
    """The built estimator (its params hold the current gains k_p, k_i)."""
    path: object
    """Its ``CarrierPath``: what the models read of the drive and the estimator."""
    carrier: object
    szabo: object
    """Szabó's model of the loop (None for `improved`)."""

    @property
    def current_gains(self):
        """(A_p, T_i) the estimator runs with now."""
        p = self.estimator.params
        return p.kp, (p.kp / p.ki if p.ki > 0.0 else math.inf)


def pll_design(nameplate, commissioning, inverter, estimator_name, settings, T_s=1e-4):
    """Both models of ``estimator_name``'s loop with estimator ``settings`` on a motor known by its
    ``nameplate`` and ``commissioning`` record (R_s and the HF inductances) on ``inverter``
    (InverterRating: U_dc and the computation delay)."""
    estimator = make_estimator(estimator_name, nameplate, T_s, settings, commissioning, inverter)
    R = commissioning.R_s_ohm
    path = carrier_path(estimator, R, commissioning.L_dh_H, commissioning.L_qh_H, inverter.delay_periods)
    szabo = None
    if not path.alphabeta:
        process = pll_process(R, commissioning.L_dh_H, commissioning.L_qh_H,
                              path.omega_h_rad_s / (2.0 * math.pi), path.injection_amplitude_V, path.u_star)
        szabo = szabo_loop(process, lambda omega: sos_response(path.lowpass, omega, T_s),
                           0.999 * math.pi / T_s)
    return PllDesign(nameplate.name, estimator, path, carrier_loop(path), szabo)


def largest_loop_filter(nameplate, commissioning, inverter, settings, phase_margin_deg, crossover_rad_s,
                        model="carrier"):
    """`synchronous`'s largest T_f [s] (most ripple filtering) with which ``model``'s loop still reaches
    ``phase_margin_deg`` at ``crossover_rad_s`` (PI zero a decade below); ValueError if none does."""
    def reaches(T_f):
        design = pll_design(nameplate, commissioning, inverter, "synchronous", {**settings, "T_f_s": T_f})
        try:
            return highest_crossover(getattr(design, model), phase_margin_deg) >= crossover_rad_s
        except ValueError:
            return False

    low, high = 1e-6, 1e-2
    if not reaches(low):
        raise ValueError(f"a crossover of {crossover_rad_s:g} rad/s at {phase_margin_deg:g}° is out of reach "
                         f"even with T_f = {low:g} s")
    for _ in range(40):
        middle = math.sqrt(low * high)
        low, high = (middle, high) if reaches(middle) else (low, middle)
    return low


def tuned(loop, phase_margin_deg, crossover_rad_s=None):
    """{A_p, T_i_s, margins} for the request; crossover None: the highest reaching the margin."""
    if crossover_rad_s is None:
        _, A_p, T_i = fastest_pi(loop, phase_margin_deg)
    else:
        A_p, T_i = tune_pi(loop, phase_margin_deg, crossover_rad_s)
    return {"A_p": float(A_p), "T_i_s": float(T_i), **dataclasses.asdict(margins(loop, A_p, T_i))}
