"""The CAN mapping of the inverter protocol as numba kernels on byte arrays (docs/inverter-protocol.md, "CAN
mapping" and "CAN FD: blocks"): a CAN frame's data to the serial payload (version, type, body; no CRC) of the
message it completes, and a serial payload to its CAN frames. One algorithm: the Python codec
(inverter_protocol.CanDecoder, to_can, to_canfd) calls these kernels, and so does the compiled answer over
CAN (drive_bridge.compiled_bridge), without the interpreter's lock. No allocation in the kernels."""
import numpy as np
from numba import njit

from .frame_codec import (
    COMMAND,
    COMMAND_BLOCK,
    COMMAND_BLOCK_ENTRY,
    COMMAND_BLOCK_HEAD,
    CONTROL,
    FRAME_FRAMING,
    FRAME_UNKNOWN_TYPE,
    FRAME_VERSION,
    HEARTBEAT,
    HELLO,
    TELEMETRY,
    TELEMETRY_BLOCK,
    TELEMETRY_BLOCK_ENTRY,
    TELEMETRY_BLOCK_HEAD,
    VERSION,
    put_u16,
    put_u32,
    u16,
    u32,
)

CAN_COMMAND, CAN_CONTROL, CAN_HEARTBEAT, CAN_COMMAND_BLOCK = 0x00, 0x01, 0x02, 0x03
CAN_TELEMETRY_B, CAN_TELEMETRY_A, CAN_HELLO_A, CAN_HELLO_B, CAN_HELLO_C = 0x08, 0x09, 0x0A, 0x0B, 0x0C
CAN_TELEMETRY_BLOCK = 0x0D
TELEMETRY_CHUNK, COMMAND_CHUNK = 6, 14
"""Most samples in one 64-byte CAN FD frame of a TELEMETRY_BLOCK, a COMMAND_BLOCK."""
CANFD_LENGTHS = np.array((0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64), dtype=np.int64)
IDS_PER_DRIVE = 0x20
"""A drive's identifiers: base … base + 0x1F (base 0x100 + 0x20 × drive_id)."""
MAX_FRAMES = 5
"""Most CAN frames one payload takes: a TELEMETRY_BLOCK of 30 samples in chunks of 6."""
LAST_SEQ, U_DC, ENCODER, STATUS, HELLO_PARTS = range(5)
"""A decoder's state (int64): the last sequence number unwrapped, TELEMETRY_B's u_dc, encoder and status, the
HELLO parts (A, B, C: bits 0-2) held; its ``hello`` (uint8, HELLO_BYTES) holds them in the serial layout."""
HELLO_BYTES = 24
"""HELLO's serial payload: version, type and its 22-byte body."""


def can_decoder():
    """(state, hello) of a decoder that has heard nothing."""
    return np.zeros(5, dtype=np.int64), np.zeros(HELLO_BYTES, dtype=np.uint8)


@njit(cache=True, nogil=True)
def unwrap16(low, last):
    """The u32 sequence number whose low 16 bits are ``low``, nearest to ``last``."""
    delta = ((low - last) + 0x8000) % 0x10000 - 0x8000
    return (last + delta) % 0x100000000


@njit(cache=True, nogil=True)
def _copy(source, at, target, to, n):
    """``source[at:at + n]`` into ``target[to:to + n]``."""
    for i in range(n):
        target[to + i] = source[at + i]


@njit(cache=True, nogil=True)
def payload_of_frame(offset, data, n, state, hello, raw):
    """The serial payload the frame ``data[:n]`` at identifier offset ``offset`` (from the drive's base)
    completes, into ``raw``: its length; 0 when it completes none (TELEMETRY_B, a HELLO part); −(frame_codec's
    error kind) for a frame that is none of the protocol's (a wrong length, a block of 0 or too many samples:
    FRAME_FRAMING; a HELLO of another version: FRAME_VERSION; an unknown offset: FRAME_UNKNOWN_TYPE).
    Classic frames carry the low 16 bits of seq, unwrapped against the last one (``state``); a CAN FD block
    frame is the block message of its own samples (its padding ignored)."""
    raw[0] = VERSION
    if offset == CAN_TELEMETRY_A or offset == CAN_COMMAND or offset == CAN_TELEMETRY_B:
        if n != 8:
            return -FRAME_FRAMING
        if offset == CAN_TELEMETRY_B:
            state[U_DC], state[ENCODER], state[STATUS] = u16(data, 2), u16(data, 4), u16(data, 6)
            return 0
        seq = unwrap16(u16(data, 0), state[LAST_SEQ])
        state[LAST_SEQ] = seq
        put_u32(raw, 2, seq)
        _copy(data, 2, raw, 6, 6 if offset == CAN_TELEMETRY_A else 4)
        if offset == CAN_COMMAND:
            raw[1], raw[10] = COMMAND, data[6]
            return 11
        raw[1] = TELEMETRY
        put_u16(raw, 12, state[U_DC])
        put_u16(raw, 14, state[ENCODER])
        put_u16(raw, 16, state[STATUS])
        return 18
    if offset == CAN_TELEMETRY_BLOCK or offset == CAN_COMMAND_BLOCK:
        telemetry = offset == CAN_TELEMETRY_BLOCK
        head = TELEMETRY_BLOCK_HEAD if telemetry else COMMAND_BLOCK_HEAD
        entry = TELEMETRY_BLOCK_ENTRY if telemetry else COMMAND_BLOCK_ENTRY
        most = TELEMETRY_CHUNK if telemetry else COMMAND_CHUNK
        count = np.int64(data[head - 1]) if n >= head else 0
        length = head + count * entry
        if not 1 <= count <= most or n < length:
            return -FRAME_FRAMING
        raw[1] = TELEMETRY_BLOCK if telemetry else COMMAND_BLOCK
        _copy(data, 0, raw, 2, length)
        return 2 + length
    if offset == CAN_CONTROL or offset == CAN_HEARTBEAT:
        size = 1 if offset == CAN_CONTROL else 4
        if n != size:
            return -FRAME_FRAMING
        raw[1] = CONTROL if offset == CAN_CONTROL else HEARTBEAT
        _copy(data, 0, raw, 2, size)
        return 2 + size
    if offset == CAN_HELLO_A or offset == CAN_HELLO_B or offset == CAN_HELLO_C:
        if n != 8:
            return -FRAME_FRAMING
        if offset == CAN_HELLO_A:
            hello[0] = data[0]
            _copy(data, 1, hello, 2, 3)
            _copy(data, 4, hello, 6, 4)
        elif offset == CAN_HELLO_B:
            _copy(data, 0, hello, 10, 8)
        else:
            _copy(data, 0, hello, 18, 6)
            hello[5] = data[6]
        state[HELLO_PARTS] |= 1 << (offset - CAN_HELLO_A)
        if state[HELLO_PARTS] != 7:
            return 0
        state[HELLO_PARTS] = 0
        if hello[0] != VERSION:
            return -FRAME_VERSION
        _copy(hello, 2, raw, 2, HELLO_BYTES - 2)
        raw[1] = HELLO
        return HELLO_BYTES
    return -FRAME_UNKNOWN_TYPE


