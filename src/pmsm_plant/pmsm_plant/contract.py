"""The ROS side of shared/drive-interface.md, shared by the three nodes: topic names, QoS, stamps of
sample k, the ROS parameters every node reads, drive_config, /diagnostics and fault counting.

Only the nodes import this module (it imports rclpy); the cores never do.
"""
import json
import math
import time

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import String

PER_SAMPLE_QOS = QoSProfile(reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST,
                            depth=1000, durability=DurabilityPolicy.VOLATILE)
"""Lock-step topics: reliable, in order, and deep enough that a slow observer (recorder, echo)
loses nothing within a second of lag at 1 kHz and far more than the one message in flight."""
COMMAND_QOS = QoSProfile(reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST,
                         depth=100, durability=DurabilityPolicy.VOLATILE)
"""speed_command / load_torque / angle_error / joint_states: reliable; volatile so `ros2 topic pub`
and Foxglove publishers match."""
LATCHED_QOS = QoSProfile(reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST,
                         depth=10, durability=DurabilityPolicy.TRANSIENT_LOCAL)
"""drive_config: published once per node start, delivered to late joiners (10 deep, so a subscriber
keeps the configs of all the drive's nodes)."""
DIAGNOSTICS_QOS = QoSProfile(reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST,
                             depth=10, durability=DurabilityPolicy.VOLATILE)
PER_SAMPLE_TOPICS = ("currents", "rotor_state", "rotor_estimate", "injection", "voltage_command",
                     "estimator_state", "/clock")


def topic_qos(topic):
    """The QoS every publisher and subscriber of a contract topic uses."""
    if topic in PER_SAMPLE_TOPICS:
        return PER_SAMPLE_QOS
    return {"drive_config": LATCHED_QOS, "/diagnostics": DIAGNOSTICS_QOS}.get(topic, COMMAND_QOS)

GLOBAL_PARAMETERS = {
    "scenario": ("wang_100rpm", "shipped scenario name or YAML path: the file `drive run` reads"),
    "estimator": ("", "estimator type (empty: the scenario's)"),
    "seed": (-1, "sensor-noise seed (−1: the scenario's)"),
    "injection.frequency_Hz": (0.0, "HF injection frequency [Hz] (0: the scenario's)"),
    "injection.amplitude_V": (0.0, "HF injection amplitude [V] (0: the scenario's)"),
    "controller.current_limit_A": (0.0, "current limit [A] (0: the scenario's or commissioned)"),
    "controller.speed_limit_rad_s": (math.inf, "mechanical speed reference limit [rad/s], positive"),
    "duration_s": (0.0, "run length [s] (0: the scenario's)"),
    "lockstep_timeout_s": (1.0, "wall time to wait for an answer before declaring a fault [s]"),
    "diagnostics_period_s": (1.0, "period of /diagnostics [s]"),
    "trip_current_A": (0.0, "|phase current| above this is absurd input (0: 3 × preset limit) [A]"),
}
"""ROS parameters every node declares: the scenario file (shared with the one-process runner) and
the overrides applied on top of it; settable with --ros-args -p NAME:=VALUE or a params file."""


RESYNC_SAMPLES = 1000
"""How far ahead a sample may be for a node to follow the plant past samples it lost; a stamp beyond
this is treated as a wrong stamp (a stray publisher), not as progress."""


def stamp_ns(k, T_s):
    """Integer nanoseconds of sampling instant k (the contract's header.stamp of sample k)."""
    return round(k * T_s * 1e9)


def stamp(k, T_s):
    """builtin_interfaces/Time of sampling instant k."""
    sec, nanosec = divmod(stamp_ns(k, T_s), 1_000_000_000)
    return Time(sec=sec, nanosec=nanosec)


