"""The inverter's dead-time voltage as the drive models it (docs/commissioning.md §2): each phase loses
V_dt·sign(i_x) of its average voltage, the sign smoothed near zero current (commutation through the
switches' capacitance is not instantaneous). The commissioning measures V_dt; our estimator subtracts the
modelled loss from the voltage it pairs with each current step. One kernel: numba per sample, and its
``py_func`` on numpy arrays."""
import numpy as np
from numba import njit

from .frames import inverse_clarke

SQRT3 = 3.0 ** 0.5
SMOOTHING_PER_RATED_CURRENT = 0.01
"""The sign is smoothed as tanh(i / (this × rated current)): an assumption, the drive cannot resolve it
at standstill."""
MIN_SMOOTHING_A = 0.05
"""Ours smooths the sign over at least this current: a small MOSFET bridge's switches commutate within about
2·C_oss·U_dc/t_dead ≈ 2 · 300 pF · 24 V / 0.3 µs ≈ 50 mA whatever the motor's rating, so 1 % of a rating below 5 A
is too sharp (on drawn motors rated 0.5-2 A a sharper sign doubled ours' error: docs/results.md, "Random motors
(issue 51)"). The simulated plant commutates within 50 mA on every motor; the drive does not measure it."""


@njit(cache=True)
def dead_time_direction(i_a, i_b, i_c, smoothing_A):
    """Clarke transform (α, β) of the phase currents' smoothed signs (hard signs when smoothing_A is 0):
    the dead-time voltage per volt of per-phase loss (4/3 along a phase axis)."""
    if smoothing_A > 0.0:
        s_a, s_b, s_c = np.tanh(i_a / smoothing_A), np.tanh(i_b / smoothing_A), np.tanh(i_c / smoothing_A)
    else:
        s_a, s_b, s_c = np.sign(i_a), np.sign(i_b), np.sign(i_c)
    return (2.0 * s_a - s_b - s_c) / 3.0, (s_b - s_c) / SQRT3


@njit(cache=True)
def net_of_dead_time(u_alpha, u_beta, i_alpha, i_beta, dead_time_voltage_V, smoothing_A):
    """The applied voltage (α, β) [V] net of the modelled dead-time loss over a period that started at the
    currents (i_α, i_β) [A]: each phase's loss ``dead_time_voltage_V`` [V] along its current's sign smoothed
    over ``smoothing_A`` [A]; the voltage as it is where the loss is not modelled (0 V)."""
    if dead_time_voltage_V == 0.0:
        return u_alpha, u_beta
    start_a, start_b, start_c = inverse_clarke(i_alpha, i_beta)
    loss_alpha, loss_beta = dead_time_direction(start_a, start_b, start_c, smoothing_A)
    return u_alpha - dead_time_voltage_V * loss_alpha, u_beta - dead_time_voltage_V * loss_beta
