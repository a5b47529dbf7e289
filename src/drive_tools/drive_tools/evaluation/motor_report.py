"""Reports of motors (drive presets, motor show, commission): what the drive is told of a motor beside the
simulated plant's truth, the loops scaled to it, and what commissioning identified; each as text lines."""
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from drive_common.math.tables import table_value

from .report_text import cell


def side_by_side(preset):
    """What the drive is told (the nameplate) beside the simulated plant's truth, under the same keys."""
    from pmsm_plant.model import incremental_inductances

    plate, m, mech, inv, sens = preset.nameplate, preset.machine, preset.mechanics, preset.inverter, preset.sensor
    L_dh, L_qh, _ = incremental_inductances(m)
    told = {"n_p": plate.n_p, "R_s_ohm": plate.R_s_ohm, "L_d_H": plate.L_d_H, "L_q_H": plate.L_q_H,
            "L_dh_H": plate.L_d_H, "L_qh_H": plate.L_q_H, "psi_f_Wb": plate.psi_f_Wb, "J_kgm2": plate.J_kgm2,
            "B_Nms": plate.B_Nms, "U_dc_V": inv.U_dc_V}
    truth = {"n_p": m.n_p, "R_s_ohm": m.R_s_ohm, "L_d_H": m.L_d_H, "L_q_H": m.L_q_H, "L_dh_H": L_dh, "L_qh_H": L_qh,
             "psi_f_Wb": m.psi_f_Wb, "J_kgm2": mech.J_kgm2, "B_Nms": mech.B_Nms, "U_dc_V": inv.U_dc_V,
             "t_dead_s": inv.t_dead_s, "sensor_gains": [sens.gain_a, sens.gain_b, sens.gain_c],
             "sensor_offsets_A": [sens.offset_a_A, sens.offset_b_A, sens.offset_c_A],
             "sensor_noise_A": sens.noise_std_A}
    return told, truth


def presets_report():
    """Every simulated motor preset: its source, assumptions, nameplate, the plant's parts, told and truth."""
    from pmsm_plant.presets import PRESETS

    entries = []
    for p in PRESETS.values():
        told, truth = side_by_side(p)
        entries.append({"name": p.name, "source": p.source, "assumptions": list(p.assumptions),
                        "nameplate": p.nameplate._asdict(), "told": told, "truth": truth,
                        "machine": p.machine._asdict(), "mechanics": p.mechanics._asdict(),
                        "inverter": p.inverter._asdict(), "sensor": p.sensor._asdict()})
    return entries


def presets_lines(entries):
    lines = []
    for e in entries:
        lines.append(f"{e['name']}: {e['source']}")
        lines.append(f"  {'':14s} {'nameplate (the drive)':>22s} {'plant (truth)':>16s}")
        for key, value in e["truth"].items():
            lines.append(f"  {key:14s} {cell(e['told'].get(key, '—')):>22s} {cell(value):>16s}")
        lines += [f"  - {a}" for a in e["assumptions"]]
    return lines


MOTOR_LOOP_ROWS = (("rated-torque acceleration", "acceleration_e_rad_s2", "rad/s² el."),
                   ("tracking bandwidth (ours)", "tracking_bandwidth_Hz", "Hz"),
                   ("injection frequency (ours)", "injection_frequency_Hz", "Hz"),
                   ("injection amplitude (ours)", "injection_amplitude_V", "V"),
                   ("amplitude cap (bus)", "amplitude_cap_V", "V"),
                   ("speed loop bandwidth", "speed_bandwidth_rad_s", "rad/s"))


