"""Inverter wire protocol, version 2 (docs/inverter-protocol.md): messages (per sample, and blocks of
samples), the serial framing (COBS + CRC-16/CCITT-FALSE, 0x00-delimited), the classic-CAN mapping and
blocks on CAN FD. No I/O; the serial framing and the telemetry and command bodies are frame_codec's kernels."""
import struct
from dataclasses import dataclass

import numpy as np

from . import can_codec, frame_codec

VERSION = frame_codec.VERSION
MAX_BLOCK = frame_codec.MAX_BLOCK
"""Most samples in one TELEMETRY_BLOCK or COMMAND_BLOCK (the largest frame then fits one COBS run)."""
MAX_FRAME = frame_codec.MAX_FRAME
"""Largest decoded frame (version, type, body, CRC) a receiver accepts [bytes]: a TELEMETRY_BLOCK of
MAX_BLOCK samples."""

TELEMETRY, HELLO, TELEMETRY_BLOCK = frame_codec.TELEMETRY, frame_codec.HELLO, frame_codec.TELEMETRY_BLOCK
COMMAND, CONTROL, HEARTBEAT, COMMAND_BLOCK = (frame_codec.COMMAND, frame_codec.CONTROL, frame_codec.HEARTBEAT,
                                              frame_codec.COMMAND_BLOCK)
CONTROL_DISABLE, CONTROL_CLEAR_FAULTS, CONTROL_SEND_HELLO = 1, 2, 3
ENABLE = 0x01
SAFE_STATE_SHIFT, SAFE_STATE_MASK = 1, 0x06
"""COMMAND and COMMAND_BLOCK flags bits 1-2: the safe state the host asks for whenever the bridge stops
switching (SAFE_AUTO: the inverter's own choice; drive_common.math.safe_state's FREEWHEEL 1, ASC 2)."""
SAFE_AUTO = 0
HELLO_ENCODER_PRESENT = 0x01
HELLO_SAFE_STATES = 0x02
HELLO_INDEX_INPUT = 0x04
"""HELLO flags bit 2: the inverter has an index input (status INDEX_TOGGLE)."""
"""The inverter takes the safe state of the flags and reports OVERVOLTAGE, FREEWHEELING, SHORT_CIRCUIT."""

OVERCURRENT, WATCHDOG, PWM_OFF, COMMAND_MISSING = 1 << 0, 1 << 1, 1 << 2, 1 << 3
HEARTBEAT_LOST, BAD_FRAME, UNDERVOLTAGE, ENCODER_VALID = 1 << 4, 1 << 5, 1 << 6, 1 << 7
OVERVOLTAGE, FREEWHEELING, SHORT_CIRCUIT = 1 << 8, 1 << 9, 1 << 10
INDEX_TOGGLE = 1 << 11
"""Toggles at each pulse of the inverter's index input (once per turn; a block's: as at its last sample)."""
CLEARED_BY_HOST = WATCHDOG | HEARTBEAT_LOST
"""Latched faults a link loss or a silent host causes; the host clears them when the link is back,
never an overcurrent or an over-voltage."""
STATUS_NAMES = {OVERCURRENT: "overcurrent", WATCHDOG: "watchdog", PWM_OFF: "pwm_off",
                COMMAND_MISSING: "command_missing", HEARTBEAT_LOST: "heartbeat_lost", BAD_FRAME: "bad_frame",
                UNDERVOLTAGE: "undervoltage", ENCODER_VALID: "encoder_valid", OVERVOLTAGE: "overvoltage",
                FREEWHEELING: "freewheeling", SHORT_CIRCUIT: "short_circuit", INDEX_TOGGLE: "index_toggle"}


def command_flags(enable, safe_state=SAFE_AUTO):
    """The flags byte of a COMMAND or COMMAND_BLOCK: ENABLE and the safe state asked for (SAFE_AUTO, FREEWHEEL,
    ASC)."""
    return (ENABLE if enable else 0) | (safe_state << SAFE_STATE_SHIFT) & SAFE_STATE_MASK


