"""Corrupted bags (40; 220 under the `heavy` marker: flipped bits, zeroed ranges, truncations, duplicated
chunks, inserted garbage, broken or missing metadata, extra files) through `bag info`, `bench replay`,
`bench compare` and `bag reindex`: no traceback, the bag untouched by all but reindex, and reindex keeps
every message that survived the corruption. Bags whose metadata.yaml or drive_config is mutated key by
key: read, or refused naming the bag and the key.

What survived is decided here with the mcap library, not with the code under test: every message of a
chunk whose bytes the corruption did not touch, provided its channel's definition survived too (in the
first chunk or in the file's summary)."""
import dataclasses
import io
import json
import random
import shutil

import pytest
import yaml
from mcap.data_stream import ReadDataStream
from mcap.reader import make_reader
from mcap.records import Channel, Chunk, Message
from mcap.stream_reader import breakup_chunk

from drive_common.config.scenario import load_scenario
from drive_common.contract.strict_json import dumps
from drive_tools.bags.common import typestore
from drive_tools.bags.writer import BagWriter, write_run_bag
from drive_tools.cli.cli import main
from drive_tools.runner.runner import run_scenario
from helpers import blames, mutate

SAMPLE_CASES, FULL_CASES = 40, 220
"""Corrupted bags in the default run, and under the `heavy` marker."""


@dataclasses.dataclass
class Layout:
    """Where the original .mcap keeps its chunks and summary, and the messages of each chunk."""

    size: int
    chunks: list
    """(start, end, [(topic, log_time, data)]) per chunk, in file order."""
    summary_start: int
    channels_in_first_chunk: bool


def layout(data):
    summary = make_reader(io.BytesIO(data)).get_summary()
    topics = {c.id: c.topic for c in summary.channels.values()}
    chunks, first_defines = [], False
    for index in sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset):
        start, end = index.chunk_start_offset, index.chunk_start_offset + index.chunk_length
        chunk = Chunk.read(ReadDataStream(io.BytesIO(data[start + 9:end])))
        records = breakup_chunk(chunk, validate_crc=True)
        if not chunks:
            first_defines = {r.id for r in records if isinstance(r, Channel)} == set(topics)
        chunks.append((start, end, [(topics[r.channel_id], r.log_time, r.data) for r in records
                                    if isinstance(r, Message)]))
    footer = len(data) - 8 - 29
    assert data[footer] == 0x02
    summary_start = int.from_bytes(data[footer + 9:footer + 17], "little")
    assert chunks[-1][1] <= summary_start < footer
    return Layout(len(data), chunks, summary_start, first_defines)


def surviving(lay, touched, cut=None):
    """Messages that survive when the byte ranges ``touched`` changed and the file was cut at ``cut``."""
    def intact(start, end):
        return (cut is None or end <= cut) and all(end <= a or b <= start for a, b in touched)
    definitions = (lay.channels_in_first_chunk and lay.chunks and intact(*lay.chunks[0][:2])) or (
        cut is None and intact(lay.summary_start, lay.size))
    if not definitions:
        return set()
    return {m for start, end, messages in lay.chunks if intact(start, end) for m in messages}


def messages_of(bag):
    found = set()
    for path in bag.glob("*.mcap"):
        with path.open("rb") as stream:
            for _, channel, message in make_reader(stream).iter_messages():
                found.add((channel.topic, message.log_time, message.data))
    return found


def contents(directory):
    """Every file under ``directory`` and its bytes."""
    return {path: path.read_bytes() for path in directory.rglob("*") if path.is_file()}


@pytest.fixture(scope="module")
def original(tmp_path_factory):
    root = tmp_path_factory.mktemp("fuzz")
    scenario = dataclasses.replace(load_scenario("wang_100rpm"), duration_s=0.02)
    bag = write_run_bag(run_scenario(scenario), root / "original", chunk_bytes=4096)
    (mcap,) = bag.glob("*.mcap")
    data = mcap.read_bytes()
    lay = layout(data)
    assert len(lay.chunks) > 10
    return root, bag, data, lay


