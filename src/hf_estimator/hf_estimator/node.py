"""The ``hf_estimator`` node: an estimator core over topics.

For sample k it joins `currents`(k) with the voltage applied during the period that produced them,
`voltage_command`(k−1−d) from its delay line (drive_common.math.command_delay; d the drive's delay; zero
before sample 0, and zero if the controller stays silent past half the lock-step timeout, which is what
the plant then applied) and, for `sensored` only, `rotor_state`(k). It answers
`rotor_estimate`(k), `injection`(k), `estimator_state`(k) (x = ε, y = signal, z = the start-up state
code, hf_estimator.startup) and `estimator_blend`(k) (x = injection amplitude, y = observer weight, z =
leader; on /diagnostics too). Each sample, or each block of N (``block_samples`` N > 1: it takes
`currents_block` and `voltage_command_block` and answers the block twins, plus `estimator_state` of each
block's first sample), is one call of ``estimator_block``. In one process with the inverter's bridge (``drive launch
--link ... --intra-process``) these inputs are handed over on the bridge's link thread, not subscribed to:
the whole block, from its telemetry to its command, runs there (docs/ros-graph.md, "Real time"). A lost
lock or a refused start is a fault (ERROR on /diagnostics, counted).
Non-finite or absurd currents are not fed to the core: the node answers with its last estimate and
no injection, and reports the fault.

What it knows of the motor: the scenario's nameplate and the commissioning record
(``DriveNode.load_commissioning``); it reads the currents corrected by the record's sensor
calibration. Its drive_config carries what the controller needs of it (``Estimator.facts``) and every
motor value it uses with its source (``motor_knowledge``).
"""
import sys
import threading
import time

import numpy as np

from drive_common.contract.drive_records import drive_inputs
from drive_common.contract.estimator_records import estimates
from drive_common.contract.estimator_states import LEADER_NAMES, LOCK_LOST, STATE_NAMES
from drive_common.contract.log import COLUMN
from drive_common.contract.stamps import RESYNC_SAMPLES, sample_at, stamp_parts
from drive_common.contract.topics import (
    CURRENTS,
    ESTIMATOR_BLEND,
    ESTIMATOR_STATE,
    INJECTION,
    ROTOR_ESTIMATE,
    ROTOR_STATE,
    TOPICS,
    VOLTAGE_COMMAND,
    ZERO_VOLTAGE,
    block,
)
from drive_common.contract.wire import BlockWire, JointWire, Vector3Wire
from drive_common.math.command_delay import command_line, issue_command
from drive_common.math.current_sensing import current_sensing
from drive_common.math.winding import R_S_IN_USE, winding_block, winding_params, winding_state
from drive_common.motor.commissioning import commissioning_record
from drive_common.motor.knowledge import motor_knowledge
from drive_common.ros.node import DriveNode, finite, run_node
from drive_common.runtime.bound_kernels import bound

from .block import estimator_block
from .build import estimator_for_scenario
from .interface import contract_injection
from .startup import estimator_startup


