"""A copper winding's resistance against its temperature."""
from numba import njit

COPPER_ALPHA_PER_K = 0.00393
"""Temperature coefficient of copper's resistance at 20 °C [1/K]."""


@njit(cache=True)
def copper_resistance(R_s_ohm, T_ref_degC, T_degC):
    """R(T) [Ω] of a copper winding that has R_s_ohm at T_ref [°C]: R (1 + α(T − 20 °C))/(1 + α(T_ref − 20 °C))."""
    return R_s_ohm * (1.0 + COPPER_ALPHA_PER_K * (T_degC - 20.0)) / (1.0 + COPPER_ALPHA_PER_K * (T_ref_degC - 20.0))