def corruptions(rng, data, lay, cases):
    """(kind, new .mcap bytes, touched ranges, cut, metadata action, extra file) per case."""
    kinds = ["flip", "flips", "zero", "truncate", "duplicate", "garbage", "no_metadata", "bad_metadata",
             "extra_copy", "empty_extra"]
    for i in range(cases):
        kind = kinds[i % len(kinds)]
        d, touched, cut, metadata, extra = bytearray(data), [], None, "keep", None
        if kind in ("flip", "flips"):
            for _ in range(1 if kind == "flip" else 5):
                at = rng.randrange(len(d))
                d[at] ^= 1 << rng.randrange(8)
                touched.append((at, at + 1))
        elif kind == "zero":
            at = rng.randrange(len(d) - 64)
            d[at:at + 64] = bytes(64)
            touched.append((at, at + 64))
        elif kind == "truncate":
            cut = rng.randrange(8, len(d))
            del d[cut:]
        elif kind == "duplicate":
            start, end, _ = rng.choice(lay.chunks)
            d[end:end] = data[start:end]
            touched.append((lay.summary_start, lay.size))
        elif kind == "garbage":
            _, end, _ = rng.choice(lay.chunks)
            d[end:end] = bytes(rng.randrange(256) for _ in range(100))
            touched.append((lay.summary_start, lay.size))
        elif kind == "no_metadata":
            metadata = "delete"
        elif kind == "bad_metadata":
            metadata = "garbage"
        elif kind == "extra_copy":
            extra = bytes(data)
        elif kind == "empty_extra":
            extra = b""
        yield f"{i:03d}_{kind}", bytes(d), touched, cut, metadata, extra


@pytest.mark.parametrize("cases", [SAMPLE_CASES, pytest.param(FULL_CASES, marks=pytest.mark.heavy)])
def test_corrupted_bags_give_one_line_or_a_result_and_reindex_keeps_what_survived(original, tmp_path, capsys, cases):
    root, bag, data, lay = original
    rng = random.Random(20261122)
    rebuilt = 0
    for name, content, touched, cut, metadata, extra in corruptions(rng, data, lay, cases):
        case = tmp_path / name
        shutil.copytree(bag, case)
        (mcap,) = case.glob("*.mcap")
        mcap.write_bytes(content)
        if metadata == "delete":
            (case / "metadata.yaml").unlink()
        elif metadata == "garbage":
            (case / "metadata.yaml").write_bytes(bytes(rng.randrange(256) for _ in range(200)))
        if extra is not None:
            (case / f"{case.name}_1.mcap").write_bytes(extra)
        out = tmp_path / "out"
        as_given = contents(case)
        for argv in (["bag", "info", str(case)],
                     ["bench", "replay", str(case), "--estimators", "sensored", "--no-plot", "--out", str(out)],
                     ["bench", "compare", str(case), str(bag), "--no-plot", "--out", str(out)],
                     ["bag", "reindex", str(case), "--force"]):
            code = main(argv)
            _, err = capsys.readouterr()
            assert code in (0, 2), (name, argv[:2], err)
            assert code == 0 or (err.count("\n") == 1 and "Traceback" not in err), (name, argv[:2], err)
            assert argv[1] == "reindex" or contents(case) == as_given, (name, argv[:2])
        expected = surviving(lay, touched, cut)
        if code == 0:
            rebuilt += 1
            assert expected <= messages_of(case), (name, str(case), touched, len(expected - messages_of(case)))
            kept = case / "reindex-original" / mcap.name
            assert kept.read_bytes() == content, name
        else:
            assert not expected, name
            assert mcap.read_bytes() == content, name
    assert rebuilt > cases // 2


def test_a_corrupt_index_length_that_lands_on_the_summary_hides_no_chunk(original, tmp_path):
    """The message index after the third chunk given a length that ends exactly where the summary begins:
    stepping over it lands on records that parse up to the footer. Reindex still keeps every chunk after it
    (found by the closing sweep over plausible chunks)."""
    root, bag, data, lay = original
    _, end, _ = lay.chunks[2]
    assert data[end] == 0x07
    corrupt = bytearray(data)
    corrupt[end + 1:end + 9] = (lay.summary_start - end - 9).to_bytes(8, "little")
    case = tmp_path / "index_length"
    shutil.copytree(bag, case)
    (mcap,) = case.glob("*.mcap")
    mcap.write_bytes(bytes(corrupt))
    assert main(["bag", "reindex", str(case), "--force"]) == 0
    assert surviving(lay, [(end, end + 9)]) <= messages_of(case)


