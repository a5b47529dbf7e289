"""The ROS side of the contract, shared by every node: QoS profiles from the topic table, stamps of
sample k, drive_config, /diagnostics with fault counting and callback timing, executors, and the
``main`` every node executable runs. The only module of this package that imports rclpy; cores never
import it."""
import argparse
import importlib
import math
import signal
import sys
import time

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.logging import LoggingSeverity
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from std_msgs.msg import String

from drive_common.config.parameter_sources import (
    ROS_ARGS,
    ParameterSourceError,
    command_line_sources,
    label,
    unknown_parameters,
)
from drive_common.contract.exit_codes import EXIT_NODE_FAULTS, EXIT_REFUSED
from drive_common.contract.graph import EXECUTORS
from drive_common.contract.settings import show_warnings_in_one_line
from drive_common.contract.stamps import stamp_parts
from drive_common.contract.strict_json import dumps
from drive_common.contract.topics import CLOCK, CONTRACT_VERSION, DIAGNOSTICS, DRIVE_CONFIG, TOPICS
from drive_common.contract.wire import WireError, decode_block, decoder_of
from drive_common.runtime.realtime import (
    QUIET_TIME,
    add_scheduling_arguments,
    collect_young,
    collector_held,
    real_time_scheduled,
)

FAULT_REPORT_MIN_S = 0.1
FAULT_LOG_PERIOD_S = 1.0
"""A node logs each kind of fault at most this often (all are counted, and shown on /diagnostics)."""
PEER_CHECK_PERIOD_S = 0.5
PEER_GONE_CHECKS = 3
"""Consecutive checks without the peer's publisher before a node gives up on it (graph changes are
seen through discovery, which can lag)."""


def log_line(node, severity, message):
    """Log ``message`` at ``severity`` (rclpy.logging.LoggingSeverity) under ``node``'s logger (the console,
    /rosout), its caller read from the calling frame. rclpy's own ``logger.error`` looks for its caller with
    ``inspect`` on every call, throttled or not: 0.6 ms in a small process, tens of ms in a drive's (module
    scans, the interpreter lock held: docs/ros-graph.md, "Real time"); this costs a few µs."""
    from rclpy.impl.implementation_singleton import rclpy_implementation
    logger = node.get_logger()
    if logger.is_enabled_for(severity):
        caller = sys._getframe(1)
        rclpy_implementation.rclpy_logging_rcutils_log(severity, logger.name, message, caller.f_code.co_name,
                                                       caller.f_code.co_filename, caller.f_lineno)


def qos_profile(spec):
    """The rclpy QoSProfile of a topics.QosSpec."""
    durability = DurabilityPolicy.TRANSIENT_LOCAL if spec.transient_local else DurabilityPolicy.VOLATILE
    return QoSProfile(reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST,
                      depth=spec.depth, durability=durability)


def topic_qos(topic):
    """The QoS every publisher and subscriber of a contract topic uses."""
    return qos_profile(TOPICS[topic].qos)


def message_class(topic):
    """The rclpy message class of a contract topic."""
    package, _, name = TOPICS[topic].type.split("/")
    return getattr(importlib.import_module(f"{package}.msg"), name)


def stamp(k, T_s):
    """builtin_interfaces/Time of sampling instant k."""
    sec, nanosec = stamp_parts(k, T_s)
    return Time(sec=sec, nanosec=nanosec)


def finite(*values):
    return all(math.isfinite(v) for v in values)


class Health:
    """Cumulative fault counters; the worst level and the first fault since the last /diagnostics
    message (the first is the cause, the ones that follow are often its consequences)."""

    def __init__(self):
        self.counters = {}
        self.message = ""
        self.faults_since = 0
        self.level = DiagnosticStatus.OK
        self.latched = None

    def fault(self, kind, message):
        self.counters[kind] = self.counters.get(kind, 0) + 1
        if not self.faults_since:
            self.message = message
        self.faults_since += 1
        self.level = DiagnosticStatus.ERROR

    def status_message(self):
        """The status message: the first fault since the last status, and how many followed it."""
        more = self.faults_since - 1
        return self.message + (f" (and {more} more fault{'s' * (more > 1)} since)" if more > 0 else "")

    def reset(self):
        """A status was published: the next one reports what happens from now on."""
        self.level = DiagnosticStatus.OK
        self.message = ""
        self.faults_since = 0


