"""Motor files: a motor as its user describes it (YAML, docs/motors-and-control.md "Motor files").

A motor file holds the nameplate (the contract's drive_config ``motor`` keys), the inverter that drives it
(DC-link voltage and computation delay) and, for a simulation only, a ``plant:`` section with the
simulated motor's truth (read by ``pmsm_plant.presets.plant_truth``, never by the drive). The shipped
motors are such files (``motors/``); every command and node that takes a motor name also takes a path.
"""
import math
from dataclasses import dataclass, field
from pathlib import Path

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

from .nameplate import InverterRating, Nameplate, NameplateError, nameplate_from_mapping

MOTOR_DIR = Path(__file__).parent / "motors"
MAX_FILE_BYTES = 1 << 20
TOP_KEYS = (FORMAT_VERSION_KEY, "name", "description", "nameplate", "inverter", "plant")
FORMAT_VERSION = 1
"""The motor file format this drive writes and reads (docs/motors-and-control.md "Motor files")."""
INVERTER_KEYS = (
    Key("U_dc_V", "V", 0.0, 1e5, doc="the DC-link voltage"),
    Key("delay_periods", "periods", 0, 2, low_inclusive=True, integer=True, default=1),
    Key("current_rating_A", "A", 0.0, 1e4, default=math.inf, infinite=True,
        doc="the inverter's peak phase current; the current limit stays within it"),
    Key("C_dc_F", "F", 0.0, 10.0, default=math.inf, infinite=True, doc="the DC-link capacitance (∞: a stiff bus)"),
    Key("R_brake_ohm", "Ω", 0.0, 1e6, default=math.inf, infinite=True, doc="the brake chopper's resistor (∞: none)"),
    Key("U_brake_on_V", "V", 0.0, 1e5, default=math.inf, infinite=True),
    Key("U_brake_off_V", "V", 0.0, 1e5, default=math.inf, infinite=True),
    Key("U_overvoltage_V", "V", 0.0, 1e5, default=math.inf, infinite=True,
        doc="the bus at which the drive trips (∞: foc_controller.protection's default)"),
)
"""The inverter section's keys, declared once (drive_common.contract.settings.Key; docs/protections.md)."""


BUS_PER_RATED_SPEED_NEED = 20.0
"""A motor file's DC-link voltage may be at most this many times what the motor's back-EMF at rated speed
needs (``rated_speed_bus_V``): more is another motor's bus, or a unit slip, and would drive this one far
beyond its rating at the first fault of the current loop."""


def rated_speed_bus_V(plate):
    """The DC-link voltage [V] the back-EMF at rated speed needs with space-vector modulation: √3·ω_e·ψ_f."""
    return math.sqrt(3.0) * plate.rated_speed_rpm * math.pi / 30.0 * plate.n_p * plate.psi_f_Wb


class MotorFileError(DriveError):
    """A motor file is unusable; the message names its source (option, parameter, scenario key), the file
    and the key."""


@dataclass(frozen=True)
class Motor:
    """A motor as the drive is told it (nameplate, inverter) and, for a simulation, the plant's truth."""

    name: str
    nameplate: Nameplate
    inverter: InverterRating
    plant: dict = field(default_factory=dict)
    """The file's ``plant:`` section as written (pmsm_plant.presets.plant_truth reads it); {} when absent."""
    source: str = ""
    """The file it was read from."""
    description: str = ""
    given_by: str = "motor"
    """Where the drive was told of it ("--motor", "parameter motor_file", "SCENARIO: motor"): errors found
    later (the plant section, pmsm_plant.presets.plant_truth) name it."""

    def __str__(self):
        return self.name

    @property
    def shipped(self):
        """The motor is one of the shipped files (motors/)."""
        return bool(self.source) and Path(self.source).parent == MOTOR_DIR


def shipped_motor_names():
    """The names of the shipped motor files."""
    return sorted(p.stem for p in MOTOR_DIR.glob("*.yaml"))


def motor_path(name_or_path):
    """The shipped motor file called ``name_or_path``, else that path; None when neither exists."""
    shipped = MOTOR_DIR / f"{name_or_path}.yaml"
    if "/" not in str(name_or_path) and shipped.is_file():
        return shipped
    path = Path(name_or_path)
    return path if path.is_file() else None


