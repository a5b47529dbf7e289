"""The ``pmsm_plant`` node: the plant core over topics, in lock-step on sim time.

Publishes sample k (`currents`, `rotor_state`, `/clock` unless another node does), waits for
`voltage_command` stamped k, takes it into its delay line (drive_common.math.command_delay) and advances to
k+1 under the command the line holds for period k. A command with another stamp is discarded and
counted; if no valid command comes within ``lockstep_timeout_s`` the plant applies zero voltage for that
period and names the silent topic.
`angle_error` is published for each `rotor_estimate` that matches a recent sample.

With ``scenario_schedule`` (set by the launcher: the scenario is the dyno) the plant applies its
scenario's load torque of sample k, and the shaft speed of imposed-speed scenarios, sample-exact and with
no message per sample; it starts at the first `load_torque` message (the launcher's go, sent once every
endpoint is matched), whose value the schedule already has. Otherwise the latest `load_torque` and
`speed_command` apply.

A scenario's holding brake keeps the shaft at rest until its lift time after the estimator first
reports tracking: until that report the plant advances sample k only once it has `estimator_state`(k)
too, so the release falls on the same sample as in one process.

The plant runs in blocks of ``block_samples`` N samples (simulated by ``plant_block`` from the commands
of earlier blocks), N = 1 the per-sample case: with N > 1 it publishes `currents_block` and
`rotor_state_block`, waits for `voltage_command_block` of the block, and simulates the next; a brake's
release is learnt from `estimator_state_block` one block later (as drive_tools.runner.loop.run_blocks
models it). With N = 1 the same path carries the per-sample topics.
"""
import sys
import time

import numpy as np
from geometry_msgs.msg import Vector3Stamped
from std_msgs.msg import Float64

from drive_common.config.parameters import SCHEDULE_PARAMETER
from drive_common.contract.stamps import sample_at, stamp_parts
from drive_common.contract.topics import (
    ANGLE_ERROR,
    CURRENTS,
    ESTIMATOR_STATE,
    LOAD_TORQUE,
    ROTOR_ESTIMATE,
    ROTOR_STATE,
    SPEED_COMMAND,
    TOPICS,
    VOLTAGE_COMMAND,
)
from drive_common.contract.wire import BlockWire, JointWire, Vector3Wire, encode_clock
from drive_common.math.command_delay import issue_command
from drive_common.math.frames import wrap
from drive_common.ros.node import DriveNode, SamplePublisher, finite, run_node, topic_qos

from .build import plant_for_scenario
from .model import NOT_RELEASED, plant_block

HISTORY_SAMPLES = 8


