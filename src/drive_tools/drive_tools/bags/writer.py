"""Recordings as the contract says: a rosbag2 directory (metadata.yaml + one zstd-chunked .mcap), storage
`mcap`, serialization `cdr`, standard message types, offered QoS stored, written with the `mcap` library
from serialized bytes (message definitions and type hashes from the `rosbags` typestore). Log times are
sim time: a message's own stamp when it carries the sample instant, otherwise the instant of the latest
sample recorded.

The one-process runner writes the same topics from its log (``write_run_bag``), except `/diagnostics`
and `joint_states`, which only nodes produce.
"""
from pathlib import Path
from typing import NamedTuple

import numpy as np

from drive_common.contract.log import COLUMN, LOG_COLUMNS
from drive_common.contract.strict_json import dumps
from drive_common.contract.topics import (
    ANGLE_ERROR,
    CLOCK,
    CONTRACT_VERSION,
    CURRENTS,
    DIAGNOSTICS,
    DRIVE_CONFIG,
    ESTIMATOR_BLEND,
    ESTIMATOR_STATE,
    INJECTION,
    JOINT_STATES,
    LOAD_TORQUE,
    ROTOR_ESTIMATE,
    ROTOR_STATE,
    SPEED_COMMAND,
    TOPICS,
    TORQUE_FEEDFORWARD,
    VECTOR3,
    VOLTAGE_COMMAND,
    full_name,
)
from drive_common.math.frames import wrap
from drive_common.motor.commissioning import commissioning_record
from drive_common.motor.nameplate import contract_inverter, contract_motor
from drive_common.runtime.interrupt import deferred

from .common import BagError, BagWriteError, offered_qos, sample_stamp_ns, typestore

CHUNK_BYTES = 1 << 20
"""MCAP chunk size before zstd: what a killed recorder can lose (≈ 0.1 s of a 10 kHz drive)."""
WRITE_BLOCK_SAMPLES = 1000
"""write_run_bag writes this many samples at a time, a signal held until the block's end: a message is never
in the file and missing from the counts of metadata.yaml, a sample never recorded in part."""


