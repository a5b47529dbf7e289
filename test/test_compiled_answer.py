"""The answer through the bridge compiled whole (issue 53), over a pty and over CAN (the cable's sockets): the same
samples as the answer in Python to the bit, link faults counted alike, and a lossless hand-off through the ring:
every sample recorded, or a counted overflow when its reader stalls, which leaves the answers themselves untouched.
The inverter runs in lock-step (docs/architecture.md, "Tests"): no wall clock is asserted."""
import dataclasses
import threading
import time

import numpy as np
import pytest

from drive_common.config.scenario import load_scenario
from drive_common.contract.log import COLUMN
from drive_common.runtime import machine_setting, realtime
from drive_common.runtime.realtime import ROBOT_RT_PRIORITY
from drive_tools.doubles.faults import FaultPlan, faulty
from drive_tools.doubles.virtual_inverter import VirtualInverter
from drive_tools.launch.launcher import DriveSpec, GraphError, GraphOptions, RealTime, launch
from drive_tools.runner.bridge_loop import run_through_bridge
from drive_tools.runner.compiled_answer import AnswerOptions

SCENARIO = dataclasses.replace(load_scenario("wang_100rpm"), duration_s=0.3)
TRUTH = slice(1, 8)
"""The log's columns the virtual inverter fills (the plant's truth): what the host's commands made."""


def same_run(python, compiled):
    """The two runs' samples, what the host received and every counter agree exactly."""
    assert np.array_equal(python.log, compiled.log)
    assert np.array_equal(python.received, compiled.received)
    assert python.counters == {k: v for k, v in compiled.counters.items() if k != "ring_overflow"}
    assert python.frame_errors == compiled.frame_errors
    assert python.inverter_counters == compiled.inverter_counters


@pytest.mark.parametrize("link, block_samples, priority", [("pty", 1, 0), ("pty", 10, ROBOT_RT_PRIORITY),
                                                             ("can", 1, 0), ("can", 10, ROBOT_RT_PRIORITY),
                                                             ("can", 15, 0)])
def test_the_compiled_answer_gives_the_python_answers_samples_to_the_bit(link, block_samples, priority):
    """Also with its thread at SCHED_FIFO where the machine allows it (else one statement says why not). Over
    CAN, blocks of 10 and 15 come as two and three CAN FD frames, put together as the Python bridge puts them;
    blocks of 1 as classic frames (TELEMETRY_B, A)."""
    scenario = dataclasses.replace(SCENARIO, block_samples=block_samples)
    python = run_through_bridge(scenario, link)
    compiled = run_through_bridge(scenario, link, answer=AnswerOptions(priority=priority))
    same_run(python, compiled)
    assert len(compiled.scheduling["applied"] + compiled.scheduling["refused"]) == (1 if priority else 0)
    assert compiled.received.all() and compiled.counters["ring_overflow"] == 0
    assert compiled.log.shape[0] == scenario.n_samples


def test_link_faults_are_counted_as_the_python_answer_counts_them():
    """Corrupt, dropped, repeated and reordered telemetry frames, as test_bridge's Python answer meets them:
    each counted by kind, every lost sample a period without its command. (Not compared sample by sample:
    a frame lost in lock-step keeps the inverter waiting, whose end against the host's own timeout is the
    machine's pace.)"""
    faults = FaultPlan(corrupt_every=97, drop_every=89, duplicate_every=83, reorder_every=101, garbage_every=71)
    result = run_through_bridge(SCENARIO, "pty", inverter=faulty(faults), answer=AnswerOptions())
    injected, counters, errors = faults.counts, result.counters, result.frame_errors
    assert counters["duplicated"] == injected["duplicated"]
    bad_frames = errors.get("crc", 0) + errors.get("framing", 0)
    assert injected["corrupted"] + injected["garbage"] <= bad_frames <= 2 * injected["corrupted"] + injected["garbage"]
    assert counters["samples"] + counters["dropped"] == SCENARIO.n_samples
    inverter = result.inverter_counters
    assert inverter["missing"] == counters["dropped"] + inverter["discarded"] - counters["safe_state"]
    assert injected["reordered"] - 1 <= counters["reordered"] <= injected["reordered"]
    assert counters["dropped"] == injected["dropped"] + injected["corrupted"] + counters["reordered"]
    assert counters["ring_overflow"] == 0 and result.received.sum() == counters["samples"]


