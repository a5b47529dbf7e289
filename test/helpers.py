"""Shared test helpers: scenarios from dictionaries, run and score; fixed-seed mutations of documents."""
import math
import re

from drive_common.config.scenario import load_scenario, parse_scenario
from drive_tools.evaluation.metrics import compute_metrics
from drive_tools.runner.runner import run_scenario


def scenario(**fields):
    base = dict(motor="wang_spmsm", estimator="sensored", duration_s=0.5, sampling_period_s=1e-4,
                speed=dict(unit="rpm", points=[[0.0, 0.0]]))
    base.update(fields)
    return parse_scenario(base, "test", "test-scenario")


def run(s):
    result = run_scenario(s)
    return result, compute_metrics(result)


def shipped(name, estimator=None, duration_s=None):
    import dataclasses
    s = load_scenario(name, estimator_override=estimator)
    return dataclasses.replace(s, duration_s=duration_s) if duration_s else s


def ideal_commissioning(machine, i_max_A, points=65, d_sweep_A=0.01):
    """A test oracle: the record a perfect commissioning would write for ``machine`` (its R_s,
    incremental inductances and saliency tables over ±i_max_A; ideal sensors, no dead time). Only tests
    of a core in isolation hand it to an estimator; the drive itself measures (drive_commissioning)."""
    import numpy as np

    from drive_common.motor.commissioning import Commissioning
    from pmsm_plant.commissioning import saliency_shift_and_slope
    from pmsm_plant.model import incremental_inductances

    L_dh, L_qh, _ = incremental_inductances(machine)
    currents = np.linspace(-i_max_A, i_max_A, points)
    shift, slope = np.array([saliency_shift_and_slope(machine, i_q, d_sweep_A) for i_q in currents]).T
    return Commissioning(machine.R_s_ohm, 0.0, 1.0, 1.0, 1.0, 0.0, 0.0, 0.0, 0.0, L_dh, L_qh, currents, shift, slope,
                         source="ideal (test oracle)")


class VirtualClock:
    """A test double for the machine's clock: ``monotonic()`` reads it, ``sleep(s)`` advances it by ``s``, and
    a sleep that reaches a stall's start ends only at its end (``stalls``: [(start, length)] [s]), as a CPU
    taken from the sleeper would. ``until(t)``: an event-like stop that is set once the clock reads ``t``."""

    def __init__(self, stalls=()):
        self.now = 0.0
        self.stalls = sorted(stalls)

    def monotonic(self):
        return self.now

    def sleep(self, seconds):
        before, self.now = self.now, self.now + seconds
        for start, length in self.stalls:
            if before < start <= self.now:
                self.now = max(self.now, start + length)

    def until(self, end_s):
        from types import SimpleNamespace
        return SimpleNamespace(is_set=lambda: self.now >= end_s)


class HostOnAVirtualClock:
    """A test double for a paced inverter's link and the host behind it, on a VirtualClock ``clock``: every
    TELEMETRY or TELEMETRY_BLOCK the inverter sends is answered by ``answer(k0, n)`` → (write_s, wire_s):
    the host writes the command (block) answering samples k0 … k0 + n − 1 write_s after the telemetry left
    (None: never), and it reaches the inverter's thread wire_s after that (a slow link's kernel).
    ``receive(timeout)`` hands over what has arrived by the clock plus ``timeout``, moving the clock to its
    arrival, or moves the clock by ``timeout``: the inverter then paces itself on the virtual clock, and its
    verdicts depend on the times the test states, never on the machine's pace. ``written_at(k)``: when the
    host wrote the command answering sample k (NaN: not written), for VirtualInverter.hear_host_writes."""

    def __init__(self, clock, answer, u_alpha_V=1.0):
        self.clock, self.answer, self.u_alpha_V = clock, answer, u_alpha_V
        self.pending, self.written, self.errors, self.status = [], {}, {}, {}
        self.voltage_lsb_V = None

    def send(self, message):
        import heapq

        from drive_bridge.inverter_protocol import ENABLE, Command, CommandBlock, Hello, Telemetry, TelemetryBlock
        if isinstance(message, Hello):
            self.voltage_lsb_V = message.voltage_lsb_V
            return
        if not isinstance(message, (Telemetry, TelemetryBlock)):
            return
        n = len(message.samples) if isinstance(message, TelemetryBlock) else 1
        self.status.update({k: message.status for k in range(message.seq, message.seq + n)})
        write_s, wire_s = self.answer(message.seq, n)
        if write_s is None:
            return
        code = round(self.u_alpha_V / self.voltage_lsb_V)
        written = self.clock.now + write_s
        command = (CommandBlock(message.seq, ENABLE, ((code, 0),) * n) if isinstance(message, TelemetryBlock)
                   else Command(message.seq, code, 0, ENABLE))
        for k in range(message.seq, message.seq + n):
            self.written[k] = written
        heapq.heappush(self.pending, (written + wire_s, message.seq, command))

    def receive(self, timeout_s):
        import heapq
        if self.pending and self.pending[0][0] <= self.clock.now + timeout_s:
            self.clock.now = max(self.clock.now, self.pending[0][0])
            arrived = []
            while self.pending and self.pending[0][0] <= self.clock.now:
                arrived.append(heapq.heappop(self.pending)[2])
            return arrived
        self.clock.now += timeout_s
        return []

    def written_at(self, k):
        written = self.written.get(k, float("nan"))
        return written if written <= self.clock.now else float("nan")


