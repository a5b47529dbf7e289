"""`drive up ROBOT.yaml --record BAG` (docs/robot.md, "Recording"): every axis's contract topics, the robot's joint
topics and /diagnostics written into one recording (the contract's bag, drive_tools.bags.writer.BagWriter) as they
are published, by a node of the robot's process spun on a thread of its own below the drive's real-time threads
(launcher.Listening): the bag grows while the robot runs (a killed process leaves what reached the disk, which
`drive bag reindex` makes a bag again) and is closed when it stops, a signal or a lost link included."""
import time
from collections import deque
from pathlib import Path

from drive_common.contract.topics import CLOCK, DIAGNOSTICS, JOINT_STATES, TOPICS, full_name

RECORDED_TOPICS = tuple(topic for topic in TOPICS if topic not in (CLOCK, DIAGNOSTICS))
"""Each axis's contract topics a recording holds: all but the simulation clock (a robot has none) and /diagnostics
(one topic for the whole robot, recorded once)."""
HEARD_WAIT_S = 10.0
"""How long a node's publishers and the recorder's readers may take to match each other before the node publishes
(in one process: milliseconds on a quiet machine, longer on a loaded one); the bound keeps a start from hanging, and
a topic not heard within it is reported."""
DRAIN_QUIET_SPINS, DRAIN_LIMIT_S = 5, 5.0
"""At the end, the recorder takes what its readers hold until 5 spins of 20 ms write nothing (at most 5 s)."""
TAPPED_WRITE_PERIOD_S = 0.01
"""How often the recorder's thread writes what the taps queued (a 10-sample block every 1 ms per topic: ten a time)."""


class RobotRecording:
    """The recording of ``robot`` (robot_file.RobotSpec) into the bag directory ``path`` by a node in ``context``
    spun by its own ``executor``: ``heard(nodes)`` before they publish, ``close(nodes)`` at the end."""

    def __init__(self, robot, path, context, executor):
        from rclpy.node import Node
        from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

        from drive_common.ros.node import SAMPLE_PUBLISHER_HOOKS, message_class, topic_qos
        from drive_tools.bags.common import offered_qos
        from drive_tools.bags.writer import BagWriter

        from .launcher import Listening
        self.path = Path(path)
        self.writer = BagWriter(self.path)
        self.node = Node("drive_recorder", context=context)
        self.subscriptions = {}
        self.stamped = {}
        self.tapped = deque()
        """(topic, data) of the taps (SamplePublisher.tap), appended on the publishing threads, written on the
        recorder's: unbounded (nothing is dropped), its largest length reported (``queued_max``)."""
        self.queued_max = 0
        self.node.create_timer(TAPPED_WRITE_PERIOD_S, self._write_tapped)
        self.context = context
        SAMPLE_PUBLISHER_HOOKS[id(context)] = self._offered
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
        self.unheard = []
        """Topics whose publisher the recorder had not matched within HEARD_WAIT_S (their first messages may be
        missing)."""

    def _subscribe(self, name, cls, qos, recorded):
        """Record ``name`` (``recorded``: its type, offered QoS as the bag stores it, whether its first field is the
        sample instant: log times are sample instants, the robot's own topics at the latest one)."""
        msgtype, offered, stamped = recorded
        self.writer.add(name, msgtype, offered)
        self.stamped[name] = stamped
        write = self.writer.write
        self.subscriptions[name] = self.node.create_subscription(cls, name, lambda data: write(name, data, stamped),
                                                                 qos, raw=True)

    def _write_tapped(self):
        tapped, write, stamped = self.tapped, self.writer.write, self.stamped
        self.queued_max = max(self.queued_max, len(tapped))
        while tapped:
            name, data = tapped.popleft()
            write(name, data, stamped[name])

    def _offered(self, publisher):
        """Tap a sample publisher on a recorded topic as its node makes it (SAMPLE_PUBLISHER_HOOKS), before it can
        publish, and drop the recorder's DDS reader of the topic: the recording holds its first message, whatever
        DDS's matching does, and never twice."""
        name = publisher.publisher.topic_name
        if name in self.stamped:
            reader = self.subscriptions.pop(name, None)
            if reader is not None:
                self.node.destroy_subscription(reader)
            publisher.tap(self._tap)

    def heard(self, *nodes):
        """Before ``nodes`` publish: for their publishers on a recorded topic not tapped (_offered takes the
        per-sample and block topics in the process), wait (at most HEARD_WAIT_S in all) until the publisher and the
        recorder's reader have matched each other (both sides: a reader that has not matched its writer yet drops what
        the writer already sends it)."""
        deadline = time.monotonic() + HEARD_WAIT_S
        for node in nodes:
            for publisher in node.publishers:
                reader = self.subscriptions.get(publisher.topic_name)
                if reader is None:
                    continue
                while ((publisher.get_subscription_count() == 0 or reader.get_publisher_count() == 0)
                       and time.monotonic() < deadline):
                    time.sleep(0.001)
                if publisher.get_subscription_count() == 0 or reader.get_publisher_count() == 0:
                    self.unheard.append(publisher.topic_name)

    def _tap(self, topic, data):
        self.tapped.append((topic, data))

    def _drain(self):
        """Stop the recorder's thread, then take on this one every message its readers hold (acknowledged is
        received, not yet written): spun until nothing more is written for DRAIN_QUIET_SPINS spins (at most
        DRAIN_LIMIT_S). Whether the readers fell quiet (False: the limit came first, and messages may be left
        unwritten)."""
        listening = self.listening
        listening.stopped.set()
        if listening.thread.is_alive():
            listening.thread.join(5.0)
        quiet, deadline = 0, time.monotonic() + DRAIN_LIMIT_S
        while quiet < DRAIN_QUIET_SPINS and time.monotonic() < deadline:
            before = sum(self.writer.counts.values())
            listening.executor.spin_once(timeout_sec=0.02)
            self._write_tapped()
            quiet = quiet + 1 if sum(self.writer.counts.values()) == before else 0
        return quiet >= DRAIN_QUIET_SPINS

    def acknowledge(self, nodes):
        """Wait until what ``nodes`` published is acknowledged by the recorder's readers (at most the launcher's
        ACKNOWLEDGE_WAIT_S): before they stop publishing."""
        from drive_common.ros.node import acknowledged

        from .launcher import ACKNOWLEDGE_WAIT_S
        acknowledged(nodes, ACKNOWLEDGE_WAIT_S)

    def close(self):
        """End the recording once its sources stopped (the axes' links closed: while a link is open its bridge
        publishes the inverter's telemetry, and the readers would never fall quiet): its thread stopped, what its
        readers hold written, the bag closed. The recording's report: path, messages written, where a write failed
        the error (BagWriteError's one line), the topics not heard from their start, and whether its readers fell
        quiet before it closed (``drained``), and the most messages the taps' queue held at a write (``queued_max``)."""
        from drive_tools.bags.common import BagWriteError
        if self.closed is not None:
            return self.closed
        from drive_common.ros.node import SAMPLE_PUBLISHER_HOOKS
        SAMPLE_PUBLISHER_HOOKS.pop(id(self.context), None)
        drained = self._drain()
        self.listening.executor.shutdown()
        error = None
        try:
            self.writer.close()
        except BagWriteError as failure:
            error = str(failure)
        self.node.destroy_node()
        self.closed = {"path": str(self.path), "messages": sum(self.writer.counts.values()), "error": error,
                       "not_heard_from_the_start": sorted(set(self.unheard)), "drained": drained,
                       "queued_max": self.queued_max}
        return self.closed
