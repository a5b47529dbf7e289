"""Soft real time of a drive's process (drive_common.runtime.realtime): the garbage collector held out of the
sample path and given back, scheduling that the system refuses said in one line, CPU lists checked, the
kernel's unbound workqueues moved for a run and put back."""
import argparse
import gc
import os
import re
import sys
import time

import numpy as np
import pytest

from drive_common.runtime import realtime

pytestmark = pytest.mark.unit


def test_the_collector_is_held_for_the_run_and_given_back():
    before = sys.getswitchinterval()
    with realtime.collector_held(switch_s=1e-4):
        assert not gc.isenabled() and gc.get_freeze_count() > 0
        assert sys.getswitchinterval() == pytest.approx(1e-4)
        cycle = []
        cycle.append(cycle)
        del cycle
        assert realtime.collect_young() > 0.0
    assert gc.isenabled() and gc.get_freeze_count() == 0 and sys.getswitchinterval() == before
    assert realtime.collect_young() == 0.0


def test_scheduling_the_system_refuses_is_one_line_not_an_error(monkeypatch):
    def refuse(*_):
        raise PermissionError(1, "Operation not permitted")
    monkeypatch.setattr(os, "sched_setscheduler", refuse)
    applied, refused = realtime.real_time_scheduling(40, None)
    assert applied == [] and len(refused) == 1
    assert refused[0].startswith("SCHED_FIFO priority 40 refused: Operation not permitted (needs CAP_SYS_NICE")
    assert realtime.real_time_scheduling(0, None) == ([], [])


def test_cpu_lists_and_priorities_are_checked():
    assert realtime.cpu_set("0") == {0}
    every = os.sched_getaffinity(0)
    with pytest.raises(argparse.ArgumentTypeError, match="not among this process's"):
        realtime.cpu_set(str(max(every) + 1))
    with pytest.raises(argparse.ArgumentTypeError, match="not a CPU list"):
        realtime.cpu_set("a-b")
    assert realtime.fifo_priority("0") == 0 and realtime.fifo_priority("99") == 99
    with pytest.raises(argparse.ArgumentTypeError, match="1-99"):
        realtime.fifo_priority("100")


def test_the_kernels_unbound_workqueues_go_where_asked_for_the_run_and_come_back(tmp_path):
    """A system-wide setting: put back after the run, also when the run fails; a refusal is one line."""
    mask, holders = tmp_path / "cpumask", tmp_path / "holders"
    mask.write_text("3\n")
    with pytest.raises(RuntimeError), realtime.unbound_work_on({1}, mask, holders) as work:
        assert mask.read_text() == "2"
        assert work == {"applied": ["kernel's unbound workqueues on CPU 1"], "refused": []}
        raise RuntimeError
    assert mask.read_text() == "3"
    with realtime.unbound_work_on(None, mask, holders) as work:
        assert work == {"applied": [], "refused": []} and mask.read_text() == "3"
    with realtime.unbound_work_on({0, 1}, tmp_path / "absent", holders) as work:
        assert not work["applied"] and len(work["refused"]) == 1
        assert work["refused"][0].startswith(f"kernel's unbound workqueues on CPU 0,1 refused: {tmp_path / 'absent'}")
    assert realtime.cpu_mask({0, 1}) == "3" and realtime.cpu_mask({1, 4}) == "12"
    assert realtime.cpu_mask({33}) == "2,00000000"


HOLDER = """import json, sys
from drive_common.runtime.realtime import unbound_work_on
with unbound_work_on({int(sys.argv[1])}, sys.argv[2], sys.argv[3]) as work:
    print(json.dumps(work), flush=True)
    sys.stdin.readline()
"""


