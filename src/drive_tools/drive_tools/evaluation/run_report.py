"""A run's report (drive run, launch, bridge): its metrics with what the drive knew of the motor, what it
injected, warned of and supervised; and the report as text lines."""
import math

from drive_common.contract.exit_codes import EXIT_NOT_FOLLOWING, EXIT_NOT_TRACKING, EXIT_SIGNAL_BASE, EXIT_TRIPPED
from foc_controller.supervision import fault_line

from .metrics import compute_metrics, configuration_warnings, supervision_faults

RUN_ROWS = (("angle error RMS (steady)", "angle_error_rms", "rad"),
            ("angle error bias (steady)", "angle_error_bias", "rad"),
            ("angle error peak (all after start)", "angle_error_peak", "rad"),
            ("angle error peak (transients)", "angle_error_peak_transient", "rad"),
            ("speed estimation error RMS", "speed_error_rms", "rad/s"),
            ("speed tracking error RMS", "speed_tracking_error_rms", "rad/s"),
            ("settling time (worst step)", "settling_time_s", "s"),
            ("observable fraction", "observable_fraction", ""),
            ("current limit", "current_limit_A", "A"))
"""The metrics a run's text report lists: label, key, unit."""


def run_report(result):
    """The metrics of a run (drive_tools.runner.runner.RunResult or one like it) with ``commissioning`` (its
    source), ``motor_knowledge``, ``injection`` (when the estimator injects), ``loops`` (what it ran with, as
    `drive motor show --scenario` prints it), ``warnings`` and
    ``supervision`` (the speed supervisor's faults), ``sensorless_torque`` (the torque the drive stated it holds,
    drive_common.motor.torque_limit) and ``protection`` (what the drive's protections did,
    where the run composed them: foc_controller.protection.protection_summary)."""
    from drive_common.motor.knowledge import motor_knowledge

    metrics = compute_metrics(result)
    if result.commissioning is not None:
        metrics["commissioning"] = result.commissioning.source
        metrics["commissioning_tests"] = result.commissioning.tests()
        metrics["motor_knowledge"] = motor_knowledge(result.scenario.motor.nameplate, result.commissioning)
    facts = result.estimator_facts or {}
    if facts.get("injection_amplitude_V") is not None:
        metrics["injection"] = {"frequency_Hz": facts["injection_frequency_Hz"],
                                "amplitude_V": facts["injection_amplitude_V"], "note": facts["injection_note"]}
    if (metrics.get("startup") or {}).get("refused"):
        metrics["startup"]["refused"] = refusal_cause(metrics["startup"], result)
    metrics["loops"] = {"sample_period_s": result.scenario.T_s, "current_limit_A": result.current_limit_A,
                        **{key: facts.get(key) for key in ("injection_frequency_Hz", "injection_amplitude_V",
                                                           "tracking_bandwidth_Hz")}}
    metrics["warnings"] = configuration_warnings(result)
    metrics["supervision"] = supervision_faults(result)
    metrics["sensorless_torque"] = getattr(result, "sensorless_torque", None)
    if getattr(result, "protection", None) is not None:
        metrics["protection"] = result.protection
    return metrics


def refusal_cause(startup, result):
    """The start-up's refusal (``startup["refused"]``, hf_estimator.startup.REFUSALS) with the cause the drive
    measured and its figure: the commissioned saliency where no angle signal was seen, the pulses' asymmetry
    where no polarity was told."""
    from drive_common.motor.commissioning import MIN_SALIENCY_RATIO, NAMEPLATE_ONLY
    from hf_estimator.startup import DEFAULTS, REFUSALS
    from hf_estimator.startup_state import NO_POLARITY, NO_SALIENCY

    refused, record = startup["refused"], result.commissioning
    settings = {**DEFAULTS, **(result.scenario.estimator_settings or {})}
    if refused == REFUSALS[NO_SALIENCY]:
        timeout = f"{1e3 * settings['align_timeout_s']:g} ms"
        if record is None or record.source == NAMEPLATE_ONLY:
            plate = result.scenario.motor.nameplate
            return (f"no angle signal while aligning ({timeout}): the estimator never found it observable; the motor "
                    f"is not commissioned (nameplate L_q/L_d = {plate.L_q_H / plate.L_d_H:.3g}): `drive commission` "
                    f"measures its saliency")
        ratio = abs(record.delta / record.sigma)
        if ratio < MIN_SALIENCY_RATIO:
            return (f"no saliency: commissioning measured |Δ|/Σ = {ratio:.3g} < {MIN_SALIENCY_RATIO:g}, a round rotor "
                    f"to HF injection: its angle cannot be told")
        return (f"no angle signal while aligning ({timeout}): the estimator never found it observable although "
                f"commissioning measured |Δ|/Σ = {ratio:.3g}: the signal at this carrier and amplitude is lost in the "
                f"current sensors' noise")
    if refused == REFUSALS[NO_POLARITY]:
        ratio = result.startup["polarity_ratio"]
        return (f"the polarity pulses found no saturation asymmetry: ratio {ratio:+.3g} within the margin "
                f"±{settings['polarity_margin']:g} after {settings['polarity_tries']} tries: the magnet's polarity "
                f"cannot be told")
    return refused


