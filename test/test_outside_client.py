"""An outside DDS client without rclpy (test/tools/dds_client.py: Cyclone DDS from PyPI, speaking RTPS to the
drive's Fast DDS over the loopback): it reads a running drive's `angle_error` and `joint_states`, and commands
`speed_command` on a drive without a scenario (docs/ros-graph.md, "A drive without a scenario")."""
import json
import time
from pathlib import Path

import numpy as np
import pytest

from drive_common.contract.estimator_states import TRACKING

pytest.importorskip("cyclonedds")
from tools.dds_process import client, lines, matched  # noqa: E402

COMMISSIONING = Path(__file__).resolve().parent.parent / "commissioning" / "wang_spmsm.yaml"
SPEED_RAD_PER_S = 4.0


def test_an_outside_client_reads_a_running_drives_angle_error_and_joint_states(tmp_path):
    """1 s of wang_100rpm over the graph, recorded: the client, started first, reads its angle error (10 kHz of the
    drive's time) and joint states (100 Hz) as their QoS promises a reliable, volatile reader: once the drive's
    new writers and the client's reader have found each other (discovery takes its time, and a reader may get a few
    messages before its writer has matched it: on this machine the run's first 0-12 % went before, once with 128
    messages read ahead of a gap of 761), every message to the run's end, each the recorded value to the bit; and
    that within the first fifth of the run."""
    from drive_tools.bags.reader import read_topics
    from drive_tools.launch.launcher import DriveSpec, launch
    reader = client(tmp_path / "read.jsonl", "--read", "/outside/angle_error", "Vector3Stamped",
                    "--read", "/outside/joint_states", "JointState", "--duration", "120", "--count", "10100",
                    "--idle", "5")
    matched(reader, tmp_path / "read.jsonl", ())
    time.sleep(1.0)  # the drive's writers are made by the launch; the client's participant known to the graph first
    bag = tmp_path / "run"
    result = launch(DriveSpec("wang_100rpm", "/outside", duration_s=1.0, bag=str(bag)))
    assert not result.node_faults
    got, summary = lines(reader, tmp_path / "read.jsonl")
    _, recorded = read_topics(bag, ("angle_error", "joint_states"), "/outside")
    for topic, n in (("angle_error", 10_000), ("joint_states", 100)):
        truth = {(m.header.stamp.sec, m.header.stamp.nanosec): m for _, m in recorded[topic]}
        assert len(truth) == n
        mine = [r for r in got if r["topic"] == f"/outside/{topic}"]
        read = sorted((r["header"]["stamp"]["sec"], r["header"]["stamp"]["nanosec"]) for r in mine)
        stamps = sorted(truth)
        tail = 0
        while tail < len(read) and read[-1 - tail] == stamps[-1 - tail]:
            tail += 1
        assert tail >= 0.8 * n, f"{topic}: {len(read)} read, the last {tail} of the run without a gap"
        for r in mine:
            m = truth[(r["header"]["stamp"]["sec"], r["header"]["stamp"]["nanosec"])]
            if topic == "angle_error":
                assert [r["vector"][a] for a in "xyz"] == [m.vector.x, m.vector.y, m.vector.z]
            else:
                assert r["velocity"] == list(m.velocity) and r["name"] == ["outside"]


def test_an_outside_client_commands_the_speed_of_a_drive_without_a_scenario(tmp_path):
    """The estimator and the controller run from a drive configuration alone (scenario:=''), the plant its
    experiment (2 s at rest from 1.3 rad, no speed of its own for them); the client publishes `speed_command`
    4 rad/s at 20 Hz and reads `joint_states`: the estimated speed it reads goes from 0 to 4 rad/s (its mean
    over the last 0.2 s within 0.2 rad/s; each reading within ±0.65 rad/s, the injection's ripple: measured
    mean 4.03 rad/s on 2026-11-28), which the plant's true speed confirms (mean 4.03 rad/s)."""
    import rclpy
    from geometry_msgs.msg import Vector3Stamped
    from rclpy.node import Node
    from rclpy.signals import SignalHandlerOptions
    from sensor_msgs.msg import JointState

    from drive_common.ros.node import make_executor, parameter_overrides, topic_qos
    from foc_controller.node import ControllerNode
    from hf_estimator.node import EstimatorNode
    from pmsm_plant.node import PlantNode

    (tmp_path / "drive.yaml").write_text(f"format_version: 1\nmotor: wang_spmsm\nestimator: injection_frame\n"
                                         f"commissioning: {COMMISSIONING}\nsampling_period_s: 1.0e-4\n")
    (tmp_path / "experiment.yaml").write_text("drive: drive.yaml\nduration_s: 2.0\ninitial: {theta_m_rad: 1.3}\n"
                                              "speed: {unit: rpm, points: [[0.0, 0.0]]}\n")
    namespace = "/outside_speed"
    commander = client(tmp_path / "commanded.jsonl",
                       "--publish", f"{namespace}/speed_command", "Float64", json.dumps({"data": SPEED_RAD_PER_S}),
                       "--read", f"{namespace}/joint_states", "JointState", "--rate", "20", "--duration", "600",
                       "--idle", "5")
    context = rclpy.Context()
    rclpy.init(context=context, signal_handler_options=SignalHandlerOptions.NO)
    alone = {"scenario": "", "drive_configuration": str(tmp_path / "drive.yaml")}
    nodes = [PlantNode(context=context, namespace=namespace,
                       parameter_overrides=parameter_overrides({"scenario": str(tmp_path / "experiment.yaml")})),
             EstimatorNode(context=context, namespace=namespace, parameter_overrides=parameter_overrides(alone)),
             ControllerNode(context=context, namespace=namespace, parameter_overrides=parameter_overrides(alone))]
    tester = Node("tester", context=context, namespace=namespace)
    truth, states = [], []
    tester.create_subscription(JointState, "rotor_state", lambda m: truth.append(m.velocity[0]),
                               topic_qos("rotor_state"))
    tester.create_subscription(Vector3Stamped, "estimator_state", lambda m: states.append(m.vector.z),
                               topic_qos("estimator_state"))
    executor = make_executor("events", context)
    try:
        assert all(n.configured for n in nodes) and nodes[2].scenario is None and nodes[2].config.open_ended
        matched(commander, tmp_path / "commanded.jsonl", (f"{namespace}/speed_command", f"{namespace}/joint_states"))
        for node in nodes + [tester]:
            executor.add_node(node)
        end = time.monotonic() + 300.0
        while len(truth) < 20_000:
            assert time.monotonic() < end, f"{len(truth)} samples in 300 s"
            executor.spin_once(timeout_sec=0.05)
    finally:
        executor.shutdown()
        for node in nodes + [tester]:
            node.destroy_node()
        context.try_shutdown()
    got, summary = lines(commander, tmp_path / "commanded.jsonl", timeout_s=600.0)
    assert summary["published"] > 0 and summary["read"] >= 180  # of 200; any before its reader matched: not promised
    velocity = [r["velocity"][0] for r in got]
    assert truth[0] == 0.0
    stamps = np.array([r["stamp_s"] for r in got])
    late = np.array(velocity)[stamps >= 1.8]
    assert late.size >= 10 and abs(np.mean(late) - SPEED_RAD_PER_S) < 0.2, late
    assert abs(np.mean(truth[-2000:]) - SPEED_RAD_PER_S) < 0.2
    assert states.count(TRACKING) > 15_000