def motor_report(motor, T_s, scenario=None):
    """A motor (drive_common.motor.motor_file.Motor): its nameplate, inverter and the loops scaled to it at the
    sampling period T_s [s] (drive_common.motor.scaled_loops); with a ``scenario`` (its motor this one), what
    `drive run` of it uses instead (drive_loops)."""
    from drive_common.config.motor_experiments import ExperimentOptions
    from drive_common.config.scenario import motor_experiment
    from drive_common.contract.settings import FormatMigrated
    from drive_common.motor.scaled_loops import scaled_loops

    loops = scaled_loops(motor.nameplate, motor.inverter, T_s)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FormatMigrated)  # said once already, when the motor was read
        own = motor_experiment("low_speed", motor, "motor show", options=ExperimentOptions(T_s))
    report = {"name": motor.name, "file": motor.source, "description": motor.description,
              "nameplate": motor.nameplate._asdict(), "inverter": motor.inverter._asdict(),
              "simulated_plant": bool(motor.plant), "sample_period_s": T_s, "loops": loops._asdict(),
              "run": drive_loops(scenario) if scenario is not None else None,
              "sensorless_torque": stated_torque_report(scenario if scenario is not None else own)}
    report["loops"]["notes"] = list(loops.notes)
    return report


def stated_torque_report(scenario):
    """The torque ``scenario``'s drive states it holds sensorless at low speed (foc_controller.build.stated_torque,
    SensorlessTorque.as_dict), built as a run builds its drive; {"line": why not} where the drive refuses it."""
    from drive_common.contract.errors import DriveError
    from drive_tools.runner.runner import scenario_commissioning
    from foc_controller.build import controller_for_scenario, stated_torque
    from hf_estimator.build import estimator_for_scenario

    try:
        commissioning = scenario_commissioning(scenario)
        estimator = estimator_for_scenario(scenario, commissioning)
        controller = controller_for_scenario(scenario, estimator.injection_frequency_Hz,
                                             estimator.tracking_bandwidth_Hz, estimator.tracking_current_limit_A,
                                             commissioning, estimator.tracking_acceleration_rad_s2,
                                             estimator.tracking_loop)
    except DriveError as error:
        return {"line": f"sensorless torque limit not stated: the drive refuses to run it ({error})"}
    return stated_torque(scenario, commissioning, controller, estimator.tracking_current_limit_A is not None,
                         estimator.tracking_current_bound).as_dict()


def drive_loops(scenario):
    """What a run of ``scenario`` uses, built as drive_tools.runner.runner.build_drive builds it (the same
    commissioning, estimator and controller builders): {scenario, sample_period_s, commissioning, the
    estimator's facts (carrier, amplitude, tracking bandwidth and current, note), current_limit_A, the speed
    loop's kp, ki and ω_n [rad/s], the speed reference's ramp [rad/s², ∞: none]}."""
    from drive_tools.runner.runner import scenario_commissioning
    from foc_controller.build import controller_for_scenario, speed_loop
    from hf_estimator.build import estimator_for_scenario

    commissioning = scenario_commissioning(scenario)
    estimator = estimator_for_scenario(scenario, commissioning)
    controller = controller_for_scenario(scenario, estimator.injection_frequency_Hz, estimator.tracking_bandwidth_Hz,
                                         estimator.tracking_current_limit_A, commissioning,
                                         estimator.tracking_acceleration_rad_s2, estimator.tracking_loop)
    omega_n = speed_loop(scenario, commissioning, controller, estimator.facts()).omega_n_rad_s
    return {"scenario": scenario.name, "sample_period_s": scenario.T_s, "commissioning": commissioning.source,
            **estimator.facts(), "current_limit_A": controller.i_max_A, "speed_kp": controller.kp_speed,
            "speed_ki": controller.ki_speed, "speed_bandwidth_rad_s": omega_n,
            "speed_ramp_rad_s2": controller.speed_ramp_rad_s2}


RUN_ROWS = (("injection frequency", "injection_frequency_Hz", "Hz"),
            ("injection amplitude", "injection_amplitude_V", "V"),
            ("tracking bandwidth", "tracking_bandwidth_Hz", "Hz"), ("current limit", "current_limit_A", "A"),
            ("speed loop kp", "speed_kp", "A·s/rad"), ("speed loop ki", "speed_ki", "A/rad"),
            ("speed loop ω_n", "speed_bandwidth_rad_s", "rad/s"),
            ("speed ramp", "speed_ramp_rad_s2", "rad/s²"))
