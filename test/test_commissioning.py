"""Self-commissioning at standstill: the plant's deviation from its nameplate, the identification's
accuracy on both presets with every non-ideality and a deviation, its current limit and length, the three
hosts running one procedure, the file, and what the drive then knows and uses."""
import dataclasses
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from drive_common.config.scenario import ScenarioError, load_scenario, parse_scenario
from drive_common.contract.estimator_states import TRACKING
from drive_common.contract.log import COLUMN, LOG_COLUMNS
from drive_common.math.dead_time import dead_time_direction
from drive_common.math.tables import table_value
from drive_common.motor.commissioning import (
    CommissioningError,
    load_commissioning,
    nameplate_commissioning,
    resolve_commissioning,
    save_commissioning,
)
from drive_common.motor.motor_file import nameplate
from drive_tools.evaluation.metrics import compute_metrics
from drive_tools.runner.commissioning_run import commission_in_process, commission_through_bridge
from drive_tools.runner.runner import run_scenario
from hf_estimator.commissioning.identification import resistance_and_dead_time
from hf_estimator.commissioning.loaded import DURATION_S, HOLD_S, LEVELS, START_S, LoadedTestError, loaded_shift
from hf_estimator.commissioning.procedure import procedure_for_scenario
from hf_estimator.injection_frame import loaded_correction
from hf_estimator.interface import make_estimator
from pmsm_plant.model import incremental_inductances
from pmsm_plant.presets import PRESETS, plant_parameters

DRIVE = [sys.executable, "-m", "drive_tools.cli.cli"]
DEVIATION = {"R_s": 1.4, "L_d": 0.9, "L_q": 1.1, "psi_f": 0.92, "sensor_gain_b": 1.01, "dead_time": 1.5}
INVERTED = {key: 1.0 / value for key, value in DEVIATION.items()}
ALL_ON = {key: True for key in ("saturation", "dead_time", "delay", "sensor_noise", "sensor_offset_gain", "adc")}


def deviated(name, deviation, theta_m_rad=0.0):
    """The shipped scenario with the plant deviated, its shaft at ``theta_m_rad``."""
    scenario = load_scenario(name)
    return dataclasses.replace(scenario, plant_deviation={**scenario.plant_deviation, **deviation},
                               initial_theta_m_rad=theta_m_rad)


def test_a_deviation_scales_the_whole_flux_map_and_the_rest_of_the_plant():
    """L factors scale the incremental inductances at no load exactly (saturation moves with the map),
    ψ_f scales the magnet; R_s, J, friction, dead time, sensor gains and offsets follow their keys."""
    preset = PRESETS["wang_spmsm"]
    deviation = {"R_s": 1.4, "L_d": 0.9, "L_q": 1.1, "psi_f": 0.92, "J": 2.0, "friction": 3.0,
                 "sensor_gain_b": 1.01, "sensor_offset_c": 0.02, "dead_time": 1.5}
    machine, mechanics, inverter, sensor = plant_parameters(preset, ALL_ON, deviation)
    L_dh0, L_qh0, _ = incremental_inductances(preset.machine)
    L_dh, L_qh, L_dqh = incremental_inductances(machine)
    assert (L_dh / L_dh0, L_qh / L_qh0) == pytest.approx((0.9, 1.1), rel=1e-9)
    assert abs(L_dqh) < 1e-15
    assert machine.psi_f_Wb == pytest.approx(0.92 * preset.machine.psi_f_Wb)
    assert machine.R_s_ohm == pytest.approx(1.4 * 0.27)
    assert (mechanics.J_kgm2, mechanics.B_Nms) == pytest.approx((8e-4, 3e-5))
    assert inverter.t_dead_s == pytest.approx(0.75e-6)
    assert sensor.gain_b == pytest.approx(0.998 * 1.01) and sensor.offset_c_A == pytest.approx(0.023)
    assert plant_parameters(preset, ALL_ON, None)[0] == preset.machine


