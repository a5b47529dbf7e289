"""The nameplate: what a robot builder tells the drive about the motor (datasheet values and estimates),
and the drive's own inverter rating. Estimators and the controller read these, never the plant."""
import math
from typing import NamedTuple


class Nameplate(NamedTuple):
    """Motor data from the datasheet, linear model, SI units."""

    name: str
    n_p: int
    """Pole pairs."""
    R_s_ohm: float
    L_d_H: float
    L_q_H: float
    psi_f_Wb: float
    """Permanent-magnet flux linkage (amplitude-invariant scaling)."""
    rated_power_W: float
    rated_current_A: float
    """Peak phase current (amplitude-invariant), the current limit's basis."""
    rated_speed_rpm: float
    rated_torque_Nm: float
    current_limit_A: float
    J_kgm2: float
    """Inertia estimate of rotor and coupled load."""
    B_Nms: float
    """Viscous friction estimate."""


class InverterRating(NamedTuple):
    """The drive's own inverter as designed: the DC-link voltage and the computation delay."""

    U_dc_V: float
    delay_periods: int
    """1: a command computed from sample k is applied during period k+1."""


def _wang_spmsm():
    n_p, rated_power, rated_current, rated_speed = 2, 70.0, 4.6, 3000.0
    rated_torque = rated_power / (rated_speed * 2.0 * math.pi / 60.0)
    return Nameplate(name="wang_spmsm", n_p=n_p, R_s_ohm=0.27, L_d_H=0.9e-3, L_q_H=0.9e-3,
                     psi_f_Wb=rated_torque / (1.5 * n_p * rated_current), rated_power_W=rated_power,
                     rated_current_A=rated_current, rated_speed_rpm=rated_speed, rated_torque_Nm=rated_torque,
                     current_limit_A=1.5 * rated_current, J_kgm2=4.0e-4, B_Nms=1.0e-5)


def _szabo_ipmsm():
    return Nameplate(name="szabo_ipmsm", n_p=3, R_s_ohm=6.2, L_d_H=20.025e-3, L_q_H=40.17e-3, psi_f_Wb=0.305,
                     rated_power_W=1100.0, rated_current_A=2.53, rated_speed_rpm=3000.0, rated_torque_Nm=3.5,
                     current_limit_A=1.5 * 2.53, J_kgm2=3.5e-3, B_Nms=0.0011)


NAMEPLATES = {"wang_spmsm": _wang_spmsm(), "szabo_ipmsm": _szabo_ipmsm()}
"""The nameplates of the shipped motors (Wang et al. 2019 §III-C; Szabó & Veszprémi Table 1)."""
INVERTER_RATINGS = {"wang_spmsm": InverterRating(U_dc_V=24.0, delay_periods=1),
                    "szabo_ipmsm": InverterRating(U_dc_V=560.0, delay_periods=1)}
"""The inverter each shipped motor is driven by."""
TRIP_PER_CURRENT_LIMIT = 3.0
"""A phase current beyond this many times the nameplate's current limit is absurd input, not a current."""


def trip_current_A(plate):
    """The default trip current [A] of a motor with nameplate ``plate``."""
    return TRIP_PER_CURRENT_LIMIT * plate.current_limit_A


def nameplate(name):
    """The shipped nameplate called ``name``; KeyError names the known ones."""
    try:
        return NAMEPLATES[name]
    except KeyError:
        raise KeyError(f"unknown motor '{name}' (known: {', '.join(sorted(NAMEPLATES))})") from None
