"""The command timeout of a robot's axis (foc_controller.command_hold, issue 54): the reference ramps to zero at its
deceleration, then holds the angle where it stopped, then releases torque; a brake releases once stopped; a fresh
command takes over at once. On a virtual clock: no wall time."""
import math

import pytest

from foc_controller.command_hold import HOLDING, RELEASED, CommandHold, HoldSettings

pytestmark = pytest.mark.unit
SETTINGS = HoldSettings(timeout_s=0.1, hold_timeout_s=2.0, brake=False, deceleration_rad_s2=50.0, gain_per_s=5.0,
                        hold_speed_rad_s=2.0)
DT_S = 1e-3


def run(hold, start_s, seconds, theta=lambda t: 0.0):
    """(time, ω*, τ_ff, torque) every DT_S from ``start_s`` for ``seconds``; the estimated angle ``theta(t)``."""
    out = []
    for i in range(int(round(seconds / DT_S))):
        t = start_s + i * DT_S
        out.append((t, *hold.reference(t, DT_S, theta(t))))
    return out


def test_a_fresh_command_is_followed_until_it_is_older_than_the_timeout():
    hold = CommandHold(SETTINGS, 0.0)
    hold.command(0.0, 4.0, 0.05)
    rows = run(hold, 0.0, 0.1)
    assert all(row[1:] == (4.0, 0.05, True) for row in rows)


def test_an_old_command_ramps_to_zero_at_the_deceleration_then_holds_the_angle():
    hold = CommandHold(SETTINGS, 0.0)
    hold.command(0.0, 4.0, 0.05)
    rows = run(hold, 0.0, 1.0, theta=lambda t: 0.3 if t > 0.5 else 0.2)
    ramp = [row for row in rows if 0.1 < row[0] <= 0.18]
    assert ramp[0][1] == pytest.approx(4.0 - 50.0 * DT_S)
    assert all(a[1] - b[1] == pytest.approx(50.0 * DT_S) for a, b in zip(ramp, ramp[1:]))
    stopped_at = 0.1 + 4.0 / 50.0
    assert hold.mode == HOLDING and hold.theta_hold == pytest.approx(0.2)
    held = [row for row in rows if row[0] > 0.6]
    assert all(row[1] == pytest.approx(5.0 * (0.2 - 0.3)) and row[3] for row in held), "k_θ (θ_hold − θ̂)"
    assert all(row[1] == 0.0 for row in rows if stopped_at + 2 * DT_S < row[0] <= 0.5), "at the hold angle: ω* = 0"
    far = run(hold, 1.0, 0.01, theta=lambda t: 10.0)
    assert far[-1][1] == -SETTINGS.hold_speed_rad_s, "the hold's speed bounded"


def test_the_hold_timeout_releases_torque_and_a_fresh_command_takes_over():
    hold = CommandHold(SETTINGS, 0.0)
    rows = run(hold, 0.0, 2.5)
    assert hold.mode == RELEASED
    assert [row for row in rows if row[0] > 2.0][-1][1:] == (0.0, 0.0, False)
    assert all(row[3] for row in rows if row[0] <= 2.0)
    hold.command(2.5, -1.0)
    assert hold.reference(2.51, DT_S, 0.0) == (-1.0, 0.0, True)
    assert hold.timeouts == 1


def test_a_braked_joint_releases_torque_once_stopped():
    hold = CommandHold(HoldSettings(0.1, math.inf, True, 50.0, 5.0, 2.0), 0.0)
    hold.command(0.0, 1.0)
    rows = run(hold, 0.0, 0.3)
    assert hold.mode == RELEASED and rows[-1][1:] == (0.0, 0.0, False)
    assert all(row[3] for row in rows if row[0] <= 0.1 + 1.0 / 50.0)


def test_no_timeout_keeps_a_command_for_good():
    hold = CommandHold(HoldSettings(0.0, math.inf, False, 50.0, 5.0, 2.0), 0.0)
    hold.command(0.0, 2.0)
    assert run(hold, 0.0, 5.0)[-1][1:] == (2.0, 0.0, True)


def test_the_compiled_answer_follows_the_command_it_is_given_as_the_node_would():
    """What a compiled answer follows (command_now's speed command, evaluated block by block from its own reference by
    speed_command.commanded_speed) is what ``reference`` gives the nodes' answer, through a timeout, the ramp and
    the hold, a position command included; and the live command's rows are written before their index."""
    import numpy as np

    from drive_tools.launch.axis_answer import LiveCommand
    from drive_tools.runner.compiled_answer import COMMAND_SLOT, COMMAND_SLOTS, RUN_FIELDS
    from foc_controller.speed_command import commanded_speed, speed_command
    nodes, compiled = CommandHold(SETTINGS, 0.0), CommandHold(SETTINGS, 0.0)
    for hold in (nodes, compiled):
        hold.command(0.0, 1.5, 0.1)
    live = LiveCommand(np.tile(speed_command(0.0), (COMMAND_SLOTS, 1)), np.zeros(1), np.zeros(RUN_FIELDS, np.int64))
    speed, slots = 0.0, set()
    for i in range(600):
        t, theta = i * DT_S, 0.3 * math.sin(i * DT_S)
        if i == 400:
            for hold in (nodes, compiled):
                hold.command(t, None, None, theta_ref=0.2)
        expected = nodes.reference(t, DT_S, theta)
        command, feedforward, torque = compiled.command_now(t, DT_S, theta)
        live.write(command, feedforward)
        slots.add(int(live.run[COMMAND_SLOT]))
        speed = commanded_speed(live.commands[live.run[COMMAND_SLOT]], speed, theta, DT_S)
        assert (speed, live.tau_feedforward[0], torque) == pytest.approx(expected), i
    assert nodes.mode == compiled.mode and slots == set(range(COMMAND_SLOTS))


def test_a_speed_command_steps_or_ramps_and_a_position_command_is_bounded():
    from foc_controller.speed_command import commanded_speed, position_command, speed_command
    assert commanded_speed(speed_command(3.0), -1.0, 0.0, DT_S) == 3.0, "a rate of ∞ steps"
    assert commanded_speed(speed_command(3.0, 100.0), 1.0, 0.0, DT_S) == pytest.approx(1.1)
    assert commanded_speed(speed_command(1.05, 100.0), 1.0, 0.0, DT_S) == 1.05, "within a step: the target"
    assert commanded_speed(speed_command(0.0, 100.0), math.nan, 0.0, DT_S) == 0.0, "no reference yet: the target"
    assert commanded_speed(position_command(1.0, 0.5, 4.0, 2.0), 0.0, 0.8, DT_S) == pytest.approx(1.3)
    assert commanded_speed(position_command(1.0, 0.5, 4.0, 2.0), 0.0, -5.0, DT_S) == 2.0
