"""The inverter's ends of virtual links: the device end of a pseudo-terminal (a UART the virtual inverter
stands behind) and a fresh pair of (inverter endpoint, host link) on a pty or a CAN bus. No rclpy."""
import os
import select
import time
from pathlib import Path

from drive_bridge.inverter_link import CanLink, SerialLink, uart_frame_s
from drive_bridge.inverter_protocol import FrameReader, encode_frame

LINKS = ("pty", "can")


class PtyEndpoint:
    """The inverter's end of a pseudo-terminal: frames written to and read from the master side; the
    slave's path (for the host) is a symlink at ``link_path`` that ``replug`` points at a new pty."""

    def __init__(self, link_path):
        self.link_path = str(link_path)
        self.master = self.slave = None
        self.reader = FrameReader()
        self.replug()

    def replug(self):
        import tty
        self.unplug()
        self.master, self.slave = os.openpty()
        tty.setraw(self.master)
        tty.setraw(self.slave)
        temporary = self.link_path + ".new"
        if os.path.lexists(temporary):
            os.unlink(temporary)
        os.symlink(os.ttyname(self.slave), temporary)
        os.replace(temporary, self.link_path)
        self.reader = FrameReader()

    def unplug(self):
        for fd in (self.master, self.slave):
            if fd is not None:
                os.close(fd)
        self.master = self.slave = None

    @property
    def errors(self):
        return self.reader.errors

    def receive(self, timeout_s):
        """Messages from the host within ``timeout_s``; none while unplugged (another thread may unplug
        at any moment, so a vanished descriptor is no error)."""
        deadline = time.monotonic() + timeout_s
        while True:
            master = self.master
            try:
                ready, _, _ = select.select([master], [], [], max(0.0, deadline - time.monotonic()))
                data = os.read(master, 4096) if ready else None
            except (OSError, TypeError, ValueError):
                time.sleep(max(0.0, min(0.005, deadline - time.monotonic())))
                data = None
            if data == b"":
                time.sleep(max(0.0, min(0.005, deadline - time.monotonic())))
            elif data:
                messages = self.reader.feed(data)
                if messages:
                    return messages
            if time.monotonic() >= deadline:
                return []

    def send_bytes(self, data):
        """Write to the host; lost while unplugged."""
        try:
            os.write(self.master, data)
        except (OSError, TypeError):
            pass

    def send(self, message):
        self.send_bytes(encode_frame(message))

    @staticmethod
    def wire_time_s(message):
        """Time ``message`` takes on the UART this pty stands for [s]."""
        return uart_frame_s(len(encode_frame(message)))

    def close(self):
        self.unplug()
        if os.path.lexists(self.link_path):
            os.unlink(self.link_path)


def make_links(link, workdir, drive_id=0):
    """(inverter endpoint, host link) of a fresh virtual link in ``workdir``: a pty whose slave the host opens
    by a symlink there, or a CAN bus on a cable there (drive_bridge.can_cable: sockets, as SocketCAN is, so that
    the compiled answer reads and writes it as it would a real bus); a link of an earlier run, gone or not,
    never shares it."""
    if link == "pty":
        endpoint = PtyEndpoint(Path(workdir) / f"inverter{drive_id}")
        return endpoint, SerialLink(endpoint.link_path)
    if link == "can":
        channel = str(Path(workdir) / f"can_cable{drive_id}")
        endpoint = CanLink(channel, drive_id, "cable")
        endpoint.open()
        return endpoint, CanLink(channel, drive_id, "cable")
    raise ValueError(f"unknown virtual link '{link}' (known: {', '.join(LINKS)})")
