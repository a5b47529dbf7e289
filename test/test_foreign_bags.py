"""Replay of recordings the project did not write: bags written here with `rosbags` alone, as another
recorder on a robot would (contract v2 drive_config without a scenario, no drive_config, no ground
truth, an unknown drive_config key, another sample period), and a corpus of them."""
import json
from pathlib import Path

import numpy as np
import pytest

from drive_common.config.scenario import load_scenario
from drive_common.contract.log import COLUMN
from drive_common.motor.commissioning import commissioning_record
from drive_tools.runner.runner import run_scenario
from helpers import drive_in_process

SCENARIO = """\
motor: wang_spmsm
estimator: {estimator}
injection: {{frequency_Hz: {frequency}, amplitude_V: 5.0}}
duration_s: 0.8
sampling_period_s: {T_s}
initial: {{theta_m_rad: 1.3}}
speed: {{unit: rpm, interpolation: linear, points: [[0.0, 0.0], [0.1, 100.0], [0.8, 100.0]]}}
"""
WANG_MOTOR = {"name": "wang_spmsm", "n_p": 2, "R_s_ohm": 0.27, "L_d_H": 0.0009, "L_q_H": 0.0009,
              "psi_f_Wb": 0.0162, "rated_current_A": 4.6}


def recorded_run(tmp_path, estimator, T_s=1e-4, frequency=900.0):
    path = tmp_path / f"{estimator}_{T_s:g}.yaml"
    path.write_text(SCENARIO.format(estimator=estimator, T_s=T_s, frequency=frequency))
    return run_scenario(load_scenario(str(path)))


