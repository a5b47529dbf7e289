"""Reading recordings: what `ros2 bag info` shows, the contract topics deserialised, a run's log filled
from its per-sample topics, and a recorded run rebuilt with its scenario so it is scored as `drive run`
is."""
import dataclasses
import json
import warnings
from pathlib import Path

import numpy as np

from drive_common.config.parameters import all_parameters, scenario_from_parameters
from drive_common.config.scenario import ScenarioError, load_scenario
from drive_common.contract.log import COLUMN, LOG_COLUMNS, fill_block, fill_sample
from drive_common.contract.settings import FormatMigrated
from drive_common.contract.topics import (
    BLOCK_LOGGED,
    CONTRACT_VERSION,
    CURRENTS,
    DRIVE_CONFIG,
    HELD_LOGGED,
    LEGACY_TYPES,
    SAMPLE_LOGGED,
    TOPICS,
    ZERO_VOLTAGE,
    block,
    full_name,
)

from .common import BagCutError, BagError, typestore


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
            raise BagCutError(f"{path}: no metadata.yaml, the recording was cut before it closed (killed?); "
                              f"its {mcaps[0].name} can be rebuilt into a complete bag", path)
        raise BagError(f"{path}: not a rosbag2 bag (a directory without metadata.yaml or a .mcap file)")
    try:
        reader = Reader(path)
        reader.open()
    except Exception as error:
        reason = str(error) if isinstance(error, ReaderError) else f"{type(error).__name__}: {error}"
        if path.is_dir():
            raise BagCutError(f"{path}: not a readable rosbag2 bag ({reason}); if its .mcap was cut or "
                              f"damaged, it can be rebuilt into a complete bag", path) from None
        raise BagError(f"{path}: not a readable rosbag2 bag ({reason})") from None
    return reader


def bag_info(path):
    """What `ros2 bag info` shows: storage, duration, message counts, topics with type, count and QoS,
    and ``warnings`` where metadata.yaml and the files disagree."""
    reader = open_bag(path)
    path = Path(path)
    try:
        topics = [{"topic": c.topic, "type": c.msgtype, "count": c.msgcount,
                   "serialization": c.ext.serialization_format,
                   "offered_qos": [_qos_dict(q) for q in c.ext.offered_qos_profiles]}
                  for c in sorted(reader.connections, key=lambda c: c.topic)]
        stored = sorted(path.glob("*.mcap")) + sorted(path.glob("*.db3")) if path.is_dir() else [path]
        info = {"bag": str(path), "storage": _storage_identifier(path),
                "compression": f"{reader.compression_mode} {reader.compression_format}"
                if reader.compression_mode else _chunk_compression(stored),
                "files": [{"path": p.name, "bytes": p.stat().st_size} for p in stored],
                "start_s": reader.start_time / 1e9, "end_s": reader.end_time / 1e9,
                "duration_s": reader.duration / 1e9, "messages": reader.message_count, "topics": topics}
    except Exception as error:
        raise BagCutError(f"{path}: not a readable rosbag2 bag ({type(error).__name__}: {error}); it can be "
                          f"rebuilt into a complete bag", path) from None
    finally:
        reader.close()
    info["warnings"] = _disagreements(path, stored, info["messages"])
    if info["duration_s"] < 0.0 or info["end_s"] < info["start_s"]:
        info["warnings"].append(f"metadata says the recording ends before it starts (start {info['start_s']:.6f} s, "
                                f"end {info['end_s']:.6f} s); duration not known")
        info["duration_s"] = None
    return info



def bag_info_lines(info):
    """bag_info as text lines, like `ros2 bag info`."""
    lines = [f"bag {info['bag']}: storage {info['storage']}, compression {info['compression']}"]
    lines += [f"  file {f['path']} ({f['bytes']:,} bytes)" for f in info["files"]]
    duration = "not known" if info["duration_s"] is None else f"{info['duration_s']:.6f} s"
    lines.append(f"  duration {duration} (start {info['start_s']:.6f} s, "
                 f"end {info['end_s']:.6f} s), {info['messages']:,} messages")
    width = max((len(t["topic"]) for t in info["topics"]), default=0)
    for t in info["topics"]:
        qos = t["offered_qos"][0] if t["offered_qos"] else {}
        qos_text = "/".join(str(qos.get(key, "?")).lower() for key in ("reliability", "durability", "depth"))
        lines.append(f"  {t['topic']:{width}s}  {t['type']:38s} {t['count']:8d}  {t['serialization']}  {qos_text}")
    lines += [f"  warning: {warning}" for warning in info["warnings"]]
    return lines

