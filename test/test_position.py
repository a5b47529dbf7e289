"""A robot joint's position (issue 54, foc_controller.position): homing against a hard stop found by current, the
position loop and its timeout, on a virtual clock (unit); then the drift of the homed joint's estimated position
against the plant's truth over back-and-forth moves with a load, on the shipped motor and on drawn motors with more
than one pole pair (drive_tools.evaluation.position_drift)."""
import math
from pathlib import Path

import pytest

from drive_tools.evaluation.position_drift import PEAK_ERROR_E_RAD, drawn_rows, drift_run
from foc_controller.command_hold import HOLDING, CommandHold, HoldSettings
from foc_controller.position import (
    BACKED_OFF_WITHIN_RAD,
    BACKING_OFF,
    FAILED,
    HARD_STOP,
    HOMED,
    INDEX,
    SEEKING,
    Homing,
    HomingSettings,
    position_speed,
)

DT_S = 1e-3
SEARCH = HomingSettings(HARD_STOP, -1.0, 2.0, current_A=1.5, offset_rad=0.7, backoff_rad=0.3, dwell_s=0.02,
                        timeout_s=5.0)


def homing(settings=SEARCH):
    h = Homing(settings, gain_per_s=10.0, limit_rad_s=3.0, acceleration_rad_s2=20.0)
    h.start()
    return h


@pytest.mark.unit
def test_the_search_ramps_to_its_speed_and_its_acceleration_current_never_reads_as_the_stop():
    """Moving (|ω̂| above half the search speed), any current is acceleration, not the stop; the ramp reaches the
    search speed at the stated acceleration."""
    h = homing()
    speeds = [h.reference(DT_S, (0.0, -2.0), -10.0) for _ in range(200)]
    assert speeds[0] == pytest.approx(-20.0 * DT_S)
    assert speeds[49] == pytest.approx(-20.0 * 50 * DT_S)
    assert speeds[-1] == pytest.approx(-2.0) and h.state == SEEKING


@pytest.mark.unit
@pytest.mark.parametrize("i_q, found", [(-1.6, True), (-1.4, False), (1.6, False)])
def test_a_stalled_shaft_pushing_with_the_stop_current_for_the_dwell_is_the_stop(i_q, found):
    """Stalled, the q current pushing in the direction of travel (negative here) above current_A for dwell_s is the
    stop; below it, or pulling the other way, is not."""
    h = homing()
    for _ in range(25):
        h.reference(DT_S, (-1.0, 0.0), i_q)
    assert (h.state == BACKING_OFF) == found
    if found:
        assert h.theta_found == -1.0 and h.theta_zero == pytest.approx(-1.0 + 0.7)
        assert h.target == pytest.approx(-1.0 + 0.3), "backs off away from the stop"
        assert h.position(-1.0) == pytest.approx(-0.7)


@pytest.mark.unit
def test_a_pulse_of_current_shorter_than_the_dwell_is_not_the_stop():
    h = homing()
    for i in range(100):
        h.reference(DT_S, (-1.0, 0.0), -2.0 if i % 15 < 10 else 0.0)
    assert h.state == SEEKING


@pytest.mark.unit
def test_backing_off_ends_homed_within_its_tolerance_at_the_target():
    h = homing()
    for _ in range(25):
        h.reference(DT_S, (-1.0, 0.0), -2.0)
    assert h.reference(DT_S, (-1.0, 0.0), 0.0) == pytest.approx(3.0), "0.3 rad away at 10/s: bounded at 3 rad/s"
    assert h.state == BACKING_OFF
    h.reference(DT_S, (h.target - 0.5 * BACKED_OFF_WITHIN_RAD, 0.0), 0.0)
    assert h.state == HOMED and h.homed and not h.active


@pytest.mark.unit
def test_no_stop_within_the_timeout_fails_naming_why():
    h = homing()
    for _ in range(int(5.1 / DT_S)):
        h.reference(DT_S, (0.0, -2.0), 0.0)
    assert h.state == FAILED and "no stop found in 5 s" in h.reason
    assert h.reference(DT_S, (0.0, 0.0), 0.0) == 0.0
    assert math.isnan(h.position(0.0))


