"""The serial framing of the inverter protocol as numba kernels on byte arrays (docs/inverter-protocol.md,
"Serial framing"): CRC-16/CCITT-FALSE, COBS, a received frame's checks, the TELEMETRY and TELEMETRY_BLOCK
bodies read and the COMMAND, COMMAND_BLOCK and CONTROL frames written. One algorithm: the Python codec
(inverter_protocol) calls these kernels, and so does the compiled answer (drive_tools.runner.compiled_answer),
without the interpreter's lock. No allocation in the kernels."""
import numpy as np
from numba import njit

VERSION = 2
MAX_BLOCK = 30
MAX_FRAME = 253
TELEMETRY, HELLO, TELEMETRY_BLOCK = 0x01, 0x02, 0x03
COMMAND, CONTROL, HEARTBEAT, COMMAND_BLOCK = 0x10, 0x11, 0x12, 0x13
BODY_BYTES = {TELEMETRY: 16, HELLO: 22, COMMAND: 9, CONTROL: 1, HEARTBEAT: 4}
"""Body size of each fixed-size message [bytes]; the blocks' are their head and count entries."""
TELEMETRY_BLOCK_HEAD, TELEMETRY_BLOCK_ENTRY = 9, 8
COMMAND_BLOCK_HEAD, COMMAND_BLOCK_ENTRY = 6, 4
FRAME_OK, FRAME_FRAMING, FRAME_CRC, FRAME_VERSION, FRAME_UNKNOWN_TYPE = 0, 1, 2, 3, 4
FRAME_ERROR_KINDS = ("", "framing", "crc", "version", "unknown_type")
"""What ``check_frame`` returns, and the counter each error goes to."""
WIRE_BYTES = MAX_FRAME + MAX_FRAME // 254 + 2
"""Most bytes one frame takes on the wire: COBS's code bytes and the delimiter."""


@njit(cache=True, nogil=True)
def crc16(data, n):
    """CRC-16/CCITT-FALSE of ``data[:n]`` (uint8): polynomial 0x1021, initial 0xFFFF, no reflection, no final
    XOR."""
    crc = 0xFFFF
    for i in range(n):
        crc ^= np.int64(data[i]) << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) if crc & 0x8000 else crc << 1
            crc &= 0xFFFF
    return crc


@njit(cache=True, nogil=True)
def cobs_encode(data, n, out):
    """COBS of ``data[:n]`` into ``out`` (no 0x00 in it, no delimiter); the bytes written."""
    code_at, m, run = 0, 1, 1
    for i in range(n):
        byte = data[i]
        if byte == 0:
            out[code_at] = run
            code_at, m, run = m, m + 1, 1
        else:
            out[m] = byte
            m += 1
            run += 1
            if run == 255:
                out[code_at] = 255
                code_at, m, run = m, m + 1, 1
    out[code_at] = run
    return m


@njit(cache=True, nogil=True)
def cobs_decode(data, n, out, where):
    """Inverse of cobs_encode from ``data[:n]`` into ``out``: the bytes written, or −1 for a block overrunning
    the frame (``where``: its code and position) and −2 for a 0x00 inside one."""
    i, m = 0, 0
    while i < n:
        code = np.int64(data[i])
        if code == 0 or i + code > n:
            where[0], where[1] = code, i
            return -1
        for j in range(i + 1, i + code):
            if data[j] == 0:
                return -2
            out[m] = data[j]
            m += 1
        i += code
        if code < 255 and i < n:
            out[m] = 0
            m += 1
    return m


@njit(cache=True, nogil=True)
def u16(data, at):
    """The u16 at byte ``at`` (little-endian)."""
    return np.int64(data[at]) | np.int64(data[at + 1]) << 8


@njit(cache=True, nogil=True)
def i16(data, at):
    """The i16 at byte ``at`` (little-endian, two's complement)."""
    value = u16(data, at)
    return value - 65536 if value >= 32768 else value


@njit(cache=True, nogil=True)
def u32(data, at):
    """The u32 at byte ``at`` (little-endian)."""
    return u16(data, at) | u16(data, at + 2) << 16


