"""The host's answer through the bridge compiled whole (docs/ros-graph.md, "The compiled answer"): from the
telemetry read to the command written — the link's bytes read (read/poll on its descriptor), frames checked and
decoded, the estimator's, protections' and controller's block kernels, the command encoded and written — one
numba function that does not hold the interpreter's lock, on a thread of its own (SCHED_FIFO where the
machine allows it). What it produced (per sample: k, the host's time, the log row) goes into a preallocated
lock-free ring (drive_common.runtime.sample_ring) that a thread that is not real-time reads: the recording
waits for nothing and a full ring is counted, never silent. Reconnecting, HELLO's requests and the reports
stay in Python, between calls of the compiled loop. On a serial link (a UART, USB CDC, a pty) or a CAN bus
through its socket (SocketCAN, or drive_bridge.can_cable between processes); blocks that come as several CAN FD
frames are put together as InverterBridge puts them."""
import contextlib
import os
import threading
import time
from typing import NamedTuple

import numpy as np
from numba import njit

from drive_bridge import compiled_bridge as cb
from drive_bridge.can_cable import MEMBERS_REFRESH_S
from drive_bridge.inverter_protocol import COMMAND_MISSING, CONTROL_SEND_HELLO, MAX_BLOCK, PWM_OFF
from drive_common.contract.log import LOG_COLUMNS
from drive_common.math.command_delay import issue_command
from drive_common.math.safe_state import safe_state_for
from drive_common.runtime.bound_kernels import bound
from drive_common.runtime.sample_ring import drain, free_slot, publish, sample_ring
from foc_controller.protection import SAFE_STATE, TRIPPED
from foc_controller.speed_command import N_FIELDS, commanded_speed

from .answer_kernels import fill_inputs, issue_and_log
from .loop import DriveCores, copied, drive_block

RING_K, RING_HOST_S, RING_THETA_M, RING_STATUS, RING_LOG = 0, 1, 2, 3, 4
"""A ring row: the sample k, the host's time from its telemetry read to its command written [s], the encoder's
angle as received [rad, mechanical; NaN: none], the inverter's status word of its block, then its log row
(LOG_COLUMNS)."""
RING_ROWS = 1 << 15
"""The ring's rows by default: 3.3 s of samples at 10 kHz (8 MiB)."""
(STOP, NEXT_K, LAST_ANSWERED, N_SAMPLES, DELAY, DRAINING, ORIGIN, COMMAND_SLOT, COMMAND_AT_NS,
 STALE_NS) = range(10)
"""Fields of the loop's ``run`` array (int64): set by Python (STOP, N_SAMPLES, DELAY, DRAINING: nothing more
will come; with a live command, COMMAND_SLOT: the row of HostCore.live_commands to follow, COMMAND_AT_NS: when
Python last wrote it [ns, CLOCK_MONOTONIC], STALE_NS: older than this, the loop holds zero speed (0: never)), kept by
the loop (NEXT_K: the next sample expected, LAST_ANSWERED), and ORIGIN: the inverter's sample the drive counts from
(its sample 0), set by Python (0: a run from the inverter's start) or, at −1, by the loop at the first whole block
it takes (an axis armed on a running inverter). NEXT_K, LAST_ANSWERED and N_SAMPLES count the drive's samples."""
RUN_FIELDS = 10
OPEN_ENDED = 1 << 62
"""N_SAMPLES of an answer that runs until it is stopped (a robot's axis)."""
DONE, STOPPED, RECONNECT = 1, 2, 3
PART_K0, PART_N, PART_STATUS = range(3)
"""Fields of HostCore.part (int64): the first sample of the part of a block held, its samples (0: none held),
its status; HostCore.part_at holds its bus [V] and when it was read [s]."""
POLL_MS = 50
"""The loop's wait for bytes before it checks the link's and the graph's silence (InverterBridge's 0.05 s)."""


