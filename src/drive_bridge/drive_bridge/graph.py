"""The drive as a ROS 2 graph: the three nodes over topics in lock-step, a scenario driver that
commands speed and load over `speed_command` / `load_torque` and records the per-sample topics into
the runner's log layout, and a launcher (no `ros2 launch` here) that composes the nodes in one process
or starts them as separate processes.

Node processes: ``python -m drive_bridge.graph {pmsm_plant,hf_estimator,foc_controller} --ros-args ...``.
"""
import dataclasses
import math
import signal
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass

import numpy as np

from .loop import COLUMN, LOG_COLUMNS
from .runner import RunResult, build_drive
from .scenario import ScenarioError, load_scenario, resolve

EXECUTORS = ("events", "single")
DRIVE_ROLES = ("pmsm_plant", "hf_estimator", "foc_controller")
ROLES = DRIVE_ROLES + ("drive_bridge",)
DEFAULT_NAMESPACE = "/drive"
DELIVERIES_PER_SAMPLE = 9
"""Messages delivered per lock-step sample without recording: currents → estimator, controller;
rotor_estimate → controller, plant; injection → controller; voltage_command → plant, estimator,
launcher; load_torque → plant. Composed on one executor thread, a sample costs their sum."""


def scenario_from_parameters(parameters):
    """The scenario the nodes run: the file named by ``scenario`` with the override parameters
    (pmsm_plant.contract.GLOBAL_PARAMETERS) applied; errors name the parameter."""
    scenario = load_scenario(parameters["scenario"], estimator_override=parameters["estimator"] or None)
    changes = {}
    if parameters["seed"] >= 0:
        changes["seed"] = int(parameters["seed"])
    if parameters["duration_s"] > 0.0:
        changes["duration_s"] = float(parameters["duration_s"])
    injection = dict(scenario.injection)
    for key in ("frequency_Hz", "amplitude_V"):
        if parameters[f"injection.{key}"] > 0.0:
            injection[key] = float(parameters[f"injection.{key}"])
    controller = dict(scenario.controller)
    if parameters["controller.current_limit_A"] > 0.0:
        controller["current_limit_A"] = float(parameters["controller.current_limit_A"])
    if parameters["controller.speed_limit_rad_s"] != math.inf:
        controller["speed_limit_rad_s"] = parameters["controller.speed_limit_rad_s"]
    return dataclasses.replace(scenario, injection=injection, controller=controller, **changes)


def build_from_parameters(parameters):
    """The nodes' builder: fresh cores for the scenario the parameters name."""
    return build_drive(scenario_from_parameters(parameters))


def make_node(role, context=None, namespace=None, parameters=None, link=None):
    """One of the drive's nodes, built from its ROS parameters (plus ``parameters`` overrides); the
    drive_bridge node on ``link`` when given (a link object, for composed graphs)."""
    from pmsm_plant.contract import parameter_overrides
    kwargs = {"context": context, "namespace": namespace,
              "parameter_overrides": parameter_overrides(parameters or {})}
    if role == "pmsm_plant":
        from pmsm_plant.node import PlantNode
        return PlantNode(build_from_parameters, **kwargs)
    if role == "hf_estimator":
        from hf_estimator.node import EstimatorNode
        return EstimatorNode(build_from_parameters, **kwargs)
    if role == "foc_controller":
        from foc_controller.node import ControllerNode
        return ControllerNode(build_from_parameters, **kwargs)
    if role == "drive_bridge":
        from .bridge_node import InverterBridgeNode
        return InverterBridgeNode(link=link, **kwargs)
    raise ValueError(f"unknown node '{role}' (known: {', '.join(ROLES)})")


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
    raise ScenarioError(f"--executor: must be one of {', '.join(EXECUTORS)}, not '{name}'")


@dataclass
class GraphResult(RunResult):
    processes: str = "composed"
    executor: str = "events"
    interrupted: bool = False
    diagnostics: dict = None
    """Last /diagnostics status per node: level, message, values."""


