"""A virtual CAN bus between processes on one host, for machines without SocketCAN (no PF_CAN, so no
vcan): every member of the bus is a UNIX datagram socket in one directory, the bus's channel, and a frame
sent goes to every other member, as on a CAN bus. python-can's own virtual bus lives in one process; this
one lets the virtual inverter run in a process of its own (drive_tools.doubles.inverter_process). No rclpy.

A frame on the socket: arbitration id (uint32, little-endian), flags (bit 0 extended id, bit 1 CAN FD,
bit 2 bit-rate switch), then the data bytes (0-64)."""
import os
import select
import socket
import struct
import time

import can

HEADER = struct.Struct("<IB")
EXTENDED, FD, BRS = 1, 2, 4
MEMBERS_REFRESH_S = 0.05
"""How often a member looks for members that joined or left the bus."""
SOCKET_BUFFER_BYTES = 1 << 20
SOCKET_PATH_MAX = 100
"""A UNIX socket's path holds at most 107 bytes (sun_path); a member of a bus in a directory deeper than
this is bound and reached through the directory's descriptor, /proc/self/fd/N/NAME."""


class CableBus(can.BusABC):
    """One member of the bus whose directory is ``channel`` (created if missing). A frame sent while no
    other member is there is lost, as on a bus with no other node."""

    def __init__(self, channel, can_filters=None, receive_own_messages=False, fd=True, **kwargs):
        super().__init__(channel, can_filters=can_filters, **kwargs)
        self.directory = str(channel)
        self.channel_info = f"cable {self.directory}"
        os.makedirs(self.directory, exist_ok=True)
        self.directory_fd = os.open(self.directory, os.O_RDONLY | os.O_DIRECTORY)
        self.name = f"member-{os.getpid()}-{id(self):x}.sock"
        self.path = os.path.join(self.directory, self.name)
        self.socket = self._bound()
        self.members, self.members_at = [], 0.0
        self.connected = None
        self._open = True

    def _bound(self):
        """A new datagram socket bound to this member's name."""
        member = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        member.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, SOCKET_BUFFER_BYTES)
        member.bind(self._address(self.name))
        member.setblocking(False)
        return member

    def fileno(self):
        return self.socket.fileno()

    def _address(self, name):
        """The address of the member socket ``name`` of this bus: its path, or one through the directory's
        descriptor where the path is too long for a UNIX socket."""
        path = os.path.join(self.directory, name)
        return path if len(os.fsencode(path)) <= SOCKET_PATH_MAX else f"/proc/self/fd/{self.directory_fd}/{name}"

    def _peers(self):
        now = time.monotonic()
        if now - self.members_at > MEMBERS_REFRESH_S:
            self.members_at = now
            self.members = [self._address(name) for name in sorted(os.listdir(self.directory_fd))
                            if name.endswith(".sock") and name != self.name]
        return self.members

    def connect_peer(self):
        """Connect the socket to the bus's other member, for a writer of the socket itself (the compiled answer,
        drive_bridge.compiled_bridge): True when connected; False while no other member is there, the socket
        then bound anew, unconnected (a socket connected to a member gone hears no other: a member that joins
        again is heard); ValueError when there are several (a frame then goes to each, which only ``send``
        does). The socket's descriptor may change: read ``fileno()`` after it."""
        self.members_at = 0.0
        peers = self._peers()
        if len(peers) > 1:
            raise ValueError(f"{self.channel_info}: {len(peers)} other members; a writer of the socket reaches "
                             f"one")
        if peers:
            try:
                self.socket.connect(peers[0])
                self.connected = peers[0]
                return True
            except (ConnectionRefusedError, FileNotFoundError):
                pass
        if self.connected is not None:
            self.socket.close()
            os.unlink(self.name, dir_fd=self.directory_fd)
            self.socket, self.connected = self._bound(), None
        return False

    def send(self, msg, timeout=None):
        """To every other member; with one other member, on a socket connected both ways (so that the
        kernel's small queue limit of unconnected datagrams, net.unix.max_dgram_qlen, does not apply). A frame
        no member takes (the member gone, or one whose socket still hears only a member gone) is lost, as on a
        bus with no other node."""
        if not self._open:
            raise can.CanOperationError(f"{self.channel_info}: closed")
        flags = (EXTENDED if msg.is_extended_id else 0) | (FD if msg.is_fd else 0) | (BRS if msg.bitrate_switch else 0)
        frame = HEADER.pack(msg.arbitration_id, flags) + bytes(msg.data)
        peers = self._peers()
        try:
            if len(peers) == 1:
                if self.connected != peers[0]:
                    self.socket.connect(peers[0])
                    self.connected = peers[0]
                self.socket.send(frame)
            else:
                for peer in peers:
                    self.socket.sendto(frame, peer)
        except (ConnectionRefusedError, ConnectionResetError, FileNotFoundError, PermissionError):
            self.connected, self.members_at = None, 0.0
        except BlockingIOError:
            raise can.CanOperationError(f"{self.channel_info}: a member's receive queue is full") from None

    def _recv_internal(self, timeout):
        """One frame within ``timeout``; None for none, and for the error a frame sent earlier to a member since
        gone leaves on the socket (the bus is not down: the member is looked for again)."""
        if not self._open:
            raise can.CanOperationError(f"{self.channel_info}: closed")
        ready, _, _ = select.select([self.socket], [], [], timeout)
        if not ready:
            return None, False
        try:
            frame = self.socket.recv(HEADER.size + 64)
        except BlockingIOError:
            return None, False
        except (ConnectionRefusedError, ConnectionResetError):
            self.connected, self.members_at = None, 0.0
            return None, False
        identifier, flags = HEADER.unpack_from(frame)
        data = frame[HEADER.size:]
        return can.Message(timestamp=time.time(), arbitration_id=identifier, is_extended_id=bool(flags & EXTENDED),
                           is_fd=bool(flags & FD), bitrate_switch=bool(flags & BRS), data=data, dlc=len(data),
                           channel=self.directory, is_rx=True), False

    def shutdown(self):
        super().shutdown()
        if self._open:
            self._open = False
            self.socket.close()
            try:
                os.unlink(self.name, dir_fd=self.directory_fd)
            except FileNotFoundError:
                pass
            os.close(self.directory_fd)
