"""Recordings as the contract says: a rosbag2 directory (metadata.yaml + one zstd-chunked .mcap), storage
`mcap`, serialization `cdr`, standard message types, offered QoS stored, written with the `mcap` library
from serialized bytes (message definitions and type hashes from the `rosbags` typestore). Log times are
sim time: a message's own stamp when it carries the sample instant, otherwise the instant of the latest
sample recorded.

The one-process runner writes the same topics from its log (``write_run_bag``), except `/diagnostics`
and `joint_states`, which only nodes produce.
"""
import dataclasses
import json
import math
from pathlib import Path

import numpy as np

from .loop import COLUMN, LOG_COLUMNS
from .scenario import ScenarioError

SAMPLE_STAMPED = {"currents", "rotor_state", "rotor_estimate", "injection", "voltage_command",
                  "estimator_state", "angle_error", "joint_states", "/clock"}
"""Topics whose first field is the sample instant (header.stamp or clock)."""
DRIVE_TOPICS = {
    "currents": "geometry_msgs/msg/Vector3Stamped", "rotor_state": "sensor_msgs/msg/JointState",
    "rotor_estimate": "sensor_msgs/msg/JointState", "injection": "geometry_msgs/msg/Vector3Stamped",
    "voltage_command": "geometry_msgs/msg/Vector3Stamped",
    "estimator_state": "geometry_msgs/msg/Vector3Stamped",
    "/clock": "rosgraph_msgs/msg/Clock", "angle_error": "geometry_msgs/msg/Vector3Stamped",
    "joint_states": "sensor_msgs/msg/JointState", "speed_command": "std_msgs/msg/Float64",
    "load_torque": "std_msgs/msg/Float64", "drive_config": "std_msgs/msg/String",
    "/diagnostics": "diagnostic_msgs/msg/DiagnosticArray"}
"""Every contract topic (relative to the drive's namespace unless absolute) and its type."""


class BagError(ScenarioError):
    """A bag is unusable; the message names the bag (and topic) in one line."""


def typestore():
    from rosbags.typesys import Stores, get_typestore
    return get_typestore(Stores.ROS2_JAZZY)


def full_topic(namespace, topic):
    return topic if topic.startswith("/") else f"{namespace.rstrip('/')}/{topic}"


def rosbags_qos(history=1, depth=10, reliability=1, durability=2):
    """A rosbags Qos from the rmw enum values (KEEP_LAST 1, RELIABLE 1, VOLATILE 2, TRANSIENT_LOCAL 1)."""
    from rosbags.interfaces import (Qos, QosDurability, QosHistory, QosLiveliness, QosReliability,
                                    QosTime)
    return Qos(QosHistory(history), depth, QosReliability(reliability), QosDurability(durability),
               QosTime(0, 0), QosTime(0, 0), QosLiveliness.AUTOMATIC, QosTime(0, 0), False)


def offered_qos(topic):
    """The contract's QoS of a topic (pmsm_plant.contract.topic_qos) as rosbags stores it."""
    from pmsm_plant.contract import topic_qos
    q = topic_qos(topic)
    return rosbags_qos(q.history.value, q.depth, q.reliability.value, q.durability.value)


VECTOR_COLUMNS = {"currents": ("i_a_meas", "i_b_meas", "i_c_meas"),
                  "injection": ("u_inj_alpha", "u_inj_beta"),
                  "voltage_command": ("u_alpha", "u_beta"),
                  "estimator_state": ("eps", "signal", "observable")}
"""Log columns (drive_bridge.loop.LOG_COLUMNS) of the x, y, z of each per-sample Vector3Stamped topic."""
SAMPLE_LOGGED = ("currents", "rotor_state", "rotor_estimate", "injection", "voltage_command",
                 "estimator_state")
"""The per-sample topics whose content goes into the log."""


