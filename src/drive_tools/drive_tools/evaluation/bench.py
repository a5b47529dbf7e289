"""``drive bench throughput``: closed-loop samples per second of the one-process runner, per estimator,
and of motulator's signal-injection example when motulator is installed (a side environment is fine).
``drive bench graph``: real-time factor of the lock-step ROS graph. ``drive bench blocks``: what the block
size costs and buys, graph speed against ours' angle error."""
import contextlib
import dataclasses
import importlib.util
import json
import os
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from drive_common.config.scenario import PACED_BLOCK_SAMPLES, load_scenario
from drive_common.contract.log import LOG_COLUMNS
from drive_common.runtime import interrupt
from drive_common.runtime.realtime import ROBOT_RT_PRIORITY, stolen_s
from drive_tools.runner.runner import build_drive
from hf_estimator.build import refusable

BENCH_SCENARIO = "wang_100rpm"


def throughput(estimator, samples=1_000_000, chunk=50_000, repeats=3, scenario_name=BENCH_SCENARIO):
    """Samples/s of the compiled closed loop (plant + estimator + controller + logging) on one core.

    The loop is compiled and warmed up first; each of ``repeats`` timed runs continues the same drive for
    ``samples`` samples in chunks that reuse one log buffer, as a long ``drive run`` does between
    progress reports. Reports the best run (as timeit does: the others lost time to the machine) and
    the median. The drive runs as `drive run --force` would: a bench of its speed, not of whether the motor
    suits the estimator (the I-f start refuses the bench's low speeds).
    """
    scenario = load_scenario(scenario_name, estimator_override=estimator)
    forced = {"run_refused": True} if refusable(estimator) else {}
    scenario = dataclasses.replace(scenario, duration_s=(repeats * samples + chunk) * scenario.T_s,
                                   estimator_settings={**scenario.estimator_settings, **forced})
    drive = build_drive(scenario)
    log = np.zeros((chunk, len(LOG_COLUMNS)))
    drive.run(0, chunk, log)
    walls, cpus = [], []
    for r in range(repeats):
        first = chunk + r * samples
        start, start_cpu = time.perf_counter(), time.process_time()
        for k0 in range(first, first + samples, chunk):
            k1 = min(k0 + chunk, first + samples)
            drive.run(k0, k1, log[:k1 - k0])
        walls.append(time.perf_counter() - start)
        cpus.append(time.process_time() - start_cpu)
    return {"estimator": estimator, "scenario": scenario_name, "samples": samples, "repeats": repeats,
            "wall_time_s": min(walls), "samples_per_second": samples / min(walls),
            "samples_per_second_median": samples / float(np.median(walls)),
            "cpu_time_s": min(cpus), "samples_per_cpu_second": samples / min(cpus),
            "samples_per_cpu_second_median": samples / float(np.median(cpus))}


REPOSITORY = Path(__file__).resolve().parents[4]
"""The repository this drive runs from (its git history holds the commits ``throughput_against`` times)."""


def _cli(tree):
    """The command line of ``drive`` in the source tree ``tree``: ``drive_cli.cli`` in a commit of the 14
    packages before the merge into six, ``drive_tools.cli.cli`` since."""
    return [sys.executable, "-m", "drive_cli.cli" if (tree / "src" / "drive_cli").is_dir() else "drive_tools.cli.cli"]


def _tree_estimators(tree, environment):
    """The estimators the drive in source tree ``tree`` knows (``drive estimators --json``)."""
    proc = subprocess.run(_cli(tree) + ["estimators", "--json"], cwd=tree, env=environment, capture_output=True,
                          text=True)
    try:
        return {row["name"] for row in json.loads(proc.stdout)}
    except (ValueError, KeyError, TypeError):
        return set()


CPU_CLOCK_THROUGHPUT = """import json, sys, time
time.perf_counter = time.process_time
try:
    from drive_tools.evaluation.bench import throughput
except ImportError:
    from drive_evaluation.bench import throughput
print(json.dumps({name: throughput(name, samples=int(sys.argv[1]), repeats=1)["samples_per_second"]
                  for name in sys.argv[2].split(",")}))
"""
"""A source tree's own ``throughput`` timed on its process's CPU clock: what the loop costs, whatever else
the machine runs (on a shared machine the wall clock also counts the waits for a core)."""