def write_foreign_bag(path, result, config=None, truth=True, epoch_s=0.0, jitter_s=0.0, lost=0.0, seed=7):
    """A contract bag written with rosbags' own Writer and serialiser: the per-sample topics of a run (no
    /clock, no angle_error), with ``config`` as its drive_config (None: none); a robot's: stamped from a
    wall clock at ``epoch_s``, each stamp off its instant by up to ± ``jitter_s``, a share ``lost`` of each
    topic's messages never recorded."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore
    store = get_typestore(Stores.ROS2_JAZZY)
    Vector3Stamped = store.types["geometry_msgs/msg/Vector3Stamped"]
    JointState = store.types["sensor_msgs/msg/JointState"]
    Header, Time = store.types["std_msgs/msg/Header"], store.types["builtin_interfaces/msg/Time"]
    Vector3, String = store.types["geometry_msgs/msg/Vector3"], store.types["std_msgs/msg/String"]
    log, c, n_p = result.log, COLUMN, result.n_p
    T_s = result.scenario.T_s
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        def connection(topic, msgtype):
            return writer.add_connection(f"/robot/{topic}", msgtype, typestore=store)
        if config is not None:
            writer.write(connection("drive_config", "std_msgs/msg/String"), 0,
                         store.serialize_cdr(String(data=json.dumps(config)), "std_msgs/msg/String"))
        vectors = {"currents": ("abc", ("i_a_meas", "i_b_meas", "i_c_meas")),
                   "voltage_command": ("alpha_beta", ("u_alpha", "u_beta")),
                   "injection": ("alpha_beta", ("u_inj_alpha", "u_inj_beta")),
                   "estimator_state": ("", ("eps", "signal", "state"))}
        joints = {"rotor_estimate": (("theta_e_hat", 1.0 / n_p), ("omega_e_hat", 1.0 / n_p))}
        if truth:
            joints["rotor_state"] = (("theta_m", 1.0), ("omega_m", 1.0), ("tau_e", 1.0))
        vector_connections = {t: connection(t, "geometry_msgs/msg/Vector3Stamped") for t in vectors}
        joint_connections = {t: connection(t, "sensor_msgs/msg/JointState") for t in joints}
        rng = np.random.default_rng(seed)
        n = log.shape[0]
        kept = {t: rng.random(n) >= lost for t in (*vectors, *joints)}
        offsets = int(round(epoch_s * 1e9)) + np.round((np.arange(n) * T_s + rng.uniform(-jitter_s, jitter_s, n))
                                                       * 1e9).astype(np.int64)
        for k in range(n):
            t_ns = int(offsets[k])
            header = Header(stamp=Time(sec=t_ns // 10**9, nanosec=t_ns % 10**9), frame_id="")
            for topic, (frame, columns) in vectors.items():
                if not kept[topic][k]:
                    continue
                values = [float(log[k, c[name]]) for name in columns] + [0.0] * (3 - len(columns))
                message = Vector3Stamped(header=Header(stamp=header.stamp, frame_id=frame), vector=Vector3(*values))
                writer.write(vector_connections[topic], t_ns, store.serialize_cdr(message, Vector3Stamped.__msgtype__))
            for topic, fields in joints.items():
                if not kept[topic][k]:
                    continue
                values = [np.array([log[k, c[name]] * scale]) for name, scale in fields]
                message = JointState(header=header, name=["wheel"], position=values[0], velocity=values[1],
                                     effort=values[2] if len(values) > 2 else np.array([np.nan]))
                writer.write(joint_connections[topic], t_ns, store.serialize_cdr(message, JointState.__msgtype__))
    return path


def v2_config(result, estimator, **extra):
    """A v2 drive_config with the commissioning the recording drive ran on (``commissioning`` in extra
    replaces it; None leaves it out)."""
    extra = {"commissioning": commissioning_record(result.commissioning), **extra}
    if extra["commissioning"] is None:
        del extra["commissioning"]
    return {"contract_version": 2, "node": "someone_elses_drive", "T_s_s": result.scenario.T_s,
            "command_delay_periods": 1, "motor": WANG_MOTOR,
            "injection": {"kind": "pulsating_sine", "frequency_Hz": result.scenario.injection["frequency_Hz"],
                          "amplitude_V": 5.0}, "estimator": estimator, **extra}


def replay(bag, *options, cwd=None):
    out = drive_in_process(["bench", "replay", str(bag), "--json", "--no-plot", *options], cwd)
    assert out.returncode == 0, out.stderr
    report = json.loads(out.stdout)
    return report, {e["estimator"]: e for e in report["results"]}


@pytest.fixture(scope="module")
def conventional(tmp_path_factory):
    return recorded_run(tmp_path_factory.mktemp("conventional"), "conventional")


def test_a_v2_bag_without_scenario_replays_ours_better_than_its_recorder(conventional, tmp_path):
    """drive_config in the v2 schema, no scenario, an unknown extra key: the motor, sample period, delay
    and injection come from it, the windows are found automatically, the recording's own estimator
    replays to its recorded angle error exactly, and ours, fitting the recorded pulsating sine, beats it."""
    bag = write_foreign_bag(tmp_path / "v2", conventional,
                            v2_config(conventional, "conventional", wheel_radius_m=0.05))
    report, results = replay(bag, "--estimators", "injection_frame,conventional,conventional_aligned,sensored",
                             "--out", str(tmp_path / "out"))
    assert report["scenario"] is None and report["motor"] == "wang_spmsm"
    assert report["sources"]["motor"] == "drive_config motor"
    assert report["sources"]["command_delay"] == "drive_config command_delay_periods"
    assert report["windows"]["source"].startswith("automatic: ")
    assert report["windows"]["steady_s"][0][0] >= 0.2 and report["windows"]["steady_s"][-1][1] == pytest.approx(0.8)
    assert report["excitation"]["kind"] == "pulsating_sine"
    assert report["excitation"]["frequency_Hz"] == pytest.approx(900.0, abs=2.0)
    own, ours = results["conventional"], results["injection_frame"]
    from drive_tools.evaluation.metrics import _mask, angle_error
    t = conventional.log[:, COLUMN["t"]]
    recorded = angle_error(conventional.log, 2)[_mask(t, report["windows"]["steady_s"])]
    assert own["applicable"] and own["angle_error_rms"] == pytest.approx(np.sqrt(np.mean(recorded ** 2)), rel=1e-9)
    assert ours["applicable"] and not ours["lost"]
    assert ours["angle_error_rms"] < 0.6 * own["angle_error_rms"]
    assert abs(ours["angle_error_bias"]) < 0.01
    assert not results["conventional_aligned"]["applicable"]
    assert "recording estimator's axis" in results["conventional_aligned"]["reason"]
    assert results["sensored"]["applicable"] and results["sensored"]["angle_error_rms"] < 1e-9
    out = drive_in_process(["bench", "compare", str(bag), str(bag), "--json", "--no-plot"])
    assert out.returncode == 0, out.stderr
    compared = json.loads(out.stdout)["runs"][0]
    assert compared["estimator"] == "conventional" and compared["windows"] == report["windows"]
    assert compared["angle_error_rms"] == pytest.approx(own["angle_error_rms"], rel=1e-9)


def test_a_bag_without_drive_config_needs_and_takes_the_motor_and_sample_period(conventional, tmp_path):
    """No drive_config: each missing piece is a one-line error naming its option, and a sample period the
    stamps do not show (half of them off its grid) is refused naming it; given --sample-period and --motor (a
    file of the contract's motor keys), it replays with the contract's usual delay."""
    bag = write_foreign_bag(tmp_path / "bare", conventional)
    for options, says in (((), "give --sample-period S"), (("--sample-period", "1e-4"), "give --motor PRESET|FILE"),
                          (("--sample-period", "1e-4", "--motor", "no_such_motor"), "--motor: 'no_such_motor' is "
                                                                                   "neither a shipped motor"),
                          (("--sample-period", "2e-4", "--motor", "wang_spmsm"), "--sample-period 0.0002 s does not "
                                                                                 "fit the recording")):
        out = drive_in_process(["bench", "replay", str(bag), "--no-plot", *options])
        assert out.returncode == 2 and out.stderr.count("\n") == 1 and says in out.stderr, out.stderr
    motor = tmp_path / "motor.yaml"
    motor.write_text(json.dumps(WANG_MOTOR))
    report, results = replay(bag, "--sample-period", "1e-4", "--motor", str(motor), "--estimators",
                             "injection_frame", "--windows", "0.3:0.8")
    assert report["sources"]["motor"] == "--motor" and report["sources"]["sample_period"] == "--sample-period"
    assert report["sources"]["command_delay"].startswith("the contract's usual 1 period")
    assert report["windows"] == {"source": "--windows", "steady_s": [[0.3, 0.8]]}
    assert results["injection_frame"]["applicable"] and results["injection_frame"]["angle_error_rms"] < 0.03


def test_a_bag_without_ground_truth_scores_none_and_says_who_needs_it(conventional, tmp_path):
    bag = write_foreign_bag(tmp_path / "no_truth", conventional, v2_config(conventional, "conventional"),
                            truth=False)
    report, results = replay(bag, "--estimators", "injection_frame,sensored")
    assert not report["ground_truth"]
    assert results["injection_frame"]["applicable"] and "angle_error_rms" not in results["injection_frame"]
    assert results["injection_frame"]["lost"] is False
    assert not results["sensored"]["applicable"] and "ground truth" in results["sensored"]["reason"]


def test_a_bag_of_another_sample_period_replays_at_its_own(tmp_path):
    """8 kHz sampling, 800 Hz injection, recorded with `improved`: ours replays at the bag's sample period
    and beats the recording's estimator there too."""
    run = recorded_run(tmp_path, "improved", T_s=1.25e-4, frequency=800.0)
    bag = write_foreign_bag(tmp_path / "slow", run, v2_config(run, "improved"))
    report, results = replay(bag, "--estimators", "injection_frame,improved")
    assert report["sample_period_s"] == pytest.approx(1.25e-4) and report["samples"] == 6400
    assert report["excitation"]["frequency_Hz"] == pytest.approx(800.0, abs=2.0)
    assert results["injection_frame"]["applicable"] and results["improved"]["applicable"]
    assert results["injection_frame"]["angle_error_rms"] < results["improved"]["angle_error_rms"]


def test_a_corpus_gives_one_summary_row_per_estimator(conventional, tmp_path):
    """A directory of bags, one without drive_config: the command line's motor and sample period supply
    what a bag does not say and are not used where it does; one summary row per estimator."""
    corpus = tmp_path / "corpus"
    write_foreign_bag(corpus / "a", conventional, v2_config(conventional, "conventional"))
    write_foreign_bag(corpus / "b", conventional, v2_config(conventional, "conventional"), truth=False)
    write_foreign_bag(corpus / "c", conventional)
    out = drive_in_process(["bench", "replay", str(corpus), "--estimators",
                                  "injection_frame,conventional_aligned", "--motor", "wang_spmsm",
                                  "--sample-period", "1e-4", "--json"])
    assert out.returncode == 0, out.stderr
    report = json.loads(out.stdout)
    a, b, c = report["per_bag"]
    assert report["bags"] == 3 and [a["bag"], b["bag"], c["bag"]] == [str(corpus / n) for n in "abc"]
    assert a["sources"]["motor"] == "drive_config motor (--motor not used)" and c["sources"]["motor"] == "--motor"
    ours, aligned = report["summary"]
    assert ours["estimator"] == "injection_frame" and ours["scored"] == 2 and ours["lost"] == 0
    scored = sorted(bag["results"][0]["angle_error_rms"] for bag in (a, c))
    assert ours["rms_median"] == pytest.approx(np.median(scored)) and ours["rms_worst"] == scored[-1]
    assert aligned["scored"] == 0 and aligned["not_applicable"] == 3 and aligned["rms_median"] is None
    out = drive_in_process(["bench", "replay", str(corpus / "[ab]")])
    assert out.returncode == 0 and "replay of 2 bags" in out.stdout, out.stderr


def test_a_corpus_skips_what_is_not_a_bag_and_scores_the_rest(conventional, tmp_path):
    """A glob over a shelf with a README, an empty folder and a bag: one line on stderr per skipped path
    (naming it), the bag scored, exit 0; nothing but skips: one line, exit 2."""
    shelf = tmp_path / "shelf"
    write_foreign_bag(shelf / "a", conventional, v2_config(conventional, "conventional"))
    (shelf / "README.md").write_text("recordings of the left wheel\n")
    (shelf / "empty").mkdir()
    out = drive_in_process(["bench", "replay", str(shelf / "*"), "--estimators", "injection_frame", "--json"])
    assert out.returncode == 0, out.stderr
    report = json.loads(out.stdout)
    assert report["bags"] == 1 and report["summary"][0]["scored"] == 1
    assert sorted(Path(s["path"]).name for s in report["skipped"]) == ["README.md", "empty"]
    lines = [line for line in out.stderr.splitlines() if line.startswith("drive: skipped")]
    assert len(lines) == 2 and any("README.md" in line for line in lines)
    out = drive_in_process(["bench", "replay", str(shelf / "[Re]*")])
    assert out.returncode == 2 and "none of its 2 paths could be replayed" in out.stderr


def test_ours_on_a_recording_of_synchronous_beats_it(tmp_path):
    """`szabo_profile_aligned` (IPMSM, 1500 Hz / 40 V on d̂, Szabó's synchronous demodulation aligned; the
    first 1.2 s: ramp to 300 rpm, a rated load step and its release) recorded by `drive run --record`:
    ours replayed on that excitation is applicable, holds its lock and beats `synchronous`' own error."""
    from drive_tools.bags.writer import write_run_bag
    from helpers import shipped
    bag = write_run_bag(run_scenario(shipped("szabo_profile_aligned", duration_s=1.2)), tmp_path / "szabo")
    report, results = replay(bag, "--estimators", "injection_frame,synchronous")
    ours, own = results["injection_frame"], results["synchronous"]
    assert report["recorded_estimator"] == "synchronous" and own["applicable"] and ours["applicable"]
    assert not ours["lost"] and not own["lost"]
    assert ours["angle_error_rms"] < 0.6 * own["angle_error_rms"]


def test_a_replay_takes_the_recorded_commissioning_wherever_it_runs(conventional, tmp_path):
    """The recording drive ran on commissioning/wang_spmsm.yaml (found in the repository root): its bag keeps
    the values in drive_config, so a replay from another directory scores the same to the last digit and
    says where they came from; a bag that records none replays on the nameplate and says so, wherever it runs;
    --commissioning replaces the recorded one."""
    from drive_tools.bags.writer import write_run_bag
    assert conventional.commissioning.source == "commissioning/wang_spmsm.yaml"
    bag = write_run_bag(conventional, tmp_path / "runner")
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    here, ours_here = replay(bag, "--estimators", "injection_frame")
    there, ours_there = replay(bag, "--estimators", "injection_frame", cwd=elsewhere)
    assert here["sources"]["commissioning"] == there["sources"]["commissioning"] == (
        "drive_config commissioning (recorded from commissioning/wang_spmsm.yaml)")
    for key in ("angle_error_rms", "angle_error_bias", "angle_error_peak"):
        assert ours_here["injection_frame"][key] == ours_there["injection_frame"][key]
    assert ours_here["injection_frame"]["angle_error_rms"] < 0.02
    bare = write_foreign_bag(tmp_path / "v2_bare", conventional, v2_config(conventional, "conventional",
                                                                          commissioning=None))
    for cwd in (None, elsewhere):
        report, _ = replay(bare, "--estimators", "injection_frame", cwd=cwd)
        assert report["sources"]["commissioning"].startswith("nameplate only: the bag records no commissioning")
    told, _ = replay(bag, "--estimators", "injection_frame", "--commissioning",
                     str(Path("commissioning/wang_spmsm.yaml").resolve()), cwd=elsewhere)
    assert told["sources"]["commissioning"].endswith("(the bag's not used)")


def test_a_robots_recording_replays_wall_clock_jitter_lost_messages_and_a_cut(tmp_path):
    """Written with rosbags alone, as a robot records: stamps from a wall clock at 1.76e9 s with ±3 µs
    jitter, 0.2 % of every topic's messages lost, drive_config without a scenario. Replay indexes from the
    first sample, measures the jitter, counts each topic's lost samples, rebuilds the currents of those the
    drive answered (all here) and scores ours within 5 % of the clean recording's RMS (0.01029 against
    0.01022; 0.0124 when replay stepped over them) and under ours' 0.02 rad. Cut
    mid-chunk (a power loss: no metadata.yaml, the .mcap truncated), `drive bag reindex` mends it and ours
    replays up to its last whole sample with the same quality."""
    run = recorded_run(tmp_path, "injection_frame")
    config = v2_config(run, "injection_frame")
    clean, clean_ours = replay(write_foreign_bag(tmp_path / "clean", run, config), "--estimators", "injection_frame",
                               "--windows", "0.3:0.8")
    robot = write_foreign_bag(tmp_path / "robot", run, config, epoch_s=1.76e9, jitter_s=3e-6, lost=0.002)
    report, results = replay(robot, "--estimators", "injection_frame", "--windows", "0.3:0.8")
    n = run.log.shape[0]
    timing = report["timing"]
    assert timing["epoch_s"] == pytest.approx(1.76e9, abs=1e-5) and timing["off_grid_messages"] == 0
    assert 1e-6 < timing["jitter_rms_s"] < 3e-6 and timing["jitter_max_s"] <= 3e-6 + 1e-9
    missing = report["missing_samples"]
    assert set(missing) >= {"currents", "voltage_command", "rotor_state", "rotor_estimate"}
    assert all(0.0005 * n < missing[t] < 0.005 * n for t in ("currents", "voltage_command", "rotor_state"))
    assert report["samples"] == n - report["cut_samples"] and report["cut_samples"] <= 5
    ours, clean_rms = results["injection_frame"], clean_ours["injection_frame"]["angle_error_rms"]
    assert ours["samples"] >= n - 2 and not ours["lost"]
    assert ours["angle_error_rms"] == pytest.approx(clean_rms, rel=0.05) and ours["angle_error_rms"] < 0.02

    mcap = next(robot.glob("*.mcap"))
    data = mcap.read_bytes()
    mcap.write_bytes(data[:int(0.7 * len(data))])
    (robot / "metadata.yaml").unlink()
    out = drive_in_process(["bench", "replay", str(robot), "--no-plot"])
    assert out.returncode == 2 and "drive bag reindex" in out.stderr and out.stderr.count("\n") == 1
    mended = drive_in_process(["bag", "reindex", str(robot)])
    assert mended.returncode == 0, mended.stderr
    cut, results = replay(robot, "--estimators", "injection_frame", "--windows", "0.3:0.5")
    assert 0.5 * n < cut["samples"] < 0.75 * n
    assert results["injection_frame"]["angle_error_rms"] < 0.02 and not results["injection_frame"]["lost"]


def test_currents_the_recorder_lost_are_rebuilt_within_the_measurement_noise():
    """A salient winding (L_d, L_q, R drawn; the rotor at a drawn angle, turning slowly) driven by a sine
    carrier of 4-20 samples a period and 0.05-0.5 A ripple per sample and a drifting fundamental, its currents
    measured with noise σ = 0.01 A: where the recorder lost 20 gaps of 1-3 samples that the drive answered,
    each is rebuilt within 3 σ of the true current, median within 1.2 σ (measured 0.7-1.0 σ, largest
    1.5-2.2 σ), where interpolating between its neighbours errs 2.9-7 σ at the median; a sample the drive
    did not answer stays lost, and so does a gap with a lost voltage in it."""
    from drive_tools.evaluation.recorded_inputs import rebuilt_currents

    rng = np.random.default_rng(11)
    for _ in range(5):
        n, T_s, sigma = 6000, 1.0 / rng.uniform(5e3, 20e3), 0.01
        L_d = rng.uniform(2e-4, 5e-3)
        L_q, R = L_d * rng.uniform(1.1, 3.0), rng.uniform(0.05, 2.0)
        theta = rng.uniform(-np.pi, np.pi) + 2 * np.pi * rng.uniform(0.0, 2.0) * np.arange(n) * T_s
        k = np.arange(n)
        ripple_A = rng.uniform(0.05, 0.5)
        carrier = ripple_A * L_d / T_s * np.sin(2 * np.pi * k / rng.uniform(4.0, 20.0))
        u = np.column_stack((carrier * np.cos(theta) + 0.3 * np.sin(k * T_s * 7),
                             carrier * np.sin(theta) + 0.2 * np.cos(k * T_s * 5)))
        i = np.zeros((n, 2))
        for j in range(1, n):
            c, s = np.cos(theta[j - 1]), np.sin(theta[j - 1])
            rot = np.array([[c, -s], [s, c]])
            admittance = rot @ np.diag((1 / L_d, 1 / L_q)) @ rot.T
            i[j] = i[j - 1] + T_s * admittance @ (u[j] - R * i[j - 1])
        abc = np.column_stack((i[:, 0], -0.5 * i[:, 0] + np.sqrt(3) / 2 * i[:, 1],
                               -0.5 * i[:, 0] - np.sqrt(3) / 2 * i[:, 1]))
        measured = abc + rng.normal(0.0, sigma, abc.shape)
        lost = np.zeros(n, dtype=bool)
        for start in rng.choice(np.arange(100, n - 100), size=20, replace=False):
            lost[start:start + rng.integers(1, 4)] = True
        answered = np.ones(n, dtype=bool)
        unanswered = rng.choice(np.flatnonzero(lost), size=3, replace=False)
        answered[unanswered] = False
        recorded = measured.copy()
        recorded[lost] = np.nan
        rebuilt = rebuilt_currents(recorded, u, answered)
        done = lost & np.isfinite(rebuilt).all(axis=1)
        assert np.isnan(rebuilt[unanswered]).all()
        error = np.abs(rebuilt[done] - abc[done]).max(axis=1)
        assert done.sum() >= lost.sum() - 3 * 3 and error.max() <= 3 * sigma
        assert np.median(error) <= 1.2 * sigma
        at = np.flatnonzero(~lost)
        interpolated = np.column_stack([np.interp(np.flatnonzero(done), at, measured[at, j]) for j in range(3)])
        assert np.median(np.abs(interpolated - abc[done]).max(axis=1)) > 2.5 * np.median(error)
        u_lost = u.copy()
        gap = np.flatnonzero(done)[0]
        u_lost[gap] = np.nan
        assert np.isnan(rebuilt_currents(recorded, u_lost, answered)[gap]).all()
