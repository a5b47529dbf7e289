"""`drive tune current|speed|pll`: the bandwidth/damping method reproduces Szabó Table 2 where it can,
the speed loop stays below the PLL, and tune pll reports both models and each estimator's mapping."""
import json
import math

import numpy as np
import pytest

from drive_tools.cli.cli import main
from foc_controller.params import make_controller_params
from foc_controller.tuning import SZABO_TABLE2

pytestmark = pytest.mark.unit


def run_json(capsys, *argv):
    assert main(list(argv) + ["--json"]) == 0
    return json.loads(capsys.readouterr().out)


@pytest.mark.parametrize("axis, bandwidth, damping", [("q", 377.0, 1.0), ("d", 565.5, 0.78)])
def test_current_gains_reproduce_table2(capsys, axis, bandwidth, damping):
    """Table 2's current PIs are this method's at round values: q 60 Hz (377 rad/s) with ζ = 1, d 90 Hz
    (565.5 rad/s) with ζ = 0.78; within 1 %."""
    report = run_json(capsys, "tune", "current", "--axis", axis, "--bandwidth", str(bandwidth),
                      "--damping", str(damping))
    gains, table = report["gains"][axis], SZABO_TABLE2[axis]
    assert gains["A_p"] == pytest.approx(table.kp, rel=0.01)
    assert gains["T_i_s"] == pytest.approx(table.kp / table.ki, rel=0.01)
    assert report["table2"][axis]["bandwidth_rad_s"] == pytest.approx(bandwidth, rel=0.01)


def test_speed_gains_reproduce_table2_and_stay_below_the_pll(capsys):
    report = run_json(capsys, "tune", "speed", "--bandwidth", "55.9", "--pll-crossover", "350")
    table = SZABO_TABLE2["speed"]
    assert not report["limited_by_pll"]
    assert report["gains"]["A_p"] == pytest.approx(table.kp, rel=0.02)
    assert report["gains"]["T_i_s"] == pytest.approx(table.kp / table.ki, rel=0.02)
    report = run_json(capsys, "tune", "speed", "--bandwidth", "55.9", "--commissioning", "nameplate")
    assert report["limited_by_pll"]
    assert report["pll_crossover_rad_s"] == pytest.approx(68.7, abs=0.5)
    assert report["bandwidth_rad_s"] == pytest.approx(0.25 * 68.7, abs=0.2)


def test_tune_pll_reports_both_models_and_the_mapping(capsys, tmp_path):
    report = run_json(capsys, "tune", "pll", "--crossover", "175", "--out", str(tmp_path), "--commissioning",
                      "nameplate")
    assert report["tuned"]["szabo"]["A_p"] == pytest.approx(2899.3, abs=1.0)
    assert report["tuned"]["carrier"]["phase_margin_deg"] == pytest.approx(60.0, abs=1.0)
    assert report["current_gains"]["szabo"]["crossover_rad_s"] == pytest.approx(268.3, abs=0.5)
    assert {p.rsplit("_", 1)[-1] for p in report["plots"]} == {"process.png", "loop.png"}
    report = run_json(capsys, "tune", "pll", "--estimator", "improved", "--motor", "wang_spmsm", "--no-plot")
    assert "szabo" not in report["tuned"] and "not of Szabó's form" in report["mapping"]
    assert main(["tune", "pll", "--estimator", "improved", "--motor", "wang_spmsm", "--model", "szabo"]) == 2
    assert "--model szabo" in capsys.readouterr().err


def test_tune_pll_picks_the_largest_loop_filter_for_a_crossover(capsys):
    report = run_json(capsys, "tune", "pll", "--crossover", "350", "--T-f", "auto", "--no-plot")
    assert report["T_f_s"] == pytest.approx(0.488e-3, rel=0.02)
    tuned = report["tuned"]["carrier"]
    assert (tuned["crossover_rad_s"], tuned["phase_margin_deg"]) == pytest.approx((350.0, 60.0), abs=1.0)
    assert main(["tune", "pll", "--crossover", "350", "--T-f", "auto", "--model", "szabo"]) == 2
    assert "out of reach" in capsys.readouterr().err


@pytest.mark.parametrize("delay_periods", [1, 5, 10, 20])
def test_current_loops_stay_damped_with_the_delay_of_blocks(delay_periods):
    """With 'rule' gains the current loop of wang_spmsm, sampled at 10 kHz with its whole delay d (blocks
    of N samples: d = N), answers a current step without growing: overshoot ≤ 25 %, within 2 % of the step
    after 40 loop delays. Without the delay cap the default 250 Hz overshoots 70 % at d = 3 and diverges
    at d = 5."""
    from drive_common.motor.motor_file import load_motor

    motor, T_s = load_motor("wang_spmsm", "test"), 1e-4
    plate, rating = motor.nameplate, motor.inverter._replace(delay_periods=delay_periods)
    c = make_controller_params(plate, rating, T_s)
    a = math.exp(-plate.R_s_ohm * T_s / plate.L_d_H)
    b = (1.0 - a) / plate.R_s_ohm
    n = 40 * (delay_periods + 1) + 200
    i, integral, u = np.zeros(n + 1), 0.0, np.zeros(n)
    for k in range(n):
        e = 1.0 - i[k]
        u[k] = c.kp_d * e + integral
        integral += T_s * c.ki_d * e
        i[k + 1] = a * i[k] + b * (u[k - delay_periods] if k >= delay_periods else 0.0)
    assert i.max() <= 1.25
    assert np.abs(i[40 * (delay_periods + 1):] - 1.0).max() <= 0.02
