"""The host bridge's per-frame work on a serial link or a CAN bus as numba kernels without the interpreter's
lock, for an answer compiled whole (drive_tools.runner.compiled_answer): bytes read from the link's
descriptor, split at 0x00 and checked (frame_codec), or one CAN frame read from a socket (drive_bridge.can_cable's
datagram, or SocketCAN's can_frame / canfd_frame) and mapped to its payload (can_codec), HELLO taken, telemetry
accepted as InverterBridge accepts it (sequence unwrapped, gaps, repeats and late frames counted, currents and
the encoder's angle in SI units), commands encoded and written with the latches a link loss causes cleared once,
the link's and the graph's silence timed. The state lives in arrays (``BridgeArrays``) that InverterBridge loads
and takes back (``load_bridge``, ``store_bridge``), so that reconnecting, HELLO's requests and the reports stay in
Python."""
import math
from typing import NamedTuple

import numpy as np
from numba import njit

from . import can_codec as cc
from . import frame_codec as fc
from .compiled_io import ieee_remainder as remainder
from .compiled_io import io_scratch, monotonic_s, read_into, wait_readable, write_all
from .inverter_protocol import (
    CLEARED_BY_HOST,
    CONTROL_CLEAR_FAULTS,
    CONTROL_DISABLE,
    ENCODER_VALID,
    HELLO,
    LAYOUTS,
    OVERCURRENT,
    OVERVOLTAGE,
    TELEMETRY,
    TELEMETRY_BLOCK,
    Hello,
)

COUNTERS = ("samples", "dropped", "duplicated", "reordered", "link_lost", "bus_off", "reconnects", "safe_state",
            "faults_cleared", "before_hello", "commands", "command_errors", "inverter_faults", "block_mismatch")
"""InverterBridge.counters in their order; then the frame errors of frame_codec.FRAME_ERROR_KINDS."""
C = {name: i for i, name in enumerate(COUNTERS)}
SAMPLES, DROPPED, DUPLICATED, REORDERED, LINK_LOST = (C[k] for k in COUNTERS[:5])
SAFE_STATE, FAULTS_CLEARED, BEFORE_HELLO, COMMANDS, COMMAND_ERRORS, INVERTER_FAULTS, BLOCK_MISMATCH = (
    C[k] for k in ("safe_state", "faults_cleared", "before_hello", "commands", "command_errors", "inverter_faults",
                   "block_mismatch"))
FRAME_ERRORS = len(COUNTERS)
"""counters[FRAME_ERRORS + kind]: frames failing frame_codec's check ``kind`` (1-4)."""

STATE = ("fd", "last_seq", "k_offset", "status", "theta_m", "last_telemetry_at", "last_command_at", "lost", "safe",
         "clear_sent", "hello", "current_lsb_A", "voltage_lsb_V", "block_samples", "link_timeout_s",
         "command_timeout_s", "rx_bytes", "link_kind", "can_base", "peer_lost", "answer_wait_s")
