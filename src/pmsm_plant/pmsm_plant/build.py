"""The plant of a scenario: the preset's true machine with the scenario's non-idealities, its state at
the scenario's initial shaft angle and speed, and what a period's integration needs."""
from dataclasses import dataclass

import numpy as np

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
    x = np.zeros(N_STATE)
    plant_reset(x, scenario.initial_theta_m_rad, scenario.initial_omega_m_rad_s, machine)
    return Plant(machine, mechanics, inverter, sensor, x, scenario.seed, scenario.T_s, scenario.substeps,
                 scenario.mode == "imposed_speed", command_line(inverter.delay_periods))
