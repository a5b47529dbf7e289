"""``drive bench motor FILE ...``: a motor nobody tuned for, as a robot builder meets it (docs/motors-and-
control.md "Measured on motors nobody tuned for"). For each motor file: commission it from its nameplate
(shaft held, in simulation) and let it measure ours' error under load (the loaded test, shaft still held),
start it from angles over the electrical circle (polarity), then run ours on the loops scaled to it through
the issue's cases at 5 % rated speed. Each case says what the drive said:
within ours' targets, over them, refused (and why), lock lost, or the shaft not following (supervision)."""
import tempfile
from pathlib import Path

import numpy as np

from drive_common.config.scenario import ScenarioError, parse_scenario
from drive_common.motor.commissioning import save_commissioning
from drive_common.motor.motor_file import load_motor
from drive_tools.evaluation.metrics import compute_metrics, configuration_warnings, supervision_faults
from drive_tools.evaluation.startup_bench import STANDARD_CASES, startup_sweep
from drive_tools.runner.commissioning_run import commission_in_process, loaded_test_in_process, with_loaded_test
from drive_tools.runner.runner import run_scenario
from hf_estimator.commissioning.loaded import LoadedTestError

RMS_TARGET_RAD = 0.02
PEAK_TARGET_RAD = 0.15
SPEED_PER_RATED = 0.05
CASES = {
    "rated load at 5 %": {"speed": [[0.0, 0.0], [0.1, 1.0], [1.2, 1.0]],
                          "load": [[0.0, 0.0], [0.3, 0.0], [0.4, 1.0], [1.2, 1.0]], "load_interpolation": "linear"},
    "speed step 5 → 10 %": {"speed": [[0.0, 0.0], [0.1, 1.0], [0.6, 1.0], [0.6, 2.0], [1.2, 2.0]],
                            "load": [[0.0, 0.0]]},
    "reversal ±5 %": {"speed": [[0.0, 0.0], [0.1, 1.0], [0.5, 1.0], [0.7, -1.0], [1.2, -1.0]], "load": [[0.0, 0.0]]},
    "rated load step at 5 %": {"speed": [[0.0, 0.0], [0.1, 1.0], [1.2, 1.0]], "load": [[0.0, 0.0], [0.6, 1.0]]},
}
"""Speed in units of 5 % rated speed, load per rated torque; 1.2 s each, the rotor starting at 0.7 rad."""
DURATION_S = 1.2


def case_scenario(motor, case, commissioning, T_s=1e-4):
    """The scenario of one case on ``motor`` (a Motor) with its ``commissioning`` file."""
    spec = CASES[case]
    unit = SPEED_PER_RATED * motor.nameplate.rated_speed_rpm
    data = {"motor": motor.source, "estimator": "injection_frame", "duration_s": DURATION_S, "sampling_period_s": T_s,
            "commissioning": str(commissioning), "initial": {"theta_m_rad": 0.7}, "metrics": {"settle_s": 0.3},
            "speed": {"unit": "rpm", "interpolation": "linear", "points": [[t, v * unit] for t, v in spec["speed"]]},
            "load": {"unit": "rated", "interpolation": spec.get("load_interpolation", "step"),
                     "points": spec["load"]}}
    return parse_scenario(data, f"motor_bench_{motor.name}", "drive bench motor")


def verdict(metrics, faults, refused):
    """One phrase: what the drive did in a case."""
    if refused:
        return f"refused: {refused}"
    kinds = sorted({f["kind"] for f in faults})
    if metrics["lock_lost_s"]:
        return "lock lost" + (f"; {', '.join(kinds)}" if kinds else "")
    if kinds:
        return ", ".join(kinds)
    within = metrics["angle_error_rms"] <= RMS_TARGET_RAD and metrics["angle_error_peak"] <= PEAK_TARGET_RAD
    return "within targets" if within else "over target"