S = {name: i for i, name in enumerate(STATE)}
"""state[S[name]]: InverterBridge's attribute of that name (NaN for its None; hello: 1 taken, 0 none), the
link's descriptor, the bytes waiting in ``rx`` for their delimiter (serial) or the CAN frame read (CAN), the
link's kind (SERIAL, CABLE, SOCKETCAN), the drive's base CAN identifier and, on a cable, whether its other
member is missing (0: connected; PEER_GONE, PEER_NONE)."""
FD, LAST_SEQ, K_OFFSET, STATUS, THETA_M, LAST_TELEMETRY_AT, LAST_COMMAND_AT, LOST, SAFE, CLEAR_SENT = range(10)
HAS_HELLO, CURRENT_LSB, VOLTAGE_LSB, BLOCK_SAMPLES, LINK_TIMEOUT, COMMAND_TIMEOUT, RX_BYTES = range(10, 17)
LINK_KIND, CAN_BASE, PEER_LOST, ANSWER_WAIT = range(17, 21)
SERIAL, CABLE, SOCKETCAN = 0, 1, 2
"""The link's kind: a serial port (COBS frames in a byte stream); drive_bridge.can_cable's datagrams (a 5-byte
header: identifier u32 LE, flags; then the data); a SocketCAN raw socket (struct can_frame, 16 bytes, or struct
canfd_frame, 72: identifier u32 in host order, length, flags, a reserved byte, the length again (classic
frames: len8_dlc), then the data; as python-can's SocketCAN bus writes them)."""
PEER_GONE, PEER_NONE = 1.0, 2.0
"""PEER_LOST: a frame found no member (Python looks for one at once); Python found none (it looks again when
the link is quiet for a poll, or at the next frame written)."""
CAN_FRAME_BYTES, CANFD_FRAME_BYTES = 16, 72
CAN_EFF_FLAG, CAN_RTR_FLAG, CAN_ERR_FLAG = 0x80000000, 0x40000000, 0x20000000
CAN_EFF_MASK, CAN_SFF_MASK = 0x1FFFFFFF, 0x7FF
CANFD_BRS, CANFD_FDF = 0x01, 0x04
CABLE_FD_BRS = 6
"""A cable datagram's flags of a CAN FD frame with bit-rate switch (drive_bridge.can_cable's FD | BRS; not
imported: that module brings python-can with it)."""
READ_BYTES = 4096
"""One read(2) at most, as SerialLink reads."""
LINK_DOWN = -1
ASK_HELLO = -2
"""accept_telemetry's answer to a hundredth sample before HELLO: not taken, and HELLO is to be asked for."""


class TelemetryArrays(NamedTuple):
    """What accept_telemetry reads and changes of a bridge: ``state`` (STATE), ``counters`` (COUNTERS then the
    frame errors), a frame's ``entries`` (counts: i_a, i_b, i_c, encoder per sample) and a timespec scratch.
    InverterBridge keeps its own state in these arrays; BridgeArrays holds the same ones."""

    state: np.ndarray
    counters: np.ndarray
    entries: np.ndarray
    timespec: np.ndarray


def bridge_state(block_samples, link_timeout_s, command_timeout_s, answer_wait_s=0.0):
    """(state, counters) of a bridge that has heard nothing: no sequence, no time, the link lost."""
    state = np.zeros(len(STATE))
    state[[LAST_SEQ, THETA_M, LAST_TELEMETRY_AT, LAST_COMMAND_AT]] = np.nan
    state[LOST] = 1.0
    state[BLOCK_SAMPLES], state[LINK_TIMEOUT], state[COMMAND_TIMEOUT] = block_samples, link_timeout_s, command_timeout_s
    state[ANSWER_WAIT] = answer_wait_s
    return state, np.zeros(FRAME_ERRORS + len(fc.FRAME_ERROR_KINDS), dtype=np.int64)


def telemetry_arrays(state, counters):
    """TelemetryArrays over a bridge's ``state`` and ``counters``, with their scratch, its kernel loaded."""
    arrays = TelemetryArrays(state, counters, np.zeros((fc.MAX_BLOCK, 4), dtype=np.int64), io_scratch()[1])
    scratch = TelemetryArrays(np.zeros_like(state), np.zeros_like(counters), arrays.entries, arrays.timespec)
    accept_telemetry(scratch, 0, 1, 0, 0, np.zeros((1, 3)), np.zeros(1))
    return arrays


class BridgeArrays(NamedTuple):
    """An InverterBridge on a serial link or a CAN bus as arrays: ``state`` (float64, STATE), ``counters`` (int64,
    COUNTERS then the frame errors), ``written`` (its ring of command writes), the bytes read and not yet
    framed or the CAN frame read (``rx``), a frame's payload and wire bytes, a block's entries and commands in
    steps, the last HELLO's payload (``hello``), the calls' scratch (pollfd, timespec), and on CAN the link's
    decoder (``can_state``, ``can_hello``: can_codec's, shared with CanLink's decoder) and the frames of a
    payload to write (``can_ids``, ``can_lengths``, ``can_data``)."""

    state: np.ndarray
    counters: np.ndarray
    written: np.ndarray
    rx: np.ndarray
    raw: np.ndarray
    wire: np.ndarray
    entries: np.ndarray
    steps: np.ndarray
    hello: np.ndarray
    pollfd: np.ndarray
    timespec: np.ndarray
    can_state: np.ndarray
    can_hello: np.ndarray
    can_ids: np.ndarray
    can_lengths: np.ndarray
    can_data: np.ndarray


