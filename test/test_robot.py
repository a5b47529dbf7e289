"""`drive up ROBOT.yaml` (issue 54, docs/robot.md): robot files refused in one line; the documented hand-started
commands as written in a shell; two virtual axes in one process, driven through the lifecycle from this (another)
process, commanded on the joint command topic, bad commands refused and counted, a command timeout that holds a
loaded joint and later releases it, and SIGTERM that leaves every inverter switched off."""
import contextlib
import json
import math
import os
import re
import signal
import subprocess
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
DRIVE = ROOT / ".venv" / "bin" / "drive"
LOAD_NM = 0.045
"""The shoulder's load from LOAD_ON_S of the simulation on (≈ 20 % of wang_spmsm's rated torque): gravity."""
LOAD_ON_S = 7.0
LOAD_SETTLE_S = 1.0
"""Simulated time after the load steps on within which the shoulder's speed may still be off its command (the
speed loop's recovery from the step)."""
JUDGED_SPAN_MARGIN_S = 0.3
"""Simulated time a judged span is kept clear of the load step beyond its length: `spin_simulated` first spins 0.1 s
of the host's time, and the states a client reads lag the simulation."""
HOLD_WITHIN_RAD = 0.25
"""The held shaft's angle (the simulation's truth) stays within this range while the joint is held."""
VELOCITY_LIMIT = 20.0
HOLD_S = 6.0
"""The shoulder's hold timeout [s of the host's time]: lock-step, the two axes' simulations run at a fraction of real
time (≈ 0.1-0.2 on a loaded 2-core machine), and the hold must last STOP_SETTLE_S of simulated time and more."""
STOPPED_RAD_S = 0.2
"""The shoulder has stopped once its true speed is below this."""
STOP_WITHIN_S = 2.0
"""Simulated time from the command timeout (as the client's host time maps it) within which the shoulder stops: the
ramp takes at most 0.2 s; the rest is how late a loaded machine delivers the client's last commands and the truth."""
STOP_SETTLE_S = 0.3
"""Simulated time from the shoulder's stop until it is judged held: the hold's settling."""
COMMAND_TIMEOUT_S = 0.5
"""The shoulder's command timeout [s]: the test's clients publish every 20-50 ms, and a loaded machine held one for
over 0.1 s (the shoulder then held its joint between two commands)."""
LOCKSTEP_LINK_TIMEOUT_S = 3.0
"""The lock-step axes' link timeout [s of the host's time] (the robot file's default is 0.5 s): their virtual
inverter is a simulation on a thread of `drive up`'s process, and with both cores busy and more (the suite's other
worker and a second run) its next block came over 0.5 s after the answer, so the whole arm stopped as a lost link."""


def drive_files(folder, duration_s=120.0, load=True):
    """A drive configuration, the simulated machine (a scenario: the load steps on at LOAD_ON_S) and a robot file."""
    (folder / "arm_drive.yaml").write_text(
        "format_version: 1\nmotor: wang_spmsm\n"
        f"commissioning: {ROOT / 'commissioning' / 'wang_spmsm.yaml'}\n"
        "estimator: injection_frame\nsampling_period_s: 1.0e-4\nblock_samples: 10\n")
    load_points = f"[[0.0, 0.0], [{LOAD_ON_S}, {LOAD_NM}]]" if load else "[[0.0, 0.0]]"
    (folder / "arm_sim.yaml").write_text(
        f"drive: arm_drive.yaml\nduration_s: {duration_s}\ninitial: {{theta_m_rad: 1.3}}\n"
        "speed: {unit: rad_s, interpolation: step, points: [[0.0, 0.0]]}\n"
        f"load: {{unit: Nm, interpolation: step, points: {load_points}}}\n")


def robot_file(folder, text):
    path = folder / "robot.yaml"
    path.write_text(text)
    return path


ARM = f"""format_version: 1
axes:
  - {{joint: shoulder, drive: arm_drive.yaml, link: virtual, scenario: arm_sim.yaml, paced: false,
     link_timeout_s: {LOCKSTEP_LINK_TIMEOUT_S}, velocity_limit_rad_s: {VELOCITY_LIMIT},
     command_timeout_s: {COMMAND_TIMEOUT_S}, hold_timeout_s: {HOLD_S}}}
  - {{joint: wrist, drive: arm_drive.yaml, link: virtual, scenario: arm_sim.yaml, reversed: true, paced: false,
     link_timeout_s: {LOCKSTEP_LINK_TIMEOUT_S}}}
"""


