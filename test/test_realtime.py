"""Soft real time of a drive's process (drive_interface.realtime): the garbage collector held out of the
sample path and given back, scheduling that the system refuses said in one line, CPU lists checked."""
import argparse
import gc
import os
import sys

import pytest

from drive_interface import realtime

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


def test_the_real_time_bench_and_launch_check_their_options():
    import subprocess
    drive = [sys.executable, "-m", "drive_cli.cli"]
    run = subprocess.run(drive + ["bench", "bridge", "--graph"], capture_output=True, text=True, timeout=60)
    assert run.returncode == 2 and run.stderr.strip().endswith("give --paced --graph")
    run = subprocess.run(drive + ["bench", "bridge", "--paced", "--graph", "--levers", "turbo"], capture_output=True,
                         text=True, timeout=60)
    assert run.returncode == 2 and "--levers: 'turbo' is not one of plain, collector" in run.stderr
    run = subprocess.run(drive + ["launch", "wang_100rpm", "--rt-priority", "100"], capture_output=True, text=True,
                         timeout=60)
    assert run.returncode == 2 and "--rt-priority: a SCHED_FIFO priority 1-99" in run.stderr
