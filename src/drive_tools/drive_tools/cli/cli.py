"""The ``drive`` command line: one entry, a subcommand per job, each family in its own module; every
result-printing command also has ``--json``. Domain errors (drive_common.contract.errors.DriveError) are printed as
one line, exit code 2; every other non-zero exit prints its one-line reason on stderr too (options.say_reason, else
options.fallback_reason)."""
import os
import sys
from pathlib import Path

from drive_common.contract.errors import DriveError
from drive_common.contract.exit_codes import EXIT_READER_GONE, EXIT_REFUSED, EXIT_SIGNAL_BASE
from drive_common.contract.settings import show_warnings_in_one_line
from drive_common.runtime import interrupt
from drive_common.runtime.interrupt import Interrupted

from . import bag, bench_drive, bench_timing, motor, replay, robot, run, tune, view
from .options import OneLineParser, os_error_line
from .outcome import fallback_reason, forget_reasons, reasons_said, say_reason


def build_parser():
    parser = OneLineParser(prog="drive", description="Sensorless PMSM drive stack.")
    sub = parser.add_subparsers(dest="command", required=True)
    run.add_commands(sub)
    motor.add_commands(sub)
    bench = sub.add_parser("bench", help="benchmarks")
    bench_sub = bench.add_subparsers(dest="bench", required=True)
    bench_timing.add_bench_commands(bench_sub)
    bench_drive.add_bench_commands(bench_sub)
    replay.add_bench_commands(bench_sub)
    tune.add_commands(sub)
    bag.add_commands(sub)
    robot.add_commands(sub)
    view.add_commands(sub)
    return parser


def _remedy(error, args):
    """What the user can do about a domain error, in the command line's words."""
    from drive_tools.bags.common import BagCompleteError, BagCutError
    if isinstance(error, BagCutError):
        force = " --force" if (Path(error.path) / "metadata.yaml").exists() else ""
        return f"; `drive bag reindex {error.path}{force}` rebuilds it"
    if isinstance(error, BagCompleteError):
        return "; --force rebuilds it anyway"
    from drive_tools.launch.launcher import NamespaceOccupiedError
    if isinstance(error, NamespaceOccupiedError):
        return " (--namespace NAME)"
    return ""


def _interrupted_cause(error):
    """The Interrupted that caused ``error`` (a signal that came while a C extension was being imported turns into
    that import's ImportError), or None."""
    seen = error.__cause__ or error.__context__
    while seen is not None and not isinstance(seen, Interrupted):
        seen = seen.__cause__ or seen.__context__
    return seen


def main(argv=None, early_signals=()):
    """Run the command ``argv``; ``early_signals``: SIGINT/SIGTERM noted before this was called (by
    drive_tools.cli.entry), so that the command stops at once as interrupted."""
    args = build_parser().parse_args(argv)
    show_warnings_in_one_line("drive")
    forget_reasons()
    try:
        with interrupt.handled():
            if early_signals:
                raise Interrupted(early_signals[0])
            code = args.func(args)
            if interrupt.requested() and code < EXIT_SIGNAL_BASE:
                raise Interrupted(interrupt.requested())
            if code and not reasons_said():
                say_reason(fallback_reason(args.command, code))
            return code
    except DriveError as error:
        text = " ".join(f"{error}{_remedy(error, args)}".split())
        print(f"drive: {text}", file=sys.stderr)
        return EXIT_REFUSED
    except (Interrupted, ImportError) as error:
        stop = error if isinstance(error, Interrupted) else _interrupted_cause(error)
        if stop is None:
            raise
        print(f"drive: {args.command}: interrupted by {stop}", file=sys.stderr)
        return EXIT_SIGNAL_BASE + stop.signum
    except BrokenPipeError:
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_READER_GONE
    except OSError as error:
        print(f"drive: {os_error_line(error)}", file=sys.stderr)
        return EXIT_REFUSED


if __name__ == "__main__":
    sys.exit(main())
