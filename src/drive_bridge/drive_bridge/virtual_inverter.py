"""A virtual inverter: the plant core (motor, inverter, current sensors, the scenario's load or
dynamometer) behind the inverter protocol, on a pseudo-terminal or a CAN bus. It keeps an inverter's
duties (docs/inverter-protocol.md): telemetry at each period start, the command of sample k applied
during period k + 1, zero volts for a missing command, PWM off after ``watchdog_periods`` missing ones
or 100 ms without the host, and an overcurrent trip. PWM off is modelled as zero volts.

Clock: ``rate_Hz`` paces the periods in wall time (a real inverter's clock; a late command is missing,
100 ms of host silence trips; a period the simulation itself starts late is an overrun, and the clock
restarts there); without it the inverter waits up to ``command_wait_s`` for each command
(lock-step over the link, for simulations faster or slower than real time; a missing command is one
that did not come within that wait, and host silence is left to the watchdog)."""
import math
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from control_math.command_delay import applied_voltage, issue_command
from motor_params.nameplate import nameplate
from motor_params.nameplate import trip_current_A as default_trip_current_A
from pmsm_plant.build import plant_for_scenario
from pmsm_plant.model import OMEGA_M, THETA_M, plant_advance, plant_outputs, sense_currents

from .inverter_link import CanLink, LinkDown, PtyEndpoint, SerialLink
from .inverter_protocol import (
    BAD_FRAME,
    COMMAND_MISSING,
    CONTROL_CLEAR_FAULTS,
    CONTROL_DISABLE,
    CONTROL_SEND_HELLO,
    ENABLE,
    ENCODER_VALID,
    HEARTBEAT_LOST,
    HELLO_ENCODER_PRESENT,
    OVERCURRENT,
    PWM_OFF,
    WATCHDOG,
    Command,
    Control,
    Hello,
    Telemetry,
    encode_frame,
)

LINKS = ("pty", "can")

HOST_SILENCE_S = 0.1
"""Nothing from the host for this long: PWM off, HEARTBEAT_LOST latched (the protocol's 100 ms)."""


@dataclass
class FaultPlan:
    """Link faults the virtual inverter injects into its telemetry, every Nth frame (0: never)."""

    corrupt_every: int = 0
    """Flip one byte of the frame (serial only)."""
    drop_every: int = 0
    duplicate_every: int = 0
    reorder_every: int = 0
    """Hold the frame back and send it after the next one."""
    garbage_every: int = 0
    """Insert random bytes before the frame (resynchronisation; serial only)."""
    seed: int = 1
    counts: dict = field(default_factory=dict)


def _clip16(value):
    return int(max(-32768, min(32767, round(value))))