def fill_sample(row, topic, msg, n_p):
    """Write what a per-sample message of ``topic`` says into a log row: rclpy and rosbags messages alike,
    so a recording from the graph and one read back from a bag fill the same columns."""
    if topic in VECTOR_COLUMNS:
        v = msg.vector
        for column, value in zip(VECTOR_COLUMNS[topic], (v.x, v.y, v.z)):
            row[COLUMN[column]] = value
    elif not len(msg.position):
        return
    elif topic == "rotor_state":
        row[COLUMN["theta_m"]], row[COLUMN["omega_m"]] = msg.position[0], msg.velocity[0]
        row[COLUMN["tau_e"]] = msg.effort[0] if len(msg.effort) else math.nan
    elif topic == "rotor_estimate":
        row[COLUMN["theta_e_hat"]], row[COLUMN["omega_e_hat"]] = n_p * msg.position[0], n_p * msg.velocity[0]


def sample_stamp_ns(data):
    """The header stamp (or clock) of a serialized message whose first field is a builtin Time."""
    order = "little" if data[1] == 1 else "big"
    return int.from_bytes(data[4:8], order, signed=True) * 1_000_000_000 + int.from_bytes(data[8:12], order)


CHUNK_BYTES = 1 << 20
"""MCAP chunk size before zstd: what a killed recorder can lose (≈ 0.1 s of a 10 kHz drive)."""


class BagWriter:
    """A rosbag2 directory (metadata.yaml version 9 + one .mcap written by the `mcap` library) taking
    serialized messages; ``close`` makes the bag complete."""

    def __init__(self, path):
        from mcap.writer import CompressionType, Writer
        self.path = Path(path)
        if self.path.exists():
            raise BagError(f"{self.path}: already exists; choose a new bag name")
        self.path.mkdir(parents=True)
        self.file_name = f"{self.path.name}.mcap"
        self.stream = (self.path / self.file_name).open("xb")
        self.writer = Writer(self.stream, chunk_size=CHUNK_BYTES, compression=CompressionType.ZSTD)
        self.writer.start(profile="ros2", library="drive_bridge")
        self.store = typestore()
        self.schemas, self.channels, self.topics, self.counts = {}, {}, {}, {}
        self.latest_ns = 0
        self.start_ns, self.end_ns = None, None

    def add(self, topic, msgtype, qos):
        import yaml
        from rosbags.rosbag2.metadata import dump_qos_v9
        if msgtype not in self.schemas:
            msgdef, _ = self.store.generate_msgdef(msgtype, ros_version=2)
            self.schemas[msgtype] = self.writer.register_schema(msgtype, "ros2msg", msgdef.encode())
        profiles = dump_qos_v9([qos])
        self.channels[topic] = self.writer.register_channel(
            topic, "cdr", self.schemas[msgtype], {"offered_qos_profiles": yaml.safe_dump(profiles)})
        self.topics[topic] = {"name": topic, "type": msgtype, "serialization_format": "cdr",
                              "offered_qos_profiles": profiles,
                              "type_description_hash": self.store.hash_rihs01(msgtype)}
        self.counts[topic] = 0

    def write(self, topic, data, stamped, t_ns=None):
        """Write one serialized message at ``t_ns``, or at its own sample instant when ``stamped``
        (its first field is one), or else at the latest sample instant written."""
        if stamped:
            t_ns = sample_stamp_ns(data)
            self.latest_ns = max(self.latest_ns, t_ns)
        elif t_ns is None:
            t_ns = self.latest_ns
        self.writer.add_message(self.channels[topic], log_time=t_ns, data=data, publish_time=t_ns,
                                sequence=self.counts[topic])
        self.counts[topic] += 1
        self.start_ns = t_ns if self.start_ns is None else min(self.start_ns, t_ns)
        self.end_ns = t_ns if self.end_ns is None else max(self.end_ns, t_ns)

    def close(self):
        import yaml
        self.writer.finish()
        self.stream.close()
        start = self.start_ns or 0
        duration = (self.end_ns - start + 1) if self.end_ns is not None else 0
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
        (self.path / "metadata.yaml").write_text(
            yaml.safe_dump({"rosbag2_bagfile_information": information}, sort_keys=False))


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


