"""The ROS side of the contract, shared by every node: the base class of every drive node (``DriveNode``:
its drive configuration or scenario from the node's parameters, QoS profiles from the topic table, stamps
of sample k, drive_config, /diagnostics with fault counting and callback timing), executors, and the
``main`` every node executable runs. The library's only module that imports rclpy; cores never import
it."""
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
from drive_common.config.parameters import NODE_PARAMETERS, run_samples, scenario_from_parameters
from drive_common.config.scenario import Scenario
from drive_common.contract.exit_codes import EXIT_NODE_FAULTS, EXIT_REFUSED
from drive_common.contract.graph import EXECUTORS
from drive_common.contract.settings import show_warnings_in_one_line
from drive_common.contract.stamps import stamp_parts
from drive_common.contract.strict_json import dumps
from drive_common.contract.topics import BLOCK_TOPIC, CLOCK, CONTRACT_VERSION, DIAGNOSTICS, DRIVE_CONFIG, TOPICS
from drive_common.contract.wire import WireError, decode_block, decoder_of
from drive_common.motor.commissioning import resolve_commissioning
from drive_common.motor.nameplate import contract_inverter, contract_motor, trip_current_A
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
SAMPLE_PUBLISHER_HOOKS = {}
"""id(rclpy context) → hook(SamplePublisher), called as each node of that context makes a sample publisher, before it
can publish (an in-process recorder taps it: drive_tools.launch.robot_recording)."""
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

    def tap(self, take):
        """From now on also hand every message published to ``take(topic, data)`` on the publishing thread, after
        rcl has it: an in-process reader (a recorder's queue) that DDS's matching cannot make miss a message."""
        publish_raw, topic = self.publisher.handle.publish_raw, self.publisher.topic_name

        def publish(data):
            publish_raw(data)
            take(topic, data)
        self.publish = publish