def _value(x):
    return math.nan if x is None else float(x)


def link_kind(link):
    """(SERIAL, CABLE or SOCKETCAN, the descriptor the compiled answer reads and writes) of an open ``link``
    (SerialLink or CanLink); ValueError for a bus that has no socket (python-can's in-process virtual bus)."""
    if hasattr(link, "port"):
        return SERIAL, link.fd
    from .can_cable import CableBus
    bus = link.bus
    if isinstance(bus, CableBus):
        return CABLE, bus.fileno()
    if type(bus).__name__ == "SocketcanBus":
        return SOCKETCAN, bus.socket.fileno()
    raise ValueError(f"the compiled answer reads and writes a CAN bus through its socket: {bus.channel_info} "
                     f"has none (SocketCAN, or the cable between processes: interface 'cable')")


def load_bridge(bridge):
    """BridgeArrays holding ``bridge`` (InverterBridge on an open SerialLink or CanLink) as it is now: its own
    state and counters arrays (shared: what the kernels change is the bridge's at once), the link's kind and
    descriptor, frame errors, bytes not yet framed (serial) or the decoder's state (CAN, shared); on a cable,
    connected to the bus's other member (PEER_LOST while there is none)."""
    state, counters = bridge.state, bridge.counter_array
    link = bridge.link
    for name in ("block_samples", "link_timeout_s", "command_timeout_s", "answer_wait_s"):
        state[S[name]] = _value(getattr(bridge, name))
    kind, fd = link_kind(link)
    state[FD], state[LINK_KIND] = fd, kind
    for error, count in link.errors.items():
        counters[FRAME_ERRORS + fc.FRAME_ERROR_KINDS.index(error)] = count
    rx = rx_buffer()
    state[RX_BYTES] = 0
    if kind == SERIAL:
        can_state, can_hello = cc.can_decoder()
        pending = bytes(link.reader.buffer)
        rx[:len(pending)] = np.frombuffer(pending, dtype=np.uint8)
        state[RX_BYTES] = len(pending)
    else:
        can_state, can_hello = link.decoder.state, link.decoder.hello
        state[CAN_BASE] = link.decoder.base
        state[PEER_LOST] = PEER_NONE if kind == CABLE and not link.bus.connect_peer() else 0.0
        state[FD] = link_kind(link)[1]
    return bridge_arrays(state, counters, bridge.written, rx, (can_state, can_hello))


def rx_buffer():
    """The bytes received and not yet framed: a read's worth and two frames."""
    return np.zeros(READ_BYTES + 2 * fc.MAX_FRAME + 1, dtype=np.uint8)


def copied_bridge(bridge):
    """BridgeArrays over copies of ``bridge``'s (InverterBridge) state, counters and ring of writes, nothing received
    and a fresh CAN decoder: the kernels loaded on them leave the bridge and its link untouched."""
    return bridge_arrays(bridge.state.copy(), bridge.counter_array.copy(), bridge.written.copy(), rx_buffer(),
                         cc.can_decoder())


def bridge_arrays(state, counters, written, rx, decoder):
    """BridgeArrays over a bridge's ``state``, ``counters``, ring of writes ``written``, bytes received ``rx`` and
    CAN ``decoder`` (can_codec's state and hello), with fresh buffers and scratch."""
    pollfd, timespec = io_scratch()
    return BridgeArrays(state, counters, written, rx, np.zeros(fc.MAX_FRAME + 2, dtype=np.uint8),
                        np.zeros(fc.WIRE_BYTES, dtype=np.uint8), np.zeros((fc.MAX_BLOCK, 4), dtype=np.int64),
                        np.zeros((fc.MAX_BLOCK, 2), dtype=np.int64), np.zeros(fc.BODY_BYTES[HELLO] + 2, dtype=np.uint8),
                        pollfd, timespec, *decoder, np.zeros(cc.MAX_FRAMES, dtype=np.int64),
                        np.zeros(cc.MAX_FRAMES, dtype=np.int64), np.zeros((cc.MAX_FRAMES, 64), dtype=np.uint8))


