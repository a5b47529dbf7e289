"""`drive up ROBOT.yaml`: a robot's axes run open-ended in one process, each a managed node composing its drive's
nodes (drive_tools.launch.axis) in the real-time configuration `drive launch` measures (one process, the answer on
each bridge's link thread, SCHED_FIFO and affinity: launcher.real_time_held), commanded as ROS robots are: the
robot node ``/drive_robot`` publishes every joint's state on ``/joint_states`` and takes the joint command topic
(sensor_msgs/JointState, the convention of ros-controls' topic_based_ros2_control), until SIGINT/SIGTERM or a
link lost, which bring every axis to its safe state (docs/robot.md)."""
import math
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

from drive_common.contract.exit_codes import EXIT_NODE_FAULTS, EXIT_OK, EXIT_SIGNAL_BASE
from drive_common.runtime.interrupt import polled, requested

from .launcher import NamespaceLock, RealTime, check_namespace, real_time_held, refuse_occupied

COMMAND_QOS_DEPTH = 10
JOINT_STATES_QOS_DEPTH = 10
SAFE_STATE_WAIT_S = 1.0
SAFE_STATE_RETELL_S = 0.05
"""At the end, each inverter is told to switch off every SAFE_STATE_RETELL_S until its telemetry says it is off, for
at most SAFE_STATE_WAIT_S."""
TRANSITION_IDS = {"configure": 1, "cleanup": 2, "activate": 3, "deactivate": 4, "shutdown": 5}
"""lifecycle_msgs/Transition ids of the transitions `drive axis` asks for (shutdown: from unconfigured)."""


@dataclass
class RobotResult:
    """How `drive up` ended: ``exit_code``, ``reason`` (one line, empty when stopped by the operator), per axis its
    report (axis.AxisNode.report), the robot node's fault counters, the real-time ``scheduling`` and the recording."""

    exit_code: int = EXIT_OK
    reason: str = ""
    axes: list = field(default_factory=list)
    faults: dict = field(default_factory=dict)
    scheduling: dict = None
    recording: dict = None
    """With ``record``: robot_recording.RobotRecording.close's report (path, messages, error)."""
    running: dict = None
    """The wall and CPU time of the process [s] from the axes' initial state to the run's end."""


def robot_node_class():
    """The robot node's class (rclpy imported only when a robot runs)."""
    from sensor_msgs.msg import JointState

    from drive_common.ros.node import DriveNode

    class RobotNode(DriveNode):
        """``/drive_robot``: the robot's joints on ``/joint_states`` and its joint command topic, dispatched to
        the active axes' controllers. A command message is taken whole or not at all: an unknown joint, a
        NaN, a value over an axis's limits, a position for a joint not homed, or arrays that do not match the names
        refuse it (counted on /diagnostics, never applied); a joint whose axis is not active is left out (counted,
        not a fault). A joint with homing is published only once homed (its position is unknown before)."""

        reads_configuration = False

        def __init__(self, robot, axes, **kwargs):
            from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
            super().__init__("drive_robot", **kwargs)
            self.robot, self.axes = robot, {axis.spec.joint: axis for axis in axes}
            self.not_active = 0
            self.commands_taken = 0
            self.state_pub = self.create_publisher(JointState, robot.joint_states_topic, QoSProfile(
                reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST, depth=JOINT_STATES_QOS_DEPTH))
            self.create_subscription(JointState, robot.command_topic, self.on_command, QoSProfile(
                reliability=ReliabilityPolicy.BEST_EFFORT, history=HistoryPolicy.KEEP_LAST, depth=COMMAND_QOS_DEPTH))
            self.create_timer(1.0 / robot.joint_states_rate_Hz, self.publish_joint_states)

        def publish_joint_states(self):
            """Each active axis's joint: position, velocity and effort at the shaft [rad, rad/s, N·m], the joint's
            sign (REP-103), stamped now."""
            msg = JointState()
            msg.header.stamp = self.get_clock().now().to_msg()
            for joint, axis in self.axes.items():
                c = axis.controller if axis.active else None
                latest = c.joint_msg if c is not None else None
                if latest is None or not latest.position or math.isnan(latest.position[0]):
                    continue
                sign = axis.spec.sign
                msg.name.append(joint)
                msg.position.append(sign * latest.position[0])
                msg.velocity.append(sign * latest.velocity[0])
                msg.effort.append(sign * latest.effort[0])
            self.state_pub.publish(msg)

        def on_command(self, msg):
            refused = self.refusal(msg)
            if refused:
                self.fault(refused[0], f"{self.robot.command_topic}: {refused[1]}; the message refused, not applied")
                return
            for i, joint in enumerate(msg.name):
                axis = self.axes[joint]
                velocity, effort, position = _values(msg, i, axis.spec.sign)
                if not axis.active:
                    self.not_active += 1
                else:
                    axis.controller.take_command(velocity, effort, f"{self.robot.command_topic} {joint}", position)
            self.commands_taken += 1

        def refusal(self, msg):
            """(fault kind, reason) of a command message that may not be applied, else None."""
            n = len(msg.name)
            arrays = (msg.position, msg.velocity, msg.effort)
            if any(len(a) not in (0, n) for a in arrays) or not any(arrays):
                return "command_malformed", (f"{n} names with {len(msg.position)} positions, {len(msg.velocity)} "
                                             f"velocities and {len(msg.effort)} efforts (each none or one per name, "
                                             f"at least one of them)")
            if len(set(msg.name)) != n:
                return "command_malformed", "a joint named twice"
            for i, joint in enumerate(msg.name):
                axis = self.axes.get(joint)
                if axis is None:
                    return "command_unknown_joint", f"unknown joint {joint!r} (known: {', '.join(self.axes)})"
                velocity, effort, position = _values(msg, i, axis.spec.sign)
                if any(v is not None and not math.isfinite(v) for v in (velocity, effort, position)):
                    return "command_not_finite", (f"joint {joint}: position {position}, velocity {velocity}, "
                                                  f"effort {effort}")
                c = axis.controller
                refused = c.refusal(velocity, effort) if c is not None else None
                if refused is None and axis.active:
                    refused = c.position_refusal(position)
                if refused:
                    return refused[0], f"joint {joint}: {refused[1]}"
            return None

        def status_values(self):
            return {"commands_taken": self.commands_taken, "commands_to_inactive_joints": self.not_active,
                    **{f"axis.{joint}": _lifecycle_label(axis) for joint, axis in self.axes.items()}}

    return RobotNode


