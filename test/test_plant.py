"""Plant physics against analytic solutions: RL step, exact ZOH response to HF injection, short-circuit
(back-EMF) currents, torque, saturation, inverter limits and current sensing."""
import math

import numpy as np
import pytest
from scipy.linalg import expm

from drive_common.math.command_delay import command_line, issue_command
from drive_common.math.frames import clarke, inverse_clarke, rotate, wrap
from pmsm_plant.model import (
    N_STATE,
    OMEGA_M,
    PSI_ALPHA,
    PSI_BETA,
    current_from_flux,
    duty_cycles,
    flux_from_current,
    incremental_inductances,
    inverter_voltage,
    plant_advance,
    plant_block,
    plant_outputs,
    plant_reset,
    sense_currents,
)
from pmsm_plant.params import IDEAL_SENSOR, InverterParams, MechanicsParams, PlantInputs, PlantParams, SensorParams
from pmsm_plant.presets import PRESETS, plant_parameters

pytestmark = pytest.mark.unit

SZABO = PRESETS["szabo_ipmsm"]
SZABO = SZABO.__class__(**{**SZABO.__dict__, "machine": SZABO.machine._replace(a_d=0.0)})
"""The IPMSM with its linear magnetics (the analytic models below are linear; the preset's d-axis
saturation is tested in test_startup.py through the polarity it reveals)."""
WANG = PRESETS["wang_spmsm"]
IDEAL_INVERTER = InverterParams(U_dc_V=1000.0, t_dead_s=0.0, i_dead_A=0.05, delay_periods=0)
MECH = MechanicsParams(J_kgm2=1e-3, B_Nms=0.0)
T_S = 1e-4


def _alpha_beta_current(x, machine):
    i_a, i_b, i_c, _ = plant_outputs(x, machine)
    return clarke(i_a, i_b, i_c)


@pytest.mark.parametrize("axis", ["d", "q"])
def test_rl_current_step_matches_analytic(axis):
    """A voltage step on one rotor axis at standstill: i = U/R (1 − e^{−tR/L}) within 1e-7 of U/R."""
    m = SZABO.machine
    x = np.zeros(N_STATE)
    plant_reset(x, 0.0, 0.0, m)
    U = 20.0
    u_alpha, u_beta = (U, 0.0) if axis == "d" else (0.0, U)
    L = m.L_d_H if axis == "d" else m.L_q_H
    worst = 0.0
    for k in range(1, 400):
        plant_advance(x, u_alpha, u_beta, 0.0, True, 0.0, PlantParams(m, MECH, IDEAL_INVERTER, IDEAL_SENSOR, 0, T_S, 1))
        i_alpha, i_beta = _alpha_beta_current(x, m)
        i = i_alpha if axis == "d" else i_beta
        expected = U / m.R_s_ohm * (1.0 - math.exp(-k * T_S * m.R_s_ohm / L))
        worst = max(worst, abs(i - expected))
    assert worst < 1e-7 * U / m.R_s_ohm


def _exact_zoh_response(machine, theta_e, voltages):
    """Exact sampled currents of the linear R-L stator at standstill under ZOH voltages (αβ)."""
    L_dq = np.diag([machine.L_d_H, machine.L_q_H])
    rot = np.array([[math.cos(theta_e), -math.sin(theta_e)], [math.sin(theta_e), math.cos(theta_e)]])
    L_inv = np.linalg.inv(rot @ L_dq @ rot.T)
    aug = np.zeros((4, 4))
    aug[:2, :2] = -L_inv * machine.R_s_ohm
    aug[:2, 2:] = L_inv
    phi = expm(aug * T_S)
    a, b = phi[:2, :2], phi[:2, 2:]
    i = np.zeros(2)
    out = []
    for u in voltages:
        i = a @ i + b @ u
        out.append(i.copy())
    return np.array(out)


