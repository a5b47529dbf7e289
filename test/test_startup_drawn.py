"""On motors drawn, not chosen (docs/startup.md "Pulses from the commissioning", docs/hf-demodulation.md §5):
the start-up of many-pole, low-inertia rotors commissioned in simulation, and ours' angle error predicted
before running against the error measured, over a seeded draw of saliency values."""
import math

import numpy as np
import pytest

from drive_common.config.scenario import parse_scenario
from drive_common.motor.commissioning import load_commissioning, save_commissioning
from drive_tools.evaluation.metrics import compute_metrics
from drive_tools.evaluation.startup_bench import drawn_startup_bench
from drive_tools.runner.commissioning_run import commission_in_process
from drive_tools.runner.runner import build_drive, run_scenario
from hf_estimator.build import predicted_error

PREDICTION_FACTOR = 1.6
"""Measured over predicted RMS lies within [1/this, this]: the prediction holds the sensor noise only, the
measurement adds the dead time, the rotor's motion and the fit's bias (1.16-1.33 measured on six draws,
2026-11-27)."""


def test_drawn_many_pole_rotors_start_with_the_right_polarity_or_are_refused_before_torque():
    """Three drawn many-pole, low-inertia motors, commissioned, each started from 4 angles: every start is
    the right pole and turns the shaft less than 5° backwards, or the drive refuses the motor up front naming
    the commissioned asymmetry (the bench at scale: `drive bench startup --drawn 10`, docs/results.md)."""
    reports = drawn_startup_bench(3, seed=2, angles=4, seeds=(1,))
    assert len(reports) == 3
    for report in reports:
        if report["refused"]:
            assert "polarity cannot be told before torque: saturation asymmetry" in report["refused"]
            continue
        started = [row for row in report["rows"] if row["completed"]]
        assert all(row["polarity_correct"] for row in started), report["motor"]
        assert report["reverse_rotation_max_m_deg"] is None or report["reverse_rotation_max_m_deg"] < 5.0


WEAK_BASE = """format_version: 1
name: sal_{j}
nameplate: {{n_p: 4, R_s_ohm: 0.25, L_d_H: 0.85e-3, L_q_H: {L_qh:.6g}, psi_f_Wb: 0.028, rated_current_A: 8.0,
            rated_speed_rpm: 3000.0, J_kgm2: 3.0e-4, B_Nms: 5.0e-5}}
inverter: {{U_dc_V: 48.0}}
plant: {{L_d_H: 0.9e-3, L_q_H: {L_q:.6g}, L_dh_H: 0.85e-3, L_qh_H: {L_qh:.6g}, t_dead_s: 0.5e-6}}
"""
"""A 400 W, 48 V surface-magnet servo whose saliency is drawn (L_qh over L_dh)."""


def test_ours_predicted_angle_error_holds_over_a_draw_of_saliency(tmp_path):
    """Three saliencies |Δ|/Σ drawn in [0.02, 0.12] (seed 7): each motor commissioned, ours run at 150 rpm
    told to run whatever its prediction (`--force`); the RMS angle error measured lies within
    PREDICTION_FACTOR of the one predicted before running."""
    rng = np.random.default_rng(7)
    for j in range(3):
        ratio = float(rng.uniform(0.02, 0.12))
        L_qh = 0.85e-3 * (1.0 + ratio) / (1.0 - ratio)
        motor = tmp_path / f"sal_{j}.yaml"
        motor.write_text(WEAK_BASE.format(j=j, L_qh=L_qh, L_q=1.06 * L_qh))

        def scenario(commissioning, duration_s, motor=motor, j=j):
            return parse_scenario({"motor": str(motor), "commissioning": commissioning, "duration_s": duration_s,
                                   "estimator": {"type": "injection_frame", "settings": {"run_refused": True}},
                                   "sampling_period_s": 1e-4, "metrics": {"settle_s": 0.2},
                                   "speed": {"unit": "rpm", "points": [[0.0, 150.0]]}}, f"sal_{j}", "test")
        measured = commission_in_process(scenario("nameplate", 0.5)).procedure.result()
        commissioning = save_commissioning(tmp_path / f"sal_{j}_c.yaml", measured, f"sal_{j}", "test")
        run = scenario(str(commissioning), 1.0)
        rms, peak, _ = predicted_error(build_drive(run).estimator, load_commissioning(commissioning)[0])
        metrics = compute_metrics(run_scenario(run))
        assert math.isfinite(rms) and peak == pytest.approx(4.0 * rms)
        assert 1.0 / PREDICTION_FACTOR <= metrics["angle_error_rms"] / rms <= PREDICTION_FACTOR, (ratio, rms, metrics)
