"""The nameplate: what a robot builder tells the drive about the motor (datasheet values and estimates),
and the drive's own inverter rating. Estimators and the controller read these, never the plant."""
import math
from typing import NamedTuple

from drive_common.contract.settings import REQUIRED, Key, read_keys


class Nameplate(NamedTuple):
    """Motor data from the datasheet, linear model, SI units."""

    name: str
    n_p: int
    """Pole pairs."""
    R_s_ohm: float
    L_d_H: float
    L_q_H: float
    psi_f_Wb: float
    """Permanent-magnet flux linkage (amplitude-invariant scaling)."""
    rated_power_W: float
    rated_current_A: float
    """Peak phase current (amplitude-invariant), the current limit's basis."""
    rated_speed_rpm: float
    rated_torque_Nm: float
    current_limit_A: float
    J_kgm2: float
    """Inertia estimate of rotor and coupled load."""
    B_Nms: float
    """Viscous friction estimate."""


class InverterRating(NamedTuple):
    """The drive's own inverter as designed: the DC-link voltage and the computation delay."""

    U_dc_V: float
    delay_periods: int
    """1: a command computed from sample k is applied during period k+1."""
    current_rating_A: float = math.inf
    """The inverter's peak phase current (∞: not stated); a motor's current limit stays within it."""
    C_dc_F: float = math.inf
    """DC-link capacitance (∞: a stiff bus, a supply that also absorbs; docs/protections.md)."""
    R_brake_ohm: float = math.inf
    """Brake-chopper resistor (∞: none)."""
    U_brake_on_V: float = math.inf
    """The chopper switches on above this bus voltage ..."""
    U_brake_off_V: float = math.inf
    """... and off below this one."""
    U_overvoltage_V: float = math.inf
    """The bus voltage at which the drive trips to its safe state (∞: OVERVOLTAGE_PER_BUS × U_dc_V,
    foc_controller.protection)."""


TRIP_PER_CURRENT_LIMIT = 3.0
"""A phase current beyond this many times the nameplate's current limit is absurd input, not a current."""


def trip_current_A(plate):
    """The default trip current [A] of a motor with nameplate ``plate``."""
    return TRIP_PER_CURRENT_LIMIT * plate.current_limit_A


ASSUMED_RATED_SPEED_RPM = 3000.0
"""A motor description without ``rated_speed_rpm`` is taken to be rated at this speed (it only sets the
lock monitor's 2 % back-EMF margin)."""


NAMEPLATE_KEYS = (
    Key("n_p", "pole pairs", 1, 100, low_inclusive=True, integer=True),
    Key("R_s_ohm", "Ω", 0.0, 1e3, low_inclusive=True, doc="phase resistance"),
    Key("L_d_H", "H", 1e-8, 10.0, low_inclusive=True),
    Key("L_q_H", "H", 1e-8, 10.0, low_inclusive=True),
    Key("psi_f_Wb", "Wb", 1e-6, 100.0, low_inclusive=True),
    Key("rated_power_W", "W", 1e-3, 1e7, low_inclusive=True, default=None),
    Key("rated_current_A", "A", 1e-3, 1e4, low_inclusive=True),
    Key("rated_speed_rpm", "rpm", 1.0, 1e6, low_inclusive=True, default=None),
    Key("rated_torque_Nm", "N·m", 1e-7, 1e6, low_inclusive=True, default=None),
    Key("current_limit_A", "A", 1e-3, 1e4, low_inclusive=True, default=None),
    Key("J_kgm2", "kg·m²", 1e-10, 1e5, low_inclusive=True, default=None),
    Key("B_Nms", "N·m·s", 0.0, 1e4, low_inclusive=True, default=None),
)
"""Each nameplate key declared once (drive_common.contract.settings.Key): unit and physical range (a value
outside it is a typo or a unit slip), required or optional (None: nameplate_from_mapping's default).
Every reader of a nameplate reads it through these: motor files, drive configuration files, a bag's
drive_config."""
NAMEPLATE_REQUIRED = tuple(key.name for key in NAMEPLATE_KEYS if key.default is REQUIRED)
"""What a motor description must give (the contract's drive_config ``motor``); the rest of a Nameplate
defaults as nameplate_from_mapping says."""