class ScenarioDriver:
    """The launcher's own node, the dyno and operator of the scenario: waits until every lock-step
    endpoint is matched, then publishes the speed (when it changes) and the load torque of sample 0,
    which starts the plant (``load_torque_per_sample``); on `voltage_command`(k), after the controller
    has used the speed of k, it publishes those of k+1. With ``record`` it fills a log
    (drive_bridge.loop.LOG_COLUMNS) from the topics; columns no topic carries stay NaN. With a
    ``recorder`` (drive_bridge.bag.BagWriter) it writes every contract topic as received, serialized.
    With a virtual ``inverter`` (the bridge in the plant's place) it starts the inverter at sample 0."""

    def __init__(self, node, scenario, drive, record, settle_s, startup_timeout_s, progress, recorder=None,
                 inverter=None):
        from pmsm_plant.contract import COMMAND_QOS
        from rclpy.serialization import serialize_message
        from std_msgs.msg import Float64

        self.node, self.scenario, self.drive = node, scenario, drive
        self.n = scenario.n_samples
        self.n_p = drive.machine.n_p
        self.record = record
        self.settle_s, self.startup_timeout_s, self.progress = settle_s, startup_timeout_s, progress
        self.speed, self.load = drive.speed_ref, drive.tau_load
        self.log = np.full((self.n if record else 1, len(LOG_COLUMNS)), np.nan)
        if record:
            self.log[:, COLUMN["t"]] = np.arange(self.n) * scenario.T_s
            self.log[:, COLUMN["omega_m_ref"]] = self.speed
            self.log[:, COLUMN["tau_load"]] = self.load
        self.speed_pub = node.create_publisher(Float64, "speed_command", COMMAND_QOS)
        self.load_pub = node.create_publisher(Float64, "load_torque", COMMAND_QOS)
        self.Float64, self.serialize = Float64, serialize_message
        self.recorder = recorder
        self.inverter = inverter
        handlers = {"voltage_command": self.on_voltage, "/diagnostics": self.on_diagnostics}
        recorded = ("currents", "rotor_state", "rotor_estimate", "injection", "estimator_state")
        if record:
            handlers.update({topic: self.logger_of(topic) for topic in recorded})
        self.subscribe(handlers)
        self.received = dict.fromkeys(("voltage_command",) + (recorded if record else ()), 0)
        self.sent_speed = None
        self.created = time.monotonic()
        self.ready_since = None
        self.started_at = self.finished_at = None
        self.last_sample = -1
        self.error = None
        self.diagnostics = {}
        self.done = None
        node.create_timer(0.05, self.tick)

    def subscribe(self, handlers):
        """Subscribe the handlers; with a recorder, every contract topic raw, written as it comes and
        deserialised only for a handler. The launcher's own commands are written where published."""
        from .bag import DRIVE_TOPICS, SAMPLE_STAMPED, offered_qos
        types = topic_types()
        topics = set(handlers)
        if self.recorder:
            topics |= set(types) - {"speed_command", "load_torque"}
        for topic in sorted(topics):
            cls, qos = types[topic]
            handler = handlers.get(topic)
            if not self.recorder:
                self.node.create_subscription(cls, topic, handler, qos)
                continue
            callback = self.recording(topic, cls, handler, topic in SAMPLE_STAMPED)
            self.node.create_subscription(cls, topic, callback, qos, raw=True)
        if self.recorder:
            for topic in sorted(types):
                name = self.node.resolve_topic_name(topic)
                self.recorder.add(name, DRIVE_TOPICS[topic], offered_qos(topic))

    def recording(self, topic, cls, handler, stamped):
        from rclpy.serialization import deserialize_message
        name = self.node.resolve_topic_name(topic)

        def callback(data):
            self.recorder.write(name, data, stamped)
            if handler:
                handler(deserialize_message(data, cls))
        return callback

    def expected_endpoints(self):
        """(topic, publishers, subscribers) that must exist before sample 0, this node included (with
        an inverter, which keeps its own load and clock, no plant subscribes to load_torque)."""
        r = 1 if self.record or self.recorder else 0
        sensored = self.drive.estimator.name == "sensored"
        endpoints = [("currents", 1, 2 + r), ("rotor_estimate", 1, 2 + r), ("injection", 1, 1 + r),
                     ("voltage_command", 1, 3), ("estimator_state", 1, r), ("speed_command", 1, 1)]
        if self.inverter is None:
            endpoints += [("rotor_state", 1, r + sensored), ("load_torque", 1, 1)]
        return endpoints

    def missing_endpoints(self):
        missing = []
        for topic, pubs, subs in self.expected_endpoints():
            name = self.node.resolve_topic_name(topic)
            have_pubs, have_subs = self.node.count_publishers(name), self.node.count_subscribers(name)
            if have_pubs < pubs or have_subs < subs:
                missing.append(f"{name} ({have_pubs}/{pubs} publishers, {have_subs}/{subs} subscribers)")
        return missing

    def command(self, k):
        from pmsm_plant.contract import stamp_ns
        published = []
        if self.speed[k] != self.sent_speed:
            self.sent_speed = self.speed[k]
            published.append((self.speed_pub, self.Float64(data=float(self.sent_speed))))
        published.append((self.load_pub, self.Float64(data=float(self.load[k]))))
        for publisher, msg in published:
            publisher.publish(msg)
            if self.recorder:
                self.recorder.write(publisher.topic_name, self.serialize(msg), False,
                                    stamp_ns(k, self.scenario.T_s))

    def tick(self):
        now = time.monotonic()
        if self.started_at is None:
            missing = self.missing_endpoints()
            if missing:
                self.ready_since = None
                if now - self.created > self.startup_timeout_s:
                    self.finish(f"graph not complete after {self.startup_timeout_s:g} s: missing "
                                + "; ".join(missing))
                return
            self.ready_since = self.ready_since or now
            if now - self.ready_since >= self.settle_s:
                self.started_at = now
                self.command(0)
                if self.inverter is not None:
                    threading.Thread(target=self.inverter.run, name="virtual_inverter", daemon=True).start()
            return
        if self.progress:
            self.progress((self.last_sample + 1) / self.n)
        if self.finished_at is not None and (self.complete() or now - self.finished_at > 1.0):
            self.finish()

    def complete(self):
        return all(count >= self.n for count in self.received.values())

    def finish(self, error=None):
        if self.done is not None and not self.done.done():
            self.error = error
            self.done.set_result(error is None)

    def sample(self, msg, topic):
        from pmsm_plant.contract import sample_of
        k = sample_of(msg.header, self.scenario.T_s)
        if k is None or not 0 <= k < self.n:
            return None
        self.received[topic] += 1
        return k

    def logger_of(self, topic):
        """A handler writing what a per-sample message of ``topic`` says into its log row."""
        from .bag import fill_sample

        def log_sample(msg):
            k = self.sample(msg, topic)
            if k is not None:
                fill_sample(self.log[k], topic, msg, self.n_p)
        return log_sample

    def on_voltage(self, msg):
        k = self.sample(msg, "voltage_command")
        if k is None:
            return
        self.last_sample = max(self.last_sample, k)
        if k + 1 < self.n:
            self.command(k + 1)
        if self.record:
            from .bag import fill_sample
            fill_sample(self.log[k], "voltage_command", msg, self.n_p)
        if k == self.n - 1:
            self.finished_at = time.monotonic()
            if self.complete():
                self.finish()

    def on_diagnostics(self, msg):
        prefix = self.node.get_namespace().rstrip("/") + "/"
        for status in msg.status:
            if status.name.startswith(prefix):
                self.diagnostics[status.name] = {"level": int.from_bytes(status.level, "little"),
                                                 "message": status.message,
                                                 "values": {v.key: v.value for v in status.values}}


