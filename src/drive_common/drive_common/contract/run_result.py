"""The record of one run of the drive, however it ran (one process, the ROS graph, the bridge, a recording
read back): its scenario, its log in the contract's layout and what the drive said of itself."""
import math
from dataclasses import dataclass

import numpy as np


@dataclass
class RunResult:
    scenario: object
    estimator: str
    log: np.ndarray
    """One row per sample, columns drive_common.contract.log.LOG_COLUMNS."""
    wall_time_s: float
    current_limit_A: float
    """The controller's current limit (for injecting estimators: where saliency tracking holds)."""
    interrupted: int = 0
    """The signal that stopped the run early (the log and the scenario's duration then end at the last
    sample run), or 0."""
    commissioning: object = None
    """The commissioning record the drive ran on (drive_common.motor.commissioning), when known."""
    estimator_facts: dict = None
    """What the estimator says of itself and its injection (hf_estimator Estimator.facts()), when known."""
    startup: dict = None
    """The start-up's own account at the end (hf_estimator.startup.startup_summary), for an injecting
    estimator run in process."""

    recording_n_p: int = None
    """Pole pairs of a recording's motor when it has no scenario (None: the scenario's motor's)."""
    protection: dict = None
    """What the drive's protections did (foc_controller.protection.protection_summary), when known."""
    injection: dict = None
    """drive_config's ``injection`` object (contract v2: kind, frequency_Hz, amplitude_V) of the estimator as
    it ran (hf_estimator.interface.contract_injection), when known."""

    sensorless_torque: dict = None
    """The torque the drive stated it holds at its current limit (drive_common.motor.torque_limit
    SensorlessTorque.as_dict: N·m, share of rated, current, why), when known."""
    speed_ramp_rad_s2: float = math.inf
    """The controller's ramp of the speed reference [rad/s², mechanical] (ControllerParams; ∞: none or unknown)."""

    @property
    def n_p(self):
        """Pole pairs of the run's motor (its nameplate)."""
        return self.recording_n_p or self.scenario.motor.nameplate.n_p
