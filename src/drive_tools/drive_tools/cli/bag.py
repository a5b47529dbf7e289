"""``drive echo`` and ``drive bag info|reindex|synth``: a drive topic as it goes by, and recordings."""
import os
import sys
from pathlib import Path

from drive_common.contract.graph import DEFAULT_NAMESPACE

from .options import CommandLineError, exit_code, finite_float, print_report

MAX_SYNTHETIC_BAGS = 100_000


def cmd_echo(args):
    from drive_tools.launch.echo import echo
    for flag, value in (("--count", args.count), ("--every", args.every)):
        if value is not None and value < 1:
            raise CommandLineError(f"{flag}: must be at least 1, not {value}")
    if args.timeout is not None and args.timeout <= 0.0:
        raise CommandLineError(f"--timeout: must be positive (seconds), not {args.timeout:g}")
    return echo(args.topic, args.namespace, args.count, args.every, args.json, args.timeout)


def cmd_bag_info(args):
    from drive_tools.bags.reader import bag_info, bag_info_lines
    print_report(bag_info(args.bag), args, bag_info_lines)
    return 0


def cmd_bag_reindex(args):
    from drive_tools.bags.reindex import reindex, reindex_line
    print_report(reindex(args.bag, force=args.force), args, lambda info: [reindex_line(info)])
    return 0


def cmd_bag_synth(args):
    from drive_tools.evaluation.synthetic_corpus import SyntheticOptions, corpus_lines, synthetic_corpus
    for flag, value, low in (("--count", args.count, 1), ("--workers", args.workers, 1), ("--seed", args.seed, 0)):
        if value < low:
            raise CommandLineError(f"--{flag.lstrip('-')}: must be at least {low}, not {value}")
    if args.count > MAX_SYNTHETIC_BAGS:
        raise CommandLineError(f"--count: at most {MAX_SYNTHETIC_BAGS} bags, not {args.count}")
    if not 0.2 <= args.duration <= 60.0:
        raise CommandLineError(f"--duration: from 0.2 to 60 s per bag, not {args.duration:g}")
    folder = Path(args.dir)
    if folder.exists() and (not folder.is_dir() or any(folder.iterdir())):
        raise CommandLineError(f"{folder}: exists and is not an empty folder; name a new one")
    options = SyntheticOptions(args.count, args.seed, folder, args.duration, args.workers)
    report = synthetic_corpus(options, lambda line: print(line, file=sys.stderr, flush=True))
    print_report(report, args, corpus_lines)
    return exit_code(report["interrupted"])


def add_commands(sub):
    """echo, bag info|reindex|synth."""
    echo = sub.add_parser("echo", help="print a drive topic (like ros2 topic echo)")
    echo.add_argument("topic", help="contract topic, e.g. angle_error, joint_states, /diagnostics")
    echo.add_argument("--namespace", default=DEFAULT_NAMESPACE)
    echo.add_argument("--count", type=int, help="stop after this many printed messages")
    echo.add_argument("--every", type=int, default=1, help="print every N-th message")
    echo.add_argument("--timeout", type=finite_float, help="stop after this many seconds")
    echo.add_argument("--json", action="store_true", help="one JSON object per line")
    echo.set_defaults(func=cmd_echo)

    bag = sub.add_parser("bag", aliases=["bags"], help="recordings (rosbag2 directories with MCAP storage)")
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
    synth = bag_sub.add_parser("synth", help="write a varied corpus of recordings with ground truth from random "
                                             "motors (docs/recordings.md#a-synthetic-corpus)")
    synth.add_argument("dir", help="the corpus folder (new, or empty)")
    synth.add_argument("--count", type=int, required=True, metavar="N", help="how many bags")
    synth.add_argument("--seed", type=int, default=1, help="the draw's seed (bag i of a seed is the same for any N)")
    synth.add_argument("--duration", type=finite_float, default=1.0, metavar="S", help="each bag's length [s]")
    synth.add_argument("--workers", type=int, default=min(2, os.cpu_count() or 1),
                       help="processes writing bags side by side (default: 2, or 1 on one CPU)")
    synth.add_argument("--json", action="store_true")
    synth.set_defaults(func=cmd_bag_synth)