CURRENT_LIMIT_PER_RATED = 3.0
"""The current limit may be at most this many times the rated current (a drive's peak rating; beyond it
the windings and the inverter are out of their rating)."""


class NameplateError(ValueError):
    """A motor description is unusable; the message names its source and the key."""


def nameplate_from_mapping(data, source, defaults=None, key_prefix=""):
    """A Nameplate from a motor description (the contract's drive_config ``motor``: the keys of
    NAMEPLATE_REQUIRED, optionally name and any other Nameplate field; unknown keys are ignored).
    Missing optional values: the Nameplate ``defaults``' where given; else current_limit_A 1.5 ×
    rated current, rated_torque_Nm 1.5·n_p·ψ_f·I_rated, rated_speed_rpm ASSUMED_RATED_SPEED_RPM,
    rated_power_W their product, J_kgm2 and B_Nms NaN (not known). NameplateError names ``source`` and
    the key (after ``key_prefix``, e.g. ``nameplate.`` in a motor file)."""
    if not isinstance(data, dict):
        raise NameplateError(f"{source}: a motor description is a mapping of keys, not {type(data).__name__}")
    missing = [key for key in NAMEPLATE_REQUIRED if key not in data]
    if missing:
        raise NameplateError(f"{source}: {', '.join(key_prefix + key for key in missing)}: missing (a motor needs "
                             f"{', '.join(NAMEPLATE_REQUIRED)})")
    known = {key.name for key in NAMEPLATE_KEYS}
    given = {key: value for key, value in data.items() if key in known}
    try:
        values = {key: value for key, value in read_keys(given, NAMEPLATE_KEYS, key_prefix).items()
                  if value is not None}
    except ValueError as error:
        raise NameplateError(f"{source}: {error}") from None
    name = str(data.get("name", "motor"))
    if defaults is not None:
        plate = defaults._replace(**values)
    else:
        current = values["rated_current_A"]
        values.setdefault("current_limit_A", 1.5 * current)
        values.setdefault("rated_torque_Nm", 1.5 * values["n_p"] * values["psi_f_Wb"] * current)
        values.setdefault("rated_speed_rpm", ASSUMED_RATED_SPEED_RPM)
        values.setdefault("rated_power_W", values["rated_torque_Nm"] * values["rated_speed_rpm"] * math.pi / 30.0)
        values.setdefault("J_kgm2", math.nan)
        values.setdefault("B_Nms", math.nan)
        plate = Nameplate(name=name, **values)
    if plate.current_limit_A < plate.rated_current_A:
        raise NameplateError(f"{source}: {key_prefix}current_limit_A: {plate.current_limit_A:g} A is below the rated "
                             f"current {plate.rated_current_A:g} A: the drive could not hold rated torque; give the "
                             f"current the motor is rated for as rated_current_A (and its torque as rated_torque_Nm)")
    if plate.current_limit_A > CURRENT_LIMIT_PER_RATED * plate.rated_current_A:
        raise NameplateError(f"{source}: {key_prefix}current_limit_A: {plate.current_limit_A:g} A is more than "
                             f"{CURRENT_LIMIT_PER_RATED:g} × the rated current {plate.rated_current_A:g} A: out of "
                             f"the motor's rating")
    return plate


def contract_motor(plate):
    """The drive_config ``motor`` object of contract v2 for a nameplate: its every field, SI keys."""
    return plate._asdict()


def contract_inverter(rating):
    """The drive_config ``inverter`` object (a project addition to contract v2) of an InverterRating: its
    every field, SI keys (∞, not stated, as null in the strict JSON)."""
    return rating._asdict()
