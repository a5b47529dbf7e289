"""Motors without enough saliency (issue 52 item 3): the I-f start, then the back-EMF observer above its minimum
speed (hf_estimator.if_observer, drive_common.motor.open_loop_start, foc_controller.control.open_loop_step).
The plan's rules are checked over a random draw; the behaviour on a small fixed draw of round rotors (surface
magnets, no saturation: no saliency at all), commissioned at standstill as a robot builder would, judged on
the plant's truth: the start reaches the hand-over speed in synchronism from every start angle tried, the
observer within its error bound at the hand-over, which does not jump the torque, closed loop on the observer
follows a speed step; a standstill case is refused up front."""
import math

import numpy as np
import pytest

from drive_common.config.motor_experiments import ExperimentOptions
from drive_common.config.scenario import motor_experiment
from drive_common.contract.estimator_records import ESTIMATE, SAMPLE
from drive_common.contract.estimator_states import OPEN_LOOP
from drive_common.contract.log import COLUMN
from drive_common.math.dead_time import MIN_SMOOTHING_A, SMOOTHING_PER_RATED_CURRENT, net_of_dead_time
from drive_common.motor.commissioning import resolve_commissioning, save_commissioning
from drive_common.motor.motor_file import load_motor, motor_from_mapping
from drive_common.motor.open_loop_start import (
    ACCELERATION_SHARE,
    COMMUTATION_MARGIN,
    HANDBACK_PER_HANDOVER,
    MIN_HANDOVER_PER_RATED,
    OBSERVER_ERROR_BOUND_RAD,
    OBSERVER_GAIN_PER_SPEED,
    OBSERVER_SPEED_BANDWIDTH_RAD_S,
    RELUCTANCE_SHARE,
    SETTLE_DECAYS,
    SWING_PER_CURRENT_LOOP,
    observer_error_V,
    open_loop_start,
)
from drive_tools.cli.cli import main
from drive_tools.evaluation.above_speed_bench import (
    PEAK_TARGET_RAD,
    RMS_TARGET_RAD,
    SPEED_TOLERANCE,
    above_speed_plan,
    case_figures,
    saliency_refusal,
)
from drive_tools.evaluation.random_motors import draw_motor, draw_motors, write_motor_files
from drive_tools.runner.commissioning_run import commission_in_process
from drive_tools.runner.runner import run_scenario
from foc_controller.control import IF_THETA, controller_state, open_loop_step
from foc_controller.params import make_controller_params
from hf_estimator.if_observer import make_if_observer

ROUND_ROTORS = ((5, 54), (5, 20))
"""(seed, index) of drawn surface-magnet motors without saturation, J on the nameplate: a light 28-pole-pair
one (acceleration time 14 ms) and a 16-pole-pair one (0.41 s)."""
START_ANGLES_E_RAD = (-2.9, -1.6, -0.3, 1.0, 2.3)
TORQUE_JUMP_PER_IF = 0.25
"""The hand-over keeps the torque current: the true torque's mean over the 2 ms after it within this share of
the I-f torque of its mean over the 2 ms before."""


