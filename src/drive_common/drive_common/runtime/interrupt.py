"""SIGINT and SIGTERM for long jobs: the first signal raises ``Interrupted`` in the main thread (at the
next Python instruction, so a compiled kernel finishes its chunk first); inside ``deferred()`` it is
held until the block ends, so a swap of files or a bag's close is never cut half-way. Jobs that can
stop cleanly by themselves (the ROS graph) poll ``requested()`` inside ``polled()`` instead. A signal
never raises inside code that cannot take it (``CANNOT_TAKE_A_RAISE``: numba compiling a kernel, llvmlite,
a finalizer): it is held there and delivered again every ``REDELIVERY_S`` until it lands in code that can. A
raise that lands in a C callback is swallowed there; the signal stays recorded in ``requested()``: a long
job's loop calls ``checkpoint()`` each pass, and the command line checks ``requested()`` when the job
returns."""
import _thread
import signal
import sys
import threading
import time
from contextlib import contextmanager

SIGNALS = (signal.SIGINT, signal.SIGTERM)
CANNOT_TAKE_A_RAISE = ("numba", "llvmlite")
"""Top-level packages a signal must not raise in (a compile cut half-way leaves llvmlite's objects half-made:
their finalizers print tracebacks); a frame of a ``__del__`` method is held too."""
REDELIVERY_S = 0.01
"""How often a held signal is delivered again to the main thread [s]."""


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
    held = False
    """A raise is due but landed in code that cannot take it; a thread delivers the signal again."""
    forced = False
    """The raise held is a second signal's, due inside deferred() and polled() too."""
    redeliveries = 0
    """Deliveries the thread made that the handler has not yet taken."""


_state = _State()
_redelivery_lock = threading.Lock()
_redelivery = [None]
"""The thread delivering a held signal again, or None."""


def _handler(signum, frame):
    with _redelivery_lock:
        redelivered = _state.redeliveries > 0
        _state.redeliveries -= redelivered
    if redelivered and not _state.held:
        return
    first = not _state.signum
    if first:
        _state.signum = signum
    forced = (not first and not redelivered) or (redelivered and _state.forced)
    if not (_state.raising or forced):
        _state.pending = True
        _state.held = False
        return
    if frame is not None and not _takes_a_raise(frame):
        _state.forced = forced
        _hold()
        return
    _state.held = False
    raise Interrupted(_state.signum)


def _takes_a_raise(frame):
    """Whether a raise may land in ``frame``: no frame of its stack is in ``CANNOT_TAKE_A_RAISE`` or a finalizer."""
    while frame is not None:
        if (frame.f_globals.get("__name__", "").partition(".")[0] in CANNOT_TAKE_A_RAISE
                or frame.f_code.co_name == "__del__"):
            return False
        frame = frame.f_back
    return True


def _hold():
    """Deliver the signal recorded again every REDELIVERY_S until the handler raises it or a block ends."""
    with _redelivery_lock:
        _state.held = True
        if _redelivery[0] is None:
            _redelivery[0] = threading.Thread(target=_redeliver, name="signal redelivery", daemon=True)
            _redelivery[0].start()


def _redeliver():
    while True:
        time.sleep(REDELIVERY_S)
        with _redelivery_lock:
            if not _state.held:
                _redelivery[0] = None
                return
            _state.redeliveries += 1
            _thread.interrupt_main(_state.signum)


def _release():
    """Stop delivering a held signal again; returns once the thread has ended."""
    with _redelivery_lock:
        _state.held = False
        thread = _redelivery[0]
    if thread is not None:
        thread.join()


@contextmanager
def handled():
    """Handle SIGINT and SIGTERM as above inside the block (main thread only); the previous handlers
    are restored after it, and a signal still held raises then."""
    _state.signum = 0
    _state.raising = True
    _state.pending = False
    previous = {signum: signal.signal(signum, _handler) for signum in SIGNALS}
    hook = sys.unraisablehook
    sys.unraisablehook = _quiet_about_interrupts(hook)
    held = 0
    try:
        yield
        held = _state.held and _state.signum
    finally:
        _release()
        sys.unraisablehook = hook
        _state.signum = 0
        for signum, handler in previous.items():
            signal.signal(signum, handler)
        _state.redeliveries = 0
    if held:
        raise Interrupted(held)


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
    """Raise the signal recorded if its raise was swallowed (a C callback, a finalizer) or is held; nothing
    inside deferred() or polled(). Called each pass of a long job's loop, where
    a raise that was not swallowed would have left the loop already."""
    if _state.raising and _state.signum:
        _state.held = False
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
            _release()
            _state.signum = 0
            for signum, handler in previous.items():
                signal.signal(signum, handler)
            _state.redeliveries = 0