class VirtualInverter:
    """The plant of ``scenario`` behind the protocol on ``endpoint`` (PtyEndpoint or an opened
    CanLink); ``run`` in a thread, ``stop`` to end. ``truth`` holds θ_m, ω_m, τ_e, τ_load and the true
    currents per sample for scoring."""

    def __init__(self, scenario, endpoint, rate_Hz=None, command_wait_s=0.5, watchdog_periods=10,
                 trip_current_A=None, drive_id=0, faults=None, encoder=True):
        self.plant = plant_for_scenario(scenario)
        self.speed_ref, self.tau_load = scenario.schedule()
        self.scenario = scenario
        self.endpoint = endpoint
        self.rate_Hz, self.command_wait_s = rate_Hz, command_wait_s
        self.watchdog_periods = watchdog_periods
        self.trip_current_A = trip_current_A or default_trip_current_A(nameplate(scenario.motor))
        self.encoder = encoder
        self.faults = faults or FaultPlan()
        self.random = np.random.default_rng(self.faults.seed)
        self.current_lsb = float(np.float32(2.0 * self.trip_current_A / 32767.0))
        self.voltage_lsb = float(np.float32(2.0 * self.plant.inverter.U_dc_V / 32767.0))
        self.hello = Hello(drive_id, HELLO_ENCODER_PRESENT if encoder else 0, self.plant.machine.n_p, 1,
                           round(scenario.T_s * 1e9), self.current_lsb, self.voltage_lsb,
                           float(np.float32(self.trip_current_A)), watchdog_periods)
        self.k = 0
        self.enabled = False
        self.latched = 0
        self.missing = 0
        self.last_heard = time.monotonic()
        self.held_back = None
        self.inbox = deque()
        self.bad_frames = 0
        self.sent_frames = 0
        self.stopped = threading.Event()
        self.counters = {"commands": 0, "missing": 0, "discarded": 0, "trips": 0, "watchdog_trips": 0,
                         "host_silent_trips": 0, "link_down": 0, "overruns": 0}
        """overruns: periods the simulated inverter itself started more than a period behind its clock
        (its Python simulation, not the host, was slow); its clock then restarts from that moment, as
        the host cannot be blamed for periods a real inverter's timer would have kept."""
        self.latencies_s = []
        """Time from TELEMETRY(k) sent to COMMAND(k) received, per command in time."""
        self.late_latencies_s = []
        """The same for commands that came after their period had begun (applied: none; zero volts)."""
        self.sent_at = np.zeros(scenario.n_samples)
        self.truth = np.full((scenario.n_samples, 7), np.nan)

    def stop(self):
        self.stopped.set()

    def run(self):
        p, s = self.plant, self.scenario
        self.warm_up()
        self.send(self.hello)
        start = self.last_heard = time.monotonic()
        hello_at = start + 1.0
        while not self.stopped.is_set() and self.k < s.n_samples:
            k = self.k
            behind = time.monotonic() - (start + k / self.rate_Hz) if self.rate_Hz else 0.0
            if behind > 1.0 / (self.rate_Hz or math.inf):
                start += behind
                self.counters["overruns"] += 1
            i_a, i_b, i_c, tau_e = plant_outputs(p.x, p.machine)
            m_a, m_b, m_c = sense_currents(i_a, i_b, i_c, p.sensor, p.seed, k)
            if max(abs(m_a), abs(m_b), abs(m_c)) > self.trip_current_A and not self.latched & OVERCURRENT:
                self.latched |= OVERCURRENT
                self.counters["trips"] += 1
            if (self.rate_Hz and time.monotonic() - self.last_heard > HOST_SILENCE_S
                    and not self.latched & HEARTBEAT_LOST):
                self.latched |= HEARTBEAT_LOST
                self.counters["host_silent_trips"] += 1
            status = self.latched | (0 if self.switching() else PWM_OFF)
            status |= COMMAND_MISSING if self.missing else 0
            bad_frames = sum(self.endpoint.errors.values())
            status |= BAD_FRAME if bad_frames > self.bad_frames else 0
            self.bad_frames = bad_frames
            theta_m = p.x[THETA_M]
            encoder = round((theta_m % (2.0 * math.pi)) / (2.0 * math.pi) * 65536.0) % 65536
            status |= ENCODER_VALID if self.encoder else 0
            lsb = self.current_lsb
            telemetry = Telemetry(k % 2 ** 32, _clip16(m_a / lsb), _clip16(m_b / lsb), _clip16(m_c / lsb),
                                  min(65535, round(p.inverter.U_dc_V / self.voltage_lsb)),
                                  encoder if self.encoder else 0, status)
            self.truth[k] = (theta_m, p.x[OMEGA_M], tau_e, self.tau_load[k], i_a, i_b, i_c)
            sent_at = self.sent_at[k] = time.monotonic()
            self.transmit(telemetry)
            if time.monotonic() >= hello_at:
                self.send(self.hello)
                hello_at += 1.0
            deadline = (start + (k + 1) / self.rate_Hz) if self.rate_Hz else sent_at + self.command_wait_s
            command = self.await_command(k, deadline, sent_at)
            if command is None:
                self.missing += 1
                self.counters["missing"] += 1
                if self.missing >= self.watchdog_periods and not self.latched & WATCHDOG:
                    self.latched |= WATCHDOG
                    self.counters["watchdog_trips"] += 1
                u_alpha = u_beta = 0.0
            else:
                self.missing = 0
                self.enabled = bool(command.flags & ENABLE)
                u_alpha, u_beta = command.u_alpha * self.voltage_lsb, command.u_beta * self.voltage_lsb
            if not self.switching():
                u_alpha = u_beta = 0.0
            issue_command(p.line, k, u_alpha, u_beta)
            plant_advance(p.x, *applied_voltage(p.line, k), self.tau_load[k], p.imposed_speed, self.speed_ref[k],
                          p.machine, p.mechanics, p.inverter, p.T_s, p.substeps)
            self.k += 1
            if self.rate_Hz:
                wait = start + (k + 1) / self.rate_Hz - time.monotonic()
                if wait > 0.0:
                    time.sleep(wait)

    def warm_up(self):
        """Load the plant's kernels and the codec on copies before the clock starts, so that the first
        period is not spent compiling."""
        p = self.plant
        x = p.x.copy()
        i_a, i_b, i_c, _ = plant_outputs(x, p.machine)
        sense_currents(i_a, i_b, i_c, p.sensor, p.seed, 0)
        plant_advance(x, 0.0, 0.0, 0.0, p.imposed_speed, 0.0, p.machine, p.mechanics, p.inverter, p.T_s, p.substeps)
        line = p.line.copy()
        issue_command(line, 0, 0.0, 0.0)
        applied_voltage(line, 0)
        encode_frame(Telemetry(0, 0, 0, 0, 0, 0, 0))

    def switching(self):
        return self.enabled and not self.latched

    def await_command(self, k, deadline, sent_at):
        """The command for sample k, handling whatever else arrives, until ``deadline`` (monotonic).
        Waiting for the host, what has arrived is read even when the deadline has passed; on its own
        clock a command read after the deadline is late (zero volts), as a real inverter latches its
        duties at the period's start. What arrived after the command waits in the inbox for the next
        period."""
        while True:
            remaining = max(0.0, deadline - time.monotonic())
            if not self.inbox:
                self.inbox.extend(self.receive(min(remaining, 0.05)))
            while self.inbox:
                message = self.inbox.popleft()
                self.last_heard = time.monotonic()
                if isinstance(message, Command):
                    now = time.monotonic()
                    if message.seq == k % 2 ** 32 and not (self.rate_Hz and now > deadline):
                        self.counters["commands"] += 1
                        self.latencies_s.append(now - sent_at)
                        return message
                    self.counters["discarded"] += 1
                    if message.seq <= k:
                        self.late_latencies_s.append(now - self.sent_at[message.seq])
                elif isinstance(message, Control):
                    if message.action == CONTROL_CLEAR_FAULTS:
                        self.latched = 0
                        self.missing = 0
                    elif message.action == CONTROL_DISABLE:
                        self.enabled = False
                    elif message.action == CONTROL_SEND_HELLO:
                        self.send(self.hello)
            if remaining <= 0.0 or self.stopped.is_set():
                return None

    def send(self, message):
        """Send, or lose the frame while the link is down (an unplugged cable, a bus being reopened)."""
        try:
            self.endpoint.send(message)
        except LinkDown:
            self.counters["link_down"] += 1

    def receive(self, timeout_s):
        try:
            return self.endpoint.receive(timeout_s)
        except LinkDown:
            time.sleep(timeout_s)
            return []

    def transmit(self, telemetry):
        """Send a telemetry frame through the fault plan: on a byte link (pty) the encoded frame, on CAN
        the message; corruption and garbage exist on byte links only (CAN's own CRC would turn them
        into error frames, which never arrive)."""
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
            return
        if byte_link and due(f.corrupt_every, "corrupted"):
            frame[int(self.random.integers(0, len(frame) - 1))] ^= 0x5A
        if byte_link and due(f.garbage_every, "garbage"):
            self.endpoint.send_bytes(bytes(self.random.integers(1, 256, 7, dtype=np.uint8)) + b"\x00")
        if self.held_back is None and due(f.reorder_every, "reordered"):
            self.held_back = bytes(frame) if byte_link else telemetry
            return
        emit(item)
        if self.held_back is not None:
            emit(self.held_back)
            self.held_back = None
        if due(f.duplicate_every, "duplicated"):
            emit(item)