def test_the_start_is_stated_from_the_nameplate_and_commissioning_over_a_random_draw():
    """Over 300 drawn motors (nameplate-only commissioning): the I-f current within rated current, the swing
    frequency and the reluctance softening within their shares, the ramp's torque share, the minimum speed from
    the observer's error bound (and at least its floor), the hand-back below it, the hand-over's wait SETTLE_DECAYS of
    the observer's flux error at the hand-over speed; no J: refused naming it."""
    checked = 0
    for motor in draw_motors(300, 7):
        plate = motor_from_mapping(motor.document, motor.name, whole_file=True).nameplate
        commissioning = resolve_commissioning(plate, "nameplate")
        U_dc, bandwidth = motor.document["inverter"]["U_dc_V"], 2.0 * math.pi * 250.0
        plan = open_loop_start(plate, commissioning, U_dc, bandwidth)
        if not math.isfinite(plate.J_kgm2):
            assert "J_kgm2" in plan.refused
            continue
        checked += 1
        assert 0.0 < plan.current_A <= plate.rated_current_A * (1 + 1e-12)
        assert plan.swing_rad_s <= SWING_PER_CURRENT_LOOP * min(bandwidth, OBSERVER_SPEED_BANDWIDTH_RAD_S) * (1 + 1e-9)
        softening = abs(plate.L_q_H - plate.L_d_H) * plan.current_A / plate.psi_f_Wb
        assert softening <= RELUCTANCE_SHARE * (1 + 1e-9)
        J_e = plate.J_kgm2 / plate.n_p
        assert plan.acceleration_rad_s2 * J_e == pytest.approx(ACCELERATION_SHARE * plan.torque_Nm, rel=1e-9)
        rated_e = plate.n_p * plate.rated_speed_rpm * math.pi / 30.0
        u_err = observer_error_V(plate, commissioning, U_dc, plan.current_A)
        assert plan.handover_rad_s >= u_err / (OBSERVER_ERROR_BOUND_RAD * plate.psi_f_Wb) * (1 - 1e-9)
        assert plan.handover_rad_s >= MIN_HANDOVER_PER_RATED * rated_e * (1 - 1e-9)
        assert plan.handback_rad_s == pytest.approx(HANDBACK_PER_HANDOVER * plan.handover_rad_s)
        sigma_0 = 0.25 * commissioning.R_s_ohm * (1.0 / plate.L_d_H + 1.0 / plate.L_q_H)
        decay = sigma_0 + OBSERVER_GAIN_PER_SPEED * plan.handover_rad_s
        assert plan.observer_settle_s * decay == pytest.approx(SETTLE_DECAYS)
        band = max(MIN_SMOOTHING_A, SMOOTHING_PER_RATED_CURRENT * plate.rated_current_A)
        if plan.current_A < COMMUTATION_MARGIN * band:
            assert plan.refused, "an I-f current near the switches' commutation band is refused"
        if not plan.refused:
            assert "works above" in plan.statement(plate.n_p) and "no standstill torque" in plan.statement(plate.n_p)
    assert checked > 100


def drawn_with_inertia(seed):
    """(motor file, nameplate, commissioning) of the motors 0-199 of ``seed`` whose nameplate states J, each with a
    measured dead time (0.5 % of U_dc, the drawn switches': the nameplate-only 2 % refuses most starts)."""
    for motor in draw_motors(200, seed):
        whole = motor_from_mapping(motor.document, motor.name, whole_file=True)
        plate = whole.nameplate
        if math.isfinite(plate.J_kgm2):
            yield whole, plate, resolve_commissioning(plate, "nameplate")._replace(
                dead_time_voltage_V=0.005 * whole.inverter.U_dc_V)


def test_the_lock_turns_its_quarter_turn_smoothly_over_a_random_draw():
    """Over 40 drawn motors whose I-f start is accepted (nameplate and a measured dead time, the controller's lock
    from rest with the observer at rest): the current's angle holds for the lock's first half, then turns by
    π/2 with no step, its rate at most (π/4)·π/T per second (T a quarter of the lock: ¼π·(1 − cos(π·t/T))),
    and holds again."""
    tried = 0
    for whole, plate, commissioning in drawn_with_inertia(13):
        if open_loop_start(plate, commissioning, whole.inverter.U_dc_V, 2.0 * math.pi * 250.0).refused:
            continue
        c = make_controller_params(plate, whole.inverter, 1e-4, commissioning=commissioning, open_loop=True)
        x, _ = controller_state(c)
        angles = []
        for _ in range(c.if_align_samples):
            assert open_loop_step(x, c, OPEN_LOOP, 0.0, 0.0, 0.0)[0]
            angles.append(x[IF_THETA])
        steps = np.abs(np.diff(np.concatenate(([0.0], angles))))
        half, turn = c.if_align_samples // 2, max(c.if_align_samples // 4, 1)
        assert np.all(steps[:half] == 0.0)
        assert angles[-1] == pytest.approx(0.5 * math.pi, abs=1e-9)
        assert np.max(steps) <= 0.25 * math.pi * math.pi / turn * (1 + 1e-9)
        assert np.all(steps[half + turn + 1:] == 0.0)
        tried += 1
        if tried == 40:
            break
    assert tried == 40


