"""Recordings: the graph's and the runner's bags have the contract's layout, are read alike by rosbags
and by the mcap library, stamp every per-sample message with its sample instant, and a cut recording is
rebuilt by `drive bag reindex`."""
import dataclasses
import json
import math
import subprocess
import sys

import numpy as np
import pytest

from drive_common.config.scenario import load_scenario
from drive_common.contract.log import COLUMN
from drive_common.contract.run_result import RunResult
from drive_common.contract.topics import CONTRACT_VERSION, SAMPLE_BLOCK, TOPICS
from drive_tools.bags.common import BagCutError, BagError
from drive_tools.bags.reader import bag_info, bag_log, bag_scenario, recorded_estimator
from drive_tools.bags.writer import write_run_bag
from drive_tools.evaluation.metrics import compute_metrics
from drive_tools.runner.runner import run_scenario

DRIVE = [sys.executable, "-m", "drive_tools.cli.cli"]
PER_SAMPLE = ("currents", "rotor_state", "rotor_estimate", "injection", "voltage_command", "estimator_state",
              "angle_error", "/clock", "load_torque")
SCENARIO = """\
motor: wang_spmsm
estimator: injection_frame
injection: {frequency_Hz: 900.0, amplitude_V: 5.0}
duration_s: 0.05
sampling_period_s: 1.0e-4
speed: {unit: rpm, interpolation: linear, points: [[0.0, 0.0], [0.05, 50.0]]}
load: {unit: rated, points: [[0.0, 0.0], [0.02, 0.3]]}
metrics: {settle_s: 0.01}
"""


def recorded_run(path):
    """A recorded run as a RunResult, its scenario rebuilt from the bag's drive_config, so that it is scored
    as `drive run` scores a run: what the replays and comparisons are checked against."""
    log, T_s, configs = bag_log(path)
    scenario = bag_scenario(path, configs)
    if scenario is None:
        raise BagError(f"{path}: no drive_config names a scenario to score the run against")
    scenario = dataclasses.replace(scenario, duration_s=log.shape[0] * T_s, T_s=T_s)
    limit = next((c["current_limit_A"] for c in configs if "current_limit_A" in c),
                 next((c["controller"]["i_max_A"] for c in configs if isinstance(c.get("controller"), dict)
                       and "i_max_A" in c["controller"]), math.nan))
    return RunResult(scenario, recorded_estimator(configs) or scenario.estimator, log, 0.0, limit)


