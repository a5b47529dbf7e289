"""Rebuilding a cut recording into a complete bag from the chunks that reached the disk."""
from pathlib import Path

from .common import BagCompleteError, BagError, rosbags_qos
from .reader import bag_info
from .writer import BagWriter


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
            raise BagCompleteError(f"{path}: already complete (has metadata.yaml)")
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