def _tree_throughput(tree, estimators, samples, environment):
    """One run of the throughput bench of source tree ``tree`` in its own process, on its CPU clock
    ({estimator: samples per CPU second}), or {"error": ...} with the tail of what it printed."""
    if not estimators:
        return {"error": "knows none of the estimators"}
    proc = subprocess.run([sys.executable, "-c", CPU_CLOCK_THROUGHPUT, str(samples), ",".join(estimators)],
                          cwd=tree, env=environment, capture_output=True, text=True)
    try:
        return json.loads(proc.stdout.strip().splitlines()[-1])
    except (ValueError, IndexError):
        return {"error": (proc.stderr or proc.stdout).strip().splitlines()[-1:] or [f"exit {proc.returncode}"]}


def throughput_against(commit, estimators, samples=1_000_000, rounds=3, progress=None):
    """Samples per CPU second of today's closed loop and of commit ``commit``'s, each its own throughput
    bench in its own process on its CPU clock (CPU_CLOCK_THROUGHPUT; this venv; the commit's package
    directories first on PYTHONPATH, from a git worktree in a temporary directory), alternating ``rounds``
    times so that both meet the same machine load.
    Per estimator: the best and the median of each, and their ratios today / then (an estimator the
    commit did not have: today's alone)."""
    import tempfile

    resolved = subprocess.run(["git", "-C", str(REPOSITORY), "rev-parse", "--verify", f"{commit}^{{commit}}"],
                              capture_output=True, text=True)
    if resolved.returncode:
        raise ValueError(f"{commit!r} is not a commit of {REPOSITORY}")
    sha = resolved.stdout.strip()
    runs = {"today": [], sha[:7]: []}
    with tempfile.TemporaryDirectory(prefix="drive-bench-") as scratch:
        old = Path(scratch) / sha[:7]
        subprocess.run(["git", "-C", str(REPOSITORY), "worktree", "add", "--detach", "--quiet", str(old), sha],
                       check=True)
        try:
            old_path = os.pathsep.join(str(d) for d in sorted((old / "src").glob("*/")) if d.is_dir())
            old_env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [old_path,
                                                                                 os.environ.get("PYTHONPATH")]))}
            known = _tree_estimators(old, old_env)
            trees = (("today", REPOSITORY, dict(os.environ), estimators),
                     (sha[:7], old, old_env, [name for name in estimators if name in known]))
            for r in range(rounds):
                for label, tree, environment, names in trees:
                    runs[label].append(_tree_throughput(tree, names, samples, environment))
                    if progress:
                        progress(f"round {r + 1}/{rounds}: {label} timed")
        finally:
            subprocess.run(["git", "-C", str(REPOSITORY), "worktree", "remove", "--force", str(old)],
                           capture_output=True)
    results = {}
    for name in estimators:
        row = {}
        for label, measured in runs.items():
            rates = [run[name] for run in measured if name in run]
            row[label] = ({"best": max(rates), "median": float(np.median(rates)), "runs": len(rates)} if rates else
                          {"error": next((run["error"] for run in measured if "error" in run), "not in this commit")})
        if "best" in row["today"] and "best" in row[sha[:7]]:
            row["ratio_best"] = row["today"]["best"] / row[sha[:7]]["best"]
            row["ratio_median"] = row["today"]["median"] / row[sha[:7]]["median"]
        results[name] = row
    return {"benchmark": "throughput_against", "commit": sha, "label": sha[:7], "samples": samples,
            "rounds": rounds, "results": results}


MOTULATOR_VENV = Path(__file__).resolve().parents[4] / ".venv-motulator" / "bin" / "python"
"""Where ``./setup.sh --with-motulator`` puts the side environment (motulator needs Python ≥ 3.12)."""


def motulator_python():
    """The interpreter that has motulator: $DRIVE_MOTULATOR_PYTHON, the repository's .venv-motulator,
    or this one; None if none has it."""
    candidates = [os.environ.get("DRIVE_MOTULATOR_PYTHON"), str(MOTULATOR_VENV)]
    for candidate in candidates:
        if candidate and Path(candidate).is_file():
            return candidate
    return sys.executable if importlib.util.find_spec("motulator") else None


