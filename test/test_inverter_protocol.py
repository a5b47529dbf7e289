"""The inverter wire protocol: the Python codec and the C codec (built here with the host compiler)
against the same test vectors; round trips and resynchronisation fuzzed with hypothesis."""
import struct
import subprocess
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drive_bridge.inverter_protocol import (
    MAX_BLOCK,
    CanDecoder,
    Command,
    CommandBlock,
    Control,
    FrameError,
    FrameReader,
    Heartbeat,
    Hello,
    Telemetry,
    TelemetryBlock,
    can_base,
    cobs_decode,
    cobs_encode,
    command_flags,
    crc16,
    decode_frame,
    encode_frame,
    payload_message,
    requested_safe_state,
    to_can,
    to_canfd,
    unwrap16,
)

pytestmark = pytest.mark.unit

FIRMWARE = Path(__file__).resolve().parents[1] / "firmware" / "inverter_protocol"
VECTORS = FIRMWARE / "test_vectors.txt"
CLASSES = {cls.__name__.upper(): cls for cls in (Telemetry, Hello, Command, Control, Heartbeat)}


def parse_message(words):
    if words[0] in ("TELEMETRY_BLOCK", "COMMAND_BLOCK"):
        return parse_block(words)
    cls = CLASSES[words[0]]
    values = []
    for name, text in zip(cls.__dataclass_fields__, words[1:]):
        if cls.__dataclass_fields__[name].type == "float" or cls.__dataclass_fields__[name].type is float:
            values.append(struct.unpack("<f", struct.pack("<I", int(text, 16)))[0])
        else:
            values.append(int(text))
    return cls(*values)


def parse_block(words):
    """TELEMETRY_BLOCK seq u_dc status n (i_a i_b i_c encoder) × n, or COMMAND_BLOCK seq flags n
    (u_α u_β) × n."""
    values = [int(word) for word in words[1:]]
    if words[0] == "TELEMETRY_BLOCK":
        seq, u_dc, status, n, *rest = values
        return TelemetryBlock(seq, u_dc, status, tuple(tuple(rest[4 * i:4 * i + 4]) for i in range(n)))
    seq, flags, n, *rest = values
    return CommandBlock(seq, flags, tuple(tuple(rest[2 * i:2 * i + 2]) for i in range(n)))


def vectors(kind):
    for line in VECTORS.read_text().splitlines():
        if line.startswith(kind + " "):
            yield line[len(kind) + 1:]


@pytest.mark.parametrize("line", list(vectors("serial")))
def test_serial_vectors(line):
    fields, wire = line.split(" = ")
    message = parse_message(fields.split())
    assert encode_frame(message).hex() == wire
    assert FrameReader().feed(bytes.fromhex(wire)) == [message]


@pytest.mark.parametrize("line", list(vectors("can")))
def test_can_vectors(line):
    fields, frames = line.split(" = ")
    drive, *words = fields.split()
    message = parse_message(words)
    expected = [(int(i, 16), bytes.fromhex(d)) for i, d in (f.split(":") for f in frames.split())]
    assert to_can(message, int(drive)) == expected
    decoder = CanDecoder(int(drive))
    decoded = [m for m in (decoder.feed(i, d) for i, d in expected) if m is not None]
    assert len(decoded) == 1
    got = decoded[0]
    if hasattr(message, "seq"):
        assert got.seq & 0xFFFF == message.seq & 0xFFFF
        got = type(got)(**{**vars(got), "seq": message.seq})
    assert got == message


