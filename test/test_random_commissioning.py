"""Commissioning over a fixed small random draw (issue 51 item 1, docs/random-motors.md): every salient motor
(HF saliency L_qh/L_dh or its inverse ≥ 1.3) is commissioned, not refused, and what commissioning measures
(R_s, L_dh, L_qh; ψ_f and J by the rotating test where the nameplate gives no J) lies within 10 % of the
plant's truth. The motors are those the draw gives, not chosen: the salient ones among the first DRAWN of
seed SEED."""
import math

import pytest

from drive_common.config.motor_experiments import ExperimentOptions
from drive_common.config.scenario import motor_experiment
from drive_common.motor.commissioning import save_commissioning
from drive_tools.evaluation.motor_bench import IDENTIFICATION_TOLERANCE, NOT_APPLICABLE
from drive_tools.evaluation.random_motor_bench import SALIENT_RATIO
from drive_tools.evaluation.random_motors import draw_motors, write_motor_files
from drive_tools.runner.commissioning_run import commission_in_process, rotating_test_in_process

SEED, DRAWN = 3, 16


def _salient(motor):
    ratio = motor.figures["L_qh_per_L_dh"]
    return max(ratio, 1.0 / ratio) >= SALIENT_RATIO


MOTORS = [i for i, motor in enumerate(draw_motors(DRAWN, SEED)) if _salient(motor)]


@pytest.mark.parametrize("index", MOTORS)
def test_a_salient_drawn_motor_is_commissioned_within_ten_percent(index, tmp_path):
    """Standstill commissioning, then the rotating test where the nameplate gives no J: no refusal, and every
    value measured within IDENTIFICATION_TOLERANCE (10 %) of the plant's truth."""
    path = write_motor_files(draw_motors(index + 1, SEED)[index:], tmp_path)[0]
    scenario = motor_experiment("standstill_hold", str(path), "test",
                                options=ExperimentOptions(1e-4, commissioning="nameplate"))
    record_file = tmp_path / f"{path.stem}_commissioning.yaml"
    try:
        run = commission_in_process(scenario)
        record = run.procedure.result()
        errors = {key: getattr(record, key) / run.truth[key] - 1.0 for key in ("R_s_ohm", "L_dh_H", "L_qh_H")}
        save_commissioning(record_file, record, scenario.motor.name, "test")
        if not math.isfinite(scenario.motor.nameplate.J_kgm2):
            estimates, truth, _ = rotating_test_in_process(scenario, record_file)
            errors.update({key: estimates[key] / truth[key] - 1.0 for key in ("psi_f_Wb", "J_kgm2")})
    except NOT_APPLICABLE as refusal:
        pytest.fail(f"{path.stem} (salient) refused by commissioning: {refusal}")
    beyond = {key: f"{100.0 * error:+.1f} %" for key, error in errors.items()
              if abs(error) > IDENTIFICATION_TOLERANCE}
    assert not beyond, f"{path.stem}: identified beyond 10 %: {beyond}"
