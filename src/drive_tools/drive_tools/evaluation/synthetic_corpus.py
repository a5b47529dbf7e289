"""``drive bag synth DIR --count N --seed S``: a varied corpus of recordings with ground truth for estimator
authors who have no robot (issue 55 item 3; docs/recordings.md "A synthetic corpus"). Bag i of seed S is drawn
by its own generator: a motor of the random-motor distribution (drive_tools.evaluation.random_motors), its
sensor noise scaled, the estimator the recording drive ran, a sampling period, a speed profile at low speed,
a load, and what a robot's recorder does to the messages (drive_tools.bags.writer.RecorderFlaws). The drive
is commissioned at standstill in simulation as a robot builder would, then runs the case (forced past its own
refusals: a recording of a drive that fails is data too); the plant's truth is in each bag (`rotor_state`).
``corpus.json`` lists every bag with the figures it was drawn by."""
import dataclasses
import math
import tempfile
import time
from pathlib import Path
from typing import NamedTuple

import numpy as np

from drive_common.config.scenario import ScenarioError, parse_scenario
from drive_common.contract.errors import DriveError
from drive_common.contract.strict_json import dumps
from drive_common.motor.commissioning import save_commissioning
from drive_tools.bags.writer import RecorderFlaws, write_run_bag
from drive_tools.runner.commissioning_run import commission_in_process
from drive_tools.runner.runner import run_scenario
from hf_estimator.interface import injects

from .metrics import compute_metrics
from .random_motor_bench import each_in_processes
from .random_motors import draw_motor, write_motor_files

RECORDING_ESTIMATORS = (("injection_frame", 0.4), ("conventional", 0.15), ("improved", 0.15),
                        ("synchronous", 0.15), ("square_wave", 0.15))
"""The estimator the recording drive ran, with its probability."""
SAMPLE_PERIODS_S = ((1e-4, 0.6), (5e-5, 0.2), (2e-4, 0.2))
"""The recording drive's sampling period, with its probability."""
PROFILES = ("hold", "constant", "step", "reversal", "ramp")
"""The speed profile, uniform: zero speed; a constant speed; a step to twice it; a reversal through zero; a
ramp from zero."""
SPEED_PER_RATED = (0.01, 0.1)
"""The profile's speed: uniform in this share of the motor's rated speed."""
LOADED_SHARE = 0.5
LOAD_PER_RATED = (0.1, 1.0)
"""With probability LOADED_SHARE a load steps in at a uniform time of the run's second half, uniform in this
share of rated torque."""
NOISE_FACTOR = (0.5, 2.0)
"""The drawn motor's sensor noise scaled by a log-uniform factor in this range."""
FLAWED_SHARE = 0.5
LOST_SHARE = (1e-4, 5e-3)
JITTER_PER_PERIOD = (0.0, 0.05)
"""With probability FLAWED_SHARE the recorder is a robot's: a wall-clock epoch, stamps jittered by up to a
uniform share of the sampling period, a log-uniform share of each topic's messages lost."""
WALL_CLOCK_EPOCH_S = (1.7e9, 1.8e9)
ATTEMPTS = 5
"""A case the drive refuses to build (its sampling period, its injection on that motor) is drawn again, the
motor kept, at most this many times."""


class SyntheticCase(NamedTuple):
    """One bag's draw: the motor's name, the recording drive's estimator and sampling period [s], the speed
    profile and its speed [rpm], the load [share of rated torque] and when it steps in [share of the run] (NaN:
    none), the noise factor, the rotor's initial electrical angle [rad] and the recorder's flaws."""

    motor: str
    estimator: str
    T_s: float
    profile: str
    speed_rpm: float
    load_per_rated: float
    load_at_share: float
    noise_factor: float
    theta_e_rad: float
    flaws: RecorderFlaws


class SyntheticOptions(NamedTuple):
    """A corpus: how many bags of which seed, written into ``folder`` (pathlib.Path), each ``duration_s``
    long, by how many processes."""

    count: int
    seed: int
    folder: object
    duration_s: float = 1.0
    workers: int = 2


def _choice(rng, weighted):
    values, weights = zip(*weighted)
    return values[int(rng.choice(len(values), p=np.array(weights) / sum(weights)))]


def _log_uniform(rng, bounds):
    return float(math.exp(rng.uniform(math.log(bounds[0]), math.log(bounds[1]))))


