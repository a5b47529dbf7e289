"""``drive bench startup|motor|full-speed|injection-cost|stop``: how well the drive runs: start-up over angles
and loads, motors nobody tuned for, the whole speed range, what the injection costs, and how soon a signal
stops it."""
import sys

from drive_common.config.scenario import load_scenario
from drive_common.motor.motor_file import load_motor
from drive_common.runtime.interrupt import Interrupted
from hf_estimator.interface import injects
from hf_estimator.registry import estimator_names

from .bench_motors import add_random_motors_command
from .bench_robot import add_robot_bench_command
from .options import (
    CommandLineError,
    estimator_arg,
    estimator_list,
    exit_code,
    finite_float,
    print_json,
    print_report,
    sample_period_arg,
    warn_if_nameplate_only,
)

FULL_SPEED_SCENARIOS = ("wang_full_speed", "szabo_full_speed")


def _swept(benchmark, items, measure, args, lines, **facts):
    """Run ``measure(item, progress)`` per item and print the reports (``lines`` of them) or their JSON
    {benchmark, **facts, results}; interrupted, what was measured is printed and the exit code says so."""
    from drive_tools.runner.runner import terminal_progress

    reports = []
    try:
        for item, label in items:
            reports.append(measure(item, None if args.json else terminal_progress(label)))
    except Interrupted as stop:
        if args.json:
            print_json({"benchmark": benchmark, "results": reports, "interrupted": True})
        return exit_code(stop.signum)
    if args.json:
        print_json({"benchmark": benchmark, **facts, "results": reports})
    else:
        print("\n".join(lines(reports)))
    return 0


def cmd_bench_full_speed(args):
    from drive_tools.evaluation.bench_report import full_speed_lines
    from drive_tools.evaluation.speed_range import full_speed_comparison

    scenarios = [load_scenario(name) for name in args.scenarios or FULL_SPEED_SCENARIOS]
    return _swept("full-speed", [(s, s.name) for s in scenarios], full_speed_comparison, args, full_speed_lines)


def cmd_bench_injection_cost(args):
    from drive_tools.evaluation.bench_report import injection_cost_lines
    from drive_tools.evaluation.speed_range import injection_cost
    from drive_tools.runner.runner import terminal_progress

    names = estimator_list(args.estimators) if args.estimators else [n for n in estimator_names() if injects(n)]
    scenario = load_scenario(args.scenario)
    try:
        report = injection_cost(scenario, names, None if args.json else terminal_progress(scenario.name))
    except Interrupted as stop:
        return exit_code(stop.signum)
    if args.json:
        print_json({"benchmark": "injection-cost", **report})
    else:
        print("\n".join(injection_cost_lines(report)))
    return 0


def cmd_bench_motor(args):
    from drive_tools.evaluation.bench_report import motor_bench_lines
    from drive_tools.evaluation.motor_bench import TrialOptions, motor_trial

    if args.angles < 1:
        raise CommandLineError(f"--angles: must be at least 1, not {args.angles}")
    sample_period_arg(args.sample_period)
    motors = [load_motor(m, "drive bench motor") for m in args.motors]
    trial = TrialOptions(args.sample_period, args.angles)
    return _swept("motor", [(m, m.name) for m in motors],
                  lambda motor, progress: motor_trial(motor, trial, progress), args,
                  motor_bench_lines, angles=args.angles, sample_period_s=args.sample_period)


