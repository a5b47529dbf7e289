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

from drive_interface.errors import DriveError

from .nameplate import InverterRating, Nameplate, NameplateError, nameplate_from_mapping

MOTOR_DIR = Path(__file__).parent / "motors"
MAX_FILE_BYTES = 1 << 20
TOP_KEYS = ("name", "description", "nameplate", "inverter", "plant")
INVERTER_KEYS = ("U_dc_V", "delay_periods") + InverterRating._fields[2:]


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
        raise MotorFileError(f"{source}: {name_or_path!r} is neither a shipped motor "
                             f"({', '.join(shipped_motor_names())}) nor a motor file")
    try:
        if path.stat().st_size > MAX_FILE_BYTES:
            raise MotorFileError(f"{source}: {path}: larger than {MAX_FILE_BYTES} bytes; not a motor file")
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
    except OSError as error:
        raise MotorFileError(f"{source}: {path}: cannot be read ({error.strerror})") from None
    except (UnicodeDecodeError, yaml.YAMLError, RecursionError) as error:
        raise MotorFileError(f"{source}: {path}: not a YAML motor file ({str(error).splitlines()[0]})") from None
    return motor_from_mapping(data, f"{source}: {path}", default_name=path.stem, path=str(path), given_by=source)


def motor_from_mapping(data, source, default_name="motor", path="", given_by=None):
    """A Motor from a motor file's document (TOP_KEYS); MotorFileError names ``source`` and the key.
    ``given_by``: where the drive was told of it (default: ``source``)."""
    def fail(key, problem):
        raise MotorFileError(f"{source}: {key}: {problem}")

    if not isinstance(data, dict):
        raise MotorFileError(f"{source}: a motor file is a mapping of keys ({', '.join(TOP_KEYS)})")
    for key in sorted(set(data) - set(TOP_KEYS), key=str):
        fail(key, f"unknown key (known: {', '.join(TOP_KEYS)})")
    for key in ("nameplate", "inverter"):
        if not isinstance(data.get(key), dict):
            fail(key, "missing, or not a mapping of keys (`drive motor template` shows one)")
    name = data.get("name", default_name)
    if not isinstance(name, str) or not name or "/" in name or not name.isprintable() or len(name) > 100:
        fail("name", f"must be a word (it names the default commissioning file), not {name!r}")
    plate_data = dict(data["nameplate"])
    for key in sorted(set(plate_data) - set(Nameplate._fields[1:]), key=str):
        fail(f"nameplate.{key}", f"unknown key (known: {', '.join(Nameplate._fields[1:])})")
    try:
        plate = nameplate_from_mapping({**plate_data, "name": name}, source, key_prefix="nameplate.")
    except NameplateError as error:
        raise MotorFileError(str(error)) from None
    inverter = data["inverter"]
    for key in sorted(set(inverter) - set(INVERTER_KEYS), key=str):
        fail(f"inverter.{key}", f"unknown key (known: {', '.join(INVERTER_KEYS)})")
    U_dc = inverter.get("U_dc_V")
    if isinstance(U_dc, bool) or not isinstance(U_dc, (int, float)) or not math.isfinite(U_dc) or U_dc <= 0.0:
        fail("inverter.U_dc_V", f"the DC-link voltage must be a positive number [V], not {U_dc!r}")
    needed = rated_speed_bus_V(plate)
    if U_dc > BUS_PER_RATED_SPEED_NEED * needed:
        fail("inverter.U_dc_V", f"{U_dc:g} V is more than {BUS_PER_RATED_SPEED_NEED:g} × the {needed:.3g} V the "
                                f"rated speed needs (√3·ω_e·ψ_f): not this motor's bus")
    delay = inverter.get("delay_periods", 1)
    if isinstance(delay, bool) or not isinstance(delay, int) or not 0 <= delay <= 2:
        fail("inverter.delay_periods", f"must be 0, 1 or 2 (periods from sample to applied command), not {delay!r}")
    link = {key: inverter[key] for key in InverterRating._fields[2:] if key in inverter}
    for key, v in link.items():
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not v > 0.0:
            fail(f"inverter.{key}", f"must be a positive number (.inf: none), not {v!r}")
    if link.get("U_brake_off_V", 0.0) > link.get("U_brake_on_V", math.inf):
        fail("inverter.U_brake_off_V", "must not exceed U_brake_on_V (the chopper's hysteresis)")
    for key in ("U_brake_off_V", "U_overvoltage_V"):
        if link.get(key, math.inf) <= U_dc:
            fail(f"inverter.{key}", f"{link[key]:g} V must exceed the supply's U_dc_V {U_dc:g} V (a chopper below it "
                                    f"drains the supply; a trip below it trips at rest)")
    plant = data.get("plant") or {}
    if not isinstance(plant, dict):
        fail("plant", "must be a mapping of the simulated motor's truth")
    description = data.get("description", "")
    if not isinstance(description, str):
        fail("description", f"must be text, not {description!r}")
    rating = InverterRating(float(U_dc), delay, **{key: float(v) for key, v in link.items()})
    return Motor(name, plate, rating, plant, path or source, description, source if given_by is None else given_by)


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
    """The nameplate of a shipped motor or a motor file (motor_params.motor_file), or one read from a
    YAML/JSON file of the contract's motor keys (nameplate_from_mapping); NameplateError names ``source``
    (e.g. "--motor") and the file or key."""
    path = motor_path(preset_or_file)
    if path is None:
        raise NameplateError(f"{source}: {preset_or_file!r} is neither a shipped motor "
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
