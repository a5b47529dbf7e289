"""Estimators: demodulation against the true angle error with the shaft held (no controller), low
observability on a round rotor, locking in closed loop, the improved method's predicted bias."""
import math

import numpy as np
import pytest

from drive_common.contract.estimator_records import SAMPLE, estimates
from drive_common.contract.log import COLUMN
from drive_common.math.command_delay import applied_voltage, command_line, issue_command
from drive_common.math.dead_time import MIN_SMOOTHING_A
from drive_common.motor.commissioning import MIN_CONVERGENCE_SLOPE, nameplate_commissioning
from drive_common.motor.motor_file import load_motor
from drive_tools.runner.runner import run_scenario
from helpers import ideal_commissioning as commission
from helpers import run, scenario, shipped
from hf_estimator.injection_frame import (
    dead_time_modelled,
    dead_time_share,
    raised_injection_amplitude,
)
from hf_estimator.registry import make_estimator
from pmsm_plant.model import N_STATE, plant_advance, plant_outputs, plant_reset, saturation_saliency_angle
from pmsm_plant.params import IDEAL_SENSOR, PlantParams
from pmsm_plant.presets import PRESETS, plant_parameters

pytestmark = pytest.mark.unit

WANG = PRESETS["wang_spmsm"]
WANG_INVERTER = load_motor("wang_spmsm", "test").inverter


def held_shaft_response(name, error_e, saturation=True, samples=600, excitation=None):
    """Run estimator ``name`` with its injection only (PLL frozen, start-up held in its alignment) on the
    standstill Wang motor at ``error_e`` from the estimate (θ̂ = 0); return its last (ε, signal,
    observable: the start-up's 1 while aligning on a signal, else 0) and the commissioning.
    ``excitation(k) -> (u_α, u_β)``: a voltage applied instead of the estimator's own (a recording's)."""
    flags = {k: False for k in ("saturation", "dead_time", "delay", "sensor_noise",
                                "sensor_offset_gain", "adc")}
    flags.update(saturation=saturation, delay=True)
    machine, _, inverter, _ = plant_parameters(WANG, flags)
    x = np.zeros(N_STATE)
    plant_reset(x, error_e / machine.n_p, 0.0, machine)
    c = commission(machine, WANG.nameplate.current_limit_A)
    hold = {"pll_bandwidth_Hz": 1e-9, "settle_s": 1.0, "align_tolerance_rad": 1.0}
    rating = WANG_INVERTER._replace(delay_periods=inverter.delay_periods)
    e = make_estimator(name, WANG.nameplate, 1e-4, hold, c, rating)
    line = command_line(inverter.delay_periods)
    sample, out = np.zeros(1, SAMPLE)[0], estimates(1)[0]
    for k in range(samples):
        sample["i_a"], sample["i_b"], sample["i_c"], _ = plant_outputs(x, machine)
        sample["u_applied_alpha"], sample["u_applied_beta"] = applied_voltage(line, k - 1)
        e.step(e.state[0], e.params, k, sample, out)
        eps, signal, observable = out["eps"], out["signal"], out["state"]
        issue_command(line, k, *(excitation(k) if excitation else (out["u_inj_alpha"], out["u_inj_beta"])))
        plant_advance(x, *applied_voltage(line, k), 0.0, True, 0.0,
                      PlantParams(machine, WANG.mechanics, inverter, IDEAL_SENSOR, 0, 1e-4, 1))
    return eps, signal, observable, c


def pulsating(axis_rad, wave):
    """A 5 V pulsating injection along ``axis_rad``, carrier ``wave(k)`` in [−1, 1]."""
    return lambda k: (5.0 * wave(k) * math.cos(axis_rad), 5.0 * wave(k) * math.sin(axis_rad))


