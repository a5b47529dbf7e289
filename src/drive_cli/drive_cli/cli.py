"""The ``drive`` command line: one entry, a subcommand per job; every result-printing command also has
``--json``. Domain errors (drive_interface.errors.DriveError) are printed as one line, exit code 2."""
import argparse
import dataclasses
import math
import os
import sys
from pathlib import Path

import numpy as np

from drive_evaluation.metrics import configuration_warnings, supervision_faults
from drive_interface import interrupt
from drive_interface.errors import DriveError
from drive_interface.exit_codes import (
    EXIT_NODE_FAULTS,
    EXIT_NOT_FOLLOWING,
    EXIT_NOT_TRACKING,
    EXIT_READER_GONE,
    EXIT_RECORDING_FAILED,
    EXIT_REFUSED,
    EXIT_SIGNAL_BASE,
)
from drive_interface.graph import DEFAULT_NAMESPACE, EXECUTORS
from drive_interface.interrupt import Interrupted
from drive_interface.realtime import add_scheduling_arguments
from drive_interface.strict_json import dumps
from drive_scenarios.scenario import (
    MAX_BLOCK_SAMPLES,
    MAX_SAMPLES,
    PACED_BLOCK_SAMPLES,
    SAMPLING_PERIOD_RANGE_S,
    behind_an_inverter,
    link_block_samples,
    load_scenario,
    scenario_names,
)
from foc_controller.supervision import fault_line
from hf_estimator.interface import injects
from hf_estimator.registry import describe, estimator_names
from motor_params.motor_file import load_motor

PLL_ESTIMATORS = ("synchronous", "conventional", "improved")
MOTOR_HELP = ("the motor in place of the scenario's: a shipped motor's name or a motor file "
              "(`drive motor template` writes one)")
COMMISSIONING_HELP = ("the drive's commissioning file (written by `drive commission`), or 'nameplate' for the "
                      "nameplate alone (default: the scenario's key, else commissioning/MOTOR.yaml when present)")


class CommandLineError(DriveError):
    """An option's value is unusable; the message names the option."""


def _exit_code(interrupted=0, node_faults=None, output_error=None, not_tracking=False, not_following=False):
    """128 + the signal that stopped the run, else the worst of drive_interface.exit_codes (an output, bag
    or plot, not written in full; the drive not tracking at the end; the shaft not following its command;
    a node fault), else 0."""
    if interrupted:
        return EXIT_SIGNAL_BASE + interrupted
    if output_error:
        return EXIT_RECORDING_FAILED
    if not_tracking:
        return EXIT_NOT_TRACKING
    if not_following:
        return EXIT_NOT_FOLLOWING
    return EXIT_NODE_FAULTS if node_faults else 0


def _not_tracking(result):
    """The estimator refused to start, or the run ended holding zero torque after a lost lock (the log's
    last state; the estimator's own account). A run shorter than the start-up is not a failure."""
    from drive_interface.log import COLUMN
    states = result.log[:, COLUMN["state"]]
    if not states.size:
        return False
    return bool((result.startup or {}).get("refused")) or states[-1] == 4.0


def _record_arg(path):
    """Refuse a --record target before running: it must be new, in a writable directory that exists."""
    import tempfile
    if path is None:
        return
    target = Path(path)
    if target.exists():
        raise CommandLineError(f"--record: {path} already exists; choose a new bag name")
    if not target.parent.is_dir():
        raise CommandLineError(f"--record: the directory {target.parent} does not exist")
    try:
        tempfile.TemporaryDirectory(dir=target.parent).cleanup()
    except OSError as error:
        raise CommandLineError(f"--record: cannot write in {target.parent} ({error.strerror})") from None


def _motor_reference(name_or_path):
    """A --motor as nodes in other processes find it: a motor file's absolute path (a name stays a name
    when it is not a file; the nodes' loader then names it in its error)."""
    from motor_params.motor_file import motor_path
    path = motor_path(name_or_path)
    return str(path.resolve()) if path is not None else name_or_path


def _print_json(data):
    print(dumps(data, indent=2, ensure_ascii=False))


def _estimator_arg(args):
    """Refuse an unknown --estimator before anything runs, naming the option."""
    if args.estimator and args.estimator not in estimator_names():
        raise CommandLineError(f"--estimator: unknown estimator '{args.estimator}' "
                               f"(known: {', '.join(estimator_names())})")


class OneLineParser(argparse.ArgumentParser):
    """argparse whose errors are one line naming the command and the option (its subcommands inherit it);
    ``--help`` shows the usage."""

    def error(self, message):
        self.exit(EXIT_REFUSED, f"{self.prog}: {message} (`{self.prog} --help` shows the usage)\n")


def finite_float(text):
    """argparse type: a finite real number (inf and nan are refused as the option's error)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be a finite number, not {text!r}")
    return value


def _sample_period_arg(T_s):
    """--sample-period checked against the range a scenario file's sampling_period_s has."""
    low, high = SAMPLING_PERIOD_RANGE_S
    if not low <= T_s <= high:
        raise CommandLineError(f"--sample-period: must lie in [{low:g}, {high:g}] s, not {T_s!r}")
    return T_s


def _duration_arg(duration, T_s):
    """--duration checked: positive, and within the sample cap a scenario file has (MAX_SAMPLES at T_s)."""
    if duration is None:
        return None
    if duration <= 0.0:
        raise CommandLineError(f"--duration: must be positive, not {duration}")
    if duration / T_s > MAX_SAMPLES:
        raise CommandLineError(f"--duration: {duration:g} s at {T_s:g} s per sample is more than {MAX_SAMPLES} "
                               f"samples (the cap a scenario file has too)")
    return duration


def _scenario_arg(args):
    """The scenario named on the command line, with --estimator and --duration applied."""
    _estimator_arg(args)
    scenario = load_scenario(args.scenario, estimator_override=args.estimator,
                             override_source="command line --estimator", motor_override=args.motor,
                             motor_source="--motor")
    if _duration_arg(args.duration, scenario.T_s) is not None:
        scenario = dataclasses.replace(scenario, duration_s=args.duration)
    if args.commissioning:
        scenario = dataclasses.replace(scenario, commissioning=args.commissioning)
    blocks = getattr(args, "block_samples", None)
    if blocks is not None:
        if not 1 <= blocks <= MAX_BLOCK_SAMPLES:
            raise CommandLineError(f"--block-samples: must be from 1 to {MAX_BLOCK_SAMPLES}, not {blocks}")
        scenario = dataclasses.replace(scenario, block_samples=blocks)
    answer = getattr(args, "answer_periods", None)
    if answer is not None:
        if not 1 <= answer <= MAX_BLOCK_SAMPLES + 1:
            raise CommandLineError(f"--answer-periods: must be from 1 to {MAX_BLOCK_SAMPLES + 1}, not {answer}")
        scenario = dataclasses.replace(scenario, answer_periods=answer)
    return scenario


def cmd_run(args):
    from drive_runner.runner import run_scenario, terminal_progress

    scenario = _scenario_arg(args)
    _record_arg(args.record)
    result = run_scenario(scenario, progress=terminal_progress(f"{scenario.name}/{scenario.estimator}"))
    interrupted = result.interrupted
    extra, recording_error = {"interrupted": bool(interrupted)}, None
    if args.record:
        from drive_bags.common import BagWriteError
        from drive_bags.writer import write_run_bag
        progress = terminal_progress(f"writing {args.record}")
        try:
            extra["bag"] = str(write_run_bag(result, args.record, progress=progress))
        except BagWriteError as error:
            recording_error = str(error)
        except Interrupted as stop:
            interrupted = interrupted or stop.signum
            extra["interrupted"] = True
            recording_error = f"{args.record}: writing interrupted; the bag is closed as far as written"
        if recording_error:
            extra["recording_error"] = recording_error
    plot_error, metrics = _report(result, args, extra)
    if recording_error:
        _output_failed(recording_error)
    return _exit_code(interrupted, output_error=recording_error or plot_error, not_tracking=_not_tracking(result),
                      not_following=bool(metrics["supervision"]))


def _warn_if_nameplate_only(source, motor, scenario_name):
    """Say on stderr that a drive found no commissioning file and ran on its nameplate alone."""
    from motor_params.commissioning import NAMEPLATE_ONLY, default_commissioning_file

    if source == NAMEPLATE_ONLY:
        print(f"drive: no {default_commissioning_file(motor)} here and none named: the drive ran on "
              f"its nameplate alone (`drive commission {scenario_name}` measures the motor)", file=sys.stderr)


def _report(result, args, extra=None):
    """Print a run's metrics (drive run, launch, bridge), write its plot unless --no-plot; returns (why
    the plot could not be written, or None; the metrics, printed either way)."""
    from drive_evaluation.metrics import compute_metrics
    from drive_evaluation.plots import plot_run

    scenario = result.scenario
    metrics = compute_metrics(result)
    if result.commissioning is not None:
        from motor_params.commissioning import NAMEPLATE_ONLY
        from motor_params.knowledge import motor_knowledge
        metrics["commissioning"] = result.commissioning.source
        if scenario.commissioning != NAMEPLATE_ONLY:
            _warn_if_nameplate_only(result.commissioning.source, scenario.motor.name, scenario.name)
        metrics["motor_knowledge"] = motor_knowledge(scenario.motor.nameplate, result.commissioning)
    facts = result.estimator_facts or {}
    if facts.get("injection_amplitude_V") is not None:
        metrics["injection"] = {"frequency_Hz": facts["injection_frequency_Hz"],
                                "amplitude_V": facts["injection_amplitude_V"], "note": facts["injection_note"]}
    metrics["warnings"] = configuration_warnings(result)
    metrics["supervision"] = supervision_faults(result)
    metrics.update(extra or {})
    if not args.no_plot and result.log.shape[0]:
        out_dir = Path(args.out) if args.out else Path("runs") / scenario.name
        try:
            metrics["plots"] = [str(plot_run(result, out_dir, args.command))]
        except OSError as error:
            metrics["plot_error"] = _os_error_line(error)
    if args.json:
        _print_json(metrics)
        return _output_failed(metrics.get("plot_error")), metrics
    print(f"scenario {metrics['scenario']} ({metrics['motor']}), estimator {metrics['estimator']}, "
          f"{metrics['duration_s']:g} s, {metrics['samples']} samples in {metrics['wall_time_s']:.2f} s")
    if "motor_knowledge" in metrics:
        print(f"  {'motor known from':36s} {_knowledge_line(metrics['motor_knowledge'])}")
    for line in metrics["warnings"]:
        print(f"  {'WARNING':36s} {line}")
    if metrics.get("injection", {}).get("note"):
        injection = metrics["injection"]
        print(f"  {'injection':36s} {injection['amplitude_V']:.3g} V at {injection['frequency_Hz']:.1f} Hz "
              f"({injection['note']})")
    for key, value in (extra or {}).items():
        if value is False:
            continue
        if key == "node_faults":
            value = "; ".join(f"{name} ({', '.join(f'{kind} ×{n}' for kind, n in d['faults'].items())}): "
                              f"{' | '.join(d['messages'])}" for name, d in value.items()) or "none"
        elif isinstance(value, dict):
            value = ", ".join(f"{k} {v}" for k, v in value.items() if v) or "none"
        print(f"  {key:36s} {value}")
    rows = [("angle error RMS (steady)", "angle_error_rms", "rad"),
            ("angle error bias (steady)", "angle_error_bias", "rad"),
            ("angle error peak (all after start)", "angle_error_peak", "rad"),
            ("angle error peak (transients)", "angle_error_peak_transient", "rad"),
            ("speed estimation error RMS", "speed_error_rms", "rad/s"),
            ("speed tracking error RMS", "speed_tracking_error_rms", "rad/s"),
            ("settling time (worst step)", "settling_time_s", "s"),
            ("observable fraction", "observable_fraction", ""),
            ("current limit", "current_limit_A", "A")]
    for label, key, unit in rows:
        value = metrics[key]
        text = "n/a" if value is None else f"{value:+.4f} {unit}"
        if key == "settling_time_s" and metrics["settling_note"]:
            text = metrics["settling_note"]
        print(f"  {label:36s} {text}")
    print(f"  {'start-up':36s} {_startup_line(metrics['startup'])}")
    lost = metrics["lock_lost_s"]
    lock = ("n/a (no ground truth in the scored window)" if lost is None else "held" if not lost else
            f"LOST for {lost:.4f} s (|angle error| > π/2), first at {metrics['lock_lost_at_s']:.4f} s")
    if metrics["lock_lost"]:
        lock += f"; the estimator reported {metrics['lock_lost']} lost lock(s)"
    print(f"  {'lock':36s} {lock}")
    print(f"  {'speed supervision':36s} "
          f"{'; '.join(fault_line(f) for f in metrics['supervision']) or 'the shaft followed its command'}")
    for path in metrics.get("plots", []):
        print(f"  plot: {path}")
    return _output_failed(metrics.get("plot_error")), metrics


