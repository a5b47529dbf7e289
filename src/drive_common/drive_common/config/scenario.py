"""Scenario files (YAML): motor (a shipped name, a motor file or the file's mapping), estimator, speed and
load time tables, duration, sampling period
and non-idealities. Every error names the file and the key at fault in one line.

A scenario holds two parts: the drive's (DRIVE_KEYS: what the estimator, controller and bridge nodes
read) and the experiment's (the rest: the simulated plant's and the runner's). The drive's part may live
in a drive configuration file of its own (``drive: FILE`` in a scenario; the nodes' ``drive_configuration``
parameter), which a drive on a robot runs with and no scenario (docs/ros-graph.md)."""
import dataclasses
import math
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from drive_common.contract.errors import DriveError
from drive_common.contract.settings import (
    FORMAT_VERSION_KEY,
    Key,
    read_format_version,
    read_keys,
    refuse_unknown_keys,
    shown,
)
from drive_common.motor.commissioning import NAMEPLATE_ONLY
from drive_common.motor.motor_file import Motor, MotorFileError, load_motor, motor_from_mapping

SCENARIO_DIR = Path(__file__).parent / "scenarios"
NON_IDEALITIES = ("saturation", "dead_time", "delay", "sensor_noise", "sensor_offset_gain", "adc")
TOP_KEYS = {"description", "motor", "estimator", "injection", "duration_s", "sampling_period_s", "mode",
            "speed", "load", "non_idealities", "initial", "controller", "protection", "metrics", "seed", "substeps",
            "plant_deviation", "commissioning", "brake", "torque_feedforward", "block_samples", "answer_periods",
            "drive", FORMAT_VERSION_KEY}
DRIVE_KEYS = ("motor", "estimator", "injection", "commissioning", "controller", "protection", "sampling_period_s",
              "block_samples", "answer_periods")
"""The drive's part of a scenario, and all a drive configuration file holds (with ``description`` and
``format_version``)."""
DRIVE_FORMAT_VERSION = 1
"""The drive configuration file format this drive writes and reads (docs/ros-graph.md)."""
NO_DEVIATION = {"R_s": 1.0, "L_d": 1.0, "L_q": 1.0, "psi_f": 1.0, "J": 1.0, "friction": 1.0,
                "sensor_gain_a": 1.0, "sensor_gain_b": 1.0, "sensor_gain_c": 1.0,
                "sensor_offset_a": 0.0, "sensor_offset_b": 0.0, "sensor_offset_c": 0.0, "dead_time": 1.0}
"""``plant_deviation`` keys and their neutral values: factors on the preset's R_s, the flux map's L_d, L_q
and ψ_f, the inertia J, the friction, each current sensor's gain and the dead time; sensor offsets
[A] added to the preset's. The plant alone deviates; the drive still knows only the nameplate."""
RPM = 2.0 * math.pi / 60.0
BRAKE_RELEASE_S = 0.02
"""A holding brake's default lift time after the drive allows torque (small spring-applied servo brakes
take 10-60 ms)."""
MAX_FILE_BYTES = 1 << 20
MAX_SAMPLES = 10_000_000
"""A run's log holds 200 bytes per sample: 10 M samples are 2 GB."""
MAX_TABLE_POINTS = 10_000
MAX_SUBSTEPS = 100
MAX_BLOCK_SAMPLES = 100
DRIVE_VALUE_KEYS = (
    Key("sampling_period_s", "s", 1e-6, 1e-2, low_inclusive=True),
    Key("block_samples", "samples", 1, MAX_BLOCK_SAMPLES, low_inclusive=True, integer=True, default=1),
    Key("answer_periods", "periods", 0, MAX_BLOCK_SAMPLES + 1, low_inclusive=True, integer=True, default=0,
        doc="0: the inverter's own delay"),
)
"""The drive's numbers in a scenario or drive configuration, declared once (drive_common.contract.settings.Key)."""
SAMPLING_PERIOD = DRIVE_VALUE_KEYS[0]
INJECTION_KEYS = (
    Key("frequency_Hz", "Hz", 0.0, default=None),
    Key("amplitude_V", "V", 0.0, default=None),
)
"""``injection:`` of a scenario or drive configuration (unset: the estimator's own)."""


class ScenarioError(DriveError):
    """A scenario is unusable; the message names its source (file, command line, parameter) and key."""


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


