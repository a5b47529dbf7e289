"""The commissioning record: what the drive's standstill tests measure on its own motor and inverter
(docs/commissioning.md), the record a drive assumes from its nameplate alone, and the file.

The file (YAML) holds the values with their units in the keys, how they were obtained (``method``),
the motor, the conditions and the date. Every error names the file and the key at fault.
"""
import datetime
import math
import os
from pathlib import Path
from typing import NamedTuple

import numpy as np
import yaml

from drive_common.contract.errors import DriveError
from drive_common.contract.settings import (
    FORMAT_VERSION_KEY,
    REQUIRED,
    Key,
    read_format_version,
    read_keys,
    refuse_unknown_keys,
)
from drive_common.math.current_sensing import CurrentCalibration

MIN_CONVERGENCE_SLOPE = 0.75
"""Sensorless operation keeps the current where a saliency tracker keeps three quarters of its loop gain
(on `wang_spmsm`: 5.6 A, 1.22× rated; at 1.5× rated the slope is −0.2)."""
MIN_SALIENCY_RATIO = 0.01
"""Below this |Δ|/Σ the saliency is not measurable: HF injection cannot tell the rotor's angle."""
WEAK_SALIENCY_RATIO = 0.05
"""Below this |Δ|/Σ (measured) what ours' predicted angle error leaves out weighs more: the drive says so. It does
not say the targets are missed: of 13 such drawn motors (2026-11-29, docs/results.md "Random motors"), 10 ran within
them and 3 over (0.021-0.032 rad RMS)."""
SALIENCY_RETAINED = 0.5
"""Sensorless operation also keeps the current where the saliency |Δ|/Σ keeps half its no-load strength:
the q axis saturating under load can take a weak saliency away (the angle noise grows as 1/|Δ|)."""
INDUCTANCE_TOLERANCE = 2.0
"""A commissioned HF inductance more than this factor off its nameplate value contradicts the motor (a file
measured on another motor, or a nameplate in the wrong unit): the drive refuses it. Not tighter: the
commissioned inductance is incremental at no load, the nameplate's apparent; a surface magnet's saturation
alone lowers the incremental L_d by up to a quarter, and a datasheet's L is often 10-20 % off (0.7 × the
nameplate's is a sound motor, docs/random-motors.md)."""
RESISTANCE_TOLERANCE = 2.0
"""Likewise R_s, with room for temperature (copper: +40 % from 20 °C to 120 °C)."""
NAMEPLATE_ONLY = "nameplate"
"""The commissioning source of a drive told its nameplate only."""
DEFAULT = "default"
class CommissioningError(DriveError):
    """A commissioning file is unusable; the message names the file and the key."""


