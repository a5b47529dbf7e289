"""An inverter's switching modes and the safe state at speed (docs/protections.md): with all switches
off (freewheel) the diodes rectify a back-EMF above the bus into it; with the low-side switches on (active
short circuit, ASC) the machine's short-circuit current flows and the bus stays where it is."""
import math

from numba import njit

PWM, FREEWHEEL, ASC = 0, 1, 2
"""Switching the commanded voltage; all switches off; all low-side switches on."""
SAFE_STATE_MARGIN = 0.9
"""ASC once the back-EMF's line-to-line peak reaches this share of the bus."""
OVERVOLTAGE_PER_BUS = 1.25
"""Without a stated over-voltage trip level (InverterRating.U_overvoltage_V) the inverter and the drive trip
at this many times the rated bus."""


def overvoltage_trip_V(rating):
    """The bus voltage [V] an inverter with this InverterRating trips at."""
    return rating.U_overvoltage_V if math.isfinite(rating.U_overvoltage_V) else OVERVOLTAGE_PER_BUS * rating.U_dc_V


@njit(cache=True)
def safe_state_for(omega_e, U_dc, psi_f_Wb):
    """ASC where the back-EMF's line-to-line peak √3 |ω_e| ψ_f [V] reaches SAFE_STATE_MARGIN of the bus
    U_dc [V], else FREEWHEEL (ω_e [rad/s], electrical; ψ_f [Wb])."""
    if math.sqrt(3.0) * abs(omega_e) * psi_f_Wb >= SAFE_STATE_MARGIN * U_dc:
        return ASC
    return FREEWHEEL
