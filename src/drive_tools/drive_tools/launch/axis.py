"""One axis of a robot as a managed (lifecycle) node, ``NAMESPACE/drive_axis`` (docs/robot.md): configure opens the
axis's link (the drive_bridge node; with a virtual device, the virtual inverter behind it) with the inverter
disabled, zero volts, and composes the estimator and the controller in this process; activate arms them: a start-up,
then commands. Armed, the axis answers each telemetry block either compiled whole (``answer: compiled``, the default:
drive_tools.launch.axis_answer, the link handed to a loop off the interpreter's lock on a thread of its own) or by its
nodes on the bridge's link thread (``answer: nodes``: the configuration of `drive launch --intra-process`,
docs/ros-graph.md "Real time"). Deactivate disarms (zero volts, the inverter told to switch off); cleanup closes the
link. The standard lifecycle services (``change_state``, ``get_state`` ...) drive it."""
import threading
import time

from rclpy.lifecycle import LifecycleNode, TransitionCallbackReturn

from drive_bridge.inverter_protocol import MAX_BLOCK
from drive_common.config.drive_config import ScenarioError
from drive_common.config.scenario import behind_an_inverter, load_drive_configuration, load_scenario, with_drive
from drive_common.contract.errors import DriveError
from drive_common.contract.stamps import sample_at, stamp_parts

from .launcher import DriveSpec, RealTime, make_node

BRIDGE_COMMAND_TIMEOUT_S = 0.1
"""No command from the armed drive for this long: the bridge tells the inverter to switch off."""
LOCKSTEP_TIMEOUT_S = 10.0
"""The estimator's wait for a command it misses (the controller in this process answers at once), and a virtual
inverter's in lock-step (``paced: false``) while the drive commands: the simulation waits for the drive, so its
outcome does not depend on the machine's pace. The wait guards against a dead drive, not a slow one: at 1 s a
machine running two test suites at once held a drive longer and its axis stopped on a lost link (stop 63)."""
TIMING_REPORT_WAIT_S = 5.0
"""A virtual inverter apart (its own process) is stopped and its report waited for this long at most."""
ARM_WAIT_S = 30.0
"""Activated with the compiled answer: the estimator and the controller must be ready (the controller's core built from
the estimator's facts, a spin or two) within this [s], or the axis is not armed (the loop's first compile after an
edit included)."""
DISABLED_WAIT_S = 0.05
"""A virtual inverter in lock-step waits this long for each command while the drive does not command (before it is
armed; disarmed, its bridge says CONTROL disable): its simulation then runs at 1/50 of real time."""


def homing_parameters(spec):
    """The controller's homing parameters of an axis (robot_file.AxisSpec): its direction and offset turned into the
    motor's sign; none where the axis has no homing."""
    h = spec.homing
    if h is None:
        return {}
    return {"homing_method": h["method"], "homing_direction": spec.sign * h["direction"],
            "homing_speed_rad_s": h["speed_rad_s"] or 0.0, "homing_current_A": h["current_A"] or 0.0,
            "homing_torque_Nm": h["torque_Nm"] or 0.0, "homing_offset_rad": spec.sign * h["offset_rad"],
            "homing_backoff_rad": h["backoff_rad"], "homing_timeout_s": h["timeout_s"]}