@dataclass(frozen=True)
class Scenario:
    name: str
    source: str
    description: str
    motor: Motor
    """The motor file (drive_common.motor.motor_file): nameplate and inverter for the drive, plant for the simulator."""
    estimator: str
    estimator_settings: dict
    injection: dict
    """frequency_Hz and amplitude_V of the HF injection, for whichever injecting estimator runs."""
    duration_s: float
    T_s: float
    mode: str
    speed: Table
    """Mechanical speed [rad/s]: the reference, and in imposed_speed mode also the shaft speed."""
    load: Table
    """External load torque [N·m]."""
    non_idealities: dict
    initial_theta_m_rad: float
    """The rotor's true angle at t = 0 [rad, mechanical]; the drive is not told it (θ̂ starts at 0)."""
    initial_omega_m_rad_s: float
    controller: dict
    settle_s: float
    metrics_start_s: float
    seed: int
    substeps: int
    plant_deviation: dict
    """NO_DEVIATION's keys: how the simulated plant differs from its preset (the drive is not told)."""
    commissioning: str = ""
    """The commissioning file the drive loads (a path, resolved against the scenario file's folder), or
    'nameplate'; empty: the default (drive_common.motor.commissioning.resolve_commissioning)."""
    estimator_source: str = ""
    """Where the estimator's name came from (the file's key, or an override's command-line option or
    parameter), for errors that blame it."""
    brake: bool = False
    """A holding brake holds the shaft at rest (load or not) until ``brake_release_s`` after the drive
    first allows torque (estimator state 3), then releases for good."""
    brake_release_s: float = 0.0
    """How long the brake takes to lift once the drive allows torque (a spring-applied brake's armature:
    tens of ms)."""
    block_samples: int = 1
    """N: the per-sample data travel in blocks of N samples, so the command answering sample k acts N − 1
    periods later than with one message per sample (docs/architecture.md "Block transport")."""
    answer_periods: int = 0
    """Periods the host has from a block's last sample to the first of its commands acting (0: the
    inverter's own delay, 1; a paced inverter with blocks wants N + 1, docs/architecture.md)."""
    torque_feedforward: Table = None
    """The torque the robot expects the motor to deliver [N·m] (its gravity model), sent to the drive's
    `torque_feedforward`; None: none."""
    drive_file: str = ""
    """The drive configuration file the drive's part came from ("": the scenario file itself)."""
    from_drive_file: tuple = ()
    """The keys the drive configuration file (``drive: FILE``) gave."""
    protection: dict = dataclasses.field(default_factory=dict)
    """The drive's protection figures (foc_controller.protection.SETTINGS; unset: their defaults)."""

    def source_of(self, key):
        """The file that gave the top-level ``key``: the drive configuration file, or the scenario's source."""
        return self.drive_file if key in self.from_drive_file else self.source

    @property
    def open_ended(self):
        """A drive configuration without an experiment: it runs until stopped (no duration, no tables)."""
        return not math.isfinite(self.duration_s)

    @property
    def n_samples(self):
        return sys.maxsize if self.open_ended else int(round(self.duration_s / self.T_s))

    def schedule(self):
        """(ω*_m [rad/s], τ_load [N·m]) per sample k, arrays of n_samples."""
        t = np.arange(self.n_samples) * self.T_s
        return self.speed.sample(t).astype(float), self.load.sample(t).astype(float)

    def feedforward(self):
        """τ_ff [N·m] per sample k, an array of n_samples (zeros without a torque_feedforward table)."""
        if self.torque_feedforward is None:
            return np.zeros(self.n_samples)
        return self.torque_feedforward.sample(np.arange(self.n_samples) * self.T_s).astype(float)

    def answer_delay_periods(self):
        """Periods from a block's last sample to its first command acting: ``answer_periods``, else the
        inverter's own delay."""
        return self.answer_periods or self.motor.inverter.delay_periods

    def drive_delay_periods(self):
        """The drive's delay d from sample to applied command [periods]: the answer delay (none when the
        scenario turns the delay off), plus N − 1 with blocks of N samples."""
        answer = self.answer_delay_periods() if self.non_idealities["delay"] else 0
        return answer + self.block_samples - 1

    def events_s(self):
        """Instants where a table changes (transient starts), sorted."""
        events = set()
        for table in (self.speed, self.load):
            for i in range(1, len(table.times_s)):
                if table.values[i] != table.values[i - 1] or table.interpolation == "linear":
                    events.add(table.times_s[i])
        return sorted(e for e in events if 0.0 < e < self.duration_s)


