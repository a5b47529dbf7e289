"""``drive bench motor FILE ...`` and ``drive bench motors --random N``: a motor nobody tuned for, run as a
robot builder would (docs/motors-and-control.md "Measured on motors nobody tuned for", docs/random-motors.md).
Per motor: commission it from its nameplate in simulation (standstill, shaft held; the rotating test where
the nameplate gives no inertia; the loaded test), start it from angles over the electrical circle, then run
the motor's own experiments (drive_common.config.motor_experiments) on the loops scaled to it; score each
case against the plant's truth and give the motor one verdict of issue 51 (VERDICTS)."""
import dataclasses
import math
import re
import tempfile
from pathlib import Path
from typing import NamedTuple

import numpy as np

from drive_common.config.motor_experiments import ExperimentOptions, experiment_names
from drive_common.config.scenario import ScenarioError, motor_experiment
from drive_common.contract.errors import DriveError
from drive_common.contract.exit_codes import EXIT_NOT_FOLLOWING, EXIT_NOT_TRACKING, EXIT_REFUSED, EXIT_TRIPPED
from drive_common.contract.log import COLUMN
from drive_common.motor.commissioning import save_commissioning
from drive_common.motor.motor_file import load_motor
from drive_tools.evaluation.above_speed_bench import above_speed_trial, saliency_refusal
from drive_tools.evaluation.metrics import compute_metrics, configuration_warnings, startup_metrics, supervision_faults
from drive_tools.evaluation.startup_bench import STANDARD_CASES, bench_scenario
from drive_tools.runner.commissioning_run import (
    commission_in_process,
    loaded_test_in_process,
    rotating_test_in_process,
    with_loaded_test,
)
from drive_tools.runner.runner import build_drive, run_scenario
from hf_estimator.build import predicted_error
from hf_estimator.commissioning.procedure import CommissioningError

RMS_TARGET_RAD = 0.02
PEAK_TARGET_RAD = 0.15
IDENTIFICATION_TOLERANCE = 0.10
"""Identification within 10 % of the plant's truth (issue 51's "works")."""
DERATED_LOAD_PER_LIMIT = 0.9
"""A drive that states a sensorless torque limit below rated torque (drive_common.motor.torque_limit: the torque
on its current path, MTPA where it gains, at its sensorless current limit) is loaded to this share of it
instead of rated torque."""
VERDICTS = ("works", "works derated", "works above a speed", "refused up front", "failure")
"""Issue 51's four verdicts, and failure: anything else. "works above a speed": a motor ours refuses for its
saliency, run on the I-f start and the back-EMF observer (drive_tools.evaluation.above_speed_bench)."""
CASES = tuple(experiment_names())
IDENTIFIED = ("R_s_ohm", "L_dh_H", "L_qh_H")
ROTATING_IDENTIFIED = ("psi_f_Wb", "J_kgm2")
NOT_APPLICABLE = (DriveError, CommissioningError)
"""What the drive raises when it refuses: a one-line reason (exit 2 at the command line)."""
SALIENCY_REFUSAL = "predicted angle error"
"""The words of the drive's refusal for too weak an angle signal (hf_estimator.build.refused_signal): such a motor
is run anyway (`drive run --force`) so that its predicted error can be set against the measured one."""
INJECTIONS = ("injection_frame", "square_wave")
"""The two injections the loops' rule chooses between; the rated-load case runs on both (issue 52 item 4)."""
COMPARED_CASE = "rated_load"


class TrialOptions(NamedTuple):
    """How a motor is tried: the sampling period [s], the start-up runs, and the seed of the rotor's start
    angles (None: the starts evenly over the electrical circle, every experiment from 1 rad)."""

    T_s: float = 1e-4
    starts: int = 24
    angle_seed: tuple = None


def angles_e_rad(options):
    """(start-up angles, one angle per experiment) [rad, electrical] of a trial."""
    if options.angle_seed is None:
        return (2.0 * math.pi * np.arange(options.starts) / options.starts - math.pi,
                np.full(len(CASES), ExperimentOptions().theta_e_rad))
    rng = np.random.default_rng(list(options.angle_seed))
    return rng.uniform(-math.pi, math.pi, options.starts), rng.uniform(-math.pi, math.pi, len(CASES))


