"""Checks of configuration values: each returns the value in its Python type or raises ValueError
saying, in one line, what the key must be and what it was. The caller adds where it came from."""
import math


def number(key, value, low=None, high=None, low_inclusive=False, high_inclusive=True, allow_infinite=False,
           integer=False):
    """A real number (an int when ``integer``) in the interval given by ``low``/``high`` (None: open)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or (integer and not isinstance(value, int)):
        raise ValueError(f"{key}: must be {'a whole' if integer else 'a'} number, not {value!r}")
    if math.isnan(value) or (math.isinf(value) and not allow_infinite):
        raise ValueError(f"{key}: must be a finite number, not {value!r}")
    below = low is not None and (value < low if low_inclusive else value <= low)
    above = high is not None and (value > high if high_inclusive else value >= high)
    if below or above:
        left = "[" if low_inclusive else "("
        right = "]" if high_inclusive else ")"
        interval = f"{left}{'−∞' if low is None else f'{low:g}'}, {'∞' if high is None else f'{high:g}'}{right}"
        raise ValueError(f"{key}: must lie in {interval}, not {value!r}")
    return int(value) if integer else float(value)


def positive(key, value, high=None, allow_infinite=False):
    """A number > 0 (and ≤ ``high``)."""
    return number(key, value, low=0.0, high=high, allow_infinite=allow_infinite)


def flag(key, value):
    """true or false."""
    if not isinstance(value, bool):
        raise ValueError(f"{key}: must be true or false, not {value!r}")
    return value


def choice(key, value, choices):
    """One of ``choices``."""
    if value not in choices:
        raise ValueError(f"{key}: must be one of {', '.join(map(str, choices))}, not {value!r}")
    return value
