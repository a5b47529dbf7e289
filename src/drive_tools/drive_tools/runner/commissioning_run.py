"""Commissioning the simulated motor in one process: the plant with its shaft held (imposed zero
speed, as a brake would) sampled and driven by the commissioning procedure core, one sample at a time,
in the contract's order (sample → command → delay → PWM)."""
import dataclasses
import math
import time
from dataclasses import dataclass

import numpy as np

from drive_common.config.scenario import shaft_held
from drive_common.contract.errors import DriveError
from drive_common.math.command_delay import applied_voltage, issue_command
from drive_common.runtime.interrupt import Interrupted
from hf_estimator.commissioning.procedure import procedure_for_scenario
from pmsm_plant.build import plant_for_scenario
from pmsm_plant.commissioning import commissioning_truth
from pmsm_plant.model import plant_advance, plant_outputs, sense_currents


class BridgeCommissioningError(DriveError):
    """The link to the virtual inverter ended before the procedure did."""


@dataclass
class CommissioningRun:
    procedure: object
    """hf_estimator.commissioning.procedure.CommissioningProcedure, finished."""
    truth: dict
    """The plant's true values (commissioning_truth), for scoring."""
    true_currents: np.ndarray
    """Per sample: the true phase currents (a, b, c) [A]."""
    wall_time_s: float
    host: str


TEST_CHUNK_SAMPLES = 1000
"""The rotating and loaded tests run in chunks of this many samples: a signal stops them after the chunk in
progress (0.1 s of the test at 10 kHz), never only at the test's end."""


def commission_in_process(scenario, settings=None, progress=None):
    """Run the procedure against the scenario's simulated plant (its deviation and non-idealities
    included) in this process; returns a CommissioningRun."""
    procedure = procedure_for_scenario(scenario, settings)
    plant = plant_for_scenario(shaft_held(scenario, procedure.total_samples * scenario.T_s))
    n = procedure.total_samples
    true_currents = np.zeros((n, 3))
    params = plant.params
    start = time.perf_counter()
    for k in range(n):
        i_a, i_b, i_c, _ = plant_outputs(plant.x, plant.machine)
        true_currents[k] = (i_a, i_b, i_c)
        m = sense_currents(i_a, i_b, i_c, plant.sensor, plant.seed, k)
        issue_command(plant.line, k, *procedure.step(k, *m))
        plant_advance(plant.x, *applied_voltage(plant.line, k), 0.0, True, 0.0, params)
        if progress and k % 1000 == 0:
            progress(k / n)
    if progress:
        progress(1.0)
    truth = commissioning_truth(plant, scenario.motor.nameplate.rated_current_A)
    return CommissioningRun(procedure, truth, true_currents, time.perf_counter() - start, "one process, plant core")


def commission_through_bridge(scenario, link="pty", settings=None, progress=None):
    """Run the procedure with the simulated plant behind the virtual inverter and the bridge core on
    ``link`` ('pty' or 'can'), in this process (bridge_loop's link, the collector held: drive_common.runtime.realtime);
    returns a CommissioningRun (truth from the inverter)."""
    from drive_common.runtime.interrupt import checkpoint
    from drive_common.runtime.realtime import collector_held

    from .bridge_loop import virtual_inverter_link

    procedure = procedure_for_scenario(scenario, settings)
    n = procedure.total_samples
    with virtual_inverter_link(shaft_held(scenario, n * scenario.T_s), link) as (inverter, bridge):
        start = time.perf_counter()
        bridge.poll(0.0)
        inverter.start()
        with collector_held():
            while not procedure.done and (inverter.is_alive() or bridge.open):
                checkpoint()
                for s in bridge.poll(0.05):
                    if s.k == procedure.k:
                        bridge.command(s.k, *procedure.step(s.k, s.i_a, s.i_b, s.i_c))
                        if progress and s.k % 1000 == 0:
                            progress(s.k / n)
        inverter.join(2.0)
    if not procedure.done:
        raise BridgeCommissioningError(f"the virtual inverter over {link} stopped at sample {procedure.k} of {n}")
    if progress:
        progress(1.0)
    truth = commissioning_truth(inverter.plant, scenario.motor.nameplate.rated_current_A)
    return CommissioningRun(procedure, truth, inverter.truth[:, 4:7], time.perf_counter() - start,
                            f"virtual inverter over {link}, bridge core")



