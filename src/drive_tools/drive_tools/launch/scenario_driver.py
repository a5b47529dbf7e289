"""The launcher's scenario driver: the node that stands in for the dyno and the operator of a simulated
drive, and records what the graph says."""
import threading
import time
from dataclasses import dataclass

import numpy as np
from rclpy.serialization import deserialize_message, serialize_message
from std_msgs.msg import Float64

from drive_common.contract.log import COLUMN, LOG_COLUMNS, fill_block, fill_values
from drive_common.contract.stamps import sample_at, stamp_ns
from drive_common.contract.topics import (
    BLOCK_TOPIC,
    CURRENTS,
    DIAGNOSTICS,
    ESTIMATOR_BLEND,
    ESTIMATOR_STATE,
    INJECTION,
    LOAD_TORQUE,
    ROTOR_ESTIMATE,
    ROTOR_STATE,
    SAMPLE_LOGGED,
    SPEED_COMMAND,
    TOPICS,
    TORQUE_FEEDFORWARD,
    VOLTAGE_COMMAND,
    block,
)
from drive_common.contract.wire import WireError, decode_block, decoder_of
from drive_common.ros.node import message_class, topic_qos
from drive_tools.bags.common import offered_qos
from drive_tools.runner.compiled_answer import RING_K, RING_LOG, RING_THETA_M, CompiledAnswer, RingBlocks

ANSWER_RING = "answer_ring"
"""With a compiled answer, what the driver counts as received: the rows its ring handed over."""
ERROR = 2
"""diagnostic_msgs/DiagnosticStatus.ERROR: a fault (WARN, e.g. a bridge waiting for its inverter, is not)."""
MAX_FAULT_MESSAGES = 5
FOREIGN_CHECK_S = 0.5
"""How often a running drive looks for another drive's publishers in its namespace (discovery can show
one only after the start-up check)."""
FINAL_WAIT_S = 4.0
"""After the last sample, how long to wait at most for the last recorded messages and final /diagnostics:
a reliable writer resends a message lost on the way (e.g. a full shared-memory queue of a starved
reader) on its next heartbeat, every 3 s by default in Fast DDS; a complete run ends at once."""


@dataclass(frozen=True)
class DriverSettings:
    """How the scenario driver runs a drive: ``record`` fills a log; ``settle_s`` [s] after every lock-step
    endpoint is matched before it starts the plant, at most ``startup_timeout_s`` [s] for that;
    ``intra_process``: the controller takes the estimator's answers and the currents directly (no
    subscriptions of its own to match)."""

    record: bool = True
    settle_s: float = 0.1
    startup_timeout_s: float = 60.0
    intra_process: bool = False


