"""Random motors: motor files drawn from one fixed distribution over the range a robot builder meets
(docs/random-motors.md, issue 51). Each draw is physically consistent: the rating's dependent quantities
come from physics (ψ_f from the bus that must drive rated speed at rated torque, the current from the
rated torque and ψ_f, R_s from the copper loss, the inductances from a per-unit reactance, J from the
time rated torque takes to reach rated speed), and its ``plant:`` truth lies within ±TRUTH_SPREAD of
the nameplate. Motor i of seed S is the same whatever N is drawn (its own generator, seeded by (S, i))."""
import math
from typing import NamedTuple

import numpy as np
import yaml

from drive_common.motor.motor_file import FORMAT_VERSION, motor_from_mapping

POWER_W = (10.0, 5000.0)
"""Rated power, log-uniform."""
POLE_PAIRS = (1, 30)
"""Pole pairs, uniform over the whole numbers."""
RATED_SPEED_RPM = (300.0, 6000.0)
"""Rated speed, log-uniform, its top held to MAX_RATED_ELECTRICAL_HZ / n_p."""
MAX_RATED_ELECTRICAL_HZ = 600.0
BUS_V = (12.0, 600.0)
"""DC link, log-uniform between max(12 V, P / BUS_LOW_W_PER_V) and min(600 V, 48 V·√(P / 10 W))."""
BUS_LOW_W_PER_V = 50.0
BUS_HIGH_AT_10_W_V = 48.0
BUS_USE = (0.6, 0.9)
"""Share of the linear voltage range U_dc/√3 the rated point (rated speed, rated torque) takes, uniform."""
COPPER_LOSS_PER_RATED = (0.02, 0.15)
"""1.5·R_s·I² per rated power, log-uniform."""
REACTANCE_PER_UNIT = (0.1, 0.5)
"""L_d·I_rated / ψ_f, log-uniform."""
INTERIOR_SHARE = 0.5
"""Share of interior magnets (L_q/L_d uniform in SALIENCY_RATIO); the rest are surface magnets (L_q = L_d
geometrically, their saliency from saturation alone)."""
SALIENCY_RATIO = (1.0, 3.5)
SATURATION_SHARE = 0.75
"""Share of motors whose iron saturates: the magnet lowers the incremental L_dh (surface: by
SURFACE_D_SATURATION; interior: L_dh falls by INTERIOR_D_DROP at rated magnetising current) and the q axis
saturates by Q_DROP_AT_RATED at rated current. The rest are linear."""
SURFACE_D_SATURATION = (0.0, 0.25)
INTERIOR_D_DROP = (0.05, 0.2)
Q_DROP_AT_RATED = (0.0, 0.15)
CROSS_SATURATION_SHARE = 0.5
"""Share of motors with cross-saturation: the incremental L_qh at no load below L_q by CROSS_DROP."""
CROSS_DROP = (0.01, 0.06)
ACCELERATION_TIME_S = (3e-3, 3.0)
"""J·ω_rated/τ_rated (rotor and load), log-uniform: three decades for the power."""
FRICTION_PER_RATED = (0.002, 0.02)
"""B·ω_rated per rated torque, log-uniform."""
INERTIA_ON_NAMEPLATE_SHARE = 0.5
"""Share of nameplates that state J (and B); the rest leave them for `drive commission --rotating`."""
CURRENT_LIMIT_PER_RATED = (1.5, 2.0)
INVERTER_PER_LIMIT = (1.0, 1.5)
"""The inverter's current rating per current limit, uniform (the limit stays within it)."""
TRUTH_SPREAD = 0.1
"""The plant's R_s, ψ_f, L_d, L_q, J and B: the nameplate's × (1 + uniform(−0.1, 0.1)), each its own factor
(a surface-magnet rotor stays round: L_q the same as L_d)."""


class SensorClass(NamedTuple):
    """The inverter's switches and current sensing of a power class."""

    name: str
    up_to_W: float
    dead_time_s: tuple
    """Log-uniform."""
    noise_per_range: tuple
    """Sensor noise RMS per ADC full scale, log-uniform."""
    adc_bits: int


