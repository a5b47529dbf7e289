"""Soft real time for a drive's process (docs/ros-graph.md, "Real time"): the cyclic garbage collector kept
out of the sample path, a short thread switch interval, periodic work kept for the quiet part of a block,
and, where the system allows it, real-time scheduling and CPU affinity for every thread of the process and
the kernel's unbound workqueues on the drive's CPUs; the machine's own floor and the hypervisor's steal.
No rclpy."""
import contextlib
import gc
import math
import os
import sys
import threading
import time

from .machine_setting import SharedSetting

GIL_SWITCH_S = 2e-4
"""Python's thread switch interval while a drive runs (its default is 5 ms): a thread woken by the link or
the middleware waits this long at most for the one holding the interpreter to hand over."""


@contextlib.contextmanager
def collector_held(switch_s=GIL_SWITCH_S):
    """The cyclic garbage collector off for the run (after one full collection, whose survivors are frozen
    out of every later one) and the thread switch interval ``switch_s``: a full collection in a large process
    pauses for tens of ms (measured: up to 140 ms in `drive launch`), longer than the link's watchdog. Cyclic
    garbage made meanwhile is collected by ``collect_young`` where the host calls it (a status timer)."""
    gc.collect()
    gc.freeze()
    gc.disable()
    interval = sys.getswitchinterval()
    sys.setswitchinterval(switch_s)
    try:
        yield
    finally:
        sys.setswitchinterval(interval)
        gc.unfreeze()
        gc.enable()


def collect_young():
    """While the collector is held: collect the objects made since the last call (generations 0 and 1: a
    short pause, as only what outlived its reference counts is left there); its duration [s], 0 when the
    collector is not held."""
    if gc.isenabled():
        return 0.0
    start = time.perf_counter()
    gc.collect(1)
    return time.perf_counter() - start


class QuietTime:
    """Work of this process that can wait for the quiet part of a block. Where a drive_bridge node runs the
    loop (the inverter's clock), each node's periodic status (a young collection, /diagnostics: up to
    0.5 ms, measured) would otherwise land between a block's telemetry and its command; held, each piece
    waits for a command to have been written (``quiet``, called by the bridge node) and one piece runs
    there. A piece still waiting when its node's next period comes runs then (the link is down: no command
    is written), so /diagnostics is at most one period late. The bridge's link thread and the executor's
    may both take pieces: each is taken once, under a lock, and run outside it."""

    def __init__(self):
        self.holders = 0
        self.pending = []
        self.lock = threading.Lock()

    def hold(self):
        """A bridge node runs the loop in this process."""
        self.holders += 1

    def release(self):
        """That bridge node is gone: with none left, nothing waits (what is queued is dropped: its nodes
        are being torn down with it; their last status went out with ``complete_run``)."""
        self.holders -= 1
        if not self.holders:
            with self.lock:
                self.pending.clear()

    def later(self, *jobs):
        """Run ``jobs`` now, or queue them while held."""
        if not self.holders:
            for job in jobs:
                job()
            return
        with self.lock:
            self.pending.extend(jobs)

    def overdue(self, jobs):
        """Run those of ``jobs`` still queued, now."""
        with self.lock:
            due = [j for j in self.pending if j in jobs]
            for job in due:
                self.pending.remove(job)
        for job in due:
            job()

    def quiet(self):
        """A command was just written: run one queued piece."""
        with self.lock:
            job = self.pending.pop(0) if self.pending else None
        if job is not None:
            job()


QUIET_TIME = QuietTime()


ROBOT_RT_PRIORITY = 50
"""The SCHED_FIFO priority of the robot's configuration: `drive launch --link L --paced`'s default and the
`drive bench bridge --paced --graph` levers that measure it."""


def _threads():
    try:
        return [int(tid) for tid in os.listdir("/proc/self/task")]
    except OSError:
        return [0]


def real_time_scheduling(priority=0, cpus=None):
    """SCHED_FIFO at ``priority`` (1-99; 0: left as it is) for every thread of this process, and the
    process's CPU affinity ``cpus`` (a set of CPU numbers; None: left as it is). Returns (what was applied,
    what the system refused), each a list of one-line statements; a refusal is never an exception."""
    applied, refused = [], []
    if cpus:
        try:
            for tid in _threads():
                os.sched_setaffinity(tid, cpus)
            applied.append(f"CPU affinity {','.join(str(c) for c in sorted(cpus))}")
        except (OSError, ValueError) as error:
            refused.append(f"CPU affinity {sorted(cpus)} refused: {error.strerror or error}")
    if priority:
        try:
            for tid in _threads():
                os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(priority))
            applied.append(f"SCHED_FIFO priority {priority}")
        except (OSError, AttributeError) as error:
            reason = getattr(error, "strerror", None) or str(error)
            refused.append(f"SCHED_FIFO priority {priority} refused: {reason} (needs CAP_SYS_NICE or an rtprio "
                           f"limit, e.g. in /etc/security/limits.conf); the drive runs with normal scheduling")
    return applied, refused


