"""`drive bench stop`: how soon a signal stops the drive. `drive commission` (its standstill, rotating and
loaded tests) and `drive run` run as a user runs them (standard error on a terminal, in a session of their
own); SIGINT or SIGTERM goes at points of each test (its start, or its progress past a percentage); measured
from
the signal to the stop reported (the "interrupted" line, printed once the chunk in progress finished and no
command follows; for `drive run`, its report, which follows the run's metrics, and the samples it ran after
the signal) and to the process's exit; and checked: exit 128 + N, one line, no traceback, no file written
or left half-written."""
import json
import os
import re
import select
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from statistics import median

OUT = "joint.yaml"
STOP_CASES = {
    "commission standstill": (["commission", "{scenario}", "--out", OUT], 0),
    "commission rotating": (["commission", "{scenario}", "--out", OUT, "--rotating"], 1),
    "commission loaded": (["commission", "{scenario}", "--out", OUT, "--loaded"], 1),
    "run": (["run", "{scenario}", "--duration", "{duration}", "--no-plot", "--json"], 0),
}
"""Per case: the command and which of its tests (0: the first; a commissioning's standstill part ends at
100 %, its next test starts over) the signal lands in."""
RUN_DURATION_S = 20.0
"""The run's simulated length: ten chunks of the runner's (a progress line after each)."""
POINTS_PERCENT = (None, 0.0, 50.0)
"""Where in the test the signal goes: once its progress shows at least this percentage; None: as soon as the
test before it showed 100 % (the test setting up: its drive built, its kernels compiled), for a second test
only."""
PERCENT = re.compile(r"\r[^\r\n]*?(\d+\.\d) %")
WAIT_S = 300.0
"""The longest a command may take to reach a point or to stop (a bound on the bench, not a figure)."""


class Terminal:
    """A command's standard error on a pty and its standard output on a pipe, each read by a thread that
    notes when every piece arrived (time.monotonic)."""

    def __init__(self, argv, cwd):
        import pty
        master, slave = pty.openpty()
        self.process = subprocess.Popen(argv, cwd=cwd, stdout=subprocess.PIPE, stderr=slave, start_new_session=True)
        os.close(slave)
        self.err, self.out = [], []
        self.changed = threading.Condition()
        self.readers = [threading.Thread(target=self._read, args=(master, self.err), daemon=True),
                        threading.Thread(target=self._read, args=(self.process.stdout.fileno(), self.out),
                                         daemon=True)]
        self.master = master
        for reader in self.readers:
            reader.start()

    def _read(self, fd, pieces):
        while True:
            try:
                chunk = os.read(fd, 4096)
            except OSError:
                chunk = b""
            with self.changed:
                if chunk:
                    pieces.append((time.monotonic(), chunk.decode(errors="replace")))
                self.changed.notify_all()
            if not chunk:
                return

    def progress(self):
        """(the test in progress, its percentage) from what the terminal shows so far."""
        text = "".join(piece for _, piece in self.err)
        parts = text.split("100.0 %")
        shown = PERCENT.findall(parts[-1])
        return len(parts) - 1, float(shown[-1]) if shown else None

    def wait_for(self, part, percent):
        """Wait until test ``part`` shows at least ``percent`` (None: has begun); False when the command ended
        or went past it first."""
        deadline = time.monotonic() + WAIT_S
        with self.changed:
            while time.monotonic() < deadline and self.process.poll() is None:
                now, shown = self.progress()
                if now > part or (now == part and (percent is None or shown is not None and shown >= percent)):
                    return now == part
                self.changed.wait(0.5)
        return False

    def close(self):
        if self.process.poll() is None:
            self.process.kill()
        self.process.wait()
        for reader in self.readers:
            reader.join(5.0)
        os.close(self.master)
        self.process.stdout.close()


def _first(pieces, instant, said=lambda text: True):
    """When the output first ``said`` something (given all of it to then) in a piece after ``instant``."""
    text = ""
    for t, piece in pieces:
        text += piece
        if t >= instant and said(text):
            return t
    return None


def _lines(pieces):
    text = PERCENT.sub("", "".join(piece for _, piece in pieces).replace("\r\n", "\n"))
    return [line for line in text.splitlines() if line.strip() and not line.startswith("drive: no commissioning")]


def stop_once(argv, part, percent, signum, workdir, samples=None):
    """One run of ``drive ARGV`` stopped by ``signum`` in test ``part`` at ``percent``: latencies [ms] to the
    stop reported and to the exit, what went wrong, and for a run of ``samples`` (drive run --json) how many
    it ran after the signal."""
    before = sorted(p.name for p in Path(workdir).iterdir())
    terminal = Terminal([sys.executable, "-m", "drive_tools.cli", *argv], workdir)
    try:
        if not terminal.wait_for(part, percent):
            return {"percent": percent, "problems": [f"ended or moved on before {point_name(percent)} of test "
                                                     f"{part}"]}
        _, shown = terminal.progress()
        ended = os.pidfd_open(terminal.process.pid)  # readable the instant it exits (Popen.wait polls)
        try:
            signalled = time.monotonic()
            terminal.process.send_signal(signum)
            select.select([ended], [], [], WAIT_S)
            exited = time.monotonic()
        finally:
            os.close(ended)
    finally:
        terminal.close()
    said = (_first(terminal.err, signalled, lambda text: "interrupted by" in text), _first(terminal.out, signalled))
    reported = min((t for t in said if t is not None), default=exited)
    code, err = terminal.process.returncode, _lines(terminal.err)
    problems = [f"exit {code}, not {128 + signum}"] * (code != 128 + signum)
    reports = "--json" in argv
    problems += [f"{len(err)} lines on stderr: {err}"] * (len(err) > 1 or (not reports and len(err) != 1))
    problems += ["a traceback"] * any(
        "Traceback" in line for line in err)
    left = sorted(p.name for p in Path(workdir).iterdir())
    problems += [f"files left: {sorted(set(left) - set(before))}"] * (left != before)
    run = {"percent": percent, "shown_percent": shown, "reported_ms": 1e3 * (reported - signalled),
           "exit_ms": 1e3 * (exited - signalled), "problems": problems}
    if reports:
        try:
            report = json.loads("".join(piece for _, piece in terminal.out))
            run["samples_after_signal"] = report["samples"] - round(shown / 100.0 * samples)
            problems += ["report not marked interrupted"] * (not report["interrupted"])
        except (ValueError, KeyError) as error:
            problems.append(f"no JSON report ({error})")
    return run