def rotating_test_in_process(scenario, commissioning_file, progress=None):
    """The rotating test (hf_estimator.commissioning.rotating) on the scenario's simulated plant, shaft free and
    unloaded: the drive, commissioned at standstill (``commissioning_file``), spins it through the test's
    speed profile, pass after pass, each tuned on the J the one before measured (rotating.next_inertia_kgm2):
    the drive is told that J by a pass's own commissioning record (the standstill one with J_kgm2), so the
    plant, and a ``plant_deviation`` relative to the nameplate, stay what they are. Returns (estimates, the
    plant's true ψ_f, J and B, the last pass's RunResult); RotatingTestError from the last pass where it did
    not follow; Interrupted when a signal stopped it (after the chunk in progress)."""
    import tempfile
    from pathlib import Path

    from drive_common.motor.commissioning import resolve_commissioning, save_commissioning
    from hf_estimator.commissioning.rotating import (
        HEAVIEST_RAMP_S,
        PASSES,
        RotatingTestError,
        assumed_inertia_kgm2,
        inertia_from_log,
        next_inertia_kgm2,
        rotating_estimates,
        test_timing,
    )

    plate = scenario.motor.nameplate
    record = resolve_commissioning(plate, str(commissioning_file), "the standstill commissioning")
    J_tuned = plate.J_kgm2 if math.isfinite(plate.J_kgm2) else assumed_inertia_kgm2(plate)
    with tempfile.TemporaryDirectory(prefix="rotating_test_") as folder:
        told = Path(folder) / f"{plate.name}.yaml"
        for attempt in range(PASSES):
            timing = test_timing(plate, J_tuned)
            save_commissioning(told, record._replace(J_kgm2=J_tuned), plate.name, "the rotating test's pass")
            test = _rotating_pass(scenario, told, timing)
            result = run_scenario_chunked(test, progress)
            try:
                estimates, refusal = rotating_estimates(result.log, plate, record, test.T_s,
                                                        test.answer_delay_periods(), timing[0]), None
                J_measured = estimates["J_kgm2"]
            except RotatingTestError as error:
                estimates, refusal = None, error
                J_measured = inertia_from_log(result.log, plate, test.T_s)
            J_next = next_inertia_kgm2(J_tuned, J_measured, attempt == PASSES - 1,
                                       assumed_inertia_kgm2(plate, HEAVIEST_RAMP_S))
            if J_next is None and refusal is None:
                break
            if J_next is None:
                raise refusal
            J_tuned = J_next
    plant = plant_for_scenario(test)
    truth = {"psi_f_Wb": plant.machine.psi_f_Wb, "J_kgm2": plant.mechanics.J_kgm2, "B_Nms": plant.mechanics.B_Nms}
    return estimates, truth, result


def _rotating_pass(scenario, commissioning_file, timing):
    """The scenario of one rotating-test pass on the record ``commissioning_file`` (its J tunes the speed loop
    and ours' loops), its profile ``timing`` (rotating.test_timing): the speed loop at
    TEST_SPEED_BANDWIDTH_RAD_S unless the scenario sets it (the test needs no stiffness). Ours runs where a run
    would be refused before it (its predicted error over a run's targets, a polarity the pulses may miss): the
    test checks what it measured itself (rotating._check_followed), and the free, unloaded shaft may turn."""
    from drive_common.config.experiment import RPM, Table
    from hf_estimator.commissioning.rotating import DURATION_S, TEST_SPEED_BANDWIDTH_RAD_S, speed_profile

    plate = scenario.motor.nameplate
    controller = dict(scenario.controller)
    controller.setdefault("speed_bandwidth_rad_s", TEST_SPEED_BANDWIDTH_RAD_S)
    profile = speed_profile(plate.rated_speed_rpm, timing)
    return dataclasses.replace(
        scenario, estimator="injection_frame", estimator_settings={"run_refused": True},
        duration_s=timing[0] * DURATION_S, mode="speed_control",
        speed=Table(tuple(t for t, _ in profile), tuple(RPM * v for _, v in profile), "linear"),
        load=Table((0.0,), (0.0,), "step"), torque_feedforward=None, brake=False, initial_omega_m_rad_s=0.0,
        commissioning=str(commissioning_file), controller=controller, block_samples=1, answer_periods=0)


def run_scenario_chunked(scenario, progress=None):
    """run_scenario in TEST_CHUNK_SAMPLES chunks; Interrupted when a signal stopped it."""
    from drive_tools.runner.runner import run_scenario

    result = run_scenario(scenario, progress, chunk_samples=TEST_CHUNK_SAMPLES)
    if result.interrupted:
        raise Interrupted(result.interrupted)
    return result


