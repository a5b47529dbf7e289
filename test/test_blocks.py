"""Blocks of samples in one process: what a run computes depends on the drive's delay d alone, not on
how the samples are grouped into blocks (docs/architecture.md, "Block transport")."""
import dataclasses

import numpy as np
import pytest

from drive_common.config.scenario import load_scenario
from drive_tools.runner.runner import run_scenario

pytestmark = pytest.mark.unit


def test_the_samples_depend_on_the_delay_not_on_the_block_size():
    """Blocks of 10 answered in one period (d = 10) and blocks of 5 answered in 6 periods (d = 10, the
    delay a paced inverter with blocks needs) give the same samples to the bit; and d differs from the
    per-sample run's, whose samples differ."""
    base = dataclasses.replace(load_scenario("wang_load_step"), duration_s=0.08)
    tens = dataclasses.replace(base, block_samples=10)
    fives = dataclasses.replace(base, block_samples=5, answer_periods=6)
    assert tens.drive_delay_periods() == fives.drive_delay_periods() == 10
    a, b = run_scenario(tens).log, run_scenario(fives).log
    assert np.array_equal(a, b)
    assert not np.array_equal(a, run_scenario(base).log)


def test_a_run_shorter_than_one_block_is_refused_behind_an_inverter():
    """Behind an inverter nothing answers a block that never fills: the scenario is refused naming its
    duration and the block, before any process starts."""
    from drive_bridge.inverter_protocol import MAX_BLOCK
    from drive_common.config.scenario import ScenarioError, behind_an_inverter
    short = dataclasses.replace(load_scenario("wang_100rpm"), duration_s=5e-4, block_samples=10)
    with pytest.raises(ScenarioError, match=r"duration_s: 0\.0005 s is less than one block of 10 samples \(0\.001 s\)"):
        behind_an_inverter(short, MAX_BLOCK)
    assert behind_an_inverter(dataclasses.replace(short, duration_s=1e-3), MAX_BLOCK).answer_periods == 11
