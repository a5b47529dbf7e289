"""``drive bench throughput|graph|blocks|bridge|platform``: how fast the drive runs, in one process, over the ROS
graph and through the inverter bridge, with the hop cost beside every real-time figure, and the
machine's own wake-up floor."""
import sys

from drive_common.config.scenario import PACED_BLOCK_SAMPLES, link_block_samples, load_scenario
from drive_common.runtime.realtime import add_scheduling_arguments, fifo_priority

from .options import (
    CommandLineError,
    block_sizes,
    duration_arg,
    estimator_list,
    exit_code,
    finite_float,
    print_json,
    progress_lines,
)


def _at_least_one(*options):
    for flag, value in options:
        if value < 1:
            raise CommandLineError(f"{flag}: must be at least 1, not {value}")


def cmd_bench_throughput(args):
    from drive_tools.evaluation.bench import motulator_python, motulator_throughput, throughput
    from drive_tools.evaluation.bench_report import motulator_lines, throughput_line

    _at_least_one(("--samples", args.samples), ("--repeats", args.repeats))
    names = estimator_list(args.estimators)
    if args.against:
        return _throughput_against(args, names)
    results = []
    for name in names:
        if not args.json:
            print(f"  {name:14s} ...", end="", flush=True)
        results.append(throughput(name, samples=args.samples, repeats=args.repeats))
        if not args.json:
            print(f"\r{throughput_line(results[-1])}")
    report = {"benchmark": "throughput", "results": results,
              "samples_per_second": {r["estimator"]: r["samples_per_second"] for r in results}}
    python = None if args.no_motulator else motulator_python()
    if python:
        if not args.json:
            print("  motulator 2.2-kW PMSM signal-injection example ...", end="", flush=True)
        reference = motulator_throughput(python)
        report["motulator"] = reference
        if "error" not in reference:
            report["ratio_to_motulator"] = {r["estimator"]: r["samples_per_cpu_second"]
                                            / reference["samples_per_cpu_second"] for r in results}
            report["ratio_to_motulator_wall"] = {r["estimator"]: r["samples_per_second"]
                                                 / reference["samples_per_second"] for r in results}
        if not args.json:
            print("\r" + "\n".join(motulator_lines(report, python)))
    elif not args.json:
        print("  motulator: not installed (./setup.sh --with-motulator, or DRIVE_MOTULATOR_PYTHON)")
    if args.json:
        print_json(report)
    return 0


def _throughput_against(args, names):
    """bench throughput --against COMMIT: today's and the commit's bench, alternating in one run."""
    from drive_tools.evaluation.bench import throughput_against
    from drive_tools.evaluation.bench_report import against_lines

    try:
        report = throughput_against(args.against, names, args.samples, args.repeats,
                                    progress=None if args.json else lambda line: print(f"  {line}", file=sys.stderr))
    except ValueError as error:
        raise CommandLineError(f"--against: {error}") from None
    if args.json:
        print_json(report)
    else:
        print("\n".join(against_lines(report)))
    return 0


def cmd_bench_graph(args):
    from drive_tools.evaluation.bench import GRAPH_CONFIGURATIONS, INTRA_PROCESS, graph_throughput
    duration_arg(args.duration, load_scenario(args.scenario).T_s)
    _at_least_one(("--repeats", args.repeats))
    report = graph_throughput(args.scenario, args.duration, record=args.record, repeats=args.repeats,
                              progress=progress_lines(args),
                              block_sizes=block_sizes(args.block_samples),
                              configurations=GRAPH_CONFIGURATIONS + ((INTRA_PROCESS,) if args.intra_process else ()))
    if args.json:
        print_json(report)
    elif report["interrupted"]:
        print("  interrupted: the configuration being timed is not reported")
    return exit_code(report["interrupted"])


def cmd_bench_blocks(args):
    from drive_tools.evaluation.bench import BLOCK_SCENARIOS, block_size_table
    duration_arg(args.duration, min(load_scenario(name).T_s for name in BLOCK_SCENARIOS))
    _at_least_one(("--repeats", args.repeats))
    report = block_size_table(block_sizes(args.block_samples), duration_s=args.duration, repeats=args.repeats,
                              progress=progress_lines(args))
    if args.json:
        print_json(report)
    return exit_code(report["interrupted"])