@pytest.mark.parametrize("block_samples", [1, 10])
def test_can_frames_lost_repeated_and_reordered_are_answered_as_the_python_answer_answers_them(block_samples):
    """Over CAN (classic frames, or a block's CAN FD frames put together): dropped, repeated and reordered
    telemetry messages (the bus's CRC drops a corrupt frame: no garbage here) give the Python answer's samples,
    counters and inverter counts to the bit, every sample received or dropped, every lost one a period
    without its command."""
    scenario = dataclasses.replace(SCENARIO, block_samples=block_samples)
    python_faults, compiled_faults = (FaultPlan(drop_every=89, duplicate_every=83, reorder_every=101)
                                      for _ in range(2))
    python = run_through_bridge(scenario, "can", inverter=faulty(python_faults))
    compiled = run_through_bridge(scenario, "can", inverter=faulty(compiled_faults), answer=AnswerOptions())
    assert python_faults.counts == compiled_faults.counts and min(compiled_faults.counts.values()) > 0
    same_run(python, compiled)
    counters, inverter = compiled.counters, compiled.inverter_counters
    assert counters["samples"] + counters["dropped"] == scenario.n_samples and counters["dropped"] > 0
    assert inverter["missing"] == counters["dropped"] + inverter["discarded"] - counters["safe_state"]


def test_an_inverter_that_leaves_the_can_cable_and_comes_back_is_answered_again():
    """Right after sample 1500 the inverter's member of the cable leaves (its socket gone: the compiled answer's
    commands find no member, lost as on a bus with no other node) and joins again with a new socket once its
    0.3 s later; the compiled answer looks for the member again and drives on: the last 1000 samples
    received, the estimate back on the rotor within 0.2 s."""
    from drive_tools.doubles.faults import acting_at
    from drive_tools.doubles.virtual_inverter import InverterOptions
    from drive_tools.evaluation.metrics import angle_error
    rejoined = threading.Event()

    def leave(inverter):
        inverter.endpoint.close()

        def rejoin_later():
            time.sleep(0.3)
            inverter.endpoint.open()
            rejoined.set()
        threading.Thread(target=rejoin_later, daemon=True).start()

    scenario = dataclasses.replace(SCENARIO, duration_s=1.0)
    result = run_through_bridge(scenario, "can", InverterOptions(command_wait_s=0.1), inverter=acting_at(1500, leave),
                                answer=AnswerOptions())
    assert rejoined.is_set()
    assert result.inverter_counters["link_down"] > 0
    assert result.received[-1000:].all()
    error = angle_error(result.log, result.n_p)
    assert np.abs(error[1500 + 2000:]).max() < 0.2


@pytest.mark.parametrize("link", ["pty", "can"])
def test_lost_command_blocks_are_zero_volts_the_compiled_answer_pairs_as_the_python_answer_does(link):
    """Every 37th command block lost on the way (the inverter hears it, so never waits: the outcome is what
    the host sent): its 10 periods at zero volts, which the host writes into its estimator's delay line; the
    same samples as the Python answer's, to the bit."""
    scenario = dataclasses.replace(SCENARIO, block_samples=10)
    python_faults, compiled_faults = FaultPlan(lose_command_every=37), FaultPlan(lose_command_every=37)
    python = run_through_bridge(scenario, link, inverter=faulty(python_faults))
    compiled = run_through_bridge(scenario, link, inverter=faulty(compiled_faults), answer=AnswerOptions())
    lost = compiled_faults.counts["commands_lost"]
    assert python_faults.counts == compiled_faults.counts and lost == scenario.n_samples // 10 // 37
    assert compiled.inverter_counters["missing"] == 10 * lost
    same_run(python, compiled)


def test_a_stalled_reader_costs_recorded_samples_counted_never_the_answers():
    """The ring's reader pauses 50 ms after each read with a ring of 64 rows: the rows it had no room for
    are counted (recorded + overflow = samples answered), and the commands, hence what the inverter
    sampled, are those of the run whose reader kept up (the default ring), to the bit; no command missed
    its period."""
    scenario = dataclasses.replace(SCENARIO, block_samples=10)
    kept_up = run_through_bridge(scenario, "pty", answer=AnswerOptions())
    stalled = run_through_bridge(scenario, "pty", answer=AnswerOptions(ring_rows=64, reader_stall_s=0.05))
    overflow = stalled.counters["ring_overflow"]
    assert kept_up.counters["ring_overflow"] == 0 and overflow > 0
    assert stalled.received.sum() + overflow == scenario.n_samples
    assert np.array_equal(stalled.log[:, TRUTH], kept_up.log[:, TRUTH])
    recorded = stalled.received
    assert np.array_equal(stalled.log[recorded], kept_up.log[recorded])
    assert stalled.inverter_counters["missing"] == kept_up.inverter_counters["missing"] == 0


def test_the_compiled_answer_is_refused_on_a_bus_without_a_socket():
    """python-can's in-process virtual bus is objects of the interpreter: nothing to read from compiled code."""
    from drive_bridge.compiled_bridge import link_kind
    from drive_bridge.inverter_link import CanLink
    link = CanLink("compiled_answer_refused", 0, "virtual")
    link.open()
    try:
        with pytest.raises(ValueError, match="has none"):
            link_kind(link)
    finally:
        link.close()


