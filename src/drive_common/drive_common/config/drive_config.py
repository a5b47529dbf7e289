"""What a drive reads (DRIVE_KEYS), as a robot's drive runs it with no experiment: the motor, the estimator
with its settings and injection, the commissioning record, the controller's settings, the protections, the
sampling period and the block transport. A drive configuration file holds these alone; a scenario holds
them too, or names such a file (``drive: FILE``). Every number is read through its declared Key
(drive_common.contract.settings); errors name the file and the key in one line."""
import sys
from dataclasses import dataclass, field, fields
from pathlib import Path

import yaml

from drive_common.contract.errors import DriveError
from drive_common.contract.settings import Key, read_keys, read_or_fail, refuse_unknown_keys, shown
from drive_common.motor.commissioning import NAMEPLATE_ONLY
from drive_common.motor.motor_file import Motor, MotorFileError, load_motor, motor_from_mapping

DRIVE_KEYS = ("motor", "estimator", "injection", "commissioning", "controller", "protection", "sampling_period_s",
              "block_samples", "answer_periods")
"""The drive's keys, all a drive configuration file holds (with ``description`` and ``format_version``)."""
DRIVE_FORMAT_VERSION = 1
"""The drive configuration file format this drive writes and reads (docs/ros-graph.md)."""
MAX_FILE_BYTES = 1 << 20
MAX_BLOCK_SAMPLES = 100
DRIVE_VALUE_KEYS = (
    Key("sampling_period_s", "s", 1e-6, 1e-2, low_inclusive=True),
    Key("block_samples", "samples", 1, MAX_BLOCK_SAMPLES, low_inclusive=True, integer=True, default=1),
    Key("answer_periods", "periods", 0, MAX_BLOCK_SAMPLES + 1, low_inclusive=True, integer=True, default=0,
        doc="0: the inverter's own delay"),
)
"""The drive's numbers, declared once (drive_common.contract.settings.Key)."""
SAMPLING_PERIOD = DRIVE_VALUE_KEYS[0]
INJECTION_KEYS = (
    Key("frequency_Hz", "Hz", 0.0, default=None),
    Key("amplitude_V", "V", 0.0, default=None),
)
"""``injection:`` of a scenario or drive configuration (unset: the estimator's own)."""
ESTIMATOR_KEYS = ("type", "settings")
"""``estimator:`` as a mapping (else the estimator's name alone)."""


class ScenarioError(DriveError):
    """A scenario or drive configuration is unusable; the message names its source (file, command line,
    parameter) and key."""


@dataclass(frozen=True, kw_only=True)
class DriveConfig:
    """The drive's part of a configuration (DRIVE_KEYS), all the estimator, controller and bridge nodes read.
    Alone (a drive configuration file) it runs until stopped."""

    name: str
    source: str
    """Where it was read from (a file, or a tool's name for a scenario it made)."""
    description: str = ""
    motor: Motor
    """The motor file (drive_common.motor.motor_file): nameplate and inverter for the drive, plant for the simulator."""
    estimator: str
    estimator_settings: dict
    injection: dict
    """frequency_Hz and amplitude_V of the HF injection, for whichever injecting estimator runs."""
    T_s: float
    controller: dict
    protection: dict = field(default_factory=dict)
    """The drive's protection figures (foc_controller.protection.SETTINGS; unset: their defaults)."""
    commissioning: str = ""
    """The commissioning file the drive loads (a path, resolved against its file's folder), or
    'nameplate'; empty: the default (drive_common.motor.commissioning.resolve_commissioning)."""
    estimator_source: str = ""
    """Where the estimator's name came from (the file's key, or an override's command-line option or
    parameter), for errors that blame it."""
    block_samples: int = 1
    """N: the per-sample data travel in blocks of N samples, so the command answering sample k acts N − 1
    periods later than with one message per sample (docs/architecture.md "Block transport")."""
    answer_periods: int = 0
    """Periods the host has from a block's last sample to the first of its commands acting (0: the
    inverter's own delay, 1; a paced inverter with blocks wants N + 1, docs/architecture.md)."""
    drive_file: str = ""
    """The drive configuration file the drive's part came from ("": a scenario file itself)."""
    from_drive_file: tuple = ()
    """The keys the drive configuration file (a scenario's ``drive: FILE``) gave."""
    written_for: str = ""
    """The motor the file's injection and loops were written for, where an override put another motor in its
    place ("": the file's own motor runs)."""

    def source_of(self, key):
        """The file that gave the top-level ``key``: the drive configuration file, or the source."""
        return self.drive_file if key in self.from_drive_file else self.source

    @property
    def open_ended(self):
        """A drive without an experiment runs until stopped."""
        return True

    @property
    def n_samples(self):
        return sys.maxsize

    def answer_delay_periods(self):
        """Periods from a block's last sample to its first command acting: ``answer_periods``, else the
        inverter's own delay."""
        return self.answer_periods or self.motor.inverter.delay_periods

    def drive_delay_periods(self):
        """The drive's delay d from sample to applied command [periods]: the answer delay, plus N − 1 with
        blocks of N samples."""
        return self.answer_delay_periods() + self.block_samples - 1


