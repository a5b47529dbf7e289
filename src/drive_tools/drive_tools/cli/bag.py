"""``drive echo`` and ``drive bag info|reindex``: a drive topic as it goes by, and recordings."""
from drive_common.contract.graph import DEFAULT_NAMESPACE

from .options import CommandLineError, finite_float, print_report


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


def add_commands(sub):
    """echo, bag info|reindex."""
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