def machine_facts(seconds=2.0):
    """What the figures depend on: CPUs, load, the rclpy hop, the machine's wake-up floor."""
    from drive_common.runtime.realtime import stall_report, wakeup_latencies
    from drive_tools.launch.hop_cost import HOP_ROUND_TRIPS_BESIDE_A_RUN, hop_latency
    late, _ = wakeup_latencies(seconds)
    floor = stall_report(late, 1e-3)
    return {"cpus": os.cpu_count(), "load_average": [round(x, 2) for x in os.getloadavg()],
            "hop_us": round(hop_latency(HOP_ROUND_TRIPS_BESIDE_A_RUN)["us_per_hop"], 1),
            "wakeup_p99_us": round(floor["latency_p99_us"]), "wakeup_max_us": round(floor["latency_max_us"])}


def point_name(percent):
    return "start" if percent is None else f"{percent:g} %"


def _figures(values):
    values = [v for v in values if v is not None]
    if not values:
        return None
    return {"best": round(min(values), 1), "median": round(median(values), 1), "max": round(max(values), 1)}


def stop_bench(scenario="wang_100rpm", cases=tuple(STOP_CASES), repeats=3, points=POINTS_PERCENT, progress=None):
    """Each case stopped by SIGINT and by SIGTERM at each point, ``repeats`` times, in a fresh directory
    each time; per case and point the latencies' best/median/max [ms] and every problem seen."""
    from drive_common.config.scenario import load_scenario
    from drive_common.runtime.realtime import stolen_s
    T_s = load_scenario(scenario).T_s
    with tempfile.TemporaryDirectory() as warm:
        subprocess.run([sys.executable, "-m", "drive_tools.cli", "run", scenario, "--duration", "0.01", "--no-plot"],
                       cwd=warm, capture_output=True)
    machine = machine_facts()
    stolen = stolen_s()
    results = []
    for case in cases:
        template, part = STOP_CASES[case]
        argv = [arg.format(scenario=scenario, duration=RUN_DURATION_S) for arg in template]
        for percent in (p for p in points if p is not None or part > 0):
            runs = []
            for signum in (signal.SIGINT, signal.SIGTERM):
                for repeat in range(repeats):
                    if progress:
                        progress(f"{case}, {signal.Signals(signum).name} at {point_name(percent)}: {repeat + 1} of "
                                 f"{repeats}")
                    with tempfile.TemporaryDirectory() as workdir:
                        runs.append({"signal": signal.Signals(signum).name,
                                     **stop_once(argv, part, percent, signum, workdir,
                                                 round(RUN_DURATION_S / T_s) if case == "run" else None)})
            results.append({"case": case, "point": point_name(percent), "command": "drive " + " ".join(argv),
                            "runs": runs, "reported_ms": _figures(r.get("reported_ms") for r in runs),
                            "exit_ms": _figures(r.get("exit_ms") for r in runs),
                            "samples_after_signal_max": max((r["samples_after_signal"] for r in runs
                                                             if r.get("samples_after_signal") is not None),
                                                            default=None),
                            "clean": sum(not r["problems"] for r in runs),
                            "problems": sorted({p for r in runs for p in r["problems"]})})
    machine["stolen_ms"] = round(1e3 * sum(after - stolen.get(cpu, after) for cpu, after in stolen_s().items()))
    return {"benchmark": "stop", "scenario": scenario, "repeats": repeats,
            "machine": machine, "results": results}


def stop_lines(report):
    """The bench's table as text lines."""
    m = report["machine"]
    lines = [f"drive bench stop: {report['scenario']}, SIGINT and SIGTERM {report['repeats']} times each per case "
             f"and point; {m['cpus']} CPUs, load {' '.join(map(str, m['load_average']))}, rclpy hop {m['hop_us']} "
             f"µs, wake-up p99 {m['wakeup_p99_us']} µs (max {m['wakeup_max_us']}), stolen by the host "
             f"{m['stolen_ms']} ms",
             f"{'case':22s} {'point':6s} {'stop reported [ms]':>22s} {'exit [ms]':>22s}  clean",
             f"{'':29s} {'best / median / max':>22s} {'best / median / max':>22s}"]
    for r in report["results"]:
        cells = ["n/a" if f is None else f"{f['best']:.0f} / {f['median']:.0f} / {f['max']:.0f}"
                 for f in (r["reported_ms"], r["exit_ms"])]
        after = f"  ({r['samples_after_signal_max']} samples after the signal, at most)" \
            if r["samples_after_signal_max"] is not None else ""
        lines.append(f"{r['case']:22s} {r['point']:6s} {cells[0]:>22s} {cells[1]:>22s}  {r['clean']}/"
                     f"{len(r['runs'])}{after}")
        lines += [f"  problem: {p}" for p in r["problems"]]
    return lines
