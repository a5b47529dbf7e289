"""An armed axis's answer compiled whole (docs/robot.md, "The compiled answer per axis"): the axis's own cores and
states (its estimator node's estimator, its controller node's controller and protections) stepped by
drive_tools.runner.compiled_answer's loop, which reads and writes the inverter's link off the interpreter's lock on a
thread of its own (SCHED_FIFO where the robot's real-time settings allow). What is not real-time runs on the answer's
ring reader, from the rows the loop answered: what the axis is told (homing, the command hold, the position loop:
ControllerNode.reference's decisions, as a foc_controller.speed_command the loop follows on its own, a position loop
included), the speed supervision, `joint_states`, every contract topic (each node publishes its own) and /diagnostics.
A reader that falls silent for COMMAND_STALE_S leaves the loop holding zero speed, never the last command."""
import time
from typing import NamedTuple

import numpy as np

from drive_bridge.inverter_bridge import BridgeBlock
from drive_bridge.inverter_protocol import INDEX_TOGGLE
from drive_common.contract.log import COLUMN, LOG_COLUMNS
from drive_common.math.command_delay import command_line
from drive_tools.runner.compiled_answer import (
    COMMAND_AT_NS,
    COMMAND_SLOT,
    COMMAND_SLOTS,
    LAST_ANSWERED,
    OPEN_ENDED,
    ORIGIN,
    RING_K,
    RING_LOG,
    RING_STATUS,
    RING_THETA_M,
    STALE_NS,
    AnswerOptions,
    AnswerParts,
    CompiledAnswer,
    RingBlocks,
    host_core,
    warm_answer,
)
from drive_tools.runner.loop import DriveCores
from foc_controller.speed_command import speed_command

COMMAND_STALE_S = 0.5
"""The live command not written for this long (its reader stalled or died): the loop holds zero speed."""
CURRENTS = slice(RING_LOG + COLUMN["i_a_meas"], RING_LOG + COLUMN["i_c_meas"] + 1)


def axis_parts(estimator, controller):
    """AnswerParts of an axis's ``estimator`` (EstimatorNode) and ``controller`` (ControllerNode, its core built):
    their cores and states (what the loop changes is theirs, read by their /diagnostics), a live command (at first:
    zero speed)."""
    e, c = estimator, controller
    cores = DriveCores(e.core, c.params, c.x, c.z, c.protection, c.protection_x, c.sensing)
    commands = np.tile(speed_command(0.0), (COMMAND_SLOTS, 1))
    return AnswerParts(cores, e.estimator.step, np.zeros(1), np.array([c.tau_feedforward]), commands, e.T_s)


def warm_axis_answer(bridge_node, estimator, controller):
    """Load (or compile, once: tens of seconds) the loop an axis's AxisAnswer will run, touching nothing of the
    axis: done while it is inactive, so that arming it takes no compile."""
    parts = axis_parts(estimator, controller)
    host = host_core(parts, command_line(estimator.delay), bridge_node.block_samples)
    warm_answer(host, parts.step, bridge_node.bridge, RING_LOG + len(LOG_COLUMNS))


class LiveCommand(NamedTuple):
    """The command the loop follows (AnswerParts.live_commands, the loop's ``run`` array's COMMAND_SLOT and
    COMMAND_AT_NS) and the torque feed-forward it adds [N·m] (an array of one)."""

    commands: np.ndarray
    tau_feedforward: np.ndarray
    run: np.ndarray

    def write(self, command, tau_feedforward):
        """A new ``command`` (foc_controller.speed_command's fields) into the row after the one followed, then the
        row's index; the feed-forward [N·m]; now as when it was written."""
        slot = (int(self.run[COMMAND_SLOT]) + 1) % COMMAND_SLOTS
        self.commands[slot] = command
        self.run[COMMAND_SLOT] = slot
        self.tau_feedforward[0] = tau_feedforward
        self.run[COMMAND_AT_NS] = time.monotonic_ns()


