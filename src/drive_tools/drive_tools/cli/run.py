"""``drive run``, ``launch``, ``bridge``: a scenario's drive in one process, over the ROS graph, or through
the inverter bridge; ``drive scenarios`` and ``drive estimators`` list what they run."""
import argparse
import dataclasses
import sys
from pathlib import Path

from drive_common.config.scenario import (
    PACED_BLOCK_SAMPLES,
    behind_an_inverter,
    link_block_samples,
    load_scenario,
    scenario_names,
)
from drive_common.contract.graph import DEFAULT_NAMESPACE, EXECUTORS
from drive_common.runtime.interrupt import Interrupted
from drive_common.runtime.realtime import ROBOT_RT_PRIORITY, add_scheduling_arguments
from hf_estimator.registry import describe, estimator_names, plugin_errors

from .options import (
    COMMISSIONING_HELP,
    MOTOR_HELP,
    UNSET,
    CommandLineError,
    answer_argument,
    answer_options,
    block_sizes,
    duration_arg,
    estimator_arg,
    finite_float,
    motor_reference,
    os_error_line,
    print_json,
    record_arg,
    robot_real_time,
    scenario_arg,
    warn_if_nameplate_only,
)
from .outcome import node_fault_line, not_following, not_tracking, outcome, output_failed, say_reason, tripped


def cmd_run(args):
    from drive_tools.evaluation.above_speed_bench import stated_before_run
    from drive_tools.runner.runner import run_scenario, terminal_progress

    scenario = scenario_arg(args)
    record_arg(args.record)
    for line in filter(None, (stated_before_run(scenario),)):
        print(f"drive: {line}", file=sys.stderr)
    result = run_scenario(scenario, progress=terminal_progress(f"{scenario.name}/{scenario.estimator}"))
    interrupted = result.interrupted
    extra, recording_error = {"interrupted": bool(interrupted)}, None
    if args.record:
        from drive_tools.bags.common import BagWriteError
        from drive_tools.bags.writer import write_run_bag
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

    def judge(metrics):
        return outcome(interrupted, output_error=output_failed(recording_error, metrics.get("plot_error")),
                       not_tracking=not_tracking(result, metrics), not_following=not_following(metrics),
                       tripped=tripped(metrics))
    return _report(result, args, extra, judge)


def _report(result, args, extra, judge):
    """Print a run's report (drive run, launch, bridge) or its JSON, its plot written unless --no-plot, with
    its ``outcome`` (exit code and reason) from ``judge(metrics)`` (options.outcome); the reason of a non-zero
    exit said on stderr after it. Returns the exit code."""
    from drive_common.motor.commissioning import NAMEPLATE_ONLY
    from drive_tools.evaluation.run_report import run_lines, run_report

    scenario = result.scenario
    metrics = run_report(result)
    if result.commissioning is not None and scenario.commissioning != NAMEPLATE_ONLY:
        warn_if_nameplate_only(result.commissioning.source, scenario.motor.name, scenario.name)
    metrics.update(extra)
    if not args.no_plot and result.log.shape[0]:
        from drive_tools.evaluation.plots import plot_run  # matplotlib: imported only to plot
        out_dir = Path(args.out) if args.out else Path("runs") / scenario.name
        try:
            metrics["plots"] = [str(plot_run(result, out_dir, args.command))]
        except OSError as error:
            metrics["plot_error"] = os_error_line(error)
    code, reason = judge(metrics)
    metrics["outcome"] = {"exit_code": code, "reason": reason}
    if args.json:
        print_json(metrics)
    else:
        print("\n".join(run_lines(metrics, extra)))
    if code:
        say_reason(reason)
    return code


