"""Protections (docs/protections.md): the DC link as a capacitor fed by a supply that cannot absorb, with
a brake chopper; the winding's temperature and R_s(T); the inverter's safe states at speed (freewheel,
active short circuit) in the plant."""
import dataclasses
import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from drive_bridge.inverter_protocol import FREEWHEELING, OVERVOLTAGE, PWM_OFF, SAFE_AUTO, SHORT_CIRCUIT
from drive_common.config.experiment import NON_IDEALITIES, Table
from drive_common.config.scenario import load_scenario
from drive_common.contract.drive_records import commands, drive_inputs
from drive_common.contract.estimator_records import ESTIMATE, SAMPLE, estimates
from drive_common.contract.estimator_states import TRACKING
from drive_common.contract.exit_codes import EXIT_TRIPPED
from drive_common.math.copper import COPPER_ALPHA_PER_K
from drive_common.math.current_sensing import CurrentCalibration
from drive_common.math.frames import clarke, rotate
from drive_common.math.safe_state import ASC, FREEWHEEL, safe_state_for
from drive_common.math.winding import R_S_IN_USE, R_S_STEP, winding_estimate
from drive_common.motor.commissioning import nameplate_commissioning
from drive_common.motor.motor_file import MotorFileError, load_motor, motor_path
from drive_common.motor.nameplate import InverterRating
from drive_tools.cli.outcome import exit_code, tripped
from drive_tools.doubles.virtual_inverter import VirtualInverter
from drive_tools.evaluation.run_report import protection_line, run_report
from drive_tools.runner.runner import run_scenario
from foc_controller.control import REGEN_CUT, controller_state, controller_step
from foc_controller.params import make_controller_params
from foc_controller.protection import make_protection_params, protection_block, protection_state
from hf_estimator.flux_observer import flux_observer_step, make_flux_observer
from pmsm_plant.model import (
    INVERTER_MODE,
    N_STATE,
    OMEGA_M,
    THETA_M,
    WINDING_RISE,
    bus_voltage,
    plant_advance,
    plant_outputs,
    plant_reset,
    winding_resistance,
)
from pmsm_plant.params import IDEAL_SENSOR, InverterParams, PlantParams
from pmsm_plant.presets import PRESETS, plant_truth

pytestmark = pytest.mark.unit

WANG = PRESETS["wang_spmsm"]
MACHINE = WANG.machine._replace(a_d=0.0, a_q=0.0, a_dq=0.0)
"""The Wang SPMSM, linear (the analytic short-circuit current below is the linear machine's)."""
T_S = 1e-4
RATED_OMEGA_M = 3000.0 * math.pi / 30.0
LOW_BUS = InverterParams(U_dc_V=12.0, t_dead_s=0.0, i_dead_A=0.05, delay_periods=0, C_dc_F=1e-3)
"""A 12 V, 1 mF link: the Wang motor's back-EMF at rated speed (√3·ω_e·ψ_f = 17.6 V line-to-line
peak) exceeds it."""


def _spin(inv, mode, omega_m, periods, machine=MACHINE):
    """The plant at an imposed shaft speed with its inverter in ``mode`` for ``periods``: (state, peak
    bus [V])."""
    x = np.zeros(N_STATE)
    plant_reset(x, 0.0, omega_m, machine)
    x[INVERTER_MODE] = mode
    peak = 0.0
    for _ in range(periods):
        plant_advance(x, 0.0, 0.0, 0.0, True, omega_m,
                      PlantParams(machine, WANG.mechanics, inv, IDEAL_SENSOR, 0, T_S, 1))
        peak = max(peak, bus_voltage(x, inv))
    return x, peak


def _dq_current(x, machine=MACHINE):
    i_a, i_b, i_c, _ = plant_outputs(x, machine)
    return rotate(*clarke(i_a, i_b, i_c), -machine.n_p * x[THETA_M])


def test_freewheel_at_rated_speed_rectifies_the_back_emf_into_the_bus():
    """All switches off at rated speed with a back-EMF above the 12 V bus: the diodes charge the link to
    the back-EMF's line-to-line peak √3·ω_e·ψ_f (17.6 V; within 5 %), far above the supply."""
    emf_peak = math.sqrt(3.0) * MACHINE.n_p * RATED_OMEGA_M * MACHINE.psi_f_Wb
    x, peak = _spin(LOW_BUS, FREEWHEEL, RATED_OMEGA_M, 300)
    assert bus_voltage(x, LOW_BUS) == pytest.approx(emf_peak, rel=0.05)
    assert peak < 1.05 * emf_peak