def draw_case(seed, index, attempt, motor):
    """Bag ``index``'s case of seed ``seed`` at its ``attempt``-th draw on ``motor`` (a RandomMotor)."""
    rng = np.random.default_rng([seed, index, 1 + attempt])
    rated_rpm = motor.document["nameplate"]["rated_speed_rpm"]
    T_s = _choice(rng, SAMPLE_PERIODS_S)
    loaded = bool(rng.random() < LOADED_SHARE)
    flawed = bool(rng.random() < FLAWED_SHARE)
    flaws = RecorderFlaws(float(rng.uniform(*WALL_CLOCK_EPOCH_S)), float(rng.uniform(*JITTER_PER_PERIOD)) * T_s,
                          _log_uniform(rng, LOST_SHARE), int(rng.integers(2**31)), False) if flawed else \
        RecorderFlaws(scenario_named=False)
    profile = PROFILES[int(rng.integers(len(PROFILES)))]
    speed_rpm = float(rng.uniform(*SPEED_PER_RATED)) * rated_rpm
    return SyntheticCase(motor.name, _choice(rng, RECORDING_ESTIMATORS), T_s, profile,
                         0.0 if profile == "hold" else speed_rpm,
                         float(rng.uniform(*LOAD_PER_RATED)) if loaded else 0.0,
                         float(rng.uniform(0.5, 0.9)) if loaded else math.nan,
                         _log_uniform(rng, NOISE_FACTOR), float(rng.uniform(-math.pi, math.pi)), flaws)


def speed_points(case, duration_s):
    """The case's speed table [[t s, rpm], …] over ``duration_s``: the profile at its speed, from rest."""
    v, end = case.speed_rpm, duration_s
    return {"hold": [[0.0, 0.0], [end, 0.0]],
            "constant": [[0.0, 0.0], [0.1, v], [end, v]],
            "step": [[0.0, 0.0], [0.1, v], [0.5 * end, v], [0.5 * end, 2.0 * v], [end, 2.0 * v]],
            "reversal": [[0.0, 0.0], [0.1, v], [0.4 * end, v], [0.6 * end, -v], [end, -v]],
            "ramp": [[0.0, 0.0], [end, v]]}[case.profile]


def case_document(case, motor_path, n_p, seed, duration_s):
    """The scenario document (drive_common.config.scenario) of ``case`` on the motor file ``motor_path`` (its
    ``n_p`` pole pairs), on the nameplate alone."""
    load = [[0.0, 0.0]]
    if math.isfinite(case.load_at_share):
        load += [[case.load_at_share * duration_s, case.load_per_rated]]
    return {"description": f"synthetic recording: {case.profile} at {case.speed_rpm:.4g} rpm, load "
                           f"{case.load_per_rated:.2f} rated ({case.estimator})",
            "motor": str(motor_path), "estimator": case.estimator, "duration_s": duration_s,
            "sampling_period_s": case.T_s, "seed": seed, "commissioning": "nameplate",
            "initial": {"theta_m_rad": case.theta_e_rad / n_p},
            "speed": {"unit": "rpm", "interpolation": "linear", "points": speed_points(case, duration_s)},
            "load": {"unit": "rated", "interpolation": "step", "points": load}}


def recorded_motor(motor, factor):
    """``motor`` (a RandomMotor) as the recording drive knew it: its plant's sensor noise scaled by ``factor``,
    its rotor's J and B on the nameplate (drawn with the motor; a lab recording a bench knows its rig)."""
    plate = dict(motor.document["nameplate"])
    if "J_kgm2" not in plate:
        omega_m = plate["rated_speed_rpm"] * math.pi / 30.0
        plate["J_kgm2"] = float(f"{plate['rated_torque_Nm'] * motor.figures['acceleration_time_s'] / omega_m:.6g}")
        plate["B_Nms"] = float(f"{motor.document['plant']['B_Nms']:.6g}")
    document = {**motor.document, "nameplate": plate, "plant": {**motor.document["plant"]}}
    sensor = dict(document["plant"]["sensor"])
    sensor["noise_std_A"] = float(f"{sensor['noise_std_A'] * factor:.6g}")
    document["plant"]["sensor"] = sensor
    return motor._replace(document=document)


def synthetic_bag(job):
    """Draw, commission, run and record bag ``index`` of ``seed`` (``job``: seed, index, folder, duration);
    its corpus row: the bag's name, the motor's class figures, the case, the recording drive's outcome, or
    ``written: False`` and why."""
    seed, index, folder, duration_s = job
    motor = draw_motor(seed, index)
    row = {"bag": f"bag_{index:04d}", "index": index, "motor": motor.name, "figures": motor.figures,
           "written": False, "reason": "", "attempts": []}
    with tempfile.TemporaryDirectory(prefix="synth_") as scratch:
        for attempt in range(ATTEMPTS):
            case = draw_case(seed, index, attempt, motor)
            drawn = recorded_motor(motor, case.noise_factor)
            motor_path = write_motor_files([drawn], Path(scratch) / f"attempt_{attempt}")[0]
            try:
                result, commissioned = _recorded_run(case, motor_path, motor.figures["n_p"], seed * 100_000 + index,
                                                     duration_s, scratch)
            except (ScenarioError, DriveError) as error:
                row["attempts"].append(f"{case.estimator} at {case.T_s:g} s: "
                                      f"{str(error).splitlines()[0].rsplit(': ', 1)[-1]}")
                continue
            bag = Path(folder) / row["bag"]
            write_run_bag(result, bag, flaws=case.flaws)
            metrics = compute_metrics(result)
            row.update(written=True, case=_case_row(case, duration_s), commissioned=commissioned,
                       samples=result.log.shape[0], recording_rms_rad=metrics.get("angle_error_rms"),
                       recording_peak_rad=metrics.get("angle_error_peak"))
            return row
    row["reason"] = f"no case of {ATTEMPTS} draws could run on this motor"
    return row