class AnswerParts(NamedTuple):
    """What the answer steps: the drive's ``cores`` (drive_tools.runner.loop.DriveCores, their states the
    drive's), its estimator's ``step`` kernel, the speed reference [rad/s] and torque feed-forward [N·m] per
    sample of the run (a scenario's schedule) or each an array of one (a robot's axis: drive_tools.launch.axis_answer:
    the feed-forward written by a thread that is not real-time, the speed reference the loop's own, following the live
    ``live_commands``), the live commands (COMMAND_SLOTS rows of foc_controller.speed_command's fields; none: the
    schedule's speed) and the sample period ``T_s`` [s]."""

    cores: object
    step: object
    speed_ref: np.ndarray
    tau_feedforward: np.ndarray
    live_commands: np.ndarray
    T_s: float


COMMAND_SLOTS = 4
"""Rows of a live command: Python writes a new command into the row after the one followed, then COMMAND_SLOT (one
store), so the loop never reads a row being written unless Python writes three more within one of its reads."""


def drive_parts(drive):
    """AnswerParts of a runner.Drive built for a scenario: its schedule per sample."""
    return AnswerParts(drive.cores(), drive.estimator.step, drive.speed_ref, drive.tau_feedforward,
                       np.zeros((0, N_FIELDS)), drive.scenario.T_s)


class HostCore(NamedTuple):
    """The drive's cores as the answer steps them (AnswerParts.cores), its speed reference and torque
    feed-forward (per sample, or live), the delay line and the block's buffers: the currents and
    angles as received (MAX_BLOCK rows), the block's currents (N × 3), its records (DRIVE_INPUT, ESTIMATE,
    COMMAND), its voltages [V] and its log rows; T_s [s]; the currents and angles of one telemetry message
    (``chunk_*``: a CAN FD frame carries part of a block), the part of a block held (``part``, ``part_at``) and
    the live commands (AnswerParts.live_commands)."""

    drive: DriveCores
    speed_ref: np.ndarray
    tau_feedforward: np.ndarray
    line: np.ndarray
    received_currents: np.ndarray
    received_theta: np.ndarray
    currents: np.ndarray
    inputs: np.ndarray
    estimates: np.ndarray
    commands: np.ndarray
    voltages: np.ndarray
    rows: np.ndarray
    T_s: float
    chunk_currents: np.ndarray
    chunk_theta: np.ndarray
    part: np.ndarray
    part_at: np.ndarray
    live_commands: np.ndarray