@pytest.fixture(scope="module")
def round_rotors(tmp_path_factory):
    """The drawn round rotors, each commissioned at standstill: (motor, its commissioning file, the plan, the
    experiments' options, the controller's lock [s])."""
    folder = tmp_path_factory.mktemp("round_rotors")
    rotors = []
    for seed, index in ROUND_ROTORS:
        drawn = draw_motor(seed, index)
        assert drawn.figures["rotor"] == "surface" and not drawn.figures["saturation"]
        motor = load_motor(str(write_motor_files([drawn], folder)[0]), "test")
        first = motor_experiment("low_speed", motor, "test", options=ExperimentOptions(commissioning="nameplate"))
        commissioning = folder / f"{motor.name}_commissioning.yaml"
        save_commissioning(commissioning, commission_in_process(first).procedure.result(), motor.name, "test")
        ours = motor_experiment("low_speed", motor, "test", options=ExperimentOptions(commissioning=str(commissioning)))
        assert saliency_refusal(ours), "a round rotor is refused for its saliency"
        plan, options, align_s = above_speed_plan(motor, commissioning, 1e-4)
        assert not plan.refused
        rotors.append((motor, commissioning, plan, options, align_s))
    return rotors


def _run(motor, options, case, theta_e):
    return run_scenario(motor_experiment(case, motor, "test", options=options._replace(theta_e_rad=theta_e)))


@pytest.mark.parametrize("which", range(len(ROUND_ROTORS)))
def test_the_start_reaches_the_handover_in_synchronism_from_every_angle_without_a_torque_jump(round_rotors, which):
    motor, _, plan, options, align_s = round_rotors[which]
    for theta_e in START_ANGLES_E_RAD:
        result = _run(motor, options, "low_speed", theta_e)
        figures = case_figures(result, align_s)
        assert figures["load_angle_max_rad"] < 0.5 * math.pi, f"lost synchronism from {theta_e} rad"
        log = result.log
        open_loop = log[:, COLUMN["i_d_ref"]] > 0.0
        handover = int(np.argmax(~open_loop[1:] & open_loop[:-1])) + 1
        assert handover > 1 and not open_loop[handover:].any(), f"one hand-over, no hand-back, from {theta_e} rad"
        speed_e = abs(log[handover, COLUMN["omega_m"]]) * motor.nameplate.n_p
        assert speed_e >= HANDBACK_PER_HANDOVER * plan.handover_rad_s
        error = math.remainder(log[handover, COLUMN["theta_e_hat"]]
                               - motor.nameplate.n_p * log[handover, COLUMN["theta_m"]], 2.0 * math.pi)
        assert abs(error) <= OBSERVER_ERROR_BOUND_RAD, f"the observer {error:+.3f} rad off at the hand-over"
        window = int(round(0.002 / result.scenario.T_s))
        before = np.mean(log[handover - window:handover, COLUMN["tau_e"]])
        after = np.mean(log[handover:handover + window, COLUMN["tau_e"]])
        assert abs(after - before) <= TORQUE_JUMP_PER_IF * plan.torque_Nm, f"torque jump from {theta_e} rad"
        assert figures["angle_error_rms"] <= RMS_TARGET_RAD and figures["angle_error_peak"] <= PEAK_TARGET_RAD


@pytest.mark.parametrize("which", range(len(ROUND_ROTORS)))
def test_closed_loop_on_the_observer_follows_a_speed_step(round_rotors, which):
    motor, _, _, options, align_s = round_rotors[which]
    result = _run(motor, options, "speed_step", 1.0)
    figures = case_figures(result, align_s)
    unit = options.unit_rpm * math.pi / 30.0
    assert figures["closed_at_end"] and figures["load_angle_max_rad"] < 0.5 * math.pi
    assert figures["speed_error_final_rad_s"] <= SPEED_TOLERANCE * unit
    assert np.max(np.abs(result.log[:, COLUMN["omega_m_ref"]])) == pytest.approx(2.0 * unit)
    assert figures["angle_error_rms"] <= RMS_TARGET_RAD and figures["angle_error_peak"] <= PEAK_TARGET_RAD