@pytest.mark.parametrize("f_h", [1500.0, 2500.0, 4000.0])
def test_hf_injection_is_integrated_exactly_at_standstill(f_h):
    """Pulsating HF injection (ZOH at 10 kHz) on a salient rotor: the plant's samples equal the exact
    discrete-time solution within 1e-7 of the HF current amplitude."""
    m = SZABO.machine
    theta_m = 0.13
    theta_e = m.n_p * theta_m
    x = np.zeros(N_STATE)
    plant_reset(x, theta_m, 0.0, m)
    U_h, theta_i = 40.0, theta_e - 0.3
    n = 300
    carrier = U_h * np.cos(2.0 * np.pi * f_h * T_S * np.arange(n))
    voltages = np.stack([carrier * math.cos(theta_i), carrier * math.sin(theta_i)], axis=1)
    expected = _exact_zoh_response(m, theta_e, voltages)
    got = []
    for u in voltages:
        plant_advance(x, u[0], u[1], 0.0, True, 0.0, PlantParams(m, MECH, IDEAL_INVERTER, IDEAL_SENSOR, 0, T_S, 1))
        got.append(_alpha_beta_current(x, m))
    amplitude = np.max(np.abs(expected))
    assert np.max(np.abs(np.array(got) - expected)) < 1e-7 * amplitude


def test_hf_integration_converged_at_speed_with_saturation():
    """Saturated SPMSM at 3000 rpm with 1 kHz injection and dead time: one RK4 step per period agrees
    with a 64-substep reference within 1e-5 of the HF current amplitude."""
    machine, _, inverter, _ = plant_parameters(WANG, {k: True for k in
                                                   ("saturation", "dead_time", "delay", "sensor_noise",
                                                    "sensor_offset_gain", "adc")})
    omega_m = 3000.0 * 2.0 * math.pi / 60.0
    runs = []
    for substeps in (1, 64):
        x = np.zeros(N_STATE)
        plant_reset(x, 0.0, omega_m, machine)
        currents = []
        for k in range(400):
            theta_e = machine.n_p * omega_m * k * T_S
            u_d = 5.0 * math.cos(2.0 * math.pi * 1000.0 * k * T_S)
            u_alpha, u_beta = rotate(u_d + 0.3, omega_m * machine.n_p * machine.psi_f_Wb, theta_e)
            plant_advance(x, u_alpha, u_beta, 0.0, True, omega_m,
                          PlantParams(machine, WANG.mechanics, inverter, IDEAL_SENSOR, 0, T_S, substeps))
            currents.append(_alpha_beta_current(x, machine))
        runs.append(np.array(currents))
    hf_amplitude = 5.0 / (2.0 * math.pi * 1000.0 * 0.9e-3)
    assert np.max(np.abs(runs[0] - runs[1])) < 1e-5 * hf_amplitude


def test_short_circuit_currents_match_back_emf_model():
    """Shorted terminals at an imposed speed: steady currents solve 0 = R i + jω L i + jω ψ_f."""
    m = SZABO.machine
    omega_m = 50.0
    w = m.n_p * omega_m
    x = np.zeros(N_STATE)
    plant_reset(x, 0.0, omega_m, m)
    for _ in range(3000):
        plant_advance(x, 0.0, 0.0, 0.0, True, omega_m, PlantParams(m, MECH, IDEAL_INVERTER, IDEAL_SENSOR, 0, T_S, 1))
    i_alpha, i_beta = _alpha_beta_current(x, m)
    theta_e = m.n_p * (3000 * T_S * omega_m)
    i_d, i_q = rotate(i_alpha, i_beta, -theta_e)
    den = m.R_s_ohm ** 2 + w ** 2 * m.L_d_H * m.L_q_H
    assert i_d == pytest.approx(-w ** 2 * m.L_q_H * m.psi_f_Wb / den, rel=1e-5)
    assert i_q == pytest.approx(-w * m.psi_f_Wb * m.R_s_ohm / den, rel=1e-5)


