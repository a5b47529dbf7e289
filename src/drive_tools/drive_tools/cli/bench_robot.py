"""``drive bench robot``: how many axes `drive up` runs together within the late bound on this machine, quiet or with
a core kept busy, and the CPU price per axis (docs/robot.md, "Axes together")."""
import sys
from pathlib import Path

from .options import CommandLineError, finite_float, print_json


def _counts(flag, text, low, high):
    try:
        values = [int(part) for part in text.split(",")]
    except ValueError:
        raise CommandLineError(f"{flag}: comma-separated whole numbers, not {text!r}") from None
    if not values or any(not low <= v <= high for v in values):
        raise CommandLineError(f"{flag}: each between {low} and {high}, not {text!r}")
    return values


def cmd_bench_robot(args):
    from drive_tools.evaluation.bench import core_kept_busy
    from drive_tools.evaluation.robot_bench import LATE_BOUND, robot_bench
    from drive_tools.launch.hop_cost import HOP_ROUND_TRIPS_BESIDE_A_RUN, hop_latency

    axes = _counts("--axes", args.axes, 1, 8)
    blocks = _counts("--blocks", args.blocks, 1, 20)
    if not 0.5 <= args.duration <= 60.0:
        raise CommandLineError(f"--duration: between 0.5 and 60 s, not {args.duration:g}")
    if args.repeats < 1:
        raise CommandLineError(f"--repeats: at least 1, not {args.repeats}")
    answers = args.answer.split(",")
    if not answers or any(a not in ("compiled", "nodes") for a in answers):
        raise CommandLineError(f"--answer: compiled, nodes or both comma-separated, not {args.answer!r}")
    drive = str(Path(sys.executable).with_name("drive"))
    hop = hop_latency(HOP_ROUND_TRIPS_BESIDE_A_RUN)
    with core_kept_busy(args.load):
        rows = robot_bench(axes, blocks, args.duration, args.repeats, drive,
                           lambda line: print(f"drive bench robot: {line}", file=sys.stderr, flush=True), answers,
                           args.inverter_apart)
    report = {"benchmark": "robot_axes", "duration_s": args.duration, "load": bool(args.load),
              "inverter_apart": args.inverter_apart,
              "late_bound": LATE_BOUND, "hop_us": hop["us_per_hop"], "rows": rows}
    if args.json:
        print_json(report)
        return 0
    print(f"drive up, N paced virtual axes over ptys, {args.duration:g} s each, hop {hop['us_per_hop']:.1f} µs"
          f"{', one core kept busy' if args.load else ''}")
    for row in rows:
        runs = row["runs"]
        late = "; ".join(", ".join("-" if s is None else f"{100 * s:.2f}" for s in r["late_fractions"]) for r in runs)
        cpu = ", ".join("-" if r["cpu_us_per_period_and_axis"] is None else f"{r['cpu_us_per_period_and_axis']:.0f}"
                        for r in runs)
        print(f"  {row['answer']}, {row['axes']} axes, blocks of {row['block_samples']}: every axis within "
              f"{100 * LATE_BOUND:g} % late in {row['runs_every_axis_kept_pace']} of {len(runs)} runs; late % per "
              f"axis {late}; CPU µs per period and axis {cpu}")
        for reason in sorted({r["reason"] for r in runs if not r["ended_as_expected"]}):
            print(f"    not run to its end: {reason}")
    return 0


def add_robot_bench_command(bench_sub):
    """bench robot."""
    robot = bench_sub.add_parser("robot", help="how many axes drive up runs together within 0.1 %% late (paced "
                                               "virtual inverters), and the CPU per axis (docs/robot.md)")
    robot.add_argument("--axes", default="1,2,3", help="axis counts to run, comma-separated (default 1,2,3)")
    robot.add_argument("--blocks", default="10", help="samples per block, comma-separated (default 10)")
    robot.add_argument("--duration", type=finite_float, default=3.0, help="seconds of each run (default 3)")
    robot.add_argument("--repeats", type=int, default=2, help="runs per axis count and block size (default 2)")
    robot.add_argument("--load", action="store_true", help="another process keeps one core busy meanwhile")
    robot.add_argument("--answer", default="compiled", help="how each axis answers: compiled, nodes, or both "
                                                            "comma-separated (default compiled; docs/robot.md)")
    robot.add_argument("--inverter-apart", action="store_true",
                       help="each virtual inverter in a process of its own, as a real inverter is a device of its own")
    robot.add_argument("--json", action="store_true")
    robot.set_defaults(func=cmd_bench_robot)