def case_exit_code(result, faults):
    """The exit code `drive run` gives a finished run (docs/drive-interface.md): 7 tripped, 5 refused to start
    or ended holding zero torque after a lost lock, 6 the shaft not following, else 0."""
    if (result.protection or {}).get("trip"):
        return EXIT_TRIPPED
    states = result.log[:, COLUMN["state"]]
    if (result.startup or {}).get("refused") or (states.size and states[-1] == 4.0):
        return EXIT_NOT_TRACKING
    return EXIT_NOT_FOLLOWING if faults else 0


def case_verdict(metrics, faults, refused):
    """One phrase: what the drive did in a case."""
    if refused:
        return f"refused to start: {refused}"
    kinds = sorted({f["kind"] for f in faults})
    if metrics["lock_lost_s"]:
        return "lock lost" + (f"; {', '.join(kinds)}" if kinds else "")
    if kinds:
        return ", ".join(kinds)
    within = metrics["angle_error_rms"] <= RMS_TARGET_RAD and metrics["angle_error_peak"] <= PEAK_TARGET_RAD
    return "within targets" if within else "over target"


def one_line(error):
    """A refusal's reason: the error's text without the experiment and motor it names first."""
    text = " ".join(str(error).split())
    return re.sub(r"^\w+ on [\w.-]+: ", "", text.partition("estimator: ")[2] or text)


def motor_trial(motor_ref, options=None, progress=None):
    """Try one motor (a shipped name or a motor file) as a robot builder would (module docstring); a row of
    SI figures: identification errors, what the drive stated, the starts, every case (exit code, RMS and
    peak angle error, polarity) and the verdict with its reason."""
    options = options or TrialOptions()
    motor = load_motor(motor_ref, "drive bench motor")
    start_angles, case_angles = angles_e_rad(options)
    row = {"motor": motor.name, "file": motor.source, "description": motor.description,
           "sample_period_s": options.T_s, "tests": [], "identification_error": {}, "exit_codes": {},
           "current_limit_A": None, "warnings": [], "drive_notes": "", "loaded_test": None,
           "tracking_bandwidth_Hz": None, "injection_frequency_Hz": None, "injection_amplitude_V": None,
           "startup": None, "polarity_correct": None, "cases": [], "refused_at": None, "reason": "",
           "problems": [], "derated": False, "testing": None, "sensorless_torque": None, "injection": None,
           "injection_reason": "", "predicted": None, "forced": None, "rated_load_by_injection": {}}
    steps = 3 + options.starts + len(CASES)

    def advanced(done):
        if progress:
            progress(min(1.0, done / steps))
    with tempfile.TemporaryDirectory(prefix="motor_bench_") as folder:
        commissioning = Path(folder) / f"{motor.name}.yaml"
        first = motor_experiment(CASES[0], motor, "drive bench motor",
                                 options=ExperimentOptions(options.T_s, commissioning="nameplate"))
        try:
            _commission(first, commissioning, row)
        except RefusedForSaliency as refusal:
            row["problems"] = _identification_problems(row)
            row = above_speed_trial(motor, commissioning, options.T_s, row, str(refusal),
                                    (start_angles, dict(zip(CASES, case_angles))),
                                    lambda result: case_exit_code(result, supervision_faults(result)))
            row["forced"] = _forced_commissioning(first, commissioning, (motor, case_angles, options.T_s), row,
                                                  str(refusal))
            return row
        except NOT_APPLICABLE as error:
            refused = (f"commissioning, the {row['testing']} test", one_line(error))
            if SALIENCY_REFUSAL in refused[1]:
                row["forced"] = _forced_commissioning(first, commissioning, (motor, case_angles, options.T_s), row,
                                                      refused[1])
            return _verdict(row, refused=refused)
        advanced(3)
        try:
            row["startup"] = _starts(motor, start_angles, commissioning, options.T_s, advanced)
            _cases(motor, case_angles, commissioning, options.T_s, row, lambda i: advanced(3 + options.starts + i))
        except ScenarioError as error:
            reason = one_line(error)
            if SALIENCY_REFUSAL in reason:
                row["forced"] = _forced_cases(motor, case_angles, options.T_s, commissioning, row)
            return _verdict(row, refused=("the drive", reason))
    return _verdict(row)


def forced(scenario):
    """``scenario`` run as `drive run --force` runs it (the estimator setting ``run_refused``)."""
    return dataclasses.replace(scenario, estimator_settings={**scenario.estimator_settings, "run_refused": True})


