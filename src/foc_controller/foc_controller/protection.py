"""The drive's protections (docs/protections.md), from what it knows (nameplate, inverter rating, its
thermal figures or their defaults) and measures (phase currents, the DC-link voltage, its speed
estimate); never the plant's truth. One kernel per block of samples, ``protection_block``:

- DC-link over-voltage controller: above U_ovc_start_V the braking (regenerative) q-current is cut,
  linearly to none at U_ovc_full_V (40 % and 80 % of the way from the rated bus to the trip); above
  U_overvoltage_V the drive trips, latched, into its safe state.
- I²t: a first-order winding temperature estimate, τ dΔT̂/dt = ΔT_rated (R̂_s(T̂)/R̂_s(T_a + ΔT_rated))
  (|i|/I_rated)² − ΔT̂ (the plant's model, pmsm_plant.model, with R_th, C_th told as τ = R_th C_th and the
  rise at rated current). Above T_warning_degC the current limit folds back linearly to the current
  whose steady rise ends at the warning, reached at T_limit_degC: the temperature settles between them.
- R̂_s(T̂) = R_s (1 + α(T̂ − 20 °C))/(1 + α(T_a − 20 °C)) (drive_common.math.copper), R_s measured at ambient
  (the commissioning), handed to the estimators' resistive drop in steps of R_S_STEP (``R_S_IN_USE``, the
  caller puts it in their SAMPLE's R_s_ohm).
- The safe state at speed (drive_common.math.safe_state): active short circuit where the back-EMF √3 |ω̂_e| ψ_f
  reaches SAFE_STATE_MARGIN of the bus (freewheeling would rectify it into the link), freewheel below.

The limits reach the controller through its state (foc_controller.control: FOLDBACK_A, REGEN_CUT).
"""
import math
from typing import NamedTuple

import numpy as np
from numba import njit

from drive_common.contract.settings import Key, read_keys
from drive_common.math.safe_state import ASC, FREEWHEEL, overvoltage_trip_V, safe_state_for
from drive_common.math.winding import R_S_IN_USE, WINDING_KEYS, winding_block

from .control import FOLDBACK_A, REGEN_CUT

SETTINGS = (
    Key("ovc_start_share", "", 0.0, 1.0, default=0.4,
        doc="where the over-voltage controller starts, of the way from the rated bus to the trip"),
    Key("ovc_full_share", "", 0.0, 1.0, default=0.8, doc="where it has cut all braking current"),
    *WINDING_KEYS,
    Key("warning_degC", "°C", -60.0, 300.0, default=120.0, doc="the current limit folds back from here"),
    Key("limit_degC", "°C", -60.0, 300.0, default=130.0, doc="the winding's class limit"),
)
"""The drive's protection figures (a scenario's or drive configuration's ``protection:``), each declared once
(drive_common.contract.settings.Key)."""
DEFAULTS = {key.name: key.default for key in SETTINGS}
"""Without figures of its own the drive assumes a class-B winding (130 °C) rising 80 K at rated current in
a 40 °C ambient, τ = 5 min, and cuts braking current from 40 % of the way from the rated bus to the
over-voltage trip (the inverter rating's U_overvoltage_V, else drive_common.math.safe_state.OVERVOLTAGE_PER_BUS ×
the rated bus), none left at 80 %: from 1.1 × to 1.2 × the rated bus with the default trip."""

# Protection state layout: the winding's (drive_common.math.winding: ΔT̂ [K], the R̂_s [Ω] handed to the
# estimators), tripped (1), the safe state chosen, the cause, the sample it tripped at, the highest T̂ [°C]
# and bus [V] seen.
TRIPPED, SAFE_STATE, CAUSE, TRIP_K, PEAK_DEGC, PEAK_BUS_V = range(R_S_IN_USE + 1, R_S_IN_USE + 7)
N_STATE = PEAK_BUS_V + 1
OVERVOLTAGE = 1
"""The cause of a trip (state CAUSE; 0 while none)."""
CAUSES = {OVERVOLTAGE: "DC-link over-voltage"}
SAFE_STATE_NAMES = {FREEWHEEL: "freewheel", ASC: "active short circuit"}