@njit(nogil=True, _nrt=False, inline='always')
def answer_block(step, h, b, run, block, ring):
    """Block k0 … k0 + n − 1 (``block``: k0, n, the bus [V], the status, when it was read [s]; its samples
    accepted into ``h.received_*``) as bridge_loop's host answers it: the commands of
    samples never received and of periods run at zero volts are zero in the delay line; a whole block (its
    first sample a multiple of N; N samples, or the run's last ones) is answered by the block kernels and one
    command message, then each sample goes into ``ring`` (rows, indices). ``block`` counts the inverter's
    samples, the cores and the log the drive's (from ORIGIN on; nothing before it is answered). False when the
    link failed."""
    k_inverter, n, u_dc_V, status, arrived = block
    n_total, delay, N = run[N_SAMPLES], run[DELAY], h.currents.shape[0]
    if run[ORIGIN] < 0:
        if k_inverter % N or n < N:
            return True
        run[ORIGIN] = k_inverter
    k0 = k_inverter - run[ORIGIN]
    if k0 < 0 or k0 >= n_total:
        return True
    k_end = min(k0 + n, n_total)
    for missed in range(run[NEXT_K], k0):
        issue_command(h.line, missed, 0.0, 0.0)
    run[NEXT_K] = k_end
    if status & (COMMAND_MISSING | PWM_OFF):
        for k in range(max(k0, delay), k_end):
            issue_command(h.line, k - delay, 0.0, 0.0)
    m = min(N, n_total - k0)
    if k0 % N or n < m:
        return True
    for i in range(m):
        for j in range(3):
            h.currents[i, j] = h.received_currents[i, j]
    cores = h.drive
    if h.live_commands.shape[0] > 0:
        n_p = cores.controller.n_p
        stale = run[STALE_NS] > 0 and cb.monotonic_s(b.timespec) * 1e9 - run[COMMAND_AT_NS] > run[STALE_NS]
        h.speed_ref[0] = 0.0 if stale else commanded_speed(h.live_commands[run[COMMAND_SLOT]], h.speed_ref[0],
                                                           h.estimates[m - 1].theta_e_hat / n_p, m * h.T_s)
    fill_inputs(h.inputs, h.currents, h.received_theta, cores.controller.n_p, h.speed_ref, h.tau_feedforward, k0, m)
    drive_block(step, cores, (k0, m, u_dc_V), h.line, (h.currents, h.inputs, h.estimates, h.commands))
    enable = cores.protection_x[TRIPPED] == 0.0
    safe = int(cores.protection_x[SAFE_STATE]) if not enable else safe_state_for(h.estimates[m - 1].omega_e_hat,
                                                                                 u_dc_V, cores.protection.psi_f_Wb)
    issue_and_log(h.line, h.rows, k0, m, h.T_s, h.inputs, h.estimates, h.commands)
    for i in range(m):
        h.voltages[0, i], h.voltages[1, i] = h.commands[i].u_alpha_V, h.commands[i].u_beta_V
    if not cb.write_commands(b, k_inverter, h.voltages[0], h.voltages[1], m, enable, safe):
        return False
    host_s = cb.monotonic_s(b.timespec) - arrived
    rows, indices = ring
    for i in range(m):
        slot = free_slot(rows, indices)
        if slot >= 0:
            rows[slot, RING_K], rows[slot, RING_HOST_S] = k_inverter + i, host_s
            rows[slot, RING_THETA_M], rows[slot, RING_STATUS] = h.received_theta[i], status
            for j in range(h.rows.shape[1]):
                rows[slot, RING_LOG + j] = h.rows[i, j]
            publish(indices)
    run[LAST_ANSWERED] = k0 + m - 1
    return True


@njit(nogil=True, _nrt=False, inline='always')
def take_part(step, h, b, run, chunk, ring):
    """Samples k0 … k0 + n − 1 (``chunk``: k0, n, the bus [V], the status, when it was read [s]; in
    ``h.chunk_*``) put into blocks as InverterBridge._assemble puts them: after the part of a block held
    before it when they follow on in one block (else that part is given as it is first), the whole block
    answered, or held as the part until the rest comes. False when the link failed."""
    k0, n, u_dc_V, status, arrived = chunk
    N, part = h.currents.shape[0], h.part
    at = 0
    if cb.follows_part(part[PART_K0], part[PART_N], k0, N):
        at, k0 = part[PART_N], part[PART_K0]
    elif part[PART_N]:
        if not give_part(step, h, b, run, ring):
            return False
    part[PART_N] = 0
    for i in range(n):
        for j in range(3):
            h.received_currents[at + i, j] = h.chunk_currents[i, j]
        h.received_theta[at + i] = h.chunk_theta[i]
    n += at
    if (k0 + n) % N:
        part[PART_K0], part[PART_N], part[PART_STATUS] = k0, n, status
        h.part_at[0], h.part_at[1] = u_dc_V, arrived
        return True
    return answer_block(step, h, b, run, (k0, n, u_dc_V, status, arrived), ring)


@njit(nogil=True, _nrt=False, inline='always')
def give_part(step, h, b, run, ring):
    """The part of a block held (its rest never came) given as it is."""
    part = h.part
    n, part[PART_N] = part[PART_N], 0
    return answer_block(step, h, b, run, (part[PART_K0], n, h.part_at[0], part[PART_STATUS], h.part_at[1]), ring)