def test_the_workqueue_mask_is_shared_by_the_machines_drives_and_the_last_one_out_puts_it_back(tmp_path):
    """Two drive processes holding the kernel's unbound workqueues on CPU 1: the first one out leaves the mask
    as the other needs it, the last puts back the mask found before the first; a drive asking for other CPUs
    meanwhile is refused naming the holder. A holder killed with SIGKILL is found stale by the next drive,
    which puts the saved mask back first, and its own exit restores it."""
    import json
    import signal
    import subprocess
    import sys

    mask, holders = tmp_path / "cpumask", tmp_path / "holders"
    mask.write_text("3\n")

    def holder(cpu):
        child = subprocess.Popen([sys.executable, "-c", HOLDER, str(cpu), str(mask), str(holders)],
                                 stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        return child, json.loads(child.stdout.readline())

    def leave(child):
        child.stdin.write("\n")
        child.stdin.flush()
        assert child.wait(30) == 0

    first, work = holder(1)
    assert work["applied"] and mask.read_text() == "2"
    second, work = holder(1)
    assert work["applied"] and mask.read_text() == "2"
    other, work = holder(0)
    assert not work["applied"] and "held at 2 by drive process" in work["refused"][0]
    assert {str(first.pid), str(second.pid)} <= set(re.findall(r"\d+", work["refused"][0]))
    leave(other)
    leave(first)
    assert mask.read_text() == "2"
    leave(second)
    assert mask.read_text() == "3"
    killed, _ = holder(1)
    killed.send_signal(signal.SIGKILL)
    killed.wait(30)
    assert mask.read_text() == "2"
    with realtime.unbound_work_on({1}, mask, holders) as work:
        assert work["applied"][1] == f"{mask} put back to 3 (its last holder was gone)"
        assert mask.read_text() == "2"
    assert mask.read_text() == "3"


def test_the_cpus_wake_up_latency_is_held_for_the_run_only(tmp_path):
    """PM QoS: the request (a 32-bit µs count) is written and held open for the run, dropped after it, also
    when the run fails; None leaves it; a refusal is one line."""
    request = tmp_path / "cpu_dma_latency"
    request.write_bytes(b"")

    def held():
        return any(os.path.realpath(f"/proc/self/fd/{fd}") == str(request) for fd in os.listdir("/proc/self/fd"))

    with pytest.raises(RuntimeError), realtime.cpu_wakeup_latency_held(0, request) as idle:
        assert request.read_bytes() == b"\0\0\0\0" and held()
        assert idle == {"applied": [f"CPU wake-up latency held at 0 µs ({request})"], "refused": []}
        raise RuntimeError
    assert not held()
    with realtime.cpu_wakeup_latency_held(None, request) as idle:
        assert idle == {"applied": [], "refused": []} and not held()
    with realtime.cpu_wakeup_latency_held(5, tmp_path / "absent") as idle:
        assert not idle["applied"] and idle["refused"][0].startswith(f"CPU wake-up latency 5 µs refused: {tmp_path}")
    with pytest.raises(argparse.ArgumentTypeError, match="a whole number of µs ≥ 0, not '-1'"):
        realtime.microseconds("-1")


def test_the_time_the_hypervisor_took_is_read_per_cpu():
    stolen = realtime.stolen_s()
    assert set(stolen) == set(range(os.cpu_count())) and all(t >= 0.0 for t in stolen.values())


def test_a_paced_link_launches_the_robots_configuration_unless_told_otherwise(monkeypatch):
    """`drive launch --link L --paced` fills what its command line left unset with the robot's configuration:
    SCHED_FIFO 50, the last CPU, over a pty the kernel's unbound workqueues there too, the answer compiled
    (pty and CAN), intra-process when composed; given values stay; without --paced none of it; paced separate
    processes are refused up front."""
    from drive_tools.cli.cli import build_parser
    from drive_tools.cli.options import CommandLineError, robot_real_time
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1})

    def settings(*words):
        args = build_parser().parse_args(["launch", "wang_100rpm", *words])
        robot_real_time(args)
        return args.rt_priority, args.cpus, args.workqueue_cpus, args.intra_process
    assert settings("--link", "pty", "--paced") == (50, {1}, {1}, True)
    assert settings("--link", "can", "--paced") == (50, {1}, None, True)
    with pytest.raises(CommandLineError, match="--paced --processes separate: refused"):
        settings("--link", "can", "--paced", "--processes", "separate")
    assert settings("--link", "pty", "--paced", "--rt-priority", "0", "--cpus", "0", "--no-intra-process") == \
        (0, {0}, {0}, False)
    assert settings("--link", "pty") == settings() == (0, None, None, False)
    assert settings("--intra-process") == (0, None, None, True)
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0})
    assert settings("--link", "pty", "--paced") == (50, None, None, True)

    def answer(*words):
        args = build_parser().parse_args(["launch", "wang_100rpm", *words])
        robot_real_time(args)
        return args.answer
    assert answer("--link", "pty", "--paced") == answer("--link", "can", "--paced") == "compiled"
    assert answer("--link", "can") == answer("--link", "pty") == "python"
    assert answer("--link", "can", "--answer", "compiled") == "compiled"
    with pytest.raises(CommandLineError, match=r"--answer compiled: needs --link pty\|can"):
        answer("--answer", "compiled")


