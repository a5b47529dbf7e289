"""Signals and pipes, by class: every long command stops on the first SIGINT or SIGTERM with exit code
128 + the signal, no traceback, what it had printed marked interrupted and no process left behind; a
reader that goes away ends the output quietly (exit 141). Isolated: localhost discovery, the session's
domain (conftest)."""
import json
import os
import re
import signal
import subprocess
import sys
import time

import pytest

DRIVE = [sys.executable, "-m", "drive_tools.cli"]

COMMANDS = {
    "run": (["run", "wang_100rpm", "--duration", "600", "--no-plot", "--json"], True),
    "bridge": (["bridge", "wang_100rpm", "--duration", "60", "--no-plot", "--json"], True),
    "tune_check": (["tune", "pll", "--check", "--no-plot", "--json"], True),
    "bench_graph": (["bench", "graph", "--duration", "0.5", "--repeats", "1", "--json"], True),
    "echo": (["echo", "currents", "--namespace", "/nobody_here"], False),
}
"""Each command's arguments, and whether the signal waits for its first progress on a terminal (its job has
begun, on a machine of any pace); else it comes 0.5 s after the start, wherever the command then is."""
PROGRESS_WAIT_S = 300.0
PROGRESS = re.compile(r"\r[^\r\n]*%[ \t]*|[^\r\n]*real-time factor[^\r\n]*")
"""A command's progress on a terminal: a line it rewrites ending in a percentage, or a bench's result line."""


def stop(tmp_path, args, at_progress, signum, ready=PROGRESS, env=None):
    """Run ``drive ARGS`` in its own session with standard error on a terminal (as a user runs it), send
    ``signum`` once its terminal shows ``ready`` (``at_progress``) or after 0.5 s; (code, stdout, stderr
    without the progress), once every process of the session is gone. ``env``: variables set for it."""
    import pty
    import threading
    master, slave = pty.openpty()
    process = subprocess.Popen(DRIVE + args, cwd=tmp_path, stdout=subprocess.PIPE, stderr=slave, text=True,
                               start_new_session=True, env={**os.environ, **(env or {})})
    os.close(slave)
    err, progressed = [], threading.Event()

    def read_terminal():
        while True:
            try:
                chunk = os.read(master, 4096)
            except OSError:
                return
            if not chunk:
                return
            err.append(chunk.decode(errors="replace"))
            if ready.search("".join(err)):
                progressed.set()
    reader = threading.Thread(target=read_terminal, daemon=True)
    reader.start()
    if at_progress:
        assert progressed.wait(PROGRESS_WAIT_S), f"drive {' '.join(args)} showed no progress: {''.join(err)}"
    else:
        time.sleep(0.5)
    assert process.poll() is None, f"drive {' '.join(args)} ended before the signal: {''.join(err)}"
    process.send_signal(signum)
    out, _ = process.communicate(timeout=60)
    deadline = time.monotonic() + 10.0
    while time.monotonic() < deadline:
        try:
            os.killpg(process.pid, 0)
        except ProcessLookupError:
            break
        time.sleep(0.1)
    else:
        pytest.fail(f"drive {' '.join(args)}: processes left behind in its session")
    reader.join(5.0)
    os.close(master)
    lines = [line for line in PROGRESS.sub("", "".join(err).replace("\r\n", "\n")).splitlines() if line.strip()]
    return process.returncode, out, "\n".join(lines)


@pytest.fixture(scope="module", autouse=True)
def warm_caches(tmp_path_factory):
    """Compile the kernels once, so the signal lands in the job, not the compiler."""
    subprocess.run(DRIVE + ["run", "wang_100rpm", "--duration", "0.01", "--no-plot"],
                   cwd=tmp_path_factory.mktemp("warm"), capture_output=True, check=True)


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
@pytest.mark.parametrize("command", COMMANDS)
def test_the_first_signal_stops_a_command_cleanly(tmp_path, command, signum):
    args, at_progress = COMMANDS[command]
    code, out, err = stop(tmp_path, args, at_progress, signum)
    assert code == 128 + signum, err
    assert "Traceback" not in err, err
    assert len([line for line in err.splitlines() if not line.startswith("[INFO]")]) <= 1, err
    if command in ("run", "bridge", "bench_graph"):
        report = json.loads(out)
        assert report["interrupted"]
    if command in ("run", "bridge"):
        asked_s = float(args[args.index("--duration") + 1])
        assert 0 < report["samples"] and report["duration_s"] < asked_s
    if command == "bench_graph":
        assert len(report["results"]) < 3 and "ping_pong" not in report


STANDSTILL_DONE = re.compile(r"100\.0 %")
"""A commissioning's standstill part done: the next test sets up (seconds: its drive built and compiled), then
runs its chunks (tens of ms here), then the file is written."""
COMMISSIONING_PARTS = {"standstill": ([], PROGRESS), "rotating": (["--rotating"], STANDSTILL_DONE),
                       "loaded": (["--loaded"], STANDSTILL_DONE)}


