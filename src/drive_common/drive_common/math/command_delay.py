"""The computation delay between the controller and the inverter as a delay line of voltage commands.

The command answering sample k acts during the period [t_{k+d}, t_{k+d+1}] (d = the drive's delay in
periods: the inverter's own, plus N − 1 with blocks of N samples; docs/architecture.md "Block
transport"), so the voltage acting in period j is command(j − d), zero before the first command. The
plant (or the virtual inverter) applies it; the estimator pairs the current step i[j+1] − i[j] with it.
A line holds the last d + 1 commands, so every period of a block can be served from the commands of
earlier blocks.
"""
import numpy as np
from numba import njit


def command_line(delay_periods):
    """An empty delay line for a delay of ``delay_periods`` ≥ 0: (d + 1) × 2 commands [V, αβ]."""
    return np.zeros((int(delay_periods) + 1, 2))


@njit(cache=True, _nrt=False)
def issue_command(line, k, u_alpha, u_beta):
    """Store the command answering sample k [V, αβ]."""
    slot = k % line.shape[0]
    line[slot, 0] = u_alpha
    line[slot, 1] = u_beta


@njit(cache=True, _nrt=False)
def applied_voltage(line, j):
    """The command acting during period j (from t_j to t_{j+1}): command(j − d), zero before sample 0."""
    k = j - (line.shape[0] - 1)
    if k < 0:
        return 0.0, 0.0
    slot = k % line.shape[0]
    return line[slot, 0], line[slot, 1]