@pytest.mark.parametrize("entry, message", [
    ({"L_x": 1.0}, "plant_deviation.L_x: unknown key"),
    ({"R_s": 0.0}, "plant_deviation.R_s: must lie in [0.1, 10], not 0.0"),
    ({"J": 50.0}, "plant_deviation.J: must lie in [0.1, 10], not 50.0"),
    ({"sensor_offset_a": float("nan")}, "plant_deviation.sensor_offset_a: must be a finite number"),
])
def test_a_bad_deviation_is_refused_in_one_line(entry, message):
    data = {"motor": "wang_spmsm", "estimator": "injection_frame", "duration_s": 0.1, "sampling_period_s": 1e-4,
            "speed": {"unit": "rpm", "points": [[0.0, 0.0]]}, "plant_deviation": entry}
    with pytest.raises(ScenarioError, match=f"^s.yaml: {message}".replace("[", r"\[")):
        parse_scenario(data, "s", "s.yaml")


@pytest.mark.parametrize("name, deviation, theta_m_rad", [
    ("wang_100rpm", DEVIATION, 0.0), ("wang_100rpm", INVERTED, 1.0),
    ("szabo_profile", DEVIATION, 2.2), ("szabo_profile", INVERTED, -0.7)])
def test_identification_accuracy_time_and_current_limit(name, deviation, theta_m_rad):
    """Every non-ideality on and the plant off its nameplate: R_s and L_dh, L_qh within 3 %, δ at rated
    current within 0.01 rad, the sensors' relative gains within 0.05 %, their noise within 5 %; at most 2 s
    of motor time; the true phase currents never beyond the current limit. (Inverted on `wang_spmsm`, L_dh > L_qh: the
    d axis is told by its saturation, not by the smaller inductance.) The shaft is held wherever it
    stopped: the procedure does not know the angle."""
    scenario = deviated(name, deviation, theta_m_rad)
    run = commission_in_process(scenario)
    record, truth = run.procedure.result(), run.truth
    for key in ("R_s_ohm", "L_dh_H", "L_qh_H"):
        assert getattr(record, key) == pytest.approx(truth[key], rel=0.03), key
    rated = nameplate(scenario.motor).rated_current_A
    shift = table_value(rated, record.saliency_shift_i_q_A, record.saliency_shift_rad)
    assert shift == pytest.approx(truth["saliency_shift_at_rated_rad"], abs=0.01)
    for x, y in (("a", "b"), ("a", "c"), ("b", "c")):
        measured = getattr(record, f"sensor_gain_{x}") / getattr(record, f"sensor_gain_{y}")
        assert measured == pytest.approx(truth[f"sensor_gain_{x}"] / truth[f"sensor_gain_{y}"], rel=5e-4)
    assert record.sensor_noise_A == pytest.approx(truth["sensor_noise_A"], rel=0.05)
    assert run.procedure.total_samples * scenario.T_s <= 2.0
    assert np.max(np.abs(run.true_currents)) <= nameplate(scenario.motor).current_limit_A


def test_the_bridge_host_runs_the_same_procedure():
    """Through the virtual inverter and the bridge core (currents quantised by the protocol) the
    identification meets the same tolerances."""
    scenario = deviated("wang_100rpm", DEVIATION)
    run = commission_through_bridge(scenario, "pty")
    record, truth = run.procedure.result(), run.truth
    for key in ("R_s_ohm", "L_dh_H", "L_qh_H"):
        assert getattr(record, key) == pytest.approx(truth[key], rel=0.03), key
    assert np.max(np.abs(run.true_currents)) <= nameplate(scenario.motor).current_limit_A


def test_the_graph_host_gives_the_one_process_record(tmp_path):
    """`drive commission --graph`: the plant node with its shaft held and the drive_commissioning node
    over topics write the record the one-process host writes, to the last digit."""
    out = tmp_path / "graph.yaml"
    env = {**os.environ, "ROS_DOMAIN_ID": os.environ["ROS_DOMAIN_ID"]}
    done = subprocess.run(DRIVE + ["commission", "wang_100rpm", "--graph", "--out", str(out), "--json",
                                   "--namespace", "/commission_graph"],
                          capture_output=True, text=True, timeout=300, env=env)
    assert done.returncode == 0, done.stderr
    report = json.loads(done.stdout)
    graph, _ = load_commissioning(out)
    local = commission_in_process(load_scenario("wang_100rpm")).procedure.result()
    for key in ("R_s_ohm", "dead_time_voltage_V", "sensor_gain_b", "L_dh_H", "L_qh_H"):
        assert getattr(graph, key) == getattr(local, key), key
    assert np.array_equal(graph.saliency_shift_rad, local.saliency_shift_rad)
    assert report["truth"]["R_s_ohm"] == 0.27 and set(report["identified"]) >= set(report["truth"])


