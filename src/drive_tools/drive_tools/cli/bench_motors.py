"""``drive bench motors --random N --seed S``: motors drawn from the fixed distribution of random motors
(docs/random-motors.md), each tried as a robot builder would, with a verdict per motor."""
import os
import sys
from pathlib import Path

from .options import CommandLineError, exit_code, finite_float, print_json, sample_period_arg

MAX_RANDOM_MOTORS = 100_000


def cmd_bench_motors(args):
    from drive_tools.evaluation.random_motor_bench import RandomBenchOptions, random_bench_lines, random_motor_bench

    for flag, value, low in (("--random", args.random, 1), ("--starts", args.starts, 1), ("--workers", args.workers, 1),
                             ("--seed", args.seed, 0)):
        if value < low:
            raise CommandLineError(f"{flag}: must be at least {low}, not {value}")
    if args.random > MAX_RANDOM_MOTORS:
        raise CommandLineError(f"--random: at most {MAX_RANDOM_MOTORS} motors, not {args.random}")
    sample_period_arg(args.sample_period)
    folder = Path(args.out) if args.out else Path("runs") / "random_motors" / f"seed_{args.seed}"
    if folder.exists() and not folder.is_dir():
        raise CommandLineError(f"--out: {folder} is a file, not a folder")
    options = RandomBenchOptions(args.random, args.seed, folder, args.sample_period, args.starts, args.workers)
    report = random_motor_bench(options, lambda line: print(line, file=sys.stderr, flush=True))
    if args.json:
        print_json(report)
    else:
        print("\n".join(random_bench_lines(report)))
    return exit_code(report["interrupted"])


def add_random_motors_command(bench_sub):
    """bench motors."""
    motors = bench_sub.add_parser("motors", help="N motors drawn at random over the range a robot builder meets, "
                                                 "each commissioned, started and run through its own experiments: "
                                                 "a verdict per motor and the counts (docs/random-motors.md)")
    motors.add_argument("--random", type=int, required=True, metavar="N", help="how many motors to draw")
    motors.add_argument("--seed", type=int, default=1, help="the draw's seed (motor i of a seed is the same for any N)")
    motors.add_argument("--out", metavar="DIR", help="where the motor files go (default runs/random_motors/seed_S)")
    motors.add_argument("--starts", type=int, default=8, help="start-ups per motor from random rotor angles")
    motors.add_argument("--workers", type=int, default=min(2, os.cpu_count() or 1),
                        help="processes trying motors side by side (default: 2, or 1 on one CPU)")
    motors.add_argument("--sample-period", type=finite_float, default=1e-4, metavar="S",
                        help="the drive's sampling period [s] (default 1e-4)")
    motors.add_argument("--json", action="store_true")
    motors.set_defaults(func=cmd_bench_motors)