"""What motor_lines prints of drive_loops: label, key, unit."""


def motor_lines(report):
    lines = [f"{report['name']}: {report['description'] or report['file']} ({report['file']})"]
    lines += [f"  {key:34s} {cell(value)}" for key, value in {**report["nameplate"], **report["inverter"]}.items()
              if key != "name"]
    run = report.get("run")
    if run:
        lines.append(f"  what `drive run {run['scenario']} --motor {report['file']}` uses "
                     f"({1.0 / run['sample_period_s']:g} Hz sampling, {run['estimator']}, commissioning: "
                     f"{run['commissioning']}):")
        lines += [f"  {label:34s} {cell(run[key])} {unit}" for label, key, unit in RUN_ROWS if run[key] is not None]
        lines += [f"  note: {note}" for note in (run["injection_note"] or "").split("; ") if note]
    else:
        lines.append(f"  loops scaled to it at {1.0 / report['sample_period_s']:g} Hz sampling: what ours runs where "
                     f"a scenario sets no carrier or loop of its own (docs/motors-and-control.md; the paper scenarios "
                     f"set their paper's: `--scenario S` prints what `drive run S --motor` uses):")
        loops = report["loops"]
        lines += [f"  {label:34s} {loops[key]:.4g} {unit}" for label, key, unit in MOTOR_LOOP_ROWS]
        lines += [f"  note: {note}" for note in loops["notes"]]
    lines.append(f"  {report['sensorless_torque']['line']}")
    plant = "given (plant:)" if report["simulated_plant"] else "none: the nameplate is the plant"
    lines.append(f"  simulated plant: {plant}")
    return lines


@dataclass(frozen=True)
class CommissioningWritten:
    """A commissioning file as ``drive commission`` wrote it: its path ``out``, the motor's name, the
    identification ``method`` and the ``conditions`` the file states."""

    out: Path
    motor_name: str
    method: str
    conditions: dict


def commissioning_report(written, run, record, rated_A, rotating=None, loaded=None):
    """What ``drive commission`` wrote (``written``, a CommissioningWritten) and identified: ``run`` how it ran
    (drive_tools.runner.commissioning_run.CommissioningRun: the finished hf_estimator.commissioning.procedure,
    the host, its wall time, and the plant's truth and true currents where a simulation knows them), ``record``
    its Commissioning, with ψ_f and J from ``rotating`` when the rotating test ran and ours' correction from
    ``loaded`` (hf_estimator.commissioning.loaded.loaded_shift with its conditions and the true error at each
    hold) when the loaded test ran; ``rated_A`` the motor's rated current [A]."""
    from drive_common.motor.commissioning import SCALARS

    identified = {key: float(getattr(record, key)) for key in SCALARS}
    if rotating:
        identified.update({key: float(getattr(record, key)) for key in ("psi_f_Wb", "J_kgm2")})
    identified["saliency_shift_at_rated_rad"] = table_value(rated_A, record.saliency_shift_i_q_A,
                                                            record.saliency_shift_rad)
    identified["convergence_slope_at_rated"] = table_value(rated_A, record.saliency_shift_i_q_A,
                                                           record.convergence_slope)
    identified["tracking_current_limit_A"] = record.tracking_current_limit_A()
    conditions, procedure = written.conditions, run.procedure
    report = {"file": str(written.out), "written": str(written.out), "tests_completed": conditions["tests_completed"],
              "refused": None, "motor": written.motor_name, "method": written.method, "host": run.host,
              "duration_s": conditions["duration_s"], "wall_time_s": run.wall_time_s, "scaled": conditions["scaled"],
              "polarity": conditions["polarity"], "saliency": conditions["saliency"],
              "current_limit_A": procedure.limit_A, "peak_measured_current_A": float(np.max(np.abs(procedure.raw))),
              "identified": identified}
    if run.truth is not None:
        report["truth"] = run.truth
    if run.true_currents is not None:
        report["peak_true_current_A"] = float(np.max(np.abs(run.true_currents)))
    if rotating:
        report["rotating_test"] = rotating
    if loaded:
        identified["estimator_shift_at_rated_rad"] = table_value(rated_A, record.saliency_shift_i_q_A,
                                                                 record.estimator_shift_rad)
        report["loaded_test"] = {key: loaded[key] for key in ("top_current_A", "zero_spread_rad", "significant",
                                                              "injection_frequency_Hz", "injection_amplitude_V",
                                                              "holds", "loaded_test_current_A")}
    return report