class PlantNode(DriveNode):
    node_parameters = {**SCHEDULE_PARAMETER, "currents_readers": (
        2, "lock-step readers of currents to wait for before sample 0: the estimator and the controller (2), or "
           "the estimator alone where the controller takes them from it in one process (1: drive launch "
           "--intra-process)")}

    def __init__(self, **kwargs):
        super().__init__("pmsm_plant", **kwargs)
        self.declare_parameter("angle_error_decimation", 1)
        self.offer_clock()
        self.scheduled = bool(self.get_parameter("scenario_schedule").value)
        self.go = not self.scheduled
        self.angle_error_decimation = max(1, int(self.get_parameter("angle_error_decimation").value))
        self.currents_pub = self.sample_publisher(self.contract_topics(CURRENTS)[0])
        self.rotor_state_pub = self.sample_publisher(self.contract_topics(ROTOR_STATE)[0])
        self.clock_pub = None
        self.angle_error_pub = SamplePublisher(self.create_publisher(Vector3Stamped, ANGLE_ERROR,
                                                                     topic_qos(ANGLE_ERROR)))
        voltage, estimate, state = self.contract_topics(VOLTAGE_COMMAND, ROTOR_ESTIMATE, ESTIMATOR_STATE)
        self.voltage_sub = self.sample_subscription(voltage, self.timed(self.per_message(self.on_voltage_block)))
        self.sample_subscription(estimate, self.per_message(self.on_rotor_estimate_block))
        self.create_subscription(Float64, LOAD_TORQUE, self.on_load_torque, topic_qos(LOAD_TORQUE))
        self.create_subscription(Float64, SPEED_COMMAND, self.on_speed_command, topic_qos(SPEED_COMMAND))
        self.braked = bool(self.configured and self.scenario.brake)
        """Waiting for the estimator's first tracking sample (the brake's lift time starts there)."""
        self.brake_release_k = None
        self.brake_states = {}
        self.pending_command = None
        self.state_sub = None
        if self.braked:
            self.state_sub = self.sample_subscription(state, self.per_message(self.on_estimator_state_block))
        self.k = 0
        self.tau_load = 0.0
        self.latest_speed = 0.0
        self.started = False
        self.finished = False
        self.sent_at = 0.0
        self.history = {}
        self.estimate_seen = -1
        self.zero_voltage_periods = 0
        self.currents_wire = Vector3Wire(TOPICS[CURRENTS].frame_id)
        self.rotor_state_wire = JointWire("rotor")
        self.error_wire = Vector3Wire(TOPICS[ANGLE_ERROR].frame_id)
        self.currents_block_wire = BlockWire(TOPICS[CURRENTS].frame_id)
        self.rotor_state_block_wire = BlockWire()
        self.schedule = None
        if self.configured:
            s, p = self.scenario, self.plant
            self.n_samples = s.n_samples
            if self.scheduled:
                self.schedule = s.schedule()
            else:
                self.commanded = (np.zeros(s.n_samples), np.zeros(s.n_samples))
                """Speed and load per period, filled from the latest commands as blocks are simulated."""
            self.plant_out = np.zeros((self.block_samples, 10))
            self.publish_config({"scenario": s.name, "T_s_s": s.T_s, "samples": s.n_samples,
                                 "mode": s.mode, "machine": p.machine, "mechanics": p.mechanics,
                                 "inverter": p.inverter, "sensor": p.sensor, "non_idealities": s.non_idealities})
            self.create_timer(min(self.timeout_s / 4.0, 0.05), self.watchdog)
            self.watch_foreign_publishers(self.contract_topics(VOLTAGE_COMMAND))
        else:
            self.publish_config({})

    def build(self, scenario):
        self.plant = plant_for_scenario(scenario)

    def warm_up(self):
        p = self.plant
        line = p.line.copy()
        issue_command(line, 0, 0.0, 0.0)
        wrap(0.0)
        plant_block(p.x.copy(), line, 1, 1, p.inputs(np.zeros(2), np.zeros(2)), p.params, np.zeros((1, 10)))

    def per_message(self, callback):
        """``callback`` of a block topic, as the subscription of this drive's topic calls it: unchanged when
        it carries blocks; with one sample per message, its values as blocks of one (empty where None)."""
        if self.block_samples > 1:
            return callback
        return lambda sec, nanosec, *values: callback(
            sec, nanosec, *(np.empty(0) if value is None else np.array([value], dtype=float) for value in values))

    def on_load_torque(self, msg):
        if not finite(msg.data):
            self.fault("bad_input", f"load_torque: {msg.data} is not a finite torque; ignored")
            return
        if self.scheduled:
            self.go = True
        else:
            self.tau_load = msg.data

    def on_speed_command(self, msg):
        if finite(msg.data):
            self.latest_speed = msg.data

    def ready(self):
        """Every lock-step partner is matched: `currents` reaches every subscriber the graph shows (at
        least ``currents_readers``; a graph entry is not yet a match), so do `rotor_state` and
        `angle_error` (a watcher the graph shows, `drive echo`, is matched before the first sample; it hears
        the samples once its own side has matched too, which Fast DDS may finish later), a
        `voltage_command` publisher is matched, `estimator_state` too while a brake holds, and the
        launcher's go has come when the scenario is the schedule. With the shaft held (commissioning) one
        partner answers currents with voltages and no estimator runs."""
        matched = self.currents_pub.get_subscription_count()
        held = self.parameters["shaft_held"]
        readers = 1 if held else int(self.get_parameter("currents_readers").value)
        currents, estimate, rotor = self.contract_topics(CURRENTS, ROTOR_ESTIMATE, ROTOR_STATE)
        watched = all(publisher.get_subscription_count() >= self.count_subscribers(topic)
                      for publisher, topic in ((self.rotor_state_pub, rotor), (self.angle_error_pub, ANGLE_ERROR)))
        return (watched and matched >= max(readers, self.count_subscribers(currents))
                and self.voltage_sub.get_publisher_count() >= 1
                and (held or self.count_publishers(estimate) >= 1)
                and (self.state_sub is None or self.state_sub.get_publisher_count() >= 1) and self.go)

    def watchdog(self):
        if self.finished:
            return
        if not self.started:
            if self.ready():
                self.started = True
                self.clock_pub = self.claim_clock()
                self.publish_block()
            return
        if time.monotonic() - self.sent_at <= self.timeout_s:
            return
        estimating = not self.parameters["shaft_held"] and self.estimate_seen < self.k
        silent = ROTOR_ESTIMATE if estimating else VOLTAGE_COMMAND
        self.fault("timeout", f"sample {self.k}: no answer within {self.timeout_s:g} s (silent topic: "
                              f"{self.resolve_topic_name(self.contract_topics(silent)[0])}); zero voltage applied")
        self.advance_block(np.zeros(self.block_length()), np.zeros(self.block_length()), safe_state=True)

    def block_length(self):
        """Samples in the block that starts at self.k (the last block of a run may be shorter)."""
        return min(self.block_samples, self.n_samples - self.k)

    def publish_block(self):
        """Simulate the block of samples self.k … (each period under the delay line's command) and publish
        it: `currents_block`, `rotor_state_block`, `/clock` at its first sample."""
        p, k0, n = self.plant, self.k, self.block_length()
        if self.schedule:
            speed, load = self.schedule
        else:
            speed, load = self.commanded
            periods = slice(max(k0 - 1, 0), k0 + n - 1)
            speed[periods], load[periods] = self.latest_speed, self.tau_load
        release = -1
        if self.scenario.brake:
            release = NOT_RELEASED if self.braked else self.brake_release_k
        out = self.plant_out[:n]
        plant_block(p.x, p.line, k0, n, p.inputs(load, speed, release), p.params, out)
        self.history[k0] = out[:, 6:8].copy()
        self.history.pop(k0 - HISTORY_SAMPLES * self.block_samples, None)
        sec, nanosec = stamp_parts(k0, self.T_s)
        if self.clock_pub:
            self.clock_pub.publish(encode_clock(sec, nanosec))
        self.sent_at = time.monotonic()
        if self.block_samples > 1:
            self.rotor_state_pub.publish(self.rotor_state_block_wire.encode(sec, nanosec, out[:, 6], out[:, 7],
                                                                            out[:, 8]))
            self.currents_pub.publish(self.currents_block_wire.encode(sec, nanosec, out[:, 3], out[:, 4], out[:, 5]))
        else:
            self.rotor_state_pub.publish(self.rotor_state_wire.encode(sec, nanosec, *out[0, 6:9]))
            self.currents_pub.publish(self.currents_wire.encode(sec, nanosec, *out[0, 3:6]))

    def on_voltage_block(self, sec, nanosec, u_alpha, u_beta, _):
        if not self.started or self.finished:
            return
        k0, n = sample_at(sec, nanosec, self.T_s), self.block_length()
        if k0 != self.k or len(u_alpha) != n or len(u_beta) != n:
            self.fault("wrong_stamp", f"{self.contract_topics(VOLTAGE_COMMAND)[0]} stamped "
                                      f"{sec}.{nanosec:09d} with {len(u_alpha)} samples while waiting for the {n} "
                                      f"of sample {self.k}; discarded")
            return
        limit = self.plant.inverter.U_dc_V
        if not (np.isfinite(u_alpha).all() and np.isfinite(u_beta).all()) or max(
                np.abs(u_alpha).max(), np.abs(u_beta).max()) > limit:
            self.fault("bad_input", f"{self.contract_topics(VOLTAGE_COMMAND)[0]} of sample {k0}: not voltages the "
                                    f"inverter can apply; zero voltage applied for the block")
            self.advance_block(np.zeros(n), np.zeros(n), safe_state=True)
            return
        if self.braked and k0 not in self.brake_states:
            self.pending_command = (u_alpha, u_beta)
            return
        self.advance_block(u_alpha, u_beta)

    def on_estimator_state_block(self, sec, nanosec, _, __, states):
        """While the brake holds: the estimator's states of a block (its first tracking sample releases it)."""
        k0 = sample_at(sec, nanosec, self.T_s)
        if not self.braked or k0 is None or k0 < self.k:
            return
        self.brake_states[k0] = states
        if self.pending_command is not None and self.k in self.brake_states:
            self.advance_block(*self.pending_command)

    def advance_block(self, u_alpha, u_beta, safe_state=False):
        """Take the block's commands (zero voltage as the safe state after a fault) into the delay line and
        simulate the next block."""
        p, k0, n = self.plant, self.k, len(u_alpha)
        self.zero_voltage_periods += n if safe_state else 0
        self.pending_command = None
        for i in range(n):
            issue_command(p.line, k0 + i, u_alpha[i], u_beta[i])
        if self.braked:
            tracking = np.flatnonzero(self.brake_states.pop(k0, np.empty(0)) == 3.0)
            if tracking.size:
                self.braked = False
                self.brake_states.clear()
                self.brake_release_k = max(k0 + int(tracking[0]) + round(self.scenario.brake_release_s / self.T_s),
                                           k0 + n - 1)
        self.sample_handled(k0 + n - 1)
        self.k = k0 + n
        if self.k >= self.n_samples:
            self.finished = True
            return
        self.publish_block()

    def on_rotor_estimate_block(self, sec, nanosec, theta_m_hat, omega_m_hat, _):
        """`angle_error` of each block's first sample (introspection, decimated to one per block at least)."""
        k0 = sample_at(sec, nanosec, self.T_s)
        if k0 is None or k0 not in self.history or not len(theta_m_hat) or not len(omega_m_hat):
            return
        self.estimate_seen = max(self.estimate_seen, k0 + len(theta_m_hat) - 1)
        if (k0 // self.block_samples) % max(1, self.angle_error_decimation // self.block_samples) or not finite(
                theta_m_hat[0], omega_m_hat[0]):
            return
        theta_m, omega_m = self.history[k0][0]
        n_p = self.plant.machine.n_p
        self.angle_error_pub.publish(self.error_wire.encode(sec, nanosec, wrap(n_p * (theta_m - theta_m_hat[0])),
                                                            omega_m - omega_m_hat[0], 0.0))

    def status_values(self):
        return {"sample": self.k, "started": self.started, "finished": self.finished,
                "sim_time_s": self.k * self.T_s, "safe_state_periods": self.zero_voltage_periods}


def main(argv=None):
    """``plant_node [--executor events|single] --ros-args ...`` (``ros2 run pmsm_plant plant_node``)."""
    return run_node(PlantNode, "plant_node", argv)


if __name__ == "__main__":
    sys.exit(main())
