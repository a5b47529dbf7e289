"""Rebuilding a recording into a complete bag from whatever of it reached the disk, without losing a byte.

Every .mcap of the bag is scanned: its summary (when it has one) for the channel definitions, then its
records in order. A corrupt record or chunk (bad CRC, bad compression, a length that runs off the file)
is skipped and counted, and the scan resynchronises on the next chunk that decodes and passes its CRC;
a closing sweep reads every plausible chunk the scan stepped over.
Exact duplicates (the same message twice) are kept once. The new bag is written beside the old one and
swapped in only when it is complete; the original files are kept in ``reindex-original/`` inside the bag,
so nothing is ever deleted or shrunk, and a failure (a full disk) leaves the bag as it was.
"""
import io
import shutil
import zlib
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

from drive_common.runtime.interrupt import deferred

from .common import BagCompleteError, BagError
from .reader import bag_info
from .writer import BagWriter

MAGIC = b"\x89MCAP0\r\n"
SCHEMA, CHANNEL, MESSAGE, CHUNK, FOOTER, DATA_END = 0x03, 0x04, 0x05, 0x06, 0x02, 0x0F
KNOWN_OPCODES = set(range(0x01, 0x10))
COMPRESSIONS = ("", "zstd", "lz4")
ORIGINALS = "reindex-original"
DEFAULT_QOS = [{"history": "keep_last", "depth": 10, "reliability": "reliable", "durability": "volatile",
                "deadline": {"sec": 0, "nsec": 0}, "lifespan": {"sec": 0, "nsec": 0},
                "liveliness": "automatic", "liveliness_lease_duration": {"sec": 0, "nsec": 0},
                "avoid_ros_namespace_conventions": False}]


@dataclass
class Recovered:
    """What a scan found: schemas and channels per (file, id), messages, and what was skipped."""

    schemas: dict = field(default_factory=dict)
    channels: dict = field(default_factory=dict)
    checked: set = field(default_factory=set)
    """Definitions that came with a checksum (a chunk's or the summary's): unchecked ones never replace
    them."""
    messages: list = field(default_factory=list)
    """(log_time, file, channel id, sequence, publish_time, data)."""
    skipped: Counter = field(default_factory=Counter)


def _read_chunk_records(content):
    """The records of a chunk record's content, its CRC checked; ValueError (or the library's) if corrupt."""
    from mcap.data_stream import ReadDataStream
    from mcap.records import Chunk
    from mcap.stream_reader import breakup_chunk
    chunk = Chunk.read(ReadDataStream(io.BytesIO(content)))
    if chunk.compression not in COMPRESSIONS:
        raise ValueError(f"unknown chunk compression {chunk.compression!r}")
    return breakup_chunk(chunk, validate_crc=True)


def _plausible_chunk(data, pos):
    """Whether a chunk record could start at ``pos`` (its lengths agree with each other and the file)."""
    if pos + 9 + 40 > len(data) or data[pos] != CHUNK:
        return False
    length = int.from_bytes(data[pos + 1:pos + 9], "little")
    body = pos + 9
    compression_length = int.from_bytes(data[body + 28:body + 32], "little")
    if compression_length > 8 or body + 32 + compression_length + 8 > len(data):
        return False
    tail = body + 32 + compression_length
    records_length = int.from_bytes(data[tail:tail + 8], "little")
    return length == 28 + 4 + compression_length + 8 + records_length and body + length <= len(data)


def _register(found, file_index, record, checked):
    from mcap.records import Channel, Message, Schema
    if isinstance(record, (Schema, Channel)):
        key = (type(record).__name__, file_index, record.id)
        if key in found.checked and not checked:
            return
        if checked:
            found.checked.add(key)
    if isinstance(record, Schema):
        found.schemas[file_index, record.id] = (record.name, record.encoding, record.data)
    elif isinstance(record, Channel):
        found.channels[file_index, record.id] = record
    elif isinstance(record, Message):
        found.messages.append((record.log_time, file_index, record.channel_id, record.sequence,
                               record.publish_time, record.data))


FOOTER_BYTES = 1 + 8 + 8 + 8 + 4
"""opcode, length, summary_start, summary_offset_start, summary_crc."""


