"""The plant of a scenario: the preset's true machine with the scenario's non-idealities, its state at
the scenario's initial shaft angle and speed, and what a period's integration needs."""
import math
from dataclasses import dataclass

import numpy as np

from drive_common.config.drive_config import ScenarioError
from drive_common.math.command_delay import command_line

from .model import N_STATE, plant_reset
from .params import InverterParams, MachineParams, MechanicsParams, PlantInputs, PlantParams, SensorParams
from .presets import get_preset, plant_parameters


@dataclass
class Plant:
    machine: MachineParams
    mechanics: MechanicsParams
    inverter: InverterParams
    sensor: SensorParams
    x: np.ndarray
    """State (model.N_STATE)."""
    seed: int
    """Sensor-noise seed."""
    T_s: float
    substeps: int
    imposed_speed: bool
    """The shaft follows the speed table (dynamometer) instead of its torque balance."""
    line: np.ndarray
    """The inverter's delay line of commands (drive_common.math.command_delay), ``inverter.delay_periods`` long."""

    @property
    def params(self):
        """The kernels' parameter record (PlantParams)."""
        return PlantParams(self.machine, self.mechanics, self.inverter, self.sensor, self.seed, self.T_s, self.substeps)

    def inputs(self, load_Nm, speed_rad_s, release_k=-1):
        """A block's PlantInputs: load and speed per period [N·m, rad/s], the brake's release (−1: none)."""
        return PlantInputs(load_Nm, speed_rad_s, self.imposed_speed, release_k)


def plant_for_scenario(scenario):
    """A fresh Plant for ``scenario`` (drive_common.config.scenario.Scenario); its inverter's delay line is
    the drive's delay (``Scenario.drive_delay_periods``: answer delay and blocks)."""
    preset = get_preset(scenario.motor)
    machine, mechanics, inverter, sensor = plant_parameters(preset, scenario.non_idealities,
                                                            scenario.plant_deviation)
    inverter = inverter._replace(delay_periods=scenario.drive_delay_periods())
    if scenario.end_stop:
        mechanics = with_end_stop(mechanics, scenario.end_stop, scenario.T_s / scenario.substeps, scenario.source)
    x = np.zeros(N_STATE)
    plant_reset(x, scenario.initial_theta_m_rad, scenario.initial_omega_m_rad_s, machine)
    return Plant(machine, mechanics, inverter, sensor, x, scenario.seed, scenario.T_s, scenario.substeps,
                 scenario.mode == "imposed_speed", command_line(inverter.delay_periods))


END_STOP_STEP_RAD = 0.5
"""A default end stop's natural frequency times the integration step, ω_stop h = √(k/J) h: as stiff as RK4 stays
accurate (stable up to ≈ 2.8); a stiffer one given is refused above STIFFEST_STEP_RAD."""
STIFFEST_STEP_RAD = 1.0


def with_end_stop(mechanics, stop, h_s, source):
    """``mechanics`` (MechanicsParams) with the end stops of a scenario's ``end_stop`` section
    (drive_common.config.experiment.END_STOP_KEYS) on a shaft integrated in steps of ``h_s`` [s]: stiffness by
    default END_STOP_STEP_RAD, damping by default critical (b = 2 √(k J)); ScenarioError names ``source`` and the
    key where the stop is too stiff for the step."""
    J = mechanics.J_kgm2
    k = stop["stiffness_Nm_rad"]
    if k is None:
        k = J * (END_STOP_STEP_RAD / h_s) ** 2
    elif math.sqrt(k / J) * h_s > STIFFEST_STEP_RAD:
        raise ScenarioError(f"{source}: end_stop.stiffness_Nm_rad: {k:g} N·m/rad on an inertia of {J:g} kg·m² "
                            f"rings faster than the simulation's step {h_s:g} s resolves (at most "
                            f"{J * (STIFFEST_STEP_RAD / h_s) ** 2:.4g} N·m/rad, or more substeps)")
    b = stop["damping_Nms_rad"]
    b = 2.0 * math.sqrt(k * J) if b is None else b
    low, high = stop["low_rad"], stop["high_rad"]
    return mechanics._replace(stop_low_rad=-math.inf if low is None else low,
                              stop_high_rad=math.inf if high is None else high,
                              stop_stiffness_Nm_rad=k, stop_damping_Nms_rad=b)