SENSOR_CLASSES = (
    SensorClass("10-100 W", 100.0, (0.2e-6, 0.5e-6), (3e-4, 1e-3), 12),
    SensorClass("100 W-1 kW", 1000.0, (0.5e-6, 1.0e-6), (3e-4, 1e-3), 12),
    SensorClass("1-5 kW", math.inf, (1.0e-6, 2.0e-6), (5e-4, 1.5e-3), 12),
)
"""MOSFETs and shunts below 1 kW, IGBTs and Hall sensors above; the ADC spans ±2 × the current limit,
offsets within ±0.5 % and gains within ±0.3 % of it."""
OFFSET_PER_RANGE = 0.005
GAIN_SPREAD = 0.003


class RandomMotor(NamedTuple):
    """One draw: its motor file's document and the class figures the bench reports it by."""

    name: str
    document: dict
    """The motor file (drive_common.motor.motor_file), ``plant:`` included."""
    figures: dict
    """Class figures: power class, the plant's L_qh/L_dh at no load, n_p, P, U_dc, the nameplate's L_q/L_d,
    rotor kind, saturation, cross-saturation, acceleration time, J on the nameplate."""


def _log_uniform(rng, bounds):
    low, high = bounds
    return float(math.exp(rng.uniform(math.log(low), math.log(high))))


def _uniform(rng, bounds):
    return float(rng.uniform(*bounds))


def power_class(power_W):
    """The SensorClass of a rated power [W]."""
    return next(c for c in SENSOR_CLASSES if power_W <= c.up_to_W)


def draw_motor(seed, index):
    """Motor ``index`` of the draw seeded ``seed``: a RandomMotor (distribution above)."""
    rng = np.random.default_rng([seed, index])
    power = _log_uniform(rng, POWER_W)
    n_p = int(rng.integers(POLE_PAIRS[0], POLE_PAIRS[1] + 1))
    top_rpm = min(RATED_SPEED_RPM[1], MAX_RATED_ELECTRICAL_HZ * 60.0 / n_p)
    speed_rpm = _log_uniform(rng, (min(RATED_SPEED_RPM[0], top_rpm), top_rpm))
    omega_m = speed_rpm * math.pi / 30.0
    torque = power / omega_m
    bus = _log_uniform(rng, (max(BUS_V[0], power / BUS_LOW_W_PER_V),
                             min(BUS_V[1], BUS_HIGH_AT_10_W_V * math.sqrt(power / POWER_W[0]))))
    interior = bool(rng.random() < INTERIOR_SHARE)
    ratio = _uniform(rng, SALIENCY_RATIO) if interior else 1.0
    saturation, cross = bool(rng.random() < SATURATION_SHARE), bool(rng.random() < CROSS_SATURATION_SHARE)
    copper, reactance = _log_uniform(rng, COPPER_LOSS_PER_RATED), _log_uniform(rng, REACTANCE_PER_UNIT)
    # At rated speed and torque with i_d = 0: u_q = ω_e·ψ_f·(1 + copper share), u_d = −ω_e·ψ_f·(L_q·I/ψ_f);
    # their magnitude takes BUS_USE of U_dc/√3.
    omega_e = n_p * omega_m
    psi_f = _uniform(rng, BUS_USE) * bus / math.sqrt(3.0) / (omega_e * math.hypot(1.0 + copper, ratio * reactance))
    current = torque / (1.5 * n_p * psi_f)
    R_s = copper * power / (1.5 * current ** 2)
    L_d = reactance * psi_f / current
    acceleration_s = _log_uniform(rng, ACCELERATION_TIME_S)
    J, B = torque * acceleration_s / omega_m, _log_uniform(rng, FRICTION_PER_RATED) * torque / omega_m
    limit = _uniform(rng, CURRENT_LIMIT_PER_RATED) * current
    sensors = power_class(power)
    plate = {"n_p": n_p, "R_s_ohm": R_s, "L_d_H": L_d, "L_q_H": ratio * L_d, "psi_f_Wb": psi_f,
             "rated_power_W": power, "rated_current_A": current, "rated_speed_rpm": speed_rpm,
             "rated_torque_Nm": torque, "current_limit_A": limit}
    inertia_known = bool(rng.random() < INERTIA_ON_NAMEPLATE_SHARE)
    if inertia_known:
        plate.update(J_kgm2=J, B_Nms=B)
    truth = {key: value * (1.0 + rng.uniform(-TRUTH_SPREAD, TRUTH_SPREAD))
             for key, value in (("R_s_ohm", R_s), ("psi_f_Wb", psi_f), ("J_kgm2", J), ("B_Nms", B),
                                ("L_d_H", L_d), ("L_q_H", ratio * L_d))}
    if not interior:
        truth["L_q_H"] = truth["L_d_H"]
    d_saturation = _uniform(rng, SURFACE_D_SATURATION if not interior else INTERIOR_D_DROP)
    q_drop, cross_drop = _uniform(rng, Q_DROP_AT_RATED), _uniform(rng, CROSS_DROP)
    if saturation and interior:
        truth["L_dh_H"] = truth.pop("L_d_H")
        truth["L_dh_drop_at_rated"] = d_saturation
    elif saturation:
        truth["L_dh_H"] = truth["L_d_H"] * (1.0 - d_saturation)
    if saturation:
        truth["L_qh_drop_at_rated"] = q_drop
    if cross:
        truth["L_qh_H"] = truth["L_q_H"] * (1.0 - cross_drop)
    adc_range = 2.0 * limit
    truth["t_dead_s"] = _log_uniform(rng, sensors.dead_time_s)
    truth["sensor"] = {"noise_std_A": _log_uniform(rng, sensors.noise_per_range) * adc_range,
                       **{f"offset_{x}_A": rng.uniform(-OFFSET_PER_RANGE, OFFSET_PER_RANGE) * adc_range
                          for x in "abc"},
                       **{f"gain_{x}": 1.0 + rng.uniform(-GAIN_SPREAD, GAIN_SPREAD) for x in "abc"},
                       "adc_bits": sensors.adc_bits, "adc_range_A": adc_range}
    name = f"random_{seed}_{index:04d}"
    kind = "interior" if interior else "surface"
    description = (f"random draw {index} of seed {seed}: {power:.3g} W, {bus:.3g} V, {n_p} pole pairs, "
                   f"{kind} magnets, L_q/L_d {ratio:.2f}")
    document = {"format_version": FORMAT_VERSION, "name": name, "description": description,
                "nameplate": _rounded(plate),
                "inverter": {"U_dc_V": _round(bus), "delay_periods": 1,
                             "current_rating_A": _round(_uniform(rng, INVERTER_PER_LIMIT) * limit)},
                "plant": {"source": f"drive bench motors --random, seed {seed}, motor {index} "
                                    f"(docs/random-motors.md)", **_rounded(truth)}}
    figures = {"power_class": sensors.name, "L_qh_per_L_dh": round(true_saliency(document), 4), "n_p": n_p,
               "rated_power_W": _round(power), "U_dc_V": _round(bus),
               "L_q_per_L_d": round(ratio, 4), "rotor": kind, "saturation": saturation,
               "cross_saturation": cross, "acceleration_time_s": _round(acceleration_s),
               "J_on_nameplate": inertia_known}
    return RandomMotor(name, document, figures)


