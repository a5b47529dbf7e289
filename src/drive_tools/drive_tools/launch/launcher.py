"""The drive as a ROS 2 graph: the launcher (there is no `ros2 launch` here) composes the drive's nodes in
one process or starts them as separate processes (each node's own executable module), with the scenario
driver commanding speed and load and recording the per-sample topics into the runner's log layout.

The estimator and controller nodes load the commissioning record the one-process runner would (the
scenario's ``commissioning``, a --commissioning override, or the default file in the working
directory, else the nameplate alone)."""
import contextlib
import dataclasses
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from drive_bridge.inverter_protocol import MAX_BLOCK
from drive_common.config.parameters import all_parameters, scenario_from_parameters
from drive_common.config.scenario import behind_an_inverter, resolve
from drive_common.contract.errors import DriveError
from drive_common.contract.graph import DEFAULT_NAMESPACE, NODES
from drive_common.contract.run_result import RunResult
from drive_common.runtime.interrupt import polled, requested
from drive_common.runtime.realtime import collector_held, cpu_wakeup_latency_held, real_time_scheduled, unbound_work_on
from drive_tools.bags.common import BagWriteError
from drive_tools.bags.writer import BagWriter
from drive_tools.doubles.inverter_timing import timing_report
from drive_tools.doubles.virtual_inverter import InverterOptions, VirtualInverter
from drive_tools.runner.runner import build_drive, cut
from foc_controller.build import protection_for_scenario

from .hop_cost import HOP_ROUND_TRIPS_BESIDE_A_RUN, hop_latency, in_hops

PROCESSES = ("composed", "separate")
LINKS = ("pty", "can")
DELIVERIES_PER_SAMPLE = 8
"""Messages delivered per lock-step sample without recording: currents → estimator, controller;
rotor_estimate → controller, plant; injection, estimator_state → controller; voltage_command → plant,
estimator. The scenario's schedule costs none (``scenario_schedule``). Composed on one executor thread, a
sample costs their sum."""
DELIVERIES_PER_SAMPLE_INTRA_PROCESS = 4
"""The same with ``intra_process``: the controller's four (currents, rotor_estimate, injection,
estimator_state) are handed over, not delivered."""


RUN_DEADLINE_FACTOR = 50.0
RUN_DEADLINE_MARGIN_S = 60.0
"""A run's deadline once started (run_deadline_s): its duration × the factor (a lock-step graph runs at a
real-time factor of 0.1-1.4 here) plus the margin (the final wait, the first kernels' loading)."""


class GraphError(DriveError):
    """The graph could not run as asked."""


class NamespaceOccupiedError(GraphError):
    """Another drive's nodes are in the namespace asked for."""


DRIVE_NODE_NAMES = set(NODES) | {"drive_launcher", "drive_recorder"}
DISCOVERY_S = 1.0
"""How long the launcher looks at the graph for another drive in its namespaces before it creates its
nodes. Discovery of a busy process can take longer (2-3 s measured here); a drive found later is refused
by the scenario driver's start-up check (more publishers than its own), and one that appears during a
run stops that run (the same check, every 0.5 s) and is counted by the nodes (``foreign_publisher``)."""


def check_namespace(namespace):
    """GraphError unless ``namespace`` is a valid absolute ROS namespace."""
    from rclpy.exceptions import InvalidNamespaceException
    from rclpy.validate_namespace import validate_namespace
    try:
        validate_namespace(namespace)
    except InvalidNamespaceException as error:
        reason = str(error).splitlines()[0].split(": ", 1)[-1]
        raise GraphError(f"namespace {namespace!r} is not a ROS namespace ({reason})") from None