def test_active_short_circuit_keeps_the_bus_and_carries_the_short_circuit_current():
    """ASC at rated speed: the bus stays at the supply's 12 V and the current settles at the short circuit
    of the back-EMF, i_d = −ψ_f ω²L/(R² + ω²L²), i_q = −ψ_f ωR/(R² + ω²L²) (within 1 %); its magnitude
    approaches ψ_f/L_d (16.6 A) as ωL ≫ R: here 15.2 A."""
    x, peak = _spin(LOW_BUS, ASC, RATED_OMEGA_M, 500)
    assert peak == LOW_BUS.U_dc_V
    w, R, L, psi = MACHINE.n_p * RATED_OMEGA_M, MACHINE.R_s_ohm, MACHINE.L_d_H, MACHINE.psi_f_Wb
    z2 = R * R + (w * L) ** 2
    i_d, i_q = _dq_current(x)
    assert i_d == pytest.approx(-psi * w * w * L / z2, rel=0.01)
    assert i_q == pytest.approx(-psi * w * R / z2, rel=0.01)
    assert math.hypot(i_d, i_q) == pytest.approx(psi / L, rel=0.1)


def test_freewheel_below_the_bus_leaves_no_current():
    """All switches off at a tenth of rated speed (back-EMF 1.8 V against 12 V): no current (< 1 mA) and
    the bus stays at the supply's (within 1 mV)."""
    x, peak = _spin(LOW_BUS, FREEWHEEL, 0.1 * RATED_OMEGA_M, 300)
    assert math.hypot(*_dq_current(x)) < 1e-3
    assert peak < LOW_BUS.U_dc_V + 1e-3


def test_brake_chopper_holds_the_bus_within_its_hysteresis():
    """The same rectifying freewheel with a 10 Ω chopper switching on above 15 V and off below 14.5 V: the
    bus stays under 16 V (the on-threshold plus the rise of the period the chopper takes to answer, at most
    T_s·i/C = 0.1 V per ampere), against 17.6 V without it, and ends within the hysteresis (±0.8 V)."""
    inv = LOW_BUS._replace(R_brake_ohm=10.0, U_brake_on_V=15.0, U_brake_off_V=14.5)
    x, peak = _spin(inv, FREEWHEEL, RATED_OMEGA_M, 300)
    assert 15.0 < peak < 16.0
    assert 14.5 - 0.8 < bus_voltage(x, inv) < 15.0 + 0.8


def test_stiff_bus_by_default():
    """Without a capacitance the link is the supply's whatever the bridge does (the shipped motors)."""
    inv = LOW_BUS._replace(C_dc_F=math.inf)
    _, peak = _spin(inv, FREEWHEEL, RATED_OMEGA_M, 100)
    assert peak == inv.U_dc_V


def test_winding_heats_by_its_first_order_model_and_its_resistance_follows():
    """A DC current of 2× rated at standstill into a winding of C_th = 2 J/K, R_th = 5 K/W (τ = 10 s): after
    1 s the rise matches the first-order model with R_s(T) integrated alongside (within 1 %), and
    R_s(T) = R_s,20 (1 + 0.00393 (T − 20 °C))."""
    machine = MACHINE._replace(C_th_J_K=2.0, R_th_K_W=5.0, T_ambient_degC=25.0)
    inv = InverterParams(U_dc_V=24.0, t_dead_s=0.0, i_dead_A=0.05, delay_periods=0)
    x = np.zeros(N_STATE)
    plant_reset(x, 0.0, 0.0, machine)
    current = 2.0 * WANG.nameplate.rated_current_A
    T_s = 1e-3
    rise = 0.0
    for _ in range(1000):
        u = winding_resistance(x, machine) * current
        plant_advance(x, u, 0.0, 0.0, True, 0.0, PlantParams(machine, WANG.mechanics, inv, IDEAL_SENSOR, 0, T_s, 1))
        R = machine.R_s_ohm * (1.0 + COPPER_ALPHA_PER_K * (machine.T_ambient_degC + rise - 20.0))
        rise += T_s / machine.C_th_J_K * (1.5 * R * current ** 2 - rise / machine.R_th_K_W)
    assert x[WINDING_RISE] == pytest.approx(rise, rel=0.01)
    assert rise > 5.0
    T = machine.T_ambient_degC + x[WINDING_RISE]
    assert winding_resistance(x, machine) == pytest.approx(machine.R_s_ohm * (1 + 0.00393 * (T - 20.0)), rel=1e-12)