@pytest.mark.unit
@pytest.mark.parametrize("text, where", [
    ("format_version: 1\naxes: []\n", "axes: must be a list"),
    ("format_version: 1\naxes:\n  - {joint: a, drive: arm_drive.yaml, link: serial}\n", "axes[0].port: missing"),
    ("format_version: 1\naxes:\n  - {joint: a, drive: nope.yaml, link: can}\n",
     "nope.yaml: no such drive configuration"),
    ("format_version: 1\naxes:\n  - {joint: a, drive: arm_drive.yaml, link: can, command_timeout_s: -1}\n",
     "axes[0].command_timeout_s: must"),
    ("format_version: 1\naxes:\n  - {joint: a, drive: arm_drive.yaml, link: can}\n  - {joint: a, drive: "
     "arm_drive.yaml, link: can, namespace: /b}\n", "axes[1].joint: 'a' is another axis's"),
    ("format_version: 1\nreal_time: {cpus: [99]}\naxes:\n  - {joint: a, drive: arm_drive.yaml, link: can}\n",
     "real_time.cpus: [99]"),
    ("format_version: 1\ninitial_state: on\naxes:\n  - {joint: a, drive: arm_drive.yaml, link: can}\n",
     "initial_state: must be one of"),
    ("format_version: 1\naxes:\n  - {joint: a, drive: arm_drive.yaml, link: wire}\n", "axes[0].link: must be one"),
    ("format_version: 1\naxes:\n  - {joint: a, drive: arm_drive.yaml, link: can, inverter_apart: true}\n",
     "axes[0].inverter_apart: a virtual inverter apart needs link: virtual and paced: true"),
    ("format_version: 1\naxes:\n  - {joint: a, drive: arm_drive.yaml, link: can, answer: python}\n",
     "axes[0].answer: must be one of"),
    ("format_version: 1\naxes:\n  - {joint: a, drive: arm_drive.yaml, link: can, homing: {method: hard_stop, "
     "direction: 1}}\n", "axes[0].homing: hard_stop: give current_A or torque_Nm"),
    ("format_version: 1\naxes:\n  - {joint: a, drive: arm_drive.yaml, link: can, homing: {method: hard_stop, "
     "direction: 2, current_A: 1.0}}\n", "axes[0].homing.direction: must be"),
])
def test_a_bad_robot_file_is_refused_in_one_line_naming_file_key_and_value(tmp_path, text, where):
    from drive_tools.launch.robot_file import RobotFileError, load_robot
    drive_files(tmp_path)
    path = robot_file(tmp_path, text)
    with pytest.raises(RobotFileError) as error:
        load_robot(path)
    line = str(error.value)
    assert "\n" not in line and line.startswith(f"{path}: ") and where in line


@pytest.mark.unit
def test_a_callback_defect_ends_drive_up_in_one_line_naming_where_it_was_raised():
    """A callback that raises (a defect: once a race tore a joint state) ends `drive up`'s spin with exit 3 and one
    line naming the exception and its file:line; bring_up then stops every axis."""
    from drive_common.contract.exit_codes import EXIT_NODE_FAULTS
    from drive_tools.launch.robot import _run

    class Raising:
        def spin_once(self, timeout_sec):
            raise IndexError("array index out of range")

    code, reason = _run(Raising(), [])
    assert code == EXIT_NODE_FAULTS
    assert "\n" not in reason and "IndexError: array index out of range at test_robot.py:" in reason
    assert "safe state" in reason


@pytest.mark.unit
def test_an_armed_axis_whose_compiled_answer_stopped_ends_drive_up_in_one_line():
    """An axis armed with the compiled answer that could not be armed, or whose loop or reader raised: `drive up`
    ends, exit 3, naming the axis and why (the caller then brings every axis to its safe state)."""
    from drive_common.contract.exit_codes import EXIT_NODE_FAULTS
    from drive_tools.launch.robot import _run

    class Idle:
        def spin_once(self, timeout_sec):
            pass

    class Axis:
        spec = type("Spec", (), {"joint": "wrist"})

        def link_lost(self):
            return False

        def answer_failure(self):
            return "its compiled answer's reader stopped (ValueError('x'))"

    code, reason = _run(Idle(), [Axis()])
    assert code == EXIT_NODE_FAULTS
    assert reason == ("axis wrist: its compiled answer's reader stopped (ValueError('x')); every axis put in its safe "
                      "state")


@pytest.mark.unit
def test_stopping_an_axis_whose_compiled_loop_died_goes_on_to_its_safe_state():
    """The loop's exception is reported by the axis (answer_failure), not raised again when the axis is stopped: the
    stop goes on to tell the inverter (drive up's _stop and safe_state)."""
    from drive_tools.launch.axis_answer import AxisAnswer

    class Died:
        stopped = False

        def stop(self):
            self.stopped = True

        def join(self, timeout_s=None):
            raise RuntimeError("the loop died")

    answer = object.__new__(AxisAnswer)
    answer.answer = Died()
    answer.stop()
    assert answer.answer.stopped


def test_the_documented_hand_started_commands_work_as_written_in_a_shell(tmp_path):
    """docs/ros-graph.md, "A drive without a scenario": the estimator's and the controller's lines, `-p scenario:=''`
    and all, run through bash as written; each node starts open-ended on the drive configuration."""
    text = (ROOT / "docs" / "ros-graph.md").read_text()
    lines = re.findall(r"^\.venv/bin/(?:estimator|controller)_node .*scenario:=''.*$", text, re.M)
    assert len(lines) == 2
    (tmp_path / "left_wheel.yaml").write_text(
        f"format_version: 1\nmotor: wang_spmsm\ncommissioning: {ROOT / 'commissioning' / 'wang_spmsm.yaml'}\n"
        "estimator: injection_frame\nsampling_period_s: 1.0e-4\n")
    (tmp_path / ".venv").symlink_to(ROOT / ".venv")
    started = []
    for i, line in enumerate(lines):
        err = tmp_path / f"node_{i}.log"
        started.append((line, err, subprocess.Popen(["bash", "-c", line.replace("/left_wheel", "/documented_wheel")],
                                                    cwd=tmp_path, stderr=err.open("w"), start_new_session=True)))
    try:
        for line, err, process in started:
            deadline = time.monotonic() + 60.0
            while "no experiment: until stopped" not in err.read_text() and process.poll() is None:
                assert time.monotonic() < deadline, (line, err.read_text()[-600:])
                time.sleep(0.2)
    finally:
        for _, _, process in started:
            if process.poll() is None:
                os.killpg(process.pid, signal.SIGINT)
            process.wait(timeout=60)
    for line, err, _ in started:
        assert "no experiment: until stopped" in err.read_text(), (line, err.read_text()[-600:])
        assert "Couldn't parse" not in err.read_text()


