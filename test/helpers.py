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