@pytest.mark.unit
def test_an_index_pulse_sets_the_zero_where_the_count_changes():
    h = homing(HomingSettings(INDEX, 1.0, 2.0, offset_rad=-0.25))
    for _ in range(10):
        h.reference(DT_S, (0.1, 2.0), 0.0, index_count=7)
    h.reference(DT_S, (0.4, 2.0), 0.0, index_count=8)
    assert h.theta_zero == pytest.approx(0.15) and h.target == pytest.approx(0.4)
    assert h.state == HOMED, "at an index the joint stays where it is: homed at once"


@pytest.mark.unit
def test_the_position_loop_is_proportional_with_feed_forward_within_its_bound():
    assert position_speed(1.0, 0.5, 0.9, 10.0, 3.0) == pytest.approx(1.5)
    assert position_speed(1.0, 0.0, -1.0, 10.0, 3.0) == 3.0
    assert position_speed(-1.0, 0.0, 1.0, 10.0, 3.0) == -3.0


@pytest.mark.unit
def test_a_position_command_is_followed_then_held_at_its_target_when_it_times_out():
    settings = HoldSettings(timeout_s=0.1, hold_timeout_s=2.0, brake=False, deceleration_rad_s2=50.0, gain_per_s=5.0,
                            hold_speed_rad_s=2.0, velocity_limit_rad_s=4.0)
    hold = CommandHold(settings, 0.0)
    hold.command(0.0, 0.2, 0.01, theta_ref=1.0)
    assert hold.reference(0.05, DT_S, 0.0) == (pytest.approx(4.0), 0.01, True), "0.2 + 5 × 1 bounded at 4"
    assert hold.reference(0.05, DT_S, 0.9)[0] == pytest.approx(0.7)
    speed, _, torque = hold.reference(0.2, DT_S, 0.9)
    assert hold.mode == HOLDING and hold.theta_hold == 1.0 and torque
    assert speed == pytest.approx(0.5), "held at the target, the hold's bound"
    hold.command(0.3, 1.5)
    assert math.isnan(hold.theta_ref) and hold.reference(0.3, DT_S, 0.9)[0] == 1.5, "a speed command takes over"


ROOT = Path(__file__).resolve().parent.parent
DRAWN_SEED = 4
"""Not the docs' seed 1 (docs/random-motors.md): the property is checked on a draw it was not tuned on."""


def assert_homed_and_within_tolerance(row):
    """A run of drift_run: homed, its homing error within the drive's peak angle error over n_p, its drift within
    twice that (each end within it), and no slip of a pole pair (2π/n_p, far beyond)."""
    assert not row["failed"], row
    n_p = row["n_p"]
    assert abs(row["homing_error_rad"]) <= PEAK_ERROR_E_RAD / n_p, row
    assert abs(row["drift_rad"]) <= row["tolerance_rad"] == pytest.approx(2.0 * PEAK_ERROR_E_RAD / n_p), row
    assert row["peak_deviation_rad"] < math.pi / n_p, row


@pytest.mark.parametrize("direction", [1.0, -1.0])
def test_the_shipped_motor_homes_against_a_stop_and_its_position_does_not_drift(direction):
    """wang_spmsm (2 pole pairs: two mechanical angles per electrical one), a stop above or below the start."""
    row = drift_run("wang_spmsm", ROOT / "commissioning" / "wang_spmsm.yaml", direction)
    assert_homed_and_within_tolerance(row)


def check_draw(count, seed, folder):
    """Every drawn motor with n_p > 1 is refused by the drive (saying why), or homes and holds its position within
    the tolerance, or says it lost its lock and with it the homed position (never a silent slip); at least half of
    them home and hold."""
    rows = drawn_rows(count, seed, folder)
    ran = [row for row in rows if not row["failed"].startswith(("refused: ", "lost: "))]
    assert len(ran) >= count / 2, rows
    for row in ran:
        assert row["n_p"] > 1
        assert_homed_and_within_tolerance(row)


def test_drawn_motors_with_several_pole_pairs_home_and_hold_their_position(tmp_path):
    check_draw(6, DRAWN_SEED, tmp_path)


