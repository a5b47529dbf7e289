"""The speed loop's margins predicted and its ripple measured (docs/motors-and-control.md "The speed loop's margin"):
wang_spmsm with ours as test_robot's arm runs it (10 kHz, the scaled loops), in blocks of 1, 5 and 10, held at 0 and
3 rad/s for 6 s; per case the speed loop's ω_n, its predicted crossover and margins (foc_controller.speed_margin on
the estimator's own loop), the shaft speed's RMS about its mean over the last 3 s, the frequency it rings at and ours'
angle error RMS there. One JSON line per case.

    .venv/bin/python test/tools/speed_margin_table.py
"""
import dataclasses
import json
import math
import sys
import tempfile
from pathlib import Path

import numpy as np

from drive_common.config.scenario import load_scenario
from drive_common.contract.log import COLUMN
from drive_tools.runner.runner import build_drive, run_scenario
from foc_controller.build import speed_loop
from foc_controller.speed_margin import margins

ROOT = Path(__file__).resolve().parents[2]
DRIVE = ("format_version: 1\nmotor: wang_spmsm\ncommissioning: {commissioning}\nestimator: injection_frame\n"
         "sampling_period_s: 1.0e-4\nblock_samples: 1\n")
SCENARIO = ("drive: drive.yaml\nduration_s: 6.0\ninitial: {{theta_m_rad: 1.3}}\n"
            "speed: {{unit: rad_s, interpolation: step, points: [[0.0, 0.0], [2.0, {speed}]]}}\n"
            "load: {{unit: Nm, interpolation: step, points: [[0.0, 0.0]]}}\n")


def case(path, block_samples):
    scenario = dataclasses.replace(load_scenario(str(path)), block_samples=block_samples)
    drive = build_drive(scenario)
    c = drive.controller
    loop = speed_loop(scenario, drive.commissioning, c, drive.estimator.facts())
    predicted = margins(loop.plant, c.kp_speed, c.ki_speed)
    log = run_scenario(scenario).log
    t = log[:, COLUMN["t"]]
    last = t >= t[-1] - 3.0
    ripple = log[last, COLUMN["omega_m"]] - log[last, COLUMN["omega_m"]].mean()
    frequency = np.fft.rfftfreq(ripple.size, c.T_s_s)
    spectrum = np.abs(np.fft.rfft(ripple * np.hanning(ripple.size))) * ((frequency > 1.0) & (frequency < 100.0))
    error = np.angle(np.exp(1j * (c.n_p * log[last, COLUMN["theta_m"]] - log[last, COLUMN["theta_e_hat"]])))
    return {"blocks": block_samples, "omega_n_rad_s": round(loop.omega_n_rad_s, 1),
            "crossover_Hz": round(predicted.crossover_rad_s / (2.0 * math.pi), 2),
            "phase_margin_deg": round(predicted.phase_margin_deg, 1),
            "gain_margin_dB": round(predicted.gain_margin_db, 1),
            "ripple_rad_s": round(float(ripple.std()), 3), "ring_Hz": round(float(frequency[np.argmax(spectrum)]), 1),
            "angle_error_rms": round(float(np.sqrt(np.mean(error ** 2))), 4)}


def main():
    folder = Path(tempfile.mkdtemp(prefix="speed_margin_"))
    (folder / "drive.yaml").write_text(DRIVE.format(commissioning=ROOT / "commissioning" / "wang_spmsm.yaml"))
    for speed in (0.0, 3.0):
        path = folder / f"hold_{speed:g}.yaml"
        path.write_text(SCENARIO.format(speed=speed))
        for block_samples in (1, 5, 10):
            print(json.dumps({"speed_rad_s": speed, **case(path, block_samples)}), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