@njit(cache=True, nogil=True)
def put_u16(data, at, value):
    """``value``'s low 16 bits at byte ``at`` (little-endian)."""
    data[at], data[at + 1] = value & 0xFF, (value >> 8) & 0xFF


@njit(cache=True, nogil=True)
def put_u32(data, at, value):
    """``value``'s low 32 bits at byte ``at`` (little-endian)."""
    put_u16(data, at, value & 0xFFFF)
    put_u16(data, at + 2, (value >> 16) & 0xFFFF)


@njit(cache=True, nogil=True)
def check_frame(raw, m):
    """The checks of a COBS-decoded frame ``raw[:m]`` (version, type, body, CRC16 LE) in the protocol's
    order: length, CRC, version, type, a block's length against its count; FRAME_OK or the failed check."""
    if m < 4 or m > MAX_FRAME:
        return FRAME_FRAMING
    if crc16(raw, m - 2) != u16(raw, m - 2):
        return FRAME_CRC
    if raw[0] != VERSION:
        return FRAME_VERSION
    kind, body = raw[1], m - 4
    if kind == TELEMETRY_BLOCK or kind == COMMAND_BLOCK:
        head, entry = ((TELEMETRY_BLOCK_HEAD, TELEMETRY_BLOCK_ENTRY) if kind == TELEMETRY_BLOCK
                       else (COMMAND_BLOCK_HEAD, COMMAND_BLOCK_ENTRY))
        if body < head:
            return FRAME_FRAMING
        count = np.int64(raw[2 + head - 1])
        return FRAME_OK if 1 <= count <= MAX_BLOCK and body == head + count * entry else FRAME_FRAMING
    if kind == TELEMETRY:
        return FRAME_OK if body == 16 else FRAME_FRAMING
    if kind == HELLO:
        return FRAME_OK if body == 22 else FRAME_FRAMING
    if kind == COMMAND:
        return FRAME_OK if body == 9 else FRAME_FRAMING
    if kind == CONTROL:
        return FRAME_OK if body == 1 else FRAME_FRAMING
    if kind == HEARTBEAT:
        return FRAME_OK if body == 4 else FRAME_FRAMING
    return FRAME_UNKNOWN_TYPE


@njit(cache=True, nogil=True)
def read_telemetry(raw, entries):
    """A checked TELEMETRY or TELEMETRY_BLOCK frame ``raw`` (version, type, body): its samples' (i_a, i_b, i_c,
    encoder) counts into ``entries`` (n × 4, int64) and (seq, u_dc, status, n)."""
    if raw[1] == TELEMETRY:
        for j in range(3):
            entries[0, j] = i16(raw, 6 + 2 * j)
        entries[0, 3] = u16(raw, 14)
        return u32(raw, 2), u16(raw, 12), u16(raw, 16), 1
    n = np.int64(raw[10])
    for i in range(n):
        at = 11 + TELEMETRY_BLOCK_ENTRY * i
        for j in range(3):
            entries[i, j] = i16(raw, at + 2 * j)
        entries[i, 3] = u16(raw, at + 6)
    return u32(raw, 2), u16(raw, 6), u16(raw, 8), n


@njit(cache=True, nogil=True)
def write_telemetry(seq, u_dc, status, entries, n, block, raw):
    """The payload (version, type, body) of TELEMETRY (``block`` false; n = 1) or TELEMETRY_BLOCK of ``n``
    samples (``entries``: n × 4 counts i_a, i_b, i_c, encoder) into ``raw``; its length."""
    raw[0] = VERSION
    if not block:
        raw[1] = TELEMETRY
        put_u32(raw, 2, seq)
        for j in range(3):
            put_u16(raw, 6 + 2 * j, entries[0, j])
        put_u16(raw, 12, u_dc)
        put_u16(raw, 14, entries[0, 3])
        put_u16(raw, 16, status)
        return 18
    raw[1] = TELEMETRY_BLOCK
    put_u32(raw, 2, seq)
    put_u16(raw, 6, u_dc)
    put_u16(raw, 8, status)
    raw[10] = n
    for i in range(n):
        at = 11 + TELEMETRY_BLOCK_ENTRY * i
        for j in range(3):
            put_u16(raw, at + 2 * j, entries[i, j])
        put_u16(raw, at + 6, entries[i, 3])
    return 11 + TELEMETRY_BLOCK_ENTRY * n