GRAPH = DriveSpec("wang_100rpm", duration_s=0.3, extra_parameters={"block_samples": 10}, link="pty")
DRIVE_COLUMNS = ("i_a_meas", "i_b_meas", "i_c_meas", "theta_e_hat", "omega_e_hat", "u_alpha", "u_beta", "u_inj_alpha",
                 "u_inj_beta", "eps", "signal", "state", "theta_m", "omega_m")
"""What the graph's nodes log of a drive behind an inverter (the encoder's angle and speed for the truth)."""


@pytest.mark.parametrize("link", ["pty", "can"])
def test_the_compiled_answer_in_the_graph_gives_the_nodes_samples_to_the_bit_and_records_every_one(tmp_path, link):
    """`drive launch --link pty|can` with the answer compiled (no estimator or controller node: the bridge node
    publishes what the ring hands over) against the nodes answering on the bridge's link thread, lock-step:
    every logged column equal to the bit, every sample in the log and in the recording, written from the ring
    (0 missing, no overflow)."""
    from drive_tools.bags.reader import bag_log
    graph = dataclasses.replace(GRAPH, link=link)
    nodes = launch(graph, GraphOptions(intra_process=True))
    bag = tmp_path / "compiled"
    compiled = launch(dataclasses.replace(graph, bag=str(bag)), GraphOptions(answer=AnswerOptions()))
    n = round(GRAPH.duration_s / SCENARIO.T_s)
    assert compiled.missing_samples == {} and compiled.recording_error is None
    assert compiled.answer["recorded"] == n and compiled.answer["ring_overflow"] == 0
    for name in DRIVE_COLUMNS:
        assert np.array_equal(compiled.log[:, COLUMN[name]], nodes.log[:, COLUMN[name]], equal_nan=True), name
    recorded, _, _ = bag_log(str(bag))
    assert recorded.shape[0] == n
    assert np.array_equal(recorded[:, COLUMN["u_alpha"]], compiled.log[:, COLUMN["u_alpha"]])


def test_a_stalled_writer_in_the_graph_is_a_counted_overflow_never_a_late_answer():
    """The ring's reader (the publisher and the log's writer) pauses 50 ms after each read, the ring 64 rows:
    the samples it had no room for are missing by name (``ring_overflow``), recorded + overflow = answered,
    and the inverter missed no command."""
    stalled = launch(GRAPH, GraphOptions(answer=AnswerOptions(ring_rows=64, reader_stall_s=0.05)))
    overflow = stalled.answer["ring_overflow"]
    assert overflow > 0 and stalled.answer["recorded"] + overflow == round(GRAPH.duration_s / SCENARIO.T_s)
    assert stalled.missing_samples == {"/drive/answer ring_overflow": overflow}
    assert stalled.timing["missing"] == 0


def test_the_compiled_answer_in_the_graph_is_refused_where_it_cannot_run():
    with pytest.raises(GraphError, match=r"needs --link pty\|can"):
        launch(dataclasses.replace(GRAPH, link=None), GraphOptions(answer=AnswerOptions()))
    with pytest.raises(GraphError, match="composed"):
        launch(GRAPH, GraphOptions("separate", answer=AnswerOptions()))


class SilentInverter(VirtualInverter):
    """An inverter that never starts sending: what a drive waits for never comes."""

    def start(self):
        pass


@pytest.mark.parametrize("answer", [None, AnswerOptions()])
def test_a_run_whose_inverter_never_sends_stops_at_its_deadline_and_gives_the_machine_back(tmp_path, answer):
    """At SCHED_FIFO with the workqueue mask held (a stand-in file: the holders count works on any file), a
    run whose inverter never sends ends at its deadline with one error naming it, and the mask is put back:
    nothing waits at real-time priority for what never comes."""
    mask, holders = tmp_path / "cpumask", tmp_path / "holders"
    mask.write_text("3\n")
    spec = dataclasses.replace(GRAPH, inverter=SilentInverter, paced=True)
    real_time = RealTime(rt_priority=ROBOT_RT_PRIORITY)
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(realtime, "WORKQUEUE_CPUMASK", str(mask))
        patch.setattr(machine_setting, "HOLDERS_ROOT", str(holders))
        with pytest.raises(GraphError, match=r"did not end within 3 s of its start \(deadline_s"):
            launch(spec, GraphOptions(real_time=dataclasses.replace(real_time, workqueue_cpus={0}), deadline_s=3.0,
                                      answer=answer))
    assert mask.read_text().strip() == "3" and any(holders.iterdir()), "the mask was taken, then put back"
