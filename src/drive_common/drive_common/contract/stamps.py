"""Sample stamps: header.stamp of every per-sample message is the sampling instant t_k = k·T_s."""

RESYNC_SAMPLES = 1000
"""How far ahead a sample may be for a node to follow the plant past samples it lost; a stamp beyond
this is treated as a wrong stamp (a stray publisher), not as progress."""


def stamp_ns(k, T_s):
    """Integer nanoseconds of sampling instant k."""
    return round(k * T_s * 1e9)


def stamp_parts(k, T_s):
    """(sec, nanosec) of sampling instant k."""
    return divmod(stamp_ns(k, T_s), 1_000_000_000)


def sample_at(sec, nanosec, T_s):
    """The sample index of a stamp (sec, nanosec), or None when it is not exactly a sampling instant."""
    ns = sec * 1_000_000_000 + nanosec
    k = round(ns / (T_s * 1e9))
    return k if k >= 0 and stamp_ns(k, T_s) == ns else None


def sample_of(header, T_s):
    """The sample index a header's stamp belongs to, or None when it is not exactly a sampling instant."""
    return sample_at(header.stamp.sec, header.stamp.nanosec, T_s)