def motulator_throughput(python, timeout_s=900.0):
    """Time motulator's 2.2-kW PMSM signal-injection example with ``python`` (drive_tools.evaluation.
    motulator_reference); returns its JSON result, or {"error": ...} naming what failed."""
    script = Path(__file__).with_name("motulator_reference.py")
    try:
        proc = subprocess.run([python, str(script)], capture_output=True, text=True, timeout=timeout_s)
    except (OSError, subprocess.TimeoutExpired) as error:
        return {"error": f"{python} {script.name}: {error}"}
    if proc.returncode != 0:
        last = (proc.stderr.strip().splitlines() or ["no output"])[-1]
        return {"error": f"{python} {script.name} exited {proc.returncode}: {last}"}
    return {**json.loads(proc.stdout.strip().splitlines()[-1]), "python": python}


GRAPH_CONFIGURATIONS = (("composed", "events"), ("composed", "single"), ("separate", "events"))
INTRA_PROCESS = ("composed", "events", "intra")
"""The configuration `drive bench graph --intra-process` adds: composed, the controller taking the estimator's
answers directly (launch's ``intra_process``; launcher.DELIVERIES_PER_SAMPLE_INTRA_PROCESS messages per block)."""


def graph_throughput(scenario_name=BENCH_SCENARIO, duration_s=0.5, record=False, repeats=2, progress=None,
                     block_sizes=(1,), configurations=GRAPH_CONFIGURATIONS):
    """Real-time factor (simulated / wall time) of the lock-step graph per block size N (``block_sizes``;
    1: one message per sample) and (processes, executor[, "intra"]), best and median of ``repeats`` runs after a
    short warm-up run; the wall time per sample and per delivered message (launcher.DELIVERIES_PER_SAMPLE
    messages per block), and the ping-pong hop time that bounds it. A signal stops it: the
    configurations done are returned, ``interrupted`` names the signal, and the one cut (a configuration
    or the ping-pong) is left out."""
    report = {"benchmark": "graph", "scenario": scenario_name, "duration_s": duration_s, "record": record,
              "sampling_rate_Hz": 1.0 / load_scenario(scenario_name).T_s, "results": [], "interrupted": 0}
    with interrupt.polled():
        _graph_runs(report, scenario_name, duration_s, record, repeats, progress, block_sizes, configurations)
    return report


def _graph_runs(report, scenario_name, duration_s, record, repeats, progress, block_sizes, configurations):
    """graph_throughput's runs into ``report``, stopping at the first signal (polled between steps)."""
    from drive_tools.launch.launcher import (
        DELIVERIES_PER_SAMPLE,
        DELIVERIES_PER_SAMPLE_INTRA_PROCESS,
        DriveSpec,
        GraphOptions,
        launch,
    )

    results = report["results"]
    report["interrupted"] = launch(DriveSpec(scenario_name, duration_s=0.05), GraphOptions(record=record)).interrupted
    if report["interrupted"]:
        return
    for (processes, executor, *intra), block in ((c, n) for n in block_sizes for c in configurations):
        walls, samples = [], 0
        deliveries = DELIVERIES_PER_SAMPLE_INTRA_PROCESS if intra else DELIVERIES_PER_SAMPLE
        for _ in range(repeats):
            r = launch(DriveSpec(scenario_name, duration_s=duration_s, extra_parameters={"block_samples": block}),
                       GraphOptions(processes, executor, record, intra_process=bool(intra)))
            report["interrupted"] = r.interrupted or interrupt.requested()
            if report["interrupted"]:
                return
            walls.append(r.wall_time_s)
            samples = r.scenario.n_samples
        wall, median = min(walls), float(np.median(walls))
        entry = {"processes": processes, "executor": executor, "intra_process": bool(intra),
                 "block_samples": block, "record": record,
                 "samples": samples, "repeats": repeats, "wall_time_s": wall,
                 "real_time_factor": samples * r.scenario.T_s / wall,
                 "real_time_factor_median": samples * r.scenario.T_s / median,
                 "us_per_sample": 1e6 * wall / samples,
                 "us_per_delivered_message": 1e6 * wall * block / samples / deliveries}
        results.append(entry)
        if progress:
            label = f"{processes}{'-intra' if intra else ''}"
            progress(f"  N = {block:<3d} {label:15s} {executor:7s} real-time factor {entry['real_time_factor']:.3f} "
                     f"(median {entry['real_time_factor_median']:.3f}; {entry['us_per_sample']:.0f} µs per sample, "
                     f"{entry['us_per_delivered_message']:.0f} µs per delivered message)")
    from drive_tools.launch.hop_cost import hop_latency

    hop = hop_latency()
    report["interrupted"] = interrupt.requested()
    if report["interrupted"]:
        return
    if progress:
        progress(f"  ping-pong of one Vector3Stamped between two nodes in one process (events executor): "
                 f"{hop['us_per_hop']:.1f} µs per hop")
    report["ping_pong"] = hop


