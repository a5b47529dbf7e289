"""The commissioning record: what a standstill HF test measures on the drive's own motor, and its file.

The file (YAML) holds the values with their units in the keys, how they were obtained (``method``),
the motor, the conditions and the date. Every error names the file and the key at fault.
"""
import datetime
import math
from pathlib import Path
from typing import NamedTuple

import numpy as np
import yaml

from drive_interface.errors import DriveError

MIN_CONVERGENCE_SLOPE = 0.75
"""Sensorless operation keeps the current where a saliency tracker keeps three quarters of its loop gain
(on `wang_spmsm`: 5.6 A, 1.22× rated; at 1.5× rated the slope is −0.2)."""


class CommissioningError(DriveError):
    """A commissioning file is unusable; the message names the file and the key."""


class Commissioning(NamedTuple):
    """HF inductances at no load, and how load current turns the saliency axis (rotor locked at a known
    angle, the current vector stepped along the q axis up to the current limit and swept a little about
    it, the HF admittance's axis recorded: the cross-saturation shift and its dependence on i_d)."""

    L_dh_H: float
    L_qh_H: float
    saliency_shift_i_q_A: np.ndarray
    """q currents of the tables [A] (uniform grid, ascending)."""
    saliency_shift_rad: np.ndarray
    """Saliency-axis angle from the rotor d axis at those currents [rad, electrical]."""
    convergence_slope: np.ndarray
    """d(saliency-axis angle)/d(rotor angle) with the current vector held still, at those currents:
    1 + i_q·∂δ/∂i_d [1]. It is the slope of every saliency tracker's error signal; at 0 the HF
    admittance no longer tells the rotor angle (the axis turns back as fast as the rotor turns)."""

    @property
    def sigma(self):
        """Σ = ½(1/L_dh + 1/L_qh) [1/H] (docs/hf-demodulation.md)."""
        return 0.5 * (1.0 / self.L_dh_H + 1.0 / self.L_qh_H)

    @property
    def delta(self):
        """Δ = ½(1/L_dh − 1/L_qh) [1/H]."""
        return 0.5 * (1.0 / self.L_dh_H - 1.0 / self.L_qh_H)

    def tracking_current_limit_A(self, min_slope=MIN_CONVERGENCE_SLOPE):
        """The largest table current |i_q| [A] up to which the convergence slope stays at or above
        ``min_slope`` on both signs of the current."""
        magnitude = np.abs(self.saliency_shift_i_q_A)
        failing = magnitude[self.convergence_slope < min_slope]
        inside = magnitude < failing.min() if failing.size else np.ones_like(magnitude, dtype=bool)
        return float(magnitude[inside].max())


SCALARS = ("L_dh_H", "L_qh_H")
TABLES = ("saliency_shift_i_q_A", "saliency_shift_rad", "convergence_slope")


def save_commissioning(path, commissioning, motor, method, conditions=None):
    """Write ``commissioning`` to a new YAML file at ``path`` (floats written exactly); returns the path."""
    values = {key: float(getattr(commissioning, key)) for key in SCALARS}
    values.update({key: [float(v) for v in getattr(commissioning, key)] for key in TABLES})
    document = {"motor": motor, "method": method, "date": datetime.date.today().isoformat(),
                "conditions": dict(conditions or {}), "values": values}
    path = Path(path)
    path.write_text(yaml.safe_dump(document, sort_keys=False, width=100))
    return path


def load_commissioning(path):
    """(Commissioning, metadata dict without the values) from a commissioning file."""
    path = Path(path)
    try:
        document = yaml.safe_load(path.read_text())
    except OSError as error:
        raise CommissioningError(f"{path}: cannot read the commissioning file ({error.strerror})") from None
    except (yaml.YAMLError, UnicodeDecodeError) as error:
        raise CommissioningError(f"{path}: not a commissioning file ({str(error).splitlines()[0]})") from None
    if not isinstance(document, dict) or not isinstance(document.get("values"), dict):
        raise CommissioningError(f"{path}: values: missing (a mapping of the measured quantities)")
    values = document["values"]
    parsed = {}
    for key in SCALARS:
        value = values.get(key)
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
                or value <= 0.0:
            raise CommissioningError(f"{path}: values.{key}: must be a positive inductance in H, not {value!r}")
        parsed[key] = float(value)
    lengths = set()
    for key in TABLES:
        table = values.get(key)
        if not isinstance(table, list) or not all(isinstance(v, (int, float)) and not isinstance(v, bool)
                                                  and math.isfinite(v) for v in table):
            raise CommissioningError(f"{path}: values.{key}: must be a list of finite numbers")
        parsed[key] = np.asarray(table, dtype=float)
        lengths.add(len(table))
    if len(lengths) != 1 or lengths == {0}:
        raise CommissioningError(f"{path}: values: the tables {', '.join(TABLES)} must have one equal, "
                                 f"non-zero length")
    if np.any(np.diff(parsed["saliency_shift_i_q_A"]) <= 0.0):
        raise CommissioningError(f"{path}: values.saliency_shift_i_q_A: must be ascending")
    metadata = {key: value for key, value in document.items() if key != "values"}
    return Commissioning(**parsed), metadata