def store_bridge(arrays, bridge):
    """Give ``bridge`` back what the kernels changed in ``arrays`` beyond its state, counters and CAN decoder
    (shared): the HELLO taken, the frame errors and the bytes not yet framed."""
    state = arrays.state
    if state[HAS_HELLO] and arrays.hello.any():
        bridge.hello = Hello(*LAYOUTS[HELLO][1].unpack(arrays.hello[2:].tobytes()))
    elif not state[HAS_HELLO]:
        bridge.hello = None
    errors = bridge.link.errors
    for kind in range(1, len(fc.FRAME_ERROR_KINDS)):
        if arrays.counters[FRAME_ERRORS + kind]:
            errors[fc.FRAME_ERROR_KINDS[kind]] = int(arrays.counters[FRAME_ERRORS + kind])
    if state[LINK_KIND] == SERIAL:
        bridge.link.reader.buffer = bytearray(arrays.rx[:int(state[RX_BYTES])].tobytes())


@njit(cache=True, nogil=True)
def follows_part(part_k0, part_n, k0, N):
    """True when samples from ``k0`` continue the part of a block held (``part_n`` samples from ``part_k0``; 0:
    none) within its block of N: the one rule by which InverterBridge and the compiled answer put a block's
    CAN FD frames together."""
    return part_n > 0 and k0 == part_k0 + part_n and k0 // N == part_k0 // N


@njit(cache=True, nogil=True)
def send_payload(b, m):
    """The payload ``b.raw[:m]`` (version, type, body) written on the link: a serial frame, or its CAN frames
    (can_codec) as cable datagrams or SocketCAN frames. False when the link failed; on a cable a frame no member
    takes (none connected, the member gone, its queue full) is lost, as on a bus with no other node, and
    PEER_LOST set to PEER_GONE (Python looks for the member again)."""
    s = b.state
    fd, kind = int(s[FD]), s[LINK_KIND]
    if kind == SERIAL:
        return write_all(fd, b.wire, fc.frame_wire(b.raw, m, b.wire))
    frames = cc.frames_of_payload(b.raw, m, np.int64(s[CAN_BASE]), True, b.can_ids, b.can_lengths, b.can_data)
    block = b.raw[1] == fc.TELEMETRY_BLOCK or b.raw[1] == fc.COMMAND_BLOCK
    for i in range(frames):
        length = b.can_lengths[i]
        fc.put_u32(b.wire, 0, b.can_ids[i])
        if kind == CABLE:
            b.wire[4] = CABLE_FD_BRS if block else 0
            at, size = 5, 5 + length
        else:
            b.wire[4], b.wire[5], b.wire[6], b.wire[7] = length, CANFD_BRS | CANFD_FDF if block else 0, 0, length
            at, size = 8, CANFD_FRAME_BYTES if block else CAN_FRAME_BYTES
        for j in range(size - at):
            b.wire[at + j] = b.can_data[i, j] if j < length else 0
        if kind == CABLE and s[PEER_LOST] != 0.0:
            s[PEER_LOST] = PEER_GONE
        elif not write_all(fd, b.wire, size):
            if kind != CABLE:
                return False
            s[PEER_LOST] = PEER_GONE
    return True


@njit(cache=True, nogil=True)
def send_control(b, action):
    """CONTROL(``action``) on the link; False when the write failed."""
    return send_payload(b, fc.write_control(action, b.raw))


@njit(cache=True, nogil=True)
def take_hello(b, raw):
    """A checked HELLO: taken when it announces this drive's block size, else counted and named by its
    payload (kept in ``b.hello``) with no HELLO taken."""
    for i in range(b.hello.shape[0]):
        b.hello[i] = raw[i]
    if raw[5] != b.state[BLOCK_SAMPLES]:
        b.counters[BLOCK_MISMATCH] += 1
        b.state[HAS_HELLO] = 0.0
        return
    b.state[HAS_HELLO] = 1.0
    b.state[CURRENT_LSB], b.state[VOLTAGE_LSB] = f32(fc.u32(raw, 10)), f32(fc.u32(raw, 14))