class BagWriter:
    """A rosbag2 directory (metadata.yaml version 9 + ``NAME_0.mcap`` written by the `mcap` library)
    taking serialized messages; ``close`` makes the bag complete.

    A write that fails (a full disk, a lost device) stops the recording: later messages are counted as
    dropped, ``close`` closes the file as far as it was written and raises BagWriteError saying so."""

    def __init__(self, path, chunk_bytes=CHUNK_BYTES):
        from mcap.writer import CompressionType, Writer
        self.path = Path(path)
        if self.path.exists():
            raise BagError(f"{self.path}: already exists; choose a new bag name")
        if not self.path.parent.is_dir():
            raise BagError(f"{self.path}: its directory {self.path.parent} does not exist")
        try:
            self.path.mkdir()
            self.file_name = f"{self.path.name}_0.mcap"
            self.stream = (self.path / self.file_name).open("xb")
            self.writer = Writer(self.stream, chunk_size=chunk_bytes, compression=CompressionType.ZSTD)
            self.writer.start(profile="ros2", library="drive_tools.bags")
        except OSError as error:
            raise BagError(f"{self.path}: cannot be written ({error.strerror})") from None
        self.store = typestore()
        self.schemas, self.channels, self.topics, self.counts = {}, {}, {}, {}
        self.latest_ns = 0
        self.start_ns, self.end_ns = None, None
        self.error = None
        self.dropped = 0

    def add(self, topic, msgtype, qos, schema=None):
        """Register ``topic`` of ``msgtype`` with its offered QoS (a rosbags Qos, or rosbag2's profile list);
        ``schema``: (encoding, data) as recorded, for a type the typestore does not know."""
        import yaml
        from rosbags.rosbag2.metadata import dump_qos_v9
        known = msgtype in self.store.types
        if msgtype not in self.schemas:
            encoding, data = schema if schema and not known else ("ros2msg", None)
            if data is None:
                data = self.store.generate_msgdef(msgtype, ros_version=2)[0].encode()
            self.schemas[msgtype] = self.writer.register_schema(msgtype, encoding, data)
        profiles = qos if isinstance(qos, list) else dump_qos_v9([qos])
        type_hash = self.store.hash_rihs01(msgtype) if known else ""
        self.channels[topic] = self.writer.register_channel(
            topic, "cdr", self.schemas[msgtype],
            {"offered_qos_profiles": yaml.safe_dump(profiles), "topic_type_hash": type_hash})
        self.topics[topic] = {"name": topic, "type": msgtype, "serialization_format": "cdr",
                              "offered_qos_profiles": profiles, "type_description_hash": type_hash}
        self.counts[topic] = 0

    def write(self, topic, data, stamped, t_ns=None):
        """Write one serialized message at ``t_ns``, or at its own sample instant when ``stamped``
        (its first field is one), or else at the latest sample instant written."""
        if self.error:
            self.dropped += 1
            return
        if stamped:
            t_ns = sample_stamp_ns(data)
            self.latest_ns = max(self.latest_ns, t_ns)
        elif t_ns is None:
            t_ns = self.latest_ns
        try:
            self.writer.add_message(self.channels[topic], log_time=t_ns, data=data, publish_time=t_ns,
                                    sequence=self.counts[topic])
        except OSError as error:
            self.error = error
            self.dropped += 1
            return
        self.counts[topic] += 1
        self.start_ns = t_ns if self.start_ns is None else min(self.start_ns, t_ns)
        self.end_ns = t_ns if self.end_ns is None else max(self.end_ns, t_ns)

    def close(self):
        """Finish the .mcap and write metadata.yaml; BagWriteError when a write failed (the file then
        holds what reached the disk, and `reindex` rebuilds the bag from it)."""
        import yaml
        try:
            if not self.error:
                self.writer.finish()
        except OSError as error:
            self.error = error
        try:
            self.stream.close()
        except OSError as error:
            self.error = self.error or error
        start = self.start_ns or 0
        duration = (self.end_ns - start) if self.end_ns is not None else 0
        count = sum(self.counts.values())
        information = {
            "version": 9, "storage_identifier": "mcap", "relative_file_paths": [self.file_name],
            "duration": {"nanoseconds": duration}, "starting_time": {"nanoseconds_since_epoch": start},
            "message_count": count,
            "topics_with_message_count": [{"topic_metadata": meta, "message_count": self.counts[topic]}
                                          for topic, meta in self.topics.items()],
            "compression_format": "", "compression_mode": "",
            "files": [{"path": self.file_name, "starting_time": {"nanoseconds_since_epoch": start},
                       "duration": {"nanoseconds": duration}, "message_count": count}],
            "custom_data": None, "ros_distro": "jazzy"}
        if not self.error:
            try:
                (self.path / "metadata.yaml").write_text(
                    yaml.safe_dump({"rosbag2_bagfile_information": information}, sort_keys=False))
            except OSError as error:
                self.error = error
        if self.error:
            (self.path / "metadata.yaml").unlink(missing_ok=True)
            raise BagWriteError(f"{self.path}: recording stopped at {start / 1e9 + duration / 1e9:.4f} s "
                                f"({self.error.strerror or self.error}); {count} messages written, "
                                f"{self.dropped} dropped; the file is closed as far as it was written",
                                self.path)


CDR_LITTLE_ENDIAN = 0x0100
"""The 4-byte CDR encapsulation header 00 01 00 00 read as a little-endian uint32."""


def _cdr_vector3_stamped(sec, nanosec, frame, x, y, z):
    """n geometry_msgs/Vector3Stamped as CDR records (n × size bytes), vectorised."""
    length = len(frame) + 1
    pad = -(12 + length) % 8
    fields = [("enc", "<u4"), ("sec", "<i4"), ("nanosec", "<u4"), ("length", "<u4"), ("frame", f"S{length}")]
    fields += [("pad", "u1", (pad,))] if pad else []
    records = np.zeros(len(sec), dtype=fields + [("x", "<f8"), ("y", "<f8"), ("z", "<f8")])
    records["length"], records["frame"] = length, frame.encode()
    for name, values in (("sec", sec), ("nanosec", nanosec), ("x", x), ("y", y), ("z", z)):
        records[name] = values
    return records


