"""The simulated motor of a motor file: its ``plant:`` section (drive_common.motor.motor_file) turned into the
true machine, mechanics, inverter and sensors the simulator integrates, with every default written down.

A preset holds the true plant (``machine``: saturation included; mechanics, inverter, sensors) beside the
``nameplate`` a user would know from the datasheet (``drive_common.motor.nameplate``, what the drive is told).
The two are kept apart on purpose: only the plant reads the truth. The shipped motors' files carry the
papers' machines with their assumptions.
"""
import math
from dataclasses import dataclass, field

from drive_common.config.experiment import NO_DEVIATION
from drive_common.contract.settings import refuse_unknown_keys, shown
from drive_common.motor.motor_file import MotorFileError, load_motor, shipped_motor_names
from drive_common.motor.nameplate import NAMEPLATE_KEYS, Nameplate

from .params import InverterParams, MachineParams, MechanicsParams, SensorParams

NAMEPLATE_DECLARED = {key.name: key for key in NAMEPLATE_KEYS}
"""The nameplate's declarations by key: the plant's truth of the same quantity stays within them."""


@dataclass(frozen=True)
class MotorPreset:
    name: str
    machine: MachineParams
    nameplate: Nameplate
    mechanics: MechanicsParams
    inverter: InverterParams
    sensor: SensorParams
    source: str
    assumptions: tuple = field(default_factory=tuple)


PLANT_KEYS = ("source", "assumptions", "R_s_ohm", "psi_f_Wb", "J_kgm2", "B_Nms", "L_d_H", "L_q_H", "L_dh_H",
              "L_dh_drop_at_rated", "L_qh_H", "L_qh_drop_at_rated", "t_dead_s", "i_dead_A", "sensor",
              "C_th_J_K", "R_th_K_W", "T_ambient_degC")
SENSOR_KEYS = SensorParams._fields
DEFAULT_DEAD_TIME_S = 0.5e-6
DEFAULT_DEAD_CURRENT_A = 0.05
DEFAULT_ADC_BITS = 12
ADC_RANGE_PER_CURRENT_LIMIT = 2.0
"""Without a ``sensor`` section: a 12-bit ADC over ± this many times the current limit."""
NOISE_PER_ADC_RANGE = 1e-3
"""Without a noise figure: this share of the ADC range, RMS (the shipped motors: 1e-3 and 6e-4)."""


def _spmsm_saturation(L_d_H, L_q_H, L_dh0_H, L_qh0_H, psi_f_Wb, psi_q_rated_Wb, L_qh_drop_rated):
    """Saturation coefficients (a_d, a_q, a_dq) of MachineParams from incremental inductances at no load.

    The magnet flux saturates the iron so the incremental inductances are L_dh0 ≤ L_d, L_qh0 ≤ L_q
    (saturation saliency, e.g. a round-rotor SPMSM): 5 a_d ψ_f⁴ = 1/L_dh0 − 1/L_d and (a_dq/3) ψ_f³ =
    1/L_qh0 − 1/L_q. The q-axis self-saturation makes L_qh fall by the fraction L_qh_drop_rated at the
    rated q flux: 3 a_q ψ_q² = (1/(1−drop) − 1)/L_qh0.
    """
    a_d = (1.0 / L_dh0_H - 1.0 / L_d_H) / (5.0 * psi_f_Wb ** 4)
    a_dq = 3.0 * (1.0 / L_qh0_H - 1.0 / L_q_H) / psi_f_Wb ** 3
    a_q = (1.0 / (1.0 - L_qh_drop_rated) - 1.0) / L_qh0_H / (3.0 * psi_q_rated_Wb ** 2)
    return a_d, a_q, a_dq


def _d_axis_saturation(L_dh0_H, psi_f_Wb, i_rated_A, L_dh_drop_rated):
    """(L_0, a_d) of MachineParams for a d axis that the magnet saturates: incremental L_dh0 at no load
    (ψ_d = ψ_f), falling by the fraction L_dh_drop_rated at ψ_d = ψ_f + L_dh0·i_rated (rated
    magnetising d current) and rising towards L_0 on the demagnetising side: 1/L_dh(ψ) = 1/L_0 + 5 a_d ψ⁴."""
    psi_high = psi_f_Wb + L_dh0_H * i_rated_A
    a_d = (1.0 / ((1.0 - L_dh_drop_rated) * L_dh0_H) - 1.0 / L_dh0_H) / (5.0 * (psi_high ** 4 - psi_f_Wb ** 4))
    return 1.0 / (1.0 / L_dh0_H - 5.0 * a_d * psi_f_Wb ** 4), a_d