@njit(nogil=True, _nrt=False, inline='always')
def answer_loop(step, h, b, run, ring):
    """Answer the inverter on ``b``'s link until the run's last sample is answered (DONE), Python asks to stop
    or nothing came while it drains (STOPPED), the link failed (compiled_bridge.LINK_DOWN) or, on a CAN cable,
    a frame found no member to take it, or the cable is quiet for a poll with no member found or the link
    lost (RECONNECT: Python looks for the member again; one that left and joined anew has a new socket)."""
    while True:
        if run[STOP]:
            return STOPPED
        got = cb.read_link(b, POLL_MS)
        if got == cb.LINK_DOWN:
            return cb.LINK_DOWN
        arrived = cb.monotonic_s(b.timespec)
        start = 0
        while True:
            after, m = cb.next_payload(b, start)
            if after < 0:
                break
            start = after
            if m == 0:
                continue
            seq, n, u_dc, status = cb.frame_telemetry(b, m)
            if n == 0:
                continue
            k0 = cb.accept_telemetry(b, seq, n, u_dc, status, h.chunk_currents, h.chunk_theta)
            if k0 == cb.ASK_HELLO:
                cb.send_control(b, CONTROL_SEND_HELLO)
            if k0 < 0:
                continue
            if not take_part(step, h, b, run, (k0, n, u_dc * b.state[cb.VOLTAGE_LSB], status, arrived), ring):
                cb.keep_unframed(b, start)
                return cb.LINK_DOWN
            if run[LAST_ANSWERED] == run[N_SAMPLES] - 1:
                cb.keep_unframed(b, start)
                return DONE
        cb.keep_unframed(b, start)
        lost = b.state[cb.PEER_LOST]
        cable_silent = got == 0 and b.state[cb.LINK_KIND] == cb.CABLE and (lost or b.state[cb.LOST])
        if lost == cb.PEER_GONE or cable_silent:
            return RECONNECT
        if got == 0 and h.part[PART_N] and not give_part(step, h, b, run, ring):
            return cb.LINK_DOWN
        if not cb.check_silence(b):
            return cb.LINK_DOWN
        if got == 0 and run[DRAINING]:
            return STOPPED


class RingBlocks:
    """The ring's rows (RING_K, …: ``columns`` each) as whole blocks of ``block_samples``, in order: a block whose rows
    the reader drained in two parts is handed on whole; rows that start no whole block (a gap) are left out."""

    def __init__(self, block_samples, columns):
        self.N = block_samples
        self.pending = np.zeros((0, columns))
        """The first rows of a block whose rest the ring has not handed over yet."""

    def blocks(self, rows):
        """Each whole block (an array of N rows) among the rows held and ``rows``; the first rows of one to come
        held."""
        rows = np.concatenate((self.pending, rows)) if len(self.pending) else rows
        self.pending = rows[:0]
        N, k = self.N, rows[:, RING_K].astype(np.int64)
        whole, start = [], 0
        while start < len(k):
            if k[start] % N:
                start += 1
            elif start + N > len(k):
                self.pending = rows[start:].copy()
                break
            elif k[start + N - 1] != k[start] + N - 1:
                start += 1
            else:
                whole.append(rows[start:start + N])
                start += N
        return whole


def link_name(link):
    """The port or CAN channel of ``link`` (SerialLink, CanLink), as its errors name it."""
    return getattr(link, "port", None) or f"CAN {link.channel}"