BLOCK_SCENARIOS = ("wang_100rpm", "wang_load_step", "wang_reversal", "wang_speed_step")
BLOCK_CONFIGURATIONS = (("composed", "events"), ("separate", "events"))


def block_size_table(block_sizes, scenarios=BLOCK_SCENARIOS, duration_s=0.5, repeats=2, progress=None):
    """Per block size N: the graph's real-time factor composed and separate (``graph_throughput``) and
    ours' angle error on each scenario run in one process with that N (the same samples as the graph).
    A signal stops it; ``interrupted`` names it and what was done is returned."""
    from drive_tools.runner.runner import run_scenario

    from .metrics import compute_metrics

    report = {"benchmark": "blocks", "block_samples": list(block_sizes), "angle_error": [], "interrupted": 0,
              "graph": graph_throughput(duration_s=duration_s, repeats=repeats, progress=progress,
                                        block_sizes=block_sizes, configurations=BLOCK_CONFIGURATIONS)}
    report["interrupted"] = report["graph"]["interrupted"]
    for block in block_sizes if not report["interrupted"] else ():
        for name in scenarios:
            scenario = dataclasses.replace(load_scenario(name), block_samples=block)
            result = run_scenario(scenario)
            if result.interrupted:
                report["interrupted"] = result.interrupted
                return report
            m = compute_metrics(result)
            row = {"block_samples": block, "scenario": name, "delay_periods": scenario.drive_delay_periods(),
                   **{key: m[key] for key in ("angle_error_rms", "angle_error_bias", "angle_error_peak",
                                              "lock_lost_s")}}
            report["angle_error"].append(row)
            if progress:
                progress(f"  N = {block:<3d} {name:16s} RMS {row['angle_error_rms']:.4f}  bias "
                         f"{row['angle_error_bias']:+.4f}  peak {row['angle_error_peak']:.4f}  lost "
                         f"{row['lock_lost_s']:.3f} s")
    return report


def link_echo_us(link, rounds=2000):
    """Median round trip [µs] of a bare 22-byte echo over the link kind (a pty between two threads, or
    python-can's virtual bus): the floor under one closed-loop sample, without any protocol work."""
    import os
    import select
    import threading
    import tty

    times = np.zeros(rounds)
    if link == "pty":
        master, slave = os.openpty()
        tty.setraw(master)
        tty.setraw(slave)

        def echo():
            for _ in range(rounds):
                select.select([master], [], [])
                os.write(master, os.read(master, 64))
        thread = threading.Thread(target=echo, daemon=True)
        thread.start()
        for i in range(rounds):
            start = time.perf_counter()
            os.write(slave, bytes(22))
            select.select([slave], [], [])
            os.read(slave, 64)
            times[i] = time.perf_counter() - start
        thread.join()
        os.close(master)
        os.close(slave)
    else:
        import can
        channel = f"echo_{os.getpid()}"
        near, far = (can.Bus(interface="virtual", channel=channel) for _ in range(2))

        def echo():
            for _ in range(rounds):
                far.send(far.recv())
        thread = threading.Thread(target=echo, daemon=True)
        thread.start()
        frame = can.Message(arbitration_id=0x109, data=bytes(8), is_extended_id=False)
        for i in range(rounds):
            start = time.perf_counter()
            near.send(frame)
            near.recv()
            times[i] = time.perf_counter() - start
        thread.join()
        near.shutdown()
        far.shutdown()
    return float(np.median(times) * 1e6)


