"""The inverter's dead-time voltage as the drive models it (docs/commissioning.md §2): each phase loses
V_dt·sign(i_x) of its average voltage, the sign smoothed near zero current (commutation through the
switches' capacitance is not instantaneous). The commissioning measures V_dt; our estimator subtracts the
modelled loss from the voltage it pairs with each current step. One kernel: numba per sample, and its
``py_func`` on numpy arrays."""
import numpy as np
from numba import njit

SQRT3 = 3.0 ** 0.5
SMOOTHING_PER_RATED_CURRENT = 0.01
"""The sign is smoothed as tanh(i / (this × rated current)): an assumption, the drive cannot resolve it
at standstill."""


@njit(cache=True)
def dead_time_direction(i_a, i_b, i_c, smoothing_A):
    """Clarke transform (α, β) of the phase currents' smoothed signs (hard signs when smoothing_A is 0):
    the dead-time voltage per volt of per-phase loss (4/3 along a phase axis)."""
    if smoothing_A > 0.0:
        s_a, s_b, s_c = np.tanh(i_a / smoothing_A), np.tanh(i_b / smoothing_A), np.tanh(i_c / smoothing_A)
    else:
        s_a, s_b, s_c = np.sign(i_a), np.sign(i_b), np.sign(i_c)
    return (2.0 * s_a - s_b - s_c) / 3.0, (s_b - s_c) / SQRT3
