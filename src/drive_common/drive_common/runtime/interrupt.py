"""SIGINT and SIGTERM for long jobs: the first signal raises ``Interrupted`` in the main thread (at the
next Python instruction, so a compiled kernel finishes its chunk first); inside ``deferred()`` it is
held until the block ends, so a swap of files or a bag's close is never cut half-way. Jobs that can
stop cleanly by themselves (the ROS graph) poll ``requested()`` inside ``polled()`` instead. A raise
that lands in a C callback (numba's compiler calls back into Python) is swallowed there; the signal
stays recorded in ``requested()``: a long job's loop calls ``checkpoint()`` each pass, and the command line
checks ``requested()`` when the job returns."""
import signal
import sys
from contextlib import contextmanager

SIGNALS = (signal.SIGINT, signal.SIGTERM)


class Interrupted(BaseException):
    """A job was stopped by a signal; ``signum`` says which (exit code 128 + signum)."""

    def __init__(self, signum):
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


class _State:
    signum = 0
    """The first signal received since handled() began, or 0."""
    raising = True
    """False inside deferred() and polled(): the signal is only recorded."""
    pending = False
    """A signal was recorded inside deferred() and is raised when the block ends."""


_state = _State()


def _handler(signum, frame):
    first = not _state.signum
    if first:
        _state.signum = signum
    if _state.raising or not first:
        raise Interrupted(_state.signum)
    _state.pending = True


@contextmanager
def handled():
    """Handle SIGINT and SIGTERM as above inside the block (main thread only); the previous handlers
    are restored after it."""
    _state.signum = 0
    _state.raising = True
    _state.pending = False
    previous = {signum: signal.signal(signum, _handler) for signum in SIGNALS}
    hook = sys.unraisablehook
    sys.unraisablehook = _quiet_about_interrupts(hook)
    try:
        yield
    finally:
        sys.unraisablehook = hook
        _state.signum = 0
        for signum, handler in previous.items():
            signal.signal(signum, handler)


def _quiet_about_interrupts(hook):
    """An unraisable-exception hook that passes over ``Interrupted`` (a raise swallowed by a C callback:
    the signal stays recorded) and hands anything else to ``hook``."""
    def quiet(unraisable):
        if not isinstance(unraisable.exc_value, Interrupted):
            hook(unraisable)
    return quiet


def requested():
    """The first signal that asked the job to stop, or 0."""
    return _state.signum


def checkpoint():
    """Raise the signal recorded if its raise was swallowed (a C callback: a finalizer run by a collection,
    numba's compiler); nothing inside deferred() or polled(). Called each pass of a long job's loop, where
    a raise that was not swallowed would have left the loop already."""
    if _state.raising and _state.signum:
        raise Interrupted(_state.signum)


@contextmanager
def _recording_only():
    """Inside the block a first signal is recorded, not raised; yields whether it raised before."""
    before = _state.raising
    _state.raising = False
    try:
        yield before
    finally:
        _state.raising = before


@contextmanager
def deferred():
    """Hold a signal that arrives inside the block; raise it when the block ends."""
    with _recording_only() as raised_before:
        yield
    if raised_before and _state.pending:
        _state.pending = False
        raise Interrupted(_state.signum)


@contextmanager
def polled():
    """Record a signal that arrives inside the block without raising (a second one raises): the block
    polls ``requested()`` and winds down by itself. Installs the handlers for the block when handled()
    has not (a library caller), and then starts with no signal recorded."""
    previous = {signum: signal.getsignal(signum) for signum in SIGNALS}
    borrowed = any(handler is not _handler for handler in previous.values())
    if borrowed:
        _state.signum = 0
        for signum in SIGNALS:
            signal.signal(signum, _handler)
    try:
        with _recording_only():
            yield
    finally:
        _state.pending = False
        if borrowed:
            _state.signum = 0
            for signum, handler in previous.items():
                signal.signal(signum, handler)
