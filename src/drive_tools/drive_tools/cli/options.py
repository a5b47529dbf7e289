"""What every ``drive`` command shares: the parser whose errors are one line, the checks of options that
name the option at fault, JSON printing and the exit code."""
import argparse
import dataclasses
import math
import os
import sys
from pathlib import Path

from drive_common.config.drive_config import MAX_BLOCK_SAMPLES, SAMPLING_PERIOD
from drive_common.config.experiment import MAX_SAMPLES
from drive_common.config.scenario import load_scenario
from drive_common.contract.errors import DriveError
from drive_common.contract.exit_codes import EXIT_REFUSED
from drive_common.contract.strict_json import dumps
from drive_common.runtime.realtime import ROBOT_RT_PRIORITY
from hf_estimator.build import refusable
from hf_estimator.registry import estimator_names, known_estimator

from .outcome import exit_code as exit_code  # the commands share it from here

MOTOR_HELP = ("the motor in place of the scenario's: a shipped motor's name or a motor file "
              "(`drive motor template` writes one)")
COMMISSIONING_HELP = ("the drive's commissioning file (written by `drive commission`), or 'nameplate' for the "
                      "nameplate alone (default: the scenario's key, else commissioning/MOTOR.yaml when present)")


class CommandLineError(DriveError):
    """An option's value is unusable; the message names the option."""


class OneLineParser(argparse.ArgumentParser):
    """argparse whose errors are one line naming the command and the option (its subcommands inherit it);
    ``--help`` shows the usage."""

    def error(self, message):
        self.exit(EXIT_REFUSED, f"{self.prog}: {message} (`{self.prog} --help` shows the usage)\n")


def finite_float(text):
    """argparse type: a finite real number (inf and nan are refused as the option's error)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be a finite number, not {text!r}")
    return value


def print_json(data):
    print(dumps(data, indent=2, ensure_ascii=False))


def progress_lines(args):
    """Where a bench's progress lines go: standard output as text; with --json (standard output is the
    report's) standard error when it is a terminal, else nowhere."""
    if not args.json:
        return print
    if sys.stderr.isatty():
        return lambda line: print(line, file=sys.stderr, flush=True)
    return None


def print_report(report, args, lines):
    """Print ``report`` as JSON with --json, else as its text ``lines(report)``."""
    if args.json:
        print_json(report)
    else:
        print("\n".join(lines(report)))


def os_error_line(error):
    """An OS error as one line naming the file (an unwritable working directory, a full disk)."""
    where = error.filename or "output"
    return f"{where}: cannot be written ({error.strerror or error})"


def record_arg(path):
    """Refuse a --record target before running: it must be new, in a writable directory that exists."""
    import tempfile
    if path is None:
        return
    target = Path(path)
    if target.exists():
        raise CommandLineError(f"--record: {path} already exists; choose a new bag name")
    if not target.parent.is_dir():
        raise CommandLineError(f"--record: the directory {target.parent} does not exist")
    try:
        tempfile.TemporaryDirectory(dir=target.parent).cleanup()
    except OSError as error:
        raise CommandLineError(f"--record: cannot write in {target.parent} ({error.strerror})") from None


def motor_reference(name_or_path):
    """A --motor as nodes in other processes find it: a motor file's absolute path (a name stays a name
    when it is not a file; the nodes' loader then names it in its error)."""
    from drive_common.motor.motor_file import motor_path
    path = motor_path(name_or_path)
    return str(path.resolve()) if path is not None else name_or_path


def estimator_arg(args):
    """Refuse an unknown --estimator (or a plugin that cannot be loaded) before anything runs, naming the
    option."""
    if args.estimator:
        known_estimator_arg("--estimator", args.estimator)


def known_estimator_arg(option, name):
    """CommandLineError naming ``option`` unless ``name`` is an estimator: registered, an installed plugin's or
    a ``module:factory`` (docs/estimator-plugins.md)."""
    try:
        known = known_estimator(name)
    except KeyError as error:
        raise CommandLineError(f"{option}: {error.args[0]}") from None
    if not known:
        raise CommandLineError(f"{option}: unknown estimator '{name}' (known: {', '.join(estimator_names())}; "
                               f"or MODULE:FACTORY)")