def paced_on_a_virtual_clock(scenario, answer, rate_Hz, by_host_writes=False, **options):
    """A VirtualInverter of ``scenario`` paced at ``rate_Hz`` on a VirtualClock behind a
    HostOnAVirtualClock answering as ``answer`` says (``by_host_writes``: the inverter judges commands by
    the host's write time), run to its end: (inverter, host)."""
    from drive_tools.doubles.virtual_inverter import InverterOptions, VirtualInverter
    clock = VirtualClock()
    host = HostOnAVirtualClock(clock, answer)
    inverter = VirtualInverter(scenario, host, InverterOptions(rate_Hz=rate_Hz, clock=clock.monotonic, **options))
    if by_host_writes:
        inverter.hear_host_writes(host.written_at)
    inverter.run()
    return inverter, host


def drive_in_process(argv, cwd=None):
    """`drive ARGV` run in this process (no interpreter to start, the kernels already loaded), in ``cwd``
    when given: an object with returncode, stdout and stderr, as subprocess.run's."""
    import contextlib
    import io
    import os
    from types import SimpleNamespace

    from drive_tools.cli.cli import main
    out, err, before = io.StringIO(), io.StringIO(), os.getcwd()
    try:
        if cwd is not None:
            os.chdir(cwd)
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            code = main([str(arg) for arg in argv])
    finally:
        os.chdir(before)
    return SimpleNamespace(returncode=code, stdout=out.getvalue(), stderr=err.getvalue())


NESTED = [[[[[[[[[[1.0]]]]]]]]]]
HOSTILE = [math.nan, math.inf, -math.inf, -1.0, 0, 0.0, 1e308, 5e-324, 2 ** 70, -2 ** 70, "abc", "5", True, None,
           [], {}, [1.0, 2.0], "a\0b", "a\nb", NESTED]
"""Values a fuzzed key is given: not finite, huge, tiny, negative, zero, of the wrong type, text with NUL or a
line break, nested deep."""
UNKNOWN = ["R_s_Ohm", "voltage", "a\nb", "x\0y", "nameplate", 7]
"""Keys a fuzzed mapping is given: typos, text with a line break or NUL, a known key in the wrong place, a number."""


def trails(node, trail=()):
    """Every mapping key's path in a document (list items left alone)."""
    for key, value in node.items():
        yield trail + (key,)
        if isinstance(value, dict):
            yield from trails(value, trail + (key,))


def at(document, trail):
    for key in trail:
        document = document[key]
    return document


def dotted(trail):
    return ".".join(map(str, trail))


def mutate(rng, document):
    """One mutation of ``document`` in place: a hostile value, a unit slip (× 1000 or ÷ 1000), a key deleted
    or an unknown one added; (kind, its trail, the value written or None, the keys a refusal may name: the
    key or one enclosing it)."""
    paths = list(trails(document))
    kind = rng.choice(["hostile", "hostile", "slip", "delete", "unknown"])
    if kind == "slip":
        trail = rng.choice([t for t in paths if type(at(document, t)) in (int, float)])
        value = at(document, trail) * rng.choice([1000, 1e-3])
    elif kind == "unknown":
        parent = rng.choice([()] + [t for t in paths if isinstance(at(document, t), dict)])
        trail, value = parent + (rng.choice(UNKNOWN),), 1.0
    else:
        trail = rng.choice(paths)
        value = rng.choice(HOSTILE)
    parent = at(document, trail[:-1])
    if kind == "delete":
        del parent[trail[-1]]
        value = None
    else:
        parent[trail[-1]] = value
    return kind, trail, value, tuple(dotted(trail[:n]) for n in range(len(trail), 0, -1))


def names(message, key):
    """``message`` names ``key`` as a whole key (not a part of a longer one)."""
    return re.search(rf"(?<![\w.]){re.escape(key)}(?![\w.])", message) is not None


def blames(message, blamed):
    """``message`` names one of the keys ``blamed`` (mutate's; a line break in one as the command line prints
    it, a space), or a key inside the first of them."""
    keys = set(blamed) | {" ".join(key.split()) for key in blamed}
    return any(names(message, key) for key in keys) or f"{blamed[0]}." in message