def test_the_graph_host_behind_the_virtual_inverter_gives_the_bridge_loops_record(tmp_path):
    """`drive commission --graph --link pty`: the virtual inverter and the drive_bridge node in the plant
    node's place write the record the one-process loop through the same bridge writes, to the last digit."""
    from drive_tools.runner.commissioning_run import commission_through_bridge

    out = tmp_path / "graph_pty.yaml"
    done = subprocess.run(DRIVE + ["commission", "wang_100rpm", "--graph", "--link", "pty", "--out", str(out),
                                   "--json", "--namespace", "/commission_graph_pty"],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    graph, _ = load_commissioning(out)
    local = commission_through_bridge(load_scenario("wang_100rpm"), "pty").procedure.result()
    for key in ("R_s_ohm", "dead_time_voltage_V", "sensor_gain_b", "L_dh_H", "L_qh_H"):
        assert getattr(graph, key) == getattr(local, key), key
    assert np.array_equal(graph.saliency_shift_rad, local.saliency_shift_rad)


@pytest.mark.unit
def test_the_dead_time_voltage_is_a_loss_never_negative():
    """DC points u = R·i + V_dt·K(i) + noise (the commissioning's fit, identification.resistance_and_dead_time):
    with a dead time it is found (V_dt within 2 %); without one, over 50 noise draws, V_dt is 0 where the free fit
    went below it and R stays within 2 %, so an inverter without dead time writes a file it can load (a negative
    V_dt was written and then refused by its own loader)."""
    rng = np.random.default_rng(53)
    angles = np.linspace(0.0, 2.0 * np.pi, 6, endpoint=False)
    phase = np.array([[a * np.cos(t - k * 2.0 * np.pi / 3.0) for k in range(3)]
                      for a in (2.0, 4.0) for t in angles])
    i_ab = np.array([[(2.0 * p[0] - p[1] - p[2]) / 3.0, (p[1] - p[2]) / np.sqrt(3.0)] for p in phase])
    k = np.column_stack(dead_time_direction.py_func(*phase.T, 0.0))
    R = 0.8
    _, V = resistance_and_dead_time(i_ab, R * i_ab + 0.6 * k, phase)
    assert V == pytest.approx(0.6, rel=0.02)
    negative = 0
    for _ in range(50):
        commands = R * i_ab + rng.normal(0.0, 0.02, i_ab.shape)
        design = np.vstack([np.column_stack([i_ab[:, 0], k[:, 0]]), np.column_stack([i_ab[:, 1], k[:, 1]])])
        free = np.linalg.lstsq(design, np.concatenate([commands[:, 0], commands[:, 1]]), rcond=None)[0][1]
        negative += free < 0.0
        fitted_R, fitted_V = resistance_and_dead_time(i_ab, commands, phase)
        assert fitted_V >= 0.0 and fitted_R == pytest.approx(R, rel=0.02)
    assert negative > 0


def test_the_file_round_trips_and_a_bad_one_names_its_key(tmp_path):
    record = commission_in_process(load_scenario("szabo_profile")).procedure.result()
    path = save_commissioning(tmp_path / "m.yaml", record, "szabo_ipmsm", "standstill_tests", {"x": 1})
    loaded, metadata = load_commissioning(path)
    assert loaded.R_s_ohm == record.R_s_ohm and loaded.source == str(path)
    assert metadata["motor"] == "szabo_ipmsm" and metadata["conditions"] == {"x": 1}
    text = path.read_text()
    (tmp_path / "old.yaml").write_text(text.replace("  R_s_ohm:", "  R_ohm:"))
    with pytest.raises(CommissioningError, match=r"old.yaml: values.R_s_ohm: missing .*drive commission"):
        load_commissioning(tmp_path / "old.yaml")
    (tmp_path / "bad.yaml").write_text(text.replace(f"sensor_gain_b: {float(record.sensor_gain_b)!r}",
                                                    "sensor_gain_b: 3.0"))
    with pytest.raises(CommissioningError, match=r"bad.yaml: values.sensor_gain_b: must lie in"):
        load_commissioning(tmp_path / "bad.yaml")
    with pytest.raises(CommissioningError, match=r"--commissioning: .*m.yaml is for motor szabo_ipmsm"):
        resolve_commissioning(nameplate("wang_spmsm"), str(path), "--commissioning")


def test_every_value_says_where_it_came_from(capsys):
    """`drive run --json`: the commissioning file's values name it, the nameplate's say nameplate; with
    --commissioning nameplate the rest is default."""
    from drive_tools.cli.cli import main
    for given, source in (("", "commissioning file commissioning/wang_spmsm.yaml"), ("nameplate", "nameplate")):
        args = ["run", "wang_100rpm", "--duration", "0.05", "--no-plot", "--json"]
        assert main(args + (["--commissioning", given] if given else [])) == 0
        knowledge = json.loads(capsys.readouterr().out)["motor_knowledge"]
        assert knowledge["R_s_ohm"]["source"] == source
        assert knowledge["psi_f_Wb"]["source"] == "nameplate"
        assert knowledge["sensor_gain_b"]["source"] == (source if given == "" else "default")


def test_commissioning_pays_off_on_a_plant_off_its_nameplate():
    """Ours on `wang_spmsm` with the plant off its nameplate: commissioned, it holds its 100 rpm targets
    (RMS ≤ 0.02, |bias| ≤ 0.01 rad) and under rated load its bias stays below 0.01 rad, where with the
    nameplate alone (no saliency shift, uncalibrated sensors) it is 0.02 rad."""
    measured = commission_in_process(deviated("wang_100rpm", DEVIATION)).procedure.result()
    path = save_commissioning("dev.yaml", measured, "wang_spmsm", "standstill_tests")
    still = compute_metrics(run_scenario(dataclasses.replace(deviated("wang_100rpm", DEVIATION),
                                                             commissioning=str(path))))
    assert still["angle_error_rms"] <= 0.02 and abs(still["angle_error_bias"]) <= 0.01
    loaded = {c: compute_metrics(run_scenario(dataclasses.replace(deviated("wang_load_step", DEVIATION),
                                                                  commissioning=c)))
              for c in (str(path), "nameplate")}
    assert abs(loaded[str(path)]["angle_error_bias"]) < 0.01 < abs(loaded["nameplate"]["angle_error_bias"])
    assert loaded[str(path)]["angle_error_peak_transient"] <= 0.1


def test_a_weakly_salient_plant_gets_a_stronger_injection_and_holds_its_targets():
    """The inverted plant is reverse-salient at half the preset's |Δ|/Σ: at the scenario's 5 V ours'
    saliency current is 3.3 σ of the sensor noise and the 100 rpm RMS misses 0.02 rad; ours raises its
    amplitude from the commissioned saliency and noise (to the voltage cap, 0.8·U_dc/√3) and meets
    RMS ≤ 0.02 and |bias| ≤ 0.01 at 100 rpm and peak ≤ 0.1 rad on the reversal."""
    measured = commission_in_process(deviated("wang_100rpm", INVERTED)).procedure.result()
    path = str(save_commissioning("inverted.yaml", measured, "wang_spmsm", "standstill_tests"))
    steady = deviated("wang_100rpm", INVERTED)
    fixed = compute_metrics(run_scenario(dataclasses.replace(steady, commissioning=path, estimator_settings={
        "saliency_snr_min": 0.0, "run_refused": True})))
    raised = run_scenario(dataclasses.replace(steady, commissioning=path))
    assert raised.estimator_facts["injection_amplitude_V"] == pytest.approx(0.8 * 24.0 / np.sqrt(3.0))
    assert "held by the voltage cap" in raised.estimator_facts["injection_note"]
    raised = compute_metrics(raised)
    assert fixed["angle_error_rms"] > 0.02 >= raised["angle_error_rms"]
    assert abs(raised["angle_error_bias"]) <= 0.01
    reversal = compute_metrics(run_scenario(dataclasses.replace(deviated("wang_reversal", INVERTED),
                                                                commissioning=path)))
    assert reversal["angle_error_peak"] <= 0.1 and not reversal["lock_lost_s"]


def test_the_procedure_refuses_bad_settings_and_counts_its_samples():
    scenario = load_scenario("wang_100rpm")
    procedure = procedure_for_scenario(scenario)
    assert procedure.total_samples == 19210
    with pytest.raises(KeyError, match="commissioning: unknown setting"):
        procedure_for_scenario(scenario, {"hf_Hz": 1.0})
    with pytest.raises(ValueError, match="commissioning: q_points: must be odd"):
        procedure_for_scenario(scenario, {"q_points": 8})
    with pytest.raises(ValueError, match="out of order"):
        procedure.step(3, 0.0, 0.0, 0.0)


def test_a_round_rotor_is_reported_without_saliency():
    """Saturation off, `wang_spmsm` is round: the record says no saliency is measurable and keeps flat
    tables; the paper methods then get no gain rather than an enormous one."""
    scenario = load_scenario("wang_100rpm")
    scenario = dataclasses.replace(scenario, non_idealities={**scenario.non_idealities, "saturation": False})
    run = commission_in_process(scenario)
    record = run.procedure.result()
    assert run.procedure.conditions()["saliency"].startswith("none measurable")
    assert not record.salient() and not record.saliency_shift_rad.any() and (record.convergence_slope == 1).all()
    assert record.R_s_ohm == pytest.approx(0.27, rel=0.03)


@pytest.mark.parametrize("stopped_in", ["rotating", "loaded"])
def test_a_commissioning_stopped_in_a_later_test_writes_nothing_and_can_run_again(capsys, monkeypatch, stopped_in):
    """SIGINT during the rotating or the loaded test (the run stops after its chunk in progress): exit 130, no
    commissioning file and no partial one left, so that the next commissioning is not refused; a complete
    one names the tests it completed."""
    import signal

    from drive_common.motor.commissioning import load_commissioning
    from drive_common.runtime.interrupt import Interrupted
    from drive_tools.cli.cli import main
    from drive_tools.runner import commissioning_run

    def stopped(*args, **kwargs):
        raise Interrupted(signal.SIGINT)
    asked = ["--rotating", "--loaded"] if stopped_in == "loaded" else ["--rotating"]
    with monkeypatch.context() as patched:
        patched.setattr(commissioning_run, f"{stopped_in}_test_in_process", stopped)
        if stopped_in == "loaded":
            patched.setattr(commissioning_run, "rotating_test_in_process", lambda scenario, path, progress=None: (
                {"psi_f_Wb": 0.0161, "J_kgm2": 4e-4, "B_Nms": 1e-5, "friction_Nm": 0.0, "speeds_rad_s": [1.0]},
                {"psi_f_Wb": 0.0161, "J_kgm2": 4e-4}, None))
        assert main(["commission", "wang_100rpm", "--out", "stopped.yaml", *asked]) == 130
    assert capsys.readouterr().err.strip() == "drive: commission: interrupted by SIGINT"
    assert sorted(os.listdir(".")) == ["commissioning"]
    assert main(["commission", "wang_100rpm", "--out", "stopped.yaml", "--json"]) == 0
    _, metadata = load_commissioning("stopped.yaml")
    assert metadata["conditions"]["tests_completed"] == ["standstill"]
    capsys.readouterr()
    main(["run", "wang_100rpm", "--duration", "0.05", "--commissioning", "stopped.yaml", "--no-plot", "--json"])
    assert json.loads(capsys.readouterr().out)["commissioning_tests"] == ["standstill"]


def test_commission_keeps_an_existing_file_and_prints_identified_beside_truth(capsys):
    from drive_tools.cli.cli import main
    assert main(["commission", "wang_100rpm"]) == 2
    assert "--out: commissioning/wang_spmsm.yaml already exists (--force replaces it)" in capsys.readouterr().err
    assert main(["commission", "szabo_profile", "--out", "new.yaml", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert set(report["truth"]) <= set(report["identified"]) and report["file"] == "new.yaml"
    assert report["peak_true_current_A"] <= report["current_limit_A"]
    assert load_commissioning("new.yaml")[1]["conditions"]["host"] == "one process, plant core"


def test_a_scenario_names_its_commissioning_file_beside_it(tmp_path):
    """The key `commissioning:` is a path relative to the scenario file (or 'nameplate'); the drive loads
    what it names."""
    record = commission_in_process(load_scenario("wang_100rpm")).procedure.result()
    folder = tmp_path / "robot"
    folder.mkdir()
    save_commissioning(folder / "left_wheel.yaml", record, "wang_spmsm", "standstill_tests")
    text = Path(load_scenario("wang_100rpm").source).read_text()
    (folder / "run.yaml").write_text(text + "commissioning: left_wheel.yaml\n")
    (folder / "plate.yaml").write_text(text + "commissioning: nameplate\n")
    named = run_scenario(dataclasses.replace(load_scenario(str(folder / "run.yaml")), duration_s=0.01))
    assert named.commissioning.source == str(folder / "left_wheel.yaml")
    plate = run_scenario(dataclasses.replace(load_scenario(str(folder / "plate.yaml")), duration_s=0.01))
    assert plate.commissioning.source == "nameplate" and plate.commissioning.sensor_gain_b == 1.0


def test_the_current_limit_keeps_half_the_saliency_and_a_weak_one_is_named():
    """Where the measured |Δ|/Σ falls to half its no-load value under load, the sensorless current limit
    stops there (a linear fall from 0.06 at 0 A to 0.02 at 6 A: 4.5 A); a file without the table keeps the
    slope's limit. A saliency below 5 % is named; 6.6 % (wang_spmsm) is not."""
    from drive_common.motor.commissioning import Commissioning, nameplate_commissioning
    currents = np.linspace(-6.0, 6.0, 13)
    base = Commissioning(0.27, 0.0, 1.0, 1.0, 1.0, 0.0, 0.0, 0.0, 0.01, 0.84e-3, 0.96e-3, currents, np.zeros(13),
                         np.ones(13), source="test")
    fading = base._replace(saliency_ratio=0.06 - 0.04 * np.abs(currents) / 6.0)
    assert base.tracking_current_limit_A() == 6.0 and fading.tracking_current_limit_A() == pytest.approx(4.5)
    assert base.weak_saliency_note() == ""
    weak = base._replace(L_dh_H=0.85e-3, L_qh_H=0.9e-3)
    assert "weak saliency (|Δ|/Σ = 2.9 %" in weak.weak_saliency_note()
    assert nameplate_commissioning(nameplate("wang_spmsm"))._replace(L_qh_H=0.88e-3).weak_saliency_note() == ""


def held_shaft_log(moved, zero_drift=0.0, lost_at_s=None):
    """A loaded test's log as ours would write it on a held shaft: θ̂ = 0.3 + moved(i_q) at each hold's
    current (±1, ±2, ±3 A), the zero holds drifting by ``zero_drift`` from the first to the last."""
    t = np.arange(int(round(DURATION_S / 1e-4))) * 1e-4
    log = np.zeros((t.size, len(LOG_COLUMNS)))
    log[:, COLUMN["t"]] = t
    log[:, COLUMN["state"]] = TRACKING
    hold = np.clip(((t - START_S) // HOLD_S).astype(int), 0, len(LEVELS) - 1)
    i_q = 3.0 * np.asarray(LEVELS)[hold] * (t >= START_S)
    log[:, COLUMN["i_q"]] = i_q
    log[:, COLUMN["theta_e_hat"]] = 0.3 + moved(i_q) + zero_drift * t / DURATION_S
    if lost_at_s is not None:
        log[t >= lost_at_s, COLUMN["state"]] = 0
    return log


def test_the_loaded_test_reads_ours_error_under_load_from_a_held_shaft():
    """θ̂ moved by 0.004·i_q + 0.0005·i_q³ rad under load, with a convergence slope of 0.9: the correction is
    0.9 × that at every hold (fitted odd, held beyond the largest current); a move within the zero holds'
    spread (its odd part: a move alike at ±i_q is the zero reference's error) gives no correction; a shaft
    that turned or ours losing track measures nothing: a load that took the angle (lost in the hold at full
    load, 0.7 s) gives the current a test run again may reach (the largest load held before, 2 A), a loss
    before any load none."""
    grid = np.linspace(-4.0, 4.0, 9)
    record = nameplate_commissioning(nameplate("wang_spmsm"))._replace(
        saliency_shift_i_q_A=grid, saliency_shift_rad=np.zeros(9), convergence_slope=np.full(9, 0.9))
    result = loaded_shift(held_shaft_log(lambda i: 0.004 * i + 0.0005 * i ** 3), record, 3.0)
    assert result["significant"] and result["zero_spread_rad"] < 1e-12 and result["top_current_A"] == 3.0
    for hold in result["holds"]:
        i = hold["i_q_A"]
        assert hold["correction_rad"] == pytest.approx(0.9 * (0.004 * i + 0.0005 * i ** 3), abs=1e-9)
    expected = 0.9 * (0.004 * np.clip(grid, -3, 3) + 0.0005 * np.clip(grid, -3, 3) ** 3)
    assert np.allclose(result["estimator_shift_rad"], expected, atol=1e-9)
    quiet = loaded_shift(held_shaft_log(lambda i: 0.0005 * np.sign(i), zero_drift=0.001), record, 3.0)
    assert not quiet["significant"] and not quiet["estimator_shift_rad"].any()
    even = loaded_shift(held_shaft_log(lambda i: 0.01 * np.abs(i) + 0.0003 * i, zero_drift=0.001), record, 3.0)
    assert not even["significant"] and not even["estimator_shift_rad"].any()
    with pytest.raises(LoadedTestError, match="moved by 0.0.* rad between holds up to 3 A, more than 0.02 rad "
                                              ".*shaft turned") as moved:
        loaded_shift(held_shaft_log(lambda i: 0.0 * i, zero_drift=0.05), record, 3.0)
    assert moved.value.retry_current_A == pytest.approx(2.0)
    with pytest.raises(LoadedTestError, match="ours stopped tracking for .* %.*the load took its angle") as lost:
        loaded_shift(held_shaft_log(lambda i: 0.0 * i, lost_at_s=0.7), record, 3.0)
    assert lost.value.retry_current_A == pytest.approx(2.0)
    with pytest.raises(LoadedTestError, match="before any load: ours did not start") as unstarted:
        loaded_shift(held_shaft_log(lambda i: 0.0 * i, lost_at_s=0.31), record, 3.0)
    assert unstarted.value.retry_current_A is None


def test_ours_takes_the_loaded_correction_only_at_the_tests_carrier_and_amplitude(tmp_path):
    """The file keeps the loaded test's table with its carrier and amplitude (all or none of the three); ours
    adds the table where it runs within 2 % of both, else it leaves it out and says why; the square wave, which
    the loaded test runs where the loops' rule chooses it, likewise at its own carrier and amplitude."""
    record = commission_in_process(load_scenario("wang_100rpm")).procedure.result()
    correction = 0.01 * record.saliency_shift_i_q_A / 5.0
    tested = record._replace(estimator_shift_rad=correction, loaded_test_frequency_Hz=1000.0,
                             loaded_test_amplitude_V=5.0)
    path = save_commissioning(tmp_path / "m.yaml", tested, "wang_spmsm", "standstill_tests")
    loaded, _ = load_commissioning(path)
    assert np.array_equal(loaded.estimator_shift_rad, correction) and loaded.loaded_test_amplitude_V == 5.0
    shift, note = loaded_correction(loaded, 1000.0, 5.05)
    assert np.array_equal(shift, record.saliency_shift_rad + correction) and note == ""
    shift, note = loaded_correction(loaded, 1000.0, 6.0)
    assert np.array_equal(shift, record.saliency_shift_rad)
    assert "measured at 1000 Hz, 5 V, ours runs at 1000 Hz, 6 V" in note and "--loaded" in note
    assert loaded_correction(record, 1000.0, 5.0) == (record.saliency_shift_rad, "")
    scenario = load_scenario("wang_100rpm")
    plate, inverter = record.refined(scenario.motor.nameplate), scenario.motor.inverter
    built = make_estimator("square_wave", plate, 1e-4, {}, record, inverter)
    carrier_Hz, amplitude_V = built.injection_frequency_Hz, built.injection_amplitude_V
    square = record._replace(estimator_shift_rad=correction, loaded_test_frequency_Hz=carrier_Hz,
                             loaded_test_amplitude_V=amplitude_V)
    taken = make_estimator("square_wave", plate, 1e-4, {}, square, inverter)
    assert np.array_equal(taken.params.shift_rad, record.saliency_shift_rad + correction)
    other = make_estimator("square_wave", plate, 1e-4, {}, square._replace(loaded_test_amplitude_V=1.2 * amplitude_V),
                           inverter)
    assert np.array_equal(other.params.shift_rad, record.saliency_shift_rad)
    assert "the loaded test's correction left out" in other.injection_note
    (tmp_path / "half.yaml").write_text(path.read_text().replace("  loaded_test_amplitude_V: 5.0\n", ""))
    with pytest.raises(CommissioningError, match=r"half.yaml: values: estimator_shift_rad, .* go together"):
        load_commissioning(tmp_path / "half.yaml")
