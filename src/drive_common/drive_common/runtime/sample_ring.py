"""A lock-free single-producer, single-consumer ring of fixed-width float64 rows, allocated once: the
real-time answer (the producer, compiled, without the interpreter's lock) hands each sample it produced to a
thread that is not real-time (the consumer: publishing, recording) and never waits for it, as ros2_control's
realtime_tools RealtimePublisher does with a try-lock. A full ring drops the row and counts it
(``overflow``): never silent, never blocking. The indices count rows ever written and read (int64, never
wrapping in practice); the producer writes a row then publishes the head with release order, the consumer
reads the head with acquire order, copies, then publishes the tail with release order (on x86 these are
compiler barriers: its stores are not reordered with stores, nor its loads with loads)."""
from typing import NamedTuple

import numpy as np
from numba import njit, types
from numba.extending import intrinsic

HEAD, TAIL, OVERFLOW = 0, 1, 2
"""Fields of a ring's ``indices``: rows written, rows read, rows dropped on a full ring."""


class SampleRing(NamedTuple):
    rows: np.ndarray
    """(capacity, width) float64."""
    indices: np.ndarray
    """int64: HEAD, TAIL, OVERFLOW."""


def sample_ring(capacity, width):
    """A ring of ``capacity`` rows of ``width`` float64 values, empty."""
    return SampleRing(np.zeros((capacity, width)), np.zeros(3, dtype=np.int64))


@intrinsic
def release_fence(typingctx):
    """No load or store before it moves after a store that follows it (LLVM ``fence release``)."""
    def codegen(context, builder, signature, arguments):
        builder.fence("release")
        return context.get_dummy_value()
    return types.none(), codegen


@intrinsic
def acquire_fence(typingctx):
    """No load or store after it moves before a load that precedes it (LLVM ``fence acquire``)."""
    def codegen(context, builder, signature, arguments):
        builder.fence("acquire")
        return context.get_dummy_value()
    return types.none(), codegen


@njit(cache=True, nogil=True, _nrt=False)
def free_slot(rows, indices):
    """The producer's next row to fill, or −1 when the ring is full (the row is then counted as dropped)."""
    head = indices[HEAD]
    acquire_fence()
    tail = indices[TAIL]
    if head - tail >= rows.shape[0]:
        indices[OVERFLOW] += 1
        return -1
    return head % rows.shape[0]


@njit(cache=True, nogil=True, _nrt=False)
def publish(indices):
    """The producer: the row of ``free_slot`` is filled; the consumer may read it."""
    release_fence()
    indices[HEAD] = indices[HEAD] + 1


@njit(cache=True, nogil=True)
def drain(rows, indices, out):
    """The consumer: copy the rows written and not yet read into ``out`` (at most its length), oldest first,
    and free them; how many."""
    head = indices[HEAD]
    acquire_fence()
    tail = indices[TAIL]
    count = min(head - tail, out.shape[0])
    capacity = rows.shape[0]
    for i in range(count):
        out[i, :] = rows[(tail + i) % capacity, :]
    release_fence()
    indices[TAIL] = tail + count
    return count
