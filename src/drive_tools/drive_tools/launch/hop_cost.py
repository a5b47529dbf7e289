"""What one message hop costs in rclpy on this machine (publish → take → callback, one process, the events
executor): the unit in which the graph's real-time figures compare across machines (docs/results.md)."""
import os
import time

from drive_common.contract.errors import DriveError
from drive_common.contract.topics import CURRENTS

HOP_ROUND_TRIPS_BESIDE_A_RUN = 2000
"""Round trips timed beside a real-time run (about 0.1 s)."""


def hop_latency(round_trips=20000):
    """Wall time of one message hop (publish → take → callback) between two nodes of one process on
    the events executor, from a ping-pong of Vector3Stamped with the lock-step QoS: the floor under
    every sample of the graph."""
    import rclpy
    from geometry_msgs.msg import Vector3Stamped
    from rclpy.node import Node
    from rclpy.signals import SignalHandlerOptions
    from rclpy.task import Future

    from drive_common.ros.node import make_executor, topic_qos

    PER_SAMPLE_QOS = topic_qos(CURRENTS)

    context = rclpy.Context()
    rclpy.init(context=context, signal_handler_options=SignalHandlerOptions.NO)
    executor = make_executor("events", context)
    try:
        a, b = Node("hop_ping", context=context), Node("hop_pong", context=context)
        ping_topic, pong_topic = f"hop_ping_{os.getpid()}", f"hop_pong_{os.getpid()}"
        ping = a.create_publisher(Vector3Stamped, ping_topic, PER_SAMPLE_QOS)
        pong = b.create_publisher(Vector3Stamped, pong_topic, PER_SAMPLE_QOS)
        done, count, message = Future(), [0], Vector3Stamped()

        def on_pong(_):
            count[0] += 1
            if count[0] >= round_trips:
                done.set_result(True)
            else:
                ping.publish(message)
        b.create_subscription(Vector3Stamped, ping_topic, pong.publish, PER_SAMPLE_QOS)
        a.create_subscription(Vector3Stamped, pong_topic, on_pong, PER_SAMPLE_QOS)
        executor.add_node(a)
        executor.add_node(b)
        end = time.monotonic() + 10.0
        while min(ping.get_subscription_count(), pong.get_subscription_count()) < 1:
            if time.monotonic() > end:
                raise DriveError("the ping-pong nodes of the hop benchmark did not match within 10 s")
            executor.spin_once(timeout_sec=0.05)
        start = time.perf_counter()
        ping.publish(message)
        while not done.done():
            executor.spin_until_future_complete(done, timeout_sec=1.0)
        wall = time.perf_counter() - start
        return {"round_trips": round_trips, "us_per_hop": 1e6 * wall / (2 * round_trips)}
    finally:
        executor.shutdown()
        context.try_shutdown()


def in_hops(timing, hop):
    """A timing report (drive_tools.doubles.inverter_timing.timing_report) with the hop cost beside it: ``hop_us``
    and each latency and answer figure also in hops (``latency_p50_hops``, ``answer_p50_hops`` ...)."""
    us = hop["us_per_hop"]
    extra = {"hop_us": us}
    for key in ("latency_p50_us", "latency_p99_us", "latency_max_us", "answer_p50_us", "answer_p99_us",
                "answer_max_us"):
        value = timing.get(key)
        extra[key.replace("_us", "_hops")] = value / us if value is not None and us > 0 else None
    return {**timing, **extra}