def mcap_stamps(bag, topic):
    """(log time, header stamp) pairs of a topic read with the mcap library and its ROS 2 decoder."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    (file,) = bag.glob("*.mcap")
    with file.open("rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        return [(m.log_time, (d.clock if topic == "/clock" else d.header.stamp))
                for _, _, m, d in reader.iter_decoded_messages(topics=[topic])]


@pytest.fixture(scope="module")
def bags(tmp_path_factory):
    pytest.importorskip("rclpy")
    from drive_tools.launch.launcher import DriveSpec, launch
    root = tmp_path_factory.mktemp("bags")
    path = root / "scenario.yaml"
    path.write_text(SCENARIO)
    launch(DriveSpec(str(path), "/drive", bag=str(root / "graph")))
    write_run_bag(run_scenario(load_scenario(str(path))), root / "run")
    return root / "graph", root / "run", 500


def test_graph_and_runner_bags_have_the_contract_layout(bags):
    graph, run, n = bags
    for bag in (graph, run):
        info = bag_info(bag)
        assert info["storage"] == "mcap" and info["compression"] == "MCAP chunks: zstd"
        counts = {t["topic"]: (t["type"], t["count"]) for t in info["topics"]}
        for topic in PER_SAMPLE:
            name = topic if topic.startswith("/") else f"/drive/{topic}"
            assert counts[name] == (TOPICS[topic].type, n), (bag.name, topic)
        assert counts["/drive/drive_config"][1] >= 1
        assert all(t["serialization"] == "cdr" and t["offered_qos"] for t in info["topics"])
    graph_topics = {t["topic"] for t in bag_info(graph)["topics"]}
    run_topics = {t["topic"] for t in bag_info(run)["topics"]}
    assert graph_topics - run_topics == {"/diagnostics", "/drive/joint_states"}


def test_every_drive_config_follows_the_v2_schema(bags):
    """Both bags' drive_config entries carry the contract-v2 keys: version, sample period, delay, the
    nameplate as `motor`, the scenario; the estimator's and the runner's its injection by kind."""
    from drive_common.motor.nameplate import NAMEPLATE_REQUIRED
    for bag in bags[:2]:
        _, _, configs = bag_log(bag)
        for config in configs:
            assert config["contract_version"] == CONTRACT_VERSION, config["node"]
            assert config["T_s_s"] == pytest.approx(1e-4), config["node"]
            assert config["command_delay_periods"] == 1 and config["motor"]["name"] == "wang_spmsm"
            assert set(NAMEPLATE_REQUIRED) <= set(config["motor"]) and config["scenario"] == "scenario"
        injections = [c["injection"] for c in configs if "injection" in c]
        assert injections and all(i["kind"] == "alternating" and i["frequency_Hz"] == pytest.approx(1e4 / 11)
                                  for i in injections), injections


def test_per_sample_messages_are_stamped_with_their_sample_instant(bags):
    for bag in bags[:2]:
        for topic in ("/drive/currents", "/drive/voltage_command", "/drive/rotor_estimate", "/clock"):
            pairs = mcap_stamps(bag, topic)
            stamps = np.array([s.sec * 1_000_000_000 + s.nanosec for _, s in pairs])
            np.testing.assert_array_equal(stamps, np.arange(bags[2]) * 100_000)
            np.testing.assert_array_equal([t for t, _ in pairs], stamps)


def test_both_bags_hold_the_same_samples(bags):
    graph, run, _ = bags
    a, T_s, configs = bag_log(graph)
    b, _, _ = bag_log(run)
    assert T_s == pytest.approx(1e-4) and {c["n_p"] for c in configs} == {2}
    for name in ("theta_m", "omega_m", "i_a_meas", "theta_e_hat", "u_alpha", "u_inj_beta", "state",
                 "omega_m_ref", "tau_load"):
        np.testing.assert_allclose(a[:, COLUMN[name]], b[:, COLUMN[name]], atol=1e-9, err_msg=name)


def test_a_cut_recording_is_rebuilt_losing_at_most_the_last_chunk(tmp_path):
    scenario = dataclasses.replace(load_scenario("wang_100rpm"), duration_s=0.4)
    bag = write_run_bag(run_scenario(scenario), tmp_path / "cut")
    full = bag_info(bag)
    (mcap,) = bag.glob("*.mcap")
    (bag / "metadata.yaml").unlink()
    with mcap.open("r+b") as f:
        f.truncate(int(mcap.stat().st_size * 0.7))
    with pytest.raises(BagCutError, match="cut before it closed"):
        bag_info(bag)
    out = subprocess.run(DRIVE + ["bag", "info", str(bag)], capture_output=True, text=True)
    assert out.returncode == 2 and f"`drive bag reindex {bag}` rebuilds it" in out.stderr
    out = subprocess.run(DRIVE + ["bag", "reindex", str(bag), "--json"], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    rebuilt = json.loads(out.stdout)
    assert 0.3 * full["messages"] < rebuilt["messages"] < full["messages"]
    counts = {t["topic"]: t["count"] for t in bag_info(bag)["topics"]}
    assert counts["/drive/currents"] > 1000
    pairs = mcap_stamps(bag, "/drive/currents")
    stamps = [s.sec * 1_000_000_000 + s.nanosec for _, s in pairs]
    assert stamps == list(range(0, 100_000 * len(stamps), 100_000))


def test_bag_errors_name_the_bag(tmp_path):
    out = subprocess.run(DRIVE + ["bag", "info", str(tmp_path / "missing")], capture_output=True, text=True)
    assert out.returncode == 2 and "missing: no such bag" in out.stderr
    (tmp_path / "taken").mkdir()
    out = subprocess.run(DRIVE + ["run", "wang_100rpm", "--duration", "0.01", "--no-plot", "--record",
                                  str(tmp_path / "taken")], capture_output=True, text=True)
    assert out.returncode == 2 and "taken already exists" in out.stderr


def test_compare_scores_the_graph_and_runner_bags_alike(bags, tmp_path):
    graph, run, _ = bags
    out = subprocess.run(DRIVE + ["bench", "compare", str(graph), str(run), "--json", "--out", str(tmp_path)],
                         capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    a, b = json.loads(out.stdout)["runs"]
    assert a["ground_truth"] and b["ground_truth"] and a["samples"] == b["samples"] == 500
    assert a["angle_error_peak"] > 0.0
    assert a["angle_error_peak"] == pytest.approx(b["angle_error_peak"], abs=1e-9)
    assert (tmp_path / "graph_vs_run.png").is_file()


def test_replay_and_compare_score_the_windows_they_are_given(bags, tmp_path):
    """`--windows T0:T1,...` replaces the scenario's steady windows: the replay of the recorded
    estimator scores exactly the recording's angle error over those intervals, and compare too; the
    report says where its windows came from. A window past the recording or not a T0 < T1 pair is
    refused in one line naming the option."""
    from drive_tools.evaluation.metrics import angle_error
    graph, run, _ = bags
    recorded = recorded_run(graph)
    t, error = recorded.log[:, COLUMN["t"]], angle_error(recorded.log, recorded.n_p)
    inside = ((t >= 0.01) & (t < 0.02)) | ((t >= 0.03) & (t < 0.045))
    expected = float(np.sqrt(np.mean(error[inside] ** 2)))
    out = subprocess.run(DRIVE + ["bench", "replay", str(graph), "--estimators", "injection_frame", "--windows",
                                  "0.01:0.02,0.03:0.045", "--json", "--no-plot", "--out", str(tmp_path)],
                         capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    report = json.loads(out.stdout)
    assert report["windows"] == {"source": "--windows", "steady_s": [[0.01, 0.02], [0.03, 0.045]]}
    assert report["results"][0]["angle_error_rms"] == pytest.approx(expected, rel=1e-12)
    out = subprocess.run(DRIVE + ["bench", "compare", str(graph), str(run), "--windows", "0.01:0.02,0.03:0.045",
                                  "--json", "--no-plot"], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert json.loads(out.stdout)["runs"][0]["angle_error_rms"] == pytest.approx(expected, rel=1e-12)
    for windows, says in (("0.01:9", "ends after the recording"), ("0.02:0.01", "0 ≤ T0 < T1"),
                          ("a:b", "0 ≤ T0 < T1")):
        out = subprocess.run(DRIVE + ["bench", "replay", str(graph), "--windows", windows, "--no-plot"],
                             capture_output=True, text=True)
        assert out.returncode == 2 and out.stderr.count("\n") == 1, out.stderr
        assert out.stderr.startswith("drive: --windows: ") and says in out.stderr, out.stderr


def foreign_bag(path, topics):
    """A bag written by someone else: {topic: (msgtype, [serialized messages])}."""
    from drive_tools.bags.common import rosbags_qos
    from drive_tools.bags.writer import BagWriter
    writer = BagWriter(path)
    for topic, (msgtype, messages) in topics.items():
        writer.add(topic, msgtype, rosbags_qos())
        for i, data in enumerate(messages):
            writer.write(topic, data, False, i * 100_000)
    writer.close()
    return path


def test_foreign_bags_with_missing_or_mistyped_topics_are_named(tmp_path):
    from drive_tools.bags.common import typestore
    store = typestore()
    Float64 = store.types["std_msgs/msg/Float64"]
    data = [store.serialize_cdr(Float64(data=1.0), "std_msgs/msg/Float64")] * 3
    mistyped = foreign_bag(tmp_path / "mistyped", {"/drive/currents": ("std_msgs/msg/Float64", data)})
    with pytest.raises(BagError, match="mistyped: /drive/currents is std_msgs/msg/Float64, the contract says "
                                       "geometry_msgs/msg/Vector3Stamped"):
        bag_log(mistyped)
    empty = foreign_bag(tmp_path / "no_currents", {"/drive/speed_command": ("std_msgs/msg/Float64", data)})
    with pytest.raises(BagError, match="no_currents: no /drive/currents messages"):
        bag_log(empty)


def test_replay_reproduces_the_recorded_estimator_and_says_who_it_measures(bags, tmp_path):
    """The recording's own estimator replays to its recorded errors exactly; a demodulating method is not
    applicable on another estimator's excitation, and the report says why."""
    graph, _, n = bags
    out = subprocess.run(DRIVE + ["bench", "replay", str(graph), "--estimators",
                                  "injection_frame,conventional", "--json", "--out", str(tmp_path)],
                         capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    report = json.loads(out.stdout)
    own, other = report["results"]
    recorded = compute_metrics(recorded_run(graph))
    assert report["ground_truth"] and report["recorded_estimator"] == "injection_frame"
    assert own["applicable"] and "any injection whose voltage is known" in own["reason"]
    for key in ("angle_error_rms", "angle_error_bias", "angle_error_peak"):
        assert own[key] == pytest.approx(recorded[key], abs=1e-12), key
    assert not other["applicable"] and "own carrier on its own axis" in other["reason"]
    assert "angle_error_rms" not in other and "lost" not in other
    assert own["samples"] == n and own["samples_per_second"] > 0
    assert (tmp_path / "replay.json").is_file() and (tmp_path / "angle_error.png").is_file()


def test_a_block_recording_reads_back_sample_by_sample_and_replays_exactly(tmp_path):
    """A graph run in blocks of 10 is recorded on the block twins (`currents_block` …, 50 messages of 10
    samples); read back it holds the samples of the runner with the same N, and replaying its own
    estimator (the applied voltage lagging by d + 1 = 11 samples) gives the recorded estimate exactly. The same
    recording as contract version 2 made it (its blocks sensor_msgs/JointState) reads and replays the same."""
    pytest.importorskip("rclpy")
    from drive_tools.launch.launcher import DriveSpec, launch
    path = tmp_path / "blocks.yaml"
    path.write_text(SCENARIO + "block_samples: 10\n")
    bag = tmp_path / "graph"
    assert not launch(DriveSpec(str(path), "/blocks", bag=str(bag))).node_faults
    counts = {t["topic"]: (t["type"], t["count"]) for t in bag_info(bag)["topics"]}
    for topic in ("currents", "rotor_state", "rotor_estimate", "injection", "voltage_command", "estimator_state"):
        assert counts[f"/blocks/{topic}_block"] == ("drive_msgs/msg/SampleBlock", 50), topic
        assert f"/blocks/{topic}" not in counts or topic == "estimator_state"
    log, T_s, _ = bag_log(bag)
    reference = run_scenario(load_scenario(str(path))).log
    assert log.shape == reference.shape and T_s == pytest.approx(1e-4)
    for name in ("theta_m", "i_a_meas", "theta_e_hat", "u_alpha", "u_inj_beta", "state"):
        np.testing.assert_allclose(log[:, COLUMN[name]], reference[:, COLUMN[name]], atol=1e-9, err_msg=name)
    legacy = tmp_path / "as_contract_v2"
    as_contract_v2(bag, legacy)
    assert {t["type"] for t in bag_info(legacy)["topics"] if t["topic"].endswith("_block")} == {
        "sensor_msgs/msg/JointState"}
    np.testing.assert_array_equal(bag_log(legacy)[0], log)
    recorded = compute_metrics(recorded_run(bag))
    for recording in (bag, legacy):
        out = subprocess.run(DRIVE + ["bench", "replay", str(recording), "--estimators", "injection_frame", "--json",
                                      "--out", str(tmp_path / f"replay_{recording.name}")], capture_output=True,
                             text=True)
        assert out.returncode == 0, out.stderr
        (own,) = json.loads(out.stdout)["results"]
        assert own["applicable"]
        assert own["angle_error_rms"] == pytest.approx(recorded["angle_error_rms"], abs=1e-12)


def as_contract_v2(bag, out):
    """``bag`` rewritten as contract version 2 recorded it: its blocks typed sensor_msgs/msg/JointState (the same
    CDR bytes), everything else as it is."""
    from drive_tools.bags.reader import open_bag
    from drive_tools.bags.writer import BagWriter
    reader, writer = open_bag(bag), BagWriter(out)
    try:
        for c in reader.connections:
            writer.add(c.topic, "sensor_msgs/msg/JointState" if c.msgtype == SAMPLE_BLOCK else c.msgtype,
                       c.ext.offered_qos_profiles[0])
        for c, t_ns, data in reader.messages():
            writer.write(c.topic, data, False, t_ns)
    finally:
        reader.close()
        writer.close()


def copy_without(source, target, dropped):
    """A copy of a bag without some topics (as a bag recorded without ground truth would be)."""
    from rosbags.rosbag2 import Reader

    from drive_tools.bags.common import rosbags_qos
    from drive_tools.bags.writer import BagWriter
    writer = BagWriter(target)
    with Reader(source) as reader:
        kept = [c for c in reader.connections if c.topic not in dropped]
        for c in kept:
            writer.add(c.topic, c.msgtype, rosbags_qos())
        for c, t, data in reader.messages(kept):
            writer.write(c.topic, data, False, t)
    writer.close()
    return target


def test_replay_without_ground_truth_scores_consistency_only(bags, tmp_path):
    bag = copy_without(bags[1], tmp_path / "no_truth", {"/drive/rotor_state", "/drive/angle_error"})
    out = subprocess.run(DRIVE + ["bench", "replay", str(bag), "--estimators", "injection_frame"],
                         capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert "no ground truth (rotor_state) in this bag: scored for consistency only" in out.stdout
    no_voltage = copy_without(bags[1], tmp_path / "no_voltage", {"/drive/voltage_command"})
    out = subprocess.run(DRIVE + ["bench", "replay", str(no_voltage)], capture_output=True, text=True)
    assert out.returncode == 2 and "no_voltage: no sample holds both currents and voltage_command" in out.stderr


def test_a_killed_recorder_leaves_chunks_that_reindex_makes_a_bag(tmp_path):
    import signal
    import time
    bag = tmp_path / "killed"
    launcher = subprocess.Popen(DRIVE + ["launch", "wang_100rpm", "--namespace", "/killed", "--no-plot",
                                         "--record", str(bag)],
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 60.0
    while sum(f.stat().st_size for f in bag.glob("*.mcap")) < 300_000:
        assert time.monotonic() < deadline and launcher.poll() is None, "recording did not grow"
        time.sleep(0.05)
    launcher.send_signal(signal.SIGKILL)
    launcher.wait()
    out = subprocess.run(DRIVE + ["bag", "info", str(bag)], capture_output=True, text=True)
    assert out.returncode == 2 and f"drive bag reindex {bag}" in out.stderr
    out = subprocess.run(DRIVE + ["bag", "reindex", str(bag), "--json"], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    counts = {t["topic"]: t["count"] for t in json.loads(out.stdout)["topics"]}
    assert 1000 < counts["/killed/currents"] < 15000


def test_a_truncated_mcap_under_a_complete_metadata_is_named(tmp_path):
    scenario = dataclasses.replace(load_scenario("wang_100rpm"), duration_s=0.4)
    bag = write_run_bag(run_scenario(scenario), tmp_path / "truncated")
    (mcap,) = bag.glob("*.mcap")
    with mcap.open("r+b") as f:
        f.truncate(mcap.stat().st_size // 3)
    out = subprocess.run(DRIVE + ["bench", "replay", str(bag)], capture_output=True, text=True)
    assert out.returncode == 2 and out.stderr.startswith(f"drive: {bag}: ")
    assert f"drive bag reindex {bag} --force" in out.stderr
    out = subprocess.run(DRIVE + ["bag", "reindex", str(bag), "--force", "--json"], capture_output=True,
                         text=True)
    assert out.returncode == 0, out.stderr
    assert 0 < json.loads(out.stdout)["messages"]


def test_bulk_cdr_records_equal_the_rosbags_serialiser():
    from drive_tools.bags.writer import (
        CDR_LITTLE_ENDIAN,
        _cdr_joint_state,
        _cdr_scalars,
        _cdr_vector3_stamped,
        typestore,
    )
    store = typestore()
    T = store.types
    stamp = T["builtin_interfaces/msg/Time"](sec=3, nanosec=700)
    header = T["std_msgs/msg/Header"]

    def same(records, msg, msgtype):
        records["enc"] = CDR_LITTLE_ENDIAN
        assert records.tobytes() == bytes(store.serialize_cdr(msg, msgtype)), msgtype

    one = (np.array([3]), np.array([700]))
    for frame in ("abc", "alpha_beta", ""):
        vector = T["geometry_msgs/msg/Vector3"](x=1.5, y=-2.0, z=3.25)
        same(_cdr_vector3_stamped(*one, frame, [1.5], [-2.0], [3.25]),
             T["geometry_msgs/msg/Vector3Stamped"](header=header(stamp=stamp, frame_id=frame), vector=vector),
             "geometry_msgs/msg/Vector3Stamped")
    for effort in ([], [0.5]):
        msg = T["sensor_msgs/msg/JointState"](header=header(stamp=stamp, frame_id=""), name=["rotor"],
                                              position=np.array([1.5]), velocity=np.array([-2.0]),
                                              effort=np.array(effort, dtype=float))
        same(_cdr_joint_state(*one, [1.5], [-2.0], effort or None), msg, "sensor_msgs/msg/JointState")
    same(_cdr_scalars(("<f8",), [2.5]), T["std_msgs/msg/Float64"](data=2.5), "std_msgs/msg/Float64")
    same(_cdr_scalars(("<i4", "<u4"), [3], [700]), T["rosgraph_msgs/msg/Clock"](clock=stamp),
         "rosgraph_msgs/msg/Clock")


def test_a_bag_with_an_unknown_message_type_is_named(tmp_path):
    from rosbags.rosbag2 import StoragePlugin, Writer
    path = tmp_path / "unknown_type"
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        connection = writer.add_connection("/drive/currents", "my_msgs/msg/PhaseCurrents",
                                           msgdef="float64 a\nfloat64 b\nfloat64 c", rihs01="RIHS01_" + "0" * 64)
        writer.write(connection, 0, b"\x00\x01\x00\x00" + b"\x00" * 24)
    assert [t["type"] for t in bag_info(path)["topics"]] == ["my_msgs/msg/PhaseCurrents"]
    out = subprocess.run(DRIVE + ["bench", "replay", str(path)], capture_output=True, text=True)
    assert out.returncode == 2
    assert out.stderr.strip() == (f"drive: {path}: /drive/currents is my_msgs/msg/PhaseCurrents, the contract "
                                  f"says geometry_msgs/msg/Vector3Stamped")


def test_a_metadata_duration_that_ends_before_it_starts_is_not_reported_as_fact(tmp_path):
    """metadata.yaml edited to a negative duration: `drive bag info` says the duration is not known and warns,
    rather than printing a negative one."""
    import re

    from drive_tools.bags.reader import bag_info_lines
    bag = write_run_bag(run_scenario(dataclasses.replace(load_scenario("wang_100rpm"), duration_s=0.05)),
                        tmp_path / "negative")
    metadata = bag / "metadata.yaml"
    metadata.write_text(re.sub(r"(duration:\s*\n\s*nanoseconds:\s*)(\d+)", r"\g<1>-\2", metadata.read_text(), count=1))
    info = bag_info(bag)
    assert info["duration_s"] is None
    assert any("ends before it starts" in warning for warning in info["warnings"])
    assert "  duration not known (start " in "\n".join(bag_info_lines(info))