def estimator_list(text):
    """The estimators of ``--estimators a,b`` (all when empty); CommandLineError names an unknown one."""
    names = text.split(",") if text else estimator_names()
    for name in names:
        known_estimator_arg("--estimators", name)
    return names


def sample_period_arg(T_s):
    """--sample-period checked against the range a scenario file's sampling_period_s has."""
    try:
        return SAMPLING_PERIOD.read(T_s)
    except ValueError as error:
        raise CommandLineError(f"--sample-period: {str(error).split(': ', 1)[1]}") from None


def duration_arg(duration, T_s, block_samples=1):
    """--duration checked: at least one sample (one block of ``block_samples``), and within the sample cap a
    scenario file has (MAX_SAMPLES at T_s)."""
    if duration is None:
        return None
    if duration <= 0.0:
        raise CommandLineError(f"--duration: must be positive, not {duration}")
    if round(duration / T_s) < 1:
        raise CommandLineError(f"--duration: {duration:g} s is less than one sample ({T_s:g} s): nothing to run")
    if round(duration / T_s) < block_samples:
        raise CommandLineError(f"--duration: {duration:g} s is less than one block of {block_samples} samples "
                               f"({block_samples * T_s:g} s): nothing to answer")
    if duration / T_s > MAX_SAMPLES:
        raise CommandLineError(f"--duration: {duration:g} s at {T_s:g} s per sample is more than {MAX_SAMPLES} "
                               f"samples (the cap a scenario file has too)")
    return duration


def scenario_arg(args):
    """The scenario named on the command line, with --estimator and --duration applied."""
    estimator_arg(args)
    scenario = load_scenario(args.scenario, estimator_override=args.estimator,
                             override_source="command line --estimator", motor_override=args.motor,
                             motor_source="--motor")
    if duration_arg(args.duration, scenario.T_s) is not None:
        scenario = dataclasses.replace(scenario, duration_s=args.duration)
    if args.commissioning:
        scenario = dataclasses.replace(scenario, commissioning=args.commissioning)
    if getattr(args, "force", False) and refusable(scenario.estimator):
        scenario = dataclasses.replace(scenario, estimator_settings={**scenario.estimator_settings,
                                                                     "run_refused": True})
    blocks = getattr(args, "block_samples", None)
    if blocks is not None:
        if not 1 <= blocks <= MAX_BLOCK_SAMPLES:
            raise CommandLineError(f"--block-samples: must be from 1 to {MAX_BLOCK_SAMPLES}, not {blocks}")
        scenario = dataclasses.replace(scenario, block_samples=blocks)
    answer = getattr(args, "answer_periods", None)
    if answer is not None:
        if not 1 <= answer <= MAX_BLOCK_SAMPLES + 1:
            raise CommandLineError(f"--answer-periods: must be from 1 to {MAX_BLOCK_SAMPLES + 1}, not {answer}")
        scenario = dataclasses.replace(scenario, answer_periods=answer)
    return scenario


def block_sizes(text):
    """The block sizes of ``--block-samples N[,N...]``; CommandLineError names the option."""
    try:
        sizes = [int(part) for part in text.split(",")]
    except ValueError:
        sizes = []
    if not sizes or any(not 1 <= n <= MAX_BLOCK_SAMPLES for n in sizes):
        raise CommandLineError(f"--block-samples: must be whole numbers from 1 to {MAX_BLOCK_SAMPLES}, "
                               f"comma-separated, not {text!r}")
    return sizes


def windows_arg(text):
    """The (t0, t1) scoring windows [s] of ``--windows T0:T1[,T0:T1...]`` (None without the option);
    CommandLineError names the option."""
    if not text:
        return None
    windows = []
    for part in text.split(","):
        try:
            t0, t1 = (float(value) for value in part.split(":"))
        except ValueError:
            t0 = t1 = math.nan
        if not (math.isfinite(t0) and math.isfinite(t1) and 0.0 <= t0 < t1):
            raise CommandLineError(f"--windows: T0:T1[,T0:T1...] in seconds with 0 ≤ T0 < T1, not {part!r}")
        windows.append((t0, t1))
    return windows