@contextlib.contextmanager
def real_time_scheduled(priority=0, cpus=None):
    """``real_time_scheduling`` for a run, yielding {"applied": [...], "refused": [...]}; afterwards every
    thread of the process is back to SCHED_OTHER on the CPUs it had."""
    before = os.sched_getaffinity(0)
    applied, refused = real_time_scheduling(priority, cpus)
    try:
        yield {"applied": applied, "refused": refused}
    finally:
        if applied:
            for tid in _threads():
                try:
                    os.sched_setscheduler(tid, os.SCHED_OTHER, os.sched_param(0))
                    os.sched_setaffinity(tid, before)
                except OSError:
                    pass


WORKQUEUE_CPUMASK = "/sys/devices/virtual/workqueue/cpumask"
"""The CPUs the kernel's unbound workqueues may run on (a hexadecimal mask). Bytes written to a serial port
or a pty reach the reader through one (the tty layer's flush_to_ldisc, an ordinary task's priority): where
an ordinary task holds its CPU, the reader waits (measured: 1.2-1.6 ms, docs/results.md)."""


def cpu_mask(cpus):
    """``cpus`` (a set of CPU numbers) as a sysfs CPU mask: hexadecimal, 32 CPUs per comma-separated group."""
    bits = sum(1 << c for c in cpus)
    groups = []
    while True:
        groups.append(bits & 0xFFFFFFFF)
        bits >>= 32
        if not bits:
            break
    return ",".join(f"{g:08x}" if i else f"{g:x}" for i, g in enumerate(reversed(groups)))


@contextlib.contextmanager
def unbound_work_on(cpus, mask_file=None, holders_dir=None):
    """The kernel's unbound workqueues on ``cpus`` (None: left as they are) for a run (``mask_file``: None,
    WORKQUEUE_CPUMASK). System-wide: every
    unbound kernel work item runs there meanwhile; shared by the machine's drive processes
    (machine_setting.SharedSetting, its holders in ``holders_dir``): the last one out puts the mask found
    before the first back, also after a holder was killed. Yields {"applied": [...], "refused": [...]} as
    real_time_scheduled; a refusal (not root, another drive holding other CPUs) is never an exception."""
    applied, refused, setting = [], [], None
    mask_file = mask_file or WORKQUEUE_CPUMASK
    if cpus:
        text = ",".join(str(c) for c in sorted(cpus))
        shared = SharedSetting(mask_file, holders_dir)
        try:
            why_not, note = shared.take(cpu_mask(cpus))
        except OSError as error:
            why_not, note = f"{error.filename or mask_file}: {error.strerror or error} (needs root)", None
        if why_not:
            refused.append(f"kernel's unbound workqueues on CPU {text} refused: {why_not}; they stay where they "
                           f"were")
        else:
            setting = shared
            applied += [f"kernel's unbound workqueues on CPU {text}"] + ([note] if note else [])
    try:
        yield {"applied": applied, "refused": refused}
    finally:
        if setting is not None:
            with contextlib.suppress(OSError):
                setting.give_back()


CPU_DMA_LATENCY = "/dev/cpu_dma_latency"


@contextlib.contextmanager
def cpu_wakeup_latency_held(max_us, request_file=CPU_DMA_LATENCY):
    """The kernel's CPU wake-up latency limit (PM QoS, ``/dev/cpu_dma_latency``) at ``max_us`` (None: left
    as it is) for a run: no CPU enters an idle state slower to leave than that (0: the CPUs poll when idle,
    never halt). System-wide, and only while the request is held; cyclictest holds it so. Yields
    {"applied": [...], "refused": [...]} as real_time_scheduled; a refusal is never an exception."""
    applied, refused, request = [], [], None
    if max_us is not None:
        try:
            request = os.open(request_file, os.O_WRONLY)
            os.write(request, int(max_us).to_bytes(4, sys.byteorder, signed=True))
            applied.append(f"CPU wake-up latency held at {max_us} µs ({request_file})")
        except OSError as error:
            if request is not None:
                os.close(request)
                request = None
            refused.append(f"CPU wake-up latency {max_us} µs refused: {request_file}: {error.strerror or error} "
                           f"(needs root); the CPUs idle as they were")
    try:
        yield {"applied": applied, "refused": refused}
    finally:
        if request is not None:
            os.close(request)


def microseconds(text):
    """argparse type of ``--cpu-dma-latency-us``: a whole number of µs ≥ 0."""
    return _whole_number(text, 0, math.inf, "a whole number of µs ≥ 0")


