"""The one-process runner: composes the plant, estimator and controller cores for a scenario (the same
builders the nodes use) and runs the compiled loop in chunks between progress reports."""
import dataclasses
import sys
import time
from dataclasses import dataclass

import numpy as np

from drive_common.contract.log import LOG_COLUMNS
from drive_common.contract.run_result import RunResult
from drive_common.math.current_sensing import current_sensing
from drive_common.motor.commissioning import resolve_commissioning
from drive_common.motor.nameplate import trip_current_A
from drive_common.runtime.bound_kernels import bound
from drive_common.runtime.interrupt import Interrupted, checkpoint, deferred
from foc_controller.build import controller_for_scenario, protection_for_scenario, stated_torque
from foc_controller.control import controller_state
from foc_controller.protection import protection_state, protection_summary
from hf_estimator.build import estimator_for_scenario
from hf_estimator.interface import contract_injection
from hf_estimator.startup import estimator_startup
from pmsm_plant.build import plant_for_scenario

from .loop import ClosedLoop, DriveCores, PlantCore, Schedule, block_buffers, run_blocks


@dataclass
class Drive:
    """Every core of one drive, built for a scenario, with fresh state."""

    scenario: object
    plant: object
    """pmsm_plant.build.Plant."""
    estimator: object
    controller: object
    controller_x: np.ndarray
    controller_z: np.ndarray
    speed_ref: np.ndarray
    tau_load: np.ndarray
    tau_feedforward: np.ndarray
    """The robot's torque feed-forward to the controller per sample [N·m]."""
    brake: np.ndarray
    """[has a brake (1/0), sample it releases at (−1: not yet known), its lift time in samples]
    (drive_tools.runner.loop.run_blocks)."""
    commissioning: object
    """drive_common.motor.commissioning.Commissioning: what the drive knows beyond its nameplate."""
    protection: object
    """foc_controller.protection.ProtectionParams."""
    protection_x: np.ndarray
    """The protections' state (foc_controller.protection.protection_state)."""

    def run(self, k_start, k_end, log):
        """Run samples k_start..k_end−1 of the compiled loop (k_start a multiple of the scenario's
        block_samples); ``log`` receives one row per sample."""
        bound(run_blocks, self.estimator.step)(self.closed_loop(), k_start, k_end, log)

    def closed_loop(self):
        """The loop's cores and states (drive_tools.runner.loop.ClosedLoop); the states are this drive's."""
        p = self.plant
        plant = PlantCore(p.x, p.line, p.machine, p.mechanics, p.inverter, p.sensor, p.seed, p.T_s, p.substeps,
                          p.imposed_speed)
        schedule = Schedule(self.speed_ref, self.tau_load, self.tau_feedforward, self.brake)
        return ClosedLoop(plant, self.cores(), schedule, self.scenario.block_samples,
                          block_buffers(self.scenario.block_samples))

    def cores(self):
        """The drive's cores a block steps (drive_tools.runner.loop.DriveCores); the states are this drive's."""
        return DriveCores(self.estimator.core(), self.controller, self.controller_x, self.controller_z,
                          self.protection, self.protection_x, self.sensing())

    def sensing(self):
        """How this drive reads its currents: the commissioned calibration and the motor's trip current."""
        return current_sensing(self.commissioning.calibration(), trip_current_A(self.scenario.motor.nameplate))


def brake_state(scenario):
    """The brake array of run_blocks for ``scenario``."""
    return np.array([1.0 if scenario.brake else 0.0, -1.0, round(scenario.brake_release_s / scenario.T_s)])


def scenario_commissioning(scenario):
    """The commissioning record the scenario's drive loads (its ``commissioning`` key or override, the
    default file, or the nameplate alone)."""
    return resolve_commissioning(scenario.motor.nameplate, scenario.commissioning,
                                 f"{scenario.source}: commissioning")


def build_drive(scenario):
    """Plant, estimator and controller for a scenario; ScenarioError or CommissioningError name the key
    at fault."""
    plant = plant_for_scenario(scenario)
    commissioning = scenario_commissioning(scenario)
    estimator = estimator_for_scenario(scenario, commissioning)
    controller = controller_for_scenario(scenario, estimator.injection_frequency_Hz,
                                         estimator.tracking_bandwidth_Hz, estimator.tracking_current_limit_A,
                                         commissioning, estimator.tracking_acceleration_rad_s2, estimator.tracking_loop)
    controller_x, controller_z = controller_state(controller)
    speed_ref, tau_load = scenario.schedule()
    return Drive(scenario, plant, estimator, controller, controller_x, controller_z, speed_ref, tau_load,
                 scenario.feedforward(), brake_state(scenario), commissioning,
                 protection_for_scenario(scenario, commissioning, controller.i_max_A), protection_state())


def run_scenario(scenario, progress=None, chunk_samples=20000):
    """Run a scenario to the end; ``progress(fraction)`` is called between chunks (whole blocks). A signal
    (drive_common.runtime.interrupt) stops it after the chunk in progress, the first one's compilation
    included: the result holds the samples run."""
    drive = build_drive(scenario)
    n = scenario.n_samples
    chunk_samples = -(-chunk_samples // scenario.block_samples) * scenario.block_samples
    log = np.zeros((n, len(LOG_COLUMNS)))
    start = time.perf_counter()
    done, interrupted = 0, 0
    try:
        for k0 in range(0, n, chunk_samples):
            k1 = min(k0 + chunk_samples, n)
            checkpoint()
            with deferred():
                drive.run(k0, k1, log[k0:k1])
                done = k1
            if progress:
                progress(k1 / n)
    except Interrupted as stop:
        interrupted = stop.signum
    wall = time.perf_counter() - start
    return RunResult(cut(scenario, done), drive.estimator.name, log[:done], wall, drive.controller.i_max_A,
                     interrupted, drive.commissioning, drive.estimator.facts(), estimator_startup(drive.estimator),
                     protection=protection_summary(drive.protection_x, drive.protection),
                     injection=contract_injection(drive.estimator.facts(), scenario.injection),
                     sensorless_torque=stated_torque(scenario, drive.commissioning, drive.controller,
                                                     drive.estimator.tracking_current_limit_A is not None,
                                                     drive.estimator.tracking_current_bound).as_dict(),
                     speed_ramp_rad_s2=drive.controller.speed_ramp_rad_s2)


def cut(scenario, samples):
    """``scenario`` with its duration shortened to ``samples`` when a run stopped early."""
    if samples >= scenario.n_samples:
        return scenario
    return dataclasses.replace(scenario, duration_s=samples * scenario.T_s)


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
