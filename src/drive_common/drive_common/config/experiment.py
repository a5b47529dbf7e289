"""What a simulation adds to a drive (EXPERIMENT_KEYS): the speed, load and feed-forward tables, the run's
length, the rotor's initial state, the non-idealities, the plant's deviation from its preset, a holding
brake, the metrics' window, the noise seed and the plant's substeps. The drive is told none of it. Every
number and flag is read through its declared Key (drive_common.contract.settings)."""
import math
from dataclasses import dataclass, fields

import numpy as np

from drive_common.contract.settings import Key, number, read_keys, read_or_fail, shown

NON_IDEALITIES = ("saturation", "dead_time", "delay", "sensor_noise", "sensor_offset_gain", "adc")
RPM = 2.0 * math.pi / 60.0
BRAKE_RELEASE_S = 0.02
"""A holding brake's default lift time after the drive allows torque (small spring-applied servo brakes
take 10-60 ms)."""
MAX_SAMPLES = 10_000_000
"""A run's log holds 200 bytes per sample: 10 M samples are 2 GB."""
MAX_TABLE_POINTS = 10_000
MAX_SUBSTEPS = 100
MODES = ("speed_control", "imposed_speed")
EXPERIMENT_KEYS = ("duration_s", "mode", "speed", "load", "torque_feedforward", "non_idealities", "initial",
                   "metrics", "seed", "substeps", "plant_deviation", "brake", "end_stop")
"""An experiment's keys in a scenario file (beside the drive's, drive_config.DRIVE_KEYS)."""
EXPERIMENT_VALUE_KEYS = (
    Key("duration_s", "s", 0.0),
    Key("mode", "", choices=MODES, default="speed_control"),
    Key("seed", "", 0, 2 ** 63 - 1, low_inclusive=True, integer=True, default=1),
    Key("substeps", "", 1, MAX_SUBSTEPS, low_inclusive=True, integer=True, default=1),
)
"""The experiment's top-level numbers and words."""
INITIAL_KEYS = (Key("theta_m_rad", "rad", default=0.0), Key("omega_m_rpm", "rpm", default=0.0))
"""``initial:``: the rotor's true angle and speed at t = 0 (the drive is not told them)."""
METRICS_KEYS = (Key("settle_s", "s", 0.0, low_inclusive=True, default=0.3),
                Key("start_s", "s", 0.0, low_inclusive=True, default=None, doc="default: settle_s"))
"""``metrics:``: the settling time after a transient, and where the metrics start."""
BRAKE_KEYS = (Key("release_s", "s", 0.0, low_inclusive=True, default=BRAKE_RELEASE_S),)
"""``brake:`` as a mapping (else true or false)."""
END_STOP_KEYS = (
    Key("low_rad", "rad", default=None, nullable=True, doc="the shaft cannot turn below this angle (null: no stop)"),
    Key("high_rad", "rad", default=None, nullable=True, doc="the shaft cannot turn above this angle (null: no stop)"),
    Key("stiffness_Nm_rad", "N·m/rad", 0.0, None, default=None, nullable=True,
        doc="the stop's spring (null: stiff as the simulation's step allows, pmsm_plant.build)"),
    Key("damping_Nms_rad", "N·m·s/rad", 0.0, None, low_inclusive=True, default=None, nullable=True,
        doc="the stop's damper (null: critical with the shaft's inertia)"),
)
"""``end_stop:``: a mechanical hard stop on the shaft (the simulation's truth: a robot joint's end of travel), a
spring-damper acting beyond ``low_rad`` or ``high_rad`` [rad, mechanical, the plant's angle]."""
NON_IDEALITY_KEYS = tuple(Key(name, "", choices=(True, False), default=True) for name in NON_IDEALITIES)
"""``non_idealities:``: each on (the default) or off."""
DEVIATION_KEYS = (
    *(Key(name, "", 0.1, 10.0, low_inclusive=True, default=1.0)
      for name in ("R_s", "L_d", "L_q", "psi_f", "J", "friction", "sensor_gain_a", "sensor_gain_b", "sensor_gain_c")),
    *(Key(f"sensor_offset_{x}", "A", default=0.0) for x in "abc"),
    Key("dead_time", "", 0.1, 10.0, low_inclusive=True, default=1.0),
)
"""``plant_deviation:``: factors on the preset's R_s, the flux map's L_d, L_q and ψ_f, the inertia J, the
friction, each current sensor's gain and the dead time; sensor offsets [A] added to the preset's. The plant
alone deviates; the drive still knows only the nameplate."""
NO_DEVIATION = {key.name: key.default for key in DEVIATION_KEYS}
"""``plant_deviation`` keys and their neutral values."""
TABLE_POINTS = "points"