@pytest.mark.parametrize("part, signum, cold", [("standstill", signal.SIGINT, False),
                                                ("standstill", signal.SIGTERM, False),
                                                ("rotating", signal.SIGINT, False), ("loaded", signal.SIGTERM, False),
                                                ("rotating", signal.SIGINT, True)])
def test_a_signal_during_commissioning_writes_nothing(tmp_path_factory, tmp_path, part, signum, cold):
    """At standstill, or once it is done, in the rotating or loaded test (held until the chunk in progress
    ends, or until numba's compile of its kernels ends: ``cold``, an empty kernel cache of its own, as on a
    first run): exit 128 + N, one line, neither the commissioning file nor its working file left, nothing else
    written."""
    extra, ready = COMMISSIONING_PARTS[part]
    before = sorted(tmp_path.rglob("*"))
    env = {"NUMBA_CACHE_DIR": str(tmp_path_factory.mktemp("empty_kernel_cache"))} if cold else None
    code, out, err = stop(tmp_path, ["commission", "wang_100rpm", "--out", "joint.yaml", "--json", *extra], True,
                          signum, ready, env)
    assert (code, out, err) == (128 + signum, "", f"drive: commission: interrupted by {signal.Signals(signum).name}")
    assert sorted(tmp_path.rglob("*")) == before


@pytest.mark.parametrize("during, signum", [("run", signal.SIGINT), ("writing", signal.SIGTERM)])
def test_a_signal_during_a_recorded_run_leaves_a_closed_readable_bag(tmp_path, during, signum):
    """During the run: the samples run, recorded whole; during the bag's writing: the bag closed as far as
    written and said so, whole samples only. Either way `drive bag info` reads it with no warning."""
    from drive_tools.bags.reader import bag_info
    duration, ready = ("600", PROGRESS) if during == "run" else ("2", re.compile(r"writing [^\r\n]*%"))
    code, out, err = stop(tmp_path, ["run", "wang_100rpm", "--duration", duration, "--no-plot", "--json", "--record",
                                     "bag"], True, signum, ready)
    report = json.loads(out)
    assert code == 128 + signum and report["interrupted"] and "Traceback" not in err, err
    info = bag_info(tmp_path / "bag")
    counts = {t["topic"]: t["count"] for t in info["topics"]}
    currents = counts["/drive/currents"]
    assert info["warnings"] == [], info["warnings"]
    assert {counts[f"/drive/{topic}"] for topic in ("rotor_state", "angle_error", "voltage_command")} == {currents}
    if during == "run":
        assert "recording_error" not in report and currents == report["samples"] > 0
    else:
        assert "bag" in report["recording_error"] and currents < report["samples"] == 20000


def test_a_reader_that_goes_away_ends_the_output_quietly(tmp_path):
    process = subprocess.Popen(DRIVE + ["presets"], cwd=tmp_path, stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE)
    process.stdout.close()
    err = process.stderr.read().decode()
    assert process.wait(timeout=60) == 128 + signal.SIGPIPE
    assert err == ""


def test_a_signal_inside_a_deferred_block_is_raised_when_it_ends():
    """A bag's close or a file swap is never cut half-way: the signal waits for the block's end."""
    from drive_common.runtime import interrupt
    finished = []
    with pytest.raises(interrupt.Interrupted) as stopped, interrupt.handled():
        with interrupt.deferred():
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(0.05)
            finished.append(True)
    assert finished == [True] and stopped.value.signum == signal.SIGTERM


def signal_at_compile_start(signum):
    """A numba event listener that sends this process ``signum`` as a compile starts."""
    from numba.core import event

    class SignalAtCompileStart(event.Listener):
        def on_start(self, _event):
            os.kill(os.getpid(), signum)

        def on_end(self, _event):
            pass
    return SignalAtCompileStart()


def raised_in(error):
    """The module of each frame an exception's traceback passed through, outermost first."""
    import traceback
    return [frame.f_globals.get("__name__", "") for frame, _ in traceback.walk_tb(error.__traceback__)]


def test_a_signal_during_a_cold_compile_waits_for_its_end(monkeypatch):
    """A signal that lands while numba compiles a kernel (here: sent at the compile's start, no cache) is held
    until the compile ends and raised in the caller: the kernel compiled whole, no frame of numba or llvmlite in
    the raise's traceback, nothing unraisable (llvmlite's finalizers had printed tracebacks)."""
    import numba
    import numpy as np
    from numba.core import event

    from drive_common.runtime import interrupt

    unraisable = []
    monkeypatch.setattr(sys, "unraisablehook", unraisable.append)

    @numba.njit(cache=False)
    def kernel(x):
        return np.sum(np.sin(x)) + np.cumsum(x)[-1]

    deadline = time.monotonic() + 60.0
    with pytest.raises(interrupt.Interrupted) as stopped, interrupt.handled():
        with event.install_listener("numba:compile", signal_at_compile_start(signal.SIGINT)):
            kernel(np.arange(3.0))
        while time.monotonic() < deadline:
            time.sleep(0.01)
    frames = raised_in(stopped.value)
    assert stopped.value.signum == signal.SIGINT and len(kernel.overloads) == 1
    assert frames[-2:] == [__name__, interrupt.__name__], f"raised in {frames}, not in the compile's caller"
    assert not [name for name in frames if name.partition(".")[0] in interrupt.CANNOT_TAKE_A_RAISE], frames
    assert unraisable == [] and interrupt.requested() == 0