@pytest.mark.heavy
def test_a_larger_draw_homes_and_holds_its_position(tmp_path):
    check_draw(30, DRAWN_SEED + 1, tmp_path)


@pytest.mark.unit
@pytest.mark.parametrize("side", [1.0, -1.0])
def test_a_shaft_pushed_into_its_end_stop_rests_where_the_spring_carries_the_load(side):
    """The plant's end stop (pmsm_plant.model.end_stop_torque): a constant torque of 0.05 N·m pushes the shaft into
    the stop; it comes to rest at θ_stop + τ/k (the spring's deflection), within 1 µrad, and never gets further in
    than the energy it hit with allows (½ k d² ≤ ½ J ω² + τ d at the deepest point d)."""
    import numpy as np

    from pmsm_plant.build import with_end_stop
    from pmsm_plant.model import N_STATE, OMEGA_M, THETA_M, plant_advance, plant_reset
    from pmsm_plant.params import IDEAL_SENSOR, InverterParams, MechanicsParams, PlantParams
    from pmsm_plant.presets import PRESETS
    machine = PRESETS["wang_spmsm"].machine
    stop = {"low_rad": None, "high_rad": None, "stiffness_Nm_rad": 200.0, "damping_Nms_rad": None}
    stop["high_rad" if side > 0 else "low_rad"] = side * 0.5
    mechanics = with_end_stop(MechanicsParams(J_kgm2=1e-4, B_Nms=0.0), stop, 1e-4, "test")
    assert mechanics.stop_damping_Nms_rad == pytest.approx(2.0 * math.sqrt(200.0 * 1e-4)), "critical by default"
    params = PlantParams(machine, mechanics, InverterParams(1000.0, 0.0, 0.05, 0), IDEAL_SENSOR, 0, 1e-4, 1)
    x = np.zeros(N_STATE)
    plant_reset(x, 0.0, 0.0, machine)
    hit_speed, deepest = 0.0, 0.0
    for _ in range(30000):
        omega = abs(x[OMEGA_M])
        plant_advance(x, 0.0, 0.0, -side * 0.05, False, 0.0, params)
        depth = side * x[THETA_M] - 0.5
        if depth > 0.0 and hit_speed == 0.0:
            hit_speed = omega
        deepest = max(deepest, depth)
    assert x[THETA_M] == pytest.approx(side * (0.5 + 0.05 / 200.0), abs=1e-6) and abs(x[OMEGA_M]) < 1e-6
    assert hit_speed > 1.0
    assert 0.5 * 200.0 * deepest ** 2 <= 0.5 * 1e-4 * hit_speed ** 2 + 0.05 * deepest + 1e-9


@pytest.mark.unit
def test_an_end_stop_too_stiff_for_the_step_is_refused_naming_the_key():
    from drive_common.config.drive_config import ScenarioError
    from pmsm_plant.build import with_end_stop
    from pmsm_plant.params import MechanicsParams
    stop = {"low_rad": -1.0, "high_rad": None, "stiffness_Nm_rad": 1e9, "damping_Nms_rad": None}
    with pytest.raises(ScenarioError, match=r"^arm.yaml: end_stop.stiffness_Nm_rad: 1e\+09 N·m/rad"):
        with_end_stop(MechanicsParams(J_kgm2=1e-4, B_Nms=0.0), stop, 1e-4, "arm.yaml")


@pytest.mark.unit
def test_a_homed_zero_is_lost_with_the_estimators_lock_and_not_found_again_unasked():
    """After a lost lock the estimator re-finds the electrical angle, the mechanical one only modulo 2π/n_p: the
    zero is gone (LOST, the position NaN) until the joint is homed again."""
    from foc_controller.position import LOST
    h = homing()
    for _ in range(25):
        h.reference(DT_S, (-1.0, 0.0), -2.0)
    h.reference(DT_S, (h.target, 0.0), 0.0)
    assert h.homed
    h.lose("estimator state 4 (not tracking)")
    assert h.state == LOST and "home again" in h.reason and math.isnan(h.position(0.0))
    assert h.reference(DT_S, (0.0, 0.0), 0.0) == 0.0 and h.state == LOST
    h.start()
    assert h.state == SEEKING