class NamespaceLock:
    """This host's claim on (ROS_DOMAIN_ID, namespace) for a launcher's lifetime: an exclusive flock on
    a file in the temporary directory, released when the process ends however it ends. It closes the
    gap discovery leaves (a busy process can take seconds to show in another's graph)."""

    def __init__(self, namespace):
        import fcntl
        import os
        directory = Path(tempfile.gettempdir()) / f"drive-namespaces-{os.getuid()}"
        directory.mkdir(exist_ok=True)
        domain = os.environ.get("ROS_DOMAIN_ID", "0") or "0"
        self.path = directory / f"domain{domain}{namespace.replace('/', '%')}.lock"
        self.file = self.path.open("a+")
        try:
            fcntl.flock(self.file, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            self.file.seek(0)
            holder = self.file.read().strip() or "?"
            self.file.close()
            raise NamespaceOccupiedError(f"namespace {namespace} is in use: another drive runs there (process "
                                         f"{holder} on this host, domain {domain}); run this one in another "
                                         f"namespace") from None
        self.file.truncate(0)
        self.file.write(str(os.getpid()))
        self.file.flush()

    def release(self):
        self.file.close()


def refuse_occupied(context, namespaces, discovery_s=DISCOVERY_S):
    """NamespaceOccupiedError when a drive's node or a publisher is already in one of ``namespaces``
    (looked for during ``discovery_s``); readers (`drive echo`, a recorder) are welcome."""
    from rclpy.node import Node
    probe = Node("drive_namespace_probe", context=context, namespace="/")
    try:
        deadline = time.monotonic() + discovery_s
        while True:
            for namespace in namespaces:
                prefix = namespace.rstrip("/") + "/"
                nodes = sorted(name for name, ns in probe.get_node_names_and_namespaces()
                               if ns == namespace and name in DRIVE_NODE_NAMES)
                topics = [t for t, _ in probe.get_topic_names_and_types()
                          if t.startswith(prefix) and probe.count_publishers(t)]
                if nodes or topics:
                    found = f"nodes {', '.join(nodes)}" if nodes else f"publishers on {', '.join(topics[:3])}"
                    raise NamespaceOccupiedError(f"namespace {namespace} is in use ({found}): another drive "
                                                 f"runs there; run this one in another namespace")
            if time.monotonic() >= deadline:
                return
            time.sleep(0.05)
    finally:
        probe.destroy_node()


def make_node(name, context=None, namespace=None, parameters=None, link=None, estimator=None, controller=None,
              inputs_handed=False):
    """One of the drive's nodes (``drive_common.contract.graph.NODES``) with ``parameters`` as overrides; the
    drive_bridge node on ``link`` when given (a link object, for composed graphs). Intra-process partners,
    made before: the controller takes the answers of ``estimator`` (the EstimatorNode of this process)
    directly, the bridge the commands of ``controller``; with ``inputs_handed`` the estimator takes its
    inputs from the bridge and the controller made after it, which hand them over (the bridge's link thread
    runs the drive's whole answer)."""
    from drive_common.ros.node import parameter_overrides
    kwargs = {"context": context, "namespace": namespace,
              "parameter_overrides": parameter_overrides(parameters or {})}
    if name == "pmsm_plant":
        from pmsm_plant.node import PlantNode
        return PlantNode(**kwargs)
    if name == "hf_estimator":
        from hf_estimator.node import EstimatorNode
        return EstimatorNode(inputs_handed=inputs_handed, **kwargs)
    if name == "foc_controller":
        from foc_controller.node import ControllerNode
        return ControllerNode(estimator=estimator, **kwargs)
    if name == "drive_commissioning":
        from hf_estimator.commissioning.node import CommissioningNode
        return CommissioningNode(**kwargs)
    if name == "drive_bridge":
        from drive_bridge.bridge_node import InverterBridgeNode
        return InverterBridgeNode(link=link, controller=controller, estimator=estimator, **kwargs)
    raise GraphError(f"unknown node '{name}' (known: {', '.join(NODES)})")


@dataclass
class GraphResult(RunResult):
    processes: str = "composed"
    executor: str = "events"
    recording_error: str = None
    """Why the recording stopped early (it is closed as far as it was written), or None."""
    diagnostics: dict = None
    """Per node: its last /diagnostics status (level, message, values), the worst level of the run, its
    cumulative fault counters and fault messages."""
    node_faults: dict = None
    """{node: {"faults": {kind: count}, "messages": [...]}} of every node that reported a fault."""
    timing: dict = None
    """Behind a virtual inverter: how the graph kept pace with it
    (drive_tools.doubles.inverter_timing.timing_report)."""
    missing_samples: dict = None
    """{topic: samples never received within the final wait} of a run that ended (its log holds NaN
    there, a recording lacks them); empty when everything came."""
    scheduling: dict = None
    """{"applied": [...], "refused": [...]}: the real-time scheduling of the run (drive_common.runtime.realtime),
    one line each."""
    answer: dict = None
    """With the compiled answer: its thread's scheduling, the samples its ring handed over (``recorded``) and
    those it had no room for (``ring_overflow``, never silent: they are missing samples too)."""


def node_parameters(scenario_ref, estimator=None, duration_s=None, timeout_s=1.0, extra=None):
    """The parameter overrides the launcher gives every node."""
    parameters = {"scenario": str(resolve(scenario_ref)), "lockstep_timeout_s": float(timeout_s)}
    if estimator:
        parameters["estimator"] = estimator
    if duration_s:
        parameters["duration_s"] = float(duration_s)
    parameters.update(extra or {})
    return parameters


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
    paced: bool = False
    """With a link: the virtual inverter on its own clock at the sampling rate, never waiting."""
    inverter_apart: bool = False
    """With a link: the virtual inverter in a process of its own (as a real one is a device of its own) instead
    of a thread of the launcher's, paced or in lock-step: paced on this 2-core machine it makes the graph later,
    not earlier (docs/results.md, 2026-11-26), so it is a lever to measure, not the default."""
    inverter: Callable = VirtualInverter
    """With a link, the inverter on a thread of the launcher: the double that stands in for it, a class or
    factory called as VirtualInverter (a faulty one, drive_tools.doubles.faults, for a bench or test of how
    the drive degrades)."""


@dataclass(frozen=True)
class RealTime:
    """The graph's soft real-time levers (drive_common.runtime.realtime): ``rt_priority`` (SCHED_FIFO; 0: none)
    and ``cpus`` of its processes, ``workqueue_cpus``: the kernel's unbound workqueues there for the run,
    ``cpu_dma_latency_us``: the CPUs' wake-up latency limit for the run, ``hold_collector``: the garbage
    collector out of the sample path (off only to measure what it gives)."""

    rt_priority: int = 0
    cpus: frozenset = None
    workqueue_cpus: frozenset = None
    cpu_dma_latency_us: int = None
    hold_collector: bool = True


@dataclass(frozen=True)
class GraphOptions:
    """How a graph runs: its nodes composed in this process or ``processes`` of their own, the ``executor``,
    whether the launcher ``record``s a log, the lock-step wait ``timeout_s`` [s] of every node, how long the
    drives may take to start (``startup_timeout_s`` [s]), whether each controller takes its estimator's
    answers directly (``intra_process``, composed only), and its ``real_time`` levers."""

    processes: str = "composed"
    executor: str = "events"
    record: bool = True
    timeout_s: float = 1.0
    startup_timeout_s: float = 60.0
    intra_process: bool = False
    real_time: RealTime = RealTime()
    deadline_s: float = None
    """How long the run may take once started [s] (None: run_deadline_s's, from the scenarios' duration)."""
    answer: object = None
    """Behind a virtual inverter: drive_tools.runner.compiled_answer.AnswerOptions, the drive's whole
    answer in one compiled function off the interpreter's lock on a thread of its own, one step above the
    process's SCHED_FIFO priority unless its ``priority`` says (its estimator and controller are no nodes
    then: the bridge node publishes what the answer's ring hands over, and the log and recording are that
    ring's rows); None: the nodes answer."""


def launch(drive, options=GraphOptions(), progress=None):
    """Run one drive (a DriveSpec) through the ROS graph as ``options`` (GraphOptions) say; returns a
    GraphResult (metrics as for drive run). SIGINT/SIGTERM stop the run cleanly (children too) and return
    what was recorded, marked ``interrupted``; a bag being recorded is closed complete."""
    return launch_many([drive], options, progress)[0]


def launch_many(specs, options=GraphOptions(), progress=None):
    """Run several drives side by side in one graph (one namespace each); one GraphResult per spec. A
    scenario whose drive is a drive configuration file (``drive: FILE``) gives the estimator that file and
    no scenario (as on a robot); the plant and the controller's speed schedule take the experiment. With
    ``intra_process`` each controller takes its estimator's answers and currents directly, not over topics
    (they are still published for everyone else: the recorder, tools); it needs the nodes composed."""
    import rclpy
    from rclpy.node import Node
    from rclpy.signals import SignalHandlerOptions
    from rclpy.task import Future

    from drive_common.ros.node import make_executor

    from .scenario_driver import DriverSettings, ScenarioDriver

    processes, executor, timeout_s = options.processes, options.executor, options.timeout_s
    intra_process, real_time = options.intra_process, options.real_time
    if processes not in PROCESSES:
        raise GraphError(f"processes: must be one of {', '.join(PROCESSES)}, not '{processes}'")
    if intra_process and processes != "composed":
        raise GraphError("intra-process: the estimator hands its answers to the controller in one process; "
                         "it needs the nodes composed, not --processes separate")
    if len({spec.namespace for spec in specs}) < len(specs):
        raise GraphError("drives side by side need distinct namespaces")
    for spec in specs:
        check_namespace(spec.namespace)
    check_answer(specs, options)
    for spec in specs:
        if spec.link not in (None,) + LINKS:
            raise GraphError(f"unknown virtual link {spec.link!r} (known: {', '.join(LINKS)})")
        if spec.link == "can" and processes == "separate" and not spec.inverter_apart:
            raise GraphError("a virtual CAN bus (python-can's) lives in one process: it needs the nodes "
                             "composed, or a pty link")
    locks = []
    context = rclpy.Context()
    rclpy.init(context=context, signal_handler_options=SignalHandlerOptions.NO)
    try:
        for spec in specs:
            locks.append(NamespaceLock(spec.namespace))
        refuse_occupied(context, [spec.namespace for spec in specs])
    except GraphError:
        context.try_shutdown()
        for lock in locks:
            lock.release()
        raise
    try:
        recorders = [BagWriter(spec.bag) if spec.bag and options.answer is None else None for spec in specs]
        workdir = tempfile.TemporaryDirectory(prefix="drive_bridge_")
        inverters, answers = [], []
        children, nodes, drivers, drives, listeners = [], [], [], [], []
        polling = polled()
        polling.__enter__()
        ex = listening = None
        try:
            hop = hop_latency(HOP_ROUND_TRIPS_BESIDE_A_RUN) if any(spec.link for spec in specs) else None
            ex = make_executor(executor, context)
            for i, spec in enumerate(specs):
                parameters = node_parameters(spec.scenario, spec.estimator, spec.duration_s, timeout_s,
                                             spec.extra_parameters)
                scenario = scenario_from_parameters(all_parameters(parameters))
                if spec.link:
                    scenario = behind_an_inverter(scenario, MAX_BLOCK)
                    parameters["answer_periods"] = scenario.answer_periods
                drive = build_drive(scenario)
                protection_for_scenario(scenario, drive.commissioning, bus_measured=False)
                scheduled = {**parameters, "scenario_schedule": True}
                estimator = parameters
                if scenario.drive_file:
                    estimator = {**parameters, "drive_configuration": scenario.drive_file, "scenario": "",
                                 "duration_s": scenario.duration_s}
                plant = {**scheduled, "publish_clock": i == 0, "currents_readers": 1 if intra_process else 2}
                roles = {"pmsm_plant": plant, "hf_estimator": estimator, "foc_controller": scheduled}
                inverter = None
                if spec.link:
                    inverter, host_link = _virtual_inverter(scenario, parameters, spec, (workdir.name, i),
                                                            InverterOptions(command_wait_s=timeout_s), real_time)
                    inverters.append(inverter)
                    del roles["pmsm_plant"]
                    period = float(all_parameters(parameters)["diagnostics_period_s"])
                    timeouts = {"link_timeout_s": timeout_s, "command_timeout_s": timeout_s,
                                "diagnostics_period_s": period, "publish_clock": i == 0,
                                "block_samples": scenario.block_samples}
                    roles["drive_bridge"] = timeouts if processes == "composed" else {**_link_parameters(host_link),
                                                                                      **timeouts}
                made, answer = {}, None
                if options.answer is not None:
                    answer, bridge_node = _compiled_answer(drive, host_link, (context, spec.namespace),
                                                           roles.pop("drive_bridge"), options)
                    del roles["hf_estimator"], roles["foc_controller"]
                    made["drive_bridge"] = bridge_node
                    nodes.append(bridge_node)
                    answers.append(answer)
                for role, role_parameters in roles.items():
                    if processes == "composed":
                        partners = {"estimator": made.get("hf_estimator"), "controller": made.get("foc_controller")}
                        made[role] = make_node(role, context, spec.namespace, role_parameters,
                                               link=host_link if spec.link else None,
                                               inputs_handed=intra_process and bool(spec.link),
                                               **(partners if intra_process else {}))
                        nodes.append(made[role])
                    else:
                        children.append((role, _spawn(role, spec.namespace, role_parameters, executor, real_time)))
                driver_node = Node("drive_launcher", context=context, namespace=spec.namespace)
                nodes.append(driver_node)
                listener = Node("drive_recorder", context=context, namespace=spec.namespace)
                listeners.append(listener)
                host_bridge = made["drive_bridge"].bridge if spec.link and processes == "composed" else None
                host_bridge = answer or host_bridge
                if host_bridge is not None and spec.paced and spec.inverter_apart:
                    inverter.hear_writes_of(answer.bridge if answer is not None else host_bridge)
                elif host_bridge is not None and spec.paced:
                    inverter.hear_host_writes(host_bridge.written_at)
                settings = DriverSettings(options.record, 0.1 if processes == "composed" else 0.5,
                                          options.startup_timeout_s, intra_process)
                driver = ScenarioDriver(driver_node, scenario, settings, progress if i == 0 else None,
                                        None if answer else recorders[i], inverter, listener, host_bridge)
                if answer is not None:
                    driver.publish_answered = made["drive_bridge"].publish_answered
                driver.done = Future()
                drives.append(drive)
                drivers.append(driver)
            for node in nodes:
                ex.add_node(node)
            all_done = Future()
            watcher = nodes[-1].create_timer(0.05, lambda: _watch(drivers, children, all_done))
            for driver in drivers:
                driver.start_allowed = False
            while not all_done.done() and not all(driver.ready or driver.done.done() for driver in drivers):
                ex.spin_until_future_complete(all_done, timeout_sec=0.05)
            with real_time_held(real_time) as scheduling:
                if listeners_apart(scheduling):
                    listening = Listening(make_executor(executor, context), listeners)
                    listening.start()
                else:
                    for listener in listeners:
                        ex.add_node(listener)
                for driver in drivers:
                    driver.start_allowed = True
                deadline = time.monotonic() + run_deadline_s([driver.scenario for driver in drivers], options)
                while not all_done.done():
                    ex.spin_until_future_complete(all_done, timeout_sec=min(1.0, max(deadline - time.monotonic(), 0.0)))
                    if time.monotonic() > deadline:
                        for driver in drivers:
                            driver.finish(f"the run did not end within {run_deadline_s([driver.scenario], options):g} "
                                          f"s of its start (deadline_s; its inverter or answer never finished): "
                                          f"stopped, the machine's settings given back")
                if listening:
                    listening.stop()
            nodes[-1].destroy_timer(watcher)
            _stop_answers(answers)
            results = [_result(driver, drive, options, requested(), hop)
                       for driver, drive in zip(drivers, drives)]
        finally:
            polling.__exit__(None, None, None)
            _stop_answers(answers)
            _stop_children([child for _, child in children])
            if listening is not None:
                listening.stop()
            tear_down(ex, nodes + listeners, context, inverters, workdir)
            recording_errors = [_close(recorder) for recorder in recorders]
        for i, (result, drive) in enumerate(zip(results, drives)):
            if options.answer is not None and specs[i].bag:
                recording_errors[i] = _record_answered(result, specs[i], drive)
        for result, error in zip(results, recording_errors):
            result.recording_error = error
            thread = (result.answer or {}).get("scheduling", {"applied": [], "refused": []})
            result.scheduling = {key: scheduling[key] + thread[key] for key in scheduling}
        return results
    finally:
        for lock in locks:
            lock.release()


@contextlib.contextmanager
def real_time_held(real_time):
    """The ``real_time`` levers (RealTime) held for a run: SCHED_FIFO and affinity, the unbound workqueues, the
    CPUs' wake-up latency, the collector out of the sample path; yields {"applied": [...], "refused": [...]},
    one line each. `drive launch` and `drive up` run their graphs inside it."""
    with real_time_scheduled(real_time.rt_priority, real_time.cpus) as scheduling, \
            unbound_work_on(real_time.workqueue_cpus) as work, \
            cpu_wakeup_latency_held(real_time.cpu_dma_latency_us) as idle, \
            collector_held() if real_time.hold_collector else contextlib.nullcontext():
        yield {key: scheduling[key] + work[key] + idle[key] for key in scheduling}


def listeners_apart(scheduling):
    """Whether the listeners (recorder, /diagnostics) spin apart from the drive (Listening): where the drive
    got SCHED_FIFO."""
    return any(line.startswith("SCHED_FIFO") for line in scheduling["applied"])


class Listening:
    """Where the drive runs SCHED_FIFO, the launcher's listeners (what it records, /diagnostics) spun by their own
    executor on a thread of their own, below the drive's SCHED_FIFO threads (SCHED_OTHER): what is recorded
    never waits in, nor delays, the queue of the drive's own callbacks. Without it the listeners share the
    drive's executor: two threads of one interpreter at the same priority on two CPUs made the graph later
    (docs/results.md, 2026-11-26)."""

    def __init__(self, executor, nodes):
        import threading
        self.executor, self.stopped = executor, threading.Event()
        for node in nodes:
            executor.add_node(node)
        self.thread = threading.Thread(target=self.spin, name="drive_recorder", daemon=True)

    def start(self):
        self.thread.start()

    def spin(self):
        import os
        try:
            os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
        except (OSError, AttributeError):
            pass
        while not self.stopped.is_set():
            self.executor.spin_once(timeout_sec=0.05)

    def stop(self):
        """Stop spinning (every message taken so far handled), then the executor."""
        if not self.stopped.is_set():
            self.stopped.set()
            if self.thread.is_alive():
                self.thread.join(5.0)
            self.executor.shutdown()


def run_deadline_s(scenarios, options):
    """How long a graph's run may take once started, with the machine's settings held (SCHED_FIFO, the
    workqueue mask): ``options.deadline_s``, else the longest scenario's duration × RUN_DEADLINE_FACTOR +
    RUN_DEADLINE_MARGIN_S (a lock-step run slower than real time included). Past it the run stops: nothing
    waits at real-time priority for what may never come."""
    if options.deadline_s is not None:
        return options.deadline_s
    return max(scenario.duration_s for scenario in scenarios) * RUN_DEADLINE_FACTOR + RUN_DEADLINE_MARGIN_S


def check_answer(specs, options):
    """GraphError unless ``options.answer`` can answer every drive of ``specs``: the compiled answer needs the
    nodes composed and a virtual inverter behind a link (it reads and writes the link's descriptor)."""
    if options.answer is None:
        return
    if options.processes != "composed":
        raise GraphError("the compiled answer runs in the drive's process: it needs the nodes composed, not "
                         "--processes separate")
    for spec in specs:
        if not spec.link:
            raise GraphError("the compiled answer reads and writes an inverter's link: it needs --link pty|can, "
                             "not the plant node")


def _compiled_answer(drive, host_link, where, bridge_parameters, options):
    """(the compiled answer of ``drive`` on ``host_link`` as ``options.answer`` says, the bridge node that
    publishes what it answered), ``where``: (context, namespace). Its thread runs one step above the process's
    SCHED_FIFO priority (none without it) unless ``options.answer.priority`` says: no thread of this process
    delays it."""
    from drive_bridge.bridge_node import InverterBridgeNode
    from drive_common.ros.node import parameter_overrides
    from drive_tools.runner.compiled_answer import answer_of
    context, namespace = where
    node = InverterBridgeNode(link=host_link, answered_elsewhere=True, context=context, namespace=namespace,
                              parameter_overrides=parameter_overrides(bridge_parameters))
    scenario = drive.scenario
    rt_priority = options.real_time.rt_priority
    answer_options = options.answer
    if not answer_options.priority and rt_priority:
        answer_options = answer_options._replace(priority=min(rt_priority + 1, 99))
    answer = answer_of(drive, node.bridge, answer_options)
    node.answered_by(answer.counters, scenario.T_s, scenario.motor.nameplate.n_p)
    return answer, node


def _stop_answers(answers):
    """Stop the compiled answers (each notices within its poll, 50 ms) and wait for them and their readers."""
    for answer in answers:
        answer.stop()
    for answer in answers:
        answer.join(2.0)


def _record_answered(result, spec, drive):
    """Write the recording of ``drive`` (runner.Drive) that a compiled answer ran from its log (the rows its
    ring handed over, as the graph records them: drive_tools.bags.writer.write_run_bag); what went wrong, or
    None."""
    from drive_tools.bags.writer import write_run_bag
    from hf_estimator.interface import contract_injection
    facts = drive.estimator.facts()
    try:
        write_run_bag(dataclasses.replace(result, injection=contract_injection(facts, result.scenario.injection)),
                      spec.bag, spec.namespace)
    except (BagWriteError, OSError) as error:
        return str(error)
    return None


ACKNOWLEDGE_WAIT_S = 2.0
"""At the end of a graph, how long its publishers wait at most for slow reliable readers (an outside client, a
recorder in another process) to acknowledge what was published: what a reader was promised (its topic's depth) is
delivered before the publishers go."""


def tear_down(ex, nodes, context, inverters, workdir):
    """End a graph in order: the virtual inverters stop, the executor shuts down, every reader is given what
    was published to it (acknowledged, at most ACKNOWLEDGE_WAIT_S) before the nodes are destroyed, the context
    ends, then the inverters' links close and the working directory goes."""
    from drive_common.ros.node import acknowledged
    for inverter in inverters:
        inverter.stop()
    if ex is not None:
        ex.shutdown()
    acknowledged(nodes, ACKNOWLEDGE_WAIT_S)
    for node in nodes:
        node.destroy_node()
    context.try_shutdown()
    for inverter in inverters:
        inverter.endpoint.close()
    workdir.cleanup()


def _close(recorder):
    """Close a recording; what went wrong with it (a full disk), or None."""
    if recorder is None:
        return None
    try:
        recorder.close()
    except BagWriteError as error:
        return str(error)
    return None


def _result(driver, drive, options, interrupted, hop=None):
    """The GraphResult of one drive (``drive``: the runner's composition of the same scenario, for its
    current limit and commissioning record) run as ``options`` (GraphOptions) say."""
    from .scenario_driver import ANSWER_RING
    scenario = driver.scenario
    if driver.inverter is not None:
        driver.inverter.stop()
        driver.inverter.join(2.0)
    if driver.error and not interrupted:
        raise GraphError(f"{driver.node.get_namespace()} ({scenario.name}): {driver.error}")
    end = driver.finished_at or time.monotonic()
    wall = end - driver.started_at if driver.started_at else 0.0
    written_at = driver.host_bridge.written_at if driver.host_bridge else None
    log = driver.log[:driver.last_sample + 1] if options.record else driver.log[:0]
    scenario = cut(scenario, driver.last_sample + 1)
    return GraphResult(scenario, scenario.estimator, log, wall, drive.controller.i_max_A,
                       commissioning=drive.commissioning, estimator_facts=drive.estimator.facts(),
                       speed_ramp_rad_s2=drive.controller.speed_ramp_rad_s2,
                       processes=options.processes, executor=options.executor,
                       interrupted=interrupted,
                       diagnostics=dict(driver.diagnostics), node_faults=driver.faults(),
                       missing_samples={} if interrupted else driver.missing_samples(),
                       timing=in_hops(timing_report(driver.inverter, scenario.T_s, written_at), hop)
                       if driver.inverter else None,
                       answer={"by": "compiled", "scheduling": driver.answer.scheduling,
                               "recorded": driver.received[ANSWER_RING], "ring_overflow": driver.answer.overflow}
                       if driver.answer else None)


def _virtual_inverter(scenario, parameters, spec, where, waits, real_time=RealTime()):
    """The virtual inverter of ``spec``'s link for ``scenario`` (not yet running) and the host's end of its link,
    ``where``: (working directory, drive id). Paced (``spec.paced``), it runs on its own clock, else it waits
    for each of the graph's commands as ``waits`` (InverterOptions: ``command_wait_s`` as long as a plant node
    would, ``disabled_wait_s`` while the host keeps PWM disabled) say. Apart
    (``spec.inverter_apart``): in a process of its own, as a real inverter is a device of its own (on the CPUs
    ``real_time.cpus`` leave, if any; CAN then on a cable between processes, drive_bridge.can_cable). Not apart,
    it is ``spec.inverter`` (a double) on a thread of the host's process."""
    import os

    from drive_bridge.inverter_link import CanLink, SerialLink
    from drive_tools.doubles.inverter_process import InverterProcess, InverterProcessError
    from drive_tools.doubles.virtual_links import make_links
    workdir, drive_id = where
    options = dataclasses.replace(waits, rate_Hz=1.0 / scenario.T_s if spec.paced else None, drive_id=drive_id)
    if not spec.inverter_apart:
        endpoint, host_link = make_links(spec.link, workdir, drive_id)
        return spec.inverter(scenario, endpoint, options), host_link
    if spec.inverter is not VirtualInverter:
        raise GraphError("a double of the virtual inverter runs on a thread of the launcher, not apart")
    path = Path(workdir) / (f"inverter{drive_id}" if spec.link == "pty" else f"can_cable{drive_id}")
    cpus = real_time.cpus
    others = set(os.sched_getaffinity(0)) - set(cpus) if cpus else None
    try:
        inverter = InverterProcess(parameters, spec.link, path, options, real_time.rt_priority, others or None)
    except InverterProcessError as error:
        raise GraphError(str(error)) from None
    host_link = SerialLink(str(path)) if spec.link == "pty" else CanLink(str(path), drive_id, "cable")
    return inverter, host_link


def _link_parameters(host_link):
    """The drive_bridge node's link parameters for ``host_link`` (a node in a process of its own)."""
    if hasattr(host_link, "port"):
        return {"link": "serial", "port": host_link.port}
    return {"link": "can", "can_channel": host_link.channel, "can_interface": host_link.interface or "",
            "drive_id": host_link.drive_id}


def _watch(drivers, children, all_done):
    for driver in drivers:
        if requested():
            driver.finish("interrupted")
        processes = list(children)
        inverter_process = getattr(driver.inverter, "process", None)
        if inverter_process is not None:
            processes.append(("virtual_inverter", inverter_process))
        for role, child in processes:
            if child.poll() is not None and role not in driver.exited and not driver.done.done():
                driver.exited[role] = child.returncode
                driver.finish()
    if all(driver.done.done() for driver in drivers) and not all_done.done():
        all_done.set_result(True)


def _spawn(name, namespace, parameters, executor, real_time=RealTime()):
    cpus = real_time.cpus
    scheduling = ["--rt-priority", str(real_time.rt_priority)] + (["--cpus", ",".join(map(str, sorted(cpus)))]
                                                                  if cpus else [])
    args = [sys.executable, "-m", NODES[name], "--executor", executor, *scheduling, "--ros-args", "-r",
            f"__ns:={namespace}"]
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


def missing_samples_line(missing):
    """One line naming the topics whose samples never reached the launcher (its log and recording lack
    them), or None. With no node fault to explain them (a node that missed a sample never published
    its answer), they were lost on the way: `drive launch` exits 4, as for a recording cut short."""
    from .scenario_driver import FINAL_WAIT_S
    if not missing:
        return None
    topics = ", ".join(f"{topic} {count}" for topic, count in missing.items())
    return (f"samples never received within {FINAL_WAIT_S:g} s of the run's end (the log and any recording "
            f"lack them): {topics}")