def node_parameters(scenario_ref, estimator=None, duration_s=None, timeout_s=1.0, extra=None):
    """The parameter overrides the launcher gives every node."""
    parameters = {"scenario": str(resolve(scenario_ref)), "lockstep_timeout_s": float(timeout_s)}
    if estimator:
        parameters["estimator"] = estimator
    if duration_s:
        parameters["duration_s"] = float(duration_s)
    parameters.update(extra or {})
    return parameters


def _all_parameters(overrides):
    from pmsm_plant.contract import GLOBAL_PARAMETERS
    merged = {name: default for name, (default, _) in GLOBAL_PARAMETERS.items()}
    merged.update(overrides)
    return merged


@dataclass(frozen=True)
class DriveSpec:
    """One drive of a graph: its scenario (name or path), namespace and overrides."""

    scenario: str
    namespace: str = DEFAULT_NAMESPACE
    estimator: str = None
    duration_s: float = None
    extra_parameters: dict = None
    bag: str = None
    """Record every contract topic of this drive into this new rosbag2 directory."""
    link: str = None
    """None: the simulated plant node. 'pty' or 'can': the virtual inverter behind that link and the
    drive_bridge node in the plant's place."""


def launch(scenario_ref, estimator=None, duration_s=None, processes="composed", executor="events",
           namespace=DEFAULT_NAMESPACE, record=True, timeout_s=1.0, startup_timeout_s=60.0,
           progress=None, extra_parameters=None, bag=None, link=None):
    """Run a scenario through the ROS graph; returns a GraphResult (metrics as for drive run).

    SIGINT/SIGTERM stop the run cleanly (children too) and return what was recorded, marked
    ``interrupted``; a ``bag`` being recorded is closed complete. ``link`` ('pty', 'can') puts the
    virtual inverter and the drive_bridge node in the plant's place."""
    spec = DriveSpec(scenario_ref, namespace, estimator, duration_s, extra_parameters, bag, link)
    return launch_many([spec], processes, executor, record, timeout_s, startup_timeout_s, progress)[0]