@njit(cache=True, nogil=True)
def f32(bits):
    """The IEEE 754 binary32 value of ``bits`` (u32), exactly, as a float64."""
    sign = -1.0 if bits >> 31 else 1.0
    exponent, fraction = (bits >> 23) & 0xFF, bits & 0x7FFFFF
    if exponent == 0xFF:
        return sign * math.inf if fraction == 0 else math.nan
    if exponent == 0:
        return sign * math.ldexp(float(fraction), -149)
    return sign * math.ldexp(float(fraction | 0x800000), exponent - 150)


@njit(cache=True, nogil=True)
def accept_telemetry(b, seq, n, u_dc, status, currents, theta):
    """Samples seq … seq + n − 1 (their counts in ``b.entries``) taken by the bridge (the one algorithm of the
    Python bridge, InverterBridge._telemetry, and the compiled answer; ``b``: TelemetryArrays or
    BridgeArrays): their first k (unwrapped past 2³²), or −1 for samples before HELLO (ASK_HELLO at every
    hundredth: the caller asks for HELLO), a repeat or a late frame; every gap counted as dropped.
    ``currents`` (n × 3) [A], ``theta`` (n) [rad, mechanical; NaN without the encoder] receive them; the bus
    [V] is u_dc × voltage_lsb_V."""
    s, c = b.state, b.counters
    if s[HAS_HELLO] == 0.0:
        before = c[BEFORE_HELLO]
        c[BEFORE_HELLO] += n
        return ASK_HELLO if (before + n - 1) // 100 != (before - 1) // 100 else -1
    wrap = np.int64(1) << 32
    if not math.isnan(s[LAST_SEQ]):
        last = np.int64(s[LAST_SEQ])
        step = (seq - last) % wrap
        if step == 0:
            c[DUPLICATED] += 1
            return -1
        if step >= wrap // 2:
            c[REORDERED] += 1
            return -1
        c[DROPPED] += step - 1
        if seq < last:
            s[K_OFFSET] += wrap
    k0 = np.int64(s[K_OFFSET]) + seq
    if seq + n > wrap:
        s[K_OFFSET] += wrap
    s[LAST_SEQ] = (seq + n - 1) % wrap
    s[LAST_TELEMETRY_AT] = monotonic_s(b.timespec)
    if s[LOST] != 0.0:
        s[LOST] = 0.0
        s[LAST_COMMAND_AT] = np.nan
    new_faults = status & ~np.int64(s[STATUS]) & (OVERCURRENT | OVERVOLTAGE | CLEARED_BY_HOST)
    while new_faults:
        c[INVERTER_FAULTS] += new_faults & 1
        new_faults >>= 1
    s[STATUS] = status
    if not status & CLEARED_BY_HOST:
        s[CLEAR_SENT] = 0.0
    c[SAMPLES] += n
    lsb = s[CURRENT_LSB]
    previous = s[THETA_M]
    for i in range(n):
        for j in range(3):
            currents[i, j] = np.float64(b.entries[i, j]) * lsb
        if status & ENCODER_VALID:
            turn = np.float64(b.entries[i, 3]) * (2.0 * math.pi / 65536.0)
            previous = turn if math.isnan(previous) else previous + remainder(turn - previous, 2.0 * math.pi)
            theta[i] = previous
        else:
            theta[i] = np.nan
    s[THETA_M] = theta[n - 1]
    return k0


