"""The ``foc_controller`` node: the cascade controller core over topics.

For sample k it joins `currents`, `rotor_estimate`, `injection` and `estimator_state` stamped k (the
state code gates torque: no torque before the estimator's start-up reports tracking), runs the core with
the latest `speed_command` and `torque_feedforward` (the robot's expected torque, N·m, added to the speed
loop's output), and answers `voltage_command`(k). With ``scenario_schedule`` (set by the launcher) the
speed reference and the feed-forward of sample k are its scenario's, sample-exact, and those topics are
not read. The robot-facing `joint_states` (estimated
position, speed, torque) is published every ``joint_states_decimation`` samples. Bad currents or
estimates, or a rejected speed limit, give zero voltage and a reported fault; the node keeps answering.
Each sample, or each block of N (``block_samples`` N > 1: it joins the four block twins of a block and
answers `voltage_command_block`), is one call of ``controller_block``. Composed in one process with the estimator
(``drive launch --intra-process``) it takes the currents and the estimator's answers from the estimator
node directly, at once, instead of four deliveries; the estimator still publishes them. With the
inverter's bridge there too, it hands its commands to the bridge, then to the estimator.

The core is built once the estimator's drive_config tells what the controller needs of it: its
injection frequency (the notch), its tracking bandwidth (the speed loop stays below it) and the current
up to which its angle holds (the current limit). Until then `voltage_command` is not offered, so the
plant does not start. The current loops use the commissioning record's R_s
(``DriveNode.load_commissioning``) and read the currents corrected by its sensor calibration.
"""
import dataclasses
import json
import math
import sys
import threading
import time

import numpy as np
from rcl_interfaces.msg import SetParametersResult
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64, String
from std_srvs.srv import Trigger

from drive_common.config.parameters import SCHEDULE_PARAMETER
from drive_common.contract.drive_records import commands, drive_inputs
from drive_common.contract.estimator_records import estimates
from drive_common.contract.estimator_states import HOLD, TRACKING
from drive_common.contract.log import COLUMN
from drive_common.contract.stamps import RESYNC_SAMPLES, sample_at, stamp_parts
from drive_common.contract.topics import (
    CURRENTS,
    DRIVE_CONFIG,
    ESTIMATOR_STATE,
    INJECTION,
    JOINT_STATES,
    ROTOR_ESTIMATE,
    SPEED_COMMAND,
    TOPICS,
    TORQUE_FEEDFORWARD,
    VOLTAGE_COMMAND,
    block,
)
from drive_common.contract.wire import BlockWire, Vector3Wire
from drive_common.math.current_sensing import current_sensing
from drive_common.motor.knowledge import motor_knowledge
from drive_common.ros.node import DriveNode, describe, finite, run_node, stamp, topic_qos

from .build import check_controller_settings, controller_for_scenario, protection_for_scenario, stated_torque
from .command_hold import HOLD_GAIN_PER_SPEED_ZERO, STOP_TIME_S, CommandHold, HoldSettings
from .control import (
    OMEGA_FILTERED,
    TORQUE_ALLOWED,
    TORQUE_RELEASED,
    controller_block,
    controller_state,
    estimated_torque,
)
from .params import check_speed_limit
from .position import HARD_STOP, HOMING_METHODS, INDEX, Homing, HomingSettings, search_acceleration
from .protection import protection_block, protection_state
from .supervision import SpeedSupervisor, fault_line

SPEED_LIMIT = "controller.speed_limit_rad_s"
ESTIMATOR_NODE = "hf_estimator"
COMMAND_PARAMETERS = {
    "command_timeout_s": (0.0, "a speed_command or torque_feedforward older than this [s]: the speed ramps to zero "
                               "and the joint is held there (0: commands never expire)"),
    "hold_timeout_s": (math.inf, "a command older than this [s]: zero torque (inf: hold for good)"),
    "brake": (False, "the joint has a holding brake: zero torque once stopped after a command timeout"),
    "stop_deceleration_rad_s2": (0.0, "the ramp to zero after a command timeout [rad/s²] (0: the velocity "
                                      "limit in 0.2 s)"),
    "velocity_limit_rad_s": (0.0, "commands faster than this are refused [rad/s] (0: the speed limit, else the "
                                  "rated speed)"),
    "effort_limit_Nm": (0.0, "torque feed-forwards above this are refused [N·m] (0: the drive's stated torque)"),
    "homing_method": ("", "how the joint finds its zero: hard_stop, index, or empty (no homing: position commands "
                          "refused); foc_controller.position"),
    "homing_direction": (1.0, "the search's direction, +1 or -1 (the motor's sign)"),
    "homing_speed_rad_s": (0.0, "the search's speed [rad/s] (0: 3 % of rated speed)"),
    "homing_current_A": (0.0, "hard_stop: the stop is found where the pushing q current exceeds this [A]"),
    "homing_torque_Nm": (0.0, "hard_stop: or where the pushing torque exceeds this [N·m] (the drive's k_t)"),
    "homing_offset_rad": (0.0, "the joint's zero from the stop or index [rad, the motor's sign]"),
    "homing_backoff_rad": (0.2, "hard_stop: how far the joint backs off the stop once found [rad]"),
    "homing_timeout_s": (30.0, "no stop or index found within this [s]: homing failed"),
}
"""How the controller takes commands on a robot (`drive up`, docs/robot.md); a scenario's schedule ignores them."""


