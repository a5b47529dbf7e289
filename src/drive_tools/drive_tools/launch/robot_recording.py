"""`drive up ROBOT.yaml --record BAG` (docs/robot.md, "Recording"): every axis's contract topics, the robot's joint
topics and /diagnostics written into one recording (the contract's bag, drive_tools.bags.writer.BagWriter) as they
are published, by a node of the robot's process spun on a thread of its own below the drive's real-time threads
(launcher.Listening): the bag grows while the robot runs (a killed process leaves what reached the disk, which
`drive bag reindex` makes a bag again) and is closed when it stops, a signal or a lost link included."""
import time
from pathlib import Path

from drive_common.contract.topics import CLOCK, DIAGNOSTICS, JOINT_STATES, TOPICS, full_name

RECORDED_TOPICS = tuple(topic for topic in TOPICS if topic not in (CLOCK, DIAGNOSTICS))
"""Each axis's contract topics a recording holds: all but the simulation clock (a robot has none) and /diagnostics
(one topic for the whole robot, recorded once)."""
HEARD_WAIT_S = 2.0
"""How long a node's publishers may take to be matched by the recorder before they publish (in one process: at
once; the bound keeps a start from hanging)."""


class RobotRecording:
    """The recording of ``robot`` (robot_file.RobotSpec) into the bag directory ``path`` by a node in ``context``
    spun by its own ``executor``: ``heard(nodes)`` before they publish, ``close(nodes)`` at the end."""

    def __init__(self, robot, path, context, executor):
        from rclpy.node import Node
        from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

        from drive_common.ros.node import message_class, topic_qos
        from drive_tools.bags.common import offered_qos
        from drive_tools.bags.writer import BagWriter

        from .launcher import Listening
        self.path = Path(path)
        self.writer = BagWriter(self.path)
        self.node = Node("drive_recorder", context=context)
        self.names = set()
        for axis in robot.axes:
            for topic in RECORDED_TOPICS:
                self._subscribe(full_name(axis.namespace, topic), message_class(topic), topic_qos(topic),
                                (TOPICS[topic].type, offered_qos(topic), TOPICS[topic].stamped))
        self._subscribe(DIAGNOSTICS, message_class(DIAGNOSTICS), topic_qos(DIAGNOSTICS),
                        (TOPICS[DIAGNOSTICS].type, offered_qos(DIAGNOSTICS), False))
        joint_state = message_class(JOINT_STATES)
        reliable = QoSProfile(reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST, depth=100)
        any_publisher = QoSProfile(reliability=ReliabilityPolicy.BEST_EFFORT, history=HistoryPolicy.KEEP_LAST,
                                   depth=100)
        self._subscribe(robot.joint_states_topic, joint_state, reliable,
                        (TOPICS[JOINT_STATES].type, offered_qos(JOINT_STATES), False))
        self._subscribe(robot.command_topic, joint_state, any_publisher,
                        (TOPICS[JOINT_STATES].type, offered_qos(JOINT_STATES), False))
        self.listening = Listening(executor, [self.node])
        self.listening.start()
        self.closed = None

    def _subscribe(self, name, cls, qos, recorded):
        """Record ``name`` (``recorded``: its type, offered QoS as the bag stores it, whether its first field is the
        sample instant: log times are sample instants, the robot's own topics at the latest one)."""
        msgtype, offered, stamped = recorded
        self.writer.add(name, msgtype, offered)
        write = self.writer.write
        self.node.create_subscription(cls, name, lambda data: write(name, data, stamped), qos, raw=True)
        self.names.add(name)

    def heard(self, *nodes):
        """Wait (at most HEARD_WAIT_S in all) until every publisher of ``nodes`` on a recorded topic is matched by
        the recorder: nothing they publish from then on is missed."""
        deadline = time.monotonic() + HEARD_WAIT_S
        for node in nodes:
            for publisher in node.publishers:
                while (publisher.topic_name in self.names and publisher.get_subscription_count() == 0
                       and time.monotonic() < deadline):
                    time.sleep(0.001)

    def close(self, nodes=()):
        """End the recording: what ``nodes`` published acknowledged by the recorder (at most the launcher's
        ACKNOWLEDGE_WAIT_S), its thread stopped, the bag closed. The recording's report: path, messages written
        and, where a write failed, the error (BagWriteError's one line)."""
        from drive_common.ros.node import acknowledged
        from drive_tools.bags.common import BagWriteError

        from .launcher import ACKNOWLEDGE_WAIT_S
        if self.closed is not None:
            return self.closed
        acknowledged(nodes, ACKNOWLEDGE_WAIT_S)
        self.listening.stop()
        error = None
        try:
            self.writer.close()
        except BagWriteError as failure:
            error = str(failure)
        self.node.destroy_node()
        self.closed = {"path": str(self.path), "messages": sum(self.writer.counts.values()), "error": error}
        return self.closed
