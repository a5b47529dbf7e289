"""Random motors (issue 51): the draw is reproducible and physically consistent over its whole range; the
motor's own experiments scale with the motor's rating; the random bench gives every motor of a fixed small
draw one verdict of the issue's set and its counts add up (not that every motor works); the predicted angle error
holds within its factor on a few drawn motors."""
import math

import numpy as np
import pytest

from drive_common.config.motor_experiments import LOW_SPEED_PER_RATED, ExperimentOptions, experiment_names
from drive_common.config.scenario import ScenarioError, load_scenario, motor_experiment
from drive_common.motor.motor_file import motor_from_mapping
from drive_tools.cli.cli import main
from drive_tools.evaluation.motor_bench import (
    CASES,
    INJECTIONS,
    PEAK_TARGET_RAD,
    RMS_TARGET_RAD,
    VERDICTS,
    TrialOptions,
    motor_trial,
)
from drive_tools.evaluation.random_motor_bench import (
    PREDICTION_FACTOR,
    RandomBenchOptions,
    compact_row,
    prediction_rows,
    random_motor_bench,
)
from drive_tools.evaluation.random_motors import (
    ACCELERATION_TIME_S,
    BUS_USE,
    TRUTH_SPREAD,
    draw_motor,
    draw_motors,
    write_motor_files,
)
from pmsm_plant.presets import plant_truth

DRAW = 300
"""Motors of the property checks (drawing is cheap; running them is the bench's)."""


@pytest.fixture(scope="module")
def drawn():
    return draw_motors(DRAW, 7)


def test_the_draw_is_reproducible_and_motor_i_is_the_same_for_any_count():
    five = draw_motors(5, 3)
    assert [m.document for m in five] == [m.document for m in draw_motors(5, 3)]
    assert [m.document for m in draw_motors(2, 3)] == [m.document for m in five[:2]]
    assert draw_motor(4, 0).document["nameplate"] != five[0].document["nameplate"]


def test_the_draw_covers_the_stated_ranges(drawn):
    plates = [m.document["nameplate"] for m in drawn]
    buses = [m.document["inverter"]["U_dc_V"] for m in drawn]
    assert {p["n_p"] for p in plates} <= set(range(1, 31)) and len({p["n_p"] for p in plates}) >= 25
    powers = [p["rated_power_W"] for p in plates]
    assert 10.0 <= min(powers) < 20.0 and 2500.0 < max(powers) <= 5000.0
    assert 12.0 <= min(buses) < 20.0 and 400.0 < max(buses) <= 600.0
    ratios = [p["L_q_H"] / p["L_d_H"] for p in plates]
    assert 1.0 - 1e-5 <= min(ratios) and 3.0 < max(ratios) <= 3.5 + 1e-5
    kinds = {(m.figures["rotor"], m.figures["saturation"], m.figures["cross_saturation"]) for m in drawn}
    assert len(kinds) == 8, "surface and interior magnets, saturation and cross-saturation each on and off"
    times = [m.figures["acceleration_time_s"] for m in drawn]
    assert max(times) / min(times) > 300.0, "J over (nearly) three decades for the power"
    assert ACCELERATION_TIME_S[0] <= min(times) and max(times) <= ACCELERATION_TIME_S[1]
    assert {m.figures["power_class"] for m in drawn} == {"10-100 W", "100 W-1 kW", "1-5 kW"}


def test_every_drawn_motor_is_physically_consistent(drawn):
    """The bus drives rated speed at rated torque (i_d = 0) within the linear range, the torque is the
    magnet's at rated current, the limit lies between rated current and the inverter's rating, the truth
    within ±10 % of the nameplate, and the motor file and its plant section are read without complaint."""
    for m in drawn:
        motor = motor_from_mapping(m.document, m.name, whole_file=True)
        plate, bus = motor.nameplate, motor.inverter.U_dc_V
        omega_e = plate.n_p * plate.rated_speed_rpm * math.pi / 30.0
        current = plate.rated_current_A
        u = math.hypot(plate.R_s_ohm * current + omega_e * plate.psi_f_Wb, omega_e * plate.L_q_H * current)
        assert BUS_USE[0] - 1e-4 <= u / (bus / math.sqrt(3.0)) <= BUS_USE[1] + 1e-4, m.name
        assert plate.rated_torque_Nm == pytest.approx(1.5 * plate.n_p * plate.psi_f_Wb * current, rel=1e-4)
        assert plate.rated_power_W == pytest.approx(plate.rated_torque_Nm * plate.rated_speed_rpm * math.pi / 30.0,
                                                    rel=1e-4)
        assert current < plate.current_limit_A <= motor.inverter.current_rating_A
        truth = plant_truth(motor)
        assert abs(truth.machine.R_s_ohm / plate.R_s_ohm - 1.0) <= TRUTH_SPREAD + 1e-5
        assert abs(truth.machine.psi_f_Wb / plate.psi_f_Wb - 1.0) <= TRUTH_SPREAD + 1e-5
        assert abs(truth.machine.L_q_H / plate.L_q_H - 1.0) <= TRUTH_SPREAD + 1e-5
        if m.figures["rotor"] == "surface":
            assert truth.machine.L_d_H == pytest.approx(truth.machine.L_q_H, rel=1e-5), "a round rotor"
        if not m.figures["saturation"] and not m.figures["cross_saturation"]:
            assert truth.machine.a_d == truth.machine.a_q == truth.machine.a_dq == 0.0


