"""What the bag writer, reader and reindexer share: the rosbags typestore, QoS as rosbag2 stores it, the
sample stamp of a serialized message, and the bag's error."""
import functools
from importlib.resources import files

from drive_common.contract.errors import DriveError
from drive_common.contract.topics import SAMPLE_BLOCK, TOPICS


class BagError(DriveError):
    """A bag is unusable; the message names the bag (and topic) in one line."""


class BagCutError(BagError):
    """A recording was cut before it closed (its metadata.yaml missing, or its .mcap shorter than it says):
    what reached the disk can be rebuilt into a complete bag (``reindex``)."""

    def __init__(self, message, path):
        super().__init__(message)
        self.path = path


class BagWriteError(BagCutError):
    """A recording could not be written to the end (a full disk, a lost device)."""


class BagCompleteError(BagError):
    """A bag asked to be rebuilt is complete already."""


@functools.cache
def typestore():
    """The rosbags typestore of ROS 2 Jazzy with the drive's own drive_msgs/msg/SampleBlock."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore
    store = get_typestore(Stores.ROS2_JAZZY)
    definition = files("drive_common.contract").joinpath("msg", "SampleBlock.msg").read_text()
    store.register(get_types_from_msg(definition, SAMPLE_BLOCK))
    return store


def rosbags_qos(history=1, depth=10, reliability=1, durability=2):
    """A rosbags Qos from the rmw enum values (KEEP_LAST 1, RELIABLE 1, VOLATILE 2, TRANSIENT_LOCAL 1)."""
    from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
    return Qos(QosHistory(history), depth, QosReliability(reliability), QosDurability(durability),
               QosTime(0, 0), QosTime(0, 0), QosLiveliness.AUTOMATIC, QosTime(0, 0), False)


def offered_qos(topic):
    """The contract's QoS of a topic (drive_common.contract.topics) as rosbags stores it."""
    q = TOPICS[topic].qos
    return rosbags_qos(1, q.depth, 1, 1 if q.transient_local else 2)


def sample_stamp_ns(data):
    """The header stamp (or clock) of a serialized message whose first field is a builtin Time."""
    order = "little" if data[1] == 1 else "big"
    return int.from_bytes(data[4:8], order, signed=True) * 1_000_000_000 + int.from_bytes(data[8:12], order)
