"""The sensorless loop through the inverter bridge in one process: the virtual inverter on its own
thread behind a pseudo-terminal or a CAN bus, the bridge core, and the estimator and controller cores
answering each telemetry frame. For tests, `drive bridge` and `drive bench bridge`."""
import contextlib
import gc
import tempfile
import threading
import time
from dataclasses import dataclass, field

import numpy as np

from control_math.command_delay import applied_voltage, command_line, issue_command
from control_math.current_sensing import corrected_currents
from drive_bridge.inverter_bridge import InverterBridge
from drive_bridge.virtual_inverter import VirtualInverter, make_links, timing_report
from drive_interface.interrupt import Interrupted
from drive_interface.log import COLUMN, LOG_COLUMNS
from drive_scenarios.scenario import refuse_behind_an_inverter
from foc_controller.control import controller_step

from .loop import write_row
from .runner import RunResult, build_drive, cut


@dataclass
class BridgeRunResult(RunResult):
    link: str = ""
    counters: dict = field(default_factory=dict)
    frame_errors: dict = field(default_factory=dict)
    inverter_counters: dict = field(default_factory=dict)
    injected: dict = field(default_factory=dict)
    latencies_s: np.ndarray = None
    """Inverter-side time from sending TELEMETRY(k) to receiving COMMAND(k), per answered sample."""
    received: np.ndarray = None
    """Per sample: True when the host received its telemetry."""
    host_s: np.ndarray = None
    """Per answered sample: the host's time from the telemetry's arrival to its command written."""
    timing: dict = None
    """How the host kept pace with the inverter (drive_bridge.virtual_inverter.timing_report)."""


def run_through_bridge(scenario, link="pty", faults=None, rate_Hz=None, command_wait_s=0.5, progress=None,
                       inverter_hook=None):
    """Run ``scenario`` with its plant behind the virtual inverter and the bridge. ``inverter_hook(
    inverter, endpoint, k)`` is called by the host loop after each sample (tests unplug links with it).
    The garbage collector is held off during the loop (``collector_held``)."""
    with virtual_inverter_link(scenario, link, rate_Hz=rate_Hz, command_wait_s=command_wait_s,
                               faults=faults) as (inverter, endpoint, bridge):
        return _run(scenario, link, inverter, endpoint, bridge, progress, inverter_hook)


@contextlib.contextmanager
def virtual_inverter_link(scenario, link, **inverter_options):
    """(virtual inverter, its link endpoint, the host's bridge core) for ``scenario`` on ``link`` ('pty',
    'can') in a temporary directory; the inverter is not started. All three are stopped and closed on
    exit."""
    refuse_behind_an_inverter(scenario)
    with tempfile.TemporaryDirectory(prefix="drive_bridge_") as workdir:
        endpoint, host_link = make_links(link, workdir)
        inverter = VirtualInverter(scenario, endpoint, **inverter_options)
        bridge = InverterBridge(host_link)
        try:
            yield inverter, endpoint, bridge
        finally:
            inverter.stop()
            bridge.close()
            endpoint.close()


@contextlib.contextmanager
def collector_held():
    """Python's cyclic garbage collector off (after one collection) for a loop through the bridge: a
    full collection in a large process pauses past the link timeout (50 ms) and reads as a lost link."""
    gc.collect()
    gc.disable()
    try:
        yield
    finally:
        gc.enable()


def _run(scenario, link, inverter, endpoint, bridge, progress, inverter_hook):
    host = build_drive(scenario)
    e, n_p, n = host.estimator, host.controller.n_p, scenario.n_samples
    cx, cz, cp = host.controller_x, host.controller_z, host.controller
    calibration = host.commissioning.calibration()
    line = command_line(scenario.drive_delay_periods())
    log = np.zeros((n, len(LOG_COLUMNS)))
    received = np.zeros(n, dtype=bool)
    host_s = np.zeros(n)
    bridge.poll(0.0)
    thread = threading.Thread(target=inverter.run, name="virtual_inverter", daemon=True)
    start = time.perf_counter()
    thread.start()
    last_report = 0
    interrupted = 0
    try:
        with collector_held():
            while thread.is_alive() or bridge.open:
                samples = bridge.poll(0.05)
                arrived = time.perf_counter()
                if not samples and not thread.is_alive():
                    break
                for s in samples:
                    k = s.k
                    if k >= n:
                        continue
                    theta_e = n_p * s.theta_m if s.theta_m == s.theta_m else 0.0
                    c_a, c_b, c_c = corrected_currents(s.i_a, s.i_b, s.i_c, calibration)
                    theta_hat, omega_hat, u_inj_a, u_inj_b, eps, signal, state = e.step(
                        e.x, e.z, e.params, k, c_a, c_b, c_c, *applied_voltage(line, k - 1), theta_e, 0.0)
                    u_a, u_b, i_d, i_q, i_d_ref, i_q_ref = controller_step(
                        cx, cz, cp, c_a, c_b, c_c, theta_hat, omega_hat, host.speed_ref[k], u_inj_a, u_inj_b, state,
                        host.tau_feedforward[k])
                    issue_command(line, k, u_a, u_b)
                    bridge.command(k, u_a, u_b)
                    host_s[k] = time.perf_counter() - arrived
                    received[k] = True
                    write_row(log[k], k * scenario.T_s, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, s.i_a, s.i_b, s.i_c,
                              theta_hat, omega_hat, u_a, u_b, u_inj_a, u_inj_b, host.speed_ref[k], i_d, i_q, i_d_ref,
                              i_q_ref, eps, signal, state)
                    if inverter_hook:
                        inverter_hook(inverter, endpoint, k)
                    if progress and k - last_report >= n // 100:
                        last_report = k
                        progress(k / n)
                if received[n - 1]:
                    break
    except Interrupted as stop:
        interrupted = stop.signum
        inverter.stop()
    thread.join(timeout=2.0)
    wall = time.perf_counter() - start
    if progress and not interrupted:
        progress(1.0)
    truth = inverter.truth
    done = inverter.k
    log = log[:done]
    for column, name in enumerate(("theta_m", "omega_m", "tau_e", "tau_load", "i_a", "i_b", "i_c")):
        log[:, COLUMN[name]] = truth[:done, column]
    log[:, COLUMN["t"]] = np.arange(done) * scenario.T_s
    return BridgeRunResult(cut(scenario, done), e.name, log, wall, cp.i_max_A, interrupted, host.commissioning,
                           host.estimator.facts(),
                           link=link,
                           counters=dict(bridge.counters), frame_errors=bridge.frame_errors(),
                           inverter_counters=dict(inverter.counters), injected=dict(inverter.faults.counts),
                           latencies_s=np.asarray(inverter.latencies_s), received=received[:done],
                           host_s=host_s[:done][received[:done]], timing=timing_report(inverter, scenario.T_s))
