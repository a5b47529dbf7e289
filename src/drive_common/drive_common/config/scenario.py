"""Scenario files (YAML): a drive (drive_config.DriveConfig: motor, estimator, sampling period, ...) and an
experiment (experiment.Experiment: speed and load tables, duration, initial state, non-idealities, ...).
Every error names the file and the key at fault in one line.

The drive's part may live in a drive configuration file of its own (``drive: FILE`` in a scenario; the
nodes' ``drive_configuration`` parameter), which a drive on a robot runs with and no scenario
(docs/ros-graph.md)."""
import dataclasses
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from drive_common.contract.settings import FORMAT_VERSION_KEY, read_format_version, refuse_unknown_keys, shown
from drive_common.motor.motor_file import MotorFileError, load_motor

from .drive_config import (
    DRIVE_FIELDS,
    DRIVE_FORMAT_VERSION,
    DRIVE_KEYS,
    DriveConfig,
    ScenarioError,
    read_drive,
    read_yaml,
)
from .experiment import (
    EXPERIMENT_FIELDS,
    EXPERIMENT_KEYS,
    Experiment,
    Table,
    read_experiment,
)
from .motor_experiments import EXPERIMENTS, ExperimentOptions, describe_experiment, experiment_document

SCENARIO_DIR = Path(__file__).parent / "scenarios"
TOP_KEYS = (*DRIVE_KEYS, *EXPERIMENT_KEYS, "description", "drive", FORMAT_VERSION_KEY)
"""A scenario file's keys: the drive's, the experiment's, its description, a drive configuration file
(``drive: FILE``) in place of the drive's keys, and the drive part's format version."""