def shaft_held(scenario, duration_s):
    """``scenario`` with its shaft held at the initial angle (imposed zero speed, no load: a brake) for
    ``duration_s``, one sample per message: the plant of a commissioning run."""
    still = Table((0.0,), (0.0,), "step")
    return dataclasses.replace(scenario, mode="imposed_speed", speed=still, load=still, initial_omega_m_rad_s=0.0,
                               duration_s=duration_s, brake=False, block_samples=1, answer_periods=0)


PACED_BLOCK_SAMPLES = 10
"""Samples per frame of a virtual inverter on its own clock when none are asked for: one frame per
sample cannot keep 10 kHz in Python, blocks of 10 can (docs/results.md "The paced inverter")."""


def link_block_samples(paced, requested):
    """N for a run behind the virtual inverter: ``requested`` (None: not asked), else PACED_BLOCK_SAMPLES
    when paced, else None (the scenario's)."""
    if requested is not None:
        return requested
    return PACED_BLOCK_SAMPLES if paced else None


def behind_an_inverter(scenario, max_block_samples):
    """``scenario`` as it runs behind the inverter bridge; ScenarioError naming the key of what cannot:
    a holding brake (an inverter does not see the drive's state, which releases the brake), blocks of
    more than the protocol's ``max_block_samples``, and with blocks of N samples an
    ``answer_periods`` other than N + 1 (the protocol applies a COMMAND_BLOCK during the block after
    next, docs/inverter-protocol.md), which is set when left to the inverter."""
    if scenario.brake:
        raise ScenarioError(f"{scenario.source}: brake: the virtual inverter has no holding brake; run the "
                            f"scenario with `drive run`, or `drive launch` without --link")
    n = scenario.block_samples
    if n > max_block_samples:
        raise ScenarioError(f"{scenario.source}: block_samples: {n}: the inverter protocol carries at most "
                            f"{max_block_samples} samples per block")
    if n > 1 and scenario.answer_periods not in (0, n + 1):
        raise ScenarioError(f"{scenario.source}: answer_periods: {scenario.answer_periods}: an inverter "
                            f"with blocks of {n} applies a block's commands from the block after next, "
                            f"{n + 1} periods after its last sample; use {n + 1} (or leave it out)")
    return dataclasses.replace(scenario, answer_periods=n + 1) if n > 1 else scenario


def scenario_names():
    return sorted(p.stem for p in SCENARIO_DIR.glob("*.yaml"))


def resolve(name_or_path):
    """A shipped scenario by name, or a YAML file by path."""
    path = Path(name_or_path)
    if path.suffix in (".yaml", ".yml") or path.exists():
        if not path.is_file():
            raise ScenarioError(f"{name_or_path}: no such scenario file")
        return path
    shipped = SCENARIO_DIR / f"{name_or_path}.yaml"
    if not shipped.is_file():
        raise ScenarioError(f"{name_or_path}: unknown scenario (shipped: {', '.join(scenario_names())})")
    return shipped


def _read_yaml(path, what):
    """The YAML document of ``path``; ScenarioError names the file."""
    try:
        if path.stat().st_size > MAX_FILE_BYTES:
            raise ScenarioError(f"{path}: larger than {MAX_FILE_BYTES} bytes; not a {what}")
        return yaml.safe_load(path.read_text(encoding="utf-8"))
    except OSError as error:
        raise ScenarioError(f"{path}: cannot be read ({error.strerror})") from None
    except UnicodeDecodeError:
        raise ScenarioError(f"{path}: not UTF-8 text") from None
    except yaml.YAMLError as error:
        raise ScenarioError(f"{path}: not valid YAML ({str(error).splitlines()[0]})") from None
    except RecursionError:
        raise ScenarioError(f"{path}: nested too deeply to be a {what}") from None


def load_scenario(name_or_path, estimator_override=None, override_source="estimator override", motor_override=None,
                  motor_source="motor override"):
    """The scenario of a shipped name or a YAML path; ``estimator_override`` replaces its estimator
    (``override_source`` names where it came from: "command line --estimator", "parameter estimator"), and
    ``motor_override`` (a shipped motor or a motor file, from ``motor_source``) its motor."""
    path = resolve(name_or_path)
    return parse_scenario(_read_yaml(path, "scenario file"), path.stem, str(path), estimator_override,
                          override_source, motor_override, motor_source)


