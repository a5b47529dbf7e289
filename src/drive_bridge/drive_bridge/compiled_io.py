"""The C library's calls a compiled answer needs on the link, as ctypes function pointers that numba calls in
nopython mode without the interpreter's lock: read, write and poll on the link's file descriptor,
clock_gettime (CLOCK_MONOTONIC, the clock of Python's time.monotonic) and the C library's IEEE remainder
(math.remainder's value: both exact). Buffer addresses are passed as size_t (``array.ctypes.data``). Kernels
calling them are not cached on disk (numba cannot cache a ctypes pointer); they compile with the loop that
calls them."""
import ctypes
import ctypes.util

import numpy as np
from numba import njit

_libc = ctypes.CDLL(None, use_errno=True)
_libm = ctypes.CDLL(ctypes.util.find_library("m") or "libm.so.6")


def _function(library, name, restype, *argtypes):
    function = getattr(library, name)
    function.restype, function.argtypes = restype, argtypes
    return function


c_read = _function(_libc, "read", ctypes.c_ssize_t, ctypes.c_int, ctypes.c_size_t, ctypes.c_size_t)
c_write = _function(_libc, "write", ctypes.c_ssize_t, ctypes.c_int, ctypes.c_size_t, ctypes.c_size_t)
c_poll = _function(_libc, "poll", ctypes.c_int, ctypes.c_size_t, ctypes.c_ulong, ctypes.c_int)
c_clock_gettime = _function(_libc, "clock_gettime", ctypes.c_int, ctypes.c_int, ctypes.c_size_t)
c_remainder = _function(_libm, "remainder", ctypes.c_double, ctypes.c_double, ctypes.c_double)

CLOCK_MONOTONIC = 1
POLLIN, POLLERR, POLLHUP, POLLNVAL = 0x001, 0x008, 0x010, 0x020


def io_scratch():
    """What the calls below fill: a pollfd (int32 fd, int16 events, int16 revents) and a timespec (int64 s,
    int64 ns)."""
    return np.zeros(2, dtype=np.int32), np.zeros(2, dtype=np.int64)


@njit(nogil=True)
def monotonic_s(timespec):
    """CLOCK_MONOTONIC now [s] (``timespec``: int64[2] scratch)."""
    c_clock_gettime(CLOCK_MONOTONIC, timespec.ctypes.data)
    return timespec[0] + timespec[1] * 1e-9


@njit(nogil=True)
def wait_readable(pollfd, fd, timeout_ms):
    """poll(2) on ``fd`` for reading up to ``timeout_ms``: 1 readable, 0 nothing (or interrupted), −1 the
    descriptor failed (error, hang-up, invalid)."""
    pollfd[0], pollfd[1] = fd, POLLIN
    ready = c_poll(pollfd.ctypes.data, 1, timeout_ms)
    if ready <= 0:
        return 0
    revents = (pollfd[1] >> 16) & 0xFFFF
    if revents & POLLIN:
        return 1
    return -1 if revents & (POLLERR | POLLHUP | POLLNVAL) else 0


@njit(nogil=True)
def read_into(fd, buffer, at, count):
    """read(2) up to ``count`` bytes into ``buffer[at:]``: the bytes read, 0 at end of file, −1 on error."""
    return c_read(fd, buffer.ctypes.data + at, count)


@njit(nogil=True)
def write_all(fd, data, n):
    """write(2) of ``data[:n]`` until all of it is written; False on error (a full non-blocking port
    included, as os.write's BlockingIOError)."""
    done = 0
    while done < n:
        written = c_write(fd, data.ctypes.data + done, n - done)
        if written < 0:
            return False
        done += written
    return True


@njit(nogil=True)
def ieee_remainder(x, y):
    """x − n·y with n the integer nearest x/y (ties to even), exactly (math.remainder)."""
    return c_remainder(x, y)