def _forced_commissioning(first, commissioning, trial, row, reason):
    """A motor whose commissioning's rotating or loaded test was refused for its weak angle signal: commissioned
    anyway (`--force`), then its cases run anyway (_forced_cases: ``trial`` is the motor, its cases' angles and
    the sampling period); where the commissioning fails even so, {"commissioning": its reason}, and the prediction
    the refusal ``reason`` stated into ``row``."""
    try:
        _commission(forced(first), commissioning, {**row, "tests": [], "identification_error": {}})
    except NOT_APPLICABLE as error:
        stated = re.search(r"predicted angle error ([\d.]+) rad RMS, ([\d.]+) rad peak", reason)
        if stated:
            row["predicted"] = {"rms": float(stated[1]), "peak": float(stated[2]), "estimator": "injection_frame"}
        return {"commissioning": one_line(error)}
    return _forced_cases(*trial, commissioning, row)


def _predicted(scenario):
    """{rms, peak} [rad] of the angle error the drive predicts for ``scenario`` before running
    (hf_estimator.build.predicted_error), None where it predicts none."""
    drive = build_drive(scenario)
    predicted = predicted_error(drive.estimator, drive.commissioning)
    return None if predicted is None else {"rms": float(predicted[0]), "peak": float(predicted[1]),
                                           "estimator": drive.estimator.name}


def _case_figures(result):
    """A case's exit code and angle error figures."""
    metrics, faults = compute_metrics(result), supervision_faults(result)
    refused = (result.startup or {}).get("refused")
    return {"exit_code": case_exit_code(result, faults), "angle_error_rms": metrics["angle_error_rms"],
            "angle_error_peak": metrics["angle_error_peak"], "lock_lost_s": metrics["lock_lost_s"],
            "verdict": case_verdict(metrics, faults, refused)}


def _forced_cases(motor, angles, T_s, commissioning, row):
    """A motor the drive refused for its weak angle signal, run anyway (`drive run --force`): every case's
    figures, and the prediction it was refused on into ``row``."""
    cases = {}
    for case, theta_e in zip(CASES, angles):
        scenario = motor_experiment(case, motor, "drive bench motor",
                                    options=ExperimentOptions(T_s, float(theta_e), 1, 1.0, str(commissioning)))
        scenario = forced(scenario)
        if row["predicted"] is None:
            row["predicted"] = _predicted(scenario)
        cases[case] = _case_figures(run_scenario(scenario))
    return cases


def _commission(scenario, commissioning, row):
    """Commission ``scenario``'s motor into the file ``commissioning`` as `drive commission --loaded` (and
    --rotating where the nameplate gives no J) does; fill ``row``'s identification errors and tests."""
    row["testing"] = "standstill"
    run = commission_in_process(scenario)
    measured, truth = run.procedure.result(), dict(run.truth)
    name = scenario.motor.name
    save_commissioning(commissioning, measured, name, "drive bench motor")
    row["tests"].append("standstill")
    row["identification_error"] = _errors(measured, truth, IDENTIFIED)
    if math.isfinite(scenario.motor.nameplate.J_kgm2):
        _refuse_for_saliency(scenario, commissioning)
    else:
        row["testing"] = "rotating"
        estimates, rotating_truth, _ = rotating_test_in_process(scenario, commissioning)
        measured = measured._replace(psi_f_Wb=estimates["psi_f_Wb"], J_kgm2=estimates["J_kgm2"])
        save_commissioning(commissioning, measured, name, "drive bench motor")
        row["tests"].append("rotating")
        row["identification_error"].update(_errors(measured, rotating_truth, ROTATING_IDENTIFIED))
        _refuse_for_saliency(scenario, commissioning)
    if _polarity_by_torque(scenario, commissioning):
        row["tests"].append("loaded not offered: its shaft is held, and this motor's polarity is told by turning it")
        return
    row["testing"] = "loaded"
    loaded, _ = loaded_test_in_process(scenario, commissioning)
    measured = with_loaded_test(measured, loaded)
    save_commissioning(commissioning, measured, name, "drive bench motor")
    row["tests"].append("loaded")
    rated = scenario.motor.nameplate.rated_current_A
    row["loaded_test"] = {"significant": loaded["significant"], "zero_spread_rad": loaded["zero_spread_rad"],
                          "correction_at_rated_rad": float(np.interp(rated, measured.saliency_shift_i_q_A,
                                                                     loaded["estimator_shift_rad"]))}


