"""Correction of measured phase currents by the commissioned sensor gains and offsets, as a numba
kernel: every core that reads the `currents` topic calls it first (docs/commissioning.md §2)."""
from typing import NamedTuple

from numba import njit


class CurrentCalibration(NamedTuple):
    """Relative gains of the three current sensors (mean 1) and their offsets [A]: a reading is
    m_x = gain_x · i_x + offset_x."""

    gain_a: float
    gain_b: float
    gain_c: float
    offset_a_A: float
    offset_b_A: float
    offset_c_A: float



@njit(cache=True)
def corrected_currents(m_a, m_b, m_c, cal):
    """Measured phase currents [A] → the currents the sensors imply: (m_x − offset_x) / gain_x."""
    return ((m_a - cal.offset_a_A) / cal.gain_a, (m_b - cal.offset_b_A) / cal.gain_b,
            (m_c - cal.offset_c_A) / cal.gain_c)