def host_core(parts, line, block_samples):
    """HostCore of ``parts`` (AnswerParts) with the delay ``line``, for blocks of ``block_samples``."""
    from drive_common.contract.drive_records import commands, drive_inputs
    from drive_common.contract.estimator_records import estimates
    N = block_samples
    return HostCore(parts.cores, parts.speed_ref, parts.tau_feedforward, line, np.zeros((MAX_BLOCK, 3)),
                    np.full(MAX_BLOCK, np.nan), np.zeros((N, 3)), drive_inputs(N), estimates(N), commands(N),
                    np.zeros((2, N)), np.zeros((N, len(LOG_COLUMNS))), parts.T_s, np.zeros((MAX_BLOCK, 3)),
                    np.full(MAX_BLOCK, np.nan), np.zeros(3, dtype=np.int64), np.zeros(2), parts.live_commands)


def warm_answer(host, step, bridge, ring_columns):
    """Load the loop of ``host`` (HostCore) and its estimator's ``step`` for ``bridge`` (InverterBridge) and a ring of
    ``ring_columns``, compiled on a first run (then cached on disk: bound_kernels; a first compile takes tens of
    seconds), by a call on copies of every state that stops at once: the drive, the bridge and its link untouched."""
    copy = host._replace(drive=copied(host.drive), line=host.line.copy(), part=host.part.copy(),
                         speed_ref=host.speed_ref.copy(), live_commands=host.live_commands.copy())
    run = np.zeros(RUN_FIELDS, dtype=np.int64)
    run[STOP] = 1
    bound(answer_loop, step)(copy, cb.copied_bridge(bridge), run, sample_ring(1, ring_columns))
    empty = sample_ring(1, ring_columns)
    drain(empty.rows, empty.indices, np.zeros((1, ring_columns)))


class AnswerOptions(NamedTuple):
    """How the compiled answer runs: its thread's SCHED_FIFO ``priority`` (0: normal scheduling), the ring's
    ``ring_rows``, and ``reader_stall_s``: a pause the ring's reader takes after each read (0: none), the
    stall of the side that is not real-time a bench injects."""

    priority: int = 0
    ring_rows: int = RING_ROWS
    reader_stall_s: float = 0.0