def _polarity_by_torque(scenario, commissioning):
    """Whether ours tells this motor's polarity by torque pulses on the free shaft (docs/startup.md), on what the
    file ``commissioning`` holds: the loaded test, whose shaft is held, cannot start it."""
    try:
        drive = build_drive(dataclasses.replace(scenario, commissioning=str(commissioning)))
    except ScenarioError:
        return False
    startup = getattr(getattr(drive.estimator.params, "hf", drive.estimator.params), "startup", None)
    return startup is not None and startup.torque_pulse_A > 0.0


def _refuse_for_saliency(scenario, commissioning):
    """RefusedForSaliency where ours refuses the motor for its saliency on what the file ``commissioning``
    holds so far (the rotating test's J where the nameplate gives none: ours' loops and polarity pulses are
    sized on the rotor's inertia, so a refusal on an assumed J would refuse motors that run); nothing for a
    forced scenario."""
    if not scenario.estimator_settings.get("run_refused"):
        refusal = saliency_refusal(dataclasses.replace(scenario, commissioning=str(commissioning)))
        if refusal:
            raise RefusedForSaliency(refusal)


class RefusedForSaliency(Exception):
    """Ours refuses the motor for its saliency after the standstill test (its one line)."""


def _errors(measured, truth, keys):
    return {key: float(getattr(measured, key) / truth[key] - 1.0) for key in keys if truth.get(key)}


def _starts(motor, angles, commissioning, T_s, advanced):
    """Start-ups from rest at each electrical angle of ``angles``, no load: their summary."""
    rows = []
    for i, theta_e in enumerate(angles):
        scenario = bench_scenario(motor, None, float(theta_e), 1, STANDARD_CASES[0], commissioning=commissioning,
                                  T_s=T_s)
        result = run_scenario(scenario)
        rows.append({**startup_metrics(scenario, result.log, result.n_p),
                     "refused": (result.startup or {}).get("refused")})
        advanced(4 + i)
    correct = [bool(r["polarity_correct"]) for r in rows]
    backwards = [r["reverse_rotation_m_rad"] for r in rows if r["reverse_rotation_m_rad"] is not None]
    errors = [abs(r["angle_error_e_rad"]) for r in rows if r["angle_error_e_rad"] is not None]
    return {"runs": len(rows), "polarity_correct": int(sum(correct)),
            "polarity_correct_fraction": float(np.mean(correct)) if rows else None,
            "angle_error_max_e_rad": max(errors, default=None),
            "reverse_rotation_max_m_deg": math.degrees(max(backwards)) if backwards else None,
            "refused": sum(1 for r in rows if r["refused"]), "not_started": sum(1 for r in rows if not r["completed"]),
            "lock_lost": int(sum(r["lock_lost"] for r in rows))}


def _cases(motor, angles, commissioning, T_s, row, advanced):
    """Run the motor's experiments, each from its angle of ``angles``, into ``row``. A drive that states a
    sensorless torque limit below rated torque (its first case shows it) is loaded to DERATED_LOAD_PER_LIMIT
    of it."""
    load_per_rated = 1.0
    for i, (case, theta_e) in enumerate(zip(CASES, angles)):
        experiment = ExperimentOptions(T_s, float(theta_e), 1, load_per_rated, str(commissioning))
        scenario = motor_experiment(case, motor, "drive bench motor", options=experiment)
        result = run_scenario(scenario)
        metrics, faults = compute_metrics(result), supervision_faults(result)
        refused = (result.startup or {}).get("refused")
        code = case_exit_code(result, faults)
        row["exit_codes"][case] = code
        top_load = max(abs(v) for v in scenario.load.values) / motor.nameplate.rated_torque_Nm
        row["cases"].append({"case": case, "load_per_rated": top_load, "exit_code": code,
                             "angle_error_rms": metrics["angle_error_rms"],
                             "angle_error_peak": metrics["angle_error_peak"],
                             "speed_tracking_error_rms": metrics["speed_tracking_error_rms"],
                             "polarity_correct": metrics["startup"]["polarity_correct"],
                             "lock_lost_s": metrics["lock_lost_s"], "supervision": faults,
                             "verdict": case_verdict(metrics, faults, refused)})
        if case == COMPARED_CASE:
            _both_injections(scenario, result, row)
        if i == 0:
            facts = result.estimator_facts
            row["injection"] = facts.get("estimator")
            row["predicted"] = _predicted(scenario)
            row.update(current_limit_A=result.current_limit_A, warnings=configuration_warnings(result),
                       drive_notes=facts.get("injection_note", ""),
                       tracking_bandwidth_Hz=facts.get("tracking_bandwidth_Hz"),
                       injection_frequency_Hz=facts.get("injection_frequency_Hz"),
                       injection_amplitude_V=facts.get("injection_amplitude_V"))
            row["sensorless_torque"] = result.sensorless_torque
            stated = result.sensorless_torque["rated_share"]
            row["derated"] = stated < 1.0
            load_per_rated = DERATED_LOAD_PER_LIMIT * stated if row["derated"] else 1.0
        advanced(i + 1)