def write_run_bag(result, path, namespace="/drive", progress=None):
    """Write a one-process run (drive_bridge.runner.RunResult) as the graph would have recorded it,
    its messages serialised to CDR in bulk with numpy."""
    from .metrics import wrap
    log, scenario = result.log, result.scenario
    n, n_p, c = log.shape[0], result.preset.machine.n_p, COLUMN
    writer = BagWriter(path)
    for topic, msgtype in DRIVE_TOPICS.items():
        if topic in ("/diagnostics", "joint_states"):
            continue
        writer.add(full_topic(namespace, topic), msgtype, offered_qos(topic))
    config = {"node": "drive run", "n_p": n_p, "scenario": scenario.name, "source": scenario.source,
              "motor": scenario.motor, "estimator": result.estimator, "T_s_s": scenario.T_s, "samples": n,
              "injection": scenario.injection, "controller": scenario.controller,
              "current_limit_A": result.current_limit_A, "non_idealities": scenario.non_idealities}
    t_ns = np.round(np.arange(n) * scenario.T_s * 1e9).astype(np.int64)
    sec, nanosec = np.divmod(t_ns, 1_000_000_000)
    col = {name: log[:, c[name]] for name in LOG_COLUMNS}
    theta_hat_m, omega_hat_m = col["theta_e_hat"] / n_p, col["omega_e_hat"] / n_p
    speed_changes = np.ones(n, dtype=bool)
    speed_changes[1:] = col["omega_m_ref"][1:] != col["omega_m_ref"][:-1]
    vector = _cdr_vector3_stamped
    per_sample = [
        ("/clock", _cdr_scalars(("<i4", "<u4"), sec, nanosec), None),
        ("speed_command", _cdr_scalars(("<f8",), col["omega_m_ref"]), speed_changes),
        ("load_torque", _cdr_scalars(("<f8",), col["tau_load"]), None),
        ("rotor_state", _cdr_joint_state(sec, nanosec, col["theta_m"], col["omega_m"], col["tau_e"]), None),
        ("currents", vector(sec, nanosec, "abc", col["i_a_meas"], col["i_b_meas"], col["i_c_meas"]), None),
        ("injection", vector(sec, nanosec, "alpha_beta", col["u_inj_alpha"], col["u_inj_beta"], 0.0), None),
        ("rotor_estimate", _cdr_joint_state(sec, nanosec, theta_hat_m, omega_hat_m), None),
        ("estimator_state", vector(sec, nanosec, "", col["eps"], col["signal"], col["observable"]), None),
        ("angle_error", vector(sec, nanosec, "", wrap(n_p * (col["theta_m"] - theta_hat_m)),
                               col["omega_m"] - omega_hat_m, 0.0), None),
        ("voltage_command", vector(sec, nanosec, "alpha_beta", col["u_alpha"], col["u_beta"], 0.0), None)]
    streams = []
    for topic, records in ((t, r) for t, r, _ in per_sample):
        records["enc"] = CDR_LITTLE_ENDIAN
        streams.append((full_topic(namespace, topic), memoryview(records.tobytes()), records.dtype.itemsize))
    masks = [mask for _, _, mask in per_sample]
    config_data = writer.store.serialize_cdr(writer.store.types["std_msgs/msg/String"](
        data=json.dumps(config, default=str)), "std_msgs/msg/String")
    writer.write(full_topic(namespace, "drive_config"), config_data, False, 0)
    write = writer.write
    for k in range(n):
        t = int(t_ns[k])
        for (topic, data, size), mask in zip(streams, masks):
            if mask is None or mask[k]:
                write(topic, data[k * size:(k + 1) * size], False, t)
        if progress and k % 10000 == 0:
            progress(k / n)
    writer.close()
    return Path(path)