class Client:
    """An rclpy client in this process (another than the drive's): the lifecycle, joint commands, /joint_states,
    /diagnostics and the shoulder's encoder (the simulation's truth, `rotor_state_block`)."""

    def __init__(self):
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import QoSProfile
        from sensor_msgs.msg import JointState

        from drive_common.contract.topics import ROTOR_STATE, block
        from drive_common.contract.wire import decode_block
        from drive_common.ros.node import message_class, topic_qos
        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node("robot_test_client", context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.states, self.diagnostics, self.truth, self.zero_voltage, self.commands_seen = [], {}, [], [], []
        self.commanded_at = None
        """The host time of the last command spin() published."""
        self.shoulder_modes = []
        """(host time, mode) of each /diagnostics the shoulder's controller sent with its command mode."""
        self.command_pub = self.node.create_publisher(JointState, "/joint_commands", 10)
        self.states_at = []
        """(shoulder's, wrist's simulated time [s]) when each of self.states came."""

        def on_states(msg):
            self.states.append(msg)
            self.states_at.append((self.truth[-1][0] if self.truth else math.nan, self.wrist_at[0]))
        self.node.create_subscription(JointState, "/joint_states", on_states, QoSProfile(depth=100))

        def on_diagnostics(msg):
            for status in msg.status:
                self.diagnostics[status.name] = {v.key: v.value for v in status.values}
                if status.name == "/shoulder/foc_controller" and "command" in self.diagnostics[status.name]:
                    self.shoulder_modes.append((time.monotonic(), self.diagnostics[status.name]["command"]))
        self.node.create_subscription(DiagnosticArray, "/diagnostics", on_diagnostics, QoSProfile(depth=100))
        topic = block(ROTOR_STATE)

        def on_truth(data):
            sec, nanosec, theta, _, _ = decode_block(data)
            self.truth.append((sec + 1e-9 * nanosec, float(theta[0]), time.monotonic()))
        self.node.create_subscription(message_class(topic), f"/shoulder/{topic}", on_truth, topic_qos(topic),
                                      raw=True)
        self.wrist_at = [0.0]
        """The wrist's simulated time [s] (its own lock-step simulation runs at its own pace)."""

        def on_wrist(data):
            sec, nanosec, *_ = decode_block(data)
            self.wrist_at[0] = sec + 1e-9 * nanosec
        self.node.create_subscription(message_class(topic), f"/wrist/{topic}", on_wrist, topic_qos(topic), raw=True)
        self.node.create_subscription(message_class("zero_voltage"), "/shoulder/zero_voltage",
                                      lambda data: self.zero_voltage.append(time.monotonic()),
                                      topic_qos("zero_voltage"), raw=True)
        self.node.create_subscription(message_class(block("voltage_command")), "/shoulder/voltage_command_block",
                                      lambda data: self.commands_seen.append(time.monotonic()),
                                      topic_qos(block("voltage_command")), raw=True)

    def spin(self, seconds, command=None):
        """Spin ``seconds``, publishing ``command`` (names, velocities, efforts) at 50 Hz if given."""
        from sensor_msgs.msg import JointState
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            if command:
                names, velocity, effort = command
                self.command_pub.publish(JointState(name=names, velocity=velocity, effort=effort))
                self.commanded_at = time.monotonic()
            self.executor.spin_once(timeout_sec=0.02)

    def spin_simulated(self, seconds, command=None):
        """Spin until both joints' simulations have run ``seconds`` more (lock-step: each one's pace is the
        machine's)."""
        self.spin(0.1, command)
        start, wrist, deadline = self.truth[-1][0], self.wrist_at[0], time.monotonic() + 60.0
        while self.truth[-1][0] < start + seconds or self.wrist_at[0] < wrist + seconds:
            assert time.monotonic() < deadline, (f"the simulations stopped at {self.truth[-1][0]:.3f} s (shoulder), "
                                                 f"{self.wrist_at[0]:.3f} s (wrist)")
            self.spin(0.1, command)

    def lifecycle(self, namespace, transition=None):
        """The axis's state after ``transition`` (a lifecycle_msgs Transition id) if given."""
        from lifecycle_msgs.srv import ChangeState, GetState
        if transition is not None:
            client = self.node.create_client(ChangeState, f"{namespace}/drive_axis/change_state")
            assert client.wait_for_service(timeout_sec=60.0)
            request = ChangeState.Request()
            request.transition.id = transition
            future = client.call_async(request)
            self.executor.spin_until_future_complete(future, timeout_sec=30.0)
            assert future.result().success
        client = self.node.create_client(GetState, f"{namespace}/drive_axis/get_state")
        assert client.wait_for_service(timeout_sec=60.0)
        future = client.call_async(GetState.Request())
        self.executor.spin_until_future_complete(future, timeout_sec=120.0)
        return future.result().current_state.label

    def joint(self, name, last=10, over_s=None):
        """The mean (position, velocity) of ``name`` over its last ``last`` distinct states on /joint_states, or with
        ``over_s`` over those that came in the joint's last ``over_s`` of simulated time (a mean over a span of the
        simulation: a handful of states may come within a fraction of one period of the speed loop's ripple). A
        state repeated while the lock-step simulation waits counts once."""
        side = 1 if name == "wrist" else 0
        end = self.states_at[-1][side] if self.states_at else math.nan
        held = []
        for m, at in zip(self.states, self.states_at):
            if name in m.name and (over_s is None or at[side] >= end - over_s):
                state = (m.position[m.name.index(name)], m.velocity[m.name.index(name)])
                if not held or state != held[-1]:
                    held.append(state)
        held = held if over_s is not None else held[-last:]
        if not held:
            return math.nan, math.nan
        return sum(p for p, _ in held) / len(held), sum(v for _, v in held) / len(held)

    def robot_faults(self):
        return {k: int(v) for k, v in self.diagnostics.get("/drive_robot", {}).items() if k.startswith("faults.")}

    def close(self):
        self.executor.shutdown()
        self.node.destroy_node()
        self.context.try_shutdown()


UP_WAIT_S = 300.0
"""The longest `drive up` may take to say it is up: its axes' compiled answer is compiled once after an install or an
edit (tens of seconds, longer with the suite's other worker compiling too)."""


def wait_until_up(process, log):
    """Wait until `drive up` said its axes are in their initial state (its "drive up: N axes: ..." line on ``log``)."""
    deadline = time.monotonic() + UP_WAIT_S
    while not re.search(r"^drive up: \d+ axes?:", log.read_text(), re.MULTILINE):
        assert process.poll() is None, log.read_text()[-2000:]
        assert time.monotonic() < deadline, f"not up within {UP_WAIT_S:g} s: {log.read_text()[-2000:]}"
        time.sleep(0.2)


@pytest.fixture(scope="module")
def arm(tmp_path_factory):
    """`drive up` of a two-axis arm (shoulder, wrist: virtual inverters) left inactive, and this process's client."""
    folder = tmp_path_factory.mktemp("arm")
    drive_files(folder)
    path = robot_file(folder, ARM)
    out, err = (folder / "up.json").open("w"), (folder / "up.log").open("w")
    process = subprocess.Popen([str(DRIVE), "up", str(path), "--json", "--record", "arm_bag"], cwd=folder, stdout=out,
                               stderr=err)
    process.folder = folder
    client = Client()
    try:
        wait_until_up(process, folder / "up.log")
        assert client.lifecycle("/shoulder") == "inactive"
        yield process, client
    finally:
        client.close()
        if process.poll() is None:
            process.kill()
            process.wait()


def test_inactive_axes_apply_zero_volts_and_another_process_drives_their_lifecycle(arm):
    process, client = arm
    client.spin(1.0)
    assert process.poll() is None
    assert client.lifecycle("/wrist") == "inactive"
    assert len(client.zero_voltage) >= 10, "the inverter reports every block at zero volts while inactive"
    assert not client.commands_seen, "no voltage command while inactive"
    supervisor = subprocess.run([str(DRIVE), "axis", "shoulder", "activate", "--json"], capture_output=True,
                                text=True, timeout=60)
    assert supervisor.returncode == 0, supervisor.stderr
    assert json.loads(supervisor.stdout)["state"] == "active"
    assert client.lifecycle("/wrist", transition=3) == "active"
    cleanup_while_active = subprocess.run([str(DRIVE), "axis", "wrist", "cleanup"], capture_output=True, text=True,
                                          timeout=60)
    assert cleanup_while_active.returncode == 2 and "refused" in cleanup_while_active.stderr
    assert client.lifecycle("/wrist") == "active" and process.poll() is None
    client.spin(2.0)
    assert client.commands_seen, "armed, the drive answers"


def clear_of_the_load_step(client, span_s, command=None):
    """Spin (publishing ``command``) until the next ``span_s`` of both joints' simulated time lies clear of the load's
    step and the speed loop's recovery from it (LOAD_ON_S to LOAD_ON_S + LOAD_SETTLE_S), with JUDGED_SPAN_MARGIN_S.
    Lock-step, how far the simulations have run when a test begins is the machine's pace: on a loaded one the step
    fell in a judged span and the shoulder read -2.7 rad/s for -2.0."""
    def clear(now):
        return now + span_s + JUDGED_SPAN_MARGIN_S < LOAD_ON_S or now > LOAD_ON_S + LOAD_SETTLE_S
    while not (clear(client.truth[-1][0]) and clear(client.wrist_at[0])):
        client.spin_simulated(0.1, command)


def test_joint_commands_move_both_joints_at_their_speed_and_sign(arm):
    _, client = arm
    command = (["shoulder", "wrist"], [3.0, -3.0], [])
    clear_of_the_load_step(client, 1.0, command)
    client.spin_simulated(1.0, command)
    for joint, speed in (("shoulder", 3.0), ("wrist", -3.0)):
        assert client.joint(joint, over_s=0.5)[1] == pytest.approx(speed, abs=0.6), (joint, {
            name: status for name, status in client.diagnostics.items() if name.startswith(f"/{joint}/")})


def test_an_outside_client_without_rclpy_commands_both_joints_and_reads_their_states(arm, tmp_path):
    """A Cyclone DDS client (no rclpy, test/tools/dds_client.py) publishes the joint command topic for both joints at
    20 Hz and reads `/joint_states`: once both joints turn the commanded way at half the command or more (the robot's
    subscription may match the client's writer later than the client matches it: the joints reversing from the last
    test's command then fell in the judged span) and the span is clear of the load's step, what it reads shows each
    joint at its commanded speed and sign, the mean over the joint's distinct states (lock-step, `/joint_states`
    repeats a joint's last state at its host-timed rate while the simulation waits: a mean over every message weights
    the state a loaded machine held longest)."""
    pytest.importorskip("cyclonedds")
    from tools.dds_process import client as outside_client
    from tools.dds_process import matched, read_so_far
    _, client = arm
    out = tmp_path / "outside.jsonl"
    command = json.dumps({"name": ["shoulder", "wrist"], "velocity": [-2.0, 2.5]})
    outside = outside_client(out, "--publish", "/joint_commands", "JointState", command, "--read", "/joint_states",
                             "JointState", "--rate", "20", "--duration", "600")
    try:
        matched(outside, out, ("/joint_commands", "/joint_states"))
        deadline = time.monotonic() + 120.0
        while not (client.joint("shoulder", last=3)[1] < -1.0 and client.joint("wrist", last=3)[1] > 1.25):
            assert time.monotonic() < deadline, "the outside client's command never took effect"
            client.spin_simulated(0.1)
        client.spin_simulated(0.7)
        clear_of_the_load_step(client, 0.8)
        settled, began, modes_from = len(read_so_far(out)), client.truth[-1], len(client.shoulder_modes)
        client.spin_simulated(0.8)
        read = [r for r in read_so_far(out)[settled:] if set(r["name"]) == {"shoulder", "wrist"}]
        ended = client.truth[-1]
    finally:
        outside.terminate()
        outside.wait(timeout=30)
    assert len(read) >= 5, read
    span = (f"judged over the shoulder's simulated {began[0]:.2f}-{ended[0]:.2f} s, where its truth turned at "
            f"{(ended[1] - began[1]) / (ended[0] - began[0]):.2f} rad/s; its command modes: "
            f"{[mode for _, mode in client.shoulder_modes[modes_from:]]}")
    for joint, speed in (("shoulder", -2.0), ("wrist", 2.5)):
        states = [(r["position"][r["name"].index(joint)], r["velocity"][r["name"].index(joint)]) for r in read]
        speeds = [v for i, (p, v) in enumerate(states) if i == 0 or p != states[i - 1][0]]
        assert len(speeds) >= 5 and sum(speeds) / len(speeds) == pytest.approx(speed, abs=0.6), (joint, span, speeds)


@pytest.mark.parametrize("names, velocity, effort, kind", [
    (["shoulder", "elbow"], [3.0, 3.0], [], "command_unknown_joint"),
    (["shoulder", "wrist"], [math.nan, 3.0], [], "command_not_finite"),
    (["shoulder", "wrist"], [2.0 * VELOCITY_LIMIT, 3.0], [], "command_over_limit"),
    (["shoulder", "wrist"], [3.0, -3.0], [1e3, 0.0], "command_over_limit"),
    (["shoulder", "wrist"], [3.0], [], "command_malformed"),
])
def test_a_bad_command_is_refused_counted_on_diagnostics_and_never_applied(arm, names, velocity, effort, kind):
    """The bad command and a good one are sent in turns: the refusal is counted and the joints follow the good one
    alone (judged over the last 0.3 s of simulated time, LOAD_SETTLE_S clear of the load stepping on at LOAD_ON_S)."""
    _, client = arm
    good = (["shoulder", "wrist"], [3.0, -3.0], [])
    client.spin_simulated(1.0, good)
    before = client.robot_faults().get(f"faults.{kind}", 0)
    from sensor_msgs.msg import JointState
    start, began = client.truth[-1][0], time.monotonic()

    def judged():
        clear = all(now - 0.3 > LOAD_ON_S + LOAD_SETTLE_S or now < LOAD_ON_S
                    for now in (client.truth[-1][0], client.wrist_at[0]))
        return client.truth[-1][0] >= start + 0.3 and time.monotonic() >= began + 1.0 and clear
    while not judged() and time.monotonic() < began + 60.0:
        client.command_pub.publish(JointState(name=names, velocity=velocity, effort=effort))
        client.command_pub.publish(JointState(name=good[0], velocity=good[1]))
        client.spin(0.04)
    assert client.robot_faults().get(f"faults.{kind}", 0) > before
    for joint, speed in zip(*good[:2]):
        assert client.joint(joint, over_s=0.3)[1] == pytest.approx(speed, abs=1.0), f"{joint} took the refused one"


def test_a_command_timeout_holds_the_loaded_joint_then_releases_it(arm):
    """Commands stop with the load on (gravity): the shoulder ramps to zero and is held within HOLD_WITHIN_RAD (the
    simulation's truth, from STOP_SETTLE_S of simulated time after it stopped, which must be within STOP_WITHIN_S of
    the command's timeout) until its hold timeout (HOLD_S of the host's time), then at zero torque the load turns it.
    The test waits for the controller's own word (/diagnostics, once a second of simulated time) on each step: the ramp
    and the hold's settling take simulated time, which a loaded machine stretches; and it finds the stop in the truth,
    not by the host's time, at which a loaded machine's processes (the client's, the drive's commands) lag."""
    _, client = arm
    command = (["shoulder", "wrist"], [3.0, -3.0], [])
    while not client.truth or client.truth[-1][0] < LOAD_ON_S + 0.5:
        client.spin_simulated(0.2, command)
    stopped = client.commanded_at
    modes = []
    while "released" not in modes:
        assert time.monotonic() < stopped + 120.0, f"the shoulder's command modes since the stop: {modes}"
        client.spin(0.1)
        modes = [mode for at, mode in client.shoulder_modes if at > stopped]
    assert "holding" in modes, modes
    released_at = min(at for at, mode in client.shoulder_modes if at > stopped and mode == "released")
    assert released_at > stopped + HOLD_S, "released before its hold timeout (counted from the last command)"
    timed_out = next(t for t, _, at in client.truth if at >= stopped + COMMAND_TIMEOUT_S)
    after = [(t, theta) for t, theta, at in client.truth if t >= timed_out and at <= stopped + HOLD_S - 0.1]
    stop = next((t1 for (t0, a0), (t1, a1) in zip(after, after[1:]) if abs(a1 - a0) < STOPPED_RAD_S * (t1 - t0)),
                math.inf)
    assert stop < timed_out + STOP_WITHIN_S, f"still moving {stop - timed_out:.2f} s of simulation after the timeout"
    held = [theta for t, theta in after if t >= stop + STOP_SETTLE_S]
    assert len(held) > 20, f"{len(held)} states held: the simulation ran {client.truth[-1][0] - timed_out:.2f} s"
    assert max(held) - min(held) < HOLD_WITHIN_RAD
    client.spin_simulated(0.5)
    assert abs(client.truth[-1][1] - held[-1]) > 0.5, "at zero torque the load turns the shaft"


def test_sigterm_brings_every_axis_to_its_safe_state(arm):
    process, _ = arm
    process.send_signal(signal.SIGTERM)
    process.wait(timeout=60)
    assert process.returncode == 128 + signal.SIGTERM, (process.folder / "up.log").read_text()[-800:]
    report = json.loads((process.folder / "up.json").read_text())
    for axis in report["axes"]:
        assert axis["inverter_off"] and axis["safe_state_sent"] >= 1, axis
    assert report["recording"]["error"] is None
    recorded_whole(process.folder / "arm_bag", report)


def recorded_whole(bag, report):
    """`drive up --record`'s bag is closed, its readers quiet first, and holds every sample each axis's bridge took
    (from the first it took, after those that came before the inverter's HELLO, but for at most its first two blocks;
    without a gap, at least as many as its report counted but those: the bridge takes more until its link closes),
    and each armed axis's estimate lies on its truth (the drive's topics stamped in the inverter's count, as the
    bridge's: an axis armed at sample k0 counts from 0 inside, and a shift of k0 samples would put the estimate
    radians off its truth)."""
    import numpy as np

    from drive_common.contract.log import COLUMN
    from drive_common.contract.stamps import sample_at
    from drive_tools.bags.reader import bag_topics, log_from_topics
    assert (bag / "metadata.yaml").exists(), "the bag is closed"
    assert report["recording"]["not_heard_from_the_start"] == []
    assert report["recording"]["drained"], "the recorder's readers fell quiet before the bag closed (links closed)"
    for axis in report["axes"]:
        namespace = axis["namespace"]
        _, topics, configs = bag_topics(str(bag), namespace)
        blocks = [(sample_at(msg.header.stamp.sec, msg.header.stamp.nanosec, 1e-4), len(msg.a))
                  for _, msg in topics["currents_block"]]
        assert all(k + n == k_next for (k, n), (k_next, _) in zip(blocks, blocks[1:])), f"{namespace}: a gap"
        # Known defect (docs/robot.md, "Recording"): now and then an axis's first one or two blocks are not in the bag.
        # The recorder takes every block published (tapped in the process); the blocks missing were never published
        # (seen on compiled answers' starts). Bounded here, not yet mended.
        assert 0 <= blocks[0][0] - axis["before_hello"] <= 20, (axis, blocks[0])
        assert sum(n for _, n in blocks) >= axis["samples"] - (blocks[0][0] - axis["before_hello"]), (axis, blocks[-1])
        n_p = next(config["n_p"] for config in configs if "n_p" in config)
        log = log_from_topics(str(bag), namespace, topics, configs)[0]
        theta_e = log[:, COLUMN["theta_m"]] * n_p
        estimate = log[:, COLUMN["theta_e_hat"]]
        armed = np.flatnonzero(np.isfinite(estimate))
        assert armed.size > 5000, f"{namespace}: the armed drive's estimates are in the bag"
        last = armed[-5000:]
        error = np.angle(np.exp(1j * (estimate[last] - theta_e[last])))
        assert np.sqrt(np.mean(error ** 2)) < 0.1, (namespace, np.sqrt(np.mean(error ** 2)))


@pytest.mark.parametrize("answer", ["compiled", "nodes"])
def test_a_lost_link_brings_every_axis_to_its_safe_state_and_exits_3(tmp_path, answer):
    """The shoulder's simulation ends after 1.5 s: its link goes silent, and `drive up` stops every axis; either answer
    (the other tests arm the default, compiled)."""
    drive_files(tmp_path, duration_s=1.5, load=False)
    text = ARM.replace("format_version: 1", "format_version: 1\ninitial_state: active")
    path = robot_file(tmp_path, text.replace("paced: false", f"paced: false, answer: {answer}"))
    run = subprocess.run([str(DRIVE), "up", str(path), "--json", "--record", "robot_bag"], cwd=tmp_path,
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 3, run.stderr[-800:]
    assert "link is lost (no telemetry for" in run.stderr.splitlines()[-1]
    report = json.loads(run.stdout)
    for axis in report["axes"]:
        assert axis["safe_state_sent"] >= 1, axis
    recorded_whole(tmp_path / "robot_bag", report)


def test_a_paced_axis_with_its_inverter_apart_runs_to_the_end_of_its_simulation(tmp_path):
    """`inverter_apart: true`: the paced virtual inverter runs in a process of its own (as `drive bench robot
    --inverter-apart` measures it), judges the compiled answer's commands by the host's writes across processes, and
    reports its timing; its simulation's end is a lost link (exit 3). Lateness is the bench's, not judged here."""
    drive_files(tmp_path, duration_s=1.5, load=False)
    path = robot_file(tmp_path, "format_version: 1\ninitial_state: active\naxes:\n  - {joint: shoulder, drive: "
                                "arm_drive.yaml, link: virtual, scenario: arm_sim.yaml, inverter_apart: true}\n")
    run = subprocess.run([str(DRIVE), "up", str(path), "--json"], cwd=tmp_path, capture_output=True, text=True,
                         timeout=300)
    assert run.returncode == 3 and "link is lost" in run.stderr.splitlines()[-1], run.stderr[-800:]
    timing = json.loads(run.stdout)["axes"][0]["inverter_timing"]
    assert timing["periods_since_start"] > 5000, timing


def test_an_axis_whose_drive_refuses_its_configuration_ends_the_start_in_one_line(tmp_path):
    """Blocks of 20 samples delay the answer past what ours' targets allow on this motor: the estimator refuses its
    configuration, `drive up` exits 3 naming the axis and the reason (no traceback), the other axis told to stop."""
    drive_files(tmp_path, duration_s=4.0, load=False)
    drive = tmp_path / "arm_drive.yaml"
    drive.write_text(drive.read_text().replace("block_samples: 10", "block_samples: 20"))
    path = robot_file(tmp_path, ARM.replace("format_version: 1", "format_version: 1\ninitial_state: active"))
    run = subprocess.run([str(DRIVE), "up", str(path), "--json"], cwd=tmp_path, capture_output=True, text=True,
                         timeout=120)
    assert run.returncode == 3 and "Traceback" not in run.stderr, run.stderr[-800:]
    reason = run.stderr.splitlines()[-1]
    assert "axis shoulder: configure failed: the estimator refused its configuration" in reason, reason
    assert json.loads(run.stdout)["axes"][0]["error"]


def test_drive_up_with_view_serves_the_robots_axes_live_while_it_runs(tmp_path):
    """`drive up ROBOT.yaml --view`: a `drive view` process serves the robot's axes while the robot runs; its page
    answers at the address said on stderr, and the view goes with the robot (here at the lost link's exit 3)."""
    import re
    import time
    import urllib.request
    drive_files(tmp_path, duration_s=4.0, load=False)
    path = robot_file(tmp_path, ARM.replace("format_version: 1", "format_version: 1\ninitial_state: active"))
    err = (tmp_path / "up.log").open("w+")
    process = subprocess.Popen([str(DRIVE), "up", str(path), "--view", "--view-port", "0", "--json"], cwd=tmp_path,
                               stdout=subprocess.DEVNULL, stderr=err)
    try:
        page, deadline = None, time.monotonic() + 60.0
        while page is None and process.poll() is None and time.monotonic() < deadline:
            said = re.search(r"drive: view at (http://\S+)", (tmp_path / "up.log").read_text())
            if said:
                with urllib.request.urlopen(said.group(1), timeout=10) as answer:
                    page = answer.read().decode()
            time.sleep(0.2)
        assert page is not None and "<script>" in page, (tmp_path / "up.log").read_text()[-800:]
        assert process.wait(timeout=120) == 3
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
        err.close()


HOMED_ARM = f"""format_version: 1
initial_state: active
axes:
  - {{joint: shoulder, drive: arm_drive.yaml, link: virtual, scenario: arm_sim.yaml, paced: false, hold_timeout_s: .inf,
     link_timeout_s: {LOCKSTEP_LINK_TIMEOUT_S}, command_timeout_s: 0.5,
     homing: {{method: hard_stop, direction: 1, current_A: 1.5, offset_rad: -1.0, backoff_rad: 0.3}}}}
  - {{joint: wrist, drive: arm_drive.yaml, link: virtual, scenario: arm_sim.yaml, paced: false,
     link_timeout_s: {LOCKSTEP_LINK_TIMEOUT_S}}}
"""
STOP_RAD = 2.3
"""The shoulder's end stop in the simulation (its truth; the drive is not told): 1 rad above its start."""


@contextlib.contextmanager
def homed_robot(folder, text, wait_s):
    """`drive up` of robot file ``text`` in ``folder`` and this process's client, yielded (client, deadline) once the
    shoulder's controller says it is homed (within ``wait_s``; the deadline is that bound); the robot stopped after."""
    path = robot_file(folder, text)
    err = (folder / "up.log").open("w")
    process = subprocess.Popen([str(DRIVE), "up", str(path)], cwd=folder, stdout=subprocess.DEVNULL, stderr=err)
    client = Client()
    try:
        deadline = time.monotonic() + wait_s
        while client.diagnostics.get("/shoulder/foc_controller", {}).get("homing") != "homed":
            assert time.monotonic() < deadline and process.poll() is None, (folder / "up.log").read_text()[-800:]
            client.spin(0.2)
        yield client, deadline
    finally:
        client.close()
        process.send_signal(signal.SIGTERM)
        process.wait(timeout=60)
        err.close()


def command_positions(client, positions, simulated_s, deadline):
    """Publish ``positions`` ({joint: rad}) as joint commands every 40 ms until the shoulder's simulation ran
    ``simulated_s`` more (before ``deadline``)."""
    from sensor_msgs.msg import JointState
    start = client.truth[-1][0]
    while client.truth[-1][0] < start + simulated_s:
        assert time.monotonic() < deadline
        for joint, position in positions.items():
            client.command_pub.publish(JointState(name=[joint], position=[position]))
        client.spin(0.04)


def test_a_joint_homes_against_its_stop_then_follows_position_commands(tmp_path):
    """The shoulder homes after its start-up (the stop found by current, backed off 0.3 rad: the joint at 0.7 rad
    with its zero 1 rad below the stop) and is published on /joint_states only once homed; a position command moves
    it there (the simulation's truth); position commands to the wrist, which has no homing, are refused and counted."""
    drive_files(tmp_path, load=False)
    sim = (tmp_path / "arm_sim.yaml").read_text()
    (tmp_path / "arm_sim.yaml").write_text(sim + f"end_stop: {{high_rad: {STOP_RAD}}}\n")
    with homed_robot(tmp_path, HOMED_ARM, 120.0) as (client, deadline):
        client.spin_simulated(0.5)
        assert client.truth[-1][1] == pytest.approx(STOP_RAD - 0.3, abs=0.06)
        assert client.joint("shoulder")[0] == pytest.approx(0.7, abs=0.06)
        assert all(math.isfinite(m.position[m.name.index("shoulder")]) for m in client.states if "shoulder" in m.name)
        target = 0.2
        command_positions(client, {"shoulder": target, "wrist": 0.0}, 1.5, deadline + 60.0)
        assert client.truth[-1][1] == pytest.approx(STOP_RAD - 1.0 + target, abs=0.06)
        assert client.joint("shoulder")[0] == pytest.approx(target, abs=0.06)
        assert client.robot_faults().get("faults.command_not_homed", 0) > 0


INDEXED_ARM = f"""format_version: 1
initial_state: active
axes:
  - {{joint: shoulder, drive: arm_drive.yaml, link: virtual, scenario: arm_sim.yaml, paced: false, hold_timeout_s: .inf,
     link_timeout_s: {LOCKSTEP_LINK_TIMEOUT_S}, command_timeout_s: 0.5,
     homing: {{method: index, direction: 1, offset_rad: 0.4}}}}
  - {{joint: wrist, drive: arm_drive.yaml, link: virtual, scenario: arm_sim.yaml, paced: false,
     link_timeout_s: {LOCKSTEP_LINK_TIMEOUT_S}}}
"""
INDEX_RAD = 2.0 * math.pi
"""Where the virtual inverter's index input pulses on the shoulder's way up from 1.3 rad: its true mechanical angle
passing a whole turn (the drive is not told)."""


def test_a_joint_homes_at_its_index_pulse_then_follows_position_commands(tmp_path):
    """The shoulder searches upward after its start-up until the inverter's index input pulses (status INDEX_TOGGLE),
    holds there with its zero 0.4 rad above it, and a position command moves it to its zero (the simulation's truth):
    the homed frame is the index's, whatever mechanical angle the start-up took for the rotor's."""
    drive_files(tmp_path, load=False)
    with homed_robot(tmp_path, INDEXED_ARM, 180.0) as (client, deadline):
        client.spin_simulated(0.5)
        assert client.truth[-1][1] == pytest.approx(INDEX_RAD, abs=0.06)
        assert client.joint("shoulder")[0] == pytest.approx(-0.4, abs=0.06)
        command_positions(client, {"shoulder": 0.0}, 1.5, deadline + 60.0)
        assert client.truth[-1][1] == pytest.approx(INDEX_RAD + 0.4, abs=0.06)
