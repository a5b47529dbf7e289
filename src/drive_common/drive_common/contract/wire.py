"""The per-sample messages and their blocks as serialized bytes (CDR, little endian, as rmw_fastrtps puts
them on the wire), so that nodes publish and take them with ``raw=True`` and skip rclpy's message
objects: a hop then costs about a third (docs/ros-graph.md, "Transport"). No rclpy import: the layouts
are plain ``struct``.

Encoders write the project's own layout of each type; decoders read any publisher's (any frame_id, joint
names and array lengths) and raise ``WireError`` on bytes that are not that type.
"""
import struct

import numpy as np

ENCAPSULATION = b"\x00\x01\x00\x00"
"""CDR little endian, no options."""
_HEAD = struct.Struct("<iII")
_U32 = struct.Struct("<I")
_F64 = struct.Struct("<d")
_VECTOR = struct.Struct("<3d")


class WireError(ValueError):
    """Bytes that are not a message of the expected type."""


def _layout(fields):
    """A struct format (after the encapsulation) of CDR fields in order, each aligned to its own size as
    CDR wants: ``i``/``I`` 4 bytes, ``d`` 8, ``Ns`` N bytes unaligned."""
    fmt, offset = "<4s", 0
    for field in fields:
        size = struct.calcsize("<" + field)
        alignment = 1 if field.endswith("s") else size
        pad = -offset % alignment
        fmt += f"{pad}x{field}" if pad else field
        offset += pad + size
    return struct.Struct(fmt)


def _string(text):
    """A CDR string's bytes after its length field: the text and its NUL."""
    return text.encode() + b"\0"


class Vector3Wire:
    """geometry_msgs/msg/Vector3Stamped with a fixed frame_id: ``encode(sec, nanosec, x, y, z)`` → bytes."""

    def __init__(self, frame_id=""):
        self._frame = _string(frame_id)
        self._struct = _layout(("i", "I", "I", f"{len(self._frame)}s", "d", "d", "d"))

    def encode(self, sec, nanosec, x, y, z):
        return self._struct.pack(ENCAPSULATION, sec, nanosec, len(self._frame), self._frame, x, y, z)


def decode_vector3(data):
    """(sec, nanosec, x, y, z) of a serialized Vector3Stamped."""
    try:
        sec, nanosec, length = _HEAD.unpack_from(data, 4)
        offset = 12 + length
        offset += -offset % 8
        x, y, z = _VECTOR.unpack_from(data, 4 + offset)
    except struct.error:
        raise WireError(f"{len(data)} bytes are not a Vector3Stamped") from None
    return sec, nanosec, x, y, z


class JointWire:
    """sensor_msgs/msg/JointState of one joint named ``name``, frame_id empty:
    ``encode(sec, nanosec, position, velocity, effort)`` → bytes; effort None leaves it empty."""

    def __init__(self, name):
        self._name = _string(name)
        head = ("i", "I", "I", "1s", "I", "I", f"{len(self._name)}s", "I", "d", "I", "d", "I")
        self._without_effort = _layout(head)
        self._with_effort = _layout(head + ("d",))

    def encode(self, sec, nanosec, position, velocity, effort=None):
        head = (ENCAPSULATION, sec, nanosec, 1, b"\0", 1, len(self._name), self._name, 1, position, 1, velocity)
        if effort is None:
            return self._without_effort.pack(*head, 0)
        return self._with_effort.pack(*head, 1, effort)


def _joint_channels(data):
    """(sec, nanosec, [(offset, count)] × 3) of a serialized JointState: where position, velocity and
    effort lie (offset in ``data`` of the first float64). WireError when the bytes are not one."""
    try:
        sec, nanosec, length = _HEAD.unpack_from(data, 4)
        offset = 12 + length
        offset += -offset % 4
        (names,) = _U32.unpack_from(data, 4 + offset)
        offset += 4
        for _ in range(names):
            offset += -offset % 4
            (length,) = _U32.unpack_from(data, 4 + offset)
            offset += 4 + length
        channels = []
        for _ in range(3):
            offset += -offset % 4
            (count,) = _U32.unpack_from(data, 4 + offset)
            offset += 4
            if count:
                offset += -offset % 8
            channels.append((4 + offset, count))
            offset += 8 * count
    except struct.error:
        raise WireError(f"{len(data)} bytes are not a JointState") from None
    if offset + 4 > len(data):
        raise WireError(f"{len(data)} bytes are not a JointState")
    return sec, nanosec, channels


def decode_joint(data):
    """(sec, nanosec, position[0], velocity[0], effort[0]) of a serialized JointState; a missing entry is
    None."""
    sec, nanosec, channels = _joint_channels(data)
    return (sec, nanosec, *(_F64.unpack_from(data, offset)[0] if count else None for offset, count in channels))


class BlockWire:
    """A block of samples as drive_msgs/msg/SampleBlock (docs/ros-graph.md, "Block transport"): header
    (the first sample's stamp, ``frame_id``), no labels, and three float64 channels of n samples in a, b and c
    (the CDR layout of a sensor_msgs/msg/JointState without names, the blocks' type up to contract version 2).
    ``encode(sec, nanosec, a, b, c)`` → bytes; a, b, c are float64 arrays
    of one length (c None: effort empty)."""

    def __init__(self, frame_id=""):
        self._frame = _string(frame_id)
        self._head = _layout(("i", "I", "I", f"{len(self._frame)}s", "I"))

    def encode(self, sec, nanosec, a, b, c=None):
        parts = [self._head.pack(ENCAPSULATION, sec, nanosec, len(self._frame), self._frame, 0)]
        offset = self._head.size - 4
        for channel in (a, b, c):
            count = 0 if channel is None else len(channel)
            pad = -offset % 4
            parts.append(b"\0" * pad + _U32.pack(count))
            offset += pad + 4
            if count:
                pad = -offset % 8
                data = channel.astype("<f8", copy=False).tobytes()
                parts.append(b"\0" * pad + data)
                offset += pad + len(data)
        return b"".join(parts)


def decode_block(data):
    """(sec, nanosec, a, b, c) of a serialized SampleBlock (or position, velocity, effort of a JointState: the
    same layout), the arrays as float64 numpy arrays (empty where not carried)."""
    sec, nanosec, channels = _joint_channels(data)
    return (sec, nanosec, *(np.frombuffer(data, "<f8", count, offset).copy() for offset, count in channels))


_CLOCK = struct.Struct("<4siI")


def encode_clock(sec, nanosec):
    """rosgraph_msgs/msg/Clock."""
    return _CLOCK.pack(ENCAPSULATION, sec, nanosec)


def decoder_of(message_type):
    """The decoder of a per-sample message type ('sensor_msgs/msg/JointState' or
    'geometry_msgs/msg/Vector3Stamped'): bytes → (sec, nanosec, a, b, c)."""
    return decode_joint if message_type == "sensor_msgs/msg/JointState" else decode_vector3
