"""Frame conventions of the drive interface contract (docs/drive-interface.md), as numba kernels.

Clarke is amplitude-invariant: i_α = i_a, i_β = (i_b − i_c)/√3. Angles are electrical, positive
from α towards β. Every core imports these; there is no second copy.
"""
import math

import numpy as np
from numba import njit

SQRT3 = math.sqrt(3.0)
TWO_PI = 2.0 * math.pi


@njit(cache=True)
def clarke(a, b, c):
    """Phase quantities → (α, β), amplitude-invariant, zero sequence dropped."""
    return (2.0 * a - b - c) / 3.0, (b - c) / SQRT3


@njit(cache=True)
def clarke_contract(a, b, c):
    """The contract's Clarke (x=a, y=b, z=c → α = a, β = (b − c)/√3), used on measured currents."""
    return a, (b - c) / SQRT3


@njit(cache=True)
def inverse_clarke(alpha, beta):
    """(α, β) → phase quantities with zero sum."""
    return alpha, -0.5 * alpha + 0.5 * SQRT3 * beta, -0.5 * alpha - 0.5 * SQRT3 * beta


@njit(cache=True)
def rotate(x, y, angle):
    """Rotate the vector (x, y) by +angle: stationary → stationary, or dq → αβ with the rotor angle."""
    c = math.cos(angle)
    s = math.sin(angle)
    return c * x - s * y, s * x + c * y


@njit(cache=True)
def wrap(angle):
    """Wrap an angle to (−π, π]; ``wrap.py_func`` does the same for numpy arrays."""
    return np.pi - np.mod(np.pi - angle, TWO_PI)