def _percentile(values, q):
    """The q-th percentile of ``values``, None when there are none."""
    return float(np.percentile(values, q)) if len(values) else None


def bridge_rates(scenario_ref, links, duration_s, repeats=3, paced=False, block_samples=None, answer=None):
    """`drive bench bridge`: the sensorless loop through the bridge and the virtual inverter per link.
    Waiting for the host's answers (default): the sustained rate, best of ``repeats`` after a warm-up.
    ``paced``: the inverter on its own clock at the scenario's rate, never waiting: missing (late)
    commands and their latency, and the angle error of the run, worst of ``repeats``. Latency: the
    inverter's time from sending TELEMETRY(k) to receiving COMMAND(k); host: the host's part of it
    (telemetry decoded, estimator and controller run, command encoded and written). ``block_samples``:
    N (None: the scenario's). ``answer`` (compiled_answer.AnswerOptions; None: the answer in Python): the
    answer compiled whole on the pty (the CAN link keeps the Python answer); each row says which ran, with the
    samples its ring had no room for. Beside them the machine's rclpy hop cost (``hop_us``) and the latencies
    in hops, so that figures compare across machines."""
    from drive_tools.doubles.virtual_inverter import InverterOptions
    from drive_tools.evaluation.metrics import compute_metrics
    from drive_tools.launch.hop_cost import HOP_ROUND_TRIPS_BESIDE_A_RUN, hop_latency
    from drive_tools.runner.bridge_loop import run_through_bridge

    scenario = load_scenario(scenario_ref)
    if duration_s is not None:
        scenario = dataclasses.replace(scenario, duration_s=duration_s)
    rate = 1.0 / scenario.T_s if paced else None
    blocks = block_samples or scenario.block_samples
    linked = dataclasses.replace(scenario, block_samples=blocks)
    rows = []
    hop_us = hop_latency(HOP_ROUND_TRIPS_BESIDE_A_RUN)["us_per_hop"]
    for link in links:
        compiled = answer
        run_through_bridge(dataclasses.replace(linked, duration_s=min(scenario.duration_s, 0.05)), link,
                           answer=compiled)
        best = None
        for _ in range(repeats):
            result = run_through_bridge(linked, link, InverterOptions(rate_Hz=rate), answer=compiled)
            if best is None or (result.timing["missing"] > best.timing["missing"] if paced
                                else result.wall_time_s < best.wall_time_s):
                best = result
        latencies, host = best.latencies_s * 1e6, best.host_s * 1e6
        row = {"link": link, "block_samples": blocks, "samples_per_s": best.log.shape[0] / best.wall_time_s,
               "latency_p50_us": _percentile(latencies, 50), "latency_p99_us": _percentile(latencies, 99),
               "host_p50_us": _percentile(host, 50), "host_p99_us": _percentile(host, 99),
               "link_echo_us": link_echo_us(link),
               "missing_commands": int(best.inverter_counters["missing"]), "hop_us": hop_us,
               "answer": "compiled" if compiled else "python", "ring_overflow": best.counters.get("ring_overflow"),
               "scheduling": best.scheduling}
        row.update({key.replace("_us", "_hops"): row[key] / hop_us if row[key] is not None else None
                    for key in ("latency_p50_us", "latency_p99_us", "host_p50_us", "host_p99_us")})
        if paced:
            metrics = compute_metrics(best)
            row.update(best.timing)
            row.update({key: metrics[key] for key in ("angle_error_rms", "angle_error_bias", "angle_error_peak",
                                                      "lock_lost")})
        rows.append(row)
    return {"scenario": scenario.name, "samples": scenario.n_samples, "repeats": repeats, "paced": paced,
            "sampling_rate_Hz": 1.0 / scenario.T_s, "links": rows}