def motor_bench(motor_ref, angles=24, progress=None, T_s=1e-4):
    """The bench of one motor (shipped name or file) sampled every ``T_s``: its commissioning against the
    plant's truth, the start-up sweep and the cases; a report dictionary (SI units)."""
    motor = load_motor(motor_ref, "drive bench motor")
    with tempfile.TemporaryDirectory(prefix="motor_bench_") as folder:
        commissioning = Path(folder) / f"{motor.name}.yaml"
        first = case_scenario(motor, "speed step 5 → 10 %", "nameplate", T_s)
        run = commission_in_process(first)
        measured = run.procedure.result()
        save_commissioning(commissioning, measured, motor.name, "drive bench motor")
        steps = len(CASES) + 1
        try:
            loaded = loaded_test(first, measured, commissioning)
            sweep = startup_sweep(motor, STANDARD_CASES[0], angles=angles, seeds=(1,), commissioning=commissioning,
                                  progress=progress and (lambda f: progress(f / steps)), T_s=T_s)
        except ScenarioError as error:
            return refused_motor(motor, measured, run.truth, T_s, str(error).partition("estimator: ")[2] or str(error))
        cases = []
        for i, case in enumerate(CASES):
            result = run_scenario(case_scenario(motor, case, commissioning, T_s))
            metrics = compute_metrics(result)
            faults = supervision_faults(result)
            refused = (result.startup or {}).get("refused")
            cases.append({"case": case, "angle_error_rms": metrics["angle_error_rms"],
                          "angle_error_peak": metrics["angle_error_peak"],
                          "speed_tracking_error_rms": metrics["speed_tracking_error_rms"],
                          "polarity_correct": (metrics.get("startup") or {}).get("polarity_correct"),
                          "lock_lost_s": metrics["lock_lost_s"], "supervision": faults,
                          "verdict": verdict(metrics, faults, refused)})
            if progress:
                progress((i + 2) / steps)
    facts = result.estimator_facts
    rated = motor.nameplate.rated_current_A
    return {**_motor_facts(motor, measured, run.truth, T_s),
            "current_limit_A": result.current_limit_A, "warnings": configuration_warnings(result),
            "drive_notes": facts.get("injection_note", ""),
            "loaded_test": loaded if "refused" in loaded else {
                "significant": loaded["significant"], "zero_spread_rad": loaded["zero_spread_rad"],
                "correction_at_rated_rad": float(np.interp(rated, measured.saliency_shift_i_q_A,
                                                           loaded["estimator_shift_rad"]))},
            "tracking_bandwidth_Hz": facts.get("tracking_bandwidth_Hz"),
            "injection_frequency_Hz": facts.get("injection_frequency_Hz"),
            "injection_amplitude_V": facts.get("injection_amplitude_V"),
            "startup": {key: sweep[key] for key in ("runs", "polarity_correct_fraction", "angle_error_max_e_rad",
                                                    "duration_max_s", "lock_lost", "not_started")},
            "cases": cases}


def loaded_test(scenario, measured, commissioning):
    """The loaded test on the standstill record ``measured`` saved at ``commissioning``: its result, the file
    rewritten with ours' correction; {"refused": why} where the test did not hold its conditions."""
    try:
        loaded, _ = loaded_test_in_process(scenario, commissioning)
    except LoadedTestError as error:
        return {"refused": str(error)}
    save_commissioning(commissioning, with_loaded_test(measured, loaded), scenario.motor.name, "drive bench motor")
    return loaded


def _motor_facts(motor, measured, truth, T_s):
    return {"motor": motor.name, "file": motor.source, "description": motor.description, "sample_period_s": T_s,
            "commissioning_error": {key: float(getattr(measured, key) / truth[key] - 1.0)
                                    for key in ("R_s_ohm", "L_dh_H", "L_qh_H") if truth.get(key)}}


def refused_motor(motor, measured, truth, T_s, reason):
    """The report of a motor the commissioned drive refuses to run (``reason``: its one line): every case
    refused, nothing scored."""
    return {**_motor_facts(motor, measured, truth, T_s), "current_limit_A": None, "warnings": [], "drive_notes": "",
            "loaded_test": None,
            "tracking_bandwidth_Hz": None, "injection_frequency_Hz": None, "injection_amplitude_V": None,
            "startup": None, "refused": reason,
            "cases": [{"case": case, "angle_error_rms": None, "angle_error_peak": None,
                       "speed_tracking_error_rms": None, "polarity_correct": None, "lock_lost_s": None,
                       "supervision": [], "verdict": f"refused: {reason}"} for case in CASES]}