def test_motor_files_are_written_and_read_back(tmp_path):
    motors = draw_motors(3, 11)
    paths = write_motor_files(motors, tmp_path / "motors")
    for motor, path in zip(motors, paths):
        assert path.name == f"{motor.name}.yaml"
        assert load_scenario("low_speed", motor_override=str(path)).motor.name == motor.name


@pytest.mark.parametrize("index", [0, 5, 9])
def test_the_motors_own_experiments_scale_with_its_rating(index, tmp_path):
    """Speeds are shares of rated speed (5 %, 10 % after the step, −5 % after the reversal, zero when
    holding), the load a share of rated torque; the drive's loops are left to the motor (no injection set) and
    the injection to the loops' rule."""
    path = write_motor_files([draw_motor(2, index)], tmp_path)[0]
    motor = load_scenario("low_speed", motor_override=str(path)).motor
    rated_rad_s = motor.nameplate.rated_speed_rpm * math.pi / 30.0
    low = LOW_SPEED_PER_RATED * rated_rad_s
    expected = {"standstill_hold": (0.0, 0.0, 0.0), "low_speed": (low, low, 0.0), "rated_load": (low, low, 1.0),
                "speed_step": (2.0 * low, 2.0 * low, 0.0), "reversal": (low, -low, 0.0)}
    for name in experiment_names():
        scenario = motor_experiment(name, str(path), options=ExperimentOptions(load_per_rated=0.5))
        speeds, loads = scenario.schedule()
        top, last, load = expected[name]
        assert np.max(np.abs(speeds)) == pytest.approx(top, rel=1e-9)
        assert speeds[-1] == pytest.approx(last, rel=1e-9)
        assert np.max(loads) == pytest.approx(0.5 * load * motor.nameplate.rated_torque_Nm, rel=1e-9)
        assert scenario.injection == {} and scenario.estimator_settings == {"injection_by_rule": True}
        assert scenario.initial_theta_m_rad == pytest.approx(ExperimentOptions().theta_e_rad / motor.nameplate.n_p)


