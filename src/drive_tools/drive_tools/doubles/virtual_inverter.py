"""A virtual inverter: the plant core (motor, inverter, current sensors, the scenario's load or
dynamometer) behind the inverter protocol, on a pseudo-terminal or a CAN bus. It keeps an inverter's
duties (docs/inverter-protocol.md): telemetry at each period start (with blocks of N samples, at the
block's last sample), the command of sample k applied during period k + 1 (k + 2N with blocks), zero
volts for a missing command, PWM off after ``watchdog_periods`` missing ones
or 100 ms without the host, and an overcurrent trip. PWM off is modelled as zero volts.

Clock: ``rate_Hz`` paces the periods in wall time (a real inverter's clock; a late command is missing,
late by when this thread read it or, as a device, by when the host wrote it: ``hear_host_writes``;
100 ms of host silence trips; a block the simulation itself sends more than a period late is an overrun,
and the clock restarts there); without it the inverter waits up to ``command_wait_s`` for each command
(lock-step over the link, for simulations faster or slower than real time; a missing command is one
that did not come within that wait, and host silence is left to the watchdog)."""
import collections
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from drive_bridge.inverter_link import LinkDown
from drive_bridge.inverter_protocol import (
    BAD_FRAME,
    COMMAND_MISSING,
    CONTROL_CLEAR_FAULTS,
    CONTROL_DISABLE,
    CONTROL_SEND_HELLO,
    ENABLE,
    ENCODER_VALID,
    FREEWHEELING,
    HEARTBEAT_LOST,
    HELLO_ENCODER_PRESENT,
    HELLO_INDEX_INPUT,
    HELLO_SAFE_STATES,
    INDEX_TOGGLE,
    MAX_BLOCK,
    OVERCURRENT,
    OVERVOLTAGE,
    PWM_OFF,
    SAFE_AUTO,
    SHORT_CIRCUIT,
    WATCHDOG,
    Command,
    CommandBlock,
    Control,
    Hello,
    Telemetry,
    TelemetryBlock,
    decode_frame,
    encode_frame,
    requested_safe_state,
)
from drive_common.config.scenario import behind_an_inverter
from drive_common.math.command_delay import issue_command
from drive_common.math.safe_state import ASC, FREEWHEEL, PWM, overvoltage_trip_V
from drive_common.motor.nameplate import trip_current_A as default_trip_current_A
from pmsm_plant.build import plant_for_scenario
from pmsm_plant.model import INVERTER_MODE, bus_voltage, plant_block

CAUGHT_UP_POLL_S = 0.0005
"""Lock-step: how often the host's catching up is looked at (hear_host_caught_up)."""
HOST_SILENCE_S = 0.1
"""Nothing from the host for this long: PWM off, HEARTBEAT_LOST latched (the protocol's 100 ms)."""


@dataclass(frozen=True)
class InverterOptions:
    """How a virtual inverter runs: ``rate_Hz`` its clock (None: lock-step, waiting up to ``command_wait_s``
    [s] for each command; ``disabled_wait_s`` instead until the host's first command and after it said CONTROL
    disable, until it commands again: None, the same), ``watchdog_periods`` missing commands in a row that switch
    PWM off (None: 10
    periods, three blocks with blocks), ``trip_current_A`` its overcurrent trip (None: the nameplate's),
    ``drive_id`` on the link, ``encoder`` whether it has one, ``clock`` its clock [s] (a test's virtual
    clock paces it without the machine's pace)."""

    rate_Hz: float = None
    command_wait_s: float = 0.5
    disabled_wait_s: float = None
    watchdog_periods: int = None
    trip_current_A: float = None
    drive_id: int = 0
    encoder: bool = True
    clock: Callable[[], float] = time.monotonic


def _clip16(value):
    return int(max(-32768, min(32767, round(value))))


