"""The polarity by torque pulses (docs/startup.md "Polarity by torque pulses", hf_estimator.torque_polarity): the
design over a draw of the random motors, the decision fed by hand, and the whole start on drawn interior rotors
whose d axis does not saturate (the motors the saturation pulses cannot serve): the right pole from random
angles, the shaft's motion within the bound the drive states."""
import dataclasses
import math
import tempfile
from pathlib import Path

import numpy as np
import pytest

from drive_common.contract.estimator_states import ALIGNING, HOLD, POLARITY
from drive_common.contract.log import COLUMN
from drive_common.motor.commissioning import nameplate_commissioning, save_commissioning
from drive_common.motor.motor_file import load_motor
from drive_tools.evaluation.metrics import startup_metrics
from drive_tools.evaluation.random_motors import draw_motor, write_motor_files
from drive_tools.evaluation.startup_bench import STANDARD_CASES, bench_scenario
from drive_tools.runner.commissioning_run import commission_in_process
from drive_tools.runner.runner import build_drive, run_scenario
from hf_estimator.startup_state import NO_MOTION, STARTUP
from hf_estimator.torque_polarity import (
    BOUND_PER_TARGET,
    GROWTH,
    TARGET_E_RAD,
    TRIES,
    doublet_turn_e_rad,
    startup_fields,
    torque_decide,
    torque_polarity_design,
)

T_S = 1e-4
DURATION_S = 0.6
"""Each start runs this long: a heavy rotor's doublets, escalated, take longer than the start-up bench's 0.25 s."""
STATE = np.dtype([("theta", np.float64), ("omega", np.float64), ("startup", STARTUP)])


def _motors(seed, count, keep, folder):
    """Motors ``keep`` accepts among the first ``count`` of the random draw ``seed`` (Motor records, their files
    written into ``folder``)."""
    picked = [m for m in (draw_motor(seed, i) for i in range(count)) if keep(m)]
    return [load_motor(str(path), "test") for path in write_motor_files(picked, Path(folder))]


def _unsaturated_interior(motor):
    """An interior rotor whose iron does not saturate (no asymmetry for the d-axis pulses), L_q/L_d ≥ 1.3 (the
    salient motors issue 51 says must not be refused), J on its nameplate."""
    return (motor.figures["rotor"] == "interior" and not motor.figures["saturation"]
            and motor.figures["L_q_per_L_d"] >= 1.3 and "J_kgm2" in motor.document["nameplate"])


@pytest.mark.unit
def test_the_design_turns_the_rotor_by_its_target_within_rated_current_over_a_draw(tmp_path):
    """Over the random motors of seeds 2-4 with J on the nameplate (the first 60 of each, about 90): the first doublet
    stays within
    rated current and the current limit, turns the nameplate's rotor by the designed target (electrical) to
    within the whole-sample rounding (≤ +30 %), the target at most TARGET_E_RAD and at most 2° at the shaft
    (0.12 rad electrical where that is more); the stated bound BOUND_PER_TARGET × the target covers an
    escalation's GROWTH × the margin."""
    checked = 0
    for seed in (2, 3, 4):
        for motor in _motors(seed, 60, lambda m: "J_kgm2" in m.document["nameplate"], tmp_path):
            plate = motor.nameplate
            design = torque_polarity_design(plate, nameplate_commissioning(plate), T_S,
                                            motor.inverter._replace(delay_periods=1))
            assert design.problem == ""
            assert 0.0 < design.current_A <= min(plate.rated_current_A, plate.current_limit_A) * (1 + 1e-9)
            turn = doublet_turn_e_rad(plate.n_p, plate.psi_f_Wb, plate.J_kgm2, design.current_A, design.samples * T_S)
            assert design.target_e_rad * (1 - 1e-9) <= turn <= 1.3 * design.target_e_rad, motor.name
            assert design.target_e_rad <= min(TARGET_E_RAD, max(0.12, plate.n_p * math.radians(2.0))) * (1 + 1e-9)
            assert GROWTH * design.margin_rad <= design.target_e_rad * BOUND_PER_TARGET
            assert design.bound_shaft_deg <= BOUND_PER_TARGET * max(math.degrees(0.12 / plate.n_p), 2.0) * (1 + 1e-9)
            checked += 1
    assert checked > 70


@pytest.mark.unit
def test_the_decision_takes_half_the_difference_of_a_mirrored_pair():
    """Fed by hand: a pair that turned the axis −0.2 then +0.2 rad (the held end the south) is flipped by π; a
    pair whose creep of +0.1 rad each time cancels to 0 is another, stronger pair; TRIES of those refuse the start
    (the shaft did not turn)."""
    plate = load_motor("wang_spmsm", "test").nameplate
    design = torque_polarity_design(plate, nameplate_commissioning(plate), T_S,
                                    load_motor("wang_spmsm", "test").inverter._replace(delay_periods=1))
    from hf_estimator.startup import make_startup  # noqa: F401  (StartupParams built as a drive builds them)
    from hf_estimator.startup_state import StartupParams
    base = {name: 0.0 for name in StartupParams._fields}
    p = StartupParams(**{**base, **startup_fields(design), "delay_periods": 1, "T_s_s": T_S})

    def after(x, first, second):
        s = x["startup"]
        s["theta_held"], s["moved"], s["axis_count"] = 1.0, 1.0, 1.0
        s["axis_ref"], s["axis_sum"] = 1.0 + first, 0.0
        assert torque_decide(x, p, 10) == (False, float(ALIGNING))
        s["moved"], s["axis_ref"] = 2.0, 1.0 + first + second
        return torque_decide(x, p, 20)

    x = np.zeros(1, STATE)[0]
    x["theta"] = 1.0
    assert after(x, -0.2, 0.2) == (True, float(POLARITY))
    assert x["startup"]["flipped"] == 1.0 and math.cos(x["theta"] - 1.0 - math.pi) > 0.99
    x = np.zeros(1, STATE)[0]
    x["theta"] = 1.0
    for _ in range(TRIES):
        decided, state = after(x, 0.1, 0.1)
        assert not decided
    assert state == float(HOLD) and x["startup"]["refused"] == NO_MOTION