def sample_of(header, T_s):
    """The sample index a stamp belongs to, or None when it is not exactly a sampling instant."""
    ns = header.stamp.sec * 1_000_000_000 + header.stamp.nanosec
    k = round(ns / (T_s * 1e9))
    return k if k >= 0 and stamp_ns(k, T_s) == ns else None


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

    def __init__(self, node_name, **kwargs):
        super().__init__(node_name, **kwargs)
        name = "diagnostics_period_s"
        default, text = GLOBAL_PARAMETERS[name]
        self.declare_parameter(name, default, descriptor=_descriptor(text))
        self.health = Health()
        self.callback_time_s = 0.0
        self.callback_max_s = 0.0
        self.callbacks = 0
        self.config_pub = self.create_publisher(String, "drive_config", LATCHED_QOS)
        self.diagnostics_pub = self.create_publisher(DiagnosticArray, "/diagnostics", DIAGNOSTICS_QOS)
        self.create_timer(float(self.get_parameter(name).value), self.publish_diagnostics)

    def publish_config(self, config):
        """drive_config: this node, its parameters (``self.parameters``), a latched error, and ``config``."""
        config = {"node": self.get_fully_qualified_name(), "parameters": self.parameters,
                  "error": self.health.latched, **config}
        self.config_pub.publish(String(data=json.dumps(_plain(config))))

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


class DriveNode(ContractNode):
    """Base of the simulated drive's nodes: declares GLOBAL_PARAMETERS, builds the cores with ``builder``
    (parameters dict → drive_bridge.runner.Drive, raising ValueError naming the key at fault) and
    publishes drive_config once.

    A build error leaves ``self.drive`` None: the node stays up, answers with the safe output and
    reports the error (``self.health.latched``). Otherwise ``warm_up`` compiles the node's kernels on
    copies of its state before any per-sample endpoint exists, so no first sample waits for the compiler."""

    def __init__(self, node_name, builder, **kwargs):
        super().__init__(node_name, **kwargs)
        for name, (default, text) in GLOBAL_PARAMETERS.items():
            if not self.has_parameter(name):
                self.declare_parameter(name, default, descriptor=_descriptor(text))
        self.parameters = {name: self.get_parameter(name).value for name in GLOBAL_PARAMETERS}
        try:
            self.drive = builder(self.parameters)
        except ValueError as error:
            self.drive = None
            self.health.latched = str(error)
            self.health.fault("configuration", str(error))
            self.get_logger().error(f"configuration rejected, output held safe: {error}")
        else:
            self.warm_up()
        self.T_s = self.drive.scenario.T_s if self.drive else 1e-4
        self.timeout_s = float(self.parameters["lockstep_timeout_s"])

    def warm_up(self):
        """Call the node's kernels once on copies of its state, with the argument types of a sample."""

    def open_when_matched(self, subscriptions, open_outputs):
        """Call ``open_outputs`` (creating the node's per-sample answer publishers) once every input
        subscription is matched to a publisher. An answer sent before its reader matched is lost, and a
        graph entry is not yet a match: gated so, the answer publishers' appearance tells the plant, at
        the end of the chain, that every node before it can hear its inputs."""
        def check():
            if all(s.get_publisher_count() >= 1 for s in subscriptions):
                timer.cancel()
                open_outputs()
        timer = self.create_timer(0.02, check)

    def publish_config(self, config):
        if self.drive:
            config = {"motor": self.drive.scenario.motor, "n_p": self.drive.machine.n_p, "T_s_s": self.T_s,
                      **config}
        super().publish_config(config)

    def trip_current_A(self):
        given = float(self.parameters["trip_current_A"])
        return given if given > 0.0 else 3.0 * self.drive.preset.current_limit_A
def _descriptor(text):
    from rcl_interfaces.msg import ParameterDescriptor
    return ParameterDescriptor(description=text)


def _text(value):
    return f"{value:.6g}" if isinstance(value, float) else str(value)


def _plain(value):
    """JSON-ready data: parameter tuples become dicts, arrays lists, anything else unknown text."""
    if hasattr(value, "_asdict"):
        return {k: _plain(v) for k, v in value._asdict().items()}
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if hasattr(value, "tolist"):
        return value.tolist()
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    return str(value)


def parameter_overrides(values):
    """rclpy Parameters from a {name: value} dict (for composed nodes, as --ros-args -p would)."""
    return [Parameter(name, value=value) for name, value in values.items()]