def cmd_bench_startup(args):
    from drive_tools.evaluation.bench_report import startup_lines
    from drive_tools.evaluation.startup_bench import (
        MOTOR_SCENARIOS,
        STANDARD_CASES,
        LoadCase,
        bench_scenario,
        startup_sweep,
    )
    from drive_tools.runner.runner import scenario_commissioning

    estimator_arg(args)
    for flag, value in (("--angles", args.angles), ("--seeds", args.seeds)):
        if value < 1:
            raise CommandLineError(f"{flag}: must be at least 1, not {value}")
    seeds = tuple(range(1, args.seeds + 1))
    if args.drawn:
        from drive_tools.evaluation.startup_bench import drawn_lines, drawn_startup_bench
        return _swept("startup", [(args.drawn, f"{args.drawn} drawn motors")],
                      lambda count, progress: drawn_startup_bench(count, args.draw_seed, args.angles, seeds, progress),
                      args, lambda reports: drawn_lines(reports[0]), draw_seed=args.draw_seed)
    motors = [load_motor(args.motor, "--motor")] if args.motor else [load_motor(m) for m in sorted(MOTOR_SCENARIOS)]
    cases = STANDARD_CASES
    if args.load is not None:
        if not 0.0 <= args.load <= 1.5:
            raise CommandLineError(f"--load: a fraction of rated torque in [0, 1.5], not {args.load}")
        name = f"{args.load:g} rated{', brake' if args.brake else ', active'}{', ff' if args.feedforward else ''}"
        cases = (LoadCase(name, args.load, args.brake, args.feedforward),)
    for motor in motors:
        first = bench_scenario(motor, args.estimator, 0.0, 1, cases[0])
        warn_if_nameplate_only(scenario_commissioning(first).source, motor.name,
                               MOTOR_SCENARIOS.get(motor.name, f"wang_100rpm --motor {motor.source}"))
    return _swept("startup", [((motor, case), f"{motor}, {case.name}") for motor in motors for case in cases],
                  lambda item, progress: startup_sweep(*item, args.angles, seeds, args.estimator, progress), args,
                  startup_lines, angles=args.angles, seeds=args.seeds)


def cmd_bench_stop(args):
    from drive_tools.evaluation.stop_bench import STOP_CASES, stop_bench, stop_lines

    cases = args.cases.split(",") if args.cases else list(STOP_CASES)
    for case in cases:
        if case not in STOP_CASES:
            raise CommandLineError(f"--cases: {case!r} is not one of {', '.join(STOP_CASES)}")
    if args.repeats < 1:
        raise CommandLineError(f"--repeats: must be at least 1, not {args.repeats}")
    load_scenario(args.scenario)
    report = stop_bench(args.scenario, cases, args.repeats, progress=lambda line: print(line, file=sys.stderr))
    for result in report["results"]:
        for problem in result["problems"]:
            print(f"drive: warning: {result['case']} at {result['point']}: {problem}", file=sys.stderr)
    print_report(report, args, stop_lines)
    return 0


def add_bench_commands(bench_sub):
    """bench startup, motor, full-speed, injection-cost, stop."""
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
    startup.add_argument("--drawn", type=int, metavar="N", help="N many-pole, low-inertia motors drawn, commissioned, "
                         "started without load (docs/startup.md)")
    startup.add_argument("--draw-seed", type=int, default=1, help="with --drawn: the draw's seed")
    startup.add_argument("--json", action="store_true")
    startup.set_defaults(func=cmd_bench_startup)

    motor_bench = bench_sub.add_parser("motor", help="motors nobody tuned for: commissioned from the nameplate, "
                                                     "start-up polarity, then the motor's own experiments on the "
                                                     "loops scaled to each, and a verdict")
    motor_bench.add_argument("motors", nargs="+", metavar="NAME|FILE", help="shipped motors or motor files")
    motor_bench.add_argument("--angles", type=int, default=24, help="start angles over the electrical circle")
    motor_bench.add_argument("--sample-period", type=finite_float, default=1e-4, metavar="S",
                             help="the drive's sampling period [s] (default 1e-4)")
    motor_bench.add_argument("--json", action="store_true")
    motor_bench.set_defaults(func=cmd_bench_motor)

    add_random_motors_command(bench_sub)
    add_robot_bench_command(bench_sub)

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
    stop = bench_sub.add_parser("stop", help="SIGINT and SIGTERM during `drive commission` (standstill, --rotating, "
                                             "--loaded) and `drive run`: time to the stop reported and to the exit, "
                                             "and nothing left written")
    stop.add_argument("--scenario", default="wang_100rpm")
    stop.add_argument("--cases", metavar="C[,C...]", help="comma-separated: commission standstill, commission "
                                                         "rotating, commission loaded, run (default: all)")
    stop.add_argument("--repeats", type=int, default=3, help="runs per case, point and signal")
    stop.add_argument("--json", action="store_true")
    stop.set_defaults(func=cmd_bench_stop)