def test_an_experiment_without_a_motor_is_refused_naming_the_option(capsys):
    with pytest.raises(ScenarioError, match="--motor"):
        load_scenario("low_speed", motor_source="--motor")
    assert main(["run", "rated_load", "--no-plot"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "rated_load" in err and "--motor" in err


@pytest.mark.parametrize("argv, option", [(["--random", "0"], "--random"),
                                          (["--random", "2", "--starts", "0"], "--starts"),
                                          (["--random", "2", "--workers", "0"], "--workers"),
                                          (["--random", "2", "--sample-period", "1"], "--sample-period")])
def test_the_random_bench_refuses_bad_options_in_one_line(argv, option, capsys, tmp_path):
    assert main(["bench", "motors", *argv, "--out", str(tmp_path / "m")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and option in err
    assert not (tmp_path / "m").exists()


def test_a_small_random_draw_gets_a_verdict_per_motor_and_counts_that_add_up(tmp_path):
    """The fixed small draw of the suite (the full table: `drive bench motors --random N`, docs/results.md):
    each motor one verdict of the issue's set; a refusal has its reason and exit 2 for every case; a
    failure names its problems; a motor that works ran every case with exit 0 within ours' targets."""
    lines = []
    report = random_motor_bench(RandomBenchOptions(4, 1, tmp_path / "motors", starts=2, workers=1), lines.append)
    rows, summary = report["rows"], report["summary"]
    assert len(rows) == 4 and len(lines) == 4 and report["interrupted"] == 0
    assert sum(summary["verdicts"].values()) == summary["motors"] == 4
    for title, table in summary["by_class"].items():
        assert sum(sum(counts.values()) for counts in table.values()) == 4, title
    refused = [r for r in rows if r["verdict"] == "refused up front"]
    assert sum(summary["refusal_reasons"].values()) == len(refused)
    assert sum(summary["failure_kinds"].values()) == summary["verdicts"]["failure"]
    for row in rows:
        assert row["verdict"] in VERDICTS
        assert set(row["exit_codes"]) == set(CASES)
        if row["verdict"] == "refused up front":
            assert row["reason"] and "\n" not in row["reason"] and set(row["exit_codes"].values()) == {2}
        elif row["verdict"] == "failure":
            assert row["problems"] and row["reason"]
        elif row["verdict"] == "works above a speed":
            assert "works above" in row["reason"] and "no standstill torque" in row["reason"]
            assert row["exit_codes"].pop("standstill_hold") == 2 and set(row["exit_codes"].values()) == {0}
            assert all(c["angle_error_rms"] <= RMS_TARGET_RAD and c["angle_error_peak"] <= PEAK_TARGET_RAD
                       for name, c in row["cases"].items() if name != "standstill_hold")
        else:
            assert set(row["exit_codes"].values()) == {0}
            assert all(c["angle_error_rms"] <= RMS_TARGET_RAD and c["angle_error_peak"] <= PEAK_TARGET_RAD
                       for c in row["cases"].values())
            assert row["polarity_correct"]["correct"] == row["polarity_correct"]["starts"]
    assert {r["file"] for r in rows} == {str(p) for p in sorted((tmp_path / "motors").glob("*.yaml"))}


def test_a_trial_that_raises_is_a_failure_row_not_a_lost_one(tmp_path, monkeypatch):
    import drive_tools.evaluation.random_motor_bench as bench

    def crash(path, options):
        raise FloatingPointError("overflow in the plant")
    monkeypatch.setattr(bench, "motor_trial", crash)
    report = random_motor_bench(RandomBenchOptions(2, 5, tmp_path, workers=1))
    assert [row["verdict"] for row in report["rows"]] == ["failure", "failure"]
    assert report["summary"]["failure_kinds"] == {"the trial raised FloatingPointError: overflow in the plant": 2}


@pytest.mark.heavy
def test_a_larger_random_draw_gets_a_verdict_per_motor(tmp_path):
    report = random_motor_bench(RandomBenchOptions(24, 2, tmp_path / "motors", starts=4, workers=2))
    assert report["summary"]["motors"] == 24 == sum(report["summary"]["verdicts"].values())
    assert all(row["verdict"] in VERDICTS for row in report["rows"])


@pytest.mark.parametrize("seed, index", [pytest.param(2, 7, marks=pytest.mark.heavy), (2, 8),
                                         pytest.param(2, 9, marks=pytest.mark.heavy), (2, 11),
                                         pytest.param(2, 35, marks=pytest.mark.heavy), (1, 148)])
def test_the_predicted_angle_error_holds_within_its_factor_on_drawn_motors(seed, index, tmp_path):
    """Issue 51 item 4 on a fixed small draw (seed 2: motor 7 on the sine carrier, 8 and 9 on the square wave the
    loops' rule chose, 11 refused for its weak angle signal, 35 on the sine with its dead-time model, which the
    dead time's 0.017 rad bias put at 2.9× its prediction without it; seed 1 motor 148, whose dead time, 0.24 of
    the saliency's share of the carrier, put it at 2.4× without the model): where the motor runs, its measured
    low-speed angle error RMS is within PREDICTION_FACTOR (0.5-2×) of the one predicted before running; the refused
    motor, run anyway (`--force`), misses ours' targets or loses the angle as its prediction said. Every motor that
    ran says which injection ran and ran the rated load on both. (A refused motor's verdict is then its I-f
    trial's, issue 52 item 3.)"""
    path = write_motor_files([draw_motor(seed, index)], tmp_path)[0]
    row = motor_trial(str(path), TrialOptions(1e-4, 1, (seed, index)))
    predictions = prediction_rows([compact_row(row, {})])
    assert len(predictions) == 1, row["reason"]
    p = predictions[0]
    low, high = PREDICTION_FACTOR
    if p["refused"]:
        assert row["verdict"] in ("refused up front", "works above a speed", "failure")
        assert p["predicted_rms"] > RMS_TARGET_RAD or p["predicted_peak"] > PEAK_TARGET_RAD
        assert (p["measured_rms"] is None or p["measured_rms"] > RMS_TARGET_RAD
                or p["measured_peak"] > PEAK_TARGET_RAD)
    else:
        assert low <= p["ratio_rms"] <= high, p
        assert row["injection"] in INJECTIONS and set(row["rated_load_by_injection"]) == set(INJECTIONS)
