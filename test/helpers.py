"""Shared test helpers: scenarios from dictionaries, run and score."""
from drive_evaluation.metrics import compute_metrics
from drive_runner.runner import run_scenario
from drive_scenarios.scenario import load_scenario, parse_scenario


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

    from motor_params.commissioning import Commissioning
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
