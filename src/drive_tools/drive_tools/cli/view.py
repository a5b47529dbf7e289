"""``drive view``: the live view beside any running drive (drive_tools.view.server), and ``drive launch --view``:
the same in a process of its own for the time of the launch (its interpreter apart from the drive's)."""
import subprocess
import sys
import tempfile
import time

from drive_common.contract.errors import DriveError
from drive_common.contract.exit_codes import EXIT_SIGNAL_BASE

from .options import CommandLineError, finite_float

READY_PREFIX = "drive view: page "
START_TIMEOUT_S = 30.0


def cmd_view(args):
    import rclpy
    from rclpy.signals import SignalHandlerOptions

    from drive_common.runtime.interrupt import polled, requested
    from drive_tools.view.server import start_view
    options = view_options(args)
    context = rclpy.Context()
    rclpy.init(context=context, signal_handler_options=SignalHandlerOptions.NO)
    try:
        with polled():
            try:
                view = start_view(context, options)
            except (OSError, RuntimeError) as error:
                raise DriveError(f"--port {args.port} / --page-port {args.page_port}: cannot serve ({error})") \
                    from None
            which = ", ".join(options.namespaces) or "every drive that appears"
            print(f"{READY_PREFIX}{view.url} (Foxglove app: {view.ws_url}); serving {which}; Ctrl-C stops",
                  flush=True)
            end = time.monotonic() + args.duration if args.duration else None
            while not requested() and (end is None or time.monotonic() < end):
                time.sleep(0.1)
            view.stop()
            stopped_by = requested()
    finally:
        context.try_shutdown()
    return EXIT_SIGNAL_BASE + stopped_by if stopped_by else 0


def view_options(args):
    from drive_tools.view.server import ViewOptions
    for option, port in (("--port", args.port), ("--page-port", args.page_port)):
        if not 0 <= port <= 65535:
            raise CommandLineError(f"{option}: {port} is not a TCP port (0-65535; 0: any free one)")
    if args.currents_every < 1:
        raise CommandLineError(f"--currents-every: {args.currents_every} must be at least 1")
    if args.duration is not None and args.duration <= 0:
        raise CommandLineError(f"--duration: {args.duration} must be positive")
    return ViewOptions(tuple(args.namespace or ()), args.host, args.port, args.page_port, args.currents_every)


def with_view(command, namespaces):
    """``command`` (drive launch, drive up) with ``--view``: a ``drive view`` process serves its drives
    (``namespaces(args)``: their namespaces) while it runs, its page's address said on stderr."""
    def run(args):
        if not args.view:
            return command(args)
        if not 0 <= args.view_port <= 65534:
            raise CommandLineError(f"--view-port: {args.view_port} is not a TCP port with one after it (0-65534)")
        page_port = args.view_port + 1 if args.view_port else 0
        said = tempfile.TemporaryFile("w+")
        served = [word for namespace in namespaces(args) for word in ("--namespace", namespace)]
        child = subprocess.Popen([sys.executable, "-m", "drive_tools.cli", "view", *served,
                                  "--port", str(args.view_port), "--page-port", str(page_port)],
                                 stdout=subprocess.PIPE, stderr=said, text=True)
        try:
            line = child.stdout.readline()
            if not line.startswith(READY_PREFIX):
                child.wait(START_TIMEOUT_S)
                said.seek(0)
                reason = " ".join(said.read().split()) or f"exit code {child.returncode}"
                raise DriveError(f"--view: the view did not start ({reason})")
            print(f"drive: view at {line[len(READY_PREFIX):].split(';')[0]}", file=sys.stderr, flush=True)
            return command(args)
        finally:
            child.send_signal(2)
            try:
                child.wait(5.0)
            except subprocess.TimeoutExpired:
                child.kill()
                child.wait()
            said.close()
    return run


def add_commands(sub):
    """``drive view``; ``--view`` on ``drive launch`` (added to its parser)."""
    view = sub.add_parser("view", help="serve running drives live: the Foxglove WebSocket protocol and a page "
                                       "that plots angle error, speed and currents per axis")
    view.add_argument("--namespace", action="append", metavar="NS",
                      help="a drive's namespace (repeat for several axes; default: every drive that appears)")
    view.add_argument("--host", default="127.0.0.1", help="address to serve on (default 127.0.0.1)")
    view.add_argument("--port", type=int, default=8765, help="Foxglove WebSocket port (default 8765; 0: any)")
    view.add_argument("--page-port", type=int, default=8766, help="the page's HTTP port (default 8766; 0: any)")
    view.add_argument("--currents-every", type=int, default=10, metavar="N",
                      help="forward every Nth per-sample currents message (default 10; blocks: all)")
    view.add_argument("--duration", type=finite_float, help="stop after this many seconds (default: Ctrl-C)")
    view.set_defaults(func=cmd_view)
    for name, namespaces in (("launch", lambda args: [args.namespace]), ("up", _robot_namespaces)):
        parser = sub.choices[name]
        parser.add_argument("--view", action="store_true", help="serve the drives live while they run (drive view)")
        parser.add_argument("--view-port", type=int, default=8765, metavar="P",
                            help="with --view: the Foxglove WebSocket port (default 8765); the page on P + 1 "
                                 "(0: any free ports)")
        parser.set_defaults(func=with_view(parser.get_default("func"), namespaces))


def _robot_namespaces(args):
    """The namespaces of the robot file's axes (drive up)."""
    from drive_tools.launch.robot_file import load_robot
    return [axis.namespace for axis in load_robot(args.robot).axes]
