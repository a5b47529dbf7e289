"""The sensorless loop through the inverter bridge in one process: the virtual inverter on its own
thread behind a pseudo-terminal or a CAN bus, the bridge core, and the estimator and controller cores
answering each telemetry frame (with blocks of N samples, each TELEMETRY_BLOCK by the block kernels and
one COMMAND_BLOCK). For tests, `drive bridge` and `drive bench bridge`."""
import contextlib
import tempfile
import time
from dataclasses import dataclass, field

import numpy as np

from drive_bridge.inverter_bridge import COMMAND_TIMEOUT_S, LINK_TIMEOUT_S, InverterBridge
from drive_bridge.inverter_protocol import MAX_BLOCK
from drive_common.config.scenario import behind_an_inverter
from drive_common.contract.drive_records import commands, drive_inputs
from drive_common.contract.estimator_records import estimates
from drive_common.contract.log import COLUMN, LOG_COLUMNS
from drive_common.contract.run_result import RunResult
from drive_common.math.command_delay import command_line, issue_command
from drive_common.math.safe_state import safe_state_for
from drive_common.math.winding import R_S_IN_USE
from drive_common.runtime.bound_kernels import bound
from drive_common.runtime.interrupt import Interrupted, checkpoint
from drive_common.runtime.realtime import collector_held
from drive_tools.doubles.inverter_timing import timing_report
from drive_tools.doubles.virtual_inverter import InverterOptions, VirtualInverter
from drive_tools.doubles.virtual_links import make_links
from foc_controller.control import controller_block
from foc_controller.protection import SAFE_STATE, TRIPPED, protection_block, protection_summary
from hf_estimator.block import estimator_block
from hf_estimator.interface import contract_injection

from .answer_kernels import fill_inputs, issue_and_log
from .runner import build_drive, cut


@dataclass
class BridgeRunResult(RunResult):
    link: str = ""
    counters: dict = field(default_factory=dict)
    frame_errors: dict = field(default_factory=dict)
    inverter_counters: dict = field(default_factory=dict)
    latencies_s: np.ndarray = None
    """Inverter-side time from sending TELEMETRY(k) to receiving COMMAND(k), per answered sample."""
    received: np.ndarray = None
    """Per sample: True when the host received its telemetry."""
    host_s: np.ndarray = None
    """Per answered sample: the host's time from the telemetry's arrival to its command written."""
    timing: dict = None
    """How the host kept pace with the inverter (drive_tools.doubles.inverter_timing.timing_report)."""
    scheduling: dict = None
    """The compiled answer's thread: the real-time scheduling applied and refused (None: the answer in Python)."""


def run_through_bridge(scenario, link="pty", options=None, progress=None, inverter=VirtualInverter, answer=None):
    """Run ``scenario`` with its plant behind a virtual inverter on ``link`` ('pty', 'can') and the bridge
    (with blocks, at the protocol's answer delay: ``behind_an_inverter``); ``options`` (InverterOptions,
    None: lock-step): the inverter's clock and wait; ``inverter``: the double to run behind (a class or factory
    called as VirtualInverter: a faulty one of drive_tools.doubles.faults for the tests); ``answer``
    (compiled_answer.AnswerOptions; None: the answer in Python, the reference): the answer compiled whole, off
    the interpreter's lock. The garbage collector is held off during the loop (``collector_held``)."""
    scenario = behind_an_inverter(scenario, MAX_BLOCK)
    with virtual_inverter_link(scenario, link, options, inverter) as (virtual, bridge):
        if answer is not None:
            return _run_compiled(scenario, link, virtual, bridge, (progress, answer))
        return _run(scenario, link, virtual, bridge, progress)


@contextlib.contextmanager
def virtual_inverter_link(scenario, link, options=None, inverter=VirtualInverter):
    """(virtual inverter, the host's bridge core) for ``scenario`` on ``link`` ('pty', 'can') in a temporary
    directory, the inverter made by ``inverter`` (a class or factory called as VirtualInverter) with
    ``options`` (InverterOptions; None: lock-step); the inverter is not started. Both and the link are
    stopped and closed on exit. In lock-step the inverter is silent while it waits for the host (up to its
    ``command_wait_s``), and a link it lost stays silent until its watchdog trips (``watchdog_periods`` such
    waits): the bridge takes the link for lost, or the host (this loop) for silent, after half that silence (at
    least a wait and LINK_TIMEOUT_S or COMMAND_TIMEOUT_S), so a host slowed by its machine for less is neither, on
    any machine."""
    scenario = behind_an_inverter(scenario, MAX_BLOCK)
    with tempfile.TemporaryDirectory(prefix="drive_bridge_") as workdir:
        endpoint, host_link = make_links(link, workdir)
        virtual = inverter(scenario, endpoint, options or InverterOptions())
        wait, silence = virtual.command_wait_s, 0.5 * virtual.watchdog_periods * virtual.command_wait_s
        timeouts = {} if virtual.rate_Hz else {"link_timeout_s": max(wait + LINK_TIMEOUT_S, silence),
                                               "command_timeout_s": max(wait + COMMAND_TIMEOUT_S, silence)}
        bridge = InverterBridge(host_link, block_samples=scenario.block_samples, **timeouts)
        if virtual.rate_Hz:
            virtual.hear_host_writes(bridge.written_at)
        try:
            yield virtual, bridge
        finally:
            virtual.stop()
            bridge.close()
            endpoint.close()