def load_drive_configuration(path, label="drive configuration", estimator_override=None,
                             override_source="estimator override", motor_override=None, motor_source="motor override"):
    """The drive alone, from a drive configuration file (DRIVE_KEYS): a Scenario with no experiment
    (open-ended, no speed or load table). ScenarioError names ``label`` (where the file was named), the
    file and the key; overrides as for load_scenario."""
    file = Path(path)
    if not file.is_file():
        raise ScenarioError(f"{label}: {path}: no such drive configuration file")
    try:
        return parse_scenario(_read_yaml(file, "drive configuration"), file.stem, str(file), estimator_override,
                              override_source, motor_override, motor_source, drive_only=True)
    except ScenarioError as error:
        raise ScenarioError(f"{label}: {error}") from None


def with_drive(scenario, drive):
    """``scenario``'s experiment run by the drive of ``drive`` (a Scenario, e.g. load_drive_configuration's)."""
    return dataclasses.replace(
        scenario, motor=drive.motor, estimator=drive.estimator, estimator_settings=drive.estimator_settings,
        estimator_source=drive.estimator_source, injection=drive.injection, commissioning=drive.commissioning,
        controller=drive.controller, protection=drive.protection, T_s=drive.T_s, block_samples=drive.block_samples,
        answer_periods=drive.answer_periods, drive_file=drive.drive_file,
        from_drive_file=DRIVE_KEYS if drive.drive_file else ())


def _drive_format(data, source):
    """ScenarioError unless the format version the document of ``source`` states (or leaves out) for its
    drive part is one this drive reads (read_format_version)."""
    try:
        read_format_version(data, DRIVE_FORMAT_VERSION, "drive configuration", source)
    except ValueError as error:
        raise ScenarioError(f"{source}: {error}") from None


def _refuse_experiment_keys(data, fail, source):
    """``fail`` on the first key of a drive configuration's document that is not a drive key, or on its
    format version (_drive_format)."""
    _drive_format(data, source)
    for key in sorted(set(data) & TOP_KEYS - set(DRIVE_KEYS) - {"description", FORMAT_VERSION_KEY}, key=str):
        fail(key, f"not a drive key (a drive configuration holds {', '.join(DRIVE_KEYS)}; the experiment "
                  f"belongs to a scenario)")
    _refuse_unknown_keys(data, DRIVE_KEYS + ("description", FORMAT_VERSION_KEY), fail)


def _refuse_unknown_keys(data, known, fail):
    """``fail`` on the first key of ``data`` not in ``known``, naming the nearest known one (a typo)."""
    try:
        refuse_unknown_keys(data, known)
    except ValueError as error:
        key, problem = str(error).split(": ", 1)
        fail(key, problem)


def _drive_part(data, source, fail):
    """A scenario's ``drive: FILE``: the file's drive keys in the scenario's place (relative paths in it
    taken from its own folder), and the file's path."""
    spec = data["drive"]
    if not isinstance(spec, str) or not spec:
        fail("drive", f"must be the path of a drive configuration file, not {shown(spec)}")
    file = Path(spec)
    if not file.is_absolute() and source.endswith((".yaml", ".yml")):
        file = Path(source).parent / file
    if not file.is_file():
        fail("drive", f"{spec}: no such drive configuration file")
    drive = _read_yaml(file, "drive configuration")
    if not isinstance(drive, dict):
        raise ScenarioError(f"{file}: top level must be a mapping of keys")

    def fail_in_drive(key, problem):
        raise ScenarioError(f"{file}: {key}: {problem}")
    _refuse_experiment_keys(drive, fail_in_drive, str(file))
    for key in sorted(set(drive) & set(data) - {"description", FORMAT_VERSION_KEY}, key=str):
        fail(key, f"given here and in the drive configuration {file}: one place only")
    for key in ("motor", "commissioning"):
        value = drive.get(key)
        if isinstance(value, str) and not Path(value).is_absolute() and (file.parent / value).is_file():
            drive[key] = str(file.parent / value)
    given = {k: v for k, v in drive.items() if k not in ("description", FORMAT_VERSION_KEY)}
    merged = {**given, **data}
    del merged["drive"]
    return merged, str(file.resolve()), set(given)


