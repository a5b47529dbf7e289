"""The metrics people read: settling time means "entered and stayed in its settled envelope", never
settled and no step are told apart, and a lost lock is reported plainly. Synthetic logs, exact answers."""
import numpy as np
import pytest

from drive_common.config.scenario import parse_scenario
from drive_common.contract.log import COLUMN, LOG_COLUMNS
from drive_tools.evaluation.metrics import LOCK_LOST_RAD, lock_loss, settling_summary, settling_times

pytestmark = pytest.mark.unit

T_S = 1e-3


def scenario(points, interpolation="step"):
    return parse_scenario({"motor": "wang_spmsm", "estimator": "sensored", "duration_s": 2.0,
                           "sampling_period_s": T_S,
                           "speed": {"unit": "rad_s", "interpolation": interpolation, "points": points}},
                          "synthetic", "synthetic.yaml")


def log_of(omega):
    log = np.zeros((omega.size, len(LOG_COLUMNS)))
    log[:, COLUMN["t"]] = np.arange(omega.size) * T_S
    log[:, COLUMN["omega_m"]] = omega
    return log


def first_order(t, t_step, target, tau):
    return np.where(t < t_step, 0.0, target * (1.0 - np.exp(-(t - t_step) / tau)))


def test_settling_is_unaffected_by_a_steady_ripple_wider_than_five_percent():
    """10 rad/s step at 0.5 s, τ = 50 ms, plus ±1 rad/s ripple (twice the ±5 % band): the settled
    envelope is offset + peak ripple (≈ 1 rad/s), and the speed is in it for good once the exponential's
    remainder is below what the ripple leaves (between τ·ln(10/1.01) = 0.115 s and τ·ln(1000) = 0.345 s);
    the ±5 % band alone never saw it settle."""
    t = np.arange(2000) * T_S
    ripple = 1.0 * np.sin(2 * np.pi * 37.0 * t)
    steps = settling_times(scenario([[0.0, 0.0], [0.5, 10.0]]), log_of(first_order(t, 0.5, 10.0, 0.05) + ripple))
    assert len(steps) == 1
    step = steps[0]
    assert step["band_rad_s"] == pytest.approx(1.0, abs=0.02) and step["tolerance_rad_s"] == 0.5
    assert 0.115 <= step["settling_time_s"] <= 0.346
    assert settling_summary(steps) == (step["settling_time_s"], None)


def test_a_speed_that_stays_off_its_reference_never_settled_and_says_so():
    t = np.arange(2000) * T_S
    steps = settling_times(scenario([[0.0, 0.0], [0.5, 10.0]]), log_of(first_order(t, 0.5, 8.0, 0.05)))
    assert steps[0]["settling_time_s"] is None
    value, note = settling_summary(steps)
    assert value is None and note.startswith("never settled after the step at 0.5 s")


def test_no_step_is_not_never_settled():
    steps = settling_times(scenario([[0.0, 5.0]]), log_of(np.full(2000, 5.0)))
    assert settling_summary(steps) == (None, "no speed step in the run")


def test_a_ramp_settles_from_its_end():
    """A linear ramp 0 → 10 rad/s over 0.1 s to 0.2 s, followed exactly: settled at the ramp's end."""
    t = np.arange(2000) * T_S
    omega = np.interp(t, [0.0, 0.1, 0.2], [0.0, 0.0, 10.0])
    steps = settling_times(scenario([[0.0, 0.0], [0.1, 0.0], [0.2, 10.0]], "linear"), log_of(omega))
    assert [s["t_s"] for s in steps] == [0.2] and steps[0]["settling_time_s"] == 0.0


def test_a_lost_lock_is_measured_from_ground_truth():
    t = np.arange(1000) * T_S
    error = np.where((t >= 0.3) & (t < 0.5), 3.0, 0.01)
    lost_s, first_s = lock_loss(t, error, start_s=0.1)
    assert lost_s == pytest.approx(0.2) and first_s == pytest.approx(0.3)
    assert lock_loss(t, np.full(1000, LOCK_LOST_RAD / 2), 0.0) == (0.0, None)
    assert lock_loss(t, np.full(1000, np.nan), 0.0) == (None, None)


def test_run_plots_of_run_launch_and_bridge_do_not_overwrite_one_another(tmp_path):
    import dataclasses

    from drive_common.config.scenario import load_scenario
    from drive_tools.evaluation.plots import plot_run
    from drive_tools.runner.runner import run_scenario
    result = run_scenario(dataclasses.replace(load_scenario("wang_load_step"), duration_s=0.05))
    paths = {plot_run(result, tmp_path, command) for command in ("run", "launch", "bridge")}
    assert len(paths) == 3 and all(p.is_file() and p.stat().st_size > 10_000 for p in paths)


def test_a_corner_between_two_ramps_is_not_a_step_to_settle_after():
    """Ramps 0 → 10 → 30 rad/s then a hold: only the last ramp's end (where the reference holds) is a change
    to settle after; the corner at 0.5 s is not (the reference goes on ramping)."""
    s = scenario([[0.0, 0.0], [0.5, 10.0], [1.0, 30.0], [2.0, 30.0]], "linear")
    t = np.arange(s.n_samples) * T_S
    steps = settling_times(s, log_of(s.speed.sample(t)))
    assert [step["t_s"] for step in steps] == [1.0] and steps[0]["settling_time_s"] == 0.0
