"""The live view (``drive view``, ``drive launch --view``): the topics of running drives served over the Foxglove
WebSocket protocol (foxglove-sdk) for the Foxglove app, each message as its serialized CDR bytes (schema
``ros2msg``), and a page of our own (``page.html``: no internet, its script inline) that connects to the same
server and plots angle error, speed and currents per axis as they come, with the drive's error counters.

``start_view(context, options)`` is the serving core: it adds one rclpy node to ``context`` and spins it on a
thread of its own; ``stop()`` ends it."""
import http.server
import threading
from dataclasses import dataclass
from importlib.resources import files

from drive_common.contract.graph import DEFAULT_NAMESPACE
from drive_common.contract.topics import (
    ANGLE_ERROR,
    CURRENTS,
    DIAGNOSTICS,
    DRIVE_CONFIG,
    JOINT_STATES,
    TOPICS,
    block,
    full_name,
)

AXIS_TOPICS = (ANGLE_ERROR, JOINT_STATES, CURRENTS, block(CURRENTS), DRIVE_CONFIG)
"""What the view forwards of each drive (axis): its angle error, robot-facing estimate (speed), currents
(per sample, decimated, or in blocks) and configuration; /diagnostics once for all."""
FOUND_BY = (DRIVE_CONFIG, ANGLE_ERROR, CURRENTS, block(CURRENTS))
"""A namespace holding one of these topics holds a drive (found while watching every drive)."""
DISCOVERY_PERIOD_S = 0.5
BACKLOG_MESSAGES = 65536
"""Messages the server buffers per client before it drops the oldest (the SDK's default is 1024: 0.1 s of a
10 kHz topic)."""


@dataclass(frozen=True)
class ViewOptions:
    """Which drives (``namespaces``; empty: every drive that appears in the graph), where the Foxglove
    WebSocket server listens (``host``, ``port``; 0: any free port) and the page (``page_port``; 0: any
    free port), and every how many per-sample currents the view forwards (``currents_every``)."""

    namespaces: tuple = ()
    host: str = "127.0.0.1"
    port: int = 8765
    page_port: int = 8766
    currents_every: int = 10


class LiveView:
    """A running view: ``url`` (the page), ``ws_url`` (the Foxglove server), ``forwarded`` (messages per
    topic), ``namespaces`` (the drives it serves); ``stop()``."""

    def __init__(self, context, options):
        import foxglove
        from rclpy.node import Node

        from drive_common.ros.node import make_executor
        self.options = options
        self.forwarded = {}
        self.namespaces = []
        self.channels = {}
        self.latest_ns = 0
        self.fox = foxglove.Context()
        self.server = foxglove.start_server(name="drive view", host=options.host, port=options.port,
                                            context=self.fox, message_backlog_size=BACKLOG_MESSAGES)
        self.ws_url = f"ws://{options.host}:{self.server.port}"
        self.page = _page_server(options.host, options.page_port, self.server.port)
        self.url = f"http://{options.host}:{self.page.server_address[1]}/"
        self.node = Node("drive_view", context=context, namespace="/")
        self._forward(DIAGNOSTICS)
        for namespace in options.namespaces:
            self._add_drive(namespace)
        if not options.namespaces:
            self.node.create_timer(DISCOVERY_PERIOD_S, self._discover)
            self._discover()
        self.executor = make_executor("events", context)
        self.executor.add_node(self.node)
        self.running = True
        self.threads = [threading.Thread(target=self._spin, name="drive_view", daemon=True),
                        threading.Thread(target=self.page.serve_forever, name="drive_view_page", daemon=True)]
        for thread in self.threads:
            thread.start()

    def _spin(self):
        while self.running:
            self.executor.spin_once(timeout_sec=0.1)

    def _discover(self):
        """Add each namespace that has come to hold a drive's topic."""
        for name, _ in self.node.get_topic_names_and_types():
            namespace, _, topic = name.rpartition("/")
            if topic in FOUND_BY and namespace not in self.namespaces:
                self._add_drive(namespace or "/")

    def _add_drive(self, namespace):
        self.namespaces.append(namespace)
        for topic in AXIS_TOPICS:
            self._forward(topic, namespace)

    def _forward(self, topic, namespace=DEFAULT_NAMESPACE):
        """Subscribe to ``topic`` of ``namespace`` serialized, with its contract QoS, and log every message (or
        every ``currents_every``-th of the per-sample currents) to a Foxglove channel of the same name."""
        import foxglove

        from drive_common.ros.node import message_class, topic_qos
        from drive_tools.bags.common import typestore
        name = full_name(namespace, topic)
        message_type = TOPICS[topic].type
        schema = foxglove.Schema(name=message_type, encoding="ros2msg",
                                 data=typestore().generate_msgdef(message_type, ros_version=2)[0].encode())
        channel = foxglove.Channel(name, schema=schema, message_encoding="cdr", context=self.fox)
        self.channels[name] = channel
        self.forwarded[name] = 0
        every = self.options.currents_every if topic == CURRENTS else 1
        stamped = TOPICS[topic].stamped or topic == DIAGNOSTICS
        seen = [0]

        def take(data):
            seen[0] += 1
            if (seen[0] - 1) % every:
                return
            if stamped:
                self.latest_ns = int.from_bytes(data[4:8], "little", signed=True) * 1_000_000_000 + \
                    int.from_bytes(data[8:12], "little")
            channel.log(data, log_time=self.latest_ns)
            self.forwarded[name] += 1
        self.node.create_subscription(message_class(topic), name, take, topic_qos(topic), raw=True)

    def stop(self):
        """Stop serving: the node's thread, the page, the Foxglove server."""
        self.running = False
        self.threads[0].join(timeout=2.0)
        self.executor.shutdown()
        self.node.destroy_node()
        self.page.shutdown()
        self.page.server_close()
        self.server.stop()


def start_view(context, options=ViewOptions()):
    """Serve the drives ``options`` name (ViewOptions) from a node in the rclpy ``context``; returns the
    LiveView (its ``url`` the page's address)."""
    return LiveView(context, options)


def page_html(ws_port):
    """The page, its script inline, connecting to the Foxglove server on ``ws_port`` of the page's host."""
    text = files("drive_tools.view").joinpath("page.html").read_text()
    return text.replace("__WS_PORT__", str(int(ws_port)))


def _page_server(host, port, ws_port):
    """An HTTP server that answers every GET with the page."""
    body = page_html(ws_port).encode()

    class Page(http.server.BaseHTTPRequestHandler):
        def do_GET(self):
            self.send_response(200)
            self.send_header("Content-Type", "text/html; charset=utf-8")
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)

        def log_message(self, *args):
            pass
    return http.server.ThreadingHTTPServer((host, port), Page)
