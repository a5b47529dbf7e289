"""Links carrying the inverter protocol: a serial port (pyserial; a real UART, USB CDC, or the pseudo-
terminal of the virtual inverter, drive_tools.doubles) and a CAN bus (python-can: SocketCAN where the kernel has it, its
virtual bus otherwise). Both directions use the same classes; a failing port or bus raises LinkDown."""
import os
import select
import time

from .inverter_protocol import (
    CanDecoder,
    CommandBlock,
    FrameReader,
    Telemetry,
    TelemetryBlock,
    encode_frame,
    to_can,
    to_canfd,
)


class LinkDown(OSError):
    """The port or bus failed (unplugged, bus-off, closed); reopen to continue."""


UART_BAUD = 3_000_000
"""The serial link's rate the protocol is sized for (docs/inverter-protocol.md): 8N1, 10 bits a byte."""
CAN_ARBITRATION_BITRATE, CAN_DATA_BITRATE = 1_000_000, 5_000_000


def uart_frame_s(n_bytes, baudrate=UART_BAUD):
    """Time on the wire of ``n_bytes`` sent back to back on a UART, 8N1 [s]."""
    return 10.0 * n_bytes / baudrate


def can_frame_s(n_bytes, fd):
    """Time on the bus of one CAN frame of ``n_bytes`` data [s], worst-case bit stuffing (one in five) on
    what is stuffed: classic (11-bit identifier) at the arbitration rate; CAN FD with bit-rate switch, its
    arbitration, acknowledge and end (30 bits) at the arbitration rate and the rest (DLC, data, stuff
    count, CRC: 8n + 30 bits) at the data rate."""
    if not fd:
        return (1.2 * (34 + 8 * n_bytes) + 13) / CAN_ARBITRATION_BITRATE
    return 30 / CAN_ARBITRATION_BITRATE + 1.2 * (8 * n_bytes + 30) / CAN_DATA_BITRATE


class SerialLink:
    """Protocol frames over a serial port opened by path (a symlink such as /dev/serial/by-id/... is
    followed at each open, so a re-plugged device is found again). pyserial opens and configures the
    port (raw mode, baud rate); frames then go through its file descriptor with select, read and write."""

    def __init__(self, port, baudrate=UART_BAUD):
        self.port, self.baudrate = port, baudrate
        self.serial = None
        self.fd = None
        self.reader = FrameReader()

    def open(self):
        import serial
        try:
            self.serial = serial.Serial(self.port, self.baudrate, timeout=0, write_timeout=0.1)
        except (serial.SerialException, OSError, ValueError) as error:
            self.serial = None
            raise LinkDown(f"{self.port}: {error}") from None
        self.fd = self.serial.fileno()
        self.reader = FrameReader()

    @property
    def errors(self):
        return self.reader.errors

    def receive(self, timeout_s):
        """Messages arriving within ``timeout_s`` (returns as soon as one frame is complete)."""
        import serial
        if self.serial is None:
            raise LinkDown(f"{self.port}: not open")
        deadline = time.monotonic() + timeout_s
        try:
            while True:
                ready, _, _ = select.select([self.fd], [], [], max(0.0, deadline - time.monotonic()))
                if ready:
                    data = os.read(self.fd, 4096)
                    if not data:
                        raise LinkDown(f"{self.port}: the device is gone")
                    messages = self.reader.feed(data)
                    if messages:
                        return messages
                if time.monotonic() >= deadline:
                    return []
        except (serial.SerialException, OSError, ValueError, TypeError) as error:
            self.close()
            raise LinkDown(f"{self.port}: {error}") from None

    def send(self, message):
        import serial
        if self.serial is None:
            raise LinkDown(f"{self.port}: not open")
        try:
            os.write(self.fd, encode_frame(message))
        except (serial.SerialException, OSError, ValueError) as error:
            self.close()
            raise LinkDown(f"{self.port}: {error}") from None

    def close(self):
        if self.serial is not None:
            try:
                self.serial.close()
            except OSError:
                pass
        self.serial = None