def requested_safe_state(flags):
    """The safe state a command's flags ask for (SAFE_AUTO, FREEWHEEL, ASC); the reserved value 3 reads as
    SAFE_AUTO."""
    state = (flags & SAFE_STATE_MASK) >> SAFE_STATE_SHIFT
    return state if state in (1, 2) else SAFE_AUTO


@dataclass(frozen=True)
class Telemetry:
    seq: int
    i_a: int
    i_b: int
    i_c: int
    u_dc: int
    encoder: int
    status: int


@dataclass(frozen=True)
class TelemetryBlock:
    """Samples seq … seq + n − 1: ``samples`` holds (i_a, i_b, i_c, encoder) of each; u_dc and status
    as at the block's last sample."""

    seq: int
    u_dc: int
    status: int
    samples: tuple


@dataclass(frozen=True)
class Hello:
    drive_id: int
    flags: int
    n_p: int
    block_samples: int
    """N: samples per TELEMETRY_BLOCK (1: TELEMETRY per sample)."""
    T_s_ns: int
    current_lsb_A: float
    voltage_lsb_V: float
    trip_current_A: float
    watchdog_periods: int


@dataclass(frozen=True)
class Command:
    seq: int
    u_alpha: int
    u_beta: int
    flags: int


@dataclass(frozen=True)
class CommandBlock:
    """Commands answering samples seq … seq + n − 1: ``samples`` holds (u_α, u_β) of each."""

    seq: int
    flags: int
    samples: tuple


@dataclass(frozen=True)
class Control:
    action: int


@dataclass(frozen=True)
class Heartbeat:
    counter: int


LAYOUTS = {TELEMETRY: (Telemetry, struct.Struct("<IhhhHHH")), HELLO: (Hello, struct.Struct("<BBBBIfffH")),
           COMMAND: (Command, struct.Struct("<IhhB")), CONTROL: (Control, struct.Struct("<B")),
           HEARTBEAT: (Heartbeat, struct.Struct("<I"))}
BLOCK_LAYOUTS = {TELEMETRY_BLOCK: (TelemetryBlock, struct.Struct("<IHHB"), struct.Struct("<hhhH")),
                 COMMAND_BLOCK: (CommandBlock, struct.Struct("<IBB"), struct.Struct("<hh"))}
"""Block messages: the head (the sample count last), then one entry per sample."""
TYPE_OF = {cls: kind for kind, (cls, *_) in {**LAYOUTS, **BLOCK_LAYOUTS}.items()}


class FrameError(ValueError):
    """A received frame is unusable; ``kind`` names the counter it goes to."""

    def __init__(self, kind, message):
        super().__init__(message)
        self.kind = kind


def crc16(data):
    """CRC-16/CCITT-FALSE: polynomial 0x1021, initial 0xFFFF, no reflection, no final XOR
    (frame_codec.crc16)."""
    data = _bytes_array(data)
    return int(frame_codec.crc16(data, len(data)))


def _bytes_array(data):
    return np.frombuffer(bytes(data), dtype=np.uint8)