def run_lines(metrics, extra):
    """A run's report as text lines; ``extra``: what the host adds (graph, link, timing, faults), each a
    line of its own."""
    lines = [f"scenario {metrics['scenario']} ({metrics['motor']}), estimator {metrics['estimator']}, "
             f"{metrics['duration_s']:g} s, {metrics['samples']} samples in {metrics['wall_time_s']:.2f} s"]
    if "motor_knowledge" in metrics:
        lines.append(f"  {'motor known from':36s} {knowledge_line(metrics['motor_knowledge'])}")
    if "commissioning_tests" in metrics:
        tests = ", ".join(metrics["commissioning_tests"]) or "none (the nameplate alone)"
        lines.append(f"  {'commissioning tests used':36s} {tests}")
    lines += [f"  {'WARNING':36s} {line}" for line in metrics["warnings"]]
    if metrics.get("injection", {}).get("note"):
        injection = metrics["injection"]
        lines.append(f"  {'injection':36s} {injection['amplitude_V']:.3g} V at {injection['frequency_Hz']:.1f} Hz "
                     f"({injection['note']})")
    for key, value in extra.items():
        if value is False:
            continue
        if key == "node_faults":
            value = "; ".join(f"{name} ({', '.join(f'{kind} ×{n}' for kind, n in d['faults'].items())}): "
                              f"{' | '.join(d['messages'])}" for name, d in value.items()) or "none"
        elif isinstance(value, dict):
            value = ", ".join(f"{k} {v}" for k, v in value.items() if v) or "none"
        lines.append(f"  {key:36s} {value}")
    for label, key, unit in RUN_ROWS:
        value = metrics[key]
        text = "n/a" if value is None else f"{value:+.4f} {unit}"
        if key == "settling_time_s" and metrics["settling_note"]:
            text = metrics["settling_note"]
        lines.append(f"  {label:36s} {text}")
    lines.append(f"  {'start-up':36s} {startup_line(metrics['startup'])}")
    lost = metrics["lock_lost_s"]
    lock = ("n/a (no ground truth in the scored window)" if lost is None else "held" if not lost else
            f"LOST for {lost:.4f} s (|angle error| > π/2), first at {metrics['lock_lost_at_s']:.4f} s")
    if metrics["lock_lost"]:
        lock += f"; the estimator reported {metrics['lock_lost']} lost lock(s)"
    lines.append(f"  {'lock':36s} {lock}")
    lines.append(f"  {'speed supervision':36s} {supervision_line(metrics)}")
    if "protection" in metrics:
        lines.append(f"  {'protections':36s} {protection_line(metrics['protection'])}")
    lines += [f"  plot: {path}" for path in metrics.get("plots", [])]
    if "outcome" in metrics:
        lines.append(f"  {'outcome':36s} {outcome_line(metrics['outcome'])}")
    return lines


def supervision_line(metrics):
    """The speed supervision in one line: its faults; else that the shaft followed its command only where the
    run ended with the drive tracking and holding torque (its ``outcome``), else why it was not judged."""
    faults = metrics["supervision"]
    if faults:
        return "; ".join(fault_line(f) for f in faults)
    code = (metrics.get("outcome") or {}).get("exit_code", 0)
    if code in (EXIT_NOT_TRACKING, EXIT_NOT_FOLLOWING, EXIT_TRIPPED) or code >= EXIT_SIGNAL_BASE:
        return "no fault found before the drive stopped driving the shaft (see the outcome)"
    return "the shaft followed its command"


def outcome_line(outcome):
    """The run's exit code and why, in one line."""
    if not outcome["exit_code"]:
        return "exit 0: done"
    return f"exit {outcome['exit_code']}: {outcome['reason']}"


def protection_line(protection):
    """What the drive's protections did, in one line."""
    seen = (f"winding estimate up to {protection['winding_peak_degC']:.1f} °C, bus up to "
            f"{protection['bus_peak_V']:.4g} V")
    trip = protection["trip"]
    if trip is None:
        return f"no trip; {seen}"
    return f"TRIPPED at {trip['at_s']:.4f} s: {trip['cause']}, into {trip['safe_state']}; {seen}"


def startup_line(startup):
    """The start-up in one line: when torque came, the polarity and error then, or why it never came."""
    if not startup["completed"]:
        if startup.get("refused"):
            return f"REFUSED: {startup['refused']}"
        return "not completed within the run (no torque applied)"
    text = f"torque from {1e3 * startup['duration_s']:.1f} ms"
    if startup["polarity_correct"] is not None:
        text += (f", polarity {'correct' if startup['polarity_correct'] else 'WRONG'}, angle error "
                 f"{startup['angle_error_e_rad']:+.3f} rad")
    if startup["reverse_rotation_m_rad"] is not None:
        text += f", {math.degrees(startup['reverse_rotation_m_rad']):.2f}° against the command"
    if startup.get("refused"):
        text += f"; then {startup['refused']}"
    return text


def knowledge_line(knowledge):
    """One line saying where the drive's motor values came from (drive_config has them value by value)."""
    by_source = {}
    for key, entry in knowledge.items():
        by_source.setdefault(entry["source"], []).append(key)

    def names(keys):
        text = ", ".join(keys)
        for stem in ("sensor_gain_", "sensor_offset_"):
            unit = "_A" if "offset" in stem else ""
            text = text.replace(f"{stem}a{unit}, {stem}b{unit}, {stem}c{unit}", f"{stem}a/b/c{unit}")
        return text
    return "; ".join(f"{source}: {names(keys)}" for source, keys in by_source.items())