def open_bag(path):
    """A rosbags Reader for a rosbag2 directory; a cut or foreign bag gives a BagError naming it."""
    from rosbags.rosbag2 import Reader
    from rosbags.rosbag2.errors import ReaderError
    path = Path(path)
    if not path.exists():
        raise BagError(f"{path}: no such bag")
    if path.is_dir() and not (path / "metadata.yaml").exists():
        mcaps = sorted(path.glob("*.mcap"))
        if mcaps:
            raise BagError(f"{path}: no metadata.yaml, the recording was cut before it closed (killed?); "
                           f"`drive bag reindex {path}` rebuilds it from {mcaps[0].name}")
    try:
        reader = Reader(path)
        reader.open()
    except ReaderError as error:
        hint = (f"; if its .mcap was cut, `drive bag reindex {path} --force` rebuilds it"
                if path.is_dir() else "")
        raise BagError(f"{path}: not a readable rosbag2 bag ({error}){hint}") from None
    return reader


def bag_info(path):
    """What `ros2 bag info` shows: storage, duration, message counts, topics with type, count and QoS."""
    reader = open_bag(path)
    try:
        topics = [{"topic": c.topic, "type": c.msgtype, "count": c.msgcount,
                   "serialization": c.ext.serialization_format,
                   "offered_qos": [_qos_dict(q) for q in c.ext.offered_qos_profiles]}
                  for c in sorted(reader.connections, key=lambda c: c.topic)]
        path = Path(path)
        stored = sorted(path.glob("*.mcap")) + sorted(path.glob("*.db3")) if path.is_dir() else [path]
        files = [{"path": p.name, "bytes": p.stat().st_size} for p in stored]
        return {"bag": str(path), "storage": _storage_identifier(path),
                "compression": f"{reader.compression_mode} {reader.compression_format}"
                if reader.compression_mode else _chunk_compression(path),
                "files": files, "start_s": reader.start_time / 1e9, "end_s": reader.end_time / 1e9,
                "duration_s": reader.duration / 1e9, "messages": reader.message_count, "topics": topics}
    finally:
        reader.close()


def _chunk_compression(path):
    """How the MCAP chunks are compressed, from the first file's summary."""
    from mcap.reader import make_reader
    for file in (sorted(path.glob("*.mcap")) if path.is_dir() else [path] if path.suffix == ".mcap" else []):
        with file.open("rb") as stream:
            summary = make_reader(stream).get_summary()
        kinds = sorted({c.compression or "none" for c in summary.chunk_indexes}) if summary else []
        return f"MCAP chunks: {', '.join(kinds) or 'none'}"
    return "none"


def _storage_identifier(path):
    if not path.is_dir():
        return path.suffix.lstrip(".")
    import yaml
    metadata = yaml.safe_load((path / "metadata.yaml").read_text())
    return metadata["rosbag2_bagfile_information"]["storage_identifier"]


def _qos_dict(qos):
    return {"history": qos.history.name, "depth": qos.depth, "reliability": qos.reliability.name,
            "durability": qos.durability.name}


def read_topics(path, wanted, namespace=None):
    """{topic (relative): [(log_time_ns, message), ...]} of the wanted contract topics, deserialised.

    ``namespace``: the drive's; by default the one namespace the bag's `currents` topic is in. A topic in
    the wrong type is a BagError naming bag and topic."""
    reader = open_bag(path)
    store = typestore()
    try:
        connections = {c.topic: c for c in reader.connections}
        if namespace is None:
            namespaces = sorted(t.rsplit("/", 1)[0] or "/" for t in connections if t.endswith("/currents"))
            if len(namespaces) > 1:
                raise BagError(f"{path}: drives in {', '.join(namespaces)}; name one with --namespace")
            namespace = namespaces[0] if namespaces else "/drive"
        chosen = {}
        for topic in wanted:
            name = full_topic(namespace, topic)
            if name not in connections:
                continue
            c = connections[name]
            if c.msgtype != DRIVE_TOPICS[topic]:
                raise BagError(f"{path}: {name} is {c.msgtype}, the contract says {DRIVE_TOPICS[topic]}")
            chosen[c.id] = topic
        out = {topic: [] for topic in chosen.values()}
        try:
            for connection, t, data in reader.messages([c for c in reader.connections if c.id in chosen]):
                out[chosen[connection.id]].append((t, store.deserialize_cdr(data, connection.msgtype)))
        except Exception as error:
            raise BagError(f"{path}: unreadable message data ({type(error).__name__}: {error})") from None
        return namespace, out
    finally:
        reader.close()