class DriveNode(Node):
    """Base of every drive node, one class below rclpy's Node: fault counting, callback timing,
    drive_config (latched) and /diagnostics every ``diagnostics_period_s``.

    A node that ``reads_configuration`` declares NODE_PARAMETERS (and its ``node_parameters``), reads the
    configuration they name (``self.config``: a DriveConfig, or a Scenario, which is one, where the node
    reads an experiment: ``needs_experiment``) and calls ``build(config)``, the node's own core (a
    ValueError there names the key at fault). A configuration error leaves ``self.configured`` False: the
    node stays up, answers with the safe output and reports the error (``self.health.latched``).
    Otherwise ``warm_up`` compiles the node's kernels on copies of its state before any per-sample
    endpoint exists, so no first sample waits for the compiler."""

    parameters = {}
    """The node's parameters as published in drive_config."""
    reads_configuration = True
    """False for the bridge node: its parameters are its link's, its inverter tells it the sampling period."""
    node_parameters = {}
    """The node's own parameters beyond NODE_PARAMETERS: name → (default, description)."""
    stamp_origin = 0
    """Samples added to the stamps of the samples this node publishes: a drive armed on a running inverter counts
    its samples from 0 (drive_tools.launch.axis.HandOver), its topics stay in the inverter's count."""

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
        self.config = None
        self.configured = False
        self.block_samples = 1
        """N: samples per message on the per-sample topics (the configuration's block_samples)."""
        if self.reads_configuration:
            self.read_configuration()

    def read_configuration(self):
        """Declare the parameters, read the configuration they name, build the node's core and warm it up
        (or latch the error)."""
        for name, (default, text) in {**NODE_PARAMETERS, **self.node_parameters}.items():
            if not self.has_parameter(name):
                self.declare_parameter(name, default, descriptor=describe(text))
        self.parameters = {name: self.get_parameter(name).value for name in NODE_PARAMETERS}
        self.n_samples = 0
        try:
            config = scenario_from_parameters(self.parameters, self.label, self.needs_experiment())
            self.build(config)
        except ValueError as error:
            self.reject(error)
        else:
            self.config = config
            self.configured = True
            self.block_samples = config.block_samples
            self.n_samples = run_samples(config, self.parameters)
            self.warm_up()
        self.T_s = self.config.T_s if self.config else 1e-4
        self.timeout_s = float(self.parameters["lockstep_timeout_s"])

    @property
    def scenario(self):
        """The Scenario the node runs (its configuration with an experiment), else None."""
        return self.config if isinstance(self.config, Scenario) else None

    def needs_experiment(self):
        """With a ``drive_configuration``: whether the node also reads its scenario's experiment (the
        plant does; the estimator does not)."""
        return True

    def contract_topics(self, *topics):
        """The per-sample topics as this drive carries them: themselves, or their block twins."""
        return tuple(BLOCK_TOPIC[t] if self.block_samples > 1 else t for t in topics)

    def label(self, name):
        """How errors name parameter ``name`` (its params file, the command line, or the parameter)."""
        return label(self.parameter_sources, name)

    def sample_handled(self, k):
        """Sample k is done; after the run's last one, /diagnostics says the run is complete."""
        if self.config and k == self.n_samples - 1:
            self.complete_run()

    def reject(self, error):
        """Latch a configuration error: the output is held safe and /diagnostics says why."""
        self.health.latched = str(error)
        self.health.fault("configuration", str(error))
        self.get_logger().error(f"configuration rejected, output held safe: {error}")

    def build(self, config):
        """Build the node's core for ``config`` (a DriveConfig or Scenario)."""

    def warm_up(self):
        """Call the node's kernels once on copies of its state, with the argument types of a sample."""

    def open_when_matched(self, subscriptions, open_outputs, ready=lambda: True):
        """Call ``open_outputs`` (creating the node's per-sample answer publishers) once every input
        subscription is matched to a publisher and ``ready()``. An answer sent before its reader matched
        is lost, and a graph entry is not yet a match: gated so, the answer publishers' appearance tells
        the plant, at the end of the chain, that every node before it can hear its inputs."""
        def check():
            if ready() and all(s.get_publisher_count() >= 1 for s in subscriptions):
                timer.cancel()
                open_outputs()
        timer = self.create_timer(0.02, check)

    def nameplate(self):
        """The nameplate of the configuration's motor."""
        return self.config.motor.nameplate

    def load_commissioning(self, config):
        """What the drive knows beyond the nameplate (drive_common.motor.commissioning.resolve_commissioning):
        the file of the parameter ``commissioning`` or the configuration's key, the default file, or the
        nameplate alone; CommissioningError names the parameter or the file's key at fault."""
        label = (self.label("commissioning") if self.parameters["commissioning"]
                 else f"{config.source}: commissioning")
        return resolve_commissioning(config.motor.nameplate, config.commissioning, label)

    def trip_current_A(self):
        given = float(self.parameters["trip_current_A"])
        return given if given > 0.0 else trip_current_A(self.nameplate())

    def publish_config(self, config):
        """drive_config: the contract's version, this node, its parameters (``self.parameters``), a latched
        error, what the node runs (motor, sampling period, blocks, delay) and ``config``."""
        if self.config:
            config = {"motor": contract_motor(self.nameplate()),
                      "inverter": contract_inverter(self.config.motor.inverter),
                      "scenario": self.config.name, "n_p": self.nameplate().n_p, "T_s_s": self.T_s,
                      "block_samples": self.block_samples,
                      "command_delay_periods": self.config.drive_delay_periods(), **config}
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
        publisher = SamplePublisher(self.create_publisher(message_class(topic), topic, topic_qos(topic)))
        hook = SAMPLE_PUBLISHER_HOOKS.get(id(self.context))
        if hook is not None:
            hook(publisher)
        return publisher

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
        line = f"{self.get_name()} started in namespace {self.get_namespace()}"
        if not self.reads_configuration:
            return line
        if not self.config:
            return f"{line}: configuration rejected, output held safe"
        c = self.config
        run = "no experiment: until stopped" if self.n_samples == sys.maxsize else f"{self.n_samples} samples"
        what = f"scenario {c.name}" if self.scenario else f"drive configuration {c.drive_file}"
        return f"{line}: {what}, motor {c.motor}, estimator {c.estimator}, {1.0 / c.T_s:g} Hz, {run}"

    def data_time(self):
        """The time of the data the node handles now (the stamp of /diagnostics): the stamp of its sample
        (sim time) where it reads a configuration; else its clock's now."""
        if self.reads_configuration:
            return stamp(getattr(self, "k", 0), self.T_s)
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


def acknowledged(nodes, timeout_s):
    """Wait until every reader matched to the ``nodes``' publishers has acknowledged what they published (a
    reliable reader that fell behind gets the rest before the publishers go), at most ``timeout_s`` [s] in all;
    whether all were."""
    from rclpy.duration import Duration
    deadline = time.monotonic() + timeout_s
    done = True
    for node in nodes:
        for publisher in node.publishers:
            left = deadline - time.monotonic()
            done = left > 0.0 and publisher.wait_for_all_acked(Duration(nanoseconds=int(left * 1e9))) and done
    return done


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
    SIGTERM (exit code 0, as ROS nodes do) or until the node sets ``exit_code`` (its peer is gone). ``-p NAME:=``,
    what a shell leaves of ``-p NAME:=''``, sets the empty text (rcl refuses it as written)."""
    import rclpy
    from rclpy._rclpy_pybind11 import RCLError
    from rclpy.exceptions import ParameterException
    from rclpy.signals import SignalHandlerOptions
    from rclpy.task import Future

    show_warnings_in_one_line(program)
    argv = sys.argv[1:] if argv is None else argv
    ros_args = argv[argv.index("--ros-args"):] if "--ros-args" in argv else []
    ros_args = [f"{arg}''" if arg.endswith(":=") and i and ros_args[i - 1] == "-p" else arg
                for i, arg in enumerate(ros_args)]
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