class AxisAnswer:
    """The compiled answer of an axis's ``bridge_node`` (its link handed over: InverterBridgeNode.hand_link_over),
    ``estimator`` (EstimatorNode) and ``controller`` (ControllerNode, its core built), the loop's thread at SCHED_FIFO
    ``priority`` (0: normal scheduling). The drive counts its samples from the first whole block the loop takes (its
    start-up's sample 0); every topic is stamped in the inverter's count, as the nodes' answer stamps it."""

    def __init__(self, bridge_node, estimator, controller, priority=0):
        e, c = estimator, controller
        self.bridge_node, self.estimator, self.controller = bridge_node, e, c
        parts = axis_parts(e, c)
        self.answer = CompiledAnswer(parts, bridge_node.bridge, command_line(e.delay), (OPEN_ENDED, e.delay),
                                     AnswerOptions(priority=priority), origin=-1)
        run = self.answer.run
        run[COMMAND_AT_NS], run[STALE_NS] = time.monotonic_ns(), round(COMMAND_STALE_S * 1e9)
        self.live = LiveCommand(parts.live_commands, parts.tau_feedforward, run)
        self.origin = None
        """The inverter's sample the drive counts from, once the loop has taken its first block."""
        self.ring_blocks = RingBlocks(bridge_node.block_samples, RING_LOG + len(LOG_COLUMNS))
        self.handed_up_to = -1
        """The inverter's last sample whose row has been handed on (its topics published, the next command
        decided)."""
        self.error = None
        """What the reader raised (the axis's nodes then publish nothing more), or None."""

    @property
    def scheduling(self):
        return self.answer.scheduling

    def start(self):
        self.answer.start(self.take)

    def stop(self, timeout_s=2.0):
        """The loop stopped (within its poll, 50 ms) and its rows handed over. A loop that died of an exception is
        not raised again here (it is the answer's ``error``, which AxisNode.answer_failure reports): stopping an axis
        always goes on to its safe state."""
        self.answer.stop()
        try:
            self.answer.join(timeout_s)
        except Exception:
            pass

    def alive(self):
        return self.answer.alive()

    @property
    def overflow(self):
        return self.answer.overflow

    def take(self, rows):
        """Rows the ring handed over (compiled_answer's RING_K, RING_HOST_S, RING_THETA_M, RING_STATUS, then the log
        row), on its reader: each whole block to the bridge node (`currents`, `rotor_state`, the link's faults), the
        estimator node (its topics, its state's changes) and the controller node (the command for the blocks to come,
        the index input's state, the supervision, `joint_states`, `voltage_command`)."""
        if self.error is not None:
            return
        try:
            self.hand_on(rows)
        except Exception as error:
            self.error = error
            self.controller.fault("answer_reader", f"the compiled answer's reader stopped: {error!r}; the loop holds "
                                                   f"zero speed from {COMMAND_STALE_S:g} s on")

    def hand_on(self, rows):
        e, c = self.estimator, self.controller
        if self.origin is None:
            self.origin = int(self.live.run[ORIGIN])
            with e.sample_lock:
                e.stamp_origin = c.stamp_origin = self.origin
                c.join_at(0)
        for here in self.ring_blocks.blocks(rows):
            k_drive = int(here[0, RING_K]) - self.origin
            currents = np.ascontiguousarray(here[:, CURRENTS])
            theta = np.ascontiguousarray(here[:, RING_THETA_M])
            self.bridge_node.publish_blocks([BridgeBlock(int(here[0, RING_K]), currents, theta, np.nan, 0)])
            e.publish_answered(k_drive, here[:, RING_LOG:])
            index = int(bool(int(here[-1, RING_STATUS]) & INDEX_TOGGLE))
            c.take_answered(k_drive, here[:, RING_LOG:], self.live, index)
            self.handed_up_to = int(here[-1, RING_K])

    def caught_up(self, k):
        """Whether the row of the inverter's sample k has been handed on, where the loop answered it (or the loop has
        stopped)."""
        run = self.live.run
        answered = run[ORIGIN] + run[LAST_ANSWERED] if run[ORIGIN] >= 0 else -1
        return self.handed_up_to >= min(k, answered) or not self.answer.alive()
