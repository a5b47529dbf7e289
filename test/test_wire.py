"""The serialized per-sample messages (drive_common.contract.wire) against rclpy's own CDR serialization: what
the nodes publish, any ROS 2 tool reads as the contract's types; what any publisher sends, they decode."""
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drive_common.contract.wire import (
    BlockWire,
    JointWire,
    Vector3Wire,
    WireError,
    decode_block,
    decode_joint,
    decode_vector3,
    encode_clock,
)

serialization = pytest.importorskip("rclpy.serialization")
from geometry_msgs.msg import Vector3Stamped  # noqa: E402
from rosgraph_msgs.msg import Clock  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402

pytestmark = pytest.mark.unit

values = st.floats(allow_nan=False, width=64)
stamps = st.tuples(st.integers(0, 2 ** 31 - 1), st.integers(0, 999_999_999))
names = st.text(st.characters(codec="ascii", exclude_characters="\0"), max_size=12)


@settings(max_examples=200, deadline=None)
@given(stamps, names, values, values, values)
def test_a_vector3_round_trips_through_rclpy(stamp, frame_id, x, y, z):
    data = Vector3Wire(frame_id).encode(*stamp, x, y, z)
    msg = serialization.deserialize_message(data, Vector3Stamped)
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec, msg.header.frame_id) == (*stamp, frame_id)
    assert (msg.vector.x, msg.vector.y, msg.vector.z) == (x, y, z)
    assert decode_vector3(serialization.serialize_message(msg)) == (*stamp, x, y, z)


@settings(max_examples=200, deadline=None)
@given(stamps, names, values, values, st.one_of(st.none(), values))
def test_a_joint_state_round_trips_through_rclpy(stamp, name, position, velocity, effort):
    data = JointWire(name).encode(*stamp, position, velocity, effort)
    msg = serialization.deserialize_message(data, JointState)
    assert list(msg.name) == [name] and list(msg.position) == [position] and list(msg.velocity) == [velocity]
    assert list(msg.effort) == ([] if effort is None else [effort])
    assert decode_joint(data) == (*stamp, position, velocity, effort)


@settings(max_examples=100, deadline=None)
@given(stamps, names, st.integers(1, 40), st.booleans(), st.data())
def test_a_block_round_trips_through_rclpy(stamp, frame_id, n, with_effort, data):
    """A block of n samples is a drive_msgs/SampleBlock with three float64 channels, read by rclpy and read back;
    a block of contract version 2 (a JointState, its position, velocity, effort the channels: the same CDR
    layout) is read the same way."""
    from drive_msgs.msg import SampleBlock
    a, b, c = (np.array(data.draw(st.lists(values, min_size=n, max_size=n))) for _ in range(3))
    encoded = BlockWire(frame_id).encode(*stamp, a, b, c if with_effort else None)
    msg = serialization.deserialize_message(encoded, SampleBlock)
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec, msg.header.frame_id) == (*stamp, frame_id)
    assert list(msg.labels) == [] and list(msg.a) == a.tolist() and list(msg.b) == b.tolist()
    assert list(msg.c) == (c.tolist() if with_effort else [])
    legacy = JointState(position=msg.a, velocity=msg.b, effort=msg.c)
    legacy.header = msg.header
    for message in (msg, legacy):
        sec, nanosec, x, y, z = decode_block(serialization.serialize_message(message))
        assert (sec, nanosec) == stamp and x.tolist() == a.tolist() and y.tolist() == b.tolist()
        assert z.tolist() == (c.tolist() if with_effort else [])


def test_any_publishers_joint_state_is_read_by_its_first_entries():
    msg = JointState(name=["left_wheel", "right_wheel"], position=[1.5, 2.5], velocity=[], effort=[0.25, 0.5])
    msg.header.frame_id = "base_link"
    msg.header.stamp.sec, msg.header.stamp.nanosec = 3, 400
    assert decode_joint(serialization.serialize_message(msg)) == (3, 400, 1.5, None, 0.25)
    assert decode_joint(serialization.serialize_message(JointState())) == (0, 0, None, None, None)


def test_non_finite_values_travel_as_they_are():
    sec, nanosec, x, y, z = decode_vector3(Vector3Wire("abc").encode(0, 0, math.nan, math.inf, -math.inf))
    assert math.isnan(x) and y == math.inf and z == -math.inf


def test_bytes_of_another_type_are_refused_by_name():
    clock = encode_clock(1, 2)
    msg = serialization.deserialize_message(clock, Clock)
    assert (msg.clock.sec, msg.clock.nanosec) == (1, 2)
    for decode, name in ((decode_vector3, "Vector3Stamped"), (decode_joint, "JointState"),
                         (decode_block, "JointState")):
        with pytest.raises(WireError, match=name):
            decode(clock)
