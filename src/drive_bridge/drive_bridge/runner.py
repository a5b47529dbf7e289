"""The one-process runner: builds the cores for a scenario and runs the compiled loop in chunks
between progress reports."""
import functools
import sys
import time
from dataclasses import dataclass

import numpy as np

from foc_controller.control import controller_state
from foc_controller.params import make_controller_params
from hf_estimator.common import MIN_CONVERGENCE_SLOPE, commission
from hf_estimator.interface import injects
from hf_estimator.registry import make_estimator
from pmsm_plant.model import N_STATE, plant_reset
from pmsm_plant.presets import get_preset, plant_parameters

from .loop import LOG_COLUMNS, run_samples
from .scenario import ScenarioError


@dataclass
class RunResult:
    scenario: object
    preset: object
    estimator: str
    log: np.ndarray
    """One row per sample, columns drive_bridge.loop.LOG_COLUMNS."""
    wall_time_s: float
    current_limit_A: float
    """The controller's current limit (for injecting estimators: where saliency tracking holds)."""


@dataclass
class Drive:
    """Every core of one drive, built for a scenario, with fresh state."""

    scenario: object
    preset: object
    machine: object
    inverter: object
    sensor: object
    estimator: object
    controller: object
    plant_x: np.ndarray
    controller_x: np.ndarray
    controller_z: np.ndarray
    speed_ref: np.ndarray
    tau_load: np.ndarray

    def run(self, k_start, k_end, log):
        """Run samples k_start..k_end−1 of the compiled loop; ``log`` receives one row per sample."""
        s, e = self.scenario, self.estimator
        run_samples(k_start, k_end, self.plant_x, self.machine, self.preset.mechanics, self.inverter,
                    self.sensor, s.seed, s.T_s, s.substeps, e.step, e.x, e.z, e.params,
                    self.controller_x, self.controller_z, self.controller, self.speed_ref,
                    self.tau_load, s.mode == "imposed_speed", log)


@functools.lru_cache(maxsize=8)
def _commission(machine, i_q_max_A):
    """Commissioning is a pure function of the machine: the nodes of one process share it."""
    return commission(machine, i_q_max_A)


def build_drive(scenario):
    """Plant, estimator and controller for a scenario; errors name the scenario key at fault."""
    preset = get_preset(scenario.motor)
    machine, inverter, sensor = plant_parameters(preset, scenario.non_idealities)
    n_p = machine.n_p
    theta_e0 = n_p * scenario.initial_theta_m_rad
    commissioning = _commission(machine, preset.current_limit_A)
    controller_settings = dict(scenario.controller)
    try:
        settings = dict(scenario.estimator_settings)
        if injects(scenario.estimator):
            settings = {**scenario.injection, **settings}
            controller_settings.setdefault(
                "current_limit_A", commissioning.tracking_current_limit_A(MIN_CONVERGENCE_SLOPE))
        estimator = make_estimator(scenario.estimator, preset, scenario.T_s, settings,
                                   theta_e0 - scenario.initial_angle_error_e_rad,
                                   n_p * scenario.initial_omega_m_rad_s, commissioning,
                                   inverter.delay_periods)
    except (KeyError, ValueError) as error:
        raise ScenarioError(f"{scenario.source}: estimator: {error.args[0]}") from None
    try:
        controller = make_controller_params(preset, scenario.T_s, controller_settings,
                                            estimator.injection_frequency_Hz,
                                            estimator.tracking_bandwidth_Hz)
    except (KeyError, ValueError) as error:
        raise ScenarioError(f"{scenario.source}: controller: {error.args[0]}") from None
    plant_x = np.zeros(N_STATE)
    plant_reset(plant_x, scenario.initial_theta_m_rad, scenario.initial_omega_m_rad_s, machine)
    controller_x, controller_z = controller_state(controller, n_p * scenario.initial_omega_m_rad_s)
    t = np.arange(scenario.n_samples) * scenario.T_s
    return Drive(scenario, preset, machine, inverter, sensor, estimator, controller, plant_x, controller_x,
                 controller_z, scenario.speed.sample(t).astype(float),
                 scenario.load.sample(t).astype(float))


def run_scenario(scenario, progress=None, chunk_samples=20000):
    """Run a scenario to the end; ``progress(fraction)`` is called between chunks."""
    drive = build_drive(scenario)
    n = scenario.n_samples
    log = np.zeros((n, len(LOG_COLUMNS)))
    start = time.perf_counter()
    for k0 in range(0, n, chunk_samples):
        k1 = min(k0 + chunk_samples, n)
        drive.run(k0, k1, log[k0:k1])
        if progress:
            progress(k1 / n)
    return RunResult(scenario, drive.preset, drive.estimator.name, log, time.perf_counter() - start,
                     drive.controller.i_max_A)


def terminal_progress(label):
    """A progress callback printing to stderr when it is a terminal."""
    if not sys.stderr.isatty():
        return None

    def report(fraction):
        sys.stderr.write(f"\r{label}: {100.0 * fraction:5.1f} %")
        if fraction >= 1.0:
            sys.stderr.write("\n")
        sys.stderr.flush()
    return report
