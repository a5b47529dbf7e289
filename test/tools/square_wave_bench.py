"""The square wave against ours' sine carrier on the same motors and cases (docs/results.md, "Square-wave
injection against the sine carrier"): per motor file, commissioned from its nameplate as `drive bench motor`
does (the loaded test included), then ``drive bench motor``'s four cases per estimator and noise seed: angle
error RMS / peak, the verdict, the HF current (sampled, and for the square wave the triangle between samples)
and its copper loss; and the tracking loop's closed-loop bandwidth, measured by the stepped sine of
`drive tune pll --check` (shaft driven, speed loop held). One JSON document on stdout.

``python test/tools/square_wave_bench.py [--sample-period S] [--seeds 1,2] [--no-bandwidth] [--scenarios A,B] FILE ...``
(``--scenarios``: shipped scenarios run by both estimators as they ship, the same measures).
"""
import argparse
import dataclasses
import json
import math
import sys
import tempfile
from pathlib import Path

import numpy as np

from drive_common.config.scenario import load_scenario, parse_scenario
from drive_common.motor.commissioning import resolve_commissioning, save_commissioning
from drive_common.motor.motor_file import load_motor
from drive_tools.evaluation.metrics import compute_metrics, supervision_faults
from drive_tools.evaluation.motor_bench import CASES, case_scenario, loaded_test, verdict
from drive_tools.evaluation.pll_check import SPEED_LOOPS, closed_loop_figures, measure_tracking_response
from drive_tools.evaluation.speed_range import hf_current
from drive_tools.runner.commissioning_run import commission_in_process
from drive_tools.runner.runner import run_scenario
from hf_estimator.square_wave import square_wave_serves

ESTIMATORS = ("injection_frame", "square_wave")
BANDWIDTH_OMEGAS_RAD_S = np.logspace(math.log10(30.0), math.log10(8000.0), 20)


def case_row(scenario, estimator, seed):
    """One case run by ``estimator`` at noise ``seed``: scores, verdict, HF current."""
    s = dataclasses.replace(scenario, estimator=estimator, estimator_settings={}, seed=seed)
    result = run_scenario(s)
    metrics = compute_metrics(result)
    faults = supervision_faults(result)
    facts = result.estimator_facts
    samples = max(1, int(round(1.0 / (facts["injection_frequency_Hz"] * s.T_s))))
    t = result.log[:, 0]
    hf = hf_current(result.log, result.n_p, samples)[t >= s.metrics_start_s]
    sampled_rms = float(np.sqrt(np.mean(hf ** 2)))
    # The square wave's current is a triangle between its samples (they sit on its corners): RMS = peak/√3.
    true_rms = sampled_rms / math.sqrt(3.0) if estimator == "square_wave" and samples == 2 else sampled_rms
    R_s = s.motor.nameplate.R_s_ohm
    return {"estimator": estimator, "seed": seed, "rms": metrics["angle_error_rms"],
            "peak": metrics["angle_error_peak"],
            "verdict": verdict(metrics, faults, (result.startup or {}).get("refused")),
            "amplitude_V": facts.get("injection_amplitude_V"), "frequency_Hz": facts["injection_frequency_Hz"],
            "tracking_Hz": facts["tracking_bandwidth_Hz"], "hf_sampled_rms_A": sampled_rms, "hf_rms_A": true_rms,
            "hf_copper_loss_W": 1.5 * R_s * true_rms ** 2, "note": facts.get("injection_note", "")}


def measured_bandwidth(motor, commissioning, estimator, T_s):
    """−3 dB bandwidth [rad/s] and peak [dB] of θ̂/θ (stepped sine, shaft driven, speed loop held)."""
    data = {"motor": motor.source, "estimator": estimator, "commissioning": str(commissioning), "duration_s": 1.0,
            "sampling_period_s": T_s, "mode": "imposed_speed", "speed": {"unit": "rad_s", "points": [[0.0, 0.0]]},
            "controller": SPEED_LOOPS["off"]}
    scenario = parse_scenario(data, f"square_wave_bench_{motor.name}", "square_wave_bench")
    omegas = BANDWIDTH_OMEGAS_RAD_S[BANDWIDTH_OMEGAS_RAD_S < 0.2 * math.pi / T_s]
    response = measure_tracking_response(scenario, omegas)
    return closed_loop_figures(response.omega_rad_s, response.T)


def motor_rows(motor_ref, T_s, seeds, bandwidth):
    motor = load_motor(motor_ref, "square_wave_bench")
    with tempfile.TemporaryDirectory(prefix="square_wave_bench_") as folder:
        commissioning = Path(folder) / f"{motor.name}.yaml"
        first = case_scenario(motor, "speed step 5 → 10 %", "nameplate", T_s)
        measured = commission_in_process(first).procedure.result()
        save_commissioning(commissioning, measured, motor.name, "square_wave_bench")
        loaded_test(first, measured, commissioning)
        record = resolve_commissioning(motor.nameplate, str(commissioning))
        choice = square_wave_serves(motor.nameplate, record, motor.inverter, T_s)
        rows = []
        for case in CASES:
            scenario = case_scenario(motor, case, commissioning, T_s)
            for estimator in ESTIMATORS:
                for seed in seeds:
                    rows.append({"case": case, **case_row(scenario, estimator, seed)})
                    print(f"{motor.name} {case} {rows[-1]['estimator']} seed {seed}: {rows[-1]['rms']:.4f} / "
                          f"{rows[-1]['peak']:.3f} {rows[-1]['verdict']}", file=sys.stderr)
        bandwidths = {e: measured_bandwidth(motor, commissioning, e, T_s) for e in ESTIMATORS} if bandwidth else {}
    return {"motor": motor.name, "T_s": T_s, "rule": choice._asdict(), "bandwidth": bandwidths, "cases": rows}


def scenario_rows(names, seeds):
    """The shipped scenarios ``names`` run by each estimator at each noise seed."""
    rows = []
    for name in names:
        for estimator in ESTIMATORS:
            for seed in seeds:
                rows.append({"scenario": name, **case_row(load_scenario(name), estimator, seed)})
                row = rows[-1]
                print(f"{name} {estimator} seed {seed}: {row['rms']:.4f} / {row['peak']:.3f}", file=sys.stderr)
    return rows


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("motors", nargs="*")
    parser.add_argument("--scenarios", default="", help="comma-separated shipped scenarios")
    parser.add_argument("--sample-period", type=float, default=1e-4)
    parser.add_argument("--seeds", default="1")
    parser.add_argument("--no-bandwidth", action="store_true")
    args = parser.parse_args()
    seeds = [int(s) for s in args.seeds.split(",")]
    report = [motor_rows(m, args.sample_period, seeds, not args.no_bandwidth) for m in args.motors]
    if args.scenarios:
        report.append({"scenarios": scenario_rows(args.scenarios.split(","), seeds)})
    json.dump(report, sys.stdout, indent=1, default=float)


if __name__ == "__main__":
    main()
