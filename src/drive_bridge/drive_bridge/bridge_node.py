"""The ``drive_bridge`` node: a real (or the virtual) inverter in the plant's place in the graph.

It publishes what `pmsm_plant` publishes — `currents` stamped k·T_s from the inverter's sample
counter, `rotor_state` and `angle_error` when the encoder is valid, `/clock`, `drive_config`,
`/diagnostics` — and answers `voltage_command`(k) with COMMAND(k). With an inverter sending blocks of
N samples (parameter ``block_samples``, which must match its HELLO) it publishes `currents_block` and
`rotor_state_block` of each whole block and answers `voltage_command_block` with COMMAND_BLOCK. Composed
with the estimator and the controller (``drive launch --intra-process``) it hands each sample or block to
the estimator on its link thread before publishing it, and the controller's commands come back to it
there: the drive's whole answer runs on that thread, with no delivery or thread switch in it. The
service `clear_faults`
(std_srvs/Trigger) clears the inverter's latched faults, an overcurrent included. Frames are read on a
thread of their own, so the graph never waits on the link; the inverter's clock paces everything. Link
faults are counted and reported, never raised (docs/inverter-protocol.md, "The host")."""
import math
import sys
import threading
import time

import numpy as np
from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import Vector3Stamped
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.logging import LoggingSeverity
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger

from drive_common.contract.log import COLUMN
from drive_common.contract.stamps import sample_at, sample_of, stamp_parts
from drive_common.contract.topics import (
    ANGLE_ERROR,
    CURRENTS,
    ROTOR_ESTIMATE,
    ROTOR_STATE,
    SAMPLE_LOGGED,
    TOPICS,
    VOLTAGE_COMMAND,
    ZERO_VOLTAGE,
    block,
)
from drive_common.contract.wire import BlockWire
from drive_common.math.frames import wrap
from drive_common.ros.node import DriveNode, finite, log_line, run_node, stamp, topic_qos
from drive_common.runtime.realtime import QUIET_TIME

from .inverter_bridge import COMMAND_TIMEOUT_S, LINK_TIMEOUT_S, InverterBridge
from .inverter_link import CanLink, SerialLink
from .inverter_protocol import MAX_BLOCK

PARAMETERS = {
    "link": ("serial", "serial or can"),
    "port": ("/dev/ttyACM0", "serial port path (a /dev/serial/by-id/ symlink survives re-plugging)"),
    "baudrate": (3_000_000, "serial baud rate (ignored by USB CDC and ptys)"),
    "can_channel": ("can0", "CAN channel (SocketCAN interface, or python-can virtual channel name)"),
    "can_interface": ("", "python-can interface (empty: socketcan where present, else virtual)"),
    "drive_id": (0, "CAN drive number 0-15"),
    "link_timeout_s": (LINK_TIMEOUT_S, "no telemetry for this long: link lost [s]"),
    "command_timeout_s": (COMMAND_TIMEOUT_S, "no voltage_command for this long: safe state [s]"),
    "answer_wait_s": (0.0, "an inverter in lock-step (it sends once answered): the longest the drive may take to "
                           "answer before its silence counts against the link [s]; 0: the inverter keeps its own pace"),
    "block_samples": (1, "samples per TELEMETRY_BLOCK the inverter announces, N (1: a frame per sample)"),
}
HISTORY_SAMPLES = 64
NO_CHANNEL = np.zeros(0)