def _run(scenario, link, inverter, bridge, progress):
    """The host's loop. The estimator pairs each current step with the voltage that acted: the commands of
    periods the inverter ran at zero volts (``BridgeBlock.at_zero_volts``: period j, the command of sample
    j − d) and the command of a sample never received are zero in its delay line."""
    host = build_drive(scenario)
    n = scenario.n_samples
    delay = scenario.drive_delay_periods()
    line = command_line(delay)
    log = np.zeros((n, len(LOG_COLUMNS)))
    received = np.zeros(n, dtype=bool)
    host_s = np.zeros(n)
    answer = _HostAnswer(host, scenario, line, log)
    bridge.poll(0.0)
    start = time.perf_counter()
    last_report = 0
    interrupted = 0
    next_k = 0
    try:
        with collector_held():
            inverter.start()
            while inverter.is_alive() or bridge.open:
                checkpoint()
                blocks = bridge.poll_blocks(0.05)
                arrived = time.perf_counter()
                if not blocks and not inverter.is_alive() and bridge.part is None:
                    break
                for b in blocks:
                    k0, k_end = b.k0, min(b.k0 + len(b), n)
                    if k0 >= n:
                        continue
                    for missed in range(next_k, k0):
                        issue_command(line, missed, 0.0, 0.0)
                    next_k = k_end
                    if b.at_zero_volts:
                        for k in range(max(k0, delay), k_end):
                            issue_command(line, k - delay, 0.0, 0.0)
                    for answered in answer.block(b, bridge):
                        host_s[answered] = time.perf_counter() - arrived
                        received[answered] = True
                    for k in range(k0, k_end):
                        if progress and k - last_report >= n // 100:
                            last_report = k
                            progress(k / n)
                if received[n - 1]:
                    break
    except Interrupted as stop:
        interrupted = stop.signum
        inverter.stop()
    inverter.stop()
    inverter.join(2.0)
    wall = time.perf_counter() - start
    if progress and not interrupted:
        progress(1.0)
    return _bridge_result((scenario, link, inverter, bridge, host), log, (wall, interrupted), (received, host_s),
                          dict(bridge.counters))


def _run_compiled(scenario, link, inverter, bridge, progress_and_options):
    """The host's loop compiled whole (compiled_answer.CompiledAnswer): the same answer as ``_run``, its
    samples recorded from the ring; ``ring_overflow`` counts those the ring had no room for."""
    from .compiled_answer import RING_HOST_S, RING_K, RING_LOG, CompiledAnswer, drive_parts
    progress, answer_options = progress_and_options
    host = build_drive(scenario)
    n = scenario.n_samples
    delay = scenario.drive_delay_periods()
    line = command_line(delay)
    log = np.zeros((n, len(LOG_COLUMNS)))
    received = np.zeros(n, dtype=bool)
    host_s = np.zeros(n)
    bridge.poll(0.0)
    answer = CompiledAnswer(drive_parts(host), bridge, line, (n, delay), answer_options)
    reported = [0]

    def take(rows):
        k = rows[:, RING_K].astype(np.int64)
        log[k], host_s[k], received[k] = rows[:, RING_LOG:], rows[:, RING_HOST_S], True
        if progress and k[-1] - reported[0] >= n // 100:
            reported[0] = k[-1]
            progress(k[-1] / n)

    start = time.perf_counter()
    interrupted = 0
    try:
        with collector_held():
            inverter.start()
            answer.start(take)
            while answer.alive():
                checkpoint()
                if not inverter.is_alive():
                    answer.drain_then_stop()
                answer.answering.join(0.05)
    except Interrupted as stop:
        interrupted = stop.signum
        answer.stop()
    inverter.stop()
    answer.stop()
    answer.join(5.0)
    inverter.join(2.0)
    wall = time.perf_counter() - start
    if progress and not interrupted:
        progress(1.0)
    return _bridge_result((scenario, link, inverter, bridge, host), log, (wall, interrupted), (received, host_s),
                          {**bridge.counters, "ring_overflow": answer.overflow}, answer.scheduling)