DRIVE_FIELDS = tuple(f.name for f in fields(DriveConfig))


def read_yaml(path, what):
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


def read_drive(data, name, source, drive_file, origin, fail, overrides):
    """The DriveConfig of a document's drive keys (``data``: the required ones present); ``drive_file``: the
    drive configuration file it came from ("": a scenario file), ``origin``: {key: the drive configuration
    file that gave it where not ``source``}; ``fail(key, problem)`` raises naming the file and key.
    ``overrides``: {estimator_override, override_source, motor_override, motor_source} as
    scenario.load_scenario takes them."""
    estimator_override, motor_override = overrides["estimator_override"], overrides["motor_override"]
    motor = _motor(motor_override or data["motor"], overrides["motor_source"] if motor_override else
                   f"{origin.get('motor', source)}: motor", origin.get("motor", source), from_file=not motor_override)
    written_for = ""
    if motor_override:
        try:
            own = _motor(data["motor"], f"{origin.get('motor', source)}: motor", origin.get("motor", source), True)
            written_for = own.name if own.name != motor.name else ""
        except ScenarioError:
            written_for = str(data["motor"])
    estimator, settings = _estimator(data["estimator"], fail)
    estimator_source = f"{origin.get('estimator', source)}: estimator"
    if estimator_override:
        estimator, settings = estimator_override, (settings if estimator_override == estimator else {})
        estimator_source = overrides["override_source"]
    injection = data.get("injection") or {}
    values = read_or_fail(fail, read_keys, {key.name: data[key.name] for key in DRIVE_VALUE_KEYS if key.name in data},
                          DRIVE_VALUE_KEYS)
    given = read_or_fail(fail, read_keys, injection, INJECTION_KEYS, "injection.")
    for key in ("controller", "protection"):
        if not isinstance(data.get(key) or {}, dict):
            fail(key, "must be a mapping of keys")
    commissioning = data.get("commissioning", "")
    if not isinstance(commissioning, str):
        fail("commissioning", f"must be a file path or '{NAMEPLATE_ONLY}', not {shown(commissioning)}")
    commissioning_source = origin.get("commissioning", source)
    if commissioning and commissioning != NAMEPLATE_ONLY and commissioning_source.endswith((".yaml", ".yml")):
        commissioning = str(Path(commissioning_source).parent / commissioning)
    description = data.get("description", "")
    if not isinstance(description, str):
        fail("description", f"must be text, not {shown(description)}")
    return DriveConfig(
        name=name, source=source, description=description, motor=motor, estimator=estimator,
        estimator_settings=settings, injection={key: given[key] for key in injection}, T_s=values["sampling_period_s"],
        controller=data.get("controller") or {}, protection=dict(data.get("protection") or {}),
        commissioning=commissioning, estimator_source=estimator_source, block_samples=values["block_samples"],
        answer_periods=values["answer_periods"], drive_file=drive_file, from_drive_file=tuple(sorted(origin)),
        written_for=written_for)



def _estimator(spec, fail):
    """(name, settings) of an ``estimator:`` key: a name, or a mapping with ``type`` and ``settings``."""
    if isinstance(spec, str):
        return spec, {}
    if not isinstance(spec, dict) or not isinstance(spec.get("type"), str):
        fail("estimator", "must be a name or a mapping with 'type' (and optional 'settings')")
    if not isinstance(spec.get("settings") or {}, dict):
        fail("estimator.settings", "must be a mapping of settings")
    read_or_fail(fail, refuse_unknown_keys, spec, ESTIMATOR_KEYS, "estimator.")
    return spec["type"], dict(spec.get("settings") or {})


def _motor(spec, label, file_source, from_file):
    """The Motor a ``motor`` key (or an override) names: a shipped motor, a motor file (a path relative
    to the configuration file's folder) or, in the file, the motor file's mapping itself."""
    try:
        if isinstance(spec, dict) and from_file:
            return motor_from_mapping(spec, label, default_name="motor")
        if not isinstance(spec, str):
            raise ScenarioError(f"{label}: must be a shipped motor's name, a motor file or its mapping, "
                                f"not {shown(spec)}")
        if from_file and file_source.endswith((".yaml", ".yml")) and not Path(spec).is_absolute():
            beside = Path(file_source).parent / spec
            if beside.is_file():
                spec = str(beside)
        return load_motor(spec, label)
    except MotorFileError as error:
        raise ScenarioError(str(error)) from None