class InverterBridgeNode(DriveNode):
    reads_configuration = False

    def __init__(self, link=None, controller=None, estimator=None, answered_elsewhere=False, **kwargs):
        """``link``: a link object (composed graphs), else the parameters' link; ``controller``: the
        ControllerNode of this process to take the voltage commands from directly (``drive launch
        --intra-process``), instead of subscribing to them; ``estimator``: the EstimatorNode of this process
        whose inputs are handed over (EstimatorNode.inputs_handed), on the link thread. With
        ``answered_elsewhere`` the node neither reads the link nor takes commands: a compiled answer of this
        process (drive_tools.runner.compiled_answer) owns the link, and hands what it answered to
        ``publish_answered`` from a thread that is not real-time."""
        super().__init__("drive_bridge", **kwargs)
        QUIET_TIME.hold()
        for name, (default, text) in PARAMETERS.items():
            self.declare_parameter(name, default, descriptor=ParameterDescriptor(description=text))
        p = {name: self.get_parameter(name).value for name in PARAMETERS}
        self.parameters = p
        if link is None:
            if p["link"] == "serial":
                link = SerialLink(p["port"], int(p["baudrate"]))
            elif p["link"] == "can":
                link = CanLink(p["can_channel"], int(p["drive_id"]), p["can_interface"] or None)
            else:
                raise ValueError(f"parameter link: 'serial' or 'can', not {p['link']!r}")
        self.block_samples = int(p["block_samples"])
        if not 1 <= self.block_samples <= MAX_BLOCK:
            raise ValueError(f"parameter block_samples: from 1 to {MAX_BLOCK}, not {self.block_samples}")
        self.bridge = InverterBridge(link, float(p["link_timeout_s"]), float(p["command_timeout_s"]),
                                     block_samples=self.block_samples, answer_wait_s=float(p["answer_wait_s"]))
        self.offer_clock()
        self.clock_pub = self.claim_clock()
        self.angle_error_pub = self.create_publisher(Vector3Stamped, ANGLE_ERROR, topic_qos(ANGLE_ERROR))
        self.zero_voltage_pub = self.sample_publisher(ZERO_VOLTAGE)
        self.zero_voltage_wire = BlockWire()
        self.zero_voltage_periods = 0
        self.answered_elsewhere = answered_elsewhere
        self.live_counters = None
        if answered_elsewhere:
            self.answered_pubs = {topic: self.sample_publisher(block(topic)) for topic in SAMPLE_LOGGED}
            self.answered_wires = {topic: BlockWire(TOPICS[topic].frame_id) for topic in SAMPLE_LOGGED}
        elif self.block_samples > 1:
            self.currents_pub = self.sample_publisher(block(CURRENTS))
            self.rotor_state_pub = self.sample_publisher(block(ROTOR_STATE))
            if controller is None:
                self.sample_subscription(block(VOLTAGE_COMMAND), self.timed(self.on_voltage_block))
            self.sample_subscription(block(ROTOR_ESTIMATE), self.on_rotor_estimate_block)
            self.currents_wire = BlockWire(TOPICS[CURRENTS].frame_id)
            self.rotor_state_wire = BlockWire()
        else:
            self.currents_pub = self.create_publisher(Vector3Stamped, CURRENTS, topic_qos(CURRENTS))
            self.rotor_state_pub = self.create_publisher(JointState, ROTOR_STATE, topic_qos(ROTOR_STATE))
            if controller is None:
                self.create_subscription(Vector3Stamped, VOLTAGE_COMMAND, self.timed(self.on_voltage_command),
                                         topic_qos(VOLTAGE_COMMAND))
            self.create_subscription(JointState, ROTOR_ESTIMATE, self.on_rotor_estimate,
                                     topic_qos(ROTOR_ESTIMATE))
        if controller is not None:
            controller.hand_commands_to(self.timed(self.take_commands))
        self.estimator = estimator if estimator is not None and estimator.inputs_handed else None
        self.create_service(Trigger, "clear_faults", self.on_clear_faults)
        wrap(0.0)
        self.T_s = None
        self.k = None
        self.n_p = None
        self.history = {}
        self.reported = {}
        self.running = True
        self.currents_msg, self.rotor_msg, self.clock_msg = Vector3Stamped(), JointState(name=["rotor"]), Clock()
        self.currents_msg.header.frame_id = TOPICS[CURRENTS].frame_id
        self.previous_encoder = None
        """(k, θ_m) of the last sample with a valid encoder angle (per-sample topics: its speed by difference)."""
        self.link_handed_over = False
        self.link_idle = threading.Event()
        """Set by the link thread while the link is handed over and it does not poll."""
        self.thread = threading.Thread(target=self.read_link, name="drive_bridge_link", daemon=True)
        if not answered_elsewhere:
            self.thread.start()

    def read_link(self):
        """The link thread: poll, publish each sample (each whole block), report new faults; while a compiled
        answer owns the link (hand_link_over), nothing."""
        logged = ""
        while self.running:
            if self.link_handed_over:
                self.link_idle.set()
                time.sleep(0.02)
                continue
            self.link_idle.clear()
            if self.link_handed_over:
                continue
            blocks = self.bridge.poll_blocks(0.02)
            if not self.bridge.open and self.bridge.last_error not in ("", logged):
                logged = self.bridge.last_error
                log_line(self, LoggingSeverity.ERROR,
                         f"inverter link: {logged}; retrying every {self.bridge.reconnect_s:g} s")
            hello = self.bridge.hello
            if hello is not None and self.T_s is None:
                self.configure(hello)
            self.publish_blocks(blocks)

    def hand_link_over(self):
        """From now on a compiled answer of this process reads and writes the link (drive_tools.launch.axis_answer):
        the link thread stops polling; returns once it has (within a poll)."""
        self.link_idle.clear()
        self.link_handed_over = True
        if self.thread.is_alive():
            self.link_idle.wait(1.0)

    def take_link_back(self):
        """The link thread polls the link again."""
        self.link_handed_over = False

    def publish_blocks(self, blocks):
        """Publish each sample (each whole block) of ``blocks`` (BridgeBlocks), then report new faults."""
        if self.block_samples > 1:
            for b in blocks:
                self.publish_block(b, self.clock_msg)
            self.report_new_faults()
            return
        currents, rotor, clock = self.currents_msg, self.rotor_msg, self.clock_msg
        for b in blocks:
            self.report_zero_volts(b)
        for s in (s for b in blocks for s in b.samples()):
            self.k = s.k
            velocity = None
            previous = self.previous_encoder
            if not math.isnan(s.theta_m):
                velocity = (s.theta_m - previous[1]) / ((s.k - previous[0]) * self.T_s) \
                    if previous and s.k > previous[0] else 0.0
                self.history[s.k] = (s.theta_m, velocity)
                self.history.pop(s.k - HISTORY_SAMPLES, None)
                self.previous_encoder = (s.k, s.theta_m)
            if self.estimator is not None:
                self.hand_sample(s, velocity)
            t = stamp(s.k, self.T_s)
            if self.clock_pub:
                clock.clock = t
                self.clock_pub.publish(clock)
            if velocity is not None:
                rotor.header.stamp = t
                rotor.position, rotor.velocity, rotor.effort = [s.theta_m], [velocity], [math.nan]
                self.rotor_state_pub.publish(rotor)
            currents.header.stamp = t
            currents.vector.x, currents.vector.y, currents.vector.z = s.i_a, s.i_b, s.i_c
            self.currents_pub.publish(currents)
        self.report_new_faults()

    def publish_block(self, b, clock):
        """A whole block (its first sample a multiple of N, N samples; a part of one is dropped):
        `currents_block` first (what the drive answers; the encoder's angles kept before it, for
        `angle_error`), then `/clock` (its first sample) and `rotor_state_block` (when the encoder is valid
        throughout)."""
        N, k0 = self.block_samples, b.k0
        self.k = k0 + len(b) - 1
        if len(b) != N or k0 % N:
            return
        self.report_zero_volts(b)
        sec, nanosec = stamp_parts(k0, self.T_s)
        theta = b.theta_m
        encoder = not np.isnan(theta).any()
        if encoder:
            before = self.history.get(k0 - N)
            previous = before[0][-1] if before is not None else theta[0]
            velocity = np.diff(theta, prepend=previous) / self.T_s
            self.history[k0] = (theta, velocity)
            self.history.pop(k0 - HISTORY_SAMPLES * N, None)
        i = b.currents_A
        if self.estimator is not None:
            self.hand_block(sec, nanosec, i, theta if encoder else None, velocity if encoder else None)
        self.currents_pub.publish(self.currents_wire.encode(sec, nanosec, i[:, 0], i[:, 1], i[:, 2]))
        if self.clock_pub:
            clock.clock = stamp(k0, self.T_s)
            self.clock_pub.publish(clock)
        if encoder:
            self.rotor_state_pub.publish(self.rotor_state_wire.encode(sec, nanosec, theta, velocity,
                                                                      np.full(N, np.nan)))

    def publish_answered(self, k0, theta_m, rows):
        """What a compiled answer produced for samples k0 … k0 + n − 1 (``theta_m``: the encoder's angle as
        received [rad, mechanical; NaN: none]; ``rows``: their log rows, drive_common.contract.log.LOG_COLUMNS),
        as the graph's nodes publish it: each logged topic's block twin (`rotor_state_block` from the encoder,
        where it is valid throughout), then `/clock` at k0. From the ring's reader, never the answer's thread."""
        n, n_p, T_s = len(theta_m), self.n_p, self.T_s
        self.k = k0 + n - 1
        sec, nanosec = stamp_parts(k0, T_s)
        encoder = not np.isnan(theta_m).any()
        for topic, publisher in self.answered_pubs.items():
            t = TOPICS[topic]
            if topic == ROTOR_STATE:
                if not encoder:
                    continue
                before = self.history.get(k0 - n)
                previous = before[0][-1] if before is not None else theta_m[0]
                velocity = np.diff(theta_m, prepend=previous) / T_s
                self.history[k0] = (theta_m, velocity)
                self.history.pop(k0 - HISTORY_SAMPLES * n, None)
                channels = (theta_m, velocity, np.full(n, np.nan))
            else:
                scale = 1.0 / n_p if t.electrical else 1.0
                channels = tuple(scale * rows[:, COLUMN[c]] for c in t.log_columns)
            publisher.publish(self.answered_wires[topic].encode(sec, nanosec, *channels))
        if self.clock_pub:
            self.clock_pub.publish(Clock(clock=stamp(k0, T_s)))
        self.report_new_faults()

    def hand_block(self, sec, nanosec, currents, theta, velocity):
        """The block's currents [A, (N, 3)] and, for the sensored estimator, its encoder angles [rad] and
        speeds [rad/s] (None: not valid throughout) to the estimator, which answers through the controller
        to take_commands before this returns."""
        e = self.estimator
        with e.sample_lock:
            if theta is not None and e.sensored:
                e.take_rotor_state(sec, nanosec, theta, velocity, None)
            e.take_currents(sec, nanosec, currents[:, 0], currents[:, 1], currents[:, 2])

    def hand_sample(self, s, velocity):
        """The same for one sample (blocks of one; ``velocity``: None where the encoder is not valid)."""
        e, (sec, nanosec) = self.estimator, stamp_parts(s.k, self.T_s)
        with e.sample_lock:
            if velocity is not None and e.sensored:
                e.take_rotor_state(sec, nanosec, s.theta_m, velocity, None)
            e.take_currents(sec, nanosec, s.i_a, s.i_b, s.i_c)

    def report_zero_volts(self, b):
        """`zero_voltage` for a block whose periods ran at zero volts, before its currents: the estimator
        then pairs them with zero, not with their commands."""
        if b.at_zero_volts and self.T_s is not None:
            self.zero_voltage_periods += len(b)
            sec, nanosec = stamp_parts(b.k0, self.T_s)
            if self.estimator is not None:
                with self.estimator.sample_lock:
                    self.estimator.on_zero_voltage(sec, nanosec, np.ones(len(b)), NO_CHANNEL, NO_CHANNEL)
            self.zero_voltage_pub.publish(self.zero_voltage_wire.encode(sec, nanosec, np.ones(len(b)),
                                                                        NO_CHANNEL))

    def on_voltage_block(self, sec, nanosec, u_alpha, u_beta, _):
        if self.T_s is not None:
            self.command_block(sample_at(sec, nanosec, self.T_s), u_alpha, u_beta, f"{sec}.{nanosec:09d}")

    def take_commands(self, k, u_alpha, u_beta):
        """The voltage command of sample k (floats), or with blocks of the block from sample k (arrays),
        handed over by the controller of this process (ControllerNode.hand_commands_to): on the link at once."""
        if self.T_s is None:
            return
        if self.block_samples > 1:
            self.command_block(k, u_alpha, u_beta, f"of sample {k}")
        else:
            self.command(k, u_alpha, u_beta, f"of sample {k}")

    def command_block(self, k0, u_alpha, u_beta, which):
        """COMMAND_BLOCK from sample k0; anything but a block of finite voltages: safe state."""
        if k0 is None or len(u_alpha) != self.block_samples or len(u_beta) != self.block_samples or not (
                np.isfinite(u_alpha).all() and np.isfinite(u_beta).all()):
            self.fault("bad_input", f"voltage_command_block {which}: not a block of "
                                    f"{self.block_samples} voltages; safe state")
            self.bridge.safe_state("bad voltage_command_block")
            return
        self.bridge.command_block(k0, u_alpha, u_beta)
        QUIET_TIME.quiet()

    def on_rotor_estimate_block(self, sec, nanosec, theta_m_hat, omega_m_hat, _):
        """`angle_error` of each block's first sample."""
        if self.T_s is None:
            return
        k0 = sample_at(sec, nanosec, self.T_s)
        encoder = self.history.get(k0)
        if encoder is None or not len(theta_m_hat) or not finite(theta_m_hat[0], omega_m_hat[0]):
            return
        theta, velocity = encoder
        error = Vector3Stamped()
        error.header.stamp = stamp(k0, self.T_s)
        error.vector.x = wrap(self.n_p * (theta[0] - theta_m_hat[0]))
        error.vector.y = velocity[0] - omega_m_hat[0]
        self.angle_error_pub.publish(error)

    def answered_by(self, counters, T_s, n_p):
        """A compiled answer owns the link (``answered_elsewhere``): its ``counters()`` are the bridge's on
        /diagnostics; samples of ``T_s`` [s] from a motor of ``n_p`` pole pairs (the inverter's HELLO is read
        by the answer)."""
        self.live_counters, self.T_s, self.n_p = counters, T_s, n_p
        self.publish_config({"T_s_s": T_s, "n_p": n_p, "answer": "compiled"})

    def configure(self, hello):
        """The inverter's HELLO sets the sampling period and is published in drive_config."""
        self.n_p, self.T_s = hello.n_p, hello.T_s_ns * 1e-9
        self.publish_config({"T_s_s": self.T_s, "n_p": self.n_p, "inverter": vars(hello)})

    def report_new_faults(self):
        counters = self.live_counters() if self.live_counters else self.bridge.counters
        counts = {**counters, **{f"frame_{k}": v for k, v in self.bridge.frame_errors().items()}}
        for kind in ("dropped", "duplicated", "reordered", "link_lost", "bus_off", "safe_state",
                     "inverter_faults", "command_errors", "frame_crc", "frame_framing", "frame_version",
                     "frame_unknown_type"):
            new = counts.get(kind, 0) - self.reported.get(kind, 0)
            if new > 0:
                detail = self.bridge.last_error or ", ".join(self.bridge.status_names())
                self.fault(kind, f"{kind}: {new} new ({detail})")
        self.reported = counts
        if self.bridge.safe or (self.bridge.lost and self.bridge.counters["samples"]):
            self.health.level = DiagnosticStatus.ERROR
            self.health.message = self.bridge.last_error or "link down"
        elif self.bridge.lost and self.health.level == DiagnosticStatus.OK:
            self.health.level = DiagnosticStatus.WARN
            self.health.message = f"waiting for the inverter ({self.bridge.last_error or 'no telemetry yet'})"

    def on_voltage_command(self, msg):
        if self.T_s is not None:
            self.command(sample_of(msg.header, self.T_s), msg.vector.x, msg.vector.y,
                         f"{msg.header.stamp.sec}.{msg.header.stamp.nanosec:09d}")

    def command(self, k, u_alpha, u_beta, which):
        """COMMAND of sample k; anything but a sample's finite voltage: safe state."""
        if k is None or not finite(u_alpha, u_beta):
            self.fault("bad_input", f"voltage_command {which}: ({u_alpha}, {u_beta}) is not a sample's "
                                    f"voltage; safe state")
            self.bridge.safe_state("bad voltage_command")
            return
        self.bridge.command(k, u_alpha, u_beta)
        QUIET_TIME.quiet()

    def on_clear_faults(self, request, response):
        """The operator's reset (service `clear_faults`): CONTROL 2, the only way an overcurrent clears."""
        response.success = self.bridge.clear_faults()
        reason = self.bridge.last_error or "link down"
        response.message = "sent" if response.success else f"not sent: {reason}"
        return response

    def on_rotor_estimate(self, msg):
        if self.T_s is None:
            return
        k = sample_of(msg.header, self.T_s)
        encoder = self.history.get(k)
        if encoder is None or not finite(*msg.position, *msg.velocity):
            return
        theta_m, omega_m = encoder
        error = Vector3Stamped()
        error.header.stamp = msg.header.stamp
        error.vector.x = wrap(self.n_p * (theta_m - msg.position[0]))
        error.vector.y = omega_m - msg.velocity[0]
        self.angle_error_pub.publish(error)

    def status_values(self):
        b = self.bridge
        counters = self.live_counters() if self.live_counters else b.counters
        return {"link": "lost" if b.lost else "up", "inverter_status": ",".join(b.status_names()) or "ok",
                "zero_voltage_periods": self.zero_voltage_periods,
                "last_sample": b.last_seq if b.last_seq is not None else -1,
                **counters, **{f"frame_errors.{k}": v for k, v in b.frame_errors().items()}}

    def data_time(self):
        """The stamp of the inverter's latest sample (the data's clock); the node's clock before any."""
        return stamp(self.k, self.T_s) if self.k is not None else super().data_time()

    def destroy_node(self):
        self.running = False
        if self.thread.is_alive():
            self.thread.join(timeout=1.0)
        self.bridge.close()
        QUIET_TIME.release()
        return super().destroy_node()


def main(argv=None):
    """``bridge_node [--executor events|single] --ros-args -p link:=serial|can ...`` (``ros2 run drive_bridge
    bridge_node``)."""
    return run_node(InverterBridgeNode, "bridge_node", argv)


if __name__ == "__main__":
    sys.exit(main())