@pytest.mark.parametrize("block", ["deferred", "polled"])
def test_a_second_signal_during_a_cold_compile_inside_a_held_block_raises_once_it_ends(block):
    """Inside deferred() or polled() the first signal is recorded and a second raises: sent while numba compiles,
    the second is held until the compile ends, then raised in the caller, inside the block."""
    import numba
    import numpy as np
    from numba.core import event

    from drive_common.runtime import interrupt

    @numba.njit(cache=False)
    def kernel(x):
        return np.sum(np.cos(x))

    deadline = time.monotonic() + 60.0
    with pytest.raises(interrupt.Interrupted) as stopped, interrupt.handled():
        with getattr(interrupt, block)():
            os.kill(os.getpid(), signal.SIGINT)
            assert interrupt.requested() == signal.SIGINT
            with event.install_listener("numba:compile", signal_at_compile_start(signal.SIGTERM)):
                kernel(np.arange(3.0))
            while time.monotonic() < deadline:
                time.sleep(0.01)
    frames = raised_in(stopped.value)
    assert stopped.value.signum == signal.SIGINT and len(kernel.overloads) == 1
    assert frames[-2:] == [__name__, interrupt.__name__], f"raised in {frames}, not in the block"


def test_a_signal_swallowed_by_a_c_callback_still_stops_the_command(monkeypatch, capsys):
    """numba's compiler calls back into Python; a signal raised there is swallowed by the callback
    (the run goes on), but it stays recorded: the command ends as interrupted, with one line and no
    traceback."""
    import ctypes

    from drive_common.runtime import interrupt
    from drive_tools.cli import cli, run

    def job(args):
        callback = ctypes.CFUNCTYPE(None)(lambda: interrupt._handler(signal.SIGTERM, None))
        callback()
        return 0

    monkeypatch.setattr(run, "cmd_scenarios", job)
    assert cli.main(["scenarios"]) == 128 + signal.SIGTERM
    err = capsys.readouterr().err
    assert "Traceback" not in err and err.strip() == "drive: scenarios: interrupted by SIGTERM"


def swallowed_sigterm():
    """SIGTERM's raise landing in a C callback, as a collection's finalizer or numba's compiler would take
    it: recorded, not raised."""
    import ctypes

    from drive_common.runtime import interrupt
    ctypes.CFUNCTYPE(None)(lambda: interrupt._handler(signal.SIGTERM, None))()


@pytest.mark.parametrize("loop", ["runner", "bridge"])
def test_a_long_loop_stops_at_its_next_pass_after_a_swallowed_signal(loop):
    """A swallowed raise must not let a 60 s job run to its end: the loop's checkpoint raises it."""
    import dataclasses

    from drive_common.config.scenario import load_scenario
    from drive_common.runtime import interrupt
    from drive_tools.doubles.faults import acting_at
    from drive_tools.doubles.virtual_inverter import InverterOptions
    from drive_tools.runner.bridge_loop import run_through_bridge
    from drive_tools.runner.runner import run_scenario

    scenario = dataclasses.replace(load_scenario("wang_100rpm"), duration_s=60.0)
    with interrupt.handled():
        if loop == "runner":
            result = run_scenario(scenario, progress=lambda fraction: swallowed_sigterm(), chunk_samples=2000)
        else:
            result = run_through_bridge(scenario, options=InverterOptions(command_wait_s=0.02),
                                        inverter=acting_at(100, lambda inverter: swallowed_sigterm()))
    assert result.interrupted == signal.SIGTERM
    assert 0 < len(result.log) <= {"runner": 2000, "bridge": 1000}[loop]
    assert interrupt.requested() == 0


@pytest.mark.unit
def test_a_signal_during_an_import_is_the_commands_interruption(monkeypatch, capsys):
    """A signal that comes while a C extension is imported (rclpy's, at a command's start) reaches the command line
    as that import's ImportError, caused by the interruption: exit 128 + N and one line, no traceback."""
    from drive_common.runtime.interrupt import Interrupted
    from drive_tools.cli import cli, motor

    def importing(args):
        try:
            raise Interrupted(signal.SIGINT)
        except Interrupted as stop:
            raise ImportError("initialization failed") from stop
    monkeypatch.setattr(motor, "cmd_presets", importing)
    assert cli.main(["presets"]) == 128 + signal.SIGINT
    err = capsys.readouterr().err
    assert err == "drive: presets: interrupted by SIGINT\n"