class ProtectionParams(NamedTuple):
    """The drive's protection figures (SI; temperatures in °C)."""

    T_s_s: float
    psi_f_Wb: float
    """Nameplate."""
    R_s_ohm: float
    """Stator resistance at the ambient temperature (commissioning or nameplate)."""
    rated_current_A: float
    current_limit_A: float
    U_ovc_start_V: float
    U_ovc_full_V: float
    U_overvoltage_V: float
    thermal_time_constant_s: float
    rise_at_rated_K: float
    ambient_degC: float
    warning_degC: float
    limit_degC: float


def make_protection_params(nameplate, inverter, T_s, settings=None, commissioning=None):
    """ProtectionParams of a motor (Nameplate, InverterRating) at the sample period T_s [s]; ``settings``
    overrides DEFAULTS by key; R_s is the commissioning record's when given. ValueError names a key
    unknown or out of order."""
    s = read_keys(settings or {}, SETTINGS, "protection.")
    U = inverter.U_dc_V
    trip = overvoltage_trip_V(inverter)
    start, full = U + s["ovc_start_share"] * (trip - U), U + s["ovc_full_share"] * (trip - U)
    if not U < start < full < trip:
        raise ValueError(f"protection: the over-voltage controller's {start:g} V … {full:g} V must lie between "
                         f"the bus {U:g} V and the trip {trip:g} V, in that order")
    if not s["ambient_degC"] < s["warning_degC"] < s["limit_degC"]:
        raise ValueError("protection: ambient_degC < warning_degC < limit_degC, in that order")
    R_s = commissioning.R_s_ohm if commissioning is not None else nameplate.R_s_ohm
    return ProtectionParams(T_s_s=T_s, psi_f_Wb=nameplate.psi_f_Wb, R_s_ohm=R_s,
                            rated_current_A=nameplate.rated_current_A, current_limit_A=nameplate.current_limit_A,
                            U_ovc_start_V=start, U_ovc_full_V=full, U_overvoltage_V=trip,
                            **{key: float(s[key]) for key in ("thermal_time_constant_s", "rise_at_rated_K",
                                                              "ambient_degC", "warning_degC", "limit_degC")})


@njit(cache=True, _nrt=False, inline='always')
def protection_block(s, p, currents, n, k_last, U_dc, omega_e_hat, cx):
    """n samples, the last sample k_last: the phase currents (n × 3, measured [A]) heat the winding estimate
    (winding_block); the bus U_dc [V] measured at the last of them and the speed estimate ω̂_e [rad/s] there
    set the controller state cx's limits (FOLDBACK_A, REGEN_CUT) and trip. Returns the safe state to switch
    to (FREEWHEEL, ASC) when the drive trips in this block, else 0."""
    T = winding_block(s, p, currents, n)
    s[PEAK_DEGC] = max(s[PEAK_DEGC], T)
    s[PEAK_BUS_V] = max(s[PEAK_BUS_V], U_dc)
    share = min(max((T - p.warning_degC) / (p.limit_degC - p.warning_degC), 0.0), 1.0)
    continuous = p.rated_current_A * math.sqrt((p.warning_degC - p.ambient_degC) / p.rise_at_rated_K)
    cx[FOLDBACK_A] = share * max(p.current_limit_A - continuous, 0.0)
    cx[REGEN_CUT] = min(max((U_dc - p.U_ovc_start_V) / (p.U_ovc_full_V - p.U_ovc_start_V), 0.0), 1.0)
    if s[TRIPPED] == 0.0 and U_dc > p.U_overvoltage_V:
        s[TRIPPED] = 1.0
        s[TRIP_K] = k_last
        s[CAUSE] = OVERVOLTAGE
        s[SAFE_STATE] = safe_state_for(omega_e_hat, U_dc, p.psi_f_Wb)
        return int(s[SAFE_STATE])
    return 0


def protection_state():
    """A fresh protection state: the winding at ambient, no trip."""
    s = np.zeros(N_STATE)
    s[TRIP_K] = -1.0
    s[PEAK_DEGC] = -273.15
    return s


def protection_summary(s, p):
    """What the protections did, for a run's report: the trip (its cause, the sample it came at, the safe
    state chosen) or None, the highest winding temperature estimate [°C] and bus voltage [V] seen."""
    trip = None
    if s[TRIPPED]:
        trip = {"cause": CAUSES[int(s[CAUSE])], "at_s": float(s[TRIP_K] * p.T_s_s),
                "safe_state": SAFE_STATE_NAMES[int(s[SAFE_STATE])]}
    return {"trip": trip, "winding_peak_degC": float(s[PEAK_DEGC]), "bus_peak_V": float(s[PEAK_BUS_V])}