@pytest.mark.parametrize("line", list(vectors("canfd")))
def test_canfd_vectors(line):
    """A block on CAN FD: chunks of at most 6 telemetry or 14 command samples, each a block message of
    its own samples with its first sample's seq; together they are the block."""
    fields, frames = line.split(" = ")
    drive, *words = fields.split()
    message = parse_message(words)
    expected = [(int(i, 16), bytes.fromhex(d)) for i, d in (f.split(":") for f in frames.split())]
    assert to_canfd(message, int(drive)) == expected
    assert all(len(data) in (12, 16, 20, 24, 32, 48, 64) or len(data) <= 8 for _, data in expected)
    decoder = CanDecoder(int(drive))
    chunks = [decoder.feed(i, d) for i, d in expected]
    assert [chunk.seq for chunk in chunks] == [(message.seq + sum(len(c.samples) for c in chunks[:j])) % 2 ** 32
                                               for j in range(len(chunks))]
    assert sum((chunk.samples for chunk in chunks), ()) == message.samples
    assert all(vars(chunk) | {"seq": 0, "samples": ()} == vars(message) | {"seq": 0, "samples": ()}
               for chunk in chunks)


@pytest.mark.parametrize("line", list(vectors("bad")))
def test_bad_frames_are_named(line):
    wire, kind = line.split()
    with pytest.raises(FrameError) as error:
        decode_frame(bytes.fromhex(wire))
    assert error.value.kind == kind


@pytest.mark.parametrize("line", list(vectors("safe")))
def test_safe_state_flags(line):
    """The safe state a command's flags ask for (bits 1-2), and the flags of an asked one (bits 0-2)."""
    flags, state = map(int, line.split(" = "))
    assert requested_safe_state(flags) == state
    if (flags & 0x06) >> 1 == state:
        assert command_flags(flags & 1, state) == flags & 0x07


def test_a_version_1_peer_is_named_not_misread():
    """A version 1 frame (here a v1 TELEMETRY, valid CRC) is a version error naming both versions."""
    with pytest.raises(FrameError, match="protocol version 1, this host speaks 2") as error:
        decode_frame(bytes.fromhex("040101070101049cff32023206c05dd2048003414d"))
    assert error.value.kind == "version"


def test_blocks_hold_one_to_max_block_samples():
    for samples in ((), ((0, 0),) * (MAX_BLOCK + 1)):
        with pytest.raises(ValueError, match=f"1 to {MAX_BLOCK} samples"):
            encode_frame(CommandBlock(0, 1, samples))


def test_crc_check_value_and_unwrap():
    assert crc16(b"123456789") == 0x29B1
    assert unwrap16(0x0002, 0xFFFFFFFE) == 2 and unwrap16(0xFFFE, 3) == 0xFFFFFFFE


def test_c_codec_passes_the_same_vectors(tmp_path):
    """`make test` in firmware/inverter_protocol: C99, -Wall -Wextra -Werror -pedantic."""
    done = subprocess.run(["make", "-s", "-C", str(FIRMWARE), "test", f"BUILD={tmp_path}"],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stdout + done.stderr
    count = sum(1 for kind in ("serial", "can", "canfd", "bad", "safe") for _ in vectors(kind))
    assert f"{count} vectors, 0 failures" in done.stdout


u16, u32 = st.integers(0, 0xFFFF), st.integers(0, 0xFFFFFFFF)
i16 = st.integers(-0x8000, 0x7FFF)
f32 = st.floats(width=32, allow_nan=False)
messages = st.one_of(
    st.builds(Telemetry, u32, i16, i16, i16, u16, u16, u16),
    st.builds(Hello, st.integers(0, 255), st.integers(0, 255), st.integers(0, 255), st.integers(0, 255), u32,
              f32, f32, f32, u16),
    st.builds(Command, u32, i16, i16, st.integers(0, 255)),
    st.builds(TelemetryBlock, u32, u16, u16,
              st.lists(st.tuples(i16, i16, i16, u16), min_size=1, max_size=MAX_BLOCK).map(tuple)),
    st.builds(CommandBlock, u32, st.integers(0, 255),
              st.lists(st.tuples(i16, i16), min_size=1, max_size=MAX_BLOCK).map(tuple)),
    st.builds(Control, st.integers(0, 255)),
    st.builds(Heartbeat, u32))


PROTOCOL_MESSAGES = (Telemetry, TelemetryBlock, Command, CommandBlock, Control, Heartbeat, Hello)


@settings(max_examples=300, deadline=None)
@given(st.lists(messages, min_size=1, max_size=8))
def test_any_messages_round_trip_through_the_stream(batch):
    assert FrameReader().feed(b"".join(encode_frame(m) for m in batch)) == batch


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=300))
def test_cobs_round_trips(data):
    encoded = cobs_encode(data)
    assert 0 not in encoded and cobs_decode(encoded) == data


