"""The ideal commissioning measurement: what a perfect standstill HF test would measure on the
simulated machine, computed from its model. Only the simulation's composition calls this; the drive
itself reads a commissioning file (``motor_params.commissioning``)."""
import functools

import numpy as np

from motor_params.commissioning import Commissioning

from .model import incremental_inductances, saturation_saliency_angle

METHOD = "plant_model"
"""How an ideal record was obtained, as written in its file."""


@functools.lru_cache(maxsize=8)
def ideal_commissioning(machine, i_q_max_A, points=65, d_sweep_A=0.01):
    """The standstill HF test's result on ``machine`` (MachineParams): tables over ±i_q_max_A (the
    drive's current limit); the d current is swept by ±d_sweep_A about zero for the convergence slope.
    Cached: a pure function of the machine, shared by the cores of one process."""
    L_dh, L_qh, _ = incremental_inductances(machine)
    currents = np.linspace(-i_q_max_A, i_q_max_A, points)
    shift = np.array([saturation_saliency_angle(machine, 0.0, i_q) for i_q in currents])
    slope = np.array([1.0 + i_q * (saturation_saliency_angle(machine, d_sweep_A, i_q)
                                   - saturation_saliency_angle(machine, -d_sweep_A, i_q))
                      / (2.0 * d_sweep_A) for i_q in currents])
    return Commissioning(L_dh, L_qh, currents, shift, slope)