def _command(cx, cz, c, currents, theta_e, omega_e, omega_ref):
    """The controller's voltage command (u_α, u_β) [V] for exact currents [A] and an exact, tracking estimate."""
    inputs, estimate, out = drive_inputs(1)[0], estimates(1)[0], commands(1)[0]
    inputs["i_a_A"], inputs["i_b_A"], inputs["i_c_A"] = currents
    inputs["omega_m_ref_rad_s"] = omega_ref
    estimate["theta_e_hat"], estimate["omega_e_hat"], estimate["state"] = theta_e, omega_e, TRACKING
    controller_step(cx, cz, c, inputs, estimate, CurrentCalibration(1.0, 1.0, 1.0, 0.0, 0.0, 0.0), out)
    return out["u_alpha_V"], out["u_beta_V"]


def _drive_loop(plant_machine, inv, omega_m0, omega_ref, seconds, T_s, protection=None, obey_cut=True,
                imposed=False):
    """The plant under the cascade controller (foc_controller.control) fed the true angle and speed (an
    encoder: the protections, not the estimator, are under test), with the drive's protections
    (``protection``: ProtectionParams) stepped before it each sample; a trip switches the inverter to the
    safe state the drive chose. ``obey_cut`` False: a drive without the over-voltage controller. Returns
    the per-sample arrays bus [V], winding temperature [°C], R_s true and estimated [Ω], T̂ [°C], ω_m
    [rad/s], |i| [A], the trip's safe state (0: none), and the protections' final state."""
    plate = WANG.nameplate
    c = make_controller_params(plate, InverterRating(inv.U_dc_V, 1), T_s)
    cx, cz = controller_state(c)
    ps = protection_state()
    x = np.zeros(N_STATE)
    plant_reset(x, 0.0, omega_m0, plant_machine)
    n = round(seconds / T_s)
    rows = np.zeros((n, 7))
    u = (0.0, 0.0)
    currents = np.zeros((1, 3))
    tripped = 0
    for k in range(n):
        plant_advance(x, u[0], u[1], 0.0, imposed, omega_m0,
                      PlantParams(plant_machine, WANG.mechanics, inv, IDEAL_SENSOR, 0, T_s, 1))
        i_a, i_b, i_c, _ = plant_outputs(x, plant_machine)
        theta_e, omega_e = plate.n_p * x[THETA_M], plate.n_p * x[OMEGA_M]
        U_dc = bus_voltage(x, inv)
        T_hat, R_hat = math.nan, math.nan
        if protection is not None:
            currents[0] = i_a, i_b, i_c
            safe = protection_block(ps, protection, currents, 1, k, U_dc, omega_e, cx)
            if not obey_cut:
                cx[REGEN_CUT] = 0.0
            if safe:
                tripped = safe
                x[INVERTER_MODE] = safe
            T_hat, R_hat = winding_estimate(ps, protection)
        u = _command(cx, cz, c, (i_a, i_b, i_c), theta_e, omega_e, omega_ref)
        rows[k] = (U_dc, plant_machine.T_ambient_degC + x[WINDING_RISE], winding_resistance(x, plant_machine),
                   R_hat, T_hat, x[OMEGA_M], math.hypot(*clarke(i_a, i_b, i_c)))
    return rows, tripped, ps


HOT = MACHINE._replace(C_th_J_K=1.0, R_th_K_W=10.0, T_ambient_degC=25.0)
"""The Wang winding with a thermal time constant shortened to τ = R_th·C_th = 10 s (a test of minutes in
seconds), in a 25 °C ambient."""


def _steady_rise(machine, current_A):
    """The steady temperature rise [K] of the plant's winding at a current amplitude: ΔT = R_th·1.5 R(T) I²
    with R(T) linear in T, solved for ΔT."""
    g = machine.R_th_K_W * 1.5 * current_A ** 2 * machine.R_s_ohm
    return g * (1 + COPPER_ALPHA_PER_K * (machine.T_ambient_degC - 20.0)) / (1.0 - g * COPPER_ALPHA_PER_K)