def _cdr_joint_state(sec, nanosec, position, velocity, effort=None):
    """n sensor_msgs/JointState of the one joint `rotor` (frame ''), as CDR records."""
    fields = [("enc", "<u4"), ("sec", "<i4"), ("nanosec", "<u4"), ("frame_length", "<u4"), ("frame", "S1"),
              ("pad0", "u1", (3,)), ("names", "<u4"), ("name_length", "<u4"), ("name", "S6"),
              ("pad1", "u1", (2,)),
              ("positions", "<u4"), ("pad2", "u1", (4,)), ("position", "<f8"),
              ("velocities", "<u4"), ("pad3", "u1", (4,)), ("velocity", "<f8"), ("efforts", "<u4")]
    fields += [("pad4", "u1", (4,)), ("effort", "<f8")] if effort is not None else []
    records = np.zeros(len(sec), dtype=fields)
    records["frame_length"] = records["names"] = records["positions"] = records["velocities"] = 1
    records["name_length"], records["name"] = 6, b"rotor"
    records["position"], records["velocity"] = position, velocity
    if effort is not None:
        records["efforts"], records["effort"] = 1, effort
    records["sec"], records["nanosec"] = sec, nanosec
    return records


def _cdr_scalars(dtype, *columns):
    """n messages of fixed scalar fields (Float64: one f8; Clock: i4 sec, u4 nanosec) as CDR records."""
    records = np.zeros(len(columns[0]), dtype=[("enc", "<u4")] + [(f"f{i}", t) for i, t in enumerate(dtype)])
    for i, values in enumerate(columns):
        records[f"f{i}"] = values
    return records


class RecorderFlaws(NamedTuple):
    """What a robot's recorder does to a run's messages (docs/recordings.md, "A robot's recording"): its
    stamps from a wall clock at ``epoch_s`` [s], each off its sample instant by up to ± ``jitter_s`` [s] (the
    same for every topic of a sample), a share ``lost_share`` of each per-sample topic's messages never
    recorded (drawn per topic from ``seed``); ``scenario_named``: drive_config names the scenario file (a
    robot's drive runs none: its drive_config then gives the motor, inverter, estimator and its settings,
    injection and controller settings alone). The defaults record as the graph does."""

    epoch_s: float = 0.0
    jitter_s: float = 0.0
    lost_share: float = 0.0
    seed: int = 0
    scenario_named: bool = True


AS_THE_GRAPH_RECORDS = RecorderFlaws()


