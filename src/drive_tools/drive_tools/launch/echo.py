"""`drive echo`: print a drive topic as `ros2 topic echo` does (there is none in a PyPI-only install)."""
import rclpy
from rclpy.node import Node
from rclpy.serialization import deserialize_message
from rclpy.signals import SignalHandlerOptions
from rclpy.task import Future

from drive_common.contract.errors import DriveError
from drive_common.contract.exit_codes import EXIT_SIGNAL_BASE
from drive_common.contract.graph import DEFAULT_NAMESPACE
from drive_common.contract.strict_json import dumps
from drive_common.contract.topics import TOPICS
from drive_common.ros.node import make_executor, message_class, topic_qos
from drive_common.runtime.interrupt import polled, requested


def message_dict(msg):
    """A ROS message as plain Python data (what `ros2 topic echo` shows)."""
    if hasattr(msg, "get_fields_and_field_types"):
        return {name: message_dict(getattr(msg, name)) for name in msg.get_fields_and_field_types()}
    if isinstance(msg, (list, tuple)) or hasattr(msg, "tolist"):
        return [message_dict(v) for v in msg]
    if isinstance(msg, bytes):
        return int.from_bytes(msg, "little")
    return msg


def echo(topic, namespace=DEFAULT_NAMESPACE, count=None, every=1, as_json=False, timeout_s=None):
    """Print messages of a contract topic (taken serialized, deserialized only when printed, so the
    reader keeps up with a 10 kHz topic; the contract's QoS) until ``count`` were printed, ``timeout_s`` passed or
    SIGINT/SIGTERM; returns the exit code (128 + the signal when one stopped it). BrokenPipeError
    when the reader of the output went away."""
    key = topic if topic in TOPICS else topic.rsplit("/", 1)[-1]
    if key not in TOPICS:
        raise DriveError(f"{topic}: not a drive topic (known: {', '.join(TOPICS)})")
    message_type, qos = message_class(key), topic_qos(key)
    context = rclpy.Context()
    rclpy.init(context=context, signal_handler_options=SignalHandlerOptions.NO)
    done = Future()
    seen, printed, reader_gone = [0], [0], []

    def show(serialized):
        seen[0] += 1
        if (seen[0] - 1) % every or done.done():
            return
        data = message_dict(deserialize_message(serialized, message_type))
        try:
            print(dumps(data) if as_json else _yaml_like(data) + "\n---", flush=True)
        except BrokenPipeError:
            reader_gone.append(True)
            done.set_result(True)
            return
        printed[0] += 1
        if count and printed[0] >= count:
            done.set_result(True)

    node = Node("drive_echo", context=context, namespace=namespace)
    executor = None
    try:
        with polled():
            node.create_subscription(message_type, topic if topic.startswith("/") else key, show, qos, raw=True)
            if timeout_s:
                node.create_timer(timeout_s, lambda: done.done() or done.set_result(True))
            node.create_timer(0.1, lambda: requested() and not done.done() and done.set_result(True))
            executor = make_executor("events", context)
            executor.add_node(node)
            while not done.done():
                executor.spin_until_future_complete(done, timeout_sec=0.25)
            stopped_by = requested()
    finally:
        if executor is not None:
            executor.shutdown()
        node.destroy_node()
        context.try_shutdown()
    if reader_gone:
        raise BrokenPipeError("the reader of the output went away")
    return EXIT_SIGNAL_BASE + stopped_by if stopped_by else 0


def _yaml_like(data, indent=""):
    lines = []
    for name, value in data.items():
        if isinstance(value, dict):
            lines.append(f"{indent}{name}:")
            lines.append(_yaml_like(value, indent + "  "))
        elif isinstance(value, list) and value and isinstance(value[0], dict):
            lines.append(f"{indent}{name}:")
            for item in value:
                body = _yaml_like(item, indent + "  ")
                lines.append(f"{indent}- " + body.lstrip())
        else:
            lines.append(f"{indent}{name}: {value}")
    return "\n".join(lines)