def _values(msg, i, sign):
    """(velocity, effort, position) of name i of a command message in the motor's sign (None where not given)."""
    velocity = sign * msg.velocity[i] if msg.velocity else None
    effort = sign * msg.effort[i] if msg.effort else None
    position = sign * msg.position[i] if msg.position else None
    return velocity, effort, position


def _lifecycle_label(axis):
    return axis._state_machine.current_state[1]


def bring_up(robot, executor_name="events", started=None, record=None):
    """Run ``robot`` (robot_file.RobotSpec) until SIGINT/SIGTERM or a lost link: every axis taken to the robot's
    initial state, then the operator's (lifecycle services) and the robot's commands followed. ``started(axes)``
    is called once the axes are in their initial state; ``record``: a new bag directory every topic is recorded into
    (robot_recording). Returns a RobotResult; every axis ends in its safe state (zero volts, the inverter told, the
    link closed), then the recording is closed."""
    import rclpy
    from rclpy.signals import SignalHandlerOptions

    from drive_common.ros.node import make_executor

    from .axis import AxisNode

    for axis in robot.axes:
        check_namespace(axis.namespace)
    real_time = RealTime(robot.rt_priority, robot.cpus, robot.workqueue_cpus, robot.cpu_dma_latency_us)
    context = rclpy.Context()
    rclpy.init(context=context, signal_handler_options=SignalHandlerOptions.NO)
    locks, axes, result = [], [], RobotResult()
    workdir = tempfile.TemporaryDirectory(prefix="drive_up_")
    polling = polled()
    polling.__enter__()
    executor = robot_node = recording = None
    try:
        for axis in robot.axes:
            locks.append(NamespaceLock(axis.namespace))
        refuse_occupied(context, [axis.namespace for axis in robot.axes])
        executor = make_executor(executor_name, context)
        if record is not None:
            from .robot_recording import RobotRecording
            recording = RobotRecording(robot, record, context, make_executor(executor_name, context))
        axes = [AxisNode(spec, i, context, executor, workdir.name, real_time, recording)
                for i, spec in enumerate(robot.axes)]
        robot_node = robot_node_class()(robot, axes, context=context)
        for node in (*axes, robot_node):
            executor.add_node(node)
        with real_time_held(real_time) as scheduling:
            result.scheduling = scheduling
            result.exit_code, result.reason = _initial_state(robot, axes)
            if not result.exit_code:
                result.exit_code, result.reason = _warmed(executor, axes)
            if not result.exit_code:
                if started:
                    started(axes)
                wall, cpu = time.monotonic(), time.process_time()
                result.exit_code, result.reason = _run(executor, axes)
                result.running = {"wall_s": time.monotonic() - wall, "cpu_s": time.process_time() - cpu}
            result.axes = _stop(axes, executor)
            if recording is not None:
                recording.acknowledge([robot_node, *(n for axis in axes for n in axis.drive_nodes())])
        result.faults = dict(robot_node.health.counters)
    finally:
        polling.__exit__(None, None, None)
        for axis in axes:
            axis.safe_state("stopped")
        if recording is not None:
            result.recording = recording.close()
        if executor is not None:
            executor.shutdown()
        for node in (*axes, robot_node):
            if node is not None:
                node.destroy_node()
        context.try_shutdown()
        workdir.cleanup()
        for lock in locks:
            lock.release()
    return result