def write_run_bag(result, path, namespace="/drive", progress=None, chunk_bytes=CHUNK_BYTES,
                  flaws=AS_THE_GRAPH_RECORDS):
    """Write a one-process run (drive_common.contract.run_result.RunResult, its ``injection`` known) as the
    graph would have recorded it, its messages serialised to CDR in bulk with numpy; ``flaws``
    (RecorderFlaws) as a robot's recorder would have."""
    log, scenario = result.log, result.scenario
    n, n_p, c = log.shape[0], result.n_p, COLUMN
    writer = BagWriter(path, chunk_bytes)
    for topic, t in TOPICS.items():
        if topic in (DIAGNOSTICS, JOINT_STATES):
            continue
        writer.add(full_name(namespace, topic), t.type, offered_qos(topic))
    config = {"contract_version": CONTRACT_VERSION, "node": "drive run", "n_p": n_p, "scenario": scenario.name,
              "source": scenario.source, "motor": contract_motor(scenario.motor.nameplate),
              "inverter": contract_inverter(scenario.motor.inverter),
              "estimator": result.estimator, "T_s_s": scenario.T_s, "samples": n,
              "injection": result.injection,
              "scenario_injection": scenario.injection, "controller": scenario.controller,
              "current_limit_A": result.current_limit_A, "non_idealities": scenario.non_idealities,
              "block_samples": scenario.block_samples, "answer_periods": scenario.answer_periods,
              "command_delay_periods": scenario.drive_delay_periods()}
    if result.commissioning is not None:
        config["commissioning"] = commissioning_record(result.commissioning)
    if result.estimator_facts and result.estimator_facts.get("estimator_settings") is not None:
        config["estimator_settings"] = result.estimator_facts["estimator_settings"]
    if not flaws.scenario_named:
        for key in ("scenario", "source", "scenario_injection"):
            del config[key]
    rng = np.random.default_rng(flaws.seed)
    jitter_s = rng.uniform(-flaws.jitter_s, flaws.jitter_s, n) if flaws.jitter_s > 0.0 else 0.0
    t_ns = (int(round(flaws.epoch_s * 1e9)) + np.round((np.arange(n) * scenario.T_s + jitter_s) * 1e9)).astype(np.int64)
    sec, nanosec = np.divmod(t_ns, 1_000_000_000)
    col = {name: log[:, c[name]] for name in LOG_COLUMNS}

    def logged(topic):
        """A per-sample topic's records from its log columns (drive_common.contract.topics)."""
        t = TOPICS[topic]
        values = [col[name] / n_p if t.electrical else col[name] for name in t.log_columns]
        if t.type == VECTOR3:
            return _cdr_vector3_stamped(sec, nanosec, t.frame_id, *values, *[0.0] * (3 - len(values)))
        return _cdr_joint_state(sec, nanosec, *values)

    theta_m_hat, omega_m_hat = col["theta_e_hat"] / n_p, col["omega_e_hat"] / n_p
    speed_changes = np.ones(n, dtype=bool)
    speed_changes[1:] = col["omega_m_ref"][1:] != col["omega_m_ref"][:-1]
    per_sample = [
        (CLOCK, _cdr_scalars(("<i4", "<u4"), sec, nanosec), None),
        (SPEED_COMMAND, _cdr_scalars(("<f8",), col["omega_m_ref"]), speed_changes),
        (LOAD_TORQUE, _cdr_scalars(("<f8",), col["tau_load"]), None),
        (ROTOR_STATE, logged(ROTOR_STATE), None),
        (CURRENTS, logged(CURRENTS), None),
        (INJECTION, logged(INJECTION), None),
        (ROTOR_ESTIMATE, logged(ROTOR_ESTIMATE), None),
        (ESTIMATOR_STATE, logged(ESTIMATOR_STATE), None),
        (ESTIMATOR_BLEND, logged(ESTIMATOR_BLEND), None),
        (ANGLE_ERROR, _cdr_vector3_stamped(sec, nanosec, TOPICS[ANGLE_ERROR].frame_id,
                                             wrap.py_func(n_p * (col["theta_m"] - theta_m_hat)),
                                             col["omega_m"] - omega_m_hat, 0.0), None),
        (VOLTAGE_COMMAND, logged(VOLTAGE_COMMAND), None)]
    if scenario.torque_feedforward is not None:
        feedforward = scenario.feedforward()[:n]
        changes = np.ones(n, dtype=bool)
        changes[1:] = feedforward[1:] != feedforward[:-1]
        per_sample.insert(2, (TORQUE_FEEDFORWARD, _cdr_scalars(("<f8",), feedforward), changes))
    streams = []
    for topic, records in ((t, r) for t, r, _ in per_sample):
        records["enc"] = CDR_LITTLE_ENDIAN
        streams.append((full_name(namespace, topic), memoryview(records.tobytes()), records.dtype.itemsize))
    masks = [mask if flaws.lost_share <= 0.0 or topic == CLOCK or mask is not None
             else rng.random(n) >= flaws.lost_share for topic, _, mask in per_sample]
    config_data = writer.store.serialize_cdr(writer.store.types["std_msgs/msg/String"](
        data=dumps(config)), "std_msgs/msg/String")
    writer.write(full_name(namespace, DRIVE_CONFIG), config_data, False, 0)
    write = writer.write
    try:
        for k0 in range(0, n, WRITE_BLOCK_SAMPLES):
            if progress and k0 % (10 * WRITE_BLOCK_SAMPLES) == 0:
                progress(k0 / n)
            with deferred():
                for k in range(k0, min(k0 + WRITE_BLOCK_SAMPLES, n)):
                    t = int(t_ns[k])
                    for (topic, data, size), mask in zip(streams, masks):
                        if mask is None or mask[k]:
                            write(topic, data[k * size:(k + 1) * size], False, t)
    finally:
        with deferred():
            writer.close()
    return Path(path)