class HandOver:
    """Between an axis's bridge and its estimator and controller: to the bridge it is the estimator its link thread
    hands each block to and the controller whose commands it takes. Disarmed (inactive), nothing is handed on and
    nothing commanded; armed, once the estimator answers and the controller offers commands, the drive joins the
    inverter's samples at the next block and answers from there. The armed drive counts its samples from that block
    (sample 0 of its start-up, whose phases are timed in samples from the run's first: EstimatorNode.join_at,
    ControllerNode.join_at): the hand-over shifts the stamps it hands on by the block's sample number, and the
    commands' back; what the drive's nodes publish is stamped in the inverter's count (DriveNode.stamp_origin), as
    the bridge's topics are."""

    inputs_handed = True

    def __init__(self):
        self.sample_lock = threading.Lock()
        """Held by the bridge's link thread around a block, and while the drive is armed or disarmed."""
        self.estimator = self.controller = None
        self.origin = None
        """The inverter's sample the armed drive counts from (None: not joined yet)."""
        self.bridge_takes = None
        """The bridge's ``take_commands`` (registered by the bridge: ``hand_commands_to``)."""

    @property
    def sensored(self):
        return self.estimator is not None and self.estimator.sensored

    def hand_commands_to(self, take_commands):
        self.bridge_takes = take_commands

    def take_commands(self, k, u_alpha, u_beta):
        """The controller's commands of its sample k: the bridge's of the inverter's sample k + origin."""
        self.bridge_takes(k + self.origin, u_alpha, u_beta)

    def arm(self, estimator, controller):
        with self.sample_lock:
            self.estimator, self.controller, self.origin = estimator, controller, None

    def disarm(self):
        with self.sample_lock:
            self.estimator = self.controller = None

    def handed(self, sec, nanosec):
        """(the estimator, the stamp in the drive's count) to hand the sample (block) stamped (sec, nanosec) on
        with, joined there if it is the first; None while disarmed or not ready."""
        e, c = self.estimator, self.controller
        if e is None or not e.answering or c.voltage_pub is None:
            return None
        k = sample_at(sec, nanosec, e.T_s)
        if self.origin is None:
            self.origin = k
            with e.sample_lock:
                e.join_at(0)
                c.join_at(0)
                e.stamp_origin = c.stamp_origin = k
        return e, stamp_parts(k - self.origin, e.T_s)

    def hand(self, take, sec, nanosec, values):
        """Hand the estimator's ``take`` (its method's name) the sample (block) stamped (sec, nanosec) and its
        ``values``, in the drive's count; nothing while disarmed or not ready."""
        handed = self.handed(sec, nanosec)
        if handed is not None:
            e, stamp = handed
            with e.sample_lock:
                getattr(e, take)(*stamp, *values)

    def take_currents(self, sec, nanosec, *currents):
        self.hand("take_currents", sec, nanosec, currents)

    def take_rotor_state(self, sec, nanosec, *values):
        self.hand("take_rotor_state", sec, nanosec, values)

    def on_zero_voltage(self, sec, nanosec, *values):
        self.hand("on_zero_voltage", sec, nanosec, values)