class Commissioning(NamedTuple):
    """What the drive knows of its motor beyond the nameplate: the stator resistance, the inverter's
    dead-time voltage, the current sensors' relative gains and offsets, the HF inductances at no load, and
    how load current turns the saliency axis (shaft held, the current vector stepped along q up to the
    current limit and swept a little about it in d). ``source`` says where each value came from: a
    file's path, or NAMEPLATE_ONLY (``sources()`` itemises)."""

    R_s_ohm: float
    dead_time_voltage_V: float
    """Per-phase average voltage lost to the dead time at full conduction (t_dead/T_s · U_dc)."""
    sensor_gain_a: float
    """Relative gain of the phase-a current sensor (the three have mean 1)."""
    sensor_gain_b: float
    sensor_gain_c: float
    sensor_offset_a_A: float
    sensor_offset_b_A: float
    sensor_offset_c_A: float
    sensor_noise_A: float
    """RMS noise of one phase-current reading at zero current [A] (0: not measured)."""
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
    source: str = NAMEPLATE_ONLY
    psi_f_Wb: float = math.nan
    """Magnet flux linkage from the rotating test (hf_estimator.commissioning.rotating) [V·s]; NaN: not run."""
    J_kgm2: float = math.nan
    """Inertia of the rotor and what turns with it, from the rotating test [kg·m²]; NaN: not run."""
    saliency_ratio: np.ndarray = None
    """|Δ|/Σ at the table's currents (i_d = 0) [1]; None: not measured (a file written before)."""
    estimator_shift_rad: np.ndarray = None
    """Ours' own angle error under load at the table's currents, from the loaded test (shaft held,
    hf_estimator.commissioning.loaded) [rad]: added to ours' shift table where it runs the test's carrier and
    amplitude; None: not run."""
    loaded_test_frequency_Hz: float = math.nan
    """The carrier ours ran during the loaded test [Hz]; NaN: not run."""
    loaded_test_amplitude_V: float = math.nan
    """The HF amplitude ours ran during the loaded test [V]; NaN: not run."""
    saturation_asymmetry: float = math.nan
    """(L_dh at −I_rated − L_dh at +I_rated)/their mean along the magnet's d axis (the standstill test's polarity
    step) [1]: the magnet's saturation the start-up's polarity pulses measure; NaN: a file written before."""
    loaded_test_current_A: float = math.nan
    """The largest current ours kept its angle at in the loaded test [A] where that is below the tables' own
    limit (the test found the sensorless limit itself); NaN: not found lower, or not run."""

    def loaded_test_values(self):
        """{key: value} of the loaded test's conditions (empty where it did not run)."""
        return {key: float(getattr(self, key)) for key in LOADED if math.isfinite(getattr(self, key))}

    def tests(self):
        """The commissioning tests this record holds the results of, in order ("standstill", "rotating",
        "loaded"); none for the nameplate alone. A test not held leaves its values to the nameplate or the
        defaults (``sources``, drive_common.motor.knowledge), which a run states."""
        if self.source == NAMEPLATE_ONLY:
            return []
        return ["standstill"] + (["rotating"] if self.rotating_values() else []) + \
            (["loaded"] if self.loaded_test_values() else [])

    def rotating_values(self):
        """{key: value} of what the rotating test measured (ROTATING keys it ran for; empty if it did not)."""
        return {key: float(getattr(self, key)) for key in ROTATING if math.isfinite(getattr(self, key))}

    def refined(self, plate):
        """The nameplate ``plate`` with what the rotating test measured (ψ_f, J) in place of its own."""
        return plate._replace(**self.rotating_values())

    def calibration(self):
        """The current sensors' correction (drive_common.math.current_sensing)."""
        return CurrentCalibration(self.sensor_gain_a, self.sensor_gain_b, self.sensor_gain_c,
                                  self.sensor_offset_a_A, self.sensor_offset_b_A, self.sensor_offset_c_A)

    def sources(self):
        """Each value's origin: ``nameplate`` (R_s, L_dh = L_d, L_qh = L_q), ``default`` (ideal sensors,
        no dead time, no saliency shift) or ``commissioning file PATH``."""
        if self.source != NAMEPLATE_ONLY:
            return {key: f"commissioning file {self.source}" for key in SCALARS + TABLES}
        from_plate = ("R_s_ohm", "L_dh_H", "L_qh_H")
        return {key: NAMEPLATE_ONLY if key in from_plate else DEFAULT for key in SCALARS + TABLES}

    @property
    def sigma(self):
        """Σ = ½(1/L_dh + 1/L_qh) [1/H] (docs/hf-demodulation.md)."""
        return 0.5 * (1.0 / self.L_dh_H + 1.0 / self.L_qh_H)

    @property
    def delta(self):
        """Δ = ½(1/L_dh − 1/L_qh) [1/H]."""
        return 0.5 * (1.0 / self.L_dh_H - 1.0 / self.L_qh_H)

    def salient(self):
        """|Δ|/Σ reaches MIN_SALIENCY_RATIO: there is an angle for HF injection to find."""
        return abs(self.delta) >= MIN_SALIENCY_RATIO * abs(self.sigma)

    def weak_saliency_note(self):
        """What the drive says of a measured saliency below WEAK_SALIENCY_RATIO ("" otherwise)."""
        ratio = abs(self.delta / self.sigma)
        if self.source == NAMEPLATE_ONLY or not self.salient() or ratio >= WEAK_SALIENCY_RATIO:
            return ""
        return (f"weak saliency (|Δ|/Σ = {100.0 * ratio:.1f} % < {100.0 * WEAK_SALIENCY_RATIO:g} %): what the "
                f"predicted angle error leaves out (the dead time's residue, the load's turn of the axis) weighs more "
                f"against so small a signal, and a fast load step may outrun it")

    def saliency_retained(self, i_q_A):
        """The share of its no-load |Δ|/Σ the saliency keeps at q current ±``i_q_A`` [A] (the smaller of the
        two signs, interpolated in the table); 1 where the commissioning did not measure it."""
        if self.saliency_ratio is None:
            return 1.0
        currents, ratio = self.saliency_shift_i_q_A, np.abs(self.saliency_ratio)
        at_zero = float(np.interp(0.0, currents, ratio))
        loaded = min(float(np.interp(i_q_A, currents, ratio)), float(np.interp(-i_q_A, currents, ratio)))
        return loaded / at_zero if at_zero > 0.0 else 1.0

    def convergence_slope_range(self, limit_A):
        """(smallest, largest) convergence slope F over q currents within ±``limit_A`` [A]: the table's points there
        and its values interpolated at ±limit_A."""
        currents, slope = self.saliency_shift_i_q_A, self.convergence_slope
        inside = slope[np.abs(currents) <= limit_A]
        ends = np.interp([-limit_A, limit_A], currents, slope)
        values = np.concatenate([inside, ends])
        return float(np.min(values)), float(np.max(values))

    def tracking_current_limit_A(self, min_slope=MIN_CONVERGENCE_SLOPE):
        """The largest current |i_q| [A] up to which the convergence slope (interpolated linearly in the
        table) stays at or above ``min_slope`` on both signs of the current and, where the commissioning
        measured it, the saliency keeps SALIENCY_RETAINED of its strength at no load; the table's end if
        neither falls below; at most the loaded test's current where it found ours losing its angle lower."""
        currents = self.saliency_shift_i_q_A
        limit = held_up_to(currents, self.convergence_slope, min_slope)
        if self.saliency_ratio is not None:
            ratio = np.abs(self.saliency_ratio)
            limit = min(limit, held_up_to(currents, ratio, SALIENCY_RETAINED * ratio[np.argmin(np.abs(currents))]))
        if math.isfinite(self.loaded_test_current_A):
            limit = min(limit, self.loaded_test_current_A)
        return limit