_FIFO_CPU1 = {"rt_priority": ROBOT_RT_PRIORITY, "cpus": {1}}
_ROBOT = {**_FIFO_CPU1, "workqueue_cpus": {1}, "intra_process": True}
REAL_TIME_LEVERS = {"plain": {"hold_collector": False}, "collector": {}, "collector+cpu1": {"cpus": {1}},
                    "collector+fifo": {"rt_priority": ROBOT_RT_PRIORITY},
                    "collector+fifo+cpu1": _FIFO_CPU1,
                    "collector+fifo+cpu1+inverter_apart": {**_FIFO_CPU1, "inverter_apart": True},
                    "collector+fifo+cpu1+workqueue1": {**_FIFO_CPU1, "workqueue_cpus": {1}},
                    "collector+fifo+cpu1+workqueue1+intra": _ROBOT,
                    "collector+fifo+cpu1+workqueue1+intra+pmqos": {**_ROBOT, "cpu_dma_latency_us": 0},
                    "collector+fifo+cpu1+workqueue1+intra+inverter_apart": {**_ROBOT, "inverter_apart": True},
                    "robot": {**_ROBOT, "answer": {}},
                    "robot+inverter_apart": {**_ROBOT, "answer": {}, "inverter_apart": True},
                    "robot+publisher_sleep_50ms": {**_ROBOT, "answer": {"reader_stall_s": 0.05}},
                    "robot+collect_every_100ms": {**_ROBOT, "answer": {}, "forced_collection_s": 0.1}}
"""The soft real-time levers `drive bench bridge --paced --graph` measures one at a time (docs/ros-graph.md,
"Real time"): none; the garbage collector held out of the sample path (the default); and the process on
CPU 1; and SCHED_FIFO priority 50 (on every CPU, or on CPU 1); and the kernel's unbound workqueues (a serial
link's bytes pass through one) on CPU 1 too; and the controller taking the estimator's answers directly
(intra_process: four deliveries a block fewer); and the CPUs kept out of idle states slower to leave than
0 µs (pmqos: PM QoS, /dev/cpu_dma_latency). The virtual inverter runs on a thread of the graph's process
but in inverter_apart, where it has a process of its own (on the CPU the graph leaves). ``robot``: `drive
launch --link L --paced` as it runs by default, the answer compiled (``answer``: its AnswerOptions'
fields); ``robot+inverter_apart``: the same with the virtual inverter in
a process of its own, judged by the host's write and the wire as on a thread (the host's ring of writes in shared
memory); and the stalls of its side that is not real-time: the
ring's reader (the publisher and the log's writer) sleeping 50 ms after each read, a full garbage collection
forced every 100 ms on a thread of the drive's process (``forced_collection_s``). Each lever's keys are
launch's: RealTime's fields, GraphOptions' ``intra_process`` and ``answer``, DriveSpec's
``inverter_apart``."""


def lever_launch(lever, link):
    """(GraphOptions, inverter_apart, the period of forced collections [s] or None) of ``lever`` (a
    REAL_TIME_LEVERS name) on ``link``, as launch takes them (drive_tools.launch.launcher: RealTime,
    GraphOptions, DriveSpec)."""
    from drive_tools.launch.launcher import GraphOptions, RealTime
    from drive_tools.runner.compiled_answer import AnswerOptions
    settings = dict(REAL_TIME_LEVERS[lever])
    intra_process, inverter_apart = settings.pop("intra_process", False), settings.pop("inverter_apart", False)
    answer, collection_s = settings.pop("answer", None), settings.pop("forced_collection_s", None)
    answer = AnswerOptions(**answer) if answer is not None else None
    return (GraphOptions(intra_process=intra_process, real_time=RealTime(**settings), answer=answer),
            inverter_apart, collection_s)


@contextlib.contextmanager
def collections_forced(period_s):
    """A thread of this process forcing a full garbage collection every ``period_s`` [s] (None: none), the
    interpreter's lock held meanwhile: a stall of the drive's side that is not real-time."""
    if period_s is None:
        yield
        return
    import gc
    import threading
    stop = threading.Event()

    def collect():
        while not stop.wait(period_s):
            gc.collect()
    thread = threading.Thread(target=collect, name="forced_collections", daemon=True)
    thread.start()
    try:
        yield
    finally:
        stop.set()
        thread.join()