def recording_options(parser):
    """The options that supply what a bag does not say (docs/recordings.md)."""
    parser.add_argument("--motor", metavar="PRESET|FILE",
                        help="the motor, for a bag whose drive_config does not name one: a shipped motor or a "
                             "YAML/JSON file of the contract's drive_config motor keys")
    parser.add_argument("--sample-period", type=finite_float, metavar="S",
                        help="the sample period [s], for a bag without drive_config")
    parser.add_argument("--commissioning", metavar="FILE", help=COMMISSIONING_HELP)
    parser.add_argument("--windows", metavar="T0:T1[,T0:T1...]",
                        help="score these intervals [s] (default: the scenario's steady windows, else found "
                             "automatically where the recorded speed is steady)")
    parser.add_argument("--namespace", metavar="NS",
                        help="the drive's namespace, for a bag holding several (a robot's: `drive up --record`)")


def warn_if_nameplate_only(source, motor, scenario_name):
    """Say on stderr that a drive found no commissioning file and ran on its nameplate alone."""
    from drive_common.motor.commissioning import NAMEPLATE_ONLY, default_commissioning_file

    if source == NAMEPLATE_ONLY:
        print(f"drive: warning: no {default_commissioning_file(motor)} here and none named: the drive ran on "
              f"its nameplate alone (`drive commission {scenario_name}` measures the motor)", file=sys.stderr)


UNSET = object()
"""A scheduling option not given on `drive launch`'s command line (robot_real_time fills it)."""


def robot_real_time(args):
    """Fill in what `drive launch`'s command line left unset. With --link and --paced, the robot's
    configuration (docs/ros-graph.md, "Real time"): SCHED_FIFO ROBOT_RT_PRIORITY, the process on the last
    CPU of two or more and, over a pty, the kernel's unbound workqueues there too (a serial link's bytes pass
    through one), and composed, the controller taking the estimator's answers directly, the answer compiled
    whole (--answer compiled). Otherwise none of it. Where the system refuses a setting, the run says so in one
    line and goes on without it. Refused: --paced with --processes separate, an answer compiled elsewhere than
    composed behind a link, --intra-process with separate processes."""
    if args.paced and args.processes == "separate":
        raise CommandLineError("--paced --processes separate: refused: each block would cross three processes "
                               "over DDS within its window, and every period ran at zero volts (measured, "
                               "docs/ros-graph.md \"Real time\"); a paced drive runs composed")
    robot = bool(args.paced and args.link)
    cpus = sorted(os.sched_getaffinity(0))
    last = {cpus[-1]} if robot and len(cpus) > 1 else None
    if args.rt_priority is UNSET:
        args.rt_priority = ROBOT_RT_PRIORITY if robot else 0
    if args.cpus is UNSET:
        args.cpus = last
    if args.workqueue_cpus is UNSET:
        args.workqueue_cpus = args.cpus if robot and args.link == "pty" else None
    if args.intra_process is None:
        args.intra_process = robot and args.processes == "composed"
    if args.intra_process and args.processes != "composed":
        raise CommandLineError("--intra-process: needs --processes composed (the estimator hands its answers to "
                               "the controller in one process)")
    if args.answer is None:
        args.answer = "compiled" if robot and args.processes == "composed" else "python"
    if args.answer == "compiled" and (not args.link or args.processes != "composed"):
        raise CommandLineError(f"--answer compiled: needs --link pty|can and --processes composed (it reads and "
                               f"writes the link's descriptor in the drive's process), not --link "
                               f"{args.link or '(none)'} --processes {args.processes}")


def answer_argument(parser, default):
    """``--answer python|compiled`` (drive_tools.runner.compiled_answer) with ``default`` (None: robot_real_time
    chooses)."""
    parser.add_argument("--answer", choices=("python", "compiled"), default=default,
                        help="the drive's answer in Python (its nodes in `drive launch`), or compiled whole off the "
                             "interpreter's lock on a thread of its own (`drive launch`'s default with --link and "
                             "--paced)")


def answer_options(args):
    """The AnswerOptions of ``--answer compiled`` (its thread's priority from --rt-priority), else None."""
    if args.answer != "compiled":
        return None
    from drive_tools.runner.compiled_answer import AnswerOptions
    return AnswerOptions()