def rewritten(bag, target, drive_config):
    """A copy of ``bag`` at ``target``: its messages as recorded but drive_config's JSON replaced by
    ``drive_config``."""
    (mcap,) = bag.glob("*.mcap")
    writer = BagWriter(target)
    with mcap.open("rb") as stream:
        for schema, channel, message in make_reader(stream).iter_messages():
            if channel.topic not in writer.channels:
                writer.add(channel.topic, schema.name, yaml.safe_load(channel.metadata["offered_qos_profiles"]))
            data = message.data
            if channel.topic.endswith("/drive_config"):
                data = writer.store.serialize_cdr(writer.store.types["std_msgs/msg/String"](
                    data=dumps(drive_config)), "std_msgs/msg/String")
            writer.write(channel.topic, data, False, message.log_time)
    writer.close()
    return target


def recorded_config(bag):
    (mcap,) = bag.glob("*.mcap")
    with mcap.open("rb") as stream:
        for *_, message in make_reader(stream).iter_messages(topics=["/drive/drive_config"]):
            return json.loads(typestore().deserialize_cdr(message.data, "std_msgs/msg/String").data)


def not_strict(constant):
    raise AssertionError(f"non-strict JSON constant {constant}")


def test_a_mutated_drive_config_is_replayed_or_refused_naming_the_bag_and_key(original, tmp_path, capsys):
    """Each key of the recorded drive_config given a hostile value, a unit slip, deleted, or an unknown key
    added: `bench replay` scores it (strict JSON) or refuses in one line naming the bag and the key."""
    _, bag, _, _ = original
    config = recorded_config(bag)
    rng = random.Random(20261127)
    outcomes = {0: 0, 2: 0}
    for i in range(30):
        document = json.loads(json.dumps(config))
        kind, trail, _, blamed = mutate(rng, document)
        case = rewritten(bag, tmp_path / f"{i:02d}_{kind}", document)
        code = main(["bench", "replay", str(case), "--estimators", "sensored", "--no-plot", "--json"])
        out, err = capsys.readouterr()
        assert code in outcomes, (case.name, trail, err)
        outcomes[code] += 1
        if code == 2:
            assert err.count("\n") == 1 and str(case) in err and "drive_config" in err, (case.name, err)
            assert blames(err, blamed + (str(trail[-1]),)), (case.name, trail, err)
        else:
            assert json.loads(out, parse_constant=not_strict)["results"], case.name
    assert outcomes[0] > 10 and outcomes[2] > 3, outcomes


def test_a_mutated_metadata_yaml_is_read_or_refused_naming_the_bag(original, tmp_path, capsys):
    """metadata.yaml's keys mutated one at a time: `bag info` reads the bag (what the .mcap holds, a warning
    where they disagree) or refuses in one line naming it; the bag is left as it was."""
    _, bag, _, lay = original
    metadata = yaml.safe_load((bag / "metadata.yaml").read_text())
    recorded = sum(len(messages) for _, _, messages in lay.chunks)
    rng = random.Random(20261128)
    outcomes = {0: 0, 2: 0}
    for i in range(30):
        document = yaml.safe_load(yaml.safe_dump(metadata))
        kind, trail, _, _ = mutate(rng, document)
        case = tmp_path / f"{i:02d}_{kind}"
        shutil.copytree(bag, case)
        (case / "metadata.yaml").write_text(yaml.safe_dump(document, allow_unicode=True), encoding="utf-8")
        as_given = contents(case)
        code = main(["bag", "info", str(case), "--json"])
        out, err = capsys.readouterr()
        assert code in outcomes and contents(case) == as_given, (case.name, trail, err)
        outcomes[code] += 1
        if code == 2:
            assert err.count("\n") == 1 and str(case) in err and "Traceback" not in err, (case.name, err)
        else:
            info = json.loads(out)
            assert info["messages"] == recorded or info["warnings"], (case.name, trail, info["messages"])
    assert outcomes[0] > 5 and outcomes[2] > 5, outcomes