class CompiledAnswer:
    """The compiled answer of ``parts`` (AnswerParts) through ``bridge`` (InverterBridge on a SerialLink, or a
    CanLink on SocketCAN or the cable), ``n_samples`` samples (OPEN_ENDED: until stopped) at the command delay
    ``delay``, the drive's sample 0 at the inverter's ``origin`` (−1: the first whole block taken): ``start`` its
    thread and the ring's reader, which hands the rows it drains (RING_K, RING_HOST_S, RING_THETA_M, then the
    log row) to ``take(rows)``, oldest first; ``stop``; ``join``. The answer thread runs the compiled loop, and
    between its calls reconnects a failed link as InverterBridge does (on a cable, looks for the other
    member). The reader runs at normal scheduling (SCHED_OTHER) in a process whose threads are SCHED_FIFO: it
    is not real-time."""

    def __init__(self, parts, bridge, line, run_samples, options=None, origin=0):
        n_samples, delay = run_samples
        self.bridge, self.options = bridge, options or AnswerOptions()
        options = self.options
        self.step = parts.step
        self.host = host_core(parts, line, bridge.block_samples)
        self.run = np.zeros(RUN_FIELDS, dtype=np.int64)
        self.run[N_SAMPLES], self.run[DELAY], self.run[LAST_ANSWERED] = n_samples, delay, -1
        self.run[ORIGIN] = origin
        self.ring = sample_ring(options.ring_rows, RING_LOG + len(LOG_COLUMNS))
        self.scheduling = {"applied": [], "refused": []}
        self.answering = threading.Thread(target=self._answer, name="drive_answer", daemon=True)
        self.reading = None
        self.arrays = None
        """The bridge's BridgeArrays the running loop holds (its counters live), None between calls."""
        self.error = None
        self._warm_up()

    def _warm_up(self):
        """Load the loop before the inverter starts (warm_answer); the link is opened (and HELLO asked for) if
        it is not open yet."""
        if not self.bridge.open:
            self.bridge.reopen()
        warm_answer(self.host, self.step, self.bridge, self.ring.rows.shape[1])

    def start(self, take):
        self.reading = threading.Thread(target=self._read, args=(take,), name="drive_answer_reader", daemon=True)
        self.answering.start()
        self.reading.start()

    def _answer(self):
        """The answer thread: SCHED_FIFO where allowed, then the compiled loop, called again after a failed
        link is reopened."""
        priority = self.options.priority
        if priority:
            try:
                os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
                self.scheduling["applied"].append(f"SCHED_FIFO priority {priority} (the answer thread)")
            except OSError as error:
                self.scheduling["refused"].append(f"SCHED_FIFO priority {priority} refused: {error.strerror}")
        bridge = self.bridge
        try:
            while not self.run[STOP]:
                if not bridge.open:
                    if self.run[DRAINING]:
                        return
                    time.sleep(max(0.0, min(0.05, bridge.next_open_at - time.monotonic())))
                    if time.monotonic() >= bridge.next_open_at:
                        bridge.reopen()
                    continue
                self.arrays = arrays = cb.load_bridge(bridge)
                code = bound(answer_loop, self.step)(self.host, arrays, self.run, self.ring)
                self.arrays = None
                cb.store_bridge(arrays, bridge)
                if code == RECONNECT:
                    time.sleep(MEMBERS_REFRESH_S)
                    continue
                if code != cb.LINK_DOWN:
                    return
                bridge.link.close()
                bridge.link_down(f"{link_name(bridge.link)}: the device is gone or failed")
        except Exception as error:
            self.error = error

    def counters(self):
        """The bridge's counters now (InverterBridge.counters: the running loop's own arrays)."""
        return dict(self.bridge.counters)

    def _read(self, take):
        """The ring's reader (not real-time): the rows drained to ``take`` until the answer thread has ended
        and the ring is empty."""
        with contextlib.suppress(OSError):
            os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
        rows = np.zeros((max(1, self.ring.rows.shape[0] // 4), self.ring.rows.shape[1]))
        stall = self.options.reader_stall_s
        while True:
            ended = not self.answering.is_alive()
            count = drain(self.ring.rows, self.ring.indices, rows)
            if count:
                take(rows[:count])
            if count == 0 and ended:
                return
            time.sleep(stall if stall > 0 else (0.0 if count else 0.002))

    def drain_then_stop(self):
        """No more telemetry will come: end the loop once nothing arrives."""
        self.run[DRAINING] = 1

    def stop(self):
        self.run[STOP] = 1

    def alive(self):
        return self.answering.is_alive()

    def finished(self):
        """The answer thread has ended and the reader has handed over every row."""
        return (self.reading is not None and not self.answering.is_alive() and not self.reading.is_alive())

    def join(self, timeout_s=None):
        """Wait up to ``timeout_s`` for the answer thread to end, then for the reader to have handed over every
        row (it ends once the answer thread has and the ring is empty: a bounded wait); the answer thread's
        exception, if it died of one, raised here."""
        if self.reading is None:
            return
        self.answering.join(timeout_s)
        if not self.answering.is_alive():
            self.reading.join()
        if self.error is not None:
            raise self.error

    def written_at(self, k):
        """When the command answering sample k was written (InverterBridge.written_at)."""
        return self.bridge.written_at(k)

    @property
    def overflow(self):
        """Rows the ring had no room for (samples answered but not recorded)."""
        from drive_common.runtime.sample_ring import OVERFLOW
        return int(self.ring.indices[OVERFLOW])


def answer_of(drive, bridge, options=None):
    """The CompiledAnswer of ``drive`` (runner.Drive) through ``bridge`` for its scenario's whole run, at its
    command delay, as ``options`` (AnswerOptions) say."""
    from drive_common.math.command_delay import command_line
    scenario = drive.scenario
    delay = scenario.drive_delay_periods()
    return CompiledAnswer(drive_parts(drive), bridge, command_line(delay), (scenario.n_samples, delay), options)