def test_i2t_foldback_holds_the_winding_under_its_limit_and_tracks_r_s():
    """A locked rotor asked for full torque (the current limit, 6.9 A, would settle the winding above 800 °C):
    over 40 s (4 τ) the I²t foldback holds the plant's winding under the drive's 130 °C limit (it ends at
    128.9 °C, the current folded back to 4.2 A), the drive's estimate T̂ stays within 0.1 K of the plant's
    temperature (0.01 K measured) and R̂_s(T̂) within 0.1 % of the plant's R_s(T), which rises 40 %. The
    drive is told the winding as a datasheet would, here exactly: τ = 10 s, the rise at rated current, the
    ambient; R_s at ambient."""
    plate = WANG.nameplate
    assert HOT.T_ambient_degC + _steady_rise(HOT, plate.current_limit_A) > 800.0
    T_s = 1e-3
    protection = make_protection_params(
        plate, InverterRating(24.0, 1), T_s,
        {"thermal_time_constant_s": HOT.R_th_K_W * HOT.C_th_J_K, "ambient_degC": HOT.T_ambient_degC,
         "rise_at_rated_K": _steady_rise(HOT, plate.rated_current_A), "warning_degC": 120.0, "limit_degC": 130.0})
    protection = protection._replace(R_s_ohm=winding_resistance(np.zeros(N_STATE), HOT))
    inv = InverterParams(U_dc_V=24.0, t_dead_s=0.0, i_dead_A=0.05, delay_periods=0)
    rows, tripped, ps = _drive_loop(HOT, inv, 0.0, 100.0, 40.0, T_s, protection, imposed=True)
    T, R, R_hat, T_hat = rows[:, 1], rows[:, 2], rows[:, 3], rows[:, 4]
    assert tripped == 0
    assert T.max() < 130.0
    assert 120.0 < T[-1] < 130.0
    assert np.max(np.abs(T_hat - T)) < 0.1
    assert np.max(np.abs(R_hat / R - 1.0)) < 0.001
    assert R[-1] / R[0] > 1.35
    assert abs(ps[R_S_IN_USE] / R[-1] - 1.0) <= R_S_STEP


def test_braking_is_limited_by_the_bus_and_an_over_voltage_trips_to_the_safe_state():
    """A stop from 2000 rpm (8.7 J in the shaft) on a 24 V, 1 mF link with no brake resistor (it can take
    0.13 J up to 28.8 V). With the over-voltage controller (braking current cut from 26.4 V, none left at
    28.8 V) the bus peaks under the 30 V trip (29.5 V: the current loops' lag), the drive does not trip
    and the shaft's lost energy is what the link took, the copper and the friction (within 5 %): without a
    brake resistor braking is as slow as that. A drive without it regenerates
    past the 30 V trip; the trip, at a back-EMF under the bus, chooses freewheel and the bus stays within
    6 % of the trip level (the diodes take the winding's magnetic energy, 1.5·½L_d i² = 35 mJ at 6.9 A, into
    the link: 31.6 V), then no further."""
    T_s = 1e-4
    inv = InverterParams(U_dc_V=24.0, t_dead_s=0.0, i_dead_A=0.05, delay_periods=0, C_dc_F=1e-3)
    protection = make_protection_params(WANG.nameplate, InverterRating(24.0, 1), T_s)
    omega0 = 2000.0 * math.pi / 30.0
    rows, tripped, ps = _drive_loop(MACHINE, inv, omega0, 0.0, 0.3, T_s, protection)
    assert tripped == 0
    assert protection.U_ovc_full_V < rows[:, 0].max() < protection.U_overvoltage_V
    bus, omega, current = rows[:, 0], rows[:, 5], rows[:, 6]
    shaft = 0.5 * WANG.mechanics.J_kgm2 * (omega0 ** 2 - omega[-1] ** 2)
    taken = 0.5 * inv.C_dc_F * (bus[-1] ** 2 - inv.U_dc_V ** 2) + T_s * np.sum(
        1.5 * MACHINE.R_s_ohm * current ** 2 + WANG.mechanics.B_Nms * omega ** 2)
    assert taken == pytest.approx(shaft, rel=0.05)
    rows, tripped, ps = _drive_loop(MACHINE, inv, omega0, 0.0, 0.3, T_s, protection, obey_cut=False)
    assert tripped == FREEWHEEL
    assert protection.U_overvoltage_V < rows[:, 0].max() < 1.06 * protection.U_overvoltage_V
    assert rows[-1, 0] - rows[-1000, 0] < 1e-3