@pytest.mark.parametrize("kind, axis, excitation", [
    ("sine on another d̂", 0.15, pulsating(0.15, lambda k: math.cos(2.0 * math.pi * 900.0 * k * 1e-4))),
    ("Szabó's sine at 1500 Hz", -0.1, pulsating(-0.1, lambda k: math.sin(2.0 * math.pi * 1500.0 * k * 1e-4))),
    ("square wave, 4 samples a level", 0.25, pulsating(0.25, lambda k: 1.0 if (k // 4) % 2 == 0 else -1.0)),
    ("rotating sine", None, lambda k: (5.0 * math.cos(2.0 * math.pi * 1000.0 * k * 1e-4),
                                       5.0 * math.sin(2.0 * math.pi * 1000.0 * k * 1e-4)))])
@pytest.mark.parametrize("error_e", [-0.3, 0.2])
def test_injection_frame_measures_the_angle_from_any_known_excitation(kind, axis, excitation, error_e):
    """Held shaft, the voltage not ours but another estimator's injection (known, as in a recording):
    ours' ε is still the true error. On one excited axis (hf_estimator/injection_frame.py item 3b) the
    commissioned |Δ| scales the angle from that axis: within 0.005 rad + 6 % of it (a recording's axis
    follows the rotor within about 0.1 rad); a rotating injection excites both axes: within 0.01 rad."""
    eps, signal, observable, c = held_shaft_response("injection_frame", error_e, excitation=excitation)
    tolerance = 0.01 if axis is None else 0.005 + 0.06 * abs(error_e - axis)
    assert eps == pytest.approx(error_e, abs=tolerance), kind
    assert observable == 1.0


@pytest.mark.parametrize("error_e", [-0.6, -0.3, 0.3, 0.6])
def test_injection_frame_measures_angle_error_and_saliency(error_e):
    """Held shaft: ε equals the true error within 0.01 rad and |Δ̂| the commissioned Δ within 2 %."""
    eps, signal, observable, c = held_shaft_response("injection_frame", error_e)
    assert eps == pytest.approx(error_e, abs=0.01)
    assert signal == pytest.approx(c.delta, rel=0.02)
    assert observable == 1.0


@pytest.mark.parametrize("name", ["conventional", "improved"])
def test_wang_demodulation_sign(name):
    """The papers' ε has the sign of θ − θ̂, so their tracking loops turn the right way."""
    assert held_shaft_response(name, 0.3)[0] > 0.0
    assert held_shaft_response(name, -0.3)[0] < 0.0


@pytest.mark.parametrize("name, paper_share", [("conventional", 0.8), ("improved", 0.8)])
def test_aligned_demodulation_gives_the_papers_their_whole_gain(name, paper_share):
    """Held shaft, 0.1 rad off: with its carrier aligned to the sampled current (ours) a Wang method's ε is
    the nominal 2(U_h/ω_h)Δ·½ sin 2Δθ within 3 %; as printed, the carrier evaluated at the sampling
    instant lags the current (command delay, hold, band-pass) and keeps less than ``paper_share`` of it
    (58 % and 75 % here)."""
    aligned, _, _, c = held_shaft_response(f"{name}_aligned", 0.1)
    nominal = 2.0 * 5.0 * c.delta / (2.0 * math.pi * 900.0) * math.sin(0.2) / 2.0
    assert aligned == pytest.approx(nominal, rel=0.03)
    assert held_shaft_response(f"{name}_aligned", -0.1)[0] == pytest.approx(-aligned, rel=1e-6)
    assert 0.0 < held_shaft_response(name, 0.1)[0] < paper_share * nominal


def test_aligned_carrier_phase_vanishes_for_the_papers_continuous_loop():
    """No delay, a sampling period far below the time constants, no band-pass and the papers' lossless
    inductances (R → 0): the sampled current is the continuous one and the aligned carrier is the
    paper's (φ → 0); the resistance alone turns it by about R/(ω_h L) (0.1 rad here)."""
    from hf_estimator.pll_model import aligned_demodulation_phase
    w_h, none = 2.0 * math.pi * 900.0, np.zeros((0, 6))
    assert aligned_demodulation_phase(1e-6, 0.8e-3, 1.2e-3, 1e-7, 0, w_h, none) == pytest.approx(0.0, abs=1e-3)
    assert aligned_demodulation_phase(0.27, 0.8e-3, 1.2e-3, 1e-7, 0, w_h, none) == pytest.approx(0.1, abs=0.01)


def test_conventional_aligned_meets_ours_targets_where_the_printed_one_does_not():
    """`wang_100rpm` closed loop: `conventional` as printed 0.046 RMS / −0.027 bias / 0.15 peak;
    aligned within the 100 rpm targets (RMS ≤ 0.02, |bias| ≤ 0.01, peak ≤ 0.1 rad)."""
    _, printed = run(shipped("wang_100rpm", "conventional"))
    _, aligned = run(shipped("wang_100rpm", "conventional_aligned"))
    assert printed["angle_error_rms"] > 0.03
    assert aligned["angle_error_rms"] <= 0.02 and abs(aligned["angle_error_bias"]) <= 0.01
    assert aligned["angle_error_peak"] <= 0.1


@pytest.mark.parametrize("name", ["injection_frame", "conventional", "improved"])
def test_round_rotor_reports_low_observability(name):
    """L_dh = L_qh (saturation off, round rotor): no angle information; the start-up refuses (0) after its
    100 ms timeout; the salient rotor keeps aligning on its signal (1)."""
    _, signal, _, c = held_shaft_response(name, 0.3, saturation=False)
    assert c.delta == pytest.approx(0.0, abs=1e-9)
    assert signal < 0.02 * c.sigma
    assert held_shaft_response(name, 0.3, saturation=False, samples=1200)[2] == 0.0
    assert held_shaft_response(name, 0.3)[2] == 1.0


def test_ours_raises_its_amplitude_until_the_saliency_current_stands_above_the_noise():
    """U_h·|Δ|/ω_h reaches 8 σ of the commissioned noise; a weak saliency stops at the voltage cap
    (0.8·U_dc/√3); nothing changes without a measured noise or saliency, or above the wanted amplitude."""
    plate, omega_h = WANG.nameplate, 2.0 * math.pi * 1000.0
    c = commission(WANG.machine, plate.current_limit_A)._replace(sensor_noise_A=0.01)
    wanted = 8.0 * 0.01 * omega_h / abs(c.delta)
    amplitude, note = raised_injection_amplitude(5.0, c, plate, WANG_INVERTER, omega_h, 8.0)
    assert amplitude == pytest.approx(wanted) and 6.0 < wanted < 7.0 and "8.0 σ" in note
    weak = c._replace(L_dh_H=0.93e-3, L_qh_H=0.87e-3)
    amplitude, note = raised_injection_amplitude(5.0, weak, plate, WANG_INVERTER, omega_h, 8.0)
    assert amplitude == pytest.approx(0.8 * 24.0 / math.sqrt(3.0)) and note.endswith("held by the voltage cap")
    for record, snr, requested in ((c._replace(sensor_noise_A=0.0), 8.0, 5.0), (nameplate_commissioning(plate), 8.0,
                                   5.0), (c, 0.0, 5.0), (c, 8.0, 10.0)):
        assert raised_injection_amplitude(requested, record, plate, WANG_INVERTER, omega_h, snr) == (requested, "")


def test_ours_models_the_dead_time_wherever_the_commissioning_measured_it():
    """``dead_time_model: auto`` (injection_frame item 2): the commissioned dead-time voltage is subtracted
    whatever its share of the saliency's share of the carrier voltage U_h·|Δ|/Σ (the note states that share), not
    without a commissioned dead-time voltage or saliency; True and False hold as set. The model's sign is smoothed
    over at least MIN_SMOOTHING_A (Wang's motor: 1 % of its rated current is less)."""
    plate = WANG.nameplate
    c = commission(WANG.machine, plate.current_limit_A)._replace(dead_time_voltage_V=0.12)
    share_one_V = 0.12 * abs(c.sigma / c.delta)
    assert dead_time_share(c, share_one_V) == pytest.approx(1.0, rel=1e-12)
    for amplitude_V, share in ((share_one_V, "1.00"), (20.0 * share_one_V, "0.05")):
        on, note = dead_time_modelled("auto", c, amplitude_V)
        assert on and note.startswith(f"dead-time model on: the 0.12 V dead-time voltage is {share}")
    assert dead_time_modelled(True, c, share_one_V) == (True, "")
    assert dead_time_modelled(False, c, share_one_V) == (False, "")
    assert dead_time_modelled("auto", c._replace(dead_time_voltage_V=0.0), share_one_V) == (False, "")
    assert dead_time_modelled("auto", c._replace(L_dh_H=c.L_qh_H), share_one_V) == (False, "")
    settings = {"amplitude_V": 20.0 * share_one_V, "saliency_snr_min": 0.0}
    for setting, subtracted in (("auto", 0.12), (False, 0.0)):
        p = make_estimator("injection_frame", plate, 1e-4, {**settings, "dead_time_model": setting}, c,
                           WANG_INVERTER).params
        assert p.dead_time_voltage_V == subtracted
        assert p.dead_time_smoothing_A == MIN_SMOOTHING_A > 0.01 * plate.rated_current_A


def test_injection_frame_locks_at_100_rpm_closed_loop():
    """wang_100rpm (900 Hz / 5 V, all non-idealities, 0.5 rad initial error), shortened to 1.1 s:
    the issue's targets, steady RMS ≤ 0.02 rad (0.0135-0.0161 over noise seeds 1, 3, 4) and
    |bias| ≤ 0.01 rad; peak < 0.1 rad; observable throughout."""
    _, m = run(shipped("wang_100rpm", duration_s=1.1))
    assert m["angle_error_rms"] <= 0.02
    assert abs(m["angle_error_bias"]) < 0.01
    assert m["angle_error_peak"] < 0.1
    assert m["observable_fraction"] == 1.0


LOCK_CASES = [("injection_frame", "wang_spmsm", 900.0, 5.0, 0.05, 0.05),
              ("conventional", "wang_spmsm", 900.0, 5.0, 0.05, 0.15),
              ("improved", "wang_spmsm", 900.0, 5.0, 0.05, 0.2),
              ("improved_aligned", "wang_spmsm", 900.0, 5.0, 0.05, 0.2),
              ("synchronous", "szabo_ipmsm", 1500.0, 40.0, 0.05, 0.05),
              ("injection_frame", "szabo_ipmsm", 1500.0, 40.0, 0.05, 0.05)]


@pytest.mark.parametrize("name, motor, f_h, U_h, bias_rad, peak_rad", LOCK_CASES)
def test_each_estimator_locks_from_half_a_radian(name, motor, f_h, U_h, bias_rad, peak_rad):
    """Speed-controlled standstill, rotor 0.5 rad from the estimate's start, all non-idealities: locked
    (start-up done) within 0.25 s
    (|bias| < bias_rad and |error| < peak_rad over 0.25-0.4 s: 0.05 rad for ours and the synchronous
    method, the Wang methods' leaked ripple allows peaks of 0.15 and 0.2) and observable throughout. `improved` as
    printed holds about +0.03 rad at standstill once its speed loop no longer hunts (its carrier's phase; aligned,
    0.01), which a speed loop hunting at ±2 rad/s had averaged away (foc_controller.speed_margin)."""
    s = scenario(motor=motor, estimator=name, injection={"frequency_Hz": f_h, "amplitude_V": U_h},
                 duration_s=0.4, initial={"theta_m_rad": 0.5 / PRESETS[motor].nameplate.n_p},
                 metrics={"settle_s": 0.25})
    _, m = run(s)
    assert abs(m["angle_error_bias"]) < bias_rad
    assert m["angle_error_peak"] < peak_rad
    assert m["observable_fraction"] == 1.0


@pytest.mark.parametrize("rpm", [100.0, 200.0, -100.0])
def test_improved_bias_follows_sigma_term_formula(rpm):
    """Faithful `improved` at imposed speed lags by the Σ-term bias of docs/hf-demodulation.md
    §2, ½(Σ/Δ)·ω_e·τ_g (τ_g: the 300 Hz 2nd-order Butterworth's group delay √2/ω_c), within ±25 %."""
    s = scenario(estimator="improved", mode="imposed_speed", duration_s=0.6,
                 injection={"frequency_Hz": 900.0, "amplitude_V": 5.0},
                 speed={"unit": "rpm", "interpolation": "linear", "points": [[0.0, 0.0], [0.1, rpm], [0.6, rpm]]},
                 metrics={"settle_s": 0.3})
    _, m = run(s)
    machine = WANG.machine
    c = commission(machine, WANG.nameplate.current_limit_A)
    omega_e = machine.n_p * rpm * 2.0 * math.pi / 60.0
    predicted = 0.5 * (c.sigma / c.delta) * omega_e * math.sqrt(2.0) / (2.0 * math.pi * 300.0)
    assert m["angle_error_bias"] == pytest.approx(predicted, rel=0.25)


def test_injection_frame_stays_locked_through_reversal():
    """50 → −50 rpm step at 0.3 s (Wang §III-C reversal, shortened), 1000 Hz / 10 V: the estimate
    never slips (peak < 0.2 rad after start) and is back within 0.02 rad RMS 0.2 s after the step."""
    s = scenario(estimator="injection_frame", injection={"frequency_Hz": 1000.0, "amplitude_V": 10.0},
                 duration_s=0.7, speed={"unit": "rpm", "interpolation": "linear",
                                        "points": [[0.0, 0.0], [0.1, 50.0], [0.3, 50.0], [0.3001, -50.0],
                                                   [0.7, -50.0]]},
                 metrics={"settle_s": 0.2, "start_s": 0.1})
    _, m = run(s)
    assert m["angle_error_peak"] < 0.2
    assert m["steady_windows"][-1]["angle_error_rms"] < 0.02


@pytest.mark.parametrize("i_q", [0.0, 4.6, 5.6, 6.9])
def test_convergence_slope_is_how_the_saliency_axis_follows_the_rotor(i_q):
    """Commissioned slope F = 1 + i_q·∂δ/∂i_d equals d(saliency-axis angle)/d(rotor angle) with the
    current vector held still in the stator, found by turning the rotor ±1 mrad (within 0.01)."""
    machine = WANG.machine
    c = commission(machine, WANG.nameplate.current_limit_A)
    step = 1e-3

    def axis_in_stator(theta):
        i_d, i_q_rotor = i_q * math.sin(theta), i_q * math.cos(theta)
        return theta + saturation_saliency_angle(machine, i_d, i_q_rotor)

    measured = (axis_in_stator(step) - axis_in_stator(-step)) / (2.0 * step)
    table = float(np.interp(i_q, c.saliency_shift_i_q_A, c.convergence_slope))
    assert table == pytest.approx(measured, abs=0.01)


def test_drive_keeps_current_where_saliency_tracking_holds():
    """`wang_spmsm`: the slope is near 1 at no load, above ¾ at rated current and negative at the 1.5×
    rated limit (the HF axis then says nothing of the rotor). Injecting estimators run with the current
    limit where F ≥ ¾ (between rated and 1.25× rated); the sensored drive and an explicit setting keep
    theirs."""
    c = commission(WANG.machine, WANG.nameplate.current_limit_A)
    no_load, rated, limit = np.interp([0.0, WANG.nameplate.rated_current_A, WANG.nameplate.current_limit_A],
                                      c.saliency_shift_i_q_A, c.convergence_slope)
    assert no_load == pytest.approx(1.0, abs=1e-3)
    assert rated > MIN_CONVERGENCE_SLOPE
    assert limit < 0.0
    limits = {}
    for estimator, controller in [("injection_frame", {}), ("improved", {}), ("sensored", {}),
                                  ("injection_frame", {"current_limit_A": 6.0})]:
        result = run_scenario(scenario(estimator=estimator, controller=controller, duration_s=0.01))
        limits[estimator, bool(controller)] = result.current_limit_A
    assert WANG.nameplate.rated_current_A < limits["injection_frame", False] < 1.25 * WANG.nameplate.rated_current_A
    assert limits["improved", False] == limits["injection_frame", False]
    assert limits["sensored", False] == pytest.approx(WANG.nameplate.current_limit_A)
    assert limits["injection_frame", True] == 6.0


def test_injection_frame_holds_through_rated_load_step():
    """Rated load applied suddenly at 100 rpm (Wang §IV-E, shortened to 0.3 s after the step),
    1000 Hz / 10 V: the motor dips and recovers, the angle error stays within 0.1 rad."""
    s = scenario(estimator="injection_frame", injection={"frequency_Hz": 1000.0, "amplitude_V": 10.0},
                 duration_s=0.6, initial={"omega_m_rpm": 100.0},
                 speed={"unit": "rpm", "points": [[0.0, 100.0]]},
                 load={"unit": "rated", "points": [[0.0, 0.0], [0.3, 1.0]]},
                 metrics={"settle_s": 0.2, "start_s": 0.1})
    result, m = run(s)
    assert m["angle_error_peak"] < 0.1
    assert result.log[-1, COLUMN["omega_m"]] * 30.0 / math.pi == pytest.approx(100.0, abs=10.0)


@pytest.mark.parametrize("motor, rpm", [("wang_spmsm", 1000.0), ("wang_spmsm", -1500.0), ("wang_spmsm", 3000.0),
                                        ("szabo_ipmsm", 1000.0), ("szabo_ipmsm", -3000.0)])
def test_flux_observer_finds_and_holds_the_angle_at_speed(motor, rpm):
    """Shaft turned at a fixed speed from an angle the drive is not told (1.3 rad mechanical), no
    injection: the back-EMF observer (Hinkkanen et al. 2018) tracks within 10 ms and holds the angle within
    0.02 rad and the speed within 0.1 % over the last half."""
    s = scenario(motor=motor, estimator="flux_observer", mode="imposed_speed", duration_s=0.4,
                 initial={"theta_m_rad": 1.3}, speed={"unit": "rpm", "points": [[0.0, rpm]]})
    result = run_scenario(s)
    log, t = result.log, result.log[:, COLUMN["t"]]
    late = t > 0.2
    error = np.angle(np.exp(1j * (result.n_p * log[:, COLUMN["theta_m"]] - log[:, COLUMN["theta_e_hat"]])))
    assert t[np.argmax(log[:, COLUMN["state"]] == 3.0)] < 0.01 and (log[late, COLUMN["state"]] == 3.0).all()
    assert np.abs(error[late]).max() < 0.02
    omega = result.n_p * log[late, COLUMN["omega_m"]]
    assert log[late, COLUMN["omega_e_hat"]] == pytest.approx(omega, rel=1e-3)


def test_flux_observer_holds_where_the_back_emf_is_too_small():
    """At rest and at 100 rpm on `wang_spmsm` (back-EMF 0.34 V, below 5 % of the rated 3.4 V) the observer
    says it has no angle (state HOLD): the drive gets no torque from it."""
    for rpm in (0.0, 100.0):
        s = scenario(estimator="flux_observer", mode="imposed_speed", duration_s=0.1,
                     speed={"unit": "rpm", "points": [[0.0, rpm]]})
        assert (run_scenario(s).log[:, COLUMN["state"]] == 0.0).all()


@pytest.mark.parametrize("name", ["injection_frame", "conventional", "synchronous", "full_speed"])
def test_a_carrier_longer_than_the_state_holds_is_refused_naming_the_setting(name):
    """20 Hz at 50 kHz sampling is 2500 samples a period, beyond the 1000 an estimator's rings hold: one
    ValueError naming frequency_Hz (the drive's one-line refusal), never a ring that wraps early."""
    plate = WANG.nameplate
    with pytest.raises(ValueError, match="frequency_Hz: 2500 samples per carrier period"):
        make_estimator(name, plate, 2e-5, {"frequency_Hz": 20.0}, nameplate_commissioning(plate),
                       WANG_INVERTER._replace(delay_periods=1))