def cmd_launch(args):
    from drive_tools.launch.launcher import DriveSpec, GraphOptions, RealTime, launch, missing_samples_line
    from drive_tools.runner.runner import terminal_progress

    estimator_arg(args)
    scenario = load_scenario(args.scenario, estimator_override=args.estimator,
                             override_source="command line --estimator", motor_override=args.motor,
                             motor_source="--motor")
    record_arg(args.record)
    if args.paced and not args.link:
        raise CommandLineError("--paced: needs --link pty|can (the virtual inverter is what keeps the clock)")
    robot_real_time(args)
    extra = {"commissioning": args.commissioning} if args.commissioning else {}
    if args.motor:
        extra["motor_file"] = motor_reference(args.motor)
    blocks = link_block_samples(args.paced, args.block_samples)
    if blocks is not None:
        extra["block_samples"] = block_sizes(str(blocks))[0]
    duration_arg(args.duration, scenario.T_s, extra.get("block_samples") or scenario.block_samples)
    if args.link:
        from drive_bridge.inverter_protocol import MAX_BLOCK
        behind_an_inverter(dataclasses.replace(scenario, block_samples=blocks or scenario.block_samples), MAX_BLOCK)
    drive = DriveSpec(args.scenario, args.namespace, args.estimator, args.duration, extra or None, args.record,
                      args.link, args.paced)
    real_time = RealTime(args.rt_priority, args.cpus, args.workqueue_cpus, args.cpu_dma_latency_us)
    options = GraphOptions(args.processes, args.executor, timeout_s=args.timeout, intra_process=args.intra_process,
                           real_time=real_time, answer=answer_options(args))
    result = launch(drive, options, terminal_progress(f"{scenario.name}/{scenario.estimator} over ROS"))
    for line in result.scheduling["refused"]:
        print(f"drive: warning: {line}", file=sys.stderr)
    faults = result.node_faults
    plant = f"virtual inverter over {args.link} + drive_bridge" if args.link else "pmsm_plant"
    intra = {"compiled": ", the drive's answer compiled whole on its own thread (estimator and controller not "
                         "nodes)"}.get(args.answer, ", the controller taking the estimator's answers directly"
                                       if args.intra_process else "")
    extra = {"graph": f"{args.processes} processes, {args.executor} executor, namespace {args.namespace}, "
                      f"{plant}{intra}",
             "real_time_factor": round(result.scenario.duration_s / result.wall_time_s, 4)
             if result.wall_time_s > 0 else None,
             "interrupted": bool(result.interrupted), "node_faults": faults, "scheduling": result.scheduling,
             "answer": result.answer}
    if result.timing:
        extra["timing"] = result.timing
    if args.record:
        extra["bag"] = args.record
    if result.recording_error:
        extra["recording_error"] = result.recording_error
    lost = missing_samples_line(result.missing_samples)
    if lost:
        extra["missing_samples"] = result.missing_samples
        if faults:
            print(f"drive: warning: {lost}", file=sys.stderr)
    lost_on_the_way = lost if not faults else None

    def judge(metrics):
        return outcome(result.interrupted, node_fault_line(faults),
                       output_failed(result.recording_error, lost_on_the_way, metrics.get("plot_error")),
                       not_tracking=not_tracking(result, metrics), not_following=not_following(metrics))
    return _report(result, args, extra, judge)


def cmd_bridge(args):
    from drive_tools.doubles.virtual_inverter import InverterOptions
    from drive_tools.runner.bridge_loop import run_through_bridge
    from drive_tools.runner.runner import terminal_progress

    args.block_samples = link_block_samples(args.paced, args.block_samples)
    scenario = scenario_arg(args)
    paced = InverterOptions(rate_Hz=1.0 / scenario.T_s if args.paced else None)
    result = run_through_bridge(scenario, args.link, paced,
                                progress=terminal_progress(f"{scenario.name}/{scenario.estimator} through the "
                                                           f"bridge ({args.link})"),
                                answer=answer_options(args))
    extra = {"link": f"virtual inverter over {args.link}, bridge core, estimator and controller cores",
             "samples_per_s": round(result.log.shape[0] / result.wall_time_s) if result.wall_time_s > 0 else None,
             "bridge": result.counters, "frame_errors": result.frame_errors,
             "inverter": result.inverter_counters, "timing": result.timing, "interrupted": bool(result.interrupted)}

    def judge(metrics):
        return outcome(result.interrupted, output_error=metrics.get("plot_error"),
                       not_tracking=not_tracking(result, metrics), not_following=not_following(metrics),
                       tripped=tripped(metrics))
    return _report(result, args, extra, judge)


def cmd_scenarios(args):
    entries = []
    for name in scenario_names():
        s = load_scenario(name)
        entries.append({"name": name, "motor": s.motor.name, "estimator": s.estimator,
                        "duration_s": s.duration_s, "description": s.description})
    from drive_common.config.motor_experiments import DURATION_S, describe_experiment, experiment_names
    entries += [{"name": name, "motor": "--motor", "estimator": "injection_frame", "duration_s": DURATION_S,
                 "description": f"the motor's own experiment: {describe_experiment(name)}"}
                for name in experiment_names()]
    if args.json:
        print_json(entries)
    else:
        for e in entries:
            print(f"{e['name']:18s} {e['motor']:12s} {e['estimator']:12s} {e['duration_s']:5g} s  "
                  f"{e['description']}")
    return 0


def cmd_estimators(args):
    entries = [describe(n) for n in estimator_names()] + [{"name": name, "error": why}
                                                          for name, why in sorted(plugin_errors().items())]
    if args.json:
        print_json(entries)
    else:
        for e in entries:
            if "error" in e:
                print(f"{e['name']:16s} not loaded: {e['error']}")
            else:
                print(f"{e['name']:16s} {e['description']}\n{'':16s} {e['paper']}; module {e['module']}")
    return 0