def bag_log(path, T_s=None, namespace=None):
    """The runner's log layout (LOG_COLUMNS) filled from a bag's per-sample topics (NaN where the bag
    says nothing), the sample period and the bag's drive_config entries."""
    wanted = SAMPLE_LOGGED + ("speed_command", "load_torque", "drive_config")
    namespace, topics = read_topics(path, wanted, namespace)
    if not topics.get("currents"):
        raise BagError(f"{path}: no {full_topic(namespace, 'currents')} messages; the contract needs them")
    stamps = np.array([_stamp_ns(m.header.stamp) for _, m in topics["currents"]], dtype=np.int64)
    if T_s is None:
        steps = np.diff(stamps)
        if steps.size == 0 or steps.min() <= 0:
            raise BagError(f"{path}: {full_topic(namespace, 'currents')} stamps are not increasing sample "
                           f"instants")
        T_s = float(np.median(steps)) * 1e-9
    n = int(round(stamps[-1] * 1e-9 / T_s)) + 1
    log = np.full((n, len(LOG_COLUMNS)), np.nan)
    log[:, COLUMN["t"]] = np.arange(n) * T_s
    configs = [json.loads(m.data) for _, m in topics.get("drive_config", [])]
    n_p = _pole_pairs(configs)

    def index(stamp):
        k = int(round(_stamp_ns(stamp) * 1e-9 / T_s))
        return k if 0 <= k < n else None

    for topic in SAMPLE_LOGGED:
        for _, m in topics.get(topic, []):
            k = index(m.header.stamp)
            if k is not None:
                fill_sample(log[k], topic, m, n_p)
    for topic, column in (("speed_command", "omega_m_ref"), ("load_torque", "tau_load")):
        _hold(log[:, COLUMN[column]], topics.get(topic, []), T_s, n)
    return log, T_s, configs


def _hold(column, messages, T_s, n):
    """Fill a column with unstamped commands, each held from its log time on."""
    for t, m in messages:
        k = int(round(t * 1e-9 / T_s))
        if 0 <= k < n:
            column[k:] = m.data


def _pole_pairs(configs):
    """p from the bag's drive_config (every node's carries ``n_p``); 1 when the bag has none."""
    for config in configs:
        if "n_p" in config:
            return int(config["n_p"])
    return 1


def _stamp_ns(stamp):
    return stamp.sec * 1_000_000_000 + stamp.nanosec