@njit(cache=True, nogil=True)
def next_frame(b, start):
    """The next complete frame in ``b.rx`` from byte ``start``: (the byte after its delimiter, the payload's
    length in ``b.raw`` or 0 for one dropped and counted); (−1, 0) when no delimiter follows. Bytes with no
    delimiter beyond two frames' worth are dropped as one framing error, as FrameReader drops them."""
    end_of_data = np.int64(b.state[RX_BYTES])
    for end in range(start, end_of_data):
        if b.rx[end] != 0:
            continue
        if end == start:
            return end + 1, 0
        m = fc.cobs_decode(b.rx[start:end], end - start, b.raw, b.steps[0])
        check = fc.FRAME_FRAMING if m < 0 else fc.check_frame(b.raw, m)
        if check != fc.FRAME_OK:
            b.counters[FRAME_ERRORS + check] += 1
            return end + 1, 0
        return end + 1, m
    return -1, 0


@njit(cache=True, nogil=True)
def keep_unframed(b, start):
    """Move the bytes from ``start`` that await their delimiter to the front of ``b.rx``."""
    left = np.int64(b.state[RX_BYTES]) - start
    for i in range(left):
        b.rx[i] = b.rx[start + i]
    if left > 2 * fc.MAX_FRAME:
        b.counters[FRAME_ERRORS + fc.FRAME_FRAMING] += 1
        left = 0
    b.state[RX_BYTES] = left


@njit(cache=True, nogil=True)
def read_link(b, timeout_ms):
    """Wait up to ``timeout_ms`` for the link: on a serial link append what one read(2) gives to ``b.rx``, on CAN
    read one frame into it (``b.rx`` holds only that frame then). The bytes read (0: none came), LINK_DOWN when
    the descriptor failed or the device is gone; on a cable the error a frame written to a member since gone
    leaves on the socket is read (cleared) and PEER_LOST set, as CableBus takes it."""
    fd, have, cable = int(b.state[FD]), np.int64(b.state[RX_BYTES]), b.state[LINK_KIND] == CABLE
    ready = wait_readable(b.pollfd, fd, timeout_ms)
    if ready < 0 and not cable:
        return LINK_DOWN
    if ready == 0:
        return 0
    if b.state[LINK_KIND] != SERIAL:
        have = 0
    got = read_into(fd, b.rx, have, READ_BYTES)
    if got <= 0 and cable:
        b.state[PEER_LOST] = PEER_GONE
        return 0
    if got <= 0:
        return LINK_DOWN
    b.state[RX_BYTES] = have + got
    return got


@njit(cache=True, nogil=True)
def next_payload(b, start):
    """The next payload in ``b.rx`` from byte ``start``, into ``b.raw``: (where the next one starts, its length
    or 0 for none: a frame dropped and counted, a CAN frame of another drive or one that completes no
    message); (−1, 0) when none is left. Serial: the next complete frame (next_frame). CAN: the frame read, once,
    mapped to its payload by the link's decoder (can_codec.payload_of_frame); error frames, remote requests and
    identifiers beyond the drive's 32 ignored, frames that are no protocol frame counted."""
    end = np.int64(b.state[RX_BYTES])
    if b.state[LINK_KIND] == SERIAL:
        return next_frame(b, start)
    if start >= end:
        return -1, 0
    if b.state[LINK_KIND] == CABLE:
        if end < 5:
            return end, 0
        identifier, at, n = fc.u32(b.rx, 0), 5, end - 5
    else:
        head = fc.u32(b.rx, 0)
        if end < CAN_FRAME_BYTES or head & (CAN_ERR_FLAG | CAN_RTR_FLAG):
            return end, 0
        identifier = head & (CAN_EFF_MASK if head & CAN_EFF_FLAG else CAN_SFF_MASK)
        at, n = 8, min(np.int64(b.rx[4]), end - 8)
    offset = identifier - np.int64(b.state[CAN_BASE])
    if not 0 <= offset < cc.IDS_PER_DRIVE:
        return end, 0
    m = cc.payload_of_frame(offset, b.rx[at:at + n], n, b.can_state, b.can_hello, b.raw)
    if m < 0:
        b.counters[FRAME_ERRORS - m] += 1
        return end, 0
    return end, m