@dataclass(frozen=True)
class Table:
    """A time table [[t_s, value], ...] in SI units, held ('step') or interpolated ('linear')."""

    times_s: tuple
    values: tuple
    interpolation: str

    def sample(self, t):
        times = np.asarray(self.times_s)
        values = np.asarray(self.values)
        if self.interpolation == "linear":
            return np.interp(t, times, values)
        index = np.searchsorted(times, t, side="right") - 1
        return values[np.clip(index, 0, len(values) - 1)]


@dataclass(frozen=True, kw_only=True)
class Experiment:
    """What a simulation adds to the drive: the plant's schedule, its state, its truth and the run."""

    duration_s: float
    mode: str
    speed: Table
    """Mechanical speed [rad/s]: the reference, and in imposed_speed mode also the shaft speed."""
    load: Table
    """External load torque [N·m]."""
    non_idealities: dict
    initial_theta_m_rad: float
    """The rotor's true angle at t = 0 [rad, mechanical]; the drive is not told it (θ̂ starts at 0)."""
    initial_omega_m_rad_s: float
    settle_s: float
    metrics_start_s: float
    seed: int
    substeps: int
    plant_deviation: dict
    """NO_DEVIATION's keys: how the simulated plant differs from its preset (the drive is not told)."""
    brake: bool = False
    """A holding brake holds the shaft at rest (load or not) until ``brake_release_s`` after the drive
    first allows torque (estimator state 3), then releases for good."""
    brake_release_s: float = 0.0
    """How long the brake takes to lift once the drive allows torque (a spring-applied brake's armature:
    tens of ms)."""
    torque_feedforward: Table = None
    """The torque the robot expects the motor to deliver [N·m] (its gravity model), sent to the drive's
    `torque_feedforward`; None: none."""
    end_stop: dict = None
    """END_STOP_KEYS: the shaft's mechanical end stops (None: it turns freely)."""

    def events_s(self):
        """Instants where a table changes (transient starts), sorted."""
        events = set()
        for table in (self.speed, self.load):
            for i in range(1, len(table.times_s)):
                if table.values[i] != table.values[i - 1] or table.interpolation == "linear":
                    events.add(table.times_s[i])
        return sorted(e for e in events if 0.0 < e < self.duration_s)


EXPERIMENT_FIELDS = tuple(f.name for f in fields(Experiment))