def test_safe_state_is_chosen_by_speed_and_bus():
    """ASC from 90 % of the bus in back-EMF (√3·ω_e·ψ_f) on, freewheel below: the Wang motor at rated speed
    (17.6 V) on 12 V is shorted, on 24 V freewheels; at standstill it freewheels."""
    w = MACHINE.n_p * RATED_OMEGA_M
    assert safe_state_for(w, 12.0, MACHINE.psi_f_Wb) == ASC
    assert safe_state_for(-w, 12.0, MACHINE.psi_f_Wb) == ASC
    assert safe_state_for(w, 24.0, MACHINE.psi_f_Wb) == FREEWHEEL
    assert safe_state_for(0.0, 12.0, MACHINE.psi_f_Wb) == FREEWHEEL


def test_motor_file_states_the_link_and_the_plant_section_the_winding(tmp_path):
    """A motor file's inverter keys reach the drive's rating and the plant's inverter, the plant section's
    thermal keys the plant's machine; a brake that switches off above its on-threshold is refused by name."""
    text = Path(motor_path("wang_spmsm")).read_text()
    text = text.replace("  delay_periods: 1\n", "  delay_periods: 1\n  C_dc_F: 1.0e-3\n  R_brake_ohm: 10.0\n"
                        "  U_brake_on_V: 28.0\n  U_brake_off_V: 27.0\n  U_overvoltage_V: 32.0\n", 1)
    text = text.replace("plant:\n", "plant:\n  C_th_J_K: 50.0\n  R_th_K_W: 2.0\n", 1)
    path = tmp_path / "wang_link.yaml"
    path.write_text(text)
    motor = load_motor(str(path))
    assert (motor.inverter.C_dc_F, motor.inverter.U_overvoltage_V) == (1e-3, 32.0)
    preset = plant_truth(motor)
    assert (preset.inverter.C_dc_F, preset.inverter.R_brake_ohm, preset.inverter.U_brake_off_V) == (1e-3, 10.0, 27.0)
    assert (preset.machine.C_th_J_K, preset.machine.R_th_K_W) == (50.0, 2.0)
    assert make_protection_params(motor.nameplate, motor.inverter, 1e-4).U_overvoltage_V == 32.0
    path.write_text(text.replace("U_brake_off_V: 27.0", "U_brake_off_V: 29.0"))
    with pytest.raises(MotorFileError, match="inverter.U_brake_off_V"):
        load_motor(str(path))


def _low_bus_motor(tmp_path):
    """The Wang motor on a 12 V, 1 mF link (trip at 15 V by default): its rated-speed back-EMF exceeds the bus."""
    text = Path(motor_path("wang_spmsm")).read_text()
    text = text.replace("U_dc_V: 24.0", "U_dc_V: 12.0", 1).replace("  delay_periods: 1\n",
                                                                   "  delay_periods: 1\n  C_dc_F: 1.0e-3\n", 1)
    path = tmp_path / "wang_12V.yaml"
    path.write_text(text)
    return load_motor(str(path))


def _stopped_inverter(motor, speed_rad_s, safe_request, periods):
    """A virtual inverter whose drive started and then stopped switching (disabled), its shaft driven at
    ``speed_rad_s``, the host asking for ``safe_request``: per period its status, bus [V] and |i| [A]."""
    scenario = dataclasses.replace(load_scenario("wang_100rpm"), motor=motor, mode="imposed_speed",
                                   speed=Table((0.0,), (speed_rad_s,), "step"), initial_omega_m_rad_s=speed_rad_s,
                                   duration_s=periods * 1e-4, non_idealities=dict.fromkeys(NON_IDEALITIES, False))
    inverter = VirtualInverter(scenario, endpoint=SimpleNamespace(errors={}))
    inverter.started, inverter.safe_request = True, safe_request
    out = np.zeros((1, 10))
    rows = []
    for k in range(periods):
        inverter.simulate(k, 1, out)
        rows.append((inverter.status(), bus_voltage(inverter.plant.x, inverter.plant.inverter),
                     math.hypot(*clarke(*out[0, :3]))))
    return rows