def _summary_intact(data):
    """Whether the file ends in a footer whose summary CRC matches (a summary without CRC is trusted)."""
    footer = len(data) - len(MAGIC) - FOOTER_BYTES
    if footer < 0 or not data.endswith(MAGIC) or data[footer] != FOOTER:
        return False
    summary_start = int.from_bytes(data[footer + 9:footer + 17], "little")
    crc = int.from_bytes(data[footer + 25:footer + 29], "little")
    if not 0 < summary_start <= footer:
        return False
    return crc == 0 or zlib.crc32(data[summary_start:footer + 25]) == crc


def _read_summary(data, file_index, found):
    """Schemas and channels from the file's summary section, when its footer and summary are intact."""
    from mcap.reader import make_reader
    summary = None
    if _summary_intact(data):
        try:
            summary = make_reader(io.BytesIO(data)).get_summary()
        except Exception:
            summary = None
    if summary is None:
        found.skipped["files without an intact summary"] += 1
        return
    for record in list(summary.schemas.values()) + list(summary.channels.values()):
        _register(found, file_index, record, checked=True)


def _next_chunk(data, start, failed):
    """The first position at or after ``start`` where a chunk plausibly starts and has not failed."""
    while True:
        pos = data.find(bytes([CHUNK]), start)
        if pos < 0:
            return len(data)
        if pos not in failed and _plausible_chunk(data, pos):
            return pos
        start = pos + 1


def scan(data, file_index, found):
    """Collect what ``data`` (one .mcap file's bytes) holds into ``found``: its summary (when its CRC holds),
    then its data section up to DataEnd. Records that are not parsed (indexes) are stepped over by their
    length; after any failure the scan resumes from the end of the last record that parsed, at the first
    plausible chunk; at the end every plausible chunk it did not reach is read (_sweep_chunks), so a
    corrupt length never hides an intact chunk."""
    from mcap.data_stream import ReadDataStream
    from mcap.records import Channel, Message, Schema
    _read_summary(data, file_index, found)
    pos = len(MAGIC) if data.startswith(MAGIC) else 0
    trusted, failed, parsed = pos, set(), set()
    while pos + 9 <= len(data):
        opcode, length = data[pos], int.from_bytes(data[pos + 1:pos + 9], "little")
        end = pos + 9 + length
        try:
            if opcode not in KNOWN_OPCODES or end > len(data):
                raise ValueError("not a record")
            content = data[pos + 9:end]
            if opcode == CHUNK:
                for record in _read_chunk_records(content):
                    _register(found, file_index, record, checked=True)
                parsed.add(pos)
                trusted = end
            elif opcode in (SCHEMA, CHANNEL, MESSAGE):
                stream = ReadDataStream(io.BytesIO(content))
                read = {SCHEMA: Schema.read, CHANNEL: Channel.read}.get(opcode)
                _register(found, file_index, read(stream) if read else Message.read(stream, length), checked=False)
                trusted = end
        except Exception:
            found.skipped["corrupt chunks or records"] += 1
            failed.add(pos)
            pos = _next_chunk(data, trusted, failed)
            continue
        if opcode in (DATA_END, FOOTER):
            break
        pos = end
    _sweep_chunks(data, file_index, found, parsed | failed)


def _sweep_chunks(data, file_index, found, seen):
    """Every plausible chunk the scan did not reach (an index record's corrupt length can step over chunks
    onto a record that parses, up to DataEnd): read if its CRC holds, else counted as corrupt."""
    pos = _next_chunk(data, 0, seen)
    while pos < len(data):
        end = pos + 9 + int.from_bytes(data[pos + 1:pos + 9], "little")
        try:
            for record in _read_chunk_records(data[pos + 9:end]):
                _register(found, file_index, record, checked=True)
            start = end
        except Exception:
            found.skipped["corrupt chunks or records"] += 1
            start = pos + 1
        seen.add(pos)
        pos = _next_chunk(data, start, seen)


