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
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import String

from .graph import EXECUTORS
from .stamps import stamp_ns
from .strict_json import dumps
from .topics import TOPICS


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
    sec, nanosec = divmod(stamp_ns(k, T_s), 1_000_000_000)
    return Time(sec=sec, nanosec=nanosec)


def finite(*values):
    return all(math.isfinite(v) for v in values)


class Health:
    """Fault counters and the worst level since the last /diagnostics message."""

    def __init__(self):
        self.counters = {}
        self.last_fault = ""
        self.level = DiagnosticStatus.OK
        self.latched = None

    def fault(self, kind, message):
        self.counters[kind] = self.counters.get(kind, 0) + 1
        self.last_fault = message
        self.level = DiagnosticStatus.ERROR


class ContractNode(Node):
    """Base of every drive node: fault counting, callback timing, drive_config (latched) and
    /diagnostics every ``diagnostics_period_s``."""

    parameters = {}
    """The node's parameters as published in drive_config."""

    def __init__(self, node_name, **kwargs):
        super().__init__(node_name, **kwargs)
        name = "diagnostics_period_s"
        if not self.has_parameter(name):
            self.declare_parameter(name, 1.0, descriptor=describe("period of /diagnostics [s]"))
        self.health = Health()
        self.callback_time_s = 0.0
        self.callback_max_s = 0.0
        self.callbacks = 0
        self.config_pub = self.create_publisher(String, "drive_config", topic_qos("drive_config"))
        self.diagnostics_pub = self.create_publisher(DiagnosticArray, "/diagnostics", topic_qos("/diagnostics"))
        self.create_timer(float(self.get_parameter(name).value), self.publish_diagnostics)

    def publish_config(self, config):
        """drive_config: this node, its parameters (``self.parameters``), a latched error, and ``config``."""
        config = {"node": self.get_fully_qualified_name(), "parameters": self.parameters,
                  "error": self.health.latched, **config}
        self.config_pub.publish(String(data=dumps(config)))

    def fault(self, kind, message):
        """Count a fault, log it (throttled) and show it at the next /diagnostics."""
        self.health.fault(kind, message)
        self.get_logger().error(message, throttle_duration_sec=1.0)

    def timed(self, callback):
        """Wrap a per-sample callback to accumulate its wall time for /diagnostics."""
        def run(msg):
            start = time.perf_counter()
            callback(msg)
            spent = time.perf_counter() - start
            self.callback_time_s += spent
            self.callback_max_s = max(self.callback_max_s, spent)
            self.callbacks += 1
        return run

    def status_values(self):
        """Node-specific key/values for /diagnostics (lock, observability, saturation...)."""
        return {}

    def publish_diagnostics(self):
        h = self.health
        values = {"callbacks": self.callbacks,
                  "callback_mean_us": 1e6 * self.callback_time_s / max(self.callbacks, 1),
                  "callback_max_us": 1e6 * self.callback_max_s,
                  **{f"faults.{kind}": n for kind, n in sorted(h.counters.items())},
                  **self.status_values()}
        level = DiagnosticStatus.ERROR if h.latched else h.level
        message = h.latched or (h.last_fault if level != DiagnosticStatus.OK else "ok")
        status = DiagnosticStatus(level=level, name=self.get_fully_qualified_name(),
                                  message=message, hardware_id=self.get_namespace(),
                                  values=[KeyValue(key=k, value=_text(v)) for k, v in values.items()])
        array = DiagnosticArray(status=[status])
        array.header.stamp = self.get_clock().now().to_msg()
        self.diagnostics_pub.publish(array)
        h.level = DiagnosticStatus.OK
        h.last_fault = ""
        self.callback_max_s = 0.0


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
    SIGTERM. Returns the exit code."""
    import rclpy
    from rclpy.signals import SignalHandlerOptions
    from rclpy.task import Future

    argv = sys.argv[1:] if argv is None else argv
    ros_args = argv[argv.index("--ros-args"):] if "--ros-args" in argv else []
    parser = argparse.ArgumentParser(prog=program)
    parser.add_argument("--executor", choices=EXECUTORS, default="events")
    args = parser.parse_args(argv[:len(argv) - len(ros_args)])
    rclpy.init(args=[program] + ros_args, signal_handler_options=SignalHandlerOptions.NO)
    stop = Future()
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, lambda *_: stop.done() or stop.set_result(True))
    node = make_node()
    executor = make_executor(args.executor, rclpy.get_default_context())
    executor.add_node(node)
    try:
        while not stop.done():
            executor.spin_until_future_complete(stop, timeout_sec=0.25)
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0