@settings(max_examples=500, deadline=None)
@given(st.binary(max_size=200), messages)
def test_garbage_never_crashes_and_the_stream_resynchronises(garbage, message):
    """Arbitrary bytes are counted as bad frames or ignored, never raise; after a delimiter the next
    frame decodes."""
    reader = FrameReader()
    reader.feed(garbage)
    assert reader.feed(b"\x00" + encode_frame(message))[-1:] == [message]


@settings(max_examples=300, deadline=None)
@given(messages, st.data())
def test_a_flipped_bit_is_caught(message, data):
    """Any single corrupted bit in a frame is dropped (CRC-16 catches all 1-bit errors), never decoded
    as another message."""
    wire = bytearray(encode_frame(message))
    position = data.draw(st.integers(0, len(wire) - 2))
    wire[position] ^= 1 << data.draw(st.integers(0, 7))
    reader = FrameReader()
    assert reader.feed(bytes(wire)) == [] and sum(reader.errors.values()) >= 1


@settings(max_examples=300, deadline=None)
@given(st.integers(0, 0x7FF), st.binary(max_size=8))
def test_can_decoder_takes_any_frame(identifier, data):
    """Any classic frame gives a protocol message, nothing (a frame that completes none, or one of another
    drive), or a counted framing error with its reason; never a raise."""
    decoder = CanDecoder(0)
    message = decoder.feed(identifier, data)
    assert message is None or isinstance(message, PROTOCOL_MESSAGES)
    if message is None and decoder.errors:
        assert sum(decoder.errors.values()) == 1 and decoder.last_error.startswith(f"CAN {identifier:#05x}: ")


@settings(max_examples=200, deadline=None)
@given(st.integers(0, 15), st.one_of(
    st.builds(TelemetryBlock, u32, u16, u16,
              st.lists(st.tuples(i16, i16, i16, u16), min_size=1, max_size=MAX_BLOCK).map(tuple)),
    st.builds(CommandBlock, u32, st.integers(0, 255),
              st.lists(st.tuples(i16, i16), min_size=1, max_size=MAX_BLOCK).map(tuple))))
def test_any_block_round_trips_through_can_fd(drive, block):
    decoder = CanDecoder(drive)
    chunks = [decoder.feed(identifier, data) for identifier, data in to_canfd(block, drive)]
    assert chunks[0].seq == block.seq and sum((c.samples for c in chunks), ()) == block.samples


@settings(max_examples=300, deadline=None)
@given(st.sampled_from((0x103, 0x10D)), st.binary(max_size=64))
def test_can_fd_decoder_takes_any_frame(identifier, data):
    """Any bytes in a CAN FD block frame give a block of the samples the frame says it holds, or one
    counted framing error; never a raise."""
    decoder = CanDecoder(0)
    block = decoder.feed(identifier, data)
    if block is None:
        assert sum(decoder.errors.values()) == 1
    else:
        assert isinstance(block, (TelemetryBlock, CommandBlock)) and 1 <= len(block.samples) <= MAX_BLOCK
        assert decoder.errors == {}


def _compiled_can_bridge(kind, fd=-1, drive=3):
    """compiled_bridge's arrays of a bridge on a CAN link of ``kind`` (CABLE, SOCKETCAN) writing to ``fd``, with
    HELLO taken (voltage step 1 V)."""
    import numpy as np

    from drive_bridge import can_codec
    from drive_bridge import compiled_bridge as cb
    state, counters = cb.bridge_state(10, 1.0, 1.0)
    state[cb.FD], state[cb.LINK_KIND], state[cb.CAN_BASE] = fd, kind, can_base(drive)
    state[cb.HAS_HELLO], state[cb.VOLTAGE_LSB], state[cb.CURRENT_LSB] = 1.0, 1.0, 1.0
    rx = np.zeros(cb.READ_BYTES, dtype=np.uint8)
    return cb.bridge_arrays(state, counters, np.full((8, 2), np.nan), rx, can_codec.can_decoder())