def cobs_encode(data):
    """COBS: the bytes without any 0x00 (the frame delimiter is not included; frame_codec.cobs_encode)."""
    data = _bytes_array(data)
    out = np.empty(len(data) + len(data) // 254 + 1, dtype=np.uint8)
    return out[:frame_codec.cobs_encode(data, len(data), out)].tobytes()


def cobs_decode(data):
    """Inverse of cobs_encode; FrameError('framing') for a malformed block (frame_codec.cobs_decode)."""
    data = _bytes_array(data)
    out, where = np.empty(len(data), dtype=np.uint8), np.zeros(2, dtype=np.int64)
    m = frame_codec.cobs_decode(data, len(data), out, where)
    if m == -1:
        raise FrameError("framing", f"COBS block of {where[0]} at byte {where[1]} overruns the frame")
    if m == -2:
        raise FrameError("framing", "0x00 inside a COBS frame")
    return out[:m].tobytes()


def pack(message):
    """version, type and body of a message (no CRC); ValueError for a block of 0 or over MAX_BLOCK samples.
    Telemetry, commands and CONTROL are written by the kernels the compiled answer uses (frame_codec)."""
    kind = TYPE_OF[type(message)]
    if kind in BLOCK_LAYOUTS and not 1 <= len(message.samples) <= MAX_BLOCK:
        raise ValueError(f"a block carries 1 to {MAX_BLOCK} samples, not {len(message.samples)}")
    raw = np.zeros(MAX_FRAME + 2, dtype=np.uint8)
    if kind in (TELEMETRY, TELEMETRY_BLOCK):
        block = kind == TELEMETRY_BLOCK
        entries = np.array(message.samples if block else [(message.i_a, message.i_b, message.i_c,
                                                            message.encoder)], dtype=np.int64)
        _check_ranges(entries[:, :3], -32768, 32767, entries[:, 3], 0, 65535)
        m = frame_codec.write_telemetry(message.seq, message.u_dc, message.status, entries, len(entries), block, raw)
    elif kind in (COMMAND, COMMAND_BLOCK):
        block = kind == COMMAND_BLOCK
        counts = np.array(message.samples if block else [(message.u_alpha, message.u_beta)], dtype=np.int64)
        _check_ranges(counts, -32768, 32767)
        m = frame_codec.write_command(message.seq, message.flags, counts, len(counts), block, raw)
    elif kind == CONTROL:
        m = frame_codec.write_control(message.action, raw)
    else:
        return bytes((VERSION, kind)) + LAYOUTS[kind][1].pack(*vars(message).values())
    return raw[:m].tobytes()


def _check_ranges(*arrays_and_bounds):
    """struct.error for a field out of its integer type's range (as struct.pack refuses it)."""
    for values, low, high in zip(*[iter(arrays_and_bounds)] * 3):
        if values.size and not (low <= values.min() and values.max() <= high):
            raise struct.error(f"a field out of {low} to {high}")


def encode_frame(message):
    """The serial wire bytes of one message: COBS(version, type, body, CRC16 LE) + 0x00 (frame_codec; the
    messages the compiled answer writes or reads in one kernel call, frame_codec.message_wire)."""
    kind = TYPE_OF[type(message)]
    wire = np.empty(frame_codec.WIRE_BYTES, dtype=np.uint8)
    if kind in (TELEMETRY, TELEMETRY_BLOCK, COMMAND, COMMAND_BLOCK, CONTROL):
        if kind == TELEMETRY:
            head, entries = (message.seq, message.u_dc, message.status), [(message.i_a, message.i_b, message.i_c,
                                                                           message.encoder)]
        elif kind == COMMAND:
            head, entries = (message.seq, message.flags), [(message.u_alpha, message.u_beta)]
        elif kind == CONTROL:
            head, entries = (message.action,), [(0, 0)]
        else:
            if not 1 <= len(message.samples) <= MAX_BLOCK:
                raise ValueError(f"a block carries 1 to {MAX_BLOCK} samples, not {len(message.samples)}")
            head = (message.seq, message.u_dc, message.status) if kind == TELEMETRY_BLOCK else (message.seq,
                                                                                                message.flags)
            entries = message.samples
        length = frame_codec.message_wire(kind, np.array(head, dtype=np.int64), np.array(entries, dtype=np.int64),
                                          len(entries), wire)
        if length < 0:
            raise struct.error(f"a field of {message!r} out of its integer type's range")
        return wire[:length].tobytes()
    payload = pack(message)
    raw = np.zeros(len(payload) + 2, dtype=np.uint8)
    raw[:len(payload)] = np.frombuffer(payload, dtype=np.uint8)
    return wire[:frame_codec.frame_wire(raw, len(payload), wire)].tobytes()


def decode_frame(encoded):
    """A message from the bytes between two delimiters; FrameError naming the check that failed
    (frame_codec.read_frame: COBS, the checks and a telemetry frame's fields in one kernel call)."""
    data = _bytes_array(encoded)
    raw, where = np.empty(max(len(data), 4), dtype=np.uint8), np.zeros(2, dtype=np.int64)
    entries = np.empty((MAX_BLOCK, 4), dtype=np.int64)
    m, check, seq, u_dc, status, count = frame_codec.read_frame(data, len(data), raw, entries, where)
    if m == -1:
        raise FrameError("framing", f"COBS block of {where[0]} at byte {where[1]} overruns the frame")
    if m == -2:
        raise FrameError("framing", "0x00 inside a COBS frame")
    if not 4 <= m <= MAX_FRAME:
        raise FrameError("framing", f"frame of {m} bytes (4 to {MAX_FRAME} allowed)")
    payload, (crc,) = raw[:m - 2].tobytes(), struct.unpack("<H", raw[m - 2:m].tobytes())
    if check == frame_codec.FRAME_CRC:
        raise FrameError("crc", f"CRC {crc:#06x}, computed {crc16(payload):#06x}")
    if check == frame_codec.FRAME_VERSION:
        raise FrameError("version", f"protocol version {payload[0]}, this host speaks {VERSION}")
    if check == frame_codec.FRAME_UNKNOWN_TYPE:
        raise FrameError("unknown_type", f"message type {payload[1]:#04x}")
    if check == frame_codec.FRAME_OK and payload[1] == TELEMETRY_BLOCK:
        return TelemetryBlock(seq, u_dc, status, tuple(map(tuple, entries[:count].tolist())))
    if check == frame_codec.FRAME_OK and payload[1] == TELEMETRY:
        i_a, i_b, i_c, encoder = entries[0].tolist()
        return Telemetry(seq, i_a, i_b, i_c, u_dc, encoder, status)
    return payload_message(payload)


def payload_message(payload):
    """The message of a serial payload (version, type, body) of a known type; FrameError for a body whose
    length is not its type's."""
    kind = payload[1]
    if kind == TELEMETRY and len(payload) == 2 + LAYOUTS[TELEMETRY][1].size:
        return _telemetry(np.frombuffer(payload, dtype=np.uint8), False)
    if kind in BLOCK_LAYOUTS:
        return _decode_block(payload)
    cls, body = LAYOUTS[kind]
    if len(payload) - 2 != body.size:
        raise FrameError("framing", f"{cls.__name__} body of {len(payload) - 2} bytes, expected {body.size}")
    return cls(*body.unpack(payload[2:]))


def _telemetry(data, block):
    """A checked TELEMETRY (``block`` false) or TELEMETRY_BLOCK frame's message (frame_codec.read_telemetry)."""
    entries = np.zeros((MAX_BLOCK, 4), dtype=np.int64)
    seq, u_dc, status, n = frame_codec.read_telemetry(data, entries)
    if block:
        return TelemetryBlock(seq, u_dc, status, tuple(map(tuple, entries[:n].tolist())))
    i_a, i_b, i_c, encoder = entries[0].tolist()
    return Telemetry(seq, i_a, i_b, i_c, u_dc, encoder, status)


def _decode_block(payload):
    """A TELEMETRY_BLOCK or COMMAND_BLOCK from its payload (version, type, body)."""
    cls, head, entry = BLOCK_LAYOUTS[payload[1]]
    if len(payload) - 2 < head.size:
        raise FrameError("framing", f"{cls.__name__} body of {len(payload) - 2} bytes, shorter than its head")
    *fields, count = head.unpack_from(payload, 2)
    if not 1 <= count <= MAX_BLOCK or len(payload) - 2 != head.size + count * entry.size:
        raise FrameError("framing", f"{cls.__name__} of {count} samples in a body of {len(payload) - 2} bytes")
    if payload[1] == TELEMETRY_BLOCK:
        return _telemetry(np.frombuffer(payload, dtype=np.uint8), True)
    return cls(*fields, tuple(entry.iter_unpack(payload[2 + head.size:])))


class FrameReader:
    """Splits a byte stream at 0x00 and decodes each frame; bad frames are counted by kind and dropped,
    the next delimiter resynchronises."""

    def __init__(self):
        self.buffer = bytearray()
        self.errors = {}
        self.last_error = ""

    def feed(self, data):
        """Messages completed by ``data``, in order."""
        messages = []
        self.buffer += data
        while True:
            end = self.buffer.find(0)
            if end < 0:
                if len(self.buffer) > 2 * MAX_FRAME:
                    self._count(FrameError("framing", f"{len(self.buffer)} bytes without a delimiter"))
                    self.buffer.clear()
                return messages
            frame = bytes(self.buffer[:end])
            del self.buffer[:end + 1]
            if not frame:
                continue
            try:
                messages.append(decode_frame(frame))
            except FrameError as error:
                self._count(error)

    def _count(self, error):
        self.errors[error.kind] = self.errors.get(error.kind, 0) + 1
        self.last_error = str(error)


def can_base(drive_id):
    if not 0 <= drive_id <= 15:
        raise ValueError(f"drive_id {drive_id}: CAN drives are numbered 0 to 15")
    return 0x100 + can_codec.IDS_PER_DRIVE * drive_id


def _can_frames(message, drive_id, with_status=True):
    """The (identifier, data) CAN frames of a message (can_codec.frames_of_payload)."""
    payload = pack(message)
    raw = np.zeros(MAX_FRAME + 2, dtype=np.uint8)
    raw[:len(payload)] = np.frombuffer(payload, dtype=np.uint8)
    ids, lengths = np.zeros(can_codec.MAX_FRAMES, dtype=np.int64), np.zeros(can_codec.MAX_FRAMES, dtype=np.int64)
    data = np.zeros((can_codec.MAX_FRAMES, 64), dtype=np.uint8)
    count = can_codec.frames_of_payload(raw, len(payload), can_base(drive_id), with_status, ids, lengths, data)
    return [(int(ids[i]), data[i, :lengths[i]].tobytes()) for i in range(count)]


def to_can(message, drive_id, with_status=True):
    """The (identifier, data) CAN frames of a message; TELEMETRY gives B (if ``with_status``), then A,
    which completes the sample."""
    if isinstance(message, (TelemetryBlock, CommandBlock)):
        raise TypeError(f"not a classic-CAN message: {message!r} (blocks travel as CAN FD frames: to_canfd)")
    return _can_frames(message, drive_id, with_status)


def to_canfd(message, drive_id):
    """The (identifier, data) CAN FD frames of a block message: chunks of at most 6 telemetry or 14
    command samples, each the block message of its own samples (the serial body: no version, type or
    CRC), zero-padded to a CAN FD length."""
    if not isinstance(message, (TelemetryBlock, CommandBlock)):
        raise TypeError(f"not a block: {message!r} (classic CAN frames: to_can)")
    return _can_frames(message, drive_id)


def unwrap16(low, last):
    """The u32 sequence number whose low 16 bits are ``low``, nearest to ``last``."""
    return int(can_codec.unwrap16(low, last))


class CanDecoder:
    """Messages from one drive's CAN frames (can_codec.payload_of_frame): TELEMETRY_A with the latest B,
    HELLO_A/B/C assembled, COMMAND/CONTROL/HEARTBEAT; 16-bit sequence numbers unwrapped against the last one;
    a CAN FD block frame as the block message of its samples."""

    def __init__(self, drive_id):
        self.base = can_base(drive_id)
        self.state, self.hello = can_codec.can_decoder()
        self.raw = np.zeros(MAX_FRAME + 2, dtype=np.uint8)
        self.errors = {}
        self.last_error = ""

    @property
    def last_seq(self):
        return int(self.state[can_codec.LAST_SEQ])

    def feed(self, identifier, data):
        """The message a frame completes, or None."""
        frame = np.frombuffer(bytes(data), dtype=np.uint8)
        m = can_codec.payload_of_frame(identifier - self.base, frame, len(frame), self.state, self.hello, self.raw)
        if m < 0:
            kind = frame_codec.FRAME_ERROR_KINDS[-m]
            self.errors[kind] = self.errors.get(kind, 0) + 1
            what = {"framing": f"{len(frame)} data bytes are no protocol frame there",
                    "version": f"protocol version {self.hello[0]}, this host speaks {VERSION}",
                    "unknown_type": f"identifier offset {identifier - self.base:#04x} is not a protocol frame"}
            self.last_error = f"CAN {identifier:#05x}: {what[kind]}"
            return None
        if m == 0:
            return None
        return payload_message(self.raw[:m].tobytes())