def _graph_real_time(args, links):
    """bench bridge --paced --graph: the ROS graph on the inverter's clock, per link and lever."""
    from drive_tools.evaluation.bench import REAL_TIME_LEVERS, RealTimeBench, graph_real_time

    if not (args.paced and args.graph):
        raise CommandLineError("--graph, --load and --levers measure the ROS graph on the inverter's clock: "
                               "give --paced --graph")
    levers = (args.levers or "collector").split(",")
    for lever in levers:
        if lever not in REAL_TIME_LEVERS:
            raise CommandLineError(f"--levers: {lever!r} is not one of {', '.join(REAL_TIME_LEVERS)}")
    _at_least_one(("--repeats", args.repeats))
    if args.lose_command_every < 0 or (args.lose_command_every and any("inverter_apart" in lever for lever in levers)):
        raise CommandLineError(f"--lose-command-every: N ≥ 0, with the inverter in the launcher's process (not "
                               f"inverter_apart), not {args.lose_command_every}")
    blocks = link_block_samples(True, args.block_samples)
    from drive_bridge.inverter_protocol import MAX_BLOCK
    if not 2 <= blocks <= MAX_BLOCK:
        raise CommandLineError(f"--block-samples: the paced graph runs in blocks of 2 to {MAX_BLOCK} samples, "
                               f"not {blocks}")
    lost = f", every {args.lose_command_every}th command block lost" if args.lose_command_every else ""
    print(f"drive launch {args.scenario} --link L --paced, {args.repeats} runs per link and lever"
          f"{', one core kept busy by another process' if args.load else ''}{lost}", file=sys.stderr)
    bench = RealTimeBench(tuple(links), args.repeats, args.load, tuple(levers), blocks, args.lose_command_every,
                          args.watch_machine)
    report = graph_real_time(args.scenario, bench, progress=lambda line: print(line, file=sys.stderr))
    if args.json:
        print_json(report)
    return exit_code(report["interrupted"])


def cmd_bench_bridge(args):
    from drive_tools.evaluation.bench import bridge_rates
    from drive_tools.evaluation.bench_report import bridge_lines

    links = args.links.split(",")
    for link in links:
        if link not in ("pty", "can"):
            raise CommandLineError(f"--links: 'pty' and/or 'can', not {link!r}")
    if args.graph or args.load or args.levers or args.lose_command_every or args.watch_machine:
        return _graph_real_time(args, links)
    duration = args.duration if args.duration is not None or args.paced else 1.0
    duration_arg(duration, load_scenario(args.scenario).T_s)
    if args.block_samples is not None:
        from drive_bridge.inverter_protocol import MAX_BLOCK
        if not 1 <= args.block_samples <= MAX_BLOCK:
            raise CommandLineError(f"--block-samples: the inverter protocol carries 1 to {MAX_BLOCK} samples per "
                                   f"block, not {args.block_samples}")
    answer = None
    if args.answer == "compiled":
        from drive_tools.runner.compiled_answer import AnswerOptions
        if args.reader_stall_ms < 0:
            raise CommandLineError(f"--reader-stall-ms: a pause ≥ 0 ms, not {args.reader_stall_ms:g}")
        answer = AnswerOptions(priority=args.rt_priority, reader_stall_s=args.reader_stall_ms * 1e-3)
    report = bridge_rates(args.scenario, links, duration, args.repeats, args.paced,
                          link_block_samples(args.paced, args.block_samples), answer)
    if args.json:
        print_json(report)
    else:
        print("\n".join(bridge_lines(report, args.paced)))
    return 0


def cmd_bench_platform(args):
    """bench platform: how late a SCHED_FIFO thread wakes on this machine, with nothing of the drive running."""
    from drive_common.runtime.realtime import stall_report, wakeup_latencies
    from drive_tools.evaluation.bench import core_kept_busy

    _at_least_one(("--seconds", args.seconds))
    with core_kept_busy(args.load):
        late, scheduling = wakeup_latencies(args.seconds, 1e-3, args.rt_priority, args.cpus)
    for line in scheduling["refused"]:
        print(f"drive: warning: {line}", file=sys.stderr)
    report = {"benchmark": "platform", "load": args.load, "scheduling": scheduling,
              **stall_report(late, 1e-3)}
    if args.json:
        print_json(report)
    else:
        print(f"{report['wakeups']} wake-ups every 1 ms ({', '.join(scheduling['applied']) or 'normal scheduling'}"
              f"{', one core kept busy' if args.load else ''}): late p50 {report['latency_p50_us']:.0f} µs, "
              f"p99 {report['latency_p99_us']:.0f} µs, max {report['latency_max_us']:.0f} µs; "
              f"{report['stalls_over_0_5_ms']} stalls over 0.5 ms ({report['stalls_over_1_ms']} over 1 ms)")
    return 0


