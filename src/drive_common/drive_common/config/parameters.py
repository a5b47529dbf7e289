"""The ROS parameters every scenario-configured node declares: the scenario file (the one `drive run`
reads) and the overrides applied on top of it."""
import dataclasses
import math

from drive_common.contract.settings import number, shown

from .drive_config import MAX_BLOCK_SAMPLES
from .scenario import (
    Scenario,
    ScenarioError,
    load_drive_configuration,
    load_scenario,
    shaft_held,
    with_drive,
)

NODE_PARAMETERS = {
    "scenario": ("wang_100rpm", "shipped scenario name or YAML path: the file `drive run` reads"),
    "drive_configuration": ("", "a drive configuration file (motor, commissioning, estimator, injection, controller, "
                                "sampling period): the estimator and the controller then run without a scenario; "
                                "the plant takes the scenario's experiment with this drive"),
    "motor_file": ("", "the motor: a shipped motor's name or a motor file (empty: the scenario's)"),
    "estimator": ("", "estimator type (empty: the scenario's)"),
    "commissioning": ("", "commissioning file, or 'nameplate' (empty: the scenario's, else "
                          "commissioning/MOTOR.yaml in the working directory when present, else the nameplate)"),
    "seed": (-1, "sensor-noise seed (−1: the scenario's)"),
    "injection.frequency_Hz": (0.0, "HF injection frequency [Hz] (0: the scenario's)"),
    "injection.amplitude_V": (0.0, "HF injection amplitude [V] (0: the scenario's)"),
    "controller.current_limit_A": (0.0, "current limit [A] (0: the scenario's or commissioned)"),
    "controller.speed_limit_rad_s": (math.inf, "mechanical speed reference limit [rad/s], positive"),
    "duration_s": (0.0, "run length [s] (0: the scenario's)"),
    "block_samples": (0, "samples per message on the per-sample topics, N (0: the scenario's; the command "
                         "then acts N − 1 periods later)"),
    "answer_periods": (0, "periods from a block's last sample to its first command acting (0: the scenario's; "
                          "behind an inverter with blocks of N, N + 1)"),
    "shaft_held": (False, "hold the shaft at its initial angle, no load (a brake: commissioning; the plant "
                          "then starts without an estimator in the graph)"),
    "lockstep_timeout_s": (1.0, "wall time to wait for an answer before declaring a fault [s]"),
    "diagnostics_period_s": (1.0, "period of /diagnostics [s]"),
    "trip_current_A": (0.0, "|phase current| above this is absurd input (0: 3 × the nameplate's limit) [A]"),
}
"""name → (default, description); settable with --ros-args -p NAME:=VALUE or a params file."""


def all_parameters(overrides):
    """Every node parameter: the defaults with ``overrides`` applied."""
    merged = {name: default for name, (default, _) in NODE_PARAMETERS.items()}
    merged.update(overrides)
    return merged


SCHEDULE_PARAMETER = {"scenario_schedule": (
    False, "take each sample's speed reference and torque feed-forward (controller), load torque and imposed "
           "speed (plant) from the scenario, sample-exact with no message per sample; the launcher sets it, "
           "otherwise the topics apply")}
"""The plant's and the controller's own parameter (drive_common.ros.node.DriveNode.node_parameters)."""
PARAMETER_RANGES = {
    "seed": (-1, 2 ** 63 - 1),
    "injection.frequency_Hz": (0.0, math.inf),
    "injection.amplitude_V": (0.0, math.inf),
    "controller.current_limit_A": (0.0, math.inf),
    "duration_s": (0.0, math.inf),
    "block_samples": (0, MAX_BLOCK_SAMPLES),
    "answer_periods": (0, MAX_BLOCK_SAMPLES + 1),
    "lockstep_timeout_s": (1e-3, 3600.0),
    "diagnostics_period_s": (1e-3, 3600.0),
    "trip_current_A": (0.0, math.inf),
}
"""Allowed [low, high] of the numeric parameters (finite unless high is inf, where only inf itself is
refused); the speed limit is checked by the controller."""


def check_parameters(parameters, label=lambda name: f"parameter {name}"):
    """ScenarioError naming the first parameter out of its range (``label(name)`` says where it came
    from: a params file, the command line, a launcher)."""
    for name, (low, high) in PARAMETER_RANGES.items():
        value = parameters[name]
        try:
            number(name, value, low=low, high=None if math.isinf(high) else high, low_inclusive=True)
        except ValueError:
            raise ScenarioError(f"{label(name)}: must be a finite number in [{low:g}, {high:g}], "
                                f"not {shown(value)}") from None


def scenario_from_parameters(parameters, label=lambda name: f"parameter {name}", experiment=True):
    """What the nodes run: the Scenario of the file named by ``scenario`` with the override parameters
    applied; with ``drive_configuration``, its DriveConfig run on that scenario's experiment, or the
    DriveConfig alone (no experiment: it runs until stopped) where the node needs none (not ``experiment``:
    the estimator; the controller taking its speed from `speed_command`). ScenarioError naming the
    parameter (``label(name)``) or the file's key."""
    check_parameters(parameters, label)
    overrides = {"estimator_override": parameters["estimator"] or None, "override_source": label("estimator"),
                 "motor_override": parameters["motor_file"] or None, "motor_source": label("motor_file")}
    if parameters["drive_configuration"]:
        drive = load_drive_configuration(parameters["drive_configuration"], label("drive_configuration"), **overrides)
        config = with_drive(load_scenario(parameters["scenario"]), drive) if experiment else drive
    else:
        config = load_scenario(parameters["scenario"], **overrides)
    changes = {}
    if parameters["commissioning"]:
        changes["commissioning"] = str(parameters["commissioning"])
    if parameters["block_samples"] > 0:
        changes["block_samples"] = int(parameters["block_samples"])
    if parameters["answer_periods"] > 0:
        changes["answer_periods"] = int(parameters["answer_periods"])
    if isinstance(config, Scenario):
        if parameters["seed"] >= 0:
            changes["seed"] = int(parameters["seed"])
        if parameters["duration_s"] > 0.0:
            changes["duration_s"] = float(parameters["duration_s"])
    injection = dict(config.injection)
    for key in ("frequency_Hz", "amplitude_V"):
        if parameters[f"injection.{key}"] > 0.0:
            injection[key] = float(parameters[f"injection.{key}"])
    controller = dict(config.controller)
    if parameters["controller.current_limit_A"] > 0.0:
        controller["current_limit_A"] = float(parameters["controller.current_limit_A"])
    if parameters["controller.speed_limit_rad_s"] != math.inf:
        controller["speed_limit_rad_s"] = parameters["controller.speed_limit_rad_s"]
    config = dataclasses.replace(config, injection=injection, controller=controller, **changes)
    if isinstance(config, Scenario) and parameters["shaft_held"]:
        return shaft_held(config, config.duration_s)
    return config


def run_samples(config, parameters):
    """The samples a node runs: its scenario's, else (a DriveConfig alone) the ``duration_s`` parameter's,
    else until stopped (sys.maxsize)."""
    if isinstance(config, Scenario) or parameters["duration_s"] <= 0.0:
        return config.n_samples
    return int(round(parameters["duration_s"] / config.T_s))
