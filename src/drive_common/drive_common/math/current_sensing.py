"""Correction of measured phase currents by the commissioned sensor gains and offsets, as a numba
kernel: every core that reads the `currents` topic calls it first (docs/commissioning.md §2)."""
import math
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



class CurrentSensing(NamedTuple):
    """How a core reads the measured currents: their commissioned correction, and the trip current [A]
    beyond which (or not finite) a sample is bad input."""

    calibration: CurrentCalibration
    trip_A: float


def current_sensing(calibration, trip_A):
    """CurrentSensing of ``calibration`` and ``trip_A`` [A] (a float: one compiled type)."""
    return CurrentSensing(calibration, float(trip_A))


@njit(cache=True)
def bad_currents(i_a, i_b, i_c, trip_A):
    """True when a measured phase current is not finite or beyond ``trip_A`` [A]."""
    return not (math.isfinite(i_a) and math.isfinite(i_b) and math.isfinite(i_c)) or max(
        abs(i_a), abs(i_b), abs(i_c)) > trip_A


@njit(cache=True)
def corrected_currents(m_a, m_b, m_c, cal):
    """Measured phase currents [A] → the currents the sensors imply: (m_x − offset_x) / gain_x."""
    return ((m_a - cal.offset_a_A) / cal.gain_a, (m_b - cal.offset_b_A) / cal.gain_b,
            (m_c - cal.offset_c_A) / cal.gain_c)