def _warmed(executor, axes):
    """Spin until every axis composed with the compiled answer has loaded its loop (axis.AxisNode.warm_compiled: a
    first compile after an install or an update takes tens of seconds, said on stderr), so that arming is at once;
    (exit code, reason)."""
    said = False
    started = time.monotonic()
    while any(axis.warming is not None and axis.warming.is_alive() for axis in axes):
        if requested():
            return EXIT_SIGNAL_BASE + requested(), ""
        if not said and time.monotonic() - started > 2.0:
            said = True
            sys.stderr.write("drive up: loading the axes' compiled answer (compiled once after an install or an "
                             "update: up to a minute)\n")
            sys.stderr.flush()
        executor.spin_once(timeout_sec=0.05)
    return EXIT_OK, ""


def _initial_state(robot, axes):
    """Every axis configured (and activated) as the robot file's ``initial_state`` says; (exit code, reason)."""
    from rclpy.lifecycle import TransitionCallbackReturn
    steps = {"unconfigured": (), "inactive": ("configure",), "active": ("configure", "activate")}
    for step in steps[robot.initial_state]:
        for axis in axes:
            if requested():
                return EXIT_SIGNAL_BASE + requested(), ""
            if getattr(axis, f"trigger_{step}")() != TransitionCallbackReturn.SUCCESS:
                return EXIT_NODE_FAULTS, f"axis {axis.spec.joint}: {step} failed: {axis.error}"
    return EXIT_OK, ""


def _run(executor, axes):
    """Spin until a signal, a lost link, an armed axis whose compiled answer stopped or a callback's defect (every
    axis then brought to its safe state by the caller, the defect said in one line: where it was raised and what);
    (exit code, reason)."""
    while True:
        try:
            executor.spin_once(timeout_sec=0.05)
        except Exception as error:
            return EXIT_NODE_FAULTS, f"a defect in a callback stopped the robot ({where_raised(error)}); every axis " \
                                     "put in its safe state"
        if requested():
            return EXIT_SIGNAL_BASE + requested(), ""
        for axis in axes:
            if axis.link_lost():
                return EXIT_NODE_FAULTS, (f"axis {axis.spec.joint}: its inverter link is lost "
                                          f"({axis.bridge.bridge.lost_reason}); every axis put in its safe state")
            failure = axis.answer_failure()
            if failure:
                return EXIT_NODE_FAULTS, f"axis {axis.spec.joint}: {failure}; every axis put in its safe state"


def where_raised(error):
    """``error``'s type, text and the file:line it was raised at (its innermost frame), in one line."""
    import traceback
    frame = traceback.extract_tb(error.__traceback__)[-1] if error.__traceback__ else None
    at = f" at {Path(frame.filename).name}:{frame.lineno} {frame.name}" if frame else ""
    return f"{type(error).__name__}: {error}{at}"


def _stop(axes, executor):
    """Every axis disarmed (zero volts, its inverter told to switch off; an axis whose configuration failed has no link
    open), told again until its telemetry says its PWM is off (commands written before the telling, which act a block
    or two later, switch it on again) or SAFE_STATE_WAIT_S passed (a callback's defect raised meanwhile does not stop
    the telling: _run said the first); their reports."""
    timings = [axis.inverter_timing() for axis in axes]
    for axis in axes:
        axis.stop_answering()
    linked = [axis for axis in axes if axis.bridge is not None]
    deadline, told = time.monotonic() + SAFE_STATE_WAIT_S, 0.0
    while time.monotonic() < deadline:
        waiting = [axis for axis in linked if not axis.inverter_off() or not told]
        if not waiting:
            break
        if time.monotonic() - told >= SAFE_STATE_RETELL_S:
            told = time.monotonic()
            for axis in waiting:
                axis.bridge.bridge.safe_state("stopped")
        try:
            executor.spin_once(timeout_sec=0.01)
        except Exception:
            continue
    return [{**axis.report(), "state": _lifecycle_label(axis), **({"inverter_timing": timing} if timing else {})}
            for axis, timing in zip(axes, timings)]