class ScenarioDriver:
    """The launcher's own node, the operator of the scenario: waits until every lock-step endpoint is
    matched, then publishes the load torque of sample 0, which starts the plant. The plant and the
    controller take the scenario's schedule themselves, sample-exact (``scenario_schedule``), so the
    driver costs the lock-step nothing per sample; it learns the run's progress and end from the nodes'
    /diagnostics; ``settings`` (DriverSettings) say how. With ``record`` it fills a log
    (drive_common.contract.log.LOG_COLUMNS) from the per-sample topics; columns no topic carries stay NaN.
    With a ``recorder`` (drive_tools.bags.writer.BagWriter) it writes every contract topic as received,
    serialized, and the schedule's speed, load and feed-forward of each sample as the plant reaches it. With
    a virtual ``inverter`` (the bridge in the plant's place) it starts the inverter at sample 0, and once the
    inverter ran out (its last period sent, or it stopped) the run ends FINAL_WAIT_S later wherever the host
    stands: the samples it never reached count as missing."""

    def __init__(self, node, scenario, settings, progress=None, recorder=None, inverter=None, listener=None,
                 host_bridge=None):
        self.node, self.scenario = node, scenario
        record = settings.record
        self.intra_process = settings.intra_process
        """The controller takes the estimator's answers and the currents directly (no subscriptions)."""
        self.host_bridge = host_bridge
        """Behind a virtual inverter in this process, the bridge node's InverterBridge (its write times), or the
        compiled answer (drive_tools.runner.compiled_answer.CompiledAnswer) that answers on it."""
        self.answer = host_bridge if isinstance(host_bridge, CompiledAnswer) else None
        """The compiled answer: the driver starts it with the inverter, and its log is what the answer's ring
        hands over (``take_answered``), not what it hears on topics."""
        self.publish_answered = None
        """With a compiled answer: where each whole block it answered goes to be published, as
        (k0, encoder angles [rad], log rows) (the bridge node's ``publish_answered``), or None."""
        self.listener = listener or node
        """The node that takes what the graph says (its subscriptions): the launcher spins it on a thread of
        its own, so that what is recorded never waits in the drive's queue of callbacks."""
        self.n = scenario.n_samples
        self.n_p = scenario.motor.nameplate.n_p
        self.record = record
        self.settle_s, self.startup_timeout_s, self.progress = settings.settle_s, settings.startup_timeout_s, progress
        self.speed, self.load = scenario.schedule()
        self.feedforward = scenario.feedforward() if scenario.torque_feedforward is not None else None
        self.log = np.full((self.n if record else 1, len(LOG_COLUMNS)), np.nan)
        if record:
            self.log[:, COLUMN["t"]] = np.arange(self.n) * scenario.T_s
            self.log[:, COLUMN["omega_m_ref"]] = self.speed
            self.log[:, COLUMN["tau_load"]] = self.load
        self.load_pub = node.create_publisher(Float64, LOAD_TORQUE, topic_qos(LOAD_TORQUE))
        self.recorder = recorder
        self.writing = threading.Lock()
        """The recorder is written from the listener's thread and, at the start, from the driver's."""
        self.inverter = inverter
        self.blocks = scenario.block_samples > 1
        self.carried = BLOCK_TOPIC if self.blocks else {topic: topic for topic in SAMPLE_LOGGED}
        """Per-sample topic → the topic that carries it in this drive (itself, or its block twin)."""
        handlers = {DIAGNOSTICS: self.on_diagnostics}
        recorded = tuple(self.carried[topic] for topic in SAMPLE_LOGGED if topic != VOLTAGE_COMMAND)
        if record and self.answer is None:
            handlers.update({topic: self.logger_of(topic) for topic in recorded})
        if (record or recorder) and self.answer is None:
            handlers[self.carried[VOLTAGE_COMMAND]] = self.on_voltage
        self.recorded_commands = {SPEED_COMMAND: self.speed, LOAD_TORQUE: self.load,
                                  TORQUE_FEEDFORWARD: self.feedforward}
        self.last_recorded = {}
        self.received = dict.fromkeys((topic for topic in handlers if topic in self.carried.values()), 0)
        """Samples received per recorded topic (with a compiled answer: per the one ring, ANSWER_RING)."""
        if self.answer is not None:
            self.received = {ANSWER_RING: 0}
            self.ring_blocks = RingBlocks(scenario.block_samples, RING_LOG + len(LOG_COLUMNS))
            """The ring's rows put back into whole blocks to publish (a block drained in two parts is published)."""
        self.listening = {}
        """Topic → this driver's subscription (what it logs and records)."""
        self.subscribe(handlers)
        self.created = time.monotonic()
        self.ready_since = None
        self.checked_at = 0.0
        self.started_at = self.finished_at = None
        self.ready = False
        """Every endpoint matched and settled: the run may start."""
        self.start_allowed = True
        """False while the launcher has yet to take the machine's settings (SCHED_FIFO, the workqueue mask): a
        ready driver waits for it, so that nothing waits for the graph at real-time priority."""
        self.inverter_ran_out = False
        """The inverter's last period went before the host reached the run's last sample: the run ends
        FINAL_WAIT_S later, short of it."""
        self.last_sample = -1
        self.error = None
        self.exited = {}
        """Processes of the drive that exited during the run: name → exit code (a negative one: the signal
        that killed it). Each is a node fault of the run, which ends there."""
        self.diagnostics = {}
        self.nodes_complete = set()
        self.lockstep_nodes = (2 if inverter is not None else 3) if self.answer is None else 0
        """Nodes that report ``run_complete``: estimator, controller and the plant (not the bridge; none where a
        compiled answer runs the drive)."""
        self.done = None
        node.create_timer(0.05, self.tick)

    def subscribe(self, handlers):
        """Subscribe the handlers, serialized: a per-sample topic's handler gets its decoded values
        (drive_common.contract.wire), another topic's its message. With a recorder, every contract topic, written
        as it comes (the schedule's commands are written by ``record_commands``)."""
        topics = set(handlers)
        if self.recorder:
            topics |= self.bag_topics()
        for topic in sorted(topics):
            cls, qos = message_class(topic), topic_qos(topic)
            handler = handlers.get(topic)
            if handler and topic in self.carried.values():
                handler = self.decoding(topic, handler)
            elif handler:
                handler = self.deserializing(cls, handler)
            if self.recorder:
                handler = self.recording(topic, handler, TOPICS[topic].stamped)
            self.listening[topic] = self.listener.create_subscription(cls, topic, handler, qos, raw=True)
        if self.recorder:
            for topic in sorted(self.bag_topics() | set(self.recorded_commands)):
                name = self.node.resolve_topic_name(topic)
                self.recorder.add(name, TOPICS[topic].type, offered_qos(topic))

    def bag_topics(self):
        """The contract topics a recording holds, as received: every one but the schedule's commands
        (``record_commands``) and the per-sample topics this drive does not carry (with blocks, the
        per-sample ones but `estimator_state`, decimated to each block's first sample; otherwise the
        block twins)."""
        if self.blocks:
            left_out = set(SAMPLE_LOGGED) - {ESTIMATOR_STATE}
        else:
            left_out = set(BLOCK_TOPIC.values())
        return set(TOPICS) - set(self.recorded_commands) - left_out

    def recording(self, topic, handler, stamped):
        """``handler`` (if any) after the serialized message is written into the bag."""
        name = self.node.resolve_topic_name(topic)

        def callback(data):
            with self.writing:
                self.recorder.write(name, data, stamped)
            if handler:
                handler(data)
        return callback

    def decoding(self, topic, handler):
        """``handler(topic's sample index, values)`` of a serialized per-sample or block message (a
        block's index is its first sample's, its values its channels); messages of no sample of this
        run, or not of the topic's type, are left out."""
        block = bool(TOPICS[topic].block_of)
        decode = decode_block if block else decoder_of(TOPICS[topic].type)
        T_s = self.scenario.T_s

        def callback(data):
            try:
                sec, nanosec, *values = decode(data)
            except WireError:
                return
            k = sample_at(sec, nanosec, T_s)
            if k is not None and 0 <= k < self.n:
                self.received[topic] += len(values[0]) if block else 1
                handler(k, values)
        return callback

    @staticmethod
    def deserializing(cls, handler):
        return lambda data: handler(deserialize_message(data, cls))

    def expected_endpoints(self):
        """(topic, publishers, subscribers) that must exist before sample 0, this node included (with
        an inverter, which keeps its own load and clock, no plant subscribes to load_torque; intra-process,
        the controller subscribes to none of the estimator's answers nor to the currents; with an inverter
        too, the estimator neither to the currents nor to the commands, the bridge not to the commands)."""
        if self.answer is not None:
            return []
        r = 1 if self.record or self.recorder else 0
        c = 0 if self.intra_process else 1
        sensored = self.scenario.estimator == "sensored"
        b = 0 if self.intra_process and self.inverter is not None else 1
        endpoints = [(CURRENTS, 1, b + c + r), (ROTOR_ESTIMATE, 1, 1 + c + r), (INJECTION, 1, c + r),
                     (VOLTAGE_COMMAND, 1, 2 * b + r), (ESTIMATOR_STATE, 1, c + r), (ESTIMATOR_BLEND, 1, r)]
        if self.inverter is None:
            endpoints += [(ROTOR_STATE, 1, r + sensored)]
        endpoints = [(self.carried[topic], pubs, subs) for topic, pubs, subs in endpoints]
        return endpoints + ([(LOAD_TORQUE, 1, 1)] if self.inverter is None else [])

    def missing_endpoints(self):
        """The expected endpoints the graph does not show yet, and the topics this driver takes whose
        publishers its own subscription has not matched yet (a graph entry is not a match: the first
        samples would be lost to the log and the bag)."""
        missing = []
        for topic, pubs, subs in self.expected_endpoints():
            name = self.node.resolve_topic_name(topic)
            have_pubs, have_subs = self.node.count_publishers(name), self.node.count_subscribers(name)
            if have_pubs < pubs or have_subs < subs:
                missing.append(f"{name} ({have_pubs}/{pubs} publishers, {have_subs}/{subs} subscribers)")
            elif topic in self.listening and self.listening[topic].get_publisher_count() < pubs:
                missing.append(f"{name} (its publisher not yet matched by the launcher's subscription)")
        return missing

    def foreign_publishers(self):
        """Lock-step topics with more publishers than this drive has: another drive in the namespace."""
        surplus = []
        for topic, pubs, _ in self.expected_endpoints():
            name = self.node.resolve_topic_name(topic)
            count = self.node.count_publishers(name)
            if count > pubs:
                surplus.append(f"{count} publishers of {name}, {pubs} expected")
        return surplus

    def record_commands(self, k):
        """Write the schedule's commands of sample k into the bag: the load every sample, the speed and
        the feed-forward where they change (as `drive run --record` writes them)."""
        for topic, values in self.recorded_commands.items():
            if values is None or (topic != LOAD_TORQUE and self.last_recorded.get(topic) == values[k]):
                continue
            self.last_recorded[topic] = values[k]
            with self.writing:
                self.recorder.write(self.node.resolve_topic_name(topic),
                                    serialize_message(Float64(data=float(values[k]))), False,
                                    stamp_ns(k, self.scenario.T_s))

    def tick(self):
        now = time.monotonic()
        if self.started_at is None or (self.finished_at is None and now - self.checked_at >= FOREIGN_CHECK_S):
            self.checked_at = now
            foreign = self.foreign_publishers()
            if foreign:
                during = "" if self.started_at is None else "; they appeared during the run, which is stopped"
                self.finish(f"namespace {self.node.get_namespace()} is in use ({'; '.join(foreign[:2])}{during}): "
                            f"another drive runs there; run this one in another namespace")
                return
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
                self.ready = True
                if not self.start_allowed:
                    return
                self.started_at = now
                self.load_pub.publish(Float64(data=float(self.load[0])))
                if self.recorder:
                    self.record_commands(0)
                if self.answer is not None:
                    self.answer.start(self.take_answered)
                if self.inverter is not None:
                    self.inverter.start()
            return
        if self.progress:
            self.progress((self.last_sample + 1) / self.n)
        if self.finished_at is None and self.inverter is not None and self.inverter.ran_out():
            self.finished_at = now
            self.inverter_ran_out = True
            if self.answer is not None:
                self.answer.drain_then_stop()
        if self.finished_at is None and self.answer is not None and self.answer.finished():
            self.finished_at = now
        if self.finished_at is not None and (self.complete() or now - self.finished_at > FINAL_WAIT_S):
            self.finish()

    def take_answered(self, rows):
        """Rows a compiled answer's ring handed over (compiled_answer: RING_K, RING_HOST_S, RING_THETA_M, then
        the log row), on its reader's thread: the drive's columns into the log, the encoder's angle as the
        bridge node publishes it (theta_m, omega_m: its difference over a period), each whole block to
        ``publish_answered``."""
        k = rows[:, RING_K].astype(np.int64)
        inside = k < self.n
        rows, k = rows[inside], k[inside]
        if not len(k):
            return
        theta = rows[:, RING_THETA_M]
        if self.record:
            drive = slice(COLUMN["i_a_meas"], len(LOG_COLUMNS))
            self.log[k, drive] = rows[:, RING_LOG + drive.start:]
            self.log[k, COLUMN["theta_m"]] = theta
            before = np.where(k > 0, self.log[np.maximum(k - 1, 0), COLUMN["theta_m"]], theta)
            before = np.where(np.isnan(before), theta, before)
            self.log[k, COLUMN["omega_m"]] = (theta - before) / self.scenario.T_s
        self.received[ANSWER_RING] += len(k)
        self.last_sample = max(self.last_sample, int(k[-1]))
        if self.publish_answered is not None:
            for block in self.ring_blocks.blocks(rows):
                self.publish_answered(int(block[0, RING_K]), block[:, RING_THETA_M], block[:, RING_LOG:])
        if self.last_sample == self.n - 1 and self.finished_at is None:
            self.finished_at = time.monotonic()

    def complete(self):
        """Every recorded topic has its last sample and every lock-step node said its run is complete."""
        return (all(count >= self.n for count in self.received.values())
                and len(self.nodes_complete) >= self.lockstep_nodes)

    def missing_samples(self):
        """{topic: samples of the run's span (up to the last sample reached; all of them when the inverter ran
        out first) never received}, for every logged topic short of them."""
        reached = self.n if self.inverter_ran_out else self.last_sample + 1
        if self.answer is not None:
            overflow = self.answer.overflow
            missing = {"ring_overflow": overflow, "not_answered": reached - self.received[ANSWER_RING] - overflow}
            return {f"{self.node.get_namespace().rstrip('/')}/answer {kind}": count
                    for kind, count in missing.items() if count > 0}
        return {self.node.resolve_topic_name(topic): reached - count
                for topic, count in sorted(self.received.items()) if count < reached}

    def nodes_finished(self):
        """Every lock-step node said its run is complete: the run's end, when nothing per sample is
        taken here."""
        if self.finished_at is None:
            self.last_sample = self.n - 1
            self.finished_at = time.monotonic()
        if self.complete():
            self.finish()

    def finish(self, error=None):
        if self.done is not None and not self.done.done():
            self.error = error
            self.done.set_result(error is None)

    def logger_of(self, topic):
        """A handler writing what a per-sample or block message of ``topic`` says into its log rows."""
        if TOPICS[topic].block_of:
            def log_block(k0, channels):
                fill_block(self.log, k0, topic, channels, self.n_p)
            return log_block

        def log_sample(k, values):
            fill_values(self.log[k], topic, values, self.n_p)
        return log_sample

    def on_voltage(self, k0, values):
        """The voltage command of sample k0 (a block's: of samples k0 …) came: the run has reached it."""
        k = k0 + (len(values[0]) - 1 if self.blocks else 0)
        self.last_sample = max(self.last_sample, k)
        if self.recorder:
            for j in range(k0 + 1, min(k + 2, self.n)):
                self.record_commands(j)
        if self.record:
            if self.blocks:
                fill_block(self.log, k0, block(VOLTAGE_COMMAND), values, self.n_p)
            else:
                fill_values(self.log[k], VOLTAGE_COMMAND, values, self.n_p)
        if k == self.n - 1:
            self.finished_at = time.monotonic()
            if self.complete():
                self.finish()

    def on_diagnostics(self, msg):
        """Keep, per node of this namespace, its last status and what the run saw of it: the worst level,
        its cumulative fault counters and the distinct fault messages (the first MAX_FAULT_MESSAGES)."""
        prefix = self.node.get_namespace().rstrip("/") + "/"
        for status in msg.status:
            if not status.name.startswith(prefix):
                continue
            level = int.from_bytes(status.level, "little")
            values = {v.key: v.value for v in status.values}
            seen = self.diagnostics.setdefault(status.name, {"worst_level": 0, "faults": {}, "messages": []})
            seen.update(level=level, message=status.message, values=values)
            seen["worst_level"] = max(seen["worst_level"], level)
            for key, value in values.items():
                if key.startswith("faults."):
                    kind = key[len("faults."):]
                    seen["faults"][kind] = max(seen["faults"].get(kind, 0), int(value))
            if level >= ERROR and status.message not in seen["messages"] and len(seen["messages"]) < MAX_FAULT_MESSAGES:
                seen["messages"].append(status.message)
            if values.get("run_complete") == "True":
                self.nodes_complete.add(status.name)
                if len(self.nodes_complete) >= self.lockstep_nodes and not self.record:
                    self.nodes_finished()
            elif status.name.endswith("/pmsm_plant") and not self.record and "sample" in values:
                self.last_sample = max(self.last_sample, int(values["sample"]) - 1)

    def faults(self):
        """{node: {"faults": {kind: count}, "messages": [...]}} for every node that reported a fault
        during the run (counters are cumulative, so a fault between two statuses is not missed), and for
        every process of the drive that exited during it (``process_exited``)."""
        faults = {name: {"faults": d["faults"], "messages": d["messages"]}
                  for name, d in sorted(self.diagnostics.items()) if d["faults"] or d["worst_level"] >= ERROR}
        for name, code in self.exited.items():
            full = f"{self.node.get_namespace().rstrip('/')}/{name}"
            how = f"killed by signal {-code}" if code < 0 else f"exited with code {code}"
            entry = faults.setdefault(full, {"faults": {}, "messages": []})
            entry["faults"] = {**entry["faults"], "process_exited": 1}
            entry["messages"] = [*entry["messages"], f"its process {how} during the run"]
        return faults