def held_up_to(currents, values, threshold):
    """The largest |current| [A] up to which ``values`` (a table over ``currents``, interpolated linearly)
    stays at or above ``threshold`` on both signs; 0 where the value at zero current is below it."""
    if values[np.argmin(np.abs(currents))] < threshold:
        return 0.0
    limit = float(np.max(np.abs(currents)))
    for j in range(len(currents) - 1):
        (i0, i1), (f0, f1) = currents[j:j + 2], values[j:j + 2]
        for inner, outer, f_inner, f_outer in ((i1, i0, f1, f0), (i0, i1, f0, f1)):
            if abs(outer) > abs(inner) and f_inner >= threshold > f_outer:
                crossing = inner + (outer - inner) * (f_inner - threshold) / (f_inner - f_outer)
                limit = min(limit, abs(float(crossing)))
    return limit


VALUE_KEYS = (
    Key("R_s_ohm", "Ω", 0.0),
    Key("dead_time_voltage_V", "V", 0.0, low_inclusive=True),
    *(Key(f"sensor_gain_{x}", "", 0.5, 2.0, low_inclusive=True) for x in "abc"),
    *(Key(f"sensor_offset_{x}_A", "A") for x in "abc"),
    Key("sensor_noise_A", "A", 0.0, low_inclusive=True),
    Key("L_dh_H", "H", 0.0),
    Key("L_qh_H", "H", 0.0),
    Key("psi_f_Wb", "Wb", 0.0, default=math.nan, doc="the rotating test's"),
    Key("J_kgm2", "kg·m²", 0.0, default=math.nan, doc="the rotating test's"),
    Key("loaded_test_frequency_Hz", "Hz", 0.0, default=math.nan, doc="the loaded test's"),
    Key("loaded_test_amplitude_V", "V", 0.0, default=math.nan, doc="the loaded test's"),
    Key("saturation_asymmetry", "", -1.0, 1.0, default=math.nan, doc="the standstill test's polarity step"),
    Key("loaded_test_current_A", "A", 0.0, default=math.nan, doc="the loaded test's limit where it found one"),
)
"""A commissioning file's scalar values, declared once (drive_common.contract.settings.Key); the tables
(TABLES, OPTIONAL_TABLES) are lists of finite numbers of one length."""
SCALARS = tuple(key.name for key in VALUE_KEYS if key.default is REQUIRED)
"""The values every commissioning file holds (the standstill test's)."""
TABLES = ("saliency_shift_i_q_A", "saliency_shift_rad", "convergence_slope")
ROTATING = ("psi_f_Wb", "J_kgm2")
"""Values only the rotating test measures: optional in a file (a shaft that cannot turn)."""
LOADED = ("loaded_test_frequency_Hz", "loaded_test_amplitude_V")
"""The loaded test's conditions: optional in a file (a test the shaft's brake may not allow)."""
OPTIONAL_TABLES = ("saliency_ratio", "estimator_shift_rad")
"""Tables a file written before they were measured lacks (estimator_shift_rad: the loaded test's)."""