def load_motor(name_or_path, source="motor"):
    """The Motor of a shipped name or a motor file's path; MotorFileError names ``source`` (where the name
    came from: "--motor", "parameter motor_file", "SCENARIO: motor"), the file and the key."""
    if isinstance(name_or_path, Motor):
        return name_or_path
    path = motor_path(name_or_path)
    if path is None:
        raise MotorFileError(f"{source}: {shown(name_or_path)} is neither a shipped motor "
                             f"({', '.join(shipped_motor_names())}) nor a motor file")
    try:
        if path.stat().st_size > MAX_FILE_BYTES:
            raise MotorFileError(f"{source}: {path}: larger than {MAX_FILE_BYTES} bytes; not a motor file")
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
    except OSError as error:
        raise MotorFileError(f"{source}: {path}: cannot be read ({error.strerror})") from None
    except (UnicodeDecodeError, yaml.YAMLError, RecursionError) as error:
        raise MotorFileError(f"{source}: {path}: not a YAML motor file ({str(error).splitlines()[0]})") from None
    return motor_from_mapping(data, f"{source}: {path}", default_name=path.stem, path=str(path), given_by=source,
                              whole_file=True)


def motor_from_mapping(data, source, default_name="motor", path="", given_by=None, whole_file=False):
    """A Motor from a motor file's document (TOP_KEYS); MotorFileError names ``source`` and the key.
    ``given_by``: where the drive was told of it (default: ``source``). A ``whole_file`` says its format
    version (read_format_version); a mapping inside a scenario is of the scenario's format."""
    def fail(key, problem):
        raise MotorFileError(f"{source}: {key}: {problem}")

    if not isinstance(data, dict):
        raise MotorFileError(f"{source}: a motor file is a mapping of keys ({', '.join(TOP_KEYS)})")
    try:
        refuse_unknown_keys(data, TOP_KEYS)
        if whole_file or FORMAT_VERSION_KEY in data:
            read_format_version(data, FORMAT_VERSION, "motor file", source)
    except ValueError as error:
        raise MotorFileError(f"{source}: {error}") from None
    for key in ("nameplate", "inverter"):
        if not isinstance(data.get(key), dict):
            fail(key, "missing, or not a mapping of keys (`drive motor template` shows one)")
    name = data.get("name", default_name)
    if not isinstance(name, str) or not name or "/" in name or not name.isprintable() or len(name) > 100:
        fail("name", f"must be a word (it names the default commissioning file), not {shown(name)}")
    plate_data = dict(data["nameplate"])
    try:
        refuse_unknown_keys(plate_data, Nameplate._fields[1:], "nameplate.")
        plate = nameplate_from_mapping({**plate_data, "name": name}, source, key_prefix="nameplate.")
        inverter = InverterRating(**read_keys(data["inverter"], INVERTER_KEYS, "inverter."))
    except NameplateError as error:
        raise MotorFileError(str(error)) from None
    except ValueError as error:
        raise MotorFileError(f"{source}: {error}") from None
    needed = rated_speed_bus_V(plate)
    if inverter.U_dc_V > BUS_PER_RATED_SPEED_NEED * needed:
        fail("inverter.U_dc_V", f"{inverter.U_dc_V:g} V is more than {BUS_PER_RATED_SPEED_NEED:g} × the {needed:.3g} V "
                                f"the rated speed needs (√3·ω_e·ψ_f): not this motor's bus")
    if plate.current_limit_A > inverter.current_rating_A:
        fail("nameplate.current_limit_A", f"{plate.current_limit_A:g} A is more than the inverter's rating "
                                          f"(inverter.current_rating_A {inverter.current_rating_A:g} A)")
    if inverter.U_brake_off_V > inverter.U_brake_on_V:
        fail("inverter.U_brake_off_V", "must not exceed U_brake_on_V (the chopper's hysteresis)")
    for key in ("U_brake_off_V", "U_overvoltage_V"):
        level = getattr(inverter, key)
        if level <= inverter.U_dc_V:
            fail(f"inverter.{key}", f"{level:g} V must exceed the supply's U_dc_V {inverter.U_dc_V:g} V (a chopper "
                                    f"below it drains the supply; a trip below it trips at rest)")
    plant = data.get("plant") or {}
    if not isinstance(plant, dict):
        fail("plant", "must be a mapping of the simulated motor's truth")
    description = data.get("description", "")
    if not isinstance(description, str):
        fail("description", f"must be text, not {shown(description)}")
    return Motor(name, plate, inverter, plant, path or source, description,
                 source if given_by is None else given_by)


def nameplate(name_or_path):
    """The nameplate of a shipped motor or a motor file; MotorFileError names the known ones."""
    return load_motor(name_or_path).nameplate


