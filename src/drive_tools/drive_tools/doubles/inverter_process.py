"""The virtual inverter in a process of its own, as a real inverter is a device of its own: its simulation
then never holds the host's interpreter lock (docs/bridge.md, "Virtual inverter"). No rclpy.

``InverterProcess`` (the host's side) starts ``python -m drive_tools.doubles.inverter_process`` with the scenario's
node parameters, waits until its link is open and its kernels are loaded, starts its clock, stops it and
reads back what ``timing_report`` needs. The child speaks lines on its standard streams: it prints
``ready``, waits for ``start``, runs until ``stop`` (or its last sample), then prints one JSON line of its
counters and latencies, and keeps its link open until its standard input ends (the host's tear-down), so
that the host never sees its inverter vanish mid-run; an error is one line on its standard error and exit
code 2."""
import argparse
import json
import select
import signal
import subprocess
import sys
import threading

import numpy as np

from .virtual_inverter import InverterOptions

READY_TIMEOUT_S = 120.0
"""How long the host waits for the child's link and kernels (a cold numba cache compiles for tens of s)."""
EXIT_WAIT_S = 20.0
"""How long a child whose input closed has to exit by itself (its interpreter's tear-down took over 2 s on a
machine at half this one's pace with the other core busy) before it is killed."""


class InverterProcessError(RuntimeError):
    """The inverter's process could not start or ended without its report."""


