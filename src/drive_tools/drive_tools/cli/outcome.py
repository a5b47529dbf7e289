"""The exit codes of the ``drive`` commands and their one-line reasons (drive_common.contract.exit_codes): every
non-zero exit says why on stderr, once."""
import sys

from drive_common.contract.exit_codes import (
    EXIT_NODE_FAULTS,
    EXIT_NOT_FOLLOWING,
    EXIT_NOT_TRACKING,
    EXIT_RECORDING_FAILED,
    EXIT_REFUSED,
    EXIT_SIGNAL_BASE,
    EXIT_TRIPPED,
)

EXIT_MEANINGS = {EXIT_REFUSED: "refused", EXIT_NODE_FAULTS: "a node reported a fault during the run",
                 EXIT_RECORDING_FAILED: "an output was not written in full",
                 EXIT_NOT_TRACKING: "the drive refused to start or ended holding zero torque after a lost lock",
                 EXIT_NOT_FOLLOWING: "the shaft did not follow its command",
                 EXIT_TRIPPED: "the drive's protections tripped it into its safe state"}
"""What each non-zero exit code means, in the words of the fallback reason line (drive_common.contract.exit_codes)."""
_REASONS = []
"""The reason lines said on stderr by the command in progress (reset by the command line's main)."""


def say_reason(line):
    """Print the one-line reason of a non-zero exit on stderr (``drive: …``) and note it was said."""
    text = " ".join(str(line).split())
    _REASONS.append(text)
    print(f"drive: {text}", file=sys.stderr)


def reasons_said():
    """The reason lines the command in progress printed (say_reason)."""
    return list(_REASONS)


def forget_reasons():
    _REASONS.clear()


def fallback_reason(command, code):
    """The reason line for a non-zero exit that printed none of its own."""
    if code >= EXIT_SIGNAL_BASE:
        return f"{command}: stopped by signal {code - EXIT_SIGNAL_BASE}; what was done is printed, marked interrupted"
    return f"{command}: {EXIT_MEANINGS.get(code, f'exit {code}')} (the report says more)"


def outcome(interrupted=0, node_faults=None, output_error=None, not_tracking=None, not_following=None,
            tripped=None):
    """(code, reason): 128 + the signal that stopped the run, else the worst of drive_common.contract.exit_codes
    (an output, bag or plot, not written in full; the drive tripped by its protections; the drive not
    tracking at the end; the shaft not following its command; a node fault), else (0, None). Each argument
    but ``interrupted`` is the one-line reason of its cause, or empty where it did not happen."""
    if interrupted:
        return EXIT_SIGNAL_BASE + interrupted, (f"interrupted by signal {interrupted}; what was done is printed, "
                                                f"marked interrupted")
    for code, reason in ((EXIT_RECORDING_FAILED, output_error), (EXIT_TRIPPED, tripped),
                         (EXIT_NOT_TRACKING, not_tracking), (EXIT_NOT_FOLLOWING, not_following),
                         (EXIT_NODE_FAULTS, node_faults)):
        if reason:
            return code, " ".join(str(reason).split())
    return 0, None


def exit_code(*causes, **named):
    """The exit code of ``outcome(*causes, **named)``, its reason said on stderr (say_reason) when non-zero."""
    code, reason = outcome(*causes, **named)
    if code:
        say_reason(reason)
    return code


def tripped(metrics):
    """Why the drive's protections tripped it during the run (its report's ``protection``), or None."""
    trip = (metrics.get("protection") or {}).get("trip")
    if not trip:
        return None
    return f"the drive's protections tripped it at {trip['at_s']:.4f} s: {trip['cause']}, into {trip['safe_state']}"


def not_tracking(result, metrics=None):
    """Why the run is not tracking at its end, or None: the estimator refused to start, or the run ended holding
    zero torque after a lost lock (the log's last state; the estimator's own account). A run shorter than the
    start-up is not a failure. ``metrics``: the run's report (its start-up line names the measured cause)."""
    import numpy as np

    from drive_common.contract.estimator_states import LOCK_LOST
    from drive_common.contract.log import COLUMN
    states = result.log[:, COLUMN["state"]]
    if not states.size:
        return None
    startup = (metrics or {}).get("startup") or {}
    refused = startup.get("refused") or (result.startup or {}).get("refused")
    if refused and not startup.get("completed"):
        return f"the start was refused, no torque applied: {refused}"
    if states[-1] == LOCK_LOST:
        lost = int(startup.get("lock_lost") or 0)
        held = states.size - int(np.argmax(states[::-1] != LOCK_LOST)) if (states != LOCK_LOST).any() else 0
        at_s = float(result.log[held, COLUMN["t"]])
        return (f"the drive lost its lock {lost} time(s) by its own account and holds zero torque from {at_s:.3f} s "
                f"to the end: the shaft no longer follows its command")
    return None


def not_following(metrics):
    """Why the shaft did not follow its command (the speed supervision's faults), or None."""
    from foc_controller.supervision import fault_line
    faults = metrics.get("supervision") or []
    if not faults:
        return None
    more = f" (and {len(faults) - 1} more fault(s))" if len(faults) > 1 else ""
    return f"the shaft did not follow its command: {fault_line(faults[0])}{more}"


def node_fault_line(faults):
    """The node faults of a run in one line, or None."""
    if not faults:
        return None
    return "node fault(s) during the run: " + "; ".join(
        f"{name} ({', '.join(f'{kind} ×{n}' for kind, n in d['faults'].items())})" for name, d in faults.items())


def output_failed(*errors):
    """The errors of outputs not written in full (bag, plot, log), as one line; None when there are none."""
    found = [" ".join(e.split()) for e in errors if e]
    return "; ".join(found) or None
