"""Protections (docs/protections.md): the DC link as a capacitor fed by a supply that cannot absorb, with
a brake chopper; the winding's temperature and R_s(T); the inverter's safe states at speed (freewheel,
active short circuit) in the plant."""
import math

import numpy as np
import pytest

from control_math.frames import clarke, rotate
from pmsm_plant.model import (
    ASC,
    FREEWHEEL,
    INVERTER_MODE,
    N_STATE,
    THETA_M,
    WINDING_RISE,
    bus_voltage,
    plant_advance,
    plant_outputs,
    plant_reset,
    winding_resistance,
)
from pmsm_plant.params import COPPER_ALPHA_PER_K, InverterParams
from pmsm_plant.presets import PRESETS

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
        plant_advance(x, 0.0, 0.0, 0.0, True, omega_m, machine, WANG.mechanics, inv, T_S, 1)
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
        plant_advance(x, u, 0.0, 0.0, True, 0.0, machine, WANG.mechanics, inv, T_s, 1)
        R = machine.R_s_ohm * (1.0 + COPPER_ALPHA_PER_K * (machine.T_ambient_degC + rise - 20.0))
        rise += T_s / machine.C_th_J_K * (1.5 * R * current ** 2 - rise / machine.R_th_K_W)
    assert x[WINDING_RISE] == pytest.approx(rise, rel=0.01)
    assert rise > 5.0
    T = machine.T_ambient_degC + x[WINDING_RISE]
    assert winding_resistance(x, machine) == pytest.approx(machine.R_s_ohm * (1 + 0.00393 * (T - 20.0)), rel=1e-12)
