"""``drive bench startup``: the start-up from rotor angles over the whole electrical circle, noise seeds,
with and without load (docs/startup.md). Each run is a short scenario: the rotor at rest at angle θ_e,
the estimator told nothing, the speed reference zero for the start-up's budget (``HOLD_S``: a released
brake's load meets a drive told to hold still) and then ramping to ``SPEED_PER_RATED`` of rated speed;
the load opposes that direction (the case where rolling back shows)."""
import math
import tempfile
from pathlib import Path
from typing import NamedTuple

import numpy as np
import yaml

from drive_common.config.scenario import load_scenario, parse_scenario
from drive_common.motor.motor_file import load_motor
from drive_tools.evaluation.metrics import startup_metrics
from drive_tools.runner.runner import run_scenario

MOTOR_SCENARIOS = {"wang_spmsm": "wang_100rpm", "szabo_ipmsm": "szabo_profile"}
"""The shipped scenario whose injection and controller a shipped motor's bench runs use (any other motor
runs with the drive's own, scaled to it: docs/motors-and-control.md "Loops scaled to the motor")."""
SPEED_PER_RATED = 0.03
HOLD_S = 0.05
RAMP_S = 0.1
DURATION_S = 0.25


class LoadCase(NamedTuple):
    name: str
    load_per_rated: float
    brake: bool
    feedforward: bool = False
    """The robot tells the drive the load's torque (`torque_feedforward`, its gravity model)."""
    forced: bool = False
    """The drive runs as `drive run --force` would (the estimator's setting ``run_refused``)."""


STANDARD_CASES = (LoadCase("no load", 0.0, False), LoadCase("0.5 rated, brake", 0.5, True),
                  LoadCase("0.5 rated, brake, ff", 0.5, True, True), LoadCase("0.3 rated, active", 0.3, False))
"""The issue's cases: no load; half rated load held by a brake released at first torque, the drive told
nothing of it or told its torque by the robot; a gravity-like 0.3 rated load from t = 0 that moves the
rotor during start-up."""


def bench_scenario(motor, estimator, theta_e_rad, seed, case, settings=None, commissioning="", T_s=None):
    """The scenario of one bench run on ``motor`` (a shipped name, a motor file or a Motor), with the
    ``commissioning`` file given (default: the scenario's lookup), sampled every ``T_s`` (default: the
    shipped scenario's, else 10 kHz)."""
    m = load_motor(motor, "--motor")
    shipped = load_scenario(MOTOR_SCENARIOS[m.name]) if m.shipped else None
    plate = m.nameplate
    speed = SPEED_PER_RATED * plate.rated_speed_rpm
    settings = {**(settings or {}), **({"run_refused": True} if case.forced else {})}
    data = {"motor": m.source, "estimator": {"type": estimator or "injection_frame", "settings": settings},
            "injection": dict(shipped.injection) if shipped else {}, "duration_s": DURATION_S,
            "sampling_period_s": T_s or (shipped.T_s if shipped else 1e-4),
            "speed": {"unit": "rpm", "interpolation": "linear",
                      "points": [[0.0, 0.0], [HOLD_S, 0.0], [HOLD_S + RAMP_S, speed]]},
            "load": {"unit": "rated", "points": [[0.0, case.load_per_rated]]}, "seed": seed,
            "initial": {"theta_m_rad": theta_e_rad / plate.n_p}, "brake": case.brake,
            "metrics": {"settle_s": 0.05}, "controller": dict(shipped.controller) if shipped else {},
            **({"commissioning": str(commissioning)} if commissioning else {})}
    if case.feedforward:
        data["torque_feedforward"] = {"unit": "rated", "points": [[0.0, case.load_per_rated]]}
    return parse_scenario(data, f"startup_{m.name}", "drive bench startup")


def startup_sweep(motor, case, angles=72, seeds=(1, 2, 3), estimator=None, progress=None, commissioning="",
                  T_s=None):
    """One row per (angle, seed): the start-up metrics (metrics.startup_metrics) of a bench run, and
    the summary of them all."""
    rows = []
    total = angles * len(seeds)
    for i in range(angles):
        theta_e = 2.0 * math.pi * i / angles - math.pi
        for seed in seeds:
            scenario = bench_scenario(motor, estimator, theta_e, seed, case, commissioning=commissioning, T_s=T_s)
            result = run_scenario(scenario)
            rows.append({"theta_e_rad": theta_e, "seed": seed, **startup_metrics(scenario, result.log, result.n_p),
                         "refused": (result.startup or {}).get("refused")})
            if progress:
                progress(len(rows) / total)
    return {"motor": load_motor(motor, "--motor").name, "case": case.name, "load_per_rated": case.load_per_rated,
            "brake": case.brake,
            "estimator": estimator or "injection_frame", "runs": len(rows), **summary(rows), "rows": rows}