def refused_report(motor_name, test, reason):
    """What ``drive commission`` reports where its ``test`` refused before anything was written."""
    return {"file": None, "written": None, "tests_completed": [], "motor": motor_name,
            "refused": {"test": test, "reason": reason}}


def refusal_lines(report):
    """What was written and what was refused, as text lines (empty where nothing was refused)."""
    refused = report.get("refused")
    if not refused:
        return []
    written = (f"written: {report['written']} (the {', '.join(report['tests_completed'])} test(s) only)"
               if report.get("written") else "nothing written")
    return [f"  REFUSED: the {refused['test']} test: {refused['reason']}", f"  {written}"]


def commissioning_lines(report):
    truth = report.get("truth")
    if report.get("written") is None:
        return [f"{report['motor']}: commissioning refused"] + refusal_lines(report)
    lines = [f"{report['file']}: {report['motor']} commissioned at standstill, shaft held ({report['host']}), "
             f"{report['duration_s']:.2f} s of motor time in {report['wall_time_s']:.2f} s"
             + (", then turning (the rotating test: ψ_f, J)" if report.get("rotating_test") else ""),
             f"  polarity: {report['polarity']}"]
    lines += [f"  scaled to the bus: {note}" for note in report.get("scaled", [])]
    if report["saliency"] != "measured":
        lines.append(f"  saliency: {report['saliency']}")
    lines.append(f"  {'':30s} {'identified':>12s}" + (f" {'truth':>12s} {'error':>9s}" if truth else ""))
    for key, value in report["identified"].items():
        line = f"  {key:30s} {value:12.6g}"
        if truth and key in truth:
            error = value - truth[key]
            relative = "offset" not in key and "shift" not in key and truth[key]
            line += f" {truth[key]:12.6g} " + (f"{100.0 * error / truth[key]:+8.3f}%" if relative else f"{error:+9.2e}")
        lines.append(line)
    peak = report.get("peak_true_current_A", report["peak_measured_current_A"])
    lines.append(f"  peak phase current {peak:.3f} A (limit {report['current_limit_A']:.3f} A)")
    if report.get("sensorless_torque"):
        lines.append(f"  {report['sensorless_torque']['line']}")
    loaded = report.get("loaded_test")
    if loaded:
        outcome = ("ours corrects it from now on" if loaded["significant"] else
                   f"within 3× its own noise ({loaded['zero_spread_rad']:.3g} rad at zero current): no correction")
        lines.append(f"  loaded test (shaft held, ours at {loaded['injection_frequency_Hz']:.0f} Hz, "
                     f"{loaded['injection_amplitude_V']:.3g} V): θ̂ moved under load; {outcome}")
        if loaded.get("loaded_test_current_A"):
            lines.append(f"  the loads took ours' angle above {loaded['loaded_test_current_A']:.3g} A: the drive's "
                         f"sensorless limit from now on (the test ran again up to it)")
        lines.append(f"  {'i_q [A]':>12s} {'θ̂ moved [rad]':>15s} {'correction':>11s} {'true θ − θ̂':>11s}")
        for hold in loaded["holds"]:
            lines.append(f"  {hold['i_q_A']:12.3f} {hold['moved_rad']:+15.4f} {hold['correction_rad']:+11.4f} "
                         f"{hold['true_error_rad']:+11.4f}")
    return lines + refusal_lines(report)
