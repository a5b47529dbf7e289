"""Motor presets: the papers' machines as the simulator integrates them, with every assumption written
down where the paper is silent.

A preset holds the true plant (``machine``: saturation included; mechanics, inverter, sensors) beside the
``nameplate`` a user would know from the datasheet (``motor_params.nameplate``, what the drive is told).
The two are kept apart on purpose: only the plant reads the truth.
"""
from dataclasses import dataclass, field

from drive_scenarios.scenario import NO_DEVIATION
from motor_params.nameplate import NAMEPLATES, Nameplate

from .params import InverterParams, MachineParams, MechanicsParams, SensorParams


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


def _spmsm_saturation(L_0_H, L_dh0_H, L_qh0_H, psi_f_Wb, psi_q_rated_Wb, L_qh_drop_rated):
    """Saturation coefficients (a_d, a_q, a_dq) of MachineParams for a round-rotor SPMSM.

    The geometric (unsaturated) inductance L_0 is the same on both axes; at no load the magnet flux
    saturates the iron so the incremental inductances are L_dh0 < L_qh0 < L_0 (saturation saliency):
    5 a_d ψ_f⁴ = 1/L_dh0 − 1/L_0 and (a_dq/3) ψ_f³ = 1/L_qh0 − 1/L_0. The q-axis self-saturation
    makes L_qh fall by the fraction L_qh_drop_rated at the rated q flux: 3 a_q ψ_q² = (1/(1−drop) − 1)/L_qh0.
    """
    a_d = (1.0 / L_dh0_H - 1.0 / L_0_H) / (5.0 * psi_f_Wb ** 4)
    a_dq = 3.0 * (1.0 / L_qh0_H - 1.0 / L_0_H) / psi_f_Wb ** 3
    a_q = (1.0 / (1.0 - L_qh_drop_rated) - 1.0) / L_qh0_H / (3.0 * psi_q_rated_Wb ** 2)
    return a_d, a_q, a_dq


def _d_axis_saturation(L_dh0_H, psi_f_Wb, i_rated_A, L_dh_drop_rated):
    """(L_0, a_d) of MachineParams for a d axis that the magnet saturates: incremental L_dh0 at no load
    (ψ_d = ψ_f), falling by the fraction L_dh_drop_rated at ψ_d = ψ_f + L_dh0·i_rated (rated
    magnetising d current) and rising towards L_0 on the demagnetising side: 1/L_dh(ψ) = 1/L_0 + 5 a_d ψ⁴."""
    psi_high = psi_f_Wb + L_dh0_H * i_rated_A
    a_d = (1.0 / ((1.0 - L_dh_drop_rated) * L_dh0_H) - 1.0 / L_dh0_H) / (5.0 * (psi_high ** 4 - psi_f_Wb ** 4))
    return 1.0 / (1.0 / L_dh0_H - 5.0 * a_d * psi_f_Wb ** 4), a_d


def _wang_spmsm():
    nameplate = NAMEPLATES["wang_spmsm"]
    psi_f = nameplate.psi_f_Wb
    a_d, a_q, a_dq = _spmsm_saturation(L_0_H=0.97e-3, L_dh0_H=0.84e-3, L_qh0_H=0.96e-3,
                                       psi_f_Wb=psi_f, psi_q_rated_Wb=0.96e-3 * nameplate.rated_current_A,
                                       L_qh_drop_rated=0.05)
    return MotorPreset(
        name="wang_spmsm",
        machine=MachineParams(n_p=nameplate.n_p, R_s_ohm=0.27, L_d_H=0.97e-3, L_q_H=0.97e-3, psi_f_Wb=psi_f,
                              a_d=a_d, a_q=a_q, a_dq=a_dq),
        nameplate=nameplate,
        mechanics=MechanicsParams(J_kgm2=4.0e-4, B_Nms=1.0e-5),
        inverter=InverterParams(U_dc_V=24.0, t_dead_s=0.5e-6, i_dead_A=0.05, delay_periods=1),
        sensor=SensorParams(noise_std_A=0.01, offset_a_A=0.005, offset_b_A=-0.004, offset_c_A=0.003,
                            gain_a=1.002, gain_b=0.998, gain_c=1.0, adc_bits=12, adc_range_A=10.0),
        source="Wang et al. 2019, §III-C and §IV: 70 W, 24 V, 4.6 A, 2 pole pairs, 0.27 Ω, 0.9 mH SPMSM",
        assumptions=(
            "rated speed 3000 rpm (not given) → rated torque 0.223 N·m and ψ_f = 16.2 mWb from "
            "τ = 1.5·p·ψ_f·i with 4.6 A taken as the peak phase current",
            "0.9 mH is the nameplate inductance; the true rotor is round (L_0 = 0.97 mH both axes) and the "
            "magnet saturates the iron: incremental L_dh = 0.84 mH, L_qh = 0.96 mH at no load "
            "(Σ/Δ ≈ 15, as in docs/hf-demodulation.md)",
            "cross-saturation from the same magnetic energy turns the HF saliency axis by 0.088 rad at "
            "rated q-current (0.032 rad at half); L_qh falls 4.8 % at rated current",
            "J = 4e-4 kg·m²: motor ≈ 0.5e-4 plus coupling and magnetic-powder brake (Wang Fig. 10); "
            "B = 1e-5 N·m·s",
            "U_dc = 24 V (the rated voltage); MOSFET dead time 0.5 µs",
            "current sensing: 12-bit ADC over ±10 A, 10 mA rms noise, offsets of a few mA, gain errors ±0.2 %",
        ),
    )


