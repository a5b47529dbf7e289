"""The drive as a ROS 2 graph: the three nodes over topics in lock-step, a scenario driver that
commands speed and load over `speed_command` / `load_torque` and records the per-sample topics into
the runner's log layout, and a launcher (no `ros2 launch` here) that composes the nodes in one process
or starts them as separate processes.

Node processes: ``python -m drive_bridge.graph {pmsm_plant,hf_estimator,foc_controller} --ros-args ...``.
"""
import dataclasses
import math
import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass

import numpy as np

from .loop import COLUMN, LOG_COLUMNS
from .runner import RunResult, build_drive
from .scenario import ScenarioError, load_scenario, resolve

EXECUTORS = ("events", "single")
ROLES = ("pmsm_plant", "hf_estimator", "foc_controller")
DEFAULT_NAMESPACE = "/drive"
HOPS_PER_SAMPLE = 3
"""Sequential hops of one lock-step sample: currents → estimator → controller → plant."""


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


def make_node(role, context=None, namespace=None, parameters=None):
    """One of the drive's nodes, built from its ROS parameters (plus ``parameters`` overrides)."""
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
    (drive_bridge.loop.LOG_COLUMNS) from the topics; columns no topic carries stay NaN."""

    def __init__(self, node, scenario, drive, record, settle_s, startup_timeout_s, progress):
        from diagnostic_msgs.msg import DiagnosticArray
        from geometry_msgs.msg import Vector3Stamped
        from pmsm_plant.contract import COMMAND_QOS, PER_SAMPLE_QOS
        from sensor_msgs.msg import JointState
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
        self.Float64 = Float64
        node.create_subscription(Vector3Stamped, "currents", self.on_currents, PER_SAMPLE_QOS)
        node.create_subscription(Vector3Stamped, "voltage_command", self.on_voltage, PER_SAMPLE_QOS)
        node.create_subscription(DiagnosticArray, "/diagnostics", self.on_diagnostics, 50)
        if record:
            node.create_subscription(JointState, "rotor_state", self.on_rotor_state, PER_SAMPLE_QOS)
            node.create_subscription(JointState, "rotor_estimate", self.on_estimate, PER_SAMPLE_QOS)
            node.create_subscription(Vector3Stamped, "injection", self.on_injection, PER_SAMPLE_QOS)
            node.create_subscription(Vector3Stamped, "estimator_state", self.on_estimator_state,
                                     PER_SAMPLE_QOS)
        self.received = dict.fromkeys(("currents", "voltage_command") + (
            ("rotor_state", "rotor_estimate", "injection", "estimator_state") if record else ()), 0)
        self.sent_speed = None
        self.created = time.monotonic()
        self.ready_since = None
        self.started_at = self.finished_at = None
        self.last_sample = -1
        self.error = None
        self.diagnostics = {}
        self.done = None
        node.create_timer(0.05, self.tick)

    def expected_endpoints(self):
        """(topic, publishers, subscribers) that must exist before sample 0, this node included."""
        r = 1 if self.record else 0
        sensored = self.drive.estimator.name == "sensored"
        return [("currents", 1, 3), ("rotor_state", 1, r + sensored), ("rotor_estimate", 1, 2 + r),
                ("injection", 1, 1 + r), ("voltage_command", 1, 3), ("estimator_state", 1, r),
                ("speed_command", 1, 1), ("load_torque", 1, 1)]

    def missing_endpoints(self):
        missing = []
        for topic, pubs, subs in self.expected_endpoints():
            name = self.node.resolve_topic_name(topic)
            have_pubs, have_subs = self.node.count_publishers(name), self.node.count_subscribers(name)
            if have_pubs < pubs or have_subs < subs:
                missing.append(f"{name} ({have_pubs}/{pubs} publishers, {have_subs}/{subs} subscribers)")
        return missing

    def command(self, k):
        if self.speed[k] != self.sent_speed:
            self.sent_speed = self.speed[k]
            self.speed_pub.publish(self.Float64(data=float(self.sent_speed)))
        self.load_pub.publish(self.Float64(data=float(self.load[k])))

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

    def on_currents(self, msg):
        k = self.sample(msg, "currents")
        if k is not None and self.record:
            row = self.log[k]
            row[COLUMN["i_a_meas"]], row[COLUMN["i_b_meas"]], row[COLUMN["i_c_meas"]] = (
                msg.vector.x, msg.vector.y, msg.vector.z)

    def on_voltage(self, msg):
        k = self.sample(msg, "voltage_command")
        if k is None:
            return
        self.last_sample = max(self.last_sample, k)
        if k + 1 < self.n:
            self.command(k + 1)
        if self.record:
            self.log[k, COLUMN["u_alpha"]], self.log[k, COLUMN["u_beta"]] = msg.vector.x, msg.vector.y
        if k == self.n - 1:
            self.finished_at = time.monotonic()
            if self.complete():
                self.finish()

    def on_rotor_state(self, msg):
        k = self.sample(msg, "rotor_state")
        if k is not None:
            row = self.log[k]
            row[COLUMN["theta_m"]], row[COLUMN["omega_m"]] = msg.position[0], msg.velocity[0]
            row[COLUMN["tau_e"]] = msg.effort[0]

    def on_estimate(self, msg):
        k = self.sample(msg, "rotor_estimate")
        if k is not None:
            self.log[k, COLUMN["theta_e_hat"]] = self.n_p * msg.position[0]
            self.log[k, COLUMN["omega_e_hat"]] = self.n_p * msg.velocity[0]

    def on_injection(self, msg):
        k = self.sample(msg, "injection")
        if k is not None:
            self.log[k, COLUMN["u_inj_alpha"]], self.log[k, COLUMN["u_inj_beta"]] = msg.vector.x, msg.vector.y

    def on_estimator_state(self, msg):
        k = self.sample(msg, "estimator_state")
        if k is not None:
            row = self.log[k]
            row[COLUMN["eps"]], row[COLUMN["signal"]], row[COLUMN["observable"]] = (
                msg.vector.x, msg.vector.y, msg.vector.z)

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


def launch(scenario_ref, estimator=None, duration_s=None, processes="composed", executor="events",
           namespace=DEFAULT_NAMESPACE, record=True, timeout_s=1.0, startup_timeout_s=60.0,
           progress=None, extra_parameters=None, domain_id=None):
    """Run a scenario through the ROS graph; returns a GraphResult (metrics as for drive run).

    SIGINT/SIGTERM stop the run cleanly (children too) and return what was recorded, marked
    ``interrupted``."""
    import rclpy
    from rclpy.signals import SignalHandlerOptions
    from rclpy.task import Future

    if processes not in ("composed", "separate"):
        raise ScenarioError(f"--processes: must be 'composed' or 'separate', not '{processes}'")
    parameters = node_parameters(scenario_ref, estimator, duration_s, timeout_s, extra_parameters)
    all_parameters = _all_parameters(parameters)
    scenario = scenario_from_parameters(all_parameters)
    drive = build_drive(scenario)
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain_id, signal_handler_options=SignalHandlerOptions.NO)
    children, nodes = [], []
    interrupted = []
    previous = {s: signal.signal(s, lambda signum, frame: interrupted.append(signum))
                for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        ex = make_executor(executor, context)
        plant_parameters = {**parameters, "load_torque_per_sample": True}
        if processes == "composed":
            for role in ROLES:
                nodes.append(make_node(role, context, namespace,
                                       plant_parameters if role == "pmsm_plant" else parameters))
        else:
            children = [_spawn(role, namespace, plant_parameters if role == "pmsm_plant" else parameters,
                               executor, domain_id) for role in ROLES]
        from rclpy.node import Node
        driver_node = Node("drive_launcher", context=context, namespace=namespace)
        nodes.append(driver_node)
        driver = ScenarioDriver(driver_node, scenario, drive, record,
                                0.1 if processes == "composed" else 0.5, startup_timeout_s, progress)
        driver.done = Future()
        for node in nodes:
            ex.add_node(node)
        watcher = driver_node.create_timer(0.05, lambda: _watch(driver, interrupted, children))
        while not driver.done.done():
            ex.spin_until_future_complete(driver.done, timeout_sec=1.0)
        driver_node.destroy_timer(watcher)
        if driver.error and not interrupted:
            raise ScenarioError(f"{scenario.name}: {driver.error}")
        end = driver.finished_at or time.monotonic()
        wall = end - driver.started_at if driver.started_at else 0.0
        log = driver.log[:driver.last_sample + 1] if record else driver.log[:0]
        result_scenario = scenario
        if driver.last_sample + 1 < scenario.n_samples:
            result_scenario = dataclasses.replace(scenario, duration_s=(driver.last_sample + 1) * scenario.T_s)
        return GraphResult(result_scenario, drive.preset, drive.estimator.name, log, wall,
                           drive.controller.i_max_A, processes=processes, executor=executor,
                           interrupted=bool(interrupted), diagnostics=dict(driver.diagnostics))
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
        _stop_children(children)
        for node in nodes:
            node.destroy_node()
        context.try_shutdown()


def _watch(driver, interrupted, children):
    if interrupted:
        driver.finish("interrupted")
    for role, child in zip(ROLES, children):
        if child.poll() is not None:
            driver.finish(f"node process {role} exited with code {child.returncode}")


def _spawn(role, namespace, parameters, executor, domain_id):
    args = [sys.executable, "-m", "drive_bridge.graph", role, "--executor", executor,
            "--ros-args", "-r", f"__ns:={namespace}"]
    for name, value in parameters.items():
        args += ["-p", f"{name}:={_ros_value(value)}"]
    env = dict(os.environ)
    if domain_id is not None:
        env["ROS_DOMAIN_ID"] = str(domain_id)
    return subprocess.Popen(args, env=env)


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