def test_the_virtual_inverter_stops_into_the_safe_state_for_its_speed_and_bus(tmp_path):
    """A virtual inverter stopped at rated speed on a 12 V link (back-EMF 17.6 V). Left to choose
    (SAFE_AUTO) it freewheels, the diodes charge the link past its 15 V trip, it latches OVERVOLTAGE and
    shorts the winding: the bus stays under 16.5 V (a period's rise past the trip) and the current settles
    at the short circuit's 15.2 A (ψ_f/L_d = 16.6 A; within 3 %). Asked for freewheel it obeys and the bus
    rises to the back-EMF's 17.6 V (within 5 %). Asked for ASC it shorts at once: the bus stays at 12 V.
    Stopped at a tenth of rated speed it freewheels with no current (< 1 mA) and no trip."""
    motor = _low_bus_motor(tmp_path)
    rated = RATED_OMEGA_M
    rows = _stopped_inverter(motor, rated, SAFE_AUTO, 600)
    status = [r[0] for r in rows]
    assert status[0] & FREEWHEELING and status[0] & PWM_OFF and not status[0] & OVERVOLTAGE
    tripped = next(k for k, s in enumerate(status) if s & OVERVOLTAGE)
    assert all(s & OVERVOLTAGE and s & SHORT_CIRCUIT for s in status[tripped + 1:])
    assert 15.0 < max(r[1] for r in rows) < 16.5
    assert rows[-1][2] == pytest.approx(15.2, rel=0.03)
    rows = _stopped_inverter(motor, rated, FREEWHEEL, 400)
    assert rows[-1][0] & FREEWHEELING and rows[-1][0] & OVERVOLTAGE
    assert rows[-1][1] == pytest.approx(math.sqrt(3.0) * MACHINE.n_p * rated * MACHINE.psi_f_Wb, rel=0.05)
    rows = _stopped_inverter(motor, rated, ASC, 100)
    assert max(r[1] for r in rows) == 12.0 and rows[-1][0] & SHORT_CIRCUIT
    rows = _stopped_inverter(motor, 0.1 * rated, SAFE_AUTO, 300)
    assert rows[-1][2] < 1e-3 and not any(r[0] & OVERVOLTAGE for r in rows) and rows[-1][0] & FREEWHEELING


def _stop_from_2000_rpm(tmp_path, link_keys):
    """``drive run``'s loop (drive_tools.runner.runner.run_scenario) stopping the Wang motor from 2000 rpm at
    0.05 s on the encoder, its inverter section with ``link_keys`` added: (report metrics, exit code)."""
    text = Path(motor_path("wang_spmsm")).read_text()
    text = text.replace("  delay_periods: 1\n", "  delay_periods: 1\n" + link_keys, 1)
    path = tmp_path / "wang_link.yaml"
    path.write_text(text)
    rpm = 2000.0 * math.pi / 30.0
    scenario = dataclasses.replace(load_scenario("wang_100rpm"), motor=load_motor(str(path)), estimator="sensored",
                                   injection=None, speed=Table((0.0, 0.05), (rpm, 0.0), "step"),
                                   initial_omega_m_rad_s=rpm, duration_s=0.25)
    metrics = run_report(run_scenario(scenario))
    return metrics, exit_code(tripped=tripped(metrics))


def test_drive_run_limits_braking_by_the_bus_or_reports_the_trip(tmp_path):
    """The one-process loop composes the protections: on a 1 mF link the over-voltage controller holds a
    stop from 2000 rpm under the 30 V trip (exit 0, the bus peak in the report); with the trip at 27 V (the
    controller's band then 25.2 … 26.4 V) the current loops' overshoot trips it (exit 7, the report
    names the cause, the time and the safe state: freewheel, the back-EMF being under the bus)."""
    metrics, code = _stop_from_2000_rpm(tmp_path, "  C_dc_F: 1.0e-3\n")
    assert code == 0 and metrics["protection"]["trip"] is None
    assert 26.4 < metrics["protection"]["bus_peak_V"] < 30.0
    metrics, code = _stop_from_2000_rpm(tmp_path, "  C_dc_F: 1.0e-3\n  U_overvoltage_V: 27.0\n")
    trip = metrics["protection"]["trip"]
    assert code == EXIT_TRIPPED and trip["cause"] == "DC-link over-voltage" and trip["safe_state"] == "freewheel"
    assert 0.05 < trip["at_s"] < 0.25
    assert "TRIPPED at" in protection_line(metrics["protection"])