def test_the_platform_probe_wakes_every_period_and_counts_the_late_ones():
    """`drive bench platform`'s probe: one wake-up per period over the time asked, none early, and the
    figures (percentiles, stalls over 0.5 ms) taken from those latencies."""
    late, scheduling = realtime.wakeup_latencies(0.2, period_s=1e-3)
    assert len(late) == 200 and (late >= 0.0).all() and scheduling == {"applied": [], "refused": []}
    report = realtime.stall_report(late, 1e-3)
    assert report["seconds"] == pytest.approx(0.2) and report["stalls_over_0_5_ms"] == (late > 5e-4).sum()
    assert report["latency_p50_us"] <= report["latency_p99_us"] <= report["latency_max_us"]
    fake = realtime.stall_report(np.array([1e-5, 2e-3, 7e-4, 1e-5]), 1e-3)
    assert fake["stalls_over_0_5_ms"] == 2 and fake["stalls_over_1_ms"] == 1 and fake["stalls_per_s"] == 500.0
    assert fake["stalled_ms"] == pytest.approx(2.7)


def test_the_machine_watch_notes_a_stall_once_and_says_which_late_blocks_it_explains():
    """The watch wakes every period and notes a stall once (the wake-ups catching up within it are part of
    it): on a virtual clock, 40 ms taken from it at 0.1 s of 0.24 s. A late block is the machine's when the
    stalls take at least its window less the run's median latency."""
    from drive_common.runtime.machine_watch import STALL_NOTED_S, missing_runs_explained, stalled_within, watch
    from helpers import VirtualClock

    clock = VirtualClock(stalls=[(0.1, 0.04)])
    count, stalls = watch(5e-4, clock.until(0.24), clock.monotonic, clock.sleep)
    assert count == pytest.approx(0.24 / 5e-4, abs=1)
    assert len(stalls) == 1
    due, late = stalls[0]
    assert due == pytest.approx(0.1, abs=5e-4) and late == pytest.approx(0.04, abs=5e-4) and late > STALL_NOTED_S

    stalls = [[1.0e-4, 1.0e-3], [5.0005, 3e-4]]
    assert stalled_within(stalls, 0.0, 1.1e-3) == pytest.approx(1.0e-3)
    windows = [[0.0, 1.1e-3], [5.0, 5.0011], [9.0, 9.0011]]
    assert missing_runs_explained(windows, stalls, 4e-4) == 1


def test_the_machine_watch_runs_beside_as_a_process_of_its_own():
    """The child reports once its input ends: the scheduling it got, its wake-ups and its stalls, each later
    than STALL_NOTED_S and after the one before it ended. How many wake-ups a wall-clock time holds is the
    machine's pace, measured by `drive bench platform`, not asserted here."""
    from drive_common.runtime.machine_watch import STALL_NOTED_S, MachineWatch

    with MachineWatch(0) as watch:
        time.sleep(0.05)
    report = watch.report
    assert set(report) == {"scheduling", "wakeups", "stalls"} and watch.process.returncode == 0
    assert report["scheduling"] == {"applied": [], "refused": []} and report["wakeups"] >= 1
    assert all(late > STALL_NOTED_S for _, late in report["stalls"])
    assert all(later[0] >= due + late for (due, late), later in zip(report["stalls"], report["stalls"][1:]))


