"""How the host kept pace with a virtual inverter (on a thread, or in a process of its own): missing
commands, latencies, the runs of missing periods, and what the host's write times say of them. No rclpy."""
import math

import numpy as np

LATENCY_BINS_PER_PERIOD = (0.0, 0.25, 0.5, 0.75, 1.0, 2.0, 5.0, 10.0, math.inf)
"""Edges of the command latency histogram, in sampling periods: below 1 a command can be in time."""


MISSING_RUNS_SHOWN = 20


def timing_report(inverter, T_s, written_at=None):
    """How the host kept pace with a virtual inverter: periods run, commands missing (late or never
    sent: zero volts), their fraction, latency percentiles [µs] over every command that came (late ones
    included), as a device also the host's answer percentiles [µs] (telemetry sent to the host's write of its
    command, over the commands written after the drive started; None otherwise) and how many it never wrote
    (``never_answered``), the histogram of those latencies (edges in sampling periods and µs), the runs of missing
    periods (how many, the longest, the first ones as [time s, periods]) and the periods before the drive
    started (before its first command in time, PWM off: not missing). With ``written_at(k)`` (the host
    bridge's InverterBridge.written_at, on the same machine) also how many of those runs began with a
    command the host had written early enough to arrive in time over the real link's wire. ``in_time_by``:
    whether a command counted as arrived when the host's write and the wire were done ("host write + wire",
    VirtualInverter.hear_host_writes) or when the inverter's thread read it ("inverter read");
    ``sent_late_in_time``: periods in time only because the simulation sent their telemetry late (the host's
    window counts from then); ``read_late_in_time``: periods whose command was read after its deadline
    but had arrived in time by the host's write time."""
    every = np.concatenate([inverter.latencies_s, inverter.late_latencies_s]) * 1e6
    if getattr(inverter, "host_written_at", None) is not None:
        inverter.note_answers(final=True)
    answers = np.asarray(getattr(inverter, "answers_s", ())) * 1e6
    edges = np.asarray(LATENCY_BINS_PER_PERIOD)
    counts, _ = np.histogram(every, bins=edges * T_s * 1e6)
    return {"paced": bool(inverter.rate_Hz), "periods": inverter.k, "missing": inverter.counters["missing"],
              "late_fraction": inverter.counters["missing"] / max(inverter.k, 1),
              "late_arrivals": len(inverter.late_latencies_s),
              "latency_p50_us": float(np.percentile(every, 50)) if every.size else None,
              "latency_p99_us": float(np.percentile(every, 99)) if every.size else None,
              "latency_max_us": float(every.max()) if every.size else None,
              "answer_p50_us": float(np.percentile(answers, 50)) if answers.size else None,
              "answer_p99_us": float(np.percentile(answers, 99)) if answers.size else None,
              "answer_max_us": float(answers.max()) if answers.size else None,
              "never_answered": getattr(inverter, "never_answered", 0),
              "latency_histogram": {"edges_periods": [float(e) if math.isfinite(e) else None for e in edges],
                                    "counts": [int(c) for c in counts]},
              "watchdog_trips": inverter.counters["watchdog_trips"], "overruns": inverter.counters["overruns"],
              "host_silent_trips": inverter.counters["host_silent_trips"],
              "periods_before_start": inverter.before_start, **since_start(inverter),
              "in_time_by": "host write + wire" if getattr(inverter, "host_written_at", None) else "inverter read",
              "sent_late_in_time": inverter.counters.get("sent_late", 0),
              "read_late_in_time": inverter.counters.get("read_late", 0),
              "missing_runs": missing_runs(inverter.missing_runs, T_s),
              **written_before_due(inverter.missing_runs, written_at, getattr(inverter, "command_wire_s", 0.0))}


def since_start(inverter):
    """Periods from the drive's first command in time on, and the share of them without a command in time (a
    drive armed on a running inverter: the periods before it are not its); 1.0 when none ever came in time."""
    started_at = getattr(inverter, "started_at", None)
    if started_at is None:
        return {"periods_since_start": 0, "late_fraction_since_start": 1.0}
    periods = inverter.k - started_at
    missing = inverter.counters["missing"] - getattr(inverter, "missing_at_start", 0)
    return {"periods_since_start": periods, "late_fraction_since_start": missing / max(periods, 1)}


def written_before_due(runs, written_at, wire_s=0.0):
    """Of the runs of missing periods, how long before its due time each one's first command had arrived by
    the host's write time (kept in the run, else ``written_at``) and ``wire_s`` on the wire [µs]
    (negative: after; NaN: not known), and how many had so arrived in time; None without ``written_at``."""
    if written_at is None:
        return {"missing_runs_written_in_time": None, "missing_runs_written_before_due_us": None}
    before = [1e6 * (run[3] - (run[5] if len(run) > 5 and math.isfinite(run[5]) else written_at(run[4])) - wire_s)
              for run in runs if run[3]]
    return {"missing_runs_written_in_time": sum(b >= 0.0 for b in before),
            "missing_runs_written_before_due_us": [round(b, 1) if math.isfinite(b) else None for b in before]}


def missing_runs(runs, T_s):
    """How many runs of periods without a command in time, the longest [periods], the first ones as
    [time s, periods], and each one's window [telemetry sent, command due] on the machine's monotonic clock
    (paced; to set beside what else watched the machine then, drive_common.runtime.machine_watch)."""
    return {"count": len(runs), "longest_periods": max((run[1] for run in runs), default=0),
            "first": [[round(run[0] * T_s, 4), run[1]] for run in runs[:MISSING_RUNS_SHOWN]],
            "windows_monotonic_s": [run[2:4] for run in runs if run[3]]}