def plant_truth(motor, source="motor"):
    """The MotorPreset of a Motor (or a shipped name or motor file path; ``source`` says where it came from)
    from its file's ``plant:`` section, each value the nameplate's where the section is silent;
    MotorFileError names where the motor was given, the file and the key."""
    motor = load_motor(motor, source)
    plate, plant = motor.nameplate, motor.plant
    where = f"{motor.given_by}: {motor.source}: plant"
    if motor.given_by.endswith(motor.source):
        where = f"{motor.given_by}: plant"

    def fail(key, problem):
        raise MotorFileError(f"{where}.{key}: {problem}")

    _refuse_typos(plant, PLANT_KEYS, "", fail)

    def value(key, default, low=0.0, low_inclusive=False, high=math.inf):
        v = plant.get(key, default)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            fail(key, f"must be a finite number, not {shown(v)}")
        if (v < low if low_inclusive else v <= low) or v >= high:
            fail(key, f"must lie in {'[' if low_inclusive else '('}{low:g}, {high:g}), not {shown(v)}")
        declared = NAMEPLATE_DECLARED.get(key.replace("h_H", "_H"))
        if declared and key in plant:
            try:
                declared.read(v)
            except ValueError as error:
                fail(key, f"{str(error).split(': ', 1)[1]}, the nameplate's range (a typo or a unit slip?)")
        return float(v)

    R_s, psi_f = value("R_s_ohm", plate.R_s_ohm), value("psi_f_Wb", plate.psi_f_Wb)
    if "J_kgm2" not in plant and not math.isfinite(plate.J_kgm2):
        fail("J_kgm2", "missing: the nameplate gives no inertia, and a simulated shaft needs one")
    J = value("J_kgm2", plate.J_kgm2)
    B = value("B_Nms", plate.B_Nms if math.isfinite(plate.B_Nms) else 0.0, low_inclusive=True)
    L_q = value("L_q_H", plate.L_q_H)
    L_qh = value("L_qh_H", L_q)
    if L_qh > L_q:
        fail("L_qh_H", f"{L_qh:g} H exceeds the unsaturated L_q_H {L_q:g} H: saturation lowers the incremental "
                       f"inductance")
    q_drop = value("L_qh_drop_at_rated", 0.0, low_inclusive=True, high=0.9)
    if "L_dh_drop_at_rated" in plant:
        if "L_d_H" in plant:
            fail("L_dh_drop_at_rated", "give L_d_H (unsaturated) or L_dh_drop_at_rated, not both")
        L_dh = value("L_dh_H", plate.L_d_H)
        L_d, a_d = _d_axis_saturation(L_dh, psi_f, plate.rated_current_A,
                                      value("L_dh_drop_at_rated", 0.0, high=0.9))
        _, a_q, a_dq = _spmsm_saturation(L_d, L_q, L_dh, L_qh, psi_f, L_qh * plate.rated_current_A, q_drop)
    else:
        L_d = value("L_d_H", plate.L_d_H)
        L_dh = value("L_dh_H", L_d)
        if L_dh > L_d:
            fail("L_dh_H", f"{L_dh:g} H exceeds the unsaturated L_d_H {L_d:g} H: saturation lowers the incremental "
                           f"inductance (or give L_dh_drop_at_rated)")
        a_d, a_q, a_dq = _spmsm_saturation(L_d, L_q, L_dh, L_qh, psi_f, L_qh * plate.rated_current_A, q_drop)
    source = plant.get("source", motor.description or motor.source)
    if not isinstance(source, str):
        fail("source", "must be text (where the simulated motor's values come from)")
    assumptions = plant.get("assumptions") or []
    if not isinstance(assumptions, list) or not all(isinstance(a, str) for a in assumptions):
        fail("assumptions", "must be a list of sentences")
    machine = MachineParams(n_p=plate.n_p, R_s_ohm=R_s, L_d_H=L_d, L_q_H=L_q, psi_f_Wb=psi_f,
                            a_d=a_d, a_q=a_q, a_dq=a_dq, C_th_J_K=value("C_th_J_K", 0.0, low_inclusive=True),
                            R_th_K_W=value("R_th_K_W", 1.0), T_ambient_degC=value("T_ambient_degC", 20.0, -60.0, True))
    link = {key: getattr(motor.inverter, key) for key in ("C_dc_F", "R_brake_ohm", "U_brake_on_V", "U_brake_off_V")}
    inverter = InverterParams(U_dc_V=motor.inverter.U_dc_V, t_dead_s=value("t_dead_s", DEFAULT_DEAD_TIME_S, 0.0, True),
                              i_dead_A=value("i_dead_A", DEFAULT_DEAD_CURRENT_A),
                              delay_periods=motor.inverter.delay_periods, **link)
    return MotorPreset(name=motor.name, machine=machine, nameplate=plate,
                       mechanics=MechanicsParams(J_kgm2=J, B_Nms=B), inverter=inverter,
                       sensor=_sensor(plant.get("sensor") or {}, plate, fail),
                       source=source, assumptions=tuple(assumptions))


def _refuse_typos(given, known, prefix, fail):
    """``fail`` on the first unknown key of ``given``, naming the nearest known one (refuse_unknown_keys)."""
    try:
        refuse_unknown_keys(given, known, prefix)
    except ValueError as error:
        fail(*str(error).split(": ", 1))