DOCUMENT_KEYS = (FORMAT_VERSION_KEY, "motor", "method", "date", "conditions", "values", "source")
"""A commissioning file's top-level keys (``source``: a recording's record of one)."""
FORMAT_VERSION = 1
"""The commissioning file format this drive writes and reads (docs/commissioning.md)."""
SALIENCY_SIGN_RATIO = 0.05
"""A nameplate whose |L_q − L_d|/(L_q + L_d) reaches this states which axis has the larger inductance: a
commissioning file saying the other (L_dh and L_qh swapped) contradicts it and is refused."""


def nameplate_commissioning(plate):
    """The record of a drive told only its nameplate (drive_common.motor.nameplate.Nameplate): R_s, L_dh = L_d
    and L_qh = L_q from it; ideal current sensors (noise not measured), no dead-time voltage, no saliency
    shift (slope 1) over ± the current limit."""
    currents = np.array([-plate.current_limit_A, 0.0, plate.current_limit_A])
    return Commissioning(plate.R_s_ohm, 0.0, 1.0, 1.0, 1.0, 0.0, 0.0, 0.0, 0.0, plate.L_d_H, plate.L_q_H,
                         currents, np.zeros(3), np.ones(3), NAMEPLATE_ONLY)


def default_commissioning_file(motor):
    """Where a motor's commissioning file is looked for when none is named (the working directory)."""
    return Path("commissioning") / f"{motor}.yaml"


def resolve_commissioning(plate, given="", label="commissioning"):
    """What the drive knows beyond the nameplate ``plate``: the file ``given`` (``label`` says where that
    name came from: a command-line option, a parameter, a scenario key), NAMEPLATE_ONLY, or when empty the
    default file when present, else the nameplate alone. CommissioningError names the file and key."""
    if given == NAMEPLATE_ONLY:
        return nameplate_commissioning(plate)
    path = Path(given) if given else default_commissioning_file(plate.name)
    if not given and not path.is_file():
        return nameplate_commissioning(plate)
    try:
        commissioning, metadata = load_commissioning(path)
    except CommissioningError as error:
        raise CommissioningError(f"{label}: {error}") from None
    if metadata.get("motor") not in (None, plate.name):
        raise CommissioningError(f"{label}: {path} is for motor {metadata['motor']}, this drive's is {plate.name}")
    told_saliency = (plate.L_q_H - plate.L_d_H) / (plate.L_q_H + plate.L_d_H)
    measured_saliency = commissioning.L_qh_H - commissioning.L_dh_H
    if abs(told_saliency) >= SALIENCY_SIGN_RATIO and told_saliency * measured_saliency < 0.0:
        larger = "d" if measured_saliency < 0 else "q"
        raise CommissioningError(f"{label}: {path}: values.L_dh_H, values.L_qh_H: {commissioning.L_dh_H:.4g} H and "
                                 f"{commissioning.L_qh_H:.4g} H say the {larger} axis has the larger inductance; "
                                 f"the nameplate's L_d_H {plate.L_d_H:.4g} H and L_q_H "
                                 f"{plate.L_q_H:.4g} H say the other: swapped? Commission again (`drive commission`)")
    for key, told, tolerance in (("L_dh_H", plate.L_d_H, INDUCTANCE_TOLERANCE),
                                 ("L_qh_H", plate.L_q_H, INDUCTANCE_TOLERANCE),
                                 ("R_s_ohm", plate.R_s_ohm, RESISTANCE_TOLERANCE)):
        measured = float(getattr(commissioning, key))
        if told > 0.0 and not 1.0 / tolerance <= measured / told <= tolerance:
            raise CommissioningError(f"{label}: {path}: values.{key}: {measured:.4g} is {measured / told:.2f} × the "
                                     f"nameplate's {told:.4g} (more than {tolerance:g}× off): measured on another "
                                     f"motor? Commission this one (`drive commission`)")
    return commissioning


def commissioning_values(commissioning):
    """The values of a commissioning record as its file holds them (floats exact, tables as lists)."""
    values = {key: float(getattr(commissioning, key)) for key in SCALARS}
    values.update(commissioning.rotating_values())
    values.update(commissioning.loaded_test_values())
    for key in ("saturation_asymmetry", "loaded_test_current_A"):
        if math.isfinite(getattr(commissioning, key)):
            values[key] = float(getattr(commissioning, key))
    values.update({key: [float(v) for v in getattr(commissioning, key)] for key in TABLES})
    values.update({key: [float(v) for v in getattr(commissioning, key)] for key in OPTIONAL_TABLES
                   if getattr(commissioning, key) is not None})
    return values


