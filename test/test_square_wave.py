"""The square-wave estimator (hf_estimator/square_wave.py): its error signal against the model on the plant, the
closed loop on a shipped scenario, and the rule that says when it serves a motor."""
import math
from pathlib import Path

import numpy as np
import pytest

from drive_common.contract.estimator_records import SAMPLE, estimates
from drive_common.math.command_delay import applied_voltage, command_line, issue_command
from drive_common.motor.commissioning import nameplate_commissioning
from drive_common.motor.motor_file import load_motor
from helpers import ideal_commissioning as commission
from helpers import run, shipped
from hf_estimator.registry import make_estimator
from hf_estimator.square_wave import (
    demodulation_delay_s,
    sine_tracking_limit_Hz,
    square_wave_serves,
    square_wave_tracking_limit_Hz,
)
from pmsm_plant.model import N_STATE, plant_advance, plant_outputs, plant_reset
from pmsm_plant.params import IDEAL_SENSOR, PlantParams
from pmsm_plant.presets import PRESETS, plant_parameters

pytestmark = pytest.mark.unit

WANG = PRESETS["wang_spmsm"]
WANG_INVERTER = load_motor("wang_spmsm", "test").inverter
ROOT = Path(__file__).resolve().parent.parent
LINEAR = {"saturation": False, "dead_time": False, "delay": True, "sensor_noise": False, "sensor_offset_gain": False,
          "adc": False}


def held_square_wave(error_e, L_d_H, L_q_H, samples=400):
    """The square wave's last ε and |Δ̂| [1/H] with its loop frozen, on the Wang plant made linear with these
    inductances, the shaft held at ``error_e`` from θ̂ = 0; and the commissioning it was given (the oracle's)."""
    machine, _, inverter, _ = plant_parameters(WANG, LINEAR)
    machine = machine._replace(L_d_H=L_d_H, L_q_H=L_q_H, a_d=0.0, a_q=0.0, a_dq=0.0)
    x = np.zeros(N_STATE)
    plant_reset(x, error_e / machine.n_p, 0.0, machine)
    c = commission(machine, WANG.nameplate.current_limit_A)
    hold = {"pll_bandwidth_Hz": 1e-9, "settle_s": 1.0, "align_tolerance_rad": 1.0, "amplitude_V": 5.0,
            "dead_time_model": False}
    e = make_estimator("square_wave", WANG.nameplate, 1e-4, hold, c,
                       WANG_INVERTER._replace(delay_periods=inverter.delay_periods))
    line = command_line(inverter.delay_periods)
    sample, out = np.zeros(1, SAMPLE)[0], estimates(1)[0]
    plant = PlantParams(machine, WANG.mechanics, inverter, IDEAL_SENSOR, 0, 1e-4, 1)
    for k in range(samples):
        sample["i_a"], sample["i_b"], sample["i_c"], _ = plant_outputs(x, machine)
        sample["u_applied_alpha"], sample["u_applied_beta"] = applied_voltage(line, k - 1)
        e.step(e.state[0], e.params, k, sample, out)
        issue_command(line, k, out["u_inj_alpha"], out["u_inj_beta"])
        plant_advance(x, *applied_voltage(line, k), 0.0, True, 0.0, plant)
    return float(out["eps"]), float(out["signal"]), c


@pytest.mark.parametrize("draw", range(12))
def test_error_signal_has_the_models_sign_and_gain(draw):
    """Over random angle errors (±0.7 rad) and saliencies (L_q/L_d 0.6-2.5, reverse saliency included), held
    shaft, delay on: ε = ½ sin 2θ̃ (z_q = Δ sin 2θ̃ over 2Δ̂, item 2 of the module) within 2 % of |θ̃| + 0.002
    rad, and |Δ̂| the model's ½|1/L_dh − 1/L_qh| within 3 %."""
    rng = np.random.default_rng(52 + draw)
    error = rng.uniform(-0.7, 0.7)
    L_d = rng.uniform(0.5e-3, 2e-3)
    ratio = rng.choice([rng.uniform(0.6, 0.9), rng.uniform(1.1, 2.5)])
    eps, signal, c = held_square_wave(error, L_d, ratio * L_d)
    assert eps == pytest.approx(0.5 * math.sin(2.0 * error), abs=0.002 + 0.02 * abs(error))
    assert signal == pytest.approx(abs(c.delta), rel=0.03)