def launch_many(specs, processes="composed", executor="events", record=True, timeout_s=1.0,
                startup_timeout_s=60.0, progress=None):
    """Run several drives side by side in one graph (one namespace each); one GraphResult per spec."""
    import rclpy
    from rclpy.node import Node
    from rclpy.signals import SignalHandlerOptions
    from rclpy.task import Future

    if processes not in ("composed", "separate"):
        raise ScenarioError(f"--processes: must be 'composed' or 'separate', not '{processes}'")
    if len({spec.namespace for spec in specs}) < len(specs):
        raise ScenarioError("--namespace: drives side by side need distinct namespaces")
    from .bag import BagWriter
    for spec in specs:
        if spec.link not in (None, "pty", "can"):
            raise ScenarioError(f"--link: 'pty' or 'can', not {spec.link!r}")
        if spec.link == "can" and processes == "separate":
            raise ScenarioError("--link can: python-can's virtual bus lives in one process; use --processes "
                                "composed, or pty")
    recorders = [BagWriter(spec.bag) if spec.bag else None for spec in specs]
    workdir = tempfile.TemporaryDirectory(prefix="drive_bridge_")
    inverters = []
    context = rclpy.Context()
    rclpy.init(context=context, signal_handler_options=SignalHandlerOptions.NO)
    children, nodes, drivers = [], [], []
    interrupted = []
    previous = {s: signal.signal(s, lambda signum, frame: interrupted.append(signum))
                for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        ex = make_executor(executor, context)
        for i, spec in enumerate(specs):
            parameters = node_parameters(spec.scenario, spec.estimator, spec.duration_s, timeout_s,
                                         spec.extra_parameters)
            scenario = scenario_from_parameters(_all_parameters(parameters))
            roles = {"pmsm_plant": {**parameters, "load_torque_per_sample": True},
                     "hf_estimator": parameters, "foc_controller": parameters}
            inverter = None
            if spec.link:
                inverter, host_link = _virtual_inverter(scenario, spec.link, workdir.name, i)
                inverters.append(inverter)
                del roles["pmsm_plant"]
                period = float(_all_parameters(parameters)["diagnostics_period_s"])
                timeouts = {"link_timeout_s": timeout_s, "command_timeout_s": timeout_s,
                            "diagnostics_period_s": period}
                if processes == "composed":
                    nodes.append(make_node("drive_bridge", context, spec.namespace, timeouts, link=host_link))
                else:
                    roles["drive_bridge"] = {"link": "serial", "port": host_link.port, **timeouts}
            for role, role_parameters in roles.items():
                if processes == "composed":
                    nodes.append(make_node(role, context, spec.namespace, role_parameters))
                else:
                    children.append((role, _spawn(role, spec.namespace, role_parameters, executor)))
            driver_node = Node("drive_launcher", context=context, namespace=spec.namespace)
            nodes.append(driver_node)
            driver = ScenarioDriver(driver_node, scenario, build_drive(scenario), record,
                                    0.1 if processes == "composed" else 0.5, startup_timeout_s,
                                    progress if i == 0 else None, recorders[i], inverter)
            driver.done = Future()
            drivers.append(driver)
        for node in nodes:
            ex.add_node(node)
        all_done = Future()
        watcher = nodes[-1].create_timer(0.05, lambda: _watch(drivers, interrupted, children, all_done))
        while not all_done.done():
            ex.spin_until_future_complete(all_done, timeout_sec=1.0)
        nodes[-1].destroy_timer(watcher)
        return [_result(driver, record, processes, executor, interrupted) for driver in drivers]
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
        _stop_children([child for _, child in children])
        for inverter in inverters:
            inverter.stop()
        for node in nodes:
            node.destroy_node()
        context.try_shutdown()
        for inverter in inverters:
            inverter.endpoint.close()
        workdir.cleanup()
        for recorder in recorders:
            if recorder:
                recorder.close()


def _result(driver, record, processes, executor, interrupted):
    scenario, drive = driver.scenario, driver.drive
    if driver.error and not interrupted:
        raise ScenarioError(f"{driver.node.get_namespace()} ({scenario.name}): {driver.error}")
    end = driver.finished_at or time.monotonic()
    wall = end - driver.started_at if driver.started_at else 0.0
    log = driver.log[:driver.last_sample + 1] if record else driver.log[:0]
    if driver.last_sample + 1 < scenario.n_samples:
        scenario = dataclasses.replace(scenario, duration_s=(driver.last_sample + 1) * scenario.T_s)
    return GraphResult(scenario, drive.preset, drive.estimator.name, log, wall, drive.controller.i_max_A,
                       processes=processes, executor=executor, interrupted=bool(interrupted),
                       diagnostics=dict(driver.diagnostics))


def _virtual_inverter(scenario, link, workdir, drive_id):
    """A virtual inverter for ``scenario`` (not yet running; paced by the graph's commands) and the
    host's end of its link."""
    from .bridge_loop import make_links
    from .virtual_inverter import VirtualInverter
    endpoint, host_link = make_links(link, workdir, drive_id)
    return VirtualInverter(scenario, endpoint, drive_id=drive_id), host_link


def _watch(drivers, interrupted, children, all_done):
    for driver in drivers:
        if interrupted:
            driver.finish("interrupted")
        for role, child in children:
            if child.poll() is not None:
                driver.finish(f"node process {role} exited with code {child.returncode}")
    if all(driver.done.done() for driver in drivers) and not all_done.done():
        all_done.set_result(True)


def _spawn(role, namespace, parameters, executor):
    args = [sys.executable, "-m", "drive_bridge.graph", role, "--executor", executor,
            "--ros-args", "-r", f"__ns:={namespace}"]
    for name, value in parameters.items():
        args += ["-p", f"{name}:={_ros_value(value)}"]
    return subprocess.Popen(args)


def _ros_value(value):
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return f"'{value}'"
    return repr(value)


def _stop_children(children, grace_s=5.0):
    for child in children:
        if child.poll() is None:
            child.send_signal(signal.SIGTERM)
    deadline = time.monotonic() + grace_s
    for child in children:
        try:
            child.wait(max(deadline - time.monotonic(), 0.0))
        except subprocess.TimeoutExpired:
            child.kill()
            child.wait()


def topic_types():
    """Message class and QoS of each contract topic (names relative to the drive's namespace), from
    drive_bridge.bag.DRIVE_TOPICS and pmsm_plant.contract.topic_qos."""
    import importlib

    from pmsm_plant.contract import topic_qos

    from .bag import DRIVE_TOPICS
    types = {}
    for topic, msgtype in DRIVE_TOPICS.items():
        package, _, name = msgtype.split("/")
        types[topic] = (getattr(importlib.import_module(f"{package}.msg"), name), topic_qos(topic))
    return types


def message_dict(msg):
    """A ROS message as plain Python data (what `ros2 topic echo` shows)."""
    if hasattr(msg, "get_fields_and_field_types"):
        return {name: message_dict(getattr(msg, name)) for name in msg.get_fields_and_field_types()}
    if isinstance(msg, (list, tuple)) or hasattr(msg, "tolist"):
        return [message_dict(v) for v in msg]
    if isinstance(msg, bytes):
        return int.from_bytes(msg, "little")
    return msg


def echo(topic, namespace=DEFAULT_NAMESPACE, count=None, every=1, as_json=False, timeout_s=None):
    """Print messages of a contract topic until ``count`` were printed, ``timeout_s`` passed or
    Ctrl-C; there is no `ros2 topic echo` in a PyPI-only install."""
    import json

    import rclpy
    from rclpy.node import Node
    from rclpy.signals import SignalHandlerOptions
    from rclpy.task import Future

    types = topic_types()
    key = topic if topic in types else topic.rsplit("/", 1)[-1]
    if key not in types:
        raise ScenarioError(f"{topic}: not a drive topic (known: {', '.join(types)})")
    message_type, qos = types[key]
    context = rclpy.Context()
    rclpy.init(context=context, signal_handler_options=SignalHandlerOptions.NO)
    done = Future()
    previous = {s: signal.signal(s, lambda *_: done.done() or done.set_result(True))
                for s in (signal.SIGINT, signal.SIGTERM)}
    seen, printed = [0], [0]

    def show(msg):
        seen[0] += 1
        if (seen[0] - 1) % every or done.done():
            return
        data = message_dict(msg)
        print(json.dumps(data) if as_json else _yaml_like(data) + "\n---", flush=True)
        printed[0] += 1
        if count and printed[0] >= count:
            done.set_result(True)

    node = Node("drive_echo", context=context, namespace=namespace)
    try:
        node.create_subscription(message_type, topic if topic.startswith("/") else key, show, qos)
        if timeout_s:
            node.create_timer(timeout_s, lambda: done.done() or done.set_result(True))
        executor = make_executor("events", context)
        executor.add_node(node)
        while not done.done():
            executor.spin_until_future_complete(done, timeout_sec=0.25)
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
        node.destroy_node()
        context.try_shutdown()
    return 0


def _yaml_like(data, indent=""):
    lines = []
    for name, value in data.items():
        if isinstance(value, dict):
            lines.append(f"{indent}{name}:")
            lines.append(_yaml_like(value, indent + "  "))
        elif isinstance(value, list) and value and isinstance(value[0], dict):
            lines.append(f"{indent}{name}:")
            for item in value:
                body = _yaml_like(item, indent + "  ")
                lines.append(f"{indent}- " + body.lstrip())
        else:
            lines.append(f"{indent}{name}: {value}")
    return "\n".join(lines)


def node_main(argv=None):
    """Entry of a node process: ``ROLE [--executor E] --ros-args ...``; stops on SIGINT/SIGTERM."""
    import argparse

    import rclpy
    from rclpy.signals import SignalHandlerOptions
    from rclpy.task import Future

    argv = sys.argv[1:] if argv is None else argv
    ros_args = argv[argv.index("--ros-args"):] if "--ros-args" in argv else []
    own = argv[:len(argv) - len(ros_args)]
    parser = argparse.ArgumentParser(prog="python -m drive_bridge.graph")
    parser.add_argument("role", choices=ROLES)
    parser.add_argument("--executor", choices=EXECUTORS, default="events")
    args = parser.parse_args(own)
    rclpy.init(args=["node"] + ros_args, signal_handler_options=SignalHandlerOptions.NO)
    stop = Future()
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, lambda *_: stop.done() or stop.set_result(True))
    node = make_node(args.role)
    executor = make_executor(args.executor, rclpy.get_default_context())
    executor.add_node(node)
    try:
        while not stop.done():
            executor.spin_until_future_complete(stop, timeout_sec=0.25)
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(node_main())