class SamplePublisher:
    """An rclpy publisher whose ``publish(data)`` hands serialized bytes straight to rcl: rclpy's
    ``Publisher.publish`` checks the argument's type and takes the handle's lock on every call, a third
    of a publish's cost at one message per sample. Nodes destroy their publishers only after their
    executor has stopped, so no publish can race the destruction the lock guards against."""

    __slots__ = ("publisher", "publish")

    def __init__(self, publisher):
        self.publisher = publisher
        self.publish = publisher.handle.publish_raw

    def get_subscription_count(self):
        return self.publisher.get_subscription_count()


class ContractNode(Node):
    """Base of every drive node: fault counting, callback timing, drive_config (latched) and
    /diagnostics every ``diagnostics_period_s``."""

    parameters = {}
    """The node's parameters as published in drive_config."""

    def __init__(self, node_name, **kwargs):
        super().__init__(node_name, **kwargs)
        self.parameter_sources = command_line_sources(ROS_ARGS, self.get_name(), self.get_namespace())
        name = "diagnostics_period_s"
        if not self.has_parameter(name):
            self.declare_parameter(name, 1.0, descriptor=describe("period of /diagnostics [s]"))
        self.health = Health()
        self.fault_logged_at = {}
        self.run_complete = False
        self.exit_code = None
        """Set when the node decides to end (its peer is gone); its executable then exits with it."""
        self.diagnostics_sent_at = 0.0
        self.callback_time_s = 0.0
        self.callback_max_s = 0.0
        self.callbacks = 0
        self.config_pub = self.create_publisher(String, DRIVE_CONFIG, topic_qos(DRIVE_CONFIG))
        self.diagnostics_pub = self.create_publisher(DiagnosticArray, DIAGNOSTICS, topic_qos(DIAGNOSTICS))
        self.collector_s = 0.0
        self.create_timer(float(self.get_parameter(name).value), self.periodic_status)

    def publish_config(self, config):
        """drive_config: the contract's version, this node, its parameters (``self.parameters``), a latched
        error, and ``config``."""
        config = {"contract_version": CONTRACT_VERSION, "node": self.get_fully_qualified_name(),
                  "parameters": self.parameters, "error": self.health.latched, **config}
        self.config_pub.publish(String(data=dumps(config)))

    def fault(self, kind, message):
        """Count a fault, log it (each kind at most every ``FAULT_LOG_PERIOD_S``) and show it on /diagnostics:
        at once when the last status said ok (at most every ``FAULT_REPORT_MIN_S``), else at the next
        period. Counters are cumulative."""
        first = self.health.level == DiagnosticStatus.OK
        self.health.fault(kind, message)
        now = time.monotonic()
        if now - self.fault_logged_at.get(kind, -math.inf) >= FAULT_LOG_PERIOD_S:
            self.fault_logged_at[kind] = now
            log_line(self, LoggingSeverity.ERROR, message)
        if first and now - self.diagnostics_sent_at >= FAULT_REPORT_MIN_S:
            self.publish_diagnostics()

    def complete_run(self):
        """The node has handled its run's last sample: say so on /diagnostics now (``run_complete``), so
        that a launcher collects every fault of the run before it stops."""
        if not self.run_complete:
            self.run_complete = True
            self.publish_diagnostics()

    def offer_clock(self):
        """Declare ``publish_clock`` (default true): this node may publish /clock (sim time)."""
        self.declare_parameter("publish_clock", True, descriptor=describe(
            "publish /clock (sim time) unless another node already does"))

    def claim_clock(self):
        """The /clock publisher, when this node is to publish sim time (``offer_clock``): its parameter
        ``publish_clock`` and no other publisher of /clock in the graph (one clock per graph); else None,
        and the node says which."""
        if not self.get_parameter("publish_clock").value:
            return None
        if self.count_publishers(CLOCK):
            self.get_logger().info("/clock is published by another node of the graph; this node does not")
            return None
        return self.create_publisher(Clock, CLOCK, topic_qos(CLOCK))

    def watch_foreign_publishers(self, topics):
        """Count a ``foreign_publisher`` fault each time one of the lock-step input ``topics`` gets more
        than one publisher (another drive in this namespace); its samples, not of this drive's sample,
        are discarded by stamp and counted there."""
        names = [self.resolve_topic_name(topic) for topic in topics]
        expected = dict.fromkeys(names, 1)

        def check():
            for name in names:
                count = self.count_publishers(name)
                if count > expected[name]:
                    self.fault("foreign_publisher", f"{count} publishers of {name}, 1 expected: another drive "
                                                    f"in this namespace; its samples are discarded")
                expected[name] = max(count, 1)
        self.create_timer(PEER_CHECK_PERIOD_S, check)

    def watch_peer(self, topic, peer):
        """End the node (``exit_code``) when ``topic``'s publishers (the ``peer``, e.g. the plant) are gone
        for good after having been there: the node's outputs stay in their safe state, and it says so."""
        name = self.resolve_topic_name(topic)
        seen, absent = [False], [0]

        def check():
            count = self.count_publishers(name)
            seen[0] = seen[0] or count > 0
            absent[0] = absent[0] + 1 if seen[0] and count == 0 else 0
            if absent[0] >= PEER_GONE_CHECKS and self.exit_code is None:
                self.exit_code = 0 if self.run_complete and not self.health.counters else EXIT_NODE_FAULTS
                log_line(self, LoggingSeverity.ERROR, f"{peer} is gone (no publisher of {name}): outputs stay "
                                                      f"safe, the node exits")
        self.create_timer(PEER_CHECK_PERIOD_S, check)

    def sample_subscription(self, topic, callback):
        """Subscribe ``callback(sec, nanosec, a, b, c)`` to a per-sample contract topic, taken serialized
        and decoded by drive_common.contract.wire (a, b, c: x, y, z of a Vector3Stamped; the first position,
        velocity and effort of a JointState, None where empty; of a topic of channels (a block twin,
        `zero_voltage`), its three channels as float64 arrays, drive_common.contract.wire.decode_block). Bytes
        that are not the topic's type are a ``bad_input`` fault and go no further."""
        decode = decode_block if TOPICS[topic].channels else decoder_of(TOPICS[topic].type)

        def take(data):
            try:
                values = decode(data)
            except WireError as error:
                self.fault("bad_input", f"{self.resolve_topic_name(topic)}: {error}; discarded")
                return
            callback(*values)
        return self.create_subscription(message_class(topic), topic, take, topic_qos(topic), raw=True)

    def sample_publisher(self, topic):
        """A publisher of a per-sample or block contract topic that takes serialized bytes
        (drive_common.contract.wire)."""
        return SamplePublisher(self.create_publisher(message_class(topic), topic, topic_qos(topic)))

    def timed(self, callback):
        """Wrap a per-sample callback to accumulate its wall time for /diagnostics."""
        def run(*msg):
            start = time.perf_counter()
            callback(*msg)
            spent = time.perf_counter() - start
            self.callback_time_s += spent
            self.callback_max_s = max(self.callback_max_s, spent)
            self.callbacks += 1
        return run

    def start_line(self):
        """The one line a node logs when it starts: role, namespace and what it runs."""
        return f"{self.get_name()} started in namespace {self.get_namespace()}"

    def data_time(self):
        """The time of the data the node handles now (the stamp of /diagnostics): its clock's now; nodes
        in lock-step on sim time give their sample's stamp."""
        return self.get_clock().now().to_msg()

    def status_values(self):
        """Node-specific key/values for /diagnostics (lock, observability, saturation...)."""
        return {}

    def periodic_status(self):
        """Every ``diagnostics_period_s``: the garbage made since the last period collected (while the
        collector is held out of the sample path, drive_common.runtime.realtime), then /diagnostics; each in the
        quiet part of a block where a bridge node runs the loop (QUIET_TIME)."""
        jobs = (self.collect_garbage, self.publish_diagnostics)
        QUIET_TIME.overdue(jobs)
        QUIET_TIME.later(*jobs)

    def collect_garbage(self):
        self.collector_s = max(self.collector_s, collect_young())

    def publish_diagnostics(self):
        h = self.health
        values = {"run_complete": self.run_complete, "callbacks": self.callbacks,
                  "callback_mean_us": 1e6 * self.callback_time_s / max(self.callbacks, 1),
                  "callback_max_us": 1e6 * self.callback_max_s, "collector_max_us": 1e6 * self.collector_s,
                  **{f"faults.{kind}": n for kind, n in sorted(h.counters.items())},
                  **self.status_values()}
        level = DiagnosticStatus.ERROR if h.latched else h.level
        message = h.latched or (h.status_message() if level != DiagnosticStatus.OK else "ok")
        status = DiagnosticStatus(level=level, name=self.get_fully_qualified_name(),
                                  message=message, hardware_id=self.get_namespace(),
                                  values=[KeyValue(key=k, value=_text(v)) for k, v in values.items()])
        array = DiagnosticArray(status=[status])
        array.header.stamp = self.data_time()
        self.diagnostics_pub.publish(array)
        self.diagnostics_sent_at = time.monotonic()
        h.reset()
        self.callback_max_s = self.collector_s = 0.0