@njit(cache=True, nogil=True)
def frame_telemetry(b, m):
    """(seq, n, u_dc, status) of a checked TELEMETRY or TELEMETRY_BLOCK payload ``b.raw[:m]``, its counts in
    ``b.entries``; a HELLO is taken (n = 0), any other message ignored (n = 0)."""
    kind = b.raw[1]
    if kind == HELLO:
        take_hello(b, b.raw)
        return 0, 0, 0, 0
    if kind != TELEMETRY and kind != TELEMETRY_BLOCK:
        return 0, 0, 0, 0
    if b.state[HAS_HELLO] == 0.0 and b.counters[BLOCK_MISMATCH] > 0:
        return 0, 0, 0, 0
    seq, u_dc, status, n = fc.read_telemetry(b.raw, b.entries)
    return seq, n, u_dc, status


@njit(cache=True, nogil=True)
def write_commands(b, k0, u_alpha_V, u_beta_V, n, enable, safe_state):
    """COMMAND (blocks of one) or COMMAND_BLOCK answering samples k0 … k0 + n − 1, rounded to the inverter's
    steps (clipped to int16, non-finite as 0) as InverterBridge.command_block rounds, with the flags of
    inverter_protocol.command_flags; before an enabling one the latches a link loss causes are cleared once.
    Noted in ``b.written`` when written; False when the link failed."""
    s, c = b.state, b.counters
    if s[HAS_HELLO] == 0.0:
        c[COMMAND_ERRORS] += 1
        return True
    lsb = s[VOLTAGE_LSB]
    for i in range(n):
        for j, u in enumerate((u_alpha_V[i], u_beta_V[i])):
            step = np.rint(u / lsb) if math.isfinite(u / lsb) else 0.0
            b.steps[i, j] = np.int64(min(32767.0, max(-32768.0, step)))
    flags = (1 if enable else 0) | (safe_state << 1) & 0x06
    status = np.int64(s[STATUS])
    if enable and status & CLEARED_BY_HOST and not status & (OVERCURRENT | OVERVOLTAGE) and s[CLEAR_SENT] == 0.0:
        s[CLEAR_SENT] = 1.0
        c[FAULTS_CLEARED] += 1
        if not send_control(b, CONTROL_CLEAR_FAULTS):
            return False
    now = monotonic_s(b.timespec)
    s[LAST_COMMAND_AT] = now
    s[SAFE] = 0.0 if enable else 1.0
    N = np.int64(s[BLOCK_SAMPLES])
    m = fc.write_command(k0 % (np.int64(1) << 32), flags, b.steps, n, N > 1, b.raw)
    if not send_payload(b, m):
        c[COMMAND_ERRORS] += N == 1
        return False
    slot = (k0 // N) % b.written.shape[0]
    b.written[slot, 1] = monotonic_s(b.timespec)
    b.written[slot, 0] = k0
    c[COMMANDS] += 1
    return True


@njit(cache=True, nogil=True)
def check_silence(b):
    """InverterBridge._check_timeouts: the link lost after ``link_timeout_s`` without telemetry (an inverter in
    lock-step, ``answer_wait_s`` > 0: while telemetry taken after the last command is owed an answer, after
    ``answer_wait_s`` more; once answered, ``link_timeout_s`` after the answer); the safe state (CONTROL 1)
    after ``command_timeout_s`` without a command while the link is up. False when the link failed."""
    s, now = b.state, monotonic_s(b.timespec)
    since, timeout = s[LAST_TELEMETRY_AT], s[LINK_TIMEOUT]
    if s[ANSWER_WAIT] > 0.0 and not math.isnan(since):
        if not math.isnan(s[LAST_COMMAND_AT]) and s[LAST_COMMAND_AT] >= since:
            since = s[LAST_COMMAND_AT]
        else:
            timeout += s[ANSWER_WAIT]
    if not math.isnan(since) and now - since > timeout and s[LOST] == 0.0:
        s[LOST] = 1.0
        b.counters[LINK_LOST] += 1
    if (s[LOST] == 0.0 and s[SAFE] == 0.0 and not math.isnan(s[LAST_COMMAND_AT])
            and now - s[LAST_COMMAND_AT] > s[COMMAND_TIMEOUT]):
        s[SAFE] = 1.0
        b.counters[SAFE_STATE] += 1
        return send_control(b, CONTROL_DISABLE)
    return True