def _summary(file):
    """The .mcap file's summary, or None when it has none that reads."""
    from mcap.reader import make_reader
    try:
        with file.open("rb") as stream:
            return make_reader(stream).get_summary()
    except Exception:
        return None


def _chunk_compression(files):
    """How the MCAP chunks are compressed, from the first file's summary."""
    for file in (f for f in files if f.suffix == ".mcap"):
        summary = _summary(file)
        kinds = sorted({c.compression or "none" for c in summary.chunk_indexes}) if summary else []
        return f"MCAP chunks: {', '.join(kinds) or 'unknown (no summary)'}"
    return "none"


def _disagreements(path, files, metadata_messages):
    """Where metadata.yaml and the .mcap files it describes disagree, one sentence each."""
    if not path.is_dir():
        return []
    import yaml
    listed = yaml.safe_load((path / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    listed = set(listed.get("relative_file_paths") or [])
    warnings = [f"{name} is listed in metadata.yaml but missing" for name in sorted(listed)
                if not (path / name).is_file()]
    warnings += [f"{f.name} is not listed in metadata.yaml (not read)" for f in files if f.name not in listed]
    counted = 0
    for file in (f for f in files if f.name in listed and f.suffix == ".mcap"):
        summary = _summary(file)
        if summary is None or summary.statistics is None:
            warnings.append(f"{file.name} has no readable summary: cut or damaged after the bag was closed")
            return warnings
        counted += summary.statistics.message_count
    if counted != metadata_messages:
        warnings.append(f"metadata.yaml says {metadata_messages} messages, the files hold {counted}")
    return warnings


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
            namespaces = sorted({t.rsplit("/", 1)[0] or "/" for t in connections
                                 if t.endswith(("/currents", "/currents_block"))})
            if len(namespaces) > 1:
                raise BagError(f"{path}: drives in {', '.join(namespaces)}; which one is ambiguous "
                               f"(--namespace names it)")
            namespace = namespaces[0] if namespaces else "/drive"
        chosen = {}
        for topic in wanted:
            name = full_name(namespace, topic)
            if name not in connections:
                continue
            c = connections[name]
            if c.msgtype != TOPICS[topic].type and c.msgtype not in LEGACY_TYPES.get(TOPICS[topic].type, ()):
                raise BagError(f"{path}: {name} is {c.msgtype}, the contract says {TOPICS[topic].type}")
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
    """The runner's log layout (LOG_COLUMNS) filled from a bag's per-sample topics or their block twins
    (NaN where the bag says nothing), the sample period (``T_s``, else the drive_config's, else the
    stamps') and the bag's drive_config entries."""
    namespace, topics, configs = bag_topics(path, namespace)
    log, T_s, _, _ = log_from_topics(path, namespace, topics, configs, T_s)
    return log, T_s, configs


def bag_topics(path, namespace=None):
    """(namespace, the logged topics' messages, the drive_config entries as dicts) of a bag, read once."""
    wanted = SAMPLE_LOGGED + BLOCK_LOGGED + HELD_LOGGED + (ZERO_VOLTAGE, DRIVE_CONFIG)
    namespace, topics = read_topics(path, wanted, namespace)
    configs = []
    for _, message in topics.get(DRIVE_CONFIG, []):
        try:
            config = json.loads(message.data)
        except ValueError:
            raise BagError(f"{path}: {full_name(namespace, DRIVE_CONFIG)}: a message is not JSON") from None
        if isinstance(config, dict):
            configs.append(config)
    versions = {config.get("contract_version") for config in configs}
    newer = [v for v in versions if isinstance(v, int) and not isinstance(v, bool) and v > CONTRACT_VERSION]
    if newer:
        raise BagError(f"{path}: {full_name(namespace, DRIVE_CONFIG)}: contract_version {max(newer)}: a recording of "
                       f"a newer contract than this drive reads (up to {CONTRACT_VERSION}); update the drive")
    older = sorted("unstated" if v is None else str(v) for v in versions if v is None or v < NAMEPLATE_KEYS_SINCE)
    if older:
        warnings.warn(f"{path}: {full_name(namespace, DRIVE_CONFIG)}: contract_version {', '.join(older)}, read as "
                      f"version {CONTRACT_VERSION} (its motor a name, its missing keys from the command line)",
                      FormatMigrated, stacklevel=2)
    return namespace, topics, configs


NAMEPLATE_KEYS_SINCE = 2
"""The contract version from which drive_config carries the nameplate's keys; an older recording is read with a
warning. Version 2 differs from 3 only in the blocks' message type, which the reader reads either way."""
SIM_CLOCK_START_MAX_S = 60.0
"""A bag naming a scenario whose first stamp is before this is on sim time (the run's sample 0 at 0 s)."""
GRID_TOLERANCE = 0.25
"""A stamp within this share of T_s of a sample instant is placed on it (its jitter measured); one further
off is not a sample of this grid and is dropped (counted)."""
OFF_GRID_SHARE_MAX = 0.05
"""More of the currents' stamps than this share off the grid: the sample period given is not the recording's
(a robot's jitter and lost messages leave the rest on it)."""
MAX_RECORDING_SAMPLES = 200_000_000
"""A recording longer than this many samples (5.6 h at 10 kHz; 13 GiB of log) is refused, not allocated (a
recording may be longer than a simulation, drive_common.config.experiment.MAX_SAMPLES)."""


def log_from_topics(path, namespace, topics, configs, T_s=None, n_p=None, T_s_source="the sample period"):
    """(log, T_s, timing, zero_volts) from bag_topics' messages (bag_log); ``zero_volts``: per sample, True where
    the period from it ran at zero volts (the bridge's `zero_voltage`: the inverter's report of a command missing
    or PWM off, docs/drive-interface.md); ``n_p`` turns mechanical angles electrical
    (default: the drive_config's). Samples are indexed from the recording's own first sample, whatever the
    clock's epoch (a robot's wall clock or sim time), the grid's origin the median of the current stamps'
    offsets from it (one jittered stamp does not set it); a simulation's bag (its drive_config names a
    scenario, its stamps sim time from near 0) keeps its clock's zero, the run's sample 0. ``timing``: the
    epoch [s], the stamps' jitter about the grid (RMS and largest [s]) and how many were off it
    (docs/recordings.md). BagError, naming ``T_s_source``, when more than OFF_GRID_SHARE_MAX of the currents'
    stamps lie off the grid of ``T_s``: the sample period is not the recording's."""
    n_p = n_p or _pole_pairs(configs)
    blocks = not topics.get(CURRENTS) and bool(topics.get(block(CURRENTS)))
    currents = block(CURRENTS) if blocks else CURRENTS
    if not topics.get(currents):
        raise BagError(f"{path}: no {full_name(namespace, CURRENTS)} messages; the contract needs them")
    stamps = np.array([_stamp_ns(m.header.stamp) for _, m in topics[currents]], dtype=np.int64)
    width = len(block_channels(topics[currents][0][1])[0]) if blocks else 1
    if T_s is None:
        T_s = next((float(c["T_s_s"]) for c in configs if "T_s_s" in c), None)
    steps = np.diff(stamps) / width  # per sample [ns]: their median is the sample period the stamps show
    if T_s is None:
        if steps.size == 0 or steps.min() <= 0:
            raise BagError(f"{path}: {full_name(namespace, currents)} stamps are not increasing sample "
                           f"instants")
        T_s = float(np.median(steps)) * 1e-9
    simulation = any(isinstance(c.get("scenario"), str) or "source" in c for c in configs)
    simulation &= bool(stamps.min() < SIM_CLOCK_START_MAX_S * 1e9)
    T_ns = T_s * 1e9
    epoch_ns = log_epoch_ns = 0
    if not simulation:
        first = int(stamps.min())
        offsets = (stamps - first).astype(float)
        epoch_ns = first + int(round(float(np.median(offsets - np.round(offsets / T_ns) * T_ns))))
        log_epoch_ns = int(topics[currents][0][0]) + (epoch_ns - int(stamps[0]))
    offsets = (stamps - epoch_ns).astype(float)
    off = np.abs(offsets - np.round(offsets / T_ns) * T_ns) > GRID_TOLERANCE * T_ns
    if off.mean() > OFF_GRID_SHARE_MAX:
        shown = f"; they show {float(np.median(steps)) * 1e-9:g} s" if steps.size and np.median(steps) > 0 else ""
        raise BagError(f"{path}: {T_s_source} {T_s:g} s does not fit the recording: {off.mean():.0%} of its "
                       f"{full_name(namespace, currents)} stamps lie off that grid{shown}")
    if (stamps.max() - epoch_ns) / T_ns > MAX_RECORDING_SAMPLES:
        raise BagError(f"{path}: {full_name(namespace, currents)} stamps span {(stamps.max() - epoch_ns) * 1e-9:.3g} s "
                       f"from {epoch_ns * 1e-9:.3f} s, more than {MAX_RECORDING_SAMPLES} samples of {T_s:g} s")
    n = int(round((stamps.max() - epoch_ns) / T_ns)) + width
    log = np.full((n, len(LOG_COLUMNS)), np.nan)
    log[:, COLUMN["t"]] = np.arange(n) * T_s
    residuals = []
    off_grid = [0]

    def index(stamp):
        offset = _stamp_ns(stamp) - epoch_ns
        k = int(round(offset / T_ns))
        residual = offset - k * T_ns
        if abs(residual) > GRID_TOLERANCE * T_ns or not 0 <= k < n:
            off_grid[0] += 1
            return None
        residuals.append(residual)
        return k

    for topic in SAMPLE_LOGGED:
        for _, m in topics.get(topic, []):
            k = index(m.header.stamp)
            if k is not None:
                fill_sample(log[k], topic, m, n_p)
    for topic in BLOCK_LOGGED:
        for _, m in topics.get(topic, []):
            k = index(m.header.stamp)
            if k is not None:
                fill_block(log, k, topic, block_channels(m), n_p)
    for topic in HELD_LOGGED:
        _hold(log[:, COLUMN[TOPICS[topic].log_columns[0]]], topics.get(topic, []), T_s, n, log_epoch_ns)
    zero_volts = np.zeros(n, dtype=bool)
    for _, m in topics.get(ZERO_VOLTAGE, []):
        j = index(m.header.stamp)
        if j is not None:
            periods = np.asarray(block_channels(m)[0][:n - j], dtype=float) == 1.0
            zero_volts[j:j + len(periods)] |= periods
    jitter = np.abs(np.asarray(residuals, dtype=float)) * 1e-9
    timing = {"epoch_s": epoch_ns * 1e-9, "jitter_rms_s": float(np.sqrt(np.mean(jitter ** 2))) if jitter.size else 0.0,
              "jitter_max_s": float(jitter.max()) if jitter.size else 0.0, "off_grid_messages": off_grid[0],
              "zero_voltage_periods": int(zero_volts.sum())}
    return log, T_s, timing, zero_volts


def block_channels(message):
    """The three channels of a block message: a, b, c of a drive_msgs/msg/SampleBlock; position, velocity, effort
    of a sensor_msgs/JointState (the blocks up to contract version 2)."""
    if hasattr(message, "a"):
        return message.a, message.b, message.c
    return message.position, message.velocity, message.effort


def _hold(column, messages, T_s, n, epoch_ns=0):
    """Fill a column with unstamped commands, each held from its log time (from ``epoch_ns``; one logged
    before the first sample holds from it) on."""
    for t, m in messages:
        k = max(0, int(round((t - epoch_ns) * 1e-9 / T_s)))
        if k < n:
            column[k:] = m.data


def _pole_pairs(configs):
    """p from the bag's drive_config (every node's carries ``n_p``, a contract-v2 one in ``motor``); 1 when
    the bag has none."""
    for config in configs:
        if "n_p" in config:
            return int(config["n_p"])
        if isinstance(config.get("motor"), dict) and "n_p" in config["motor"]:
            return int(config["motor"]["n_p"])
    return 1


def _stamp_ns(stamp):
    return stamp.sec * 1_000_000_000 + stamp.nanosec


def recorded_estimator(configs):
    """The estimator a bag was recorded with: a node's ``estimator`` parameter, else a drive_config's
    ``estimator``; "" when none says."""
    for config in configs:
        if isinstance(config.get("parameters"), dict) and config["parameters"].get("estimator"):
            return str(config["parameters"]["estimator"])
    return next((c["estimator"] for c in configs if isinstance(c.get("estimator"), str)), "")


def bag_scenario(path, configs):
    """The scenario a bag was recorded from, rebuilt from its drive_config entries (the project's own:
    a node's parameters, or the runner's scenario source); None when none names one, BagError when the one
    named cannot be loaded."""
    for config in configs:
        try:
            if "parameters" in config:
                given = {k: v for k, v in config["parameters"].items() if v is not None}
                return scenario_from_parameters(all_parameters(given))
            if "source" in config:
                s = load_scenario(config["source"], estimator_override=config.get("estimator"))
                return dataclasses.replace(s, injection=_scenario_injection(config, s.injection),
                                           controller=config.get("controller", s.controller),
                                           block_samples=config.get("block_samples", s.block_samples),
                                           answer_periods=config.get("answer_periods", s.answer_periods))
        except ScenarioError as error:
            raise BagError(f"{path}: drive_config names a scenario that cannot be loaded ({error})") from None
    return None


def _scenario_injection(config, default):
    """The scenario injection a runner bag was recorded with: ``scenario_injection``, or in bags written
    before contract v2, ``injection`` (now the contract's {kind, frequency_Hz, amplitude_V})."""
    if isinstance(config.get("scenario_injection"), dict):
        return config["scenario_injection"]
    given = config.get("injection")
    return given if isinstance(given, dict) and "kind" not in given else default


def has_ground_truth(log):
    return bool(np.isfinite(log[:, COLUMN["theta_m"]]).any())