def test_open_circuit_flux_rotates_with_back_emf_amplitude():
    """With i = 0 imposed by the matching voltage, |dψ/dt| = ω_e ψ_f (back-EMF) within 1e-6."""
    m = SZABO.machine
    omega_m = 80.0
    w = m.n_p * omega_m
    x = np.zeros(N_STATE)
    plant_reset(x, 0.0, omega_m, m)
    k = 50
    theta_mid = m.n_p * omega_m * (k + 0.5) * T_S
    psi_before = np.array(rotate(m.psi_f_Wb, 0.0, m.n_p * omega_m * k * T_S))
    psi_after = np.array(rotate(m.psi_f_Wb, 0.0, m.n_p * omega_m * (k + 1) * T_S))
    emf = (psi_after - psi_before) / T_S
    assert np.hypot(*emf) == pytest.approx(2.0 * m.psi_f_Wb * math.sin(w * T_S / 2) / T_S, rel=1e-12)
    x[PSI_ALPHA], x[PSI_BETA] = psi_before
    x[3] = omega_m * k * T_S
    plant_advance(x, emf[0], emf[1], 0.0, True, omega_m, PlantParams(m, MECH, IDEAL_INVERTER, IDEAL_SENSOR, 0, T_S, 8))
    assert np.hypot(*_alpha_beta_current(x, m)) < 2e-3
    assert np.hypot(*emf) == pytest.approx(w * m.psi_f_Wb, rel=1e-3)
    assert theta_mid > 0.0


def test_torque_formula_and_mechanics():
    """τ_e = 1.5 p (ψ_f i_q + (L_d − L_q) i_d i_q), and the shaft accelerates at τ_e/J."""
    m = SZABO.machine
    i_d, i_q = -1.0, 2.0
    psi_d, psi_q = flux_from_current(m, i_d, i_q)
    theta_m = 0.2
    x = np.zeros(N_STATE)
    plant_reset(x, theta_m, 0.0, m)
    x[PSI_ALPHA], x[PSI_BETA] = rotate(psi_d, psi_q, m.n_p * theta_m)
    _, _, _, tau = plant_outputs(x, m)
    expected = 1.5 * m.n_p * (m.psi_f_Wb * i_q + (m.L_d_H - m.L_q_H) * i_d * i_q)
    assert tau == pytest.approx(expected, rel=1e-12)
    u_alpha, u_beta = rotate(m.R_s_ohm * i_d, m.R_s_ohm * i_q, m.n_p * theta_m)
    dt = 1e-6
    plant_advance(x, u_alpha, u_beta, 0.0, False, 0.0, PlantParams(m, MECH, IDEAL_INVERTER, IDEAL_SENSOR, 0, dt, 1))
    assert x[OMEGA_M] * MECH.J_kgm2 / dt == pytest.approx(expected, rel=1e-3)


def test_wang_saturation_saliency_and_reciprocity():
    """No-load incremental L_dh = 0.84 mH, L_qh = 0.96 mH; Γ symmetric; round rotor without saturation."""
    m = WANG.machine
    L_dh, L_qh, L_dqh = incremental_inductances(m)
    assert L_dh == pytest.approx(0.84e-3, rel=1e-9)
    assert L_qh == pytest.approx(0.96e-3, rel=1e-9)
    assert L_dqh == pytest.approx(0.0, abs=1e-15)
    psi = np.array(flux_from_current(m, -1.0, 3.0))
    h = 1e-7
    jac = np.zeros((2, 2))
    for j in range(2):
        dp = np.zeros(2)
        dp[j] = h
        jac[:, j] = (np.array(current_from_flux(*(psi + dp), m))
                     - np.array(current_from_flux(*(psi - dp), m))) / (2 * h)
    assert jac[0, 1] == pytest.approx(jac[1, 0], rel=1e-6)
    round_rotor = m._replace(a_d=0.0, a_q=0.0, a_dq=0.0)
    L_dh, L_qh, _ = incremental_inductances(round_rotor, 0.0, 4.6)
    assert L_dh == pytest.approx(L_qh, rel=1e-12)


def test_inverter_linear_range_and_limit():
    """Inside the hexagon's circle the averaged voltage equals the command; outside it is clipped
    to at most the hexagon vertex 2U_dc/3, and duties stay in [0, 1]."""
    inv = IDEAL_INVERTER._replace(U_dc_V=24.0)
    limit = 24.0 / math.sqrt(3.0)
    for angle in np.linspace(0, 2 * math.pi, 37):
        u_alpha, u_beta = rotate(0.999 * limit, 0.0, angle)
        d = duty_cycles(u_alpha, u_beta, inv.U_dc_V)
        assert all(0.0 <= di <= 1.0 for di in d)
        realised = inverter_voltage(*d, 0.0, 0.0, inv, T_S, inv.U_dc_V)
        assert realised == pytest.approx((u_alpha, u_beta), abs=1e-12)
        d = duty_cycles(*rotate(3.0 * limit, 0.0, angle), inv.U_dc_V)
        assert all(0.0 <= di <= 1.0 for di in d)
        assert math.hypot(*inverter_voltage(*d, 0.0, 0.0, inv, T_S, inv.U_dc_V)) <= 2.0 / 3.0 * 24.0 + 1e-12


