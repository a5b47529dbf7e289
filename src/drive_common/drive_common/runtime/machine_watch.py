"""The machine's stalls while a drive runs, beside it: a process of its own on the drive's CPUs, at a
SCHED_FIFO priority above the drive's, wakes every ``period_s`` and notes each wake-up later than
``STALL_NOTED_S`` as [due, late] on the system's monotonic clock (the clock every process of the machine
reads). The highest-priority task of a CPU waking late means the CPU was nobody's in the guest: the
hypervisor had it, or the kernel's own work that no priority preempts. ``missing_runs_explained`` compares
them with a drive's late blocks (docs/ros-graph.md, "Real time"). It does not see a CPU that runs slower,
or is taken in slices shorter than ``STALL_NOTED_S``. No rclpy.

The child speaks lines: it prints ``ready`` once scheduled, runs until its standard input ends, then
prints one JSON line: the scheduling applied and refused, its wake-ups and its stalls."""
import argparse
import json
import subprocess
import sys
import threading
import time

from .realtime import cpu_set, fifo_priority, real_time_scheduled, wakeups

PERIOD_S = 5e-4
"""How often the watch wakes [s]: any stall longer than this contains a wake-up."""

STALL_NOTED_S = 2.5e-4
"""A wake-up later than this is noted [s]."""


class MachineWatch:
    """``with MachineWatch(priority, cpus) as watch: ...`` runs the watch in a child process for the
    block's duration; afterwards ``watch.report`` holds {"scheduling", "wakeups", "stalls": [[due, late]]}
    (monotonic s, s), or None when the child gave nothing."""

    def __init__(self, priority, cpus=None, period_s=PERIOD_S):
        self.args = [sys.executable, "-m", "drive_common.runtime.machine_watch", "--rt-priority", str(priority),
                     "--period-s", repr(period_s)]
        if cpus:
            self.args += ["--cpus", ",".join(str(c) for c in sorted(cpus))]
        self.report = None

    def __enter__(self):
        self.process = subprocess.Popen(self.args, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        self.process.stdout.readline()
        return self

    def __exit__(self, *_):
        try:
            self.process.stdin.close()
            line = self.process.stdout.readline()
            self.report = json.loads(line) if line else None
        except (OSError, ValueError):
            self.report = None
        finally:
            try:
                self.process.wait(5.0)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        return False


def stalled_within(stalls, start, end):
    """Seconds of [start, end] (monotonic s) inside the stalls, each [due, due + late]."""
    return sum(max(0.0, min(end, due + late) - max(start, due)) for due, late in stalls)


def missing_runs_explained(windows, stalls, latency_s):
    """How many of a run's late blocks, each its window [telemetry sent, command due] (monotonic s), the
    machine explains: the CPU was nobody's for at least the window less ``latency_s`` (the run's median
    command latency), so that a command at that latency would have been late anyway."""
    return sum(stalled_within(stalls, start, end) >= (end - start) - latency_s for start, end in windows)


def watch(period_s, stop, clock=time.monotonic, sleep=time.sleep):
    """Wake every ``period_s`` until ``stop`` is set: the number of wake-ups and the stalls as [due, late]
    [s] (the wake-ups catching up within a stall are part of it). ``clock``, ``sleep``: as ``wakeups``."""
    stalls, count, stalled_until = [], 0, 0.0
    for due, late in wakeups(period_s, lambda: not stop.is_set(), clock, sleep):
        count += 1
        if late > STALL_NOTED_S and due >= stalled_until:
            stalls.append([due, late])
            stalled_until = due + late
    return count, stalls


def main(argv=None):
    parser = argparse.ArgumentParser(prog="machine_watch", description=__doc__.split("\n\n")[0])
    parser.add_argument("--rt-priority", type=fifo_priority, default=0)
    parser.add_argument("--cpus", type=cpu_set, default=None)
    parser.add_argument("--period-s", type=float, default=PERIOD_S)
    args = parser.parse_args(argv)
    stop = threading.Event()
    threading.Thread(target=lambda: (sys.stdin.read(), stop.set()), daemon=True).start()
    with real_time_scheduled(args.rt_priority, args.cpus) as scheduling:
        print("ready", flush=True)
        count, stalls = watch(args.period_s, stop)
    print(json.dumps({"scheduling": scheduling, "wakeups": count, "stalls": stalls}), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