def test_the_square_waves_loop_is_wider_than_the_sine_carriers_by_the_delay_rule():
    """At 10 kHz, d = 1: the sine carrier allows f_s/5/25 = 80 Hz; the square wave's delay (2.5 samples) allows
    0.35 rad/τ = 223 Hz: 2.8 times wider; a longer delay narrows it (d = 3: 0.35/(4.5 T_s) = 124 Hz)."""
    assert sine_tracking_limit_Hz(1e-4) == pytest.approx(80.0)
    assert demodulation_delay_s(1e-4, 1, 1) == pytest.approx(2.5e-4)
    assert square_wave_tracking_limit_Hz(1e-4, 1) == pytest.approx(0.35 / 2.5e-4 / (2.0 * math.pi))
    assert square_wave_tracking_limit_Hz(1e-4, 1) / sine_tracking_limit_Hz(1e-4) > 2.7
    assert square_wave_tracking_limit_Hz(1e-4, 3) == pytest.approx(0.35 / 4.5e-4 / (2.0 * math.pi))


def test_closed_loop_meets_the_targets_on_a_shipped_scenario():
    """`drive run wang_100rpm --estimator square_wave`: started from an angle it is not told, locked, within
    ours' targets (RMS ≤ 0.02, peak ≤ 0.15 rad)."""
    _, metrics = run(shipped("wang_100rpm", estimator="square_wave"))
    assert metrics["angle_error_rms"] <= 0.02
    assert metrics["angle_error_peak"] <= 0.15
    assert not metrics["lock_lost_s"]


def rated_commissioning(motor, noise_A):
    """What commissioning would find on a docs/ motor file's plant, to the rule's needs: its HF inductances and
    sensor noise (no saliency table: the no-load saliency throughout)."""
    plant = motor.plant
    c = nameplate_commissioning(motor.nameplate)
    return c._replace(L_dh_H=plant["L_dh_H"], L_qh_H=plant["L_qh_H"], sensor_noise_A=noise_A)


@pytest.mark.parametrize("motor_file, T_s, serves", [
    ("docs/motors/joint_21pp_48v.yaml", 1e-4, True),
    ("docs/motors/joint_14pp_24v.yaml", 1e-4, True),
    ("docs/motors/robot_joint_10pp.yaml", 1e-4, True),
    ("docs/motors/robot_joint_10pp.yaml", 5e-5, False),
    ("docs/motors/joint_21pp_48v_geared.yaml", 1e-4, False),
    ("docs/motors/ipmsm_2kw.yaml", 1e-4, False),
])
def test_the_rule_takes_the_square_wave_where_the_rotors_acceleration_outruns_the_sine(motor_file, T_s, serves):
    """square_wave_serves: the light joints at 10 kHz (their rated-torque acceleration wants 116-201 Hz of tracking,
    the sine allows 80) take it; at 20 kHz the sine's 160 Hz covers robot_joint_10pp's 116; a geared joint (J × 10)
    and a 2 kW motor want less than the sine allows. Where it serves, the rotor wants more than the sine allows
    and the square wave's delay allows more than the sine."""
    motor = load_motor(str(ROOT / motor_file), "test")
    choice = square_wave_serves(motor.nameplate, rated_commissioning(motor, 0.015), motor.inverter, T_s)
    assert choice.serves == serves, choice.reason
    if serves:
        assert choice.wanted_Hz > choice.sine_limit_Hz
        assert choice.square_limit_Hz > choice.sine_limit_Hz


def test_the_rule_leaves_a_weak_signal_to_the_sine():
    """The same light joint with 10 times the sensor noise: the square wave's signal would make it refuse, so the
    rule does not take it, and says so."""
    motor = load_motor(str(ROOT / "docs/motors/joint_21pp_48v.yaml"), "test")
    choice = square_wave_serves(motor.nameplate, rated_commissioning(motor, 0.15), motor.inverter, 1e-4)
    assert not choice.serves
    assert "refuse" in choice.reason
