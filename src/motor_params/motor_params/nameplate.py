"""The nameplate: what a robot builder tells the drive about the motor (datasheet values and estimates),
and the drive's own inverter rating. Estimators and the controller read these, never the plant."""
import math
from typing import NamedTuple


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


NAMEPLATE_REQUIRED = ("n_p", "R_s_ohm", "L_d_H", "L_q_H", "psi_f_Wb", "rated_current_A")
"""What a motor description must give (the contract's drive_config ``motor``); the rest of a Nameplate
defaults as ASSUMED says."""
ASSUMED_RATED_SPEED_RPM = 3000.0
"""A motor description without ``rated_speed_rpm`` is taken to be rated at this speed (it only sets the
lock monitor's 2 % back-EMF margin)."""


NAMEPLATE_RANGES = {
    "n_p": (1, 100, "pole pairs"),
    "R_s_ohm": (0.0, 1e3, "Ω"),
    "L_d_H": (1e-8, 10.0, "H"),
    "L_q_H": (1e-8, 10.0, "H"),
    "psi_f_Wb": (1e-6, 100.0, "Wb"),
    "rated_power_W": (1e-3, 1e7, "W"),
    "rated_current_A": (1e-3, 1e4, "A"),
    "rated_speed_rpm": (1.0, 1e6, "rpm"),
    "rated_torque_Nm": (1e-7, 1e6, "N·m"),
    "current_limit_A": (1e-3, 1e4, "A"),
    "J_kgm2": (1e-10, 1e5, "kg·m²"),
    "B_Nms": (0.0, 1e4, "N·m·s"),
}
"""Each nameplate key's physical range (low, high, unit), declared once: a value outside it is a typo or a
unit slip, refused naming the key and the range, wherever a nameplate is read (motor files, drive
configuration files, a bag's drive_config)."""

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
    values = {}
    for key in Nameplate._fields[1:]:
        if key not in data:
            continue
        value = data[key]
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise NameplateError(f"{source}: {key_prefix}{key}: {value!r} is not a finite number")
        low_ok = value >= 0.0 if key in ("R_s_ohm", "B_Nms") else value > 0.0
        if not low_ok or (key == "n_p" and value != int(value)):
            raise NameplateError(f"{source}: {key_prefix}{key}: {value!r} is not a {'whole ' if key == 'n_p' else ''}"
                                 f"{'non-negative' if key in ('R_s_ohm', 'B_Nms') else 'positive'} number")
        low, high, unit = NAMEPLATE_RANGES[key]
        if not low <= value <= high:
            raise NameplateError(f"{source}: {key_prefix}{key}: {value!r} lies outside {low:g} … {high:g} {unit} "
                                 f"(a typo or a unit slip?)")
        values[key] = int(value) if key == "n_p" else float(value)
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
    if plate.current_limit_A > CURRENT_LIMIT_PER_RATED * plate.rated_current_A:
        raise NameplateError(f"{source}: {key_prefix}current_limit_A: {plate.current_limit_A:g} A is more than "
                             f"{CURRENT_LIMIT_PER_RATED:g} × the rated current {plate.rated_current_A:g} A: out of "
                             f"the motor's rating")
    return plate


def contract_motor(plate):
    """The drive_config ``motor`` object of contract v2 for a nameplate: its every field, SI keys."""
    return plate._asdict()