def read_experiment(data, T_s, rated_torque_Nm, fail):
    """The Experiment of a scenario document's experiment keys (``data``: duration_s and speed present),
    run at ``T_s`` [s] by a motor of ``rated_torque_Nm`` (the load tables' unit 'rated'); ``fail(key,
    problem)`` raises naming the file and the key."""
    values = read_or_fail(fail, read_keys, {key.name: data[key.name] for key in EXPERIMENT_VALUE_KEYS
                                            if key.name in data}, EXPERIMENT_VALUE_KEYS)
    duration = values["duration_s"]
    if T_s > duration:
        fail("sampling_period_s", f"{T_s} s is longer than duration_s {duration} s")
    if duration / T_s > MAX_SAMPLES:
        fail("duration_s", f"{shown(duration)} s at {T_s:g} s per sample is more than {MAX_SAMPLES} samples")
    speed = _table(data["speed"], "speed", {"rpm": RPM, "rad_s": 1.0}, fail, duration)
    torque_units = {"Nm": 1.0, "rated": rated_torque_Nm}
    load = _table(data.get("load", {"unit": "Nm", TABLE_POINTS: [[0.0, 0.0]]}), "load", torque_units, fail, duration)
    feedforward = data.get("torque_feedforward")
    if feedforward is not None:
        feedforward = _table(feedforward, "torque_feedforward", torque_units, fail, duration)
    non_idealities = _section(data, "non_idealities", NON_IDEALITY_KEYS, fail)
    initial = data.get("initial") or {}
    if isinstance(initial, dict) and "angle_error_e_rad" in initial:
        fail("initial.angle_error_e_rad", "no longer a scenario key: the estimator is told nothing of the angle "
                                          "and finds it itself; set the rotor's angle with initial.theta_m_rad")
    initial = _section(data, "initial", INITIAL_KEYS, fail)
    brake, brake_release = data.get("brake", False), 0.0
    if isinstance(brake, dict):
        brake_release, brake = _section(data, "brake", BRAKE_KEYS, fail)["release_s"], True
    elif isinstance(brake, bool):
        brake_release = BRAKE_RELEASE_S if brake else 0.0
    else:
        fail("brake", f"must be true, false or {{release_s: SECONDS}}, not {shown(brake)}")
    metrics = _section(data, "metrics", METRICS_KEYS, fail)
    settle = metrics["settle_s"]
    start = metrics["start_s"] if metrics["start_s"] is not None else (settle if settle < duration else 0.0)
    if start >= duration:
        fail("metrics.start_s", f"{shown(start)} s is not before the end of the run ({shown(duration)} s)")
    return Experiment(
        duration_s=duration, mode=values["mode"], speed=speed, load=load, non_idealities=non_idealities,
        initial_theta_m_rad=initial["theta_m_rad"], initial_omega_m_rad_s=RPM * initial["omega_m_rpm"],
        settle_s=settle, metrics_start_s=start, seed=values["seed"], substeps=values["substeps"],
        plant_deviation=_section(data, "plant_deviation", DEVIATION_KEYS, fail), brake=brake,
        brake_release_s=brake_release, torque_feedforward=feedforward, end_stop=_end_stop(data, fail))



def _end_stop(data, fail):
    """The ``end_stop:`` section (END_STOP_KEYS), or None where there is none."""
    if data.get("end_stop") is None:
        return None
    stop = _section(data, "end_stop", END_STOP_KEYS, fail)
    if stop["low_rad"] is None and stop["high_rad"] is None:
        fail("end_stop", "give low_rad, high_rad or both")
    if None not in (stop["low_rad"], stop["high_rad"]) and stop["low_rad"] >= stop["high_rad"]:
        fail("end_stop.high_rad", f"{shown(stop['high_rad'])} is not above low_rad {shown(stop['low_rad'])}")
    return stop


def _section(data, key, keys, fail):
    """The mapping ``data[key]`` (absent or null: empty) read through ``keys``."""
    return read_or_fail(fail, read_keys, data.get(key) or {}, keys, f"{key}.")


def _table(spec, key, units, fail, duration):
    """A Table of ``spec`` ({unit, points, interpolation}); ``units``: {unit: its SI factor}."""
    declared = (Key("unit", "", choices=tuple(units)), Key("interpolation", "", choices=("step", "linear"),
                                                           default="step"))
    given = read_or_fail(fail, read_keys, spec, declared, f"{key}.", known_extra=(TABLE_POINTS,))
    points = spec.get(TABLE_POINTS)
    if not isinstance(points, list) or not points:
        fail(f"{key}.points", "missing or empty: give [[time_s, value], ...]")
    if len(points) > MAX_TABLE_POINTS:
        fail(f"{key}.points", f"{len(points)} points; at most {MAX_TABLE_POINTS}")
    times, values = [], []
    for i, point in enumerate(points):
        if not isinstance(point, (list, tuple)) or len(point) != 2:
            fail(f"{key}.points[{i}]", f"must be [time_s, value], not {shown(point)}")
        t = read_or_fail(fail, number, f"{key}.points[{i}] time", point[0], 0.0, low_inclusive=True)
        if times and t < times[-1]:
            fail(f"{key}.points[{i}]", f"time {t} s goes backwards")
        if t > duration:
            fail(f"{key}.points[{i}]", f"time {t} s is after duration_s {duration} s")
        times.append(t)
        values.append(units[given["unit"]] * read_or_fail(fail, number, f"{key}.points[{i}] value", point[1]))
    return Table(tuple(times), tuple(values), given["interpolation"])