def _szabo_ipmsm():
    L_0, a_d = _d_axis_saturation(L_dh0_H=20.025e-3, psi_f_Wb=0.305, i_rated_A=2.53, L_dh_drop_rated=0.1)
    return MotorPreset(
        name="szabo_ipmsm",
        machine=MachineParams(n_p=3, R_s_ohm=6.2, L_d_H=L_0, L_q_H=40.17e-3, psi_f_Wb=0.305, a_d=a_d),
        nameplate=NAMEPLATES["szabo_ipmsm"],
        mechanics=MechanicsParams(J_kgm2=3.5e-3, B_Nms=0.0011),
        inverter=InverterParams(U_dc_V=560.0, t_dead_s=1.5e-6, i_dead_A=0.05, delay_periods=1),
        sensor=SensorParams(noise_std_A=0.005, offset_a_A=0.004, offset_b_A=-0.003, offset_c_A=0.002,
                            gain_a=1.002, gain_b=0.998, gain_c=1.0, adc_bits=12, adc_range_A=8.0),
        source="Szabó & Veszprémi, Table 1: 1.1 kW, 400 V, 2.53 A, 6.2 Ω, L_d 20.025 mH, L_q 40.17 mH, "
               "ψ_p 0.305 V·s, p = 3, F = 0.0011 N·m·s, m_n = 3.5 N·m",
        assumptions=(
            "the saliency is geometric, as in the paper (L_q 40.17 mH linear, no cross-saturation); the "
            "paper's model is linear, but a real IPMSM's d axis is saturated by its magnet, and without that "
            "no standstill test can tell the magnet's polarity: L_dh = 20.025 mH at no load (the paper's "
            "L_d), 10 % lower at rated magnetising d current, 23.0 mH unsaturated",
            "2.53 A is the peak phase current: 1.5·3·0.305·2.53 = 3.47 N·m ≈ m_n",
            "rated speed 3000 rpm: §3 gives a nominal mechanical frequency of 50 Hz (1.1 kW / 314 rad/s = 3.5 N·m)",
            "J = 3.5e-3 kg·m²: with the speed-loop rule of foc_controller.tuning, Table 2's speed PI "
            "(A_p 0.287, T_i 36 ms) then has damping 1 and ω_n ≈ 55 rad/s",
            "U_dc = 560 V (400 V three-phase rectified); IGBT dead time 1.5 µs",
            "current sensing: 12-bit ADC over ±8 A, 5 mA rms noise, offsets of a few mA, gain errors ±0.2 %",
        ),
    )


PRESETS = {"wang_spmsm": _wang_spmsm(), "szabo_ipmsm": _szabo_ipmsm()}


def get_preset(name):
    """The preset called ``name``; KeyError names the known ones."""
    try:
        return PRESETS[name]
    except KeyError:
        raise KeyError(f"unknown motor preset '{name}' (known: {', '.join(sorted(PRESETS))})") from None


def plant_parameters(preset, non_idealities, deviation=None):
    """(machine, mechanics, inverter, sensor) of a preset with each non-ideality switched on or off and
    the scenario's ``deviation`` of the plant from the preset (drive_scenarios.scenario.DEVIATION_KEYS:
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
