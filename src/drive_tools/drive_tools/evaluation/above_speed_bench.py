"""A motor refused for saliency, tried as it can run (issue 52 item 3, docs/random-motors.md "works above a
speed"): the I-f start up to the back-EMF observer's minimum speed, then closed loop on the observer
(hf_estimator.if_observer, drive_common.motor.open_loop_start). The motor's own experiments run with their
speeds in units of ABOVE_SPEED_MARGIN of that speed and their times stretched so the I-f ramp can follow
them; the standstill hold must be refused up front (exit 2). Each case is judged on the plant's truth:
- I-f: no loss of synchronism, the load angle λ (the true current's angle less the rotor's d axis) within
  ±π/2 in every open-loop sample after the first lock where the current has reached half the I-f current;
- closed loop: the observer's angle error within ours' targets (RMS ≤ 0.02 rad, peak ≤ 0.15 rad) over the
  closed-loop samples from SETTLED_S after each hand-over; the drive in closed loop by the case's end;
- the speed followed: the mean |ω_m − ω*_m| over the case's last FINAL_SHARE within SPEED_TOLERANCE of the
  experiments' speed unit;
- exit code 0 (no trip, no supervision fault)."""
import dataclasses
import math

import numpy as np

from drive_common.config.motor_experiments import ExperimentOptions
from drive_common.config.scenario import ScenarioError, motor_experiment
from drive_common.contract.exit_codes import EXIT_REFUSED
from drive_common.contract.log import COLUMN
from drive_common.math.frames import clarke_contract
from drive_common.motor.open_loop_start import ESTIMATOR
from drive_tools.runner.runner import run_scenario, scenario_commissioning

ABOVE_SPEED_MARGIN = (1.5, 1.2)
"""The experiments' speed unit (a speed step's low level, a reversal's end points and the load's speed): 1.5 ×
the stated minimum speed, at most half rated speed (the speed step doubles it) but at least 1.2 × that speed
(a speed step past rated speed failed on the bus, not on the start)."""
SETTLED_S = 0.02
FINAL_SHARE = 0.1
SPEED_TOLERANCE = 0.1
RMS_TARGET_RAD = 0.02
PEAK_TARGET_RAD = 0.15
RAMP_S = 0.1
"""The experiments' tables reach their speed in 0.1 s; stretched so the I-f ramp gets there in that time."""
REFUSED_CASE = "standstill_hold"


def saliency_refusal(scenario):
    """"" or the one line with which ours (``scenario``'s injecting estimator, on its commissioning) refuses the
    motor for its saliency; where the nameplate gives no J, with the J the rotating test assumes (ours' start-up
    sizes its polarity pulses on it, as it would in that test)."""
    from hf_estimator.build import SALIENCY_REFUSALS, estimator_for_scenario
    from hf_estimator.commissioning.rotating import assumed_inertia_kgm2
    plate = scenario.motor.nameplate
    if not math.isfinite(plate.J_kgm2):
        motor = dataclasses.replace(scenario.motor, nameplate=plate._replace(J_kgm2=assumed_inertia_kgm2(plate)))
        scenario = dataclasses.replace(scenario, motor=motor)
    commissioning = scenario_commissioning(scenario)
    if not commissioning.salient():
        return "no saliency measured at standstill: the HF injection has no angle to find"
    try:
        estimator_for_scenario(scenario, commissioning)
    except ScenarioError as error:
        text = " ".join(str(error).split())
        if any(kind in text for kind in SALIENCY_REFUSALS):
            return (text.partition("estimator: ")[2] or text).partition("; `estimator: ")[0].partition(
                "; nor can it start open loop")[0]
    return ""


