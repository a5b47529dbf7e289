"""The drive command line: JSON keys of a run, and one-line errors for bad scenario files."""
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from drive_common.config.scenario import load_scenario
from drive_common.contract.exit_codes import EXIT_NOT_TRACKING
from drive_common.contract.log import COLUMN
from drive_tools.cli.cli import main
from drive_tools.evaluation.metrics import compute_metrics
from drive_tools.runner.runner import run_scenario

RUN_KEYS = {"angle_error_rms", "angle_error_bias", "angle_error_peak", "speed_error_rms"}


def _write(tmp_path, text):
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    return str(path)


GOOD = """motor: wang_spmsm
estimator: sensored
duration_s: 0.3
metrics: {settle_s: 0.1}
sampling_period_s: 1.0e-4
speed: {unit: rpm, points: [[0.0, 50.0]]}
"""


@pytest.mark.parametrize("text, key", [
    (GOOD.replace("wang_spmsm", "no_such_motor"), "motor"),
    (GOOD.replace("duration_s: 0.3\n", ""), "duration_s"),
    (GOOD.replace("duration_s: 0.3", "duration_s: -1"), "duration_s"),
    (GOOD.replace("unit: rpm", "unit: furlongs"), "speed.unit"),
    (GOOD.replace("estimator: sensored", "estimator: crystal_ball"), "estimator"),
    (GOOD + "non_idealities: {dead_time: maybe}\n", "non_idealities.dead_time"),
    (GOOD + "injection: {frequency_Hz: -900.0}\n", "injection.frequency_Hz"),
    (GOOD + "injection: {phase_rad: 1.0}\n", "injection.phase_rad"),
    (GOOD + "controller: {current_limit_A: -2}\n", "controller"),
    ("motor: [unclosed", "YAML"),
])
def test_bad_scenario_is_one_line_naming_the_key(tmp_path, capsys, text, key):
    path = _write(tmp_path, text)
    assert main(["run", path, "--no-plot"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and path in err and key in err, err


def test_bad_scenario_from_shell_has_no_traceback(tmp_path):
    path = _write(tmp_path, GOOD.replace("duration_s: 0.3", "duration_s: -1"))
    proc = subprocess.run([sys.executable, "-m", "drive_tools.cli.cli", "run", path],
                          capture_output=True, text=True)
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr and "duration_s" in proc.stderr


def test_run_json_has_metric_keys(tmp_path):
    path = _write(tmp_path, GOOD)
    proc = subprocess.run([sys.executable, "-m", "drive_tools.cli.cli", "run", path, "--json",
                           "--out", str(tmp_path)], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    metrics = json.loads(proc.stdout)
    assert RUN_KEYS <= set(metrics)
    assert all(isinstance(metrics[k], float) for k in RUN_KEYS)
    assert metrics["plots"] and (tmp_path / "bad_sensored_run.png").is_file()


def test_bench_json_reports_samples_per_second_per_estimator():
    proc = subprocess.run([sys.executable, "-m", "drive_tools.cli.cli", "bench", "throughput", "--json",
                           "--samples", "20000", "--repeats", "2", "--estimators",
                           "sensored,injection_frame", "--no-motulator"], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    report = json.loads(proc.stdout)
    assert set(report["samples_per_second"]) == {"sensored", "injection_frame"}
    assert all(value > 0.0 for value in report["samples_per_second"].values())
    assert all(row["samples_per_cpu_second"] >= 0.9 * row["samples_per_second"] for row in report["results"])
    assert "motulator" not in report


def test_bench_rejects_zero_repeats():
    proc = subprocess.run([sys.executable, "-m", "drive_tools.cli.cli", "bench", "throughput",
                           "--repeats", "0"], capture_output=True, text=True)
    assert proc.returncode == 2 and proc.stderr.strip() == "drive: --repeats: must be at least 1, not 0"


def test_bench_against_refuses_what_is_not_a_commit():
    proc = subprocess.run([sys.executable, "-m", "drive_tools.cli.cli", "bench", "throughput", "--against",
                           "no-such-commit"], capture_output=True, text=True)
    assert proc.returncode == 2 and proc.stderr.startswith("drive: --against: 'no-such-commit' is not a commit of")


@pytest.mark.parametrize("argv, message", [
    (["run", "wang_100rpm", "--duration", "inf"], "argument --duration: must be a finite number, not 'inf'"),
    (["run", "wang_100rpm", "--duration", "nan"], "argument --duration: must be a finite number, not 'nan'"),
    (["launch", "wang_100rpm", "--timeout", "nan"], "argument --timeout: must be a finite number"),
    (["run", "wang_100rpm", "--duration", "1e9"], "--duration: 1e+09 s at 0.0001 s per sample is more than 10000000"),
    (["bench", "graph", "--duration", "1e9"], "--duration: 1e+09 s at 0.0001 s per sample is more than 10000000"),
    (["run", "wang_100rpm", "--duration", "1e-12"], "--duration: 1e-12 s is less than one sample (0.0001 s)"),
    (["launch", "wang_100rpm", "--duration", "1e-12"], "--duration: 1e-12 s is less than one sample"),
    (["bridge", "wang_100rpm", "--duration", "1e-12"], "--duration: 1e-12 s is less than one sample"),
    (["launch", "wang_100rpm", "--link", "pty", "--paced", "--duration", "1e-4"],
     "--duration: 0.0001 s is less than one block of 10 samples (0.001 s): nothing to answer"),
    (["echo", "currents", "--timeout", "0"], "--timeout: must be positive (seconds), not 0"),
    (["echo", "currents", "--timeout", "-1"], "--timeout: must be positive (seconds), not -1"),
    (["tune", "pll", "--crossover", "0"], "--crossover: must be positive, not 0"),
    (["tune", "pll", "--phase-margin", "95"], "--phase-margin: between 0 and 90 degrees, not 95"),
    (["bench", "stop", "--repeats", "0"], "--repeats: must be at least 1, not 0"),
    (["bench", "stop", "--cases", "run,walk"], "--cases: 'walk' is not one of commission standstill"),
])
def test_numeric_options_are_checked_before_anything_runs(capsys, argv, message):
    """inf, nan, a duration past the scenario file's sample cap or under one sample (one block), a wait that would never
    end or a division by zero: exit 2 and the option named, never an allocation of terabytes, an empty run or a
    traceback."""
    try:
        code = main(argv)
    except SystemExit as stop:
        code = stop.code
    assert code == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err


def test_a_signal_noted_before_the_command_line_loaded_stops_the_command_in_one_line(capsys):
    """A SIGINT or SIGTERM that came while the command line's modules loaded (drive_tools.cli.entry notes it from
    the first instruction on) stops the command as one during its job: 128 + N and one line."""
    import signal
    assert main(["scenarios"], early_signals=[signal.SIGTERM]) == 128 + signal.SIGTERM
    assert capsys.readouterr().err.strip() == "drive: scenarios: interrupted by SIGTERM"
    assert main(["presets"], early_signals=[signal.SIGINT]) == 128 + signal.SIGINT


def test_the_real_time_bench_and_launch_check_their_options():
    """The real-time options are checked before anything runs: one line naming the option (run as a user
    runs the command, so it is here and not in the unit tier)."""
    drive = [sys.executable, "-m", "drive_tools.cli.cli"]
    run = subprocess.run(drive + ["bench", "bridge", "--graph"], capture_output=True, text=True, timeout=60)
    assert run.returncode == 2 and run.stderr.strip().endswith("give --paced --graph")
    run = subprocess.run(drive + ["bench", "bridge", "--paced", "--graph", "--levers", "turbo"], capture_output=True,
                         text=True, timeout=60)
    assert run.returncode == 2 and "--levers: 'turbo' is not one of plain, collector" in run.stderr
    run = subprocess.run(drive + ["launch", "wang_100rpm", "--rt-priority", "100"], capture_output=True, text=True,
                         timeout=60)
    assert run.returncode == 2 and "--rt-priority: a SCHED_FIFO priority 1-99" in run.stderr
    run = subprocess.run(drive + ["bench", "bridge", "--paced", "--graph", "--lose-command-every", "-1"],
                         capture_output=True, text=True, timeout=60)
    assert run.returncode == 2 and "--lose-command-every: N ≥ 0" in run.stderr
    run = subprocess.run(drive + ["launch", "wang_100rpm", "--intra-process", "--processes", "separate"],
                         capture_output=True, text=True, timeout=60)
    assert run.returncode == 2 and "--intra-process: needs --processes composed" in run.stderr
    run = subprocess.run(drive + ["launch", "wang_100rpm", "--cpu-dma-latency-us", "x"], capture_output=True,
                         text=True, timeout=60)
    assert run.returncode == 2 and "--cpu-dma-latency-us: a whole number of µs ≥ 0" in run.stderr
    run = subprocess.run(drive + ["bench", "bridge", "--watch-machine"], capture_output=True, text=True, timeout=60)
    assert run.returncode == 2 and run.stderr.strip().endswith("give --paced --graph")


def test_improved_under_rated_load_reports_its_lost_lock_and_ends_at_zero_torque():
    """`drive run wang_load_step --estimator improved`: it slips under the rated load; the drive says so
    (lock_lost, exit code 5) and ends either tracking or holding zero torque (no q-current reference)."""
    result = run_scenario(load_scenario("wang_load_step", "improved"))
    state = result.log[:, COLUMN["state"]]
    assert compute_metrics(result)["lock_lost"] >= 1
    assert state[-1] == 3 or (state[-1] == 4 and np.all(result.log[-100:, COLUMN["i_q_ref"]] == 0.0))
    run = subprocess.run([sys.executable, "-m", "drive_tools.cli.cli", "run", "wang_load_step", "--estimator",
                          "improved", "--no-plot"], capture_output=True, text=True)
    assert run.returncode == (EXIT_NOT_TRACKING if state[-1] == 4 else 0)
    assert "the estimator reported" in run.stdout and "lost lock" in run.stdout


def test_protection_figures_are_declared_keys_and_the_graph_refuses_a_link_it_cannot_see(tmp_path):
    """A scenario's `protection:` figures are read through their declarations (a typo names the key meant,
    a value out of its interval names it), and `drive launch` refuses a motor whose link can rise (C_dc_F:
    the graph's topics carry no bus voltage), one line naming the key, before any node starts."""
    from drive_common.config.scenario import ScenarioError
    from drive_common.motor.commissioning import nameplate_commissioning
    from foc_controller.build import protection_for_scenario

    base = Path(load_scenario("wang_100rpm").source).read_text()
    for protection, refused in (("{limt_degC: 100.0}", r"protection.limt_degC: unknown key \(did you mean limit_degC"),
                                ("{thermal_time_constant_s: -1.0}", r"protection.thermal_time_constant_s: must lie"),
                                ("{warning_degC: 140.0}", r"ambient_degC < warning_degC < limit_degC")):
        path = tmp_path / "s.yaml"
        path.write_text(base + f"protection: {protection}\n")
        scenario = load_scenario(str(path))
        with pytest.raises(ScenarioError, match=rf"^{path}: .*{refused}"):
            protection_for_scenario(scenario, nameplate_commissioning(scenario.motor.nameplate))
    link = Path(__file__).resolve().parent.parent / "docs" / "motors" / "wang_spmsm_link.yaml"
    done = subprocess.run([sys.executable, "-m", "drive_tools.cli", "launch", "wang_100rpm", "--motor", str(link),
                           "--duration", "0.01", "--no-plot"], capture_output=True, text=True)
    assert done.returncode == 2 and done.stderr.count("\n") == 1, done.stderr
    assert "inverter.C_dc_F" in done.stderr and str(link) in done.stderr, done.stderr