def test_a_standstill_case_is_refused_up_front_in_one_line(round_rotors, capsys):
    motor, commissioning, plan, _, _ = round_rotors[0]
    code = main(["run", "standstill_hold", "--motor", motor.source, "--estimator", "if_observer",
                 "--commissioning", str(commissioning), "--no-plot"])
    lines = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    rpm = f"{plan.handover_rpm(motor.nameplate.n_p):.0f} rpm"
    assert f"works above {rpm}, no standstill torque" in lines[0], "stated before acting"
    assert len(lines) == 2 and "standstill" in lines[1] and f"below {rpm}" in lines[1] and "refused" in lines[1]


def test_ours_refusal_for_saliency_offers_the_start(round_rotors, capsys):
    motor, commissioning, plan, _, _ = round_rotors[0]
    code = main(["run", "low_speed", "--motor", motor.source, "--commissioning", str(commissioning), "--no-plot"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1
    assert f"`estimator: if_observer` runs it without injection: works above " \
           f"{plan.handover_rpm(motor.nameplate.n_p):.0f} rpm, no standstill torque" in err[0]


def test_the_observer_is_set_to_the_measured_current_angle_in_the_lock_over_a_random_draw():
    """Over 20 drawn motors whose I-f start is accepted: with the rotor at rest on the lock's axis (the current at
    I_f along a random angle, the voltage R_s·i and the dead time's), the observer is at that angle within 1e-9 rad
    and at zero speed from SETTLED_PER_LOCK of the lock on, set again at SETTLED_AT_LOCK_END, and never after."""
    rng = np.random.default_rng(3)
    tried = 0
    for whole, plate, commissioning in drawn_with_inertia(17):
        plan = open_loop_start(plate, commissioning, whole.inverter.U_dc_V, math.inf)
        if plan.refused:
            continue
        estimator = make_if_observer(plate, 1e-4, {}, commissioning, whole.inverter)
        x, p = estimator.state.view(np.recarray)[0], estimator.params
        angle = rng.uniform(-math.pi, math.pi)
        s = np.zeros(1, SAMPLE).view(np.recarray)[0]
        s.i_a, s.i_b, s.i_c = plan.current_A * np.cos(angle - np.array([0.0, 2.0, 4.0]) * math.pi / 3.0)
        i_alpha, i_beta = plan.current_A * math.cos(angle), plan.current_A * math.sin(angle)
        lost = net_of_dead_time(0.0, 0.0, i_alpha, i_beta, p.obs.dead_time_voltage_V, p.obs.dead_time_smoothing_A)
        s.u_applied_alpha = commissioning.R_s_ohm * i_alpha - lost[0]
        s.u_applied_beta = commissioning.R_s_ohm * i_beta - lost[1]
        out = np.zeros(1, ESTIMATE).view(np.recarray)[0]
        for k in range(p.settled_samples):
            estimator.step(x, p, k, s, out)
        assert abs(math.remainder(x.theta - angle, 2.0 * math.pi)) < 1e-9 and x.omega == 0.0
        x.observer.theta += 0.5
        estimator.step(x, p, p.settled_samples, s, out)
        assert abs(math.remainder(x.theta - angle, 2.0 * math.pi)) > 0.4, "not set between"
        for k in range(p.settled_samples + 1, p.settled_end_samples):
            estimator.step(x, p, k, s, out)
        assert abs(math.remainder(x.theta - angle, 2.0 * math.pi)) < 1e-9 and x.omega == 0.0
        x.observer.theta += 0.5
        estimator.step(x, p, p.settled_end_samples, s, out)
        assert abs(math.remainder(x.theta - angle, 2.0 * math.pi)) > 0.4, "never set after the lock's end"
        tried += 1
        if tried == 20:
            break
    assert tried == 20