def reindex(path, force=False):
    """Rebuild a cut recording (no metadata.yaml: the recorder was killed) into a complete bag from the
    chunks that reached the disk; the chunk being written when it died is lost. ``force``: also when a
    metadata.yaml exists (an .mcap cut after the bag was closed). Returns bag_info."""
    import shutil
    import struct

    import yaml
    from mcap.exceptions import McapError
    from mcap.records import Channel, Message, Schema
    from mcap.stream_reader import StreamReader

    path = Path(path)
    if (path / "metadata.yaml").exists():
        if not force:
            raise BagError(f"{path}: already complete (has metadata.yaml); --force rebuilds it anyway")
        (path / "metadata.yaml").unlink()
    mcaps = sorted(path.glob("*.mcap"))
    if not mcaps:
        raise BagError(f"{path}: no .mcap file to reindex")
    rebuilt = path.with_name(path.name + ".reindexed")
    if rebuilt.exists():
        shutil.rmtree(rebuilt)
    writer = BagWriter(rebuilt)
    schemas, topics, kept = {}, {}, 0
    try:
        with mcaps[0].open("rb") as stream:
            try:
                for record in StreamReader(stream).records:
                    if isinstance(record, Schema):
                        schemas[record.id] = record.name
                    elif isinstance(record, Channel):
                        text = record.metadata.get("offered_qos_profiles", "") or "[]"
                        profiles = yaml.safe_load(text) or [{}]
                        writer.add(record.topic, schemas[record.schema_id],
                                   rosbags_qos(**_qos_values(profiles[0])))
                        topics[record.id] = record.topic
                    elif isinstance(record, Message) and record.channel_id in topics:
                        writer.write(topics[record.channel_id], record.data, False, record.log_time)
                        kept += 1
            except (McapError, EOFError, ValueError, KeyError, struct.error):
                pass
    finally:
        writer.close()
    cut = path.with_name(path.name + ".cut")
    path.rename(cut)
    rebuilt.rename(path)
    (path / f"{rebuilt.name}.mcap").rename(path / mcaps[0].name)
    _rename_in_metadata(path, f"{rebuilt.name}.mcap", mcaps[0].name)
    shutil.rmtree(cut)
    return bag_info(path)


def _qos_values(q):
    names = {"keep_last": 1, "keep_all": 2, "reliable": 1, "best_effort": 2, "transient_local": 1,
             "volatile": 2}
    return {"history": names.get(q.get("history"), 1), "depth": int(q.get("depth", 10)),
            "reliability": names.get(q.get("reliability"), 1),
            "durability": names.get(q.get("durability"), 2)}


def _rename_in_metadata(path, old, new):
    metadata = path / "metadata.yaml"
    metadata.write_text(metadata.read_text().replace(old, new))


def bag_result(path, namespace=None):
    """A recorded run as drive_bridge.runner.RunResult, its scenario rebuilt from the bag's drive_config
    (the scenario file and overrides the nodes or the runner used), so it is scored as `drive run` is."""
    from pmsm_plant.presets import get_preset

    from .runner import RunResult
    log, T_s, configs = bag_log(path, namespace=namespace)
    scenario = _bag_scenario(path, configs)
    scenario = dataclasses.replace(scenario, duration_s=log.shape[0] * T_s, T_s=T_s)
    recorded = next((c["estimator"] for c in configs if "estimator" in c), scenario.estimator)
    from_nodes = (c["parameters"]["estimator"] or scenario.estimator for c in configs if "parameters" in c)
    estimator = next(from_nodes, recorded)
    limit = next((c["current_limit_A"] for c in configs if "current_limit_A" in c),
                 next((c["controller"]["i_max_A"] for c in configs if isinstance(c.get("controller"), dict)
                       and "i_max_A" in c["controller"]), math.nan))
    return RunResult(scenario, get_preset(scenario.motor), estimator, log, 0.0, limit)


def _bag_scenario(path, configs):
    from .graph import scenario_from_parameters
    from .scenario import load_scenario
    for config in configs:
        try:
            if "parameters" in config:
                return scenario_from_parameters(config["parameters"])
            if "source" in config:
                s = load_scenario(config["source"], estimator_override=config.get("estimator"))
                return dataclasses.replace(s, injection=config.get("injection", s.injection),
                                           controller=config.get("controller", s.controller))
        except ScenarioError as error:
            raise BagError(f"{path}: drive_config names a scenario that cannot be loaded ({error})") from None
    raise BagError(f"{path}: no drive_config, so no scenario to score the run against (its windows and "
                   f"motor); record with `drive run|launch --record`")


def has_ground_truth(log):
    return bool(np.isfinite(log[:, COLUMN["theta_m"]]).any())