def save_commissioning(path, commissioning, motor, method, conditions=None):
    """Write ``commissioning`` to the YAML file at ``path`` (floats written exactly), whole or not at all: a
    temporary file beside it, renamed over it once written; returns the path."""
    document = {"format_version": FORMAT_VERSION, "motor": motor, "method": method,
                "date": datetime.date.today().isoformat(), "conditions": dict(conditions or {}),
                "values": commissioning_values(commissioning)}
    path = Path(path)
    writing = path.with_name(f".{path.name}.writing")
    try:
        writing.write_text(yaml.safe_dump(document, sort_keys=False, width=100))
        os.replace(writing, path)
    finally:
        writing.unlink(missing_ok=True)
    return path


def commissioning_record(commissioning):
    """What a recording keeps of the drive's commissioning (its drive_config ``commissioning``): where it came
    from, and the values themselves unless it is the nameplate alone, so that a replay needs no file."""
    if commissioning.source == NAMEPLATE_ONLY:
        return {"source": NAMEPLATE_ONLY}
    return {"source": commissioning.source, "values": commissioning_values(commissioning)}


def recorded_commissioning(plate, record, where):
    """The Commissioning a recording's drive_config ``record`` (commissioning_record) holds; ``where`` names it
    in a CommissioningError."""
    if not isinstance(record, dict) or not isinstance(record.get("source"), str):
        raise CommissioningError(f"{where}: not a commissioning record (a mapping with source and values)")
    if record["source"] == NAMEPLATE_ONLY:
        return nameplate_commissioning(plate)
    commissioning, _ = commissioning_from_document(record, where)
    return commissioning._replace(source=f"{where} (recorded from {record['source']})")


def load_commissioning(path):
    """(Commissioning, metadata dict without the values) from a commissioning file."""
    path = Path(path)
    try:
        document = yaml.safe_load(path.read_text())
    except OSError as error:
        raise CommissioningError(f"{path}: cannot read the commissioning file ({error.strerror})") from None
    except (yaml.YAMLError, UnicodeDecodeError) as error:
        raise CommissioningError(f"{path}: not a commissioning file ({str(error).splitlines()[0]})") from None
    return commissioning_from_document(document, path)


def commissioning_from_document(document, path):
    """(Commissioning, metadata without the values) from a commissioning document (a file's, or a record's in
    a recording); ``path`` names it in a CommissioningError."""
    if not isinstance(document, dict) or not isinstance(document.get("values"), dict):
        raise CommissioningError(f"{path}: values: missing (a mapping of the measured quantities)")
    values = document["values"]
    missing = [key for key in SCALARS if key not in values]
    if missing:
        raise CommissioningError(f"{path}: values.{missing[0]}: missing (a file written before the drive measured "
                                 f"it: run `drive commission` again)")
    try:
        refuse_unknown_keys(document, DOCUMENT_KEYS)
        if "source" not in document:
            read_format_version(document, FORMAT_VERSION, "commissioning file", path)
        parsed = read_keys(values, VALUE_KEYS, "values.", known_extra=TABLES + OPTIONAL_TABLES)
    except ValueError as error:
        raise CommissioningError(f"{path}: {error}") from None
    lengths = set()
    for key in TABLES + OPTIONAL_TABLES:
        table = values.get(key)
        if key in OPTIONAL_TABLES and table is None:
            continue
        if not isinstance(table, list) or not all(isinstance(v, (int, float)) and not isinstance(v, bool)
                                                  and math.isfinite(v) for v in table):
            raise CommissioningError(f"{path}: values.{key}: must be a list of finite numbers")
        parsed[key] = np.asarray(table, dtype=float)
        lengths.add(len(table))
    if len(lengths) != 1 or lengths == {0}:
        raise CommissioningError(f"{path}: values: the tables {', '.join(TABLES + OPTIONAL_TABLES)} must have one "
                                 f"equal, non-zero length")
    if np.any(np.diff(parsed["saliency_shift_i_q_A"]) <= 0.0):
        raise CommissioningError(f"{path}: values.saliency_shift_i_q_A: must be ascending")
    if ("estimator_shift_rad" in parsed) != all(math.isfinite(parsed[key]) for key in LOADED):
        raise CommissioningError(f"{path}: values: estimator_shift_rad, {', '.join(LOADED)}: the loaded test's "
                                 f"result and its conditions go together (give all or none)")
    metadata = {key: value for key, value in document.items() if key != "values"}
    return Commissioning(**parsed, source=str(path)), metadata