class InverterProcess:
    """A virtual inverter running in a child process behind ``link`` ('pty': a pseudo-terminal whose slave
    is at ``link_path``; 'can': the CAN cable whose directory is ``link_path``, drive_bridge.can_cable), run as
    ``options`` (InverterOptions: its clock, wait and drive id) say, with real-time priority ``rt_priority``
    on ``cpus``. Its attributes after ``join`` are those of VirtualInverter that ``timing_report`` reads."""

    def __init__(self, parameters, link, link_path, options=None, rt_priority=0, cpus=None):
        options = options or InverterOptions()
        args = [sys.executable, "-m", "drive_tools.doubles.inverter_process", "--parameters",
                json.dumps(parameters), "--link", link, "--link-path", str(link_path),
                "--command-wait-s", repr(options.command_wait_s), "--drive-id", str(options.drive_id),
                "--rt-priority", str(rt_priority)]
        if options.rate_Hz:
            args += ["--rate-Hz", repr(options.rate_Hz)]
        if cpus:
            args += ["--cpus", ",".join(str(c) for c in sorted(cpus))]
        self.rate_Hz = options.rate_Hz
        self.k = 0
        self.counters = {"missing": 0, "watchdog_trips": 0, "overruns": 0, "host_silent_trips": 0}
        self.latencies_s, self.late_latencies_s, self.missing_runs = [], [], []
        self.before_start = 0
        self.answers_s, self.never_answered = [], 0
        self.host_written_at = None
        self.started_at, self.missing_at_start = None, 0
        self.scheduling = {"applied": [], "refused": []}
        self.stopped = False
        self.report = None
        self.endpoint = self
        self.process = subprocess.Popen(args, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        line = self._read_line(READY_TIMEOUT_S)
        if line != "ready":
            self.process.kill()
            self.process.wait()
            raise InverterProcessError(f"the virtual inverter's process did not start (exit code "
                                       f"{self.process.returncode}; its error is above)")

    def _read_line(self, timeout_s):
        ready, _, _ = select.select([self.process.stdout], [], [], timeout_s)
        return self.process.stdout.readline().strip() if ready else None

    def hear_writes_of(self, bridge):
        """Judge commands by when the host wrote them (VirtualInverter.hear_host_writes), across processes: the
        host ``bridge``'s (InverterBridge) ring of writes in shared memory, mapped by the child before its clock
        starts, then the name unlinked. InverterProcessError when the child does not take it."""
        self._tell(f"host_writes {bridge.share_written()} {bridge.block_samples}")
        heard = self._read_line(READY_TIMEOUT_S)
        bridge.unlink_written()
        if heard != "heard":
            raise InverterProcessError(f"the virtual inverter's process did not map the host's writes ({heard!r})")
        self.host_written_at = bridge.written_at

    def note_answers(self, final=False):
        """The child noted its answers itself (its report's ``answers_s``)."""

    def start(self):
        """Start the inverter's clock."""
        self._tell("start")

    def stop(self):
        """Stop the inverter (it reports once it has)."""
        if not self.stopped:
            self.stopped = True
            self._tell("stop")

    def _tell(self, word):
        try:
            self.process.stdin.write(word + "\n")
            self.process.stdin.flush()
        except (BrokenPipeError, ValueError):
            pass

    def is_alive(self):
        return self.process.poll() is None

    def join(self, timeout_s):
        """Stop the clock and wait up to ``timeout_s`` for the child's report; read it into the attributes
        (its link stays open until ``close``)."""
        self.stop()
        self._take_report(timeout_s)

    def ran_out(self):
        """Its run is over (its report came, or the child exited): nothing more comes from it."""
        return self._take_report(0.0) or self.process.poll() is not None

    def _take_report(self, timeout_s):
        """Read the child's report (within ``timeout_s``) into the attributes, once; whether it is read."""
        if self.report is None and self.process.poll() is None:
            line = self._read_line(timeout_s)
            if line:
                self.report = json.loads(line)
                self.k = self.report["k"]
                self.counters.update(self.report["counters"])
                self.latencies_s = self.report["latencies_s"]
                self.late_latencies_s = self.report["late_latencies_s"]
                self.missing_runs = self.report["missing_runs"]
                self.before_start = self.report["before_start"]
                self.answers_s, self.never_answered = self.report["answers_s"], self.report["never_answered"]
                self.started_at, self.missing_at_start = self.report["started_at"], self.report["missing_at_start"]
                self.scheduling = self.report["scheduling"]
        return self.report is not None

    def close(self, timeout_s=EXIT_WAIT_S):
        """Close the link and end the child however it stands (the host's tear-down): it has ``timeout_s``
        to exit by itself once its input closes, then it is killed."""
        for stream in (self.process.stdin, self.process.stdout):
            try:
                stream.close()
            except (BrokenPipeError, OSError):
                pass
        try:
            self.process.wait(timeout_s)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()


def _arguments(argv):
    parser = argparse.ArgumentParser(prog="python -m drive_tools.doubles.inverter_process",
                                     description="A virtual inverter in a process of its own (started by drive "
                                                 "launch --link ... --paced)")
    parser.add_argument("--parameters", required=True, help="the node parameters of the scenario, JSON")
    parser.add_argument("--link", choices=("pty", "can"), required=True)
    parser.add_argument("--link-path", required=True)
    parser.add_argument("--rate-Hz", type=float, default=None)
    parser.add_argument("--command-wait-s", type=float, default=1.0)
    parser.add_argument("--drive-id", type=int, default=0)
    parser.add_argument("--rt-priority", type=int, default=0)
    parser.add_argument("--cpus", default=None)
    return parser.parse_args(argv)


def _hear_host_writes(inverter, name, block_samples):
    """Map the host's ring of writes (InverterBridge.share_written) named ``name`` and judge commands by it; the
    mapping (kept while the inverter runs). The host unlinks the name: this process's resource tracker is told to
    leave it alone."""
    from multiprocessing import resource_tracker, shared_memory

    from drive_bridge.inverter_bridge import WRITES_KEPT, written_at
    shared = shared_memory.SharedMemory(name=name)
    resource_tracker.unregister(shared._name, "shared_memory")
    written = np.ndarray((WRITES_KEPT, 2), dtype=np.float64, buffer=shared.buf)
    n = int(block_samples)
    inverter.hear_host_writes(lambda k: written_at(written, n, k))
    return shared


def main(argv=None):
    from drive_bridge.inverter_link import CanLink
    from drive_common.config.parameters import all_parameters, scenario_from_parameters
    from drive_common.contract.errors import DriveError
    from drive_common.runtime.realtime import collector_held, real_time_scheduling

    from .virtual_inverter import VirtualInverter
    from .virtual_links import PtyEndpoint

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    args = _arguments(argv)
    try:
        scenario = scenario_from_parameters(all_parameters(json.loads(args.parameters)))
        if args.link == "pty":
            endpoint = PtyEndpoint(args.link_path)
        else:
            endpoint = CanLink(args.link_path, args.drive_id, "cable")
            endpoint.open()
        inverter = VirtualInverter(scenario, endpoint, InverterOptions(rate_Hz=args.rate_Hz,
                                                                       command_wait_s=args.command_wait_s,
                                                                       drive_id=args.drive_id))
        inverter.warm_up(np.zeros((inverter.block_samples, 10)))
    except (DriveError, ValueError, OSError) as error:
        print(f"virtual inverter: {error}", file=sys.stderr)
        return 2
    cpus = {int(c) for c in args.cpus.split(",")} if args.cpus else None
    applied, refused = real_time_scheduling(args.rt_priority, cpus)
    print("ready", flush=True)
    line, shared = sys.stdin.readline().strip(), None
    if line.startswith("host_writes "):
        shared = _hear_host_writes(inverter, *line.split()[1:])
        print("heard", flush=True)
        line = sys.stdin.readline().strip()
    if line != "start":
        endpoint.close()
        return 0
    listener = threading.Thread(target=lambda: (sys.stdin.readline(), inverter.stop()), daemon=True)
    listener.start()
    with collector_held():
        inverter.run()
    if shared is not None:
        inverter.note_answers(final=True)
    report = {"k": inverter.k, "counters": inverter.counters, "latencies_s": inverter.latencies_s,
              "late_latencies_s": inverter.late_latencies_s, "missing_runs": inverter.missing_runs,
              "before_start": inverter.before_start, "answers_s": inverter.answers_s,
              "never_answered": inverter.never_answered, "started_at": inverter.started_at,
              "missing_at_start": inverter.missing_at_start, "scheduling": {"applied": applied, "refused": refused}}
    try:
        print(json.dumps(report), flush=True)
    except BrokenPipeError:
        pass
    listener.join()
    sys.stdin.read()
    endpoint.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