def summary(rows):
    """Polarity correct fraction, worst |angle error| at first torque, worst rotation against the
    commanded direction [deg mechanical], slowest start-up, lock losses, runs that never started."""
    started = [r for r in rows if r["completed"]]

    def worst(key, scale=1.0):
        values = [abs(r[key]) * scale for r in started if r[key] is not None]
        return float(max(values)) if values else None
    correct = [r["polarity_correct"] for r in started if r["polarity_correct"] is not None]
    return {"polarity_correct_fraction": float(np.mean(correct)) if len(started) == len(rows) and correct
            else (float(np.sum(correct)) / len(rows) if rows else None),
            "angle_error_max_e_rad": worst("angle_error_e_rad"),
            "reverse_rotation_max_m_deg": worst("reverse_rotation_m_rad", 180.0 / math.pi),
            "duration_max_s": worst("duration_s"),
            "lock_lost": int(sum(r["lock_lost"] for r in rows)),
            "not_started": len(rows) - len(started)}


DRAWN_RANGES = {"n_p": (8, 30), "U_dc_V": (24.0, 72.0), "rated_current_A": (3.0, 20.0),
                "rated_speed_rpm": (300.0, 2000.0),
                "back_emf_per_bus": (0.3, 0.6), "inductive_per_bus": (0.1, 0.3), "L_q_per_L_d": (1.0, 1.3),
                "L_dh_per_L_d": (0.82, 0.95), "L_qh_per_L_q": (0.95, 1.0), "L_dh_drop_at_rated": (0.03, 0.12),
                "L_qh_drop_at_rated": (0.0, 0.1), "time_constant_s": (3e-4, 3e-3),
                "acceleration_rad_s2": (5e3, 5e4), "noise_per_adc_range": (5e-4, 2e-3), "t_dead_s": (2e-7, 5e-7),
                "plant_off_nameplate": (-0.05, 0.05)}
"""The many-pole, low-inertia motors ``drive bench startup --drawn`` draws (docs/startup.md): pole pairs
uniform, the rest log-uniform where a ratio (bus, current, speed, L/R, the rated torque's acceleration of the
bare rotor τ_rated/J, noise), else uniform. Back-EMF at rated speed and the inductive voltage at rated current
and speed are these shares of U_dc/√3 (a bus that drives rated speed); saliency from saturation (L_dh below L_d)
and shape (L_q above L_d); the plant's R_s, ψ_f, J up to ±5 % off the nameplate."""


def drawn_motor(rng, index):
    """One many-pole, low-inertia motor file (a dict) drawn from DRAWN_RANGES with ``rng``
    (numpy Generator)."""
    r = DRAWN_RANGES

    def uniform(key):
        return float(rng.uniform(*r[key]))

    def log_uniform(key):
        low, high = r[key]
        return float(math.exp(rng.uniform(math.log(low), math.log(high))))
    n_p = int(rng.integers(r["n_p"][0], r["n_p"][1] + 1))
    U_dc, I_r, speed = log_uniform("U_dc_V"), log_uniform("rated_current_A"), log_uniform("rated_speed_rpm")
    omega_e = n_p * speed * 2.0 * math.pi / 60.0
    psi_f = uniform("back_emf_per_bus") * U_dc / math.sqrt(3.0) / omega_e
    L_d = uniform("inductive_per_bus") * U_dc / math.sqrt(3.0) / (omega_e * I_r)
    L_q = L_d * uniform("L_q_per_L_d")
    R_s = L_d / log_uniform("time_constant_s")
    J = 1.5 * n_p * psi_f * I_r / log_uniform("acceleration_rad_s2")
    adc_range = 4.0 * I_r

    def off(value):
        return value * (1.0 + uniform("plant_off_nameplate"))
    return {"format_version": 1, "name": f"drawn_{index:02d}",
            "description": f"drawn many-pole low-inertia motor {index}, {n_p} pole pairs",
            "nameplate": {"n_p": n_p, "R_s_ohm": R_s, "L_d_H": L_d, "L_q_H": L_q, "psi_f_Wb": psi_f,
                          "rated_current_A": I_r, "rated_speed_rpm": speed, "current_limit_A": 1.5 * I_r,
                          "J_kgm2": J, "B_Nms": 1e-3 * J * 100.0},
            "inverter": {"U_dc_V": U_dc},
            "plant": {"R_s_ohm": off(R_s), "psi_f_Wb": off(psi_f), "J_kgm2": off(J),
                      "L_dh_H": L_d * uniform("L_dh_per_L_d"), "L_dh_drop_at_rated": uniform("L_dh_drop_at_rated"),
                      "L_q_H": L_q, "L_qh_H": L_q * uniform("L_qh_per_L_q"),
                      "L_qh_drop_at_rated": uniform("L_qh_drop_at_rated"), "t_dead_s": uniform("t_dead_s"),
                      "sensor": {"noise_std_A": log_uniform("noise_per_adc_range") * adc_range, "adc_bits": 12,
                                 "adc_range_A": adc_range}}}