def _startup_line(startup):
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


def _knowledge_line(knowledge):
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


def _output_failed(error):
    """Say on stderr, in one line, that an output could not be written; return the error."""
    if error:
        print(f"drive: {' '.join(error.split())}", file=sys.stderr)
    return error


def cmd_launch(args):
    from drive_launch.launcher import launch
    from drive_runner.runner import terminal_progress

    _estimator_arg(args)
    scenario = load_scenario(args.scenario, estimator_override=args.estimator,
                             override_source="command line --estimator", motor_override=args.motor,
                             motor_source="--motor")
    _duration_arg(args.duration, scenario.T_s)
    _record_arg(args.record)
    if args.paced and not args.link:
        raise CommandLineError("--paced: needs --link pty|can (the virtual inverter is what keeps the clock)")
    extra = {"commissioning": args.commissioning} if args.commissioning else {}
    if args.motor:
        extra["motor_file"] = _motor_reference(args.motor)
    blocks = link_block_samples(args.paced, args.block_samples)
    if blocks is not None:
        extra["block_samples"] = _block_sizes(str(blocks))[0]
    if args.link:
        from drive_bridge.inverter_protocol import MAX_BLOCK
        behind_an_inverter(dataclasses.replace(scenario, block_samples=blocks or scenario.block_samples), MAX_BLOCK)
    result = launch(args.scenario, estimator=args.estimator, duration_s=args.duration,
                    processes=args.processes, executor=args.executor, namespace=args.namespace,
                    timeout_s=args.timeout, bag=args.record, link=args.link, paced=args.paced,
                    extra_parameters=extra or None, rt_priority=args.rt_priority, cpus=args.cpus,
                    progress=terminal_progress(f"{scenario.name}/{scenario.estimator} over ROS"))
    for line in result.scheduling["refused"]:
        print(f"drive: warning: {line}", file=sys.stderr)
    faults = result.node_faults
    plant = f"virtual inverter over {args.link} + drive_bridge" if args.link else "pmsm_plant"
    extra = {"graph": f"{args.processes} processes, {args.executor} executor, namespace {args.namespace}, "
                      f"{plant}",
             "real_time_factor": round(result.scenario.duration_s / result.wall_time_s, 4)
             if result.wall_time_s > 0 else None,
             "interrupted": bool(result.interrupted), "node_faults": faults, "scheduling": result.scheduling}
    if result.timing:
        extra["timing"] = result.timing
    if args.record:
        extra["bag"] = args.record
    if result.recording_error:
        extra["recording_error"] = result.recording_error
    plot_error, metrics = _report(result, args, extra)
    if result.recording_error:
        _output_failed(result.recording_error)
    return _exit_code(result.interrupted, faults, result.recording_error or plot_error,
                      not_following=bool(metrics["supervision"]))


def cmd_bridge(args):
    from drive_runner.bridge_loop import run_through_bridge
    from drive_runner.runner import terminal_progress

    args.block_samples = link_block_samples(args.paced, args.block_samples)
    scenario = _scenario_arg(args)
    result = run_through_bridge(scenario, args.link, rate_Hz=1.0 / scenario.T_s if args.paced else None,
                                progress=terminal_progress(f"{scenario.name}/{scenario.estimator} through the "
                                                           f"bridge ({args.link})"))
    extra = {"link": f"virtual inverter over {args.link}, bridge core, estimator and controller cores",
             "samples_per_s": round(result.log.shape[0] / result.wall_time_s) if result.wall_time_s > 0 else None,
             "bridge": result.counters, "frame_errors": result.frame_errors,
             "inverter": result.inverter_counters, "timing": result.timing, "interrupted": bool(result.interrupted)}
    plot_error, metrics = _report(result, args, extra)
    return _exit_code(result.interrupted, output_error=plot_error, not_following=bool(metrics["supervision"]))


def cmd_bench_bridge(args):
    from drive_evaluation.bench import REAL_TIME_LEVERS, bridge_rates, graph_real_time

    links = args.links.split(",")
    for link in links:
        if link not in ("pty", "can"):
            raise CommandLineError(f"--links: 'pty' and/or 'can', not {link!r}")
    if args.graph or args.load or args.levers:
        if not (args.paced and args.graph):
            raise CommandLineError("--graph, --load and --levers measure the ROS graph on the inverter's clock: "
                                   "give --paced --graph")
        levers = (args.levers or "collector").split(",")
        for lever in levers:
            if lever not in REAL_TIME_LEVERS:
                raise CommandLineError(f"--levers: {lever!r} is not one of {', '.join(REAL_TIME_LEVERS)}")
        if args.repeats < 1:
            raise CommandLineError(f"--repeats: at least 1, not {args.repeats}")
        print(f"drive launch {args.scenario} --link L --paced, {args.repeats} runs per link and lever"
              f"{', one core kept busy by another process' if args.load else ''}", file=sys.stderr)
        report = graph_real_time(args.scenario, links, args.repeats, args.load, levers,
                                 progress=lambda line: print(line, file=sys.stderr))
        if args.json:
            _print_json(report)
        return _exit_code(report["interrupted"])
    duration = args.duration if args.duration is not None or args.paced else 1.0
    _duration_arg(duration, load_scenario(args.scenario).T_s)
    if args.block_samples is not None:
        from drive_bridge.inverter_protocol import MAX_BLOCK
        if not 1 <= args.block_samples <= MAX_BLOCK:
            raise CommandLineError(f"--block-samples: the inverter protocol carries 1 to {MAX_BLOCK} samples per "
                                   f"block, not {args.block_samples}")
    report = bridge_rates(args.scenario, links, duration, args.repeats, args.paced,
                          link_block_samples(args.paced, args.block_samples))
    if args.json:
        _print_json(report)
        return 0
    hop = report["links"][0]["hop_us"] if report["links"] else None
    hop_line = f"  one rclpy hop on this machine: {hop:.1f} µs (latencies in hops in --json)" if hop else ""
    if args.paced:
        print(f"bridge closed loop, {report['scenario']} ({report['samples']} samples, inverter on its own clock "
              f"at {report['sampling_rate_Hz']:g} Hz; worst of {report['repeats']})")
        print(f"  {'link':6s} {'N':>3s} {'late':>8s} {'latency p50':>12s} {'p99':>9s} {'max':>9s} {'angle RMS':>10s} "
              f"{'peak':>7s} {'lost':>5s}")
        for row in report["links"]:
            microseconds = [_formatted(row[key], "{:.0f}") for key in ("latency_p50_us", "latency_p99_us",
                                                                         "latency_max_us")]
            angles = [_formatted(row[key], "{:.4f}") for key in ("angle_error_rms", "angle_error_peak")]
            print(f"  {row['link']:6s} {row['block_samples']:3d} {100.0 * row['late_fraction']:7.3f}% "
                  f"{microseconds[0]:>9s} µs "
                  f"{microseconds[1]:>6s} µs {microseconds[2]:>6s} µs {angles[0]:>10s} {angles[1]:>7s} "
                  f"{row['lock_lost']:5d}")
        print(hop_line)
        return 0
    print(f"bridge closed loop, {report['scenario']} ({report['samples']} samples, inverter paced by the "
          f"host's answers; best of {report['repeats']})")
    print(f"  {'link':6s} {'samples/s':>10s} {'latency p50':>12s} {'p99':>9s} {'host p50':>9s} {'p99':>9s} "
          f"{'bare echo':>10s} {'missing':>8s}")
    for row in report["links"]:
        print(f"  {row['link']:6s} {row['samples_per_s']:10.0f} {row['latency_p50_us']:9.0f} µs "
              f"{row['latency_p99_us']:6.0f} µs {row['host_p50_us']:6.0f} µs {row['host_p99_us']:6.0f} µs "
              f"{row['link_echo_us']:7.0f} µs {row['missing_commands']:8d}")
    print(hop_line)
    return 0


def cmd_scenarios(args):
    entries = []
    for name in scenario_names():
        s = load_scenario(name)
        entries.append({"name": name, "motor": s.motor.name, "estimator": s.estimator,
                        "duration_s": s.duration_s, "description": s.description})
    if args.json:
        _print_json(entries)
    else:
        for e in entries:
            print(f"{e['name']:18s} {e['motor']:12s} {e['estimator']:12s} {e['duration_s']:5g} s  "
                  f"{e['description']}")
    return 0


def cmd_estimators(args):
    entries = [describe(n) for n in estimator_names()]
    if args.json:
        _print_json(entries)
    else:
        for e in entries:
            print(f"{e['name']:16s} {e['description']}\n{'':16s} {e['paper']}; module {e['module']}")
    return 0