def can_bus(channel, interface=None):
    """A python-can bus: ``interface`` as given ('cable': drive_bridge.can_cable's bus between processes,
    ``channel`` its directory), else SocketCAN when the kernel has PF_CAN and the channel exists, else
    python-can's in-process virtual bus on ``channel``."""
    import can
    if interface == "cable":
        from .can_cable import CableBus
        try:
            return CableBus(channel)
        except OSError as error:
            raise LinkDown(f"CAN cable:{channel}: {error}") from None
    if interface is None:
        interface = "socketcan" if socketcan_available(channel) else "virtual"
    try:
        return can.Bus(interface=interface, channel=channel, receive_own_messages=False, fd=True)
    except (can.CanError, OSError, ValueError) as error:
        raise LinkDown(f"CAN {interface}:{channel}: {error}") from None


def socketcan_available(channel):
    import socket
    try:
        with socket.socket(socket.PF_CAN, socket.SOCK_RAW, socket.CAN_RAW) as s:
            s.bind((channel,))
        return True
    except (AttributeError, OSError):
        return False


class CanLink:
    """Protocol frames of one drive (``drive_id``) on a CAN bus (blocks as CAN FD frames, the bus opened
    for CAN FD); frames of other drives are ignored."""

    def __init__(self, channel, drive_id=0, interface=None, status_every=1):
        self.channel, self.drive_id, self.interface = channel, drive_id, interface
        self.status_every = status_every
        self.bus = None
        self.decoder = CanDecoder(drive_id)
        self.sent_telemetry = 0

    def open(self):
        self.bus = can_bus(self.channel, self.interface)
        self.decoder = CanDecoder(self.drive_id)

    @property
    def errors(self):
        return self.decoder.errors

    def receive(self, timeout_s):
        import can
        if self.bus is None:
            raise LinkDown(f"CAN {self.channel}: not open")
        deadline = time.monotonic() + timeout_s
        messages = []
        try:
            while not messages:
                frame = self.bus.recv(max(0.0, deadline - time.monotonic()))
                if frame is None:
                    break
                base = self.decoder.base
                if frame.is_error_frame or not base <= frame.arbitration_id < base + 0x20:
                    continue
                message = self.decoder.feed(frame.arbitration_id, frame.data)
                if message is not None:
                    messages.append(message)
        except (can.CanError, OSError) as error:
            self.close()
            raise LinkDown(f"CAN {self.channel}: {error}") from None
        return messages

    def send(self, message):
        import can
        if self.bus is None:
            raise LinkDown(f"CAN {self.channel}: not open")
        with_status = True
        if isinstance(message, Telemetry):
            with_status = self.sent_telemetry % self.status_every == 0
            self.sent_telemetry += 1
        fd = isinstance(message, (TelemetryBlock, CommandBlock))
        frames = to_canfd(message, self.drive_id) if fd else to_can(message, self.drive_id, with_status)
        try:
            for identifier, data in frames:
                self.bus.send(can.Message(arbitration_id=identifier, data=data, is_extended_id=False, is_fd=fd,
                                          bitrate_switch=fd))
        except (can.CanError, OSError) as error:
            self.close()
            raise LinkDown(f"CAN {self.channel}: {error} (bus-off?)") from None

    def wire_time_s(self, message):
        """Time ``message`` takes on the bus [s] (blocks as CAN FD frames)."""
        if isinstance(message, (TelemetryBlock, CommandBlock)):
            return sum(can_frame_s(len(data), True) for _, data in to_canfd(message, self.drive_id))
        return sum(can_frame_s(len(data), False) for _, data in to_can(message, self.drive_id))

    def close(self):
        import can
        if self.bus is not None:
            try:
                self.bus.shutdown()
            except (can.CanError, OSError):
                pass
        self.bus = None