def _observer_angle_error(plant_R_ohm, drive_R_ohm):
    """The back-EMF (flux) observer (hf_estimator.flux_observer) beside the encoder-run loop: the Wang
    winding at ``plant_R_ohm`` and an imposed 1000 rpm, the speed loop asking for more (the current at its
    6.9 A limit); the observer, told the nameplate, fed each sample's currents, the voltage that acted and
    ``drive_R_ohm`` as SAMPLE.R_s_ohm (0: the commissioned R_s). Its mean angle error [rad] over the last
    0.1 s of 0.3 s."""
    plate = WANG.nameplate
    hot = MACHINE._replace(R_s_ohm=plant_R_ohm)
    T_s, omega_m = 1e-4, 1000.0 * math.pi / 30.0
    inv = InverterParams(U_dc_V=24.0, t_dead_s=0.0, i_dead_A=0.05, delay_periods=0)
    c = make_controller_params(plate, InverterRating(24.0, 1), T_s)
    cx, cz = controller_state(c)
    est = make_flux_observer(plate, T_s, {}, nameplate_commissioning(plate), InverterRating(24.0, 1))
    params = est.params._replace(dead_time_voltage_V=0.0)
    state = est.state.copy()
    state["omega"] = state["omega_s"] = plate.n_p * omega_m
    sample, out = np.zeros(1, SAMPLE), np.zeros(1, ESTIMATE)
    sample["R_s_ohm"] = drive_R_ohm
    x = np.zeros(N_STATE)
    plant_reset(x, 0.0, omega_m, hot)
    u, errors = (0.0, 0.0), []
    for k in range(3000):
        plant_advance(x, u[0], u[1], 0.0, True, omega_m, PlantParams(hot, WANG.mechanics, inv, IDEAL_SENSOR, 0, T_s, 1))
        i_a, i_b, i_c, _ = plant_outputs(x, hot)
        sample["i_a"], sample["i_b"], sample["i_c"] = i_a, i_b, i_c
        sample["u_applied_alpha"], sample["u_applied_beta"] = u
        flux_observer_step(state[0], params, k, sample[0], out[0])
        theta_e = plate.n_p * x[THETA_M]
        errors.append(math.remainder(out["theta_e_hat"][0] - theta_e, 2.0 * math.pi))
        u = _command(cx, cz, c, (i_a, i_b, i_c), theta_e, plate.n_p * omega_m, 2.0 * omega_m)
    return float(np.mean(errors[-1000:]))


def test_the_back_emf_observer_takes_the_warm_winding_resistance():
    """R̂_s reaches the estimators' resistive drop (SAMPLE.R_s_ohm, hf_estimator.interface.stator_resistance):
    the flux observer at 1000 rpm and 6.9 A on a winding 40 % above its commissioned R_s (about 110 K warm)
    is off by 0.29 rad fed the commissioned R_s; fed the warm one, by what it is off on a cold winding (0.031
    rad, the nameplate's inductance against the plant's; within 1 mrad)."""
    R = MACHINE.R_s_ohm
    cold_winding = _observer_angle_error(R, 0.0)
    unaware = _observer_angle_error(1.4 * R, 0.0)
    told = _observer_angle_error(1.4 * R, 1.4 * R)
    assert abs(unaware) > 0.25
    assert abs(told - cold_winding) < 1e-3


@pytest.mark.parametrize("keys, key", [("  U_overvoltage_V: 24.0\n", "inverter.U_overvoltage_V"),
                                       ("  R_brake_ohm: 10.0\n  U_brake_on_V: 26.0\n  U_brake_off_V: 20.0\n",
                                        "inverter.U_brake_off_V"),
                                       ("  C_dc_F: -1.0e-3\n", "inverter.C_dc_F")])
def test_a_link_that_would_trip_at_rest_or_drain_its_supply_is_refused(tmp_path, keys, key):
    """A trip level at the supply's voltage trips at rest, a chopper on at it drains the supply, a
    capacitance is positive: refused, the key named."""
    text = Path(motor_path("wang_spmsm")).read_text().replace("  delay_periods: 1\n", "  delay_periods: 1\n" + keys, 1)
    (tmp_path / "bad.yaml").write_text(text)
    with pytest.raises(MotorFileError, match=key):
        load_motor(str(tmp_path / "bad.yaml"))