def cmd_commission(args):
    from drive_commissioning.procedure import METHOD

    from control_math.tables import table_value
    from drive_runner.runner import terminal_progress
    from motor_params.commissioning import SCALARS, default_commissioning_file, save_commissioning

    scenario = load_scenario(args.scenario, motor_override=args.motor, motor_source="--motor")
    if args.rotating and (args.graph or args.link):
        raise CommandLineError("--rotating: the rotating test runs in one process only (not yet over --graph or "
                               "--link)")
    out = Path(args.out) if args.out else default_commissioning_file(scenario.motor.name)
    if out.exists() and not args.force:
        raise CommandLineError(f"--out: {out} already exists (--force replaces it)")
    if not args.out:
        out.parent.mkdir(exist_ok=True)
    elif not out.parent.is_dir():
        raise CommandLineError(f"--out: the directory {out.parent} does not exist")
    progress = terminal_progress(f"commissioning {scenario.motor.name}")
    rated = scenario.motor.nameplate.rated_current_A
    truth, true_currents = None, None
    if args.graph:
        from drive_launch.commissioning_graph import commission_over_ros
        from pmsm_plant.build import plant_for_scenario
        from pmsm_plant.commissioning import commissioning_truth
        procedure, wall = commission_over_ros(args.scenario, args.namespace, args.link, progress=progress,
                                              motor=args.motor and _motor_reference(args.motor))
        host = "ROS graph: " + (f"virtual inverter over {args.link} + drive_bridge node" if args.link
                                else "pmsm_plant node") + " + drive_commissioning node"
        truth = commissioning_truth(plant_for_scenario(scenario), rated)
    else:
        from drive_runner.commissioning_run import commission_in_process, commission_through_bridge
        run = (commission_through_bridge(scenario, args.link, progress=progress) if args.link
               else commission_in_process(scenario, progress=progress))
        procedure, wall, host, truth, true_currents = run.procedure, run.wall_time_s, run.host, run.truth, \
            run.true_currents
    record = procedure.result()
    conditions = {"scenario": scenario.name, "host": host, **procedure.conditions()}
    save_commissioning(out, record, scenario.motor.name, METHOD, conditions)
    rotating = None
    if args.rotating:
        from drive_runner.commissioning_run import rotating_test_in_process
        estimates, rotating_truth, _ = rotating_test_in_process(scenario, out, progress=progress)
        record = record._replace(psi_f_Wb=estimates["psi_f_Wb"], J_kgm2=estimates["J_kgm2"])
        rotating = {key: estimates[key] for key in ("B_Nms", "friction_Nm", "speeds_rad_s")}
        conditions["rotating_test"] = {"speeds_rad_s": estimates["speeds_rad_s"], "load": "none, shaft free"}
        save_commissioning(out, record, scenario.motor.name, METHOD, conditions)
        truth = {**(truth or {}), **{key: rotating_truth[key] for key in ("psi_f_Wb", "J_kgm2")}}
    identified = {key: float(getattr(record, key)) for key in SCALARS}
    if rotating:
        identified.update({key: float(getattr(record, key)) for key in ("psi_f_Wb", "J_kgm2")})
    identified["saliency_shift_at_rated_rad"] = table_value(rated, record.saliency_shift_i_q_A,
                                                            record.saliency_shift_rad)
    identified["convergence_slope_at_rated"] = table_value(rated, record.saliency_shift_i_q_A,
                                                           record.convergence_slope)
    identified["tracking_current_limit_A"] = record.tracking_current_limit_A()
    report = {"file": str(out), "motor": scenario.motor.name, "method": METHOD, "host": host,
              "duration_s": conditions["duration_s"], "wall_time_s": wall, "polarity": conditions["polarity"],
              "saliency": conditions["saliency"], "current_limit_A": procedure.limit_A,
              "peak_measured_current_A": float(np.max(np.abs(procedure.raw))), "identified": identified}
    if truth is not None:
        report["truth"] = truth
    if true_currents is not None:
        report["peak_true_current_A"] = float(np.max(np.abs(true_currents)))
    if rotating:
        report["rotating_test"] = rotating
    if args.json:
        _print_json(report)
        return 0
    print(f"{out}: {scenario.motor.name} commissioned at standstill, shaft held ({host}), "
          f"{conditions['duration_s']:.2f} s of motor time in {wall:.2f} s"
          + (", then turning (the rotating test: ψ_f, J)" if rotating else ""))
    print(f"  polarity: {conditions['polarity']}")
    if conditions["saliency"] != "measured":
        print(f"  saliency: {conditions['saliency']}")
    print(f"  {'':30s} {'identified':>12s}" + (f" {'truth':>12s} {'error':>9s}" if truth else ""))
    for key, value in identified.items():
        line = f"  {key:30s} {value:12.6g}"
        if truth and key in truth:
            error = value - truth[key]
            relative = "offset" not in key and "shift" not in key and truth[key]
            line += f" {truth[key]:12.6g} " + (f"{100.0 * error / truth[key]:+8.3f}%" if relative else f"{error:+9.2e}")
        print(line)
    peak = report.get("peak_true_current_A", report["peak_measured_current_A"])
    print(f"  peak phase current {peak:.3f} A (limit {procedure.limit_A:.3f} A)")
    return 0


def _side_by_side(preset):
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


def cmd_presets(args):
    entries = []
    from pmsm_plant.presets import PRESETS

    for p in PRESETS.values():
        told, truth = _side_by_side(p)
        entries.append({"name": p.name, "source": p.source, "assumptions": list(p.assumptions),
                        "nameplate": p.nameplate._asdict(), "told": told, "truth": truth,
                        "machine": p.machine._asdict(), "mechanics": p.mechanics._asdict(),
                        "inverter": p.inverter._asdict(), "sensor": p.sensor._asdict()})
    if args.json:
        _print_json(entries)
        return 0
    for e in entries:
        print(f"{e['name']}: {e['source']}")
        print(f"  {'':14s} {'nameplate (the drive)':>22s} {'plant (truth)':>16s}")
        for key, value in e["truth"].items():
            shown = e["told"].get(key, "—")
            print(f"  {key:14s} {_cell(shown):>22s} {_cell(value):>16s}")
        for a in e["assumptions"]:
            print(f"  - {a}")
    return 0


def cmd_motor_template(args):
    from motor_params.motor_file import TEMPLATE
    sys.stdout.write(TEMPLATE)
    return 0


def cmd_motor_show(args):
    from motor_params.scaled_loops import scaled_loops

    motor = load_motor(args.motor, "motor")
    T_s = _sample_period_arg(args.sample_period)
    loops = scaled_loops(motor.nameplate, motor.inverter, T_s)
    report = {"name": motor.name, "file": motor.source, "description": motor.description,
              "nameplate": motor.nameplate._asdict(), "inverter": motor.inverter._asdict(),
              "simulated_plant": bool(motor.plant), "sample_period_s": T_s, "loops": loops._asdict()}
    report["loops"]["notes"] = list(loops.notes)
    if args.json:
        _print_json(report)
        return 0
    print(f"{motor.name}: {motor.description or motor.source} ({motor.source})")
    for key, value in {**motor.nameplate._asdict(), **motor.inverter._asdict()}.items():
        if key != "name":
            print(f"  {key:34s} {_cell(value)}")
    print(f"  loops scaled to it at {1.0 / T_s:g} Hz sampling (docs/motors-and-control.md):")
    rows = (("rated-torque acceleration", loops.acceleration_e_rad_s2, "rad/s² el."),
            ("tracking bandwidth (ours)", loops.tracking_bandwidth_Hz, "Hz"),
            ("injection frequency (ours)", loops.injection_frequency_Hz, "Hz"),
            ("injection amplitude (ours)", loops.injection_amplitude_V, "V"),
            ("amplitude cap (bus)", loops.amplitude_cap_V, "V"),
            ("speed loop bandwidth", loops.speed_bandwidth_rad_s, "rad/s"))
    for label, value, unit in rows:
        print(f"  {label:34s} {value:.4g} {unit}")
    for note in loops.notes:
        print(f"  note: {note}")
    print(f"  simulated plant: {'given (plant:)' if motor.plant else 'none: the nameplate is the plant'}")
    return 0


def _cell(value):
    if isinstance(value, list):
        return " ".join(f"{v:.4g}" for v in value)
    return value if isinstance(value, str) else f"{value:.5g}"


def cmd_echo(args):
    from drive_launch.echo import echo
    for flag, value in (("--count", args.count), ("--every", args.every)):
        if value is not None and value < 1:
            raise CommandLineError(f"{flag}: must be at least 1, not {value}")
    return echo(args.topic, args.namespace, args.count, args.every, args.json, args.timeout)


def cmd_bag_info(args):
    from drive_bags.reader import bag_info
    info = bag_info(args.bag)
    if args.json:
        _print_json(info)
        return 0
    print(f"bag {info['bag']}: storage {info['storage']}, compression {info['compression']}")
    for f in info["files"]:
        print(f"  file {f['path']} ({f['bytes']:,} bytes)")
    print(f"  duration {info['duration_s']:.6f} s (start {info['start_s']:.6f} s, "
          f"end {info['end_s']:.6f} s), {info['messages']:,} messages")
    width = max((len(t["topic"]) for t in info["topics"]), default=0)
    for t in info["topics"]:
        qos = t["offered_qos"][0] if t["offered_qos"] else {}
        qos_text = "/".join(str(qos.get(key, "?")).lower() for key in ("reliability", "durability", "depth"))
        print(f"  {t['topic']:{width}s}  {t['type']:38s} {t['count']:8d}  {t['serialization']}  {qos_text}")
    for warning in info["warnings"]:
        print(f"  warning: {warning}")
    return 0


def cmd_bag_reindex(args):
    from drive_bags.reindex import reindex
    info = reindex(args.bag, force=args.force)
    if args.json:
        _print_json(info)
    else:
        recovery = info["recovery"]
        skipped = ", ".join(f"{n} {what}" for what, n in recovery["skipped"].items()) or "nothing"
        print(f"{info['bag']}: rebuilt, {info['messages']:,} messages over {info['duration_s']:.6f} s; "
              f"skipped: {skipped}; the original files are kept in {recovery['originals']}")
    return 0


COMPARED_METRICS = (("angle error RMS (steady)", "angle_error_rms", "rad"),
                    ("angle error bias (steady)", "angle_error_bias", "rad"),
                    ("angle error peak", "angle_error_peak", "rad"),
                    ("speed estimation error RMS", "speed_error_rms", "rad/s"),
                    ("observable fraction", "observable_fraction", ""))


def _recording(bag, args):
    """A bag read for scoring with the command line's --motor, --sample-period, --commissioning, --windows."""
    from drive_evaluation.recording import read_recording
    return read_recording(bag, motor=args.motor, sample_period_s=args.sample_period,
                          commissioning=args.commissioning, windows=_windows_arg(args.windows))


def cmd_bench_compare(args):
    from drive_evaluation.metrics import angle_scores
    from drive_evaluation.plots import plot_angle_errors
    from drive_runner.runner import RunResult

    results, entries = [], []
    for bag in (args.bag_a, args.bag_b):
        recording = _recording(bag, args)
        entry = {**recording.report(), "estimator": recording.estimator or None}
        scores = angle_scores(recording.log, recording.n_p, recording.windows, recording.start_s)
        entry.update({key: scores[key] if entry["ground_truth"] or key == "observable_fraction" else None
                      for _, key, _ in COMPARED_METRICS})
        results.append(RunResult(recording.scenario, recording.estimator, recording.log, 0.0, math.nan,
                                 pole_pairs=recording.n_p))
        entries.append(entry)
    names = [Path(bag).name for bag in (args.bag_a, args.bag_b)]
    report = {"benchmark": "compare", "runs": entries}
    if not args.no_plot:
        out = Path(args.out) if args.out else Path("runs") / "compare"
        report["plot"] = str(plot_angle_errors(results, names, out / f"{names[0]}_vs_{names[1]}.png"))
    if args.json:
        _print_json(report)
        return 0
    print(f"  {'':30s} {names[0]:>24s} {names[1]:>24s}")
    for label, key, unit in (("scenario", "scenario", ""), ("estimator", "estimator", ""),
                             ("samples", "samples", "")) + COMPARED_METRICS:
        cells = [e[key] for e in entries]
        text = ["n/a" if v is None else f"{v:+.4f} {unit}" if isinstance(v, float) else str(v)
                for v in cells]
        print(f"  {label:30s} {text[0]:>24s} {text[1]:>24s}")
    for entry in entries:
        print(f"  {entry['bag']}: windows {entry['windows']['source']}")
        if not entry["ground_truth"]:
            print(f"  {entry['bag']}: no ground truth (rotor_state); only consistency is scored")
    if "plot" in report:
        print(f"  plot: {report['plot']}")
    return 0


