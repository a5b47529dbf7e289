"""The ``drive`` command's entry: SIGINT and SIGTERM are noted from the first instruction on, before the
command line's modules load (seconds on a slow machine), and a signal noted then stops the command as one
that came during its job would (exit 128 + N, one line), never as a traceback."""
import signal
import sys


def main(argv=None):
    early = []
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, lambda received, _frame: early.append(received))
    from .cli import main as run
    return run(argv, early)


if __name__ == "__main__":
    sys.exit(main())