def recover(files):
    """Recovered messages of every file, in log-time order, exact duplicates once."""
    found = Recovered()
    for file_index, path in enumerate(files):
        scan(path.read_bytes(), file_index, found)
    unique, seen = [], set()
    for message in sorted(found.messages, key=lambda m: (m[0], m[1])):
        log_time, file_index, channel_id, sequence, publish_time, data = message
        channel = found.channels.get((file_index, channel_id))
        if channel is None or (file_index, channel.schema_id) not in found.schemas:
            found.skipped["messages of a channel whose definition was lost"] += 1
            continue
        key = (channel.topic, sequence, log_time, publish_time, zlib.crc32(data), len(data))
        if key in seen:
            found.skipped["duplicates"] += 1
            continue
        seen.add(key)
        unique.append(message)
    found.messages = unique
    return found


def _offered_qos(channel):
    """The channel's offered QoS profiles as recorded, or the default when they do not parse."""
    import yaml
    from rosbags.rosbag2.metadata import parse_qos
    try:
        profiles = yaml.safe_load(channel.metadata.get("offered_qos_profiles", "") or "")
        if isinstance(profiles, list) and profiles and parse_qos(profiles):
            return profiles
    except Exception:
        pass
    return DEFAULT_QOS


def _write(found, target):
    writer = BagWriter(target)
    topics = {}
    for (file_index, channel_id), channel in sorted(found.channels.items()):
        schema = found.schemas.get((file_index, channel.schema_id))
        if schema is None:
            continue
        if channel.topic not in writer.channels:
            writer.add(channel.topic, schema[0], _offered_qos(channel), schema=(schema[1], schema[2]))
        topics[file_index, channel_id] = channel.topic
    for log_time, file_index, channel_id, _, _, data in found.messages:
        writer.write(topics[file_index, channel_id], data, False, log_time)
    writer.close()


def _free_name(directory, name):
    candidate, n = directory / name, 1
    while candidate.exists():
        n += 1
        candidate = directory / f"{name}-{n}"
    return candidate


def reindex(path, force=False):
    """Rebuild the bag at ``path`` from every .mcap in it. Without ``force`` only a bag that lacks its
    metadata.yaml (a killed recorder) is rebuilt. Returns bag_info of the result with ``recovery``: the
    messages kept, what was skipped, and where the originals are."""
    path = Path(path)
    if not path.is_dir():
        raise BagError(f"{path}: no such bag directory")
    if (path / "metadata.yaml").exists() and not force:
        raise BagCompleteError(f"{path}: already complete (has metadata.yaml)")
    files = sorted(p for p in path.glob("*.mcap") if p.is_file())
    if not files:
        raise BagError(f"{path}: no .mcap file to reindex")
    found = recover(files)
    if not found.messages:
        raise BagError(f"{path}: nothing recoverable in {', '.join(f.name for f in files)} "
                       f"({', '.join(f'{n} {k}' for k, n in found.skipped.items()) or 'no messages'}); "
                       f"the bag is left as it was")
    staging = _free_name(path.parent, f".{path.name}.reindexing")
    target = staging / path.name
    try:
        staging.mkdir()
        _write(found, target)
    except (OSError, BagError) as error:
        shutil.rmtree(staging, ignore_errors=True)
        reason = error.strerror if isinstance(error, OSError) else str(error)
        raise BagError(f"{path}: reindex failed ({reason}); the bag is left as it was") from None
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    with deferred():
        originals = _free_name(path, ORIGINALS)
        originals.mkdir()
        for old in files + [path / "metadata.yaml"]:
            if old.exists():
                old.rename(originals / old.name)
        for new in target.iterdir():
            new.rename(path / new.name)
        shutil.rmtree(staging)
    info = bag_info(path)
    info["recovery"] = {"messages": len(found.messages), "skipped": dict(found.skipped),
                        "originals": str(originals)}
    return info


def reindex_line(info):
    """What reindex did, in one line."""
    recovery = info["recovery"]
    skipped = ", ".join(f"{n} {what}" for what, n in recovery["skipped"].items()) or "nothing"
    return (f"{info['bag']}: rebuilt, {info['messages']:,} messages over {info['duration_s']:.6f} s; "
            f"skipped: {skipped}; the original files are kept in {recovery['originals']}")
