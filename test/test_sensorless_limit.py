"""A load beyond the torque the drive states it holds sensorless (issue 52 item 1): the drive holds its
limit, keeps its angle and says so (exit 6 naming the figure in --json and on stderr), never a lost lock and
zero torque. On a drawn interior-magnet motor (seed 11, motor 67: L_q/L_d 2.98, 23 pole pairs, J on its
nameplate) commissioned as a robot builder does (`drive commission low_speed --motor F --loaded`), run
through its own rated-load experiment with the load at OVERLOAD × the stated torque."""
import json

import pytest
import yaml

from drive_common.config.motor_experiments import ExperimentOptions, experiment_document
from drive_common.contract.exit_codes import EXIT_NOT_FOLLOWING
from drive_common.motor.motor_file import load_motor
from drive_tools.cli.cli import main
from drive_tools.evaluation.motor_bench import PEAK_TARGET_RAD, RMS_TARGET_RAD
from drive_tools.evaluation.random_motors import draw_motor, write_motor_files

OVERLOAD = 1.15
"""The load per the stated sensorless torque."""


@pytest.fixture(scope="module")
def commissioned(tmp_path_factory):
    """(motor file, commissioning file, `drive commission --json`'s report) of the drawn motor."""
    folder = tmp_path_factory.mktemp("sensorless_limit")
    motor_file, = write_motor_files([draw_motor(11, 67)], folder)
    out = folder / "commissioning.yaml"
    return motor_file, out, folder


def test_commission_states_the_sensorless_torque_and_a_larger_load_is_held_at_it(commissioned, capsys):
    """`drive commission --json` states the torque (N·m, share of rated, current, MTPA, what sets it); a run
    loaded to OVERLOAD × that torque ends with the current reference held at the limit, ours' angle within
    its targets (RMS ≤ 0.02 rad, peak ≤ 0.15 rad) and tracking to the end, exit 6 with the fault naming the
    stated figure in --json and the one-line reason on stderr."""
    motor_file, out, folder = commissioned
    assert main(["commission", "low_speed", "--motor", str(motor_file), "--loaded", "--out", str(out),
                 "--json"]) == 0
    stated = json.loads(capsys.readouterr().out)["sensorless_torque"]
    assert stated["mtpa"] and stated["d_current_A"] < 0.0 and stated["torque_Nm"] > stated["torque_zero_d_Nm"]
    assert stated["line"].startswith(f"sensorless torque limit {stated['torque_Nm']:.3g} N·m "
                                     f"({100.0 * stated['rated_share']:.0f} % of rated)")
    assert main(["motor", "show", str(motor_file), "--scenario", "low_speed", "--commissioning", str(out),
                 "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["sensorless_torque"]["line"] == stated["line"]

    motor = load_motor(str(motor_file))
    share = OVERLOAD * stated["rated_share"]
    document = experiment_document("rated_load", motor, ExperimentOptions(1e-4, 1.0, 1, share, str(out)))
    scenario = folder / "overload.yaml"
    scenario.write_text(yaml.safe_dump(document))
    code = main(["run", str(scenario), "--json", "--no-plot", "--out", str(folder / "runs")])
    captured = capsys.readouterr()
    metrics = json.loads(captured.out)
    assert code == EXIT_NOT_FOLLOWING and metrics["sensorless_torque"]["line"] == stated["line"]
    faults = metrics["supervision"]
    assert faults and all(fault["torque_limit"] == stated["line"] for fault in faults)
    assert "dragged backwards" in {fault["kind"] for fault in faults}
    assert stated["line"] in captured.err
    assert metrics["angle_error_rms"] <= RMS_TARGET_RAD and metrics["angle_error_peak"] <= PEAK_TARGET_RAD
    assert not metrics["lock_lost_s"]