def default_joint_name(namespace):
    """The namespace's last part (``/robot/left_wheel`` → ``left_wheel``), ``rotor`` at the root."""
    return namespace.rstrip("/").rsplit("/", 1)[-1] or "rotor"


class ControllerNode(DriveNode):
    node_parameters = {**SCHEDULE_PARAMETER, **COMMAND_PARAMETERS}

    def __init__(self, estimator=None, **kwargs):
        """``estimator``: the EstimatorNode of this process to take the answers from directly
        (``drive launch --intra-process``), instead of subscribing to them and to the currents."""
        self.params = None
        self.schedule = None
        super().__init__("foc_controller", **kwargs)
        self.declare_parameter("joint_states_decimation", 100)
        self.decimation = max(1, int(self.get_parameter("joint_states_decimation").value))
        self.joint_pub = self.create_publisher(JointState, JOINT_STATES, topic_qos(JOINT_STATES))
        self.hand_commands = None
        """In one process, the bridge's ``take_commands(k, u_alpha, u_beta)`` (hand_commands_to), else None."""
        self.voltage_pub = None
        """`voltage_command`('s block twin), offered once the core is built and the inputs are matched."""
        def ready():
            return (self.params or not self.configured) and (estimator is None or estimator.answering)

        self.sample_lock = threading.Lock() if estimator is None else estimator.sample_lock
        """Held while a sample or block is stepped, and by the executor's callbacks that rebuild what it
        steps: one with the estimator's where the answers are handed over (the bridge's link thread may step
        both)."""
        self.commands_to_estimator = None
        """Where the estimator's inputs are handed over (EstimatorNode.inputs_handed), its
        ``take_handed_commands``: the commands go there after the bridge."""
        if estimator is not None:
            inputs = []
            estimator.hand_answers_to(self.timed(self.take_answers))
            if estimator.inputs_handed:
                self.commands_to_estimator = estimator.take_handed_commands
        elif self.block_samples > 1:
            inputs = [self.sample_subscription(block(CURRENTS), self.timed(self.on_currents_block)),
                      self.sample_subscription(block(ROTOR_ESTIMATE), self.on_estimate_block),
                      self.sample_subscription(block(INJECTION), self.on_injection_block),
                      self.sample_subscription(block(ESTIMATOR_STATE), self.on_estimator_state_block)]
        else:
            inputs = [self.sample_subscription(CURRENTS, self.timed(self.on_currents)),
                      self.sample_subscription(ROTOR_ESTIMATE, self.on_estimate),
                      self.sample_subscription(INJECTION, self.on_injection),
                      self.sample_subscription(ESTIMATOR_STATE, self.on_estimator_state)]
        self.open_when_matched(inputs, self.open_outputs, ready=ready)
        self.hold = None
        """The command's timeout and hold (foc_controller.command_hold), made with the core."""
        self.homing = None
        """The joint's homing (foc_controller.position.Homing), made with the core where homing_method says."""
        self.last_i_q = 0.0
        self.index_input = None
        """The inverter's index input (index_from), or None: none known."""
        self.index_count = 0
        """The index input's count or parity at the last block answered."""
        self.homing_now = False
        """The last block's speed reference was homing's: a shaft stalled at the stop is what it looks for, not a
        fault of the speed supervision."""
        self.create_service(Trigger, "~/home", self.on_home)
        self.create_subscription(Float64, SPEED_COMMAND, self.on_speed_command, topic_qos(SPEED_COMMAND))
        self.create_subscription(Float64, TORQUE_FEEDFORWARD, self.on_torque_feedforward,
                                 topic_qos(TORQUE_FEEDFORWARD))
        self.tau_feedforward = 0.0
        self.create_subscription(String, DRIVE_CONFIG, self.on_drive_config, topic_qos(DRIVE_CONFIG))
        self.add_on_set_parameters_callback(self.on_set_parameters)
        self.watch_peer(self.contract_topics(CURRENTS)[0], "the plant")
        self.watch_foreign_publishers(self.contract_topics(CURRENTS, ROTOR_ESTIMATE, INJECTION,
                                                           ESTIMATOR_STATE))
        self.currents, self.estimates, self.injections, self.states = {}, {}, {}, {}
        self.k = 0
        self.joined_at = 0
        """The first sample answered: inputs of earlier ones came before `voltage_command` was offered."""
        self.omega_m_ref = 0.0
        self.current_limited = False
        self.voltage_wire = Vector3Wire(TOPICS[VOLTAGE_COMMAND].frame_id)
        self.block_wire = BlockWire(TOPICS[VOLTAGE_COMMAND].frame_id)
        self.declare_parameter("joint_name", "", descriptor=describe(
            "the joint's name in joint_states (empty: the namespace's last part, e.g. left_wheel)"))
        self.joint_msg = JointState(name=[self.get_parameter("joint_name").value or default_joint_name(
            self.get_namespace())])
        """The last joint state published, replaced whole each time (a robot node reads it from another thread)."""
        if not self.configured:
            self.publish_config({})

    def needs_experiment(self):
        """The scenario's speed schedule, when told to take it (scenario_schedule); else `speed_command`."""
        return bool(self.get_parameter("scenario_schedule").value)

    def build(self, scenario):
        check_controller_settings(scenario)
        if self.get_parameter("scenario_schedule").value:
            self.schedule = scenario.schedule()[0], scenario.feedforward()
        self.commissioning = self.load_commissioning(scenario)
        self.calibration = self.commissioning.calibration()
        self.protection = protection_for_scenario(scenario, self.commissioning, bus_measured=False)
        self.protection_x = protection_state()
        self.bus_V = scenario.motor.inverter.U_dc_V
        """The bus the protections take: the rated one (the graph's topics carry none measured)."""

    def on_drive_config(self, msg):
        with self.sample_lock:
            self.build_core(msg)

    def build_core(self, msg):
        """Build the core from the estimator's facts (its drive_config), once."""
        if self.params is not None or not self.configured:
            return
        try:
            config = json.loads(msg.data)
        except ValueError:
            return
        if not str(config.get("node", "")).endswith(f"/{ESTIMATOR_NODE}"):
            return
        try:
            if "estimator" not in config:
                raise ValueError(f"the estimator's configuration was rejected ({config.get('error')}); "
                                 f"nothing to control with")
            bandwidth = config["tracking_bandwidth_Hz"]
            self.params = controller_for_scenario(self.config, config["injection_frequency_Hz"],
                                                  math.inf if bandwidth is None else bandwidth,
                                                  config["tracking_current_limit_A"], self.commissioning,
                                                  config.get("tracking_acceleration_rad_s2") or math.inf,
                                                  config.get("tracking_loop"))
        except ValueError as error:
            self.configured = False
            self.reject(error)
            self.publish_config({})
            return
        self.n_p = self.params.n_p
        self.trip_A = self.trip_current_A()
        self.sensing = current_sensing(self.calibration, self.trip_A)
        self.stated_torque = stated_torque(self.config, self.commissioning, self.params,
                                           config["tracking_current_limit_A"] is not None,
                                           config.get("tracking_current_bound"))
        self.torque_limit = self.stated_torque.line()
        self.hold = CommandHold(self.hold_settings(), time.monotonic())
        self.hold.command(time.monotonic(), self.omega_m_ref, self.tau_feedforward)
        try:
            self.homing = self.make_homing()
        except ValueError as error:
            self.configured = False
            self.reject(error)
            self.publish_config({})
            return
        self.supervisor = SpeedSupervisor(self.n_p, self.nameplate().rated_speed_rpm * math.pi / 30.0,
                                          self.params.i_max_A, self.T_s, self.torque_limit,
                                          self.params.speed_ramp_rad_s2)
        self.supervisor.warm_up()
        self.x, self.z = controller_state(self.params)
        self.protection = self.protection._replace(current_limit_A=self.params.i_max_A)
        protection_block(self.protection_x.copy(), self.protection, np.zeros((1, 3)), 1, 0, self.bus_V, 0.0,
                         self.x.copy())
        controller_block(self.x.copy(), self.z.copy(), self.params, 1, drive_inputs(1), estimates(1), self.sensing,
                         commands(1))
        self.publish_config({"controller": self.params, "estimator": config["estimator"],
                             "motor_knowledge": motor_knowledge(self.nameplate(), self.commissioning)})

    def open_outputs(self):
        self.joined_at = self.k
        self.voltage_pub = self.sample_publisher(self.contract_topics(VOLTAGE_COMMAND)[0])

    def on_set_parameters(self, parameters):
        with self.sample_lock:
            return self.set_speed_limit(parameters)

    def set_speed_limit(self, parameters):
        """The parameter ``controller.speed_limit_rad_s`` among ``parameters``, checked and applied."""
        for p in parameters:
            if p.name != SPEED_LIMIT:
                continue
            try:
                check_speed_limit(p.value)
            except ValueError as error:
                self.health.latched = f"parameter {SPEED_LIMIT} rejected ({error}); zero voltage until a " \
                                      f"valid limit is set"
                self.fault("parameter", self.health.latched)
                return SetParametersResult(successful=False, reason=str(error))
            if self.params:
                self.params = self.params._replace(speed_limit_rad_s=float(p.value))
            elif self.config:
                self.config = dataclasses.replace(
                    self.config, controller={**self.config.controller, "speed_limit_rad_s": float(p.value)})
            if self.health.latched and SPEED_LIMIT in self.health.latched:
                self.health.latched = None
        return SetParametersResult(successful=True)

    def make_homing(self):
        """The Homing of the parameters (None without a homing_method): the stop's current, the search's speed (3 %
        of rated speed by default) and ramp, the position loop's gain and bound as the hold's."""
        method = str(self.get_parameter("homing_method").value)
        if not method:
            return None
        if method not in HOMING_METHODS:
            raise ValueError(f"homing_method: must be one of {', '.join(HOMING_METHODS)} or empty, not {method!r}")
        value = {name: float(self.get_parameter(f"homing_{name}").value) for name in
                 ("direction", "speed_rad_s", "current_A", "torque_Nm", "offset_rad", "backoff_rad", "timeout_s")}
        known = self.commissioning.refined(self.nameplate())
        speed = value["speed_rad_s"] or 0.03 * known.rated_speed_rpm * math.pi / 30.0
        k_t = 1.5 * known.n_p * known.psi_f_Wb
        current = (value["current_A"] or value["torque_Nm"] / k_t) if method == HARD_STOP else math.inf
        if method == HARD_STOP and not 0.0 < current < self.params.i_max_A:
            raise ValueError(f"homing_current_A: {current:g} A must be above 0 and below the current limit "
                             f"{self.params.i_max_A:g} A (the speed loop pushes the stop with at most that)")
        settings = HomingSettings(method, math.copysign(1.0, value["direction"]), speed, current, value["offset_rad"],
                                  value["backoff_rad"], timeout_s=value["timeout_s"])
        acceleration = search_acceleration(known.J_kgm2, k_t, current if method == HARD_STOP else
                                           0.25 * self.params.i_max_A)
        hold = self.hold.settings
        return Homing(settings, hold.gain_per_s, hold.hold_speed_rad_s, acceleration)

    def on_home(self, _, response):
        """The `~/home` service (std_srvs/Trigger): home the joint again from now (it must be tracking)."""
        with self.sample_lock:
            if self.homing is None:
                response.success, response.message = False, "this joint has no homing (homing_method)"
            else:
                self.start_homing()
                response.success = self.homing.active
                response.message = "homing" if self.homing.active else self.homing.reason
        return response

    def index_from(self, index_input):
        """The inverter's index input: ``index_input()`` gives (whether the inverter has one, its count or parity now:
        a change is a pulse), read at each block the nodes answer (a compiled answer hands it with its rows)."""
        self.index_input = index_input

    def start_homing(self):
        """Homing started (again); where it looks for an index the inverter has none, failed at once (said on
        /diagnostics)."""
        h = self.homing
        h.start()
        if h.settings.method == INDEX and (self.index_input is None or not self.index_input()[0]):
            h.fail("the inverter reports no index input (its HELLO); home against a stop (hard_stop) instead")
            self.fault("homing_failed", h.reason)

    def on_speed_command(self, msg):
        self.take_command(msg.data, None, SPEED_COMMAND)

    def on_torque_feedforward(self, msg):
        self.take_command(None, msg.data, TORQUE_FEEDFORWARD)

    def command_limits(self):
        """(velocity [rad/s], effort [N·m]) a command may not exceed: the parameters', else the speed limit (the
        rated speed where it is ∞) and the stated torque; ∞ before the core is built where no parameter says."""
        velocity = float(self.get_parameter("velocity_limit_rad_s").value)
        effort = float(self.get_parameter("effort_limit_Nm").value)
        built = self.params is not None and self.hold is not None
        if velocity <= 0.0:
            velocity = math.inf
            if self.params is not None:
                velocity = self.params.speed_limit_rad_s
                velocity = velocity if math.isfinite(velocity) else self.nameplate().rated_speed_rpm * math.pi / 30.0
        if effort <= 0.0:
            effort = self.stated_torque.torque_Nm if built else math.inf
        return velocity, effort

    def refusal(self, velocity, effort):
        """Why a command of ``velocity`` [rad/s] and ``effort`` [N·m] (None: not given) is refused, as
        (fault kind, reason), or None."""
        limits = self.command_limits()
        for value, limit, what, unit in ((velocity, limits[0], "velocity", "rad/s"), (effort, limits[1], "effort",
                                                                                   "N·m")):
            if value is None:
                continue
            if not finite(value):
                return "command_not_finite", f"{what} {value} is not finite"
            if abs(value) > limit:
                return "command_over_limit", f"{what} {value:g} {unit} is over the axis's limit {limit:g} {unit}"
        return None

    def position_refusal(self, position):
        """Why a position command [rad, the joint's position in the motor's sign] is refused, as (fault kind,
        reason), or None."""
        if position is None:
            return None
        if not finite(position):
            return "command_not_finite", f"position {position} is not finite"
        if self.homing is None:
            return "command_not_homed", "position commands need homing (no homing_method)"
        if not self.homing.homed:
            return "command_not_homed", f"the joint is not homed ({self.homing.state})"
        return None

    def take_command(self, velocity, effort, source, position=None):
        """A command of ``velocity`` [rad/s], ``effort`` [N·m] and/or ``position`` [rad, the homed joint's] (None:
        not given) from ``source``: applied, or refused (counted on /diagnostics, never applied); True when
        applied. With a position the velocity is the position loop's feed-forward; a command of effort alone
        keeps the last velocity or position."""
        refused = self.refusal(velocity, effort) or self.position_refusal(position)
        if refused:
            self.fault(refused[0], f"{source}: {refused[1]}; refused, not applied")
            return False
        with self.sample_lock:
            theta_ref = None
            if position is not None:
                theta_ref = self.homing.theta_zero + float(position)
            elif velocity is None and self.hold is not None and not math.isnan(self.hold.theta_ref):
                theta_ref = self.hold.theta_ref
            self.omega_m_ref = self.omega_m_ref if velocity is None else float(velocity)
            self.tau_feedforward = self.tau_feedforward if effort is None else float(effort)
            if self.hold is not None:
                self.hold.command(time.monotonic(), self.omega_m_ref if theta_ref is None or velocity is not None
                                  else 0.0, self.tau_feedforward, theta_ref)
        return True

    def hold_settings(self):
        """HoldSettings of the parameters and the built core (the speed PI's zero sets the hold's gain)."""
        velocity = self.command_limits()[0]
        deceleration = float(self.get_parameter("stop_deceleration_rad_s2").value) or velocity / STOP_TIME_S
        return HoldSettings(float(self.get_parameter("command_timeout_s").value),
                            float(self.get_parameter("hold_timeout_s").value), bool(self.get_parameter("brake").value),
                            deceleration, HOLD_GAIN_PER_SPEED_ZERO * self.params.ki_speed / self.params.kp_speed,
                            0.1 * velocity, velocity)

    def on_currents(self, sec, nanosec, i_a, i_b, i_c):
        self.store(self.currents, sec, nanosec, (i_a, i_b, i_c))

    def on_estimate(self, sec, nanosec, theta_m, omega_m, _):
        value = (theta_m, omega_m) if theta_m is not None and omega_m is not None else (math.nan, math.nan)
        self.store(self.estimates, sec, nanosec, value)

    def on_injection(self, sec, nanosec, u_alpha, u_beta, _):
        self.store(self.injections, sec, nanosec, (u_alpha, u_beta))

    def on_estimator_state(self, sec, nanosec, _, __, state):
        self.store(self.states, sec, nanosec, state)

    def hand_commands_to(self, take_commands):
        """In one process (``drive launch --intra-process``): hand each sample's or block's voltage commands
        to ``take_commands(k, u_alpha, u_beta)`` (the bridge's; floats, or arrays of the block's samples)
        before publishing them: the command is on the link before its topic is published."""
        self.hand_commands = take_commands

    def take_answers(self, k, currents, estimate, injection, state):
        """Sample or block k's currents and the estimator's answers, handed over in one process
        (EstimatorNode.hand_answers_to): answered at once; a later k means samples were lost before it.
        Before `voltage_command` is offered (the core not built yet) nothing is answered: the inverter, whose
        samples may come before the drive is ready, applies zero volts."""
        if self.before_joining(k, len(currents[0]) if self.block_samples > 1 else 1):
            return
        if k < self.k:
            self.fault("wrong_stamp", f"answers of sample {k} handed over at sample {self.k}; discarded")
            return
        if k > self.k:
            self.resynchronise(k)
        if self.block_samples > 1:
            self.k = self.step_block(k, currents, estimate, injection, state)
        else:
            self.step(k, currents, estimate, injection, state)
            self.k = k + 1

    def join_at(self, k0):
        """Join a running inverter's samples at k0 (an axis armed, drive_tools.launch.axis): the first answered."""
        self.k = self.joined_at = k0
        for table in (self.currents, self.estimates, self.injections, self.states):
            table.clear()

    def before_joining(self, k, n):
        """True when the inputs of the n samples from k are not to be answered: they came before
        `voltage_command` was offered (the core not built yet; a real inverter may stream before the drive is
        ready, and applies zero volts meanwhile), and the drive joins after them; or they are the rest of
        the last sample (block) whose first input came before it joined."""
        if self.voltage_pub is None:
            self.k = max(self.k, k + n)
            return True
        return k + n == self.joined_at

    def store(self, table, sec, nanosec, value):
        k = sample_at(sec, nanosec, self.T_s)
        if k is not None and self.before_joining(k, 1):
            return
        if k is None or not self.k <= k <= self.k + RESYNC_SAMPLES:
            self.fault("wrong_stamp", f"stamp {sec}.{nanosec:09d} is not a "
                                      f"sample in {self.k}..{self.k + RESYNC_SAMPLES}; discarded")
            return
        table[k] = value
        if table is self.currents and k > self.k:
            self.resynchronise(k)
        k = self.k
        while k in self.currents and k in self.estimates and k in self.injections and k in self.states:
            self.step(k, self.currents.pop(k), self.estimates.pop(k), self.injections.pop(k), self.states.pop(k))
            k = self.k = k + 1

    def on_currents_block(self, sec, nanosec, i_a, i_b, i_c):
        self.store_block(self.currents, sec, nanosec, (i_a, i_b, i_c))

    def on_estimate_block(self, sec, nanosec, theta_m, omega_m, _):
        self.store_block(self.estimates, sec, nanosec, (theta_m, omega_m))

    def on_injection_block(self, sec, nanosec, u_alpha, u_beta, _):
        self.store_block(self.injections, sec, nanosec, (u_alpha, u_beta))

    def on_estimator_state_block(self, sec, nanosec, eps, signal, state):
        self.store_block(self.states, sec, nanosec, (eps, signal, state))

    def store_block(self, table, sec, nanosec, channels):
        """Keep a block input; run every block whose four inputs are in, in order."""
        k0 = sample_at(sec, nanosec, self.T_s)
        if k0 is not None and self.before_joining(k0, len(channels[0])):
            return
        if k0 is None or k0 < self.k or len({len(c) for c in channels}) != 1:
            self.fault("wrong_stamp", f"block stamped {sec}.{nanosec:09d} is not a block from sample {self.k} "
                                      f"with equal channels; discarded")
            return
        table[k0] = channels
        if table is self.currents and k0 > self.k and self.k not in self.currents:
            self.resynchronise(k0)
        k0 = self.k
        while k0 in self.currents and k0 in self.estimates and k0 in self.injections and k0 in self.states:
            self.k = self.step_block(k0, self.currents.pop(k0), self.estimates.pop(k0), self.injections.pop(k0),
                                     self.states.pop(k0))
            k0 = self.k

    def step_block(self, k0, currents, estimate, injection, state):
        """Answer the samples k0 … k0 + n − 1 (a block; n = 1 with per-sample topics): their inputs as
        channels of n values (currents: i_a, i_b, i_c; estimate: θ̂_m, ω̂_m; injection: u_α, u_β; state: ε,
        signal, code), their voltage commands on voltage_command (its block twin with blocks); returns the next
        sample to answer."""
        n = len(currents[0])
        out = commands(n)
        if self.params and not self.health.latched and all(len(c) == n for c in (*estimate, *injection, *state)):
            if self.schedule:
                speed, feedforward = self.schedule[0][k0:k0 + n], self.schedule[1][k0:k0 + n]
                self.omega_m_ref, self.tau_feedforward = speed[-1], feedforward[-1]
            else:
                if self.index_input is not None:
                    self.index_count = self.index_input()[1]
                reference, ff, torque = self.reference(n, estimate, state)
                speed, feedforward = np.full(n, reference), np.full(n, ff)
            estimated = estimates(n)
            estimated["theta_e_hat"], estimated["omega_e_hat"] = self.n_p * estimate[0], self.n_p * estimate[1]
            estimated["u_inj_alpha"], estimated["u_inj_beta"] = injection
            estimated["eps"], estimated["signal"], estimated["state"] = state
            released = not self.schedule and not torque
            self.release_torque(released)
            measured = np.column_stack(currents)
            inputs = drive_inputs(n)
            inputs["i_a_A"], inputs["i_b_A"], inputs["i_c_A"] = currents
            inputs["omega_m_ref_rad_s"], inputs["tau_feedforward_Nm"] = speed, feedforward
            protection_block(self.protection_x, self.protection, measured, n, k0 + n - 1, self.bus_V,
                             estimated["omega_e_hat"][-1], self.x)
            bad = controller_block(self.x, self.z, self.params, n, inputs, estimated, self.sensing, out)
            if bad:
                self.fault("bad_input", f"currents at samples {k0}..{k0 + n - 1}: {bad} of {n} not finite or beyond "
                                        f"the {self.trip_A:g} A trip, or a non-finite estimate; zero voltage there")
            self.note_block(k0, (speed, estimate, state[2]), out, released)
        elif self.params and not self.health.latched:
            self.fault("bad_input", f"block {k0}: inputs of unequal length; zero voltage")
        u_alpha, u_beta = out["u_alpha_V"], out["u_beta_V"]
        if self.block_samples == 1:
            u_alpha, u_beta = float(u_alpha[0]), float(u_beta[0])
        if self.hand_commands:
            self.hand_commands(k0, u_alpha, u_beta)
        if self.commands_to_estimator:
            self.commands_to_estimator(k0, u_alpha, u_beta)
        self.publish_voltages(k0, u_alpha, u_beta)
        self.sample_handled(k0 + n - 1)
        return k0 + n

    def publish_voltages(self, k0, u_alpha, u_beta):
        """The voltage commands of the samples from k0 (arrays: a block, on the block twin; floats: one sample)."""
        sec, nanosec = stamp_parts(k0 + self.stamp_origin, self.T_s)
        if self.block_samples > 1:
            self.voltage_pub.publish(self.block_wire.encode(sec, nanosec, u_alpha, u_beta))
        else:
            self.voltage_pub.publish(self.voltage_wire.encode(sec, nanosec, u_alpha, u_beta, 0.0))

    def note_block(self, k0, inputs, out, released):
        """What the controller tells of the n samples from k0 it answered: ``inputs`` (the speed reference per
        sample [rad/s], the estimate (θ̂_m [rad], ω̂_m [rad/s]) and the estimator's state code per sample), ``out``
        its COMMAND records; the speed supervision (not while the torque is released or the joint homes) and,
        every ``joint_states_decimation`` samples, `joint_states`."""
        speed, estimate, codes = inputs
        n = len(out)
        self.last_i_q = float(out["i_q_A"][-1])
        current_ref = np.hypot(out["i_d_ref_A"], out["i_q_ref_A"])
        self.current_limited = bool(current_ref[-1] >= (1.0 - 1e-9) * self.params.i_max_A)
        if not released and not self.homing_now:
            self.supervise(self.supervisor.update(k0, speed, self.n_p * estimate[1], current_ref, codes))
        joint = next((i for i in range(n) if (k0 + i) % self.decimation == 0), None)
        if joint is not None:
            j = JointState(name=self.joint_msg.name, position=[self.joint_position(float(estimate[0][joint]))],
                           velocity=[self.x[OMEGA_FILTERED] / self.n_p],
                           effort=[estimated_torque(self.params, out[joint]["i_d_A"], out[joint]["i_q_A"])])
            j.header.stamp = stamp(k0 + joint + self.stamp_origin, self.T_s)
            self.joint_msg = j
            self.joint_pub.publish(j)

    def take_answered(self, k0, rows, live, index_count=0):
        """What a compiled answer (drive_tools.launch.axis_answer) answered for the drive's samples k0 … k0 + n − 1,
        from their log rows (drive_common.contract.log.LOG_COLUMNS), on the answer's ring reader (not real-time):
        what the joint is told for the blocks to come (homing, the command hold, the position loop: ``reference``'s
        speed command) written into ``live`` (axis_answer.LiveCommand), the torque released or not
        (control.TORQUE_RELEASED, read by the answer's next sample), then what note_block tells and the voltage
        commands published; ``index_count``: the inverter's index input at the last of them (a count or its parity:
        a change is a pulse)."""
        n = len(rows)
        self.index_count = index_count
        estimate = (rows[:, COLUMN["theta_e_hat"]] / self.n_p, rows[:, COLUMN["omega_e_hat"]] / self.n_p)
        codes = rows[:, COLUMN["state"]]
        with self.sample_lock:
            if not self.params or self.health.latched:
                return
            command, feedforward, torque = self.reference(n, estimate, (None, None, codes), followed=False)
            live.write(command, feedforward)
            self.x[TORQUE_RELEASED] = 0.0 if torque else 1.0
            self.k = k0 + n
            out = commands(n)
            for column, name in (("u_alpha", "u_alpha_V"), ("u_beta", "u_beta_V"), ("i_d", "i_d_A"),
                                 ("i_q", "i_q_A"), ("i_d_ref", "i_d_ref_A"), ("i_q_ref", "i_q_ref_A")):
                out[name] = rows[:, COLUMN[column]]
            self.note_block(k0, (rows[:, COLUMN["omega_m_ref"]], estimate, codes), out, not torque)
            if self.block_samples > 1:
                self.publish_voltages(k0, out["u_alpha_V"], out["u_beta_V"])
            else:
                for i in range(n):
                    self.publish_voltages(k0 + i, float(out[i]["u_alpha_V"]), float(out[i]["u_beta_V"]))
            self.sample_handled(k0 + n - 1)

    def release_torque(self, released):
        """The command hold's release (zero torque although the estimator tracks: control.TORQUE_RELEASED) on or
        off from the next sample the core steps."""
        self.x[TORQUE_RELEASED] = 1.0 if released else 0.0
        if released:
            self.x[TORQUE_ALLOWED] = 0.0

    def reference(self, n, estimate, state, followed=True):
        """(ω*_m [rad/s], τ_ff [N·m], torque allowed) for a block of ``n`` samples from its estimates (θ̂_m, ω̂_m) and
        estimator states: homing's once the estimator tracks (started then, the first time), else the command's
        (CommandHold); a joint just homed holds where its back-off ended. With ``followed`` false, the speed command
        itself (foc_controller.speed_command) in ω*_m's place, for a compiled answer to follow."""
        theta, omega = float(estimate[0][-1]), float(estimate[1][-1])
        h = self.homing
        lost = [code for code in state[2] if code not in (HOLD, TRACKING)]
        if h is not None and lost and h.state != "not_homed":
            was = h.state
            h.lose(f"estimator state {int(lost[0])} (not tracking)")
            if h.state != was:
                self.fault("homing_lost", h.reason)
                self.hold.command(time.monotonic(), 0.0, self.tau_feedforward)
        if h is not None and h.state == "not_homed" and state[2][-1] == TRACKING:
            self.start_homing()
        self.homing_now = h is not None and h.active
        if self.homing_now:
            speed = (h.reference if followed else h.command_now)(n * self.T_s, (theta, omega), self.last_i_q,
                                                                 self.index_count)
            if h.homed:
                self.hold.command(time.monotonic(), 0.0, self.tau_feedforward, h.target)
            return speed, self.tau_feedforward, True
        return (self.hold.reference if followed else self.hold.command_now)(time.monotonic(), n * self.T_s, theta)

    def joint_position(self, theta_m_hat):
        """The joint's position [rad]: the estimated mechanical angle ``theta_m_hat`` [rad] from the homed zero
        (NaN before), or from wherever the start-up found the rotor where the joint has no homing."""
        return theta_m_hat if self.homing is None else self.homing.position(theta_m_hat)

    def resynchronise(self, k):
        """Currents of a later sample mean the plant gave up on samples self.k..k−1 (they never completed
        here: an input was lost, e.g. sent before a subscription matched); follow it to k."""
        self.fault("missed_sample", f"samples {self.k}..{k - 1} never completed (currents, rotor_estimate, "
                                    f"injection or estimator_state missing); following the plant to sample {k}")
        for table in (self.currents, self.estimates, self.injections, self.states):
            for old in [j for j in table if j < k]:
                del table[old]
        self.k = k

    def step(self, k, currents, estimate, injection, state):
        """Answer sample k from its per-sample inputs (scalars; state: the code) as a block of one."""
        def channels(*values):
            return tuple(np.array([v], dtype=float) for v in values)
        self.step_block(k, channels(*currents), channels(*estimate), channels(*injection), channels(0.0, 0.0, state))

    def supervise(self, raised):
        """Report the speed supervision's new faults (foc_controller.supervision) on /diagnostics."""
        for fault in raised:
            self.fault("not_following", f"speed supervision: {fault_line(fault)}")

    def status_values(self):
        values = {"sample": self.k, "speed_command_rad_s": self.omega_m_ref,
                  "current_limited": self.current_limited}
        if self.hold is not None and not self.schedule:
            values["command"] = self.hold.mode
            values["command_age_s"] = self.hold.age_s(time.monotonic())
            values["command_timeouts"] = self.hold.timeouts
        if self.homing is not None:
            values["homing"] = self.homing.reason or self.homing.state
            values["homed_zero_rad"] = self.homing.theta_zero
        if self.params:
            values["speed_supervision"] = "; ".join(fault_line(f) for f in self.supervisor.open.values()) or "ok"
            values["sensorless_torque_limit"] = self.torque_limit
        return values


def main(argv=None):
    """``controller_node [--executor events|single] --ros-args ...`` (``ros2 run foc_controller
    controller_node``)."""
    return run_node(ControllerNode, "controller_node", argv)


if __name__ == "__main__":
    sys.exit(main())