class EstimatorNode(DriveNode):
    def needs_experiment(self):
        return False

    def __init__(self, inputs_handed=False, **kwargs):
        """``inputs_handed``: the currents, `zero_voltage`, `rotor_state` and the commands come from the
        drive_bridge node and the controller of this process (``take_currents``, ``on_zero_voltage``,
        ``take_rotor_state``, ``take_handed_commands``, called holding ``sample_lock``), not over topics."""
        super().__init__("hf_estimator", **kwargs)
        self.inputs_handed = inputs_handed
        self.sample_lock = threading.Lock()
        """Held while a sample or block is stepped: by the bridge's link thread where the inputs are handed
        over, and by the executor's callbacks that step or rebuild what it steps (the watchdog's)."""
        self.currents = {}
        self.issued = -1
        """The last sample whose voltage_command is in the delay line."""
        self.encoder = {}
        self.waiting_since = None
        self.estimate_wire = JointWire("rotor")
        self.injection_wire = Vector3Wire(TOPICS[INJECTION].frame_id)
        self.state_wire = Vector3Wire(TOPICS[ESTIMATOR_STATE].frame_id)
        self.blend_wire = Vector3Wire(TOPICS[ESTIMATOR_BLEND].frame_id)
        self.blend = (0.0, 0.0, 0.0)
        """The last sample's injection amplitude [V], observer weight and leader code (`estimator_blend`)."""
        self.block_wire = BlockWire()
        self.state = 0.0
        self.lock_losses = 0
        self.refusal_reported = False
        self.signal = 0.0
        self.answering = False
        """True once the answer publishers are open (their readers can hear the plant)."""
        self.hand_over = None
        """In one process, the controller's ``take_answers(k, currents, estimate, injection, state)``
        (hand_answers_to), else None."""
        if not self.configured:
            self.open_outputs()
            self.publish_config({})
            return
        e = self.estimator
        self.sensored = e.name == "sensored"
        self.n_p = self.nameplate().n_p
        self.delay = self.config.drive_delay_periods()
        self.line = command_line(self.delay)
        self.k = 0
        self.theta_hat = self.omega_hat = 0.0
        self.trip_A = self.trip_current_A()
        self.sensing = current_sensing(self.calibration, self.trip_A)
        self.zero_volts = set()
        """Samples whose commands the inverter reported not applied (`zero_voltage`), not yet in the line."""
        self.zero_voltage_periods = 0
        blocks = self.block_samples > 1
        self.take_currents = self.timed(self.on_currents_block if blocks else self.on_currents)
        self.take_rotor_state = self.on_rotor_state_block if blocks else self.on_rotor_state
        inputs = []
        if not inputs_handed:
            self.sample_subscription(ZERO_VOLTAGE, self.on_zero_voltage)
            inputs.append(self.sample_subscription(block(CURRENTS) if blocks else CURRENTS, self.take_currents))
            if blocks:
                self.sample_subscription(block(VOLTAGE_COMMAND), self.on_voltage_block)
            else:
                self.sample_subscription(VOLTAGE_COMMAND, self.on_voltage_command)
            if self.sensored:
                inputs.append(self.sample_subscription(block(ROTOR_STATE) if blocks else ROTOR_STATE,
                                                       self.take_rotor_state))
        self.open_when_matched(inputs, self.open_outputs)
        self.create_timer(min(self.timeout_s / 8.0, 0.05), self.watchdog)
        currents, voltages = self.contract_topics(CURRENTS, VOLTAGE_COMMAND)
        self.watch_peer(currents, "the plant")
        self.watch_foreign_publishers((currents, voltages))
        self.publish_config({**e.facts(), "injection": contract_injection(e.facts(), self.config.injection),
                             "motor_knowledge": motor_knowledge(self.nameplate(), self.commissioning),
                             "commissioning": commissioning_record(self.commissioning),
                             "estimator_parameters": e.params})

    def build(self, scenario):
        self.commissioning = self.load_commissioning(scenario)
        self.calibration = self.commissioning.calibration()
        self.estimator = estimator_for_scenario(scenario, self.commissioning)
        self.core = self.estimator.core()
        self.estimator_block = bound(estimator_block, self.estimator.step)
        """The estimator's block kernel bound to its step (drive_common.runtime.bound_kernels)."""
        self.winding = winding_params(scenario.motor.nameplate.rated_current_A, self.commissioning.R_s_ohm,
                                      scenario.T_s, scenario.protection)
        self.winding_x = winding_state()
        """The drive's winding estimate (drive_common.math.winding), run here on the currents the controller node's
        protections see, for the R̂_s the estimator's resistive drop takes."""

    def open_outputs(self):
        """The answer publishers; `voltage_command` is not waited for (the controller opens its own
        publisher only after these match, and sample 0 needs no previous command). In blocks, the block
        twins and `estimator_state` of each block's first sample (introspection)."""
        self.state_pub = self.sample_publisher(ESTIMATOR_STATE)
        if self.configured and self.block_samples > 1:
            self.estimate_pub = self.sample_publisher(block(ROTOR_ESTIMATE))
            self.injection_pub = self.sample_publisher(block(INJECTION))
            self.state_block_pub = self.sample_publisher(block(ESTIMATOR_STATE))
            self.blend_pub = self.sample_publisher(block(ESTIMATOR_BLEND))
        else:
            self.estimate_pub = self.sample_publisher(ROTOR_ESTIMATE)
            self.injection_pub = self.sample_publisher(INJECTION)
            self.blend_pub = self.sample_publisher(ESTIMATOR_BLEND)
        self.answering = True

    def hand_answers_to(self, take_answers):
        """In one process (``drive launch --intra-process``): hand each sample's or block's answers, with
        its currents, to ``take_answers(k, (i_a, i_b, i_c), (θ̂_m, ω̂_m), (u_α, u_β), state)`` (the
        controller's; per channel a float, or an array of the block's samples; state: its code, or with
        blocks (ε, signal, code)) before publishing them: the controller then waits for no delivery."""
        self.hand_over = take_answers

    def warm_up(self):
        e = self.estimator
        issue_command(command_line(1), 0, 0.0, 0.0)
        self.estimator_block(e.core(e.state.copy()), 0, 1, drive_inputs(1), command_line(1),
                             current_sensing(self.calibration, 1.0), estimates(1))
        winding_block(self.winding_x.copy(), self.winding, np.zeros((1, 3)), 1)

    def before_joining(self, k, n):
        """True when the currents of the n samples from k came before the answer publishers are open (a
        real inverter may stream before the drive is ready): not answered, and the estimator joins after
        them; the commands of the samples before it are zero in the delay line (nobody answered them)."""
        if self.answering:
            return False
        self.k = max(self.k, k + n)
        self.take_commands(self.k, [], [])
        return True

    def join_at(self, k0):
        """Join a running inverter's samples at k0 (an axis armed, drive_tools.launch.axis): nothing before k0 is
        answered, and the commands acting before it are zero in the delay line (none was sent)."""
        self.k = k0
        self.currents.clear()
        self.encoder.clear()
        self.issued = max(self.issued, k0 - self.delay - 2)
        self.take_commands(k0, [], [])

    def on_currents(self, sec, nanosec, i_a, i_b, i_c):
        k = sample_at(sec, nanosec, self.T_s)
        if k is not None and self.before_joining(k, 1):
            return
        if k is None or not self.k <= k <= self.k + RESYNC_SAMPLES:
            self.fault("wrong_stamp", f"currents stamp {sec}.{nanosec:09d} "
                                      f"is not a sample in {self.k}..{self.k + RESYNC_SAMPLES}; discarded")
            return
        if k > self.k:
            self.fault("missed_sample", f"currents of samples {self.k}..{k - 1} never arrived; following the "
                                        f"plant to sample {k}")
            self.currents.clear()
            self.k = k
        self.currents[k] = np.array([[i_a, i_b, i_c]], dtype=float)
        self.answer_ready()

    def on_voltage_command(self, sec, nanosec, u_alpha, u_beta, _):
        k = sample_at(sec, nanosec, self.T_s)
        if k is not None and k > self.issued:
            self.take_commands(k, [u_alpha], [u_beta])
            self.answer_ready()

    def take_handed_commands(self, k, u_alpha, u_beta):
        """The controller's commands of sample k (floats) or of the block from k (arrays), handed over in
        one process (inputs_handed): into the delay line, as `voltage_command` would bring them."""
        if self.block_samples > 1:
            self.on_voltage_block(*stamp_parts(k, self.T_s), u_alpha, u_beta, None)
        else:
            self.on_voltage_command(*stamp_parts(k, self.T_s), u_alpha, u_beta, None)

    def take_commands(self, k0, u_alpha, u_beta):
        """Commands of samples k0 … into the delay line (zero for samples skipped before k0, which the
        plant ran at zero volts, and for non-finite values)."""
        for k in range(self.issued + 1, k0):
            issue_command(self.line, k, 0.0, 0.0)
        for i, (u_a, u_b) in enumerate(zip(u_alpha, u_beta)):
            zero = not finite(u_a, u_b) or k0 + i in self.zero_volts
            issue_command(self.line, k0 + i, *((0.0, 0.0) if zero else (u_a, u_b)))
        self.issued = max(self.issued, k0 + len(u_alpha) - 1)
        if self.zero_volts:
            self.zero_volts = {k for k in self.zero_volts if k > self.issued}

    def on_zero_voltage(self, sec, nanosec, zero, _, __):
        """Periods j … of a block (or a sample) ran at zero volts (the inverter's report through the bridge):
        the commands of samples j − d are zero in the delay line, as they acted (those still in it, or when
        they come)."""
        j0 = sample_at(sec, nanosec, self.T_s)
        if j0 is None:
            return
        oldest = self.issued - self.delay
        for j in j0 + np.flatnonzero(zero):
            k = int(j) - self.delay
            if k > self.issued:
                self.zero_volts.add(k)
            elif k >= max(oldest, 0):
                issue_command(self.line, k, 0.0, 0.0)
            self.zero_voltage_periods += 1

    def on_rotor_state(self, sec, nanosec, theta_m, omega_m, _):
        k = sample_at(sec, nanosec, self.T_s)
        if k is not None and k >= self.k and theta_m is not None and omega_m is not None:
            self.encoder[k] = np.array([[self.n_p * theta_m, self.n_p * omega_m]])
            self.answer_ready()

    def note_state(self, k, state):
        """The estimator's state changed to ``state`` at sample k: a lost lock or a refused start is a fault."""
        if state == LOCK_LOST and self.state != LOCK_LOST:
            self.lock_losses += 1
            self.fault("lock_lost", f"sample {k}: lock lost (the back-EMF contradicts the estimate); zero torque, "
                                    f"starting again")
        summary = estimator_startup(self.estimator) if state != self.state and not self.refusal_reported else None
        if summary and summary["refused"]:
            self.refusal_reported = True
            self.fault("start_refused", f"sample {k}: {summary['refused']}")
        self.state = state

    def on_currents_block(self, sec, nanosec, i_a, i_b, i_c):
        k0 = sample_at(sec, nanosec, self.T_s)
        if k0 is not None and len(i_a) and self.before_joining(k0, len(i_a)):
            return
        if k0 is None or not self.k <= k0 <= self.k + RESYNC_SAMPLES or not len(i_a) == len(i_b) == len(i_c) > 0:
            self.fault("wrong_stamp", f"currents_block stamped {sec}.{nanosec:09d} is not a block of samples in "
                                      f"{self.k}..{self.k + RESYNC_SAMPLES} with three equal channels; discarded")
            return
        if k0 > self.k and self.k not in self.currents:
            self.fault("missed_sample", f"currents of samples {self.k}..{k0 - 1} never arrived; following the "
                                        f"plant to sample {k0} (no command answers them: zero volts)")
            self.take_commands(k0, [], [])
            self.k = k0
        self.currents[k0] = np.ascontiguousarray(np.column_stack((i_a, i_b, i_c)))
        self.answer_ready()

    def on_voltage_block(self, sec, nanosec, u_alpha, u_beta, _):
        k0 = sample_at(sec, nanosec, self.T_s)
        if k0 is None or k0 <= self.issued or len(u_alpha) != len(u_beta):
            return
        self.take_commands(k0, u_alpha, u_beta)
        self.answer_ready()

    def on_rotor_state_block(self, sec, nanosec, theta_m, omega_m, _):
        k0 = sample_at(sec, nanosec, self.T_s)
        if k0 is not None and k0 >= self.k and len(theta_m) == len(omega_m):
            self.encoder[k0] = np.ascontiguousarray(self.n_p * np.column_stack((theta_m, omega_m)))
            self.answer_ready()

    def answer_ready(self, force_voltage=False):
        """Answer every sample (block) whose inputs are in, in order (``force_voltage``: the first one even
        without the commands acting in its periods: zero volts there)."""
        answered = self.try_block(force_voltage)
        while answered:
            answered = self.try_block()

    def try_block(self, force_voltage=False):
        """Run the samples of self.k (a block of N, or one sample) once its currents are in and the delay line
        holds every command acting in its periods (those of the block before: d ≥ N − 1); True when it ran."""
        k0 = self.k
        if k0 not in self.currents:
            return False
        currents = self.currents[k0]
        n = len(currents)
        acted = k0 + n - 2 - self.delay
        if acted > self.issued and not force_voltage:
            self.waiting_since = self.waiting_since or time.monotonic()
            return False
        if self.sensored and k0 not in self.encoder:
            return False
        self.waiting_since = None
        del self.currents[k0]
        for k in range(self.issued + 1, acted + 1):
            issue_command(self.line, k, 0.0, 0.0)
        self.issued = max(self.issued, acted)
        encoder = self.encoder.pop(k0, None)
        if encoder is None or len(encoder) != n:
            encoder = np.zeros((n, 2))
        records, inputs = estimates(n), drive_inputs(n)
        inputs["i_a_A"], inputs["i_b_A"], inputs["i_c_A"] = currents.T
        inputs["theta_e_encoder_rad"], inputs["omega_e_encoder_rad_s"] = encoder.T
        self.core.sample[0]["R_s_ohm"] = self.winding_x[R_S_IN_USE]
        bad = self.estimator_block(self.core, k0, n, inputs, self.line, self.sensing, records)
        winding_block(self.winding_x, self.winding, currents, n)
        if bad:
            self.fault("bad_input", f"currents at samples {k0}..{k0 + n - 1}: {bad} of {n} not finite or beyond "
                                    f"the {self.trip_A:g} A trip; estimate held, no injection there")
        self.k = k0 + n
        self.note_records(k0, records)
        if self.block_samples > 1:
            self.publish_block(k0, records, currents)
        else:
            self.publish_sample(k0, records[0], currents[0])
        self.sample_handled(k0 + n - 1)
        return True

    def note_records(self, k0, records):
        """The ESTIMATE records of samples k0 …: each change of state noted (note_state), the last values kept for
        /diagnostics."""
        state = records["state"]
        for i in np.flatnonzero(state != np.concatenate(([self.state], state[:-1]))):
            self.note_state(k0 + i, state[i])
        last = records[-1]
        self.theta_hat, self.omega_hat, self.signal = last["theta_e_hat"], last["omega_e_hat"], last["signal"]
        self.blend = (last["injection_amplitude"], last["observer_weight"], last["leader"])

    def publish_answered(self, k0, rows):
        """What a compiled answer (drive_tools.launch.axis_answer) answered for the drive's samples k0 … k0 + n − 1,
        from their log rows (drive_common.contract.log.LOG_COLUMNS), as try_block publishes its own answers: the
        state's changes noted, the block twins (or each sample's topics). From the answer's ring reader, a thread
        that is not real-time; nothing is handed over (the answer ran the controller)."""
        records = estimates(len(rows))
        for name in records.dtype.names:
            records[name] = rows[:, COLUMN[name]]
        with self.sample_lock:
            self.k = k0 + len(rows)
            self.note_records(k0, records)
            if self.block_samples > 1:
                self.publish_records(k0, records)
            else:
                for i in range(len(rows)):
                    self.publish_sample_record(k0 + i, records[i])
            self.sample_handled(k0 + len(rows) - 1)

    def publish_block(self, k0, records, currents):
        """Publish a block's ESTIMATE records on the block twins, and `estimator_state` of its first sample
        (handed over first, with the block's ``currents``, where hand_answers_to said so)."""
        r = records
        if self.hand_over:
            self.hand_over(k0, currents.T, (r["theta_e_hat"] / self.n_p, r["omega_e_hat"] / self.n_p),
                           (r["u_inj_alpha"], r["u_inj_beta"]), (r["eps"], r["signal"], r["state"]))
        self.publish_records(k0, records)

    def publish_records(self, k0, records):
        """A block's ESTIMATE records on the block twins, and `estimator_state` of its first sample."""
        r, wire = records, self.block_wire
        state = r["state"]
        theta_m, omega_m = r["theta_e_hat"] / self.n_p, r["omega_e_hat"] / self.n_p
        sec, nanosec = stamp_parts(k0 + self.stamp_origin, self.T_s)
        self.injection_pub.publish(wire.encode(sec, nanosec, r["u_inj_alpha"], r["u_inj_beta"]))
        self.estimate_pub.publish(wire.encode(sec, nanosec, theta_m, omega_m))
        self.state_block_pub.publish(wire.encode(sec, nanosec, r["eps"], r["signal"], state))
        self.state_pub.publish(self.state_wire.encode(sec, nanosec, r[0]["eps"], r[0]["signal"], r[0]["state"]))
        self.blend_pub.publish(wire.encode(sec, nanosec, r["injection_amplitude"], r["observer_weight"], r["leader"]))

    def publish_sample(self, k, e, currents):
        """Publish sample k's ESTIMATE record on the per-sample topics (handed over first, with the sample's
        ``currents``, where hand_answers_to said so)."""
        if self.hand_over:
            self.hand_over(k, tuple(currents.tolist()), (e["theta_e_hat"] / self.n_p, e["omega_e_hat"] / self.n_p),
                           (e["u_inj_alpha"], e["u_inj_beta"]), e["state"])
        self.publish_sample_record(k, e)

    def publish_sample_record(self, k, e):
        """Sample k's ESTIMATE record on the per-sample topics."""
        theta_m, omega_m = e["theta_e_hat"] / self.n_p, e["omega_e_hat"] / self.n_p
        self.blend = (e["injection_amplitude"], e["observer_weight"], e["leader"])
        sec, nanosec = stamp_parts(k + self.stamp_origin, self.T_s)
        self.injection_pub.publish(self.injection_wire.encode(sec, nanosec, e["u_inj_alpha"], e["u_inj_beta"], 0.0))
        self.estimate_pub.publish(self.estimate_wire.encode(sec, nanosec, theta_m, omega_m))
        self.state_pub.publish(self.state_wire.encode(sec, nanosec, e["eps"], e["signal"], e["state"]))
        self.blend_pub.publish(self.blend_wire.encode(sec, nanosec, *self.blend))

    def watchdog(self):
        with self.sample_lock:
            self.force_when_silent()

    def force_when_silent(self):
        if self.waiting_since and time.monotonic() - self.waiting_since > self.timeout_s / 2.0:
            topic = self.resolve_topic_name(self.contract_topics(VOLTAGE_COMMAND)[0])
            self.fault("timeout", f"sample {self.k}: no {topic} for the commands acting in its period(s); "
                                  f"estimating with zero voltage (what the plant applied)")
            self.answer_ready(force_voltage=True)

    def status_values(self):
        if not self.configured:
            return {}
        amplitude, weight, leader = self.blend
        return {"sample": getattr(self, "k", 0), "state": STATE_NAMES.get(int(self.state), "?"),
                "lock_lost": self.lock_losses, "signal": self.signal, "estimator": self.estimator.name,
                "injection_amplitude_V": amplitude, "observer_weight": weight,
                "leader": LEADER_NAMES.get(int(leader), "?"), "zero_voltage_periods": self.zero_voltage_periods}


def main(argv=None):
    """``estimator_node [--executor events|single] --ros-args ...`` (``ros2 run hf_estimator estimator_node``)."""
    return run_node(EstimatorNode, "estimator_node", argv)


if __name__ == "__main__":
    sys.exit(main())