def describe(text):
    """A ParameterDescriptor carrying ``text``."""
    return ParameterDescriptor(description=text)


def _text(value):
    return f"{value:.6g}" if isinstance(value, float) else str(value)


def parameter_overrides(values):
    """rclpy Parameters from a {name: value} dict (for composed nodes, as --ros-args -p would)."""
    return [Parameter(name, value=value) for name, value in values.items()]


def make_executor(name, context):
    """``events``: rclpy.experimental.EventsExecutor (≈ 10× less overhead per message here; its
    spin_until_future_complete without a timeout never returns in this rclpy, so callers pass one);
    ``single``: the default SingleThreadedExecutor, the fallback."""
    if name == "events":
        from rclpy.experimental import EventsExecutor
        return EventsExecutor(context=context)
    if name == "single":
        from rclpy.executors import SingleThreadedExecutor
        return SingleThreadedExecutor(context=context)
    raise ValueError(f"unknown executor '{name}' (known: {', '.join(EXECUTORS)})")


def run_node(make_node, program, argv=None):
    """A node executable's main: ``[--executor E] --ros-args ...``; spins ``make_node()`` until SIGINT or
    SIGTERM (exit code 0, as ROS nodes do) or until the node sets ``exit_code`` (its peer is gone)."""
    import rclpy
    from rclpy._rclpy_pybind11 import RCLError
    from rclpy.exceptions import ParameterException
    from rclpy.signals import SignalHandlerOptions
    from rclpy.task import Future

    show_warnings_in_one_line(program)
    argv = sys.argv[1:] if argv is None else argv
    ros_args = argv[argv.index("--ros-args"):] if "--ros-args" in argv else []
    parser = argparse.ArgumentParser(prog=program)
    parser.add_argument("--executor", choices=EXECUTORS, default="events")
    add_scheduling_arguments(parser)
    args = parser.parse_args(argv[:len(argv) - len(ros_args)])
    ROS_ARGS[:] = ros_args
    try:
        command_line_sources(ros_args)
        rclpy.init(args=[program] + ros_args, signal_handler_options=SignalHandlerOptions.NO)
    except (ParameterSourceError, RCLError) as error:
        return _refuse(program, str(error).split(", at ")[0])
    stop = Future()
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, lambda *_: stop.done() or stop.set_result(True))
    try:
        node = make_node()
    except ParameterException as error:
        rclpy.try_shutdown()
        return _refuse(program, _parameter_error(error, ros_args))
    unknown = unknown_parameters(node, node.parameter_sources)
    if unknown:
        node.destroy_node()
        rclpy.try_shutdown()
        return _refuse(program, "; ".join(unknown))
    node.get_logger().info(node.start_line())
    executor = make_executor(args.executor, rclpy.get_default_context())
    executor.add_node(node)
    try:
        with real_time_scheduled(args.rt_priority, args.cpus) as scheduling, collector_held():
            for line in scheduling["applied"]:
                node.get_logger().info(line)
            for line in scheduling["refused"]:
                node.get_logger().warning(line)
            while not stop.done() and node.exit_code is None:
                executor.spin_until_future_complete(stop, timeout_sec=0.25)
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
    return node.exit_code or 0


def _refuse(program, message):
    print(f"{program}: {' '.join(message.split())}", file=sys.stderr)
    return EXIT_REFUSED


def _parameter_error(error, ros_args):
    """A parameter value of the wrong type, named by its source (params file or command line)."""
    text = str(error)
    name = text.rsplit(": ", 1)[-1].strip()
    reason = text.rsplit(": ", 1)[0].replace(f"Trying to set parameter '{name}' to", "").strip()
    return f"{label(command_line_sources(ros_args), name)}: {reason}"