def above_speed_plan(motor, commissioning_file, T_s):
    """(the I-f start the drive states for ``motor`` with its commissioning, the experiments' ExperimentOptions
    but for the angle and the load, the controller's first lock [s]; None where the start is refused)."""
    from foc_controller.build import controller_for_scenario
    from hf_estimator.if_observer import plan_for
    scenario = motor_experiment("low_speed", motor, "drive bench motor",
                                options=ExperimentOptions(T_s, commissioning=str(commissioning_file),
                                                          estimator=ESTIMATOR))
    commissioning = scenario_commissioning(scenario)
    plan = plan_for(commissioning.refined(motor.nameplate), commissioning, motor.inverter)
    if plan.refused:
        return plan, None, None
    controller = controller_for_scenario(scenario, 0.0, math.inf, None, commissioning)
    handover_rpm = plan.handover_rpm(motor.nameplate.n_p)
    unit_rpm = max(min(ABOVE_SPEED_MARGIN[0] * handover_rpm, 0.5 * motor.nameplate.rated_speed_rpm),
                   ABOVE_SPEED_MARGIN[1] * handover_rpm)
    unit_e = unit_rpm * math.pi / 30.0 * motor.nameplate.n_p
    scale = max(1.0, (plan.align_s + unit_e / plan.acceleration_rad_s2) / RAMP_S,
                2.0 * unit_e / plan.acceleration_rad_s2 / (2.0 * RAMP_S))
    return (plan, ExperimentOptions(T_s, 1.0, 1, 1.0, str(commissioning_file), unit_rpm, scale, ESTIMATOR),
            controller.if_align_samples * T_s)


def case_figures(result, align_s):
    """The above-speed figures of a finished case (module docstring): the largest load angle in I-f [rad],
    the closed-loop share, the angle error RMS and peak [rad] and the final speed error [rad/s] (mech.)."""
    log, n_p = result.log, result.n_p
    t = log[:, COLUMN["t"]]
    theta = n_p * log[:, COLUMN["theta_m"]]
    i_alpha, i_beta = clarke_contract(log[:, COLUMN["i_a"]], log[:, COLUMN["i_b"]], log[:, COLUMN["i_c"]])
    load_angle = np.angle(np.exp(1j * (np.arctan2(i_beta, i_alpha) - theta)))
    open_loop = log[:, COLUMN["i_d_ref"]] > 0.0
    current = np.hypot(i_alpha, i_beta)
    synchronism = open_loop & (t > align_s) & (current >= 0.5 * log[:, COLUMN["i_d_ref"]])
    closed = ~open_loop
    since = np.zeros(len(t))
    run = 0
    for k, c in enumerate(closed):
        run = run + 1 if c else 0
        since[k] = run * result.scenario.T_s
    judged = closed & (since >= SETTLED_S)
    error = np.angle(np.exp(1j * (log[:, COLUMN["theta_e_hat"]] - theta)))[judged]
    final = t >= (1.0 - FINAL_SHARE) * t[-1]
    speed_error = np.abs(log[final, COLUMN["omega_m"]] - log[final, COLUMN["omega_m_ref"]])
    return {"load_angle_max_rad": float(np.max(np.abs(load_angle[synchronism]))) if synchronism.any() else 0.0,
            "closed_loop_share": float(np.mean(closed)), "closed_at_end": bool(closed[-1]),
            "angle_error_rms": float(np.sqrt(np.mean(error ** 2))) if error.size else math.nan,
            "angle_error_peak": float(np.max(np.abs(error))) if error.size else math.nan,
            "speed_error_final_rad_s": float(np.mean(speed_error))}


def case_problems(figures, unit_rad_s):
    """What misses the above-speed targets in a case's figures (module docstring)."""
    problems = []
    if figures["load_angle_max_rad"] >= 0.5 * math.pi:
        problems.append(f"I-f lost synchronism (load angle {figures['load_angle_max_rad']:.2f} rad)")
    if not figures["closed_at_end"]:
        problems.append("not in closed loop at the end")
    if not (figures["angle_error_rms"] <= RMS_TARGET_RAD and figures["angle_error_peak"] <= PEAK_TARGET_RAD):
        problems.append(f"observer over target (RMS {figures['angle_error_rms']:.3g} rad, peak "
                        f"{figures['angle_error_peak']:.3g} rad)")
    if figures["speed_error_final_rad_s"] > SPEED_TOLERANCE * unit_rad_s:
        problems.append(f"speed off by {figures['speed_error_final_rad_s']:.3g} rad/s at the end")
    return problems


