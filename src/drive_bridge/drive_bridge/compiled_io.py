"""The C library's calls a compiled answer needs on the link, as external functions that numba calls by name in
nopython mode without the interpreter's lock: read, write and poll on the link's file descriptor, clock_gettime
(CLOCK_MONOTONIC, the clock of Python's time.monotonic) and the C library's IEEE remainder (math.remainder's value:
both exact). Buffer addresses are passed as size_t (``array.ctypes.data``). Called by name (the symbol resolved
when a kernel is loaded), the kernels calling them are cached on disk like any other."""
import ctypes.util

import numpy as np
from llvmlite import binding
from numba import njit, types

binding.load_library_permanently(ctypes.util.find_library("m") or "libm.so.6")

c_read = types.ExternalFunction("read", types.intp(types.intc, types.uintp, types.uintp))
c_write = types.ExternalFunction("write", types.intp(types.intc, types.uintp, types.uintp))
c_poll = types.ExternalFunction("poll", types.intc(types.uintp, types.uint64, types.intc))
c_clock_gettime = types.ExternalFunction("clock_gettime", types.intc(types.intc, types.uintp))
c_remainder = types.ExternalFunction("remainder", types.float64(types.float64, types.float64))

CLOCK_MONOTONIC = 1
POLLIN, POLLERR, POLLHUP, POLLNVAL = 0x001, 0x008, 0x010, 0x020


def io_scratch():
    """What the calls below fill: a pollfd (int32 fd, int16 events, int16 revents) and a timespec (int64 s,
    int64 ns)."""
    return np.zeros(2, dtype=np.int32), np.zeros(2, dtype=np.int64)


@njit(nogil=True, cache=True)
def monotonic_s(timespec):
    """CLOCK_MONOTONIC now [s] (``timespec``: int64[2] scratch)."""
    c_clock_gettime(CLOCK_MONOTONIC, timespec.ctypes.data)
    return timespec[0] + timespec[1] * 1e-9


@njit(nogil=True, cache=True)
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


@njit(nogil=True, cache=True)
def read_into(fd, buffer, at, count):
    """read(2) up to ``count`` bytes into ``buffer[at:]``: the bytes read, 0 at end of file, −1 on error."""
    return c_read(fd, buffer.ctypes.data + at, count)


@njit(nogil=True, cache=True)
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


@njit(nogil=True, cache=True)
def ieee_remainder(x, y):
    """x − n·y with n the integer nearest x/y (ties to even), exactly (math.remainder)."""
    return c_remainder(x, y)