@njit(cache=True, nogil=True)
def write_command(seq, flags, counts, n, block, raw):
    """The payload of COMMAND (``block`` false; n = 1) or COMMAND_BLOCK of ``n`` samples (``counts``: n × 2,
    u_α and u_β in voltage steps) into ``raw``; its length."""
    raw[0] = VERSION
    put_u32(raw, 2, seq)
    if not block:
        raw[1] = COMMAND
        put_u16(raw, 6, counts[0, 0])
        put_u16(raw, 8, counts[0, 1])
        raw[10] = flags
        return 11
    raw[1] = COMMAND_BLOCK
    raw[6], raw[7] = flags, n
    for i in range(n):
        put_u16(raw, 8 + COMMAND_BLOCK_ENTRY * i, counts[i, 0])
        put_u16(raw, 10 + COMMAND_BLOCK_ENTRY * i, counts[i, 1])
    return 8 + COMMAND_BLOCK_ENTRY * n


@njit(cache=True, nogil=True)
def write_control(action, raw):
    """The payload of CONTROL(``action``) into ``raw``; its length."""
    raw[0], raw[1], raw[2] = VERSION, CONTROL, action
    return 3


@njit(cache=True, nogil=True)
def frame_wire(raw, m, wire):
    """The serial wire bytes of the payload ``raw[:m]``: COBS(payload, CRC16 LE) + 0x00 into ``wire`` (``raw``
    needs two bytes beyond m for the CRC); their length."""
    put_u16(raw, m, crc16(raw, m))
    length = cobs_encode(raw, m + 2, wire)
    wire[length] = 0
    return length + 1


@njit(cache=True, nogil=True)
def message_wire(kind, head, entries, n, wire):
    """The serial wire bytes of a TELEMETRY, TELEMETRY_BLOCK, COMMAND, COMMAND_BLOCK or CONTROL into ``wire``
    in one call: ``head`` (int64) its seq and (telemetry) u_dc and status, (commands) flags, (CONTROL) the
    action first; ``entries`` (n × 4 or n × 2, int64) its samples. Their length, or −1 for a field out of
    its integer type's range."""
    width = 4 if kind == TELEMETRY or kind == TELEMETRY_BLOCK else 2
    for i in range(n if kind != CONTROL else 0):
        for j in range(width):
            low, high = (0, 65535) if j == 3 else (-32768, 32767)
            if not low <= entries[i, j] <= high:
                return -1
    raw = np.empty(MAX_FRAME + 2, dtype=np.uint8)
    if kind == CONTROL:
        m = write_control(head[0], raw)
    elif width == 4:
        m = write_telemetry(head[0], head[1], head[2], entries, n, kind == TELEMETRY_BLOCK, raw)
    else:
        m = write_command(head[0], head[1], entries, n, kind == COMMAND_BLOCK, raw)
    return frame_wire(raw, m, wire)


@njit(cache=True, nogil=True)
def read_frame(data, n, raw, entries, where):
    """The bytes between two delimiters ``data[:n]`` COBS-decoded into ``raw`` and checked in one call:
    (the payload's length or cobs_decode's −1/−2, check_frame's verdict, and for a telemetry frame its seq,
    u_dc, status and sample count, the counts in ``entries``; zeros otherwise)."""
    m = cobs_decode(data, n, raw, where)
    if m < 0:
        return m, FRAME_FRAMING, 0, 0, 0, 0
    check = check_frame(raw, m)
    if check != FRAME_OK or (raw[1] != TELEMETRY and raw[1] != TELEMETRY_BLOCK):
        return m, check, 0, 0, 0, 0
    seq, u_dc, status, count = read_telemetry(raw, entries)
    return m, check, seq, u_dc, status, count