def cpu_set(text):
    """argparse type of ``--cpus``: "0", "0,1" or "0-1" → a set of CPU numbers."""
    import argparse
    cpus = set()
    try:
        for part in text.split(","):
            first, _, last = part.partition("-")
            cpus |= set(range(int(first), int(last or first) + 1))
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a CPU list such as 0 or 0,1 or 0-1: {text!r}") from None
    available = os.sched_getaffinity(0)
    if not cpus or not cpus <= available:
        raise argparse.ArgumentTypeError(f"CPUs {text!r} are not among this process's {sorted(available)}")
    return cpus


def fifo_priority(text):
    """argparse type of ``--rt-priority``: 0 (normal scheduling) or a SCHED_FIFO priority 1-99."""
    return _whole_number(text, 0, 99, "a SCHED_FIFO priority 1-99, or 0 for normal scheduling")


def _whole_number(text, low, high, expected):
    """``text`` as a whole number from ``low`` to ``high``; else argparse's error: ``expected``, not text."""
    import argparse
    try:
        value = int(text)
    except ValueError:
        value = None
    if value is None or not low <= value <= high:
        raise argparse.ArgumentTypeError(f"{expected}, not {text!r}")
    return value


def add_scheduling_arguments(parser, system_wide=False):
    """``--rt-priority`` and ``--cpus`` (real_time_scheduling) on a drive process's command line; with
    ``system_wide``, the machine's settings for the run too: ``--workqueue-cpus`` (unbound_work_on) and
    ``--cpu-dma-latency-us`` (cpu_wakeup_latency_held)."""
    parser.add_argument("--rt-priority", type=fifo_priority, default=0, metavar="1-99",
                        help="SCHED_FIFO priority for every thread of the process (default 0: normal scheduling)")
    parser.add_argument("--cpus", type=cpu_set, default=None, metavar="LIST",
                        help="CPU affinity of the process, e.g. 1 or 0-1 (default: every CPU)")
    if system_wide:
        parser.add_argument("--workqueue-cpus", type=cpu_set, default=None, metavar="LIST",
                            help="the kernel's unbound workqueues (a serial link's bytes pass through one) on "
                                 "these CPUs for the run, system-wide, put back afterwards; needs root "
                                 "(default: left as they are)")
        parser.add_argument("--cpu-dma-latency-us", type=microseconds, default=None, metavar="US",
                            help="no CPU idles in a state slower to leave than this for the run (PM QoS "
                                 "/dev/cpu_dma_latency; 0: CPUs poll when idle), system-wide; needs root "
                                 "(default: left as it is)")


def stolen_s():
    """Per CPU, the time the hypervisor has given its virtual CPU to others since boot [s] (/proc/stat's
    steal column, in 10 ms ticks); {} where the system does not say."""
    try:
        with open("/proc/stat") as f:
            lines = [line.split() for line in f if line.startswith("cpu") and line[3].isdigit()]
        return {int(fields[0][3:]): int(fields[8]) / os.sysconf("SC_CLK_TCK") for fields in lines}
    except (OSError, ValueError, IndexError):
        return {}


STALL_S = 5e-4
"""A wake-up later than this is a stall: half of a block of 10 at 10 kHz."""


def wakeups(period_s, go_on, clock=time.monotonic, sleep=time.sleep):
    """Sleep to each multiple of ``period_s`` from now while ``go_on()``; yield each wake-up's (due,
    late) [s on ``clock``, s]. ``clock`` and ``sleep``: the machine's by default, a virtual clock in tests."""
    due = clock()
    while go_on():
        due += period_s
        remaining = due - clock()
        if remaining > 0:
            sleep(remaining)
        yield due, clock() - due


def wakeup_latencies(seconds, period_s=1e-3, priority=0, cpus=None):
    """The machine's own floor for a drive: a thread of this process sleeps to each multiple of
    ``period_s`` for ``seconds`` (SCHED_FIFO ``priority`` and ``cpus`` where allowed, as a drive's threads)
    and measures how late it wakes. Returns (latencies [s] as a float64 array, the scheduling applied and
    refused). Run in a process with nothing else to do, it measures the kernel and the hypervisor alone."""
    import numpy as np
    n = max(1, int(round(seconds / period_s)))
    with real_time_scheduled(priority, cpus) as scheduling:
        late = np.array([late for _, (_, late) in zip(range(n), wakeups(period_s, lambda: True))])
    return late, scheduling


def stall_report(late, period_s):
    """Wake-up latency figures of ``wakeup_latencies`` [µs], and the stalls (later than STALL_S) per second."""
    import numpy as np
    seconds = len(late) * period_s
    stalls = late > STALL_S
    return {"seconds": seconds, "period_s": period_s, "wakeups": len(late),
            "latency_p50_us": float(np.percentile(late, 50) * 1e6),
            "latency_p99_us": float(np.percentile(late, 99) * 1e6), "latency_max_us": float(late.max() * 1e6),
            "stalls_over_0_5_ms": int(stalls.sum()), "stalls_over_1_ms": int((late > 1e-3).sum()),
            "stalls_per_s": float(stalls.sum() / seconds), "stalled_ms": float(late[stalls].sum() * 1e3)}