def _starts(motors, angles, seed):
    """Each motor commissioned at standstill from its nameplate (in simulation), then started without load from
    ``angles`` random angles, each for DURATION_S: per motor (its stated bound [°], rows of (right pole, the
    shaft's largest turn from the first doublet to the first torque [°], reached torque))."""
    rng = np.random.default_rng(seed)
    results = []
    with tempfile.TemporaryDirectory() as folder:
        for motor in motors:
            commissioning = Path(folder) / f"{motor.name}.yaml"
            first = bench_scenario(motor, None, 0.0, 1, STANDARD_CASES[0], commissioning="nameplate")
            save_commissioning(commissioning, commission_in_process(first).procedure.result(), motor.name, "test")
            drive = build_drive(bench_scenario(motor, None, 0.0, 1, STANDARD_CASES[0], commissioning=commissioning))
            assert "torque pulses on the free shaft" in drive.estimator.injection_note, motor.name
            bound = drive.estimator.params.startup.torque_bound_shaft_deg
            rows = []
            for j in range(angles):
                scenario = dataclasses.replace(bench_scenario(
                    motor, None, float(rng.uniform(-math.pi, math.pi)), j + 1, STANDARD_CASES[0],
                    commissioning=commissioning), duration_s=DURATION_S)
                result = run_scenario(scenario)
                log = result.log
                tracking = np.flatnonzero(log[:, COLUMN["state"]] == 3)
                end = tracking[0] if tracking.size else len(log)
                tested = np.flatnonzero(log[:end, COLUMN["state"]] == 2)
                first = tested[0] if tested.size else 0
                turn = np.max(np.abs(log[first:end + 1, COLUMN["theta_m"]] - log[first, COLUMN["theta_m"]]))
                metrics = startup_metrics(scenario, log, result.n_p)
                rows.append((bool(metrics["polarity_correct"]), math.degrees(turn), bool(tracking.size)))
            results.append((motor.name, bound, rows))
    return results


def _check(results, share, bounded_share):
    """The right pole in ``share`` of the starts, every start reaching torque, the shaft's turn within the stated
    bound in ``bounded_share`` of them."""
    right = sum(r[0] for _, _, rows in results for r in rows)
    total = sum(len(rows) for _, _, rows in results)
    wrong = [(name, j) for name, _, rows in results for j, r in enumerate(rows) if not r[0]]
    beyond = [(name, j, round(r[1], 1), round(bound, 1)) for name, bound, rows in results
              for j, r in enumerate(rows) if r[1] > bound]
    print(f"{len(results)} motors, {right} of {total} starts right, wrong: {wrong}; beyond the bound: {beyond}")
    assert right >= share * total, wrong
    assert all(r[2] for _, _, rows in results for r in rows)
    assert len(beyond) <= (1.0 - bounded_share) * total, beyond


def test_unsaturated_interior_rotors_start_on_the_right_pole_with_the_shaft_motion_bounded(tmp_path):
    """Two drawn interior rotors without saturation (seed 5: a 21-pole-pair one whose rated torque takes it to
    rated speed in 8 ms, a 5-pole-pair one in 11 ms), commissioned, 3 random angles each: every start reaches
    torque on the right pole, the shaft turning less than the stated bound before torque."""
    motors = [m for m in _motors(5, 83, _unsaturated_interior, tmp_path)
              if m.name in ("random_5_0069", "random_5_0082")]
    assert len(motors) == 2
    _check(_starts(motors, 3, 5), 1.0, 1.0)


DRAW = ((3, 4, 5), 200, 12, 7)
"""The heavy draw: seeds, motors per seed looked at, start angles per motor, the angles' seed."""


@pytest.mark.heavy
def test_unsaturated_interior_rotors_over_a_draw_start_on_the_right_pole(tmp_path):
    """Every interior rotor without saturation, L_q/L_d ≥ 1.3, J on its nameplate, among the first 200 motors of
    seeds 3, 4 and 5 (the docs' seed 1 not among them), commissioned, 12 random angles each: the right pole in
    ≥ 99.5 % of the starts, every start reaching torque (docs/results.md "Polarity by torque pulses")."""
    seeds, count, angles, angle_seed = DRAW
    motors = [m for seed in seeds for m in _motors(seed, count, _unsaturated_interior, tmp_path)]
    assert len(motors) >= 12
    _check(_starts(motors, angles, angle_seed), 0.995, 0.0)


@pytest.mark.heavy
@pytest.mark.xfail(strict=True, reason="open: light rotors creep at zero current during the test's alignments and "
                   "escalated pairs overshoot; 26 of 396 starts beyond the stated bound (docs/results.md)")
def test_unsaturated_interior_rotors_keep_the_shaft_within_the_stated_bound(tmp_path):
    """The same draw: the shaft's turn from the first doublet to torque within the bound the drive states before
    the run in ≥ 99 % of the starts."""
    seeds, count, angles, angle_seed = DRAW
    motors = [m for seed in seeds for m in _motors(seed, count, _unsaturated_interior, tmp_path)]
    assert len(motors) >= 12
    _check(_starts(motors, angles, angle_seed), 0.0, 0.99)