class AxisNode(LifecycleNode):
    """The managed node of one axis (``spec``: robot_file.AxisSpec, the ``index``-th of its robot), composing its
    drive's nodes into ``executor`` (the robot's, in ``context``); ``workdir``: where a virtual link's files go;
    ``recording`` (robot_recording.RobotRecording or None) hears each of its nodes before it publishes."""

    def __init__(self, spec, index, context, executor, workdir, real_time=None, recording=None):
        super().__init__("drive_axis", context=context, namespace=spec.namespace)
        self.spec, self.index, self.executor, self.workdir = spec, index, executor, workdir
        self.real_time = real_time or RealTime()
        self.recording = recording
        self.handover = HandOver()
        self.answer = None
        """The armed axis's compiled answer (axis_answer.AxisAnswer), or None."""
        self.arming = None
        """The thread that arms the compiled answer once the nodes are ready (None: not arming)."""
        self.armed = False
        """Activated with the compiled answer (arming or answering)."""
        self.warming = None
        """The thread that loads the compiled answer's loop while the axis is inactive (None: none)."""
        self.bridge = self.inverter = self.estimator = self.controller = None
        self.drive = None
        self.error = ""
        """Why the last transition failed, or empty."""

    def _LifecycleNodeMixin__on_change_state(self, request, response):
        """The `change_state` service: rclpy's, except that a transition the current state does not have (cleanup
        from active) answers ``success`` false instead of raising in the executor, which ended the process."""
        from rclpy._rclpy_pybind11 import RCLError
        try:
            return super()._LifecycleNodeMixin__on_change_state(request, response)
        except RCLError as error:
            reason = str(error).split(", at ")[0]
            self.error = f"transition {request.transition.id or request.transition.label} refused: {reason}"
            self.get_logger().error(f"{self.spec.joint}: {self.error}")
            response.success = False
            return response

    def fail(self, error):
        self.error = str(error)
        self.get_logger().error(f"{self.spec.joint}: {self.error}")
        return TransitionCallbackReturn.FAILURE

    def on_configure(self, state):
        """The drive configuration loaded, the link open with the inverter disabled, the estimator and the controller
        built (the commissioning file loaded: a refusal names it)."""
        spec = self.spec
        try:
            self.drive = drive = load_drive_configuration(spec.drive, f"{spec.joint}: drive")
            n = drive.block_samples
            if n > MAX_BLOCK:
                raise ScenarioError(f"{spec.drive}: block_samples: {n}: an inverter sends at most {MAX_BLOCK}")
            host_link = self.open_link(drive)
            if spec.answer == "compiled":
                from drive_bridge.compiled_bridge import link_kind
                try:
                    link_kind(host_link)
                except ValueError as error:
                    host_link.close()
                    raise ValueError(f"{spec.joint}: answer: compiled: {error}; or answer: nodes") from None
        except (DriveError, ValueError, OSError) as error:
            return self.fail(error)
        lock_step = spec.link == "virtual" and not spec.paced
        wait = LOCKSTEP_TIMEOUT_S if lock_step else 0.0
        timeouts = {"link_timeout_s": spec.link_timeout_s, "answer_wait_s": wait,
                    "command_timeout_s": BRIDGE_COMMAND_TIMEOUT_S + wait, "publish_clock": False, "block_samples": n}
        self.bridge = make_node("drive_bridge", self.context, spec.namespace, timeouts, link=host_link,
                                controller=self.handover, estimator=self.handover)
        self.executor.add_node(self.bridge)
        if self.recording is not None:
            self.recording.heard(self.bridge)
        if self.inverter is not None:
            if spec.paced and spec.inverter_apart:
                self.inverter.hear_writes_of(self.bridge.bridge)
            elif spec.paced:
                self.inverter.hear_host_writes(self.bridge.bridge.written_at)
            else:
                self.inverter.hear_host_caught_up(self.caught_up)
            self.inverter.start()
        refused = self.compose()
        if refused:
            self.close()
            return self.fail(refused)
        self.error = ""
        return TransitionCallbackReturn.SUCCESS

    def open_link(self, drive):
        """The host's end of the axis's link; with a virtual device, the virtual inverter (paced at the drive's
        rate, not started yet) runs the scenario's machine at the other end."""
        from drive_bridge.inverter_link import CanLink, SerialLink
        from drive_tools.doubles.virtual_inverter import InverterOptions

        from .launcher import _virtual_inverter, node_parameters
        spec = self.spec
        if spec.link == "serial":
            return SerialLink(spec.port, spec.baudrate)
        if spec.link == "can":
            return CanLink(spec.can_channel, spec.drive_id, spec.can_interface or None)
        scenario = behind_an_inverter(with_drive(load_scenario(spec.scenario), drive), MAX_BLOCK)
        where = DriveSpec(scenario=spec.scenario, namespace=spec.namespace, link=spec.virtual_link, paced=spec.paced,
                          inverter_apart=spec.inverter_apart)
        waits = InverterOptions(command_wait_s=LOCKSTEP_TIMEOUT_S, disabled_wait_s=DISABLED_WAIT_S)
        parameters = node_parameters(spec.scenario) if spec.inverter_apart else {}
        self.inverter, host_link = _virtual_inverter(scenario, parameters, where, (self.workdir, self.index), waits,
                                                     self.real_time)
        return host_link

    def node_parameters(self):
        """The estimator's and the controller's parameters: the drive configuration, no scenario; the delay of
        blocks behind an inverter; the joint's name and how it takes commands."""
        spec, n = self.spec, self.drive.block_samples
        drive = {"drive_configuration": spec.drive, "scenario": "", "lockstep_timeout_s": LOCKSTEP_TIMEOUT_S,
                 "block_samples": n, "answer_periods": n + 1 if n > 1 else 0}
        commands = {"joint_name": spec.joint, "command_timeout_s": spec.command_timeout_s,
                    "hold_timeout_s": spec.hold_timeout_s, "brake": spec.brake,
                    "stop_deceleration_rad_s2": spec.stop_deceleration_rad_s2 or 0.0,
                    "velocity_limit_rad_s": spec.velocity_limit_rad_s or 0.0,
                    "effort_limit_Nm": spec.effort_limit_Nm or 0.0, **homing_parameters(spec)}
        return drive, {**drive, **commands}

    def compose(self):
        """The estimator and the controller built (not armed): their drive configuration loaded, their kernels
        warmed up, the controller's core built once the estimator's drive_config reaches it (a spin later). Why
        not, or None."""
        drive, controller = self.node_parameters()
        estimator = make_node("hf_estimator", self.context, self.spec.namespace, drive, inputs_handed=True)
        if not estimator.configured:
            estimator.destroy_node()
            return f"the estimator refused its configuration: {estimator.health.latched}"
        self.estimator = estimator
        self.controller = make_node("foc_controller", self.context, self.spec.namespace, controller,
                                    estimator=estimator)
        self.controller.hand_commands_to(self.handover.take_commands)
        self.controller.index_from(self.index_input)
        for node in (estimator, self.controller):
            self.executor.add_node(node)
        if self.recording is not None:
            self.recording.heard(estimator, self.controller)
        if self.spec.answer == "compiled":
            self.warming = threading.Thread(target=self.warm_compiled, name=f"{self.spec.joint}_warming", daemon=True)
            self.warming.start()
        return None

    def ready(self):
        """The controller's core is built (from the estimator's facts, a spin or two after compose) and it answers."""
        e, c = self.estimator, self.controller
        return e is not None and c is not None and e.answering and c.params and c.voltage_pub is not None

    def wait_ready(self, until):
        """Wait until ready() while ``until()`` holds, at most ARM_WAIT_S; whether it is ready."""
        deadline = time.monotonic() + ARM_WAIT_S
        while until() and not self.ready():
            if time.monotonic() > deadline:
                return False
            time.sleep(0.01)
        return self.ready()

    def warm_compiled(self):
        """While inactive: the compiled answer's loop loaded for the nodes just composed (its first compile after an
        edit takes tens of seconds; arming then takes none)."""
        from .axis_answer import warm_axis_answer
        e, c, bridge = self.estimator, self.controller, self.bridge
        if self.wait_ready(lambda: self.estimator is e):
            try:
                warm_axis_answer(bridge, e, c)
            except Exception as error:
                self.error = f"{self.spec.joint}: the compiled answer could not be loaded: {error}"
                self.get_logger().error(self.error)

    def index_input(self):
        """(whether the inverter has an index input, by its HELLO; the parity of its index pulses now, by its
        status)."""
        from drive_bridge.inverter_protocol import HELLO_INDEX_INPUT, INDEX_TOGGLE
        b = self.bridge.bridge if self.bridge is not None else None
        if b is None or b.hello is None:
            return False, 0
        return bool(b.hello.flags & HELLO_INDEX_INPUT), int(bool(b.status & INDEX_TOGGLE))

    def drive_nodes(self):
        """The axis's drive nodes now (bridge, estimator, controller: those that exist)."""
        return [node for node in (self.bridge, self.estimator, self.controller) if node is not None]

    def on_activate(self, state):
        """Armed: the drive joins the inverter's samples as soon as it is ready (its start-up, then its commands;
        zero speed until one comes)."""
        self.error = ""
        if self.spec.answer == "compiled":
            self.armed = True
            self.arming = threading.Thread(target=self.arm_compiled, name=f"{self.spec.joint}_arming", daemon=True)
            self.arming.start()
        else:
            self.handover.arm(self.estimator, self.controller)
        return TransitionCallbackReturn.SUCCESS

    def arm_compiled(self):
        """Once the controller's core is built and the estimator answers: the link handed to the compiled answer,
        started. Not within ARM_WAIT_S, or a failed build: said on the axis's error, the axis left disarmed."""
        from .axis_answer import AxisAnswer
        e, c = self.estimator, self.controller
        if self.warming is not None:
            self.warming.join()
        ready = self.wait_ready(lambda: self.armed)
        if not self.armed:
            return
        if not ready:
            self.error = f"{self.spec.joint}: the drive was not ready within {ARM_WAIT_S:g} s; not armed"
            self.get_logger().error(self.error)
            return
        priority = min(self.real_time.rt_priority + 1, 99) if self.real_time.rt_priority else 0
        self.bridge.hand_link_over()
        try:
            answer = AxisAnswer(self.bridge, e, c, priority)
        except Exception as error:
            self.bridge.take_link_back()
            self.error = f"{self.spec.joint}: the compiled answer could not be built: {error}"
            self.get_logger().error(self.error)
            return
        if self.armed:
            self.answer = answer
            answer.start()
        else:
            self.bridge.take_link_back()

    def answer_failure(self):
        """Why the armed axis's compiled answer is not answering (it could not be armed, its loop or its reader
        raised), in one line; None while it answers, is being armed, or the axis is not armed with it."""
        if not self.armed:
            return None
        answer = self.answer
        if answer is None:
            arming = self.arming
            return self.error or None if arming is not None and not arming.is_alive() else None
        if answer.error is not None:
            return f"its compiled answer's reader stopped ({answer.error!r})"
        if answer.answer.error is not None:
            return f"its compiled answer stopped ({answer.answer.error!r})"
        return None

    def caught_up(self, k):
        """Whether the drive has done all it does with the inverter's sample k (the compiled answer's reader has handed
        its row on); always, without a compiled answer (the nodes' answer is written once they are done)."""
        answer = self.answer
        return answer is None or answer.caught_up(k)

    @property
    def active(self):
        return self.handover.estimator is not None or self.armed

    def stop_answering(self):
        """Nothing answers the inverter any more (the bridge's link thread reads it again): its commands stop."""
        self.handover.disarm()
        self.armed = False
        if self.arming is not None:
            self.arming.join(ARM_WAIT_S + 5.0)
            self.arming = None
        if self.answer is not None:
            self.answer.stop()
            self.answer = None
            self.bridge.take_link_back()

    def on_deactivate(self, state):
        """Disarmed (zero volts, the inverter told), a fresh estimator and controller built for the next
        activation (a new start-up: the angle is not known after zero volts)."""
        self.disarm("deactivated")
        refused = self.compose()
        return self.fail(refused) if refused else TransitionCallbackReturn.SUCCESS

    def disarm(self, why):
        """Zero volts: nothing handed on, the inverter told to switch off (its safe state)."""
        self.stop_answering()
        if self.bridge is not None:
            self.bridge.bridge.safe_state(f"axis {why}")
        self.discard()

    def discard(self):
        """The estimator and the controller gone (disarmed first)."""
        for node in (self.controller, self.estimator):
            if node is not None:
                self.executor.remove_node(node)
                node.destroy_node()
        self.controller = self.estimator = None

    def on_cleanup(self, state):
        self.close()
        return TransitionCallbackReturn.SUCCESS

    def close(self):
        """The estimator and the controller gone, the link closed (the virtual inverter stopped first)."""
        self.discard()
        if self.inverter is not None:
            self.inverter.stop()
            self.inverter.join(1.0)
        if self.bridge is not None:
            self.executor.remove_node(self.bridge)
            self.bridge.destroy_node()
            self.bridge = None
        if self.inverter is not None:
            self.inverter.endpoint.close()
            self.inverter = None

    def on_shutdown(self, state):
        self.safe_state("shut down")
        return TransitionCallbackReturn.SUCCESS

    def on_error(self, state):
        self.safe_state("in error")
        return TransitionCallbackReturn.SUCCESS

    def safe_state(self, why):
        """From any state: zero volts, the inverter told, the link closed."""
        self.disarm(why)
        self.close()

    def inverter_off(self):
        """Whether the inverter says its PWM is off (its last telemetry's status), or its link is closed."""
        from drive_bridge.inverter_protocol import PWM_OFF
        b = self.bridge.bridge if self.bridge is not None else None
        return b is None or not b.open or b.lost or bool(b.status & PWM_OFF)

    def link_lost(self):
        """Whether the axis's link, up before, is lost (no telemetry for the bridge's link timeout)."""
        b = self.bridge.bridge if self.bridge is not None else None
        return b is not None and b.lost and b.counters["samples"] > 0

    def inverter_timing(self):
        """How the armed drive kept pace with its virtual inverter, paced (drive_tools.doubles.inverter_timing, from
        its first command in time on); None for a real inverter or a lock-step one."""
        from drive_tools.doubles.inverter_timing import timing_report
        if None in (self.inverter, self.bridge) or not self.spec.paced or not hasattr(self.inverter, "counters"):
            return None
        if self.spec.inverter_apart:
            self.inverter.join(TIMING_REPORT_WAIT_S)
        t = timing_report(self.inverter, self.drive.T_s, self.bridge.bridge.written_at)
        return {key: t[key] for key in ("periods_since_start", "late_fraction_since_start", "watchdog_trips",
                                        "answer_p50_us", "answer_p99_us", "overruns")}

    def report(self):
        """What the axis did: its lifecycle state, the bridge's counters, the virtual inverter's state."""
        report = {"joint": self.spec.joint, "namespace": self.spec.namespace, "error": self.error}
        if self.bridge is not None:
            b = self.bridge.bridge
            report.update(link="lost" if b.lost else "up", safe_state_sent=b.counters["safe_state"],
                          samples=b.counters["samples"], before_hello=b.counters["before_hello"],
                          inverter_off=self.inverter_off())
        if self.inverter is not None and hasattr(self.inverter, "enabled"):
            report["inverter_enabled"] = self.inverter.enabled
        return report