def parse_scenario(data, name, source, estimator_override=None, override_source="estimator override",
                   motor_override=None, motor_source="motor override", drive_only=False):
    """A Scenario from a scenario file's document (or, ``drive_only``, a drive configuration's: DRIVE_KEYS
    and no experiment); ScenarioError names ``source`` and the key, or the drive configuration file
    (``drive: FILE``) a drive key came from."""
    origin = {}

    def fail(key, problem):
        raise ScenarioError(f"{origin.get(key.split('.')[0], source)}: {key}: {problem}")

    if not isinstance(data, dict):
        raise ScenarioError(f"{source}: top level must be a mapping of keys")
    drive_file = source if drive_only else ""
    if drive_only:
        _refuse_experiment_keys(data, fail, source)
    else:
        _refuse_unknown_keys(data, tuple(sorted(TOP_KEYS)), fail)
        if FORMAT_VERSION_KEY in data:
            _drive_format(data, source)
        data = {key: value for key, value in data.items() if key != FORMAT_VERSION_KEY}
        if "drive" in data:
            data, drive_file, from_drive = _drive_part(data, source, fail)
            origin.update({key: drive_file for key in from_drive})
    required = ("motor", "estimator", "sampling_period_s") if drive_only else \
        ("motor", "estimator", "duration_s", "sampling_period_s", "speed")
    for key in required:
        if key not in data:
            if drive_file and key in DRIVE_KEYS:
                origin[key] = drive_file
            fail(key, "missing")

    for key in ("initial", "metrics", "controller", "protection", "injection", "non_idealities"):
        if data.get(key) is not None and not isinstance(data[key], dict):
            fail(key, "must be a mapping of keys")
    motor = _motor(motor_override or data["motor"], motor_source if motor_override else
                   f"{origin.get('motor', source)}: motor", origin.get("motor", source), from_file=not motor_override)

    estimator_spec = data["estimator"]
    if isinstance(estimator_spec, str):
        estimator, settings = estimator_spec, {}
    elif isinstance(estimator_spec, dict) and isinstance(estimator_spec.get("type"), str):
        estimator = estimator_spec["type"]
        if not isinstance(estimator_spec.get("settings") or {}, dict):
            fail("estimator.settings", "must be a mapping of settings")
        settings = dict(estimator_spec.get("settings") or {})
        for key in sorted(set(estimator_spec) - {"type", "settings"}, key=str):
            fail(f"estimator.{key}", "unknown key (known: type, settings)")
    else:
        fail("estimator", "must be a name or a mapping with 'type' (and optional 'settings')")
    estimator_source = f"{origin.get('estimator', source)}: estimator"
    if estimator_override:
        estimator, settings = estimator_override, (settings if estimator_override == estimator else {})
        estimator_source = override_source

    injection = data.get("injection", {}) or {}
    if not isinstance(injection, dict):
        fail("injection", "must be a mapping with frequency_Hz and amplitude_V")
    drive_values = _drive_values(data, injection, fail)
    injection = {key: drive_values[f"injection.{key}"] for key in injection}

    duration = math.inf if drive_only else _positive(data["duration_s"], "duration_s", fail)
    T_s = drive_values["sampling_period_s"]
    if not drive_only and T_s > duration:
        fail("sampling_period_s", f"{T_s} s is longer than duration_s {duration} s")
    if not drive_only and duration / T_s > MAX_SAMPLES:
        fail("duration_s", f"{shown(duration)} s at {T_s:g} s per sample is more than {MAX_SAMPLES} samples")
    mode = data.get("mode", "speed_control")
    if not isinstance(mode, str) or mode not in ("speed_control", "imposed_speed"):
        fail("mode", f"must be 'speed_control' or 'imposed_speed', not '{mode}'")

    speed = _table(data.get("speed", {"unit": "rad_s", "points": [[0.0, 0.0]]}), "speed", {"rpm": RPM, "rad_s": 1.0},
                   fail, duration)
    torque_units = {"Nm": 1.0, "rated": motor.nameplate.rated_torque_Nm}
    load = _table(data.get("load", {"unit": "Nm", "points": [[0.0, 0.0]]}), "load", torque_units, fail, duration)
    feedforward = data.get("torque_feedforward")
    if feedforward is not None:
        feedforward = _table(feedforward, "torque_feedforward", torque_units, fail, duration)

    non_idealities = {key: True for key in NON_IDEALITIES}
    given = data.get("non_idealities", {}) or {}
    if not isinstance(given, dict):
        fail("non_idealities", "must be a mapping of on/off flags")
    for key, value in given.items():
        if key not in NON_IDEALITIES:
            fail(f"non_idealities.{key}", f"unknown (known: {', '.join(NON_IDEALITIES)})")
        if not isinstance(value, bool):
            fail(f"non_idealities.{key}", f"must be true or false, not {shown(value)}")
        non_idealities[key] = value

    initial = data.get("initial", {}) or {}
    if "angle_error_e_rad" in initial:
        fail("initial.angle_error_e_rad", "no longer a scenario key: the estimator is told nothing of the angle "
                                          "and finds it itself; set the rotor's angle with initial.theta_m_rad")
    for key in sorted(set(initial) - {"theta_m_rad", "omega_m_rpm"}, key=str):
        fail(f"initial.{key}", "unknown key (known: theta_m_rad, omega_m_rpm)")
    brake = data.get("brake", False)
    brake_release = BRAKE_RELEASE_S if brake is True else 0.0
    if isinstance(brake, dict):
        for key in sorted(set(brake) - {"release_s"}, key=str):
            fail(f"brake.{key}", "unknown key (known: release_s)")
        brake_release = _nonnegative(brake.get("release_s", BRAKE_RELEASE_S), "brake.release_s", fail)
        brake = True
    if not isinstance(brake, bool):
        fail("brake", f"must be true, false or {{release_s: SECONDS}}, not {shown(brake)}")
    metrics = data.get("metrics", {}) or {}
    for key in sorted(set(metrics) - {"settle_s", "start_s"}, key=str):
        fail(f"metrics.{key}", "unknown key (known: settle_s, start_s)")
    settle = _nonnegative(metrics.get("settle_s", 0.3), "metrics.settle_s", fail)
    start = _nonnegative(metrics.get("start_s", settle if settle < duration else 0.0), "metrics.start_s", fail)
    if start >= duration:
        fail("metrics.start_s", f"{shown(start)} s is not before the end of the run ({shown(duration)} s)")
    substeps = data.get("substeps", 1)
    if isinstance(substeps, bool) or not isinstance(substeps, int) or not 1 <= substeps <= MAX_SUBSTEPS:
        fail("substeps", f"must be a whole number from 1 to {MAX_SUBSTEPS}, not {shown(substeps)}")
    block_samples, answer_periods = drive_values["block_samples"], drive_values["answer_periods"]
    seed = data.get("seed", 1)
    if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed < 2 ** 63:
        fail("seed", f"must be a whole number from 0 to 2⁶³ − 1, not {shown(seed)}")
    description = data.get("description", "")
    if not isinstance(description, str):
        fail("description", f"must be text, not {shown(description)}")
    controller = data.get("controller", {}) or {}
    if not isinstance(controller, dict):
        fail("controller", "must be a mapping of controller settings")
    protection = dict(data.get("protection", {}) or {})
    deviation = data.get("plant_deviation", {}) or {}
    if not isinstance(deviation, dict):
        fail("plant_deviation", "must be a mapping of factors and sensor offsets")
    for key in sorted(set(deviation) - set(NO_DEVIATION), key=str):
        fail(f"plant_deviation.{key}", f"unknown key (known: {', '.join(NO_DEVIATION)})")
    deviation = {key: (_number(value, f"plant_deviation.{key}", fail) if key.startswith("sensor_offset")
                       else _factor(value, f"plant_deviation.{key}", fail)) for key, value in deviation.items()}
    commissioning = data.get("commissioning", "")
    if not isinstance(commissioning, str):
        fail("commissioning", f"must be a file path or '{NAMEPLATE_ONLY}', not {shown(commissioning)}")
    commissioning_source = origin.get("commissioning", source)
    if commissioning and commissioning != NAMEPLATE_ONLY and commissioning_source.endswith((".yaml", ".yml")):
        commissioning = str(Path(commissioning_source).parent / commissioning)

    return Scenario(
        name=name, source=source, description=description, motor=motor,
        estimator=estimator, estimator_settings=settings, injection=injection, duration_s=duration,
        T_s=T_s, mode=mode, speed=speed, load=load, non_idealities=non_idealities,
        initial_theta_m_rad=_number(initial.get("theta_m_rad", 0.0), "initial.theta_m_rad", fail),
        initial_omega_m_rad_s=RPM * _number(initial.get("omega_m_rpm", 0.0), "initial.omega_m_rpm", fail),
        controller=controller, protection=protection, settle_s=settle, metrics_start_s=start,
        seed=seed, substeps=substeps, plant_deviation={**NO_DEVIATION, **deviation},
        commissioning=commissioning, estimator_source=estimator_source, brake=brake, brake_release_s=brake_release,
        torque_feedforward=feedforward, block_samples=block_samples, answer_periods=answer_periods,
        drive_file=drive_file, from_drive_file=tuple(sorted(origin)))


