"""Controller and tuning: the bandwidth/damping rule, Szabó Table 2, sensored speed control on both
presets, the voltage limit and the back-EMF seen by the current loop."""
import math

import numpy as np
import pytest

from drive_interface.log import COLUMN
from foc_controller.tuning import SZABO_TABLE2, current_pi_gains, speed_pi_gains
from helpers import run, scenario

pytestmark = pytest.mark.unit


def test_current_rule_places_closed_loop_poles():
    """L s² + (R + k_p) s + k_i has roots with the requested ω_n and ζ."""
    L, R = 20.025e-3, 6.2
    gains = current_pi_gains(L, R, 600.0, 0.8)
    roots = np.roots([L, R + gains.kp, gains.ki])
    assert np.abs(roots) == pytest.approx([600.0, 600.0], rel=1e-9)
    assert -roots[0].real / abs(roots[0]) == pytest.approx(0.8, rel=1e-9)


def test_speed_rule_places_closed_loop_poles():
    J, B, k_t = 3.5e-3, 0.0011, 1.5 * 3 * 0.305
    gains = speed_pi_gains(J, B, k_t, 55.0, 1.0)
    roots = np.roots([J, B + gains.kp * k_t, gains.ki * k_t])
    assert np.abs(roots) == pytest.approx([55.0, 55.0], rel=1e-6)


def test_szabo_table2_conversion_and_assumed_inertia():
    """Table 2: A_p/T_i → k_i; the stated inertia 3.5e-3 kg·m² makes its speed PI critically damped."""
    assert SZABO_TABLE2["d"].ki == pytest.approx(11.49 / 1.8e-3)
    speed = SZABO_TABLE2["speed"]
    k_t, J, B = 1.5 * 3 * 0.305, 3.5e-3, 0.0011
    omega_n = math.sqrt(speed.ki * k_t / J)
    zeta = (B + speed.kp * k_t) / (2.0 * J * omega_n)
    assert omega_n == pytest.approx(55.9, abs=0.5)
    assert zeta == pytest.approx(1.0, abs=0.03)


@pytest.mark.parametrize("motor, rpm, controller", [
    ("wang_spmsm", 100.0, {}),
    ("szabo_ipmsm", 500.0, {"gains": "szabo_table2"}),
])
def test_sensored_speed_step_and_reversal(motor, rpm, controller):
    """0 → n at 0.05 s, n → −n at 0.6 s: each step settles within 5 % of its size in < 0.15 s and the
    steady tracking error is < 0.02 rad/s RMS (sensor noise, ADC, dead time and delay on)."""
    s = scenario(motor=motor, duration_s=1.2, controller=controller,
                 speed=dict(unit="rpm", points=[[0.0, 0.0], [0.05, rpm], [0.6, -rpm]]),
                 metrics=dict(settle_s=0.3))
    _, m = run(s)
    assert len(m["speed_steps"]) == 2
    for step in m["speed_steps"]:
        assert step["settling_time_s"] is not None and step["settling_time_s"] < 0.15
    assert m["speed_tracking_error_rms"] < 0.02


def test_voltage_command_respects_inverter_limit():
    """A step to 4000 rpm under load asks for more than the 24 V link gives: the controller sits in the
    limit for a while, and |u| never exceeds U_dc/√3."""
    s = scenario(duration_s=0.4, speed=dict(unit="rpm", points=[[0.0, 3000.0], [0.05, 4000.0]]),
                 initial=dict(omega_m_rpm=3000.0), load=dict(unit="rated", points=[[0.0, 0.5]]))
    result, _ = run(s)
    u = np.hypot(result.log[:, COLUMN["u_alpha"]], result.log[:, COLUMN["u_beta"]])
    limit = result.scenario.motor.inverter.U_dc_V / math.sqrt(3.0)
    assert u.max() <= limit * (1.0 + 1e-12)
    assert np.mean(u > 0.999 * limit) > 0.01


def test_back_emf_amplitude_at_no_load():
    """Imposed 2000 rpm, speed reference equal, zero current: |u| = ω_e ψ_f within 0.5 %."""
    s = scenario(motor="szabo_ipmsm", mode="imposed_speed", duration_s=0.3,
                 speed=dict(unit="rpm", points=[[0.0, 2000.0]]), initial=dict(omega_m_rpm=2000.0),
                 non_idealities=dict(saturation=False, dead_time=False, sensor_noise=False, sensor_offset_gain=False,
                                     adc=False))
    result, _ = run(s)
    late = result.log[-1000:]
    u = np.hypot(late[:, COLUMN["u_alpha"]], late[:, COLUMN["u_beta"]])
    omega_e = 3 * 2000.0 * 2.0 * math.pi / 60.0
    assert np.mean(u) == pytest.approx(omega_e * 0.305, rel=5e-3)
    assert np.max(np.abs(late[:, COLUMN["i_a"]])) < 0.02


def test_the_speed_filter_stays_above_a_wide_tracking_loop():
    """Unless set, the speed estimate's filter sits at 1.25 × the estimator's tracking bandwidth where that
    exceeds the 100 Hz default (a 116 Hz loop: 145 Hz), else stays at 100 Hz; a set value is kept."""
    from foc_controller.params import make_controller_params
    from motor_params.motor_file import load_motor
    m = load_motor("wang_spmsm")

    def filter_Hz(bandwidth_Hz, settings=None):
        c = make_controller_params(m.nameplate, m.inverter, 5e-5, settings, 1000.0, bandwidth_Hz)
        return -math.log(1.0 - c.speed_filter_gain) / (2.0 * math.pi * 5e-5)
    assert filter_Hz(116.0) == pytest.approx(145.0)
    assert filter_Hz(18.0) == pytest.approx(100.0) and filter_Hz(80.0) == pytest.approx(100.0)
    assert filter_Hz(116.0, {"speed_filter_Hz": 60.0}) == pytest.approx(60.0)