def recorded_nameplate(data, source):
    """The Nameplate of a recording's motor description (nameplate_from_mapping): a shipped motor of the
    same name gives the optional values the description leaves out."""
    name = data.get("name") if isinstance(data, dict) else None
    shipped = nameplate(name) if isinstance(name, str) and name in shipped_motor_names() else None
    return nameplate_from_mapping(data, source, defaults=shipped)


def load_nameplate(preset_or_file, source):
    """The nameplate of a shipped motor or a motor file (drive_common.motor.motor_file), or one read from a
    YAML/JSON file of the contract's motor keys (nameplate_from_mapping); NameplateError names ``source``
    (e.g. "--motor") and the file or key."""
    path = motor_path(preset_or_file)
    if path is None:
        raise NameplateError(f"{source}: {shown(preset_or_file)} is neither a shipped motor "
                             f"({', '.join(shipped_motor_names())}) nor a file")
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as error:
        raise NameplateError(f"{source}: {path}: not a readable YAML/JSON motor description "
                             f"({str(error).splitlines()[0]})") from None
    if isinstance(data, dict) and isinstance(data.get("nameplate"), dict):
        return load_motor(path, source).nameplate
    if isinstance(data, dict) and isinstance(data.get("motor"), dict):
        data = data["motor"]
    return recorded_nameplate(data, f"{source}: {path}")


TEMPLATE = """\
# A motor file (docs/motors-and-control.md "Motor files"). SI units in every key.
# Use it wherever a motor is named: `drive run SCENARIO --motor my_motor.yaml`, `drive commission`,
# `drive bench startup --motor`, `drive tune`, replay's --motor, and the nodes' `motor_file` parameter.
format_version: 1         # the motor file format this file is written in
name: my_motor            # names the default commissioning file, commissioning/my_motor.yaml
description: "A 24 V robot-joint PMSM"

nameplate:                # what the datasheet says (the drive is told these, nothing else)
  n_p: 7                  # pole pairs
  R_s_ohm: 0.5            # phase resistance (line-to-line / 2)
  L_d_H: 0.00040          # d-axis inductance (for a surface-magnet motor L_d ≈ L_q)
  L_q_H: 0.00046
  psi_f_Wb: 0.0055        # magnet flux linkage, amplitude-invariant: k_t / (1.5 n_p) [V·s]
  rated_current_A: 6.0    # peak phase current at rated torque
  # optional (defaults in brackets):
  rated_speed_rpm: 2000.0 # [3000]
  rated_torque_Nm: 0.35   # [1.5 n_p psi_f rated_current]
  current_limit_A: 9.0    # [1.5 x rated_current]
  J_kgm2: 6.0e-5          # rotor and load inertia [unknown: `drive commission` measures it]
  B_Nms: 1.0e-5           # viscous friction [unknown]

inverter:
  U_dc_V: 24.0            # DC-link voltage
  delay_periods: 1        # [1] periods from sampling to the command acting
  current_rating_A: 20.0  # [not stated] the inverter's peak phase current: the current limit stays within it

# Optional, simulation only: the simulated motor's truth (the drive never reads it).
# plant:
#   R_s_ohm: 0.5            # [nameplate]   true resistance, magnet flux, mechanics
#   psi_f_Wb: 0.0055        # [nameplate]
#   J_kgm2: 6.0e-5          # [nameplate; required when the nameplate has none]
#   B_Nms: 1.0e-5           # [nameplate, else 0]
#   L_d_H: 0.00042          # [nameplate]   unsaturated (geometric) inductances
#   L_q_H: 0.00048          # [nameplate]
#   L_dh_H: 0.00038         # [L_d_H]       incremental d inductance at no load (the magnet saturates the d iron)
#   L_dh_drop_at_rated: 0.1 # [none]        or: L_dh falls by this at rated magnetising d current (sets L_d_H)
#   L_qh_H: 0.00046         # [L_q_H]       incremental q inductance at no load (cross-saturation below L_q_H)
#   L_qh_drop_at_rated: 0.05 # [0]          L_qh falls by this at rated q current (q self-saturation)
#   t_dead_s: 5.0e-7        # [0.5 µs]      inverter dead time; i_dead_A its commutation current [0.05]
#   sensor: {noise_std_A: 0.01, adc_bits: 12, adc_range_A: 20.0}  # [1e-3 x range noise, 12 bits, 2 x limit]
"""
"""What `drive motor template` prints: a commented motor file."""
