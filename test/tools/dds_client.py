"""An outside DDS client of the drive, without rclpy: Eclipse Cyclone DDS (the `cyclonedds` PyPI package) speaking
RTPS to the drive's Fast DDS on this machine, with the ROS 2 conventions by hand: topic `rt/` + the ROS name,
type `PKG::msg::dds_::NAME_`, reliable, volatile. Generic: read messages of a type on one topic, publish messages
of a type on another (a JointState naming joints, a Float64), for as long as asked.

    python test/tools/dds_client.py [--domain N] [--read TOPIC TYPE] [--publish TOPIC TYPE JSON]
                                    [--rate HZ] [--duration S] [--count N] [--idle S]

TYPE: JointState, Vector3Stamped or Float64; JSON: the message's fields ({"name": ["j1"], "velocity": [1.0]},
{"data": 4.0}). Prints one JSON line per message read ({"topic", "stamp_s", fields}) and, at the end, one summary
line {"summary": {"read": N, "published": N}}; once a reader has matched a writer of its topic (and a writer
a reader), one line {"matched": TOPIC}; before all, once its readers and writers exist, {"started": true}.
The domain is ROS_DOMAIN_ID's; discovery is unicast on the loopback
(as ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST makes Fast DDS do)."""
import argparse
import json
import os
import sys
import time
from dataclasses import dataclass, field

from cyclonedds.idl import IdlStruct
from cyclonedds.idl.types import float64, int32, sequence, uint32

LOOPBACK_CONFIG = ("<CycloneDDS><Domain id='any'><General><Interfaces><NetworkInterface name='lo'/></Interfaces>"
                   "<AllowMulticast>false</AllowMulticast></General><Discovery>"
                   "<ParticipantIndex>auto</ParticipantIndex><MaxAutoParticipantIndex>120</MaxAutoParticipantIndex>"
                   "<Peers><Peer address='127.0.0.1'/></Peers></Discovery></Domain></CycloneDDS>")
"""Cyclone DDS on the loopback, finding participants by unicast (Fast DDS's localhost range: no multicast)."""


@dataclass
class Time(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    sec: int32 = 0
    nanosec: uint32 = 0


@dataclass
class Header(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    stamp: Time = field(default_factory=Time)
    frame_id: str = ""


@dataclass
class JointState(IdlStruct, typename="sensor_msgs::msg::dds_::JointState_"):
    header: Header = field(default_factory=Header)
    name: sequence[str] = field(default_factory=list)
    position: sequence[float64] = field(default_factory=list)
    velocity: sequence[float64] = field(default_factory=list)
    effort: sequence[float64] = field(default_factory=list)


@dataclass
class Vector3(IdlStruct, typename="geometry_msgs::msg::dds_::Vector3_"):
    x: float64 = 0.0
    y: float64 = 0.0
    z: float64 = 0.0


@dataclass
class Vector3Stamped(IdlStruct, typename="geometry_msgs::msg::dds_::Vector3Stamped_"):
    header: Header = field(default_factory=Header)
    vector: Vector3 = field(default_factory=Vector3)


@dataclass
class Float64(IdlStruct, typename="std_msgs::msg::dds_::Float64_"):
    data: float64 = 0.0


TYPES = {"JointState": JointState, "Vector3Stamped": Vector3Stamped, "Float64": Float64}


def dds_topic(ros_name):
    """The DDS topic of a ROS topic name: `rt` + the fully qualified name."""
    return "rt" + (ros_name if ros_name.startswith("/") else "/" + ros_name)


def fields(message):
    """A message as JSON-ready data."""
    if isinstance(message, IdlStruct):
        return {name: fields(getattr(message, name)) for name in message.__dataclass_fields__}
    if isinstance(message, (list, tuple)):
        return [fields(v) for v in message]
    return message


def build(kind, values):
    """A message of ``kind`` from JSON ``values`` (its header stamped now)."""
    message = TYPES[kind](**values)
    if hasattr(message, "header"):
        now = time.time()
        message.header = Header(stamp=Time(sec=int(now), nanosec=int(now % 1 * 1e9)))
    return message


def main(argv=None):
    parser = argparse.ArgumentParser(prog="dds_client")
    parser.add_argument("--domain", type=int, default=int(os.environ.get("ROS_DOMAIN_ID", "0")))
    parser.add_argument("--read", nargs=2, action="append", default=[], metavar=("TOPIC", "TYPE"))
    parser.add_argument("--publish", nargs=3, action="append", default=[], metavar=("TOPIC", "TYPE", "JSON"))
    parser.add_argument("--rate", type=float, default=20.0, help="publishing rate [Hz]")
    parser.add_argument("--duration", type=float, default=5.0, help="how long to run [s]")
    parser.add_argument("--count", type=int, default=0, help="stop after reading this many (0: run the duration)")
    parser.add_argument("--idle", type=float, default=0.0,
                        help="stop once nothing was read for this long after a first message [s] (0: never)")
    args = parser.parse_args(argv)
    os.environ.setdefault("CYCLONEDDS_URI", LOOPBACK_CONFIG)
    from cyclonedds.domain import DomainParticipant
    from cyclonedds.pub import DataWriter
    from cyclonedds.qos import Policy, Qos
    from cyclonedds.sub import DataReader
    from cyclonedds.topic import Topic
    from cyclonedds.util import duration

    participant = DomainParticipant(args.domain)
    qos = Qos(Policy.Reliability.Reliable(max_blocking_time=duration(milliseconds=100)),
              Policy.History.KeepLast(10_000), Policy.Durability.Volatile)
    readers = [(name, DataReader(participant, Topic(participant, dds_topic(name), TYPES[kind]), qos=qos))
               for name, kind in args.read]
    writers = [(DataWriter(participant, Topic(participant, dds_topic(name), TYPES[kind]), qos=qos), kind,
                json.loads(values)) for name, kind, values in args.publish]
    read = published = 0
    end, next_publish = time.monotonic() + args.duration, time.monotonic()
    last_read = None
    unmatched = {name: reader.get_subscription_matched_status for name, reader in readers}
    unmatched.update({name: writer.get_publication_matched_status
                      for (name, _, _), (writer, _, _) in zip(args.publish, writers)})
    print(json.dumps({"started": True}), flush=True)
    while time.monotonic() < end and not (args.count and read >= args.count):
        for name, status in list(unmatched.items()):
            if status().current_count > 0:
                print(json.dumps({"matched": name}), flush=True)
                del unmatched[name]
        if args.idle and last_read is not None and time.monotonic() - last_read > args.idle:
            break
        if writers and time.monotonic() >= next_publish:
            for writer, kind, values in writers:
                writer.write(build(kind, values))
                published += 1
            next_publish += 1.0 / args.rate
        for name, reader in readers:
            for message in reader.take(N=256):
                if not isinstance(message, IdlStruct):
                    continue  # the writer went away (an InvalidSample: its instance disposed), no data
                stamp = message.header.stamp if hasattr(message, "header") else None
                print(json.dumps({"topic": name, "stamp_s": stamp and stamp.sec + stamp.nanosec * 1e-9,
                                  **fields(message)}), flush=True)
                read += 1
                last_read = time.monotonic()
        time.sleep(0.002)
    print(json.dumps({"summary": {"read": read, "published": published}}), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