REPLAY_COLUMNS = (
    ("samples/s", "replay speed, best of the timed runs"),
    ("observable", "fraction of samples after the scoring start the estimator reports tracking"),
    ("RMS [rad]", "electrical angle error θ_e − θ̂_e against the recorded rotor_state, scored windows"),
    ("bias [rad]", "its mean, scored windows"), ("peak [rad]", "its largest magnitude from the first window on"),
    ("speed RMS", "speed estimation error [rad/s], scored windows"),
    ("lock [s]", "time until |θ_e − θ̂_e| stays within π/8 to the end"),
    ("lost", "a real loss of lock: |θ_e − θ̂_e| > π/2 from the first window on (without ground truth: a loss "
             "the estimator reported)"))


def _estimator_list(text):
    """The estimators of ``--estimators a,b`` (all when empty); CommandLineError names an unknown one."""
    names = text.split(",") if text else estimator_names()
    for name in names:
        if name not in estimator_names():
            raise CommandLineError(f"--estimators: unknown estimator '{name}' "
                                   f"(known: {', '.join(estimator_names())})")
    return names


def _bags(pattern):
    """The bags named by a bag path, a directory of bags or a glob; CommandLineError when none."""
    import glob
    path = Path(pattern)
    if path.is_dir() and not (path / "metadata.yaml").exists() and not any(path.glob("*.mcap")):
        found = sorted(p for p in path.rglob("metadata.yaml"))
        bags = [str(p.parent) for p in found]
        if not bags:
            raise CommandLineError(f"bag: {pattern}: a directory without a bag (metadata.yaml) in it")
        return bags, True
    if any(c in pattern for c in "*?["):
        bags = sorted(glob.glob(pattern))
        if not bags:
            raise CommandLineError(f"bag: {pattern}: no bag matches")
        return bags, True
    return [pattern], False


def cmd_bench_replay(args):
    from drive_evaluation.plots import plot_angle_errors
    from drive_evaluation.replay import replay

    names = _estimator_list(args.estimators)
    bags, corpus = _bags(args.bag)
    if corpus:
        return _replay_corpus(bags, names, args)
    recording = _recording(args.bag, args)
    entries, results = replay(recording, names)
    truth = recording.ground_truth
    out = Path(args.out) if args.out else Path("runs") / "replay" / Path(args.bag).name
    report = {"benchmark": "replay", **recording.report(), "results": entries}
    drawn = [(result, entry["estimator"]) for result, entry in zip(results, entries) if entry["applicable"]]
    if not args.no_plot and truth:
        skipped = [f"{e['estimator']}: not applicable" for e in entries if not e["applicable"]]
        report["plot"] = str(plot_angle_errors([r for r, _ in drawn], [n for _, n in drawn],
                                               out / "angle_error.png", not_drawn=skipped,
                                               title=f"replay of {Path(args.bag).name} (recorded with "
                                                     f"{recording.estimator or 'an unnamed estimator'}): "
                                                     f"θ_e − θ̂_e per estimator"))
    _save_report(report, out / "replay.json")
    if args.json:
        _print_json(report)
        return 0
    e = recording.excitation
    print(f"replay of {args.bag}: {report['samples']} samples at {recording.T_s:g} s, motor "
          f"{recording.nameplate.name}, recorded with {recording.estimator or 'an estimator the bag does not name'}")
    print(f"  recorded excitation (measured): {e['kind']}"
          + (f", {e['frequency_Hz']:.0f} Hz, {e['amplitude_V']:.3g} V" if e["kind"] != "none" else ""))
    print("  from: " + "; ".join(f"{key} {value}" for key, value in recording.sources.items()))
    timing, lost = recording.timing, {k: v for k, v in recording.gaps["missing_samples"].items() if v}
    print(f"  stamps from {timing['epoch_s']:.6f} s, jitter {timing['jitter_rms_s'] * 1e6:.2g} µs RMS "
          f"({timing['jitter_max_s'] * 1e6:.2g} max), {timing['off_grid_messages']} off the grid; missing samples: "
          + (", ".join(f"{k} {v}" for k, v in lost.items()) or "none")
          + (f"; cut: the last {recording.gaps['cut_samples']} samples incomplete, left off" if recording.gaps[
              "cut_samples"] else ""))
    if not truth:
        print("  no ground truth (rotor_state) in this bag: scored for consistency only")
    columns = [("samples/s", "samples_per_second", "{:,.0f}"), ("observable", "observable_fraction", "{:.3f}")]
    if truth:
        columns += [("RMS [rad]", "angle_error_rms", "{:.4f}"), ("bias [rad]", "angle_error_bias", "{:+.4f}"),
                    ("peak [rad]", "angle_error_peak", "{:.4f}"), ("speed RMS", "speed_error_rms", "{:.3f}"),
                    ("lock [s]", "time_to_lock_s", "{:.4f}")]
    columns.append(("lost", "lost", "{}"))
    print(f"  {'estimator':22s}" + "".join(f"{label:>12s}" for label, _, _ in columns))
    for e in entries:
        cells = ["n/a" if e.get(key) is None else fmt.format(e[key]) for _, key, fmt in columns]
        print(f"  {e['estimator']:22s}" + "".join(f"{c:>12s}" for c in cells)
              + ("" if e["applicable"] else "   not applicable"))
    for e in entries:
        print(f"  {e['estimator']}: {'' if e['applicable'] else 'NOT APPLICABLE: '}{e['reason']}")
    shown = {label for label, _, _ in columns}
    for label, explanation in REPLAY_COLUMNS:
        if label in shown:
            print(f"  {label:>12s}: {explanation}")
    for key in ("plot", "json"):
        if key in report:
            print(f"  {key}: {report[key]}")
    return 0