def test_dead_time_error_opposes_current():
    """Dead time lowers the voltage along a large current by (4/3)(t_d/T_s) U_dc·(phase geometry)."""
    inv = InverterParams(U_dc_V=24.0, t_dead_s=1e-6, i_dead_A=0.05, delay_periods=0)
    d = duty_cycles(0.0, 0.0, inv.U_dc_V)
    u_alpha, u_beta = inverter_voltage(*d, 10.0, 0.0, inv, T_S, inv.U_dc_V)
    i_a, i_b, i_c = inverse_clarke(10.0, 0.0)
    signs = np.tanh(np.array([i_a, i_b, i_c]) / inv.i_dead_A)
    expected = clarke(*(-1e-6 / T_S * 24.0 * signs))
    assert (u_alpha, u_beta) == pytest.approx(expected, abs=1e-12)
    assert u_alpha == pytest.approx(-4.0 / 3.0 * 0.01 * 24.0, rel=1e-6)


def test_current_sensing_noise_offset_gain_quantisation():
    s = SensorParams(noise_std_A=0.02, offset_a_A=0.01, offset_b_A=0.0, offset_c_A=0.0, gain_a=1.05,
                     gain_b=1.0, gain_c=1.0, adc_bits=12, adc_range_A=10.0)
    lsb = 20.0 / 4096
    samples = np.array([sense_currents(1.0, 0.0, -1.0, s, 7, k) for k in range(20000)])
    assert np.mean(samples[:, 0]) == pytest.approx(1.06, abs=0.002)
    assert np.std(samples[:, 1]) == pytest.approx(0.02, rel=0.05)
    assert np.allclose(np.round(samples / lsb) * lsb, samples, atol=1e-12)
    again = np.array([sense_currents(1.0, 0.0, -1.0, s, 7, k) for k in range(100)])
    assert np.array_equal(again, samples[:100])
    clipped = sense_currents(50.0, -50.0, 0.0, s._replace(noise_std_A=0.0, gain_a=1.0,
                                                         offset_a_A=0.0), 7, 0)
    assert clipped[0] == pytest.approx(10.0 - lsb) and clipped[1] == pytest.approx(-10.0)


def test_wrap_range():
    for angle in (-7.0, -math.pi, 0.0, math.pi, 3 * math.pi + 0.1):
        w = wrap(angle)
        assert -math.pi < w <= math.pi
        assert math.isclose(math.cos(w), math.cos(angle), abs_tol=1e-12)


@pytest.mark.parametrize("block", [1, 5])
def test_a_block_applies_each_command_n_periods_later(block):
    """With blocks of N samples the delay line holds d = N periods (the inverter's one plus N − 1): a lone
    command answering sample 3 first moves the current at sample 3 + N + 1, and every block is simulated
    from the commands of earlier blocks alone."""
    inverter = IDEAL_INVERTER._replace(delay_periods=block)
    params = PlantParams(WANG.machine, MECH, inverter, IDEAL_SENSOR, 0, T_S, 1)
    x, line = np.zeros(N_STATE), command_line(inverter.delay_periods)
    plant_reset(x, 0.0, 0.0, WANG.machine)
    n = 4 * block + 8
    zeros, out, measured = np.zeros(n), np.zeros((block, 10)), np.zeros(n)
    for k0 in range(0, n, block):
        count = min(block, n - k0)
        plant_block(x, line, k0, count, PlantInputs(zeros, zeros, True, -1), params, out)
        measured[k0:k0 + count] = out[:count, 3]
        for k in range(k0, k0 + count):
            issue_command(line, k, 10.0 if k == 3 else 0.0, 0.0)
    first = int(np.flatnonzero(np.abs(measured) > 1e-9)[0])
    assert first == 3 + block + 1