def test_status_work_waits_for_the_quiet_part_of_a_block_and_never_more_than_a_period():
    """Where a bridge node runs the loop, a node's periodic status runs after a command is written, one
    piece per command; a piece still queued at the node's next period runs then; without a bridge, at once."""
    quiet, done = realtime.QuietTime(), []
    collect, publish = (lambda: done.append("collect")), (lambda: done.append("publish"))
    quiet.later(collect)
    assert done == ["collect"]
    quiet.hold()
    quiet.later(collect, publish)
    assert done == ["collect"]
    quiet.quiet()
    assert done == ["collect", "collect"]
    quiet.overdue((collect, publish))
    assert done == ["collect", "collect", "publish"] and not quiet.pending
    quiet.later(collect)
    quiet.release()
    assert not quiet.pending and len(done) == 3
    quiet.later(publish)
    assert done[-1] == "publish"


def test_status_work_taken_by_two_threads_runs_each_piece_once():
    """The bridge's link thread (a command written) and the executor's (a node's next period) may take
    queued pieces at the same time, thread switches forced often: each runs once, none is lost, neither
    thread fails."""
    import threading
    quiet, done, failed = realtime.QuietTime(), [], []
    jobs = [lambda i=i: done.append(i) for i in range(600)]
    quiet.hold()
    quiet.later(*jobs)

    def taking(step, times=None):
        def take():
            try:
                n = 0
                while quiet.pending and (times is None or n < times):
                    step()
                    n += 1
            except Exception as error:
                failed.append(error)
        return threading.Thread(target=take)
    threads = [taking(quiet.quiet), taking(lambda: quiet.overdue(jobs[::7]), times=100)]
    interval = sys.getswitchinterval()
    sys.setswitchinterval(1e-6)
    try:
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join(timeout=30.0)
    finally:
        sys.setswitchinterval(interval)
    assert not failed and sorted(done) == list(range(600))


def test_the_real_time_benchs_lines_show_a_run_without_a_figure_as_a_question_mark():
    """A run cut short measured no answer: its figure is `?` in the bench's progress line, never a traceback."""
    from drive_tools.evaluation.bench import figures
    runs = [{"answer_p99_us": 812.4}, {"answer_p99_us": None}]
    assert figures(runs, "answer_p99_us") == "812, ?"


def test_the_sample_ring_hands_over_every_row_in_order_and_counts_what_a_full_ring_drops():
    """A random interleaving of writes and reads (seeded): the rows read are the rows written that found room,
    in order, none twice; a write to a full ring is dropped and counted, never blocking; written = read +
    dropped + left in the ring."""
    from drive_common.runtime.sample_ring import HEAD, OVERFLOW, TAIL, drain, free_slot, publish, sample_ring
    rng = np.random.default_rng(7)
    ring = sample_ring(16, 3)
    accepted, read, value = [], [], 0
    out = np.zeros((5, 3))
    for _ in range(2000):
        if rng.random() < 0.8:
            slot = free_slot(ring.rows, ring.indices)
            if slot >= 0:
                ring.rows[slot] = value, -value, 2 * value
                publish(ring.indices)
                accepted.append(value)
            value += 1
        else:
            count = drain(ring.rows, ring.indices, out)
            read.extend(out[:count, 0].astype(int).tolist())
            rows = out[:count]
            assert np.array_equal(rows[:, 1], -rows[:, 0]) and np.array_equal(rows[:, 2], 2 * rows[:, 0])
    head, tail, dropped = ring.indices[HEAD], ring.indices[TAIL], ring.indices[OVERFLOW]
    assert read == accepted[:len(read)] and dropped > 0
    assert value == head + dropped and head - tail == len(accepted) - len(read) <= 16


@pytest.mark.unit
def test_the_rings_rows_are_put_back_into_whole_blocks_however_they_were_drained():
    """A block of N samples whose rows the ring's reader drained in two parts is handed on whole and in order; rows
    that start no whole block (a gap in the samples) are left out (drive_tools.runner.compiled_answer.RingBlocks)."""
    import numpy as np

    from drive_tools.runner.compiled_answer import RING_K, RingBlocks
    N, rows = 10, np.zeros((60, 4))
    rows[:, RING_K] = np.r_[0:30, 35:45, 50:60, 60:70]
    assembled = RingBlocks(N, 4)
    handed = [b for part in np.split(rows, [7, 13, 29, 41, 58]) for b in assembled.blocks(part)]
    assert [int(b[0, RING_K]) for b in handed] == [0, 10, 20, 50, 60]
    assert all(len(b) == N and np.array_equal(b[:, RING_K], b[0, RING_K] + np.arange(N)) for b in handed)