@dataclass(frozen=True)
class RealTimeBench:
    """What `drive bench bridge --paced --graph` runs: per link of ``links`` and lever of ``levers``
    (REAL_TIME_LEVERS' names), ``repeats`` runs in blocks of ``block_samples``; with ``load`` another process
    keeps one core busy meanwhile; ``lose_command_every``: the inverter (a faulty double,
    drive_tools.doubles.faults) loses every Nth command block (ours' degradation; 0: none);
    ``watch_machine``: beside each run a process above the drive's priority on its CPUs notes when the
    machine stalls (drive_common.runtime.machine_watch)."""

    links: tuple = ("pty", "can")
    repeats: int = 3
    load: bool = False
    levers: tuple = tuple(REAL_TIME_LEVERS)
    block_samples: int = PACED_BLOCK_SAMPLES
    lose_command_every: int = 0
    watch_machine: bool = False


@contextlib.contextmanager
def core_kept_busy(load=True):
    """With ``load``, another process spinning meanwhile (one core kept busy); else nothing."""
    busy = subprocess.Popen([sys.executable, "-c", "while True: pass"]) if load else None
    try:
        yield
    finally:
        if busy is not None:
            busy.kill()
            busy.wait()


def machine_stalls(report, timing):
    """What the machine watch saw during one run (None: it gave nothing): how many of its stalls were over
    0.5 ms, all of them together [ms], the run's runs of late periods and how many the stalls explain."""
    from drive_common.runtime.machine_watch import missing_runs_explained
    windows = timing["missing_runs"]["windows_monotonic_s"]
    if report is None:
        return {"watched": False, "missing_runs": len(windows)}
    stalls = report["stalls"]
    latency_s = 1e-6 * (timing["latency_p50_us"] or 0.0)
    return {"watched": not report["scheduling"]["refused"], "wakeups": report["wakeups"],
            "stalls_over_0_5_ms": sum(late > 5e-4 for _, late in stalls),
            "stalled_ms": round(1e3 * sum(late for _, late in stalls), 3), "missing_runs": len(windows),
            "missing_runs_explained": missing_runs_explained(windows, stalls, latency_s)}


def machine_line(machine):
    """``explained/late`` of one run, ``?`` where the watch was refused its priority."""
    if not machine["watched"]:
        return f"?/{machine['missing_runs']}"
    return f"{machine['missing_runs_explained']}/{machine['missing_runs']}"


def figures(runs, key):
    """The runs' ``key`` figures for a progress line, rounded; ``?`` for a run that has none (it measured no
    answer: a run cut short)."""
    return ", ".join("?" if r[key] is None else f"{r[key]:.0f}" for r in runs)


