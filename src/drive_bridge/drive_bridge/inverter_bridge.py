"""The host side of the inverter link (no rclpy): telemetry in SI units with its sample counter,
commands out, every dropped or odd frame counted, link loss and a silent graph answered with the safe
state (docs/inverter-protocol.md, "The host"). The ROS node and the one-process loop both use it."""
import math
import threading
import time
from collections.abc import MutableMapping
from dataclasses import dataclass

import numpy as np

from . import compiled_bridge as cb
from .inverter_link import LinkDown
from .inverter_protocol import (
    CLEARED_BY_HOST,
    COMMAND_MISSING,
    CONTROL_CLEAR_FAULTS,
    CONTROL_DISABLE,
    CONTROL_SEND_HELLO,
    OVERCURRENT,
    OVERVOLTAGE,
    PWM_OFF,
    SAFE_AUTO,
    STATUS_NAMES,
    Command,
    CommandBlock,
    Control,
    Hello,
    Telemetry,
    TelemetryBlock,
    command_flags,
    decode_frame,
    encode_frame,
)

LINK_TIMEOUT_S = 0.05
COMMAND_TIMEOUT_S = 0.05
RECONNECT_S = 0.1
WRITES_KEPT = 16384
"""Command messages whose write time the bridge keeps (a ring, allocated once, 256 KiB): 16 s of blocks of
10 at 10 kHz, longer than any paced benchmark's run."""


@dataclass(frozen=True)
class BridgeSample:
    k: int
    """Sample counter, unwrapped past 2³²."""
    i_a: float
    i_b: float
    i_c: float
    """Phase currents [A]."""
    u_dc_V: float
    theta_m: float
    """Encoder angle, continuous [rad, mechanical]; NaN without a valid encoder."""
    status: int


@dataclass(frozen=True, eq=False)
class BridgeBlock:
    """Consecutive samples k0 … k0 + n − 1 as one TELEMETRY_BLOCK (or one TELEMETRY: n = 1) brought them."""

    k0: int
    currents_A: np.ndarray
    """(n, 3) phase currents i_a, i_b, i_c [A]."""
    theta_m: np.ndarray
    """(n,) encoder angle, continuous [rad, mechanical]; NaN without a valid encoder."""
    u_dc_V: float
    status: int
    """The inverter's status word (a block's: as at its last sample)."""

    def __len__(self):
        return len(self.theta_m)

    @property
    def at_zero_volts(self):
        """True when the periods k0 … k0 + n − 1 ran at zero volts, not as commanded: the inverter reports a
        command missing or PWM off (docs/inverter-protocol.md, "Timing"; a block's status covers all its
        periods)."""
        return bool(self.status & (COMMAND_MISSING | PWM_OFF))

    def samples(self):
        """The block sample by sample."""
        return [BridgeSample(self.k0 + i, i_a, i_b, i_c, self.u_dc_V, theta, self.status)
                for i, ((i_a, i_b, i_c), theta) in enumerate(zip(self.currents_A.tolist(), self.theta_m.tolist()))]


