"""Faulty doubles of the virtual inverter, for the tests and the benches that need them: link faults by plan
(``FaultPlan``, ``faulty``: frames corrupted, dropped, duplicated, reordered, garbage, command messages lost)
and an event at a sample a test names (``acting_at``: a link unplugged, a bus gone off, a signal). Each is
a factory called as VirtualInverter(scenario, endpoint, options) is, which is what the loop through the bridge
(drive_tools.runner.bridge_loop) and the launcher (DriveSpec.inverter) take. No rclpy."""
import functools
from dataclasses import dataclass, field

import numpy as np

from drive_bridge.inverter_protocol import encode_frame

from .virtual_inverter import InverterOptions, VirtualInverter


@dataclass
class FaultPlan:
    """Link faults the virtual inverter injects into its telemetry, every Nth frame (0: never), and into the
    commands it hears; ``counts`` what it injected, by kind."""

    corrupt_every: int = 0
    """Flip one byte of the frame (serial only)."""
    drop_every: int = 0
    duplicate_every: int = 0
    reorder_every: int = 0
    """Hold the frame back and send it after the next one."""
    garbage_every: int = 0
    """Insert random bytes before the frame (resynchronisation; serial only)."""
    lose_command_every: int = 0
    """Lose every Nth command message the host sends (to the inverter, an answer that came too late)."""
    lose_commands: tuple = ()
    """Also lose these command messages, by their number in the order heard (1 the first): a run of
    consecutive ones is a run of late blocks."""
    seed: int = 1
    counts: dict = field(default_factory=dict)


class FaultyInverter(VirtualInverter):
    """A virtual inverter behind a faulty link: what ``faults`` (a FaultPlan) says is lost, corrupted,
    duplicated or reordered on the way, counted in ``faults.counts``."""

    def __init__(self, scenario, endpoint, options=None, faults=None):
        super().__init__(scenario, endpoint, options or InverterOptions())
        self.faults = faults or FaultPlan()
        self.random = np.random.default_rng(self.faults.seed)
        self.held_back = None
        self.commands_heard = 0

    def take_command(self, c0, values, flags, now):
        """Lose the command messages the plan names (heard all the same: lock-step does not wait for them),
        take the others."""
        f = self.faults
        if f.lose_command_every or f.lose_commands:
            self.commands_heard += 1
            every = f.lose_command_every
            if (every and self.commands_heard % every == 0) or self.commands_heard in f.lose_commands:
                f.counts["commands_lost"] = f.counts.get("commands_lost", 0) + 1
                return
        super().take_command(c0, values, flags, now)

    def transmit(self, telemetry, k0):
        """Send the telemetry frame of samples k0 … through the fault plan: on a byte link (pty) the encoded
        frame, on CAN the message; corruption and garbage exist on byte links only (CAN's own CRC would turn
        them into error frames, which never arrive). A frame dropped, corrupted or held back is noted in
        ``lost_on_the_way``."""
        f = self.faults
        self.sent_frames += 1
        n = self.sent_frames
        byte_link = hasattr(self.endpoint, "send_bytes")
        if byte_link:
            frame = bytearray(encode_frame(telemetry))
            item, emit = frame, lambda x: self.endpoint.send_bytes(bytes(x))
        else:
            item, emit = telemetry, self.send

        def due(every, kind):
            if every and n % every == 0:
                f.counts[kind] = f.counts.get(kind, 0) + 1
                return True
            return False

        if due(f.drop_every, "dropped"):
            self.lost_on_the_way.add(k0)
            return
        if byte_link and due(f.corrupt_every, "corrupted"):
            frame[int(self.random.integers(0, len(frame) - 1))] ^= 0x5A
            self.lost_on_the_way.add(k0)
        if byte_link and due(f.garbage_every, "garbage"):
            self.endpoint.send_bytes(bytes(self.random.integers(1, 256, 7, dtype=np.uint8)) + b"\x00")
        if self.held_back is None and due(f.reorder_every, "reordered"):
            self.held_back = bytes(frame) if byte_link else telemetry
            self.lost_on_the_way.add(k0)
            return
        emit(item)
        if self.held_back is not None:
            emit(self.held_back)
            self.held_back = None
        if due(f.duplicate_every, "duplicated"):
            emit(item)


def faulty(faults):
    """A factory of FaultyInverters that inject ``faults`` (a FaultPlan, its counts kept there)."""
    return functools.partial(FaultyInverter, faults=faults)


def acting_at(k, action, inverter=VirtualInverter):
    """A factory of virtual inverters (``inverter``'s, a class or a factory called as VirtualInverter) that
    call ``action(inverter)`` once, on the inverter's thread, right after sending the telemetry of sample
    ``k`` (of the block holding it): a link unplugged, a bus gone off, a signal at a sample the test names."""

    def make(scenario, endpoint, options=None):
        made = inverter(scenario, endpoint, options or InverterOptions())
        send_samples = made.send_samples

        def sending(k0, n, out):
            send_samples(k0, n, out)
            if k0 <= k < k0 + n:
                action(made)
        made.send_samples = sending
        return made
    return make