def _drive_values(data, injection, fail):
    """The drive's numbers of a scenario or drive configuration, read through DRIVE_VALUE_KEYS: {key:
    value}, the injection's as ``injection.KEY`` (None where not given)."""
    try:
        values = read_keys({key: data[key] for key in ("sampling_period_s", "block_samples", "answer_periods")
                            if key in data}, DRIVE_VALUE_KEYS)
        values.update({f"injection.{key}": value
                       for key, value in read_keys(injection, INJECTION_KEYS, "injection.").items()})
    except ValueError as error:
        key, problem = str(error).split(": ", 1)
        fail(key, problem)
    return values


def _motor(spec, label, scenario_source, from_file):
    """The Motor a scenario's ``motor`` key (or an override) names: a shipped motor, a motor file (a path
    relative to the scenario file's folder) or, in the file, the motor file's mapping itself."""
    try:
        if isinstance(spec, dict) and from_file:
            return motor_from_mapping(spec, label, default_name="motor")
        if not isinstance(spec, str):
            raise ScenarioError(f"{label}: must be a shipped motor's name, a motor file or its mapping, "
                                f"not {shown(spec)}")
        if from_file and scenario_source.endswith((".yaml", ".yml")) and not Path(spec).is_absolute():
            beside = Path(scenario_source).parent / spec
            if beside.is_file():
                spec = str(beside)
        return load_motor(spec, label)
    except MotorFileError as error:
        raise ScenarioError(str(error)) from None