def loaded_test_in_process(scenario, commissioning_file, progress=None):
    """The loaded test (hf_estimator.commissioning.loaded) on the scenario's simulated plant, shaft held: the drive,
    commissioned at standstill (``commissioning_file``), runs ours as the scenario configures it and steps its
    torque feed-forward; where a load took ours' angle it runs again lower (loaded.TRIES) and the current the last
    run completed at, when lower, is ``loaded_test_current_A`` (None otherwise). Its controller may reach the
    test's first current (the tables' limit), whatever lower limit ours' prediction sets for running. Returns
    (the loaded_shift result with ``injection_frequency_Hz`` and ``injection_amplitude_V`` ours ran at, and each
    hold's true angle error θ − θ̂ [rad] as ``true_error_rad``, for scoring; the RunResult). A correction the file
    already holds, where ours ran with it, stays in the one returned. Interrupted when a signal stopped it (after
    the chunk in progress)."""
    from drive_common.config.experiment import Table
    from drive_common.contract.log import COLUMN
    from drive_common.math.frames import wrap
    from drive_common.motor.commissioning import resolve_commissioning
    from drive_tools.runner.runner import run_scenario
    from hf_estimator.commissioning.loaded import (
        DURATION_S,
        LEVELS,
        SPEED_BANDWIDTH_RAD_S,
        TRIES,
        LoadedTestError,
        hold_windows,
        loaded_shift,
        test_current_A,
        torque_profile,
    )
    from hf_estimator.injection_frame import loaded_correction

    record = resolve_commissioning(scenario.motor.nameplate, str(commissioning_file), "the standstill commissioning")
    plate = record.refined(scenario.motor.nameplate)
    first = top = test_current_A(record, plate.current_limit_A)
    ours = scenario.estimator == "injection_frame"
    for run in range(TRIES):
        profile = torque_profile(top, 1.5 * plate.n_p * plate.psi_f_Wb)
        test = dataclasses.replace(
            shaft_held(scenario, DURATION_S), estimator="injection_frame",
            estimator_settings=dict(scenario.estimator_settings) if ours else {}, commissioning=str(commissioning_file),
            controller={"current_limit_A": first, **scenario.controller,
                        "speed_bandwidth_rad_s": SPEED_BANDWIDTH_RAD_S},
            torque_feedforward=Table(tuple(t for t, _ in profile), tuple(v for _, v in profile), "linear"))
        result = run_scenario(test, progress, chunk_samples=TEST_CHUNK_SAMPLES)
        if result.interrupted:
            raise Interrupted(result.interrupted)
        try:
            measured = loaded_shift(result.log, record, top)
            break
        except LoadedTestError as error:
            if error.retry_current_A is None:
                raise
            if run == TRIES - 1:
                raise LoadedTestError(f"{error} (in each of {TRIES} runs, the last up to {top:.3g} A, "
                                      f"{100.0 * top / first:.0f} % of the first: not the load alone)") from None
            top = error.retry_current_A
    measured["loaded_test_current_A"] = top if top < first else None
    facts = result.estimator_facts
    frequency_Hz, amplitude_V = float(facts["injection_frequency_Hz"]), float(facts["injection_amplitude_V"])
    ran_with, _ = loaded_correction(record, frequency_Hz, amplitude_V)
    measured.update(injection_frequency_Hz=frequency_Hz, injection_amplitude_V=amplitude_V,
                    estimator_shift_rad=measured["estimator_shift_rad"] + ran_with - record.saliency_shift_rad)
    n_p, log = result.n_p, result.log
    error = wrap.py_func(n_p * log[:, COLUMN["theta_m"]] - log[:, COLUMN["theta_e_hat"]])
    loaded = [w for w, level in zip(hold_windows(log[:, COLUMN["t"]]), LEVELS) if level != 0.0]
    for hold, window in zip(measured["holds"], loaded):
        hold["true_error_rad"] = float(np.mean(error[window]))
    return measured, result


def with_loaded_test(record, loaded):
    """The commissioning ``record`` with ours' correction from a ``loaded_test_in_process`` result ``loaded``
    and the carrier and amplitude it was measured at."""
    return record._replace(estimator_shift_rad=loaded["estimator_shift_rad"],
                           loaded_test_frequency_Hz=loaded["injection_frequency_Hz"],
                           loaded_test_amplitude_V=loaded["injection_amplitude_V"],
                           loaded_test_current_A=loaded.get("loaded_test_current_A") or math.nan)