def add_bench_commands(bench_sub):
    """bench throughput, graph, blocks, bridge, platform."""
    tp = bench_sub.add_parser("throughput", help="closed-loop samples/s in one process, per estimator")
    tp.add_argument("--estimators", help="comma-separated (default: all)")
    tp.add_argument("--samples", type=int, default=1_000_000)
    tp.add_argument("--repeats", type=int, default=3, help="timed runs per estimator (best reported; with "
                                                             "--against: rounds)")
    tp.add_argument("--against", metavar="COMMIT",
                    help="also time the bench of this older commit (a git worktree of it, this venv), alternating "
                         "with today's in separate processes, each on its CPU clock: best, median and the ratio "
                         "per estimator")
    tp.add_argument("--no-motulator", action="store_true",
                    help="skip timing motulator's signal-injection example")
    tp.add_argument("--json", action="store_true")
    tp.set_defaults(func=cmd_bench_throughput)
    graph = bench_sub.add_parser("graph", help="real-time factor of the lock-step ROS graph at the "
                                               "scenario's sampling rate, composed and separate")
    graph.add_argument("--scenario", default="wang_100rpm")
    graph.add_argument("--duration", type=finite_float, default=0.5, help="simulated seconds per run")
    graph.add_argument("--record", action="store_true", help="also record every per-sample topic")
    graph.add_argument("--block-samples", default="1", metavar="N[,N...]",
                       help="block sizes to time (samples per message; default 1)")
    graph.add_argument("--repeats", type=int, default=2, help="timed runs per configuration (best kept)")
    graph.add_argument("--intra-process", action="store_true",
                       help="also composed with the controller taking the estimator's answers directly")
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
                                   "(default), collector+cpu1, collector+fifo, collector+fifo+cpu1, "
                                   "collector+fifo+cpu1+inverter_apart, collector+fifo+cpu1+workqueue1 (the "
                                   "kernel's unbound workqueues on CPU 1 too; needs root), and with +intra (the "
                                   "nodes hand over in one process), +intra+pmqos (the CPUs kept out of idle "
                                   "states), +intra+inverter_apart")
    bench_bridge.add_argument("--lose-command-every", type=int, default=0, metavar="N",
                              help="with --graph: the inverter loses every Nth command block (as if late: zero "
                                   "volts), to measure how ours degrades")
    bench_bridge.add_argument("--watch-machine", action="store_true",
                              help="with --graph: beside each run a process above the drive's priority on its CPUs "
                                   "notes the machine's stalls; each run says how many of its late blocks they "
                                   "explain")
    bench_bridge.add_argument("--answer", choices=("python", "compiled"), default="python",
                              help="the host's answer on the pty: in Python (the reference) or compiled whole, off "
                                   "the interpreter's lock, on a thread of its own (CAN keeps Python's)")
    bench_bridge.add_argument("--rt-priority", type=fifo_priority, default=0, metavar="1-99",
                              help="with --answer compiled: SCHED_FIFO priority of its answer thread (0: normal)")
    bench_bridge.add_argument("--reader-stall-ms", type=finite_float, default=0.0, metavar="MS",
                              help="with --answer compiled: a pause of the ring's reader after each read (a "
                                   "stall of the side that is not real-time)")
    bench_bridge.add_argument("--json", action="store_true")
    bench_bridge.set_defaults(func=cmd_bench_bridge)
    platform = bench_sub.add_parser("platform", help="the machine's own floor: how late a SCHED_FIFO thread "
                                                     "wakes every 1 ms, nothing of the drive running")
    platform.add_argument("--seconds", type=finite_float, default=15.0)
    platform.add_argument("--load", action="store_true", help="another process keeps one core busy meanwhile")
    add_scheduling_arguments(platform)
    platform.add_argument("--json", action="store_true")
    platform.set_defaults(func=cmd_bench_platform)