def _drive_arguments(parser):
    """What run, launch and bridge share: the scenario, what replaces its estimator, motor, duration and
    commissioning, and the outputs."""
    parser.add_argument("scenario", help="shipped scenario name (see 'drive scenarios') or YAML path")
    parser.add_argument("--estimator", help="override the scenario's estimator")
    parser.add_argument("--motor", metavar="NAME|FILE", help=MOTOR_HELP)
    parser.add_argument("--duration", type=finite_float, help="override the duration [s]")
    parser.add_argument("--commissioning", metavar="FILE", help=COMMISSIONING_HELP)
    parser.add_argument("--out", help="plot directory (default runs/SCENARIO)")
    parser.add_argument("--no-plot", action="store_true", help="skip the PNG plot")
    parser.add_argument("--json", action="store_true", help="print the metrics as JSON")


def add_commands(sub):
    """run, scenarios, estimators, launch, bridge."""
    run = sub.add_parser("run", help="run a scenario in one process, print metrics, write plots")
    _drive_arguments(run)
    run.add_argument("--block-samples", type=int, metavar="N",
                     help="override the scenario's block_samples: data in blocks of N samples, the command "
                          "acting N − 1 periods later (docs/architecture.md)")
    run.add_argument("--answer-periods", type=int, metavar="P",
                     help="periods the host has from a block's last sample to its first command acting "
                          "(default: the inverter's 1; docs/architecture.md)")
    run.add_argument("--record", metavar="BAG",
                     help="write the run as a rosbag2/MCAP bag into this new directory")
    run.add_argument("--force", action="store_true", help="run a motor the drive refuses before running (its "
                     "predicted angle error, its polarity: docs/startup.md)")
    run.set_defaults(func=cmd_run)

    for name, func, text in (("scenarios", cmd_scenarios, "list shipped scenarios"),
                             ("estimators", cmd_estimators, "list estimators")):
        p = sub.add_parser(name, help=text)
        p.add_argument("--json", action="store_true")
        p.set_defaults(func=func)

    launch = sub.add_parser("launch", help="run a scenario through the ROS 2 graph (nodes over topics)")
    _drive_arguments(launch)
    launch.add_argument("--block-samples", type=int, metavar="N",
                        help="override the scenario's block_samples: the per-sample topics travel in blocks of N "
                             f"(docs/ros-graph.md; {PACED_BLOCK_SAMPLES} with --link and --paced)")
    launch.add_argument("--processes", choices=("composed", "separate"), default="composed",
                        help="nodes in this process (default) or one process per node")
    launch.add_argument("--executor", choices=EXECUTORS, default="events",
                        help="events (rclpy.experimental.EventsExecutor, default) or single (fallback)")
    launch.add_argument("--intra-process", action=argparse.BooleanOptionalAction, default=None,
                        help="composed: the controller takes the estimator's answers and the currents directly, "
                             "not over topics (still published for everyone else; docs/ros-graph.md; default "
                             "with --link and --paced)")
    launch.add_argument("--namespace", default=DEFAULT_NAMESPACE)
    launch.add_argument("--timeout", type=finite_float, default=1.0, help="lock-step answer timeout [s]")
    launch.add_argument("--record", metavar="BAG",
                        help="record every drive topic into this new rosbag2 directory")
    launch.add_argument("--link", choices=("pty", "can"),
                        help="put the virtual inverter (behind this link) and the drive_bridge node in the "
                             "plant's place")
    launch.add_argument("--paced", action="store_true",
                        help="with --link: the virtual inverter on its own clock at the sampling rate, never "
                             "waiting for the graph: a late command is zero volts, counted")
    answer_argument(launch, None)
    add_scheduling_arguments(launch, system_wide=True)
    launch.set_defaults(func=cmd_launch, rt_priority=UNSET, cpus=UNSET, workqueue_cpus=UNSET)
    launch.epilog = ("With --link and --paced, the robot's configuration unless given otherwise: --rt-priority "
                     f"{ROBOT_RT_PRIORITY}, --cpus the last CPU (--workqueue-cpus too over a pty), "
                     "--intra-process, over a pty --answer compiled (docs/ros-graph.md, \"Real time\")")

    bridge = sub.add_parser("bridge", help="the sensorless loop through the inverter bridge and the virtual "
                                           "inverter, in one process")
    _drive_arguments(bridge)
    bridge.add_argument("--link", choices=("pty", "can"), default="pty")
    bridge.add_argument("--paced", action="store_true",
                        help="the inverter on its own clock at the sampling rate, never waiting for the host: a "
                             "late command is zero volts, counted")
    bridge.add_argument("--block-samples", type=int, metavar="N",
                        help=f"samples per frame (default: the scenario's; {PACED_BLOCK_SAMPLES} with --paced)")
    answer_argument(bridge, "python")
    bridge.set_defaults(func=cmd_bridge)