def _both_injections(scenario, result, row):
    """The rated-load case on both injections (the one the loops' rule chose ran as ``result``; the other runs
    on its own rules, a refusal counted as such) into ``row['rated_load_by_injection']``."""
    chosen = result.estimator_facts.get("estimator")
    for name in INJECTIONS:
        if name == chosen:
            row["rated_load_by_injection"][name] = _case_figures(result)
            continue
        other = dataclasses.replace(scenario, estimator=name, estimator_settings={})
        try:
            row["rated_load_by_injection"][name] = _case_figures(run_scenario(other))
        except ScenarioError as error:
            row["rated_load_by_injection"][name] = {"exit_code": EXIT_REFUSED, "angle_error_rms": None,
                                                    "angle_error_peak": None, "lock_lost_s": None,
                                                    "verdict": f"refused: {one_line(error)}"}


def _verdict(row, refused=None):
    """``row`` with its verdict (VERDICTS) and the reason, by issue 51's definitions."""
    if refused:
        row["refused_at"], row["reason"] = refused
        row["problems"] = [refused[1]]
        row["verdict"] = "refused up front"
        row["exit_codes"] = {case: EXIT_REFUSED for case in CASES}
        return row
    starts = row["startup"]
    polarity = [starts["polarity_correct"]] + [int(bool(c["polarity_correct"])) for c in row["cases"]]
    runs = starts["runs"] + len(row["cases"])
    row["polarity_correct"] = {"correct": int(sum(polarity)), "starts": runs}
    problems = _identification_problems(row)
    if sum(polarity) < runs:
        problems.append(f"polarity wrong or not found in {runs - sum(polarity)} of {runs} starts")
    for case in row["cases"]:
        if case["exit_code"]:
            problems.append(f"{case['case']}: exit {case['exit_code']} ({case['verdict']})")
        elif case["verdict"] != "within targets":
            problems.append(f"{case['case']}: {case['verdict']} (RMS {case['angle_error_rms']:.3g} rad, peak "
                            f"{case['angle_error_peak']:.3g} rad)")
    derated = row["derated"]
    row["problems"] = problems
    if problems:
        row["verdict"], row["reason"] = "failure", "; ".join(problems)
    elif derated:
        row["verdict"] = "works derated"
        row["reason"] = f"{row['sensorless_torque']['line']}, stated before the run"
    else:
        row["verdict"] = "works"
    return row


def _identification_problems(row):
    return [f"identification {key} {100.0 * error:+.1f} %" for key, error in row["identification_error"].items()
            if abs(error) > IDENTIFICATION_TOLERANCE]


def crashed_row(motor_ref, options, error):
    """The failure row of a trial that raised ``error`` (a defect of the drive or the bench, shown as such)."""
    motor = load_motor(motor_ref, "drive bench motor")
    reason = f"the trial raised {type(error).__name__}: {' '.join(str(error).split())}"
    return {"motor": motor.name, "file": motor.source, "description": motor.description,
            "sample_period_s": options.T_s, "tests": [], "identification_error": {}, "exit_codes": {},
            "current_limit_A": None, "warnings": [], "polarity_correct": None, "cases": [], "refused_at": None,
            "verdict": "failure", "reason": reason, "problems": [reason]}


def reason_kind(reason):
    """A reason with its numbers and motor names taken out: refusals and failures of one cause count
    together."""
    text = re.sub(r"\S*motor_bench_\S*\.yaml", "FILE", reason)
    text = re.sub(r"random_\d+_\d+", "MOTOR", text)
    return re.sub(r"[-+−]?\d+(\.\d+)?(e[-+]?\d+)?", "#", text)