def written_at(written, block_samples, k):
    """When the command answering sample k was written to the link (monotonic s) by the ring of writes ``written``
    (InverterBridge.written) of blocks of ``block_samples``; NaN when it was not, or is no longer kept."""
    k0 = k - k % block_samples
    first, at = written[(k0 // block_samples) % written.shape[0]]
    return at if first == k0 else math.nan


def _state_field(index, kind, unset=math.nan):
    """An InverterBridge attribute held in its ``state`` array at ``index``, as ``kind`` (``unset`` for NaN)."""
    def get(self):
        value = self.state[index]
        return unset if math.isnan(value) else kind(value)

    def set(self, value):
        self.state[index] = math.nan if value is None else float(value)
    return property(get, set)


class Counters(MutableMapping):
    """InverterBridge.counters: its counter array (compiled_bridge.COUNTERS) by name, as ints."""

    def __init__(self, array):
        self.array = array

    def __getitem__(self, name):
        return int(self.array[cb.C[name]])

    def __setitem__(self, name, value):
        self.array[cb.C[name]] = value

    def __delitem__(self, name):
        raise TypeError("a bridge's counters are fixed")

    def __iter__(self):
        return iter(cb.COUNTERS)

    def __len__(self):
        return len(cb.COUNTERS)


class InverterBridge:
    """One inverter behind ``link`` (SerialLink or CanLink) that sends blocks of ``block_samples``
    samples (1: TELEMETRY per sample). ``poll`` from one thread, ``command`` and ``command_block`` from
    any; they never raise on link trouble, they count it. An inverter announcing another block size is
    counted (``block_mismatch``) and named, and its telemetry not taken. ``answer_wait_s`` > 0: an inverter in
    lock-step (a virtual one that sends its next block only once answered): while the host owes an answer (telemetry
    taken after its last command) the link is lost only after link_timeout_s + answer_wait_s (a slow drive is not a
    silent link); once it has answered, after link_timeout_s from its answer (a simulation that ended is seen at
    once); the compiled answer's check (compiled_bridge.check_silence) keeps the same rule by the times of the last
    telemetry and the last command."""

    def __init__(self, link, link_timeout_s=LINK_TIMEOUT_S, command_timeout_s=COMMAND_TIMEOUT_S,
                 reconnect_s=RECONNECT_S, block_samples=1, answer_wait_s=0.0):
        self.link = link
        self.block_samples = block_samples
        self.link_timeout_s, self.command_timeout_s = link_timeout_s, command_timeout_s
        self.answer_wait_s = answer_wait_s
        self.received_k0 = self.answered_k0 = -1
        """The first sample of the last telemetry block taken, and of the last block answered."""
        self.reconnect_s = reconnect_s
        self.state, self.counter_array = cb.bridge_state(block_samples, link_timeout_s, command_timeout_s,
                                                         answer_wait_s)
        """Its state and counters as arrays (compiled_bridge.STATE, COUNTERS), the attributes below views of
        them: the telemetry is taken by the kernel the compiled answer runs (compiled_bridge.accept_telemetry),
        which changes them in place."""
        self.counters = Counters(self.counter_array)
        self.telemetry = cb.telemetry_arrays(self.state, self.counter_array)
        decode_frame(encode_frame(Telemetry(0, 0, 0, 0, 0, 0, 0))[:-1])
        """The codec's kernels loaded (or compiled, without a cache: seconds) before any inverter runs, not at the
        first frame read while a lock-step inverter waits for the first command."""
        self._hello = None
        self.open = False
        self.last_error = ""
        self.next_open_at = 0.0
        self.part = None
        """The first samples of a block whose rest has not come yet (CAN FD frames)."""
        self.send_lock = threading.Lock()
        self.written = np.full((WRITES_KEPT, 2), np.nan)
        """[first sample answered, monotonic s] of each command message written to the link (a ring; the time is
        stored before the sample, so a reader that finds the sample finds its time)."""
        self.shared = None
        """The shared memory holding ``written`` once shared (share_written)."""

    last_seq = _state_field(cb.LAST_SEQ, int, None)
    """The last sequence number taken (None: none yet)."""
    k_offset = _state_field(cb.K_OFFSET, int)
    status = _state_field(cb.STATUS, int)
    theta_m = _state_field(cb.THETA_M, float)
    last_telemetry_at = _state_field(cb.LAST_TELEMETRY_AT, float, None)
    last_command_at = _state_field(cb.LAST_COMMAND_AT, float, None)
    lost = _state_field(cb.LOST, bool)
    safe = _state_field(cb.SAFE, bool)
    clear_sent = _state_field(cb.CLEAR_SENT, bool)

    @property
    def lost_reason(self):
        """Why the link is lost, in a few words (the compiled answer's check counts a silence but keeps no words)."""
        return self.last_error or f"no telemetry for {self.link_timeout_s * 1e3:g} ms"

    @property
    def hello(self):
        """The inverter's HELLO taken (None: none)."""
        return self._hello

    @hello.setter
    def hello(self, message):
        self._hello = message
        self.state[cb.HAS_HELLO] = message is not None
        if message is not None:
            self.state[cb.CURRENT_LSB], self.state[cb.VOLTAGE_LSB] = message.current_lsb_A, message.voltage_lsb_V

    def written_at(self, k):
        """When the command answering sample k was written to the link (monotonic s); NaN when it was not,
        or is no longer kept."""
        return written_at(self.written, self.block_samples, k)

    def note_written(self, k0):
        self.answered_k0 = max(self.answered_k0, k0)
        slot = (k0 // self.block_samples) % WRITES_KEPT
        self.written[slot, 1] = time.monotonic()
        self.written[slot, 0] = k0

    def share_written(self):
        """Move the ring of writes into shared memory, for an inverter in another process of this machine to read
        when each command was written (CLOCK_MONOTONIC is the machine's); its name. The host unlinks the name once
        the reader has mapped it (``unlink_written``)."""
        from multiprocessing import shared_memory
        if self.shared is None:
            self.shared = shared_memory.SharedMemory(create=True, size=self.written.nbytes)
            shared = np.ndarray(self.written.shape, dtype=self.written.dtype, buffer=self.shared.buf)
            shared[:] = self.written
            self.written = shared
        return self.shared.name

    def unlink_written(self):
        """Remove the shared ring's name (the memory stays while it is mapped)."""
        if self.shared is not None:
            self.shared.unlink()

    def frame_errors(self):
        """CRC, framing, version and unknown-type counts of the link's decoder."""
        return dict(self.link.errors)

    def poll(self, timeout_s):
        """Samples received within ``timeout_s`` (in order, duplicates and late ones dropped)."""
        return [sample for block in self.poll_blocks(timeout_s) for sample in block.samples()]

    def poll_blocks(self, timeout_s):
        """BridgeBlocks received within ``timeout_s``, one per block of N samples (a TELEMETRY_BLOCK, or its
        CAN FD frames put together) or per TELEMETRY; in order, duplicates and late ones dropped. A part of a
        block is held until the rest comes, and given as it is when something else comes or nothing does."""
        now = time.monotonic()
        if not self.open:
            if now < self.next_open_at:
                time.sleep(min(timeout_s, self.next_open_at - now))
                return []
            self._open()
            if not self.open:
                return []
        try:
            messages = self.link.receive(timeout_s)
        except LinkDown as error:
            self._link_down(str(error))
            return []
        blocks = []
        for message in messages:
            if isinstance(message, Hello) and message.block_samples != self.block_samples:
                self.counters["block_mismatch"] += 1
                self.hello = None
                self.last_error = (f"the inverter sends blocks of {message.block_samples} samples; this drive "
                                   f"is set for {self.block_samples} (block_samples)")
            elif isinstance(message, Hello):
                self.hello = message
            elif isinstance(message, (Telemetry, TelemetryBlock)) and not (self.hello is None
                                                                          and self.counters["block_mismatch"]):
                block = self._telemetry(*_entries(message))
                if block is not None:
                    blocks.extend(self._assemble(block))
        if not messages and self.part is not None:
            blocks.append(self.part)
            self.part = None
        self._check_timeouts()
        return blocks

    def _assemble(self, block):
        """The whole blocks ``block`` completes (with the part held before it), in order."""
        N, part, done = self.block_samples, self.part, []
        self.part = None
        if part is not None and cb.follows_part(part.k0, len(part), block.k0, N):
            block = BridgeBlock(part.k0, np.vstack((part.currents_A, block.currents_A)),
                                np.concatenate((part.theta_m, block.theta_m)), block.u_dc_V, block.status)
        elif part is not None:
            done.append(part)
        if (block.k0 + len(block)) % N:
            self.part = block
        else:
            done.append(block)
        return done

    def reopen(self):
        """Open the link again (after ``link_down``) and ask for HELLO; without effect until it opens."""
        self._open()

    def link_down(self, reason):
        """The link failed (``reason``): counted, reopened after ``reconnect_s``."""
        self._link_down(reason)

    def _open(self):
        try:
            self.link.open()
        except LinkDown as error:
            self.last_error = str(error)
            self.next_open_at = time.monotonic() + self.reconnect_s
            return
        self.open = True
        self.counters["reconnects"] += self.counters["link_lost"] > 0
        self._send(Control(CONTROL_SEND_HELLO))

    def _link_down(self, reason):
        self.open = False
        self.next_open_at = time.monotonic() + self.reconnect_s
        self.last_error = reason
        if "bus-off" in reason:
            self.counters["bus_off"] += 1
        if not self.lost:
            self.lost = True
            self.counters["link_lost"] += 1

    def _telemetry(self, seq, entries, u_dc, status):
        """The BridgeBlock of samples seq … (``entries``: their (i_a, i_b, i_c, encoder) counts), or None
        for one before HELLO, a repeat or a late one; every gap counted as dropped samples."""
        n = len(entries)
        t = self.telemetry
        t.entries[:n] = entries
        currents, theta = np.empty((n, 3)), np.empty(n)
        k0 = cb.accept_telemetry(t, seq, n, u_dc, status, currents, theta)
        if k0 == cb.ASK_HELLO:
            self._send(Control(CONTROL_SEND_HELLO))
        if k0 < 0:
            return None
        self.received_k0 = max(self.received_k0, int(k0) - int(k0) % self.block_samples)
        return BridgeBlock(int(k0), currents, theta, u_dc * self.hello.voltage_lsb_V, status)

    def _check_timeouts(self):
        now = time.monotonic()
        since, timeout, answered = self.last_telemetry_at, self.link_timeout_s, ""
        if self.answer_wait_s and since is not None:
            if self.last_command_at is not None and self.answered_k0 >= self.received_k0:
                since, answered = max(since, self.last_command_at), " after its answer"
            else:
                timeout += self.answer_wait_s
        silent = since is not None and now - since > timeout
        if silent and not self.lost:
            self.lost = True
            self.counters["link_lost"] += 1
            self.last_error = f"no telemetry for {timeout * 1e3:g} ms{answered}"
        if (not self.lost and not self.safe and self.last_command_at is not None
                and now - self.last_command_at > self.command_timeout_s):
            self.safe_state(f"no voltage_command for {self.command_timeout_s * 1e3:g} ms")

    def command(self, k, u_alpha_V, u_beta_V, enable=True, safe_state=SAFE_AUTO):
        """COMMAND(k) with the voltage rounded to the inverter's resolution (clipped to int16) and the safe
        state asked for (``safe_state``: SAFE_AUTO, FREEWHEEL, ASC; drive_common.math.safe_state.safe_state_for
        chooses by speed and bus). An enabling command first clears the latches a link loss causes
        (watchdog, host silence), once, never an overcurrent or an over-voltage."""
        if self.hello is None:
            self.counters["command_errors"] += 1
            return
        lsb = self.hello.voltage_lsb_V
        message = Command(k % 2 ** 32, _int16(u_alpha_V / lsb), _int16(u_beta_V / lsb),
                          command_flags(enable, safe_state))
        self._enabling(enable)
        if self._send(message):
            self.note_written(k)
            self.counters["commands"] += 1

    def command_block(self, k0, u_alpha_V, u_beta_V, enable=True, safe_state=SAFE_AUTO):
        """COMMAND_BLOCK answering samples k0 … k0 + n − 1 (``u_alpha_V``, ``u_beta_V``: n voltages [V]),
        rounded as ``command`` rounds; the same safe state and latch clearing."""
        if self.hello is None:
            self.counters["command_errors"] += 1
            return
        counts = np.column_stack((u_alpha_V, u_beta_V)) / self.hello.voltage_lsb_V
        counts = np.clip(np.rint(np.nan_to_num(counts, nan=0.0, posinf=0.0, neginf=0.0)), -32768, 32767)
        message = CommandBlock(k0 % 2 ** 32, command_flags(enable, safe_state),
                               tuple(map(tuple, counts.astype(int).tolist())))
        self._enabling(enable)
        if self._send(message):
            self.note_written(k0)
            self.counters["commands"] += 1

    def _enabling(self, enable):
        """Before an enabling command: clear the latches a link loss causes, once, never an overcurrent or an
        over-voltage."""
        if enable and self.status & CLEARED_BY_HOST and not self.status & (OVERCURRENT | OVERVOLTAGE) \
                and not self.clear_sent:
            self.clear_sent = True
            self.counters["faults_cleared"] += 1
            self._send(Control(CONTROL_CLEAR_FAULTS))
        self.last_command_at = time.monotonic()
        self.safe = not enable

    def clear_faults(self):
        """CONTROL 2 (every latched fault, an overcurrent included: the operator's reset)."""
        return self._send(Control(CONTROL_CLEAR_FAULTS))

    def safe_state(self, reason):
        """PWM off at once: CONTROL 1 (disable); the next enabling command switches it on again."""
        self.safe = True
        self.counters["safe_state"] += 1
        self.last_error = f"safe state: {reason}"
        self._send(Control(CONTROL_DISABLE))

    def _send(self, message):
        if not self.open:
            self.counters["command_errors"] += isinstance(message, Command)
            return False
        try:
            with self.send_lock:
                self.link.send(message)
            return True
        except LinkDown as error:
            self.counters["command_errors"] += isinstance(message, Command)
            self._link_down(str(error))
            return False

    def status_names(self):
        return [name for bit, name in STATUS_NAMES.items() if self.status & bit]

    def close(self):
        self.link.close()
        self.open = False


def _entries(message):
    """(seq, ((i_a, i_b, i_c, encoder), ...), u_dc, status) of a TELEMETRY or a TELEMETRY_BLOCK."""
    if isinstance(message, Telemetry):
        return message.seq, ((message.i_a, message.i_b, message.i_c, message.encoder),), message.u_dc, message.status
    return message.seq, message.samples, message.u_dc, message.status


def _int16(value):
    if not math.isfinite(value):
        return 0
    return int(max(-32768, min(32767, round(value))))