@njit(cache=True, nogil=True)
def canfd_length(n):
    """The CAN FD data length that holds ``n`` bytes (the next of 0-8, 12, 16, 20, 24, 32, 48, 64)."""
    for length in CANFD_LENGTHS:
        if length >= n:
            return length
    return -1


@njit(cache=True, nogil=True)
def frames_of_payload(raw, m, base, with_status, ids, lengths, data):
    """The CAN frames of the serial payload ``raw[:m]`` (version, type, body) of a drive whose base identifier
    is ``base``: frame i's identifier ``ids[i]``, data length ``lengths[i]``, data ``data[i]`` (MAX_FRAMES × 64);
    their number (−1 for a message CAN does not carry). TELEMETRY: B (if ``with_status``), then A, which
    completes the sample; HELLO: A, B, C; a block: CAN FD frames of at most 6 telemetry or 14 command samples,
    each the block message of its own samples (the serial body: no version, type or CRC), zero-padded to a
    CAN FD length. Classic frames carry seq's low 16 bits."""
    kind = raw[1]
    if kind == TELEMETRY_BLOCK or kind == COMMAND_BLOCK:
        telemetry = kind == TELEMETRY_BLOCK
        head = TELEMETRY_BLOCK_HEAD if telemetry else COMMAND_BLOCK_HEAD
        entry = TELEMETRY_BLOCK_ENTRY if telemetry else COMMAND_BLOCK_ENTRY
        chunk = TELEMETRY_CHUNK if telemetry else COMMAND_CHUNK
        identifier = base + (CAN_TELEMETRY_BLOCK if telemetry else CAN_COMMAND_BLOCK)
        seq, count = u32(raw, 2), np.int64(raw[2 + head - 1])
        frames = 0
        for start in range(0, count, chunk):
            part = min(chunk, count - start)
            size = head + part * entry
            length = canfd_length(size)
            frame = data[frames]
            _copy(raw, 2, frame, 0, head)
            put_u32(frame, 0, (seq + start) % 0x100000000)
            frame[head - 1] = part
            _copy(raw, 2 + head + start * entry, frame, head, part * entry)
            for i in range(size, length):
                frame[i] = 0
            ids[frames], lengths[frames] = identifier, length
            frames += 1
        return frames
    if kind == TELEMETRY:
        frames = 0
        if with_status:
            frame = data[0]
            put_u16(frame, 0, u16(raw, 2))
            _copy(raw, 12, frame, 2, 6)
            ids[0], lengths[0] = base + CAN_TELEMETRY_B, 8
            frames = 1
        frame = data[frames]
        put_u16(frame, 0, u16(raw, 2))
        _copy(raw, 6, frame, 2, 6)
        ids[frames], lengths[frames] = base + CAN_TELEMETRY_A, 8
        return frames + 1
    if kind == COMMAND:
        frame = data[0]
        put_u16(frame, 0, u16(raw, 2))
        _copy(raw, 6, frame, 2, 5)
        frame[7] = 0
        ids[0], lengths[0] = base + CAN_COMMAND, 8
        return 1
    if kind == CONTROL or kind == HEARTBEAT:
        size = 1 if kind == CONTROL else 4
        _copy(raw, 2, data[0], 0, size)
        ids[0], lengths[0] = base + (CAN_CONTROL if kind == CONTROL else CAN_HEARTBEAT), size
        return 1
    if kind == HELLO:
        a, b, c = data[0], data[1], data[2]
        a[0] = VERSION
        _copy(raw, 2, a, 1, 3)
        _copy(raw, 6, a, 4, 4)
        _copy(raw, 10, b, 0, 8)
        _copy(raw, 18, c, 0, 6)
        c[6], c[7] = raw[5], 0
        for i in range(3):
            ids[i], lengths[i] = base + CAN_HELLO_A + i, 8
        return 3
    return -1