def drawn_motors(count, seed, folder):
    """``count`` motor files drawn with ``seed`` (drawn_motor), written into ``folder``; their paths."""
    rng = np.random.default_rng(seed)
    paths = []
    for index in range(count):
        path = Path(folder) / f"drawn_{index:02d}.yaml"
        path.write_text(yaml.safe_dump(drawn_motor(rng, index), sort_keys=False))
        paths.append(path)
    return paths


def drawn_startup_bench(count, seed, angles, seeds, progress=None):
    """The start-up of ``count`` drawn motors (drawn_motors): each commissioned at standstill from its
    nameplate (in simulation), then started without load from ``angles`` angles × ``seeds`` noise seeds; one
    report per motor (startup_sweep's, with the motor's figures; ``refused``: the drive's one line where it
    refuses the motor before running). A motor refused for ours' predicted angle error, not its polarity, is
    started as `drive run --force` would (``signal_refused`` says so): its polarity is still measured."""
    from drive_common.config.scenario import ScenarioError
    from drive_common.motor.commissioning import save_commissioning
    from drive_tools.runner.commissioning_run import commission_in_process
    from drive_tools.runner.runner import build_drive

    reports = []
    with tempfile.TemporaryDirectory(prefix="startup_drawn_") as folder:
        for j, path in enumerate(drawn_motors(count, seed, folder)):
            motor = load_motor(str(path), "drive bench startup --drawn")
            commissioning = Path(folder) / f"{motor.name}_commissioning.yaml"
            first = bench_scenario(motor, None, 0.0, 1, STANDARD_CASES[0], commissioning="nameplate")
            measured = commission_in_process(first).procedure.result()
            save_commissioning(commissioning, measured, motor.name, "drive bench startup --drawn")
            figures = {"n_p": motor.nameplate.n_p, "J_kgm2": motor.nameplate.J_kgm2,
                       "saliency_ratio": abs(measured.delta / measured.sigma),
                       "saturation_asymmetry": measured.saturation_asymmetry, "motor_file": drawn_motor_text(path)}
            signal_refused = None
            try:
                build_drive(bench_scenario(motor, None, 0.0, 1, STANDARD_CASES[0], commissioning=commissioning))
            except ScenarioError as error:
                if "polarity" in str(error):
                    reports.append({"motor": motor.name, "case": STANDARD_CASES[0].name, **figures, "runs": 0,
                                    "refused": str(error), "signal_refused": None, **summary([])})
                    continue
                signal_refused = str(error)
            case = STANDARD_CASES[0]._replace(forced=bool(signal_refused))
            sweep = startup_sweep(motor, case, angles, seeds, commissioning=commissioning,
                                  progress=progress and (lambda f, j=j: progress((j + f) / count)))
            reports.append({**sweep, **figures, "refused": None, "signal_refused": signal_refused})
    return reports


def drawn_motor_text(path):
    """A drawn motor file's nameplate and plant as one mapping (what reproduces it)."""
    data = yaml.safe_load(Path(path).read_text())
    return {key: data[key] for key in ("nameplate", "inverter", "plant")}


def drawn_lines(reports):
    """drawn_startup_bench's reports as a table: per motor its figures, the starts that reached torque and
    those with the right pole, the starts refused before torque, the largest rotation against the command
    [° mechanical], or the drive's refusal of the motor; then the totals."""
    lines = [f"{'motor':9s} {'n_p':>3s} {'J kg·m²':>8s} {'|Δ|/Σ':>6s} {'asym':>6s} {'runs':>5s} {'torque':>6s} "
             f"{'right':>6s} {'refused':>7s} {'back max':>9s}  note"]
    totals = np.zeros(4, dtype=int)
    for r in reports:
        rows = r.get("rows", [])
        counts = (len(rows), sum(row["completed"] for row in rows), sum(bool(row["polarity_correct"]) for row in rows),
                  sum(not row["completed"] for row in rows))
        totals += counts
        back = r["reverse_rotation_max_m_deg"]
        note = r["refused"] or ("the angle signal refused, run as --force" if r["signal_refused"] else "")
        lines.append(f"{r['motor']:9s} {r['n_p']:3d} {r['J_kgm2']:8.1e} {r['saliency_ratio']:6.3f} "
                     f"{r['saturation_asymmetry']:6.3f} {counts[0]:5d} {counts[1]:6d} {counts[2]:6d} {counts[3]:7d} "
                     f"{'' if back is None else f'{back:.2f}°':>9s}  {note}")
    lines.append(f"{len(reports)} motors: {totals[0]} starts, {totals[1]} reached torque, {totals[2]} with the right "
                 f"pole, {totals[3]} refused before torque")
    return lines