def true_saliency(document):
    """The plant's incremental L_qh/L_dh at no load of a motor file's document (its HF saliency)."""
    from pmsm_plant.model import incremental_inductances
    from pmsm_plant.presets import plant_truth

    L_dh, L_qh, _ = incremental_inductances(plant_truth(motor_from_mapping(document, "random motor",
                                                                            whole_file=True)).machine)
    return L_qh / L_dh


def _round(value):
    """A value to 6 significant digits (a motor file a reader can read)."""
    return float(f"{value:.6g}")


def _rounded(mapping):
    return {key: (_rounded(v) if isinstance(v, dict) else _round(v) if isinstance(v, float) else v)
            for key, v in mapping.items()}


def draw_motors(count, seed):
    """The first ``count`` motors of the draw seeded ``seed`` (a list of RandomMotor)."""
    return [draw_motor(seed, index) for index in range(count)]


def write_motor_files(motors, folder):
    """Write each RandomMotor as ``folder``/NAME.yaml (the folder made if missing); the paths, in order.
    Each document is read back through the motor file reader first (a draw it refuses is a defect here)."""
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for motor in motors:
        motor_from_mapping(motor.document, f"random motor {motor.name}", whole_file=True)
        path = folder / f"{motor.name}.yaml"
        path.write_text(f"# {motor.document['description']}\n# Drawn by `drive bench motors --random` "
                        f"(docs/random-motors.md).\n" + yaml.safe_dump(motor.document, sort_keys=False),
                        encoding="utf-8")
        paths.append(path)
    return paths