@dataclass(frozen=True, kw_only=True)
class Scenario(DriveConfig, Experiment):
    """A drive and an experiment: what `drive run`, the runner and the simulated plant read."""

    @property
    def drive(self):
        """The DriveConfig alone (what the drive's nodes read)."""
        return DriveConfig(**{name: getattr(self, name) for name in DRIVE_FIELDS})

    @property
    def experiment(self):
        """The Experiment alone."""
        return Experiment(**{name: getattr(self, name) for name in EXPERIMENT_FIELDS})

    @classmethod
    def of(cls, drive, experiment):
        """The Scenario of a DriveConfig and an Experiment."""
        return cls(**{name: getattr(drive, name) for name in DRIVE_FIELDS},
                   **{name: getattr(experiment, name) for name in EXPERIMENT_FIELDS})

    @property
    def open_ended(self):
        """A scenario's run ends after its duration."""
        return False

    @property
    def n_samples(self):
        return int(round(self.duration_s / self.T_s))

    def schedule(self):
        """(ω*_m [rad/s], τ_load [N·m]) per sample k, arrays of n_samples."""
        t = np.arange(self.n_samples) * self.T_s
        return self.speed.sample(t).astype(float), self.load.sample(t).astype(float)

    def feedforward(self):
        """τ_ff [N·m] per sample k, an array of n_samples (zeros without a torque_feedforward table)."""
        if self.torque_feedforward is None:
            return np.zeros(self.n_samples)
        return self.torque_feedforward.sample(np.arange(self.n_samples) * self.T_s).astype(float)

    def drive_delay_periods(self):
        """The drive's delay d from sample to applied command [periods]: the answer delay (none when the
        scenario turns the delay off), plus N − 1 with blocks of N samples."""
        answer = self.answer_delay_periods() if self.non_idealities["delay"] else 0
        return answer + self.block_samples - 1


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
    more than the protocol's ``max_block_samples``, a run shorter than one block, and with blocks of N samples an
    ``answer_periods`` other than N + 1 (the protocol applies a COMMAND_BLOCK during the block after
    next, docs/inverter-protocol.md), which is set when left to the inverter."""
    if scenario.brake:
        raise ScenarioError(f"{scenario.source}: brake: the virtual inverter has no holding brake; run the "
                            f"scenario with `drive run`, or `drive launch` without --link")
    n = scenario.block_samples
    if n > max_block_samples:
        raise ScenarioError(f"{scenario.source}: block_samples: {n}: the inverter protocol carries at most "
                            f"{max_block_samples} samples per block")
    if scenario.n_samples < n:
        raise ScenarioError(f"{scenario.source}: duration_s: {scenario.duration_s:g} s is less than one block of {n} "
                            f"samples ({n * scenario.T_s:g} s): nothing to answer")
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


def load_scenario(name_or_path, estimator_override=None, override_source="estimator override", motor_override=None,
                  motor_source="motor override"):
    """The scenario of a shipped name or a YAML path; ``estimator_override`` replaces its estimator
    (``override_source`` names where it came from: "command line --estimator", "parameter estimator"), and
    ``motor_override`` (a shipped motor or a motor file, from ``motor_source``) its motor. The name of one
    of a motor's own experiments (motor_experiments) makes it from ``motor_override``'s rating."""
    if name_or_path in EXPERIMENTS and not Path(name_or_path).exists():
        return motor_experiment(name_or_path, motor_override, motor_source, estimator_override, override_source)
    path = resolve(name_or_path)
    return parse_scenario(read_yaml(path, "scenario file"), path.stem, str(path), estimator_override,
                          override_source, motor_override, motor_source)


def motor_experiment(name, motor, motor_source="--motor", estimator_override=None,
                     override_source="estimator override", options=None):
    """The Scenario of the motor's own experiment ``name`` on ``motor`` (a shipped name, a motor file or a
    Motor read from a file) with ``options`` (motor_experiments.ExperimentOptions); ScenarioError names
    ``motor_source`` where no motor is given."""
    if motor is None:
        raise ScenarioError(f"{name}: a motor's own experiment ({describe_experiment(name)}): give the motor "
                            f"({motor_source} NAME|FILE)")
    try:
        loaded = load_motor(motor, motor_source)
    except MotorFileError as error:
        raise ScenarioError(str(error)) from None
    return parse_scenario(experiment_document(name, loaded, options or ExperimentOptions()), name,
                          f"{name} on {loaded.name}", estimator_override, override_source, loaded.source, motor_source)


def load_drive_configuration(path, label="drive configuration", estimator_override=None,
                             override_source="estimator override", motor_override=None, motor_source="motor override"):
    """The DriveConfig of a drive configuration file (DRIVE_KEYS). ScenarioError names ``label`` (where the
    file was named), the file and the key; overrides as for load_scenario."""
    file = Path(path)
    if not file.is_file():
        raise ScenarioError(f"{label}: {path}: no such drive configuration file")
    source = str(file)

    def fail(key, problem):
        raise ScenarioError(f"{source}: {key}: {problem}")
    try:
        data = read_yaml(file, "drive configuration")
        if not isinstance(data, dict):
            raise ScenarioError(f"{source}: top level must be a mapping of keys")
        _refuse_experiment_keys(data, fail, source)
        for key in ("motor", "estimator", "sampling_period_s"):
            if key not in data:
                fail(key, "missing")
        return read_drive(data, file.stem, source, source, {}, fail, {
            "estimator_override": estimator_override, "override_source": override_source,
            "motor_override": motor_override, "motor_source": motor_source})
    except ScenarioError as error:
        raise ScenarioError(f"{label}: {error}") from None


def with_drive(scenario, drive):
    """``scenario``'s experiment run by the DriveConfig ``drive`` (e.g. load_drive_configuration's)."""
    return Scenario.of(dataclasses.replace(drive, name=scenario.name, source=scenario.source,
                                           description=scenario.description,
                                           from_drive_file=DRIVE_KEYS if drive.drive_file else ()),
                       scenario.experiment)


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
    for key in sorted(set(data) & {*EXPERIMENT_KEYS, "drive"}, key=str):
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
    drive = read_yaml(file, "drive configuration")
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
                   motor_override=None, motor_source="motor override"):
    """A Scenario from a scenario file's document: its DriveConfig (drive_config.read_drive) and its
    Experiment (experiment.read_experiment). ScenarioError names ``source`` and the key, or the drive
    configuration file (``drive: FILE``) a drive key came from."""
    origin = {}

    def fail(key, problem):
        raise ScenarioError(f"{origin.get(key.split('.')[0], source)}: {key}: {problem}")

    if not isinstance(data, dict):
        raise ScenarioError(f"{source}: top level must be a mapping of keys")
    _refuse_unknown_keys(data, tuple(sorted(TOP_KEYS)), fail)
    if FORMAT_VERSION_KEY in data:
        _drive_format(data, source)
    data = {key: value for key, value in data.items() if key != FORMAT_VERSION_KEY}
    drive_file = ""
    if "drive" in data:
        data, drive_file, from_drive = _drive_part(data, source, fail)
        origin.update({key: drive_file for key in from_drive})
    for key in ("motor", "estimator", "duration_s", "sampling_period_s", "speed"):
        if key not in data:
            if drive_file and key in DRIVE_KEYS:
                origin[key] = drive_file
            fail(key, "missing")
    drive = read_drive(data, name, source, drive_file, origin, fail, {
        "estimator_override": estimator_override, "override_source": override_source,
        "motor_override": motor_override, "motor_source": motor_source})
    return Scenario.of(drive, read_experiment(data, drive.T_s, drive.motor.nameplate.rated_torque_Nm, fail))
