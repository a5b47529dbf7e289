"""`drive bench robot`: how many axes `drive up` runs together in real time on this machine (docs/robot.md,
"Axes together"). Each run is `drive up` in a process of its own on a robot file of N axes, each a virtual inverter
paced at the drive's rate over a pty (wang_spmsm, its commissioning file, held at zero speed), armed from the start;
the simulated machines end after the run's duration, which ends the run (a lost link: exit 3, expected). Per axis:
the share of its periods, from its drive's first command in time on, that had no command in time; the process's CPU
time per period and axis while the axes ran. No rclpy in this process."""
import json
import subprocess
import tempfile
from pathlib import Path

from drive_common.contract.errors import DriveError
from drive_common.contract.exit_codes import EXIT_NODE_FAULTS

from .bench import REPOSITORY

COMMISSIONING = REPOSITORY / "commissioning" / "wang_spmsm.yaml"
LATE_BOUND = 0.001
"""An axis keeps pace when at most this share of its periods had no command in time (issue 54's bound)."""


def robot_files(folder, axes, block_samples, duration_s, answer="compiled", apart=False):
    """The drive configuration, the simulated machine and the robot file of ``axes`` paced virtual axes in
    ``folder``, each answered as ``answer`` says (compiled, nodes), its inverter in a process of its own where
    ``apart``; the robot file's path."""
    folder = Path(folder)
    (folder / "drive.yaml").write_text(
        f"format_version: 1\nmotor: wang_spmsm\ncommissioning: {COMMISSIONING}\nestimator: injection_frame\n"
        f"sampling_period_s: 1.0e-4\nblock_samples: {block_samples}\n")
    (folder / "machine.yaml").write_text(
        f"drive: drive.yaml\nduration_s: {duration_s}\ninitial: {{theta_m_rad: 1.3}}\n"
        "speed: {unit: rad_s, interpolation: step, points: [[0.0, 0.0]]}\n")
    lines = ["format_version: 1", "initial_state: active", "axes:"]
    lines += [f"  - {{joint: axis{i}, drive: drive.yaml, link: virtual, scenario: machine.yaml, paced: true, "
              f"answer: {answer}, inverter_apart: {str(apart).lower()}}}" for i in range(axes)]
    path = folder / "robot.yaml"
    path.write_text("\n".join(lines) + "\n")
    return path


def robot_run(axes, block_samples, duration_s, drive_command, answer="compiled", apart=False):
    """One `drive up` of ``axes`` paced axes (``drive_command``: the `drive` executable) answered as ``answer`` says;
    its row: per axis its late share and answer percentiles, the worst share, whether every axis kept pace, CPU µs
    per period and axis."""
    with tempfile.TemporaryDirectory(prefix="robot_bench_") as folder:
        path = robot_files(folder, axes, block_samples, duration_s, answer, apart)
        run = subprocess.run([drive_command, "up", str(path), "--json"], cwd=folder, capture_output=True, text=True,
                             timeout=120 + 60 * duration_s * axes)
    try:
        report = json.loads(run.stdout)
    except json.JSONDecodeError:
        raise DriveError(f"drive up exited {run.returncode} without its report: "
                         f"{(run.stderr.strip().splitlines() or ['nothing on stderr'])[-1]}") from None
    timings = [axis.get("inverter_timing") or {} for axis in report["axes"]]
    shares = [t.get("late_fraction_since_start") for t in timings]
    periods = sum(t.get("periods_since_start", 0) for t in timings)
    running = report.get("running") or {}
    kept = all(share is not None and share <= LATE_BOUND for share in shares)
    return {"axes": axes, "block_samples": block_samples, "answer": answer, "inverter_apart": apart,
            "exit_code": report["exit_code"],
            "ended_as_expected": report["exit_code"] == EXIT_NODE_FAULTS and "link is lost" in report["reason"],
            "reason": report["reason"].replace(f"{folder}/", ""),
            "late_fractions": shares, "worst_late_fraction": max((s for s in shares if s is not None), default=None),
            "every_axis_kept_pace": kept,
            "answer_p99_us": [t.get("answer_p99_us") for t in timings],
            "watchdog_trips": sum(t.get("watchdog_trips", 0) for t in timings),
            "cpu_us_per_period_and_axis": 1e6 * running["cpu_s"] / periods if periods and running else None,
            "running_wall_s": running.get("wall_s"), "scheduling": report.get("scheduling")}


def robot_bench(axes_counts, block_sizes, duration_s, repeats, drive_command, progress=None, answers=("compiled",),
                apart=False):
    """Rows of robot_run for every answer, axis count and block size, ``repeats`` runs each, in that order (the
    inverters apart where ``apart``)."""
    rows = []
    for answer in answers:
        for axes in axes_counts:
            for block_samples in block_sizes:
                runs = []
                for repeat in range(repeats):
                    if progress:
                        progress(f"{answer}, {axes} axes, blocks of {block_samples}: run {repeat + 1} of {repeats}")
                    runs.append(robot_run(axes, block_samples, duration_s, drive_command, answer, apart))
                rows.append({"answer": answer, "axes": axes, "block_samples": block_samples, "runs": runs,
                             "runs_every_axis_kept_pace": sum(r["every_axis_kept_pace"] for r in runs)})
    return rows