def _recorded_run(case, motor_path, n_p, seed, duration_s, scratch):
    """(the RunResult of ``case``, whether standstill commissioning took): commissioned at standstill first;
    the nameplate alone where commissioning refuses the motor or the drive refuses what it measured."""
    commissioning = Path(scratch) / "commissioning.yaml"
    scenario = parse_scenario(case_document(case, motor_path, n_p, seed, duration_s), "synthetic",
                              f"synthetic recording on {motor_path}")
    if injects(scenario.estimator):
        scenario = dataclasses.replace(scenario, estimator_settings={**scenario.estimator_settings,
                                                                     "run_refused": True})
    try:
        measured = commission_in_process(scenario).procedure.result()
        save_commissioning(commissioning, measured, case.motor, "drive bag synth")
        return run_scenario(dataclasses.replace(scenario, commissioning=str(commissioning))), True
    except DriveError:
        return run_scenario(scenario), False


def _case_row(case, duration_s):
    """The corpus row of ``case``: its fields, the load's step also in seconds (None: no load step)."""
    row = case._asdict()
    row["flaws"] = case.flaws._asdict()
    stepped = math.isfinite(case.load_at_share)
    row["load_at_share"] = case.load_at_share if stepped else None
    row["load_at_s"] = case.load_at_share * duration_s if stepped else None
    return row


def synthetic_corpus(options, progress=None):
    """Write the corpus of ``options`` (SyntheticOptions) into its folder; ``progress(line)`` hears of each
    bag. The report (also written as corpus.json): the draw's facts, one row per bag, counts, ``interrupted``
    (the signal that stopped it, 0: none)."""
    folder = Path(options.folder)
    folder.mkdir(parents=True, exist_ok=True)
    jobs = [(options.seed, i, str(folder), options.duration_s) for i in range(options.count)]
    rows, start = [None] * len(jobs), time.perf_counter()

    def finished(index, row):
        rows[index] = row
        if progress:
            done = sum(r is not None for r in rows)
            elapsed = time.perf_counter() - start
            progress(f"[{done}/{len(rows)}] {row['bag']} ({row['motor']}): "
                     f"{'written' if row['written'] else row['reason']} ({elapsed:.0f} s, about "
                     f"{elapsed / done * (len(rows) - done):.0f} s left)")
    interrupted = each_in_processes(synthetic_bag, jobs, options.workers, finished)
    done = [r for r in rows if r is not None]
    report = {"corpus": str(folder), "count": options.count, "seed": options.seed, "duration_s": options.duration_s,
              "written": sum(r["written"] for r in done), "not_written": sum(not r["written"] for r in done),
              "wall_time_s": time.perf_counter() - start, "interrupted": interrupted, "bags": done}
    (folder / "corpus.json").write_text(dumps(report, indent=1))
    return report


def corpus_lines(report):
    """The text of a corpus report."""
    lines = [f"{report['corpus']}: {report['written']} bags written of {report['count']} drawn (seed {report['seed']}, "
             f"{report['duration_s']:g} s each) in {report['wall_time_s']:.0f} s"]
    for row in report["bags"]:
        if row["written"]:
            case = row["case"]
            rms = row["recording_rms_rad"]
            lines.append(f"  {row['bag']}  {row['motor']}  n_p {row['figures']['n_p']:>2}  "
                         f"L_qh/L_dh {row['figures']['L_qh_per_L_dh']:.2f}  {case['estimator']:<16} "
                         f"{case['profile']:<8} {case['speed_rpm']:8.3g} rpm  load {case['load_per_rated']:.2f}  "
                         f"recording drive {'n/a' if rms is None else f'{rms:.3f}'} rad RMS")
        else:
            lines.append(f"  {row['bag']}  {row['motor']}  not written: {row['reason']}")
    if report["interrupted"]:
        lines.append(f"interrupted by signal {report['interrupted']}: the bags above are complete")
    return lines