def test_the_compiled_answer_writes_socketcan_frames_as_python_can_builds_them():
    """SocketCAN's frame layout (no PF_CAN on this machine to run it): what the compiled answer writes for a
    COMMAND_BLOCK of 20 samples (two CAN FD frames) and a CONTROL (a classic frame), byte for byte python-can's
    SocketCAN frames of the same messages (to_canfd, to_can)."""
    import os

    import can
    import numpy as np
    from can.interfaces.socketcan.socketcan import build_can_frame

    from drive_bridge import compiled_bridge as cb
    from drive_bridge.inverter_protocol import CONTROL_DISABLE
    read_end, write_end = os.pipe()
    try:
        b = _compiled_can_bridge(cb.SOCKETCAN, write_end)
        u_alpha, u_beta = np.arange(20) * 3.0 - 30.0, 7.0 - np.arange(20)
        assert cb.write_commands(b, 40, u_alpha, u_beta, 20, True, 0)
        assert cb.send_control(b, CONTROL_DISABLE)
        written = os.read(read_end, 4096)
    finally:
        os.close(read_end)
        os.close(write_end)
    block = CommandBlock(40, command_flags(True), tuple(zip(u_alpha.astype(int).tolist(), u_beta.astype(int).tolist())))
    frames = [can.Message(arbitration_id=i, data=d, is_extended_id=False, is_fd=True, bitrate_switch=True)
              for i, d in to_canfd(block, 3)]
    frames += [can.Message(arbitration_id=i, data=d, is_extended_id=False)
               for i, d in to_can(Control(CONTROL_DISABLE), 3)]
    assert written == b"".join(build_can_frame(frame) for frame in frames)


def test_the_compiled_answer_reads_socketcan_frames_as_the_python_codec_does():
    """python-can's SocketCAN frames of a TELEMETRY_BLOCK of 10 samples (two CAN FD frames) and of a HELLO (three
    classic frames): the compiled reader gives the payloads the Python codec decodes to the same messages."""
    import can
    from can.interfaces.socketcan.socketcan import build_can_frame

    from drive_bridge import compiled_bridge as cb
    b = _compiled_can_bridge(cb.SOCKETCAN)
    block = TelemetryBlock(70000, 812, 0x80, tuple((i, -i, 2 * i, 100 * i) for i in range(10)))
    hello = Hello(3, 1, 4, 10, 100000, 0.01, 0.02, 20.0, 30)
    messages = []
    for identifier, data in to_canfd(block, 3) + to_can(hello, 3):
        frame = can.Message(arbitration_id=identifier, data=data, is_extended_id=False, is_fd=len(data) > 8,
                            bitrate_switch=len(data) > 8)
        raw = build_can_frame(frame)
        b.rx[:len(raw)] = list(raw)
        b.state[cb.RX_BYTES] = len(raw)
        after, m = cb.next_payload(b, 0)
        assert after == len(raw) and cb.next_payload(b, after) == (-1, 0)
        if m:
            messages.append(payload_message(b.raw[:m].tobytes()))
    decoder = CanDecoder(3)
    expected = [decoder.feed(i, d) for i, d in to_canfd(block, 3) + to_can(hello, 3)]
    assert messages == [m for m in expected if m is not None] and len(messages) == 3


def test_the_compiled_answer_flags_a_cable_frame_as_the_cable_does():
    from drive_bridge import can_cable
    from drive_bridge import compiled_bridge as cb
    assert cb.CABLE_FD_BRS == can_cable.FD | can_cable.BRS