def _number(value, key, fail):
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        fail(key, f"must be a finite number, not {shown(value)}")
    return float(value)


def _positive(value, key, fail):
    value = _number(value, key, fail)
    if value <= 0.0:
        fail(key, f"must be positive, not {value}")
    return value


def _factor(value, key, fail):
    value = _positive(value, key, fail)
    if not 0.1 <= value <= 10.0:
        fail(key, f"a factor must lie in [0.1, 10], not {shown(value)}")
    return value


def _nonnegative(value, key, fail):
    value = _number(value, key, fail)
    if value < 0.0:
        fail(key, f"must not be negative, not {value}")
    return value


def _table(spec, key, units, fail, duration):
    if not isinstance(spec, dict):
        fail(key, "must be a mapping with unit, points and optional interpolation")
    for extra in sorted(set(spec) - {"unit", "points", "interpolation"}, key=str):
        fail(f"{key}.{extra}", "unknown key (known: unit, points, interpolation)")
    unit = spec.get("unit")
    if not isinstance(unit, str) or unit not in units:
        fail(f"{key}.unit", f"must be one of {', '.join(units)}, not {shown(unit)}")
    interpolation = spec.get("interpolation", "step")
    if not isinstance(interpolation, str) or interpolation not in ("step", "linear"):
        fail(f"{key}.interpolation", f"must be 'step' or 'linear', not {shown(interpolation)}")
    points = spec.get("points")
    if not isinstance(points, list) or not points:
        fail(f"{key}.points", "missing or empty: give [[time_s, value], ...]")
    if len(points) > MAX_TABLE_POINTS:
        fail(f"{key}.points", f"{len(points)} points; at most {MAX_TABLE_POINTS}")
    times, values = [], []
    for i, point in enumerate(points):
        if not isinstance(point, (list, tuple)) or len(point) != 2:
            fail(f"{key}.points[{i}]", f"must be [time_s, value], not {shown(point)}")
        t = _nonnegative(point[0], f"{key}.points[{i}] time", fail)
        if times and t < times[-1]:
            fail(f"{key}.points[{i}]", f"time {t} s goes backwards")
        if t > duration:
            fail(f"{key}.points[{i}]", f"time {t} s is after duration_s {duration} s")
        times.append(t)
        values.append(units[unit] * _number(point[1], f"{key}.points[{i}] value", fail))
    return Table(tuple(times), tuple(values), interpolation)