def graph_real_time(scenario_ref, bench=None, progress=None):
    """`drive bench bridge --paced --graph`: the robot's configuration, `drive launch --link L --paced`
    (the composed graph behind the virtual inverter on its own clock, in blocks), run as ``bench``
    (RealTimeBench; None: its defaults) says. Per run: late periods, watchdog trips, lock losses, ours' angle
    error and the latencies in µs and in hops (each run measures the rclpy hop beside it); with the machine
    watched, how many of its late blocks the machine explains. A signal stops it; what was done is returned."""
    from drive_common.runtime.machine_watch import MachineWatch
    from drive_tools.doubles.faults import FaultPlan, faulty
    from drive_tools.doubles.virtual_inverter import VirtualInverter
    from drive_tools.launch.launcher import DriveSpec, launch

    from .metrics import compute_metrics
    from .speed_range import meets_targets

    bench = bench or RealTimeBench()
    scenario = load_scenario(scenario_ref)
    report = {"benchmark": "graph_real_time", "scenario": scenario.name, "samples": scenario.n_samples,
              "block_samples": bench.block_samples, "repeats": bench.repeats, "load": bench.load,
              "lose_command_every": bench.lose_command_every, "rows": [], "interrupted": 0}
    watch_machine, every = bench.watch_machine, bench.lose_command_every
    with core_kept_busy(bench.load), interrupt.polled():
        for link in bench.links:
            for lever in bench.levers:
                runs = []
                options, inverter_apart, collection_s = lever_launch(lever, link)
                real_time = options.real_time
                for _ in range(bench.repeats):
                    stolen_before = stolen_s()
                    inverter = faulty(FaultPlan(lose_command_every=every)) if every else VirtualInverter
                    drive = DriveSpec(scenario_ref, extra_parameters={"block_samples": bench.block_samples},
                                      link=link, paced=True, inverter_apart=inverter_apart, inverter=inverter)
                    with (MachineWatch(real_time.rt_priority + 1, real_time.cpus)
                          if watch_machine else contextlib.nullcontext()) as watch, collections_forced(collection_s):
                        result = launch(drive, options)
                    report["interrupted"] = result.interrupted or interrupt.requested()
                    if report["interrupted"]:
                        return report
                    metrics, t = compute_metrics(result), result.timing
                    runs.append({"late_fraction": t["late_fraction"], "watchdog_trips": t["watchdog_trips"],
                                 "meets_targets": meets_targets(metrics),
                                 "overruns": t["overruns"], "lock_lost": metrics["lock_lost"],
                                 "lock_lost_s": metrics["lock_lost_s"],
                                 "angle_error_rms": metrics["angle_error_rms"],
                                 "angle_error_peak": metrics["angle_error_peak"],
                                 "missing_samples": sum(result.missing_samples.values()),
                                 "answer": result.answer,
                                 **{key: t[key] for key in ("missing_runs", "missing_runs_written_in_time",
                                                            "missing_runs_written_before_due_us", "in_time_by",
                                                            "sent_late_in_time", "read_late_in_time", "hop_us",
                                                            "latency_p50_us", "latency_p99_us",
                                                            "latency_max_us", "latency_p50_hops",
                                                            "latency_p99_hops", "latency_max_hops",
                                                            "answer_p50_us", "answer_p99_us", "answer_max_us",
                                                            "answer_p50_hops", "answer_p99_hops", "never_answered")},
                                 "scheduling": result.scheduling,
                                 "stolen_ms": {cpu: round(1e3 * (after - stolen_before[cpu]))
                                               for cpu, after in stolen_s().items() if cpu in stolen_before},
                                 **({"machine": machine_stalls(watch.report, t)} if watch_machine else {})})
                worst = max(runs, key=lambda r: r["late_fraction"])
                row = {"link": link, "lever": lever, "runs": runs, "worst_late_fraction": worst["late_fraction"],
                       "runs_without_a_late_period": sum(r["late_fraction"] == 0.0 for r in runs),
                       "watchdog_trips": sum(r["watchdog_trips"] for r in runs),
                       "runs_lock_held": sum(r["lock_lost_s"] == 0.0 for r in runs),
                       "runs_meeting_targets": sum(r["meets_targets"] for r in runs)}
                report["rows"].append(row)
                if progress:
                    late = ", ".join(f"{100 * r['late_fraction']:.2f}" for r in runs)
                    p99 = figures(runs, "latency_p99_hops")
                    stolen_ms = ", ".join(str(sum(r["stolen_ms"].values())) for r in runs)
                    progress(f"  {link:4s} {lever:20s} late {late} %, watchdog trips {row['watchdog_trips']}, "
                             f"lock held in {row['runs_lock_held']} of {len(runs)}, ours within its targets in "
                             f"{row['runs_meeting_targets']}, latency p99 {p99} hops "
                             f"(hop {runs[0]['hop_us']:.1f} µs), stolen by the host {stolen_ms} ms")
                    if any(r["missing_samples"] for r in runs):
                        missing = ", ".join(str(r["missing_samples"]) for r in runs)
                        progress(f"       samples that never reached the launcher's log: {missing}")
                    if any(r["answer_p99_us"] is not None for r in runs):
                        answers = figures(runs, "answer_p99_us")
                        progress(f"       the drive's answer (telemetry sent to command written) p99 {answers} µs")
                    written = ", ".join(f"{r['missing_runs_written_in_time']}/{r['missing_runs']['count']}"
                                        if r["missing_runs_written_in_time"] is not None else "?" for r in runs)
                    progress(f"       late blocks whose command had arrived in time (the host's write and the wire): "
                             f"{written}")
                    simulation = ", ".join(f"{r['sent_late_in_time']}/{r['read_late_in_time']}" for r in runs)
                    progress(f"       periods in time that the simulated inverter sent late / read late "
                             f"(judged by {runs[0]['in_time_by']}): {simulation}")
                    if watch_machine:
                        explained = ", ".join(machine_line(r["machine"]) for r in runs)
                        progress(f"       late blocks the machine's stalls explain: {explained}")
                    for line in sorted({line for r in runs for line in r["scheduling"]["refused"]}):
                        progress(f"       {lever}: {line}")
    return report