def _save_report(report, path):
    """Write a report as JSON to ``path`` (its directory made) and name the file in it."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(dumps(report, indent=2))
    report["json"] = str(path)


def _replay_corpus(bags, names, args):
    """Every bag of a corpus replayed; one summary row per estimator. A path that is not a bag, or a bag
    that cannot be replayed, is skipped with one line on stderr (and listed under ``skipped``)."""
    from drive_evaluation.replay import replay, summarise
    from drive_runner.runner import terminal_progress

    per_bag, skipped = [], []
    progress = terminal_progress(f"replay of {len(bags)} bags")
    for i, bag in enumerate(bags):
        try:
            recording = _recording(bag, args)
            entries, _ = replay(recording, names)
        except DriveError as error:
            skipped.append({"path": bag, "reason": str(error)})
            print(f"drive: skipped {bag}: {error}", file=sys.stderr)
        else:
            per_bag.append({**recording.report(), "results": entries})
        if progress:
            progress((i + 1) / len(bags))
    if not per_bag:
        raise CommandLineError(f"bag: {args.bag}: none of its {len(bags)} paths could be replayed")
    summary = summarise(per_bag, names)
    report = {"benchmark": "replay corpus", "pattern": args.bag, "bags": len(per_bag), "summary": summary,
              "skipped": skipped, "per_bag": per_bag}
    if args.out:
        _save_report(report, Path(args.out) / "replay_corpus.json")
    if args.json:
        _print_json(report)
        return 0
    print(f"replay of {len(per_bag)} bags ({args.bag})" + (f", {len(skipped)} paths skipped (not a bag, or "
                                                            f"not replayable: one line each above)"
                                                            if skipped else ""))
    print(f"  {'estimator':22s}{'scored':>8s}{'n/a':>5s}{'lost':>6s}{'RMS med':>10s}{'RMS worst':>11s}"
          f"{'bias med':>10s}{'bias worst':>11s}{'peak med':>10s}{'peak worst':>11s}{'samples/s':>12s}")
    for row in summary:
        print(f"  {row['estimator']:22s}{row['scored']:8d}{row['not_applicable']:5d}{row['lost']:6d}"
              f"{_formatted(row['rms_median'], '{:.4f}'):>10s}{_formatted(row['rms_worst'], '{:.4f}'):>11s}"
              f"{_formatted(row['bias_median'], '{:+.4f}'):>10s}{_formatted(row['bias_worst'], '{:+.4f}'):>11s}"
              f"{_formatted(row['peak_median'], '{:.4f}'):>10s}{_formatted(row['peak_worst'], '{:.4f}'):>11s}"
              f"{_formatted(row['samples_per_second_min'], '{:,.0f}'):>12s}")
    print("  scored: bags where it is applicable and the bag has ground truth; n/a: bags where it is not "
          "applicable; lost: real losses of lock; worst bias: the largest magnitude; samples/s: the slowest bag")
    if "json" in report:
        print(f"  json: {report['json']}")
    return 0


def _gains_entry(gains):
    return {"A_p": gains.kp, "T_i_s": gains.kp / gains.ki, "kp": gains.kp, "ki": gains.ki}


def cmd_tune_current(args):
    from foc_controller.params import DEFAULTS
    from foc_controller.tuning import SZABO_TABLE2, current_bandwidth_damping, current_pi_gains

    m = load_motor(args.motor, "--motor").nameplate
    omega_n = args.bandwidth or DEFAULTS["current_bandwidth_rad_s"]
    zeta = args.damping or DEFAULTS["current_damping"]
    axes = ("d", "q") if args.axis == "both" else (args.axis,)
    inductance = {"d": m.L_d_H, "q": m.L_q_H}
    report = {"motor": args.motor, "bandwidth_rad_s": omega_n, "damping": zeta,
              "method": "closed-loop poles of the PI around 1/(Ls + R): k_p = 2ζω_n L − R, k_i = ω_n² L "
                        "(Szabó ref. [16])", "gains": {}}
    try:
        for axis in axes:
            report["gains"][axis] = _gains_entry(current_pi_gains(inductance[axis], m.R_s_ohm, omega_n, zeta))
    except ValueError as error:
        raise CommandLineError(f"--bandwidth: {error}") from None
    if args.motor == "szabo_ipmsm":
        report["table2"] = {axis: {**_gains_entry(SZABO_TABLE2[axis]), **dict(zip(
            ("bandwidth_rad_s", "damping"),
            current_bandwidth_damping(inductance[axis], m.R_s_ohm, SZABO_TABLE2[axis])))} for axis in axes}
    if args.json:
        _print_json(report)
        return 0
    print(f"current PI on {args.motor}: ω_n {omega_n:.1f} rad/s, ζ {zeta:g} ({report['method']})")
    for axis, g in report["gains"].items():
        line = f"  {axis}: A_p {g['A_p']:8.3f} V/A  T_i {1e3 * g['T_i_s']:7.3f} ms"
        if "table2" in report:
            t = report["table2"][axis]
            line += (f"   (Table 2: A_p {t['A_p']:.2f}, T_i {1e3 * t['T_i_s']:.1f} ms, "
                     f"which this method gives "
                     f"for ω_n {t['bandwidth_rad_s']:.1f} rad/s, ζ {t['damping']:.3f})")
        print(line)
    return 0


def cmd_tune_speed(args):
    from foc_controller.params import DEFAULTS
    from foc_controller.tuning import SZABO_TABLE2, speed_bandwidth_damping, speed_pi_gains
    from hf_estimator.pll_model import margins
    from motor_params.scaled_loops import scaled_loops

    motor = load_motor(args.motor, "--motor")
    m = motor.nameplate
    if not math.isfinite(m.J_kgm2):
        raise CommandLineError(f"--motor {args.motor}: nameplate.J_kgm2 unknown: no speed loop to tune "
                               f"(`drive commission --rotating` measures it)")
    k_t = 1.5 * m.n_p * m.psi_f_Wb
    requested = args.bandwidth or scaled_loops(m, motor.inverter, 1e-4).speed_bandwidth_rad_s
    zeta = args.damping or DEFAULTS["speed_damping"]
    pll = args.pll_crossover
    source = "--pll-crossover"
    if pll is None:
        from drive_evaluation.pll_check import design_for_motor
        try:
            design = design_for_motor(args.motor, args.estimator, {}, commissioning=args.commissioning)
        except (KeyError, ValueError) as error:
            raise CommandLineError(f"--estimator {args.estimator}: {error.args[0]} "
                                f"(give --pll-crossover)") from None
        pll = margins(design.carrier, *design.current_gains).crossover_rad_s
        source = f"carrier model of `{args.estimator}` with its current gains"
    cap = args.ratio * pll
    omega_n = min(requested, cap)
    try:
        gains = speed_pi_gains(m.J_kgm2, m.B_Nms, k_t, omega_n, zeta)
    except ValueError as error:
        raise CommandLineError(f"--bandwidth: {error}") from None
    report = {"motor": args.motor, "requested_bandwidth_rad_s": requested, "bandwidth_rad_s": omega_n,
              "damping": zeta, "pll_crossover_rad_s": pll, "pll_crossover_from": source,
              "ratio": args.ratio, "limited_by_pll": requested > cap,
              "method": "closed-loop poles of the PI around k_t/(Js + B), current loop ideal: "
                        "k_p = (2ζω_n J − B)/k_t, k_i = ω_n² J/k_t (Szabó ref. [16])",
              "gains": _gains_entry(gains)}
    if args.motor == "szabo_ipmsm":
        table = SZABO_TABLE2["speed"]
        report["table2"] = {**_gains_entry(table), **dict(zip(
            ("bandwidth_rad_s", "damping"), speed_bandwidth_damping(m.J_kgm2, m.B_Nms, k_t, table)))}
    if args.json:
        _print_json(report)
        return 0
    print(f"speed PI on {args.motor}: ω_n {omega_n:.1f} rad/s, ζ {zeta:g} (J {m.J_kgm2:g} kg·m², "
          f"k_t {k_t:.4f} N·m/A)")
    print(f"  PLL crossover {pll:.1f} rad/s ({source}); the speed loop is kept at ≤ {args.ratio:g} × it"
          + (f": the requested {requested:g} rad/s was lowered to {cap:.1f}" if requested > cap else ""))
    g = report["gains"]
    print(f"  A_p {g['A_p']:.4f} A·s/rad  T_i {1e3 * g['T_i_s']:.2f} ms")
    if "table2" in report:
        t = report["table2"]
        print(f"  Table 2: A_p {t['A_p']:.3f}, T_i {1e3 * t['T_i_s']:.0f} ms, which this method gives for "
              f"ω_n {t['bandwidth_rad_s']:.1f} rad/s, ζ {t['damping']:.3f} with the nameplate's J")
    return 0


def cmd_tune_pll(args):
    import math

    from drive_evaluation.pll_check import check_tuning, design_for_motor, largest_loop_filter_for_motor
    from drive_evaluation.plots import plot_pll
    from hf_estimator.pll_model import margins
    from hf_estimator.pll_tuning import MAPPINGS, tuned
    from hf_estimator.synchronous import DEFAULTS as SYNCHRONOUS_DEFAULTS

    given = (("frequency_Hz", args.frequency), ("amplitude_V", args.amplitude), ("u_star", args.u_star),
             ("demodulation", args.demodulation))
    settings = {key: value for key, value in given if value is not None}
    if args.estimator != "synchronous" and (set(settings) - {"frequency_Hz", "amplitude_V"} or args.T_f):
        raise CommandLineError(f"--u-star, --T-f and --demodulation belong to `synchronous`, "
                               f"not `{args.estimator}`")
    if args.T_f == "auto":
        if args.crossover is None:
            raise CommandLineError("--T-f auto: give --crossover (the largest T_f is chosen for it)")
        try:
            settings["T_f_s"] = largest_loop_filter_for_motor(args.motor, settings, args.phase_margin,
                                                              args.crossover, args.model, args.commissioning)
        except ValueError as error:
            raise CommandLineError(f"--crossover: {error}") from None
    elif args.T_f is not None:
        try:
            settings["T_f_s"] = float(args.T_f)
        except ValueError:
            raise CommandLineError(f"--T-f: a time constant in seconds or 'auto', not {args.T_f!r}") from None
    try:
        design = design_for_motor(args.motor, args.estimator, settings, commissioning=args.commissioning)
    except KeyError as error:
        raise CommandLineError(f"--motor/--estimator: {error.args[0]}") from None
    except ValueError as error:
        raise CommandLineError(f"--estimator {args.estimator}: {error}") from None
    models = {"carrier": design.carrier, "szabo": design.szabo}
    if models[args.model] is None:
        raise CommandLineError(f"--model szabo: {MAPPINGS[args.estimator]}")
    A_now, T_now = design.current_gains
    report = {"motor": args.motor, "estimator": args.estimator, "mapping": MAPPINGS[args.estimator],
              "injection": {"frequency_Hz": design.path.omega_h_rad_s / (2.0 * math.pi),
                            "amplitude_V": design.path.u_h_V, "demodulation_amplitude": design.path.u_star},
              "request": {"phase_margin_deg": args.phase_margin, "crossover_rad_s": args.crossover,
                          "model": args.model},
              "T_f_s": settings.get("T_f_s", SYNCHRONOUS_DEFAULTS["T_f_s"]) if args.estimator == "synchronous"
              else None,
              "tuned": {}, "current_gains": {"A_p": A_now, "T_i_s": T_now}}
    for name, loop in models.items():
        if loop is None:
            continue
        try:
            report["tuned"][name] = tuned(loop, args.phase_margin, args.crossover)
        except ValueError as error:
            report["tuned"][name] = {"error": str(error)}
        report["current_gains"][name] = dataclasses.asdict(margins(loop, A_now, T_now))
    if "error" in report["tuned"][args.model]:
        raise CommandLineError(f"--phase-margin/--crossover: {report['tuned'][args.model]['error']}")
    choice = report["tuned"][args.model]
    interrupted = 0
    if args.check:
        from drive_runner.runner import terminal_progress
        report["check"] = []
        try:
            for label, A, T in (("current gains", A_now, T_now), ("tuned gains", choice["A_p"], choice["T_i_s"])):
                for ideal, plant in ((True, "ideal"), (False, "full")):
                    report["check"].append(check_tuning(design, A, T, settings, ideal, args.check_speed_loop,
                                                        terminal_progress(f"closed-loop check, {label}, "
                                                                          f"{plant} plant")))
        except Interrupted as stop:
            interrupted = report["interrupted"] = stop.signum
    if not args.no_plot:
        out = Path(args.out) if args.out else Path("runs") / "tune"
        report["plots"] = plot_pll(design, choice["A_p"], choice["T_i_s"], report.get("check"),
                                   out / f"{load_motor(args.motor, '--motor').name}_{args.estimator}")
    if args.json:
        _print_json(report)
        return _exit_code(interrupted)
    print(f"PLL of `{args.estimator}` on {args.motor}: {report['injection']['frequency_Hz']:g} Hz, "
          f"{report['injection']['amplitude_V']:g} V")
    print(f"  maps onto the model as: {report['mapping']}")
    if report["T_f_s"] is not None:
        print(f"  loop filter T_f {1e3 * report['T_f_s']:.3f} ms")
    rows = [(f"current gains, {m}", A_now, T_now, report["current_gains"][m]) for m in models if models[m]]
    rows += [(f"tuned by the {m} model", t["A_p"], t["T_i_s"], t) for m, t in report["tuned"].items()
             if "error" not in t]
    print(f"  {'':34s} {'A_p':>10s} {'T_i [ms]':>9s} {'crossover':>10s} {'margin':>7s} {'gain margin':>11s}")
    for label, A, T, m in rows:
        print(f"  {label:34s} {A:10.1f} {1e3 * T:9.2f} {m['crossover_rad_s']:10.1f} "
              f"{m['phase_margin_deg']:6.1f}° {m['gain_margin_dB']:8.1f} dB")
    for m, t in report["tuned"].items():
        if "error" in t:
            print(f"  tuned by the {m} model: {t['error']}")
    for check in report.get("check", []):
        print(f"  closed loop, A_p {check['A_p']:.1f}, T_i {1e3 * check['T_i_s']:.2f} ms "
              f"({check['plant']} plant): "
              f"{'bandwidth':>10s} {'peak':>8s} {'crossover':>10s} {'margin':>7s}")
        for label in ("measured", "carrier_model", "szabo_model"):
            if label in check:
                f = check[label]
                print(f"    {label:30s} {f['bandwidth_rad_s']:10.1f} {f['peak_dB']:6.2f} dB "
                      f"{f['crossover_rad_s']:10.1f} {f['phase_margin_deg']:6.1f}°")
    for path in report.get("plots", []):
        print(f"  plot: {path}")
    if interrupted:
        print(f"  closed-loop check interrupted after {len(report['check'])} of 4 runs")
    return _exit_code(interrupted)


def cmd_bench_graph(args):
    from drive_evaluation.bench import graph_throughput
    _duration_arg(args.duration, load_scenario(args.scenario).T_s)
    if args.repeats < 1:
        raise CommandLineError(f"--repeats: must be at least 1, not {args.repeats}")
    report = graph_throughput(args.scenario, args.duration, record=args.record, repeats=args.repeats,
                              progress=None if args.json else print,
                              block_sizes=_block_sizes(args.block_samples))
    if args.json:
        _print_json(report)
    elif report["interrupted"]:
        print("  interrupted: the configuration being timed is not reported")
    return _exit_code(report["interrupted"])


def cmd_bench_blocks(args):
    from drive_evaluation.bench import BLOCK_SCENARIOS, block_size_table
    _duration_arg(args.duration, min(load_scenario(name).T_s for name in BLOCK_SCENARIOS))
    if args.repeats < 1:
        raise CommandLineError(f"--repeats: must be at least 1, not {args.repeats}")
    report = block_size_table(_block_sizes(args.block_samples), duration_s=args.duration, repeats=args.repeats,
                              progress=None if args.json else print)
    if args.json:
        _print_json(report)
    return _exit_code(report["interrupted"])


def _windows_arg(text):
    """The (t0, t1) scoring windows [s] of ``--windows T0:T1[,T0:T1...]`` (None without the option);
    CommandLineError names the option."""
    if not text:
        return None
    windows = []
    for part in text.split(","):
        try:
            t0, t1 = (float(value) for value in part.split(":"))
        except ValueError:
            t0 = t1 = math.nan
        if not (math.isfinite(t0) and math.isfinite(t1) and 0.0 <= t0 < t1):
            raise CommandLineError(f"--windows: T0:T1[,T0:T1...] in seconds with 0 ≤ T0 < T1, not {part!r}")
        windows.append((t0, t1))
    return windows


def _recording_options(parser):
    """The options that supply what a bag does not say (docs/recordings.md)."""
    parser.add_argument("--motor", metavar="PRESET|FILE",
                        help="the motor, for a bag whose drive_config does not name one: a shipped motor or a "
                             "YAML/JSON file of the contract's drive_config motor keys")
    parser.add_argument("--sample-period", type=finite_float, metavar="S",
                        help="the sample period [s], for a bag without drive_config")
    parser.add_argument("--commissioning", metavar="FILE", help=COMMISSIONING_HELP)
    parser.add_argument("--windows", metavar="T0:T1[,T0:T1...]",
                        help="score these intervals [s] (default: the scenario's steady windows, else found "
                             "automatically where the recorded speed is steady)")


def _block_sizes(text):
    """The block sizes of ``--block-samples N[,N...]``; CommandLineError names the option."""
    try:
        sizes = [int(part) for part in text.split(",")]
    except ValueError:
        sizes = []
    if not sizes or any(not 1 <= n <= MAX_BLOCK_SAMPLES for n in sizes):
        raise CommandLineError(f"--block-samples: must be whole numbers from 1 to {MAX_BLOCK_SAMPLES}, "
                               f"comma-separated, not {text!r}")
    return sizes


def _formatted(value, form):
    return "n/a" if value is None else form.format(value)


FULL_SPEED_SCENARIOS = ("wang_full_speed", "szabo_full_speed")


def _band_label(band):
    return f"{100 * band[0]:g}-{100 * band[1]:g} %"


def cmd_bench_full_speed(args):
    from drive_evaluation.speed_range import full_speed_comparison
    from drive_runner.runner import terminal_progress

    reports = []
    try:
        for name in args.scenarios or FULL_SPEED_SCENARIOS:
            scenario = load_scenario(name)
            progress = None if args.json else terminal_progress(scenario.name)
            reports.append(full_speed_comparison(scenario, progress))
    except Interrupted as stop:
        if args.json:
            _print_json({"benchmark": "full-speed", "results": reports, "interrupted": True})
        return _exit_code(stop.signum)
    if args.json:
        _print_json({"benchmark": "full-speed", "results": reports})
        return 0
    for report in reports:
        print(f"{report['scenario']} ({report['motor']}, {report['duration_s']:g} s); angle error RMS / peak "
              f"[rad el.] and HF current RMS [A] per |speed| band (share of rated)")
        bands = [_band_label(b["band"]) for b in report["runs"][0]["bands"]]
        print(f"  {'estimator':16s} {'loop':8s} {'whole run':>15s} {'targets':>8s} "
              + " ".join(f"{b:>22s}" for b in bands))
        for run in report["runs"]:
            whole = (f"{_formatted(run['angle_error_rms'], '{:.4f}')} / "
                     f"{_formatted(run['angle_error_peak'], '{:.3f}')}")
            kept = {True: "kept", False: "missed", None: "-"}[run.get("meets_targets")]
            cells = [f"{_formatted(b.get('angle_error_rms'), '{:.4f}')} / "
                     f"{_formatted(b.get('angle_error_peak'), '{:.3f}')} "
                     f"{_formatted(b.get('hf_current_rms_A'), '{:.2f}')}"
                     for b in run["bands"]]
            print(f"  {run['estimator']:16s} {run['loop'].split(',')[0]:8s} {whole:>15s} {kept:>8s} "
                  + " ".join(f"{c:>22s}" for c in cells))
    return 0


def cmd_bench_injection_cost(args):
    from drive_evaluation.speed_range import injection_cost
    from drive_runner.runner import terminal_progress

    names = _estimator_list(args.estimators) if args.estimators else [n for n in estimator_names() if injects(n)]
    scenario = load_scenario(args.scenario)
    progress = None if args.json else terminal_progress(scenario.name)
    try:
        report = injection_cost(scenario, names, progress)
    except Interrupted as stop:
        return _exit_code(stop.signum)
    if args.json:
        _print_json({"benchmark": "injection-cost", **report})
        return 0
    print(f"{report['scenario']} ({report['motor']}): what the injection costs over the steady windows")
    print(f"  {'estimator':28s} {'U_h [V]':>8s} {'HF RMS [A]':>11s} {'P_cu,HF [W]':>12s} {'RMS [rad]':>10s} "
          f"{'peak [rad]':>11s} {'targets':>8s}")
    for row in report["estimators"] + report["sweep"]:
        print(f"  {row['estimator']:28s} {_formatted(row['amplitude_V'], '{:.2f}'):>8s} "
              f"{row['hf_current_rms_A']:11.3f} {row['hf_copper_loss_W']:12.4f} "
              f"{_formatted(row['angle_error_rms'], '{:.4f}'):>10s} "
              f"{_formatted(row['angle_error_peak'], '{:.3f}'):>11s} "
              f"{'kept' if row['meets_targets'] else 'missed':>8s}")
    least = report["least_amplitude_V"]
    print(f"  least amplitude keeping the targets (ours): {_formatted(least, '{:g} V')}")
    return 0


def cmd_bench_motor(args):
    from drive_evaluation.motor_bench import motor_bench
    from drive_runner.runner import terminal_progress

    if args.angles < 1:
        raise CommandLineError(f"--angles: must be at least 1, not {args.angles}")
    _sample_period_arg(args.sample_period)
    motors = [load_motor(m, "drive bench motor") for m in args.motors]
    reports = []
    try:
        for motor in motors:
            progress = None if args.json else terminal_progress(motor.name)
            reports.append(motor_bench(motor, args.angles, progress, args.sample_period))
    except Interrupted as stop:
        if args.json:
            _print_json({"benchmark": "motor", "results": reports, "interrupted": True})
        return _exit_code(stop.signum)
    if args.json:
        _print_json({"benchmark": "motor", "angles": args.angles, "sample_period_s": args.sample_period,
                     "results": reports})
        return 0
    for r in reports:
        errors = ", ".join(f"{k} {100.0 * v:+.2f} %" for k, v in r["commissioning_error"].items())
        print(f"{r['motor']}: {r['description'] or r['file']}")
        if r.get("refused"):
            print(f"  commissioned (against the plant's truth): {errors}")
            print(f"  REFUSED {r['refused']}")
            continue
        s = r["startup"]
        print(f"  commissioned (against the plant's truth): {errors}; current limit {r['current_limit_A']:.3g} A")
        print(f"  loops: tracking {r['tracking_bandwidth_Hz']:.3g} Hz, carrier {r['injection_frequency_Hz']:.4g} Hz, "
              f"{r['injection_amplitude_V']:.3g} V")
        for line in r["warnings"]:
            print(f"  WARNING {line}")
        fraction = s["polarity_correct_fraction"]
        print(f"  start-up over {s['runs']} angles: polarity "
              f"{_formatted(None if fraction is None else 100.0 * fraction, '{:.1f} %')}, "
              f"lock lost {s['lock_lost']}, not started {s['not_started']}")
        for c in r["cases"]:
            print(f"  {c['case']:24s} RMS {c['angle_error_rms']:.4f} rad  peak {c['angle_error_peak']:.3f} rad  "
                  f"speed tracking {c['speed_tracking_error_rms']:.3g} rad/s  {c['verdict']}")
    return 0


def cmd_bench_startup(args):
    from drive_evaluation.startup_bench import MOTOR_SCENARIOS, STANDARD_CASES, LoadCase, bench_scenario, startup_sweep
    from drive_runner.runner import scenario_commissioning, terminal_progress

    _estimator_arg(args)
    if args.angles < 1:
        raise CommandLineError(f"--angles: must be at least 1, not {args.angles}")
    if args.seeds < 1:
        raise CommandLineError(f"--seeds: must be at least 1, not {args.seeds}")
    motors = [load_motor(args.motor, "--motor")] if args.motor else [load_motor(m) for m in sorted(MOTOR_SCENARIOS)]
    cases = STANDARD_CASES
    if args.load is not None:
        if not 0.0 <= args.load <= 1.5:
            raise CommandLineError(f"--load: a fraction of rated torque in [0, 1.5], not {args.load}")
        name = f"{args.load:g} rated{', brake' if args.brake else ', active'}{', ff' if args.feedforward else ''}"
        cases = (LoadCase(name, args.load, args.brake, args.feedforward),)
    reports = []
    try:
        for motor in motors:
            first = bench_scenario(motor, args.estimator, 0.0, 1, cases[0])
            _warn_if_nameplate_only(scenario_commissioning(first).source, motor.name,
                                    MOTOR_SCENARIOS.get(motor.name, f"wang_100rpm --motor {motor.source}"))
            for case in cases:
                progress = None if args.json else terminal_progress(f"{motor}, {case.name}")
                reports.append(startup_sweep(motor, case, args.angles, tuple(range(1, args.seeds + 1)),
                                             args.estimator, progress))
    except Interrupted as stop:
        if args.json:
            _print_json({"benchmark": "startup", "results": reports, "interrupted": True})
        return _exit_code(stop.signum)
    if args.json:
        _print_json({"benchmark": "startup", "angles": args.angles, "seeds": args.seeds, "results": reports})
        return 0
    print(f"{'motor':12s} {'load':20s} {'runs':>5s} {'polarity':>9s} {'|err| max':>10s} {'back max':>9s} "
          f"{'start max':>10s} {'lost':>5s} {'no start':>9s}")
    for r in reports:
        fraction, duration = r["polarity_correct_fraction"], r["duration_max_s"]
        cells = (_formatted(None if fraction is None else 100.0 * fraction, "{:.1f} %"),
                 _formatted(r["angle_error_max_e_rad"], "{:.3f} rad"),
                 _formatted(r["reverse_rotation_max_m_deg"], "{:.2f}°"),
                 _formatted(None if duration is None else 1e3 * duration, "{:.1f} ms"))
        print(f"{r['motor']:12s} {r['case']:20s} {r['runs']:5d} {cells[0]:>9s} {cells[1]:>10s} {cells[2]:>9s} "
              f"{cells[3]:>10s} {r['lock_lost']:5d} {r['not_started']:9d}")
    return 0


def cmd_bench(args):
    from drive_evaluation.bench import motulator_python, motulator_throughput, throughput

    for flag, value in (("--samples", args.samples), ("--repeats", args.repeats)):
        if value < 1:
            raise CommandLineError(f"{flag}: must be at least 1, not {value}")
    names = args.estimators.split(",") if args.estimators else estimator_names()
    for name in names:
        if name not in estimator_names():
            raise CommandLineError(f"--estimators: unknown estimator '{name}' "
                                f"(known: {', '.join(estimator_names())})")
    results = []
    for name in names:
        if not args.json:
            print(f"  {name:14s} ...", end="", flush=True)
        r = throughput(name, samples=args.samples, repeats=args.repeats)
        results.append(r)
        if not args.json:
            print(f"\r  {name:14s} {r['samples_per_second']:12,.0f} samples/s "
                  f"(best of {r['repeats']} × {r['samples']} samples; median "
                  f"{r['samples_per_second_median']:,.0f})")
    report = {"benchmark": "throughput", "results": results,
              "samples_per_second": {r["estimator"]: r["samples_per_second"] for r in results}}
    python = None if args.no_motulator else motulator_python()
    if python:
        if not args.json:
            print("  motulator 2.2-kW PMSM signal-injection example ...", end="", flush=True)
        reference = motulator_throughput(python)
        report["motulator"] = reference
        if "error" not in reference:
            report["ratio_to_motulator"] = {r["estimator"]: r["samples_per_second"]
                                            / reference["samples_per_second"] for r in results}
        if not args.json:
            if "error" in reference:
                print(f"\r  motulator: not timed ({reference['error']})")
            else:
                print(f"\r  motulator      {reference['samples_per_second']:12,.0f} samples/s "
                      f"({reference['samples']} samples in {reference['wall_time_s']:.2f} s, {python})")
                for name, ratio in report["ratio_to_motulator"].items():
                    print(f"  {name:14s} {ratio:12,.0f} × motulator")
    elif not args.json:
        print("  motulator: not installed (./setup.sh --with-motulator, or DRIVE_MOTULATOR_PYTHON)")
    if args.json:
        _print_json(report)
    return 0


def build_parser():
    parser = OneLineParser(prog="drive", description="Sensorless PMSM drive stack.")
    sub = parser.add_subparsers(dest="command", required=True)

    run = sub.add_parser("run", help="run a scenario in one process, print metrics, write plots")
    run.add_argument("scenario", help="shipped scenario name (see 'drive scenarios') or YAML path")
    run.add_argument("--estimator", help="override the scenario's estimator")
    run.add_argument("--motor", metavar="NAME|FILE", help=MOTOR_HELP)
    run.add_argument("--duration", type=finite_float, help="override the duration [s]")
    run.add_argument("--commissioning", metavar="FILE", help=COMMISSIONING_HELP)
    run.add_argument("--block-samples", type=int, metavar="N",
                     help="override the scenario's block_samples: data in blocks of N samples, the command "
                          "acting N − 1 periods later (docs/architecture.md)")
    run.add_argument("--answer-periods", type=int, metavar="P",
                     help="periods the host has from a block's last sample to its first command acting "
                          "(default: the inverter's 1; docs/architecture.md)")
    run.add_argument("--out", help="plot directory (default runs/SCENARIO)")
    run.add_argument("--no-plot", action="store_true", help="skip the PNG plot")
    run.add_argument("--record", metavar="BAG",
                     help="write the run as a rosbag2/MCAP bag into this new directory")
    run.add_argument("--json", action="store_true", help="print the metrics as JSON")
    run.set_defaults(func=cmd_run)

    for name, func, text in (("scenarios", cmd_scenarios, "list shipped scenarios"),
                             ("estimators", cmd_estimators, "list estimators"),
                             ("presets", cmd_presets, "motor presets: the nameplate the drive is told beside the "
                                                      "simulated plant's truth, and the assumptions")):
        p = sub.add_parser(name, help=text)
        p.add_argument("--json", action="store_true")
        p.set_defaults(func=func)

    motor = sub.add_parser("motor", help="motor files: a commented template; what the drive makes of a motor")
    motor_sub = motor.add_subparsers(dest="motor_command", required=True)
    template = motor_sub.add_parser("template", help="print a commented motor file (drive motor template > m.yaml)")
    template.set_defaults(func=cmd_motor_template)
    show = motor_sub.add_parser("show", help="a motor's nameplate, inverter and the loops scaled to it")
    show.add_argument("motor", metavar="NAME|FILE")
    show.add_argument("--sample-period", type=finite_float, default=1e-4, metavar="S", help="sampling period [s]")
    show.add_argument("--json", action="store_true")
    show.set_defaults(func=cmd_motor_show)

    commission = sub.add_parser("commission", help="measure the scenario's motor at standstill, shaft held "
                                                   "(R_s, dead time, current sensors, L_dh, L_qh, saliency shift) "
                                                   "and write its commissioning file")
    commission.add_argument("scenario", help="shipped scenario name or YAML path (its motor and plant)")
    commission.add_argument("--motor", metavar="NAME|FILE", help=MOTOR_HELP)
    commission.add_argument("--out", help="file to write (default commissioning/MOTOR.yaml)")
    commission.add_argument("--force", action="store_true", help="replace an existing file")
    commission.add_argument("--link", choices=("pty", "can"),
                            help="through the bridge: the virtual inverter behind this link")
    commission.add_argument("--graph", action="store_true",
                            help="through the ROS graph (plant node, or with --link the drive_bridge node, and "
                                 "the drive_commissioning node)")
    commission.add_argument("--namespace", default=DEFAULT_NAMESPACE, help="the graph's namespace (--graph)")
    commission.add_argument("--rotating", action="store_true",
                            help="then the rotating test (shaft free, unloaded): the drive spins it and measures "
                                 "ψ_f and J (docs/commissioning.md)")
    commission.add_argument("--json", action="store_true")
    commission.set_defaults(func=cmd_commission)

    bench = sub.add_parser("bench", help="benchmarks")
    bench_sub = bench.add_subparsers(dest="bench", required=True)
    tp = bench_sub.add_parser("throughput", help="closed-loop samples/s in one process, per estimator")
    tp.add_argument("--estimators", help="comma-separated (default: all)")
    tp.add_argument("--samples", type=int, default=1_000_000)
    tp.add_argument("--repeats", type=int, default=3, help="timed runs per estimator (best reported)")
    tp.add_argument("--no-motulator", action="store_true",
                    help="skip timing motulator's signal-injection example")
    tp.add_argument("--json", action="store_true")
    tp.set_defaults(func=cmd_bench)
    graph = bench_sub.add_parser("graph", help="real-time factor of the lock-step ROS graph at the "
                                               "scenario's sampling rate, composed and separate")
    graph.add_argument("--scenario", default="wang_100rpm")
    graph.add_argument("--duration", type=finite_float, default=0.5, help="simulated seconds per run")
    graph.add_argument("--record", action="store_true", help="also record every per-sample topic")
    graph.add_argument("--block-samples", default="1", metavar="N[,N...]",
                       help="block sizes to time (samples per message; default 1)")
    graph.add_argument("--repeats", type=int, default=2, help="timed runs per configuration (best kept)")
    graph.add_argument("--json", action="store_true")
    graph.set_defaults(func=cmd_bench_graph)
    blocks = bench_sub.add_parser("blocks", help="per block size: the graph's real-time factor (composed, "
                                                 "separate) and ours' angle error on the four Wang scenarios")
    blocks.add_argument("--block-samples", default="1,5,10,20", metavar="N[,N...]")
    blocks.add_argument("--duration", type=finite_float, default=0.5, help="simulated seconds per graph run")
    blocks.add_argument("--repeats", type=int, default=2, help="timed graph runs per configuration")
    blocks.add_argument("--json", action="store_true")
    blocks.set_defaults(func=cmd_bench_blocks)
    bench_bridge = bench_sub.add_parser("bridge", help="sustained closed-loop sample rate and command "
                                                       "latency through the bridge, over a pty and a CAN bus")
    bench_bridge.add_argument("--scenario", default="wang_100rpm")
    bench_bridge.add_argument("--duration", type=finite_float,
                              help="simulated seconds per run (default 1, or the whole scenario with --paced)")
    bench_bridge.add_argument("--links", default="pty,can", help="comma-separated: pty, can")
    bench_bridge.add_argument("--repeats", type=int, default=3, help="timed runs per link (best kept)")
    bench_bridge.add_argument("--paced", action="store_true",
                              help="the inverter on its own clock, never waiting: late commands, latency, angle error")
    bench_bridge.add_argument("--block-samples", type=int, metavar="N",
                              help=f"samples per frame (default: the scenario's; {PACED_BLOCK_SAMPLES} with --paced)")
    bench_bridge.add_argument("--graph", action="store_true",
                              help="with --paced: through the ROS graph as `drive launch --link L --paced` runs it "
                                   "(per run: late periods, watchdog trips, lock, latency in µs and hops)")
    bench_bridge.add_argument("--load", action="store_true",
                              help="with --graph: another process keeps one core busy meanwhile")
    bench_bridge.add_argument("--levers", metavar="L[,L...]",
                              help="with --graph: soft real-time levers, measured one at a time: plain, collector "
                                   "(default), collector+cpu1, collector+fifo, collector+fifo+cpu1")
    bench_bridge.add_argument("--json", action="store_true")
    bench_bridge.set_defaults(func=cmd_bench_bridge)

    startup = bench_sub.add_parser("startup", help="start-up from rotor angles over the electrical circle, noise "
                                                   "seeds and loads: polarity, error at first torque, roll-back")
    startup.add_argument("--motor", metavar="NAME|FILE", help="one motor: shipped or a motor file (default: both "
                                                               "shipped)")
    startup.add_argument("--angles", type=int, default=72, help="start angles over the electrical circle")
    startup.add_argument("--seeds", type=int, default=3, help="noise seeds 1..S per angle")
    startup.add_argument("--load", type=finite_float, help="one case: this fraction of rated load, opposing the "
                                                    "command (default: the three standard cases)")
    startup.add_argument("--brake", action="store_true", help="with --load: held by a brake until first torque")
    startup.add_argument("--feedforward", action="store_true",
                         help="with --load: the robot tells the drive the load's torque (torque_feedforward)")
    startup.add_argument("--estimator", help="an injecting estimator (default: injection_frame)")
    startup.add_argument("--json", action="store_true")
    startup.set_defaults(func=cmd_bench_startup)

    motor_bench = bench_sub.add_parser("motor", help="motors nobody tuned for: commissioned from the nameplate, "
                                                     "start-up polarity, rated load, a speed step, a reversal and "
                                                     "a load step at 5 %% rated speed on the loops scaled to each")
    motor_bench.add_argument("motors", nargs="+", metavar="NAME|FILE", help="shipped motors or motor files")
    motor_bench.add_argument("--angles", type=int, default=24, help="start angles over the electrical circle")
    motor_bench.add_argument("--sample-period", type=finite_float, default=1e-4, metavar="S",
                             help="the drive's sampling period [s] (default 1e-4)")
    motor_bench.add_argument("--json", action="store_true")
    motor_bench.set_defaults(func=cmd_bench_motor)

    full = bench_sub.add_parser("full-speed", help="the whole speed range: the blended estimator, injection only "
                                                   "and the observer only, angle error and HF current per speed band")
    full.add_argument("scenarios", nargs="*", help=f"scenarios (default: {', '.join(FULL_SPEED_SCENARIOS)})")
    full.add_argument("--json", action="store_true")
    full.set_defaults(func=cmd_bench_full_speed)
    cost = bench_sub.add_parser("injection-cost", help="HF current RMS and its copper loss per estimator at low "
                                                       "speed; the least amplitude that keeps ours' targets")
    cost.add_argument("--scenario", default="wang_100rpm")
    cost.add_argument("--estimators", help="comma-separated (default: every injecting estimator)")
    cost.add_argument("--json", action="store_true")
    cost.set_defaults(func=cmd_bench_injection_cost)

    compare = bench_sub.add_parser("compare", help="two recorded runs side by side: metrics and angle error")
    compare.add_argument("bag_a")
    compare.add_argument("bag_b")
    _recording_options(compare)
    compare.add_argument("--out", help="plot directory (default runs/compare)")
    compare.add_argument("--no-plot", action="store_true")
    compare.add_argument("--json", action="store_true")
    compare.set_defaults(func=cmd_bench_compare)

    rp = bench_sub.add_parser("replay",
                              help="estimators on a recording's currents, scored against its ground truth")
    rp.add_argument("bag", help="a bag, a directory of bags or a glob (a corpus: one summary per estimator)")
    rp.add_argument("--estimators", help="comma-separated (default: all)")
    _recording_options(rp)
    rp.add_argument("--out", help="directory for angle_error.png and replay.json (default runs/replay/BAG; a "
                                  "corpus writes replay_corpus.json only with --out)")
    rp.add_argument("--no-plot", action="store_true")
    rp.add_argument("--json", action="store_true")
    rp.set_defaults(func=cmd_bench_replay)

    tune = sub.add_parser("tune", help="controller tuning from models")
    tune_sub = tune.add_subparsers(dest="tune", required=True)
    pll = tune_sub.add_parser("pll", help="PI of a pulsating-injection estimator's PLL from Szabó's model "
                                          "(§2.4) and our carrier model, with a closed-loop check")
    pll.add_argument("--motor", default="szabo_ipmsm", metavar="NAME|FILE",
                     help="motor preset (its commissioned R_s, L_dh, L_qh)")
    pll.add_argument("--commissioning", metavar="FILE", help=COMMISSIONING_HELP)
    pll.add_argument("--estimator", default="synchronous", choices=PLL_ESTIMATORS)
    pll.add_argument("--model", default="carrier", choices=("carrier", "szabo"),
                     help="model the tuned gains come from (both are reported)")
    pll.add_argument("--phase-margin", type=finite_float, default=60.0, help="[deg]")
    pll.add_argument("--crossover", type=finite_float, help="[rad/s] (default: the highest reaching the margin "
                                                     "with the PI zero a decade below)")
    pll.add_argument("--frequency", type=finite_float, help="injection frequency [Hz] (default: the estimator's)")
    pll.add_argument("--amplitude", type=finite_float, help="injection amplitude [V] (default: the estimator's)")
    pll.add_argument("--u-star", type=finite_float, help="synchronous: demodulation amplitude u* (default 1)")
    pll.add_argument("--T-f", help="synchronous: loop filter time constant [s] (default 0.53 ms), or 'auto': "
                                   "the largest reaching --crossover at --phase-margin")
    pll.add_argument("--demodulation", choices=("paper", "aligned"),
                     help="synchronous: demodulation carrier as the paper, or turned by the sampled "
                          "current's phase lag (ours)")
    pll.add_argument("--check", action="store_true",
                     help="measure the closed loop in the runner with the current and the tuned gains, on "
                          "the ideal plant (no dead time or sensor errors: the models' assumptions) and the "
                          "full one")
    pll.add_argument("--check-speed-loop", choices=("off", "rule", "table2"), default="off",
                     help="speed loop during the check: 1 rad/s (the PLL alone), the controller's rule, or "
                          "Szabó's Table 2 cascade")
    pll.add_argument("--out", help="plot directory (default runs/tune)")
    pll.add_argument("--no-plot", action="store_true")
    pll.add_argument("--json", action="store_true")
    pll.set_defaults(func=cmd_tune_pll)
    current = tune_sub.add_parser("current", help="d/q current PI gains from a bandwidth and damping")
    current.add_argument("--motor", default="szabo_ipmsm", metavar="NAME|FILE",
                         help="a shipped motor or a motor file (nameplate R, L_d, L_q)")
    current.add_argument("--bandwidth", type=finite_float, help="closed-loop ω_n [rad/s] (default 2π·250)")
    current.add_argument("--damping", type=finite_float, help="ζ (default 0.8)")
    current.add_argument("--axis", choices=("d", "q", "both"), default="both")
    current.add_argument("--json", action="store_true")
    current.set_defaults(func=cmd_tune_current)
    speed = tune_sub.add_parser("speed",
                                help="speed PI gains from a bandwidth and damping, kept below the PLL")
    speed.add_argument("--motor", default="szabo_ipmsm", metavar="NAME|FILE",
                       help="a shipped motor or a motor file (J, B, k_t)")
    speed.add_argument("--bandwidth", type=finite_float, help="closed-loop ω_n [rad/s] (default: scaled to the motor, "
                                                       "40 for the shipped ones)")
    speed.add_argument("--damping", type=finite_float, help="ζ (default 1)")
    speed.add_argument("--estimator", default="synchronous", choices=PLL_ESTIMATORS,
                       help="whose PLL crossover (carrier model, current gains) bounds the speed loop")
    speed.add_argument("--commissioning", metavar="FILE", help=COMMISSIONING_HELP)
    speed.add_argument("--pll-crossover", type=finite_float, help="[rad/s] instead of the estimator's model")
    speed.add_argument("--ratio", type=finite_float, default=0.25, help="speed bandwidth ≤ ratio × PLL crossover")
    speed.add_argument("--json", action="store_true")
    speed.set_defaults(func=cmd_tune_speed)

    launch = sub.add_parser("launch", help="run a scenario through the ROS 2 graph (nodes over topics)")
    launch.add_argument("scenario", help="shipped scenario name or YAML path")
    launch.add_argument("--estimator", help="override the scenario's estimator")
    launch.add_argument("--motor", metavar="NAME|FILE", help=MOTOR_HELP)
    launch.add_argument("--duration", type=finite_float, help="override the duration [s]")
    launch.add_argument("--commissioning", metavar="FILE", help=COMMISSIONING_HELP)
    launch.add_argument("--block-samples", type=int, metavar="N",
                        help="override the scenario's block_samples: the per-sample topics travel in blocks of N "
                             f"(docs/ros-graph.md; {PACED_BLOCK_SAMPLES} with --link and --paced)")
    launch.add_argument("--processes", choices=("composed", "separate"), default="composed",
                        help="nodes in this process (default) or one process per node")
    launch.add_argument("--executor", choices=EXECUTORS, default="events",
                        help="events (rclpy.experimental.EventsExecutor, default) or single (fallback)")
    launch.add_argument("--namespace", default=DEFAULT_NAMESPACE)
    launch.add_argument("--timeout", type=finite_float, default=1.0, help="lock-step answer timeout [s]")
    launch.add_argument("--out", help="plot directory (default runs/SCENARIO)")
    launch.add_argument("--no-plot", action="store_true")
    launch.add_argument("--record", metavar="BAG",
                        help="record every drive topic into this new rosbag2 directory")
    launch.add_argument("--link", choices=("pty", "can"),
                        help="put the virtual inverter (behind this link) and the drive_bridge node in the "
                             "plant's place")
    launch.add_argument("--paced", action="store_true",
                        help="with --link: the virtual inverter on its own clock at the sampling rate, never "
                             "waiting for the graph: a late command is zero volts, counted")
    add_scheduling_arguments(launch)
    launch.add_argument("--json", action="store_true")
    launch.set_defaults(func=cmd_launch)

    bridge = sub.add_parser("bridge", help="the sensorless loop through the inverter bridge and the virtual "
                                           "inverter, in one process")
    bridge.add_argument("scenario", help="shipped scenario name or YAML path")
    bridge.add_argument("--link", choices=("pty", "can"), default="pty")
    bridge.add_argument("--paced", action="store_true",
                        help="the inverter on its own clock at the sampling rate, never waiting for the host: a "
                             "late command is zero volts, counted")
    bridge.add_argument("--block-samples", type=int, metavar="N",
                        help=f"samples per frame (default: the scenario's; {PACED_BLOCK_SAMPLES} with --paced)")
    bridge.add_argument("--estimator", help="override the scenario's estimator")
    bridge.add_argument("--motor", metavar="NAME|FILE", help=MOTOR_HELP)
    bridge.add_argument("--duration", type=finite_float, help="override the duration [s]")
    bridge.add_argument("--commissioning", metavar="FILE", help=COMMISSIONING_HELP)
    bridge.add_argument("--out", help="plot directory (default runs/SCENARIO)")
    bridge.add_argument("--no-plot", action="store_true")
    bridge.add_argument("--json", action="store_true")
    bridge.set_defaults(func=cmd_bridge)

    echo = sub.add_parser("echo", help="print a drive topic (like ros2 topic echo)")
    echo.add_argument("topic", help="contract topic, e.g. angle_error, joint_states, /diagnostics")
    echo.add_argument("--namespace", default=DEFAULT_NAMESPACE)
    echo.add_argument("--count", type=int, help="stop after this many printed messages")
    echo.add_argument("--every", type=int, default=1, help="print every N-th message")
    echo.add_argument("--timeout", type=finite_float, help="stop after this many seconds")
    echo.add_argument("--json", action="store_true", help="one JSON object per line")
    echo.set_defaults(func=cmd_echo)

    bag = sub.add_parser("bag", help="recordings (rosbag2 directories with MCAP storage)")
    bag_sub = bag.add_subparsers(dest="bag_command", required=True)
    info = bag_sub.add_parser("info", help="topics, types, counts, duration (like ros2 bag info)")
    info.add_argument("bag")
    info.add_argument("--json", action="store_true")
    info.set_defaults(func=cmd_bag_info)
    reindex = bag_sub.add_parser("reindex", help="make a cut recording (killed recorder) a complete bag")
    reindex.add_argument("bag")
    reindex.add_argument("--force", action="store_true", help="also when metadata.yaml exists (a cut .mcap)")
    reindex.add_argument("--json", action="store_true")
    reindex.set_defaults(func=cmd_bag_reindex)
    return parser


def _remedy(error, args):
    """What the user can do about a domain error, in the command line's words."""
    from drive_bags.common import BagCompleteError, BagCutError
    if isinstance(error, BagCutError):
        force = " --force" if (Path(error.path) / "metadata.yaml").exists() else ""
        return f"; `drive bag reindex {error.path}{force}` rebuilds it"
    if isinstance(error, BagCompleteError):
        return "; --force rebuilds it anyway"
    from drive_launch.launcher import NamespaceOccupiedError
    if isinstance(error, NamespaceOccupiedError):
        return " (--namespace NAME)"
    return ""


def main(argv=None):
    args = build_parser().parse_args(argv)
    try:
        with interrupt.handled():
            code = args.func(args)
            if interrupt.requested() and code < EXIT_SIGNAL_BASE:
                raise Interrupted(interrupt.requested())
            return code
    except DriveError as error:
        text = " ".join(f"{error}{_remedy(error, args)}".split())
        print(f"drive: {text}", file=sys.stderr)
        return EXIT_REFUSED
    except Interrupted as stop:
        print(f"drive: {args.command}: interrupted by {stop}", file=sys.stderr)
        return EXIT_SIGNAL_BASE + stop.signum
    except BrokenPipeError:
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_READER_GONE
    except OSError as error:
        print(f"drive: {_os_error_line(error)}", file=sys.stderr)
        return EXIT_REFUSED


def _os_error_line(error):
    """An OS error as one line naming the file (an unwritable working directory, a full disk)."""
    where = error.filename or "output"
    return f"{where}: cannot be written ({error.strerror or error})"


if __name__ == "__main__":
    sys.exit(main())