class VirtualInverter:
    """The plant of ``scenario`` behind the protocol on ``endpoint`` (a PtyEndpoint, drive_tools.doubles.virtual_links,
    or an opened CanLink), run as ``options`` say; ``start`` (a thread), ``stop`` to end, ``join``. With the scenario's
    ``block_samples`` N > 1 it announces N in HELLO, sends TELEMETRY_BLOCK and takes COMMAND_BLOCK (the
    command answering sample k acts in period k + 2N: docs/inverter-protocol.md; ScenarioError for what
    cannot run behind an inverter, drive_common.config.scenario.behind_an_inverter). ``truth`` holds θ_m,
    ω_m, τ_e, τ_load and the true currents per sample for scoring, ``modes`` the bridge's mode in the period
    before each sample (drive_common.math.safe_state: PWM, FREEWHEEL, ASC)."""

    def __init__(self, scenario, endpoint, options=InverterOptions()):
        self.clock = options.clock
        """The inverter's clock [s] (a test double's virtual clock paces it without the machine's pace)."""
        scenario = behind_an_inverter(scenario, MAX_BLOCK)
        self.plant = plant_for_scenario(scenario)
        self.speed_ref, self.tau_load = scenario.schedule()
        self.scenario = scenario
        self.block_samples = scenario.block_samples
        self.delay = scenario.drive_delay_periods()
        self.endpoint = endpoint
        self.rate_Hz, self.command_wait_s = options.rate_Hz, options.command_wait_s
        self.disabled_wait_s = options.disabled_wait_s
        self.commanding = False
        """Lock-step: the host commands (a command message heard since its last CONTROL disable)."""
        self.watchdog_periods = options.watchdog_periods or max(10, 3 * self.block_samples)
        """Missing commands in a row that switch PWM off (default 10 periods, three blocks with blocks)."""
        self.trip_current_A = options.trip_current_A or default_trip_current_A(scenario.motor.nameplate)
        self.encoder = encoder = options.encoder
        drive_id = options.drive_id
        self.current_lsb = float(np.float32(2.0 * self.trip_current_A / 32767.0))
        self.voltage_lsb = float(np.float32(2.0 * self.plant.inverter.U_dc_V / 32767.0))
        self.hello = Hello(drive_id, (HELLO_ENCODER_PRESENT if encoder else 0) | HELLO_SAFE_STATES | HELLO_INDEX_INPUT,
                           self.plant.machine.n_p, self.block_samples, round(scenario.T_s * 1e9), self.current_lsb,
                           self.voltage_lsb, float(np.float32(self.trip_current_A)), self.watchdog_periods)
        self.k = 0
        self.index_turn, self.index_pulses = None, 0
        """The index input: a pulse each time the shaft's true mechanical angle passes a whole turn (θ_m ≡ 0 mod 2π);
        the turn of the last sample sent and the pulses so far (the status's INDEX_TOGGLE: their parity)."""
        self.clock_start = 0.0
        self.enabled = False
        self.latched = 0
        self.overvoltage_V = overvoltage_trip_V(scenario.motor.inverter)
        self.safe_request = SAFE_AUTO
        """The safe state the host's last command asked for (its flags)."""
        self.shorting = False
        """In SAFE_AUTO: the link rose past the trip level while freewheeling (the diodes rectifying a
        back-EMF above it): short the winding instead, until the faults are cleared."""
        self.missing = 0
        self.missing_in_block = False
        """A period of the block being sent (from its first sample's to its last's) had no command in
        time: COMMAND_MISSING in its status."""
        self.decided = 0
        """Periods before this one have their voltage in the plant's delay line."""
        self.last_heard = self.clock()
        self.commands = {}
        """sample → (u_α [V], u_β [V], flags, when read [monotonic s]) of each command received and not yet
        applied."""
        self.bad_frames = 0
        self.sent_frames = 0
        self.stopped = threading.Event()
        self.worker = None
        self.counters = {"commands": 0, "missing": 0, "discarded": 0, "trips": 0, "watchdog_trips": 0,
                         "host_silent_trips": 0, "overvoltage_trips": 0, "link_down": 0, "overruns": 0,
                         "sent_late": 0, "read_late": 0}
        """commands: samples whose command came in time. overruns: blocks the simulated inverter itself
        sent more than a period behind its clock (its Python simulation, not the host, was slow); its
        clock then restarts from that moment, as the host cannot be blamed for periods a real inverter's
        timer would have kept. sent_late: periods whose command came after the start of its first period
        on the clock, but within the host's window from when the simulation sent its telemetry late.
        read_late: periods whose command this thread read after its deadline, but that had arrived in time
        by the host's write time (``hear_host_writes``)."""
        self.host_written_at = None
        self.host_caught_up = None
        """k → when the host finished writing the command answering sample k (monotonic s, NaN: unknown),
        or None: a command arrives when this thread reads it."""
        wire_time_s = getattr(endpoint, "wire_time_s", None)
        full = CommandBlock(0, ENABLE, ((0, 0),) * self.block_samples) if self.block_samples > 1 else Command(
            0, 0, 0, ENABLE)
        self.command_wire_s = wire_time_s(full) if wire_time_s else 0.0
        """A full command message's time on the wire of the real link this one stands for [s]."""
        self.heard_up_to = -1
        """The last sample answered by a command message heard (in time or not, lost or kept)."""
        self.lost_on_the_way = set()
        """First samples of the telemetry frames lost on the way (by a faulty double, drive_tools.doubles.faults:
        dropped, corrupted, held back): in lock-step their answers are not waited for, since the host cannot
        send them in time."""
        self.started = False
        """A command came in time: the drive runs, and the watchdog counts."""
        self.started_at, self.missing_at_start = None, 0
        """The period of the first command in time, and the commands missing before it (a drive armed on a running
        inverter, drive_tools.launch.axis, starts after many)."""
        self.before_start = 0
        """Periods without a command before the drive started (PWM off; docs/inverter-protocol.md)."""
        self.missing_runs = []
        """[first period, periods, telemetry sent, command due, command's sample, host wrote it] of each run of
        periods in a row without a command in time; sent and due (monotonic s, paced only; else 0) are the
        window its first command had; when the host wrote it (``hear_host_writes``; NaN when it had not by
        the time the run's first period was decided) is taken then, as the host keeps its write times for a
        few seconds only."""
        self.latencies_s = []
        """Time from TELEMETRY(_BLOCK) sent to its COMMAND(_BLOCK) received, per command message in time."""
        self.late_latencies_s = []
        """The same for command messages that came after their first period had begun (zero volts)."""
        self.answers_s = []
        """As a device (``hear_host_writes``), once the drive started: per command message the host wrote,
        the time from its telemetry sent to the host's write of it (the host's answer, the wire not
        included)."""
        self.unanswered = collections.deque()
        """Samples starting a command message whose answer time is not known yet (not written when decided)."""
        self.never_answered = 0
        """Command messages after the start the host had not written HOST_SILENCE_S after their telemetry."""
        self.sent_at = np.zeros(scenario.n_samples)
        self.sent_late_s = np.zeros(scenario.n_samples)
        """Per sample: how late on its clock the simulation sent its telemetry [s] (under a period; more is
        an overrun, and the clock restarts)."""
        self.truth = np.full((scenario.n_samples, 7), np.nan)
        self.modes = np.full(scenario.n_samples, PWM, dtype=np.int8)

    def stop(self):
        self.stopped.set()

    def start(self):
        """Run on a thread of its own."""
        self.worker = threading.Thread(target=self.run, name="virtual_inverter", daemon=True)
        self.worker.start()

    def is_alive(self):
        return self.worker is not None and self.worker.is_alive()

    def ran_out(self):
        """Started and its thread ended: its last period is sent (or it stopped, or failed); nothing more comes."""
        return self.worker is not None and not self.worker.is_alive()

    def join(self, timeout_s):
        if self.worker is not None:
            self.worker.join(timeout_s)

    def run(self):
        """Blocks of N samples (one sample without blocks): the voltages of the periods before them
        decided from the commands received (zero volts for a missing one), the plant simulated through
        them, the block's own last period decided and the block sent at its last sample's period start
        (``rate_Hz``) or as soon as the commands it needs came (lock-step)."""
        s, N = self.scenario, self.block_samples
        period = 1.0 / self.rate_Hz if self.rate_Hz else 0.0
        out = np.zeros((N, 10))
        self.warm_up(out)
        self.send(self.hello)
        self.clock_start = self.last_heard = self.clock()
        hello_at = self.clock_start + 1.0
        while not self.stopped.is_set() and self.k < s.n_samples:
            k0 = self.k
            n = min(N, s.n_samples - k0)
            k_last = k0 + n - 1
            self.missing_in_block = False
            self.take_commands(k_last - 1)
            self.simulate(k0, n, out)
            self.take_commands(k_last)
            if self.stopped.is_set():
                break
            late = self.clock() - (self.clock_start + k_last * period) if self.rate_Hz else 0.0
            if late > period:
                self.clock_start += late
                self.counters["overruns"] += 1
                late = 0.0
            self.sent_late_s[k0:k0 + n] = max(late, 0.0)
            self.send_samples(k0, n, out)
            if self.clock() >= hello_at:
                self.send(self.hello)
                hello_at += 1.0
            self.k = k0 + n

    def take_commands(self, j_last):
        """Decide the voltages of the periods up to j_last: what the host sends is taken until period
        j_last begins or its command's deadline passed, whichever is later (``rate_Hz``; as a device also
        the commands the host wrote in time that this thread has not read yet), or until the commands
        acting in them came (lock-step)."""
        if self.rate_Hz:
            until = self.clock_start + j_last / self.rate_Hz
            c_last = j_last - self.delay
            self.receive_until(max(until, self.deadline(c_last)) if c_last >= 0 else until)
            if self.host_written_at is not None:
                self.receive_written(range(max(self.decided - self.delay, 0), min(c_last + 1, self.k)))
        else:
            self.await_commands(self.decided - self.delay, j_last + 1 - self.delay)
        for j in range(max(self.decided, self.delay), j_last + 1):
            issue_command(self.plant.line, j - self.delay, *self.decide(j))
        self.decided = max(self.decided, j_last + 1)

    def warm_up(self, out):
        """Load the plant's kernels and the codec on copies before the clock starts, so that the first
        period is not spent compiling."""
        p = self.plant
        line = p.line.copy()
        issue_command(line, 0, 0.0, 0.0)
        plant_block(p.x.copy(), line, 1, 1, p.inputs(self.tau_load, self.speed_ref), p.params, out)
        encode_frame(Telemetry(0, 0, 0, 0, 0, 0, 0))
        encode_frame(TelemetryBlock(0, 0, 0, ((0, 0, 0, 0),)))
        decode_frame(encode_frame(Command(0, 0, 0, 0))[:-1])

    def switching(self):
        return self.enabled and not self.latched

    def hear_host_writes(self, written_at):
        """Judge a command by when it reached this device, not by when this thread read it: when the host
        finished writing it (``written_at(k)``, the host bridge's InverterBridge.written_at on the same
        machine, monotonic s) plus its time on the link's wire, as a real inverter's receive buffer takes it
        (docs/bridge.md, "As a device"). Paced only."""
        self.host_written_at = written_at

    def arrived(self, c):
        """When the command answering sample c reached the device by the host's write time [monotonic s];
        inf when that is not known."""
        if self.host_written_at is None:
            return math.inf
        at = self.host_written_at(c) + self.command_wire_s
        return at if math.isfinite(at) else math.inf

    def in_time(self, c, read_at):
        """Whether the command answering sample c, read by this thread at ``read_at`` (inf: never), came in
        time (``arrival``), counting the simulation's share; called once per period, when it is decided
        (after the host has noted its write)."""
        how = self.arrival(c, read_at)
        if how in ("sent_late", "read_late"):
            self.counters[how] += 1
        return how is not None

    def arrival(self, c, read_at):
        """How the command answering sample c, read at ``read_at`` (inf: never), came in time: "read" (by
        its deadline; lock-step: it came), "sent_late" (by its deadline, only because the simulation sent the
        telemetry late), "read_late" (read after its deadline, but arrived by then by the host's write time);
        None: late, or never."""
        if not self.rate_Hz:
            return "read" if math.isfinite(read_at) else None
        due = self.deadline(c)
        if read_at <= due:
            return "sent_late" if 0 <= c < self.k and read_at > due - self.sent_late_s[c] else "read"
        if math.isfinite(read_at) and self.arrived(c) <= due:
            return "read_late"
        return None

    def deadline(self, c):
        """When the command answering sample c must have arrived [monotonic s]: the host's window (N + 1
        periods with blocks, one without) after its telemetry left. That is the start of the first period
        the message acts in, on the clock the telemetry was sent by; a simulation that sent it late does not
        shorten the window, nor does a later restart of its clock lengthen it. A sample not sent yet: that
        period's start on the clock as it is."""
        N = self.block_samples
        first = c - c % N
        if 0 <= first < self.k:
            return float(self.sent_at[first]) + (self.delay - N + 1) / self.rate_Hz
        return self.clock_start + (first + self.delay) / self.rate_Hz

    def decide(self, j):
        """The voltage of period j [V, αβ]: command(j − d) if it came in time and the bridge switches, else
        zero (a missing command counts; the watchdog trips after ``watchdog_periods`` in a row). The drive
        starts with the first command in time: periods before it, within ``watchdog_periods`` of the first
        a command can act in, have PWM off and count as before the start, not as missing."""
        c = j - self.delay
        u_alpha, u_beta, flags, read_at = self.commands.pop(c, (0.0, 0.0, 0, math.inf))
        in_time = self.in_time(c, read_at)
        if self.host_written_at is not None and self.started and 0 <= c < self.k and c % self.block_samples == 0:
            self.unanswered.append(c)
            self.note_answers()
        if not in_time and not self.started and j < self.delay + self.watchdog_periods:
            self.before_start += 1
            return 0.0, 0.0
        if in_time:
            if not self.started:
                self.started_at, self.missing_at_start = j, self.counters["missing"]
            self.started = True
            self.missing = 0
            self.enabled = bool(flags & ENABLE)
            self.safe_request = requested_safe_state(flags)
            self.counters["commands"] += 1
        else:
            if self.missing == 0:
                window = (float(self.sent_at[c]), self.deadline(c)) if self.rate_Hz and 0 <= c < self.k else (0.0, 0.0)
                written = self.host_written_at(c) if self.host_written_at is not None and c >= 0 else math.nan
                self.missing_runs.append([j, 0, *window, c, float(written)])
            self.missing_runs[-1][1] += 1
            self.missing += 1
            self.missing_in_block = True
            self.counters["missing"] += 1
            if self.missing >= self.watchdog_periods and not self.latched & WATCHDOG:
                self.latched |= WATCHDOG
                self.counters["watchdog_trips"] += 1
            u_alpha = u_beta = 0.0
        return (u_alpha, u_beta) if self.switching() else (0.0, 0.0)

    def note_answers(self, final=False):
        """The answer times of the command messages waiting in ``unanswered`` that the host has written, in
        order; one not written HOST_SILENCE_S after its telemetry (or at the run's end, ``final``) counts as
        never answered."""
        while self.unanswered:
            c = self.unanswered[0]
            written = self.host_written_at(c)
            if math.isfinite(written):
                self.answers_s.append(written - self.sent_at[c])
            elif final or self.clock() - self.sent_at[c] > HOST_SILENCE_S:
                self.never_answered += 1
            else:
                return
            self.unanswered.popleft()

    def bridge_mode(self):
        """The bridge's mode for the next block (drive_common.math.safe_state): PWM while it switches, and before
        the drive's start (the plant's zero volts, as ever); once stopped, the safe state the host asked
        for, or its own choice: freewheel, and the short circuit once the link rose past its trip level
        freewheeling."""
        if self.switching() or not self.started:
            return PWM
        if self.safe_request != SAFE_AUTO:
            return self.safe_request
        return ASC if self.shorting else FREEWHEEL

    def simulate(self, k0, n, out):
        """Samples k0 … k0 + n − 1 into ``out``, each period before them under its decided voltage (or in
        the safe state, ``bridge_mode``); an overcurrent sensed at a sample switches PWM off from that
        sample's period on (the block is simulated again from its start with zero volts there); a bus above
        the trip level at the block's end latches OVERVOLTAGE, the safe state from the next block on."""
        p = self.plant
        if self.rate_Hz and self.clock() - self.last_heard > HOST_SILENCE_S and not self.latched & HEARTBEAT_LOST:
            self.latched |= HEARTBEAT_LOST
            self.counters["host_silent_trips"] += 1
        p.x[INVERTER_MODE] = self.bridge_mode()
        x0 = p.x.copy()
        while True:
            plant_block(p.x, p.line, k0, n, p.inputs(self.tau_load, self.speed_ref), p.params, out)
            over = np.flatnonzero(np.abs(out[:n, 3:6]).max(axis=1) > self.trip_current_A)
            if self.latched & OVERCURRENT or not over.size:
                break
            self.latched |= OVERCURRENT
            self.counters["trips"] += 1
            for j in range(max(self.delay, k0 + int(over[0])), k0 + n - 1):
                issue_command(p.line, j - self.delay, 0.0, 0.0)
            p.x[:] = x0
        if bus_voltage(p.x, p.inverter) > self.overvoltage_V:
            if not self.latched & OVERVOLTAGE:
                self.latched |= OVERVOLTAGE
                self.counters["overvoltage_trips"] += 1
            self.shorting = self.shorting or p.x[INVERTER_MODE] == FREEWHEEL

    def status(self):
        """The status word of the block being sent."""
        mode = self.plant.x[INVERTER_MODE]
        status = self.latched | (0 if self.switching() else PWM_OFF)
        status |= FREEWHEELING if mode == FREEWHEEL else SHORT_CIRCUIT if mode == ASC else 0
        status |= COMMAND_MISSING if self.missing_in_block else 0
        bad_frames = sum(self.endpoint.errors.values())
        status |= BAD_FRAME if bad_frames > self.bad_frames else 0
        self.bad_frames = bad_frames
        status |= INDEX_TOGGLE if self.index_pulses % 2 else 0
        return status | (ENCODER_VALID if self.encoder else 0)

    def send_samples(self, k0, n, out):
        """TELEMETRY of sample k0 (TELEMETRY_BLOCK of samples k0 … with blocks), the truth kept."""
        lsb = self.current_lsb
        samples = []
        for i in range(n):
            row = out[i]
            encoder = round((row[6] % (2.0 * math.pi)) / (2.0 * math.pi) * 65536.0) % 65536 if self.encoder else 0
            samples.append((_clip16(row[3] / lsb), _clip16(row[4] / lsb), _clip16(row[5] / lsb), encoder))
            self.truth[k0 + i] = (row[6], row[7], row[8], row[9], row[0], row[1], row[2])
            turn = math.floor(row[6] / (2.0 * math.pi))
            if self.index_turn is not None:
                self.index_pulses += abs(turn - self.index_turn)
            self.index_turn = turn
        self.modes[k0:k0 + n] = self.plant.x[INVERTER_MODE]
        u_dc = min(65535, round(bus_voltage(self.plant.x, self.plant.inverter) / self.voltage_lsb))
        status = self.status()
        if self.block_samples > 1:
            message = TelemetryBlock(k0 % 2 ** 32, u_dc, status, tuple(samples))
        else:
            i_a, i_b, i_c, encoder = samples[0]
            message = Telemetry(k0 % 2 ** 32, i_a, i_b, i_c, u_dc, encoder, status)
        self.sent_at[k0:k0 + n] = self.clock()
        self.transmit(message, k0)

    def receive_until(self, until):
        """Take what the host sends until ``until`` (monotonic)."""
        while not self.stopped.is_set():
            remaining = until - self.clock()
            if remaining <= 0.0:
                return
            for message in self.receive(min(remaining, 0.05)):
                self.handle(message)

    def receive_written(self, samples):
        """Take the commands answering ``samples`` that arrived in time by the host's write time and that
        this thread has not read yet (the link's kernel or this thread was slow), each for at most
        HOST_SILENCE_S."""
        for c in samples:
            if c in self.commands or self.heard_up_to >= c or not self.arrived(c) <= self.deadline(c):
                continue
            until = self.clock() + HOST_SILENCE_S
            while (c not in self.commands and self.heard_up_to < c and self.clock() < until
                   and not self.stopped.is_set()):
                for message in self.receive(min(until - self.clock(), 0.05)):
                    self.handle(message)

    def await_commands(self, first, last):
        """Lock-step: wait until the commands answering samples first … last − 1 came, or a command message
        answering that sample or a later one was heard (the link keeps order: one lost on the way, by a
        faulty double, is not waited for), each at most ``command_wait_s`` after its telemetry was sent; nor is
        the answer to telemetry lost on the way (``lost_on_the_way``). What arrived by then is taken even when
        this thread could not run until after it (a loaded machine, another thread holding the interpreter). The
        outcome then does not depend on the machine's pace, only on what the host sent. While the host does not
        command (none heard yet, or none since it said CONTROL disable) the wait is ``disabled_wait_s`` where
        given: the simulation of a disarmed drive goes on at that pace."""
        N = self.block_samples
        for c in range(max(0, first), min(last, self.k)):
            if c - c % N in self.lost_on_the_way:
                continue
            while (c not in self.commands and self.heard_up_to < c and self.clock() < self.waits_until(c)
                   and not self.stopped.is_set()):
                for message in self.receive(min(self.waits_until(c) - self.clock(), 0.05)):
                    self.handle(message)
            while c not in self.commands and self.heard_up_to < c and not self.stopped.is_set():
                arrived = self.receive(0.0)
                if not arrived:
                    break
                for message in arrived:
                    self.handle(message)
        if self.host_caught_up is not None and last > first:
            deadline = self.clock() + self.command_wait_s
            while not self.host_caught_up(last - 1) and self.clock() < deadline and not self.stopped.is_set():
                time.sleep(CAUGHT_UP_POLL_S)

    def hear_host_caught_up(self, caught_up):
        """Lock-step: wait also until ``caught_up(c)`` says the host has done all it does with the sample c its
        command answers (a compiled answer's reader: the topics published, the next command decided), at most
        ``command_wait_s``: the simulation waits for the whole drive, whose outcome then does not depend on how far
        the side that is not real-time lags on this machine."""
        self.host_caught_up = caught_up

    def waits_until(self, c):
        """Lock-step: until when the command answering sample c is waited for [s of the clock]: ``command_wait_s``
        after its telemetry was sent, ``disabled_wait_s`` (where given) while the host does not command (a CONTROL
        disable heard meanwhile ends a longer wait)."""
        wait = self.command_wait_s if self.commanding or self.disabled_wait_s is None else self.disabled_wait_s
        return self.sent_at[c] + wait

    def handle(self, message):
        """A message from the host: a command stored for its period with when it was read (whether in
        time is judged when its period is decided: ``in_time``; once per sample: a repeat or one for a
        period already decided is discarded), a CONTROL carried out."""
        now = self.last_heard = self.clock()
        if isinstance(message, (Command, CommandBlock)):
            self.commanding = True
            if isinstance(message, Command):
                seq, values = message.seq, ((message.u_alpha, message.u_beta),)
            else:
                seq, values = message.seq, message.samples
            c0 = seq + (self.k // 2 ** 32) * 2 ** 32
            if c0 > self.k + 2 ** 31:
                c0 -= 2 ** 32
            if 0 <= c0 <= self.k:
                self.heard_up_to = max(self.heard_up_to, c0 + len(values) - 1)
            self.take_command(c0, values, message.flags, now)
        elif isinstance(message, Control):
            if message.action == CONTROL_CLEAR_FAULTS:
                self.latched = 0
                self.missing = 0
                self.shorting = False
            elif message.action == CONTROL_DISABLE:
                self.enabled = self.commanding = False
            elif message.action == CONTROL_SEND_HELLO:
                self.send(self.hello)

    def take_command(self, c0, values, flags, now):
        """Store the voltages of a command message heard at ``now`` [monotonic s] answering samples c0 … (each
        (u_α, u_β) in the protocol's integers) for their periods, with their latency; one for periods already
        decided or already answered is discarded."""
        in_time = self.arrival(c0, now) is not None
        fresh = [c for c in range(c0, c0 + len(values))
                 if 0 <= c < self.k and c + self.delay >= self.decided and c not in self.commands]
        if fresh:
            (self.latencies_s if in_time else self.late_latencies_s).append(now - self.sent_at[fresh[0]])
        else:
            self.counters["discarded"] += 1
            if 0 <= c0 < self.k:
                self.late_latencies_s.append(now - self.sent_at[c0])
            return
        lsb = self.voltage_lsb
        for c, (u_alpha, u_beta) in zip(range(c0, c0 + len(values)), values):
            if c in fresh:
                self.commands[c] = (u_alpha * lsb, u_beta * lsb, flags, now)

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

    def transmit(self, telemetry, k0):
        """Send the telemetry frame of samples k0 …: on a byte link (pty) the encoded frame, on CAN the
        message."""
        self.sent_frames += 1
        if hasattr(self.endpoint, "send_bytes"):
            self.endpoint.send_bytes(encode_frame(telemetry))
        else:
            self.send(telemetry)