def above_speed_cases(motor, options, align_s, angles, starts, exit_code):
    """Run the start from each of ``starts`` (electrical angles, the low-speed case) and the experiments, each
    from its angle (``angles``: case name → electrical angle), with ``options`` and the first lock ``align_s``
    (above_speed_plan's); ``exit_code(result)``: a finished run's exit code. Returns (start rows, case rows)."""
    start_rows, case_rows = [], []
    unit = options.unit_rpm * math.pi / 30.0
    jobs = [("low_speed", float(a), True) for a in starts] + [(c, float(a), False) for c, a in angles.items()]
    for case, theta_e, is_start in jobs:
        scenario_options = options._replace(theta_e_rad=theta_e, load_per_rated=1.0)
        try:
            scenario = motor_experiment(case, motor, "drive bench motor", options=scenario_options)
            result = run_scenario(scenario)
        except ScenarioError as error:
            refused = " ".join(str(error).split()).partition("estimator: ")[2]
            row = {"case": case, "exit_code": EXIT_REFUSED, "verdict": f"refused: {refused}",
                   "angle_error_rms": None, "angle_error_peak": None, "load_per_rated": 0.0,
                   "problems": [] if case == REFUSED_CASE else [f"{case}: refused ({refused})"]}
            (start_rows if is_start else case_rows).append(row)
            continue
        figures = case_figures(result, align_s)
        code = exit_code(result)
        problems = case_problems(figures, unit)
        if code:
            problems.insert(0, f"exit {code}")
        if case == REFUSED_CASE:
            problems.insert(0, "standstill hold not refused up front")
        row = {"case": case, "exit_code": code, "theta_e_rad": theta_e, **figures,
               "load_per_rated": float(max(abs(v) for v in scenario.load.values)
                                       / motor.nameplate.rated_torque_Nm),
               "verdict": "; ".join(problems) or "within targets",
               "problems": [f"{case}: {p}" for p in problems]}
        (start_rows if is_start else case_rows).append(row)
    return start_rows, case_rows



def above_speed_trial(motor, commissioning_file, T_s, row, reason, angles, exit_code):
    """``row`` (motor_bench.motor_trial's, commissioned at standstill into ``commissioning_file``, its
    ``problems`` the identification's) of a motor ours refuses for its saliency (``reason``) tried above a
    speed at the sampling period ``T_s``: refused up front where the I-f start is (its reason after the
    saliency's), else its starts and cases (``angles``: (start angles, case name → angle) [rad, electrical];
    ``exit_code(result)``) and the verdict "works above a speed" or failure with its problems."""
    plan, experiment, align_s = above_speed_plan(motor, commissioning_file, T_s)
    row["refused_for_saliency"] = reason
    if experiment is None:
        row.update(refused_at="the drive", reason=f"{reason}; {plan.refused}", problems=[plan.refused],
                   verdict="refused up front", exit_codes={case: EXIT_REFUSED for case in angles[1]})
        return row
    n_p = motor.nameplate.n_p
    row.update(stated=plan.statement(n_p), above_speed_rpm=plan.handover_rpm(n_p), drive_notes=plan.statement(n_p))
    starts, cases = above_speed_cases(motor, experiment, align_s, angles[1], angles[0], exit_code)
    row["startup"] = {"runs": len(starts), "synchronous": sum(1 for r in starts if not r["problems"]),
                      "load_angle_max_rad": max((r.get("load_angle_max_rad", 0.0) for r in starts), default=None)}
    row["cases"] = cases
    row["exit_codes"] = {c["case"]: c["exit_code"] for c in cases}
    problems = list(row["problems"])
    problems += [f"start from {r['theta_e_rad']:+.2f} rad: {p}" for r in starts for p in r["problems"]]
    problems += [p for r in cases for p in r["problems"]]
    row["problems"] = problems
    if problems:
        row["verdict"], row["reason"] = "failure", "; ".join(problems)
    else:
        row["verdict"], row["reason"] = "works above a speed", plan.statement(n_p)
    return row


def stated_before_run(scenario):
    """The line `drive run` says before it acts with the I-f start ("" with another estimator)."""
    if scenario.estimator != ESTIMATOR:
        return ""
    from hf_estimator.if_observer import plan_for
    commissioning = scenario_commissioning(scenario)
    plan = plan_for(commissioning.refined(scenario.motor.nameplate), commissioning, scenario.motor.inverter)
    return "" if plan.refused else f"{scenario.motor.name}: {plan.statement(scenario.motor.nameplate.n_p)}"