def _sensor(given, plate, fail):
    """SensorParams of a plant section's ``sensor`` mapping, with the defaults stated above."""
    if not isinstance(given, dict):
        fail("sensor", f"must be a mapping ({', '.join(SENSOR_KEYS)})")
    _refuse_typos(given, SENSOR_KEYS, "sensor.", fail)

    def checked(key, v):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            fail(f"sensor.{key}", f"must be a finite number, not {shown(v)}")
        if (key == "adc_bits" and (v != int(v) or not 0 <= v <= 24)) or \
                (key.startswith(("gain", "adc_range")) and v <= 0.0) or (key == "noise_std_A" and v < 0.0):
            fail(f"sensor.{key}", f"out of range: {shown(v)}")
        return v

    adc_range = checked("adc_range_A", given.get("adc_range_A", ADC_RANGE_PER_CURRENT_LIMIT * plate.current_limit_A))
    defaults = {"noise_std_A": NOISE_PER_ADC_RANGE * adc_range, "adc_bits": DEFAULT_ADC_BITS, "adc_range_A": adc_range,
                **{f"offset_{x}_A": 0.0 for x in "abc"}, **{f"gain_{x}": 1.0 for x in "abc"}}
    values = {key: checked(key, given.get(key, default)) for key, default in defaults.items()}
    return SensorParams(**{key: (int(values[key]) if key == "adc_bits" else float(values[key])) for key in SENSOR_KEYS})


PRESETS = {name: plant_truth(name, "shipped motor") for name in shipped_motor_names()}


def get_preset(motor):
    """The MotorPreset of a shipped motor's name, a motor file's path or a Motor; MotorFileError names the
    known ones."""
    if isinstance(motor, str) and motor in PRESETS:
        return PRESETS[motor]
    return plant_truth(motor)


def plant_parameters(preset, non_idealities, deviation=None):
    """(machine, mechanics, inverter, sensor) of a preset with each non-ideality switched on or off and
    the scenario's ``deviation`` of the plant from the preset (drive_common.config.experiment.DEVIATION_KEYS:
    factors, sensor offsets added in A) applied.

    Keys of non_idealities: saturation, dead_time, delay, sensor_noise, sensor_offset_gain, adc. Without
    saturation the machine is linear with its unsaturated inductances (a round rotor for ``wang_spmsm``).
    """
    d = {**NO_DEVIATION, **(deviation or {})}
    machine = scaled_flux_map(preset.machine, d["L_d"], d["L_q"], d["psi_f"])._replace(
        R_s_ohm=preset.machine.R_s_ohm * d["R_s"])
    mechanics = preset.mechanics._replace(J_kgm2=preset.mechanics.J_kgm2 * d["J"],
                                          B_Nms=preset.mechanics.B_Nms * d["friction"])
    inverter = preset.inverter._replace(t_dead_s=preset.inverter.t_dead_s * d["dead_time"])
    sensor = preset.sensor._replace(**{f"gain_{x}": getattr(preset.sensor, f"gain_{x}") * d[f"sensor_gain_{x}"]
                                       for x in "abc"},
                                    **{f"offset_{x}_A": getattr(preset.sensor, f"offset_{x}_A")
                                       + d[f"sensor_offset_{x}"] for x in "abc"})
    if not non_idealities["saturation"]:
        machine = machine._replace(a_d=0.0, a_q=0.0, a_dq=0.0)
    if not non_idealities["dead_time"]:
        inverter = inverter._replace(t_dead_s=0.0)
    if not non_idealities["delay"]:
        inverter = inverter._replace(delay_periods=0)
    if not non_idealities["sensor_noise"]:
        sensor = sensor._replace(noise_std_A=0.0)
    if not non_idealities["sensor_offset_gain"]:
        sensor = sensor._replace(offset_a_A=0.0, offset_b_A=0.0, offset_c_A=0.0,
                                 gain_a=1.0, gain_b=1.0, gain_c=1.0)
    if not non_idealities["adc"]:
        sensor = sensor._replace(adc_bits=0)
    return machine, mechanics, inverter, sensor


def scaled_flux_map(machine, k_d, k_q, k_f):
    """MachineParams whose whole flux map is scaled: the magnetic energy becomes
    W'(ψ) = c·W(ψ_d/a, ψ_q/b) with a = k_f, c = k_f²/k_d, b = k_f·√(k_q/k_d). It stays a gradient (the
    incremental inductance matrix symmetric), the magnet flux becomes k_f·ψ_f and, at corresponding
    operating points (ψ' = (aψ_d, bψ_q), currents scaled by c/a and c/b), the incremental inductances are
    k_d and k_q times the preset's: saturation and cross-saturation move with the map."""
    a, c = k_f, k_f * k_f / k_d
    b = k_f * (k_q / k_d) ** 0.5
    return machine._replace(L_d_H=machine.L_d_H * k_d, L_q_H=machine.L_q_H * k_q, psi_f_Wb=machine.psi_f_Wb * k_f,
                            a_d=machine.a_d * c / a ** 6, a_q=machine.a_q * c / b ** 4,
                            a_dq=machine.a_dq * c / (a ** 3 * b * b))