def make_links(link, workdir, drive_id=0, channel=None):
    """(inverter endpoint, host link) of a fresh virtual link: a pty whose slave the host opens by a
    symlink in ``workdir``, or a CAN channel (python-can's virtual bus unless SocketCAN has it)."""
    if link == "pty":
        endpoint = PtyEndpoint(Path(workdir) / f"inverter{drive_id}")
        return endpoint, SerialLink(endpoint.link_path)
    if link == "can":
        channel = channel or f"drive_bridge_{id(workdir)}"
        endpoint = CanLink(channel, drive_id)
        endpoint.open()
        return endpoint, CanLink(channel, drive_id)
    raise ValueError(f"unknown virtual link '{link}' (known: {', '.join(LINKS)})")


LATENCY_BINS_PER_PERIOD = (0.0, 0.25, 0.5, 0.75, 1.0, 2.0, 5.0, 10.0, math.inf)
"""Edges of the command latency histogram, in sampling periods: below 1 a command can be in time."""


def timing_report(inverter, T_s):
    """How the host kept pace with a virtual inverter: periods run, commands missing (late or never
    sent: zero volts), their fraction, latency percentiles [µs] over every command that came (late ones
    included) and the histogram of those latencies (edges in sampling periods and µs)."""
    every = np.concatenate([inverter.latencies_s, inverter.late_latencies_s]) * 1e6
    edges = np.asarray(LATENCY_BINS_PER_PERIOD)
    counts, _ = np.histogram(every, bins=edges * T_s * 1e6)
    return {"paced": bool(inverter.rate_Hz), "periods": inverter.k, "missing": inverter.counters["missing"],
              "late_fraction": inverter.counters["missing"] / max(inverter.k, 1),
              "late_arrivals": len(inverter.late_latencies_s),
              "latency_p50_us": float(np.percentile(every, 50)) if every.size else None,
              "latency_p99_us": float(np.percentile(every, 99)) if every.size else None,
              "latency_max_us": float(every.max()) if every.size else None,
              "latency_histogram": {"edges_periods": [float(e) if math.isfinite(e) else None for e in edges],
                                    "counts": [int(c) for c in counts]},
              "watchdog_trips": inverter.counters["watchdog_trips"], "overruns": inverter.counters["overruns"],
              "host_silent_trips": inverter.counters["host_silent_trips"]}