def _bridge_result(run, log, ended, samples, counters, scheduling=None):
    """The BridgeRunResult of a run through the bridge, either answer: ``run`` (scenario, link, inverter, bridge,
    host), its ``log`` with the inverter's truth filled in up to the last sample it simulated, ``ended`` (wall
    time [s], the signal that stopped it or 0), ``samples`` (per sample: received, the host's time [s]), the
    bridge's ``counters`` and the answer thread's ``scheduling`` (None: the answer in Python)."""
    scenario, link, inverter, bridge, host = run
    wall, interrupted = ended
    received, host_s = samples
    truth = inverter.truth
    done = inverter.k
    log = log[:done]
    for column, name in enumerate(("theta_m", "omega_m", "tau_e", "tau_load", "i_a", "i_b", "i_c")):
        log[:, COLUMN[name]] = truth[:done, column]
    log[:, COLUMN["t"]] = np.arange(done) * scenario.T_s
    e, cp = host.estimator, host.controller
    return BridgeRunResult(cut(scenario, done), e.name, log, wall, cp.i_max_A, interrupted, host.commissioning,
                           e.facts(), protection=protection_summary(host.protection_x, host.protection),
                           speed_ramp_rad_s2=cp.speed_ramp_rad_s2,
                           injection=contract_injection(e.facts(), scenario.injection), link=link,
                           counters=counters, frame_errors=bridge.frame_errors(),
                           inverter_counters=dict(inverter.counters),
                           latencies_s=np.asarray(inverter.latencies_s), received=received[:done],
                           host_s=host_s[:done][received[:done]],
                           timing=timing_report(inverter, scenario.T_s, bridge.written_at), scheduling=scheduling)


def protect(host, currents, n, k_last, u_dc_V, omega_e_hat, cx, px):
    """The drive's protections over n samples of measured ``currents`` with the inverter's bus ``u_dc_V``
    (foc_controller.protection.protection_block on the controller state cx and protection state px):
    (enable, the safe state the command asks for). Tripped, the command disables the bridge into the safe
    state chosen at the trip; otherwise it enables it and asks for the safe state by speed and bus."""
    protection_block(px, host.protection, currents, n, k_last, u_dc_V, omega_e_hat, cx)
    if px[TRIPPED]:
        return False, int(px[SAFE_STATE])
    return True, safe_state_for(omega_e_hat, u_dc_V, host.protection.psi_f_Wb)


class _HostAnswer:
    """The host's answer to each whole block of N samples (N = 1: each sample): ``estimator_block`` and
    ``controller_block`` (as ``drive run`` composes them), one COMMAND_BLOCK (N = 1: one COMMAND). A block
    with a sample missing is not answered (the inverter applies zero volts for it)."""

    def __init__(self, host, scenario, line, log):
        self.host, self.scenario, self.line, self.log = host, scenario, line, log
        self.sensing = host.sensing()
        N = scenario.block_samples
        self.currents, self.inputs = np.zeros((N, 3)), drive_inputs(N)
        self.est_out, self.ctrl_out, self.core = estimates(N), commands(N), host.estimator.core()
        self.estimator_block = bound(estimator_block, host.estimator.step)
        self.warm_up()

    def warm_up(self):
        """Load the kernels on copies of the states before the inverter starts: a first call loads a kernel
        from numba's cache (up to 0.3 s), longer than the bridge's link timeout in lock-step."""
        host, N = self.host, self.scenario.block_samples
        e = host.estimator
        fill_inputs(self.inputs, self.currents, np.zeros(N), 1, host.speed_ref, host.tau_feedforward, 0, N)
        self.estimator_block(e.core(e.state.copy()), 0, N, self.inputs, self.line.copy(), self.sensing, self.est_out)
        controller_block(host.controller_x.copy(), host.controller_z.copy(), host.controller, N, self.inputs,
                         self.est_out, self.sensing, self.ctrl_out)
        protect(host, self.currents, N, 0, 0.0, 0.0, host.controller_x.copy(), host.protection_x.copy())
        issue_and_log(self.line.copy(), np.zeros((1, len(LOG_COLUMNS))), 0, 1, self.scenario.T_s, self.inputs,
                      self.est_out, self.ctrl_out)

    def block(self, b, bridge):
        """Answer block ``b`` when it is a whole one (its first sample a multiple of N; N samples, or the
        run's last ones): the samples answered."""
        N, k0 = self.scenario.block_samples, b.k0
        n = min(N, self.scenario.n_samples - k0)
        if k0 % N or len(b) < n:
            return ()
        host, line = self.host, self.line
        self.currents[:n] = b.currents_A[:n]
        fill_inputs(self.inputs, self.currents, b.theta_m, host.controller.n_p, host.speed_ref, host.tau_feedforward,
                    k0, n)
        self.core.sample[0]["R_s_ohm"] = host.protection_x[R_S_IN_USE]
        self.estimator_block(self.core, k0, n, self.inputs, line, self.sensing, self.est_out)
        enable, safe = protect(host, self.currents, n, k0 + n - 1, b.u_dc_V, self.est_out[n - 1]["omega_e_hat"],
                               host.controller_x, host.protection_x)
        controller_block(host.controller_x, host.controller_z, host.controller, n, self.inputs, self.est_out,
                         self.sensing, self.ctrl_out)
        issue_and_log(line, self.log[k0:k0 + n], k0, n, self.scenario.T_s, self.inputs, self.est_out, self.ctrl_out)
        c = self.ctrl_out
        if N == 1:
            bridge.command(k0, c[0]["u_alpha_V"], c[0]["u_beta_V"], enable, safe)
        else:
            bridge.command_block(k0, c["u_alpha_V"][:n], c["u_beta_V"][:n], enable, safe)
        return range(k0, k0 + n)
