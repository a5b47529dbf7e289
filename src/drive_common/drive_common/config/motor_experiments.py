"""A motor's own experiments (issue 51 item 2): scenarios made from a motor's rating, not a paper's motor,
run by ``drive run NAME --motor FILE`` and by ``drive bench motor(s)``. Speeds are in shares of the
motor's rated speed, loads in shares of its rated torque; the drive runs on the loops scaled to the
motor (drive_common.motor.scaled_loops: no injection, estimator loop or speed loop is set here), ours' sine carrier
or the square wave as the loops' rule chooses (the estimator setting injection_by_rule). Each is
DURATION_S long, the rotor starting at rest from an angle the drive is not told
(docs/motors-and-control.md "The motor's own experiments")."""
from typing import NamedTuple

LOW_SPEED_PER_RATED = 0.05
"""The experiments' low speed: 5 % of rated speed."""
DURATION_S = 1.2
SETTLE_S = 0.3
EXPERIMENTS = {
    "standstill_hold": ("hold the shaft at zero speed, no load",
                        {"speed": [[0.0, 0.0], [DURATION_S, 0.0]], "load": [[0.0, 0.0]]}),
    "low_speed": ("5 % rated speed, no load",
                  {"speed": [[0.0, 0.0], [0.1, 1.0], [DURATION_S, 1.0]], "load": [[0.0, 0.0]]}),
    "rated_load": ("5 % rated speed, rated load ramped in over 0.3-0.4 s",
                   {"speed": [[0.0, 0.0], [0.1, 1.0], [DURATION_S, 1.0]],
                    "load": [[0.0, 0.0], [0.3, 0.0], [0.4, 1.0], [DURATION_S, 1.0]], "load_interpolation": "linear"}),
    "speed_step": ("5 % rated speed, a step to 10 % at 0.6 s, no load",
                   {"speed": [[0.0, 0.0], [0.1, 1.0], [0.6, 1.0], [0.6, 2.0], [DURATION_S, 2.0]],
                    "load": [[0.0, 0.0]]}),
    "reversal": ("+5 % rated speed, reversed to −5 % over 0.5-0.7 s, no load",
                 {"speed": [[0.0, 0.0], [0.1, 1.0], [0.5, 1.0], [0.7, -1.0], [DURATION_S, -1.0]],
                  "load": [[0.0, 0.0]]}),
}
"""name: (what it does, its tables: speed in units of LOW_SPEED_PER_RATED × rated speed, load per
``ExperimentOptions.load_per_rated`` × rated torque)."""


class ExperimentOptions(NamedTuple):
    """How an experiment runs: the sampling period [s], the rotor's initial electrical angle [rad], the
    sensor-noise seed, the load's top per rated torque (1: rated; below 1 for a drive that states a lower
    torque limit), and the commissioning file ("": the default lookup)."""

    T_s: float = 1e-4
    theta_e_rad: float = 1.0
    seed: int = 1
    load_per_rated: float = 1.0
    commissioning: str = ""
    unit_rpm: float = 0.0
    """The tables' speed unit [rpm] (0: LOW_SPEED_PER_RATED × rated speed)."""
    time_scale: float = 1.0
    """The tables' times stretched by this (a start the motor can follow: an I-f ramp)."""
    estimator: str = "injection_frame"


def experiment_names():
    """The motor's own experiments, in the order a bench runs them."""
    return list(EXPERIMENTS)


def describe_experiment(name):
    """One line: what experiment ``name`` does."""
    return EXPERIMENTS[name][0]


def _estimator(name):
    """A scenario's estimator key for the experiments' estimator ``name``: ours with the loops' rule choosing its
    injection (hf_estimator.build.chosen_estimator), any other as it is."""
    if name == "injection_frame":
        return {"type": "injection_frame", "settings": {"injection_by_rule": True}}
    return name


def experiment_document(name, motor, options=None):
    """The scenario document (a scenario file's keys, drive_common.config.scenario.parse_scenario reads it)
    of experiment ``name`` on ``motor`` (a drive_common.motor.motor_file.Motor read from a file)."""
    description, tables = EXPERIMENTS[name]
    options = options or ExperimentOptions()
    plate = motor.nameplate
    unit_rpm = options.unit_rpm or LOW_SPEED_PER_RATED * plate.rated_speed_rpm
    scale = options.time_scale
    data = {"description": f"{description} ({motor.name}: the motor's own experiment)",
            "motor": motor.source, "estimator": _estimator(options.estimator), "duration_s": DURATION_S * scale,
            "sampling_period_s": options.T_s, "seed": options.seed,
            "initial": {"theta_m_rad": options.theta_e_rad / plate.n_p}, "metrics": {"settle_s": SETTLE_S * scale},
            "speed": {"unit": "rpm", "interpolation": "linear",
                      "points": [[t * scale, v * unit_rpm] for t, v in tables["speed"]]},
            "load": {"unit": "rated", "interpolation": tables.get("load_interpolation", "step"),
                     "points": [[t * scale, v * options.load_per_rated] for t, v in tables["load"]]}}
    if options.commissioning:
        data["commissioning"] = options.commissioning
    return data
